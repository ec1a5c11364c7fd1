"""SOR's top region and its box in one pass (zcut.sor_region.region_at_or_above, h/rep2's kernel): the same mask
and box as the NumPy expressions (``zone & (height >= threshold)``, replay.pipeline.zone.zone_box) on random
heights with NaN, ±inf and signed zeros, values exactly on the threshold, float32, strided and Fortran-order
input, a zone that is not bool, empty, one-row, one-column and one-pixel images; SOR in the known box is SOR on the
zone."""

from __future__ import annotations

import zlib

import numpy as np
import pytest

from replay.pipeline.zone import _sor_on_zone, zone_box
from zcut.sor import sor_outliers
from zcut.sor_region import region_at_or_above


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


def _same(h: np.ndarray, zone: np.ndarray, threshold: float) -> None:
    with np.errstate(invalid="ignore"):
        want = zone & (h >= threshold)
    mask, box = region_at_or_above(h, zone, threshold)
    assert mask.dtype == want.dtype and mask.shape == want.shape and np.array_equal(mask, want)
    assert box == zone_box(want)


@pytest.mark.parametrize("shape", [(37, 53), (1, 80), (80, 1), (1, 1), (0, 5), (5, 0), (200, 3)])
@pytest.mark.parametrize("nan", [0.0, 0.3, 1.0])
@pytest.mark.parametrize("inf", ["none", "+", "both"])
def test_the_region_and_its_box_are_numpys(shape, nan, inf):
    rng = np.random.default_rng(zlib.crc32(repr((shape, nan, inf)).encode()))  # the same seeds in every process
    for trial in range(4):
        h = _heights(rng, shape, nan=nan, inf=inf)
        zone = rng.random(shape) < (0.1, 0.5, 0.9, 1.0)[trial]
        zone &= np.isfinite(h) if trial % 2 else True
        for threshold in (-600.0, -630.0, -np.inf, np.inf, 0.0, -0.0, np.nan):
            _same(h, zone, threshold)


def test_values_on_the_threshold_float32_and_strided_input():
    rng = np.random.default_rng(5)
    h = np.full((40, 60), -500.0)
    h[10, 20] = -490.0
    h[5:15, 5:15] = -492.0  # exactly on the threshold: in the region
    h[30:, 40:] = np.nextafter(-492.0, -np.inf)  # just under it: out
    zone = np.ones_like(h, dtype=bool)
    _same(h, zone, -492.0)
    mask, box = region_at_or_above(h, zone, -492.0)
    assert mask[5:15, 5:15].all() and not mask[30:, 40:].any() and box == (slice(5, 15), slice(5, 21))
    _same(h.astype(np.float32), zone, -492.0)  # float32 compares in float32, as NumPy does
    big = _heights(rng, (80, 120), nan=0.2, inf="none")
    bigzone = rng.random((80, 120)) < 0.6
    _same(big[::2, 1::3], bigzone[::2, 1::3], -605.0)  # views, not C order
    _same(np.asfortranarray(big), bigzone, -605.0)
    _same(big, bigzone.astype(np.uint8), -605.0)  # a zone that is not bool: NumPy's expression


def test_region_at_or_above_on_its_own():
    h = np.array([[1.0, np.nan, 3.0], [0.5, 2.0, -1.0]])
    zone = np.array([[True, True, False], [True, True, True]])
    mask, box = region_at_or_above(h, zone, 1.0)
    assert mask.tolist() == [[True, False, False], [False, True, False]]
    assert box == (slice(0, 2), slice(0, 2))
    mask, box = region_at_or_above(h, zone, 5.0)
    assert not mask.any() and box is None


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
    for box in (False, zone_box(zone)):
        got = _sor_on_zone(xyz, zone, whole=False, box=box, k=4, std_ratio=1.0, convention="pcl")
        assert np.array_equal(got, want)
