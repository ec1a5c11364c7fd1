"""``zcut record-stereo``: a log from scikit-image's Motorcycle built at test time, its truth checked
pixel for pixel against an independent computation; bad inputs are one line naming the file."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest
from cli_helpers import run_cli
from stereo_helpers import independent_truth, middlebury, motorcycle, write_pfm, write_scene

from replay.logs import layout
from replay.logs.reader import LogReader
from replay.synth.truth_depth import read_truth_depth


@pytest.fixture(scope="module")
def scene():
    return motorcycle(4)


@pytest.fixture(scope="module")
def scene_dir(scene, tmp_path_factory):
    return write_scene(tmp_path_factory.mktemp("stereo") / "Motorcycle", scene)


def _sgbm(scene) -> np.ndarray:
    """The disparity as the test computes it: OpenCV's SGBM, its post-filters off."""
    m = cv2.StereoSGBM_create(minDisparity=0, numDisparities=scene["ndisp"], blockSize=5, P1=8 * 3 * 25,
                              P2=32 * 3 * 25, disp12MaxDiff=-1, preFilterCap=63, uniquenessRatio=0,
                              speckleWindowSize=0, speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM)
    raw = m.compute(scene["left"], scene["right"])
    d = raw.astype(np.float64) / 16.0
    d[raw < 0] = np.nan
    return d


def test_motorcycle_log_holds_the_cloud_and_its_exact_truth(scene, scene_dir, tmp_path, capsys):
    log = tmp_path / "moto.mcap"
    rc, out, err = run_cli(capsys, "record-stereo", scene_dir, "-o", log, "--tau-px", "1.5")
    assert rc == 0, err
    assert "0 Motorcycle: 125x185" in out and "wrote 1 frame" in out
    reader = LogReader(log)
    (frame,) = list(reader.frames())
    c = scene["calib"]
    # the cloud: Z = B f / (d + doffs), X = (u - cx) Z / f, Y = (v - cy) Z / f, metres; NaN unmatched
    d = _sgbm(scene)
    z = c["baseline"] * c["focal"] / (d + c["doffs"]) / 1000.0
    v, u = np.mgrid[0:d.shape[0], 0:d.shape[1]]
    want = np.stack([(u - c["cx"]) * z / c["focal"], (v - c["cy"]) * z / c["focal"], z], axis=2)
    assert np.array_equal(np.isnan(frame.xyz), np.isnan(want))
    assert np.isfinite(want[..., 2]).mean() > 0.7
    np.testing.assert_allclose(frame.xyz, want, rtol=1e-6, atol=1e-6, equal_nan=True)
    assert np.array_equal(frame.rgb, scene["left"])
    k = frame.intrinsics
    assert (k.fx, k.fy, k.cx, k.cy, k.width, k.height) == pytest.approx(
        (c["focal"], c["focal"], c["cx"], c["cy"], 185, 125))
    # the truth, pixel for pixel, from the cloud as written, the disparity file's values and the calibration
    ind = independent_truth(frame.xyz[..., 2], scene["gt"], scene["mask"], c, tau_px=1.5)
    for name, topic in (("outliers", layout.TRUTH_OUTLIERS), ("unknown", layout.TRUTH_UNKNOWN),
                        ("detectable", layout.TRUTH_DETECTABLE)):
        assert np.array_equal(frame.masks[topic], ind[name]), name
    n = int(ind["outliers"].sum())
    assert 100 < n and 0 < int(ind["detectable"].sum()) < n  # a real share of errors, some detectable
    assert ind["unknown"][scene["mask"] == 128].all() and ind["unknown"][~np.isfinite(scene["gt"])].all()
    # the truth depth: Z_GT in metres where the disparity is known
    (depth,) = read_truth_depth(log).values()
    gt = scene["gt"].astype(np.float64)
    zg = np.where(np.isfinite(gt), c["baseline"] * c["focal"] / (gt + c["doffs"]) / 1000.0, np.nan)
    np.testing.assert_allclose(depth, zg, rtol=1e-6, equal_nan=True)
    meta = reader.metadata[layout.STEREO_METADATA]
    assert float(meta["tau_px"]) == 1.5 and meta["matcher"] == "sgbm"
    (fm,) = json.loads(meta["frames"])
    assert fm["scene"] == "Motorcycle" and fm["calibration"]["focal_px"] == pytest.approx(c["focal"])
    assert fm["matcher"]["speckle_window"] == 0 and fm["matcher"]["uniqueness_ratio"] == 0


def test_other_layouts_by_flags_give_the_same_log_content(scene, scene_dir, tmp_path, capsys):
    """Images under other names, calibration as flags, the truth as NPY, the occlusion mask named."""
    d = tmp_path / "flat"
    d.mkdir()
    shutil.copy(scene_dir / "im0.png", d / "left.png")
    shutil.copy(scene_dir / "im1.png", d / "right.png")
    shutil.copy(scene_dir / "mask0nocc.png", d / "occ.png")
    np.save(d / "gt.npy", scene["gt"])
    c = scene["calib"]
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    assert run_cli(capsys, "record-stereo", scene_dir, "-o", a)[0] == 0
    rc, _, err = run_cli(capsys, "record-stereo", d, "-o", b, "--left", "left.png", "--right", "right.png",
                         "--gt", "gt.npy", "--occlusion", "occ.png", "--focal", c["focal"], "--baseline",
                         c["baseline"], "--doffs", c["doffs"], "--cx", c["cx"], "--cy", c["cy"],
                         "--num-disparities", scene["ndisp"])
    assert rc == 0, err
    (fa,), (fb,) = list(LogReader(a).frames()), list(LogReader(b).frames())
    assert np.array_equal(fa.xyz, fb.xyz, equal_nan=True)
    assert fa.masks.keys() == fb.masks.keys() and all(np.array_equal(fa.masks[t], fb.masks[t]) for t in fa.masks)
    # a PNG ground truth with a scale: 16-bit, disparity x 256, 0 = unknown (exact at these values? no:
    # quantised, so only its topics and unknown pixels are compared)
    png = np.where(np.isfinite(scene["gt"]), np.round(scene["gt"] * 256), 0).astype(np.uint16)
    cv2.imwrite(str(d / "gt.png"), png)
    rc, _, err = run_cli(capsys, "record-stereo", scene_dir, "-o", tmp_path / "c.mcap", "--gt", d / "gt.png",
                         "--gt-scale", "256")
    assert rc == 0, err
    (fc,) = list(LogReader(tmp_path / "c.mcap").frames())
    assert np.array_equal(fc.masks[layout.TRUTH_UNKNOWN], fa.masks[layout.TRUTH_UNKNOWN])


def test_post_filters_on_request_and_bm(scene_dir, tmp_path, capsys):
    counts = {}
    for name, extra in (("plain", ()), ("filtered", ("--speckle-window", "50", "--uniqueness", "10",
                                                     "--disp12-max-diff", "1")), ("bm", ("--matcher", "bm"))):
        rc, _, err = run_cli(capsys, "record-stereo", scene_dir, "-o", tmp_path / f"{name}.mcap", *extra)
        assert rc == 0, err
        (f,) = list(LogReader(tmp_path / f"{name}.mcap").frames())
        counts[name] = int(np.isfinite(f.xyz[..., 2]).sum())
    assert counts["filtered"] < counts["plain"] and counts["bm"] > 0


def _bad_pfm(d):
    (d / "disp0GT.pfm").write_bytes(b"Pf\n185 125\n-1.0\n" + b"\0" * 100)


def _wrong_size_gt(d):
    write_pfm(d / "disp0GT.pfm", np.ones((60, 90), np.float32))


def _wrong_size_right(d):
    cv2.imwrite(str(d / "im1.png"), np.zeros((60, 90, 3), np.uint8))


def _wrong_size_mask(d):
    cv2.imwrite(str(d / "mask0nocc.png"), np.zeros((60, 90), np.uint8))


def _calib_text(text):
    return lambda d: (d / "calib.txt").write_text(text)


def _not_png(d):
    (d / "im0.png").write_bytes(b"not an image at all, really not")


def _no_calib(d):
    (d / "calib.txt").unlink()


BAD = [
    ("pfm-truncated", _bad_pfm, [], "disp0GT.pfm: 100 bytes of pixels"),
    ("pfm-size", _wrong_size_gt, [], "disp0GT.pfm: ground truth is 60x90 but the image im0.png is 125x185"),
    ("right-size", _wrong_size_right, [], "im1.png: image is 60x90 but the left image im0.png is 125x185"),
    ("mask-size", _wrong_size_mask, [], "mask0nocc.png: mask is 60x90"),
    ("not-png", _not_png, [], "im0.png: not a PNG image"),
    ("calib-garbage", _calib_text("cam0=[1 2 3]\nbaseline=10\n"), [], "calib.txt: line 1: cam0 has 3 numbers"),
    ("calib-number", _calib_text("cam0=[100 0 50; 0 100 40; 0 0 1]\nbaseline=ten\n"), [],
     "calib.txt: line 2: baseline = 'ten' is not a number"),
    ("calib-missing-baseline", _calib_text("cam0=[100 0 50; 0 100 40; 0 0 1]\n"), [], "calib.txt: no baseline"),
    ("calib-width", _calib_text("cam0=[100 0 50; 0 100 40; 0 0 1]\nbaseline=10\nwidth=99\n"), [],
     "calib.txt: width 99 but the image im0.png is 125x185"),
    ("calib-negative-focal", _calib_text("cam0=[-100 0 50; 0 100 40; 0 0 1]\nbaseline=10\n"), [],
     "calib.txt: focal_px must be a positive finite number"),
    ("no-calib", _no_calib, [], "no such file"),
    ("png-gt-needs-scale", lambda d: None, ["--gt", "mask0nocc.png"], "needs --gt-scale"),
    ("gt-suffix", lambda d: None, ["--gt", "calib.txt"], "calib.txt: ground truth must be a .pfm, .png, .npy file"),
    ("num-disparities", lambda d: None, ["--num-disparities", "20"], "num_disparities must be a positive multiple of 16"),
    ("tau", lambda d: None, ["--tau-px", "0"], "--tau-px must be a positive number"),
]


@pytest.mark.parametrize(("name", "damage", "flags", "message"), BAD, ids=[b[0] for b in BAD])
def test_bad_input_is_one_line_naming_the_file(name, damage, flags, message, scene_dir, tmp_path, capsys):
    d = tmp_path / "scene"
    shutil.copytree(scene_dir, d)
    damage(d)
    out = tmp_path / "out.mcap"
    rc, _, err = run_cli(capsys, "record-stereo", d, "-o", out, *flags)
    assert rc == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], err
    assert not out.exists() and list(tmp_path.iterdir()) == [d]  # nothing written, no temporaries


def test_middlebury_scene_truth_matches_an_independent_computation(tmp_path, capsys):
    """A real scene of the shared folder (skips without it, fails under CI): PFM rows bottom-up,
    mask0nocc's 128 and 0 unknown, the calibration of calib.txt."""
    d = middlebury() / "Teddy"
    log = tmp_path / "teddy.mcap"
    rc, _, err = run_cli(capsys, "record-stereo", d, "-o", log)
    assert rc == 0, err
    (frame,) = list(LogReader(log).frames())
    raw = (d / "disp0GT.pfm").read_bytes()
    header = raw.split(b"\n", 3)
    w, h = (int(v) for v in header[1].split())
    gt = np.frombuffer(header[3], "<f4").reshape(h, w)[::-1]
    mask = cv2.imread(str(d / "mask0nocc.png"), cv2.IMREAD_UNCHANGED)
    calib = {k.strip(): v.strip() for k, v in (ln.split("=", 1) for ln in (d / "calib.txt").read_text().splitlines()
                                              if "=" in ln)}
    k0 = [float(v) for v in calib["cam0"].strip("[]").replace(";", " ").split()]
    c = {"focal": k0[0], "doffs": float(calib["doffs"]), "baseline": float(calib["baseline"])}
    ind = independent_truth(frame.xyz[..., 2], gt, mask, c)
    assert np.array_equal(frame.masks[layout.TRUTH_OUTLIERS], ind["outliers"])
    assert np.array_equal(frame.masks[layout.TRUTH_UNKNOWN], ind["unknown"])
    assert np.array_equal(frame.masks[layout.TRUTH_DETECTABLE], ind["detectable"])
