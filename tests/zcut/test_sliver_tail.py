"""zcut.sliver_fits: the support's residual profile (``SliverParams.max_tail``; docs/labelling.md, "Twenty-fifth
round"). A pose is accepted only when the 90th percentile of its explained pixels' distance over their Err is at most
Q: a nut's surface measured cleanly is posed as with no bound; the same surface with half its pixels pushed ±2.4 Err
along the ray (its residual still under the pass's bound, its share explained at least 0.8) is refused at Q = 1.645 and
posed without the bound; a bound just over a pose's own profile keeps it, one just under refuses it; a negative Q is
refused in one line."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "fits"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import sliver_scene  # noqa: E402
from fit_scenes import K_TEST, pose, render  # noqa: E402
from sliver_scene import FLOOR_Z, true_pose  # noqa: E402

from zcut.sliver_fits import SliverParams, fit_slivers  # noqa: E402

SIGMA = 0.05


@pytest.fixture(scope="module")
def scene():  # type: ignore[no-untyped-def]
    v, t, model = sliver_scene.nut()
    T = true_pose()
    xyz, ids = render([(v, t, T)], floor_z_mm=FLOOR_Z)
    xyz = xyz.astype(np.float64)
    return model, xyz, np.isfinite(xyz).all(axis=2), ids == 1, pose(T[:3, :3], (-40.0, -20.0, 380.0))


def _err(xyz: np.ndarray) -> np.ndarray:
    foot = np.abs(xyz[..., 2]) / K_TEST[0]
    return np.maximum(0.1, np.sqrt(SIGMA ** 2 + foot ** 2 / 2.0))


def _run(scene, xyz: np.ndarray, **kw: float) -> list:  # type: ignore[no-untyped-def, type-arg]
    model, _, valid, part, neighbour = scene
    return fit_slivers(xyz, valid, part, model, neighbour[None], sigma_mm=SIGMA, intrinsics=K_TEST,
                       params=SliverParams(min_px=20, max_px=100_000, **kw))


def _profile(model, xyz: np.ndarray, fit) -> float:  # type: ignore[no-untyped-def]
    pts = xyz.reshape(-1, 3)[fit.pixels]
    d = model.distance((pts - fit.pose[:3, 3]) @ fit.pose[:3, :3])
    return float(np.percentile(d / _err(xyz).reshape(-1)[fit.pixels], 90))


def test_a_clean_surface_is_posed_as_with_no_bound(scene) -> None:  # type: ignore[no-untyped-def]
    xyz = scene[1]
    off = _run(scene, xyz)
    assert len(off) == 1 and _profile(scene[0], xyz, off[0]) < 1.0
    on = _run(scene, xyz, max_tail=1.645)
    assert [f.pixels.tolist() for f in on] == [f.pixels.tolist() for f in off]
    assert np.array_equal(on[0].pose, off[0].pose)


def test_a_band_as_wide_as_the_gate_is_refused(scene) -> None:  # type: ignore[no-untyped-def]
    model, xyz, _, part, _ = scene
    rows, cols = np.nonzero(part)
    # half the pixels ±2.4 Err along the ray (alternating), half on the surface: RMS about 1.7 Err along the ray
    step = np.select([(rows + cols) % 4 == 0, (rows + cols) % 4 == 2], [2.4, -2.4], 0.0) * _err(xyz)[rows, cols]
    band = xyz.copy()
    rng = np.linalg.norm(band[rows, cols], axis=1)
    band[rows, cols] *= (1.0 + step / rng)[:, None]
    off = _run(scene, band)
    assert len(off) == 1 and off[0].share >= 0.8  # the residual and the share pass: only the profile tells
    assert _profile(model, band, off[0]) > 1.645
    assert _run(scene, band, max_tail=1.645) == []


def test_the_bound_at_a_poses_own_profile(scene) -> None:  # type: ignore[no-untyped-def]
    model, xyz, _, part, _ = scene
    rows, cols = np.nonzero(part)
    step = np.where((rows + cols) % 2 == 0, 1.5, -1.5) * _err(xyz)[rows, cols]
    band = xyz.copy()
    band[rows, cols] *= (1.0 + step / np.linalg.norm(band[rows, cols], axis=1))[:, None]
    off = _run(scene, band)
    assert len(off) == 1
    q = _profile(model, band, off[0])
    kept = _run(scene, band, max_tail=1.001 * q)
    assert [f.pixels.tolist() for f in kept] == [f.pixels.tolist() for f in off]
    assert all(_profile(model, band, f) <= 0.999 * q for f in _run(scene, band, max_tail=0.999 * q))


@pytest.mark.parametrize("bad", [-0.1, float("nan")])
def test_a_negative_bound_is_refused(bad: float) -> None:
    with pytest.raises(ValueError, match=r"^SliverParams.max_tail must be at least 0, got "):
        SliverParams(max_tail=bad)
