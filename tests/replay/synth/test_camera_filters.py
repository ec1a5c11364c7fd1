"""The camera's own filters on the ray-traced sensor (``zcut synth --sensor raytraced --camera-filters``):
each does what the vendor's documentation says on tiny frames, and without them nothing changed."""

from __future__ import annotations

import hashlib

import mujoco
import numpy as np
import pytest

from replay.logs import layout
from replay.logs.reader import LogReader
from replay.synth.raytrace import SensorModel, synthesize_raytraced_frame, write_raytraced_log
from replay.synth.raytrace.camera_filters import (
    NOISE,
    OUTLIER,
    REFLECTION,
    CameraFilters,
    isolated_points,
    phase_residual_sigmas,
    snr_of,
)
from replay.synth.raytrace.optics import Phasors, decode
from replay.synth.sensor import pixel_rays
from tests.cli_helpers import run_cli
from zcut.errors import ParameterError

FILL = 6.0  # mm: a few dozen parts, the pile's simulation a fraction of a second
#: sha256 of a frame's arrays (xyz, rgb, truth, kinds, off_surface, true depth) made by the sensor
#: without the option (size 64 x 40, fill 6 mm): the default must keep them. Since the hits' t, uv and face
#: normal are float64 Möller–Trumbore's, not Embree's float32 answers (round of 2026-12-06e, docs/synthetic.md
#: "Exact hits"), this CPU and an emulated Haswell (qemu-x86_64) write these same bytes: one set, no second.
PINNED = {
    ("rods", 4): "96c4263de720e423e7acab39599547b0159942a4e3e2917a3740fc92dd8a8bea",
    ("zinc_nuts", 5): "5d0acfc3c3c3fc87cada18549c88e916eb8f6e969210abc4dfaad3c6c9c3f446",
}


def _digest(rf) -> str:
    h = hashlib.sha256()
    for a in (rf.frame.xyz, rf.frame.rgb, rf.truth, rf.outlier_kind, rf.off_surface, rf.depth_true_m):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


@pytest.mark.parametrize("kind, seed", sorted(PINNED))
def test_off_by_default_the_frames_are_the_bytes_they_were(kind, seed):
    off = CameraFilters(noise_snr=None, reflection_sigmas=None, outlier_mm=None)
    assert not off.enabled
    for filters in (None, off):
        rf = synthesize_raytraced_frame(kind=kind, seed=seed, size=(40, 64), fill_mm=FILL, camera_filters=filters)
        assert _digest(rf) == PINNED[(kind, seed)], f"MuJoCo {mujoco.__version__}: the pile is another release's (pyproject pins 4.0.0)"
        assert rf.camera_removed is None and "camera_filters" not in rf.cpu_s


def test_off_by_default_the_log_records_nothing(tmp_path):
    kw = dict(kind="rods", seed=4, frames=1, size=(24, 40), fill_mm=FILL)
    for d in ("a", "b", "c"):
        (tmp_path / d).mkdir()
    a = write_raytraced_log(tmp_path / "a" / "log.mcap", **kw)
    b = write_raytraced_log(tmp_path / "b" / "log.mcap", camera_filters=CameraFilters(None, None, None), **kw)
    assert a.read_bytes() == b.read_bytes()
    assert not any(k.startswith("camera_filter") for k in LogReader(a).metadata[layout.SYNTH_METADATA])
    c = write_raytraced_log(tmp_path / "c" / "log.mcap", camera_filters=CameraFilters(outlier_mm=3.0), **kw)
    meta = LogReader(c).metadata[layout.SYNTH_METADATA]
    assert meta["camera_filter_noise_snr"] == "7" and meta["camera_filter_outlier_mm"] == "3"
    assert meta["camera_filter_reflection_sigmas"] == "4"
    assert "SNR < 7" in meta["camera_filters"] and "within 3 mm" in meta["camera_filters"]


def test_snr_is_one_over_the_phase_noise():
    """Zivid's noise filter discards pixels below an SNR; here SNR = 1 / sigma_phase at the finest period."""
    model = SensorModel()
    snr = snr_of(np.array([0.375, 0.039, 0.004, 0.0]), model)
    sigma_phase = 2 * np.pi * model.sigma_code(np.array([0.375])) / model.periods_px[-1]
    assert snr[0] == pytest.approx(1 / sigma_phase[0]) and snr[0] == pytest.approx(21.6, abs=0.1)
    assert snr[1] == pytest.approx(7.0, abs=0.1)  # Zivid's hint: 7, at a tenth of the reference signal
    assert snr[2] == snr[3] == pytest.approx(2.2, abs=0.05)  # the readable minimum, and below it


def test_the_outlier_filter_discards_points_with_no_neighbour_within_its_distance():
    """Zivid: "discard point if Euclidean distance to neighboring points is above a threshold"."""
    z = np.full((7, 9), 500.0)
    xyz = np.stack([np.tile(np.arange(9.0), (7, 1)), np.tile(np.arange(7.0)[:, None], (1, 9)), z], axis=2)
    xyz[1, 1, 2] = 520.0      # a lone point 20 mm above its neighbours
    xyz[4, 5:7, 2] = 530.0    # a patch of two points floating together
    xyz[5, 2, 2] = 504.0      # 4 mm above the plane: within 5 mm of a neighbour
    xyz[6, 8] = np.nan        # a hole
    xyz[0, 7, 2] = 450.0      # and a lone point beside it at the border
    lone = isolated_points(xyz, within_mm=5.0)
    want = np.zeros((7, 9), bool)
    want[1, 1] = want[0, 7] = True
    np.testing.assert_array_equal(lone, want)
    assert not isolated_points(xyz, within_mm=60.0).any()
    alone = np.full((3, 3, 3), np.nan)
    alone[1, 1] = (0.0, 0.0, 500.0)  # no valid neighbour at all
    assert isolated_points(alone, within_mm=5.0)[1, 1]


def test_the_reflection_filter_sees_two_codes_in_one_pixel():
    """One code per pixel: the phases of every period agree (residual 0). A mirrored path with
    another code beside the direct one: the coarser periods disagree with the code decoded from
    the finest, beyond the noise the pixel's signal explains."""
    model = SensorModel()
    ph = Phasors.zeros(len(model.periods_px), (1, 3))
    one = np.array([0])
    ph.add_reference(one, np.array([0.5]), np.array([400.3]), model.periods_px)           # direct only
    ph.add_reference(one + 1, np.array([0.5]), np.array([400.3]), model.periods_px)       # direct ...
    ph.add_reference(one + 1, np.array([0.2]), np.array([430.3]), model.periods_px)       # ... and a ghost
    ph.add_reference(one + 2, np.array([0.5]), np.array([400.3]), model.periods_px)
    ph.add_reference(one + 2, np.array([0.02]), np.array([430.3]), model.periods_px)      # a faint ghost
    dec = decode(ph, model)
    assert np.isfinite(dec.code).all()  # the decoder alone keeps all three (contrast and consistency pass)
    assert abs(dec.code[0, 1] - 400.3) > 0.4  # the ghost pulls the code by ~1 mm of depth
    res = phase_residual_sigmas(ph, dec, model)[0]
    assert res[0] == pytest.approx(0.0, abs=1e-6)
    assert res[1] > 4.0 > res[2]


@pytest.fixture(scope="module")
def pair():
    kw = dict(kind="spheres", seed=3, size=(60, 96), fill_mm=FILL)
    return synthesize_raytraced_frame(**kw), synthesize_raytraced_frame(**kw, camera_filters=CameraFilters())


def test_filters_only_discard_and_the_scene_truth_stays(pair):
    raw, cam = pair
    v_raw = np.isfinite(raw.frame.xyz[..., 2])
    v_cam = np.isfinite(cam.frame.xyz[..., 2])
    removed = cam.camera_removed
    assert removed is not None and set(np.unique(removed)) <= {0, NOISE, REFLECTION, OUTLIER}
    np.testing.assert_array_equal(v_cam, v_raw & (removed == 0))  # a discarded point is NaN, nothing added
    assert (removed[~v_raw] == 0).all()
    np.testing.assert_array_equal(cam.frame.xyz[v_cam], raw.frame.xyz[v_cam])  # the kept points unmoved
    np.testing.assert_array_equal(cam.frame.rgb, raw.frame.rgb)
    np.testing.assert_array_equal(cam.depth_true_m, raw.depth_true_m)
    # the truth judges what the camera delivers: the raw truth on the kept points
    np.testing.assert_array_equal(cam.truth, raw.truth & v_cam)
    np.testing.assert_array_equal(cam.outlier_kind, np.where(v_cam, raw.outlier_kind, 0))
    np.testing.assert_array_equal(cam.off_surface, raw.off_surface & v_cam)
    assert (removed > 0).sum() > 0 and cam.truth.sum() < raw.truth.sum()


def test_each_filter_applies_its_documented_rule(pair):
    raw, cam = pair
    model = SensorModel()
    v_raw = np.isfinite(raw.frame.xyz[..., 2])
    removed = cam.camera_removed
    # the outlier filter: exactly the points the first two left that have no neighbour within 5 mm
    after_two = np.where((removed == 0) | (removed == OUTLIER), raw.frame.xyz[..., 2] * 1000.0, np.nan)
    lone = isolated_points(pixel_rays(raw.frame.intrinsics) * after_two[..., None], within_mm=5.0)
    np.testing.assert_array_equal(removed == OUTLIER, lone)
    # the noise filter alone: exactly the measured pixels below SNR 7
    noise_only = synthesize_raytraced_frame(kind="spheres", seed=3, size=(60, 96), fill_mm=FILL,
                                            camera_filters=CameraFilters(reflection_sigmas=None, outlier_mm=None))
    gone = noise_only.camera_removed == NOISE
    assert gone.any() and not (noise_only.camera_removed == OUTLIER).any()
    np.testing.assert_array_equal(gone, v_raw & (removed == NOISE))
    assert model.min_signal < 0.039  # SNR 7 lies above what the decoder alone reads


def test_bad_thresholds_and_the_flag_on_the_wrong_sensor(tmp_path, capsys):
    for bad in (0.0, -1.0, float("nan"), "7"):
        with pytest.raises(ParameterError, match="CameraFilters.noise_snr"):
            CameraFilters(noise_snr=bad)  # type: ignore[arg-type]
    rc, _out, err = run_cli(capsys, "synth", "--camera-filters", "-o", str(tmp_path / "x.mcap"), "--size", "64x40")
    assert rc == 1
    errors = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "--camera-filters" in errors[0] and "Traceback" not in err
    assert not (tmp_path / "x.mcap").exists()


def test_the_flag_reaches_the_log(tmp_path, capsys):
    """``zcut synth --sensor raytraced --camera-filters`` writes a log that says so (rods: a small pile)."""
    log = tmp_path / "rods.mcap"
    rc, _out, err = run_cli(capsys, "synth", "--sensor", "raytraced", "--camera-filters", "--parts", "rods",
                            "--size", "40x24", "--seed", "2", "-o", str(log))
    assert rc == 0, err
    assert "camera filters" in err
    meta = LogReader(log).metadata[layout.SYNTH_METADATA]
    assert meta["camera_filters"] == CameraFilters().describe()
    assert (meta["camera_filter_noise_snr"], meta["camera_filter_outlier_mm"]) == ("7", "5")
