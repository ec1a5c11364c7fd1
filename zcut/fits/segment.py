"""Candidate regions of the zone: 3-D connectivity across the organized grid, broken at depth jumps.

Two 4-neighbouring pixels of the zone join when their 3-D distance is at most ``jump_mm`` plus
``jump_px`` pixel footprints (z / f, the footprint at their depth): a part's visible surface is one
region, the depth discontinuity at its occluding edge separates it from what lies below.
"""

from __future__ import annotations

import numpy as np

__all__ = ["segment"]


def segment(xyz: np.ndarray, flat: np.ndarray, *, f_px: float, jump_mm: float, jump_px: float,
            min_px: int) -> list[np.ndarray]:
    """The regions of the pixels ``flat`` with at least ``min_px`` pixels, largest first.

    Parameters
    ----------
    xyz : (H, W, 3) float64 ndarray
        Camera frame, mm (finite at ``flat``).
    flat : (n,) int64 ndarray
        Flat pixel indices (row-major) of the pixels to segment, sorted ascending.
    f_px : float
        Focal length (pixels) for the footprint z / f.

    Returns
    -------
    list of (k,) int64 ndarray
        Flat pixel indices of each region, sorted ascending.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    H, W = xyz.shape[:2]
    flat = np.asarray(flat, np.int64)
    if len(flat) < min_px:
        return []
    pts = xyz.reshape(-1, 3)
    rows: list[np.ndarray] = []
    cols: list[np.ndarray] = []
    for step, ok in ((1, (flat % W) < W - 1), (W, flat < (H - 1) * W)):
        ia = np.flatnonzero(ok)
        b = flat[ia] + step
        ib = np.searchsorted(flat, b)
        ib = np.minimum(ib, len(flat) - 1)
        both = flat[ib] == b
        ia, ib = ia[both], ib[both]
        pa, pb = pts[flat[ia]], pts[flat[ib]]
        d = np.linalg.norm(pa - pb, axis=1)
        z = np.minimum(pa[:, 2], pb[:, 2])
        near = d <= jump_mm + jump_px * np.abs(z) / f_px
        rows.append(ia[near])
        cols.append(ib[near])
    r = np.concatenate(rows)
    c = np.concatenate(cols)
    g = coo_matrix((np.ones(len(r), np.int8), (r, c)), shape=(len(flat), len(flat)))
    n, lab = connected_components(g, directed=False)
    counts = np.bincount(lab, minlength=n)
    keep = np.flatnonzero(counts >= min_px)
    keep = keep[np.argsort(-counts[keep], kind="stable")]
    order = np.argsort(lab, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)])
    return [flat[order[starts[k]:starts[k + 1]]] for k in keep]
