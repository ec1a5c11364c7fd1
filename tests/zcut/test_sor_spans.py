"""SOR's statistics over each row's valid span only (zcut.sor._mean_std_spans, _outlier_masks_spans; round of
2026-12-07g): the same sums, masks and d̄ as over whole rows and as the literal references, on fields with large
invalid regions, single-pixel runs, rows all invalid and all valid."""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d
import pytest
from reference.sor_reference import mean_distances_reference, outliers_from_mean_distances_reference

import zcut.sor as sor_module
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


def _spans(valid: np.ndarray) -> np.ndarray:
    span = np.empty((valid.shape[0], 2), np.int64)
    for r, row in enumerate(valid):
        cols = np.flatnonzero(row)
        span[r] = (cols[0], cols[-1]) if cols.size else (valid.shape[1], -1)
    return span


def _literal(dbar: np.ndarray, valid: np.ndarray, n: float, open3d: bool) -> tuple[float, float]:
    terms = [float(d) for d, ok in zip(dbar.ravel(), valid.ravel(), strict=True) if ok and (not open3d or d > 0.0)]
    s = 0.0
    for t in terms:
        s = s + t
    mean = s / n
    sq = 0.0
    for t in terms:
        sq = sq + (t - mean) * (t - mean)
    return mean, math.sqrt(sq / (n - 1))


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("open3d", [False, True])
def test_statistics_over_spans_are_those_over_whole_rows(kind: str, open3d: bool) -> None:
    # d̄ over several decades with zeros; outside the valid pixels NaN, inf, -0.0 and garbage (never read or added)
    rng = np.random.default_rng(17 + open3d)
    valid = _mask(kind, 9)
    dbar = np.exp(rng.uniform(-12.0, 2.0, valid.shape))
    dbar[rng.random(valid.shape) < 0.1] = 0.0
    dbar = np.where(valid, dbar, rng.choice(np.array([np.nan, np.inf, -0.0, -1.0, 5e-324]), valid.shape))
    n = float(np.count_nonzero(valid))
    span = _spans(valid)
    ratios = np.array([0.5, 1.0, 2.5])
    got = np.array(sor_module._mean_std_spans(dbar, valid, span, n, open3d))
    whole = np.array(sor_module._mean_std(dbar, valid, n, open3d))
    want = np.array(_literal(dbar, valid, n, open3d))
    assert np.array_equal(got.view(np.uint64), want.view(np.uint64)), (got, want)
    assert np.array_equal(whole.view(np.uint64), want.view(np.uint64))
    masks = sor_module._outlier_masks_spans(dbar, valid, span, n, ratios, open3d)
    np.testing.assert_array_equal(masks, sor_module._outlier_masks(dbar, valid, n, ratios, open3d))
    assert masks.any() and not masks[:, ~valid].any()


def test_statistics_of_a_box_with_no_valid_row_in_part() -> None:
    # rows with first > last (W, -1) are passed by; a span narrower than the row reads only its columns
    valid = np.zeros((4, 9), bool)
    valid[1, 3] = True
    valid[2, 2:7] = True
    dbar = np.full(valid.shape, np.nan)
    dbar[valid] = [0.5, 0.25, 1.0, 0.125, 2.0, 0.75]
    span = _spans(valid)
    assert span[0].tolist() == [9, -1] and span[3].tolist() == [9, -1]
    got = sor_module._mean_std_spans(dbar, valid, span, 6.0, False)
    assert got == _literal(dbar, valid, 6.0, False)
    masks = sor_module._outlier_masks_spans(dbar, valid, span, 6.0, np.array([0.5]), False)
    assert masks[0].tolist() == (valid & (dbar > got[0] + 0.5 * got[1])).tolist()
