"""zcut.fits.kernels, round of 2026-12-06d (docs/fits.md, "Seventeenth round"): a
match computes its closest point only where its plane residual leaves its distance below the bound the caller asks
(``_match_within``); the ICP gates, the guesses' scores and the last refinement's band give the same answers as
with every closest point computed (``_match``, ``surface_distances``), to the bit. The ICP kernel against its
reference: test_fits_cost.py; the fits: test_fits_defaults.py's literal digests."""

from __future__ import annotations

import numpy as np
from fit_scenes import hex_nut_mesh, icosphere, pose, rotation

from zcut.fits import prepare_model
from zcut.fits.kernels import WITHIN, _match, _match_within, guess_score, surface_distances, window_band


def _models():  # type: ignore[no-untyped-def]
    v, t = hex_nut_mesh()
    box_v = np.array([[x, y, z] for x in (0, 40) for y in (0, 6) for z in (0, 6)], float)
    box_t = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                      [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return [prepare_model(v, t), prepare_model(box_v, box_t)]


def _near_surface(rng: np.random.Generator, model, count: int, spread: float) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Model-frame points about the model's surface samples, off by up to ``spread`` mm."""
    s = model.samples[rng.integers(0, len(model.samples), count)]
    return s + rng.normal(0, 1, s.shape) * rng.uniform(0, spread, (count, 1))


def test_a_match_within_a_bound_is_the_match_where_it_can_be_below_it():
    rng = np.random.default_rng(61)
    for model in _models():
        ix = model.index
        assert ix is not None
        inv_h, slack = 1.0 / ix.h, 0.8660254037844386 * ix.h
        skipped = computed = 0
        for q in _near_surface(rng, model, 4000, 6.0):
            want = _match(q[0], q[1], q[2], ix.origin, inv_h, slack, ix.tri_grid, ix.a, ix.b, ix.c, ix.n)
            for bound in (1e-3, 0.05, 0.3, 1.0, 3.0, 1e6):
                got = _match_within(q[0], q[1], q[2], ix.origin, inv_h, slack, ix.tri_grid, ix.a, ix.b, ix.c, ix.n,
                                    bound)
                assert got[0] == want[0]
                if got[1] == np.inf and want[1] != np.inf:  # skipped: farther than the bound, as the proof says
                    assert want[1] > bound and abs(want[2]) >= bound * WITHIN
                    skipped += 1
                else:
                    assert got == want
                    computed += 1
                # every test the callers make answers the same
                assert (got[1] < bound) == (want[1] < bound) and (got[1] <= bound) == (want[1] <= bound)
                assert min(got[1], bound) == min(want[1], bound)
        assert skipped > 1000 and computed > 1000


def _guess_score_reference(points, edge_points, R, t, tol, edge_tol, ix):  # type: ignore[no-untyped-def]
    """``guess_score`` as it was: every point's distance by ``surface_distances``, summed in order."""
    from zcut.fits.kernels import edge_distances

    d = surface_distances(points, R, t, ix.origin, ix.h, ix.tri_grid, ix.a, ix.b, ix.c, ix.n)
    inl = near = 0.0
    for x in d:
        if x <= tol:
            inl += 1.0
        near += min(float(x), tol) / tol
    e_inl = 1.0
    if len(edge_points):
        de = edge_distances(edge_points, R, t, ix.origin, ix.h, ix.seg_grid, ix.p0, ix.p1)
        e_inl = 0.0
        for x in de:
            if x <= edge_tol:
                e_inl += 1.0
        e_inl /= len(de)
    m = max(len(d), 1)
    return inl / m, near / m, e_inl


def test_the_guess_scores_are_the_scores_of_every_distance():
    rng = np.random.default_rng(62)
    for model in _models():
        ix = model.index
        assert ix is not None
        for _ in range(60):
            T = pose(rotation(tuple(rng.normal(size=3)), float(rng.uniform(0, 180))),
                     (float(rng.normal(0, 20)), float(rng.normal(0, 20)), float(rng.uniform(200, 500))))
            pts = _near_surface(rng, model, int(rng.integers(0, 300)), float(rng.choice([0.1, 1.0, 5.0])))
            # camera frame; a guess off the truth by a turn and a shift
            cam = np.ascontiguousarray(pts @ T[:3, :3].T + T[:3, 3])
            edge = np.ascontiguousarray(cam[: len(cam) // 3])
            G = T @ pose(rotation(tuple(rng.normal(size=3)), float(rng.uniform(0, 30))), tuple(rng.normal(0, 2, 3)))
            R, t = np.ascontiguousarray(G[:3, :3]), np.ascontiguousarray(G[:3, 3])
            for tol in (0.05, 0.3, 2.0):
                args = (cam, edge, R, t, tol, 0.4, ix.origin, ix.h, ix.tri_grid, ix.a, ix.b, ix.c, ix.n, ix.seg_grid,
                        ix.p0, ix.p1)
                assert guess_score(*args) == _guess_score_reference(cam, edge, R, t, tol, 0.4, ix)


def test_the_band_is_the_points_within_the_tolerance_by_every_distance():
    rng = np.random.default_rng(63)
    H, W = 60, 80
    for model in _models():
        ix = model.index
        assert ix is not None
        for _ in range(40):
            T = pose(rotation(tuple(rng.normal(size=3)), float(rng.uniform(0, 180))), (0.0, 0.0, 300.0))
            # a cloud whose points lie about the posed model (and some far off), some pixels out of the zone
            pts = _near_surface(rng, model, H * W, float(rng.choice([0.2, 2.0])))
            xyz = np.ascontiguousarray(pts @ T[:3, :3].T + T[:3, 3])
            zone = rng.random(H * W) < 0.8
            region = np.flatnonzero(zone & (rng.random(H * W) < 0.2))  # a region is zone pixels
            r0, c0 = int(rng.integers(0, H)), int(rng.integers(0, W))
            r1, c1 = int(rng.integers(r0, H + 1)), int(rng.integers(c0, W + 1))
            R, t = np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3])
            for tol in (0.1, 0.5, 3.0):
                got = window_band(xyz, zone, region, r0, r1, c0, c1, W, R, t, tol, ix.origin, ix.h, ix.tri_grid, ix.a,
                                  ix.b, ix.c, ix.n)
                rr, cc = np.mgrid[r0:r1, c0:c1]
                win = (rr * W + cc).reshape(-1)
                flat = np.union1d(region, win[zone[win]])
                d = surface_distances(xyz[flat], R, t, ix.origin, ix.h, ix.tri_grid, ix.a, ix.b, ix.c, ix.n)
                assert np.array_equal(got, xyz[flat][d <= tol])


def test_a_ball_model_has_no_index_and_is_untouched():
    # a sphere's fits use the closed form, not the index: nothing of this round reaches them
    v, t = icosphere(10.0)
    assert prepare_model(v, t).sphere_radius is not None
