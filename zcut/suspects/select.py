"""Exact order statistics of large float arrays by bucket selection (the suspects' medians).

``np.partition`` (introselect) costs ~10 ns a value and several times that on data with many equal
values (a sensor's quantized depth: 0.18 CPU-s for the 4.6 M reach samples of a 1920 × 1200 frame
quantized to 1 mm). :func:`order_pair` finds the same values (the k-th and the (k+1)-th smallest, as
``np.partition`` places them) in a few linear passes: the values are bucketed by a monotone function
of their bits (the IEEE bits of a non-negative double order as integers), the buckets holding the two
ranks are kept, and so on until one value remains. A value sorts where ``np.partition`` puts it, so
the results are the same bit for bit (``tests/zcut/test_suspects_fast.py`` fuzzes it against
``np.partition``); arrays with a negative value, -0.0 or NaN are left to ``np.partition``.
"""

from __future__ import annotations

import numba
import numpy as np

_BUCKETS = 1 << 16


@numba.njit(cache=True)
def _order_pair(x, k0, k1):  # type: ignore[no-untyped-def]  # numba kernel
    """(ok, the k0-th and k1-th smallest values of x), k0 <= k1 <= k0 + 1; ok = False when x holds a
    value whose bits do not order as the value (negative, -0.0, NaN)."""
    keys = x.view(np.int64)
    kmin = np.iinfo(np.int64).max
    kmax = -1
    for k in keys:
        if k < kmin:
            kmin = k
        if k > kmax:
            kmax = k
    if kmin < 0 or kmax >= 0x7FF0000000000001:  # a sign bit set (negative, -0.0), or NaN
        return False, 0.0, 0.0
    cur = keys
    hist = np.zeros(_BUCKETS, np.int64)
    while True:
        if kmin == kmax:
            v = np.empty(1, np.int64)
            v[0] = kmin
            f = v.view(np.float64)[0]
            return True, f, f
        shift = 0
        while ((kmax - kmin) >> shift) >= _BUCKETS:
            shift += 1
        hist[:] = 0
        for k in cur:
            hist[(k - kmin) >> shift] += 1
        b0 = -1
        b1 = -1
        below = 0
        base = 0
        for b in range(_BUCKETS):
            c = hist[b]
            if b0 < 0 and below + c > k0:
                b0 = b
                base = below
            if below + c > k1:
                b1 = b
                break
            below += c
        if shift == 0:  # a bucket is one value
            v = np.empty(2, np.int64)
            v[0] = kmin + b0
            v[1] = kmin + b1
            f = v.view(np.float64)
            return True, f[0], f[1]
        lo = kmin
        if b0 < b1:  # adjacent ranks in two buckets: the largest of the first, the smallest of the second
            v = np.empty(2, np.int64)
            v[0] = -1
            v[1] = np.iinfo(np.int64).max
            for k in cur:
                b = (k - lo) >> shift
                if b == b0 and k > v[0]:
                    v[0] = k
                elif b == b1 and k < v[1]:
                    v[1] = k
            f = v.view(np.float64)
            return True, f[0], f[1]
        # both in one bucket (narrower than the values' span: fewer values each round)
        buf = np.empty(hist[b0], np.int64)
        n = 0
        nmin = np.iinfo(np.int64).max
        nmax = -1
        for k in cur:
            if (k - lo) >> shift == b0:
                buf[n] = k
                n += 1
                if k < nmin:
                    nmin = k
                if k > nmax:
                    nmax = k
        cur = buf
        kmin = nmin
        kmax = nmax
        k0 -= base
        k1 -= base


def order_pair(x: np.ndarray, k0: int, k1: int) -> tuple[float, float]:
    """The k0-th and k1-th smallest values of the 1-D float64 array ``x`` (0-based; k0 <= k1 <= k0 + 1),
    the values ``np.partition`` places there; ``x`` is not modified."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    if not 0 <= k0 <= k1 <= min(k0 + 1, x.size - 1):
        raise ValueError(f"ranks {k0}, {k1} out of order or range for {x.size} values")
    ok, a, b = _order_pair(x, k0, k1)
    if ok:
        return float(a), float(b)
    t = x.copy()
    t.partition((k0, k1))
    return float(t[k0]), float(t[k1])


# :func:`kth_of_both`: the sample (every _SAMPLE_EVERY-th value of the first array) and the window's half-width in
# the sample's ranks, _SAMPLE_SIGMAS × its rank's standard deviation (~sqrt(n) / 2 at the middle) plus a few
_SAMPLE_EVERY = 32
_SAMPLE_SIGMAS = 6.0
# below this many values, :func:`order_pair` of each array
_SAMPLE_MIN = 1 << 16


@numba.njit(cache=True)
def _window_counts(x, y, a):  # type: ignore[no-untyped-def]  # numba kernel
    """The counts of x and of y below ``a`` (x.size = y.size), and of the NaN's in either, in one pass without a
    branch (in vector lanes: a value is below the window about half the time, at random)."""
    cx = 0
    cy = 0
    nan = 0
    for k in range(x.size):
        u = x[k]
        v = y[k]
        cx += u < a
        cy += v < a
        nan += (u != u) | (v != v)
    return cx, cy, nan


@numba.njit(cache=True)
def _window_values(x, y, a, b, bx, by):  # type: ignore[no-untyped-def]  # numba kernel
    """The values of x and of y in [a, b] (0 < a <= b; no NaN in x or y), in order, into ``bx`` / ``by``; their
    counts. A value's bits, less a's, as an unsigned integer, are at most b's less a's exactly when the value is
    in the window (a value below a, -0.0 and the negatives among them, wraps around to a large one): one
    comparison a value, its branch rarely taken."""
    kx = x.view(np.int64)
    ky = y.view(np.int64)
    ends = np.empty(2)
    ends[0] = a
    ends[1] = b
    ke = ends.view(np.int64)
    ka = ke[0]
    span = np.uint64(ke[1] - ka)
    nx = 0
    ny = 0
    for k in range(x.size):
        if np.uint64(kx[k] - ka) <= span:
            bx[nx] = x[k]
            nx += 1
        if np.uint64(ky[k] - ka) <= span:
            by[ny] = y[k]
            ny += 1
    return nx, ny


@numba.njit(cache=True)
def _window_count_one(x, a):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_window_counts` of one array: its count below ``a`` and of its NaN's."""
    c = 0
    nan = 0
    for k in range(x.size):
        u = x[k]
        c += u < a
        nan += u != u
    return c, nan


@numba.njit(cache=True)
def _window_values_one(x, a, b, bx):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_window_values` of one array."""
    kx = x.view(np.int64)
    ends = np.empty(2)
    ends[0] = a
    ends[1] = b
    ke = ends.view(np.int64)
    ka = ke[0]
    span = np.uint64(ke[1] - ka)
    nx = 0
    for k in range(x.size):
        if np.uint64(kx[k] - ka) <= span:
            bx[nx] = x[k]
            nx += 1
    return nx


def _sample_window(x: np.ndarray, k0: int, k1: int) -> tuple[float, float]:
    """A window [a, b] that likely holds the k0-th to the k1-th smallest values of ``x`` (k0 <= k1): the values of
    the sample (every ``_SAMPLE_EVERY``-th value) ``_SAMPLE_SIGMAS`` standard deviations of their rank around
    them (-inf, +inf past the sample's ends)."""
    n = x.size
    sample = np.ascontiguousarray(x[::_SAMPLE_EVERY])
    ns = sample.size
    half = int(_SAMPLE_SIGMAS * 0.5 * np.sqrt(ns)) + 4
    r0 = k0 * ns // n - half
    r1 = k1 * ns // n + half
    a = order_pair(sample, r0, r0)[0] if r0 >= 0 else -np.inf
    b = order_pair(sample, r1, r1)[0] if r1 < ns else np.inf
    return a, b


def order_pair_large(x: np.ndarray, k0: int, k1: int) -> tuple[float, float]:
    """:func:`order_pair` ``(x, k0, k1)``, the same values, for large arrays: a window from a sample
    (:func:`_sample_window`), one pass counting the values below it, one gathering those in it, and
    :func:`order_pair` of these when the count places both ranks in it and it lies above zero (a value is then
    its bits); else, and below ``_SAMPLE_MIN`` values, :func:`order_pair` of the whole array."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    n = x.size
    if not 0 <= k0 <= k1 <= min(k0 + 1, n - 1):
        raise ValueError(f"ranks {k0}, {k1} out of order or range for {n} values")
    if n < _SAMPLE_MIN:
        return order_pair(x, k0, k1)
    a, b = _sample_window(x, k0, k1)
    if not a > 0.0:  # a zero of either sign may be in the window (order_pair's order of -0.0 and 0.0 is its own)
        return order_pair(x, k0, k1)
    c, nan = _window_count_one(x, a)
    if nan or c > k0:
        return order_pair(x, k0, k1)
    bx = np.empty(n)  # only the entries written are touched: few pages
    m = _window_values_one(x, a, b, bx)
    if not k1 < c + m:
        return order_pair(x, k0, k1)
    return order_pair(bx[:m], k0 - c, k1 - c)


def kth_of_both(x: np.ndarray, y: np.ndarray, kx: int, ky: int) -> tuple[float, float]:
    """``(order_pair(x, kx, kx)[0], order_pair(y, ky, ky)[0])`` of two 1-D float64 arrays of one size whose values
    lie close to each other entry by entry (the gate's brackets' lower and upper ends), the same values.

    A window [a, b] around the kx-th value is read off a sample of x (every ``_SAMPLE_EVERY``-th value); one pass
    counts the values of each array below it, a second gathers those in it, and the k-th value is the right one of
    these when the counts place it in the window: the window is then above zero, so its values are positive and
    a value is its bits, as in :func:`order_pair`. Otherwise (a window from zero or below, a NaN, a rank outside
    it), and for small arrays, :func:`order_pair` of the whole array."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    y = np.ascontiguousarray(y, dtype=np.float64)
    n = x.size
    if y.size != n:
        raise ValueError(f"x and y must have one size, got {x.size} and {y.size}")
    if not (0 <= kx < n and 0 <= ky < n):
        raise ValueError(f"ranks {kx}, {ky} out of range for {n} values")
    if n < _SAMPLE_MIN:
        return order_pair(x, kx, kx)[0], order_pair(y, ky, ky)[0]
    a, b = _sample_window(x, min(kx, ky), max(kx, ky))
    if not a > 0.0:  # a zero of either sign may be in the window (order_pair's order of -0.0 and 0.0 is its own)
        return order_pair(x, kx, kx)[0], order_pair(y, ky, ky)[0]
    cx, cy, nan = _window_counts(x, y, a)
    if nan:
        return order_pair(x, kx, kx)[0], order_pair(y, ky, ky)[0]
    nx = ny = 0
    if cx <= kx and cy <= ky:
        bx, by = np.empty(n), np.empty(n)  # only the entries written are touched: few pages
        nx, ny = _window_values(x, y, a, b, bx, by)
    if cx <= kx < cx + nx:
        vx = order_pair(bx[:nx], kx - cx, kx - cx)[0]
    else:  # pragma: no cover - the sample's window missed the rank
        vx = order_pair(x, kx, kx)[0]
    if cy <= ky < cy + ny:
        vy = order_pair(by[:ny], ky - cy, ky - cy)[0]
    else:  # pragma: no cover - the sample's window missed the rank
        vy = order_pair(y, ky, ky)[0]
    return vx, vy


def median(x: np.ndarray) -> float:
    """``np.median`` of a 1-D float64 array: the middle value, or the mean of the two middle ones as
    ``np.mean`` takes it ((a + b) / 2); NaN when empty or when any value is NaN."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    n = x.size
    if n == 0:
        return float("nan")
    h = n // 2
    k0 = h if n % 2 else h - 1
    ok, a, b = _order_pair(x, k0, h)
    if not ok:
        if np.isnan(x).any():
            return float("nan")
        t = x.copy()
        t.partition((k0, h))
        a, b = t[k0], t[h]
    if n % 2:
        return float(b)
    return float((np.float64(a) + np.float64(b)) / 2.0)


# the radix sort's digits: 11 bits (2048 buckets), six passes over the 64 bits of a key
RADIX_BITS = 11
RADIX_PASSES = 6


@numba.njit(cache=True)
def _stable_argsort_kernel(x):  # type: ignore[no-untyped-def]  # numba kernel
    """LSD radix sort of the keys (the values' bits as signed integers ordered as the floats, -0.0 made
    0): one pass counts every digit's buckets; each digit then moves the keys with their indices (read
    in order), a digit whose keys all fall in one bucket being skipped."""
    n = x.size
    keys = np.empty(n, np.int64)
    bits = x.view(np.int64)
    nb = 1 << RADIX_BITS
    mask = nb - 1
    top = 64 - RADIX_BITS * (RADIX_PASSES - 1)  # the last digit's bits, the sign's among them
    count = np.zeros((RADIX_PASSES, nb + 1), np.int64)
    for i in range(n):
        b = bits[i]
        k = b if b >= 0 else b ^ 0x7FFFFFFFFFFFFFFF  # signed integers ordered as the floats
        k = 0 if k == -1 else k  # -0.0 ties with 0.0, as in a comparison sort
        keys[i] = k
        for p in range(RADIX_PASSES - 1):
            count[p, ((k >> (RADIX_BITS * p)) & mask) + 1] += 1
        # the last digit: the sign bit flipped, negative keys first
        count[RADIX_PASSES - 1, (((k >> (RADIX_BITS * (RADIX_PASSES - 1))) & ((1 << top) - 1))
                                 ^ (1 << (top - 1))) + 1] += 1
    order = np.arange(n)
    tmp = np.empty(n, np.int64)
    tmp_keys = np.empty(n, np.int64)
    for p in range(RADIX_PASSES):
        shift = RADIX_BITS * p
        last = p == RADIX_PASSES - 1
        c = count[p]
        if n and c.max() == n:  # every key has this digit: the pass keeps the order
            continue
        for d in range(nb):
            c[d + 1] += c[d]
        for i in range(n):
            k = keys[i]
            if last:
                d = ((k >> shift) & ((1 << top) - 1)) ^ (1 << (top - 1))
            else:
                d = (k >> shift) & mask
            j = c[d]
            tmp[j] = order[i]
            tmp_keys[j] = k
            c[d] = j + 1
        order, tmp = tmp, order
        keys, tmp_keys = tmp_keys, keys
    return order


def stable_argsort(x: np.ndarray) -> np.ndarray:
    """``np.argsort(x, kind="stable")`` of a 1-D float64 array without NaN (an LSD radix sort of the
    values' bits: equal values, -0.0 and 0.0 among them, keep their order)."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    if np.isnan(x).any():
        return np.argsort(x, kind="stable")
    order: np.ndarray = _stable_argsort_kernel(x)
    return order
