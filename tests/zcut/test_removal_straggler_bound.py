"""The straggler pass bounded by 3 of the bin's Err (issue 31 item 2, docs/bin_robustness.md).

A straggler (a pixel beside bin pixels, beyond τ of the bin model) is bin only within
min(τ + ``straggler_mm``, 3 × max(0.05 mm, √(σ_bin² + c²/2))) of the model, σ_bin the residual scale
of the pixels τ is measured on (:attr:`zcut.removal.Tolerance.sigma_mm`), c the pixel's footprint (z / f). On a hand-made synthetic frame
(300 x 480, registered as the replay does), inner-wall pixels moved along their rays to a known distance from the
model: within the bound they are bin, beyond it (but within τ + 2 mm, where the previous rule took them) they
stay in the zone; the fast path equals its ``reference=True`` path and the literal reference
(``tests/reference/removal_reference.py``), on that frame, with large invalid regions and on degenerate frames.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from reference.removal_reference import remove_table_and_bin_reference

from replay.pipeline import stages
from replay.pipeline.bin_model import bin_model_for
from replay.pipeline.session import ReplaySession
from replay.synth.log import write_synthetic_log
from replay.synth.scene import LABEL_WALL
from replay.synth.synthesize import synthesize_frame
from zcut.params import RemovalParams
from zcut.removal import (
    STRAGGLER_ERR_FLOOR_MM,
    STRAGGLER_ERRS,
    _radius,
    bin_sigma_m,
    frame_tolerance,
    pixel_angle,
    prepare_removal_index,
    remove_table_and_bin,
    straggler_bound_m,
)

H, W = 300, 480
BOUND = RemovalParams(straggler_bound="global")  # the bound everywhere (the default bounds below the rim's band)
KIND, SEED = "spheres", 31
FIELDS = ("table", "easy_outliers", "bin_points", "zone", "height_mm", "xyz")


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A hand-made frame located as the replay does: (xyz, footprint, ring, T, model, focal length, wall picks):
    inner-wall pixels whose 7 x 7 neighbourhood is wall and labelled bin, every 9th pixel (isolated stragglers; the
    pile covers the floor)."""
    path = write_synthetic_log(tmp_path_factory.mktemp("strag") / "s.mcap", kind=KIND, frames=1, seed=SEED,
                               size=(H, W))
    s = ReplaySession.open(path, choose_bin_model=lambda reader: bin_model_for(reader, None))
    frame = next(iter(s.reader.frames()))
    loc = stages.locate_bin(frame, s.config, bin_model=s.prepared, seed=s.seed)
    assert loc.registration is not None and loc.registration.converged and s.prepared is not None
    surface = synthesize_frame(kind=KIND, seed=SEED, index=0, size=(H, W)).surface
    T = loc.registration.T_cam_bin
    model = s.prepared.model
    rem = remove_table_and_bin(frame.xyz, loc.bin_mask.mask, index=prepare_removal_index(model, BOUND),
                               T_cam_bin=T, ring=loc.ring)
    wall = (surface == LABEL_WALL) & rem.bin_points
    inner = wall.copy()
    for dr in range(-3, 4):
        for dc in range(-3, 4):
            inner &= np.roll(np.roll(wall, dr, axis=0), dc, axis=1)
    grid = np.zeros((H, W), bool)
    grid[5::9, 5::9] = True
    picks = np.argwhere(inner & grid)
    assert len(picks) >= 40
    assert frame.intrinsics is not None
    return frame.xyz, loc.bin_mask.mask, loc.ring, T, model, frame.intrinsics.fx, picks


def _moved(xyz, T, model, picks, dist_m):
    """``xyz`` with each pick moved along its ray to ``dist_m`` above the tangent plane of its nearest model point
    (a planar wall face: its points' planes the same)."""
    from scipy.spatial import cKDTree

    out = xyz.copy()
    R, t = T[:3, :3], T[:3, 3]
    tree = cKDTree(model.points)
    camera = (-t) @ R  # the camera's centre, bin frame
    for (r, c), d in zip(picks, dist_m, strict=True):
        p = xyz[r, c].astype(np.float64)
        ray = p / np.linalg.norm(p)
        q = (p - t) @ R
        _, j = tree.query(q)
        n, m = model.normals[j], model.points[j]
        side = 1.0 if n @ (camera - m) >= 0 else -1.0  # towards the camera
        step = (side * d - n @ (q - m)) / (n @ (ray @ R))
        out[r, c] = (p + step * ray).astype(np.float32)
    return out


def _reference(xyz, fp, model, T, p, tol, *, bounded: bool):
    d = tol.tolerance_mm / 1000.0
    radius = max(_radius(p, model.spacing_m, d), tol.reach_mm / 1000.0)
    straggler = p.straggler_m + d
    err = (tol.sigma_mm / 1000.0, tol.pixel_rad) if bounded and p.straggler_bound != "off" else None
    return remove_table_and_bin_reference(
        xyz, fp, model=model, T_cam_bin=T, delta_m=d, rim_offset_m=p.rim_offset_m, search_radius_m=radius,
        straggler_m=straggler, straggler_radius_m=max(radius + p.straggler_m, straggler),
        straggler_neighbours=p.straggler_neighbours, bin_first=True, straggler_err=err,
        straggler_top_m=_top(model, p))


def _top(model, p):
    """The height (bin frame, m) above which "below_rim" bounds no straggler: the model's rim (the 99.5th percentile
    of its -z) less ``rim_offset_mm``; +inf for the other settings."""
    if p.straggler_bound != "below_rim":
        return np.inf
    return float(np.percentile(-model.points[:, 2], 99.5)) - p.rim_offset_m


def _heights(xyz, T, picks):
    """The picks' heights (-z in the bin frame, m)."""
    p = xyz[picks[:, 0], picks[:, 1]].astype(np.float64)
    return -((p - T[:3, 3]) @ T[:3, :3])[:, 2]


def _assert_same(a, b):
    for f in FIELDS:
        x, y = getattr(a, f), getattr(b, f)
        assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=True), f"{f}: {int(np.sum(x != y))} differ"


def test_stragglers_beyond_three_errs_stay_in_the_zone(scene):
    xyz, fp, ring, T, model, f, picks = scene
    p = BOUND
    index = prepare_removal_index(model, p)
    tol = frame_tolerance(xyz, ring, index, T)  # the ring (rim, upper walls) holds no pick: τ as with them moved
    assert np.isfinite(tol.sigma_mm) and 0.01 < tol.sigma_mm < 0.5
    assert tol.pixel_rad == pytest.approx(1.0 / f, rel=1e-5)
    tau = tol.tolerance_mm / 1000.0
    z = xyz[picks[:, 0], picks[:, 1], 2].astype(np.float64)
    bound = straggler_bound_m(z, tol.sigma_mm / 1000.0, tol.pixel_rad, tau + p.straggler_m)
    reach = tau + p.straggler_m
    assert (bound > tau + 3e-4).all() and (bound < reach - 3e-4).all()  # the bound lies between τ and τ + 2 mm
    # half the picks moved between τ and the bound (the bin's own stragglers), half between it and τ + 2 mm
    inside = np.arange(len(picks)) % 2 == 0
    moved = _moved(xyz, T, model, picks, np.where(inside, 0.5 * (tau + bound), 0.5 * (bound + reach)))
    got = remove_table_and_bin(moved, fp, index=index, T_cam_bin=T, ring=ring)
    assert got.tolerance_mm == tol.tolerance_mm
    binp = got.bin_points[picks[:, 0], picks[:, 1]]
    assert binp[inside].all()
    # beyond the bound: in the zone, but for a few whose search reaches another face's points (their distance is
    # to the nearest point's plane; the test takes any point within its radius whose plane passes near)
    out = got.zone[picks[~inside, 0], picks[~inside, 1]]
    assert out.mean() >= 0.85, f"{int((~out).sum())} of {out.size}"
    ref = _reference(moved, fp, model, T, p, tol, bounded=True)
    _assert_same(got, ref)
    _assert_same(got, remove_table_and_bin(moved, fp, index=index, T_cam_bin=T, ring=ring, reference=True))
    # the previous rule (τ + straggler_mm) took them all; nothing else changes here
    unbounded = _reference(moved, fp, model, T, p, tol, bounded=False)
    assert unbounded.bin_points[picks[:, 0], picks[:, 1]].all()
    # the straggler pass still labels pixels (the bin's noise tail it exists for): more bin than without it
    no_pass = prepare_removal_index(model, dataclasses.replace(p, straggler_mm=0.0))
    plain = remove_table_and_bin(moved, fp, index=no_pass, T_cam_bin=T, ring=ring)
    assert (got.bin_points & ~plain.bin_points).sum() > inside.sum()


def test_the_bound_applies_below_the_rims_band_by_default():
    assert RemovalParams().straggler_bound == "below_rim"


@pytest.mark.parametrize("case", ["global", "below_rim", "off", "below_rim half-way"])
def test_the_switch(scene, case):
    """``RemovalParams.straggler_bound``: "global" bounds every straggler by the frame's σ_bin, "off" is the previous
    rule (τ + ``straggler_mm``: every moved pick is bin), "below_rim" bounds those below the rim's band only; with
    the band ``rim_offset_mm`` reaching half-way down the picks ("below_rim half-way"), the picks beyond the frame's
    bound above the band's bottom are bin (τ + ``straggler_mm``, as "off"), those below it stay in the zone (as
    "global"). Fast = its reference path = the literal reference."""
    xyz, fp, ring, T, model, f, picks = scene
    h = _heights(xyz, T, picks)
    if case == "below_rim half-way":
        base = prepare_removal_index(model, RemovalParams())
        p = RemovalParams(straggler_bound="below_rim", rim_offset_mm=float(1000.0 * (base.rim_b - np.median(h))))
    else:
        p = RemovalParams(straggler_bound=case)
    index = prepare_removal_index(model, p)
    tol = frame_tolerance(xyz, ring, index, T)
    tau = tol.tolerance_mm / 1000.0
    z = xyz[picks[:, 0], picks[:, 1], 2].astype(np.float64)
    bound = straggler_bound_m(z, tol.sigma_mm / 1000.0, tol.pixel_rad, tau + p.straggler_m)
    moved = _moved(xyz, T, model, picks, 0.5 * (bound + tau + p.straggler_m))  # beyond the frame's bound
    got = remove_table_and_bin(moved, fp, index=index, T_cam_bin=T, ring=ring)
    _assert_same(got, remove_table_and_bin(moved, fp, index=index, T_cam_bin=T, ring=ring, reference=True))
    _assert_same(got, _reference(moved, fp, model, T, p, tol, bounded=True))
    taken = got.bin_points[picks[:, 0], picks[:, 1]]
    if case == "off":
        assert taken.all()
        return
    if case == "global":
        assert (~taken).mean() >= 0.85
        return
    # "below_rim": the picks in the rim's band are bin as with "off", the others bounded as "global"
    top = _top(model, p)
    above = _heights(moved, T, picks) > top
    assert taken[above].all()
    assert (~taken[~above]).mean() >= 0.85
    if case == "below_rim":  # the default band (5 mm) holds less than half of the picks
        assert above.sum() < 0.5 * len(picks)
        return
    assert top == pytest.approx(index.rim_b - p.rim_offset_m, abs=1e-12)
    assert 0.3 < above.mean() < 0.7
    # the bound's own formula, per pixel: straggler_m above the band, the frame's bound below it
    np.testing.assert_array_equal(
        straggler_bound_m(z, tol.sigma_mm / 1000.0, tol.pixel_rad, tau + p.straggler_m, height_m=h, top_m=top),
        np.where(h > top, tau + p.straggler_m, bound))


@pytest.mark.parametrize("p", [BOUND, RemovalParams(straggler_bound="below_rim", rim_offset_mm=40.0)],
                         ids=["global", "below_rim"])
@pytest.mark.parametrize("case", ["half NaN", "bands", "all NaN", "one pixel"])
def test_the_bounded_pass_equals_the_reference_on_invalid_and_degenerate_frames(scene, case, p):
    """Large invalid regions and degenerate frames: the fast path, its ``reference=True`` path and the literal
    reference agree (the bound is known when the ring measures a field, else not applied)."""
    xyz, fp, ring, T, model, f, picks = scene
    index = prepare_removal_index(model, p)
    a = _moved(xyz, T, model, picks, np.full(len(picks), 0.003))
    if case == "half NaN":
        a[:, : W // 2] = np.nan
    elif case == "bands":
        a[::5] = np.nan
        a[:, 100:220] = np.nan
    else:
        keep = a[picks[0, 0], picks[0, 1]].copy()
        a[:] = np.nan
        if case == "one pixel":
            a[picks[0, 0], picks[0, 1]] = keep
    tol = frame_tolerance(a, ring, index, T)
    got = remove_table_and_bin(a, fp, index=index, T_cam_bin=T, ring=ring)
    _assert_same(got, remove_table_and_bin(a, fp, index=index, T_cam_bin=T, ring=ring, reference=True))
    known = bool(np.isfinite(tol.sigma_mm) and np.isfinite(tol.pixel_rad))  # the bound (one pixel: no neighbour)
    if np.isfinite(tol.reach_mm):
        _assert_same(got, _reference(a, fp, model, T, p, tol, bounded=known))
    assert known == (case in ("half NaN", "bands"))


def test_the_bound():
    """min(straggler_m, 3 × max(0.05 mm, √(σ² + c²/2))), c = |z| × the pixel's angle; unknown σ: straggler_m."""
    z = np.array([0.0, 0.5, -0.5, 1.0, 10.0])
    got = straggler_bound_m(z, 2e-4, 1.0 / 500.0, 0.004)
    c = np.abs(z) / 500.0
    want = np.minimum(0.004, STRAGGLER_ERRS * np.maximum(STRAGGLER_ERR_FLOOR_MM / 1000.0, np.sqrt(4e-8 + c * c / 2)))
    np.testing.assert_array_equal(got, want)
    assert got[0] == pytest.approx(6e-4) and got[-1] == 0.004  # σ alone at z = 0; the cap far away
    np.testing.assert_allclose(straggler_bound_m(np.zeros(2), 0.0, 0.0, 0.004), 1.5e-4, rtol=1e-12)  # the floor
    for sigma, rad in ((np.nan, 0.002), (2e-4, np.nan)):
        assert straggler_bound_m(z, sigma, rad, 0.0035).tolist() == [0.0035] * len(z)


def test_the_pixel_angle(scene):
    xyz, fp, ring, T, model, f, picks = scene
    flat = np.flatnonzero(ring)
    assert pixel_angle(xyz, flat) == pytest.approx(1.0 / f, rel=1e-5)
    assert np.isnan(pixel_angle(xyz, flat[:0]))
    assert np.isnan(pixel_angle(np.full_like(xyz, np.nan), flat))
    assert np.isnan(pixel_angle(xyz[:1, :1], np.array([0])))  # no neighbour


def test_no_bound_without_a_measured_tolerance(scene):
    """A fixed τ measures no residual: σ_bin unknown, the pass as before; a model without normals measures its
    residuals as distances, and σ_bin from them."""
    xyz, fp, ring, T, model, f, picks = scene
    tol = frame_tolerance(xyz, ring, prepare_removal_index(model, RemovalParams(tolerance_mm=1.5)), T)
    assert np.isnan(tol.sigma_mm) and np.isnan(tol.pixel_rad)
    tol = frame_tolerance(xyz, ring, prepare_removal_index(dataclasses.replace(model, normals=None), RemovalParams()), T)
    assert np.isfinite(tol.sigma_mm) and tol.pixel_rad == pytest.approx(1.0 / f, rel=1e-5)


def test_sigma_is_the_residual_scale_of_taus_pixels():
    """σ_bin = 1.4826 × the median of the residuals (mm → m); NaN with none, +inf when most are infinite."""
    assert bin_sigma_m(np.array([0.1, 0.2, 0.3])) == 1.4826 * 0.2 / 1000.0
    assert np.isnan(bin_sigma_m(np.zeros(0)))
    assert bin_sigma_m(np.array([0.1, np.inf, np.inf])) == np.inf
