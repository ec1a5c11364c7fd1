"""zcut.fits' shortcuts give the answers of the plain computations they replace (the previous code kept
here as the oracle): the lower bound that spares exact distances, the ray casts of the rays that meet
the model's box, the normals at a region's pixels, the vote clusters walked in order."""

from __future__ import annotations

import numpy as np
from fit_scenes import K_TEST, hex_nut_mesh, icosphere, pose, render, rotation

from zcut.fits import prepare_model


def _grid_normals_reference(xyz: np.ndarray, step: int = 2) -> np.ndarray:
    """The previous whole-frame normals (before they were computed at a region's pixels only)."""
    H, W = xyz.shape[:2]
    n = np.full((H, W, 3), np.nan)
    s = step
    dx = xyz[s:-s, 2 * s:] - xyz[s:-s, : -2 * s]
    dy = xyz[2 * s:, s:-s] - xyz[: -2 * s, s:-s]
    c = np.cross(dx, dy)
    norm = np.linalg.norm(c, axis=2, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = c / norm
    p = xyz[s:-s, s:-s]
    flip = np.einsum("ijk,ijk->ij", c, p) > 0
    c[flip] = -c[flip]
    n[s:-s, s:-s] = c
    return n


def _vote_centres_reference(points: np.ndarray, normals: np.ndarray, radius: float, *, min_votes: int,
                            max_votes: int, max_centres: int = 64) -> list[np.ndarray]:
    """The previous loop: an argmax over the alive votes at each step."""
    from scipy.spatial import cKDTree

    ok = np.isfinite(normals).all(axis=1)
    votes = points[ok] - radius * normals[ok]
    if len(votes) < 4:
        return []
    step = max(1, len(votes) // max_votes)
    votes = votes[::step]
    min_votes = max(3, int(np.ceil(min_votes / step)))
    r = 0.2 * radius
    tree = cKDTree(votes)
    counts = np.asarray(tree.query_ball_point(votes, r, return_length=True))
    alive = np.ones(len(votes), bool)
    out: list[np.ndarray] = []
    while alive.any() and len(out) < max_centres:
        i = int(np.argmax(np.where(alive, counts, -1)))
        if counts[i] < min_votes:
            break
        near = [j for j in tree.query_ball_point(votes[i], r) if alive[j]]
        if len(near) < min_votes:
            alive[i] = False
            continue
        c: np.ndarray = np.median(votes[near], axis=0)
        out.append(c)
        alive[tree.query_ball_point(c, radius)] = False
        alive[i] = False
    return out


def _nut_scene() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    v, t = hex_nut_mesh()
    T = pose(rotation((1, 0.3, 0), 25), (2.0, -1.0, 300.0))
    T2 = pose(rotation((0, 1, 0.2), 140), (-20.0, 12.0, 310.0))
    xyz, ids = render([(v, t, T), (v, t, T2)], floor_z_mm=330)
    return v, t, T, xyz, ids


def test_the_lower_bound_spares_only_points_farther_than_the_tolerance():
    """Every point whose exact distance is within the tolerance gets that exact distance; the others
    are inf or their exact distance: the same answer to d <= tol, on the part, beside it and far off."""
    from zcut.fits.fit import _near_distances

    v, t, T, xyz, ids = _nut_scene()
    model = prepare_model(v, t)
    rng = np.random.default_rng(3)
    pts = xyz[np.isfinite(xyz).all(axis=2)]
    pts = np.concatenate([pts, pts[rng.choice(len(pts), 3000)] + rng.normal(0, 1.0, (3000, 3)),
                          rng.uniform(-60, 60, (2000, 3)) + [0, 0, 300]])
    exact = model.distance((pts - T[:3, 3]) @ T[:3, :3])
    for tol in (0.3, 0.6, 1.5, 4.5):
        got = _near_distances(model, pts, T, tol)
        inside = exact <= tol
        assert inside.sum() > 100 and (~inside).sum() > 100
        assert np.array_equal(got[inside], exact[inside])
        assert np.all((got[~inside] == np.inf) | (got[~inside] == exact[~inside]))
        assert np.isinf(got).sum() > 0.3 * len(got)  # it spares something


def test_ray_depths_cast_only_the_rays_that_meet_the_box_and_answer_the_same():
    import open3d as o3d

    v, t = hex_nut_mesh()
    model = prepare_model(v, t)
    rng = np.random.default_rng(4)
    origin = np.array([3.0, -2.0, -300.0])
    target = rng.uniform(-25, 25, (20000, 3))
    target[:50, 0] = origin[0]  # rays in the x = const plane through the origin (a zero direction component)
    d = target - origin
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.broadcast_to(origin, d.shape).copy()
    got = model.ray_depths(o, d)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(t.astype(np.uint32)))
    want = scene.cast_rays(o3d.core.Tensor(np.c_[o, d].astype(np.float32)))["t_hit"].numpy().astype(np.float64)
    assert np.isfinite(want).sum() > 1000 and np.isinf(want).sum() > 1000
    assert np.array_equal(got, want)


def test_normals_at_a_regions_pixels_equal_the_whole_frame_normals():
    from zcut.fits.fit import _normals_at

    _, _, _, xyz, ids = _nut_scene()
    xyz = xyz.copy()
    xyz[100:110, 150:170] = np.nan  # a hole: its neighbours have no normal
    H, W = ids.shape
    want = _grid_normals_reference(xyz).reshape(-1, 3)
    flat = np.concatenate([np.flatnonzero(ids.reshape(-1) > 0), [0, 1, W - 1, H * W - 1, 2 * W + 1]])
    got = _normals_at(xyz, flat)
    assert np.isfinite(got).all(axis=1).sum() > 1000
    assert np.array_equal(got, want[flat], equal_nan=True)


def test_vote_centres_walked_in_order_equal_the_argmax_loop():
    from zcut.fits.fit import _normals_at
    from zcut.fits.sphere import vote_centres

    v, t = icosphere(10.0, 4)
    truths = [pose(np.eye(3), (x, y, 300.0)) for x, y in ((-21.0, 0.0), (0.0, 1.0), (20.5, -2.0), (5.0, 21.0))]
    xyz, ids = render([(v, t, T) for T in truths], K=K_TEST, floor_z_mm=320)
    flat = np.flatnonzero(ids.reshape(-1) > 0)
    pts = xyz.reshape(-1, 3)[flat]
    nrm = _normals_at(xyz, flat)
    for max_votes in (50, 400, 5000):
        got = vote_centres(pts, nrm, 10.0, min_votes=10, max_votes=max_votes)
        want = _vote_centres_reference(pts, nrm, 10.0, min_votes=10, max_votes=max_votes)
        assert len(got) == len(want) >= 4
        assert all(np.array_equal(a, b) for a, b in zip(got, want))
