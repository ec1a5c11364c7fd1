"""The empty-bin model, and the model prepared once for a replay's registration and removal.

A :class:`BinModel` is a point set in the bin's own frame. The stages that use it every frame need
search structures built from it (downsampled copies with normals for ICP, a KD-tree for the pose
check, a grid of cells for the bin-point test). :func:`prepare_bin_model` builds all of them once,
for one set of stage parameters, into a frozen :class:`PreparedBinModel` that the caller passes to
:func:`zcut.registration.register_bin`, :func:`zcut.registration.pose_fitness` and
:func:`zcut.removal.remove_table_and_bin`: no module-level cache, nothing shared between threads
but read-only arrays.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .errors import InputShapeError, ParameterError, describe_array

if TYPE_CHECKING:
    from .params import RegistrationParams, RemovalParams
    from .registration import IcpModel
    from .removal import RemovalIndex

__all__ = ["BinModel", "PreparedBinModel", "prepare_bin_model"]


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


@dataclass(frozen=True, slots=True)
class PreparedBinModel:
    """A bin model with the search structures of registration and removal, built once.

    Attributes
    ----------
    model : BinModel
    icp : zcut.registration.IcpModel
        Downsampled model clouds with normals, the KD-tree and the model's top and centre, for
        the parameters it was prepared with.
    removal : zcut.removal.RemovalIndex
        Cell grids of the model for the bin-point tests, for the parameters it was prepared with.
    """

    model: BinModel
    icp: IcpModel
    removal: RemovalIndex


def prepare_bin_model(model: BinModel, *, registration: RegistrationParams,
                      removal: RemovalParams) -> PreparedBinModel:
    """Build every per-model structure the registration and removal stages need.

    Parameters
    ----------
    model : BinModel
    registration : RegistrationParams
    removal : RemovalParams
        The parameters the prepared model will be used with (voxel sizes, search radii).

    Returns
    -------
    PreparedBinModel
    """
    from .registration import prepare_icp_model
    from .removal import prepare_removal_index

    return PreparedBinModel(model, prepare_icp_model(model, registration),
                            prepare_removal_index(model, removal))
