"""The ray-traced scene: table, bin and pile as one triangle mesh in the camera frame, ready to cast.

World frame as :mod:`replay.synth.scene` (z up, table top at 0, camera above the origin looking
down); camera optical frame: x = world x, y = -world y, z = camera height - world z (mm). Rays are
cast with Open3D's ``RaycastingScene`` (Embree); every triangle carries its material, its surface
label and its part index, looked up by the primitive id a ray returns. Embree says only whether a ray
hits and which triangle: the hit's ``t``, barycentric coordinates and face normal are computed in
float64 from that triangle (Möller–Trumbore), because Embree's float32 answers differ in their last
bits between CPUs (docs/synthetic.md, "Exact hits").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from replay.presets import BIN, BinGeometry
from replay.synth.raytrace import kernels
from replay.synth.raytrace.materials import BIN_PLASTIC, PART_MATERIALS, TABLE, Material, material_table
from replay.synth.raytrace.meshes import Mesh, bin_mesh, check_mesh, concatenate, part_mesh, table_mesh
from replay.synth.raytrace.pile import Pile
from replay.synth.scene import LABEL_TABLE, BinPose
from replay.synth.sensor import CAMERA_HEIGHT_MM
from zcut.ray_hits import hit_tuv_reference, triangle_edges

if TYPE_CHECKING:
    import open3d as o3d

    from replay.synth.surfaces import TrueSurfaces

#: half size of the table top (mm): wider than what the camera and the projector see
TABLE_HALF_MM = (900.0, 700.0)
_D = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True, slots=True)
class Hits:
    """Where a batch of rays hit the scene.

    Attributes
    ----------
    t : (n,) float64 ndarray
        Ray parameter of the hit (distance for unit directions; inf for a miss).
    point : (n, 3) float64 ndarray
        Hit point, camera frame, mm (NaN for a miss).
    normal : (n, 3) float64 ndarray
        Unit shading normal facing the ray's origin (zero for a miss).
    geo_normal : (n, 3) float64 ndarray
        Unit face normal facing the ray's origin (zero for a miss).
    material : (n,) int64 ndarray
        Material id (-1 for a miss).
    label : (n,) uint8 ndarray
        ``LABEL_*`` (``LABEL_NONE`` for a miss).
    part : (n,) int32 ndarray
        1-based index of the part hit (0 for the bin, the table or a miss).
    """

    t: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    geo_normal: np.ndarray
    material: np.ndarray
    label: np.ndarray
    part: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        hit: np.ndarray = np.isfinite(self.t)
        return hit

    def take(self, idx: np.ndarray) -> Hits:
        """The hits of rays ``idx``."""
        return Hits(self.t[idx], self.point[idx], self.normal[idx], self.geo_normal[idx], self.material[idx],
                    self.label[idx], self.part[idx])

    @staticmethod
    def empty(n: int) -> Hits:
        """Room for the hits of ``n`` rays (to be filled by :meth:`TracedScene.cast`)."""
        return Hits(np.empty(n), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty(n, np.int64),
                    np.empty(n, np.uint8), np.empty(n, np.int32))

    @staticmethod
    def concat(parts: list[Hits]) -> Hits:
        """One batch of the hits of ``parts``, in order."""
        return Hits(*(np.concatenate([getattr(h, f) for h in parts])
                      for f in ("t", "point", "normal", "geo_normal", "material", "label", "part")))


class TracedScene:
    """The scene's triangles in the camera frame and the ray caster built on them (built once per frame).

    Parameters
    ----------
    meshes : list of (Mesh, Material, part index)
        World-frame meshes, each with its material and 1-based part index (0: not a part).
    camera_height_mm : float

    Raises
    ------
    ParameterError
        A mesh without faces or with non-finite vertices.
    """

    def __init__(self, meshes: list[tuple[Mesh, Material, int]], *, camera_height_mm: float = CAMERA_HEIGHT_MM):
        import open3d as o3d

        materials: list[Material] = []
        mat_ids: list[np.ndarray] = []
        part_ids: list[np.ndarray] = []
        for i, (m, mat, pid) in enumerate(meshes):
            check_mesh(m, what=f"scene object {i} ({mat.name})")
            if mat not in materials:
                materials.append(mat)
            mat_ids.append(np.full(len(m.triangles), materials.index(mat), np.int64))
            part_ids.append(np.full(len(m.triangles), pid, np.int32))
        world = concatenate([m for m, _, _ in meshes])
        self.vertices = world.vertices @ _D.T + np.array([0.0, 0.0, camera_height_mm])
        self.triangles = world.triangles
        self.normals = world.normals @ _D.T  # corner normals, camera frame
        # per triangle, float64: its first corner and two edges (Möller–Trumbore's) and its unit face normal
        # (e1 x e2, Embree's orientation): a hit's t, uv and geometric normal are computed from these, not
        # read from Embree's float32 answers, which differ between CPUs (docs/synthetic.md)
        self.v0, self.e1, self.e2 = triangle_edges(self.vertices, self.triangles)
        self.face_normals = _unit_cross(self.e1, self.e2)
        self.label = world.label
        self.material_id = np.concatenate(mat_ids)
        self.part_id = np.concatenate(part_ids)
        self.materials = materials
        self.mat = material_table(materials)
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(
            o3d.core.Tensor(self.vertices.astype(np.float32)),  # type: ignore[call-overload]  # Open3D's stub makes dtype and device required
            o3d.core.Tensor(self.triangles.astype(np.uint32)),  # type: ignore[call-overload]  # Open3D's stub makes dtype and device required
        )

    def _raw(self, rays: np.ndarray) -> dict[str, o3d.core.Tensor]:
        import open3d as o3d

        # Tensor.from_numpy shares the rays' memory (Tensor(rays) copied them: 24 bytes a ray, no value changes)
        return self._scene.cast_rays(o3d.core.Tensor.from_numpy(np.ascontiguousarray(rays, np.float32)))

    def _cast_raw(self, origins: np.ndarray, directions: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, dict[str, o3d.core.Tensor]]:
        """``(origins, directions, Embree's answers)``: the rays as contiguous float64 (origins (n, 3) or one
        broadcast row), cast as float32 rays (:func:`kernels.ray_array`)."""
        origins = np.ascontiguousarray(np.asarray(origins, np.float64).reshape(-1, 3))
        directions = np.ascontiguousarray(directions, np.float64)
        rays = np.empty((directions.shape[0], 6), np.float32)
        kernels.ray_array(origins, directions, rays)
        return origins, directions, self._raw(rays)

    def cast(self, origins: np.ndarray, directions: np.ndarray, *, out: Hits | None = None, at: int = 0) -> Hits:
        """First hits of rays ``origins + t * directions`` (camera frame, mm; directions unit length).

        Parameters
        ----------
        origins : (n, 3) or (3,) float ndarray
        directions : (n, 3) float ndarray
        out : Hits or None
            Write the hits into ``out``'s rows ``at .. at + n`` (and return ``out``) instead of new arrays.
        at : int
        """
        origins, directions, res = self._cast_raw(origins, directions)
        n = directions.shape[0]
        if out is None:
            out = Hits.empty(n)
            at = 0
        sl = slice(at, at + n)
        kernels.finish_hits(
            res["t_hit"].numpy(), res["primitive_ids"].numpy(), res["primitive_uvs"].numpy(),
            res["primitive_normals"].numpy(), origins, directions, self.v0, self.e1, self.e2, self.face_normals,
            self.normals, self.material_id, self.label, self.part_id, out.t[sl], out.point[sl], out.normal[sl],
            out.geo_normal[sl], out.material[sl], out.label[sl], out.part[sl],
        )
        return out

    def surfaces(self) -> TrueSurfaces:
        """The scene's triangles as :class:`replay.synth.surfaces.TrueSurfaces` (the same ray caster:
        distances to exactly the triangles the rays hit)."""
        from replay.synth.surfaces import TrueSurfaces

        return TrueSurfaces(self.vertices, self.triangles, scene=self._scene)

    def cast_t(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """:meth:`cast`'s ``t`` alone (float64; inf for a miss): the ray parameter of the first hit.

        Parameters
        ----------
        origins : (n, 3) or (3,) float ndarray
        directions : (n, 3) float ndarray
        """
        origins, directions, res = self._cast_raw(origins, directions)
        t = np.empty(directions.shape[0])
        kernels.hit_t(res["t_hit"].numpy(), res["primitive_ids"].numpy(), origins, directions, self.v0, self.e1,
                      self.e2, t)
        return t

    def cast_reference(self, origins: np.ndarray, directions: np.ndarray) -> Hits:
        """:meth:`cast` in whole-array numpy (the reference the numba kernel must equal bit for bit).

        Parameters
        ----------
        origins : (n, 3) or (3,) float ndarray
        directions : (n, 3) float ndarray
        """
        import open3d as o3d

        n = directions.shape[0]
        rays = np.empty((n, 6), np.float32)
        rays[:, :3] = origins
        rays[:, 3:] = directions
        res = self._scene.cast_rays(o3d.core.Tensor(rays))  # type: ignore[call-overload]  # Open3D's stub makes dtype and device required
        t = res["t_hit"].numpy().astype(np.float64)
        prim = res["primitive_ids"].numpy().astype(np.int64)
        hit = np.isfinite(t)
        prim = np.where(hit, prim, 0)
        uv = res["primitive_uvs"].numpy().astype(np.float64)
        geo = res["primitive_normals"].numpy().astype(np.float64)
        # Embree decides hit or miss and the triangle; t, uv and the face normal are float64 Möller–Trumbore's
        det, tm, bu, bv = hit_tuv_reference(np.asarray(origins, np.float64), directions, self.v0[prim],
                                            self.e1[prim], self.e2[prim])
        with np.errstate(invalid="ignore"):
            mt = hit & (det != 0.0) & np.isfinite(tm) & np.isfinite(bu) & np.isfinite(bv)
        t[mt] = tm[mt]
        uv[mt, 0] = bu[mt]
        uv[mt, 1] = bv[mt]
        geo[mt] = self.face_normals[prim[mt]]
        corner = self.normals[prim]  # (n, 3, 3)
        w = np.stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], axis=1)
        shade = np.einsum("nk,nkj->nj", w, corner)
        shade /= np.maximum(np.linalg.norm(shade, axis=1, keepdims=True), 1e-12)
        facing = np.einsum("nj,nj->n", geo, directions) > 0
        geo[facing] *= -1.0
        shade[facing] *= -1.0
        # a shading normal turned away from the viewer would light the back: fall back to the face's
        back = np.einsum("nj,nj->n", shade, directions) >= 0
        shade[back] = geo[back]
        point = np.asarray(origins, np.float64) + t[:, None] * directions
        point[~hit] = np.nan
        geo[~hit] = 0.0
        shade[~hit] = 0.0
        return Hits(
            t, point, shade, geo,
            np.where(hit, self.material_id[prim], -1),
            np.where(hit, self.label[prim], 0).astype(np.uint8),
            np.where(hit, self.part_id[prim], 0).astype(np.int32),
        )


def _unit_cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rows ``a x b / max(|a x b|, 1e-12)``, the norm ``sqrt((x² + y²) + z²)``."""
    c = np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                  a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)
    n = np.sqrt((c[:, 0] * c[:, 0] + c[:, 1] * c[:, 1]) + c[:, 2] * c[:, 2])
    out: np.ndarray = c / np.maximum(n, 1e-12)[:, None]
    return out


def build_scene(pose: BinPose, pile: Pile | None, *, geometry: BinGeometry = BIN,
                camera_height_mm: float = CAMERA_HEIGHT_MM) -> TracedScene:
    """Table, bin at ``pose`` and the parts of ``pile`` (None: the empty bin) as one :class:`TracedScene`."""
    objects: list[tuple[Mesh, Material, int]] = [
        (table_mesh(*TABLE_HALF_MM), TABLE, 0),
        (bin_mesh(pose, geometry), BIN_PLASTIC, 0),
    ]
    if pile is not None and len(pile):
        local = part_mesh(pile.kind)
        mat = PART_MATERIALS[pile.kind]
        for i in range(len(pile)):
            objects.append((local.transformed(pile.R[i], pile.t_mm[i]), mat, i + 1))
    return TracedScene(objects, camera_height_mm=camera_height_mm)


__all__ = ["LABEL_TABLE", "TABLE_HALF_MM", "Hits", "TracedScene", "build_scene"]
