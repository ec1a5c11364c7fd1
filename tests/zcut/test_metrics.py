"""zcut.metrics: hand-computed relative metrics (SPEC §3), true accuracy (SPEC §4), agreement."""

from __future__ import annotations

import math

import numpy as np
import pytest

from zcut import InputShapeError, ParameterError
from zcut.metrics import (
    ACCURACY_KEYS,
    AccuracyCounts,
    RelativeMetrics,
    Sensitivity,
    accuracy_counts,
    cohen_kappa,
    mask_iou,
    ratio,
    relative_metrics,
    sensitivity,
    sensitivity_of,
)


def draw(*rows: str) -> np.ndarray:
    """A bool mask from rows of '.' (False) and 'X' (True)."""
    return np.array([[ch == "X" for ch in row] for row in rows], dtype=bool)


def same(a: float, b: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or a == b


# ------------------------------------------------------------------------------------------------
# ratio
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("num", "den", "want"),
    [(3, 4, 0.75), (0, 5, 0.0), (1, 0, math.inf), (7, 0, math.inf), (-2, 0, -math.inf), (0, 0, math.nan),
     (1.5, 0.5, 3.0), (0.0, 0.0, math.nan)],
)
def test_ratio(num: float, den: float, want: float) -> None:
    got = ratio(num, den)
    assert isinstance(got, float) and same(got, want)


# ------------------------------------------------------------------------------------------------
# SPEC §3
# ------------------------------------------------------------------------------------------------
def test_relative_metrics_by_hand() -> None:
    sor = draw(
        "XX..",
        ".X..",
        "...X",
    )
    zcut = draw(
        "X...",
        ".XXX",
        "XX..",
    )
    # both: (0,0) (1,1); SOR only: (0,1) (2,3); z-cut only: (1,2) (1,3) (2,0) (2,1)
    got = relative_metrics(sor, zcut)
    assert got == RelativeMetrics(n_both=2, n1=2, n2=4, alpha=0.5, beta1=1.0, beta2=0.5)
    assert all(type(v) is int for v in (got.n_both, got.n1, got.n2))


@pytest.mark.parametrize(
    ("sor", "zcut", "counts", "alpha", "beta1", "beta2"),
    [
        # identical masks: N1 = N2 = 0, N_both = 3 -> α = 0/0, β = 3/0
        (draw("XX.", "..X"), draw("XX.", "..X"), (3, 0, 0), math.nan, math.inf, math.inf),
        # SOR found nothing: α = 0/2 = 0, β1 = 0/0, β2 = 0/2
        (draw("...", "..."), draw("X..", "..X"), (0, 0, 2), 0.0, math.nan, 0.0),
        # z-cut found nothing: α = 1/0, β1 = 0/1, β2 = 0/0
        (draw(".X.", "..."), draw("...", "..."), (0, 1, 0), math.inf, 0.0, math.nan),
        # nothing at all
        (draw("...", "..."), draw("...", "..."), (0, 0, 0), math.nan, math.nan, math.nan),
    ],
)
def test_relative_metrics_divisions_by_zero(
    sor: np.ndarray, zcut: np.ndarray, counts: tuple[int, int, int], alpha: float, beta1: float, beta2: float
) -> None:
    got = relative_metrics(sor, zcut)
    assert (got.n_both, got.n1, got.n2) == counts
    assert same(got.alpha, alpha) and same(got.beta1, beta1) and same(got.beta2, beta2)


def test_sensitivity_by_hand() -> None:
    assert sensitivity(6, 4, 3) == Sensitivity(lo=1.5, hi=0.75)
    s = sensitivity(2, 0, 0)  # nominal count 0: 2/0 = inf, 0/0 = NaN
    assert s.lo == math.inf and math.isnan(s.hi)
    assert sensitivity(0, 5, 10) == Sensitivity(lo=0.0, hi=2.0)


def test_sensitivity_of_relative_metrics() -> None:
    # θ_n from three z-cut runs at 0.5, 1, 1.5 ρ*: N1 = 10, 8, 4 and N2 = 30, 40, 50
    lo = RelativeMetrics.from_counts(5, 10, 30)
    nominal = RelativeMetrics.from_counts(7, 8, 40)
    hi = RelativeMetrics.from_counts(9, 4, 50)
    theta1, theta2 = sensitivity_of(lo, nominal, hi)
    assert theta1 == Sensitivity(lo=1.25, hi=0.5)
    assert theta2 == Sensitivity(lo=0.75, hi=1.25)


def test_from_counts_matches_definitions() -> None:
    got = RelativeMetrics.from_counts(3, 6, 12)
    assert (got.alpha, got.beta1, got.beta2) == (0.5, 0.5, 0.25)


# ------------------------------------------------------------------------------------------------
# SPEC §4
# ------------------------------------------------------------------------------------------------
LABELS = draw(
    ".XX.....",
    ".X.....X",
    "........",
    "...X....",
    "....X...",
    "........",
)
PREDICTED = draw(
    ".X......",
    ".X....X.",
    "........",
    "...X....",
    "........",
    "XX......",
)


def test_accuracy_by_hand() -> None:
    # true clusters (8-connected): A = {(0,1),(0,2),(1,1)}, B = {(1,7)}, C = {(3,3),(4,4)}
    #   A: 2/3 predicted -> found; B: 0/1 -> missed; C: 1/2 = 50 % -> found
    # predicted clusters: {(0,1),(1,1)} all true -> correct; {(1,6)} -> wrong; {(3,3)} -> correct;
    #   {(5,0),(5,1)} -> wrong
    got = accuracy_counts(PREDICTED, LABELS)
    assert got == AccuracyCounts(
        tp=3, fp=3, fn=3, true_clusters=3, true_clusters_found=2, pred_clusters=4, pred_clusters_correct=2
    )
    assert got.precision == 0.5 and got.recall == 0.5 and got.f1 == 0.5
    assert got.iou == pytest.approx(1 / 3, abs=0, rel=1e-15)
    assert got.cluster_precision == 0.5 and got.cluster_recall == pytest.approx(2 / 3, abs=0, rel=1e-15)


def test_accuracy_over_reviewed_pixels_only() -> None:
    labels = LABELS.copy()
    labels[4, 4] = False  # rows 4 and 5 are not reviewed, so they carry no label
    reviewed = np.zeros_like(labels)
    reviewed[:4] = True
    # P ∩ R = {(0,1),(1,1),(1,6),(3,3)}: TP 3, FP 1 ((1,6)); FN = (0,2),(1,7)
    got = accuracy_counts(PREDICTED, labels, reviewed=reviewed)
    assert got == AccuracyCounts(
        tp=3, fp=1, fn=2, true_clusters=3, true_clusters_found=2, pred_clusters=3, pred_clusters_correct=2
    )
    assert got.precision == 0.75 and got.recall == 0.6 and got.iou == 0.5
    assert got.f1 == pytest.approx(2 / 3, abs=0, rel=1e-15)


def test_reviewed_defaults_to_valid() -> None:
    labels = LABELS.copy()
    labels[4, 4] = False
    valid = np.zeros_like(labels)
    valid[:4] = True
    assert accuracy_counts(PREDICTED, labels, valid=valid) == accuracy_counts(PREDICTED, labels, reviewed=valid)


def test_cluster_half_rule_counts_exactly_fifty_percent() -> None:
    labels = draw("XXXX", "....")
    half = draw("XX..", "XX..")  # 2 of 4 label pixels predicted; predicted cluster 2 of 4 true
    got = accuracy_counts(half, labels)
    assert (got.true_clusters, got.true_clusters_found) == (1, 1)
    assert (got.pred_clusters, got.pred_clusters_correct) == (1, 1)
    less = draw("X...", "XXX.")  # 1 of 4: missed; predicted cluster 1 of 4 true: wrong
    got = accuracy_counts(less, labels)
    assert (got.true_clusters_found, got.pred_clusters_correct) == (0, 0)


def test_nothing_to_find_gives_nan_rates() -> None:
    empty = np.zeros((3, 3), dtype=bool)
    got = accuracy_counts(empty, empty)
    assert got == AccuracyCounts.zero()
    d = got.as_dict()
    assert [d[k] for k in ("tp", "fp", "fn")] == [0, 0, 0]
    assert all(math.isnan(d[k]) for k in ACCURACY_KEYS[3:])


def test_as_dict_keys_and_types() -> None:
    d = accuracy_counts(PREDICTED, LABELS).as_dict()
    assert tuple(d) == ACCURACY_KEYS
    assert set(d) == {"tp", "fp", "fn", "precision", "recall", "f1", "iou", "cluster_precision", "cluster_recall"}
    assert all(type(d[k]) is int for k in ("tp", "fp", "fn"))
    assert all(type(d[k]) is float for k in ACCURACY_KEYS[3:])


def test_pooling_sums_counts() -> None:
    a = AccuracyCounts(3, 3, 3, 3, 2, 4, 2)
    b = AccuracyCounts(3, 1, 2, 3, 2, 3, 2)
    pooled = a + b
    assert pooled == AccuracyCounts(6, 4, 5, 6, 4, 7, 4)
    assert sum([a, b]) == pooled and sum([a, b], AccuracyCounts.zero()) == pooled
    # micro average: 6 / 10, not the mean of 0.5 and 0.75
    assert pooled.precision == 0.6 and pooled.recall == 6 / 11
    assert pooled.cluster_precision == 4 / 7 and pooled.cluster_recall == 4 / 6
    assert sum([], AccuracyCounts.zero()) == AccuracyCounts.zero()


def test_counts_are_python_ints() -> None:
    c = AccuracyCounts(np.int64(2), np.int32(1), 0, 1, 1, 1, 0)
    assert type(c.tp) is int and type(c.fp) is int and c.as_dict()["tp"] == 2


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"tp": -1}, r"AccuracyCounts.tp must be a non-negative integer, got -1"),
        ({"fp": 1.0}, r"AccuracyCounts.fp must be a non-negative integer, got 1.0"),
        ({"fn": True}, r"AccuracyCounts.fn must be a non-negative integer, got True"),
        ({"true_clusters": 1, "true_clusters_found": 2}, r"true_clusters_found \(2\) exceeds true_clusters \(1\)"),
        ({"pred_clusters": 0, "pred_clusters_correct": 1}, r"pred_clusters_correct \(1\) exceeds pred_clusters \(0\)"),
    ],
)
def test_bad_counts(kwargs: dict, match: str) -> None:
    base = dict(tp=0, fp=0, fn=0, true_clusters=2, true_clusters_found=0, pred_clusters=2, pred_clusters_correct=0)
    with pytest.raises(ParameterError, match=match):
        AccuracyCounts(**{**base, **kwargs})


M = np.zeros((3, 4), dtype=bool)


@pytest.mark.parametrize(
    ("args", "kwargs", "error", "match"),
    [
        ((M, np.zeros((3, 5), dtype=bool)), {}, InputShapeError, r"outliers must have shape \(3, 4\)"),
        ((M.astype(np.uint8), M), {}, InputShapeError, r"predicted must be an \(H, W\) bool array, got shape \(3, 4\) uint8"),
        ((M, M[None]), {}, InputShapeError, r"outliers must be an \(H, W\) bool array, got shape \(1, 3, 4\)"),
        ((M, M), {"reviewed": np.ones((4, 3), dtype=bool)}, InputShapeError, r"reviewed must have shape \(3, 4\)"),
        ((M, np.ones_like(M)), {"reviewed": M}, ParameterError,
         r"outliers must lie inside reviewed: 12 labelled pixel\(s\) are not reviewed"),
        ((M, M), {"reviewed": np.ones_like(M), "valid": M}, ParameterError,
         r"reviewed must lie inside valid: 12 reviewed pixel\(s\) are invalid"),
        ((M, np.ones_like(M)), {"valid": M}, ParameterError, r"outliers must lie inside reviewed"),
    ],
)
def test_bad_accuracy_input(args: tuple, kwargs: dict, error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        accuracy_counts(*args, **kwargs)


def test_bad_relative_input() -> None:
    with pytest.raises(InputShapeError, match=r"zcut_mask must have shape \(3, 4\)"):
        relative_metrics(M, np.zeros((4, 4), dtype=bool))
    with pytest.raises(ParameterError, match=r"n_nominal must be a non-negative integer, got -1"):
        sensitivity(1, -1, 1)
    with pytest.raises(ParameterError, match=r"n1 must be a non-negative integer, got 0.5"):
        RelativeMetrics.from_counts(1, 0.5, 1)


# ------------------------------------------------------------------------------------------------
# agreement between annotators
# ------------------------------------------------------------------------------------------------
def test_cohen_kappa_by_hand() -> None:
    a = draw("XX", "..")
    b = draw("X.", "..")
    # p_o = 3/4, p_e = (2·1 + 2·3) / 16 = 1/2  ->  κ = (3/4 − 1/2) / (1 − 1/2) = 1/2
    assert cohen_kappa(a, b) == 0.5
    assert cohen_kappa(a, a) == 1.0
    assert cohen_kappa(a, ~a) == -1.0
    assert math.isnan(cohen_kappa(np.zeros((2, 2), bool), np.zeros((2, 2), bool)))  # 0/0


def test_cohen_kappa_where() -> None:
    a = draw("XX.X", "..XX")
    b = draw("X..X", "...X")
    where = draw("XXX.", "XXX.")
    # over where: a = 1 1 0 / 0 0 1, b = 1 0 0 / 0 0 0 -> n 6, agree 4, n_a 3, n_b 1
    # κ = (6·4 − (3·1 + 3·5)) / (36 − 18) = 6 / 18 = 1/3
    assert cohen_kappa(a, b, where=where) == 1 / 3
    assert math.isnan(cohen_kappa(a, b, where=np.zeros_like(a)))  # no pixel


def test_mask_iou() -> None:
    a = draw("XX.", "...")
    b = draw("X..", "..X")
    assert mask_iou(a, b) == 1 / 3
    assert mask_iou(a, b, where=draw("XXX", "...")) == 0.5
    assert math.isnan(mask_iou(np.zeros((2, 2), bool), np.zeros((2, 2), bool)))
    with pytest.raises(InputShapeError, match=r"b must have shape \(2, 3\)"):
        mask_iou(a, np.zeros((3, 2), bool))
