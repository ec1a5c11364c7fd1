"""zcut.sliver_fits: the regions cut at the scan's depth steps (``SliverParams.split_steps``; docs/labelling.md,
"Twenty-third round"). :func:`zcut.sliver_fits.depth_steps` equals a literal per-pixel reference (an invalid neighbour
is never a step, where the depth edges, computed here literally, count it); a nut whose unexplained region also holds pixels
across a depth step (the surface beneath, attached to its silhouette) is posed only when the region is cut there, and
invalid pixels spread over the nut's face do not cut it; off, the pass is the one before (the same call)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

sys.path.insert(0, str(Path(__file__).resolve().parent / "fits"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import sliver_scene  # noqa: E402
from fit_scenes import K_TEST, pose, render  # noqa: E402
from sliver_scene import FLOOR_Z, true_pose  # noqa: E402

from zcut.sliver_fits import SliverParams, depth_steps, fit_slivers  # noqa: E402

FX = K_TEST[0]
#: A valid pixel is at a depth edge when a 4-neighbour is invalid or more than this many footprints off in depth
#: (docs/labelling.md, "Seventeenth round"; the cut of the "Twenty-second round", reverted): the steps' contrast.
EDGE_FOOTPRINTS = 10.0


@pytest.fixture(scope="module")
def nut():  # type: ignore[no-untyped-def]
    return sliver_scene.nut()


def _marked(xyz: np.ndarray, valid: np.ndarray, n: float, *, edges: bool) -> np.ndarray:
    """Pixel by pixel: a valid pixel with a valid 4-neighbour (inside the image) more than n footprints off in z; with
    ``edges`` also one whose 4-neighbour is outside the image or invalid (a depth edge)."""
    H, W = valid.shape
    out = np.zeros((H, W), bool)
    for r in range(H):
        for c in range(W):
            if not valid[r, c]:
                continue
            z = xyz[r, c, 2]
            for a, b in ((r, c + 1), (r, c - 1), (r + 1, c), (r - 1, c)):
                if not (0 <= a < H and 0 <= b < W and valid[a, b]):
                    if edges:
                        out[r, c] = True
                        break
                elif abs(xyz[a, b, 2] - z) > n * abs(z) / FX:
                    out[r, c] = True
                    break
    return out


def _edges(xyz: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """A 4-neighbour outside the image, invalid, or more than EDGE_FOOTPRINTS footprints off in z."""
    return _marked(xyz, valid, EDGE_FOOTPRINTS, edges=True)


def _steps_reference(xyz: np.ndarray, valid: np.ndarray, n: float) -> np.ndarray:
    """A valid 4-neighbour (inside the image) more than n footprints off in z."""
    return _marked(xyz, valid, n, edges=False)


def _scene(nut):  # type: ignore[no-untyped-def]
    """(xyz, valid, model, T, the nut's pixels, the unexplained region: the nut and a strip of the floor beside it)."""
    v, t, model = nut
    T = true_pose()
    xyz, ids = render([(v, t, T)], floor_z_mm=FLOOR_Z)
    xyz = xyz.astype(np.float64)
    part = ids == 1
    cols = np.nonzero(part)[1]
    strip = ndimage.binary_dilation(part, iterations=10) & ~part
    strip[:, :int(np.median(cols))] = False
    return xyz, np.isfinite(xyz).all(axis=2), model, T, part, part | strip


def test_depth_steps_equal_their_literal_reference(nut) -> None:  # type: ignore[no-untyped-def]
    xyz, valid, _, _, part, _ = _scene(nut)
    rows, cols = np.nonzero(part)
    win = (slice(rows.min() - 8, rows.max() + 9), slice(cols.min() - 8, cols.max() + 9))
    x, ok = xyz[win].copy(), valid[win].copy()
    ok[3, 3:9] = False  # invalid pixels inside the window
    x[~ok] = np.nan
    ref = _edges(x, ok)
    assert ref.sum() > 50
    for n in (10.0, 3.0):
        steps = depth_steps(x, ok, FX, n)
        sref = _steps_reference(x, ok, n)
        assert np.array_equal(steps, sref) and 50 < sref.sum() < ref.sum()
    assert not (depth_steps(x, ok, FX, 10.0) & ~ok).any()  # an invalid pixel is never a step


def test_a_region_cut_at_the_depth_step_poses_the_nut(nut) -> None:  # type: ignore[no-untyped-def]
    xyz, valid, model, T, part, region = _scene(nut)
    assert ndimage.label(region, structure=np.ones((3, 3), bool))[1] == 1  # one region: the nut and the floor strip
    assert (region & ~part).sum() > 0.3 * region.sum()
    neighbour = pose(T[:3, :3], (-40.0, -20.0, 380.0))
    base = dict(min_px=20, max_px=100_000)
    off = fit_slivers(xyz, valid, region, model, neighbour[None], sigma_mm=0.05, params=SliverParams(**base))
    assert off == []  # the floor strip holds too much of the region: no pose explains 0.8 of it
    assert [f.pixels.tolist() for f in off] == [f.pixels.tolist() for f in fit_slivers(
        xyz, valid, region, model, neighbour[None], sigma_mm=0.05, params=SliverParams(**base, split_steps=0.0))]
    on = fit_slivers(xyz, valid, region, model, neighbour[None], sigma_mm=0.05,
                     params=SliverParams(**base, split_steps=EDGE_FOOTPRINTS))
    assert len(on) == 1
    steps = depth_steps(xyz, valid, FX, EDGE_FOOTPRINTS).ravel()
    assert part.ravel()[on[0].pixels].all() and not steps[on[0].pixels].any()
    c_true = T[:3, :3] @ model.centroid + T[:3, 3]
    c_got = on[0].pose[:3, :3] @ model.centroid + on[0].pose[:3, 3]
    assert float(np.linalg.norm(c_got - c_true)) < 1.0


def test_dropouts_over_the_face_do_not_cut_the_region(nut) -> None:  # type: ignore[no-untyped-def]
    xyz, valid, model, T, part, region = _scene(nut)
    rows, cols = np.nonzero(part)
    drop = np.zeros_like(part)
    drop[rows[::9], cols[::9]] = True  # invalid pixels spread over the nut's face (the ray-traced scan's dropouts)
    xyz = xyz.copy()
    xyz[drop] = np.nan
    valid = valid & ~drop
    region = region & ~drop
    nut_px = part & valid
    lab_steps = ndimage.label(nut_px & ~depth_steps(xyz, valid, FX, EDGE_FOOTPRINTS), structure=np.ones((3, 3), bool))
    lab_edges = ndimage.label(nut_px & ~_edges(xyz, valid), structure=np.ones((3, 3), bool))
    sizes_steps = np.bincount(lab_steps[0].ravel())[1:]
    sizes_edges = np.bincount(lab_edges[0].ravel())[1:]
    assert sizes_steps.max() > 0.8 * nut_px.sum() > 1.5 * sizes_edges.max()  # the edges cut the face, the steps not
    neighbour = pose(T[:3, :3], (-40.0, -20.0, 380.0))
    on = fit_slivers(xyz, valid, region, model, neighbour[None], sigma_mm=0.05,
                     params=SliverParams(min_px=20, max_px=100_000, split_steps=EDGE_FOOTPRINTS))
    assert len(on) == 1 and part.ravel()[on[0].pixels].all()
