"""SOR's statistics skip the blocks of pixels with no valid one (h/fps4): the sums stay the literal loop's, bit for
bit, on sparse, clustered valid pixels (most blocks skipped) at widths on and around the block's multiples."""

import math

import numpy as np
import pytest

from zcut import sor as sor_module


def _literal(dbar: np.ndarray, valid: np.ndarray, n: float, open3d: bool) -> np.ndarray:
    """(mean, std) of the literal loop over the summed values only, in raster order."""
    terms = [float(d) for d, ok in zip(dbar.ravel(), valid.ravel()) if ok and (not open3d or d > 0.0)]
    s = 0.0
    for t in terms:
        s = s + t
    mean = s / n
    sq = 0.0
    for t in terms:
        sq = sq + (t - mean) * (t - mean)
    with np.errstate(invalid="ignore"):
        std = math.sqrt(sq / (n - 1)) if not sq < 0.0 else math.nan
    return np.array([mean, std])


@pytest.mark.parametrize("open3d", [False, True])
@pytest.mark.parametrize("W", [1, 15, 16, 17, 31, 32, 33, 47, 200])
def test_sums_skip_blocks_without_a_valid_pixel(open3d: bool, W: int) -> None:
    # valid pixels in a few rectangles (the top region's shape: most blocks of a row have none, some one pixel at
    # their first or last column); skipped pixels hold NaN, inf, -0.0, garbage or subnormals, which would show in
    # the sums if read; d̄ over decades (the order of the additions shows), zeros (open3d leaves them out)
    assert sor_module._SUM_BLOCK == 16
    rng = np.random.default_rng(3 + W + 100 * open3d)
    H = 29
    dbar = np.exp(rng.uniform(-12.0, 2.0, (H, W)))
    dbar[rng.random((H, W)) < 0.1] = 0.0
    valid = np.zeros((H, W), bool)
    for _ in range(3):
        r0, c0 = rng.integers(0, H), rng.integers(0, W)
        valid[r0:r0 + rng.integers(1, 6), c0:c0 + rng.integers(1, 7)] = True
    for c in (15, 16, 31, 32):  # a lone pixel at a block's last and next block's first column
        if c < W:
            valid[H // 2, c] = True
    valid[-1, -1] = True
    valid[0, 0] = True
    junk = rng.choice(np.array([np.nan, np.inf, -np.inf, -0.0, 5e-324, 1e300]), (H, W))
    dbar = np.where(valid, dbar, junk)
    n = float(max(np.count_nonzero(valid), 2))
    got = np.array(sor_module._mean_std(dbar, valid, n, open3d))
    want = _literal(dbar, valid, n, open3d)
    assert np.array_equal(got.view(np.uint64), want.view(np.uint64)), (got, want)


@pytest.mark.parametrize("open3d", [False, True])
def test_sums_on_a_frame_with_no_valid_block_but_one(open3d: bool) -> None:
    # one valid pixel in a 1920-wide frame of invalid pixels holding inf: one block added, the rest passed by
    dbar = np.full((40, 1920), np.inf)
    valid = np.zeros(dbar.shape, bool)
    valid[17, 1001], dbar[17, 1001] = True, 0.125
    valid[39, 1919], dbar[39, 1919] = True, 3.5
    n = 2.0
    got = np.array(sor_module._mean_std(dbar, valid, n, open3d))
    want = _literal(dbar, valid, n, open3d)
    assert np.array_equal(got.view(np.uint64), want.view(np.uint64)), (got, want)
