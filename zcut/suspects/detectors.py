"""The detectors' names and bits, and the grid helpers every detector shares (:mod:`zcut.suspects`)."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from ..errors import ParameterError

#: Detector names, in the order of their bits (bit i = 1 << i) and of precedence: a pixel flagged by
#: several detectors is grouped with the first of them here.
DETECTORS = ("above_rim", "floating", "mixed", "residual_down", "residual_up")
ABOVE_RIM, FLOATING, MIXED, RESIDUAL_DOWN, RESIDUAL_UP = (1 << i for i in range(len(DETECTORS)))

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


def label_medians(values: np.ndarray, labels: np.ndarray, n: int) -> np.ndarray:
    """Median of the finite ``values`` under each label 1..n (NaN for a label with none)."""
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
