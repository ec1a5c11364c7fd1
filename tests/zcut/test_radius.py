"""zcut.radius: the fast radius filter against Open3D's remove_radius_outlier itself and against the
brute-force reference, through every search path, on random, nasty, degenerate and real clouds."""

from __future__ import annotations

import functools
import math

import numpy as np
import open3d as o3d
import pytest
from bank_clouds import KINDS, assert_equals_reference, degenerate_clouds, pinhole, random_cloud, steep, with_holes
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import zcut.radius as radius_module
from zcut import InputShapeError, ParameterError, RadiusParams, radius_outliers, radius_outliers_reference, radius_stage
from zcut.radius import radius_neighbour_counts


def open3d_outliers(xyz: np.ndarray, radius_mm: float, min_points: int) -> np.ndarray:
    """Outlier mask of Open3D's remove_radius_outlier over the valid pixels."""
    valid = np.isfinite(xyz).all(axis=2)
    pts = np.ascontiguousarray(xyz[valid], dtype=np.float64)
    out = np.zeros(valid.shape, dtype=bool)
    if pts.shape[0] == 0:
        return out
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    _, kept = cloud.remove_radius_outlier(nb_points=min_points, radius=radius_mm / 1000.0)
    keep = np.zeros(pts.shape[0], dtype=bool)
    keep[np.asarray(kept, dtype=np.int64)] = True
    out[valid] = ~keep
    return out


CASES = [(seed, kind) for kind in KINDS for seed in range(10)]
# radii in mm and neighbour counts; 125 mm and 15.625 mm are exact distances on the quantized clouds
SETTINGS = [(5.0, 1), (20.0, 4), (30.0, 8), (125.0, 3), (15.625, 2), (60.0, 20), (250.0, 40)]


@functools.cache
def reference_outliers(seed: int, kind: str) -> dict[tuple[float, int], np.ndarray]:
    """``radius_outliers_reference`` of ``random_cloud(seed, kind)`` for each of :data:`SETTINGS`: the oracle,
    computed once for the tests and the search paths held to it (read-only)."""
    xyz = random_cloud(seed, kind)
    out = {(r, m): radius_outliers_reference(xyz, r, m) for r, m in SETTINGS}
    for a in out.values():
        a.setflags(write=False)
    return out


# ------------------------------------------------------------------------------------------------
# fast = Open3D = reference
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("seed", "kind"), CASES)
def test_equals_open3d_and_reference(seed: int, kind: str) -> None:
    xyz = random_cloud(seed, kind)
    for radius_mm, min_points in SETTINGS:
        got = radius_outliers(xyz, radius_mm, min_points)
        want = reference_outliers(seed, kind)[radius_mm, min_points]
        np.testing.assert_array_equal(got, want, err_msg=f"{radius_mm} mm, {min_points}")
        np.testing.assert_array_equal(want, open3d_outliers(xyz, radius_mm, min_points))


def test_semantics_by_hand() -> None:
    # Open3D counts the point itself and only distances strictly below the radius
    xyz = np.full((1, 4, 3), np.nan)
    xyz[0, 0] = (0.0, 0.0, 1.0)
    xyz[0, 1] = (0.001, 0.0, 1.0)  # 1 mm from the first (exactly: 0.001 is the difference)
    xyz[0, 3] = (0.5, 0.0, 1.0)
    d = 1000.0 * math.sqrt(((0.0 - 0.001) ** 2 + 0.0) + 0.0)  # the computed distance in mm
    assert radius_outliers(xyz, 1.5, 1).tolist() == [[False, False, False, True]]
    assert radius_outliers(xyz, d, 1).tolist() == [[True, True, False, True]]  # on the sphere: out
    assert radius_outliers(xyz, 1.5, 2).tolist() == [[True, True, False, True]]
    for r, k in ((1.5, 1), (d, 1), (1.5, 2)):
        np.testing.assert_array_equal(radius_outliers(xyz, r, k), open3d_outliers(xyz, r, k))


SEARCH_PATHS = {
    "auto": {},
    "no-window": {"_WINDOW_EXTRA": -5},  # a window of nothing: every pixel is searched
    "wide-window": {"_WINDOW_EXTRA": 4},  # rings up to the generic loop's reach
    "kdtree": {"_USE_COLUMNS": False},  # every undecided pixel by the KD-tree
    "sparse-grid": {"_COLUMNS_PER_POINT": 0},  # the grid would be too large: KD-tree
    "no-budget": {"_BUDGET_PER_QUERY": 0, "_BUDGET_FLOOR": 0},  # one column query, then KD-tree
}


@pytest.fixture(params=list(SEARCH_PATHS))
def search_path(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    for name, value in SEARCH_PATHS[request.param].items():
        monkeypatch.setattr(radius_module, name, value)
    return request.param


@pytest.mark.parametrize("kind", list(KINDS))
def test_every_search_path(search_path: str, kind: str) -> None:
    for seed in range(3):
        xyz = random_cloud(seed, kind)
        for radius_mm, min_points in SETTINGS:
            np.testing.assert_array_equal(radius_outliers(xyz, radius_mm, min_points),
                                          reference_outliers(seed, kind)[radius_mm, min_points])


def test_counts_are_capped_counts() -> None:
    rng = np.random.default_rng(3)
    xyz = with_holes(rng, pinhole(rng, 30, 40), 0.1)
    valid = np.isfinite(xyz).all(axis=2)
    pts = xyz[valid]
    d = pts[:, None, :] - pts[None, :, :]
    d2 = (d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]) + d[..., 2] * d[..., 2]
    r = 25.0 / 1000.0
    full = (d2 < r * r).sum(axis=1)
    for cap in (1, 5, 30, 10_000):
        got = radius_neighbour_counts(xyz, radius_mm=25.0, cap=cap)
        assert got.dtype == np.int64 and (got[~valid] == 0).all()
        np.testing.assert_array_equal(got[valid], np.minimum(full, cap))


@pytest.mark.parametrize("name", list(degenerate_clouds()))
def test_degenerate_clouds(name: str) -> None:
    xyz = degenerate_clouds()[name]
    for radius_mm, min_points in SETTINGS + [(1e-300, 1), (1e300, 1)]:
        got = assert_equals_reference(radius_outliers, radius_outliers_reference, xyz, radius_mm, min_points)
        np.testing.assert_array_equal(got, open3d_outliers(xyz, radius_mm, min_points))
    if name == "one-valid":
        assert radius_outliers(xyz, 1000.0, 1).sum() == 1  # alone: an outlier, as in Open3D
    if name == "identical":  # 180 copies: every point has 179 others at distance 0
        assert not radius_outliers(xyz, 1e-3, 179).any()
        assert radius_outliers(xyz, 1e-3, 180).all()


@settings(max_examples=80, deadline=None)
@given(
    xyz=arrays(np.float64, st.tuples(st.integers(1, 6), st.integers(1, 6), st.just(3)),
               elements=st.one_of(st.sampled_from([0.0, 0.001, -0.001, 0.002, 1.0, np.nan, np.inf]),
                                  st.floats(-1, 1, allow_nan=False, width=64))),
    radius_mm=st.sampled_from([0.5, 1.0, 2.0, 1000.0, 3000.0]),
    min_points=st.integers(1, 6),
)
def test_property_equals_reference(xyz: np.ndarray, radius_mm: float, min_points: int) -> None:
    got = radius_outliers(xyz, radius_mm, min_points)
    assert not (got & ~np.isfinite(xyz).all(axis=2)).any()
    np.testing.assert_array_equal(got, radius_outliers_reference(xyz, radius_mm, min_points))


def test_far_away_points_change_nothing_nearby() -> None:
    rng = np.random.default_rng(9)
    xyz = with_holes(rng, pinhole(rng, 30, 30), 0.05)
    base = radius_outliers(xyz, 20.0, 4)
    far = xyz.copy()
    far[0, 0] = (1e6, -1e6, 5e5)  # one point a thousand kilometres away (and the grid gets huge)
    got = radius_outliers(far, 20.0, 4)
    assert got[0, 0]
    np.testing.assert_array_equal(got[1:], base[1:])
    np.testing.assert_array_equal(got[0, 1:], base[0, 1:])


def test_huge_coordinates() -> None:
    rng = np.random.default_rng(10)
    xyz = pinhole(rng, 20, 20) * 1e30  # cell keys would overflow: the KD-tree alone
    np.testing.assert_array_equal(radius_outliers(xyz, 1e32, 3), radius_outliers_reference(xyz, 1e32, 3))
    np.testing.assert_array_equal(radius_outliers(xyz, 1e32, 3), open3d_outliers(xyz, 1e32, 3))


def test_float32_is_upcast() -> None:
    rng = np.random.default_rng(11)
    xyz = pinhole(rng, 25, 30).astype(np.float32)
    np.testing.assert_array_equal(radius_outliers(xyz, 10.0, 5), radius_outliers(xyz.astype(np.float64), 10.0, 5))
    np.testing.assert_array_equal(radius_outliers(xyz, 10.0, 5), open3d_outliers(xyz, 10.0, 5))


def test_stage_uses_its_params() -> None:
    rng = np.random.default_rng(12)
    xyz = pinhole(rng, 20, 20)
    np.testing.assert_array_equal(radius_stage(xyz, params=RadiusParams(radius_mm=15.0, min_points=6)),
                                  radius_outliers(xyz, 15.0, 6))
    assert radius_stage(xyz, params=RadiusParams()).shape == (20, 20)
    with pytest.raises(ParameterError, match="params must be a RadiusParams, got float"):
        radius_stage(xyz, params=2.0)  # type: ignore[arg-type]


# ------------------------------------------------------------------------------------------------
# full size: bounded time on heaps of duplicates and tall parts (by construction, checked exactly)
# ------------------------------------------------------------------------------------------------
FULL = (1200, 1920)


@pytest.mark.parametrize("layout", ["identical", "two-points", "one-odd-point", "shell"])
def test_heaps_of_identical_points_full_size(layout: str) -> None:
    # every point is a copy of one or two points; "shell": 3000 pixels scattered 2.1 to 30 mm around
    # a heap of two million copies (each query near the heap finds it in its own cell or column)
    rng = np.random.default_rng(21)
    a, b = np.array([0.1, -0.2, 0.5]), np.array([0.1, -0.2, 0.5 + 0.003])
    xyz = np.broadcast_to(a, (*FULL, 3)).copy()
    if layout == "two-points":
        xyz = np.where(rng.random(FULL)[..., None] < 0.5, a, b)
    elif layout == "one-odd-point":
        xyz[600, 960] = b
    elif layout == "shell":
        flat = rng.choice(FULL[0] * FULL[1], 3000, replace=False)
        u = rng.normal(size=(flat.size, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        xyz.reshape(-1, 3)[flat] = a + u * rng.uniform(0.0021, 0.03, (flat.size, 1))
    for min_points in (4, 30):
        got = radius_outliers(xyz, 2.0, min_points)
        if layout == "identical":
            assert not got.any()
        elif layout == "two-points":
            assert not got.any()  # 3 mm apart: each point only sees its own copies
        elif layout == "one-odd-point":
            assert got.sum() == 1 and got[600, 960]
        else:
            assert 0 < got.sum() <= 3000
            np.testing.assert_array_equal(got, radius_outliers_reference(xyz, 2.0, min_points, method="kdtree"))
    if layout != "shell":
        small = xyz[590:630, 940:1000]  # Open3D is quadratic on duplicates: a corner only
        np.testing.assert_array_equal(radius_outliers(small, 2.0, 4), open3d_outliers(small, 2.0, 4))


def exact_counts(xyz: np.ndarray, rows: np.ndarray, cols: np.ndarray, radius_mm: float) -> np.ndarray:
    """Points strictly within the radius of the pixels (rows, cols), themselves included, in the
    arithmetic of the module notes (scipy proposes candidates, each copy of a point counts)."""
    from scipy.spatial import cKDTree

    valid = np.isfinite(xyz).all(axis=2)
    uniq, mult = np.unique(xyz[valid].astype(np.float64), axis=0, return_counts=True)
    r = radius_mm / 1000.0
    q = xyz[rows, cols].astype(np.float64)
    out = np.empty(q.shape[0], dtype=np.int64)
    for i, cand in enumerate(cKDTree(uniq).query_ball_point(q, r * (1 + 1e-9))):
        d = q[i] - uniq[cand]
        out[i] = mult[np.asarray(cand, dtype=np.int64)[((d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2])
                                                       < r * r]].sum()
    return out


def test_unorganized_dense_cloud() -> None:
    # 300,000 distinct points in a 10 mm ball and as many copies of its centre, pixels at random:
    # no image window helps, the columns run out of budget and the KD-tree finishes
    rng = np.random.default_rng(24)
    a = np.array([0.1, -0.2, 0.5])
    shape = (600, 960)
    xyz = np.broadcast_to(a, (*shape, 3)).copy()
    pick = rng.random(shape) < 0.5
    u = rng.normal(size=(int(pick.sum()), 3))
    u *= rng.uniform(0.0, 1.0, (u.shape[0], 1)) ** (1 / 3) / np.linalg.norm(u, axis=1, keepdims=True)
    xyz[pick] = a + 0.01 * u
    need = 37  # about as many points as a 0.5 mm ball holds on average
    counts = radius_neighbour_counts(xyz, radius_mm=0.5, cap=need)
    outliers = radius_outliers(xyz, 0.5, need - 1)
    np.testing.assert_array_equal(outliers, counts < need)
    assert 0.2 < outliers[pick].mean() < 0.8 and not outliers[~pick].any()
    rows, cols = np.nonzero(pick)
    some = rng.choice(rows.size, 3000, replace=False)
    np.testing.assert_array_equal(counts[rows[some], cols[some]],
                                  np.minimum(exact_counts(xyz, rows[some], cols[some], 0.5), need))


def test_steep_relief_frame_equals_kdtree_reference() -> None:
    rng = np.random.default_rng(22)
    xyz = with_holes(rng, steep(rng, 240, 320), 0.02).astype(np.float32)
    for radius_mm, min_points in ((8.0, 4), (20.0, 12)):
        np.testing.assert_array_equal(radius_outliers(xyz, radius_mm, min_points),
                                      radius_outliers_reference(xyz, radius_mm, min_points, method="kdtree"))


# ------------------------------------------------------------------------------------------------
# real sensor data: Kinect clouds (quantized depth, flying pixels, NaN holes)
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["mosd_test16.pcd", "table_scene_mug_stereo_textured.pcd"])
def test_real_clouds_equal_open3d(real_data, name: str) -> None:
    cloud = o3d.io.read_point_cloud(str(real_data / name), remove_nan_points=False, remove_infinite_points=False)
    xyz = np.asarray(cloud.points).reshape(480, 640, 3)
    assert np.isfinite(xyz).all(axis=2).sum() > 100_000
    for radius_mm, min_points in ((5.0, 4), (10.0, 12), (3.0, 2)):
        got = radius_outliers(xyz, radius_mm, min_points)
        assert got.any() and not got.all()
        np.testing.assert_array_equal(got, open3d_outliers(xyz, radius_mm, min_points))


# ------------------------------------------------------------------------------------------------
# bad input
# ------------------------------------------------------------------------------------------------
GOOD = np.zeros((4, 4, 3))


@pytest.mark.parametrize(
    ("args", "error", "match"),
    [
        ((np.zeros((4, 4)), 2.0, 8), InputShapeError, r"xyz must be an \(H, W, 3\) float array, got shape \(4, 4\)"),
        ((np.zeros((4, 4, 3), np.int64), 2.0, 8), InputShapeError, r"int64"),
        ((GOOD, 0.0, 8), ParameterError, r"RadiusParams\.radius_mm must be a number > 0, got 0\.0"),
        ((GOOD, -2, 8), ParameterError, r"RadiusParams\.radius_mm must be a number > 0, got -2"),
        ((GOOD, math.nan, 8), ParameterError, r"got nan"),
        ((GOOD, math.inf, 8), ParameterError, r"got inf"),
        ((GOOD, "2", 8), ParameterError, r"got '2'"),
        ((GOOD, 2.0, 0), ParameterError, r"RadiusParams\.min_points must be an integer >= 1, got 0"),
        ((GOOD, 2.0, 2.5), ParameterError, r"got 2\.5"),
        ((GOOD, 2.0, True), ParameterError, r"got True"),
    ],
)
def test_bad_input(args: tuple, error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        radius_outliers(*args)


def test_numpy_scalars_and_reference_method() -> None:
    xyz = pinhole(np.random.default_rng(13), 10, 10)
    np.testing.assert_array_equal(radius_outliers(xyz, np.float32(20.0), np.int64(3)), radius_outliers(xyz, 20.0, 3))
    with pytest.raises(ParameterError, match="method must be 'brute' or 'kdtree', got 'exact'"):
        radius_outliers_reference(xyz, 20.0, 3, method="exact")
