"""z-cut: the clusters alone (zcut.cuts.cluster_labels_of: the pruned flood, and for a cut holding every pixel the
same clusters from K' = q_min - 2) against find_clusters' clusters, areas and levels, bit for bit, on the cuts the
suspects' floating detector makes (the zone's whole height range), on shallower and deeper ones, large invalid
regions, the z-cut bench's frames at seeds it does not use, and degenerate inputs; the pruned flood forced on small
frames (``minimum=0``) and giving up its labelling after a row."""

from __future__ import annotations

import math

import numpy as np
import pytest
from bench_frames import bench_kinds
from test_cuts_fast import bumpy, terraces

from zcut import ZCutParams, find_clusters
from zcut.cut_tree import SHALLOW_LEVELS, qlevel
from zcut.cuts import _cluster_labels, _finite_range, _levels, cluster_labels_of
from zcut.params import n_levels


def same_clusters(z: np.ndarray, params: ZCutParams, *, forced: bool = True) -> int:
    """cluster_labels_of (and, with ``forced``, the pruned flood whatever the frame's size, labelling every pixel
    or giving up after the first row) equal to find_clusters' clusters, areas and levels; the cluster count."""
    want = find_clusters(z, params=params)
    runs = [cluster_labels_of(z, params=params)]
    if forced:
        runs += [_cluster_labels(z, params, minimum=0, check=2**40), _cluster_labels(z, params, minimum=0, check=1)]
    for clusters, areas, levels in runs:
        for name, got, exp in (("clusters", clusters, want.clusters), ("areas", areas, want.areas),
                               ("levels", levels, want.levels)):
            assert got.dtype == exp.dtype and got.shape == exp.shape, name
            np.testing.assert_array_equal(got, exp, err_msg=name)
    return want.n_clusters


def whole_range(z: np.ndarray, step: float, max_area: float, extra: float = 1.0) -> ZCutParams:
    """The floating detector's cut: every level of the finite heights' range and ``extra`` steps more."""
    fin = z[np.isfinite(z)]
    span = float(fin.max() - fin.min()) if fin.size else 0.0
    return ZCutParams(step=step, max_depth=span + extra * step, max_area=max_area)


def every_pixel_in_the_cuts(z: np.ndarray, params: ZCutParams) -> bool:
    n, lo, hi, _ = _finite_range(np.ascontiguousarray(z, dtype=np.float64))
    K = n_levels(params.step, params.max_depth)
    return n > 0 and K >= int(qlevel(lo, hi, params.step, np.int64(K + 2))) - 1


@pytest.mark.parametrize("seed", range(8))
def test_whole_range_cuts_on_terraces(seed: int) -> None:
    """Plateaus, cliffs of 1-3 levels, spikes, pits and NaN holes, every tie exact: the floating detector's cut
    (every pixel in the cuts: the clusters of K' = q_min - 2) and cuts one level shallower, at q_min - 2, deeper."""
    rng = np.random.default_rng(4100 + seed)
    step = 0.25
    z = terraces(rng, int(rng.integers(8, 40)), int(rng.integers(8, 150)), step)
    tagged = 0
    for conn in (8, 4):
        for max_area in (1.0, 3.0, 17.0, 60.0, 400.0, float(z.size), z.size + 1.0, math.inf):
            for extra in (1.0, 0.0, -1.0, -2.0, 3.0, 40.0):
                p = whole_range(z, step, max_area, extra)
                if p.max_depth < 0:
                    continue
                p = ZCutParams(step=p.step, max_depth=p.max_depth, max_area=p.max_area, connectivity=conn)
                tagged += same_clusters(z, p)
    assert tagged > 0


@pytest.mark.parametrize("seed", range(4))
def test_whole_range_cuts_on_random_fields(seed: int) -> None:
    """Bumps, floating patches and NaN on the step/2 grid, the floating detector's cut and shallower ones."""
    rng = np.random.default_rng(4200 + seed)
    step = 0.2
    z = bumpy(rng, 60, 150, step)
    z[rng.random(z.shape) < 0.1] = np.nan
    z[10:30, 40:90] = np.nan  # a large invalid region
    assert every_pixel_in_the_cuts(z, whole_range(z, step, 50.0))
    for max_area in (5.0, 50.0, 500.0):
        for p in (whole_range(z, step, max_area), whole_range(z, step, max_area, 0.5),
                  ZCutParams(step=step, max_depth=4.0, max_area=max_area)):
            same_clusters(z, p)


@pytest.mark.parametrize("kind", ["pile", "holes"])
def test_bench_frames_at_held_out_seeds(kind: str) -> None:
    """The z-cut bench's 1920 x 1200 pile and the same with large invalid regions, at seeds the bench does not use,
    cut as the floating detector cuts (0.1 mm steps over the whole range, 3456 px: 0.15 of 1 % of the frame): the
    pruned flood applies (fewer than SHALLOW_LEVELS levels) and gives find_clusters' clusters."""
    z = bench_kinds()[kind](seed=4301)
    p = whole_range(z, 0.1, 3456.0)
    assert every_pixel_in_the_cuts(z, p)
    _, lo, hi, _ = _finite_range(z)
    assert _levels(lo, hi, p.step, n_levels(p.step, p.max_depth))[1] < SHALLOW_LEVELS
    assert same_clusters(z, p, forced=False) > 0


def test_deep_cuts_take_the_whole_flood() -> None:
    """More than SHALLOW_LEVELS levels (a ray-traced frame's far points): the whole tree's flood without the pixel
    levels, the same clusters."""
    rng = np.random.default_rng(4400)
    z = bumpy(rng, 40, 90, 0.2)
    z[0, 0] = z[np.isfinite(z)].min() - 5000 * 0.2  # one far point: ~5000 levels
    z[5:9, 5:30] = np.nan
    p = whole_range(z, 0.2, 40.0)
    _, lo, hi, _ = _finite_range(z)
    assert _levels(lo, hi, p.step, n_levels(p.step, p.max_depth))[1] >= SHALLOW_LEVELS
    assert same_clusters(z, p) > 0


@pytest.mark.parametrize("case", ["no finite", "one pixel", "flat", "two levels", "one row", "one column", "K 0",
                                  "all NaN but a spike"])
def test_degenerate(case: str) -> None:
    z = np.zeros((6, 9))
    if case == "no finite":
        z[:] = np.nan
    elif case == "one pixel":
        z = np.array([[3.0]])
    elif case == "two levels":
        z[2:4, 3:5] = 0.3
    elif case == "one row":
        z = np.array([[0.0, 0.5, 0.5, 0.0, np.nan, 1.0, 0.0]])
    elif case == "one column":
        z = np.array([[0.0, 0.5, 0.5, 0.0, np.nan, 1.0, 0.0]]).T.copy()
    elif case == "all NaN but a spike":
        z[:] = np.nan
        z[2, 2], z[2, 3] = 1.0, 0.0
    for max_area in (1.0, 2.0, 5.0, float(z.size), math.inf):
        for p in (whole_range(z, 0.25, max_area), whole_range(z, 0.1, max_area, 3.0),
                  ZCutParams(step=0.25, max_depth=0.1 if case == "K 0" else 1.0, max_area=max_area)):
            same_clusters(z, p)


def test_checks_as_find_clusters() -> None:
    from zcut.errors import InputShapeError, ParameterError

    with pytest.raises(InputShapeError):
        cluster_labels_of(np.zeros(5), params=ZCutParams(step=0.1, max_depth=1.0, max_area=5.0))
    with pytest.raises(ParameterError):
        cluster_labels_of(np.zeros((3, 3)), params=(0.1, 1.0, 5.0))  # type: ignore[arg-type]


def test_the_suspects_call_itself() -> None:
    """cluster_labels_of as zcut.suspects.floating calls it (its arguments captured, on two small synthetic frames):
    the whole range in the cuts, every kernel's find_clusters as the union-find's (tests/zcut/test_cuts_deep.py's
    check), and cluster_labels_of's clusters, areas and levels find_clusters'. The floating detector's cut is this
    call since round 2026-12-07e (test_cuts_deep.py's test of the same name spies find_clusters, which the detector
    no longer calls)."""
    import importlib

    from test_cuts_deep import check_all, whole
    from test_cuts_fast import height_mm

    from replay.synth import synthesize_frame
    from zcut.edge_surface import EdgeSurfaceParams
    from zcut.params import SuspectParams
    from zcut.suspects import suspects

    floating = importlib.import_module("zcut.suspects.floating")
    calls: list[tuple[np.ndarray, ZCutParams]] = []
    real = floating.cluster_labels_of

    def spy(h: np.ndarray, *, params: ZCutParams) -> object:
        calls.append((h.copy(), params))
        return real(h, params=params)

    for kind, seed in (("zinc_nuts", 11), ("spheres", 12)):
        xyz = synthesize_frame(kind=kind, seed=seed, size=(120, 192)).frame.xyz
        h = height_mm(xyz)
        zone = np.isfinite(xyz).all(axis=2)
        calls.clear()
        mp = pytest.MonkeyPatch()
        try:
            mp.setattr(floating, "cluster_labels_of", spy)
            suspects(xyz, h, zone, params=SuspectParams(), edge_surface=EdgeSurfaceParams())
        finally:
            mp.undo()
        assert len(calls) == 1
        hz, p = calls[0]
        assert whole(hz, p)
        check_all(hz, p, reference=False)
        assert same_clusters(hz, p) > 0


@pytest.mark.parametrize("seed", range(6))
def test_deep_cuts_with_squeezed_levels(seed: int) -> None:
    """A cut that holds every pixel over more than SHALLOW_LEVELS levels, most of them empty (far points, terraces
    apart by bands of 1, 2, 3 and thousands of empty levels, NaN holes): the pruned flood on the squeezed heights
    (zcut.cuts._squeezed_clusters applies) gives find_clusters' clusters, areas and levels (mapped back)."""
    from zcut.cuts import _squeezed_clusters

    rng = np.random.default_rng(4700 + seed)
    step = 0.5
    z = terraces(rng, int(rng.integers(20, 50)), int(rng.integers(30, 120)), step)
    fin = np.isfinite(z)
    for gap in rng.choice([1, 2, 3, 700, 2500], size=int(rng.integers(2, 6))):
        cut = float(rng.choice(z[fin]))
        z[fin & (z < cut)] -= float(gap) * step  # a band of empty levels below the height `cut`
    far = rng.integers(0, z.size, size=3)
    z.flat[far] = np.nanmin(z) - rng.uniform(4200, 9000) * step  # far points
    p = whole_range(z, step, float(rng.choice([3.0, 17.0, 60.0, 400.0])))
    _, lo, hi, _ = _finite_range(z)
    q_min = int(qlevel(lo, hi, p.step, np.int64(n_levels(p.step, p.max_depth) + 2)))
    assert q_min - 1 >= SHALLOW_LEVELS
    _, _, _, seg = _finite_range(z)
    assert _squeezed_clusters(z, seg, hi, p.step, q_min, p.max_area, p.connectivity, 0, None) is not None
    same_clusters(z, p)


def squeezed_reference(z: np.ndarray, z_max: float, step: float, q_min: int) -> tuple[np.ndarray, ...]:
    """``zcut.cut_tree.squeezed_heights`` literally: :func:`qlevel` of every finite pixel, the occupied levels with
    0 and 1, the gaps counted min(g, 2); the squeezed heights -map[q] (NaN where not finite), and their
    :func:`_finite_range`. Returns (map, inverse, heights, (n, min, max, row segments' maxima))."""
    fin = np.isfinite(z)
    q = np.full(z.shape, -1, np.int64)
    for i, v in np.ndenumerate(z):
        if fin[i]:
            q[i] = int(qlevel(float(v), z_max, step, np.int64(q_min + 1)))
    assert q.max(initial=0) <= q_min
    occupied = sorted({0, 1} & set(range(q_min + 1)) | set(q[fin].tolist()))
    fwd = np.full(q_min + 1, -1, np.int64)
    m, last = 0, 0
    fwd[0] = 0
    for level in occupied[1:]:
        m += min(level - last, 2)
        fwd[level] = m
        last = level
    inv = np.full(m + 1, -1, np.int64)
    inv[fwd[occupied]] = occupied
    out = np.full(z.shape, np.nan)
    out[fin] = 0.0 - fwd[q[fin]].astype(np.float64)
    return fwd, inv, out, _finite_range(out)


def squeeze_inputs(case: str, seed: int) -> tuple[np.ndarray, float]:
    """(heights, step) of a squeeze test: ``shallow`` (terraces on a dyadic step: every tie exact), ``deep``
    (terraces thousands of levels apart, far points, a step that is not dyadic: heights on its levels' rounded
    values, where the guess is off by one, and between them), ``nan-heavy`` (90 % NaN and a few infinities),
    ``single`` (one height), ``invalid`` (no finite height), ``coarse`` (heights whose ulp exceeds the step)."""
    rng = np.random.default_rng(8100 + seed)
    H, W = int(rng.integers(5, 40)), int(rng.integers(60, 200))  # (W: row segments of 64 and a part one)
    if case == "shallow":
        return terraces(rng, H, W, 0.5), 0.5
    step = float(rng.choice([0.1, 0.6819036739778641, 1.0 / 3.0]))
    if case == "single":
        z = np.full((H, W), float(rng.normal(0, 50)))
        z[rng.random((H, W)) < 0.2] = np.nan
        return z, step
    if case == "invalid":
        return np.full((H, W), np.nan), step
    if case == "coarse":  # heights of ulp 1 on a step of 0.1: a guess off by several levels (qlevel's search)
        z = 2.0**52 + 2.0**20 - rng.integers(0, 40, (H, W)) - rng.integers(0, 2, (H, W)) * 600.0
        z[rng.random((H, W)) < 0.1] = np.nan
        return z, 0.1
    q = rng.integers(0, 9, (H, W)) + rng.choice([0, 1, 2, 3, 700, 2500, 9000], (H, W), p=[.5, .1, .1, .1, .1, .05, .05])
    z = 12.25 - q * step  # on the levels' rounded heights
    off = rng.random((H, W)) < 0.4
    z[off] -= rng.random(int(off.sum())) * step  # between them
    if case == "nan-heavy":
        z[rng.random((H, W)) < 0.9] = np.nan
        z.flat[rng.integers(0, z.size, 4)] = rng.choice([np.inf, -np.inf], 4)
    return z, step


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("case", ["shallow", "deep", "nan-heavy", "single", "invalid", "coarse"])
def test_squeezed_heights_as_the_literal_reference(case: str, seed: int) -> None:
    """zcut.cut_tree.squeezed_heights (two vectorised passes, the squeezed heights' row segments' maxima from the
    heights') against its literal reference: the map, its inverse, the heights and :func:`_finite_range` of them,
    bit for bit; and the range _squeezed_clusters takes for them (max 0.0, min -map[q_min]) that range."""
    from zcut.cut_tree import squeezed_heights

    z, step = squeeze_inputs(case, seed)
    n, lo, hi, seg = _finite_range(z)
    if n > 0:
        q_min = int(qlevel(lo, hi, step, np.int64(2**40)))
    else:
        lo, hi, q_min = 0.0, 0.0, 5  # (the kernel is not called so; the same answer all the same)
    fwd, inv, out, (n2, lo2, hi2, seg2) = squeezed_reference(z, hi, step, q_min)
    got = np.full(z.shape, 7.0)
    got_seg = np.full(seg.shape, 7.0)
    got_fwd, got_inv = squeezed_heights(z, seg, hi, step, np.int64(q_min), got, got_seg)
    assert np.array_equal(got_fwd, fwd) and np.array_equal(got_inv, inv)
    assert np.array_equal(got.view(np.int64), out.view(np.int64))
    assert np.array_equal(got_seg.view(np.int64), seg2.view(np.int64))
    if n > 0:
        assert (n2 > 0, lo2, hi2) == (True, 0.0 - float(fwd[q_min]), 0.0)
        assert math.copysign(1.0, hi2) == 1.0
    else:
        assert np.isnan(out).all() and n2 == 0
    if case == "deep":
        assert q_min > 2500 and int(fwd[q_min]) < q_min // 10  # squeezed
