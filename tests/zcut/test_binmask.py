"""zcut.binmask: the RGB bin footprint on a ray-cast bin scene with known geometry; the bin pixels
(rim and upper walls) on synthetic scans whose shiny parts are as bright as the bin."""

from __future__ import annotations

import numpy as np
import pipeline_scene as ps
import pytest

from zcut.binmask import BinMaskResult, bin_mask, bin_pixels, fill_holes
from zcut.errors import InputShapeError, ParameterError
from zcut.params import BinMaskParams

filled = pytest.fixture(scope="module")(ps.filled_bin_scene)  # the 240 x 320 filled bin, shifted


def test_bin_mask_is_the_bin_footprint(filled):
    frame, _ = filled
    r = bin_mask(frame.rgb)
    truth_walls = ps.bin_pixels(frame)
    inside = truth_walls | (frame.rgb == np.array(ps.PART, np.uint8)).all(axis=2)
    assert r.found and r.covers_centre
    assert r.mask[inside].all()                       # every bin or part pixel is in the footprint
    table = (frame.rgb == np.array(ps.DARK, np.uint8)).all(axis=2)
    assert (r.mask & table).sum() == 0  # the closing leaves no fringe of table
    assert r.walls[truth_walls].mean() > 0.99 and not (r.walls & ~truth_walls).any()
    assert r.area_px == r.mask.sum()
    y0, x0, y1, x1 = r.bbox_rc
    assert r.mask[y0:y1, x0:x1].sum() == r.area_px


def test_bin_mask_prefers_the_centre_over_a_larger_component():
    rgb = np.zeros((100, 200, 3), np.uint8)
    rgb[:, :60] = 230          # a large bright thing at the left edge (6000 px)
    rgb[30:70, 80:120] = 230   # a bin ring around the centre (1600 px outer) ...
    rgb[35:65, 85:115] = 10    # ... with a dark inside
    r = bin_mask(rgb, params=BinMaskParams(dilate_px=0))
    assert r.covers_centre and r.mask[50, 100] and not r.mask[:, :60].any()
    assert r.area_px == 40 * 40
    r2 = bin_mask(rgb, params=BinMaskParams(dilate_px=0, prefer_centre=False))
    assert r2.mask[:, :60].all() and not r2.mask[50, 100]


def test_bin_mask_without_a_bin_is_empty():
    r = bin_mask(np.full((20, 30, 3), 20, np.uint8))
    assert not r.found and not r.mask.any() and r.area_px == 0 and np.isnan(r.centroid_rc[0])


def test_fill_holes_fills_only_enclosed_background():
    m = np.zeros((7, 7), bool)
    m[1:6, 1:6] = True
    m[3, 3] = False
    m[0:3, 2] = False  # a notch open to the border is not a hole
    f = fill_holes(m)
    assert f[3, 3] and not f[1, 2] and not f[2, 2]
    assert np.array_equal(f, m | (np.arange(7)[:, None] == 3) & (np.arange(7)[None] == 3))


@pytest.mark.parametrize("kw, match", [
    ({"threshold": 300}, "BinMaskParams.threshold"),
    ({"dilate_px": -1}, "BinMaskParams.dilate_px"),
    ({"min_area_frac": 2.0}, "BinMaskParams.min_area_frac"),
    ({"prefer_centre": 1}, "BinMaskParams.prefer_centre"),
])
def test_bin_mask_bad_parameters(kw, match):
    with pytest.raises(ParameterError, match=match):
        bin_mask(np.zeros((4, 4, 3), np.uint8), params=BinMaskParams(**kw))


def test_bin_mask_takes_its_parameters_as_one_object():
    with pytest.raises(ParameterError, match="params must be a BinMaskParams, got dict"):
        bin_mask(np.zeros((4, 4, 3), np.uint8), params={"threshold": 100})  # type: ignore[arg-type]
    with pytest.raises(TypeError):
        bin_mask(np.zeros((4, 4, 3), np.uint8), threshold=100)  # type: ignore[call-arg]


@pytest.mark.parametrize("rgb", [np.zeros((4, 4), np.uint8), np.zeros((4, 4, 3), np.float32)])
def test_bin_mask_bad_image(rgb):
    with pytest.raises(InputShapeError, match="rgb must be"):
        bin_mask(rgb)




# --- bin_pixels: the ring along the footprint's border ----------------------------------------------


def _result(mask: np.ndarray, walls: np.ndarray) -> BinMaskResult:
    rows, cols = np.nonzero(mask)
    bbox = (rows.min(), cols.min(), rows.max() + 1, cols.max() + 1)
    return BinMaskResult(mask, walls, True, int(mask.sum()), 1, (rows.mean(), cols.mean()), bbox, True)


def test_bin_pixels_is_a_ring_of_the_footprint_measured_from_its_border():
    from scipy.ndimage import distance_transform_edt

    h, w = 100, 200
    mask = np.zeros((h, w), bool)
    mask[10:91, 0:151] = True  # cut by the image's left edge: no wall there
    xyz = np.ones((h, w, 3), np.float32)
    xyz[50, 140] = np.nan
    r = _result(mask, mask.copy())
    frac = 0.25
    got = bin_pixels(r, xyz, ring_frac=frac)
    dist = distance_transform_edt(mask)  # the distance to the nearest background pixel of the image
    want = mask & (dist <= frac * dist.max()) & np.isfinite(xyz).all(axis=2)
    differ = got != want
    assert np.abs(dist[differ] - frac * dist.max()).max(initial=0.0) < 1e-3  # float32 ties at most
    assert differ.sum() <= 4
    assert got[12, 75] and got[88, 75] and got[50, 148]          # top, bottom and right borders
    assert not got[50, 0] and not got[50, 75] and not got[50, 140]  # image edge, middle, invalid point
    # a ring narrower than min_ring_px is widened to it
    narrow = bin_pixels(r, xyz, ring_frac=0.01, min_ring_px=12.0)
    assert np.array_equal(narrow, mask & (dist <= 12.0) & np.isfinite(xyz).all(axis=2))
    assert np.array_equal(bin_pixels(r, xyz, ring_frac=frac, min_ring_px=0.0), got)
    # only the bright pixels of the component: a dark pixel of the ring is not bin plastic
    walls = mask.copy()
    walls[12, 75] = False
    assert not bin_pixels(_result(mask, walls), xyz, ring_frac=frac)[12, 75]


def test_bin_pixels_with_the_whole_ring_is_the_bright_component(filled):
    frame, _ = filled
    r = bin_mask(frame.rgb)
    xyz = frame.xyz.copy()
    xyz[::9, ::4] = np.nan
    assert np.array_equal(bin_pixels(r, xyz, ring_frac=1.0), r.walls & np.isfinite(xyz).all(axis=2))
    ring = bin_pixels(r, xyz)
    assert ring.any() and not (ring & ~r.walls).any()


def test_bin_pixels_without_a_bin_or_a_border():
    xyz = np.zeros((20, 30, 3), np.float32)
    assert not bin_pixels(bin_mask(np.full((20, 30, 3), 20, np.uint8)), xyz).any()
    whole = np.ones((20, 30), bool)
    assert bin_pixels(_result(whole, whole), xyz).all()  # the footprint is the image: all of it


def test_bin_pixels_are_bin_and_not_parts_on_a_synthetic_shiny_pile():
    from replay.synth.scene import LABEL_PART, LABEL_RIM
    from replay.synth.synthesize import synthesize_frame

    sf = synthesize_frame(kind="spheres", seed=12, index=0, size=(300, 480))
    f = sf.frame
    r = bin_mask(f.rgb)
    valid = np.isfinite(f.xyz).all(axis=2)
    part = sf.surface == LABEL_PART
    assert part[r.walls & valid].mean() > 0.3  # the shiny spheres are as bright as the bin
    px = bin_pixels(r, f.xyz)
    assert not (px & part).any()
    rim = (sf.surface == LABEL_RIM) & r.walls & valid
    assert px[rim].mean() > 0.97


@pytest.mark.parametrize("xyz, kw, exc, match", [
    (np.zeros((24, 32, 3), np.float32), {}, InputShapeError, r"xyz must be an \(240, 320, 3\) float array"),
    (np.zeros((240, 320), np.float32), {}, InputShapeError, "xyz must be an"),
    (np.zeros((240, 320, 3), np.int32), {}, InputShapeError, "xyz must be an"),
    (np.zeros((240, 320, 3), np.float32), {"ring_frac": 0.0}, ParameterError, "ring_frac"),
    (np.zeros((240, 320, 3), np.float32), {"ring_frac": 1.5}, ParameterError, "ring_frac"),
    (np.zeros((240, 320, 3), np.float32), {"ring_frac": True}, ParameterError, "ring_frac"),
    (np.zeros((240, 320, 3), np.float32), {"ring_frac": "0.2"}, ParameterError, "ring_frac"),
    (np.zeros((240, 320, 3), np.float32), {"min_ring_px": -1.0}, ParameterError, "min_ring_px"),
    (np.zeros((240, 320, 3), np.float32), {"min_ring_px": np.nan}, ParameterError, "min_ring_px"),
    (np.zeros((240, 320, 3), np.float32), {"min_ring_px": True}, ParameterError, "min_ring_px"),
])
def test_bin_pixels_bad_input(filled, xyz, kw, exc, match):
    frame, _ = filled
    with pytest.raises(exc, match=match):
        bin_pixels(bin_mask(frame.rgb), xyz, **kw)
