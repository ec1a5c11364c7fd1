"""The patch detector's two-pass labelling (``zcut.suspects.patches._patch_kernel``, round of 2026-12-07c,
docs/performance.md) against its literal reference (:func:`zcut.suspects.patches.cut_off_patches_reference`), bit for
bit, on the inputs that stress a labelling: labels met late (U shapes, spirals, combs, whose provisional labels join
rows after they start), every pixel its own piece, one piece, stripes of unmeasured pixels, NaN jumps, one row, one
column, and frames of a few hundred thousand pixels (< 2 s warm in all).
"""

from __future__ import annotations

import numpy as np
import pytest

from zcut.suspects.patches import cut_off_patches, cut_off_patches_reference

KWS = ({"max_px": 12}, {"factor": 0.5, "max_px": 200.0, "min_step_share": 0.0}, {"max_px": 1e9, "min_step_share": 1.0},
       {"max_px": 0}, {"max_px": 40, "min_step_share": 0.25})


def check(h: np.ndarray, jump: np.ndarray) -> None:
    for kw in KWS:
        fast = cut_off_patches(h, jump, **kw)
        assert fast.dtype == bool and fast.shape == h.shape
        assert np.array_equal(fast, cut_off_patches_reference(h, jump, **kw)), kw


def spiral(n: int) -> np.ndarray:
    """A one-pixel path winding inwards at height 0, on a ground at 50: a piece whose raster labels meet late."""
    h = np.full((n, n), 50.0)
    r0, c0, r1, c1 = 0, 0, n - 1, n - 1
    while r0 <= r1 and c0 <= c1:
        h[r0, c0:c1 + 1] = 0.0
        h[r0:r1 + 1, c1] = 0.0
        if r1 - 2 >= r0:
            h[r1, c0 + 2 if c0 + 2 <= c1 else c1:c1 + 1] = 0.0
        r0, c0, r1, c1 = r0 + 2, c0 + 2, r1 - 2, c1 - 2
    return h


def comb(h: int, w: int) -> np.ndarray:
    """Teeth going up from a spine on the last row: each tooth a label of its own until the spine joins them."""
    a = np.full((h, w), 30.0)
    a[:, ::2] = 0.0
    a[-1, :] = 0.0
    return a


@pytest.mark.parametrize("case", ["spiral", "comb", "u_shapes", "checker", "one_piece", "stripes", "row", "column"])
def test_shapes_that_join_labels_late(case: str) -> None:
    rng = np.random.default_rng(7)
    if case == "spiral":
        h = spiral(41)
    elif case == "comb":
        h = comb(17, 33)
    elif case == "u_shapes":
        h = np.full((30, 40), 20.0)
        for c in range(2, 36, 6):
            h[5:25, c] = h[5:25, c + 3] = 0.0
            h[24, c:c + 4] = 0.0
    elif case == "checker":  # every pixel its own piece: as many labels as pixels
        h = (np.indices((25, 31)).sum(axis=0) % 2) * 100.0
    elif case == "one_piece":
        h = np.zeros((20, 30))
    elif case == "stripes":
        h = rng.normal(0.0, 0.1, (40, 50))
        h[:, 5::7] = np.nan
        h[11::9, :] = np.nan
        h[rng.random(h.shape) < 0.05] += 25.0
    elif case == "row":
        h = np.repeat(rng.integers(0, 3, 60) * 10.0, 1)[None, :]
    else:
        h = (rng.integers(0, 3, 60) * 10.0)[:, None]
    jump = np.full(h.shape, 2.0)
    check(h, jump)
    jump2 = jump.copy()
    jump2[rng.random(h.shape) < 0.1] = np.nan  # a NaN jump cuts its pixel off
    check(h, jump2)


@pytest.mark.parametrize("seed", range(4))
def test_large_random_frames(seed: int) -> None:
    rng = np.random.default_rng(20261207 + seed)
    H, W = (480, 640) if seed == 0 else (int(rng.integers(100, 400)), int(rng.integers(100, 400)))
    r, c = np.mgrid[0:H, 0:W]
    h = 500.0 + 0.1 * r + 0.05 * c + rng.normal(0.0, 0.3, (H, W))
    for _ in range(60):  # blocks in front of and behind the plane, some touching, some cut by holes
        r0, c0 = int(rng.integers(0, H)), int(rng.integers(0, W))
        h[r0:r0 + int(rng.integers(1, 30)), c0:c0 + int(rng.integers(1, 30))] += rng.choice([-40.0, 15.0, 60.0])
    h[rng.random((H, W)) < rng.choice([0.0, 0.02, 0.3])] = np.nan
    h[int(H * 0.4):int(H * 0.6), :] = np.nan if seed % 2 else h[int(H * 0.4):int(H * 0.6), :]
    jump = np.maximum(2.0, rng.uniform(0.5, 4.0, (H, W)))
    check(h, jump)
