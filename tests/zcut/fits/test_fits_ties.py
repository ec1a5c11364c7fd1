"""zcut.fits: the choice among near-tied guesses (docs/fits.md, "The fits' choice among near-tied guesses"): every
guess whose coarse score lies within ``TIE_MARGIN`` of the best's (at most ``TIE_CANDIDATES``, distinct poses) is
refined, and the refined fit that explains the most of the region is kept — which of them is scored first no
longer decides."""

from __future__ import annotations

from typing import Any

import numpy as np
from fit_scenes import K_TEST, hex_nut_mesh, pose, render, rotation
from prepared_models import prepared

import zcut.fits.fit as F
import zcut.fits.params as P
from zcut.fits import FitParams, pose_error
from zcut.fits.kernels import coarse_scores, coarse_search

TRUE = pose(rotation((1, 0.3, 0), 25) @ rotation((0, 0, 1), 20), (4, -2, 300))


def _scene() -> tuple[F._Frame, np.ndarray, Any]:
    """A noisy nut on a floor: the frame, the nut's pixels (flat) and the model."""
    v, t = hex_nut_mesh()
    model = prepared(v, t)
    xyz, ids = render([(v, t, TRUE)], floor_z_mm=325)
    xyz = xyz + np.random.default_rng(3).normal(0, 0.05, xyz.shape)
    zone = ids == 1
    valid = np.isfinite(xyz).all(axis=2)
    frame = F._Frame(xyz=xyz, valid=valid, zone=zone & valid, K=K_TEST)
    return frame, np.flatnonzero(frame.zone.reshape(-1)), model


def test_coarse_scores_keeps_each_guess_as_coarse_search_gives_it():
    """kernels.coarse_scores: the winner, its pose and score of coarse_search to the bit, and each guess run the
    pose and score coarse_search gives that guess alone; the early stop at the same guess."""
    frame, flat, model = _scene()
    ix = model.index
    assert ix is not None
    pts = frame.xyz.reshape(-1, 3)[flat]
    coarse = np.ascontiguousarray(pts[F._subsample(np.arange(len(pts)), 150)])
    edge = np.ascontiguousarray(coarse[::7] + 0.2)
    Rs = np.stack(F.initial_rotations(pts, model))
    ts = F.guess_translations(pts, Rs, model)
    assert len(Rs) >= 4

    def args(R: np.ndarray, t: np.ndarray, stop: float) -> tuple[Any, ...]:
        return (coarse, edge, np.ascontiguousarray(R), np.ascontiguousarray(t), 4, 4.0, 3.0, 0.1, 1.5,
                float(model.extent_mm), 1.0, 0.9, ix.origin, ix.h, ix.tri_grid, ix.a, ix.b, ix.c, ix.n, ix.tri,
                ix.seg_grid, ix.p0, ix.p1, F.EDGE_WEAK, stop, 0.0)

    for stop in (2.0, 0.5):
        i, done, scores, Rk, tk = coarse_scores(*args(Rs, ts, stop))
        j, R, t, score = coarse_search(*args(Rs, ts, stop))
        assert i == j and scores[i] == score and np.array_equal(Rk[i], R) and np.array_equal(tk[i], t)
        assert (done == len(Rs)) == (stop > 1) and done >= 1
        for g in range(done):
            _, R1, t1, s1 = coarse_search(*args(Rs[g:g + 1], ts[g:g + 1], 2.0))
            assert scores[g] == s1 and np.array_equal(Rk[g], R1) and np.array_equal(tk[g], t1)


def test_same_pose_up_to_the_models_symmetries():
    _, _, model = _scene()
    assert len(model.symmetries) == 12
    for S in model.symmetries:
        assert F._same_pose(model, TRUE, TRUE @ pose(S, (0, 0, 0)))
    assert not F._same_pose(model, TRUE, TRUE @ pose(rotation((1, 0, 0), 10), (0, 0, 0)))
    assert not F._same_pose(model, TRUE, pose(TRUE[:3, :3], (4, -2, 302)))


def test_the_better_of_two_near_tied_guesses_wins_in_either_order(monkeypatch):  # type: ignore[no-untyped-def]
    """Two guesses — one 4° off the nut's pose, one turned 90° about its first axis — whose coarse scores are made
    equal (the coarse poses the real ones; no early stop): with one candidate (``TIE_CANDIDATES`` 1, main's search)
    the first decides, so the wrong one first gives a fit far off; with the near-tied ones refined, the same fit (to
    the bit) in either order, the one near the truth."""
    frame, flat, model = _scene()
    R_good = TRUE[:3, :3] @ rotation((0.2, 1, 0.4), 4.0)
    R_bad = TRUE[:3, :3] @ rotation((1, 0, 0), 90.0)
    real = F.coarse_scores

    def tied(*a: Any) -> Any:  # the real coarse poses, their scores made equal, no early stop
        _, done, scores, R, t = real(*a[:-2], 2.0, a[-1])
        scores[:done] = 1.0
        return 0, done, scores, R, t

    monkeypatch.setattr(F, "coarse_scores", tied)
    fits = {}
    for order in ((R_good, R_bad), (R_bad, R_good)):
        monkeypatch.setattr(F, "initial_rotations", lambda pts, model, axes=None, order=order: list(order))
        for k in (1, 2):
            monkeypatch.setattr(P, "TIE_CANDIDATES", k)
            fits[order[0] is R_good, k] = F._fit_general(frame, flat, model, FitParams())
    for good_first in (True, False):
        T, err = fits[good_first, 2]
        dt, da = pose_error(T, TRUE, model)
        assert dt < 0.5 and da < 2.0 and err < 0.2
    assert np.array_equal(fits[True, 2][0], fits[False, 2][0]) and fits[True, 2][1] == fits[False, 2][1]
    assert np.array_equal(fits[True, 1][0], fits[True, 2][0])  # the better one first: main's search keeps it too
    assert pose_error(fits[False, 1][0], TRUE, model)[1] > 20.0  # the wrong one first: main's search keeps its fit
