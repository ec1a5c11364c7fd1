"""The ray-traced sensor (replay.synth.raytrace): a small frame, its truth, its log, bad inputs."""

from __future__ import annotations

import numpy as np
import pytest

from replay.logs import layout
from replay.logs.reader import LogReader
from replay.presets import BinGeometry
from replay.synth import write_synthetic_log
from replay.synth.raytrace import SensorModel, synthesize_raytraced_frame, write_raytraced_log
from replay.synth.raytrace.materials import TABLE
from replay.synth.raytrace.meshes import Mesh, part_mesh
from replay.synth.raytrace.pile import Pile, drop_parts
from replay.synth.raytrace.scene import TracedScene
from replay.synth.raytrace.synthesize import check_pile
from replay.synth.scene import BinPose
from replay.synth.synthesize import synthesize_frame
from replay.synth.truth_depth import read_truth_depth
from tests.cli_helpers import run_cli
from zcut.errors import ParameterError

SIZE = (60, 96)
FILL = 6.0  # mm: a few dozen parts, so the pile's simulation takes a fraction of a second


@pytest.fixture(scope="module")
def frame():
    return synthesize_raytraced_frame(kind="spheres", seed=3, size=SIZE, fill_mm=FILL)


def test_a_small_frame_keeps_the_layout(frame):
    f = frame.frame
    valid = np.isfinite(f.xyz).all(axis=2)
    assert f.xyz.shape == SIZE + (3,) and f.xyz.dtype == np.float32
    assert f.rgb.shape == SIZE + (3,) and f.rgb.dtype == np.uint8
    assert (f.masks[layout.TRUTH_OUTLIERS] == frame.truth).all()
    assert f.codes[layout.TRUTH_OUTLIER_KIND] is frame.outlier_kind
    assert ((frame.outlier_kind > 0) == frame.truth).all()
    assert not (frame.truth & ~valid).any()
    assert set(np.unique(frame.outlier_kind)) <= {0, 5, 6, 7, 8}
    assert 0.5 < valid.mean() < 1.0  # shadows and rejected pixels, but most of the frame measured
    assert len(frame.pile) > 5
    # every measured point lies on its pixel's ray, and the table and bin are hit everywhere
    z = f.xyz[..., 2]
    K = f.intrinsics
    u = np.arange(SIZE[1])[None, :]
    np.testing.assert_allclose(f.xyz[..., 0][valid], ((u - K.cx) / K.fx * z)[valid], rtol=1e-5, atol=1e-7)
    assert np.isfinite(frame.depth_true_m).all()


def test_the_truth_rule(frame):
    """Outlier iff the noise-free decoded depth is farther than 4 sigmas from every surface of the
    pixel; measured inliers away from edges lie within that plus the noise of the true depth."""
    valid = np.isfinite(frame.frame.xyz[..., 2])
    z_meas = frame.frame.xyz[..., 2].astype(np.float64) * 1000
    z_true = frame.depth_true_m.astype(np.float64) * 1000
    err = np.abs(frame.error_mm)
    thr = 4.0 * frame.sigma_mm
    # the centre surface is one of the pixel's surfaces: farther than the threshold from it is
    # necessary for an outlier
    assert (err[frame.truth] > thr[frame.truth]).all()
    inlier = valid & ~frame.truth
    near = inlier & (err <= thr)
    assert near.sum() > 0.9 * inlier.sum()  # the others are inliers on a sub-pixel's surface
    assert (np.abs(z_meas - z_true)[near] < thr[near] + 8 * frame.sigma_mm[near] + 1e-3).all()


def test_an_empty_bin_has_no_interreflections():
    """No shiny surface, no specular bounce: the empty bin's outliers are edge pixels only."""
    rf = synthesize_raytraced_frame(empty=True, seed=1, index=0, size=SIZE)
    assert rf.pile is None
    assert not (rf.outlier_kind == 6).any()
    assert np.isfinite(rf.frame.xyz[..., 2]).mean() > 0.6


def test_same_seed_same_bytes(tmp_path):
    kw = dict(kind="rods", frames=1, size=(40, 64), fill_mm=FILL)
    from replay.synth.raytrace import log as rt_log

    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a = write_raytraced_log(tmp_path / "a" / "log.mcap", seed=4, **kw).read_bytes()
    b = write_raytraced_log(tmp_path / "b" / "log.mcap", seed=4, **kw).read_bytes()
    assert a == b
    assert rt_log.RAYTRACE_VERSION == "2"


def test_depth_topic_round_trip(tmp_path):
    for d in ("h", "r"):
        (tmp_path / d).mkdir()
    path = write_synthetic_log(tmp_path / "h" / "log.mcap", kind="black_nuts", frames=2, seed=2, size=(48, 80))
    depth = read_truth_depth(path)
    assert len(depth) == 2
    reader = LogReader(path)
    for f in reader.frames():
        sf = synthesize_frame(kind="black_nuts", seed=2, index=f.index, size=(48, 80))
        want = np.where(np.isfinite(sf.surface_depth_mm), sf.surface_depth_mm / np.float32(1000), np.nan)
        got = depth[f.stamp_ns]
        assert got.dtype == np.float32 and got.shape == (48, 80)
        np.testing.assert_array_equal(got, want.astype(np.float32))
        # truth before noise: the measured inliers lie within a few tenths of a millimetre of it
        inl = np.isfinite(f.xyz[..., 2]) & ~f.masks[layout.TRUTH_OUTLIERS]
        assert np.abs(f.xyz[..., 2][inl] - got[inl]).max() < 1e-3
    rt = write_raytraced_log(tmp_path / "r" / "log.mcap", kind="spheres", frames=1, seed=3, size=(40, 64),
                            fill_mm=FILL)
    rd = read_truth_depth(rt)
    (stamp,) = rd
    f = next(LogReader(rt).frames())
    assert f.stamp_ns == stamp and rd[stamp].shape == (40, 64)
    assert set(np.unique(f.codes[layout.TRUTH_OUTLIER_KIND])) <= {0, 5, 6, 7, 8}


def _empty_mesh() -> Mesh:
    return Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros((0, 3, 3)), np.zeros(0, np.uint8))


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: TracedScene([(_empty_mesh(), TABLE, 0)]), "has no faces"),
        (lambda: drop_parts("sprockets", BinPose(), np.random.default_rng(0), count=3,
                            geometry=BinGeometry(outer_length_mm=120, outer_width_mm=90, rim_mm=10)),
         "larger than the bin's floor"),
        (lambda: synthesize_raytraced_frame(kind="rods", size=(24, 40), fill_mm=2.0,
                                            model=SensorModel(projector_c_px=(-9000.0, -9000.0))),
         "projector lights nothing"),
        (lambda: check_pile(Pile("rods", np.zeros((0, 3, 3)), np.zeros((0, 3)), 1.0, True, 12), seed=7, index=0),
         "seed 7, frame 0: the simulation left no part"),
        (lambda: SensorModel(samples=9), "SensorModel.samples"),
        (lambda: part_mesh("bolts"), "kind must be one of"),
    ],
)
def test_bad_inputs(make, match):
    with pytest.raises(ParameterError, match=match):
        make()


def test_cli_refuses_handmade_options_for_the_raytraced_sensor(tmp_path, capsys):
    rc, _out, err = run_cli(capsys, "synth", "--sensor", "raytraced", "--shiny", "-o", str(tmp_path / "x.mcap"))
    assert rc == 1
    assert err.strip().startswith("error:") and "--shiny" in err and "Traceback" not in err
    assert not (tmp_path / "x.mcap").exists()
