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
STRAGGLER_PASSES = 8


def finite_xyz(xyz: XYZ) -> Mask:
    """(H, W) bool: all three coordinates finite (per-channel ANDs: faster than ``.all(axis=2)``)."""
    return np.isfinite(xyz[..., 0]) & np.isfinite(xyz[..., 1]) & np.isfinite(xyz[..., 2])


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


@dataclass(frozen=True, slots=True)
class _ModelIndex:
    """Per-model search structures, built once: KD-tree, dilated occupancy grid, planes."""

    tree: object
    cell: float
    origin: np.ndarray
    occupied: np.ndarray  # (X, Y, Z) bool, dilated by one cell
    points32: np.ndarray
    normals32: np.ndarray | None
    offsets32: np.ndarray | None  # n . m per model point
    rim_b: float  # 99.5th percentile of the model's height (-z), bin frame
    floor_b: float  # 0.5th percentile


_INDEX: dict[tuple[int, float], tuple[np.ndarray, _ModelIndex]] = {}


GRID_CELL_M = 0.002


def _model_index(points: np.ndarray, normals: np.ndarray | None, radius: float) -> _ModelIndex:
    """Search structures of a model array, valid for search radii up to ``radius`` (cached)."""
    from scipy.spatial import cKDTree

    cell = max(GRID_CELL_M, float(radius))
    key = (id(points), cell)
    hit = _INDEX.get(key)
    if hit is not None and hit[0] is points:
        return hit[1]
    origin = points.min(axis=0) - 2 * cell
    ijk = np.floor((points - origin) / cell).astype(np.int64)
    dims = ijk.max(axis=0) + 3
    core = np.zeros(tuple(int(d) for d in dims), bool)
    core[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = True
    occ = core.copy()  # dilate by one cell: the union of the 26 shifted copies
    for a in range(3):
        grown = occ.copy()
        grown[(slice(None),) * a + (slice(1, None),)] |= occ[(slice(None),) * a + (slice(None, -1),)]
        grown[(slice(None),) * a + (slice(None, -1),)] |= occ[(slice(None),) * a + (slice(1, None),)]
        occ = grown
    n32 = None if normals is None else np.ascontiguousarray(normals, np.float32)
    off = None if normals is None else np.einsum("ij,ij->i", points, normals).astype(np.float32)
    h = -points[:, 2]
    index = _ModelIndex(cKDTree(points), float(cell), origin, occ,
                        np.ascontiguousarray(points, np.float32), n32, off,
                        float(np.percentile(h, 99.5)), float(np.percentile(h, 0.5)))
    if len(_INDEX) >= 6:
        _INDEX.pop(next(iter(_INDEX)))
    _INDEX[key] = (points, index)
    return index


def _plane_test(points: np.ndarray, model: np.ndarray, normals: np.ndarray | None, *,
                delta_m: float, radius_m: float) -> tuple[np.ndarray, np.ndarray]:
    """((M,) bool ok, (M,) int64 nearest model point within the radius or -1).

    ``points`` and ``model`` in the same frame. With normals: ok when a model point within
    ``radius_m`` (the nearest, else any of the 4 nearest: near an edge the nearest point may lie on
    the other face) has its tangent plane within ``delta_m``; without: the nearest model point is
    within ``delta_m``. A dilated occupancy grid of the model rejects most far points before the
    KD-tree is asked.
    """
    ok_all = np.zeros(len(points), bool)
    near_all = np.full(len(points), -1, np.int64)
    if len(points) == 0 or len(model) == 0:
        return ok_all, near_all
    reach = delta_m if normals is None else radius_m
    index = _model_index(model, normals, reach)
    ijk = np.floor((points - index.origin) * (1.0 / index.cell)).astype(np.int64)
    i, j_, k = ijk[:, 0], ijk[:, 1], ijk[:, 2]
    d0, d1_, d2 = index.occupied.shape
    inb = (i >= 0) & (i < d0) & (j_ >= 0) & (j_ < d1_) & (k >= 0) & (k < d2)
    cand = np.flatnonzero(inb)
    cand = cand[index.occupied[i[cand], j_[cand], k[cand]]]
    if len(cand) == 0:
        return ok_all, near_all
    pc = points[cand]
    if normals is None:
        dist, idx = index.tree.query(pc, k=1, distance_upper_bound=delta_m, workers=-1)
        ok_all[cand] = dist <= delta_m
        near_all[cand] = np.where(np.isfinite(dist), idx, -1)
        return ok_all, near_all
    pc32 = pc.astype(np.float32)
    # the nearest model point's plane decides for most points ...
    dist, idx = index.tree.query(pc, k=1, distance_upper_bound=radius_m, workers=-1)
    hit = np.isfinite(dist)
    j = np.where(hit, idx, 0)
    d1 = np.abs(np.einsum("ik,ik->i", pc32, index.normals32[j]) - index.offsets32[j])
    ok = hit & (d1 <= delta_m)
    # ... the others ask their 4 nearest
    again = np.flatnonzero(hit & ~ok)
    if len(again):
        dist4, idx4 = index.tree.query(pc[again], k=4, distance_upper_bound=radius_m, workers=-1)
        hit4 = np.isfinite(dist4)
        j4 = np.where(hit4, idx4, 0)
        d4 = np.abs(np.einsum("ik,ijk->ij", pc32[again], index.normals32[j4]) - index.offsets32[j4])
        d4[~hit4] = np.inf
        ok[again] = d4.min(axis=1) <= delta_m
    ok_all[cand] = ok
    near_all[cand] = np.where(hit, idx, -1)
    return ok_all, near_all


def _near_model(points: np.ndarray, model: np.ndarray, normals: np.ndarray | None, *,
                delta_m: float, radius_m: float) -> np.ndarray:
    """(M,) bool: points within ``delta_m`` of the model surface (see :func:`_plane_test`)."""
    return _plane_test(points, model, normals, delta_m=delta_m, radius_m=radius_m)[0]


def remove_table_and_bin(
    xyz: XYZ,
    footprint: Mask,
    *,
    model: BinModel | None = None,
    T_cam_bin: np.ndarray | None = None,
    delta_m: float = 1e-4,
    rim_offset_m: float = 0.005,
    search_radius_m: float | None = None,
    straggler_m: float = 0.0,
    straggler_neighbours: int = 5,
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
    straggler_m : float
        A second, looser test for the noise tail of the bin surface: a remaining pixel with at
        least ``straggler_neighbours`` of its 8 neighbours labelled table or bin or invalid, and within
        ``straggler_m`` of the model, is bin too (0: off); repeated up to
        :data:`STRAGGLER_PASSES` times, so that it grows along clumps of such pixels. Without it a few noisy rim pixels stay
        in the zone, become its highest points and move the z-cut's z_max up to the rim.
    straggler_neighbours : int
        See ``straggler_m``.

    Returns
    -------
    RemovalResult
    """
    a = check_xyz(xyz)
    fp = np.asarray(footprint)
    if fp.shape != a.shape[:2] or fp.dtype != np.bool_:
        raise InputShapeError(f"footprint must be an {a.shape[:2]} bool array, got {describe_array(fp)}")
    if int(straggler_neighbours) != straggler_neighbours or not 0 <= straggler_neighbours <= 8:
        raise ParameterError(f"straggler_neighbours must be an integer in 0..8, got {straggler_neighbours!r}")
    for name, v in (("delta_m", delta_m), ("rim_offset_m", rim_offset_m), ("straggler_m", straggler_m)):
        if not (np.isfinite(v) and v >= 0):
            raise ParameterError(f"{name} must be a non-negative number, got {v!r}")
    if (model is None) != (T_cam_bin is None):
        raise ParameterError("model and T_cam_bin must be given together")
    z64 = a[..., 2].astype(np.float64)
    valid = finite_xyz(a)
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
        # heights along up = -z in the bin frame; work in the bin frame so that the model's
        # KD-tree is built once per model, not once per frame
        mi = _model_index(model.points, model.normals, 0.0)
        rim_b, floor_b = mi.rim_b, mi.floor_b
        shift = float(t @ up)  # height of the bin origin along up, camera frame
        rim, floor = rim_b + shift, floor_b + shift
        rows, cols = np.nonzero(inside)
        p_bin = (a[rows, cols].astype(np.float64) - t) @ R
        h = -p_bin[:, 2]
        is_easy = h > rim_b + rim_offset_m
        easy[rows[is_easy], cols[is_easy]] = True
        rest = np.flatnonzero(~is_easy)
        radius = search_radius_m if search_radius_m is not None else max(delta_m, 1.5 * model.spacing_m)
        radius = max(radius, delta_m, 1e-9)
        if delta_m > 0:
            near = _near_model(p_bin[rest], model.points, model.normals, delta_m=delta_m, radius_m=radius)
            binp[rows[rest[near]], cols[rest[near]]] = True
        if straggler_m > 0:
            import cv2

            index = np.full(valid.shape, -1, np.int64)
            index[rows, cols] = np.arange(len(rows))
            tried = np.zeros_like(valid)
            kernel = np.ones((3, 3), np.float32)
            for _ in range(STRAGGLER_PASSES):  # grows along the noisy rim, one ring per pass
                lab = (table | binp | ~valid).astype(np.uint8)  # invalid neighbours count as not zone
                n_lab = cv2.filter2D(lab, -1, kernel, borderType=cv2.BORDER_CONSTANT) - lab
                loose = inside & ~easy & ~binp & ~tried & (n_lab >= straggler_neighbours)
                if not loose.any():
                    break
                tried |= loose
                sel = index[loose]
                near = _near_model(p_bin[sel], model.points, model.normals, delta_m=straggler_m,
                                   radius_m=max(radius, straggler_m))
                if not near.any():
                    break
                binp[rows[sel[near]], cols[sel[near]]] = True
                tried[rows[sel[near]], cols[sel[near]]] = False
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
