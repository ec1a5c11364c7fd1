"""Organized-cloud helpers: validity, camera intrinsics, height images."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InputShapeError, ParameterError, describe_array
from .types import XYZ, FloatImage, Mask


@dataclass(frozen=True, slots=True)
class Intrinsics:
    """Pinhole intrinsics in pixels (ROS CameraInfo K), for an image of ``height`` x ``width``."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        for name in ("fx", "fy"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ParameterError(f"Intrinsics.{name} must be a positive finite number, got {v!r}")
        for name in ("width", "height"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ParameterError(f"Intrinsics.{name} must be a positive integer, got {v!r}")

    @property
    def K(self) -> np.ndarray:
        """(3, 3) float64 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


def check_xyz(xyz: XYZ, *, name: str = "xyz") -> np.ndarray:
    """Return ``xyz`` as an (H, W, 3) float array or raise :class:`InputShapeError`."""
    a = np.asarray(xyz)
    if a.ndim != 3 or a.shape[2] != 3 or not np.issubdtype(a.dtype, np.floating):
        raise InputShapeError(f"{name} must be an (H, W, 3) float array, got {describe_array(a)}")
    return a


def check_mask(mask: object, *, name: str, shape: tuple[int, ...] | None = None) -> Mask:
    """Return ``mask`` as an (H, W) bool array (of ``shape`` when given) or raise
    :class:`InputShapeError` naming ``name``, the shape and the dtype it got."""
    m = np.asarray(mask)
    if m.ndim != 2 or m.dtype != np.bool_:
        raise InputShapeError(f"{name} must be an (H, W) bool array, got {describe_array(m)}")
    if shape is not None and m.shape != tuple(shape):
        raise InputShapeError(f"{name} must have shape {tuple(shape)} like the other masks, got {describe_array(m)}")
    return m


def valid_mask(xyz: XYZ) -> Mask:
    """(H, W) bool: True where all three coordinates are finite."""
    a = check_xyz(xyz)
    return np.isfinite(a).all(axis=2)


def height_mm(xyz: XYZ) -> FloatImage:
    """Height image for a top-down camera in its optical frame: ``-1000 * z`` in float64 (NaN kept)."""
    a = check_xyz(xyz)
    return -1000.0 * a[..., 2].astype(np.float64)
