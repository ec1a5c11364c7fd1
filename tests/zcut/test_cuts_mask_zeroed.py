"""The outlier mask zeroed by the pruned flood's level pass (:func:`zcut.cut_tree.gentle_levels`' ``zero``), not
by ``np.zeros`` before the call: :func:`zcut.cuts.zcut_outliers` allocates the mask with ``np.empty``, so a byte
the level pass missed would read as garbage. Each case here hands the pruned path a mask of garbage (every byte
True, or random bytes) and compares the result with the previous full-image path and the literal loop: windows of
one row in the middle of a frame (every row outside the window zeroed all the same), frames with every pixel in the
cuts (the path without the labels' list), the labelling given up (``check``), 4-connected cuts and gentle
components, held-out piles, large invalid regions and dense frames at full size, real clouds; and the paths that
do not take the pruned flood (too few pixels, no finite height, K < 1) still return zeros."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from test_cuts_fast import height_mm, previous_outliers

from zcut import zcut_outliers
from zcut.cuts import _check_height, _finite_range, _pruned_outliers, zcut_outliers_reference
from zcut.params import n_levels

NOMINAL = dict(step=0.2, max_depth=30.0, max_area=210.0)


def _frames() -> dict:
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
    try:
        from bench_zcut import dense_frame, holes_frame, pile_frame
    finally:
        sys.path.pop(0)
    return {"pile": pile_frame, "holes": holes_frame, "dense": dense_frame}


def pruned_on_garbage(z: np.ndarray, *, step: float, max_depth: float, max_area: float, connectivity: int = 8,
                      fill: str = "ones", **kw: object) -> np.ndarray | None:
    """``_pruned_outliers`` into a mask of garbage; None when the path does not apply (then the mask must be as
    it was)."""
    z = _check_height(z)
    n, lo, hi, seg = _finite_range(z)
    assert n > 0
    if fill == "ones":
        out = np.ones(z.shape, bool)
    else:
        out = np.random.default_rng(5).integers(0, 256, z.shape, dtype=np.uint8).view(np.bool_)
    before = out.copy()
    if not _pruned_outliers(z, seg, lo, hi, step, n_levels(step, max_depth), max_area, connectivity, out,
                            **kw):  # type: ignore[arg-type]
        assert out.tobytes() == before.tobytes()  # nothing written
        return None
    assert set(np.unique(out.view(np.uint8))) <= {0, 1}  # every byte written: False or True, no garbage left
    return out


def field(rng: np.random.Generator, H: int, W: int, amp: float) -> np.ndarray:
    z = np.cumsum(rng.normal(0.0, amp, (H, W)), axis=1) + np.cumsum(rng.normal(0.0, amp, (H, 1)), axis=0)
    z += rng.normal(0.0, 0.05, (H, W))
    return z


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("connectivity", [8, 4])
def test_small_frames_against_the_literal_loop(seed: int, connectivity: int) -> None:
    """Random fields with invalid regions: the pruned path forced (``minimum`` 0) into a mask of garbage."""
    rng = np.random.default_rng(100 + seed)
    H, W = int(rng.integers(2, 40)), int(rng.integers(2, 150))
    z = field(rng, H, W, 0.3)
    z[rng.random((H, W)) < 0.1] = np.nan
    z[:, : int(rng.integers(0, W // 2 + 1))] = np.nan
    params = dict(step=0.2, max_depth=float(rng.uniform(0.5, 4.0)), max_area=float(rng.integers(3, 40)))
    ref = zcut_outliers_reference(z, **params, connectivity=connectivity)
    for fill in ("ones", "random"):
        for gentle in ("auto", 4):
            got = pruned_on_garbage(z, **params, connectivity=connectivity, fill=fill, minimum=0, gentle=gentle)
            assert got is not None
            np.testing.assert_array_equal(got, ref)
    np.testing.assert_array_equal(zcut_outliers(z, **params, connectivity=connectivity), ref)


@pytest.mark.parametrize(("H", "W", "row"), [(30, 200, 15), (30, 200, 0), (30, 200, 29), (1, 300, 0), (9, 1, 4),
                                             (40, 64, 20), (40, 65, 39)])
def test_a_window_of_one_row(H: int, W: int, row: int) -> None:
    """Only one row in the cuts (the window one row high): the whole mask, every row outside the window too, is
    zeroed by that one row's share."""
    rng = np.random.default_rng(H * 1000 + W + row)
    z = np.full((H, W), -100.0)
    z[row] = 5.0 + rng.normal(0.0, 0.05, W)
    z[row, W // 3:W // 3 + 3] += 2.0  # a small bump: outliers, or not, as the literal loop says
    for area in (5.0, min(150.0, H * W)):  # (the path takes max_area <= H * W only)
        params = dict(step=0.2, max_depth=3.0, max_area=area)
        ref = zcut_outliers_reference(z, **params)
        got = pruned_on_garbage(z, **params, minimum=0)
        assert got is not None
        np.testing.assert_array_equal(got, ref)
        np.testing.assert_array_equal(zcut_outliers(z, **params), ref)


def test_every_pixel_in_the_cuts_and_the_labelling_given_up() -> None:
    """Every pixel in the cuts (no list of labels: the other call of the level pass) and a frame whose labelling
    gives up at the check (``check`` 1: the levels go on, the mask still zeroed)."""
    rng = np.random.default_rng(7)
    z = field(rng, 50, 130, 0.05)
    params = dict(step=0.2, max_depth=400.0, max_area=30.0)
    ref = zcut_outliers_reference(z, **params)
    for kw in (dict(minimum=0), dict(minimum=0, check=1)):
        got = pruned_on_garbage(z, **params, **kw)  # type: ignore[arg-type]
        assert got is not None
        np.testing.assert_array_equal(got, ref)
    noisy = rng.normal(0.0, 2.0, (40, 90))  # few gentle edges: the labelling gives up
    ref = zcut_outliers_reference(noisy, **NOMINAL)
    got = pruned_on_garbage(noisy, **NOMINAL, minimum=0, check=64)
    assert got is not None
    np.testing.assert_array_equal(got, ref)


@pytest.mark.parametrize(("kind", "seed"), [("pile", 25), ("pile", 26), ("holes", 27), ("dense", 33)])
def test_full_size_frames(kind: str, seed: int) -> None:
    """The bench's kinds at 1920 x 1200, at seeds no bench or other test uses: the pruned path into a mask of
    garbage, and ``zcut_outliers``, against the previous full-image path."""
    z = _frames()[kind](seed)
    ref = previous_outliers(z, **NOMINAL)
    got = pruned_on_garbage(z, **NOMINAL)
    assert got is not None
    np.testing.assert_array_equal(got, ref)
    np.testing.assert_array_equal(zcut_outliers(z, **NOMINAL), ref)


def test_paths_without_the_pruned_flood_return_zeros() -> None:
    """Where the pruned flood does not run (no finite height, K < 1, too few pixels in the cuts) the mask is
    zeroed before the other paths; the literal loop's masks on small frames."""
    for shape in ((0, 4), (3, 0), (0, 0)):
        out = zcut_outliers(np.zeros(shape), **NOMINAL)
        assert out.shape == shape and out.dtype == np.bool_
    for z in (np.full((5, 7), np.nan), np.full((4, 4), np.inf)):
        out = zcut_outliers(z, **NOMINAL)
        assert out.dtype == np.bool_ and not out.any()
    rng = np.random.default_rng(3)
    f = field(rng, 30, 80, 0.4)
    assert not zcut_outliers(f, step=0.2, max_depth=0.1, max_area=50.0).any()  # K = 0
    for z in (f, np.full((3, 3), 1.0), np.where(rng.random((6, 9)) < 0.5, f[:6, :9], np.nan)):
        for params in (NOMINAL, dict(step=0.2, max_depth=3.0, max_area=20.0)):
            ref = zcut_outliers_reference(z, **params)
            np.testing.assert_array_equal(zcut_outliers(z, **params), ref)
            got = pruned_on_garbage(z, **params)  # (None: too few pixels, nothing written; with every pixel in
            assert got is None or np.array_equal(got, ref)  # the cuts the path runs on any frame)


@pytest.mark.parametrize("name", ["mosd_test20.pcd", "milk_cartoon_all_small_clorox.pcd"])
def test_real_clouds(real_data, name: str) -> None:  # type: ignore[no-untyped-def]
    """Two real clouds, forced through the pruned flood (they hold fewer than ``PRUNE_MIN`` pixels in the cuts),
    into a mask of garbage, at Δd 0.2 and 1 mm."""
    import open3d as o3d

    cloud = o3d.io.read_point_cloud(str(real_data / name), remove_nan_points=False, remove_infinite_points=False)
    xyz = np.asarray(cloud.points).reshape(480, 640, 3)
    z = height_mm(xyz)
    for params in (NOMINAL, dict(step=1.0, max_depth=60.0, max_area=210.0)):
        ref = previous_outliers(z, **params)
        got = pruned_on_garbage(z, **params, minimum=0)
        assert got is not None
        np.testing.assert_array_equal(got, ref)
