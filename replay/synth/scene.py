"""A table, a plastic bin and a pile of parts, as a height field on a world grid (millimetres).

World frame: z up, the table top at z = 0, the camera above the origin. The bin is a rectangular
tub with drafted inner walls, a floor and a flat rim; it stands at a pose (yaw, offset). Parts are
dropped one after another: each falls vertically until its bottom surface touches the current height
field, which it then raises to its top surface. That keeps parts resting on the floor or on each
other and never interpenetrating (in the height-field sense: nothing of a part lies below what was
already there).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numba
import numpy as np

from replay.presets import BIN, PART_KINDS, BinGeometry
from replay.synth.parts import (
    Solid,
    height_profile,
    part_solid,
    random_rest_rotation,
)
from zcut.errors import ParameterError

# surface labels (per grid node, per pixel)
LABEL_NONE = 0
LABEL_TABLE = 1
LABEL_FLOOR = 2
LABEL_WALL = 3
LABEL_RIM = 4
LABEL_PART = 5



#: How a pile lies in the bin (``zcut synth --pile``): ``floor``, parts dropped over the flat floor and
#: kept off the walls (the paper's scenes); ``walls``, parts settled as in a bin tilted towards one wall
#: or a corner, so that they touch and lean on those walls and the pile heaps against them.
PILES = ("floor", "walls")
#: The walls a ``walls`` pile may lean on, as bin-frame outward directions: one wall (+x, -x, +y, -y)
#: or a corner (two adjacent walls); :func:`lean_walls` draws one set per frame.
WALL_SETS: tuple[tuple[str, ...], ...] = (
    ("+x",), ("-x",), ("+y",), ("-y",), ("+x", "+y"), ("+x", "-y"), ("-x", "+y"), ("-x", "-y"))
#: The ``walls`` pile settles as under gravity tilted by this angle towards its walls: a part moves
#: towards them unless that lifts it by more than tan(15°) = 0.27 mm per mm, so the parts reach the
#: walls and the pile's top slopes down from them by about that much.
WALL_TILT_DEG = 15.0
_WALL_DIRS = {"+x": (1.0, 0.0), "-x": (-1.0, 0.0), "+y": (0.0, 1.0), "-y": (0.0, -1.0)}


def check_pile(pile: object) -> str:
    """``pile`` if it is one of :data:`PILES`, else :class:`ParameterError` naming them."""
    if not isinstance(pile, str) or pile not in PILES:
        raise ParameterError(f"pile must be one of {', '.join(PILES)}, got {pile!r}")
    return pile


def lean_walls(seed: int, index: int) -> tuple[str, ...]:
    """The walls frame ``index`` of a ``walls`` pile with ``seed`` leans on (one of :data:`WALL_SETS`).

    Drawn from a generator of its own, so that the bin pose, the fill and everything else a frame
    draws are those of the ``floor`` pile with the same seed, and both generators lean on the same
    walls for the same seed and frame.
    """
    rng = np.random.default_rng([int(seed) % (2**63), int(index), 0x3A115])
    return WALL_SETS[int(rng.integers(len(WALL_SETS)))]


def tilt_vector(walls: tuple[str, ...], tilt_deg: float = WALL_TILT_DEG) -> tuple[float, float]:
    """Bin-frame (u, v) of the horizontal pull towards ``walls``: tan(tilt) times the unit vector
    towards them (the corner's diagonal for two walls); (0, 0) for none."""
    if not walls:
        return 0.0, 0.0
    for w in walls:
        if w not in _WALL_DIRS:
            raise ParameterError(f"walls must be of {', '.join(_WALL_DIRS)}, got {w!r}")
    du = sum(_WALL_DIRS[w][0] for w in walls)
    dv = sum(_WALL_DIRS[w][1] for w in walls)
    n = math.hypot(du, dv)
    if n == 0:
        raise ParameterError(f"walls {walls!r} pull nowhere (opposite walls)")
    k = math.tan(math.radians(tilt_deg)) / n
    return du * k, dv * k


def wall_distance_mm(p: np.ndarray, geometry: BinGeometry = BIN) -> np.ndarray:
    """Distance (mm) from bin-frame points to the nearest inner wall face of the nominal bin.

    ``p``: (..., 3) in the scene's bin frame (u, v along the bin's length and width from its
    centre, z up, the table at 0), millimetres. Each wall face is the drafted plane from the floor's
    edge up to the rim's inner edge; a point's foot on a face is clamped to the face's height
    (floor to rim) and then to its length at that height (exact on the face and beside its middle;
    at the corners it may overstate the distance by a fraction of the draft). NaN where ``p`` is not
    finite.
    """
    p = np.asarray(p, np.float64)
    fx, fy = geometry.floor_half
    d = math.radians(geometry.draft_deg)
    c, s = math.cos(d), math.sin(d)
    f, h = geometry.floor_mm, geometry.height_mm
    slope_len = (h - f) / c
    best = np.full(p.shape[:-1], np.inf)
    for axis, half, other_half in ((0, fx, fy), (1, fy, fx)):
        a = p[..., axis]
        b = p[..., 1 - axis]
        z = p[..., 2]
        for sign in (1.0, -1.0):
            x = sign * a - half  # outward from the floor's edge
            # face coordinates: t up the slope from the floor edge, n the signed distance along the inward normal
            t = x * s + (z - f) * c
            n = -x * c + (z - f) * s
            tc = np.clip(t, 0.0, slope_len)
            width = other_half + tc * s  # the face's half length at that height (the draft widens it)
            bc = np.clip(b, -width, width)
            # the clamped foot back in (x, z): x = tc*s - 0*c, z - f = tc*c
            dx = x - tc * s
            dz = (z - f) - tc * c
            dist = np.sqrt(dx * dx + dz * dz + (b - bc) ** 2)
            dist = np.where(t == tc, np.sqrt(n * n + (b - bc) ** 2), dist)
            best = np.fmin(best, dist)
    return np.where(np.isfinite(p).all(axis=-1), best, np.nan)


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


#: Largest bulge or deformation amplitude (mm) and scale deviation the generator accepts: beyond
#: them the height-field bin stops being a plastic tub (walls through the rim, a folded floor).
MAX_BIN_SHAPE_MM = 20.0
MAX_BIN_SCALE_DEVIATION = 0.05


@dataclass(frozen=True, slots=True)
class BinShape:
    """How the scanned bin differs from the nominal one (:data:`replay.presets.BIN`, the CAD bin).

    A bin model made from a CAD file is the nominal bin; the real one is a little larger or smaller,
    its walls bulge under the load of the pile, and a plastic tub flexes between scans. These knobs
    make such bins, so that the bin stages can be measured against a model that is not the bin.

    Attributes
    ----------
    scale : float
        The whole bin scaled about its centre on the table (1: nominal; 1.002 adds 0.8 mm to its
        length, 0.24 mm to its height).
    bulge_mm : float
        Outward bulge of every inner wall (negative: inward): largest halfway along the wall and
        halfway down it, none at the corners, at the rim and at the floor.
    deform_mm : float
        Amplitude of a deformation drawn anew for every scan: each wall's bulge changes by up to
        ±``deform_mm`` and the bin twists (two opposite corners rise, the other two sink, by up to
        ``deform_mm``).
    """

    scale: float = 1.0
    bulge_mm: float = 0.0
    deform_mm: float = 0.0

    def __post_init__(self) -> None:
        checks: tuple[tuple[str, float, Callable[[float], bool]], ...] = (
            ("scale", self.scale, lambda x: abs(x - 1.0) <= MAX_BIN_SCALE_DEVIATION),
            ("bulge_mm", self.bulge_mm, lambda x: abs(x) <= MAX_BIN_SHAPE_MM),
            ("deform_mm", self.deform_mm, lambda x: 0.0 <= x <= MAX_BIN_SHAPE_MM))
        for name, v, ok in checks:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not ok(float(v)):
                limits = {"scale": f"within {MAX_BIN_SCALE_DEVIATION:g} of 1",
                          "bulge_mm": f"within ±{MAX_BIN_SHAPE_MM:g} mm",
                          "deform_mm": f"in [0, {MAX_BIN_SHAPE_MM:g}] mm"}[name]
                raise ParameterError(f"BinShape.{name} must be a number {limits}, got {v!r}")
            object.__setattr__(self, name, float(v))

    @property
    def nominal(self) -> bool:
        """The nominal bin (no scale, bulge or deformation)."""
        return self.scale == 1.0 and self.bulge_mm == 0.0 and self.deform_mm == 0.0

    def realise(self, rng: np.random.Generator | None) -> BinDeformation:
        """This scan's bin: the fixed scale and bulge plus a deformation drawn from ``rng`` (needed
        only when ``deform_mm`` > 0)."""
        bulges = np.full(4, self.bulge_mm)
        twist = 0.0
        if self.deform_mm > 0:
            if rng is None:
                raise ParameterError("BinShape.realise: deform_mm > 0 needs a random generator")
            bulges = bulges + rng.uniform(-self.deform_mm, self.deform_mm, 4)
            twist = float(rng.uniform(-self.deform_mm, self.deform_mm))
        return BinDeformation(self.scale, tuple(float(b) for b in bulges), twist)  # type: ignore[arg-type]  # four walls


@dataclass(frozen=True, slots=True)
class BinDeformation:
    """One scan's bin shape (:meth:`BinShape.realise`).

    Attributes
    ----------
    scale : float
    bulges_mm : tuple of 4 floats
        Outward bulge of the walls at bin-frame +x, -x, +y, -y.
    twist_mm : float
        Height added at the (+x, +y) and (-x, -y) corners, taken from the other two.
    """

    scale: float = 1.0
    bulges_mm: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    twist_mm: float = 0.0

    def geometry(self, nominal: BinGeometry = BIN) -> BinGeometry:
        """The nominal geometry scaled (the draft angle kept)."""
        if self.scale == 1.0:
            return nominal
        k = self.scale
        return replace(nominal, outer_length_mm=nominal.outer_length_mm * k, outer_width_mm=nominal.outer_width_mm * k,
                       height_mm=nominal.height_mm * k, rim_mm=nominal.rim_mm * k, floor_mm=nominal.floor_mm * k)

    def rim_top_mm(self, nominal: BinGeometry = BIN) -> float:
        """The highest point of the rim above the table (mm)."""
        return self.geometry(nominal).height_mm + abs(self.twist_mm)


NOMINAL_DEFORMATION = BinDeformation()


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
    solid : (primitives, hole) or None
        The part's solid in its local frame (:func:`replay.synth.parts.part_solid`), from which
        ``replay.synth.surfaces`` builds its exact surface (all faces, hidden ones included).
    """

    rows: slice
    cols: slice
    bottom: np.ndarray
    top: np.ndarray
    R: np.ndarray
    centre_mm: np.ndarray
    solid: Solid | None = None


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
    deformation : BinDeformation
        How the bin differs from the nominal one.
    walls : tuple of str
        The walls the pile leans on (:data:`WALL_SETS`; empty: a ``floor`` pile).
    """

    grid: Grid
    height: np.ndarray
    label: np.ndarray
    part_id: np.ndarray
    bin_height: np.ndarray
    parts: tuple[PlacedPart, ...]
    kind: str | None
    bin_pose: BinPose
    deformation: BinDeformation = NOMINAL_DEFORMATION
    walls: tuple[str, ...] = ()


def make_grid(*, half_x_mm: float, half_y_mm: float, step_mm: float) -> Grid:
    """A grid centred on the world origin covering [-half_x, half_x] x [-half_y, half_y]."""
    nx = int(np.ceil(2 * half_x_mm / step_mm)) + 1
    ny = int(np.ceil(2 * half_y_mm / step_mm)) + 1
    return Grid(-step_mm * (nx - 1) / 2, -step_mm * (ny - 1) / 2, step_mm, nx, ny)


def bin_height_field(grid: Grid, pose: BinPose, geometry: BinGeometry = BIN,
                     deformation: BinDeformation = NOMINAL_DEFORMATION) -> tuple[np.ndarray, np.ndarray]:
    """Height (mm) and LABEL_* of the table plus the empty bin at every grid node.

    ``deformation`` scales ``geometry``, moves each inner wall outward by its bulge times
    cos(π/2 · position along the wall) · sin(π · height up the wall) (zero at the corners, the floor
    and the rim), and adds the twist times (u / half length)(v / half width) to the whole bin.

    Returns
    -------
    height : (ny, nx) float64 ndarray
    label : (ny, nx) uint8 ndarray
    """
    geometry = deformation.geometry(geometry)
    X, Y = np.meshgrid(grid.xs - pose.x_mm, grid.ys - pose.y_mm)
    c, s = np.cos(pose.yaw_rad), np.sin(pose.yaw_rad)
    u = c * X + s * Y  # bin frame
    v = -s * X + c * Y
    a = np.abs(u)
    b = np.abs(v)
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
    if any(deformation.bulges_mm):
        # how far up the wall each node is (0 floor, 1 rim): no bulge at either end
        up_wall = np.clip((wall_z - geometry.floor_mm) / (geometry.height_mm - geometry.floor_mm), 0.0, 1.0)
        depth = np.sin(np.pi * up_wall)
        bx = np.where(u >= 0, deformation.bulges_mm[0], deformation.bulges_mm[1])
        by = np.where(v >= 0, deformation.bulges_mm[2], deformation.bulges_mm[3])
        ex = bx * np.cos(0.5 * np.pi * np.clip(v / iy, -1.0, 1.0)) * depth
        ey = by * np.cos(0.5 * np.pi * np.clip(u / ix, -1.0, 1.0)) * depth
        beyond = np.maximum(a - fx - ex, b - fy - ey)
        wall_z = np.minimum(geometry.floor_mm + np.maximum(beyond, 0.0) / tan_d, geometry.height_mm)
    height[inside_inner] = wall_z[inside_inner]
    label[inside_inner] = np.where(beyond[inside_inner] > 0, LABEL_WALL, LABEL_FLOOR)
    if deformation.twist_mm:
        height[inside_outer] += deformation.twist_mm * (u[inside_outer] / ox) * (v[inside_outer] / oy)
    return height, label


def bin_mesh_mm(geometry: BinGeometry = BIN) -> tuple[np.ndarray, np.ndarray]:
    """The nominal bin as a CAD mesh: the rim, the drafted inner walls, the floor, the outer walls.

    World frame of the scene (z up, the table at z = 0, the bin centred on the origin, yaw 0),
    millimetres.

    Returns
    -------
    vertices : (16, 3) float64 ndarray
    faces : (M, 3) int64 ndarray
        Triangles.
    """
    ox, oy = geometry.outer_length_mm / 2, geometry.outer_width_mm / 2
    ix, iy = geometry.inner_top_half
    fx, fy = geometry.floor_half
    h, f = geometry.height_mm, geometry.floor_mm

    def rect(hx: float, hy: float, z: float) -> list[tuple[float, float, float]]:  # corners counter-clockwise from (+x, +y)
        return [(hx, hy, z), (-hx, hy, z), (-hx, -hy, z), (hx, -hy, z)]

    vertices = np.array(rect(ox, oy, h) + rect(ix, iy, h) + rect(fx, fy, f) + rect(ox, oy, 0.0), np.float64)
    outer_top, inner_top, floor, outer_bottom = 0, 4, 8, 12
    faces = []
    for i in range(4):  # a band of quads between two rectangles
        j = (i + 1) % 4
        for a, b in ((outer_top, inner_top), (inner_top, floor), (outer_bottom, outer_top)):
            faces += [(a + i, a + j, b + j), (a + i, b + j, b + i)]
    faces += [(floor, floor + 1, floor + 2), (floor, floor + 2, floor + 3)]
    return vertices, np.array(faces, np.int64)


@numba.njit(cache=True, nogil=True)
def _rest(height, lo_hit, di, dj, n, x0, y0, g, R2, tx, ty, lim_u, lim_v, u, v):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
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
def _settle(height, lo_hit, di, dj, n, x0, y0, g, R2, tx, ty, lim_u, lim_v, us, vs, roll, finest, rounds, gu, gv):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover
    """Lowest rest among the drop points (us, vs), then downhill moves in 8 directions, ``rounds`` at most of
    ``roll`` mm, then as many of half that, and so on down to ``finest`` mm; return (base, row, col), base -inf
    if no drop point lands on the grid.

    "Lowest" is the potential: the resting base minus gu·u + gv·v, gravity tilted by (gu, gv) in the bin
    frame. The floor pile calls it with no tilt (0, 0: the potential is the base itself), 8 rounds and
    ``finest = roll`` (moves of ``roll`` only); the pile against walls with the tilt, 64 rounds and
    ``finest`` one grid step, so that a part slides on until it touches what stops it (a wall, another part)."""
    best_p, best_b, best_i, best_j, best_u, best_v = np.inf, -np.inf, 0, 0, 0.0, 0.0
    for k in range(us.size):
        b, ci, cj, u, v = _rest(height, lo_hit, di, dj, n, x0, y0, g, R2, tx, ty, lim_u, lim_v, us[k], vs[k])
        if b != -np.inf:
            p = b - gu * u - gv * v
            if p < best_p:
                best_p, best_b, best_i, best_j, best_u, best_v = p, b, ci, cj, u, v
    if best_b == -np.inf:
        return best_b, best_i, best_j
    step = roll
    while True:
        for _ in range(rounds):
            moved = False
            for a in range(8):
                u = best_u + step * np.cos(a * np.pi / 4)
                v = best_v + step * np.sin(a * np.pi / 4)
                b, ci, cj, u, v = _rest(height, lo_hit, di, dj, n, x0, y0, g, R2, tx, ty, lim_u, lim_v, u, v)
                if b != -np.inf:
                    p = b - gu * u - gv * v
                    if p < best_p - 1e-9:
                        best_p, best_b, best_i, best_j, best_u, best_v = p, b, ci, cj, u, v
                        moved = True
            if not moved:
                break
        if step <= finest:
            break
        step = max(0.5 * step, finest)
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
    deformation: BinDeformation = NOMINAL_DEFORMATION,
    walls: tuple[str, ...] = (),
) -> Scene:
    """Drop parts of ``kind`` into the bin until the mean pile height above the floor reaches ``fill_mm``.

    ``deformation`` changes the bin, not the pile: the parts settle in the nominal bin (the same
    seed drops the very same pile), which is then replaced by the deformed one under them. The
    parts lie over the flat floor, which a scale moves by thousandths of a millimetre and a bulge
    not at all; a twist tilts it by up to 0.7 × ``twist_mm`` at the floor's corners, where a part
    then floats or sinks by as much.

    Each part gets a random resting orientation and a position (snapped to the grid) whose footprint
    stays over the flat floor; it falls straight down until it touches the height field. Of
    ``settle_tries`` drop points around a random one, the part keeps the one where it rests lowest and
    then moves downhill in steps of half its radius while that lowers it (a crude stand-in for
    rolling and sliding into gaps, which packs the pile densely and keeps its top nearly level).

    ``walls`` (of :data:`WALL_SETS`; empty: the floor pile above) piles the parts against those
    walls instead: a part may lie anywhere inside the rim's opening, over the floor or on the drafted
    walls, and settles as in a bin tilted by :data:`WALL_TILT_DEG` towards them (it takes the drop
    point and then the moves, down to one grid step, that lower its resting base minus the tilt's
    pull), so it slides until a wall or another part stops it. The fill level is then the mean over
    the whole floor, and a part that would stick out above the rim is dropped elsewhere (after 200
    such in a row the pile is full). Only the nominal bin (``deformation`` must be the nominal one).
    """
    walls = tuple(walls)
    gu, gv = tilt_vector(walls)
    if walls and deformation != NOMINAL_DEFORMATION:
        raise ParameterError("a pile against the walls needs the nominal bin (no scale, bulge or deformation)")
    height, label = bin_height_field(grid, pose, geometry)
    bin_height = height.copy()
    part_id = np.zeros(height.shape, np.int32)
    fxh, fyh = geometry.floor_half
    R2 = pose.R
    # the fill level is measured over the floor away from the walls (parts keep off the walls)
    X, Y = np.meshgrid(grid.xs - pose.x_mm, grid.ys - pose.y_mm)
    c, s = np.cos(pose.yaw_rad), np.sin(pose.yaw_rad)
    margin = min(PART_KINDS[kind].bounding_radius_mm + 5.0, 0.4 * min(fxh, fyh)) if not walls else 0.0
    ixh, iyh = geometry.inner_top_half
    rejected = 0
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
        lim_u, lim_v = (fxh - extent, fyh - extent) if not walls else (ixh - extent, iyh - extent)
        u0 = rng.uniform(-lim_u, lim_u)
        v0 = rng.uniform(-lim_v, lim_v)
        jitter = rng.uniform(-2.0, 2.0, (settle_tries, 2)) * r
        jitter[0] = 0.0
        best = _settle(
            height, lo[hit], ii - n, jj - n, n, grid.x0, grid.y0, g, R2, pose.x_mm, pose.y_mm,
            lim_u, lim_v, u0 + jitter[:, 0], v0 + jitter[:, 1], 0.5 * r, g if walls else 0.5 * r,
            64 if walls else 8, gu, gv,
        )
        if best[0] == -np.inf:
            continue
        base, ci, cj = best[0], int(best[1]), int(best[2])
        rows = slice(ci - n, ci + n + 1)
        cols = slice(cj - n, cj + n + 1)
        win = height[rows, cols]
        bottom = lo + base
        top = hi + base
        if walls:
            if float(np.nanmax(top)) > geometry.height_mm:  # it would stick out of the bin
                rejected += 1
                if rejected >= 200:
                    break
                continue
            rejected = 0
        raise_ = hit & (top > win)
        win[raise_] = top[raise_]
        label[rows, cols][raise_] = LABEL_PART
        part_id[rows, cols][raise_] = len(parts) + 1
        centre = np.array([grid.x0 + cj * g, grid.y0 + ci * g, base])
        parts.append(
            PlacedPart(rows, cols, bottom.astype(np.float32), top.astype(np.float32), R, centre, (prims, hole))
        )
    if deformation != NOMINAL_DEFORMATION:  # the same pile in the deformed bin
        height, label = bin_height_field(grid, pose, geometry, deformation)
        bin_height = height.copy()
        part_id = np.zeros(height.shape, np.int32)
        for i, p in enumerate(parts):
            win = height[p.rows, p.cols]
            raise_ = np.isfinite(p.top) & (p.top > win)
            win[raise_] = p.top[raise_]
            label[p.rows, p.cols][raise_] = LABEL_PART
            part_id[p.rows, p.cols][raise_] = i + 1
    return Scene(grid, height, label, part_id, bin_height, tuple(parts), kind, pose, deformation, walls)


def empty_scene(grid: Grid, pose: BinPose, *, geometry: BinGeometry = BIN,
                deformation: BinDeformation = NOMINAL_DEFORMATION) -> Scene:
    """The table and the empty bin."""
    height, label = bin_height_field(grid, pose, geometry, deformation)
    return Scene(grid, height, label, np.zeros(height.shape, np.int32), height.copy(), (), None, pose, deformation)
