"""ICP's correspondences kept between iterations (branch h/px3): ``zcut.icp_fast._correspond_kept`` answers a
source point from its last search while its nearest model point cannot have changed, and the ICP built on it is
the previous loop bit for bit.

- ``_correspond_kept`` against ``_correspond`` (itself held to brute force in ``test_registration_kept.py``) over
  runs of moves: tiny, around the gap between a point's two nearest model points, large; on lattices (exact ties
  and exact gaps), on a bin model's points, with queries outside the grid and out of reach;
- ``_transform_moved`` against ``_transform_rows`` (the same bits) and the distance each row moved;
- ``icp`` against the previous loop (``_transform_rows`` and ``_correspond`` every iteration, written out here
  with the same update kernels): pose, fitness, RMSE, iterations and correspondences in bytes, both methods, on the
  filled bin from near and far starts, on random clouds, on a lattice model and on the real scans.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pipeline_scene as ps
import pytest

from zcut.binmask import bin_mask, bin_pixels
from zcut.icp_fast import (
    _cell_order,
    _correspond,
    _correspond_kept,
    _is_identity,
    _matmul4,
    _point_to_plane,
    _point_to_point,
    _transform_moved,
    _transform_rows,
    build_grid,
    icp,
)
from zcut.params import RegistrationParams
from zcut.registration import prepare_icp_model, prepare_target

REAL = Path("/work/shared/data/real")
filled = pytest.fixture(scope="module")(ps.filled_bin_scene)
model = pytest.fixture(scope="module")(ps.shifted_bin_model)


def _state(m: int) -> tuple[np.ndarray, ...]:
    return np.empty(m), np.full(m, -1, np.int64), np.empty(m, np.int64), np.empty(m, np.int64), np.empty(m), np.zeros(m)


def _answers(grid, q: np.ndarray, order: np.ndarray, dist: float) -> tuple[int, float, np.ndarray, np.ndarray]:  # type: ignore[no-untyped-def]
    nx, ny, nz = (int(v) for v in grid.dims)
    m = len(q)
    st = (np.empty(m), np.empty(m, np.int64), np.empty(m, np.int64), np.empty(m, np.int64))
    n, e2 = _correspond(q, order, grid.origin, grid.cell, nx, ny, nz, grid.near_start, grid.near, grid.near_dist,
                        grid.points, grid.order, dist, *st)
    return n, e2, st[2][:n].copy(), st[3][:n].copy()


def _check_runs(pts: np.ndarray, q0: np.ndarray, dist: float, steps: list[float], rng: np.random.Generator) -> int:
    """Move ``q0`` by random rigid or per-point steps of the given sizes; after each, ``_correspond_kept`` (its
    state carried along) against a fresh ``_correspond``. Returns how many answers were kept (not searched)."""
    grid = build_grid(pts, None, radius=dist)
    nx, ny, nz = (int(v) for v in grid.dims)
    q = q0.copy()
    m = len(q)
    order = rng.permutation(m).astype(np.int64)
    st = _state(m)
    kept = 0
    for t, size in enumerate([0.0, *steps]):
        if t:
            if t % 2:  # a small rigid move, through _transform_moved (as an ICP update moves the source)
                a = rng.normal(0.0, size / 0.05, 3) * 180.0 / math.pi
                U = ps.turned_pose(a * 1e-3, rng.normal(0.0, size, 3))
                before = q.copy()
                _transform_moved(U, q, st[5])
                want = before.copy()
                _transform_rows(U, want)
                assert q.tobytes() == want.tobytes()
            else:  # every point its own move
                step = rng.normal(0.0, size, q.shape)
                st[5][:] += np.sqrt((step**2).sum(axis=1)) * (1.0 + 1e-9)
                q += step
        moved_before = st[5].copy()
        n, e2 = _correspond_kept(q, order, grid.origin, grid.cell, nx, ny, nz, grid.near_start, grid.near,
                                 grid.near_dist, grid.points, grid.order, dist, *st, t == 0)
        if t:  # a point searched again starts from 0; one answered from its last search keeps its distance
            kept += int(np.count_nonzero((moved_before > 0) & (st[5] == moved_before)))
        want = _answers(grid, q, order, dist)
        assert (n, e2) == want[:2], t
        assert np.array_equal(st[2][:n], want[2]) and np.array_equal(st[3][:n], want[3]), t
    return kept


@pytest.mark.parametrize("case", ["random", "lattice (ties)", "bin model", "outside and out of reach"])
def test_kept_correspondences_are_the_searched_ones(case, model):
    rng = np.random.default_rng(3301)
    dist = 10.0 / 3000.0
    total_kept = 0
    for _ in range(6):
        if case == "random":
            pts = rng.uniform(0.0, 0.03, (600, 3)) + (0.2, -0.1, 0.7)
        elif case == "lattice (ties)":  # exact ties and exact gaps between neighbours
            g = np.arange(0.0, 0.02, 0.001)
            pts = np.stack(np.meshgrid(g, g, g[:5], indexing="ij"), axis=-1).reshape(-1, 3) + (0.25, 0.125, 0.5)
        elif case == "bin model":
            pts = model.points[rng.choice(len(model.points), 4000, replace=False)]
        else:
            pts = rng.uniform(0.0, 0.02, (300, 3))
        q0 = pts[rng.integers(len(pts), size=1500)] + rng.normal(0.0, dist / 2, (1500, 3))
        if case == "lattice (ties)":
            q0[::3] = pts[rng.integers(len(pts), size=len(q0[::3]))] + 0.0005  # exactly between lattice points
        if case == "outside and out of reach":
            q0[::4] += rng.normal(0.0, 0.02, (len(q0[::4]), 3))
            q0[1::9] += 1.0
        steps = [1e-6, 1e-5, 1e-4, 1e-4, 3e-4, 1e-3, 1e-7, 1e-2, 1e-6, 0.0, 1e-5]
        total_kept += _check_runs(pts, q0, dist, steps, rng)
    assert total_kept > 0  # some answers were kept, not searched


def test_transform_moved_is_transform_rows_and_its_distance():
    rng = np.random.default_rng(3302)
    for t in range(20):
        T = ps.turned_pose(rng.normal(0.0, 2.0, 3), rng.normal(0.0, 0.01, 3))
        if t % 5 == 4:
            T[3] = rng.normal(0.0, 0.01, 4) + (0.0, 0.0, 0.0, 1.0)  # projective: the division form
        pcd = rng.normal(0.0, 0.5, (400, 3))
        got, want = pcd.copy(), pcd.copy()
        moved = np.full(400, 0.25)
        _transform_moved(T, got, moved)
        _transform_rows(T, want)
        assert got.tobytes() == want.tobytes()
        exact = np.sqrt(((got - pcd) ** 2).sum(axis=1))
        assert np.all(moved - 0.25 >= exact)
        assert np.all(moved - 0.25 <= exact * (1 + 1e-8) + 1e-15)


def _icp_previous(source: np.ndarray, grid, *, max_distance: float, init: np.ndarray, point_to_plane: bool,  # type: ignore[no-untyped-def]
                  max_iteration: int) -> tuple[np.ndarray, float, float, int, int]:
    """``icp`` as the previous tree ran it: every iteration moves the source with ``_transform_rows`` and searches
    every point with ``_correspond`` (Open3D's loop, ``_icp_loop`` before this round)."""
    nx, ny, nz = (int(v) for v in grid.dims)
    pcd = np.ascontiguousarray(source, dtype=np.float64).copy()
    T = np.ascontiguousarray(init, dtype=np.float64)
    if not _is_identity(T):
        _transform_rows(T, pcd)
    m = len(pcd)
    st = (np.empty(m), np.empty(m, np.int64), np.empty(m, np.int64), np.empty(m, np.int64))
    order = _cell_order(pcd, grid.origin, grid.cell, nx, ny)

    def search() -> tuple[int, float, float]:
        n, e2 = _correspond(pcd, order, grid.origin, grid.cell, nx, ny, nz, grid.near_start, grid.near,
                            grid.near_dist, grid.points, grid.order, max_distance, *st)
        return n, n / m if n else 0.0, math.sqrt(e2 / n) if n else 0.0

    n, fit, rmse = search()
    T = T.copy()
    its = 0
    for _ in range(max_iteration):
        its += 1
        U = (_point_to_plane(pcd, grid.points, grid.normals, st[2], st[3], n) if point_to_plane
             else _point_to_point(pcd, grid.points, st[2], st[3], n))
        fit0, rmse0 = fit, rmse
        T = _matmul4(U, T)
        _transform_rows(U, pcd)
        n, fit, rmse = search()
        if abs(fit0 - fit) < 1e-6 and abs(rmse0 - rmse) < 1e-6:
            break
    return T, fit, rmse, its, n


def _same_as_previous(src: np.ndarray, pts: np.ndarray, nrm: np.ndarray | None, *, dist: float, init: np.ndarray,
                      point_to_plane: bool, max_iteration: int = 30) -> int:
    grid = build_grid(pts, nrm, radius=dist)
    got = icp(src, grid, max_distance=dist, init=init, point_to_plane=point_to_plane, max_iteration=max_iteration)
    T, fit, rmse, its, n = _icp_previous(src, grid, max_distance=dist, init=init, point_to_plane=point_to_plane,
                                         max_iteration=max_iteration)
    assert got.transformation.tobytes() == T.tobytes()
    assert (got.fitness, got.inlier_rmse, got.iterations, got.n_correspondences) == (fit, rmse, its, n)
    return its


@pytest.mark.parametrize("point_to_plane", [True, False])
def test_icp_is_the_previous_loop_on_a_filled_bin(filled, model, point_to_plane):
    """The registration's two passes' inputs (the frame's downsampled bin points, the model's grids) from the
    translation guess, from poses off by a few millimetres and degrees, and from the right pose."""
    frame, _ = filled
    p = RegistrationParams(voxel_mm=1.0)
    m = prepare_icp_model(model, p)
    target = prepare_target(frame.xyz[bin_pixels(bin_mask(frame.rgb), frame.xyz)].astype(np.float64),
                            voxel_m=p.voxel_m, intrinsics=frame.intrinsics)
    src = target.cloud.points
    from zcut.registration import _guess

    T0 = np.linalg.inv(_guess(m.top_centre, target.points))
    its = []
    for off_deg, off_m in ((0.0, 0.0), (1.0, 0.004), (3.0, 0.012), (0.2, 0.001)):
        init = T0 @ ps.turned_pose((off_deg, -off_deg / 2, off_deg), (off_m, -off_m, off_m / 2))
        for pc, dist in ((m.coarse, p.max_correspondence_m), (m.fine, p.fine_correspondence_m)):
            nrm = pc.normals if point_to_plane else None
            its.append(_same_as_previous(src, pc.points, nrm, dist=dist, init=init, point_to_plane=point_to_plane))
    assert max(its) >= 3  # runs long enough to keep answers


def test_icp_is_the_previous_loop_on_random_and_lattice_clouds():
    rng = np.random.default_rng(3303)
    for t in range(12):
        if t % 3 == 2:
            g = np.arange(0.0, 0.05, 0.002)
            pts = np.stack(np.meshgrid(g, g, [0.0, 0.002], indexing="ij"), axis=-1).reshape(-1, 3) + (0.1, 0.2, 0.6)
        else:
            pts = rng.uniform(0.0, 0.05, (3000, 3)) + (0.1, 0.2, 0.6)
        nrm = rng.normal(size=pts.shape)
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        src = pts[rng.choice(len(pts), 800, replace=False)] + rng.normal(0.0, 0.0005, (800, 3))
        init = ps.turned_pose(rng.normal(0.0, 1.0, 3), rng.normal(0.0, 0.002, 3))
        for point_to_plane in (True, False):
            _same_as_previous(src, pts, nrm if point_to_plane else None, dist=0.005, init=init,
                              point_to_plane=point_to_plane)


@pytest.mark.parametrize("name", ["mosd_test16.pcd", "milk_cartoon_all_small_clorox.pcd", "mosd_test44.pcd"])
def test_icp_is_the_previous_loop_on_real_scans(name):
    import open3d as o3d

    from replay.logs.pcd import read_pcd

    if not (REAL / name).is_file():
        pytest.skip(f"{name} not in {REAL}")
    xyz = read_pcd(REAL / name).xyz.reshape(-1, 3).astype(np.float64)
    xyz = xyz[np.isfinite(xyz).all(axis=1)]
    model_pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz)).voxel_down_sample(0.005)
    model_pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.02, max_nn=30))
    src = np.asarray(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz[::3])).voxel_down_sample(0.008).points)
    for init in (ps.turned_pose((0.5, -0.8, 1.5), (0.006, -0.004, 0.01)), np.eye(4)):
        for point_to_plane in (True, False):
            for dist in (0.02, 0.008):
                _same_as_previous(src, np.asarray(model_pc.points), np.asarray(model_pc.normals), dist=dist,
                                  init=init, point_to_plane=point_to_plane)
