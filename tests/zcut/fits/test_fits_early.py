"""zcut.fits, tenth round (docs/fits.md, "Tenth round"): a candidate whose coarse pose already loses to a fit it
overlaps is refused before its fine ICP and last refinement (``FitParams.early_share``); 0 gives the ninth round's
fits to the bit."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
from fit_digests import degenerate_frames
from fit_scenes import K_TEST, hand_made_nut_frame, hex_nut_mesh, pose, render, rotation

import zcut.fits.fit as F
from zcut.errors import ParameterError
from zcut.fits import FitParams, PartFit, fit_prepared, prepare_model

NUT = pose(rotation((1, 0.3, 0), 25) @ rotation((0, 0, 1), 20), (0, 0, 300))


def _nut_scene() -> tuple[np.ndarray, np.ndarray]:
    v, t = hex_nut_mesh()
    xyz, ids = render([(v, t, NUT)], floor_z_mm=330)
    xyz = xyz + np.random.default_rng(10).normal(0, 0.05, xyz.shape)
    return xyz, ids == 1


def _frame(xyz: np.ndarray, zone: np.ndarray) -> F._Frame:
    valid = np.isfinite(xyz).all(axis=2)
    return F._Frame(xyz=xyz, valid=valid, zone=zone & valid, K=K_TEST)


def _claims_of(model, params: FitParams, xyz: np.ndarray, fit: PartFit) -> F._Claims:  # type: ignore[no-untyped-def]
    claims = F._Claims(model, params, xyz.shape[0] * xyz.shape[1])
    claims.add(fit.pose, fit.err_mm, (fit.pixels, np.zeros(len(fit.pixels))))
    return claims


def test_a_candidate_that_clearly_loses_to_a_fit_it_overlaps_is_refused_early():
    """The nut is fitted; a candidate posed 2 mm off it (overlapping it) on 30 of its pixels explains fewer than
    ``early_share`` of the fit's pixels: refused. On all its pixels, or posed where no fit is, it is not."""
    v, t = hex_nut_mesh()
    model = prepare_model(v, t)
    xyz, zone = _nut_scene()
    params = FitParams(early_share=0.1)  # the share the tenth round measured (off by default)
    fits = fit_prepared(xyz, zone, model, intrinsics=K_TEST, params=params)
    assert len(fits) == 1
    frame = _frame(xyz, zone)
    claims = _claims_of(model, params, xyz, fits[0])
    flat = np.flatnonzero(frame.zone.reshape(-1))
    off = NUT.copy()
    off[:3, 3] += (2.0, 0.0, 0.0)
    tol = 1.0
    assert F._loses_early(frame, flat[:30], model, params, off, claims, tol)
    assert not F._loses_early(frame, flat, model, params, NUT, claims, tol)  # explains as much: not a clear loss
    far = NUT.copy()
    far[:3, 3] += (60.0, 0.0, 0.0)
    assert not F._loses_early(frame, flat[:30], model, params, far, claims, tol)  # no overlap: no rival
    assert not F._loses_early(frame, flat[:30], model, FitParams(early_share=0.01), off, claims, tol)


def test_an_early_refusal_spends_no_fine_icp(monkeypatch):  # type: ignore[no-untyped-def]
    """A region whose candidate loses early: Err inf, and no ICP after the coarse search (the fine ICP and the
    last refinement are the only calls of ``icp`` for a model with a voxel index)."""
    v, t = hex_nut_mesh()
    model = prepare_model(v, t)
    xyz, zone = _nut_scene()
    params = FitParams(early_share=0.1)  # on (off by default)
    fit = fit_prepared(xyz, zone, model, intrinsics=K_TEST, params=params)[0]
    frame = _frame(xyz, zone)
    claims = _claims_of(model, params, xyz, fit)
    flat = np.flatnonzero(frame.zone.reshape(-1))
    calls = []
    real = F.icp
    monkeypatch.setattr(F, "icp", lambda *a, **k: calls.append(1) or real(*a, **k))
    T, err = F._fit_general(frame, flat[:60], model, params, claims=claims)
    assert err == np.inf and not calls
    T, err = F._fit_general(frame, flat, model, params, claims=None)  # no claims: refined as before
    assert np.isfinite(err) and calls


def _digest(fits: list[PartFit]) -> str:
    return hashlib.sha256(b"".join(f.pose.tobytes() + f.pixels.tobytes() for f in fits)).hexdigest()[:16]


#: the ninth round's fits (the previous tree, 849b5ca, its defaults) of a hand-made zinc-nut frame, seed 5,
#: 480 × 300: (number of fits, sha256 of their poses and pixels)
NINTH = (237, "4dbc0d09d81ceaae")


def test_early_share_zero_gives_the_ninth_rounds_fits_to_the_bit():
    xyz, zone, model, K = hand_made_nut_frame()
    fits = fit_prepared(xyz, zone, model, intrinsics=K,
                        params=FitParams(early_share=0.0, fine_window=False, fine_robust=0.0))
    assert (len(fits), _digest(fits)) == NINTH  # the eleventh round's last refinement off (docs/fits.md)


def test_the_early_refusal_leaves_degenerate_frames_alone():
    v, t = hex_nut_mesh()
    model = prepare_model(v, t)
    xyz, zone = _nut_scene()
    for x, z in degenerate_frames(xyz, zone):
        assert fit_prepared(x, z, model, intrinsics=K_TEST, params=FitParams(early_share=0.1)) == []


def test_the_early_share_says_what_is_wrong():
    with pytest.raises(ParameterError, match="early_share"):
        FitParams(early_share=-0.1)
    assert FitParams().early_share == 0.0
