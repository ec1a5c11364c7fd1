"""zcut.fits' shortcuts give the answers of the plain computations they replace (the previous code kept
here as the oracle): the lower bound that spares exact distances, the ray casts of the rays that meet
the model's box, the normals at a region's pixels, the vote clusters walked in order."""

from __future__ import annotations

import numpy as np
from fit_scenes import K_TEST, hex_nut_mesh, icosphere, pose, render, rotation
from prepared_models import prepared


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
    model = prepared(v, t)
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

    from zcut.ray_hits import mesh_hit_t

    v, t = hex_nut_mesh()
    model = prepared(v, t)
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
    res = scene.cast_rays(o3d.core.Tensor(np.c_[o, d].astype(np.float32)))
    want = np.empty(len(d))  # every ray cast, the hit's depth exact as ray_depths makes it (zcut.ray_hits)
    mesh_hit_t(res["t_hit"].numpy(), res["primitive_ids"].numpy(), o, d, v, t, want)
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


def _region(xyz: np.ndarray, ids: np.ndarray, which: int) -> np.ndarray:
    return xyz.reshape(-1, 3)[np.flatnonzero(ids.reshape(-1) == which)]


def test_coarse_search_in_one_call_equals_the_loop_over_the_guesses():
    """kernels.coarse_search gives the pose, score and winner of the previous Python loop (icp, then
    guess_score, per guess; the first of equal scores; the early stop) to the bit."""
    from zcut.fits.fit import _subsample
    from zcut.fits.icp import EDGE_WEAK, icp, initial_poses, initial_rotations
    from zcut.fits.kernels import coarse_search, guess_score

    v, t, T, xyz, ids = _nut_scene()
    model = prepared(v, t)
    ix = model.index
    assert ix is not None
    pts = _region(xyz, ids, 1)
    rng = np.random.default_rng(5)
    pts = pts + rng.normal(0, 0.05, pts.shape)  # noise: the scores differ between guesses
    coarse = np.ascontiguousarray(pts[_subsample(np.arange(len(pts)), 150)])
    edge = np.ascontiguousarray(coarse[::7] + 0.2)
    guesses = initial_poses(pts, initial_rotations(pts, model), model)
    assert len(guesses) >= 4
    opts = dict(gate_mm=4.0, k=3.0, floor_mm=0.1, edge_gate_mm=1.5)
    for stop_inl, stop_edge, e in ((2.0, 0.7, edge), (0.5, 0.0, edge), (2.0, 0.7, np.zeros((0, 3)))):
        best = None
        for i, T0 in enumerate(guesses):
            Tc, _, _ = icp(coarse, model, T0, iterations=4, edge_points=e, **opts)
            inl, near, e_inl = guess_score(coarse, e, np.ascontiguousarray(Tc[:3, :3]), np.ascontiguousarray(Tc[:3, 3]),
                                           1.0, 0.9, ix.origin, ix.h, ix.tri_grid, ix.a, ix.b, ix.c, ix.n, ix.tri,
                                           ix.seg_grid, ix.p0, ix.p1)
            score = inl - 0.01 * near + (0.5 * e_inl if len(e) else 0.0)
            if best is None or score > best[1]:
                best = (i, score, Tc)
            if inl >= stop_inl and e_inl >= stop_edge:
                break
        assert best is not None
        Ts = np.stack(guesses)
        i, R, tt, score = coarse_search(coarse, e, np.ascontiguousarray(Ts[:, :3, :3]), np.ascontiguousarray(Ts[:, :3, 3]),
                                        4, 4.0, 3.0, 0.1, 1.5, float(model.extent_mm), 1.0, 0.9, ix.origin, ix.h,
                                        ix.tri_grid, ix.a, ix.b, ix.c, ix.n, ix.tri, ix.seg_grid, ix.p0, ix.p1, EDGE_WEAK,
                                        stop_inl, stop_edge)
        assert i == best[0] and score == best[1]
        assert np.array_equal(R, best[2][:3, :3]) and np.array_equal(tt, best[2][:3, 3])


def test_the_slab_test_in_numba_equals_numpy():
    from zcut.fits.model import _box_hits, _box_hits_reference

    rng = np.random.default_rng(6)
    lo, hi = np.array([-10.0, -8.0, -3.0]), np.array([10.0, 8.0, 3.0])
    o = rng.uniform(-30, 30, (20000, 3))
    d = rng.normal(size=(20000, 3))
    d[:300, 0] = 0.0  # parallel to a slab, inside or outside it
    d[300:400, :2] = 0.0
    o[400:450, 2] = hi[2] + 0.01  # on a grown slab's plane, parallel to it: NaN, the slab left free
    d[400:450, 2] = 0.0
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    got = _box_hits(o, d, lo, hi)
    want = _box_hits_reference(o, d, lo, hi)
    assert want.sum() > 1000 and (~want).sum() > 1000
    assert np.array_equal(got, want)


def _support_reference(frame, T, model, tol, known=None):  # type: ignore[no-untyped-def]
    """The previous support: every ray of the window computed in NumPy and cast (through the box test)."""
    from zcut.fits.fit import _model_distance, _window

    win = _window(frame, T, model)
    if win is None:
        return 0.0
    fx, fy, cx, cy = frame.K
    rs, cs = win
    rr, cc = np.mgrid[rs, cs]
    d = np.stack([(cc - cx) / fx, (rr - cy) / fy, np.ones(rr.shape)], axis=-1).reshape(-1, 3)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    R, t = T[:3, :3], T[:3, 3]
    origin = np.broadcast_to(-R.T @ t, d.shape)
    hit = model.ray_depths(np.ascontiguousarray(origin), d @ R)
    predicted = np.isfinite(hit)
    if not predicted.any():
        return 0.0
    pts = frame.xyz[rs, cs].reshape(-1, 3)[predicted]
    pflat = (rr * frame.valid.shape[1] + cc).reshape(-1)[predicted]
    ok = np.isfinite(pts).all(axis=1)
    rng = np.full(len(pts), np.nan)
    rng[ok] = np.linalg.norm(pts[ok], axis=1)
    dist = np.full(len(pts), np.inf)
    dist[ok] = _model_distance(frame, T, model, pflat[ok], tol, known)
    supported = dist <= tol
    with np.errstate(invalid="ignore"):
        occluded = ok & (rng < hit[predicted] - tol) & ~supported
    denom = int((ok & ~occluded).sum())
    return float(supported.sum() / denom) if denom else 0.0


def test_the_support_casting_only_the_rays_near_the_box_equals_casting_the_window():
    """kernels.window_rays keeps every ray the ray casts' own box test keeps: the support is the same
    number, on the true poses, on poses moved off them and on a pose beside the image."""
    from zcut.fits.fit import _Frame, _support
    from zcut.fits.kernels import window_rays

    v, t, T, xyz, ids = _nut_scene()
    model = prepared(v, t)
    valid = np.isfinite(xyz).all(axis=2)
    frame = _Frame(xyz=xyz, valid=valid, zone=valid, K=K_TEST)
    rng = np.random.default_rng(7)
    T2 = pose(rotation((0, 1, 0.2), 140), (-20.0, 12.0, 310.0))
    poses = [T, T2, pose(rotation((0, 0, 1), 30), (150.0, 0.0, 300.0))]
    for _ in range(12):
        Tm = (T if rng.random() < 0.5 else T2).copy()
        Tm[:3, :3] = rotation(tuple(rng.normal(size=3)), rng.uniform(0, 40)) @ Tm[:3, :3]
        Tm[:3, 3] += rng.normal(0, 2.0, 3)
        poses.append(Tm)
    kept = []
    for Tp in poses:
        for tol in (0.3, 1.0):
            assert _support(frame, Tp, model, tol) == _support_reference(frame, Tp, model, tol)
        lo, hi = v.min(axis=0) - 0.05, v.max(axis=0) + 0.05
        rr, cc = window_rays(0, 240, 0, 320, *K_TEST, np.ascontiguousarray(Tp[:3, :3]), np.ascontiguousarray(Tp[:3, 3]),
                             lo, hi)
        kept.append(len(rr))
    assert 0 < max(kept) < 0.2 * 240 * 320  # it spares rays


def test_the_icp_kernel_equals_the_previous_kernel_to_the_bit():
    """The ninth round's kernel (normal matrices in scalars, the eigen-decomposition skipped when
    kernels._stiff proves no weak direction) gives the previous kernel's pose, rms and count to the bit
    (tests/zcut/fits/kernel_reference.py), from poses near and far, with and without the silhouette's
    points, on a nut seen near head-on (weak directions: the decomposition runs) and one turned away."""
    from kernel_reference import icp_kernel_reference

    from zcut.fits.fit import _Frame, _occluding_boundary
    from zcut.fits.icp import EDGE_WEAK
    from zcut.fits.kernels import _stiff, icp_kernel

    v, t, T, xyz, ids = _nut_scene()
    model = prepared(v, t)
    ix = model.index
    assert ix is not None
    rng = np.random.default_rng(11)
    noisy = xyz + rng.normal(0, 0.05, xyz.shape)
    valid = np.isfinite(noisy).all(axis=2)
    frame = _Frame(xyz=noisy, valid=valid, zone=valid & (ids > 0), K=K_TEST)
    T2 = pose(rotation((0, 1, 0.2), 140), (-20.0, 12.0, 310.0))
    checked = 0
    for which, Tt in ((1, T), (2, T2)):
        flat = np.flatnonzero((ids.reshape(-1) == which) & valid.reshape(-1))
        pts = np.ascontiguousarray(noisy.reshape(-1, 3)[flat])
        edge = np.ascontiguousarray(noisy.reshape(-1, 3)[_occluding_boundary(frame, flat, 1.5)])
        assert len(pts) > 200 and len(edge) > 20
        for e in (edge, np.zeros((0, 3))):
            for axis, deg, shift, its in (((0, 0, 1), 3, (0.3, -0.2, 0.1), 30), ((1, 0.2, 0), 12, (1.5, 1.0, -0.5), 30),
                                          ((0.3, 1, 0), 35, (3.0, -2.0, 1.0), 4), ((0, 0, 1), 0.5, (0, 0, 0), 30)):
                T0 = Tt @ pose(rotation(axis, deg), shift)
                args = (pts, np.ascontiguousarray(T0[:3, :3]), np.ascontiguousarray(T0[:3, 3]), its, 4.0, 3.0, 0.1, e,
                        1.5, float(model.extent_mm), ix.origin, ix.h, ix.tri_grid, ix.a, ix.b, ix.c, ix.n, ix.seg_grid,
                        ix.p0, ix.p1, EDGE_WEAK)
                got, want = icp_kernel(*args[:17], ix.tri, *args[17:]), icp_kernel_reference(*args)
                assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
                assert got[2] == want[2] or (np.isnan(got[2]) and np.isnan(want[2]))
                assert got[3] == want[3]
                checked += 1
    assert checked == 16
    # the proof it rests on: _stiff says yes only when LAPACK finds no eigenvalue below weak x the largest, and
    # it does say yes (a well-conditioned matrix) and no (a nearly singular one, a NaN)
    said = [0, 0]
    for i in range(3000):
        A = rng.normal(size=(6, 6 + i % 4)) * rng.uniform(0.01, 10, 6)[:, None]
        H = A @ A.T
        if i % 3 == 0:
            H[:, 5] *= 1e-3
            H[5, :] *= 1e-3
        ev = np.linalg.eigvalsh(H)
        s = _stiff(H, EDGE_WEAK)
        said[int(s)] += 1
        if s:
            assert ev.min() >= EDGE_WEAK * ev.max()
    assert said[0] > 100 and said[1] > 100
    assert not _stiff(np.full((6, 6), np.nan), EDGE_WEAK) and not _stiff(np.zeros((6, 6)), EDGE_WEAK)
    assert not _stiff(np.eye(6), 0.6)


def test_farthest_points_in_numba_equal_the_numpy_loop():
    """kernels.farthest_points gives the indices of the previous loop of zcut.fits.icp.shifted_poses (ties
    and repeated points included)."""
    from zcut.fits.kernels import farthest_points

    def reference(fs: np.ndarray, n: int) -> list[int]:
        sel = [0]
        dmin = np.linalg.norm(fs - fs[0], axis=1)
        for _ in range(min(n, len(fs)) - 1):
            j = int(np.argmax(dmin))
            sel.append(j)
            dmin = np.minimum(dmin, np.linalg.norm(fs - fs[j], axis=1))
        return sel

    rng = np.random.default_rng(2)
    for trial in range(2000):
        m = int(rng.integers(1, 120))
        fs = rng.normal(size=(m, 3)) * rng.uniform(0.1, 30)
        if trial % 3 == 0:
            fs = np.round(fs)  # ties and repeated points
        n = int(rng.integers(1, 9))
        assert list(farthest_points(np.ascontiguousarray(fs), min(n, m))) == reference(fs, n)


def test_the_percentile_test_by_counts_equals_numpy():
    """fit._percentile_above answers np.percentile(r, q) > thr, also at and one ulp off the percentile itself."""
    from zcut.fits.fit import _percentile_above

    rng = np.random.default_rng(4)
    for trial in range(5000):
        n = int(rng.integers(1, 400))
        r = rng.random(n) * 10
        if trial % 3 == 0:
            r = np.round(r, 1)
        p = float(np.percentile(r, 98))
        for thr in (p, float(np.nextafter(p, 0)), float(np.nextafter(p, 20)), float(rng.random() * 10)):
            assert _percentile_above(r, 98.0, thr) == bool(np.percentile(r, 98) > thr)


def test_the_occluding_boundary_on_the_regions_box_equals_the_whole_frame():
    """fit._occluding_boundary (the region's membership on its box) gives the previous whole-frame answer,
    regions at the frame's borders and corners included."""
    from zcut.fits.fit import _Frame, _occluding_boundary

    def reference(frame: _Frame, flat: np.ndarray, jump_mm: float) -> np.ndarray:
        H, W = frame.valid.shape
        inside = np.zeros(H * W, bool)
        inside[flat] = True
        z = frame.xyz[..., 2].reshape(-1)
        valid = frame.valid.reshape(-1)
        r, c = np.divmod(flat, W)
        edge = np.zeros(len(flat), bool)
        for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
            rr, cc = r + dr, c + dc
            ok = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
            nb = np.where(ok, rr * W + cc, 0)
            edge |= ok & ~inside[nb] & (~valid[nb] | (z[nb] > z[flat] + jump_mm))
        return flat[edge]

    rng = np.random.default_rng(6)
    H, W = 40, 56
    xyz = np.stack([rng.normal(size=(H, W)), rng.normal(size=(H, W)), 300 + rng.normal(0, 3, (H, W))], axis=-1)
    xyz[rng.random((H, W)) < 0.1] = np.nan
    valid = np.isfinite(xyz).all(axis=2)
    frame = _Frame(xyz=xyz, valid=valid, zone=valid, K=K_TEST)
    for trial in range(300):
        r0, c0 = int(rng.integers(0, H)), int(rng.integers(0, W))
        r1, c1 = int(rng.integers(r0, H)) + 1, int(rng.integers(c0, W)) + 1
        box = np.zeros((H, W), bool)
        box[r0:r1, c0:c1] = rng.random((r1 - r0, c1 - c0)) < (0.5 if trial % 2 else 1.0)
        flat = np.flatnonzero(box.reshape(-1) & valid.reshape(-1))
        assert np.array_equal(_occluding_boundary(frame, flat, 1.5), reference(frame, flat, 1.5))
