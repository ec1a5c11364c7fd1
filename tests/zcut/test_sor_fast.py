"""zcut.sor reading only each row's valid runs (issue 32, item 7 and the SOR stage of a replay).

The kernels skip what holds no valid pixel: rows without one, columns outside a row's first and last
valid pixel, runs of more than ``sor_window._GAP`` invalid columns inside it (the row stages' chunks
start at a valid pixel), tiles without a valid pixel of the row (the block statistics), columns of
the column search no query can reach. The oracle is the one today's code was held to and equals
bit for bit (tests/reference/sor_reference.py: d̄ by brute force or by scipy's KD-tree with every
candidate re-measured, the masks from it; and Open3D itself for the ``open3d`` convention), on
inputs made to hit these paths: masks with gaps just below, at and above the gap and wider than a
chunk, isolated pixels, pixels on the borders; the project's hand-made frames of several kinds and
seeds with the pipeline's top-of-pile region; a small ray-traced frame; the real Kinect clouds; large
invalid regions with steep walls through the column search; degenerate inputs.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterator
from typing import Any

import bank_clouds
import numba
import numpy as np
import open3d as o3d
import pytest
from reference.sor_reference import mean_distances_reference, outliers_from_mean_distances_reference

import zcut.sor as sor_module
from zcut import sor_window
from zcut.sor import sor_mean_distances, sor_outliers
from zcut.sor_camera import plane_bound_at


def open3d_outliers(xyz: np.ndarray, *, k: int, std_ratio: float) -> np.ndarray:
    valid = np.isfinite(xyz).all(axis=2)
    pts = np.ascontiguousarray(xyz[valid], dtype=np.float64)
    _, kept = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)).remove_statistical_outlier(
        nb_neighbors=k, std_ratio=std_ratio)
    keep = np.zeros(pts.shape[0], dtype=bool)
    keep[np.asarray(kept, dtype=np.int64)] = True
    out = np.zeros(valid.shape, dtype=bool)
    out[valid] = ~keep
    return out


def masked_copy(xyz: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    return xyz if mask is None else np.where(mask[..., None], xyz, np.nan).astype(xyz.dtype)


#: The oracle's answers by the cloud's bytes, shape and dtype and the arguments (read-only): a cloud held to it
#: under several search settings (the tests below monkeypatch the search, never the oracle) is measured once.
_ORACLE: dict[tuple[object, ...], np.ndarray] = {}


def _oracle(what: str, copy: np.ndarray, **kw: Any) -> np.ndarray:
    """``mean_distances_reference`` (``what`` "dbar") or :func:`open3d_outliers` ("open3d") of ``copy``, once."""
    key = (what, hashlib.sha256(copy.tobytes()).hexdigest(), copy.shape, copy.dtype.str, *sorted(kw.items()))
    if key not in _ORACLE:
        out = mean_distances_reference(copy, **kw) if what == "dbar" else open3d_outliers(copy, **kw)
        out.setflags(write=False)
        _ORACLE[key] = out
    return _ORACLE[key]


@pytest.fixture(scope="module", autouse=True)
def _forget_the_oracle() -> Iterator[None]:
    yield
    _ORACLE.clear()


def assert_as_oracle(xyz: np.ndarray, mask: np.ndarray | None = None, *, ks=(4,), ratios=(1.0,),
                     conventions=("pcl", "open3d")) -> None:
    """d̄ and the masks of zcut.sor (with ``mask``, and on the NaN-masked copy) equal the oracle's."""
    copy = masked_copy(xyz, mask)
    n = int(np.isfinite(copy).all(axis=2).sum())
    method = "brute" if n <= 3000 else "kdtree"
    for k in ks:
        for convention in conventions:
            if n < k + 1:
                continue
            want = _oracle("dbar", copy, k=k, convention=convention, method=method)
            np.testing.assert_array_equal(sor_mean_distances(xyz, k=k, convention=convention, mask=mask), want)
            np.testing.assert_array_equal(sor_mean_distances(copy, k=k, convention=convention), want)
            for ratio in ratios:
                got = sor_outliers(xyz, k=k, std_ratio=ratio, convention=convention, mask=mask)
                np.testing.assert_array_equal(got, sor_outliers(copy, k=k, std_ratio=ratio, convention=convention))
                if convention == "open3d":
                    np.testing.assert_array_equal(got, _oracle("open3d", copy, k=k, std_ratio=ratio))
                else:  # sor_outliers_reference of the copy, its d̄ (want) computed once for every ratio
                    np.testing.assert_array_equal(
                        got, outliers_from_mean_distances_reference(want, k=k, std_ratio=ratio, convention="pcl"))


def camera(rng: np.random.Generator, h: int, w: int, *, f: float = 300.0) -> np.ndarray:
    """A camera cloud with bumps, a depth step and a few flying pixels (the window phase proves most)."""
    return bank_clouds.pinhole(rng, h, w, f=f, flying=0.01)


# ------------------------------------------------------------------------------------------------
# masks made to hit the row runs
# ------------------------------------------------------------------------------------------------
def gap_mask(h: int, w: int, gap: int, run: int) -> np.ndarray:
    """Runs of ``run`` valid columns separated by ``gap`` invalid ones, shifted by one every row."""
    c = np.arange(w)
    return np.stack([((c + r) % (run + gap)) < run for r in range(h)])


def mask_kinds(rng: np.random.Generator, h: int, w: int) -> dict[str, np.ndarray]:
    from scipy.ndimage import gaussian_filter

    G = sor_window._GAP
    field = gaussian_filter(rng.normal(size=(h, w)), 6.0)
    border = np.zeros((h, w), bool)
    border[:, [0, 1, w - 2, w - 1]] = True
    border[[0, 1, h - 2, h - 1], :] = True
    rows = np.zeros((h, w), bool)
    rows[::3] = True  # two empty rows between valid ones
    return {
        **{f"gap{g}": gap_mask(h, w, g, run) for g, run in ((G - 1, 3), (G, 1), (G + 1, 5), (G + 2, 2))},
        "wide": gap_mask(h, w, 3, sor_window.CH + 37),  # runs longer than a chunk
        "isolated": rng.random((h, w)) < 0.02,
        "blobs": field > np.quantile(field, 0.7),  # a top-of-pile-like region
        "border": border,
        "rows": rows,
        "right-edge": np.broadcast_to(np.arange(w) >= w - 3, (h, w)).copy(),
    }


@pytest.mark.parametrize(("kind", "dtype"), [("gap7", np.float32), ("gap8", np.float64), ("gap9", np.float32),
                                           ("gap10", np.float64), ("wide", np.float32), ("isolated", np.float64),
                                           ("blobs", np.float32), ("border", np.float64), ("rows", np.float32),
                                           ("right-edge", np.float64)])
def test_masks_with_gaps_runs_and_borders(kind: str, dtype) -> None:
    assert sor_window._GAP == 8  # the names above
    rng = np.random.default_rng(5150 + len(kind))
    w = 2 * sor_window.CH + 90 if kind == "wide" else 150
    xyz = bank_clouds.with_holes(rng, camera(rng, 36, w), 0.02).astype(dtype)
    mask = mask_kinds(rng, *xyz.shape[:2])[kind]
    sl = (slice(3, 34), slice(1, w - 2))  # a strided crop, as the pipeline's zone box
    assert_as_oracle(xyz[sl], mask[sl], ks=(1, 4, 9), ratios=(0.5, 1.0))


@pytest.mark.parametrize("seed", [3, 17])
def test_large_invalid_regions_and_steep_walls(seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    # blob-shaped holes over half of the image and tall parts on end (the bench's holes-walls and
    # steep classes, small); the column search, forced for every unproven pixel, fills only the
    # columns its queries can reach
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(seed)
    xyz = bank_clouds.steep(rng, 120, 200)
    field = gaussian_filter(rng.normal(size=xyz.shape[:2]), 5.0)
    xyz[field > np.quantile(field, 0.5)] = np.nan
    assert_as_oracle(xyz, ks=(4, 8))
    monkeypatch.setattr(sor_module, "_COLUMNS_MIN_SHARE", 1 << 40)
    monkeypatch.setattr(sor_module, "_COLUMNS_COST", 0.0)
    monkeypatch.setattr(sor_module, "_COLUMN_WIDTH", 0.05)
    assert_as_oracle(xyz, ks=(4,))
    assert_as_oracle(xyz, np.isfinite(xyz[..., 2]) & (xyz[..., 2] < 0.79), ks=(4,))


def relief_with_holes(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """A camera 1 m above a random height field: smooth bumps, flat-topped parts 40-200 mm tall with
    vertical walls (their wall pixels' image neighbours are far in 3D: the window grows ring by ring
    or gives up), blob-shaped and scattered invalid pixels; coordinates rounded to 1 mm so that
    distances tie (at the m-th one too)."""
    from scipy.ndimage import gaussian_filter

    f = 60.0
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    height = 0.02 * gaussian_filter(rng.normal(size=(h, w)), 3.0)
    for _ in range(int(rng.integers(3, 9))):
        r0, c0 = rng.integers(0, h), rng.integers(0, w)
        dr, dc = rng.integers(2, 10, size=2)
        height[max(0, r0 - dr):r0 + dr, max(0, c0 - dc):c0 + dc] = rng.uniform(0.04, 0.2)
    z = 1.0 - height
    xyz = np.round(np.stack([(u - w / 2) / f * z, (v - h / 2) / f * z, z], axis=-1) / 1e-3) * 1e-3
    field = gaussian_filter(rng.normal(size=(h, w)), 4.0)
    xyz[field > np.quantile(field, rng.uniform(0.5, 0.9))] = np.nan  # large invalid regions
    xyz[rng.random((h, w)) < rng.uniform(0.0, 0.3)] = np.nan  # and scattered ones
    return xyz


@pytest.mark.parametrize("seed", range(8))
def test_fuzz_relief_with_holes_and_ties(seed: int) -> None:
    # the growing window (ring by ring, its bound checked after each ring), the columns and the
    # tiles on what escapes the 3 x 3 and 5 x 5 windows; d̄ and masks equal the brute-force oracle,
    # ties included
    rng = np.random.default_rng(7000 + seed)
    xyz = relief_with_holes(rng, int(rng.integers(20, 48)), int(rng.integers(30, 62)))
    assert_as_oracle(xyz, ks=(1, 4, 8), ratios=(0.5, 1.0))


def test_slots_follow_m() -> None:
    # 4 slots while m - 1 <= 4 (k = 4 in both conventions), 8 up to m = 9; beyond, no row stage
    assert [len(sor_window.slots_for(m)) for m in range(1, 10)] == [4] * 5 + [8] * 4
    assert sor_window.first_window(9, 16) == 1 and sor_window.first_window(10, 16) == 2


@pytest.mark.parametrize("seed", [11, 12])
def test_five_by_five_hands_its_slots_to_the_growing_window(seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    # tall parts on end (the 5 x 5 window leaves their side pixels to the growing window), in a
    # band of rows with half of the pixels invalid (the whole-row 5 x 5 stage and the rows that go
    # straight to it) and a band without (the 5 x 5 stage over a list of pixels); k from 1 to 9
    # covers 4 and 8 slots in both conventions (m = k + 1 or k) and m = 10 (no row stage); with
    # the growing window capped at w = 2 (the hand-off gives up at once) and at w = 3
    rng = np.random.default_rng(seed)
    xyz = bank_clouds.steep(rng, 72, 90)
    xyz[:30][rng.random((30, 90)) < 0.5] = np.nan
    xyz[50:53, 10:80] = np.nan  # a large invalid region across the list rows
    assert_as_oracle(xyz, ks=(1, 3, 4, 5, 8, 9), ratios=(1.0,))
    for wmax in (2, 3):
        monkeypatch.setattr(sor_module, "_WINDOW_MAX", wmax)
        assert_as_oracle(xyz, ks=(4, 5), ratios=(1.0,))


# ------------------------------------------------------------------------------------------------
# the project's frames
# ------------------------------------------------------------------------------------------------
def top_of_pile(xyz: np.ndarray, share: float) -> np.ndarray:
    """The nearest ``share`` of the valid points (like the pipeline's ``sor.region = "top"``: the top
    of the pile, scattered over its box)."""
    ok = np.isfinite(xyz).all(axis=2)
    return ok & (xyz[..., 2] <= np.quantile(xyz[ok, 2], share))


@pytest.mark.parametrize(("kind", "seed"), [("zinc_nuts", 4), ("rods", 9), ("spheres", 23)])
def test_hand_made_frames_and_their_top(kind: str, seed: int) -> None:
    from replay.synth.synthesize import synthesize_frame

    xyz = np.asarray(synthesize_frame(kind=kind, seed=seed, size=(60, 96)).frame.xyz)
    assert_as_oracle(xyz, ks=(4,))
    top = top_of_pile(xyz, 0.3)
    assert 50 < top.sum() < np.isfinite(xyz).all(axis=2).sum()
    rows, cols = np.flatnonzero(top.any(axis=1)), np.flatnonzero(top.any(axis=0))
    sl = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))  # the zone box, as the pipeline crops it
    assert_as_oracle(xyz[sl], top[sl], ks=(4, 6))


def test_small_ray_traced_frame() -> None:
    from replay.synth.raytrace import synthesize_raytraced_frame

    xyz = np.asarray(synthesize_raytraced_frame(kind="spheres", seed=3, size=(60, 96), fill_mm=6.0).frame.xyz)
    assert np.isfinite(xyz).all(axis=2).sum() > 1000
    assert_as_oracle(xyz, ks=(4, 8))
    assert_as_oracle(xyz, top_of_pile(xyz, 0.3), ks=(4,))


@pytest.mark.parametrize("name", ["mosd_test16.pcd", "milk_cartoon_all_small_clorox.pcd"])
def test_real_kinect_clouds(real_data, name: str) -> None:
    cloud = o3d.io.read_point_cloud(str(real_data / name), remove_nan_points=False, remove_infinite_points=False)
    xyz = np.asarray(cloud.points).reshape(480, 640, 3)
    valid = np.isfinite(xyz).all(axis=2)
    # the whole frame in Open3D's convention, against Open3D
    np.testing.assert_array_equal(sor_outliers(xyz, k=4, convention="open3d"), open3d_outliers(xyz, k=4, std_ratio=1.0))
    # the nearest fifth of the scene as a mask on its box, both conventions
    near = valid & (xyz[..., 2] <= np.quantile(xyz[valid, 2], 0.2))
    rows, cols = np.flatnonzero(near.any(axis=1)), np.flatnonzero(near.any(axis=0))
    sl = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
    assert_as_oracle(xyz[sl], near[sl], ks=(4,))


# ------------------------------------------------------------------------------------------------
# degenerate inputs
# ------------------------------------------------------------------------------------------------
def all_points_mean(xyz: np.ndarray, convention: str) -> np.ndarray:
    """d̄ when there are fewer valid points than the search needs: over all of them (Open3D)."""
    valid = np.isfinite(xyz).all(axis=2)
    p = xyz[valid].astype(np.float64)
    n = p.shape[0]
    out = np.full(valid.shape, np.nan)
    vals = []
    for q in p:
        d = q - p
        d2 = np.sort((d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2])
        s = 0.0
        for v in d2:
            s += math.sqrt(v)
        vals.append(s / (n - 1 if convention == "pcl" else n) if (n - 1 if convention == "pcl" else n) else 0.0)
    out[valid] = vals
    return out


@pytest.mark.parametrize("convention", ["pcl", "open3d"])
def test_degenerate_inputs(convention: str) -> None:
    rng = np.random.default_rng(808)
    xyz = camera(rng, 30, 40)
    none = np.zeros((30, 40), bool)
    one = none.copy()
    one[29, 39] = True
    three = none.copy()
    three[[0, 15, 29], [0, 39, 20]] = True
    column = none.copy()
    column[:, 39] = True
    last_row = none.copy()
    last_row[29, :] = True
    for name, mask in (("all masked", none), ("one pixel", one), ("three", three)):
        for k in (1, 4, 12):  # k larger than the points for all but k = 1 with three
            if mask.sum() < k + 1:
                assert not sor_outliers(xyz, k=k, convention=convention, mask=mask).any(), name
            got = sor_mean_distances(xyz, k=k, convention=convention, mask=mask)
            if mask.sum() and mask.sum() < (k + 1 if convention == "pcl" else k):
                np.testing.assert_array_equal(got, all_points_mean(masked_copy(xyz, mask), convention))
            elif not mask.sum():
                assert np.isnan(got).all()
    for name, cloud in (("all NaN", np.full((20, 600, 3), np.nan, np.float32)),
                        ("all NaN but a corner", np.where(one[..., None], xyz, np.nan))):
        assert not sor_outliers(cloud, k=4, convention=convention).any(), name
    assert_as_oracle(xyz, column, ks=(1, 4, 12), conventions=(convention,))
    assert_as_oracle(xyz, last_row, ks=(1, 4, 12), conventions=(convention,))
    assert_as_oracle(xyz, three, ks=(1, 2), conventions=(convention,))
    for name, cloud in bank_clouds.degenerate_clouds().items():
        n = int(np.isfinite(cloud).all(axis=2).sum())
        if n >= 5:
            assert_as_oracle(cloud, ks=(4,), conventions=(convention,))
        else:
            assert not sor_outliers(cloud, k=4, convention=convention).any(), name


# ------------------------------------------------------------------------------------------------
# the 3 x 3 kernel: what is constant over a column band comes as scalars
# ------------------------------------------------------------------------------------------------
def _plane_bound(p: np.ndarray, q: np.ndarray) -> float:
    return max(p[0] * q[0] + p[1] * q[1] + p[2] * q[2] + p[3], 0.0) * sor_window.KEEP


@pytest.mark.parametrize("m", [2, 4, 5, 6, 7])  # 4 slots up to m = 5, 8 beyond
def test_three_by_three_kernel_against_a_literal_transcription(m: int) -> None:
    # _chunk_3x3 on a scratch buffer of random coordinates (some invalid, some duplicated) and
    # random planes, with the column band's planes below and above the window and the corner floor
    # as scalars: d̄ where the window is proven, NaN elsewhere, as a per-pixel loop computes it
    # (the strip bound the smallest of the four planes' bounds, the floor's bound, the count)
    rng = np.random.default_rng(40 + m)
    CH = sor_window.CH
    S, X, Y, Z, T = sor_window._S1, sor_window._X1, sor_window._Y1, sor_window._Z1, sor_window._T1
    n = CH - 3
    buf = np.full(sor_window.SCRATCH, np.nan)
    row, col = np.mgrid[0:3, 0:n + 2]
    pts = np.stack([0.01 * col, 0.01 * row, np.full((3, n + 2), 0.5)], axis=-1) + rng.uniform(0.0, 0.02, (3, n + 2, 3))
    pts[rng.random((3, n + 2)) < 0.05] = np.inf
    pts[1, 10:14] = pts[0, 10]  # duplicates: m distances of 0 for some m
    pts[2, 9:16] = pts[0, 10]
    for k in range(3):
        buf[X + k * S:X + k * S + n + 2] = pts[k, :, 0]
        buf[Y + k * S:Y + k * S + n + 2] = pts[k, :, 1]
        buf[Z + k * S:Z + k * S + n + 2] = pts[k, :, 2]

    def random_plane(q: np.ndarray) -> np.ndarray:  # a bound of 0.005 to 0.06 at q, larger or smaller nearby
        normal = rng.normal(size=3)
        normal /= np.linalg.norm(normal)
        return np.append(normal, -normal @ np.where(np.isfinite(q), q, 0.0) + rng.uniform(0.005, 0.06))

    right = np.array([random_plane(pts[1, i + 1]) for i in range(n)])
    left = np.array([random_plane(pts[1, i + 1]) for i in range(n)])
    for f in range(4):
        buf[T + f * CH:T + f * CH + n] = right[:, f]
        buf[T + (4 + f) * CH:T + (4 + f) * CH + n] = left[:, f]
    below = np.array([0.0, 0.0, 1.0, -0.5 + 0.01])  # bounds of 0.01 to 0.03: often the decisive ones
    above = np.array([0.0, 0.0, -1.0, 0.52 + 0.01])
    floor = 0.9
    divisor = float(m - 1)
    init = sor_window.slots_for(m)
    sor_window._chunk_3x3(buf, n, m, divisor, True, init, (*below, *above, floor))
    got = buf[T + 8 * CH:T + 8 * CH + n]
    want = np.full(n, np.nan)
    for i in range(n):
        q = pts[1, i + 1]
        if not q[0] < np.inf:
            continue
        nbrs = [pts[k, i + j] for k in range(3) for j in range(3) if (k, j) != (1, 1)]
        d2 = sorted(((q[0] - p[0]) * (q[0] - p[0]) + (q[1] - p[1]) * (q[1] - p[1])) + (q[2] - p[2]) * (q[2] - p[2])
                    for p in nbrs)
        count = 1 + sum(bool(p[0] < np.inf) for p in nbrs)
        if count < m:
            continue
        dm2 = d2[m - 2] if m >= 2 else 0.0
        sb = min(min(_plane_bound(right[i], q), _plane_bound(left[i], q)),
                 min(_plane_bound(below, q), _plane_bound(above, q)))
        if dm2 == 0.0 or (dm2 <= sb * sb * sor_window.KEEP and dm2 <= floor * floor * sor_window.KEEP):
            s = 0.0
            for v in d2[:m - 1]:
                s += math.sqrt(v)
            want[i] = s / divisor
    np.testing.assert_array_equal(got, want)
    assert np.count_nonzero(want > 0.0) >= 10 and np.count_nonzero(np.isnan(want)) >= 20  # both outcomes


# ------------------------------------------------------------------------------------------------
# the growing window grows in rows and columns separately
# ------------------------------------------------------------------------------------------------
def distorted(rng: np.random.Generator, h: int, w: int, *, k1: float) -> np.ndarray:
    """:func:`camera`'s surface seen through a lens with radial distortion k1: each pixel's ray is
    bent by (1 + k1 r²), so rows and columns curve across a band and weaken one of the two strip
    bounds (U near the left and right edges, V near the top and bottom), the case the separate
    half-widths of ``sor_window._grow_from`` are for."""
    return bent(bank_clouds.pinhole(rng, h, w, f=0.5 * max(h, w), flying=0.01), k1)  # r <= 1.2 at the corners


def bent(xyz: np.ndarray, k1: float) -> np.ndarray:
    """Every ray x / z, y / z of ``xyz`` times (1 + k1 r²), r² = (x / z)² + (y / z)²; NaN stays NaN."""
    z = xyz[..., 2]
    with np.errstate(invalid="ignore"):
        xn, yn = xyz[..., 0] / z, xyz[..., 1] / z
    bend = 1.0 + k1 * (xn * xn + yn * yn)
    return np.stack([xn * bend * z, yn * bend * z, z], axis=-1)


@pytest.mark.parametrize(("seed", "k1"), [(41, 0.05), (42, 0.15), (43, -0.08)])
def test_distorted_clouds_grow_in_rows_and_columns(seed: int, k1: float, monkeypatch: pytest.MonkeyPatch) -> None:
    # two frames of 3 x 4 bands: with barrel and pincushion distortion, a band of scattered invalid
    # pixels (the whole-row 5 x 5 stage hands its pixels on), a large invalid region and a depth step;
    # k = 1, 4, 6 (4 and 8 slots, m up to 7) in both conventions; the window capped at 3, 5 and 16
    # (a half-width that reaches the cap gives the pixel up to the columns and tiles)
    rng = np.random.default_rng(seed)
    xyz = distorted(rng, 150, 230, k1=k1)
    xyz[100:120][rng.random((20, 230)) < 0.5] = np.nan
    xyz[20:60, 150:200] = np.nan
    assert_as_oracle(xyz, ks=(1, 4, 6), ratios=(1.0, 2.0))
    for wmax in (3, 5):
        monkeypatch.setattr(sor_module, "_WINDOW_MAX", wmax)
        assert_as_oracle(xyz, ks=(4,), ratios=(1.0,))
    monkeypatch.undo()
    assert_as_oracle(bent(bank_clouds.steep(rng, 96, 140), 4.0 * k1), ks=(4,), ratios=(1.0,))  # tall parts on end


# ------------------------------------------------------------------------------------------------
# a distorted cloud's camera: the pinhole behind the lens (division model), not a plain DLT
# ------------------------------------------------------------------------------------------------
def _planes(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    valid = np.isfinite(xyz).all(axis=2)
    x, y, z = (np.where(valid, xyz[..., i], np.inf).astype(np.float64) for i in range(3))
    return x, y, z, valid


def _uv(P: np.ndarray, p: np.ndarray) -> np.ndarray:
    q = p @ P[:, :3].T + P[:, 3]
    return q[..., :2] / q[..., 2:]


def _parallax(P: np.ndarray, xyz: np.ndarray) -> float:
    """Median change of (U, V) when a point moves along its own ray (times 0.7 and 1.4), in units of
    the median U step from one column to the next: a camera whose centre is on the rays has none."""
    p = xyz[np.isfinite(xyz).all(axis=2)].astype(np.float64)
    move = np.abs(_uv(P, 1.4 * p) - _uv(P, 0.7 * p)).max(axis=1)
    uv = _uv(P, xyz.astype(np.float64))
    step = np.nanmedian(np.abs(np.diff(uv[..., 0], axis=1)))
    return float(np.median(move) / step)


def _plain_dlt(x: np.ndarray, y: np.ndarray, z: np.ndarray, valid: np.ndarray) -> np.ndarray:
    from zcut import sor_camera

    rr, cc = np.nonzero(valid)
    pick = np.linspace(0, rr.size - 1, 4096).astype(np.int64)
    normal, T, _, _ = sor_camera._dlt_normal_matrix(x, y, z, rr[pick], cc[pick])
    return np.linalg.eigh(normal)[1][:, 0].reshape(3, 4) @ T


@pytest.mark.parametrize(("seed", "k1"), [(44, 0.05), (45, 0.15), (46, -0.08)])
def test_a_distorted_cloud_is_fitted_with_the_pinhole_behind_its_lens(seed: int, k1: float,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    # a plain DLT fitted to a distorted cloud puts its centre off the rays (U and V change along a
    # ray: a pile's relief then loosens every band bound); the division model's pinhole keeps every
    # ray at one U and V. A pinhole cloud never tries the lens (same camera as the plain DLT).
    from zcut import sor_camera

    rng = np.random.default_rng(seed)
    xyz = distorted(rng, 150, 230, k1=k1)
    x, y, z, valid = _planes(xyz)
    P = sor_camera.fit_camera(x, y, z, valid)
    assert P is not None
    # (a point moved along its ray from 0.7 to 1.4 times its depth: 6-21 columns with a plain DLT,
    # 0.03-0.23 with the lens; the division model is not the cloud's polynomial one)
    assert _parallax(P, xyz) < 0.05 * _parallax(_plain_dlt(x, y, z, valid), xyz)

    def no_lens(*args: object) -> None:
        raise AssertionError("a pinhole cloud tried the division model")

    monkeypatch.setattr(sor_camera, "_fit_division", no_lens)
    pin = bank_clouds.pinhole(rng, 150, 230, f=115.0, flying=0.01)
    x, y, z, valid = _planes(pin)
    P = sor_camera.fit_camera(x, y, z, valid)
    assert P is not None and _parallax(P, pin) < 1e-6


@pytest.mark.parametrize("always", [False, True])
def test_the_division_model_camera_changes_no_distance(always: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    # d̄ and the masks against the oracle with the lens modelled on distorted clouds (and, with
    # ``always``, tried on every cloud: pinhole, quantized, tall parts on end, a large invalid region)
    from zcut import sor_camera

    rng = np.random.default_rng(20261206)
    if always:
        monkeypatch.setattr(sor_camera, "_DISTORTION_MIN_PX", -1.0)
    clouds = [distorted(rng, 120, 170, k1=0.1), bent(bank_clouds.steep(rng, 96, 140), 0.3)]
    if always:
        clouds += [bank_clouds.pinhole(rng, 90, 120), bank_clouds.quantized(rng, 60, 80),
                   bank_clouds.steep(rng, 80, 100)]
    clouds[0][30:80, 40:120] = np.nan
    if always:  # degenerate samples: one row, one column, a 4 x 4 patch, coincident points
        lens = distorted(rng, 60, 80, k1=0.1)
        flat = lens.copy()
        flat[..., 2] = 0.5
        clouds += [lens[30:31], lens[:, 40:41], lens[10:14, 10:14], np.repeat(lens[:1, :1], 30, axis=1), flat]
    for xyz in clouds:
        assert_as_oracle(xyz, ks=(1, 4), ratios=(1.0,))



# ------------------------------------------------------------------------------------------------
# _strips is its two halves, _strips_u and _strips_v, folded: bit for bit the four-term chain
# ------------------------------------------------------------------------------------------------
@numba.njit
def _strips_chain(r, c, w, H, W, b, bc, xq, yq, zq, R, C, terms):  # type: ignore[no-untyped-def]  # numba kernel
    # the four-term chain _strips was before it was folded, transcribed; terms := the four bounds
    # (NaN where the strip is outside the image)
    terms[:] = np.nan
    s = np.inf
    if c + w + 1 < W:
        terms[0] = plane_bound_at(R[b], 0, c + w + 1, xq, yq, zq)
        s = min(s, terms[0])
    if c - w - 1 >= 0:
        terms[1] = plane_bound_at(R[b], 4, c - w - 1, xq, yq, zq)
        s = min(s, terms[1])
    if r + w + 1 < H:
        terms[2] = plane_bound_at(C[bc], 0, r + w + 1, xq, yq, zq)
        s = min(s, terms[2])
    if r - w - 1 >= 0:
        terms[3] = plane_bound_at(C[bc], 4, r - w - 1, xq, yq, zq)
        s = min(s, terms[3])
    return s


@numba.njit
def _strips_both(rs, cs, ws, qs, R, C, H, W, b, bc, out, terms):  # type: ignore[no-untyped-def]  # numba kernel
    for i in range(rs.shape[0]):
        out[i, 0] = sor_window._strips(rs[i], cs[i], ws[i], H, W, b, bc, qs[i, 0], qs[i, 1], qs[i, 2], R, C)
        out[i, 1] = _strips_chain(rs[i], cs[i], ws[i], H, W, b, bc, qs[i, 0], qs[i, 1], qs[i, 2], R, C, terms[i])


def test_folded_strips_equal_the_four_term_chain_with_nan_and_signed_zero_bounds() -> None:
    # bound tables whose planes give NaN (0 * inf, inf - inf), +inf, 0.0 and -0.0 (a plane through
    # the query: numba's max(-0.0, 0.0) is -0.0) and ties between the U and the V bounds, at pixels
    # near every border (0 to 4 of the terms exist); the results compared as bit patterns
    rng = np.random.default_rng(20261205)
    H, W, b, bc = 24, 30, 1, 1
    special = np.array([np.nan, np.inf, -np.inf, 0.0, -0.0, 1.0, 0.5])
    n = 20_000
    rs, cs, ws = rng.integers(0, H, n), rng.integers(0, W, n), rng.integers(1, 17, n)
    qs = np.where(rng.random((n, 3)) < 0.5, rng.choice(np.array([0.0, -0.0, 1.0, 0.25, np.inf]), (n, 3)),
                  rng.uniform(-1.0, 1.0, (n, 3)))
    seen = {"nan term": 0, "-0.0 result": 0, "tie": 0, "no term": 0}
    for _ in range(4):  # fresh tables a round: random planes with special values sprinkled in
        R = rng.normal(size=(3, 8, W))
        C = rng.normal(size=(3, 8, H))
        for tab in (R, C):
            pick = rng.random(tab.shape) < 0.3
            tab[pick] = rng.choice(special, int(pick.sum()))
        C[bc, :, ::3] = 0.0  # planes 0 x + 0 y + 0 z + 0: a bound of -0.0 or 0.0, ties between U and V
        R[b, :, ::4] = 0.0
        C[bc, 3, ::3] = -0.0
        out, terms = np.empty((n, 2)), np.empty((n, 4))
        _strips_both(rs, cs, ws, qs, R, C, H, W, b, bc, out, terms)
        assert np.array_equal(out[:, 0].view(np.uint64), out[:, 1].view(np.uint64))
        exists = np.array([cs + ws + 1 < W, cs - ws - 1 >= 0, rs + ws + 1 < H, rs - ws - 1 >= 0]).T
        u = np.where(exists[:, :2], terms[:, :2], np.inf).min(axis=1)
        v = np.where(exists[:, 2:], terms[:, 2:], np.inf).min(axis=1)
        seen["nan term"] += int(np.count_nonzero((np.isnan(terms) & exists).any(axis=1)))
        seen["-0.0 result"] += int(np.count_nonzero((out[:, 0] == 0.0) & np.signbit(out[:, 0])))
        seen["tie"] += int(np.count_nonzero((u == v) & np.isfinite(u)))
        seen["no term"] += int(np.count_nonzero(~exists.any(axis=1)))
    assert min(seen.values()) >= 20, seen  # every case the fold could differ on was driven


# ------------------------------------------------------------------------------------------------
# the statistics: two sequential sums in row-major order, gathered a row at a time
# ------------------------------------------------------------------------------------------------

def _literal_sums(dbar: np.ndarray, valid: np.ndarray, n: float, open3d: bool) -> tuple[list[float], float, float, float]:
    """The literal loop of ``_mean_std``'s sums over the summed values only, in raster order: (terms, sum, mean,
    sum of squared deviations)."""
    terms = [float(d) for d, ok in zip(dbar.ravel(), valid.ravel()) if ok and (not open3d or d > 0.0)]
    s = 0.0
    for t in terms:
        s = s + t
    mean = s / n
    sq = 0.0
    for t in terms:
        sq = sq + (t - mean) * (t - mean)
    return terms, s, mean, sq

@pytest.mark.parametrize("open3d", [False, True])
@pytest.mark.parametrize("shape", [(1, 2), (1, 9), (9, 1), (37, 53), (120, 301)])  # n >= 2 (callers: n >= k + 1)
def test_outlier_masks_sum_in_row_major_order(open3d: bool, shape: tuple[int, int]) -> None:
    # random d̄ over several decades (so the order of the additions shows in the last bits), with
    # zeros (open3d leaves them out of its sums), invalid pixels holding NaN, +inf, negatives or
    # garbage, whole invalid rows and a fully valid one; against a literal loop
    rng = np.random.default_rng(7 + sum(shape) + open3d)
    H, W = shape
    dbar = np.exp(rng.uniform(-12.0, 2.0, shape))
    dbar[rng.random(shape) < 0.1] = 0.0
    valid = rng.random(shape) < 0.6
    valid[H // 3] = False
    valid[-1] = True
    junk = rng.choice(np.array([np.nan, np.inf, -1.0, 5.0]), shape)
    dbar = np.where(valid, dbar, junk)
    n = float(np.count_nonzero(valid))
    ratios = np.array([0.25, 1.0, 3.0])
    got = sor_module._outlier_masks(dbar, valid, n, ratios, open3d)
    got_mean, got_std = sor_module._mean_std(dbar, valid, n, open3d)
    terms, s, mean, sq = _literal_sums(dbar, valid, n, open3d)
    std = math.sqrt(sq / (n - 1))
    assert (got_mean, got_std) == (mean, std)  # bit for bit (no NaN here: n >= 2, finite terms)
    if len(terms) > 1000:  # another order of the same additions would show
        assert float(np.sum(terms)) != s
    with np.errstate(invalid="ignore"):
        for i, ratio in enumerate(ratios):
            thr = mean + ratio * std
            want = valid & ~((dbar > 0.0) & (dbar < thr)) if open3d else valid & (dbar > thr)
            np.testing.assert_array_equal(got[i], want)


@pytest.mark.parametrize("open3d", [False, True])
@pytest.mark.parametrize("case", ["overflow", "inf term", "nan term", "signed zeros", "no term", "subnormal"])
def test_mean_std_adds_nothing_for_the_pixels_it_skips(open3d: bool, case: str) -> None:
    # _mean_std adds +0.0 for every pixel it does not sum (branch-free): the sums must still be
    # those of the literal loop over the summed values only, bit for bit, where a skipped +0.0
    # could show: an accumulator that overflows to inf (a mean of inf: (mean - mean)² would be
    # NaN), inf and NaN terms (sor_outliers_from_distances takes any d̄), -0.0 and +0.0 terms,
    # no summed term at all, subnormal terms; skipped pixels hold NaN, inf, -0.0 or subnormals
    rng = np.random.default_rng(11)
    shape = (23, 41)
    dbar = np.exp(rng.uniform(-5.0, 2.0, shape))
    valid = rng.random(shape) < 0.5
    if case == "overflow":
        dbar[valid] = 1.5e308
    elif case == "inf term":
        dbar[3, valid[3]] = np.inf
    elif case == "nan term":
        dbar[5, valid[5]] = np.nan
    elif case == "signed zeros":
        dbar[rng.random(shape) < 0.5] = -0.0
        dbar[rng.random(shape) < 0.3] = 0.0
    elif case == "no term":
        dbar[:] = 0.0 if open3d else dbar
        valid[:] = valid if open3d else False
    else:
        dbar[rng.random(shape) < 0.5] = 5e-324
    junk = rng.choice(np.array([np.nan, np.inf, -0.0, 5e-324]), shape)
    dbar = np.where(valid, dbar, junk)
    n = float(max(np.count_nonzero(valid), 2))
    terms, s, mean, sq = _literal_sums(dbar, valid, n, open3d)
    with np.errstate(invalid="ignore", over="ignore"):
        std = math.sqrt(sq / (n - 1)) if not sq < 0.0 else math.nan
    got = np.array(sor_module._mean_std(dbar, valid, n, open3d))
    want = np.array([mean, std])
    assert np.array_equal(got.view(np.uint64), want.view(np.uint64)), (got, want)


# ------------------------------------------------------------------------------------------------
# the column stage's range from the tiles' boxes, the KD-tree built on a copy (round of 2026-12-06e)
# ------------------------------------------------------------------------------------------------
def _tile_boxes(xyz: np.ndarray, mask: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """x, y, z, valid and the tiles' boxes of a call (``_prepare``, then ``block_rows`` without a camera)."""
    from zcut import sor_camera
    from zcut.sor_workspace import SorWorkspace

    ws = SorWorkspace(max_bytes=0)
    run = lambda kernel, n, *args: kernel(0, n, *args) if n else None  # noqa: E731 - the serial runner
    x, y, z, valid, _, span = sor_module._prepare(xyz, run, ws, mask)
    stats = sor_camera.new_stats(*valid.shape)
    sor_camera.block_rows(0, stats[0].shape[0], x, y, z, valid, span, np.zeros((3, 4)), 1.0, False, *stats)
    return x, y, z, valid, stats[3]


@pytest.mark.parametrize("kind", ["steep-holes", "masked-crop", "negative", "signed-zeros", "one-row", "one-valid",
                                  "all-nan", "single"])
def test_the_tiles_boxes_give_the_valid_range(kind: str) -> None:
    # the column stage takes the smallest and largest x, y, z of the valid pixels from the tiles'
    # boxes (no pass over the frame): the values of the pass it replaced, sor_search.valid_range,
    # with or without a mask, on blob-shaped holes over half of the image, and when nothing is valid
    from scipy.ndimage import gaussian_filter

    from zcut.sor_search import valid_range

    rng = np.random.default_rng(64 + len(kind))
    mask = None
    if kind in ("steep-holes", "masked-crop"):
        xyz = bank_clouds.steep(rng, 75, 133)
        field = gaussian_filter(rng.normal(size=xyz.shape[:2]), 5.0)
        xyz[field > np.quantile(field, 0.5)] = np.nan
        if kind == "masked-crop":
            mask = (rng.random(xyz.shape[:2]) < 0.3)[2:70, 5:131]
            xyz = xyz[2:70, 5:131]
    elif kind in ("negative", "signed-zeros"):
        xyz = -bank_clouds.with_holes(rng, camera(rng, 41, 57), 0.3)
        if kind == "signed-zeros":
            xyz[::3, ::2, 0] = -0.0
            xyz[1::3, ::2, 0] = 0.0
    else:
        xyz = bank_clouds.degenerate_clouds()[{"one-row": "row", "one-valid": "one-valid"}.get(kind, kind)]
    x, y, z, valid, tbox = _tile_boxes(xyz, mask)
    got, want = sor_module._tile_range(tbox), valid_range(x, y, z, valid)
    assert np.array_equal(np.array(got), np.array(want)), (got, want)
    if valid.any():
        assert all(math.isfinite(v) for v in got)
    else:
        assert got == (np.inf, -np.inf, np.inf, -np.inf, np.inf, -np.inf)


def _index_kd_build(pts: np.ndarray, leaf: int) -> tuple[np.ndarray, ...]:
    """The KD-tree build before this round, transcribed literally: an index array permuted by a
    Hoare quickselect on pts[idx[i], dim], each node's box read through the index."""
    n = pts.shape[0]
    idx = np.arange(n)
    lo, hi, start, end, child = [], [], [0], [n], [-1]

    def select(s: int, e: int, kth: int, dim: int) -> None:
        left, right = s, e - 1
        while right > left:
            mid = (left + right) // 2
            a, b, c = pts[idx[left], dim], pts[idx[mid], dim], pts[idx[right], dim]
            pivot = max(min(a, b), min(max(a, b), c))
            i, j = left, right
            while i <= j:
                while pts[idx[i], dim] < pivot:
                    i += 1
                while pts[idx[j], dim] > pivot:
                    j -= 1
                if i <= j:
                    idx[i], idx[j] = idx[j], idx[i]
                    i += 1
                    j -= 1
            if kth <= j:
                right = j
            elif kth >= i:
                left = i
            else:
                break

    stack = [0]
    boxes: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    while stack:
        k = stack.pop()
        s, e = start[k], end[k]
        box_lo, box_hi = [math.inf] * 3, [-math.inf] * 3
        for t in range(s, e):  # in the index's order, the first of equal values kept (-0.0 and 0.0)
            for a in range(3):
                box_lo[a] = min(box_lo[a], pts[idx[t], a])
                box_hi[a] = max(box_hi[a], pts[idx[t], a])
        boxes[k] = np.array(box_lo), np.array(box_hi)
        if e - s <= leaf:
            continue
        ext = boxes[k][1] - boxes[k][0]
        dim = 0
        for a in (1, 2):
            if ext[a] > ext[dim]:
                dim = a
        mid = (s + e) // 2
        select(s, e, mid, dim)
        child[k] = len(start)
        start += [s, mid]
        end += [mid, e]
        child += [-1, -1]
        stack += [child[k], child[k] + 1]
    lo = np.array([boxes[k][0] for k in range(len(start))])
    hi = np.array([boxes[k][1] for k in range(len(start))])
    return pts[idx], lo, hi, np.array(start), np.array(end), np.array(child)


@pytest.mark.parametrize("kind", ["uniform", "quantized", "coincident", "one-plane", "two", "one"])
def test_kd_build_makes_the_index_builds_tree(kind: str) -> None:
    # kd_build now moves the points themselves as it splits (no index into the input): the same
    # swaps on the same keys, so the same tree bit for bit, duplicates and ties included
    from zcut.sor_search import KD_LEAF, kd_build

    rng = np.random.default_rng(1 + len(kind))
    n = {"two": 2, "one": 1}.get(kind, 700)
    pts = rng.random((n, 3))
    if kind == "quantized":
        pts = np.round(pts * 6.0) / 6.0
    elif kind == "coincident":
        pts[:] = pts[0]
    elif kind == "one-plane":
        pts[:, 2] = -0.0
        pts[::2, 2] = 0.0
    for leaf in (1, 3, KD_LEAF, 64):
        got = kd_build(pts.copy(), leaf)
        want = _index_kd_build(pts, leaf)
        for g, w in zip(got, want, strict=True):
            assert g.shape == w.shape and g.tobytes() == w.tobytes()
    assert kd_build(pts)[0].tobytes() == _index_kd_build(pts, KD_LEAF)[0].tobytes()


@pytest.mark.parametrize("leaf", [1, 64, 1 << 20])
@pytest.mark.parametrize("seed", [3, 17])
def test_the_kd_tree_of_any_leaf_size_gives_the_same_distances(seed: int, leaf: int,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    # every unproven pixel of steep relief with blob-shaped holes sent to the KD-tree of the tiles
    # within its radius, and to the KD-tree of all points, built with leaves of any size
    from scipy.ndimage import gaussian_filter

    from zcut import sor_search

    build = sor_search.kd_build
    leaves = []

    def kd_build(pts, leaf_asked=sor_search.KD_LEAF):  # noqa: ANN001, ANN202 - a spy with the kernel's signature
        leaves.append(leaf_asked)
        return build(pts, leaf)

    rng = np.random.default_rng(seed)
    xyz = bank_clouds.steep(rng, 60, 90)
    field = gaussian_filter(rng.normal(size=xyz.shape[:2]), 5.0)
    xyz[field > np.quantile(field, 0.6)] = np.nan
    monkeypatch.setattr(sor_search, "kd_build", kd_build)
    monkeypatch.setattr(sor_module, "_TILE_SCAN_CAP", 0)
    assert_as_oracle(xyz, ks=(1, 4))
    monkeypatch.setattr(sor_module, "_MARK_MAX_TILES", 0)
    assert_as_oracle(xyz, ks=(4,))
    assert leaves


def test_few_queries_get_the_large_leaves(monkeypatch: pytest.MonkeyPatch) -> None:
    # the leaf size follows the points per query: 64 when the tree has at least 64 points per query
    # (the few tile searches that hit their cap, over the tiles within their radius), the default
    # for the KD-tree of every point of a cloud that is not organized (as many queries as points)
    from zcut import sor_search

    build, queries = sor_search.kd_build, sor_search.kd_queries
    asked: list[list[int]] = []

    def kd_build(pts, leaf=sor_search.KD_LEAF):  # noqa: ANN001, ANN202 - a spy with the kernel's signature
        asked.append([pts.shape[0], leaf, 0])
        return build(pts, leaf)

    def kd_queries(q0, q1, *args):  # noqa: ANN001, ANN002, ANN202 - a spy with the kernel's signature
        asked[-1][2] += q1 - q0
        return queries(q0, q1, *args)

    rng = np.random.default_rng(5)
    monkeypatch.setattr(sor_search, "kd_build", kd_build)
    monkeypatch.setattr(sor_search, "kd_queries", kd_queries)
    monkeypatch.setattr(sor_module, "_TILE_SCAN_CAP", 8)
    sor_mean_distances(bank_clouds.steep(rng, 96, 128), k=4)
    monkeypatch.setattr(sor_module, "_TILE_SCAN_CAP", 0)
    monkeypatch.setattr(sor_module, "_SAMPLE", 2)
    sor_mean_distances(bank_clouds.scattered(rng, 40, 50), k=4)
    assert len(asked) == 2
    for n, leaf, n_queries in asked:
        assert leaf == (sor_module._KD_LEAF_FEW if n_queries * sor_module._KD_LEAF_FEW <= n else sor_search.KD_LEAF)
    assert [leaf for _, leaf, _ in asked] == [sor_module._KD_LEAF_FEW, sor_search.KD_LEAF]
