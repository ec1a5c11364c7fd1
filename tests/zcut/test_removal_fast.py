"""The removal's fast path (issue 32) against its previous implementation, kept as ``reference=True``.

Every class mask, the height image, the cloud, rim, floor, tolerance, residual and radius bit for bit,
and the frame tolerance's residuals, on: hand-made synthetic logs of several part kinds and seeds (their
piles lie against the bin's walls), a small ray-traced frame, frames with large invalid regions and
degenerate ones (all NaN, one valid pixel, 3 x 3), in both modes and with the stragglers off.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from removal_inputs import located_removal as _inputs

from replay.synth.log import write_synthetic_log
from replay.synth.raytrace import write_raytraced_log
from zcut.bin_check import check_bin_removal
from zcut.params import RemovalParams
from zcut.removal import (
    coherent_residuals,
    frame_tolerance,
    prepare_removal_index,
    remove_table_and_bin,
    surface_residuals,
)

SIZE = (150, 200)
FIELDS = ("table", "easy_outliers", "bin_points", "zone", "height_mm", "xyz", "rim_m", "floor_m", "tolerance_mm",
          "residual_mm", "radius_mm")


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """Synthetic logs of four part kinds and seeds, and a ray-traced one, with their frames located."""
    d = tmp_path_factory.mktemp("removal_fast")
    made = {}
    for kind, seed in (("zinc_nuts", 3), ("rods", 5), ("spheres", 9), ("sprockets", 11)):
        made[f"{kind}-{seed}"] = _inputs(write_synthetic_log(d / f"{kind}.mcap", kind=kind, frames=2, seed=seed,
                                                             size=SIZE))
    made["spheres-walls"] = _inputs(write_synthetic_log(d / "walls.mcap", kind="spheres", frames=2, seed=13, size=SIZE,
                                                        pile="walls"))
    made["raytraced"] = _inputs(write_raytraced_log(d / "rt.mcap", kind="zinc_nuts", frames=1, seed=4, size=(120, 160)))
    return made


PARAMS = {
    "robust": {},
    "robust-no-stragglers": {"straggler_mm": 0.0},
    "robust-global-bound": {"straggler_bound": "global"},
    "robust-below-rim-bound": {"straggler_bound": "below_rim"},
    # the rim's band 40 mm deep: the walls' upper stragglers unbounded, the lower ones bounded
    "robust-below-rim-deep": {"straggler_bound": "below_rim", "rim_offset_mm": 40.0},
    "paper": {"mode": "paper"},
    "paper-stragglers": {"mode": "paper", "straggler_mm": 2.0, "straggler_neighbours": 3},
    "paper-no-stragglers": {"mode": "paper", "straggler_mm": 0.0},
    "robust-fixed-tolerance": {"tolerance_mm": 2.0, "straggler_neighbours": 5},
    # τ near its maximum: the bin test's radius near the grid's cell, the stragglers' beyond it
    "robust-wide-tolerance": {"min_tolerance_mm": 7.5, "straggler_neighbours": 2},
}


def _assert_same(fast, ref, what=""):
    for f in FIELDS:
        a, b = getattr(fast, f), getattr(ref, f)
        assert np.asarray(a).dtype == np.asarray(b).dtype and np.shape(a) == np.shape(b), f"{what} {f}"
        assert np.array_equal(a, b, equal_nan=True), f"{what} {f}: {int(np.sum(a != b))} differ"
    assert np.array_equal(fast.up_cam, ref.up_cam)


def _both(xyz, fp, index, T, ring):
    fast = remove_table_and_bin(xyz, fp, index=index, T_cam_bin=T, ring=ring)
    ref = remove_table_and_bin(xyz, fp, index=index, T_cam_bin=T, ring=ring, reference=True)
    return fast, ref


@pytest.mark.parametrize("name", list(PARAMS))
def test_fast_equals_reference_on_synthetic_logs(logs, name):
    for log, (model, params, frames) in logs.items():
        index = prepare_removal_index(model, dataclasses.replace(params, **PARAMS[name]))
        for i, (xyz, fp, ring, T) in enumerate(frames):
            fast, ref = _both(xyz, fp, index, T, ring)
            _assert_same(fast, ref, f"{log} frame {i} {name}")
            assert fast.bin_points.any() and fast.zone.any()


@pytest.mark.parametrize("extra", [{}, {"mode": "paper", "delta_mm": 0.5}])
def test_fast_equals_reference_with_a_model_without_normals(logs, extra):
    """Point distances instead of plane distances: the first point that passes (the previous pixel's, tried
    first) decides as any other would."""
    for log in ("zinc_nuts-3", "sprockets-11"):
        model, params, frames = logs[log]
        index = prepare_removal_index(dataclasses.replace(model, normals=None), dataclasses.replace(params, **extra))
        for i, (xyz, fp, ring, T) in enumerate(frames):
            fast, ref = _both(xyz, fp, index, T, ring)
            _assert_same(fast, ref, f"{log} frame {i} {extra}")
            assert fast.bin_points.any()


@pytest.mark.parametrize("bound", [{}, {"straggler_bound": "below_rim", "rim_offset_mm": 40.0}])
def test_fast_equals_reference_with_large_invalid_regions(logs, bound):
    model, params, frames = logs["zinc_nuts-3"]
    index = prepare_removal_index(model, dataclasses.replace(params, **bound))
    xyz, fp, ring, T = frames[0]
    rng = np.random.default_rng(2)
    for holes in ("left half", "bands", "speckle"):
        a = xyz.copy()
        if holes == "left half":
            a[:, : a.shape[1] // 2] = np.nan
        elif holes == "bands":
            a[::7] = np.nan
            a[:, 40:90] = np.nan
        else:
            a[rng.random(a.shape[:2]) < 0.4] = np.nan
            a[rng.random(a.shape[:2]) < 0.02, 1] = np.inf  # one non-finite coordinate: invalid
        with np.errstate(invalid="ignore"):
            fast, ref = _both(a, fp, index, T, ring)
        _assert_same(fast, ref, holes)


def test_fast_equals_reference_on_degenerate_frames(logs):
    model, params, frames = logs["rods-5"]
    xyz, fp, ring, T = frames[0]
    for extra in ({}, {"mode": "paper"}, {"straggler_mm": 0.0}):
        index = prepare_removal_index(model, dataclasses.replace(params, **extra))
        nan = np.full_like(xyz, np.nan)
        one = nan.copy()
        r, c = np.argwhere(ring)[len(np.argwhere(ring)) // 2]
        one[r, c] = xyz[r, c]
        tiny = np.ascontiguousarray(xyz[r - 1:r + 2, c - 1:c + 2])
        cases = [(nan, fp, ring), (one, fp, ring), (one, np.ones_like(fp), None),
                 (tiny, np.ones((3, 3), bool), np.ones((3, 3), bool)), (tiny, np.zeros((3, 3), bool), None),
                 (xyz, np.zeros_like(fp), np.zeros_like(ring))]
        for k, (a, f, g) in enumerate(cases):
            fast, ref = _both(a, f, index, T, g)
            _assert_same(fast, ref, f"case {k} {extra}")


def test_residuals_equal_reference(logs):
    """The frame tolerance, its surface residuals and the bin check's coherent residuals (8 neighbours)."""
    for log, (model, params, frames) in logs.items():
        index = prepare_removal_index(model, params)
        for xyz, _, ring, T in frames:
            fast, ref = frame_tolerance(xyz, ring, index, T), frame_tolerance(xyz, ring, index, T, reference=True)
            assert (fast.tolerance_mm, fast.n_pixels, fast.n_coherent, fast.n_off_field) == \
                (ref.tolerance_mm, ref.n_pixels, ref.n_coherent, ref.n_off_field), log
            assert np.array_equal([fast.residual_mm, fast.reach_mm, fast.sigma_mm, fast.pixel_rad],
                                  [ref.residual_mm, ref.reach_mm, ref.sigma_mm, ref.pixel_rad], equal_nan=True)
            assert np.isfinite(fast.sigma_mm) and np.isfinite(fast.pixel_rad), log  # the stragglers' bound is known
            pixels = np.flatnonzero(ring | np.roll(ring, 3, axis=1))[::3]
            for a, b in zip(coherent_residuals(xyz, ring, pixels, index, T),
                            coherent_residuals(xyz, ring, pixels, index, T, reference=True), strict=True):
                assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True), log


def test_the_check_reads_the_removals_residuals(logs):
    """The bin check gets the residuals the removal measured (the same arrays), and the same verdict."""
    model, params, frames = logs["spheres-9"]
    index = prepare_removal_index(model, params)
    xyz, fp, ring, T = frames[0]
    fast, ref = _both(xyz, fp, index, T, ring)
    assert fast.surface is not None and ref.surface is None
    kept = surface_residuals(xyz, ring, index, T, removal=fast)
    assert kept[0] is fast.surface.residuals
    again = surface_residuals(xyz, ring, index, T)
    for a, b in zip(kept, again, strict=True):
        assert np.array_equal(a, b, equal_nan=True)
    assert surface_residuals(xyz, ring.copy(), index, T, removal=fast)[0] is not fast.surface.residuals
    c_fast, c_ref = (check_bin_removal(r, ring, params=params, band_mm=10.0, xyz=xyz, index=index, T_cam_bin=T)
                     for r in (fast, ref))
    assert (c_fast.value, c_fast.flagged, c_fast.reason) == (c_ref.value, c_ref.flagged, c_ref.reason)


def test_params_cover_both_modes():
    assert RemovalParams().robust and not RemovalParams(mode="paper").robust


def test_the_checks_candidates_equal_numpy(logs):
    """The bin check's candidates and counts (two kernel passes) against the numpy expressions they replace,
    on the removals of every log and on nasty inputs: NaN and float32 heights, values exactly on the
    threshold, no zone, an empty ring, a 1 x N image."""
    from zcut.bin_check import _candidates, _candidates_numpy

    def same(ring, easy, zone, h, band):
        a, b = _candidates(ring, easy, zone, h, band), _candidates_numpy(ring, easy, zone, h, band)
        assert np.array_equal(a[0], b[0]) and a[1:] == b[1:], (a[1:], b[1:])
        return b

    for model, params, frames in logs.values():
        index = prepare_removal_index(model, params)
        for xyz, fp, ring, T in frames:
            rem = remove_table_and_bin(xyz, fp, index=index, T_cam_bin=T, ring=ring)
            for band in (0.0, 2.0, 10.0, 1e9):
                same(ring, rem.easy_outliers, rem.zone, rem.height_mm, band)
            same(ring, rem.easy_outliers, np.zeros_like(rem.zone), rem.height_mm, 10.0)
            same(np.zeros_like(ring), rem.easy_outliers, rem.zone, rem.height_mm, 10.0)
            h = rem.height_mm.copy()
            top = float(np.max(h[rem.zone]))
            ring_zone = np.argwhere(ring & rem.zone)
            if len(ring_zone):  # a ring pixel exactly on the threshold
                r, c = ring_zone[0]
                h[r, c] = top - 3.0
            got = same(ring, rem.easy_outliers, rem.zone, h, 3.0)
            assert len(ring_zone) == 0 or got[0][r, c]
            same(ring, rem.easy_outliers, rem.zone, h.astype(np.float32), 3.0)  # compared in float32, as numpy does
            nan = h.copy()
            nan.reshape(-1)[np.flatnonzero(rem.zone)[:: 7]] = np.nan  # a NaN in the zone: np.max says NaN, no zone candidate
            same(ring, rem.easy_outliers, rem.zone, nan, 3.0)
    rng = np.random.default_rng(7)
    for shape in ((1, 50), (50, 1), (1, 1), (0, 4)):
        masks = [rng.random(shape) < 0.5 for _ in range(3)]
        same(*masks, rng.normal(size=shape), 0.5)
    # a threshold (1 + 5e-8) that float32 rounds onto the heights (1.0): numpy compares in float32, so all count
    h32 = np.full((2, 3), np.float32(1.0))
    ones = np.ones((2, 3), bool)
    assert same(ones, ~ones, ones, h32, -5e-8)[1] == 6
    assert same(ones, ~ones, ones, h32.astype(np.float64), -5e-8)[1] == 0


def test_nearest_points_equal_the_tree(logs):
    """The residuals' nearest-point query (the cell grid, each search starting from the previous row's
    nearest point; the tree where the two could differ) against the model's KD-tree, distances and points
    bit for bit: ring pixels in image order, shuffled and every 7th, random points in and around the model, points
    on cell faces, corners and middles, the model's own points (distance 0, ties) and points jittered off them or
    half a cell off (the faces of the 2 x 2 x 2 block that answers most rows), points in the grid's outer cells, in
    blocks and alone."""
    from zcut.removal import _nearest_points

    rng = np.random.default_rng(11)
    for log, (model, params, frames) in logs.items():
        index = prepare_removal_index(model, params)
        g, ub = index.nearest, params.max_tolerance_mm / 1000.0
        xyz, _, ring, T = frames[0]
        pts = xyz[ring].astype(np.float64)
        ring_pts = (pts - T[:3, 3]) @ T[:3, :3]
        lo, hi = g.origin, g.origin + g.dims * g.cell
        own = model.points[rng.choice(len(model.points), 500)]
        cases = {"ring": ring_pts, "random": rng.uniform(lo - 0.02, hi + 0.02, (3000, 3)),
                 "faces": np.round((ring_pts[:800] - g.origin) / g.cell) * g.cell + g.origin,
                 "model": own, "jitter": own + rng.normal(0, 1e-3, own.shape), "one": ring_pts[:1],
                 "reversed": ring_pts[::-1],
                 # rows whose previous row's point lies too far: the row's own cell bounds the search
                 "shuffled": ring_pts[rng.permutation(len(ring_pts))], "every 7th": ring_pts[::7],
                 "cell corners": np.floor((own - g.origin) / g.cell) * g.cell + g.origin,
                 # the block of 2 x 2 x 2 cells: points half-way across a cell (where the block's side switches),
                 # its faces a nearest distance away, and the grid's outer cells (no block there)
                 "cell middles": (np.floor((ring_pts[:800] - g.origin) / g.cell) + 0.5) * g.cell + g.origin,
                 "block faces": own + rng.choice([-1.0, 1.0], own.shape) * (g.cell / 2 - 1e-13),
                 "outer cells": g.origin + g.cell * (rng.uniform(0, 1, (600, 3)) + np.where(
                     rng.random((600, 3)) < 0.5, 0.0, g.dims - 1.0) * (rng.random((600, 3)) < 0.7)),
                 "next to outer cells": g.origin + g.cell * (rng.uniform(0, 1, (600, 3)) + np.where(
                     rng.random((600, 3)) < 0.5, 1.0, g.dims - 2.0))}
        for name, q in cases.items():
            q = np.ascontiguousarray(q)
            d, j = _nearest_points(q, index)
            d_t, j_t = index.tree.query(q, k=1, distance_upper_bound=ub)
            assert np.array_equal(d, d_t) and np.array_equal(j, j_t), f"{log} {name}"


def test_the_field_fit_equals_the_reference(logs):
    """The tolerance's residual field (:func:`zcut.removal._fit_field`, kernels around numpy's products) and the
    pixels it leaves out (:func:`zcut.removal._off_field_fast`) against :func:`fit_residual_field` and
    :func:`zcut.removal._off_field`, bit for bit: on every log's measured pixels, and with blocks of them moved
    1.5-6 mm off the field (parts leaning on a wall: many left out), on a subsample too small to fit, and
    without normals."""
    from zcut.removal import (
        COHERENCE_MM,
        MAX_RESIDUAL_PX,
        _around_median,
        _field_inputs,
        _fit_field,
        _off_field,
        _off_field_fast,
        _own_and_neighbours,
        _query,
        _sample_ring,
        fit_residual_field,
    )

    rng = np.random.default_rng(5)
    n_off = 0
    for log, (model, params, frames) in logs.items():
        index = prepare_removal_index(model, params)
        for xyz, _, ring, T in frames:
            flat, want, own_at, nb_at = _sample_ring(xyz, ring, MAX_RESIDUAL_PX)
            q0 = _query(xyz, want, index, T)
            for shift in (None, 1.5, 6.0):
                q = q0
                if shift is not None:  # blocks of the measured pixels' residuals moved off the field
                    signed = q.signed_m.copy()
                    blocks = rng.choice(len(signed), max(1, len(signed) // 200), replace=False)
                    for b in blocks:
                        signed[b: b + 40] += shift / 1000.0
                    q = dataclasses.replace(q, signed_m=signed, residual_mm=np.abs(signed) * 1000.0)
                res, nbr = _own_and_neighbours(q.residual_mm, own_at, nb_at)
                with np.errstate(invalid="ignore"):
                    coherent = np.isfinite(res) & (np.abs(res - _around_median(nbr)) <= COHERENCE_MM)
                for normals in (model.normals, None):
                    fast = _off_field_fast(q, own_at, nb_at, coherent, normals)
                    ref = _off_field(q.signed_m, q.p_bin, q.nearest_j, own_at, nb_at, coherent, normals)
                    assert np.array_equal(fast, ref), (log, shift)
                    n_off += int(np.count_nonzero(fast))
                rows, r, p, n = _field_inputs(q.signed_m, q.p_bin, q.nearest_j, own_at, model.normals)
                for k in (len(r), 49, 60):  # all, too few to fit, just enough
                    got = _fit_field(r[:k], p[:k], n[:k])
                    want_fit = fit_residual_field(r[:k], p[:k], n[:k], normal_equations=True, reference=True)
                    assert (got is None) == (want_fit is None), (log, shift, k)
                    if got is not None and want_fit is not None:
                        coef, centre, _, _ = want_fit
                        assert np.array_equal(got[0], coef) and np.array_equal(got[1], centre), (log, shift, k)
    assert n_off > 100  # the moved blocks were left out


def test_the_ring_sample_equals_numpy():
    """The tolerance's sample, its ring neighbours and the queried pixels with their positions
    (:func:`zcut.removal._sample_ring`: the ring read a word at a time, five sorted lists merged) against the
    reference's numpy expressions (:func:`_ring_sample`, :func:`_ring_neighbours`, ``np.unique``,
    ``np.searchsorted``): random rings of every density on images whose pixel count is and is not a multiple
    of 8, with NaN and infinite points, every pixel sampled or every few, a 1 x N and an N x 1 image, an empty
    ring, a ring slice that is not contiguous."""
    from zcut.removal import _ring_neighbours, _ring_sample, _sample_ring

    rng = np.random.default_rng(3)
    cases = []
    for _ in range(150):
        h, w = int(rng.integers(1, 40)), int(rng.integers(1, 50))
        xyz = rng.normal(size=(h, w, 3)).astype(np.float32 if rng.random() < 0.5 else np.float64)
        xyz[rng.random((h, w)) < 0.2 * rng.random()] = np.nan
        xyz[rng.random((h, w)) < 0.02, 2] = np.inf
        cases.append((xyz, rng.random((h, w)) < rng.random(), int(rng.integers(1, 200))))
    big = rng.normal(size=(64, 96, 3))
    cases += [(big, np.zeros((64, 96), bool), 50), (big, np.ones((64, 96), bool), 10**6),
              (big[:, :7], (rng.random((64, 96)) < 0.5)[:, :7], 40)]
    for xyz, ring, max_px in cases:
        flat, want, own_at, nb_at = _sample_ring(xyz, ring, max_px)
        ref_flat = _ring_sample(xyz, ring, max_px)
        nb = _ring_neighbours(xyz.shape[:2], ring, ref_flat, 4)
        ref_want = np.unique(np.concatenate([ref_flat, nb[nb >= 0]]))
        assert np.array_equal(flat, ref_flat) and np.array_equal(want, ref_want)
        assert np.array_equal(own_at, np.searchsorted(ref_want, ref_flat))
        assert np.array_equal(nb_at, np.where(nb >= 0, np.searchsorted(ref_want, np.where(nb >= 0, nb, 0)), -1))

