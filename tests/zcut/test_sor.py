"""zcut.sor: the "open3d" convention against Open3D itself, "pcl" against a brute-force reference."""

from __future__ import annotations

import functools
import math
import subprocess
import sys

import bank_clouds
import numpy as np
import open3d as o3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from reference.sor_reference import (
    mean_distances_reference,
    outliers_from_mean_distances_reference,
    sor_outliers_reference,
)

import zcut.sor as sor_module
from zcut import InputShapeError, ParameterError, sor_outliers
from zcut.sor import sor_mean_distances, sor_outliers_from_distances


def open3d_outliers(xyz: np.ndarray, *, k: int, std_ratio: float) -> np.ndarray:
    """Outlier mask of Open3D's remove_statistical_outlier over the valid pixels in row-major order."""
    valid = np.isfinite(xyz).all(axis=2)
    pts = np.ascontiguousarray(xyz[valid], dtype=np.float64)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    _, kept = cloud.remove_statistical_outlier(nb_neighbors=k, std_ratio=std_ratio)
    keep = np.zeros(pts.shape[0], dtype=bool)
    keep[np.asarray(kept, dtype=np.int64)] = True
    out = np.zeros(valid.shape, dtype=bool)
    out[valid] = ~keep
    return out


# ------------------------------------------------------------------------------------------------
# cloud generators (seeded)
# ------------------------------------------------------------------------------------------------
def pinhole(rng: np.random.Generator, h: int, w: int, *, f: float = 60.0, flying: float = 0.05) -> np.ndarray:
    """A wavy surface 0.5 m in front of a pinhole camera, noise along the rays, flying pixels."""
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    z = 0.5 + 0.03 * np.sin(u / rng.uniform(3, 15)) * np.cos(v / rng.uniform(3, 15))
    z = z + (u > w * rng.uniform(0.3, 0.7)) * rng.uniform(-0.1, 0.1)  # a depth step
    z = z * (1 + rng.normal(0, 1e-3, z.shape))
    fly = rng.random(z.shape) < flying
    z = np.where(fly, z + rng.normal(0, 0.05, z.shape), z)
    return np.stack([(u - w / 2) / f * z, (v - h / 2) / f * z, z], axis=-1)


def with_holes(rng: np.random.Generator, xyz: np.ndarray, frac: float) -> np.ndarray:
    xyz = xyz.copy()
    xyz[rng.random(xyz.shape[:2]) < frac] = np.nan
    if xyz.shape[0] > 4 and xyz.shape[1] > 4:  # a rectangular hole, and a single NaN coordinate
        r, c = rng.integers(0, xyz.shape[0] - 3), rng.integers(0, xyz.shape[1] - 3)
        xyz[r:r + 3, c:c + 3] = np.nan
        xyz[rng.integers(0, xyz.shape[0]), rng.integers(0, xyz.shape[1]), rng.integers(0, 3)] = np.nan
    return xyz


def quantized(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """Coordinates on a coarse grid: many exact distance ties and coincident points."""
    q = rng.choice([0.005, 0.01, 0.03])
    return np.round(pinhole(rng, h, w) / q) * q


def coincident(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """Pinhole cloud with groups of exactly coincident points (d̄ = 0 for the open3d convention)."""
    return bank_clouds.coincident(rng, h, w, cloud=pinhole)


def scattered(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """No camera at all: organized only by name (window bound useless, fallback path)."""
    return rng.normal(size=(h, w, 3)) * rng.uniform(0.1, 10.0)


def behind(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """Some z <= 0 (exactly 0 too): the window bound does not apply."""
    xyz = pinhole(rng, h, w)
    xyz[..., 2] -= 0.5
    xyz[rng.random((h, w)) < 0.1, 2] = 0.0
    return xyz


KINDS = {
    "pinhole": pinhole,
    "quantized": quantized,
    "coincident": coincident,
    "scattered": scattered,
    "behind": behind,
}


def random_case(seed: int, kind: str) -> tuple[np.ndarray, int, float]:
    rng = np.random.default_rng(1000 * seed + len(kind))
    h, w = int(rng.integers(1, 45)), int(rng.integers(1, 45))
    xyz = KINDS[kind](rng, h, w)
    xyz = with_holes(rng, xyz, float(rng.choice([0.0, 0.05, 0.3])))
    if rng.random() < 0.3:
        xyz = xyz.astype(np.float32)
    k = int(rng.choice([1, 2, 3, 4, 5, 8, 12]))
    std_ratio = float(rng.choice([0.3, 1.0, 1.7, 3.0]))
    return xyz, k, std_ratio


CASES = [(seed, kind) for kind in KINDS for seed in range(12)]


# ------------------------------------------------------------------------------------------------
# equivalence
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("seed", "kind"), CASES)
def test_open3d_convention_equals_open3d(seed: int, kind: str) -> None:
    xyz, k, std_ratio = random_case(seed, kind)
    got = sor_outliers(xyz, k=k, std_ratio=std_ratio, convention="open3d")
    n = int(np.isfinite(xyz).all(axis=2).sum())
    if n < k + 1:
        assert not got.any()
    else:
        np.testing.assert_array_equal(got, open3d_outliers(xyz, k=k, std_ratio=std_ratio))


@pytest.mark.parametrize(("seed", "kind"), CASES)
def test_pcl_convention_equals_reference(seed: int, kind: str) -> None:
    xyz, k, std_ratio = random_case(seed, kind)
    got = sor_outliers(xyz, k=k, std_ratio=std_ratio, convention="pcl")
    np.testing.assert_array_equal(got, sor_outliers_reference(xyz, k=k, std_ratio=std_ratio, convention="pcl"))


@pytest.mark.parametrize("kind", ["pinhole", "quantized", "coincident"])
@pytest.mark.parametrize("k", [1, 4, 9])
def test_open3d_reference_is_open3d(kind: str, k: int) -> None:
    # the brute-force reference's open3d branch is itself checked against Open3D
    rng = np.random.default_rng(k)
    xyz = with_holes(rng, KINDS[kind](rng, 30, 40), 0.1)
    np.testing.assert_array_equal(
        sor_outliers_reference(xyz, k=k, std_ratio=1.0, convention="open3d"),
        open3d_outliers(xyz, k=k, std_ratio=1.0),
    )


SEARCH_PATHS = {
    "auto": {},
    "window-1": {"_WINDOW_MAX": 1},  # no growing windows: more pixels for the tile search
    "no-camera": {"_USE_CAMERA": False},  # only distances of 0 proven in the window
    "tiles": {"_USE_CAMERA": False, "_TILE_SCAN_CAP": 1 << 40},  # every unproven pixel by tiles
    "kdtree": {"_TILE_SCAN_CAP": 0},  # KD-tree over the tiles within each pixel's radius
    "kdtree-all": {"_TILE_SCAN_CAP": 0, "_MARK_MAX_TILES": 0},  # KD-tree over all valid points
    "unorganized": {"_TILE_SCAN_CAP": 0, "_SAMPLE": 2},  # the sample says "not organized"
    "columns": {"_COLUMNS_MIN_SHARE": 1 << 40, "_COLUMNS_COST": 0.0},  # every unproven pixel with a bound by the columns
    "columns-narrow": {"_COLUMNS_MIN_SHARE": 1 << 40, "_COLUMNS_COST": 0.0, "_COLUMN_WIDTH": 0.01},  # many rings
    "columns-then-tiles": {"_COLUMNS_MIN_SHARE": 1 << 40, "_COLUMNS_COST": 0.0, "_COLUMN_SCAN": 3},  # the budget runs out
    "columns-no-camera": {"_COLUMNS_MIN_SHARE": 1 << 40, "_COLUMNS_COST": 0.0, "_USE_CAMERA": False, "_WINDOW_MAX": 2},
}


@pytest.fixture(params=list(SEARCH_PATHS))
def search_path(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """Force the unproven points through one of the searches."""
    for name, value in SEARCH_PATHS[request.param].items():
        monkeypatch.setattr(sor_module, name, value)
    return request.param


@functools.cache
def bit_identical_case(kind: str, convention: str) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """The 36 x 48 cloud of ``kind`` (seed 7, 5 % holes) and the reference's d̄ of it for k = 1, 4, 7: the
    oracle, computed once for the search paths that are held to it (read-only)."""
    rng = np.random.default_rng(7)
    xyz = with_holes(rng, KINDS[kind](rng, 36, 48), 0.05)
    wants = {k: mean_distances_reference(xyz, k=k, convention=convention) for k in (1, 4, 7)}
    for a in (xyz, *wants.values()):
        a.setflags(write=False)
    return xyz, wants


@pytest.mark.parametrize("convention", ["pcl", "open3d"])
@pytest.mark.parametrize("kind", ["pinhole", "quantized", "coincident", "scattered", "behind"])
def test_mean_distances_bit_identical(search_path: str, convention: str, kind: str) -> None:
    cloud, wants = bit_identical_case(kind, convention)
    xyz = cloud.copy()  # the search gets a fresh array, as each case made its own
    for k in (1, 4, 7):
        got = sor_mean_distances(xyz, k=k, convention=convention)
        np.testing.assert_array_equal(got, wants[k])  # NaN where invalid, bit-identical elsewhere


@pytest.mark.parametrize("convention", ["pcl", "open3d"])
def test_camera_cloud_with_flying_pixels(convention: str) -> None:
    # big enough for the window bound, the tile search and a steep wall to matter
    rng = np.random.default_rng(3)
    xyz = with_holes(rng, pinhole(rng, 72, 96, f=150.0, flying=0.02), 0.05)
    for k, std_ratio in ((4, 1.0), (10, 2.0)):
        got = sor_outliers(xyz, k=k, std_ratio=std_ratio, convention=convention)
        if convention == "open3d":
            want = open3d_outliers(xyz, k=k, std_ratio=std_ratio)
        else:
            want = sor_outliers_reference(xyz, k=k, std_ratio=std_ratio, convention="pcl")
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("convention", ["pcl", "open3d"])
def test_steep_relief_uses_the_columns(convention: str, monkeypatch: pytest.MonkeyPatch) -> None:
    # tall narrow parts standing on end: many pixels stay unproven in their windows and the column
    # stage (on by default from one unproven pixel in _COLUMNS_MIN_SHARE) settles them
    from bank_clouds import steep

    rng = np.random.default_rng(14)
    xyz = with_holes(rng, steep(rng, 240, 320), 0.02).astype(np.float32)
    settled = []
    stage = sor_module._column_stage

    def spy(*args, **kwargs):
        done = stage(*args, **kwargs)
        settled.append(int(done.sum()))
        return done

    monkeypatch.setattr(sor_module, "_column_stage", spy)
    for k in (4, 8):
        np.testing.assert_array_equal(sor_mean_distances(xyz, k=k, convention=convention),
                                      mean_distances_reference(xyz, k=k, convention=convention, method="kdtree"))
    assert settled and min(settled) > 100
    if convention == "open3d":
        np.testing.assert_array_equal(sor_outliers(xyz, k=4, convention="open3d"),
                                      open3d_outliers(xyz, k=4, std_ratio=1.0))


@pytest.mark.parametrize("convention", ["pcl", "open3d"])
def test_a_sampled_tile_search_chooses_the_columns(convention: str, monkeypatch: pytest.MonkeyPatch) -> None:
    # many unproven pixels (one valid pixel in _COLUMNS_MIN_SHARE or more) in both clouds: a tile
    # search of _SAMPLE of them, whose results are kept, says whether the columns pay; whatever it
    # says, d̄ is the reference's
    from bank_clouds import steep

    rng = np.random.default_rng(14)
    tall = with_holes(rng, steep(rng, 240, 320), 0.02).astype(np.float32)
    rng = np.random.default_rng(5)
    scattered = with_holes(rng, pinhole(rng, 240, 320, f=400.0, flying=0.01), 0.3)
    column_rows: list[int] = []
    unproven: list[int] = []
    stage, fallback = sor_module._column_stage, sor_module._fallback

    def spy_columns(*args, **kwargs):
        column_rows.append(int(args[4].size))
        return stage(*args, **kwargs)

    def spy_fallback(*args, **kwargs):
        unproven.append(int(args[4].size))
        return fallback(*args, **kwargs)

    monkeypatch.setattr(sor_module, "_column_stage", spy_columns)
    monkeypatch.setattr(sor_module, "_fallback", spy_fallback)
    monkeypatch.setattr(sor_module, "_SAMPLE", 32)
    for xyz in (tall, scattered):
        want = mean_distances_reference(xyz, k=4, convention=convention, method="kdtree")
        for cost, columns in ((0.0, "all"), (1e9, "none"), (sor_module._COLUMNS_COST, "sampled")):
            monkeypatch.setattr(sor_module, "_COLUMNS_COST", cost)
            column_rows.clear()
            unproven.clear()
            np.testing.assert_array_equal(sor_mean_distances(xyz, k=4, convention=convention), want)
            assert len(unproven) == 1 and unproven[0] * sor_module._COLUMNS_MIN_SHARE >= np.isfinite(xyz).all(-1).sum()
            if columns == "all":  # no sample: every unproven pixel goes to the columns
                assert column_rows == unproven
            elif columns == "none":
                assert column_rows == []
            elif xyz is tall or column_rows:  # the tall parts need them; the sample's found pixels are not searched again
                assert len(column_rows) == 1 and unproven[0] - 32 <= column_rows[0] < unproven[0]


@pytest.mark.parametrize("invalid", [0.3, 0.5, 0.7])
def test_sparse_camera_cloud(invalid: float) -> None:
    # scattered invalid pixels: rows where the 3 x 3 stage leaves many pixels go through the 5 x 5
    # one (as a list, a whole row, or straight away), the rest through growing windows
    rng = np.random.default_rng(int(invalid * 10))
    xyz = with_holes(rng, pinhole(rng, 120, 160, f=200.0, flying=0.01), invalid)
    for k in (4, 8):
        for convention in ("pcl", "open3d"):
            np.testing.assert_array_equal(
                sor_mean_distances(xyz, k=k, convention=convention),
                mean_distances_reference(xyz, k=k, convention=convention, method="kdtree"),
            )
        np.testing.assert_array_equal(sor_outliers(xyz, k=k, convention="open3d"), open3d_outliers(xyz, k=k, std_ratio=1.0))


@settings(max_examples=60, deadline=None)
@given(
    xyz=arrays(
        np.float64,
        st.tuples(st.integers(1, 6), st.integers(1, 6), st.just(3)),
        elements=st.one_of(
            st.sampled_from([0.0, 1.0, -1.0, 0.5, np.nan, np.inf]),
            st.floats(-10, 10, allow_nan=False, width=64),
        ),
    ),
    k=st.integers(1, 5),
    std_ratio=st.sampled_from([0.1, 1.0, 2.5]),
    convention=st.sampled_from(["pcl", "open3d"]),
)
def test_property_equals_reference(xyz: np.ndarray, k: int, std_ratio: float, convention: str) -> None:
    got = sor_outliers(xyz, k=k, std_ratio=std_ratio, convention=convention)
    valid = np.isfinite(xyz).all(axis=2)
    assert not (got & ~valid).any()  # outliers are valid pixels
    np.testing.assert_array_equal(got, sor_outliers_reference(xyz, k=k, std_ratio=std_ratio, convention=convention))


# ------------------------------------------------------------------------------------------------
# hand-checked cases and edges
# ------------------------------------------------------------------------------------------------
def test_isolated_point_is_the_outlier() -> None:
    # a 3 x 4 grid of points 1 apart in a plane, one of them lifted far away
    u, v = np.meshgrid(np.arange(4.0), np.arange(3.0))
    xyz = np.stack([u, v, np.full_like(u, 5.0)], axis=-1)
    xyz[1, 2, 2] = 50.0
    for convention in ("pcl", "open3d"):
        got = sor_outliers(xyz, k=2, std_ratio=1.0, convention=convention)
        want = np.zeros((3, 4), dtype=bool)
        want[1, 2] = True
        np.testing.assert_array_equal(got, want)


def test_open3d_drops_points_with_k_coincident_copies() -> None:
    # Open3D keeps only 0 < d̄: a point with k - 1 exact copies has d̄ = 0 and is removed
    rng = np.random.default_rng(5)
    xyz = pinhole(rng, 10, 10, flying=0.0)
    xyz[4, 4] = xyz[4, 5] = xyz[4, 6]
    got = sor_outliers(xyz, k=3, std_ratio=3.0, convention="open3d")
    assert got[4, 4] and got[4, 5] and got[4, 6]
    np.testing.assert_array_equal(got, open3d_outliers(xyz, k=3, std_ratio=3.0))
    assert not sor_outliers(xyz, k=3, std_ratio=3.0, convention="pcl")[4, 4:7].any()


@pytest.mark.parametrize("convention", ["pcl", "open3d"])
def test_too_few_valid_points_means_no_outliers(convention: str) -> None:
    xyz = np.full((3, 3, 3), np.nan)
    xyz[0, 0] = (0.0, 0.0, 1.0)
    xyz[1, 1] = (0.0, 0.0, 2.0)
    xyz[2, 2] = (0.0, 0.0, 30.0)
    assert not sor_outliers(xyz, k=3, convention=convention).any()  # 3 valid < k + 1
    assert sor_outliers(xyz, k=2, std_ratio=0.5, convention=convention).any()  # 3 valid = k + 1


@pytest.mark.parametrize("shape", [(0, 0, 3), (0, 5, 3), (4, 0, 3), (1, 1, 3)])
def test_empty_and_single_pixel(shape: tuple[int, int, int]) -> None:
    out = sor_outliers(np.ones(shape), k=1)
    assert out.shape == shape[:2] and out.dtype == bool and not out.any()


def test_all_nan_and_one_row() -> None:
    assert not sor_outliers(np.full((5, 7, 3), np.nan)).any()
    rng = np.random.default_rng(11)
    row = rng.normal(size=(1, 50, 3))
    for convention in ("pcl", "open3d"):
        np.testing.assert_array_equal(
            sor_outliers(row, k=3, convention=convention),
            sor_outliers_reference(row, k=3, std_ratio=1.0, convention=convention),
        )


def test_inf_is_invalid_like_nan() -> None:
    rng = np.random.default_rng(2)
    xyz = pinhole(rng, 20, 20)
    a, b = xyz.copy(), xyz.copy()
    a[3, 3, 0] = np.inf
    b[3, 3, :] = np.nan
    for convention in ("pcl", "open3d"):
        out = sor_outliers(a, convention=convention)
        assert not out[3, 3]
        np.testing.assert_array_equal(out, sor_outliers(b, convention=convention))


def test_float32_is_upcast() -> None:
    rng = np.random.default_rng(4)
    xyz = pinhole(rng, 25, 30).astype(np.float32)
    np.testing.assert_array_equal(sor_outliers(xyz), sor_outliers(xyz.astype(np.float64)))


def test_input_is_not_modified() -> None:
    rng = np.random.default_rng(6)
    xyz = with_holes(rng, pinhole(rng, 10, 12), 0.2)
    before = xyz.copy()
    sor_outliers(xyz, convention="open3d")
    np.testing.assert_array_equal(xyz, before)


# ------------------------------------------------------------------------------------------------
# any camera frame: the window bound needs no z > 0
# ------------------------------------------------------------------------------------------------
def rigidly_moved(xyz: np.ndarray, frame: str) -> np.ndarray:
    """The cloud in another frame: OpenGL camera (y up, z < 0), a tilted bin frame (z of both
    signs), or an arbitrary rotation and translation."""
    if frame == "negative-z":
        return xyz * np.array([1.0, -1.0, -1.0])
    a, b, c = {"mixed-z": (0.35, 0.5, 0.0), "rotated": (1.1, -0.7, 2.3)}[frame]
    Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    Ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    Rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    out = xyz @ (Rz @ Ry @ Rx).T
    return out - np.nanmedian(out, axis=(0, 1))


@pytest.mark.parametrize("frame", ["negative-z", "mixed-z", "rotated"])
def test_any_rigid_frame(frame: str) -> None:
    rng = np.random.default_rng(17)
    xyz = rigidly_moved(with_holes(rng, pinhole(rng, 60, 80, f=120.0, flying=0.02), 0.05), frame)
    x, y, z = (np.where(np.isfinite(xyz[..., i]), xyz[..., i], np.inf) for i in range(3))
    assert sor_module._camera.fit_camera(x, y, z, np.isfinite(xyz).all(axis=2)) is not None  # the fast path holds
    for convention in ("pcl", "open3d"):
        np.testing.assert_array_equal(
            sor_mean_distances(xyz, k=4, convention=convention),
            mean_distances_reference(xyz, k=4, convention=convention),
        )
    np.testing.assert_array_equal(sor_outliers(xyz, k=4, convention="open3d"), open3d_outliers(xyz, k=4, std_ratio=1.0))


# ------------------------------------------------------------------------------------------------
# one d̄ computation, every threshold of a sweep
# ------------------------------------------------------------------------------------------------
RATIOS = [0.3, 1.0, 1.7, 3.0, 0.05]


@pytest.mark.parametrize(("seed", "kind"), CASES[::4])
def test_outliers_from_distances_equals_sor_outliers(seed: int, kind: str) -> None:
    xyz, k, _ = random_case(seed, kind)
    for convention in ("pcl", "open3d"):
        dbar = sor_mean_distances(xyz, k=k, convention=convention)
        masks = sor_outliers_from_distances(dbar, k=k, std_ratios=RATIOS, convention=convention)
        assert masks.shape == (len(RATIOS), *xyz.shape[:2]) and masks.dtype == bool
        for ratio, mask in zip(RATIOS, masks):
            np.testing.assert_array_equal(mask, sor_outliers(xyz, k=k, std_ratio=ratio, convention=convention))


def test_outliers_from_distances_edges() -> None:
    rng = np.random.default_rng(12)
    xyz = pinhole(rng, 20, 30)
    dbar = sor_mean_distances(xyz, k=4)
    assert sor_outliers_from_distances(dbar, k=4, std_ratios=[]).shape == (0, 20, 30)
    gen = sor_outliers_from_distances(dbar, k=4, std_ratios=(r for r in (1.0, np.float32(2.0), 3)))
    np.testing.assert_array_equal(gen[1], sor_outliers(xyz, k=4, std_ratio=2.0))
    few = np.full((4, 4), np.nan)
    few[0, :3] = 0.5  # 3 valid pixels < k + 1
    assert not sor_outliers_from_distances(few, k=3, std_ratios=[0.1]).any()
    assert not sor_outliers_from_distances(np.full((0, 7), np.nan), k=1, std_ratios=[1.0]).any()


@pytest.mark.parametrize(
    ("dbar", "kwargs", "error", "match"),
    [
        (np.zeros((4, 4, 1)), {}, InputShapeError, r"dbar must be an \(H, W\) float array, got shape \(4, 4, 1\)"),
        (np.zeros((4, 4), dtype=np.int64), {}, InputShapeError, r"int64"),
        (np.zeros((4, 4)), {"std_ratios": [1.0, 0.0]}, ParameterError, r"every std_ratio must be a finite number > 0, got 0.0"),
        (np.zeros((4, 4)), {"std_ratios": [float("nan")]}, ParameterError, r"got nan"),
        (np.zeros((4, 4)), {"std_ratios": [True]}, ParameterError, r"got True"),
        (np.zeros((4, 4)), {"std_ratios": "1"}, ParameterError, r"std_ratios must be an iterable of numbers, got '1'"),
        (np.zeros((4, 4)), {"std_ratios": 1.0}, ParameterError, r"std_ratios must be an iterable of numbers, got 1.0"),
        (np.zeros((4, 4)), {"k": 0}, ParameterError, r"k must be an integer >= 1, got 0"),
        (np.zeros((4, 4)), {"convention": "matlab"}, ParameterError, r"convention must be one of"),
    ],
)
def test_outliers_from_distances_bad_input(dbar: np.ndarray, kwargs: dict, error: type[Exception], match: str) -> None:
    args = {"k": 4, "std_ratios": [1.0], "convention": "pcl"} | kwargs
    with pytest.raises(error, match=match):
        sor_outliers_from_distances(dbar, **args)


# ------------------------------------------------------------------------------------------------
# degenerate clouds at full size: exact, and O(n·k) time and O(n) memory by construction
# ------------------------------------------------------------------------------------------------
FULL = (1200, 1920)


def full_camera_cloud(rng: np.random.Generator) -> np.ndarray:
    """A 1920 x 1200 pinhole cloud of a wavy surface 0.5 m away, float32."""
    u, v = np.meshgrid(np.arange(FULL[1], dtype=np.float64), np.arange(FULL[0], dtype=np.float64))
    z = 0.5 + 0.02 * np.sin(u / 90.0) * np.cos(v / 70.0) + rng.normal(0.0, 1e-4, u.shape)
    f = 1700.0
    return np.stack([(u - FULL[1] / 2) / f * z, (v - FULL[0] / 2) / f * z, z], axis=-1).astype(np.float32)


@pytest.mark.parametrize("layout", ["identical", "two-points", "one-odd-point"])
def test_heaps_of_one_or_two_points_full_size(layout: str) -> None:
    # the m nearest of every point are copies at distance 0 (or, for the odd one, ties at the same
    # distance): the tie rule ends each search at once -- the KD-tree fallback this replaced took
    # 5 GB for 10,000 identical points
    rng = np.random.default_rng(21)
    a, b = np.array([0.1, -0.2, 0.5]), np.array([0.3, 0.1, 0.7])
    if layout == "identical":
        xyz = np.broadcast_to(a, (*FULL, 3)).copy()
    elif layout == "two-points":
        xyz = np.where(rng.random(FULL)[..., None] < 0.5, a, b)
    else:
        xyz = np.broadcast_to(a, (*FULL, 3)).copy()
        xyz[600, 960] = b
    for k in (4, 9):
        for convention in ("pcl", "open3d"):
            dbar = sor_mean_distances(xyz, k=k, convention=convention)
            if layout == "one-odd-point":
                m = k + 1 if convention == "pcl" else k
                # the documented metric, summed in the kernel's order: sqrt((dx*dx + dy*dy) + dz*dz)
                dx, dy, dz = (b - a).tolist()
                dist = math.sqrt((dx * dx + dy * dy) + dz * dz)
                want = 0.0
                for _ in range(m - 1):
                    want += dist
                assert dbar[600, 960] == want / k
                dbar[600, 960] = 0.0
            assert (dbar == 0.0).all()
            got = sor_outliers(xyz, k=k, convention=convention)
            want_mask = np.full(FULL, convention == "open3d")  # Open3D keeps only d̄ > 0
            if layout == "one-odd-point":
                want_mask[600, 960] = True  # the one d̄ > 0 is above μ + σ ≈ d̄ / sqrt(n)
            np.testing.assert_array_equal(got, want_mask)
    small = xyz[590:630, 940:1000]  # where Open3D finishes (it is quadratic on duplicates)
    for k in (4, 9):
        np.testing.assert_array_equal(sor_outliers(small, k=k, convention="open3d"), open3d_outliers(small, k=k, std_ratio=1.0))


@pytest.mark.parametrize(("layout", "convention"), [("runs", "open3d"), ("scattered", "pcl")])
def test_ninety_percent_duplicates_full_size(layout: str, convention: str) -> None:
    # "runs": every row in runs of 10 pixels with the coordinates of the run's first pixel
    # (organized); "scattered": 90 % of the pixels copy a random one of the other 10 %
    # (no organization left at all: the KD-tree over all points)
    rng = np.random.default_rng(22)
    xyz = full_camera_cloud(rng)
    if layout == "runs":
        xyz = np.repeat(xyz[:, ::10], 10, axis=1)
    else:
        flat = xyz.reshape(-1, 3)
        originals = rng.permutation(flat.shape[0])[: flat.shape[0] // 10]
        copy = np.ones(flat.shape[0], dtype=bool)
        copy[originals] = False
        copies = np.flatnonzero(copy)  # np.setdiff1d(np.arange(n), originals): the same sorted indices, no sort
        flat[copies] = flat[rng.choice(originals, copies.size)]
    xyz[rng.random(FULL) < 0.05] = np.nan
    want = mean_distances_reference(xyz, k=4, convention=convention, method="kdtree")
    got = sor_mean_distances(xyz, k=4, convention=convention)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(  # (sor_outliers is sor_outliers_from_distances of the same d̄)
        sor_outliers_from_distances(got, k=4, std_ratios=[1.0], convention=convention)[0],
        outliers_from_mean_distances_reference(want, k=4, std_ratio=1.0, convention=convention),
    )


def test_single_valid_row_full_size() -> None:
    rng = np.random.default_rng(23)
    xyz = np.full((*FULL, 3), np.nan)
    xyz[600] = full_camera_cloud(rng)[600]
    for k in (1, 4, 9):
        np.testing.assert_array_equal(sor_outliers(xyz, k=k, convention="open3d"), open3d_outliers(xyz, k=k, std_ratio=1.0))
        np.testing.assert_array_equal(
            sor_mean_distances(xyz, k=k, convention="pcl"), mean_distances_reference(xyz, k=k, convention="pcl")
        )


def test_no_global_numba_setting_changes() -> None:
    # importing zcut and running sor_outliers leave numba's threading layer to the command line
    code = (
        "import numba, numpy as np\n"
        "before = list(numba.config.THREADING_LAYER_PRIORITY)\n"
        "import zcut\n"
        "from zcut.sor import sor_outliers\n"
        "sor_outliers(np.random.default_rng(0).normal(size=(50, 60, 3)))\n"
        "import numba.np.ufunc.parallel as parallel\n"
        "assert list(numba.config.THREADING_LAYER_PRIORITY) == before\n"
        "assert not parallel._is_initialized, 'numba threading layer started'\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, timeout=600)


# ------------------------------------------------------------------------------------------------
# bad input
# ------------------------------------------------------------------------------------------------
GOOD = np.zeros((4, 4, 3))


@pytest.mark.parametrize(
    ("xyz", "kwargs", "error", "match"),
    [
        (np.zeros((4, 4)), {}, InputShapeError, r"xyz must be an \(H, W, 3\) float array, got shape \(4, 4\)"),
        (np.zeros((4, 4, 2)), {}, InputShapeError, r"shape \(4, 4, 2\)"),
        (np.zeros((4, 4, 3), dtype=np.int32), {}, InputShapeError, r"int32"),
        ([[1.0, 2.0, 3.0]], {}, InputShapeError, r"shape \(1, 3\)"),
        (GOOD, {"k": 0}, ParameterError, r"k must be an integer >= 1, got 0"),
        (GOOD, {"k": -2}, ParameterError, r"k must be an integer >= 1, got -2"),
        (GOOD, {"k": 2.0}, ParameterError, r"k must be an integer >= 1, got 2.0"),
        (GOOD, {"k": True}, ParameterError, r"k must be an integer >= 1, got True"),
        (GOOD, {"k": "4"}, ParameterError, r"k must be an integer >= 1, got '4'"),
        (GOOD, {"std_ratio": 0.0}, ParameterError, r"std_ratio must be a finite number > 0, got 0.0"),
        (GOOD, {"std_ratio": -1}, ParameterError, r"std_ratio must be a finite number > 0, got -1"),
        (GOOD, {"std_ratio": float("nan")}, ParameterError, r"std_ratio must be a finite number > 0, got nan"),
        (GOOD, {"std_ratio": float("inf")}, ParameterError, r"got inf"),
        (GOOD, {"std_ratio": "1"}, ParameterError, r"got '1'"),
        (GOOD, {"convention": "matlab"}, ParameterError, r"convention must be one of \('pcl', 'open3d'\), got 'matlab'"),
        (GOOD, {"convention": None}, ParameterError, r"got None"),
    ],
)
def test_bad_input(xyz: object, kwargs: dict, error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        sor_outliers(xyz, **kwargs)


def test_numpy_integer_k_is_accepted() -> None:
    rng = np.random.default_rng(8)
    xyz = pinhole(rng, 12, 12)
    np.testing.assert_array_equal(sor_outliers(xyz, k=np.int64(3)), sor_outliers(xyz, k=3))


# ------------------------------------------------------------------------------------------------
# real sensor data: Kinect clouds with depth quantization, flying pixels and NaN holes
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["mosd_test16.pcd", "table_scene_mug_stereo_textured.pcd"])
def test_real_clouds_equal_open3d(real_data, name: str) -> None:
    cloud = o3d.io.read_point_cloud(str(real_data / name), remove_nan_points=False, remove_infinite_points=False)
    xyz = np.asarray(cloud.points).reshape(480, 640, 3)
    assert np.isfinite(xyz).all(axis=2).sum() > 100_000
    for k, std_ratio in ((4, 1.0), (8, 2.0)):
        np.testing.assert_array_equal(
            sor_outliers(xyz, k=k, std_ratio=std_ratio, convention="open3d"),
            open3d_outliers(xyz, k=k, std_ratio=std_ratio),
        )


def test_real_crop_pcl_equals_reference(real_data) -> None:
    cloud = o3d.io.read_point_cloud(
        str(real_data / "mosd_test20.pcd"), remove_nan_points=False, remove_infinite_points=False
    )
    xyz = np.asarray(cloud.points).reshape(480, 640, 3)[200:260, 300:380]
    assert int(np.isfinite(xyz).all(axis=2).sum()) >= 6 + 1  # sor_outliers_reference is then a function of d̄
    for k in (4, 6):
        want = mean_distances_reference(xyz, k=k, convention="pcl")
        np.testing.assert_array_equal(sor_mean_distances(xyz, k=k, convention="pcl"), want)
        np.testing.assert_array_equal(  # sor_outliers_reference of the crop, its d̄ (want) computed once
            sor_outliers(xyz, k=k, convention="pcl"),
            outliers_from_mean_distances_reference(want, k=k, std_ratio=1.0, convention="pcl"),
        )


@pytest.mark.parametrize("convention", ["pcl", "open3d"])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("gen", [pinhole, quantized, scattered])
def test_mask_on_a_crop_equals_the_nan_masked_copy(convention: str, dtype, gen) -> None:
    """``mask`` on a strided crop of the frame (how the pipeline runs SOR on its zone) gives what the
    NaN-masked copy of the crop gives, bit for bit: outliers and d̄."""
    rng = np.random.default_rng(41)
    xyz = with_holes(rng, gen(rng, 70, 90), 0.05).astype(dtype)
    mask = rng.random(xyz.shape[:2]) < 0.7
    mask[:, :10] = False
    sl = (slice(5, 61), slice(7, 83))
    crop, m = xyz[sl], mask[sl]
    assert not crop.flags.c_contiguous
    copy = np.where(m[..., None], crop, np.nan).astype(dtype)
    for ratio in (0.5, 1.0, 2.0):
        assert np.array_equal(sor_outliers(crop, k=4, std_ratio=ratio, convention=convention, mask=m),
                              sor_outliers(copy, k=4, std_ratio=ratio, convention=convention))
    np.testing.assert_array_equal(sor_mean_distances(crop, k=4, convention=convention, mask=m),
                                  sor_mean_distances(copy, k=4, convention=convention))
    with pytest.raises(InputShapeError, match="mask"):
        sor_outliers(crop, mask=mask)
