"""zcut.components: speckle and cluster removal, the union-find pass against scipy's connected
components (bit for bit), speckles against OpenCV's filterSpeckles, areas by hand, bad input."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from bank_clouds import KINDS, assert_equals_reference, degenerate_clouds, pinhole, random_cloud, steep
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from zcut import (
    ClusterParams,
    InputShapeError,
    Intrinsics,
    ParameterError,
    SpeckleParams,
    cluster_outliers,
    cluster_outliers_reference,
    cluster_stage,
    speckle_outliers,
    speckle_outliers_reference,
    speckle_stage,
)

CASES = [(seed, kind) for kind in KINDS for seed in range(10)]
# whole binary fractions of a millimetre: ties on the quantized clouds (depth steps of 1000/1024 mm)
SPECKLE_SETTINGS = [(0.0, 0), (0.0, 3), (1000 / 1024, 2), (125 / 16, 5), (2.0, 10), (20.0, 40), (1e9, 1)]
# distances of 1/8, 1/64 m...: ties on the quantized clouds; areas around a few pixels' footprints
CLUSTER_SETTINGS = [(125.0, 0.0, 8), (125.0, 40.0, 8), (1000 / 64, 5.0, 4), (15.0, 1e4, 8), (3.0, 2e3, 4),
                    (1e9, 1e12, 8)]


def camera(f: float = 60.0) -> Intrinsics:
    return Intrinsics(fx=f, fy=f * 1.25, cx=0.0, cy=0.0, width=1, height=1)


# ------------------------------------------------------------------------------------------------
# fast = reference
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("seed", "kind"), CASES)
def test_speckle_equals_reference(seed: int, kind: str) -> None:
    xyz = random_cloud(seed, kind)
    for max_diff, max_size in SPECKLE_SETTINGS:
        np.testing.assert_array_equal(speckle_outliers(xyz, max_diff_mm=max_diff, max_size_px=max_size),
                                      speckle_outliers_reference(xyz, max_diff_mm=max_diff, max_size_px=max_size))


@pytest.mark.parametrize(("seed", "kind"), CASES)
def test_cluster_equals_reference(seed: int, kind: str) -> None:
    xyz = random_cloud(seed, kind)
    for dist, area, conn in CLUSTER_SETTINGS:
        kw = dict(max_neighbour_mm=dist, min_area_mm2=area, intrinsics=camera(), connectivity=conn)
        np.testing.assert_array_equal(cluster_outliers(xyz, **kw), cluster_outliers_reference(xyz, **kw))


def test_settings_are_not_trivial() -> None:
    # on the random clouds every setting (bar the extremes) removes something and keeps something
    rng_clouds = [random_cloud(s, k) for k in KINDS for s in range(10)]
    for max_diff, max_size in SPECKLE_SETTINGS[1:-1]:
        n = sum(int(speckle_outliers(x, max_diff_mm=max_diff, max_size_px=max_size).sum()) for x in rng_clouds)
        assert 0 < n < sum(int(np.isfinite(x).all(axis=2).sum()) for x in rng_clouds)
    for dist, area, conn in CLUSTER_SETTINGS[1:-1]:
        kw = dict(max_neighbour_mm=dist, min_area_mm2=area, intrinsics=camera(), connectivity=conn)
        assert sum(int(cluster_outliers(x, **kw).sum()) for x in rng_clouds) > 0


@pytest.mark.parametrize("name", list(degenerate_clouds()))
def test_degenerate_clouds(name: str) -> None:
    xyz = degenerate_clouds()[name]
    for max_diff, max_size in SPECKLE_SETTINGS:
        assert_equals_reference(speckle_outliers, speckle_outliers_reference, xyz, max_diff_mm=max_diff,
                                max_size_px=max_size)
    for dist, area, conn in CLUSTER_SETTINGS:
        assert_equals_reference(cluster_outliers, cluster_outliers_reference, xyz, max_neighbour_mm=dist,
                                min_area_mm2=area, intrinsics=camera(), connectivity=conn)
    if name == "identical":  # one region of 180 pixels
        assert not speckle_outliers(xyz, max_diff_mm=0.0, max_size_px=179).any()
        assert speckle_outliers(xyz, max_diff_mm=0.0, max_size_px=180).all()
    if name == "one-valid":  # its own region: 1 pixel, footprint (600 / 60) * (600 / 75) = 80 mm²
        assert speckle_outliers(xyz, max_diff_mm=5.0, max_size_px=1).sum() == 1
        kw = dict(max_neighbour_mm=1.0, intrinsics=camera())
        fp = (600.0 * 600.0) * (1.0 / (60.0 * 75.0))
        assert fp == pytest.approx(80.0)
        assert cluster_outliers(xyz, min_area_mm2=np.nextafter(fp, np.inf), **kw).sum() == 1
        assert not cluster_outliers(xyz, min_area_mm2=fp, **kw).any()


@settings(max_examples=80, deadline=None)
@given(
    xyz=arrays(np.float64, st.tuples(st.integers(1, 7), st.integers(1, 7), st.just(3)),
               elements=st.one_of(st.sampled_from([0.0, 0.001, -0.001, 0.002, 1.0, np.nan, np.inf]),
                                  st.floats(-2, 2, allow_nan=False, width=64))),
    max_diff=st.sampled_from([0.0, 1.0, 1000.0]),
    max_size=st.integers(0, 6),
    dist=st.sampled_from([1.0, 1000.0, 3000.0]),
    area=st.sampled_from([0.0, 1.0, 1e4]),
    conn=st.sampled_from([4, 8]),
)
def test_property_equals_reference(xyz, max_diff, max_size, dist, area, conn) -> None:
    valid = np.isfinite(xyz).all(axis=2)
    got = speckle_outliers(xyz, max_diff_mm=max_diff, max_size_px=max_size)
    assert not (got & ~valid).any()
    np.testing.assert_array_equal(got, speckle_outliers_reference(xyz, max_diff_mm=max_diff, max_size_px=max_size))
    kw = dict(max_neighbour_mm=dist, min_area_mm2=area, intrinsics=camera(), connectivity=conn)
    got = cluster_outliers(xyz, **kw)
    assert not (got & ~valid).any()
    np.testing.assert_array_equal(got, cluster_outliers_reference(xyz, **kw))


def test_large_frame_equals_reference() -> None:
    # long chains of unions across many rows (the union-find's path compression at work)
    rng = np.random.default_rng(31)
    xyz = steep(rng, 240, 320)
    xyz[rng.random(xyz.shape[:2]) < 0.02] = np.nan
    np.testing.assert_array_equal(speckle_outliers(xyz, max_diff_mm=3.0, max_size_px=60),
                                  speckle_outliers_reference(xyz, max_diff_mm=3.0, max_size_px=60))
    kw = dict(max_neighbour_mm=4.0, min_area_mm2=200.0, intrinsics=camera(300.0))
    np.testing.assert_array_equal(cluster_outliers(xyz, **kw), cluster_outliers_reference(xyz, **kw))


# ------------------------------------------------------------------------------------------------
# OpenCV's filterSpeckles on whole-millimetre depth images
# ------------------------------------------------------------------------------------------------
def millimetre_cloud(rng: np.random.Generator, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """A cloud whose depths are whole millimetres (1000 * z gives them back exactly), and the int16
    depth image OpenCV filters (0 = invalid)."""
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    mm = 500 + 40 * np.sin(u / rng.uniform(3, 12)) * np.cos(v / rng.uniform(3, 12))
    mm = mm + (u > w * rng.uniform(0.2, 0.8)) * rng.integers(-60, 60)
    mm = mm + rng.integers(-2, 3, mm.shape) * (rng.random(mm.shape) < 0.5)
    spikes = rng.random(mm.shape) < 0.03
    mm = np.where(spikes, mm + rng.integers(-300, 300, mm.shape), mm)
    mm = np.round(mm).astype(np.int64)
    invalid = rng.random(mm.shape) < rng.choice([0.0, 0.05, 0.3])
    z = mm / 1000.0
    assert (1000.0 * z == mm).all()  # the round trip the comparison relies on
    xyz = np.stack([(u - w / 2) / 500 * z, (v - h / 2) / 500 * z, z], axis=-1)
    xyz[invalid] = np.nan
    depth = np.where(invalid, 0, mm).astype(np.int16)
    return xyz, depth


@pytest.mark.parametrize("seed", range(12))
def test_speckle_equals_opencv(seed: int) -> None:
    rng = np.random.default_rng(seed)
    h, w = int(rng.integers(1, 120)), int(rng.integers(1, 160))
    xyz, depth = millimetre_cloud(rng, h, w)
    for max_diff in (0, 1, 2, 5, 40):
        for max_size in (0, 1, 4, 30, 500):
            img = depth.copy()
            cv2.filterSpeckles(img, 0, max_size, max_diff)
            want = (depth != 0) & (img == 0)
            got = speckle_outliers(xyz, max_diff_mm=float(max_diff), max_size_px=max_size)
            np.testing.assert_array_equal(got, want, err_msg=f"max_diff={max_diff} max_size={max_size}")


def test_speckle_equals_opencv_full_size() -> None:
    rng = np.random.default_rng(77)
    xyz, depth = millimetre_cloud(rng, 1200, 1920)
    img = depth.copy()
    cv2.filterSpeckles(img, 0, 100, 2)
    np.testing.assert_array_equal(speckle_outliers(xyz, max_diff_mm=2.0, max_size_px=100), (depth != 0) & (img == 0))


# ------------------------------------------------------------------------------------------------
# hand-checked
# ------------------------------------------------------------------------------------------------
def test_speckle_by_hand() -> None:
    z = np.full((5, 8), np.nan)
    z[1, 1:4] = 0.100  # a 3-pixel region
    z[3, 5:7] = [0.200, 0.202]  # 2 pixels 2 mm apart
    xyz = np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=-1)
    region3 = np.zeros((5, 8), bool)
    region3[1, 1:4] = True
    region2 = np.zeros((5, 8), bool)
    region2[3, 5:7] = True
    np.testing.assert_array_equal(speckle_outliers(xyz, max_diff_mm=2.0, max_size_px=3), region3 | region2)
    np.testing.assert_array_equal(speckle_outliers(xyz, max_diff_mm=2.0, max_size_px=2), region2)
    assert not speckle_outliers(xyz, max_diff_mm=2.0, max_size_px=1).any()  # the 2 mm step joins
    np.testing.assert_array_equal(speckle_outliers(xyz, max_diff_mm=1.9, max_size_px=1), region2)
    # diagonal pixels are not 4-neighbours
    d = np.full((2, 2, 3), np.nan)
    d[0, 0] = d[1, 1] = (0.0, 0.0, 1.0)
    assert speckle_outliers(d, max_diff_mm=1.0, max_size_px=1).sum() == 2


def test_cluster_by_hand() -> None:
    # a 4 x 4 patch 1 m away (pixel pitch 1 mm), a 2-pixel cluster floating 5 mm above it
    K = Intrinsics(fx=1000.0, fy=1000.0, cx=0.0, cy=0.0, width=8, height=8)
    z = np.full((8, 8), np.nan)
    z[0:4, 0:4] = 1.0
    z[6, 6:8] = 0.995
    u, v = np.meshgrid(np.arange(8.0), np.arange(8.0))
    xyz = np.stack([u * 0.001 * z, v * 0.001 * z, z], axis=-1)
    small = np.zeros((8, 8), bool)
    small[6, 6:8] = True
    # footprints: 1 mm² per patch pixel (16 mm²), 0.995² mm² per floating pixel (1.98 mm²)
    np.testing.assert_array_equal(cluster_outliers(xyz, max_neighbour_mm=1.5, min_area_mm2=2.0, intrinsics=K), small)
    assert not cluster_outliers(xyz, max_neighbour_mm=1.5, min_area_mm2=1.9, intrinsics=K).any()
    assert cluster_outliers(xyz, max_neighbour_mm=1.5, min_area_mm2=16.5, intrinsics=K).sum() == 18
    # a step of 0.5 mm in depth inside the patch splits it only below 0.5 mm
    z2 = z.copy()
    z2[0:4, 2:4] = 1.0005
    xyz2 = np.stack([u * 0.001 * z2, v * 0.001 * z2, z2], axis=-1)
    assert cluster_outliers(xyz2, max_neighbour_mm=0.9, min_area_mm2=9.0, intrinsics=K)[0:4, 0:4].all()
    assert not cluster_outliers(xyz2, max_neighbour_mm=1.2, min_area_mm2=9.0, intrinsics=K)[0:4, 0:4].any()


def test_cluster_connectivity() -> None:
    K = camera()
    d = np.full((2, 2, 3), np.nan)
    d[0, 0] = (0.0, 0.0, 1.0)
    d[1, 1] = (0.0005, 0.0, 1.0)
    fp = (1000.0 * 1000.0) * (1.0 / (K.fx * K.fy))  # the footprint at 1 m, as documented
    assert not cluster_outliers(d, max_neighbour_mm=1.0, min_area_mm2=2 * fp, intrinsics=K, connectivity=8).any()
    assert cluster_outliers(d, max_neighbour_mm=1.0, min_area_mm2=2 * fp, intrinsics=K, connectivity=4).sum() == 2


def test_stages_use_their_params() -> None:
    rng = np.random.default_rng(8)
    xyz = pinhole(rng, 30, 30)
    sp = SpeckleParams(max_diff_mm=3.0, max_size_px=7)
    np.testing.assert_array_equal(speckle_stage(xyz, params=sp), speckle_outliers(xyz, max_diff_mm=3.0, max_size_px=7))
    cp = ClusterParams(max_neighbour_mm=20.0, min_area_mm2=500.0, connectivity=4)
    np.testing.assert_array_equal(
        cluster_stage(xyz, params=cp, intrinsics=camera()),
        cluster_outliers(xyz, max_neighbour_mm=20.0, min_area_mm2=500.0, intrinsics=camera(), connectivity=4),
    )
    assert speckle_stage(xyz, params=SpeckleParams()).shape == (30, 30)
    assert cluster_stage(xyz, params=ClusterParams(), intrinsics=camera()).shape == (30, 30)
    with pytest.raises(ParameterError, match="params must be a SpeckleParams, got ClusterParams"):
        speckle_stage(xyz, params=cp)  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match="params must be a ClusterParams, got SpeckleParams"):
        cluster_stage(xyz, params=sp, intrinsics=camera())  # type: ignore[arg-type]


# ------------------------------------------------------------------------------------------------
# bad input
# ------------------------------------------------------------------------------------------------
GOOD = np.zeros((4, 4, 3))


@pytest.mark.parametrize(
    ("call", "error", "match"),
    [
        (lambda: speckle_outliers(np.zeros((4, 4, 2)), max_diff_mm=1, max_size_px=5), InputShapeError,
         r"shape \(4, 4, 2\)"),
        (lambda: speckle_outliers(GOOD, max_diff_mm=-1, max_size_px=5), ParameterError,
         r"SpeckleParams\.max_diff_mm must be a number >= 0, got -1"),
        (lambda: speckle_outliers(GOOD, max_diff_mm=math.inf, max_size_px=5), ParameterError, r"got inf"),
        (lambda: speckle_outliers(GOOD, max_diff_mm=1, max_size_px=-2), ParameterError,
         r"SpeckleParams\.max_size_px must be an integer >= 0, got -2"),
        (lambda: speckle_outliers(GOOD, max_diff_mm=1, max_size_px=1.5), ParameterError, r"got 1\.5"),
        (lambda: cluster_outliers(GOOD, max_neighbour_mm=0, min_area_mm2=5, intrinsics=camera()), ParameterError,
         r"ClusterParams\.max_neighbour_mm must be a number > 0, got 0"),
        (lambda: cluster_outliers(GOOD, max_neighbour_mm=1, min_area_mm2=-5, intrinsics=camera()), ParameterError,
         r"ClusterParams\.min_area_mm2 must be a number >= 0, got -5"),
        (lambda: cluster_outliers(GOOD, max_neighbour_mm=1, min_area_mm2=5, intrinsics=camera(), connectivity=6),
         ParameterError, r"ClusterParams\.connectivity must be 4 or 8, got 6"),
        (lambda: cluster_outliers(GOOD, max_neighbour_mm=1, min_area_mm2=5, intrinsics=None), ParameterError,
         r"the cluster filter needs the camera intrinsics \(fx, fy\) to measure areas in mm², got none"),
        (lambda: cluster_outliers(GOOD, max_neighbour_mm=1, min_area_mm2=5, intrinsics=(600.0, 600.0)),
         ParameterError, r"intrinsics must be a zcut\.Intrinsics, got tuple"),
        (lambda: cluster_stage(GOOD, params=ClusterParams(), intrinsics=None), ParameterError, r"got none"),
    ],
)
def test_bad_input(call, error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        call()
