"""The disagreement blobs' nearest kept pixels, searched in windows around the blobs, are those of the whole
image's Euclidean feature transform: the tie rule the window search relies on, checked against a brute-force
search, and the blobs checked against the literal whole-image version (tests/reference/blobs_reference.py)
over random, tied, sparse, invalid-heavy, degenerate and real frames."""

from __future__ import annotations

import numpy as np
import pytest
from reference.blobs_reference import disagreement_blobs as reference_blobs
from scipy import ndimage

import studies.compare as cmp
from studies.compare import disagreement_blobs
from zcut.cloud import Intrinsics


def _brute_nearest(kept: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every pixel's nearest kept pixel: the smallest squared distance, then the smallest column, then the
    smallest row (the rule ``studies.compare._nearest_kept`` states for SciPy's transform)."""
    kr, kc = np.nonzero(kept)
    h, w = kept.shape
    rr, cc = np.mgrid[0:h, 0:w]
    d2 = (rr.ravel()[:, None] - kr[None, :]) ** 2 + (cc.ravel()[:, None] - kc[None, :]) ** 2
    key = np.lexsort((kr[None, :].repeat(d2.shape[0], 0), kc[None, :].repeat(d2.shape[0], 0), d2), axis=1)[:, 0]
    return kr[key].reshape(h, w), kc[key].reshape(h, w)


def _kept_masks(rng: np.random.Generator):
    """Kept masks of many kinds: random densities, lattices (many exact ties), lines, one pixel, 1 x N."""
    for _ in range(40):
        h, w = int(rng.integers(1, 24)), int(rng.integers(1, 24))
        yield rng.random((h, w)) < rng.choice([0.02, 0.1, 0.5, 0.9])
    for step in (2, 3, 4, 5, 7):
        for h, w in ((17, 23), (20, 20), (1, 31), (31, 1)):
            k = np.zeros((h, w), bool)
            k[::step, ::step] = True
            yield k
            k2 = np.zeros((h, w), bool)
            k2[1::step, ::step + 1] = True
            yield k2
    k = np.zeros((15, 15), bool)
    k[7, 7] = True
    yield k
    k = np.zeros((15, 15), bool)
    k[[0, 14, 0, 14], [0, 0, 14, 14]] = True  # the centre is equally far from all four corners
    yield k


def test_scipy_names_the_nearest_kept_pixel_of_smallest_column_then_row(rng):
    """The rule the window search stands on: among equally near kept pixels SciPy's feature transform
    names the one of the smallest column, then of the smallest row (tested on exact ties: lattices, the
    centre of four corners)."""
    n = 0
    for kept in _kept_masks(rng):
        if not kept.any():
            continue
        ri, ci = ndimage.distance_transform_edt(~kept, return_distances=False, return_indices=True)
        br, bc = _brute_nearest(kept)
        np.testing.assert_array_equal(ri, br)
        np.testing.assert_array_equal(ci, bc)
        n += 1
    assert n > 60


def _same(got, want):
    assert [b.as_dict() for b in got] == [b.as_dict() for b in want]


def _frame(rng, h, w, *, invalid=0.0, block=False):
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float64)
    z = 1.0 + 0.02 * np.sin(rows / 7.0) + 0.01 * rng.standard_normal((h, w))
    xyz = np.dstack([cols * 0.001, rows * 0.001, z]).astype(np.float32)
    if invalid:
        xyz[rng.random((h, w)) < invalid] = np.nan
    if block:  # a large invalid region (a bin wall's shadow)
        xyz[h // 4: 3 * h // 4, : w // 2] = np.nan
    return xyz


def _cases(rng):
    """(mask_a, mask_b, where, xyz, truth) of many kinds."""
    for h, w, pa, pb, invalid, block in ((60, 80, 0.02, 0.03, 0.0, False), (60, 80, 0.2, 0.2, 0.1, False),
                                         (90, 70, 0.005, 0.0, 0.3, True), (1, 200, 0.1, 0.1, 0.0, False),
                                         (200, 1, 0.1, 0.05, 0.2, False), (40, 40, 0.45, 0.45, 0.0, False),
                                         (300, 400, 0.001, 0.002, 0.05, True)):
        xyz = _frame(rng, h, w, invalid=invalid, block=block)
        valid = np.isfinite(xyz).all(axis=2)
        a = (rng.random((h, w)) < pa) & valid
        b = (rng.random((h, w)) < pb) & valid
        where = valid & (rng.random((h, w)) < 0.97)
        lab = rng.random((h, w)) < 0.05
        yield a, b, where, xyz, (lab, where)
    # blobs far from anything kept: the window must grow (kept only in one corner)
    h, w = 120, 160
    xyz = _frame(rng, h, w)
    a = np.zeros((h, w), bool)
    a[60:64, 100:103] = True
    b = np.zeros((h, w), bool)
    b[5:7, 150:152] = True
    where = np.zeros((h, w), bool)
    where[:3, :3] = True
    where |= a | b
    yield a, b, where, xyz, None
    # nothing kept at all, and a frame without disagreement
    yield a, b, a | b, xyz, None
    yield a, a, np.ones((h, w), bool), xyz, None
    # exact ties: kept pixels on a lattice around one-pixel blobs
    where = np.ones((h, w), bool)
    a = np.ones((h, w), bool)
    a[::4, ::4] = False
    yield a, np.zeros((h, w), bool), where, xyz, None


@pytest.mark.parametrize("tile, margin", [(128, 8), (8, 1), (3, 0)])
def test_blobs_equal_those_of_the_whole_image_transform(rng, monkeypatch, tile, margin):
    """Every blob (height above the nearest kept pixel, distance to it, the rest) is the literal version's,
    to the bit, with the shipped windows and with tiny ones that must grow and overlap."""
    monkeypatch.setattr(cmp, "_TILE_PX", tile)
    monkeypatch.setattr(cmp, "_MARGIN_PX", margin)
    n = 0
    for a, b, where, xyz, truth in _cases(rng):
        k = Intrinsics(fx=600.0, fy=610.0, cx=1.0, cy=2.0, width=xyz.shape[1], height=xyz.shape[0])
        fp = cmp.pixel_footprint_mm2(xyz, k)  # NaN where invalid
        got = disagreement_blobs("l", 3, 7, a, b, where, truth=truth, footprint=fp, xyz=xyz)
        _same(got, reference_blobs("l", 3, 7, a, b, where, truth=truth, footprint=fp, xyz=xyz))
        # the footprint computed at the blobs' pixels alone (as compare does): the same areas, to the bit
        assert disagreement_blobs("l", 3, 7, a, b, where, truth=truth, intrinsics=k, xyz=xyz) == got
        n += len(got)
    assert n > 1000


def test_blobs_of_real_scans_equal_the_whole_image_transform(real_data, monkeypatch):
    """Real organized scans (their own invalid regions): the blobs of the z-cut at two ρ_thr."""
    from replay.logs.pcd import read_pcd
    from zcut import zcut_outliers

    for name in ("mosd_test16.pcd", "table_scene_mug_stereo_textured.pcd"):
        xyz = read_pcd(real_data / name).xyz
        valid = np.isfinite(xyz).all(axis=2)
        height = -1000.0 * xyz[..., 2].astype(np.float64)
        a = zcut_outliers(height, step=0.2, max_depth=30.0, max_area=400)
        b = zcut_outliers(height, step=0.2, max_depth=30.0, max_area=100)
        c = zcut_outliers(height, step=0.5, max_depth=10.0, max_area=2000)
        for tile, margin in ((128, 8), (16, 2)):
            monkeypatch.setattr(cmp, "_TILE_PX", tile)
            monkeypatch.setattr(cmp, "_MARGIN_PX", margin)
            for ma, mb in ((a, b), (b, c), (a, c)):
                got = disagreement_blobs("l", 0, 0, ma, mb, valid, xyz=xyz)
                assert got, name
                _same(got, reference_blobs("l", 0, 0, ma, mb, valid, xyz=xyz))


def test_pixel_footprint_is_the_literal_formula_to_the_bit(rng):
    """z² / (fx·fy) in mm², computed in place: the literal formula's bits (NaN where invalid); None without
    a camera model or for another image size."""
    xyz = _frame(rng, 50, 70, invalid=0.2, block=True)
    k = Intrinsics(fx=1234.567, fy=1235.891, cx=35.0, cy=25.0, width=70, height=50)
    z_mm = 1000.0 * xyz[..., 2].astype(np.float64)
    want = z_mm * z_mm / (float(k.fx) * float(k.fy))
    got = cmp.pixel_footprint_mm2(xyz, k)
    assert got is not None and np.array_equal(got.view(np.int64), want.view(np.int64))
    assert cmp.pixel_footprint_mm2(xyz, None) is None
    assert cmp.pixel_footprint_mm2(xyz[:, :60], k) is None
