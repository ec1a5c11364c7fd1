"""The seed check of branch h/px3: ``zcut.registration.pose_fitness_at_least`` (the rim counted only until the
answer is decided) against ``pose_fitness(...) >= fitness``, the comparison the pipeline made before.

The thresholds asked are every bin fitness a count can give at a pose (k / n for every k), the doubles either side
of each, and the ends (0, 1, above 1, negative, NaN, infinities): the answer must be the comparison's on each.
Poses: the registered one, and ones turned and shifted so that a third, half or all of the rim goes unconfirmed.
"""

from __future__ import annotations

import math

import numpy as np
import pipeline_scene as ps
import pytest

from zcut.binmask import bin_mask, bin_pixels
from zcut.params import RegistrationParams
from zcut.registration import (
    _least_count,
    _rim_fitness,
    pose_fitness,
    pose_fitness_at_least,
    prepare_icp_model,
    prepare_target,
    register_bin,
)

filled = pytest.fixture(scope="module")(ps.filled_bin_scene)
model = pytest.fixture(scope="module")(ps.shifted_bin_model)


def _thresholds(n: int, rng: np.random.Generator) -> list[float]:
    """Bin fitnesses a count of n rim points gives (k / n), the doubles beside them, and the ends."""
    ks = sorted({0, 1, n // 3, n // 2, (9 * n) // 10, n - 1, n, *rng.integers(0, n + 1, 12).tolist()})
    out = [-math.inf, -1.0, -0.0, 0.0, 1.0, math.nextafter(1.0, 2.0), 1.5, math.inf, math.nan]
    for k in ks:
        v = k / n
        out += [v, math.nextafter(v, -1.0), math.nextafter(v, 2.0), 0.9 * v]
    return out


def test_the_least_count_is_the_comparisons():
    """``_least_count(n, f)`` is the least k with ``float(k) / n >= f`` (n + 1 when none), for every k's
    fitness and the doubles beside it."""
    rng = np.random.default_rng(3201)
    for n in (1, 2, 3, 7, 10, 49, 100, 2418, 65537, *rng.integers(1, 5000, 20).tolist()):
        for f in _thresholds(int(n), rng):
            want = next((k for k in range(n + 1) if float(k) / n >= f), n + 1)
            assert _least_count(int(n), f) == want, (n, f)


@pytest.mark.parametrize("intrinsics", [True, False], ids=["in view", "no camera model"])
def test_the_early_answer_is_the_full_counts(filled, model, intrinsics):
    """At the registered pose and at poses moved off it (a part, half or all of the rim unconfirmed), for every
    threshold a count can give and those beside it: the same answer as the full count's comparison."""
    frame, _ = filled
    params = RegistrationParams(voxel_mm=1.0)
    m = prepare_icp_model(model, params)
    pixels = bin_pixels(bin_mask(frame.rgb), frame.xyz)
    K = frame.intrinsics if intrinsics else None
    target = prepare_target(frame.xyz[pixels], voxel_m=params.voxel_m, intrinsics=K)
    T_reg = register_bin(m, target).T_cam_bin
    rng = np.random.default_rng(3202)
    poses = [T_reg, T_reg @ ps.turned_pose((0.0, 0.0, 2.0), (0.0, 0.0, 0.0)),
             T_reg @ ps.turned_pose((0.0, 0.0, 0.0), (0.01, 0.0, 0.0)),
             T_reg @ ps.turned_pose((0.0, 0.0, 0.0), (0.05, 0.0, 0.0)),
             T_reg @ ps.turned_pose((0.0, 0.0, 0.0), (1.0, 1.0, 0.0))]
    poses += [T_reg @ ps.turned_pose(rng.normal(0.0, 1.0, 3), rng.normal(0.0, 0.004, 3)) for _ in range(4)]
    seen = set()
    for T in poses:
        for dist in (params.fine_correspondence_m, 0.001):
            f = pose_fitness(m, target, T, max_correspondence_m=dist)
            seen.add(round(f, 1))
            n = max(1, _rim_fitness(m, target, T, dist)[1])  # the thresholds k / n of the rim scored, and f's own
            for want in [*_thresholds(n, rng), f, math.nextafter(f, 2.0), math.nextafter(f, -1.0)]:
                got = pose_fitness_at_least(m, target, T, max_correspondence_m=dist, fitness=want)
                assert got is (f >= want), (f, want)
    assert len(seen) >= 3  # poses that confirm all, some and none of the rim


def test_degenerate_targets_and_rims(filled, model):
    """No target point, no rim point in view, a bad pose: as ``pose_fitness`` (0 there), and its error."""
    frame, _ = filled
    params = RegistrationParams(voxel_mm=1.0)
    m = prepare_icp_model(model, params)
    pixels = bin_pixels(bin_mask(frame.rgb), frame.xyz)
    empty = prepare_target(np.zeros((0, 3)), voxel_m=params.voxel_m, intrinsics=frame.intrinsics)
    target = prepare_target(frame.xyz[pixels], voxel_m=params.voxel_m, intrinsics=frame.intrinsics)
    behind = np.eye(4)
    behind[2, 3] = -5.0  # the whole rim behind the camera: none in view
    T = register_bin(m, target).T_cam_bin
    for tgt, pose in ((empty, T), (target, behind)):
        f = pose_fitness(m, tgt, pose, max_correspondence_m=0.003)
        assert f == 0.0
        for want in (-1.0, 0.0, 1e-300, 0.5, 1.0, math.nan):
            assert pose_fitness_at_least(m, tgt, pose, max_correspondence_m=0.003, fitness=want) is (f >= want)
    with pytest.raises(ValueError, match="T_cam_bin"):
        pose_fitness_at_least(m, target, np.eye(3), max_correspondence_m=0.003, fitness=0.5)
    bad = T.copy()
    bad[0, 3] = np.nan
    with pytest.raises(ValueError, match="finite"):
        pose_fitness_at_least(m, target, bad, max_correspondence_m=0.003, fitness=0.5)


def test_the_kept_grid_is_the_one_the_final_fitness_reads(filled, model):
    """The seed check builds the target's cell grid as ``pose_fitness`` does, and keeps it: the registration's
    fitness after it is the same as on a fresh target."""
    frame, _ = filled
    params = RegistrationParams(voxel_mm=1.0)
    m = prepare_icp_model(model, params)
    pixels = bin_pixels(bin_mask(frame.rgb), frame.xyz)
    checked = prepare_target(frame.xyz[pixels], voxel_m=params.voxel_m, intrinsics=frame.intrinsics)
    fresh = prepare_target(frame.xyz[pixels], voxel_m=params.voxel_m, intrinsics=frame.intrinsics)
    T = register_bin(m, fresh).T_cam_bin
    pose_fitness_at_least(m, checked, T, max_correspondence_m=params.fine_correspondence_m, fitness=0.9)
    assert checked._cells is not None
    a, b = register_bin(m, checked, init=T, coarse=False), register_bin(m, fresh, init=T, coarse=False)
    assert a.fitness == b.fitness and a.n_rim == b.n_rim and np.array_equal(a.T_cam_bin, b.T_cam_bin)
