"""The bin model prepared once for a replay's registration and removal.

The stages that use a :class:`~zcut.bin_model.BinModel` every frame need search structures built
from it (downsampled copies with normals for ICP, a KD-tree for the pose check, a grid of cells for
the bin-point test). :func:`prepare_bin_model` builds all of them once, for one set of stage
parameters, into a frozen :class:`PreparedBinModel` that the caller passes to the stages
(:func:`zcut.registration.register_bin` takes ``.icp``, :func:`zcut.removal.remove_table_and_bin`
``.removal``): no module-level cache, nothing shared between threads but read-only arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

from .bin_model import BinModel
from .params import RegistrationParams, RemovalParams
from .registration import IcpModel, prepare_icp_model
from .removal import RemovalIndex, prepare_removal_index

__all__ = ["PreparedBinModel", "prepare_bin_model"]


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
    return PreparedBinModel(model, prepare_icp_model(model, registration),
                            prepare_removal_index(model, removal))
