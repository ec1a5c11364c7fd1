"""z-cut: the fast component-tree version against the literal loop, nasty cases, laws, stage view."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scipy import ndimage

from zcut import (
    CutResult,
    InputShapeError,
    ParameterError,
    ZCutParams,
    find_clusters,
    zcut_outliers,
    zcut_outliers_reference,
)
from zcut.cut_grid import zcut_tree
from zcut.cut_tree import FLOOD_MAX_LEVELS, SHALLOW_LEVELS
from zcut.cuts import KERNELS, n_levels

STEPS = (0.2, 0.25, 0.3, 0.5, 1.0, 0.1)


def random_frame(rng: np.random.Generator) -> tuple[np.ndarray, dict]:
    """A small random pile: tilted floor, blobs (parts), floating clusters, NaN holes.

    Heights lie on a grid of step/2 so that many values fall exactly on the thresholds
    ``z_max - k * step``; sometimes float32, sometimes 0 x N.
    """
    H = int(rng.choice([0, 1, 1, 2, 3, 5, 8, 13, 20, 31]))
    W = int(rng.choice([1, 1, 2, 3, 5, 8, 13, 20, 31]))
    if rng.random() < 0.5:
        H, W = W, H
    step = float(rng.choice(STEPS))
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    z = rng.normal(0.0, 0.3) * yy + rng.normal(0.0, 0.3) * xx
    for _ in range(int(rng.integers(0, 6))):  # parts
        cy, cx = rng.uniform(0, max(H, 1)), rng.uniform(0, max(W, 1))
        r = rng.uniform(1.0, 6.0)
        z = np.maximum(z, rng.uniform(0, 8) * step + rng.uniform(1, 10) * step
                       * np.clip(1 - ((yy - cy) ** 2 + (xx - cx) ** 2) / r**2, 0, None))
    for _ in range(int(rng.integers(0, 5))):  # floating clusters
        if H == 0 or W == 0:
            break
        y, x = int(rng.integers(0, H)), int(rng.integers(0, W))
        sl = (slice(y, y + int(rng.integers(1, 4))), slice(x, x + int(rng.integers(1, 4))))
        z[sl] = z[sl].max() + rng.uniform(0.3, 6.0) * step
    z = z + rng.normal(0.0, rng.choice([0.0, 0.2, 1.0]) * step, z.shape)
    z = np.round(z / (step / 2)) * (step / 2)  # on the step/2 grid
    nan_frac = float(rng.choice([0.0, 0.0, 0.05, 0.2, 0.5, 0.95]))
    z[rng.random(z.shape) < nan_frac] = np.nan
    if H > 2 and rng.random() < 0.3:  # a NaN hole around a patch (paper Figure 11)
        y, x = int(rng.integers(0, H - 2)), int(rng.integers(0, W - 2 if W > 2 else 1))
        z[y:y + 3, x:x + 3] = np.nan
    if rng.random() < 0.3:
        z = z.astype(np.float32)
    params = dict(
        step=step,
        max_depth=float(rng.choice([rng.uniform(0, 12), rng.integers(0, 12)])) * step,
        max_area=float(rng.choice([1, 2, 3, 5, 10, 40, math.inf, rng.uniform(1, 30)])),
        connectivity=int(rng.choice([4, 8])),
    )
    return z, params


@pytest.fixture(params=["flood", "union-find"])
def kernel(request) -> str:
    """Each component-tree kernel, passed explicitly to find_clusters and zcut_tree: the flood
    (what zcut_outliers uses below FLOOD_MAX_LEVELS levels) and the union-find (used beyond)."""
    return request.param


def kernel_outliers(z: np.ndarray, kernel: str, **params) -> np.ndarray:
    """The outlier mask computed with ``kernel``, through the tree view (its read-out differs from
    zcut_outliers', the tree is the same)."""
    step, max_depth, max_area = params["step"], params["max_depth"], params["max_area"]
    tree = zcut_tree(z, step=step, max_depth=max_depth, connectivity=params.get("connectivity", 8),
                     kernel=kernel)
    return tree.outliers(max_depth, max_area)


@pytest.mark.parametrize("seed", range(10))
def test_fast_equals_reference_on_random_frames(seed: int, kernel: str) -> None:
    rng = np.random.default_rng(1000 + seed)
    n_outliers = 0
    for _ in range(60):  # 10 x 60 = 600 frames
        z, params = random_frame(rng)
        fast = zcut_outliers(z, **params)
        ref = zcut_outliers_reference(z, **params)
        assert fast.shape == z.shape and fast.dtype == bool
        np.testing.assert_array_equal(fast, ref, err_msg=repr((z.tolist(), params)))
        np.testing.assert_array_equal(kernel_outliers(z, kernel, **params), ref)
        res = find_clusters(z, params=ZCutParams(params["step"], params["max_depth"], params["max_area"],
                                                      connectivity=params["connectivity"]), kernel=kernel)
        np.testing.assert_array_equal(res.outliers, ref)
        n_outliers += int(ref.sum())
    assert n_outliers > 0  # the frames do exercise the tagging


@pytest.mark.parametrize("seed", range(3))
def test_fast_equals_reference_with_many_levels(seed: int, kernel: str) -> None:
    """Larger noisy frames with 60 .. 400 levels: the flood's bucket queue spans several words of
    its bit map, its stack gets deep, and it descends and rises often."""
    rng = np.random.default_rng(3000 + seed)
    n_outliers = 0
    for _ in range(8):
        H, W = (int(x) for x in rng.integers(20, 60, 2))
        step = float(rng.choice([0.1, 0.2, 0.25]))
        n_lev = int(rng.integers(60, 400))
        yy, xx = np.mgrid[0:H, 0:W]
        wave = np.sin(yy / rng.uniform(3, 12)) * np.cos(xx / rng.uniform(3, 12))
        z = n_lev * step / 2 * (1 + wave)
        z = z + rng.normal(0.0, float(rng.choice([0.3, 1.0, 3.0])) * step, z.shape)
        z = np.round(z / (step / 2)) * (step / 2)
        z[rng.random(z.shape) < 0.03] = np.nan
        params = dict(step=step, max_depth=float(rng.integers(n_lev // 2, n_lev + 5)) * step,
                      max_area=float(rng.choice([3, 20, 200, math.inf])),
                      connectivity=int(rng.choice([4, 8])))
        ref = zcut_outliers_reference(z, **params)
        np.testing.assert_array_equal(zcut_outliers(z, **params), ref)
        np.testing.assert_array_equal(kernel_outliers(z, kernel, **params), ref)
        res = find_clusters(z, params=ZCutParams(params["step"], params["max_depth"], params["max_area"],
                                                      connectivity=params["connectivity"]), kernel=kernel)
        np.testing.assert_array_equal(res.outliers, ref)
        n_outliers += int(ref.sum())
    assert n_outliers > 0


# --------------------------------------------------------------------------------------------
# Nasty cases: each checked against the reference and against the expected mask where it is known
# --------------------------------------------------------------------------------------------

NAN = np.nan
NASTY = {
    # name: (height, params, expected or None)
    "empty 0x5": (np.zeros((0, 5)), dict(step=0.2, max_depth=1.0, max_area=10), np.zeros((0, 5), bool)),
    "empty 5x0": (np.zeros((5, 0)), dict(step=0.2, max_depth=1.0, max_area=10), np.zeros((5, 0), bool)),
    "1x1": (np.array([[3.0]]), dict(step=0.2, max_depth=1.0, max_area=10), np.array([[True]])),
    "1x1 K=0": (np.array([[3.0]]), dict(step=0.2, max_depth=0.1, max_area=10), np.array([[False]])),
    "1x1 NaN": (np.array([[NAN]]), dict(step=0.2, max_depth=1.0, max_area=10), np.array([[False]])),
    "all NaN": (np.full((4, 6), NAN), dict(step=0.2, max_depth=1.0, max_area=10), np.zeros((4, 6), bool)),
    "all inf": (np.full((2, 2), np.inf), dict(step=0.2, max_depth=1.0, max_area=10), np.zeros((2, 2), bool)),
    # a constant image is one component that never changes: tagged iff smaller than max_area
    "constant small": (np.full((3, 4), 7.0), dict(step=0.5, max_depth=2.0, max_area=13), np.ones((3, 4), bool)),
    "constant = max_area": (np.full((3, 4), 7.0), dict(step=0.5, max_depth=2.0, max_area=12), np.zeros((3, 4), bool)),
    "max_area inf": (np.full((3, 4), 7.0), dict(step=0.5, max_depth=2.0, max_area=math.inf), np.ones((3, 4), bool)),
    "max_area 1 tags nothing": (np.array([[9.0, 0.0, 0.0]]), dict(step=1.0, max_depth=5.0, max_area=1), np.zeros((1, 3), bool)),
    "max_depth < step": (np.array([[9.0, 0.0, 0.0]]), dict(step=1.0, max_depth=0.999, max_area=5), np.zeros((1, 3), bool)),
    "max_depth 0": (np.array([[9.0, 0.0, 0.0]]), dict(step=1.0, max_depth=0.0, max_area=5), np.zeros((1, 3), bool)),
    # 0.6 / 0.2 = 2.9999999999999996: the 1e-9 makes K = 3
    "K from rounding": (np.array([[0.6, 0.0, 0.0]]), dict(step=0.2, max_depth=0.6, max_area=2), None),
    # 1 x N: the top pixel 2 steps above a plateau that sits exactly on the threshold of S_2:
    # {top} is alone in S_0 and S_1 only, and the loop starts at k = 1: not tagged
    "1xN on threshold": (np.array([[2.0, 0.0, 0.0, 0.0]]), dict(step=1.0, max_depth=3.0, max_area=2),
                         np.zeros((1, 4), bool)),
    # ... half a step higher, {top} is alone in S_1 and S_2: tagged
    "1xN above threshold": (np.array([[2.5, 0.0, 0.0, 0.0]]), dict(step=1.0, max_depth=3.0, max_area=2),
                            np.array([[True, False, False, False]])),
    "1xN half step": (np.array([[0.5, 0.0, 0.0, 0.0]]), dict(step=1.0, max_depth=3.0, max_area=2),
                      np.zeros((1, 4), bool)),
    "Nx1": (np.array([[1.0], [NAN], [0.0], [2.5]]), dict(step=0.5, max_depth=2.0, max_area=3), None),
    # NaN pixels take z_min (4.5 here) and connect: the top pixel joins the rest in S_1
    "NaN bridge": (np.array([[5.0, NAN, 4.5, 4.5]]), dict(step=1.0, max_depth=3.0, max_area=3),
                   np.zeros((1, 4), bool)),
    # with a valid 0 instead, both the top pixel and the 4.5 pair float above the floor
    "no NaN bridge": (np.array([[5.0, 0.0, 4.5, 4.5]]), dict(step=1.0, max_depth=3.0, max_area=3),
                      np.array([[True, False, True, True]])),
    # diagonal neighbours: one component with connectivity 8, two with 4
    "diagonal 8": (np.array([[5.0, 0.0], [0.0, 5.0]]), dict(step=1.0, max_depth=3.0, max_area=3),
                   np.array([[True, False], [False, True]])),
    "diagonal 4": (np.array([[5.0, 0.0], [0.0, 5.0]]), dict(step=1.0, max_depth=3.0, max_area=2, connectivity=4),
                   np.array([[True, False], [False, True]])),
    "diagonal 8 area": (np.array([[5.0, 0.0], [0.0, 5.0]]), dict(step=1.0, max_depth=3.0, max_area=2),
                        np.zeros((2, 2), bool)),
    "negative heights": (np.array([[-100.0, -103.5, -103.5]]), dict(step=1.0, max_depth=5.0, max_area=2),
                         np.array([[True, False, False]])),
    "huge heights": (np.array([[1e300, -1e300, 0.0]]), dict(step=1e299, max_depth=1e300, max_area=2), None),
    "tiny step, many levels": (np.array([[0.0, 1.0], [0.5, 0.75]]), dict(step=1e-3, max_depth=1.5, max_area=2), None),
    "float32 thresholds": (np.array([[0.3, 0.1, 0.2], [0.1, 0.0, 0.3]], np.float32),
                           dict(step=0.1, max_depth=0.5, max_area=3), None),
}


@pytest.mark.parametrize("conn", [8, 4])
@pytest.mark.parametrize("name", list(NASTY))
def test_nasty_cases(name: str, conn: int, kernel: str) -> None:
    z, case, expected = NASTY[name]
    params = {**case, "connectivity": conn}
    fast = zcut_outliers(z, **params)
    ref = zcut_outliers_reference(z, **params)
    np.testing.assert_array_equal(fast, ref)
    if expected is not None and conn == case.get("connectivity", 8):
        np.testing.assert_array_equal(fast, expected)
    res = find_clusters(z, params=ZCutParams(params["step"], params["max_depth"], params["max_area"],
                                                  connectivity=params["connectivity"]), kernel=kernel)
    np.testing.assert_array_equal(res.outliers, fast)
    np.testing.assert_array_equal(kernel_outliers(z, kernel, **params), fast)


def test_float32_is_upcast_before_the_comparison() -> None:
    # docs/filters.md: float32 heights are upcast, every threshold is computed and compared in float64
    # (numpy 2 would compare a float32 array with a Python float in float32)
    z32 = np.array([[0.3, 0.1, 0.0]], np.float32)
    params = dict(step=0.1, max_depth=0.5, max_area=2)
    np.testing.assert_array_equal(zcut_outliers(z32, **params), zcut_outliers(z32.astype(np.float64), **params))
    np.testing.assert_array_equal(zcut_outliers(z32, **params), zcut_outliers_reference(z32, **params))


def test_very_many_levels_use_the_sort_path() -> None:
    # 5e9 levels between the top pixel and the floor (more than int32 can count)
    z = np.array([[0.0, 0.0, 5.0]])
    out = zcut_outliers(z, step=1e-9, max_depth=10.0, max_area=2)
    np.testing.assert_array_equal(out, [[False, False, True]])
    out = zcut_outliers(z, step=1e-9, max_depth=10.0, max_area=1)
    assert not out.any()


def _limit_frame(K: int, seed: int) -> np.ndarray:
    """A 7 x 9 frame whose levels 0 .. K + 1 take part (z_min at level K + 2, beyond the cuts), with a
    pair floating near the top and a NaN block (step 1)."""
    rng = np.random.default_rng(seed)
    z = rng.integers(0, K + 3, (7, 9)).astype(np.float64)
    z[0, 0], z[6, 8] = K + 2, 0.0  # the full range: z_min at level K + 2 (beyond the cuts)
    z[6, 6:8] = 1.0  # level K + 1, the last one of the cuts
    z[3:5, 3:5] = np.nan
    z[1, 1:3] = K + 1.5  # a pair floating near the top
    return z


@pytest.mark.parametrize("n_levels_above", [-1, 0, 1])
def test_kernels_meet_at_the_queue_switch(n_levels_above: int) -> None:
    """Around SHALLOW_LEVELS levels (the flood's two-tier bucket map fills all its 64 x 64 bits just
    below; the three-tier map takes over at the limit): every kernel agrees with the reference."""
    K = SHALLOW_LEVELS - 2 + n_levels_above  # levels 0 .. K + 1 take part
    z = _limit_frame(K, 5 + n_levels_above)
    for conn in (8, 4):
        params = dict(step=1.0, max_depth=float(K), max_area=3, connectivity=conn)
        ref = zcut_outliers_reference(z, **params)
        assert ref.any()
        np.testing.assert_array_equal(zcut_outliers(z, **params), ref)
        for kernel in KERNELS:
            res = find_clusters(z, params=ZCutParams(1.0, float(K), 3, connectivity=conn), kernel=kernel)
            np.testing.assert_array_equal(res.outliers, ref)
            np.testing.assert_array_equal(kernel_outliers(z, kernel, **params), ref)


@pytest.mark.parametrize("n_levels_above", [-1, 0, 1])
def test_kernels_meet_at_the_level_limit(n_levels_above: int) -> None:
    """Around FLOOD_MAX_LEVELS levels (the three-tier map fills all its 8 x 64 x 64 bits just below; the
    union-find takes over at the limit): both agree with the reference (zcut_outliers and the tree view:
    find_clusters takes fewer levels, MAX_STAGE_LEVELS)."""
    K = FLOOD_MAX_LEVELS - 2 + n_levels_above  # levels 0 .. K + 1 take part
    z = _limit_frame(K, 5 + n_levels_above)
    params = dict(step=1.0, max_depth=float(K), max_area=3, connectivity=8)
    ref = zcut_outliers_reference(z, **params)
    assert ref.any()
    np.testing.assert_array_equal(zcut_outliers(z, **params), ref)
    for kernel in KERNELS:
        if kernel == "flood" and n_levels_above > 0:  # levels 0 .. 32768: too many to flood
            with pytest.raises(ParameterError, match=r"kernel 'flood' .*fewer than 32768 levels"):
                kernel_outliers(z, kernel, **params)
            continue
        np.testing.assert_array_equal(kernel_outliers(z, kernel, **params), ref)


def test_int32_levels() -> None:
    # 40000 levels between the top pixel and the floor: int32 level image, union-find kernel
    z = np.array([[0.0, 0.0, 40.0], [0.0, 39.9995, 0.0]])
    params = dict(step=1e-3, max_depth=50.0)
    out = zcut_outliers(z, max_area=3, **params)
    np.testing.assert_array_equal(out, [[False, False, True], [False, True, False]])
    out = zcut_outliers(z, max_area=3, connectivity=4, **params)  # two separate singletons
    np.testing.assert_array_equal(out, [[False, False, True], [False, True, False]])
    out = zcut_outliers(z, max_area=2, **params)  # 8-connected: one pair, from level 1 on
    np.testing.assert_array_equal(out, np.zeros((2, 3), bool))
    res = find_clusters(z, params=ZCutParams(step=1e-3, max_depth=30.0, max_area=3))
    assert res.pixel_level[0, 2] == 0 and res.pixel_level[1, 1] == 1 and res.pixel_level[0, 0] == -1
    np.testing.assert_array_equal(res.levels, [1])


def test_large_max_depth_is_capped() -> None:
    z = np.array([[0.0, 0.0, 5.0]])
    assert n_levels(1e-300, 1e300) == 2**60
    out = zcut_outliers(z, step=1e-300, max_depth=1e300, max_area=2)
    np.testing.assert_array_equal(out, [[False, False, True]])


# --------------------------------------------------------------------------------------------
# The paper's Figure 6 and Figure 11 in miniature
# --------------------------------------------------------------------------------------------


def figure6_scene() -> np.ndarray:
    """A part with a bump, a cluster floating above the part, a NaN-walled patch (12 x 16, mm).

    - the part: a plateau at 10 mm rising in rings of one step (0.5 mm) to a 2 x 2 bump at
      11.5 mm: every cluster of the bump in Z_d is a strict subset of one in Z_{d+Δd} (Figure 6,
      relation 2): never tagged;
    - ``floating``: 2 x 2 pixels at 14 mm over the part, 3.5 mm above their neighbours (relation 3,
      identical clusters on consecutive cuts): tagged;
    - ``walled``: a 2 x 2 patch at 9 mm surrounded by NaN (Figure 11): the NaN ring takes z_min
      (0 mm), so the patch is cut off from everything and gets tagged unless max_area excludes it.
    """
    z = np.zeros((12, 16))
    z[1:10, 1:10] = 10.0
    z[2:8, 2:8] = 10.5
    z[3:7, 3:7] = 11.0
    z[4:6, 4:6] = 11.5  # the bump
    z[7:9, 7:9] = 14.0  # the floating cluster
    z[1:5, 11:15] = np.nan
    z[2:4, 12:14] = 9.0  # the walled patch
    return z


def figure6_truth() -> tuple[np.ndarray, np.ndarray]:
    """The pixels of :func:`figure6_scene`'s floating cluster and of its walled patch."""
    floating = np.zeros((12, 16), bool)
    floating[7:9, 7:9] = True
    walled = np.zeros((12, 16), bool)
    walled[2:4, 12:14] = True
    return floating, walled


def test_figure6_and_figure11() -> None:
    z = figure6_scene()
    floating, walled = figure6_truth()
    for f in (zcut_outliers, zcut_outliers_reference):
        out = f(z, step=0.5, max_depth=8.0, max_area=5)
        np.testing.assert_array_equal(out, floating | walled)
        out = f(z, step=0.5, max_depth=8.0, max_area=4)  # both have 4 pixels
        np.testing.assert_array_equal(out, np.zeros(z.shape, bool))
        # a step as large as the floating gap (3.5 mm) no longer separates the floating cluster
        out = f(z, step=3.5, max_depth=14.0, max_area=5)
        np.testing.assert_array_equal(out, walled)
    res = find_clusters(z, params=ZCutParams(step=0.5, max_depth=8.0, max_area=5, a_max=40))
    assert res.n_clusters == 2
    np.testing.assert_array_equal(res.clusters > 0, floating | walled)
    assert res.clusters[2, 12] == 1 and res.clusters[7, 7] == 2  # raster order of first pixel
    np.testing.assert_array_equal(res.areas, [4, 4])
    np.testing.assert_allclose(res.rho, [0.1, 0.1])
    # z_max = 14: the walled patch enters the cuts at level (14 - 9) / 0.5 = 10, the floating
    # cluster is alone from level 0 on and first checked at k = 1
    np.testing.assert_array_equal(res.levels, [10, 1])
    np.testing.assert_array_equal(res.pixel_level[4:6, 4:6], 5)


# --------------------------------------------------------------------------------------------
# The stage view
# --------------------------------------------------------------------------------------------


def brute_stage(z: np.ndarray, step: float, max_depth: float, connectivity: int):
    """Per-pixel levels and per-level component counts straight from the definitions."""
    z = z.astype(np.float64)
    valid = np.isfinite(z)
    K = n_levels(step, max_depth)
    z_min, z_max = z[valid].min(), z[valid].max()
    zt = np.where(valid, z, z_min)
    structure = ndimage.generate_binary_structure(2, 2 if connectivity == 8 else 1)
    pixel_level = np.full(z.shape, -1, np.int64)
    counts = []
    for k in range(K + 1, -1, -1):
        cut = zt >= z_max - k * step
        pixel_level[cut] = k
        if k >= 1:
            counts.append(ndimage.label(cut, structure=structure)[1])
    return pixel_level, np.array(counts[::-1]), zt, z_max, structure


@pytest.mark.parametrize("seed", range(4))
def test_find_clusters_consistency(seed: int, kernel: str) -> None:
    rng = np.random.default_rng(2000 + seed)
    checked = 0
    for _ in range(40):
        z, p = random_frame(rng)
        if not np.isfinite(z).any():
            continue
        a_max = float(rng.choice([50.0, 123.0]))
        conn = p["connectivity"]
        params = ZCutParams(p["step"], p["max_depth"], p["max_area"], a_max=a_max, connectivity=conn)
        res = find_clusters(z, params=params)
        assert isinstance(res, CutResult)
        K = n_levels(p["step"], p["max_depth"])
        assert res.n_levels == K
        np.testing.assert_array_equal(res.outliers, zcut_outliers(z, **p))
        np.testing.assert_array_equal(res.outliers, res.clusters > 0)
        assert res.clusters.dtype == np.int32 and res.pixel_level.dtype == np.int16
        np.testing.assert_array_equal(res.areas, np.bincount(res.clusters.ravel(),
                                                             minlength=res.n_clusters + 1)[1:])
        assert (res.areas > 0).all()
        np.testing.assert_allclose(res.rho, res.areas / a_max)
        pixel_level, counts, zt, z_max, structure = brute_stage(z, p["step"], p["max_depth"], conn)
        np.testing.assert_array_equal(res.pixel_level, pixel_level)
        np.testing.assert_array_equal(res.level_counts, counts)
        assert res.z_max == z_max
        # each cluster is an outermost tagged component: identical in the cuts L and L + 1,
        # smaller than max_area, not identical in L - 1 and L (else it would be tagged at L - 1)
        for i, level in enumerate(res.levels, start=1):
            assert 1 <= level <= K
            member = res.clusters == i
            seed_px = tuple(np.argwhere(member)[0])
            comps = []  # the component holding the cluster's first pixel in the cuts L-1, L, L+1
            for k in (level - 1, level, level + 1):
                lab, _ = ndimage.label(zt >= z_max - k * p["step"], structure=structure)
                comps.append((lab == lab[seed_px]) & (lab[seed_px] > 0))
            assert np.array_equal(comps[1], comps[2])
            assert np.array_equal(comps[1] & np.isfinite(z), member)
            assert comps[1].sum() < p["max_area"]
            assert level == 1 or not np.array_equal(comps[0], comps[1])
            checked += 1
    assert checked > 0


def test_find_clusters_without_a_max_and_without_valid_pixels() -> None:
    z = figure6_scene()
    res = find_clusters(z, params=ZCutParams(step=0.5, max_depth=8.0, max_area=5))
    assert res.rho.shape == (2,) and np.isnan(res.rho).all()
    res = find_clusters(np.full((3, 4), np.nan), params=ZCutParams(step=0.5, max_depth=2.0, max_area=5))
    assert res.n_clusters == 0 and not res.outliers.any() and math.isnan(res.z_max)
    assert res.level_counts.shape == (5,) and (res.pixel_level == -1).all()
    res = find_clusters(np.zeros((0, 7)), params=ZCutParams(step=0.5, max_depth=2.0, max_area=5))
    assert res.clusters.shape == (0, 7)


def test_find_clusters_refuses_too_many_levels() -> None:
    with pytest.raises(ParameterError, match="levels"):
        find_clusters(np.zeros((2, 2)), params=ZCutParams(step=1e-6, max_depth=1.0, max_area=5))


# --------------------------------------------------------------------------------------------
# Laws (hypothesis)
# --------------------------------------------------------------------------------------------

DYADIC_STEPS = st.sampled_from([0.125, 0.25, 0.5, 1.0, 2.0])


@st.composite
def dyadic_frames(draw):
    """Heights = small integers x step/2 with a power-of-two step, some NaN."""
    step = draw(DYADIC_STEPS)
    shape = draw(hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=9))
    ints = draw(hnp.arrays(np.int64, shape, elements=st.integers(-40, 40)))
    nan = draw(hnp.arrays(np.bool_, shape, elements=st.booleans()))
    z = ints * (step / 2)
    z[nan & draw(st.booleans())] = np.nan
    params = dict(step=step, max_depth=draw(st.integers(0, 12)) * step / 2,
                  max_area=draw(st.integers(1, 20)), connectivity=draw(st.sampled_from([4, 8])))
    return z, params


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(dyadic_frames(), st.integers(-2**20, 2**20))
def test_shift_changes_nothing(frame, m: int) -> None:
    """Adding c = m * step to every height changes nothing.

    With a power-of-two step, heights that are integers times step/2 and |m| < 2**20, every
    height, shifted height, z_max - k*step and shifted threshold is a dyadic number with few
    significant bits, so all of them are exact in float64 and every comparison keeps its outcome.
    (With a step like 0.2 a shift can move a height across a threshold by rounding: not a law.)
    """
    z, params = frame
    c = m * params["step"]
    out = zcut_outliers(z, **params)
    np.testing.assert_array_equal(zcut_outliers(z + c, **params), out)
    np.testing.assert_array_equal(out, zcut_outliers_reference(z, **params))


@settings(max_examples=150, deadline=None)
@given(dyadic_frames())
def test_outliers_are_valid_and_symmetric(frame) -> None:
    """Outliers are valid pixels; transposing or flipping the image transposes/flips the mask."""
    z, params = frame
    out = zcut_outliers(z, **params)
    assert not (out & ~np.isfinite(z)).any()
    np.testing.assert_array_equal(zcut_outliers(z.T.copy(), **params), out.T)
    np.testing.assert_array_equal(zcut_outliers(z[::-1, ::-1].copy(), **params), out[::-1, ::-1])


@settings(max_examples=100, deadline=None)
@given(dyadic_frames(), st.integers(1, 5), st.sampled_from(["right", "below"]))
def test_nan_padding_below_every_cut_changes_nothing(frame, width: int, side: str) -> None:
    """NaN pixels take z_min; when z_min lies below the deepest cut (level K + 1), NaN pixels are in
    no cut, so a NaN band added beside the image changes nothing. (When z_min is inside the cuts,
    a NaN band joins the components along that edge: not a law.)"""
    z, params = frame
    z = z.copy()
    K = n_levels(params["step"], params["max_depth"])
    z[0, 0] = -1000.0  # far below z_max - (K + 1) * step, if another pixel is valid
    assume(np.isfinite(z).sum() >= 2)
    pad = np.full((z.shape[0], width) if side == "right" else (width, z.shape[1]), np.nan)
    zp = np.hstack([z, pad]) if side == "right" else np.vstack([z, pad])
    out = zcut_outliers(z, **params)
    outp = zcut_outliers(zp, **params)
    assert np.nanmax(z) - (K + 1) * params["step"] > -1000.0
    np.testing.assert_array_equal(outp[: z.shape[0], : z.shape[1]], out)
    assert not outp[z.shape[0]:, :].any() and not outp[:, z.shape[1]:].any()


# --------------------------------------------------------------------------------------------
# Bad input
# --------------------------------------------------------------------------------------------

GOOD = dict(step=0.2, max_depth=3.0, max_area=10)
BAD = [
    (np.zeros(5), {}, InputShapeError, r"height .*shape \(5,\)"),
    (np.zeros((2, 2, 3)), {}, InputShapeError, r"height .*shape \(2, 2, 3\)"),
    (np.zeros((2, 2), np.int32), {}, InputShapeError, r"height .*int32"),
    (np.zeros((2, 2), bool), {}, InputShapeError, r"height .*bool"),
    (np.zeros((2, 2), complex), {}, InputShapeError, r"height .*complex128"),
    ([[1, 2], [3, 4]], {}, InputShapeError, r"height .*int64"),
    (np.zeros((2, 2)), dict(step=0.0), ParameterError, r"step .*got 0\.0"),
    (np.zeros((2, 2)), dict(step=-0.2), ParameterError, r"step .*got -0\.2"),
    (np.zeros((2, 2)), dict(step=math.nan), ParameterError, r"step .*got nan"),
    (np.zeros((2, 2)), dict(step=math.inf), ParameterError, r"step .*got inf"),
    (np.zeros((2, 2)), dict(step="0.2"), ParameterError, r"step .*got '0\.2'"),
    (np.zeros((2, 2)), dict(max_depth=-1.0), ParameterError, r"max_depth .*got -1\.0"),
    (np.zeros((2, 2)), dict(max_depth=math.inf), ParameterError, r"max_depth .*got inf"),
    (np.zeros((2, 2)), dict(max_depth=math.nan), ParameterError, r"max_depth .*got nan"),
    (np.zeros((2, 2)), dict(max_area=0), ParameterError, r"max_area .*got 0"),
    (np.zeros((2, 2)), dict(max_area=-5), ParameterError, r"max_area .*got -5"),
    (np.zeros((2, 2)), dict(max_area=math.nan), ParameterError, r"max_area .*got nan"),
    (np.zeros((2, 2)), dict(max_area=True), ParameterError, r"max_area .*got True"),
    (np.zeros((2, 2)), dict(connectivity=6), ParameterError, r"connectivity .*got 6"),
    (np.zeros((2, 2)), dict(connectivity=8.0), ParameterError, r"connectivity .*got 8\.0"),
    (np.zeros((2, 2)), dict(connectivity=True), ParameterError, r"connectivity .*got True"),
]


@pytest.mark.parametrize("fn", [zcut_outliers, zcut_outliers_reference])
@pytest.mark.parametrize(("height", "override", "error", "match"), BAD)
def test_bad_input(fn, height, override, error, match) -> None:
    with pytest.raises(error, match=match):
        fn(height, **{**GOOD, **override})


def test_find_clusters_bad_input() -> None:
    with pytest.raises(ParameterError, match="params must be a ZCutParams, got dict"):
        find_clusters(np.zeros((2, 2)), params=GOOD)  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match="ZCutParams.connectivity must be 4 or 8, got 5"):
        find_clusters(np.zeros((2, 2)), params=ZCutParams(**GOOD, connectivity=5))
    with pytest.raises(InputShapeError, match=r"height .*shape \(4,\)"):
        find_clusters(np.zeros(4), params=ZCutParams(**GOOD))
    with pytest.raises(ParameterError, match="kernel must be one of 'auto', 'flood', 'union-find', got 'fast'"):
        find_clusters(np.zeros((2, 2)), params=ZCutParams(**GOOD), kernel="fast")
