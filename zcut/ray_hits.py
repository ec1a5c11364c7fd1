"""Ray hits to the bit on any CPU: a hit's ``t`` and barycentric ``u, v`` in float64 on the triangle a ray caster found.

Open3D's ``RaycastingScene`` (Embree) answers in float32 from SIMD kernels chosen at run time by the CPU: two CPUs
give the same rays the same triangle (``primitive_ids``) and the same hit or miss, but ``t_hit`` and
``primitive_uvs`` differing in their last 1-3 ulp (docs/synthetic.md, "Exact hits"). Whoever needs bytes that do not
move with the CPU takes from Embree only whether a ray hits and which triangle, and computes the hit here:
Möller–Trumbore in float64 on that triangle's float64 first corner ``v0`` and edges ``e1 = v1 - v0``,
``e2 = v2 - v0``. A ray in the triangle's plane (determinant 0) or a non-finite result keeps Embree's float32 ``t``.

One kernel, used by the ray-traced sensor (``replay.synth.raytrace.kernels.finish_hits``,
``replay.synth.raytrace.scene.TracedScene.cast_t``) and the fits' ray casts (``zcut.fits.model.PartModel.ray_depths``):

- :func:`hit_tuv`: one ray on one triangle, ``(det, t, u, v)``; the operations in the order of
  :func:`hit_tuv_reference`, its whole-array numpy oracle (the same bits: no ``fastmath``, each dot product
  ``(x + y) + z``);
- :func:`hit_t`: the ``t`` of a batch of rays, the triangles given as ``(v0, e1, e2)`` tables
  (:func:`triangle_edges`);
- :func:`mesh_hit_t`: the same ``t`` with the triangles given as a mesh's vertices and triangles (the edges of each
  hit triangle computed where needed: the same subtractions, the same bits as the tables).

Pure arithmetic on arrays: the ray casting itself is the caller's.
"""

from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ["hit_t", "hit_tuv", "hit_tuv_reference", "mesh_hit_t", "triangle_edges"]


def triangle_edges(vertices: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per triangle its first corner and two edges, float64, C-ordered.

    Parameters
    ----------
    vertices : (n, 3) float ndarray
    triangles : (m, 3) int ndarray

    Returns
    -------
    v0, e1, e2 : (m, 3) float64 ndarray
        ``v0 = vertices[triangles[:, 0]]``, ``e1 = v1 - v0``, ``e2 = v2 - v0``.
    """
    corners = np.asarray(vertices, np.float64)[np.asarray(triangles)]
    v0 = np.ascontiguousarray(corners[:, 0])
    e1 = corners[:, 1] - corners[:, 0]
    e2 = corners[:, 2] - corners[:, 0]
    return v0, e1, e2


@nb.njit(cache=True, error_model="numpy")
def _tuv(ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, vx: float, vy: float, vz: float,
         ax: float, ay: float, az: float, bx: float, by: float, bz: float) -> tuple[float, float, float, float]:
    """Möller–Trumbore of the ray ``o + t d`` on the triangle ``v0 = (vx, vy, vz)``, ``e1 = a``, ``e2 = b``:
    ``(det, t, u, v)`` with ``P = d x e2``, ``det = e1 . P``, ``S = o - v0``, ``Q = S x e1``, ``u = (S . P) / det``,
    ``v = (d . Q) / det``, ``t = (e2 . Q) / det``, each dot product ``(x + y) + z``."""
    px = dy * bz - dz * by
    py = dz * bx - dx * bz
    pz = dx * by - dy * bx
    det = (ax * px + ay * py) + az * pz
    sx = ox - vx
    sy = oy - vy
    sz = oz - vz
    qx = sy * az - sz * ay
    qy = sz * ax - sx * az
    qz = sx * ay - sy * ax
    u = ((sx * px + sy * py) + sz * pz) / det
    v = ((dx * qx + dy * qy) + dz * qz) / det
    t = ((bx * qx + by * qy) + bz * qz) / det
    return det, t, u, v


@nb.njit(cache=True, error_model="numpy")
def hit_tuv(i: int, p: np.int64, o: int, origins: np.ndarray, directions: np.ndarray, v0: np.ndarray, e1: np.ndarray,
            e2: np.ndarray) -> tuple[float, float, float, float]:
    """Möller–Trumbore of ray ``i`` (origin row ``o``) on triangle ``p`` in float64: ``(det, t, u, v)``.

    Parameters
    ----------
    i, p, o : int
        The ray's row of ``directions``, the triangle's row of the tables, the ray's row of ``origins``.
    origins, directions : (n, 3) float64 ndarray
    v0, e1, e2 : (m, 3) float64 ndarray
        :func:`triangle_edges`.
    """
    return _tuv(origins[o, 0], origins[o, 1], origins[o, 2], directions[i, 0], directions[i, 1], directions[i, 2],
                v0[p, 0], v0[p, 1], v0[p, 2], e1[p, 0], e1[p, 1], e1[p, 2], e2[p, 0], e2[p, 1], e2[p, 2])


@nb.njit(cache=True, error_model="numpy")
def _exact(ti: float, det: float, tm: float, bu: float, bv: float) -> float:
    """Möller–Trumbore's ``t`` unless the ray lies in the plane or a result is not finite: then Embree's ``ti``."""
    if det != 0.0 and np.isfinite(tm) and np.isfinite(bu) and np.isfinite(bv):
        return np.float64(tm)
    return ti


@nb.njit(cache=True, error_model="numpy")
def hit_t(t32: np.ndarray, prim: np.ndarray, origins: np.ndarray, directions: np.ndarray, v0: np.ndarray,
          e1: np.ndarray, e2: np.ndarray, t: np.ndarray) -> None:
    """The float64 ``t`` of each ray's hit into ``t`` (inf for a miss).

    Parameters
    ----------
    t32 : (n,) float32 ndarray
        Embree's ``t_hit``: only whether it is finite (a hit) is read, and its value where Möller–Trumbore has none
        (the ray in the triangle's plane, a non-finite result).
    prim : (n,) integer ndarray
        Embree's ``primitive_ids``: the rows of ``v0, e1, e2`` (read only for the hits).
    origins : (n, 3) or (1, 3) float64 ndarray
        The rays' origins (one row: every ray's).
    directions : (n, 3) float64 ndarray
    v0, e1, e2 : (m, 3) float64 ndarray
        :func:`triangle_edges`.
    t : (n,) float64 ndarray
        Output.
    """
    one = origins.shape[0] == 1
    for i in range(t32.shape[0]):
        ti: float = np.float64(t32[i])
        if np.isfinite(ti):
            det, tm, bu, bv = hit_tuv(i, np.int64(prim[i]), 0 if one else i, origins, directions, v0, e1, e2)
            ti = _exact(ti, det, tm, bu, bv)
        t[i] = ti


@nb.njit(cache=True, error_model="numpy")
def mesh_hit_t(t32: np.ndarray, prim: np.ndarray, origins: np.ndarray, directions: np.ndarray, vertices: np.ndarray,
               triangles: np.ndarray, t: np.ndarray) -> None:
    """:func:`hit_t` with the triangles given as a mesh: ``prim`` indexes ``triangles`` (m, 3) into ``vertices``
    (k, 3) float64; each hit triangle's ``v0``, ``e1``, ``e2`` are :func:`triangle_edges`' (the same subtractions)."""
    one = origins.shape[0] == 1
    for i in range(t32.shape[0]):
        ti: float = np.float64(t32[i])
        if np.isfinite(ti):
            p = np.int64(prim[i])
            o = 0 if one else i
            a, b, c = triangles[p, 0], triangles[p, 1], triangles[p, 2]
            vx, vy, vz = vertices[a, 0], vertices[a, 1], vertices[a, 2]
            det, tm, bu, bv = _tuv(origins[o, 0], origins[o, 1], origins[o, 2],
                                   directions[i, 0], directions[i, 1], directions[i, 2], vx, vy, vz,
                                   vertices[b, 0] - vx, vertices[b, 1] - vy, vertices[b, 2] - vz,
                                   vertices[c, 0] - vx, vertices[c, 1] - vy, vertices[c, 2] - vz)
            ti = _exact(ti, det, tm, bu, bv)
        t[i] = ti


def hit_tuv_reference(o: np.ndarray, d: np.ndarray, v0: np.ndarray, e1: np.ndarray,
                      e2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`hit_tuv` in whole-array numpy, the same operations in the same order: ``(det, t, u, v)``.

    Parameters
    ----------
    o : (n, 3) or (3,) float64 ndarray
        The rays' origins.
    d : (n, 3) float64 ndarray
        The rays' directions.
    v0, e1, e2 : (n, 3) float64 ndarray
        Each ray's triangle (:func:`triangle_edges` taken at the rays' triangles).
    """
    px = d[:, 1] * e2[:, 2] - d[:, 2] * e2[:, 1]
    py = d[:, 2] * e2[:, 0] - d[:, 0] * e2[:, 2]
    pz = d[:, 0] * e2[:, 1] - d[:, 1] * e2[:, 0]
    det = (e1[:, 0] * px + e1[:, 1] * py) + e1[:, 2] * pz
    o = np.broadcast_to(o, d.shape)
    sx = o[:, 0] - v0[:, 0]
    sy = o[:, 1] - v0[:, 1]
    sz = o[:, 2] - v0[:, 2]
    qx = sy * e1[:, 2] - sz * e1[:, 1]
    qy = sz * e1[:, 0] - sx * e1[:, 2]
    qz = sx * e1[:, 1] - sy * e1[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = ((sx * px + sy * py) + sz * pz) / det
        v = ((d[:, 0] * qx + d[:, 1] * qy) + d[:, 2] * qz) / det
        t = ((e2[:, 0] * qx + e2[:, 1] * qy) + e2[:, 2] * qz) / det
    return det, t, u, v
