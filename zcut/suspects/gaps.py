"""The gap of a suspect pixel to the local surface around it (mm, positive = toward the camera)."""

from __future__ import annotations

import numba
import numpy as np

from ..cloud import check_mask
from ..errors import InputShapeError, describe_array
from ..types import FloatImage, Mask

# local surface of a suspect pixel: the median of at least this many non-suspect measured pixels in
# the smallest square window (radius 1, 2, 4, ... up to GAP_MAX_RADIUS) that holds them
GAP_MIN_PIXELS = 3
GAP_MAX_RADIUS = 64


@numba.njit(cache=True)
def _gap_kernel(h, suspect, surface, min_px, max_radius, out):  # type: ignore[no-untyped-def]  # numba kernel
    H, W = h.shape
    buf = np.empty((2 * max_radius + 1) ** 2)
    for i in range(H):
        for j in range(W):
            out[i, j] = np.nan
            if not suspect[i, j] or not np.isfinite(h[i, j]):
                continue
            r = 1
            while r <= max_radius:
                m = 0
                for a in range(max(i - r, 0), min(i + r + 1, H)):
                    for b in range(max(j - r, 0), min(j + r + 1, W)):
                        if surface[a, b]:
                            buf[m] = h[a, b]
                            m += 1
                if m >= min_px:
                    s = np.sort(buf[:m])
                    med = s[m // 2] if m % 2 == 1 else 0.5 * (s[m // 2 - 1] + s[m // 2])
                    out[i, j] = h[i, j] - med
                    break
                r *= 2


def _check_gap_args(height: object, suspect: object, surface: object) -> tuple[np.ndarray, Mask, Mask]:
    h = np.asarray(height)
    if h.ndim != 2 or h.dtype.kind != "f":
        raise InputShapeError(f"height must be an (H, W) real float array, got {describe_array(h)}")
    suspect = check_mask(suspect, name="suspect", shape=h.shape)
    surface = check_mask(surface, name="surface", shape=h.shape)
    h = np.ascontiguousarray(h, dtype=np.float64)
    return h, suspect, surface & np.isfinite(h)


def local_gaps(height: FloatImage, suspect: Mask, surface: Mask) -> np.ndarray:
    """Gap (mm, positive = toward the camera) of every suspect pixel to the local surface.

    The local surface of a suspect pixel is the median height of the ``surface`` pixels (measured,
    not suspects) in the smallest square window of radius 1, 2, 4, …, 64 around it holding at
    least 3 of them; NaN where none does.

    Parameters
    ----------
    height : (H, W) float ndarray
    suspect, surface : (H, W) bool ndarray

    Returns
    -------
    (H, W) float64 ndarray
        NaN outside ``suspect``.
    """
    h, suspect, surface = _check_gap_args(height, suspect, surface)
    out = np.empty(h.shape)
    _gap_kernel(h, np.ascontiguousarray(suspect), np.ascontiguousarray(surface), GAP_MIN_PIXELS, GAP_MAX_RADIUS,
                out)
    return out


def local_gaps_reference(height: FloatImage, suspect: Mask, surface: Mask) -> np.ndarray:
    """:func:`local_gaps` as a plain loop with ``np.median`` (slow; the tests' oracle)."""
    h, suspect, surface = _check_gap_args(height, suspect, surface)
    H, W = h.shape
    out = np.full(h.shape, np.nan)
    for i, j in zip(*np.nonzero(suspect & np.isfinite(h))):
        r = 1
        while r <= GAP_MAX_RADIUS:
            win = (slice(max(i - r, 0), i + r + 1), slice(max(j - r, 0), j + r + 1))
            vals = h[win][surface[win]]
            if vals.size >= GAP_MIN_PIXELS:
                out[i, j] = h[i, j] - np.median(vals)
                break
            r *= 2
    return out
