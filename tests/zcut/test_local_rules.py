"""zcut.local_rules: Basler's 3 x 3 rule and the mixed-pixel test, fast kernel against the literal
numpy reference (bit for bit), hand-checked cases, the parameters' edges and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from bank_clouds import KINDS, assert_equals_reference, degenerate_clouds, pinhole, random_cloud
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from zcut import (
    InputShapeError,
    MixedPixelParams,
    ParameterError,
    WindowParams,
    mixed_pixel_outliers,
    mixed_pixel_outliers_reference,
    mixed_pixel_stage,
    window_outliers,
    window_outliers_reference,
    window_stage,
)

CASES = [(seed, kind) for kind in KINDS for seed in range(10)]
WINDOW_SETTINGS = [(0, 0.01), (1, 0.0), (3, 0.005), (3, 0.5), (5, 0.02), (8, 0.25), (8, 1.0)]
ANGLES = [0.0, 1.0, 8.0, 30.0, 60.0, 89.0, 90.0]


# ------------------------------------------------------------------------------------------------
# fast = reference
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("seed", "kind"), CASES)
def test_window_equals_reference(seed: int, kind: str) -> None:
    xyz = random_cloud(seed, kind)
    for min_inliers, tol in WINDOW_SETTINGS:
        got = window_outliers(xyz, min_inliers=min_inliers, rel_tolerance=tol)
        want = window_outliers_reference(xyz, min_inliers=min_inliers, rel_tolerance=tol)
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize(("seed", "kind"), CASES)
def test_mixed_pixel_equals_reference(seed: int, kind: str) -> None:
    xyz = random_cloud(seed, kind)
    for angle in ANGLES:
        np.testing.assert_array_equal(mixed_pixel_outliers(xyz, min_angle_deg=angle),
                                      mixed_pixel_outliers_reference(xyz, min_angle_deg=angle))


@pytest.mark.parametrize("name", list(degenerate_clouds()))
def test_degenerate_clouds(name: str) -> None:
    xyz = degenerate_clouds()[name]
    for min_inliers, tol in WINDOW_SETTINGS:
        assert_equals_reference(window_outliers, window_outliers_reference, xyz, min_inliers=min_inliers,
                                rel_tolerance=tol)
    for angle in ANGLES:
        assert_equals_reference(mixed_pixel_outliers, mixed_pixel_outliers_reference, xyz, min_angle_deg=angle)
    if name.startswith("identical"):  # every neighbour at the same depth, every segment of length 0
        assert not window_outliers(xyz, min_inliers=3, rel_tolerance=0.0).any()
        assert not mixed_pixel_outliers(xyz, min_angle_deg=89.0).any()


@settings(max_examples=80, deadline=None)
@given(
    xyz=arrays(np.float64, st.tuples(st.integers(1, 6), st.integers(1, 6), st.just(3)),
               elements=st.one_of(st.sampled_from([0.0, 1.0, -1.0, 0.5, 2.0, np.nan, np.inf]),
                                  st.floats(-10, 10, allow_nan=False, width=64))),
    min_inliers=st.integers(0, 8),
    tol=st.sampled_from([0.0, 0.5, 1.0, 0.125]),
    angle=st.sampled_from([0.0, 10.0, 45.0, 90.0]),
)
def test_property_equals_reference(xyz: np.ndarray, min_inliers: int, tol: float, angle: float) -> None:
    valid = np.isfinite(xyz).all(axis=2)
    got = window_outliers(xyz, min_inliers=min_inliers, rel_tolerance=tol)
    assert not (got & ~valid).any()
    np.testing.assert_array_equal(got, window_outliers_reference(xyz, min_inliers=min_inliers, rel_tolerance=tol))
    got = mixed_pixel_outliers(xyz, min_angle_deg=angle)
    assert not (got & ~valid).any()
    np.testing.assert_array_equal(got, mixed_pixel_outliers_reference(xyz, min_angle_deg=angle))


def test_float32_is_judged_in_float64() -> None:
    rng = np.random.default_rng(3)
    xyz = pinhole(rng, 30, 40).astype(np.float32)
    np.testing.assert_array_equal(window_outliers(xyz, min_inliers=4, rel_tolerance=0.002),
                                  window_outliers(xyz.astype(np.float64), min_inliers=4, rel_tolerance=0.002))
    np.testing.assert_array_equal(mixed_pixel_outliers(xyz, min_angle_deg=10.0),
                                  mixed_pixel_outliers(xyz.astype(np.float64), min_angle_deg=10.0))


def test_non_contiguous_and_other_float_types() -> None:
    rng = np.random.default_rng(4)
    xyz = pinhole(rng, 20, 30)
    view = np.asfortranarray(xyz)[:, ::-1]
    np.testing.assert_array_equal(window_outliers(view, min_inliers=4, rel_tolerance=0.002),
                                  window_outliers(np.ascontiguousarray(view), min_inliers=4, rel_tolerance=0.002))
    half = xyz.astype(np.float16)
    np.testing.assert_array_equal(mixed_pixel_outliers(half, min_angle_deg=10.0),
                                  mixed_pixel_outliers_reference(half.astype(np.float64), min_angle_deg=10.0))


# ------------------------------------------------------------------------------------------------
# hand-checked
# ------------------------------------------------------------------------------------------------
def plane(h: int = 5, w: int = 5, z: float = 1.0) -> np.ndarray:
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    return np.stack([(u - w // 2) * 0.001, (v - h // 2) * 0.001, np.full(u.shape, z)], axis=-1)


def test_window_rule_by_hand() -> None:
    xyz = plane()
    xyz[2, 2, 2] = 1.5  # a spike: no neighbour within 10 % of 1.5
    got = window_outliers(xyz, min_inliers=1, rel_tolerance=0.1)
    want = np.zeros((5, 5), bool)
    want[2, 2] = True
    np.testing.assert_array_equal(got, want)
    # the tolerance is inclusive and relative to the centre: |1.5 - 1| = 0.5 = 1/3 * 1.5
    assert not window_outliers(xyz, min_inliers=1, rel_tolerance=1 / 3 + 1e-12)[2, 2]
    # a corner pixel has 3 neighbours, an edge pixel 5, an inner one 8
    flat = plane()
    got = window_outliers(flat, min_inliers=4, rel_tolerance=0.0)
    assert got[0, 0] and got[4, 4] and not got[0, 2] and not got[2, 2]
    assert window_outliers(flat, min_inliers=8, rel_tolerance=0.0).sum() == 16  # the border ring
    assert not window_outliers(flat, min_inliers=0, rel_tolerance=0.0).any()


def test_window_ignores_invalid_neighbours() -> None:
    xyz = plane()
    xyz[1:4, 1:4] = np.nan
    xyz[2, 2] = (0.0, 0.0, 1.0)
    assert window_outliers(xyz, min_inliers=1, rel_tolerance=1.0)[2, 2]  # no valid neighbour at all
    assert not window_outliers(xyz, min_inliers=1, rel_tolerance=1.0)[1, 1]  # invalid: never an outlier


def test_mixed_pixel_between_two_surfaces() -> None:
    # a foreground plane at 0.5 m left of column 5, background at 1.0 m right of it, and one mixed
    # pixel at 0.75 m in column 5 of row 3, on its own ray
    h, w, f = 7, 11, 100.0
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    z = np.where(u < 5, 0.5, 1.0)
    z[3, 5] = 0.75
    xyz = np.stack([(u - w / 2) / f * z, (v - h / 2) / f * z, z], axis=-1)
    got = mixed_pixel_outliers(xyz, min_angle_deg=10.0)
    assert got[3, 5]
    # the column-5 pixels above and below sit on the background, with a background neighbour to the
    # right: kept; so are the foreground pixels at the edge (their left neighbour is on their surface)
    assert not got[2, 5] and not got[4, 5] and not got[3, 4]
    assert got.sum() == 1
    np.testing.assert_array_equal(got, mixed_pixel_outliers_reference(xyz, min_angle_deg=10.0))


def test_mixed_pixel_grazing_surface_goes_by_design() -> None:
    # a plane seen edge-on at 85 deg from the view direction: every segment along its slope is
    # within 5 deg of the rays... at the centre; with a 20 deg threshold its middle rows go
    h, w, f = 9, 9, 200.0
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    xr, yr = (u - w / 2) / f, (v - h / 2) / f
    slope = math.tan(math.radians(85.0))
    z = 1.0 / (1.0 - slope * yr)  # the plane z = 1 + slope * y through the rays
    xyz = np.stack([xr * z, yr * z, z], axis=-1)
    assert mixed_pixel_outliers(xyz, min_angle_deg=20.0)[4].all()
    assert not mixed_pixel_outliers(plane(), min_angle_deg=60.0).any()  # a plane facing the camera


def test_stages_use_their_params() -> None:
    rng = np.random.default_rng(5)
    xyz = pinhole(rng, 25, 25)
    np.testing.assert_array_equal(window_stage(xyz, params=WindowParams(min_inliers=5, rel_tolerance=0.01)),
                                  window_outliers(xyz, min_inliers=5, rel_tolerance=0.01))
    np.testing.assert_array_equal(mixed_pixel_stage(xyz, params=MixedPixelParams(min_angle_deg=12.0)),
                                  mixed_pixel_outliers(xyz, min_angle_deg=12.0))
    assert window_stage(xyz, params=WindowParams()).shape == (25, 25)  # the defaults run
    with pytest.raises(ParameterError, match="params must be a WindowParams, got MixedPixelParams"):
        window_stage(xyz, params=MixedPixelParams())  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match="params must be a MixedPixelParams, got dict"):
        mixed_pixel_stage(xyz, params={})  # type: ignore[arg-type]


def test_numpy_scalars_are_accepted() -> None:
    xyz = plane()
    np.testing.assert_array_equal(window_outliers(xyz, min_inliers=np.int64(4), rel_tolerance=np.float32(0.5)),
                                  window_outliers(xyz, min_inliers=4, rel_tolerance=float(np.float32(0.5))))
    assert not mixed_pixel_outliers(xyz, min_angle_deg=np.float64(5.0)).any()


# ------------------------------------------------------------------------------------------------
# bad input
# ------------------------------------------------------------------------------------------------
GOOD = np.zeros((4, 4, 3))


@pytest.mark.parametrize(
    ("call", "error", "match"),
    [
        (lambda: window_outliers(np.zeros((4, 4)), min_inliers=3, rel_tolerance=0.1), InputShapeError,
         r"xyz must be an \(H, W, 3\) float array, got shape \(4, 4\)"),
        (lambda: window_outliers(np.zeros((4, 4, 3), np.int32), min_inliers=3, rel_tolerance=0.1), InputShapeError,
         r"int32"),
        (lambda: window_outliers(GOOD, min_inliers=9, rel_tolerance=0.1), ParameterError,
         r"WindowParams\.min_inliers must be an integer >= 0 and <= 8, got 9"),
        (lambda: window_outliers(GOOD, min_inliers=2.5, rel_tolerance=0.1), ParameterError,
         r"WindowParams\.min_inliers .*got 2\.5"),
        (lambda: window_outliers(GOOD, min_inliers=True, rel_tolerance=0.1), ParameterError, r"got True"),
        (lambda: window_outliers(GOOD, min_inliers=3, rel_tolerance=-0.1), ParameterError,
         r"WindowParams\.rel_tolerance must be a number >= 0, got -0\.1"),
        (lambda: window_outliers(GOOD, min_inliers=3, rel_tolerance=math.nan), ParameterError, r"got nan"),
        (lambda: mixed_pixel_outliers(GOOD, min_angle_deg=91), ParameterError,
         r"MixedPixelParams\.min_angle_deg must be a number >= 0 and <= 90, got 91"),
        (lambda: mixed_pixel_outliers(GOOD, min_angle_deg=-1.0), ParameterError, r"got -1\.0"),
        (lambda: mixed_pixel_outliers(GOOD, min_angle_deg="8"), ParameterError, r"got '8'"),
        (lambda: mixed_pixel_outliers([[1.0, 2.0, 3.0]], min_angle_deg=8), InputShapeError, r"shape \(1, 3\)"),
    ],
)
def test_bad_input(call, error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        call()


def test_input_is_not_modified() -> None:
    rng = np.random.default_rng(6)
    xyz = pinhole(rng, 10, 12).astype(np.float32)
    before = xyz.copy()
    window_outliers(xyz, min_inliers=3, rel_tolerance=0.01)
    mixed_pixel_outliers(xyz, min_angle_deg=8.0)
    np.testing.assert_array_equal(xyz, before)
