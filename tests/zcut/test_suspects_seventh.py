"""The suspects' seventh round (issue 32, item 5): the grouping's merge with listed neighbours and a tournament
tree gives the reference agglomeration's groups bit for bit, whatever the length of the lists (the whole call
against ``suspects_reference``: tests/zcut/test_suspects_fast.py)."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from zcut.suspects.grouping import NEAR, _merge_compact, _merge_kernel

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
