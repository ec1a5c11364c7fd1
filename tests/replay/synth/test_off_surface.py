"""The paper's truth (``/ground_truth/off_surface``) and the part model a synthetic log carries.

The meshes of the hand-made parts are checked against their solids (closed, every vertex on the
solid, the solid's volume); the truth against an independent brute-force point-to-triangle distance
in numpy over every triangle of a small scene; the ``part_model.ply`` attachment is read back with
the independent ``mcap`` library; ``zcut record --part-model`` with a good and a bad mesh.
"""

from __future__ import annotations

import numpy as np
import pytest
from mcap.reader import make_reader

from replay.logs import layout
from replay.logs.part_model import (
    PART_MODEL_ATTACHMENT,
    PART_MODEL_MEDIA_TYPE,
    part_model_ply_bytes,
    read_part_model,
    read_part_model_bytes,
)
from replay.logs.reader import LogReader
from replay.presets import HEX_M_MM, HEX_S_MM, NUT_BORE_MM
from replay.synth import write_synthetic_log
from replay.synth.parts import part_solid
from replay.synth.raytrace import synthesize_raytraced_frame, write_raytraced_log
from replay.synth.raytrace.meshes import part_mesh
from replay.synth.sensor import CAMERA_HEIGHT_MM
from replay.synth.surfaces import (
    OFF_SURFACE_K,
    TrueSurfaces,
    err_mm,
    handmade_surfaces,
    kind_model_mesh,
    off_surface,
    solid_mesh,
)
from replay.synth.synthesize import synthesize_frame
from tests.cli_helpers import run_cli

SIZE = (60, 96)


def _volume(v: np.ndarray, t: np.ndarray) -> float:
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _inside(prims, hole, p: np.ndarray, eps: float) -> np.ndarray:
    inn = np.zeros(len(p), bool)
    for pr in prims:
        inn |= (p @ pr[1].T <= pr[2] + eps).all(axis=1)
    if hole is not None:
        inn &= ~(p @ hole[1].T < hole[2] - eps).all(axis=1)
    return inn


def _point_triangle_distance(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Distance of each point (n, 3) to the nearest of the triangles (m, 3, 3): Ericson's closest
    point on a triangle, all regions, in numpy (chunked over points)."""
    out = np.empty(len(p))
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac = b - a, c - a
    for k in range(len(p)):
        x = p[k]
        ap, bp, cp = x - a, x - b, x - c
        d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
        d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
        d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
        va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
        with np.errstate(divide="ignore", invalid="ignore"):
            denom = 1.0 / (va + vb + vc)
            v, w = vb * denom, vc * denom
            q = a + ab * v[:, None] + ac * w[:, None]  # inside the face
            # edges
            t_ab = np.clip(d1 / (d1 - d3), 0, 1)
            t_ac = np.clip(d2 / (d2 - d6), 0, 1)
            t_bc = np.clip((d4 - d3) / ((d4 - d3) + (d5 - d6)), 0, 1)
        cand = np.stack([q, a, b, c, a + ab * np.nan_to_num(t_ab)[:, None], a + ac * np.nan_to_num(t_ac)[:, None],
                         b + (c - b) * np.nan_to_num(t_bc)[:, None]])
        inside = (va >= 0) & (vb >= 0) & (vc >= 0)
        dist = np.linalg.norm(cand - x, axis=2)  # (7, m)
        edge = dist[1:].min(axis=0)
        best = np.where(inside, np.minimum(dist[0], edge), edge)
        out[k] = best.min()
    return out


@pytest.mark.parametrize("kind", ["zinc_nuts", "rods", "black_screws", "sprockets"])
def test_part_meshes_are_the_solids(kind):
    prims, hole = part_solid(kind, np.random.default_rng(7))
    v, t = solid_mesh(prims, hole)
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert (counts == 2).all()  # closed, every edge shared by two triangles
    assert _inside(prims, hole, v[np.unique(t)], 1e-6).all()  # every vertex on the solid
    # and nothing of the solid is missing: its volume (Monte Carlo over its bounding box)
    rng = np.random.default_rng(1)
    lo, hi = v.min(axis=0), v.max(axis=0)
    q = rng.uniform(lo, hi, (200_000, 3))
    mc = _inside(prims, hole, q, 0.0).mean() * np.prod(hi - lo)
    assert _volume(v, t) == pytest.approx(mc, rel=0.01)


def test_the_nut_mesh_has_the_nuts_volume():
    v, t = kind_model_mesh("zinc_nuts")
    bore = 24 * (NUT_BORE_MM / 2) ** 2 * np.tan(np.pi / 24)  # the 24-gon the generator bores
    assert _volume(v, t) == pytest.approx((np.sqrt(3) / 2 * HEX_S_MM**2 - bore) * HEX_M_MM, rel=1e-12)


def test_err_is_noise_and_half_the_footprint_diagonal():
    # z = 500 mm, f = 1600 px: footprint 0.3125 mm; sigma 0.1 mm
    assert err_mm(np.array(500.0), 0.1, 1600.0) == pytest.approx(np.sqrt(0.01 + 0.3125**2 / 2))
    assert err_mm(np.array(500.0), 0.1, 1600.0, cell_mm=0.5) == pytest.approx(np.sqrt(0.01 + 0.125))
    assert err_mm(np.array(500.0), 0.0, 1e12, quantize_mm=1.0) == pytest.approx(np.sqrt(1 / 12))


def test_a_point_on_a_surface_is_not_flagged_and_one_beyond_3_err_is():
    # a unit-less box (two triangles per face) and a ball
    box_v = np.array([[x, y, z] for x in (0, 10) for y in (0, 10) for z in (100, 110)], float)
    box_t = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    s = TrueSurfaces(box_v, box_t, sphere_centres=np.array([[50.0, 0.0, 100.0]]), sphere_radius=5.0)
    xyz = np.full((2, 4, 3), np.nan)
    xyz[0, 0] = (5.0, 5.0, 100.0)  # on the box's face
    xyz[0, 1] = (50.0, 5.0, 100.0)  # on the ball
    xyz[0, 2] = (5.0, 5.0, 100.0 - 0.3 - 1e-3)  # 0.301 from the face: beyond 3 × 0.1
    xyz[0, 3] = (5.0, 5.0, 100.0 - 0.3 + 1e-3)  # 0.299: within
    xyz[1, 0] = (50.0, 5.4, 100.0)  # 0.4 off the ball
    xyz[1, 1] = (5.0, 5.0, 105.0)  # inside the box, 5 from every face
    err = np.full((2, 4), 0.1)
    out = off_surface(xyz, err, s)
    assert out.tolist() == [[False, False, True, False], [True, True, False, False]]


@pytest.fixture(scope="module")
def nuts():
    return synthesize_frame(kind="zinc_nuts", seed=901, size=SIZE, fill_mm=6.0)


def test_handmade_truth_by_an_independent_distance(nuts):
    sf = nuts
    off = sf.off_surface
    valid = np.isfinite(sf.frame.xyz).all(axis=2)
    assert not (off & ~valid).any() and off.any() and (valid & ~off).any()
    assert sf.frame.masks[layout.TRUTH_OFF_SURFACE] is off
    # every triangle of the scene, rebuilt in the camera frame, and the sampled pixels' distances
    surfaces = handmade_surfaces(sf.scene, camera_height_mm=CAMERA_HEIGHT_MM)
    del surfaces  # only to show it builds; the check below is independent of Open3D
    tris = []
    for part in sf.scene.parts:
        v, t = solid_mesh(*part.solid)
        w = v @ part.R.T + part.centre_mm
        tris.append(w[t])
    from replay.presets import BIN
    from replay.synth.raytrace.meshes import bin_mesh

    m = bin_mesh(sf.scene.bin_pose, BIN)
    tris.append(m.vertices[m.triangles])
    g = sf.scene.grid
    x0, x1, y0, y1 = g.x0, g.x0 + g.step * (g.nx - 1), g.y0, g.y0 + g.step * (g.ny - 1)
    tris.append(np.array([[[x0, y0, 0], [x1, y0, 0], [x1, y1, 0]], [[x0, y0, 0], [x1, y1, 0], [x0, y1, 0]]], float))
    world = np.concatenate(tris)
    cam = np.stack([world[..., 0], -world[..., 1], CAMERA_HEIGHT_MM - world[..., 2]], axis=-1)
    rng = np.random.default_rng(0)
    flagged = np.argwhere(off)
    kept = np.argwhere(valid & ~off)
    pick = np.concatenate([flagged[rng.choice(len(flagged), min(60, len(flagged)), replace=False)],
                           kept[rng.choice(len(kept), 140, replace=False)]])
    p = sf.frame.xyz[pick[:, 0], pick[:, 1]].astype(np.float64) * 1000.0
    d = _point_triangle_distance(p, cam)
    thr = OFF_SURFACE_K * sf.err_mm[pick[:, 0], pick[:, 1]].astype(np.float64)
    far = d > thr
    near_edge = np.abs(d - thr) < 1e-3  # float32 inside Open3D: undecidable within 1e-3 mm
    np.testing.assert_array_equal(far[~near_edge], off[pick[:, 0], pick[:, 1]][~near_edge])


def test_points_on_the_true_surfaces_are_not_flagged(nuts):
    sf = nuts
    surfaces = handmade_surfaces(sf.scene, camera_height_mm=CAMERA_HEIGHT_MM)
    rng = np.random.default_rng(3)
    pts = []
    for part in sf.scene.parts[:40]:
        v, t = solid_mesh(*part.solid)
        w = v @ part.R.T + part.centre_mm
        k = rng.integers(0, len(t), 5)
        bary = rng.dirichlet(np.ones(3), 5)
        pts.append(np.einsum("kj,kjd->kd", bary, w[t[k]]))
    world = np.concatenate(pts)
    cam = np.column_stack([world[:, 0], -world[:, 1], CAMERA_HEIGHT_MM - world[:, 2]])
    assert surfaces.distance(cam).max() < 1e-3
    xyz = cam.reshape(1, -1, 3)
    assert not off_surface(xyz, np.full(xyz.shape[:2], 0.01), surfaces).any()


def test_a_deformed_empty_bin_explains_its_own_points():
    from replay.synth.scene import BinShape

    sf = synthesize_frame(empty=True, seed=906, size=SIZE, bin_shape=BinShape(bulge_mm=6.0, deform_mm=4.0))
    valid = np.isfinite(sf.frame.xyz).all(axis=2)
    assert not (sf.off_surface & ~valid).any()
    # the bulging, twisting bin is its own height field: only the sensor's outliers are off it
    assert (sf.off_surface & ~sf.truth).sum() <= 0.002 * valid.sum()


def test_handmade_log_carries_the_truth_and_the_part_model(tmp_path):
    path = write_synthetic_log(tmp_path / "nuts.mcap", kind="zinc_nuts", frames=1, seed=902, size=SIZE)
    frames = list(LogReader(path).frames())
    for f in frames:
        sf = synthesize_frame(kind="zinc_nuts", seed=902, index=f.index, size=SIZE)
        np.testing.assert_array_equal(f.masks[layout.TRUTH_OFF_SURFACE], sf.off_surface)
        np.testing.assert_array_equal(f.masks[layout.TRUTH_OUTLIERS], sf.truth)
        assert not (f.masks[layout.TRUTH_OFF_SURFACE] & ~np.isfinite(f.xyz).all(axis=2)).any()
    with open(path, "rb") as fh:
        atts = {a.name: a for a in make_reader(fh, validate_crcs=True).iter_attachments()}
    assert set(atts) == {layout.BIN_MODEL_ATTACHMENT, PART_MODEL_ATTACHMENT}
    assert atts[PART_MODEL_ATTACHMENT].media_type == PART_MODEL_MEDIA_TYPE
    model = read_part_model(path)
    v, t = kind_model_mesh("zinc_nuts")
    assert model is not None and model.unit == "mm"
    np.testing.assert_array_equal(model.vertices, v)
    np.testing.assert_array_equal(model.triangles, t)
    np.testing.assert_allclose(model.vertices_m, v / 1000.0, rtol=1e-15)


def test_an_empty_bin_log_carries_no_part_model(tmp_path):
    path = write_synthetic_log(tmp_path / "empty.mcap", empty=True, frames=1, seed=3, size=SIZE)
    assert read_part_model(path) is None
    (f,) = LogReader(path).frames()
    assert layout.TRUTH_OFF_SURFACE in f.masks


def test_raytraced_truth_and_part_model(tmp_path):
    rf = synthesize_raytraced_frame(kind="spheres", seed=903, size=SIZE, fill_mm=6.0)
    valid = np.isfinite(rf.frame.xyz).all(axis=2)
    assert not (rf.off_surface & ~valid).any()
    assert rf.frame.masks[layout.TRUTH_OFF_SURFACE] is rf.off_surface
    # independently: every triangle of the scene the rays were cast on, rebuilt from its pile
    from replay.synth.raytrace.scene import build_scene
    from replay.synth.synthesize import bin_pose_for, frame_rng

    scene = build_scene(bin_pose_for(frame_rng(903, 0, empty=False), empty=False, index=0), rf.pile)
    cam = scene.vertices[scene.triangles]
    idx = np.argwhere(valid)
    pick = idx[np.random.default_rng(1).choice(len(idx), 80, replace=False)]
    pick = np.concatenate([pick, np.argwhere(rf.off_surface)[:40]])
    p = rf.frame.xyz[pick[:, 0], pick[:, 1]].astype(np.float64) * 1000.0
    d = _point_triangle_distance(p, cam)
    thr = OFF_SURFACE_K * rf.err_mm[pick[:, 0], pick[:, 1]].astype(np.float64)
    near_edge = np.abs(d - thr) < 1e-3
    np.testing.assert_array_equal((d > thr)[~near_edge], rf.off_surface[pick[:, 0], pick[:, 1]][~near_edge])

    path = write_raytraced_log(tmp_path / "rt.mcap", kind="rods", frames=1, seed=904, size=(40, 64), fill_mm=6.0)
    (f,) = LogReader(path).frames()
    assert layout.TRUTH_OFF_SURFACE in f.masks
    model = read_part_model(path)
    m = part_mesh("rods")
    assert model is not None and model.unit == "mm"
    np.testing.assert_array_equal(model.vertices, m.vertices)
    np.testing.assert_array_equal(model.triangles, m.triangles)


def test_a_part_model_without_unit_or_faces_is_refused():
    from replay.errors import LogFormatError

    good = part_model_ply_bytes(np.eye(3), np.array([[0, 1, 2]]), unit="m")
    assert read_part_model_bytes(good).unit == "m"
    with pytest.raises(LogFormatError, match="unit"):
        read_part_model_bytes(good.replace(b"unit: m", b"size: m"))


def _cloud_dir(tmp_path):
    d = tmp_path / "clouds"
    d.mkdir()
    h, w = 4, 5
    xyz = np.zeros((h, w, 3), np.float32)
    xyz[..., 0], xyz[..., 1] = np.meshgrid(np.arange(w) * 0.01, np.arange(h) * 0.01)
    xyz[..., 2] = 0.5
    lines = ["ply", "format ascii 1.0", f"element vertex {h * w}", "property float x", "property float y", "property float z", "end_header"]
    lines += [f"{x} {y} {z}" for x, y, z in xyz.reshape(-1, 3)]
    (d / "a.ply").write_text("\n".join(lines) + "\n")
    return d


def test_record_attaches_a_part_model(tmp_path, capsys):
    import open3d as o3d

    stl = tmp_path / "part.stl"
    v, t = kind_model_mesh("zinc_nuts")
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(t.astype(np.int32)))
    mesh.compute_triangle_normals()
    assert o3d.io.write_triangle_mesh(str(stl), mesh)
    src = _cloud_dir(tmp_path)
    out = tmp_path / "log.mcap"
    rc, _, err = run_cli(capsys, "record", src, "-o", out, "--size", "5x4", "--unit", "m", "--part-model", stl, "--part-model-unit", "mm")
    assert rc == 0, err
    model = read_part_model(out)
    assert model is not None and model.unit == "mm" and len(model.triangles) == len(t)
    np.testing.assert_allclose(model.vertices.min(axis=0), v.min(axis=0), atol=1e-5)  # STL: float32
    np.testing.assert_allclose(model.vertices.max(axis=0), v.max(axis=0), atol=1e-5)
    assert _volume(model.vertices, model.triangles) == pytest.approx(_volume(v, t), rel=1e-5)


@pytest.mark.parametrize("content, unit, match", [
    (b"not a mesh at all", "mm", "part.stl"),
    (None, "mm", "no such part model"),
    (b"solid x\nendsolid x\n", None, "--part-model-unit"),
])
def test_record_refuses_a_bad_part_model(tmp_path, capsys, content, unit, match):
    bad = tmp_path / "part.stl"
    if content is not None:
        bad.write_bytes(content)
    src = _cloud_dir(tmp_path)
    out = tmp_path / "log.mcap"
    argv = ["record", src, "-o", out, "--size", "5x4", "--unit", "m", "--part-model", bad] + (["--part-model-unit", unit] if unit else [])
    rc, _, err = run_cli(capsys, *argv)
    assert rc == 1
    lines = [x for x in err.splitlines() if not x.startswith("zcut: compiling")]  # a first run's notice
    assert len(lines) == 1 and lines[0].startswith("error: ") and match in lines[0], err
    assert not out.exists()
