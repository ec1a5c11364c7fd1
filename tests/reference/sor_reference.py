"""Obviously-correct SOR: all pairwise distances (O(n²) memory), numpy only. Small clouds only.

The arithmetic is the one SPEC §2 and zcut.sor fix: squared distance ((dx² + dy²) + dz²) in
float64 of query minus point, the m smallest summed in ascending order from 0.0, statistics summed
sequentially (np.cumsum) over the valid pixels in row-major order.
"""

from __future__ import annotations

import numpy as np


def mean_distances_reference(xyz: np.ndarray, *, k: int, convention: str) -> np.ndarray:
    """(H, W) d̄ (NaN on invalid pixels) by brute force; needs at least m valid points."""
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


def _seq_sum(a: np.ndarray) -> float:
    return float(np.cumsum(a)[-1]) if a.size else 0.0


def sor_outliers_reference(xyz: np.ndarray, *, k: int, std_ratio: float, convention: str) -> np.ndarray:
    """(H, W) bool outlier mask of SPEC §2 by brute force."""
    valid = np.isfinite(xyz).all(axis=2)
    n = int(valid.sum())
    out = np.zeros(valid.shape, dtype=bool)
    if n < k + 1:
        return out
    d = mean_distances_reference(xyz, k=k, convention=convention)[valid]
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
