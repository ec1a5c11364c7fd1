"""The matches' fast path (docs/fits.md, eighteenth round) gives the exact match's answers to the bit: a point whose
projection lies within its voxel triangle's margin (:func:`zcut.fits.kernels.triangle_table`) is answered |r|
without its closest point, and the ICP decides such a point's facing test without it where the sign is clear.
The oracles: ``kernels._match`` (the exact match, point by point) and tests/zcut/fits/kernel_reference.py (the ICP
kernel before the ninth round, on the exact match)."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from fit_scenes import K_TEST, hex_nut_mesh, icosphere, pose, render, rotation
from prepared_models import prepared

from zcut.fits.kernels import _match, triangle_table


@numba.njit(cache=False)
def _exact_distances(points: np.ndarray, R: np.ndarray, t: np.ndarray, origin: np.ndarray, h: float,
                     grid: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray,
                     n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(distance, plane residual) of each point by the exact match, one point at a time."""
    inv_h = 1.0 / h
    slack = 0.8660254037844386 * h
    d = np.empty(len(points))
    r = np.empty(len(points))
    for i in range(len(points)):
        px, py, pz = points[i, 0] - t[0], points[i, 1] - t[1], points[i, 2] - t[2]
        qx = R[0, 0] * px + R[1, 0] * py + R[2, 0] * pz
        qy = R[0, 1] * px + R[1, 1] * py + R[2, 1] * pz
        qz = R[0, 2] * px + R[1, 2] * py + R[2, 2] * pz
        _, d[i], r[i], _, _, _ = _match(qx, qy, qz, origin, inv_h, slack, grid, a, b, c, n)
    return d, r


def _box_mesh(sx: float, sy: float, sz: float) -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[x, y, z] for x in (0, sx) for y in (0, sy) for z in (0, sz)], float) - [sx / 2, sy / 2, sz / 2]
    t = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, t


_MODELS = {"nut": hex_nut_mesh, "box": lambda: _box_mesh(30.0, 12.0, 6.0), "sphere": lambda: icosphere(8.0, 2)}


def _fast_share(points: np.ndarray, R: np.ndarray, t: np.ndarray, ix: object) -> float:
    """The share of ``points`` the fast path answers (its test, in NumPy)."""
    q = (points - t) @ R
    cell = np.floor((q - ix.origin) / ix.h).astype(np.int64)  # type: ignore[attr-defined]
    inside = ((cell >= 0) & (cell < np.array(ix.tri_grid.shape))).all(axis=1)  # type: ignore[attr-defined]
    j = ix.tri_grid[tuple(cell[inside].T)].astype(np.int64)  # type: ignore[attr-defined]
    tri = ix.tri  # type: ignore[attr-defined]
    ap = q[inside] - tri[j, 0:3]
    d1, d2 = (ap * tri[j, 3:6]).sum(axis=1), (ap * tri[j, 6:9]).sum(axis=1)
    v, w = tri[j, 12] * d1 + tri[j, 13] * d2, tri[j, 13] * d1 + tri[j, 14] * d2
    mu = tri[j, 15]
    return float(((v >= -mu) & (w >= -mu) & (v + w <= 1 + mu)).sum() / max(len(points), 1))


@pytest.mark.parametrize("name", sorted(_MODELS))
def test_the_fast_distances_are_the_exact_matches_to_the_bit(name: str) -> None:
    """surface_distances and guess_score against the exact match point by point: points on the surface, near it
    (noise 0.05-3 mm), spread over the grid's box and outside it, at three poses; most take the fast path."""
    from zcut.fits.kernels import guess_score, surface_distances

    v, t = _MODELS[name]()
    model = prepared(v, t)
    ix = model.index
    assert ix is not None and np.isfinite(ix.tri[:, 15]).all()
    rng = np.random.default_rng(5)
    s = model.samples[rng.choice(len(model.samples), 3000)]
    nrm = model.normals[rng.choice(len(model.samples), 3000)]
    hi = ix.origin + ix.h * np.array(ix.tri_grid.shape)
    q = np.concatenate([s, s + rng.normal(0, 0.05, s.shape), s + rng.uniform(-3, 3, (len(s), 1)) * nrm,
                        s + rng.normal(0, 1.0, s.shape), rng.uniform(ix.origin - 2, hi + 2, (3000, 3))])
    for T in (np.eye(4), pose(rotation((1, 0.3, 0), 25), (2.0, -1.0, 300.0)),
              pose(rotation((0, 1, 0.2), 140), (-20.0, 12.0, 310.0))):
        R, tt = np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3])
        pts = np.ascontiguousarray(q @ R.T + tt)
        got = surface_distances(pts, R, tt, ix.origin, ix.h, ix.tri_grid, ix.a, ix.b, ix.c, ix.n, ix.tri)
        want, _ = _exact_distances(pts, R, tt, ix.origin, ix.h, ix.tri_grid, ix.a, ix.b, ix.c, ix.n)
        assert np.array_equal(got, want)
        assert np.isinf(got).any() and np.isfinite(got).any()
        assert _fast_share(pts, R, tt, ix) > 0.4
        for tol in (0.1, 1.0):
            inl, near, e_inl = guess_score(pts, np.zeros((0, 3)), R, tt, tol, 1.0, ix.origin, ix.h, ix.tri_grid,
                                           ix.a, ix.b, ix.c, ix.n, ix.tri, ix.seg_grid, ix.p0, ix.p1)
            m = len(want)
            assert inl == float((want <= tol).sum()) / m and e_inl == 1.0
            acc = 0.0
            for d in want:  # the kernel's sum, in its order
                acc += min(d, tol) / tol
            assert near == acc / m
    empty = np.zeros((0, 3))
    assert len(surface_distances(empty, np.eye(3), np.zeros(3), ix.origin, ix.h, ix.tri_grid, ix.a, ix.b, ix.c,
                                 ix.n, ix.tri)) == 0


@pytest.mark.parametrize("name", ["nut", "box"])
def test_the_icp_kernel_with_the_fast_path_equals_the_exact_kernel(name: str) -> None:
    """icp_kernel (fast matches, the facing test decided without the closest point where its sign is clear)
    against the pre-ninth-round kernel on exact matches, to the bit: a scene of the part seen from the camera
    (the facing test rejects the far side), from poses near and far, with and without silhouette points,
    and points behind the part (whose matches the facing test must reject)."""
    from kernel_reference import icp_kernel_reference

    from zcut.fits.fit import _Frame, _occluding_boundary
    from zcut.fits.icp import EDGE_WEAK
    from zcut.fits.kernels import icp_kernel

    v, t = _MODELS[name]()
    model = prepared(v, t)
    ix = model.index
    assert ix is not None
    T = pose(rotation((1, 0.3, 0), 25), (2.0, -1.0, 300.0))
    xyz, ids = render([(v, t, T)], floor_z_mm=330)
    rng = np.random.default_rng(17)
    noisy = xyz + rng.normal(0, 0.05, xyz.shape)
    valid = np.isfinite(noisy).all(axis=2)
    frame = _Frame(xyz=noisy, valid=valid, zone=valid & (ids > 0), K=K_TEST)
    flat = np.flatnonzero((ids.reshape(-1) == 1) & valid.reshape(-1))
    pts = np.ascontiguousarray(noisy.reshape(-1, 3)[flat])
    # the far side's points too (the model's samples posed): their matches face away from the camera
    back = model.samples[rng.choice(len(model.samples), 400)] @ T[:3, :3].T + T[:3, 3]
    edge = np.ascontiguousarray(noisy.reshape(-1, 3)[_occluding_boundary(frame, flat, 1.5)])
    assert len(pts) > 200 and len(edge) > 10
    checked = 0
    for p in (pts, np.ascontiguousarray(np.concatenate([pts, back]))):
        for e in (edge, np.zeros((0, 3))):
            for axis, deg, shift, its in (((0, 0, 1), 3, (0.3, -0.2, 0.1), 30), ((1, 0.2, 0), 12, (1.5, 1.0, -0.5), 30),
                                          ((0.3, 1, 0), 35, (3.0, -2.0, 1.0), 4)):
                T0 = T @ pose(rotation(axis, deg), shift)
                args = (p, np.ascontiguousarray(T0[:3, :3]), np.ascontiguousarray(T0[:3, 3]), its, 4.0, 3.0, 0.1, e,
                        1.5, float(model.extent_mm), ix.origin, ix.h, ix.tri_grid, ix.a, ix.b, ix.c, ix.n)
                got = icp_kernel(*args, ix.tri, ix.seg_grid, ix.p0, ix.p1, EDGE_WEAK)
                want = icp_kernel_reference(*args, ix.seg_grid, ix.p0, ix.p1, EDGE_WEAK)
                assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
                assert got[2] == want[2] or (np.isnan(got[2]) and np.isnan(want[2]))
                assert got[3] == want[3]
                checked += 1
    assert checked == 12


def test_the_triangle_table_refuses_the_fast_path_where_its_margin_is_not_proven() -> None:
    """A triangle without area, a sliver (sin² of its angle below 1e-6), a normal that is not its own: μ = −inf,
    and those triangles' matches are the exact ones; a sound triangle gets μ > 0 and its inverse Gram matrix."""
    a = np.array([[0.0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0]])
    b = np.array([[1.0, 0, 0], [1, 0, 0], [1, 0, 0], [1, 0, 0], [2, 0, 0]])
    c = np.array([[0.0, 1, 0], [2, 0, 0], [1, 1e-4, 0], [0, 1, 0], [4, 1e-12, 0]])
    n = np.array([[0.0, 0, 1], [0, 0, 0], [0, 0, 1], [0, 0.01, 0.99995], [0, 0, 1]])
    tab = triangle_table(a, b, c, n, h_mm=0.3)
    assert tab[0, 15] > 0 and np.isneginf(tab[1:, 15]).all()
    e1, e2 = b[0] - a[0], c[0] - a[0]
    G = np.array([[e1 @ e1, e1 @ e2], [e1 @ e2, e2 @ e2]])
    assert np.allclose([[tab[0, 12], tab[0, 13]], [tab[0, 13], tab[0, 14]]], np.linalg.inv(G))
    # an outward normal of either orientation is its own
    assert triangle_table(a[:1], b[:1], c[:1], -n[:1], h_mm=0.3)[0, 15] == tab[0, 15]
    # the margin keeps the in-plane distance within a quarter of the slack: 2 μ Σ|X − G| = 0.25 · 0.866 h
    g = (a[0] + b[0] + c[0]) / 3
    spread = sum(np.linalg.norm(x - g) for x in (a[0], b[0], c[0]))
    assert np.isclose(2 * tab[0, 15] * spread, 0.25 * 0.8660254037844386 * 0.3)
