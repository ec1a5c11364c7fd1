"""zcut.fits with its defaults: the fits of the recorded frames to the bit (``fit_digests.DEFAULTS``,
``DEFAULTS_REAL``), degenerate frames, and the region's principal axes computed once a candidate (docs/fits.md,
"Fourteenth round").

Until 2026-12-06 each switch that was off by default (``slide``, ``split_refused``, ``skip_share``, ``coarse_keep``)
had its own copy of the digest check ("without the switch the fits are round N's"); with the switches removed they
are one check, this one."""

from __future__ import annotations

import numpy as np
import pytest
from fit_digests import DEFAULTS, DEFAULTS_REAL, degenerate_frames, digest, hand_made, hand_made_fits, holed, real_crop
from fit_scenes import K_TEST, hex_nut_mesh, pose, render, rotation
from prepared_models import prepared

from zcut.fits import fit_prepared, pose_error
from zcut.fits.icp import initial_rotations

#: a rod lying tilted, its axis (model x) about 40° off the image's rows
ROD = pose(rotation((0, 0, 1), 40) @ rotation((1, 0, 0), 20), (4, -2, 420))


@pytest.mark.parametrize("kind", ["zinc_nuts", "spheres", "rods", "black_nuts"])
def test_the_defaults_are_the_recorded_fits_to_the_bit(kind: str) -> None:
    xyz, zone, model, K = hand_made(kind)
    fits = list(hand_made_fits(kind))  # fit_prepared(xyz, zone, model, intrinsics=K), made once
    assert (len(fits), digest(fits)) == DEFAULTS[(kind, False)]
    fits = fit_prepared(holed(xyz), zone, model, intrinsics=K)  # type: ignore[arg-type]  # a third of it invalid
    assert (len(fits), digest(fits)) == DEFAULTS[(kind, True)]


def test_a_real_cloud_is_the_recorded_fits_to_the_bit(real_data):  # type: ignore[no-untyped-def]
    xyz, zone, model, _ = real_crop(real_data)
    fits = fit_prepared(xyz, zone, model)  # type: ignore[arg-type]
    assert (len(fits), digest(fits)) == DEFAULTS_REAL


def test_degenerate_frames_of_a_rod_give_no_fits() -> None:
    """A rod (the elongated part; a nut's: tests/zcut/fits/test_fits_pose.py) in the degenerate frames gives no fit;
    half of it NaN (a dropout) still one fit, near the truth."""
    from replay.synth.surfaces import kind_model_mesh

    v, t = kind_model_mesh("rods")
    model = prepared(v, t)
    xyz, ids = render([(v, t, ROD)], floor_z_mm=440)
    zone = ids == 1
    for x, z in degenerate_frames(xyz, zone):
        assert fit_prepared(x, z, model, intrinsics=K_TEST) == []
    half = xyz.copy()
    half[:, : int(np.median(np.nonzero(zone)[1]))] = np.nan
    fits = fit_prepared(half, zone, model, intrinsics=K_TEST)
    assert len(fits) == 1 and pose_error(fits[0].pose, ROD, model)[1] < 1.0


def test_initial_rotations_with_the_callers_axes_are_its_own_and_leave_them_alone(rng: np.random.Generator) -> None:
    v, t = hex_nut_mesh()
    model = prepared(v, t)
    for _ in range(20):
        pts = rng.normal(size=(int(rng.integers(3, 600)), 3)) * rng.uniform(0.1, 10.0, 3) + rng.uniform(-50, 50, 3)
        _, ax = np.linalg.eigh(np.cov((pts - pts.mean(axis=0)).T))
        kept = ax.copy()
        got = initial_rotations(pts, model, axes=ax)
        want = initial_rotations(pts, model)
        assert len(got) == len(want) and all(np.array_equal(a, b) for a, b in zip(got, want))
        assert np.array_equal(ax, kept)  # the caller's axes are not flipped in place
