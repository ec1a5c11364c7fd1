"""zcut.fits, round of 2026-12-06c (docs/fits.md, "Sixteenth round"): three NumPy steps walked by numba kernels —
the segmentation's connected components (a union-find for SciPy's sparse graph), a region's occluding boundary and
the window's zone pixels outside a region — give the NumPy steps' answers exactly, on random grids and the nasty
ones (empty, one pixel, 1 × N, N × 1, NaN holes, regions at the borders). The fits they make are the previous
tree's to the bit: test_fits_defaults.py's literal digests."""

from __future__ import annotations

import numpy as np
import pytest
from fit_scenes import K_TEST, same_regions, segment_cloud
from prepared_models import prepared

import zcut.fits.fit as F
from zcut.fits.segment import segment, segment_reference


@pytest.mark.parametrize("shape", [(1, 1), (1, 37), (29, 1), (2, 2), (17, 23), (40, 64)])
def test_the_segmentation_is_scipys_components_in_scipys_order(shape):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(sum(shape))
    H, W = shape
    for trial in range(60):
        xyz = segment_cloud(rng, H, W, (0.0, 0.1, 0.5)[trial % 3])
        valid = np.isfinite(xyz).all(axis=2)
        flat = np.flatnonzero(valid.reshape(-1) & (rng.random(H * W) < rng.uniform(0.3, 1.0)))
        for min_px in (1, 4, 40):
            kw = dict(f_px=500.0, jump_mm=(1.5, 0.5)[trial % 2], jump_px=3.0, min_px=min_px)
            assert same_regions(segment(xyz, flat, **kw), segment_reference(xyz, flat, **kw))


def test_the_segmentation_of_degenerate_input():
    xyz = np.full((5, 6, 3), np.nan)
    kw = dict(f_px=500.0, jump_mm=1.5, jump_px=3.0, min_px=1)
    assert segment(xyz, np.zeros(0, np.int64), **kw) == [] == segment_reference(xyz, np.zeros(0, np.int64), **kw)
    xyz[2, 3] = (0.0, 0.0, 300.0)
    one = segment(xyz, np.array([15]), **kw)
    assert same_regions(one, segment_reference(xyz, np.array([15]), **kw)) and same_regions(one, [np.array([15])])
    assert segment(np.zeros((0, 4, 3)), np.zeros(0, np.int64), **kw) == []
    # float32 clouds go the reference's way (its arithmetic is float32's)
    rng = np.random.default_rng(3)
    x32 = segment_cloud(rng, 20, 30, 0.1).astype(np.float32)
    flat = np.flatnonzero(np.isfinite(x32).all(axis=2))
    assert same_regions(segment(x32, flat, **kw), segment_reference(x32, flat, **kw))


def test_the_occluding_boundary_and_the_window_pixels_are_numpys():
    rng = np.random.default_rng(12)
    for H, W in ((1, 1), (1, 30), (30, 1), (40, 56)):
        xyz = segment_cloud(rng, H, W, 0.1)
        valid = np.isfinite(xyz).all(axis=2)
        zone = valid & (rng.random((H, W)) < 0.8)
        frame = F._Frame(xyz=xyz, valid=valid, zone=zone, K=K_TEST)
        for trial in range(100):
            r0, c0 = int(rng.integers(0, H)), int(rng.integers(0, W))
            r1, c1 = int(rng.integers(r0, H)) + 1, int(rng.integers(c0, W)) + 1
            box = np.zeros((H, W), bool)
            box[r0:r1, c0:c1] = rng.random((r1 - r0, c1 - c0)) < (0.5 if trial % 2 else 1.0)
            flat = np.flatnonzero(box.reshape(-1) & zone.reshape(-1))
            for jump in (0.5, 1.5):
                assert np.array_equal(F._occluding_boundary(frame, flat, jump),
                                      F._occluding_boundary_reference(frame, flat, jump))
            # a pose whose window lands anywhere (or off the image): the window's zone pixels less the region's
            T = np.eye(4)
            T[:3, 3] = (rng.normal(0, 20), rng.normal(0, 20), rng.uniform(-10, 400))
            model = _Model(extent_mm=float(rng.uniform(1, 30)))
            ref = F._window_flat_reference(frame, T, model)  # type: ignore[arg-type]
            assert np.array_equal(F._window_flat(frame, T, model), ref)  # type: ignore[arg-type]
            assert np.array_equal(F._window_flat(frame, T, model, outside=flat),  # type: ignore[arg-type]
                                  ref[~np.isin(ref, flat, assume_unique=True)])
            shuffled = rng.permutation(flat)  # not ascending: the same answer
            assert np.array_equal(F._window_flat(frame, T, model, outside=shuffled),  # type: ignore[arg-type]
                                  ref[~np.isin(ref, flat, assume_unique=True)])


class _Model:
    """What :func:`zcut.fits.fit._window` reads of a part model."""

    def __init__(self, extent_mm: float) -> None:
        self.extent_mm = extent_mm
        self.centroid = np.zeros(3)


def test_the_guesses_as_arrays_are_the_poses_of_initial_poses_and_shifted_poses():
    """``guess_translations`` and ``shifted_guesses`` (the search's guesses without a 4 × 4 matrix each) give the
    rotations and translations of ``initial_poses`` and ``shifted_poses`` to the bit, on regions of a nut's and
    a rod-like box's points seen from many poses."""
    from fit_scenes import hex_nut_mesh

    from zcut.fits.icp import guess_translations, initial_poses, initial_rotations, shifted_guesses, shifted_poses

    rng = np.random.default_rng(29)
    v, t = hex_nut_mesh()
    box_v = np.array([[x, y, z] for x in (0, 40) for y in (0, 6) for z in (0, 6)], float)
    box_t = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                      [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    for model in (prepared(v, t), prepared(box_v, box_t)):
        for _ in range(40):
            pts = rng.normal(0, 1, (int(rng.integers(5, 400)), 3)) * rng.uniform(0.5, 12, 3) + (
                rng.normal(0, 40), rng.normal(0, 40), rng.uniform(200, 600))
            rotations = initial_rotations(pts, model)
            Rs = np.stack(rotations)
            ref = np.stack(initial_poses(pts, rotations, model))
            assert np.array_equal(guess_translations(pts, Rs, model), ref[:, :3, 3])
            for n in (0, 1, 4):
                Rsh, tsh = shifted_guesses(pts, Rs, model, n)
                poses = shifted_poses(pts, rotations, model, n)
                assert len(Rsh) == len(tsh) == len(poses)
                if poses:
                    ref = np.stack(poses)
                    assert np.array_equal(Rsh, ref[:, :3, :3]) and np.array_equal(tsh, ref[:, :3, 3])
