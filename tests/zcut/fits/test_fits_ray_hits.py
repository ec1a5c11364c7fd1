"""The fits' ray casts do not depend on the last bits of Embree's float answers (docs/fits.md, "The fits' ray casts
exact").

``zcut.fits.model.PartModel.ray_depths`` (the support's predicted depths) and the test scenes' renderer
(``fit_scenes.render``) take from Open3D's ``RaycastingScene`` (Embree) only whether a ray hits and which triangle, and
compute the depth in float64 with the ray-traced sensor's kernel (:mod:`zcut.ray_hits`). Embree answers in float32
from SIMD kernels chosen by the CPU, and two CPUs' ``t_hit`` differ in their last 1-2 ulp; these tests nudge it by
that much, as another CPU would, and ask for the same bytes: of the depths, of the rendered scenes and of the fits.
Also: the numba kernels equal their whole-array numpy reference bit for bit, on random rays and the nasty ones (rays in
a face's plane, misses, empty and one-ray batches, one origin for every ray).
"""

from __future__ import annotations

import hashlib
from typing import Any

import numpy as np
import pytest
from fit_scenes import K_TEST, hex_nut_mesh, icosphere, pose, render, rotation
from ulp_nudge import nudge as _nudge

from zcut.fits import FitParams, fit_parts, prepare_model
from zcut.ray_hits import hit_t, hit_tuv_reference, mesh_hit_t, triangle_edges


class _NudgedScene:
    """An Open3D ``RaycastingScene`` whose ``cast_rays`` answers with ``t_hit``, ``primitive_uvs`` and
    ``primitive_normals`` nudged by ±1-2 ulp (the ids kept); counts its casts."""

    def __init__(self, scene: Any, *, seed: int = 0) -> None:
        self._scene = scene
        self._rng = np.random.default_rng(seed)
        self.casts = 0

    def add_triangles(self, *args: Any) -> int:
        return int(self._scene.add_triangles(*args))

    def compute_distance(self, points: Any) -> Any:
        """Not nudged: the closest-point queries agreed between the CPUs (docs/synthetic.md, "Exact hits")."""
        return self._scene.compute_distance(points)

    def cast_rays(self, rays: Any) -> dict[str, Any]:
        import open3d as o3d

        res = self._scene.cast_rays(rays)
        out = {k: res[k] for k in res}
        for k in ("t_hit", "primitive_uvs", "primitive_normals"):
            a = res[k].numpy()
            b = _nudge(a, self._rng)
            assert not np.isfinite(a).any() or (b != a).any()
            out[k] = o3d.core.Tensor.from_numpy(np.ascontiguousarray(b))
        self.casts += 1
        return out


def _nudge_renders(monkeypatch: pytest.MonkeyPatch, seed: int) -> list[_NudgedScene]:
    """From now on every ``RaycastingScene`` made (by ``fit_scenes.render``) is a :class:`_NudgedScene`."""
    import open3d as o3d

    made: list[_NudgedScene] = []
    real = o3d.t.geometry.RaycastingScene

    def factory() -> _NudgedScene:
        made.append(_NudgedScene(real(), seed=seed + len(made)))
        return made[-1]

    monkeypatch.setattr(o3d.t.geometry, "RaycastingScene", factory)
    return made


def _nudged_model(model: Any, seed: int) -> Any:
    """``model`` whose ray casts answer nudged (its other fields shared)."""
    import dataclasses

    return dataclasses.replace(model, _scene=_NudgedScene(model._scene, seed=seed))


def _rays(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Rays from a camera 300 mm away toward a box of 50 mm about the origin (the nut), unit directions;
    the first 50 in the plane x = 3 of the origin (a zero direction component)."""
    rng = np.random.default_rng(seed)
    origin = np.array([3.0, -2.0, -300.0])
    target = rng.uniform(-25, 25, (n, 3))
    target[:50, 0] = origin[0]
    d = target - origin
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.broadcast_to(origin, d.shape).copy(), d


@pytest.mark.parametrize("seed", range(3))
def test_ray_depths_take_only_the_triangle_from_embree(seed):
    v, t = hex_nut_mesh()
    model = prepare_model(v, t)
    o, d = _rays(20000, seed)
    before = model.ray_depths(o, d)
    nudged = _nudged_model(model, seed)
    after = nudged.ray_depths(o, d)
    assert nudged._scene.casts == 1
    assert np.isfinite(before).sum() > 1000 and np.isinf(before).sum() > 1000
    assert before.tobytes() == after.tobytes()


def test_ray_depths_are_embrees_to_float32_and_on_the_triangle():
    """The exact depth is the same geometry as Embree's: the same rays hit, t within float32's error at 300 mm, the
    hit point on its triangle's plane to float64's error (Embree's float32 t put it up to 1e-4 mm off)."""
    import open3d as o3d

    v, t = hex_nut_mesh()
    model = prepare_model(v, t)
    o, d = _rays(20000, 7)
    got = model.ray_depths(o, d)
    res = model._scene.cast_rays(o3d.core.Tensor(np.c_[o, d].astype(np.float32)))
    t32 = res["t_hit"].numpy().astype(np.float64)
    hit = np.isfinite(t32)
    assert np.array_equal(np.isfinite(got), hit) and hit.sum() > 1000
    assert np.abs(got[hit] - t32[hit]).max() < 1e-3
    prim = res["primitive_ids"].numpy()[hit].astype(np.int64)
    v0, e1, e2 = triangle_edges(model.vertices, model.triangles)
    n = np.cross(e1[prim], e2[prim])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    off = np.einsum("ij,ij->i", o[hit] + got[hit, None] * d[hit] - v0[prim], n)
    assert np.abs(off).max() < 1e-9


def test_a_sphere_model_keeps_its_closed_form():
    model = prepare_model(*icosphere(10.0, 4))
    assert model.sphere_radius is not None
    o, d = _rays(2000, 3)
    o = o + np.array([0.0, 0.0, 290.0])  # 10 mm from the sphere's near side
    nudged = _nudged_model(model, 0)
    got = nudged.ray_depths(o, d)
    assert nudged._scene.casts == 0 and np.isfinite(got).any()


@pytest.mark.parametrize("floor", [None, 330.0])
def test_renders_do_not_move_with_embrees_last_bits(monkeypatch, floor):
    v, t = hex_nut_mesh()
    meshes = [(v, t, pose(rotation((1, 0.3, 0), 20), (45, -20, 300))),
              (v, t, pose(rotation((-0.736, -0.163, -0.482), 42.67), (15, 10, 305))),
              (*icosphere(8.0, 3), pose(np.eye(3), (-30.0, 20.0, 310.0)))]
    xyz, ids = render(meshes, floor_z_mm=floor)
    made = _nudge_renders(monkeypatch, 5)
    xyz2, ids2 = render(meshes, floor_z_mm=floor)
    assert len(made) == 1 and made[0].casts == 1
    assert xyz.tobytes() == xyz2.tobytes() and ids.tobytes() == ids2.tobytes()
    assert {1, 2, 3} <= set(np.unique(ids).tolist()) and (floor is None) == bool(np.isnan(xyz).any())
    # the depth is z: every point on a face of the mesh its pixel names (the floor at its z exactly)
    if floor is not None:
        assert (xyz[ids == 0][:, 2] == floor).all()


def _fits_digest(fits: list[Any]) -> str:
    return hashlib.sha256(b"".join(repr(f.err_mm).encode() + f.pose.tobytes() + f.pixels.tobytes()
                                   for f in fits)).hexdigest()


def test_fits_do_not_move_with_embrees_last_bits(monkeypatch):
    """A scene rendered and fitted with Embree nudged everywhere (the renderer's casts and the fits' support casts)
    gives the same fits to the bit: two nuts, one partly hidden by a plate (test_fits_claims' scene)."""
    v, t = hex_nut_mesh()
    A = pose(rotation((1, 0.3, 0), 20), (45, -20, 300))
    B = pose(rotation((-0.736, -0.163, -0.482), 42.67), (15, 10, 305))
    plate = (np.array([[19.0, -300, 0], [-281, -300, 0], [-281, 300, 0], [19.0, 300, 0]]),
             np.array([[0, 1, 2], [0, 2, 3]]))
    meshes = [(v, t, A), (v, t, B), (*plate, pose(np.eye(3), (0, 0, 285)))]
    model = prepare_model(v, t)

    def fits_of(m: Any) -> str:
        xyz, ids = render(meshes, floor_z_mm=330)
        from zcut.fits import fit_prepared

        return _fits_digest(fit_prepared(xyz, (ids == 1) | (ids == 2), m, intrinsics=K_TEST))

    before = fits_of(model)
    made = _nudge_renders(monkeypatch, 9)
    nudged = _nudged_model(model, 9)
    after = fits_of(nudged)
    assert len(made) == 1 and nudged._scene.casts >= 2  # a support per accepted fit
    assert before == after


def test_fits_of_a_general_mesh_and_a_sphere_stay_on_their_parts():
    """Sanity on the exact depths: the nut of test_fits_claims' split scene is still found to 0.05 mm."""
    from zcut.fits import pose_error

    v, t = hex_nut_mesh()
    T = pose(rotation((1, 0.2, 0), 35) @ rotation((0, 0, 1), 10), (0, 0, 300))
    xyz, ids = render([(v, t, T)], floor_z_mm=320)
    fits = fit_parts(xyz, ids == 1, v, t, intrinsics=K_TEST, params=FitParams())
    assert len(fits) == 1
    dt, da = pose_error(fits[0].pose, T, prepare_model(v, t))
    assert dt < 0.05 and da < 0.5


# --- the kernels against their numpy reference ------------------------------------------------------------------


def _reference_t(t32: np.ndarray, prim: np.ndarray, o: np.ndarray, d: np.ndarray, v0: np.ndarray, e1: np.ndarray,
                 e2: np.ndarray) -> np.ndarray:
    """``hit_t`` in whole-array numpy: Embree's t where it misses, lies in the plane or a result is not finite."""
    t = t32.astype(np.float64)
    hit = np.isfinite(t)
    p = np.where(hit, prim, 0).astype(np.int64)
    det, tm, bu, bv = hit_tuv_reference(np.broadcast_to(o, d.shape), d, v0[p], e1[p], e2[p])
    with np.errstate(invalid="ignore"):
        ok = hit & (det != 0.0) & np.isfinite(tm) & np.isfinite(bu) & np.isfinite(bv)
    t[ok] = tm[ok]
    return t


def _cases() -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, origins, directions): random rays at the nut, one origin row for all, rays in a face's plane (from a
    corner along an edge: determinant 0), one ray, none."""
    v, _ = hex_nut_mesh()
    o, d = _rays(3000, 11)
    edge = v[1] - v[0]
    inplane_d = np.array([edge / np.linalg.norm(edge), -edge / np.linalg.norm(edge)])
    return [("random", o, d), ("one_origin", o[:1], d), ("in_plane", np.array([v[0] - 5 * inplane_d[0]] * 2),
                                                          inplane_d),
            ("one", o[:1], d[:1]), ("none", o[:0], d[:0])]


@pytest.mark.parametrize("case", range(5), ids=[c[0] for c in _cases()])
def test_the_kernels_equal_the_reference(case):
    import open3d as o3d

    _, o, d = _cases()[case]
    v, t = hex_nut_mesh()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(t.astype(np.uint32)))
    ob = np.broadcast_to(o, d.shape) if len(o) else np.zeros((0, 3))
    res = scene.cast_rays(o3d.core.Tensor(np.c_[ob, d].astype(np.float32).reshape(-1, 6)))
    t32, prim = res["t_hit"].numpy(), res["primitive_ids"].numpy()
    v0, e1, e2 = triangle_edges(v, t)
    want = _reference_t(t32, prim, np.ascontiguousarray(o), d, v0, e1, e2)
    got_tables = np.empty(len(d))
    hit_t(t32, prim, np.ascontiguousarray(o), np.ascontiguousarray(d), v0, e1, e2, got_tables)
    got_mesh = np.empty(len(d))
    mesh_hit_t(t32, prim, np.ascontiguousarray(o), np.ascontiguousarray(d), v, t, got_mesh)
    assert got_tables.tobytes() == want.tobytes() and got_mesh.tobytes() == want.tobytes()


def test_a_ray_in_the_triangles_plane_keeps_embrees_t():
    """Determinant 0 (a ray along a triangle's own plane) and a non-finite result keep the given float32 t."""
    v0 = np.array([[0.0, 0.0, 0.0]])
    e1 = np.array([[1.0, 0.0, 0.0]])
    e2 = np.array([[0.0, 1.0, 0.0]])
    o = np.array([[-1.0, 0.2, 0.0], [0.2, 0.2, -1.0], [0.2, 0.2, -1.0]])
    d = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    t32 = np.array([1.25, 0.75, np.inf], np.float32)
    t = np.empty(3)
    with np.errstate(invalid="ignore", divide="ignore"):
        hit_t(t32, np.zeros(3, np.int64), o, d, v0, e1, e2, t)
    assert t.tolist() == [1.25, 1.0, np.inf]  # in the plane: Embree's; across it: the exact 1.0; a miss: inf
    tm = np.empty(3)
    mesh_hit_t(t32, np.zeros(3, np.int64), o, d, np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]),
               np.array([[0, 1, 2]]), tm)
    assert tm.tobytes() == t.tobytes()
