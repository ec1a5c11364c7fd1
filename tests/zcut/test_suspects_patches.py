"""The patch detector (:mod:`zcut.suspects.patches`): the numba kernel against its literal reference, what it flags
on synthetic patches, and the suspects' groups it adds (docs/labelling_real.md, "Stereo errors the page can hold")."""

from __future__ import annotations

import numpy as np
import pytest

from zcut.errors import InputShapeError
from zcut.params import SuspectParams
from zcut.suspects import DETECTORS, PATCH, suspects
from zcut.suspects.patches import PATCH_RHO, cut_off_patches, cut_off_patches_reference


def plane(h: int = 120, w: int = 160, *, seed: int = 3, sigma: float = 0.3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    r, c = np.mgrid[0:h, 0:w]
    return 100.0 + 0.05 * r + 0.02 * c + rng.normal(0.0, sigma, (h, w))


def xyz_of(height_mm: np.ndarray) -> np.ndarray:
    """An organized cloud whose heights (-1000 z) are ``height_mm`` (x, y on a 1 mm grid)."""
    H, W = height_mm.shape
    r, c = np.mgrid[0:H, 0:W]
    return np.stack([c * 1e-3, r * 1e-3, -height_mm / 1000.0], axis=2)


def random_case(rng: np.random.Generator, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Terraces with noise, patches and NaN: many pieces of every kind."""
    h = np.round(rng.normal(0.0, 3.0, shape)).cumsum(axis=1) * rng.choice([0.0, 1.0], shape, p=[0.7, 0.3])
    h = h + rng.integers(0, 4, shape) * 5.0 * (rng.random(shape) < 0.2)
    h[rng.random(shape) < rng.choice([0.0, 0.1, 0.5])] = np.nan
    jump = rng.uniform(0.5, 6.0, shape)
    jump[rng.random(shape) < 0.02] = np.nan
    return h, jump


@pytest.mark.parametrize("shape", [(0, 0), (0, 5), (1, 1), (1, 40), (40, 1), (23, 31), (64, 48)])
def test_kernel_equals_reference(shape: tuple[int, int]) -> None:
    rng = np.random.default_rng(20261207 + shape[0] * 100 + shape[1])
    for _ in range(6):
        h, jump = random_case(rng, shape)
        for kw in ({"max_px": 12}, {"factor": 0.5, "max_px": 200.0, "min_step_share": 0.0},
                   {"max_px": 1e9, "min_step_share": 1.0}, {"max_px": 0}):
            fast = cut_off_patches(h, jump, **kw)
            ref = cut_off_patches_reference(h, jump, **kw)
            assert fast.dtype == bool and fast.shape == h.shape
            assert np.array_equal(fast, ref), kw


def test_degenerate_inputs() -> None:
    nan = np.full((5, 7), np.nan)
    assert not cut_off_patches(nan, np.ones((5, 7)), max_px=100).any()
    one = np.arange(9.0)[None, :]
    assert not cut_off_patches(one, np.full((1, 9), 2.0), max_px=100).any()  # one piece, bounded by the image only
    assert not cut_off_patches(np.ones((4, 4), np.float32), np.ones((4, 4), np.float32), max_px=100).any()
    assert not cut_off_patches(np.zeros((0, 3)), np.zeros((0, 3)), max_px=100).any()


def test_a_patch_at_another_depth_is_flagged_and_only_it() -> None:
    h = plane()
    jump = np.full(h.shape, 2.0)
    h[20:30, 30:42] += 40.0  # a smooth patch 40 mm off the plane, measured all around
    out = cut_off_patches(h, jump, max_px=200)
    want = np.zeros(h.shape, bool)
    want[20:30, 30:42] = True
    assert np.array_equal(out, want)
    assert not cut_off_patches(h, jump, max_px=119).any()  # larger than the largest patch
    h[20:30, 30:42] -= 80.0  # behind the plane: a patch too
    assert np.array_equal(cut_off_patches(h, jump, max_px=200), want)


def test_islands_steps_and_large_pieces_are_not_patches() -> None:
    h = plane()
    jump = np.full(h.shape, 2.0)
    island = h.copy()
    island[18:32, 28:44] = np.nan  # a patch bordered by unmeasured pixels: no depth step bounds it
    island[20:30, 30:42] += 40.0
    assert not cut_off_patches(island, jump, max_px=200).any()
    step = h.copy()
    step[:, 80:] += 40.0  # two halves at two depths: each too large (and bounded mostly by the image)
    assert not cut_off_patches(step, jump, max_px=200).any()
    smooth = plane(sigma=0.3)  # noise well under the jump: one piece
    assert not cut_off_patches(smooth, jump, max_px=200).any()


def test_suspects_group_the_patch_with_its_gap() -> None:
    h = plane(sigma=0.05)
    h[20:30, 30:42] += 40.0
    xyz = xyz_of(h)
    zone = np.ones(h.shape, bool)
    params = SuspectParams(a_max=500.0)  # 120 px in front: larger than the floating cut's components (75 px)
    assert params.floating_rho * params.a_max < 120 <= PATCH_RHO * params.a_max
    res = suspects(xyz, h, zone, params=params)
    bit = PATCH
    assert DETECTORS[-1] == "patch" and bit == 1 << (len(DETECTORS) - 1)
    flagged = (res.detectors & bit) > 0
    assert flagged[20:30, 30:42].all() and flagged.sum() == 120
    g = np.unique(res.groups[flagged])
    assert g.size == 1 and g[0] > 0
    k = int(g[0]) - 1
    assert res.group_gap_mm[k] == pytest.approx(40.0, abs=1.0)
    assert res.group_gap_mm[k] > 3 * res.threshold_mm


@pytest.mark.parametrize(("h", "jump", "match"), [
    (np.zeros(5), np.zeros(5), "height_mm must be an"),
    (np.zeros((3, 3), np.int32), np.zeros((3, 3)), "height_mm must be an"),
    (np.zeros((3, 3)), np.zeros((3, 4)), "jump_mm must be a float array"),
    (np.zeros((3, 3)), np.zeros((3, 3), np.int64), "jump_mm must be a float array"),
])
def test_bad_inputs(h: np.ndarray, jump: np.ndarray, match: str) -> None:
    with pytest.raises(InputShapeError, match=match):
        cut_off_patches(h, jump, max_px=10)
