"""bench/diag_free.py's helpers (docs/labelling.md, "Twenty-first round"): the true pose recovered from a posed mesh,
the depth edges, the see-through pixels it splits equal to ``zcut.sliver_fits.see_through_share``'s share and
silhouette, the readings off the rim and the edges, and the causes' order."""

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


@pytest.fixture(scope="module")
def bench() -> Iterator[ModuleType]:
    yield from bench_module("diag_free.py")


def test_the_rigid_pose_of_a_posed_copy(bench) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(0)
    a = rng.normal(size=(50, 3)) * 10.0
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    R = q * np.sign(np.linalg.det(q))
    T, res = bench.rigid(a, a @ R.T + [1.0, -2.0, 300.0])
    assert res < 1e-9 and np.allclose(T[:3, :3], R) and np.allclose(T[:3, 3], [1.0, -2.0, 300.0])


def test_depth_edges(bench) -> None:  # type: ignore[no-untyped-def]
    z = np.full((5, 6), 500.0)
    z[:, 3:] = 520.0  # a 20 mm step; the footprint at 500 mm and fx 1000 is 0.5 mm: 10 footprints = 5 mm
    z[1:4, 1:3] += 1.0  # 1 mm: no edge
    xyz = np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=-1)
    valid = np.ones(z.shape, bool)
    valid[4, 0] = False
    e = bench.depth_edges(xyz, valid, 1000.0)
    assert e[:, 2].all() and e[:, 3].all()  # both sides of the step
    assert e[0].all() and e[-1, 1:].all() and e[:4, 0].all() and e[:, -1].all()  # the image border
    # (an invalid pixel is no edge itself; its neighbours are)
    assert not e[4, 0] and not e[1:4, 1].any() and not e[1:4, 4].any()


def test_the_split_pixels_are_the_share_s(bench) -> None:  # type: ignore[no-untyped-def]
    import sliver_scene
    from fit_scenes import K_TEST, render
    from sliver_scene import FLOOR_Z, true_pose

    from zcut.sliver_fits import see_through_share

    v, t, model = sliver_scene.nut()
    T = true_pose()
    xyz, ids = render([(v, t, T)], floor_z_mm=FLOOR_Z)
    xyz = xyz.astype(np.float64)
    rows, cols = np.nonzero(ids == 1)
    back = np.zeros(ids.shape, bool)
    back[rows[::7], cols[::7]] = True  # some of the nut's pixels measured 5 mm behind it
    p = xyz[back]
    xyz[back] = p * (1.0 + 5.0 / np.linalg.norm(p, axis=1))[:, None]
    valid = np.isfinite(xyz).all(axis=2)
    st = bench.see_through_pixels(xyz, valid, model, T, intrinsics=K_TEST, sigma_mm=0.05, k=3.0, floor_mm=0.1)
    share, sil = see_through_share(xyz, valid, model, T, intrinsics=K_TEST, sigma_mm=0.05, k=3.0, floor_mm=0.1)
    assert st["share"] == share and st["silhouette"] == sil and 0.05 < share < 0.3
    assert set(zip(st["rows"][st["behind"]].tolist(), st["cols"][st["behind"]].tolist())) <= set(
        zip(*np.nonzero(back)))
    edges = bench.depth_edges(xyz, valid, K_TEST[0])
    r = bench.rule_shares(st, edges)
    assert r["all"] == pytest.approx(share, abs=1e-4)
    assert set(r) == set(bench.RULES) and r["ring >= 3"] <= 1.0
    assert st["ring"].min() >= 0 and (st["ring"] >= 1).mean() > 0.9


def test_the_causes_first_that_applies(bench) -> None:  # type: ignore[no-untyped-def]
    from replay.logs import layout

    inter = next(c for c, n in layout.OUTLIER_KINDS.items() if n == "interreflection")
    got = bench.causes(np.array([1, 2, 3, 3, 3, 3, 3]), np.array([1, 0, 1, 0, 0, 0, 0], bool),
                       np.array([inter, 0, inter, inter, 0, 0, 0]),
                       np.array(["off every true surface", "on the instance itself", "on another instance",
                                 "on the bin or table", "on another instance", "on the bin or table",
                                 "on the instance itself"]))
    assert got.tolist() == ["rim (rings 1-2)", "rim (rings 1-2)", "inside, depth edge",
                            "inside, interreflection ghost", "inside, a surface beneath", "inside, a surface beneath",
                            "inside, other"]
