"""bench/diag_unfit.py's ray casts (docs/fits.md, "Twentieth round"): an instance's silhouette alone, the instance
each pixel's ray meets first among several, and from them the visible share the split and "fully visible" read."""

from __future__ import annotations

from collections.abc import Iterator
from types import ModuleType

import numpy as np
import pytest
from bench_helpers import bench_module

K = (100.0, 100.0, 31.5, 23.5)  # fx, fy, cx, cy of a 64 × 48 image
H, W = 48, 64


@pytest.fixture(scope="module")
def bench() -> Iterator[ModuleType]:
    yield from bench_module("diag_unfit.py")


def _square(cx: float, cy: float, z: float, half: float) -> tuple[np.ndarray, np.ndarray]:
    """A square facing the camera at depth ``z`` (mm), centred on (cx, cy), two triangles."""
    v = np.array([[cx - half, cy - half, z], [cx + half, cy - half, z], [cx + half, cy + half, z],
                  [cx - half, cy + half, z]])
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def test_a_square_alone_covers_its_projected_area(bench) -> None:  # type: ignore[no-untyped-def]
    v, t = _square(0.0, 0.0, 100.0, 5.0)  # 10 mm at 100 mm and f = 100 px: 10 × 10 px
    n = bench._silhouette_px(v, t, K, H, W)
    assert 81 <= n <= 121
    hits = bench._first_hits([(v, t)], K, H, W)
    assert int((hits == 0).sum()) == n and int((hits == -1).sum()) == H * W - n


def test_an_occluder_takes_the_first_hits_and_not_the_silhouette(bench) -> None:  # type: ignore[no-untyped-def]
    back = _square(0.0, 0.0, 100.0, 5.0)
    front = _square(1.0, 0.0, 80.0, 2.0)  # nearer, inside the back square's pixels
    alone = bench._silhouette_px(*back, K, H, W)
    hits = bench._first_hits([back, front], K, H, W)
    seen_back, seen_front = int((hits == 0).sum()), int((hits == 1).sum())
    assert seen_front == bench._silhouette_px(*front, K, H, W) > 0
    assert seen_back + seen_front == alone  # the front square lies inside the back one's silhouette
    assert 0 < seen_back / alone < 1


def test_a_part_behind_the_camera_or_off_the_image_has_no_silhouette(bench) -> None:  # type: ignore[no-untyped-def]
    assert bench._silhouette_px(*_square(0.0, 0.0, -100.0, 5.0), K, H, W) == 0
    assert bench._silhouette_px(*_square(500.0, 0.0, 100.0, 5.0), K, H, W) == 0


@pytest.mark.parametrize("extra, what", [(["--area-share", "1.5"], "--area-share A in [0, 1], got None and 1.5"),
                                         (["--min-px", "0"], "--min-px takes N >= 1")])
def test_bad_floor_refused_in_one_line(bench, monkeypatch, extra: list[str], what: str
                                       ) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setattr("sys.argv", ["diag_unfit.py", "/nonexistent.mcap", *extra])
    with pytest.raises(SystemExit) as e:
        bench.main()
    assert what in str(e.value) and "\n" not in str(e.value)
