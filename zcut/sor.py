"""Statistical outlier removal (SOR) on organized clouds, exact and fast (SPEC §2).

For every valid pixel the mean distance d̄ to its k nearest neighbours among the valid points is
computed exactly (no approximate search), then points far above the cloud's mean d̄ are outliers.

Search strategy (all exact):

1. *Image window.* The m nearest candidates (m = k + 1 with the point itself for ``"pcl"``,
   m = k for ``"open3d"``) are taken from a small image window around the pixel. When every valid
   z is positive, the window is *proven* sufficient without intrinsics: the points in the columns
   right of the window all satisfy x/z >= t (t = suffix minimum of the per-column minima of x/z),
   i.e. lie in the half-space x - t·z >= 0, whose distance from the query bounds their distance
   from below; likewise left (prefix maximum), above and below (rows, y/z). If the m-th smallest
   distance found is within the smallest of the four bounds (less a 1e-9·|P| safety margin for
   rounding), no point outside the window can be closer. Otherwise the window grows (up to a cap).
2. *Tile hierarchy.* Unproven points are searched over 8 × 8 pixel tiles and 8 × 8 tile
   super-tiles of the image, each with the axis-aligned bounding box of its valid points, pruned
   by the current m-th distance (works for any organized cloud, including z <= 0).
3. *KD-tree.* Points whose tile search would visit too many pixels go to
   :class:`scipy.spatial.cKDTree` over all valid points; its candidates within a slightly enlarged
   radius are re-measured with the arithmetic below, so the result stays exact.

Distances are those of Open3D's nanoflann L2 metric: ``sqrt((dx*dx + dy*dy) + dz*dz)`` in float64,
and d̄ sums the m smallest in ascending order, so d̄ is bit-identical to Open3D's. The statistics
are accumulated sequentially over the valid pixels in row-major order (the order in which
``xyz[valid]`` hands them to Open3D).
"""

from __future__ import annotations

import math
import os

import numba as nb
import numpy as np

from .cloud import check_xyz
from .errors import ParameterError
from .types import XYZ, Mask

__all__ = ["CONVENTIONS", "sor_outliers", "sor_mean_distances"]

CONVENTIONS = ("pcl", "open3d")

# Prefer numba's own workqueue threads unless the user chose a layer: OpenMP workers spin after
# each parallel region and steal the CPU on a busy machine (measured 2-3x slower here), and an
# old TBB shipped by other wheels makes numba warn when it probes the "tbb" layer.
if "NUMBA_THREADING_LAYER" not in os.environ and "NUMBA_THREADING_LAYER_PRIORITY" not in os.environ:
    nb.config.THREADING_LAYER_PRIORITY = ["workqueue", "omp", "tbb"]

_TILE = 8            # pixels per tile edge
_SUPER = 8           # tiles per super-tile edge
_TILE_SEARCH_CAP = 1 << 14   # pixels a tile search may measure before handing over to the KD-tree
_KD_ALL_ABOVE = 4096  # more unproven points than this and than n / 8: KD-tree for all of them
_MARGIN = 1e-9       # relative safety margin of the window bound (units of |P|)

# status codes of the window phase
_INVALID = 0
_DONE = 1
_UNPROVEN = 2


# --------------------------------------------------------------------------------------------
# small numba helpers
# --------------------------------------------------------------------------------------------
@nb.njit(cache=True, inline="always")
def _d2(xq, yq, zq, xp, yp, zp):
    # nanoflann L2_Adaptor::evalMetric for dim 3: ((0 + dx²) + dy²) + dz², query minus point.
    dx = xq - xp
    dy = yq - yp
    dz = zq - zp
    return (dx * dx + dy * dy) + dz * dz


@nb.njit(cache=True, inline="always")
def _insert(best, d2):
    # keep best[] sorted ascending, drop the largest; returns the new last value
    m = best.shape[0]
    if d2 >= best[m - 1]:
        return best[m - 1]
    i = m - 1
    while i > 0 and best[i - 1] > d2:
        best[i] = best[i - 1]
        i -= 1
    best[i] = d2
    return best[m - 1]


@nb.njit(cache=True, inline="always")
def _insert_minmax(best, d2):
    # the same as _insert without branches (top down, each slot reads its old lower neighbour)
    for i in range(best.shape[0] - 1, 0, -1):
        best[i] = min(best[i], max(best[i - 1], d2))
    best[0] = min(best[0], d2)


@nb.njit(cache=True, inline="always")
def _mean_of_sorted(best, divisor):
    # std::accumulate(sqrt(dist)) / size, in ascending order from 0.0
    s = 0.0
    for i in range(best.shape[0]):
        s += math.sqrt(best[i])
    return s / divisor


@nb.njit(cache=True)
def _ratio_bounds(x, y, z, valid):
    """Suffix/prefix extremes of x/z per column and y/z per row (for the window bound)."""
    H, W = valid.shape
    cmin = np.full(W, np.inf)
    cmax = np.full(W, -np.inf)
    rmin = np.full(H, np.inf)
    rmax = np.full(H, -np.inf)
    for r in range(H):
        for c in range(W):
            if valid[r, c]:
                tx = x[r, c] / z[r, c]
                ty = y[r, c] / z[r, c]
                if tx < cmin[c]:
                    cmin[c] = tx
                if tx > cmax[c]:
                    cmax[c] = tx
                if ty < rmin[r]:
                    rmin[r] = ty
                if ty > rmax[r]:
                    rmax[r] = ty
    csuf = cmin.copy()   # csuf[c] = min over columns >= c
    for c in range(W - 2, -1, -1):
        csuf[c] = min(csuf[c], csuf[c + 1])
    cpre = cmax.copy()   # cpre[c] = max over columns <= c
    for c in range(1, W):
        cpre[c] = max(cpre[c], cpre[c - 1])
    rsuf = rmin.copy()
    for r in range(H - 2, -1, -1):
        rsuf[r] = min(rsuf[r], rsuf[r + 1])
    rpre = rmax.copy()
    for r in range(1, H):
        rpre[r] = max(rpre[r], rpre[r - 1])
    return csuf, cpre, rsuf, rpre


@nb.njit(cache=True)
def _inv_norms(t):
    # 1 / sqrt(1 + t²) for the plane u - t z = 0 (0 where t is infinite: no point on that side)
    out = np.zeros(t.shape[0])
    for i in range(t.shape[0]):
        if np.isfinite(t[i]):
            out[i] = 1.0 / math.sqrt(1.0 + t[i] * t[i])
    return out


@nb.njit(cache=True, inline="always")
def _plane_bound(t, inv, a, zq, sign):
    # distance from the query to the half-space sign*(u - t z) >= 0 (u = x or y), 0 if inside
    if inv == 0.0:
        return np.inf
    num = sign * (t * zq - a)
    if num <= 0.0:
        return 0.0
    return num * inv


@nb.njit(cache=True, inline="always")
def _window_bound(r, c, w, H, W, xq, yq, zq, csuf, cpre, rsuf, rpre, icsuf, icpre, irsuf, irpre):
    # lower bound on the distance from the query to every valid point outside the window
    b = np.inf
    if c + w + 1 < W:
        b = min(b, _plane_bound(csuf[c + w + 1], icsuf[c + w + 1], xq, zq, 1.0))
    if c - w - 1 >= 0:
        b = min(b, _plane_bound(cpre[c - w - 1], icpre[c - w - 1], xq, zq, -1.0))
    if r + w + 1 < H:
        b = min(b, _plane_bound(rsuf[r + w + 1], irsuf[r + w + 1], yq, zq, 1.0))
    if r - w - 1 >= 0:
        b = min(b, _plane_bound(rpre[r - w - 1], irpre[r - w - 1], yq, zq, -1.0))
    return b


@nb.njit(cache=True, inline="always")
def _scan_ring(best, r, c, w_old, w_new, H, W, x, y, z, valid, xq, yq, zq):
    # add the pixels of the (2 w_new + 1)² window that are outside the (2 w_old + 1)² one
    n = 0
    r0 = max(0, r - w_new)
    r1 = min(H - 1, r + w_new)
    c0 = max(0, c - w_new)
    c1 = min(W - 1, c + w_new)
    for rr in range(r0, r1 + 1):
        inner_row = abs(rr - r) <= w_old
        for cc in range(c0, c1 + 1):
            if inner_row and abs(cc - c) <= w_old:
                continue
            if valid[rr, cc]:
                _insert(best, _d2(xq, yq, zq, x[rr, cc], y[rr, cc], z[rr, cc]))
                n += 1
    return n


# --------------------------------------------------------------------------------------------
# phase 1: image window with the half-space bound
# --------------------------------------------------------------------------------------------
@nb.njit(cache=True, parallel=True)
def _window_phase(x, y, z, valid, m, divisor, w_cap, use_bound,
                  csuf, cpre, rsuf, rpre, icsuf, icpre, irsuf, irpre):
    H, W = valid.shape
    dbar = np.zeros((H, W))
    status = np.zeros((H, W), np.uint8)
    radius2 = np.full((H, W), np.inf)
    w0 = 1
    while (2 * w0 + 1) * (2 * w0 + 1) < m:
        w0 += 1
    for r in nb.prange(H):
        best = np.empty(m)
        for c in range(W):
            if not valid[r, c]:
                continue
            xq = x[r, c]
            yq = y[r, c]
            zq = z[r, c]
            best[0] = 0.0  # the point itself
            for i in range(1, m):
                best[i] = np.inf
            if w0 == 1 and 0 < r < H - 1 and 0 < c < W - 1:
                # interior 3 x 3 window, branch-free: invalid pixels hold +inf coordinates,
                # hence an infinite distance that never enters the m smallest
                count = 1
                for rr in range(r - 1, r + 2):
                    for cc in (c - 1, c, c + 1):
                        if rr != r or cc != c:
                            _insert_minmax(best, _d2(xq, yq, zq, x[rr, cc], y[rr, cc], z[rr, cc]))
                            count += valid[rr, cc]
            else:
                count = 1 + _scan_ring(best, r, c, 0, w0, H, W, x, y, z, valid, xq, yq, zq)
            w = w0
            while count < m and w < w_cap:
                count += _scan_ring(best, r, c, w, w + 1, H, W, x, y, z, valid, xq, yq, zq)
                w += 1
            proven = False
            if count >= m and use_bound:
                dm2 = best[m - 1]
                margin = _MARGIN * (abs(xq) + abs(yq) + abs(zq))  # >= 1e-9 |P|
                for w_try in range(w, w_cap + 1):
                    b = _window_bound(r, c, w_try, H, W, xq, yq, zq,
                                      csuf, cpre, rsuf, rpre, icsuf, icpre, irsuf, irpre) - margin
                    if b > 0.0 and dm2 <= b * b:
                        if w_try > w:
                            _scan_ring(best, r, c, w, w_try, H, W, x, y, z, valid, xq, yq, zq)
                        proven = True
                        break
            if proven:
                status[r, c] = _DONE
                dbar[r, c] = _mean_of_sorted(best, divisor)
            else:
                status[r, c] = _UNPROVEN
                radius2[r, c] = best[m - 1]
    return dbar, status, radius2


# --------------------------------------------------------------------------------------------
# phase 2: tile hierarchy
# --------------------------------------------------------------------------------------------
@nb.njit(cache=True, parallel=True)
def _tile_boxes(x, y, z, valid, size):
    # per tile: min and max of x, y, z over its valid pixels (empty tile: lo = inf > hi = -inf)
    H, W = valid.shape
    th = (H + size - 1) // size
    tw = (W + size - 1) // size
    lo = np.full((th, tw, 3), np.inf)
    hi = np.full((th, tw, 3), -np.inf)
    for tr in nb.prange(th):
        for r in range(tr * size, min(H, (tr + 1) * size)):
            for c in range(W):
                if valid[r, c]:
                    tc = c // size
                    v0 = x[r, c]
                    v1 = y[r, c]
                    v2 = z[r, c]
                    lo[tr, tc, 0] = min(lo[tr, tc, 0], v0)
                    hi[tr, tc, 0] = max(hi[tr, tc, 0], v0)
                    lo[tr, tc, 1] = min(lo[tr, tc, 1], v1)
                    hi[tr, tc, 1] = max(hi[tr, tc, 1], v1)
                    lo[tr, tc, 2] = min(lo[tr, tc, 2], v2)
                    hi[tr, tc, 2] = max(hi[tr, tc, 2], v2)
    return lo, hi


@nb.njit(cache=True)
def _merge_boxes(lo, hi, f):
    th, tw = lo.shape[0], lo.shape[1]
    sh = (th + f - 1) // f
    sw = (tw + f - 1) // f
    slo = np.full((sh, sw, 3), np.inf)
    shi = np.full((sh, sw, 3), -np.inf)
    for i in range(th):
        for j in range(tw):
            for a in range(3):
                slo[i // f, j // f, a] = min(slo[i // f, j // f, a], lo[i, j, a])
                shi[i // f, j // f, a] = max(shi[i // f, j // f, a], hi[i, j, a])
    return slo, shi


@nb.njit(cache=True, inline="always")
def _box_d2(lo, hi, i, j, xq, yq, zq):
    # squared distance from the query to a box; empty boxes are infinitely far
    if lo[i, j, 0] > hi[i, j, 0]:
        return np.inf
    g = max(lo[i, j, 0] - xq, 0.0, xq - hi[i, j, 0])
    s = g * g
    g = max(lo[i, j, 1] - yq, 0.0, yq - hi[i, j, 1])
    s += g * g
    g = max(lo[i, j, 2] - zq, 0.0, zq - hi[i, j, 2])
    s += g * g
    return s


@nb.njit(cache=True, parallel=True)
def _tile_phase(x, y, z, valid, rows, cols, radius2, m, divisor, tlo, thi, slo, shi, cap):
    H, W = valid.shape
    n = rows.shape[0]
    out = np.zeros(n)
    ok = np.zeros(n, np.bool_)
    sh, sw = slo.shape[0], slo.shape[1]
    th, tw = tlo.shape[0], tlo.shape[1]
    slack = 1.0 + 1e-9
    for q in nb.prange(n):
        r = rows[q]
        c = cols[q]
        xq = x[r, c]
        yq = y[r, c]
        zq = z[r, c]
        best = np.full(m, np.inf)
        lim = radius2[q]            # upper bound on the m-th squared distance (inf if unknown)
        # super-tiles within the bound, nearest first (an early small m-th distance prunes more)
        sd = np.empty(sh * sw)
        sid = np.empty(sh * sw, np.int64)
        ns = 0
        for i in range(sh):
            for j in range(sw):
                d = _box_d2(slo, shi, i, j, xq, yq, zq)
                if d <= lim * slack:
                    sd[ns] = d
                    sid[ns] = i * sw + j
                    ns += 1
        order = np.argsort(sd[:ns])
        measured = 0
        aborted = False
        for o in range(ns):
            if sd[order[o]] > min(lim, best[m - 1]) * slack:
                break
            s = sid[order[o]]
            si = s // sw
            sj = s % sw
            for ti in range(si * _SUPER, min(th, (si + 1) * _SUPER)):
                for tj in range(sj * _SUPER, min(tw, (sj + 1) * _SUPER)):
                    cur = min(lim, best[m - 1]) * slack
                    if _box_d2(tlo, thi, ti, tj, xq, yq, zq) > cur:
                        continue
                    for rr in range(ti * _TILE, min(H, (ti + 1) * _TILE)):
                        for cc in range(tj * _TILE, min(W, (tj + 1) * _TILE)):
                            if valid[rr, cc]:
                                _insert(best, _d2(xq, yq, zq, x[rr, cc], y[rr, cc], z[rr, cc]))
                                measured += 1
                    if measured > cap:
                        aborted = True
                        break
                if aborted:
                    break
            if aborted:
                break
        if not aborted:
            ok[q] = True
            out[q] = _mean_of_sorted(best, divisor)
    return out, ok


# --------------------------------------------------------------------------------------------
# phase 3: KD-tree, re-measured exactly
# --------------------------------------------------------------------------------------------
@nb.njit(cache=True)
def _remeasure(pts, queries, flat_idx, offsets, m, divisor):
    n = queries.shape[0]
    out = np.zeros(n)
    best = np.empty(m)
    for q in range(n):
        for i in range(m):
            best[i] = np.inf
        xq, yq, zq = pts[queries[q], 0], pts[queries[q], 1], pts[queries[q], 2]
        for t in range(offsets[q], offsets[q + 1]):
            p = flat_idx[t]
            _insert(best, _d2(xq, yq, zq, pts[p, 0], pts[p, 1], pts[p, 2]))
        out[q] = _mean_of_sorted(best, divisor)
    return out


def _kdtree_mean_distances(pts: np.ndarray, queries: np.ndarray, m: int, divisor: float) -> np.ndarray:
    from scipy.spatial import cKDTree

    tree = cKDTree(pts, balanced_tree=False, compact_nodes=False)
    dist, _ = tree.query(pts[queries], k=[m])
    # every point whose exactly computed distance could tie the m-th: radius slightly enlarged
    radius = dist[:, 0] * (1.0 + 1e-9) + 1e-300
    lists = tree.query_ball_point(pts[queries], radius, workers=-1)
    lengths = np.fromiter((len(a) for a in lists), dtype=np.int64, count=len(lists))
    offsets = np.zeros(len(lists) + 1, dtype=np.int64)
    np.cumsum(lengths, out=offsets[1:])
    flat = np.fromiter((i for a in lists for i in a), dtype=np.int64, count=int(offsets[-1]))
    return _remeasure(pts, queries.astype(np.int64), flat, offsets, m, divisor)


# --------------------------------------------------------------------------------------------
# statistics
# --------------------------------------------------------------------------------------------
@nb.njit(cache=True)
def _outliers_open3d(dbar, valid, n, std_ratio):
    # PointCloud::RemoveStatisticalOutliers: mean over d̄ > 0 divided by the count of ALL points,
    # Bessel-corrected std over the same terms, inlier iff 0 < d̄ < threshold (strict)
    H, W = valid.shape
    s = 0.0
    for r in range(H):
        for c in range(W):
            if valid[r, c] and dbar[r, c] > 0.0:
                s = s + dbar[r, c]
    mean = s / n
    sq = 0.0
    for r in range(H):
        for c in range(W):
            if valid[r, c] and dbar[r, c] > 0.0:
                sq = sq + (dbar[r, c] - mean) * (dbar[r, c] - mean)
    std = math.sqrt(sq / (n - 1))
    thr = mean + std_ratio * std
    out = np.zeros((H, W), np.bool_)
    for r in range(H):
        for c in range(W):
            if valid[r, c]:
                d = dbar[r, c]
                out[r, c] = not (d > 0.0 and d < thr)
    return out


@nb.njit(cache=True)
def _outliers_pcl(dbar, valid, n, std_ratio):
    # d̄ > mean + std_ratio * std, sample std (n - 1), sequential sums in row-major order
    H, W = valid.shape
    s = 0.0
    for r in range(H):
        for c in range(W):
            if valid[r, c]:
                s = s + dbar[r, c]
    mean = s / n
    sq = 0.0
    for r in range(H):
        for c in range(W):
            if valid[r, c]:
                sq = sq + (dbar[r, c] - mean) * (dbar[r, c] - mean)
    std = math.sqrt(sq / (n - 1))
    thr = mean + std_ratio * std
    out = np.zeros((H, W), np.bool_)
    for r in range(H):
        for c in range(W):
            if valid[r, c]:
                out[r, c] = dbar[r, c] > thr
    return out


# --------------------------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------------------------
def _check_params(k: object, std_ratio: object, convention: object) -> tuple[int, float]:
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)):
        raise ParameterError(f"k must be an integer >= 1, got {k!r}")
    if k < 1:
        raise ParameterError(f"k must be an integer >= 1, got {k!r}")
    if isinstance(std_ratio, (bool, np.bool_)) or not isinstance(std_ratio, (int, float, np.integer, np.floating)):
        raise ParameterError(f"std_ratio must be a finite number > 0, got {std_ratio!r}")
    ratio = float(std_ratio)
    if not (math.isfinite(ratio) and ratio > 0.0):
        raise ParameterError(f"std_ratio must be a finite number > 0, got {std_ratio!r}")
    if convention not in CONVENTIONS:
        raise ParameterError(f"convention must be one of {CONVENTIONS}, got {convention!r}")
    return int(k), ratio


@nb.njit(cache=True, parallel=True)
def _split_planes(a):
    H, W = a.shape[0], a.shape[1]
    x = np.zeros((H, W))
    y = np.zeros((H, W))
    z = np.zeros((H, W))
    valid = np.zeros((H, W), np.bool_)
    for r in nb.prange(H):
        for c in range(W):
            u = np.float64(a[r, c, 0])
            v = np.float64(a[r, c, 1])
            w = np.float64(a[r, c, 2])
            if np.isfinite(u) and np.isfinite(v) and np.isfinite(w):
                valid[r, c] = True
                x[r, c] = u
                y[r, c] = v
                z[r, c] = w
            else:  # never a neighbour: infinitely far from every valid point
                x[r, c] = np.inf
                y[r, c] = np.inf
                z[r, c] = np.inf
    return x, y, z, valid


def _prepare(xyz: XYZ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """float64 x, y, z planes (+inf where invalid) and the valid mask."""
    a = check_xyz(xyz)
    if a.dtype != np.float32:  # one compiled variant per dtype: float32 or float64, C order
        a = a.astype(np.float64, copy=False)
    return _split_planes(np.ascontiguousarray(a))


def sor_mean_distances(xyz: XYZ, *, k: int = 4, convention: str = "pcl") -> np.ndarray:
    """Mean distance d̄ of every valid pixel to its k nearest neighbours, exactly.

    Parameters
    ----------
    xyz : (H, W, 3) float ndarray
        Organized cloud; a pixel is valid iff its three coordinates are finite.
    k : int
        Number of neighbours, >= 1.
    convention : {"pcl", "open3d"}
        ``"pcl"``: the point itself excluded; ``"open3d"``: included (at distance 0).

    Returns
    -------
    (H, W) float64 ndarray
        d̄ in the unit of ``xyz``; NaN on invalid pixels. With fewer valid points than the
        search needs, the mean is over all the valid points there are (Open3D's behaviour).
    """
    k, _ = _check_params(k, 1.0, convention)
    x, y, z, valid = _prepare(xyz)
    dbar = np.full(valid.shape, np.nan)
    n = int(valid.sum())
    if n == 0:
        return dbar
    m = k + 1 if convention == "pcl" else k
    divisor = float(k)
    if n < m:  # too few points for a full neighbourhood: average over what exists
        m = n
        divisor = float(n - 1 if convention == "pcl" else n)
        if divisor == 0.0:
            dbar[valid] = 0.0
            return dbar
    dbar[valid] = _mean_distances(x, y, z, valid, m, divisor)[valid]
    return dbar


def _mean_distances(x, y, z, valid, m: int, divisor: float) -> np.ndarray:
    H, W = valid.shape
    use_bound = bool(np.all(z[valid] > 0.0))
    if use_bound:
        ratios = _ratio_bounds(x, y, z, valid)
    else:
        ratios = (np.zeros(W), np.zeros(W), np.zeros(H), np.zeros(H))
    bounds = ratios + tuple(_inv_norms(t) for t in ratios)
    w0 = 1
    while (2 * w0 + 1) ** 2 < m:
        w0 += 1
    w_cap = max(6, w0 + 4)
    dbar, status, radius2 = _window_phase(x, y, z, valid, m, divisor, w_cap, use_bound, *bounds)
    rows, cols = np.nonzero(status == _UNPROVEN)
    n = int(np.count_nonzero(valid))
    if rows.size and rows.size <= max(_KD_ALL_ABOVE, n // 8):  # else not organized enough: KD-tree for all
        tlo, thi = _tile_boxes(x, y, z, valid, _TILE)
        slo, shi = _merge_boxes(tlo, thi, _SUPER)
        vals, ok = _tile_phase(
            x, y, z, valid, rows, cols, radius2[rows, cols], m, divisor, tlo, thi, slo, shi, _TILE_SEARCH_CAP
        )
        dbar[rows[ok], cols[ok]] = vals[ok]
        rows, cols = rows[~ok], cols[~ok]
    if rows.size:
        index = np.full(valid.shape, -1, dtype=np.int64)
        index[valid] = np.arange(n)
        pts = np.stack([x[valid], y[valid], z[valid]], axis=1)
        dbar[rows, cols] = _kdtree_mean_distances(pts, index[rows, cols], m, divisor)
    return dbar


def sor_outliers(xyz: XYZ, *, k: int = 4, std_ratio: float = 1.0, convention: str = "pcl") -> Mask:
    """Statistical outlier removal on an organized cloud (SPEC §2).

    Parameters
    ----------
    xyz : (H, W, 3) float ndarray
        Organized cloud; a pixel is valid iff its three coordinates are finite. float32 is upcast
        to float64. Invalid pixels are never outliers and never neighbours.
    k : int
        Number of nearest neighbours, >= 1 (pcdenoise / the paper: 4).
    std_ratio : float
        Threshold in standard deviations, finite and > 0 (pcdenoise: 1).
    convention : {"pcl", "open3d"}
        ``"pcl"``: d̄ over the k nearest other points; outlier iff d̄ > μ + std_ratio·σ, with μ the
        mean and σ the sample standard deviation of d̄ over the valid points.
        ``"open3d"``: exactly what ``open3d.geometry.PointCloud.remove_statistical_outlier(k,
        std_ratio)`` keeps when given the valid points in row-major order: the point itself counts
        as a neighbour at distance 0, μ = (sum of the d̄ > 0) / (number of points), σ² = (sum over
        the d̄ > 0 of (d̄ − μ)²) / (number of points − 1); inlier iff 0 < d̄ < μ + std_ratio·σ, and
        the outliers are the other valid pixels (so a point with k coincident copies is an outlier).

    Returns
    -------
    (H, W) bool ndarray
        True at outliers. Fewer than k + 1 valid points: no outliers.

    Raises
    ------
    InputShapeError
        ``xyz`` is not an (H, W, 3) float array.
    ParameterError
        ``k``, ``std_ratio`` or ``convention`` out of range.
    """
    k, ratio = _check_params(k, std_ratio, convention)
    x, y, z, valid = _prepare(xyz)
    n = int(valid.sum())
    if n < k + 1:
        return np.zeros(valid.shape, dtype=bool)
    m = k + 1 if convention == "pcl" else k
    dbar = _mean_distances(x, y, z, valid, m, float(k))
    if convention == "pcl":
        return _outliers_pcl(dbar, valid, float(n), ratio)
    return _outliers_open3d(dbar, valid, float(n), ratio)
