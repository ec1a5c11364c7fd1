"""Closed-form fits of a sphere of known radius.

The algebraic fit is linear least squares: a point p on the sphere (centre c, radius r) satisfies
|p|² = 2 c·p + (r² − |c|²), linear in (c, r² − |c|²); exact on noise-free points of any cap. Its
centre then takes a few Gauss-Newton steps on the geometric residual |p − c| − R with the model's
radius R fixed (a partial cap constrains the centre better with the radius known).

Touching spheres share a region; the initial centre of each comes from normal votes: a point p with
outward unit normal n (estimated on the organized grid) votes for the centre p − R n; the densest
vote cluster is one sphere's centre.
"""

from __future__ import annotations

import numpy as np

__all__ = ["algebraic_sphere", "refine_sphere", "vote_centres"]


def algebraic_sphere(points: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre (3,), radius) of the least-squares algebraic sphere through ``points`` (n >= 4)."""
    p = np.asarray(points, np.float64)
    A = np.c_[2.0 * p, np.ones(len(p))]
    b = np.einsum("ij,ij->i", p, p)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    c = sol[:3]
    r2 = sol[3] + c @ c
    return c, float(np.sqrt(max(r2, 0.0)))


def refine_sphere(points: np.ndarray, centre: np.ndarray, radius: float, *, iterations: int = 5) -> np.ndarray:
    """Gauss-Newton on Σ (|p − c| − radius)² over the centre c, from ``centre``."""
    c = np.asarray(centre, np.float64).copy()
    p = np.asarray(points, np.float64)
    for _ in range(iterations):
        v = p - c
        d = np.linalg.norm(v, axis=1)
        ok = d > 1e-9
        if ok.sum() < 4:
            break
        J = -v[ok] / d[ok, None]
        r = d[ok] - radius
        step = np.linalg.solve(J.T @ J + 1e-12 * np.eye(3), -J.T @ r)
        c += step
        if np.abs(step).max() < 1e-9:
            break
    return c


def vote_centres(points: np.ndarray, normals: np.ndarray, radius: float, *, min_votes: int = 10,
                 max_centres: int = 64, max_votes: int = 400) -> list[np.ndarray]:
    """The vote clusters p − R n (``normals`` outward, NaN where unknown), densest first: each the
    median of the votes within R / 5 of the densest vote left; the votes within R of a chosen centre
    (its own sphere) are then removed. Stops when the densest cluster has fewer than ``min_votes``
    votes of an even subsample of at most ``max_votes`` (counting the votes near each vote grows with
    the square of their number: a sphere's votes all fall near its centre)."""
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
    # the densest alive vote first (the counts do not change, a vote only dies): the votes in order of
    # their counts, ties by index, the dead ones skipped
    for i in np.argsort(-counts, kind="stable"):
        if len(out) >= max_centres or counts[i] < min_votes:
            break
        if not alive[i]:
            continue
        near = np.asarray(tree.query_ball_point(votes[i], r), np.int64)
        near = near[alive[near]]
        if len(near) < min_votes:
            alive[i] = False
            continue
        c: np.ndarray = np.median(votes[near], axis=0)
        out.append(c)
        gone = tree.query_ball_point(c, radius)
        alive[gone] = False
        alive[i] = False
    return out
