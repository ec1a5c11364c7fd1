"""The suspects' fast path against the previous code (``zcut.suspects._reference``), bit for bit (issue 32).

Every field of the result (mask, groups, detectors, gaps, residuals, per-group tables, noise, the
edge-aware distances) on synthetic hand-made logs of several kinds and seeds, a ray-traced frame, the
real Kinect scans, frames with large invalid regions and degenerate ones; and each fast part against
its previous version on its own.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from components_check import check_components
from suspects_helpers import patch_covariances
from test_suspects import random_heights, scene

from replay.logs.pcd import read_pcd
from replay.logs.reader import LogReader
from replay.synth.log import write_synthetic_log
from replay.synth.raytrace import write_raytraced_log
from zcut.edge_surface import EdgeSurfaceParams, edge_surfaces, signed_edge_distance
from zcut.params import SuspectParams
from zcut.suspects import _reference as ref
from zcut.suspects import noise_profile, suspects
from zcut.suspects.grouping import _merge_compact
from zcut.suspects.noise import local_height

SIZE = (120, 160)
FIELDS = [f.name for f in dataclasses.fields(ref.SuspectResult) if not f.name.startswith("_")] + ["surface_mm"]


def assert_same(fast, old) -> None:
    """Every field equal, dtype and NaN included."""
    for name in FIELDS:
        a, b = getattr(fast, name), getattr(old, name)
        if name == "noise_profile":
            for part in ("heights_mm", "sigma_mm", "step_mm"):
                assert np.array_equal(getattr(a, part), getattr(b, part), equal_nan=True), f"noise_profile.{part}"
            continue
        if a is None or b is None:
            assert a is None and b is None, name
            continue
        a, b = np.asarray(a), np.asarray(b)
        assert a.dtype == b.dtype and a.shape == b.shape, f"{name}: {a.dtype}{a.shape} vs {b.dtype}{b.shape}"
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), name


def both(xyz, height, zone, above=None, params=None, edge=True) -> None:
    params = params or SuspectParams()
    es = EdgeSurfaceParams() if edge else None
    fast = suspects(xyz, height, zone, above, params=params, edge_surface=es)
    old = ref.suspects_reference(xyz, height, zone, above, params=params, edge_surface=es)
    assert_same(fast, old)


def frames_of(path):
    return [(f.xyz, -1000.0 * f.xyz[..., 2].astype(np.float64)) for f in LogReader(path).frames()]


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("suspects_fast")
    out = {}
    for kind, seed in (("zinc_nuts", 3), ("black_nuts", 5), ("spheres", 9), ("sprockets", 11)):
        out[f"{kind}-{seed}"] = frames_of(write_synthetic_log(d / f"{kind}.mcap", kind=kind, frames=1, seed=seed,
                                                              size=SIZE))
    out["quantized"] = frames_of(write_synthetic_log(d / "q.mcap", kind="rods", frames=1, seed=2, size=SIZE,
                                                     quantize_mm=1.0))
    out["raytraced"] = frames_of(write_raytraced_log(d / "rt.mcap", kind="zinc_nuts", frames=1, seed=4, size=SIZE))
    return out


@pytest.mark.parametrize("name", ["zinc_nuts-3", "black_nuts-5", "spheres-9", "sprockets-11", "quantized",
                                  "raytraced"])
def test_fast_equals_reference_on_logs(logs, name) -> None:
    for xyz, height in logs[name]:
        valid = np.isfinite(xyz).all(axis=2)
        both(xyz, height, valid, params=SuspectParams(a_max=200.0))
        # a zone with a hole, points above the rim, no edge surface, other grouping
        zone = valid.copy()
        zone[30:70, 40:100] = False
        above = valid & (np.arange(xyz.shape[1])[None, :] > 150)
        both(xyz, height, zone, above, params=SuspectParams(a_max=50.0, merge_radius_px=1, max_groups=5))
        both(xyz, height, zone, params=SuspectParams(a_max=1000.0), edge=False)


def test_fast_equals_reference_with_large_invalid_regions(logs) -> None:
    rng = np.random.default_rng(7)
    for name in ("zinc_nuts-3", "raytraced"):
        xyz, height = (a.copy() for a in logs[name][0])
        xyz[:60, :] = np.nan  # half the frame unmeasured
        xyz[rng.random(xyz.shape[:2]) < 0.3] = np.nan  # and a third of the rest
        height = -1000.0 * xyz[..., 2].astype(np.float64)
        both(xyz, height, np.isfinite(xyz).all(axis=2), params=SuspectParams(a_max=100.0))


def test_fast_equals_reference_on_real_scans(real_data) -> None:
    for name in ("mosd_test16.pcd", "table_scene_mug_stereo_textured.pcd"):
        xyz = read_pcd(real_data / name).xyz
        valid = np.isfinite(xyz).all(axis=2)
        both(xyz, -1000.0 * xyz[..., 2].astype(np.float64), valid)


def test_fast_equals_reference_on_hand_made_scenes() -> None:
    rng = np.random.default_rng(31)
    for _ in range(4):
        xyz, height, zone, above, _ = scene(rng)
        both(xyz, height, zone, above, params=SuspectParams(a_max=2000))
    for _ in range(40):  # random small scenes of every size from 0 x 0, ties on the thresholds
        h = random_heights(rng).astype(np.float64)
        H, W = h.shape
        yy, xx = np.mgrid[0:H, 0:W]
        z = -h / 1000.0 + 0.6
        xyz = np.stack([(xx - W / 2) * z / 600.0, (yy - H / 2) * z / 600.0, z], axis=2)
        zone = np.isfinite(h) & (rng.random((H, W)) < 0.9)
        above = (rng.random((H, W)) < 0.02) if rng.random() < 0.5 else None
        params = SuspectParams(a_max=float(rng.choice([10, 100, 1000])), max_groups=int(rng.choice([5, 8, 40])),
                               merge_radius_px=int(rng.choice([0, 1, 3])))
        both(xyz, -1000.0 * xyz[..., 2], zone, above, params=params)


@pytest.mark.parametrize("case", ["0x0", "1x1", "3x3", "1xN", "Nx1", "all NaN", "one point", "identical points",
                                  "empty zone", "float32"])
def test_fast_equals_reference_on_degenerate_frames(case: str) -> None:
    shapes = {"0x0": (0, 0), "1x1": (1, 1), "3x3": (3, 3), "1xN": (1, 50), "Nx1": (50, 1)}
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
    both(xyz, -1000.0 * xyz[..., 2].astype(np.float64), zone)


# --------------------------------------------------------------------------------------------
# The parts on their own
# --------------------------------------------------------------------------------------------


def test_edge_surfaces_equal_the_previous_kernels(logs, real_data) -> None:
    clouds = [logs[n][0][0] for n in ("zinc_nuts-3", "raytraced", "quantized")]
    clouds.append(read_pcd(real_data / "mosd_test20.pcd").xyz)
    for xyz in clouds:
        a = 1000.0 * np.asarray(xyz, np.float64)
        valid = np.isfinite(a).all(axis=2)
        for params in (EdgeSurfaceParams(), EdgeSurfaceParams(patch_radius_px=2, min_patch_px=10, max_incidence_deg=90),
                       EdgeSurfaceParams(max_incidence_deg=30.0, side_step_mm=0.0)):
            old = ref._signed_edge_distance_reference(a, valid, params=params)
            assert np.array_equal(signed_edge_distance(a, valid, params=params), old, equal_nan=True)
            where = np.random.default_rng(1).random(valid.shape) < 0.1
            part = edge_surfaces(a, valid, params=params).distance(where)
            assert np.array_equal(part, np.where(where, old, np.nan), equal_nan=True)


def test_surfaces_and_planes_equal_the_previous_kernel(logs, real_data) -> None:
    """The surface mask, and the planes fitted again where a distance reads them (every surface's when
    asked), are the previous whole-frame kernel's bit for bit."""
    from zcut.edge_surface import _reach, _surfaces

    clouds = [logs[n][0][0] for n in ("sprockets-11", "quantized")] + [read_pcd(real_data / "mosd_test16.pcd").xyz]
    for xyz in clouds:
        a = 1000.0 * np.asarray(xyz, np.float64)
        valid = np.isfinite(a).all(axis=2)
        for params in (EdgeSurfaceParams(), EdgeSurfaceParams(patch_radius_px=2, min_patch_px=10, max_incidence_deg=90)):
            H, W = valid.shape
            cen, nrm, rms = np.zeros((H, W, 3)), np.zeros((H, W, 3)), np.empty((H, W))
            ref._patch_kernel(a, valid, params.patch_radius_px, params.min_patch_px, _reach(a, valid, params),
                              params.side_step_mm, cen, nrm, rms)
            surface = _surfaces(rms, nrm, cen, params)
            got = edge_surfaces(a, valid, params=params)
            got.distance(np.random.default_rng(5).random(valid.shape) < 0.05)  # some planes fitted first
            assert surface.any()
            np.testing.assert_array_equal(got.surface, surface)
            np.testing.assert_array_equal(got.centre, np.where(surface[..., None], cen, 0.0))
            np.testing.assert_array_equal(got.normal, np.where(surface[..., None], nrm, 0.0))


def test_local_height_and_noise_profile_equal_the_previous_code(logs) -> None:
    rng = np.random.default_rng(2)
    heights = [h for n in logs for _, h in logs[n]] + [random_heights(rng).astype(np.float64) for _ in range(30)]
    for h in heights:
        judged = np.isfinite(h) & (rng.random(h.shape) < 0.8)
        assert np.array_equal(local_height(h), ref.local_height_reference(h), equal_nan=True)
        a, b = noise_profile(h, judged), ref.noise_profile_reference(h, judged)
        for part in ("heights_mm", "sigma_mm", "step_mm"):
            assert np.array_equal(getattr(a, part), getattr(b, part), equal_nan=True)


def test_merge_compact_equals_the_previous_code() -> None:
    rng = np.random.default_rng(4)
    for _ in range(60):
        n = int(rng.integers(1, 300))
        r0 = rng.integers(0, 100, n)
        c0 = rng.integers(0, 100, n)
        boxes = np.stack([r0, c0, r0 + rng.integers(1, 6, n), c0 + rng.integers(1, 6, n)], 1)
        if rng.random() < 0.3:  # many ties
            boxes = boxes // 8 * 8
        kind = rng.integers(0, int(rng.integers(1, 6)), n)
        m = int(rng.integers(1, n + 1))
        np.testing.assert_array_equal(_merge_compact(boxes, kind, m), ref._merge_compact_reference(boxes, kind, m))


def test_sparse_components_equal_the_grown_mask_labels() -> None:
    """The components linked pixel to pixel are the grown mask's, numbered as ``ndimage.label`` does."""

    rng = np.random.default_rng(8)
    for _ in range(80):
        H, W = int(rng.integers(1, 60)), int(rng.integers(1, 60))
        m = rng.random((H, W)) < float(rng.choice([0.002, 0.02, 0.1, 0.5]))
        r = int(rng.choice([0, 1, 2, 3, 7, 20]))
        check_components(m, r)


def test_fill_blobs_equal_the_previous_kernel() -> None:
    from zcut.suspects import fill_blobs

    rng = np.random.default_rng(12)
    for _ in range(60):
        H, W = int(rng.integers(0, 50)), int(rng.integers(0, 50))
        seed = rng.random((H, W)) < float(rng.choice([0.01, 0.1, 0.3, 0.6]))
        valid = rng.random((H, W)) < 0.9
        judged = valid & (rng.random((H, W)) < 0.9)
        it = int(rng.choice([0, 1, 2, 5, 50]))
        np.testing.assert_array_equal(fill_blobs(seed, judged, valid, iterations=it),
                                      ref._fill_blobs_previous(seed, judged, valid, iterations=it))


# --------------------------------------------------------------------------------------------
# The second round (issue 32 item 5): brackets, lazy surfaces, bucket selection, residual kernel
# --------------------------------------------------------------------------------------------


def _fuzz_cloud(rng: np.random.Generator, H: int, W: int) -> np.ndarray:
    """An organized cloud (mm) of a random height field: holes, NaN, ties (quantized depth), flat
    patches, lines, single points."""
    h = random_heights(rng, H, W).astype(np.float64)
    if rng.random() < 0.4:
        h = np.round(h * float(rng.choice([1.0, 4.0]))) / float(rng.choice([1.0, 4.0]))  # quantized: ties
    if rng.random() < 0.3:
        h[:, : W // 3] = 5.0  # a perfectly flat third
    if rng.random() < 0.3:
        h[rng.random(h.shape) < float(rng.choice([0.3, 0.7]))] = np.nan  # large invalid regions
    yy, xx = np.mgrid[0:H, 0:W]
    z = 600.0 - h
    f = float(rng.choice([300.0, 600.0, 1200.0]))
    return np.stack([(xx - W / 2) * z / f, (yy - H / 2) * z / f, z], axis=2)


def test_order_pair_equals_partition() -> None:
    from zcut.edge_surface import _median_of_temporary
    from zcut.suspects.select import median, order_pair

    rng = np.random.default_rng(21)
    for t in range(400):
        n = int(rng.integers(1, 3000))
        kind = t % 6
        if kind == 0:
            x = rng.random(n)
        elif kind == 1:  # many ties
            x = rng.integers(0, 4, n) * 0.25
        elif kind == 2:  # every exponent
            x = np.abs(rng.normal(size=n)) * 10.0 ** rng.integers(-300, 300, n)
        elif kind == 3:
            x = np.full(n, 3.0)
            x[rng.integers(0, n)] = np.inf
        elif kind == 4:  # negative values: left to np.partition
            x = rng.normal(size=n)
        else:  # subnormals and zeros
            x = rng.integers(0, 3, n) * 5e-324
        if t % 7 == 0:
            x[rng.integers(0, n)] = np.nan
        if t % 11 == 0:
            x[rng.integers(0, n)] = -0.0
        a, b = median(x), _median_of_temporary(x.copy())
        assert (np.isnan(a) and np.isnan(b)) or (a == b and np.signbit(a) == np.signbit(b)), (t, a, b)
        if not np.isnan(x).any():
            k = int(rng.integers(0, n))
            k1 = min(k + 1, n - 1)
            s = np.sort(x)
            got = order_pair(x, k, k1)
            assert got == (s[k], s[k1]) and np.signbit(got[0]) == np.signbit(s[k])


def test_brackets_hold_the_closed_form_eigenvalue() -> None:
    """Where :func:`_lambda_bracket` (or :func:`_newton_fixed` then :func:`_certified`, the whole-frame
    pass's way) gives a bracket, the closed form's λ_min lies in it and whether its normal is determined
    is as said: covariances of random patches, flat, tilted to grazing, on a line,
    of one point, quantized, at every scale."""
    from zcut.edge_surface import _smallest_eigvec
    from zcut.suspects.surfaces import _certified, _lambda_bracket, _newton_fixed, _row_certified

    rng = np.random.default_rng(22)
    brackets = certified = 0
    for t, c in enumerate(patch_covariances(rng, 20000, tilts=(0.0, 0.1, 1.0, 10.0, 100.0),
                                            noises=(0.0, 1e-6, 1e-3, 0.05, 1.0), quantized_every=5, decades=4)):
        lam, nx, _, _ = _smallest_eigvec(*c)
        ok, lo, hi, fitted = _lambda_bracket(*c)
        if ok:
            brackets += 1
            assert lo <= lam <= hi, (t, lo, lam, hi)
            assert fitted == bool(np.isfinite(nx)), t
        # the whole-frame pass's way: a fixed number of Newton steps from below, then the checks; they
        # hold wherever below λ_min the steps stopped (also after fewer steps, or set back)
        sane, tr, lam_fixed = _newton_fixed(*c)
        zz = float(rng.choice([1.0, 0.25, 4e4]))
        row = (np.zeros(1, bool), np.zeros(1), np.zeros(1), np.zeros(1, bool))
        # the whole-frame pass's branchless form of both, with the ratios' bracket
        _row_certified(1, *(np.array([v]) for v in c), np.array([np.sqrt(zz)]), *row)
        if not sane:
            assert not row[0][0], t
            continue
        ok, lo, hi, fitted = _certified(*c, tr, lam_fixed)
        assert bool(row[0][0]) == ok, t
        if ok:
            assert bool(row[3][0]) == fitted, t
            assert (row[1][0], row[2][0]) == (np.sqrt(max(lo, 0.0)) / zz, np.sqrt(max(hi, 0.0)) / zz), t
        for back in (0.0, 1e-13, 1e-12, 1e-9, 1e-6, 1e-3):
            ok, lo, hi, fitted = _certified(*c, tr, lam_fixed - back * tr)
            if not ok:
                continue
            certified += 1
            assert lo <= lam <= hi, (t, back, lo, lam, hi)
            assert fitted == bool(np.isfinite(nx)), (t, back)
    assert brackets > 2000  # the test exercises brackets (3,830 of these 20,000)
    assert certified > 4000  # (5,985 of the 20,000 patches × 6 starts)


def test_row_moments_equal_the_patch_moments() -> None:
    """:func:`_row_moments` (a row's patches in vector lanes, points not in a patch adding +0.0) gives
    :func:`zcut.edge_surface._patch_moments`' count, centroid depth and covariance bit for bit, signs
    of zero included: random fields with holes, ties, flat regions, -0.0 coordinates, pixels finite
    but not valid, patch radii 1-3."""
    import math

    from zcut.edge_surface import _patch_moments
    from zcut.suspects.surfaces import _planar_row, _row_moments

    rng = np.random.default_rng(31)
    compared = 0
    for t in range(60):
        H, W = int(rng.integers(3, 40)), int(rng.integers(3, 60))
        r = int(rng.integers(1, 4))
        a = _fuzz_cloud(rng, H, W)
        if t % 3 == 0:
            a[..., 0][a[..., 0] == 0.0] = -0.0
            a[rng.random((H, W)) < 0.1, int(rng.integers(0, 3))] = -0.0
        valid = np.isfinite(a).all(axis=2)
        if t % 4 == 1:
            valid &= rng.random((H, W)) < 0.8  # finite points left out
        valid = np.ascontiguousarray(valid)
        a = np.ascontiguousarray(a)
        per_px, tan = float(rng.choice([0.0, 1e-3, 2e-3])), math.tan(math.radians(float(rng.choice([45, 80, 89.9]))))
        floor = float(rng.choice([0.0, 0.5, 1.0]))
        L, side = 2 * r + 1, (2 * r + 1) ** 2
        X, Y, Z, V = np.empty((L, W)), np.empty((L, W)), np.empty((L, W)), np.zeros((L, W), bool)
        sel = np.empty((side, W), bool)
        scratch = [np.empty(W) for _ in range(12)]
        if H <= 2 * r or W <= 2 * r:
            continue
        for i0 in range(2 * r):
            _planar_row(a, valid, i0, i0 % L, X, Y, Z, V)
        px, py, pz = np.empty(side), np.empty(side), np.empty(side)
        for i in range(r, H - r):
            _planar_row(a, valid, i + r, (i + r) % L, X, Y, Z, V)
            _row_moments(i, r, per_px, tan, floor, W, X, Y, Z, V, *scratch[:2], sel, *scratch[2:])
            nn, mz, cs = scratch[2], scratch[5], scratch[6:]
            for j in range(r, W - r):
                want = _patch_moments(a, valid, i, j, r, 1, per_px, tan, floor, px, py, pz)
                assert nn[j - r] == want[0], (t, i, j)
                if want[0] == 0:
                    continue
                got = np.array([mz[j - r]] + [c[j - r] for c in cs])
                exp = np.array([want[3]] + list(want[4:]))
                assert np.array_equal(got.view(np.int64), exp.view(np.int64)), (t, i, j, got, exp)
                compared += 1
    assert compared > 5000


def test_lazy_surfaces_equal_edge_surfaces_on_random_fields() -> None:
    """The gate, every surface and every distance of :func:`lazy_surfaces` are
    :func:`zcut.edge_surface.edge_surfaces`' bit for bit: random fields with holes, NaN, ties and flat
    patches, small and 120 x 160."""
    import math

    from zcut.edge_surface import _median_of_temporary, _patch_gate_kernel, _reach_samples
    from zcut.suspects.surfaces import lazy_surfaces

    rng = np.random.default_rng(23)
    for t in range(40):
        H, W = ((120, 160) if t % 4 == 0 else (int(rng.integers(1, 40)), int(rng.integers(1, 40))))
        a = _fuzz_cloud(rng, H, W)
        valid = np.ascontiguousarray(np.isfinite(a).all(axis=2))
        params = (EdgeSurfaceParams() if t % 3 else
                  EdgeSurfaceParams(patch_radius_px=2, min_patch_px=10, max_incidence_deg=90, min_fit_mm=0.0))
        old = edge_surfaces(a, valid, params=params)
        new = lazy_surfaces(np.ascontiguousarray(a), valid, params)
        # the gate: the previous pass's median of rms / z²
        rms, z2, steep, ratios = np.empty((H, W)), np.empty((H, W)), np.empty((H, W), bool), np.empty(H * W)
        step = _reach_samples(a, valid)
        per_px = _median_of_temporary(step) if step.size else 0.0
        tan = min(math.tan(math.radians(params.max_incidence_deg)), 1e6)
        m = _patch_gate_kernel(a, valid, params.patch_radius_px, params.min_patch_px, per_px, tan, params.side_step_mm,
                               math.cos(math.radians(params.max_incidence_deg)), rms, z2, steep, ratios)
        assert new.n_fitted == m
        if m:
            gate = params.fit_k * _median_of_temporary(ratios[:m])
            assert new._gate_k == gate or (np.isnan(gate) and np.isnan(new._gate_k))
        where = rng.random((H, W)) < 0.1
        assert np.array_equal(new.distance(where), old.distance(where), equal_nan=True)
        assert np.array_equal(new.distance(), old.distance(), equal_nan=True)
        np.testing.assert_array_equal(new.surface, old.surface)


def test_residual_kernel_equals_the_previous_kernel() -> None:
    from zcut.suspects import surface_residuals

    rng = np.random.default_rng(24)
    for t in range(80):
        H, W = ((120, 160) if t % 8 == 0 else (int(rng.integers(0, 30)), int(rng.integers(0, 30))))
        h = random_heights(rng, H, W).astype(np.float64)
        if t % 3 == 0:
            h[rng.random(h.shape) < 0.5] = np.nan
        judged = rng.random((H, W)) < 0.9
        tau = rng.choice([0.0, 0.125, 0.5]) if t % 2 else rng.choice([0.0, 0.125, 0.5, 1.0], size=(H, W))
        jump = 0.25 if t % 5 else rng.choice([0.0, 0.25, 2.0], size=(H, W))
        mb = int(rng.integers(1, 9))
        got = surface_residuals(h, judged, tau=tau, jump=jump, min_below=mb)
        want = ref._surface_residuals_previous(h, judged, tau=tau, jump=jump, min_below=mb)
        np.testing.assert_array_equal(got[0], want[0])
        assert np.array_equal(got[1], want[1], equal_nan=True)


def test_local_height_kernel_equals_the_previous_kernel() -> None:
    """Bit for bit, the sign of zero included (the median-of-five network leaves zeros to the
    insertion): small fields of few levels (ties), NaN, -0.0, and 120 x 160."""
    from zcut.suspects.noise import _local_height_kernel

    rng = np.random.default_rng(25)
    for t in range(600):
        H, W = ((120, 160) if t % 50 == 0 else (int(rng.integers(0, 14)), int(rng.integers(0, 14))))
        h = rng.integers(-3, 4, (H, W)).astype(np.float64) * float(rng.choice([1.0, 0.5, 1e-3]))
        h[rng.random((H, W)) < float(rng.choice([0.0, 0.2, 0.6]))] = np.nan
        if t % 3 == 0:
            h[rng.random((H, W)) < 0.3] *= -0.0
        got, want = np.empty((H, W)), np.empty((H, W))
        _local_height_kernel(h, got)
        ref._local_height_kernel_previous(h, want)
        np.testing.assert_array_equal(got.view(np.int64), want.view(np.int64))


def test_stable_argsort_equals_numpy() -> None:
    from zcut.suspects.select import stable_argsort

    rng = np.random.default_rng(26)
    for t in range(400):
        n = int(rng.integers(0, 3000))
        x = [rng.normal(size=n), np.round(rng.normal(size=n) * 3) / 4, rng.integers(-2, 3, n) * 0.0,
             -np.abs(rng.normal(size=n)) * 1e300, rng.integers(0, 3, n) * 5e-324][t % 5].astype(np.float64)
        if n and t % 7 == 0:
            x[rng.integers(0, n)] = np.inf
        if n and t % 11 == 0:
            x[rng.integers(0, n)] = -np.inf
        if n and t % 13 == 0:
            x[rng.integers(0, n)] = np.nan
        if n and t % 5 == 2:
            x[rng.random(n) < 0.5] *= -1.0  # -0.0 among 0.0
        np.testing.assert_array_equal(stable_argsort(x), np.argsort(x, kind="stable"))


def test_sampled_differences_in_two_sweeps_equal_the_eight() -> None:
    from zcut.suspects.noise import _sampled_both, _sampled_differences

    rng = np.random.default_rng(27)
    for t in range(300):
        h = random_heights(rng).astype(np.float64)
        if t % 2:
            h = np.round(h)
        if t % 3 == 0:
            h[rng.random(h.shape) < 0.5] = np.nan
        judged = np.isfinite(h) & (rng.random(h.shape) < 0.8)
        most = int(rng.choice([1, 2, 3, 7, 50, 200_000]))
        got = _sampled_both(h, judged, most)
        want = (*_sampled_differences(h, judged, 2, most), *_sampled_differences(h, judged, 1, most))
        for g, w in zip(got, want):
            np.testing.assert_array_equal(g.view(np.int64), w.view(np.int64))
