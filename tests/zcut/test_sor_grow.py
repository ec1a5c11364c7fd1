"""The whole-row 5 × 5 stage of the window phase and the growing window it hands its pixels to
(``zcut.sor_window._row_stage`` with w = 2; written in the round of 2026-12-08a, h/sor20, for a lever on that
stage, reverted; these cases stand on their own) against the brute-force reference: tall parts on end (most pixels fail
the 3 × 3 proof, one in ten grows past the 5 × 5 window), with half of the pixels invalid at random, large invalid
regions, single-pixel runs, empty rows, and a strided float32 crop."""

from __future__ import annotations

import bank_clouds
import numpy as np
import pytest
from reference.sor_reference import mean_distances_reference, outliers_from_mean_distances_reference

import zcut.sor as sor_module
from zcut import sor_window
from zcut.sor import sor_mean_distances, sor_outliers

H, W = 40, 72
KINDS = ["steep", "half invalid", "large invalid regions", "single-pixel runs", "empty rows"]


def _cloud(kind: str, seed: int = 11) -> np.ndarray:
    rng = np.random.default_rng(seed)
    xyz = bank_clouds.steep(rng, H, W)
    if kind == "half invalid":
        xyz[rng.random((H, W)) < 0.5] = np.nan
    elif kind == "large invalid regions":
        v, u = np.mgrid[0:H, 0:W]
        xyz[((v - 12) ** 2 + (u - 20) ** 2 < 90) | ((v - 28) ** 2 / 3 + (u - 52) ** 2 < 80)] = np.nan
    elif kind == "single-pixel runs":
        xyz[rng.random((H, W)) < 0.6] = np.nan
        xyz[10, 1::2] = np.nan  # every other pixel of a row
        xyz[30, :] = np.nan
        xyz[30, 40] = xyz[31, 40]  # a row with one valid pixel (a copy of its neighbour's point)
    elif kind == "empty rows":
        xyz[:4] = np.nan
        xyz[20:23] = np.nan
        xyz[-3:] = np.nan
        xyz[:, :5] = np.nan
    else:
        assert kind == "steep", kind
    return xyz


def _mth_d2(xyz: np.ndarray, m: int) -> np.ndarray:
    """(H, W) the m-th smallest squared distance of every valid pixel to the valid points (itself included), by
    brute force in the reference's arithmetic; NaN where invalid."""
    valid = np.isfinite(xyz).all(axis=2)
    p = xyz[valid].astype(np.float64)
    out = np.empty(p.shape[0])
    for i0 in range(0, p.shape[0], 512):
        d = p[i0:i0 + 512, None, :] - p[None, :, :]
        d2 = (d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]) + d[..., 2] * d[..., 2]
        out[i0:i0 + 512] = np.partition(d2, m - 1, axis=1)[:, m - 1]
    res = np.full(valid.shape, np.nan)
    res[valid] = out
    return res


def _window_inputs(xyz: np.ndarray, k: int, convention: str, monkeypatch: pytest.MonkeyPatch) -> tuple:
    """The arguments zcut.sor hands window_rows for this cloud (captured from a call)."""
    seen: list[tuple] = []
    real = sor_window.window_rows

    def capture(r0, r1, *args):  # type: ignore[no-untyped-def]  # the kernel's arguments
        seen.append(tuple(a.copy() if isinstance(a, np.ndarray) else a for a in args))
        return real(r0, r1, *args)

    with monkeypatch.context() as mp:
        mp.setattr(sor_module._window, "window_rows", capture)
        mp.setattr(sor_module.nb.config, "NUMBA_NUM_THREADS", 1)
        sor_mean_distances(xyz, k=k, convention=convention)
    assert len(seen) == 1
    return seen[0]


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("convention", ["pcl", "open3d"])
@pytest.mark.parametrize("k", [4])
def test_the_whole_row_five_by_five_stage_and_its_growth_are_exact(kind: str, convention: str, k: int,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    # every row through the 5 x 5 stage (merge or not), with the window growing to 16 and held at 2: a pixel it
    # writes d̄ >= 0 for has the brute-force d̄ bit for bit; any other valid pixel carries minus an upper bound on
    # its m-th squared distance (or -inf); with merge, the values already there stay. The growth proves pixels
    # the 5 x 5 window alone leaves (the path is run).
    xyz = _cloud(kind)
    (x, y, z, valid, span, m, divisor, w0, wmax, use_cam, R, C, Q, floor, _dbar, _unproven,
     init) = _window_inputs(xyz, k, convention, monkeypatch)
    assert use_cam
    want = mean_distances_reference(xyz, k=k, convention=convention)
    mth = _mth_d2(xyz, m)
    buf = np.empty(sor_window.SCRATCH)
    best = np.empty(m)
    proven = {}
    for wm in (2, wmax):
        for merge in (False, True):
            d = np.full((H, W), np.nan)
            if merge:  # some pixels already decided by an earlier stage: kept as they are
                d[::3, ::2] = 1234.5
            for r in range(2, H - 2):
                sor_window._row_stage(buf, 2, r, x, y, z, valid, span[r, 0], span[r, 1], m, divisor, use_cam, R, C,
                                      Q, floor, (r + 16) // 32, d, merge, init, best, wm)
            inner = np.zeros((H, W), bool)
            inner[2:H - 2, 3:W - 3] = True
            for r in range(H):  # the columns the stage runs on: first valid .. last valid, within 3 .. W - 4
                if span[r, 0] > span[r, 1]:
                    inner[r] = False
                else:
                    inner[r, :span[r, 0]] = False
                    inner[r, span[r, 1] + 1:] = False
            kept = np.zeros((H, W), bool)
            if merge:
                kept[::3, ::2] = True
                assert np.all(d[kept & inner] == 1234.5)
            ours = inner & valid & ~kept
            good = ours & (d >= 0.0)
            np.testing.assert_array_equal(d[good], want[good])
            bad = ours & ~(d >= 0.0)
            assert np.all(-d[bad] >= mth[bad])
            if not merge:
                proven[wm] = good
    grown = proven[wmax] & ~proven[2]
    assert not np.any(proven[2] & ~proven[wmax])
    if kind == "steep":
        assert grown.sum() >= 20, int(grown.sum())


@pytest.mark.parametrize("kind", [*KINDS, "float32 strided"])
@pytest.mark.parametrize("convention", ["pcl", "open3d"])
def test_sor_of_tall_parts_equals_the_reference(kind: str, convention: str) -> None:
    # the whole call (window phase, growth, fallback) against the brute-force reference
    if kind == "float32 strided":  # a crop of a larger float32 frame, only a mask's pixels valid
        rng = np.random.default_rng(5)
        big = bank_clouds.steep(rng, H + 20, W + 30).astype(np.float32)
        xyz = big[7:7 + H, 11:11 + W]
        mask = rng.random((H, W)) < 0.7
        mask[15:30, 30:60] = False
        copy = np.where(mask[..., None], xyz.astype(np.float64), np.nan)
    else:
        xyz = _cloud(kind, seed=3)
        mask = None
        copy = xyz
    want = mean_distances_reference(copy, k=4, convention=convention)
    got = sor_mean_distances(xyz, k=4, convention=convention, mask=mask)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(sor_outliers(xyz, k=4, convention=convention, mask=mask),
                                  outliers_from_mean_distances_reference(want, k=4, std_ratio=1.0,
                                                                         convention=convention))
