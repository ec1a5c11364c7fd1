"""zcut.registration.Points, the arrays registration keeps of a cloud, and to_open3d, the Open3D cloud
built from them only where Open3D computes (docs/performance.md, "Open3D out of the replay")."""

from __future__ import annotations

import numpy as np
import pytest

from zcut.bin_model import BinModel
from zcut.errors import InputShapeError
from zcut.params import RegistrationParams
from zcut.registration import Points, prepare_icp_model, prepare_target, register_bin, to_open3d


def test_points_are_float64_c_order_without_a_copy_when_they_already_are() -> None:
    p = np.random.default_rng(3).normal(size=(50, 3))
    assert Points(p).points is p
    f = Points(np.asfortranarray(p.astype(np.float32)), np.asfortranarray(p))
    assert f.points.dtype == np.float64 and f.points.flags.c_contiguous and f.normals is not None
    assert f.normals.flags.c_contiguous and np.array_equal(f.normals, p)
    assert np.array_equal(f.points, p.astype(np.float32).astype(np.float64))


@pytest.mark.parametrize(("points", "normals", "match"), [
    (np.zeros((4, 2)), None, r"Points.points must be an \(N, 3\) float array, got .*\(4, 2\)"),
    (np.zeros(3), None, r"Points.points must be an \(N, 3\) float array"),
    (np.zeros((4, 3)), np.zeros((3, 3)), r"Points.normals must match points \(4, 3\), got .*\(3, 3\)"),
])
def test_bad_arrays_are_named(points: np.ndarray, normals: np.ndarray | None, match: str) -> None:
    with pytest.raises(InputShapeError, match=match):
        Points(points, normals)


@pytest.mark.parametrize("n", [0, 1, 40])
@pytest.mark.parametrize("with_normals", [False, True])
def test_has_normals_and_to_open3d_are_open3ds(n: int, with_normals: bool) -> None:
    rng = np.random.default_rng(n)
    p = rng.normal(size=(n, 3))
    nrm = rng.normal(size=(n, 3)) if with_normals else None
    cloud = Points(p, nrm)
    pc = to_open3d(cloud)
    assert cloud.has_normals() == pc.has_normals() == (with_normals and n > 0)
    assert len(cloud) == len(pc.points) == n
    assert np.asarray(pc.points).tobytes() == p.tobytes()
    if nrm is not None:
        assert np.asarray(pc.normals).tobytes() == nrm.tobytes()


def test_a_model_without_normals_gets_open3ds_and_both_icps_agree() -> None:
    """The fallback paths: normals estimated by Open3D for a model that has none, and the reference ICP
    (Open3D's, on clouds built from the arrays) giving the fast one's pose."""
    rng = np.random.default_rng(12)
    u, v = rng.uniform(-0.15, 0.15, size=(2, 6000))
    floor = np.stack([u, v, np.zeros_like(u)], axis=1)
    t = rng.uniform(-0.15, 0.15, size=3000)
    h = rng.uniform(-0.08, 0.0, size=3000)
    walls = np.concatenate([np.stack([t, np.full_like(t, 0.15), h], 1), np.stack([np.full_like(t, -0.15), t, h], 1),
                            np.stack([t, np.full_like(t, -0.15), h], 1), np.stack([np.full_like(t, 0.15), t, h], 1)])
    model = BinModel(np.concatenate([floor, walls]), None, 0.003)
    p = RegistrationParams(voxel_mm=3.0)
    icp = prepare_icp_model(model, p)
    assert icp.fine.normals is not None and icp.fine.has_normals() and icp.coarse.has_normals()
    assert np.allclose(np.linalg.norm(icp.fine.normals, axis=1), 1.0)
    T = np.eye(4)
    T[:3, 3] = (0.004, -0.003, 0.6)
    target = prepare_target(model.points @ T[:3, :3].T + T[:3, 3], voxel_m=p.voxel_m)
    fast = register_bin(icp, target, min_points=10)
    ref = register_bin(icp, target, min_points=10, reference=True)
    assert np.abs(fast.T_cam_bin - ref.T_cam_bin).max() <= 1e-12
    assert fast.icp_fitness == ref.icp_fitness and ref.iterations == (-1, -1)
    assert np.abs(fast.T_cam_bin[:3, 3] - T[:3, 3]).max() < 1e-3
