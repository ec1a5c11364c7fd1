"""z-cut: the levels of a read segment without a branch (zcut.cut_tree._segment_levels) and the uphill rule of
the prune (zcut.cut_tree.gentle_prune: a kept pixel lying within one level below a left-out one is left out
too), against qlevel, the literal loop and the previous full-image path, on held-out frames (seeds not looked
at while building it), the real clouds, large invalid regions and degenerate inputs, through the pruned
path forced whatever the frame's size."""

from __future__ import annotations

import math

import numpy as np
import pytest
from bench_frames import bench_kinds
from gentle_state import gentle_labelled
from test_cuts_fast import bumpy, check, height_mm, previous_outliers, pruned_outliers, terraces

from zcut import ZCutParams, find_clusters, zcut_outliers, zcut_outliers_reference
from zcut.cut_tree import KEPT, gentle_levels, qlevel
from zcut.cuts import _finite_range, _levels
from zcut.params import n_levels

NOMINAL = dict(step=0.2, max_depth=30.0, max_area=210.0)


def prune_state(z: np.ndarray, *, step: float, max_depth: float, max_area: float, connectivity: int = 8,
                gentle: int = 4) -> tuple[np.ndarray, np.ndarray, int, int, int]:
    """The kernels' own state after the level pass (every pixel labelled, gentle components of connectivity
    ``gentle``) and the prune: ``(levels (H, W), left out (H, W), pixels in the cuts, kept, top)``; the
    levels -1 outside the cuts."""
    state = gentle_labelled(z, step=step, max_depth=max_depth, max_area=max_area, gentle=gentle)
    assert state.labelled
    levels = state.levels()
    keep = state.prune(max_area=max_area, connectivity=connectivity)
    after = state.levels()
    left_out = (after >= 0) & (after < KEPT)  # a pixel left out keeps its level, a kept one is marked KEPT + level
    assert np.array_equal(np.where(after >= KEPT, after - KEPT, after), levels)  # the levels kept in the marks
    return levels, left_out, state.m, keep, state.top


def literal_levels(z: np.ndarray, lo: float, hi: float, step: float, k_eff: int, top: int) -> np.ndarray:
    """Each pixel's level by ``qlevel``, one pixel at a time (a non-finite height read as ``lo``); -1 for the pixels
    below the top ``top`` levels, which the level pass leaves out."""
    H, W = z.shape
    want = np.full((H, W), -1, np.int64)
    for r in range(H):
        for c in range(W):
            zt = z[r, c] if np.isfinite(z[r, c]) else lo
            if zt >= hi - top * step:
                want[r, c] = qlevel(zt, hi, step, np.int64(k_eff + 2))
    return want


# ------------------------------------------------------------------------------------------------
# the levels of a segment: qlevel's, bit for bit
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", range(6))
def test_segment_levels_are_qlevels_on_the_thresholds(seed: int) -> None:
    """Heights exactly on the cuts' thresholds z_max - k * step, one ulp either side, NaN, infinities, signed
    zeros, huge and tiny values, steps that are not dyadic: every pixel's level is qlevel's (-1 outside the
    cuts), whatever the guess floor((z_max - z) / step) gives."""
    rng = np.random.default_rng(7000 + seed)
    H, W = 9, 3 * 64 + 5
    step = float(rng.choice([0.1, 0.2, 0.3, 1 / 3, 0.7, 1e-3]))
    z_max = float(rng.choice([0.0, -0.0, 1.0, 123.456, -5e3, 1e6]))
    k = rng.integers(0, 40, (H, W))
    z = z_max - k * step
    z = np.where(rng.random((H, W)) < 0.2, np.nextafter(z, np.inf), z)
    z = np.where(rng.random((H, W)) < 0.2, np.nextafter(z, -np.inf), z)
    z = np.minimum(z, z_max)
    z[0, 0] = z_max
    z[rng.random((H, W)) < 0.05] = np.nan
    z[1, 3], z[2, 70], z[3, 140] = np.inf, -np.inf, -0.0 if z_max == 0.0 else z[3, 140]
    z[4, 5] = -1e300
    for max_depth in (0.0, step, 10 * step, 25 * step + step / 3, 1e5):
        K = n_levels(step, max_depth)
        n, lo, hi, seg = _finite_range(z)
        k_eff, top = _levels(lo, hi, step, K)
        size = (H + 2) * (W + 2)
        st, gl = np.empty(size, np.int16), np.empty(size, np.int32)
        pix, gpar, gcnt = (np.empty(H * W, np.int32) for _ in range(3))
        m, _, _ = gentle_levels(z, seg, lo, hi, step, np.int64(k_eff + 2), np.int64(top), True, 10.0,
                                np.int64(2**40), st, pix, gl, gpar, gcnt)
        got = st.reshape(H + 2, W + 2)
        want = literal_levels(z, lo, hi, step, k_eff, top)
        np.testing.assert_array_equal(got[1:-1, 1:-1], want)
        assert (got[0] == -1).all() and (got[-1] == -1).all() and (got[:, 0] == -1).all() and (got[:, -1] == -1).all()
        assert m == int((want >= 0).sum())
        if top < 4096:  # the whole path too
            check(z, step=step, max_depth=max_depth, max_area=6.0)


def guess_fails(z: np.ndarray, *, z_min: float, z_max: float, step: float, top: int) -> np.ndarray:
    """(H, W) bool: the pixels in the cuts whose level neither the guess k = floor((z_max - z) / step) nor k + 1
    is (zcut.cut_tree._segment_levels' test, in numpy): where the segment must be levelled again by qlevel."""
    zt = np.where(np.isfinite(z), z, z_min)
    k = np.clip((z_max - zt) * (1.0 / step), 0.0, float(top + 1)).astype(np.int64)
    in0 = zt >= z_max - k * step
    inm = zt >= z_max - (k - 1) * step
    inp = zt >= z_max - (k + 1) * step
    ok = (in0 & ((k == 0) | ~inm)) | (~in0 & inp)
    return (zt >= z_max - top * step) & ~ok


@pytest.mark.parametrize("seed", range(4))
def test_segment_levels_fall_back_to_qlevel_when_the_guess_is_off(seed: int) -> None:
    """Heights of 2**60 and a step of 1 (or 3, or 0.75): the cuts' thresholds z_max - k * step round to the
    float64 grid (an ulp of 128 or 256), so many k share a threshold and the guess floor((z_max - z) / step) is
    off by far more than one level, both ways. Those segments must be levelled again by qlevel: the levels of
    the level pass (gentle_levels' st), find_clusters' pixel_level and the masks are qlevel's and the literal
    loop's. (With the fallback's test or its call removed, the levels of the pixels it catches go wrong.)"""
    rng = np.random.default_rng(7100 + seed)
    H, W = 7, 2 * 64 + 9
    z_max = float(2**60) * float(rng.choice([1.0, -1.0, 0.5]))
    step = float(rng.choice([1.0, 3.0, 0.75]))
    z = z_max - np.floor(rng.uniform(0.0, 1500.0, (H, W))) * step
    z[0, 0] = z_max
    z[rng.random((H, W)) < 0.05] = np.nan
    z[:, 64:128] = z_max - 2000.0 * step  # a segment below every cut (not read again)
    z[3, 70] = z_max  # ... but one pixel in: the segment is read
    max_depth = 1200.0 * step
    K = n_levels(step, max_depth)
    n, lo, hi, seg = _finite_range(z)
    k_eff, top = _levels(lo, hi, step, K)
    assert top < 4096
    fails = guess_fails(z, z_min=lo, z_max=hi, step=step, top=top)
    assert fails.sum() > H * W // 4  # the fallback is reached, on most segments
    want = literal_levels(z, lo, hi, step, k_eff, top)
    for gentle in (4, 8):
        state = gentle_labelled(z, step=step, max_depth=max_depth, max_area=6.0, gentle=gentle)
        np.testing.assert_array_equal(state.levels(), want)
    pixel_level = np.where(want <= K + 1, want, -1)
    result = find_clusters(z, params=ZCutParams(step, max_depth, 6.0))
    np.testing.assert_array_equal(result.pixel_level, pixel_level)
    for max_area in (3.0, 40.0):
        np.testing.assert_array_equal(pruned_outliers(z, step=step, max_depth=max_depth, max_area=max_area),
                                      zcut_outliers_reference(z, step=step, max_depth=max_depth, max_area=max_area))
        check(z, reference=False, step=step, max_depth=max_depth, max_area=max_area)


def test_segment_levels_with_a_subnormal_step() -> None:
    """1 / step is infinite: the guess is NaN (0 * inf) or infinite, the exact comparisons decide."""
    step = 5e-324
    z = np.full((3, 70), 1.0)
    z[1, 5:9] = 0.0
    z[2, 60] = np.nan
    for max_depth in (0.0, 2 * step, 3 * step):
        check(z, step=step, max_depth=max_depth, max_area=3.0)
        check(z, step=step, max_depth=max_depth, max_area=300.0)


# ------------------------------------------------------------------------------------------------
# the uphill rule: what it leaves out is in no tagged node, and the masks do not change
# ------------------------------------------------------------------------------------------------
def assert_sound(z: np.ndarray, *, connectivity: int = 8, **params: float) -> tuple[int, int]:
    """The pixels the prune leaves out hold no outlier of the literal loop (nor of the whole tree, invalid
    pixels included: find_clusters' clusters), and the pruned flood gives the literal loop's mask with
    every way of labelling. Returns (pixels in the cuts, kept)."""
    want = zcut_outliers_reference(z, connectivity=connectivity, **params)
    got = None
    for gentle in {4, connectivity}:
        levels, left_out, m, keep, top = prune_state(z, connectivity=connectivity, gentle=gentle, **params)
        assert not (left_out & want).any()
        assert int((levels >= 0).sum()) == m and keep == m - int(left_out.sum())
        got = (m, keep)
    for way in ("auto", 4, connectivity):
        np.testing.assert_array_equal(pruned_outliers(z, gentle=way, connectivity=connectivity, **params), want)
    np.testing.assert_array_equal(zcut_outliers(z, connectivity=connectivity, **params), want)
    assert got is not None
    return got


@pytest.mark.parametrize("seed", range(40, 52))
def test_held_out_terraces(seed: int) -> None:
    """Plateaus, cliffs of 1 to 3 levels, spikes and pits with exact ties (seeds not used elsewhere)."""
    rng = np.random.default_rng(seed)
    step = 0.25
    z = terraces(rng, int(rng.integers(8, 50)), int(rng.integers(8, 160)), step)
    for conn in (8, 4):
        for max_area in (2.0, 5.0, 17.0, 60.0):
            for max_depth in (0.5, 1.0, 2.0, 10.0):
                if np.isfinite(z).any():
                    assert_sound(z, step=step, max_depth=max_depth, max_area=max_area, connectivity=conn)


@pytest.mark.parametrize("seed", range(60, 68))
def test_held_out_random_fields(seed: int) -> None:
    """Bumps with floating patches, heights on the step/2 grid, scattered and block NaN, an infinity."""
    rng = np.random.default_rng(seed)
    z = bumpy(rng, int(rng.integers(30, 70)), int(rng.integers(60, 200)), 0.5)
    z[rng.random(z.shape) < 0.1] = np.nan
    z[5:20, 10:50] = np.nan
    z[0, 1] = np.inf
    for params in (dict(step=0.5, max_depth=3.0, max_area=30.0), dict(step=0.5, max_depth=20.0, max_area=8.0),
                   dict(step=0.25, max_depth=1000.0, max_area=200.0)):
        for conn in (8, 4):
            assert_sound(z, connectivity=conn, **params)


@pytest.mark.parametrize(("kind", "seed"), [("pile", 101), ("pile", 102), ("dense", 103), ("holes", 104),
                                            ("dense", 105), ("holes", 106)])
def test_held_out_bench_frames(kind: str, seed: int) -> None:
    """Crops of the benchmark's frame kinds at seeds the benchmark does not use, at nominal parameters: the
    pile (parts, floating patches, shadows), the dense noisy surface, large invalid regions."""
    z = bench_kinds()[kind](seed)
    rng = np.random.default_rng(seed)
    r0, c0 = int(rng.integers(150, 750)), int(rng.integers(200, 1300))
    crop = np.ascontiguousarray(z[r0:r0 + 240, c0:c0 + 320])
    m, keep = assert_sound(crop, **NOMINAL)
    if kind == "dense":
        assert keep < m / 10  # the prune leaves out most of the noisy surface


def test_the_uphill_rule_leaves_out_more_of_the_pile() -> None:
    """On the benchmark's pile the pixels below the large gentle components go too: far fewer are flooded
    than the gentle components alone keep (30,422 of the whole frame's 117,023 pixels in the cuts before
    this rule, docs/performance.md), and the mask is the whole flood's."""
    z = np.ascontiguousarray(bench_kinds()["pile"]()[300:700, 500:1300])
    levels, left_out, m, keep, _ = prune_state(z, **NOMINAL)
    want = previous_outliers(z, **NOMINAL)
    assert want.any() and not (left_out & want).any()
    assert 0 < keep < m / 8
    np.testing.assert_array_equal(pruned_outliers(z, **NOMINAL), want)


def test_a_spike_on_a_slope_and_a_pit_below_a_plateau() -> None:
    """By hand: a plateau of 38 pixels (max_area 30: large), a pit two levels below it (left out: a pixel of
    a tagged node has every neighbour within one level below it in that node, and the plateau is in none),
    a one-pixel spike three levels above the plateau (tagged, kept) and a lone pixel far away (kept)."""
    step = 1.0
    z = np.full((8, 12), -10.0)  # below the cuts
    z[1:6, 1:9] = 0.0  # the plateau, at level 3
    z[3, 4] = -2.0  # a pit inside it: level 5
    z[2, 6] = 3.0  # a spike: level 0
    z[6, 11] = -1.0  # alone: level 4
    params = dict(step=step, max_depth=6.0, max_area=30.0)
    levels, left_out, m, keep, top = prune_state(z, **params)
    assert levels[3, 4] == 5 and levels[2, 6] == 0 and levels[1, 1] == 3 and levels[6, 11] == 4 and top == 7
    assert left_out[3, 4] and left_out[1, 1] and not left_out[2, 6] and not left_out[6, 11]
    assert keep == 2
    want = zcut_outliers_reference(z, **params)
    assert want[2, 6] and want[6, 11] and want.sum() == 2
    np.testing.assert_array_equal(pruned_outliers(z, **params), want)


@pytest.mark.parametrize("name", ["mosd_test16.pcd", "table_scene_mug_stereo_textured.pcd"])
def test_real_clouds_through_the_pruned_flood(real_data, name: str) -> None:
    """The real Kinect / stereo clouds through the pruned flood, forced (zcut_outliers floods them whole:
    fewer than PRUNE_MIN pixels in the cuts), every pixel labelled, at Δd 0.2 mm and 1 mm."""
    import open3d as o3d

    cloud = o3d.io.read_point_cloud(str(real_data / name), remove_nan_points=False, remove_infinite_points=False)
    z = height_mm(np.asarray(cloud.points).reshape(480, 640, 3))
    for params in (NOMINAL, dict(step=1.0, max_depth=30.0, max_area=210.0)):
        want = previous_outliers(z, **params)
        for gentle in ("auto", 4, 8):
            np.testing.assert_array_equal(pruned_outliers(z, gentle=gentle, **params), want)
        np.testing.assert_array_equal(zcut_outliers(z, **params), want)
        fc = find_clusters(z, params=ZCutParams(params["step"], params["max_depth"], params["max_area"]))
        np.testing.assert_array_equal(fc.outliers, want)
    sub = np.ascontiguousarray(z[200:330, 250:450])
    np.testing.assert_array_equal(pruned_outliers(sub, **NOMINAL), zcut_outliers_reference(sub, **NOMINAL))


@pytest.mark.parametrize("case", ["all_nan", "one_pixel", "one_nan_pixel", "one_row", "one_column", "infinities",
                                  "signed_zeros", "constant", "empty", "empty_rows"])
def test_degenerate_through_the_pruned_flood(case: str) -> None:
    z = {
        "all_nan": np.full((6, 70), np.nan),
        "one_pixel": np.array([[2.5]]),
        "one_nan_pixel": np.array([[np.nan]]),
        "one_row": np.array([[0.0, 2.0, 2.0, 0.0, np.nan, 3.0, 0.0, 0.5, 0.5, 2.0]]),
        "one_column": np.array([[0.0], [2.0], [np.nan], [0.5], [0.0], [2.0]]),
        "infinities": np.array([[np.inf, 1.0, 0.0], [-np.inf, 3.0, 0.0], [0.0, np.nan, np.inf]]),
        "signed_zeros": np.array([[-0.0, 0.0, 1.0, -0.0], [0.0, -0.0, np.nan, 0.0], [1.0, 1.0, -0.0, 0.0]]),
        "constant": np.full((9, 130), 7.0),
        "empty": np.zeros((0, 0)),
        "empty_rows": np.zeros((0, 5)),
    }[case]
    for params in (dict(step=0.5, max_depth=2.0, max_area=1.0), dict(step=0.5, max_depth=2.0, max_area=4.0),
                   dict(step=1.0, max_depth=0.0, max_area=4.0), dict(step=0.25, max_depth=10.0, max_area=3.0,
                                                                     connectivity=4)):
        want = zcut_outliers_reference(z, **params)
        for gentle in ("auto", 4, int(params.get("connectivity", 8))):
            if not (z.size and np.isfinite(z).any()) or math.isinf(params["max_area"]):
                continue
            np.testing.assert_array_equal(pruned_outliers(z, gentle=gentle, **params), want)
        check(z, **params)


@pytest.mark.parametrize("seed", range(4))
def test_the_window_of_the_pixels_in_the_cuts(seed: int) -> None:
    """The pruned flood works on the rows and segment columns that hold pixels in the cuts: pixels in the
    cuts at the window's four edges, in the frame's last (short) segment, in its first and last rows, and
    invalid holes inside and around it."""
    from zcut.cut_tree import SEGMENT

    rng = np.random.default_rng(9000 + seed)
    H, W = 40, 4 * SEGMENT + 9
    z = np.full((H, W), -100.0)  # far below the cuts
    r0, r1 = int(rng.integers(0, 10)), int(rng.integers(30, H + 1))
    c0, c1 = int(rng.integers(0, 2 * SEGMENT)), int(rng.integers(2 * SEGMENT + 1, W + 1))
    z[r0:r1, c0:c1] = bumpy(rng, r1 - r0, c1 - c0, 0.5)[:, :]
    z[rng.random(z.shape) < 0.05] = np.nan
    z[r0, c0], z[r1 - 1, c1 - 1] = np.nan, np.inf
    for params in (dict(step=0.5, max_depth=3.0, max_area=20.0), dict(step=0.5, max_depth=8.0, max_area=6.0,
                                                                      connectivity=4)):
        want = zcut_outliers_reference(z, **params)
        for gentle in ("auto", 4, int(params.get("connectivity", 8))):
            np.testing.assert_array_equal(pruned_outliers(z, gentle=gentle, **params), want)
        np.testing.assert_array_equal(pruned_outliers(z.T.copy(), **params), zcut_outliers_reference(z.T, **params))
