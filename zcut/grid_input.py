"""Input handling shared by the filters of the bank (docs/filters.md, "The filter bank").

Every filter takes an organized cloud ``xyz`` of shape (H, W, 3): the camera optical frame in
metres, a pixel valid iff its three coordinates are finite. The numba kernels read it directly, in
float32 or float64 (one compiled variant each), and do every comparison in float64.
"""

from __future__ import annotations

from typing import Any

import numba as nb
import numpy as np

from .cloud import check_xyz
from .types import XYZ


def as_cloud(xyz: XYZ) -> np.ndarray:
    """``xyz`` as a C-contiguous (H, W, 3) float32 or float64 array (other float types become
    float64); raise :class:`~zcut.errors.InputShapeError` if it is not an (H, W, 3) float array."""
    a = check_xyz(xyz)
    if a.dtype != np.float32:
        a = a.astype(np.float64, copy=False)
    return np.ascontiguousarray(a)


def plain_number(value: object) -> Any:
    """A numpy scalar as the Python number it holds (so that the parameter classes, which accept
    ``int`` and ``float``, take ``np.int64(3)`` too); anything else unchanged (typed Any: the
    parameter class it goes to validates it and names it when it is not a number)."""
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    return value


@nb.njit(cache=True, nogil=True, inline="always")
def valid_at(row, c):  # type: ignore[no-untyped-def]  # numba kernel
    """All three coordinates of pixel c of a row ``a[r]`` finite (kernels index rows: much faster
    in numba). ``v * 0`` is 0 for a finite v and NaN for inf and NaN: one comparison, no branch."""
    return row[c, 0] * 0.0 + row[c, 1] * 0.0 + row[c, 2] * 0.0 == 0.0


@nb.njit(cache=True, nogil=True)
def depth_plane(a, scale):  # type: ignore[no-untyped-def]  # numba kernel
    """(H, W) float64 ``scale * z`` at the valid pixels, NaN elsewhere, and the valid mask."""
    H, W = a.shape[0], a.shape[1]
    z = np.empty((H, W))
    valid = np.empty((H, W), np.bool_)
    for r in range(H):
        row, zr, vr = a[r], z[r], valid[r]
        for c in range(W):
            ok = valid_at(row, c)
            vr[c] = ok
            zr[c] = scale * np.float64(row[c, 2]) if ok else np.nan
    return z, valid


def depth_plane_reference(xyz: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """numpy version of :func:`depth_plane` (the same float64 products)."""
    valid = np.isfinite(xyz).all(axis=2)
    with np.errstate(over="ignore"):  # a huge depth times scale: inf, as in the kernel
        z = np.where(valid, scale * xyz[..., 2].astype(np.float64), np.nan)
    return z, valid
