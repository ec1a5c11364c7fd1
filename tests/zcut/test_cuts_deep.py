"""The z-cut's flood with many levels (the three-tier bucket map, ``SHALLOW_LEVELS`` .. ``FLOOD_MAX_LEVELS``)
and with every pixel in the cuts (:func:`zcut.cut_tree.flood_whole`: the deepest level not flooded), as the
suspects' floating detector calls :func:`zcut.find_clusters` (a fine step over the zone's whole height range).

Oracles: the literal loop (:func:`zcut.zcut_outliers_reference`) for the masks, the union-find kernel
(``find_clusters(..., kernel="union-find")``, which neither change touches) for every field of the stage view.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_cuts_fast import bumpy, height_mm, same_result

from zcut import ZCutParams, find_clusters, zcut_outliers, zcut_outliers_reference
from zcut.cut_tree import FLOOD_MAX_LEVELS, SHALLOW_LEVELS, flood_core, flood_core_deep, flood_whole, level_counts
from zcut.cuts import _finite_range, _flood, _flood_scratch, _levels, _stage_params, find_clusters_many
from zcut.params import n_levels

#: The suspects' floating detector's area limit (SuspectParams().floating_rho * a_max at a_max 2880 px).
SUSPECT_AREA = 3456.0


def suspects_params(z: np.ndarray, step: float = 0.1, max_area: float = SUSPECT_AREA) -> ZCutParams:
    """The parameters of the suspects' call (zcut.suspects.floating): the step, at least the span over
    ``MAX_STAGE_LEVELS - 2`` levels, and a depth of the span plus a step: every pixel in the cuts."""
    fin = z[np.isfinite(z)]
    span = float(fin.max() - fin.min()) if fin.size else 0.0
    step = max(step, span / (32766 - 2))
    return ZCutParams(step=step, max_depth=span + step, max_area=max_area)


def check_all(z: np.ndarray, p: ZCutParams, *, reference: bool = True) -> None:
    """find_clusters by every kernel, field by field, against the union-find's; zcut_outliers and the
    stage's outliers against the literal loop (when ``reference``)."""
    uf = find_clusters(z, params=p, kernel="union-find")
    for kernel in ("auto", "flood"):
        same_result(find_clusters(z, params=p, kernel=kernel), uf)
    kw = dict(step=p.step, max_depth=p.max_depth, max_area=p.max_area, connectivity=p.connectivity)
    got = zcut_outliers(z, **kw)
    np.testing.assert_array_equal(got, uf.outliers)
    if reference:
        np.testing.assert_array_equal(got, zcut_outliers_reference(z, **kw))


def whole(z: np.ndarray, p: ZCutParams) -> bool:
    """Every pixel of z in the cuts of p (flood_whole's case)."""
    step, max_area, connectivity, K = _stage_params(p)
    n, lo, hi, seg = _finite_range(np.ascontiguousarray(z, dtype=np.float64))
    if n == 0:
        return False
    _, top = _levels(lo, hi, step, K)
    return bool(lo >= hi - top * step)


# ------------------------------------------------------------------------------------------------
# many levels: the three-tier bucket map
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("seed", "n_cuts"), [(0, 4100), (1, 5000), (2, 9000), (3, 17067), (4, 32000)])
def test_deep_queue_equals_the_union_find(seed: int, n_cuts: int) -> None:
    """Noisy frames with 4,100 .. 32,000 levels (the ray-traced frame's 17,067 among them): the three-tier map
    spans many words of each tier; the flood's tree, field by field, is the union-find's."""
    rng = np.random.default_rng(500 + seed)
    H, W = 23, 37
    step = 0.1
    z = np.cumsum(rng.normal(0.0, 1.0, (H, W)), axis=1) + rng.normal(0.0, 0.05, (H, W))
    z = (z - z.min()) / (z.max() - z.min()) * n_cuts * step  # the range: n_cuts levels
    z[rng.random((H, W)) < 0.15] = np.nan
    z[5:9, 10:20] = np.nanmax(z) + rng.uniform(2 * step, 8 * step, (4, 10))  # a plateau floating at the top
    fin = z[np.isfinite(z)]
    assert (fin.max() - fin.min()) / step > SHALLOW_LEVELS
    for max_depth in (0.9 * n_cuts * step, (fin.max() - fin.min()) + step):
        for conn in (8, 4):
            p = ZCutParams(step=step, max_depth=max_depth, max_area=12.0, connectivity=conn)
            assert p.n_levels <= 32766
            check_all(z, p, reference=seed < 2 and conn == 8)


def test_deep_queue_sparse_levels() -> None:
    """A few pixels over 30,000 levels, far apart in level: the map's search crosses empty words of every tier
    (a word's last bit, the next middle word, the summary)."""
    step = 1.0
    levels = [0, 63, 64, 4095, 4096, 4097, 8191, 8192, 12000, 20000, 24575, 24576, 30000, 32700]
    z = np.full((4, len(levels)), np.nan)
    z[1] = 40000.0 - np.array(levels, float)
    z[2, ::3] = 40000.0 - np.array(levels[::3], float) - 1.0
    z[0, 0] = 40000.0
    z[3, -1] = 40000.0 - 32760.0
    for max_area in (1.0, 2.0, 3.0, math.inf):
        for conn in (8, 4):
            check_all(z, ZCutParams(step=step, max_depth=32760.0, max_area=max_area, connectivity=conn))


def test_deep_and_shallow_flood_cores_agree() -> None:
    """The same prepared state flooded with the two-tier and the three-tier map (below SHALLOW_LEVELS both
    apply): the same nodes in the same order, bit for bit."""
    rng = np.random.default_rng(77)
    z = bumpy(rng, 60, 150, 0.2) * 20.0
    z[rng.random(z.shape) < 0.1] = np.nan
    p = ZCutParams(step=0.2, max_depth=300.0, max_area=30.0)
    step, max_area, connectivity, K = _stage_params(p)
    n, lo, hi, seg = _finite_range(z)
    k_eff, top = _levels(lo, hi, step, K)
    assert 200 < top < SHALLOW_LEVELS
    H, W = z.shape
    outs = []
    for core in (flood_core, flood_core_deep):
        tree = _flood(z, seg, lo, hi, step, K, max_area, connectivity)
        assert tree is not None
        st, pix, own, lab = _flood_scratch((H + 2) * (W + 2))
        from zcut.cut_tree import flood_levels

        start = np.zeros(top + 2, np.int64)
        m = int(flood_levels(z, seg, lo, hi, step, np.int64(k_eff + 2), np.int64(top), np.int64(K), st, start, pix,
                             own, np.empty((1, 1), np.int16), False))
        res = core(st, start, pix[:m], W, np.int64(k_eff), np.int64(top), True, max_area, lab)
        outs.append((*res, lab[pix[:m]].copy()))
    for a, b in zip(*outs, strict=True):
        np.testing.assert_array_equal(a, b)


# ------------------------------------------------------------------------------------------------
# every pixel in the cuts: the deepest level not flooded
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(6))
def test_whole_range_on_piles_with_large_invalid_regions(seed: int) -> None:
    """The suspects' parameters (step 0.1, the whole range) on crops of piles with large invalid regions,
    scattered dropouts and infinities: every field as the union-find's, the mask as the literal loop's."""
    rng = np.random.default_rng(900 + seed)
    H, W = 64, 150
    z = bumpy(rng, H, W, 0.5) * 4.0
    if seed % 2:
        z[:, : W // 3] = np.nan  # a third of the width invalid
    z[10:40, 90:130] = np.nan  # a block
    z[rng.random(z.shape) < 0.2] = np.nan
    z[3, 7] = np.inf
    z[4, 8] = -np.inf
    p = suspects_params(z, max_area=float(rng.choice([3.0, 30.0, 400.0, SUSPECT_AREA])))
    assert whole(z, p) and p.n_levels > 100
    check_all(z, p, reference=seed < 3)
    p4 = ZCutParams(step=p.step, max_depth=p.max_depth, max_area=p.max_area, connectivity=4)
    check_all(z, p4, reference=False)


@pytest.mark.parametrize(("kind", "seed"), [("spheres", 3), ("zinc_nuts", 1), ("black_nuts", 2), ("sprockets", 4)])
def test_whole_range_on_synthetic_scans(kind: str, seed: int) -> None:
    """The kinds of the suspects' bench frames (bench/bench_suspects_steps.py), small, at the suspects'
    parameters, and at a step of 0.01 mm (10 x as many levels; the deep map where it passes SHALLOW_LEVELS)."""
    from replay.synth import synthesize_frame

    z = height_mm(synthesize_frame(kind=kind, seed=seed, size=(96, 160),
                                   quantize_mm=1.0 if kind == "spheres" else 0.0).frame.xyz)
    for step in (0.1, 0.01):
        p = suspects_params(z, step=step)
        assert whole(z, p)
        check_all(z, p, reference=step == 0.1)


def test_whole_range_on_a_raytraced_frame() -> None:
    from replay.synth.raytrace import synthesize_raytraced_frame

    z = height_mm(synthesize_raytraced_frame(kind="zinc_nuts", seed=905, size=(60, 96)).frame.xyz)
    p = suspects_params(z, step=0.01)
    assert whole(z, p)
    check_all(z, p, reference=False)
    check_all(z, suspects_params(z), reference=True)


@pytest.mark.parametrize("shape", [(1, 1), (1, 9), (9, 1), (2, 2), (3, 70), (70, 3)])
def test_whole_range_degenerate(shape: tuple[int, int]) -> None:
    """One pixel, one row, one column, tiny frames: valid, constant, one valid pixel, every pixel at the
    deepest level but one, all NaN (nothing valid: no tree)."""
    rng = np.random.default_rng(sum(shape))
    H, W = shape
    frames = [rng.normal(0.0, 1.0, shape), np.full(shape, 2.5), np.full(shape, np.nan)]
    one = np.full(shape, np.nan)
    one[H // 2, W // 2] = 1.0
    frames.append(one)
    low = np.zeros(shape)
    low[0, 0] = 3.0
    frames.append(low)
    for z in frames:
        for max_area in (1.0, 2.0, float(H * W), H * W + 1.0, math.inf):
            fin = z[np.isfinite(z)]
            span = float(fin.max() - fin.min()) if fin.size else 0.0
            for step in (0.1, 1.0):
                for conn in (8, 4):
                    p = ZCutParams(step=step, max_depth=span + step, max_area=max_area, connectivity=conn)
                    check_all(z, p)


def test_flood_whole_builds_the_same_tree() -> None:
    """flood_whole against flood_core on the same state: the same level counts, the same outermost tagged
    pixel sets, a root born at the deepest level with every pixel, and no node over the deepest pixels but it."""
    rng = np.random.default_rng(31)
    z = bumpy(rng, 50, 140, 0.1) * 10.0
    z[rng.random(z.shape) < 0.3] = np.nan
    z[:, :40] = np.nan
    H, W = z.shape
    p = suspects_params(z, max_area=50.0)
    step, max_area, connectivity, K = _stage_params(p)
    n, lo, hi, seg = _finite_range(z)
    k_eff, top = _levels(lo, hi, step, K)
    from zcut.cut_tree import flood_levels, listed_cluster_labels

    got = []
    for core in (flood_core, flood_whole):
        st, pix, own, lab = _flood_scratch((H + 2) * (W + 2))
        start = np.zeros(top + 2, np.int64)
        m = int(flood_levels(z, seg, lo, hi, step, np.int64(k_eff + 2), np.int64(top), np.int64(K), st, start, pix,
                             own, np.empty((1, 1), np.int16), False))
        assert m == H * W
        qd = int(np.nonzero(start)[0].max()) - 1
        deepest = st[pix[:m]] == qd
        node_b, node_size, node_parent, tagged, fin = core(st, start, pix[:m], W, np.int64(k_eff), np.int64(top),
                                                           True, max_area, lab)
        roots = np.nonzero(node_parent < 0)[0]
        assert roots.size == 1 and node_b[roots[0]] == qd and node_size[roots[0]] == H * W
        assert (lab[pix[:m]][deepest] == roots[0]).all()
        assert sorted(fin.tolist()) == list(range(node_b.size)) and fin[-1] == roots[0]
        counts = np.zeros(K + 1, np.int64)
        level_counts(node_b, node_parent, counts)
        labels = np.zeros(H * W, np.int32)
        outl = np.zeros(H * W, bool)
        tops, areas = listed_cluster_labels(lab, pix[:m], own[:m], fin, node_parent, tagged, labels, outl)
        got.append((counts, labels, areas, node_b[tops]))
    for a, b in zip(*got, strict=True):
        np.testing.assert_array_equal(a, b)
    assert got[0][2].size > 0  # clusters found


def test_many_sets_share_the_whole_tree() -> None:
    """find_clusters_many over area limits at the suspects' step (one tree, retagged): each as its own call."""
    rng = np.random.default_rng(41)
    z = bumpy(rng, 40, 90, 0.3) * 5.0
    z[rng.random(z.shape) < 0.25] = np.nan
    p = suspects_params(z)
    sets = [ZCutParams(step=p.step, max_depth=p.max_depth, max_area=a) for a in (2.0, 20.0, 200.0, 4000.0)]
    for got, q in zip(find_clusters_many(z, params=sets), sets, strict=True):
        same_result(got, find_clusters(z, params=q, kernel="union-find"))


def test_level_limits() -> None:
    assert SHALLOW_LEVELS == 4096 and FLOOD_MAX_LEVELS == 32768
    assert n_levels(1.0, 32766.0) == 32766


@pytest.mark.parametrize("seed", range(4))
def test_whole_frame_with_the_deepest_level_at_the_last_cut(seed: int) -> None:
    """Every pixel in the cuts with z_min exactly at level K + 1 (the last cut, ``top``: the deepest level is
    past K, the root never tagged, the regions ending at K + 1) or at K (the root at K), on integer heights."""
    rng = np.random.default_rng(70 + seed)
    K = int(rng.integers(3, 40))
    for depth_levels in (K + 1, K):
        z = rng.integers(0, depth_levels + 1, (17, 23)).astype(np.float64)
        z[rng.random(z.shape) < 0.2] = np.nan
        z[0, 0], z[16, 22] = float(depth_levels), 0.0  # the range: exactly depth_levels levels
        z[4:8, 4:9] = max(depth_levels - 3.0, 0.0)
        z[5:7, 5:8] = float(depth_levels)  # a cluster at the top, 3 levels above its ring
        for max_area in (2.0, 7.0, 50.0, math.inf):
            for conn in (8, 4):
                p = ZCutParams(step=1.0, max_depth=float(K), max_area=max_area, connectivity=conn)
                assert whole(z, p)
                check_all(z, p)
