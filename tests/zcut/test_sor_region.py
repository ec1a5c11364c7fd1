"""SOR's top region in two passes (zcut.sor_region): the same z_max, mask and box as the NumPy expressions
replay.pipeline.zone.sor_region was written with (round of 2026-12-07a, h/rep2), on random heights with NaN,
±inf and signed zeros, values exactly on the threshold, float32 and strided input, empty, one-row, one-column,
all-NaN and one-pixel images, and the real scans' heights."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from replay.pipeline.zone import _sor_in_box, _top_region, sor_region, zone_box
from zcut.params import ZCutParams
from zcut.sor import sor_outliers
from zcut.sor_region import finite_max, region_at_or_above


def _finite_max_numpy(h: np.ndarray) -> float | None:
    finite = np.isfinite(h)
    if not finite.any():
        return None
    return float(np.max(h, where=finite, initial=-np.inf))


def _region_numpy(h: np.ndarray, zone: np.ndarray, zcut: ZCutParams) -> np.ndarray:
    # replay.pipeline.zone.sor_region before this round, literally
    finite = np.isfinite(h)
    if not finite.any():
        return np.zeros_like(zone)
    z_max = float(np.max(h, where=finite, initial=-np.inf))
    threshold = z_max - zcut.n_levels * zcut.step
    with np.errstate(invalid="ignore"):
        return zone & (h >= threshold)


def _heights(rng: np.random.Generator, shape: tuple[int, int], *, nan: float, inf: str) -> np.ndarray:
    h = rng.normal(-600.0, 15.0, shape).round(1)  # rounded: many values exactly on a threshold
    h[rng.random(shape) < nan] = np.nan
    if h.size and inf in ("+", "both"):
        h.flat[rng.integers(h.size)] = np.inf
    if h.size and inf in ("-", "both"):
        h.flat[rng.integers(h.size)] = -np.inf
    if h.size > 4:
        h.flat[rng.integers(h.size, size=2)] = [0.0, -0.0]
    return h


def _same(h: np.ndarray, zone: np.ndarray, zcut: ZCutParams) -> None:
    want = _region_numpy(h, zone, zcut)
    got = sor_region(h, zone, zcut)
    assert got.dtype == want.dtype and got.shape == want.shape
    assert np.array_equal(got, want)
    mask, box = _top_region(h, zone, zcut)
    assert np.array_equal(mask, want)
    assert box == zone_box(want)


@pytest.mark.parametrize("shape", [(37, 53), (1, 80), (80, 1), (1, 1), (0, 5), (5, 0), (200, 3)])
@pytest.mark.parametrize("nan", [0.0, 0.3, 1.0])
@pytest.mark.parametrize("inf", ["none", "+", "-", "both"])
def test_the_region_and_its_box_are_numpys(shape, nan, inf):
    rng = np.random.default_rng([sum(shape), int(10 * nan), "none+-both".index(inf)])
    zcut = ZCutParams(step=0.2, max_depth=30.0, max_area=100.0)
    for trial in range(4):
        h = _heights(rng, shape, nan=nan, inf=inf)
        zone = rng.random(shape) < (0.1, 0.5, 0.9, 1.0)[trial]
        zone &= np.isfinite(h) if trial % 2 else True
        assert finite_max(h) == _finite_max_numpy(h)
        _same(h, zone, zcut)


def test_values_on_the_threshold_float32_and_strided_input():
    rng = np.random.default_rng(5)
    zcut = ZCutParams(step=0.5, max_depth=2.0, max_area=100.0)  # 4 levels: the threshold is z_max - 2.0
    h = np.full((40, 60), -500.0)
    h[10, 20] = -490.0
    h[5:15, 5:15] = -492.0  # exactly on the threshold: in the region
    h[30:, 40:] = np.nextafter(-492.0, -np.inf)  # just under it: out
    zone = np.ones_like(h, dtype=bool)
    _same(h, zone, zcut)
    assert sor_region(h, zone, zcut)[5:15, 5:15].all() and not sor_region(h, zone, zcut)[30:, 40:].any()
    _same(h.astype(np.float32), zone, zcut)  # float32 compares in float32, as NumPy does
    big = _heights(rng, (80, 120), nan=0.2, inf="none")
    bigzone = rng.random((80, 120)) < 0.6
    _same(big[::2, 1::3], bigzone[::2, 1::3], zcut)  # views, not C order
    _same(np.asfortranarray(big), bigzone, zcut)
    _same(big, bigzone.astype(np.uint8), zcut)  # a zone that is not bool: NumPy's expression
    assert finite_max(big.astype(np.float32)) == _finite_max_numpy(big.astype(np.float32))


def test_no_finite_height_gives_no_region():
    zcut = ZCutParams(step=0.2, max_depth=30.0, max_area=100.0)
    for fill in (np.nan, np.inf, -np.inf):
        h = np.full((6, 7), fill)
        zone = np.ones((6, 7), bool)
        assert finite_max(h) is None
        mask, box = _top_region(h, zone, zcut)
        assert not mask.any() and box is None and mask.shape == (6, 7)
    h = np.array([[np.nan, np.inf], [-np.inf, np.nan]])
    assert finite_max(h) is None


def test_region_at_or_above_on_its_own():
    h = np.array([[1.0, np.nan, 3.0], [0.5, 2.0, -1.0]])
    zone = np.array([[True, True, False], [True, True, True]])
    mask, box = region_at_or_above(h, zone, 1.0)
    assert mask.tolist() == [[True, False, False], [False, True, False]]
    assert box == (slice(0, 2), slice(0, 2))
    mask, box = region_at_or_above(h, zone, 5.0)
    assert not mask.any() and box is None


def test_the_real_scans_heights(real_data: Path):
    from replay.logs.pcd import read_pcd

    rng = np.random.default_rng(11)
    scans = [-1000.0 * read_pcd(p).xyz[..., 2].astype(np.float64) for p in sorted(real_data.glob("*.pcd"))]
    assert scans
    for zcut in (ZCutParams(step=0.2, max_depth=30.0, max_area=100.0),
                 ZCutParams(step=1.0, max_depth=200.0, max_area=100.0)):
        for h in scans:
            valid = np.isfinite(h)
            _same(h, valid, zcut)
            _same(h, valid & (rng.random(h.shape) < 0.5), zcut)


@pytest.mark.parametrize("kind", ["blob", "scattered", "empty"])
def test_sor_in_the_known_box_is_sor_on_the_zone(kind):
    rng = np.random.default_rng(21)
    h, w = 60, 80
    v, u = np.mgrid[0:h, 0:w]
    xyz = np.stack([(u - 40) * 0.001, (v - 30) * 0.001, 0.5 + rng.normal(0, 0.002, (h, w))], axis=2).astype(np.float32)
    xyz[rng.random((h, w)) < 0.05] = np.nan
    zone = np.zeros((h, w), bool)
    if kind == "blob":
        zone[10:50, 20:70] = True
    elif kind == "scattered":
        zone = rng.random((h, w)) < 0.4
    zone &= np.isfinite(xyz).all(axis=2)
    want = sor_outliers(np.where(zone[..., None], xyz, np.nan).astype(np.float32), k=4, std_ratio=1.0) & zone
    got = _sor_in_box(xyz, zone, zone_box(zone), k=4, std_ratio=1.0, convention="pcl")
    assert np.array_equal(got, want)
