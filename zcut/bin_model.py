"""The empty-bin model: a point set in the bin's own frame (see :mod:`zcut.prepared_model` for the
search structures built from it once per replay)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InputShapeError, ParameterError, describe_array

__all__ = ["BinModel"]


@dataclass(frozen=True, slots=True)
class BinModel:
    """A bin model in its own frame.

    Attributes
    ----------
    points : (N, 3) float64 ndarray
        Metres, bin frame (the camera frame of the first empty scan: up is -z).
    normals : (N, 3) float64 ndarray or None
        Unit normals, for point-to-plane distances in the bin-point test.
    spacing_m : float
        Typical distance between neighbouring model points (the downsampling voxel).
    """

    points: np.ndarray
    normals: np.ndarray | None
    spacing_m: float

    def __post_init__(self) -> None:
        p = np.asarray(self.points)
        if p.ndim != 2 or p.shape[1] != 3 or p.dtype != np.float64:
            raise InputShapeError(f"BinModel.points must be (N, 3) float64, got {describe_array(p)}")
        if not np.isfinite(p).all():
            raise InputShapeError("BinModel.points must be finite")
        if self.normals is not None and np.shape(self.normals) != p.shape:
            raise InputShapeError(
                f"BinModel.normals must match points {p.shape}, got {describe_array(self.normals)}"
            )
        if not (np.isfinite(self.spacing_m) and self.spacing_m > 0):
            raise ParameterError(f"BinModel.spacing_m must be > 0, got {self.spacing_m!r}")
