"""The bin footprint from the RGB image (paper §5.1/§5.2).

RGB -> gray -> threshold -> dilate -> connected components -> the component covering the image
centre (else the largest) -> fill holes -> erode back by the dilation radius. The bright plastic
walls and rim of the bin survive the threshold; filling the holes adds the (possibly dark) parts
inside, so the result is the bin's footprint on the image. The final erosion (with the dilation, a
morphological closing) removes the fringe of table the dilation added. Everything outside the
footprint is table.

The bright component is not all bin: shiny parts are as bright as the plastic, and those touching
the walls join the component (a third to a half of it on synthetic shiny piles). The pixels the
bin model is registered to are therefore a ring along the footprint's border (:func:`bin_pixels`):
the rim and the upper walls, which the pile, lying below the rim, does not reach.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba
import numpy as np

from .errors import InputShapeError, ParameterError, describe_array
from .params import BinMaskParams
from .types import RGB, XYZ, Mask

__all__ = ["MIN_RING_PX", "BinMaskResult", "bin_mask", "bin_mask_reference", "bin_pixels", "bin_pixels_reference",
           "fill_holes"]

#: The narrowest ring of bin pixels (:func:`bin_pixels`), in pixels: in a small image (a bin 100 px
#: across) a fifth of the inradius is the rim and little else, too little for the ICP to hold on to.
MIN_RING_PX = 10.0


@dataclass(frozen=True, slots=True)
class BinMaskResult:
    """The bin footprint of one image.

    Attributes
    ----------
    mask : (H, W) bool ndarray
        The footprint: the chosen component with its holes filled, eroded back by the dilation
        radius (never losing a bright pixel of the component).
    walls : (H, W) bool ndarray
        The bright pixels of the chosen component (before dilation and filling): the walls and the
        rim the bin model is registered to.
    found : bool
        False when no bright component of at least ``min_area_frac`` of the image exists; then both
        masks are all False.
    area_px : int
        Pixels in ``mask``.
    n_components : int
        Bright components after dilation (all sizes).
    centroid_rc : tuple of float
        (row, col) centroid of ``mask``; NaN when not found.
    bbox_rc : tuple of int
        (row0, col0, row1, col1) of ``mask``, end exclusive; zeros when not found.
    covers_centre : bool
        True when the chosen component covers the image centre pixel.
    """

    mask: Mask
    walls: Mask
    found: bool
    area_px: int
    n_components: int
    centroid_rc: tuple[float, float]
    bbox_rc: tuple[int, int, int, int]
    covers_centre: bool


def _check_rgb(rgb: RGB) -> np.ndarray:
    a = np.asarray(rgb)
    if a.ndim != 3 or a.shape[2] != 3 or a.dtype != np.uint8:
        raise InputShapeError(f"rgb must be an (H, W, 3) uint8 array, got {describe_array(a)}")
    return a


def fill_holes(mask: Mask) -> Mask:
    """Fill the holes of a binary mask: background pixels not 4-connected to the image border.

    Parameters
    ----------
    mask : (H, W) bool ndarray

    Returns
    -------
    (H, W) bool ndarray
    """
    m = np.ascontiguousarray(mask, dtype=np.uint8)
    h, w = m.shape
    padded = np.zeros((h + 2, w + 2), np.uint8)
    padded[1:-1, 1:-1] = m
    flood = np.zeros((h + 4, w + 4), np.uint8)
    cv2.floodFill(padded, flood, (0, 0), 2, flags=4)
    return (padded[1:-1, 1:-1] != 2)


@numba.njit(cache=True, nogil=True)
def _pad_component(labels, y, x, chosen, padded):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """``padded`` (uint8, the box's shape plus one pixel each side): 1 where the box of ``labels`` at row
    ``y``, column ``x`` holds ``chosen``, 0 elsewhere and on the frame."""
    h, w = padded.shape[0] - 2, padded.shape[1] - 2
    padded[0, :] = 0
    padded[h + 1, :] = 0
    for r in range(h):
        lr = labels[y + r, x:x + w]
        pr = padded[r + 1]
        pr[0] = 0
        pr[w + 1] = 0
        for c in range(w):
            pr[c + 1] = lr[c] == chosen


def _flooded(labels: np.ndarray, box: tuple[int, int, int, int], chosen: int) -> np.ndarray:
    """The box (x, y, bw, bh) of ``labels`` padded by one pixel, flooded as :func:`fill_holes` floods it: 1
    where it holds ``chosen`` (the flood changes only zeros), 0 in the component's holes, 2 outside."""
    x, y, bw, bh = box
    padded = np.empty((bh + 2, bw + 2), np.uint8)
    _pad_component(labels, y, x, chosen, padded)
    flood = np.zeros((bh + 4, bw + 4), np.uint8)
    cv2.floodFill(padded, flood, (0, 0), 2, flags=4)
    return padded


def _fill_component(labels: np.ndarray, box: tuple[int, int, int, int], chosen: int) -> Mask:
    """``fill_holes(labels[y:y + bh, x:x + bw] == chosen)`` for ``box`` = (x, y, bw, bh), without its
    copies (the comparison written into the padded image at once, :func:`_flooded`)."""
    return (_flooded(labels, box, chosen)[1:-1, 1:-1] != 2)


def _check_pixels_args(result: BinMaskResult, xyz: XYZ, ring_frac: float, min_ring_px: float) -> np.ndarray:
    a = np.asarray(xyz)
    shape = result.mask.shape
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[:2] != shape or not np.issubdtype(a.dtype, np.floating):
        raise InputShapeError(f"xyz must be an {shape + (3,)} float array (the bin mask's image), "
                              f"got {describe_array(a)}")
    if isinstance(ring_frac, bool) or not isinstance(ring_frac, (int, float, np.integer, np.floating)) \
            or not 0.0 < float(ring_frac) <= 1.0:
        raise ParameterError(f"ring_frac must be a number in (0, 1], got {ring_frac!r}")
    if isinstance(min_ring_px, bool) or not isinstance(min_ring_px, (int, float, np.integer, np.floating)) \
            or not min_ring_px >= 0:
        raise ParameterError(f"min_ring_px must be a number >= 0, got {min_ring_px!r}")
    return a


#: The bytes of ``bin_mask``'s grown image a word holds when all eight are set (0/1 bytes).
_ONES = np.uint64(0x0101010101010101)


def _row_words(img: np.ndarray) -> np.ndarray:
    """``img`` (H, W) uint8, C order, as (H, W / 8) uint64 words when its rows are whole aligned words;
    else an (H, 0) array (:func:`_component_stats` then reads bytes only)."""
    h, w = img.shape
    if w % 8 == 0 and img.flags.c_contiguous and img.ctypes.data % 8 == 0:
        return img.view(np.uint64)
    return np.empty((h, 0), np.uint64)


@numba.njit(cache=True, nogil=True)
def _component_stats(labels, grown, words, n):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """OpenCV's component statistics (left, top, width, height, area) of labels 0..n-1, by runs.

    ``labels`` are ``cv2.connectedComponents``' of ``grown`` (uint8): 0 where ``grown`` is 0, else the
    pixel's component. Within a row, a run of nonzero pixels of ``grown`` is one component (neighbours in a
    row are connected) and a run of zeros is label 0, so the runs of ``labels`` are those of ``grown`` and a
    run's label is its first pixel's: the image is scanned as bytes (4 times less memory than the labels),
    eight at a time where a run goes on over whole ``words`` (``_row_words(grown)``: all zero, or all
    :data:`_ONES`), and a label read once a run. The same statistics as a scan of every label (5.0 -> 2.2
    CPU ms on a 1920 x 1200 zinc-nut frame's ~25k runs; tests/zcut/test_binmask_stats.py)."""
    H, W = labels.shape
    nw = words.shape[1]
    lo_c = np.full(n, W, np.int64)
    hi_c = np.full(n, -1, np.int64)
    lo_r = np.full(n, H, np.int64)
    hi_r = np.full(n, -1, np.int64)
    area = np.zeros(n, np.int64)
    for r in range(H):
        g = grown[r]
        wr = words[r]
        c = 0
        while c < W:
            on = g[c] != 0
            start = c
            c += 1
            while c < W and (c & 7) != 0 and (g[c] != 0) == on:  # up to the next word
                c += 1
            if c < W and (c & 7) == 0 and (g[c] != 0) == on:  # whole words of the run, then its last bytes
                t = _ONES if on else np.uint64(0)
                k = c >> 3
                while k < nw and wr[k] == t:
                    k += 1
                c = k << 3
                while c < W and (g[c] != 0) == on:
                    c += 1
            lab = labels[r, start]
            area[lab] += c - start
            if start < lo_c[lab]:
                lo_c[lab] = start
            if c - 1 > hi_c[lab]:
                hi_c[lab] = c - 1
            if r < lo_r[lab]:
                lo_r[lab] = r
            hi_r[lab] = r
    stats = np.zeros((n, 5), np.int64)
    for i in range(n):
        if area[i] > 0:
            stats[i, 0] = lo_c[i]
            stats[i, 1] = lo_r[i]
            stats[i, 2] = hi_c[i] - lo_c[i] + 1
            stats[i, 3] = hi_r[i] - lo_r[i] + 1
            stats[i, 4] = area[i]
    return stats


@numba.njit(cache=True, nogil=True)
def _assemble(filled, flooded, bright, y, x, keep_bright, mask, walls):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """On the chosen component's box (``filled``'s shape at row ``y``, column ``x`` of the full
    images; masks as 0/1 bytes): walls = comp & bright, mask = filled | walls (only ``filled``
    unless ``keep_bright``); the mask's per-row and per-column counts. The component is where the box's
    flooded image (:func:`_flooded`, one pixel of frame) holds 1: its bytes are read, not the labels'
    int32 (a quarter of the memory)."""
    H, W = filled.shape
    per_row = np.zeros(H, np.int64)
    per_col = np.zeros(W, np.int64)
    kb = np.uint8(1 if keep_bright else 0)
    for r in range(H):
        lr = flooded[r + 1, 1:W + 1]
        br = bright[y + r, x:x + W]
        fr = filled[r]
        mr = mask[y + r, x:x + W]
        wr = walls[y + r, x:x + W]
        k = 0
        for c in range(W):
            w = np.uint8(lr[c] == 1) & br[c]
            m = fr[c] | (kb & w)
            wr[c] = w
            mr[c] = m
            k += m
            per_col[c] += m
        per_row[r] = k
    return per_row, per_col


@numba.njit(cache=True, nogil=True)
def _ring(dist, thr, walls, xyz, r0, r1, c0, c1, all_in, out):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """On the crop [r0:r1, c0:c1] (``dist``'s unless ``all_in``; ``walls`` and ``out`` as 0/1 bytes):
    out = walls & (dist <= thr, or everywhere when ``all_in``) & finite(xyz)."""
    W = c1 - c0
    for r in range(r1 - r0):
        wr = walls[r0 + r, c0:c0 + W]
        orow = out[r0 + r, c0:c0 + W]
        for c in range(W):
            if wr[c] and (all_in or dist[r, c] <= thr):
                p = xyz[r0 + r, c0 + c]
                orow[c] = np.isfinite(p[0]) and np.isfinite(p[1]) and np.isfinite(p[2])


#: "No zero in this column" among the vertical distances of :func:`_column_distances` (int16).
_NONE = (1 << 15) - 1


@numba.njit(cache=True, nogil=True)
def _row_distances(f, sqr, inv, out):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """One row of OpenCV's precise distance transform (``trueDistTrans``'s second stage, its float32
    arithmetic step by step): ``f`` the squared column distances (1e15 where a column has no zero);
    the row's largest distance."""
    n = f.shape[0]
    inf = np.float32(1e15)
    z = np.empty(n + 1, np.float32)
    v = np.empty(n + 1, np.int64)
    v[0] = 0
    z[0] = -inf
    z[1] = inf
    k = 0
    for q in range(1, n):
        fq = f[q]
        while True:
            p = v[k]
            s = (((fq + sqr[q]) - f[p]) - sqr[p]) * inv[q - p]
            if s > z[k]:
                k += 1
                v[k] = q
                z[k] = s
                z[k + 1] = inf
                break
            k -= 1
    k = 0
    best = np.float32(0.0)
    for q in range(n):
        while z[k + 1] < q:
            k += 1
        p = v[k]
        x = np.float32(np.sqrt(sqr[abs(q - p)] + f[p]))
        out[q] = x
        if x > best:
            best = x
    return best


@numba.njit(cache=True, nogil=True)
def _column_distances(fp):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """(m, n) int16: every pixel's distance to the nearest zero of its column in the crop ``fp``
    (0/1 bytes; ``_NONE`` when the column has none), and each row's largest."""
    m, n = fp.shape
    g = np.empty((m, n), np.int16)
    run = np.full(n, _NONE, np.int32)
    for r in range(m):  # down: rows since the last zero above
        fr = fp[r]
        gr = g[r]
        for c in range(n):
            x = min(run[c] + 1, _NONE)
            x = x if fr[c] else 0
            run[c] = x
            gr[c] = x
    run[:] = _NONE
    row_max = np.zeros(m, np.int64)
    for r in range(m - 1, -1, -1):  # up: and below
        fr = fp[r]
        gr = g[r]
        best = 0
        for c in range(n):
            x = min(run[c] + 1, _NONE)
            x = x if fr[c] else 0
            run[c] = x
            y = min(x, gr[c])
            y = y if y < m else _NONE
            gr[c] = y
            best = max(best, y)
        row_max[r] = best
    return g, row_max


@numba.njit(cache=True, nogil=True)
def _largest_distance(g, row_max, order):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """The largest value of OpenCV's distance transform of the crop: rows in decreasing order of
    their largest column distance (a bound of the row's distances), computed until no remaining
    row can beat the best found."""
    m, n = g.shape
    sqr = np.empty(n, np.float32)
    inv = np.empty(n, np.float32)
    sqr[0] = 0.0
    inv[0] = 0.0
    for i in range(1, n):
        inv[i] = np.float32(0.5 / i)
        sqr[i] = np.float32(i * i)
    f = np.empty(n, np.float32)
    out = np.empty(n, np.float32)
    best = np.float32(-1.0)
    for i in range(m):
        r = order[i]
        bound = row_max[r]
        if bound < _NONE and np.float32(np.sqrt(np.float32(bound * bound))) <= best:
            break
        for c in range(n):
            x = np.int64(g[r, c])
            f[c] = np.float32(x * x) if x < _NONE else np.float32(1e15)
        x = _row_distances(f, sqr, inv, out)
        if x > best:
            best = x
    return best


@numba.njit(cache=True, nogil=True)
def _ring_bounded(g, vin, vout, walls, xyz, r0, c0, out):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """out = walls & (squared distance to the nearest zero <= vin) & finite(xyz) on the crop at
    (r0, c0), from the column distances ``g``: in the ring when the vertical or the horizontal
    distance is within reach; out of it when no column within reach of ``vout`` has its zero within
    that reach; else by the exact squared distance over those columns. Returns the number of bright
    pixels with a finite point whose squared distance lies in (vin, vout]: those the two bounds do
    not decide (0 when ``vin == vout``); it stops at the first (``out`` then incomplete).

    A row is walked from the right; a span of columns none of which lies within reach of a column
    whose own vertical distance is within reach (``near``) is out as a whole and skipped: its pixels
    have no zero within reach either way (a zero is near) and no column that could bring them within
    reach. The exact squared distance is the minimum over every column within reach (branch-free,
    so vectorised); the first one within ``vin`` decided the same before (the order changes no
    minimum)."""
    m, n = g.shape
    r_in = _isqrt_floor(vin)
    reach = _isqrt_floor(vout)
    far = 1 << 40
    zero_left = np.empty(n, np.int64)
    near_left = np.empty(n, np.int64)
    cap = np.int32(vout + 1)  # vout <= 2^25 (the shapes _bounded_shape takes), g <= _NONE: int32 holds every sum
    for r in range(m):
        gr = g[r]
        wr = walls[r0 + r, c0:c0 + n]
        orow = out[r0 + r, c0:c0 + n]
        xr = xyz[r0 + r, c0:c0 + n]
        zl = -far
        nl = -far
        for c in range(n):
            x = gr[c]
            if x == 0:
                zl = c
            if x <= reach:
                nl = c
            zero_left[c] = zl
            near_left[c] = nl
        zr = far
        nr = far
        c = n - 1
        while c >= 0:
            x = gr[c]
            if x == 0:
                zr = c
            if x <= reach:
                nr = c
            elif nr - c > reach and c - near_left[c] > reach:
                # columns near_left[c] + reach + 1 .. c: none near, so zr and nr stay; every one out
                c = near_left[c] + reach
                continue
            if not wr[c]:
                c -= 1
                continue
            inside = x <= r_in or min(c - zero_left[c], zr - c) <= r_in
            if not inside and min(c - near_left[c], nr - c) <= reach:
                best = cap
                for j in range(max(c - reach, 0), min(c + reach, n - 1) + 1):
                    y = np.int32(gr[j])
                    d = np.int32(j - c)
                    best = min(best, y * y + d * d)
                inside = best <= vin
                if not inside and best <= vout and xr[c, 0] * 0 + xr[c, 1] * 0 + xr[c, 2] * 0 == 0:
                    return 1
            if inside:
                # 0 * v is 0 for a finite v, NaN for an infinite or NaN one
                orow[c] = xr[c, 0] * 0 + xr[c, 1] * 0 + xr[c, 2] * 0 == 0
            c -= 1
    return 0


@numba.njit(cache=True, nogil=True)
def _isqrt_floor(v):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """The largest integer whose square is <= v (v >= 0)."""
    r = int(np.sqrt(v))
    while (r + 1) * (r + 1) <= v:
        r += 1
    while r * r > v:
        r -= 1
    return r


#: The bounded distance transform of :func:`bin_pixels` stands for OpenCV's precise one where that
#: is the exact Euclidean distance transform: not below 2^14 pixels or on one thread, where OpenCV
#: runs Intel IPP's (another rounding); not on crops 1449 px wide or more, where the float32
#: intersections of its parabolas could, in principle, err by more than the gap between two of them
#: at a pixel (an error-bound argument, not a formal proof: their error is below |s| 2^-23 for an
#: intersection s < W, a wrong choice needs a gap below 1/(2 W) over a slope difference below 2 W,
#: and 4 W^2 2^-23 < 1 for W <= 1448, W^2 < 2^21 (1448^2 = 2,096,704; the limit was 1447 until the
#: round of 2026-12-06g, one column short of its own bound, which sent every 1448 px crop of a
#: 1920 x 1200 zinc-nut log to OpenCV); tests/zcut/test_binmask_fast.py and test_binmask_wide.py check it
#: against OpenCV); nor where the squared distances (row^2 + col^2) leave float32's integers (2^24).
#: Elsewhere: OpenCV's.
_EXACT_MIN_PX = 1 << 14
_EXACT_MAX_W = 1448


#: Where OpenCV runs Intel IPP's transform instead (one thread, or a small crop), its distances are
#: not the exact ones but within this relative error of them (measured: at most 1.23e-7, i.e. 1 or 2
#: float32 ulps, on every pixel of synthetic, ray-traced and random footprints; tests/zcut/
#: test_binmask_fast.py checks it on each). :func:`bin_pixels` takes the exact transform's ring there
#: only when no bright pixel's distance lies within this error of the threshold (nor the threshold
#: within it of its own value, through the largest distance); else it calls OpenCV.
_IPP_REL_ERROR = 2.0**-21


def _bounded_shape(shape: tuple[int, int]) -> bool:
    """May the bounded transform stand for OpenCV's on a crop this shape, exactly or within
    :data:`_IPP_REL_ERROR` (see above)?"""
    m, n = shape
    return n <= _EXACT_MAX_W and m * m + n * n < (1 << 24)


def _exact_opencv(shape: tuple[int, int]) -> bool:
    """Is OpenCV's precise distance transform of a crop this shape the exact one (see above)?"""
    m, n = shape
    return m * n >= _EXACT_MIN_PX and _bounded_shape(shape) and cv2.getNumThreads() > 1


def _ring_threshold(largest: float, ring_frac: float, min_ring_px: float) -> np.float32:
    """The ring's threshold of :func:`bin_pixels_reference` (compared in float32) for the largest
    distance ``largest``."""
    return np.float32(max(float(ring_frac) * float(largest), float(min_ring_px)))


def _vmax_below(t: float) -> int:
    """The largest integer V whose float32 square root is <= ``t`` (a float64 bound)."""
    cap = 1 << 25
    v = min(int(np.floor(t * t)), cap)
    while v < cap and float(np.sqrt(np.float32(v + 1))) <= t:
        v += 1
    while v >= 0 and float(np.sqrt(np.float32(v))) > t:
        v -= 1
    return v


def _near_bounds(largest: np.float32, ring_frac: float, min_ring_px: float) -> tuple[int, int]:
    """(vin, vout) where OpenCV's distances are IPP's, within :data:`_IPP_REL_ERROR` of the exact
    ones: a squared distance up to vin is in the ring whatever IPP's rounding, one above vout out of
    it. ``largest`` is the exact transform's largest distance; IPP's is within the error of it."""
    e = _IPP_REL_ERROR
    lo = float(_ring_threshold(float(largest) * (1.0 - e), ring_frac, min_ring_px))
    hi = float(_ring_threshold(float(largest) * (1.0 + e), ring_frac, min_ring_px))
    # float32 of the products above rounds: one more float32 ulp on each side
    lo = float(np.nextafter(np.float32(lo), np.float32(-np.inf)))
    hi = float(np.nextafter(np.float32(hi), np.float32(np.inf)))
    # a squared distance of 0 is 0 in IPP too, never above the threshold (>= 0)
    return max(_vmax_below(lo / (1.0 + e)), 0), max(_vmax_below(hi / (1.0 - e)), 0)


def _vmax(thr: np.float32) -> int:
    """The largest integer V whose float32 square root is <= thr (the ring's squared distances)."""
    cap = 1 << 25  # above every squared distance of a crop the bounded transform takes
    v = min(int(np.floor(float(thr) * float(thr))), cap)
    while v < cap and np.sqrt(np.float32(v + 1)) <= thr:
        v += 1
    while v >= 0 and np.sqrt(np.float32(v)) > thr:
        v -= 1
    return v


def bin_mask(rgb: RGB, *, params: BinMaskParams = BinMaskParams()) -> BinMaskResult:
    """Segment the bin footprint from an RGB image (paper §5.1; the stage's parameters are
    :class:`~zcut.params.BinMaskParams`).

    Parameters
    ----------
    rgb : (H, W, 3) uint8 ndarray
    params : BinMaskParams
        ``threshold``: gray level (0-255); pixels brighter than this are bin-plastic candidates.
        ``dilate_px``: radius of the elliptic dilation closing small gaps in the walls (0: none).
        ``min_area_frac``: smallest accepted component, as a fraction of the image.
        ``prefer_centre``: take the component covering the image centre after filling when there
        is one (a bin is usually centred); otherwise, or when none covers it, the largest.
        (``enabled`` is the pipeline's switch; this function ignores it.)

    Returns
    -------
    BinMaskResult

    The result is :func:`bin_mask_reference`'s bit for bit (the tests compare them); it costs a third
    of it: OpenCV's components without their statistics (which OpenCV gathers pixel by pixel, 18 of
    its 21 ms on a 1920 x 1200 image) and the statistics from the grown image's runs, the erosion without a
    padded copy, the masks and their counts in one pass over the chosen component's flooded box.
    """
    a = _check_rgb(rgb)
    if not isinstance(params, BinMaskParams):
        raise ParameterError(f"params must be a BinMaskParams, got {type(params).__name__}")
    threshold, dilate_px, min_area_frac = params.threshold, params.dilate_px, params.min_area_frac
    prefer_centre = params.prefer_centre
    h, w = a.shape[:2]
    empty = np.zeros((h, w), bool)
    if h == 0 or w == 0:
        return BinMaskResult(empty, empty, False, 0, 0, (np.nan, np.nan), (0, 0, 0, 0), False)
    gray = cv2.cvtColor(np.ascontiguousarray(a), cv2.COLOR_RGB2GRAY)
    # gray is an integer: gray > threshold <=> gray > floor(threshold); 0/1 bytes without a copy
    bright = (gray > int(np.floor(threshold))).view(np.uint8)
    grown: np.ndarray = bright
    if dilate_px > 0:
        k = 2 * int(dilate_px) + 1
        grown = cv2.dilate(bright, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
    # the labels of connectedComponentsWithStats (the same algorithm), without its slow statistics
    n, labels = cv2.connectedComponents(grown, connectivity=8, ltype=cv2.CV_32S)
    stats = _component_stats(labels, grown, _row_words(grown), n)
    n_components = n - 1
    min_area = max(1, int(np.ceil(min_area_frac * h * w)))
    candidates = [i for i in range(1, n) if stats[i, 4] >= min_area]
    if not candidates:
        return BinMaskResult(empty, empty, False, 0, n_components, (np.nan, np.nan), (0, 0, 0, 0), False)
    chosen = None
    covers = False
    flooded = None
    cr, cc = h // 2, w // 2
    if prefer_centre:
        for i in sorted(candidates, key=lambda i: -stats[i, 4]):
            x, y, bw, bh = stats[i, :4]
            if not (y <= cr < y + bh and x <= cc < x + bw):
                continue
            sub = _flooded(labels, (int(x), int(y), int(bw), int(bh)), i)
            if sub[cr - y + 1, cc - x + 1] != 2:  # the filled component covers the centre
                chosen, covers, flooded = i, True, sub
                break
    if chosen is None:
        chosen = max(candidates, key=lambda i: stats[i, 4])
    x, y, bw, bh = (int(v) for v in stats[chosen, :4])
    if flooded is None:
        flooded = _flooded(labels, (x, y, bw, bh), chosen)
    filled = flooded[1:-1, 1:-1] != 2
    f: np.ndarray = filled.view(np.uint8)
    if dilate_px > 0:
        # erode back by the same radius (a closing); outside the box counts as background
        k = 2 * int(dilate_px) + 1
        f = cv2.erode(f, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)),
                      borderType=cv2.BORDER_CONSTANT, borderValue=0)
    mask = np.zeros((h, w), bool)
    walls = np.zeros((h, w), bool)
    per_row, per_col = _assemble(np.ascontiguousarray(f), flooded, bright, y, x, dilate_px > 0,
                                 mask.view(np.uint8), walls.view(np.uint8))
    area = int(per_row.sum())
    r_sum = int(per_row @ np.arange(y, y + bh, dtype=np.int64))
    c_sum = int(per_col @ np.arange(x, x + bw, dtype=np.int64))
    return BinMaskResult(
        mask=mask,
        walls=walls,
        found=True,
        area_px=area,
        n_components=n_components,
        centroid_rc=(r_sum / area, c_sum / area),
        bbox_rc=(y, x, y + bh, x + bw),
        covers_centre=covers,
    )


def bin_pixels(result: BinMaskResult, xyz: XYZ, *, ring_frac: float = 0.2, min_ring_px: float = MIN_RING_PX) -> Mask:
    """The pixels of the bin itself: its rim and upper walls, never the parts inside it.

    The bright pixels of the component (``result.walls``) with a finite point that lie no farther
    from the footprint's border than ``ring_frac`` times the footprint's inradius (the largest
    distance of a footprint pixel to the border), or ``min_ring_px`` when that is wider. The rim is the outermost band of the footprint,
    the walls come next, and the pile lies below the rim, in from the walls: a shiny part, as
    bright as the plastic, joins the component but not the ring. Distances are Euclidean, in
    pixels, to the nearest pixel outside the footprint; the image's own edge is no border (a bin
    cut by the image edge has no wall there).

    The default 0.2 keeps the rim and about the top third of the walls of the synthetic bin
    (400 x 300 mm, rim 15 mm, 120 mm deep) and no part pixel on any of the six synthetic kinds,
    at any image size (the ring scales with the footprint); ``ring_frac=1`` keeps the whole bright
    component (``result.walls & valid``).

    Parameters
    ----------
    result : BinMaskResult
        From :func:`bin_mask` on the frame's image.
    xyz : (H, W, 3) float ndarray
        The frame's organized cloud (NaN = invalid), the image's size.
    ring_frac : float
        Width of the ring as a fraction of the footprint's inradius, in (0, 1].
    min_ring_px : float
        The narrowest ring, in pixels (>= 0).

    Returns
    -------
    (H, W) bool ndarray
        All False when no bin was found.

    The result is :func:`bin_pixels_reference`'s bit for bit (the tests compare them): the distance
    transform is the same OpenCV call; the points are tested for finiteness only at the bright pixels
    of the ring, in the pass that compares the distances, not over the whole crop (25 ms of 46 on a
    1920 x 1200 frame).
    """
    a = _check_pixels_args(result, xyz, ring_frac, min_ring_px)
    shape = result.mask.shape
    out = np.zeros(shape, bool)
    if not result.found:
        return out
    walls = np.asarray(result.walls)
    if a.dtype not in (np.float32, np.float64) or walls.dtype != bool or walls.shape != shape:
        # other float types, or masks not as bin_mask makes them: the oracle's own arithmetic
        return bin_pixels_reference(result, a, ring_frac=ring_frac, min_ring_px=min_ring_px)
    y0, x0, y1, x1 = result.bbox_rc
    r0, c0 = max(y0 - 1, 0), max(x0 - 1, 0)
    r1, c1 = min(y1 + 1, shape[0]), min(x1 + 1, shape[1])
    fp = np.ascontiguousarray(result.mask[r0:r1, c0:c1], dtype=np.uint8)
    walls = np.ascontiguousarray(walls).view(np.uint8)
    all_in = bool(fp.all())
    if not all_in and _bounded_shape(fp.shape):
        # the bounded transform: the largest distance from the few rows that can hold it, the ring's
        # distances only where the bounds do not decide
        g, row_max = _column_distances(fp)
        largest = _largest_distance(g, row_max, np.argsort(-row_max, kind="stable"))
        if _exact_opencv(fp.shape):
            vin = vout = _vmax(_ring_threshold(largest, ring_frac, min_ring_px))
        else:  # OpenCV would run IPP's transform (one thread, or a small crop): its ring where no pixel is near
            vin, vout = _near_bounds(largest, ring_frac, min_ring_px)
        if _ring_bounded(g, vin, vout, walls, a, r0, c0, out.view(np.uint8)) == 0:
            return out
        out[:] = False  # a pixel within IPP's rounding of the threshold: OpenCV's own transform decides
    dist: np.ndarray
    if all_in:
        dist = np.zeros((1, 1), np.float32)
        thr = np.float32(0.0)
    else:
        dist = cv2.distanceTransform(fp, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        # `dist <= thr` of the oracle compares in float32 (NumPy casts a Python float to the array's type)
        thr = _ring_threshold(float(dist.max()), ring_frac, min_ring_px)
    _ring(dist, thr, walls, a, r0, r1, c0, c1, all_in, out.view(np.uint8))
    return out


def bin_mask_reference(rgb: RGB, *, params: BinMaskParams = BinMaskParams()) -> BinMaskResult:
    """:func:`bin_mask` as first written: OpenCV's components with their statistics, the footprint
    eroded in a padded copy. The tests' and ``bench/bench_binmask.py``'s oracle (slower: 35 ms a
    1920 x 1200 image against ~10)."""
    a = _check_rgb(rgb)
    if not isinstance(params, BinMaskParams):
        raise ParameterError(f"params must be a BinMaskParams, got {type(params).__name__}")
    threshold, dilate_px, min_area_frac = params.threshold, params.dilate_px, params.min_area_frac
    prefer_centre = params.prefer_centre
    h, w = a.shape[:2]
    empty = np.zeros((h, w), bool)
    if h == 0 or w == 0:
        return BinMaskResult(empty, empty, False, 0, 0, (np.nan, np.nan), (0, 0, 0, 0), False)
    gray = cv2.cvtColor(np.ascontiguousarray(a), cv2.COLOR_RGB2GRAY)
    # gray is an integer: gray > threshold <=> gray > floor(threshold) (no float64 copy of the image)
    bright = gray > int(np.floor(threshold))
    grown: np.ndarray = bright.astype(np.uint8)
    if dilate_px > 0:
        k = 2 * int(dilate_px) + 1
        grown = cv2.dilate(grown, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(grown, connectivity=8, ltype=cv2.CV_32S)
    n_components = n - 1
    min_area = max(1, int(np.ceil(min_area_frac * h * w)))
    candidates = [i for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] >= min_area]
    if not candidates:
        return BinMaskResult(empty, empty, False, 0, n_components, (np.nan, np.nan), (0, 0, 0, 0), False)
    chosen = None
    covers = False
    filled = None
    cr, cc = h // 2, w // 2
    if prefer_centre:
        # Does any candidate's filled footprint cover the centre? Test cheaply with bounding boxes first.
        for i in sorted(candidates, key=lambda i: -stats[i, cv2.CC_STAT_AREA]):
            x, y, bw, bh = stats[i, :4]
            if not (y <= cr < y + bh and x <= cc < x + bw):
                continue
            sub = fill_holes(labels[y:y + bh, x:x + bw] == i)
            if sub[cr - y, cc - x]:
                chosen, covers, filled = i, True, sub
                break
    if chosen is None:
        chosen = max(candidates, key=lambda i: stats[i, cv2.CC_STAT_AREA])
    x, y, bw, bh = (int(v) for v in stats[chosen, :4])
    mask = np.zeros((h, w), bool)
    comp = labels[y:y + bh, x:x + bw] == chosen
    if filled is None:
        filled = fill_holes(comp)
    if dilate_px > 0:
        # erode back by the same radius (a closing): the dilation's fringe of table is not bin
        k = 2 * int(dilate_px) + 1
        pad = int(dilate_px) + 1
        f: np.ndarray = np.pad(filled.astype(np.uint8), pad)
        f = cv2.erode(f, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
        filled = f[pad:-pad, pad:-pad].astype(bool) | (comp & bright[y:y + bh, x:x + bw])
    mask[y:y + bh, x:x + bw] = filled
    walls = np.zeros((h, w), bool)
    walls[y:y + bh, x:x + bw] = comp & bright[y:y + bh, x:x + bw]
    # centroid from per-row and per-column counts: integer sums, exact like the mean of np.nonzero
    per_row = np.count_nonzero(filled, axis=1)
    per_col = np.count_nonzero(filled, axis=0)
    area = int(per_row.sum())
    r_sum = int(per_row @ np.arange(y, y + bh, dtype=np.int64))
    c_sum = int(per_col @ np.arange(x, x + bw, dtype=np.int64))
    return BinMaskResult(
        mask=mask,
        walls=walls,
        found=True,
        area_px=area,
        n_components=n_components,
        centroid_rc=(r_sum / area, c_sum / area),
        bbox_rc=(y, x, y + bh, x + bw),
        covers_centre=covers,
    )




def bin_pixels_reference(result: BinMaskResult, xyz: XYZ, *, ring_frac: float = 0.2,
                         min_ring_px: float = MIN_RING_PX) -> Mask:
    """:func:`bin_pixels` as first written: every pixel of the crop tested for a finite point. The
    tests' and ``bench/bench_binmask.py``'s oracle."""
    a = _check_pixels_args(result, xyz, ring_frac, min_ring_px)
    shape = result.mask.shape
    out = np.zeros(shape, bool)
    if not result.found:
        return out
    y0, x0, y1, x1 = result.bbox_rc
    # one pixel of margin inside the image, so that a footprint reaching its bounding box's edge
    # (but not the image's) still has background beside it
    r0, c0 = max(y0 - 1, 0), max(x0 - 1, 0)
    r1, c1 = min(y1 + 1, shape[0]), min(x1 + 1, shape[1])
    fp = np.ascontiguousarray(result.mask[r0:r1, c0:c1], dtype=np.uint8)
    if fp.all():
        ring = np.ones(fp.shape, bool)  # the footprint fills the whole image: no border to measure from
    else:
        dist = cv2.distanceTransform(fp, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        ring = dist <= max(float(ring_frac) * float(dist.max()), float(min_ring_px))
    sub = result.walls[r0:r1, c0:c1] & ring
    sub &= np.isfinite(a[r0:r1, c0:c1]).all(axis=2)
    out[r0:r1, c0:c1] = sub
    return out
