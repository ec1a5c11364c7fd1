"""zcut.registration: ICP of a prepared bin model on a ray-cast bin scene and on synthetic scans with
known pose; the bin fitness (the share of the model's rim the frame confirms)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pipeline_scene as ps
import pytest

from zcut.binmask import bin_mask, bin_pixels
from zcut.cloud import Intrinsics
from zcut.errors import InputShapeError, ParameterError
from zcut.params import RegistrationParams
from zcut.registration import (
    PIXEL_REACH,
    initial_guess,
    pose_fitness,
    prepare_icp_model,
    prepare_target,
    register_bin,
    rim_points,
    to_open3d,
    transform_points,
)

SHIFT = ps.SHIFT
# the 240 x 320 filled bin, shifted, and the bin model it is registered to (tests/pipeline_scene.py)
filled = pytest.fixture(scope="module")(ps.filled_bin_scene)
model = pytest.fixture(scope="module")(ps.shifted_bin_model)


def _register(model, target, **params):
    p = RegistrationParams(**{"voxel_mm": 1.0, **params})
    return register_bin(prepare_icp_model(model, p), prepare_target(target, voxel_m=p.voxel_m))


def test_registration_recovers_the_known_pose(filled, model):
    frame, _ = filled
    bm = bin_mask(frame.rgb)
    target = frame.xyz[bm.walls].astype(np.float64)
    r = _register(model, target)
    assert r.converged and r.reason == ""
    assert r.fitness >= 0.95 and r.n_rim > 100  # the bin fitness: the model's rim, confirmed
    assert r.icp_fitness > 0.5  # Open3D's (no bright part here: the target is all bin)
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
    assert not r.converged and "fitness" in r.reason and r.fitness < 0.1
    few = _register(model, junk[:10], voxel_mm=0.0)
    assert not few.converged and "too few points" in few.reason and np.isnan(few.inlier_rmse)
    assert few.fitness == few.icp_fitness == 0.0 and few.n_rim == 0


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


def test_coordinates_no_voxel_grid_can_hold_are_an_input_error():
    """Open3D throws a RuntimeError from C++ when the extent / voxel overflows its 32-bit voxel index
    (found by the fuzz suite: a cloud with coordinates near 3.4e38)."""
    from zcut.bin_model import BinModel

    huge = np.array([[0.0, 0.0, 1.0], [3.4e38, -3.4e38, 1.0], [1.0, 1.0, 1.0]])
    with pytest.raises(InputShapeError, match="the target spans 3.4e"):
        prepare_target(huge, voxel_m=0.003)
    with pytest.raises(InputShapeError, match="the bin model spans"):
        prepare_icp_model(BinModel(huge, None, 0.003), RegistrationParams())
    ok = prepare_target(np.random.default_rng(0).uniform(-0.3, 0.3, (500, 3)), voxel_m=0.003)
    assert 0 < len(ok.cloud.points) <= 500


def test_pose_fitness_scores_a_pose_without_icp(filled, model):
    frame, _ = filled
    target = frame.xyz[bin_mask(frame.rgb).walls].astype(np.float64)
    p = RegistrationParams(voxel_mm=1.0)
    icp, tgt = prepare_icp_model(model, p), prepare_target(target, voxel_m=p.voxel_m)
    r = register_bin(icp, tgt)
    fine = 0.01 / 3.0
    at_pose = pose_fitness(icp, tgt, r.T_cam_bin, max_correspondence_m=fine)
    assert at_pose == r.fitness >= 0.95
    moved = r.T_cam_bin.copy()
    moved[:3, 3] += [0.0, 0.0, 0.02]  # 2 cm deeper: the rim and walls no longer fit
    assert pose_fitness(icp, tgt, moved, max_correspondence_m=fine) < 0.5 * at_pose
    with pytest.raises(InputShapeError, match="T_cam_bin"):
        pose_fitness(icp, tgt, np.eye(3), max_correspondence_m=fine)


def _brute_force_fitness(rim: np.ndarray, T: np.ndarray, cloud: np.ndarray, dist: float,
                         K: Intrinsics | None) -> tuple[float, int]:
    """The bin fitness, literally: every rim point in view against every target point."""
    p = rim @ T[:3, :3].T + T[:3, 3]
    if K is not None:
        u = K.fx * p[:, 0] / p[:, 2] + K.cx
        v = K.fy * p[:, 1] / p[:, 2] + K.cy
        p = p[(p[:, 2] > 0) & (u >= -0.5) & (u < K.width - 0.5) & (v >= -0.5) & (v < K.height - 0.5)]
    if len(p) == 0:
        return 0.0, 0
    from scipy.spatial.distance import cdist

    reach = np.full(len(p), dist) if K is None else np.maximum(dist, PIXEL_REACH * p[:, 2] / min(K.fx, K.fy))
    d = cdist(p, cloud).min(axis=1)
    return float(np.count_nonzero(d <= reach)) / len(p), len(p)


def test_pose_fitness_equals_a_brute_force_count(filled, model):
    frame, _ = filled
    target = frame.xyz[bin_mask(frame.rgb).walls].astype(np.float64)
    p = RegistrationParams(voxel_mm=2.0)
    icp = prepare_icp_model(model, p)
    r = register_bin(icp, prepare_target(target, voxel_m=p.voxel_m))
    K = frame.intrinsics
    half = Intrinsics(fx=K.fx, fy=K.fy, cx=K.cx, cy=K.cy, width=K.width // 2, height=K.height)  # the left half
    fine = Intrinsics(fx=4 * K.fx, fy=4 * K.fy, cx=4 * K.cx, cy=4 * K.cy, width=4 * K.width, height=4 * K.height)
    for intrinsics in (None, K, half, fine):
        tgt = prepare_target(target, voxel_m=p.voxel_m, intrinsics=intrinsics)
        cloud = np.asarray(tgt.cloud.points)
        for shift_mm, dist in [(0.0, 0.01 / 3), (1.0, 0.01 / 3), (3.0, 0.002), (0.5, 0.01), (6.0, 0.004)]:
            T = r.T_cam_bin.copy()
            T[:3, 3] += [shift_mm / 1000.0, -shift_mm / 2000.0, shift_mm / 1000.0]
            want, n = _brute_force_fitness(icp.rim, T, cloud, dist, intrinsics)
            assert n > 0
            assert pose_fitness(icp, tgt, T, max_correspondence_m=dist) == want
    empty = prepare_target(target[:0], voxel_m=p.voxel_m)
    assert pose_fitness(icp, empty, r.T_cam_bin, max_correspondence_m=0.01) == 0.0
    behind = r.T_cam_bin.copy()
    behind[2, 3] -= 2.0  # the whole bin behind the camera: nothing in view
    assert pose_fitness(icp, prepare_target(target, voxel_m=p.voxel_m, intrinsics=K), behind,
                        max_correspondence_m=0.01) == 0.0


def test_a_coarse_camera_confirms_the_rim_within_its_pixel_footprint():
    from replay.pipeline.bin_model import build_bin_model

    # 160 px wide: a pixel is 3.5 mm on the rim, more than the fine distance (3.3 mm), and the rim
    # (8 mm) is two pixels wide; at the true pose, knowing the camera, the whole rim is confirmed
    h, w = 120, 160
    empty = [dataclasses.replace(ps.scene(h=h, w=w, shift=s, parts=False)[0], index=i)
             for i, s in enumerate([(0, 0, 0), (0.02, 0, 0), (-0.02, 0, 0)])]
    model = build_bin_model(empty, registration=RegistrationParams(voxel_mm=2.0), voxel_mm=2.0)[0]
    frame, _ = ps.scene(h=h, w=w, shift=SHIFT)
    T = np.eye(4)
    T[:3, 3] = SHIFT
    p = RegistrationParams(voxel_mm=2.0)
    icp = prepare_icp_model(model, p)
    pts = frame.xyz[bin_mask(frame.rgb).walls].astype(np.float64)
    dist = p.fine_correspondence_m
    with_camera = pose_fitness(icp, prepare_target(pts, voxel_m=p.voxel_m, intrinsics=frame.intrinsics), T,
                               max_correspondence_m=dist)
    blind = pose_fitness(icp, prepare_target(pts, voxel_m=p.voxel_m), T, max_correspondence_m=dist)
    assert with_camera >= 0.95 > blind
    assert (ps.RIM_Z + SHIFT[2]) / frame.intrinsics.fx > dist  # a pixel on the rim: indeed more than the distance


def test_icp_fitness_is_open3ds_at_the_final_pose(filled, model):
    import open3d as o3d

    frame, _ = filled
    target = frame.xyz[bin_mask(frame.rgb).walls].astype(np.float64)
    p = RegistrationParams(voxel_mm=1.0)
    icp, tgt = prepare_icp_model(model, p), prepare_target(target, voxel_m=p.voxel_m)
    r = register_bin(icp, tgt)
    want = o3d.pipelines.registration.evaluate_registration(to_open3d(tgt.cloud), to_open3d(icp.fine),
                                                            p.fine_correspondence_m,
                                                            np.linalg.inv(r.T_cam_bin))
    assert r.icp_fitness == pytest.approx(want.fitness, abs=1e-9)
    assert r.inlier_rmse == pytest.approx(want.inlier_rmse, rel=1e-6)


def test_rim_points_are_the_top_facing_up_and_follow_a_tilt(model):
    p = RegistrationParams(voxel_mm=1.0)
    icp = prepare_icp_model(model, p)
    rim, up = icp.rim, icp.up
    assert np.allclose(up, [0, 0, -1], atol=0.01)
    # the wall tops of the ray-cast bin: 8 mm wide at z = RIM_Z, nothing of the floor
    assert len(rim) > 100 and np.abs(rim[:, 2] - ps.RIM_Z).max() < 0.003
    hx, hy = ps.HALF
    inner = (np.abs(rim[:, 0]) < hx - ps.WALL - 0.002) & (np.abs(rim[:, 1]) < hy - ps.WALL - 0.002)
    assert not inner.any()
    # the same model seen by a camera tilted 10 degrees: the up direction and the rim follow it
    a = np.radians(10.0)
    R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    fine = np.asarray(icp.fine.points)
    normals = np.asarray(icp.fine.normals)
    rim_t, up_t = rim_points(fine @ R.T, -(normals @ R.T))  # normals of either sign
    assert np.allclose(up_t, R @ up, atol=0.01)
    assert abs(len(rim_t) - len(rim)) <= 0.02 * len(rim)


@pytest.mark.parametrize("args, kw, exc, match", [
    ((np.zeros((4, 2)), np.zeros((4, 2))), {}, InputShapeError, "points must be an"),
    ((np.zeros((4, 3)), np.zeros((3, 3))), {}, InputShapeError, "normals must match"),
    ((np.zeros((4, 3)), np.zeros((4, 3))), {"band_m": -0.001}, ParameterError, "band_m"),
    ((np.zeros((4, 3)), np.zeros((4, 3))), {"max_tilt_deg": 90.0}, ParameterError, "max_tilt_deg"),
])
def test_rim_points_bad_input(args, kw, exc, match):
    with pytest.raises(exc, match=match):
        rim_points(*args, **kw)


def test_prepare_target_bad_intrinsics():
    with pytest.raises(InputShapeError, match="intrinsics must be a zcut.cloud.Intrinsics"):
        prepare_target(np.zeros((4, 3)), voxel_m=0.0, intrinsics=np.eye(3))


# --- synthetic scans (replay.synth): shiny parts are as bright as the bin ---------------------------

SYNTH_SIZE = (300, 480)


@pytest.fixture(scope="module")
def synth_model():
    from replay.pipeline.bin_model import build_bin_model
    from replay.synth.synthesize import synthesize_frame

    empty = [synthesize_frame(empty=True, seed=7, index=i, size=SYNTH_SIZE).frame for i in range(5)]
    m, reports = build_bin_model(empty, voxel_mm=2.0)
    assert all(r.skipped == "" for r in reports)
    # scan-to-scan registrations are scored on the scan's rim too
    assert all(r.registration.fitness >= 0.95 for r in reports[1:])
    return prepare_icp_model(m, RegistrationParams(min_fitness=0.9))


@pytest.fixture(scope="module", params=["spheres", "black_nuts"])
def synth_frame(request):
    from replay.synth.synthesize import synthesize_frame

    return synthesize_frame(kind=request.param, seed=12, index=0, size=SYNTH_SIZE)


def _synth_target(sf, pixels: np.ndarray, params: RegistrationParams):
    f = sf.frame
    return prepare_target(f.xyz[pixels].astype(np.float64), voxel_m=params.voxel_m, intrinsics=f.intrinsics)


def _pose_error(T: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    centre = np.array([0.0, 0.0, 0.52])  # about the bin's centre, in the bin frame
    d = (T[:3, :3] @ centre + T[:3, 3]) - (T_true[:3, :3] @ centre + T_true[:3, 3])
    R = T_true[:3, :3].T @ T[:3, :3]
    return float(np.linalg.norm(d)) * 1000.0, float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


def test_bin_fitness_is_high_at_the_right_pose_on_shiny_and_matte_parts(synth_model, synth_frame):
    sf, icp = synth_frame, synth_model
    f = sf.frame
    bm = bin_mask(f.rgb)
    r = register_bin(icp, _synth_target(sf, bin_pixels(bm, f.xyz), icp.params))
    assert r.converged and r.reason == ""
    assert r.fitness >= 0.95 and r.icp_fitness >= 0.95
    mm, deg = _pose_error(r.T_cam_bin, sf.T_cam_bin)
    assert mm < 0.5 and deg < 0.05
    # the whole bright component as target: the same pose, the same bin fitness; Open3D's fitness
    # falls with the shiny parts in it (what `fitness` used to report)
    walls = bm.walls & np.isfinite(f.xyz).all(axis=2)
    old = register_bin(icp, _synth_target(sf, walls, icp.params))
    assert old.fitness >= 0.95 and _pose_error(old.T_cam_bin, sf.T_cam_bin)[0] < 0.5
    if sf.shiny:
        assert old.icp_fitness < 0.8
    else:
        assert old.icp_fitness >= 0.95


def _wrong_start(T: np.ndarray, shift_m: float = 0.05, turn_deg: float = 20.0) -> np.ndarray:
    c, s = np.cos(np.radians(turn_deg)), np.sin(np.radians(turn_deg))
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    out = T.copy()
    out[:3, :3] = R @ T[:3, :3]
    out[:3, 3] = R @ T[:3, 3] + [shift_m, 0.0, 0.0]
    return out


def test_a_wrong_pose_has_a_low_fitness_and_is_not_converged(synth_model, synth_frame):
    sf, icp = synth_frame, synth_model
    f = sf.frame
    tgt = _synth_target(sf, bin_pixels(bin_mask(f.rgb), f.xyz), icp.params)
    start = _wrong_start(sf.T_cam_bin)
    assert pose_fitness(icp, tgt, start, max_correspondence_m=icp.params.fine_correspondence_m) < 0.3
    # the fine pass alone (a previous frame's pose on a bin that moved) cannot get back from 5 cm, 20°
    r = register_bin(icp, tgt, init=start, coarse=False)
    assert _pose_error(r.T_cam_bin, sf.T_cam_bin)[0] > 20.0
    assert not r.converged and r.fitness < 0.6
    assert "fitness" in r.reason and "rim" in r.reason
    assert r.n_rim > 0.5 * len(icp.rim)


def test_only_the_rim_in_view_is_scored(synth_model):
    from replay.synth.synthesize import synthesize_frame

    icp = synth_model
    sf = synthesize_frame(kind="black_nuts", seed=12, index=0, size=SYNTH_SIZE)
    f = sf.frame
    K = f.intrinsics
    w = K.width // 2
    # the left half of the image: a camera that sees half the bin
    half = Intrinsics(fx=K.fx, fy=K.fy, cx=K.cx, cy=K.cy, width=w, height=K.height)
    pixels = bin_pixels(bin_mask(f.rgb), f.xyz)[:, :w]
    pts = f.xyz[:, :w][pixels].astype(np.float64)
    seen = prepare_target(pts, voxel_m=icp.params.voxel_m, intrinsics=half)
    blind = prepare_target(pts, voxel_m=icp.params.voxel_m)
    dist = icp.params.fine_correspondence_m
    assert pose_fitness(icp, seen, sf.T_cam_bin, max_correspondence_m=dist) >= 0.95
    assert pose_fitness(icp, blind, sf.T_cam_bin, max_correspondence_m=dist) < 0.7
