"""Suspects: each fast kernel against its literal reference, nasty inputs, laws, the union and its groups."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from zcut import InputShapeError, Intrinsics, ParameterError, SuspectParams, suspects
from zcut.cuts import find_clusters
from zcut.params import ZCutParams
from zcut.suspects import (
    DETECTORS,
    detector_bits,
    detector_names,
    fill_blobs,
    fill_blobs_reference,
    floating_evidence,
    floating_evidence_reference,
    frame_noise_mm,
    local_gaps,
    local_gaps_reference,
    noise_profile,
    surface_residuals,
    surface_residuals_reference,
)

SIZES = (0, 1, 1, 2, 3, 4, 5, 8, 13, 21, 34)


def random_heights(rng: np.random.Generator, H: int | None = None, W: int | None = None) -> np.ndarray:
    """A small random scene on a grid of 1/8 mm (so that residuals fall exactly on thresholds and
    shifts are exact): tilted planes, domes, steps, spikes both ways, mixed pixels, floating patches,
    NaN holes; sometimes float32."""
    H = int(rng.choice(SIZES)) if H is None else H
    W = int(rng.choice(SIZES)) if W is None else W
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    z = rng.normal(0, 0.5) * yy + rng.normal(0, 0.5) * xx
    for _ in range(int(rng.integers(0, 4))):  # parts: domes and boxes
        cy, cx, r = rng.uniform(0, max(H, 1)), rng.uniform(0, max(W, 1)), rng.uniform(1, 8)
        d = (yy - cy) ** 2 + (xx - cx) ** 2 < r * r
        if rng.random() < 0.5:
            z = np.where(d, np.maximum(z, rng.uniform(2, 20) * (1 - ((yy - cy) ** 2 + (xx - cx) ** 2) / r**2)), z)
        else:
            z = np.where(d, z + rng.uniform(2, 20), z)
    if H and W:
        for _ in range(int(rng.integers(0, 6))):  # spikes, mixed pixels, patches
            y, x = int(rng.integers(0, H)), int(rng.integers(0, W))
            kind = rng.integers(0, 3)
            if kind == 0:
                z[y, x] += rng.choice([-1, 1]) * rng.uniform(0.5, 8)
            elif kind == 1:
                z[y:y + 1, x:x + 3] = z[y:y + 1, x:x + 3] / 2
            else:
                z[y:y + 3, x:x + 3] = np.nanmax(z[y:y + 3, x:x + 3]) + rng.uniform(0.2, 6)
    z = z + rng.normal(0, float(rng.choice([0, 0.05, 0.3])), z.shape)
    z = np.round(z * 8) / 8
    z[rng.random(z.shape) < float(rng.choice([0, 0, 0.05, 0.2, 0.6, 1.0]))] = np.nan
    if rng.random() < 0.3:
        z = z.astype(np.float32)
    return z


def random_thresholds(rng: np.random.Generator, h: np.ndarray):
    """Thresholds as one number or per pixel; often a value some residual takes exactly (ties)."""
    tau = float(rng.choice([0.0, 0.125, 0.25, 0.5, 1.0, 0.3]))
    jump = float(rng.choice([0.0, 0.5, 1.0, 2.0]))
    if rng.random() < 0.4:
        tau = np.round(rng.uniform(0, 1, h.shape) * 8) / 8
    if rng.random() < 0.3:
        jump = np.round(rng.uniform(0, 3, h.shape) * 8) / 8
    return tau, jump


# --------------------------------------------------------------------------------------------
# Each fast kernel against its reference
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(8))
def test_surface_residuals_equal_reference(seed: int) -> None:
    rng = np.random.default_rng(5000 + seed)
    flagged = 0
    for _ in range(60):
        h = random_heights(rng)
        judged = rng.random(h.shape) < float(rng.choice([1.0, 0.7, 0.2]))
        tau, jump = random_thresholds(rng, h)
        min_below = int(rng.integers(1, 9))
        codes, res = surface_residuals(h, judged, tau=tau, jump=jump, min_below=min_below)
        rc, rr = surface_residuals_reference(h, judged, tau=tau, jump=jump, min_below=min_below)
        np.testing.assert_array_equal(codes, rc, err_msg=repr((h.tolist(), tau, jump, min_below)))
        np.testing.assert_array_equal(res, rr)
        assert codes.dtype == np.uint8 and res.dtype == np.float64
        flagged += int((codes > 0).sum())
    assert flagged > 0


@pytest.mark.parametrize("seed", range(6))
def test_fill_blobs_equals_reference(seed: int) -> None:
    rng = np.random.default_rng(6000 + seed)
    grown = 0
    for _ in range(60):
        H, W = int(rng.choice(SIZES)), int(rng.choice(SIZES))
        seedmask = rng.random((H, W)) < float(rng.choice([0.1, 0.3, 0.5, 0.8]))
        judged = rng.random((H, W)) < 0.9
        valid = rng.random((H, W)) < 0.8
        it = int(rng.integers(0, 7))
        fast = fill_blobs(seedmask, judged, valid, iterations=it)
        np.testing.assert_array_equal(fast, fill_blobs_reference(seedmask, judged, valid, iterations=it))
        assert (fast >= seedmask).all()
        grown += int(fast.sum() - seedmask.sum())
    assert grown > 0


@pytest.mark.parametrize("seed", range(6))
def test_floating_evidence_equals_reference(seed: int) -> None:
    rng = np.random.default_rng(7000 + seed)
    for _ in range(40):
        h = random_heights(rng).astype(np.float64)
        fin = np.isfinite(h)
        if rng.random() < 0.5 and fin.any():  # the components the detector gives it
            lab = find_clusters(h, params=ZCutParams(0.125, 50.0, float(rng.choice([3, 20, math.inf])))).clusters
        else:  # any labels, touching each other
            lab = rng.integers(0, 4, h.shape).astype(np.int32)
        valid = fin | (rng.random(h.shape) < 0.1)
        rough = rng.random(h.shape) < 0.3
        fast = floating_evidence(lab, valid, rough, h)
        ref = floating_evidence_reference(lab, valid, rough, h)
        for a, b in zip(fast, ref):
            np.testing.assert_array_equal(a, b)
        n = int(lab.max()) if lab.size else 0
        assert all(a.shape == (n,) for a in fast)


@pytest.mark.parametrize("seed", range(6))
def test_local_gaps_equal_reference(seed: int) -> None:
    rng = np.random.default_rng(8000 + seed)
    found = 0
    for _ in range(40):
        h = random_heights(rng)
        suspect = rng.random(h.shape) < float(rng.choice([0.05, 0.3, 0.9]))
        surface = ~suspect & (rng.random(h.shape) < float(rng.choice([1.0, 0.5, 0.05])))
        fast = local_gaps(h, suspect, surface)
        np.testing.assert_array_equal(fast, local_gaps_reference(h, suspect, surface))
        assert np.isnan(fast[~suspect]).all()
        found += int(np.isfinite(fast).sum())
    assert found > 0


def test_local_gaps_grow_the_window_until_three_surface_pixels() -> None:
    h = np.zeros((11, 11))
    h[5, 5] = 4.0
    suspect = np.zeros((11, 11), bool)
    suspect[5, 5] = True
    surface = np.zeros((11, 11), bool)
    surface[5, 9] = surface[1, 5] = True  # radius 4
    surface[0, 0] = True  # radius 5: beyond 4, reached at 8
    h[0, 0] = -2.0
    assert local_gaps(h, suspect, surface)[5, 5] == 4.0  # median(0, 0, -2) = 0
    surface[0, 0] = False
    assert np.isnan(local_gaps(h, suspect, surface)[5, 5])  # only 2 anywhere


# --------------------------------------------------------------------------------------------
# Nasty inputs
# --------------------------------------------------------------------------------------------

NAN = np.nan


@pytest.mark.parametrize("h", [
    np.zeros((0, 5)), np.zeros((5, 0)), np.zeros((0, 0)), np.array([[1.0]]), np.array([[NAN]]),
    np.full((4, 6), NAN), np.arange(7.0)[None, :], np.arange(7.0)[:, None],
    np.array([[0.0, 0.0, 9.0, 0.0, 0.0]]),  # a 1 x N spike
    np.array([[1e300, -1e300, 1e300, 5.0, -1e300]]),  # overflow to inf in the continuations
    np.array([[np.inf, 0.0, 0.0, 0.0], [0.0, -np.inf, 0.0, 1.0]]),
    np.full((3, 3), 7.0, np.float32),
], ids=lambda a: f"{a.shape}")
def test_nasty_heights(h: np.ndarray) -> None:
    judged = np.ones(h.shape, bool)
    for tau, jump in ((0.5, 2.0), (0.0, 0.0)):
        c, r = surface_residuals(h, judged, tau=tau, jump=jump, min_below=1)
        rc, rr = surface_residuals_reference(h, judged, tau=tau, jump=jump, min_below=1)
        np.testing.assert_array_equal(c, rc)
        np.testing.assert_array_equal(r, rr)
    np.testing.assert_array_equal(local_gaps(h, judged, ~judged), local_gaps_reference(h, judged, ~judged))


def test_residual_classes_on_a_plane() -> None:
    yy, xx = np.mgrid[0:9, 0:9].astype(np.float64)
    h = 0.5 * yy - 0.25 * xx  # a tilted plane: every continuation is exact
    h[2, 2] += 3.0  # spike toward the camera
    h[6, 6] -= 3.0  # spike away
    judged = np.ones(h.shape, bool)
    codes, res = surface_residuals(h, judged, tau=0.5, jump=2.0, min_below=5)
    assert detector_names(codes[2, 2]) == ("residual_up",) and res[2, 2] == 3.0
    assert detector_names(codes[6, 6]) == ("residual_down",) and res[6, 6] == -3.0
    # the neighbours of a spike keep a clean continuation on the far side: not suspects
    assert set(np.unique(codes)) == {0, detector_bits(["residual_up"]), detector_bits(["residual_down"])}
    # tie: a residual exactly at tau is not beyond it
    codes, _ = surface_residuals(h, judged, tau=3.0, jump=2.0, min_below=5)
    assert not codes.any()


def test_a_mixed_pixel_between_two_surfaces() -> None:
    h = np.zeros((7, 9))
    h[:, 5:] = 10.0  # a step edge of 10 mm
    h[3, 4] = 5.0  # halfway: a flying pixel
    codes, _ = surface_residuals(h, np.ones(h.shape, bool), tau=0.5, jump=2.0, min_below=5)
    assert detector_names(codes[3, 4]) == ("mixed",)
    assert int((codes > 0).sum()) == 1  # the clean edge pixels on both sides are not suspects


def test_below_needs_enough_directions() -> None:
    h = np.array([[0.0, 0.0, -5.0, 0.0, 0.0]])  # a 1 x N dip: 2 directions only
    j = np.ones(h.shape, bool)
    assert surface_residuals(h, j, tau=0.5, jump=2.0, min_below=2)[0][0, 2] == detector_bits(["residual_down"])
    assert surface_residuals(h, j, tau=0.5, jump=2.0, min_below=3)[0][0, 2] == 0


def test_bad_kernel_arguments() -> None:
    h = np.zeros((3, 3))
    j = np.ones((3, 3), bool)
    with pytest.raises(InputShapeError, match="height must be an"):
        surface_residuals(np.zeros((3, 3), int), j, tau=0.5, jump=1.0, min_below=5)
    with pytest.raises(InputShapeError, match="judged must have shape"):
        surface_residuals(h, np.ones((3, 4), bool), tau=0.5, jump=1.0, min_below=5)
    with pytest.raises(ParameterError, match="tau must be"):
        surface_residuals(h, j, tau=-1.0, jump=1.0, min_below=5)
    with pytest.raises(ParameterError, match="tau must be"):
        surface_residuals(h, j, tau=np.full((3, 3), np.nan), jump=1.0, min_below=5)
    with pytest.raises(ParameterError, match="jump must be"):
        surface_residuals(h, j, tau=0.5, jump=np.ones((2, 2)), min_below=5)
    with pytest.raises(ParameterError, match="min_below"):
        surface_residuals(h, j, tau=0.5, jump=1.0, min_below=9)
    with pytest.raises(ParameterError, match="iterations"):
        fill_blobs(j, j, j, iterations=-1)
    with pytest.raises(InputShapeError, match="labels must be"):
        floating_evidence(np.zeros((3, 3)), j, j, h)
    with pytest.raises(ParameterError, match="unknown detector"):
        detector_bits(["ghosts"])


# --------------------------------------------------------------------------------------------
# Laws
# --------------------------------------------------------------------------------------------

heights_st = st.integers(0, 2**31 - 1).map(lambda s: random_heights(np.random.default_rng(s)))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(h=heights_st, shift=st.integers(-4000, 4000), tau=st.sampled_from([0.125, 0.5, 1.0]))
def test_residual_codes_ignore_a_height_shift(h: np.ndarray, shift: int, tau: float) -> None:
    """Shifting every height by a constant changes no code and no residual (exact on the 1/8 grid)."""
    h = h.astype(np.float64)
    j = np.isfinite(h)
    a = surface_residuals(h, j, tau=tau, jump=2.0, min_below=5)
    b = surface_residuals(h + shift / 8, j, tau=tau, jump=2.0, min_below=5)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(h=heights_st)
def test_residual_codes_commute_with_flips_and_transposition(h: np.ndarray) -> None:
    j = np.isfinite(h)
    codes, _ = surface_residuals(h, j, tau=0.5, jump=2.0, min_below=5)
    for f in (np.fliplr, np.flipud, np.transpose):
        c2, _ = surface_residuals(np.ascontiguousarray(f(h)), np.ascontiguousarray(f(j)), tau=0.5, jump=2.0,
                                  min_below=5)
        np.testing.assert_array_equal(c2, f(codes))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(h=heights_st, tau=st.sampled_from([0.25, 0.5]))
def test_residual_suspects_are_judged_and_measured(h: np.ndarray, tau: float) -> None:
    j = np.random.default_rng(int(np.nansum(np.nan_to_num(h)) * 8) % 1000).random(h.shape) < 0.7
    codes, res = surface_residuals(h, j, tau=tau, jump=2.0, min_below=5)
    assert not codes[~(j & np.isfinite(h))].any()
    assert np.isnan(res[~(j & np.isfinite(h))]).all()
    # a larger threshold flags a subset
    c2, _ = surface_residuals(h, j, tau=2 * tau, jump=2.0, min_below=5)
    assert ((c2 > 0) <= (codes > 0) | (c2 == detector_bits(["mixed"]))).all()


# --------------------------------------------------------------------------------------------
# The union and its groups
# --------------------------------------------------------------------------------------------


def scene(rng: np.random.Generator, H: int = 120, W: int = 160):
    """A synthetic frame with known outliers: a floor 550 mm away, boxes on it, a spike up, a spike
    down, mixed pixels along one box's edge, a floating patch and points above the rim."""
    z = np.full((H, W), 550.0) + np.round(rng.normal(0, 0.02, (H, W)) * 1024) / 1024  # mm from the camera
    z[20:60, 20:70] -= 30.0  # a box 30 mm high
    z[70:110, 90:150] -= 20.0
    truth = np.zeros((H, W), bool)
    z[40, 40] -= 4.0  # spike toward the camera
    z[90, 120] += 4.0  # spike away
    truth[40, 40] = truth[90, 120] = True
    for r in range(25, 55, 2):  # mixed pixels along the box's right edge (column 70)
        z[r, 70] = 535.0
        truth[r, 70] = True
    z[80:84, 30:34] -= 6.0  # a floating patch over the floor
    truth[80:84, 30:34] = True
    above = np.zeros((H, W), bool)
    above[5:7, 140:143] = True
    z[above] = 400.0
    xyz = np.zeros((H, W, 3))
    yy, xx = np.mgrid[0:H, 0:W]
    xyz[..., 0] = (xx - W / 2) * z / 1000.0 / 600.0
    xyz[..., 1] = (yy - H / 2) * z / 1000.0 / 600.0
    xyz[..., 2] = z / 1000.0
    holes = rng.random((H, W)) < 0.01
    holes[truth | above] = False
    xyz[holes] = np.nan
    valid = ~holes
    zone = valid & ~above
    height = -1000.0 * xyz[..., 2]
    return xyz, height, zone, above, truth


def test_suspects_find_the_planted_outliers(rng) -> None:
    xyz, height, zone, above, truth = scene(rng)
    res = suspects(xyz, height, zone, above, params=SuspectParams(a_max=2000))
    assert res.mask[truth].all()
    assert res.mask[above].all() and (res.detectors[above] & detector_bits(["above_rim"])).all()
    assert res.detector_mask("residual_up")[40, 40] and res.detector_mask("residual_down")[90, 120]
    assert res.detector_mask("mixed")[25:55:2, 70].all()
    assert res.detector_mask("floating")[80:84, 30:34].all()
    assert int(res.mask.sum()) <= 3 * int(truth.sum() + above.sum())  # few false suspects
    g = res.groups[81, 31]
    grp = res.group(int(g))
    assert grp.detectors[0] == "floating" and grp.gap_mm == pytest.approx(6.0, abs=0.1)
    run = np.unique(res.groups[25:55:2, 70])
    assert run.size == 1  # the flying pixels along one edge are one group
    assert res.group(int(run[0])).detectors[0] == "mixed"
    spike = res.group(int(res.groups[40, 40]))
    assert spike.gap_mm == pytest.approx(4.0, abs=0.1) and spike.size_px == 1
    assert res.group(int(res.groups[90, 120])).gap_mm == pytest.approx(-4.0, abs=0.1)


def check_result(res, xyz, zone, above, params) -> None:
    """The invariants of every SuspectResult."""
    H, W = zone.shape
    valid = np.isfinite(xyz).all(axis=2)
    assert res.mask.shape == res.groups.shape == res.detectors.shape == (H, W)
    assert res.groups.dtype == np.int32 and res.mask.dtype == bool
    allowed = valid & (zone | (above if above is not None else False))
    assert not res.mask[~allowed].any()
    np.testing.assert_array_equal(res.mask, res.groups > 0)
    np.testing.assert_array_equal(res.mask, res.detectors > 0)
    n = res.n_groups
    assert n <= params.max_groups
    assert res.groups.max(initial=0) == n
    np.testing.assert_array_equal(res.group_size, np.bincount(res.groups.ravel(), minlength=n + 1)[1:])
    assert (np.diff(res.group_score) <= 0).all()  # numbered by decreasing score
    for g in range(1, n + 1):
        grp = res.group(g)
        r0, c0, r1, c1 = grp.bbox
        inside = np.zeros((H, W), bool)
        inside[r0:r1, c0:c1] = True
        assert not (res.groups == g)[~inside].any()
        bits = np.bitwise_or.reduce(res.detectors[res.groups == g])
        assert detector_bits(grp.detectors) == bits
        assert grp.detectors[0] == DETECTORS[res.group_primary[g - 1]]


def test_suspects_invariants_on_random_frames() -> None:
    rng = np.random.default_rng(9000)
    for _ in range(40):
        h = random_heights(rng).astype(np.float64)
        H, W = h.shape
        xyz = np.stack([np.zeros((H, W)), np.zeros((H, W)), -h / 1000.0 + 0.6], axis=2)
        zone = np.isfinite(h) & (rng.random((H, W)) < 0.9)
        above = (rng.random((H, W)) < 0.02) if rng.random() < 0.5 else None
        params = SuspectParams(a_max=float(rng.choice([10, 100, 1000])), max_groups=int(rng.choice([5, 8, 40])),
                               merge_radius_px=int(rng.choice([0, 1, 3])))
        res = suspects(xyz, -1000.0 * xyz[..., 2], zone, above, params=params)
        check_result(res, xyz, zone, above, params)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), shift=st.integers(-200, 200))
def test_suspects_ignore_a_height_shift(seed: int, shift: int) -> None:
    """Moving the whole scene along the optical axis by a constant changes no suspect (z on a grid of
    2**-13 m and the shift on it: every height and difference is exact)."""
    rng = np.random.default_rng(seed)
    xyz, height, zone, above, _ = scene(rng)
    xyz[..., 2] = np.round(xyz[..., 2] * 8192) / 8192
    moved = xyz.copy()
    moved[..., 2] += shift / 8192
    p = SuspectParams(a_max=500)
    a = suspects(xyz, -1000.0 * xyz[..., 2], zone, above, params=p)
    b = suspects(moved, -1000.0 * moved[..., 2], zone, above, params=p)
    np.testing.assert_array_equal(a.mask, b.mask)
    np.testing.assert_array_equal(a.detectors, b.detectors)
    np.testing.assert_array_equal(a.groups, b.groups)


@pytest.mark.parametrize("case", ["empty", "1x1", "1xN", "Nx1", "all NaN", "one point", "identical points",
                                  "empty zone", "float32"])
def test_degenerate_frames(case: str) -> None:
    shapes = {"empty": (0, 0), "1x1": (1, 1), "1xN": (1, 50), "Nx1": (50, 1)}
    H, W = shapes.get(case, (30, 40))
    rng = np.random.default_rng(3)
    xyz = np.stack([rng.normal(0, 0.1, (H, W)), rng.normal(0, 0.1, (H, W)), 0.5 + rng.normal(0, 0.002, (H, W))], 2)
    if case == "all NaN":
        xyz[:] = np.nan
    if case == "one point":
        xyz[:] = np.nan
        xyz[3, 4] = (0.0, 0.0, 0.5)
    if case == "identical points":
        xyz[:] = (0.01, 0.02, 0.5)
    if case == "float32":
        xyz = xyz.astype(np.float32)
    valid = np.isfinite(xyz).all(axis=2)
    zone = np.zeros((H, W), bool) if case == "empty zone" else valid
    p = SuspectParams()
    res = suspects(xyz, -1000.0 * xyz[..., 2].astype(np.float64), zone, params=p)
    check_result(res, xyz, zone, None, p)
    if case in ("empty", "all NaN", "empty zone", "identical points"):
        assert not res.mask.any() and res.n_groups == 0


def test_at_most_max_groups_with_a_hundred_thousand_suspects() -> None:
    """A 1920 x 1200 frame with 100,000 spikes spread over it: groups stay within max_groups."""
    rng = np.random.default_rng(11)
    H, W = 1200, 1920
    z = np.full((H, W), 500.0) + np.round(rng.normal(0, 0.05, (H, W)) * 64) / 64
    idx = rng.choice(H * W, 100_000, replace=False)
    z.reshape(-1)[idx] -= rng.uniform(2, 8, idx.size)
    xyz = np.stack([np.zeros((H, W)), np.zeros((H, W)), z / 1000.0], 2)
    zone = np.ones((H, W), bool)
    p = SuspectParams(a_max=5000)
    res = suspects(xyz, -z, zone, params=p)
    assert res.mask.sum() >= 80_000  # spikes next to other spikes can continue each other
    check_result(res, xyz, zone, None, p)
    assert res.n_groups <= 40


def test_noise_is_measured_per_height() -> None:
    """A quantized sensor: depth in steps growing with range; the profile sees σ̂ and the step grow."""
    rng = np.random.default_rng(5)
    H, W = 200, 200
    yy, xx = np.mgrid[0:H, 0:W]
    depth = 600.0 + 6.0 * yy + rng.normal(0, 0.5, (H, W)) * (1 + yy / 50)  # mm, noisier far away
    step = np.where(yy < 100, 1.0, 4.0)
    depth = np.round(depth / step) * step
    h = -depth
    prof = noise_profile(h, np.ones((H, W), bool))
    assert prof.heights_mm.size > 4 and (np.diff(prof.heights_mm) > 0).all()
    near, far = prof.sigma_at(-650.0), prof.sigma_at(-1700.0)
    assert far > 2 * near > 0
    assert prof.step_at(-650.0) >= 1.0 and prof.step_at(-1700.0) >= 4.0
    smooth = noise_profile(-(600.0 + 6.0 * yy + rng.normal(0, 0.5, (H, W))), np.ones((H, W), bool))
    assert (smooth.step_mm == 0).all()  # continuous depth has no step
    assert frame_noise_mm(np.zeros((0, 3)), np.zeros((0, 3), bool)) == 0.0
    assert noise_profile(np.full((3, 3), np.nan), np.ones((3, 3), bool)).heights_mm.size == 0


def test_bad_suspects_arguments() -> None:
    xyz = np.zeros((4, 5, 3))
    h = np.zeros((4, 5))
    z = np.ones((4, 5), bool)
    p = SuspectParams()
    with pytest.raises(ParameterError, match="params must be a SuspectParams"):
        suspects(xyz, h, z, params=ZCutParams(0.2, 30, 10))
    with pytest.raises(InputShapeError, match="xyz must be an"):
        suspects(np.zeros((4, 5)), h, z, params=p)
    with pytest.raises(InputShapeError, match="height_mm must be"):
        suspects(xyz, np.zeros((4, 6)), z, params=p)
    with pytest.raises(InputShapeError, match="zone must have shape"):
        suspects(xyz, h, np.ones((5, 4), bool), params=p)
    with pytest.raises(InputShapeError, match="above_rim must be an"):
        suspects(xyz, h, z, np.zeros((4, 5), np.uint8), params=p)
    with pytest.raises(InputShapeError, match="intrinsics are for 480x640"):
        suspects(xyz, h, z, params=p, intrinsics=Intrinsics(500, 500, 320, 240, 640, 480))
    with pytest.raises(ParameterError, match="group label must be"):
        suspects(xyz, h, z, params=p).group(1)


@pytest.mark.parametrize(("changes", "match"), [
    (dict(min_residual_mm=0), r"SuspectParams\.min_residual_mm .*got 0"),
    (dict(noise_k=-1), r"SuspectParams\.noise_k .*got -1"),
    (dict(jump_mm=math.nan), r"SuspectParams\.jump_mm .*got nan"),
    (dict(below_min_directions=0), r"SuspectParams\.below_min_directions .*got 0"),
    (dict(below_min_directions=2.5), r"SuspectParams\.below_min_directions must be an integer"),
    (dict(fill_iterations=65), r"SuspectParams\.fill_iterations .*got 65"),
    (dict(floating_step_mm=0), r"SuspectParams\.floating_step_mm .*got 0"),
    (dict(floating_rho=math.inf), r"SuspectParams\.floating_rho .*got inf"),
    (dict(plain_rho=0.2), r"SuspectParams\.plain_rho must be <= floating_rho"),
    (dict(evidence_holes=1.5), r"SuspectParams\.evidence_holes .*got 1\.5"),
    (dict(evidence_ring_valid="0.3"), r"SuspectParams\.evidence_ring_valid .*got '0\.3'"),
    (dict(a_max=0), r"SuspectParams\.a_max .*got 0"),
    (dict(merge_radius_px=-1), r"SuspectParams\.merge_radius_px .*got -1"),
    (dict(max_groups=4), r"SuspectParams\.max_groups .*got 4"),
    (dict(max_groups=True), r"SuspectParams\.max_groups .*got True"),
])
def test_bad_params(changes: dict, match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        dataclasses.replace(SuspectParams(), **changes)


def test_params_are_frozen_and_typed() -> None:
    p = SuspectParams(min_residual_mm=1, a_max=100, max_groups=40.0)
    assert isinstance(p.min_residual_mm, float) and isinstance(p.max_groups, int) and p.a_max == 100.0
    with pytest.raises(AttributeError):
        p.jump_mm = 3.0  # type: ignore[misc]


def test_real_scans_propose_few_groups(real_data) -> None:
    """On the Kinect scans (no truth): suspects stay a small share of the valid points, in at most
    max_groups groups, and the quantized far range is not proposed as floating terraces."""
    from replay.logs.pcd import read_pcd

    for name in ("mosd_test55.pcd", "milk_cartoon_all_small_clorox.pcd", "table_scene_mug_stereo_textured.pcd"):
        xyz = read_pcd(real_data / name).xyz
        valid = np.isfinite(xyz).all(axis=2)
        p = SuspectParams()
        res = suspects(xyz, -1000.0 * xyz[..., 2].astype(np.float64), valid, params=p)
        check_result(res, xyz, valid, None, p)
        assert 0 < res.mask.sum() < 0.02 * valid.sum(), name
        assert res.noise_profile.step_mm.max() >= 1.0  # the sensor reports whole millimetres or coarser


def test_strength_classes_take_each_component_median() -> None:
    """A component's class is the number of STRENGTH_CLASSES bounds its median |gap| / τ reaches; NaN is strongest."""
    from zcut.suspects import STRENGTH_CLASSES, strength_classes

    primary = np.full((6, 12), -1, np.int8)
    strength = np.zeros((6, 12))
    primary[1, 1:4] = 2          # one mixed run: median 1.0 -> class 0
    strength[1, 1:4] = [0.5, 1.0, 30.0]
    primary[4, 1:3] = 2          # another: median exactly the first bound -> class 1
    strength[4, 1:3] = [STRENGTH_CLASSES[0]] * 2
    primary[1, 8:11] = 1         # a floating one: median 9 -> class 2
    strength[1, 8:11] = [9.0, 9.0, 0.1]
    primary[4, 9] = 4            # no surface around it: NaN -> the strongest class
    strength[4, 9] = np.nan
    cls = strength_classes(primary, strength)
    assert (cls[1, 1:4] == 0).all() and (cls[4, 1:3] == 1).all() and (cls[1, 8:11] == 2).all()
    assert cls[4, 9] == len(STRENGTH_CLASSES)
    assert (cls[primary < 0] == -1).all()


def test_weak_and_strong_suspects_of_one_detector_are_separate_groups() -> None:
    """Flying pixels barely off the surface and ones far off it, interleaved along one edge, are two groups
    while the budget allows; with a budget below the kinds, classes of one detector join again."""
    H, W = 80, 80
    h = np.full((H, W), 10.0)
    h[:, 40:] = 30.0                      # an occlusion edge at column 40
    rows = np.arange(4, 76, 2)
    weak, strong = rows[::2], rows[1::2]
    h[weak, 39] = 10.0 + 0.9              # just off the low surface (< 2 τ with τ = 0.5)
    h[strong, 39] = 20.0                  # half-way up the edge: a mixed pixel
    xyz = np.stack([np.zeros((H, W)), np.zeros((H, W)), -h / 1000.0 + 0.6], axis=2)
    zone = np.ones((H, W), bool)
    params = SuspectParams(min_residual_mm=0.5, noise_k=3.0, a_max=100.0)
    res = suspects(xyz, h, zone, params=params)
    g_strong = np.unique(res.groups[strong, 39])
    g_weak = np.unique(res.groups[weak, 39])
    assert (g_strong > 0).all() and g_strong.size == 1
    assert (g_weak > 0).all() and g_weak.size == 1 and g_weak[0] != g_strong[0]
    assert res.group(int(g_weak[0])).gap_mm == pytest.approx(0.9)
    assert abs(res.group(int(g_strong[0])).gap_mm) > 9.0  # half-way up a 20 mm edge
    tight = suspects(xyz, h, zone, params=dataclasses.replace(params, max_groups=5))
    assert tight.n_groups <= 5
