"""ZCutParams: validation, the ρ form (paper eq. 5) and the Section 5.4 geometry rules."""

from __future__ import annotations

import math

import pytest

from zcut import ParameterError, ZCutParams
from zcut.params import (
    NOMINAL_MAX_DEPTH_MM,
    NOMINAL_RHO_THR,
    NOMINAL_STEP_MM,
    a_max_from_camera,
)


def test_nominal_values_are_the_papers() -> None:
    assert (NOMINAL_STEP_MM, NOMINAL_MAX_DEPTH_MM, NOMINAL_RHO_THR) == (0.2, 30.0, 0.07)
    p = ZCutParams.nominal(a_max=3000)
    assert (p.step, p.max_depth, p.a_max) == (0.2, 30.0, 3000.0)
    assert p.max_area == pytest.approx(210.0)
    assert p.n_levels == 150  # 30 / 0.2 = 149.99999999999997: the 1e-9 of docs/filters.md makes it 150
    assert p.rho_thr == pytest.approx(0.07)


def test_params_are_frozen_floats() -> None:
    p = ZCutParams(step=1, max_depth=3, max_area=10)
    assert isinstance(p.step, float) and isinstance(p.max_area, float)
    assert p.a_max is None and p.rho_thr is None
    with pytest.raises(AttributeError):
        p.step = 0.5  # type: ignore[misc]
    assert ZCutParams(0.2, 0.0, math.inf).max_area == math.inf  # no area limit, no levels


def test_from_rho() -> None:
    p = ZCutParams.from_rho(step=0.2, max_depth=30.0, rho_thr=0.05, a_max=2000)
    assert p.max_area == pytest.approx(100.0) and p.a_max == 2000.0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(step=0.0, max_depth=1, max_area=1), r"ZCutParams\.step .*got 0\.0"),
        (dict(step=-1, max_depth=1, max_area=1), r"ZCutParams\.step .*got -1"),
        (dict(step=math.nan, max_depth=1, max_area=1), r"ZCutParams\.step .*got nan"),
        (dict(step=math.inf, max_depth=1, max_area=1), r"ZCutParams\.step .*got inf"),
        (dict(step="1", max_depth=1, max_area=1), r"ZCutParams\.step .*got '1'"),
        (dict(step=True, max_depth=1, max_area=1), r"ZCutParams\.step .*got True"),
        (dict(step=1, max_depth=-0.5, max_area=1), r"ZCutParams\.max_depth .*got -0\.5"),
        (dict(step=1, max_depth=math.inf, max_area=1), r"ZCutParams\.max_depth .*got inf"),
        (dict(step=1, max_depth=None, max_area=1), r"ZCutParams\.max_depth .*got None"),
        (dict(step=1, max_depth=1, max_area=0), r"ZCutParams\.max_area .*got 0"),
        (dict(step=1, max_depth=1, max_area=math.nan), r"ZCutParams\.max_area .*got nan"),
        (dict(step=1, max_depth=1, max_area=5, a_max=0), r"ZCutParams\.a_max .*got 0"),
        (dict(step=1, max_depth=1, max_area=5, a_max=math.inf), r"ZCutParams\.a_max .*got inf"),
    ],
)
def test_bad_params(kwargs: dict, match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        ZCutParams(**kwargs)


def test_from_rho_bad() -> None:
    with pytest.raises(ParameterError, match=r"rho_thr .*got -0\.07"):
        ZCutParams.from_rho(step=0.2, max_depth=30, rho_thr=-0.07, a_max=100)
    with pytest.raises(ParameterError, match=r"a_max .*got 0"):
        ZCutParams.from_rho(step=0.2, max_depth=30, rho_thr=0.07, a_max=0)


def test_from_geometry_defaults_lie_in_the_ranges() -> None:
    p = ZCutParams.from_geometry(p_min_mm=10.0, bin_height_mm=200.0, a_max_px=3000.0)
    assert 0.01 * 10 <= p.step <= 0.04 * 10
    assert p.step == pytest.approx(0.2)  # the paper's nominal step for a 10 mm part
    assert 10.0 <= p.max_depth <= 0.7 * 200
    assert p.max_depth == pytest.approx(30.0)  # 3 p_min
    assert 0.05 * 3000 <= p.max_area <= 0.075 * 3000
    assert p.rho_thr == pytest.approx(0.07) and p.a_max == 3000.0
    # a shallow bin clips d_max to 0.7 b_h
    assert ZCutParams.from_geometry(p_min_mm=20, bin_height_mm=50, a_max_px=100).max_depth == pytest.approx(35.0)
    # a bin shallower than the part: the range is empty, d_max falls back to p_min
    assert ZCutParams.from_geometry(p_min_mm=20, bin_height_mm=10, a_max_px=100).max_depth == pytest.approx(20.0)


def test_from_geometry_overrides() -> None:
    p = ZCutParams.from_geometry(p_min_mm=10, bin_height_mm=200, a_max_px=1000, step_mm=0.3,
                                 max_depth_mm=50, rho_thr=0.06, strict=True)
    assert (p.step, p.max_depth) == (0.3, 50.0) and p.max_area == pytest.approx(60.0)
    # outside the ranges: accepted unless strict
    p = ZCutParams.from_geometry(p_min_mm=10, bin_height_mm=200, a_max_px=1000, step_mm=1.0,
                                 max_depth_mm=5, rho_thr=0.2)
    assert (p.step, p.max_depth) == (1.0, 5.0) and p.max_area == pytest.approx(200.0)
    # the range edges themselves are inside (float rounding of 0.01 * p_min forgiven)
    ZCutParams.from_geometry(p_min_mm=7, bin_height_mm=100, a_max_px=1000, step_mm=0.07,
                             max_depth_mm=70, rho_thr=0.075, strict=True)


@pytest.mark.parametrize(
    ("override", "match"),
    [
        (dict(step_mm=0.05), r"step_mm=0\.05 is outside .*\[0\.1, 0\.4\]"),
        (dict(step_mm=0.5), r"step_mm=0\.5 is outside"),
        (dict(max_depth_mm=9.0), r"max_depth_mm=9\.0 is outside .*\[10, 140\]"),
        (dict(max_depth_mm=141.0), r"max_depth_mm=141\.0 is outside"),
        (dict(rho_thr=0.04), r"rho_thr=0\.04 is outside .*\[0\.05, 0\.075\]"),
        (dict(rho_thr=0.1), r"rho_thr=0\.1 is outside"),
        (dict(bin_height_mm=10.0), r"bin_height_mm=10\.0 gives an empty max_depth range"),
        (dict(step_mm=-0.2), r"step_mm .*got -0\.2"),
        (dict(p_min_mm=0), r"p_min_mm .*got 0"),
        (dict(a_max_px=math.nan), r"a_max_px .*got nan"),
    ],
)
def test_from_geometry_strict(override: dict, match: str) -> None:
    kwargs = dict(p_min_mm=10.0, bin_height_mm=200.0, a_max_px=1000.0, strict=True)
    with pytest.raises(ParameterError, match=match):
        ZCutParams.from_geometry(**{**kwargs, **override})


def test_a_max_from_camera() -> None:
    # a 40 x 25 mm face at 1 m, fx = fy = 2000 px: one pixel covers 0.5 x 0.5 mm -> 4000 px
    assert a_max_from_camera(1000.0, distance_mm=1000.0, fx_px=2000.0, fy_px=2000.0) == pytest.approx(4000.0)
    # twice as far: a quarter of the pixels
    assert a_max_from_camera(1000.0, distance_mm=2000.0, fx_px=2000.0, fy_px=2000.0) == pytest.approx(1000.0)
    assert a_max_from_camera(100.0, distance_mm=500.0, fx_px=1000.0, fy_px=2000.0) == pytest.approx(800.0)
    with pytest.raises(ParameterError, match=r"distance_mm .*got 0"):
        a_max_from_camera(100.0, distance_mm=0, fx_px=1000.0, fy_px=1000.0)
    with pytest.raises(ParameterError, match=r"face_area_mm2 .*got -1"):
        a_max_from_camera(-1, distance_mm=500, fx_px=1000.0, fy_px=1000.0)
