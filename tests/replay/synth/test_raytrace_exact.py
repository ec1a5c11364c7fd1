"""The ray-traced sensor's bytes do not depend on the last bits of Embree's float answers.

Open3D's ``RaycastingScene`` (Embree) answers in float32 from SIMD kernels chosen at run time by
the CPU, and two CPUs answered the same rays with different last bits (docs/synthetic.md, "Exact
hits"). ``TracedScene.cast`` therefore takes from Embree only whether a ray hits and which triangle,
and computes the hit's ``t``, barycentric ``u, v`` and face normal in float64 itself. These tests
nudge Embree's float answers by 1-2 ulp, as another CPU would, and ask for the same bytes: of the
hits, of the shadow rays' ``t``, and of whole frames of two part kinds, a frame with the camera's
filters and a bin without parts.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
from ulp_nudge import nudge as _nudge

from replay.synth.raytrace import synthesize_raytraced_frame
from replay.synth.raytrace.camera_filters import CameraFilters
from replay.synth.raytrace.materials import TABLE
from replay.synth.raytrace.meshes import part_mesh
from replay.synth.raytrace.pile import drop_parts, part_count
from replay.synth.raytrace.scene import Hits, TracedScene, build_scene
from replay.synth.raytrace.synthesize import raytrace_rng
from replay.synth.synthesize import bin_pose_for, frame_rng


def _same_hits(a: Hits, b: Hits) -> bool:
    return all(np.asarray(getattr(a, f)).tobytes() == np.asarray(getattr(b, f)).tobytes() for f in Hits.__slots__)


def _nudge_embree(monkeypatch: pytest.MonkeyPatch, seed: int) -> list[int]:
    """From now on every ``TracedScene._raw`` answers Embree's with its float outputs nudged (the ids kept);
    returns a list whose one element counts the nudged calls."""
    import open3d as o3d

    raw = TracedScene._raw
    rng = np.random.default_rng(seed)
    calls = [0]

    def nudged_raw(self: TracedScene, rays: np.ndarray) -> dict[str, o3d.core.Tensor]:
        res = raw(self, rays)
        out = {k: res[k] for k in res}
        for k in ("t_hit", "primitive_uvs", "primitive_normals"):
            a = res[k].numpy()
            b = _nudge(a, rng)
            assert not np.isfinite(a).any() or (b != a).any()
            out[k] = o3d.core.Tensor.from_numpy(np.ascontiguousarray(b))
        calls[0] += 1
        return out

    monkeypatch.setattr(TracedScene, "_raw", nudged_raw)
    return calls


@pytest.fixture(scope="module")
def nuts_scene() -> TracedScene:
    pose = bin_pose_for(frame_rng(11, 0, empty=False), empty=False, index=0)
    pile = drop_parts("zinc_nuts", pose, raytrace_rng(11, 0, empty=False), count=min(part_count("zinc_nuts", 6.0), 40))
    return build_scene(pose, pile)


def _rays(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Rays from near the camera toward the bin, some pointing away (misses)."""
    rng = np.random.default_rng(seed)
    origins = rng.normal(0.0, 40.0, (n, 3))
    d = np.column_stack([rng.normal(0, 0.4, n), rng.normal(0, 0.3, n), rng.choice([1.0, 1.0, 1.0, -1.0], n)])
    return origins, d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize("seed", range(3))
def test_hits_take_only_the_triangle_from_embree(nuts_scene, monkeypatch, seed):
    origins, d = _rays(4000, seed)
    one = np.array([10.0, -5.0, 0.0])
    before = [nuts_scene.cast(origins, d), nuts_scene.cast_reference(origins, d), nuts_scene.cast(one, d)]
    t_before = [nuts_scene.cast_t(origins, d), nuts_scene.cast_t(one, d)]
    assert 0 < before[0].hit.sum() < len(d)  # hits and misses both
    calls = _nudge_embree(monkeypatch, seed)
    after = [nuts_scene.cast(origins, d), nuts_scene.cast_reference(origins, d), nuts_scene.cast(one, d)]
    t_after = [nuts_scene.cast_t(origins, d), nuts_scene.cast_t(one, d)]
    assert calls[0] == 4  # cast_reference calls Open3D itself, not through _raw
    assert _same_hits(before[0], after[0]) and _same_hits(before[2], after[2])
    assert _same_hits(before[0], before[1])  # the kernel is the reference
    for a, b in zip(t_before, t_after):
        assert a.tobytes() == b.tobytes()
    assert t_before[0].tobytes() == before[0].t.tobytes() and t_before[1].tobytes() == before[2].t.tobytes()


def test_exact_hits_are_embrees_to_float32(nuts_scene):
    """What replaced Embree's float answers is the same geometry: t within float32's error at the scene's
    600 mm, the barycentric coordinates inside the triangle, the face normal Embree's, the point on the plane."""
    import open3d as o3d

    origins, d = _rays(6000, 7)
    h = nuts_scene.cast(origins, d)
    rays = np.concatenate([origins, d], axis=1).astype(np.float32)
    res = nuts_scene._scene.cast_rays(o3d.core.Tensor.from_numpy(rays))
    t32 = res["t_hit"].numpy().astype(np.float64)
    hit = np.isfinite(t32)
    assert (h.hit == hit).all() and hit.sum() > 1000
    assert np.abs(h.t[hit] - t32[hit]).max() < 1e-3  # mm, at t of 500-700 mm: float32's few ulp
    prim = res["primitive_ids"].numpy()[hit].astype(np.int64)
    geo = res["primitive_normals"].numpy()[hit].astype(np.float64)
    assert np.abs(np.abs(np.einsum("ij,ij->i", nuts_scene.face_normals[prim], geo)) - 1.0).max() < 1e-5
    # the hit point lies on its triangle's plane, to float64's error (Embree's float32 t put it up to 1e-4 mm off)
    off = np.einsum("ij,ij->i", h.point[hit] - nuts_scene.v0[prim], nuts_scene.face_normals[prim])
    assert np.abs(off).max() < 1e-9


@pytest.mark.parametrize("kw", [
    dict(kind="rods", seed=4),
    dict(kind="zinc_nuts", seed=5),
    dict(kind="zinc_nuts", seed=5, camera_filters=CameraFilters(outlier_mm=3.0)),
    dict(kind="spheres", seed=2, empty=True),
], ids=["rods", "zinc_nuts", "zinc_nuts-filters", "empty-bin"])
def test_frames_do_not_move_with_embrees_last_bits(monkeypatch, kw):
    a = _frame_digest(size=(40, 64), fill_mm=6.0, **kw)
    calls = _nudge_embree(monkeypatch, 5)
    b = _frame_digest(size=(40, 64), fill_mm=6.0, **kw)
    assert calls[0] > 0
    assert a == b


def test_rays_in_a_face_plane_keep_embrees_answer():
    """A ray in the plane of the triangle Embree reports (Möller–Trumbore's determinant 0) keeps Embree's
    float32 t, uv and normal, in the kernel and in the reference alike."""
    scene = TracedScene([(part_mesh("rods"), TABLE, 0)])
    edge = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    with np.errstate(invalid="ignore"):
        a, b = scene.cast(np.zeros(3), edge), scene.cast_reference(np.zeros(3), edge)
    assert _same_hits(a, b)
def _frame_digest(**kw: object) -> str:
    rf = synthesize_raytraced_frame(**kw)  # type: ignore[arg-type]
    h = hashlib.sha256()
    for a in (rf.frame.xyz, rf.frame.rgb, rf.truth, rf.outlier_kind, rf.off_surface, rf.depth_true_m):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()
