"""The suspects' sixth round (issue 32, item 5): suspects()' fused kernels, the lookup of σ̂ in place and the
edge-aware distance at a list of pixels give the numpy and the calls they replace bit for bit (the whole
call against ``suspects_reference``: tests/zcut/test_suspects_fast.py)."""

from __future__ import annotations

import importlib

import numpy as np
from scipy import ndimage
from test_suspects import random_heights

from zcut.edge_surface import EdgeSurfaceParams
from zcut.suspects import ABOVE_RIM, DETECTORS, FLOATING, PATCH, RESIDUAL_UP, local_gaps
from zcut.suspects.detectors import label_medians
from zcut.suspects.surfaces import lazy_surfaces

union = importlib.import_module("zcut.suspects.union")


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal values, NaN where NaN, and the signs of zeros."""
    return bool(np.array_equal(a, b, equal_nan=True) and np.array_equal(np.signbit(a), np.signbit(b)))


def test_interp_in_place_equals_numpy_interp() -> None:
    """σ̂'s lookup against ``np.interp(np.nan_to_num(x, nan=xp[0]), xp, fp)``: one to 32 heights, ties among
    them (-0.0 and 0.0 too), values on them, beyond them, NaN, ±inf, ±0, huge scales, NaN and inf in fp."""
    rng = np.random.default_rng(61)
    for _ in range(3000):
        n = int(rng.choice([1, 2, 3, 4, 5, 8, 32]))
        xp = rng.normal(0, 50, n)
        if rng.random() < 0.4:
            xp = np.round(xp / 5) * 5
        if rng.random() < 0.1:
            xp[:] = xp[0]
        if rng.random() < 0.2:
            xp[rng.random(n) < 0.3] = float(rng.choice([0.0, -0.0]))
        if rng.random() < 0.1:
            xp = xp * 1e300
        xp = np.sort(xp)
        fp = rng.uniform(0, 3, n)
        if rng.random() < 0.3:
            fp = np.round(fp)
        if rng.random() < 0.1:
            fp[rng.random(n) < 0.3] = np.inf
        if rng.random() < 0.05:
            fp[rng.random(n) < 0.3] = np.nan
        m = int(rng.integers(1, 400))
        x = rng.normal(0, 60, m) * (1e300 if rng.random() < 0.05 else 1.0)
        k = rng.random(m)
        x[k < 0.2] = rng.choice(xp, int((k < 0.2).sum()))
        x[(k >= 0.2) & (k < 0.25)] = np.nan
        x[(k >= 0.25) & (k < 0.28)] = np.inf
        x[(k >= 0.28) & (k < 0.31)] = -np.inf
        x[(k >= 0.31) & (k < 0.33)] = -0.0
        x[(k >= 0.33) & (k < 0.35)] = 0.0
        if m % 2 == 0:
            x = x.reshape(2, -1)
        want = np.interp(np.nan_to_num(x, nan=xp[0]), xp, fp)
        got = x.copy()
        union._interp_in_place(got, xp, fp)
        assert _same_bits(got, want), (xp, fp)


def test_sigma_px_equals_the_lookup_it_replaces() -> None:
    """``_sigma_px`` (the lookup in place) against ``profile.sigma_at(local_height(context))``, with real
    profiles of random scenes, and profiles that are not a profile's (unsorted, NaN: numpy's lookup)."""
    from zcut.suspects import noise_profile
    from zcut.suspects.noise import NoiseProfile, local_height

    rng = np.random.default_rng(62)
    bins = []
    for t in range(20):
        h = random_heights(rng, int(rng.integers(20, 160)), int(rng.integers(20, 220))).astype(np.float64)
        judged = np.isfinite(h)
        profile = noise_profile(h, judged)
        if t % 10 == 7 and profile.heights_mm.size >= 2:
            profile = NoiseProfile(profile.heights_mm[::-1].copy(), profile.sigma_mm, profile.step_mm)
        if t % 10 == 9 and profile.heights_mm.size >= 1:
            xp = profile.heights_mm.copy()
            xp[0] = np.nan
            profile = NoiseProfile(xp, profile.sigma_mm, profile.step_mm)
        want = profile.sigma_at(local_height(h))
        assert _same_bits(union._sigma_px(profile, h), want)
        bins.append(profile.heights_mm.size)
    assert min(bins) <= 2 and max(bins) >= 16


def test_fused_codes_gaps_and_tables_equal_the_numpy_they_replace() -> None:
    """``_codes_and_masks``, ``_gap_kernel`` + ``_residual_gaps`` and ``_group_tables`` against the whole-frame
    numpy of the previous ``suspects()`` (codes, mask, the residual detectors' pixels, :func:`local_gaps`,
    the group sizes, bits, boxes and gap medians) on random codes, masks, residuals and groups."""
    rng = np.random.default_rng(63)
    for t in range(60):
        H, W = (int(rng.integers(1, 6)), int(rng.integers(1, 6))) if t % 6 == 0 else \
            (int(rng.integers(10, 60)), int(rng.integers(10, 70)))
        shape = (H, W)
        h = random_heights(rng, H, W).astype(np.float64)
        if t % 5 == 1:
            h[rng.random(shape) < 0.05] = np.inf
        valid = rng.random(shape) < 0.9
        easy = valid & (rng.random(shape) < 0.05)
        codes0 = np.where(rng.random(shape) < 0.2, rng.choice([2, 4, 8, 16], shape), 0).astype(np.uint8)
        off = codes0 > 0
        filled = off | (rng.random(shape) < 0.05)
        floating = rng.random(shape) < 0.05
        patch = rng.random(shape) < 0.05
        residual = rng.normal(0, 3, shape)
        residual[rng.random(shape) < 0.1] = float(rng.choice([np.inf, np.nan, -0.0]))

        codes = codes0.copy()
        codes[filled & ~off] = RESIDUAL_UP
        codes[floating] |= FLOATING
        codes[easy] |= ABOVE_RIM
        codes[patch] |= PATCH
        mask = codes > 0
        by_residual = off & ((codes & (FLOATING | ABOVE_RIM)) == 0) & np.isfinite(residual)
        gap = local_gaps(h, mask & ~by_residual & ~floating, valid & ~mask)
        gap[by_residual] = residual[by_residual]

        got_codes = codes0.copy()
        outs = [np.empty(shape, bool) for _ in range(4)]
        n_res = union._codes_and_masks(got_codes, off, filled, floating, easy, patch, residual, valid, h, *outs)
        got_mask, got_by, gap_at, surface = outs
        np.testing.assert_array_equal(got_codes, codes)
        np.testing.assert_array_equal(got_mask, mask)
        np.testing.assert_array_equal(got_by, by_residual)
        assert n_res == int(by_residual.sum())
        got_gap = np.empty(shape)
        union._gap_kernel(h, gap_at, surface, union.GAP_MIN_PIXELS, union.GAP_MAX_RADIUS, got_gap)
        at = union._residual_gaps(got_by, residual, got_gap, n_res)
        np.testing.assert_array_equal(at, np.flatnonzero(by_residual))
        assert _same_bits(got_gap, gap)

        n = int(rng.integers(0, 12))
        groups = np.where(rng.random(shape) < 0.3, rng.integers(1, n + 1, shape), 0).astype(np.int32) if n else \
            np.zeros(shape, np.int32)
        n = int(np.unique(groups[groups > 0]).size)  # dense labels 1..n, as group_suspects gives
        groups = np.searchsorted(np.unique(np.concatenate([[0], groups.ravel()])), groups).astype(np.int32)
        size, bits, bbox, in_group = union._group_tables(groups, codes, n)
        np.testing.assert_array_equal(size, np.bincount(groups.ravel(), minlength=n + 1)[1:].astype(np.int64))
        g_of, c_of = groups.ravel()[np.flatnonzero(groups)], codes.ravel()[np.flatnonzero(groups)]
        want_bits = np.zeros(n, np.uint8)
        for b in range(len(DETECTORS)):
            want_bits |= ((np.bincount(g_of, weights=(c_of >> b) & 1, minlength=n + 1)[1:] > 0) << b).astype(np.uint8)
        np.testing.assert_array_equal(bits, want_bits)
        want_box = np.array([[s[0].start, s[1].start, s[0].stop, s[1].stop]
                             for s in ndimage.find_objects(groups, max_label=n)], np.int32).reshape(-1, 4)
        assert bbox.dtype == np.int32
        np.testing.assert_array_equal(bbox, want_box)
        np.testing.assert_array_equal(in_group, np.flatnonzero(groups))
        if n:
            assert _same_bits(label_medians(gap.ravel()[in_group], groups.ravel()[in_group], n),
                              label_medians(gap, groups, n))


def test_distance_at_equals_the_distance_there() -> None:
    """``LazySurfaces.distance_at(flat)`` against ``distance(where)`` read at those pixels (fresh surfaces each)."""
    rng = np.random.default_rng(64)
    finite = 0
    for _ in range(8):
        H, W = int(rng.integers(20, 60)), int(rng.integers(20, 70))
        h = random_heights(rng, H, W).astype(np.float64)
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
        a = np.stack([xx * 0.8, yy * 0.8, 600.0 - h], axis=2)
        a[~np.isfinite(h)] = np.nan
        valid = np.ascontiguousarray(np.isfinite(a).all(axis=2))
        where = valid & (rng.random((H, W)) < 0.2)
        want = lazy_surfaces(a, valid, EdgeSurfaceParams()).distance(where)
        got = lazy_surfaces(a, valid, EdgeSurfaceParams()).distance_at(np.flatnonzero(where))
        assert _same_bits(got, want.ravel()[np.flatnonzero(where)])
        finite += int(np.isfinite(got).sum())
    assert finite > 0
