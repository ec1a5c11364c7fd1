"""Window phase of :mod:`zcut.sor`: the m nearest candidates of every pixel from an image window
around it, and the proof (camera bounds of :mod:`zcut.sor_camera`) that nothing outside the window
can be closer.

The argument is in the module docstring of :mod:`zcut.sor`. Three stages, cheapest first:

1. a 3 × 3 window for a whole row at once, written as straight-line code over the columns (the
   compiler vectorizes it): the 8 neighbour distances are sorted by a network, so any m <= 9 is
   a selection, and the w = 1 bound is four plane evaluations;
2. a 5 × 5 window for the pixels of the row stage 1 left (the inner ring sorted, the outer ring
   merged into the 8 smallest);
3. one pixel at a time, the window growing to the smallest w whose bound covers the current m-th
   distance, up to ``WINDOW_MAX``.

Every kernel here is serial and releases the GIL; :mod:`zcut.sor` runs them over row ranges on
threads.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

from .sor_camera import BLOCK, KEEP, plane_bound, plane_bound_at

WINDOW_MAX = BLOCK // 2  # the window of a pixel stays inside its row and column band
_RING2 = np.array([(dr, dc) for dr in (-2, 2) for dc in range(-2, 3)]
                  + [(dr, dc) for dr in (-1, 0, 1) for dc in (-2, 2)], dtype=np.int64)  # Chebyshev ring 2


# --------------------------------------------------------------------------------------------
# distances and the m smallest
# --------------------------------------------------------------------------------------------
@intrinsic
def _sqrt(typingctx, v):
    """IEEE square root as the llvm.sqrt intrinsic (math.sqrt is a libm call, which keeps loops
    from being vectorized); both are correctly rounded, so the results are identical."""
    sig = types.float64(types.float64)

    def codegen(context, builder, signature, args):
        fn = builder.module.declare_intrinsic("llvm.sqrt", [ir.DoubleType()])
        return builder.call(fn, [args[0]])

    return sig, codegen


@nb.njit(cache=True, inline="always")
def d2(xq, yq, zq, xp, yp, zp):
    """nanoflann's L2 metric for dim 3: ((0 + dx²) + dy²) + dz², query minus point."""
    dx = xq - xp
    dy = yq - yp
    dz = zq - zp
    return (dx * dx + dy * dy) + dz * dz


@nb.njit(cache=True, inline="always")
def insert(best, v):
    """Keep ``best`` sorted ascending with its m smallest values; drop the largest."""
    m = best.shape[0]
    if v >= best[m - 1]:
        return
    i = m - 1
    while i > 0 and best[i - 1] > v:
        best[i] = best[i - 1]
        i -= 1
    best[i] = v


@nb.njit(cache=True, inline="always")
def mean_of_sorted(best, divisor):
    """``std::accumulate(sqrt(dist)) / k`` in ascending order from 0.0 (Open3D's d̄)."""
    s = 0.0
    for i in range(best.shape[0]):
        s += _sqrt(best[i])
    return s / divisor


@nb.njit(cache=True, inline="always")
def _ce(a, b):
    return min(a, b), max(a, b)


@nb.njit(cache=True, inline="always")
def _sort8(v0, v1, v2, v3, v4, v5, v6, v7):
    # Batcher's odd-even merge sort of 8 values: 19 compare-exchanges, no branches
    v0, v1 = _ce(v0, v1)
    v2, v3 = _ce(v2, v3)
    v4, v5 = _ce(v4, v5)
    v6, v7 = _ce(v6, v7)
    v0, v2 = _ce(v0, v2)
    v1, v3 = _ce(v1, v3)
    v4, v6 = _ce(v4, v6)
    v5, v7 = _ce(v5, v7)
    v1, v2 = _ce(v1, v2)
    v5, v6 = _ce(v5, v6)
    v0, v4 = _ce(v0, v4)
    v1, v5 = _ce(v1, v5)
    v2, v6 = _ce(v2, v6)
    v3, v7 = _ce(v3, v7)
    v2, v4 = _ce(v2, v4)
    v3, v5 = _ce(v3, v5)
    v1, v2 = _ce(v1, v2)
    v3, v4 = _ce(v3, v4)
    v5, v6 = _ce(v5, v6)
    return v0, v1, v2, v3, v4, v5, v6, v7


@nb.njit(cache=True, inline="always")
def _keep8(s1, s2, s3, s4, s5, s6, s7, s8, v):
    # insert v into the ascending s1..s8, dropping the largest, without branches
    s8 = min(s8, max(s7, v))
    s7 = min(s7, max(s6, v))
    s6 = min(s6, max(s5, v))
    s5 = min(s5, max(s4, v))
    s4 = min(s4, max(s3, v))
    s3 = min(s3, max(s2, v))
    s2 = min(s2, max(s1, v))
    s1 = min(s1, v)
    return s1, s2, s3, s4, s5, s6, s7, s8


@nb.njit(cache=True, inline="always")
def _pick(m, divisor, s1, s2, s3, s4, s5, s6, s7, s8):
    # the m-th smallest squared distance (the point itself, at 0, is the first) and d̄ = sum of
    # sqrt in ascending order from 0.0 (adding 0.0 for the unused slots changes nothing)
    dm2 = 0.0
    dm2 = s1 if m == 2 else dm2
    dm2 = s2 if m == 3 else dm2
    dm2 = s3 if m == 4 else dm2
    dm2 = s4 if m == 5 else dm2
    dm2 = s5 if m == 6 else dm2
    dm2 = s6 if m == 7 else dm2
    dm2 = s7 if m == 8 else dm2
    dm2 = s8 if m == 9 else dm2
    sm = 0.0
    sm += _sqrt(s1) if m >= 2 else 0.0
    sm += _sqrt(s2) if m >= 3 else 0.0
    sm += _sqrt(s3) if m >= 4 else 0.0
    sm += _sqrt(s4) if m >= 5 else 0.0
    sm += _sqrt(s5) if m >= 6 else 0.0
    sm += _sqrt(s6) if m >= 7 else 0.0
    sm += _sqrt(s7) if m >= 8 else 0.0
    sm += _sqrt(s8) if m >= 9 else 0.0
    return dm2, sm / divisor


@nb.njit(cache=True, inline="always")
def _inner8(xq, yq, zq, x, y, z, r, c):
    # the 8 distances of the 3 x 3 window, sorted (2D indexing: one base pointer per plane keeps
    # the vectorizer's run-time alias checks few)
    return _sort8(
        d2(xq, yq, zq, x[r - 1, c - 1], y[r - 1, c - 1], z[r - 1, c - 1]),
        d2(xq, yq, zq, x[r - 1, c], y[r - 1, c], z[r - 1, c]),
        d2(xq, yq, zq, x[r - 1, c + 1], y[r - 1, c + 1], z[r - 1, c + 1]),
        d2(xq, yq, zq, x[r, c - 1], y[r, c - 1], z[r, c - 1]),
        d2(xq, yq, zq, x[r, c + 1], y[r, c + 1], z[r, c + 1]),
        d2(xq, yq, zq, x[r + 1, c - 1], y[r + 1, c - 1], z[r + 1, c - 1]),
        d2(xq, yq, zq, x[r + 1, c], y[r + 1, c], z[r + 1, c]),
        d2(xq, yq, zq, x[r + 1, c + 1], y[r + 1, c + 1], z[r + 1, c + 1]),
    )


@nb.njit(cache=True, inline="always")
def _count8(x, r, c):
    # valid pixels among the 8 neighbours (invalid ones hold +inf)
    return (np.int64(x[r - 1, c - 1] < np.inf) + np.int64(x[r - 1, c] < np.inf)
            + np.int64(x[r - 1, c + 1] < np.inf) + np.int64(x[r, c - 1] < np.inf)
            + np.int64(x[r, c + 1] < np.inf) + np.int64(x[r + 1, c - 1] < np.inf)
            + np.int64(x[r + 1, c] < np.inf) + np.int64(x[r + 1, c + 1] < np.inf))


# --------------------------------------------------------------------------------------------
# bounds of the regions outside a window
# --------------------------------------------------------------------------------------------
@nb.njit(cache=True, inline="always")
def _strips(r, c, w, H, W, b, bc, xq, yq, zq, R, C):
    # the rows of the pixel's row band right and left of the window, the columns of its column
    # band below and above it
    s = np.inf
    if c + w + 1 < W:
        s = min(s, plane_bound_at(R[b], 0, c + w + 1, xq, yq, zq))
    if c - w - 1 >= 0:
        s = min(s, plane_bound_at(R[b], 4, c - w - 1, xq, yq, zq))
    if r + w + 1 < H:
        s = min(s, plane_bound_at(C[bc], 0, r + w + 1, xq, yq, zq))
    if r - w - 1 >= 0:
        s = min(s, plane_bound_at(C[bc], 4, r - w - 1, xq, yq, zq))
    return s


@nb.njit(cache=True, inline="always")
def _corners(b, bc, xq, yq, zq, Q):
    # the four regions outside both bands of the pixel (at least 17 px away in rows and columns):
    # each lies in two half-spaces, so the larger bound holds
    nrb = Q.shape[0] - 1
    ncb = Q.shape[1] - 1
    i1, i0, j1, j0 = min(b + 1, nrb), max(b - 1, 0), min(bc + 1, ncb), max(bc - 1, 0)
    s = np.inf
    for corner in range(4):
        tab = Q[i1 if corner < 2 else i0, j1 if corner % 2 == 0 else j0, corner]
        s = min(s, max(plane_bound(tab[0:4], xq, yq, zq), plane_bound(tab[4:8], xq, yq, zq)))
    return s


# --------------------------------------------------------------------------------------------
# stage 1: 3 x 3, a row at a time (vectorized)
# --------------------------------------------------------------------------------------------
@nb.njit(cache=True, error_model="numpy")
def _row_3x3(r, c_lo, c_hi, x, y, z, m, divisor, use_cam, Rb, band, dbar):
    """Pixels (r, c_lo..c_hi), 1 <= r < H - 1, 2 <= c_lo, c_hi < W - 2, with a 3 x 3 window and
    the w = 1 bound. ``Rb`` (8, W) are the planes of the pixel's row band; ``band`` (9, W) holds
    per column the planes of its column band for the rows r + 2 and r - 2 and its corner floor.
    Writes d̄ where proven, NaN where not (or invalid).

    Straight-line code without branches (selects): no branch on use_cam (without a camera the
    planes are placeholders and the bound is ignored), no division check (error_model), no uint8
    status store -- each of them kept the loop from being vectorized.
    """
    for c in range(c_lo, c_hi + 1):
        xq = x[r, c]
        yq = y[r, c]
        zq = z[r, c]
        s1, s2, s3, s4, s5, s6, s7, s8 = _inner8(xq, yq, zq, x, y, z, r, c)
        count = 1 + _count8(x, r, c)
        dm2, mean = _pick(m, divisor, s1, s2, s3, s4, s5, s6, s7, s8)
        sb = min(plane_bound_at(Rb, 0, c + 2, xq, yq, zq), plane_bound_at(Rb, 4, c - 2, xq, yq, zq))
        sb = min(sb, min(plane_bound_at(band, 0, c, xq, yq, zq), plane_bound_at(band, 4, c, xq, yq, zq)))
        fl = band[8, c]
        proven = (dm2 == 0.0) | (use_cam & (dm2 <= sb * sb * KEEP) & (dm2 <= fl * fl * KEEP))
        ok = (xq < np.inf) & (count >= m) & proven
        dbar[r, c] = mean if ok else np.nan


@nb.njit(cache=True)
def _band_row(band, C, floor, r, b, use_cam):
    # per column: the planes of its column band for the rows r + 2 and r - 2, and its floor
    H = C.shape[2]
    W = band.shape[1]
    band[:] = 0.0
    if not use_cam:
        return
    for bc in range(C.shape[0]):
        for c in range(max(0, BLOCK * bc - BLOCK // 2), min(W, BLOCK * bc + BLOCK // 2)):
            for f in range(4):
                band[f, c] = C[bc, f, r + 2] if r + 2 < H else 0.0
                band[4 + f, c] = C[bc, 4 + f, r - 2] if r >= 2 else 0.0
            if r + 2 >= H:
                band[3, c] = np.inf  # no rows below: an empty region
            if r < 2:
                band[7, c] = np.inf
            band[8, c] = floor[b, bc]


# --------------------------------------------------------------------------------------------
# stage 2: 5 x 5 for a list of pixels of a row
# --------------------------------------------------------------------------------------------
@nb.njit(cache=True, error_model="numpy")
def _list_5x5(r, cols, n, x, y, z, m, divisor, use_cam, R, C, floor, b, dbar):
    """The pixels (r, cols[:n]), 2 <= r < H - 2, 3 <= c < W - 3, with a 5 x 5 window and the
    w = 2 bound (inner ring sorted by the network, ring 2 merged into the 8 smallest). Writes d̄
    where proven; the others are left as they are."""
    H, W = x.shape
    for j in range(n):
        c = cols[j]
        xq = x[r, c]
        yq = y[r, c]
        zq = z[r, c]
        s1, s2, s3, s4, s5, s6, s7, s8 = _inner8(xq, yq, zq, x, y, z, r, c)
        count = 1 + _count8(x, r, c)
        for k in range(16):
            rr = r + _RING2[k, 0]
            cc = c + _RING2[k, 1]
            s1, s2, s3, s4, s5, s6, s7, s8 = _keep8(s1, s2, s3, s4, s5, s6, s7, s8,
                                                    d2(xq, yq, zq, x[rr, cc], y[rr, cc], z[rr, cc]))
            count += np.int64(x[rr, cc] < np.inf)
        if count < m:
            continue
        dm2, mean = _pick(m, divisor, s1, s2, s3, s4, s5, s6, s7, s8)
        proven = dm2 == 0.0
        if use_cam and not proven:
            bc = (c + BLOCK // 2) // BLOCK
            sb = _strips(r, c, 2, H, W, b, bc, xq, yq, zq, R, C)
            fl = floor[b, bc]
            proven = (dm2 <= sb * sb * KEEP) and (dm2 <= fl * fl * KEEP)
        if proven:
            dbar[r, c] = mean


# --------------------------------------------------------------------------------------------
# stage 3: one pixel, growing window
# --------------------------------------------------------------------------------------------
@nb.njit(cache=True, inline="always")
def _scan_ring(best, r, c, w_old, w_new, H, W, x, y, z, xq, yq, zq):
    # add the pixels of the (2 w_new + 1)² window outside the (2 w_old + 1)² one, without a
    # branch on validity (random in sparse clouds): invalid pixels hold +inf coordinates, hence
    # an infinite distance that insert() drops; returns the number of valid pixels added
    n = 0
    c0 = max(0, c - w_new)
    c1 = min(W - 1, c + w_new)
    for rr in range(max(0, r - w_new), min(H - 1, r + w_new) + 1):
        full = abs(rr - r) > w_old
        a0 = c0
        a1 = c1 if full else min(c1, c - w_old - 1)
        for part in range(1 if full else 2):
            if part == 1:
                a0 = max(c0, c + w_old + 1)
                a1 = c1
            for cc in range(a0, a1 + 1):
                insert(best, d2(xq, yq, zq, x[rr, cc], y[rr, cc], z[rr, cc]))
                n += np.int64(x[rr, cc] < np.inf)
    return n


@nb.njit(cache=True)
def _grow(r, c, best, x, y, z, m, divisor, w0, wmax, use_cam, R, C, Q, floor):
    """One pixel with a growing window: its d̄ if proven, else minus the m-th smallest squared
    distance found (-inf if the largest window held fewer than m valid pixels)."""
    H, W = x.shape
    xq = x[r, c]
    yq = y[r, c]
    zq = z[r, c]
    best[0] = 0.0  # the point itself
    for i in range(1, m):
        best[i] = np.inf
    count = 1 + _scan_ring(best, r, c, 0, w0, H, W, x, y, z, xq, yq, zq)
    w = w0
    while count < m and w < wmax:
        count += _scan_ring(best, r, c, w, w + 1, H, W, x, y, z, xq, yq, zq)
        w += 1
    if count < m:
        return -np.inf
    dm2 = best[m - 1]
    if dm2 == 0.0:
        return mean_of_sorted(best, divisor)  # m distances of 0: nothing can be smaller
    if not use_cam:
        return -dm2
    b = (r + BLOCK // 2) // BLOCK
    bc = (c + BLOCK // 2) // BLOCK
    while True:
        sb = _strips(r, c, w, H, W, b, bc, xq, yq, zq, R, C)
        if dm2 <= sb * sb * KEEP:
            cb = floor[b, bc]
            if not dm2 <= cb * cb * KEEP:
                cb = _corners(b, bc, xq, yq, zq, Q)
            if dm2 <= cb * cb * KEEP:
                return mean_of_sorted(best, divisor)
            return -dm2
        if w >= wmax:
            return -dm2
        # the smallest larger window whose bound covers the current m-th distance
        w2 = w + 1
        while True:
            sb = _strips(r, c, w2, H, W, b, bc, xq, yq, zq, R, C)
            if dm2 <= sb * sb * KEEP or w2 >= wmax:
                break
            w2 += 1
        if not dm2 <= sb * sb * KEEP:
            return -dm2  # not even the largest window would do: leave it to the tiles
        _scan_ring(best, r, c, w, w2, H, W, x, y, z, xq, yq, zq)
        w = w2
        dm2 = best[m - 1]
        if dm2 == 0.0:
            return mean_of_sorted(best, divisor)


# --------------------------------------------------------------------------------------------
# the phase
# --------------------------------------------------------------------------------------------
def first_window(m: int, wmax: int) -> int:
    """Half-width of the first window: the smallest w with (2w + 1)² >= m, at most wmax."""
    w0 = 1
    while (2 * w0 + 1) ** 2 < m:
        w0 += 1
    return min(w0, wmax)


@nb.njit(cache=True, nogil=True)
def window_rows(r0, r1, x, y, z, valid, m, divisor, w0, wmax, use_cam, R, C, Q, floor, dbar):
    """Rows r0..r1-1 of the window phase.

    Writes into dbar (H, W): d̄ >= 0 where proven; at the other valid pixels minus the m-th
    smallest squared distance found in the window (an upper bound on the true one is its
    negative; -inf if the window held fewer than m valid pixels). Invalid pixels are left alone.
    """
    H, W = valid.shape
    band = np.zeros((9, W))
    cols = np.empty(W, np.int64)
    best = np.empty(m)
    for r in range(r0, r1):
        b = (r + BLOCK // 2) // BLOCK
        fast = w0 == 1 and 0 < r < H - 1 and W >= 5
        if fast:
            _band_row(band, C, floor, r, b, use_cam)
            _row_3x3(r, 2, W - 3, x, y, z, m, divisor, use_cam, R[b], band, dbar)
            if 2 <= r < H - 2 and wmax >= 2 and W >= 7:  # what it left, with a 5 x 5 window
                n = 0
                for c in range(3, W - 3):
                    cols[n] = c
                    n += valid[r, c] & np.isnan(dbar[r, c])
                if n:
                    _list_5x5(r, cols, n, x, y, z, m, divisor, use_cam, R, C, floor, b, dbar)
        for c in range(W):
            if valid[r, c] and not (fast and 2 <= c <= W - 3 and not np.isnan(dbar[r, c])):
                dbar[r, c] = _grow(r, c, best, x, y, z, m, divisor, w0, wmax, use_cam, R, C, Q, floor)
