"""zcut.removal: table, easy outliers and bin points on a ray-cast bin scene with known pose."""

from __future__ import annotations

import numpy as np
import pipeline_scene as ps
import pytest

from zcut.bin_model import BinModel
from zcut.binmask import bin_mask
from zcut.errors import InputShapeError, ParameterError
from zcut.params import RegistrationParams, RemovalParams
from zcut.registration import prepare_icp_model, prepare_target, register_bin
from zcut.removal import prepare_removal_index, remove_table_and_bin

H, W = 240, 320
SHIFT = ps.SHIFT
# the 240 x 320 filled bin, shifted, and the bin model it is registered to (tests/pipeline_scene.py)
filled = pytest.fixture(scope="module")(ps.filled_bin_scene)
model = pytest.fixture(scope="module")(ps.shifted_bin_model)


def _index(model, **mm):
    return prepare_removal_index(model, RemovalParams(**{"mode": "paper", "straggler_mm": 0.0,
                                                         "straggler_neighbours": 5, **mm}))


def test_removal_classes(filled, model):
    frame, truth = filled
    bm = bin_mask(frame.rgb)
    p = RegistrationParams(voxel_mm=1.0)
    reg = register_bin(prepare_icp_model(model, p),
                       prepare_target(frame.xyz[bm.walls].astype(np.float64), voxel_m=p.voxel_m))
    r = remove_table_and_bin(frame.xyz, bm.mask, index=_index(model, delta_mm=2.0, search_radius_mm=5.0),
                             T_cam_bin=reg.T_cam_bin)
    valid = np.isfinite(frame.xyz).all(axis=2)
    classes = [r.table, r.easy_outliers, r.bin_points, r.zone]
    assert sum(c.astype(int) for c in classes).max() == 1            # disjoint
    assert np.array_equal(r.table | r.easy_outliers | r.bin_points | r.zone, valid)
    assert np.array_equal(r.table, valid & ~bm.mask)
    bright = ps.bin_pixels(frame)
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
    r = remove_table_and_bin(xyz, bm.mask, index=_index(model, rim_offset_mm=5.0), T_cam_bin=np.eye(4))
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
    r = remove_table_and_bin(xyz, np.ones((5, 6), bool), index=_index(model), T_cam_bin=np.eye(4))
    assert not r.zone.any() and np.isnan(r.height_mm).all()


@pytest.mark.parametrize("kw, exc, match", [
    ({"footprint": np.ones((3, 3), bool)}, InputShapeError, "footprint"),
    ({"T_cam_bin": np.eye(4)}, ParameterError, "together"),
])
def test_removal_bad_arguments(kw, exc, match):
    args = {"footprint": np.ones((4, 4), bool)} | kw
    fp = args.pop("footprint")
    with pytest.raises(exc, match=match):
        remove_table_and_bin(np.zeros((4, 4, 3), np.float32), fp, **args)


@pytest.mark.parametrize("kw, match", [
    ({"delta_mm": -1.0}, r"RemovalParams\.delta_mm must be a number >= 0, got -1\.0"),
    ({"straggler_neighbours": 9}, r"RemovalParams\.straggler_neighbours"),
    ({"search_radius_mm": 0.0}, r"RemovalParams\.search_radius_mm"),
])
def test_removal_bad_parameters(kw, match):
    with pytest.raises(ParameterError, match=match):
        RemovalParams(**kw)


def test_bin_model_rejects_bad_points():
    with pytest.raises(InputShapeError, match="BinModel.points"):
        BinModel(np.zeros((3, 3), np.float32), None, 0.001)
    with pytest.raises(ParameterError, match="spacing_m"):
        BinModel(np.zeros((3, 3)), None, 0.0)


