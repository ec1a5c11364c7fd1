"""The grouping's merge made cheaper, round of 2026-12-08a (issue 32 item 5, h/sus22): the merge with its listing
scans by blocks of ``BLOCK`` boxes (the first lists' by top row, and a kind's), a relisted box's bar from the boxes
listed before, its kinds' dead boxes compacted out and its tournament updated only up to an unchanged winner
(:func:`zcut.suspects.grouping._merge_kernel`) gives the reference agglomeration's groups bit for bit
(``_merge_compact_reference``), for lists of one to ``NEAR`` boxes."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from zcut.suspects.grouping import BLOCK, NEAR, _merge_compact, _merge_kernel

ref = importlib.import_module("zcut.suspects._reference")


def _case(rng: np.random.Generator, shape: str, n: int) -> np.ndarray:
    if shape == "scattered":
        r0 = rng.integers(0, 1200, n)
        c0 = rng.integers(0, 1920, n)
        return np.stack([r0, c0, r0 + rng.integers(1, 14, n), c0 + rng.integers(1, 14, n)], 1)
    if shape == "ties":  # a coarse grid: many equal diagonals, the lowest indices must win
        r0 = rng.integers(0, 12, n) * 8
        c0 = rng.integers(0, 12, n) * 8
        return np.stack([r0, c0, r0 + 8, c0 + 8], 1)
    if shape == "clusters":  # tight clusters far apart (merged boxes' lists run out and are made again)
        centres = rng.integers(0, 1000, (int(rng.integers(1, 6)), 2))
        at = centres[rng.integers(0, len(centres), n)] + rng.integers(-6, 7, (n, 2))
        return np.concatenate([at, at + rng.integers(1, 4, (n, 2))], 1)
    if shape == "tall":  # tall boxes (the rows' bound stops the first scans late), top rows in a few bands
        r0 = rng.integers(0, 3, n) * 5
        c0 = rng.integers(0, 300, n)
        return np.stack([r0, c0, r0 + rng.integers(1, 400, n), c0 + rng.integers(1, 6, n)], 1)
    if shape == "one row":
        c0 = rng.integers(0, 500, n)
        return np.stack([np.full(n, 7), c0, np.full(n, 8), c0 + 1], 1)
    if shape == "one column":
        r0 = rng.integers(0, 500, n)
        return np.stack([r0, np.full(n, 3), r0 + 1, np.full(n, 4)], 1)
    if shape == "far apart":  # coordinates far beyond a frame's
        r0 = rng.integers(0, 1 << 27, n)
        c0 = rng.integers(0, 1 << 27, n)
        return np.stack([r0, c0, r0 + rng.integers(0, 1 << 20, n), c0 + rng.integers(0, 1 << 20, n)], 1)
    if shape == "empty boxes":  # r1 = r0, c1 = c0 (still r1 >= r0 and c1 >= c0)
        r0 = rng.integers(0, 90, n)
        c0 = rng.integers(0, 90, n)
        return np.stack([r0, c0, r0, c0], 1)
    raise AssertionError(shape)


SHAPES = ["scattered", "ties", "clusters", "tall", "one row", "one column", "far apart", "empty boxes"]


@pytest.mark.parametrize("shape", SHAPES)
def test_merge_with_blocks_equals_the_reference(shape: str) -> None:
    """Kinds of several blocks of boxes (scans by blocks, the lists' bars from the boxes listed before, the dead
    compacted out again and again), one to four kinds, budgets from one group to most of the boxes."""
    rng = np.random.default_rng(2210 + SHAPES.index(shape))
    for case in range(6):
        n = int(rng.integers(3 * BLOCK, 12 * BLOCK))
        boxes = _case(rng, shape, n)
        kind = rng.integers(0, int(rng.integers(1, 5)), n)
        m = int(rng.choice([1, 40, n // 2, n - 1]))
        for near in (1, NEAR):
            got = _merge_kernel(boxes.astype(np.int64), kind.astype(np.int64), m, near)
            np.testing.assert_array_equal(got, ref._merge_compact_reference(boxes, kind, m),
                                          err_msg=f"{shape}, case {case}, n {n}, max_groups {m}, near {near}")


@pytest.mark.parametrize("case", ["no box", "one box", "one box a kind", "all the same box", "budget above n",
                                  "upside down", "backwards"])
def test_merge_of_degenerate_inputs(case: str) -> None:
    """The degenerate inputs, and boxes with r1 < r0 (the first lists from a scan of the kind) or c1 < c0."""
    rng = np.random.default_rng(2211)
    boxes = {"no box": np.zeros((0, 4), np.int64), "one box": np.array([[3, 4, 5, 6]]),
             "one box a kind": np.array([[0, 0, 1, 1], [0, 1, 1, 2], [5, 5, 9, 9]]),
             "all the same box": np.tile([[2, 2, 3, 3]], (3 * BLOCK, 1)),
             "budget above n": np.array([[0, 0, 1, 1], [0, 1, 1, 2], [5, 5, 9, 9]]),
             "upside down": _case(rng, "scattered", 150), "backwards": _case(rng, "scattered", 150)}[case]
    boxes = np.array(boxes, np.int64)
    if case == "upside down":
        boxes[7, 2] = boxes[7, 0] - 30
    if case == "backwards":
        boxes[11, 3] = boxes[11, 1] - 30
    kind = np.arange(len(boxes)) if case == "one box a kind" else np.zeros(len(boxes), np.int64)
    m = 5 if case == "budget above n" else (1 if len(boxes) < 100 else 10)
    for near in (1, NEAR):
        got = _merge_kernel(boxes, kind.astype(np.int64), m, near)
        np.testing.assert_array_equal(got, ref._merge_compact_reference(boxes, kind, m))


def test_merge_of_a_ray_traced_sized_frame_equals_the_reference() -> None:
    """5,000 boxes in 12 kinds of 145-930, mostly specks, some larger: the ray-traced frames' merge (5,306 and
    5,085 boxes into 40 groups), down to 40 groups."""
    rng = np.random.default_rng(2212)
    sizes = [930, 650, 445, 700, 410, 240, 420, 230, 165, 510, 310, 300]
    kind = np.repeat(np.arange(len(sizes)), sizes)
    n = kind.size
    r0 = rng.integers(0, 1200, n)
    c0 = rng.integers(0, 1920, n)
    h = np.where(rng.random(n) < 0.9, rng.integers(1, 14, n), rng.integers(14, 200, n))
    w = np.where(rng.random(n) < 0.9, rng.integers(1, 12, n), rng.integers(12, 170, n))
    boxes = np.stack([r0, c0, r0 + h, c0 + w], 1)
    perm = rng.permutation(n)
    np.testing.assert_array_equal(_merge_compact(boxes[perm], kind[perm], 40),
                                  ref._merge_compact_reference(boxes[perm], kind[perm], 40))
