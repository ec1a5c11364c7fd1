"""``explained`` with its fits searching the zone without the pixels the straggler bound gave back to it
(:data:`replay.pipeline.explained.FITS_WITHOUT_PUT_BACK`, :func:`replay.pipeline.explained.fit_region`; docs/labelling.md,
"Tenth round").

A hand-made frame (spheres, 300 × 480) whose inner-wall stragglers are moved beyond the straggler bound, its zone as
the pipeline makes it with the defaults and with ``[removal] straggler_bound = "off"`` (the oracle of the given-back
pixels). Off by default: the method as before, bit for bit.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import replay.pipeline.explained as pe
from replay.options import PipelineOptions
from replay.pipeline.stages import bin_zone

pytestmark = pytest.mark.slow
H, W = 300, 480
KIND, SEED = "spheres", 31


def _moved(xyz, T, model, picks, dist_m):
    """``xyz`` with each pick moved along its ray to ``dist_m`` from the tangent plane of its nearest model point,
    towards the camera (as tests/zcut/test_removal_straggler_bound.py moves them)."""
    from scipy.spatial import cKDTree

    out = xyz.copy()
    R, t = T[:3, :3], T[:3, 3]
    tree = cKDTree(model.points)
    camera = (-t) @ R
    for (r, c), d in zip(picks, dist_m, strict=True):
        p = xyz[r, c].astype(np.float64)
        ray = p / np.linalg.norm(p)
        q = (p - t) @ R
        _, j = tree.query(q)
        n, m = model.normals[j], model.points[j]
        side = 1.0 if n @ (camera - m) >= 0 else -1.0
        step = (side * d - n @ (q - m)) / (n @ (ray @ R))
        out[r, c] = (p + step * ray).astype(np.float32)
    return out


@pytest.fixture(scope="module")
def prepared(tmp_path_factory):
    """(session, frame, zone, zone with the bound off, pipeline result): a hand-made spheres frame (300 × 480, seed
    31: the pile covers the bin floor) with every 9th inner-wall pixel moved beyond the straggler bound (as
    tests/zcut/test_removal_straggler_bound.py moves them), so that the default bound gives some back to the zone."""
    from replay.synth.log import write_synthetic_log
    from replay.synth.scene import LABEL_WALL
    from replay.synth.synthesize import synthesize_frame
    from zcut.removal import frame_tolerance, prepare_removal_index, straggler_bound_m

    log = write_synthetic_log(tmp_path_factory.mktemp("putback") / "s.mcap", kind=KIND, frames=1, seed=SEED,
                              size=(H, W))
    session = PipelineOptions(methods="zcut,explained").open_session(log)
    frame0, _ = next(iter(session.results()))
    assert session.prepared is not None and session.config.bank[pe.NAME].part_model
    z0 = bin_zone(frame0, session.config, bin_model=session.prepared)
    assert z0.removal is not None and z0.located.registration is not None
    T, model = z0.located.registration.T_cam_bin, session.prepared.model
    wall = (synthesize_frame(kind=KIND, seed=SEED, index=0, size=(H, W)).surface == LABEL_WALL) & z0.removal.bin_points
    inner = wall.copy()
    for dr in range(-3, 4):
        for dc in range(-3, 4):
            inner &= np.roll(np.roll(wall, dr, axis=0), dc, axis=1)
    grid = np.zeros((H, W), bool)
    grid[5::9, 5::9] = True
    picks = np.argwhere(inner & grid)
    p = session.config.removal
    tol = frame_tolerance(frame0.xyz, z0.located.ring, prepare_removal_index(model, p), T)
    tau = tol.tolerance_mm / 1000.0
    z = frame0.xyz[picks[:, 0], picks[:, 1], 2].astype(np.float64)
    bound = straggler_bound_m(z, tol.sigma_mm / 1000.0, tol.pixel_rad, tau + p.straggler_m)
    frame = dataclasses.replace(frame0, xyz=_moved(frame0.xyz, T, model, picks, 0.5 * (bound + tau + p.straggler_m)))
    zone = bin_zone(frame, session.config, bin_model=session.prepared, located=z0.located)
    off = dataclasses.replace(session.config, removal=dataclasses.replace(p, straggler_bound="off"))
    from zcut.prepared_model import prepare_bin_model

    zone_off = bin_zone(frame, off, bin_model=prepare_bin_model(model, registration=off.registration,
                                                                 removal=off.removal), located=z0.located)
    return session, frame, zone, zone_off, pe.run_explained(frame, zone, session.config)[0]


def _run(frame, zone, config, monkeypatch, on: bool):
    monkeypatch.setattr(pe, "FITS_WITHOUT_PUT_BACK", on)
    return pe.run_explained(frame, zone, config, judge_above_rim=True)


def test_the_fit_region_is_the_zone_without_what_the_bound_gave_back(prepared):
    session, frame, zone, zone_off, _ = prepared
    given_back = zone.zone & ~zone_off.zone
    assert given_back.sum() > 20 and not (zone_off.zone & ~zone.zone).any()
    np.testing.assert_array_equal(pe.fit_region(frame, zone, session.config), zone.zone & ~given_back)
    # with the bound off nothing is given back: the region is the zone
    off = dataclasses.replace(session.config, removal=dataclasses.replace(session.config.removal,
                                                                          straggler_bound="off"))
    np.testing.assert_array_equal(pe.fit_region(frame, zone_off, off), zone_off.zone)


def test_the_fits_search_the_region_and_every_zone_pixel_is_judged(prepared, monkeypatch):
    session, frame, zone, _, result = prepared
    region = pe.fit_region(frame, zone, session.config)
    out, d, _ = _run(frame, zone, session.config, monkeypatch, True)
    assert d is not None and d.fits
    for f in (*d.fits, *d.vetted_out):  # found on the region's pixels only
        assert region.reshape(-1)[f.pixels].all()
    valid = np.isfinite(frame.xyz).all(axis=2)
    assert not np.isnan(d.dist_mm[zone.zone & valid]).any()  # every zone pixel judged, the given-back ones too
    assert not (out & ~zone.zone).any()
    given_back = zone.zone & ~region
    assert (d.surface[given_back] != -1).all()  # each has a nearest known surface
    # the default: the method's outliers as before the switch was set
    out0, d0, _ = _run(frame, zone, session.config, monkeypatch, False)
    assert d0 is not None
    np.testing.assert_array_equal(out0, result)


def test_off_by_default_and_the_same_where_nothing_was_given_back(prepared, monkeypatch):
    session, frame, zone, zone_off, _ = prepared
    assert pe.FITS_WITHOUT_PUT_BACK is False
    off = dataclasses.replace(session.config, removal=dataclasses.replace(session.config.removal,
                                                                          straggler_bound="off"))
    a_out, a, _ = _run(frame, zone_off, off, monkeypatch, False)
    b_out, b, _ = _run(frame, zone_off, off, monkeypatch, True)
    assert a is not None and b is not None
    np.testing.assert_array_equal(a_out, b_out)
    np.testing.assert_array_equal(a.dist_mm, b.dist_mm)
    np.testing.assert_array_equal(a.surface, b.surface)
    np.testing.assert_array_equal(a.err_mm, b.err_mm)
    assert [f.pose.tolist() for f in a.fits] == [f.pose.tolist() for f in b.fits]
