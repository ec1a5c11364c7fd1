"""The bounded distance transform of zcut.binmask.bin_pixels on crops exactly 1448 px wide, the widest its
error bound takes (``_EXACT_MAX_W``; 4 W^2 2^-23 < 1 holds for W <= 1448): bin_pixels against
bin_pixels_reference (OpenCV's transform) on footprints whose crop is 1448 px wide, on OpenCV's default threads
and on one (IPP's transform, taken within its error bound); OpenCV's own row pass there equals the exact
Euclidean distances (multi-threaded), and IPP's stays within ``_IPP_REL_ERROR`` of them (one thread)."""

from __future__ import annotations

import cv2
import numpy as np

from zcut.binmask import (
    _EXACT_MAX_W,
    _IPP_REL_ERROR,
    BinMaskResult,
    _bounded_shape,
    bin_pixels,
    bin_pixels_reference,
)

W = 1448


def _wide_footprints(rng: np.random.Generator):
    """Footprints whose bin_pixels crop (the box plus one pixel each side, clipped to the image) is W wide:
    in an image W wide (box from edge to edge) and in a wider one (box W - 2 wide, one pixel of table each
    side), rectangles, tilted ellipses, notched and random blobs, with pinholes."""
    for h, img_w, x0, bw in ((300, W, 0, W), (400, 1920, 236, W - 2), (1200, 1920, 200, W - 2)):
        yy, xx = np.mgrid[0:h, 0:bw]
        for k in range(4):
            if k == 0:
                m = (yy > h * 0.1) & (yy < h * 0.9)
                m[:, [0, -1]] = True
            elif k == 1:
                a = np.radians(rng.uniform(0, 180))
                u = (xx - bw / 2) * np.cos(a) + (yy - h / 2) * np.sin(a)
                v = -(xx - bw / 2) * np.sin(a) + (yy - h / 2) * np.cos(a)
                m = (u / (0.5 * bw)) ** 2 + (v / (0.45 * h)) ** 2 < 1
                m[h // 2, [0, -1]] = True
            elif k == 2:
                m = (yy < h * 0.8).copy()
                m[int(h * 0.3):int(h * 0.35), int(bw * 0.5):] = False
            else:
                m = cv2.GaussianBlur(rng.random((h, bw)).astype(np.float32), (0, 0), 6) > 0.5
                m[:, [0, -1]] = True
            m = m & ~(rng.random(m.shape) < 0.0005)
            full = np.zeros((h, img_w), bool)
            full[:, x0:x0 + bw] = m
            yield full


def _cases(rng: np.random.Generator):
    for m in _wide_footprints(rng):
        rows, cols = np.nonzero(m)
        bbox = (int(rows.min()), int(cols.min()), int(rows.max()) + 1, int(cols.max()) + 1)
        crop_w = min(bbox[3] + 1, m.shape[1]) - max(bbox[1] - 1, 0)
        assert crop_w == W and _bounded_shape((m.shape[0], crop_w))
        walls = m & (rng.random(m.shape) < 0.7)
        r = BinMaskResult(m, walls, True, int(m.sum()), 1, (rows.mean(), cols.mean()), bbox, True)
        xyz = np.ones((*m.shape, 3), np.float32)
        xyz[rng.random(m.shape) < 0.05] = np.nan
        yield r, xyz


def test_the_limit_is_the_bounds_own():
    assert _EXACT_MAX_W == W and 4 * W * W < 2**23 <= 4 * (W + 1) ** 2
    assert not _bounded_shape((100, W + 1))


def test_bin_pixels_on_crops_1448_wide(opencv_threads):
    rng = np.random.default_rng({"default": 91, "one": 92}[opencv_threads])
    n = 0
    for r, xyz in _cases(rng):
        for frac, least in ((0.2, 10.0), (0.07, 0.0), (0.6, 1.0), (0.01, 10.0)):
            got = bin_pixels(r, xyz, ring_frac=frac, min_ring_px=least)
            want = bin_pixels_reference(r, xyz, ring_frac=frac, min_ring_px=least)
            assert np.array_equal(got, want), (r.mask.shape, frac)
        n += 1
    assert n == 12


def _exact(fp: np.ndarray, rows: range) -> np.ndarray:
    """The exact Euclidean distance of the rows ``rows`` of ``fp`` (0/1) to its nearest zero (brute force over
    the columns' vertical distances)."""
    h, w = fp.shape
    col = np.full((h, w), np.inf)
    for c in range(w):
        zeros = np.flatnonzero(fp[:, c] == 0)
        if len(zeros):
            col[:, c] = (np.abs(np.arange(h)[:, None] - zeros[None]).min(axis=1)) ** 2
    j = np.arange(w)
    out = np.empty((len(rows), w))
    for i, r in enumerate(rows):
        out[i] = np.sqrt((col[r][None, :] + (j[:, None] - j[None, :]) ** 2.0).min(axis=1))
    return out


def test_opencvs_transform_on_crops_1448_wide(opencv_threads):
    rng = np.random.default_rng(93)
    for k in range(3):
        h = 120
        fp = (cv2.GaussianBlur(rng.random((h, W)).astype(np.float32), (0, 0), 5 + 10 * k) > 0.45).astype(np.uint8)
        fp[rng.random((h, W)) < 0.0003] = 0
        fp[:, [0, -1]] = 0
        got = cv2.distanceTransform(fp, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        rows = range(0, h, 6)
        exact = _exact(fp, rows)
        if opencv_threads == "default" and cv2.getNumThreads() > 1:  # the row pass zcut emulates: exact here
            assert np.array_equal(got[list(rows)], exact.astype(np.float32))
        else:  # IPP's: within its error bound of the exact distances
            assert np.all(np.abs(got[list(rows)] - exact) <= _IPP_REL_ERROR * exact)
