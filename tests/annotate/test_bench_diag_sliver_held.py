"""bench/diag_sliver_held.py's cues of a sliver pose (docs/labelling.md, "Twenty-fifth round"), on a nut posed twice:
a pose that is a fitted one moved 8 mm along the line of sight toward the camera reads as that fit's twin (8 mm along,
about 0 across), its pixels lie in front of the fitted nut by more than k × Err, and it explains its own pixels with
no residual; bad variants are refused in one line."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from bench_helpers import bench_module

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "zcut" / "fits"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "zcut"))

import sliver_scene  # noqa: E402
from fit_scenes import K_TEST, render  # noqa: E402


@pytest.fixture(scope="module")
def bench() -> Iterator[ModuleType]:
    yield from bench_module("diag_sliver_held.py")


def test_a_fit_moved_along_the_ray_is_its_twin_in_front(bench) -> None:  # type: ignore[no-untyped-def]
    v, t, model = sliver_scene.nut()
    T = sliver_scene.true_pose()
    c = T[:3, :3] @ model.centroid + T[:3, 3]
    moved = T.copy()
    moved[:3, 3] -= 8.0 * c / np.linalg.norm(c)  # 8 mm toward the camera along the ray through its centre
    xyz, ids = render([(v, t, moved)], floor_z_mm=sliver_scene.FLOOR_Z)
    pix = np.flatnonzero((ids == 1).ravel())
    cues = bench.sliver_cues(model, xyz.astype(np.float64), moved, pix, T[None], f_px=K_TEST[0], sigma=0.05, k=3.0,
                             floor_mm=0.1)
    assert cues["twin"]["fit"] == 0
    assert cues["twin"]["along_mm"] == pytest.approx(8.0, abs=0.01) and cues["twin"]["across_mm"] < 0.01
    assert cues["behind_share"] > 0.5 and cues["behind_gap_mm"] > 3.0
    assert cues["own_rms_mm"] < 0.01 and cues["own_p90_err"] < 0.1


def test_a_pose_far_from_every_fit_has_no_twin_and_nothing_behind(bench) -> None:  # type: ignore[no-untyped-def]
    v, t, model = sliver_scene.nut()
    T = sliver_scene.true_pose()
    far = T.copy()
    far[:3, 3] += (200.0, 0.0, 0.0)
    xyz, ids = render([(v, t, T)], floor_z_mm=sliver_scene.FLOOR_Z)
    pix = np.flatnonzero((ids == 1).ravel())
    cues = bench.sliver_cues(model, xyz.astype(np.float64), T, pix, far[None], f_px=K_TEST[0], sigma=0.05, k=3.0,
                             floor_mm=0.1)
    assert cues["twin"]["across_mm"] > 100.0 and cues["behind_share"] == 0.0 and cues["met_share"] == 0.0


@pytest.mark.parametrize("extra", [["--slivers", "10"], ["--slivers", "10:12", "--free-space", "3"]])
def test_bad_variants_refused_in_one_line(bench, monkeypatch, extra: list[str]) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setattr("sys.argv", ["diag_sliver_held.py", "/nonexistent.mcap", *extra])
    with pytest.raises(SystemExit) as e:
        bench.main()
    assert str(e.value).startswith("error: --") and "\n" not in str(e.value)
