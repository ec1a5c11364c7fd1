"""zcut.sliver_fits: the regions' size floor as a share of a whole part's projected area at the region's depth
(``SliverParams.min_area_share``; docs/labelling.md, "Twenty-fourth round"). :func:`zcut.sliver_fits.projected_area_px`
is π (extent · f / z)²; a region under the share's floor is not tried, one at or over it is posed as with no floor
(the same pixels); a share outside [0, 1] is refused in one line."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "fits"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import sliver_scene  # noqa: E402
from fit_scenes import K_TEST, pose, render  # noqa: E402
from sliver_scene import FLOOR_Z, true_pose  # noqa: E402

from zcut.sliver_fits import SliverParams, fit_slivers, projected_area_px  # noqa: E402


@pytest.fixture(scope="module")
def nut():  # type: ignore[no-untyped-def]
    return sliver_scene.nut()


def test_projected_area_is_the_fits_area(nut) -> None:  # type: ignore[no-untyped-def]
    model = nut[2]
    for z, f in ((380.0, 500.0), (1200.0, 1400.0)):
        r = model.extent_mm * f / z
        assert float(projected_area_px(model, z, f)) == pytest.approx(math.pi * r * r, rel=1e-12)
    got = projected_area_px(model, np.array([400.0, 800.0]), 500.0)
    assert got.shape == (2,) and got[0] == pytest.approx(4.0 * got[1], rel=1e-12)  # twice as far: a quarter


def test_a_region_under_the_floor_is_not_tried(nut) -> None:  # type: ignore[no-untyped-def]
    v, t, model = nut
    T = true_pose()
    xyz, ids = render([(v, t, T)], floor_z_mm=FLOOR_Z)
    xyz = xyz.astype(np.float64)
    valid = np.isfinite(xyz).all(axis=2)
    part = ids == 1
    neighbour = pose(T[:3, :3], (-40.0, -20.0, 380.0))
    base = dict(min_px=20, max_px=100_000)
    n = int(part.sum())
    z = float(np.median(xyz[part][:, 2]))
    share = n / float(projected_area_px(model, z, 0.5 * (K_TEST[0] + K_TEST[1])))  # the region is this share
    assert 0.05 < share < 1.0

    def run(**kw: float) -> list:  # type: ignore[type-arg]
        return fit_slivers(xyz, valid, part, model, neighbour[None], sigma_mm=0.05, intrinsics=K_TEST,
                           params=SliverParams(**base, **kw))

    off = run()
    assert len(off) == 1
    on = run(min_area_share=0.999 * share)  # the floor just under the region's size: posed as with none
    assert [f.pixels.tolist() for f in on] == [f.pixels.tolist() for f in off]
    assert run(min_area_share=1.001 * share) == []  # just over: not tried


@pytest.mark.parametrize("bad", [-0.1, 1.5, float("nan")])
def test_a_share_outside_0_1_is_refused(bad: float) -> None:
    with pytest.raises(ValueError, match=r"^SliverParams.min_area_share must lie in \[0, 1\], got "):
        SliverParams(min_area_share=bad)
