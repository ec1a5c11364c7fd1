"""zcut_tree: every (max_depth, max_area) of one tree equals the per-point zcut_outliers call, and
its grid counts equal the counts of the explicit masks."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from test_cuts import NASTY, figure6_scene, figure6_truth, random_frame  # the z-cut's own nasty inputs

from zcut import InputShapeError, ParameterError, ZCutParams, find_clusters, zcut_outliers
from zcut.cut_grid import COUNT_KEYS, ZCutTree, zcut_tree
from zcut.cuts import zcut_outliers_reference
from zcut.params import n_levels

AREAS = (0.5, 1.0, 1.5, 2.0, 3.0, 5.0, 12.0, 13.0, 40.0, math.inf)


def explicit_counts(masks, truth, scored, within=None, plus=None) -> dict[str, np.ndarray]:
    """docs/accuracy.md counts from the explicit masks: P = (mask & within) | plus, L = truth, S = scored."""
    n_d, n_a = len(masks), len(masks[0])
    out = {k: np.zeros((n_d, n_a), np.int64) for k in COUNT_KEYS}
    for i in range(n_d):
        for j in range(n_a):
            p = masks[i][j].copy()
            if within is not None:
                p &= within
            if plus is not None:
                p |= plus
            out["tp"][i, j] = np.count_nonzero(p & truth & scored)
            out["fp"][i, j] = np.count_nonzero(p & scored & ~truth)
            out["fn"][i, j] = np.count_nonzero(truth & scored & ~p)
            out["n_pred"][i, j] = np.count_nonzero(p)
    return out


def check_tree(z, tree: ZCutTree, depths, areas, *, clusters: bool = True) -> list[list[np.ndarray]]:
    """Assert tree.outliers (and n_clusters) equal the per-point calls; return the masks."""
    masks = []
    for d in depths:
        row = []
        for a in areas:
            m = zcut_outliers(z, step=tree.step, max_depth=d, max_area=a, connectivity=tree.connectivity)
            got = tree.outliers(d, a)
            assert got.dtype == bool and got.shape == z.shape
            if not np.array_equal(got, m):  # (the message only when needed: real frames are big)
                pytest.fail(f"tree.outliers({d!r}, {a!r}) differs from zcut_outliers on "
                            f"{np.count_nonzero(got != m)} pixels: {(z.tolist(), tree.step)!r}")
            if clusters:
                res = find_clusters(z, params=ZCutParams(tree.step, d, a, connectivity=tree.connectivity))
                assert tree.n_clusters(d, a) == res.n_clusters
            row.append(m)
        masks.append(row)
    return masks


def grid_depths(rng: np.random.Generator, step: float, max_depth: float) -> list[float]:
    """0, the tree's depth, multiples of step (on the rounding edge) and arbitrary values below."""
    K = n_levels(step, max_depth)
    ds = [0.0, max_depth, *(float(k) * step for k in range(0, K + 1, max(1, K // 3)))]
    ds += [float(x) for x in rng.uniform(0, max_depth, 3)]
    return [d for d in ds if n_levels(step, d) <= K]


@pytest.fixture(params=["flood", "union-find"])
def kernel(request) -> str:
    return request.param


@pytest.mark.parametrize("seed", range(6))
def test_tree_equals_per_point_calls_on_random_frames(seed: int, kernel: str) -> None:
    rng = np.random.default_rng(4000 + seed)
    n_outliers = n_nested = 0
    for _ in range(60):  # 6 x 60 = 360 frames, ~10 x 11 grid points each
        z, p = random_frame(rng)
        tree = zcut_tree(z, step=p["step"], max_depth=p["max_depth"], connectivity=p["connectivity"],
                         kernel=kernel)
        assert tree.shape == z.shape and tree.n_levels == n_levels(p["step"], p["max_depth"])
        depths = grid_depths(rng, p["step"], p["max_depth"])
        areas = [*AREAS, float(rng.uniform(1, 30))]
        masks = check_tree(z, tree, depths, areas, clusters=kernel == "flood")
        n_outliers += sum(int(m.sum()) for row in masks for m in row)
        n_nested += int(np.count_nonzero(tree.node_parent >= 0))  # taggable nodes inside others
        truth, scored, within, plus = (rng.random(z.shape) < f for f in (0.3, 0.8, 0.7, 0.1))
        for w, q in ((None, None), (within, plus), (within, None), (None, plus)):
            got = tree.counts(depths, areas, truth=truth, scored=scored, within=w, plus=q)
            want = explicit_counts(masks, truth, scored, w, q)
            assert list(got) == list(COUNT_KEYS)
            for key in COUNT_KEYS:
                assert got[key].dtype == np.int64 and got[key].shape == (len(depths), len(areas))
                np.testing.assert_array_equal(got[key], want[key], err_msg=key)
    assert n_outliers > 0 and n_nested > 0


@pytest.mark.parametrize("conn", [8, 4])
@pytest.mark.parametrize("name", list(NASTY))
def test_nasty_cases(name: str, conn: int, kernel: str) -> None:
    z, case, expected = NASTY[name]
    step, d = case["step"], case["max_depth"]
    for tree_depth in (d, 3 * d + step):  # the case's own tree, and a deeper one
        tree = zcut_tree(z, step=step, max_depth=tree_depth, connectivity=conn, kernel=kernel)
        masks = check_tree(z, tree, [d, 0.0, d / 2], [case["max_area"], *AREAS])
        np.testing.assert_array_equal(masks[0][0], zcut_outliers_reference(z, **{**case, "connectivity": conn}))
        if expected is not None and conn == case.get("connectivity", 8):
            np.testing.assert_array_equal(tree.outliers(d, case["max_area"]), expected)
        for a in (0.5, 1.0):  # no component has fewer than one pixel
            assert not tree.outliers(tree_depth, a).any()


def test_depths_between_multiples_of_the_step() -> None:
    """K = floor(d / step + 1e-9) for every d on its own: 0.6 / 0.2 = 2.9999999999999996 gives 3."""
    z = np.array([[0.6, 0.0, 0.0, 0.4, 0.2]])
    tree = zcut_tree(z, step=0.2, max_depth=1.0)
    assert tree.n_levels == 5
    for d in (0.19, 0.2, 0.21, 0.39999999999, 0.4, 0.59, 0.6, 0.61, 0.8, 0.99, 1.0, 1.0000000001):
        assert n_levels(0.2, d) <= 5
        for a in (1.5, 2, 3, math.inf):
            np.testing.assert_array_equal(tree.outliers(d, a), zcut_outliers_reference(
                z, step=0.2, max_depth=d, max_area=a))


def test_float32_input_is_upcast() -> None:
    z32 = np.array([[0.3, 0.1, 0.2], [0.1, 0.0, 0.3]], np.float32)
    t32 = zcut_tree(z32, step=0.1, max_depth=0.5)
    t64 = zcut_tree(z32.astype(np.float64), step=0.1, max_depth=0.5)
    for d in (0.1, 0.2, 0.3, 0.5):
        for a in (2, 3, 4):
            np.testing.assert_array_equal(t32.outliers(d, a), t64.outliers(d, a))
            np.testing.assert_array_equal(t32.outliers(d, a), zcut_outliers_reference(
                z32, step=0.1, max_depth=d, max_area=a))


def test_figure6_and_figure11() -> None:
    z = figure6_scene()
    floating, walled = figure6_truth()
    tree = zcut_tree(z, step=0.5, max_depth=8.0)
    np.testing.assert_array_equal(tree.outliers(8.0, 5), floating | walled)
    assert tree.n_clusters(8.0, 5) == 2 and tree.n_clusters(8.0, 4) == 0
    # the walled patch enters the cuts at level 10 (5 mm): not checked with d_max < 5 mm
    np.testing.assert_array_equal(tree.outliers(4.5, 5), floating)
    assert tree.n_clusters(4.5, 5) == 1


def test_without_valid_pixels_or_levels_only_plus_counts() -> None:
    truth = np.array([[True, False, True]])
    scored = np.array([[True, True, False]])
    plus = np.array([[True, True, False]])
    for z, d in ((np.full((1, 3), np.nan), 1.0), (np.array([[9.0, 0.0, 0.0]]), 0.5)):
        tree = zcut_tree(z, step=1.0, max_depth=d)
        assert tree.node_kmin.size == 0 and (tree.node_of_pixel == -1).all()
        assert not tree.outliers(d, math.inf).any() and tree.n_clusters(d, math.inf) == 0
        got = tree.counts([d, 0.0], [2.0, math.inf, 1.0], truth=truth, scored=scored, plus=plus)
        for key, value in (("tp", 1), ("fp", 1), ("fn", 0), ("n_pred", 2)):
            np.testing.assert_array_equal(got[key], np.full((2, 3), value))
    tree = zcut_tree(np.zeros((0, 4)), step=0.2, max_depth=1.0)
    assert tree.outliers(1.0, 5).shape == (0, 4)
    got = tree.counts([1.0], [5], truth=np.zeros((0, 4), bool), scored=np.zeros((0, 4), bool))
    assert all(got[k].shape == (1, 1) and got[k][0, 0] == 0 for k in COUNT_KEYS)


def test_grid_order_repeats_and_empty_grids() -> None:
    """The grid's values may come in any order and repeat; the rows and columns follow them."""
    rng = np.random.default_rng(7)
    z, p = random_frame(rng)
    while not np.isfinite(z).sum() > 20:
        z, p = random_frame(rng)
    step = p["step"]
    tree = zcut_tree(z, step=step, max_depth=12 * step)
    depths = [12 * step, 0.0, 3 * step, 12 * step, 5.5 * step]
    areas = [math.inf, 3.0, 1.0, 3.0, 7.5]
    truth, scored = rng.random(z.shape) < 0.3, rng.random(z.shape) < 0.9
    got = tree.counts(np.array(depths), tuple(areas), truth=truth, scored=scored)
    want = explicit_counts(check_tree(z, tree, depths, areas, clusters=False), truth, scored)
    for key in COUNT_KEYS:
        np.testing.assert_array_equal(got[key], want[key])
    assert all(v.shape == (0, 5) for v in tree.counts([], areas, truth=truth, scored=scored).values())
    assert all(v.shape == (5, 0) for v in tree.counts(depths, [], truth=truth, scored=scored).values())


def test_a_real_frame(real_data) -> None:
    """A real Kinect cloud (480 x 640): a 6 x 6 sweep of the paper's parameters, every mask equal
    to the per-point call, the counts equal to the explicit ones."""
    from replay.logs.pcd import read_pcd

    z = -1000.0 * read_pcd(real_data / "mosd_test24.pcd").xyz[..., 2].astype(np.float64)
    depths = list(np.linspace(10.0, 50.0, 6))
    areas = list(np.linspace(0.02, 0.2, 6) * 0.01 * z.size)
    tree = zcut_tree(z, step=0.2, max_depth=50.0)
    masks = check_tree(z, tree, depths, areas, clusters=False)
    assert masks[-1][-1].sum() > masks[0][0].sum() > 0
    truth = masks[2][2]  # stands in for labels: what some parameter set finds
    valid = np.isfinite(z)
    zone = valid.copy()
    zone[:, : z.shape[1] // 2] = False  # the z-cut judges the right half
    plus = np.zeros(z.shape, bool)
    plus[:40] = valid[:40]  # the easy outliers above the rim
    got = tree.counts(depths, areas, truth=truth, scored=valid, within=zone, plus=plus)
    want = explicit_counts(masks, truth, valid, zone, plus)
    for key in COUNT_KEYS:
        np.testing.assert_array_equal(got[key], want[key])


# --------------------------------------------------------------------------------------------
# Laws (hypothesis)
# --------------------------------------------------------------------------------------------


@st.composite
def frames_and_grids(draw):
    """Heights = small integers x step/2 with a power-of-two step, some NaN; a grid of 3 x 3."""
    step = draw(st.sampled_from([0.125, 0.25, 0.5, 1.0]))
    shape = draw(hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=9))
    z = draw(hnp.arrays(np.int64, shape, elements=st.integers(-30, 30))) * (step / 2)
    nan = draw(hnp.arrays(np.bool_, shape, elements=st.booleans()))
    z[nan & draw(st.booleans())] = np.nan
    depth = draw(st.integers(0, 14)) * step / 2
    depths = sorted(draw(st.lists(st.integers(0, 14), min_size=3, max_size=3)))
    areas = sorted(draw(st.lists(st.integers(1, 25), min_size=3, max_size=3)))
    return z, step, max(depth, depths[-1] * step / 2), [d * step / 2 for d in depths], areas, \
        draw(st.sampled_from([4, 8]))


@settings(max_examples=200, deadline=None)
@given(frames_and_grids(), st.integers(0, 2**32 - 1))
def test_monotonic_in_max_area_and_max_depth(frame, seed: int) -> None:
    """A larger μ_thr or d_max never removes an outlier (larger K checks more level pairs, a
    larger area admits more components); so n_pred and TP never decrease along the grid, FN
    never increases; and the tree agrees with the oracle."""
    z, step, tree_depth, depths, areas, conn = frame
    tree = zcut_tree(z, step=step, max_depth=tree_depth, connectivity=conn)
    masks = [[tree.outliers(d, a) for a in areas] for d in depths]
    for i, d in enumerate(depths):
        for j, a in enumerate(areas):
            np.testing.assert_array_equal(masks[i][j], zcut_outliers_reference(
                z, step=step, max_depth=d, max_area=a, connectivity=conn))
            if j:
                assert not (masks[i][j - 1] & ~masks[i][j]).any()
            if i:
                assert not (masks[i - 1][j] & ~masks[i][j]).any()
    assert not (masks[-1][-1] & ~np.isfinite(z)).any()
    rng = np.random.default_rng(seed)
    truth, scored, within, plus = (rng.random(z.shape) < f for f in (0.3, 0.8, 0.7, 0.1))
    got = tree.counts(depths, areas, truth=truth, scored=scored, within=within, plus=plus)
    for axis in (0, 1):
        assert (np.diff(got["n_pred"], axis=axis) >= 0).all()
        assert (np.diff(got["tp"], axis=axis) >= 0).all()
        assert (np.diff(got["fn"], axis=axis) <= 0).all()
    np.testing.assert_array_equal(got["tp"] + got["fn"], np.count_nonzero(truth & scored))


# --------------------------------------------------------------------------------------------
# The object and bad input
# --------------------------------------------------------------------------------------------


def test_tree_is_frozen_and_read_only() -> None:
    tree = zcut_tree(figure6_scene(), step=0.5, max_depth=8.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        tree.step = 1.0  # type: ignore[misc]
    for a in (tree.node_of_pixel, tree.node_kmin, tree.node_size, tree.node_parent, tree.node_valid):
        assert not a.flags.writeable
    assert tree.node_of_pixel.dtype == np.int32 and tree.node_kmin.dtype == np.int64


GOOD = dict(step=0.2, max_depth=3.0)
BAD_BUILD = [
    (np.zeros(5), {}, InputShapeError, r"height .*shape \(5,\)"),
    (np.zeros((2, 2), np.int32), {}, InputShapeError, r"height .*int32"),
    (np.zeros((2, 2)), dict(step=0.0), ParameterError, r"step .*got 0\.0"),
    (np.zeros((2, 2)), dict(step=math.nan), ParameterError, r"step .*got nan"),
    (np.zeros((2, 2)), dict(max_depth=-1.0), ParameterError, r"max_depth .*got -1\.0"),
    (np.zeros((2, 2)), dict(max_depth=math.inf), ParameterError, r"max_depth .*got inf"),
    (np.zeros((2, 2)), dict(connectivity=6), ParameterError, r"connectivity .*got 6"),
    (np.zeros((2, 2)), dict(kernel="fast"), ParameterError, r"kernel must be one of .*got 'fast'"),
    (np.zeros((2, 2)), dict(kernel=None), ParameterError, r"kernel must be one of .*got None"),
    (np.array([[0.0, 40000.0]]), dict(step=1.0, max_depth=1e5, kernel="flood"), ParameterError,
     r"kernel 'flood' builds trees of fewer than 32768 levels, this one needs 40003"),
]


@pytest.mark.parametrize(("height", "override", "error", "match"), BAD_BUILD)
def test_bad_build_input(height, override, error, match) -> None:
    with pytest.raises(error, match=match):
        zcut_tree(height, **{**GOOD, **override})


M = np.zeros((3, 4), bool)
BAD_QUERY = [
    ("outliers", (3.2, 5), {}, ParameterError, r"max_depth 3\.2 gives K = 16 levels, more than this tree's 15"),
    ("outliers", (-0.1, 5), {}, ParameterError, r"max_depth .*got -0\.1"),
    ("outliers", (math.nan, 5), {}, ParameterError, r"max_depth .*got nan"),
    ("outliers", (3.0, 0), {}, ParameterError, r"max_area .*got 0"),
    ("outliers", (3.0, math.nan), {}, ParameterError, r"max_area .*got nan"),
    ("outliers", (3.0, "5"), {}, ParameterError, r"max_area .*got '5'"),
    ("n_clusters", (4.0, 5), {}, ParameterError, r"max_depth 4\.0 gives K = 20 levels"),
    ("counts", ([1.0, 3.5], [5]), dict(truth=M, scored=M), ParameterError,
     r"max_depths 3\.5 gives K = 17 levels"),
    ("counts", ([[1.0]], [5]), dict(truth=M, scored=M), ParameterError,
     r"max_depths must be a 1-D sequence of numbers, got shape \(1, 1\)"),
    ("counts", (1.0, [5]), dict(truth=M, scored=M), ParameterError,
     r"max_depths must be a 1-D sequence of numbers, got shape \(\)"),
    ("counts", ([1.0], [5, -1]), dict(truth=M, scored=M), ParameterError, r"max_areas .*got -1"),
    ("counts", ([1.0], [5]), dict(truth=M[:2], scored=M), InputShapeError,
     r"truth must have shape \(3, 4\) like the other masks, got shape \(2, 4\) bool"),
    ("counts", ([1.0], [5]), dict(truth=M, scored=M.astype(np.uint8)), InputShapeError,
     r"scored must be an \(H, W\) bool array, got shape \(3, 4\) uint8"),
    ("counts", ([1.0], [5]), dict(truth=M, scored=M, within=M.T), InputShapeError, r"within must have shape"),
    ("counts", ([1.0], [5]), dict(truth=M, scored=M, plus=M[0]), InputShapeError, r"plus must be an \(H, W\)"),
]


@pytest.mark.parametrize(("method", "args", "kwargs", "error", "match"), BAD_QUERY)
def test_bad_query(method, args, kwargs, error, match) -> None:
    tree = zcut_tree(np.arange(12.0).reshape(3, 4), **GOOD)
    with pytest.raises(error, match=match):
        getattr(tree, method)(*args, **kwargs)
