"""The residual field's median (:func:`zcut.removal._median`) equals ``np.median`` bit for bit.

:func:`zcut.removal._trimmed` (each trim of the frame tolerance's and the bin check's residual field) takes two
medians a trim; the kernel brackets them with a regular sample and selects among the values within the bracket.
Checked against numba's ``np.median`` (what the trims called before) and numpy's on random values of every size
around the kernel's thresholds, both parities, ties, sorted and reversed runs, constants, infinities, NaN, and
values laid out so that the regular sample misses the median's bracket on either side; the selection
(:func:`zcut.removal._select`) against a sort on small arrays. A zero median may come out as -0.0 where numba's
says 0.0 (or the reverse) when zeros of both signs tie at the middle; the trims take the misfits' median only to
subtract it before an absolute value, so their outputs are the same (:func:`test_the_trims_equal_numbas_medians`).
"""

from __future__ import annotations

import numba
import numpy as np
import pytest

from zcut.removal import _MEDIAN_SAMPLE, _median, _select


@numba.njit(cache=False)
def _numba_median(x):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    return np.median(x)


@numba.njit(cache=False)
def _selected(a, k):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    _select(a, k, 0, a.shape[0] - 1)
    return a


def _same(x: np.ndarray) -> None:
    got = _median(x)
    want = _numba_median(x)
    if np.isnan(want):
        assert np.isnan(got)
        return
    assert got == want, (len(x), got, want)
    if want != 0.0:  # among tied zeros of both signs either may be the middle one, for np.median too
        assert np.float64(got).tobytes() == np.float64(want).tobytes()
    if not np.isnan(x).any():
        assert got == np.median(x)


SIZES = [1, 2, 3, 100, 8 * _MEDIAN_SAMPLE - 1, 8 * _MEDIAN_SAMPLE, 8 * _MEDIAN_SAMPLE + 1, 15_226, 15_227,
         20_000, 20_001, 45_487]


@pytest.mark.parametrize("n", SIZES)
def test_random_values(n):
    rng = np.random.default_rng(n)
    for _ in range(5):
        _same(rng.standard_normal(n) * 1e-4)
        _same(np.abs(rng.standard_normal(n)) * 1e-4)  # the MAD's: one-sided
        _same(rng.standard_cauchy(n))


@pytest.mark.parametrize("n", SIZES)
def test_ties_runs_and_constants(n):
    rng = np.random.default_rng(1000 + n)
    _same(np.round(rng.standard_normal(n), 1))  # many ties at the median
    _same(rng.integers(0, 3, n).astype(np.float64))
    _same(np.sort(rng.standard_normal(n)))
    _same(np.sort(rng.standard_normal(n))[::-1].copy())
    _same(np.full(n, 2.5))
    _same(np.zeros(n))
    x = np.full(n, -0.0)
    x[::2] = 0.0
    _same(x)


@pytest.mark.parametrize("n", SIZES)
def test_infinities_and_nan(n):
    rng = np.random.default_rng(2000 + n)
    x = rng.standard_normal(n)
    x[rng.random(n) < 0.3] = np.inf
    _same(x)
    x[rng.random(n) < 0.3] = -np.inf
    _same(x)
    _same(np.full(n, np.inf))
    x = rng.standard_normal(n)
    x[rng.integers(0, n)] = np.nan
    _same(x)
    _same(np.full(n, np.nan))


@pytest.mark.parametrize("n", [8 * _MEDIAN_SAMPLE, 15_226, 20_001])
def test_a_sample_that_misses_the_bracket(n):
    """The sampled positions hold the largest (then the smallest) values: the bracket lies off the median, the
    counts say so and ``np.median`` answers."""
    rng = np.random.default_rng(3000 + n)
    stride = n // _MEDIAN_SAMPLE
    for sign in (1.0, -1.0):
        x = rng.standard_normal(n)
        x[::stride] = sign * (10.0 + rng.random(len(x[::stride])))
        _same(x)
        # half of the sample out of the way: the bracket's edge lies beyond the median on one side only
        x = rng.standard_normal(n)
        x[: _MEDIAN_SAMPLE // 2 * stride : stride] = sign * 10.0
        _same(x)


def test_the_selection_against_a_sort():
    rng = np.random.default_rng(4)
    for n in range(1, 40):
        for _ in range(20):
            x = rng.integers(0, max(2, n // 3), n).astype(np.float64) if n % 2 else rng.standard_normal(n)
            want = np.sort(x)
            for k in range(n):
                a = _selected(x.copy(), k)
                assert a[k] == want[k]
                assert (a[:k] <= a[k]).all() and (a[k + 1:] >= a[k]).all()
                assert np.array_equal(np.sort(a), want)


@numba.njit(cache=False)
def _trimmed_numba_median(e, keep):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """:func:`zcut.removal._trimmed` as it was, with numba's ``np.median``."""
    ek = e[keep]
    mid = np.median(ek)
    sigma = 1.4826 * np.median(np.abs(ek - mid))
    bound = max(3.0 * sigma, 1e-4)
    out = np.abs(e) <= bound
    return sigma, out, np.count_nonzero(out)


@pytest.mark.parametrize("n", [100, 4097, 15_226, 20_001])
def test_the_trims_equal_numbas_medians(n):
    from zcut.removal import _trimmed

    rng = np.random.default_rng(5000 + n)
    cases = [rng.standard_normal(n) * 1e-4, np.round(rng.standard_normal(n), 1) * 1e-4, np.zeros(n)]
    x = np.round(rng.standard_normal(n), 1)
    x[x == 0] = -0.0
    x[: n // 3][x[: n // 3] == 0] = 0.0
    cases.append(x)
    for e in cases:
        for keep in (np.ones(n, bool), rng.random(n) < 0.7, np.abs(e) < 1.5e-4):
            if not keep.any():
                continue
            got = _trimmed(e, keep)
            want = _trimmed_numba_median(e, keep)
            assert np.float64(got[0]).tobytes() == np.float64(want[0]).tobytes()
            assert np.array_equal(got[1], want[1]) and got[2] == want[2]


def test_the_median_of_residuals_and_steps_is_numpys():
    """:func:`zcut.removal._median_of` (σ_bin's and the pixel angle's median) against ``np.median``: float64 with
    infinities (residuals beyond reach), float32, NaN (numpy's), and the sizes of a frame's sample."""
    from zcut.removal import _median_of, bin_sigma_m

    rng = np.random.default_rng(6)
    for n in (1, 2, 7, 4096, 15_226, 20_000, 40_001):
        r = np.abs(rng.standard_normal(n))
        for x in (r, np.where(rng.random(n) < 0.2, np.inf, r), np.where(rng.random(n) < 0.7, np.inf, r),
                  r.astype(np.float32), np.where(rng.random(n) < 0.01, np.nan, r)):
            want = float(np.median(x))
            got = _median_of(x)
            assert (np.isnan(got) and np.isnan(want)) or np.float64(got).tobytes() == np.float64(want).tobytes()
        assert bin_sigma_m(r) == 1.4826 * float(np.median(r)) / 1000.0
