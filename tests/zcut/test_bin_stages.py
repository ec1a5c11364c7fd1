"""The pure bin stages on a ray-cast bin scene with known geometry and pose."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import pipeline_scene as ps
from replay.pipeline.bin_model import build_bin_model, model_from_points
from replay.pipeline.config import PipelineConfig, from_dict
from zcut.binmask import bin_mask, fill_holes
from zcut.errors import InputShapeError, ParameterError
from zcut.registration import initial_guess, register_bin, transform_points
from zcut.removal import BinModel, remove_table_and_bin

H, W = 240, 320
SHIFT = (0.006, -0.004, 0.003)


@pytest.fixture(scope="module")
def filled():
    return ps.scene(h=H, w=W, shift=SHIFT, specks=12, seed=3)


@pytest.fixture(scope="module")
def model() -> BinModel:
    frames = []
    for i, s in enumerate([(0, 0, 0), (0.02, 0, 0), (-0.02, 0, 0), (0, 0.02, 0), (0, -0.02, 0)]):
        f, _ = ps.scene(h=H, w=W, shift=s, parts=False)
        frames.append(dataclasses.replace(f, index=i))
    config = from_dict({"registration": {"voxel_mm": 1.0}})
    m, reports = build_bin_model(frames, config, voxel_mm=1.0)
    assert all(r.skipped == "" for r in reports)
    return m


def _bin_pixels(frame) -> np.ndarray:
    return (frame.rgb == np.array(ps.BRIGHT, np.uint8)).all(axis=2)


# ----------------------------------------------------------------------------------- bin mask

def test_bin_mask_is_the_bin_footprint(filled):
    frame, _ = filled
    r = bin_mask(frame.rgb)
    truth_walls = _bin_pixels(frame)
    inside = truth_walls | (frame.rgb == np.array(ps.PART, np.uint8)).all(axis=2)
    assert r.found and r.covers_centre
    assert r.mask[inside].all()                       # every bin or part pixel is in the footprint
    table = (frame.rgb == np.array(ps.DARK, np.uint8)).all(axis=2)
    assert (r.mask & table).sum() == 0  # the closing leaves no fringe of table
    assert r.walls[truth_walls].mean() > 0.99 and not (r.walls & ~truth_walls).any()
    assert r.area_px == r.mask.sum()
    y0, x0, y1, x1 = r.bbox_rc
    assert r.mask[y0:y1, x0:x1].sum() == r.area_px


def test_bin_mask_prefers_the_centre_over_a_larger_component():
    rgb = np.zeros((100, 200, 3), np.uint8)
    rgb[:, :60] = 230          # a large bright thing at the left edge (6000 px)
    rgb[30:70, 80:120] = 230   # a bin ring around the centre (1600 px outer) ...
    rgb[35:65, 85:115] = 10    # ... with a dark inside
    r = bin_mask(rgb, dilate_px=0)
    assert r.covers_centre and r.mask[50, 100] and not r.mask[:, :60].any()
    assert r.area_px == 40 * 40
    r2 = bin_mask(rgb, dilate_px=0, prefer_centre=False)
    assert r2.mask[:, :60].all() and not r2.mask[50, 100]


def test_bin_mask_without_a_bin_is_empty():
    r = bin_mask(np.full((20, 30, 3), 20, np.uint8))
    assert not r.found and not r.mask.any() and r.area_px == 0 and np.isnan(r.centroid_rc[0])


def test_fill_holes_fills_only_enclosed_background():
    m = np.zeros((7, 7), bool)
    m[1:6, 1:6] = True
    m[3, 3] = False
    m[0:3, 2] = False  # a notch open to the border is not a hole
    f = fill_holes(m)
    assert f[3, 3] and not f[1, 2] and not f[2, 2]
    assert np.array_equal(f, m | (np.arange(7)[:, None] == 3) & (np.arange(7)[None] == 3))


@pytest.mark.parametrize("kw, match", [
    ({"threshold": 300}, "threshold"),
    ({"dilate_px": -1}, "dilate_px"),
    ({"min_area_frac": 2.0}, "min_area_frac"),
])
def test_bin_mask_bad_parameters(kw, match):
    with pytest.raises(ParameterError, match=match):
        bin_mask(np.zeros((4, 4, 3), np.uint8), **kw)


@pytest.mark.parametrize("rgb", [np.zeros((4, 4), np.uint8), np.zeros((4, 4, 3), np.float32)])
def test_bin_mask_bad_image(rgb):
    with pytest.raises(InputShapeError, match="rgb must be"):
        bin_mask(rgb)


# ----------------------------------------------------------------------------------- registration

def test_registration_recovers_the_known_pose(filled, model):
    frame, _ = filled
    bm = bin_mask(frame.rgb)
    target = frame.xyz[bm.walls].astype(np.float64)
    r = register_bin(model.points, target, voxel_m=0.001)
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
    r = register_bin(model.points, junk, voxel_m=0.001)
    assert not r.converged and "fitness" in r.reason
    few = register_bin(model.points, junk[:10], voxel_m=0.0)
    assert not few.converged and "too few points" in few.reason and np.isnan(few.inlier_rmse)


def test_initial_guess_matches_tops_and_centres():
    m = np.array([[0, 0, 0.5], [0.2, 0.1, 0.5], [0.1, 0.05, 0.6]])
    t = m + [0.01, -0.02, 0.03]
    T = initial_guess(m, t)
    assert np.allclose(transform_points(T, m), t, atol=1e-3)


@pytest.mark.parametrize("kw, match", [
    ({"method": "magic"}, "method"),
    ({"max_correspondence_m": 0.0}, "max_correspondence_m"),
    ({"init": np.eye(3)}, "init"),
])
def test_registration_bad_parameters(model, kw, match):
    with pytest.raises((ParameterError, InputShapeError), match=match):
        register_bin(model.points, model.points, **kw)


def test_registration_bad_points():
    with pytest.raises(InputShapeError, match="model must be an"):
        register_bin(np.zeros((4, 2)), np.zeros((4, 3)))


# ----------------------------------------------------------------------------------- removal

def test_removal_classes(filled, model):
    frame, truth = filled
    bm = bin_mask(frame.rgb)
    reg = register_bin(model.points, frame.xyz[bm.walls].astype(np.float64), voxel_m=0.001)
    r = remove_table_and_bin(frame.xyz, bm.mask, model=model, T_cam_bin=reg.T_cam_bin,
                             delta_m=0.002, search_radius_m=0.005)
    valid = np.isfinite(frame.xyz).all(axis=2)
    classes = [r.table, r.easy_outliers, r.bin_points, r.zone]
    assert sum(c.astype(int) for c in classes).max() == 1            # disjoint
    assert np.array_equal(r.table | r.easy_outliers | r.bin_points | r.zone, valid)
    assert np.array_equal(r.table, valid & ~bm.mask)
    bright = _bin_pixels(frame)
    assert (r.bin_points | r.table)[bright].mean() > 0.95             # the bin is gone
    parts = (frame.rgb == np.array(ps.PART, np.uint8)).all(axis=2)
    part_tops = parts & (frame.xyz[..., 2] < ps.FLOOR_Z + SHIFT[2] - 0.005)
    assert r.zone[part_tops & ~truth].mean() > 0.99                   # parts stay
    assert r.zone[truth].all()                                        # specks stay for the z-cut
    # the rim and floor of the registered bin, along up = -z
    assert r.rim_m == pytest.approx(-(ps.RIM_Z + SHIFT[2]), abs=0.003)
    assert r.floor_m == pytest.approx(-(ps.FLOOR_Z + SHIFT[2]), abs=0.003)
    # labelled pixels keep their place on the grid with z at the floor
    lab = r.labelled
    assert np.allclose(r.xyz[lab][:, 2], ps.FLOOR_Z + SHIFT[2], atol=0.003)
    assert np.array_equal(r.xyz[lab][:, :2], frame.xyz[lab][:, :2])
    assert np.array_equal(r.height_mm[r.zone], -1000.0 * frame.xyz[r.zone][:, 2].astype(np.float64))


def test_points_above_the_rim_are_easy_outliers(model):
    frame, _ = ps.scene(h=H, w=W)
    xyz = frame.xyz.copy()
    xyz[120, 160] *= np.float32(0.45 / xyz[120, 160, 2])   # 5 cm above the rim at 0.5 m
    xyz[121, 161] *= np.float32(0.497 / xyz[121, 161, 2])  # 3 mm above: within the offset
    bm = bin_mask(frame.rgb)
    r = remove_table_and_bin(xyz, bm.mask, model=model, T_cam_bin=np.eye(4), rim_offset_m=0.005)
    assert r.easy_outliers[120, 160] and not r.easy_outliers[121, 161]
    assert r.easy_outliers.sum() == 1


def test_removal_without_model_removes_only_the_table(filled):
    frame, _ = filled
    bm = bin_mask(frame.rgb)
    r = remove_table_and_bin(frame.xyz, bm.mask)
    valid = np.isfinite(frame.xyz).all(axis=2)
    assert not r.bin_points.any() and not r.easy_outliers.any()
    assert np.array_equal(r.zone, valid & bm.mask)
    assert np.isnan(r.rim_m)


def test_removal_with_nan_and_empty_inputs(model):
    xyz = np.full((5, 6, 3), np.nan, np.float32)
    r = remove_table_and_bin(xyz, np.ones((5, 6), bool), model=model, T_cam_bin=np.eye(4))
    assert not r.zone.any() and np.isnan(r.height_mm).all()


@pytest.mark.parametrize("kw, exc, match", [
    ({"footprint": np.ones((3, 3), bool)}, InputShapeError, "footprint"),
    ({"delta_m": -1.0}, ParameterError, "delta_m"),
    ({"T_cam_bin": np.eye(4)}, ParameterError, "together"),
])
def test_removal_bad_arguments(kw, exc, match):
    args = {"footprint": np.ones((4, 4), bool)} | kw
    fp = args.pop("footprint")
    with pytest.raises(exc, match=match):
        remove_table_and_bin(np.zeros((4, 4, 3), np.float32), fp, **args)


def test_bin_model_rejects_bad_points():
    with pytest.raises(InputShapeError, match="BinModel.points"):
        BinModel(np.zeros((3, 3), np.float32), None, 0.001)
    with pytest.raises(ParameterError, match="spacing_m"):
        BinModel(np.zeros((3, 3)), None, 0.0)


def test_model_from_points_downsamples_with_normals():
    rng = np.random.default_rng(1)
    pts = np.c_[rng.uniform(-0.05, 0.05, (5000, 2)), np.full(5000, 0.5)]
    m = model_from_points(pts, voxel_mm=5.0)
    assert 100 <= len(m.points) <= 600
    assert np.allclose(np.abs(m.normals[:, 2]), 1.0, atol=1e-6)
    assert (m.normals[:, 2] < 0).all()  # oriented towards the camera at the origin
    assert isinstance(PipelineConfig().registration.voxel_mm, float)


def test_pose_fitness_scores_a_pose_without_icp(filled, model):
    from zcut.registration import pose_fitness

    frame, _ = filled
    target = frame.xyz[bin_mask(frame.rgb).walls].astype(np.float64)
    r = register_bin(model.points, target, model_normals=model.normals, voxel_m=0.001)
    fine = 0.01 / 3.0
    at_pose = pose_fitness(model.points, target, r.T_cam_bin, model_normals=model.normals, voxel_m=0.001,
                           max_correspondence_m=fine)
    assert at_pose == pytest.approx(r.fitness, abs=0.02)
    moved = r.T_cam_bin.copy()
    moved[:3, 3] += [0.0, 0.0, 0.02]  # 2 cm deeper: the rim and walls no longer fit
    assert pose_fitness(model.points, target, moved, model_normals=model.normals, voxel_m=0.001,
                        max_correspondence_m=fine) < 0.5 * at_pose
    with pytest.raises(InputShapeError, match="T_cam_bin"):
        pose_fitness(model.points, target, np.eye(3))


def test_pose_fitness_equals_open3d_evaluate_registration(filled, model):
    import open3d as o3d

    from zcut.registration import _cloud, _model_cloud, pose_fitness

    frame, _ = filled
    target = frame.xyz[bin_mask(frame.rgb).walls].astype(np.float64)
    r = register_bin(model.points, target, model_normals=model.normals, voxel_m=0.001)
    src = _cloud(target[np.isfinite(target).all(axis=1)], 0.001)
    for shift_mm, dist in [(0.0, 0.01 / 3), (1.0, 0.01 / 3), (3.0, 0.002), (0.5, 0.01)]:
        T = r.T_cam_bin.copy()
        T[:3, 3] += [shift_mm / 1000.0, -shift_mm / 2000.0, shift_mm / 1000.0]
        dst = _model_cloud(model.points, model.normals, 0.001, max(0.003, 2.0 * dist / 3.0))
        want = o3d.pipelines.registration.evaluate_registration(src, dst, dist, np.linalg.inv(T)).fitness
        got = pose_fitness(model.points, target, T, model_normals=model.normals, voxel_m=0.001,
                           max_correspondence_m=dist)
        assert got == want and 0.0 < got
    assert pose_fitness(model.points, target[:0], r.T_cam_bin, voxel_m=0.001) == 0.0
