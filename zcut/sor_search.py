"""Fallback searches of :mod:`zcut.sor` for the pixels the window phase could not prove.

Two exact k-nearest searches with the same distance arithmetic as the window phase:

* a quadtree over the image's 8 × 8 pixel tiles, each node bounded by the box of its valid
  points and (with a camera model) the four half-spaces of its U and V ranges, searched nearest
  node first, with a cap on the pixels one search may measure;
* a KD-tree (median splits, balanced whatever the duplicates) over the points of the tiles that
  can hold a neighbour of the pixels whose tile search hit the cap, or over all valid points when
  the cloud is not organized at all.

Both prune a node when its lower bound is >= the m-th smallest distance found once m candidates
are known: points at exactly that distance cannot change the multiset of the m smallest
distances, so heaps of duplicates are not searched. Box bounds are evaluated in the order of the
distance itself and rounding is monotone, so they never exceed the computed distance to a point
in the box.

Every per-query kernel is serial and releases the GIL; :mod:`zcut.sor` runs them over query
ranges on threads.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from . import columns as _columns
from .sor_camera import KEEP, TILE, node_planes, plane_bound
from .sor_window import d2, insert, mean_of_sorted

KD_LEAF = 16

# outcome of the tile search of one pixel
FOUND = 0
NEEDS_KD = 1      # cap hit; a finite radius is known: KD-tree over the tiles within it
NEEDS_KD_ALL = 2  # cap hit and no finite radius: KD-tree over every valid point


# --------------------------------------------------------------------------------------------
# columns (zcut.columns): the first fall-back, for pixels with a known bound
# --------------------------------------------------------------------------------------------
@nb.njit(cache=True, nogil=True)
def column_queries(q0, q1, x, y, z, qr, qc, qlim, eligible, m, divisor, per_query, cols, x0, y0, z0, inv, nx,  # type: ignore[no-untyped-def]  # numba kernel
                   ny, out, done):
    """Exact d̄ of the eligible query pixels q0..q1-1 by a k-nearest search in the columns, given
    ``qlim``, an upper bound on each one's m-th smallest squared distance (finite). Once the
    queries of this range have scanned ``per_query`` entries each on average, the rest are left
    (done[q] stays False) to the tile search."""
    best = np.empty(m)
    budget = per_query * (q1 - q0)
    spent = 0
    for q in range(q0, q1):
        if not eligible[q] or spent > budget:
            continue
        r = qr[q]
        c = qc[q]
        used = _columns.knn_query(cols, x0, y0, z0, inv, nx, ny, x[r, c], y[r, c], z[r, c], qlim[q], best,
                                  budget - spent)
        if used < 0:
            break
        spent += used
        if best[m - 1] < np.inf:
            out[q] = mean_of_sorted(best, divisor)
            done[q] = True


@nb.njit(cache=True)
def valid_range(x, y, z, valid):  # type: ignore[no-untyped-def]  # numba kernel
    """Smallest and largest x, y and z of the valid pixels."""
    x0 = y0 = z0 = np.inf
    x1 = y1 = z1 = -np.inf
    for r in range(valid.shape[0]):
        for c in range(valid.shape[1]):
            if valid[r, c]:
                x0 = min(x0, x[r, c])
                x1 = max(x1, x[r, c])
                y0 = min(y0, y[r, c])
                y1 = max(y1, y[r, c])
                z0 = min(z0, z[r, c])
                z1 = max(z1, z[r, c])
    return x0, x1, y0, y1, z0, z1


# --------------------------------------------------------------------------------------------
# quadtree over the tiles
# --------------------------------------------------------------------------------------------
def build_quadtree(tcount: np.ndarray, tbox: np.ndarray, tuv: np.ndarray, P: np.ndarray, M: float,
                   use_cam: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Flat quadtree: level 0 = tiles, each level merges 2 × 2 nodes, the last is one node.

    Returns (level_off, level_h, level_w, count, box, planes) with ``planes`` (n, 16) the planes
    of the U >= min, U <= max, V >= min, V <= max half-spaces of each node above the tiles (at the
    tiles, boxes prune as well and the planes cost more than they save), zeros elsewhere.
    """
    level_off, level_h, level_w, count, box, uv = _merge_levels(tcount, tbox, tuv)
    planes = np.zeros((count.shape[0], 16))
    if use_cam:
        planes[level_off[1]:] = node_planes(uv[level_off[1]:], P, M)
    return level_off, level_h, level_w, count, box, planes


@nb.njit(cache=True)
def _merge_levels(tcount, tbox, tuv):  # type: ignore[no-untyped-def]  # numba kernel
    th, tw = tcount.shape
    nlev = 1
    h, w = th, tw
    while h > 1 or w > 1:
        h = (h + 1) // 2
        w = (w + 1) // 2
        nlev += 1
    level_off = np.zeros(nlev + 1, np.int64)
    level_h = np.zeros(nlev, np.int64)
    level_w = np.zeros(nlev, np.int64)
    h, w = th, tw
    for lv in range(nlev):
        level_h[lv] = h
        level_w[lv] = w
        level_off[lv + 1] = level_off[lv] + h * w
        h = (h + 1) // 2
        w = (w + 1) // 2
    n = level_off[nlev]
    count = np.zeros(n, np.int64)
    box = np.empty((n, 6))
    box[:, 0:3] = np.inf
    box[:, 3:6] = -np.inf
    uv = np.empty((n, 4))
    uv[:, 0::2] = np.inf
    uv[:, 1::2] = -np.inf
    for i in range(th):
        for j in range(tw):
            k = i * tw + j
            count[k] = tcount[i, j]
            for a in range(6):
                box[k, a] = tbox[i, j, a]
            for a in range(4):
                uv[k, a] = tuv[i, j, a]
    for lv in range(1, nlev):
        for i in range(level_h[lv - 1]):
            for j in range(level_w[lv - 1]):
                src = level_off[lv - 1] + i * level_w[lv - 1] + j
                dst = level_off[lv] + (i // 2) * level_w[lv] + j // 2
                count[dst] += count[src]
                for a in range(3):
                    box[dst, a] = min(box[dst, a], box[src, a])
                    box[dst, 3 + a] = max(box[dst, 3 + a], box[src, 3 + a])
                uv[dst, 0] = min(uv[dst, 0], uv[src, 0])
                uv[dst, 1] = max(uv[dst, 1], uv[src, 1])
                uv[dst, 2] = min(uv[dst, 2], uv[src, 2])
                uv[dst, 3] = max(uv[dst, 3], uv[src, 3])
    return level_off, level_h, level_w, count, box, uv


@nb.njit(cache=True, inline="always")
def _box_d2(box, k, xq, yq, zq):  # type: ignore[no-untyped-def]  # numba kernel
    # squared distance from the query to a box of actual point coordinates, in the order of d2()
    g = max(box[k, 0] - xq, 0.0, xq - box[k, 3])
    s = g * g
    g = max(box[k, 1] - yq, 0.0, yq - box[k, 4])
    s += g * g
    g = max(box[k, 2] - zq, 0.0, zq - box[k, 5])
    return s + g * g


@nb.njit(cache=True, inline="always")
def _node_bound2(k, count, box, planes, use_cam, xq, yq, zq):  # type: ignore[no-untyped-def]  # numba kernel
    if count[k] == 0:
        return np.inf
    s = _box_d2(box, k, xq, yq, zq)
    if use_cam:
        h = plane_bound(planes[k, 0:4], xq, yq, zq)
        h = max(h, plane_bound(planes[k, 4:8], xq, yq, zq))
        h = max(h, plane_bound(planes[k, 8:12], xq, yq, zq))
        h = max(h, plane_bound(planes[k, 12:16], xq, yq, zq))
        s = max(s, h * h * KEEP)
    return s


@nb.njit(cache=True, inline="always")
def _prunable(bd, lim, best, found, m):  # type: ignore[no-untyped-def]  # numba kernel
    # beyond the known upper bound, an empty node (infinite bound), or no closer than the m-th
    # distance found (ties are harmless)
    return bd > lim or bd == np.inf or (found >= m and bd >= best[m - 1])


@nb.njit(cache=True)
def _tile_query(r, c, lim, best, x, y, z, valid, m, cap, use_cam, tree, stack_k, stack_l, stack_b, cb, ck):  # type: ignore[no-untyped-def]  # numba kernel
    # nearest-first search of one pixel; returns (found, aborted): best[] holds the m smallest
    # squared distances of the pixels measured. stack_*: scratch of 4 · levels + 4 entries, cb, ck:
    # of 4 (a node's children, sorted); all made once per call of tile_queries, not once per pixel
    level_off, level_h, level_w, count, box, planes = tree
    H, W = valid.shape
    nlev = level_h.shape[0]
    xq = x[r, c]
    yq = y[r, c]
    zq = z[r, c]
    for i in range(m):
        best[i] = np.inf
    found = 0
    sp = 1
    stack_k[0] = 0  # the root: (0, 0) on the last level
    stack_l[0] = nlev - 1
    stack_b[0] = 0.0
    measured = 0
    while sp > 0:
        sp -= 1
        lv = stack_l[sp]
        ij = stack_k[sp]
        if _prunable(stack_b[sp], lim, best, found, m):
            continue
        i = ij // level_w[lv]
        j = ij % level_w[lv]
        if lv == 0:
            if measured >= cap:
                return found, True
            for rr in range(i * TILE, min(H, (i + 1) * TILE)):
                for cc in range(j * TILE, min(W, (j + 1) * TILE)):
                    if valid[rr, cc]:
                        insert(best, d2(xq, yq, zq, x[rr, cc], y[rr, cc], z[rr, cc]))
                        found += 1
                        measured += 1
            continue
        # children, pushed farthest first so that the nearest is searched first
        nc = 0
        cl = lv - 1
        for di in range(2):
            ci = 2 * i + di
            if ci >= level_h[cl]:
                continue
            for dj in range(2):
                cj = 2 * j + dj
                if cj >= level_w[cl]:
                    continue
                cij = ci * level_w[cl] + cj
                kc = level_off[cl] + cij
                if count[kc] == 0:
                    continue
                # the box first: a node it prunes is pruned by any larger bound (the test is
                # monotone), so its planes are evaluated only when it does not, and never at the
                # tiles, whose planes are zeros (build_quadtree): bd is _node_bound2's
                bd = _box_d2(box, kc, xq, yq, zq)
                if _prunable(bd, lim, best, found, m):
                    continue
                if use_cam and cl > 0:
                    bd = _node_bound2(kc, count, box, planes, use_cam, xq, yq, zq)
                    if _prunable(bd, lim, best, found, m):
                        continue
                t = nc  # insertion sort, descending
                while t > 0 and cb[t - 1] < bd:
                    cb[t] = cb[t - 1]
                    ck[t] = ck[t - 1]
                    t -= 1
                cb[t] = bd
                ck[t] = cij
                nc += 1
        for t in range(nc):
            stack_k[sp] = ck[t]
            stack_l[sp] = cl
            stack_b[sp] = cb[t]
            sp += 1
    return found, False


@nb.njit(cache=True, nogil=True)
def tile_queries(q0, q1, x, y, z, valid, qr, qc, qlim, m, divisor, cap, use_cam, tree, out, outcome, radius2,  # type: ignore[no-untyped-def]  # numba kernel
                 measured):
    """Exact d̄ of the query pixels q0..q1-1 by the quadtree, measuring at most ``cap`` pixels each.

    ``qlim`` is an upper bound on each one's m-th smallest squared distance (inf if unknown).
    Writes out (d̄) and outcome FOUND, or outcome NEEDS_KD / NEEDS_KD_ALL and radius2 (a possibly
    smaller upper bound than qlim, inf if unknown); measured = the pixels each one measured (the
    search's cost).
    """
    best = np.empty(m)
    nlev = tree[1].shape[0]
    stack_k = np.empty(4 * nlev + 4, np.int64)
    stack_l = np.empty(4 * nlev + 4, np.int64)
    stack_b = np.empty(4 * nlev + 4)
    cb = np.empty(4)
    ck = np.empty(4, np.int64)
    for q in range(q0, q1):
        lim = qlim[q]
        found, aborted = _tile_query(qr[q], qc[q], lim, best, x, y, z, valid, m, cap, use_cam, tree, stack_k, stack_l,
                                     stack_b, cb, ck)
        measured[q] = found
        if not aborted:
            out[q] = mean_of_sorted(best, divisor)
            outcome[q] = FOUND
        else:
            rad = lim
            if found >= m and best[m - 1] < rad:
                rad = best[m - 1]
            radius2[q] = rad
            outcome[q] = NEEDS_KD if rad < np.inf else NEEDS_KD_ALL


@nb.njit(cache=True, nogil=True)
def mark_queries(q0, q1, x, y, z, qr, qc, qrad2, max_tiles, use_cam, tree, mark, over):  # type: ignore[no-untyped-def]  # numba kernel
    """Mark every tile whose bound is <= the radius of query q0..q1-1 (it may hold one of its
    neighbours); sets over[q] if a query reaches more than ``max_tiles`` tiles."""
    level_off, level_h, level_w, count, box, planes = tree
    nlev = level_h.shape[0]
    stack_k = np.empty(4 * nlev + 4, np.int64)
    stack_l = np.empty(4 * nlev + 4, np.int64)
    for q in range(q0, q1):
        r = qr[q]
        c = qc[q]
        xq = x[r, c]
        yq = y[r, c]
        zq = z[r, c]
        rad = qrad2[q]
        sp = 1
        stack_k[0] = 0
        stack_l[0] = nlev - 1
        n = 0
        while sp > 0:
            sp -= 1
            lv = stack_l[sp]
            ij = stack_k[sp]
            if lv == 0:
                mark[ij] = True
                n += 1
                if n > max_tiles:
                    over[q] = True
                    break
                continue
            i = ij // level_w[lv]
            j = ij % level_w[lv]
            cl = lv - 1
            for di in range(2):
                ci = 2 * i + di
                if ci >= level_h[cl]:
                    continue
                for dj in range(2):
                    cj = 2 * j + dj
                    if cj >= level_w[cl]:
                        continue
                    cij = ci * level_w[cl] + cj
                    kc = level_off[cl] + cij
                    if count[kc] > 0 and not _box_d2(box, kc, xq, yq, zq) <= rad:  # the box first, as in _tile_query
                        continue
                    if _node_bound2(kc, count, box, planes, use_cam and cl > 0, xq, yq, zq) <= rad:
                        stack_k[sp] = cij
                        stack_l[sp] = cl
                        sp += 1


@nb.njit(cache=True)
def gather_tiles(x, y, z, valid, mark, tw):  # type: ignore[no-untyped-def]  # numba kernel
    """(n, 3) float64 points of the valid pixels of the marked tiles."""
    H, W = valid.shape
    n = 0
    for k in range(mark.shape[0]):
        if mark[k]:
            i = k // tw
            j = k % tw
            for rr in range(i * TILE, min(H, (i + 1) * TILE)):
                for cc in range(j * TILE, min(W, (j + 1) * TILE)):
                    n += valid[rr, cc]
    pts = np.empty((n, 3))
    n = 0
    for k in range(mark.shape[0]):
        if mark[k]:
            i = k // tw
            j = k % tw
            for rr in range(i * TILE, min(H, (i + 1) * TILE)):
                for cc in range(j * TILE, min(W, (j + 1) * TILE)):
                    if valid[rr, cc]:
                        pts[n, 0] = x[rr, cc]
                        pts[n, 1] = y[rr, cc]
                        pts[n, 2] = z[rr, cc]
                        n += 1
    return pts


@nb.njit(cache=True)
def gather_valid(x, y, z, valid):  # type: ignore[no-untyped-def]  # numba kernel
    """(n, 3) float64 points of all valid pixels, row-major."""
    H, W = valid.shape
    n = 0
    for r in range(H):
        for c in range(W):
            n += valid[r, c]
    pts = np.empty((n, 3))
    n = 0
    for r in range(H):
        for c in range(W):
            if valid[r, c]:
                pts[n, 0] = x[r, c]
                pts[n, 1] = y[r, c]
                pts[n, 2] = z[r, c]
                n += 1
    return pts


# --------------------------------------------------------------------------------------------
# KD-tree
# --------------------------------------------------------------------------------------------
@nb.njit(cache=True)
def _select(pts, lo, hi, kth, dim):  # type: ignore[no-untyped-def]  # numba kernel
    # Hoare quickselect on the rows pts[lo:hi] by pts[:, dim], moving the rows themselves: afterwards
    # keys above row kth are <= and keys below it >= its key; runs of equal keys are split evenly,
    # so duplicates cost O(n)
    left = lo
    right = hi - 1
    while right > left:
        mid = (left + right) // 2
        a = pts[left, dim]
        b = pts[mid, dim]
        c = pts[right, dim]
        pivot = max(min(a, b), min(max(a, b), c))  # median of three
        i = left
        j = right
        while i <= j:
            while pts[i, dim] < pivot:
                i += 1
            while pts[j, dim] > pivot:
                j -= 1
            if i <= j:
                for f in range(3):
                    t = pts[i, f]
                    pts[i, f] = pts[j, f]
                    pts[j, f] = t
                i += 1
                j -= 1
        if kth <= j:
            right = j
        elif kth >= i:
            left = i
        else:
            break


@nb.njit(cache=True, nogil=True)
def kd_build(pts, leaf=KD_LEAF):  # type: ignore[no-untyped-def]  # numba kernel
    """Balanced KD-tree (median split on the widest axis of each node's box), nodes of at most
    ``leaf`` points not split.

    Returns (sorted_pts, lo, hi, start, end, child): the points reordered so that every node is a
    contiguous range; ``child[k]`` is the left child (the right one is ``child[k] + 1``), -1 at
    leaves; lo / hi are the boxes of the actual points. O(n log n) time, O(n) memory. The points
    are reordered in a copy as the splits go (each node's box and split then read its rows in
    order, not through an index into the input).
    """
    n = pts.shape[0]
    out = np.empty((n, 3))
    for t in range(n):
        for a in range(3):
            out[t, a] = pts[t, a]
    leaf = max(leaf, 1)
    cap = 4 * (n // leaf + 1) + 1
    lo = np.empty((cap, 3))
    hi = np.empty((cap, 3))
    start = np.empty(cap, np.int64)
    end = np.empty(cap, np.int64)
    child = np.full(cap, -1, np.int64)
    stack = np.empty(128, np.int64)
    start[0] = 0
    end[0] = n
    nodes = 1
    sp = 1
    stack[0] = 0
    while sp > 0:
        sp -= 1
        k = stack[sp]
        s = start[k]
        e = end[k]
        x0 = y0 = z0 = np.inf  # the box in locals (kept in registers)
        x1 = y1 = z1 = -np.inf
        for t in range(s, e):
            x0 = min(x0, out[t, 0])
            x1 = max(x1, out[t, 0])
            y0 = min(y0, out[t, 1])
            y1 = max(y1, out[t, 1])
            z0 = min(z0, out[t, 2])
            z1 = max(z1, out[t, 2])
        lo[k, 0], lo[k, 1], lo[k, 2] = x0, y0, z0
        hi[k, 0], hi[k, 1], hi[k, 2] = x1, y1, z1
        if e - s <= leaf:
            continue
        dim = 0
        ext = hi[k, 0] - lo[k, 0]
        for a in range(1, 3):
            if hi[k, a] - lo[k, a] > ext:
                ext = hi[k, a] - lo[k, a]
                dim = a
        mid = (s + e) // 2
        _select(out, s, e, mid, dim)
        child[k] = nodes
        start[nodes] = s
        end[nodes] = mid
        start[nodes + 1] = mid
        end[nodes + 1] = e
        stack[sp] = nodes
        stack[sp + 1] = nodes + 1
        sp += 2
        nodes += 2
    return out, lo[:nodes].copy(), hi[:nodes].copy(), start[:nodes].copy(), end[:nodes].copy(), child[:nodes].copy()


@nb.njit(cache=True, inline="always")
def _kd_box_d2(lo, hi, k, xq, yq, zq):  # type: ignore[no-untyped-def]  # numba kernel
    g = max(lo[k, 0] - xq, 0.0, xq - hi[k, 0])
    s = g * g
    g = max(lo[k, 1] - yq, 0.0, yq - hi[k, 1])
    s += g * g
    g = max(lo[k, 2] - zq, 0.0, zq - hi[k, 2])
    return s + g * g


@nb.njit(cache=True, nogil=True)
def kd_queries(q0, q1, x, y, z, qr, qc, qlim, m, divisor, kd, out):  # type: ignore[no-untyped-def]  # numba kernel
    """Exact d̄ of the query pixels q0..q1-1 over the KD-tree's points (which must hold their m
    nearest); ``qlim`` as for :func:`tile_queries`."""
    pts, lo, hi, start, end, child = kd
    best = np.empty(m)
    stack_k = np.empty(160, np.int64)
    stack_b = np.empty(160)
    for q in range(q0, q1):
        r = qr[q]
        c = qc[q]
        xq = x[r, c]
        yq = y[r, c]
        zq = z[r, c]
        for i in range(m):
            best[i] = np.inf
        found = 0
        lim = qlim[q]
        sp = 1
        stack_k[0] = 0
        stack_b[0] = 0.0
        while sp > 0:
            sp -= 1
            k = stack_k[sp]
            if _prunable(stack_b[sp], lim, best, found, m):
                continue
            ch = child[k]
            if ch < 0:
                for t in range(start[k], end[k]):
                    insert(best, d2(xq, yq, zq, pts[t, 0], pts[t, 1], pts[t, 2]))
                    found += 1
                continue
            b0 = _kd_box_d2(lo, hi, ch, xq, yq, zq)
            b1 = _kd_box_d2(lo, hi, ch + 1, xq, yq, zq)
            near, far, bn, bf = ch, ch + 1, b0, b1
            if b1 < b0:
                near, far, bn, bf = ch + 1, ch, b1, b0
            if not _prunable(bf, lim, best, found, m):
                stack_k[sp] = far
                stack_b[sp] = bf
                sp += 1
            if not _prunable(bn, lim, best, found, m):
                stack_k[sp] = near
                stack_b[sp] = bn
                sp += 1
        out[q] = mean_of_sorted(best, divisor)
