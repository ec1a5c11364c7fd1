"""zcut.fits, fourteenth round (docs/fits.md, "Fourteenth round"): the region's principal axes computed once a
candidate (the fits unchanged to the bit), and a small flat region not fitted (``FitParams.skip_share``, off by
default: ``zcut.fits.fit._flat_patch``)."""

from __future__ import annotations

import numpy as np
import pytest
from fit_digests import DEFAULTS, DEFAULTS_REAL, digest, hand_made, holed, real_crop
from fit_scenes import K_TEST, hex_nut_mesh, pose, render, rotation

import zcut.fits.fit as F
from zcut.errors import ParameterError
from zcut.fits import FitParams, fit_prepared, prepare_model
from zcut.fits.icp import initial_rotations


@pytest.mark.parametrize("kind", ["zinc_nuts", "spheres", "rods", "black_nuts"])
def test_the_defaults_are_the_thirteenth_rounds_fits_to_the_bit(kind: str) -> None:
    xyz, zone, model, K = hand_made(kind)
    fits = fit_prepared(xyz, zone, model, intrinsics=K)  # type: ignore[arg-type]
    assert (len(fits), digest(fits)) == DEFAULTS[(kind, False)]
    fits = fit_prepared(holed(xyz), zone, model, intrinsics=K)  # type: ignore[arg-type]  # a third of it invalid
    assert (len(fits), digest(fits)) == DEFAULTS[(kind, True)]


def test_a_real_cloud_is_the_thirteenth_rounds_to_the_bit(real_data):  # type: ignore[no-untyped-def]
    xyz, zone, model, _ = real_crop(real_data)
    fits = fit_prepared(xyz, zone, model)  # type: ignore[arg-type]
    assert (len(fits), digest(fits)) == DEFAULTS_REAL


def test_initial_rotations_with_the_callers_axes_are_its_own_and_leave_them_alone(rng: np.random.Generator) -> None:
    v, t = hex_nut_mesh()
    model = prepare_model(v, t)
    for _ in range(20):
        pts = rng.normal(size=(int(rng.integers(3, 600)), 3)) * rng.uniform(0.1, 10.0, 3) + rng.uniform(-50, 50, 3)
        _, ax = np.linalg.eigh(np.cov((pts - pts.mean(axis=0)).T))
        kept = ax.copy()
        got = initial_rotations(pts, model, axes=ax)
        want = initial_rotations(pts, model)
        assert len(got) == len(want) and all(np.array_equal(a, b) for a, b in zip(got, want))
        assert np.array_equal(ax, kept)  # the caller's axes are not flipped in place


def _patch_frame(rows: int, cols: int, ridge_mm: float = 0.0) -> tuple[F._Frame, np.ndarray]:
    """A frame of K_TEST whose zone is one rows × cols patch of a plane at 400 mm (every other row raised by
    ``ridge_mm``), and its pixels."""
    H, W = 240, 320
    fx, fy, cx, cy = K_TEST
    rr, cc = np.mgrid[0:H, 0:W]
    z = np.full((H, W), 400.0) + np.where(rr % 2 == 1, ridge_mm, 0.0)
    xyz = np.stack([(cc - cx) / fx * z, (rr - cy) / fy * z, z], axis=-1)
    zone = np.zeros((H, W), bool)
    zone[100:100 + rows, 150:150 + cols] = True
    frame = F._Frame(xyz=xyz, valid=np.ones((H, W), bool), zone=zone, K=K_TEST)
    return frame, np.flatnonzero(zone.reshape(-1))


def test_a_flat_patch_is_skipped_only_when_small_and_flat() -> None:
    v, t = hex_nut_mesh()
    model = prepare_model(v, t)
    p = FitParams(skip_share=0.1, skip_plane_mm=0.15)
    frame, flat = _patch_frame(7, 7)  # 49 px against 0.1 x the nut's ~670 px disc at 400 mm
    area = F._projected_area(frame, flat, model)
    assert 49 < 0.1 * area < 100
    assert F._flat_patch(frame, flat, model, p)
    frame, flat = _patch_frame(10, 10)  # larger than the share: fitted
    assert not F._flat_patch(frame, flat, model, p)
    frame, flat = _patch_frame(7, 7, ridge_mm=0.5)  # a ridge 0.25 mm RMS off the plane: fitted
    assert not F._flat_patch(frame, flat, model, p)
    frame, flat = _patch_frame(7, 7, ridge_mm=0.2)  # 0.1 mm RMS: flat at 0.15
    assert F._flat_patch(frame, flat, model, p)
    assert not F._flat_patch(frame, flat, model, FitParams(skip_share=0.1, skip_plane_mm=0.05))


def test_the_skip_leaves_a_nut_and_drops_a_floor_patch(monkeypatch: pytest.MonkeyPatch) -> None:
    """A nut and a small patch of the floor beside it in the zone: without the skip the patch is fitted, with it the
    patch is never fitted; the nut's fit is the same."""
    v, t = hex_nut_mesh()
    model = prepare_model(v, t)
    A = pose(rotation((1, 0, 0), 10), (0, 0, 400))
    xyz, ids = render([(v, t, A)], floor_z_mm=430)
    zone = ids == 1
    zone[20:27, 20:27] = True  # 49 px of the floor, far from the nut
    patch = set(np.flatnonzero((ids == 0).reshape(-1) & zone.reshape(-1)).tolist())
    seen: list[bool] = []
    real = F._candidates

    def record(frame, flat, model_, params, shifts=0, claims=None):  # type: ignore[no-untyped-def]
        seen.append(bool(patch & set(flat.tolist())))
        return real(frame, flat, model_, params, shifts=shifts, claims=claims)

    monkeypatch.setattr(F, "_candidates", record)
    off = fit_prepared(xyz, zone, model, intrinsics=K_TEST)
    assert any(seen)
    seen.clear()
    on = fit_prepared(xyz, zone, model, intrinsics=K_TEST, params=FitParams(skip_share=0.1))
    assert seen and not any(seen)
    # without the skip the patch is even accepted (a nut posed on the floor: a fit on no instance); with it only
    # the nut's fit is left, the same
    nut = [f for f in off if not patch & set(f.pixels.tolist())]
    assert len(off) == 2 and len(nut) == 1
    assert len(on) == 1 and np.array_equal(on[0].pose, nut[0].pose)


def test_degenerate_frames_give_no_fits_with_the_skip() -> None:
    v, t = hex_nut_mesh()
    model = prepare_model(v, t)
    xyz, ids = render([(v, t, pose(rotation((1, 0, 0), 10), (0, 0, 400)))], floor_z_mm=430)
    zone = ids == 1
    nan = np.full_like(xyz, np.nan)
    one = np.zeros_like(zone)
    one[120, 160] = True
    p = FitParams(skip_share=0.5)
    for x, z in ((xyz, np.zeros_like(zone)), (nan, zone), (xyz, one), (xyz[:0], zone[:0]), (xyz[:1, :1], zone[:1, :1])):
        assert fit_prepared(x, z, model, intrinsics=K_TEST, params=p) == []
    # one point repeated: no plane, skipped
    frame = F._Frame(xyz=np.where(zone[..., None], xyz[zone][0], xyz), valid=np.isfinite(xyz).all(axis=2), zone=zone,
                     K=K_TEST)
    assert F._flat_patch(frame, np.flatnonzero(zone.reshape(-1))[:2], model, p)


@pytest.mark.parametrize(("field", "value"), [("skip_share", -0.1), ("skip_share", 1.5), ("skip_share", "yes"),
                                              ("skip_plane_mm", -1.0)])
def test_the_fourteenth_round_params_say_what_is_wrong(field: str, value: object) -> None:
    with pytest.raises(ParameterError, match=field):
        FitParams(**{field: value})  # type: ignore[arg-type]
