"""Bad input to the bin stages: the frame is still replayed, its bin check flags it, with a reason
that says what to do, and the replay table counts it (issue 19)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pipeline_scene as ps
import pytest

from replay.pipeline.bin_model import build_bin_model
from replay.pipeline.session import FrameRow
from replay.pipeline.stages import run_frame
from zcut.bin_model import BinModel

H, W = 240, 320
SHIFT = (0.006, -0.004, 0.003)
LAYER = {"zcut": {"step_mm": 1.0, "max_depth_mm": 40.0, "max_area_px": 30.0},
         "registration": {"voxel_mm": 1.0}}


@pytest.fixture(scope="module")
def config():
    return ps.resolved_config(LAYER, (H, W))


@pytest.fixture(scope="module")
def raw_model(config) -> BinModel:
    frames = []
    for i, s in enumerate([(0, 0, 0), (0.02, 0, 0), (-0.02, 0, 0), (0, 0.02, 0), (0, -0.02, 0)]):
        f, _ = ps.scene(h=H, w=W, shift=s, parts=False)
        frames.append(dataclasses.replace(f, index=i))
    return build_bin_model(frames, bin_mask_params=config.bin_mask, registration=config.registration, voxel_mm=1.0)[0]


@pytest.fixture(scope="module")
def filled():
    frame, _ = ps.scene(h=H, w=W, shift=SHIFT, specks=8, seed=4)
    return dataclasses.replace(frame, index=7)


def replayed(frame, config, model):
    """The result and its table row; the frame was replayed whatever happened to the bin stages."""
    r = run_frame(frame, config, bin_model=None if model is None else ps.prepared(model, config))
    row = FrameRow.of(r)
    assert r.zcut_outliers.shape == (frame.xyz.shape[0], frame.xyz.shape[1]) and row.index == frame.index
    return r, row


def test_a_good_frame_is_not_flagged(filled, config, raw_model):
    r, row = replayed(filled, config, raw_model)
    assert r.bin_check is not None and not r.bin_check.flagged and r.bin_check.value == 0
    assert row.bin_check == 0.0 and row.bin_flagged is False
    assert row.as_dict()["bin_check"] == 0.0 and row.as_dict()["bin_flagged"] is False


def test_a_frame_without_bin_stages_has_no_check(filled, config, raw_model):
    r, row = replayed(dataclasses.replace(filled, rgb=None), config, raw_model)
    assert r.bin_check is None and not r.bin_flagged
    assert math.isnan(row.bin_check) and row.bin_flagged is False and row.as_dict()["bin_check"] is None


def test_a_model_of_another_bin(filled, config, raw_model):
    centre = raw_model.points.mean(axis=0)
    bigger = BinModel(centre + 1.3 * (raw_model.points - centre), raw_model.normals, raw_model.spacing_m)
    r, row = replayed(filled, config, bigger)
    assert r.bin_flagged and row.bin_flagged
    assert "bin model" in r.bin_check.reason  # what to do: the model is not of this bin


def test_an_empty_model(filled, config):
    r, row = replayed(filled, config, BinModel(np.zeros((0, 3)), None, 0.001))
    assert not r.registration.converged and "too few points" in r.registration.reason
    assert r.bin_flagged and math.isnan(row.bin_check) and row.bin_flagged
    assert "registration failed" in r.bin_check.reason and "zcut bin-model" in r.bin_check.reason


def test_a_registration_that_does_not_converge(filled, config, raw_model):
    xyz = filled.xyz.copy()
    xyz[:, : W // 2] = np.nan  # half the bin's rim in view is not seen: the fitness stays low
    r, row = replayed(dataclasses.replace(filled, xyz=xyz), config, raw_model)
    assert not r.registration.converged
    assert r.bin_flagged and row.bin_flagged and math.isnan(row.bin_check)
    assert r.bin_check.reason.startswith("the bin registration failed (fitness")


def test_most_of_the_bin_occluded(filled, config, raw_model):
    """A dark arm over most of the bin, 10 cm above the rim."""
    xyz, rgb = filled.xyz.copy(), filled.rgb.copy()
    arm = np.zeros((H, W), bool)
    arm[:, W // 5:] = True
    xyz[arm] *= np.float32(0.40) / xyz[arm][:, 2:]
    rgb[arm] = (35, 35, 40)
    r, row = replayed(dataclasses.replace(filled, xyz=xyz, rgb=rgb), config, raw_model)
    assert r.bin_flagged and row.bin_flagged
    assert any(w in r.bin_check.reason for w in ("registration failed", "bin stages failed", "in view"))


def test_most_of_the_bin_out_of_view(filled, config, raw_model):
    """The camera sees a corner of the bin only: the image cut to its top-left quarter."""
    h, w = H // 2 + 10, W // 2 + 10
    K = dataclasses.replace(filled.intrinsics, width=w, height=h)
    cut = dataclasses.replace(filled, xyz=np.ascontiguousarray(filled.xyz[:h, :w]),
                              rgb=np.ascontiguousarray(filled.rgb[:h, :w]), intrinsics=K,
                              masks={k: v[:h, :w] for k, v in filled.masks.items()})
    r, row = replayed(cut, config, raw_model)
    assert r.bin_flagged and row.bin_flagged
    # registered on the corner it sees: less than half the model's rim is in view; or not registered at all
    assert "of the bin's rim in the camera's view" in r.bin_check.reason or "registration failed" in r.bin_check.reason


def test_no_bin_in_the_image_with_a_model(filled, config, raw_model):
    r, row = replayed(dataclasses.replace(filled, rgb=np.full_like(filled.rgb, 30)), config, raw_model)
    assert r.bin_mask is None and r.bin_flagged and row.bin_flagged and math.isnan(row.bin_check)
    assert "no bin found in the RGB image" in r.bin_check.reason and "bin_mask parameters" in r.bin_check.reason


def test_a_pose_off_by_millimetres_is_flagged_in_the_paper_mode_only(filled, config, raw_model):
    from replay.pipeline.stages import locate_bin

    for mode, flagged in (("paper", True), ("robust", False)):
        c = dataclasses.replace(config, removal=dataclasses.replace(config.removal, mode=mode))
        model = ps.prepared(raw_model, c)
        located = locate_bin(filled, c, bin_model=model)
        T = located.registration.T_cam_bin.copy()
        T[:3, 3] += (0.0015, 0.0, 0.001)
        located = dataclasses.replace(located, registration=dataclasses.replace(located.registration, T_cam_bin=T))
        r = run_frame(filled, c, bin_model=model, located=located)
        assert r.bin_flagged is flagged, (mode, r.bin_check)
