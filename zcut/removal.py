"""Remove the table and the bin from a filled-bin frame (paper §5.2, Figure 3a and Figure 10).

Classes of valid pixels, in this order of precedence:

- table: outside the bin footprint;
- easy outliers: inside the footprint but above the registered rim plane plus an offset;
- bin: within ``delta`` of the registered bin model;
- zone: what remains, the top zone of the pile the z-cut and SOR work on.

Labelled points (table, easy, bin) keep their pixel, with z moved to the registered bin's floor, so
the grid stays organized and the z-cut sees them as the lowest level.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .cloud import check_xyz
from .errors import InputShapeError, ParameterError, describe_array
from .types import XYZ, FloatImage, Mask

# In the bin frame "up" is -z: models are built in a top-down camera's optical frame.
BIN_UP = np.array([0.0, 0.0, -1.0])


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
        if self.normals is not None and np.shape(self.normals) != p.shape:
            raise InputShapeError(
                f"BinModel.normals must match points {p.shape}, got {describe_array(self.normals)}"
            )
        if not (np.isfinite(self.spacing_m) and self.spacing_m > 0):
            raise ParameterError(f"BinModel.spacing_m must be > 0, got {self.spacing_m!r}")


@dataclass(frozen=True, slots=True)
class RemovalResult:
    """Per-pixel classes and the height image of the remaining zone.

    Attributes
    ----------
    table, easy_outliers, bin_points, zone : (H, W) bool ndarray
        Disjoint classes of the valid pixels (their union is the valid mask).
    height_mm : (H, W) float64 ndarray
        ``-1000 * z`` with the labelled pixels' z set to the bin floor; NaN where invalid.
    xyz : (H, W, 3) float32 ndarray
        The frame with the labelled pixels' z set to the bin floor.
    rim_m, floor_m : float
        Heights of the rim and of the floor along ``up_cam`` (metres, camera frame); NaN when no
        model was registered (then the floor is the farthest valid point).
    up_cam : (3,) float64 ndarray
        The bin's up direction in the camera frame.
    """

    table: Mask
    easy_outliers: Mask
    bin_points: Mask
    zone: Mask
    height_mm: FloatImage
    xyz: np.ndarray
    rim_m: float
    floor_m: float
    up_cam: np.ndarray

    @property
    def labelled(self) -> Mask:
        """(H, W) bool: table, easy outliers or bin."""
        return self.table | self.easy_outliers | self.bin_points


def _near_model(points: np.ndarray, model: np.ndarray, normals: np.ndarray | None, *,
                delta_m: float, radius_m: float) -> np.ndarray:
    """(M,) bool: points within ``delta_m`` of the model surface (see :func:`remove_table_and_bin`)."""
    from scipy.spatial import cKDTree

    out = np.zeros(len(points), bool)
    if len(points) == 0 or len(model) == 0:
        return out
    # Cheap pre-filter on a voxel hash with cells of the search radius: a point within the radius
    # of a model point lies in the model point's cell or one of its 26 neighbours.
    cell = radius_m
    lo = np.minimum(model.min(axis=0), points.min(axis=0)) - 2 * cell
    mk = np.floor((model - lo) / cell).astype(np.int64)
    pk = np.floor((points - lo) / cell).astype(np.int64)
    dims = np.maximum(mk.max(axis=0), pk.max(axis=0)) + 2
    offs = np.stack(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1], indexing="ij"), -1).reshape(-1, 3)
    mk_all = np.unique((mk[:, None, :] + offs[None]).reshape(-1, 3) @ np.array([dims[1] * dims[2], dims[2], 1]))
    pkey = pk @ np.array([dims[1] * dims[2], dims[2], 1])
    cand = np.nonzero(np.isin(pkey, mk_all, assume_unique=False))[0]
    if len(cand) == 0:
        return out
    tree = cKDTree(model)
    if normals is None:
        dist, _ = tree.query(points[cand], k=1, distance_upper_bound=radius_m, workers=-1)
        ok = dist <= delta_m
    else:
        # the smallest point-to-plane distance over the model points within the radius (near an
        # edge the nearest point may lie on the other face)
        k = 8
        dist, idx = tree.query(points[cand], k=k, distance_upper_bound=radius_m, workers=-1)
        hit = np.isfinite(dist)
        j = np.where(hit, idx, 0)
        diff = points[cand][:, None, :] - model[j]
        d_plane = np.abs(np.einsum("ijk,ijk->ij", diff, normals[j]))
        d_plane[~hit] = np.inf
        ok = d_plane.min(axis=1) <= delta_m
    out[cand[ok]] = True
    return out


def remove_table_and_bin(
    xyz: XYZ,
    footprint: Mask,
    *,
    model: BinModel | None = None,
    T_cam_bin: np.ndarray | None = None,
    delta_m: float = 1e-4,
    rim_offset_m: float = 0.005,
    search_radius_m: float | None = None,
) -> RemovalResult:
    """Label table, easy outliers and bin points; return the classes and the zone's height image.

    Parameters
    ----------
    xyz : (H, W, 3) float ndarray
        Metres, camera optical frame, NaN = invalid.
    footprint : (H, W) bool ndarray
        The bin footprint (:func:`zcut.binmask.bin_mask`); outside it is table.
    model : BinModel, optional
        The bin model; with ``T_cam_bin`` it gives the rim, the floor and the bin points. Without,
        only the table is removed and the floor is the farthest valid point.
    T_cam_bin : (4, 4) float ndarray, optional
        The registered pose of the model.
    delta_m : float
        δ: a point this close to the model surface (point-to-plane when the model has normals,
        else to the nearest model point) is bin. Paper: 0.1 mm.
    rim_offset_m : float
        A point higher than the rim by more than this is an easy outlier.
    search_radius_m : float, optional
        Nearest-model-point search radius for the point-to-plane test; default
        ``max(delta_m, 1.5 * model.spacing_m)``.

    Returns
    -------
    RemovalResult
    """
    a = check_xyz(xyz)
    fp = np.asarray(footprint)
    if fp.shape != a.shape[:2] or fp.dtype != np.bool_:
        raise InputShapeError(f"footprint must be an {a.shape[:2]} bool array, got {describe_array(fp)}")
    for name, v in (("delta_m", delta_m), ("rim_offset_m", rim_offset_m)):
        if not (np.isfinite(v) and v >= 0):
            raise ParameterError(f"{name} must be a non-negative number, got {v!r}")
    if (model is None) != (T_cam_bin is None):
        raise ParameterError("model and T_cam_bin must be given together")
    z64 = a[..., 2].astype(np.float64)
    valid = np.isfinite(a).all(axis=2)
    table = valid & ~fp
    inside = valid & fp
    easy = np.zeros_like(valid)
    binp = np.zeros_like(valid)
    if model is None:
        up = BIN_UP.copy()
        rim = floor = float("nan")
        zfloor = np.full(z64.shape, np.nanmax(z64[valid]) if valid.any() else np.nan)
    else:
        T = np.asarray(T_cam_bin, dtype=np.float64)
        R, t = T[:3, :3], T[:3, 3]
        up = R @ BIN_UP
        model_cam = model.points @ R.T + t
        h_model = model_cam @ up
        rim = float(np.percentile(h_model, 99.5))
        floor = float(np.percentile(h_model, 0.5))
        rows, cols = np.nonzero(inside)
        p = a[rows, cols].astype(np.float64)
        h = p @ up
        is_easy = h > rim + rim_offset_m
        easy[rows[is_easy], cols[is_easy]] = True
        rest = ~is_easy
        normals_cam = None if model.normals is None else model.normals @ R.T
        radius = search_radius_m if search_radius_m is not None else max(delta_m, 1.5 * model.spacing_m)
        if normals_cam is None:
            radius = delta_m
        if delta_m > 0:
            near = _near_model(p[rest], model_cam, normals_cam, delta_m=delta_m, radius_m=max(radius, 1e-9))
            binp[rows[rest][near], cols[rest][near]] = True
        # floor plane {q : q . up = floor}: z at (x, y) solves x*ux + y*uy + z*uz = floor
        if abs(up[2]) > 1e-6:
            x64 = a[..., 0].astype(np.float64)
            y64 = a[..., 1].astype(np.float64)
            zfloor = (floor - x64 * up[0] - y64 * up[1]) / up[2]
        else:  # a bin seen from the side: fall back to the farthest point
            zfloor = np.full(z64.shape, np.nanmax(z64[valid]))
    labelled = table | easy | binp
    zone = valid & ~labelled
    z_new = np.where(labelled, zfloor, z64)
    height = -1000.0 * z_new
    height[~valid] = np.nan
    xyz_out = a.astype(np.float32, copy=True)
    xyz_out[..., 2] = np.where(labelled, zfloor, xyz_out[..., 2]).astype(np.float32)
    return RemovalResult(table, easy, binp, zone, height, xyz_out, rim, floor, up)
