"""The removal's reads taken once (round of 2026-12-06g, h/rem10) against what they replace, bit for bit.

- :func:`zcut.removal._sample_and_steps`: the ring's sample (its words counted eight pixels at a time, the words
  whose ring pixels are all skipped passed over at once) and the pixel angle's steps taken with it, against
  :func:`zcut.removal._ring_sample` / :func:`zcut.removal._pixel_steps` of the same sample;
  :func:`zcut.removal._nonzero_bytes` against a literal count.
- :func:`zcut.removal._scatter_query` against the masked assignments it stands for, with every pixel finite (its
  points then the product's own array) and not.
- :func:`zcut.removal._nearest_again` reading the queried points against gathering them from the frame again.
- :func:`zcut.removal._straggler_first`: its row counts of passed candidates and the candidates marked tried.
- The whole removal, fast against ``reference=True`` (every class mask, the height image, the cloud, τ, the
  radius, rim, floor, up) on synthetic logs of three kinds (a walls pile and a ray-traced frame among them), in
  parameter sets where stragglers pass and where none does, with large invalid regions and degenerate frames
  (all NaN, one valid pixel, one row, one column).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import pytest
from removal_inputs import located_removal as _inputs

from replay.synth.log import write_synthetic_log
from replay.synth.raytrace import write_raytraced_log
from zcut.removal import (
    MAX_RESIDUAL_PX,
    _nearest_again,
    _nonzero_bytes,
    _pixel_steps,
    _query,
    _ring_sample,
    _sample_and_steps,
    _sample_ring,
    _scatter_query,
    _straggler_first,
    prepare_removal_index,
    remove_table_and_bin,
)

FIELDS = ("table", "easy_outliers", "bin_points", "zone", "height_mm", "xyz", "rim_m", "floor_m", "up_cam",
          "tolerance_mm", "residual_mm", "radius_mm")


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("removal_reads_once")
    return {"zinc_nuts": _inputs(write_synthetic_log(d / "zn.mcap", kind="zinc_nuts", frames=2, seed=21,
                                                     size=(160, 208))),
            "walls": _inputs(write_synthetic_log(d / "walls.mcap", kind="spheres", frames=1, seed=22, size=(150, 200),
                                                 pile="walls")),
            "raytraced": _inputs(write_raytraced_log(d / "rt.mcap", kind="zinc_nuts", frames=1, seed=23,
                                                     size=(120, 160)))}


def test_nonzero_bytes():
    rng = np.random.default_rng(1)
    words = [np.uint64(0), np.uint64(2**64 - 1)]
    for pos in range(8):
        for v in range(256):
            words.append(np.uint64(v << (8 * pos)))
    words += list(rng.integers(0, 2**63, 2000, dtype=np.uint64) * np.uint64(2))
    bytes_ = rng.integers(0, 3, (2000, 8), dtype=np.uint8) * rng.integers(0, 256, (2000, 8), dtype=np.uint8)
    words += list(bytes_.view(np.uint64).reshape(-1))
    for w in words:
        want = int(np.count_nonzero(np.array([w], np.uint64).view(np.uint8)))
        assert int(_nonzero_bytes(w)) == want, hex(int(w))


def _clouds(rng):
    """Clouds, rings and sample sizes: pinhole clouds with NaN, infinite and zero coordinates, float32 and float64,
    rings of every density, images whose pixel count is and is not a multiple of 8, one row, one column."""
    out = []
    for k in range(120):
        h, w = int(rng.integers(1, 40)), int(rng.integers(1, 60))
        if k % 10 == 0:
            h = 1
        elif k % 10 == 1:
            w = 1
        v, u = np.mgrid[0:h, 0:w].astype(np.float64)
        z = 0.8 + 0.2 * rng.random((h, w))
        xyz = np.stack([(u - w / 2) / 500 * z, (v - h / 2) / 500 * z, z], axis=-1)
        xyz[rng.random((h, w)) < 0.3 * rng.random()] = np.nan
        xyz[rng.random((h, w)) < 0.03, 2] = 0.0  # a division by 0: inf or NaN, left out
        xyz[rng.random((h, w)) < 0.02, int(rng.integers(0, 3))] = np.inf
        if k % 7 == 0:
            xyz = np.round(xyz, 2)  # ties and zero steps
        xyz = np.ascontiguousarray(xyz.astype(np.float32 if k % 2 else np.float64))
        ring = rng.random((h, w)) < rng.random()
        out.append((xyz, ring, int(rng.integers(1, 300))))
    big = np.ascontiguousarray(np.random.default_rng(2).normal(size=(96, 128, 3)))
    big[..., 2] = np.abs(big[..., 2]) + 0.5
    out += [(big, np.zeros((96, 128), bool), 50), (big, np.ones((96, 128), bool), 10**6),
            (big, np.ones((96, 128), bool), 7), (big[:, :9], (rng.random((96, 128)) < 0.5)[:, :9], 40)]
    return out


def test_the_sample_and_its_steps():
    """The sample is :func:`_ring_sample`'s (and :func:`_sample_ring`'s lists), the steps :func:`_pixel_steps` of it."""
    rng = np.random.default_rng(3)
    for xyz, ring, max_px in _clouds(rng):
        flat, want, own_at, nb_at, steps = _sample_and_steps(xyz, ring, max_px)
        assert np.array_equal(flat, _ring_sample(xyz, ring, max_px))
        for a, b in zip((flat, want, own_at, nb_at), _sample_ring(xyz, ring, max_px), strict=True):
            assert np.array_equal(a, b)
        ref = _pixel_steps(xyz, flat)
        assert steps.dtype == ref.dtype and steps.tobytes() == ref.tobytes()


def test_the_steps_on_real_clouds():
    from replay.logs.pcd import read_pcd

    root = Path(os.environ.get("ZCUT_REAL_DATA", "/work/shared/data/real"))
    clouds = sorted(root.glob("*.pcd")) if root.is_dir() else []
    if not clouds:
        pytest.skip("no real clouds")
    for path in clouds:
        xyz = np.ascontiguousarray(read_pcd(path).xyz)
        valid = np.isfinite(xyz).all(axis=2)
        for ring, max_px in ((valid, MAX_RESIDUAL_PX), (valid, 10**9), (np.ones_like(valid), 3000)):
            flat, *_, steps = _sample_and_steps(xyz, ring, max_px)
            assert steps.tobytes() == _pixel_steps(xyz, flat).tobytes(), path.name


def _scatter_literal(ok, p_bin, d, j, e, planes):
    """:func:`_scatter_query` as the masked assignments it stands for."""
    n = len(ok)
    p_all = np.full((n, 3), np.nan)
    p_all[ok] = p_bin
    near = np.full(n, np.inf)
    near[ok] = d * 1000.0
    found = np.isfinite(d)
    out = np.full(n, np.inf)
    signed = np.full(n, np.nan)
    j_all = np.full(n, -1, np.int64)
    at = np.flatnonzero(ok)[found]
    j_all[at] = j[found]
    if planes:
        out[at] = np.abs(e) * 1000.0
        signed[at] = e
    else:
        out[at] = d[found] * 1000.0
    return p_all, out, near, signed, j_all


def test_the_scatter():
    rng = np.random.default_rng(4)
    for k in range(200):
        n = int(rng.integers(0, 60))
        ok = rng.random(n) < (1.0 if k % 3 == 0 else (0.0 if k % 3 == 1 and k % 2 else rng.random()))
        m = int(np.count_nonzero(ok))
        p_bin = np.ascontiguousarray(rng.normal(size=(m, 3)))
        d = np.where(rng.random(m) < 0.8, rng.random(m) * 0.008, np.inf)
        j = np.where(np.isfinite(d), rng.integers(0, 1000, m), 1000)
        planes = bool(k % 2)
        e = rng.normal(size=int(np.count_nonzero(np.isfinite(d)))) * 1e-3 if planes else np.zeros(0)
        got = _scatter_query(ok, p_bin, d, j, e, planes)
        want = _scatter_literal(ok, p_bin, d, j, e, planes)
        for a, b in zip(got, want, strict=True):
            assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), k
        assert (got[0] is p_bin) == (m == n)  # every pixel finite: the product's own array


def test_the_second_query_reads_the_queried_points(logs):
    for name, (model, params, frames) in logs.items():
        index = prepare_removal_index(model, params)
        for xyz, _, ring, T in frames:
            T = np.asarray(T, np.float64)
            flat, want, own_at, _, _ = _sample_and_steps(xyz, np.ascontiguousarray(ring), MAX_RESIDUAL_PX)
            q = _query(xyz, want, index, T)
            assert q.moved is not None  # a ring's pixels are finite
            for keep in (np.ones(len(flat), bool), np.arange(len(flat)) % 3 == 0, np.zeros(len(flat), bool)):
                got = _nearest_again(xyz, flat[keep], own_at[keep], index, T, q)
                ref = _nearest_again(xyz, flat[keep], own_at[keep], index, T, dataclasses.replace(q, moved=None))
                assert got.tobytes() == ref.tobytes(), name
            # a queried pixel without a finite point: no points kept, the frame gathered again
            a = xyz.copy()
            a.reshape(-1, 3)[want[len(want) // 2]] = np.nan
            assert _query(a, want, index, T).moved is None


PARAMS = {
    "robust": {},
    "robust-no-stragglers": {"straggler_mm": 0.0},
    "robust-global-bound": {"straggler_bound": "global"},
    # wide tolerances and two neighbours: many stragglers pass, the later passes run
    "robust-wide-tolerance": {"min_tolerance_mm": 7.5, "straggler_neighbours": 2},
    "paper-stragglers": {"mode": "paper", "straggler_mm": 4.0, "straggler_neighbours": 2},
}


def _assert_same(fast, ref, what):
    for f in FIELDS:
        a, b = np.asarray(getattr(fast, f)), np.asarray(getattr(ref, f))
        assert a.dtype == b.dtype and a.shape == b.shape, f"{what} {f}"
        assert a.tobytes() == b.tobytes(), f"{what} {f}"


@pytest.mark.parametrize("name", list(PARAMS))
def test_fast_equals_reference(logs, name):
    passed = 0
    for log, (model, params, frames) in logs.items():
        index = prepare_removal_index(model, dataclasses.replace(params, **PARAMS[name]))
        for i, (xyz, fp, ring, T) in enumerate(frames):
            fast = remove_table_and_bin(xyz, fp, index=index, T_cam_bin=T, ring=ring)
            ref = remove_table_and_bin(xyz, fp, index=index, T_cam_bin=T, ring=ring, reference=True)
            _assert_same(fast, ref, f"{log} frame {i} {name}")
            none = prepare_removal_index(model, dataclasses.replace(params, **(PARAMS[name] | {"straggler_mm": 0.0})))
            without = remove_table_and_bin(xyz, fp, index=none, T_cam_bin=T, ring=ring)
            passed += int(np.count_nonzero(ref.bin_points & ~without.bin_points))
    if name in ("robust-wide-tolerance", "paper-stragglers"):
        assert passed > 0  # stragglers were labelled: the later passes ran


def test_fast_equals_reference_on_holes_and_degenerate_frames(logs):
    model, params, frames = logs["zinc_nuts"]
    xyz, fp, ring, T = frames[0]
    rng = np.random.default_rng(6)
    for extra in ({}, {"straggler_neighbours": 2, "min_tolerance_mm": 7.5}):
        index = prepare_removal_index(model, dataclasses.replace(params, **extra))
        half = xyz.copy()
        half[:, : xyz.shape[1] // 2] = np.nan
        bands = xyz.copy()
        bands[::7] = np.nan
        speckle = xyz.copy()
        speckle[rng.random(xyz.shape[:2]) < 0.4] = np.nan
        nan = np.full_like(xyz, np.nan)
        one = nan.copy()
        r, c = np.argwhere(ring)[len(np.argwhere(ring)) // 2]
        one[r, c] = xyz[r, c]
        cases = [(half, fp, ring), (bands, fp, ring), (speckle, fp, ring), (nan, fp, ring), (one, fp, ring),
                 (np.ascontiguousarray(xyz[r:r + 1]), fp[r:r + 1], ring[r:r + 1]),
                 (np.ascontiguousarray(xyz[:, c:c + 1]), fp[:, c:c + 1], ring[:, c:c + 1]),
                 (np.ascontiguousarray(xyz[:, :13]), fp[:, :13], ring[:, :13])]  # a width not a multiple of 8
        for k, (a, f, g) in enumerate(cases):
            f, g = np.ascontiguousarray(f), np.ascontiguousarray(g)
            with np.errstate(invalid="ignore"):
                fast = remove_table_and_bin(a, f, index=index, T_cam_bin=T, ring=g)
                ref = remove_table_and_bin(a, f, index=index, T_cam_bin=T, ring=g, reference=True)
            _assert_same(fast, ref, f"case {k} {extra}")


def test_the_first_straggler_pass_counts_and_marks(logs):
    """Its row counts are the passed candidates (``first`` = 2) of each row; the candidates, and only they, go from
    open to tried in ``code``."""
    from zcut.removal import _OPEN, _TRIED, _classify_codes, _grid_args, _radius, frame_tolerance, straggler_bound_args

    for log, (model, params0, frames) in logs.items():
        for extra in ({}, {"straggler_neighbours": 2, "min_tolerance_mm": 7.5}):
            params = dataclasses.replace(params0, **extra)
            index = prepare_removal_index(model, params)
            for xyz, fp, ring, T in frames:
                T = np.asarray(T, np.float64)
                R, t = np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3])
                tol = frame_tolerance(xyz, ring, index, T)
                delta = tol.tolerance_mm / 1000.0
                radius = max(_radius(params, model.spacing_m, delta), tol.reach_mm / 1000.0)
                code = np.empty(fp.shape, np.uint8)
                g = index.bin
                _classify_codes(xyz, np.ascontiguousarray(fp), R, t, index.rim_b + params.rim_offset_m, True, True,
                                *_grid_args(g), g.ijk, g.busy, g.box, delta, radius, True, code)
                before = code.copy()
                s = index.straggler
                first = np.zeros(fp.shape, np.uint8)
                passed = _straggler_first(xyz, code, int(params.straggler_neighbours), R, t, *_grid_args(s), s.ijk,
                                          s.busy, s.box, params.straggler_m + delta, radius + params.straggler_m,
                                          True, *straggler_bound_args(params, tol, index.rim_b), first)
                assert np.array_equal(passed, np.count_nonzero(first == 2, axis=1)), log
                assert np.array_equal(code == _TRIED, first > 0) and np.all(before[first > 0] == _OPEN), log
                assert np.array_equal(code[first == 0], before[first == 0]), log


def test_the_bin_tests_cells_by_the_inverse(logs):
    """:func:`zcut.removal._near_hint` (its cells from the coordinates times ``1 / cell``) answers as
    :func:`zcut.removal._near_one` (the reference's, divided by ``cell``): some model point passes or none, on points
    on the grid's cell faces, edges and corners and a unit in the last place either side, model points moved by up
    to the radius, and points beyond the grid, for the bin grid and the stragglers' at several radii and
    tolerances, with and without normals."""
    from zcut.removal import _near_hint, _near_one

    rng = np.random.default_rng(8)
    model, params, _ = logs["zinc_nuts"]
    index = prepare_removal_index(model, params)
    n_pass = n_fail = 0
    for g in (index.bin, index.straggler):
        own = model.points[rng.choice(len(model.points), 400)]
        for radius in (0.9 * g.cell, g.cell, 0.3 * g.cell):
            on_faces = g.origin + np.round((own - g.origin) / g.cell) * g.cell
            near = own + rng.uniform(-1, 1, own.shape) * radius
            snapped = near.copy()
            axes = rng.random(own.shape) < 0.5
            snapped[axes] = on_faces[axes]
            cases = [on_faces, np.nextafter(on_faces, np.inf), np.nextafter(on_faces, -np.inf), near, snapped,
                     g.origin + rng.uniform(-0.01, 1.0, own.shape) * g.dims * g.cell]
            for q in cases:
                for delta, planes in ((0.001, True), (0.003, True), (radius, False)):
                    nrm = g.normals
                    for px, py, pz in q:
                        want = _near_one(px, py, pz, g.origin, g.cell, g.dims, g.start, g.points, nrm, g.offsets,
                                         delta, radius, planes)
                        got = _near_hint(px, py, pz, g.origin, g.cell, g.dims, g.start, g.points, nrm, g.offsets,
                                         g.ijk, g.busy, g.box, delta, radius, planes, -1)
                        assert (got >= 0) == want, (px, py, pz, radius, delta, planes)
                        n_pass += want
                        n_fail += not want
    assert n_pass > 1000 and n_fail > 1000
