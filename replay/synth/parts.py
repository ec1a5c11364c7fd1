"""The paper's six part kinds (Figure 8) as solids made of convex primitives, in millimetres.

Every part is a union of convex primitives (polygon prisms given as half-spaces, spheres) minus at
most one convex hole. A part is placed by a rotation ``R`` (3 x 3) and a translation; its
*height profile* on a world grid is, for every vertical line through a grid node, the lowest and the
highest point of the solid on that line (a height-field footprint, which is all a top-down scene
needs).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from replay.presets import HEX_M_MM as _HEX_M
from replay.presets import HEX_S_MM as _HEX_S
from replay.presets import NUT_BORE_MM as _NUT_BORE
from replay.presets import SPROCKET_BORE_MM as _SPROCKET_BORE
from replay.presets import SPROCKET_R_ROOT_MM as _SPROCKET_R_ROOT
from replay.presets import SPROCKET_R_TIP_MM as _SPROCKET_R_TIP
from replay.presets import SPROCKET_T_MM as _SPROCKET_T
from replay.presets import SPROCKET_TEETH as _SPROCKET_TEETH
from replay.presets import PartKind
from replay.synth.trig import cos_sin

# Display colours (RGB, before shading).
PART_COLOURS: dict[str, tuple[int, int, int]] = {
    "spheres": (200, 202, 208),
    "zinc_nuts": (205, 204, 188),
    "rods": (178, 178, 184),
    "black_screws": (38, 37, 40),
    "black_nuts": (33, 33, 36),
    "sprockets": (185, 172, 150),
}


def face_area_px(kind: PartKind, *, fx: float, fy: float, distance_m: float) -> float:
    """Pixel count of the part's largest face seen from ``distance_m`` (``a_max`` of paper eq. 5).

    Parameters
    ----------
    kind : PartKind
    fx, fy : float
        Focal lengths in pixels.
    distance_m : float
        Camera-to-surface distance in metres.
    """
    footprint_x_mm = 1000.0 * distance_m / fx
    footprint_y_mm = 1000.0 * distance_m / fy
    return float(kind.face_area_mm2 / (footprint_x_mm * footprint_y_mm))


# ---------------------------------------------------------------------------------------------
# Primitives: ("poly", normals (k, 3), offsets (k,), centre (3,), radius, outline (n, 2), z0, z1, R)
#                 = {p : normals @ p <= offsets}, inside the ball (centre, radius); a prism: the convex
#                 counter-clockwise ``outline`` extruded from z0 to z1, then rotated by R (None: not
#                 rotated), which the true-surface meshes of ``replay.synth.surfaces`` are built from;
#             ("sphere", centre (3,), radius).
#: one primitive (the layouts above): its fields differ by kind, so to mypy it is a tuple of Any
Primitive = tuple[Any, ...]
#: a part's solid: the primitives of the union and the primitive subtracted (None: no hole)
Solid = tuple[list[Primitive], Primitive | None]


def _regular_polygon(n: int, circumradius: float, phase: float = 0.0) -> np.ndarray:
    a = phase + 2.0 * np.pi * np.arange(n) / n
    c, s = cos_sin(a)  # the C library's, not numpy's SIMD kernels: the same vertices on every CPU
    return np.stack([circumradius * c, circumradius * s], axis=1)


def _prism(poly: np.ndarray, z0: float, z1: float, R: np.ndarray | None = None) -> Primitive:
    """Convex prism {(x, y) in poly (CCW), z0 <= z <= z1}, optionally rotated by R about the origin."""
    nxt = np.roll(poly, -1, axis=0)
    edge = nxt - poly
    normals2 = np.stack([edge[:, 1], -edge[:, 0]], axis=1)
    normals2 /= np.linalg.norm(normals2, axis=1, keepdims=True)
    offsets = np.einsum("ij,ij->i", normals2, poly)
    normals = np.concatenate([np.c_[normals2, np.zeros(len(poly))], [[0, 0, 1.0], [0, 0, -1.0]]])
    offsets = np.concatenate([offsets, [z1, -z0]])
    verts = np.concatenate([np.c_[poly, np.full(len(poly), z0)], np.c_[poly, np.full(len(poly), z1)]])
    centre = verts.mean(axis=0)
    radius = float(np.max(np.linalg.norm(verts - centre, axis=1)))
    if R is not None:
        normals = normals @ R.T
        centre = R @ centre
    return ("poly", normals, offsets, centre, radius, poly, float(z0), float(z1), R)


_ALONG_X = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # maps local z to x


def _cylinder_x(radius: float, x0: float, x1: float, sides: int = 40, phase: float = 0.0) -> Primitive:
    return _prism(_regular_polygon(sides, radius / math.cos(np.pi / sides), phase), x0, x1, _ALONG_X)


def _hexagon(s: float, phase: float = 0.0) -> np.ndarray:
    return _regular_polygon(6, s / np.sqrt(3.0), phase)


def part_solid(name: str, rng: np.random.Generator) -> Solid:
    """Primitives of one part of kind ``name`` in its local frame (origin near the centroid).

    Returns
    -------
    primitives : list of primitive tuples (union)
    hole : primitive tuple or None (subtracted)
    """
    if name == "spheres":
        return [("sphere", np.zeros(3), 10.0)], None
    if name in ("zinc_nuts", "black_nuts"):
        body = _prism(_hexagon(_HEX_S, rng.uniform(0, np.pi / 3)), -_HEX_M / 2, _HEX_M / 2)
        hole = _prism(_regular_polygon(24, _NUT_BORE / 2 / math.cos(np.pi / 24)), -_HEX_M, _HEX_M)
        return [body], hole
    if name == "rods":
        return [_cylinder_x(8.0, -40.0, 40.0, phase=rng.uniform(0, 0.2))], None
    if name == "black_screws":
        # shaft along +x from the head; the assembly is centred at the origin (total 47.5 mm)
        shaft = _cylinder_x(6.0, -16.25, 23.75)
        head = _prism(_hexagon(_HEX_S, rng.uniform(0, np.pi / 3)), -23.75, -16.25, _ALONG_X)
        return [shaft, head], None
    if name == "sprockets":
        half = _SPROCKET_T / 2
        prims = [_prism(_regular_polygon(64, _SPROCKET_R_ROOT / math.cos(np.pi / 64)), -half, half)]
        for k in range(_SPROCKET_TEETH):
            a = 2 * np.pi * k / _SPROCKET_TEETH
            # trapezoidal tooth, 6 mm wide at the root, 2.5 mm at the tip, radially outward
            local = np.array(
                [[_SPROCKET_R_ROOT - 1.0, -3.0], [_SPROCKET_R_TIP, -1.25], [_SPROCKET_R_TIP, 1.25],
                 [_SPROCKET_R_ROOT - 1.0, 3.0]]
            )
            c, s = math.cos(a), math.sin(a)
            poly = local @ np.array([[c, s], [-s, c]])
            prims.append(_prism(poly, -half, half))
        hole = _prism(_regular_polygon(32, _SPROCKET_BORE / math.cos(np.pi / 32)), -_SPROCKET_T, _SPROCKET_T)
        return prims, hole
    raise KeyError(name)


def _rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rot_axis(axis: np.ndarray, a: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R: np.ndarray = np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * (K @ K)
    return R


def random_rest_rotation(name: str, rng: np.random.Generator) -> np.ndarray:
    """A plausible resting orientation (3 x 3 rotation, local -> world) for a dropped part."""
    yaw = rng.uniform(0.0, 2.0 * np.pi)
    tilt_axis = np.array([np.cos(yaw + 1.0), np.sin(yaw + 1.0), 0.0])
    if name == "spheres":
        return _rot_z(yaw)
    if name in ("zinc_nuts", "black_nuts"):
        rest = np.eye(3) if rng.random() < 0.8 else _rot_axis(np.array([1.0, 0, 0]), np.pi / 2)
        tilt = min(abs(rng.normal(0.0, np.radians(12))), np.radians(35))
    elif name in ("rods", "black_screws"):
        rest = _rot_axis(np.array([1.0, 0, 0]), rng.uniform(0, 2 * np.pi))  # roll about own axis
        tilt = min(abs(rng.normal(0.0, np.radians(8))), np.radians(25))
    elif name == "sprockets":
        rest = np.eye(3)
        tilt = min(abs(rng.normal(0.0, np.radians(10))), np.radians(30))
    else:
        raise KeyError(name)
    R: np.ndarray = _rot_axis(tilt_axis, tilt) @ _rot_z(yaw) @ rest
    return R


def height_profile(
    primitives: list[Primitive], hole: Primitive | None, R: np.ndarray, xs: np.ndarray, ys: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Lowest and highest point of the rotated solid on each vertical line (x, y).

    Parameters
    ----------
    primitives, hole : from :func:`part_solid`
    R : (3, 3) float ndarray
        Rotation local -> world; the part origin is at (0, 0, 0).
    xs : (nx,) float ndarray, ys : (ny,) float ndarray
        Grid node coordinates in mm relative to the part origin.

    Returns
    -------
    lo, hi : (ny, nx) float64 ndarray
        z of the bottom and top surface (mm, relative to the origin); NaN where the line misses.
    """
    lo = np.full((len(ys), len(xs)), np.inf)
    hi = np.full((len(ys), len(xs)), -np.inf)
    for prim in primitives:
        win = _window(prim, R, xs, ys)
        if win is None:
            continue
        X, Y = np.meshgrid(xs[win[1]], ys[win[0]])
        plo, phi = _interval(prim, R, X, Y)
        hit = plo <= phi
        lo[win] = np.where(hit, np.minimum(lo[win], plo), lo[win])
        hi[win] = np.where(hit, np.maximum(hi[win], phi), hi[win])
    if hole is not None and (win := _window(hole, R, xs, ys)) is not None:
        X, Y = np.meshgrid(xs[win[1]], ys[win[0]])
        hlo, hhi = _interval(hole, R, X, Y)
        wlo, whi = lo[win], hi[win]
        inh = hlo <= hhi
        covered = inh & (hlo <= wlo) & (hhi >= whi)
        low_cut = inh & ~covered & (hlo <= wlo) & (hhi > wlo)
        top_cut = inh & ~covered & (hhi >= whi) & (hlo < whi)
        wlo2 = np.where(low_cut, hhi, wlo)
        whi2 = np.where(top_cut, hlo, whi)
        lo[win] = np.where(covered, np.inf, wlo2)
        hi[win] = np.where(covered, -np.inf, whi2)
    empty = ~(lo <= hi)
    lo[empty] = np.nan
    hi[empty] = np.nan
    return lo, hi


def _window(prim: Primitive, R: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> tuple[slice, slice] | None:
    """Grid window (rows, cols) covering the primitive's bounding ball, None when off the grid."""
    c = R @ (prim[1] if prim[0] == "sphere" else prim[3])
    r = prim[2] if prim[0] == "sphere" else prim[4]
    j0, j1 = np.searchsorted(xs, [c[0] - r, c[0] + r], side="left")
    i0, i1 = np.searchsorted(ys, [c[1] - r, c[1] + r], side="left")
    j1 = min(j1 + 1, len(xs))
    i1 = min(i1 + 1, len(ys))
    if j0 >= j1 or i0 >= i1:
        return None
    return slice(int(i0), int(i1)), slice(int(j0), int(j1))


def _interval(prim: Primitive, R: np.ndarray, X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if prim[0] == "sphere":
        c = R @ prim[1]
        r2 = prim[2] ** 2 - (X - c[0]) ** 2 - (Y - c[1]) ** 2
        h = np.sqrt(np.maximum(r2, 0.0))
        lo = np.where(r2 >= 0, c[2] - h, np.inf)
        hi = np.where(r2 >= 0, c[2] + h, -np.inf)
        return lo, hi
    normals = prim[1] @ R.T
    offsets = prim[2]
    lo = np.full(X.shape, -np.inf)
    hi = np.full(X.shape, np.inf)
    for n, o in zip(normals, offsets):
        b = o - n[0] * X - n[1] * Y
        if n[2] > 1e-12:
            hi = np.minimum(hi, b / n[2])
        elif n[2] < -1e-12:
            lo = np.maximum(lo, b / n[2])
        else:
            bad = b < 0
            lo = np.where(bad, np.inf, lo)
            hi = np.where(bad, -np.inf, hi)
    return lo, hi
