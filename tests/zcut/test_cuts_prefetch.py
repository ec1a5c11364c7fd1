"""The extremes pass with its prefetch (:func:`zcut.cut_tree.finite_range`, ``PREFETCH_AHEAD``): a hint that
changes no value. Its results (the extremes, the count of segments holding a finite height, every segment's
largest height) against numpy's, on frames shorter and longer than the prefetch distance (where its index is
clamped to the last height), on the bench's full-size frames (piles, a dense frame, large invalid regions) and
on real clouds; and the z-cut's masks on those frames against the previous full-image path."""

from __future__ import annotations

import numpy as np
import pytest
from bench_frames import bench_kinds
from test_cuts_fast import height_mm, previous_outliers

from zcut import zcut_outliers
from zcut.cut_tree import PREFETCH_AHEAD, SEGMENT, finite_range
from zcut.cuts import _finite_min_max, _finite_range

NOMINAL = dict(step=0.2, max_depth=30.0, max_area=210.0)


def numpy_range(z: np.ndarray) -> tuple[int, float, float, np.ndarray]:
    """What :func:`zcut.cuts._finite_range` gives, by numpy: (segments holding a finite height, min, max,
    each segment's largest finite height, -inf for none)."""
    H, W = z.shape
    n_seg = -(-W // SEGMENT)
    pad = np.full((H, n_seg * SEGMENT), -np.inf)
    pad[:, :W] = np.where(np.isfinite(z), z, -np.inf)
    seg = pad.reshape(H, n_seg, SEGMENT).max(axis=2)
    fin = z[np.isfinite(z)]
    if fin.size == 0:
        return 0, np.inf, -np.inf, seg
    return int(np.count_nonzero(seg > -np.inf)), float(fin.min()), float(fin.max()), seg


def check_range(z: np.ndarray) -> None:
    z = np.ascontiguousarray(z, dtype=np.float64)
    n, lo, hi, seg = _finite_range(z)
    n_ref, lo_ref, hi_ref, seg_ref = numpy_range(z)
    assert (n, lo, hi) == (n_ref, lo_ref, hi_ref)
    np.testing.assert_array_equal(seg, seg_ref)
    m, lo2, hi2 = _finite_min_max(z)
    assert (lo, hi) == (lo2, hi2) and (n == 0) == (m == 0)


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (1, PREFETCH_AHEAD - 1), (1, PREFETCH_AHEAD),
                                   (1, PREFETCH_AHEAD + 1), (2, PREFETCH_AHEAD // 2 + 3), (PREFETCH_AHEAD, 1),
                                   (3, SEGMENT - 1), (5, 3 * SEGMENT + 7), (17, 2 * PREFETCH_AHEAD + 9)])
def test_short_and_long_frames(shape: tuple[int, int]) -> None:
    """Frames around the prefetch distance (its index runs past the last height and is clamped), with NaN,
    infinities and a last height that is the largest or the only finite one."""
    rng = np.random.default_rng(shape[0] * 1000 + shape[1])
    z = rng.normal(size=shape) * 50.0
    z[rng.random(shape) < 0.25] = np.nan
    if z.size > 3:
        z.flat[0], z.flat[2] = np.inf, -np.inf
    check_range(z)
    z.flat[-1] = 1e6  # the last height the largest
    check_range(z)
    z[...] = np.nan
    check_range(z)
    z.flat[-1] = -3.5  # the only finite one, the last
    check_range(z)


def test_a_frame_at_the_end_of_its_buffer() -> None:
    """The heights the last part of a larger buffer (a view whose end is the buffer's end), and the kernel
    called directly on a row view: the same results."""
    rng = np.random.default_rng(11)
    buf = rng.normal(size=40 * 300 + 5)
    z = buf[5:].reshape(40, 300)
    check_range(z)
    seg = np.empty((1, -(-300 // SEGMENT)))
    n, lo, hi = finite_range(np.ascontiguousarray(z[-1:]), seg)
    ref = numpy_range(z[-1:])
    assert (n, lo, hi) == ref[:3]
    np.testing.assert_array_equal(seg, ref[3])


@pytest.mark.parametrize(("kind", "seed"), [("pile", 23), ("pile", 24), ("holes", 25), ("dense", 32)])
def test_bench_frames_full_size(kind: str, seed: int) -> None:
    """The bench's kinds at 1920 x 1200 (seeds the bench does not use): the extremes and segment maxima
    against numpy's, and zcut_outliers against the previous full-image path."""
    z = bench_kinds()[kind](seed)
    check_range(z)
    if kind != "dense":  # (the dense frame's previous path takes seconds)
        np.testing.assert_array_equal(zcut_outliers(z, **NOMINAL), previous_outliers(z, **NOMINAL))


@pytest.mark.parametrize("name", ["mosd_test16.pcd", "table_scene_mug_stereo_textured.pcd"])
def test_real_clouds(real_data, name: str) -> None:  # type: ignore[no-untyped-def]
    """Real organised clouds (a Kinect and a stereo one, 480 x 640, NaN where the sensor saw nothing): the
    extremes and segment maxima, and the mask against the previous full-image path."""
    import open3d as o3d

    cloud = o3d.io.read_point_cloud(str(real_data / name), remove_nan_points=False, remove_infinite_points=False)
    z = height_mm(np.asarray(cloud.points).reshape(480, 640, 3))
    check_range(z)
    np.testing.assert_array_equal(zcut_outliers(z, **NOMINAL), previous_outliers(z, **NOMINAL))
