"""The ray tracer's numba kernels against its literal numpy reference: the same bits.

``replay.synth.raytrace.optics`` does the per-ray arithmetic in numba kernels
(``replay.synth.raytrace.kernels``); ``replay.synth.raytrace.reference`` is the same physics in
whole-array numpy, line by line. A frame must come out with the same bytes either way (the logs are
byte-deterministic per seed, and a kernel that rounds differently would change them silently), so
every comparison here is of bytes, over whole frames of every part kind and sensor setting, and over
random and nasty inputs of each piece: NaN, misses, empty and one-row batches, values on the
thresholds (a point on the projector image's border, a normal at right angles to the light).
"""

from __future__ import annotations

import numpy as np
import pytest

from replay.synth.raytrace import kernels, optics, reference
from replay.synth.raytrace.materials import PART_MATERIALS, TABLE
from replay.synth.raytrace.meshes import part_mesh
from replay.synth.raytrace.optics import Phasors, SensorModel
from replay.synth.raytrace.pile import drop_parts, part_count
from replay.synth.raytrace.scene import Hits, TracedScene, build_scene
from replay.synth.raytrace.synthesize import raytrace_rng
from replay.synth.sensor import default_intrinsics
from replay.synth.synthesize import bin_pose_for, frame_rng
from zcut.cloud import Intrinsics

KINDS = ("spheres", "zinc_nuts", "rods", "black_screws", "black_nuts", "sprockets")
MODELS = {
    "default": SensorModel(),
    "more": SensorModel(samples=3, bounces=2, photon_stride=1),
    "least": SensorModel(samples=1, bounces=0, photon_stride=0, glare_share=0.0),
}


def same(a: np.ndarray, b: np.ndarray) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def same_hits(a: Hits, b: Hits) -> bool:
    return all(same(getattr(a, f), getattr(b, f)) for f in Hits.__slots__)


@pytest.fixture(scope="module")
def scenes():
    """A small pile of every kind (seed 11) and an empty bin, built once."""
    out = {}
    for kind in KINDS + (None,):
        pose = bin_pose_for(frame_rng(11, 0, empty=kind is None), empty=kind is None, index=0)
        pile = None
        if kind is not None:
            pile = drop_parts(kind, pose, raytrace_rng(11, 0, empty=False), count=min(part_count(kind, 6.0), 40))
        out[kind] = build_scene(pose, pile)
    return out


def _random_rays(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Rays from near the camera toward the bin, some from the projector, some pointing away (misses)."""
    origins = rng.normal(0.0, 40.0, (n, 3))
    d = np.column_stack([rng.normal(0, 0.4, n), rng.normal(0, 0.3, n), rng.choice([1.0, 1.0, 1.0, -1.0], n)])
    return origins, d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("model", list(MODELS), ids=list(MODELS))
def test_trace_is_the_reference(scenes, kind, model):
    scene, m = scenes[kind], MODELS[model]
    K = default_intrinsics((48, 80))
    a = optics.trace(scene, K, m, np.random.default_rng(7))
    b = reference.trace_reference(scene, K, m, np.random.default_rng(7))
    for name in ("direct", "camera_bounce", "projector_bounce", "glare"):
        pa, pb = getattr(a, name), getattr(b, name)
        assert same(pa.z, pb.z) and same(pa.intensity, pb.intensity), name
    assert same(a.sub_depth_mm, b.sub_depth_mm)
    assert same(a.specular_light, b.specular_light)
    assert same_hits(a.centre, b.centre)
    assert (a.direct.intensity > 0).any()  # the comparison is of light, not of empty images


@pytest.mark.parametrize("size", [(1, 64), (64, 1), (1, 1), (7, 5)])
def test_trace_of_degenerate_images(scenes, size):
    K = default_intrinsics((60, 96))
    K = Intrinsics(fx=K.fx, fy=K.fy, cx=size[1] / 2, cy=size[0] / 2, width=size[1], height=size[0])
    a = optics.trace(scenes["rods"], K, SensorModel(), np.random.default_rng(1))
    b = reference.trace_reference(scenes["rods"], K, SensorModel(), np.random.default_rng(1))
    assert same(a.direct.z, b.direct.z) and same(a.camera_bounce.z, b.camera_bounce.z)
    assert same(a.sub_depth_mm, b.sub_depth_mm) and same_hits(a.centre, b.centre)


@pytest.mark.parametrize("seed", range(4))
def test_cast_is_the_reference(scenes, seed):
    rng = np.random.default_rng(seed)
    scene = scenes[KINDS[seed]]
    origins, d = _random_rays(rng, 3000)
    a, b = scene.cast(origins, d), scene.cast_reference(origins, d)
    assert same_hits(a, b)
    assert 0 < a.hit.sum() < len(d)  # hits and misses both compared
    one = np.array([10.0, -5.0, 0.0])  # one origin for every ray, as the camera's and the projector's
    assert same_hits(scene.cast(one, d), scene.cast_reference(one, d))
    # into rows of a larger batch, as trace fills its sub-pixel hits
    out = Hits.empty(len(d) + 5)
    scene.cast(origins, d, out=out, at=5)
    assert same_hits(out.take(np.arange(5, len(d) + 5)), b)


def test_cast_of_nasty_rays(scenes):
    scene = scenes["spheres"]
    nasty = np.array([[np.nan, 0, 1], [0, 0, 0], [0, 0, 1], [0, 0, -1], [1, 0, 0], [np.inf, 0, 0]], float)
    with np.errstate(invalid="ignore"):
        for origins in (np.zeros(3), np.zeros((len(nasty), 3)), np.array([0.0, 0.0, np.nan])):
            a, b = scene.cast(origins, nasty), scene.cast_reference(origins, nasty)
            assert same_hits(a, b)
    empty = np.zeros((0, 3))
    a, b = scene.cast(np.zeros(3), empty), scene.cast_reference(np.zeros(3), empty)
    assert same_hits(a, b) and len(a.t) == 0
    # a ray along a face's plane and one through a shared vertex of the table's triangles
    scene2 = TracedScene([(part_mesh("rods"), TABLE, 0)])
    edge = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    with np.errstate(invalid="ignore"):  # the reference's inf * 0 of a miss along an axis
        assert same_hits(scene2.cast(np.zeros(3), edge), scene2.cast_reference(np.zeros(3), edge))


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("chunk", [optics.DIRECT_CHUNK, 1, 37])
def test_direct_light_is_the_reference(scenes, seed, chunk, monkeypatch):
    """On real hits, and on made-up points on the thresholds: the projector image's border, normals at
    right angles to the light, a point at the projector, NaN points; lit in one chunk and in many."""
    monkeypatch.setattr(optics, "DIRECT_CHUNK", chunk)
    rng = np.random.default_rng(100 + seed)
    scene = scenes[KINDS[seed + 3]]
    m = SensorModel()
    origins, d = _random_rays(rng, 2000)
    h = scene.cast(origins, d)
    idx = np.flatnonzero(h.hit)
    wo = -d[idx]
    ok, rad, code, refl = optics.direct_light(scene, m, h, idx, wo)
    with np.errstate(all="ignore"):
        ok_r, rad_r, code_r = reference.direct_light_reference(scene, m, h, idx, wo)
    assert same(ok, ok_r) and same(rad, rad_r) and same(code, code_r) and ok.any() and not ok.all()
    # the reflectance returned beside the radiance is the reference BRDF
    wi = optics._unit(m.projector_origin - h.point[idx[ok]])
    f = reference.brdf_reference(scene.mat, h.material[idx[ok]], h.normal[idx[ok]], wi, wo[ok])
    assert same(refl[ok], f) and np.isnan(refl[~ok]).all()

    # points on the projector image's borders (u = -0.5, u = w - 0.5, v = -0.5, v = h - 0.5) at
    # depths where the division is exact, and just outside; normals facing the projector, at right
    # angles to it, and away
    w_p, h_p = m.projector_size
    f_px, (cx, cy), b = m.projector_f_px, m.projector_c_px, m.baseline_mm
    z = np.array([985.0, 1970.0, 492.5])
    pts = []
    for zz in z:
        for u in (-0.5, w_p - 0.5, np.nextafter(-0.5, -1), np.nextafter(w_p - 0.5, np.inf), cx):
            for v in (-0.5, h_p - 0.5, np.nextafter(h_p - 0.5, np.inf), cy):
                pts.append([(u - cx) * zz / f_px + b, (v - cy) * zz / f_px, zz])
    pts += [[b, 0.0, 0.0], [np.nan, 0.0, 800.0], [0.0, 0.0, -800.0], [0.0, 0.0, np.inf]]
    pts = np.array(pts)
    n = len(pts)
    with np.errstate(all="ignore"):
        to_p = optics._unit(m.projector_origin - pts)
    perp = np.cross(to_p, [0.0, 1.0, 0.0])
    perp = perp / np.maximum(np.linalg.norm(perp, axis=1, keepdims=True), 1e-12)
    for normal in (to_p, perp, -to_p, np.nan_to_num(to_p)):
        made = Hits(np.ones(n), pts, normal, normal, rng.integers(0, len(scene.materials), n),
                    np.zeros(n, np.uint8), np.zeros(n, np.int32))
        sel = np.arange(n)
        wo = np.tile([0.0, 0.0, -1.0], (n, 1))
        with np.errstate(all="ignore"):
            got = optics.direct_light(scene, m, made, sel, wo)
            want = reference.direct_light_reference(scene, m, made, sel, wo)
        assert all(same(g, r) for g, r in zip(got[:3], want)), normal[0]
    # nothing to light
    got = optics.direct_light(scene, m, h, np.zeros(0, np.int64), np.zeros((0, 3)))
    want = reference.direct_light_reference(scene, m, h, np.zeros(0, np.int64), np.zeros((0, 3)))
    assert all(same(g, r) for g, r in zip(got[:3], want)) and len(got[0]) == 0


@pytest.mark.parametrize("seed", range(3))
def test_phasor_sums_are_the_reference(seed):
    rng = np.random.default_rng(seed)
    periods = (1280.0, 64.0, 8.0)
    shape = (13, 17)
    n = 5000
    flat = rng.integers(0, shape[0] * shape[1], n)  # many repeats per pixel: the order of the sums counts
    weight = rng.choice([1.0, 0.25, 1 / 9], n)
    value = rng.exponential(0.3, n)
    code = rng.uniform(-10, 1300, n)
    code[:40] = np.array(periods * 13 + (0.0,))  # whole periods: phases on multiples of 2 pi
    value[40:50] = 0.0
    start = Phasors(rng.normal(size=(3,) + shape) + 1j * rng.normal(size=(3,) + shape), rng.uniform(0, 1, shape))
    a = Phasors(start.z.copy(), start.intensity.copy())
    b = Phasors(start.z.copy(), start.intensity.copy())
    a.add(flat, weight, value, code, periods)
    b.add_reference(flat, weight * value, code, periods)
    assert same(a.z, b.z) and same(a.intensity, b.intensity)
    # NaN codes and NaN light poison their pixel in both; an empty batch and a 1-element batch
    code[5], value[6] = np.nan, np.nan
    a.add(flat, weight, value, code, periods)
    b.add_reference(flat, weight * value, code, periods)
    assert same(a.z, b.z) and same(a.intensity, b.intensity) and np.isnan(a.intensity).any()
    for k in (0, 1):
        a.add(flat[:k], weight[:k], value[:k], code[:k], periods)
        b.add_reference(flat[:k], weight[:k] * value[:k], code[:k], periods)
        assert same(a.z, b.z) and same(a.intensity, b.intensity)


@pytest.mark.parametrize("shape", [(1, 1), (1, 9), (9, 1), (48, 80), (1200, 1920)])
@pytest.mark.parametrize("du", [0.0, -0.25, 1 / 3])
def test_pixel_directions_are_the_reference(shape, du):
    K = default_intrinsics((48, 80))
    K = Intrinsics(fx=K.fx, fy=K.fy, cx=(shape[1] - 1) / 2, cy=(shape[0] - 1) / 2, width=shape[1], height=shape[0])
    assert same(optics.pixel_directions(K, du, -du), reference.pixel_directions_reference(K, du, -du))
    pick = np.array([0, shape[0] * shape[1] - 1])
    assert same(optics.pixel_directions(K, du, 0.0, flat=pick), reference.pixel_directions_reference(K, du, 0.0)[pick])


def test_add_at_and_specular_share_are_the_reference():
    rng = np.random.default_rng(3)
    flat = rng.integers(0, 50, 4000)
    a, b, c = rng.exponential(1.0, (3, 4000))
    b[:3] = [np.nan, np.inf, 0.0]
    out, want = np.zeros(50), np.zeros(50)
    kernels.add_at(out, flat, a, b, c)
    with np.errstate(invalid="ignore"):
        np.add.at(want, flat, a * b * c)
    assert same(out, want)
    albedo = np.array([0.05, 0.75, 0.15])
    mat = rng.integers(0, 3, 100)
    f = albedo[mat] / np.pi + rng.choice([0.0, 1e-300, 2.5, np.inf, np.nan], 100)
    share = np.empty(100)
    kernels.specular_share(mat, albedo, f, share)
    assert same(share, 1.0 - (albedo[mat] / np.pi) / f)
    assert (share[f == albedo[mat] / np.pi] == 0.0).all()


def test_a_made_up_part_scene_matches():
    """A part alone on nothing (most rays miss), lit head-on: the shiny material's highlight path."""
    mesh = part_mesh("spheres").transformed(np.eye(3), np.array([0.0, 0.0, 200.0]))
    scene = TracedScene([(mesh, PART_MATERIALS["spheres"], 1)])
    K = default_intrinsics((40, 64))
    a = optics.trace(scene, K, SensorModel(), np.random.default_rng(0))
    with np.errstate(invalid="ignore"):  # the reference's inf * 0 of projector rays that miss along an axis
        b = reference.trace_reference(scene, K, SensorModel(), np.random.default_rng(0))
    assert same(a.direct.z, b.direct.z) and same(a.specular_light, b.specular_light)
    assert same(a.projector_bounce.z, b.projector_bounce.z)


@pytest.mark.parametrize("shape", [(0, 0), (1, 1), (1, 17), (17, 1), (2, 2), (31, 45)])
@pytest.mark.parametrize("seed", range(3))
def test_isolated_points_are_the_reference(shape, seed):
    """The camera's outlier filter as a kernel against its whole-array numpy: random clouds with holes,
    neighbours exactly at the distance (3-4-0 and 0-0-5 steps of 5 mm), float32 input."""
    from replay.synth.raytrace.camera_filters import isolated_points, isolated_points_reference

    rng = np.random.default_rng(seed)
    h, w = shape
    xyz = np.stack([np.tile(np.arange(w) * 3.0, (h, 1)), np.tile(np.arange(h)[:, None] * 4.0, (1, w)),
                    np.full((h, w), 500.0)], axis=2)
    xyz[..., 2] += rng.choice([0.0, 5.0, -5.0, 20.0, 4.999999, 5.000001], (h, w), p=[0.5, 0.1, 0.1, 0.1, 0.1, 0.1])
    xyz[rng.random((h, w)) < 0.15] = np.nan
    if h * w:
        xyz.reshape(-1, 3)[rng.integers(0, h * w)] = (np.inf, 0.0, 500.0)
    for within in (5.0, 1.0, 0.0, 25.0):
        for cloud in (xyz, xyz.astype(np.float32), xyz[:, ::-1]):
            with np.errstate(invalid="ignore"):
                want = isolated_points_reference(cloud, within_mm=within)
            got = isolated_points(cloud, within_mm=within)
            assert same(got, want), within
    if h * w > 100:
        assert isolated_points(xyz, within_mm=5.0).any() and not isolated_points(xyz, within_mm=5.0).all()


@pytest.mark.parametrize("shape", [(1, 1), (1, 23), (23, 1), (2, 3), (40, 64)])
@pytest.mark.parametrize("seed", range(3))
def test_edge_pixels_are_the_reference(shape, seed):
    """The edge test as a kernel against scipy's 3 x 3 filters: depth steps exactly at the threshold
    and just beyond, misses (inf, NaN), parts and surfaces changing, thin images."""
    rng = np.random.default_rng(seed)
    z = 500.0 + rng.choice([0.0, 1.5, 1.5000001, 3.0, -1.5], shape)
    z[rng.random(shape) < 0.1] = np.inf
    z[rng.random(shape) < 0.05] = np.nan
    part = rng.choice([0, 0, 0, 3, 7], shape).astype(np.int32)
    label = rng.choice([1, 1, 1, 2], shape).astype(np.uint8)
    for jump in (1.5, 0.0, 3.0):
        want = reference.edge_pixels_reference(z, part, label, jump_mm=jump)
        assert same(optics.edge_pixels(z, part, label, jump_mm=jump), want), jump
    flat = optics.edge_pixels(np.full(shape, 500.0), np.zeros(shape, np.int32), np.ones(shape, np.uint8))
    assert not flat.any()


def test_edge_pixels_of_a_frame_are_the_reference(scenes):
    K = default_intrinsics((60, 96))
    h = scenes["sprockets"].cast(np.zeros(3), optics.pixel_directions(K))
    z = np.where(h.hit, h.point[:, 2], np.inf).reshape(K.height, K.width)
    a = optics.edge_pixels(z, h.part.reshape(z.shape), h.label.reshape(z.shape))
    assert same(a, reference.edge_pixels_reference(z, h.part.reshape(z.shape), h.label.reshape(z.shape)))
    assert a.any() and not a.all()
