"""The bin model prepared once for a replay's registration and removal.

The stages that use a :class:`~zcut.bin_model.BinModel` every frame need search structures built
from it (downsampled copies with normals for ICP, a KD-tree for the pose check, a grid of cells for
the bin-point test). :func:`prepare_bin_model` builds all of them once, for one set of stage
parameters, into a frozen :class:`PreparedBinModel` that the caller passes to the stages
(:func:`zcut.registration.register_bin` takes ``.icp``, :func:`zcut.removal.remove_table_and_bin`
``.removal``): no module-level cache, nothing shared between threads but read-only arrays.

:func:`prepared_arrays` and :func:`prepared_from_arrays` turn a prepared model into named arrays and
back, bit for bit (the clouds from their points and normals, the KD-trees from their own
state, not rebuilt; no Open3D: a replay whose prepared model comes from the cache never imports it), so that ``replay`` can keep it in a cache file keyed by the model's content
(:func:`replay.pipeline.bin_model.prepared_bin_model`): preparing a 365k-point model costs ~0.8
CPU-s, loading it back ~0.05.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .bin_model import BinModel
from .params import RegistrationParams, RemovalParams
from .registration import IcpModel, Points, prepare_icp_model
from .removal import RemovalIndex, _ModelIndex, prepare_removal_index

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

__all__ = ["PreparedBinModel", "prepare_bin_model", "prepared_arrays", "prepared_from_arrays"]


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


# ------------------------------------------------------------------- named arrays (a cache's form)
def _tree_arrays(tree: cKDTree, prefix: str, out: dict[str, np.ndarray]) -> bool:
    """The state of a scipy ``cKDTree`` (what it pickles: its node buffer, data, indices, bounds) as
    arrays; False for a periodic tree (``boxsize``), which is not kept."""
    buf, data, n, m, leafsize, maxes, mins, indices, boxsize, boxsize_data = tree.__getstate__()
    if boxsize is not None or boxsize_data is not None:
        return False
    out.update({f"{prefix}.buffer": np.asarray(buf), f"{prefix}.data": data, f"{prefix}.sizes":
                np.array([n, m, leafsize], np.int64), f"{prefix}.maxes": maxes, f"{prefix}.mins": mins,
                f"{prefix}.indices": indices})
    return True


def _tree_of(a: dict[str, np.ndarray], prefix: str) -> cKDTree:
    from scipy.spatial import cKDTree

    n, m, leafsize = (int(v) for v in a[f"{prefix}.sizes"])
    tree = cKDTree.__new__(cKDTree)
    tree.__setstate__((a[f"{prefix}.buffer"], a[f"{prefix}.data"], n, m, leafsize, a[f"{prefix}.maxes"],
                       a[f"{prefix}.mins"], a[f"{prefix}.indices"], None, None))
    return tree


def _cloud_arrays(pc: Points, prefix: str, out: dict[str, np.ndarray]) -> bool:
    """A downsampled model cloud's points and normals; False when it has no normals (an empty model's)."""
    if not pc.has_normals():
        return False
    assert pc.normals is not None  # has_normals
    out[f"{prefix}.points"] = pc.points.copy()
    out[f"{prefix}.normals"] = pc.normals.copy()
    return True


def _cloud_of(a: dict[str, np.ndarray], prefix: str) -> Points:
    return Points(a[f"{prefix}.points"], a[f"{prefix}.normals"])


def _index_arrays(ix: _ModelIndex, prefix: str, out: dict[str, np.ndarray]) -> None:
    """A removal cell grid. Its per-cell arrays are mostly empty cells: the CSR ``start`` is kept as the
    nonzero counts, the bounds ``box`` as the occupied cells' rows, ``busy`` as ``empty_to <= 1``."""
    counts = np.diff(ix.start)
    nz = np.flatnonzero(counts)
    out.update({f"{prefix}.scalars": np.array([ix.cell, ix.rim_b, ix.floor_b]), f"{prefix}.origin": ix.origin,
                f"{prefix}.dims": ix.dims, f"{prefix}.cells": np.array([len(ix.start)], np.int64),
                f"{prefix}.nonzero": nz.astype(np.int64), f"{prefix}.counts": counts[nz].astype(np.int64),
                f"{prefix}.points": ix.points, f"{prefix}.normals": ix.normals, f"{prefix}.offsets": ix.offsets,
                f"{prefix}.ijk": ix.ijk, f"{prefix}.order": ix.order, f"{prefix}.empty_to": ix.empty_to,
                f"{prefix}.box": ix.box[nz] if len(ix.box) else np.zeros((0, 6))})


def _index_of(a: dict[str, np.ndarray], prefix: str) -> _ModelIndex:
    n_cells = int(a[f"{prefix}.cells"][0]) - 1
    nz = a[f"{prefix}.nonzero"]
    start = np.zeros(n_cells + 1, np.int64)
    start[nz + 1] = a[f"{prefix}.counts"]
    np.cumsum(start, out=start)
    cell, rim_b, floor_b = (float(v) for v in a[f"{prefix}.scalars"])
    empty_to = a[f"{prefix}.empty_to"]
    rows = a[f"{prefix}.box"]
    box = np.zeros((0, 6))
    if len(rows) or not len(nz):  # a grid made with its cells' bounds (an empty model's too)
        box = np.concatenate([np.full((n_cells, 3), np.inf), np.full((n_cells, 3), -np.inf)], axis=1)
        box[nz] = rows
    return _ModelIndex(cell, a[f"{prefix}.origin"], a[f"{prefix}.dims"], start, a[f"{prefix}.points"],
                       a[f"{prefix}.normals"], a[f"{prefix}.offsets"], rim_b, floor_b, a[f"{prefix}.ijk"],
                       empty_to <= 1, a[f"{prefix}.order"], empty_to, box)


def prepared_arrays(prepared: PreparedBinModel) -> dict[str, np.ndarray] | None:
    """Every array of ``prepared`` by name (the model's too), for :func:`prepared_from_arrays`; None
    when it holds something this form does not keep (a periodic KD-tree, a cloud without normals)."""
    icp, rem, model = prepared.icp, prepared.removal, prepared.model
    out: dict[str, np.ndarray] = {"model.points": model.points, "model.spacing": np.array([model.spacing_m])}
    if model.normals is not None:
        out["model.normals"] = model.normals
    if icp.points is not model.points or rem.model is not model or rem.tree is None:
        return None
    if icp.top_centre is not None:
        out["icp.centre"], out["icp.top"] = icp.top_centre[0], np.array([icp.top_centre[1]])
    out["icp.rim"], out["icp.up"] = icp.rim, icp.up
    if icp.coarse is not icp.fine:
        if not _cloud_arrays(icp.coarse, "icp.coarse", out):
            return None
    if not (_cloud_arrays(icp.fine, "icp.fine", out) and _tree_arrays(icp.tree, "icp.tree", out)
            and _tree_arrays(rem.tree, "removal.tree", out)):
        return None
    out["removal.scalars"] = np.array([rem.rim_b, rem.floor_b, rem.radius_m])
    _index_arrays(rem.bin, "removal.bin", out)
    if rem.straggler is not None:
        _index_arrays(rem.straggler, "removal.straggler", out)
    if rem.nearest is not None:
        _index_arrays(rem.nearest, "removal.nearest", out)
    return out


def prepared_from_arrays(arrays: dict[str, np.ndarray], *, registration: RegistrationParams,
                         removal: RemovalParams) -> PreparedBinModel:
    """The :class:`PreparedBinModel` of :func:`prepared_arrays`' output, for the same parameters
    (the caller keys what it stored by them): the same values bit for bit, nothing recomputed but
    the CSR offsets of the cell grids (a cumulative sum of the stored counts).

    Raises
    ------
    KeyError, ValueError, TypeError
        ``arrays`` is not what :func:`prepared_arrays` gave (a cache written by other code).
    """
    a = arrays
    model = BinModel(a["model.points"], a.get("model.normals"), float(a["model.spacing"][0]))
    fine = _cloud_of(a, "icp.fine")
    coarse = _cloud_of(a, "icp.coarse") if "icp.coarse.points" in a else fine
    top_centre = (a["icp.centre"], float(a["icp.top"][0])) if "icp.centre" in a else None
    icp = IcpModel(model.points, top_centre, fine, coarse, _tree_of(a, "icp.tree"), registration, a["icp.rim"],
                   a["icp.up"])
    rim_b, floor_b, radius_m = (float(v) for v in a["removal.scalars"])
    straggler = _index_of(a, "removal.straggler") if "removal.straggler.points" in a else None
    nearest = _index_of(a, "removal.nearest") if "removal.nearest.points" in a else None
    rem = RemovalIndex(model, removal, rim_b, floor_b, radius_m, _index_of(a, "removal.bin"), straggler,
                       _tree_of(a, "removal.tree"), nearest)
    return PreparedBinModel(model, icp, rem)
