"""The sliver pass's free-space bound is the method's constant (``replay.pipeline.explained.SLIVER_MAX_SEE_THROUGH``,
docs/labelling.md, "Eighteenth round"): ``_with_slivers`` hands it to :class:`zcut.sliver_fits.SliverParams`, so the
page's fits and the method's outliers read one value. The scene: a patch of a nut's face floating in front of the
floor (the rest of the nut absent: the camera saw the floor where its body would be), the pose the part fits there
seen through on most of its silhouette (tests/zcut/test_sliver_fits.py's free-space scene)."""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "zcut" / "fits"))
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "zcut"))

import sliver_scene  # noqa: E402
from fit_scenes import K_TEST, pose, render  # noqa: E402

import replay.pipeline.explained as rex  # noqa: E402
import zcut.sliver_fits  # noqa: E402
from zcut import explained as ex  # noqa: E402
from zcut.fits import PartFit  # noqa: E402
from zcut.params import ExplainedParams  # noqa: E402


@pytest.fixture(scope="module")
def floating():  # type: ignore[no-untyped-def]
    """(nut, xyz, zone, the fitted neighbour's pose): the floating patch is the zone's one unexplained region."""
    nut = sliver_scene.nut()
    v, t, _ = nut
    T = sliver_scene.true_pose()
    xyz_part, ids = render([(v, t, T)], floor_z_mm=sliver_scene.FLOOR_Z)
    xyz, _ = render([], floor_z_mm=sliver_scene.FLOOR_Z)
    rows, cols = np.nonzero(ids == 1)
    r0, c0 = int(np.median(rows)), int(np.median(cols))
    patch = np.zeros(ids.shape, bool)
    patch[r0 - 5:r0 + 5, c0 - 5:c0 + 5] = True
    patch &= ids == 1
    xyz[patch] = xyz_part[patch]
    return nut, xyz, patch, pose(T[:3, :3], (-40.0, -20.0, 380.0))


handed: list[tuple[int, float, float]] = []


def _pass(floating, monkeypatch, bound: float | None):  # type: ignore[no-untyped-def]
    """(sliver fits added, the bound SliverParams got) of the method's pass on the scene, with the constant set to
    ``bound`` (None: the tree's)."""
    (v, t, model), xyz, zone, T = floating
    monkeypatch.setattr(rex, "SLIVER_MIN_PX", 20)
    if bound is not None:
        monkeypatch.setattr(rex, "SLIVER_MAX_SEE_THROUGH", bound)
    got: list[float] = []
    inner = zcut.sliver_fits.fit_slivers

    def noted(*a, **k):  # type: ignore[no-untyped-def]
        got.append(k["params"].max_see_through)
        handed.append((k["params"].min_px, k["params"].split_steps, k["params"].min_area_share))
        return inner(*a, **k)

    monkeypatch.setattr(zcut.sliver_fits, "fit_slivers", noted)
    fits = (PartFit(T, 0.05, 1.0, np.zeros(0, np.int64)),)
    surfaces = ex.KnownSurfaces(parts=[(v @ T[:3, :3].T + T[:3, 3], t)], part_err_mm=[0.05])
    near = ex.nearest_surface(xyz, surfaces, where=zone)
    foot = ex.footprint_mm(xyz, K_TEST[0])
    p = ExplainedParams()
    n = rex._with_slivers(xyz, SimpleNamespace(zone=zone), near, surfaces, fits, v, t, model, K_TEST, foot, zone,
                          p)[3]
    return n, got


def test_the_method_hands_its_free_space_bound_to_the_pass(floating, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    # the tree's bound refuses the floating patch's pose (the camera saw the floor through it)
    n, got = _pass(floating, monkeypatch, None)
    assert n == 0 and got == [rex.SLIVER_MAX_SEE_THROUGH]
    # the same pass with the bound at 1 takes it: the constant is what refuses it
    n, got = _pass(floating, monkeypatch, 1.0)
    assert n == 1 and got == [1.0]


def test_the_method_hands_its_cut_and_floor_to_the_pass(floating, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    # docs/labelling.md, "Twenty-fourth round": the regions cut at depth steps of 3 footprints, the floor 10 px and
    # 0.025 of a whole part's projected area; the page's fits run the same pass (annotate/fits.py)
    assert (rex.SLIVER_MIN_PX, rex.SLIVER_SPLIT_STEPS, rex.SLIVER_MIN_AREA_SHARE) == (10, 3.0, 0.025)
    handed.clear()
    monkeypatch.setattr(rex, "SLIVER_SPLIT_STEPS", 7.0)
    monkeypatch.setattr(rex, "SLIVER_MIN_AREA_SHARE", 0.5)
    _pass(floating, monkeypatch, None)
    assert handed == [(20, 7.0, 0.5)]
