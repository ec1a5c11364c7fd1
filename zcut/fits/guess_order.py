"""The order in which a region's initial guesses take the coarse search (``FitParams.order_guesses``).

Each guess is scored where it stands, before any ICP step, by the coarse search's own score (the share of the
points within the score's tolerance, less 0.01 × their mean clipped distance, plus half the share of the boundary
points on the model's sharp edges: :func:`zcut.fits.kernels.guess_score`); the guesses are then searched best
first, so that the search's early stop (``FitParams.stop_edge``) fires at fewer guesses. The coarse search still
keeps the best of the guesses it tried (docs/fits.md, round of 2026-12-06g).
"""

from __future__ import annotations

import numba
import numpy as np

from .kernels import guess_score

__all__ = ["guess_order"]


@numba.njit(cache=True, nogil=True)
def guess_order(points: np.ndarray, edge_points: np.ndarray, Rs: np.ndarray, ts: np.ndarray, tol: float,
                edge_tol: float, origin: np.ndarray, h: float, grid: np.ndarray, a: np.ndarray, b: np.ndarray,
                c: np.ndarray, n: np.ndarray, tri: np.ndarray, seg_grid: np.ndarray, p0: np.ndarray,
                p1: np.ndarray) -> np.ndarray:
    """(k,) int64: the indices of the guesses (``Rs`` (k, 3, 3), ``ts`` (k, 3)) by their score at the guess, best
    first, equal scores in their order (a stable sort)."""
    k = len(Rs)
    neg = np.empty(k)
    for i in range(k):
        inl, near, e_inl = guess_score(points, edge_points, Rs[i], ts[i], tol, edge_tol, origin, h, grid, a, b, c, n,
                                       tri, seg_grid, p0, p1)
        neg[i] = -(inl - 0.01 * near + (0.5 * e_inl if len(edge_points) else 0.0))
    out: np.ndarray = np.argsort(neg, kind="mergesort")
    return out
