"""The registration's per-frame work of branch h/reg4, held to the forms it replaced, bit for bit:

- the bin fitness's rim in view and reaches (``zcut.registration._rim_in_view``) against ``_in_view`` and the
  NumPy expression of the reach;
- the target's cell grid kept across ``pose_fitness`` calls (``TargetPoints._cells``: built once, rebuilt only
  for a wider reach) against the cKDTree count and a fresh target's answer;
- the point-to-plane update summed in scalars (``zcut.icp_fast._point_to_plane``) against the literal 6 x 6
  sums, and ICP's query cells by a product (``_correspond``) against brute force on cell faces.
"""

from __future__ import annotations

import numpy as np
import pipeline_scene as ps
import pytest

from zcut.binmask import bin_mask, bin_pixels
from zcut.cloud import Intrinsics
from zcut.icp_fast import _correspond, _ldlt_solve, _point_to_plane, _vector6_to_matrix, build_grid
from zcut.params import RegistrationParams
from zcut.registration import (
    PIXEL_REACH,
    _in_view,
    _rim_in_view,
    pose_fitness,
    prepare_icp_model,
    prepare_target,
    register_bin,
    transform_points,
)

filled = pytest.fixture(scope="module")(ps.filled_bin_scene)
model = pytest.fixture(scope="module")(ps.shifted_bin_model)


def _view_and_reach_numpy(rim: np.ndarray, K: Intrinsics, dist: float) -> tuple[np.ndarray, np.ndarray]:
    """What ``_rim_fitness`` computed before: the rim in view, then ``np.maximum`` of the reaches."""
    kept = rim[_in_view(rim, K)]
    return kept, np.maximum(dist, PIXEL_REACH * kept[:, 2] / min(K.fx, K.fy))


@pytest.mark.parametrize("case", ["random", "behind the camera", "on the image's edges", "empty", "far"])
def test_the_rim_in_view_and_its_reach_are_numpys(case):
    rng = np.random.default_rng(6311)
    K = Intrinsics(fx=575.5, fy=575.25, cx=319.5, cy=239.5, width=640, height=480)
    for t in range(40):
        n = int(rng.integers(20, 3000))
        rim = np.column_stack([rng.normal(0.0, 0.4, n), rng.normal(0.0, 0.3, n), rng.uniform(0.3, 2.0, n)])
        if case == "behind the camera":
            rim[::3, 2] *= -1.0
            rim[1::7, 2] = 0.0
        elif case == "on the image's edges":  # u or v at -0.5, W - 0.5 and H - 0.5 up to rounding
            z = rim[:, 2]
            rim[0::4, 0] = (-0.5 - K.cx) * z[0::4] / K.fx
            rim[1::4, 0] = (K.width - 0.5 - K.cx) * z[1::4] / K.fx
            rim[2::4, 1] = (-0.5 - K.cy) * z[2::4] / K.fy
            rim[3::4, 1] = (K.height - 0.5 - K.cy) * z[3::4] / K.fy
            rim[::5] = np.nextafter(rim[::5], rng.choice([-np.inf, np.inf]))
        elif case == "empty":
            rim = rim[:0]
        elif case == "far":
            rim *= 1e6
        dist = float(rng.choice([0.001, 10.0 / 3000.0, 0.05]))
        want_rim, want_reach = _view_and_reach_numpy(rim, K, dist)
        got_rim, got_reach = _rim_in_view(np.ascontiguousarray(rim), K.fx, K.fy, K.cx, K.cy, float(K.width),
                                          float(K.height), dist, min(K.fx, K.fy))
        assert got_rim.tobytes() == want_rim.tobytes(), t
        assert got_reach.tobytes() == want_reach.tobytes(), t
        if case == "on the image's edges":
            assert 0 < len(got_rim) < len(rim)


def _kdtree_fitness(target, m, T: np.ndarray, dist: float) -> float:
    """The bin fitness as a cKDTree of the target's points counted it."""
    from scipy.spatial import cKDTree

    rim = transform_points(T, m.rim)
    K = target.intrinsics
    if K is not None:
        rim, reach = _view_and_reach_numpy(rim, K, dist)
    else:
        reach = np.full(len(rim), dist)
    if len(rim) == 0:
        return 0.0
    d, _ = cKDTree(target.cloud.points).query(rim, k=1, distance_upper_bound=float(reach.max()))
    return int(np.count_nonzero(d <= reach)) / len(rim)


def test_the_kept_cell_grid_answers_as_a_fresh_one(filled, model):
    """One target asked at several poses and distances, the reach growing and shrinking: each answer the
    cKDTree's and a fresh target's; the grid rebuilt only when a wider reach needs wider cells."""
    frame, _ = filled
    params = RegistrationParams(voxel_mm=1.0)
    m = prepare_icp_model(model, params)
    pixels = bin_pixels(bin_mask(frame.rgb), frame.xyz)
    rng = np.random.default_rng(4721)
    for K in (frame.intrinsics, None):
        target = prepare_target(frame.xyz[pixels], voxel_m=params.voxel_m, intrinsics=K)
        T_reg = register_bin(m, target).T_cam_bin
        widths = []
        for dist in (0.0033, 0.0033, 0.001, 0.02, 0.0005, 0.0034, 0.02):
            T = T_reg @ ps.turned_pose(rng.normal(0.0, 0.5, 3), rng.normal(0.0, 0.002, 3))
            got = pose_fitness(m, target, T, max_correspondence_m=dist)
            fresh = prepare_target(frame.xyz[pixels], voxel_m=params.voxel_m, intrinsics=K)
            assert got == pose_fitness(m, fresh, T, max_correspondence_m=dist)
            assert got == _kdtree_fitness(target, m, T, dist)
            cells = target._cells
            assert cells is not None
            widths.append(cells[0])
        assert widths[0] == widths[1] == widths[2]  # kept: the same or a narrower reach
        assert widths[3] > widths[2] and widths[3] == widths[4] == widths[5] == widths[6]  # rebuilt once, wider


def _point_to_plane_literal(pcd, gpts, gnrm, src, dst, n) -> np.ndarray:  # type: ignore[no-untyped-def]
    """The update as the 6 x 6 array form summed it, in Python floats (IEEE doubles, the same operations)."""
    if n == 0:
        return np.eye(4)
    JTJ = np.zeros((6, 6))
    JTr = np.zeros(6)
    for c in range(n):
        i, j = int(src[c]), int(dst[c])
        s0, s1, s2 = (float(v) for v in pcd[i])
        n0, n1, n2 = (float(v) for v in gnrm[j])
        g0, g1, g2 = (float(v) for v in gpts[j])
        r = (s0 - g0) * n0 + (s1 - g1) * n1 + (s2 - g2) * n2
        J = (s1 * n2 - s2 * n1, s2 * n0 - s0 * n2, s0 * n1 - s1 * n0, n0, n1, n2)
        for a in range(6):
            JTr[a] = float(JTr[a]) + J[a] * r
            for b in range(a, 6):
                JTJ[a, b] = float(JTJ[a, b]) + J[a] * J[b]
    for a in range(6):
        for b in range(a):
            JTJ[a, b] = JTJ[b, a]
    return _vector6_to_matrix(_ldlt_solve(JTJ, -JTr))


@pytest.mark.parametrize("case", ["random", "a plane", "one correspondence", "none"])
def test_the_point_to_plane_update_is_the_array_forms(case):
    rng = np.random.default_rng(6311)
    for t in range(6):
        m = int(rng.integers(5, 400))
        gpts = rng.normal(0.0, 0.1, (m, 3)) + (0.0, 0.0, 0.8)
        gnrm = rng.normal(size=(m, 3))
        if case == "a plane":
            gpts[:, 2] = 0.8
            gnrm[:] = (0.0, 0.0, 1.0)
        gnrm /= np.linalg.norm(gnrm, axis=1, keepdims=True)
        pcd = gpts[rng.integers(0, m, m)] + rng.normal(0.0, 0.002, (m, 3))
        n = {"random": m, "a plane": m, "one correspondence": 1, "none": 0}[case]
        src = rng.permutation(m)[:max(n, 1)].astype(np.int64)
        dst = rng.integers(0, m, max(n, 1)).astype(np.int64)
        got = _point_to_plane(pcd, gpts, gnrm, src, dst, n)
        assert got.tobytes() == _point_to_plane_literal(pcd, gpts, gnrm, src, dst, n).tobytes(), t


def test_query_cells_by_a_product_keep_the_exact_nearest():
    """Queries a few ulps either side of every cell face, of the padded grid's outer faces and of a point's
    distance: the nearest within the distance (ties to the lower index), as brute force finds it."""
    rng = np.random.default_rng(4721)
    dist = 10.0 / 3000.0
    pts = rng.uniform(0.0, 0.03, (400, 3)) + (0.2, -0.1, 0.7)
    grid = build_grid(pts, None, radius=dist)
    o, cell = grid.origin, grid.cell
    nx, ny, nz = (int(v) for v in grid.dims)
    faces = [o[a] + cell * np.arange(-2, int(grid.dims[a]) + 3) for a in range(3)]
    q = []
    for _ in range(3000):
        p = pts[rng.integers(len(pts))] + rng.normal(0.0, dist, 3)
        a = int(rng.integers(3))
        p[a] = np.nextafter(rng.choice(faces[a]), rng.choice([-np.inf, np.inf]))
        q.append(p)
    q = np.array(q)
    m = len(q)
    state = (np.empty(m), np.empty(m, np.int64), np.empty(m, np.int64), np.empty(m, np.int64))
    n, e2 = _correspond(q, np.arange(m), o, cell, nx, ny, nz, grid.near_start, grid.near, grid.near_dist,
                        grid.points, grid.order, dist, *state)
    d2 = ((q[:, None, :] - pts[None, :, :]) ** 2).sum(axis=2)  # model order: the lowest index of a tie first
    best = d2.argmin(axis=1)
    hit = d2[np.arange(m), best] < dist * dist
    assert n == int(hit.sum())
    assert np.array_equal(state[2][:n], np.flatnonzero(hit))
    assert np.array_equal(grid.order[state[3][:n]], best[hit])


def _transform_rows_literal(T: np.ndarray, pcd: np.ndarray) -> np.ndarray:
    """Eigen's 4 x 4 times (x, y, z, 1), then the division by w, in Python floats."""
    out = np.empty_like(pcd)
    for i, (x, y, z) in enumerate(pcd.tolist()):
        w = float(T[3, 0]) * x + float(T[3, 1]) * y + float(T[3, 2]) * z + float(T[3, 3])
        for r in range(3):
            out[i, r] = (float(T[r, 0]) * x + float(T[r, 1]) * y + float(T[r, 2]) * z + float(T[r, 3])) / w
    return out


@pytest.mark.parametrize("case", ["rigid", "projective", "huge coordinates"])
def test_transform_rows_is_the_division_form(case):
    from zcut.icp_fast import _transform_rows

    rng = np.random.default_rng(6311)
    for t in range(20):
        T = ps.turned_pose(rng.normal(0.0, 20.0, 3), rng.normal(0.0, 0.5, 3))
        pcd = rng.normal(0.0, 0.5, (500, 3))
        if case == "projective":
            T[3] = rng.normal(0.0, 0.1, 4) + (0.0, 0.0, 0.0, 1.0)
            T[3, :3][t % 3] = 0.0
        elif case == "huge coordinates":  # some rows overflow to inf: w is NaN there, as in the division form
            pcd[::7] *= 1e300
            pcd[2::7] = 1e308
            pcd[1::11] = 0.0
        got = pcd.copy()
        with np.errstate(over="ignore", invalid="ignore"):
            want = _transform_rows_literal(T, pcd)
        _transform_rows(T, got)
        assert got.tobytes() == want.tobytes(), t
