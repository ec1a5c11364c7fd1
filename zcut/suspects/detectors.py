"""The detectors' names and bits, and the grid helpers every detector shares (:mod:`zcut.suspects`)."""

from __future__ import annotations

from collections.abc import Iterable

import numba
import numpy as np

from ..errors import ParameterError

#: Detector names, in the order of their bits (bit i = 1 << i) and of precedence: a pixel flagged by
#: several detectors is grouped with the first of them here.
DETECTORS = ("above_rim", "floating", "mixed", "residual_down", "residual_up", "patch")
ABOVE_RIM, FLOATING, MIXED, RESIDUAL_DOWN, RESIDUAL_UP, PATCH = (1 << i for i in range(len(DETECTORS)))

# the 8 directions (row, column) and the index of the opposite of each
_DR = (0, 0, 1, -1, 1, 1, -1, -1)
_DC = (1, -1, 0, 0, 1, -1, 1, -1)
_OPP = (1, 0, 3, 2, 7, 6, 5, 4)


def detector_bits(names: Iterable[str]) -> int:
    """The bit mask of detector ``names`` (an iterable of :data:`DETECTORS` entries)."""
    bits = 0
    for n in names:
        if n not in DETECTORS:
            raise ParameterError(f"unknown detector {n!r}; detectors: {', '.join(DETECTORS)}")
        bits |= 1 << DETECTORS.index(n)
    return bits


def detector_names(bits: int) -> tuple[str, ...]:
    """The detector names of a bit mask (the order of :data:`DETECTORS`)."""
    return tuple(n for i, n in enumerate(DETECTORS) if int(bits) >> i & 1)


def shifted(a: np.ndarray, dr: int, dc: int, fill: float) -> np.ndarray:
    """``out[p] = a[p + (dr, dc)]``, ``fill`` beyond the border."""
    H, W = a.shape
    out = np.full_like(a, fill)
    if abs(dr) < H and abs(dc) < W:
        out[max(-dr, 0):H - max(dr, 0), max(-dc, 0):W - max(dc, 0)] = \
            a[max(dr, 0):H - max(-dr, 0), max(dc, 0):W - max(-dc, 0)]
    return out


@numba.njit(cache=True)
def label_gather(values, labels, n):  # type: ignore[no-untyped-def]  # numba kernel
    """The finite ``values`` of each label 1..n gathered in their order (a counting sort by label): ``(buf,
    start, count)``, label g's values ``buf[start[g]:start[g] + count[g]]``; labels outside 1..n are left out.
    For :func:`_label_medians_kernel` and :func:`zcut.suspects.grouping._label_classes`."""
    count = np.zeros(n + 2, np.int64)
    for k in range(values.size):
        g = labels[k]
        if 0 < g <= n and np.isfinite(values[k]):
            count[g] += 1
    start = np.zeros(n + 2, np.int64)
    for g in range(1, n + 1):
        start[g + 1] = start[g] + count[g]
    buf = np.empty(start[n + 1])
    at = start.copy()
    for k in range(values.size):
        g = labels[k]
        if 0 < g <= n and np.isfinite(values[k]):
            buf[at[g]] = values[k]
            at[g] += 1
    return buf, start, count


@numba.njit(cache=True)
def _label_medians_kernel(values, labels, n, out):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`label_medians_reference` of 1-D float64 ``values`` and integer ``labels`` into ``out`` (n, NaN):
    the finite values of each label 1..n gathered in their order (a counting sort by label), then sorted
    stably (mergesort): the order ``np.lexsort((v, g))`` gives them (stable too: equal values, -0.0 and 0.0
    among them, keep their order), so the same middle values and the same mean of the two."""
    buf, start, count = label_gather(values, labels, n)
    for g in range(1, n + 1):
        c = count[g]
        if c == 0:
            continue
        seg = buf[start[g]:start[g] + c]
        lo = (c - 1) // 2
        hi = c // 2
        if c <= 2:
            a = seg[0] if c == 1 or not seg[1] < seg[0] else seg[1]
            b = seg[c - 1] if c == 1 or not seg[1] < seg[0] else seg[0]
        else:
            order = np.argsort(seg, kind="mergesort")
            a = seg[order[lo]]
            b = seg[order[hi]]
        out[g - 1] = a if lo == hi else 0.5 * (a + b)


def label_medians(values: np.ndarray, labels: np.ndarray, n: int) -> np.ndarray:
    """Median of the finite ``values`` under each label 1..n (NaN for a label with none).

    Float64 values and integer labels: one counting sort by label, then each label's values on their own
    (:func:`_label_medians_kernel`); else :func:`label_medians_reference`. The same values bit for bit."""
    v = np.asarray(values)
    g = np.asarray(labels)
    if v.dtype != np.float64 or g.dtype.kind != "i" or v.shape != g.shape:
        return label_medians_reference(values, labels, n)
    out = np.full(n, np.nan)
    _label_medians_kernel(np.ascontiguousarray(v).reshape(-1), np.ascontiguousarray(g).reshape(-1), n, out)
    return out


def label_medians_reference(values: np.ndarray, labels: np.ndarray, n: int) -> np.ndarray:
    """:func:`label_medians` with one lexsort of every finite value by (label, value)."""
    sel = (labels > 0) & np.isfinite(values)
    g = labels[sel]
    v = values[sel]
    out = np.full(n, np.nan)
    if g.size == 0:
        return out
    order = np.lexsort((v, g))
    g, v = g[order], v[order]
    ids = np.arange(1, n + 1)
    starts = np.searchsorted(g, ids, side="left")
    counts = np.searchsorted(g, ids, side="right") - starts
    has = counts > 0
    lo = starts[has] + (counts[has] - 1) // 2
    hi = starts[has] + counts[has] // 2
    out[has] = np.where(lo == hi, v[lo], 0.5 * (v[lo] + v[hi]))
    return out
