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
        step, *_ = np.linalg.lstsq(J, -r, rcond=None)
        c += step
        if np.abs(step).max() < 1e-9:
            break
    return c


def vote_centres(points: np.ndarray, normals: np.ndarray, radius: float) -> np.ndarray | None:
    """The densest cluster of the votes p − R n (``normals`` outward, NaN where unknown): its mean,
    or None when no point has a normal."""
    from scipy.spatial import cKDTree

    ok = np.isfinite(normals).all(axis=1)
    if ok.sum() < 4:
        return None
    votes = points[ok] - radius * normals[ok]
    tree = cKDTree(votes)
    r = 0.2 * radius
    sub = votes[:: max(1, len(votes) // 400)]
    counts = np.array([len(x) for x in tree.query_ball_point(sub, r)])
    best = sub[int(np.argmax(counts))]
    near = votes[np.linalg.norm(votes - best, axis=1) <= r]
    centre: np.ndarray = np.median(near, axis=0)
    return centre
