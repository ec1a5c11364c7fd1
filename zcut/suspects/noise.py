"""The frame's noise, measured on the frame itself: σ̂ and the depth step as functions of height.

The thresholds of every detector (:mod:`zcut.suspects`) are taken from it: τ = max(min_residual_mm,
noise_k · σ̂(height)), the floating detector's step and clearance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike

from ..cloud import check_mask
from ..errors import InputShapeError, describe_array
from ..types import FloatImage, Mask
from .select import stable_argsort

# the noise profile: bins of at least this many second differences, at most this many bins
NOISE_MIN_SAMPLES = 2000
NOISE_MAX_BINS = 32
# ... from at most this many samples (every k-th, in raster order)
NOISE_MAX_SAMPLES = 200_000
# a bin is quantized when at least this share of its neighbour differences are exactly 0
QUANTIZED_ZERO_SHARE = 0.2
# Gaussian quantiles of |x|: median = 0.6745 σ, 75th percentile = 1.1503 σ
_MAD_SCALE = 1.482602218505602
_Q75_SCALE = 1.150349380376008


def _median3(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    median: np.ndarray = np.maximum(np.minimum(a, b), np.minimum(np.maximum(a, b), c))
    return median


def _second_differences(height: np.ndarray, judged: Mask) -> tuple[np.ndarray, np.ndarray]:
    """|centred second differences| along rows and columns at judged pixels with both neighbours on
    that axis measured, and the median height of their three pixels (a spike is placed at the
    height of the surface it sticks out of, not at its own)."""
    h = np.asarray(height, dtype=np.float64)
    vals, at = [np.zeros(0)], [np.zeros(0)]
    if h.shape[1] >= 3:
        a, b, c = h[:, :-2], h[:, 1:-1], h[:, 2:]
        e = a - 2.0 * b + c
        sel = judged[:, 1:-1] & np.isfinite(e)
        vals.append(e[sel])
        at.append(_median3(a[sel], b[sel], c[sel]))
    if h.shape[0] >= 3:
        a, b, c = h[:-2, :], h[1:-1, :], h[2:, :]
        e = a - 2.0 * b + c
        sel = judged[1:-1, :] & np.isfinite(e)
        vals.append(e[sel])
        at.append(_median3(a[sel], b[sel], c[sel]))
    return np.abs(np.concatenate(vals)), np.concatenate(at)


@numba.njit(cache=True, inline="always")
def _insert(v, n, y):  # type: ignore[no-untyped-def]  # numba kernel
    """Insert y into the sorted v[:n] after any equal values (a stable insertion); return n + 1."""
    m = n
    while m > 0 and v[m - 1] > y:
        v[m] = v[m - 1]
        m -= 1
    v[m] = y
    return n + 1


@numba.njit(cache=True)
def _local_height_kernel(h, out):  # type: ignore[no-untyped-def]  # numba kernel
    H, W = h.shape
    v = np.empty(5)
    for i in range(H):
        inner_row = 0 < i < H - 1
        for j in range(W):
            x = h[i, j]
            if not np.isfinite(x):
                out[i, j] = np.nan
                continue
            # the pixel, then its neighbours E, W, S, N (the previous code's order: a stable sort of
            # equal values keeps it); a pixel off the border has all four (no bounds checks)
            v[0] = x
            n = 1
            if inner_row and 0 < j < W - 1:
                a = h[i, j + 1]
                b = h[i, j - 1]
                c = h[i + 1, j]
                d = h[i - 1, j]
                if np.isfinite(a) and np.isfinite(b) and np.isfinite(c) and np.isfinite(d):
                    # five values: their middle one by a min / max network (one of the values, the
                    # insertion's v[2]); a zero is left to the insertion (-0.0 and 0.0 tie there)
                    e = x
                    a, b = min(a, b), max(a, b)
                    d, e = min(d, e), max(d, e)
                    a, d = min(a, d), max(a, d)
                    b, e = min(b, e), max(b, e)
                    c, d = min(c, d), max(c, d)
                    b, c = min(b, c), max(b, c)
                    c, d = min(c, d), max(c, d)
                    if c != 0.0:
                        out[i, j] = c
                        continue
                y = h[i, j + 1]
                if np.isfinite(y):
                    n = _insert(v, n, y)
                y = h[i, j - 1]
                if np.isfinite(y):
                    n = _insert(v, n, y)
                y = h[i + 1, j]
                if np.isfinite(y):
                    n = _insert(v, n, y)
                y = h[i - 1, j]
                if np.isfinite(y):
                    n = _insert(v, n, y)
            else:
                for k in range(4):
                    i1 = i + (0, 0, 1, -1)[k]
                    j1 = j + (1, -1, 0, 0)[k]
                    if 0 <= i1 < H and 0 <= j1 < W:
                        y = h[i1, j1]
                        if np.isfinite(y):
                            n = _insert(v, n, y)
            lo = v[(n - 1) // 2]
            hi = v[n // 2]
            out[i, j] = lo if n % 2 == 1 else 0.5 * (lo + hi)


def local_height(height: FloatImage, *, out: np.ndarray | None = None) -> np.ndarray:
    """The median of each pixel's height and its 4 neighbours' (measured ones only; NaN where the
    pixel is not measured): the height at which to look up the noise of a pixel, so that a spike
    gets the noise of the surface it sticks out of. ``out``: an (H, W) C-contiguous float64 array for it
    (not the heights' own; a caller's scratch), else a fresh one."""
    h = np.ascontiguousarray(height, dtype=np.float64)
    if out is None:
        out = np.empty(h.shape)
    elif out.shape != h.shape or out.dtype != np.float64 or not out.flags.c_contiguous or np.shares_memory(out, h):
        raise InputShapeError(f"out must be a C-contiguous float64 array of the heights' shape {h.shape}, apart "
                              f"from them, got {describe_array(out)}")
    _local_height_kernel(h, out)
    return out


@numba.njit(cache=True)
def _differences_kernel(h, judged, order, stride, vals, at):  # type: ignore[no-untyped-def]  # numba kernel
    """Every ``stride``-th of the |differences| of :func:`_sampled_differences` (all when ``vals`` is
    empty: then only counted); returns the count."""
    H, W = h.shape
    m = 0
    k = 0
    fill = vals.size > 0
    for axis in range(2):
        di = 1 if axis == 1 else 0
        dj = 1 - di
        for i in range(H - order * di):
            for j in range(W - order * dj):
                if order == 2:
                    if not judged[i + di, j + dj]:
                        continue
                    a = h[i, j]
                    b = h[i + di, j + dj]
                    c = h[i + 2 * di, j + 2 * dj]
                    e = a - 2.0 * b + c
                    if not np.isfinite(e):
                        continue
                    if fill and m % stride == 0:
                        vals[k] = abs(e)
                        # the median of three as numpy's minimum / maximum take it (the second on ties)
                        lo = a if a < b else b
                        hi = a if a > b else b
                        hi = hi if hi < c else c
                        at[k] = lo if lo > hi else hi
                        k += 1
                else:
                    if not judged[i, j]:
                        continue
                    d = h[i + di, j + dj] - h[i, j]
                    if not np.isfinite(d):
                        continue
                    if fill and m % stride == 0:
                        vals[k] = abs(d)
                        at[k] = h[i, j]
                        k += 1
                m += 1
    return m


def _sampled_differences(h: np.ndarray, judged: np.ndarray, order: int, most: int) -> tuple[np.ndarray, np.ndarray]:
    """Every k-th (k = the least that leaves at most ``most``) of the frame's |differences| of
    ``order`` 2 (what :func:`_second_differences` gives, its order: along rows, then columns) or 1
    (|h(q) - h(p)| for judged p, q its right then lower neighbour, and h(p)), and the heights they are
    at: what ``noise_profile`` subsampled from whole-frame arrays, without making them."""
    empty = np.zeros(0)
    total = _differences_kernel(h, judged, order, 1, empty, empty)
    if total == 0:
        return empty, empty
    stride = -(-total // most)
    n = -(-total // stride)
    vals = np.empty(n)
    at = np.empty(n)
    _differences_kernel(h, judged, order, stride, vals, at)
    return vals, at


@numba.njit(cache=True)
def _count_both(h, judged):  # type: ignore[no-untyped-def]  # numba kernel
    """The counts of :func:`_differences_kernel` of order 2 and of order 1, each per axis (rows, then
    columns), in one sweep of the frame."""
    H, W = h.shape
    c2r = 0
    c2c = 0
    c1r = 0
    c1c = 0
    for i in range(H):
        for j in range(W):
            x = h[i, j]
            if j + 2 < W and judged[i, j + 1] and np.isfinite(x - 2.0 * h[i, j + 1] + h[i, j + 2]):
                c2r += 1
            if i + 2 < H and judged[i + 1, j] and np.isfinite(x - 2.0 * h[i + 1, j] + h[i + 2, j]):
                c2c += 1
            if judged[i, j]:
                if j + 1 < W and np.isfinite(h[i, j + 1] - x):
                    c1r += 1
                if i + 1 < H and np.isfinite(h[i + 1, j] - x):
                    c1c += 1
    return c2r, c2c, c1r, c1c


@numba.njit(cache=True)
def _positions(ok, m, pos):  # type: ignore[no-untyped-def]  # numba kernel
    """``pos`` begins with the indices of the flags set among ``ok[:m]``, in order (branch-free)."""
    k = 0
    for j in range(m):
        pos[k] = j
        k += ok[j]


@numba.njit(cache=True, inline="always")
def _stream(order, x0, x1, x2, jd, n_cols, ok, pos, stride, w, k, vals, at):  # type: ignore[no-untyped-def]  # numba kernel
    """One row of one stream of :func:`_fill_both`: the differences of order ``order`` (2: x0 - 2 x1 + x2,
    judged where ``jd``; 1: x1 - x0, judged where ``jd``, ``x2`` unused) at entries 0 .. n_cols - 1 of
    the views ``x0``, ``x1``, ``x2`` (the row and its neighbours along the stream's axis). A branch-free
    pass flags the finite judged ones (``ok``) and lists their entries (``pos``, unless all are); the
    samples are every ``stride``-th of that list from the stream's offset ``w``, written at ``k`` on.
    Returns the stream's (w, k) after the row. Inlined at each of the four streams' calls, so that
    ``order`` is a constant there and each call compiles to its own loop."""
    n = 0
    for j in range(n_cols):
        if order == 2:
            f = jd[j] & np.isfinite(x0[j] - 2.0 * x1[j] + x2[j])
        else:
            f = jd[j] & np.isfinite(x1[j] - x0[j])
        ok[j] = f
        n += f
    full = n == n_cols  # every difference of the row: the list is the identity
    if not full:
        _positions(ok, n_cols, pos)
    t = w
    while t < n:
        j = t if full else pos[t]
        if order == 2:
            a = x0[j]
            b = x1[j]
            c = x2[j]
            vals[k] = abs(a - 2.0 * b + c)
            # the median of three as numpy's minimum / maximum take it (the second on ties)
            lo = a if a < b else b
            hi = a if a > b else b
            hi = hi if hi < c else c
            at[k] = lo if lo > hi else hi
        else:
            x = x0[j]
            vals[k] = abs(x1[j] - x)
            at[k] = x
        k += 1
        t += stride
    return t - n, k


@numba.njit(cache=True)
def _fill_both(h, judged, c2r, s2, v2, at2, c1r, s1, v1, at1):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_differences_kernel`'s samples of order 2 (every ``s2``-th) and of order 1 (every ``s1``-th)
    in one sweep: the m-th difference (rows first, ``c2r`` / ``c1r`` of them, then columns) is taken
    when m % stride == 0, at position m // stride. Per row, four streams (:func:`_stream`): order 2
    along the row and down the column, then order 1 likewise, each with its offset ``w`` (the
    differences left until its next sample) and its next sample's position ``k``."""
    H, W = h.shape
    pos = np.empty(W + 1, np.int64)
    ok = np.empty(W + 1, np.bool_)
    # per stream (order 2 rows, columns; order 1 rows, columns): the offset and the next sample's position
    w2r = 0
    k2r = 0
    w2c = (s2 - c2r % s2) % s2
    k2c = -(-c2r // s2)
    w1r = 0
    k1r = 0
    w1c = (s1 - c1r % s1) % s1
    k1c = -(-c1r // s1)
    for i in range(H):
        row = h[i]
        w2r, k2r = _stream(2, row, row[1:], row[2:], judged[i, 1:], W - 2, ok, pos, s2, w2r, k2r, v2, at2)
        if i + 2 < H:
            w2c, k2c = _stream(2, row, h[i + 1], h[i + 2], judged[i + 1], W, ok, pos, s2, w2c, k2c, v2, at2)
        w1r, k1r = _stream(1, row, row[1:], row, judged[i], W - 1, ok, pos, s1, w1r, k1r, v1, at1)
        if i + 1 < H:
            w1c, k1c = _stream(1, row, h[i + 1], row, judged[i], W, ok, pos, s1, w1c, k1c, v1, at1)


def _sampled_both(h: np.ndarray, judged: np.ndarray, most: int) -> tuple[np.ndarray, ...]:
    """``_sampled_differences(h, judged, 2, most)`` and ``_sampled_differences(h, judged, 1, most)`` in two
    sweeps of the frame instead of eight: (vals2, at2, vals1, at1)."""
    c2r, c2c, c1r, c1c = _count_both(h, judged)
    out = []
    strides = []
    for total in (c2r + c2c, c1r + c1c):
        stride = -(-total // most) if total else 1
        n = -(-total // stride) if total else 0
        strides.append(stride)
        out += [np.empty(n), np.empty(n)]
    _fill_both(h, judged, c2r, strides[0], out[0], out[1], c1r, strides[1], out[2], out[3])
    return tuple(out)


def _robust_sigma(a: np.ndarray) -> float:
    """max(1.4826 · median, 75th percentile / 1.1503) of |e| (equal for Gaussian noise)."""
    return float(max(_MAD_SCALE * np.median(a), np.quantile(a, 0.75) / _Q75_SCALE))


def _robust_sigma_one_partition(a: np.ndarray) -> float:
    """:func:`_robust_sigma` from one ``np.partition`` instead of the two of ``np.median`` and ``np.quantile``
    (and their checks): the same arithmetic as numpy's, the median the mean of the two middle values (one
    for an odd count) and the 75th percentile numpy's linear interpolation between the order statistics at
    ``floor(0.75 (n - 1))`` and the next (from the larger one when the fraction is 0.5 or more). An array
    whose largest value is not finite (NaN, inf: numpy's checks and NaN rules apply) goes to
    :func:`_robust_sigma`. ``a`` is not empty."""
    n = a.size
    h = n // 2
    v = n * 0.75 + (1.0 + 0.75 * (1.0 - 1.0 - 1.0)) - 1.0  # numpy's virtual index for the linear method
    below = np.floor(v)
    g = v - below
    p = min(max(int(below), 0), n - 1)
    q = min(p + 1, n - 1)
    part = np.partition(a, sorted({h - 1 if n % 2 == 0 else h, h, p, q, n - 1}))
    if not np.isfinite(part[n - 1]):
        return _robust_sigma(a)
    med = part[h] if n % 2 else (part[h - 1] + part[h]) / 2.0
    d = part[q] - part[p]
    q75 = part[q] - d * (1.0 - g) if g >= 0.5 else part[p] + d * g
    return float(max(_MAD_SCALE * med, q75 / _Q75_SCALE))


def frame_noise_mm(height: FloatImage, judged: Mask) -> float:
    """σ̂: the robust spread of the frame's second differences at the judged pixels (mm).

    The residuals of :func:`surface_residuals` are second differences ``h(p) - 2 h(p+d) + h(p+2d)``,
    so their noise is that of the frame's centred second differences along rows and columns, taken
    at every judged pixel whose two neighbours on that axis are measured. σ̂ is the larger of
    1.4826 · median|e| and the 75th percentile of |e| / 1.1503 (equal for Gaussian noise); the
    second keeps σ̂ honest on quantized depth (a sensor reporting whole millimetres has most second
    differences exactly 0, so its median is 0). 0 when no such triple exists.

    Parameters
    ----------
    height : (H, W) float ndarray
        Height (mm, larger = nearer the camera), NaN = unmeasured.
    judged : (H, W) bool ndarray

    Returns
    -------
    float
    """
    a, _ = _second_differences(height, check_mask(judged, name="judged", shape=np.shape(height)))
    return _robust_sigma(a) if a.size else 0.0


@dataclass(frozen=True, slots=True)
class NoiseProfile:
    """The frame's noise as a function of height (:func:`noise_profile`).

    Attributes
    ----------
    heights_mm : (B,) float64 ndarray
        Median height of each bin, increasing (empty: the frame had nothing to measure).
    sigma_mm : (B,) float64 ndarray
        Robust σ̂ of the second differences in each bin (:func:`frame_noise_mm`'s estimator).
    step_mm : (B,) float64 ndarray
        The depth step of each bin, 0 for continuous depth: a sensor reporting depth in steps (whole
        millimetres, or disparity levels that grow with the square of the range) gives many
        neighbours exactly equal depths; where at least 20 % of the neighbour differences in a bin
        are exactly 0, its step is the median of the others.
    """

    heights_mm: np.ndarray
    sigma_mm: np.ndarray
    step_mm: np.ndarray

    def _at(self, values: np.ndarray, height: ArrayLike) -> np.ndarray:
        h = np.asarray(height, dtype=np.float64)
        if self.heights_mm.size == 0:
            return np.zeros(h.shape)
        at: np.ndarray = np.interp(np.nan_to_num(h, nan=float(self.heights_mm[0])), self.heights_mm, values)
        return at

    def sigma_at(self, height: ArrayLike) -> np.ndarray:
        """σ̂ at each height (linear between bins, constant beyond; 0 without bins)."""
        return self._at(self.sigma_mm, height)

    def step_at(self, height: ArrayLike) -> np.ndarray:
        """The depth step at each height (as :meth:`sigma_at`)."""
        return self._at(self.step_mm, height)


def _sorted_median(s: np.ndarray) -> float:
    """``np.median`` of a non-empty sorted slice: its middle value, or the mean of the two middle ones as
    ``np.mean`` takes it ((a + b) / 2). ``np.median`` itself when a middle value is 0 (which zero
    ``np.partition`` places there is its own) or when the slice holds NaN (sorted last)."""
    n = s.size
    h = n // 2
    a = float(s[h - 1]) if n % 2 == 0 else float(s[h])
    b = float(s[h])
    if a == 0.0 or b == 0.0 or np.isnan(s[-1]):
        return float(np.median(s))
    return b if n % 2 else (a + b) / 2.0


def noise_profile(height: FloatImage, judged: Mask) -> NoiseProfile:
    """σ̂ and the depth step as functions of height, measured on the frame itself.

    A sensor's noise grows with range (a structured-light or stereo camera's depth step grows with
    the square of the distance), so one frame-wide σ̂ is too small far away and too large near. The
    second differences of :func:`frame_noise_mm` (every k-th of them, at most 200,000) are sorted by
    the median height of their three pixels and cut into ``min(32, n // 2000)`` bins (at least 1) of equal
    counts; each bin gives its median
    height, its robust σ̂, and the depth step of the neighbour differences |h(p) - h(q)| (rows and
    columns, judged p, measured q) whose height falls in the bin.
    """
    judged = np.ascontiguousarray(check_mask(judged, name="judged", shape=np.shape(height)))
    h = np.ascontiguousarray(height, dtype=np.float64)
    a, at, d1, d1_at = _sampled_both(h, judged, NOISE_MAX_SAMPLES)
    if a.size == 0:
        return NoiseProfile(np.zeros(0), np.zeros(0), np.zeros(0))
    order = stable_argsort(at)  # np.argsort(at, kind="stable")
    a, at = a[order], at[order]
    bins = int(min(NOISE_MAX_BINS, max(1, a.size // NOISE_MIN_SAMPLES)))
    edges = np.linspace(0, a.size, bins + 1).astype(np.int64)
    heights = np.array([_sorted_median(at[i:j]) for i, j in zip(edges[:-1], edges[1:])])
    sigmas = np.array([_robust_sigma_one_partition(a[i:j]) for i, j in zip(edges[:-1], edges[1:])])
    # a first difference belongs to the bin whose range of second-difference heights holds it
    upper = np.array([at[j - 1] for j in edges[1:]])
    which = np.minimum(np.searchsorted(upper, d1_at, side="left"), bins - 1)
    steps = np.zeros(bins)
    by_bin = np.argsort(which.astype(np.int8), kind="stable")  # bins < 128: a radix sort
    ends = np.searchsorted(which[by_bin], np.arange(bins + 1), side="left")
    for k in range(bins):
        v = d1[by_bin[ends[k]:ends[k + 1]]]
        nonzero = v[v > 0]
        if v.size and nonzero.size and (v.size - nonzero.size) >= QUANTIZED_ZERO_SHARE * v.size:
            steps[k] = np.median(nonzero)
    return NoiseProfile(heights, sigmas, steps)
