"""zcut.binmask: the RGB bin footprint on a ray-cast bin scene with known geometry."""

from __future__ import annotations

import numpy as np
import pipeline_scene as ps
import pytest

from zcut.binmask import bin_mask, fill_holes
from zcut.errors import InputShapeError, ParameterError

H, W = 240, 320
SHIFT = (0.006, -0.004, 0.003)


@pytest.fixture(scope="module")
def filled():
    return ps.scene(h=H, w=W, shift=SHIFT, specks=12, seed=3)


def _bin_pixels(frame) -> np.ndarray:
    return (frame.rgb == np.array(ps.BRIGHT, np.uint8)).all(axis=2)


def test_bin_mask_is_the_bin_footprint(filled):
    frame, _ = filled
    r = bin_mask(frame.rgb)
    truth_walls = _bin_pixels(frame)
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
    r = bin_mask(rgb, dilate_px=0)
    assert r.covers_centre and r.mask[50, 100] and not r.mask[:, :60].any()
    assert r.area_px == 40 * 40
    r2 = bin_mask(rgb, dilate_px=0, prefer_centre=False)
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
    ({"threshold": 300}, "threshold"),
    ({"dilate_px": -1}, "dilate_px"),
    ({"min_area_frac": 2.0}, "min_area_frac"),
])
def test_bin_mask_bad_parameters(kw, match):
    with pytest.raises(ParameterError, match=match):
        bin_mask(np.zeros((4, 4, 3), np.uint8), **kw)


@pytest.mark.parametrize("rgb", [np.zeros((4, 4), np.uint8), np.zeros((4, 4, 3), np.float32)])
def test_bin_mask_bad_image(rgb):
    with pytest.raises(InputShapeError, match="rgb must be"):
        bin_mask(rgb)


