"""The suspects' fifth round (issue 32, item 5): the floating detector without frame-sized temporaries
and the reach's median without its samples' array give the previous code's values bit for bit."""

from __future__ import annotations

import importlib

import numpy as np
import pytest
from test_suspects import random_heights

from zcut.edge_surface import _reach_samples
from zcut.params import SuspectParams
from zcut.suspects import _reference as ref
from zcut.suspects import noise_profile
from zcut.suspects.floating import floating_components
from zcut.suspects.select import median
from zcut.suspects.surfaces import reach_median

surfaces = importlib.import_module("zcut.suspects.surfaces")


def _floating_case(rng: np.random.Generator, H: int, W: int) -> tuple[np.ndarray, ...]:
    h = random_heights(rng, H, W).astype(np.float64)
    if rng.random() < 0.3:  # floating plateaus, some touching the border
        for _ in range(int(rng.integers(1, 8))):
            y, x = int(rng.integers(-2, H)), int(rng.integers(-2, W))
            h[max(y, 0):y + int(rng.integers(1, 5)), max(x, 0):x + int(rng.integers(1, 5))] += rng.uniform(1, 9)
    if rng.random() < 0.3:
        h = np.round(h * 2.0) / 2.0  # ties
    if rng.random() < 0.2:
        h[rng.random(h.shape) < 0.05] = 0.0
        h[rng.random(h.shape) < 0.05] = -0.0
    valid = np.isfinite(h)
    if rng.random() < 0.3:  # a height the z-cut reads but the cloud does not measure, and the reverse
        h[rng.random(h.shape) < 0.02] = np.inf
    zone = valid & (rng.random(h.shape) < (1.0 if rng.random() < 0.5 else 0.8))
    if rng.random() < 0.3:
        zone[: H // 3] = False
    rough = zone & (rng.random(h.shape) < float(rng.choice([0.0, 0.1, 0.5])))
    return h, zone, valid, rough


@pytest.mark.parametrize("seed", range(4))
def test_floating_components_equal_the_reference(seed: int) -> None:
    rng = np.random.default_rng(500 + seed)
    n_kept = 0
    for t in range(60):
        H, W = ((int(rng.integers(1, 12)), int(rng.integers(1, 12))) if t % 5 == 0
                else (int(rng.integers(20, 90)), int(rng.integers(20, 120))))
        h, zone, valid, rough = _floating_case(rng, H, W)
        ctx = np.where(zone, h, np.nan)
        profile = noise_profile(np.where(np.isfinite(ctx), ctx, np.nan), zone)
        params = SuspectParams(floating_rho=float(rng.choice([0.05, 0.15, 0.5])),
                               plain_rho=float(rng.choice([0.01, 0.05])))
        a_max = float(rng.choice([0.01 * H * W, 50.0, 400.0]))
        step = float(rng.choice([0.2, 0.5, 1.0]))
        mask, at, gap = floating_components(np.ascontiguousarray(h), zone, valid, rough, params, a_max, step, profile)
        mask_r, gap_r = ref.floating_components_reference(h, zone, valid, rough, params, a_max, step, profile)
        np.testing.assert_array_equal(mask, mask_r)
        np.testing.assert_array_equal(at, np.flatnonzero(mask_r))
        assert np.array_equal(gap, gap_r.ravel()[at], equal_nan=True)
        assert np.isnan(np.delete(gap_r.ravel(), at)).all()
        n_kept += int(mask.sum())
    assert n_kept > 0  # the cases hold floating components


def _cloud(rng: np.random.Generator, H: int, W: int, quantum: float) -> np.ndarray:
    h = random_heights(rng, H, W).astype(np.float64)
    yy, xx = np.mgrid[0:H, 0:W]
    z = 600.0 - h
    if quantum:
        z = np.round(z / quantum) * quantum
    f = float(rng.choice([300.0, 600.0, 1200.0]))
    xyz = np.stack([(xx - W / 2) * z / f, (yy - H / 2) * z / f, z], axis=2)
    if quantum:
        xyz[..., :2] = np.round(xyz[..., :2] / quantum) * quantum  # few distinct samples: ties
    if rng.random() < 0.3:
        xyz[rng.random((H, W)) < float(rng.choice([0.3, 0.9]))] = np.nan
    return np.ascontiguousarray(xyz)


def _old(a: np.ndarray, valid: np.ndarray) -> float:
    step = _reach_samples(a, valid)
    return median(step) if step.size else 0.0


def test_reach_median_equals_the_median_of_the_samples(monkeypatch) -> None:
    """Smooth, quantized and sparse clouds, frames too small for a pilot, and clouds whose pilot rows
    (every 16th) lie elsewhere than the rest (the window misses: every sample is stored, as before)."""
    calls = []
    monkeypatch.setattr(surfaces, "_reach_samples", lambda a, v: calls.append(1) or _reach_samples(a, v))
    monkeypatch.setattr(surfaces, "_FRESH_BYTES", 0)  # the window at every size (by default above 2 M pixels)
    rng = np.random.default_rng(31)
    for t in range(40):
        H, W = ((int(rng.integers(1, 10)), int(rng.integers(1, 10))) if t % 4 == 0
                else (int(rng.integers(40, 200)), int(rng.integers(40, 260))))
        a = _cloud(rng, H, W, float(rng.choice([0.0, 0.0, 0.5, 2.0])))
        if t % 7 == 3:
            a[::16, :, 0] *= 3.0  # the pilot's rows: samples three times as large
        if t % 9 == 4:
            a[:, :, 2] = np.where(rng.random((H, W)) < 0.1, 0.0, a[:, :, 2])  # |z| = 0: inf samples, left out
        valid = np.ascontiguousarray(np.isfinite(a).all(axis=2))
        new = reach_median(a, valid)
        old = _old(a, valid)
        assert new == old or (np.isnan(new) and np.isnan(old)), (t, new, old)
    assert 0 < len(calls) < 40  # some took the window, some every sample


def test_reach_median_of_the_real_scans_and_empty(real_data, monkeypatch) -> None:
    from replay.logs.pcd import read_pcd

    for pcd in sorted(real_data.glob("*.pcd")):
        a = read_pcd(pcd).xyz.astype(np.float64) * 1000.0
        valid = np.ascontiguousarray(np.isfinite(a).all(axis=2))
        assert reach_median(a, valid) == _old(a, valid), pcd.name
        with monkeypatch.context() as m:
            m.setattr(surfaces, "_FRESH_BYTES", 0)
            assert reach_median(a, valid) == _old(a, valid), pcd.name
    a = np.full((40, 50, 3), np.nan)
    assert reach_median(a, np.zeros((40, 50), bool)) == 0.0


def test_fused_passes_equal_the_numpy_they_replace() -> None:
    """suspects()' one-pass kernels (τ and the jump, rough, the grouping's strength, the lookup's
    nan_to_num) against the numpy they replace, on values with NaN, ±inf, ±0 and ties."""
    union = importlib.import_module("zcut.suspects.union")
    rng = np.random.default_rng(41)
    special = np.array([np.nan, np.inf, -np.inf, 0.0, -0.0, 0.1, 0.5, 2.0, 1e308, 5e-324])
    for _ in range(20):
        shape = (int(rng.integers(1, 30)), int(rng.integers(1, 30)))

        def field(shape: tuple[int, int] = shape) -> np.ndarray:
            x = rng.normal(0, 1, shape) * float(rng.choice([0.01, 1.0, 100.0]))
            pick = rng.random(shape) < 0.3
            x[pick] = rng.choice(special, int(pick.sum()))
            return x

        sigma, residual, gap = field(), field(), field()
        k, min_res, jump_mm = float(rng.choice([0.0, 5.0, 1e300])), float(rng.choice([0.5, 0.1])), 2.0
        tau, jump = np.empty(shape), np.empty(shape)
        union._thresholds(sigma, k, min_res, jump_mm, tau, jump)
        with np.errstate(over="ignore", invalid="ignore"):
            ks = k * sigma
        assert np.array_equal(tau, np.maximum(min_res, ks), equal_nan=True)
        assert np.array_equal(jump, np.maximum(jump_mm, ks), equal_nan=True)
        tau = np.where(rng.random(shape) < 0.2, field(), tau)
        zone = rng.random(shape) < 0.7
        rough = np.empty(shape, bool)
        union._rough(zone, residual, tau, rough)
        np.testing.assert_array_equal(rough, zone & ~(np.abs(residual) <= tau))
        strength = np.empty(shape)
        union._gap_ratio(gap, tau, min_res, strength)
        with np.errstate(all="ignore"):
            want = np.abs(gap) / np.where(np.isfinite(tau) & (tau > 0), tau, min_res)
        assert np.array_equal(strength, want, equal_nan=True)
        h = field()
        want = np.nan_to_num(h, nan=-3.5)
        union._nan_to_num(h, -3.5)
        np.testing.assert_array_equal(h, want)
