"""replay.synth outliers: exact ground truth, Figure-11 traps, shiny vs matte, the paper's headline."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from replay.synth import (
    LABEL_FLOOR,
    LABEL_PART,
    OUTLIER_CLUSTER,
    OUTLIER_FLYING,
    OUTLIER_SPIKE,
    PART_KINDS,
    synthesize_frame,
)
from replay.synth.outliers import blob
from replay.synth.sensor import depth_noise_sigma_mm
from zcut.cuts import zcut_outliers
from zcut.sor import sor_outliers

SIZE = (240, 320)
EIGHT = np.ones((3, 3), bool)


@pytest.fixture(scope="module", params=sorted(PART_KINDS) + ["empty"])
def frame(request):
    if request.param == "empty":
        return synthesize_frame(empty=True, seed=3, index=2, size=SIZE)
    return synthesize_frame(kind=request.param, seed=3, size=SIZE)


def test_every_true_outlier_is_a_valid_point(frame):
    valid = np.isfinite(frame.frame.xyz).all(axis=2)
    assert not (frame.truth & ~valid).any()
    assert (frame.frame.masks["/ground_truth/outliers"] == frame.truth).all()
    assert ((frame.outlier_kind > 0) == frame.truth).all()
    assert ((frame.cluster_id > 0) == (frame.outlier_kind == OUTLIER_CLUSTER)).all()


def test_truth_is_exactly_the_points_off_their_surface(frame):
    """Inliers are on the real surface within the noise; every outlier is clearly off it."""
    z = 1000.0 * frame.frame.xyz[..., 2].astype(np.float64)
    surf = frame.surface_depth_mm.astype(np.float64)
    valid = np.isfinite(z)
    err = z - surf
    sigma = depth_noise_sigma_mm(surf, shiny=True)  # the larger of the two finishes
    inl = valid & ~frame.truth
    assert (np.abs(err[inl]) < 6 * sigma[inl] + 1e-3).all()
    clusters = frame.outlier_kind == OUTLIER_CLUSTER
    spikes = frame.outlier_kind == OUTLIER_SPIKE
    flying = frame.outlier_kind == OUTLIER_FLYING
    assert (err[clusters] < -0.5).all()  # ghosts float toward the camera
    assert (np.abs(err[spikes]) > 0.5).all()
    assert (err[flying] < -0.5).all()  # mixed pixels lie between the foreground and this background


def test_figure11_patches_are_real_and_fenced_by_nan():
    sf = synthesize_frame(kind="rods", seed=8, size=SIZE)
    valid = np.isfinite(sf.frame.xyz).all(axis=2)
    assert sf.figure11.any()
    assert not (sf.figure11 & sf.truth).any()
    assert (valid[sf.figure11]).all()
    assert (sf.surface[sf.figure11] == LABEL_PART).all()
    labels, n = ndimage.label(valid, structure=EIGHT)
    patch_labels = np.unique(labels[sf.figure11])
    # each 8-connected component of valid pixels holding a patch is nothing but patch
    for lab in patch_labels:
        comp = labels == lab
        assert (sf.figure11[comp]).all()
    # and it is fully surrounded by NaN
    ring = ndimage.binary_dilation(sf.figure11, EIGHT) & ~sf.figure11
    assert not valid[ring].any()


def test_matte_parts_have_far_fewer_outliers():
    shiny = [synthesize_frame(kind="zinc_nuts", seed=1, size=SIZE).truth.sum()]
    matte = [synthesize_frame(kind="black_nuts", seed=1, size=SIZE).truth.sum()]
    assert sum(matte) < 0.3 * sum(shiny)
    forced = synthesize_frame(kind="zinc_nuts", seed=1, size=SIZE, shiny=False)
    assert not forced.shiny
    assert forced.truth.sum() < 0.3 * shiny[0]
    assert synthesize_frame(kind="black_nuts", seed=1, size=SIZE, shiny=True).truth.sum() > 2 * matte[0]


def test_shiny_clusters_span_a_few_to_hundreds_of_pixels():
    sf = synthesize_frame(kind="rods", seed=6, size=(600, 960))
    areas = np.bincount(sf.cluster_id.ravel())[1:]
    areas = areas[areas > 0]
    assert len(areas) >= 30
    assert areas.min() < 10 and areas.max() >= 100
    # clusters do not touch each other: each is its own 8-connected component of ghosts
    labels, n = ndimage.label(sf.cluster_id > 0, structure=EIGHT)
    assert n == len(areas)
    # most touch real surface in the image yet float above all of it by more than two z-cut steps
    height = -1000.0 * sf.frame.xyz[..., 2].astype(np.float64)
    real = np.isfinite(height) & ~sf.truth
    floating = 0
    for i in np.unique(sf.cluster_id[sf.cluster_id > 0]):
        m = sf.cluster_id == i
        ring = ndimage.binary_dilation(m, EIGHT) & ~m & real
        if ring.any() and height[m].min() - height[ring].max() > 0.4:
            floating += 1
    assert floating >= 0.7 * len(areas)


def test_deterministic_for_a_seed():
    a = synthesize_frame(kind="sprockets", seed=12, index=1, size=(120, 160))
    b = synthesize_frame(kind="sprockets", seed=12, index=1, size=(120, 160))
    c = synthesize_frame(kind="sprockets", seed=13, index=1, size=(120, 160))
    d = synthesize_frame(kind="sprockets", seed=12, index=2, size=(120, 160))
    assert a.frame.xyz.tobytes() == b.frame.xyz.tobytes()
    assert a.frame.rgb.tobytes() == b.frame.rgb.tobytes()
    assert (a.truth == b.truth).all() and a.frame.stamp_ns == b.frame.stamp_ns
    for other in (c, d):
        assert a.frame.xyz.tobytes() != other.frame.xyz.tobytes()
        assert (a.truth != other.truth).any()
    assert d.frame.stamp_ns > a.frame.stamp_ns


def test_blob_area_and_centre():
    rng = np.random.default_rng(0)
    areas = []
    for _ in range(200):
        rows, cols, m = blob((400, 400), (200, 200), 300.0, rng)
        assert m[200 - rows.start, 200 - cols.start]
        areas.append(m.sum())
    assert 0.8 * 300 < np.mean(areas) < 1.2 * 300
    rows, cols, m = blob((10, 10), (0, 9), 50.0, rng)  # clipped at the image corner
    assert m.shape == (rows.stop - rows.start, cols.stop - cols.start) and m[0, -1]


def _bin_removed(sf):
    """Paper §5.2 stand-in: only the parts and the bin floor go to the filters."""
    xyz = sf.frame.xyz.copy()
    roi = (sf.surface == LABEL_PART) | (sf.surface == LABEL_FLOOR)
    xyz[~roi] = np.nan
    return xyz, roi


@pytest.mark.parametrize("kind, seed", [("rods", 0), ("spheres", 1), ("sprockets", 2), ("zinc_nuts", 3)])
def test_zcut_finds_most_floating_clusters_sor_few(kind, seed):
    """The paper's headline as true recall: nominal z-cut (0.2 mm, 30 mm, rho 0.07) vs SOR (k=4, 1 sd)."""
    sf = synthesize_frame(kind=kind, seed=seed, size=(600, 960))
    xyz, roi = _bin_removed(sf)
    height = -1000.0 * xyz[..., 2].astype(np.float64)
    zc = zcut_outliers(height, step=0.2, max_depth=30.0, max_area=0.07 * sf.a_max_px)
    so = sor_outliers(xyz, k=4, std_ratio=1.0)
    cid = np.where(roi, sf.cluster_id, 0)
    ids = np.unique(cid[cid > 0])
    assert len(ids) >= 20

    def found(pred):
        area = np.bincount(cid.ravel(), minlength=cid.max() + 1)
        hit = np.bincount(cid.ravel(), weights=pred.ravel(), minlength=cid.max() + 1)
        return np.mean(hit[ids] >= 0.5 * area[ids])

    ghosts = cid > 0
    zc_pix = (zc & ghosts).sum() / ghosts.sum()
    so_pix = (so & ghosts).sum() / ghosts.sum()
    assert found(zc) >= 0.75  # most clusters (by count) at least half found
    assert zc_pix >= 0.6
    assert found(so) <= 0.5 and so_pix <= 0.2
    assert zc_pix > 3 * so_pix
    # the z-cut is precise on shiny scenes: most of what it flags is a true outlier
    assert (zc & sf.truth).sum() >= 0.3 * zc.sum()
