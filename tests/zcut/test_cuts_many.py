"""z-cut: one component tree answering several parameter sets (zcut.cuts.StageTree, find_clusters_many)
against find_clusters called for each set and against the literal loop, on synthetic piles, a
ray-traced frame, the real Kinect clouds, large invalid regions and degenerate inputs; sets that share
the tree (another max_area, another a_max) and sets that cannot (another step, K or connectivity:
a tree of their own)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_cuts_fast import bumpy, height_mm, same_result

from zcut import ZCutParams, find_clusters, zcut_outliers_reference
from zcut.cut_tree import SEGMENT, SHALLOW_LEVELS, retag
from zcut.cuts import StageTree, _finite_range, _flood, _flood_scratch, _levels, find_clusters_many
from zcut.errors import InputShapeError, ParameterError
from zcut.params import n_levels

NOMINAL = ZCutParams(step=0.2, max_depth=30.0, max_area=210.0, a_max=3000.0)


def pairs(step: float, max_depth: float, max_area: float) -> list[tuple[ZCutParams, ZCutParams]]:
    """(A, B) pairs: B shares A's tree (another max_area, smaller or larger, or +inf; another a_max;
    another max_depth of the same K), or cannot (another step, another K, 4-connectivity)."""
    a = ZCutParams(step, max_depth, max_area, a_max=1000.0)
    return [
        (a, ZCutParams(step, max_depth, max_area / 2, a_max=1000.0)),
        (a, ZCutParams(step, max_depth, max_area * 3, a_max=500.0)),
        (a, ZCutParams(step, max_depth, math.inf)),
        (a, ZCutParams(step, max_depth, 1.0, a_max=1000.0)),
        (a, ZCutParams(step, max_depth + 0.3 * step, max_area / 2, a_max=1000.0)),  # the same K
        (a, ZCutParams(step, max_depth, max_area)),  # the same max_area, no a_max
        (a, ZCutParams(step / 2, max_depth, max_area / 2, a_max=1000.0)),  # falls back
        (a, ZCutParams(step, max_depth / 2, max_area / 2, a_max=1000.0)),  # another K: falls back
        (a, ZCutParams(step, max_depth, max_area / 2, a_max=1000.0, connectivity=4)),  # falls back
    ]


def check_many(z: np.ndarray, step: float, max_depth: float, max_area: float, *, reference: bool = True) -> None:
    for a, b in pairs(step, max_depth, max_area):
        own = [find_clusters(z, params=p) for p in (a, b)]
        for got, want in zip(find_clusters_many(z, params=(a, b)), own, strict=True):
            same_result(got, want)
        tree = StageTree(z, params=a)
        shared = tree.shares(b)
        assert shared == (b.step == a.step and b.n_levels == a.n_levels and b.connectivity == a.connectivity)
        same_result(tree.answer(b), own[1])  # B first, then A: the order does not matter
        same_result(tree.answer(a), own[0])
        same_result(tree.answer(b), own[1])  # asked again
        assert tree.trees == (1 if shared else 3) or not np.isfinite(z).any()
        if reference:
            for p, r in zip((a, b), own, strict=True):
                np.testing.assert_array_equal(r.outliers, zcut_outliers_reference(
                    z, step=p.step, max_depth=p.max_depth, max_area=p.max_area, connectivity=p.connectivity))
    for kernel in ("flood", "union-find"):  # an explicit kernel: the same answers
        a, b = pairs(step, max_depth, max_area)[0]
        for got, p in zip(find_clusters_many(z, params=(a, b), kernel=kernel), (a, b), strict=True):
            same_result(got, find_clusters(z, params=p, kernel=kernel))


def test_retag_is_the_floods_own_tag() -> None:
    """retag with the flood's max_area gives the flood's tags, node for node (then any max_area gives
    the tags the flood would have given: the tree does not depend on it)."""
    rng = np.random.default_rng(11)
    for conn in (8, 4):
        z = bumpy(rng, 60, 2 * SEGMENT + 9, 0.5)
        z[rng.random(z.shape) < 0.2] = np.nan
        for max_area in (1.0, 7.0, 30.0, 300.0, math.inf):
            K = n_levels(0.5, 6.0)
            n, z_min, z_max, seg = _finite_range(z)
            tree = _flood(z, seg, z_min, z_max, 0.5, K, max_area, conn)
            assert tree is not None
            tagged = np.empty(tree.node_b.size, np.bool_)
            k_eff, _ = _levels(z_min, z_max, 0.5, K)
            retag(tree.node_b, tree.node_size, tree.node_parent, np.int64(k_eff), float(max_area), tagged)
            np.testing.assert_array_equal(tagged, tree.tagged)
            assert 0 < tagged.sum() < tagged.size or max_area == 1.0


@pytest.mark.parametrize(("kind", "seed"), [("zinc_nuts", 21), ("spheres", 22), ("rods", 23)])
def test_synthetic_piles(kind: str, seed: int) -> None:
    from replay.synth import synthesize_frame

    z = height_mm(synthesize_frame(kind=kind, seed=seed, size=(120, 200)).frame.xyz)
    assert np.isfinite(z).any()
    check_many(z, 0.2, 30.0, 210.0)
    check_many(z, 0.5, 60.0, 40.0)


def test_raytraced_frame() -> None:
    from replay.synth.raytrace import synthesize_raytraced_frame

    z = height_mm(synthesize_raytraced_frame(kind="zinc_nuts", seed=904, size=(60, 96), fill_mm=6.0).frame.xyz)
    check_many(z, 0.2, 30.0, 120.0)


@pytest.mark.parametrize("name", ["mosd_test16.pcd", "table_scene_mug_stereo_textured.pcd"])
def test_real_kinect_clouds(real_data, name: str) -> None:
    import open3d as o3d

    cloud = o3d.io.read_point_cloud(str(real_data / name), remove_nan_points=False, remove_infinite_points=False)
    z = height_mm(np.asarray(cloud.points).reshape(480, 640, 3))
    a, b = NOMINAL, ZCutParams(step=0.2, max_depth=30.0, max_area=12.0, a_max=3000.0)
    got = find_clusters_many(z, params=(a, b))
    for r, p in zip(got, (a, b), strict=True):
        same_result(r, find_clusters(z, params=p))
    # B's clusters lie inside A's, and the smaller max_area tags fewer pixels, not none
    assert not (got[1].outliers & ~got[0].outliers).any()
    assert got[0].outliers.sum() > got[1].outliers.sum() > 0
    check_many(z[100:300, 50:400], 1.0, 120.0, 500.0)


@pytest.mark.parametrize("seed", range(3))
def test_large_invalid_regions(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    z = bumpy(rng, 70, 3 * SEGMENT + 17, 0.5)
    z[:, : 2 * SEGMENT] = np.nan
    z[10:40, 150:] = np.nan
    z[rng.random(z.shape) < 0.3] = np.nan
    z[5, 200] = np.inf
    check_many(z, 0.5, 3.0, 30.0)
    check_many(z.astype(np.float32), 0.5, 200.0, 8.0)


@pytest.mark.parametrize("case", ["all_nan", "one_valid", "constant", "one_row", "two_values", "empty"])
def test_degenerate(case: str) -> None:
    z = {
        "all_nan": np.full((5, 70), np.nan),
        "one_valid": np.where(np.arange(200).reshape(10, 20) == 57, 3.0, np.nan),
        "constant": np.full((9, 130), 7.0),
        "one_row": np.array([[0.0, 2.0, 2.0, 0.0, np.nan, 3.0, 0.0]]),
        "two_values": np.where(np.random.default_rng(1).random((20, 140)) < 0.1, 2.0, 0.0),
        "empty": np.zeros((0, 5)),
    }[case]
    check_many(z, 0.5, 2.0, 4.0)
    check_many(z, 1.0, 0.0, 4.0)  # K = 0: no cluster


def test_many_levels_share_the_deep_flood() -> None:
    """6,000 levels (beyond the two-tier bucket map, SHALLOW_LEVELS: the flood's three-tier map; every level
    count find_clusters takes floods) share the flood's tree; with the union-find the tree is not kept:
    each set gets its own. The same answers."""
    rng = np.random.default_rng(4)
    z = bumpy(rng, 30, 70, 0.5) * 400.0
    a = ZCutParams(step=0.01, max_depth=60.0, max_area=20.0)
    b = ZCutParams(step=0.01, max_depth=60.0, max_area=5.0)
    assert a.n_levels > SHALLOW_LEVELS
    tree = StageTree(z, params=a)
    assert tree.shares(b)
    assert not StageTree(z, params=a, kernel="union-find").shares(b)
    for got, p in zip(find_clusters_many(z, params=(a, b)), (a, b), strict=True):
        same_result(got, find_clusters(z, params=p))
        same_result(got, find_clusters(z, params=p, kernel="union-find"))
    tree.answer(b)
    assert tree.trees == 1


def test_bad_input_is_find_clusters_error() -> None:
    good = ZCutParams(step=0.5, max_depth=2.0, max_area=4.0)
    with pytest.raises(ParameterError, match="params must be a ZCutParams"):
        find_clusters_many(np.zeros((2, 2)), params=(good, {"step": 0.5}))  # type: ignore[arg-type]
    with pytest.raises(InputShapeError, match=r"\(H, W\) real float"):
        find_clusters_many(np.zeros(4), params=(good,))
    with pytest.raises(ParameterError, match="kernel must be one of"):
        find_clusters_many(np.zeros((2, 2)), params=(good,), kernel="fast")
    with pytest.raises(ParameterError, match="more than find_clusters supports"):
        StageTree(np.zeros((2, 2)), params=good).answer(ZCutParams(step=1e-6, max_depth=1.0, max_area=5))
    assert find_clusters_many(np.zeros((2, 2)), params=()) == []


def test_a_caller_cannot_corrupt_another_answer() -> None:
    """The answers of one tree share its ``pixel_level``: it is read-only, so a caller writing into
    its answer gets an error and the other answers (and later ones) keep their levels; the masks,
    labels and counts are each answer's own."""
    rng = np.random.default_rng(8)
    z = bumpy(rng, 40, 90, 0.5)
    a = ZCutParams(step=0.5, max_depth=4.0, max_area=30.0)
    b = ZCutParams(step=0.5, max_depth=4.0, max_area=6.0)
    tree = StageTree(z, params=a)
    first, second = tree.answer(a), tree.answer(b)
    assert np.shares_memory(first.pixel_level, second.pixel_level)  # shared, as documented
    levels = second.pixel_level.copy()
    with pytest.raises(ValueError, match="read-only"):
        first.pixel_level[0, 0] = 99
    with pytest.raises(ValueError, match="read-only"):
        first.pixel_level.fill(-1)
    first.outliers[:] = True  # the answer's own arrays: writable, and nobody else's
    first.clusters[:] = 7
    first.level_counts[:] = 0
    np.testing.assert_array_equal(second.pixel_level, levels)
    same_result(second, find_clusters(z, params=b))
    same_result(tree.answer(a), find_clusters(z, params=a))
    for got, p in zip(find_clusters_many(z, params=(a, b)), (a, b), strict=True):
        assert not got.pixel_level.flags.writeable
        same_result(got, find_clusters(z, params=p))


def test_trees_kept_alive_do_not_share_scratch() -> None:
    """The flood's frame-sized arrays are views of one block a call (``zcut.cuts._flood_scratch``):
    disjoint, and never reused by another call while a tree (or an answer) still holds them. Trees of
    two part kinds, a frame with a large invalid region and a degenerate one, built and dropped in
    between, answer as their own fresh calls."""
    from replay.synth import synthesize_frame

    views = _flood_scratch(1000)
    assert [v.size for v in views] == [1000] * 4 and [v.dtype for v in views] == [np.int16] + [np.int32] * 3
    for i, a in enumerate(views):
        for b in views[i + 1:]:
            assert not np.shares_memory(a, b)
    rng = np.random.default_rng(57)
    frames = [height_mm(synthesize_frame(kind=kind, seed=seed, size=(90, 150)).frame.xyz)
              for kind, seed in (("zinc_nuts", 58), ("rods", 59))]
    holes = bumpy(rng, 90, 150, 0.2)
    holes[20:70, 30:110] = np.nan
    frames += [holes, np.full((1, 1), 3.0)]
    p = ZCutParams(0.2, 30.0, 210.0, a_max=3000.0)
    q = ZCutParams(0.2, 30.0, 40.0, a_max=3000.0)  # shares each tree
    want = [(find_clusters(z, params=p), find_clusters(z, params=q)) for z in frames]
    trees = [StageTree(z, params=p) for z in frames]
    first = [t.answer(p) for t in trees]
    for z in frames[::-1]:  # more calls, their blocks freed, while the trees live
        find_clusters(z, params=p)
        find_clusters_many(z, params=(p, q))
    for t, got, (wp, wq) in zip(trees, first, want, strict=True):
        same_result(got, wp)
        same_result(t.answer(q), wq)
        same_result(t.answer(p), wp)
