"""The sliver pass inside the method ``explained`` (``replay.pipeline.explained._with_slivers``,
:mod:`zcut.sliver_fits`): a sliver no fit took joins the fits and its pixels are explained by the method itself, so
the page's proposals and the method's outliers stay one definition; nothing to fit changes nothing; the largest
regions first under the region budget. The scene: tests/zcut/sliver_scene.py (a hand-made nut past a box)."""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "zcut" / "fits"))
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "zcut"))

import sliver_scene  # noqa: E402
from fit_scenes import K_TEST, pose, rotation  # noqa: E402

import replay.pipeline.explained as rex  # noqa: E402
from zcut import explained as ex  # noqa: E402
from zcut.fits import PartFit  # noqa: E402
from zcut.params import ExplainedParams  # noqa: E402
from zcut.sliver_fits import SliverParams, fit_slivers  # noqa: E402


@pytest.fixture(scope="module")
def scene():  # type: ignore[no-untyped-def]
    nut = sliver_scene.nut()
    xyz, sliver, _ = sliver_scene.occluded_scene(nut, 0.7)
    return nut, xyz, sliver


def state(nut, xyz: np.ndarray, zone: np.ndarray):  # type: ignore[no-untyped-def]
    """(fits, surfaces, nearest, footprint) of a frame whose one fit is a neighbour away from the sliver, in its
    orientation turned by 4°; every zone pixel judged against it alone (no bin, no table)."""
    v, t, _ = nut
    T = pose(rotation((0.0, 0.0, 1.0), 4.0) @ sliver_scene.true_pose()[:3, :3], (-40.0, -20.0, 380.0))
    fits = (PartFit(T, 0.05, 1.0, np.zeros(0, np.int64)),)
    surfaces = ex.KnownSurfaces(parts=[(v @ T[:3, :3].T + T[:3, 3], t)], part_err_mm=[0.05])
    near = ex.nearest_surface(xyz, surfaces, where=zone)
    return fits, surfaces, near, ex.footprint_mm(xyz, K_TEST[0])


def run(nut, xyz: np.ndarray, zone: np.ndarray, monkeypatch, min_px: int = 20, regions: int = 24):  # type: ignore[no-untyped-def]
    v, t, model = nut
    monkeypatch.setattr(rex, "SLIVER_MIN_PX", min_px)
    monkeypatch.setattr(rex, "SLIVER_MAX_REGIONS", regions)
    fits, surfaces, near, foot = state(nut, xyz, zone)
    p = ExplainedParams()
    got = rex._with_slivers(xyz, SimpleNamespace(zone=zone), near, surfaces, fits, v, t, model, K_TEST, foot, zone, p)
    return (fits, surfaces, near), got, p, foot


def test_the_sliver_joins_the_fits_and_the_method_explains_it(scene, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    nut, xyz, sliver = scene
    zone = np.isfinite(xyz).all(axis=2) & sliver
    (fits0, _, near0), (fits, surfaces, near, n), p, foot = run(nut, xyz, zone, monkeypatch)
    err0 = ex.err_image(near0, state(nut, xyz, zone)[1], foot, floor_mm=p.err_floor_mm)
    assert ex.unexplained(near0.dist_mm, err0, p.k)[zone].all()  # before: the whole sliver unexplained
    assert n == 1 and len(fits) == 2 and fits[0] is fits0[0] and len(surfaces.parts) == 2
    err = ex.err_image(near, surfaces, foot, floor_mm=p.err_floor_mm)
    out = ex.unexplained(near.dist_mm, err, p.k) & zone
    assert out.sum() <= 0.05 * zone.sum()  # after: the method explains at least 95 % of the sliver
    assert (near.surface[zone & ~out] == 1).all()  # by the sliver's fit
    # the sliver fit states the frame's median fit σ and the share of its region it explains
    assert fits[1].err_mm == pytest.approx(0.05) and fits[1].support >= 0.95
    assert near.dist_mm.dtype == np.float32 and near.surface.dtype == np.int32


def test_off_or_nothing_unexplained_changes_nothing(scene, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    nut, xyz, sliver = scene
    zone = np.isfinite(xyz).all(axis=2) & sliver
    # regions smaller than the pass's size: nothing tried, the same objects back
    (fits0, surf0, near0), (fits, surfaces, near, n), _, _ = run(nut, xyz, zone, monkeypatch, min_px=10_000)
    assert n == 0 and fits is fits0 and surfaces is surf0 and near is near0
    # an empty zone, an all-NaN cloud
    empty = np.zeros_like(zone)
    (fits0, surf0, near0), (fits, surfaces, near, n), _, _ = run(nut, xyz, empty, monkeypatch)
    assert n == 0 and fits is fits0 and near is near0
    nan = np.full_like(xyz, np.nan)
    (fits0, surf0, near0), (fits, surfaces, near, n), _, _ = run(nut, nan, zone, monkeypatch)
    assert n == 0 and fits is fits0 and near is near0


def test_the_largest_regions_first_under_the_budget(scene) -> None:  # type: ignore[no-untyped-def]
    """The sliver and a 25 px patch of scattered points before it in raster order (the floor shaken by ±3 mm: no part
    explains it): with one region allowed, the sliver (the larger) is tried and fitted; in raster order the patch
    alone would be tried."""
    (_, _, model), xyz, sliver = scene
    valid = np.isfinite(xyz).all(axis=2)
    patch = np.zeros_like(sliver)
    patch[2:7, 2:7] = True
    xyz = xyz.copy()
    xyz[patch] *= (1.0 + np.random.default_rng(5).uniform(-3.0, 3.0, patch.sum()) / xyz[patch][:, 2])[:, None]
    assert valid[patch].all() and not (patch & sliver).any() and sliver.sum() > 25
    T = pose(rotation((0.0, 0.0, 1.0), 4.0) @ sliver_scene.true_pose()[:3, :3], (-40.0, -20.0, 380.0))
    one = fit_slivers(xyz, valid, sliver | patch, model, T[None], sigma_mm=0.05,
                      params=SliverParams(min_px=20, max_regions=1), intrinsics=K_TEST)
    assert len(one) == 1 and set(one[0].pixels.tolist()) <= set(np.flatnonzero(sliver).tolist())
    assert fit_slivers(xyz, valid, patch, model, T[None], sigma_mm=0.05, params=SliverParams(min_px=20)) == []
