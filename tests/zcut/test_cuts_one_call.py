"""z-cut: the pruned flood in one kernel call (zcut.cut_tree.pruned_outliers) and the gentle-edge codes in float32
lanes (zcut.cut_tree._gentle_codes), against the integer tests the codes stood for, the passes called one by one
as zcut.cuts._pruned_outliers called them before, the whole tree's flood (find_clusters) and the literal loop:
held-out piles at full size (seeds 22 to 26), large invalid regions and degenerate frames."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from bench_frames import bench_kinds

from zcut import ZCutParams, find_clusters, zcut_outliers, zcut_outliers_reference
from zcut.cut_tree import (
    SHALLOW_LEVELS,
    _gentle_codes,
    cuts_window,
    flood_core_left_out,
    gentle_levels,
    gentle_prune,
    pruned_outlier_mask,
    pruned_scratch,
)
from zcut.cuts import PRUNE_CHECK, PRUNE_CHECK_ROWS, _finite_range, _levels, _pruned_outliers
from zcut.params import n_levels

NOMINAL = dict(step=0.2, max_depth=30.0, max_area=210.0)


def integer_codes(st: np.ndarray, b: int, c0: int, c1: int, Wp: int) -> np.ndarray:
    """The codes of ``_gentle_codes`` by their definition, on Python integers (``[c]`` for c in [c0, c1))."""

    def near(a: int, c: int) -> bool:
        return abs(a - c) <= 1

    out = np.zeros(c1, np.uint8)
    for c in range(c0, c1):
        p = b + c
        lv, qw, qn, qnw, qne = (int(st[x]) for x in (p, p - 1, p - Wp, p - Wp - 1, p - Wp + 1))
        inc = lv >= 0
        gw, gn, gnw, gne = (inc and q >= 0 and near(q, lv) for q in (qw, qn, qnw, qne))
        unw = gn and gnw and not near(qnw, qn)
        une = gne and ((gn and not near(qne, qn)) or (not gn and gnw))
        uw = gw and ((gn and not near(qw, qn)) or (not gn and gnw and not near(qw, qnw)) or (not gn and not gnw and gne))
        out[c] = gw | gne << 1 | gnw << 2 | gn << 3 | unw << 4 | une << 5 | uw << 6 | inc << 7
    return out


def test_gentle_codes_equal_the_integer_tests() -> None:
    """Every combination of five levels among -1 .. 3 (the pixel and its W, N, NW, NE neighbours), then random
    ones up to the largest level the pruned flood takes (SHALLOW_LEVELS - 1) and near it: the float32 codes are the
    integer tests' (levels and differences are exact in float32)."""
    top = SHALLOW_LEVELS - 1
    combos = np.array(list(itertools.product(range(-1, 4), repeat=5)), np.int16)
    rng = np.random.default_rng(1212)
    big = rng.integers(-1, top + 1, (4000, 5)).astype(np.int16)
    near_top = (top - rng.integers(0, 4, (2000, 5))).astype(np.int16)
    near_top[rng.random(near_top.shape) < 0.1] = -1
    seen: set[int] = set()
    for sets in (combos, big, near_top):
        n = sets.shape[0]
        # a padded strip of 3 rows: pixel i of the middle row at column 1 + 2 i (its W at 2 i), its N, NW, NE
        # above; the pixels between are the W neighbours only (their own codes are not checked)
        Wp = 2 * n + 2
        st = np.full(3 * Wp, -1, np.int16)
        cols = 1 + 2 * np.arange(n)
        st[Wp + cols] = sets[:, 0]
        st[Wp + cols - 1] = sets[:, 1]
        st[cols] = sets[:, 2]
        st[cols - 1] = sets[:, 3]
        st[cols + 1] = sets[:, 4]
        codes = np.zeros(Wp - 1, np.uint8)
        _gentle_codes(st, np.int64(Wp), np.int64(1), np.int64(Wp - 1), np.int64(Wp), codes)
        want = integer_codes(st, Wp, 1, Wp - 1, Wp)
        np.testing.assert_array_equal(codes[cols], want[cols])
        np.testing.assert_array_equal(codes[1:], want[1:])  # the W neighbours' own codes too
        seen |= set(codes[cols].tolist())
    assert len(seen) > 30  # many codes, each union bit among them
    assert all(any(c & bit for c in seen) for bit in (16, 32, 64))


def steps_outliers(z: np.ndarray, *, step: float, max_depth: float, max_area: float, connectivity: int = 8,
                   minimum: int = 0) -> np.ndarray | None:
    """The mask of the pruned flood with its passes called one by one from Python, as ``_pruned_outliers``
    called them before they became one kernel call; None where it did not apply."""
    K = n_levels(step, max_depth)
    n, lo, hi, seg = _finite_range(z)
    if n == 0 or K < 1:
        return None
    k_eff, top = _levels(lo, hi, step, K)
    H, W = z.shape
    if top >= SHALLOW_LEVELS or not max_area <= H * W:
        return None
    thr = hi - top * step
    wr, wc, wh, ww, bound = 0, 0, H, W, H * W
    if lo < thr:
        wr, wc, wh, ww, n_read = (int(v) for v in cuts_window(seg, thr, W))
        bound = n_read * 64
        if bound < minimum:
            return None
        bound = min(bound, wh * ww)
    n_pad = (wh + 2) * (ww + 2)
    st, gl = np.empty(n_pad, np.int16), np.empty(n_pad, np.int32)
    pix, gpar, gcnt = (np.empty(bound, np.int32) for _ in range(3))
    conn8 = connectivity == 8
    m, nl, labelled = gentle_levels(z, seg, lo, hi, step, np.int64(k_eff + 2), np.int64(top), conn8, float(max_area),
                                    np.int64(max(PRUNE_CHECK, PRUNE_CHECK_ROWS * W)), st, pix, gl, gpar, gcnt, 0.5,
                                    wr, wc, wh, ww)
    start = np.zeros(top + 2, np.int64)
    keep = int(gentle_prune(st, pix, m, gl, gpar, gcnt, nl, float(max_area), start, labelled, ww, conn8,
                            np.int64(top)))
    kept = pix[:keep]
    _, _, node_parent, tagged, fin = flood_core_left_out(st, start, kept, ww, np.int64(k_eff), np.int64(top), conn8,
                                                         float(max_area), gl)
    out = np.zeros(H * W, bool)
    pruned_outlier_mask(z, gl, kept, fin, node_parent, tagged, out, wr, wc, ww)
    return out.reshape(H, W)


def one_call(z: np.ndarray, *, step: float, max_depth: float, max_area: float, connectivity: int = 8,
             minimum: int = 0) -> np.ndarray | None:
    """The same through ``_pruned_outliers`` (one kernel call); None where it did not apply."""
    K = n_levels(step, max_depth)
    n, lo, hi, seg = _finite_range(z)
    if n == 0 or K < 1:
        return None
    out = np.zeros(z.shape, bool)
    if not _pruned_outliers(z, seg, lo, hi, step, K, max_area, connectivity, out, minimum=minimum):
        return None
    return out


@pytest.mark.parametrize("seed", [22, 23, 24, 25, 26])
def test_held_out_piles_at_full_size(seed: int) -> None:
    """The 1920 x 1200 piles at seeds the bench does not use (22 to 25 hold more pixels in the cuts than its pile):
    zcut_outliers (the one call) equals the passes called one by one and the whole tree's flood."""
    z = bench_kinds()["pile"](seed)
    got = zcut_outliers(z, **NOMINAL)
    np.testing.assert_array_equal(got, steps_outliers(z, **NOMINAL, minimum=65536))
    np.testing.assert_array_equal(got, find_clusters(z, params=ZCutParams(**NOMINAL)).outliers)
    assert got.sum() > 1000


@pytest.mark.parametrize("connectivity", [8, 4])
@pytest.mark.parametrize("seed", [31, 32])
def test_crops_with_large_invalid_regions(seed: int, connectivity: int) -> None:
    """Crops of the holes frame (a third of the width and big blocks invalid) and of a pile with its top rows
    invalid, through the one call and the passes one by one, against the literal loop."""
    kinds = bench_kinds()
    for z in (kinds["holes"](seed)[400:640, 500:900], kinds["pile"](seed)[450:650, 700:1000]):
        z = z.copy()
        z[: z.shape[0] // 3, :] = np.nan  # a large invalid block more
        params = dict(NOMINAL, connectivity=connectivity)
        want = zcut_outliers_reference(z, **params)
        got = one_call(z, **params)
        assert got is not None
        np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(steps_outliers(z, **params), want)
        np.testing.assert_array_equal(zcut_outliers(z, **params), want)


@pytest.mark.parametrize("case", ["all_nan", "one_pixel", "one_row", "one_column", "constant", "one_valid",
                                  "min_not_below", "too_few"])
def test_degenerate_frames_through_the_one_call(case: str) -> None:
    """Degenerate frames through ``_pruned_outliers`` forced (minimum 0) and by default: the literal loop's
    mask, and nothing written where it does not apply."""
    rng = np.random.default_rng(7)
    z = {
        "all_nan": np.full((5, 7), np.nan),
        "one_pixel": np.array([[3.0]]),
        "one_row": rng.normal(0.0, 0.3, (1, 300)),
        "one_column": rng.normal(0.0, 0.3, (300, 1)),
        "constant": np.full((40, 70), 2.5),
        "one_valid": np.where(np.arange(600).reshape(20, 30) == 317, 1.0, np.nan),
        "min_not_below": rng.uniform(0.0, 5.0, (30, 80)),  # the whole range inside the cuts: no window
        "too_few": np.where(rng.random((64, 200)) < 0.3, rng.uniform(0.0, 100.0, (64, 200)), np.nan),
    }[case]
    want = zcut_outliers_reference(z, **NOMINAL)
    np.testing.assert_array_equal(zcut_outliers(z, **NOMINAL), want)
    forced = one_call(z, **NOMINAL)
    if np.isfinite(z).any():
        assert forced is not None or not NOMINAL["max_area"] <= z.size
    if forced is not None:
        np.testing.assert_array_equal(forced, want)
        np.testing.assert_array_equal(steps_outliers(z, **NOMINAL), want)
    if case == "too_few":
        out = np.zeros(z.shape, bool)
        n, lo, hi, seg = _finite_range(z)
        assert not _pruned_outliers(z, seg, lo, hi, 0.2, 150, 210.0, 8, out)  # fewer than PRUNE_MIN: not applied
        assert not out.any()


@pytest.mark.parametrize(("n", "bound"), [(0, 0), (4, 0), (10, 3), (1026 * 572, 254016)])
def test_scratch_views_are_disjoint_and_on_cache_lines(n: int, bound: int) -> None:
    """``pruned_scratch``: six views of one block, the sizes asked, each on a 64-byte boundary from the first,
    none overlapping another."""
    views = pruned_scratch(np.int64(n), np.int64(bound), np.int64(bound // 2))
    st, gl, pix, gpar, gcnt, gls = views
    assert [v.size for v in views] == [n, n, bound, bound, bound, bound // 2]
    assert st.dtype == np.int16 and all(v.dtype == np.int32 for v in views[1:])
    base = gl.__array_interface__["data"][0]
    spans = sorted((v.__array_interface__["data"][0], v.__array_interface__["data"][0] + v.nbytes) for v in views)
    assert all((a - base) % 64 == 0 for a, _ in spans)
    assert all(e <= a2 for (_, e), (a2, _) in zip(spans, spans[1:], strict=False))
