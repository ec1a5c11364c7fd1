"""Candidate regions of the zone: 3-D connectivity across the organized grid, broken at depth jumps.

Two 4-neighbouring pixels of the zone join when their 3-D distance is at most ``jump_mm`` plus
``jump_px`` pixel footprints (z / f, the footprint at their depth): a part's visible surface is one
region, the depth discontinuity at its occluding edge separates it from what lies below.
"""

from __future__ import annotations

import numpy as np

__all__ = ["segment"]


def segment(xyz: np.ndarray, mask: np.ndarray, *, f_px: float, jump_mm: float, jump_px: float,
            min_px: int) -> list[np.ndarray]:
    """The regions of ``mask`` with at least ``min_px`` pixels, largest first.

    Parameters
    ----------
    xyz : (H, W, 3) float64 ndarray
        Camera frame, mm (finite wherever ``mask``).
    mask : (H, W) bool ndarray
    f_px : float
        Focal length (pixels) for the footprint z / f.

    Returns
    -------
    list of (n,) int64 ndarray
        Flat pixel indices of each region.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    H, W = mask.shape
    flat = np.flatnonzero(mask)
    if len(flat) < min_px:
        return []
    index = np.full(H * W, -1, np.int64)
    index[flat] = np.arange(len(flat))
    pts = xyz.reshape(-1, 3)
    rows: list[np.ndarray] = []
    cols: list[np.ndarray] = []
    for step, ok in ((1, (flat % W) < W - 1), (W, flat < (H - 1) * W)):
        a = flat[ok]
        b = a + step
        both = mask.reshape(-1)[b]
        a, b = a[both], b[both]
        d = np.linalg.norm(pts[a] - pts[b], axis=1)
        z = np.minimum(pts[a, 2], pts[b, 2])
        near = d <= jump_mm + jump_px * np.abs(z) / f_px
        rows.append(index[a[near]])
        cols.append(index[b[near]])
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
