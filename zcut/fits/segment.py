"""Candidate regions of the zone: 3-D connectivity across the organized grid, broken at depth jumps.

Two 4-neighbouring pixels of the zone join when their 3-D distance is at most ``jump_mm`` plus
``jump_px`` pixel footprints (z / f, the footprint at their depth): a part's visible surface is one
region, the depth discontinuity at its occluding edge separates it from what lies below.
"""

from __future__ import annotations

import numba
import numpy as np

from zcut.components import find_root

__all__ = ["segment", "segment_reference"]


def segment(xyz: np.ndarray, flat: np.ndarray, *, f_px: float, jump_mm: float, jump_px: float,
            min_px: int) -> list[np.ndarray]:
    """The regions of the pixels ``flat`` with at least ``min_px`` pixels, largest first.

    Parameters
    ----------
    xyz : (H, W, 3) float64 ndarray
        Camera frame, mm (finite at ``flat``).
    flat : (n,) int64 ndarray
        Flat pixel indices (row-major) of the pixels to segment, sorted ascending and distinct (checked: other
        input, or indices off the grid, go the way of :func:`segment_reference`, whose answer it is).
    f_px : float
        Focal length (pixels) for the footprint z / f.

    Returns
    -------
    list of (k,) int64 ndarray
        Flat pixel indices of each region, sorted ascending.
    """
    H, W = xyz.shape[:2]
    flat = np.asarray(flat, np.int64)
    if len(flat) < min_px:
        return []
    if xyz.dtype != np.float64 or not _ascending_on_grid(flat, H * W):
        # the kernel's arithmetic is float64's, and it walks ``flat`` as a sorted set of the grid's pixels
        return segment_reference(xyz, flat, f_px=f_px, jump_mm=jump_mm, jump_px=jump_px, min_px=min_px)
    pts = np.ascontiguousarray(xyz.reshape(-1, 3))
    grouped, counts = _components(pts, np.ascontiguousarray(flat), H, W, float(jump_mm), float(jump_px),
                                  float(f_px))
    keep = np.flatnonzero(counts >= min_px)
    keep = keep[np.argsort(-counts[keep], kind="stable")]
    starts = np.concatenate([[0], np.cumsum(counts)])
    return [grouped[starts[k]:starts[k + 1]].copy() for k in keep]


def segment_reference(xyz: np.ndarray, flat: np.ndarray, *, f_px: float, jump_mm: float, jump_px: float,
                      min_px: int) -> list[np.ndarray]:
    """:func:`segment` through SciPy's connected components of the sparse graph of the joined neighbours (the
    rounds before 2026-12-06c): the reference the kernel is tested against."""
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


@numba.njit(cache=True, nogil=True)
def _ascending_on_grid(flat: np.ndarray, size: int) -> bool:
    """Whether ``flat`` is strictly ascending (sorted, distinct) within [0, ``size``): what
    :func:`_components` assumes of it."""
    n = len(flat)
    if n == 0:
        return True
    if flat[0] < 0 or flat[n - 1] >= size:
        return False
    for i in range(1, n):
        if flat[i] <= flat[i - 1]:
            return False
    return True


@numba.njit(cache=True, nogil=True)
def _components(pts: np.ndarray, flat: np.ndarray, H: int, W: int, jump_mm: float, jump_px: float,
                f_px: float) -> tuple[np.ndarray, np.ndarray]:
    """The connected components of :func:`segment`'s graph: (the pixels ``flat`` grouped by component, ascending
    within each, the components' sizes), the components numbered in the order of their first pixel — the order
    SciPy's ``connected_components`` numbers them in (it labels the nodes' components in node order).

    Two pixels of ``flat`` (sorted ascending, distinct) 4-neighbours on the (H, W) grid join when
    sqrt((dx² + dy²) + dz²) <= ``jump_mm`` + ``jump_px`` |min(za, zb)| / ``f_px``: the arithmetic of the NumPy
    test (``np.linalg.norm(pa - pb, axis=1)`` sums the squares in that order). A union-find whose root is the
    smallest index of its set; the right neighbour of ``flat[i]`` can only be ``flat[i + 1]``, the one below
    is found by a pointer walking ``flat`` once."""
    n = len(flat)
    parent = np.arange(n)
    last = (H - 1) * W
    j = 0
    for i in range(n):
        fa = flat[i]
        for step in range(2):
            if step == 0:
                if fa % W >= W - 1 or i + 1 >= n or flat[i + 1] != fa + 1:
                    continue
                k = i + 1
            else:
                if fa >= last:
                    continue
                fb = fa + W
                while j < n and flat[j] < fb:
                    j += 1
                if j >= n or flat[j] != fb:
                    continue
                k = j
            fb = flat[k]
            dx = pts[fa, 0] - pts[fb, 0]
            dy = pts[fa, 1] - pts[fb, 1]
            dz = pts[fa, 2] - pts[fb, 2]
            d = np.sqrt((dx * dx + dy * dy) + dz * dz)
            z = min(pts[fa, 2], pts[fb, 2])
            if d <= jump_mm + jump_px * abs(z) / f_px:
                ra = find_root(parent, i)
                rb = find_root(parent, k)
                if ra < rb:
                    parent[rb] = ra
                elif rb < ra:
                    parent[ra] = rb
    label = np.empty(n, np.int64)
    counts = np.zeros(n, np.int64)
    m = 0
    for i in range(n):
        r = find_root(parent, i)
        if r == i:
            label[i] = m
            m += 1
        else:
            label[i] = label[r]
        counts[label[i]] += 1
    starts = np.zeros(m + 1, np.int64)
    for c in range(m):
        starts[c + 1] = starts[c] + counts[c]
    grouped = np.empty(n, np.int64)
    for i in range(n):
        c = label[i]
        grouped[starts[c]] = flat[i]
        starts[c] += 1
    return grouped, counts[:m]
