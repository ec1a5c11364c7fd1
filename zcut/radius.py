"""Radius outlier removal on organized clouds, identical to Open3D's, and fast.

Open3D's ``PointCloud.remove_radius_outlier(nb_points, radius)`` keeps a point iff its radius
search returns more than ``nb_points`` points; the search counts the point itself and every point
whose squared distance is strictly below ``radius * radius`` (nanoflann's radius result set), with
the squared distance ``((0 + dx²) + dy²) + dz²`` of query minus point in float64. So a point is an
inlier iff at least ``min_points`` OTHER points lie strictly inside its ball. :func:`radius_outliers`
computes exactly that on the valid pixels of an organized cloud (``radius = radius_mm / 1000``).

Only the count up to ``need = min_points + 1`` matters, so every search stops there; two phases:

1. *Image window* (numba, one pass over the pixels): the pixel's (2w + 1)² window, ring by ring up to
   a small w (the 3 x 3 or 5 x 5 window as straight-line code over float64 row buffers, which the
   compiler vectorizes). A count that reaches ``need`` proves an inlier (counts only grow). On
   surfaces this settles almost every pixel.
2. *Columns* (:mod:`zcut.columns`) for the rest (flying pixels, silhouettes, steep sides, clouds
   without a camera): the valid points in x-y columns one radius wide, ordered by depth slab, runs
   of identical points merged; only the columns some undecided pixel's ball can reach are filled.
   A query visits its own column, then the others its ball can reach, and binary-searches each for
   the slabs of the ball's z range. Its cost depends on the points near it in 3D, not on where
   they are in the image: tall parts standing on end (whose image neighbours are rarely 3D
   neighbours) cost no more than a flat bin floor.

The bounds are exact for the computed distances: the cells a query visits cover every point whose
computed squared distance can be below ``radius²`` (a margin of a few ulp, see
:func:`zcut.columns.reach`), and the KD-tree's box bounds are evaluated in the order of the distance
itself (rounding is monotone, so no point in a box is computed closer than its box's near bound
nor farther than its far bound). A heap of identical points is one column entry with a
multiplicity, or a KD-tree node inside or outside the ball whole.

A fall-back keeps time and memory bounded whatever the cloud: when the column grid would be too
large (coordinates spread far beyond the radius) or the column queries have scanned
``_BUDGET_PER_QUERY`` times ``min_points + 1`` entries per undecided pixel (dense clusters of
distinct points right at the radius), the remaining pixels go to a balanced KD-tree over all valid
points (median splits, so duplicates cannot unbalance it) that counts whole nodes inside the ball
and prunes those outside.

:func:`radius_outliers_reference` counts by brute force (all pairwise distances), or with scipy's
KD-tree and every candidate re-measured in the same arithmetic; the tests check both against the
fast path and Open3D itself. docs/filters.md, "The filter bank", describes the filter.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from . import columns as _columns
from . import sor_search as _kd
from .errors import ParameterError
from .grid_input import as_cloud, plain_number, valid_at
from .params import RadiusParams
from .types import XYZ, Mask

__all__ = ["radius_neighbour_counts", "radius_outliers", "radius_outliers_reference", "radius_stage"]

# search limits (read at call time, so that tests can force each path)
_WINDOW_EXTRA = 1         # window rings beyond the smallest window that could hold `need` pixels
_USE_COLUMNS = True       # False: every undecided pixel goes to the KD-tree
_COLUMN_WIDTH = 2.0       # column width, in radii
_COLUMNS_PER_POINT = 8    # largest grid (columns per valid point) before the KD-tree takes over
_BUDGET_PER_QUERY = 16    # entries the column queries may scan, times `need` per query ...
_BUDGET_FLOOR = 1 << 20   # ... plus this, before the KD-tree takes the remaining queries


def _params(radius_mm: object, min_points: object) -> RadiusParams:
    return RadiusParams(radius_mm=plain_number(radius_mm), min_points=plain_number(min_points))


# --------------------------------------------------------------------------------------------
# distances and box bounds (the arithmetic of Open3D's nanoflann metric)
# --------------------------------------------------------------------------------------------
_d2 = _columns.d2
# a lower bound on the computed d² to any point of box k, in the order of _d2 (the KD-tree's own)
_near2 = _kd._kd_box_d2


@nb.njit(cache=True, nogil=True, inline="always")
def _far2(lo, hi, k, xq, yq, zq):  # type: ignore[no-untyped-def]  # numba kernel
    # an upper bound on the computed d² to any point of box k: |fl(q - p)| <= max(|fl(q - lo)|,
    # |fl(q - hi)|) for lo <= p <= hi (fl is monotone), then squares and sums are monotone
    g = max(abs(xq - lo[k, 0]), abs(xq - hi[k, 0]))
    s = g * g
    g = max(abs(yq - lo[k, 1]), abs(yq - hi[k, 1]))
    s += g * g
    g = max(abs(zq - lo[k, 2]), abs(zq - hi[k, 2]))
    return s + g * g


# --------------------------------------------------------------------------------------------
# phase 1: image windows
# --------------------------------------------------------------------------------------------
def _window_reach(need: int) -> int:
    """Largest window half-width of phase 1: the smallest w with (2w + 1)² >= need, plus
    ``_WINDOW_EXTRA``."""
    w = 0
    while (2 * w + 1) ** 2 < need:
        w += 1
    return w + int(_WINDOW_EXTRA)


@nb.njit(cache=True, nogil=True, inline="always")
def _in(row, j, xq, yq, zq, r2):  # type: ignore[no-untyped-def]  # numba kernel
    # pixel j of the row is within the radius; an invalid pixel (a non-finite coordinate) never is:
    # its squared distance is NaN or inf
    return _d2(xq, yq, zq, np.float64(row[j, 0]), np.float64(row[j, 1]), np.float64(row[j, 2])) < r2


@nb.njit(cache=True, nogil=True)
def _ring(a, r, c, w, xq, yq, zq, r2):  # type: ignore[no-untyped-def]  # numba kernel
    # points within the radius among the pixels at Chebyshev distance exactly w from (r, c)
    H, W = a.shape[0], a.shape[1]
    n = 0
    for rr in range(max(r - w, 0), min(r + w, H - 1) + 1):
        row = a[rr]
        if rr == r - w or rr == r + w:
            for cc in range(max(c - w, 0), min(c + w, W - 1) + 1):
                n += _in(row, cc, xq, yq, zq, r2)
        else:
            if c - w >= 0:
                n += _in(row, c - w, xq, yq, zq, r2)
            if c + w < W:
                n += _in(row, c + w, xq, yq, zq, r2)
    return n


@nb.njit(cache=True, nogil=True, inline="always")
def _inb(xs, ys, zs, j, xq, yq, zq, r2):  # type: ignore[no-untyped-def]  # numba kernel
    # _in for a pixel of the float64 row buffers
    return np.int64(_d2(xq, yq, zq, xs[j], ys[j], zs[j]) < r2)


@nb.njit(cache=True, nogil=True)
def _window_phase(a, r2, need, wmax, state):  # type: ignore[no-untyped-def]  # numba kernel
    """state[r, c] = 0 invalid, 1 inlier (``need`` points found in a window of half-width at most
    ``wmax``), 2 undecided. Returns the number of undecided pixels and the smallest and largest
    x, y, z of the valid points.

    Rows are copied to float64 buffers (a ring of five), so that the count over the 3 x 3 (or, if
    ``need`` > 9, the 5 x 5) window of every inner pixel is straight-line code over contiguous
    arrays, which the compiler vectorizes; invalid pixels keep their non-finite coordinates, whose
    squared distances (NaN or inf) are never below r². What that window leaves undecided grows ring
    by ring up to ``wmax``.
    """
    H, W = a.shape[0], a.shape[1]
    undecided = 0
    lo0 = lo1 = lo2 = np.inf
    hi0 = hi1 = hi2 = -np.inf
    X = np.empty((5, W))
    Y = np.empty((5, W))
    Z = np.empty((5, W))
    n = np.zeros(W, np.int64)
    big = need > 9
    for rr in range(min(2, H)):  # rows 0, 1 into the ring
        for c in range(W):
            X[rr, c], Y[rr, c], Z[rr, c] = a[rr, c, 0], a[rr, c, 1], a[rr, c, 2]
    for r in range(H):
        if r + 2 < H:
            s2 = (r + 2) % 5
            row2 = a[r + 2]
            for c in range(W):
                X[s2, c], Y[s2, c], Z[s2, c] = row2[c, 0], row2[c, 1], row2[c, 2]
        xm, ym, zm = X[r % 5], Y[r % 5], Z[r % 5]
        # validity and the extremes
        st = state[r]
        for c in range(W):
            ok = xm[c] * 0.0 + ym[c] * 0.0 + zm[c] * 0.0 == 0.0
            st[c] = ok
            lo0 = min(lo0, xm[c] if ok else np.inf)
            lo1 = min(lo1, ym[c] if ok else np.inf)
            lo2 = min(lo2, zm[c] if ok else np.inf)
            hi0 = max(hi0, xm[c] if ok else -np.inf)
            hi1 = max(hi1, ym[c] if ok else -np.inf)
            hi2 = max(hi2, zm[c] if ok else -np.inf)
        # the straight window of the inner pixels
        n[:] = 0
        w0 = -1
        if not big and 0 < r < H - 1 and W >= 3 and wmax >= 1:
            xu, yu, zu = X[(r - 1) % 5], Y[(r - 1) % 5], Z[(r - 1) % 5]
            xd, yd, zd = X[(r + 1) % 5], Y[(r + 1) % 5], Z[(r + 1) % 5]
            for c in range(1, W - 1):
                xq, yq, zq = xm[c], ym[c], zm[c]
                n[c] = (_inb(xu, yu, zu, c - 1, xq, yq, zq, r2) + _inb(xu, yu, zu, c, xq, yq, zq, r2)
                        + _inb(xu, yu, zu, c + 1, xq, yq, zq, r2) + _inb(xm, ym, zm, c - 1, xq, yq, zq, r2)
                        + _inb(xm, ym, zm, c, xq, yq, zq, r2) + _inb(xm, ym, zm, c + 1, xq, yq, zq, r2)
                        + _inb(xd, yd, zd, c - 1, xq, yq, zq, r2) + _inb(xd, yd, zd, c, xq, yq, zq, r2)
                        + _inb(xd, yd, zd, c + 1, xq, yq, zq, r2))
            w0 = 1
        elif big and 1 < r < H - 2 and W >= 5 and wmax >= 2:
            for k in range(5):
                kk = (r - 2 + k) % 5
                xk, yk, zk = X[kk], Y[kk], Z[kk]
                for c in range(2, W - 2):
                    xq, yq, zq = xm[c], ym[c], zm[c]
                    n[c] += (_inb(xk, yk, zk, c - 2, xq, yq, zq, r2) + _inb(xk, yk, zk, c - 1, xq, yq, zq, r2)
                             + _inb(xk, yk, zk, c, xq, yq, zq, r2) + _inb(xk, yk, zk, c + 1, xq, yq, zq, r2)
                             + _inb(xk, yk, zk, c + 2, xq, yq, zq, r2))
            w0 = 2
        # the rest, ring by ring (ring 2 of inner pixels from the buffers, straight)
        inner2 = 1 < r < H - 2 and wmax >= 2
        xu2, yu2, zu2 = X[(r - 2) % 5], Y[(r - 2) % 5], Z[(r - 2) % 5]
        xu, yu, zu = X[(r - 1) % 5], Y[(r - 1) % 5], Z[(r - 1) % 5]
        xd, yd, zd = X[(r + 1) % 5], Y[(r + 1) % 5], Z[(r + 1) % 5]
        xd2, yd2, zd2 = X[(r + 2) % 5], Y[(r + 2) % 5], Z[(r + 2) % 5]
        for c in range(W):
            if not st[c]:
                continue
            inner = (c >= w0 and c < W - w0) and w0 >= 0
            m = n[c] if inner else 0
            w = w0 if inner else -1
            xq, yq, zq = xm[c], ym[c], zm[c]
            if m < need and w == 1 and inner2 and 1 < c < W - 2:
                m += (_inb(xu2, yu2, zu2, c - 2, xq, yq, zq, r2) + _inb(xu2, yu2, zu2, c - 1, xq, yq, zq, r2)
                      + _inb(xu2, yu2, zu2, c, xq, yq, zq, r2) + _inb(xu2, yu2, zu2, c + 1, xq, yq, zq, r2)
                      + _inb(xu2, yu2, zu2, c + 2, xq, yq, zq, r2) + _inb(xd2, yd2, zd2, c - 2, xq, yq, zq, r2)
                      + _inb(xd2, yd2, zd2, c - 1, xq, yq, zq, r2) + _inb(xd2, yd2, zd2, c, xq, yq, zq, r2)
                      + _inb(xd2, yd2, zd2, c + 1, xq, yq, zq, r2) + _inb(xd2, yd2, zd2, c + 2, xq, yq, zq, r2)
                      + _inb(xu, yu, zu, c - 2, xq, yq, zq, r2) + _inb(xu, yu, zu, c + 2, xq, yq, zq, r2)
                      + _inb(xm, ym, zm, c - 2, xq, yq, zq, r2) + _inb(xm, ym, zm, c + 2, xq, yq, zq, r2)
                      + _inb(xd, yd, zd, c - 2, xq, yq, zq, r2) + _inb(xd, yd, zd, c + 2, xq, yq, zq, r2))
                w = 2
            while m < need and w < wmax:
                w += 1
                m += _ring(a, r, c, w, xq, yq, zq, r2)
            st[c] = 1 if m >= need else 2
            undecided += m < need
    return undecided, np.array([lo0, lo1, lo2]), np.array([hi0, hi1, hi2])


@nb.njit(cache=True)
def _undecided_pixels(state, n):  # type: ignore[no-untyped-def]  # numba kernel
    rows = np.empty(n, np.int64)
    cols = np.empty(n, np.int64)
    k = 0
    for r in range(state.shape[0]):
        for c in range(state.shape[1]):
            if state[r, c] == 2:
                rows[k] = r
                cols[k] = c
                k += 1
    return rows, cols


# --------------------------------------------------------------------------------------------
# phase 2: columns sorted by depth (zcut.columns)
# --------------------------------------------------------------------------------------------
@nb.njit(cache=True, nogil=True)
def _query_coords(a, qr, qc):  # type: ignore[no-untyped-def]  # numba kernel
    q = np.empty((3, qr.shape[0]))
    for i in range(qr.shape[0]):
        for d in range(3):
            q[d, i] = a[qr[i], qc[i], d]
    return q


@nb.njit(cache=True, nogil=True)
def _column_queries(q0, q1, q, r2, rad, need, budget, x0, y0, z0, inv, nx, ny, cols, counts, left):  # type: ignore[no-untyped-def]  # numba kernel
    """Neighbour counts (up to ``need``) of the queries q0..q1-1 (coordinates q[:, i]) over the
    columns. Once ``budget`` entries have been scanned in all, the remaining queries are left to
    the KD-tree (left[i] = True)."""
    spent = 0
    for i in range(q0, q1):
        if spent > budget:
            left[i] = True
            continue
        n, used = _columns.count_query(cols, x0, y0, z0, inv, nx, ny, q[0, i], q[1, i], q[2, i], rad, r2, need, 0)
        spent += used
        counts[i] = min(n, need)


# --------------------------------------------------------------------------------------------
# the KD-tree fall-back
# --------------------------------------------------------------------------------------------
@nb.njit(cache=True)
def _gather_valid(a, n_valid):  # type: ignore[no-untyped-def]  # numba kernel
    pts = np.empty((n_valid, 3))
    k = 0
    for r in range(a.shape[0]):
        row = a[r]
        for c in range(a.shape[1]):
            if valid_at(row, c):
                for d in range(3):
                    pts[k, d] = np.float64(row[c, d])
                k += 1
    return pts


@nb.njit(cache=True, nogil=True)
def _kd_queries(q0, q1, a, qr, qc, r2, need, kd, counts):  # type: ignore[no-untyped-def]  # numba kernel
    """Neighbour counts (up to ``need``) of the query pixels q0..q1-1 over the KD-tree: a node
    beyond the radius is pruned, a node inside it counted whole."""
    pts, lo, hi, start, end, child = kd
    stack = np.empty(256, np.int64)
    for q in range(q0, q1):
        row = a[qr[q]]
        c = qc[q]
        xq = np.float64(row[c, 0])
        yq = np.float64(row[c, 1])
        zq = np.float64(row[c, 2])
        n = 0
        sp = 0
        if pts.shape[0]:
            stack[0] = 0
            sp = 1
        while sp > 0 and n < need:
            sp -= 1
            k = stack[sp]
            if _near2(lo, hi, k, xq, yq, zq) >= r2:
                continue
            if _far2(lo, hi, k, xq, yq, zq) < r2:
                n += end[k] - start[k]
                continue
            ch = child[k]
            if ch < 0:
                for t in range(start[k], end[k]):
                    n += _d2(xq, yq, zq, pts[t, 0], pts[t, 1], pts[t, 2]) < r2
                continue
            near, far = ch, ch + 1  # the nearer child is searched first (an inlier stops early)
            if _near2(lo, hi, ch + 1, xq, yq, zq) < _near2(lo, hi, ch, xq, yq, zq):
                near, far = ch + 1, ch
            stack[sp] = far
            stack[sp + 1] = near
            sp += 2
        counts[q] = min(n, need)


# --------------------------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------------------------
def radius_neighbour_counts(xyz: XYZ, *, radius_mm: float, cap: int) -> np.ndarray:
    """Points within ``radius_mm`` of every valid pixel's point, itself included, up to ``cap``.

    Parameters
    ----------
    xyz : (H, W, 3) float ndarray
        Organized cloud (metres); NaN (any non-finite coordinate) = invalid.
    radius_mm : float
        > 0; a point counts iff its squared distance is strictly below ``(radius_mm / 1000)²``.
    cap : int
        >= 1; counts stop there (``radius_outliers`` needs ``min_points + 1``).

    Returns
    -------
    (H, W) int64 ndarray
        ``min(count, cap)`` at the valid pixels, 0 at the invalid ones.
    """
    p = _params(radius_mm, cap)
    return _counts(as_cloud(xyz), p.radius_m, p.min_points)


def _counts(a: np.ndarray, radius_m: float, need: int) -> np.ndarray:
    H, W = a.shape[:2]
    r2 = radius_m * radius_m
    state = np.empty((H, W), np.int8)
    undecided, lo, hi = _window_phase(a, r2, need, _window_reach(need), state)
    counts = np.where(state == 1, need, 0).astype(np.int64)
    if undecided == 0:
        return counts
    rows, cols = _undecided_pixels(state, undecided)
    n_valid = int(np.count_nonzero(state))
    got = np.zeros(rows.size, np.int64)
    left = np.ones(rows.size, dtype=bool)
    inv = 1.0 / (_COLUMN_WIDTH * radius_m)
    with np.errstate(over="ignore", invalid="ignore"):
        nx, ny, nz = (float(np.floor((hi[i] - lo[i]) * inv)) + 1.0 for i in range(3))
    if (_USE_COLUMNS and math.isfinite(inv) and nx * ny <= _COLUMNS_PER_POINT * n_valid + 4096
            and nz < 2.0**53):  # the cells' integer coordinates stay exact
        nx, ny = int(nx), int(ny)
        q = _query_coords(a, rows, cols)
        marked = np.zeros(nx * ny, dtype=bool)
        _columns.mark_columns(q[0], q[1], np.full(rows.size, radius_m), lo[0], lo[1], inv, nx, ny, marked)
        columns = _columns.build_columns(a[:, :, 0], a[:, :, 1], a[:, :, 2], lo[0], lo[1], lo[2], inv, nx, marked)
        left[:] = False
        budget = int(_BUDGET_PER_QUERY * need * rows.size + _BUDGET_FLOOR)
        _column_queries(0, rows.size, q, r2, radius_m, need, budget, lo[0], lo[1], lo[2], inv, nx, ny, columns, got,
                        left)
    if left.any():
        kd = _kd.kd_build(_gather_valid(a, n_valid))
        sub = np.flatnonzero(left)
        sub_counts = np.zeros(sub.size, np.int64)
        _kd_queries(0, sub.size, a, rows[sub], cols[sub], r2, need, kd, sub_counts)
        got[sub] = sub_counts
    counts[rows, cols] = got
    return counts


def radius_outliers(xyz: XYZ, radius_mm: float, min_points: int) -> Mask:
    """Radius outlier removal: points with fewer than ``min_points`` others within ``radius_mm``.

    The same decision as Open3D's ``PointCloud.remove_radius_outlier(nb_points=min_points,
    radius=radius_mm / 1000)`` on the valid points (its documentation: remove points that have
    fewer than nb_points in a sphere of the given radius; its code counts the point itself and keeps
    it iff the count exceeds nb_points, the distances strictly below the radius), and PCL's
    RadiusOutlierRemoval with ``setMinNeighborsInRadius(min_points)``. Exact (no approximate
    search), in float64; float32 input is upcast. See the module notes for how.

    Parameters
    ----------
    xyz : (H, W, 3) float ndarray
        Organized cloud, camera optical frame (metres); NaN (any non-finite coordinate) = invalid.
        Invalid pixels are never outliers and never neighbours.
    radius_mm : float
        > 0, radius of the ball (mm).
    min_points : int
        >= 1, other points the ball must hold (Open3D's ``nb_points``).

    Returns
    -------
    (H, W) bool ndarray
        True at the valid pixels with fewer than ``min_points`` other valid points strictly within
        the radius.
    """
    p = _params(radius_mm, min_points)
    a = as_cloud(xyz)
    need = p.min_points + 1
    counts = _counts(a, p.radius_m, need)
    return (counts < need) & np.isfinite(a).all(axis=2)


def radius_outliers_reference(xyz: XYZ, radius_mm: float, min_points: int, *, method: str = "brute") -> Mask:
    """:func:`radius_outliers` by counting every point (slow, obviously correct).

    ``method="brute"``: all pairwise squared distances in the arithmetic of the module notes
    (small clouds). ``method="kdtree"``: scipy's KD-tree proposes the candidates within a slightly
    larger radius, each re-measured in the same arithmetic, identical points counted once per copy
    (large clouds).
    """
    p = _params(radius_mm, min_points)
    a = as_cloud(xyz)
    valid = np.isfinite(a).all(axis=2)
    pts = a[valid].astype(np.float64)
    r = p.radius_m
    r2 = r * r
    count = np.zeros(pts.shape[0], dtype=np.int64)
    with np.errstate(over="ignore", invalid="ignore"):
        if method == "brute":
            for i0 in range(0, pts.shape[0], 256):
                q = pts[i0:i0 + 256]
                d = q[:, None, :] - pts[None, :, :]
                d2 = (d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]) + d[..., 2] * d[..., 2]
                count[i0:i0 + 256] = (d2 < r2).sum(axis=1)
        elif method == "kdtree":
            from scipy.spatial import cKDTree

            uniq, inverse, mult = np.unique(pts, axis=0, return_inverse=True, return_counts=True)
            tree = cKDTree(uniq)
            lists = tree.query_ball_point(uniq, r * (1.0 + 1e-9) + 1e-300, workers=-1)
            per = np.zeros(uniq.shape[0], dtype=np.int64)
            for i, cand in enumerate(lists):
                cand = np.asarray(cand, dtype=np.int64)
                d = uniq[i] - uniq[cand]
                d2 = (d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2]
                per[i] = int(mult[cand[d2 < r2]].sum())
            count = per[inverse.ravel()]
        else:
            raise ParameterError(f"method must be 'brute' or 'kdtree', got {method!r}")
    out = np.zeros(valid.shape, dtype=bool)
    out[valid] = count < p.min_points + 1
    return out


def radius_stage(xyz: XYZ, *, params: RadiusParams) -> Mask:
    """:func:`radius_outliers` with the parameters of a :class:`~zcut.params.RadiusParams`."""
    if not isinstance(params, RadiusParams):
        raise ParameterError(f"params must be a RadiusParams, got {type(params).__name__}")
    return radius_outliers(xyz, params.radius_mm, params.min_points)
