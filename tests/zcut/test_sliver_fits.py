"""zcut.sliver_fits: a sliver of a known mesh at a known pose is found and posed; the free-space constraint
rejects a fit in front of what the camera saw; degenerate inputs give no fit."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "fits"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import sliver_scene  # noqa: E402
from fit_scenes import K_TEST, pose, render, rotation  # noqa: E402
from sliver_scene import FLOOR_Z, occluded_scene, true_pose  # noqa: E402

from zcut.errors import InputShapeError  # noqa: E402
from zcut.fits import pose_error  # noqa: E402
from zcut.sliver_fits import SliverParams, fit_slivers, see_through_share  # noqa: E402


@pytest.fixture(scope="module")
def nut():  # type: ignore[no-untyped-def]
    return sliver_scene.nut()


def test_a_sliver_of_a_known_pose_is_found_and_posed(nut) -> None:  # type: ignore[no-untyped-def]
    _, _, model = nut
    T = true_pose()
    xyz, sliver, whole = occluded_scene(nut, 0.7)
    assert 30 <= sliver.sum() <= 0.5 * whole.sum()
    H, W = sliver.shape
    # a neighbour fitted elsewhere in the same resting orientation, turned by a few degrees about the view
    neighbour = pose(rotation((0.0, 0.0, 1.0), 4.0) @ T[:3, :3], (-40.0, -20.0, 380.0))
    got = fit_slivers(xyz, np.isfinite(xyz).all(axis=2), sliver, model, neighbour[None], sigma_mm=0.05,
                      params=SliverParams(min_px=20))
    assert len(got) == 1
    f = got[0]
    assert f.share >= 0.95 and f.err_mm < 0.1 and f.see_through <= 0.05
    assert set(f.pixels.tolist()) <= set(np.flatnonzero(sliver).tolist())
    # posed: the model at the found pose explains the sliver's points and stands where the nut stands
    p = xyz[sliver]
    assert model.distance((p - f.pose[:3, 3]) @ f.pose[:3, :3]).max() < 0.3
    t_err, r_err = pose_error(f.pose, T, model)
    assert t_err < 1.0 and r_err < 2.0


def test_free_space_rejects_a_fit_in_front_of_what_the_camera_saw(nut) -> None:  # type: ignore[no-untyped-def]
    v, t, model = nut
    T = true_pose()
    xyz_part, ids = render([(v, t, T)], floor_z_mm=FLOOR_Z)
    # a patch of the nut's face floating in front of the floor, the rest of the nut absent: the camera saw the
    # floor where the nut's body would be
    xyz, _ = render([], floor_z_mm=FLOOR_Z)
    rows, cols = np.nonzero(ids == 1)
    r0, c0 = int(np.median(rows)), int(np.median(cols))
    patch = np.zeros(ids.shape, bool)
    patch[r0 - 5:r0 + 5, c0 - 5:c0 + 5] = True
    patch &= ids == 1
    xyz[patch] = xyz_part[patch]
    neighbour = pose(T[:3, :3], (-40.0, -20.0, 380.0))
    valid = np.isfinite(xyz).all(axis=2)
    params = SliverParams(min_px=20, min_share=0.9)
    assert fit_slivers(xyz, valid, patch, model, neighbour[None], sigma_mm=0.05, params=params) == []
    # the same without the constraint: a pose is found (the constraint is what rejects it)
    loose = SliverParams(min_px=20, min_share=0.9, max_see_through=1.0)
    got = fit_slivers(xyz, valid, patch, model, neighbour[None], sigma_mm=0.05, params=loose)
    assert len(got) == 1 and got[0].see_through > 0.05
    st, sil = see_through_share(xyz, valid, model, got[0].pose, intrinsics=K_TEST, sigma_mm=0.05)
    assert sil > patch.sum() and st == pytest.approx(got[0].see_through, abs=1e-3)


def test_a_part_behind_an_occluder_is_not_seen_through(nut) -> None:  # type: ignore[no-untyped-def]
    _, _, model = nut
    T = true_pose()
    xyz, _, _ = occluded_scene(nut, 1.5)  # wholly hidden: every ray stops at the box first
    valid = np.isfinite(xyz).all(axis=2)
    st, sil = see_through_share(xyz, valid, model, T, intrinsics=K_TEST, sigma_mm=0.05)
    assert sil > 0 and st == 0.0
    xyz, _ = render([], floor_z_mm=FLOOR_Z)  # absent: the floor is seen through all of it
    st, _ = see_through_share(xyz, valid, model, T, intrinsics=K_TEST, sigma_mm=0.05)
    assert st == 1.0


@pytest.mark.parametrize("shape", [(0, 0), (1, 1), (1, 40), (30, 40)])
def test_degenerate_inputs_give_no_fit(nut, shape: tuple[int, int]) -> None:  # type: ignore[no-untyped-def]
    _, _, model = nut
    pose = true_pose()[None]
    nan = np.full((*shape, 3), np.nan)
    everything = np.ones(shape, bool)
    assert fit_slivers(nan, everything, everything, model, pose, sigma_mm=0.05) == []  # all-NaN
    xyz = np.zeros((*shape, 3))
    if shape[0] * shape[1]:
        xyz[..., 2] = 400.0
        one = np.zeros(shape, bool)
        one.flat[0] = True
        assert fit_slivers(xyz, everything, one, model, pose, sigma_mm=0.05) == []  # one pixel
    assert fit_slivers(xyz, everything, np.zeros(shape, bool), model, pose, sigma_mm=0.05) == []  # nothing unexplained
    assert fit_slivers(xyz, everything, everything, model, np.zeros((0, 4, 4)), sigma_mm=0.05) == []  # no fits


@pytest.mark.parametrize(("kwargs", "match"), [({"min_px": 0}, "min_px"), ({"max_residual": 0.0}, "max_residual"),
                                               ({"min_share": 1.5}, "min_share"), ({"k": -1.0}, "k")])
def test_bad_params_are_one_line(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        SliverParams(**kwargs)


def test_bad_shapes_are_one_line(nut) -> None:  # type: ignore[no-untyped-def]
    _, _, model = nut
    with pytest.raises(InputShapeError, match="fit_slivers"):
        fit_slivers(np.zeros((4, 5, 2)), np.ones((4, 5), bool), np.ones((4, 5), bool), model, true_pose()[None],
                    sigma_mm=0.05)


def test_a_pose_inside_a_fitted_instance_is_refused(nut) -> None:  # type: ignore[no-untyped-def]
    _, _, model = nut
    T = true_pose()
    xyz, sliver, _ = occluded_scene(nut, 0.7)
    valid = np.isfinite(xyz).all(axis=2)
    # the nut is fitted already (its pose among the frame's fits): its sliver's pose would lie inside it
    assert fit_slivers(xyz, valid, sliver, model, T[None], sigma_mm=0.05, params=SliverParams(min_px=20)) == []
    loose = SliverParams(min_px=20, max_overlap=1.0)
    assert len(fit_slivers(xyz, valid, sliver, model, T[None], sigma_mm=0.05, params=loose)) == 1
