"""replay.synth sensor: geometry of the rendered cloud, projector shadows, noise, colours."""

from __future__ import annotations

import numpy as np
import pytest

from replay.synth import (
    BIN,
    CAMERA_HEIGHT_MM,
    LABEL_FLOOR,
    LABEL_PART,
    LABEL_RIM,
    LABEL_TABLE,
    LABEL_WALL,
    default_intrinsics,
    synthesize_frame,
)
from replay.synth.scene import BinPose, empty_scene, make_grid
from replay.synth.sensor import (
    NOISE_CORRELATION_PX,
    NOISE_MM_AT_500,
    correlated_noise,
    measurable,
    render,
    view_half_extent_mm,
)
from zcut.binmask import bin_mask
from zcut.params import BinMaskParams

SIZE = (240, 320)


@pytest.fixture(scope="module")
def spheres():
    return synthesize_frame(kind="spheres", seed=4, size=SIZE)


def test_intrinsics_keep_the_field_of_view():
    full = default_intrinsics()
    small = default_intrinsics(SIZE)
    assert (full.width, full.height) == (1920, 1200)
    assert (small.width, small.height) == (320, 240)
    assert full.fx / full.width == pytest.approx(small.fx / small.width)
    assert (small.cx, small.cy) == (159.5, 119.5)


def test_points_project_back_onto_their_pixels(spheres):
    """Every point, outliers included, lies on its pixel's ray: K @ xyz gives (col, row) back."""
    xyz = spheres.frame.xyz.astype(np.float64)
    K = spheres.frame.intrinsics.K
    ok = np.isfinite(xyz).all(axis=2)
    assert ok.mean() > 0.6
    rows, cols = np.nonzero(ok)
    p = xyz[ok] @ K.T
    np.testing.assert_allclose(p[:, 0] / p[:, 2], cols, atol=1e-3)
    np.testing.assert_allclose(p[:, 1] / p[:, 2], rows, atol=1e-3)
    # from the points above the rim (at most 150 mm higher: 0.31 m from the camera) to the table
    assert (xyz[ok][:, 2] > 0.3).all() and (xyz[ok][:, 2] < 0.6).all()


def test_surfaces_lie_where_the_scene_puts_them(spheres):
    """Inliers of the table and the bin floor sit at their known depths (within the noise)."""
    z_mm = 1000.0 * spheres.frame.xyz[..., 2].astype(np.float64)
    ok = np.isfinite(z_mm) & ~spheres.truth
    sigma = NOISE_MM_AT_500 * (CAMERA_HEIGHT_MM / 500.0) ** 2
    table = ok & (spheres.surface == LABEL_TABLE)
    floor = ok & (spheres.surface == LABEL_FLOOR)
    rim = ok & (spheres.surface == LABEL_RIM)
    assert table.sum() > 1000 and rim.sum() > 100
    assert np.abs(z_mm[table] - CAMERA_HEIGHT_MM).max() < 6 * sigma
    if floor.any():
        assert np.abs(z_mm[floor] - (CAMERA_HEIGHT_MM - BIN.floor_mm)).max() < 6 * sigma
    # (rim-labelled pixels also include the bin's outer wall seen at the image border)
    assert np.mean(np.abs(z_mm[rim] - (CAMERA_HEIGHT_MM - BIN.height_mm)) < 6 * sigma) > 0.9
    # noise of realistic size (Zivid-like: ~0.1 mm at 0.5 m)
    resid = z_mm[table] - CAMERA_HEIGHT_MM
    assert 0.7 * sigma < resid.std() < 1.3 * sigma
    # parts are between the floor and the rim
    part = ok & (spheres.surface == LABEL_PART)
    assert (z_mm[part] > CAMERA_HEIGHT_MM - BIN.height_mm).all()
    assert (z_mm[part] < CAMERA_HEIGHT_MM - BIN.floor_mm).all()


def test_depth_noise_is_smooth_like_a_filtered_sensor(spheres):
    """The noise of neighbouring pixels is correlated (a Gaussian of NOISE_CORRELATION_PX pixels):
    on the flat table, next-pixel residuals correlate at exp(-1 / (4 s²)) ≈ 0.9 for s = 1.5."""
    z_mm = 1000.0 * spheres.frame.xyz[..., 2].astype(np.float64)
    resid = np.where((spheres.surface == LABEL_TABLE) & ~spheres.truth, z_mm - CAMERA_HEIGHT_MM, np.nan)
    a, b = resid[:, :-1], resid[:, 1:]
    ok = np.isfinite(a) & np.isfinite(b)
    assert ok.sum() > 1000
    rho = np.corrcoef(a[ok], b[ok])[0, 1]
    assert rho == pytest.approx(np.exp(-1.0 / (4.0 * NOISE_CORRELATION_PX**2)), abs=0.08)


def test_correlated_noise_has_unit_variance():
    rng = np.random.default_rng(1)
    n = correlated_noise((400, 600), rng)
    assert n.dtype == np.float32
    assert n.std() == pytest.approx(1.0, abs=0.03) and abs(n.mean()) < 0.05
    assert np.corrcoef(n[:, :-1].ravel(), n[:, 1:].ravel())[0, 1] == pytest.approx(np.exp(-1 / 9), abs=0.02)
    white = correlated_noise((400, 600), rng, sigma_px=0.0)
    assert abs(np.corrcoef(white[:, :-1].ravel(), white[:, 1:].ravel())[0, 1]) < 0.02


def test_render_depth_is_exact_for_a_plane():
    """The empty table and bin rendered without noise: the table at exactly the camera height."""
    K = default_intrinsics((60, 80))
    hx, hy = view_half_extent_mm(K)
    scene = empty_scene(make_grid(half_x_mm=hx + 5, half_y_mm=hy + 5, step_mm=1.0), BinPose())
    view = render(scene, K)
    assert np.isfinite(view.depth_mm).all()
    table = view.label == LABEL_TABLE
    np.testing.assert_allclose(view.depth_mm[table], CAMERA_HEIGHT_MM, rtol=0, atol=1e-9)
    floor = view.label == LABEL_FLOOR
    np.testing.assert_allclose(view.depth_mm[floor], CAMERA_HEIGHT_MM - BIN.floor_mm, atol=1e-9)
    np.testing.assert_allclose(view.normal[table], np.broadcast_to([0, 0, -1.0], (table.sum(), 3)), atol=1e-12)


def test_projector_shadow_falls_away_from_the_projector():
    """The projector sits at +x: the bin shades the table on its -x side, not on its +x side."""
    K = default_intrinsics(SIZE)
    hx, hy = view_half_extent_mm(K)
    scene = empty_scene(make_grid(half_x_mm=hx + 5, half_y_mm=hy + 5, step_mm=1.0), BinPose())
    view = render(scene, K)
    ok = measurable(scene, view, K)
    rows = slice(int(K.cy) - 20, int(K.cy) + 20)

    def cols(x0_mm, x1_mm):
        return slice(int(K.cx + K.fx * x0_mm / CAMERA_HEIGHT_MM), int(K.cx + K.fx * x1_mm / CAMERA_HEIGHT_MM))

    # the camera (at x = 0) sees the table beyond x = +-(200 + 120 * 200 / 460) = +-252 mm; the
    # projector (x = +150) throws the rim's shadow to x = -200 - 120 * 350 / 460 = -291 mm
    assert (view.label[rows, cols(-285, -258)] == LABEL_TABLE).all()
    assert not ok[rows, cols(-285, -258)].any()  # shadowed strip of table
    assert ok[rows, cols(258, 290)].all()  # lit table on the projector's side
    assert ok[rows, : cols(-300, 0).start].all()  # beyond the shadow
    # the flat floor is lit
    floor = view.label == LABEL_FLOOR
    assert ok[floor].mean() > 0.9
    # steep drafted walls facing away from the projector are too oblique
    walls = view.label == LABEL_WALL
    assert 0.05 < ok[walls].mean() < 0.95


def test_rgb_bin_mask_gives_the_bin_footprint(spheres):
    """Paper §5.1: gray > threshold, dilate, component, fill holes -> exactly the bin's footprint."""
    res = bin_mask(spheres.frame.rgb, params=BinMaskParams(threshold=150.0, dilate_px=3))
    truth = (spheres.surface != LABEL_TABLE) & (spheres.surface != 0)
    iou = (res.mask & truth).sum() / (res.mask | truth).sum()
    assert iou > 0.98
    gray = spheres.frame.rgb.astype(np.float64) @ [0.299, 0.587, 0.114]
    assert np.percentile(gray[spheres.surface == LABEL_TABLE], 99) < 80
    bin_px = np.isin(spheres.surface, [LABEL_FLOOR, LABEL_WALL, LABEL_RIM])
    assert np.percentile(gray[bin_px], 1) > 150


def test_matte_black_parts_are_dark():
    sf = synthesize_frame(kind="black_screws", seed=1, size=SIZE)
    gray = sf.frame.rgb.astype(np.float64) @ [0.299, 0.587, 0.114]
    assert np.median(gray[sf.surface == LABEL_PART]) < 60
    res = bin_mask(sf.frame.rgb)
    truth = (sf.surface != LABEL_TABLE) & (sf.surface != 0)
    assert (res.mask & truth).sum() / (res.mask | truth).sum() > 0.98
