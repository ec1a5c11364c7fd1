"""run_frame: every stage on one frame; the no-bin path equals the bare z-cut exactly (docs/formats.md)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pipeline_scene as ps
import pytest

from replay.pipeline.bin_model import build_bin_model
from replay.pipeline.config import PipelineConfig
from replay.pipeline.stages import STAGES, run_frame
from replay.pipeline.zone import sor_region
from zcut import sor_outliers
from zcut.cuts import zcut_outliers
from zcut.metrics import relative_metrics

H, W = 240, 320
SHIFT = (0.006, -0.004, 0.003)
LAYER = {"zcut": {"step_mm": 1.0, "max_depth_mm": 40.0, "max_area_px": 30.0},
         "removal": {"delta_mm": 2.0, "search_radius_mm": 5.0},
         "registration": {"voxel_mm": 1.0},
         "sor": {"region": "zone"}}


@pytest.fixture(scope="module")
def config() -> PipelineConfig:
    return ps.resolved_config(LAYER, (H, W))


@pytest.fixture(scope="module")
def model(config):
    frames = []
    for i, s in enumerate([(0, 0, 0), (0.02, 0, 0), (-0.02, 0, 0), (0, 0.02, 0), (0, -0.02, 0)]):
        f, _ = ps.scene(h=H, w=W, shift=s, parts=False)
        frames.append(dataclasses.replace(f, index=i))
    raw = build_bin_model(frames, bin_mask_params=config.bin_mask, registration=config.registration, voxel_mm=1.0)[0]
    return ps.prepared(raw, config)


@pytest.fixture(scope="module")
def filled():
    return ps.scene(h=H, w=W, shift=SHIFT, specks=12, seed=4)


def test_full_pipeline_on_a_known_scene(filled, model, config):
    frame, truth = filled
    r = run_frame(frame, config, bin_model=model)
    assert r.warnings == ()
    assert r.bin_mask is not None and r.registration is not None and r.registration.converged
    assert r.registration.fitness > 0.5 and r.registration.inlier_rmse < 0.002
    assert set(r.timings) == set(STAGES) | {"total"}
    # the z-cut finds the lifted specks on the parts, and nothing on the table or the bin
    assert r.zcut_outliers[truth].mean() >= 0.9
    assert not (r.zcut_outliers & (r.removal.table | r.removal.bin_points)).any()
    assert not (r.sor_outliers & ~r.zone).any()
    assert np.array_equal(r.cut.outliers & r.zone, r.zcut_outliers)  # no easy outliers here
    m = relative_metrics(r.sor_outliers & r.zone, r.zcut_outliers & r.zone)
    assert (m.n_both, m.n1, m.n2) == (r.metrics.n_both, r.metrics.n1, r.metrics.n2)
    # SOR judged the zone only: the same as SOR on the zone with everything else invalid
    zone_xyz = np.where(r.zone[..., None], frame.xyz, np.nan).astype(np.float32)
    assert np.array_equal(r.sor_outliers, sor_outliers(zone_xyz, k=4, std_ratio=1.0) & r.zone)


def test_easy_outliers_count_for_both_methods(model, config):
    frame, _ = ps.scene(h=H, w=W, shift=SHIFT)
    xyz = frame.xyz.copy()
    xyz[118:121, 158:161] *= np.float32(0.45 / 0.585)  # a 3x3 blob far above the rim
    r = run_frame(dataclasses.replace(frame, xyz=xyz), config, bin_model=model)
    easy = r.removal.easy_outliers
    assert easy[118:121, 158:161].all() and easy.sum() == 9
    assert (r.zcut_outliers & easy).sum() == 9 and (r.sor_outliers & easy).sum() == 9
    assert r.metrics.n_both + r.metrics.n1 + r.metrics.n2 == (r.zcut_outliers | r.sor_outliers).sum() - 9


@pytest.mark.parametrize("what", ["no_rgb", "no_model", "disabled"])
def test_without_bin_the_zcut_runs_on_the_whole_frame_exactly(filled, model, config, what):
    frame, _ = filled
    # add NaNs and a float32 grid: the equality must be exact, not approximate
    xyz = frame.xyz.copy()
    xyz[::7, ::5] = np.nan
    frame = dataclasses.replace(frame, xyz=xyz)
    if what == "no_rgb":
        frame, bm, c = dataclasses.replace(frame, rgb=None), model, config
    elif what == "no_model":
        bm, c = None, config
    else:
        bm, c = model, dataclasses.replace(config, bin_mask=dataclasses.replace(config.bin_mask, enabled=False))
    # the rim is the top of the whole frame: reach down to the parts
    c = dataclasses.replace(c, zcut=dataclasses.replace(c.zcut, max_depth=100.0))
    r = run_frame(frame, c, bin_model=bm)
    assert len(r.warnings) == 1 and "z-cut on the whole frame" in r.warnings[0]
    assert r.bin_mask is None and r.registration is None and r.removal is None
    z = c.zcut
    expected = zcut_outliers(-1000 * frame.xyz[..., 2].astype(np.float64), step=z.step,
                             max_depth=z.max_depth, max_area=z.max_area)
    assert expected.any()
    assert np.array_equal(r.zcut_outliers, expected)
    assert np.array_equal(r.sor_outliers, sor_outliers(frame.xyz, k=4, std_ratio=1.0))
    assert "bin_mask" not in r.timings and "zcut" in r.timings


def test_no_bin_in_the_image_is_a_warning(filled, model, config):
    frame, _ = filled
    dark = dataclasses.replace(frame, rgb=np.full_like(frame.rgb, 30))
    r = run_frame(dark, config, bin_model=model)
    assert r.bin_mask is None and "no bin found" in r.warnings[0]


def test_failed_registration_is_reported_and_only_the_table_removed(filled, model, config):
    frame, _ = filled
    xyz = frame.xyz.copy()
    xyz[:, : W // 2] = np.nan  # the left half of the bin is in view but not seen: its rim is not confirmed
    r = run_frame(dataclasses.replace(frame, xyz=xyz), config, bin_model=model)
    assert not r.registration.converged and "fitness" in r.registration.reason
    assert r.registration.fitness < config.registration.min_fitness
    assert any("registration failed" in w for w in r.warnings)
    assert not r.removal.bin_points.any() and r.removal.table.any()
    assert r.T_cam_bin is None


def test_the_first_frames_pose_seeds_the_registration(filled, model, config):
    frame, _ = filled
    first = run_frame(frame, config, bin_model=model)
    second = run_frame(frame, config, bin_model=model, seed=first.registration)
    assert np.array_equal(second.registration.T_init, first.registration.T_cam_bin)
    no_seed = dataclasses.replace(config, registration=dataclasses.replace(config.registration,
                                                                           seed_from_first_frame=False))
    third = run_frame(frame, no_seed, bin_model=model, seed=first.registration)
    assert np.array_equal(third.registration.T_init, first.registration.T_init)


def test_sor_can_be_disabled(filled, config):
    frame, _ = filled
    c = dataclasses.replace(config, sor=dataclasses.replace(config.sor, enabled=False))
    r = run_frame(frame, c)
    assert not r.sor_outliers.any() and any("SOR disabled" in w for w in r.warnings)


def test_all_nan_frame_gives_empty_masks(config):
    frame, _ = ps.scene(h=20, w=30)
    nan = dataclasses.replace(frame, xyz=np.full_like(frame.xyz, np.nan), rgb=None)
    r = run_frame(nan, config)
    assert not r.zcut_outliers.any() and not r.sor_outliers.any() and r.cut.n_clusters == 0


def test_sor_region_top_is_the_zcuts_depth_range(filled, model, config):
    frame, _ = filled
    top = dataclasses.replace(config, sor=dataclasses.replace(config.sor, region="top"),
                              zcut=dataclasses.replace(config.zcut, max_depth=10.0))
    r = run_frame(frame, top, bin_model=model)
    judged = sor_region(r.height_mm, r.zone, top.zcut)
    finite = np.isfinite(r.height_mm)
    assert judged.any() and (judged & ~r.zone).sum() == 0
    assert (r.height_mm[judged] >= r.height_mm[finite].max() - 10.0).all()
    assert (judged.sum() < r.zone.sum())
    zone_xyz = np.where(judged[..., None], frame.xyz, np.nan).astype(np.float32)
    assert np.array_equal(r.sor_outliers & ~r.easy_outliers, sor_outliers(zone_xyz, k=4, std_ratio=1.0) & judged)


def test_a_model_prepared_for_other_removal_parameters_is_refused(filled, model, config):
    from zcut.errors import ParameterError

    frame, _ = filled
    other = dataclasses.replace(config, removal=dataclasses.replace(config.removal, delta_mm=1.0))
    with pytest.raises(ParameterError, match="other removal parameters"):
        run_frame(frame, other, bin_model=model)


def test_a_moved_bin_is_registered_afresh(model, config):
    a, _ = ps.scene(h=H, w=W, shift=SHIFT)
    b, _ = ps.scene(h=H, w=W, shift=(SHIFT[0] + 0.03, SHIFT[1], SHIFT[2]))  # the bin moved 3 cm
    first = run_frame(a, config, bin_model=model)
    second = run_frame(b, config, bin_model=model, seed=first.registration)
    assert not np.array_equal(second.registration.T_init, first.registration.T_cam_bin)
    assert second.registration.converged
    assert second.registration.T_cam_bin[0, 3] == pytest.approx(SHIFT[0] + 0.03, abs=0.002)


@pytest.mark.parametrize("zone_kind", ["blob", "scattered", "corner", "empty"])
def test_sor_on_the_zone_bounding_box_equals_sor_on_the_masked_frame(zone_kind):
    from replay.pipeline.zone import _sor_on_zone

    rng = np.random.default_rng(8)
    h, w = 90, 120
    v, u = np.mgrid[0:h, 0:w]
    xyz = np.stack([(u - 60) * 0.001, (v - 45) * 0.001, 0.5 + rng.normal(0, 0.002, (h, w))], axis=2)
    xyz = xyz.astype(np.float32)
    xyz[rng.random((h, w)) < 0.03] = np.nan
    zone = np.zeros((h, w), bool)
    if zone_kind == "blob":
        zone[20:70, 30:100] = True
    elif zone_kind == "scattered":
        zone = rng.random((h, w)) < 0.4
    elif zone_kind == "corner":
        zone[h - 15:, w - 20:] = True
    zone &= np.isfinite(xyz).all(axis=2)
    got = _sor_on_zone(xyz, zone, whole=False, k=4, std_ratio=1.0, convention="pcl")
    want = sor_outliers(np.where(zone[..., None], xyz, np.nan).astype(np.float32), k=4, std_ratio=1.0) & zone
    assert np.array_equal(got, want)
    assert got.any() == (zone_kind != "empty")
