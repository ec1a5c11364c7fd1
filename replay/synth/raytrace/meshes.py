"""Triangle meshes of the six part kinds, the bin and the table, with a material per surface (mm).

Every mesh is closed and carries, besides its vertices and triangles, a shading normal at each
corner of each triangle: the surface's own normal on curved faces (spheres, cylinders, bores), the
face normal on flat ones, so that a highlight moves smoothly over a ball or a rod instead of
flickering with the facets (the depth is the facets': they lie within 0.03 mm of the true solid).

Part dimensions are those of :mod:`replay.presets` (ISO M12 nuts and screws, M16 rods, 20 mm balls,
a 20-tooth plate sprocket); the bin is :data:`replay.presets.BIN` (rim, drafted inner walls, floor,
vertical outer walls). Local part frames are those of :mod:`replay.synth.parts`: origin near the
centroid, rods and screws along x, nuts and sprockets flat in the xy plane.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from replay.presets import (
    BIN,
    HEX_M_MM,
    HEX_S_MM,
    NUT_BORE_MM,
    PART_KINDS,
    SPROCKET_BORE_MM,
    SPROCKET_R_ROOT_MM,
    SPROCKET_R_TIP_MM,
    SPROCKET_T_MM,
    SPROCKET_TEETH,
    BinGeometry,
)
from replay.synth.scene import LABEL_FLOOR, LABEL_RIM, LABEL_TABLE, LABEL_WALL, BinPose
from zcut.errors import ParameterError


@dataclass(frozen=True, slots=True)
class Mesh:
    """A closed triangle mesh.

    Attributes
    ----------
    vertices : (n, 3) float64 ndarray
        Millimetres.
    triangles : (m, 3) int64 ndarray
        Vertex indices, counter-clockwise seen from outside.
    normals : (m, 3, 3) float64 ndarray
        Unit shading normal at each corner of each triangle, pointing out of the solid.
    label : (m,) uint8 ndarray
        Surface label (``replay.synth.scene.LABEL_*``) of each triangle.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray
    label: np.ndarray

    def transformed(self, R: np.ndarray, t: np.ndarray) -> Mesh:
        """The mesh moved by ``x -> R @ x + t``."""
        return Mesh(self.vertices @ R.T + t, self.triangles, self.normals @ R.T, self.label)


def check_mesh(mesh: Mesh, *, what: str) -> Mesh:
    """``mesh`` if it has faces and finite vertices, else :class:`ParameterError` naming ``what``."""
    if mesh.triangles.ndim != 2 or mesh.triangles.shape[0] == 0:
        raise ParameterError(f"the mesh of {what} has no faces")
    if not np.isfinite(mesh.vertices).all():
        raise ParameterError(f"the mesh of {what} has non-finite vertices")
    if mesh.triangles.min() < 0 or mesh.triangles.max() >= len(mesh.vertices):
        raise ParameterError(f"the mesh of {what} has triangles that index missing vertices")
    return mesh


def concatenate(meshes: list[Mesh]) -> Mesh:
    """One mesh holding all of ``meshes`` (triangles keep their order)."""
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
    return Mesh(
        np.concatenate([m.vertices for m in meshes]),
        np.concatenate([m.triangles + o for m, o in zip(meshes, offsets)]),
        np.concatenate([m.normals for m in meshes]),
        np.concatenate([m.label for m in meshes]),
    )


def _face_normals(v: np.ndarray, tri: np.ndarray) -> np.ndarray:
    n = np.cross(v[tri[:, 1]] - v[tri[:, 0]], v[tri[:, 2]] - v[tri[:, 0]])
    unit: np.ndarray = n / np.linalg.norm(n, axis=1, keepdims=True)
    return unit


def _flat(v: np.ndarray, tri: np.ndarray, label: int = 0) -> Mesh:
    n = _face_normals(v, tri)
    return Mesh(v, tri, np.repeat(n[:, None, :], 3, axis=1), np.full(len(tri), label, np.uint8))


def _ring_profile(angles: np.ndarray, radius: np.ndarray, z0: float, z1: float, *, smooth: bool,
                  inward: bool) -> Mesh:
    """The side wall of a star-shaped outline ``radius(angle)`` between z0 and z1 (closed loop).

    ``inward``: the wall of a bore (normals toward the axis). ``smooth``: corner normals radial
    (a cylinder), else the face normals.
    """
    n = len(angles)
    xy = np.c_[radius * np.cos(angles), radius * np.sin(angles)]
    v = np.concatenate([np.c_[xy, np.full(n, z0)], np.c_[xy, np.full(n, z1)]])
    i = np.arange(n)
    j = (i + 1) % n
    if not inward:
        tri = np.concatenate([np.c_[i, j, j + n], np.c_[i, j + n, i + n]])
    else:
        tri = np.concatenate([np.c_[i, j + n, j], np.c_[i, i + n, j + n]])
    if not smooth:
        return _flat(v, tri)
    radial = np.c_[np.cos(angles), np.sin(angles), np.zeros(n)]
    radial = np.concatenate([radial, radial])
    if inward:
        radial = -radial
    return Mesh(v, tri, radial[tri], np.zeros(len(tri), np.uint8))


def _cap(angles: np.ndarray, outer: np.ndarray, inner: np.ndarray | None, z: float, *, up: bool) -> Mesh:
    """A flat cap at height z between an outline and an optional hole (both sampled at ``angles``)."""
    n = len(angles)
    c, s = np.cos(angles), np.sin(angles)
    i = np.arange(n)
    j = (i + 1) % n
    if inner is None:
        v = np.concatenate([np.c_[outer * c, outer * s, np.full(n, z)], [[0.0, 0.0, z]]])
        tri = np.c_[np.full(n, n), i, j]
    else:
        v = np.concatenate([np.c_[outer * c, outer * s, np.full(n, z)], np.c_[inner * c, inner * s, np.full(n, z)]])
        tri = np.concatenate([np.c_[i, j, j + n], np.c_[i, j + n, i + n]])
    if not up:
        tri = tri[:, ::-1]
    return _flat(v, tri)


def extrusion(angles: np.ndarray, outer: np.ndarray, inner: np.ndarray | None, z0: float, z1: float, *,
              smooth_outer: bool) -> Mesh:
    """A prism with a star-shaped outline (and an optional round hole) from z0 to z1."""
    parts = [_ring_profile(angles, outer, z0, z1, smooth=smooth_outer, inward=False),
             _cap(angles, outer, inner, z1, up=True), _cap(angles, outer, inner, z0, up=False)]
    if inner is not None:
        parts.append(_ring_profile(angles, inner, z0, z1, smooth=True, inward=True))
    return concatenate(parts)


def _hexagon_radius(angles: np.ndarray, s: float) -> np.ndarray:
    """Distance from the centre to a hexagon (across flats ``s``, flats facing 0°, 60°, ...)."""
    a = (angles + np.pi / 6) % (np.pi / 3) - np.pi / 6
    return (s / 2) / np.cos(a)


def _sprocket_radius(angles: np.ndarray) -> np.ndarray:
    """Outline of the plate sprocket: the root circle with trapezoidal teeth (6 mm at the root, 2.5 at
    the tip, as :func:`replay.synth.parts.part_solid`)."""
    r = np.full(angles.shape, SPROCKET_R_ROOT_MM)
    d = np.c_[np.cos(angles), np.sin(angles)]
    local = np.array([[SPROCKET_R_ROOT_MM - 1.0, -3.0], [SPROCKET_R_TIP_MM, -1.25], [SPROCKET_R_TIP_MM, 1.25],
                      [SPROCKET_R_ROOT_MM - 1.0, 3.0]])
    for k in range(SPROCKET_TEETH):
        a = 2 * np.pi * k / SPROCKET_TEETH
        rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        poly = local @ rot.T
        edge = np.roll(poly, -1, axis=0) - poly
        normal = np.c_[edge[:, 1], -edge[:, 0]]  # outward for a counter-clockwise polygon
        offset = np.einsum("ij,ij->i", normal, poly)
        dn = d @ normal.T  # (n, 4)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = offset[None, :] / dn
        t_exit = np.where(dn > 0, t, np.inf).min(axis=1)
        t_enter = np.where(dn < 0, t, -np.inf).max(axis=1)
        through = (t_enter <= t_exit) & np.isfinite(t_exit)
        r = np.where(through, np.maximum(r, t_exit), r)
    return r


_ALONG_X = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # local z -> x


def _icosphere(radius: float, subdivisions: int) -> Mesh:
    t = (1.0 + 5**0.5) / 2
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
                  [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], float)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
                  [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
                  [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for _ in range(subdivisions):
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, inv = np.unique(edges, axis=0, return_inverse=True)
        mid = v[uniq[:, 0]] + v[uniq[:, 1]]
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        m = len(f)
        a, b, c = (inv[:m] + len(v)), (inv[m:2 * m] + len(v)), (inv[2 * m:] + len(v))
        v = np.concatenate([v, mid])
        f = np.concatenate([np.c_[f[:, 0], a, c], np.c_[f[:, 1], b, a], np.c_[f[:, 2], c, b], np.c_[a, b, c]])
    return Mesh(v * radius, f, v[f], np.zeros(len(f), np.uint8))


def part_mesh(kind: str) -> Mesh:
    """The closed mesh of one part of ``kind`` in its local frame (mm), label ``LABEL_PART``."""
    from replay.synth.scene import LABEL_PART

    if kind not in PART_KINDS:
        raise ParameterError(f"kind must be one of {', '.join(PART_KINDS)}, got {kind!r}")
    circle = np.linspace(0.0, 2 * np.pi, 48, endpoint=False)
    if kind == "spheres":
        m = _icosphere(10.0, 3)
    elif kind in ("zinc_nuts", "black_nuts"):
        m = extrusion(circle, _hexagon_radius(circle, HEX_S_MM), np.full(48, NUT_BORE_MM / 2), -HEX_M_MM / 2,
                      HEX_M_MM / 2, smooth_outer=False)
    elif kind == "rods":
        m = extrusion(circle, np.full(48, 8.0), None, -40.0, 40.0, smooth_outer=True).transformed(_ALONG_X, np.zeros(3))
    elif kind == "black_screws":
        # the shaft reaches 0.75 mm into the head, so that no face of one lies on a face of the other
        shaft = extrusion(circle, np.full(48, 6.0), None, -17.0, 23.75, smooth_outer=True)
        head = extrusion(circle, _hexagon_radius(circle, HEX_S_MM), None, -23.75, -16.25, smooth_outer=False)
        m = concatenate([shaft, head]).transformed(_ALONG_X, np.zeros(3))
    else:  # sprockets
        teeth = np.linspace(0.0, 2 * np.pi, SPROCKET_TEETH * 24, endpoint=False)
        m = extrusion(teeth, _sprocket_radius(teeth), np.full(len(teeth), SPROCKET_BORE_MM), -SPROCKET_T_MM / 2,
                      SPROCKET_T_MM / 2, smooth_outer=False)
    return Mesh(m.vertices, m.triangles, m.normals, np.full(len(m.triangles), LABEL_PART, np.uint8))


def _quad(a: int, b: int, c: int, d: int) -> np.ndarray:
    return np.array([[a, b, c], [a, c, d]])


def bin_mesh(pose: BinPose, geometry: BinGeometry = BIN) -> Mesh:
    """The bin at ``pose`` in the world frame (mm): rim top, drafted inner walls, floor, outer walls.

    Labels: ``LABEL_RIM`` (the flat rim), ``LABEL_WALL`` (inner and outer walls), ``LABEL_FLOOR``.
    """
    ox, oy = geometry.outer_length_mm / 2, geometry.outer_width_mm / 2
    ix, iy = geometry.inner_top_half
    fx, fy = geometry.floor_half
    h, f = geometry.height_mm, geometry.floor_mm
    if min(fx, fy) <= 0:
        raise ParameterError(f"the bin's floor is empty (floor half sizes {fx:g} x {fy:g} mm)")
    v = np.array([
        [-ox, -oy, h], [ox, -oy, h], [ox, oy, h], [-ox, oy, h],  # 0-3 outer top
        [-ix, -iy, h], [ix, -iy, h], [ix, iy, h], [-ix, iy, h],  # 4-7 inner top
        [-fx, -fy, f], [fx, -fy, f], [fx, fy, f], [-fx, fy, f],  # 8-11 floor corners
        [-ox, -oy, 0], [ox, -oy, 0], [ox, oy, 0], [-ox, oy, 0],  # 12-15 outer bottom
    ])
    rim = np.concatenate([_quad(0, 1, 5, 4), _quad(1, 2, 6, 5), _quad(2, 3, 7, 6), _quad(3, 0, 4, 7)])
    inner = np.concatenate([_quad(4, 5, 9, 8), _quad(5, 6, 10, 9), _quad(6, 7, 11, 10), _quad(7, 4, 8, 11)])
    floor = _quad(8, 9, 10, 11)
    outer = np.concatenate([_quad(12, 13, 1, 0), _quad(13, 14, 2, 1), _quad(14, 15, 3, 2), _quad(15, 12, 0, 3)])
    tri = np.concatenate([rim, inner, floor, outer])
    label = np.concatenate([np.full(len(rim), LABEL_RIM), np.full(len(inner), LABEL_WALL),
                            np.full(len(floor), LABEL_FLOOR), np.full(len(outer), LABEL_WALL)]).astype(np.uint8)
    m = _flat(v, tri)
    c, s = np.cos(pose.yaw_rad), np.sin(pose.yaw_rad)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return Mesh(m.vertices, m.triangles, m.normals, label).transformed(Rz, np.array([pose.x_mm, pose.y_mm, 0.0]))


def table_mesh(half_x_mm: float, half_y_mm: float) -> Mesh:
    """The table top (z = 0) as one rectangle, facing up, label ``LABEL_TABLE``."""
    v = np.array([[-half_x_mm, -half_y_mm, 0], [half_x_mm, -half_y_mm, 0], [half_x_mm, half_y_mm, 0],
                  [-half_x_mm, half_y_mm, 0]], float)
    m = _flat(v, _quad(0, 1, 2, 3))
    return Mesh(m.vertices, m.triangles, m.normals, np.full(2, LABEL_TABLE, np.uint8))
