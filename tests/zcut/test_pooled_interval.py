"""zcut.metrics.pooled_interval(_many): the intervals of pooled precision, recall and F1 over frames.

A literal reference (one row at a time, the Bell–McCaffrey matrix written out), the laws (frame
order, scaling every count, the level), the no-interval rule, bad input, and a small version of
the coverage simulation of ``bench/interval_coverage.py``: parametric populations of per-frame
counts fitted to the synthetic zinc-nut and black-nut populations (the tune set), 1000 samples of 6
frames and 2000 of 3, 12 and 24 frames. The lognormal FP tail of these models is heavier than the
populations' own (the z-cut's precision on zinc nuts covers ~0.93 here at 6 frames and ~0.91 at 12
and 24, 0.95 or more on the held-out populations themselves), so the bar is 0.9 at 6 frames and
0.88 at the others; the table over the held-out populations, bar 0.93, is docs/coverage.md.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from zcut import InputShapeError, ParameterError
from zcut.metrics import (
    INTERVAL_MIN_FRAMES,
    INTERVAL_STATS,
    bootstrap_ci_many,
    pooled_interval,
    pooled_interval_many,
)

PARTS = {"precision": lambda t, f, n: (t, t + f), "recall": lambda t, f, n: (t, t + n),
         "f1": lambda t, f, n: (2 * t, 2 * t + f + n)}


def _reference(tp, fp, fn, level=0.95) -> dict[str, tuple[float, float]]:
    """The documented interval, written out for one set of frames (Python floats, explicit matrices)."""
    out = {}
    for key, parts in PARTS.items():
        num, den = (np.array(a, dtype=np.float64) for a in parts(np.asarray(tp), np.asarray(fp), np.asarray(fn)))
        total = den.sum()
        defined = [i for i in range(len(den)) if den[i] > 0]
        if total == 0 or len(defined) < INTERVAL_MIN_FRAMES:
            out[key] = (math.nan, math.nan)
            continue
        r = num.sum() / total
        h = den / total
        if h.max() >= 1.0:
            out[key] = (math.nan, math.nan)
            continue
        z = num - r * den
        c = 1.0 / (1.0 - h) ** 2
        v = c * z * z
        se = math.sqrt(v.sum()) / total
        if se == 0 or not 0 < r < 1:
            out[key] = (math.nan, math.nan)
            continue
        u = np.sqrt(h)
        M = np.eye(len(den)) - np.outer(u, u)
        A = M @ np.diag(h * c) @ M
        df = np.trace(A) ** 2 / (A * A).sum()
        m = len(defined)
        df = min(df, v.sum() ** 2 / (v * v).sum() * (m - 1) / m)
        q = stats.t.ppf(0.5 + level / 2, df)
        g = math.log(r / (1 - r))
        sg = se / (r * (1 - r))
        out[key] = (_expit(g - q * sg), _expit(g + q * sg))
    return out


def _expit(x: float) -> float:
    if x < 0:
        e = math.exp(x)
        return e / (1 + e)
    return 1 / (1 + math.exp(-x))


def _close(a, b, rel=1e-9) -> bool:
    return (math.isnan(a) and math.isnan(b)) or abs(a - b) <= rel * max(abs(a), abs(b), 1e-300)


@pytest.mark.parametrize(
    ("tp", "fp", "fn"),
    [
        ([30, 12, 0, 7, 19], [3, 0, 9, 1, 4], [5, 8, 2, 0, 11]),
        ([1000, 2000, 1500, 0, 10], [10, 0, 300, 40, 0], [0, 5, 60, 700, 1]),
        ([1121, 427, 1903], [15, 0, 137], [2542, 1739, 3504]),  # a zinc-nut z-cut sample: FP vary most
        ([0, 0, 6, 0, 0, 0, 0], [0, 0, 2, 0, 0, 0, 0], [4, 1, 0, 3, 0, 2, 5]),  # one frame predicts anything
        ([5, 5, 5, 9], [0, 0, 0, 0], [1, 2, 3, 4]),  # precision 1 in every frame
    ],
)
def test_matches_the_literal_reference(tp, fp, fn) -> None:
    got = pooled_interval(np.array(tp), np.array(fp), np.array(fn))
    want = _reference(tp, fp, fn)
    assert list(got) == list(INTERVAL_STATS)
    for k in INTERVAL_STATS:
        assert all(_close(g, w) for g, w in zip(got[k], want[k])), (k, got[k], want[k])


@settings(max_examples=150, deadline=None)
@given(st.integers(3, 12).flatmap(lambda n: st.tuples(*(st.lists(st.integers(0, 5000), min_size=n, max_size=n)
                                                        for _ in range(3)))),
       st.sampled_from([0.8, 0.9, 0.95, 0.99]))
def test_random_counts_match_the_reference_and_bracket_the_figure(counts, level) -> None:
    tp, fp, fn = (np.array(c, dtype=np.int64) for c in counts)
    got = pooled_interval(tp, fp, fn, level=level)
    want = _reference(tp, fp, fn, level)
    for k in INTERVAL_STATS:
        assert all(_close(g, w, 1e-7) for g, w in zip(got[k], want[k])), (k, got[k], want[k])
        num, den = PARTS[k](tp, fp, fn)
        lo, hi = got[k]
        if not math.isnan(lo):
            assert 0 <= lo <= num.sum() / den.sum() <= hi <= 1


@settings(max_examples=60, deadline=None)
@given(st.integers(3, 10).flatmap(lambda n: st.tuples(*(st.lists(st.integers(0, 3000), min_size=n, max_size=n)
                                                        for _ in range(3)))),
       st.integers(2, 1000), st.randoms(use_true_random=False))
def test_laws_frame_order_and_scale(counts, scale, rnd) -> None:
    tp, fp, fn = (np.array(c, dtype=np.int64) for c in counts)
    base = pooled_interval(tp, fp, fn)
    order = list(range(len(tp)))
    rnd.shuffle(order)
    shuffled = pooled_interval(tp[order], fp[order], fn[order])
    scaled = pooled_interval(tp * scale, fp * scale, fn * scale)  # the same frames, finer pixels
    for k in INTERVAL_STATS:
        for other in (shuffled, scaled):
            assert all(_close(a, b, 1e-9) for a, b in zip(base[k], other[k])), (k, base[k], other[k])


def test_deterministic_and_a_batch_row_equals_the_row_alone() -> None:
    rng = np.random.default_rng(9)
    tp, fp, fn = (rng.integers(0, 500, (2, 3, 7)) for _ in range(3))
    fp[1, 2] = 0  # a row with precision 1 in every frame: no precision interval
    many = pooled_interval_many(tp, fp, fn)
    assert all(v.shape == (2, 3, 2) and v.dtype == np.float64 for v in many.values())
    again = pooled_interval_many(tp.copy(), fp.copy(), fn.copy())
    for k in INTERVAL_STATS:
        assert np.array_equal(many[k], again[k], equal_nan=True)
        for i in range(2):
            for j in range(3):
                assert np.array_equal(many[k][i, j], pooled_interval(tp[i, j], fp[i, j], fn[i, j])[k], equal_nan=True)
    assert np.isnan(many["precision"][1, 2]).all() and not np.isnan(many["recall"][1, 2]).any()
    # a batch bigger than one chunk gives the same rows
    big = rng.integers(0, 30, (3, 70000, 5))
    got = pooled_interval_many(big[0], big[1], big[2])
    for row in (0, 52428, 52429, 69999):
        one = pooled_interval(big[0, row], big[1, row], big[2, row])
        assert all(np.array_equal(got[k][row], one[k], equal_nan=True) for k in INTERVAL_STATS)


def test_a_higher_level_gives_a_wider_interval() -> None:
    tp, fp, fn = np.array([30, 12, 5, 7, 19]), np.array([3, 1, 9, 1, 4]), np.array([5, 8, 2, 3, 11])
    narrow, mid, wide = (pooled_interval(tp, fp, fn, level=lv) for lv in (0.8, 0.95, 0.99))
    for k in INTERVAL_STATS:
        assert wide[k][0] < mid[k][0] < narrow[k][0] < narrow[k][1] < mid[k][1] < wide[k][1], k


@pytest.mark.parametrize(
    ("tp", "fp", "fn", "none"),
    [
        ([], [], [], {"precision", "recall", "f1"}),
        ([3], [1], [2], {"precision", "recall", "f1"}),  # one frame
        ([3, 4], [1, 0], [2, 9], {"precision", "recall", "f1"}),  # two frames: too few
        ([3, 4, 0, 0, 0], [1, 0, 0, 0, 0], [2, 9, 1, 1, 1], {"precision"}),  # 2 frames define precision
        ([0, 0, 0], [0, 0, 0], [4, 0, 1], {"precision", "recall", "f1"}),  # precision 0/0, recall and F1 all 0
        ([5, 9, 2], [0, 0, 0], [1, 2, 3], {"precision"}),  # precision 1 in every frame
        ([2, 4, 6], [2, 4, 6], [2, 4, 6], {"precision", "recall", "f1"}),  # every frame the same figures
        ([0, 0, 6, 0], [0, 0, 2, 0], [0, 0, 1, 0], {"precision", "recall", "f1"}),  # one frame holds everything
        ([0, 5, 9], [3, 1, 2], [2, 2, 2], set()),  # a frame with precision 0 among others: an interval
    ],
)
def test_the_no_interval_rule(tp, fp, fn, none) -> None:
    got = pooled_interval(np.array(tp, dtype=np.int64), np.array(fp, dtype=np.int64), np.array(fn, dtype=np.int64))
    assert {k for k, (lo, hi) in got.items() if math.isnan(lo) and math.isnan(hi)} == none
    assert all(math.isnan(lo) == math.isnan(hi) for lo, hi in got.values())


@pytest.mark.parametrize(
    ("args", "kwargs", "error", "match"),
    [
        (([1.0, 2.0, 3.0], [0, 0, 0], [0, 0, 0]), {}, InputShapeError,
         r"tp must be an integer array of per-frame counts \(frames on the last axis\), got shape \(3,\) float64"),
        ((3, 1, 2), {}, InputShapeError, r"tp must be a 1-D array of per-frame counts, got shape \(\) int64"),
        (([1, 2], [0], [0, 0]), {}, InputShapeError, r"fp must have shape \(2,\) like tp, got shape \(1,\)"),
        (([1, 2], [0, 0], [0, -1]), {}, ParameterError, r"fn must hold non-negative counts, got -1"),
        (([1], [0], [0]), {"level": 1.0}, ParameterError, r"level must be a number in \(0, 1\), got 1.0"),
        (([1], [0], [0]), {"level": "0.95"}, ParameterError, r"level must be a number in \(0, 1\), got '0.95'"),
    ],
)
def test_bad_input(args, kwargs, error, match) -> None:
    with pytest.raises(error, match=match):
        pooled_interval(*args, **kwargs)


# ------------------------------------------------------------------ coverage: a small simulation
#: Per-frame count models fitted to the tune populations of bench/interval_coverage.py (``fit``):
#: true outlier pixels L = TP + FN lognormal(L_mu, L_sigma); recall per frame Beta(recall_a,
#: recall_b); FP 0 with probability fp_p0, else lognormal(fp_mu, fp_sigma) (its median and 90th
#: percentile those of the population's non-zero FP), rounded.
MODELS = {
    ("zinc_nuts", "zcut"): {"L_mu": 8.2, "L_sigma": 0.156, "recall_a": 5.12, "recall_b": 11.5, "fp_p0": 0.0938,
                            "fp_mu": 2.83, "fp_sigma": 1.51},
    ("zinc_nuts", "sor"): {"L_mu": 8.2, "L_sigma": 0.156, "recall_a": 2.02, "recall_b": 11.1, "fp_p0": 0.0125,
                           "fp_mu": 8.04, "fp_sigma": 1.03},
    ("zinc_nuts", "intersection"): {"L_mu": 8.2, "L_sigma": 0.156, "recall_a": 2.47, "recall_b": 21,
                                    "fp_p0": 0.225, "fp_mu": 1.61, "fp_sigma": 0.841},
    ("black_nuts", "zcut"): {"L_mu": 5.54, "L_sigma": 0.339, "recall_a": 1.54, "recall_b": 4.2, "fp_p0": 0.163,
                             "fp_mu": 2.77, "fp_sigma": 1.6},
    ("black_nuts", "sor"): {"L_mu": 5.54, "L_sigma": 0.339, "recall_a": 3.96, "recall_b": 6.2, "fp_p0": 0,
                            "fp_mu": 10.1, "fp_sigma": 0.211},
    ("black_nuts", "intersection"): {"L_mu": 5.54, "L_sigma": 0.339, "recall_a": 2.17, "recall_b": 17.2,
                                     "fp_p0": 0.169, "fp_mu": 1.79, "fp_sigma": 1.11},
}

def _population(p: dict, rng: np.random.Generator, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    L = np.rint(rng.lognormal(p["L_mu"], p["L_sigma"], size)).astype(np.int64)
    tp = rng.binomial(L, rng.beta(p["recall_a"], p["recall_b"], size))
    fp = np.where(rng.random(size) < p["fp_p0"], 0, np.rint(rng.lognormal(p["fp_mu"], p["fp_sigma"], size)))
    return tp, fp.astype(np.int64), L - tp


@pytest.mark.parametrize("model", sorted(MODELS))
def test_coverage_of_six_frames_on_fitted_populations(model) -> None:
    rng = np.random.default_rng(20)
    tp, fp, fn = _population(MODELS[model], rng, 4000)
    idx = rng.integers(0, tp.size, (1000, 6))  # 1000 samples of 6 independent frames
    ours = pooled_interval_many(tp[idx], fp[idx], fn[idx])
    boot = bootstrap_ci_many(tp[idx], fp[idx], fn[idx], n_boot=1000)
    worst_boot = 1.0
    for k in INTERVAL_STATS:
        num, den = PARTS[k](tp, fp, fn)
        truth = num.sum() / den.sum()
        lo, hi = ours[k][:, 0], ours[k][:, 1]
        has = ~np.isnan(lo)
        assert has.mean() > 0.97, (model, k)  # 6 frames: an interval nearly always
        coverage = np.mean((lo[has] <= truth) & (truth <= hi[has]))
        assert coverage >= 0.9, (model, k, coverage)
        worst_boot = min(worst_boot, np.mean((boot[k][:, 0] <= truth) & (truth <= boot[k][:, 1])))
    assert worst_boot < 0.9  # the former percentile bootstrap does not hold these populations


#: The models' FP tail beyond their 90th percentile is lognormal, heavier than the synthetic
#: populations' (the top 10 % of frames hold ~0.6 of ΣFP in the models, 0.40–0.47 in the
#: populations): the z-cut's precision covers ~0.91 here at 12 and 24 frames (20 000 samples), 0.95
#: or more on the held-out populations themselves (docs/coverage.md). The bar is below that, and
#: above the former percentile bootstrap's worst, 0.63–0.85 (docs/accuracy.md, "How well it holds").
HEAVY_TAIL_BAR = 0.88


@pytest.mark.parametrize("n", [3, 12, 24])
@pytest.mark.parametrize("model", sorted(MODELS))
def test_coverage_of_3_12_and_24_frames_on_fitted_populations(model, n) -> None:
    rng = np.random.default_rng(20)
    tp, fp, fn = _population(MODELS[model], rng, 4000)
    idx = rng.integers(0, tp.size, (2000, n))  # 2000 samples of n independent frames
    ours = pooled_interval_many(tp[idx], fp[idx], fn[idx])
    for k in INTERVAL_STATS:
        num, den = PARTS[k](tp, fp, fn)
        truth = num.sum() / den.sum()
        lo, hi = ours[k][:, 0], ours[k][:, 1]
        has = ~np.isnan(lo)
        assert has.mean() > (0.9 if n == 3 else 0.99), (model, k, n, has.mean())  # the rule rarely withholds
        assert np.array_equal(np.isnan(lo), np.isnan(hi))
        coverage = np.mean((lo[has] <= truth) & (truth <= hi[has]))
        assert coverage >= HEAVY_TAIL_BAR, (model, k, n, coverage)
        assert np.all(lo[has] <= hi[has])
