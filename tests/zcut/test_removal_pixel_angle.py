"""The pixel angle's kernel (:func:`zcut.removal._pixel_steps`) equals its numpy version bit for bit.

Both give the steps ``|Δ(x / z)|`` to the right neighbour, then ``|Δ(y / z)|`` to the one below, finite and not 0,
in the same order; :func:`zcut.removal.pixel_angle` takes their median. Checked on a pinhole cloud, clouds with
large invalid (NaN) regions, zero and negative depths, ties, float32 and float64, the image's last row and column,
and degenerate inputs (no pixel, all NaN, one pixel), and on the real clouds when they are present.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from zcut.removal import _pixel_steps, _pixel_steps_numpy, pixel_angle


def _pinhole(h, w, rng, *, f=500.0, noise=0.0):
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    z = 0.8 + 0.2 * rng.random((h, w)) + noise * rng.standard_normal((h, w))
    return np.stack([(u - w / 2) / f * z, (v - h / 2) / f * z, z], axis=-1)


def _same(a, flat):
    flat = np.asarray(flat, np.int64)
    got, want = _pixel_steps(a, flat), _pixel_steps_numpy(a, flat)
    assert got.dtype == want.dtype == np.float64
    assert np.array_equal(got, want), f"{int(np.sum(got != want)) if got.shape == want.shape else 'shapes'} differ"
    med = pixel_angle(a, flat)
    ref = float(np.median(want)) if want.size else float("nan")
    assert (np.isnan(med) and np.isnan(ref)) or med == ref


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("case", ["pinhole", "half NaN", "bands", "zeros and signs", "ties", "edges"])
def test_the_kernel_equals_numpy(dtype, case):
    rng = np.random.default_rng(7)
    h, w = 60, 80
    a = _pinhole(h, w, rng, noise=1e-3)
    flat = rng.choice(h * w, size=1500, replace=False)
    if case == "half NaN":
        a[:, : w // 2] = np.nan
    elif case == "bands":
        a[::4] = np.nan
        a[:, 30:50, 2] = np.nan
    elif case == "zeros and signs":
        a[rng.random((h, w)) < 0.2, 2] = 0.0
        a[rng.random((h, w)) < 0.2, 0] = 0.0
        a[rng.random((h, w)) < 0.2] *= -1.0
        a[5, :, 2] = np.inf
    elif case == "ties":
        a = np.round(a, 2)  # many equal steps and many zero steps
    else:
        flat = np.concatenate([np.arange(w - 3, h * w, w), np.arange((h - 1) * w, h * w)])  # the last column and row
    _same(np.ascontiguousarray(a.astype(dtype)), np.sort(flat))
    _same(np.ascontiguousarray(a.astype(dtype)), flat)  # any order


def test_degenerate():
    rng = np.random.default_rng(3)
    a = _pinhole(10, 12, rng).astype(np.float32)
    _same(a, np.zeros(0, np.int64))
    _same(np.full_like(a, np.nan), np.arange(a.shape[0] * a.shape[1]))
    _same(a[:1, :1], np.array([0]))
    _same(a, np.array([5]))
    assert pixel_angle(a, np.array([5])) == pytest.approx(1.0 / 500.0, rel=1e-5)


def test_real_clouds():
    """The real organized clouds (docs/real_data.md): every valid pixel, and a subsample."""
    from replay.logs.pcd import read_pcd

    root = Path(os.environ.get("ZCUT_REAL_DATA", "/work/shared/data/real"))
    clouds = sorted(root.glob("*.pcd")) if root.is_dir() else []
    if not clouds:
        pytest.skip("no real clouds")
    for path in clouds:
        xyz = read_pcd(path).xyz
        ok = np.flatnonzero(np.isfinite(xyz).all(axis=-1).reshape(-1))
        _same(np.ascontiguousarray(xyz), ok)
        _same(np.ascontiguousarray(xyz), ok[::7])
