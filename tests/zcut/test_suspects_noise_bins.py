"""The noise profile's first differences sorted into its bins (zcut.suspects.noise._bin_order: comparisons and a
counting sort) against numpy's searchsorted and stable argsort it replaces, bit for bit: one to 32 bins, ties among
the bins' upper ends (-0.0 and 0.0 too), values on them, beyond them, ±inf; NaN anywhere hands back to numpy; and
noise_profile on frames with NaN heights only where unmeasured, against the previous lookup."""

from __future__ import annotations

import numpy as np


def _numpy_order(upper: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    bins = upper.size
    which = np.minimum(np.searchsorted(upper, x, side="left"), bins - 1)
    by_bin = np.argsort(which.astype(np.int8), kind="stable")
    return by_bin, np.searchsorted(which[by_bin], np.arange(bins + 1), side="left")


def test_bin_order_equals_searchsorted_and_the_stable_argsort() -> None:
    from zcut.suspects.noise import _bin_order

    rng = np.random.default_rng(1707)
    for t in range(2000):
        B = int(rng.choice([1, 2, 3, 7, 31, 32]))
        upper = np.sort(rng.normal(0, 10, B))
        if t % 3 == 0:
            upper = np.sort(np.round(upper))  # ties
        if t % 7 == 0:
            upper[rng.random(B) < 0.4] = float(rng.choice([0.0, -0.0]))
            upper = np.sort(upper)
        m = int(rng.integers(0, 300))
        x = rng.normal(0, 12, m)
        k = rng.random(m)
        x[k < 0.3] = rng.choice(upper, int((k < 0.3).sum()))  # on the ends
        x[(k >= 0.3) & (k < 0.33)] = np.inf
        x[(k >= 0.33) & (k < 0.36)] = -np.inf
        x[(k >= 0.36) & (k < 0.4)] = -0.0
        nan = t % 50 == 0 and m > 0
        if nan:
            x[int(rng.integers(0, m))] = np.nan
        by_bin, ends = np.empty(m, np.int64), np.zeros(B + 1, np.int64)
        done = _bin_order(upper, x, by_bin, ends)
        assert done == (not nan), t
        if done:
            w_by, w_ends = _numpy_order(upper, x)
            assert np.array_equal(by_bin, w_by) and np.array_equal(ends, w_ends), t
    assert not _bin_order(np.array([0.0, np.nan]), np.zeros(3), np.empty(3, np.int64), np.zeros(3, np.int64))


def test_noise_profile_steps_on_quantized_and_continuous_frames() -> None:
    """noise_profile's depth steps (the bins' first differences) against the bins taken by numpy, on quantized
    (whole 0.5 mm) and continuous random relief with unmeasured holes."""
    from zcut.suspects import noise as N

    rng = np.random.default_rng(1708)
    for t in range(6):
        H, W = 120, 160
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
        h = 300.0 + 0.2 * yy + 0.1 * xx + rng.normal(0, 0.3, (H, W)) + 40.0 * (rng.random((H, W)) < 0.01)
        if t % 2 == 0:
            h = np.round(h * 2.0) / 2.0
        h[rng.random((H, W)) < 0.1] = np.nan
        judged = np.isfinite(h)
        got = N.noise_profile(h, judged)
        a, at, d1, d1_at = N._sampled_both(np.ascontiguousarray(h), judged, N.NOISE_MAX_SAMPLES)
        order = np.argsort(at, kind="stable")
        at = at[order]
        bins = int(min(N.NOISE_MAX_BINS, max(1, a.size // N.NOISE_MIN_SAMPLES)))
        edges = np.linspace(0, a.size, bins + 1).astype(np.int64)
        upper = np.array([at[j - 1] for j in edges[1:]])
        by_bin, ends = _numpy_order(upper, d1_at)
        steps = np.zeros(bins)
        for k in range(bins):
            v = d1[by_bin[ends[k]:ends[k + 1]]]
            nonzero = v[v > 0]
            if v.size and nonzero.size and (v.size - nonzero.size) >= N.QUANTIZED_ZERO_SHARE * v.size:
                steps[k] = np.median(nonzero)
        assert got.step_mm.tobytes() == steps.tobytes(), t
        assert (got.step_mm > 0).any() == (t % 2 == 0), t
