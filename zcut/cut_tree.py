"""Numba kernels of the z-cut: pixel levels, the component tree of all the cuts, its read-outs.

:mod:`zcut.cuts` explains the tree and why it equals the literal loop of docs/filters.md;
:mod:`zcut.cut_grid` explains why one tree answers every (d_max, μ_thr) pair. The kernels work on
the *padded* flat image of ``(H + 2) * (W + 2)`` pixels (a border of non-members saves the bounds
checks); a node is a component of the cut at the level where it last changed.

Building the tree

- :func:`qlevel` — the level of one height: the smallest ``k`` with ``z >= z_max - k * step``
  (exact float64 comparisons).
- :func:`pixel_levels` — that level for every pixel, into the padded level image ``q``.
- :func:`flood_tree` — the tree by flooding with a bucket queue over the levels (the default, up
  to ``FLOOD_MAX_LEVELS`` levels; :func:`flood_core_deep` from ``SHALLOW_LEVELS`` on).
- :func:`finite_range`, :func:`flood_levels`, :func:`flood_core` — the flood's fast path of
  :func:`zcut.cuts.zcut_outliers` and :func:`zcut.cuts.find_clusters`: one pass for the extremes
  (and the largest height of each row segment), one for the levels of the pixels in the cuts only
  (a segment wholly below the lowest cut is not read again), then the flood over those pixels
  (:func:`flood_whole` when they are every pixel of the frame: the deepest level not flooded).
- :func:`union_find_tree` — the same tree by union-find over the pixels sorted by level (any
  number of levels); :func:`node_image` turns its output into the flood's node image.

Reading it back

- :func:`outlier_mask` — the outlier mask of one parameter set (tags given per node).
- :func:`cluster_labels` — the outermost tagged nodes as (H, W) cluster labels.
- :func:`listed_outlier_mask`, :func:`listed_cluster_labels` — the same two over the pixels in the
  cuts only (the fast path).
- :func:`level_counts` — the number of components of every cut.
- :func:`taggable_forest` — the nodes that some ``(K, max_area)`` can tag, and for each pixel the
  lowest one holding it (the index of :class:`zcut.cut_grid.ZCutTree`).
- :func:`forest_mask` — the outlier mask of one ``(K, max_area)`` from that forest.
- :func:`grid_counts` — TP, FP and predicted pixel counts of a whole (K, max_area) grid from it.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
from llvmlite import ir
from numba.core import cgutils
from numba.core import types as nbtypes
from numba.cpython.unsafe.numbers import trailing_zeros
from numba.extending import intrinsic

__all__ = [
    "FLOOD_MAX_LEVELS",
    "KEPT",
    "PREFETCH_AHEAD",
    "PREFETCH_INTRINSIC",
    "SEGMENT",
    "SHALLOW_LEVELS",
    "cluster_labels",
    "cuts_window",
    "finite_range",
    "flood_core",
    "flood_core_deep",
    "flood_core_left_out",
    "flood_whole",
    "flood_levels",
    "flood_tree",
    "forest_mask",
    "gentle_levels",
    "gentle_prune",
    "grid_counts",
    "level_counts",
    "listed_cluster_labels",
    "listed_outlier_mask",
    "node_image",
    "outlier_mask",
    "pixel_levels",
    "pruned_cluster_labels",
    "pruned_clusters",
    "pruned_outlier_mask",
    "pruned_outliers",
    "pruned_scratch",
    "squeezed_heights",
    "qlevel",
    "segments_in_cuts",
    "taggable_forest",
    "union_find_tree",
]

# --------------------------------------------------------------------------------------------
# The component tree (numba)
# --------------------------------------------------------------------------------------------


@numba.njit(cache=True, inline="always")
def _inside(zt: float, z_max: float, step: float, k: np.int64, hi: np.int64) -> bool:
    # pixel in the cut at level k; level hi stands for "beyond" (always true)
    if k >= hi:
        return True
    return zt >= z_max - k * step  # type: ignore[return-value]  # numba kernel: a numpy bool


@numba.njit(cache=True)
def qlevel(zt: float, z_max: float, step: float, hi: np.int64) -> np.int64:
    """Smallest k in [0, hi) with zt >= z_max - k*step (exact float64 test), else hi."""
    g = (z_max - zt) / step
    if g >= hi:
        k = hi
    elif g > 0:
        k = np.int64(g)
    else:
        k = np.int64(0)
    # the division only gives a guess; the exact comparison decides
    if _inside(zt, z_max, step, k, hi):
        if k == 0 or not _inside(zt, z_max, step, k - 1, hi):
            return k
        good = k - 1
        d = np.int64(2)
        bad = np.int64(-1)
        while True:
            j = good - d
            if j < 0:
                break
            if _inside(zt, z_max, step, j, hi):
                good = j
                d *= 2
            else:
                bad = j
                break
    else:
        if _inside(zt, z_max, step, k + 1, hi):
            return k + 1
        bad = k + 1
        d = np.int64(2)
        while True:
            j = bad + d
            if j >= hi:
                good = hi
                break
            if _inside(zt, z_max, step, j, hi):
                good = j
                break
            bad = j
            d *= 2
    while good - bad > 1:
        mid = bad + (good - bad) // 2
        if _inside(zt, z_max, step, mid, hi):
            good = mid
        else:
            bad = mid
    return good


@numba.njit(cache=True, inline="always")
def _qlevel_guess(zt, z_max, step, inv_step, hi):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`qlevel`, fast when the guess ``floor((z_max - zt) * inv_step)`` or the next level is
    right (checked with the exact comparisons); else :func:`qlevel` itself."""
    g = (z_max - zt) * inv_step
    if g >= 0 and g < hi - 1:  # (False for NaN)
        k = np.int64(g)
        if zt >= z_max - k * step:
            if k == 0 or not zt >= z_max - (k - 1) * step:
                return k
        elif zt >= z_max - (k + 1) * step:  # in the cut k + 1, not in k
            return k + 1
    elif g >= hi - 1 and not zt >= z_max - (hi - 1) * step:  # not in the last cut
        return hi
    return qlevel(zt, z_max, step, hi)


@numba.njit(cache=True)
def pixel_levels(z, valid, z_min, z_max, step, hi, sentinel, q):  # type: ignore[no-untyped-def]  # numba kernel
    """Fill q, the (H + 2) * (W + 2) padded level image: interior = level, border = sentinel."""
    H, W = z.shape
    Wp = W + 2
    inv_step = 1.0 / step
    for c in range(Wp):
        q[c] = sentinel
        q[(H + 1) * Wp + c] = sentinel
    for r in range(H):
        base = (r + 1) * Wp
        q[base] = sentinel
        q[base + W + 1] = sentinel
        for c in range(W):
            zt = z[r, c] if valid[r, c] else z_min
            q[base + 1 + c] = _qlevel_guess(zt, z_max, step, inv_step, hi)


#: Row segments of :func:`finite_range`: a segment with no height in the cuts is not read twice.
SEGMENT = 64


@numba.njit(cache=True, nogil=True)
def _finite_range_float(z, seg_max):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`finite_range` by float comparisons (a scalar loop: the comparisons with NaN keep LLVM
    from vectorising it); its fallback when an extreme is a zero (both signs compare equal)."""
    H, W = z.shape
    n = 0
    lo = np.inf
    hi = -np.inf
    for r in range(H):
        for c0 in range(0, W, SEGMENT):
            c1 = min(c0 + SEGMENT, W)
            s_n = 0
            s_lo = np.inf
            s_hi = -np.inf
            for c in range(c0, c1):  # no branch: NaN fails every comparison, an infinity is checked below
                v = z[r, c]
                s_n += (v - v) == 0.0
                s_lo = v if v < s_lo else s_lo
                s_hi = v if v > s_hi else s_hi
            if s_lo == -np.inf or s_hi == np.inf:  # an infinite height (invalid) counted: again, with the test
                s_lo = np.inf
                s_hi = -np.inf
                for c in range(c0, c1):
                    v = z[r, c]
                    if np.isfinite(v):
                        s_lo = v if v < s_lo else s_lo
                        s_hi = v if v > s_hi else s_hi
            n += s_n > 0
            seg_max[r, c0 // SEGMENT] = s_hi
            # strict comparisons: the first of equal extremes in raster order, as _finite_min_max
            lo = s_lo if s_lo < lo else lo
            hi = s_hi if s_hi > hi else hi
    return n, lo, hi


#: The name :func:`_prefetch_codegen` declares ``llvm.prefetch`` under. The intrinsic is overloaded on the pointer
#: type, so each LLVM has its own mangled name (``llvm.prefetch.p0i8`` with typed pointers, LLVM <= 16;
#: ``llvm.prefetch.p0`` with opaque ones); LLVM's IR parser renames a declaration of any ``llvm.prefetch``
#: spelling to its own (checked on numba 0.60 / llvmlite 0.43 / LLVM 14, the dependency floor, 0.61 / 0.44 /
#: LLVM 15 and 0.68 / 0.50 / LLVM 22: the same declaration and a ``prefetcht0`` in the code;
#: ``tests/zcut/test_prefetch_name.py``), so no floor needs raising and no name needs choosing by version.
PREFETCH_INTRINSIC = "llvm.prefetch.p0"


def _prefetch_codegen(write: int) -> Any:
    """The code of ``llvm.prefetch`` of ``arr[idx]`` (``write``: 0 for a read, 1 for a write; kept in every
    cache level), for :func:`_prefetch_read` and :func:`_prefetch_write`."""

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(  # type: ignore[no-untyped-call]  # numba's cgutils
            context, builder, aryty, ary, [args[1]], wraparound=False, boundscheck=False)
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(  # type: ignore[no-untyped-call]  # numba's cgutils
            builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]), PREFETCH_INTRINSIC)
        builder.call(fn, [builder.bitcast(ptr, i8p), ir.Constant(i32, write), ir.Constant(i32, 3),
                          ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return codegen


def _prefetch_read(typingctx: Any, arr: Any, idx: Any) -> Any:
    """``llvm.prefetch`` of ``arr[idx]`` for a read: a hint, no effect on any value (x86's prefetch never
    faults; the callers keep ``idx`` inside ``arr`` all the same)."""
    return nbtypes.void(arr, idx), _prefetch_codegen(0)


def _prefetch_write(typingctx: Any, arr: Any, idx: Any) -> Any:
    """``llvm.prefetch`` of ``arr[idx]`` for a write (the line fetched for ownership before the store
    needs it): a hint, no effect on any value (the callers keep ``idx`` inside ``arr``)."""
    return nbtypes.void(arr, idx), _prefetch_codegen(1)


#: ``_prefetch(arr, idx)`` and ``_prefetch_w(arr, idx)`` in the kernels (:func:`_prefetch_read`,
#: :func:`_prefetch_write`).
_prefetch: Any = intrinsic(_prefetch_read)
_prefetch_w: Any = intrinsic(_prefetch_write)


#: How far ahead of the segment it reads :func:`finite_range` prefetches the heights, in heights (2 KB: 32
#: cache lines). The heights of a frame (18 MB at 1920 x 1200) are seldom in the caches when the z-cut
#: starts (the previous call, or the stage before, streamed other memory through them); read without the
#: hint the pass ran at ~10 GB/s here, ~1.6-2.0 ms instead of ~0.7 (docs/performance.md).
PREFETCH_AHEAD = 256


#: :func:`finite_range`'s integer keys: the bits of a float64 with the sign's complement below the
#: sign bit flipped, so that the keys of non-NaN floats order as the floats (-0.0 just below +0.0).
_LOW_BITS = np.int64(0x7FFFFFFFFFFFFFFF)
_EXP_BITS = np.int64(0x7FF0000000000000)  # all set: an infinity or a NaN
_NEG_INF_BITS = np.int64(-0x10000000000000)  # the bits of -inf
_KEY_MIN = np.int64(-0x7FFFFFFFFFFFFFFF - 1)
_KEY_MAX = np.int64(0x7FFFFFFFFFFFFFFF)


@numba.njit(cache=True, nogil=True)
def finite_range(z, seg_max):  # type: ignore[no-untyped-def]  # numba kernel
    """(n, min, max) of the finite heights of z (H, W, C-contiguous), n the number of row segments
    holding one (0: no finite height), and in ``seg_max`` (H, ceil(W / SEGMENT)) the largest finite
    height of each row segment of SEGMENT pixels (-inf: none). (n counted segments, not heights: one
    accumulator fewer in the vector loop, whose three reductions a segment were a third of its time;
    the callers want only whether n is 0.)

    On the bits, as integers: a height is finite iff its exponent bits are not all set, and the key
    ``bits ^ ((bits >> 63) & 0x7FF...F)`` orders the finite heights as the floats do. Integer
    extremes have no NaN to respect, so LLVM vectorises the loop (the float comparisons' is scalar:
    1.4 ms a 1920 x 1200 frame, ~0.6 ms so). The keys tell -0.0 below +0.0, which the floats do not:
    when an extreme is a zero, the extremes are taken again by :func:`_finite_range_float` (the
    first of equal extremes in raster order, as :func:`zcut.cuts._finite_min_max`). The heights
    ``PREFETCH_AHEAD`` on are prefetched (:func:`_prefetch_read`): the frame is seldom in the caches here, and the
    hardware alone read it at ~10 GB/s."""
    H, W = z.shape
    zi = z.reshape(-1).view(np.int64)
    si = seg_max.reshape(-1).view(np.int64)
    n_seg = seg_max.shape[1]
    last = zi.size - 1
    n = 0
    lo = _KEY_MAX
    hi = _KEY_MIN
    for r in range(H):
        row = r * W
        for c0 in range(0, W, SEGMENT):
            c1 = min(c0 + SEGMENT, W)
            # the heights PREFETCH_AHEAD on, a cache line (8 heights) at a time (a hint: no value changes)
            for j in range(0, SEGMENT, 8):
                _prefetch(zi, np.uint64(min(row + c0 + PREFETCH_AHEAD + j, last)))
            s_lo = _KEY_MAX
            s_hi = _KEY_MIN
            for j in range(c1 - c0):
                b = zi[np.uint64(row + c0 + j)]  # (an unsigned index: no wrap-around test, no gather)
                f = (b & _EXP_BITS) != _EXP_BITS
                k = b ^ ((b >> 63) & _LOW_BITS)
                s_hi = max(s_hi, k if f else _KEY_MIN)
                s_lo = min(s_lo, k if f else _KEY_MAX)
            si[r * n_seg + c0 // SEGMENT] = s_hi  # the key: its float below (a test here stops the vectors)
            lo = min(lo, s_lo)
            hi = max(hi, s_hi)
    for i in range(si.size):  # (_KEY_MIN: the key of a NaN, of no finite height)
        k = si[i]
        some = k != _KEY_MIN
        n += some
        si[i] = k ^ ((k >> 63) & _LOW_BITS) if some else _NEG_INF_BITS
    if n == 0:
        return n, np.inf, -np.inf
    bounds = np.empty(2, np.int64)
    bounds[0] = lo ^ ((lo >> 63) & _LOW_BITS)
    bounds[1] = hi ^ ((hi >> 63) & _LOW_BITS)
    v = bounds.view(np.float64)
    if v[0] == 0.0 or v[1] == 0.0:
        return _finite_range_float(z, seg_max)
    return n, v[0], v[1]


@numba.njit(cache=True, nogil=True)
def segments_in_cuts(seg_max, thr):  # type: ignore[no-untyped-def]  # numba kernel
    """The row segments whose largest height (``seg_max``, :func:`finite_range`'s) is in the cuts (``>=
    thr``): (their number, first row, last row + 1, first segment, last segment + 1); (0, 0, 0, 0, 0) when
    none is. One pass over ``seg_max`` (36,000 segments at 1920 x 1200) instead of four numpy passes."""
    H, n_seg = seg_max.shape
    n = 0
    r0, r1, s0, s1 = H, 0, n_seg, 0
    for r in range(H):
        row_n = 0
        first, last = n_seg, 0
        for s in range(n_seg):
            if seg_max[r, s] >= thr:
                row_n += 1
                first = min(first, s)
                last = s + 1
        if row_n > 0:
            n += row_n
            r0 = min(r0, r)
            r1 = r + 1
            s0 = min(s0, first)
            s1 = max(s1, last)
    if n == 0:
        return 0, 0, 0, 0, 0
    return n, r0, r1, s0, s1


@numba.njit(cache=True, nogil=True)
def flood_levels(z, seg_max, z_min, z_max, step, hi, top, K, st, start, pix, own, pixel_level, want_levels):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`pixel_levels` and the first pass of :func:`flood_tree` in one pass over the heights,
    touching only the pixels in the cuts (level <= ``top``) beyond one comparison each.

    Writes ``st`` (padded, int16): the level of each pixel in the cuts, -1 elsewhere and on the
    border; ``start[lv + 1]``: the number of pixels at level lv (``start`` zeroed, ``top + 2``
    long); ``pix[:m]``: the padded indices of the pixels in the cuts in raster order, and
    ``own[:m]`` their index in the flat (H, W) image, ``-1 - index`` for an invalid pixel; and,
    when ``want_levels``, ``pixel_level`` (H, W): the level where it is <= K + 1, else -1.
    Returns m. A pixel is in the cuts iff ``zt >= z_max - top * step``, the exact test of the cut
    at level ``top`` (the cuts are nested), and its level is then :func:`qlevel`'s. ``seg_max``
    is :func:`finite_range`'s: a segment of valid heights all below that threshold is not read.
    """
    H, W = z.shape
    Wp = W + 2
    inv_step = 1.0 / step
    thr = z_max - top * step
    skip = z_min < thr  # invalid pixels (at z_min) are outside the cuts: segments may be skipped
    zf = z.reshape(-1)
    for c in range(Wp):
        st[c] = -1
        st[(H + 1) * Wp + c] = -1
    m = 0
    for r in range(H):
        base = (r + 1) * Wp
        st[base] = -1
        st[base + W + 1] = -1
        for c0 in range(0, W, SEGMENT):
            c1 = min(c0 + SEGMENT, W)
            if skip and not seg_max[r, c0 // SEGMENT] >= thr:
                # no height of this segment is in the cuts: mark it without reading it again
                # (a slice fill: a memset, ~15 x faster here than a loop over the pixels)
                st[base + 1 + c0:base + 1 + c1] = -1
                if want_levels:
                    pixel_level[r, c0:c1] = -1
                continue
            _segment_levels(zf, st, r * W, base + 1, c0, c1, z_min, z_max, step, inv_step, hi, thr, top)
            for c in range(c0, c1):
                p = base + 1 + c
                lv = np.int64(st[p])
                if lv >= 0:
                    start[lv + 1] += 1
                    pix[m] = p
                    o = r * W + c
                    own[m] = o if np.isfinite(z[r, c]) else -1 - o
                    m += 1
                    if want_levels:
                        pixel_level[r, c] = lv if lv <= K + 1 else -1
                elif want_levels:
                    pixel_level[r, c] = -1
    return m


#: ``st`` of :func:`flood_core_left_out` at a pixel kept for the flood: ``KEPT + level``; a pixel in the cuts
#: left out of it keeps its level (0 .. ``top`` < ``SHALLOW_LEVELS`` < ``KEPT``), the others are -1. The prune
#: (:func:`gentle_prune`) so writes the few kept pixels only, not the many left out.
KEPT = 8192


@numba.njit(cache=True, inline="always")
def _near(qa, qb):  # type: ignore[no-untyped-def]  # numba kernel
    """Two levels within 1 of each other (no branch)."""
    return (qa - qb <= 1) & (qb - qa <= 1)


@numba.njit(cache=True, inline="always")
def _unite(gpar, ra, b):  # type: ignore[no-untyped-def]  # numba kernel
    """Union of the set of root ra and the set of label b (the smaller root becomes the root, so a
    parent's label is always smaller than its child's); returns the root."""
    if b == ra:
        return ra
    rb = np.int64(_find(gpar, b))
    if ra < rb:
        gpar[rb] = ra
        return ra
    if rb < ra:
        gpar[ra] = rb
    return rb


@numba.njit(cache=True, nogil=True, inline="always")
def _segment_levels(zf, st, row, base, c0, c1, z_min, z_max, step, inv_step, hi, thr, top):  # type: ignore[no-untyped-def]  # numba kernel
    """``st[base + c]`` for c in [c0, c1): the level of the pixel ``zf[row + c]`` in the cuts (<=
    ``top``), -1 outside them (an invalid pixel stands at ``z_min``). Without a branch, so LLVM
    vectorises it: the guess ``k = floor((z_max - zt) / step)`` (clamped to [0, top + 1], so that
    the conversion is defined) and the exact comparisons with the cuts k - 1, k and k + 1 give the level (k when
    the pixel is in the cut k and not in k - 1, k + 1 when it is in k + 1 and not in k, as
    :func:`_qlevel_guess`); where neither holds, the segment is levelled again by :func:`qlevel`."""
    gmax = np.float64(top + 1)
    bad = False
    for c in range(c0, c1):
        v = zf[np.uint64(row + c)]  # (an unsigned index: no wrap-around test)
        zt = v if (v - v) == 0.0 else z_min  # (v - v) == 0: finite
        g = (z_max - zt) * inv_step
        g = g if g < gmax else gmax
        g = g if g > 0.0 else 0.0  # (NaN too: 0 * inf with a subnormal step)
        k = np.int64(g)
        in0 = zt >= z_max - k * step
        inm = zt >= z_max - (k - 1) * step
        inp = zt >= z_max - (k + 1) * step
        ok = (in0 & ((k == 0) | (not inm))) | ((not in0) & inp)
        incut = zt >= thr
        st[np.uint64(base + c)] = (k + (not in0)) if incut else -1
        bad |= incut & (not ok)
    if bad:
        for c in range(c0, c1):
            v = zf[row + c]
            zt = v if np.isfinite(v) else z_min
            st[base + c] = _qlevel_guess(zt, z_max, step, inv_step, hi) if zt >= thr else -1


#: The bits of :func:`_gentle_codes`: a gentle edge to W, NE, NW, N; the unions with NW, NE, W that the
#: scan must make (when the labels differ); the pixel is in the cuts.
_GW, _GNE, _GNW, _GN, _UNW, _UNE, _UW, _IN_CUTS = 1, 2, 4, 8, 16, 32, 64, 128


_F0, _F1 = np.float32(0.0), np.float32(1.0)


@numba.njit(cache=True, nogil=True, inline="always")
def _gentle_codes(st, b, c0, c1, Wp, codes):  # type: ignore[no-untyped-def]  # numba kernel
    """``codes[c]`` for c in [c0, c1): what the 8-connected scan of :func:`gentle_levels` needs to know of the
    padded pixel ``b + c`` from the levels ``st`` (its row up to it and the row above complete), as bits:
    ``_GW .. _GN`` a gentle edge to that neighbour (both in the cuts, levels within 1), ``_UNW, _UNE, _UW``
    the neighbour's set is united with the label taken (from N, else NW, else NE, else W) unless a gentle
    edge joins the two neighbours already (N touches NW, NE and W; NW touches W; NE and W do not touch, nor
    NW and NE), ``_IN_CUTS``. Without a branch (unsigned indices: no wrap-around test), so LLVM vectorises
    it, in float32 lanes: numba widens every integer operation to 64 bits (8 lanes of a 512-bit vector) but
    keeps float32 (16 lanes); the levels, -1 or 0 .. ``top`` < ``SHALLOW_LEVELS``, and their differences
    are exact in float32, so "in the cuts" (``>= 0``) and "within 1" (``|a - b| <= 1``) are the integer
    tests, and the code, a sum of distinct powers of two below 256, is exact too (the pile's codes
    ~0.07 ms faster than on 64-bit integer lanes, docs/performance.md)."""
    for c in range(c0, c1):
        p = b + c
        lv = np.float32(st[np.uint64(p)])
        qw = np.float32(st[np.uint64(p - 1)])
        qn = np.float32(st[np.uint64(p - Wp)])
        qnw = np.float32(st[np.uint64(p - Wp - 1)])
        qne = np.float32(st[np.uint64(p - Wp + 1)])
        inc = lv >= _F0
        gw = inc & (qw >= _F0) & (abs(qw - lv) <= _F1)
        gn = inc & (qn >= _F0) & (abs(qn - lv) <= _F1)
        gnw = inc & (qnw >= _F0) & (abs(qnw - lv) <= _F1)
        gne = inc & (qne >= _F0) & (abs(qne - lv) <= _F1)
        ngn = not gn
        unw = gn & gnw & (abs(qnw - qn) > _F1)
        une = gne & ((gn & (abs(qne - qn) > _F1)) | (ngn & gnw))
        uw = gw & ((gn & (abs(qw - qn) > _F1)) | (ngn & gnw & (abs(qw - qnw) > _F1)) | (ngn & (not gnw) & gne))
        code = (np.float32(gw) * np.float32(_GW) + np.float32(gne) * np.float32(_GNE)
                + np.float32(gnw) * np.float32(_GNW) + np.float32(gn) * np.float32(_GN)
                + np.float32(unw) * np.float32(_UNW) + np.float32(une) * np.float32(_UNE)
                + np.float32(uw) * np.float32(_UW) + np.float32(inc) * np.float32(_IN_CUTS))
        codes[np.uint64(c)] = np.uint8(np.int32(code))


@numba.njit(cache=True, nogil=True)
def gentle_levels(z, seg_max, z_min, z_max, step, hi, top, conn8, max_area, check, st, pix, gl, gpar, gcnt,  # type: ignore[no-untyped-def]  # numba kernel
                  share=0.5, wr=0, wc=0, wh=-1, ww=-1, gls=None):
    """:func:`flood_levels` without ``own`` and ``pixel_level``, labelling on the way the *gentle
    components*: the components of the pixels in the cuts where two neighbours are joined when
    their levels differ by at most 1.

    One raster scan: a pixel copies the provisional label of a gentle neighbour before it, and the
    sets of the labels are united (a union-find over the labels) only where two gentle neighbours
    are not already known to be in one set (two neighbours joined by a gentle edge between them
    were united when the later one was labelled). The choices are made without branches where
    the data is noisy (a branch per neighbour costs a misprediction there). The 8-connected scan
    reads a segment's tests of the levels from its gentle-edge codes (:func:`_gentle_codes`, computed
    first in vector lanes), not from the levels: the dense frame's labelling 41 -> 24 ms
    (docs/performance.md).

    Writes ``st`` (padded; level or -1), ``pix[:m]`` (padded indices in raster order), ``gl``
    (padded, at the pixels in the cuts only: a provisional label), ``gpar`` (the labels'
    union-find, a parent's label smaller than its child's), ``gcnt`` (the pixels that took
    each label) and, if given, ``gls[:m]``: each labelled pixel's label in the order of ``pix`` (for
    :func:`gentle_prune` to read in order, not gathered from ``gl``; a label of the pixel's set, as ``gl``'s,
    which a union may later change to the set's root at the pixel NE of the one it unites). Returns (m,
    number of labels, labelled).

    Once ``check`` pixels in the cuts are labelled (at the end of that row), it looks whether the
    labelling pays: if fewer than ``share`` (half) of them lie in sets of ``max_area`` pixels or more
    (few gentle edges: quantised depths, steep relief; the flood would then visit most pixels
    anyway), it labels no further and returns labelled = False (the levels and ``pix`` are complete;
    the labels are not).

    ``wr, wc, wh, ww``: the window of z worked on, rows ``wr .. wr + wh - 1`` and columns ``wc .. wc
    + ww - 1`` (``wc`` a multiple of SEGMENT; ``wh, ww`` = -1: the whole frame); ``st``, ``gl`` and
    the indices in ``pix`` are then the window's (padded: ``(wh + 2) * (ww + 2)``). No pixel in the
    cuts may lie outside it."""
    ZW = z.shape[1]
    H = z.shape[0] if wh < 0 else wh
    W = ZW if ww < 0 else ww
    Wp = W + 2
    inv_step = 1.0 / step
    thr = z_max - top * step
    skip = z_min < thr  # invalid pixels (at z_min) are outside the cuts: segments may be skipped
    zf = z.reshape(-1)
    for c in range(Wp):
        st[c] = -1
        st[(H + 1) * Wp + c] = -1
    m = 0
    nl = 0
    labelling = True
    checked = False
    codes = np.empty(W, np.uint8)  # a row's gentle-edge codes (8-connected labelling)
    for r in range(H):
        if labelling and not checked and m >= check:
            checked = True
            labelling = _labelling_pays(gpar, gcnt, nl, m, max_area, share)
        base = (r + 1) * Wp
        st[base] = -1
        st[base + W + 1] = -1
        qw = np.int64(-1)  # the level and label of the pixel before (-1: not in the cuts)
        lw = np.int64(-1)
        for c0 in range(0, W, SEGMENT):
            c1 = min(c0 + SEGMENT, W)
            if r + 1 < H:
                # the segment below, worked on a row from now (hints, no value changes): its levels in st are
                # written either way, its heights read and its labels in gl written where it is read; a line
                # (64 bytes) at a time. Here the hardware did not fetch these short streams ahead itself (the
                # pile: ~0.1-0.25 ms of its 3, docs/performance.md).
                nb = base + Wp + 1 + c0
                for j in range(0, c1 - c0, 32):
                    _prefetch_w(st, np.uint64(nb + j))
                if not skip or seg_max[wr + r + 1, (wc + c0) // SEGMENT] >= thr:
                    nxt = (wr + r + 1) * ZW + wc + c0
                    for j in range(0, c1 - c0, 8):
                        _prefetch(zf, np.uint64(nxt + j))
                    for j in range(0, c1 - c0, 16):
                        _prefetch_w(gl, np.uint64(nb + j))
            if skip and not seg_max[wr + r, (wc + c0) // SEGMENT] >= thr:
                st[base + 1 + c0:base + 1 + c1] = -1
                qw = -1  # type: ignore[assignment]  # numba kernel: an int64 local
                continue
            _segment_levels(zf, st, (wr + r) * ZW + wc, base + 1, c0, c1, z_min, z_max, step, inv_step, hi, thr,
                            top)
            if labelling and conn8:
                # the 8-connected labelling from the segment's gentle-edge codes (:func:`_gentle_codes`:
                # the levels' tests, in vector lanes); the scan itself reads only the codes and labels
                _gentle_codes(st, base + 1, c0, c1, Wp, codes)
                for c in range(c0, c1):
                    cd = np.int64(codes[np.uint64(c)])
                    if cd < _IN_CUTS:
                        continue
                    p = base + 1 + c
                    pix[np.uint64(m)] = p
                    m += 1
                    ln = np.int64(gl[np.uint64(p - Wp)])  # (read even where not in the cuts: then unused)
                    lnw = np.int64(gl[np.uint64(p - Wp - 1)])
                    lne = np.int64(gl[np.uint64(p - Wp + 1)])
                    lab = lw if cd & _GW else np.int64(-1)
                    lab = lne if cd & _GNE else lab
                    lab = lnw if cd & _GNW else lab
                    lab = ln if cd & _GN else lab
                    if (((cd & _UNW) != 0) & (lnw != lab)) | (((cd & _UNE) != 0) & (lne != lab)) \
                            | (((cd & _UW) != 0) & (lw != lab)):
                        lab = np.int64(_find(gpar, lab))
                        if cd & _UNW:
                            lab = _unite(gpar, lab, lnw)
                        if cd & _UNE:
                            lab = _unite(gpar, lab, lne)
                        if cd & _UW:
                            lab = _unite(gpar, lab, lw)
                        if cd & _UNE:
                            # NE (the next pixels' N and NW) takes the root: a label of its set, so its
                            # set's count and every set are unchanged, and fewer unions are tried later
                            gl[np.uint64(p - Wp + 1)] = lab
                    if lab < 0:
                        lab = np.int64(nl)
                        gpar[nl] = nl
                        gcnt[nl] = 0
                        nl += 1
                    gl[np.uint64(p)] = lab
                    if gls is not None:
                        gls[np.uint64(m - 1)] = lab
                    gcnt[np.uint64(lab)] += 1
                    lw = lab
                continue
            for c in range(c0, c1):
                p = base + 1 + c
                lv = np.int64(st[p])
                if lv < 0:
                    qw = -1  # type: ignore[assignment]  # numba kernel: an int64 local
                    continue
                pix[m] = p
                m += 1
                if not labelling:
                    continue
                qn = np.int64(st[p - Wp])
                gw = (qw >= 0) & _near(qw, lv)
                gn = (qn >= 0) & _near(qn, lv)
                ln = np.int64(gl[p - Wp])  # (read even where not in the cuts: then unused)
                if conn8:
                    qnw = np.int64(st[p - Wp - 1])
                    qne = np.int64(st[p - Wp + 1])
                    gnw = (qnw >= 0) & _near(qnw, lv)
                    gne = (qne >= 0) & _near(qne, lv)
                    lnw = np.int64(gl[p - Wp - 1])
                    lne = np.int64(gl[p - Wp + 1])
                    lab = lw if gw else np.int64(-1)
                    lab = lne if gne else lab
                    lab = lnw if gnw else lab
                    lab = ln if gn else lab
                    # the label comes from N, else NW, else NE, else W; the others are united
                    # with it unless a gentle edge joins them to it already (N touches NW, NE
                    # and W; NW touches W; NE and W do not touch, nor NW and NE)
                    ngn = not gn
                    unw = gn & gnw & (not _near(qnw, qn))
                    une = gne & ((gn & (not _near(qne, qn))) | (ngn & gnw))
                    uw = gw & ((gn & (not _near(qw, qn))) | (ngn & gnw & (not _near(qw, qnw)))
                               | (ngn & (not gnw) & gne))
                    if (unw & (lnw != lab)) | (une & (lne != lab)) | (uw & (lw != lab)):
                        lab = np.int64(_find(gpar, lab))
                        if unw:
                            lab = _unite(gpar, lab, lnw)
                        if une:
                            lab = _unite(gpar, lab, lne)
                        if uw:
                            lab = _unite(gpar, lab, lw)
                else:
                    lab = lw if gw else np.int64(-1)
                    lab = ln if gn else lab
                    if gn & gw & (lw != lab):
                        lab = _unite(gpar, np.int64(_find(gpar, lab)), lw)
                if lab < 0:
                    lab = np.int64(nl)
                    gpar[nl] = nl
                    gcnt[nl] = 0
                    nl += 1
                gl[p] = lab
                if gls is not None:
                    gls[np.uint64(m - 1)] = lab
                gcnt[lab] += 1
                qw = lv
                lw = lab
    return m, nl, labelling


@numba.njit(cache=True, nogil=True)
def _labelling_pays(gpar, gcnt, nl, m, max_area, share):  # type: ignore[no-untyped-def]  # numba kernel
    """At least ``share`` of the m pixels labelled so far lie in sets of max_area pixels or more."""
    size = np.zeros(nl, np.int64)
    for i in range(nl):
        r = gpar[gpar[i]]  # (flattening is a valid union-find step: labels in creation order)
        gpar[i] = r
        size[r] += gcnt[i]
    big = 0
    for i in range(nl):
        if size[gpar[i]] >= max_area:
            big += gcnt[i]
    return big >= share * m


@numba.njit(cache=True, nogil=True)
def gentle_prune(st, pix, m, gl, gpar, gcnt, nl, max_area, start, labelled, W, conn8, top, gls=None):  # type: ignore[no-untyped-def]  # numba kernel
    """Keep in ``pix`` only the pixels of the gentle components (:func:`gentle_levels`) of fewer
    than ``max_area`` pixels that do not lie below a pixel left out (:func:`_uphill`), count them
    per level in ``start`` (zeroed; ``start[lv + 1]``, as :func:`flood_core` wants), and mark them
    ``KEPT + level`` in ``st`` (the pixels left out keep their level). Returns the number kept.
    Without ``labelled`` (:func:`gentle_levels` gave up) every pixel is kept. ``W``: the image's
    width; ``conn8``: the z-cut's connectivity; ``top``: the deepest level in the cuts (K + 1);
    ``gpar`` is used as scratch once the sets are read. ``gls``: the labels in the order of ``pix``
    (:func:`gentle_levels`' ``gls``), read in order; without it each pixel's label is read from ``gl``
    (a gather: the pile's pass ~2.5 x dearer, docs/performance.md).

    Why the flood over the kept pixels gives the outliers of the whole tree: a tagged node C is a
    component of two cuts k, k + 1, so every neighbour of C has a level >= k + 2 and no gentle
    edge leaves C: C is a union of whole gentle components, each smaller than C. So the kept
    pixels hold every tagged node, and each one is also a component of the same cuts among the
    kept pixels; conversely a node of the kept pixels' tree is a component of the whole cut at
    level k unless it touches a left-out pixel of level <= k, which :func:`flood_core` accounts
    for. The tagged nodes, as pixel sets, are the same in both trees. The argument needs only
    that no left-out pixel lies in a tagged node, so :func:`_uphill` may leave out more."""
    if not labelled:
        for t in range(m):
            p = pix[t]
            lv = np.int64(st[p])
            start[lv + 1] += 1
            st[p] = KEPT + lv
        return m
    for i in range(nl):  # labels in creation order: a parent's label is smaller, flattened first
        r = gpar[gpar[i]]
        gpar[i] = r
        if r != i:
            gcnt[r] += gcnt[i]  # the root's count is final once every label is flattened
    small = np.empty(nl, np.bool_)  # per label: one load a pixel below, not two dependent ones
    for i in range(nl):
        small[i] = gcnt[gpar[i]] < max_area
    keep = 0
    # the pixels of small sets listed (no branch: the kept pixels' slots are written either way), then
    # marked; the others (86 % of the pile's) are not written
    # (unsigned indices: no wrap-around test)
    if gls is not None:
        for t in range(m):
            p = pix[np.uint64(t)]
            pix[np.uint64(keep)] = p
            keep += small[np.uint64(gls[np.uint64(t)])]
    else:
        for t in range(m):
            p = pix[np.uint64(t)]
            pix[np.uint64(keep)] = p
            keep += small[np.uint64(gl[np.uint64(p)])]
    for t in range(keep):
        st[np.uint64(pix[np.uint64(t)])] += KEPT
    keep = _uphill(st, pix, keep, W, conn8, top, gpar)
    start[:] = 0
    n = 0
    for t in range(keep):
        p = pix[np.uint64(t)]
        q = np.int64(st[np.uint64(p)]) - KEPT
        if q >= 0:
            pix[np.uint64(n)] = p
            n += 1
            start[np.uint64(q + 1)] += 1
    return n


@numba.njit(cache=True, nogil=True, inline="always")
def _uphill(st, pix, keep, W, conn8, top, stack):  # type: ignore[no-untyped-def]  # numba kernel
    """Leave out (``st`` back to the level, from ``KEPT + level``), of the ``keep`` pixels kept so far
    (``pix[:keep]``), those that lie *below* a left-out pixel; returns ``keep`` (``pix`` unchanged).

    A tagged node C is a component of the cuts k and k + 1, so every neighbour of a pixel p of C
    whose level is at most ``level(p) + 1`` (<= k + 1) lies in C. Hence a pixel with such a
    neighbour in no tagged node is in no tagged node either, and neither is a pixel at level
    ``top`` (= K + 1: not in the cut at K). The left-out pixels (``0 <= st < KEPT``) are in no
    tagged node; one sweep over the kept pixels in raster order leaves out each one that has a
    left-out neighbour of level <= its level + 1 (or lies at ``top``), and from each one left out
    a depth-first walk leaves out at once every kept neighbour that it lies within one level
    below of, and so on (``stack``: ``keep`` int32 slots): the closure of the rule in one sweep.
    Neighbours: the z-cut's (``conn8``)."""
    Wp = W + 2
    if conn8:
        offs = np.array([-Wp - 1, -Wp, -Wp + 1, -1, 1, Wp - 1, Wp, Wp + 1])
    else:
        offs = np.array([-Wp, -1, 1, Wp])
    ne = offs.size
    for t in range(keep):
        p = pix[np.uint64(t)]
        q = np.int64(st[np.uint64(p)]) - KEPT
        if q < 0:  # left out by a walk already
            continue
        out = q >= top
        if not out:
            for u in range(8):  # (a constant trip count: unrolled)
                if u >= ne:
                    break
                s = np.int64(st[np.uint64(p + offs[u])])
                # a left-out neighbour (0 <= s < KEPT: its level) of level s <= q + 1 (one unsigned test)
                if np.uint64(s) <= np.uint64(q + 1):
                    out = True
                    break
        if not out:
            continue
        st[np.uint64(p)] = q
        stack[0] = p
        sp = 1
        while sp > 0:
            sp -= 1
            x = stack[np.uint64(sp)]
            qx = np.int64(st[np.uint64(x)])
            for u in range(8):
                if u >= ne:
                    break
                y = x + offs[u]
                s = np.int64(st[np.uint64(y)]) - KEPT
                if s >= 0 and qx <= s + 1:  # a kept neighbour lying within one level below x
                    st[np.uint64(y)] = s
                    stack[np.uint64(sp)] = y
                    sp += 1
    return keep


@numba.njit(cache=True, nogil=True)
def pruned_outlier_mask(z, lab, pix, fin, node_parent, tagged, out, wr=0, wc=0, ww=-1):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`listed_outlier_mask` over the pixels kept by :func:`gentle_prune` (``out`` (H * W,
    zeroed); the flat index and the validity of a pixel are found from its padded index in the
    window of :func:`gentle_levels`: rows from ``wr``, columns ``wc .. wc + ww - 1``, -1: the
    whole width)."""
    outer = _outermost(fin, node_parent, tagged)
    ZW = z.shape[1]
    W = ZW if ww < 0 else ww
    Wp = W + 2
    inv = 1.0 / Wp
    zf = z.reshape(-1)
    for t in range(pix.size):
        p = pix[t]
        if outer[lab[p]] >= 0:
            # the row p // Wp by a product: (p + 0.5) / Wp lies >= 0.5 / Wp from an integer and p
            # < 2**31, far more than the product's rounding error
            rp = np.int64((p + 0.5) * inv)
            o = (wr + rp - 1) * ZW + wc + (p - rp * Wp - 1)
            if np.isfinite(zf[o]):
                out[o] = True


@numba.njit(cache=True, nogil=True)
def _outermost(fin, node_parent, tagged):  # type: ignore[no-untyped-def]  # numba kernel
    """The outermost tagged node holding each node (itself included), -1: none."""
    outer = np.full(tagged.size, -1, np.int64)
    for t in range(fin.size - 1, -1, -1):  # parents are closed after their children
        a = fin[t]
        pa = node_parent[a]
        if pa >= 0 and outer[pa] >= 0:
            outer[a] = outer[pa]
        elif tagged[a]:
            outer[a] = a
    return outer


@numba.njit(cache=True, nogil=True)
def listed_outlier_mask(lab, pix, own, fin, node_parent, tagged, out):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`outlier_mask` over the pixels of :func:`flood_levels` only: ``out`` (H * W, zeroed)
    True on the valid ones held by a tagged node or by a node inside one."""
    outer = _outermost(fin, node_parent, tagged)
    for t in range(pix.size):
        o = own[t]
        if o >= 0 and outer[lab[pix[t]]] >= 0:
            out[o] = True


@numba.njit(inline="always", nogil=True)
def _number_cluster(x, o, n, number, tops, labels, areas):  # type: ignore[no-untyped-def]  # numba kernel
    """Pixel ``o`` joins the cluster of node ``x``, numbered at its first pixel (``number[x]``, 1-based; ``tops`` the
    nodes in that order): ``labels[o]`` its number, its pixel counted in ``areas``; returns the clusters numbered so
    far (``n`` + 1 when ``x`` is new). The read-outs :func:`listed_cluster_labels` and :func:`pruned_cluster_labels`."""
    if number[x] == 0:
        tops[n] = x
        n += 1
        number[x] = n
    i = number[x]
    labels[o] = i
    areas[i - 1] += 1
    return n


@numba.njit(cache=True, nogil=True)
def listed_cluster_labels(lab, pix, own, fin, node_parent, tagged, labels, outliers):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`cluster_labels` over the pixels of :func:`flood_levels` only (``labels`` int32 and
    ``outliers`` bool, H * W, zeroed): the same numbers (raster order of first pixel); returns the
    clusters' nodes and their valid pixel counts."""
    outer = _outermost(fin, node_parent, tagged)
    n_nodes = tagged.size
    number = np.zeros(n_nodes, np.int64)
    tops = np.empty(n_nodes, np.int64)
    areas = np.zeros(n_nodes, np.int64)
    n = 0
    for t in range(pix.size):
        o = own[t]
        if o < 0:
            continue
        x = outer[lab[pix[t]]]
        if x < 0:
            continue
        n = _number_cluster(x, o, n, number, tops, labels, areas)
        outliers[o] = True
    return tops[:n], areas[:n]


@numba.njit(cache=True, inline="always")
def _find(par, x):  # type: ignore[no-untyped-def]  # numba kernel
    """Root of x, with path halving (writes only where a path gets shorter)."""
    px = par[x]
    while px != x:
        gp = par[px]
        if gp == px:
            return px
        par[x] = gp
        x = gp
        px = par[x]
    return x


@numba.njit(cache=True, inline="always")
def _join(par, rec, p, rp, nb, rank, pend_node, pend_root, n_pend):  # type: ignore[no-untyped-def]  # numba kernel
    """Merge the set of neighbour nb with p's set (root rp, or -1 if p is not in a set yet).

    rec[r] = (size, node, stamp) of a root r; stamp = rank of the level at which r last changed.
    Returns (p's root, n_pend, 1 if two sets became one else 0).
    """
    rn = _find(par, nb)
    if rn == rp:
        return rp, n_pend, 0
    if rec[rn, 2] != rank:  # an older component changes now: its node ends at this level
        rec[rn, 2] = rank
        if rec[rn, 1] >= 0:
            pend_node[n_pend] = rec[rn, 1]
            pend_root[n_pend] = rn
            n_pend += 1
        rec[rn, 1] = -1
    if rp < 0:  # p joins as a leaf
        par[p] = rn
        rec[rn, 0] += 1
        return rn, n_pend, 1
    if rec[rn, 0] < rec[rp, 0]:
        par[rn] = rp
        rec[rp, 0] += rec[rn, 0]
        return rp, n_pend, 1
    par[rp] = rn
    rec[rn, 0] += rec[rp, 0]
    return rn, n_pend, 1


def _ring_table(ring: list[tuple[int, int]], touching: bool) -> tuple[np.ndarray, np.ndarray]:
    """For every subset (bit mask) of the ring neighbours in the cut, one neighbour per group of
    mutually touching ones (8-connectivity: ring pixels at Chebyshev distance 1 touch; they are
    in one set already, so joining one of them is enough). Returns (reps (2^n, 4), counts)."""
    n = len(ring)
    reps = np.zeros((1 << n, 4), np.int64)
    counts = np.zeros(1 << n, np.int64)
    for mask in range(1 << n):
        active = [i for i in range(n) if mask >> i & 1]
        seen: set[int] = set()
        for i in active:
            if i in seen:
                continue
            reps[mask, counts[mask]] = i
            counts[mask] += 1
            stack = [i]
            seen.add(i)
            while stack:
                a = stack.pop()
                for b in active:
                    if b not in seen and touching and max(
                        abs(ring[a][0] - ring[b][0]), abs(ring[a][1] - ring[b][1])
                    ) <= 1:
                        seen.add(b)
                        stack.append(b)
    reps.flags.writeable = False
    counts.flags.writeable = False
    return reps, counts


# ring order: the neighbours before p in raster order first
_RING8 = _ring_table([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)], True)
_RING4 = _ring_table([(-1, 0), (0, -1), (0, 1), (1, 0)], False)


@numba.njit(cache=True)
def union_find_tree(q, W, K, top, conn8, max_area):  # type: ignore[no-untyped-def]  # numba kernel
    """Union-find over the pixels in level order; one node per (component, last change).

    q : padded level image from :func:`pixel_levels`; pixels with q <= top (= K + 1) take part.
    Returns ``order`` (the padded indices of those pixels sorted by level, raster order inside a
    level), ``first`` (the first node holding ``order[t]``), the nodes' birth level, size, parent
    (the node that replaced it, -1 if it lives to the end) and tag, and the component count
    after each processed level.
    """
    n = q.size
    Wp = W + 2
    # ---- order the pixels by level (stable: raster order inside a level)
    m = 0
    for i in range(n):
        if q[i] <= top:
            m += 1
    order = np.empty(m, np.int32)
    if top + 2 <= 4 * n + 64:
        cnt = np.zeros(top + 2, np.int64)
        for i in range(n):
            if q[i] <= top:
                cnt[q[i] + 1] += 1
        for lv in range(1, top + 2):
            cnt[lv] += cnt[lv - 1]
        for i in range(n):
            qi = q[i]
            if qi <= top:
                order[cnt[qi]] = i
                cnt[qi] += 1
    else:  # more levels than pixels: sort instead of counting
        sel = np.empty(m, np.int64)
        j = 0
        for i in range(n):
            if q[i] <= top:
                sel[j] = i
                j += 1
        o = np.argsort(q[sel], kind="mergesort")
        for j in range(m):
            order[j] = sel[o[j]]

    par = np.empty(n, np.int32)  # union-find parent
    rec = np.empty((n, 4), np.int32)  # at roots only: size, node, stamp (one cache line), and
    # at the end of a level, for each root touched in it, the node its set became
    first = np.empty(m, np.int32)  # by position in order: p's root right after p was added,
    # then the node holding p at the end of its level
    node_b = np.empty(m, np.int64)
    node_size = np.empty(m, np.int64)
    node_parent = np.empty(m, np.int32)
    tagged = np.zeros(m, np.bool_)
    pend_node = np.empty(m, np.int32)
    pend_root = np.empty(m, np.int32)
    lev_value = np.empty(m, np.int64)
    lev_count = np.empty(m, np.int64)
    n_nodes = 0
    n_lev = 0
    count = 0
    if conn8:
        offs = np.array([-Wp - 1, -Wp, -Wp + 1, -1, 1, Wp - 1, Wp, Wp + 1])
        reps, reps_n = _RING8
    else:
        offs = np.array([-Wp, -1, 1, Wp])
        reps, reps_n = _RING4
    n_ring = offs.size
    n_prev = n_ring // 2  # the ring neighbours before p in raster order come first

    i = 0
    while i < m:
        lvl = q[order[i]]
        j = i
        while j < m and q[order[j]] == lvl:
            j += 1
        rank = n_lev
        n_pend = 0
        lvl_prev = np.int64(lvl)
        lvl_next = np.int64(lvl) - 1
        # ---- add the pixels of this level. A neighbour is in the cut already if its level is
        # lower, or equal and it comes before p in raster order (the later one does the joining).
        for t in range(i, j):
            p = order[t]
            count += 1
            rp = -1
            # which ring neighbours are in the cut already: lower level, or the same level and
            # before p in raster order (the later one of two same-level pixels does the joining)
            mask = 0
            for u in range(n_ring):
                mask |= (np.int64(q[p + offs[u]]) <= (lvl_prev if u < n_prev else lvl_next)) << u  # type: ignore[assignment]  # numba kernel: an int64 local
            # join one neighbour per group of touching ring neighbours (one set already)
            for u in range(reps_n[mask]):
                rp, n_pend, k = _join(par, rec, p, rp, p + offs[reps[mask, u]], rank,
                                      pend_node, pend_root, n_pend)
                count -= k
            if rp < 0:  # no neighbour in the cut: a new singleton
                par[p] = p
                rec[p, 0] = 1
                rec[p, 1] = -1
                rec[p, 2] = rank
                rp = p
                pend_node[n_pend] = -1
                pend_root[n_pend] = p
                n_pend += 1
            first[t] = rp
        # ---- one new node per component that changed at this level. Every root touched at this
        # level is listed in pend_root (with the node it ends, or -1 for a new singleton).
        for t in range(n_pend):
            x = pend_root[t]
            r = _find(par, x)
            if rec[r, 1] < 0:
                rec[r, 1] = n_nodes
                node_b[n_nodes] = lvl
                node_size[n_nodes] = rec[r, 0]
                node_parent[n_nodes] = -1
                n_nodes += 1
            rec[x, 3] = rec[r, 1]  # the node at this level of what x's set became
            # the node that ended here was unchanged over the levels [b, lvl - 1]
            old = pend_node[t]
            if old >= 0:
                node_parent[old] = rec[r, 1]
                lo = max(node_b[old], 1)
                hi = min(K, lvl - 2)
                tagged[old] = lo <= hi and node_size[old] < max_area
        for t in range(i, j):  # each pixel's root right after it was added was a touched root
            first[t] = rec[first[t], 3]
        lev_value[n_lev] = lvl
        lev_count[n_lev] = count
        n_lev += 1
        i = j
    # ---- the nodes that live to the end (e = K + 2)
    for a in range(n_nodes):
        if node_parent[a] < 0:
            tagged[a] = max(node_b[a], 1) <= K and node_size[a] < max_area
    return (order, first, node_b[:n_nodes], node_size[:n_nodes], node_parent[:n_nodes],
            tagged[:n_nodes], lev_value[:n_lev], lev_count[:n_lev])


# --------------------------------------------------------------------------------------------
# The component tree by flooding (Nistér & Stewénius, "Linear time maximally stable extremal
# regions", ECCV 2008): the default for up to FLOOD_MAX_LEVELS levels
# --------------------------------------------------------------------------------------------

#: Levels 0 .. top with top < this go to :func:`flood_tree` (its bucket queue finds the lowest
#: non-empty level in a bit map of 64 x 64 levels, or beyond ``SHALLOW_LEVELS`` in one of 8 x 64 x 64
#: levels: :func:`flood_core_deep`); more levels go to the union-find :func:`union_find_tree`. (``st``
#: is int16: the levels 0 .. 32767 fit.)
FLOOD_MAX_LEVELS = 32768
#: Levels 0 .. top with top < this flood with the two-tier bit map (:func:`flood_core`); more with the
#: three-tier one (:func:`flood_core_deep`). The pruned flood (:func:`pruned_outliers`) takes fewer
#: than this only (its float32 codes are checked up to it, and its ``KEPT + level`` marks need it).
SHALLOW_LEVELS = 4096
_U1 = np.uint64(1)


@numba.njit(cache=True, inline="always")
def _bit_set(occ, summ, lv):  # type: ignore[no-untyped-def]  # numba kernel
    w = lv >> 6
    occ[w] |= _U1 << np.uint64(lv & 63)
    return summ | (_U1 << np.uint64(w))


@numba.njit(cache=True, inline="always")
def _bit_clear(occ, summ, lv):  # type: ignore[no-untyped-def]  # numba kernel
    w = lv >> 6
    occ[w] &= ~(_U1 << np.uint64(lv & 63))
    if occ[w] == 0:
        return summ & ~(_U1 << np.uint64(w))
    return summ


@numba.njit(cache=True, inline="always")
def _bit_next(occ, summ, lv):  # type: ignore[no-untyped-def]  # numba kernel
    """Lowest set level >= lv, or -1."""
    w = lv >> 6
    x = occ[w] >> np.uint64(lv & 63)
    if x != 0:
        return lv + np.int64(trailing_zeros(x))  # type: ignore[call-arg]  # numba intrinsic: numba passes the typing context
    if w >= 63:
        return np.int64(-1)
    y = summ >> np.uint64(w + 1)
    if y == 0:
        return np.int64(-1)
    w2 = w + 1 + np.int64(trailing_zeros(y))  # type: ignore[call-arg]  # numba intrinsic: numba passes the typing context
    return w2 * 64 + np.int64(trailing_zeros(occ[w2]))


@numba.njit(cache=True, inline="always")
def _bit_set2(occ, mid, summ, lv):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_bit_set` with the deep map's signature (``mid`` unused)."""
    return _bit_set(occ, summ, lv)


@numba.njit(cache=True, inline="always")
def _bit_clear2(occ, mid, summ, lv):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_bit_clear` with the deep map's signature (``mid`` unused)."""
    return _bit_clear(occ, summ, lv)


@numba.njit(cache=True, inline="always")
def _bit_next2(occ, mid, summ, lv):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_bit_next` with the deep map's signature (``mid`` unused)."""
    return _bit_next(occ, summ, lv)


@numba.njit(cache=True, inline="always")
def _bit_set3(occ, mid, summ, lv):  # type: ignore[no-untyped-def]  # numba kernel
    """The three-tier map (:func:`flood_core_deep`): bit lv of ``occ`` (512 words), bit w of ``mid`` (8
    words: ``occ[w] != 0``), bit v of ``summ`` (``mid[v] != 0``, returned)."""
    w = lv >> 6
    v = w >> 6
    occ[w] |= _U1 << np.uint64(lv & 63)
    mid[v] |= _U1 << np.uint64(w & 63)
    return summ | (_U1 << np.uint64(v))


@numba.njit(cache=True, inline="always")
def _bit_clear3(occ, mid, summ, lv):  # type: ignore[no-untyped-def]  # numba kernel
    w = lv >> 6
    occ[w] &= ~(_U1 << np.uint64(lv & 63))
    if occ[w] == 0:
        v = w >> 6
        mid[v] &= ~(_U1 << np.uint64(w & 63))
        if mid[v] == 0:
            return summ & ~(_U1 << np.uint64(v))
    return summ


@numba.njit(cache=True, inline="always")
def _bit_next3(occ, mid, summ, lv):  # type: ignore[no-untyped-def]  # numba kernel
    """Lowest set level >= lv of the three-tier map, or -1."""
    w = lv >> 6
    x = occ[w] >> np.uint64(lv & 63)
    if x != 0:
        return lv + np.int64(trailing_zeros(x))  # type: ignore[call-arg]  # numba intrinsic: numba passes the typing context
    v = w >> 6
    if (w & 63) != 63:  # (a shift by 64 is undefined)
        y = mid[v] >> np.uint64((w & 63) + 1)
        if y != 0:
            w2 = w + 1 + np.int64(trailing_zeros(y))  # type: ignore[call-arg]  # numba intrinsic: numba passes the typing context
            return w2 * 64 + np.int64(trailing_zeros(occ[w2]))
    if v >= 7:
        return np.int64(-1)
    y = summ >> np.uint64(v + 1)
    if y == 0:
        return np.int64(-1)
    v2 = v + 1 + np.int64(trailing_zeros(y))  # type: ignore[call-arg]  # numba intrinsic: numba passes the typing context
    w2 = v2 * 64 + np.int64(trailing_zeros(mid[v2]))
    return w2 * 64 + np.int64(trailing_zeros(occ[w2]))


@numba.njit(cache=True, inline="always")
def _map_set(occ, mid, summ, lv, deep):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_bit_set3` with ``deep``, else :func:`_bit_set2` (``deep`` a constant of the calling kernel)."""
    if deep:
        return _bit_set3(occ, mid, summ, lv)
    return _bit_set2(occ, mid, summ, lv)


@numba.njit(cache=True, inline="always")
def _map_clear(occ, mid, summ, lv, deep):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_bit_clear3` with ``deep``, else :func:`_bit_clear2`."""
    if deep:
        return _bit_clear3(occ, mid, summ, lv)
    return _bit_clear2(occ, mid, summ, lv)


@numba.njit(cache=True, inline="always")
def _map_next(occ, mid, summ, lv, deep):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_bit_next3` with ``deep``, else :func:`_bit_next2`."""
    if deep:
        return _bit_next3(occ, mid, summ, lv)
    return _bit_next2(occ, mid, summ, lv)


@numba.njit(cache=True, inline="always")
def _close(a, size, parent, e, K, max_area, node_b, node_size, node_parent, tagged, fin, n_fin):  # type: ignore[no-untyped-def]  # numba kernel
    """Node a (a component of the cut at its level node_b[a]) ends: it next changes at level e
    (K + 2: never); parent is the node it becomes part of (-1: none). Returns n_fin + 1."""
    node_size[a] = size
    node_parent[a] = parent
    tagged[a] = max(node_b[a], 1) <= min(K, e - 2) and size < max_area
    fin[n_fin] = a
    return n_fin + 1


@numba.njit(cache=True)
def flood_tree(q, W, K, top, conn8, max_area):  # type: ignore[no-untyped-def]  # numba kernel
    """Component tree of the cuts by flooding, with a bucket queue over the levels.

    q : padded level image from :func:`pixel_levels`; pixels with q <= top (= K + 1 < 4096)
    take part. The flood visits each pixel once, in a cache-friendly order: from the current
    pixel it descends at once into any unvisited neighbour of a lower level (pushing the current
    pixel back, to resume at the next neighbour), and queues the others in the bucket of their
    level; the next pixel is the last one queued in the lowest non-empty bucket. A stack holds
    the components being built, at strictly increasing levels from top to bottom; when the
    flood rises to level lv, the components below lv are complete: each ends (is closed) and
    becomes part of the next one on the stack, or of a new component at lv.

    Returns ``lab`` (n,) int32, the node holding each pixel at its own level (-1: none), and the
    nodes' birth level, size, parent (-1: lives to the end), tag, and ``fin``, the nodes in
    closing order (every node is closed before its parent).
    """
    n = q.size
    nlev = top + 1
    start = np.zeros(nlev + 1, np.int64)
    # st: the level of an unseen pixel (>= 0); once seen (queued, or not in the cuts) -1 - the
    # neighbour to go on with when the pixel is popped (0 for a queued pixel)
    st = np.empty(n, np.int16)
    lab = np.empty(n, np.int32)  # written for every pixel: here, or when it is first visited
    pix = np.empty(n, np.int32)  # the pixels in the cuts, in raster order
    m = 0
    for i in range(n):
        qi = q[i]
        if qi <= top:
            start[qi + 1] += 1
            st[i] = qi
            pix[m] = i
            m += 1
        else:
            st[i] = -1
            lab[i] = -1
    if top < SHALLOW_LEVELS:
        node_b, node_size, node_parent, tagged, fin = flood_core(st, start, pix[:m], W, K, top, conn8, max_area, lab)
    else:
        node_b, node_size, node_parent, tagged, fin = flood_core_deep(st, start, pix[:m], W, K, top, conn8, max_area,
                                                                      lab)
    return lab, node_b, node_size, node_parent, tagged, fin


def _flood_kernel(left_out: bool, deep: bool = False) -> Any:
    """:func:`flood_core` (``left_out`` False) or :func:`flood_core_left_out` (True: ``st`` may hold
    left-out pixels, whose levels end the nodes they touch; a check the whole tree's flood need not
    pay in its innermost loop), or with ``deep`` :func:`flood_core_deep` (the bucket queue's bit map
    in three tiers: up to ``FLOOD_MAX_LEVELS`` levels, not ``SHALLOW_LEVELS``). The flags are
    constants of the compiled kernel."""
    # the bit map's functions are chosen inside the kernel by the constant ``deep`` (:func:`_map_set` ...), not
    # captured here: a closure over dispatchers pickles differently in every process, so numba's cache (keyed by the
    # closure's bytes) missed on every start and the kernel was compiled anew in each process (~2 CPU-s)
    n_occ = FLOOD_MAX_LEVELS // 64 if deep else SHALLOW_LEVELS // 64

    def flood_core(st, start, pix, W, K, top, conn8, max_area, lab):  # type: ignore[no-untyped-def]  # numba kernel
        """The flood of :func:`flood_tree` from its prepared state: ``st`` (padded, int16) the level
        of each pixel in the cuts and -1 elsewhere (the border included), ``start[lv + 1]`` the
        number of pixels at level lv (turned into the bucket starts here), ``pix`` the pixels in the
        cuts in raster order. Writes ``lab`` at those pixels only; returns what :func:`flood_tree`
        returns but ``lab``.

        With ``left_out`` (:func:`flood_core_left_out`) the pixels of ``pix`` hold ``KEPT + level`` in ``st``
        and the pixels in the cuts left out of the flood their level (:func:`gentle_prune`): such a
        neighbour is never flooded, but a node whose pixels touch one of level l is not a component of
        the cut at l, so its end ``e`` is taken as ``min(e, l)`` in the tag (the smallest such l is
        carried along the stack)."""
        Wp = W + 2
        nlev = top + 1
        for lv in range(nlev):
            start[lv + 1] += start[lv]
        m = start[nlev]
        fill = start[:nlev].copy()  # bucket lv = bucket[start[lv]:fill[lv]], a stack
        bucket = np.empty(m, np.int32)  # a pixel is queued at most once at a time, at its level
        occ = np.zeros(n_occ, np.uint64)  # bit lv: bucket lv non-empty
        mid = np.zeros(8, np.uint64)  # (deep) bit w: occ[w] != 0
        summ = np.uint64(0)  # bit w: occ[w] != 0 (deep: bit v: mid[v] != 0)
        stk_lv = np.empty(nlev + 1, np.int64)
        stk_area = np.empty(nlev + 1, np.int64)
        stk_node = np.empty(nlev + 1, np.int32)
        stk_lm = np.empty(nlev + 1, np.int64)  # the lowest level of a left-out neighbour
        nolim = np.int64(K + 2)
        node_b = np.empty(m, np.int64)
        node_size = np.empty(m, np.int64)
        node_parent = np.empty(m, np.int32)
        tagged = np.zeros(m, np.bool_)
        fin = np.empty(m, np.int32)
        if conn8:
            offs = np.array([-Wp - 1, -Wp, -Wp + 1, -1, 1, Wp - 1, Wp, Wp + 1])
        else:
            offs = np.array([-Wp, -1, 1, Wp])
        ne = offs.size
        n_nodes = 0
        n_fin = 0
        for t_s in range(pix.size):
            s = pix[t_s]
            if st[s] < 0:
                continue
            # ---- flood the region of the cuts that holds s. Kept in registers: the level cur of the
            # top of the stack, its node and area, and the fill of its bucket (bucket cur's bit in
            # occ is only brought up to date when cur changes)
            p = s
            cur = np.int64(st[s]) - KEPT if left_out else np.int64(st[s])
            st[p] = -1
            ftop = fill[cur]
            sbeg = start[cur]
            node = n_nodes
            node_b[node] = cur
            lab[p] = node
            n_nodes += 1
            area = np.int64(1)
            lmn = nolim
            stk_lv[0] = cur
            stk_node[0] = node
            sp = 1
            e = 0  # the neighbour of p to go on with
            while True:
                # a loop of constant trip count (unrolled by the compiler: twice as fast as a loop
                # from e to ne), leaving at the first lower neighbour
                d = -1
                dq = np.int64(0)
                for u in range(8):
                    if u < e:
                        continue
                    if u >= ne:
                        break
                    nb = p + offs[u]
                    qn = np.int64(st[nb])
                    if left_out:
                        if qn < KEPT:  # seen (< 0), or left out of the flood (its level)
                            if qn >= 0:
                                lmn = min(lmn, qn)
                            continue
                        qn -= KEPT
                    elif qn < 0:  # seen
                        continue
                    st[nb] = -1
                    if qn == cur:  # queue it
                        bucket[ftop] = nb
                        ftop += 1
                        continue
                    if qn > cur:  # queue it
                        slot = fill[qn]
                        bucket[slot] = nb
                        fill[qn] = slot + 1
                        if slot == start[qn]:
                            summ = _map_set(occ, mid, summ, qn, deep)
                        continue
                    d = u
                    dq = qn
                    break
                if d >= 0:
                    # a lower neighbour: push p back (if it has neighbours left), descend
                    if d + 1 < ne:
                        st[p] = -2 - d
                        bucket[ftop] = p
                        ftop += 1
                    fill[cur] = ftop
                    if ftop > sbeg:
                        summ = _map_set(occ, mid, summ, cur, deep)
                    else:
                        summ = _map_clear(occ, mid, summ, cur, deep)
                    stk_area[sp - 1] = area
                    if left_out:
                        stk_lm[sp - 1] = lmn
                        lmn = nolim
                    p = p + offs[d]
                    cur = dq
                    ftop = fill[cur]
                    sbeg = start[cur]
                    node = n_nodes
                    node_b[node] = cur
                    lab[p] = node
                    n_nodes += 1
                    area = 1  # type: ignore[assignment]  # numba kernel: an int64 local
                    stk_lv[sp] = cur
                    stk_node[sp] = node
                    sp += 1
                    e = 0
                    continue
                # ---- p is done: pop the next pixel from the lowest non-empty bucket
                if ftop > sbeg:
                    ftop -= 1
                    p = bucket[ftop]
                    e = -1 - np.int64(st[p])  # type: ignore[assignment]  # numba kernel: an int64 local
                    if e == 0:  # first visit (else p resumes after a descent)
                        lab[p] = node
                        area += 1
                    continue
                fill[cur] = ftop
                summ = _map_clear(occ, mid, summ, cur, deep)
                stk_area[sp - 1] = area
                if left_out:
                    stk_lm[sp - 1] = lmn
                lv = _map_next(occ, mid, summ, cur, deep)
                if lv < 0:
                    break
                # rising: close the components below lv
                while True:
                    t = sp - 1
                    if sp >= 2 and stk_lv[t - 1] <= lv:  # becomes part of the next one
                        n_fin = _close(stk_node[t], stk_area[t], stk_node[t - 1], (min(stk_lv[t - 1], stk_lm[t]) if left_out else stk_lv[t - 1]), K,
                                       max_area, node_b, node_size, node_parent, tagged, fin, n_fin)
                        stk_area[t - 1] += stk_area[t]
                        if left_out:
                            stk_lm[t - 1] = min(stk_lm[t - 1], stk_lm[t])
                        sp -= 1
                        if stk_lv[t - 1] == lv:
                            break
                    else:  # becomes part of a new component at lv
                        n_fin = _close(stk_node[t], stk_area[t], n_nodes, (min(lv, stk_lm[t]) if left_out else lv), K, max_area,
                                       node_b, node_size, node_parent, tagged, fin, n_fin)
                        stk_lv[t] = lv
                        stk_node[t] = n_nodes
                        node_b[n_nodes] = lv
                        n_nodes += 1
                        break
                cur = lv
                node = stk_node[sp - 1]
                area = stk_area[sp - 1]
                if left_out:
                    lmn = stk_lm[sp - 1]
                sbeg = start[cur]
                ftop = fill[cur] - 1
                p = bucket[ftop]
                e = -1 - np.int64(st[p])  # type: ignore[assignment]  # numba kernel: an int64 local
                if e == 0:
                    lab[p] = node
                    area += 1
            # ---- the region is flooded: each component left becomes part of the next one, and the
            # last one (the whole region) lives to the end
            while sp > 1:
                t = sp - 1
                n_fin = _close(stk_node[t], stk_area[t], stk_node[t - 1], (min(stk_lv[t - 1], stk_lm[t]) if left_out else stk_lv[t - 1]), K,
                               max_area, node_b, node_size, node_parent, tagged, fin, n_fin)
                stk_area[t - 1] += stk_area[t]
                if left_out:
                    stk_lm[t - 1] = min(stk_lm[t - 1], stk_lm[t])
                sp -= 1
            n_fin = _close(stk_node[0], stk_area[0], -1, (min(K + 2, stk_lm[0]) if left_out else K + 2), K, max_area,
                           node_b, node_size, node_parent, tagged, fin, n_fin)
        return (node_b[:n_nodes], node_size[:n_nodes], node_parent[:n_nodes], tagged[:n_nodes],
                fin[:n_fin])

    # a name of its own for each variant: numba names a compiled function (its symbol, its cache files) by its
    # module, qualified name, argument types and a per-process counter; the variants share the other three, so
    # two compiled in different processes (then loaded from the caches) could get one symbol and the wrong one
    # be called (in bench_zcut.py --alternate a "NULL descr" error when the previous tree's was loaded beside)
    name = "flood_core" + ("_left_out" if left_out else "") + ("_deep" if deep else "")
    flood_core.__name__ = flood_core.__qualname__ = name
    return numba.njit(cache=True, nogil=True)(flood_core)


flood_core = _flood_kernel(False)
flood_core_left_out = _flood_kernel(True)
flood_core_deep = _flood_kernel(False, True)


@numba.njit(cache=True, nogil=True)
def flood_whole(st, start, pix, W, K, top, conn8, max_area, lab):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`flood_core` (:func:`flood_core_deep` from ``SHALLOW_LEVELS`` levels on) when *every* pixel of
    the frame is in the cuts (``pix`` lists them all), without flooding the pixels of the deepest level.

    The same arguments and results, the same tree: the cut at the deepest level ``qd`` holds every pixel
    of the frame, one component (the pixel grid is connected), so the tree's one root is born at ``qd``
    with every pixel, and its children are the components of the cut at ``qd - 1``, each ending at ``qd``.
    Those are what the flood gives over the pixels above ``qd`` (the ones at ``qd`` marked seen in
    ``st``): each region's last node, closed as a root, gets the root as its parent and is tagged again
    with ``e = qd``; the root is added last in ``fin``, and ``lab`` at the pixels of ``qd`` is the root.
    The invalid pixels all stand at ``z_min``, at ``qd``: on the suspects' whole-range z-cut (every pixel in
    the cuts) 15-75 % of a frame is not flooded (docs/performance.md). Node numbers differ from
    :func:`flood_core`'s; no read-out depends on them (clusters are numbered in raster order)."""
    qd = top
    while qd > 0 and start[qd + 1] == 0:  # start: the counts per level (start[lv + 1])
        qd -= 1
    m = pix.size
    for t in range(m):
        p = pix[t]
        if st[p] == qd:
            st[p] = -1  # seen: never flooded, never queued
            lab[p] = -1
    start[qd + 1] = 0
    if top < SHALLOW_LEVELS:
        node_b, node_size, node_parent, tagged, fin = flood_core(st, start, pix, W, K, top, conn8, max_area, lab)
    else:
        node_b, node_size, node_parent, tagged, fin = flood_core_deep(st, start, pix, W, K, top, conn8, max_area,
                                                                      lab)
    n = node_b.size
    root = n
    b2 = np.empty(n + 1, np.int64)
    size2 = np.empty(n + 1, np.int64)
    parent2 = np.empty(n + 1, np.int32)
    tagged2 = np.empty(n + 1, np.bool_)
    fin2 = np.empty(n + 1, np.int32)
    end = min(K, qd - 2)
    for a in range(n):
        b2[a] = node_b[a]
        size2[a] = node_size[a]
        pa = node_parent[a]
        if pa < 0:  # a region's last node: a component of the cut at qd - 1, ending at qd
            parent2[a] = root
            tagged2[a] = max(node_b[a], 1) <= end and node_size[a] < max_area
        else:
            parent2[a] = pa
            tagged2[a] = tagged[a]
        fin2[a] = fin[a]
    b2[root] = qd
    size2[root] = m
    parent2[root] = -1
    tagged2[root] = max(qd, 1) <= K and m < max_area  # (e = K + 2: the root lives to the end)
    fin2[n] = root
    for t in range(m):
        p = pix[t]
        if lab[p] < 0:
            lab[p] = root
    return b2, size2, parent2, tagged2, fin2


@numba.njit(cache=True, nogil=True, inline="always")
def _aligned(nbytes):  # type: ignore[no-untyped-def]  # numba kernel
    """``nbytes`` rounded up to a multiple of 64 (a cache line)."""
    return (nbytes + 63) // 64 * 64


@numba.njit(cache=True, nogil=True)
def pruned_scratch(n, bound, n_gls):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`pruned_outliers`' scratch arrays, sized by the window (``n`` padded pixels; the pile's window is
    18 % of the frame) and by the ``bound`` on the pixels in the cuts, not by the frame: ``st`` (n,) int16,
    ``gl`` (n,) int32, ``pix``, ``gpar``, ``gcnt`` (bound,) int32 and ``gls`` (n_gls,) int32, all views of one
    block, each on a 64-byte boundary. One block, not five arrays: glibc raises its mmap and trim thresholds to the largest block
    freed, so that a call's scratch, freed, stays in the heap for the next call instead of going back to
    the system to be faulted in again page by page (the pile: ~690 faults a call, ~1.5 µs each, with five
    arrays; none with one block; docs/performance.md)."""
    a_pix = _aligned(4 * n)
    a_par = a_pix + _aligned(4 * bound)
    a_cnt = a_par + _aligned(4 * bound)
    a_gls = a_cnt + _aligned(4 * bound)
    a_st = a_gls + _aligned(4 * n_gls)
    block = np.empty(max(a_st + _aligned(2 * n), 1), np.uint8)
    gl = block[:4 * n].view(np.int32)
    pix = block[a_pix:a_pix + 4 * bound].view(np.int32)
    gpar = block[a_par:a_par + 4 * bound].view(np.int32)
    gcnt = block[a_cnt:a_cnt + 4 * bound].view(np.int32)
    gls = block[a_gls:a_gls + 4 * n_gls].view(np.int32)
    st = block[a_st:a_st + 2 * n].view(np.int16)
    return st, gl, pix, gpar, gcnt, gls


@numba.njit(cache=True, nogil=True)
def cuts_window(seg_max, thr, W):  # type: ignore[no-untyped-def]  # numba kernel
    """The window that holds every pixel in the cuts (``>= thr``; the invalid pixels outside them), from
    the segments' largest heights (``seg_max``, :func:`finite_range`'s; :func:`segments_in_cuts`): ``(row,
    column, height, width, segments)``, the column a multiple of SEGMENT, segments the number of row
    segments in the cuts; all 0 when none is."""
    n, r0, r1, s0, s1 = segments_in_cuts(seg_max, thr)
    if n == 0:
        return 0, 0, 0, 0, 0
    wc = s0 * SEGMENT
    return r0, wc, r1 - r0, min(s1 * SEGMENT, W) - wc, n


@numba.njit(cache=True, nogil=True)
def gentle_kept(z, seg_max, z_min, z_max, step, k_eff, top, conn8, gentle8, max_area, check, wr, wc, wh, ww, bound,  # type: ignore[no-untyped-def]  # numba kernel
                listed):
    """The pixels of the small gentle components in the window (:func:`gentle_levels`, then :func:`gentle_prune`),
    for :func:`pruned_outliers` and :func:`pruned_clusters`: (the flood's scratch ``st``, the level starts, the kept
    pixels, their labels ``gl``). ``listed``: the labels kept in the order of the pixels (``gls``) — when at most half
    the frame may be in the cuts (:func:`pruned_outliers` says why)."""
    st, gl, pix, gpar, gcnt, gls = pruned_scratch((wh + 2) * (ww + 2), bound, bound if listed else 0)
    if listed:
        m, nl, labelled = gentle_levels(z, seg_max, z_min, z_max, step, k_eff + 2, top, gentle8, max_area, check,
                                        st, pix, gl, gpar, gcnt, 0.5, wr, wc, wh, ww, gls)
        start = np.zeros(top + 2, np.int64)
        keep = gentle_prune(st, pix, m, gl, gpar, gcnt, nl, max_area, start, labelled, ww, conn8, top, gls)
    else:
        m, nl, labelled = gentle_levels(z, seg_max, z_min, z_max, step, k_eff + 2, top, gentle8, max_area, check,
                                        st, pix, gl, gpar, gcnt, 0.5, wr, wc, wh, ww)
        start = np.zeros(top + 2, np.int64)
        keep = gentle_prune(st, pix, m, gl, gpar, gcnt, nl, max_area, start, labelled, ww, conn8, top)
    return st, start, pix[:keep], gl


@numba.njit(cache=True, nogil=True)
def pruned_outliers(z, seg_max, z_min, z_max, step, k_eff, top, conn8, gentle8, max_area, check, minimum, out):  # type: ignore[no-untyped-def]  # numba kernel
    """The outlier mask of the flood over the pixels of the small gentle components only, into ``out``
    ((H * W,) bool, zeroed), in one call: the window of the pixels in the cuts (:func:`cuts_window`), the
    scratch (:func:`pruned_scratch`), :func:`gentle_levels` (gentle components 8-connected if ``gentle8``,
    else 4-connected), :func:`gentle_prune`, :func:`flood_core_left_out` and :func:`pruned_outlier_mask`,
    as :func:`zcut.cuts._pruned_outliers` called them one by one before (the same arrays, the same order:
    the same result; ~0.25 ms of the pile's 3 fewer, docs/performance.md). False when fewer than
    ``minimum`` pixels may lie in the cuts (counted by row segments: nothing written). ``k_eff`` and
    ``top``: :func:`zcut.cuts._levels`'; ``top`` below ``SHALLOW_LEVELS``, the padded frame below
    2**31 pixels and ``max_area`` at most the frame's pixels (the caller checks them)."""
    H, W = z.shape
    thr = z_max - top * step
    wr, wc, wh, ww = 0, 0, H, W  # the window of the pixels in the cuts
    bound = H * W  # ... and their number, at most
    some = z_min < thr  # (invalid pixels stand at z_min: outside the cuts, the segments may be skipped)
    if some:
        wr, wc, wh, ww, n_read = cuts_window(seg_max, thr, W)
        bound = n_read * SEGMENT
        if bound < minimum:
            return False  # too few pixels in the cuts for the labelling to pay
        bound = min(bound, wh * ww)
    # the labels in the order of pix (gls: gentle_prune reads them in order, not gathered from gl) when at most
    # half the frame may be in the cuts; with more, pix is close to the raster and gl is read nearly in order
    # anyway, and a frame-sized gls makes the block one that glibc maps anew at every call (page faults: the
    # dense frame 34 -> 48 ms); under half, the block stays below the largest one before gls (docs/performance.md)
    listed = some and 2 * bound <= H * W
    st, start, kept, gl = gentle_kept(z, seg_max, z_min, z_max, step, k_eff, top, conn8, gentle8, max_area, check,
                                      wr, wc, wh, ww, bound, listed)
    # the labels are read; the flood writes its node image over them at the kept pixels
    _, _, node_parent, tagged, fin = flood_core_left_out(st, start, kept, ww, k_eff, top, conn8, max_area, gl)
    pruned_outlier_mask(z, gl, kept, fin, node_parent, tagged, out, wr, wc, ww)
    return True


@numba.njit(cache=True, nogil=True)
def pruned_cluster_labels(z, lab, pix, fin, node_parent, tagged, labels, wr=0, wc=0, ww=-1):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`listed_cluster_labels` over the pixels kept by :func:`gentle_prune` (``labels`` (H * W,) int32,
    zeroed; the flat index and the validity of a pixel found from its padded index in the window as
    :func:`pruned_outlier_mask` finds them): the same numbers (raster order of first valid pixel: ``pix`` is in
    raster order); returns the clusters' nodes and their valid pixel counts."""
    outer = _outermost(fin, node_parent, tagged)
    n_nodes = tagged.size
    number = np.zeros(n_nodes, np.int64)
    tops = np.empty(n_nodes, np.int64)
    areas = np.zeros(n_nodes, np.int64)
    ZW = z.shape[1]
    W = ZW if ww < 0 else ww
    Wp = W + 2
    inv = 1.0 / Wp
    zf = z.reshape(-1)
    n = 0
    for t in range(pix.size):
        p = pix[t]
        x = outer[lab[p]]
        if x < 0:
            continue
        rp = np.int64((p + 0.5) * inv)  # (as pruned_outlier_mask)
        o = (wr + rp - 1) * ZW + wc + (p - rp * Wp - 1)
        if not np.isfinite(zf[o]):
            continue
        n = _number_cluster(x, o, n, number, tops, labels, areas)
    return tops[:n], areas[:n]


@numba.njit(cache=True, nogil=True, inline="always")
def _squeeze_levels(zf, row, c0, c1, z_max, step, inv_step, q_min, buf):  # type: ignore[no-untyped-def]  # numba kernel
    """``buf[j]`` for the pixels ``zf[row + c0 + j]``, j < c1 - c0: the level :func:`qlevel` ``(zt, z_max, step,
    q_min + 1)`` of a finite height, ``q_min + 1`` where not finite. Without a branch, so LLVM vectorises it, as
    :func:`_segment_levels`: the guess clamped to [0, q_min] and the exact comparisons with the cuts k - 1, k and
    k + 1; where they do not settle a finite height, the segment is levelled again by :func:`_qlevel_guess`."""
    gmax = np.float64(q_min)
    none = q_min + 1
    bad = False
    for j in range(c1 - c0):
        v = zf[np.uint64(row + c0 + j)]  # (an unsigned index: no wrap-around test)
        fin = (v - v) == 0.0
        g = (z_max - v) * inv_step
        g = g if g < gmax else gmax
        g = g if g > 0.0 else 0.0  # (NaN too)
        k = np.int64(g)
        in0 = v >= z_max - k * step
        inm = v >= z_max - (k - 1) * step
        inp = v >= z_max - (k + 1) * step
        ok = (in0 & ((k == 0) | (not inm))) | ((not in0) & inp)
        buf[np.uint64(j)] = (k + (not in0)) if fin else none
        bad |= fin & (not ok)
    if bad:
        for j in range(c1 - c0):
            v = zf[row + c0 + j]
            buf[j] = _qlevel_guess(v, z_max, step, inv_step, none) if np.isfinite(v) else none


@numba.njit(cache=True, nogil=True)
def squeezed_heights(z, seg_max, z_max, step, q_min, out, seg_out):  # type: ignore[no-untyped-def]  # numba kernel
    """The heights of a cut that holds every pixel with its bands of empty levels squeezed, for
    :func:`zcut.cuts.cluster_labels_of`: each finite pixel's level ``q`` (:func:`qlevel` ``(zt, z_max, step, q_min
    + 1)``, at most ``q_min``, the lowest height's) becomes ``map[q]``, where ``map`` keeps 0 and 1 and, between
    consecutive levels of S = {0, 1} ∪ {the levels some pixel is at}, counts a gap of g levels as min(g, 2);
    ``out`` = -map[q] (step 1.0 from a top of 0.0: :func:`qlevel` gives exactly ``map[q]`` there), NaN where ``z``
    is not finite. ``seg_max`` is :func:`finite_range`'s of ``z``; ``seg_out`` (its shape) gets the same of
    ``out`` (-inf: no finite height; else -map[the level of the segment's largest height], ``map`` and
    :func:`qlevel` being monotone), so that ``out``'s range is known without a pass over it: max 0.0 (the top
    pixel's level is 0), min -map[q_min]. Returns (``map`` ((q_min + 1,) int64, -1 off S), its inverse
    ((map[q_min] + 1,) int64, -1 off map(S))).

    One pass over ``z``, levelling a row segment of ``SEGMENT`` pixels at a time as vectors
    (:func:`_squeeze_levels`), marks the occupied levels and keeps each pixel's level (uint16: ``q_min`` < 2**16 -
    1, which ``MAX_STAGE_LEVELS`` bounds); a second over those writes ``out`` from a table of ``map``'s heights
    (~1 ms a 1920 x 1200 frame less than levelling ``z`` again, docs/performance.md).

    Why the clusters are the same: empty levels add no pixel, so the sequence of distinct cuts, the tree's
    nodes as pixel sets and their order are the same, a node's birth b and end e (levels in S) becoming map[b],
    map[e]; with every pixel in the cuts a node is tagged iff max(b, 1) <= e - 2 (and its size is below
    max_area: the same sets), and e - max(b, 1), a sum of gaps each >= 1, is >= 2 iff the sum of their
    min(g, 2) is (map keeps 1, so max(map[b], 1) = map[max(b, 1)])."""
    H, W = z.shape
    inv_step = 1.0 / step
    occ = np.zeros(q_min + 2, np.bool_)
    buf = np.empty(SEGMENT, np.int64)
    zf = z.reshape(-1)
    of = out.reshape(-1)
    lv = np.empty(zf.size, np.uint16)
    for r in range(H):  # the levels and the occupied ones (q_min + 1: not finite)
        for c0 in range(0, W, SEGMENT):
            c1 = min(c0 + SEGMENT, W)
            _squeeze_levels(zf, r * W, c0, c1, z_max, step, inv_step, q_min, buf)
            for j in range(c1 - c0):
                b = buf[np.uint64(j)]
                lv[np.uint64(r * W + c0 + j)] = np.uint16(b)
                occ[b] = True
    occ[0] = True
    if q_min >= 1:
        occ[1] = True
    fwd = np.full(q_min + 1, -1, np.int64)
    last = 0
    fwd[0] = 0
    m = 0
    for q in range(1, q_min + 1):
        if occ[q]:
            m += min(q - last, 2)
            fwd[q] = m
            last = q
    inv = np.full(m + 1, -1, np.int64)
    for q in range(q_min + 1):
        if fwd[q] >= 0:
            inv[fwd[q]] = q
    tab = np.empty(q_min + 2)  # the squeezed height of each level, NaN for "not finite"
    for q in range(q_min + 1):
        tab[q] = 0.0 - float(fwd[q])
    tab[q_min + 1] = np.nan
    for p in range(zf.size):
        of[np.uint64(p)] = tab[lv[np.uint64(p)]]
    for r in range(seg_max.shape[0]):
        for s in range(seg_max.shape[1]):
            v = seg_max[r, s]
            seg_out[r, s] = tab[_qlevel_guess(v, z_max, step, inv_step, q_min + 1)] if np.isfinite(v) else -np.inf
    return fwd, inv


@numba.njit(cache=True, nogil=True)
def pruned_clusters(z, seg_max, z_min, z_max, step, k_eff, top, conn8, gentle8, max_area, check, minimum, labels):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`pruned_outliers` with :func:`pruned_cluster_labels` as its read-out: the cluster labels of
    :func:`zcut.cuts.find_clusters` into ``labels`` ((H * W,) int32, zeroed), from the flood over the pixels of
    the small gentle components only (the tagged nodes, as pixel sets, are the whole tree's: :func:`gentle_prune`;
    so are the outermost ones, and their numbers, by their first valid pixel in raster order). Returns (applied,
    the clusters' areas, their levels ``max(b, 1)``); not applied: nothing written (as :func:`pruned_outliers`)."""
    H, W = z.shape
    empty = np.zeros(0, np.int64)
    thr = z_max - top * step
    wr, wc, wh, ww = 0, 0, H, W
    bound = H * W
    some = z_min < thr
    if some:
        wr, wc, wh, ww, n_read = cuts_window(seg_max, thr, W)
        bound = n_read * SEGMENT
        if bound < minimum:
            return False, empty, empty
        bound = min(bound, wh * ww)
    listed = some and 2 * bound <= H * W
    st, start, kept, gl = gentle_kept(z, seg_max, z_min, z_max, step, k_eff, top, conn8, gentle8, max_area, check,
                                      wr, wc, wh, ww, bound, listed)
    node_b, _, node_parent, tagged, fin = flood_core_left_out(st, start, kept, ww, k_eff, top, conn8, max_area, gl)
    tops, areas = pruned_cluster_labels(z, gl, kept, fin, node_parent, tagged, labels, wr, wc, ww)
    levels = np.empty(tops.size, np.int64)
    for i in range(tops.size):
        levels[i] = max(node_b[tops[i]], 1)
    return True, areas, levels


@numba.njit(cache=True, nogil=True)
def retag(node_b, node_size, node_parent, K, max_area, tagged):  # type: ignore[no-untyped-def]  # numba kernel
    """The tags of :func:`_close` for another ``max_area`` on the same tree (``tagged`` written): a node
    ends at its parent's birth level (``K + 2``: a root), ``K`` the tree's (``k_eff``). The tree itself
    (nodes, sizes, parents, closing order) does not depend on ``max_area``."""
    for a in range(node_b.size):
        pa = node_parent[a]
        e = node_b[pa] if pa >= 0 else K + 2
        tagged[a] = max(node_b[a], 1) <= min(K, e - 2) and node_size[a] < max_area


@numba.njit(cache=True)
def node_image(order, first, n):  # type: ignore[no-untyped-def]  # numba kernel
    """Node image of the union-find kernel: first[t] is the node holding pixel order[t]."""
    lab = np.full(n, -1, np.int32)
    for t in range(order.size):
        lab[order[t]] = first[t]
    return lab


@numba.njit(cache=True)
def outlier_mask(lab, fin, node_parent, tagged, valid, out):  # type: ignore[no-untyped-def]  # numba kernel
    """out (H, W): True on the valid pixels held by a tagged node or by a node inside one."""
    flag = tagged.copy()
    for t in range(fin.size - 1, -1, -1):  # parents are closed after their children
        a = fin[t]
        pa = node_parent[a]
        if pa >= 0 and flag[pa]:
            flag[a] = True
    H, W = out.shape
    Wp = W + 2
    for r in range(H):
        base = (r + 1) * Wp + 1
        for c in range(W):
            a = lab[base + c]
            out[r, c] = a >= 0 and flag[a] and valid[r, c]


@numba.njit(cache=True)
def cluster_labels(lab, fin, node_parent, tagged, valid, labels):  # type: ignore[no-untyped-def]  # numba kernel
    """Label of the outermost tagged node over each valid pixel, numbered in raster order."""
    n_nodes = tagged.size
    outer = np.full(n_nodes, -1, np.int64)  # outermost tagged ancestor (or self), -1 none
    for t in range(fin.size - 1, -1, -1):
        a = fin[t]
        pa = node_parent[a]
        if pa >= 0 and outer[pa] >= 0:
            outer[a] = outer[pa]
        elif tagged[a]:
            outer[a] = a
    H, W = labels.shape
    Wp = W + 2
    number = np.zeros(n_nodes, np.int64)
    tops = np.empty(n_nodes, np.int64)
    n = 0
    for r in range(H):
        base = (r + 1) * Wp + 1
        for c in range(W):
            labels[r, c] = 0
            a = lab[base + c]
            if a < 0 or not valid[r, c]:
                continue
            t = outer[a]
            if t < 0:
                continue
            if number[t] == 0:
                tops[n] = t
                n += 1
                number[t] = n
            labels[r, c] = number[t]
    return tops[:n]


@numba.njit(cache=True)
def level_counts(node_b, node_parent, counts):  # type: ignore[no-untyped-def]  # numba kernel
    """counts[k - 1] = number of components of the cut at level k = 1 .. K + 1 (counts (K + 1,)):
    the nodes with b <= k < e (e = the birth of the parent; never for a root)."""
    n_k = counts.size  # K + 1
    diff = np.zeros(n_k + 2, np.int64)
    for a in range(node_b.size):
        pa = node_parent[a]
        e = node_b[pa] if pa >= 0 else n_k + 1
        diff[min(node_b[a], n_k + 1)] += 1
        diff[min(e, n_k + 1)] -= 1
    c = np.int64(0)
    for k in range(n_k + 1):
        c += diff[k]
        if k >= 1:
            counts[k - 1] = c


# --------------------------------------------------------------------------------------------
# The taggable forest: every (K, max_area) answered from one tree (zcut.cut_grid)
# --------------------------------------------------------------------------------------------


@numba.njit(cache=True)
def taggable_forest(lab, fin, node_b, node_size, node_parent, taggable, valid, node_of_pixel):  # type: ignore[no-untyped-def]  # numba kernel
    """The nodes some ``(K, max_area)`` can tag, linked to their nearest taggable ancestor.

    Parameters
    ----------
    lab : (n,) int32 ndarray
        Padded node image (the node holding each pixel at its own level, -1: none).
    fin : (n_nodes,) int32 ndarray
        Every node, each before its parent.
    node_b, node_size, node_parent : (n_nodes,) ndarray
        Birth level, size (pixels, NaN-filled ones included) and parent of each node.
    taggable : (n_nodes,) bool ndarray
        The tags of the tree built with no area limit: node ``a`` is tagged at ``K`` iff
        ``taggable[a]`` and ``max(node_b[a], 1) <= K`` (:mod:`zcut.cut_grid`).
    valid : (H, W) bool ndarray
    node_of_pixel : (H, W) int32 ndarray, written
        The lowest taggable node holding each *valid* pixel, as an index into the returned
        arrays; -1 where no taggable node holds it, and on every invalid pixel.

    Returns
    -------
    kmin : (m,) int64 ndarray
        ``max(node_b, 1)`` of the m taggable nodes: the smallest K at which each is tagged.
    size : (m,) int64 ndarray
    parent : (m,) int32 ndarray
        The nearest taggable strict ancestor (index into these arrays), -1 if none.
    has_valid : (m,) bool ndarray
        The node holds at least one valid pixel.
    """
    n_nodes = taggable.size
    compact = np.full(n_nodes, -1, np.int32)
    m = 0
    for a in range(n_nodes):
        if taggable[a]:
            compact[a] = m
            m += 1
    kmin = np.empty(m, np.int64)
    size = np.empty(m, np.int64)
    parent = np.empty(m, np.int32)
    has_valid = np.zeros(m, np.bool_)
    low = np.full(n_nodes, -1, np.int32)  # the lowest taggable node holding node a (a or above)
    for t in range(fin.size - 1, -1, -1):  # parents first
        a = fin[t]
        pa = node_parent[a]
        above = low[pa] if pa >= 0 else -1
        if taggable[a]:
            c = compact[a]
            kmin[c] = max(node_b[a], 1)
            size[c] = node_size[a]
            parent[c] = above
            low[a] = c
        else:
            low[a] = above
    H, W = node_of_pixel.shape
    Wp = W + 2
    for r in range(H):
        base = (r + 1) * Wp + 1
        for c in range(W):
            a = lab[base + c]
            x = np.int32(-1)
            if a >= 0 and valid[r, c]:
                x = low[a]
                if x >= 0:
                    has_valid[x] = True
            node_of_pixel[r, c] = x
    for t in range(fin.size):  # children first: a valid pixel is in every ancestor too
        a = fin[t]
        if taggable[a]:
            c = compact[a]
            if has_valid[c] and parent[c] >= 0:
                has_valid[parent[c]] = True
    return kmin, size, parent, has_valid


@numba.njit(cache=True)
def forest_mask(node_of_pixel, tagged, out):  # type: ignore[no-untyped-def]  # numba kernel
    """out (H, W) = the pixel's lowest taggable node is tagged (``tagged`` per forest node)."""
    H, W = out.shape
    for r in range(H):
        for c in range(W):
            x = node_of_pixel[r, c]
            out[r, c] = x >= 0 and tagged[x]


@numba.njit(cache=True)
def grid_counts(node_of_pixel, kmin, size, ks, areas, truth, scored, within, has_within, plus,  # type: ignore[no-untyped-def]  # numba kernel
                has_plus, tp, fp, n_pred):
    """Pixel counts of P = (outliers(K, A) ∩ within) ∪ plus against L = truth over S = scored, for
    every K in ``ks`` and A in ``areas`` at once.

    A valid pixel is an outlier at (K, A) iff its lowest taggable node x has
    ``kmin[x] <= K`` and ``size[x] < A`` (:mod:`zcut.cut_grid`). So the weights of the pixels
    (TP: in L and S; FP: in S, not in L; 1 for the predicted count) are summed per node, each
    node's sums go to the grid cell of the smallest K and smallest A that tag it, and a 2-D
    cumulative sum gives every grid point.

    Parameters
    ----------
    node_of_pixel : (H, W) int32 ndarray
        From :func:`taggable_forest`.
    kmin, size : (m,) int64 ndarray
        From :func:`taggable_forest`.
    ks : (n_d,) int64 ndarray, ascending
    areas : (n_a,) float64 ndarray, ascending
    truth, scored : (H, W) bool ndarray
    within, plus : (H, W) bool ndarray
        Read only when ``has_within`` / ``has_plus`` (else: every pixel / no pixel).
    tp, fp, n_pred : (n_d, n_a) int64 ndarray, written
        |P ∩ L ∩ S|, |P ∩ S ∖ L|, |P|.

    Returns
    -------
    int
        |L ∩ S| (FN = |L ∩ S| - TP).
    """
    m = kmin.size
    w_tp = np.zeros(m, np.int64)
    w_fp = np.zeros(m, np.int64)
    w_n = np.zeros(m, np.int64)
    tp0 = np.int64(0)
    fp0 = np.int64(0)
    n0 = np.int64(0)
    n_ls = np.int64(0)
    H, W = node_of_pixel.shape
    for r in range(H):
        for c in range(W):
            s = scored[r, c]
            t = truth[r, c]
            if s and t:
                n_ls += 1
            if has_plus and plus[r, c]:
                n0 += 1
                if s:
                    if t:
                        tp0 += 1
                    else:
                        fp0 += 1
                continue
            x = node_of_pixel[r, c]
            if x < 0 or (has_within and not within[r, c]):
                continue
            w_n[x] += 1
            if s:
                if t:
                    w_tp[x] += 1
                else:
                    w_fp[x] += 1
    n_d = ks.size
    n_a = areas.size
    h_tp = np.zeros((n_d + 1, n_a + 1), np.int64)  # row n_d / column n_a: tagged nowhere
    h_fp = np.zeros((n_d + 1, n_a + 1), np.int64)
    h_n = np.zeros((n_d + 1, n_a + 1), np.int64)
    for x in range(m):
        if w_n[x] == 0:
            continue
        i = np.searchsorted(ks, kmin[x])  # first K >= kmin
        j = np.searchsorted(areas, np.float64(size[x]), side="right")  # first A > size
        h_tp[i, j] += w_tp[x]
        h_fp[i, j] += w_fp[x]
        h_n[i, j] += w_n[x]
    for i in range(n_d):
        a_tp = np.int64(0)
        a_fp = np.int64(0)
        a_n = np.int64(0)
        for j in range(n_a):  # type: ignore[assignment]  # numba kernel: an int64 local
            a_tp += h_tp[i, j]
            a_fp += h_fp[i, j]
            a_n += h_n[i, j]
            tp[i, j] = a_tp + (tp[i - 1, j] if i > 0 else tp0)
            fp[i, j] = a_fp + (fp[i - 1, j] if i > 0 else fp0)
            n_pred[i, j] = a_n + (n_pred[i - 1, j] if i > 0 else n0)
    return n_ls
