"""z-cut: the squeezed deep cut's pruned flood on the squeeze's own levels (zcut.cut_tree.squeezed_levels, and
gentle_levels / pruned_clusters given its table) against the literal reference (qlevel of every pixel, the map of
the occupied levels) and against the same kernels on the squeezed heights, bit for bit: shallow, deep, NaN-heavy,
single-height, all-invalid and coarse inputs (test_cuts_cluster_labels.squeeze_inputs), and a squeeze too deep for
the pruned flood (an empty table)."""

from __future__ import annotations

import numpy as np
import pytest
from test_cuts_cluster_labels import squeeze_inputs, squeezed_reference

from zcut.cut_tree import (
    SEGMENT,
    SHALLOW_LEVELS,
    cuts_window,
    gentle_levels,
    pruned_clusters,
    qlevel,
    squeezed_heights,
    squeezed_levels,
)
from zcut.cuts import _finite_range, _levels

CASES = ["shallow", "deep", "nan-heavy", "single", "invalid", "coarse"]


def literal_levels(z: np.ndarray, z_max: float, step: float, q_min: int) -> np.ndarray:
    """:func:`qlevel` ``(zt, z_max, step, q_min + 1)`` of every finite pixel, ``q_min + 1`` elsewhere."""
    q = np.full(z.shape, q_min + 1, np.int64)
    for i, v in np.ndenumerate(z):
        if np.isfinite(v):
            q[i] = int(qlevel(float(v), z_max, step, np.int64(q_min + 1)))
    return q


def inputs(case: str, seed: int) -> tuple[np.ndarray, np.ndarray, float, float, int]:
    """(heights, their row segments' maxima, z_max, step, q_min) of a squeeze test (q_min 5 where no height is
    finite, as test_cuts_cluster_labels does)."""
    z, step = squeeze_inputs(case, seed)
    n, lo, hi, seg = _finite_range(z)
    if n > 0:
        return z, seg, hi, step, int(qlevel(lo, hi, step, np.int64(2**40)))
    return z, seg, 0.0, step, 5


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("case", CASES)
def test_squeezed_levels_as_the_literal_reference(case: str, seed: int) -> None:
    """squeezed_levels: each pixel's level is qlevel's (q_min + 1 where not finite), the map and its inverse the
    literal ones, the row segments' maxima squeezed_heights' (bit for bit), and the table gives at every pixel the
    level the pruned flood takes from the squeezed heights in the cuts 0 .. map[q_min] - 1 (-1 outside them: at
    q_min, or not finite)."""
    z, seg, hi, step, q_min = inputs(case, seed)
    fwd, inv, out, (_, _, _, seg2) = squeezed_reference(z, hi, step, q_min)
    got_seg = np.full(seg.shape, 7.0)
    lv, tab, got_fwd, got_inv = squeezed_levels(z, seg, hi, step, np.int64(q_min), got_seg)
    assert lv.dtype == np.uint16 and lv.shape == z.shape and tab.dtype == np.int16
    np.testing.assert_array_equal(lv, literal_levels(z, hi, step, q_min))
    assert np.array_equal(got_fwd, fwd) and np.array_equal(got_inv, inv)
    assert np.array_equal(got_seg.view(np.int64), seg2.view(np.int64))
    assert tab.shape == (q_min + 2,)
    top = int(fwd[q_min]) - 1
    want = np.full(z.shape, -1, np.int64)  # the squeezed heights' levels in the cuts 0 .. top (step 1.0 from 0.0)
    fin = np.isfinite(out)
    for i in zip(*np.nonzero(fin)):
        k = int(qlevel(float(out[i]), 0.0, 1.0, np.int64(q_min + 2)))
        want[i] = k if k <= top else -1
    np.testing.assert_array_equal(tab[lv].astype(np.int64), want)
    if case == "invalid":
        assert (tab[lv] == -1).all()
    if case == "single":
        assert q_min == 0 and (tab == -1).all()


def test_squeeze_too_deep_for_the_pruned_flood() -> None:
    """More than SHALLOW_LEVELS squeezed levels: the table is empty (the caller falls back), the levels, the map
    and the row segments' maxima as squeezed_heights' all the same."""
    step = 0.5
    q = np.arange(SHALLOW_LEVELS + 302) * 3  # every third level occupied: gaps of 2 squeezed levels
    z = (12.25 - q * step).reshape(2, -1)
    n, lo, hi, seg = _finite_range(z)
    q_min = int(qlevel(lo, hi, step, np.int64(2**40)))
    seg_a, seg_b = np.empty_like(seg), np.empty_like(seg)
    lv, tab, fwd, inv = squeezed_levels(z, seg, hi, step, np.int64(q_min), seg_a)
    heights = np.empty_like(z)
    fwd_h, inv_h = squeezed_heights(z, seg, hi, step, np.int64(q_min), heights, seg_b)
    assert int(fwd[q_min]) > SHALLOW_LEVELS and tab.size == 0
    assert np.array_equal(fwd, fwd_h) and np.array_equal(inv, inv_h)
    assert np.array_equal(seg_a.view(np.int64), seg_b.view(np.int64))
    np.testing.assert_array_equal(lv, literal_levels(z, hi, step, q_min))


def gentle_run(z: np.ndarray, seg: np.ndarray, lo: float, hi: float, k_eff: int, top: int, conn8: bool,
               max_area: float, check: int, ltab: np.ndarray | None) -> dict[str, object]:
    """gentle_levels over the window of the cuts on arrays filled with -7 (heights, or levels with ``ltab``): every
    array and the results."""
    H, W = z.shape
    thr = hi - top
    wr, wc, wh, ww, bound = 0, 0, H, W, H * W
    if lo < thr:
        wr, wc, wh, ww, n_read = (int(v) for v in cuts_window(seg, thr, W))
        bound = max(min(n_read * SEGMENT, wh * ww), 1)
    size = (wh + 2) * (ww + 2)
    a: dict[str, object] = dict(st=np.full(size, -7, np.int16), gl=np.full(size, -7, np.int32))
    for k in ("pix", "gpar", "gcnt", "gls"):
        a[k] = np.full(bound, -7, np.int32)
    m, nl, labelled = gentle_levels(z, seg, lo, hi, 1.0, np.int64(k_eff + 2), np.int64(top), conn8, max_area,
                                    np.int64(check), a["st"], a["pix"], a["gl"], a["gpar"], a["gcnt"], 0.5, wr, wc,
                                    wh, ww, a["gls"], ltab)
    a.update(m=int(m), nl=int(nl), labelled=bool(labelled))
    return a


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("case", ["shallow", "deep", "nan-heavy", "coarse"])
def test_pruned_flood_on_the_levels_as_on_the_heights(case: str, seed: int) -> None:
    """gentle_levels given squeezed_levels' levels and table writes what it writes from the squeezed heights (every
    array, labelling every pixel or giving up after a row, 8- and 4-connected), and pruned_clusters gives the same
    clusters, areas and levels; the squeezed cuts as zcut.cuts._squeezed_clusters makes them (K' = map[q_min] -
    2)."""
    z, seg, hi, step, q_min = inputs(case, seed)
    heights, seg_h = np.empty_like(z), np.empty_like(seg)
    fwd, _ = squeezed_heights(z, seg, hi, step, np.int64(q_min), heights, seg_h)
    seg_l = np.empty_like(seg)
    lv, tab, _, _ = squeezed_levels(z, seg, hi, step, np.int64(q_min), seg_l)
    q2 = int(fwd[q_min])
    assert q2 >= 3 and q2 - 1 < SHALLOW_LEVELS
    lo2, hi2 = 0.0 - float(q2), 0.0
    k_eff, top = _levels(lo2, hi2, 1.0, q2 - 2)
    compared = 0
    for conn8 in (True, False):
        for max_area in (1.0, 5.0, 40.0, float(z.size)):
            for check in (2**40, 1):
                want = gentle_run(heights, seg_h, lo2, hi2, k_eff, top, conn8, max_area, check, None)
                got = gentle_run(lv, seg_l, lo2, hi2, k_eff, top, conn8, max_area, check, tab)
                for k, v in want.items():
                    if isinstance(v, np.ndarray):
                        np.testing.assert_array_equal(got[k], v, err_msg=k)
                    else:
                        assert got[k] == v, k
                compared += int(want["m"])  # type: ignore[call-overload]
                runs = []
                for zz, ss, lt in ((heights, seg_h, None), (lv, seg_l, tab)):
                    labels = np.zeros(z.size, np.int32)
                    ok, areas, levels = pruned_clusters(zz, ss, lo2, hi2, 1.0, np.int64(k_eff), np.int64(top), conn8,
                                                        conn8, max_area, np.int64(check), np.int64(0), labels, lt)
                    runs.append((bool(ok), labels, areas, levels))
                assert runs[0][0] and runs[1][0]
                for a, b in zip(runs[0][1:], runs[1][1:], strict=True):
                    assert a.dtype == b.dtype
                    np.testing.assert_array_equal(a, b)
    assert compared > 0
