"""zcut.registration.voxel_down_points: Open3D 0.20's ``voxel_down_sample`` without Open3D, held to it
(the oracle, run in the same test on the same input) bit for bit and in its order: random clouds at
several scales and voxels, points on voxel faces, repeated points, clouds of many voxels (the map's
rehashes up to 85k buckets), the bin pixels of synthetic frames (hand-made and ray-traced, a large invalid
region), real Kinect clouds, degenerate ones; the registration's target and its coarse cloud."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from zcut.errors import InputShapeError, ParameterError
from zcut.registration import voxel_down_points

REAL = Path("/work/shared/data/real")


def open3d_voxels(points: np.ndarray, voxel: float) -> np.ndarray:
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(points, np.float64)))
    return np.asarray(pc.voxel_down_sample(voxel).points, dtype=np.float64)


def assert_same(points: np.ndarray, voxel: float) -> np.ndarray:
    got = voxel_down_points(points, voxel)
    want = open3d_voxels(points, voxel)
    assert got.dtype == np.float64 and got.shape == want.shape, (got.shape, want.shape)
    assert got.tobytes() == want.tobytes()  # the same points in the same order
    return got


def test_random_clouds():
    rng = np.random.default_rng(41)
    for t in range(60):
        n = int(rng.integers(1, 40_000)) if t % 3 else int(rng.integers(1, 300))
        p = rng.normal(0.0, float(rng.choice([0.005, 0.05, 0.3, 2.0])), (n, 3)) + rng.normal(0.0, 1.0, 3)
        assert_same(p, float(rng.choice([0.0005, 0.001, 0.003, 0.006, 0.05])))


def test_points_on_voxel_faces_and_repeated_points():
    rng = np.random.default_rng(42)
    p = np.round(rng.normal(0.0, 0.05, (20_000, 3)) / 0.003) * 0.003 + 0.8
    assert_same(p, 0.003)
    assert_same(np.repeat(p[:500], 7, axis=0), 0.003)
    assert_same(np.tile(p[:500], (7, 1)), 0.003)
    assert_same(np.full((10, 3), 0.25), 0.003)     # one voxel
    assert_same(np.array([[0.1, 0.2, 0.3]]), 0.003)  # one point


def test_many_voxels():
    """Every point its own voxel: the arrays grow many times over, the map rehashes up to 85k buckets."""
    rng = np.random.default_rng(43)
    p = rng.uniform(0.0, 1.0, (60_000, 3))
    out = assert_same(p, 0.001)
    assert len(out) > 42_043


def test_the_bin_pixels_of_synthetic_frames():
    from replay.synth.raytrace import synthesize_raytraced_frame
    from replay.synth.synthesize import synthesize_frame
    from zcut.binmask import bin_mask, bin_pixels

    frames = [synthesize_frame(kind="zinc_nuts", seed=61, index=1, size=(480, 640)).frame,
              synthesize_frame(kind="spheres", seed=62, index=0, size=(600, 960), pile="walls").frame,
              synthesize_raytraced_frame(kind="zinc_nuts", seed=63, index=0, size=(150, 240)).frame]
    for f in frames:
        pixels = bin_pixels(bin_mask(f.rgb), f.xyz)
        pts = f.xyz[pixels].astype(np.float64)
        assert len(pts) > 100
        assert_same(pts, 0.003)
        assert_same(pts, 0.006)
        holed = f.xyz.copy()
        holed[:, : f.xyz.shape[1] // 2] = np.nan
        pts = holed[pixels & np.isfinite(holed).all(axis=2)].astype(np.float64)
        assert_same(pts, 0.003)


@pytest.mark.parametrize("name", ["mosd_test16.pcd", "table_scene_mug_stereo_textured.pcd",
                                  "milk_cartoon_all_small_clorox.pcd"])
def test_real_clouds(name):
    from replay.logs.pcd import read_pcd

    path = REAL / name
    if not path.is_file():
        pytest.skip(f"{path} is not here")
    xyz = read_pcd(path).xyz
    pts = xyz[np.isfinite(xyz).all(axis=2)].astype(np.float64)
    for voxel in (0.003, 0.01):
        assert_same(pts, voxel)


def test_empty():
    assert voxel_down_points(np.empty((0, 3)), 0.003).shape == (0, 3)


@pytest.mark.parametrize("points, voxel, exc, match", [
    (np.zeros((4, 2)), 0.003, InputShapeError, r"\(N, 3\)"),
    (np.zeros(3), 0.003, InputShapeError, r"\(N, 3\)"),
    (np.zeros((4, 3)), 0.0, ParameterError, "voxel_m must be > 0"),
    (np.zeros((4, 3)), -1.0, ParameterError, "voxel_m must be > 0"),
    (np.array([[0.0, 0.0, 0.0], [1e30, 0.0, 0.0]]), 0.003, InputShapeError, "the target spans 1e\\+30 m"),
])
def test_bad_input(points, voxel, exc, match):
    with pytest.raises(exc, match=match):
        voxel_down_points(points, voxel)


def test_the_registration_target_and_its_coarse_cloud():
    from replay.synth.synthesize import synthesize_frame
    from zcut.binmask import bin_mask, bin_pixels
    from zcut.registration import prepare_target

    f = synthesize_frame(kind="black_nuts", seed=64, index=0, size=(480, 640)).frame
    pts = f.xyz[bin_pixels(bin_mask(f.rgb), f.xyz)]
    t = prepare_target(pts, voxel_m=0.003, intrinsics=f.intrinsics)
    fine = np.asarray(t.cloud.points)
    assert fine.tobytes() == open3d_voxels(pts.astype(np.float64), 0.003).tobytes()
    assert voxel_down_points(fine, 0.006).tobytes() == open3d_voxels(fine, 0.006).tobytes()
    none = prepare_target(pts, voxel_m=0.0)
    assert np.asarray(none.cloud.points).tobytes() == np.ascontiguousarray(pts, np.float64).tobytes()
