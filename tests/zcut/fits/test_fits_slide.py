"""zcut.fits, twelfth round (docs/fits.md, "Twelfth round"): an elongated part's pose slid along its axis to where
it explains the most zone pixels (``FitParams.slide``, ``zcut.fits.fit._slide``)."""

from __future__ import annotations

import numpy as np
import pytest
from fit_digests import DEFAULTS, digest, hand_made
from fit_scenes import K_TEST, hand_made_nut_frame, hex_nut_mesh, pose, render, rotation

import zcut.fits.fit as F
from zcut.errors import ParameterError
from zcut.fits import FitParams, fit_prepared, pose_error, prepare_model

#: a rod lying tilted, its axis (model x) about 40° off the image's rows
ROD = pose(rotation((0, 0, 1), 40) @ rotation((1, 0, 0), 20), (4, -2, 420))
SLIDE = FitParams(slide=True)


def _rod_mesh() -> tuple[np.ndarray, np.ndarray]:
    from replay.synth.surfaces import kind_model_mesh

    return kind_model_mesh("rods")


#: the eleventh round's fits (the previous tree, e7420cc, its defaults) of the hand-made rod frame
ELEVENTH_RODS = DEFAULTS[("rods", False)]


def test_without_the_slide_the_rods_fits_are_the_eleventh_rounds_to_the_bit():
    xyz, zone, model, K = hand_made("rods")
    old = fit_prepared(xyz, zone, model, intrinsics=K, params=FitParams(slide=False))
    assert (len(old), digest(old)) == ELEVENTH_RODS
    default = fit_prepared(xyz, zone, model, intrinsics=K)
    assert (len(default), digest(default)) == ELEVENTH_RODS  # off by default (docs/fits.md, "Twelfth round")
    new = fit_prepared(xyz, zone, model, intrinsics=K, params=SLIDE)
    assert digest(new) != ELEVENTH_RODS[1]
    assert all(f.err_mm <= FitParams().max_err_mm and f.support >= 0.5 for f in new)


def test_the_slide_leaves_a_nuts_fits_alone():
    """A nut is not elongated: no slide, the same fits to the bit with it on or off."""
    xyz, zone, model, K = hand_made_nut_frame()
    assert F._slide_axis(model) is None  # type: ignore[arg-type]
    on = fit_prepared(xyz, zone, model, intrinsics=K, params=SLIDE)
    off = fit_prepared(xyz, zone, model, intrinsics=K, params=FitParams(slide=False))
    assert (len(on), digest(on)) == (len(off), digest(off))


def _rod_frame(seed: int) -> tuple[F._Frame, object, np.ndarray]:
    v, t = _rod_mesh()
    model = prepare_model(v, t)
    xyz, ids = render([(v, t, ROD)], floor_z_mm=440)
    xyz = xyz + np.random.default_rng(seed).normal(0, 0.03, xyz.shape)
    valid = np.isfinite(xyz).all(axis=2)
    frame = F._Frame(xyz=xyz, valid=valid, zone=(ids == 1) & valid, K=K_TEST)
    return frame, model, np.flatnonzero(frame.zone.reshape(-1))


@pytest.mark.parametrize("shift_mm", [-25.0, -12.0, 9.0, 30.0])
def test_a_rod_fit_slid_along_its_axis_comes_back_to_the_rod(shift_mm: float) -> None:
    """The fit of a piece of a rod (a third of its pixels, as a crossing rod cuts a region), its pose right but slid
    along the axis: the slide brings it back within half a millimetre; the pose it starts from is that far off."""
    frame, model, flat = _rod_frame(2)
    axis = F._slide_axis(model)  # type: ignore[arg-type]
    assert axis is not None
    u = axis[0]
    T0 = ROD.copy()
    T0[:3, 3] = ROD[:3, 3] + ROD[:3, :3] @ (shift_mm * u)
    cols = flat % frame.xyz.shape[1]
    region = flat[cols <= np.percentile(cols, 33)]
    pts = frame.xyz.reshape(-1, 3)[region]
    opts = dict(gate_mm=4.0, k=3.0, floor_mm=0.1, edge_gate_mm=1.0)
    T, err = F._slide(frame, region, pts, np.zeros((0, 3)), model, SLIDE, opts, T0, 0.05)  # type: ignore[arg-type]
    assert pose_error(T0, ROD, model)[0] > abs(shift_mm) - 0.5  # type: ignore[arg-type]
    assert pose_error(T, ROD, model)[0] < 0.5 and np.isfinite(err)  # type: ignore[arg-type]
    # at its place already: unchanged
    T1, e1 = F._slide(frame, region, pts, np.zeros((0, 3)), model, SLIDE, opts, T, err)  # type: ignore[arg-type]
    assert T1 is T and e1 == err


def test_two_crossing_rods_are_each_fitted_in_place():
    """A rod lying across another cuts it into two pieces: each rod's fit lies within a millimetre of it."""
    v, t = _rod_mesh()
    model = prepare_model(v, t)
    below = pose(rotation((0, 0, 1), -35), (0, 0, 436))
    xyz, ids = render([(v, t, ROD), (v, t, below)], floor_z_mm=460)
    xyz = xyz + np.random.default_rng(5).normal(0, 0.03, xyz.shape)
    zone = ids > 0
    fits = fit_prepared(xyz, zone, model, intrinsics=K_TEST, params=SLIDE)
    for T in (ROD, below):
        assert min(pose_error(f.pose, T, model)[0] for f in fits) < 1.0


def test_degenerate_frames_give_no_fits_with_the_slide():
    v, t = _rod_mesh()
    model = prepare_model(v, t)
    xyz, ids = render([(v, t, ROD)], floor_z_mm=440)
    zone = ids == 1
    nan = np.full_like(xyz, np.nan)
    one = np.zeros_like(zone)
    one[120, 160] = True
    for x, z in ((xyz, np.zeros_like(zone)), (nan, zone), (xyz, one), (xyz[:0], zone[:0]), (xyz[:1, :1], zone[:1, :1])):
        assert fit_prepared(x, z, model, intrinsics=K_TEST, params=SLIDE) == []
    # half the rod NaN (a dropout): still one fit, near the truth
    holed = xyz.copy()
    holed[:, : int(np.median(np.nonzero(zone)[1]))] = np.nan
    fits = fit_prepared(holed, zone, model, intrinsics=K_TEST, params=SLIDE)
    assert len(fits) == 1 and pose_error(fits[0].pose, ROD, model)[1] < 1.0


def test_the_slide_axis_is_the_rods_and_no_other_parts():
    v, t = _rod_mesh()
    axis = F._slide_axis(prepare_model(v, t))
    assert axis is not None
    u, radial, lo, hi = axis
    assert abs(abs(u[int(np.argmax(np.abs(u)))]) - 1.0) < 1e-9 and hi - lo > 2 * F.SLIDE_ELONGATION * radial / 2
    assert F._slide_axis(prepare_model(*hex_nut_mesh())) is None


@pytest.mark.parametrize("value", ["yes", 1.5])
def test_the_twelfth_round_param_says_what_is_wrong(value: object) -> None:
    with pytest.raises(ParameterError, match="slide"):
        FitParams(slide=value)  # type: ignore[arg-type]
