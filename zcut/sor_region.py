"""SOR's top region and its bounding box in one pass over the zone, given the threshold.

A replay's SOR judges the top of the pile (``sor.region = "top"``, docs/filters.md): the zone's pixels at or
above ``z_max - K * step``, as the z-cut computes its lowest cut (:func:`replay.pipeline.zone.sor_region`).
With the z-cut's z_max known (:meth:`replay.pipeline.zone.Zone.cut`), what is left is ``zone & (height >=
threshold)`` and the region's bounding box, which SOR runs on (:func:`replay.pipeline.zone.zone_box`): written
with NumPy, a comparison over the float64 heights, an ``&`` and two ``any`` passes over the result.
:func:`region_at_or_above` does them in one kernel pass (each row's pixels, the columns' "any" and the row's
"any" together; h/rep2's kernel of the round of 2026-12-07a). Exact: comparisons round nothing. It takes
float64 heights and a bool zone in C order (what the removal writes); other arrays go through the NumPy
expressions it replaces (a float32 height compares in float32 there, as NumPy does). No I/O.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .types import FloatImage, Mask

__all__ = ["region_at_or_above"]


@nb.njit(cache=True, nogil=True)
def _at_or_above(height, zone, threshold, out, cols):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - compiled
    # out := zone & (height >= threshold) (NaN compares False), cols[c] := any of column c, returns the first
    # and last row with a pixel set (H and -1 when none): one pass, no branch in the inner loop
    H, W = zone.shape
    first = H
    last = -1
    for r in range(H):
        seen = False
        for c in range(W):
            b = zone[r, c] & (height[r, c] >= threshold)
            out[r, c] = b
            cols[c] = cols[c] | b
            seen = seen | b
        if seen:
            first = min(first, r)
            last = r
    return first, last


def region_at_or_above(height: FloatImage, zone: Mask, threshold: float
                       ) -> tuple[Mask, tuple[slice, slice] | None]:
    """``zone & (height >= threshold)`` and the slices of its bounding box (None when it is empty).

    Parameters
    ----------
    height : (H, W) float ndarray
        NaN is never at or above a threshold.
    zone : (H, W) bool ndarray
    threshold : float

    Returns
    -------
    mask : (H, W) bool ndarray
        A new array.
    box : tuple of two slices or None
        Rows and columns of the smallest box holding every pixel of ``mask``, as
        :func:`replay.pipeline.zone.zone_box` gives them.
    """
    h, z = np.asarray(height), np.asarray(zone)
    if (h.dtype != np.float64 or z.dtype != np.bool_ or h.ndim != 2 or h.shape != z.shape
            or not (h.flags.c_contiguous and z.flags.c_contiguous)):
        with np.errstate(invalid="ignore"):
            mask = np.asarray(z & (h >= threshold))
        return mask, _box(mask)
    out = np.empty(z.shape, dtype=np.bool_)
    cols = np.zeros(z.shape[1], dtype=np.bool_)
    first, last = _at_or_above(h, z, float(threshold), out, cols)
    if last < 0:
        return out, None
    c = np.flatnonzero(cols)
    return out, (slice(int(first), int(last) + 1), slice(int(c[0]), int(c[-1]) + 1))


def _box(mask: np.ndarray) -> tuple[slice, slice] | None:
    if mask.ndim != 2:
        return None
    rows = np.flatnonzero(mask.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(mask.any(axis=0))
    return slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1)
