"""annotate.accuracy: the docs/accuracy.md report with a scored region, kinds, intervals and unscored frames.

Two small frames counted by hand (the z-cut, SOR, their union and intersection against the truth,
over a region that leaves one true outlier out), the exact JSON object, the text table, bad input.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from annotate.accuracy import (
    INTERVAL_NOTE,
    METHODS,
    METRIC_KEYS,
    UnscoredFrame,
    accuracy_report,
    by_kind,
    format_accuracy_table,
    frame_accuracy,
    jsonable,
    report_json,
)
from replay.logs.layout import OUTLIER_KINDS
from zcut.errors import InputShapeError, ParameterError
from zcut.metrics import KindCounts, pooled_interval

CODE = {name: code for code, name in OUTLIER_KINDS.items()}
SHAPE = (4, 6)


def _mask(pixels):
    m = np.zeros(SHAPE, bool)
    for r, c in pixels:
        m[r, c] = True
    return m


def _kinds(**pixels):
    k = np.zeros(SHAPE, np.uint8)
    for name, where in pixels.items():
        for r, c in where:
            k[r, c] = CODE[name]
    return k


# frame 0: a floating cluster A = {(0,0),(0,1)} and a flying pixel B = (3,5); the region leaves
# column 5 out, so B (and SOR's hit on it) is not scored.
T0 = _mask([(0, 0), (0, 1), (3, 5)])
K0 = _kinds(floating=[(0, 0), (0, 1)], flying=[(3, 5)])
Z0 = _mask([(0, 0), (1, 1), (2, 3)])
S0 = _mask([(0, 1), (3, 5)])
R0 = np.ones(SHAPE, bool)
R0[:, 5] = False
# frame 1: a floating cluster {(1,2),(2,2),(2,3)} and an above-the-rim point (0,5); region = all
T1 = _mask([(1, 2), (2, 2), (2, 3), (0, 5)])
K1 = _kinds(floating=[(1, 2), (2, 2), (2, 3)], above_rim=[(0, 5)])
Z1 = _mask([(1, 2), (2, 2)])
S1 = _mask([(0, 5), (3, 0)])
R1 = np.ones(SHAPE, bool)

# hand counts: frame -> method -> (tp, fp, fn)
PIXELS = {
    0: {"zcut": (1, 2, 1), "sor": (1, 0, 1), "union": (2, 2, 0), "intersection": (0, 0, 2)},
    1: {"zcut": (2, 0, 2), "sor": (1, 1, 3), "union": (3, 1, 1), "intersection": (0, 0, 4)},
}
# frame -> method -> {kind: (n, found)}; flying is held by frame 0 but outside its region (n = 0)
KIND_HAND = {
    0: {"zcut": {"floating": (2, 1), "flying": (0, 0)}, "sor": {"floating": (2, 1), "flying": (0, 0)},
        "union": {"floating": (2, 2), "flying": (0, 0)}, "intersection": {"floating": (2, 0), "flying": (0, 0)}},
    1: {"zcut": {"floating": (3, 2), "above_rim": (1, 0)}, "sor": {"floating": (3, 0), "above_rim": (1, 1)},
        "union": {"floating": (3, 2), "above_rim": (1, 1)}, "intersection": {"floating": (3, 0), "above_rim": (1, 0)}},
}


def _frames(kinds=True):
    return [
        frame_accuracy(0, 100, {"zcut": Z0, "sor": S0}, T0, region=R0, kinds=K0 if kinds else None),
        frame_accuracy(1, 200, {"zcut": Z1, "sor": S1}, T1, region=R1, kinds=K1 if kinds else None),
    ]


@pytest.fixture(scope="module")
def report():
    return accuracy_report(_frames(), region="zone", unscored=[UnscoredFrame(2, 300, "no /ground_truth/outliers")])


def test_pixels_by_hand_per_frame_and_pooled(report):
    assert report["region"] == "zone"
    for f, i in zip(report["frames"], (0, 1)):
        assert (f["index"], f["stamp_ns"]) == (i, 100 * (i + 1))
        for m in METHODS:
            assert (f[m]["tp"], f[m]["fp"], f[m]["fn"]) == PIXELS[i][m], (i, m)
    for m in METHODS:
        tp, fp, fn = (PIXELS[0][m][j] + PIXELS[1][m][j] for j in range(3))
        p = report["pooled"][m]
        assert (p["tp"], p["fp"], p["fn"]) == (tp, fp, fn)
        assert math.isnan(p["precision"]) if tp + fp == 0 else p["precision"] == tp / (tp + fp)
        assert p["recall"] == tp / (tp + fn) and p["f1"] == 2 * tp / (2 * tp + fp + fn)


def test_clusters_and_singletons_by_hand(report):
    # z-cut: frame 0 true cluster A found (1 of 2), predicted cluster {(0,0),(1,1)} correct (1 of 2),
    # predicted singleton (2,3) wrong; frame 1 true cluster found (2 of 3), true singleton (0,5)
    # missed, predicted cluster {(1,2),(2,2)} correct
    z = report["pooled"]["zcut"]
    assert (z["cluster_precision"], z["cluster_recall"], z["singletons_precision"], z["singletons_recall"]) == (
        1.0, 1.0, 0.0, 0.0)
    # SOR: predicted singletons (0,1) correct, (0,5) correct, (3,0) wrong (its (3,5) is outside frame 0's
    # region); true clusters: A found ((0,1) = 1 of 2), frame 1's cluster missed; true singleton (0,5) found
    s = report["pooled"]["sor"]
    assert math.isnan(s["cluster_precision"]) and s["cluster_recall"] == 0.5
    assert s["singletons_precision"] == 2 / 3 and s["singletons_recall"] == 1.0


def test_by_kind_by_hand(report):
    for f, i in zip(report["frames"], (0, 1)):
        for m in METHODS:
            got = {k: (v["n"], v["found"]) for k, v in f[m]["by_kind"].items()}
            assert got == KIND_HAND[i][m], (i, m)
            assert list(f[m]["by_kind"]) == [k for k in OUTLIER_KINDS.values() if k in got]  # code order
    z = report["pooled"]["zcut"]["by_kind"]
    assert list(z) == ["floating", "flying", "above_rim"]  # only the kinds the truth holds
    assert z["floating"] == {"n": 5, "found": 3, "recall": 0.6}
    assert z["flying"]["n"] == 0 and math.isnan(z["flying"]["recall"])
    assert report["pooled"]["union"]["by_kind"]["above_rim"] == {"n": 1, "found": 1, "recall": 1.0}
    # kinds count only truth pixels: they add up to tp + fn in the region
    for m in METHODS:
        p = report["pooled"][m]
        assert sum(v["n"] for v in p["by_kind"].values()) == p["tp"] + p["fn"]
        assert sum(v["found"] for v in p["by_kind"].values()) == p["tp"]


def test_no_by_kind_without_kind_truth():
    rep = accuracy_report(_frames(kinds=False), region="zone")
    assert all("by_kind" not in rep["pooled"][m] for m in METHODS)
    assert all("by_kind" not in f[m] for f in rep["frames"] for m in METHODS)
    assert "recall by kind" not in format_accuracy_table(rep)


def _four_frames():
    """The two hand-counted frames and two more made of their parts (other counts per frame)."""
    return [*_frames(),
            frame_accuracy(2, 300, {"zcut": Z0, "sor": S1}, T1, region=R1, kinds=K1),
            frame_accuracy(3, 400, {"zcut": Z1 | Z0, "sor": S0}, T0, region=R0, kinds=K0)]


def test_intervals_are_the_pooled_interval_over_frames():
    four = accuracy_report(_four_frames(), region="zone")
    held = 0
    for m in METHODS:
        tp, fp, fn = (np.array([f[m][k] for f in four["frames"]]) for k in ("tp", "fp", "fn"))
        want = pooled_interval(tp, fp, fn)
        got = four["pooled"][m]["ci95"]
        assert list(got) == ["precision", "recall", "f1"]
        for k, (lo, hi) in want.items():
            assert jsonable(got[k]) == jsonable([lo, hi]), (m, k)
            if not math.isnan(lo):
                held += 1
                assert 0 <= lo <= four["pooled"][m][k] <= hi <= 1
    assert held >= 6  # most figures vary over the four frames and get an interval
    assert report_json(accuracy_report(_four_frames(), region="zone")) == report_json(four)  # no randomness
    table = format_accuracy_table(four)
    assert f"pooled over 4 frames ({INTERVAL_NOTE})" in table
    lo, hi = four["pooled"]["zcut"]["ci95"]["recall"]
    assert f"[{lo:.3f}, {hi:.3f}]" in [ln for ln in table.splitlines() if ln.startswith("zcut ")][-1]


def test_too_few_frames_give_no_interval():
    for frames in (_frames()[:1], _frames()):
        rep = accuracy_report(frames, region="valid")
        for m in METHODS:
            p = rep["pooled"][m]
            for k in ("precision", "recall", "f1"):
                assert jsonable(p["ci95"][k]) == [None, None]
        table = format_accuracy_table(rep)
        assert "no intervals: too few frames (an interval needs 3)" in table
        pooled_zcut = [ln for ln in table.splitlines() if ln.startswith("zcut ")][-1]
        assert pooled_zcut.count("[too few frames]") == 3, pooled_zcut
    empty = json.loads(report_json(accuracy_report([], region="zone")))
    assert empty["frames"] == [] and empty["pooled"]["zcut"]["ci95"]["recall"] == [None, None]
    assert empty["pooled"]["zcut"]["tp"] == 0 and "by_kind" not in empty["pooled"]["zcut"]


def _check_entry(e, *, pooled):
    keys = [*METRIC_KEYS, *(["ci95"] if pooled else []), "by_kind", "by_size",
            *(["frames_scored", "frames_left_out", "left_out_reason"] if pooled else [])]
    assert list(e) == keys
    if pooled:
        assert type(e["frames_scored"]) is int and all(type(i) is int for i in e["frames_left_out"])
        assert (e["left_out_reason"] is None) == (e["frames_left_out"] == [])
    for k in ("tp", "fp", "fn"):
        assert type(e[k]) is int
    for k in METRIC_KEYS[3:]:
        assert e[k] is None or type(e[k]) is float
    if pooled:
        assert list(e["ci95"]) == ["precision", "recall", "f1"]
        for lo_hi in e["ci95"].values():
            assert len(lo_hi) == 2 and all(v is None or type(v) is float for v in lo_hi)
    for v in e["by_kind"].values():
        assert list(v) == ["n", "found", "recall"]
        assert type(v["n"]) is int and type(v["found"]) is int and (v["recall"] is None or type(v["recall"]) is float)


def test_json_follows_spec_section_4(report):
    text = report_json(report)
    assert "NaN" not in text and "Infinity" not in text
    back = json.loads(text)
    assert list(back) == ["region", "pooled", "frames", "unscored", "bin_flagged"]
    assert back["region"] == "zone"
    assert list(back["pooled"]) == list(METHODS)
    for m in METHODS:
        _check_entry(back["pooled"][m], pooled=True)
    for f in back["frames"]:
        assert list(f) == ["index", "stamp_ns", *METHODS, "bin_check", "bin_flagged"]
        for m in METHODS:
            _check_entry(f[m], pooled=False)
    assert back["unscored"] == [{"index": 2, "stamp_ns": 300, "reason": "no /ground_truth/outliers"}]
    assert back["pooled"]["intersection"]["precision"] is None  # 0/0
    assert back["pooled"]["intersection"]["ci95"]["precision"] == [None, None]
    assert back["pooled"]["zcut"]["by_kind"]["flying"] == {"n": 0, "found": 0, "recall": None}


def test_table(report):
    table = format_accuracy_table(report)
    lines = table.splitlines()
    assert lines[0].startswith("region: zone (the pixels the filters judge")
    assert "pooled over 2 frames (no intervals: too few frames (an interval needs 3))" in table
    pooled_zcut = [ln for ln in lines if ln.startswith("zcut ")][-1]
    assert pooled_zcut.split()[1:4] == ["3", "2", "3"]
    assert "0.600 [too few frames]" in pooled_zcut
    assert [ln.split()[0] for ln in lines if ln.startswith(("0 ", "1 "))] == ["0"] * 4 + ["1"] * 4  # per frame
    singles = next(ln for ln in lines if ln.startswith("singleton precision"))
    assert singles.split()[-4:] == ["0.000", "0.667", "0.333", "-"]  # z-cut, SOR, union, intersection
    kinds = {ln.split()[0]: ln.split()[1:] for ln in table.split("recall by kind")[1].splitlines()[2:5]}
    assert kinds["floating"][:3] == ["5", "0.600", "(3)"]
    assert kinds["flying"][:3] == ["0", "-", "(0)"]
    assert kinds["above_rim"][:3] == ["1", "0.000", "(0)"]
    assert "unscored: 1 frame\n  frame 2 (stamp_ns 300): no /ground_truth/outliers" in table
    # a method name starts a line only in the pooled pixel table (per-frame rows start with the index)
    for per_frame in (True, False):
        t = format_accuracy_table(report, per_frame=per_frame)
        assert [ln.split()[0] for ln in t.splitlines() if ln.split() and ln.split()[0] in METHODS] == list(METHODS)
    # the table of the parsed-back JSON (null rates) is the same text
    assert format_accuracy_table(json.loads(report_json(report))) == table
    assert "per frame" not in format_accuracy_table(report, per_frame=False)


def test_table_fits_120_columns_with_realistic_numbers(report):
    """Counts of a 1920 x 1200 frame (7 digits) and ROS stamps (19 digits) keep every line <= 120."""
    big = json.loads(report_json(report))
    for e in [*(big["pooled"][m] for m in METHODS), *(f[m] for f in big["frames"] for m in METHODS)]:
        e.update(tp=1_234_567, fp=2_234_567, fn=1_999_999)
        for v in e["by_kind"].values():
            v.update(n=2_304_000, found=1_234_567)
    for f in big["frames"]:
        f["stamp_ns"] = 1_712_345_678_901_234_567
    table = format_accuracy_table(big)  # two frames: "too few frames" in place of every interval
    assert "[too few frames]" in table and max(len(ln) for ln in table.splitlines()) <= 120, table
    for m in METHODS:
        big["pooled"][m]["ci95"] = {k: [0.123, 0.987] for k in ("precision", "recall", "f1")}
    table = format_accuracy_table(big)
    assert max(len(ln) for ln in table.splitlines()) <= 120, table


def test_by_kind_needs_the_truth_kinds():
    with pytest.raises(ParameterError, match=r"kinds must count the 8 kind codes of the truth, got 2"):
        by_kind(KindCounts((1, 0), (1, 0), (0, 0)))


ONE = [frame_accuracy(0, 0, {"zcut": Z0, "sor": S0}, T0)]


@pytest.mark.parametrize(
    ("call", "exc", "match"),
    [
        (lambda: accuracy_report(ONE, region="table"), ParameterError,
         r"region must be one of zone, valid, got 'table'"),
        (lambda: accuracy_report(ONE, region=None), ParameterError, r"region must be one of zone, valid, got None"),
        (lambda: accuracy_report(ONE, unscored=[(1, 2, "x")]), ParameterError,
         r"unscored must hold UnscoredFrame entries, got tuple"),
        (lambda: accuracy_report(ONE, unscored=[UnscoredFrame(0, 0, "no truth")]), ParameterError,
         r"frame\(s\) \[0\] are listed both as scored and as unscored"),
        (lambda: accuracy_report([*ONE, _frames()[1]]), ParameterError,
         r"kind truth is given for 1 of 2 frames: give it for every scored frame or for none"),
        (lambda: UnscoredFrame(0, 0, ""), ParameterError, r"UnscoredFrame.reason must be a non-empty line"),
        (lambda: UnscoredFrame(0, 0, "a\nb"), ParameterError, r"UnscoredFrame.reason must be a non-empty line"),
        (lambda: UnscoredFrame(0.5, 0, "x"), ParameterError, r"UnscoredFrame.index must be an integer, got 0.5"),
        (lambda: frame_accuracy(0, 0, {"zcut": Z0, "sor": S0}, T0, region=R0[:, :5]), InputShapeError,
         r"region must have shape \(4, 6\)"),
        (lambda: frame_accuracy(0, 0, {"zcut": Z0, "sor": S0}, T0, kinds=K0[:3]), InputShapeError,
         r"kinds must be an \(H, W\) uint8 array of shape \(4, 6\) like the outliers, got shape \(3, 6\) uint8"),
        (lambda: frame_accuracy(0, 0, {"zcut": Z0, "sor": S0}, T0, kinds=K0.astype(np.int32)), InputShapeError,
         r"kinds must be an \(H, W\) uint8 array"),
        (lambda: frame_accuracy(0, 0, {"zcut": Z0, "sor": S0}, T0, kinds=np.where(T0, 9, 0).astype(np.uint8)),
         ParameterError, r"kinds holds code\(s\) \[9\] outside 0..8 at 3 pixel\(s\)"),
        (lambda: frame_accuracy(0, 0, {"zcut": Z0, "sor": S0}, T0, kinds=K1), ParameterError,
         r"kinds must be nonzero exactly where outliers is set: 4 pixel\(s\) have a kind but are not outliers"),
        (lambda: frame_accuracy(0, 0, {"zcut": Z0, "sor": S0}, T0 | T1, kinds=K0), ParameterError,
         r"kinds must be nonzero exactly where outliers is set: 4 outlier pixel\(s\) have kind 0"),
        (lambda: frame_accuracy(0, 0, {"zcut": Z0, "sor": S0}, T0, reviewed=R0), ParameterError,
         r"outliers must lie inside reviewed: 1 labelled pixel\(s\) are not reviewed"),
        (lambda: frame_accuracy(0, 0, {"zcut": Z0, "sor": S0}, T0, valid=R0), ParameterError,
         r"outliers must lie inside reviewed"),
    ],
)
def test_bad_input(call, exc, match):
    with pytest.raises(exc, match=match):
        call()


def test_a_method_left_out_of_some_frames_says_how_many_and_which():
    """``learned`` is not scored on the frames its model was trained on: its pooled entry says how many
    frames it scored, which it left out and why; the other methods scored every frame."""
    frames = [frame_accuracy(i, 100 * i, {"zcut": Z0, "sor": S0}, T0, region=R0) for i in range(4)]
    for i, f in enumerate(frames):  # learned: counted on frames 2 and 3 only
        f.counts.update(frame_accuracy(i, 100 * i, {"learned": Z0}, T0, region=R0 & (i >= 2)).counts)
    reason = "the assistant's model was trained on these frames"
    rep = json.loads(report_json(accuracy_report(frames, region="zone", left_out={"learned": ({1, 0}, reason)})))
    lp = rep["pooled"]["learned"]
    assert (lp["frames_scored"], lp["frames_left_out"], lp["left_out_reason"]) == (2, [0, 1], reason)
    assert (lp["tp"], lp["fp"], lp["fn"]) == tuple(2 * v for v in PIXELS[0]["zcut"])
    for m in METHODS:
        assert (rep["pooled"][m]["frames_scored"], rep["pooled"][m]["frames_left_out"]) == (4, [])
        assert rep["pooled"][m]["left_out_reason"] is None
    assert [(f["learned"]["tp"], f["learned"]["fp"], f["learned"]["fn"]) for f in rep["frames"][:2]] == [(0, 0, 0)] * 2
    assert all("frames_scored" not in f["learned"] for f in rep["frames"])  # the pooled entry says it
    # nothing left out: the same report as without the argument
    assert report_json(accuracy_report(frames, region="zone", left_out={"learned": ((), reason)})) == \
        report_json(accuracy_report(frames, region="zone"))
    with pytest.raises(ParameterError, match="'nope', which the frames do not score"):
        accuracy_report(frames, region="zone", left_out={"nope": ([0], reason)})
    with pytest.raises(ParameterError, match="frame 7 is not a scored frame"):
        accuracy_report(frames, region="zone", left_out={"learned": ([7], reason)})
    with pytest.raises(ParameterError, match="frame 2 has counts for learned"):
        accuracy_report(frames, region="zone", left_out={"learned": ([2], reason)})
    with pytest.raises(ParameterError, match="reason must be a non-empty line"):
        accuracy_report(frames, region="zone", left_out={"learned": ([0], " ")})
