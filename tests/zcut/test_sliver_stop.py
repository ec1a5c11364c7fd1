"""The sliver pass stopped part-way (:mod:`zcut.cancel`; docs/labelling.md, the section of the round of 2026-12-07b):
inside a :func:`zcut.cancel.stop_when` scope :func:`zcut.sliver_fits.fit_slivers` raises :class:`zcut.errors.Cancelled`
at the first stop point after the check says stop — before each region and each guess refined — and a scope whose
check never says stop changes no sliver fit. The scene: tests/zcut/sliver_scene.py's nut seen as a sliver past a box."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "fits"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import sliver_scene  # noqa: E402
from fit_scenes import pose, rotation  # noqa: E402
from sliver_scene import occluded_scene, true_pose  # noqa: E402

from zcut.cancel import stop_when  # noqa: E402
from zcut.errors import Cancelled  # noqa: E402
from zcut.sliver_fits import SliverParams, fit_slivers  # noqa: E402

#: the pass in full (every guess iterated) and as the method runs it (a few coarse iterations, the best 8 refined)
PARAMS = [SliverParams(min_px=20), SliverParams(min_px=20, coarse=2, refine=8)]


class _Counter:
    """A check that says stop from its ``at``-th call on (never when ``at`` is None), counting its calls."""

    def __init__(self, at: int | None = None) -> None:
        self.at = at
        self.calls = 0

    def __call__(self) -> bool:
        self.calls += 1
        return self.at is not None and self.calls >= self.at


@pytest.fixture(scope="module")
def scene():  # type: ignore[no-untyped-def]
    """(xyz, valid, unexplained, model, fitted poses): the sliver, and a second region (a corner of the occluding
    box's face marked unexplained), so that the pass visits two regions."""
    nut = sliver_scene.nut()
    xyz, sliver, _ = occluded_scene(nut, 0.7)
    valid = np.isfinite(xyz).all(axis=2)
    floor = np.zeros_like(sliver)
    floor[-4:, :12] = True
    floor &= valid & ~sliver
    neighbour = pose(rotation((0.0, 0.0, 1.0), 4.0) @ true_pose()[:3, :3], (-40.0, -20.0, 380.0))
    return xyz, valid, sliver | floor, nut[2], neighbour[None]


def _fit(scene, params: SliverParams):  # type: ignore[no-untyped-def]
    xyz, valid, un, model, poses = scene
    return fit_slivers(xyz, valid, un, model, poses, sigma_mm=0.05, params=params)


def _same(a, b) -> bool:  # type: ignore[no-untyped-def]
    return len(a) == len(b) and all(
        np.array_equal(x.pose, y.pose) and x.err_mm == y.err_mm and x.share == y.share
        and x.see_through == y.see_through and np.array_equal(x.pixels, y.pixels) for x, y in zip(a, b))


@pytest.mark.parametrize("params", PARAMS, ids=["full", "coarse"])
def test_a_scope_that_never_stops_changes_no_sliver_fit(scene, params: SliverParams) -> None:  # type: ignore[no-untyped-def]
    plain = _fit(scene, params)
    check = _Counter()
    with stop_when(check):
        scoped = _fit(scene, params)
    assert len(plain) >= 1 and _same(scoped, plain)
    assert check.calls >= 2 + 2  # each of the two regions, and each guess refined in the sliver's


@pytest.mark.parametrize("params", PARAMS, ids=["full", "coarse"])
def test_a_stop_at_any_stop_point_ends_the_pass_there(scene, params: SliverParams) -> None:  # type: ignore[no-untyped-def]
    n = _Counter()
    with stop_when(n):
        full = _fit(scene, params)
    for at in sorted({1, 2, n.calls // 2, n.calls}):
        check = _Counter(at)
        with stop_when(check), pytest.raises(Cancelled, match="stopped by the caller"):
            _fit(scene, params)
        assert check.calls == at  # raised at the stop point that saw it, not later
    assert _same(_fit(scene, params), full)  # the scope left: the same fits again


def test_with_no_region_to_try_a_stop_changes_nothing(scene) -> None:  # type: ignore[no-untyped-def]
    """Degenerate inputs (no unexplained pixel, all NaN, one row, no fitted pose, regions below ``min_px``): the pass
    reaches no stop point and returns no fit, inside a scope that says stop at once."""
    xyz, valid, un, model, poses = scene
    nan = np.full_like(xyz, np.nan)
    row = (xyz[:1], valid[:1], un[:1])
    with stop_when(lambda: True):
        assert fit_slivers(xyz, valid, np.zeros_like(un), model, poses, sigma_mm=0.05) == []
        assert fit_slivers(nan, valid, un, model, poses, sigma_mm=0.05) == []
        assert fit_slivers(*row, model, poses, sigma_mm=0.05) == []
        assert fit_slivers(xyz, valid, un, model, np.zeros((0, 4, 4)), sigma_mm=0.05) == []
        assert fit_slivers(xyz, valid, un, model, poses, sigma_mm=0.05, params=SliverParams(min_px=10**6)) == []
