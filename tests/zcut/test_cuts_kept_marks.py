"""z-cut: the prune's marks (zcut.cut_tree.gentle_prune writes the kept pixels only, ``KEPT + level``; a pixel left
out keeps its level) and the labels listed in the order of the pixels in the cuts (``gls`` of
zcut.cut_tree.gentle_levels, read in order by the prune), against a literal Python prune (gentle components by a
breadth-first search, the uphill rule to its fixed point), the prune without the list (the labels gathered from
``gl``), the previous full-image path and the literal loop: held-out piles, large invalid regions, frames on
either side of the list's limit (at most half the frame in the cuts), degenerate frames and the real clouds."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest
from bench_frames import bench_kinds
from test_cuts_fast import height_mm, previous_outliers, pruned_outliers

from zcut import zcut_outliers, zcut_outliers_reference
from zcut.cut_tree import KEPT, SHALLOW_LEVELS, cuts_window, gentle_levels, gentle_prune
from zcut.cuts import _finite_range, _levels
from zcut.params import n_levels

NOMINAL = dict(step=0.2, max_depth=30.0, max_area=210.0)


def labelled_twice(z: np.ndarray, *, step: float, max_depth: float, max_area: float, gentle8: bool = True
                   ) -> tuple[dict, dict]:
    """The level pass of z (every pixel labelled, over the whole frame) run twice on fresh arrays, without and
    with ``gls``: each run's arrays and results."""
    z = np.ascontiguousarray(z, dtype=np.float64)
    H, W = z.shape
    _, lo, hi, seg = _finite_range(z)
    k_eff, top = _levels(lo, hi, step, n_levels(step, max_depth))
    runs = []
    for listed in (False, True):
        size = (H + 2) * (W + 2)
        a = dict(st=np.empty(size, np.int16), gl=np.empty(size, np.int32),
                 pix=np.empty(H * W, np.int32), gpar=np.empty(H * W, np.int32), gcnt=np.empty(H * W, np.int32))
        gls = np.full(H * W, -7, np.int32)
        args = (z, seg, lo, hi, step, np.int64(k_eff + 2), np.int64(top), gentle8, max_area, np.int64(2**40),
                a["st"], a["pix"], a["gl"], a["gpar"], a["gcnt"], 0.5, 0, 0, -1, -1)
        m, nl, labelled = gentle_levels(*args, gls) if listed else gentle_levels(*args)
        a.update(m=int(m), nl=int(nl), labelled=bool(labelled), top=int(top), H=H, W=W, gls=gls if listed else None)
        runs.append(a)
    return runs[0], runs[1]


def pruned(run: dict, *, max_area: float, conn8: bool = True) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """gentle_prune on copies of a run's arrays (with its ``gls`` when it has one): (kept, kept pixels, st,
    start)."""
    st, pix, gpar, gcnt = (run[k].copy() for k in ("st", "pix", "gpar", "gcnt"))
    start = np.zeros(run["top"] + 2, np.int64)
    args = (st, pix, run["m"], run["gl"], gpar, gcnt, run["nl"], max_area, start, run["labelled"], run["W"], conn8,
            np.int64(run["top"]))
    keep = int(gentle_prune(*args, run["gls"]) if run["gls"] is not None else gentle_prune(*args))
    return keep, pix[:keep].copy(), st, start


def literal_prune(levels: np.ndarray, *, max_area: float, top: int, conn8: bool = True) -> np.ndarray:
    """The pixels the prune keeps, by its definition, from the (H, W) levels (-1 outside the cuts): the gentle
    components (8-connected, levels within 1) by a breadth-first search, those of fewer than ``max_area`` pixels
    kept, then the uphill rule to its fixed point (a kept pixel at ``top``, or with a left-out neighbour of the
    z-cut's connectivity whose level is at most its level + 1, is left out)."""
    H, W = levels.shape
    comp = np.full((H, W), -1, np.int64)
    sizes = []
    eight = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]
    for r0 in range(H):
        for c0 in range(W):
            if levels[r0, c0] < 0 or comp[r0, c0] >= 0:
                continue
            comp[r0, c0] = len(sizes)
            n, todo = 0, deque([(r0, c0)])
            while todo:
                r, c = todo.popleft()
                n += 1
                for dr, dc in eight:
                    rr, cc = r + dr, c + dc
                    if 0 <= rr < H and 0 <= cc < W and levels[rr, cc] >= 0 and comp[rr, cc] < 0 \
                            and abs(int(levels[rr, cc]) - int(levels[r, c])) <= 1:
                        comp[rr, cc] = len(sizes)
                        todo.append((rr, cc))
            sizes.append(n)
    small = np.array(sizes + [0]) < max_area
    kept = (levels >= 0) & small[comp]
    out_cuts = (levels >= 0) & ~kept
    nbrs = eight if conn8 else [(-1, 0), (0, -1), (0, 1), (1, 0)]
    lv = np.pad(levels, 1, constant_values=-1)
    while True:
        lo = np.pad(out_cuts, 1)
        hit = np.zeros((H, W), bool)
        for dr, dc in nbrs:
            nb_out = lo[1 + dr:1 + dr + H, 1 + dc:1 + dc + W]
            nb_lv = lv[1 + dr:1 + dr + H, 1 + dc:1 + dc + W]
            hit |= nb_out & (nb_lv <= levels + 1)
        new = kept & (hit | (levels >= top))
        if not new.any():
            return kept
        kept &= ~new
        out_cuts |= new


def check_frame(z: np.ndarray, *, step: float = 0.2, max_depth: float = 30.0, max_area: float = 210.0,
                literal: bool = True) -> tuple[int, int]:
    """The level pass with and without ``gls``, the prune with and without it, the marks and (``literal``) the
    literal prune on z; returns (pixels in the cuts, kept)."""
    plain, listed = labelled_twice(z, step=step, max_depth=max_depth, max_area=max_area)
    assert (plain["m"], plain["nl"], plain["labelled"]) == (listed["m"], listed["nl"], listed["labelled"])
    m, nl = plain["m"], plain["nl"]
    np.testing.assert_array_equal(plain["st"], listed["st"])
    np.testing.assert_array_equal(plain["pix"][:m], listed["pix"][:m])
    np.testing.assert_array_equal(plain["gl"][plain["pix"][:m]], listed["gl"][plain["pix"][:m]])  # (gl: in the cuts)
    np.testing.assert_array_equal(plain["gpar"][:nl], listed["gpar"][:nl])
    np.testing.assert_array_equal(plain["gcnt"][:nl], listed["gcnt"][:nl])
    # each pixel's label, in order: a label of its set (the scan may later give gl a smaller label of the same set,
    # the root it found, at a pixel NE of one it unites)
    root = plain["gpar"][:nl].astype(np.int64)
    while not np.array_equal(root[root], root):
        root = root[root]
    if plain["labelled"]:
        np.testing.assert_array_equal(root[listed["gls"][:m]], root[plain["gl"][plain["pix"][:m]]])
    assert (listed["gls"][m:] == -7).all()  # nothing written past the pixels in the cuts
    H, W = plain["H"], plain["W"]
    levels = plain["st"].reshape(H + 2, W + 2)[1:-1, 1:-1].astype(np.int64)
    a, b = pruned(plain, max_area=max_area), pruned(listed, max_area=max_area)
    assert a[0] == b[0]
    for x, y in zip(a[1:], b[1:], strict=True):
        np.testing.assert_array_equal(x, y)
    keep, kept_pix, st, start = b
    after = st.reshape(H + 2, W + 2)
    assert (after[0] == -1).all() and (after[-1] == -1).all() and (after[:, 0] == -1).all() and (after[:, -1] == -1).all()
    inner = after[1:-1, 1:-1].astype(np.int64)
    kept = inner >= KEPT
    # a kept pixel is marked KEPT + level, a left-out one keeps its level, the others stay -1
    np.testing.assert_array_equal(np.where(kept, inner - KEPT, inner), levels)
    flat = np.zeros((H + 2) * (W + 2), bool)
    flat[kept_pix] = True
    np.testing.assert_array_equal(flat.reshape(H + 2, W + 2)[1:-1, 1:-1], kept)  # the list is the marked pixels
    assert (np.diff(kept_pix) > 0).all()  # in raster order
    np.testing.assert_array_equal(start[1:], np.bincount(levels[kept], minlength=plain["top"] + 1))
    if plain["labelled"] and literal:
        np.testing.assert_array_equal(kept, literal_prune(levels, max_area=max_area, top=plain["top"]))
    return m, keep


@pytest.mark.parametrize("seed", [22, 24])
def test_held_out_piles_keep_the_same_pixels(seed: int) -> None:
    """The full-size piles of seeds 22 and 24 (the dearest held-out ones): the marks and the kept list with and
    without the listed labels; the literal prune on a crop of each (its search is Python, one pixel at a time)."""
    z = bench_kinds()["pile"](seed)
    m, keep = check_frame(z, literal=False)
    assert m > 100_000 and 1000 < keep < m // 10
    check_frame(z[420:620, 760:1060])


@pytest.mark.parametrize("seed", [41, 42])
def test_large_invalid_regions(seed: int) -> None:
    """Crops of the holes frame (a third of the width and big blocks invalid), with a third of the rows invalid
    more, and a pile crop with NaN columns."""
    kinds = bench_kinds()
    z = kinds["holes"](seed)[380:600, 480:860].copy()
    z[: z.shape[0] // 3] = np.nan
    check_frame(z)
    z = kinds["pile"](seed)[500:700, 800:1100].copy()
    z[:, 100:180] = np.nan
    check_frame(z)


def test_noisy_fields_and_coarse_steps() -> None:
    """Random bumpy fields with spikes, at Δd 0.2 mm and 1 mm and a small max_area: many small sets, many walks."""
    rng = np.random.default_rng(2214)
    for step, max_area in ((0.2, 210.0), (1.0, 30.0), (0.5, 5.0)):
        z = np.cumsum(rng.normal(0.0, 0.4, (90, 130)), axis=1) + rng.normal(0.0, 0.2, (90, 130))
        spikes = rng.random(z.shape) < 0.02
        z[spikes] += rng.uniform(1.0, 8.0, int(spikes.sum()))
        z[rng.random(z.shape) < 0.05] = np.nan
        check_frame(z, step=step, max_area=max_area)


@pytest.mark.parametrize("case", ["one_pixel", "one_row", "one_column", "constant", "one_valid", "all_in_cuts",
                                  "at_top"])
def test_degenerate_frames(case: str) -> None:
    """Degenerate frames through the level pass and the prune with and without the list (all NaN has no level
    pass: no valid height)."""
    rng = np.random.default_rng(3)
    z = {
        "one_pixel": np.array([[3.0]]),
        "one_row": rng.normal(0.0, 0.3, (1, 300)),
        "one_column": rng.normal(0.0, 0.3, (300, 1)),
        "constant": np.full((40, 70), 2.5),
        "one_valid": np.where(np.arange(600).reshape(20, 30) == 317, 1.0, np.nan),
        "all_in_cuts": rng.uniform(0.0, 5.0, (30, 80)),
        "at_top": np.where(rng.random((30, 80)) < 0.5, 30.2, 0.0),  # half the pixels at the deepest level K + 1
    }[case]
    check_frame(z, max_area=4.0)
    check_frame(z)


def list_limit(z: np.ndarray) -> tuple[bool, bool]:
    """(some pixels below the cuts, at most half the frame may be in the cuts): when both hold the one call lists
    the labels (zcut.cut_tree.pruned_outliers)."""
    n, lo, hi, seg = _finite_range(z)
    k_eff, top = _levels(lo, hi, 0.2, n_levels(0.2, 30.0))
    thr = hi - top * 0.2
    if not lo < thr:
        return False, False
    _, _, wh, ww, n_read = (int(v) for v in cuts_window(seg, thr, z.shape[1]))
    return True, 2 * min(n_read * 64, wh * ww) <= z.size


def test_either_side_of_the_list_limit() -> None:
    """The one call lists the labels only when at most half the frame may lie in the cuts (a frame-sized list made
    glibc map the scratch anew at every call); frames on either side, and with every pixel in the cuts, give the
    literal loop's mask."""
    base = np.ascontiguousarray(bench_kinds()["dense"](17)[300:420, 200:456])
    cases = {}
    z = base.copy()
    z[:4, :4] = -100.0  # a few pixels below the cuts: the window is the frame, more than half in it
    cases["over"] = z
    z = base.copy()
    z[:, 160:] = -100.0  # 160 of 256 columns in the cuts at most (by segments: 3 of 4 segments per row)
    cases["over_by_segments"] = z
    z = base.copy()
    z[:, 128:] = -100.0  # two of four segments per row
    cases["half"] = z
    z = base.copy()
    z[:, 64:] = -100.0
    cases["under"] = z
    cases["all_in_cuts"] = base
    sides = {name: list_limit(z) for name, z in cases.items()}
    assert sides == {"over": (True, False), "over_by_segments": (True, False), "half": (True, True),
                     "under": (True, True), "all_in_cuts": (False, False)}
    for z in cases.values():
        want = zcut_outliers_reference(z, **NOMINAL)
        np.testing.assert_array_equal(pruned_outliers(z, **NOMINAL), want)
        np.testing.assert_array_equal(zcut_outliers(z, **NOMINAL), want)


def test_levels_up_to_the_pruned_flood_limit() -> None:
    """Levels up to SHALLOW_LEVELS - 1 (the largest the pruned flood takes): ``KEPT + level`` stays in int16 and
    above every level."""
    assert SHALLOW_LEVELS <= KEPT and KEPT + SHALLOW_LEVELS - 1 <= np.iinfo(np.int16).max
    rng = np.random.default_rng(5)
    z = rng.uniform(0.0, 0.02 * (SHALLOW_LEVELS - 3), (40, 90))
    z[10:13, 20:23] += 0.2  # a small cluster well above its surroundings
    params = dict(step=0.02, max_depth=0.02 * (SHALLOW_LEVELS - 3), max_area=30.0)
    _, top = _levels(float(np.nanmin(z)), float(np.nanmax(z)), 0.02, n_levels(0.02, params["max_depth"]))
    assert top >= SHALLOW_LEVELS - 4
    check_frame(z, **params)
    np.testing.assert_array_equal(pruned_outliers(z, **params), zcut_outliers_reference(z, **params))


@pytest.mark.parametrize("name", ["mosd_test24.pcd", "milk_cartoon_all_small_clorox.pcd"])
def test_real_clouds(real_data, name: str) -> None:
    """Real Kinect clouds (zcut_outliers floods them whole; here the pruned flood forced): the marks and the kept
    list with and without the listed labels, and the mask of the previous full-image path."""
    import open3d as o3d

    cloud = o3d.io.read_point_cloud(str(real_data / name), remove_nan_points=False, remove_infinite_points=False)
    z = height_mm(np.asarray(cloud.points).reshape(480, 640, 3))
    m, keep = check_frame(z, literal=False)
    assert m > 10_000
    check_frame(np.ascontiguousarray(z[200:300, 250:400]))
    for params in (NOMINAL, dict(step=1.0, max_depth=30.0, max_area=210.0)):
        np.testing.assert_array_equal(pruned_outliers(z, **params), previous_outliers(z, **params))
