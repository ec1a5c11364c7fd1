"""zcut.sliver_fits: the free-space share read on part of the silhouette (docs/labelling.md, "Twenty-first round") —
without its outer rings (``inset_px``) and without the scan's depth edges (``skip_edges``) — equals a literal
per-pixel reference; a sensor's ghosts at the silhouette's rim or at depth edges no longer refuse the true pose, and a
pose in free space (the floor seen through its middle) is still refused."""

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

from zcut.sliver_fits import EDGE_FOOTPRINTS, SliverParams, fit_slivers, see_through_share  # noqa: E402

FX, FY, CX, CY = K_TEST


@pytest.fixture(scope="module")
def nut():  # type: ignore[no-untyped-def]
    return sliver_scene.nut()


def _box(model, T, H: int, W: int) -> tuple[int, int, int, int]:  # type: ignore[no-untyped-def]
    """The rows and columns the posed model's vertices project to, 3 px wider (no ray outside it meets the model)."""
    v = model.vertices @ T[:3, :3].T + T[:3, 3]
    u, w = FX * v[:, 0] / v[:, 2] + CX, FY * v[:, 1] / v[:, 2] + CY
    return (max(int(w.min()) - 3, 0), min(int(w.max()) + 4, H), max(int(u.min()) - 3, 0), min(int(u.max()) + 4, W))


def _hits(model, T, dirs: np.ndarray) -> np.ndarray:  # type: ignore[no-untyped-def]
    """The model's first-hit distance along each camera ray (unit directions, camera frame)."""
    o = -T[:3, :3].T @ T[:3, 3]
    return np.asarray(model.ray_depths(np.repeat(o[None], len(dirs), axis=0), dirs @ T[:3, :3]))


def _silhouette(model, T, H: int, W: int) -> np.ndarray:  # type: ignore[no-untyped-def]
    """(H, W) bool: the pixels whose centre's ray meets the posed model."""
    r0, r1, c0, c1 = _box(model, T, H, W)
    out = np.zeros((H, W), bool)
    cells = [(r, c) for r in range(r0, r1) for c in range(c0, c1)]
    d = np.array([[(c - CX) / FX, (r - CY) / FY, 1.0] for r, c in cells])
    d /= np.linalg.norm(d, axis=1)[:, None]
    for (r, c), h in zip(cells, _hits(model, T, d)):
        out[r, c] = np.isfinite(h)
    return out


def _reference(xyz, valid, model, T, *, sigma, k, floor, inset, edges, sil):  # type: ignore[no-untyped-def]
    """The share by its definition, pixel by pixel: the valid pixels whose point's ray meets the posed model, less
    those within ``inset`` chessboard steps of a pixel outside ``sil`` (outside the image counts as outside), less
    (``edges``) those with a 4-neighbour invalid, outside the image or more than EDGE_FOOTPRINTS footprints off in
    z; of them, the share whose point lies more than k × Err behind the model's first hit."""
    H, W = valid.shape
    r0, r1, c0, c1 = _box(model, T, H, W)
    outside = [(r, c) for r in range(r0 - 1, r1 + 1) for c in range(c0 - 1, c1 + 1)
               if not (0 <= r < H and 0 <= c < W) or not sil[r, c]]
    out_r = np.array([p[0] for p in outside])
    out_c = np.array([p[1] for p in outside])
    cells = [(r, c) for r in range(r0, r1) for c in range(c0, c1) if valid[r, c]]
    pts = np.array([xyz[r, c] for r, c in cells], np.float64)
    hits = _hits(model, T, pts / np.linalg.norm(pts, axis=1)[:, None])
    n = behind = 0
    for (r, c), p, hit in zip(cells, pts, hits):
        rng = float(np.linalg.norm(p))
        if not np.isfinite(hit):
            continue
        if inset and np.maximum(np.abs(out_r - r), np.abs(out_c - c)).min() <= inset:
            continue
        if edges:
            z = p[2]
            nb = [(r, c + 1), (r, c - 1), (r + 1, c), (r - 1, c)]
            if any(not (0 <= a < H and 0 <= b < W) or not valid[a, b]
                   or abs(xyz[a, b, 2] - z) > EDGE_FOOTPRINTS * abs(z) / FX for a, b in nb):
                continue
        n += 1
        err = max(floor, np.sqrt(sigma ** 2 + (abs(p[2]) / FX) ** 2 / 2.0))
        behind += (rng - hit) > k * err
    return (behind / n if n else 0.0), n


def _ghosted(nut):  # type: ignore[no-untyped-def]
    """(xyz, valid, model, T, rim, holes' neighbours) of the nut at its true pose on the floor, with a sensor's ghosts:
    the silhouette's outermost ring pushed 5 mm back along the ray, and three invalid holes inside the silhouette
    whose 4-neighbours are pushed 5 mm back (ghosts at depth edges)."""
    v, t, model = nut
    T = true_pose()
    xyz, ids = render([(v, t, T)], floor_z_mm=FLOOR_Z)
    xyz = xyz.astype(np.float64)
    H, W = ids.shape
    sil = ids == 1
    inner = np.zeros_like(sil)
    inner[1:-1, 1:-1] = sil[1:-1, 1:-1] & sil[:-2, 1:-1] & sil[2:, 1:-1] & sil[1:-1, :-2] & sil[1:-1, 2:] \
        & sil[:-2, :-2] & sil[:-2, 2:] & sil[2:, :-2] & sil[2:, 2:]
    rim = sil & ~inner
    valid = np.isfinite(xyz).all(axis=2)

    def push(mask: np.ndarray, mm: float) -> None:
        p = xyz[mask]
        xyz[mask] = p * (1.0 + mm / np.linalg.norm(p, axis=1))[:, None]

    push(rim, 5.0)
    rows, cols = np.nonzero(inner)
    ring = np.zeros_like(sil)
    for i in np.linspace(0, len(rows) - 1, 5)[1:4].astype(int):
        r, c = rows[i], cols[i]
        xyz[r, c] = np.nan
        for a, b in ((r, c + 1), (r, c - 1), (r + 1, c), (r - 1, c)):
            ring[a, b] = True
    ring &= np.isfinite(xyz).all(axis=2)
    push(ring, 5.0)
    valid = np.isfinite(xyz).all(axis=2)
    return xyz, valid, model, T, rim, ring


@pytest.mark.parametrize(("inset", "edges"), [(0, False), (1, False), (2, False), (0, True), (2, True)])
def test_the_share_equals_its_literal_reference(nut, inset: int, edges: bool) -> None:  # type: ignore[no-untyped-def]
    xyz, valid, model, T, _, _ = _ghosted(nut)
    H, W = valid.shape
    sil = _silhouette(model, T, H, W)
    got = see_through_share(xyz, valid, model, T, intrinsics=K_TEST, sigma_mm=0.05, k=3.0, floor_mm=0.1,
                            inset_px=inset, skip_edges=edges)
    ref = _reference(xyz, valid, model, T, sigma=0.05, k=3.0, floor=0.1, inset=inset, edges=edges, sil=sil)
    assert got[1] == ref[1] and got[1] > 100
    assert got[0] == pytest.approx(ref[0], abs=1e-12)
    if inset == 0 and not edges:  # the default reading: the call without the new arguments, to the bit
        assert got == see_through_share(xyz, valid, model, T, intrinsics=K_TEST, sigma_mm=0.05, k=3.0, floor_mm=0.1)


def test_ghosts_at_the_rim_and_at_edges_refuse_the_true_pose_only_when_counted(nut) -> None:  # type: ignore[no-untyped-def]
    xyz, valid, model, T, rim, ring = _ghosted(nut)
    kw = dict(intrinsics=K_TEST, sigma_mm=0.05, k=3.0, floor_mm=0.1)
    whole, _ = see_through_share(xyz, valid, model, T, **kw)  # type: ignore[arg-type]
    assert whole > 0.05  # the true pose "seen through": the rim's ghosts
    rimless, _ = see_through_share(xyz, valid, model, T, inset_px=2, **kw)  # type: ignore[arg-type]
    assert 0.0 < rimless <= 0.05  # the holes' ghosts remain inside
    clean, n = see_through_share(xyz, valid, model, T, inset_px=2, skip_edges=True, **kw)  # type: ignore[arg-type]
    assert clean == 0.0 and n > 100


def test_a_pose_in_free_space_is_still_refused(nut) -> None:  # type: ignore[no-untyped-def]
    """The floating patch of test_sliver_fits.py: the floor seen through the posed nut's middle, not only its rim."""
    v, t, model = nut
    T = true_pose()
    xyz_part, ids = render([(v, t, T)], floor_z_mm=FLOOR_Z)
    xyz, _ = render([], floor_z_mm=FLOOR_Z)
    rows, cols = np.nonzero(ids == 1)
    r0, c0 = int(np.median(rows)), int(np.median(cols))
    patch = np.zeros(ids.shape, bool)
    patch[r0 - 5:r0 + 5, c0 - 5:c0 + 5] = True
    patch &= ids == 1
    xyz[patch] = xyz_part[patch]
    neighbour = pose(T[:3, :3], (-40.0, -20.0, 380.0))
    valid = np.isfinite(xyz).all(axis=2)
    strict = SliverParams(min_px=20, min_share=0.9, free_inset_px=2, free_skip_edges=True)
    assert fit_slivers(xyz, valid, patch, model, neighbour[None], sigma_mm=0.05, params=strict) == []
    loose = SliverParams(min_px=20, min_share=0.9, max_see_through=1.0, free_inset_px=2, free_skip_edges=True)
    got = fit_slivers(xyz, valid, patch, model, neighbour[None], sigma_mm=0.05, params=loose)
    assert len(got) == 1 and got[0].see_through > 0.5


def test_a_negative_inset_is_one_line() -> None:
    with pytest.raises(ValueError, match=r"^SliverParams\.free_inset_px must be at least 0, got -1$"):
        SliverParams(free_inset_px=-1)
