"""Obviously-correct SOR: all pairwise distances (O(n²), numpy only, small clouds) or, for the
benchmark's full-size clouds, scipy's KD-tree with every candidate re-measured.

The arithmetic is the one docs/filters.md and zcut.sor fix: squared distance ((dx² + dy²) + dz²) in
float64 of query minus point, the m smallest summed in ascending order from 0.0, statistics summed
sequentially (np.cumsum) over the valid pixels in row-major order.
"""

from __future__ import annotations

import numpy as np


def mean_distances_reference(xyz: np.ndarray, *, k: int, convention: str, method: str = "brute") -> np.ndarray:
    """(H, W) d̄ (NaN on invalid pixels) by brute force; needs at least m valid points.

    ``method="kdtree"``: the same by :func:`mean_distances_kdtree` (large clouds).
    """
    if method == "kdtree":
        return mean_distances_kdtree(xyz, k=k, convention=convention)
    assert method == "brute", method
    valid = np.isfinite(xyz).all(axis=2)
    p = xyz[valid].astype(np.float64)
    m = k + 1 if convention == "pcl" else k
    assert p.shape[0] >= m
    s = np.zeros(p.shape[0])
    for i0 in range(0, p.shape[0], 512):  # blocks of query rows keep the memory small
        q = p[i0:i0 + 512]
        d = q[:, None, :] - p[None, :, :]
        d2 = (d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]) + d[..., 2] * d[..., 2]
        if m < d2.shape[1]:
            d2 = np.partition(d2, m - 1, axis=1)[:, :m]
        d2.sort(axis=1)
        acc = np.zeros(q.shape[0])
        for j in range(m):
            acc = acc + np.sqrt(d2[:, j])
        s[i0:i0 + 512] = acc
    out = np.full(valid.shape, np.nan)
    out[valid] = s / k
    return out


def mean_distances_kdtree(xyz: np.ndarray, *, k: int, convention: str) -> np.ndarray:
    """(H, W) d̄ (NaN on invalid pixels) with scipy's KD-tree, exactly, also for heaps of duplicates.

    The valid points are deduplicated first (identical coordinates, identical distances). For
    every unique point, scipy finds the distance r of its m-th nearest unique point; every unique
    point within r·(1 + 1e-9) (scipy's own rounding is far below that) is re-measured in the definition's
    arithmetic, repeated as often as it occurs, and the m smallest are summed.
    """
    from scipy.spatial import cKDTree

    valid = np.isfinite(xyz).all(axis=2)
    p = np.ascontiguousarray(xyz[valid], dtype=np.float64)
    m = k + 1 if convention == "pcl" else k
    assert p.shape[0] >= m
    u, inverse, mult = np.unique(p, axis=0, return_inverse=True, return_counts=True)
    tree = cKDTree(u)
    kq = min(m, u.shape[0])
    dist, _ = tree.query(u, k=[kq], workers=-1)
    lists = tree.query_ball_point(u, dist[:, 0] * (1.0 + 1e-9) + 1e-300, workers=-1)
    counts = np.fromiter((len(a) for a in lists), dtype=np.int64, count=len(lists))
    cand = np.fromiter((i for a in lists for i in a), dtype=np.int64, count=int(counts.sum()))
    query = np.repeat(np.arange(u.shape[0]), counts)
    d = u[query] - u[cand]
    d2 = (d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2]
    order = np.lexsort((d2, query))  # by query, then ascending distance
    d2, rep = d2[order], mult[cand[order]]
    # the first m values of each query's candidates, each repeated by its multiplicity, summed one
    # at a time in ascending order from 0.0 (the candidates hold at least m points)
    pos = np.concatenate([[0], np.cumsum(counts)[:-1]])
    used = np.zeros(u.shape[0], dtype=np.int64)
    acc = np.zeros(u.shape[0])
    for _ in range(m):
        acc = acc + np.sqrt(d2[pos])
        used += 1
        step = used == rep[pos]
        pos = pos + step
        used[step] = 0
    out = np.full(valid.shape, np.nan)
    out[valid] = (acc / k)[inverse.ravel()]
    return out


def _seq_sum(a: np.ndarray) -> float:
    return float(np.cumsum(a)[-1]) if a.size else 0.0


def sor_outliers_reference(
    xyz: np.ndarray, *, k: int, std_ratio: float, convention: str, method: str = "brute"
) -> np.ndarray:
    """(H, W) bool outlier mask of docs/filters.md by brute force (or ``method="kdtree"``)."""
    valid = np.isfinite(xyz).all(axis=2)
    if int(valid.sum()) < k + 1:
        return np.zeros(valid.shape, dtype=bool)
    dbar = mean_distances_reference(xyz, k=k, convention=convention, method=method)
    return outliers_from_mean_distances_reference(dbar, k=k, std_ratio=std_ratio, convention=convention)


def outliers_from_mean_distances_reference(dbar: np.ndarray, *, k: int, std_ratio: float, convention: str) -> np.ndarray:
    """(H, W) bool outlier mask of docs/filters.md from d̄ (NaN = invalid pixel)."""
    valid = ~np.isnan(dbar)
    n = int(valid.sum())
    out = np.zeros(valid.shape, dtype=bool)
    if n < k + 1:
        return out
    d = dbar[valid]
    if convention == "pcl":
        mean = _seq_sum(d) / n
        std = np.sqrt(_seq_sum((d - mean) * (d - mean)) / (n - 1))
        out[valid] = d > mean + std_ratio * std
        return out
    pos = d > 0
    mean = _seq_sum(np.where(pos, d, 0.0)) / n  # Open3D: sum of the d̄ > 0 over the count of all
    std = np.sqrt(_seq_sum(np.where(pos, (d - mean) * (d - mean), 0.0)) / (n - 1))
    out[valid] = ~(pos & (d < mean + std_ratio * std))
    return out
