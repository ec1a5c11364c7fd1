"""The sliver pass's smallest region is a share of the part's expected image area, not a count of pixels
(``replay.pipeline.explained.sliver_min_px``, :func:`zcut.sliver_fits.expected_area_px`; docs/labelling.md,
"Eighteenth round"): ``SLIVER_MIN_PX`` (150) px where the part's expected area is ``SLIVER_REF_AREA_PX`` (the zinc
nut at 1920 × 1200), in proportion elsewhere; so on a 480 × 300 frame of hand-made zinc nuts, where no unexplained
region reaches 150 px, the pass still tries the frame's regions."""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "zcut" / "fits"))

from fit_digests import HAND_MADE_SIZE, hand_made, hand_made_fits  # noqa: E402

import replay.pipeline.explained as rex  # noqa: E402
from zcut import explained as ex  # noqa: E402
from zcut.cancel import stop_when  # noqa: E402
from zcut.errors import InputShapeError  # noqa: E402
from zcut.params import ExplainedParams  # noqa: E402
from zcut.sliver_fits import expected_area_px  # noqa: E402


def test_the_smallest_region_in_proportion_to_the_parts_image() -> None:
    ref = rex.SLIVER_REF_AREA_PX
    assert rex.sliver_min_px(ref) == rex.SLIVER_MIN_PX == 150
    assert rex.sliver_min_px(ref / 16.0) == 9  # a quarter of the resolution: 150 / 16 = 9.4
    assert rex.sliver_min_px(4.0 * ref) == 600
    assert rex.sliver_min_px(1e-6) == 1  # never below one pixel
    for bad in (float("nan"), 0.0, -1.0, float("inf")):  # no footprint to scale by: the count itself
        assert rex.sliver_min_px(bad) == rex.SLIVER_MIN_PX


def test_expected_area_from_the_median_footprint() -> None:
    foot = np.full((4, 5), 0.5)
    foot[0, 0] = 100.0  # the median, not the mean
    foot[1, 1] = np.nan
    where = np.ones((4, 5), bool)
    assert expected_area_px(10.0, foot, where) == pytest.approx(np.pi * (10.0 / 0.5) ** 2, rel=1e-12)
    only = np.zeros((4, 5), bool)
    only[0, 0] = True
    assert expected_area_px(10.0, foot, only) == pytest.approx(np.pi * 0.01, rel=1e-12)
    # no pixel, NaN only, no positive footprint: NaN (the method then keeps SLIVER_MIN_PX)
    assert np.isnan(expected_area_px(10.0, foot, np.zeros((4, 5), bool)))
    assert np.isnan(expected_area_px(10.0, np.full((4, 5), np.nan), where))
    assert np.isnan(expected_area_px(10.0, np.zeros((4, 5)), where))
    assert np.isnan(expected_area_px(10.0, np.zeros((0, 5)), np.zeros((0, 5), bool)))
    with pytest.raises(InputShapeError, match=r"expected_area_px: .* \(4, 5\), \(5, 4\)"):
        expected_area_px(10.0, foot, np.ones((5, 4), bool))


def test_the_pass_runs_at_480_x_300() -> None:
    """The hand-made zinc nuts at 480 × 300 (tests/zcut/fits/fit_digests.py's frame, its fits): every unexplained
    region is under 150 px, so a count of 150 px would try none; the share tries the largest of them (the pass's
    stop points are reached: one before each region tried, and before each guess refined)."""
    xyz, zone, model, K = hand_made("zinc_nuts")
    assert xyz.shape[:2] == HAND_MADE_SIZE == (300, 480)
    fits = hand_made_fits("zinc_nuts")
    from zcut.fits.model import PartModel

    assert isinstance(model, PartModel) and fits
    v = np.asarray(model.vertices, np.float64)
    t = np.asarray(model.triangles, np.int64)
    surfaces = ex.KnownSurfaces(parts=[(v @ f.pose[:3, :3].T + f.pose[:3, 3], t) for f in fits],
                                part_err_mm=[f.err_mm for f in fits])
    near = ex.nearest_surface(xyz, surfaces, where=zone)
    surfaces = ex.KnownSurfaces(parts=surfaces.parts, part_err_mm=ex.fit_sigmas(near, surfaces.part_err_mm,
                                                                                   where=zone))
    foot = ex.footprint_mm(xyz, K[0])
    p = ExplainedParams()
    un = ex.unexplained(near.dist_mm, ex.err_image(near, surfaces, foot, floor_mm=p.err_floor_mm, where=zone),
                        p.k) & zone
    labels, n = ndimage.label(un, structure=np.ones((3, 3), bool))
    sizes = np.bincount(labels.ravel(), minlength=n + 1)[1:]
    min_px = rex.sliver_min_px(expected_area_px(model.extent_mm, foot, zone))
    assert sizes.max() < rex.SLIVER_MIN_PX  # the count of pixels: no region to try at this size
    assert 1 <= min_px < 20 and (sizes >= min_px).sum() >= 1  # the share: regions to try
    stops: list[int] = []
    with stop_when(lambda: stops.append(1) is not None):  # never stops; counts the stop points passed
        got = rex._with_slivers(xyz, SimpleNamespace(zone=zone), near, surfaces, tuple(fits), v, t, model, K, foot,
                                zone, p)
    assert len(stops) >= min(rex.SLIVER_MAX_REGIONS, int(((sizes >= min_px) & (sizes <= 2000)).sum()))
    assert got[3] == len(got[0]) - len(fits) >= 0
