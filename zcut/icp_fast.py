"""ICP on a model kept across frames: Open3D 0.20's ``registration_icp`` with a prebuilt cell grid.

:func:`zcut.registration.register_bin` aligns a frame's bin points (the *source*) to the bin model
(the *target*), so the structure the correspondences are searched in is the model's, the same for
every frame of a replay. Open3D's ``registration_icp`` builds a KD-tree of its target on every call
(6.2 of the 12.6-15.8 CPU ms of a one-iteration call on the 28,920-point fine model); here the
model's points are sorted once into a grid of cells at least the correspondence distance wide
(:func:`build_grid`), and the iterations run in one numba kernel (:func:`icp`).

What is Open3D's and kept as it is (Open3D 0.20, ``pipelines/registration/Registration.cpp``,
``TransformationEstimation.cpp``, ``utility/Eigen.cpp``, ``geometry/KDTreeFlann.cpp``):

- the source is transformed by ``init`` unless ``init`` is the identity to Eigen's ``isIdentity``
  (1e-12), then by each update in turn (never recomputed from the accumulated pose), each point as
  Eigen multiplies a 4 x 4 matrix by ``(x, y, z, 1)``; the pose is ``update @ pose``;
- a source point's correspondence is its nearest model point when the squared distance, summed as
  nanoflann sums it (``(dx² + dy²) + dz²``), is below ``max_distance²`` (``SearchHybrid`` with one
  neighbour: ``lower_bound`` on the squared radius keeps only distances strictly below it);
  correspondences in source order; ``fitness`` = correspondences / source points, ``inlier_rmse`` =
  sqrt(sum of squared distances / correspondences), both 0 without correspondences;
- point-to-plane: per correspondence r = (vs - vt)·nt and J = (vs × nt, nt), JᵀJ and Jᵀr summed with
  weight 1 (the L2 loss), solved by Eigen's pivoting LDLT (pivots of magnitude below the smallest
  normal double give a zero component) for -Jᵀr, the 6-vector x turned into Rz(x2) Ry(x1) Rx(x0)
  through quaternions as Eigen's ``AngleAxisd`` products, translation x[3:]; no correspondence: the
  identity;
- point-to-point: Eigen's ``umeyama`` without scaling (the SVD of the cross-covariance, the last
  singular direction flipped when det U det V < 0);
- ``max_iteration`` iterations at most; after each, stop when both the fitness and the RMSE moved by
  less than ``relative_fitness`` and ``relative_rmse`` (absolute differences, despite the names).

What differs, within rounding: Open3D reduces its sums over threads (TBB) in an order that varies
from call to call (its poses differ by up to ~1e-16 between calls), Eigen's LDLT, SVD and small
products may round differently from the loops here, and an exact tie between two model points
at the same distance goes to the lower model index here, to nanoflann's traversal order there. This
kernel is serial and deterministic: the same input gives the same bits. The reference is kept:
:func:`icp_open3d` runs Open3D's own ``registration_icp`` on the same input and counts its iterations.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import numba
import numpy as np

from .errors import InputShapeError, ParameterError, describe_array

_T = TypeVar("_T")

__all__ = ["MAX_GRID_CELLS", "IcpGrid", "IcpOutcome", "build_grid", "icp", "icp_open3d"]

#: Largest number of cells of a grid's dense start table; a model whose extent would need more at
#: the correspondence distance gets wider cells (still exact: a cell only has to be at least as wide
#: as the distance).
MAX_GRID_CELLS = 1 << 24
#: A cell is this much wider than the distance, so that rounding in ``(x - origin) / cell`` cannot
#: put a point within the distance two cells away.
_CELL_MARGIN = 1.0 + 1e-6


@dataclass(frozen=True, slots=True)
class IcpGrid:
    """A model's points sorted into cubic cells, for correspondence searches within ``radius``.

    Attributes
    ----------
    radius : float
        The largest correspondence distance the grid answers (metres).
    cell : float
        Cell width (metres), at least ``radius``.
    origin : (3,) float64 ndarray
        Corner of cell (0, 0, 0).
    dims : (3,) int64 ndarray
        Cells along x, y, z; cell (i, j, k) is number ``(i * ny + j) * nz + k``.
    start : (nx * ny * nz + 1,) int64 ndarray
        The points of cell c are rows ``start[c]:start[c + 1]`` of ``points``.
    points, normals : (N, 3) float64 ndarray
        The model's points and normals (zeros when it has none), sorted by cell.
    order : (N,) int64 ndarray
        Each sorted row's index in the model as given.
    has_normals : bool
    near_start : ((nx + 2) * (ny + 2) * (nz + 2) + 1,) int64 ndarray
        The grid padded by one cell on every side: the rows of ``points`` in the 27 cells around padded
        cell (i, j, k) (that is, around cell (i - 1, j - 1, k - 1), clipped to the grid) are
        ``near[near_start[c]:near_start[c + 1]]`` for ``c = (i * (ny + 2) + j) * (nz + 2) + k``.
    near : (27 N,) int32 ndarray
        Those rows, cell after cell (a search reads one run instead of nine), each cell's in increasing
        order of their distance to the cell's centre (padded cell (i, j, k): ``origin + (i - 0.5, j - 0.5,
        k - 0.5) * cell``).
    near_dist : (27 N,) float64 ndarray
        Those distances: a search stops at the first row farther from the centre than the query is plus
        its best distance so far (the triangle inequality; :func:`_correspond`).
    """

    radius: float
    cell: float
    origin: np.ndarray
    dims: np.ndarray
    start: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    order: np.ndarray
    has_normals: bool
    near_start: np.ndarray
    near: np.ndarray
    near_dist: np.ndarray


@dataclass(frozen=True, slots=True)
class IcpOutcome:
    """What one ICP run gives (Open3D's ``RegistrationResult`` and the iterations it ran).

    Attributes
    ----------
    transformation : (4, 4) float64 ndarray
        Source frame -> target frame.
    fitness : float
        Share of the source points with a correspondence at the final pose.
    inlier_rmse : float
        RMSE of the correspondences' distances at the final pose (metres); 0 without any.
    iterations : int
        Updates computed (1 .. ``max_iteration``).
    n_correspondences : int
    """

    transformation: np.ndarray
    fitness: float
    inlier_rmse: float
    iterations: int
    n_correspondences: int


def build_grid(points: np.ndarray, normals: np.ndarray | None, *, radius: float) -> IcpGrid:
    """Sort a model's points into cells at least ``radius`` wide (once per model and distance).

    Parameters
    ----------
    points : (N, 3) float ndarray
        Finite model points (metres).
    normals : (N, 3) float ndarray or None
        Their normals (point-to-plane needs them).
    radius : float
        The largest correspondence distance the grid will be asked for (metres, > 0).

    Returns
    -------
    IcpGrid
    """
    p = np.ascontiguousarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputShapeError(f"points must be an (N, 3) float array, got {describe_array(p)}")
    if not np.isfinite(p).all():
        raise InputShapeError("points must be finite")
    if normals is None:
        n = np.zeros_like(p)
    else:
        n = np.ascontiguousarray(normals, dtype=np.float64)
        if n.shape != p.shape:
            raise InputShapeError(f"normals must match points {p.shape}, got {describe_array(n)}")
    if not (math.isfinite(radius) and radius > 0):
        raise ParameterError(f"build_grid: radius must be a finite number > 0, got {radius!r}")
    cell = radius * _CELL_MARGIN
    if len(p) == 0:
        origin, dims = np.zeros(3), np.zeros(3, np.int64)
        return IcpGrid(float(radius), cell, origin, dims, np.zeros(1, np.int64), p, n, np.zeros(0, np.int64),
                       normals is not None, np.zeros(28, np.int64), np.zeros(0, np.int32), np.zeros(0))
    lo, hi = p.min(axis=0), p.max(axis=0)
    extent = hi - lo
    # the padded grid of the neighbour lists too (wider cells change no answer, only the runs read)
    while np.prod(np.floor(extent / cell) + 3.0) > MAX_GRID_CELLS:
        cell *= 2.0
    dims = (np.floor(extent / cell) + 1).astype(np.int64)
    ijk = np.minimum(np.floor((p - lo) / cell).astype(np.int64), dims - 1)
    lin = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    order = np.argsort(lin, kind="stable")
    start = np.zeros(int(np.prod(dims)) + 1, np.int64)
    np.cumsum(np.bincount(lin, minlength=len(start) - 1), out=start[1:])
    gpts = np.ascontiguousarray(p[order])
    origin = lo.astype(np.float64)
    near_start, near, near_dist = _neighbour_lists(start, int(dims[0]), int(dims[1]), int(dims[2]), gpts, origin,
                                                   float(cell))
    return IcpGrid(float(radius), float(cell), origin, dims, start, gpts, np.ascontiguousarray(n[order]),
                   order.astype(np.int64), normals is not None, near_start, near, near_dist)


@numba.njit(cache=True, nogil=True)
def _neighbour_lists(start: np.ndarray, nx: int, ny: int, nz: int, gpts: np.ndarray, origin: np.ndarray, cell: float
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:attr:`IcpGrid.near_start`, :attr:`IcpGrid.near` and :attr:`IcpGrid.near_dist` from the cells'
    ``start``: per padded cell, the rows of the (up to) 9 columns of 3 cells around it, sorted by their
    distance to the cell's centre (insertion sort: a cell lists a few dozen)."""
    py, pz = ny + 2, nz + 2
    cells = (nx + 2) * py * pz
    # each padded cell's count, summed separably: over z, then y, then x (3 cells each, clipped)
    sz = np.zeros((nx, ny, pz), np.int64)
    for x in range(nx):
        for y in range(ny):
            base = (x * ny + y) * nz
            for c in range(pz):
                z0, z1 = max(c - 2, 0), min(c, nz - 1)
                if z0 <= z1:
                    sz[x, y, c] = start[base + z1 + 1] - start[base + z0]
    syz = np.zeros((nx, py, pz), np.int64)
    for x in range(nx):
        for b in range(py):
            for y in range(max(b - 2, 0), min(b, ny - 1) + 1):
                for c in range(pz):
                    syz[x, b, c] += sz[x, y, c]
    near_start = np.zeros(cells + 1, np.int64)
    for a in range(nx + 2):
        for x in range(max(a - 2, 0), min(a, nx - 1) + 1):
            for b in range(py):
                q = (a * py + b) * pz + 1
                for c in range(pz):
                    near_start[q + c] += syz[x, b, c]
    for q in range(cells):
        near_start[q + 1] += near_start[q]
    near = np.empty(near_start[cells], np.int32)
    w = 0
    for a in range(nx + 2):
        for b in range(py):
            for c in range(pz):
                q = (a * py + b) * pz + c
                if near_start[q + 1] == near_start[q]:
                    continue
                z0, z1 = max(c - 2, 0), min(c, nz - 1)
                for ax in range(max(a - 2, 0), min(a, nx - 1) + 1):
                    for ay in range(max(b - 2, 0), min(b, ny - 1) + 1):
                        base = (ax * ny + ay) * nz
                        for k in range(start[base + z0], start[base + z1 + 1]):
                            near[w] = k
                            w += 1
    near_dist = np.empty(near.shape[0])
    for a in range(nx + 2):
        cx = origin[0] + (a - 0.5) * cell
        for b in range(py):
            cy = origin[1] + (b - 0.5) * cell
            for c in range(pz):
                q = (a * py + b) * pz + c
                s0, s1 = near_start[q], near_start[q + 1]
                if s1 == s0:
                    continue
                cz = origin[2] + (c - 0.5) * cell
                for t in range(s0, s1):
                    k = near[t]
                    dx = gpts[k, 0] - cx
                    dy = gpts[k, 1] - cy
                    dz = gpts[k, 2] - cz
                    near_dist[t] = math.sqrt(dx * dx + dy * dy + dz * dz)
                for t in range(s0 + 1, s1):
                    d = near_dist[t]
                    k = near[t]
                    u = t - 1
                    while u >= s0 and near_dist[u] > d:
                        near_dist[u + 1] = near_dist[u]
                        near[u + 1] = near[u]
                        u -= 1
                    near_dist[u + 1] = d
                    near[u + 1] = k
    return near_start, near, near_dist


# --------------------------------------------------------------------------------------- kernel
@numba.njit(cache=True, nogil=True)
def _transform_rows(T: np.ndarray, pcd: np.ndarray) -> None:
    """``pcd <- T (x, y, z, 1)`` row by row, summed as Eigen sums a 4 x 4 matrix times a 4-vector
    (column by column); the homogeneous coordinate is 1 for finite points. Where w is exactly 1 (every
    finite point under a rigid transform: 0 x = ±0, the sum 1) the division by it is exact and left out
    (the same bits, without 3 divisions a point)."""
    for i in range(pcd.shape[0]):
        x, y, z = pcd[i, 0], pcd[i, 1], pcd[i, 2]
        w = T[3, 0] * x + T[3, 1] * y + T[3, 2] * z + T[3, 3]
        if w == 1.0:
            for r in range(3):
                pcd[i, r] = T[r, 0] * x + T[r, 1] * y + T[r, 2] * z + T[r, 3]
        else:
            for r in range(3):
                pcd[i, r] = (T[r, 0] * x + T[r, 1] * y + T[r, 2] * z + T[r, 3]) / w


@numba.njit(cache=True, nogil=True)
def _matmul4(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    C = np.empty((4, 4))
    for r in range(4):
        for c in range(4):
            C[r, c] = A[r, 0] * B[0, c] + A[r, 1] * B[1, c] + A[r, 2] * B[2, c] + A[r, 3] * B[3, c]
    return C


@numba.njit(cache=True, nogil=True)
def _cell_order(pcd: np.ndarray, origin: np.ndarray, cell: float, nx: int, ny: int) -> np.ndarray:
    """The source rows grouped by the grid column (x, y cell) they fall in, in row order within each
    (rows outside the grid's columns last; a counting sort): searched in this order, consecutive queries
    read the same cells (Open3D's voxel grid gives its points in hash order). Only the order of the
    searches changes: each answer is the same."""
    m = pcd.shape[0]
    outside = nx * ny
    key = np.empty(m, np.int64)
    first = np.zeros(outside + 2, np.int64)
    for i in range(m):
        fx = math.floor((pcd[i, 0] - origin[0]) / cell)
        fy = math.floor((pcd[i, 1] - origin[1]) / cell)
        k = outside
        if 0.0 <= fx < nx and 0.0 <= fy < ny:
            k = int(fx) * ny + int(fy)
        key[i] = k
        first[k + 1] += 1
    for k in range(outside + 1):
        first[k + 1] += first[k]
    order = np.empty(m, np.int64)
    for i in range(m):
        order[first[key[i]]] = i
        first[key[i]] += 1
    return order


@numba.njit(cache=True, nogil=True, inline="always")
def _d2(x: float, y: float, z: float, gpts: np.ndarray, k: int) -> float:
    """Squared distance as nanoflann's L2 adaptor sums it for 3 dimensions: (dx² + dy²) + dz²."""
    dx = x - gpts[k, 0]
    dy = y - gpts[k, 1]
    dz = z - gpts[k, 2]
    return dx * dx + dy * dy + dz * dz


#: A search stops at a row whose distance to the cell's centre exceeds the query's plus its best so far by
#: more than this share (and :func:`_correspond`'s absolute margin): rounding in those distances (a few
#: float64 ulps) cannot then skip a row at or below the best squared distance, a tie included.
_REACH_SLACK = 1e-9


@numba.njit(cache=True, nogil=True)
def _pairs(m: int, near: np.ndarray, best: np.ndarray, src: np.ndarray,
           dst: np.ndarray) -> tuple[int, float]:  # pragma: no cover - numba
    """The correspondences found among the first ``m`` sources (``near[i] >= 0``) written to ``src`` / ``dst`` in source order, as Open3D
    lists (and sums) them; returns their count and the sum of their squared distances ``best``."""
    n = 0
    error2 = 0.0
    for i in range(m):
        j = near[i]
        if j >= 0:
            src[n] = i
            dst[n] = j
            n += 1
            error2 += best[i]
    return n, error2


@numba.njit(cache=True, nogil=True)
def _correspond(pcd: np.ndarray, order: np.ndarray, origin: np.ndarray, cell: float, nx: int, ny: int, nz: int,
                near_start: np.ndarray, near_rows: np.ndarray, near_dist: np.ndarray, gpts: np.ndarray,
                gorder: np.ndarray, max_distance: float, best: np.ndarray, near: np.ndarray, src: np.ndarray,
                dst: np.ndarray) -> tuple[int, float]:
    """Each source point's nearest grid point with a squared distance below ``max_distance²`` (ties:
    the lowest model index), searched in the 27 cells around it: ``src[:n]`` and ``dst[:n]`` (grid
    rows), in source order; ``(n, sum of the squared distances in that order)``. The points are
    searched in ``order`` (any permutation: the answers do not depend on it).

    The 27 cells' rows are listed together in increasing distance to the cell's centre c
    (:attr:`IcpGrid.near`): a row p with |p - c| > |q - c| + (best distance so far) is farther from the
    query q than the best (|q - p| >= |p - c| - |q - c|), and so is every row after it: the search
    stops there, with a slack for rounding (:data:`_REACH_SLACK`, and an absolute margin for
    coordinates far from zero). The answer is the least (squared distance, model index) of the 27
    cells' rows either way.

    A query's cell is ``floor((x - origin) * (1 / cell))``, a product instead of :func:`build_grid`'s
    quotient: the two differ by a few ulps of the cell index, far less than the cell's margin over the
    distance (``cell = radius (1 + 1e-6)``), so a model point within the distance is still in one of the
    27 cells, and one of a query skipped as outside the padded grid is not within it; the centre the
    bound is measured from is that of the cell used, as the lists' distances are. Only which cell's list
    is read may change, never the answer."""
    r2 = max_distance * max_distance
    ox, oy, oz = origin[0], origin[1], origin[2]
    py, pz = ny + 2, nz + 2
    slack = 1.0 + _REACH_SLACK
    margin = _REACH_SLACK * (abs(ox) + abs(oy) + abs(oz) + cell * (nx + ny + nz + 6))
    inv = 1.0 / cell
    for i in order:
        x, y, z = pcd[i, 0], pcd[i, 1], pcd[i, 2]
        near[i] = -1
        fx, fy, fz = math.floor((x - ox) * inv), math.floor((y - oy) * inv), math.floor((z - oz) * inv)
        if not (-1.0 <= fx <= nx and -1.0 <= fy <= ny and -1.0 <= fz <= nz):
            continue
        ix, iy, iz = int(fx), int(fy), int(fz)
        c = ((ix + 1) * py + iy + 1) * pz + iz + 1
        ex = x - (ox + (ix + 0.5) * cell)
        ey = y - (oy + (iy + 0.5) * cell)
        ez = z - (oz + (iz + 0.5) * cell)
        dq = math.sqrt(ex * ex + ey * ey + ez * ez)
        b = r2
        bj = -1
        reach = (max_distance + dq) * slack + margin
        for q in range(near_start[c], near_start[c + 1]):
            if near_dist[q] > reach:
                break
            k = int(near_rows[q])
            d2 = _d2(x, y, z, gpts, k)
            if d2 < b or (d2 == b and bj >= 0 and gorder[k] < gorder[bj]):
                b = d2
                bj = k
                reach = (math.sqrt(b) + dq) * slack + margin
        if bj >= 0:
            near[i] = bj
            best[i] = b
    return _pairs(pcd.shape[0], near, best, src, dst)


@numba.njit(cache=True, nogil=True)
def _correspond_kept(pcd: np.ndarray, order: np.ndarray, origin: np.ndarray, cell: float, nx: int, ny: int, nz: int,
                     near_start: np.ndarray, near_rows: np.ndarray, near_dist: np.ndarray, gpts: np.ndarray,
                     gorder: np.ndarray, max_distance: float, best: np.ndarray, near: np.ndarray, src: np.ndarray,
                     dst: np.ndarray, gap: np.ndarray, moved: np.ndarray, search_all: bool) -> tuple[int, float]:
    """:func:`_correspond`'s answers (the same ``src[:n]``, ``dst[:n]``, ``n`` and sum, bit for bit), without
    searching again for a source point whose nearest model point cannot have changed since its last search.

    A search also bounds the distance to every other model point: it goes on past the nearest (distance d1)
    until the second nearest is found (d2, or the correspondence distance when there is none within it: rows
    past the search's end are farther by the triangle inequality, :func:`_correspond`'s argument, and points
    outside the 27 cells lie more than a cell away). ``gap[i]`` keeps d2 - d1 (-1 when the point had no
    correspondence) and ``moved[i]`` the distance the point has moved since (:func:`_transform_moved`, rounded
    up). While ``gap[i] > 2 moved[i]`` (with :data:`_REACH_SLACK` and the absolute margin), the old nearest is
    still the strictly nearest model point, by more than rounding can blur: its squared distance, computed as
    the search computes it, is the answer when below ``max_distance²``, and there is no correspondence
    otherwise (every other point is farther still). A tie (d2 = d1) is never kept. ``search_all``: search every
    point (the first pass of a run). In the fine pass of a frame's registration ~95 % of the queries after the
    first pass are answered so."""
    r2 = max_distance * max_distance
    ox, oy, oz = origin[0], origin[1], origin[2]
    py, pz = ny + 2, nz + 2
    slack = 1.0 + _REACH_SLACK
    margin = _REACH_SLACK * (abs(ox) + abs(oy) + abs(oz) + cell * (nx + ny + nz + 6))
    inv = 1.0 / cell
    for i in order:
        x, y, z = pcd[i, 0], pcd[i, 1], pcd[i, 2]
        j = near[i]
        if not search_all and j >= 0 and gap[i] > 2.0 * moved[i] * slack + 2.0 * margin:
            d2 = _d2(x, y, z, gpts, j)
            if d2 < r2:
                best[i] = d2
            else:  # the nearest moved out of reach, and every other point is farther
                near[i] = -1
                gap[i] = -1.0
            continue
        near[i] = -1
        gap[i] = -1.0
        moved[i] = 0.0
        fx, fy, fz = math.floor((x - ox) * inv), math.floor((y - oy) * inv), math.floor((z - oz) * inv)
        if not (-1.0 <= fx <= nx and -1.0 <= fy <= ny and -1.0 <= fz <= nz):
            continue
        ix, iy, iz = int(fx), int(fy), int(fz)
        c = ((ix + 1) * py + iy + 1) * pz + iz + 1
        ex = x - (ox + (ix + 0.5) * cell)
        ey = y - (oy + (iy + 0.5) * cell)
        ez = z - (oz + (iz + 0.5) * cell)
        dq = math.sqrt(ex * ex + ey * ey + ez * ez)
        b = r2
        b2 = r2  # the least squared distance of the rows read but the best (r2 when none is below it)
        bj = -1
        reach = (max_distance + dq) * slack + margin
        for q in range(near_start[c], near_start[c + 1]):
            if near_dist[q] > reach:
                break
            k = int(near_rows[q])
            d2 = _d2(x, y, z, gpts, k)
            if d2 < b or (d2 == b and bj >= 0 and gorder[k] < gorder[bj]):
                b2 = b
                b = d2
                bj = k
            elif d2 < b2:
                b2 = d2
            else:
                continue
            reach = (math.sqrt(b2) + dq) * slack + margin
        if bj >= 0:
            near[i] = bj
            best[i] = b
            gap[i] = math.sqrt(b2) - math.sqrt(b)
    return _pairs(pcd.shape[0], near, best, src, dst)


@numba.njit(cache=True, nogil=True)
def _transform_moved(T: np.ndarray, pcd: np.ndarray, moved: np.ndarray) -> None:
    """:func:`_transform_rows` (the same bits), adding to ``moved[i]`` how far row i moved, rounded up (the
    computed distance times 1 + :data:`_REACH_SLACK`, far more than its rounding and the sum's)."""
    up = 1.0 + _REACH_SLACK
    for i in range(pcd.shape[0]):
        x, y, z = pcd[i, 0], pcd[i, 1], pcd[i, 2]
        w = T[3, 0] * x + T[3, 1] * y + T[3, 2] * z + T[3, 3]
        if w == 1.0:
            for r in range(3):
                pcd[i, r] = T[r, 0] * x + T[r, 1] * y + T[r, 2] * z + T[r, 3]
        else:
            for r in range(3):
                pcd[i, r] = (T[r, 0] * x + T[r, 1] * y + T[r, 2] * z + T[r, 3]) / w
        dx = pcd[i, 0] - x
        dy = pcd[i, 1] - y
        dz = pcd[i, 2] - z
        moved[i] += math.sqrt(dx * dx + dy * dy + dz * dz) * up


@numba.njit(cache=True, nogil=True)
def _ldlt_solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Eigen's ``A.ldlt().solve(b)`` for a symmetric (n, n) ``A`` read from its lower triangle:
    the largest remaining diagonal entry as pivot, components whose pivot is below the smallest
    normal double set to zero."""
    n = A.shape[0]
    m = A.copy()
    perm = np.empty(n, np.int64)
    temp = np.zeros(n)
    for k in range(n):
        big = k
        for i in range(k + 1, n):
            if abs(m[i, i]) > abs(m[big, big]):
                big = i
        perm[k] = big
        if big != k:
            s = n - big - 1
            for j in range(k):
                m[k, j], m[big, j] = m[big, j], m[k, j]
            for j in range(s):
                m[big + 1 + j, k], m[big + 1 + j, big] = m[big + 1 + j, big], m[big + 1 + j, k]
            m[k, k], m[big, big] = m[big, big], m[k, k]
            for i in range(k + 1, big):
                tmp = m[i, k]
                m[i, k] = m[big, i]
                m[big, i] = tmp
        rs = n - k - 1
        if k > 0:
            for j in range(k):
                temp[j] = m[j, j] * m[k, j]
            acc = 0.0
            for j in range(k):
                acc += m[k, j] * temp[j]
            m[k, k] -= acc
            for i in range(k + 1, n):
                acc = 0.0
                for j in range(k):
                    acc += m[i, j] * temp[j]
                m[i, k] -= acc
        akk = m[k, k]
        if k == 0 and not abs(akk) > 0.0:
            return np.zeros(n)  # a zero matrix: Eigen's solution is zero
        if rs > 0 and abs(akk) > 0.0:
            for i in range(k + 1, n):
                m[i, k] /= akk
    x = b.copy()
    for k in range(n):  # x = P b
        if perm[k] != k:
            x[k], x[perm[k]] = x[perm[k]], x[k]
    for i in range(n):  # L (unit lower) forward
        acc = x[i]
        for j in range(i):
            acc -= m[i, j] * x[j]
        x[i] = acc
    tiny = 2.2250738585072014e-308
    for i in range(n):
        x[i] = x[i] / m[i, i] if abs(m[i, i]) > tiny else 0.0
    for i in range(n - 1, -1, -1):  # L^T backward
        acc = x[i]
        for j in range(i + 1, n):
            acc -= m[j, i] * x[j]
        x[i] = acc
    for k in range(n - 1, -1, -1):  # P^T
        if perm[k] != k:
            x[k], x[perm[k]] = x[perm[k]], x[k]
    return x


@numba.njit(cache=True, nogil=True)
def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Quaternion product (w, x, y, z) as Eigen writes it."""
    return np.array([
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] + a[2] * b[0] + a[3] * b[1] - a[1] * b[3],
        a[0] * b[3] + a[3] * b[0] + a[1] * b[2] - a[2] * b[1],
    ])


@numba.njit(cache=True, nogil=True)
def _vector6_to_matrix(x: np.ndarray) -> np.ndarray:
    """Open3D's ``TransformVector6dToMatrix4d``: AngleAxis(x2, z) AngleAxis(x1, y) AngleAxis(x0, x)
    as quaternions, then Eigen's quaternion-to-matrix; translation x[3:]."""
    qz = np.array([math.cos(0.5 * x[2]), 0.0, 0.0, math.sin(0.5 * x[2])])
    qy = np.array([math.cos(0.5 * x[1]), 0.0, math.sin(0.5 * x[1]), 0.0])
    qx = np.array([math.cos(0.5 * x[0]), math.sin(0.5 * x[0]), 0.0, 0.0])
    q = _qmul(_qmul(qz, qy), qx)
    w, a, b, c = q[0], q[1], q[2], q[3]
    tx, ty, tz = 2.0 * a, 2.0 * b, 2.0 * c
    twx, twy, twz = tx * w, ty * w, tz * w
    txx, txy, txz = tx * a, ty * a, tz * a
    tyy, tyz, tzz = ty * b, tz * b, tz * c
    U = np.eye(4)
    U[0, 0] = 1.0 - (tyy + tzz)
    U[0, 1] = txy - twz
    U[0, 2] = txz + twy
    U[1, 0] = txy + twz
    U[1, 1] = 1.0 - (txx + tzz)
    U[1, 2] = tyz - twx
    U[2, 0] = txz - twy
    U[2, 1] = tyz + twx
    U[2, 2] = 1.0 - (txx + tyy)
    U[0, 3], U[1, 3], U[2, 3] = x[3], x[4], x[5]
    return U


@numba.njit(cache=True, nogil=True)
def _point_to_plane(pcd: np.ndarray, gpts: np.ndarray, gnrm: np.ndarray, src: np.ndarray, dst: np.ndarray,
                    n: int) -> np.ndarray:
    """The update of ``TransformationEstimationPointToPlane::ComputeTransformation``."""
    if n == 0:
        return np.eye(4)
    # the 21 sums of the upper half of JᵀJ and the 6 of Jᵀr in scalars (registers, not a 6 x 6 array in
    # memory), each summed over the correspondences in the same order: the same bits
    h00 = h01 = h02 = h03 = h04 = h05 = h11 = h12 = h13 = h14 = h15 = 0.0
    h22 = h23 = h24 = h25 = h33 = h34 = h35 = h44 = h45 = h55 = 0.0
    g0 = g1 = g2 = g3 = g4 = g5 = 0.0
    for c in range(n):
        i, j = src[c], dst[c]
        s0, s1, s2 = pcd[i, 0], pcd[i, 1], pcd[i, 2]
        n0, n1, n2 = gnrm[j, 0], gnrm[j, 1], gnrm[j, 2]
        r = (s0 - gpts[j, 0]) * n0 + (s1 - gpts[j, 1]) * n1 + (s2 - gpts[j, 2]) * n2
        j0 = s1 * n2 - s2 * n1
        j1 = s2 * n0 - s0 * n2
        j2 = s0 * n1 - s1 * n0
        j3, j4, j5 = n0, n1, n2
        g0 += j0 * r
        g1 += j1 * r
        g2 += j2 * r
        g3 += j3 * r
        g4 += j4 * r
        g5 += j5 * r
        h00 += j0 * j0
        h01 += j0 * j1
        h02 += j0 * j2
        h03 += j0 * j3
        h04 += j0 * j4
        h05 += j0 * j5
        h11 += j1 * j1
        h12 += j1 * j2
        h13 += j1 * j3
        h14 += j1 * j4
        h15 += j1 * j5
        h22 += j2 * j2
        h23 += j2 * j3
        h24 += j2 * j4
        h25 += j2 * j5
        h33 += j3 * j3
        h34 += j3 * j4
        h35 += j3 * j5
        h44 += j4 * j4
        h45 += j4 * j5
        h55 += j5 * j5
    JTJ = np.empty((6, 6))
    JTr = np.empty(6)
    JTr[0] = g0
    JTr[1] = g1
    JTr[2] = g2
    JTr[3] = g3
    JTr[4] = g4
    JTr[5] = g5
    JTJ[0, 0] = h00
    JTJ[0, 1] = h01
    JTJ[0, 2] = h02
    JTJ[0, 3] = h03
    JTJ[0, 4] = h04
    JTJ[0, 5] = h05
    JTJ[1, 1] = h11
    JTJ[1, 2] = h12
    JTJ[1, 3] = h13
    JTJ[1, 4] = h14
    JTJ[1, 5] = h15
    JTJ[2, 2] = h22
    JTJ[2, 3] = h23
    JTJ[2, 4] = h24
    JTJ[2, 5] = h25
    JTJ[3, 3] = h33
    JTJ[3, 4] = h34
    JTJ[3, 5] = h35
    JTJ[4, 4] = h44
    JTJ[4, 5] = h45
    JTJ[5, 5] = h55
    for a in range(6):  # J[a] J[b] == J[b] J[a] exactly: the full sums' lower half, bit for bit
        for b in range(a):
            JTJ[a, b] = JTJ[b, a]
    return _vector6_to_matrix(_ldlt_solve(JTJ, -JTr))


@numba.njit(cache=True, nogil=True)
def _point_to_point(pcd: np.ndarray, gpts: np.ndarray, src: np.ndarray, dst: np.ndarray, n: int) -> np.ndarray:
    """The update of ``TransformationEstimationPointToPoint::ComputeTransformation`` (Eigen's
    ``umeyama`` without scaling)."""
    if n == 0:
        return np.eye(4)
    ms = np.zeros(3)
    md = np.zeros(3)
    for c in range(n):
        for a in range(3):
            ms[a] += pcd[src[c], a]
            md[a] += gpts[dst[c], a]
    inv = 1.0 / n
    for a in range(3):
        ms[a] *= inv
        md[a] *= inv
    sigma = np.zeros((3, 3))
    for c in range(n):
        for a in range(3):
            da = gpts[dst[c], a] - md[a]
            for b in range(3):
                sigma[a, b] += da * (pcd[src[c], b] - ms[b])
    for a in range(3):
        for b in range(3):
            sigma[a, b] *= inv
    u, _, vt = np.linalg.svd(sigma)
    s = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        s[2] = -1.0
    R = (u * s) @ vt
    U = np.eye(4)
    for a in range(3):
        for b in range(3):
            U[a, b] = R[a, b]
        U[a, 3] = md[a] - (R[a, 0] * ms[0] + R[a, 1] * ms[1] + R[a, 2] * ms[2])
    return U


@numba.njit(cache=True, nogil=True)
def _is_identity(T: np.ndarray) -> bool:
    """Eigen's ``isIdentity()`` (precision 1e-12)."""
    for r in range(4):
        for c in range(4):
            if r == c:
                if not abs(T[r, c] - 1.0) <= 1e-12 * min(abs(T[r, c]), 1.0):
                    return False
            elif not abs(T[r, c]) <= 1e-12:
                return False
    return True


@numba.njit(cache=True, nogil=True)
def _icp_start(source: np.ndarray, init: np.ndarray, origin: np.ndarray, cell: float, nx: int, ny: int, nz: int,
               near_start: np.ndarray, near_rows: np.ndarray, near_dist: np.ndarray,
               gpts: np.ndarray, gorder: np.ndarray, max_distance: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                          tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray], int, float,
                          float]:
    """The start of Open3D's ``RegistrationICP`` loop: the source moved by ``init`` (unless it is the
    identity), its correspondences: ``(pcd, search order, pose, state, n, fitness, rmse)``."""
    pcd = source.copy()
    if not _is_identity(init):
        _transform_rows(init, pcd)
    m = pcd.shape[0]
    state = (np.empty(m), np.full(m, -1, np.int64), np.empty(m, np.int64), np.empty(m, np.int64), np.empty(m),
             np.zeros(m))
    order = _cell_order(pcd, origin, cell, nx, ny)
    n, e2 = _correspond_kept(pcd, order, origin, cell, nx, ny, nz, near_start, near_rows, near_dist, gpts, gorder,
                             max_distance, *state, True)
    return pcd, order, init.copy(), state, n, n / m if n else 0.0, math.sqrt(e2 / n) if n else 0.0


@numba.njit(cache=True, nogil=True)
def _icp_step(U: np.ndarray, T: np.ndarray, pcd: np.ndarray, order: np.ndarray, origin: np.ndarray, cell: float,
              nx: int, ny: int, nz: int, near_start: np.ndarray, near_rows: np.ndarray, near_dist: np.ndarray,
              gpts: np.ndarray, gorder: np.ndarray, max_distance: float,
              state: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
              ) -> tuple[np.ndarray, int, float, float]:
    """One iteration after its update ``U``: the pose ``U T``, the source moved by ``U``, its new
    correspondences: ``(pose, n, fitness, rmse)``."""
    T = _matmul4(U, T)
    _transform_moved(U, pcd, state[5])
    n, e2 = _correspond_kept(pcd, order, origin, cell, nx, ny, nz, near_start, near_rows, near_dist, gpts, gorder,
                             max_distance, *state, False)
    m = pcd.shape[0]
    return T, n, n / m if n else 0.0, math.sqrt(e2 / n) if n else 0.0


# One loop, two kernels: numba inlines ``_icp_loop`` into each wrapper with its ``point_to_plane`` a constant and
# prunes the other branch, so each kernel holds only its own update (a process that registers point-to-plane
# never loads the SVD of point-to-point) and the loop is written once. (A function passed as an argument instead
# costs 3.3-4.8 x: numba calls it through a pointer, without inlining.)
@numba.njit(cache=True, nogil=True, inline="always")
def _icp_loop(source: np.ndarray, init: np.ndarray, origin: np.ndarray, cell: float, nx: int, ny: int, nz: int,
              near_start: np.ndarray, near_rows: np.ndarray, near_dist: np.ndarray,
              gpts: np.ndarray, gnrm: np.ndarray, gorder: np.ndarray,
              max_distance: float, max_iteration: int, relative_fitness: float, relative_rmse: float, out: np.ndarray,
              point_to_plane: bool) -> tuple[float, float, int, int]:
    """Open3D's ``RegistrationICP`` loop; the pose into ``out``; ``(fitness, rmse, iterations, n)``.
    ``point_to_plane``: the update of ``TransformationEstimationPointToPlane`` (``gnrm`` the model's
    normals), else of ``TransformationEstimationPointToPoint`` (``gnrm`` not read). Called with a
    constant ``point_to_plane`` only (:func:`_icp_plane`, :func:`_icp_point`)."""
    pcd, order, T, state, n, fit, rmse = _icp_start(source, init, origin, cell, nx, ny, nz, near_start, near_rows,
                                                    near_dist, gpts, gorder, max_distance)
    its = 0
    for _ in range(max_iteration):
        its += 1
        if point_to_plane:
            U = _point_to_plane(pcd, gpts, gnrm, state[2], state[3], n)
        else:
            U = _point_to_point(pcd, gpts, state[2], state[3], n)
        fit0, rmse0 = fit, rmse
        T, n, fit, rmse = _icp_step(U, T, pcd, order, origin, cell, nx, ny, nz, near_start, near_rows, near_dist, gpts,
                                    gorder, max_distance, state)
        if abs(fit0 - fit) < relative_fitness and abs(rmse0 - rmse) < relative_rmse:
            break
    out[:, :] = T
    return fit, rmse, its, n


@numba.njit(cache=True, nogil=True)
def _icp_plane(source: np.ndarray, init: np.ndarray, origin: np.ndarray, cell: float, nx: int, ny: int, nz: int,
               near_start: np.ndarray, near_rows: np.ndarray, near_dist: np.ndarray,
               gpts: np.ndarray, gnrm: np.ndarray, gorder: np.ndarray,
               max_distance: float, max_iteration: int, relative_fitness: float, relative_rmse: float, out: np.ndarray
               ) -> tuple[float, float, int, int]:
    """:func:`_icp_loop`, point-to-plane."""
    return _icp_loop(source, init, origin, cell, nx, ny, nz, near_start, near_rows, near_dist, gpts, gnrm, gorder,
                     max_distance, max_iteration, relative_fitness, relative_rmse, out, True)


@numba.njit(cache=True, nogil=True)
def _icp_point(source: np.ndarray, init: np.ndarray, origin: np.ndarray, cell: float, nx: int, ny: int, nz: int,
               near_start: np.ndarray, near_rows: np.ndarray, near_dist: np.ndarray,
               gpts: np.ndarray, gorder: np.ndarray, max_distance: float,
               max_iteration: int, relative_fitness: float, relative_rmse: float, out: np.ndarray
               ) -> tuple[float, float, int, int]:
    """:func:`_icp_loop`, point-to-point (no normals: ``gpts`` stands in for them, unread)."""
    return _icp_loop(source, init, origin, cell, nx, ny, nz, near_start, near_rows, near_dist, gpts, gpts, gorder,
                     max_distance, max_iteration, relative_fitness, relative_rmse, out, False)


def _check_icp_args(source: np.ndarray, init: np.ndarray, max_distance: float, max_iteration: int
                    ) -> tuple[np.ndarray, np.ndarray]:
    s = np.ascontiguousarray(source, dtype=np.float64)
    if s.ndim != 2 or s.shape[1] != 3:
        raise InputShapeError(f"source must be an (N, 3) float array, got {describe_array(s)}")
    if not np.isfinite(s).all():
        raise InputShapeError("source points must be finite")
    T0 = np.ascontiguousarray(init, dtype=np.float64)
    if T0.shape != (4, 4) or not np.isfinite(T0).all():
        raise InputShapeError(f"init must be a finite (4, 4) array, got {describe_array(T0)}")
    if not (math.isfinite(max_distance) and max_distance > 0):
        raise ParameterError(f"icp: max_distance must be a finite number > 0, got {max_distance!r}")
    if int(max_iteration) != max_iteration or max_iteration < 0:
        raise ParameterError(f"icp: max_iteration must be an integer >= 0, got {max_iteration!r}")
    return s, T0


def icp(source: np.ndarray, grid: IcpGrid, *, max_distance: float, init: np.ndarray, point_to_plane: bool,
        max_iteration: int, relative_fitness: float = 1e-6, relative_rmse: float = 1e-6) -> IcpOutcome:
    """Open3D's ``registration_icp(source, target, max_distance, init, estimation, criteria)`` with
    the target's search structure built beforehand (:func:`build_grid`).

    Parameters
    ----------
    source : (N, 3) float ndarray
        Finite source points (e.g. a frame's downsampled bin points); none: no correspondence,
        ``init`` returned after one iteration, as Open3D does.
    grid : IcpGrid
        The target's (the model's), built for a radius of at least ``max_distance``; with normals
        for point-to-plane.
    max_distance : float
        Correspondence distance (metres).
    init : (4, 4) float ndarray
        Initial source -> target transform.
    point_to_plane : bool
        Point-to-plane (Open3D's ``TransformationEstimationPointToPlane``), else point-to-point
        (``TransformationEstimationPointToPoint()``).
    max_iteration : int
    relative_fitness, relative_rmse : float
        Open3D's ``ICPConvergenceCriteria`` (its defaults).

    Returns
    -------
    IcpOutcome
    """
    s, T0 = _check_icp_args(source, init, max_distance, max_iteration)
    if max_distance > grid.radius:
        raise ParameterError(f"icp: max_distance {max_distance!r} exceeds the grid's radius {grid.radius!r}")
    if point_to_plane and not grid.has_normals:
        raise ParameterError("icp: point-to-plane needs the target's normals (the grid was built without)")
    out = np.empty((4, 4))
    nx, ny, nz = (int(v) for v in grid.dims)
    args = (s, T0, grid.origin, grid.cell, nx, ny, nz, grid.near_start, grid.near, grid.near_dist, grid.points)
    tail = (grid.order, float(max_distance), int(max_iteration), float(relative_fitness), float(relative_rmse), out)
    if point_to_plane:
        fit, rmse, its, n = _icp_plane(*args, grid.normals, *tail)
    else:
        fit, rmse, its, n = _icp_point(*args, *tail)
    return IcpOutcome(out, float(fit), float(rmse), int(its), int(n))


def icp_open3d(source: np.ndarray, points: np.ndarray, normals: np.ndarray | None, *, max_distance: float,
               init: np.ndarray, point_to_plane: bool, max_iteration: int, count_iterations: bool = False
               ) -> IcpOutcome:
    """The reference: Open3D's own ``registration_icp`` on the same input as :func:`icp`.

    ``count_iterations`` reads the iterations from Open3D's debug log (one line per iteration,
    written to the process's standard output, which is redirected to a file for the call); without
    it ``iterations`` is -1. ``n_correspondences`` is Open3D's ``correspondence_set``'s length.
    """
    import open3d as o3d

    s, T0 = _check_icp_args(source, init, max_distance, max_iteration)
    reg = o3d.pipelines.registration
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(s))
    dst = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(points, np.float64)))
    if normals is not None:
        dst.normals = o3d.utility.Vector3dVector(np.ascontiguousarray(normals, np.float64))
    est = (reg.TransformationEstimationPointToPlane() if point_to_plane
           else reg.TransformationEstimationPointToPoint())
    crit = reg.ICPConvergenceCriteria(max_iteration=int(max_iteration))
    if not count_iterations:
        r = reg.registration_icp(src, dst, float(max_distance), T0, est, crit)
        its = -1
    else:
        r, its = _with_debug_log(lambda: reg.registration_icp(src, dst, float(max_distance), T0, est, crit),
                                 "ICP Iteration #")
    return IcpOutcome(np.asarray(r.transformation, dtype=np.float64).copy(), float(r.fitness),
                      float(r.inlier_rmse), its, len(r.correspondence_set))


def _with_debug_log(call: Callable[[], _T], marker: str) -> tuple[_T, int]:
    """Run ``call()`` with Open3D's debug log on; (its result, the log's lines containing ``marker``).

    Open3D's Python module prints its log through Python's ``sys.stdout`` (caught here in a string)
    and its C++ library through the process's standard output (redirected to a temporary file for
    the call): both are read."""
    import contextlib
    import ctypes
    import io
    import os
    import sys
    import tempfile

    import open3d as o3d

    libc = ctypes.CDLL(None)
    sys.stdout.flush()
    saved = os.dup(1)
    level = o3d.utility.get_verbosity_level()
    text = io.StringIO()
    with tempfile.TemporaryFile(mode="w+b") as f:
        try:
            os.dup2(f.fileno(), 1)
            o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Debug)
            with contextlib.redirect_stdout(text):
                out = call()
        finally:
            o3d.utility.set_verbosity_level(level)
            libc.fflush(None)
            os.dup2(saved, 1)
            os.close(saved)
        f.seek(0)
        native = f.read().decode(errors="replace")
    return out, text.getvalue().count(marker) + native.count(marker)
