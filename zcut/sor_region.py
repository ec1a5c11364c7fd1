"""The region SOR judges in a replay, in two passes over the height image: its top and what lies near it.

A replay's SOR judges the top of the pile (``sor.region = "top"``, docs/filters.md): the zone's pixels at or
above ``z_max - K * step``, z_max the highest finite height of the frame, as the z-cut computes its lowest
cut (:func:`replay.pipeline.zone.sor_region`). Written with NumPy that is five passes over the float64 height
image and its masks (``isfinite``, ``any``, a masked maximum, ``>=``, ``&``) and two more for the region's
bounding box (``any`` along each axis), ~5-7 CPU ms a 1920 x 1200 frame. Here:

- :func:`finite_max`: the largest finite height in one vectorized reduction (``np.fmax.reduce`` skips NaN);
  only when that is +inf or -inf (an infinite height, or none finite) does it look again, with the masked
  maximum, so the value is the masked maximum's for every input;
- :func:`region_at_or_above`: ``zone & (height >= threshold)`` and the slices of its bounding box in one
  kernel pass (each row's pixels, the columns' "any" and the row's "any" together).

Both are exact: a maximum and comparisons round nothing. They take float64 heights and a bool zone (what the
removal writes, C order); :func:`region_at_or_above` takes other arrays through the NumPy expressions it
replaces (a float32 height compares in float32 there, as NumPy does). No I/O.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .types import FloatImage, Mask

__all__ = ["finite_max", "region_at_or_above"]


def finite_max(height: FloatImage) -> float | None:
    """The largest finite value of ``height`` (``np.max(height, where=np.isfinite(height))``), None when it has none.

    Parameters
    ----------
    height : (H, W) float ndarray
        NaN and ±inf are not finite.

    Returns
    -------
    float or None
    """
    a = np.asarray(height)
    if a.size == 0:
        return None
    top = float(np.fmax.reduce(a, axis=None))  # NaN skipped: the largest of the other values, else NaN
    if np.isfinite(top):
        return top  # no +inf (it would be the maximum), and -inf never is when a finite value exists
    if top != np.inf:  # -inf or NaN: nothing finite
        return None
    finite = np.isfinite(a)
    if not finite.any():
        return None
    return float(np.max(a, where=finite, initial=-np.inf))


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
    rows = np.flatnonzero(mask.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(mask.any(axis=0))
    return slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1)
