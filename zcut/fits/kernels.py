"""Numba kernels of the general fits: correspondences through a voxel index of the model, ICP.

The model's index (:class:`ModelIndex`, built once per model by :func:`build_index`) is a voxel
grid over the model's bounding box grown by a margin: each voxel holds the triangle nearest its
centre and the sharp-edge segment nearest its centre. A point (model frame) is matched to the
triangle of its voxel: its point-to-plane residual is exact on that triangle's plane, its distance
is the exact distance to that triangle, less the tangential part a voxel's half-diagonal can account
for (a point near the border of two coplanar triangles may sit in the voxel of the neighbour). The
same for the edges: the exact distance to the nearest segment of the voxel. No k-d tree query and no
Python loop per ICP step: one ICP run from one initial guess is one kernel call.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

__all__ = ["ModelIndex", "build_index", "coarse_search", "edge_distances", "farthest_points", "guess_score", "icp_kernel", "lower_bounds", "occluding_boundary",
           "surface_distances", "window_band", "window_pixels", "window_rays"]


@dataclass(frozen=True, slots=True, eq=False)
class ModelIndex:
    """The voxel index of a part model (model frame, mm).

    Attributes
    ----------
    origin : (3,) float64
        The corner of voxel (0, 0, 0).
    h : float
        Voxel edge (mm).
    tri_grid : (nx, ny, nz) int16 (int32 beyond 32,767 triangles)
        Index of the triangle nearest each voxel's centre.
    a, b, c, n : (m, 3) float64
        The triangles' corners and unit outward normals.
    seg_grid : (nx, ny, nz) int16 (int32 beyond 32,767 segments)
        Index of the sharp-edge segment nearest each voxel's centre (-1: the model has none).
    p0, p1 : (e, 3) float64
        The sharp-edge segments' ends.
    tri : (m, 16) float64
        Per triangle, what a match needs in one row (:func:`triangle_table`): a, b − a, c − a, n, the inverse
        Gram matrix of (b − a, c − a) and the barycentric margin of the match's fast path.
    centre_dist : (nx, ny, nz) float64
        Exact distance of each voxel's centre to the surface: a point of the voxel lies at least this
        less the half-diagonal from it (:func:`lower_bounds`).
    margin : float
        The margin (mm) the grid adds around the model's bounding box: a point outside the grid lies at
        least this far from the surface.
    """

    origin: np.ndarray
    h: float
    tri_grid: np.ndarray
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    n: np.ndarray
    seg_grid: np.ndarray
    p0: np.ndarray
    p1: np.ndarray
    tri: np.ndarray
    centre_dist: np.ndarray
    margin: float


def build_index(v: np.ndarray, t: np.ndarray, normals: np.ndarray, seg0: np.ndarray, seg1: np.ndarray, scene: object,
                *, margin_mm: float, h_mm: float) -> ModelIndex:
    """The index of the mesh (``normals`` outward per triangle, ``scene`` an Open3D RaycastingScene of
    it), the grid ``h_mm`` fine over the bounding box grown by ``margin_mm``."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    lo = v.min(axis=0) - margin_mm
    hi = v.max(axis=0) + margin_mm
    dims = np.maximum(np.ceil((hi - lo) / h_mm).astype(np.int64), 1)
    axes = [lo[i] + h_mm * (np.arange(dims[i]) + 0.5) for i in range(3)]
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    ans = scene.compute_closest_points(o3d.core.Tensor(centres.astype(np.float32)))  # type: ignore[attr-defined,call-overload]  # Open3D stub: dtype and device required
    # int16 where the indices fit: half the memory the ICP's random lookups walk (the same matches)
    tri = ans["primitive_ids"].numpy().astype(_index_dtype(len(t))).reshape(tuple(dims))
    closest = ans["points"].numpy().astype(np.float64)
    cdist = np.linalg.norm(closest - centres.astype(np.float32).astype(np.float64), axis=1).reshape(tuple(dims))
    if len(seg0):
        # the segments sampled densely enough that the nearest sample's segment is the nearest segment
        # to within a small fraction of a voxel
        step = 0.25 * h_mm
        L = np.linalg.norm(seg1 - seg0, axis=1)
        m = np.maximum(2, np.ceil(L / step).astype(np.int64) + 1)
        sid = np.repeat(np.arange(len(seg0)), m)
        s = np.concatenate([np.linspace(0.0, 1.0, k) for k in m])[:, None]
        pts = seg0[sid] + s * (seg1[sid] - seg0[sid])
        _, i = cKDTree(pts).query(centres, k=1)
        seg = sid[i].astype(_index_dtype(len(seg0))).reshape(tuple(dims))
    else:
        seg = np.full(tuple(dims), -1, np.int16)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    n = np.ascontiguousarray(normals, np.float64)
    return ModelIndex(origin=lo.astype(np.float64), h=float(h_mm), tri_grid=tri, a=a, b=b, c=c, n=n, seg_grid=seg,
                      p0=np.ascontiguousarray(seg0, np.float64), p1=np.ascontiguousarray(seg1, np.float64),
                      tri=triangle_table(a, b, c, n, h_mm=float(h_mm)), centre_dist=cdist, margin=float(margin_mm))


# the fast path's margins (:func:`triangle_table`): far above the rounding they cover (~1e-15 relative)
_SLACK_SHARE = 0.25    # the in-plane distance the fast path allows, a share of the slack (0.866 h)
_MIN_SIN2 = 1e-6       # a triangle's smallest sin² of the angle between its edges b − a and c − a
_NORMAL_TOL = 1e-12    # how far n may be from the unit normal of (b − a) × (c − a)
_FACING_REL = 1e-9     # the facing test decided without the closest point when |n·(cam − a)| exceeds this × scale


def triangle_table(a: np.ndarray, b: np.ndarray, c: np.ndarray, n: np.ndarray, *, h_mm: float) -> np.ndarray:
    """Per triangle one row of 16 float64: a, e1 = b − a, e2 = c − a, n, the inverse Gram matrix
    (g11, g12, g22) of (e1, e2), and μ, the barycentric margin of :func:`_fast`.

    A point q whose projection's barycentric coordinates (v, w) (of b and c; computed as the inverse
    Gram matrix times (e1·(q − a), e2·(q − a))) satisfy v ≥ −μ, w ≥ −μ, v + w ≤ 1 + μ lies, in the plane,
    within 2μ Σ|X − G| (X the corners, G their mean) of the triangle — the point of barycentrics
    ((u_i + μ) / (1 + 3μ)) is in it and differs by μ / (1 + 3μ) Σ (3u_i − 1)(X_i − G), |3u_i − 1| ≤ 2 + 6μ.
    μ makes that at most ``_SLACK_SHARE`` × the slack 0.866 h: the exact match (:func:`_match_at`) then finds
    a tangential part below the slack (its rounding is ~1e-15 of the point's distances, in mm) and answers
    d = |r|, which the fast path answers without the closest point. μ = −inf (never the fast path) for a
    triangle that is thin (sin² of its angle at a below ``_MIN_SIN2``: the inverse Gram matrix would amplify
    the rounding), without area, or whose n is not its unit normal to ``_NORMAL_TOL`` (the residual r is then
    not the distance to its plane)."""
    e1 = b - a
    e2 = c - a
    g11 = np.einsum("ij,ij->i", e1, e1)
    g12 = np.einsum("ij,ij->i", e1, e2)
    g22 = np.einsum("ij,ij->i", e2, e2)
    det = g11 * g22 - g12 * g12
    cr = np.cross(e1, e2)
    crn = np.linalg.norm(cr, axis=1)
    ok = (det > _MIN_SIN2 * g11 * g22) & (crn > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        m = cr / crn[:, None]
        off = np.minimum(np.abs(n - m).max(axis=1), np.abs(n + m).max(axis=1))
        ok &= off <= _NORMAL_TOL
        g = (a + b + c) / 3.0
        spread = (np.linalg.norm(a - g, axis=1) + np.linalg.norm(b - g, axis=1) + np.linalg.norm(c - g, axis=1))
        mu = _SLACK_SHARE * 0.8660254037844386 * h_mm / (2.0 * spread)
        inv = 1.0 / det
    out = np.zeros((len(a), 16))
    out[:, 0:3], out[:, 3:6], out[:, 6:9], out[:, 9:12] = a, e1, e2, n
    out[:, 12] = np.where(ok, g22 * inv, 0.0)
    out[:, 13] = np.where(ok, -g12 * inv, 0.0)
    out[:, 14] = np.where(ok, g11 * inv, 0.0)
    out[:, 15] = np.where(ok & np.isfinite(mu), mu, -np.inf)
    return out


def _index_dtype(count: int) -> type:
    """int16 when ``count`` indices (and -1) fit in it, else int32."""
    return np.int16 if count <= np.iinfo(np.int16).max else np.int32


@numba.njit(cache=True, nogil=True, inline="always")
def _closest_on_triangle(px: float, py: float, pz: float, a: np.ndarray, b: np.ndarray, c: np.ndarray,
                         j: int) -> tuple[float, float, float]:
    """The point of triangle ``j`` (a[j], b[j], c[j]) nearest p (Ericson, Real-Time Collision Detection 5.1.5).
    The corners are read by index, not through views ``a[j]``: a view of an array costs numba a reference count's
    increment and decrement (about half of a match's time, measured in the eighteenth round)."""
    a0, a1, a2 = a[j, 0], a[j, 1], a[j, 2]
    b0, b1, b2 = b[j, 0], b[j, 1], b[j, 2]
    c0, c1, c2 = c[j, 0], c[j, 1], c[j, 2]
    abx, aby, abz = b0 - a0, b1 - a1, b2 - a2
    acx, acy, acz = c0 - a0, c1 - a1, c2 - a2
    apx, apy, apz = px - a0, py - a1, pz - a2
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return a0, a1, a2
    bpx, bpy, bpz = px - b0, py - b1, pz - b2
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return b0, b1, b2
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        w = d1 / (d1 - d3)
        return a0 + w * abx, a1 + w * aby, a2 + w * abz
    cpx, cpy, cpz = px - c0, py - c1, pz - c2
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return c0, c1, c2
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return a0 + w * acx, a1 + w * acy, a2 + w * acz
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return b0 + w * (c0 - b0), b1 + w * (c1 - b1), b2 + w * (c2 - b2)
    denom = 1.0 / (va + vb + vc)
    v_ = vb * denom
    w = vc * denom
    return a0 + abx * v_ + acx * w, a1 + aby * v_ + acy * w, a2 + abz * v_ + acz * w


@numba.njit(cache=True, nogil=True, inline="always")
def _cell(qx: float, qy: float, qz: float, origin: np.ndarray, inv_h: float, grid: np.ndarray) -> tuple[int, int, int]:
    """The voxel (i, j, k) of q in ``grid``; i = -1 outside it."""
    i = int(np.floor((qx - origin[0]) * inv_h))
    j = int(np.floor((qy - origin[1]) * inv_h))
    k = int(np.floor((qz - origin[2]) * inv_h))
    if i < 0 or j < 0 or k < 0 or i >= grid.shape[0] or j >= grid.shape[1] or k >= grid.shape[2]:
        return -1, 0, 0
    return i, j, k


@numba.njit(cache=True, nogil=True, inline="always")
def _voxel(qx: float, qy: float, qz: float, origin: np.ndarray, inv_h: float, grid: np.ndarray) -> int:
    i, j, k = _cell(qx, qy, qz, origin, inv_h, grid)
    if i < 0:
        return -1
    return int(grid[i, j, k])


@numba.njit(cache=True, nogil=True, inline="always")
def _match(qx: float, qy: float, qz: float, origin: np.ndarray, inv_h: float, slack: float, grid: np.ndarray,
           a: np.ndarray, b: np.ndarray, c: np.ndarray, n: np.ndarray) -> tuple[int, float, float, float, float, float]:
    """(triangle, distance, plane residual, closest point) of q; triangle -1 outside the grid."""
    return _match_at(_voxel(qx, qy, qz, origin, inv_h, grid), qx, qy, qz, slack, a, b, c, n)


@numba.njit(cache=True, nogil=True, inline="always")
def _match_at(j: int, qx: float, qy: float, qz: float, slack: float, a: np.ndarray, b: np.ndarray, c: np.ndarray,
              n: np.ndarray) -> tuple[int, float, float, float, float, float]:
    """:func:`_match` of q given its voxel's triangle ``j`` (-1: outside the grid)."""
    if j < 0:
        return -1, np.inf, np.inf, 0.0, 0.0, 0.0
    cx, cy, cz = _closest_on_triangle(qx, qy, qz, a, b, c, j)
    dx, dy, dz = qx - cx, qy - cy, qz - cz
    d2 = dx * dx + dy * dy + dz * dz
    r = (qx - a[j, 0]) * n[j, 0] + (qy - a[j, 1]) * n[j, 1] + (qz - a[j, 2]) * n[j, 2]
    tang = np.sqrt(max(d2 - r * r, 0.0)) - slack
    d = abs(r) if tang <= 0.0 else np.sqrt(r * r + tang * tang)
    return j, d, r, cx, cy, cz


@numba.njit(cache=True, nogil=True, inline="always")
def _fast(j: int, qx: float, qy: float, qz: float, tri: np.ndarray) -> tuple[bool, float]:
    """(fast, r): whether q's projection lies within the margin of triangle ``j`` >= 0 (``tri[j]``,
    :func:`triangle_table`), where :func:`_match_at`'s distance is |r|, and r, its plane residual to the bit.
    Not fast: the caller asks :func:`_match_called` (kept out of the inlined loop: inlined with it, its branches
    cost every match ~40 ns, measured in the eighteenth round)."""
    apx, apy, apz = qx - tri[j, 0], qy - tri[j, 1], qz - tri[j, 2]
    # the exact match's residual: (qx - a[j, 0]) * n[j, 0] + ..., the same operands in the same order
    r = apx * tri[j, 9] + apy * tri[j, 10] + apz * tri[j, 11]
    d1 = tri[j, 3] * apx + tri[j, 4] * apy + tri[j, 5] * apz
    d2 = tri[j, 6] * apx + tri[j, 7] * apy + tri[j, 8] * apz
    v = tri[j, 12] * d1 + tri[j, 13] * d2
    w = tri[j, 13] * d1 + tri[j, 14] * d2
    mu = tri[j, 15]
    return v >= -mu and w >= -mu and v + w <= 1.0 + mu, r


@numba.njit(cache=True, nogil=True)
def _match_called(j: int, qx: float, qy: float, qz: float, slack: float, a: np.ndarray, b: np.ndarray, c: np.ndarray,
                  n: np.ndarray) -> tuple[int, float, float, float, float, float]:
    """:func:`_match_at`, called rather than inlined: the fast path's loop stays small (inlined, the exact match's
    branches cost every match ~30 ns, measured in the eighteenth round)."""
    return _match_at(j, qx, qy, qz, slack, a, b, c, n)


@numba.njit(cache=True, nogil=True)
def _closest_called(qx: float, qy: float, qz: float, a: np.ndarray, b: np.ndarray, c: np.ndarray,
                    j: int) -> tuple[float, float, float]:
    """:func:`_closest_on_triangle`, called rather than inlined (:func:`_match_called`)."""
    return _closest_on_triangle(qx, qy, qz, a, b, c, j)


@numba.njit(cache=True, nogil=True, inline="always")
def _match_edge(qx: float, qy: float, qz: float, origin: np.ndarray, inv_h: float, grid: np.ndarray,
                p0: np.ndarray, p1: np.ndarray) -> tuple[float, float, float, float]:
    """(distance, closest point) of q to the edge segment of its voxel; inf outside the grid."""
    return _match_edge_at(_voxel(qx, qy, qz, origin, inv_h, grid), qx, qy, qz, p0, p1)


@numba.njit(cache=True, nogil=True, inline="always")
def _match_edge_at(s: int, qx: float, qy: float, qz: float, p0: np.ndarray,
                   p1: np.ndarray) -> tuple[float, float, float, float]:
    """:func:`_match_edge` of q given its voxel's segment ``s`` (-1: outside the grid)."""
    if s < 0:
        return np.inf, 0.0, 0.0, 0.0
    ex, ey, ez = p1[s, 0] - p0[s, 0], p1[s, 1] - p0[s, 1], p1[s, 2] - p0[s, 2]
    L2 = ex * ex + ey * ey + ez * ez
    w = 0.0
    if L2 > 0.0:
        w = ((qx - p0[s, 0]) * ex + (qy - p0[s, 1]) * ey + (qz - p0[s, 2]) * ez) / L2
        w = min(max(w, 0.0), 1.0)
    cx, cy, cz = p0[s, 0] + w * ex, p0[s, 1] + w * ey, p0[s, 2] + w * ez
    d = np.sqrt((qx - cx) ** 2 + (qy - cy) ** 2 + (qz - cz) ** 2)
    return d, cx, cy, cz


@numba.njit(cache=True, nogil=True)
def surface_distances(points: np.ndarray, R: np.ndarray, t: np.ndarray, origin: np.ndarray, h: float,
                      grid: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray, n: np.ndarray,
                      tri: np.ndarray) -> np.ndarray:
    """Distance (mm) of each camera-frame point to the model posed (R, t) through the index; inf
    outside its grid."""
    inv_h = 1.0 / h
    slack = 0.8660254037844386 * h
    out = np.empty(len(points))
    for i in range(len(points)):
        px, py, pz = points[i, 0] - t[0], points[i, 1] - t[1], points[i, 2] - t[2]
        qx = R[0, 0] * px + R[1, 0] * py + R[2, 0] * pz
        qy = R[0, 1] * px + R[1, 1] * py + R[2, 1] * pz
        qz = R[0, 2] * px + R[1, 2] * py + R[2, 2] * pz
        # the fast path written out here: through an inlined helper numba's loop costs ~40 ns more a point
        j = _voxel(qx, qy, qz, origin, inv_h, grid)
        if j < 0:
            out[i] = np.inf
            continue
        fast, r = _fast(j, qx, qy, qz, tri)
        if fast:
            out[i] = abs(r)
        else:
            _, d, _, _, _, _ = _match_called(j, qx, qy, qz, slack, a, b, c, n)
            out[i] = d
    return out


@numba.njit(cache=True, nogil=True)
def window_band(xyz: np.ndarray, zone: np.ndarray, region: np.ndarray, r0: int, r1: int, c0: int, c1: int, W: int,
                R: np.ndarray, t: np.ndarray, tol: float, origin: np.ndarray, h: float, grid: np.ndarray,
                a: np.ndarray, b: np.ndarray, c: np.ndarray, n: np.ndarray) -> np.ndarray:
    """The points (camera frame) of the zone's pixels in the window (rows ``r0:r1``, columns ``c0:c1`` of an image
    ``W`` wide) and of the ``region``'s pixels (flat, ascending) outside it whose distance to the model posed
    (R, t) (:func:`surface_distances`) is at most ``tol``, in ascending flat order: the last refinement's points
    (``FitParams.fine_window``) in one pass, without the window's index arrays, their union and their gathers.
    ``xyz`` (H·W, 3), ``zone`` (H·W,) bool."""
    inv_h = 1.0 / h
    slack = 0.8660254037844386 * h
    out = np.empty((max(r1 - r0, 0) * max(c1 - c0, 0) + len(region), 3))
    m = 0
    k = 0  # the next region pixel
    nreg = len(region)
    for r in range(r0, r1 + 1):
        # the region's pixels before this window row (outside the window: rows above, or columns left of it)
        lim = r * W + c0 if r < r1 else zone.shape[0]
        while k < nreg and region[k] < lim:
            f = region[k]
            k += 1
            rr, cc = f // W, f % W
            if r0 <= rr < r1 and c0 <= cc < c1:
                continue  # a window pixel: walked below
            m = _band_point(xyz, f, R, t, tol, origin, inv_h, slack, grid, a, b, c, n, out, m)
        if r == r1:
            break
        for cc in range(c0, c1):
            f = r * W + cc
            if zone[f]:
                m = _band_point(xyz, f, R, t, tol, origin, inv_h, slack, grid, a, b, c, n, out, m)
        # the region's pixels right of the window on this row
        lim = (r + 1) * W
        while k < nreg and region[k] < lim:
            f = region[k]
            k += 1
            if r0 <= f // W < r1 and c0 <= f % W < c1:
                continue
            m = _band_point(xyz, f, R, t, tol, origin, inv_h, slack, grid, a, b, c, n, out, m)
    return out[:m]


@numba.njit(cache=True, nogil=True, inline="always")
def _band_point(xyz: np.ndarray, f: int, R: np.ndarray, t: np.ndarray, tol: float, origin: np.ndarray, inv_h: float,
                slack: float, grid: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray, n: np.ndarray,
                out: np.ndarray, m: int) -> int:
    """Append the point of pixel ``f`` to ``out[m]`` when it lies within ``tol`` of the posed model; the new count."""
    px, py, pz = xyz[f, 0] - t[0], xyz[f, 1] - t[1], xyz[f, 2] - t[2]
    qx = R[0, 0] * px + R[1, 0] * py + R[2, 0] * pz
    qy = R[0, 1] * px + R[1, 1] * py + R[2, 1] * pz
    qz = R[0, 2] * px + R[1, 2] * py + R[2, 2] * pz
    _, d, _, _, _, _ = _match(qx, qy, qz, origin, inv_h, slack, grid, a, b, c, n)
    if d <= tol:
        out[m, 0], out[m, 1], out[m, 2] = xyz[f, 0], xyz[f, 1], xyz[f, 2]
        return m + 1
    return m


@numba.njit(cache=True, nogil=True)
def edge_distances(points: np.ndarray, R: np.ndarray, t: np.ndarray, origin: np.ndarray, h: float,
                   grid: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """Distance (mm) of each camera-frame point to the posed model's sharp edges; inf outside the grid."""
    inv_h = 1.0 / h
    out = np.empty(len(points))
    for i in range(len(points)):
        px, py, pz = points[i, 0] - t[0], points[i, 1] - t[1], points[i, 2] - t[2]
        qx = R[0, 0] * px + R[1, 0] * py + R[2, 0] * pz
        qy = R[0, 1] * px + R[1, 1] * py + R[2, 1] * pz
        qz = R[0, 2] * px + R[1, 2] * py + R[2, 2] * pz
        d, _, _, _ = _match_edge(qx, qy, qz, origin, inv_h, grid, p0, p1)
        out[i] = d
    return out


@numba.njit(cache=True, nogil=True)
def lower_bounds(points: np.ndarray, R: np.ndarray, t: np.ndarray, origin: np.ndarray, h: float,
                 centre_dist: np.ndarray, margin: float) -> np.ndarray:
    """A lower bound of the distance of each of ``points`` (camera frame) to the model posed by (R, t):
    its voxel centre's distance less the half-diagonal (the triangle inequality), the grid's margin
    outside it; less a micron for the float32 of the exact distances it stands in front of."""
    out = np.empty(len(points))
    inv_h = 1.0 / h
    half = 0.8660254037844386 * h + 1e-3
    nx, ny, nz = centre_dist.shape
    for i in range(len(points)):
        px, py, pz = points[i, 0] - t[0], points[i, 1] - t[1], points[i, 2] - t[2]
        qx = R[0, 0] * px + R[1, 0] * py + R[2, 0] * pz
        qy = R[0, 1] * px + R[1, 1] * py + R[2, 1] * pz
        qz = R[0, 2] * px + R[1, 2] * py + R[2, 2] * pz
        a = int(np.floor((qx - origin[0]) * inv_h))
        b = int(np.floor((qy - origin[1]) * inv_h))
        c = int(np.floor((qz - origin[2]) * inv_h))
        if a < 0 or b < 0 or c < 0 or a >= nx or b >= ny or c >= nz:
            out[i] = margin - 1e-3
        else:
            out[i] = centre_dist[a, b, c] - half
    return out


@numba.njit(cache=True, nogil=True)
def guess_score(points: np.ndarray, edge_points: np.ndarray, R: np.ndarray, t: np.ndarray, tol: float,
                edge_tol: float, origin: np.ndarray, h: float, grid: np.ndarray, a: np.ndarray, b: np.ndarray,
                c: np.ndarray, n: np.ndarray, tri: np.ndarray, seg_grid: np.ndarray, p0: np.ndarray,
                p1: np.ndarray) -> tuple[float, float, float]:
    """(share of ``points`` within ``tol`` of the posed model, mean of min(distance, tol) / tol, share of
    ``edge_points`` within ``edge_tol`` of its sharp edges; 1 without edge points)."""
    d = surface_distances(points, R, t, origin, h, grid, a, b, c, n, tri)
    inl = 0.0
    near = 0.0
    for i in range(len(d)):
        if d[i] <= tol:
            inl += 1.0
        near += min(d[i], tol) / tol
    e_inl = 1.0
    if len(edge_points):
        de = edge_distances(edge_points, R, t, origin, h, seg_grid, p0, p1)
        e_inl = 0.0
        for i in range(len(de)):
            if de[i] <= edge_tol:
                e_inl += 1.0
        e_inl /= len(de)
    m = max(len(d), 1)
    return inl / m, near / m, e_inl


@numba.njit(cache=True, nogil=True, inline="always")
def _rodrigues(w0: float, w1: float, w2: float) -> np.ndarray:
    a = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    R = np.eye(3)
    if a < 1e-15:
        return R
    k0, k1, k2 = w0 / a, w1 / a, w2 / a
    K = np.array([[0.0, -k2, k1], [k2, 0.0, -k0], [-k1, k0, 0.0]])
    return R + np.sin(a) * K + (1.0 - np.cos(a)) * (K @ K)


@numba.njit(cache=True, nogil=True)
def _stiff(H: np.ndarray, weak: float) -> bool:
    """Whether every eigenvalue of the symmetric positive semi-definite 6 × 6 ``H`` is surely at least ``weak`` ×
    its largest, so that :func:`numpy.linalg.eigh` would find no eigenvalue below ``weak`` × its largest (the
    ICP's edges then act in no direction: the eigen-decomposition is not needed). A Cholesky factorisation of
    H − 2 ``weak`` trace(H) I that meets no pivot <= 0: the trace bounds the largest eigenvalue, the factor 2 is a
    margin orders of magnitude above the rounding of both the factorisation and LAPACK's eigenvalues (~1e-15
    × trace). False whenever in doubt (a NaN, a pivot <= 0): the caller then decomposes as before."""
    tr = 0.0
    for u in range(6):
        tr += H[u, u]
    if not tr > 0.0 or not weak < 0.5:
        return False
    mu = 2.0 * weak * tr
    L = np.zeros((6, 6))
    for j in range(6):
        d = H[j, j] - mu
        for m in range(j):
            d -= L[j, m] * L[j, m]
        if not d > 1e-12 * tr:
            return False
        L[j, j] = np.sqrt(d)
        for i in range(j + 1, 6):
            v = H[i, j]
            for m in range(j):
                v -= L[i, m] * L[j, m]
            L[i, j] = v / L[j, j]
    return True


@numba.njit(cache=True, nogil=True)
def icp_kernel(points: np.ndarray, R0: np.ndarray, t0: np.ndarray, iterations: int, gate_mm: float, k: float,
               floor_mm: float, edge_points: np.ndarray, edge_gate_mm: float, extent: float, origin: np.ndarray,
               h: float, grid: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray, n: np.ndarray,
               tri: np.ndarray, seg_grid: np.ndarray, p0: np.ndarray, p1: np.ndarray, weak: float,
               robust_mm: float = 0.0) -> tuple[np.ndarray, np.ndarray, float, int]:
    """Point-to-plane ICP of ``points`` (camera frame) from (R0, t0) (model -> camera): the steps of
    :func:`zcut.fits.icp.icp` (surface matches gated and facing the camera, the occluding boundary's
    ``edge_points`` matched to the sharp edges in the directions the surface leaves free — those of
    eigenvalue below ``weak`` × the largest of the surface's normal matrix — Cauchy weights) with the
    index's correspondences. (R, t, rms of the last step's matches, their number).

    ``robust_mm`` > 0: each surface match is weighted by Tukey's biweight of its distance d at that scale,
    (1 − (d / ``robust_mm``)²)², and none beyond it (re-weighted at every step: the last refinement's
    M-estimate, ``FitParams.fine_robust``); the rms stays the unweighted one of the matches. 0: no weights
    (the steps before, to the bit)."""
    R = R0.copy()
    t = t0.copy()
    gate = gate_mm
    rms = np.inf
    n_used = 0
    inv_h = 1.0 / h
    slack = 0.8660254037844386 * h
    use_edges = len(edge_points) > 0 and len(p0) > 0
    if use_edges and seg_grid.shape != grid.shape:
        raise ValueError("the edges' grid and the triangles' grid differ in shape")
    scale = np.array([extent, extent, extent, 1.0, 1.0, 1.0])
    H = np.zeros((6, 6))
    g = np.zeros(6)
    He = np.zeros((6, 6))
    ge = np.zeros(6)
    sc0, sc1, sc2 = scale[0], scale[1], scale[2]
    # the size of the model frame's coordinates (the grid's box): the facing test's rounding scales with it
    box = 0.0
    for ax in range(3):
        box += abs(origin[ax]) + h * grid.shape[ax]
    for _ in range(iterations):
        H[:] = 0.0
        g[:] = 0.0
        # camera centre in the model frame: -R^T t
        camx = -(R[0, 0] * t[0] + R[1, 0] * t[1] + R[2, 0] * t[2])
        camy = -(R[0, 1] * t[0] + R[1, 1] * t[1] + R[2, 1] * t[2])
        camz = -(R[0, 2] * t[0] + R[1, 2] * t[1] + R[2, 2] * t[2])
        # a fast match (no closest point c) faces the camera when n·(cam − a) clears this: n·(cam − c) differs
        # from it by n·(c − a) (c in the triangle's plane: 0 up to n's 1e-12) and the rounding (~1e-15 × scale)
        facing_tol = _FACING_REL * (1.0 + abs(camx) + abs(camy) + abs(camz) + box)
        ssq = 0.0
        n_used = 0
        # the normal matrix's upper triangle and the gradient in scalars (registers, not an array's memory):
        # each entry's products added in the points' order, as the loop over an array added them
        g0 = g1 = g2 = g3 = g4 = g5 = 0.0
        h00 = h01 = h02 = h03 = h04 = h05 = 0.0
        h11 = h12 = h13 = h14 = h15 = 0.0
        h22 = h23 = h24 = h25 = 0.0
        h33 = h34 = h35 = 0.0
        h44 = h45 = 0.0
        h55 = 0.0
        for i in range(len(points)):
            px, py, pz = points[i, 0] - t[0], points[i, 1] - t[1], points[i, 2] - t[2]
            qx = R[0, 0] * px + R[1, 0] * py + R[2, 0] * pz
            qy = R[0, 1] * px + R[1, 1] * py + R[2, 1] * pz
            qz = R[0, 2] * px + R[1, 2] * py + R[2, 2] * pz
            j = _voxel(qx, qy, qz, origin, inv_h, grid)
            if j < 0:
                continue
            fast, r = _fast(j, qx, qy, qz, tri)
            cx = cy = cz = 0.0
            if fast:
                d = abs(r)
            else:
                _, d, r, cx, cy, cz = _match_called(j, qx, qy, qz, slack, a, b, c, n)
            if not d < gate:
                continue
            nx, ny, nz = n[j, 0], n[j, 1], n[j, 2]
            if fast:
                f0 = nx * (camx - tri[j, 0]) + ny * (camy - tri[j, 1]) + nz * (camz - tri[j, 2])
                if f0 < -facing_tol:
                    continue
                if not f0 > facing_tol:  # too near the plane to tell: the closest point, as the exact match
                    cx, cy, cz = _closest_called(qx, qy, qz, a, b, c, j)
                    if nx * (camx - cx) + ny * (camy - cy) + nz * (camz - cz) <= 0.0:
                        continue
            elif nx * (camx - cx) + ny * (camy - cy) + nz * (camz - cz) <= 0.0:
                continue
            r0 = (qy * nz - qz * ny) / sc0
            r1 = (qz * nx - qx * nz) / sc1
            r2 = (qx * ny - qy * nx) / sc2
            r3, r4, r5 = nx, ny, nz
            ssq += r * r
            n_used += 1
            if robust_mm > 0.0:  # the rows and the residual times sqrt(w): H += w J Jᵀ, g += w J r
                u = d / robust_mm
                if not u < 1.0:
                    continue
                sw = 1.0 - u * u
                r0, r1, r2, r3, r4, r5, r = r0 * sw, r1 * sw, r2 * sw, r3 * sw, r4 * sw, r5 * sw, r * sw
            g0, h00, h01, h02, h03, h04, h05 = (
                g0 + r0 * r, h00 + r0 * r0, h01 + r0 * r1, h02 + r0 * r2, h03 + r0 * r3, h04 + r0 * r4, h05 + r0 * r5)
            g1, h11, h12, h13, h14, h15 = (
                g1 + r1 * r, h11 + r1 * r1, h12 + r1 * r2, h13 + r1 * r3, h14 + r1 * r4, h15 + r1 * r5)
            g2, h22, h23, h24, h25 = (
                g2 + r2 * r, h22 + r2 * r2, h23 + r2 * r3, h24 + r2 * r4, h25 + r2 * r5)
            g3, h33, h34, h35 = (
                g3 + r3 * r, h33 + r3 * r3, h34 + r3 * r4, h35 + r3 * r5)
            g4, h44, h45 = (
                g4 + r4 * r, h44 + r4 * r4, h45 + r4 * r5)
            g5, h55 = (
                g5 + r5 * r, h55 + r5 * r5)
        if n_used < 6:
            break
        H[0, 0], H[0, 1], H[0, 2], H[0, 3], H[0, 4], H[0, 5] = h00, h01, h02, h03, h04, h05
        H[1, 1], H[1, 2], H[1, 3], H[1, 4], H[1, 5] = h11, h12, h13, h14, h15
        H[2, 2], H[2, 3], H[2, 4], H[2, 5] = h22, h23, h24, h25
        H[3, 3], H[3, 4], H[3, 5] = h33, h34, h35
        H[4, 4], H[4, 5] = h44, h45
        H[5, 5] = h55
        g[0], g[1], g[2], g[3], g[4], g[5] = g0, g1, g2, g3, g4, g5
        for u in range(1, 6):
            for w in range(u):
                H[u, w] = H[w, u]
        if use_edges:
            ge0 = ge1 = ge2 = ge3 = ge4 = ge5 = 0.0
            he00 = he01 = he02 = he04 = he05 = he10 = he11 = he12 = he13 = he15 = he20 = he21 = 0.0
            he22 = he23 = he24 = he31 = he32 = he33 = he40 = he42 = he44 = he50 = he51 = he55 = 0.0
            ne = 0
            egate = max(edge_gate_mm, min(gate, 2.0 * edge_gate_mm))
            s3 = edge_gate_mm / 3.0
            for i in range(len(edge_points)):
                px, py, pz = edge_points[i, 0] - t[0], edge_points[i, 1] - t[1], edge_points[i, 2] - t[2]
                qx = R[0, 0] * px + R[1, 0] * py + R[2, 0] * pz
                qy = R[0, 1] * px + R[1, 1] * py + R[2, 1] * pz
                qz = R[0, 2] * px + R[1, 2] * py + R[2, 2] * pz
                # the edges' grid and the triangles' are one grid (:func:`build_index`): one voxel for both
                vi, vj, vk = _cell(qx, qy, qz, origin, inv_h, grid)
                de, ex, ey, ez = _match_edge_at(-1 if vi < 0 else int(seg_grid[vi, vj, vk]), qx, qy, qz, p0, p1)
                if not de < egate:
                    continue
                # a silhouette point lies on the part: a mixed pixel between it and what lies
                # behind (off every surface) says nothing of where the edge is
                if vi < 0:
                    continue
                js = int(grid[vi, vj, vk])
                fast, rs = _fast(js, qx, qy, qz, tri)
                if fast:
                    ds = abs(rs)
                else:
                    _, ds, _, _, _, _ = _match_called(js, qx, qy, qz, slack, a, b, c, n)
                if not ds < gate:
                    continue
                w2 = 1.0 / (1.0 + (de / s3) ** 2)
                # rows m of J = d(q + w x q + tau)/d(w, tau) = [-[q]x, I], scaled: jmu its entries off the
                # zeros (row m: 1 at column 3 + m); He[u, w] += w2 J[m, u] J[m, w] and ge[u] += w2 J[m, u] res[m]
                # for m = 0, 1, 2 in turn, the entries without a zero factor (adding a product of 0 changes no
                # sum: the sums start at +0 and never become -0)
                j01, j02 = qz / sc1, -qy / sc2
                j10, j12 = -qz / sc0, qx / sc2
                j20, j21 = qy / sc0, -qx / sc1
                res0, res1, res2 = qx - ex, qy - ey, qz - ez
                ju = w2 * j01
                ge1 += ju * res0
                he11 += ju * j01
                he12 += ju * j02
                he13 += ju * 1.0
                ju = w2 * j02
                ge2 += ju * res0
                he21 += ju * j01
                he22 += ju * j02
                he23 += ju * 1.0
                ju = w2 * 1.0
                ge3 += ju * res0
                he31 += ju * j01
                he32 += ju * j02
                he33 += ju * 1.0
                ju = w2 * j10
                ge0 += ju * res1
                he00 += ju * j10
                he02 += ju * j12
                he04 += ju * 1.0
                ju = w2 * j12
                ge2 += ju * res1
                he20 += ju * j10
                he22 += ju * j12
                he24 += ju * 1.0
                ju = w2 * 1.0
                ge4 += ju * res1
                he40 += ju * j10
                he42 += ju * j12
                he44 += ju * 1.0
                ju = w2 * j20
                ge0 += ju * res2
                he00 += ju * j20
                he01 += ju * j21
                he05 += ju * 1.0
                ju = w2 * j21
                ge1 += ju * res2
                he10 += ju * j20
                he11 += ju * j21
                he15 += ju * 1.0
                ju = w2 * 1.0
                ge5 += ju * res2
                he50 += ju * j20
                he51 += ju * j21
                he55 += ju * 1.0
                ne += 1
            He[:] = 0.0
            He[0, 0] = he00
            He[0, 1] = he01
            He[0, 2] = he02
            He[0, 4] = he04
            He[0, 5] = he05
            He[1, 0] = he10
            He[1, 1] = he11
            He[1, 2] = he12
            He[1, 3] = he13
            He[1, 5] = he15
            He[2, 0] = he20
            He[2, 1] = he21
            He[2, 2] = he22
            He[2, 3] = he23
            He[2, 4] = he24
            He[3, 1] = he31
            He[3, 2] = he32
            He[3, 3] = he33
            He[4, 0] = he40
            He[4, 2] = he42
            He[4, 4] = he44
            He[5, 0] = he50
            He[5, 1] = he51
            He[5, 5] = he55
            ge[0], ge[1], ge[2], ge[3], ge[4], ge[5] = ge0, ge1, ge2, ge3, ge4, ge5
            if ne >= 3 and not _stiff(H, weak):
                ev, V = np.linalg.eigh(H)
                top = max(ev.max(), 1e-300)
                P = np.zeros((6, 6))
                nw = 0
                for u in range(6):
                    if ev[u] < weak * top:
                        P += np.outer(V[:, u], V[:, u])
                        nw += 1
                if nw:
                    H = H + P @ He @ P
                    g = g + P @ ge
        x = np.linalg.solve(H + 1e-12 * np.eye(6), -g) / scale
        dR = _rodrigues(x[0], x[1], x[2])
        Rinv = dR @ R.T
        tinv = dR @ (-(R.T @ t)) + x[3:]
        R = Rinv.T.copy()
        t = -(R @ tinv)
        rms = np.sqrt(ssq / n_used)
        gate = min(gate, max(k * rms, k * floor_mm, 0.5 * gate))
        # converged: the step moves no point of the model by a micron
        if max(np.abs(x[:3]).max() * extent, np.abs(x[3:]).max()) < 1e-3:
            break
    U, _, Vt = np.linalg.svd(R)
    R = U @ Vt
    return R, t, rms, n_used


@numba.njit(cache=True, nogil=True)
def coarse_search(points: np.ndarray, edge_points: np.ndarray, Rs: np.ndarray, ts: np.ndarray, iterations: int,
                  gate_mm: float, k: float, floor_mm: float, edge_gate_mm: float, extent: float, score_tol: float,
                  edge_tol: float, origin: np.ndarray, h: float, grid: np.ndarray, a: np.ndarray, b: np.ndarray,
                  c: np.ndarray, n: np.ndarray, tri: np.ndarray, seg_grid: np.ndarray, p0: np.ndarray, p1: np.ndarray,
                  weak: float, stop_inl: float, stop_edge: float) -> tuple[int, np.ndarray, np.ndarray, float]:
    """The coarse stage of a region's search in one call: from each guess (``Rs[i]``, ``ts[i]``) in turn,
    ``iterations`` steps of :func:`icp_kernel`, scored by :func:`guess_score` as inl − 0.01 near + 0.5 e_inl
    (the last term only with ``edge_points``); the first of the best scores wins. Stops after a guess
    with inl >= ``stop_inl`` and e_inl >= ``stop_edge`` (``stop_inl`` > 1: never). (index of the best,
    its R, its t, its score); index -1 without guesses."""
    best = -1
    best_score = -np.inf
    best_R = np.eye(3)
    best_t = np.zeros(3)
    for i in range(len(Rs)):
        R, t, _, _ = icp_kernel(points, Rs[i], ts[i], iterations, gate_mm, k, floor_mm, edge_points, edge_gate_mm,
                                extent, origin, h, grid, a, b, c, n, tri, seg_grid, p0, p1, weak)
        inl, near, e_inl = guess_score(points, edge_points, R, t, score_tol, edge_tol, origin, h, grid, a, b, c, n,
                                       tri, seg_grid, p0, p1)
        score = inl - 0.01 * near + (0.5 * e_inl if len(edge_points) else 0.0)
        if best < 0 or score > best_score:
            best = i
            best_score = score
            best_R = R
            best_t = t
        if inl >= stop_inl and e_inl >= stop_edge:
            break
    return best, best_R, best_t, best_score


@numba.njit(cache=True, nogil=True)
def farthest_points(points: np.ndarray, count: int) -> np.ndarray:
    """Indices of ``count`` (>= 1) of ``points`` (m >= 1, 3) by farthest point sampling from the first: each next
    one the first of the largest distance to those taken. The arithmetic of the NumPy loop it replaces
    (:func:`zcut.fits.icp.shifted_poses`): ``np.linalg.norm(points - points[j], axis=1)`` is
    sqrt((dx² + dy²) + dz²) and ``np.argmax`` the first largest, so the same indices."""
    m = len(points)
    out = np.empty(count, np.int64)
    out[0] = 0
    dmin = np.empty(m)
    for i in range(m):
        dx, dy, dz = points[i, 0] - points[0, 0], points[i, 1] - points[0, 1], points[i, 2] - points[0, 2]
        dmin[i] = np.sqrt(dx * dx + dy * dy + dz * dz)
    for s in range(1, count):
        j = 0
        for i in range(1, m):
            if dmin[i] > dmin[j]:
                j = i
        out[s] = j
        for i in range(m):
            dx, dy, dz = points[i, 0] - points[j, 0], points[i, 1] - points[j, 1], points[i, 2] - points[j, 2]
            dmin[i] = min(dmin[i], np.sqrt(dx * dx + dy * dy + dz * dz))
    return out


@numba.njit(cache=True, nogil=True)
def window_rays(r0: int, r1: int, c0: int, c1: int, fx: float, fy: float, cx: float, cy: float, R: np.ndarray,
                t: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols), row-major, of the pixels of the window [r0, r1) × [c0, c1) whose ray from the camera
    meets the box [lo, hi] of the model posed by (R, t) (model -> camera; the box in the model frame):
    the slab test per ray."""
    ox = -(R[0, 0] * t[0] + R[1, 0] * t[1] + R[2, 0] * t[2])
    oy = -(R[0, 1] * t[0] + R[1, 1] * t[1] + R[2, 1] * t[2])
    oz = -(R[0, 2] * t[0] + R[1, 2] * t[1] + R[2, 2] * t[2])
    o = (ox, oy, oz)
    n = max(r1 - r0, 0) * max(c1 - c0, 0)
    rows = np.empty(n, np.int64)
    cols = np.empty(n, np.int64)
    m = 0
    for r in range(r0, r1):
        v = (r - cy) / fy
        for col in range(c0, c1):
            u = (col - cx) / fx
            dm = (R[0, 0] * u + R[1, 0] * v + R[2, 0], R[0, 1] * u + R[1, 1] * v + R[2, 1],
                  R[0, 2] * u + R[1, 2] * v + R[2, 2])
            near = 0.0
            far = np.inf
            for a in range(3):
                if dm[a] == 0.0:
                    if o[a] < lo[a] or o[a] > hi[a]:
                        far = -1.0
                    continue
                t0 = (lo[a] - o[a]) / dm[a]
                t1 = (hi[a] - o[a]) / dm[a]
                near = max(near, min(t0, t1))
                far = min(far, max(t0, t1))
            if far >= near:
                rows[m] = r
                cols[m] = col
                m += 1
    return rows[:m], cols[:m]


@numba.njit(cache=True, nogil=True)
def occluding_boundary(xyz: np.ndarray, valid: np.ndarray, flat: np.ndarray, H: int, W: int,
                       jump_mm: float) -> np.ndarray:
    """The pixels of the region ``flat`` (ascending) whose 4-neighbour outside it (on the H × W grid) is invalid or
    lies farther than ``jump_mm`` behind (z[nb] > z[f] + ``jump_mm``), ascending: the NumPy test of
    :func:`zcut.fits.fit._occluding_boundary` pixel by pixel (the same comparisons, so the same pixels).
    ``xyz`` (H·W, 3), ``valid`` (H·W,) bool."""
    n = len(flat)
    if n == 0:
        return flat[:0].copy()
    r0, r1, c0, c1 = H, -1, W, -1
    for i in range(n):
        r, c = flat[i] // W, flat[i] % W
        r0, r1, c0, c1 = min(r0, r), max(r1, r), min(c0, c), max(c1, c)
    r0, c0 = max(r0 - 1, 0), max(c0 - 1, 0)
    bw = min(c1 + 2, W) - c0
    inside = np.zeros((min(r1 + 2, H) - r0) * bw, np.bool_)
    for i in range(n):
        r, c = flat[i] // W, flat[i] % W
        inside[(r - r0) * bw + (c - c0)] = True
    out = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        f = flat[i]
        r, c = f // W, f % W
        zf = xyz[f, 2] + jump_mm
        for s in range(4):
            rr, cc = r, c
            if s == 0:
                cc = c + 1
            elif s == 1:
                cc = c - 1
            elif s == 2:
                rr = r + 1
            else:
                rr = r - 1
            if rr < 0 or rr >= H or cc < 0 or cc >= W or inside[(rr - r0) * bw + (cc - c0)]:
                continue
            nb = rr * W + cc
            if not valid[nb] or xyz[nb, 2] > zf:
                out[m] = f
                m += 1
                break
    return out[:m]


@numba.njit(cache=True, nogil=True)
def window_pixels(zone: np.ndarray, region: np.ndarray, r0: int, r1: int, c0: int, c1: int, W: int) -> np.ndarray:
    """The zone's pixels (flat, ascending) in the window (rows ``r0:r1``, columns ``c0:c1`` of an image ``W``
    wide) that are not in ``region`` (flat, ascending): the window's zone pixels less a region's, without the
    window's index arrays and ``np.isin``. ``zone`` (H·W,) bool."""
    out = np.empty(max(r1 - r0, 0) * max(c1 - c0, 0), np.int64)
    m = 0
    k = 0
    nreg = len(region)
    for r in range(r0, r1):
        for cc in range(c0, c1):
            f = r * W + cc
            if not zone[f]:
                continue
            while k < nreg and region[k] < f:
                k += 1
            if k < nreg and region[k] == f:
                continue
            out[m] = f
            m += 1
    return out[:m]
