"""zcut.fits, thirteenth round (docs/fits.md, "Thirteenth round"): a region whose whole fit is refused and whose
points span more than one instance can is split into lobes, each fitted (``FitParams.split_refused``,
``zcut.fits.fit._lobes``)."""

from __future__ import annotations

import numpy as np
import pytest
from fit_digests import DEFAULTS, DEFAULTS_REAL, digest, real_crop
from fit_scenes import K_TEST, hand_made_nut_frame, hex_nut_mesh, pose, render, rotation

import zcut.fits.fit as F
from zcut.errors import ParameterError
from zcut.fit_vetting import pose_overlaps
from zcut.fits import FitParams, fit_prepared, pose_error, prepare_model

SPLIT = FitParams(split_refused=0.75)

#: the twelfth round's fits (the previous tree, 846dad4, its defaults) of the hand-made nut frame
#: (``fit_scenes.hand_made_nut_frame``, ``fit_digests.hand_made("zinc_nuts")``)
TWELFTH_NUTS = DEFAULTS[("zinc_nuts", False)]


def test_without_the_split_the_nuts_fits_are_the_twelfth_rounds_to_the_bit():
    xyz, zone, model, K = hand_made_nut_frame()
    default = fit_prepared(xyz, zone, model, intrinsics=K)
    assert (len(default), digest(default)) == TWELFTH_NUTS  # off by default (docs/fits.md, "Thirteenth round")
    off = fit_prepared(xyz, zone, model, intrinsics=K, params=FitParams(split_refused=0.0))
    assert (len(off), digest(off)) == TWELFTH_NUTS
    on = fit_prepared(xyz, zone, model, intrinsics=K, params=SPLIT)
    assert digest(on) != TWELFTH_NUTS[1]
    # the split adds fits; every one is acceptable and no two share more than max_overlap of a solid
    assert len(on) >= len(default)
    assert all(f.err_mm <= SPLIT.max_err_mm and f.support >= SPLIT.min_support for f in on)
    poses = np.stack([f.pose for f in on])
    for i, f in enumerate(on):
        others = np.delete(poses, i, axis=0)
        near = np.linalg.norm(others[:, :3, 3] - f.pose[:3, 3], axis=1) < 2 * model.extent_mm  # type: ignore[attr-defined]
        if near.any():
            share = pose_overlaps(model.solid, np.broadcast_to(f.pose, (int(near.sum()), 4, 4)),  # type: ignore[attr-defined]
                                  others[near])
            assert (share <= SPLIT.max_overlap + 1e-12).all()


def _two_nuts(gap_mm: float, halves: bool = False) -> tuple[F._Frame, object, np.ndarray, np.ndarray, list[np.ndarray]]:
    """Two nuts side by side ``gap_mm`` apart, lying flat on a floor: the frame, the model, their pixels (one
    region), the id image and their poses; ``halves``: only a band across the halves facing each other measured
    (the rest NaN, as a dropout or the zone's border cuts them), a region no wider than 1.3 × the extent from its centroid (not
    fitted patch by patch: ``zcut.fits.fit._holds_many``)."""
    v, t = hex_nut_mesh()
    model = prepare_model(v, t)
    A = pose(rotation((1, 0, 0), 10), (-9.0 - gap_mm / 2, 0, 400))
    B = pose(rotation((0, 1, 0), -10) @ rotation((0, 0, 1), 17), (9.0 + gap_mm / 2, 0, 402))
    xyz, ids = render([(v, t, A), (v, t, B)], floor_z_mm=430)
    xyz = xyz + np.random.default_rng(3).normal(0, 0.03, xyz.shape)
    if halves:
        xyz[(np.abs(xyz[..., 0]) > 9.5) | (np.abs(xyz[..., 1]) > 6.0)] = np.nan
    valid = np.isfinite(xyz).all(axis=2)
    frame = F._Frame(xyz=xyz, valid=valid, zone=(ids > 0) & valid, K=K_TEST)
    return frame, model, np.flatnonzero(frame.zone.reshape(-1)), ids, [A, B]


@pytest.mark.parametrize("gap_mm", [0.0, 0.5])
def test_two_touching_nuts_split_into_one_lobe_each(gap_mm: float) -> None:
    frame, model, flat, ids, _ = _two_nuts(gap_mm)
    regions = F.segment(frame.xyz, flat, f_px=500.0, jump_mm=1.5, jump_px=3.0, min_px=40)
    assert len(regions) == 1  # the segmentation joins them
    lobes = F._lobes(frame, regions[0], model, SPLIT, 40)  # type: ignore[arg-type]
    assert len(lobes) == 2
    idf = ids.reshape(-1)
    owners = set()
    for lobe in lobes:
        counts = np.bincount(idf[lobe], minlength=3)
        assert counts.max() >= 0.95 * len(lobe)  # each lobe is (nearly) one nut's
        owners.add(int(np.argmax(counts)))
    assert owners == {1, 2}
    assert sum(len(x) for x in lobes) <= len(regions[0])
    # either nut alone spans less than twice the extent (a bound of every instance): not split at 1; at 0.75 a
    # whole nut seen from above is wide enough (0.89), so the split also cuts a single nut whose fit was refused
    bound = FitParams(split_refused=1.0)
    assert len(F._lobes(frame, regions[0], model, bound, 40)) == 2  # type: ignore[arg-type]
    for i in (1, 2):
        assert F._lobes(frame, flat[idf[flat] == i], model, bound, 40) == []  # type: ignore[arg-type]
    # the switch off never splits (the caller does not ask), a threshold above the span neither
    assert F._lobes(frame, regions[0], model, FitParams(split_refused=5.0), 40) == []  # type: ignore[arg-type]


def test_a_refused_region_of_two_nuts_is_fitted_lobe_by_lobe(monkeypatch: pytest.MonkeyPatch) -> None:
    """The region's whole fit refused (forced here: the first fit of the region fails), the split fits both nuts;
    without the split the region is abandoned."""
    frame, model, flat, _, truths = _two_nuts(0.0, halves=True)
    assert not F._holds_many(frame, flat, model)  # type: ignore[arg-type]
    real = F._candidates
    calls = {"n": 0}

    def refuse_first(frame_, flat, model_, params, shifts=0, claims=None):  # type: ignore[no-untyped-def]
        calls["n"] += 1
        if calls["n"] == 1:
            return [(np.eye(4), np.inf)]  # a refused whole fit
        return real(frame_, flat, model_, params, shifts=shifts, claims=claims)

    monkeypatch.setattr(F, "_candidates", refuse_first)
    p = FitParams(seed_shifts=0)  # the second pass would find them too: this tests the first
    off = fit_prepared(frame.xyz, frame.zone, model, intrinsics=K_TEST, params=p)  # type: ignore[arg-type]
    assert off == []
    calls["n"] = 0
    on = fit_prepared(frame.xyz, frame.zone, model, intrinsics=K_TEST,  # type: ignore[arg-type]
                      params=FitParams(seed_shifts=0, split_refused=0.75))
    assert calls["n"] >= 3  # the whole region refused, then its two lobes
    assert len(on) == 2
    for T in truths:
        assert min(pose_error(f.pose, T, model)[0] for f in on) < 0.5  # type: ignore[arg-type]


def test_degenerate_frames_give_no_fits_with_the_split():
    v, t = hex_nut_mesh()
    model = prepare_model(v, t)
    A = pose(rotation((1, 0, 0), 10), (0, 0, 400))
    xyz, ids = render([(v, t, A)], floor_z_mm=430)
    zone = ids == 1
    nan = np.full_like(xyz, np.nan)
    one = np.zeros_like(zone)
    one[120, 160] = True
    for x, z in ((xyz, np.zeros_like(zone)), (nan, zone), (xyz, one), (xyz[:0], zone[:0]), (xyz[:1, :1], zone[:1, :1])):
        assert fit_prepared(x, z, model, intrinsics=K_TEST, params=SPLIT) == []
    # a region of two pixels, or of one point repeated: no lobes
    frame = F._Frame(xyz=xyz, valid=np.isfinite(xyz).all(axis=2), zone=zone, K=K_TEST)
    flat = np.flatnonzero(zone.reshape(-1))
    assert F._lobes(frame, flat[:2], model, SPLIT, 40) == []
    assert F._lobes(frame, flat[:1], model, SPLIT, 40) == []
    same = xyz.copy()
    same[zone] = xyz[zone][0]
    frame1 = F._Frame(xyz=same, valid=frame.valid, zone=zone, K=K_TEST)
    assert F._lobes(frame1, flat, model, SPLIT, 40) == []
    # half the nut NaN (a dropout): still one fit, near the truth
    holed = xyz.copy()
    holed[:, : int(np.median(np.nonzero(zone)[1]))] = np.nan
    fits = fit_prepared(holed, zone, model, intrinsics=K_TEST, params=SPLIT)
    assert len(fits) == 1 and pose_error(fits[0].pose, A, model)[1] < 1.0


@pytest.mark.parametrize("value", [-0.5, "yes"])
def test_the_thirteenth_round_param_says_what_is_wrong(value: object) -> None:
    with pytest.raises(ParameterError, match="split_refused"):
        FitParams(split_refused=value)  # type: ignore[arg-type]


#: the twelfth round's fits (846dad4, its defaults) on ``fit_digests.real_crop``
TWELFTH_REAL = DEFAULTS_REAL


def test_a_real_cloud_without_the_split_is_the_twelfth_rounds_and_with_it_every_fit_acceptable(real_data):  # type: ignore[no-untyped-def]
    xyz, zone, model, _ = real_crop(real_data)
    off = fit_prepared(xyz, zone, model)  # type: ignore[arg-type]
    assert (len(off), digest(off)) == TWELFTH_REAL
    on = fit_prepared(xyz, zone, model, params=SPLIT)  # type: ignore[arg-type]
    assert len(on) >= len(off)
    assert all(f.err_mm <= SPLIT.max_err_mm and f.support >= SPLIT.min_support for f in on)
