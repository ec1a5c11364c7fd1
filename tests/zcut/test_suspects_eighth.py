"""The suspects' eighth round (issue 32, item 5): the components joined run by run are the grown mask's; the
noise samples taken from per-row lists of the finite differences are the eight sweeps'; the radix sort that
counts every digit in one pass is ``np.argsort(kind="stable")``; the bins' median heights read from sorted
slices are ``np.median``'s (the whole call against ``suspects_reference``: tests/zcut/test_suspects_fast.py)."""

from __future__ import annotations

import importlib

import numpy as np
import pytest
from components_check import check_components

from zcut.suspects.noise import _sampled_both, _sampled_differences, _sorted_median
from zcut.suspects.select import stable_argsort

ref = importlib.import_module("zcut.suspects._reference")



@pytest.mark.parametrize("r", [0, 1, 2, 3, 7, 16])
def test_components_of_runs_at_the_reach_equal_the_grown_mask_labels(r: int) -> None:
    """Pixels of a row exactly 2r + 1 and 2r + 2 columns apart (one run or two), rows exactly that far
    apart, runs whose spans meet only at their ends or diagonally, sparse runs over a pixel of the next
    row in their gaps, blobs and noise."""
    reach = 2 * r + 1
    rng = np.random.default_rng(800 + r)
    for case in range(80):
        H, W = int(rng.integers(1, 6 * reach + 8)), int(rng.integers(1, 6 * reach + 8))
        m = np.zeros((H, W), bool)
        kind = case % 5
        if kind == 0:  # combs in the rows: gaps of reach (one run) or reach + 1 (separate pixels)
            for i in rng.integers(0, H, 4):
                m[i, int(rng.integers(0, 3))::reach + int(rng.integers(0, 2))] = True
        elif kind == 1:  # combs in the columns
            for j in rng.integers(0, W, 4):
                m[int(rng.integers(0, 3))::reach + int(rng.integers(0, 2)), j] = True
        elif kind == 2:  # short runs at random, some touching at the reach exactly
            for _ in range(int(rng.integers(1, 12))):
                i, j = int(rng.integers(0, H)), int(rng.integers(0, W))
                m[i, j:j + int(rng.integers(1, 6))] = True
                d = reach + int(rng.integers(0, 2))
                if i + d < H and j + d < W:
                    m[i + d, j + d] = True
        elif kind == 3:  # blobs with holes
            for _ in range(int(rng.integers(1, 5))):
                i, j = int(rng.integers(0, H)), int(rng.integers(0, W))
                m[i:i + int(rng.integers(1, 15)), j:j + int(rng.integers(1, 15))] = True
            m &= rng.random((H, W)) < 0.85
        else:
            m = rng.random((H, W)) < float(rng.choice([0.005, 0.05, 0.3, 1.0]))
        check_components(m, r)


def test_components_of_degenerate_masks() -> None:
    for m in (np.ones((1, 1), bool), np.zeros((3, 3), bool), np.ones((1, 50), bool),
              np.ones((50, 1), bool), np.eye(7, dtype=bool), np.eye(7, dtype=bool)[::-1]):
        for r in (0, 1, 3):
            check_components(m, r)


def test_noise_samples_from_row_lists_equal_the_eight_sweeps() -> None:
    """Frames with whole rows finite (the list is the identity), one hole a row, large holes, infinities,
    judged masks with holes of their own, and frames 1 or 2 pixels wide or high."""
    rng = np.random.default_rng(801)
    for t in range(400):
        H, W = (int(rng.integers(1, 4)), int(rng.integers(1, 40))) if t % 4 == 0 else \
               (int(rng.integers(1, 40)), int(rng.integers(1, 4))) if t % 4 == 1 else \
               (int(rng.integers(3, 40)), int(rng.integers(3, 40)))
        h = rng.normal(800.0, 5.0, (H, W))
        if t % 2:
            h = np.round(h)
        if t % 5 == 1:
            h[rng.integers(0, H, 3), rng.integers(0, W, 3)] = np.nan
        elif t % 5 == 2:
            i, j = int(rng.integers(0, H)), int(rng.integers(0, W))
            h[i:i + int(rng.integers(1, H + 1)), j:j + int(rng.integers(1, W + 1))] = np.nan
        elif t % 5 == 3:
            h[rng.random((H, W)) < 0.05] = float(rng.choice([np.inf, -np.inf]))
        judged = np.isfinite(h) if t % 3 == 0 else rng.random((H, W)) < float(rng.choice([0.5, 0.95, 1.0]))
        most = int(rng.choice([1, 2, 3, 7, 50, 200_000]))
        got = _sampled_both(h, judged, most)
        want = (*_sampled_differences(h, judged, 2, most), *_sampled_differences(h, judged, 1, most))
        for g, w in zip(got, want):
            assert g.shape == w.shape
            np.testing.assert_array_equal(g.view(np.int64), w.view(np.int64))


def test_radix_sort_equals_numpy_stable_argsort() -> None:
    """Heights in a narrow range (the high digits all one: passes skipped), values across every exponent,
    negatives, -0.0 among 0.0, subnormals, infinities, many ties, and sizes around the buckets' count."""
    rng = np.random.default_rng(802)
    makers = [
        lambda n: 800.0 + rng.random(n),
        lambda n: rng.normal(size=n) * 10.0 ** rng.integers(-300, 300, n),
        lambda n: np.round(rng.normal(size=n) * 3.0),
        lambda n: rng.choice([0.0, -0.0, 5e-324, -5e-324, 1.7e308, -1.7e308, np.inf, -np.inf, 1.0], n),
        lambda n: np.full(n, -2.5),
        lambda n: rng.integers(-3, 4, n) * 1e-310,
    ]
    for t in range(240):
        n = int(rng.choice([0, 1, 2, 3, 2047, 2048, 2049, int(rng.integers(4, 5000))]))
        x = makers[t % len(makers)](n).astype(np.float64)
        got = stable_argsort(x)
        want = np.argsort(x, kind="stable")
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)


def test_sorted_median_equals_numpy_median() -> None:
    """Odd and even counts, middle values 0.0 and -0.0 (``np.median`` decides), NaN at the end, infinities
    and sums that overflow."""
    rng = np.random.default_rng(803)
    pool = np.array([0.0, -0.0, 1.0, 2.0, -1.5, 1e308, 1.7e308, -1.7e308, np.inf, -np.inf, 5e-324, np.nan])
    with np.errstate(over="ignore", invalid="ignore"):
        for t in range(3000):
            n = int(rng.integers(1, 30))
            x = rng.choice(pool, n) if t % 2 else rng.normal(800.0, 1.0, n)
            x = np.sort(x, kind="stable")
            got = np.float64(_sorted_median(x))
            want = np.median(x)
            assert got.tobytes() == np.float64(want).tobytes(), (x, got, want)


@pytest.mark.parametrize("near", [1, 3, 8])
def test_merge_first_lists_by_rows_equal_the_reference(near: int) -> None:
    """The first lists scan out from each box's top row: boxes in bands of equal top rows, tall boxes whose
    diagonals tie, kinds far apart in rows, and boxes upside down (r1 < r0: the scan of the kind instead)."""
    from zcut.suspects.grouping import _merge_kernel

    rng = np.random.default_rng(804 + near)
    for case in range(90):
        n = int(rng.integers(1, 200))
        r0 = rng.integers(0, 6, n) * int(rng.choice([1, 20])) if case % 3 == 0 else rng.integers(0, 400, n)
        c0 = rng.integers(0, 400, n)
        boxes = np.stack([r0, c0, r0 + rng.integers(1, int(rng.choice([2, 60])), n),
                          c0 + rng.integers(1, 10, n)], 1).astype(np.int64)
        if case % 5 == 4:
            boxes[rng.integers(0, n), 2] -= 100  # upside down
        kind = rng.integers(0, int(rng.integers(1, 4)), n).astype(np.int64)
        m = int(rng.integers(1, n + 1))
        np.testing.assert_array_equal(_merge_kernel(boxes, kind, m, near),
                                      ref._merge_compact_reference(boxes, kind, m), err_msg=f"case {case}")
