"""``zcut.binmask._component_stats`` (the statistics from the runs of the grown image, eight bytes at a time
over whole words) against OpenCV's own ``connectedComponentsWithStats``, and the bin mask against its reference
on images whose rows are not whole words."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from zcut.binmask import _component_stats, _row_words, bin_mask, bin_mask_reference
from zcut.params import BinMaskParams


def _stats_of(grown: np.ndarray, words: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    n, labels, stats, _ = cv2.connectedComponentsWithStats(grown, connectivity=8, ltype=cv2.CV_32S)
    got = _component_stats(labels, grown, _row_words(grown) if words is None else words, n)
    want = stats.astype(np.int64)
    want[want[:, 4] == 0] = 0  # a label without pixels (0 in an image without background): zeros, as bin_mask had
    return got, want


def _images() -> list[np.ndarray]:
    rng = np.random.default_rng(32_105)
    out = []
    for h, w in ((1, 1), (1, 8), (1, 9), (7, 1), (5, 16), (33, 64), (40, 61), (64, 200), (97, 127), (120, 640)):
        for density in (0.0, 0.02, 0.5, 0.97, 1.0):
            out.append((rng.random((h, w)) < density).astype(np.uint8))
        # long runs: blocks of ones and zeros whose edges fall anywhere in a word
        img = np.zeros((h, w), np.uint8)
        for _ in range(6):
            r0, c0 = rng.integers(0, h), rng.integers(0, w)
            img[r0:r0 + rng.integers(1, h + 1), c0:c0 + rng.integers(1, w + 1)] = 1
        out.append(img)
    return out


@pytest.mark.parametrize("img", _images(), ids=lambda a: f"{a.shape[0]}x{a.shape[1]}-{int(a.sum())}")
def test_the_runs_of_the_grown_image_give_opencvs_statistics(img: np.ndarray) -> None:
    got, want = _stats_of(img)
    assert np.array_equal(got, want)
    # the same without the words (bytes only), and with other nonzero values than 1 (never a whole word of ones)
    got, _ = _stats_of(img, np.empty((img.shape[0], 0), np.uint64))
    assert np.array_equal(got, want)
    got, want = _stats_of(img * np.uint8(255))
    assert np.array_equal(got, want)


def test_rows_that_are_not_aligned_words_are_read_as_bytes() -> None:
    rng = np.random.default_rng(7)
    buf = np.zeros(1 + 48 * 64, np.uint8)
    img = buf[1:].reshape(48, 64)  # whole words a row, but not on a word's address
    img[:] = rng.random((48, 64)) < 0.6
    assert _row_words(img).shape == (48, 0)
    assert _row_words(np.zeros((4, 12), np.uint8)).shape == (4, 0)
    assert _row_words(np.zeros((4, 16), np.uint8)).shape == (4, 2)
    got, want = _stats_of(img)
    assert np.array_equal(got, want)


@pytest.mark.parametrize("shape", [(48, 61), (61, 83), (120, 160)])
def test_bin_mask_equals_the_reference_on_rows_of_any_width(shape: tuple[int, int]) -> None:
    rng = np.random.default_rng(11)
    h, w = shape
    rgb = np.full((h, w, 3), 40, np.uint8)
    rgb[h // 6:h - h // 6, w // 6:w - w // 6] = 220  # a bright bin
    rgb[h // 3:h - h // 3, w // 3:w - w // 3] = 30  # its dark inside
    speckle = rng.random((h, w)) < 0.05
    rgb[speckle] = rng.integers(0, 256, (int(speckle.sum()), 3), dtype=np.uint8)
    for p in (BinMaskParams(), BinMaskParams(dilate_px=0), BinMaskParams(min_area_frac=0.0)):
        a, b = bin_mask(rgb, params=p), bin_mask_reference(rgb, params=p)
        for name in ("mask", "walls", "found", "area_px", "n_components", "centroid_rc", "bbox_rc", "covers_centre"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
