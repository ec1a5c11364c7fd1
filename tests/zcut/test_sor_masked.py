"""SOR with a mask (the replay's call: the zone's bounding box, only the zone's pixels valid) against the literal
brute-force reference on the NaN-masked copy and against Open3D, on fields with large invalid regions, single-pixel
runs, rows all invalid and all valid (round of 2026-12-07g, h/fps5: written for a lever on the rows' valid spans,
reverted; these cases stand on their own)."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest
from reference.sor_reference import mean_distances_reference, outliers_from_mean_distances_reference

from zcut import sor_outliers
from zcut.sor import sor_mean_distances

H, W = 40, 61


def _surface(seed: int) -> np.ndarray:
    """A wavy surface 0.5 m in front of a pinhole camera with a depth step and a few flying pixels."""
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    z = 0.5 + 0.02 * np.sin(u / 5.0) * np.cos(v / 7.0) + (u > W // 2) * 0.05
    z = z * (1 + rng.normal(0, 1e-3, z.shape))
    z = np.where(rng.random(z.shape) < 0.03, z + rng.normal(0, 0.05, z.shape), z)
    return np.stack([(u - W / 2) / 60.0 * z, (v - H / 2) / 60.0 * z, z], axis=-1)


def _mask(kind: str, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    if kind == "all valid":
        return np.ones((H, W), bool)
    if kind == "large invalid regions":  # two blobs in an empty box, 10-20 % of it
        v, u = np.mgrid[0:H, 0:W]
        return ((v - 12) ** 2 + (u - 15) ** 2 < 60) | ((v - 28) ** 2 / 2 + (u - 44) ** 2 < 70)
    if kind == "single-pixel runs":  # isolated pixels, every other one in a few rows
        m = rng.random((H, W)) < 0.15
        m[5, ::2] = True
        m[6] = False
        m[7, 1::2] = True
        return m
    if kind == "rows all invalid":  # a dense middle band with whole empty rows above, below and inside
        m = rng.random((H, W)) < 0.8
        m[:6] = False
        m[-5:] = False
        m[18:21] = False
        m[:, :3] = False
        return m
    raise AssertionError(kind)


KINDS = ["all valid", "large invalid regions", "single-pixel runs", "rows all invalid"]


def _open3d_outliers(xyz: np.ndarray, *, k: int) -> np.ndarray:
    valid = np.isfinite(xyz).all(axis=2)
    pts = np.ascontiguousarray(xyz[valid], dtype=np.float64)
    _, kept = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)).remove_statistical_outlier(nb_neighbors=k,
                                                                                                  std_ratio=1.0)
    keep = np.zeros(pts.shape[0], dtype=bool)
    keep[np.asarray(kept, dtype=np.int64)] = True
    out = np.zeros(valid.shape, dtype=bool)
    out[valid] = ~keep
    return out


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("convention", ["pcl", "open3d"])
def test_masked_sor_equals_the_references(kind: str, convention: str) -> None:
    # the masked call (spans from the mask) against the literal reference on the NaN-masked copy, and Open3D
    xyz = _surface(3)
    mask = _mask(kind, 5)
    nan_masked = np.where(mask[..., None], xyz, np.nan)
    dbar = mean_distances_reference(nan_masked, k=4, convention=convention)
    want = outliers_from_mean_distances_reference(dbar, k=4, std_ratio=1.0, convention=convention)
    got = sor_outliers(xyz, k=4, convention=convention, mask=mask)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(sor_outliers(nan_masked, k=4, convention=convention), want)
    assert np.array_equal(sor_mean_distances(xyz, k=4, convention=convention, mask=mask), dbar, equal_nan=True)
    if convention == "open3d":
        np.testing.assert_array_equal(got, _open3d_outliers(nan_masked, k=4))
    assert 0 < int(got.sum()) < int(mask.sum())


@pytest.mark.parametrize("kind", KINDS)
def test_masked_sor_on_a_float32_crop_of_a_frame(kind: str) -> None:
    # as the replay calls it: a strided float32 view of a larger frame (NaN around the crop), with the zone's mask
    xyz = _surface(4).astype(np.float32)
    mask = _mask(kind, 6)
    frame = np.full((H + 7, W + 9, 3), np.nan, np.float32)
    frame[3:3 + H, 5:5 + W] = xyz
    crop = frame[3:3 + H, 5:5 + W]
    assert not crop.flags.c_contiguous
    nan_masked = np.where(mask[..., None], xyz.astype(np.float64), np.nan)
    for convention in ("pcl", "open3d"):
        dbar = mean_distances_reference(nan_masked, k=4, convention=convention)
        want = outliers_from_mean_distances_reference(dbar, k=4, std_ratio=1.0, convention=convention)
        np.testing.assert_array_equal(sor_outliers(crop, k=4, convention=convention, mask=mask), want)
