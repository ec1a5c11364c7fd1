"""The stereo matcher's own post-filters as methods (issue 30): ``zcut record-stereo`` records the pixels
each post-filter would invalidate (``/stereo/rejected/...``), checked against OpenCV run here; the
methods ``stereo_uniqueness``, ``stereo_lr``, ``stereo_speckle`` and ``stereo_texture`` score them in
``accuracy`` and ``sweep`` as an independent numpy scorer does; a log without them warns and scores
nothing."""

from __future__ import annotations

import dataclasses
import json

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest
from cli_helpers import run_cli
from stereo_helpers import motorcycle, write_scene

from replay.logs import layout
from replay.logs.reader import LogReader
from zcut.stereo import POST_FILTERS, left_right_disagree_reference

POST = "stereo_uniqueness,stereo_lr,stereo_speckle"


@pytest.fixture(scope="module")
def scene():
    return motorcycle(4)


@pytest.fixture(scope="module")
def scene_dir(scene, tmp_path_factory):
    return write_scene(tmp_path_factory.mktemp("rejected") / "Motorcycle", scene)


def _opencv(scene, *, bm: bool = False, **kw) -> np.ndarray:
    """Matched pixels (bool) of OpenCV's matcher built here, post-filters off unless ``kw`` sets them."""
    s = {"uniquenessRatio": 0, "disp12MaxDiff": -1, "speckleWindowSize": 0, "speckleRange": 2, **kw}
    if bm:
        m = cv2.StereoBM_create(numDisparities=scene["ndisp"], blockSize=9)
        m.setUniquenessRatio(s["uniquenessRatio"])
        m.setDisp12MaxDiff(s["disp12MaxDiff"])
        m.setSpeckleWindowSize(s["speckleWindowSize"])
        m.setSpeckleRange(s["speckleRange"])
        m.setTextureThreshold(s.get("textureThreshold", 0))
        raw = m.compute(cv2.cvtColor(scene["left"], cv2.COLOR_RGB2GRAY), cv2.cvtColor(scene["right"], cv2.COLOR_RGB2GRAY))
    else:
        m = cv2.StereoSGBM_create(minDisparity=0, numDisparities=scene["ndisp"], blockSize=5, P1=8 * 3 * 25,
                                  P2=32 * 3 * 25, disp12MaxDiff=s["disp12MaxDiff"], preFilterCap=63,
                                  uniquenessRatio=s["uniquenessRatio"], speckleWindowSize=s["speckleWindowSize"],
                                  speckleRange=s["speckleRange"], mode=cv2.STEREO_SGBM_MODE_SGBM)
        raw = m.compute(scene["left"], scene["right"])
    return raw >= 0


def _disparity(scene, *, mirrored: bool = False) -> np.ndarray:
    """SGBM's disparity (px, NaN unmatched) of the left view, or of the right view (the mirrored pair), built here."""
    left, right = scene["left"], scene["right"]
    if mirrored:
        left, right = right[:, ::-1], left[:, ::-1]
    m = cv2.StereoSGBM.create(minDisparity=0, numDisparities=scene["ndisp"], blockSize=5, P1=8 * 3 * 25, P2=32 * 3 * 25,
                              disp12MaxDiff=-1, preFilterCap=63, uniquenessRatio=0, speckleWindowSize=0,
                              speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM)
    raw = m.compute(np.ascontiguousarray(left), np.ascontiguousarray(right))
    d = raw.astype(np.float32) / np.float32(16.0)
    d[raw < 0] = np.nan
    return d[:, ::-1] if mirrored else d


@pytest.fixture(scope="module")
def log(scene_dir, tmp_path_factory):
    """Three frames (one scene three times: an interval needs three), two strengths of each filter."""
    from cli.main import main

    p = tmp_path_factory.mktemp("rejected_log") / "moto.mcap"
    assert main(["record-stereo", str(scene_dir), str(scene_dir), str(scene_dir), "-o", str(p),
                 "--reject-uniqueness", "10,25", "--reject-lr", "0,1", "--reject-speckle", "100:2,400:1"]) == 0
    return p


def test_recorded_rejections_equal_opencv_run_here(scene, log):
    reader = LogReader(log)
    frames = list(reader.frames())
    plain = _opencv(scene)
    # the left-right check: the left view's disparity against the right view's own match (zcut.stereo's check;
    # OpenCV's disp12MaxDiff invalidates no pixel on these scenes)
    left_d, right_d = _disparity(scene), _disparity(scene, mirrored=True)
    want = {
        "uniqueness_ratio_10": plain & ~_opencv(scene, uniquenessRatio=10),
        "uniqueness_ratio_25": plain & ~_opencv(scene, uniquenessRatio=25),
        "disp12_max_diff_0": plain & left_right_disagree_reference(left_d, right_d, 0),
        "disp12_max_diff_1": plain & left_right_disagree_reference(left_d, right_d, 1),
        "speckle_window_100_speckle_range_2": plain & ~_opencv(scene, speckleWindowSize=100, speckleRange=2),
        "speckle_window_400_speckle_range_1": plain & ~_opencv(scene, speckleWindowSize=400, speckleRange=1),
    }
    assert want["uniqueness_ratio_25"].sum() > want["uniqueness_ratio_10"].sum() > 0
    assert want["speckle_window_100_speckle_range_2"].any()
    for f in frames:
        got = {t[len("/stereo/rejected/"):]: m for t, m in f.masks.items() if t.startswith("/stereo/rejected/")}
        assert got.keys() == want.keys()
        for k in want:
            assert np.array_equal(got[k], want[k]), k
        assert np.array_equal(np.isfinite(f.xyz[..., 2]), plain)  # the cloud is the plain run's
    meta = json.loads(reader.metadata[layout.STEREO_METADATA]["rejected"])
    assert [(r["method"], r["settings"]) for r in meta] == [
        ("stereo_uniqueness", {"uniqueness_ratio": 10}), ("stereo_uniqueness", {"uniqueness_ratio": 25}),
        ("stereo_lr", {"disp12_max_diff": 0}), ("stereo_lr", {"disp12_max_diff": 1}),
        ("stereo_speckle", {"speckle_window": 100, "speckle_range": 2}),
        ("stereo_speckle", {"speckle_window": 400, "speckle_range": 1})]
    assert all(r["topic"] == layout.stereo_rejected_topic(r["settings"]) for r in meta)


def test_defaults_axes_bm_and_none(scene, scene_dir, tmp_path, capsys):
    def topics(*flags):
        p = tmp_path / "x.mcap"
        rc, _, err = run_cli(capsys, "record-stereo", scene_dir, "-o", p, "--force", *flags)
        assert rc == 0, err
        (f,) = list(LogReader(p).frames())
        return {t[len("/stereo/rejected/"):]: m for t, m in f.masks.items() if t.startswith("/stereo/rejected/")}

    assert set(topics()) == {"uniqueness_ratio_10", "disp12_max_diff_1", "speckle_window_100_speckle_range_2"}
    assert topics("--no-rejected") == {}
    assert set(topics("--reject-lr", "none", "--reject-speckle", "50")) == {
        "uniqueness_ratio_10", "speckle_window_50_speckle_range_2"}
    # every point of the methods' default axes: 4 uniqueness ratios, 4 lr values, 4 x 3 speckle settings
    axes = topics("--reject-axes", "--reject-uniqueness", "none", "--reject-lr", "none", "--reject-speckle", "none")
    assert len(axes) == 4 + 4 + 12 and "speckle_window_400_speckle_range_4" in axes
    bm = topics("--matcher", "bm", "--reject-texture", "10,800")
    plain = _opencv(scene, bm=True)
    assert set(bm) == {"uniqueness_ratio_10", "disp12_max_diff_1", "speckle_window_100_speckle_range_2",
                       "texture_threshold_10", "texture_threshold_800"}
    assert np.array_equal(bm["texture_threshold_800"], plain & ~_opencv(scene, bm=True, textureThreshold=800))
    assert np.array_equal(bm["uniqueness_ratio_10"], plain & ~_opencv(scene, bm=True, uniquenessRatio=10))
    assert bm["texture_threshold_800"].sum() > bm["texture_threshold_10"].sum()


@pytest.mark.parametrize(("flags", "message"), [
    (["--reject-texture", "10"], "--reject-texture: the texture threshold is StereoBM's"),
    (["--reject-speckle", "100:x"], "--reject-speckle: '100:x' is not SPECKLE_WINDOW:SPECKLE_RANGE"),
    (["--reject-lr", "1:2"], "--reject-lr: '1:2' is not DISP12_MAX_DIFF"),
    (["--reject-uniqueness", "0"], "--reject-uniqueness: StereoUniquenessParams.uniqueness_ratio must be"),
    (["--no-rejected", "--reject-lr", "1"], "--no-rejected records no post-filter: leave out --reject-lr"),
])
def test_bad_strengths_are_one_line(flags, message, scene_dir, tmp_path, capsys):
    out = tmp_path / "out.mcap"
    rc, _, err = run_cli(capsys, "record-stereo", scene_dir, "-o", out, *flags)
    lines = err.strip().splitlines()
    assert rc == 1 and len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], err
    assert not out.exists()


def _independent(frame, pred):
    """TP, FP, FN of a prediction over S = valid & not unknown, by hand."""
    valid = np.isfinite(frame.xyz).all(axis=2)
    s = valid & ~frame.masks[layout.TRUTH_UNKNOWN]
    lab = frame.masks[layout.TRUTH_OUTLIERS] & s
    p = pred & valid
    return {"tp": int((p & lab).sum()), "fp": int((p & s & ~lab).sum()), "fn": int((lab & ~p).sum())}


def test_accuracy_of_the_post_filters_equals_an_independent_scorer(log, tmp_path, capsys):
    frames = list(LogReader(log).frames())
    want = {"stereo_uniqueness": "uniqueness_ratio_10", "stereo_lr": "disp12_max_diff_1",
            "stereo_speckle": "speckle_window_100_speckle_range_2"}
    rc, out, err = run_cli(capsys, "accuracy", log, "--methods", POST + ",zcut", "--json")
    assert rc == 0, err
    assert "stereo_" not in err  # every mask is there: no warning
    rep = json.loads(out)
    for m, key in want.items():
        pooled = {"tp": 0, "fp": 0, "fn": 0}
        for f, rf in zip(frames, rep["frames"]):
            ind = _independent(f, f.masks["/stereo/rejected/" + key])
            assert {k: rf[m][k] for k in ind} == ind, m
            pooled = {k: pooled[k] + ind[k] for k in ind}
        assert {k: rep["pooled"][m][k] for k in pooled} == pooled
    assert rep["pooled"]["stereo_uniqueness"]["tp"] > 0
    # through a results file: the replay writes each method's mask, accuracy scores it without replaying
    res = tmp_path / "results.mcap"
    rc, _, err = run_cli(capsys, "replay", log, "--methods", POST + ",zcut", "--out", res)
    assert rc == 0, err
    rc, out, err = run_cli(capsys, "accuracy", res, "--json")
    assert rc == 0, err
    again = json.loads(out)
    for m in want:
        assert {k: again["pooled"][m][k] for k in ("tp", "fp", "fn")} == {k: rep["pooled"][m][k] for k in ("tp", "fp", "fn")}
    # another recorded strength, through the config: its own mask
    cfg = tmp_path / "c.toml"
    cfg.write_text("[stereo_uniqueness]\nuniqueness_ratio = 25\n[stereo_speckle]\nspeckle_window = 400\n"
                   "speckle_range = 1\n[stereo_lr]\ndisp12_max_diff = 0\n")
    rc, out, err = run_cli(capsys, "accuracy", log, "--methods", POST, "--config", cfg, "--json")
    assert rc == 0, err
    rep = json.loads(out)
    for m, key in (("stereo_uniqueness", "uniqueness_ratio_25"), ("stereo_speckle", "speckle_window_400_speckle_range_1"),
                   ("stereo_lr", "disp12_max_diff_0")):
        for f, rf in zip(frames, rep["frames"]):
            assert {k: rf[m][k] for k in ("tp", "fp", "fn")} == _independent(f, f.masks["/stereo/rejected/" + key])


def test_the_sweep_scores_each_recorded_strength(log, tmp_path, capsys):
    frames = list(LogReader(log).frames())
    rc, _, err = run_cli(capsys, "sweep", log, "-o", tmp_path / "sw", "--methods", "zcut,stereo_uniqueness,stereo_speckle",
                         "--grid", "stereo_uniqueness.uniqueness_ratio=10,25", "--grid",
                         "stereo_speckle.speckle_window=100,400", "--grid", "stereo_speckle.speckle_range=1,2",
                         "--workers", "0", "--no-report")
    assert rc == 0, err
    rows = [r for r in pq.read_table(tmp_path / "sw" / "sweep.parquet").to_pylist() if r["method"] != "zcut"]
    seen = set()
    for r in rows:
        params = json.loads(r["params"])
        key = layout.stereo_rejected_topic(dataclasses.asdict(POST_FILTERS[r["method"]](**params)))  # fields' order
        f = frames[r["frame"]]
        if key in f.masks:
            assert {k: r[k] for k in ("tp", "fp", "fn")} == _independent(f, f.masks[key]), (r["method"], params)
            seen.add(key)
        else:  # a strength the log does not hold: nothing found
            assert r["n_pred"] == 0 and r["tp"] == 0 and r["fp"] == 0
    assert len(seen) == 4  # uniqueness 10 and 25, speckle 100:2 and 400:1


def test_a_log_without_the_masks_warns_and_scores_nothing(scene_dir, tmp_path, capsys):
    p = tmp_path / "bare.mcap"
    assert run_cli(capsys, "record-stereo", scene_dir, scene_dir, scene_dir, "-o", p, "--no-rejected")[0] == 0
    rc, out, err = run_cli(capsys, "accuracy", p, "--methods", POST + ",stereo_texture,zcut", "--json")
    assert rc == 0, err
    rep = json.loads(out)
    for m in (*POST.split(","), "stereo_texture"):
        assert rep["pooled"][m]["tp"] == 0 and rep["pooled"][m]["fp"] == 0 and rep["pooled"][m]["fn"] > 0
        warned = [ln for ln in err.splitlines() if ln.startswith("warning: frame 0: " + m + ": this frame has no")]
        assert len(warned) == 1, err  # said once, not per frame
    assert "no /stereo/rejected/uniqueness_ratio_10" in err and "it holds none" in err
    rc, out, err = run_cli(capsys, "replay", p, "--methods", "zcut,stereo_lr")
    assert rc == 0 and "stereo_lr: this frame has no /stereo/rejected/disp12_max_diff_1" in out + err
