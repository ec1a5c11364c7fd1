"""A table, a plastic bin and a pile of parts, as a height field on a world grid (millimetres).

World frame: z up, the table top at z = 0, the camera above the origin. The bin is a rectangular
tub with drafted inner walls, a floor and a flat rim; it stands at a pose (yaw, offset). Parts are
dropped one after another: each falls vertically until its bottom surface touches the current height
field, which it then raises to its top surface. That keeps parts resting on the floor or on each
other and never interpenetrating (in the height-field sense: nothing of a part lies below what was
already there).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from replay.presets import BIN, PART_KINDS, BinGeometry
from replay.synth.parts import (
    height_profile,
    part_solid,
    random_rest_rotation,
)

# surface labels (per grid node, per pixel)
LABEL_NONE = 0
LABEL_TABLE = 1
LABEL_FLOOR = 2
LABEL_WALL = 3
LABEL_RIM = 4
LABEL_PART = 5



# Bright plastic bin on a dark table (paper §5.1 segments the bin by grey level).
BIN_COLOUR = (224, 220, 208)
TABLE_COLOUR = (52, 50, 56)


@dataclass(frozen=True, slots=True)
class BinPose:
    """Bin placement on the table: yaw about the vertical (rad) and offset of its centre (mm)."""

    yaw_rad: float = 0.0
    x_mm: float = 0.0
    y_mm: float = 0.0

    @property
    def R(self) -> np.ndarray:
        """(2, 2) rotation bin -> world."""
        c, s = np.cos(self.yaw_rad), np.sin(self.yaw_rad)
        return np.array([[c, -s], [s, c]])


@dataclass(frozen=True, slots=True)
class Grid:
    """World grid of height-field nodes: node (i, j) is at x = x0 + j*step, y = y0 + i*step (mm)."""

    x0: float
    y0: float
    step: float
    nx: int
    ny: int

    @property
    def xs(self) -> np.ndarray:
        return self.x0 + self.step * np.arange(self.nx)

    @property
    def ys(self) -> np.ndarray:
        return self.y0 + self.step * np.arange(self.ny)


@dataclass(frozen=True, slots=True)
class PlacedPart:
    """One dropped part: its footprint window on the grid and its bottom / top surfaces there.

    Attributes
    ----------
    rows, cols : slice
        Window of grid nodes.
    bottom, top : (h, w) float32 ndarray
        World z (mm) of the part's lowest / highest point on each node's vertical; NaN off the part.
    R : (3, 3) float64 ndarray
        Rotation local -> world.
    centre_mm : (3,) float64 ndarray
        World position of the part origin.
    """

    rows: slice
    cols: slice
    bottom: np.ndarray
    top: np.ndarray
    R: np.ndarray
    centre_mm: np.ndarray


@dataclass(frozen=True, slots=True)
class Scene:
    """The height field the sensor sees.

    Attributes
    ----------
    grid : Grid
    height : (ny, nx) float64 ndarray
        World z (mm) of the top surface at each node.
    label : (ny, nx) uint8 ndarray
        LABEL_* of the top surface.
    part_id : (ny, nx) int32 ndarray
        1-based index into ``parts`` where the top surface is a part, else 0.
    bin_height : (ny, nx) float64 ndarray
        The empty bin and table alone (what the parts were dropped onto).
    parts : tuple of PlacedPart
    kind : str or None
        Part kind, None for an empty bin.
    bin_pose : BinPose
    """

    grid: Grid
    height: np.ndarray
    label: np.ndarray
    part_id: np.ndarray
    bin_height: np.ndarray
    parts: tuple[PlacedPart, ...]
    kind: str | None
    bin_pose: BinPose


def make_grid(*, half_x_mm: float, half_y_mm: float, step_mm: float) -> Grid:
    """A grid centred on the world origin covering [-half_x, half_x] x [-half_y, half_y]."""
    nx = int(np.ceil(2 * half_x_mm / step_mm)) + 1
    ny = int(np.ceil(2 * half_y_mm / step_mm)) + 1
    return Grid(-step_mm * (nx - 1) / 2, -step_mm * (ny - 1) / 2, step_mm, nx, ny)


def bin_height_field(grid: Grid, pose: BinPose, geometry: BinGeometry = BIN) -> tuple[np.ndarray, np.ndarray]:
    """Height (mm) and LABEL_* of the table plus the empty bin at every grid node.

    Returns
    -------
    height : (ny, nx) float64 ndarray
    label : (ny, nx) uint8 ndarray
    """
    X, Y = np.meshgrid(grid.xs - pose.x_mm, grid.ys - pose.y_mm)
    c, s = np.cos(pose.yaw_rad), np.sin(pose.yaw_rad)
    a = np.abs(c * X + s * Y)  # bin-frame |u|
    b = np.abs(-s * X + c * Y)  # bin-frame |v|
    ox, oy = geometry.outer_length_mm / 2, geometry.outer_width_mm / 2
    ix, iy = geometry.inner_top_half
    fx, fy = geometry.floor_half
    tan_d = np.tan(np.radians(geometry.draft_deg))
    height = np.zeros(X.shape)
    label = np.full(X.shape, LABEL_TABLE, np.uint8)
    inside_outer = (a <= ox) & (b <= oy)
    inside_inner = (a < ix) & (b < iy)
    rim = inside_outer & ~inside_inner
    height[rim] = geometry.height_mm
    label[rim] = LABEL_RIM
    beyond = np.maximum(a - fx, b - fy)
    wall_z = geometry.floor_mm + np.maximum(beyond, 0.0) / tan_d
    wall_z = np.minimum(wall_z, geometry.height_mm)
    height[inside_inner] = wall_z[inside_inner]
    label[inside_inner] = np.where(beyond[inside_inner] > 0, LABEL_WALL, LABEL_FLOOR)
    return height, label


@numba.njit(cache=True, nogil=True)
def _rest(height, lo_hit, di, dj, n, x0, y0, g, R2, tx, ty, lim_u, lim_v, u, v):  # pragma: no cover - numba
    """Resting base (mm) of a part whose origin is dropped at bin-frame (u, v); -inf if off-grid."""
    u = min(max(u, -lim_u), lim_u)
    v = min(max(v, -lim_v), lim_v)
    wx = R2[0, 0] * u + R2[0, 1] * v + tx
    wy = R2[1, 0] * u + R2[1, 1] * v + ty
    cj = int(np.rint((wx - x0) / g))
    ci = int(np.rint((wy - y0) / g))
    ny, nx = height.shape
    if ci - n < 0 or cj - n < 0 or ci + n + 1 > ny or cj + n + 1 > nx:
        return -np.inf, ci, cj, u, v
    b = -np.inf
    for k in range(lo_hit.size):
        d = height[ci + di[k], cj + dj[k]] - lo_hit[k]
        if d > b:
            b = d
    return b, ci, cj, u, v


@numba.njit(cache=True, nogil=True)
def _settle(height, lo_hit, di, dj, n, x0, y0, g, R2, tx, ty, lim_u, lim_v, us, vs, roll):  # pragma: no cover
    """Lowest rest among the drop points (us, vs), then downhill moves of ``roll`` mm in 8 directions."""
    best_b, best_i, best_j, best_u, best_v = -np.inf, 0, 0, 0.0, 0.0
    for k in range(us.size):
        b, ci, cj, u, v = _rest(height, lo_hit, di, dj, n, x0, y0, g, R2, tx, ty, lim_u, lim_v, us[k], vs[k])
        if b != -np.inf and (best_b == -np.inf or b < best_b):
            best_b, best_i, best_j, best_u, best_v = b, ci, cj, u, v
    if best_b == -np.inf:
        return best_b, best_i, best_j
    for _ in range(8):
        moved = False
        for a in range(8):
            u = best_u + roll * np.cos(a * np.pi / 4)
            v = best_v + roll * np.sin(a * np.pi / 4)
            b, ci, cj, u, v = _rest(height, lo_hit, di, dj, n, x0, y0, g, R2, tx, ty, lim_u, lim_v, u, v)
            if b != -np.inf and b < best_b - 1e-9:
                best_b, best_i, best_j, best_u, best_v = b, ci, cj, u, v
                moved = True
        if not moved:
            break
    return best_b, best_i, best_j


def drop_pile(
    grid: Grid,
    pose: BinPose,
    kind: str,
    rng: np.random.Generator,
    *,
    geometry: BinGeometry = BIN,
    fill_mm: float = 45.0,
    max_parts: int = 4000,
    settle_tries: int = 16,
) -> Scene:
    """Drop parts of ``kind`` into the bin until the mean pile height above the floor reaches ``fill_mm``.

    Each part gets a random resting orientation and a position (snapped to the grid) whose footprint
    stays over the flat floor; it falls straight down until it touches the height field. Of
    ``settle_tries`` drop points around a random one, the part keeps the one where it rests lowest and
    then moves downhill in steps of half its radius while that lowers it (a crude stand-in for
    rolling and sliding into gaps, which packs the pile densely and keeps its top nearly level).
    """
    height, label = bin_height_field(grid, pose, geometry)
    bin_height = height.copy()
    part_id = np.zeros(height.shape, np.int32)
    fxh, fyh = geometry.floor_half
    R2 = pose.R
    # the fill level is measured over the floor away from the walls (parts keep off the walls)
    X, Y = np.meshgrid(grid.xs - pose.x_mm, grid.ys - pose.y_mm)
    c, s = np.cos(pose.yaw_rad), np.sin(pose.yaw_rad)
    margin = min(PART_KINDS[kind].bounding_radius_mm + 5.0, 0.4 * min(fxh, fyh))
    floor_nodes = (np.abs(c * X + s * Y) < fxh - margin) & (np.abs(-s * X + c * Y) < fyh - margin)
    del X, Y
    parts: list[PlacedPart] = []
    g = grid.step
    while len(parts) < max_parts:
        if len(parts) % 25 == 0 and len(parts) > 0:
            if float(np.mean(height[floor_nodes])) - geometry.floor_mm >= fill_mm:
                break
        prims, hole = part_solid(kind, rng)
        R = random_rest_rotation(kind, rng)
        r = PART_KINDS[kind].bounding_radius_mm
        n = int(np.ceil(r / g)) + 1
        rel = g * np.arange(-n, n + 1)
        lo, hi = height_profile(prims, hole, R, rel, rel)
        hit = np.isfinite(lo)
        ii, jj = np.nonzero(hit)
        extent = float(np.max(np.hypot(rel[ii[:, None]], rel[jj[:, None]]))) + g
        if extent >= min(fxh, fyh):
            continue
        # settle: of a few nearby drop points the part takes the one where it rests lowest, then
        # rolls downhill (moves of half its radius while that lowers it)
        lim_u, lim_v = fxh - extent, fyh - extent
        u0 = rng.uniform(-lim_u, lim_u)
        v0 = rng.uniform(-lim_v, lim_v)
        jitter = rng.uniform(-2.0, 2.0, (settle_tries, 2)) * r
        jitter[0] = 0.0
        best = _settle(
            height, lo[hit], ii - n, jj - n, n, grid.x0, grid.y0, g, R2, pose.x_mm, pose.y_mm,
            lim_u, lim_v, u0 + jitter[:, 0], v0 + jitter[:, 1], 0.5 * r,
        )
        if best[0] == -np.inf:
            continue
        base, ci, cj = best[0], int(best[1]), int(best[2])
        rows = slice(ci - n, ci + n + 1)
        cols = slice(cj - n, cj + n + 1)
        win = height[rows, cols]
        bottom = lo + base
        top = hi + base
        raise_ = hit & (top > win)
        win[raise_] = top[raise_]
        label[rows, cols][raise_] = LABEL_PART
        part_id[rows, cols][raise_] = len(parts) + 1
        centre = np.array([grid.x0 + cj * g, grid.y0 + ci * g, base])
        parts.append(
            PlacedPart(rows, cols, bottom.astype(np.float32), top.astype(np.float32), R, centre)
        )
    return Scene(grid, height, label, part_id, bin_height, tuple(parts), kind, pose)


def empty_scene(grid: Grid, pose: BinPose, *, geometry: BinGeometry = BIN) -> Scene:
    """The table and the empty bin."""
    height, label = bin_height_field(grid, pose, geometry)
    return Scene(grid, height, label, np.zeros(height.shape, np.int32), height.copy(), (), None, pose)
