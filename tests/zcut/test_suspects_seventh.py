"""The suspects' seventh round (issue 32, item 5): the grouping's merge with listed neighbours and a tournament
tree gives the reference agglomeration's groups bit for bit, whatever the length of the lists; the components
that skip the part of a window the previous pixel and the pixel above have scanned are the grown mask's; the
first detector of each pixel in one pass is the masked writes' (the whole call against ``suspects_reference``:
tests/zcut/test_suspects_fast.py)."""

from __future__ import annotations

import importlib

import numpy as np
import pytest
from components_check import check_components

from zcut.suspects.detectors import label_medians
from zcut.suspects.grouping import (
    NEAR,
    STRENGTH_CLASSES,
    _label_classes,
    _merge_compact,
    _merge_kernel,
    _primary_and_suspects,
)

ref = importlib.import_module("zcut.suspects._reference")


def _boxes(rng: np.random.Generator, n: int, *, span: int, size: int) -> np.ndarray:
    r0 = rng.integers(0, span, n)
    c0 = rng.integers(0, span, n)
    return np.stack([r0, c0, r0 + rng.integers(1, size + 1, n), c0 + rng.integers(1, size + 1, n)], 1)


@pytest.mark.parametrize("near", [1, 2, 3, NEAR, 40])
def test_listed_merge_equals_the_reference(near: int) -> None:
    """Scattered boxes, boxes on a coarse grid (many equal diagonals: the lowest indices must win), clusters
    of boxes (a merged box's lists run out and are made again), one to six kinds, any group budget."""
    rng = np.random.default_rng(70 + near)
    for case in range(120):
        n = int(rng.integers(1, 260))
        shape = case % 3
        if shape == 0:
            boxes = _boxes(rng, n, span=100, size=5)
        elif shape == 1:
            boxes = _boxes(rng, n, span=100, size=5) // 8 * 8 + np.array([0, 0, 8, 8])
        else:  # a few tight clusters far apart
            centres = rng.integers(0, 1000, (int(rng.integers(1, 6)), 2))
            at = centres[rng.integers(0, len(centres), n)] + rng.integers(-6, 7, (n, 2))
            boxes = np.concatenate([at, at + rng.integers(1, 4, (n, 2))], 1)
        kind = rng.integers(0, int(rng.integers(1, 7)), n)
        m = int(rng.integers(1, n + 1))
        want = ref._merge_compact_reference(boxes, kind, m)
        got = _merge_kernel(boxes.astype(np.int64), kind.astype(np.int64), m, near)
        np.testing.assert_array_equal(got, want, err_msg=f"case {case}, n {n}, max_groups {m}")


def test_listed_merge_of_a_large_frame_equals_the_reference() -> None:
    """1,500 boxes of three kinds, as many as a ray-traced frame's largest kinds, down to 40 groups."""
    rng = np.random.default_rng(77)
    boxes = _boxes(rng, 1500, span=1200, size=12)
    kind = rng.integers(0, 3, 1500)
    np.testing.assert_array_equal(_merge_compact(boxes, kind, 40), ref._merge_compact_reference(boxes, kind, 40))


@pytest.mark.parametrize("case", ["no box", "one box", "one box a kind", "all the same box", "budget above n"])
def test_listed_merge_of_degenerate_inputs(case: str) -> None:
    boxes = {"no box": np.zeros((0, 4), np.int64), "one box": np.array([[3, 4, 5, 6]]),
             "one box a kind": np.array([[0, 0, 1, 1], [0, 1, 1, 2], [5, 5, 9, 9]]),
             "all the same box": np.tile([[2, 2, 3, 3]], (30, 1)),
             "budget above n": np.array([[0, 0, 1, 1], [0, 1, 1, 2], [5, 5, 9, 9]])}[case]
    kind = np.arange(len(boxes)) if case == "one box a kind" else np.zeros(len(boxes), np.int64)
    m = 5 if case == "budget above n" else 1
    for near in (1, NEAR):
        got = _merge_kernel(boxes.astype(np.int64), kind.astype(np.int64), m, near)
        np.testing.assert_array_equal(got, ref._merge_compact_reference(boxes, kind, m))


def test_components_of_runs_and_columns_equal_the_grown_mask_labels() -> None:
    """Masks of long runs, full columns, solid blocks, stripes a pixel apart and sparse noise, for radii 0 to
    16 (a previous pixel of the row in the window or beyond it, the pixel above set or not)."""
    rng = np.random.default_rng(78)
    for case in range(160):
        H, W = int(rng.integers(1, 50)), int(rng.integers(1, 50))
        m = rng.random((H, W)) < float(rng.choice([0.01, 0.1, 0.5, 0.9, 1.0]))
        if case % 4 == 1:
            m[:, rng.integers(0, W, 3)] = True
        elif case % 4 == 2:
            m[rng.integers(0, H, 2), :] = True
        elif case % 4 == 3:
            m[:, ::int(rng.integers(2, 5))] = False
        r = int(rng.choice([0, 1, 2, 3, 5, 8, 16]))
        check_components(m, r)


@pytest.mark.parametrize("dtype", [np.uint8, np.int8, np.int16, np.uint16, np.int32, np.int64])
def test_primary_and_suspects_equal_the_masked_writes(dtype: type) -> None:
    """Any code, bits above the detectors' and negative ones too, empty frames."""
    rng = np.random.default_rng(79)
    info = np.iinfo(dtype)
    for _ in range(40):
        H, W = int(rng.integers(0, 30)), int(rng.integers(0, 30))
        codes = rng.integers(info.min, info.max, (H, W), dtype=dtype, endpoint=True)
        codes[rng.random((H, W)) < 0.5] = 0
        want = np.full(codes.shape, -1, np.int8)
        for i in reversed(range(5)):
            want[(codes >> i) & 1 > 0] = i
        got = np.empty(codes.shape, np.int8)
        sus = _primary_and_suspects(codes, 5, got)
        np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(sus, np.flatnonzero(want.ravel() >= 0))


def test_label_classes_equal_the_searched_medians() -> None:
    """Values on the bounds and medians that fall on them (the mean of two), ±0, NaN, ±inf, labels 0 (not
    counted) and labels with no finite value."""
    rng = np.random.default_rng(80)
    bounds = np.asarray(STRENGTH_CLASSES, np.float64)
    pool = np.array([0.0, -0.0, 1.5, 2.0, 2.5, 7.0, 8.0, 9.0, np.nan, np.inf, -np.inf, 1e308])
    for _ in range(400):
        m = int(rng.integers(0, 80))
        n = int(rng.integers(1, 12))
        values = pool[rng.integers(0, pool.size, m)] if rng.random() < 0.6 else rng.random(m) * 12
        labels = rng.integers(0, n + 1, m)
        with np.errstate(over="ignore"):  # the mean of two values of 1e308
            want = np.searchsorted(bounds, label_medians(values, labels, n), side="right").astype(np.int8)
        np.testing.assert_array_equal(_label_classes(values, labels, n, bounds), want)


def test_robust_sigma_of_one_partition_equals_numpy_median_and_quantile() -> None:
    """Every count from 1 (odd and even, the quantile's fraction below, at and above 0.5), ties, zeros only,
    heavy tails, NaN, inf and values whose sums overflow (those go to numpy)."""
    noise = importlib.import_module("zcut.suspects.noise")
    rng = np.random.default_rng(81)
    for case in range(6000):
        n = int(rng.integers(1, 40)) if case % 2 else int(rng.integers(1, 5000))
        kind = case % 6
        if kind == 0:
            a = np.abs(rng.normal(0, 1, n))
        elif kind == 1:
            a = np.round(np.abs(rng.normal(0, 3, n)))
        elif kind == 2:
            a = rng.integers(0, 3, n) * 0.5
        elif kind == 3:
            a = np.abs(rng.standard_cauchy(n))
        elif kind == 4:
            a = np.abs(rng.normal(0, 1, n))
            a[rng.integers(0, n, 2)] = rng.choice([np.nan, np.inf, 1e308])
        else:
            a = rng.uniform(0.9e308, 1.7e308, n)  # finite; the mean of two overflows
        with np.errstate(over="ignore", invalid="ignore"):
            got = noise._robust_sigma_one_partition(a)
            want = noise._robust_sigma(a)
        assert got == want or (np.isnan(got) and np.isnan(want)), (case, n, got, want)
