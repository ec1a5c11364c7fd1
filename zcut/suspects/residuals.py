"""The residual detectors: surface residuals up and down, mixed pixels, and blob completion.

``residual_up`` / ``residual_down`` / ``mixed`` (:func:`surface_residuals`, see :mod:`zcut.suspects`):
a pixel off every one-sided continuation of the surface around it; blobs of them are completed by
:func:`fill_blobs`. Each numba kernel has its literal reference beside it.
"""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt
from scipy import ndimage

from ..cloud import check_mask
from ..errors import InputShapeError, ParameterError, describe_array
from ..types import FloatImage, Mask
from .detectors import _DC, _DR, _OPP, MIXED, RESIDUAL_DOWN, RESIDUAL_UP, shifted

#: A threshold of :func:`surface_residuals`: one for the frame, or one per pixel.
Threshold = float | npt.NDArray[np.floating]
# blob completion: a pixel joins when at least this many of its 8 neighbours are suspects
FILL_MIN_NEIGHBOURS = 3


@numba.njit(cache=True, inline="always")
def _pixel(h, judged, taus, jumps, min_below, codes, best, i, j, e):  # type: ignore[no-untyped-def]  # numba kernel
    """Pixel (i, j) of :func:`_residual_kernel`: its residual into ``best``, its code into ``codes``; the
    pixels two or more from the border take a path without bounds checks (the same arithmetic in the
    same order). ``e``: scratch of 8."""
    H, W = h.shape
    inner_row = 2 <= i < H - 2
    best[i, j] = np.nan
    codes[i, j] = 0
    if not judged[i, j]:
        return
    hp = h[i, j]
    if not np.isfinite(hp):
        return
    n = 0
    rmin = np.inf
    eb = np.inf
    emin = np.inf
    emax = -np.inf
    if inner_row and 2 <= j < W - 2:
        for k in range(8):
            dr = _DR[k]
            dc = _DC[k]
            a1 = h[i + dr, j + dc]
            a2 = h[i + 2 * dr, j + 2 * dc]
            e[k] = np.nan
            if np.isfinite(a1) and np.isfinite(a2):
                ek = hp - (2.0 * a1 - a2)
                e[k] = ek
                n += 1
                if abs(ek) < rmin:
                    rmin = abs(ek)
                    eb = ek
                if ek < emin:
                    emin = ek
                if ek > emax:
                    emax = ek
    else:
        for k in range(8):
            e[k] = np.nan
            i2 = i + 2 * _DR[k]
            j2 = j + 2 * _DC[k]
            if i2 < 0 or i2 >= H or j2 < 0 or j2 >= W:
                continue
            a1 = h[i + _DR[k], j + _DC[k]]
            a2 = h[i2, j2]
            if not (np.isfinite(a1) and np.isfinite(a2)):
                continue
            ek = hp - (2.0 * a1 - a2)
            e[k] = ek
            n += 1
            if abs(ek) < rmin:
                rmin = abs(ek)
                eb = ek
            if ek < emin:
                emin = ek
            if ek > emax:
                emax = ek
    best[i, j] = eb
    tau = taus[i, j]
    if n == 0 or not rmin > tau:
        return
    jump = jumps[i, j]
    if emin > tau:
        codes[i, j] = RESIDUAL_UP
        return
    if emax < -tau:
        if n >= min_below:
            codes[i, j] = RESIDUAL_DOWN
        return
    between = False
    for k in range(8):
        if e[k] > tau and e[_OPP[k]] < -tau:
            between = True
    if not between:
        hi = -np.inf
        lo = np.inf
        for k in range(8):
            i1 = i + _DR[k]
            j1 = j + _DC[k]
            if i1 < 0 or i1 >= H or j1 < 0 or j1 >= W:
                continue
            d = h[i1, j1] - hp
            if np.isfinite(d):
                if d > hi:
                    hi = d
                if d < lo:
                    lo = d
        between = hi > jump and lo < -jump
    if between:
        codes[i, j] = MIXED


@numba.njit(cache=True, inline="always")
def _direction(hp, a1, a2, n, rmin, eb, emin, emax):  # type: ignore[no-untyped-def]  # numba kernel
    """One direction of :func:`_pixel`'s inner path without a branch: the same values, the same order."""
    fin = np.isfinite(a1) & np.isfinite(a2)
    ek = hp - (2.0 * a1 - a2)
    take = fin & (abs(ek) < rmin)
    return (n + (1 if fin else 0), abs(ek) if take else rmin, ek if take else eb,
            ek if fin & (ek < emin) else emin, ek if fin & (ek > emax) else emax)


@numba.njit(cache=True)
def _row_residuals(h, i, judged, taus, best, flag):  # type: ignore[no-untyped-def]  # numba kernel
    """Row ``i`` (2 <= i < H - 2) of :func:`_residual_kernel` at columns 2 .. W - 3 (entry t: column 2 + t),
    all at once so that the processor runs neighbouring pixels in its vector lanes: each one's residual
    into ``best`` (:func:`_pixel`'s value), and ``flag[t]`` where it is off every continuation (n > 0
    and its residual's magnitude > τ), the pixels whose code :func:`_pixel` then decides."""
    W = h.shape[1]
    m = W - 4
    c, ce, ce2, cw, cw2 = h[i, 2:W - 2], h[i, 3:W - 1], h[i, 4:W], h[i, 1:W - 3], h[i, 0:W - 4]
    s1, s2, n1, n2 = h[i + 1, 2:W - 2], h[i + 2, 2:W - 2], h[i - 1, 2:W - 2], h[i - 2, 2:W - 2]
    se1, se2, sw1, sw2 = h[i + 1, 3:W - 1], h[i + 2, 4:W], h[i + 1, 1:W - 3], h[i + 2, 0:W - 4]
    ne1, ne2, nw1, nw2 = h[i - 1, 3:W - 1], h[i - 2, 4:W], h[i - 1, 1:W - 3], h[i - 2, 0:W - 4]
    jd = judged[i, 2:W - 2]
    tu = taus[i, 2:W - 2]
    bo = best[i, 2:W - 2]
    for t in range(m):
        hp = c[t]
        n, rmin, eb, emin, emax = 0, np.inf, np.inf, np.inf, -np.inf
        # the directions of _DR, _DC in their order: E, W, S, N, SE, SW, NE, NW
        n, rmin, eb, emin, emax = _direction(hp, ce[t], ce2[t], n, rmin, eb, emin, emax)
        n, rmin, eb, emin, emax = _direction(hp, cw[t], cw2[t], n, rmin, eb, emin, emax)
        n, rmin, eb, emin, emax = _direction(hp, s1[t], s2[t], n, rmin, eb, emin, emax)
        n, rmin, eb, emin, emax = _direction(hp, n1[t], n2[t], n, rmin, eb, emin, emax)
        n, rmin, eb, emin, emax = _direction(hp, se1[t], se2[t], n, rmin, eb, emin, emax)
        n, rmin, eb, emin, emax = _direction(hp, sw1[t], sw2[t], n, rmin, eb, emin, emax)
        n, rmin, eb, emin, emax = _direction(hp, ne1[t], ne2[t], n, rmin, eb, emin, emax)
        n, rmin, eb, emin, emax = _direction(hp, nw1[t], nw2[t], n, rmin, eb, emin, emax)
        ok = jd[t] & np.isfinite(hp)
        bo[t] = eb if ok else np.nan
        flag[t] = ok & (n > 0) & (rmin > tu[t])


@numba.njit(cache=True)
def _residual_kernel(h, judged, taus, jumps, min_below, codes, best):  # type: ignore[no-untyped-def]  # numba kernel
    """The residuals and codes of :func:`surface_residuals`: the rows two or more from the border a row at a
    time in vector lanes (:func:`_row_residuals`), then :func:`_pixel` for the pixels it flags and those
    near the border."""
    H, W = h.shape
    e = np.empty(8)
    flag = np.empty(max(W - 4, 0), np.bool_)
    for i in range(H):
        vec = 2 <= i < H - 2 and W > 4
        if vec:
            _row_residuals(h, i, judged, taus, best, flag)
        for j in range(W):
            if vec and 2 <= j < W - 2:
                codes[i, j] = 0
                if not flag[j - 2]:
                    continue
            _pixel(h, judged, taus, jumps, min_below, codes, best, i, j, e)


def _check_residual_args(height: object, judged: object, tau: object, jump: object, min_below: object
                         ) -> tuple[np.ndarray, Mask, np.ndarray, np.ndarray, int]:
    h = np.asarray(height)
    if h.ndim != 2 or h.dtype.kind != "f":
        raise InputShapeError(f"height must be an (H, W) real float array, got {describe_array(h)}")
    judged = check_mask(judged, name="judged", shape=h.shape)
    out = []
    for name, v in (("tau", tau), ("jump", jump)):
        if isinstance(v, (bool, np.bool_)):
            raise ParameterError(f"{name} must be a number >= 0 or an (H, W) array of them, got {v!r}")
        a = np.asarray(v, dtype=np.float64) if isinstance(v, (int, float, np.ndarray, np.floating, np.integer)) \
            else None
        if a is None or a.ndim not in (0, 2) or (a.ndim == 2 and a.shape != h.shape):
            raise ParameterError(f"{name} must be a number >= 0 or an array of the height's shape {h.shape}, "
                                 f"got {describe_array(v) if hasattr(v, 'shape') else repr(v)}")
        if not np.all(a >= 0):
            raise ParameterError(f"{name} must be >= 0 everywhere (not NaN)")
        out.append(np.ascontiguousarray(np.broadcast_to(a, h.shape)))
    if isinstance(min_below, bool) or not isinstance(min_below, (int, np.integer)) or not 1 <= min_below <= 8:
        raise ParameterError(f"min_below must be an integer in 1..8, got {min_below!r}")
    return np.ascontiguousarray(h, dtype=np.float64), np.ascontiguousarray(judged), out[0], out[1], int(min_below)


def surface_residuals(height: FloatImage, judged: Mask, *, tau: Threshold, jump: Threshold,
                      min_below: int) -> tuple[np.ndarray, np.ndarray]:
    """Residuals of the judged pixels against the one-sided continuations of the surface around them.

    For a judged pixel p and each of the 8 directions d whose two pixels p+d, p+2d are measured,
    ``e_d = h(p) - (2 h(p+d) - h(p+2d))``. The pixel's residual is the ``e_d`` of smallest
    magnitude (first in the order E, W, S, N, SE, SW, NE, NW on ties). With r = |residual| > τ:

    - ``RESIDUAL_UP`` if every ``e_d > τ`` (above every continuation);
    - ``RESIDUAL_DOWN`` if every ``e_d < -τ`` and at least ``min_below`` directions exist;
    - ``MIXED`` otherwise, if the pixel lies between two surfaces: ``e_d > τ`` and ``e_{-d} < -τ``
      for some direction d, or a neighbour nearer by more than ``jump`` and one farther by more
      than ``jump``.

    Parameters
    ----------
    height : (H, W) float ndarray
        Height (mm, larger = nearer the camera); every measured pixel serves as context, NaN =
        unmeasured. float32 is upcast to float64.
    judged : (H, W) bool ndarray
        The pixels to judge (the zone).
    tau, jump : float or (H, W) float ndarray
        Thresholds (mm, >= 0), one for the frame or one per pixel; strict comparisons.
    min_below : int
        1-8.

    Returns
    -------
    codes : (H, W) uint8 ndarray
        One of the bits above, 0 = not a suspect (and everywhere outside ``judged``).
    residual : (H, W) float64 ndarray
        The signed residual; +inf where no direction exists, NaN outside ``judged`` or unmeasured.
    """
    h, judged, tau, jump, min_below = _check_residual_args(height, judged, tau, jump, min_below)
    codes = np.zeros(h.shape, np.uint8)
    best = np.empty(h.shape, np.float64)
    _residual_kernel(h, judged, tau, jump, min_below, codes, best)
    return codes, best


def surface_residuals_reference(height: FloatImage, judged: Mask, *, tau: Threshold, jump: Threshold,
                                min_below: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`surface_residuals` as whole-image numpy operations, one shifted image per direction."""
    h, judged, tau, jump, min_below = _check_residual_args(height, judged, tau, jump, min_below)
    A1 = np.stack([shifted(h, dr, dc, np.nan) for dr, dc in zip(_DR, _DC)])
    A2 = np.stack([shifted(h, 2 * dr, 2 * dc, np.nan) for dr, dc in zip(_DR, _DC)])
    with np.errstate(over="ignore", invalid="ignore"):
        E = h - (2.0 * A1 - A2)
    have = np.isfinite(A1) & np.isfinite(A2) & np.isfinite(h)
    n = have.sum(axis=0)
    mag = np.where(have, np.abs(E), np.inf)
    k = np.argmin(mag, axis=0)
    rmin = np.take_along_axis(mag, k[None], axis=0)[0]
    eb = np.where(rmin < np.inf, np.take_along_axis(E, k[None], axis=0)[0], np.inf)
    ok = judged & np.isfinite(h)
    residual = np.where(ok, eb, np.nan)
    r = rmin
    emin = np.where(have, E, np.inf).min(axis=0)
    emax = np.where(have, E, -np.inf).max(axis=0)
    E = np.where(have, E, np.nan)
    off = ok & (n > 0) & (r > tau)
    up = off & (emin > tau)
    down_pattern = off & ~up & (emax < -tau)
    down = down_pattern & (n >= min_below)
    pair = np.zeros_like(off)
    for i, j in enumerate(_OPP):
        pair |= (E[i] > tau) & (E[j] < -tau)
    with np.errstate(over="ignore", invalid="ignore"):
        D = A1 - h
    hi = np.where(np.isfinite(D), D, -np.inf).max(axis=0)
    lo = np.where(np.isfinite(D), D, np.inf).min(axis=0)
    mixed = off & ~up & ~down_pattern & (pair | ((hi > jump) & (lo < -jump)))
    codes = np.zeros(h.shape, np.uint8)
    codes[up] = RESIDUAL_UP
    codes[down] = RESIDUAL_DOWN
    codes[mixed] = MIXED
    return codes, residual


@numba.njit(cache=True)
def _fill_frontier_kernel(seed, judged, valid, iterations, min_nb):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`zcut.suspects._reference._fill_kernel` (the previous kernel) judging only the pixels that can join: in a round, the neighbours of the
    pixels that joined in the previous one (of the seeds in the first); a pixel's counts change only
    when a neighbour joins."""
    H, W = seed.shape
    cur = seed.copy()
    stamp = np.zeros((H, W), np.int32)
    n = 0
    for i in range(H):
        for j in range(W):
            if seed[i, j]:
                n += 1
    front = np.empty(n, np.int64)
    n = 0
    for i in range(H):
        for j in range(W):
            if seed[i, j]:
                front[n] = i * W + j
                n += 1
    for it in range(1, iterations + 1):
        cand = np.empty(min(8 * front.size, H * W), np.int64)
        m = 0
        for p in front:
            i = p // W
            j = p % W
            for k in range(8):
                i1 = i + _DR[k]
                j1 = j + _DC[k]
                if i1 < 0 or i1 >= H or j1 < 0 or j1 >= W:
                    continue
                if cur[i1, j1] or not judged[i1, j1] or stamp[i1, j1] == it:
                    continue
                stamp[i1, j1] = it
                cand[m] = i1 * W + j1
                m += 1
        add = np.empty(m, np.int64)
        na = 0
        for c in range(m):
            i = cand[c] // W
            j = cand[c] % W
            nf = 0
            nv = 0
            for k in range(8):
                i1 = i + _DR[k]
                j1 = j + _DC[k]
                if i1 < 0 or i1 >= H or j1 < 0 or j1 >= W:
                    continue
                if cur[i1, j1]:
                    nf += 1
                elif valid[i1, j1]:
                    nv += 1
            if nf >= min_nb and nf > nv:
                add[na] = cand[c]
                na += 1
        if na == 0:
            break
        for c in range(na):
            cur[add[c] // W, add[c] % W] = True
        front = add[:na]
    return cur


def _check_fill_args(seed: object, judged: object, valid: object, iterations: object) -> tuple[Mask, Mask, Mask, int]:
    seed = check_mask(seed, name="seed")
    judged = check_mask(judged, name="judged", shape=seed.shape)
    valid = check_mask(valid, name="valid", shape=seed.shape)
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) or iterations < 0:
        raise ParameterError(f"iterations must be an integer >= 0, got {iterations!r}")
    return seed, judged, valid, int(iterations)


def fill_blobs(seed: Mask, judged: Mask, valid: Mask, *, iterations: int) -> Mask:
    """Complete blobs of suspects: up to ``iterations`` rounds, each adding (all at once) every judged
    pixel outside the set that has at least 3 of its 8 neighbours in the set and more neighbours in
    it than measured ones outside it.

    Parameters
    ----------
    seed, judged, valid : (H, W) bool ndarray
        The suspects, the pixels that may join, the measured pixels.
    iterations : int

    Returns
    -------
    (H, W) bool ndarray
        ``seed`` and the pixels that joined.
    """
    seed, judged, valid, iterations = _check_fill_args(seed, judged, valid, iterations)
    filled: Mask = _fill_frontier_kernel(np.ascontiguousarray(seed), np.ascontiguousarray(judged),
                                         np.ascontiguousarray(valid), iterations, FILL_MIN_NEIGHBOURS)
    return filled


def fill_blobs_reference(seed: Mask, judged: Mask, valid: Mask, *, iterations: int) -> Mask:
    """:func:`fill_blobs` with neighbour counts from ``scipy.ndimage.correlate``."""
    seed, judged, valid, iterations = _check_fill_args(seed, judged, valid, iterations)
    ring = np.ones((3, 3), np.int32)
    ring[1, 1] = 0
    cur = seed.copy()
    for _ in range(iterations):
        nf = ndimage.correlate(cur.astype(np.int32), ring, mode="constant")
        nv = ndimage.correlate((valid & ~cur).astype(np.int32), ring, mode="constant")
        add = judged & ~cur & (nf >= FILL_MIN_NEIGHBOURS) & (nf > nv)
        if not add.any():
            break
        cur = cur | add
    return cur
