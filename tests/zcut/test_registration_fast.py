"""zcut.icp_fast: the ICP on the model's grid built once, held to Open3D's ``registration_icp`` (the
oracle, run in the same test on the same input): the pose within 1e-12, the same correspondences,
fitness and iterations, on a synthetic filled bin (both methods, starts near and far), on real Kinect
scans, and on degenerate input (a plane only, no correspondence, no point, exact ties)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pipeline_scene as ps
import pytest

from zcut.binmask import bin_mask, bin_pixels
from zcut.errors import InputShapeError, ParameterError
from zcut.icp_fast import MAX_GRID_CELLS, _correspond, _ldlt_solve, build_grid, icp, icp_open3d
from zcut.params import RegistrationParams
from zcut.registration import prepare_icp_model, prepare_target, register_bin

REAL = Path("/work/shared/data/real")
filled = pytest.fixture(scope="module")(ps.filled_bin_scene)
model = pytest.fixture(scope="module")(ps.shifted_bin_model)


def _same_as_open3d(src: np.ndarray, pts: np.ndarray, nrm: np.ndarray | None, *, dist: float, init: np.ndarray,
                    point_to_plane: bool, max_iteration: int = 30, grid_radius: float | None = None) -> None:
    """icp against Open3D's registration_icp on one input: pose, correspondences, fitness, RMSE,
    iterations."""
    grid = build_grid(pts, nrm, radius=dist if grid_radius is None else grid_radius)
    ours = icp(src, grid, max_distance=dist, init=init, point_to_plane=point_to_plane, max_iteration=max_iteration)
    ref = icp_open3d(src, pts, nrm, max_distance=dist, init=init, point_to_plane=point_to_plane,
                     max_iteration=max_iteration, count_iterations=True)
    scale = max(1.0, float(np.abs(ref.transformation).max()))
    assert np.abs(ours.transformation - ref.transformation).max() <= 1e-12 * scale
    assert ours.iterations == ref.iterations
    assert ours.n_correspondences == ref.n_correspondences
    assert ours.fitness == ref.fitness  # the same count over the same number of points
    assert ours.inlier_rmse == pytest.approx(ref.inlier_rmse, rel=1e-12, abs=1e-15)
    # deterministic: the same bits again
    again = icp(src, grid, max_distance=dist, init=init, point_to_plane=point_to_plane, max_iteration=max_iteration)
    assert np.array_equal(again.transformation, ours.transformation) and again.inlier_rmse == ours.inlier_rmse


@pytest.fixture(scope="module")
def bin_case(filled, model):
    """The filled bin's bin pixels, prepared, and the model prepared for 1 mm voxels."""
    frame, _ = filled
    p = RegistrationParams(voxel_mm=1.0)
    icp_model = prepare_icp_model(model, p)
    target = prepare_target(frame.xyz[bin_pixels(bin_mask(frame.rgb), frame.xyz)].astype(np.float64),
                            voxel_m=p.voxel_m, intrinsics=frame.intrinsics)
    return icp_model, target


@pytest.mark.parametrize("point_to_plane", [True, False])
@pytest.mark.parametrize("start", ["guess", "off 4 mm 1 deg", "off 12 mm 3 deg"])
def test_icp_is_open3ds_on_a_filled_bin(bin_case, point_to_plane, start):
    icp_model, target = bin_case
    reg = register_bin(icp_model, target, coarse=False)  # the translation-only guess, inverted below
    T0 = np.linalg.inv(reg.T_init)
    if start != "guess":
        mm, deg = (4.0, 1.0) if start.startswith("off 4") else (12.0, 3.0)
        T0 = ps.turned_pose((0.3 * deg, -0.5 * deg, deg), (mm / 1000, -0.5 * mm / 1000, 0.3 * mm / 1000)) @ T0
    src = np.asarray(target.cloud.points)
    fine = icp_model.fine
    nrm = np.asarray(fine.normals)
    for dist in (icp_model.params.fine_correspondence_m, icp_model.params.max_correspondence_m):
        _same_as_open3d(src, np.asarray(fine.points), nrm, dist=dist, init=T0, point_to_plane=point_to_plane,
                        grid_radius=icp_model.params.max_correspondence_m)


@pytest.mark.parametrize("method", ["point_to_plane", "point_to_point"])
def test_register_bin_is_its_open3d_reference(bin_case, method):
    icp_model, target = bin_case
    p = RegistrationParams(voxel_mm=1.0, method=method)
    for coarse in (True, False):
        new = register_bin(icp_model, target, params=p, coarse=coarse)
        ref = register_bin(icp_model, target, params=p, coarse=coarse, reference=True)
        assert np.abs(new.T_cam_bin - ref.T_cam_bin).max() <= 1e-12
        assert new.fitness == ref.fitness and new.n_rim == ref.n_rim and new.converged == ref.converged
        assert new.icp_fitness == ref.icp_fitness
        assert new.inlier_rmse == pytest.approx(ref.inlier_rmse, rel=1e-12)
        assert len(new.iterations) == (2 if coarse else 1) and all(1 <= i <= 30 for i in new.iterations)
        assert ref.iterations == (-1,) * len(new.iterations)


def test_icp_keeps_the_grids_the_model_was_prepared_with(bin_case):
    icp_model, _ = bin_case
    p = icp_model.params
    assert icp_model.fine_grid.radius == p.fine_correspondence_m
    assert icp_model.coarse_grid.radius == p.max_correspondence_m
    assert len(icp_model.fine_grid.points) == len(icp_model.fine.points)
    # the grid holds the model's own points and normals, reordered
    order = icp_model.fine_grid.order
    assert np.array_equal(icp_model.fine_grid.points, np.asarray(icp_model.fine.points)[order])
    assert np.array_equal(icp_model.fine_grid.normals, np.asarray(icp_model.fine.normals)[order])


def _real_cloud(name: str) -> np.ndarray:
    from replay.logs.pcd import read_pcd

    xyz = read_pcd(REAL / name).xyz.reshape(-1, 3).astype(np.float64)
    return xyz[np.isfinite(xyz).all(axis=1)]


@pytest.mark.parametrize("name", ["mosd_test16.pcd", "milk_cartoon_all_small_clorox.pcd"])
@pytest.mark.parametrize("point_to_plane", [True, False])
def test_icp_is_open3ds_on_real_kinect_scans(name, point_to_plane):
    """No bin here: a real scene registered to itself, moved (the geometry and the sensor's noise, its
    flying pixels and holes are real)."""
    import open3d as o3d

    if not (REAL / name).is_file():
        pytest.skip(f"{name} not in {REAL}")
    xyz = _real_cloud(name)
    model_pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz)).voxel_down_sample(0.005)
    model_pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.02, max_nn=30))
    src = np.asarray(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz[::3])).voxel_down_sample(0.008).points)
    init = ps.turned_pose((0.5, -0.8, 1.5), (0.006, -0.004, 0.01))
    _same_as_open3d(src, np.asarray(model_pc.points), np.asarray(model_pc.normals), dist=0.02, init=init,
                    point_to_plane=point_to_plane)


def test_icp_on_a_plane_only_leaves_the_free_directions_alone():
    """Point-to-plane on a flat model: the in-plane moves and the turn about the normal are not
    constrained; JᵀJ has zero pivots there and Eigen's LDLT gives them 0, as here."""
    g = np.arange(-20, 21) * 0.003
    X, Y = np.meshgrid(g, g)
    pts = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, 0.5)])
    nrm = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    src = pts[::2] + [0.0011, -0.0007, 0.002]
    _same_as_open3d(src, pts, nrm, dist=0.005, init=np.eye(4), point_to_plane=True)
    out = icp(src, build_grid(pts, nrm, radius=0.005), max_distance=0.005, init=np.eye(4), point_to_plane=True,
              max_iteration=30)
    assert out.transformation[2, 3] == pytest.approx(-0.002, abs=1e-12)
    assert abs(out.transformation[0, 3]) < 1e-15 and abs(out.transformation[1, 3]) < 1e-15


def test_icp_without_correspondences_or_points_returns_the_start():
    rng = np.random.default_rng(3)
    pts = rng.uniform(0, 0.1, (500, 3))
    nrm = np.tile([0.0, 0.0, 1.0], (500, 1))
    grid = build_grid(pts, nrm, radius=0.01)
    init = ps.turned_pose((1, 2, 3), (0.001, 0.002, 0.003))
    far = pts[:50] + [5.0, 0.0, 0.0]
    _same_as_open3d(far, pts, nrm, dist=0.01, init=init, point_to_plane=True)
    out = icp(far, grid, max_distance=0.01, init=init, point_to_plane=True, max_iteration=30)
    assert out.iterations == 1 and out.fitness == 0.0 and out.inlier_rmse == 0.0 and out.n_correspondences == 0
    assert np.array_equal(out.transformation, init)
    empty = icp(np.zeros((0, 3)), grid, max_distance=0.01, init=init, point_to_plane=False, max_iteration=30)
    assert empty.fitness == 0.0 and np.array_equal(empty.transformation, init)
    # an empty model: nothing to correspond to
    none = icp(far, build_grid(np.zeros((0, 3)), None, radius=0.01), max_distance=0.01, init=init,
               point_to_plane=False, max_iteration=5)
    assert none.n_correspondences == 0 and np.array_equal(none.transformation, init)


def _brute(pcd: np.ndarray, pts: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
    """Per source point: the model index of its nearest point below r (ties: the lowest), else -1,
    and that squared distance, summed as nanoflann sums it."""
    d = pcd[:, None, :] - pts[None, :, :]
    d2 = d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2]
    j = np.argmin(d2, axis=1)  # the first minimum: the lowest index
    best = d2[np.arange(len(pcd)), j]
    return np.where(best < r * r, j, -1), best


@pytest.mark.parametrize("case", ["random", "lattice ties", "cell faces", "huge extent"])
def test_correspondences_are_the_exact_nearest_within_the_distance(case):
    rng = np.random.default_rng(11)
    r = 0.004
    if case == "random":
        pts = rng.uniform(-0.05, 0.05, (3000, 3))
        pcd = rng.uniform(-0.06, 0.06, (2000, 3))
    elif case == "lattice ties":  # queries at the midpoints of a lattice: exact ties everywhere
        g = np.arange(10) * 0.002
        pts = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
        pts = pts[rng.permutation(len(pts))]
        pcd = pts[:400] + [0.001, 0.0, 0.0]
    elif case == "cell faces":  # queries exactly on the grid's cell faces and at distance r
        pts = rng.uniform(0, 0.05, (2000, 3))
        cell = build_grid(pts, None, radius=r).cell
        pcd = pts.min(axis=0) + cell * rng.integers(-2, 14, (1500, 3)).astype(np.float64)
        pcd = np.concatenate([pcd, pts[:300] + [r, 0.0, 0.0], pts[300:400] + [0.0, np.nextafter(r, 0), 0.0]])
    else:  # an extent that the dense table cannot hold at the distance: wider cells, same answers
        pts = np.concatenate([rng.uniform(0, 0.05, (1000, 3)), [[200.0, 300.0, 100.0]]])
        pcd = np.concatenate([rng.uniform(-0.01, 0.06, (1000, 3)), [[200.0, 300.0, 100.003]]])
    grid = build_grid(pts, None, radius=r)
    if case == "huge extent":
        assert grid.cell > 2 * r and np.prod(grid.dims + 2) <= MAX_GRID_CELLS
    m = len(pcd)
    near, best, src, dst = np.empty(m, np.int64), np.empty(m), np.empty(m, np.int64), np.empty(m, np.int64)
    order = np.random.default_rng(5).permutation(m)
    n, err2 = _correspond(pcd, order, grid.origin, grid.cell, *(int(v) for v in grid.dims), grid.near_start, grid.near,
                          grid.near_dist, grid.points, grid.order, r, best, near, src, dst)
    want_j, want_d2 = _brute(pcd, pts, r)
    got = np.full(m, -1)
    got[src[:n]] = grid.order[dst[:n]]
    assert np.array_equal(got, want_j)
    assert n == np.count_nonzero(want_j >= 0) and n > 0
    assert err2 == pytest.approx(float(want_d2[want_j >= 0].sum()), rel=1e-12)
    if case == "lattice ties":
        assert n == len(pcd)


@pytest.mark.parametrize("shape", ["bin", "plane", "one cell"])
def test_the_neighbour_lists_are_the_27_cells_around(shape):
    """Each padded cell's list holds the rows of the cells around it, clipped to the grid, each once, in
    increasing distance to the cell's centre."""
    rng = np.random.default_rng(8)
    if shape == "bin":
        pts = rng.uniform(0, 0.04, (1500, 3)) * [1.0, 0.7, 0.4]
    elif shape == "plane":
        pts = np.c_[rng.uniform(0, 0.05, (800, 2)), np.zeros(800)]
    else:
        pts = rng.uniform(0, 0.001, (20, 3))
    grid = build_grid(pts, None, radius=0.004)
    nx, ny, nz = (int(v) for v in grid.dims)
    ijk = np.minimum(np.floor((grid.points - grid.origin) / grid.cell).astype(int), grid.dims - 1)
    assert len(grid.near) == 27 * len(pts) and len(grid.near_start) == (nx + 2) * (ny + 2) * (nz + 2) + 1
    for a, b, c in np.ndindex(nx + 2, ny + 2, nz + 2):
        q = (a * (ny + 2) + b) * (nz + 2) + c
        got = grid.near[grid.near_start[q]:grid.near_start[q + 1]]
        want = np.flatnonzero((np.abs(ijk - [a - 1, b - 1, c - 1]) <= 1).all(axis=1))
        assert np.array_equal(np.sort(got), want)
        dist = grid.near_dist[grid.near_start[q]:grid.near_start[q + 1]]
        centre = grid.origin + (np.array([a, b, c]) - 0.5) * grid.cell
        assert np.all(np.diff(dist) >= 0) and np.allclose(dist, np.linalg.norm(grid.points[got] - centre, axis=1),
                                                          rtol=1e-14, atol=0)


def test_ldlt_is_eigens_on_definite_and_singular_matrices():
    rng = np.random.default_rng(2)
    for _ in range(20):
        J = rng.normal(size=(40, 6))
        A, b = J.T @ J, rng.normal(size=6)
        assert np.allclose(_ldlt_solve(A, b), np.linalg.solve(A, b), rtol=1e-10, atol=1e-12)
    # zero rows and columns (unconstrained directions): their components are 0
    A = np.zeros((6, 6))
    A[np.ix_([0, 1, 5], [0, 1, 5])] = [[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]]
    b = np.array([1.0, 2.0, 7.0, 7.0, 7.0, 3.0])
    x = _ldlt_solve(A, b)
    assert np.all(x[2:5] == 0.0)
    assert np.allclose(x[[0, 1, 5]], np.linalg.solve(A[np.ix_([0, 1, 5], [0, 1, 5])], b[[0, 1, 5]]))
    assert np.array_equal(_ldlt_solve(np.zeros((6, 6)), b), np.zeros(6))


def test_bad_input_is_a_clear_error():
    pts = np.zeros((10, 3))
    with pytest.raises(InputShapeError, match=r"points must be an \(N, 3\)"):
        build_grid(np.zeros((10, 2)), None, radius=0.01)
    with pytest.raises(InputShapeError, match="finite"):
        build_grid(np.full((3, 3), np.nan), None, radius=0.01)
    with pytest.raises(ParameterError, match="radius must be a finite number > 0"):
        build_grid(pts, None, radius=0.0)
    with pytest.raises(InputShapeError, match="normals must match"):
        build_grid(pts, np.zeros((9, 3)), radius=0.01)
    grid = build_grid(pts, None, radius=0.01)
    with pytest.raises(ParameterError, match="exceeds the grid's radius"):
        icp(pts, grid, max_distance=0.02, init=np.eye(4), point_to_plane=False, max_iteration=3)
    with pytest.raises(ParameterError, match="needs the target's normals"):
        icp(pts, grid, max_distance=0.01, init=np.eye(4), point_to_plane=True, max_iteration=3)
    with pytest.raises(InputShapeError, match=r"init must be a finite \(4, 4\)"):
        icp(pts, grid, max_distance=0.01, init=np.eye(3), point_to_plane=False, max_iteration=3)
    with pytest.raises(InputShapeError, match="source points must be finite"):
        icp(np.full((2, 3), np.inf), grid, max_distance=0.01, init=np.eye(4), point_to_plane=False, max_iteration=3)
    with pytest.raises(ParameterError, match="max_iteration must be an integer >= 0"):
        icp(pts, grid, max_distance=0.01, init=np.eye(4), point_to_plane=False, max_iteration=-1)


def test_the_guess_percentiles_are_numpys_by_axis():
    """_top_and_centre's percentiles (order statistics of a sampled bracket, NumPy's interpolation) are
    the values of the per-axis np.percentile calls, bit for bit: sizes either side of the sampled path,
    ties, sorted and reversed columns (the sample then brackets nothing useful), halves of one value,
    zeros (NumPy's own call), a frame's bin points."""
    from zcut.registration import _top_and_centre

    rng = np.random.default_rng(4)
    for k in range(150):
        n = int(rng.choice([1, 2, 3, 50, 3000, 4096, 4097, 9001, 45_000, 104_000]))
        p = rng.normal(size=(n, 3)) * rng.uniform(0.01, 10) + rng.normal(size=3)
        kind = k % 6
        if kind == 1:
            p = np.round(p, 2)  # ties
        elif kind == 2:
            p = np.sort(p, axis=0)
        elif kind == 3:
            p = np.ascontiguousarray(np.sort(p, axis=0)[::-1])
        elif kind == 4:
            p[: n // 2, 0], p[:, 2] = -3.0, 0.7
        elif kind == 5:
            p[rng.random(n) < 0.3] = 0.0  # zeros, also at the ranks taken
        lo, hi = np.percentile(p, 1, axis=0), np.percentile(p[:, :2], 99, axis=0)
        centre, top = _top_and_centre(p)
        assert centre.tobytes() == (0.5 * (lo[:2] + hi)).tobytes() and np.float64(top).tobytes() == lo[2].tobytes()


def test_the_guess_of_a_frame_is_numpys(filled):
    from zcut.registration import _top_and_centre

    frame, _ = filled
    pts = frame.xyz[np.isfinite(frame.xyz).all(axis=2)].astype(np.float64)
    ring = pts[bin_pixels(bin_mask(frame.rgb), frame.xyz)[np.isfinite(frame.xyz).all(axis=2)]]
    assert len(pts) > 4096  # the sampled path
    for p in (pts, pts[::7], ring):
        lo, hi = np.percentile(p, 1, axis=0), np.percentile(p[:, :2], 99, axis=0)
        centre, top = _top_and_centre(p)
        assert centre.tobytes() == (0.5 * (lo[:2] + hi)).tobytes() and np.float64(top).tobytes() == lo[2].tobytes()


def test_subsampled_points_are_numpys_strided_index(filled):
    """The registration's target points (``locate_bin``'s subgrid of the bin pixels) in one pass: the rows and
    order of ``xyz[::s, ::s][pixels[::s, ::s]].astype(np.float64)``, on the filled bin's frame and ring and on
    random frames with NaN, float32 and float64, odd sizes, 1 x N, empty."""
    from zcut.registration import subsampled_points

    def same(xyz, pixels, step):
        got = subsampled_points(xyz, pixels, step=step)
        want = xyz[::step, ::step][pixels[::step, ::step]].astype(np.float64)
        assert got.dtype == np.float64 and np.array_equal(got, want, equal_nan=True), (xyz.shape, step)

    frame, _ = filled
    ring = bin_pixels(bin_mask(frame.rgb), frame.xyz)
    rng = np.random.default_rng(17)
    for step in (1, 2, 3, 5):
        same(frame.xyz, ring, step)
        for shape in ((37, 53), (1, 40), (40, 1), (0, 5), (1, 1)):
            xyz = rng.normal(size=(*shape, 3))
            xyz[rng.random(shape) < 0.2, 1] = np.nan
            pixels = rng.random(shape) < 0.4
            same(xyz, pixels, step)
            same(xyz.astype(np.float32), pixels, step)
    same(rng.normal(size=(9, 8, 3)).astype(np.float16), np.ones((9, 8), bool), 2)  # numpy's own path


@pytest.mark.parametrize(("xyz", "pixels", "step", "error", "match"), [
    (np.zeros((4, 5, 3)), np.zeros((4, 4), bool), 1, InputShapeError, "pixels an"),
    (np.zeros((4, 5)), np.zeros((4, 5), bool), 1, InputShapeError, r"\(H, W, 3\)"),
    (np.zeros((4, 5, 3)), np.zeros((4, 5), np.uint8), 1, InputShapeError, "bool"),
    (np.zeros((4, 5, 3)), np.zeros((4, 5), bool), 0, ParameterError, "step"),
    (np.zeros((4, 5, 3)), np.zeros((4, 5), bool), 1.5, ParameterError, "step"),
])
def test_subsampled_points_bad_input(xyz, pixels, step, error, match):
    from zcut.registration import subsampled_points

    with pytest.raises(error, match=match):
        subsampled_points(xyz, pixels, step=step)


def _kdtree_confirmed(rim: np.ndarray, reach: np.ndarray, pts: np.ndarray) -> int:
    """The bin fitness's count as it was computed: a cKDTree of the target, queried up to the largest reach."""
    from scipy.spatial import cKDTree

    d, _ = cKDTree(pts, balanced_tree=False, compact_nodes=False).query(rim, k=1,
                                                                         distance_upper_bound=float(reach.max()))
    return int(np.count_nonzero(d <= reach))


def test_the_rim_count_is_the_kdtrees():
    """zcut.registration._confirmed (a hashed cell grid, first hit) against the cKDTree it replaced: random
    clouds, points and rim on a 1 mm lattice (distances exactly at the reach), per-point reaches, a rim far off."""
    from zcut.registration import _confirmed

    rng = np.random.default_rng(71)
    for t in range(120):
        m, r = int(rng.integers(1, 6000)), int(rng.integers(1, 2500))
        pts = rng.normal(0.0, float(rng.choice([0.01, 0.1, 0.3])), (m, 3)) + (0.0, 0.0, 0.8)
        rim = pts[rng.integers(0, m, r)] + rng.normal(0.0, float(rng.choice([0.0005, 0.003, 0.02])), (r, 3))
        if t % 3 == 0:
            pts, rim = np.round(pts / 0.001) * 0.001, np.round(rim / 0.001) * 0.001
        base = float(rng.choice([0.001, 0.003, 10.0 / 3000.0, 0.01]))
        reach = np.maximum(base, rng.uniform(0.0, 2.0 * base, r)) if t % 2 else np.full(r, base)
        got = _confirmed(np.ascontiguousarray(rim), reach, float(reach.max()), np.ascontiguousarray(pts))
        assert got == _kdtree_confirmed(rim, reach, pts), t
    far = np.array([[50.0, 50.0, 50.0], [-1e300, 0.0, 0.0]])
    assert _confirmed(far, np.full(2, 0.003), 0.003, np.zeros((3, 3))) == 0


def test_the_bin_fitness_of_a_frame_is_the_kdtrees(filled, model):
    """pose_fitness at the registered pose and at poses off by up to a centimetre and 2 degrees, with and
    without the camera's intrinsics: the count of the cKDTree of the target's points (TargetPoints.tree,
    still that tree)."""
    from zcut.registration import PIXEL_REACH, _in_view, pose_fitness, transform_points

    frame, _ = filled
    params = RegistrationParams(voxel_mm=1.0)
    m = prepare_icp_model(model, params)
    pixels = bin_pixels(bin_mask(frame.rgb), frame.xyz)
    for K in (frame.intrinsics, None):
        target = prepare_target(frame.xyz[pixels], voxel_m=params.voxel_m, intrinsics=K)
        pts = np.asarray(target.cloud.points)
        assert target.tree.n == len(pts)
        T_reg = register_bin(m, target).T_cam_bin
        fits = []
        for T in (T_reg, T_reg @ ps.turned_pose((0.0, 0.0, 1.0), (0.004, -0.002, 0.0)),
                  T_reg @ ps.turned_pose((2.0, 0.0, 0.0), (0.0, 0.01, 0.003))):
            rim = transform_points(T, m.rim)
            if K is not None:
                rim = rim[_in_view(rim, K)]
                reach = np.maximum(params.fine_correspondence_m, PIXEL_REACH * rim[:, 2] / min(K.fx, K.fy))
            else:
                reach = np.full(len(rim), params.fine_correspondence_m)
            want = _kdtree_confirmed(rim, reach, pts) / len(rim)
            fits.append(pose_fitness(m, target, T, max_correspondence_m=params.fine_correspondence_m))
            assert fits[-1] == want
        assert fits[0] > 0.9 > min(fits[1:])  # the poses tried are told apart
