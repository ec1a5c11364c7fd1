"""Window phase of :mod:`zcut.sor`: the m nearest candidates of every pixel from an image window
around it, and the proof (camera bounds of :mod:`zcut.sor_camera`) that nothing outside the window
can be closer.

The argument is in the module docstring of :mod:`zcut.sor`. Three stages, cheapest first:

1. a 3 × 3 window for a whole row: the 8 neighbour distances sorted by a network, so any m <= 9
   is a selection, and the w = 1 bound is four plane evaluations -- straight-line code over
   chunks of columns copied into a scratch buffer, which the compiler vectorizes;
2. a 5 × 5 window for the pixels stage 1 left: the inner ring sorted, ring 2 merged into the
   smallest (4 when m <= 5, else 8: :func:`slots_for`); for the whole row (vectorized like stage 1)
   when they are many, and for the rows after such a row straight away (re-checked every 8 rows),
   else for a list of pixels;
3. one pixel at a time, the window growing until its bound covers the m-th distance found so far,
   up to ``WINDOW_MAX``; a pixel stage 2 left starts from stage 2's smallest distances and count at
   w = 2 (:func:`_grow_seeded`), the others from scratch. Once it holds m valid pixels the window
   grows by a column on each side while the strips right and left of it (U) do not cover the m-th
   distance, by a row above and below while those below and above it (V) do not
   (:func:`_grow_from`).

Every kernel here is serial and releases the GIL; :mod:`zcut.sor` runs them over row ranges on
threads.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic, overload

from .sor_camera import BLOCK, KEEP, plane_bound, plane_bound_at

WINDOW_MAX = BLOCK // 2  # the window of a pixel stays inside its row and column band
_RING2 = np.array([(dr, dc) for dr in (-2, 2) for dc in range(-2, 3)]
                  + [(dr, dc) for dr in (-1, 0, 1) for dc in (-2, 2)], dtype=np.int64)  # Chebyshev ring 2
_RING2.setflags(write=False)


# --------------------------------------------------------------------------------------------
# distances and the m smallest
# --------------------------------------------------------------------------------------------
@intrinsic
def _sqrt(typingctx, v):  # type: ignore[no-untyped-def]  # numba intrinsic
    """IEEE square root as the llvm.sqrt intrinsic (math.sqrt is a libm call, which keeps loops
    from being vectorized); both are correctly rounded, so the results are identical."""
    sig = types.float64(types.float64)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]  # numba intrinsic
        fn = builder.module.declare_intrinsic("llvm.sqrt", [ir.DoubleType()])
        return builder.call(fn, [args[0]])

    return sig, codegen


@nb.njit(cache=True, inline="always")
def d2(xq, yq, zq, xp, yp, zp):  # type: ignore[no-untyped-def]  # numba kernel
    """nanoflann's L2 metric for dim 3: ((0 + dx²) + dy²) + dz², query minus point."""
    dx = xq - xp
    dy = yq - yp
    dz = zq - zp
    return (dx * dx + dy * dy) + dz * dz


@nb.njit(cache=True, inline="always")
def insert(best, v):  # type: ignore[no-untyped-def]  # numba kernel
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
def mean_of_sorted(best, divisor):  # type: ignore[no-untyped-def]  # numba kernel
    """``std::accumulate(sqrt(dist)) / k`` in ascending order from 0.0 (Open3D's d̄)."""
    s = 0.0
    for i in range(best.shape[0]):
        s += _sqrt(best[i])  # type: ignore[call-arg]  # numba intrinsic: numba passes the typing context
    return s / divisor


@nb.njit(cache=True, inline="always")
def _ce(a, b):  # type: ignore[no-untyped-def]  # numba kernel
    return min(a, b), max(a, b)


@nb.njit(cache=True, inline="always")
def _sort8(v0, v1, v2, v3, v4, v5, v6, v7):  # type: ignore[no-untyped-def]  # numba kernel
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
def _keep8(s1, s2, s3, s4, s5, s6, s7, s8, v):  # type: ignore[no-untyped-def]  # numba kernel
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
def _pick(m, divisor, s1, s2, s3, s4, s5, s6, s7, s8):  # type: ignore[no-untyped-def]  # numba kernel
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
    sm += _sqrt(s1) if m >= 2 else 0.0  # type: ignore[call-arg]  # numba intrinsic: numba passes the typing context
    sm += _sqrt(s2) if m >= 3 else 0.0  # type: ignore[call-arg]  # numba intrinsic: numba passes the typing context
    sm += _sqrt(s3) if m >= 4 else 0.0  # type: ignore[call-arg]  # numba intrinsic: numba passes the typing context
    sm += _sqrt(s4) if m >= 5 else 0.0  # type: ignore[call-arg]  # numba intrinsic: numba passes the typing context
    sm += _sqrt(s5) if m >= 6 else 0.0  # type: ignore[call-arg]  # numba intrinsic: numba passes the typing context
    sm += _sqrt(s6) if m >= 7 else 0.0  # type: ignore[call-arg]  # numba intrinsic: numba passes the typing context
    sm += _sqrt(s7) if m >= 8 else 0.0  # type: ignore[call-arg]  # numba intrinsic: numba passes the typing context
    sm += _sqrt(s8) if m >= 9 else 0.0  # type: ignore[call-arg]  # numba intrinsic: numba passes the typing context
    return dm2, sm / divisor


# The row stages keep the S smallest neighbour distances of a pixel as a tuple of S floats: S = 4
# when m <= 5 (the paper's k = 4 in both conventions), else 8. The helpers below are specialized
# on the tuple's length at compile time, so that the 4-slot kernels carry no work for slots they
# never read (half the compare-exchanges of the 5 x 5 window, half the slots kept between passes).
SLOTS_SMALL = 4


def slots_for(m: int) -> tuple[float, ...]:
    """The empty slot tuple (all +inf) of the row stages for m: 4 slots when m <= 5, else 8."""
    return (np.inf,) * (SLOTS_SMALL if m <= SLOTS_SMALL + 1 else 8)


def _keep(s: tuple[float, ...], v: float) -> tuple[float, ...]:  # a stub: numba compiles the overload below
    """Insert v into the ascending slots s, dropping the largest, without branches."""
    raise NotImplementedError


@overload(_keep, inline="always")
def _keep_overload(s, v):  # type: ignore[no-untyped-def]  # numba typing function
    if s.count == 4:
        def keep4(s, v):  # type: ignore[no-untyped-def]  # numba kernel
            s1, s2, s3, s4 = s
            return min(s1, v), min(s2, max(s1, v)), min(s3, max(s2, v)), min(s4, max(s3, v))
        return keep4

    def keep8(s, v):  # type: ignore[no-untyped-def]  # numba kernel
        return _keep8(s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7], v)
    return keep8


def _first(s8: tuple[float, ...], like: tuple[float, ...]) -> tuple[float, ...]:  # a stub: numba compiles the overload
    """The first len(like) of the 8-tuple s8."""
    raise NotImplementedError


@overload(_first, inline="always")
def _first_overload(s8, like):  # type: ignore[no-untyped-def]  # numba typing function
    if like.count == 4:
        return lambda s8, like: (s8[0], s8[1], s8[2], s8[3])
    return lambda s8, like: s8


def _pick_slots(m: int, divisor: float, s: tuple[float, ...]) -> tuple[float, float]:  # a stub: see the overload
    """:func:`_pick` of the slots s (m <= len(s) + 1)."""
    raise NotImplementedError


@overload(_pick_slots, inline="always")
def _pick_slots_overload(m, divisor, s):  # type: ignore[no-untyped-def]  # numba typing function
    if s.count == 4:
        def pick4(m, divisor, s):  # type: ignore[no-untyped-def]  # numba kernel
            s1, s2, s3, s4 = s
            dm2 = 0.0
            dm2 = s1 if m == 2 else dm2
            dm2 = s2 if m == 3 else dm2
            dm2 = s3 if m == 4 else dm2
            dm2 = s4 if m == 5 else dm2
            sm = 0.0
            sm += _sqrt(s1) if m >= 2 else 0.0  # type: ignore[call-arg]  # numba intrinsic: numba passes the typing context
            sm += _sqrt(s2) if m >= 3 else 0.0  # type: ignore[call-arg]  # numba intrinsic: numba passes the typing context
            sm += _sqrt(s3) if m >= 4 else 0.0  # type: ignore[call-arg]  # numba intrinsic: numba passes the typing context
            sm += _sqrt(s4) if m >= 5 else 0.0  # type: ignore[call-arg]  # numba intrinsic: numba passes the typing context
            return dm2, sm / divisor
        return pick4
    return lambda m, divisor, s: _pick(m, divisor, s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7])


def _store(buf: np.ndarray, o: int, i: int, s: tuple[float, ...]) -> None:  # a stub: see the overload
    """buf[o + j * CH + i] = s[j] for every slot j."""
    raise NotImplementedError


@overload(_store, inline="always")
def _store_overload(buf, o, i, s):  # type: ignore[no-untyped-def]  # numba typing function
    if s.count == 4:
        def store4(buf, o, i, s):  # type: ignore[no-untyped-def]  # numba kernel
            buf[o + i], buf[o + CH + i], buf[o + 2 * CH + i], buf[o + 3 * CH + i] = s
        return store4

    def store8(buf, o, i, s):  # type: ignore[no-untyped-def]  # numba kernel
        buf[o + i], buf[o + CH + i], buf[o + 2 * CH + i], buf[o + 3 * CH + i] = s[0], s[1], s[2], s[3]
        buf[o + 4 * CH + i], buf[o + 5 * CH + i], buf[o + 6 * CH + i], buf[o + 7 * CH + i] = s[4], s[5], s[6], s[7]
    return store8


def _load(buf: np.ndarray, o: int, i: int, like: tuple[float, ...]) -> tuple[float, ...]:  # a stub: see the overload
    """The slots buf[o + j * CH + i], as many as ``like`` has."""
    raise NotImplementedError


@overload(_load, inline="always")
def _load_overload(buf, o, i, like):  # type: ignore[no-untyped-def]  # numba typing function
    if like.count == 4:
        return lambda buf, o, i, like: (buf[o + i], buf[o + CH + i], buf[o + 2 * CH + i], buf[o + 3 * CH + i])
    return lambda buf, o, i, like: (buf[o + i], buf[o + CH + i], buf[o + 2 * CH + i], buf[o + 3 * CH + i],
                                    buf[o + 4 * CH + i], buf[o + 5 * CH + i], buf[o + 6 * CH + i],
                                    buf[o + 7 * CH + i])


@nb.njit(cache=True, inline="always")
def _inner8(xq, yq, zq, x, y, z, r, c):  # type: ignore[no-untyped-def]  # numba kernel
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
def _count8(x, r, c):  # type: ignore[no-untyped-def]  # numba kernel
    # valid pixels among the 8 neighbours (invalid ones hold +inf)
    return (np.int64(x[r - 1, c - 1] < np.inf) + np.int64(x[r - 1, c] < np.inf)
            + np.int64(x[r - 1, c + 1] < np.inf) + np.int64(x[r, c - 1] < np.inf)
            + np.int64(x[r, c + 1] < np.inf) + np.int64(x[r + 1, c - 1] < np.inf)
            + np.int64(x[r + 1, c] < np.inf) + np.int64(x[r + 1, c + 1] < np.inf))


# --------------------------------------------------------------------------------------------
# bounds of the regions outside a window
# --------------------------------------------------------------------------------------------
@nb.njit(cache=True, inline="always")
def _strips(r, c, w, H, W, b, bc, xq, yq, zq, R, C):  # type: ignore[no-untyped-def]  # numba kernel
    # the rows of the pixel's row band right and left of the window (U), the columns of its column
    # band below and above it (V). Folded from the two halves, and bit for bit the four-term chain
    # min(min(min(min(inf, u+), u-), v+), v-) it replaces: numba's min(acc, v) is `v if v < acc
    # else acc`, so from inf a NaN bound is never taken and each chain keeps the first of its
    # smallest values (-0.0 and 0.0 included); min(su, sv) then keeps su unless sv is strictly
    # smaller, which is the chain's answer (tests/zcut/test_sor_fast.py drives NaN, -0.0, inf
    # bounds through both).
    return min(_strips_u(r, c, w, W, b, xq, yq, zq, R), _strips_v(r, c, w, H, bc, xq, yq, zq, C))


@nb.njit(cache=True, inline="always")
def _strips_u(r, c, wc, W, b, xq, yq, zq, R):  # type: ignore[no-untyped-def]  # numba kernel
    # the rows of the pixel's row band right and left of a window of half-width wc in columns
    # (the U half of _strips)
    s = np.inf
    if c + wc + 1 < W:
        s = min(s, plane_bound_at(R[b], 0, c + wc + 1, xq, yq, zq))
    if c - wc - 1 >= 0:
        s = min(s, plane_bound_at(R[b], 4, c - wc - 1, xq, yq, zq))
    return s


@nb.njit(cache=True, inline="always")
def _strips_v(r, c, wr, H, bc, xq, yq, zq, C):  # type: ignore[no-untyped-def]  # numba kernel
    # the columns of the pixel's column band below and above a window of half-width wr in rows
    # (the V half of _strips)
    s = np.inf
    if r + wr + 1 < H:
        s = min(s, plane_bound_at(C[bc], 0, r + wr + 1, xq, yq, zq))
    if r - wr - 1 >= 0:
        s = min(s, plane_bound_at(C[bc], 4, r - wr - 1, xq, yq, zq))
    return s


@nb.njit(cache=True, inline="always")
def _corners(b, bc, xq, yq, zq, Q):  # type: ignore[no-untyped-def]  # numba kernel
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
# stages 1 and 2 over whole rows: chunks of columns in a scratch buffer (vectorized)
# --------------------------------------------------------------------------------------------
# The kernels below read and write one scratch buffer at offsets fixed at compile time: the
# compiler can then prove that the stores do not alias the loads and vectorizes the loop (with
# the planes and the cloud as separate arrays it would need a run-time check per input row, and
# gives up). Layout for a chunk of CH query columns c0 .. c0 + CH - 1 and a window of half-width w:
# x, y, z of the rows r - w .. r + w at columns c0 - w .. c0 + CH - 1 + w; then the fields per
# query column: the right and left row-band planes at c ± (w + 1) (8), and for the 5 x 5 stage
# the column band's planes for the rows r ± (w + 1) and the corner floor (9 more); then the
# output. The 3 x 3 stage does not copy those 9, which are constant over a column band: its
# kernel runs over one band's columns at a time and takes them as scalars (:func:`_band_consts`).
CH = 256
_GAP = 8  # invalid columns in a row that end a chunk of the row stages


def _fields(w: int) -> int:
    """Fields per query column in the scratch buffer: 8 for the 3 x 3 stage, 17 for the 5 x 5."""
    return 8 if w == 1 else 17


def _layout(w: int) -> tuple[int, int, int, int, int, int]:
    span = CH + 2 * w                 # columns of one input row
    rows = 2 * w + 1
    ox, oy, oz = 0, rows * span, 2 * rows * span
    ot = 3 * rows * span              # _fields(w) fields of CH
    oo = ot + _fields(w) * CH         # output
    return span, ox, oy, oz, ot, oo + CH


_S1, _X1, _Y1, _Z1, _T1, _N1 = _layout(1)
_S2, _X2, _Y2, _Z2, _T2, _N2 = _layout(2)
_K2 = _N2                             # w = 2: 8 sorted slots and the count between the passes
SCRATCH = max(_N1, _N2 + 9 * CH)


@nb.njit(cache=True, inline="always")
def _chunk_plane(buf, o, xq, yq, zq):  # type: ignore[no-untyped-def]  # numba kernel
    # plane_bound of the plane at offset o of the chunk's fields (the strip bound is the smallest
    # of four, written out in the kernels: a loop or a helper for it there, keeps the column loop
    # from being vectorized)
    return max(buf[o] * xq + buf[o + CH] * yq + buf[o + 2 * CH] * zq + buf[o + 3 * CH], 0.0) * KEEP


@nb.njit(cache=True, inline="always")
def _plane_at(xq, yq, zq, p0, p1, p2, p3):  # type: ignore[no-untyped-def]  # numba kernel
    # plane_bound of the plane (p0, p1, p2, p3), its terms in the order of _chunk_plane
    return max(p0 * xq + p1 * yq + p2 * zq + p3, 0.0) * KEEP


@nb.njit(cache=True, error_model="numpy")
def _chunk_3x3(buf, n, m, divisor, use_cam, init, cb):  # type: ignore[no-untyped-def]  # numba kernel
    """Query columns 0..n-1 of ``buf`` (a view of the scratch buffer from the first of them, all in
    one column band) with a 3 x 3 window: d̄ where proven, else NaN. ``init``: the slot tuple
    (:func:`slots_for`); ``cb``: the column band's planes below and above the window and the
    corner floor (:func:`_band_consts`)."""
    pb0, pb1, pb2, pb3, pa0, pa1, pa2, pa3, fl = cb  # below, above (names not used for offsets below)
    for i in range(n):
        j = i + 1
        a0, a1, a2 = _X1 + j, _X1 + _S1 + j, _X1 + 2 * _S1 + j
        b0, b1, b2 = _Y1 + j, _Y1 + _S1 + j, _Y1 + 2 * _S1 + j
        e0, e1, e2 = _Z1 + j, _Z1 + _S1 + j, _Z1 + 2 * _S1 + j
        xq = buf[a1]
        yq = buf[b1]
        zq = buf[e1]
        sl = _first(_sort8(
            d2(xq, yq, zq, buf[a0 - 1], buf[b0 - 1], buf[e0 - 1]),
            d2(xq, yq, zq, buf[a0], buf[b0], buf[e0]),
            d2(xq, yq, zq, buf[a0 + 1], buf[b0 + 1], buf[e0 + 1]),
            d2(xq, yq, zq, buf[a1 - 1], buf[b1 - 1], buf[e1 - 1]),
            d2(xq, yq, zq, buf[a1 + 1], buf[b1 + 1], buf[e1 + 1]),
            d2(xq, yq, zq, buf[a2 - 1], buf[b2 - 1], buf[e2 - 1]),
            d2(xq, yq, zq, buf[a2], buf[b2], buf[e2]),
            d2(xq, yq, zq, buf[a2 + 1], buf[b2 + 1], buf[e2 + 1]),
        ), init)
        count = (1 + np.int64(buf[a0 - 1] < np.inf) + np.int64(buf[a0] < np.inf) + np.int64(buf[a0 + 1] < np.inf)
                 + np.int64(buf[a1 - 1] < np.inf) + np.int64(buf[a1 + 1] < np.inf)
                 + np.int64(buf[a2 - 1] < np.inf) + np.int64(buf[a2] < np.inf) + np.int64(buf[a2 + 1] < np.inf))
        dm2, mean = _pick_slots(m, divisor, sl)
        sb = min(min(_chunk_plane(buf, _T1 + i, xq, yq, zq), _chunk_plane(buf, _T1 + 4 * CH + i, xq, yq, zq)),
                 min(_plane_at(xq, yq, zq, pb0, pb1, pb2, pb3), _plane_at(xq, yq, zq, pa0, pa1, pa2, pa3)))
        proven = (dm2 == 0.0) | (use_cam & (dm2 <= sb * sb * KEEP) & (dm2 <= fl * fl * KEEP))
        ok = (xq < np.inf) & (count >= m) & proven
        buf[_T1 + 8 * CH + i] = mean if ok else np.nan


@nb.njit(cache=True, error_model="numpy")
def _chunk_5x5(buf, n, m, divisor, use_cam, init):  # type: ignore[no-untyped-def]  # numba kernel
    """Query columns 0..n-1 of the chunk with a 5 x 5 window: d̄ where proven, else NaN; the slots
    (``init``'s length, :func:`slots_for`) and the count of valid pixels stay in the buffer at _K2
    for the pixels left to the growing window.

    Three loops (the inner ring sorted, then ring 2 in two halves, with the slots and the count
    kept in the buffer between them): in one loop the compiler's dependence analysis would have
    more memory accesses than it examines, and would not vectorize it.
    """
    dy = _Y2 - _X2
    dz = _Z2 - _X2
    for i in range(n):
        j = i + 2
        r0, r1, r2, r3, r4 = _X2 + j, _X2 + _S2 + j, _X2 + 2 * _S2 + j, _X2 + 3 * _S2 + j, _X2 + 4 * _S2 + j
        xq = buf[r2]
        yq = buf[r2 + dy]
        zq = buf[r2 + dz]
        sl = _first(_sort8(
            d2(xq, yq, zq, buf[r1 - 1], buf[r1 - 1 + dy], buf[r1 - 1 + dz]),
            d2(xq, yq, zq, buf[r1], buf[r1 + dy], buf[r1 + dz]),
            d2(xq, yq, zq, buf[r1 + 1], buf[r1 + 1 + dy], buf[r1 + 1 + dz]),
            d2(xq, yq, zq, buf[r2 - 1], buf[r2 - 1 + dy], buf[r2 - 1 + dz]),
            d2(xq, yq, zq, buf[r2 + 1], buf[r2 + 1 + dy], buf[r2 + 1 + dz]),
            d2(xq, yq, zq, buf[r3 - 1], buf[r3 - 1 + dy], buf[r3 - 1 + dz]),
            d2(xq, yq, zq, buf[r3], buf[r3 + dy], buf[r3 + dz]),
            d2(xq, yq, zq, buf[r3 + 1], buf[r3 + 1 + dy], buf[r3 + 1 + dz]),
        ), init)
        count = (1 + np.int64(buf[r1 - 1] < np.inf) + np.int64(buf[r1] < np.inf) + np.int64(buf[r1 + 1] < np.inf)
                 + np.int64(buf[r2 - 1] < np.inf) + np.int64(buf[r2 + 1] < np.inf)
                 + np.int64(buf[r3 - 1] < np.inf) + np.int64(buf[r3] < np.inf) + np.int64(buf[r3 + 1] < np.inf))
        _store(buf, _K2, i, sl)
        buf[_K2 + 8 * CH + i] = np.float64(count)
    for i in range(n):
        j = i + 2
        r0, r1, r2, r3, r4 = _X2 + j, _X2 + _S2 + j, _X2 + 2 * _S2 + j, _X2 + 3 * _S2 + j, _X2 + 4 * _S2 + j
        xq = buf[r2]
        yq = buf[r2 + dy]
        zq = buf[r2 + dz]
        sl = _load(buf, _K2, i, init)
        count = np.int64(buf[_K2 + 8 * CH + i])
        sl = _keep(sl, d2(xq, yq, zq, buf[r0 - 2], buf[r0 - 2 + dy], buf[r0 - 2 + dz]))
        sl = _keep(sl, d2(xq, yq, zq, buf[r0 - 1], buf[r0 - 1 + dy], buf[r0 - 1 + dz]))
        sl = _keep(sl, d2(xq, yq, zq, buf[r0], buf[r0 + dy], buf[r0 + dz]))
        sl = _keep(sl, d2(xq, yq, zq, buf[r0 + 1], buf[r0 + 1 + dy], buf[r0 + 1 + dz]))
        sl = _keep(sl, d2(xq, yq, zq, buf[r0 + 2], buf[r0 + 2 + dy], buf[r0 + 2 + dz]))
        sl = _keep(sl, d2(xq, yq, zq, buf[r4 - 2], buf[r4 - 2 + dy], buf[r4 - 2 + dz]))
        sl = _keep(sl, d2(xq, yq, zq, buf[r4 - 1], buf[r4 - 1 + dy], buf[r4 - 1 + dz]))
        sl = _keep(sl, d2(xq, yq, zq, buf[r4], buf[r4 + dy], buf[r4 + dz]))
        count += (np.int64(buf[r0 - 2] < np.inf) + np.int64(buf[r0 - 1] < np.inf) + np.int64(buf[r0] < np.inf) + np.int64(buf[r0 + 1] < np.inf)
                  + np.int64(buf[r0 + 2] < np.inf) + np.int64(buf[r4 - 2] < np.inf) + np.int64(buf[r4 - 1] < np.inf) + np.int64(buf[r4] < np.inf))
        _store(buf, _K2, i, sl)
        buf[_K2 + 8 * CH + i] = np.float64(count)
    for i in range(n):
        j = i + 2
        r0, r1, r2, r3, r4 = _X2 + j, _X2 + _S2 + j, _X2 + 2 * _S2 + j, _X2 + 3 * _S2 + j, _X2 + 4 * _S2 + j
        xq = buf[r2]
        yq = buf[r2 + dy]
        zq = buf[r2 + dz]
        sl = _load(buf, _K2, i, init)
        count = np.int64(buf[_K2 + 8 * CH + i])
        sl = _keep(sl, d2(xq, yq, zq, buf[r4 + 1], buf[r4 + 1 + dy], buf[r4 + 1 + dz]))
        sl = _keep(sl, d2(xq, yq, zq, buf[r4 + 2], buf[r4 + 2 + dy], buf[r4 + 2 + dz]))
        sl = _keep(sl, d2(xq, yq, zq, buf[r1 - 2], buf[r1 - 2 + dy], buf[r1 - 2 + dz]))
        sl = _keep(sl, d2(xq, yq, zq, buf[r1 + 2], buf[r1 + 2 + dy], buf[r1 + 2 + dz]))
        sl = _keep(sl, d2(xq, yq, zq, buf[r2 - 2], buf[r2 - 2 + dy], buf[r2 - 2 + dz]))
        sl = _keep(sl, d2(xq, yq, zq, buf[r2 + 2], buf[r2 + 2 + dy], buf[r2 + 2 + dz]))
        sl = _keep(sl, d2(xq, yq, zq, buf[r3 - 2], buf[r3 - 2 + dy], buf[r3 - 2 + dz]))
        sl = _keep(sl, d2(xq, yq, zq, buf[r3 + 2], buf[r3 + 2 + dy], buf[r3 + 2 + dz]))
        count += (np.int64(buf[r4 + 1] < np.inf) + np.int64(buf[r4 + 2] < np.inf) + np.int64(buf[r1 - 2] < np.inf) + np.int64(buf[r1 + 2] < np.inf)
                  + np.int64(buf[r2 - 2] < np.inf) + np.int64(buf[r2 + 2] < np.inf) + np.int64(buf[r3 - 2] < np.inf) + np.int64(buf[r3 + 2] < np.inf))
        _store(buf, _K2, i, sl)
        buf[_K2 + 8 * CH + i] = np.float64(count)
        dm2, mean = _pick_slots(m, divisor, sl)
        sb = min(min(_chunk_plane(buf, _T2 + i, xq, yq, zq), _chunk_plane(buf, _T2 + 4 * CH + i, xq, yq, zq)),
                 min(_chunk_plane(buf, _T2 + 8 * CH + i, xq, yq, zq), _chunk_plane(buf, _T2 + 12 * CH + i, xq, yq, zq)))
        fl = buf[_T2 + 16 * CH + i]
        proven = (dm2 == 0.0) | (use_cam & (dm2 <= sb * sb * KEEP) & (dm2 <= fl * fl * KEEP))
        ok = (xq < np.inf) & (count >= m) & proven
        buf[_T2 + 17 * CH + i] = mean if ok else np.nan


@nb.njit(cache=True)
def _fill_chunk(buf, w, r, c0, n, x, y, z, Rb, C, floor, b, use_cam):  # type: ignore[no-untyped-def]  # numba kernel
    # the scratch buffer of a chunk (see the layout above)
    H = x.shape[0]
    span = CH + 2 * w
    rows = 2 * w + 1
    for k in range(rows):
        xr = x[r - w + k, c0 - w:c0 + n + w]
        yr = y[r - w + k, c0 - w:c0 + n + w]
        zr = z[r - w + k, c0 - w:c0 + n + w]
        o = k * span
        for j in range(n + 2 * w):
            buf[o + j] = xr[j]
        o += rows * span
        for j in range(n + 2 * w):
            buf[o + j] = yr[j]
        o += rows * span
        for j in range(n + 2 * w):
            buf[o + j] = zr[j]
    ot = 3 * rows * span
    if not use_cam:
        buf[ot:ot + (8 if w == 1 else 17) * CH] = 0.0
        return
    for f in range(4):  # row band: columns right of the window, then left of it
        right = Rb[f, c0 + w + 1:c0 + w + 1 + n]
        left = Rb[4 + f, c0 - w - 1:c0 - w - 1 + n]
        o = ot + f * CH
        for i in range(n):
            buf[o + i] = right[i]
        o = ot + (4 + f) * CH
        for i in range(n):
            buf[o + i] = left[i]
    if w == 1:
        return  # the 3 x 3 stage takes what is constant over a column band as scalars
    below = r + w + 1 < H  # column bands: rows below / above the window (a constant per band)
    above = r - w - 1 >= 0
    bc = (c0 + BLOCK // 2) // BLOCK
    i0 = 0
    while i0 < n:
        i1 = min(n, BLOCK * bc + BLOCK // 2 - c0)  # the chunk columns of band bc
        for f in range(4):
            v = C[bc, f, r + w + 1] if below else (np.inf if f == 3 else 0.0)
            buf[ot + (8 + f) * CH + i0:ot + (8 + f) * CH + i1] = v
            v = C[bc, 4 + f, r - w - 1] if above else (np.inf if f == 3 else 0.0)
            buf[ot + (12 + f) * CH + i0:ot + (12 + f) * CH + i1] = v
        buf[ot + 16 * CH + i0:ot + 16 * CH + i1] = floor[b, bc]
        i0 = i1
        bc += 1


@nb.njit(cache=True, inline="always")
def _band_consts(C, floor, b, bc, r, w, H, use_cam):  # type: ignore[no-untyped-def]  # numba kernel
    # what is constant over the columns of column band bc for row r and a window of half-width w:
    # the planes of the band's rows below and above the window (an infinite bound where there are
    # none) and the corner floor of the band cell (b, bc); zeros without camera bounds
    if not use_cam:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    rb = r + w + 1
    ra = r - w - 1
    if rb < H:
        b0, b1, b2, b3 = C[bc, 0, rb], C[bc, 1, rb], C[bc, 2, rb], C[bc, 3, rb]
    else:
        b0, b1, b2, b3 = 0.0, 0.0, 0.0, np.inf
    if ra >= 0:
        a0, a1, a2, a3 = C[bc, 4, ra], C[bc, 5, ra], C[bc, 6, ra], C[bc, 7, ra]
    else:
        a0, a1, a2, a3 = 0.0, 0.0, 0.0, np.inf
    return b0, b1, b2, b3, a0, a1, a2, a3, floor[b, bc]


@nb.njit(cache=True)
def _row_stage(buf, w, r, x, y, z, valid, first, last, m, divisor, use_cam, R, C, Q, floor, b, dbar, merge, init,  # type: ignore[no-untyped-def]  # numba kernel
               best, wmax):
    # stage 1 (w = 1: columns 2 .. W - 3) or stage 2 (w = 2: columns 3 .. W - 4, only where
    # stage 1 left NaN if merge, else all) of row r, over its valid columns first .. last: chunks
    # of at most CH columns, each starting at a valid pixel and ending before a run of more than
    # _GAP invalid ones (the columns between chunks are invalid: their dbar is left as it is).
    # Stage 2 hands the pixels it leaves straight to the growing window, from its 5 x 5 window's
    # slots (written: d̄, or minus the m-th squared distance found): stage 3 skips them.
    H, W = x.shape
    c = max(w + 1, first)
    end = min(W - w - 2, last)
    oo = 3 * (2 * w + 1) * (CH + 2 * w) + (8 if w == 1 else 17) * CH
    Rb = R[b]
    while c <= end:
        if not valid[r, c]:
            c += 1
            continue
        c0 = c
        lastv = c
        c += 1
        while c <= end and c - c0 < CH and c - lastv <= _GAP:
            lastv = c if valid[r, c] else lastv  # a select, not a branch (valid pixels at random)
            c += 1
        n = lastv - c0 + 1
        c = lastv + 1
        _fill_chunk(buf, w, r, c0, n, x, y, z, Rb, C, floor, b, use_cam)
        if w == 1:
            bc = (c0 + BLOCK // 2) // BLOCK
            i0 = 0
            while i0 < n:  # one column band at a time: its planes and floor are constants
                i1 = min(n, BLOCK * bc + BLOCK // 2 - c0)
                # (a view from the band's first column: offsets >= 0 at compile time, so no
                # wrap-around test, and the loop vectorizes)
                _chunk_3x3(buf[i0:], i1 - i0, m, divisor, use_cam, init, _band_consts(C, floor, b, bc, r, w, H, use_cam))
                i0 = i1
                bc += 1
            for i in range(n):
                dbar[r, c0 + i] = buf[oo + i]
        else:
            _chunk_5x5(buf, n, m, divisor, use_cam, init)
            for i in range(n):  # branches only where a pixel grows (valid pixels at random in sparse clouds)
                cc = c0 + i
                old = dbar[r, cc]
                keep = merge & ~np.isnan(old)
                v = buf[oo + i]
                if valid[r, cc] & np.isnan(v) & ~keep:
                    v = _grow_seeded(r, cc, best, _load(buf, _K2, i, init), np.int64(buf[_K2 + 8 * CH + i]), x, y, z,
                                     m, divisor, wmax, use_cam, R, C, Q, floor)
                dbar[r, cc] = old if keep else v


# --------------------------------------------------------------------------------------------
# stage 2: 5 x 5 for a list of pixels of a row
# --------------------------------------------------------------------------------------------
@nb.njit(cache=True, error_model="numpy")
def _list_5x5(r, cols, n, x, y, z, m, divisor, use_cam, R, C, Q, floor, b, dbar, init, best, wmax):  # type: ignore[no-untyped-def]  # numba kernel
    """The pixels (r, cols[:n]), 2 <= r < H - 2, 3 <= c < W - 3, with a 5 x 5 window and the
    w = 2 bound (inner ring sorted by the network, ring 2 merged into the slots). Writes d̄ where
    proven; the others go on to the growing window from there (d̄, or minus the m-th squared
    distance found)."""
    H, W = x.shape
    for j in range(n):
        c = cols[j]
        xq = x[r, c]
        yq = y[r, c]
        zq = z[r, c]
        sl = _first(_inner8(xq, yq, zq, x, y, z, r, c), init)
        count = 1 + _count8(x, r, c)
        for k in range(16):
            rr = r + _RING2[k, 0]
            cc = c + _RING2[k, 1]
            sl = _keep(sl, d2(xq, yq, zq, x[rr, cc], y[rr, cc], z[rr, cc]))
            count += np.int64(x[rr, cc] < np.inf)
        if count >= m:
            dm2, mean = _pick_slots(m, divisor, sl)
            proven = dm2 == 0.0
            if use_cam and not proven:
                bc = (c + BLOCK // 2) // BLOCK
                sb = _strips(r, c, 2, H, W, b, bc, xq, yq, zq, R, C)
                fl = floor[b, bc]
                proven = (dm2 <= sb * sb * KEEP) and (dm2 <= fl * fl * KEEP)
            if proven:
                dbar[r, c] = mean
                continue
        dbar[r, c] = _grow_seeded(r, c, best, sl, count, x, y, z, m, divisor, wmax, use_cam, R, C, Q, floor)


# --------------------------------------------------------------------------------------------
# stage 3: one pixel, growing window
# --------------------------------------------------------------------------------------------
@nb.njit(cache=True, inline="always")
def _scan_ring(best, r, c, w_old, w_new, H, W, x, y, z, xq, yq, zq):  # type: ignore[no-untyped-def]  # numba kernel
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
                n += np.int64(x[rr, cc] < np.inf)  # type: ignore[assignment]  # numba kernel: an int64 local
    return n


@nb.njit(cache=True, inline="always")
def _scan_row_part(best, rr, c0, c1, x, y, z, xq, yq, zq):  # type: ignore[no-untyped-def]  # numba kernel
    # pixels (rr, c0..c1) into best: their smallest distance first (a branch-free reduction the
    # compiler vectorizes), inserted one by one only if it is below the m-th found
    lo = np.inf
    for cc in range(c0, c1 + 1):
        lo = min(lo, d2(xq, yq, zq, x[rr, cc], y[rr, cc], z[rr, cc]))
    if lo < best[best.shape[0] - 1]:
        for cc in range(c0, c1 + 1):
            insert(best, d2(xq, yq, zq, x[rr, cc], y[rr, cc], z[rr, cc]))


@nb.njit(cache=True, inline="always")
def _scan_col_part(best, cc, r0, r1, x, y, z, xq, yq, zq):  # type: ignore[no-untyped-def]  # numba kernel
    # pixels (r0..r1, cc) into best, as _scan_row_part
    lo = np.inf
    for rr in range(r0, r1 + 1):
        lo = min(lo, d2(xq, yq, zq, x[rr, cc], y[rr, cc], z[rr, cc]))
    if lo < best[best.shape[0] - 1]:
        for rr in range(r0, r1 + 1):
            insert(best, d2(xq, yq, zq, x[rr, cc], y[rr, cc], z[rr, cc]))


@nb.njit(cache=True)
def _grow(r, c, best, x, y, z, m, divisor, w0, wmax, use_cam, R, C, Q, floor):  # type: ignore[no-untyped-def]  # numba kernel
    """One pixel with a growing window: its d̄ if proven, else minus the m-th smallest squared
    distance found (-inf if the largest window held fewer than m valid pixels).

    The window grows a step at a time, the bound checked after each against the m-th distance
    found so far: on steep relief the first window's m-th distance is often much larger than the
    final one (the image neighbours across a depth jump), and the window its bound would call for
    much larger than the one that proves the final distance (see :func:`_grow_from`)."""
    H, W = x.shape
    xq = x[r, c]
    yq = y[r, c]
    zq = z[r, c]
    best[0] = 0.0  # the point itself
    for i in range(1, m):
        best[i] = np.inf
    count = 1 + _scan_ring(best, r, c, 0, w0, H, W, x, y, z, xq, yq, zq)
    return _grow_from(r, c, best, count, w0, x, y, z, m, divisor, wmax, use_cam, R, C, Q, floor)


@nb.njit(cache=True)
def _grow_seeded(r, c, best, sl, count, x, y, z, m, divisor, wmax, use_cam, R, C, Q, floor):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_grow` of an interior pixel (2 <= r < H - 2, 2 <= c < W - 2) from its 5 x 5 window
    as the row stages left it: ``sl`` its smallest neighbour distances (ascending slots, at least
    m - 1 of them), ``count`` its valid pixels, the pixel itself included (the same candidates,
    hence the same state, as :func:`_grow` scanning rings 1 and 2: none is measured twice)."""
    best[0] = 0.0
    for i in range(1, m):
        best[i] = sl[i - 1]
    return _grow_from(r, c, best, count, 2, x, y, z, m, divisor, wmax, use_cam, R, C, Q, floor)


@nb.njit(cache=True)
def _grow_from(r, c, best, count, w, x, y, z, m, divisor, wmax, use_cam, R, C, Q, floor):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_grow` once the window of half-width w is scanned into ``best`` (its m smallest
    squared distances, the pixel's own 0 first) and ``count`` (its valid pixels).

    Until it holds m valid pixels the window grows ring by ring. Then it grows in rows and columns
    separately (half-widths wr, wc): the strips right and left of a window are bounded through U at
    columns c ± (wc + 1), those below and above through V at rows r ± (wr + 1) (:func:`_strips_u`,
    :func:`_strips_v`), so each half-width grows only while its own strips do not cover the m-th
    distance found so far. Lens distortion bends the rows or the columns within a band and weakens
    one of the two bounds: two short columns (or rows) a step instead of a whole ring. Every window
    with wr, wc <= ``WINDOW_MAX`` lies inside the pixel's row and column band, so the cover of the
    proof (strips, corners) holds for it as for a square one; the result never depends on the
    window, only which pixels are proven here does."""
    H, W = x.shape
    xq = x[r, c]
    yq = y[r, c]
    zq = z[r, c]
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
    su = _strips_u(r, c, w, W, b, xq, yq, zq, R)
    sv = _strips_v(r, c, w, H, bc, xq, yq, zq, C)
    if not (dm2 <= su * su * KEEP and dm2 <= sv * sv * KEEP):
        if w >= wmax:
            return -dm2
        sb = _strips(r, c, wmax, H, W, b, bc, xq, yq, zq, R, C)
        if not dm2 <= sb * sb * KEEP:
            return -dm2  # not even the largest window would do: leave it to the columns and tiles
        # the bound at wmax covers dm2, and every smaller m-th distance found on the way. The
        # window grows only in the direction whose strips do not cover dm2 yet: wc (columns) while
        # the row band's strips right and left of it (U) do not, wr (rows) while the column band's
        # strips below and above it (V) do not (lens distortion bends the rows or the columns, and
        # weakens one of the two: the window then grows by two short columns or rows a step, not
        # by a whole ring). Any (wr, wc) <= wmax is a window of the same proof (see zcut.sor).
        wr = w
        wc = w
        while True:
            grow_c = not dm2 <= su * su * KEEP
            grow_r = not dm2 <= sv * sv * KEEP
            if not (grow_c or grow_r):
                break
            if (grow_c and wc >= wmax) or (grow_r and wr >= wmax):
                return -dm2  # (not reached: the bounds at wmax cover every dm2 found on the way)
            if grow_c:
                wc += 1
                r0 = max(0, r - wr)
                r1 = min(H - 1, r + wr)
                if c - wc >= 0:
                    _scan_col_part(best, c - wc, r0, r1, x, y, z, xq, yq, zq)
                if c + wc < W:
                    _scan_col_part(best, c + wc, r0, r1, x, y, z, xq, yq, zq)
            if grow_r:
                wr += 1
                c0 = max(0, c - wc)
                c1 = min(W - 1, c + wc)
                if r - wr >= 0:
                    _scan_row_part(best, r - wr, c0, c1, x, y, z, xq, yq, zq)
                if r + wr < H:
                    _scan_row_part(best, r + wr, c0, c1, x, y, z, xq, yq, zq)
            dm2 = best[m - 1]
            if dm2 == 0.0:
                return mean_of_sorted(best, divisor)
            if grow_c:
                su = _strips_u(r, c, wc, W, b, xq, yq, zq, R)
            if grow_r:
                sv = _strips_v(r, c, wr, H, bc, xq, yq, zq, C)
    cb = floor[b, bc]
    if not dm2 <= cb * cb * KEEP:
        cb = _corners(b, bc, xq, yq, zq, Q)
    if dm2 <= cb * cb * KEEP:
        return mean_of_sorted(best, divisor)
    return -dm2


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
def window_rows(r0, r1, x, y, z, valid, span, m, divisor, w0, wmax, use_cam, R, C, Q, floor, dbar, unproven, init):  # type: ignore[no-untyped-def]  # numba kernel
    """Rows r0..r1-1 of the window phase; ``span[r]`` = the first and last valid column of row r;
    ``init`` = :func:`slots_for` (m).

    Writes into dbar (H, W): d̄ >= 0 where proven; at the other valid pixels minus the m-th
    smallest squared distance found in the window (an upper bound on the true one is its
    negative; -inf if the window held fewer than m valid pixels); anything at invalid pixels
    (those outside a row's valid runs are not written at all).
    unproven[r] = the number of the row's unproven pixels.
    """
    H, W = valid.shape
    buf = np.empty(SCRATCH)
    cols = np.empty(W, np.int64)
    best = np.empty(m)
    sparse = False  # the last row with a 3 x 3 stage left many pixels to the 5 x 5 one
    for r in range(r0, r1):
        first = span[r, 0]
        last = span[r, 1]
        if first > last:  # no valid pixel
            unproven[r] = 0
            continue
        b = (r + BLOCK // 2) // BLOCK
        lo, hi = 0, -1  # the columns the row stages decided (d̄ or NaN)
        if w0 == 1 and 0 < r < H - 1 and W >= 5:
            five = 2 <= r < H - 2 and wmax >= 2 and W >= 7
            if five and sparse and r % 8:  # straight to 5 x 5 (the same d̄ where both prove it)
                _row_stage(buf, 2, r, x, y, z, valid, first, last, m, divisor, use_cam, R, C, Q, floor, b, dbar,
                           False, init, best, wmax)
                lo, hi = 3, W - 4
            else:
                _row_stage(buf, 1, r, x, y, z, valid, first, last, m, divisor, use_cam, R, C, Q, floor, b, dbar,
                           True, init, best, wmax)
                lo, hi = 2, W - 3
                if five:  # what it left, with a 5 x 5 window
                    n = 0
                    for c in range(max(3, first), min(W - 3, last + 1)):
                        cols[n] = c
                        n += valid[r, c] & np.isnan(dbar[r, c])
                    sparse = 8 * n > last - first + 1
                    if sparse:  # many: the whole row, vectorized
                        _row_stage(buf, 2, r, x, y, z, valid, first, last, m, divisor, use_cam, R, C, Q, floor, b,
                                   dbar, True, init, best, wmax)
                    elif n:
                        _list_5x5(r, cols, n, x, y, z, m, divisor, use_cam, R, C, Q, floor, b, dbar, init, best,
                                  wmax)
        n = 0
        for c in range(first, last + 1):  # branches only where a pixel grows, as in _row_stage
            ok = valid[r, c]
            if ok & ~((lo <= c) & (c <= hi) & ~np.isnan(dbar[r, c])):
                dbar[r, c] = _grow(r, c, best, x, y, z, m, divisor, w0, wmax, use_cam, R, C, Q, floor)
            n += ok & (dbar[r, c] < 0.0)
        unproven[r] = n


@nb.njit(cache=True)
def unproven_pixels(valid, dbar, unproven):  # type: ignore[no-untyped-def]  # numba kernel
    """(rows, cols) of the pixels window_rows left unproven, row-major.

    A row with some is read in blocks of 64 columns: whether a block holds one is a vectorized
    reduction (no branch per pixel: valid pixels at random in sparse clouds would mispredict it);
    only such a block is gathered, without a branch, and the row is left once its count is found."""
    total = 0
    for r in range(unproven.shape[0]):
        total += unproven[r]
    rows = np.empty(total + 1, np.int64)  # (a gathered pixel after the last unproven one writes entry total)
    cols = np.empty(total + 1, np.int64)
    W = valid.shape[1]
    k = 0
    for r in range(unproven.shape[0]):
        if not unproven[r]:
            continue
        end = k + unproven[r]
        for c0 in range(0, W, 64):
            c1 = min(W, c0 + 64)
            hit = False
            for c in range(c0, c1):
                hit |= valid[r, c] & (dbar[r, c] < 0.0)
            if hit:
                for c in range(c0, c1):
                    rows[k] = r
                    cols[k] = c
                    k += valid[r, c] & (dbar[r, c] < 0.0)
                if k >= end:
                    break
    return rows[:total], cols[:total]
