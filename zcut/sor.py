"""Statistical outlier removal (SOR) on organized clouds, exact and fast (docs/filters.md).

For every valid pixel the mean distance d̄ to its k nearest neighbours among the valid points is
computed exactly (no approximate search), then points far above the cloud's mean d̄ are outliers.

Why the search is exact
-----------------------
Each valid pixel needs the m smallest distances to the valid points (m = k + 1 with the point
itself for ``"pcl"``, m = k for ``"open3d"``). d̄ depends only on the *multiset* of these m
values, so a candidate list is final as soon as no point outside the searched set can be strictly
closer than the m-th smallest distance found: points at exactly that distance (ties, duplicates)
would only replace one equal value by another. In particular m distances of 0 are final at once,
and a search never has to look at more than m copies of a duplicated point.

1. *Camera model* (:mod:`zcut.sor_camera`). A 3 × 4 projective map P is fitted to the organized
   cloud itself (direct linear transform from the 3D points to their pixel coordinates; through a
   lens, the pinhole of a division model of radial distortion, so that U and V stay constant along a ray);
   U = P0·p̃ / P2·p̃ and V = P1·p̃ / P2·p̃ then grow with the column and the row. Nothing below
   needs P to be right, only that the depth P2·p̃ is positive at every valid point (checked, else
   no camera bounds): the points of any image region whose U values are all >= t satisfy
   P0·p̃ - t·P2·p̃ >= 0, a half-space, and the distance from a pixel to that half-space bounds its
   distance to each of them from below. This holds in any frame: z < 0, mixed signs and rigidly
   moved clouds alike.
2. *Image window* (:mod:`zcut.sor_window`). The m nearest candidates are taken from a window of
   (2w + 1)² pixels around the pixel. Outside the window lie: the rows of the pixel's 64-row band
   right and left of it, the columns of its 64-column band below and above it (bands start every
   32 pixels, so a window with w <= 16 is inside both), and four corner regions outside both
   bands. Each region is bounded by the half-space of its extreme U or V -- per band and position
   (local, so that lens distortion, which bends columns and rows, costs little), per quadrant for
   the corners (at least 17 pixels away in both directions; each lies in two half-spaces, and a
   per-cell floor of their bound usually spares evaluating them). If the m-th distance found is
   within all of them, the window is proven. Stages, cheapest first: a 3 × 3 window for whole
   rows at once (vectorized: the 8 neighbour distances sorted by a network, so any m <= 9 is a
   selection; only the 4 smallest kept when m <= 5), a 5 × 5 window for what it leaves (the whole
   row, vectorized, when that is much), then one pixel at a time, growing the window until its
   bound covers the m-th distance found so far, up to 16 (a pixel the 5 × 5 window left grows on
   from its smallest distances there: no pixel is measured twice). The window need not be square:
   the strips right and left of it are bounded through U (they depend only on its half-width in
   columns), those below and above it through V (only on its half-width in rows), so once it holds
   m valid pixels it grows, a column or a row on each side at a time, only in the direction whose
   strips do not yet cover the m-th distance; any window with both half-widths <= 16 lies inside
   both bands, which is all the cover needs.
3. *Columns* (:mod:`zcut.columns`), when many pixels are unproven (one in ``_COLUMNS_MIN_SHARE``
   or more: tall parts standing on end, whose image neighbours are rarely 3D neighbours, and the
   flying pixels along their silhouettes) and a tile search (4.) of a sample of them says that
   searching them all by tiles would measure more pixels than building the columns reads (more
   than ``_COLUMNS_COST`` per valid point; scattered invalid pixels leave many pixels unproven
   that the tile search settles cheaply). Each unproven pixel has an upper bound on its m-th
   distance (the m-th found in its window): a k-nearest search visits x-y columns (square cells a
   quarter of the median bound wide, points ordered by depth slab) ring by ring around its own,
   the search radius shrinking to the m-th distance found. Its cost depends on the points near the
   pixel in 3D, not on where they lie in the image. A search that scans too much is left to:
4. *Tile quadtree* (:mod:`zcut.sor_search`). Unproven pixels (flying pixels, isolated points,
   clouds without a camera) are searched over a quadtree of 8 × 8 pixel tiles, nearest node
   first; a node's bound is the larger of the distance to the box of its points and of the
   half-space bounds of its U and V ranges. A search that measures more than a few thousand pixels
   stops.
5. *KD-tree.* The pixels whose tile search stopped go to a KD-tree (balanced median splits, so
   duplicates cannot unbalance it; O(n) memory) built over the points of the tiles within their
   radius, or over all valid points when the cloud turns out not to be organized at all.

All bounds are lower bounds on the *computed* distance: box distances are evaluated in the order of
the distance itself (rounding is monotone), the camera bounds carry a relative margin far above
their rounding error (see :func:`zcut.sor_camera._plane`). Distances are those of Open3D's
nanoflann L2 metric: ``sqrt((dx*dx + dy*dy) + dz*dz)`` in float64, and d̄ sums the m smallest in
ascending order, so d̄ is bit-identical to Open3D's. The statistics are accumulated sequentially
over the valid pixels in row-major order (the order in which ``xyz[valid]`` hands them to Open3D).

Only what can hold a valid pixel is read: :func:`_prepare` notes each row's first and last valid
column (with ``mask``, only the columns between the mask's first and last pixel of the row are
read), the block statistics read the tiles of that span and compute U and V over its runs of tiles
with a valid pixel, the row stages' chunks start at a valid pixel and end at a run of more than
``sor_window._GAP`` invalid columns, and the column search fills only the columns its queries can
reach. A top-of-pile region scattered over its bounding box thus costs about what its points cost,
not what the box does.

The kernels are serial numba functions that release the GIL, run over ranges of rows or pixels on
the calling thread's pool (see :func:`_workers`); importing or calling this module changes no
process-wide setting.

Every full-frame temporary of a call (the planes, the valid mask, d̄ before it is copied out, the
block statistics, the band tables, the columns) is taken from the calling
thread's :class:`zcut.sor_workspace.SorWorkspace` (see that module: one per thread). By default it keeps
nothing between calls (``zcut.sor_workspace.KEPT_BYTES``: in a replay, where the process keeps the heap it
freed, ~190 MB held for SOR alone cost the other stages more than it saved) but the column search's arrays
(``zcut.sor_workspace.KEPT_NAMES``, up to ``KEPT_NAMES_BYTES`` = 128 MiB a thread; above that they are freed
after the call like the rest): ~85 MB on a frame of tall parts on end, faulted in afresh each call when they
were made fresh. ``thread_workspace().max_bytes = None`` keeps everything, grown to the largest frame seen,
until ``thread_workspace().release()``, which frees the column arrays too.
What a call returns (d̄, the masks) is always a new array.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import wait
from contextlib import contextmanager

import numba as nb
import numpy as np

from . import columns as _columns
from . import sor_camera as _camera
from . import sor_search as _search
from . import sor_window as _window
from .cloud import check_mask, check_xyz
from .errors import InputShapeError, ParameterError, describe_array
from .sor_workspace import SorWorkspace, thread_workspace
from .types import XYZ, Mask

__all__ = ["CONVENTIONS", "SorWorkspace", "sor_mean_distances", "sor_outliers", "sor_outliers_from_distances",
           "thread_workspace"]

CONVENTIONS = ("pcl", "open3d")

# search limits (read at call time, so that tests can force each path)
_USE_CAMERA = True                 # fit a camera model and prove image windows with it
_WINDOW_MAX = _window.WINDOW_MAX   # largest window half-width, 1..16
_TILE_SCAN_CAP = 2048              # pixels one tile search may measure before the KD-tree takes over
_MARK_MAX_TILES = 4096             # tiles one pixel may need before the KD-tree takes every point
_SAMPLE = 256                      # unproven pixels tried first to tell an unorganized cloud
_USE_COLUMNS = True                # search the unproven pixels with a known bound in columns first ...
_COLUMNS_MIN_SHARE = 1000          # ... when at least one valid pixel in this many is unproven (a floor: the sample
                                   # below decides; tall parts on end leave one in 180-220)
_COLUMNS_COST = 3.0                # ... and a tile search of them would measure more than this many pixels per
                                   # valid point (estimated from _SAMPLE of them; 0: columns whenever the share holds)
_COLUMN_WIDTH = 0.25               # column width, times the median bound of the unproven pixels
_COLUMNS_PER_POINT = 8             # largest column grid, per valid point
_COLUMN_SCAN = 1024                # entries a column search may scan per query, on average
_KD_LEAF_FEW = 64                  # the KD-tree's leaf size when it has this many points per query or more

Run = Callable[..., None]


# --------------------------------------------------------------------------------------------
# input
# --------------------------------------------------------------------------------------------
def _check_ratio(std_ratio: object, name: str = "std_ratio") -> float:
    if isinstance(std_ratio, (bool, np.bool_)) or not isinstance(std_ratio, (int, float, np.integer, np.floating)):
        raise ParameterError(f"{name} must be a finite number > 0, got {std_ratio!r}")
    ratio = float(std_ratio)
    if not (math.isfinite(ratio) and ratio > 0.0):
        raise ParameterError(f"{name} must be a finite number > 0, got {std_ratio!r}")
    return ratio


def _check_params(k: object, std_ratio: object, convention: object) -> tuple[int, float]:
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)):
        raise ParameterError(f"k must be an integer >= 1, got {k!r}")
    if k < 1:
        raise ParameterError(f"k must be an integer >= 1, got {k!r}")
    ratio = _check_ratio(std_ratio)
    if convention not in CONVENTIONS:
        raise ParameterError(f"convention must be one of {CONVENTIONS}, got {convention!r}")
    return int(k), ratio


@nb.njit(cache=True, nogil=True)
def _split_rows(r0, r1, a, mask, use_mask, x, y, z, valid, rowmax, span):  # type: ignore[no-untyped-def]  # numba kernel
    # float64 x, y, z planes (+inf where invalid: infinitely far from every valid point), the
    # valid mask (finite, and in ``mask`` when ``use_mask``), per row the largest |x|, |y|, |z|
    # of its valid points and the span [first, last] of its valid columns (first > last: none).
    # With a mask, only the columns between its first and last pixel of the row are read.
    W = a.shape[1]
    for r in range(r0, r1):
        lo = 0
        hi = W - 1
        if use_mask:
            while lo < W and not mask[r, lo]:
                lo += 1
            while hi >= lo and not mask[r, hi]:
                hi -= 1
        for c in range(lo):
            valid[r, c] = False
            x[r, c] = np.inf
            y[r, c] = np.inf
            z[r, c] = np.inf
        for c in range(hi + 1, W):
            valid[r, c] = False
            x[r, c] = np.inf
            y[r, c] = np.inf
            z[r, c] = np.inf
        mx = 0.0
        my = 0.0
        mz = 0.0
        first = W
        last = -1
        for c in range(lo, hi + 1):
            u = np.float64(a[r, c, 0])
            v = np.float64(a[r, c, 1])
            w = np.float64(a[r, c, 2])
            ok = np.isfinite(u) & np.isfinite(v) & np.isfinite(w)
            if use_mask:
                ok = ok & mask[r, c]
            valid[r, c] = ok
            x[r, c] = u if ok else np.inf
            y[r, c] = v if ok else np.inf
            z[r, c] = w if ok else np.inf
            mx = max(mx, abs(u) if ok else 0.0)
            my = max(my, abs(v) if ok else 0.0)
            mz = max(mz, abs(w) if ok else 0.0)
            first = min(first, c if ok else W)
            last = max(last, c if ok else -1)
        rowmax[r, 0] = mx
        rowmax[r, 1] = my
        rowmax[r, 2] = mz
        span[r, 0] = first
        span[r, 1] = last


_NO_MASK = np.ones((1, 1), dtype=bool)
_NO_MASK.setflags(write=False)


def _prepare(xyz: XYZ, run: Run, ws: SorWorkspace, mask: Mask | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                                      np.ndarray, np.ndarray, np.ndarray]:
    """float64 x, y, z planes (+inf where invalid), the valid mask, max |coordinate| per axis, and
    per row the first and last valid column (H, 2) (first > last: the row has none).

    ``mask``: only its pixels may be valid (the same planes as of the cloud with every other pixel
    NaN, without making that copy: ``xyz`` may then be a strided view, e.g. a crop of a frame)."""
    a = check_xyz(xyz)
    if a.dtype != np.float32:  # one compiled variant per dtype: float32 or float64, C order
        a = a.astype(np.float64, copy=False)
    H, W = a.shape[:2]
    if mask is None:
        a = np.ascontiguousarray(a)
    else:
        mask = check_mask(mask, name="mask", shape=(H, W))
    x, y, z = ws.empty("x", (H, W)), ws.empty("y", (H, W)), ws.empty("z", (H, W))
    valid = ws.empty("valid", (H, W), bool)
    rowmax = ws.full("rowmax", (H, 3), 0.0)
    span = ws.empty("span", (H, 2), np.int64)
    run(_split_rows, H, a, _NO_MASK if mask is None else mask, mask is not None, x, y, z, valid, rowmax, span)
    return x, y, z, valid, rowmax.max(axis=0, initial=0.0), span


# --------------------------------------------------------------------------------------------
# threads
# --------------------------------------------------------------------------------------------
@contextmanager
def _workers(ws: SorWorkspace) -> Iterator[Run]:
    """``run(kernel, n, *args)`` calls ``kernel(i0, i1, *args)`` over chunks of range(n), on
    ``numba.config.NUMBA_NUM_THREADS`` threads (the cores, or the NUMBA_NUM_THREADS variable): the
    pool the workspace ``ws`` keeps from call to call.

    The kernels are serial numba functions that release the GIL: numba's own ``parallel=True``
    compiled this module several times slower, and not starting numba's threading layer leaves
    its choice (a process-wide setting) to the command line.
    """
    n_threads = int(nb.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]  # numba.config sets it at import
    if n_threads <= 1:
        yield lambda kernel, n, *args: kernel(0, n, *args) if n else None
        return
    pool = ws.pool(n_threads)

    def run(kernel: Callable[..., None], n: int, *args: object) -> None:
        n_chunks = min(n, 8 * n_threads)
        edges = [n * i // n_chunks for i in range(n_chunks + 1)] if n else []
        jobs = [pool.submit(kernel, i0, i1, *args) for i0, i1 in itertools.pairwise(edges) if i1 > i0]
        wait(jobs)  # all of them, even when one fails: none may write into the workspace after the call
        for job in jobs:
            job.result()

    yield run


# --------------------------------------------------------------------------------------------
# the search
# --------------------------------------------------------------------------------------------
def _mean_distances(x: np.ndarray, y: np.ndarray, z: np.ndarray, valid: np.ndarray, span: np.ndarray, amax: np.ndarray,
                    m: int, divisor: float, run: Run, ws: SorWorkspace) -> np.ndarray:
    """(H, W) d̄ over the m smallest squared distances (self included); anything where invalid.
    ``span``: per row the first and last valid column (:func:`_prepare`). The result is an array
    of the workspace ``ws``, like every full-frame temporary of the search."""
    H, W = valid.shape
    P = _camera.fit_camera(x, y, z, valid) if _USE_CAMERA else None
    use_cam = P is not None
    S = _camera.camera_scale(P, amax) if P is not None else 1.0
    if P is None:
        P = np.zeros((3, 4))
    stats = _camera.new_stats(H, W, ws)
    run(_camera.block_rows, stats[0].shape[0], x, y, z, valid, span, P, S, use_cam, *stats)
    rowU, colV, tcount, tbox, tuv, bad = stats
    use_cam = use_cam and not bad.any()  # some depth not safely positive: no camera bounds
    M = float(amax.max())
    if use_cam:
        R = _camera.band_tables(rowU, P, 0, M, ws.empty("R", (rowU.shape[0] + 1, 8, W)))
        C = _camera.band_tables(colV, P, 1, M, ws.empty("C", (colV.shape[0] + 1, 8, H)))
        Q, floor = _camera.corner_tables(tuv, P, S, M)
    else:  # placeholders of the right shapes (the row stage reads them, then ignores them)
        R = ws.full("R", (rowU.shape[0] + 1, 8, W), 0.0)
        C = ws.full("C", (colV.shape[0] + 1, 8, H), 0.0)
        Q = np.zeros((rowU.shape[0] + 1, colV.shape[0] + 1, 4, 8))
        floor = np.zeros(Q.shape[:2])
    wmax = int(min(max(_WINDOW_MAX, 1), _window.WINDOW_MAX))
    w0 = _window.first_window(m, wmax)
    dbar = ws.empty("dbar", (H, W))
    unproven = ws.full("unproven", (H,), 0, np.int64)
    run(_window.window_rows, H, x, y, z, valid, span, m, divisor, w0, wmax, use_cam, R, C, Q, floor, dbar, unproven,
        _window.slots_for(m))
    rows, cols = _window.unproven_pixels(valid, dbar, unproven)  # their dbar: minus the m-th squared distance
    if rows.size:
        def tree() -> tuple[np.ndarray, ...]:  # built only when a tile search runs
            return _search.build_quadtree(tcount, tbox, tuv, P, M, use_cam)

        _fallback(x, y, z, valid, rows, cols, -dbar[rows, cols], m, divisor, use_cam, tree, dbar, run, ws, tbox)
    return dbar


def _tile_range(tbox: np.ndarray) -> tuple[float, float, float, float, float, float]:
    """Smallest and largest x, y and z of the valid pixels (``zcut.sor_search.valid_range``'s values), from the
    per-tile boxes of :func:`zcut.sor_camera.block_rows` instead of another pass over the frame: every valid pixel
    is in its tile's box, the boxes of tiles without one are empty (+inf, -inf), and extremes are exact in any
    order."""
    lo = tbox[..., :3].min(axis=(0, 1), initial=np.inf)
    hi = tbox[..., 3:].max(axis=(0, 1), initial=-np.inf)
    return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]), float(lo[2]), float(hi[2])


def _column_stage(x: np.ndarray, y: np.ndarray, z: np.ndarray, valid: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                  lim: np.ndarray, m: int, divisor: float, dbar: np.ndarray, run: Run, ws: SorWorkspace,
                  n_valid: int, tbox: np.ndarray) -> np.ndarray:
    """k-nearest search in columns (:mod:`zcut.columns`) for the unproven pixels with a finite
    bound ``lim`` (:func:`_fallback` calls it when they are many and the tile search would measure
    many pixels for each: tall parts on end, flying pixels everywhere). ``n_valid``: the valid
    pixels; ``tbox``: the tiles' boxes (:func:`_tile_range`). Writes their d̄ into dbar; returns which it settled."""
    done = np.zeros(rows.size, dtype=bool)
    rad = np.sqrt(lim)
    eligible = np.isfinite(rad) & (rad > 0.0)
    if not eligible.any():
        return done
    width = float(np.median(rad[eligible])) * _COLUMN_WIDTH
    x0, x1, y0, y1, z0, z1 = _tile_range(tbox)
    inv = 1.0 / width
    with np.errstate(over="ignore", invalid="ignore"):
        nx, ny = np.floor((x1 - x0) * inv) + 1.0, np.floor((y1 - y0) * inv) + 1.0
        nz = np.floor((z1 - z0) * inv) + 1.0
    if not (math.isfinite(inv) and nx * ny <= _COLUMNS_PER_POINT * n_valid + 4096 and nz < 2.0**53):
        return done
    nx, ny = int(nx), int(ny)
    # only the columns a query's ball can reach (a point outside them is farther than its bound,
    # so never among its m nearest) are filled
    marked = ws.full("marked", (nx * ny,), False, bool)
    _columns.mark_columns(x[rows, cols], y[rows, cols], np.where(eligible, rad, -1.0), x0, y0, inv, nx, ny, marked)
    start = ws.empty("col_start", (nx * ny + 1,), np.int64)
    n = int(_columns.count_columns(x, y, z, x0, y0, inv, nx, marked, start))
    xs, ys, zs = ws.empty("col_x", (n,)), ws.empty("col_y", (n,)), ws.empty("col_z", (n,))
    mult, ks = ws.empty("col_mult", (n,), np.int64), ws.empty("col_slab", (n,), np.int64)
    n = int(_columns.fill_columns(x, y, z, x0, y0, z0, inv, nx, marked, start, ws.empty("col_fill", (nx * ny,), np.int64),
                                  xs, ys, zs, mult, ks))
    columns = (start, xs[:n], ys[:n], zs[:n], mult[:n], ks[:n])
    out = np.zeros(rows.size)
    run(_search.column_queries, rows.size, x, y, z, rows, cols, lim, eligible, m, divisor, int(_COLUMN_SCAN),
        columns, x0, y0, z0, inv, nx, ny, out, done)
    dbar[rows[done], cols[done]] = out[done]
    return done


def _fallback(x: np.ndarray, y: np.ndarray, z: np.ndarray, valid: np.ndarray, rows: np.ndarray, cols: np.ndarray,
              lim: np.ndarray, m: int, divisor: float, use_cam: bool, make_tree: Callable[[], tuple[np.ndarray, ...]],
              dbar: np.ndarray, run: Run, ws: SorWorkspace, tbox: np.ndarray) -> None:
    """Columns, then a tile search for the unproven pixels left (over the quadtree ``make_tree()``
    builds), then a KD-tree for those it could not finish.

    The columns are built when the unproven pixels are many (one valid pixel in
    ``_COLUMNS_MIN_SHARE`` or more) and a tile search of ``_SAMPLE`` of them, evenly spread,
    measures more than ``_COLUMNS_COST`` pixels per valid point when scaled to all of them: building
    the columns reads every valid point, which pays only when the tile searches would read more
    (tall parts on end: ≈ 800 pixels a search; scattered invalid pixels: ≈ 160, and the columns
    cost more than the searches). The sample's results are kept. Every path is exact: the choice
    changes the time, never d̄."""
    tree: tuple[np.ndarray, ...] | None = None

    def tile_search(rows: np.ndarray, cols: np.ndarray,
                    lim: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        nonlocal tree
        if tree is None:
            tree = make_tree()
        out, outcome, radius2 = np.zeros(rows.size), np.zeros(rows.size, np.uint8), np.full(rows.size, np.inf)
        measured = np.zeros(rows.size, np.int64)
        run(_search.tile_queries, rows.size, x, y, z, valid, rows, cols, lim, m, divisor, int(_TILE_SCAN_CAP),
            use_cam, tree, out, outcome, radius2, measured)
        return out, outcome, radius2, measured

    n_valid = int(np.count_nonzero(valid))
    if _USE_COLUMNS and rows.size * _COLUMNS_MIN_SHARE >= n_valid:
        use_columns = True
        if _COLUMNS_COST > 0.0:  # would the tile search read more than the column build does?
            pick = np.unique(np.linspace(0, rows.size - 1, min(_SAMPLE, rows.size)).astype(np.int64))
            out, outcome, _, measured = tile_search(rows[pick], cols[pick], lim[pick])
            use_columns = float(measured.mean()) * rows.size > _COLUMNS_COST * n_valid
            found = np.zeros(rows.size, dtype=bool)
            found[pick] = outcome == _search.FOUND
            dbar[rows[found], cols[found]] = out[outcome == _search.FOUND]
            rows, cols, lim = rows[~found], cols[~found], lim[~found]
            if not rows.size:
                return
        if use_columns:
            done = _column_stage(x, y, z, valid, rows, cols, lim, m, divisor, dbar, run, ws, n_valid, tbox)
            if done.all():
                return
            rows, cols, lim = rows[~done], cols[~done], lim[~done]

    def kd_search(pts: np.ndarray, rows: np.ndarray, cols: np.ndarray, lim: np.ndarray) -> None:
        # few queries over many points (the tile searches that hit their cap): larger leaves, a
        # shallower tree, less to build for the few leaves the queries scan
        few = rows.size * _KD_LEAF_FEW <= pts.shape[0]
        kd = _search.kd_build(pts, _KD_LEAF_FEW if few else _search.KD_LEAF)
        out = np.zeros(rows.size)
        run(_search.kd_queries, rows.size, x, y, z, rows, cols, lim, m, divisor, kd, out)
        dbar[rows, cols] = out

    if rows.size > max(4 * _SAMPLE, valid.size // 8):  # not organized at all? then every tile search would hit the cap
        pick = np.linspace(0, rows.size - 1, _SAMPLE).astype(np.int64)
        _, outcome, _, _ = tile_search(rows[pick], cols[pick], lim[pick])
        if 2 * np.count_nonzero(outcome != _search.FOUND) > pick.size:
            kd_search(_search.gather_valid(x, y, z, valid), rows, cols, lim)
            return
    out, outcome, radius2, _ = tile_search(rows, cols, lim)
    assert tree is not None
    done = outcome == _search.FOUND
    dbar[rows[done], cols[done]] = out[done]
    if done.all():
        return
    rows, cols, radius2 = rows[~done], cols[~done], radius2[~done]
    every = bool((outcome[~done] == _search.NEEDS_KD_ALL).any())
    if not every:
        level_off = tree[0]
        mark, over = np.zeros(int(level_off[1]), dtype=bool), np.zeros(rows.size, dtype=bool)
        run(_search.mark_queries, rows.size, x, y, z, rows, cols, radius2, int(_MARK_MAX_TILES), use_cam, tree,
            mark, over)
        every = bool(over.any())
    if every:
        pts = _search.gather_valid(x, y, z, valid)
    else:
        pts = _search.gather_tiles(x, y, z, valid, mark, int(tree[2][0]))
    kd_search(pts, rows, cols, radius2)


# --------------------------------------------------------------------------------------------
# statistics
# --------------------------------------------------------------------------------------------
@nb.njit(cache=True, inline="always")
def _row_terms(dbar, valid, open3d, r, row):  # type: ignore[no-untyped-def]  # numba kernel
    # row[c] := what pixel (r, c) adds to the sum of d̄: d̄ where it is summed, +0.0 elsewhere (a
    # select the compiler vectorizes: no branch, no arithmetic on what invalid pixels hold)
    for c in range(valid.shape[1]):
        d = dbar[r, c]
        row[c] = d if valid[r, c] & ((not open3d) | (d > 0.0)) else 0.0


@nb.njit(cache=True, inline="always")
def _row_deviations(dbar, valid, open3d, r, mean, row):  # type: ignore[no-untyped-def]  # numba kernel
    # row[c] := what pixel (r, c) adds to the sum of squared deviations: (d̄ - mean)² where it is
    # summed, +0.0 elsewhere (selected after the arithmetic: with a mean of inf, (mean - mean)² is NaN)
    for c in range(valid.shape[1]):
        d = dbar[r, c]
        summed = valid[r, c] & ((not open3d) | (d > 0.0))
        t = d if summed else mean
        v = (t - mean) * (t - mean)
        row[c] = v if summed else 0.0


@nb.njit(cache=True)
def _mean_std(dbar, valid, n, open3d):  # type: ignore[no-untyped-def]  # numba kernel
    # mean and std of the statistics (see _outlier_masks): each sum one accumulator over the summed
    # values in row-major order. A row's terms are made first (:func:`_row_terms`,
    # :func:`_row_deviations`: a vectorized select, +0.0 where a pixel is not summed), then added
    # one by one, every pixel's: an accumulator starts at +0.0 and a sum is -0.0 only when both
    # operands are, so it is never -0.0, and acc + 0.0 is acc exactly (NaN and inf included). So
    # the sums are those of adding only the summed values, in the same order, bit for bit. (Adding
    # d̄ if summed else 0.0 in one loop compiles to a branch per pixel, which valid pixels at random
    # mispredict; gathering each row's summed values to the front of a buffer, what this did before,
    # made each pass ~3 times slower once the frame is out of the cache.)
    H, W = valid.shape
    row = np.empty(W)
    s = 0.0
    for r in range(H):
        _row_terms(dbar, valid, open3d, r, row)
        for c in range(W):
            s = s + row[c]
    mean = s / n
    sq = 0.0
    for r in range(H):
        _row_deviations(dbar, valid, open3d, r, mean, row)
        for c in range(W):
            sq = sq + row[c]
    return mean, math.sqrt(sq / (n - 1))


@nb.njit(cache=True)
def _outlier_masks(dbar, valid, n, ratios, open3d):  # type: ignore[no-untyped-def]  # numba kernel
    # pcl: d̄ > mean + ratio * std, sample std (n - 1), sequential sums in row-major order.
    # open3d (PointCloud::RemoveStatisticalOutliers): the sums run over d̄ > 0 only but divide by
    # the count of ALL points; inlier iff 0 < d̄ < threshold (strict).
    H, W = valid.shape
    mean, std = _mean_std(dbar, valid, n, open3d)
    out = np.empty((ratios.shape[0], H, W), np.bool_)
    for i in range(ratios.shape[0]):
        thr = mean + ratios[i] * std
        for r in range(H):
            for c in range(W):
                d = dbar[r, c]
                if open3d:
                    out[i, r, c] = valid[r, c] & ~((d > 0.0) & (d < thr))
                else:
                    out[i, r, c] = valid[r, c] & (d > thr)
    return out


# --------------------------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------------------------
def sor_mean_distances(xyz: XYZ, *, k: int = 4, convention: str = "pcl", mask: Mask | None = None) -> np.ndarray:
    """Mean distance d̄ of every valid pixel to its k nearest neighbours, exactly.

    Parameters
    ----------
    xyz : (H, W, 3) float ndarray
        Organized cloud; a pixel is valid iff its three coordinates are finite.
    k : int
        Number of neighbours, >= 1.
    convention : {"pcl", "open3d"}
        ``"pcl"``: the point itself excluded; ``"open3d"``: included (at distance 0).
    mask : (H, W) bool ndarray, optional
        Only these pixels may be valid: the result of ``xyz`` with every other pixel NaN, without
        that copy.

    Returns
    -------
    (H, W) float64 ndarray
        d̄ in the unit of ``xyz``; NaN on invalid pixels. With fewer valid points than the
        search needs, the mean is over all the valid points there are (Open3D's behaviour).
    """
    k, _ = _check_params(k, 1.0, convention)
    with thread_workspace().call() as ws, _workers(ws) as run:
        x, y, z, valid, amax, span = _prepare(xyz, run, ws, mask)
        dbar = np.full(valid.shape, np.nan)  # the caller's: never a workspace array
        n = int(np.count_nonzero(valid))
        if n == 0:
            return dbar
        m = k + 1 if convention == "pcl" else k
        divisor = float(k)
        if n < m:  # too few points for a full neighbourhood: average over what exists
            m = n
            divisor = float(n - 1 if convention == "pcl" else n)
            if divisor == 0.0:
                dbar[valid] = 0.0
                return dbar
        np.copyto(dbar, _mean_distances(x, y, z, valid, span, amax, m, divisor, run, ws), where=valid)
    return dbar


def sor_outliers_from_distances(
    dbar: np.ndarray, *, k: int, std_ratios: Iterable[float], convention: str = "pcl"
) -> np.ndarray:
    """Outlier masks for several thresholds from one d̄ computation (for a sweep over std_ratio).

    ``sor_outliers_from_distances(sor_mean_distances(xyz, k=k, convention=c), k=k,
    std_ratios=ratios, convention=c)[i]`` equals ``sor_outliers(xyz, k=k, std_ratio=ratios[i],
    convention=c)`` exactly.

    Parameters
    ----------
    dbar : (H, W) float ndarray
        d̄ as :func:`sor_mean_distances` returns it for the same ``k`` and ``convention``; NaN
        marks invalid pixels.
    k : int
        The k that d̄ was computed with (fewer than k + 1 valid pixels: no outliers).
    std_ratios : iterable of float
        Thresholds in standard deviations, each finite and > 0.
    convention : {"pcl", "open3d"}
        See :func:`sor_outliers`.

    Returns
    -------
    (n_ratios, H, W) bool ndarray
        True at outliers, one mask per entry of ``std_ratios`` in order.

    Raises
    ------
    InputShapeError
        ``dbar`` is not an (H, W) float array.
    ParameterError
        ``k``, an entry of ``std_ratios`` or ``convention`` out of range.
    """
    d = np.asarray(dbar)
    if d.ndim != 2 or not np.issubdtype(d.dtype, np.floating):
        raise InputShapeError(f"dbar must be an (H, W) float array, got {describe_array(d)}")
    if isinstance(std_ratios, (str, bytes)) or not isinstance(std_ratios, Iterable):
        raise ParameterError(f"std_ratios must be an iterable of numbers, got {std_ratios!r}")
    ratios = np.array([_check_ratio(s, "every std_ratio") for s in std_ratios], dtype=np.float64)
    k, _ = _check_params(k, 1.0, convention)
    d = np.ascontiguousarray(d, dtype=np.float64)
    with thread_workspace().call() as ws:
        valid = np.isnan(d, out=ws.empty("valid", d.shape, bool))
        np.logical_not(valid, out=valid)
        n = int(np.count_nonzero(valid))
        if n < k + 1 or ratios.size == 0:
            return np.zeros((ratios.size, *d.shape), dtype=bool)
        return _outlier_masks(d, valid, float(n), ratios, convention == "open3d")


def sor_outliers(xyz: XYZ, *, k: int = 4, std_ratio: float = 1.0, convention: str = "pcl",
                 mask: Mask | None = None) -> Mask:
    """Statistical outlier removal on an organized cloud (docs/filters.md).

    Parameters
    ----------
    xyz : (H, W, 3) float ndarray
        Organized cloud; a pixel is valid iff its three coordinates are finite. float32 is upcast
        to float64. Invalid pixels are never outliers and never neighbours.
    k : int
        Number of nearest neighbours, >= 1 (pcdenoise / the paper: 4).
    std_ratio : float
        Threshold in standard deviations, finite and > 0 (pcdenoise: 1).
    convention : {"pcl", "open3d"}
        ``"pcl"``: d̄ over the k nearest other points; outlier iff d̄ > μ + std_ratio·σ, with μ the
        mean and σ the sample standard deviation of d̄ over the valid points.
        ``"open3d"``: exactly what ``open3d.geometry.PointCloud.remove_statistical_outlier(k,
        std_ratio)`` keeps when given the valid points in row-major order: the point itself counts
        as a neighbour at distance 0, μ = (sum of the d̄ > 0) / (number of points), σ² = (sum over
        the d̄ > 0 of (d̄ − μ)²) / (number of points − 1); inlier iff 0 < d̄ < μ + std_ratio·σ, and
        the outliers are the other valid pixels (so a point with k coincident copies is an outlier).
    mask : (H, W) bool ndarray, optional
        Only these pixels may be valid: the result of ``xyz`` with every other pixel NaN (exactly),
        without that copy; ``xyz`` may be a strided view (a crop of a frame).

    Returns
    -------
    (H, W) bool ndarray
        True at outliers. Fewer than k + 1 valid points: no outliers.

    Raises
    ------
    InputShapeError
        ``xyz`` is not an (H, W, 3) float array.
    ParameterError
        ``k``, ``std_ratio`` or ``convention`` out of range.

    See Also
    --------
    sor_outliers_from_distances : every threshold of a sweep from one d̄ computation.
    """
    k, ratio = _check_params(k, std_ratio, convention)
    with thread_workspace().call() as ws, _workers(ws) as run:
        x, y, z, valid, amax, span = _prepare(xyz, run, ws, mask)
        n = int(np.count_nonzero(valid))
        if n < k + 1:
            return np.zeros(valid.shape, dtype=bool)
        m = k + 1 if convention == "pcl" else k
        dbar = _mean_distances(x, y, z, valid, span, amax, m, float(k), run, ws)
        # the masks are made by the kernel: the caller's, never workspace arrays
        return _outlier_masks(dbar, valid, float(n), np.array([ratio]), convention == "open3d")[0]
