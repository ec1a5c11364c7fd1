"""zcut.registration.prepare_target's one-pass path (``_checked_copy``: the copy, the finite test and the voxel
grid's bounds together) against the composition it replaces, ``_check_points`` then ``voxel_down_points`` (which
tests/zcut/test_registration_voxels.py holds to Open3D), bit for bit: random clouds in float64 and float32, rows
with NaN or inf (which take the old path), one row, empty and all-NaN input, strided input, the bin pixels of
synthetic frames (hand-made, on the walls, ray-traced) with a large invalid region, and the real Kinect scans.
And ``subsampled_points`` (the target's points, eight unset pixels passed over at once) against NumPy's strided
boolean index on masks of every density, widths that are and are not whole words, steps 1-5, strided masks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from zcut.errors import InputShapeError
from zcut.registration import (
    _bounds,
    _check_points,
    _checked_copy,
    prepare_target,
    subsampled_points,
    voxel_down_points,
)

REAL = Path("/work/shared/data/real")


def assert_as_before(target: np.ndarray, voxel_m: float = 0.003) -> None:
    got = prepare_target(target, voxel_m=voxel_m)
    t = _check_points(target, "target")
    cloud = voxel_down_points(t, voxel_m) if voxel_m > 0 and len(t) else t
    assert got.points.dtype == np.float64 and got.points.flags.c_contiguous
    assert got.points.shape == t.shape and got.points.tobytes() == t.tobytes()
    assert got.cloud.points.shape == cloud.shape and got.cloud.points.tobytes() == cloud.tobytes()
    assert got.voxel_m == float(voxel_m)
    if len(target):
        assert not np.shares_memory(got.points, target)  # a copy, as before


def test_random_clouds_in_both_float_types():
    rng = np.random.default_rng(71)
    for t in range(40):
        n = int(rng.integers(1, 30_000)) if t % 4 else int(rng.integers(1, 50))
        p = rng.normal(0.0, float(rng.choice([0.002, 0.05, 0.4])), (n, 3)) + rng.normal(0.0, 1.0, 3)
        if t % 3 == 0:
            p[rng.random(n) < 0.2] = -0.0  # signed zeros among the bounds
        assert_as_before(p, float(rng.choice([0.001, 0.003, 0.006])))
        assert_as_before(p.astype(np.float32), 0.003)


def test_bounds_are_those_of_the_bounds_kernel():
    rng = np.random.default_rng(72)
    for n in (1, 2, 17, 5000):
        p = rng.normal(0.0, 1.0, (n, 3))
        p[rng.random(n) < 0.3, 1] = 0.0
        p[rng.random(n) < 0.3, 2] = -0.0
        out, lo, hi, finite = _checked_copy(p)
        want_lo, want_hi = _bounds(p)
        assert finite and out.tobytes() == p.tobytes()
        assert lo.tobytes() == want_lo.tobytes() and hi.tobytes() == want_hi.tobytes()


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_rows_take_the_previous_path(bad):
    rng = np.random.default_rng(73)
    p = rng.normal(0.5, 0.05, (4000, 3))
    for rows in ([0], [3999], [17, 18, 2000], list(range(0, 4000, 3))):
        q = p.copy()
        q[rows, int(rng.integers(0, 3))] = bad
        assert not _checked_copy(q)[3]
        assert_as_before(q)
        assert_as_before(q.astype(np.float32))


def test_degenerate_inputs():
    assert_as_before(np.array([[0.1, 0.2, 0.5]]))  # one row
    assert_as_before(np.full((30, 3), 0.25))  # one voxel
    assert_as_before(np.empty((0, 3)))
    assert_as_before(np.full((50, 3), np.nan))  # all NaN: no point left
    rng = np.random.default_rng(74)
    big = rng.normal(0.5, 0.05, (3000, 6))
    assert_as_before(big[:, ::2])  # strided, not C order
    assert_as_before(np.asfortranarray(big[:, :3]))
    assert_as_before(big[:, :3], voxel_m=0.0)  # no grid
    with pytest.raises(InputShapeError, match="target must be an"):
        prepare_target(np.zeros((5, 2)), voxel_m=0.003)
    with pytest.raises(InputShapeError, match="target must be an"):
        prepare_target(np.zeros((5, 3), np.int64), voxel_m=0.003)
    with pytest.raises(InputShapeError, match="too large"):
        prepare_target(np.array([[0.0, 0.0, 0.5], [1e35, 0.0, 0.5]]), voxel_m=0.003)


def test_the_bin_pixels_of_synthetic_frames():
    from replay.synth.raytrace import synthesize_raytraced_frame
    from replay.synth.synthesize import synthesize_frame
    from zcut.binmask import bin_mask, bin_pixels
    from zcut.registration import subsampled_points

    frames = [synthesize_frame(kind="zinc_nuts", seed=75, index=1, size=(480, 640)).frame,
              synthesize_frame(kind="spheres", seed=76, index=0, size=(600, 960), pile="walls").frame,
              synthesize_raytraced_frame(kind="zinc_nuts", seed=77, index=0, size=(150, 240)).frame]
    for f in frames:
        pixels = bin_pixels(bin_mask(f.rgb), f.xyz)
        for step in (1, 2):
            pts = subsampled_points(f.xyz, pixels, step=step)
            assert len(pts) > 50
            assert_as_before(pts)
            assert_as_before(pts, 0.006)
        holed = f.xyz.copy()
        holed[:, : f.xyz.shape[1] // 2] = np.nan
        assert_as_before(holed.reshape(-1, 3))  # NaN rows: the previous path
        assert_as_before(holed[pixels & np.isfinite(holed).all(axis=2)])


@pytest.mark.skipif(not REAL.is_dir(), reason="no real scans")
def test_real_scans():
    from replay.logs.pcd import read_pcd

    clouds = sorted(REAL.glob("*.pcd"))
    if not clouds:
        pytest.skip("no .pcd scan")
    for path in clouds:
        xyz = read_pcd(path).xyz
        flat = xyz.reshape(-1, 3)
        assert_as_before(flat)  # NaN rows: the previous path
        finite = np.ascontiguousarray(flat[np.isfinite(flat).all(axis=1)])
        assert_as_before(finite)
        assert_as_before(finite, 0.005)


def test_subsampled_points_against_numpy():
    rng = np.random.default_rng(78)
    for t in range(120):
        h, w = int(rng.integers(1, 60)), int(rng.choice([1, 7, 8, 16, 24, 37, 64, 101, 640]))
        xyz = rng.normal(0.0, 1.0, (h, w, 3)).astype(np.float32 if t % 2 else np.float64)
        density = float(rng.choice([0.0, 0.02, 0.15, 0.5, 0.97, 1.0]))
        m = rng.random((h, w)) < density
        if t % 5 == 0:  # runs: whole words set and unset, edges anywhere in a word
            m[:] = False
            for _ in range(int(rng.integers(0, 6))):
                r0, c0 = int(rng.integers(0, h)), int(rng.integers(0, w))
                m[r0:r0 + int(rng.integers(1, 9)), c0:c0 + int(rng.integers(1, 40))] = True
        for step in (1, 2, 3, 4, 5):
            want = xyz[::step, ::step][m[::step, ::step]].astype(np.float64)
            got = subsampled_points(xyz, m, step=step)
            assert got.dtype == np.float64 and got.shape == want.shape and got.tobytes() == want.tobytes()
    big = rng.random((40, 96)) < 0.3
    xyz = rng.normal(0.0, 1.0, (40, 96, 3))
    for m in (big[:, :48], big[:, ::2], big[1:, 8:], np.asfortranarray(big)):  # strided, unaligned, Fortran
        x = np.ascontiguousarray(xyz[: m.shape[0], : m.shape[1]])
        for step in (1, 2, 3):
            want = x[::step, ::step][m[::step, ::step]].astype(np.float64)
            assert subsampled_points(x, m, step=step).tobytes() == want.tobytes()
    for h, w in ((0, 8), (5, 0), (0, 0)):
        assert subsampled_points(np.zeros((h, w, 3)), np.zeros((h, w), bool), step=1).shape == (0, 3)
