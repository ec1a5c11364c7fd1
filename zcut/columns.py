"""Columns: a 3D search structure for the pixels the image windows cannot settle (shared by
:mod:`zcut.radius` and :mod:`zcut.sor`).

The x-y plane is cut into square cells of side ``1 / inv``; a column holds the valid points whose
(x, y) fall in its cell, ordered by slab (z cut into cells of the same side: a column is a stack
of cubes), consecutive identical points merged into one entry with a multiplicity. For a camera
looking along z (the optical frame), a column is a thin tube along the rays: a query visits the
few columns its ball can reach and, in each, binary-searches the slabs of the ball's z range, so
its cost depends on the points near it in 3D, not on where they lie in the image; tall parts
standing on end (whose image neighbours are rarely 3D neighbours) cost no more than a flat floor.
The columns are dense arrays (no hashing): neighbouring columns are neighbours in memory. Only the
columns some query can reach need to be filled (``marked``).

Exactness: every function here is monotone in each coordinate (``cell``) or carries a margin
(``reach``), so a query visits every point whose computed squared distance
``(dx² + dy²) + dz²`` (float64, query minus point) can be below its bound; see :func:`reach`.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

_EPS = 2.220446049250313e-16


@nb.njit(cache=True, nogil=True, inline="always")
def d2(xq, yq, zq, xp, yp, zp):  # type: ignore[no-untyped-def]  # numba kernel
    """Open3D's (nanoflann's) squared distance: ((0 + dx²) + dy²) + dz², query minus point."""
    dx = xq - xp
    dy = yq - yp
    dz = zq - zp
    return (dx * dx + dy * dy) + dz * dz


@nb.njit(cache=True, nogil=True, inline="always")
def cell(v, v0, inv):  # type: ignore[no-untyped-def]  # numba kernel
    """The cell of coordinate v (monotone in v: every rounding step is)."""
    return np.int64(math.floor((v - v0) * inv))


@nb.njit(cache=True, nogil=True, inline="always")
def reach(v, rad):  # type: ignore[no-untyped-def]  # numba kernel
    """R with |v - p| < R for every p whose computed (v - p)² is at most fl(rad²) (1 + 2 eps):
    then |fl(v - p)| < rad (1 + 2 eps) and |v - p| < rad (1 + 3 eps); the margin also covers the
    rounding of v ∓ R (4 eps |v|), so [fl(v - R), fl(v + R)] holds every such p."""
    return rad * (1.0 + 1e-12) + 4.0 * _EPS * abs(v) + 1e-300


@nb.njit(cache=True, nogil=True)
def mark_columns(qx, qy, qrad, x0, y0, inv, nx, ny, marked):  # type: ignore[no-untyped-def]  # numba kernel
    """Mark every column the ball (qx[i], qy[i], radius qrad[i]) can reach (qrad < 0: none)."""
    for i in range(qx.shape[0]):
        if not qrad[i] >= 0.0:
            continue
        R = reach(max(abs(qx[i]), abs(qy[i])), qrad[i])
        for iy in range(max(cell(qy[i] - R, y0, inv), 0), min(cell(qy[i] + R, y0, inv), ny - 1) + 1):
            for ix in range(max(cell(qx[i] - R, x0, inv), 0), min(cell(qx[i] + R, x0, inv), nx - 1) + 1):
                marked[iy * nx + ix] = True


@nb.njit(cache=True, nogil=True)
def _sort_by_slab(xs, ys, zs, s, e, z0, inv, tx, ty, tz, counts):  # type: ignore[no-untyped-def]  # numba kernel
    # order entries s..e-1 by their slab cell(z, z0, inv) (a counting sort, stable: raster order
    # inside a slab); counts is scratch of at least e - s + 1 entries. A column whose slabs span
    # more than e - s values is sorted by z itself (numba's introsort).
    n = e - s
    k0 = cell(zs[s], z0, inv)
    k1 = k0
    for i in range(s + 1, e):
        k = cell(zs[i], z0, inv)
        k0 = min(k0, k)
        k1 = max(k1, k)
    if k0 == k1:
        return
    if k1 - k0 >= n:
        order = np.argsort(zs[s:e])
        for t in range(n):
            i = s + order[t]
            tx[t], ty[t], tz[t] = xs[i], ys[i], zs[i]
    else:
        span = k1 - k0 + 1
        counts[:span + 1] = 0
        for i in range(s, e):
            counts[cell(zs[i], z0, inv) - k0 + 1] += 1
        for k in range(span):
            counts[k + 1] += counts[k]
        for i in range(s, e):
            k = cell(zs[i], z0, inv) - k0
            t = counts[k]
            counts[k] += 1
            tx[t], ty[t], tz[t] = xs[i], ys[i], zs[i]
    for t in range(n):
        xs[s + t], ys[s + t], zs[s + t] = tx[t], ty[t], tz[t]


def build_columns(X: np.ndarray, Y: np.ndarray, Z: np.ndarray, x0: float, y0: float, z0: float, inv: float, nx: int,
                  marked: np.ndarray) -> tuple[np.ndarray, ...]:
    """The valid points (all three of X, Y, Z finite; (H, W) planes of any float type and layout)
    of the marked columns, column by column, ordered by slab (``cell(z, z0, inv)``: cubes of the
    column's width), consecutive identical points merged.

    Returns ``(start, xs, ys, zs, mult, ks)``: column k holds entries start[k] .. start[k + 1] - 1,
    ``ks`` their slabs. (:func:`count_columns` then :func:`fill_columns` into arrays of its own.)
    """
    ncol = marked.shape[0]
    start = np.empty(ncol + 1, np.int64)
    n = count_columns(X, Y, Z, x0, y0, inv, nx, marked, start)
    xs, ys, zs, mult, ks = np.empty(n), np.empty(n), np.empty(n), np.empty(n, np.int64), np.empty(n, np.int64)
    out = fill_columns(X, Y, Z, x0, y0, z0, inv, nx, marked, start, np.empty(ncol, np.int64), xs, ys, zs, mult, ks)
    return start, xs[:out], ys[:out], zs[:out], mult[:out], ks[:out]


@nb.njit(cache=True, nogil=True)
def count_columns(X, Y, Z, x0, y0, inv, nx, marked, start):  # type: ignore[no-untyped-def]  # numba kernel
    """start (ncol + 1) := the first entry of each marked column before merging (a prefix sum of
    their valid points' counts); returns the number of those points."""
    H, W = X.shape
    ncol = marked.shape[0]
    start[:] = 0
    for r in range(H):
        xr, yr, zr = X[r], Y[r], Z[r]
        for c in range(W):
            if xr[c] * 0.0 + yr[c] * 0.0 + zr[c] * 0.0 == 0.0:
                k = cell(np.float64(yr[c]), y0, inv) * nx + cell(np.float64(xr[c]), x0, inv)
                if marked[k]:
                    start[k + 1] += 1
    for k in range(ncol):
        start[k + 1] += start[k]
    return start[ncol]


@nb.njit(cache=True, nogil=True)
def fill_columns(X, Y, Z, x0, y0, z0, inv, nx, marked, start, fill, xs, ys, zs, mult, ks):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`build_columns` into given arrays: ``start`` as :func:`count_columns` left it (made
    the entries' starts), ``fill`` scratch of ncol, xs, ys, zs, mult, ks of at least
    ``start[ncol]`` entries. Returns the number of entries (the first that many are the columns)."""
    H, W = X.shape
    ncol = marked.shape[0]
    fill[:] = start[:ncol]
    for r in range(H):
        xr, yr, zr = X[r], Y[r], Z[r]
        for c in range(W):
            if xr[c] * 0.0 + yr[c] * 0.0 + zr[c] * 0.0 == 0.0:
                x = np.float64(xr[c])
                y = np.float64(yr[c])
                k = cell(y, y0, inv) * nx + cell(x, x0, inv)
                if marked[k]:
                    j = fill[k]
                    fill[k] += 1
                    xs[j], ys[j], zs[j] = x, y, np.float64(zr[c])
    longest = 0
    for k in range(ncol):
        longest = max(longest, start[k + 1] - start[k])
    tx, ty, tz = np.empty(longest), np.empty(longest), np.empty(longest)
    counts = np.empty(longest + 1, np.int64)
    out = 0
    for k in range(ncol):
        s, e = start[k], start[k + 1]
        start[k] = out
        if e - s > 1:
            _sort_by_slab(xs, ys, zs, s, e, z0, inv, tx, ty, tz, counts)
        j = s
        while j < e:
            x, y, z = xs[j], ys[j], zs[j]
            m = 1
            j += 1
            while j < e and zs[j] == z and xs[j] == x and ys[j] == y:
                m += 1
                j += 1
            xs[out], ys[out], zs[out], mult[out] = x, y, z, m
            out += 1
    start[ncol] = out
    for j in range(out):
        ks[j] = cell(zs[j], z0, inv)
    return out


@nb.njit(cache=True, nogil=True, inline="always")
def _first_slab(ks, lo, hi, k_lo):  # type: ignore[no-untyped-def]  # numba kernel
    # the first entry of lo..hi-1 (ordered by slab) whose slab is >= k_lo
    while lo < hi:
        mid = (lo + hi) // 2
        if ks[mid] < k_lo:
            lo = mid + 1
        else:
            hi = mid
    return lo


@nb.njit(cache=True, nogil=True, inline="always")
def _count_column(cols, col, xq, yq, zq, k_lo, k_hi, r2, n, need):  # type: ignore[no-untyped-def]  # numba kernel
    # count the entries of column col in slabs k_lo..k_hi strictly within r2 of q; (n, scanned)
    start, xs, ys, zs, mult, ks = cols
    j = _first_slab(ks, start[col], start[col + 1], k_lo)
    j0 = j
    end = start[col + 1]
    while j < end and n < need and ks[j] <= k_hi:
        if d2(xq, yq, zq, xs[j], ys[j], zs[j]) < r2:
            n += mult[j]
        j += 1
    return n, j - j0


@nb.njit(cache=True, nogil=True)
def count_query(cols, x0, y0, z0, inv, nx, ny, xq, yq, zq, rad, r2, need, n):  # type: ignore[no-untyped-def]  # numba kernel
    """Points strictly within ``r2`` (= fl(rad²)) of q, added to ``n`` and stopping at ``need``:
    the query's own column first. Returns (n, entries scanned)."""
    R = reach(max(abs(xq), abs(yq)), rad)
    Rz = reach(zq, rad)
    k_lo = cell(zq - Rz, z0, inv)
    k_hi = cell(zq + Rz, z0, inv)
    own_x = cell(xq, x0, inv)
    own_y = cell(yq, y0, inv)
    n, scanned = _count_column(cols, own_y * nx + own_x, xq, yq, zq, k_lo, k_hi, r2, n, need)
    iy0, iy1 = max(cell(yq - R, y0, inv), 0), min(cell(yq + R, y0, inv), ny - 1)
    ix0, ix1 = max(cell(xq - R, x0, inv), 0), min(cell(xq + R, x0, inv), nx - 1)
    for iy in range(iy0, iy1 + 1):
        for ix in range(ix0, ix1 + 1):
            if n >= need:
                return n, scanned
            if ix != own_x or iy != own_y:
                n, used = _count_column(cols, iy * nx + ix, xq, yq, zq, k_lo, k_hi, r2, n, need)
                scanned += used
    return n, scanned


@nb.njit(cache=True, nogil=True, inline="always")
def _insert_copies(best, found, v, copies):  # type: ignore[no-untyped-def]  # numba kernel
    # insert `copies` copies of v into the ascending best (its m smallest), like sor_window.insert
    m = best.shape[0]
    for _ in range(min(copies, m)):
        if v >= best[m - 1]:
            break
        i = m - 1
        while i > 0 and best[i - 1] > v:
            best[i] = best[i - 1]
            i -= 1
        best[i] = v
    return found + copies


@nb.njit(cache=True, nogil=True, inline="always")
def _ring_reach(xq, yq, rad, x0, y0, inv, own_x, own_y):  # type: ignore[no-untyped-def]  # numba kernel
    # the largest Chebyshev distance (in columns) from the query's column of a column that can
    # hold a point within rad of q in x and y
    R = reach(max(abs(xq), abs(yq)), rad)
    return max(own_x - cell(xq - R, x0, inv), cell(xq + R, x0, inv) - own_x,
               own_y - cell(yq - R, y0, inv), cell(yq + R, y0, inv) - own_y)


@nb.njit(cache=True, nogil=True)
def knn_query(cols, x0, y0, z0, inv, nx, ny, xq, yq, zq, lim, best, max_scan):  # type: ignore[no-untyped-def]  # numba kernel
    """The m = len(best) smallest squared distances from q into ``best`` (ascending), given
    ``lim``, an upper bound on the m-th smallest (finite: at least m points lie within it).

    Columns are visited ring by ring around the query's own column (Chebyshev distance 0, 1, ...);
    the search stops after the last ring that can hold a point within the current radius, which
    shrinks from sqrt(lim) to the m-th distance found. Every point whose computed squared distance
    is <= lim, or < the m-th smallest found so far once m are found, is visited; points at exactly
    the m-th distance could only replace one equal value by another (the multiset of the m smallest
    is final). Returns the entries scanned, or -1 when more than ``max_scan`` would be needed
    (``best`` is then not final).
    """
    start, xs, ys, zs, mult, ks = cols
    m = best.shape[0]
    for i in range(m):
        best[i] = np.inf
    found = 0
    rad = math.sqrt(lim)
    own_x = cell(xq, x0, inv)
    own_y = cell(yq, y0, inv)
    kmax = _ring_reach(xq, yq, rad, x0, y0, inv, own_x, own_y)
    scanned = 0
    k = 0
    while k <= kmax:
        for iy in range(own_y - k, own_y + k + 1):
            if iy < 0 or iy >= ny:
                continue
            step = 1 if (iy == own_y - k or iy == own_y + k) else max(2 * k, 1)
            for ix in range(own_x - k, own_x + k + 1, step):
                if ix < 0 or ix >= nx:
                    continue
                Rz = reach(zq, rad)
                col = iy * nx + ix
                j = _first_slab(ks, start[col], start[col + 1], cell(zq - Rz, z0, inv))
                j0 = j
                end = start[col + 1]
                k_hi = cell(zq + Rz, z0, inv)
                while j < end and ks[j] <= k_hi:
                    v = d2(xq, yq, zq, xs[j], ys[j], zs[j])
                    if v < best[m - 1]:
                        found = _insert_copies(best, found, v, mult[j])
                        if found >= m:  # the radius, and with it the z range, shrinks
                            rad = math.sqrt(best[m - 1])
                            k_hi = cell(zq + reach(zq, rad), z0, inv)
                    else:
                        found += mult[j]
                    j += 1
                scanned += j - j0
                if scanned > max_scan:
                    return -1
        if found >= m:
            kmax = min(kmax, _ring_reach(xq, yq, rad, x0, y0, inv, own_x, own_y))
        k += 1
    return scanned
