"""Remove the table and the bin from a filled-bin frame (paper §5.2, Figure 3a and Figure 10).

Classes of valid pixels, in this order of precedence:

- table: outside the bin footprint;
- easy outliers: inside the footprint but above the registered rim plane plus an offset;
- bin: within ``delta`` of the registered bin model;
- zone: what remains, the top zone of the pile the z-cut and SOR work on.

Labelled points (table, easy, bin) keep their pixel, with z moved to the registered bin's floor, so
the grid stays organized and the z-cut sees them as the lowest level.

Two modes (``RemovalParams.mode``, described in ``docs/pipeline.md``, "Bin removal"):

- ``"paper"``: the order above with δ = ``delta_mm`` (the paper's 0.1 mm). A pose 0.2 mm off
  leaves the bin's rim in the zone, where it becomes the zone's highest surface and the z-cut,
  which judges only the top ``d_max`` of the zone, never reaches the pile.
- ``"robust"`` (default): δ is replaced by a tolerance τ measured on the frame
  (:func:`frame_tolerance`): the distances of the frame's certain bin pixels (the rim and upper
  walls the registration used) to the registered model, the ``residual_quantile`` percentile of
  those coherent with their neighbours' (a sensor's ghosts are not: :func:`coherent_residuals`) and
  on the registered bin's residual field (the faces of parts leaning on a wall are not:
  :func:`fit_residual_field`) plus ``residual_margin_mm``, within ``[min_tolerance_mm, max_tolerance_mm]``. A point within τ of
  the model is bin before it can be an easy outlier (a tilted pose lifts one end of the real rim
  above the model's rim plus the offset). The test's search radius (a model point that near, then
  the point within τ of it along its normal) is measured on the same pixels: their distances to the
  nearest model point (:attr:`Tolerance.reach_mm`; a model built from a few low-resolution scans
  is sampled more coarsely than ``1.5 × spacing_m`` says). The straggler test reaches
  ``straggler_mm`` beyond both: τ + ``straggler_mm`` along the normal, the radius + ``straggler_mm``; with
  ``RemovalParams.straggler_bound`` on (``"below_rim"`` by default, below the rim's band; ``"global"`` everywhere), no
  farther than 3 of the bin's Err along the normal (the paper's §2: a point farther than 3 Err from the fitted
  model is an outlier), Err = max(0.05 mm, √(σ_bin² + c²/2)) with σ_bin the residual scale of the pixels τ is
  measured on (:func:`bin_sigma_m`, :attr:`Tolerance.sigma_mm`) and c the pixel's footprint (z / f,
  :func:`pixel_angle`): :func:`straggler_bound_m`. Without a measured τ (fixed, no ring) the bound is not known and
  not applied. On hand-made walls piles every near-wall true outlier the removal took was a straggler 3.1-4.2
  bin Errs from the model (docs/bin_robustness.md). ``straggler_bound = "below_rim"`` applies the bound only below
  the rim's band, ``rim_offset_mm`` under the model's rim height (:func:`straggler_top_m`): a model off the bin
  leaves rim pixels 2-4 mm under the rim beyond 3 Err, while the near-wall outliers the pass took lay 45 mm or
  more below it.
  With a right pose τ stays near 1 mm (the sensor's noise); a pose 2 mm off raises it to about
  3 mm, and the removal follows the registration instead of failing on it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numba
import numpy as np

from .bin_model import BinModel
from .cloud import check_xyz
from .errors import InputShapeError, ParameterError, describe_array
from .params import RemovalParams
from .types import XYZ, FloatImage, Mask

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

# In the bin frame "up" is -z: models are built in a top-down camera's optical frame.
BIN_UP = np.array([0.0, 0.0, -1.0])
BIN_UP.setflags(write=False)
STRAGGLER_PASSES = 8
#: The straggler test's bound (issue 31 item 2): a straggler lies within this many of the bin's Err of the model
#: (the paper's §2: a point farther than 3 Err from the fitted model is an outlier, so not bin) ...
STRAGGLER_ERRS = 3.0
#: ... the Err being ``max(STRAGGLER_ERR_FLOOR_MM, sqrt(σ_bin² + c² / 2))`` (c the pixel's footprint; the floor
#: is ``explained``'s, ``ExplainedParams.err_floor_mm``): :func:`straggler_bound_m`
STRAGGLER_ERR_FLOOR_MM = 0.05
_STRAGGLER_ERR_FLOOR_M = STRAGGLER_ERR_FLOOR_MM / 1000.0
#: the kernels' (σ_bin², the pixel's angle, the height above which no straggler is bounded) when the bound is off:
#: σ_bin² < 0
_NO_BOUND = (-1.0, 0.0, np.inf)


def finite_xyz(xyz: XYZ) -> Mask:
    """(H, W) bool: all three coordinates finite (per-channel ANDs: faster than ``.all(axis=2)``)."""
    return np.isfinite(xyz[..., 0]) & np.isfinite(xyz[..., 1]) & np.isfinite(xyz[..., 2])


def valid_pixels(xyz: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels whose three coordinates are finite, :func:`finite_xyz` (the
    reference: three ``isfinite`` images and two ANDs) in one pass of a kernel over a float32 or float64
    (H, W, 3) cloud (1.7 against 6.2 CPU ms at 1920 x 1200); other inputs go to the reference."""
    if xyz.ndim != 3 or xyz.shape[2] != 3 or xyz.dtype not in (np.float32, np.float64):
        return finite_xyz(xyz)
    out = np.empty(xyz.shape[:2], dtype=np.bool_)
    _finite_pixels(xyz, out)
    return out


@numba.njit(cache=True, nogil=True)
def _finite_pixels(xyz, out):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - compiled
    h, w = out.shape
    for i in range(h):
        for j in range(w):
            out[i, j] = np.isfinite(xyz[i, j, 0]) & np.isfinite(xyz[i, j, 1]) & np.isfinite(xyz[i, j, 2])


@dataclass(frozen=True, slots=True)
class FlooredCloud:
    """The removal's float32 cloud, written only when asked for (:meth:`array`): the input frame with its labelled
    pixels' z moved to the bin's floor (no stage of the replay reads it; writing it cost ~2.6 CPU ms a
    1920 × 1200 frame).

    It keeps the removal's input and masks, not a copy: it reads the input when :meth:`array` is called, so
    the input must not be written in between (the replay's frames are not).

    Attributes
    ----------
    source : (H, W, 3) float ndarray
        The removal's input, metres, camera optical frame.
    table, easy_outliers, bin_points : (H, W) bool ndarray
        The labelled classes (:class:`RemovalResult`'s).
    plane : bool
        The floor is the plane {q : q · up_cam = floor_m}; else the constant ``z_far_m``.
    floor_m : float
    up_cam : (3,) float64 ndarray
    z_far_m : float
        The farthest valid z (metres) when the bin is seen from the side (``plane`` false); NaN otherwise.
    """

    source: np.ndarray
    table: Mask
    easy_outliers: Mask
    bin_points: Mask
    plane: bool
    floor_m: float
    up_cam: np.ndarray
    z_far_m: float

    def array(self) -> np.ndarray:
        """(H, W, 3) float32 ndarray: a new array, the same bytes as :func:`remove_table_and_bin`'s reference
        (``reference=True``) writes."""
        out = np.empty(self.source.shape, np.float32)
        _floored_cloud(self.source, self.table, self.easy_outliers, self.bin_points, self.plane, self.floor_m,
                       self.up_cam, self.z_far_m, out)
        return out


@dataclass(frozen=True, slots=True)
class RemovalResult:
    """Per-pixel classes and the height image of the remaining zone.

    Attributes
    ----------
    table, easy_outliers, bin_points, zone : (H, W) bool ndarray
        Disjoint classes of the valid pixels (their union is the valid mask).
    height_mm : (H, W) float64 ndarray
        ``-1000 * z`` with the labelled pixels' z set to the bin floor; NaN where invalid.
    cloud : (H, W, 3) float32 ndarray or FlooredCloud
        The frame with the labelled pixels' z set to the bin floor (:attr:`xyz`), or what writes it when it is
        asked for (the fast path's: no stage reads it).
    rim_m, floor_m : float
        Heights of the rim and of the floor along ``up_cam`` (metres, camera frame); NaN when no
        model was registered (then the floor is the farthest valid point).
    up_cam : (3,) float64 ndarray
        The bin's up direction in the camera frame.
    tolerance_mm : float
        The distance to the model within which a point was bin: δ in the paper mode, τ in the
        robust mode; NaN when no model was registered.
    residual_mm : float
        Robust mode: the percentile of the certain bin pixels' residuals τ was derived from (before
        the margin and the bounds; :attr:`Tolerance.residual_mm`); NaN otherwise.
    radius_mm : float
        The search radius of the bin test (mm): a point is bin when a model point within it lies
        within ``tolerance_mm`` of the point along its normal. Robust mode: at least the frame's
        reach (:attr:`Tolerance.reach_mm`); NaN when no model was registered.
    surface : optional
        The ring's residuals :func:`frame_tolerance` measured (:func:`surface_residuals` returns them
        for the same ring, model and pose instead of measuring again); None when not measured.
    zone_top : optional
        The zone's highest height, found while the height image was written (the bin check reads it for
        these ``zone`` and ``height_mm`` arrays instead of scanning them again); None from the reference.
    """

    table: Mask
    easy_outliers: Mask
    bin_points: Mask
    zone: Mask
    height_mm: FloatImage
    cloud: np.ndarray | FlooredCloud
    rim_m: float
    floor_m: float
    up_cam: np.ndarray
    tolerance_mm: float = float("nan")
    residual_mm: float = float("nan")
    radius_mm: float = float("nan")
    surface: _Surface | None = None
    zone_top: _ZoneTop | None = field(default=None, repr=False, compare=False)

    @property
    def labelled(self) -> Mask:
        """(H, W) bool: table, easy outliers or bin."""
        return self.table | self.easy_outliers | self.bin_points

    @property
    def xyz(self) -> np.ndarray:
        """(H, W, 3) float32 ndarray: the frame with the labelled pixels' z set to the bin floor (written at each
        call when :attr:`cloud` is a :class:`FlooredCloud`)."""
        c = self.cloud
        return c.array() if isinstance(c, FlooredCloud) else c


@dataclass(frozen=True, slots=True)
class _ModelIndex:
    """Per-model search structures, built once: a grid of cells with their model points (CSR).

    The points, normals and offsets are stored sorted by cell, so that a cell's points are
    contiguous in memory: those of cell c are rows ``start[c]:start[c + 1]``.
    """

    cell: float
    origin: np.ndarray  # (3,) float64
    dims: np.ndarray  # (3,) int64
    start: np.ndarray  # (n_cells + 1,) int64
    points: np.ndarray  # (N, 3) float64, sorted by cell
    normals: np.ndarray  # (N, 3) float64 (zeros when the model has none), sorted by cell
    offsets: np.ndarray  # (N,) float64: n . m, sorted by cell
    rim_b: float  # 99.5th percentile of the model's height (-z), bin frame
    floor_b: float  # 0.5th percentile
    ijk: np.ndarray  # (N, 3) int64: the cell of each point, sorted by cell
    busy: np.ndarray  # (n_cells,) bool: some model point in the cell or one of its 26 neighbours
    order: np.ndarray  # (N,) int64: the model's index of each sorted point
    empty_to: np.ndarray  # (n_cells,) uint8: Chebyshev distance in cells to the nearest occupied cell (<= 255)
    box: np.ndarray  # (n_cells, 6) float64: each cell's points' bounds (lo xyz, hi xyz; empty: +inf, -inf)


GRID_CELL_M = 0.002


def _model_index(points: np.ndarray, normals: np.ndarray | None, radius: float, *,
                 boxes: bool = True) -> _ModelIndex:
    """Search structures of a model array, valid for search radii up to ``radius`` (``boxes``: with the
    cells' bounds, which the fast path's bin and straggler tests read; the nearest-point grid has none)."""
    cell = max(GRID_CELL_M, float(radius))
    if len(points) == 0:  # an empty model: one empty cell, no point is ever near it
        empty = np.zeros((0, 3))
        return _ModelIndex(cell, np.zeros(3), np.full(3, 3, np.int64), np.zeros(28, np.int64), empty, empty.copy(),
                           np.zeros(0), float("nan"), float("nan"), np.zeros((0, 3), np.int64), np.zeros(27, bool),
                           np.zeros(0, np.int64), np.full(27, 255, np.uint8),
                           np.concatenate([np.full((27, 3), np.inf), np.full((27, 3), -np.inf)], axis=1))
    origin = points.min(axis=0) - 2 * cell
    ijk = np.floor((points - origin) / cell).astype(np.int64)
    dims = ijk.max(axis=0) + 3
    flat = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    order = np.argsort(flat, kind="stable").astype(np.int64)
    counts = np.bincount(flat, minlength=int(np.prod(dims)))
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    nrm = np.zeros_like(points) if normals is None else np.ascontiguousarray(normals, np.float64)
    h = -points[:, 2]
    offsets = np.einsum("ij,ij->i", points, nrm)
    # a cell whose 27-cell neighbourhood holds no model point: no search from it finds one (model points lie in
    # cells 2 .. dims - 3, the searched cells of a point inside 1 .. dims - 2 are within its neighbourhood)
    from scipy import ndimage

    occupied = (counts > 0).reshape(tuple(int(d) for d in dims))
    # each cell's Chebyshev distance (in cells) to the nearest occupied one: <= 1 is "busy"
    empty_to = np.minimum(ndimage.distance_transform_cdt(~occupied, metric="chessboard"), 255).astype(np.uint8)
    busy = empty_to <= 1
    return _ModelIndex(cell, origin, dims.astype(np.int64), start,
                       np.ascontiguousarray(points[order], np.float64), np.ascontiguousarray(nrm[order]),
                       offsets[order], float(np.percentile(h, 99.5)), float(np.percentile(h, 0.5)),
                       np.ascontiguousarray(ijk[order]), busy.reshape(-1), order, empty_to.reshape(-1),
                       _cell_boxes(points[order], start, counts) if boxes else np.zeros((0, 6)))


def _cell_boxes(points: np.ndarray, start: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """(n_cells, 6): the bounds of each cell's points (lo x, y, z, hi x, y, z; +inf, -inf when empty), from
    the points sorted by cell."""
    n = len(counts)
    box = np.concatenate([np.full((n, 3), np.inf), np.full((n, 3), -np.inf)], axis=1)
    full = np.flatnonzero(counts)
    for k in range(3):
        box[full, k] = np.minimum.reduceat(points[:, k], start[full])
        box[full, 3 + k] = np.maximum.reduceat(points[:, k], start[full])
    return box


@dataclass(frozen=True, slots=True)
class RemovalIndex:
    """A bin model prepared for :func:`remove_table_and_bin` with one :class:`RemovalParams`.

    Attributes
    ----------
    model : BinModel
    params : RemovalParams
    rim_b, floor_b : float
        The model's rim and floor heights (99.5th and 0.5th percentile of -z, bin frame, metres).
    radius_m : float
        The resolved nearest-model-point search radius.
    bin : _ModelIndex
        Cell grid for the bin-point test (radius ``radius_m`` with normals, else ``delta``; in the
        robust mode the largest tolerance's).
    straggler : _ModelIndex or None
        Cell grid for the straggler test (None when ``params.straggler_mm`` is 0).
    tree : scipy.spatial.cKDTree or None
        Over the model's points, for the residuals of :func:`frame_tolerance` and of the bin check.
    nearest : _ModelIndex or None
        A finer cell grid (:data:`GRID_CELL_M`) answering the tree's nearest-point queries of the residuals
        (the same points and distances, :func:`_nearest_grid`; ~4x cheaper); the tree answers the few
        where the two could differ.
    """

    model: BinModel
    params: RemovalParams
    rim_b: float
    floor_b: float
    radius_m: float
    bin: _ModelIndex
    straggler: _ModelIndex | None
    tree: cKDTree | None = None
    nearest: _ModelIndex | None = None


def _radius(params: RemovalParams, spacing_m: float, delta_m: float) -> float:
    """The nearest-model-point search radius of the bin test at tolerance ``delta_m``."""
    radius = params.search_radius_m if params.search_radius_m is not None else max(delta_m, 1.5 * spacing_m)
    return max(radius, delta_m, 1e-9)


def prepare_removal_index(model: BinModel, params: RemovalParams) -> RemovalIndex:
    """Build the cell grids of ``model`` the removal needs with ``params`` (once per replay).

    An empty model (no points) gives an index that labels nothing bin: the frame's certain bin
    pixels then stay in the zone, and the bin check says so.
    """
    h = -model.points[:, 2]
    planes = model.normals is not None
    # the robust mode's tolerance varies per frame, up to max_tolerance_mm: the grids are built for it
    delta = max(params.delta_m, params.max_tolerance_mm / 1000.0) if params.robust else params.delta_m
    radius = _radius(params, model.spacing_m, delta)
    r_bin = radius if planes else delta
    straggler = None
    if params.straggler_m > 0:
        s = params.straggler_m + (delta if params.robust else 0.0)
        r_str = max(radius, s) if planes else s
        if params.robust and planes:  # the stragglers reach straggler_mm beyond a measured radius too
            r_str = max(r_str, radius + params.straggler_m)
        straggler = _model_index(model.points, model.normals, r_str)
    from scipy.spatial import cKDTree

    # both modes: the residuals of the robust tolerance and of the bin check (zcut.bin_check)
    tree = cKDTree(model.points)
    rim_b, floor_b = (float(np.percentile(h, 99.5)), float(np.percentile(h, 0.5))) if len(h) else (np.nan, np.nan)
    return RemovalIndex(model, params, rim_b, floor_b, _radius(params, model.spacing_m, params.delta_m),
                        _model_index(model.points, model.normals, r_bin), straggler, tree,
                        _model_index(model.points, model.normals, GRID_CELL_M, boxes=False))


@numba.njit(cache=True, inline="always")
def _cell_of(px, py, pz, origin, cell):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """``(fx, fy, fz, ci, cj, ck)``: the point's coordinates in cells of the grid at ``origin`` and the cell it
    lies in (the floors): the one cell index of the bin test, the straggler test and the nearest-point query."""
    fx = (px - origin[0]) / cell
    fy = (py - origin[1]) / cell
    fz = (pz - origin[2]) / cell
    return fx, fy, fz, int(np.floor(fx)), int(np.floor(fy)), int(np.floor(fz))


@numba.njit(cache=True, inline="always")
def _cell_near(px, py, pz, origin, cell):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """:func:`_cell_of` with the coordinates multiplied by ``1 / cell`` (one division, out of the callers' loops)
    instead of divided by ``cell`` (three a point): within two units in the last place of the quotients, which
    moves a coordinate by less than 1e-15 m, far inside the 1 nm margin of the cells a search reads
    (:func:`_reach`). A point near a cell's face may so fall in the cell next to the one the division gives:
    every search from either reads every cell a model point within its radius may lie in, so whether some
    model point passes, the bin test's answer (:func:`_near_hint`), is the same (which one is found first may
    differ: it only hints the next pixel's search), and so is the nearest point (:func:`_nearest_grid`, whose
    balls have a 1 pm margin, its shells a relative 1e-9)."""
    inv = 1.0 / cell
    fx = (px - origin[0]) * inv
    fy = (py - origin[1]) * inv
    fz = (pz - origin[2]) * inv
    return fx, fy, fz, int(np.floor(fx)), int(np.floor(fy)), int(np.floor(fz))


@numba.njit(cache=True, inline="always")
def _reach(f, ci, cell, reach):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """``(lo, hi)`` in {-1, 0} x {0, 1}: the neighbouring cells along one axis that a ball of radius ``reach``
    around the point (``f`` in cells, in cell ``ci``) reaches."""
    return (-1 if (f - ci) * cell <= reach else 0), (1 if (ci + 1 - f) * cell <= reach else 0)


@numba.njit(cache=True, inline="always")
def _dist2(px, py, pz, pts, j):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """The squared distance of (px, py, pz) to the point ``pts[j]``: the three differences squared and summed in
    order, as every search of the removal computes it (``(px - x)²`` and ``(x - px)²`` are the same double: a
    difference's rounding is symmetric)."""
    ex = px - pts[j, 0]
    ey = py - pts[j, 1]
    ez = pz - pts[j, 2]
    return ex * ex + ey * ey + ez * ez


@numba.njit(cache=True, inline="always")
def _near_one(px, py, pz, origin, cell, dims, start, pts, nrm, off, delta, radius, planes):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """Some model point within ``radius`` of (px, py, pz) passes (plane distance, or distance, <= delta).

    Only the neighbouring cells that the radius reaches are searched (a cell's points lie within
    its bounds up to rounding; the 1 nm margin covers it).
    """
    fx, fy, fz, ci, cj, ck = _cell_of(px, py, pz, origin, cell)
    # model points lie in cells 2 .. dims - 3: a point outside 1 .. dims - 2 is farther than a cell
    if ci < 1 or cj < 1 or ck < 1 or ci > dims[0] - 2 or cj > dims[1] - 2 or ck > dims[2] - 2:
        return False
    reach = radius + 1e-9
    x0, x1 = _reach(fx, ci, cell, reach)
    y0, y1 = _reach(fy, cj, cell, reach)
    z0, z1 = _reach(fz, ck, cell, reach)
    r2 = radius * radius
    for dx in range(x0, x1 + 1):
        for dy in range(y0, y1 + 1):
            for dz in range(z0, z1 + 1):
                c = ((ci + dx) * dims[1] + (cj + dy)) * dims[2] + (ck + dz)
                for j in range(start[c], start[c + 1]):
                    d2 = _dist2(px, py, pz, pts, j)
                    if d2 > r2:
                        continue
                    if planes:
                        d = abs(nrm[j, 0] * px + nrm[j, 1] * py + nrm[j, 2] * pz - off[j])
                    else:
                        d = np.sqrt(d2)
                    if d <= delta:
                        return True
    return False


@numba.njit(cache=True, inline="always")
def _to_bin(a, r, c, R, t):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """Pixel (r, c) of ``a`` in the bin frame: ``(p - t) @ R`` in float64."""
    dx = np.float64(a[r, c, 0]) - t[0]
    dy = np.float64(a[r, c, 1]) - t[1]
    dz = np.float64(a[r, c, 2]) - t[2]
    return (dx * R[0, 0] + dy * R[1, 0] + dz * R[2, 0],
            dx * R[0, 1] + dy * R[1, 1] + dz * R[2, 1],
            dx * R[0, 2] + dy * R[1, 2] + dz * R[2, 2])


@numba.njit(cache=True, inline="always")
def _straggler_delta(z, h, delta, s2, rad, top):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """The straggler test's distance bound at a pixel of camera depth ``z`` (m) and height ``h`` (m, bin frame):
    :func:`straggler_bound_m` with ``s2`` = σ_bin² (m²; negative: unknown, ``delta`` as it is), ``rad`` the pixel's
    angle and ``top`` the height above which no straggler is bounded (``delta`` as it is), the same operations in
    the same order."""
    if s2 < 0.0 or h > top:
        return delta
    c = abs(np.float64(z)) * rad
    err = max(_STRAGGLER_ERR_FLOOR_M, np.sqrt(s2 + 0.5 * c * c))
    return min(delta, STRAGGLER_ERRS * err)


@numba.njit(parallel=True, cache=True, nogil=True)
def _classify(a, fp, R, t, easy_above, test_bin, bin_first, origin, cell, dims, start, pts, nrm, off, delta,  # type: ignore[no-untyped-def]  # numba kernel
              radius, planes, valid, table, easy, binp):  # pragma: no cover - numba
    """Fill the (H, W) bool masks valid, table, easy, binp (zeroed) in one pass over the frame.

    ``bin_first`` (the robust mode): a point near the model is bin even above the rim's offset.
    """
    H, W = fp.shape
    for r in numba.prange(H):
        for c in range(W):
            if not (np.isfinite(a[r, c, 0]) and np.isfinite(a[r, c, 1]) and np.isfinite(a[r, c, 2])):
                continue
            valid[r, c] = True
            if not fp[r, c]:
                table[r, c] = True
                continue
            px, py, pz = _to_bin(a, r, c, R, t)
            if bin_first:
                if test_bin and _near_one(px, py, pz, origin, cell, dims, start, pts, nrm, off, delta, radius,
                                          planes):
                    binp[r, c] = True
                elif -pz > easy_above:
                    easy[r, c] = True
            elif -pz > easy_above:
                easy[r, c] = True
            elif test_bin:
                binp[r, c] = _near_one(px, py, pz, origin, cell, dims, start, pts, nrm, off, delta,
                                       radius, planes)


@numba.njit(parallel=True, cache=True, nogil=True)
def _straggler_start(valid, table, binp, easy, fp, neighbours, lab, open_, cand):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """One pass over the frame: ``lab`` (uint8: table, bin or invalid), ``open_`` (valid, in the
    footprint, neither easy nor bin) and ``cand`` (``open_`` with at least ``neighbours`` of its 8
    neighbours in ``lab``): the straggler test's first candidates in one pass, each count a sum of
    three column sums (no branch per neighbour; three numpy masks and a count per neighbour cost
    ~3x more)."""
    H, W = valid.shape
    for r in numba.prange(H):
        col = np.zeros(W + 2, np.int64)  # col[c + 1]: labelled pixels of column c in rows r-1..r+1
        for rr in range(max(r - 1, 0), min(r + 2, H)):
            for c in range(W):
                col[c + 1] += table[rr, c] | binp[rr, c] | (not valid[rr, c])
        for c in range(W):
            here = table[r, c] | binp[r, c] | (not valid[r, c])
            lab[r, c] = here
            o = valid[r, c] and fp[r, c] and not easy[r, c] and not binp[r, c]
            open_[r, c] = o
            cand[r, c] = o and col[c] + col[c + 1] + col[c + 2] - here >= neighbours


@numba.njit(parallel=True, cache=True, nogil=True)
def _test_pixels(a, flat, R, t, origin, cell, dims, start, pts, nrm, off, delta, radius,  # type: ignore[no-untyped-def]  # numba kernel
                 planes, s2, rad, top):  # pragma: no cover - numba
    """(M,) bool: the pixels ``flat`` (row-major indices) are within ``delta`` of the model, ``delta`` bounded at
    each pixel by :func:`_straggler_delta` with the frame's σ_bin² ``s2`` (< 0: not bounded) below ``top``."""
    W = a.shape[1]
    ok = np.zeros(flat.shape[0], np.bool_)
    for i in numba.prange(flat.shape[0]):
        r = flat[i] // W
        c = flat[i] - r * W
        px, py, pz = _to_bin(a, r, c, R, t)
        d = _straggler_delta(a[r, c, 2], -pz, delta, s2, rad, top)
        ok[i] = _near_one(px, py, pz, origin, cell, dims, start, pts, nrm, off, d, radius, planes)
    return ok


@numba.njit(cache=True, nogil=True)
def _next_candidates(new, lab, open_, seen, neighbours):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """Row-major indices of the ``open_`` neighbours of ``new`` with >= ``neighbours`` pixels in ``lab``.

    ``lab``, ``open_`` and ``seen`` are flat (H * W,) views of (H, W) arrays; ``seen`` is scratch,
    all False on entry and on exit.
    """
    H, W = open_.shape
    lab_f = lab.reshape(-1)
    open_f = open_.reshape(-1)
    seen_f = seen.reshape(-1)
    out = np.empty(8 * new.shape[0], np.int64)
    n = 0
    for p in new:
        r = p // W
        c = p - r * W
        for rr in range(max(r - 1, 0), min(r + 2, H)):
            for cc in range(max(c - 1, 0), min(c + 2, W)):
                q = rr * W + cc
                if open_f[q] and not seen_f[q]:
                    seen_f[q] = True
                    out[n] = q
                    n += 1
    keep = 0
    for i in range(n):
        q = out[i]
        seen_f[q] = False
        r = q // W
        c = q - r * W
        k = 0
        for rr in range(max(r - 1, 0), min(r + 2, H)):
            for cc in range(max(c - 1, 0), min(c + 2, W)):
                if (rr != r or cc != c) and lab_f[rr * W + cc]:
                    k += 1
        if k >= neighbours:
            out[keep] = q
            keep += 1
    return out[:keep]


@numba.njit(parallel=True, cache=True, nogil=True)
def _finish(a, valid, labelled, plane, floor, up, z_far, height, xyz_out):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """Height image (mm, NaN invalid) and float32 cloud with the labelled pixels' z on the floor.

    ``plane``: the floor is the plane {q : q . up = floor} (z solves x*ux + y*uy + z*uz = floor);
    else the constant ``z_far``.
    """
    H, W = valid.shape
    for r in numba.prange(H):
        for c in range(W):
            xyz_out[r, c, 0] = np.float32(a[r, c, 0])
            xyz_out[r, c, 1] = np.float32(a[r, c, 1])
            xyz_out[r, c, 2] = np.float32(a[r, c, 2])
            if not valid[r, c]:
                height[r, c] = np.nan
            elif labelled[r, c]:
                if plane:
                    zf = (floor - np.float64(a[r, c, 0]) * up[0] - np.float64(a[r, c, 1]) * up[1]) / up[2]
                else:
                    zf = z_far
                height[r, c] = -1000.0 * zf
                xyz_out[r, c, 2] = np.float32(zf)
            else:
                height[r, c] = -1000.0 * np.float64(a[r, c, 2])


# --- the fast path (issue 32): a class code per pixel, the model search skipping empty neighbourhoods and trying
# first the model point that passed for the previous pixel. The kernels above are the reference (reference=True).

#: The class codes of the fast path's (H, W) uint8 image.
_INVALID, _TABLE, _EASY, _BIN, _OPEN, _TRIED = 0, 1, 2, 3, 4, 5


@numba.njit(cache=True, inline="always")
def _near_hint(px, py, pz, origin, cell, dims, start, pts, nrm, off, ijk, busy, box, delta, radius, planes, hint):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """:func:`_near_one` as an index: a model point that passes (-1: none), the same answer.

    ``hint`` (a point that passed for a nearby pixel, or -1) is tried first, before any cell arithmetic:
    a point within the radius lies in one of the cells :func:`_near_one` searches (a cell is at least the
    radius wide, and its reach has a 1 nm margin for the rounding of the cell indices), so when the hint
    passes the answer "some point passes" is the same, whichever point is found. Else a cell whose
    neighbourhood holds no model point answers -1 at once, and a cell whose points' bounds (``box``) lie
    beyond the radius (with a relative margin of 1e-9 for the rounding) is skipped: none of its points is
    within it.
    """
    r2 = radius * radius
    if hint >= 0:
        d2 = _dist2(px, py, pz, pts, hint)
        if d2 <= r2:
            if planes:
                d = abs(nrm[hint, 0] * px + nrm[hint, 1] * py + nrm[hint, 2] * pz - off[hint])
            else:
                d = np.sqrt(d2)
            if d <= delta:
                return hint
    fx, fy, fz, ci, cj, ck = _cell_near(px, py, pz, origin, cell)
    if ci < 1 or cj < 1 or ck < 1 or ci > dims[0] - 2 or cj > dims[1] - 2 or ck > dims[2] - 2:
        return -1
    if not busy[(ci * dims[1] + cj) * dims[2] + ck]:
        return -1
    reach = radius + 1e-9
    x0, x1 = _reach(fx, ci, cell, reach)
    y0, y1 = _reach(fy, cj, cell, reach)
    z0, z1 = _reach(fz, ck, cell, reach)
    skip2 = r2 * (1.0 + 1e-9) + 1e-18
    # the point's own cell first, then along each axis the offsets 0, -1, +1: a point that passes is found
    # sooner (whichever is found, the answer is the same; the next pixels try it first as their hint)
    for kx in range(3):
        dx = -kx if kx < 2 else 1
        if dx < x0 or dx > x1:
            continue
        for ky in range(3):
            dy = -ky if ky < 2 else 1
            if dy < y0 or dy > y1:
                continue
            for kz in range(3):
                dz = -kz if kz < 2 else 1
                if dz < z0 or dz > z1:
                    continue
                c = ((ci + dx) * dims[1] + (cj + dy)) * dims[2] + (ck + dz)
                if start[c] == start[c + 1]:
                    continue
                bx = max(box[c, 0] - px, px - box[c, 3], 0.0)
                by = max(box[c, 1] - py, py - box[c, 4], 0.0)
                bz = max(box[c, 2] - pz, pz - box[c, 5], 0.0)
                if bx * bx + by * by + bz * bz > skip2:
                    continue
                for j in range(start[c], start[c + 1]):
                    d2 = _dist2(px, py, pz, pts, j)
                    if d2 > r2:
                        continue
                    if planes:
                        d = abs(nrm[j, 0] * px + nrm[j, 1] * py + nrm[j, 2] * pz - off[j])
                    else:
                        d = np.sqrt(d2)
                    if d <= delta:
                        return j
    return -1


@numba.njit(cache=True, inline="always")
def _class_of(px, py, pz, easy_above, test_bin, bin_first, origin, cell, dims, start, pts, nrm, off, ijk, busy, box,  # type: ignore[no-untyped-def]  # numba kernel
              delta, radius, planes, hint):  # pragma: no cover - numba
    """``(k, hint)``: the class code (``_EASY``, ``_BIN`` or ``_OPEN``) of a valid pixel in the footprint at
    (px, py, pz) (bin frame) as :func:`_classify` decides it, and the hint for the row's next pixel (the model point
    that passed, or ``hint`` as it was). ``bin_first`` (the robust mode): a point near the model is bin even above
    the rim's offset. The one decision of :func:`_classify_codes` and :func:`_classify_finish`."""
    k = _OPEN
    if bin_first:
        j = -1
        if test_bin:
            j = _near_hint(px, py, pz, origin, cell, dims, start, pts, nrm, off, ijk, busy, box, delta, radius, planes,
                           hint)
        if j >= 0:
            k = _BIN
            hint = j
        elif -pz > easy_above:
            k = _EASY
    elif -pz > easy_above:
        k = _EASY
    elif test_bin:
        j = _near_hint(px, py, pz, origin, cell, dims, start, pts, nrm, off, ijk, busy, box, delta, radius, planes,
                       hint)
        if j >= 0:
            k = _BIN
            hint = j
    return k, hint


@numba.njit(parallel=True, cache=True, nogil=True)
def _classify_codes(a, fp, R, t, easy_above, test_bin, bin_first, origin, cell, dims, start, pts, nrm, off,  # type: ignore[no-untyped-def]  # numba kernel
                    ijk, busy, box, delta, radius, planes, code):  # pragma: no cover - numba
    """:func:`_classify` into one (H, W) uint8 image of class codes (``_INVALID`` .. ``_OPEN``)."""
    H, W = fp.shape
    for r in numba.prange(H):
        hint = -1
        for c in range(W):
            if not (np.isfinite(a[r, c, 0]) and np.isfinite(a[r, c, 1]) and np.isfinite(a[r, c, 2])):
                code[r, c] = _INVALID
                continue
            if not fp[r, c]:
                code[r, c] = _TABLE
                continue
            px, py, pz = _to_bin(a, r, c, R, t)
            k, hint = _class_of(px, py, pz, easy_above, test_bin, bin_first, origin, cell, dims, start, pts, nrm, off,
                                ijk, busy, box, delta, radius, planes, hint)
            code[r, c] = k


@numba.njit(parallel=True, cache=True, nogil=True)
def _classify_finish(a, fp, R, t, easy_above, test_bin, bin_first, origin, cell, dims, start, pts, nrm, off,  # type: ignore[no-untyped-def]  # numba kernel
                     ijk, busy, box, delta, radius, planes, floor, up, code, table, easy, binp, zone, height):  # pragma: no cover - numba
    """:func:`_classify_codes` and :func:`_finish_codes` (the floor a plane) in one pass over the frame: each pixel's
    class code, its four class masks and its height as :func:`_finish_codes` writes them from that code, while the
    pixel's point is at hand (the frame is read once, not twice: 27.6 MB at 1920 x 1200). Returns the zone's highest
    height row by row, ``(seen, nan, top)``, as :func:`_finish_codes` does. The straggler test then labels a few
    open pixels bin: :func:`_relabel_bin` moves them out of the zone."""
    H, W = fp.shape
    seen = np.zeros(H, np.bool_)
    nan = np.zeros(H, np.bool_)
    top = np.full(H, -np.inf)
    for r in numba.prange(H):
        hint = -1
        m = -np.inf
        for c in range(W):
            if not (np.isfinite(a[r, c, 0]) and np.isfinite(a[r, c, 1]) and np.isfinite(a[r, c, 2])):
                code[r, c] = _INVALID
                table[r, c] = False
                easy[r, c] = False
                binp[r, c] = False
                zone[r, c] = False
                height[r, c] = np.nan
                continue
            if not fp[r, c]:
                code[r, c] = _TABLE
                table[r, c] = True
                easy[r, c] = False
                binp[r, c] = False
                zone[r, c] = False
                zf = (floor - np.float64(a[r, c, 0]) * up[0] - np.float64(a[r, c, 1]) * up[1]) / up[2]
                height[r, c] = -1000.0 * zf
                continue
            px, py, pz = _to_bin(a, r, c, R, t)
            k, hint = _class_of(px, py, pz, easy_above, test_bin, bin_first, origin, cell, dims, start, pts, nrm, off,
                                ijk, busy, box, delta, radius, planes, hint)
            code[r, c] = k
            table[r, c] = False
            easy[r, c] = k == _EASY
            binp[r, c] = k == _BIN
            zone[r, c] = k == _OPEN
            if k == _OPEN:
                v = -1000.0 * np.float64(a[r, c, 2])
                height[r, c] = v
                seen[r] = True
                if np.isnan(v):
                    nan[r] = True
                elif v > m:
                    m = v
            else:
                zf = (floor - np.float64(a[r, c, 0]) * up[0] - np.float64(a[r, c, 1]) * up[1]) / up[2]
                height[r, c] = -1000.0 * zf
        top[r] = m
    return seen, nan, top


@numba.njit(cache=True, nogil=True)
def _relabel_bin(a, done, floor, up, binp, zone, height, seen, nan, top):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """The pixels ``done`` (flat indices) that the straggler test labelled bin after :func:`_classify_finish`: bin,
    out of the zone, their height the floor's (the plane's expression of :func:`_finish_codes`). A row whose zone
    may have lost its highest pixel (one of them had the row's top height, or NaN) has its ``(seen, nan, top)``
    scanned again as :func:`_finish_codes` scans it; in the other rows the top pixel is still in the zone and the
    row's values stand."""
    H, W = zone.shape
    again = np.zeros(H, np.bool_)
    for p in done:
        r = p // W
        c = p - r * W
        v = height[r, c]
        if np.isnan(v) or v == top[r]:
            again[r] = True
        binp[r, c] = True
        zone[r, c] = False
        zf = (floor - np.float64(a[r, c, 0]) * up[0] - np.float64(a[r, c, 1]) * up[1]) / up[2]
        height[r, c] = -1000.0 * zf
    for r in range(H):
        if again[r]:
            s = False
            n = False
            m = -np.inf
            for c in range(W):
                if zone[r, c]:
                    s = True
                    v = height[r, c]
                    if np.isnan(v):
                        n = True
                    elif v > m:
                        m = v
            seen[r] = s
            nan[r] = n
            top[r] = m


@numba.njit(cache=True, inline="always")
def _labelled_around(code, r, c, H, W):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """How many of the 8 neighbours of (r, c) in the image are table, bin or invalid."""
    k = 0
    for rr in range(max(r - 1, 0), min(r + 2, H)):
        for cc in range(max(c - 1, 0), min(c + 2, W)):
            if rr != r or cc != c:
                v = code[rr, cc]
                if v == _INVALID or v == _TABLE or v == _BIN:
                    k += 1
    return k


@numba.njit(cache=True, inline="always")
def _straggler_one(a, code, r, c, R, t, origin, cell, dims, start, pts, nrm, off, ijk, busy, box, delta, radius,  # type: ignore[no-untyped-def]  # numba kernel
                   planes, s2, rad, top, hint, row):  # pragma: no cover - numba
    """The straggler test of the candidate (r, c) (:func:`_straggler_first`'s), marked tried in ``code``: ``row[c]`` = 2
    when it passes. Returns the model point that passed (-1: none; the hint for the row's next candidate)."""
    code[r, c] = _TRIED
    px, py, pz = _to_bin(a, r, c, R, t)
    j = _near_hint(px, py, pz, origin, cell, dims, start, pts, nrm, off, ijk, busy, box,
                   _straggler_delta(a[r, c, 2], -pz, delta, s2, rad, top), radius, planes, hint)
    if j >= 0:
        row[c] = 2
    return j


@numba.njit(parallel=True, cache=True, nogil=True)
def _straggler_first(a, code, neighbours, R, t, origin, cell, dims, start, pts, nrm, off, ijk, busy, box, delta, radius,  # type: ignore[no-untyped-def]  # numba kernel
                     planes, s2, rad, top, first):  # pragma: no cover - numba
    """The straggler test's first pass in one pass over the frame: ``first`` (uint8) is 1 at
    :func:`_straggler_start`'s candidates (open pixels with >= ``neighbours`` labelled ones) that fail the test,
    2 at those that pass, 0 elsewhere; returns how many passed, row by row. Every candidate is judged on the
    labels before the pass, as the reference's first pass judges them: ``code`` changes only from open to tried
    (each candidate, in its own row's turn), which no count reads (an open or tried pixel is not labelled). The
    counts are :func:`_labelled_around`'s, as sums of three column sums of the row and its two neighbours (an open
    pixel is not labelled itself), each of the row's three loops free of branches but the last, over its few
    candidates, read eight pixels at a time: so they vectorize (a branch per pixel on its class, or per neighbour,
    cost 6.3 of the pass's 9.4 CPU ms at 1920 x 1200; now 0.6). ``delta`` is bounded at each pixel by
    :func:`_straggler_delta` (``s2``, ``rad``, ``top``)."""
    H, W = code.shape
    passed = np.zeros(H, np.int64)
    for r in numba.prange(H):
        col = np.zeros(W + 2, np.uint8)  # col[c + 1]: labelled pixels of column c in rows r-1..r+1
        for rr in range(max(r - 1, 0), min(r + 2, H)):
            for c in range(W):
                v = code[rr, c]
                col[c + 1] += (v == _INVALID) | (v == _TABLE) | (v == _BIN)
        for c in range(W):
            first[r, c] = (code[r, c] == _OPEN) & (col[c] + col[c + 1] + col[c + 2] >= neighbours)
        hint = -1
        n = 0
        row = first[r]
        if W % 8 == 0:  # the row's candidates (a few percent of it) looked for eight pixels at a time
            words = row.view(np.uint64)
            for w in range(W // 8):
                if words[w] != 0:
                    for c in range(8 * w, 8 * w + 8):
                        if row[c]:
                            j = _straggler_one(a, code, r, c, R, t, origin, cell, dims, start, pts, nrm, off, ijk,
                                               busy, box, delta, radius, planes, s2, rad, top, hint, row)
                            if j >= 0:
                                hint = j
                                n += 1
        else:
            for c in range(W):
                if row[c]:
                    j = _straggler_one(a, code, r, c, R, t, origin, cell, dims, start, pts, nrm, off, ijk, busy, box,
                                       delta, radius, planes, s2, rad, top, hint, row)
                    if j >= 0:
                        hint = j
                        n += 1
        passed[r] = n
    return passed


@numba.njit(cache=True, nogil=True)
def _straggler_rest(a, code, words, neighbours, passes, R, t, origin, cell, dims, start, pts, nrm, off, ijk, busy, box,  # type: ignore[no-untyped-def]  # numba kernel
                    delta, radius, planes, s2, rad, top):  # pragma: no cover - numba
    """The first pass's outcome (``first``) into ``code``, then the passes after it (up to ``passes`` in
    all), each testing the open neighbours of the pixels the previous one labelled (serial: a few
    pixels each; a parallel launch would cost more than them). ``words``: ``first`` as 64-bit words (eight
    pixels each, zero-padded), read a word at a time: the candidates are a few percent of the frame. Returns the
    pixels labelled bin (flat indices, each once; for :func:`_relabel_bin`)."""
    cf = code.reshape(-1)
    ff = words.view(np.uint8)
    n = 0
    for w in range(words.shape[0]):
        if words[w] != 0:
            for q in range(8 * w, 8 * w + 8):
                n += ff[q] == 2
    new = np.empty(n, np.int64)
    n = 0
    for w in range(words.shape[0]):
        if words[w] != 0:
            for q in range(8 * w, 8 * w + 8):
                if ff[q]:
                    cf[q] = _TRIED
                    if ff[q] == 2:
                        new[n] = q
                        n += 1
    W = code.shape[1]
    done = new.copy()  # every pixel labelled bin: the first pass's, then each later pass's appended
    n_done = n
    for _ in range(passes - 1):
        if new.shape[0] == 0:
            break
        cand = _grow_codes(new, code, neighbours)
        if cand.shape[0] == 0:
            break
        ok = np.zeros(cand.shape[0], np.bool_)
        hint = -1
        for i in range(cand.shape[0]):
            q = cand[i]
            cf[q] = _TRIED
            r = q // W
            c = q - r * W
            px, py, pz = _to_bin(a, r, c, R, t)
            j = _near_hint(px, py, pz, origin, cell, dims, start, pts, nrm, off, ijk, busy, box,
                           _straggler_delta(a[r, c, 2], -pz, delta, s2, rad, top), radius, planes, hint)
            if j >= 0:
                ok[i] = True
                hint = j
        new = cand[ok]
        if n_done + new.shape[0] > done.shape[0]:
            grown = np.empty(max(2 * done.shape[0], n_done + new.shape[0]), np.int64)
            grown[:n_done] = done[:n_done]
            done = grown
        done[n_done:n_done + new.shape[0]] = new
        n_done += new.shape[0]
    if new.shape[0]:
        for p in new:
            cf[p] = _BIN
    return done[:n_done]


@numba.njit(cache=True, nogil=True)
def _grow_codes(new, code, neighbours):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """Label ``new`` bin in ``code`` and return :func:`_next_candidates` of them, marked tried."""
    H, W = code.shape
    cf = code.reshape(-1)
    for p in new:
        cf[p] = _BIN
    out = np.empty(8 * new.shape[0], np.int64)
    n = 0
    for p in new:
        r = p // W
        c = p - r * W
        for rr in range(max(r - 1, 0), min(r + 2, H)):
            for cc in range(max(c - 1, 0), min(c + 2, W)):
                q = rr * W + cc
                if cf[q] == _OPEN:
                    cf[q] = _TRIED  # listed once; tried below or never (too few labelled neighbours: reset)
                    out[n] = q
                    n += 1
    keep = 0
    for i in range(n):
        q = out[i]
        cf[q] = _OPEN
    for i in range(n):
        q = out[i]
        r = q // W
        c = q - r * W
        if _labelled_around(code, r, c, H, W) >= neighbours:
            out[keep] = q
            keep += 1
    return np.sort(out[:keep])


@numba.njit(parallel=True, cache=True, nogil=True)
def _finish_codes(a, code, plane, floor, up, z_far, table, easy, binp, zone, height):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """:func:`_finish` from the class codes, writing the four class masks too (the valid pixels, their union, are
    not kept: not written) but not the cloud (no stage reads it: :class:`FlooredCloud` writes it when it is asked
    for, as :func:`_floored_cloud`); returns the zone's highest height
    row by row, ``(seen, nan, top)`` (H,) each, as :func:`zcut.bin_check._zone_top` scans it (:func:`_zone_top_of`)."""
    H, W = code.shape
    seen = np.zeros(H, np.bool_)
    nan = np.zeros(H, np.bool_)
    top = np.full(H, -np.inf)
    for r in numba.prange(H):
        m = -np.inf
        for c in range(W):
            k = code[r, c]
            table[r, c] = k == _TABLE
            easy[r, c] = k == _EASY
            binp[r, c] = k == _BIN
            zone[r, c] = k == _OPEN or k == _TRIED
            if k == _INVALID:
                height[r, c] = np.nan
            elif k == _TABLE or k == _EASY or k == _BIN:
                if plane:
                    zf = (floor - np.float64(a[r, c, 0]) * up[0] - np.float64(a[r, c, 1]) * up[1]) / up[2]
                else:
                    zf = z_far
                height[r, c] = -1000.0 * zf
            else:
                v = -1000.0 * np.float64(a[r, c, 2])
                height[r, c] = v
                if k == _OPEN or k == _TRIED:  # the zone: its top, as _zone_top takes it
                    seen[r] = True
                    if np.isnan(v):
                        nan[r] = True
                    elif v > m:
                        m = v
        top[r] = m
    return seen, nan, top


@numba.njit(parallel=True, cache=True, nogil=True)
def _floored_cloud(a, table, easy, binp, plane, floor, up, z_far, xyz_out):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """The float32 cloud of :func:`_finish` (the labelled pixels' z on the floor, the same expression), from the
    three labelled classes' masks."""
    H, W = table.shape
    for r in numba.prange(H):
        for c in range(W):
            xyz_out[r, c, 0] = np.float32(a[r, c, 0])
            xyz_out[r, c, 1] = np.float32(a[r, c, 1])
            if table[r, c] or easy[r, c] or binp[r, c]:
                if plane:
                    zf = (floor - np.float64(a[r, c, 0]) * up[0] - np.float64(a[r, c, 1]) * up[1]) / up[2]
                else:
                    zf = z_far
                xyz_out[r, c, 2] = np.float32(zf)
            else:
                xyz_out[r, c, 2] = np.float32(a[r, c, 2])


@numba.njit(cache=True, nogil=True)
def _zone_top_of(seen, nan, top):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """``(any zone pixel, the zone's highest height)`` from the rows' (NaN when some zone pixel's height is NaN, as
    ``np.max``): the rows' maxima taken in order, the first of equal ones kept."""
    best = -np.inf
    for r in range(top.shape[0]):
        if top[r] > best:
            best = top[r]
    return seen.any(), (np.nan if nan.any() else best)


@dataclass(frozen=True, slots=True)
class _ZoneTop:
    """The zone's highest height as the fast removal wrote it (:func:`_finish_codes`), for the bin check: valid for
    these very ``zone`` and ``height`` arrays (a result rebuilt with others measures again)."""

    zone: Mask
    height: np.ndarray
    seen: bool
    top: float


def _straggler_codes(a: np.ndarray, code: np.ndarray, R: np.ndarray, t: np.ndarray, index: _ModelIndex, *,
                     straggler_m: float, radius_m: float, planes: bool, neighbours: int,
                     bound: tuple[float, float, float]) -> np.ndarray:
    """:func:`_straggler_passes` on the class codes (in place): the same passes, each testing only the open
    neighbours of the pixels the previous one labelled. Returns the pixels it labelled bin (flat indices)."""
    grid = (*_grid_args(index), index.ijk, index.busy, index.box, float(straggler_m), float(radius_m), planes,
            *bound)
    n = code.size
    buf = np.empty(n + (-n % 8), np.uint8)  # ``first``, padded to whole 64-bit words
    buf[n:] = 0
    if not _straggler_first(a, code, neighbours, R, t, *grid, buf[:n].reshape(code.shape)).any():
        return np.zeros(0, np.int64)  # none passed: no later pass (the first marked its candidates tried)
    return _straggler_rest(a, code, buf.view(np.uint64), neighbours, STRAGGLER_PASSES, R, t, *grid)


@numba.njit(cache=True, nogil=True, inline="always")
def _scan_cells(px, py, pz, start, pts, dims, a0, a1, b0, b1, c0, c1, best, second, jb):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """The points of the cells [a0, a1] x [b0, b1] x [c0, c1] (clipped to the grid) into the running
    ``(best, second, jb)`` of :func:`_nearest_grid` (squared distances, the best point's sorted row).

    The running values are kept without branches (a point's distance against the best is a coin toss, and a
    mispredicted branch cost more than the point): ``jb`` moves to a point strictly nearer than ``best``,
    ``second`` becomes ``min(second, max(d2, best))`` (the old best when the point beats it, else the smaller of
    the old second and the point's), ``best`` the smaller: the values the branches gave, the model's points
    being finite and the query's too."""
    z0 = max(c0, 0)
    z1 = min(c1, dims[2] - 1)
    if z0 > z1:
        return best, second, jb
    for a in range(max(a0, 0), min(a1, dims[0] - 1) + 1):
        for b in range(max(b0, 0), min(b1, dims[1] - 1) + 1):
            base = (a * dims[1] + b) * dims[2]
            for j in range(start[base + z0], start[base + z1 + 1]):
                d2 = _dist2(px, py, pz, pts, j)
                jb = j if d2 < best else jb
                second = min(second, max(d2, best))
                best = min(best, d2)
    return best, second, jb


@numba.njit(cache=True, nogil=True, inline="always")
def _ball_radius(b2):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """The radius searched around a point with a model point at squared distance ``b2``: sqrt(b2) with a relative
    4e-9 and 1e-9 and 1 pm of margin (every point at most as near, and every one within a relative 1e-9 of the
    nearest, lies within it, whatever the rounding of the cell coordinates)."""
    return np.sqrt(b2 * (1.0 + 4e-9)) * (1.0 + 1e-9) + 1e-12


#: :func:`_nearest_grid` runs its rows in blocks of this many, in order within a block (each row's search
#: starts from the previous row's nearest point).
_NEAREST_BLOCK = 64


@numba.njit(parallel=True, cache=True, nogil=True)
def _nearest_grid(p, origin, cell, dims, start, pts, empty_to, order, ub):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """Nearest model point of each row of ``p`` (M, 3) within ``ub`` as ``cKDTree.query`` finds it.

    Returns ``(d, j, unsure)``: the distance (computed as the tree computes it: the square root of the
    three squared differences summed in order; +inf when no point lies within ``ub``), the point (the
    model's index, ``order``; ``len(order)`` for none, as the tree says) and whether the answer may differ from the tree's (another point within a
    relative 1e-9 of the same distance, or the distance within that of ``ub``: the tree's visiting
    order or its pruning's rounding could decide; those rows are left to the tree).

    Every search below rests on one argument: with a model point at squared distance b0 from the row's point,
    every point at most as near, and every one within a relative 1e-9 of the best (all that ``unsure`` looks
    at), lies within the ball of :func:`_ball_radius` (b0), so cells that ball does not reach need not be read,
    and the searches give the same ``best`` and, for ``unsure``, the same answer to "is the second within a
    relative 1e-9 of it".

    1. The block: the 2 x 2 x 2 cells around the point (along each axis its own cell and the neighbour on the
       nearer side: the point lies at least half a cell inside the block). When the nearest of the block's points
       has its ball within the block's faces, the block held every point the ball holds: that is the answer
       (~90 % of a ring's pixels, whose nearest model point lies a fraction of a cell away).
    2. Else the ball: rows come in blocks of :data:`_NEAREST_BLOCK`, in order within a block; the bound b0 is the
       nearest of the block's, of the previous row's nearest point (the pixels of a ring, in image order, lie a
       fraction of a cell apart) and, when the ball is still a cell wide, of the point's own cell; when the ball is
       narrower than a cell, only the cells it reaches along each axis are searched (4-8 of the 27).
    3. Else, or when that finds nothing at most as near, the cells are searched shell by shell around the
       point's, from the first that holds a point (``empty_to``), until the next shell lies farther than the best.

    Step 1 and the branch-free scans (:func:`_scan_cells`) took 3.8 -> 2.6 CPU ms on 45k ring pixels at 640 x 480,
    9.8 -> 6.0 on 96k at 1920 x 1200 (the ball alone: 6.6 -> 4.4 and 12.9 -> 9.9 before).
    """
    M = p.shape[0]
    d_out = np.full(M, np.inf)
    j_out = np.full(M, order.shape[0], np.int64)
    unsure = np.zeros(M, np.bool_)
    ub2 = ub * ub
    K = int(np.ceil(ub / cell)) + 2
    for blk in numba.prange((M + _NEAREST_BLOCK - 1) // _NEAREST_BLOCK):
        hint = -1
        for i in range(blk * _NEAREST_BLOCK, min(M, (blk + 1) * _NEAREST_BLOCK)):
            px = p[i, 0]
            py = p[i, 1]
            pz = p[i, 2]
            fx, fy, fz, ci, cj, ck = _cell_near(px, py, pz, origin, cell)
            inside = 0 <= ci < dims[0] and 0 <= cj < dims[1] and 0 <= ck < dims[2]
            best = np.inf
            second = np.inf
            jb = -1
            done = False
            if 1 <= ci < dims[0] - 1 and 1 <= cj < dims[1] - 1 and 1 <= ck < dims[2] - 1:  # 1. the block
                ax = ci - 1 if fx - ci < 0.5 else ci
                ay = cj - 1 if fy - cj < 0.5 else cj
                az = ck - 1 if fz - ck < 0.5 else ck
                best, second, jb = _scan_cells(px, py, pz, start, pts, dims, ax, ax + 1, ay, ay + 1, az, az + 1,
                                               best, second, jb)
                rb = _ball_radius(best)
                done = (rb < (fx - ax) * cell and rb < (ax + 2 - fx) * cell and rb < (fy - ay) * cell
                        and rb < (ay + 2 - fy) * cell and rb < (fz - az) * cell and rb < (az + 2 - fz) * cell)
            if inside and not done:  # 2. the ball
                b0 = best
                best = np.inf
                second = np.inf
                jb = -1
                if hint >= 0:
                    b0 = min(b0, _dist2(px, py, pz, pts, hint))
                rb = _ball_radius(b0)
                if not rb < cell:  # the nearest of the point's own cell, if nearer
                    c = (ci * dims[1] + cj) * dims[2] + ck
                    for jj in range(start[c], start[c + 1]):
                        b0 = min(b0, _dist2(px, py, pz, pts, jj))
                    rb = _ball_radius(b0)
                if rb < cell:  # the ball reaches the neighbouring cells at most
                    x0, x1 = _reach(fx, ci, cell, rb)
                    y0, y1 = _reach(fy, cj, cell, rb)
                    z0, z1 = _reach(fz, ck, cell, rb)
                    best, second, jb = _scan_cells(px, py, pz, start, pts, dims, ci + x0, ci + x1, cj + y0, cj + y1,
                                                   ck + z0, ck + z1, best, second, jb)
                    done = best <= b0
            if not done:  # 3. the shells
                best = np.inf
                second = np.inf
                jb = -1
                k0 = 0  # the shells nearer than the nearest occupied cell are empty
                if inside:
                    k0 = min(int(empty_to[(ci * dims[1] + cj) * dims[2] + ck]), K + 1)
                for k in range(k0, K + 1):
                    if k >= 2:
                        gap = (k - 1) * cell * (1.0 - 1e-9)  # every cell of shell k lies at least this far
                        g2 = gap * gap
                        if g2 > ub2 * (1.0 + 1e-6) or g2 > best * (1.0 + 1e-6):
                            break
                    for a in range(ci - k, ci + k + 1):
                        if a < 0 or a >= dims[0]:
                            continue
                        for b in range(cj - k, cj + k + 1):
                            if b < 0 or b >= dims[1]:
                                continue
                            if a == ci - k or a == ci + k or b == cj - k or b == cj + k:  # the shell's whole column
                                best, second, jb = _scan_cells(px, py, pz, start, pts, dims, a, a, b, b, ck - k,
                                                               ck + k, best, second, jb)
                            else:  # its two ends
                                best, second, jb = _scan_cells(px, py, pz, start, pts, dims, a, a, b, b, ck - k,
                                                               ck - k, best, second, jb)
                                if k > 0:
                                    best, second, jb = _scan_cells(px, py, pz, start, pts, dims, a, a, b, b, ck + k,
                                                                   ck + k, best, second, jb)
            if jb >= 0:
                hint = jb
            if best < ub2:
                d_out[i] = np.sqrt(best)
                j_out[i] = order[jb]
            unsure[i] = best < np.inf and (second <= best * (1.0 + 1e-9) or abs(best - ub2) <= ub2 * 1e-9)
    return d_out, j_out, unsure


def _grid_args(index: _ModelIndex) -> tuple[np.ndarray, float, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    return (index.origin, index.cell, index.dims, index.start, index.points, index.normals, index.offsets)


def _straggler_passes(a: np.ndarray, binp: Mask, lab: np.ndarray, open_: Mask, R: np.ndarray,
                      t: np.ndarray, index: _ModelIndex, *, straggler_m: float, radius_m: float,
                      planes: bool, neighbours: int, first: Mask, bound: tuple[float, float, float]) -> None:
    """Grow ``binp`` (in place) along the noisy bin surface, see ``straggler_m``.

    ``lab`` (uint8: table, bin or invalid) and ``open_`` (allowed, not bin, not yet tried) are
    updated too. Pass 1 tests ``first``, the open pixels with enough labelled neighbours
    (:func:`_straggler_start`); later passes only at the neighbours of the pixels the previous
    pass labelled (no other pixel's count of labelled neighbours changed, and a pixel once tested
    is not tested again: its distance to the model does not change).
    """
    grid = _grid_args(index)
    cand = np.flatnonzero(first)
    seen = np.zeros_like(open_)
    binp_f, lab_f, open_f = binp.reshape(-1), lab.reshape(-1), open_.reshape(-1)
    for _ in range(STRAGGLER_PASSES):
        if cand.size == 0:
            break
        open_f[cand] = False
        near = _test_pixels(a, cand, R, t, *grid, float(straggler_m), float(radius_m), planes, *bound)
        new = cand[near]
        if new.size == 0:
            break
        binp_f[new] = True
        lab_f[new] = 1
        cand = _next_candidates(new, lab, open_, seen, neighbours)


#: The residuals of :func:`frame_tolerance` are measured on at most this many certain bin pixels (a
#: regular subsample, each with its four neighbours): their percentile moves by less than 0.05 mm
#: from 20,000 to all 120,000 of a 1920 x 1200 frame.
MAX_RESIDUAL_PX = 20_000
#: A residual is *coherent* with its neighbours' (it lies on the surface they form) when it is
#: finite and within this many millimetres of the median of its certain-bin neighbours' residuals.
#: The bin surface's residuals vary smoothly (the sensor's noise, about 0.3 mm, and a pose error,
#: which changes them by hundredths of a millimetre per pixel); a sensor's ghost above the rim or
#: beside an edge lies millimetres off the surface its neighbours form. See ``docs/bin_robustness.md``.
COHERENCE_MM = 1.0
#: τ falls back to the percentile of all the residuals (ghosts included) when fewer than this share
#: of the measured pixels are coherent: then the residuals are not a surface's (a pose far off).
MIN_COHERENT_SHARE = 0.5
#: ... and when more than this share of them lie beyond ``max_tolerance_mm`` of the model with every
#: neighbour beyond it too (a far surface, not scattered ghosts): then the bin's own surface lies
#: that far (a pose or a model far off; the ray-traced ghost clusters are about 1 % of the certain
#: bin pixels on sphere frames). The bin check flags such a frame.
MAX_FAR_SHARE = 0.2
#: The residual field's fit (:func:`fit_residual_field`) is trimmed this many times (each keeps the rows
#: within 3 robust sigmas).
FIELD_TRIMS = 3
#: ... and needs at least this many certain bin pixels with a model point within ``max_tolerance_mm``.
FIELD_MIN_PX = 50
_N4 = ((-1, 0), (1, 0), (0, -1), (0, 1))
_N8 = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


@dataclass(frozen=True, slots=True)
class Tolerance:
    """The robust mode's tolerance of one frame (:func:`frame_tolerance`).

    Attributes
    ----------
    tolerance_mm : float
        τ: the coherent residuals' percentile plus the margin, within the bounds.
    residual_mm : float
        The percentile τ was derived from (mm): of the coherent residuals, or, when fewer than
        :data:`MIN_COHERENT_SHARE` of them are coherent, of all of them (+inf when more pixels than
        the percentile leaves out have no model point within ``max_tolerance_mm``); NaN when there
        was no pixel to measure.
    n_pixels : int
        Certain bin pixels measured.
    n_coherent : int
        Of those, the ones whose residual is coherent with their neighbours' (:data:`COHERENCE_MM`).
    reach_mm : float
        The search radius the bin test needs (mm): the ``residual_quantile`` percentile of the same
        pixels' distances to their nearest model point plus ``residual_margin_mm``, at most
        ``max_tolerance_mm``. The test looks for a model point within its search radius before it
        measures the distance along that point's normal: where the model is sampled more coarsely
        than ``1.5 × spacing_m`` (a model built from a few low-resolution scans: up to 4.4 mm between
        a 200 × 150 frame's rim pixels and the nearest point of a model from two 200 × 150 empty
        scans, whose median spacing is 1.55 mm), a pixel on the bin's surface finds none and stays
        in the zone. NaN when not measured (no pixel, a fixed τ, or a model without normals, whose
        residuals are these distances already).
    surface : optional
        The fast path's :func:`surface_residuals` of the frame (None from the reference or a fixed τ).
    n_off_field : int
        Of the coherent pixels, those left out of the percentile because they and the surface their ring
        neighbours form lie off the registered bin's residual field (:func:`off_field`: the faces of parts
        leaning on a wall); 0 when the field could not be fitted.
    sigma_mm : float
        σ_bin, the bin's residual scale: 1.4826 × the median of the residuals τ's percentile was taken over
        (:func:`bin_sigma_m`, in mm); NaN when τ was not measured (fixed, no ring pixel). With :attr:`pixel_rad`
        it bounds the straggler test at 3 × the bin's Err (:func:`straggler_bound_m`); +inf (no bound) when most
        of the pixels have no model point within ``max_tolerance_mm``.
    pixel_rad : float
        The angle one pixel subtends (rad, 1 / f, f the focal length in pixels): a pixel's footprint at depth z is
        ``z * pixel_rad`` (:func:`pixel_angle`, from the measured pixels and their neighbours); NaN when
        :attr:`sigma_mm` is (not measured) or no pair of neighbours gives it.
    """

    tolerance_mm: float
    residual_mm: float
    n_pixels: int
    n_coherent: int = 0
    reach_mm: float = float("nan")
    surface: _Surface | None = None
    n_off_field: int = 0
    sigma_mm: float = float("nan")
    pixel_rad: float = float("nan")


@dataclass(frozen=True, slots=True)
class _Surface:
    """:func:`surface_residuals` of ``xyz`` and ``ring`` with ``index`` at pose ``T``, as :func:`frame_tolerance`
    measured them (the bin check reads them from the removal, :attr:`RemovalResult.surface`)."""

    xyz: np.ndarray
    ring: Mask
    index: RemovalIndex
    T: np.ndarray
    residuals: np.ndarray
    around: np.ndarray
    coherent: np.ndarray
    #: the tree's query of the sample and its ring neighbours (the bin check's residual field reads its nearest
    #: model points, :func:`surface_nearest`)
    queried: _Queried | None = None


def _nearest_mm(a: np.ndarray, flat: np.ndarray, index: RemovalIndex, T: np.ndarray) -> np.ndarray:
    """(len(flat),) float64: the distance (mm) of each pixel ``flat`` to its nearest model point; +inf
    where the point is not finite or no model point lies within ``max_tolerance_mm``."""
    out = np.full(len(flat), np.inf)
    if len(flat) == 0 or len(index.model.points) == 0:
        return out
    pts = a.reshape(-1, 3)[flat].astype(np.float64)
    ok = np.isfinite(pts).all(axis=1)
    p_bin = (pts[ok] - T[:3, 3]) @ T[:3, :3]
    tree = index.tree
    assert tree is not None  # prepare_removal_index builds it in both modes
    d, _ = tree.query(p_bin, k=1, distance_upper_bound=index.params.max_tolerance_mm / 1000.0)
    out[ok] = d * 1000.0
    return out


def _residuals_of(a: np.ndarray, flat: np.ndarray, index: RemovalIndex, T: np.ndarray) -> np.ndarray:
    """(len(flat),) float64: residuals (mm) of the pixels ``flat`` (flat indices into ``a``'s image);
    +inf where the point is not finite or no model point lies within ``max_tolerance_mm``."""
    out = np.full(len(flat), np.inf)
    model = index.model
    if len(flat) == 0 or len(model.points) == 0:
        return out
    pts = a.reshape(-1, 3)[flat].astype(np.float64)
    ok = np.isfinite(pts).all(axis=1)
    p_bin = (pts[ok] - T[:3, 3]) @ T[:3, :3]
    reach = index.params.max_tolerance_mm / 1000.0
    tree = index.tree
    assert tree is not None  # prepare_removal_index builds it in both modes
    d, j = tree.query(p_bin, k=1, distance_upper_bound=reach)
    found = np.isfinite(d)
    r = np.full(len(p_bin), np.inf)
    if model.normals is None:
        r[found] = d[found]
    else:
        jj = j[found]
        r[found] = np.abs(np.einsum("ij,ij->i", p_bin[found] - model.points[jj], model.normals[jj]))
    out[ok] = r * 1000.0
    return out


def coherent_residuals(xyz: XYZ, ring: Mask, pixels: np.ndarray, index: RemovalIndex, T_cam_bin: np.ndarray, *,
                       neighbours: int = 8, reference: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals of ``pixels`` to the model and whether each is coherent with its neighbours'.

    Parameters
    ----------
    xyz : (H, W, 3) float ndarray
    ring : (H, W) bool ndarray
        The certain bin pixels: the neighbours looked at are these (the bin surface around).
    pixels : (M,) int ndarray
        Flat indices of the pixels to judge.
    index : RemovalIndex
    T_cam_bin : (4, 4) float ndarray
    neighbours : {4, 8}
    reference : bool
        The previous implementation (``np.unique``, ``np.nanmedian``), the oracle of the tests: the same
        arrays.

    Returns
    -------
    residuals : (M,) float64 ndarray
        mm; +inf where no model point lies within ``max_tolerance_mm``.
    around : (M,) float64 ndarray
        The median of the finite residuals of the pixel's ring neighbours (ghosts among them do not
        move it); +inf when none of them is finite, NaN for a pixel with no ring neighbour.
    coherent : (M,) bool ndarray
        The residual is finite and within :data:`COHERENCE_MM` of ``around`` (an infinite one never
        is: ray-traced ghosts above the rim come in clusters whose neighbours are ghosts too).
    """
    if index.tree is None:
        raise ParameterError("coherent_residuals: the index has no KD-tree (prepare_removal_index builds it)")
    a = np.asarray(xyz)
    pixels = np.asarray(pixels, dtype=np.int64)
    nb = _ring_neighbours(a.shape[:2], ring, pixels, neighbours)
    own, around, coherent, _ = _coherent(a, pixels, nb, index, np.asarray(T_cam_bin, dtype=np.float64),
                                         reference=reference)
    return own, around, coherent


def _ring_neighbours(shape: tuple[int, ...], ring: Mask, pixels: np.ndarray, neighbours: int) -> np.ndarray:
    """(M, 4 or 8) int64: the flat indices of the ``ring`` neighbours of ``pixels`` (-1: none there)."""
    h, w = shape
    rows, cols = np.divmod(pixels, w)
    offs = _N8 if neighbours == 8 else _N4
    nb = np.full((len(pixels), len(offs)), -1, dtype=np.int64)
    for k, (dr, dc) in enumerate(offs):
        r2, c2 = rows + dr, cols + dc
        inside = (r2 >= 0) & (r2 < h) & (c2 >= 0) & (c2 < w)
        f = r2 * w + c2
        sel = inside.copy()
        sel[inside] = ring.reshape(-1)[f[inside]]
        nb[sel, k] = f[sel]
    return nb


def _coherent(a: np.ndarray, pixels: np.ndarray, nb: np.ndarray, index: RemovalIndex, T: np.ndarray, *,
              reference: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, _Queried]:
    """:func:`coherent_residuals` of ``pixels`` with their ring neighbours ``nb`` (flat, -1: none), and the
    queried pixels (the fast path's, for :func:`frame_tolerance`'s nearest distances)."""
    if reference:
        want = np.unique(np.concatenate([pixels, nb[nb >= 0]]))
        res = _residuals_of(a, want, index, T)
        queried = _Queried(want, np.zeros((0, 3)), res, np.zeros(0))
    else:  # the same sorted distinct pixels, from a mark per pixel (np.unique hashes: ~10x slower)
        mark = np.zeros(a.shape[0] * a.shape[1], bool)
        mark[pixels] = True
        mark[nb[nb >= 0]] = True
        want = np.flatnonzero(mark)
        queried = _query(a, want, index, T)
        res = queried.residual_mm
    own = res[np.searchsorted(want, pixels)]
    nbr = np.full(nb.shape, np.nan)
    has = nb >= 0
    nbr[has] = res[np.searchsorted(want, nb[has])]
    if not reference:
        around = _around_median(nbr)
        with np.errstate(invalid="ignore"):
            coherent = np.isfinite(own) & (np.abs(own - around) <= COHERENCE_MM)
        return own, around, coherent, queried
    around = np.full(len(pixels), np.nan)
    around[has.any(axis=1)] = np.inf  # ring neighbours, none of them within max_tolerance_mm
    fin = np.where(np.isfinite(nbr), nbr, np.nan)
    some = np.isfinite(fin).any(axis=1)
    if some.any():
        around[some] = np.nanmedian(fin[some], axis=1)
    with np.errstate(invalid="ignore"):
        coherent = np.isfinite(own) & (np.abs(own - around) <= COHERENCE_MM)
    return own, around, coherent, queried


@numba.njit(cache=True, nogil=True, inline="always")
def _sort4(a, b, c, d):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """Four values (not NaN) in ascending order: a network of five compare-exchanges (min and max)."""
    a, b = min(a, b), max(a, b)
    c, d = min(c, d), max(c, d)
    a, c = min(a, c), max(a, c)
    b, d = min(b, d), max(b, d)
    b, c = min(b, c), max(b, c)
    return a, b, c, d


@numba.njit(cache=True, nogil=True)
def _around_median(nbr):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """(M,) float64: per row of ``nbr`` (NaN: no ring neighbour) the median of its finite values as
    ``np.nanmedian`` gives it (the middle one, or the two middle ones' sum halved); +inf when the row
    has neighbours but none finite, NaN when it has none. Rows of four (the tolerance's) go through a sorting
    network (:func:`_sort4`; the insertion sort's branches on the values cost ~0.45 CPU ms on 15k rows); a zero
    median comes from the insertion sort, which picks the zeros of a -0/+0 tie as before."""
    M, K = nbr.shape
    out = np.empty(M)
    buf = np.empty(K)
    for i in range(M):
        if K == 4:  # the tolerance's four neighbours: a sorting network, no branch on the values
            v0, v1, v2, v3 = nbr[i, 0], nbr[i, 1], nbr[i, 2], nbr[i, 3]
            n = np.isfinite(v0) + np.isfinite(v1) + np.isfinite(v2) + np.isfinite(v3)
            if n == 0:
                seen = not (np.isnan(v0) and np.isnan(v1) and np.isnan(v2) and np.isnan(v3))
                out[i] = np.inf if seen else np.nan
                continue
            s0, s1, s2, s3 = _sort4(v0 if np.isfinite(v0) else np.inf, v1 if np.isfinite(v1) else np.inf,
                                    v2 if np.isfinite(v2) else np.inf, v3 if np.isfinite(v3) else np.inf)
            # the same order statistics, so the same median (a sum of two is the same whichever comes first), but
            # for a tie of -0 and +0, whose zero the network may pick otherwise: a zero is taken from the sort below
            med = (s1 + s2) / 2.0 if n == 4 else (s1 if n == 3 else ((s0 + s1) / 2.0 if n == 2 else s0))
            if med != 0.0:
                out[i] = med
                continue
        n = 0
        seen = False
        for k in range(K):
            v = nbr[i, k]
            if not np.isnan(v):
                seen = True
            if np.isfinite(v):
                j = n  # insertion sort: at most 8 values
                while j > 0 and buf[j - 1] > v:
                    buf[j] = buf[j - 1]
                    j -= 1
                buf[j] = v
                n += 1
        if n == 0:
            out[i] = np.inf if seen else np.nan
        elif n % 2 == 1:
            out[i] = buf[n // 2]
        else:
            out[i] = (buf[n // 2 - 1] + buf[n // 2]) / 2.0
    return out


@dataclass(frozen=True, slots=True)
class _Queried:
    """The fast path's query of the model's KD-tree for the pixels ``flat``: their points in the bin frame
    (NaN rows where not finite), residuals and nearest-point distances (mm, +inf: none within reach)."""

    flat: np.ndarray
    p_bin: np.ndarray
    residual_mm: np.ndarray
    nearest_mm: np.ndarray
    #: the signed residual (m, along the nearest model point's normal; NaN: none within reach, no
    #: normals or not finite) and that point's index (-1: none)
    signed_m: np.ndarray | None = None
    nearest_j: np.ndarray | None = None
    #: when every queried pixel has a finite point (a ring's): those points (float64) less the pose's translation,
    #: the rows of the matrix product (:func:`_nearest_again` reads them instead of gathering the frame again)
    moved: np.ndarray | None = None


def _query(a: np.ndarray, flat: np.ndarray, index: RemovalIndex, T: np.ndarray) -> _Queried:
    """:func:`_residuals_of` and :func:`_nearest_mm` of the pixels ``flat`` from one query of the tree (the
    grid's, :func:`_nearest_points`); numpy keeps the matrix product and the einsum (their rounding is the
    reference's), :func:`_scatter_query` spreads the answers over the pixels in one pass."""
    model = index.model
    if len(flat) == 0 or len(model.points) == 0:
        return _Queried(flat, np.full((len(flat), 3), np.nan), np.full(len(flat), np.inf), np.full(len(flat), np.inf),
                        np.full(len(flat), np.nan), np.full(len(flat), -1, np.int64))
    pts, ok = _gather_finite(a, flat, np.ascontiguousarray(T[:3, 3]))
    p_bin = pts @ T[:3, :3]  # numpy's product, as the reference's: the same rounding
    d, j = _nearest_points(p_bin, index)
    if model.normals is None:
        e = np.zeros(0)
    else:
        diff, nrm = _residual_parts(p_bin, j, model.points, model.normals)
        e = np.einsum("ij,ij->i", diff, nrm)
    p_all, out, near, signed, j_all = _scatter_query(ok, p_bin, d, j, e, model.normals is not None)
    return _Queried(flat, p_all, out, near, signed, j_all, pts if len(pts) == len(flat) else None)


@numba.njit(cache=True, nogil=True)
def _scatter_query(ok, p_bin, d, j, e, planes):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """:class:`_Queried`'s ``(p_bin, residual_mm, nearest_mm, signed_m, nearest_j)`` of the queried pixels (``ok``:
    those with a finite point, whose bin-frame points, nearest distances and points are ``p_bin``, ``d``, ``j``;
    ``e``: the signed residuals of those with a point within reach, in order; ``planes``: the model has
    normals, else the residual is the distance): what ten masked assignments wrote, in one pass; ``p_bin`` itself
    when every pixel has a finite point (a ring's pixels do), not a copy of it."""
    n = ok.shape[0]
    whole = p_bin.shape[0] == n  # every queried pixel has a finite point (a ring's): its points as they are
    p_all = p_bin if whole else np.empty((n, 3))
    out = np.empty(n)  # each written once below (not filled first)
    near = np.empty(n)
    signed = np.empty(n)
    j_all = np.empty(n, np.int64)
    k = 0
    f = 0
    for i in range(n):
        if ok[i]:
            if not whole:
                for c in range(3):
                    p_all[i, c] = p_bin[k, c]
            dk = d[k]
            signed[i] = np.nan
            if np.isfinite(dk):
                if planes:
                    out[i] = abs(e[f]) * 1000.0
                    signed[i] = e[f]
                    f += 1
                else:
                    out[i] = dk * 1000.0
                j_all[i] = j[k]
            else:
                out[i] = np.inf
                j_all[i] = -1
            near[i] = dk * 1000.0
            k += 1
        else:
            for c in range(3):
                p_all[i, c] = np.nan
            out[i] = np.inf
            near[i] = np.inf
            signed[i] = np.nan
            j_all[i] = -1
    return p_all, out, near, signed, j_all


@numba.njit(cache=True, nogil=True)
def _gather_finite(a, flat, t):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """``(pts, ok)``: the float64 points of the pixels ``flat`` whose three coordinates are finite (in
    order), less ``t`` (3,), and which ones those are: ``a.reshape(-1, 3)[flat].astype(np.float64)``'s finite rows
    ``- t`` (the subtraction numpy's broadcast makes, one rounding per coordinate: the same doubles; numpy's
    broadcast over rows of three calls its inner loop once a row)."""
    n = flat.shape[0]
    W = a.shape[1]
    ok = np.zeros(n, np.bool_)
    pts = np.empty((n, 3))
    m = 0
    for i in range(n):
        r = flat[i] // W
        c = flat[i] - r * W
        x = np.float64(a[r, c, 0])
        y = np.float64(a[r, c, 1])
        z = np.float64(a[r, c, 2])
        if np.isfinite(x) and np.isfinite(y) and np.isfinite(z):
            ok[i] = True
            pts[m, 0] = x - t[0]
            pts[m, 1] = y - t[1]
            pts[m, 2] = z - t[2]
            m += 1
    return pts[:m], ok


@numba.njit(cache=True, nogil=True)
def _residual_parts(p_bin, j, points, normals):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """``(p_bin[found] - points[j[found]], normals[j[found]])`` where ``j`` names a point (``found``: below
    ``len(points)``), the operands of the residuals' ``einsum`` in one pass."""
    n = points.shape[0]
    k = 0
    for i in range(j.shape[0]):
        if j[i] < n:
            k += 1
    diff = np.empty((k, 3))
    nrm = np.empty((k, 3))
    k = 0
    for i in range(j.shape[0]):
        q = j[i]
        if q < n:
            for c in range(3):
                diff[k, c] = p_bin[i, c] - points[q, c]
                nrm[k, c] = normals[q, c]
            k += 1
    return diff, nrm


def _nearest_points(p_bin: np.ndarray, index: RemovalIndex) -> tuple[np.ndarray, np.ndarray]:
    """``cKDTree.query(p_bin, k=1, distance_upper_bound=max_tolerance)`` of the model's tree, the same
    distances and points (+inf and ``len(points)`` for none), from the grid :attr:`RemovalIndex.nearest`
    where it is sure to give them, from the tree elsewhere."""
    tree = index.tree
    assert tree is not None  # prepare_removal_index builds it in both modes
    ub = index.params.max_tolerance_mm / 1000.0
    g = index.nearest
    if g is None:
        return tree.query(p_bin, k=1, distance_upper_bound=ub)
    d, j, unsure = _nearest_grid(np.ascontiguousarray(p_bin), g.origin, g.cell, g.dims, g.start, g.points,
                                 g.empty_to, g.order, ub)
    if unsure.any():
        d[unsure], j[unsure] = tree.query(p_bin[unsure], k=1, distance_upper_bound=ub)
    return d, j


def _nearest_again(a: np.ndarray, flat: np.ndarray, at: np.ndarray, index: RemovalIndex, T: np.ndarray,
                   q: _Queried) -> np.ndarray:
    """:func:`_nearest_mm` of ``flat`` (pixels among ``q.flat``, at positions ``at`` there), from ``q``'s query
    where the batch of ``flat`` gives their points the very same bin-frame coordinates (a matrix product's
    rounding may differ with the batch: those rows are queried again)."""
    out = np.full(len(flat), np.inf)
    if len(flat) == 0 or len(index.model.points) == 0:
        return out
    if q.moved is not None:  # the queried points, every one finite: the rows ``at`` are ``flat``'s, gathered
        pts, ok = q.moved[at], np.ones(len(flat), bool)
    else:
        pts, ok = _gather_finite(a, flat, np.ascontiguousarray(T[:3, 3]))
    p_bin = pts @ T[:3, :3]
    d, same = _same_rows(p_bin, at[ok], q.p_bin, q.nearest_mm)
    if not same.all():
        d[~same] = _nearest_points(p_bin[~same], index)[0] * 1000.0
    out[ok] = d
    return out


@numba.njit(cache=True, nogil=True)
def _same_rows(p_bin, at, q_p, q_near):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """``(q_near[at], same)``: the queried distances of the rows ``at`` and whether ``p_bin`` holds the very
    points queried there (all three coordinates equal)."""
    n = at.shape[0]
    d = np.empty(n)
    same = np.empty(n, np.bool_)
    for i in range(n):
        k = at[i]
        d[i] = q_near[k]
        same[i] = p_bin[i, 0] == q_p[k, 0] and p_bin[i, 1] == q_p[k, 1] and p_bin[i, 2] == q_p[k, 2]
    return d, same


def far_share(residuals: np.ndarray, around: np.ndarray) -> float:
    """The share of the measured pixels beyond ``max_tolerance_mm`` of the model whose ring neighbours
    all are too (:data:`MAX_FAR_SHARE`); 0 with no pixel."""
    return float(np.mean(np.isinf(residuals) & np.isinf(around))) if len(residuals) else 0.0


def field_design(p: np.ndarray, n: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """(M, 7): the residual field's columns ``n``, ``(p - centre) × n``, ``n·(p - centre)`` at points ``p``
    (bin frame, m) with the normals ``n`` of their nearest model points (:func:`fit_residual_field`)."""
    q = p - centre
    return np.concatenate([n, np.cross(q, n), np.einsum("ij,ij->i", n, q)[:, None]], axis=1)


def fit_residual_field(r: np.ndarray, p: np.ndarray, n: np.ndarray, *, normal_equations: bool = False,
                       reference: bool = False) -> tuple[np.ndarray, np.ndarray, float, int] | None:
    """The residual field a small pose error and a model of a slightly different size make over the bin,
    fitted to signed residuals: ``(coef, centre, sigma_m, n_kept)`` or None.

    A pose off by a translation ``t`` and a small turn ``ω`` moves a bin point ``p`` by ``t + ω × p``, a model
    scaled by ``1 + s`` by ``s p``: the point's signed residual along the model's normal ``n`` is
    ``n·t + ω·(p × n) + s n·p`` (:func:`field_design`), seven numbers fitted by least squares trimmed to
    3 robust sigmas :data:`FIELD_TRIMS` times. ``r`` (M,): the signed residuals (m; NaN rows: no model point
    within reach, left out), ``p`` (M, 3) the points in the bin frame (m), ``n`` (M, 3) their nearest model
    points' normals. ``sigma_m``: the robust scale (1.4826 × MAD) of the kept rows' misfit. None when fewer
    than :data:`FIELD_MIN_PX` rows are finite or kept, or when 3 sigmas exceed :data:`COHERENCE_MM` (no such
    field: a pose several millimetres off, whose nearest model points lie on the wrong faces).
    :func:`zcut.bin_check.residual_field` and :func:`frame_tolerance` use it; ``normal_equations``: each least
    squares solved from its 7 x 7 normal equations instead of ``np.linalg.lstsq`` (the tolerance's: a fifth of
    the CPU on 15,000 pixels, the same field to rounding; the bin check keeps ``lstsq``). ``reference``: numpy
    throughout, as first written (the tests' oracle); else the selections, the centre, the design matrix's
    cross products and the trims' medians run in kernels (:func:`_fit_field`'s), numpy keeping the least squares
    and the products a BLAS sums: the same numbers (a 20k-pixel fit, ``lstsq``: ~10 -> ~5 CPU ms).
    """
    use = np.isfinite(r)
    if np.count_nonzero(use) < FIELD_MIN_PX:
        return None
    r, p, n = r[use], p[use], n[use]
    if not reference and r.dtype == p.dtype == n.dtype == np.float64 and r.ndim == 1 \
            and p.shape == n.shape == (len(r), 3):
        return _fit_field_trimmed(r, p, n, normal_equations=normal_equations)
    centre = p.mean(axis=0)
    A = field_design(p, n, centre)
    keep = np.ones(len(r), bool)
    coef = np.zeros(7)
    sigma = 0.0
    for _ in range(FIELD_TRIMS + 1):
        if normal_equations:
            Ak = A[keep]
            try:
                coef = np.linalg.solve(Ak.T @ Ak, Ak.T @ r[keep])
            except np.linalg.LinAlgError:  # a degenerate ring (one face): the minimum-norm solution
                coef = np.linalg.lstsq(Ak, r[keep], rcond=None)[0]
        else:
            coef = np.linalg.lstsq(A[keep], r[keep], rcond=None)[0]
        e = r - A @ coef
        sigma = 1.4826 * float(np.median(np.abs(e[keep] - np.median(e[keep]))))
        keep = np.abs(e) <= max(3.0 * sigma, 1e-4)
        if np.count_nonzero(keep) < FIELD_MIN_PX:
            return None
    if 3000.0 * sigma > COHERENCE_MM:
        return None
    return coef, centre, sigma, int(np.count_nonzero(keep))


def _off_field(signed_m: np.ndarray, p_bin: np.ndarray, nearest_j: np.ndarray, own_at: np.ndarray,
               nb_at: np.ndarray, coherent: np.ndarray, normals: np.ndarray | None) -> np.ndarray:
    """(M,) bool, of the measured pixels (``own_at``: their positions among the queried ones, whose signed
    residuals, bin-frame points and nearest model points are ``signed_m``, ``p_bin``, ``nearest_j``;
    ``nb_at``: their ring neighbours' positions, -1: none): the coherent ones that lie off the registered bin's
    residual field (:func:`fit_residual_field`, fitted to the measured pixels) by more than
    :data:`COHERENCE_MM` and whose ring neighbours' misfits have a median beyond it too: a surface of its own
    in front of (or behind) the bin's, not the bin's noise. All False without normals or a field."""
    m = len(own_at)
    off = np.zeros(m, bool)
    if normals is None or m == 0:
        return off
    j_own = nearest_j[own_at]
    has_own = j_own >= 0
    n_own = np.full((m, 3), np.nan)
    n_own[has_own] = normals[j_own[has_own]]
    fit = fit_residual_field(signed_m[own_at], p_bin[own_at], n_own, normal_equations=True, reference=True)
    if fit is None:
        return off
    coef, centre, _, _ = fit

    def misfit_mm(at: np.ndarray) -> np.ndarray:  # of the queried pixels ``at`` (NaN: no residual)
        out = np.full(len(at), np.nan)
        j = nearest_j[at]
        ok = j >= 0
        q = at[ok]
        out[ok] = 1000.0 * (signed_m[q] - field_design(p_bin[q], normals[j[ok]], centre) @ coef)
        return out

    own = misfit_mm(own_at)
    with np.errstate(invalid="ignore"):
        cand = np.flatnonzero(coherent & (np.abs(own) > COHERENCE_MM))
    if len(cand) == 0:
        return off
    nb = nb_at[cand]  # only the candidates' neighbours are looked at
    nbr = np.full(nb.shape, np.nan)
    nbr[nb >= 0] = misfit_mm(nb[nb >= 0])
    around = _around_median(nbr)
    with np.errstate(invalid="ignore"):
        off[cand] = np.abs(around) > COHERENCE_MM
    return off


def _off_field_fast(q: _Queried, own_at: np.ndarray, nb_at: np.ndarray, coherent: np.ndarray,
                    normals: np.ndarray | None) -> np.ndarray:
    """:func:`_off_field` of the fast path (the same answer, the reference keeps :func:`_off_field`): the
    design matrix built once, by :func:`_fit_field`, whose last misfit is the measured pixels' own (the
    reference builds it again for them, :func:`field_design` on the same rows); the fit's selections, centre,
    cross products and medians in kernels: 6.7 -> 3.3 CPU ms on 15k measured pixels at 640 x 480, 9.1 -> 4.6 on 20k
    at 1920 x 1200."""
    m = len(own_at)
    off = np.zeros(m, bool)
    if normals is None or m == 0 or q.signed_m is None or q.nearest_j is None:
        return off
    rows, r, p, n = _field_inputs(q.signed_m, q.p_bin, q.nearest_j, own_at, np.ascontiguousarray(normals))
    fit = _fit_field(r, p, n)
    if fit is None:
        return off
    coef, centre, e = fit
    # the reference's misfit_mm(own_at): the rows with a model point are those with a signed residual
    # (``rows``), its design matrix the fit's, row for row: the same products, the same misfit
    own = np.full(m, np.nan)
    own[rows] = 1000.0 * e
    with np.errstate(invalid="ignore"):
        cand = np.flatnonzero(coherent & (np.abs(own) > COHERENCE_MM))
    if len(cand) == 0:
        return off
    nb = nb_at[cand]
    nbr = np.full(nb.shape, np.nan)
    at = nb[nb >= 0]
    j = q.nearest_j[at]
    ok = j >= 0
    mis = np.full(len(at), np.nan)
    mis[ok] = 1000.0 * (q.signed_m[at[ok]] - field_design(q.p_bin[at[ok]], normals[j[ok]], centre) @ coef)
    nbr[nb >= 0] = mis
    around = _around_median(nbr)
    with np.errstate(invalid="ignore"):
        off[cand] = np.abs(around) > COHERENCE_MM
    return off


@numba.njit(cache=True, nogil=True)
def _field_inputs(signed_m, p_bin, nearest_j, own_at, normals):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """``(rows, r, p, n)``: of the measured pixels (``own_at``, positions among the queried ones) those with a
    finite signed residual (their positions ``rows`` in ``own_at``), their residuals, bin-frame points and
    nearest model points' normals (NaN rows without one): :func:`fit_residual_field`'s ``r[use]``,
    ``p[use]``, ``n[use]`` of :func:`_off_field`'s arrays, in one pass."""
    m = own_at.shape[0]
    k = 0
    for i in range(m):
        if np.isfinite(signed_m[own_at[i]]):
            k += 1
    rows = np.empty(k, np.int64)
    r = np.empty(k)
    p = np.empty((k, 3))
    n = np.empty((k, 3))
    k = 0
    for i in range(m):
        q = own_at[i]
        if np.isfinite(signed_m[q]):
            rows[k] = i
            r[k] = signed_m[q]
            j = nearest_j[q]
            for c in range(3):
                p[k, c] = p_bin[q, c]
                n[k, c] = normals[j, c] if j >= 0 else np.nan
            k += 1
    return rows, r, p, n


@numba.njit(cache=True, nogil=True)
def _column_means(p):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """(3,): ``p.mean(axis=0)`` of an (M >= 1, 3) array as numpy sums it (row after row from the first, then
    divided by M)."""
    m = p.shape[0]
    s = p[0].copy()
    for i in range(1, m):
        for c in range(3):
            s[c] += p[i, c]
    return s / m


@numba.njit(cache=True, nogil=True)
def _less_row(p, c):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """(M, 3): ``p - c`` for (M, 3) ``p`` and (3,) ``c``, numpy's broadcast subtraction (the same doubles) without
    its inner loop called once a row."""
    m = p.shape[0]
    q = np.empty((m, 3))
    for i in range(m):
        q[i, 0] = p[i, 0] - c[0]
        q[i, 1] = p[i, 1] - c[1]
        q[i, 2] = p[i, 2] - c[2]
    return q


@numba.njit(cache=True, nogil=True)
def _design_columns(n, q, nq):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """(M, 7): :func:`field_design`'s columns ``n``, ``q × n`` (``np.cross``'s products and differences), ``nq``
    (``n·q``, numpy's einsum, given: its summation order is numpy's)."""
    m = n.shape[0]
    A = np.empty((m, 7))
    for i in range(m):
        A[i, 0] = n[i, 0]
        A[i, 1] = n[i, 1]
        A[i, 2] = n[i, 2]
        A[i, 3] = q[i, 1] * n[i, 2] - q[i, 2] * n[i, 1]
        A[i, 4] = q[i, 2] * n[i, 0] - q[i, 0] * n[i, 2]
        A[i, 5] = q[i, 0] * n[i, 1] - q[i, 1] * n[i, 0]
        A[i, 6] = nq[i]
    return A


@numba.njit(cache=True, nogil=True)
def _kept_rows(A, r, keep):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """``(A[keep], r[keep])``, C-contiguous."""
    k = 0
    for i in range(keep.shape[0]):
        if keep[i]:
            k += 1
    Ak = np.empty((k, A.shape[1]))
    rk = np.empty(k)
    k = 0
    for i in range(keep.shape[0]):
        if keep[i]:
            Ak[k] = A[i]
            rk[k] = r[i]
            k += 1
    return Ak, rk


#: :func:`_median` takes a regular sample of this many values to bracket the median, and keeps the values between
#: the sample's order statistics this many places either side of the median's (2.8 standard deviations of the
#: median's rank in a random sample of 512: about one call in 200 misses; then, with a NaN, or below 8 samples'
#: worth of values, numba's ``np.median`` answers).
_MEDIAN_SAMPLE = 512
_MEDIAN_MARGIN = 32


@numba.njit(cache=True, nogil=True, inline="always")
def _select(a, k, lo, hi):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """Rearrange ``a[lo:hi + 1]`` so that ``a[k]`` holds its (k - lo)-th smallest value, those before it none
    larger and those after it none smaller (Hoare's selection: median-of-three pivot, the two scans stopping
    on values equal to it)."""
    while hi > lo:
        mid = (lo + hi) >> 1
        x = a[lo]
        y = a[mid]
        z = a[hi]
        if x < y:
            m = mid if y < z else (hi if x < z else lo)
        else:
            m = lo if x < z else (hi if y < z else mid)
        pv = a[m]
        a[m] = a[lo]
        a[lo] = pv
        i = lo + 1
        j = hi
        while True:
            while i <= j and a[i] < pv:
                i += 1
            while i <= j and a[j] > pv:
                j -= 1
            if i >= j:
                break
            t = a[i]
            a[i] = a[j]
            a[j] = t
            i += 1
            j -= 1
        a[lo] = a[j]
        a[j] = pv
        if j == k:
            return
        if j < k:
            lo = j + 1
        else:
            hi = j - 1


@numba.njit(cache=True, nogil=True)
def _median(x):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """``np.median(x)`` of a 1-D float64 array as numba computes it (the middle value, or the two middle values'
    sum halved), ~3x cheaper on 15-20k values (the field's trims: 0.19 -> 0.06 CPU ms a median).

    The median's order statistics lie, but for a rare sample, between the sample's order statistics
    :data:`_MEDIAN_MARGIN` places either side of theirs in a regular sample of :data:`_MEDIAN_SAMPLE` values; one
    pass without branches counts the values below that bracket and copies those within it, and a selection
    among those few gives the same order statistics. When the counts show the bracket missed them, when a
    value is NaN, or for fewer than 8 samples' worth of values, ``np.median`` answers: the value is always its
    own."""
    n = x.shape[0]
    if n < 8 * _MEDIAN_SAMPLE:
        return np.median(x)
    k_hi = n >> 1
    k_lo = k_hi - 1 if n % 2 == 0 else k_hi
    stride = n // _MEDIAN_SAMPLE
    s = np.empty(_MEDIAN_SAMPLE)
    for i in range(_MEDIAN_SAMPLE):
        s[i] = x[i * stride]
    s.sort()
    c_lo = (k_lo * _MEDIAN_SAMPLE) // n - _MEDIAN_MARGIN
    c_hi = (k_hi * _MEDIAN_SAMPLE) // n + _MEDIAN_MARGIN
    lo = s[max(c_lo, 0)]
    hi = s[min(c_hi, _MEDIAN_SAMPLE - 1)]
    buf = np.empty(n)
    below = 0
    m = 0
    nan = 0
    for i in range(n):  # branch-free: every value is written, the count moves past those within the bracket
        v = x[i]
        below += v < lo
        buf[m] = v
        m += (v >= lo) & (v <= hi)
        nan += v != v
    if nan or below > k_lo or below + m <= k_hi:
        return np.median(x)
    k = k_hi - below
    _select(buf, k, 0, m - 1)
    if k_lo == k_hi:
        return buf[k]
    a = buf[0]  # the largest of the k values before a[k]: the lower middle value
    for i in range(1, k):
        if buf[i] > a:
            a = buf[i]
    return (a + buf[k]) / 2


@numba.njit(cache=True, nogil=True)
def _trimmed(e, keep):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """One trim of :func:`fit_residual_field`: ``sigma = 1.4826 * median(|e[keep] - median(e[keep])|)`` and the
    rows within ``max(3 sigma, 1e-4)``, with their count (the medians numpy's: order statistics, the two middle
    ones' sum halved)."""
    k = 0
    for i in range(keep.shape[0]):
        if keep[i]:
            k += 1
    ek = np.empty(k)
    k = 0
    for i in range(keep.shape[0]):
        if keep[i]:
            ek[k] = e[i]
            k += 1
    mid = _median(ek)
    sigma = 1.4826 * _median(np.abs(ek - mid))
    bound = max(3.0 * sigma, 1e-4)
    out = np.empty(e.shape[0], np.bool_)
    n = 0
    for i in range(e.shape[0]):
        out[i] = abs(e[i]) <= bound
        n += out[i]
    return sigma, out, n


def _fit_field(r: np.ndarray, p: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """:func:`fit_residual_field` with ``normal_equations`` of finite rows ``r``, ``p``, ``n``: ``(coef, centre,
    e)`` (``e`` the last misfit, ``r - A @ coef``) or None, the same numbers: numpy keeps the products a BLAS
    sums (``A.T @ A``, ``A.T @ r``, ``A @ coef``), the solve and the einsum; the rest runs in kernels."""
    if len(r) < FIELD_MIN_PX:
        return None
    centre = _column_means(p)
    q = _less_row(p, centre)
    A = _design_columns(n, q, np.einsum("ij,ij->i", n, q))
    keep = np.ones(len(r), bool)
    coef = np.zeros(7)
    e = r
    sigma = 0.0
    for _ in range(FIELD_TRIMS + 1):
        Ak, rk = _kept_rows(A, r, keep)
        try:
            coef = np.linalg.solve(Ak.T @ Ak, Ak.T @ rk)
        except np.linalg.LinAlgError:  # a degenerate ring (one face): the minimum-norm solution
            coef = np.linalg.lstsq(Ak, rk, rcond=None)[0]
        e = r - A @ coef
        sigma, keep, kept = _trimmed(e, keep)
        if kept < FIELD_MIN_PX:
            return None
    if 3000.0 * sigma > COHERENCE_MM:
        return None
    return coef, centre, e


def _fit_field_trimmed(r: np.ndarray, p: np.ndarray, n: np.ndarray, *,
                       normal_equations: bool) -> tuple[np.ndarray, np.ndarray, float, int] | None:
    """:func:`fit_residual_field`'s loop on its finite float64 rows (at least :data:`FIELD_MIN_PX`), the selections,
    the centre, the cross products and the medians in :func:`_fit_field`'s kernels."""
    centre = _column_means(p)
    q = _less_row(p, centre)
    A = _design_columns(n, q, np.einsum("ij,ij->i", n, q))
    keep = np.ones(len(r), bool)
    coef = np.zeros(7)
    sigma = 0.0
    kept = len(r)
    for _ in range(FIELD_TRIMS + 1):
        Ak, rk = _kept_rows(A, r, keep)
        if normal_equations:
            try:
                coef = np.linalg.solve(Ak.T @ Ak, Ak.T @ rk)
            except np.linalg.LinAlgError:  # a degenerate ring (one face): the minimum-norm solution
                coef = np.linalg.lstsq(Ak, rk, rcond=None)[0]
        else:
            coef = np.linalg.lstsq(Ak, rk, rcond=None)[0]
        e = r - A @ coef
        sigma, keep, kept = _trimmed(e, keep)
        if kept < FIELD_MIN_PX:
            return None
    if 3000.0 * sigma > COHERENCE_MM:
        return None
    return coef, centre, float(sigma), int(kept)


def _signed_ref(a: np.ndarray, flat: np.ndarray, index: RemovalIndex,
                T: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The reference's ``(signed_m, p_bin, nearest_j)`` of the pixels ``flat`` (:class:`_Queried`'s), from the
    model's KD-tree."""
    signed = np.full(len(flat), np.nan)
    p_all = np.full((len(flat), 3), np.nan)
    j_all = np.full(len(flat), -1, np.int64)
    model = index.model
    if len(flat) == 0 or len(model.points) == 0 or model.normals is None:
        return signed, p_all, j_all
    pts = a.reshape(-1, 3)[flat].astype(np.float64)
    ok = np.isfinite(pts).all(axis=1)
    p_bin = (pts[ok] - T[:3, 3]) @ T[:3, :3]
    p_all[ok] = p_bin
    tree = index.tree
    assert tree is not None  # prepare_removal_index builds it in both modes
    d, j = tree.query(p_bin, k=1, distance_upper_bound=index.params.max_tolerance_mm / 1000.0)
    found = np.isfinite(d)
    s = np.full(len(p_bin), np.nan)
    s[found] = np.einsum("ij,ij->i", p_bin[found] - model.points[j[found]], model.normals[j[found]])
    signed[ok] = s
    jj = np.full(len(p_bin), -1, np.int64)
    jj[found] = j[found]
    j_all[ok] = jj
    return signed, p_all, j_all


def surface_residuals(xyz: XYZ, ring: Mask, index: RemovalIndex, T_cam_bin: np.ndarray, *,
                      removal: RemovalResult | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`coherent_residuals` of a regular subsample of at most :data:`MAX_RESIDUAL_PX` certain bin
    pixels with a finite point, each against its four neighbours: ``(residuals, around, coherent)``.

    ``removal``: the frame's removal; when it measured them (the robust mode's :func:`frame_tolerance`)
    of this very ``xyz``, ``ring`` and ``index`` at this pose, its arrays are returned (the same values), not
    measured again.
    """
    s = removal.surface if removal is not None else None
    if s is not None and s.xyz is xyz and s.ring is ring and s.index is index and np.array_equal(s.T, T_cam_bin):
        return s.residuals, s.around, s.coherent
    return _measured(xyz, ring, index, T_cam_bin, coherence=True)


def surface_nearest(removal: RemovalResult | None, index: RemovalIndex, pixels: np.ndarray,
                    p_bin: np.ndarray) -> np.ndarray | None:
    """(M,) int64: the nearest model point within ``max_tolerance_mm`` (-1: none) of each of ``pixels`` (flat,
    each with a finite point) whose bin-frame points are ``p_bin`` (M, 3), what ``index.tree.query(p_bin, k=1,
    distance_upper_bound=max_tolerance)`` names, read from the query :func:`frame_tolerance` made with this
    ``index`` (:attr:`RemovalResult.surface`) where it queried the same pixel at the very same point (the answer
    depends on nothing else; a matrix product's rounding may differ with the batch: those rows, and pixels it
    did not query, are queried again, :func:`_nearest_points`). None when the removal did not measure with
    ``index``."""
    s = removal.surface if removal is not None else None
    if s is None or s.queried is None or s.queried.nearest_j is None or s.index is not index:
        return None
    q = s.queried
    flat = np.asarray(pixels, dtype=np.int64)
    p = np.ascontiguousarray(p_bin, dtype=np.float64)
    if len(q.flat) == 0 or len(flat) == 0:
        return None
    at = np.minimum(np.searchsorted(q.flat, flat), len(q.flat) - 1)
    j, same = _same_nearest(p, at, flat, q.flat, q.p_bin, q.nearest_j)
    if not same.all():
        d, jj = _nearest_points(p[~same], index)
        j[~same] = np.where(np.isfinite(d), jj, -1)
    return j


@numba.njit(cache=True, nogil=True)
def _same_nearest(p_bin, at, flat, q_flat, q_p, q_j):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """``(q_j[at], same)``: the queried nearest points of the rows ``at`` and whether the pixel queried there is
    ``flat``'s with the very point ``p_bin`` (all three coordinates equal); -1 where not."""
    n = at.shape[0]
    j = np.full(n, -1, np.int64)
    same = np.empty(n, np.bool_)
    for i in range(n):
        k = at[i]
        same[i] = (q_flat[k] == flat[i] and p_bin[i, 0] == q_p[k, 0] and p_bin[i, 1] == q_p[k, 1]
                   and p_bin[i, 2] == q_p[k, 2])
        if same[i]:
            j[i] = q_j[k]
    return j, same


def bin_residuals_mm(xyz: XYZ, ring: Mask, index: RemovalIndex, T_cam_bin: np.ndarray) -> np.ndarray:
    """(M,) float64: distances (mm) of the frame's certain bin pixels to the model at ``T_cam_bin``.

    For a regular subsample of at most :data:`MAX_RESIDUAL_PX` of the ``ring`` pixels with a finite
    point: the distance to the tangent plane of the nearest model point (to the point itself when the
    model has no normals); +inf where no model point lies within ``max_tolerance_mm``.

    Parameters
    ----------
    xyz : (H, W, 3) float ndarray
        Metres, camera optical frame.
    ring : (H, W) bool ndarray
        Pixels that are bin for certain (:func:`zcut.binmask.bin_pixels`).
    index : RemovalIndex
        Prepared by :func:`prepare_removal_index` (it holds the model's KD-tree).
    T_cam_bin : (4, 4) float ndarray
    """
    return _measured(xyz, ring, index, T_cam_bin, coherence=False)[0]


def _ring_sample(a: np.ndarray, ring: Mask, max_px: int = MAX_RESIDUAL_PX) -> np.ndarray:
    """Flat indices of a regular subsample of at most ``max_px`` ring pixels with a finite point."""
    flat = np.flatnonzero(ring)
    flat = flat[:: max(1, -(-len(flat) // max_px))]
    return flat[np.isfinite(a.reshape(-1, 3)[flat]).all(axis=1)]


def _measured(xyz: XYZ, ring: Mask, index: RemovalIndex, T_cam_bin: np.ndarray, *,
              coherence: bool, reference: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if index.tree is None:
        raise ParameterError("bin_residuals_mm: the index has no KD-tree (prepare_removal_index builds it)")
    a = np.asarray(xyz)
    ring = np.asarray(ring, dtype=bool)
    if ring.shape != a.shape[:2]:
        raise InputShapeError(f"ring must be an {a.shape[:2]} bool array, got {describe_array(ring)}")
    flat = _ring_sample(a, ring)
    if not coherence:
        res = _residuals_of(a, flat, index, np.asarray(T_cam_bin, dtype=np.float64))
        return res, res, np.isfinite(res)
    return coherent_residuals(a, ring, flat, index, T_cam_bin, neighbours=4, reference=reference)


def frame_tolerance(xyz: XYZ, ring: Mask, index: RemovalIndex, T_cam_bin: np.ndarray, *,
                    reference: bool = False) -> Tolerance:
    """The robust mode's tolerance τ of one frame, from its certain bin pixels' residuals.

    τ = the ``residual_quantile`` percentile of the *coherent* residuals (:func:`coherent_residuals`
    over a subsample of the certain bin pixels, with their four neighbours) + ``residual_margin_mm``,
    clipped to ``[max(min_tolerance_mm, delta_mm), max_tolerance_mm]``; ``tolerance_mm`` when the
    parameters fix it. The residuals hold the pose's error where it shows (a wall moved sideways, a
    rim tilted) and the sensor's noise, both smooth over the surface; a sensor's ghosts (points
    floating above the rim, mixed pixels along its edges) are not coherent with their neighbours
    and do not count, however many: on ray-traced shiny frames they made the plain percentile
    infinite and τ its maximum. Nor do the faces of parts leaning on an upper wall, which lie among the
    certain bin pixels, coherent with each other, a few millimetres in front of the wall: a coherent pixel
    whose signed residual lies more than :data:`COHERENCE_MM` off the residual field a pose error and a
    model's scale make over the bin (:func:`fit_residual_field`, fitted to the same pixels), and whose ring
    neighbours' misfits have their median beyond it too (a surface of its own, not the wall's noise tail),
    is left out (:attr:`Tolerance.n_off_field`; on hand-made walls piles such faces were 1-2 % of the ring
    and raised τ to 3.5-5.2 mm at a correct pose, docs/bin_robustness.md). Without normals, or when no field
    fits (3 robust sigmas beyond :data:`COHERENCE_MM`: a pose far off), nothing is left out. When fewer than :data:`MIN_COHERENT_SHARE` of the measured pixels are
    coherent, or more than :data:`MAX_FAR_SHARE` lie beyond ``max_tolerance_mm`` among neighbours
    that do too (:func:`far_share`: a pose far off), the
    percentile of all of them is taken, as before; with no pixel to measure τ is the maximum.

    τ bounds the test along the model's normals; its search radius (a model point that near) is
    measured on the same pixels (:attr:`Tolerance.reach_mm`): the removal's radius is at least that
    reach, so a model sampled more coarsely than the frame does not leave its bin pixels in the zone.

    ``reference``: the previous implementation (two queries of the model's tree, ``np.unique``), the
    tests' oracle; the fast path queries the tree once and keeps the residuals (:attr:`Tolerance.surface`).
    """
    p = index.params
    lo = max(p.min_tolerance_mm, p.delta_mm)
    if p.tolerance_mm is not None:
        return Tolerance(max(float(p.tolerance_mm), p.delta_mm), float("nan"), 0)
    if not reference:
        return _frame_tolerance(xyz, ring, index, np.asarray(T_cam_bin, dtype=np.float64))
    res, around, coherent = _measured(xyz, ring, index, T_cam_bin, coherence=True, reference=True)
    if len(res) == 0:
        return Tolerance(max(p.max_tolerance_mm, lo), float("nan"), 0)
    n_coh = int(np.count_nonzero(coherent))
    surface = n_coh and n_coh >= MIN_COHERENT_SHARE * len(res) and far_share(res, around) <= MAX_FAR_SHARE
    a = np.asarray(xyz)
    ring_a = np.asarray(ring, dtype=bool)
    T = np.asarray(T_cam_bin, dtype=np.float64)
    flat = _ring_sample(a, ring_a)
    off = np.zeros(len(res), bool)
    if surface:  # the coherent pixels off the bin's residual field are no bin (parts leaning on a wall)
        nb = _ring_neighbours(a.shape[:2], ring_a, flat, 4)
        want = np.unique(np.concatenate([flat, nb[nb >= 0]]))
        nb_at = np.where(nb >= 0, np.searchsorted(want, np.where(nb >= 0, nb, 0)), -1)
        off = _off_field(*_signed_ref(a, want, index, T), np.searchsorted(want, flat), nb_at, coherent,
                         index.model.normals)
    keep = coherent & ~off
    use = res[keep] if surface else res
    q = float(np.percentile(use, p.residual_quantile, method="higher"))
    tau = min(max(q + p.residual_margin_mm, lo), max(p.max_tolerance_mm, lo)) if np.isfinite(q) \
        else max(p.max_tolerance_mm, lo)
    reach = float("nan")
    if index.model.normals is not None:
        # the same pixels, the same percentile and margin, for the test's other extent: its radius
        near = _nearest_mm(a, flat[keep] if surface else flat, index, T)
        q_near = float(np.percentile(near, p.residual_quantile, method="higher"))
        reach = min(q_near + p.residual_margin_mm, p.max_tolerance_mm) if np.isfinite(q_near) else p.max_tolerance_mm
    sigma_m = bin_sigma_m(use)
    rad = pixel_angle(a, flat) if np.isfinite(sigma_m) else float("nan")
    return Tolerance(float(tau), q, len(res), n_coh, float(reach), n_off_field=int(np.count_nonzero(off)),
                     sigma_mm=1000.0 * sigma_m, pixel_rad=rad)


def _percentile_higher(x: np.ndarray, q: float) -> float:
    """``float(np.percentile(x, q, method="higher"))``: numpy's index ``ceil((n - 1) * (q / 100))`` (the same
    double operations) and its order statistic from a selection (:func:`_order_statistic`), NaN when a value is;
    numpy for an empty array, other dtypes, and a zero (a tie of -0 and +0 might give the other zero)."""
    n = x.shape[0] if x.ndim == 1 else 0
    if n == 0 or x.dtype != np.float64:
        return float(np.percentile(x, q, method="higher"))
    v = float(_order_statistic(x, math.ceil((n - 1) * (q / 100.0))))
    return v if v != 0.0 else float(np.percentile(x, q, method="higher"))


@numba.njit(cache=True, nogil=True)
def _order_statistic(x, k):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """The k-th smallest value of ``x`` (1-D float64, 0 <= k < len), NaN when some value is NaN (numpy's
    partition sorts them last, and its percentile says NaN)."""
    n = x.shape[0]
    buf = np.empty(n)
    nan = 0
    for i in range(n):
        v = x[i]
        buf[i] = v
        nan += v != v
    if nan:
        return np.nan
    _select(buf, k, 0, n - 1)
    return buf[k]


def bin_sigma_m(residuals_mm: np.ndarray) -> float:
    """The bin's residual scale σ_bin (m) from the residuals (mm) τ's percentile was taken over: 1.4826 × their
    median (a normal residual's |d| has median 0.6745 σ), as ``explained`` measures the bin's
    (``zcut.explained.residual_sigma``, on the removal's bin pixels; here on the certain bin pixels, before the
    removal). It holds the pose's and the model's misfit where they show, as the residuals do. NaN with no
    residual; +inf when more than half of them are (no model point within ``max_tolerance_mm``)."""
    if len(residuals_mm) == 0:
        return float("nan")
    return 1.4826 * _median_of(residuals_mm) / 1000.0


def _median_of(x: np.ndarray) -> float:
    """``float(np.median(x))`` of a 1-D array: :func:`_median`'s kernel for float64 without NaN (the same order
    statistics, the two middle ones' sum halved as numpy halves it), numpy for the rest."""
    if x.dtype == np.float64 and x.ndim == 1 and not np.isnan(x).any():
        return float(_median(x))
    return float(np.median(x))


def pixel_angle(a: np.ndarray, flat: np.ndarray) -> float:
    """The angle one pixel subtends (rad, 1 / f), read off the organized cloud ``a`` at the pixels ``flat``: the
    median of ``|Δ(x / z)|`` to each pixel's right neighbour and ``|Δ(y / z)|`` to the one below (both finite, z
    not 0, the step not 0; a pinhole cloud's x / z is (u - cx) / fx whatever the depth); NaN when no pair gives it.
    A pixel's footprint at depth z (the Err's c, docs/bin_robustness.md) is ``z * pixel_angle``."""
    if len(flat) == 0:
        return float("nan")
    if a.ndim == 3 and a.shape[2] == 3 and a.dtype in (np.float32, np.float64):
        step = _pixel_steps(a, np.asarray(flat, np.int64))  # the numpy version's 1.1 CPU ms of 1.7 at 640 x 480
    else:  # the arrays the kernel does not take
        step = _pixel_steps_numpy(a, flat)
    return _median_of(step) if step.size else float("nan")


def _pixel_steps_numpy(a: np.ndarray, flat: np.ndarray) -> np.ndarray:
    """:func:`pixel_angle`'s steps (the right neighbours' ``|Δ(x / z)|``, then the lower ones' ``|Δ(y / z)|``,
    finite and not 0) in numpy: :func:`_pixel_steps`'s reference."""
    h, w = a.shape[:2]
    f = a.reshape(-1, 3)
    rows, cols = np.divmod(np.asarray(flat, np.int64), w)
    steps = []
    for axis, ok, nxt in ((0, cols + 1 < w, flat + 1), (1, rows + 1 < h, flat + w)):
        p, q = f[flat[ok]].astype(np.float64), f[nxt[ok]].astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            d = np.abs(q[:, axis] / q[:, 2] - p[:, axis] / p[:, 2])
        steps.append(d[np.isfinite(d) & (d > 0)])
    return np.concatenate(steps)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _pixel_steps(a, flat):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """:func:`_pixel_steps_numpy` in one kernel: the same float64 operations on the same pairs, in the same
    order (a division by 0 gives inf or NaN, as numpy's; those steps are left out)."""
    H, W = a.shape[0], a.shape[1]
    m = flat.shape[0]
    out = np.empty(2 * m)
    n = 0
    for axis in range(2):
        for i in range(m):
            r = flat[i] // W
            c = flat[i] - r * W
            if axis == 0:
                if c + 1 >= W:
                    continue
                r2, c2 = r, c + 1
            else:
                if r + 1 >= H:
                    continue
                r2, c2 = r + 1, c
            d = abs(np.float64(a[r2, c2, axis]) / np.float64(a[r2, c2, 2])
                    - np.float64(a[r, c, axis]) / np.float64(a[r, c, 2]))
            if np.isfinite(d) and d > 0:
                out[n] = d
                n += 1
    return out[:n]


def straggler_bound_args(p: RemovalParams, tol: Tolerance, rim_b: float = np.inf) -> tuple[float, float, float]:
    """The straggler kernels' bound arguments ``(σ_bin² m², the pixel's angle rad, top m)`` for the robust removal of a
    frame with tolerance ``tol``: :data:`_NO_BOUND` (σ_bin² < 0, the test's distance as it is) when
    ``p.straggler_bound`` is ``"off"`` or σ_bin or the angle is not known (:func:`straggler_bound_m`). ``top``, the
    height (bin frame) above which a straggler is not bounded: +inf for ``"global"``, :func:`straggler_top_m` of the
    model's rim height ``rim_b`` (:attr:`RemovalIndex.rim_b`) for ``"below_rim"``."""
    sigma_m = tol.sigma_mm / 1000.0
    if p.straggler_bound == "off" or not (np.isfinite(sigma_m) and np.isfinite(tol.pixel_rad)):
        return _NO_BOUND
    return (sigma_m * sigma_m, float(tol.pixel_rad), straggler_top_m(p, rim_b))


def straggler_top_m(p: RemovalParams, rim_b: float) -> float:
    """The height (bin frame, m) above which the straggler bound does not apply: with ``"below_rim"`` the bottom of
    the rim's band, ``rim_b - rim_offset_m`` (the band the easy-outlier test draws above the rim, drawn below it);
    +inf otherwise (no pixel above it). A model 0.5 % small, or one scan's, leaves rim pixels 2-4 mm below the rim
    beyond 3 of the bin's Err while every near-wall outlier the pass took lay 45 mm or more below it
    (docs/bin_robustness.md)."""
    if p.straggler_bound == "below_rim":
        return float(rim_b) - p.rim_offset_m
    return float(np.inf)


def straggler_bound_m(z_m: np.ndarray, sigma_m: float, pixel_rad: float,
                      straggler_m: float, *, height_m: np.ndarray | None = None,
                      top_m: float = np.inf) -> np.ndarray:
    """The straggler test's distance bound (m) at pixels of depth ``z_m`` (camera z, m):
    ``min(straggler_m, STRAGGLER_ERRS × max(STRAGGLER_ERR_FLOOR_MM, sqrt(σ_bin² + c² / 2)))``, c = ``|z| ×
    pixel_rad`` the pixel's footprint, σ_bin = ``sigma_m`` (:attr:`Tolerance.sigma_mm`); ``straggler_m`` (τ +
    ``straggler_mm`` in the robust mode) where σ_bin or the pixel's angle is unknown (NaN), and at the pixels whose
    ``height_m`` (bin frame, m; ``z_m``'s shape) lies above ``top_m`` (:func:`straggler_top_m`). The kernels compute
    the same numbers, in the same order (:func:`_straggler_delta`)."""
    z = np.abs(np.asarray(z_m, np.float64))
    if np.isnan(sigma_m) or not np.isfinite(pixel_rad):
        return np.full(z.shape, float(straggler_m))
    c = z * pixel_rad
    err = np.maximum(_STRAGGLER_ERR_FLOOR_M, np.sqrt(sigma_m * sigma_m + 0.5 * c * c))
    out = np.minimum(float(straggler_m), STRAGGLER_ERRS * err)
    if height_m is not None:
        out = np.where(np.asarray(height_m, np.float64) > top_m, float(straggler_m), out)
    return out


def _sample_ring(a: np.ndarray, ring: Mask, max_px: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_ring_sample`, its pixels' four ring neighbours (:func:`_ring_neighbours`) and the sorted distinct
    pixels of both (what the fast :func:`_coherent` queries): ``(flat, want, own_at, nb_at)`` with
    ``want[own_at] == flat`` and ``want[nb_at[i, k]]`` the k-th neighbour of ``flat[i]`` (-1: none), the
    positions ``np.searchsorted(want, ...)`` gives. The ring is read eight pixels at a time
    (:func:`_sample_words`)."""
    return _sample_and_steps(a, ring, max_px)[:4]


def _sample_and_steps(a: np.ndarray, ring: Mask,
                      max_px: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_sample_ring` and :func:`pixel_angle`'s steps of its sample (:func:`_pixel_steps` of ``flat``, the same
    array), taken while each sampled point is at hand: ``(flat, want, own_at, nb_at, steps)``."""
    n = ring.size
    pad = -n % 8
    rf = ring.reshape(-1).view(np.uint8)
    if pad:
        rf = np.concatenate([rf, np.zeros(pad, np.uint8)])
    return _sample_words(a, rf.view(np.uint64), ring.shape[0], ring.shape[1], max_px)


@numba.njit(cache=True, inline="always")
def _nonzero_bytes(x):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """How many of the eight bytes of the uint64 ``x`` are not 0 (each byte's high bit set when some bit of it is:
    the low seven bits plus 0x7f carry into it and stop there; those bits summed by a multiplication)."""
    low = np.uint64(0x7F7F7F7F7F7F7F7F)
    ones = np.uint64(0x0101010101010101)
    hi = (((x & low) + low) | x) >> np.uint64(7)
    return ((hi & ones) * ones) >> np.uint64(56)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _sample_words(a, words, H, W, max_px):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """:func:`_sample_ring` of the ring seen as 64-bit words (eight pixels each, zero-padded): the ring's pixels are
    counted a word at a time (:func:`_nonzero_bytes`), the words that hold none are skipped, and so is at once a
    word none of whose ring pixels is sampled (a 1920 x 1200 sample takes every ~20th ring pixel). The sample is
    every ``step``-th ring pixel in image order with a finite point, ``step`` the ring's count over ``max_px``
    rounded up; the queried pixels are the sample and its ring neighbours (above, below, left, right), sorted and
    distinct, with their positions (:func:`_queried_bits`). Also returns :func:`pixel_angle`'s steps of the sample
    (:func:`_pixel_steps`: the same expressions, in the same order), taken while each sampled point is at hand
    (the kernel was a second pass over the sample's scattered points)."""
    N = H * W
    rb = words.view(np.uint8)
    n = 0
    for w in range(words.shape[0]):
        n += int(_nonzero_bytes(words[w]))
    step = max(1, -(-n // max_px))
    flat = np.empty((n + step - 1) // step, np.int64)
    right = np.empty(flat.shape[0])  # the pixel angle's steps (_pixel_steps: to the right, then below)
    below = np.empty(flat.shape[0])
    n_right = 0
    n_below = 0
    m = 0
    k = 0  # ring pixels until the next sampled one (a count down: no division per pixel)
    for w in range(words.shape[0]):
        x = words[w]
        if x == 0:
            continue
        here = int(_nonzero_bytes(x))
        if k >= here:  # none of the word's ring pixels is sampled: counted down at once
            k -= here
            continue
        for q in range(8 * w, min(8 * w + 8, N)):
            if rb[q]:
                if k == 0:
                    k = step
                    r = q // W
                    c = q - r * W
                    if np.isfinite(a[r, c, 0]) and np.isfinite(a[r, c, 1]) and np.isfinite(a[r, c, 2]):
                        flat[m] = q
                        m += 1
                        if c + 1 < W:  # _pixel_steps' expressions (a division by 0: inf or NaN, left out)
                            d = abs(np.float64(a[r, c + 1, 0]) / np.float64(a[r, c + 1, 2])
                                    - np.float64(a[r, c, 0]) / np.float64(a[r, c, 2]))
                            if np.isfinite(d) and d > 0:
                                right[n_right] = d
                                n_right += 1
                        if r + 1 < H:
                            d = abs(np.float64(a[r + 1, c, 1]) / np.float64(a[r + 1, c, 2])
                                    - np.float64(a[r, c, 1]) / np.float64(a[r, c, 2]))
                            if np.isfinite(d) and d > 0:
                                below[n_below] = d
                                n_below += 1
                k -= 1
    flat = flat[:m]
    steps = np.empty(n_right + n_below)
    steps[:n_right] = right[:n_right]
    steps[n_right:] = below[:n_below]
    nb = np.full((m, 4), -1, np.int64)
    for i in range(m):
        q = flat[i]
        r = q // W
        c = q - r * W
        for j in range(4):  # _N4: up, down, left, right
            rr = r - 1 if j == 0 else (r + 1 if j == 1 else r)
            cc = c - 1 if j == 2 else (c + 1 if j == 3 else c)
            if 0 <= rr < H and 0 <= cc < W and rb[rr * W + cc]:
                nb[i, j] = rr * W + cc
    want, own_at, nb_at = _queried_bits(flat, nb, N)
    return flat, want, own_at, nb_at, steps


#: de Bruijn's sequence for 64 bits and the bit index of each of its 6-bit windows: the index of a word's lowest set
#: bit without a loop over its bits (:func:`_queried_bits`)
_DE_BRUIJN = 0x03F79D71B4CB0A89
_DE_BRUIJN_BIT = np.array([0, 1, 48, 2, 57, 49, 28, 3, 61, 58, 50, 42, 38, 29, 17, 4, 62, 55, 59, 36, 53, 51, 43, 22,
                           45, 39, 33, 30, 24, 18, 12, 5, 63, 47, 56, 27, 60, 41, 37, 16, 54, 35, 52, 21, 44, 32, 23, 11,
                           46, 26, 40, 15, 34, 20, 31, 10, 25, 14, 19, 9, 13, 8, 7, 6], np.int64)
_DE_BRUIJN_BIT.setflags(write=False)


@numba.njit(cache=True, inline="always")
def _ones64(x):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """The number of set bits of the uint64 ``x`` (summed in pairs, nibbles, then bytes by a multiplication)."""
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return np.int64((x * np.uint64(0x0101010101010101)) >> np.uint64(56))


@numba.njit(cache=True, inline="always")
def _rank(bits, before, q):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """How many set bits of ``bits`` come before bit ``q`` (``before``: the count before each word)."""
    w = q >> 6
    return before[w] + _ones64(bits[w] & ((np.uint64(1) << np.uint64(q & 63)) - np.uint64(1)))


@numba.njit(cache=True, nogil=True)
def _queried_bits(flat, nb, N):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """``(want, own_at, nb_at)`` of the sample ``flat`` and its ring neighbours ``nb`` (-1: none) among N pixels: the
    sorted distinct pixels of both and each one's position there. A bit a pixel (N / 8 bytes: a 1920 x 1200 image's
    fits a core's cache, where an image of marks did not), set for each of them; the sorted list is the set bits
    in order, a pixel's position the count of set bits before it. What the five sorted lists (the sample, its
    neighbours up, down, left, right) merged gave, without a comparison per list and pixel: 0.89 -> 0.56 CPU ms on
    a 1920 x 1200 frame's 94k queried pixels, 0.46 -> 0.28 on a 640 x 480 frame's 46k."""
    m = flat.shape[0]
    n_words = (N + 63) >> 6
    bits = np.zeros(n_words, np.uint64)
    one = np.uint64(1)
    for i in range(m):
        q = flat[i]
        bits[q >> 6] |= one << np.uint64(q & 63)
        for j in range(4):
            q = nb[i, j]
            if q >= 0:
                bits[q >> 6] |= one << np.uint64(q & 63)
    before = np.empty(n_words, np.int64)
    total = 0
    for w in range(n_words):
        before[w] = total
        total += _ones64(bits[w])
    want = np.empty(total, np.int64)
    k = 0
    debruijn = np.uint64(_DE_BRUIJN)
    for w in range(n_words):
        x = bits[w]
        while x != 0:
            low = x & (~x + one)  # the lowest set bit
            want[k] = (w << 6) + _DE_BRUIJN_BIT[np.int64((low * debruijn) >> np.uint64(58))]
            k += 1
            x ^= low
    own_at = np.empty(m, np.int64)
    nb_at = np.full((m, 4), -1, np.int64)
    for i in range(m):
        own_at[i] = _rank(bits, before, flat[i])
        for j in range(4):
            q = nb[i, j]
            if q >= 0:
                nb_at[i, j] = _rank(bits, before, q)
    return want, own_at, nb_at


@numba.njit(cache=True, nogil=True)
def _own_and_neighbours(res, own_at, nb_at):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """``(res[own_at], nbr)`` with ``nbr[i, k] = res[nb_at[i, k]]``, NaN where ``nb_at`` is -1."""
    m, K = nb_at.shape
    own = np.empty(m)
    nbr = np.full((m, K), np.nan)
    for i in range(m):
        own[i] = res[own_at[i]]
        for k in range(K):
            if nb_at[i, k] >= 0:
                nbr[i, k] = res[nb_at[i, k]]
    return own, nbr


def _frame_tolerance(xyz: XYZ, ring: Mask, index: RemovalIndex, T: np.ndarray) -> Tolerance:
    """:func:`frame_tolerance`'s fast path (``tolerance_mm`` not fixed): one sample, one query of the tree."""
    p = index.params
    lo = max(p.min_tolerance_mm, p.delta_mm)
    if index.tree is None:
        raise ParameterError("bin_residuals_mm: the index has no KD-tree (prepare_removal_index builds it)")
    a = np.asarray(xyz)
    ring_a = np.asarray(ring, dtype=bool)
    if ring_a.shape != a.shape[:2]:
        raise InputShapeError(f"ring must be an {a.shape[:2]} bool array, got {describe_array(ring_a)}")
    steps: np.ndarray | None = None  # the pixel angle's steps of the sample, when the kernels took them
    if a.dtype in (np.float32, np.float64) and a.ndim == 3 and a.shape[2] == 3:
        flat, want, own_at, nb_at, steps = _sample_and_steps(a, np.ascontiguousarray(ring_a), MAX_RESIDUAL_PX)
        queried = _query(a, want, index, T)
        res, nbr = _own_and_neighbours(queried.residual_mm, own_at, nb_at)
        around = _around_median(nbr)
        with np.errstate(invalid="ignore"):
            coherent = np.isfinite(res) & (np.abs(res - around) <= COHERENCE_MM)
    else:  # the arrays the kernels do not take
        flat = _ring_sample(a, ring_a)
        nb = _ring_neighbours(a.shape[:2], ring_a, flat, 4)
        res, around, coherent, queried = _coherent(a, flat, nb, index, T, reference=False)
        own_at = np.searchsorted(queried.flat, flat)
        nb_at = np.where(nb >= 0, np.searchsorted(queried.flat, np.where(nb >= 0, nb, 0)), -1)
    surface = _Surface(a, ring, index, T.copy(), res, around, coherent, queried)
    if len(res) == 0:
        return Tolerance(max(p.max_tolerance_mm, lo), float("nan"), 0, surface=surface)
    n_coh = int(np.count_nonzero(coherent))
    use_coherent = n_coh and n_coh >= MIN_COHERENT_SHARE * len(res) and far_share(res, around) <= MAX_FAR_SHARE
    off = np.zeros(len(res), bool)
    if use_coherent and queried.signed_m is not None and queried.nearest_j is not None:
        # the coherent pixels off the bin's residual field are no bin (parts leaning on a wall)
        off = _off_field_fast(queried, own_at, nb_at, coherent, index.model.normals)
    keep = coherent & ~off
    use = res[keep] if use_coherent else res
    q = _percentile_higher(use, p.residual_quantile)
    tau = min(max(q + p.residual_margin_mm, lo), max(p.max_tolerance_mm, lo)) if np.isfinite(q) \
        else max(p.max_tolerance_mm, lo)
    reach = float("nan")
    if index.model.normals is not None:
        near = _nearest_again(a, flat[keep] if use_coherent else flat, own_at[keep] if use_coherent else own_at,
                              index, T, queried)
        q_near = _percentile_higher(near, p.residual_quantile)
        reach = min(q_near + p.residual_margin_mm, p.max_tolerance_mm) if np.isfinite(q_near) else p.max_tolerance_mm
    sigma_m = bin_sigma_m(use)
    rad = float("nan")
    if np.isfinite(sigma_m):  # pixel_angle(a, flat), its steps taken with the sample
        rad = pixel_angle(a, flat) if steps is None else (_median_of(steps) if steps.size else float("nan"))
    return Tolerance(float(tau), q, len(res), n_coh, float(reach), surface=surface,
                     n_off_field=int(np.count_nonzero(off)), sigma_mm=1000.0 * sigma_m, pixel_rad=rad)


def check_removal_args(
    xyz: XYZ,
    footprint: Mask,
    *,
    model: BinModel | None,
    T_cam_bin: np.ndarray | None,
    delta_m: float,
    rim_offset_m: float,
    straggler_m: float,
    straggler_neighbours: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Validate the arguments of :func:`remove_table_and_bin`; return ``(xyz, footprint)`` as arrays."""
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
    return a, fp


def remove_table_and_bin(
    xyz: XYZ,
    footprint: Mask,
    *,
    index: RemovalIndex | None = None,
    T_cam_bin: np.ndarray | None = None,
    ring: Mask | None = None,
    reference: bool = False,
) -> RemovalResult:
    """Label table, easy outliers and bin points; return the classes and the zone's height image.

    Parameters
    ----------
    xyz : (H, W, 3) float ndarray
        Metres, camera optical frame, NaN = invalid.
    footprint : (H, W) bool ndarray
        The bin footprint (:func:`zcut.binmask.bin_mask`); outside it is table.
    index : RemovalIndex, optional
        The bin model prepared with the removal parameters (:func:`prepare_removal_index`); with
        ``T_cam_bin`` it gives the rim, the floor and the bin points. Without, only the table is
        removed and the floor is the farthest valid point. Its :class:`~zcut.params.RemovalParams`:
        ``delta_mm`` (δ: a point this close to the model surface, point-to-plane when the model has
        normals, else to the nearest model point, is bin; paper: 0.1 mm), ``rim_offset_mm`` (a point
        higher than the rim by more than this is an easy outlier), ``search_radius_mm`` (the
        nearest-model-point search radius of the point-to-plane test; default 1.5 × the model's
        spacing), ``straggler_mm`` and ``straggler_neighbours`` (a second, looser test for the noise
        tail of the bin surface: a remaining pixel with at least ``straggler_neighbours`` of its 8
        neighbours labelled table, bin or invalid, and within ``straggler_mm`` of the model, is bin
        too; repeated up to :data:`STRAGGLER_PASSES` times so that it grows along clumps of such
        pixels; without it a few noisy rim pixels stay in the zone, become its highest points and
        move the z-cut's z_max up to the rim; 0: off). ``mode``: ``"paper"`` uses δ as given;
        ``"robust"`` replaces it by the frame's tolerance (:func:`frame_tolerance`), tests it before
        the rim (a point within τ of the model is bin, not an easy outlier) and lets the
        stragglers reach ``straggler_mm`` beyond τ and beyond the search radius; with ``straggler_bound`` on
        (``"below_rim"``, the default: below the rim's band), along the normal no farther than 3 of the bin's Err at the pixel where the frame
        measured the bin's residual scale (:func:`straggler_bound_m`; ``"below_rim"``: only below the rim's
        band, :func:`straggler_top_m`).
    T_cam_bin : (4, 4) float ndarray, optional
        The registered pose of the model.
    ring : (H, W) bool ndarray, optional
        Robust mode: the frame's certain bin pixels (:func:`zcut.binmask.bin_pixels`, the rim and
        upper walls), whose residuals give τ. Without them τ is ``tolerance_mm`` if set, else
        ``max_tolerance_mm``.
    reference : bool
        The previous implementation (a mask per class, the straggler passes' masks, the tolerance's two
        queries of the model's tree), kept as the oracle of ``tests/zcut/test_removal_fast.py``: the
        same result bit for bit, ~3x the CPU time (``bench/bench_removal.py``).

    Returns
    -------
    RemovalResult
    """
    p = index.params if index is not None else RemovalParams()
    a, fp = check_removal_args(
        xyz, footprint, model=None if index is None else index.model, T_cam_bin=T_cam_bin,
        delta_m=p.delta_m, rim_offset_m=p.rim_offset_m, straggler_m=p.straggler_m,
        straggler_neighbours=p.straggler_neighbours,
    )
    if index is None:
        return _remove_table(a, fp)
    if not a.flags.c_contiguous:
        a = np.ascontiguousarray(a)
    fp = np.ascontiguousarray(fp)
    T = np.asarray(T_cam_bin, dtype=np.float64)
    R, t = np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3])
    up = R @ BIN_UP
    # heights along up = -z in the bin frame; work in the bin frame so that the model's search grid
    # is built once per model, not once per frame
    shift = float(t @ up)  # height of the bin origin along up, camera frame
    rim, floor = index.rim_b + shift, index.floor_b + shift
    planes = index.model.normals is not None
    residual_mm = float("nan")
    surface: _Surface | None = None
    # the stragglers' bound at 3 Err: (σ_bin² m², the pixel's angle); σ² < 0: none
    bound = _NO_BOUND
    if p.robust:
        if ring is not None:
            tol = frame_tolerance(a, ring, index, T, reference=reference)
            surface = tol.surface
        else:
            tol = Tolerance(max(p.tolerance_mm if p.tolerance_mm is not None else p.max_tolerance_mm, p.delta_mm),
                            float("nan"), 0)
        delta_m, residual_mm = tol.tolerance_mm / 1000.0, tol.residual_mm
        bound = straggler_bound_args(p, tol, index.rim_b)
        radius_m = _radius(p, index.model.spacing_m, delta_m)
        straggler_m = p.straggler_m + delta_m if p.straggler_m > 0 else 0.0
        r_str = max(radius_m, straggler_m)
        if p.search_radius_mm is None and np.isfinite(tol.reach_mm):  # a radius given is kept as given
            # measured like τ, a percentile: the stragglers reach straggler_mm beyond it as beyond τ
            radius_m = max(radius_m, tol.reach_mm / 1000.0)
            r_str = max(radius_m + p.straggler_m, straggler_m)
    else:
        delta_m, radius_m, straggler_m = p.delta_m, index.radius_m, p.straggler_m
        r_str = max(radius_m, straggler_m)
    r_bin = radius_m if planes else delta_m
    shape = fp.shape
    plane = abs(up[2]) > 1e-6
    if not reference and plane:  # the classes, masks and heights in one pass; the stragglers relabelled after it
        code = np.empty(shape, np.uint8)
        g = index.bin
        table, easy, binp, zone = (np.empty(shape, bool) for _ in range(4))
        height = np.empty(shape, np.float64)
        rows = _classify_finish(a, fp, R, t, index.rim_b + p.rim_offset_m, delta_m > 0, p.robust, *_grid_args(g),
                                g.ijk, g.busy, g.box, float(delta_m), float(r_bin), planes, float(floor), up,
                                code, table, easy, binp, zone, height)
        if index.straggler is not None:
            r_s = r_str if planes else straggler_m
            done = _straggler_codes(a, code, R, t, index.straggler, straggler_m=straggler_m, radius_m=r_s,
                                    planes=planes, neighbours=int(p.straggler_neighbours), bound=bound)
            if done.shape[0]:
                _relabel_bin(a, done, float(floor), up, binp, zone, height, *rows)
        seen, top = _zone_top_of(*rows)
        cloud = FlooredCloud(a, table, easy, binp, plane=plane, floor_m=float(floor), up_cam=up, z_far_m=float("nan"))
        return RemovalResult(table, easy, binp, zone, height, cloud, rim, floor, up, delta_m * 1000.0, residual_mm,
                             r_bin * 1000.0, surface, _ZoneTop(zone, height, bool(seen), float(top)))
    if not reference:  # a bin seen from the side: the floor is the farthest point, known after the classes
        code = np.empty(shape, np.uint8)
        g = index.bin
        _classify_codes(a, fp, R, t, index.rim_b + p.rim_offset_m, delta_m > 0, p.robust, *_grid_args(g),
                        g.ijk, g.busy, g.box, float(delta_m), float(r_bin), planes, code)
        if index.straggler is not None:
            r_s = r_str if planes else straggler_m
            _straggler_codes(a, code, R, t, index.straggler, straggler_m=straggler_m,
                             radius_m=r_s, planes=planes, neighbours=int(p.straggler_neighbours), bound=bound)
        z_far = np.nan
        if not plane:  # a bin seen from the side: fall back to the farthest point
            z_far = float(np.nanmax(a[..., 2][code != _INVALID])) if (code != _INVALID).any() else np.nan
        table, easy, binp, zone = (np.empty(shape, bool) for _ in range(4))
        height = np.empty(shape, np.float64)
        rows = _finish_codes(a, code, plane, float(floor), up, float(z_far), table, easy, binp, zone, height)
        seen, top = _zone_top_of(*rows)
        cloud = FlooredCloud(a, table, easy, binp, plane=plane, floor_m=float(floor), up_cam=up, z_far_m=float(z_far))
        return RemovalResult(table, easy, binp, zone, height, cloud, rim, floor, up, delta_m * 1000.0, residual_mm,
                             r_bin * 1000.0, surface, _ZoneTop(zone, height, bool(seen), float(top)))
    valid, table, easy, binp = (np.zeros(shape, bool) for _ in range(4))
    _classify(a, fp, R, t, index.rim_b + p.rim_offset_m, delta_m > 0, p.robust, *_grid_args(index.bin),
              float(delta_m), float(r_bin), planes, valid, table, easy, binp)
    if index.straggler is not None:
        r_str = r_str if planes else straggler_m
        lab = np.empty(shape, np.uint8)  # table, bin or invalid: invalid neighbours count as not zone
        open_, first = np.empty(shape, bool), np.empty(shape, bool)
        _straggler_start(valid, table, binp, easy, fp, int(p.straggler_neighbours), lab, open_, first)
        _straggler_passes(a, binp, lab, open_, R, t, index.straggler,
                          straggler_m=straggler_m, radius_m=r_str, planes=planes,
                          neighbours=int(p.straggler_neighbours), first=first, bound=bound)
    labelled = table | easy | binp
    zone = valid & ~labelled
    z_far = np.nan
    if not plane:  # a bin seen from the side: fall back to the farthest point
        z_far = float(np.nanmax(a[..., 2][valid])) if valid.any() else np.nan
    height = np.empty(shape, np.float64)
    xyz_out = np.empty(a.shape, np.float32)
    _finish(a, valid, labelled, plane, float(floor), up, float(z_far), height, xyz_out)
    return RemovalResult(table, easy, binp, zone, height, xyz_out, rim, floor, up, delta_m * 1000.0, residual_mm,
                         r_bin * 1000.0)


def _remove_table(a: np.ndarray, fp: Mask) -> RemovalResult:
    """Without a model: only the table is removed; the floor is the farthest valid point."""
    z64 = a[..., 2].astype(np.float64)
    valid = finite_xyz(a)
    table = valid & ~fp
    zfloor = np.nanmax(z64[valid]) if valid.any() else np.nan
    height = -1000.0 * np.where(table, zfloor, z64)
    height[~valid] = np.nan
    xyz_out = a.astype(np.float32, copy=True)
    xyz_out[..., 2] = np.where(table, zfloor, xyz_out[..., 2]).astype(np.float32)
    nothing = np.zeros_like(valid)
    return RemovalResult(table, nothing, nothing.copy(), valid & ~table, height, xyz_out, float("nan"),
                         float("nan"), BIN_UP.copy())
