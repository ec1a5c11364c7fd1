"""zcut.registration: ICP of a prepared bin model on a ray-cast bin scene with known pose."""

from __future__ import annotations

import dataclasses

import numpy as np
import pipeline_scene as ps
import pytest

from zcut.binmask import bin_mask
from zcut.errors import InputShapeError, ParameterError
from zcut.params import RegistrationParams
from zcut.registration import (
    initial_guess,
    pose_fitness,
    prepare_icp_model,
    prepare_target,
    register_bin,
    transform_points,
)

H, W = 240, 320
SHIFT = (0.006, -0.004, 0.003)


@pytest.fixture(scope="module")
def filled():
    return ps.scene(h=H, w=W, shift=SHIFT, specks=12, seed=3)


@pytest.fixture(scope="module")
def model():
    from replay.pipeline.bin_model import build_bin_model
    from zcut.params import RegistrationParams

    frames = []
    for i, s in enumerate([(0, 0, 0), (0.02, 0, 0), (-0.02, 0, 0), (0, 0.02, 0), (0, -0.02, 0)]):
        f, _ = ps.scene(h=H, w=W, shift=s, parts=False)
        frames.append(dataclasses.replace(f, index=i))
    m, reports = build_bin_model(frames, registration=RegistrationParams(voxel_mm=1.0), voxel_mm=1.0)
    assert all(r.skipped == "" for r in reports)
    return m


def _bin_pixels(frame) -> np.ndarray:
    return (frame.rgb == np.array(ps.BRIGHT, np.uint8)).all(axis=2)


def _register(model, target, **params):
    p = RegistrationParams(**{"voxel_mm": 1.0, **params})
    return register_bin(prepare_icp_model(model, p), prepare_target(target, voxel_m=p.voxel_m))


def test_registration_recovers_the_known_pose(filled, model):
    frame, _ = filled
    bm = bin_mask(frame.rgb)
    target = frame.xyz[bm.walls].astype(np.float64)
    r = _register(model, target)
    assert r.converged and r.reason == ""
    assert r.fitness > 0.5
    assert r.inlier_rmse < 0.002
    # the model was built in the frame of the unshifted bin: T is the shift (pixel ~1.7 mm here)
    assert np.allclose(r.T_cam_bin[:3, 3], SHIFT, atol=0.002)
    assert np.allclose(r.T_cam_bin[:3, :3], np.eye(3), atol=0.02)
    # better than the initial guess, and the guess is a pure translation
    assert np.allclose(r.T_init[:3, :3], np.eye(3))


def test_registration_failure_is_reported(model):
    rng = np.random.default_rng(5)
    junk = rng.uniform(-1, 1, (500, 3)) + [0, 0, 3]
    r = _register(model, junk)
    assert not r.converged and "fitness" in r.reason
    few = _register(model, junk[:10], voxel_mm=0.0)
    assert not few.converged and "too few points" in few.reason and np.isnan(few.inlier_rmse)


def test_initial_guess_matches_tops_and_centres():
    m = np.array([[0, 0, 0.5], [0.2, 0.1, 0.5], [0.1, 0.05, 0.6]])
    t = m + [0.01, -0.02, 0.03]
    T = initial_guess(m, t)
    assert np.allclose(transform_points(T, m), t, atol=1e-3)


@pytest.mark.parametrize("kw, match", [
    ({"method": "magic"}, "RegistrationParams.method must be one of"),
    ({"max_correspondence_mm": 0.0}, "RegistrationParams.max_correspondence_mm must be a number > 0"),
    ({"voxel_mm": -1.0}, "RegistrationParams.voxel_mm"),
])
def test_registration_bad_parameters(kw, match):
    with pytest.raises(ParameterError, match=match):
        RegistrationParams(**kw)


def test_registration_bad_init_and_params(model):
    p = RegistrationParams(voxel_mm=1.0)
    icp, target = prepare_icp_model(model, p), prepare_target(model.points, voxel_m=p.voxel_m)
    with pytest.raises(InputShapeError, match="init"):
        register_bin(icp, target, init=np.eye(3))
    with pytest.raises(ParameterError, match="voxel and correspondence distance"):
        register_bin(icp, target, params=RegistrationParams(voxel_mm=2.0))
    with pytest.raises(InputShapeError, match="prepared with voxel"):
        register_bin(icp, prepare_target(model.points, voxel_m=0.002))


def test_registration_bad_points():
    from zcut.bin_model import BinModel

    with pytest.raises(InputShapeError, match="BinModel.points"):
        BinModel(np.zeros((4, 2)), None, 0.001)
    with pytest.raises(InputShapeError, match="target must be an"):
        prepare_target(np.zeros((4, 2)), voxel_m=0.001)


def test_pose_fitness_scores_a_pose_without_icp(filled, model):
    frame, _ = filled
    target = frame.xyz[bin_mask(frame.rgb).walls].astype(np.float64)
    p = RegistrationParams(voxel_mm=1.0)
    icp, tgt = prepare_icp_model(model, p), prepare_target(target, voxel_m=p.voxel_m)
    r = register_bin(icp, tgt)
    fine = 0.01 / 3.0
    at_pose = pose_fitness(icp, tgt, r.T_cam_bin, max_correspondence_m=fine)
    assert at_pose == pytest.approx(r.fitness, abs=0.02)
    moved = r.T_cam_bin.copy()
    moved[:3, 3] += [0.0, 0.0, 0.02]  # 2 cm deeper: the rim and walls no longer fit
    assert pose_fitness(icp, tgt, moved, max_correspondence_m=fine) < 0.5 * at_pose
    with pytest.raises(InputShapeError, match="T_cam_bin"):
        pose_fitness(icp, tgt, np.eye(3), max_correspondence_m=fine)


def test_pose_fitness_equals_open3d_evaluate_registration(filled, model):
    import open3d as o3d

    from zcut.registration import _cloud, _model_cloud

    frame, _ = filled
    target = frame.xyz[bin_mask(frame.rgb).walls].astype(np.float64)
    p = RegistrationParams(voxel_mm=1.0)
    icp, tgt = prepare_icp_model(model, p), prepare_target(target, voxel_m=p.voxel_m)
    r = register_bin(icp, tgt)
    src = _cloud(target[np.isfinite(target).all(axis=1)], 0.001)
    for shift_mm, dist in [(0.0, 0.01 / 3), (1.0, 0.01 / 3), (3.0, 0.002), (0.5, 0.01)]:
        T = r.T_cam_bin.copy()
        T[:3, 3] += [shift_mm / 1000.0, -shift_mm / 2000.0, shift_mm / 1000.0]
        dst = _model_cloud(model.points, model.normals, 0.001, max(0.003, 2.0 * dist / 3.0))
        want = o3d.pipelines.registration.evaluate_registration(src, dst, dist, np.linalg.inv(T)).fitness
        got = pose_fitness(icp, tgt, T, max_correspondence_m=dist)
        assert got == want and 0.0 < got
    empty = prepare_target(target[:0], voxel_m=p.voxel_m)
    assert pose_fitness(icp, empty, r.T_cam_bin, max_correspondence_m=0.01) == 0.0
