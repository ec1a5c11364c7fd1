"""z-cut: the flood straight from the heights (zcut.cuts._flood: no valid mask, no padded level
image, row segments outside the cuts not read twice, read-outs over the pixels in the cuts only)
against the literal loop and against the previous full-image path, on synthetic scans, a ray-traced
frame, the real Kinect clouds, large invalid regions and degenerate inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from bench_frames import bench_kinds, bench_zcut
from gentle_state import gentle_labelled

from zcut import ZCutParams, find_clusters, zcut_outliers, zcut_outliers_reference
from zcut.cut_tree import SEGMENT, outlier_mask
from zcut.cuts import CutResult, _finite_min_max, _finite_range, _tree, _window
from zcut.params import n_levels

NOMINAL = dict(step=0.2, max_depth=30.0, max_area=210.0)


def previous_outliers(z: np.ndarray, *, step: float, max_depth: float, max_area: float,
                      connectivity: int = 8) -> np.ndarray:
    """zcut_outliers as it was before the fast path: valid mask, padded level image, full-image flood
    and read-out (zcut.cuts._tree, which the union-find kernel and zcut_tree still use)."""
    z = np.ascontiguousarray(z, dtype=np.float64)
    out = np.zeros(z.shape, dtype=bool)
    K = n_levels(step, max_depth)
    n, z_min, z_max = _finite_min_max(z)
    if n == 0 or K < 1:
        return out
    valid = np.isfinite(z)
    _, _, lab, _, _, node_parent, tagged, fin = _tree(z, valid, z_min, z_max, step, K, max_area, connectivity,
                                                      "flood")
    outlier_mask(lab, fin, node_parent, tagged, valid, out)
    return out


def same_result(a: CutResult, b: CutResult) -> None:
    for name in ("outliers", "clusters", "areas", "levels", "level_counts", "pixel_level"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape, name
        np.testing.assert_array_equal(x, y, err_msg=name)
    np.testing.assert_array_equal(a.rho, b.rho)
    for name in ("z_max", "z_min"):  # bit for bit, the sign of a zero included
        assert np.array(getattr(a, name)).tobytes() == np.array(getattr(b, name)).tobytes(), name
    assert a.n_levels == b.n_levels


def check(z: np.ndarray, *, reference: bool = True, **params: float) -> np.ndarray:
    """Every path agrees on z: the fast zcut_outliers, the previous path, the literal loop (when
    ``reference``), and find_clusters with the flood (fast) and the union-find (full image)."""
    got = zcut_outliers(z, **params)
    np.testing.assert_array_equal(got, previous_outliers(z, **params))
    if reference:
        np.testing.assert_array_equal(got, zcut_outliers_reference(z, **params))
    p = ZCutParams(params["step"], params["max_depth"], params["max_area"],
                   connectivity=int(params.get("connectivity", 8)), a_max=1000.0)
    fast = find_clusters(z, params=p)
    for kernel in ("flood", "union-find"):
        same_result(fast, find_clusters(z, params=p, kernel=kernel))
    np.testing.assert_array_equal(fast.outliers, got)
    return got


def height_mm(xyz: np.ndarray) -> np.ndarray:
    """The pipeline's height image of a camera cloud: -1000 z (higher = nearer)."""
    return -1000.0 * np.asarray(xyz[..., 2], dtype=np.float64)


# ------------------------------------------------------------------------------------------------
# synthetic scans, ray-traced, real
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("kind", "seed"), [("spheres", 1), ("zinc_nuts", 2), ("rods", 3), ("black_screws", 4),
                                            ("sprockets", 5)])
def test_synthetic_scans(kind: str, seed: int) -> None:
    from replay.synth import synthesize_frame

    xyz = synthesize_frame(kind=kind, seed=seed, size=(96, 160)).frame.xyz
    z = height_mm(xyz)
    assert np.isfinite(z).any()
    for params in (NOMINAL, dict(step=0.5, max_depth=60.0, max_area=40.0, connectivity=4),
                   dict(step=0.1, max_depth=400.0, max_area=math.inf)):
        check(z, **params)


def test_raytraced_frame() -> None:
    from replay.synth.raytrace import synthesize_raytraced_frame

    z = height_mm(synthesize_raytraced_frame(kind="spheres", seed=903, size=(60, 96), fill_mm=6.0).frame.xyz)
    assert np.isfinite(z).any()
    for params in (NOMINAL, dict(step=0.25, max_depth=80.0, max_area=20.0)):
        check(z, **params)


@pytest.mark.parametrize("name", ["mosd_test16.pcd", "table_scene_mug_stereo_textured.pcd"])
def test_real_kinect_clouds(real_data, name: str) -> None:
    import open3d as o3d

    cloud = o3d.io.read_point_cloud(str(real_data / name), remove_nan_points=False, remove_infinite_points=False)
    z = height_mm(np.asarray(cloud.points).reshape(480, 640, 3))
    assert np.isfinite(z).sum() > 100_000
    got = check(z, **NOMINAL)
    assert got.any()  # a case that tags something
    check(z[100:300, 50:400], step=1.0, max_depth=120.0, max_area=500.0, connectivity=4)


# ------------------------------------------------------------------------------------------------
# large invalid regions, segments, degenerate inputs
# ------------------------------------------------------------------------------------------------
def bumpy(rng: np.random.Generator, H: int, W: int, step: float) -> np.ndarray:
    """A pile of caps with floating patches, heights on the step/2 grid (many exactly on thresholds)."""
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    z = 0.01 * yy + 0.02 * xx
    for _ in range(40):
        cy, cx, r = rng.uniform(0, H), rng.uniform(0, W), rng.uniform(2, 12)
        z = np.maximum(z, rng.uniform(0, 20) * step * np.clip(1 - ((yy - cy) ** 2 + (xx - cx) ** 2) / r**2, 0, None)
                       + rng.uniform(0, 10) * step * (((yy - cy) ** 2 + (xx - cx) ** 2) < r**2))
    for _ in range(30):
        y, x = int(rng.integers(0, H)), int(rng.integers(0, W))
        z[y:y + 3, x:x + 2] += rng.uniform(1, 8) * step
    z = z + rng.normal(0, 0.3 * step, z.shape)
    return np.round(z / (step / 2)) * (step / 2)


@pytest.mark.parametrize("seed", range(4))
def test_large_invalid_regions(seed: int) -> None:
    rng = np.random.default_rng(seed)
    H, W = 70, 3 * SEGMENT + 17
    z = bumpy(rng, H, W, 0.5)
    z[:, : 2 * SEGMENT] = np.nan  # whole segments invalid
    z[10:40, 150:] = np.nan  # a block across segment edges
    z[rng.random(z.shape) < 0.3] = np.nan  # scattered dropouts
    z[5, 200] = np.inf
    z[6, 201] = -np.inf  # infinities are invalid, like NaN
    for params in (dict(step=0.5, max_depth=3.0, max_area=30.0), dict(step=0.5, max_depth=6.0, max_area=math.inf),
                   dict(step=0.5, max_depth=200.0, max_area=8.0, connectivity=4)):
        check(z, **params)
        check(z.astype(np.float32), **params)
        check(z.T.copy(), **params)


@pytest.mark.parametrize("width", [1, 2, SEGMENT - 1, SEGMENT, SEGMENT + 1, 2 * SEGMENT + 3])
def test_segment_edges(width: int) -> None:
    rng = np.random.default_rng(width)
    step = 0.5
    z = bumpy(rng, 23, width, step)
    z_max = float(z.max())
    # segments whose highest height lies exactly on, just above or just below the lowest cut
    for k, delta in ((4, 0.0), (4, step / 2), (4, -step / 2)):
        z2 = z.copy()
        z2[::3] = np.minimum(z2[::3], z_max - k * step + delta)
        z2[1::4] = np.nan
        check(z2, step=step, max_depth=(k - 1) * step, max_area=25.0)
        check(z2, step=step, max_depth=k * step, max_area=25.0, connectivity=4)


def test_every_pixel_in_the_cuts() -> None:
    """z_min within the cut range: the invalid pixels (at z_min) are in the cuts, no segment skipped."""
    rng = np.random.default_rng(5)
    z = bumpy(rng, 40, 150, 0.5)
    z[rng.random(z.shape) < 0.4] = np.nan
    z[:, 70:140] = np.nan
    check(z, step=0.5, max_depth=1000.0, max_area=50.0)
    check(z, step=0.5, max_depth=float(np.nanmax(z) - np.nanmin(z)), max_area=math.inf)


@pytest.mark.parametrize("case", ["all_nan", "one_valid", "three", "one_row", "one_column", "constant",
                                  "signed_zeros", "two_values", "empty"])
def test_degenerate(case: str) -> None:
    z = {
        "all_nan": np.full((5, 70), np.nan),
        "one_valid": np.where(np.arange(200).reshape(10, 20) == 57, 3.0, np.nan),
        "three": np.array([[0.0, 1.0, 0.0], [1.0, 5.0, 1.0], [0.0, np.nan, 0.0]]),
        "one_row": np.array([[0.0, 2.0, 2.0, 0.0, np.nan, 3.0, 0.0]]),
        "one_column": np.array([[0.0], [2.0], [np.nan], [0.5], [0.0]]),
        "constant": np.full((9, 130), 7.0),
        "signed_zeros": np.array([[-0.0, 0.0, 1.0, -0.0], [0.0, -0.0, np.nan, 0.0]]),
        "two_values": np.where(np.random.default_rng(1).random((20, 140)) < 0.1, 2.0, 0.0),
        "empty": np.zeros((0, 5)),
    }[case]
    for params in (dict(step=0.5, max_depth=2.0, max_area=4.0), dict(step=1.0, max_depth=0.0, max_area=4.0),
                   dict(step=0.25, max_depth=10.0, max_area=math.inf, connectivity=4)):
        check(z, **params)


def _segments_holding_a_finite_height(z: np.ndarray) -> int:
    return sum(bool(np.isfinite(z[r, j:j + SEGMENT]).any()) for r in range(z.shape[0]) for j in range(0, z.shape[1], SEGMENT))


def test_finite_range_equals_the_min_max() -> None:
    """The extremes and every segment's largest height; the count is of the segments holding a finite
    height (0 exactly when :func:`_finite_min_max` counts none), with the integer keys and with their
    fallback for zero extremes (the last shapes), with segments all NaN, all infinite and a mix."""
    rng = np.random.default_rng(3)
    for shape, zero in (((0, 4), False), ((3, 0), False), ((1, 1), False), ((7, SEGMENT), False),
                        ((5, 3 * SEGMENT + 1), False), ((6, 2 * SEGMENT + 5), True), ((4, 3), True)):
        z = rng.normal(size=shape)
        z[rng.random(shape) < 0.3] = np.nan
        if z.size > 4:
            z.flat[1], z.flat[3] = np.inf, -np.inf
        if shape[1] > SEGMENT:
            z[1, :SEGMENT] = np.nan  # a segment of NaN only
            z[2, SEGMENT:2 * SEGMENT] = np.where(np.arange(SEGMENT) % 2, np.inf, -np.inf)  # of infinities only
            z[3, :] = np.nan  # a whole row
        if zero and z.size:
            z[np.isfinite(z)] = np.abs(z[np.isfinite(z)])
            z.flat[int(np.flatnonzero(np.isfinite(z))[-1])] = -0.0  # the smallest height a zero
        n, lo, hi, seg = _finite_range(z)
        m, lo_ref, hi_ref = _finite_min_max(z)
        assert (lo, hi) == (lo_ref, hi_ref) and [np.signbit(lo), np.signbit(hi)] == [np.signbit(lo_ref),
                                                                                      np.signbit(hi_ref)]
        assert n == _segments_holding_a_finite_height(z) and (n == 0) == (m == 0)
        for r in range(shape[0]):
            for j in range(seg.shape[1]):
                part = z[r, j * SEGMENT:(j + 1) * SEGMENT]
                part = part[np.isfinite(part)]
                assert seg[r, j] == (part.max() if part.size else -np.inf)
    z = np.array([[-0.0, 0.0, 0.0, -0.0]])  # the first of equal extremes, as before
    assert [np.signbit(v) for v in _finite_range(z)[1:3]] == [np.signbit(v) for v in _finite_min_max(z)[1:]]
    assert _finite_range(np.full((3, 2 * SEGMENT), np.inf))[:3] == (0, np.inf, -np.inf)


@pytest.mark.parametrize("seed", range(6))
def test_window_holds_the_segments_in_the_cuts(seed: int) -> None:
    """:func:`zcut.cuts._window` (one kernel pass over the segments' largest heights) against numpy's
    passes over the boolean image of the segments in the cuts, thresholds on, above and below a segment's
    largest height, none and every segment in the cuts included."""
    rng = np.random.default_rng(400 + seed)
    H, W = int(rng.integers(1, 40)), int(rng.integers(1, 6 * SEGMENT))
    z = rng.normal(size=(H, W))
    z[rng.random((H, W)) < 0.2 * seed] = np.nan
    _, _, _, seg = _finite_range(z)
    finite = seg[np.isfinite(seg)]
    for thr in [-np.inf, np.inf, 10.0, -10.0, *rng.choice(finite, size=min(5, finite.size), replace=False),
                *(np.nextafter(finite[:2], np.inf))]:
        read = seg >= thr
        got = _window(seg, float(thr), W)
        assert got[4] == np.count_nonzero(read)
        if not read.any():
            assert got == (0, 0, 0, 0, 0)
            continue
        rows, cols = np.flatnonzero(read.any(axis=1)), np.flatnonzero(read.any(axis=0))
        wc = int(cols[0]) * SEGMENT
        assert got[:4] == (int(rows[0]), wc, int(rows[-1]) + 1 - int(rows[0]), min((int(cols[-1]) + 1) * SEGMENT, W) - wc)


def test_bench_frames_at_nominal_parameters() -> None:
    """The benchmark's two 1920 x 1200 frames: the previous path and the union-find view agree (the
    literal loop takes minutes there; bench/bench_zcut.py compares it)."""
    bench = bench_zcut()
    for z in (bench.pile_frame(), bench.dense_frame()):
        check(z, reference=False, step=0.2, max_depth=30.0, max_area=0.07 * bench.A_MAX)


# ------------------------------------------------------------------------------------------------
# the flood over the small gentle components only (zcut.cut_tree.gentle_prune)
# ------------------------------------------------------------------------------------------------
def terraces(rng: np.random.Generator, H: int, W: int, step: float) -> np.ndarray:
    """Heights exactly on the levels (z_max - k * step, dyadic step): plateaus of random sizes, cliffs of
    1, 2 and 3 levels between them, single-pixel spikes and pits, NaN holes; every tie at a level
    boundary is exact."""
    q = np.zeros((H, W), np.int64)
    for _ in range(int(rng.integers(5, 40))):
        y, x = int(rng.integers(0, H)), int(rng.integers(0, W))
        h, w = int(rng.integers(1, 14)), int(rng.integers(1, 14))
        q[y:y + h, x:x + w] = int(rng.integers(0, 9))
    spikes = rng.random((H, W)) < 0.03
    q[spikes] = rng.integers(0, 9, int(spikes.sum()))
    z = -step * q.astype(np.float64)
    z[rng.random((H, W)) < 0.05] = np.nan
    return z


def pruned_counts(z: np.ndarray, *, step: float, max_depth: float, max_area: float, connectivity: int,
                  check: int = 2**40, gentle: int | None = None) -> tuple[int, int]:
    """(pixels in the cuts, pixels kept by gentle_prune) of z, from the kernels themselves (labelling
    every pixel unless ``check`` says when to look whether it pays; ``gentle``: the labelling's
    connectivity, the z-cut's by default)."""
    state = gentle_labelled(z, step=step, max_depth=max_depth, max_area=max_area, gentle=gentle or connectivity,
                            check=check)
    return state.m, state.prune(max_area=max_area, connectivity=connectivity)


def pruned_outliers(z: np.ndarray, *, step: float, max_depth: float, max_area: float, connectivity: int = 8,
                    check: int = 2**40, gentle: int | str = "auto") -> np.ndarray:
    """zcut_outliers through the pruned flood whatever the frame's size (zcut_outliers itself floods
    frames of fewer than PRUNE_MIN pixels in the cuts whole); ``check``: when the labelling looks
    whether it pays (default: never, every pixel labelled)."""
    from zcut.cuts import _pruned_outliers

    z = np.ascontiguousarray(z, dtype=np.float64)
    out = np.zeros(z.shape, dtype=bool)
    K = n_levels(step, max_depth)
    n, lo, hi, seg = _finite_range(z)
    if n == 0 or K < 1:
        return out
    done = _pruned_outliers(z, seg, lo, hi, step, K, max_area, connectivity, out, minimum=0, check=check,
                            gentle=gentle)
    if max_area > z.size:  # no gentle component can reach max_area: the whole flood's path
        assert not done
        return zcut_outliers(z, step=step, max_depth=max_depth, max_area=max_area, connectivity=connectivity)
    assert done
    return out


#: The gentle components the prune may label, by the z-cut's connectivity ("auto": the z-cut's own; the
#: 4-connected ones are subsets of the 8-connected ones, so they may serve an 8-connected z-cut too).
GENTLE: dict[int | float, tuple[int | str, ...]] = {8: ("auto", 4, 8), 4: ("auto", 4)}


@pytest.mark.parametrize("seed", range(12))
def test_pruned_flood_on_terraces(seed: int) -> None:
    """Plateaus and cliffs whose gentle components straddle max_area, exact ties at the levels: the flood
    over the small gentle components (with the left-out neighbours' levels) gives the whole tree's mask,
    labelling every pixel or giving up after the first rows."""
    rng = np.random.default_rng(seed)
    step = 0.25
    z = terraces(rng, int(rng.integers(8, 40)), int(rng.integers(8, 150)), step)
    pruned = 0
    for conn in (8, 4):
        for max_area in (1.0, 2.0, 5.0, 17.0, 60.0, 400.0):
            for max_depth in (0.5, 1.0, 2.0, 10.0):
                params = dict(step=step, max_depth=max_depth, max_area=max_area, connectivity=conn)
                want = check(z, reference=max_area in (5.0, 60.0), **params)
                for gentle in GENTLE[conn]:
                    for when in (2**40, 1, 60):
                        np.testing.assert_array_equal(pruned_outliers(z, check=when, gentle=gentle, **params), want)
                if np.isfinite(z).any():
                    for g in {4, conn}:
                        m, keep = pruned_counts(z, gentle=g, **params)
                        pruned += m - keep
    assert pruned > 0  # the left-out pixels (and their levels at the kept ones' borders) were exercised


@pytest.mark.parametrize("seed", range(3))
def test_pruned_flood_on_random_fields(seed: int) -> None:
    """The fuzz frames of the other tests (bumps, floating patches, heights on the step/2 grid, NaN) through
    the pruned flood, against the whole flood and the literal loop."""
    rng = np.random.default_rng(100 + seed)
    z = bumpy(rng, 50, 130, 0.5)
    z[rng.random(z.shape) < 0.1] = np.nan
    z[10:25, 40:90] = np.nan
    for params in (dict(step=0.5, max_depth=3.0, max_area=30.0), dict(step=0.5, max_depth=20.0, max_area=8.0,
                                                                       connectivity=4),
                   dict(step=0.25, max_depth=1000.0, max_area=200.0)):
        want = zcut_outliers_reference(z, **params)
        np.testing.assert_array_equal(previous_outliers(z, **params), want)
        for gentle in GENTLE[params.get("connectivity", 8)]:
            for when in (2**40, 1):
                np.testing.assert_array_equal(pruned_outliers(z, check=when, gentle=gentle, **params), want)


def test_pruned_flood_keeps_few_pixels_of_the_pile() -> None:
    """On the benchmark's pile only the small gentle components are flooded, and the mask is the whole
    flood's."""
    z = bench_kinds()["pile"]()[300:700, 500:1300]
    m, keep = pruned_counts(z, step=0.2, max_depth=30.0, max_area=210.0, connectivity=8)
    assert 0 < keep < m / 3
    want = previous_outliers(z, **NOMINAL)
    assert want.any()
    np.testing.assert_array_equal(pruned_outliers(z, **NOMINAL), want)
    m4, keep4 = pruned_counts(z, step=0.2, max_depth=30.0, max_area=210.0, connectivity=8, gentle=4)
    assert m4 == m and keep <= keep4 < m / 2  # the 4-connected components: subsets of the 8-connected ones
    for gentle in ("auto", 4, 8):
        np.testing.assert_array_equal(pruned_outliers(z, gentle=gentle, **NOMINAL), want)
    np.testing.assert_array_equal(zcut_outliers(z, **NOMINAL), want)


def test_the_4_connected_components_do_not_pay_on_noisy_relief() -> None:
    """On the benchmark's dense frame (half of the edges gentle, at random) the 4-connected gentle
    components do not pay at the check (the labelling stops there, the levels and the pixel list go on
    to the end), the 8-connected ones do (most pixels left out); every way gives the whole flood's mask."""
    from zcut.cuts import PRUNE_CHECK

    z = np.ascontiguousarray(bench_kinds()["dense"]()[:240, :640])
    H, W = z.shape
    check_at = max(PRUNE_CHECK, 8 * W)
    four = gentle_labelled(z, step=0.2, max_depth=30.0, max_area=210.0, gentle=4, check=check_at)
    assert not four.labelled and four.m == H * W  # stopped labelling at the check, not levelling
    assert four.nl < 10 * W  # the labels of the first rows only
    eight = gentle_labelled(z, step=0.2, max_depth=30.0, max_area=210.0, gentle=8, check=check_at)
    assert eight.labelled and eight.m == H * W
    m, keep = pruned_counts(z, step=0.2, max_depth=30.0, max_area=210.0, connectivity=8, check=check_at)
    assert m == H * W and keep < m / 5
    want = previous_outliers(z, **NOMINAL)
    assert want.any()
    for gentle in ("auto", 4, 8):
        np.testing.assert_array_equal(pruned_outliers(z, gentle=gentle, check=int(check_at), **NOMINAL), want)
