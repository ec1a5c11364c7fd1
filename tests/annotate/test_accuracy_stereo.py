"""Truth that cannot be judged (``/ground_truth/unknown``), recall by size and on the detectable subset,
and a ground-truth mask of the wrong size, through ``zcut accuracy``, ``zcut batch`` and ``zcut replay``."""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import pytest
from annotate_helpers import spike_frame
from cli_helpers import run_cli
from scipy import ndimage
from stereo_helpers import independent_truth, motorcycle, write_scene

from replay.logs import layout
from replay.logs.frame import Frame
from replay.logs.reader import LogReader
from replay.logs.writer import LogWriter
from replay.synth.truth_depth import read_truth_depth

METHODS = ("zcut", "sor", "union", "intersection")


def _masks(results):
    """Per frame: method -> prediction, from a results file of `zcut replay --out`."""
    out = []
    for f in LogReader(results, cloudless=True).frames():
        z, s = f.masks[layout.ZCUT_OUTLIERS], f.masks[layout.SOR_OUTLIERS]
        out.append({"zcut": z, "sor": s, "union": z | s, "intersection": z & s})
    return out


def _score(p, lab, s):
    """TP, FP, FN over S, by hand."""
    return {"tp": int((p & lab & s).sum()), "fp": int((p & s & ~lab).sum()), "fn": int((lab & s & ~p).sum())}


def _by_size(p, lab):
    """n and found per size class of the 8-connected components of L (already inside S)."""
    comp, n = ndimage.label(lab, structure=np.ones((3, 3)))
    size = np.bincount(comp.ravel())
    px = size[comp]
    out = {}
    for name, lo, hi in (("1px", 1, 1), ("2-9px", 2, 9), ("10-99px", 10, 99), (">=100px", 100, 10**9)):
        cls = lab & (px >= lo) & (px <= hi)
        out[name] = (int(cls.sum()), int((cls & p).sum()))
    return out


@pytest.fixture(scope="module")
def stereo_log(tmp_path_factory):
    d = tmp_path_factory.mktemp("stereo_acc")
    sc = motorcycle(4)
    scene = write_scene(d / "Motorcycle", sc)
    log = d / "moto.mcap"
    from cli.main import main

    # three frames (one scene three times: an interval needs three)
    assert main(["record-stereo", str(scene), str(scene), str(scene), "-o", str(log)]) == 0
    results = d / "results.mcap"
    assert main(["replay", str(log), "--out", str(results)]) == 0
    return log, results, sc


def test_accuracy_on_a_stereo_log_equals_an_independent_scorer(stereo_log, capsys):
    log, results, sc = stereo_log
    rc, out, err = run_cli(capsys, "accuracy", log, "--region", "valid", "--json", "--by-displacement")
    assert rc == 0, err
    rep = json.loads(out)
    # a stereo log's real truth is its /ground_truth/outliers: the paper's truth is not there, and the report says so
    assert rep["truth"] == "the sensor's truth /ground_truth/outliers (the log has no /ground_truth/off_surface)"
    rc, _, err = run_cli(capsys, "accuracy", log, "--truth", "paper")
    assert rc == 1 and err.strip() == (f"error: {log} has no /ground_truth/off_surface (--truth paper): "
                                       "score it with --truth sensor"), err
    frames = list(LogReader(log).frames())
    preds = _masks(results)
    pooled = {m: {"tp": 0, "fp": 0, "fn": 0} for m in METHODS}
    for fr, rf, p in zip(frames, rep["frames"], preds):
        valid = np.isfinite(fr.xyz).all(axis=2)
        ind = independent_truth(fr.xyz[..., 2], sc["gt"], sc["mask"], sc["calib"])
        s = valid & ~ind["unknown"]  # S: the unknown pixels are not scored, for every method
        lab = ind["outliers"] & s
        assert ind["unknown"][valid].any() and lab.any()
        for m in METHODS:
            want = _score(p[m], lab, s)
            assert {k: rf[m][k] for k in ("tp", "fp", "fn")} == want, m
            for k in want:
                pooled[m][k] += want[k]
            assert {c: (e["n"], e["found"]) for c, e in rf[m]["by_size"].items()} == _by_size(p[m], lab)
            det = ind["detectable"] & s
            assert (rf[m]["detectable"]["n"], rf[m]["detectable"]["found"]) == (int(det.sum()), int((det & p[m]).sum()))
    for m in METHODS:
        assert {k: rep["pooled"][m][k] for k in ("tp", "fp", "fn")} == pooled[m]
        assert set(rep["pooled"][m]["by_size"]) == {"1px", "2-9px", "10-99px", ">=100px"}
    # by displacement |Z - Z_GT| (mm) from the log's true depth
    depth = read_truth_depth(log)
    for fr, rf, p in zip(frames, rep["frames"], preds):
        ind = independent_truth(fr.xyz[..., 2], sc["gt"], sc["mask"], sc["calib"])
        lab = ind["outliers"] & np.isfinite(fr.xyz).all(axis=2) & ~ind["unknown"]
        dz = np.abs(fr.xyz[..., 2].astype(np.float64) - depth[fr.stamp_ns]) * 1000.0
        for m in METHODS:
            want = {}
            for name, lo, hi in (("<=1mm", -1.0, 1.0), ("1-5mm", 1.0, 5.0), ("5-30mm", 5.0, 30.0), (">30mm", 30.0, np.inf)):
                cls = lab & (dz > lo) & (dz <= hi)
                want[name] = (int(cls.sum()), int((cls & p[m]).sum()))
            assert {c: (e["n"], e["found"]) for c, e in rf[m]["by_displacement"].items()} == want
    assert sum(e["n"] for e in rep["pooled"]["zcut"]["by_displacement"].values()) == pooled["zcut"]["tp"] + pooled["zcut"]["fn"]
    rc, text, err = run_cli(capsys, "accuracy", log, "--region", "valid")
    assert rc == 0, err
    assert "by_displacement" not in json.dumps(json.loads(run_cli(capsys, "accuracy", log, "--json")[1]))
    rc, _, err = run_cli(capsys, "accuracy", results, "--by-displacement")
    assert rc == 1 and err.strip().splitlines()[-1].startswith("error: --by-displacement needs a log"), err
    assert "recall by size of the truth's 8-connected components" in text and "\ndetectable " in text


@pytest.fixture(scope="module")
def unknown_log(tmp_path_factory):
    """Spike frames whose right third is unknown truth (two spikes and floor inside it)."""
    d = tmp_path_factory.mktemp("unknown")
    log = d / "spikes.mcap"
    truths, unknowns = [], []
    with LogWriter(log) as w:
        for i in range(3):
            fr, t = spike_frame(i)
            unk = np.zeros(fr.shape, bool)
            unk[:, 100:] = True
            w.write_frame(Frame(xyz=fr.xyz, rgb=fr.rgb, stamp_ns=fr.stamp_ns, frame_id=fr.frame_id,
                                intrinsics=fr.intrinsics, topic=fr.topic, index=i,
                                masks={**fr.masks, layout.TRUTH_UNKNOWN: unk}))
            truths.append(t)
            unknowns.append(unk)
    return log, truths, unknowns


def test_unknown_truth_is_not_scored_by_accuracy_or_batch(unknown_log, tmp_path, capsys):
    log, truths, unknowns = unknown_log
    results = tmp_path / "r.mcap"
    assert run_cli(capsys, "replay", log, "--out", results)[0] == 0
    preds = _masks(results)
    rc, out, err = run_cli(capsys, "accuracy", log, "--region", "valid", "--json")
    assert rc == 0, err
    rep = json.loads(out)
    frames = list(LogReader(log).frames())
    rows = {}
    for fr, rf, p, t, unk in zip(frames, rep["frames"], preds, truths, unknowns):
        s = np.isfinite(fr.xyz).all(axis=2) & ~unk
        assert (t & unk).any() and (p["union"] & unk).any()  # the unknown part holds outliers and predictions
        for m in METHODS:
            assert {k: rf[m][k] for k in ("tp", "fp", "fn")} == _score(p[m], t & s, s), m
        rows[fr.index] = _score(p["zcut"], t & s, s)
    # batch scores the same pixels (region valid as well)
    out_dir = tmp_path / "batch"
    rc, _, err = run_cli(capsys, "batch", log, "-o", out_dir, "--workers", "1", "--region", "valid")
    assert rc == 0, err
    for r in pq.read_table(out_dir / "frames.parquet").to_pylist():
        assert {"tp": r["zcut_tp"], "fp": r["zcut_fp"], "fn": r["zcut_fn"]} == rows[r["frame"]]


def test_a_truth_mask_of_the_wrong_size_is_wrong_size_damage(tmp_path, capsys):
    """Issue 35 item 2: a 60x80 /ground_truth/outliers with a 120x160 cloud (frame 0) passed replay and
    batch silently and made accuracy say the topic was missing."""
    log = tmp_path / "bad.mcap"
    with LogWriter(log) as w:
        for i in range(3):
            fr, t = spike_frame(i)
            if i == 0:
                w.write_cloud(layout.CLOUD, fr.xyz, rgb=fr.rgb, stamp_ns=fr.stamp_ns, frame_id=fr.frame_id)
                w.write_mask(layout.TRUTH_OUTLIERS, t[::2, ::2].copy(), stamp_ns=fr.stamp_ns, frame_id=fr.frame_id)
            else:
                w.write_frame(fr)
    for argv in (("accuracy", log), ("replay", log), ("batch", log, "-o", tmp_path / "b", "--workers", "1")):
        rc, _, err = run_cli(capsys, *argv)
        assert rc == 3, (argv[0], err)
        assert "Traceback" not in err
        warn = [ln for ln in err.splitlines() if "frame 0" in ln and "skipped" in ln]
        assert warn and "/ground_truth/outliers" in warn[0] and "mask is 60x80 but its cloud is 120x160" in warn[0], err
