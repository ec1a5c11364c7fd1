"""annotate.accuracy: the docs/accuracy.md report on a frame counted by hand."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from annotate.accuracy import (
    METHODS,
    METRIC_KEYS,
    accuracy_report,
    agreement_counts,
    format_accuracy_table,
    frame_accuracy,
    jsonable,
    method_masks,
    report_json,
)
from zcut.errors import InputShapeError, ParameterError


def _mask(shape, pixels):
    m = np.zeros(shape, bool)
    for r, c in pixels:
        m[r, c] = True
    return m


SHAPE = (4, 6)
# Truth: cluster A = {(0,0),(0,1)}, cluster B = {(3,5)}.
TRUTH = _mask(SHAPE, [(0, 0), (0, 1), (3, 5)])
# z-cut: {(0,0),(1,1)} (one 8-connected cluster, half in A) and {(2,3)} (false).
ZCUT = _mask(SHAPE, [(0, 0), (1, 1), (2, 3)])
# SOR: {(0,1)} and {(3,5)}, both true.
SOR = _mask(SHAPE, [(0, 1), (3, 5)])

# Hand counts: method -> (tp, fp, fn, precision, recall, iou, cluster_precision, cluster_recall,
#                         singletons_precision, singletons_recall)
# Clusters are components of >= 2 pixels, singletons the one-pixel ones (docs/accuracy.md): true cluster A,
# true singleton B; z-cut: cluster {(0,0),(1,1)} (half in A: correct), singleton (2,3) (wrong);
# SOR: singletons (0,1), (3,5) (both correct); union: cluster {(0,0),(0,1),(1,1)}, singletons (2,3), (3,5).
HAND = {
    "zcut": (1, 2, 2, 1 / 3, 1 / 3, 1 / 5, 1.0, 1.0, 0.0, 0.0),
    "sor": (2, 0, 1, 1.0, 2 / 3, 2 / 3, math.nan, 1.0, 1.0, 1.0),
    "union": (3, 2, 0, 3 / 5, 1.0, 3 / 5, 1.0, 1.0, 1 / 2, 1.0),
    "intersection": (0, 0, 3, math.nan, 0.0, 0.0, math.nan, 0.0, math.nan, 0.0),
}

#: method -> pixels found of the truth's components of 2-9 px (A) and of 1 px (B)
HAND_BY_SIZE = {"zcut": (1, 0), "sor": (1, 1), "union": (2, 1), "intersection": (0, 0)}


def _close(a, b):
    return (math.isnan(a) and math.isnan(b)) or a == pytest.approx(b)


def test_report_matches_hand_count():
    f = frame_accuracy(7, 123_000, {"zcut": ZCUT, "sor": SOR}, TRUTH)
    report = accuracy_report([f])
    assert list(report) == ["region", "pooled", "frames", "unscored", "bin_flagged"]
    assert report["region"] == "valid" and report["unscored"] == []
    assert report["bin_flagged"] is None  # the bin check is not known for this frame
    assert set(report["pooled"]) == set(METHODS)
    (fr,) = report["frames"]
    assert fr["index"] == 7 and fr["stamp_ns"] == 123_000
    assert fr["bin_check"] is None and fr["bin_flagged"] is None
    for m, (tp, fp, fn, p, r, iou, cp, cr, sp, sr) in HAND.items():
        e = fr[m]
        assert list(e) == [*METRIC_KEYS, "by_size"]
        # by size of the truth's components: A (2 px) is in 2-9, B (1 px) in 1
        found_2_9, found_1 = HAND_BY_SIZE[m]
        assert e["by_size"] == {"1px": {"n": 1, "found": found_1, "recall": float(found_1)},
                                "2-9px": {"n": 2, "found": found_2_9, "recall": found_2_9 / 2},
                                "10-99px": {"n": 0, "found": 0, "recall": e["by_size"]["10-99px"]["recall"]},
                                ">=100px": {"n": 0, "found": 0, "recall": e["by_size"][">=100px"]["recall"]}}
        assert math.isnan(e["by_size"]["10-99px"]["recall"]) and math.isnan(e["by_size"][">=100px"]["recall"])
        assert (e["tp"], e["fp"], e["fn"]) == (tp, fp, fn), m
        assert all(type(e[k]) is int for k in ("tp", "fp", "fn"))
        keys = ("precision", "recall", "iou", "cluster_precision", "cluster_recall", "singletons_precision",
                "singletons_recall")
        for k, v in zip(keys, (p, r, iou, cp, cr, sp, sr)):
            assert _close(e[k], v), (m, k, e[k], v)
        pooled = dict(report["pooled"][m])
        ci = pooled.pop("ci95")
        assert (pooled.pop("frames_scored"), pooled.pop("frames_left_out"), pooled.pop("left_out_reason")) == (1, [], None)
        assert jsonable(e) == jsonable(pooled)  # one frame: pooled = per frame
        for k in ("precision", "recall", "f1"):  # and one frame gets no interval (too few frames)
            assert jsonable(ci[k]) == [None, None]


def test_reviewed_restricts_counts():
    reviewed = np.ones(SHAPE, bool)
    reviewed[2, 3] = False  # the false z-cut cluster was not reviewed
    f = frame_accuracy(0, 0, {"zcut": ZCUT, "sor": SOR}, TRUTH, reviewed=reviewed)
    assert (f.counts["zcut"].tp, f.counts["zcut"].fp, f.counts["zcut"].fn) == (1, 1, 2)
    assert f.counts["zcut"].cluster_precision == pytest.approx(1.0)


def test_pooled_sums_counts_over_frames():
    f1 = frame_accuracy(0, 10, {"zcut": ZCUT, "sor": SOR}, TRUTH)
    f2 = frame_accuracy(1, 20, {"zcut": np.zeros(SHAPE, bool), "sor": TRUTH.copy()}, TRUTH)
    report = accuracy_report([f1, f2])
    assert report["pooled"]["zcut"]["tp"] == 1
    assert report["pooled"]["zcut"]["fn"] == 2 + 3
    assert report["pooled"]["sor"]["tp"] == 2 + 3
    assert report["pooled"]["sor"]["recall"] == pytest.approx(5 / 6)
    assert [f["index"] for f in report["frames"]] == [0, 1]


def test_empty_report_has_zero_counts():
    report = accuracy_report([])
    assert report["frames"] == []
    assert all(report["pooled"][m]["tp"] == 0 for m in METHODS)


def test_json_has_null_for_undefined_rates_and_int_counts():
    report = accuracy_report([frame_accuracy(0, 5, {"zcut": ZCUT, "sor": SOR}, TRUTH)])
    text = report_json(report)
    assert "NaN" not in text and "Infinity" not in text
    back = json.loads(text)
    assert back["pooled"]["intersection"]["precision"] is None
    assert back["pooled"]["intersection"]["fn"] == 3
    assert isinstance(back["frames"][0]["zcut"]["tp"], int)
    assert jsonable({"a": [float("inf"), np.float32(0.5), np.int64(3)]}) == {"a": [None, 0.5, 3]}


def test_table_lists_every_method():
    report = accuracy_report([frame_accuracy(3, 5, {"zcut": ZCUT, "sor": SOR}, TRUTH)])
    table = format_accuracy_table(report)
    for m in METHODS:
        assert m in table
    assert "pooled over 1 frame" in table
    pooled_line = [ln for ln in table.splitlines() if ln.startswith("sor ")][-1]
    assert pooled_line.split()[1:4] == ["2", "0", "1"]
    # parsed-back JSON (None rates) formats too
    assert "-" in format_accuracy_table(json.loads(report_json(report)), per_frame=False)


def test_method_masks_union_intersection():
    mm = method_masks(ZCUT, SOR)
    assert np.array_equal(mm["union"], ZCUT | SOR)
    assert not mm["intersection"].any()


@pytest.mark.parametrize(
    ("preds", "truth", "exc", "match"),
    [
        ({}, TRUTH, ParameterError, "at least one method"),
        ({"zcut": ZCUT, "sor": SOR[:2]}, TRUTH, InputShapeError, "sor"),
        ({"zcut": ZCUT.astype(np.uint8), "sor": SOR}, TRUTH, InputShapeError, "zcut"),
        ({"zcut": ZCUT, "sor": SOR}, TRUTH[None], InputShapeError, "outliers"),
    ],
)
def test_bad_input(preds, truth, exc, match):
    with pytest.raises(exc, match=match):
        frame_accuracy(0, 0, preds, truth)


# ---------------------------------------------------------------- laws (hypothesis)
_masks = st.integers(1, 12).flatmap(
    lambda h: st.integers(1, 12).flatmap(
        lambda w: st.tuples(*[arrays(np.bool_, (h, w)) for _ in range(4)])))


@settings(max_examples=60, deadline=None)
@given(_masks)
def test_union_and_intersection_laws(ms):
    z, s, truth, reviewed = ms
    truth = truth & reviewed
    c = frame_accuracy(0, 0, {"zcut": z, "sor": s}, truth, reviewed=reviewed).counts
    assert c["union"].tp == c["zcut"].tp + c["sor"].tp - c["intersection"].tp
    assert c["union"].fp == c["zcut"].fp + c["sor"].fp - c["intersection"].fp
    assert c["intersection"].tp <= min(c["zcut"].tp, c["sor"].tp)
    for m in METHODS:  # every true outlier is either found or missed
        assert c[m].tp + c[m].fn == int(truth.sum())


@settings(max_examples=60, deadline=None)
@given(_masks)
def test_agreement_is_symmetric_and_perfect_with_itself(ms):
    a, b, ra, rb = ms
    a, b = a & ra, b & rb
    ab, ba = agreement_counts(a, ra, b, rb), agreement_counts(b, rb, a, ra)
    assert (ab.both, ab.only_a, ab.only_b, ab.neither) == (ba.both, ba.only_b, ba.only_a, ba.neither)
    same = agreement_counts(a, ra, a, ra)
    assert same.only_a == same.only_b == 0
    assert math.isnan(same.kappa) or same.kappa == pytest.approx(1.0)
