"""zcut.sliver_fits.below_shares and SliverParams.max_below: the share of a region's border lying below it, against
a pixel-by-pixel count; a patch floating in front of the floor is not tried, a sliver past an occluder is; the
default tries every region as before; degenerate inputs."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parent / "fits"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import sliver_scene  # noqa: E402
from fit_scenes import pose, render  # noqa: E402
from sliver_scene import FLOOR_Z, occluded_scene, true_pose  # noqa: E402

from zcut.errors import InputShapeError  # noqa: E402
from zcut.sliver_fits import EIGHT, SliverParams, below_shares, fit_slivers  # noqa: E402


@pytest.fixture(scope="module")
def nut():  # type: ignore[no-untyped-def]
    return sliver_scene.nut()


def shares_by_pixel(xyz: np.ndarray, valid: np.ndarray, labels: np.ndarray, below_mm: float) -> dict[int, float]:
    """The definition, one pixel pair at a time."""
    H, W = labels.shape
    pairs: dict[int, list[bool]] = {}
    for r, c in zip(*np.nonzero(labels)):
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                rr, cc = r + dy, c + dx
                if (dy or dx) and 0 <= rr < H and 0 <= cc < W and valid[rr, cc] and labels[rr, cc] == 0:
                    pairs.setdefault(int(labels[r, c]), []).append(bool(xyz[rr, cc, 2] - xyz[r, c, 2] > below_mm))
    return {k: float(np.mean(v)) for k, v in pairs.items()}


@pytest.fixture(scope="module")
def floating(nut):  # type: ignore[no-untyped-def]
    return floating_patch(nut)


@pytest.fixture(scope="module")
def occluded(nut):  # type: ignore[no-untyped-def]
    return occluded_scene(nut, 0.7)


def floating_patch(nut):  # type: ignore[no-untyped-def]
    """(xyz, valid, patch): a 10 x 10 px patch of the nut's face floating in front of the floor, nothing else."""
    v, t, _ = nut
    xyz_part, ids = render([(v, t, true_pose())], floor_z_mm=FLOOR_Z)
    xyz, _ = render([], floor_z_mm=FLOOR_Z)
    rows, cols = np.nonzero(ids == 1)
    r0, c0 = int(np.median(rows)), int(np.median(cols))
    patch = np.zeros(ids.shape, bool)
    patch[r0 - 5:r0 + 5, c0 - 5:c0 + 5] = True
    patch &= ids == 1
    xyz[patch] = xyz_part[patch]
    return xyz, np.isfinite(xyz).all(axis=2), patch


def test_shares_match_the_definition_on_a_sliver_and_a_floating_patch(occluded, floating) -> None:  # type: ignore[no-untyped-def]
    xyz, sliver, _ = occluded
    fxyz, fvalid, patch = floating
    for x, m in ((xyz, sliver), (fxyz, patch)):
        valid = np.isfinite(x).all(axis=2)
        labels, n = ndimage.label(m & valid, structure=EIGHT)
        for mm in (0.5, 2.0, 50.0):
            got = below_shares(x, valid, labels, np.arange(1, n + 1), below_mm=mm)
            want = shares_by_pixel(x, valid, labels, mm)
            assert got.shape == (n + 1,) and got[0] == 0.0
            for k in range(1, n + 1):
                assert got[k] == pytest.approx(want.get(k, 0.0), abs=1e-12)
    # the floating patch: its whole border is the floor, ~30 mm behind it; farther than 50 mm, none
    labels, n = ndimage.label(patch, structure=EIGHT)
    assert n == 1
    assert below_shares(fxyz, fvalid, labels, [1])[1] == 1.0
    assert below_shares(fxyz, fvalid, labels, [1], below_mm=50.0)[1] == 0.0
    # the sliver past the box: the box (nearer) frames part of it, the floor the rest
    valid = np.isfinite(xyz).all(axis=2)
    labels, n = ndimage.label(sliver & valid, structure=EIGHT)
    s = below_shares(xyz, valid, labels, np.arange(1, n + 1))
    big = int(np.argmax(np.bincount(labels.ravel())[1:])) + 1
    assert 0.0 < s[big] < 1.0


def test_a_region_level_with_its_surroundings_or_framed_by_nothing_has_none_below() -> None:
    H, W = 20, 30
    xyz = np.zeros((H, W, 3))
    xyz[..., 2] = 500.0
    valid = np.ones((H, W), bool)
    labels = np.zeros((H, W), np.int32)
    labels[5:9, 5:9] = 1       # level with the plane around it
    labels[12:16, 20:24] = 2   # framed by invalid pixels only
    valid[11:17, 19:25] = False
    valid[12:16, 20:24] = True
    labels[0:3, 0:3] = 3       # at the image's corner, not asked for
    xyz[0:3, 0:3, 2] = 400.0
    got = below_shares(xyz, valid, labels, [1, 2])
    assert got.tolist() == [0.0, 0.0, 0.0, 0.0]
    assert below_shares(xyz, valid, labels, [3])[3] == 1.0
    assert below_shares(xyz, valid, labels, [])[1:].tolist() == [0.0, 0.0, 0.0]
    assert below_shares(xyz, valid, np.zeros((H, W), np.int32), [1]).tolist() == [0.0]
    assert below_shares(np.zeros((0, 0, 3)), np.zeros((0, 0), bool), np.zeros((0, 0), np.int32), [1]).tolist() == [0.0]


def test_a_floating_patch_is_not_tried_and_the_default_tries_it(nut, floating) -> None:  # type: ignore[no-untyped-def]
    _, _, model = nut
    xyz, valid, patch = floating
    neighbour = pose(true_pose()[:3, :3], (-40.0, -20.0, 380.0))
    loose = dict(min_px=20, min_share=0.9, max_see_through=1.0)  # free space off: the patch alone decides
    assert len(fit_slivers(xyz, valid, patch, model, neighbour[None], sigma_mm=0.05,
                           params=SliverParams(**loose))) == 1
    assert len(fit_slivers(xyz, valid, patch, model, neighbour[None], sigma_mm=0.05,
                           params=SliverParams(**loose, max_below=1.0))) == 1
    assert fit_slivers(xyz, valid, patch, model, neighbour[None], sigma_mm=0.05,
                       params=SliverParams(**loose, max_below=0.5)) == []


def test_the_sliver_past_an_occluder_is_still_tried_under_a_loose_bound(nut, occluded) -> None:  # type: ignore[no-untyped-def]
    _, _, model = nut
    T = true_pose()
    xyz, sliver, _ = occluded
    valid = np.isfinite(xyz).all(axis=2)
    labels, n = ndimage.label(sliver & valid, structure=EIGHT)
    s = float(below_shares(xyz, valid, labels, np.arange(1, n + 1)).max())
    neighbour = pose(T[:3, :3], (-40.0, -20.0, 380.0))
    for bound, found in ((min(1.0, s + 0.01), 1), (max(0.0, s - 0.01), 0)):
        got = fit_slivers(xyz, valid, sliver, model, neighbour[None], sigma_mm=0.05,
                          params=SliverParams(min_px=20, max_below=bound))
        assert len(got) == found


@pytest.mark.parametrize("kwargs, match", [({"max_below": 1.5}, "max_below"), ({"max_below": -0.1}, "max_below"),
                                           ({"below_mm": 0.0}, "below_mm")])
def test_bad_params_are_one_line(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        SliverParams(**kwargs)


def test_bad_shapes_are_one_line() -> None:
    with pytest.raises(InputShapeError, match="below_shares"):
        below_shares(np.zeros((4, 5, 3)), np.ones((4, 4), bool), np.zeros((4, 5), np.int32), [1])
    with pytest.raises(InputShapeError, match="below_shares"):
        below_shares(np.zeros((4, 5)), np.ones((4, 5), bool), np.zeros((4, 5), np.int32), [1])
