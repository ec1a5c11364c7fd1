"""zcut.metrics: hand-computed relative metrics (docs/accuracy.md), true accuracy and its intervals (docs/accuracy.md), agreement."""

from __future__ import annotations

import math
from dataclasses import FrozenInstanceError, replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from zcut import InputShapeError, ParameterError
from zcut.metrics import (
    ACCURACY_KEYS,
    BOOTSTRAP_STATS,
    AccuracyCounts,
    KindCounts,
    RelativeMetrics,
    Sensitivity,
    accuracy_counts,
    bootstrap_ci,
    bootstrap_ci_many,
    bootstrap_weights,
    cohen_kappa,
    mask_iou,
    ratio,
    relative_metrics,
    scored_truth,
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
# docs/accuracy.md
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
# docs/accuracy.md
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


def counts(tp, fp, fn, tc, tcf, pc, pcc, ts, tsf, ps, psc, kinds=None) -> AccuracyCounts:
    """AccuracyCounts positionally: pixels, clusters (>= 2 px), singletons (1 px)."""
    return AccuracyCounts(tp, fp, fn, tc, tcf, pc, pcc, ts, tsf, ps, psc, kinds=kinds)


def test_accuracy_by_hand() -> None:
    # true components (8-connected): A = {(0,1),(0,2),(1,1)}, B = {(1,7)}, C = {(3,3),(4,4)}
    #   clusters A: 2/3 predicted -> found; C: 1/2 = 50 % -> found; singleton B: missed
    # predicted components: cluster {(0,1),(1,1)} all true -> correct; cluster {(5,0),(5,1)} -> wrong;
    #   singleton {(1,6)} -> wrong; singleton {(3,3)} -> correct
    got = accuracy_counts(PREDICTED, LABELS)
    assert got == AccuracyCounts(
        tp=3, fp=3, fn=3, true_clusters=2, true_clusters_found=2, pred_clusters=2, pred_clusters_correct=1,
        true_singletons=1, true_singletons_found=0, pred_singletons=2, pred_singletons_correct=1,
    )
    assert got.precision == 0.5 and got.recall == 0.5 and got.f1 == 0.5
    assert got.iou == pytest.approx(1 / 3, abs=0, rel=1e-15)
    assert got.cluster_precision == 0.5 and got.cluster_recall == 1.0
    assert got.singletons_precision == 0.5 and got.singletons_recall == 0.0
    assert got.kinds is None


def test_accuracy_over_reviewed_pixels_only() -> None:
    labels = LABELS.copy()
    labels[4, 4] = False  # rows 4 and 5 are not reviewed, so they carry no label
    reviewed = np.zeros_like(labels)
    reviewed[:4] = True
    # P ∩ R = {(0,1),(1,1),(1,6),(3,3)}: TP 3, FP 1 ((1,6)); FN = (0,2),(1,7)
    # true: cluster A found; singletons (1,7) missed, (3,3) found
    # predicted: cluster {(0,1),(1,1)} correct; singletons (1,6) wrong, (3,3) correct
    got = accuracy_counts(PREDICTED, labels, reviewed=reviewed)
    assert got == counts(3, 1, 2, 1, 1, 1, 1, 2, 1, 2, 1)
    assert got.precision == 0.75 and got.recall == 0.6 and got.iou == 0.5
    assert got.f1 == pytest.approx(2 / 3, abs=0, rel=1e-15)


def test_reviewed_defaults_to_valid() -> None:
    labels = LABELS.copy()
    labels[4, 4] = False
    valid = np.zeros_like(labels)
    valid[:4] = True
    assert accuracy_counts(PREDICTED, labels, valid=valid) == accuracy_counts(PREDICTED, labels, reviewed=valid)


def test_region_scores_only_its_pixels() -> None:
    region = np.zeros_like(LABELS)
    region[:, :6] = True  # columns 6 and 7 are outside: label (1,7) and prediction (1,6) are not scored
    # L ∩ S: A = {(0,1),(0,2),(1,1)}, C = {(3,3),(4,4)}; P ∩ S: {(0,1),(1,1)}, {(3,3)}, {(5,0),(5,1)}
    # TP (0,1),(1,1),(3,3); FP (5,0),(5,1); FN (0,2),(4,4)
    # clusters: A, C found (2/2); predicted {(0,1),(1,1)} correct, {(5,0),(5,1)} wrong; singleton (3,3) correct
    got = accuracy_counts(PREDICTED, LABELS, region=region)
    assert got == counts(3, 2, 2, 2, 2, 2, 1, 0, 0, 1, 1)
    assert got.precision == 0.6 and got.recall == 0.6 and math.isnan(got.singletons_recall)
    # S = R ∩ region: with R = rows 0..3 as well, C is cut to the singleton (3,3)
    labels = LABELS.copy()
    labels[4, 4] = False
    reviewed = np.zeros_like(labels)
    reviewed[:4] = True
    assert accuracy_counts(PREDICTED, labels, reviewed=reviewed, region=region) == counts(3, 0, 1, 1, 1, 1, 1, 1, 1, 1, 1)
    # the default region is every pixel
    assert accuracy_counts(PREDICTED, LABELS, region=np.ones_like(LABELS)) == accuracy_counts(PREDICTED, LABELS)


def test_components_are_taken_inside_the_region() -> None:
    # the region splits one true cluster into two singletons: one found, one missed
    labels = draw("XXX")
    got = accuracy_counts(draw("X.."), labels, region=draw("X.X"))
    assert got == counts(1, 0, 1, 0, 0, 0, 0, 2, 1, 1, 1)
    assert got.singletons_recall == 0.5 and got.singletons_precision == 1.0 and math.isnan(got.cluster_recall)


def test_cluster_half_rule_counts_exactly_fifty_percent() -> None:
    labels = draw("XXXX", "....")
    half = draw("XX..", "XX..")  # 2 of 4 label pixels predicted; predicted cluster 2 of 4 true
    got = accuracy_counts(half, labels)
    assert (got.true_clusters, got.true_clusters_found) == (1, 1)
    assert (got.pred_clusters, got.pred_clusters_correct) == (1, 1)
    less = draw("X...", "XXX.")  # 1 of 4: missed; predicted cluster 1 of 4 true: wrong
    got = accuracy_counts(less, labels)
    assert (got.true_clusters_found, got.pred_clusters_correct) == (0, 0)
    assert (got.true_singletons, got.pred_singletons) == (0, 0)


def test_eight_connectivity_makes_diagonal_pixels_one_cluster() -> None:
    labels = draw("X..", ".X.", "..X")
    got = accuracy_counts(draw("X..", "...", "..."), labels)
    assert (got.true_clusters, got.true_clusters_found, got.true_singletons) == (1, 0, 0)  # 1 of 3 < 50 %
    assert (got.pred_singletons, got.pred_singletons_correct, got.pred_clusters) == (1, 1, 0)


# kinds: A floating (1), B flying (4), C spike_up (2); codes up to 5
KINDS = np.zeros(LABELS.shape, np.uint8)
KINDS[0, 1] = KINDS[0, 2] = KINDS[1, 1] = 1
KINDS[1, 7] = 4
KINDS[3, 3] = KINDS[4, 4] = 2


def test_kinds_by_hand() -> None:
    region = np.zeros_like(LABELS)
    region[:, :6] = True  # B (flying) lies outside the region: held, but not scored
    got = accuracy_counts(PREDICTED, LABELS, region=region, kinds=KINDS, n_kinds=5)
    assert got.kinds == KindCounts(labelled=(3, 2, 0, 1, 0), n=(3, 2, 0, 0, 0), found=(2, 1, 0, 0, 0))
    assert got.kinds.held == (1, 2, 4)
    assert got.kinds.recall(1) == 2 / 3 and got.kinds.recall(2) == 0.5 and math.isnan(got.kinds.recall(4))
    # kinds change nothing else
    assert replace(got, kinds=None) == accuracy_counts(PREDICTED, LABELS, region=region)
    # over every pixel B is scored and missed
    assert accuracy_counts(PREDICTED, LABELS, kinds=KINDS, n_kinds=5).kinds.n == (3, 2, 0, 1, 0)


def test_kind_counts_pool_and_check() -> None:
    a = KindCounts((3, 2), (3, 1), (2, 1))
    assert a + KindCounts((1, 0), (1, 0), (0, 0)) == KindCounts((4, 2), (4, 1), (2, 1))
    assert type(KindCounts((np.int64(1),), (1,), (0,)).labelled[0]) is int
    with pytest.raises(ParameterError, match=r"cannot pool KindCounts of 2 and 1 kinds"):
        a + KindCounts((1,), (1,), (1,))
    with pytest.raises(ParameterError, match=r"kind code must be in 1..2, got 3"):
        a.recall(3)
    with_kinds = counts(1, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, kinds=KindCounts((1, 0), (1, 0), (1, 0)))
    assert (with_kinds + with_kinds).kinds == KindCounts((2, 0), (2, 0), (2, 0))
    with pytest.raises(ParameterError, match=r"cannot pool accuracy counts with and without kind truth"):
        with_kinds + AccuracyCounts.zero()


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (((), (), ()), r"KindCounts needs at least one kind"),
        (((1, 1), (1,), (0, 0)), r"KindCounts.n has 1 entries, labelled has 2"),
        (((1,), (1,), (-1,)), r"KindCounts.found\[0\] must be a non-negative integer, got -1"),
        (((1,), (2,), (0,)), r"kind code 1 must have found <= n <= labelled, got found 0, n 2, labelled 1"),
        (((2,), (1,), (2,)), r"kind code 1 must have found <= n <= labelled"),
    ],
)
def test_bad_kind_counts(args: tuple, match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        KindCounts(*args)


def test_scored_truth_scores_many_predictions() -> None:
    region = np.ones_like(LABELS)
    region[5] = False
    truth = scored_truth(LABELS, region=region, kinds=KINDS, n_kinds=5)
    rng = np.random.default_rng(7)
    for p in [PREDICTED, LABELS, np.zeros_like(LABELS), *(rng.random(LABELS.shape) < 0.3 for _ in range(5))]:
        assert truth.counts(p) == accuracy_counts(p, LABELS, region=region, kinds=KINDS, n_kinds=5)
    assert truth.shape == LABELS.shape and truth.true_index.tolist() == [1, 2, 9, 15, 27, 36]
    with pytest.raises(ValueError, match="read-only"):
        truth.scored[0, 0] = False
    with pytest.raises(FrozenInstanceError):
        truth.scored = region  # type: ignore[misc]


def test_counts_of_is_counts_given_the_components_in_any_order() -> None:
    """``ScoredTruth.counts`` and ``annotate.accuracy``'s one-pass scoring both end in ``counts_of``: given
    where P lies (P at the true pixels, its false positives, its components' sizes and true pixels), in
    whatever order the components come, the counts are those of ``counts``."""
    from scipy import ndimage

    region = np.ones_like(LABELS)
    region[5] = False
    truth = scored_truth(LABELS, region=region, kinds=KINDS, n_kinds=5)
    rng = np.random.default_rng(11)
    for p in [PREDICTED, LABELS, np.zeros_like(LABELS), *(rng.random(LABELS.shape) < 0.3 for _ in range(8))]:
        ps = p & truth.scored
        lab, n = ndimage.label(ps, structure=np.ones((3, 3), dtype=bool))
        size = np.bincount(lab[ps], minlength=n + 1)[1:]
        inside = np.bincount(lab.ravel()[truth.true_index], minlength=n + 1)[1:]
        hit = p.ravel()[truth.true_index]
        fp = int(np.count_nonzero(ps)) - int(np.count_nonzero(hit))
        order = rng.permutation(n)
        assert truth.counts_of(hit, fp, size[order], inside[order]) == truth.counts(p)


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
    assert set(d) == {"tp", "fp", "fn", "precision", "recall", "f1", "iou", "cluster_precision", "cluster_recall",
                      "singletons_precision", "singletons_recall"}
    assert all(type(d[k]) is int for k in ("tp", "fp", "fn"))
    assert all(type(d[k]) is float for k in ACCURACY_KEYS[3:])


def test_pooling_sums_counts() -> None:
    a = counts(3, 3, 3, 3, 2, 4, 2, 1, 0, 2, 1)
    b = counts(3, 1, 2, 3, 2, 3, 2, 2, 1, 2, 1)
    pooled = a + b
    assert pooled == counts(6, 4, 5, 6, 4, 7, 4, 3, 1, 4, 2)
    assert sum([a, b]) == pooled and sum([a, b], AccuracyCounts.zero()) == pooled
    # micro average: 6 / 10, not the mean of 0.5 and 0.75
    assert pooled.precision == 0.6 and pooled.recall == 6 / 11
    assert pooled.cluster_precision == 4 / 7 and pooled.cluster_recall == 4 / 6
    assert pooled.singletons_precision == 0.5 and pooled.singletons_recall == 1 / 3
    assert sum([], AccuracyCounts.zero()) == AccuracyCounts.zero()


def test_counts_are_python_ints() -> None:
    c = counts(np.int64(2), np.int32(1), 0, 1, 1, 1, 0, np.uint8(1), 0, 0, 0)
    assert type(c.tp) is int and type(c.fp) is int and type(c.true_singletons) is int and c.as_dict()["tp"] == 2


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"tp": -1}, r"AccuracyCounts.tp must be a non-negative integer, got -1"),
        ({"fp": 1.0}, r"AccuracyCounts.fp must be a non-negative integer, got 1.0"),
        ({"fn": True}, r"AccuracyCounts.fn must be a non-negative integer, got True"),
        ({"true_clusters": 1, "true_clusters_found": 2}, r"true_clusters_found \(2\) exceeds true_clusters \(1\)"),
        ({"pred_clusters": 0, "pred_clusters_correct": 1}, r"pred_clusters_correct \(1\) exceeds pred_clusters \(0\)"),
        ({"true_singletons": 0, "true_singletons_found": 1},
         r"true_singletons_found \(1\) exceeds true_singletons \(0\)"),
        ({"pred_singletons": 1, "pred_singletons_correct": 3},
         r"pred_singletons_correct \(3\) exceeds pred_singletons \(1\)"),
        ({"kinds": (1, 2)}, r"AccuracyCounts.kinds must be a KindCounts or None, got tuple"),
    ],
)
def test_bad_counts(kwargs: dict, match: str) -> None:
    base = {"tp": 0, "fp": 0, "fn": 0, "true_clusters": 2, "true_clusters_found": 0, "pred_clusters": 2,
            "pred_clusters_correct": 0, "true_singletons": 2, "true_singletons_found": 0, "pred_singletons": 2,
            "pred_singletons_correct": 0}
    with pytest.raises(ParameterError, match=match):
        AccuracyCounts(**{**base, **kwargs})


M = np.zeros((3, 4), dtype=bool)
K = np.zeros((3, 4), dtype=np.uint8)
L1 = M.copy()
L1[1, 1] = True


def _kind(code: int, at: tuple[int, int] = (1, 1)) -> np.ndarray:
    k = K.copy()
    k[at] = code
    return k


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
        ((M, M), {"region": np.ones((4, 3), dtype=bool)}, InputShapeError, r"region must have shape \(3, 4\)"),
        ((M, M), {"region": K}, InputShapeError, r"region must be an \(H, W\) bool array, got shape \(3, 4\) uint8"),
        ((M, L1), {"kinds": _kind(1), "n_kinds": None}, ParameterError,
         r"n_kinds must be an integer in 1..255 when kinds are given, got None"),
        ((M, L1), {"kinds": _kind(1), "n_kinds": 0}, ParameterError, r"n_kinds must be an integer in 1..255"),
        ((M, L1), {"kinds": _kind(1).astype(np.int64), "n_kinds": 5}, InputShapeError,
         r"kinds must be an \(H, W\) uint8 array of shape \(3, 4\) like the outliers, got shape \(3, 4\) int64"),
        ((M, L1), {"kinds": np.zeros((3, 5), np.uint8), "n_kinds": 5}, InputShapeError,
         r"kinds must be an \(H, W\) uint8 array of shape \(3, 4\) like the outliers, got shape \(3, 5\) uint8"),
        ((M, L1), {"kinds": _kind(6), "n_kinds": 5}, ParameterError,
         r"kinds holds code\(s\) \[6\] outside 0..5 at 1 pixel\(s\)"),
        ((M, L1), {"kinds": _kind(255), "n_kinds": 5}, ParameterError, r"code\(s\) \[255\] outside 0..5"),
        ((M, L1), {"kinds": _kind(1) + _kind(2, (0, 0)), "n_kinds": 5}, ParameterError,
         r"kinds must be nonzero exactly where outliers is set: 1 pixel\(s\) have a kind but are not outliers"),
        ((M, L1), {"kinds": K, "n_kinds": 5}, ParameterError,
         r"kinds must be nonzero exactly where outliers is set: 1 outlier pixel\(s\) have kind 0"),
    ],
)
def test_bad_accuracy_input(args: tuple, kwargs: dict, error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        accuracy_counts(*args, **kwargs)


# ---------------------------------------------------------------- against a literal definition
def _components(mask: np.ndarray) -> list[list[tuple[int, int]]]:
    """8-connected components by flood fill, pixel by pixel."""
    seen = np.zeros_like(mask)
    out = []
    h, w = mask.shape
    for r0 in range(h):
        for c0 in range(w):
            if mask[r0, c0] and not seen[r0, c0]:
                comp, todo = [], [(r0, c0)]
                seen[r0, c0] = True
                while todo:
                    r, c = todo.pop()
                    comp.append((r, c))
                    for dr in (-1, 0, 1):
                        for dc in (-1, 0, 1):
                            rr, cc = r + dr, c + dc
                            if 0 <= rr < h and 0 <= cc < w and mask[rr, cc] and not seen[rr, cc]:
                                seen[rr, cc] = True
                                todo.append((rr, cc))
                out.append(comp)
    return out


def _literal(p, lab, s, kind, n_kinds):
    """docs/accuracy.md read literally, one pixel and one component at a time."""
    h, w = p.shape
    px = [(r, c) for r in range(h) for c in range(w) if s[r, c]]
    tp = sum(1 for q in px if p[q] and lab[q])
    fp = sum(1 for q in px if p[q] and not lab[q])
    fn = sum(1 for q in px if lab[q] and not p[q])
    tally = {}
    for name, comps, other in (("true", _components(lab & s), p), ("pred", _components(p & s), lab)):
        hit = [2 * sum(1 for q in comp if other[q]) >= len(comp) for comp in comps]
        many = [len(comp) >= 2 for comp in comps]
        tally[name] = (sum(many), sum(h and m for h, m in zip(hit, many)),
                       sum(not m for m in many), sum(h and not m for h, m in zip(hit, many)))
    (tc, tcf, ts, tsf), (pc, pcc, ps, psc) = tally["true"], tally["pred"]
    kinds = KindCounts(
        tuple(sum(1 for r in range(h) for c in range(w) if lab[r, c] and kind[r, c] == k) for k in range(1, n_kinds + 1)),
        tuple(sum(1 for q in px if lab[q] and kind[q] == k) for k in range(1, n_kinds + 1)),
        tuple(sum(1 for q in px if lab[q] and p[q] and kind[q] == k) for k in range(1, n_kinds + 1)),
    )
    return counts(tp, fp, fn, tc, tcf, pc, pcc, ts, tsf, ps, psc, kinds=kinds)


_frames = st.integers(1, 9).flatmap(lambda h: st.integers(1, 9).flatmap(lambda w: st.tuples(
    *[arrays(np.bool_, (h, w)) for _ in range(4)], arrays(np.uint8, (h, w), elements=st.integers(1, 3)))))


@settings(max_examples=80, deadline=None)
@given(_frames)
def test_counts_match_the_literal_definition(frame) -> None:
    p, lab, r, region, kind_codes = frame
    lab = lab & r
    kind = np.where(lab, kind_codes, 0).astype(np.uint8)
    got = accuracy_counts(p, lab, reviewed=r, region=region, kinds=kind, n_kinds=3)
    assert got == _literal(p, lab, r & region, kind, 3)


# ---------------------------------------------------------------- bootstrap intervals over frames
def _slow_bootstrap(tp, fp, fn, *, n_boot: int, seed: int) -> dict[str, tuple[float, float]]:
    """The same resampling, one resample at a time: draw the frames, sum, divide, take percentiles."""
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, len(tp), size=(n_boot, len(tp)))
    got = {"precision": [], "recall": [], "f1": []}
    for frames in draws:
        t = sum(int(tp[i]) for i in frames)
        f_p = sum(int(fp[i]) for i in frames)
        f_n = sum(int(fn[i]) for i in frames)
        for key, v in (("precision", ratio(t, t + f_p)), ("recall", ratio(t, t + f_n)),
                       ("f1", ratio(2 * t, 2 * t + f_p + f_n))):
            if not math.isnan(v):
                got[key].append(v)
    return {k: tuple(float(x) for x in np.percentile(v, [2.5, 97.5])) if v else (math.nan, math.nan)
            for k, v in got.items()}


@pytest.mark.parametrize(
    ("tp", "fp", "fn", "seed"),
    [
        ([30, 12, 0, 7, 19], [3, 0, 9, 1, 4], [5, 8, 2, 0, 11], 3),
        ([4, 9], [1, 0], [0, 6], 0),
        # one frame holds every prediction: most resamples have no predicted pixel (precision 0/0)
        ([0, 0, 6, 0, 0, 0, 0], [0, 0, 2, 0, 0, 0, 0], [4, 1, 0, 3, 0, 2, 5], 11),
        ([1000, 2000, 1500, 0, 10], [10, 0, 300, 40, 0], [0, 5, 60, 700, 1], 12345),
    ],
)
def test_bootstrap_matches_a_slow_loop(tp, fp, fn, seed) -> None:
    want = _slow_bootstrap(tp, fp, fn, n_boot=1000, seed=seed)
    got = bootstrap_ci(np.array(tp), np.array(fp), np.array(fn), n_boot=1000, seed=seed)
    assert set(got) == set(BOOTSTRAP_STATS)
    for k in BOOTSTRAP_STATS:
        assert got[k] == pytest.approx(want[k], rel=1e-12, abs=0), k


def test_bootstrap_is_deterministic_and_brackets_the_point_estimate() -> None:
    rng = np.random.default_rng(5)
    tp, fp, fn = rng.integers(0, 500, 30), rng.integers(0, 200, 30), rng.integers(0, 200, 30)
    a = bootstrap_ci(tp, fp, fn)
    assert a == bootstrap_ci(tp.copy(), fp.copy(), fn.copy())  # same input, same interval
    assert a != bootstrap_ci(tp, fp, fn, seed=1)
    pooled = counts(int(tp.sum()), int(fp.sum()), int(fn.sum()), 0, 0, 0, 0, 0, 0, 0, 0)
    for k in BOOTSTRAP_STATS:
        lo, hi = a[k]
        assert type(lo) is float and lo < getattr(pooled, k) < hi, k
    wide = bootstrap_ci(tp, fp, fn, level=0.99)
    assert all(wide[k][0] <= a[k][0] and a[k][1] <= wide[k][1] for k in BOOTSTRAP_STATS)


@pytest.mark.parametrize(("tp", "fp", "fn"), [(3, 1, 2), (1, 2, 7), (0, 5, 0), (123457, 98765, 3)])
def test_bootstrap_with_one_frame_is_degenerate(tp: int, fp: int, fn: int) -> None:
    c = counts(tp, fp, fn, 0, 0, 0, 0, 0, 0, 0, 0)
    got = bootstrap_ci([tp], [fp], [fn])
    for k in BOOTSTRAP_STATS:
        assert same(got[k][0], getattr(c, k)) and same(got[k][1], getattr(c, k)), k


def test_bootstrap_undefined_figures_are_nan() -> None:
    got = bootstrap_ci([0, 0, 0], [0, 0, 0], [4, 0, 1])  # nothing predicted: precision 0/0, recall 0
    assert all(math.isnan(v) for v in got["precision"]) and got["recall"] == (0.0, 0.0) and got["f1"] == (0.0, 0.0)
    empty = bootstrap_ci(np.zeros(0, int), np.zeros(0, int), np.zeros(0, int))
    assert all(math.isnan(v) for k in BOOTSTRAP_STATS for v in empty[k])


def test_bootstrap_many_equals_one_row_at_a_time() -> None:
    rng = np.random.default_rng(9)
    tp, fp, fn = (rng.integers(0, 50, (2, 3, 6)) for _ in range(3))
    tp[1, 2] = fp[1, 2] = 0  # a row with nothing predicted
    many = bootstrap_ci_many(tp, fp, fn, n_boot=1500, seed=4)
    assert all(v.shape == (2, 3, 2) and v.dtype == np.float64 for v in many.values())
    for i in range(2):
        for j in range(3):
            one = bootstrap_ci(tp[i, j], fp[i, j], fn[i, j], n_boot=1500, seed=4)
            for k in BOOTSTRAP_STATS:
                assert np.array_equal(many[k][i, j], one[k], equal_nan=True)
    # a batch bigger than one chunk (2**21 elements / n_boot rows) gives the same rows
    big = rng.integers(0, 30, (3, 1200, 4))
    got = bootstrap_ci_many(big[0], big[1], big[2], n_boot=2000)
    for row in (0, 1047, 1048, 1199):
        one = bootstrap_ci(big[0, row], big[1, row], big[2, row], n_boot=2000)
        assert all(np.array_equal(got[k][row], one[k]) for k in BOOTSTRAP_STATS)


def test_bootstrap_weights() -> None:
    w = bootstrap_weights(7, n_boot=50, seed=2)
    assert w.shape == (50, 7) and w.dtype == np.float64 and (w.sum(axis=1) == 7).all()
    draws = np.random.default_rng(2).integers(0, 7, size=(50, 7))
    assert np.array_equal(w, np.stack([np.bincount(d, minlength=7) for d in draws]))


@pytest.mark.parametrize(
    ("args", "kwargs", "error", "match"),
    [
        (([1.0, 2.0], [0, 0], [0, 0]), {}, InputShapeError,
         r"tp must be an integer array of per-frame counts \(frames on the last axis\), got shape \(2,\) float64"),
        (([True], [0], [0]), {}, InputShapeError, r"tp must be an integer array"),
        ((3, 1, 2), {}, InputShapeError, r"tp must be a 1-D array of per-frame counts, got shape \(\) int64"),
        (([[1]], [[1]], [[1]]), {}, InputShapeError, r"tp must be a 1-D array"),
        (([1, 2], [0], [0, 0]), {}, InputShapeError, r"fp must have shape \(2,\) like tp, got shape \(1,\)"),
        (([1, 2], [0, 0], [0, -1]), {}, ParameterError, r"fn must hold non-negative counts, got -1"),
        (([1], [0], [0]), {"n_boot": 0}, ParameterError, r"n_boot must be an integer >= 1, got 0"),
        (([1], [0], [0]), {"n_boot": 100.0}, ParameterError, r"n_boot must be an integer >= 1, got 100.0"),
        (([1], [0], [0]), {"seed": -1}, ParameterError, r"seed must be an integer >= 0, got -1"),
        (([1], [0], [0]), {"level": 1.0}, ParameterError, r"level must be a number in \(0, 1\), got 1.0"),
        (([1], [0], [0]), {"level": True}, ParameterError, r"level must be a number in \(0, 1\), got True"),
    ],
)
def test_bad_bootstrap_input(args: tuple, kwargs: dict, error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        bootstrap_ci(*args, **kwargs)


def test_bad_bootstrap_weights_input() -> None:
    with pytest.raises(ParameterError, match=r"n_frames must be an integer >= 1, got 0"):
        bootstrap_weights(0)


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
