"""The frame tolerance's small selections equal what they replaced, bit for bit.

- :func:`zcut.removal._around_median` (the neighbours' median of each sampled pixel): rows of four go through a
  sorting network (:func:`zcut.removal._sort4`), other widths through the insertion sort; both against the
  insertion sort written out (the kernel before the network) and against ``np.nanmedian``, on rows of every mix of
  finite values, NaN (no neighbour), ±inf (a neighbour beyond reach), ties, and zeros of both signs.
- :func:`zcut.removal._percentile_higher` (τ's and the reach's percentile) against ``np.percentile(...,
  method="higher")``: every size up to 60 at every quantile that puts numpy's index on an integer, and random
  sizes and quantiles, with ties, infinities, NaN and zeros; arrays it hands to numpy (empty, float32, 2-D).
"""

from __future__ import annotations

import itertools

import numba
import numpy as np
import pytest

from zcut.removal import _around_median, _percentile_higher


@numba.njit(cache=False)
def _insertion_median(nbr):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """:func:`_around_median` as it was before the network (an insertion sort a row)."""
    M, K = nbr.shape
    out = np.empty(M)
    buf = np.empty(K)
    for i in range(M):
        n = 0
        seen = False
        for k in range(K):
            v = nbr[i, k]
            if not np.isnan(v):
                seen = True
            if np.isfinite(v):
                j = n
                while j > 0 and buf[j - 1] > v:
                    buf[j] = buf[j - 1]
                    j -= 1
                buf[j] = v
                n += 1
        if n == 0:
            out[i] = np.inf if seen else np.nan
        elif n % 2 == 1:
            out[i] = buf[n // 2]
        else:
            out[i] = (buf[n // 2 - 1] + buf[n // 2]) / 2.0
    return out


def _same_bytes(a: np.ndarray, b: np.ndarray) -> None:
    assert a.shape == b.shape
    bad = np.flatnonzero(a.view(np.uint64) != b.view(np.uint64))
    assert len(bad) == 0, (bad[:5], a[bad[:5]], b[bad[:5]])


#: the values a row of neighbours is made of: NaN (no neighbour), ±inf (none within reach), zeros of both signs,
#: ties and distinct values
_VALUES = (np.nan, np.inf, -np.inf, 0.0, -0.0, 1.0, 1.0, 2.5, -3.0, 1e-300)


def test_every_row_of_four_from_a_small_alphabet():
    rows = np.array(list(itertools.product(_VALUES, repeat=4)), dtype=np.float64)
    _same_bytes(_around_median(rows), _insertion_median(rows))


@pytest.mark.parametrize("width", [1, 2, 3, 4, 8])
def test_random_rows(width):
    rng = np.random.default_rng(width)
    rows = rng.standard_normal((20_000, width)) * 1e-3
    pick = rng.random(rows.shape)
    rows[pick < 0.15] = np.nan
    rows[(pick >= 0.15) & (pick < 0.2)] = np.inf
    rows[(pick >= 0.2) & (pick < 0.25)] = 0.0
    rows[(pick >= 0.25) & (pick < 0.3)] = -0.0
    rows[(pick >= 0.3) & (pick < 0.35)] = np.round(rows[(pick >= 0.3) & (pick < 0.35)], 3)  # ties
    got = _around_median(rows)
    _same_bytes(got, _insertion_median(rows))
    fin = np.where(np.isfinite(rows), rows, np.nan)
    some = np.isfinite(fin).any(axis=1)
    with np.errstate(invalid="ignore"):
        want = np.nanmedian(fin[some], axis=1)
    assert np.array_equal(got[some], want)  # == : numpy's zero may differ in sign
    assert np.all(np.isinf(got[~some]) | np.isnan(got[~some]))


def test_residual_rows():
    """Rows as the tolerance has them: non-negative residuals (mm), +inf beyond reach, NaN without a neighbour."""
    rng = np.random.default_rng(3)
    rows = np.abs(rng.normal(0, 0.7, (30_000, 4)))
    rows[rng.random(rows.shape) < 0.1] = np.nan
    rows[rng.random(rows.shape) < 0.02] = np.inf
    rows[rng.random(rows.shape) < 0.01] = 0.0
    _same_bytes(_around_median(rows), _insertion_median(rows))
    empty = np.zeros((0, 4))
    _same_bytes(_around_median(empty), _insertion_median(empty))


def _same_percentile(x: np.ndarray, q: float) -> None:
    got = _percentile_higher(x, q)
    want = float(np.percentile(x, q, method="higher"))
    assert np.float64(got).tobytes() == np.float64(want).tobytes(), (len(x), q, got, want)


def test_every_integer_index():
    """Quantiles that put numpy's virtual index (n - 1) * q / 100 on an integer or just off it, where ``ceil``
    decides: every size up to 60."""
    rng = np.random.default_rng(1)
    for n in range(1, 61):
        x = rng.standard_normal(n)
        for k in range(n):
            q = 100.0 * k / max(n - 1, 1)
            for qq in (q, np.nextafter(q, 0.0), np.nextafter(q, 200.0)):
                if 0.0 <= qq <= 100.0:
                    _same_percentile(x, float(qq))


@pytest.mark.parametrize("n", [1, 2, 7, 100, 4096, 15_226, 20_001])
def test_random_values_and_quantiles(n):
    rng = np.random.default_rng(n)
    qs = [0.0, 50.0, 90.0, 95.0, 99.0, 99.5, 100.0, *rng.uniform(0, 100, 5)]
    for x in (rng.standard_normal(n), np.abs(rng.normal(0, 0.7, n)), np.round(rng.random(n), 2),
              np.sort(rng.random(n)), np.sort(rng.random(n))[::-1].copy(), np.full(n, 0.5)):
        for q in qs:
            _same_percentile(x, q)
        inf = x.copy()
        inf[rng.random(n) < 0.3] = np.inf  # residuals beyond reach
        for q in qs:
            _same_percentile(inf, q)
        nan = x.copy()
        nan[n // 2] = np.nan
        for q in qs:
            _same_percentile(nan, q)


def test_zeros_and_other_arrays():
    """Zeros (of both signs: numpy answers those), arrays the selection does not take (numpy answers)."""
    zeros = np.array([0.0, -0.0, 0.0, 1.0, -0.0, 2.0])
    for q in (0.0, 20.0, 40.0, 60.0, 100.0):
        _same_percentile(zeros, q)
    _same_percentile(np.abs(zeros), 50.0)
    _same_percentile(np.array([3.0, 1.0, 2.0], np.float32), 90.0)
    _same_percentile(np.array([[3.0, 1.0], [2.0, 5.0]]), 90.0)
    with pytest.raises(IndexError):
        np.percentile(np.zeros(0), 90.0, method="higher")
    with pytest.raises(IndexError):
        _percentile_higher(np.zeros(0), 90.0)


def test_nearest_points_on_real_clouds():
    """The nearest-point query (:func:`zcut.removal._nearest_points`: the 2 x 2 x 2 block, the ball, the shells,
    the tree for the unsure rows) against the KD-tree on real geometry: each real organized cloud's every 3rd valid
    point within a 30 cm box as the model (irregular spacing, several points to a cell), its other points as queries, in image order
    and shuffled, and moved by a few millimetres; distances and points bit for bit."""
    import os
    from pathlib import Path

    from replay.logs.pcd import read_pcd
    from zcut.bin_model import BinModel
    from zcut.params import RemovalParams
    from zcut.removal import _nearest_points, prepare_removal_index

    root = Path(os.environ.get("ZCUT_REAL_DATA", "/work/shared/data/real"))
    clouds = sorted(root.glob("*.pcd")) if root.is_dir() else []
    if not clouds:
        pytest.skip("no real clouds")
    rng = np.random.default_rng(17)
    for path in clouds:
        xyz = read_pcd(path).xyz.reshape(-1, 3).astype(np.float64)
        pts = xyz[np.isfinite(xyz).all(axis=1)]
        pts = pts[(np.abs(pts - np.median(pts, axis=0)) < 0.15).all(axis=1)]  # a 30 cm box: a grid of ~3M cells
        model = BinModel(np.ascontiguousarray(pts[::3]), None, 0.002)
        index = prepare_removal_index(model, RemovalParams())
        ub = index.params.max_tolerance_mm / 1000.0
        queries = np.delete(pts, np.arange(0, len(pts), 3), axis=0)[:60_000]
        for name, q in {"image order": queries, "shuffled": queries[rng.permutation(len(queries))],
                        "moved": queries + rng.normal(0, 3e-3, queries.shape)}.items():
            q = np.ascontiguousarray(q)
            d, j = _nearest_points(q, index)
            d_t, j_t = index.tree.query(q, k=1, distance_upper_bound=ub)
            assert np.array_equal(d, d_t) and np.array_equal(j, j_t), f"{path.name} {name}"
