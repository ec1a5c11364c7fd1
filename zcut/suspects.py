"""Suspects: outliers no filter chose, proposed to a person in groups (``docs/filters.md``, "Suspects").

The z-cut and SOR find what their own rules define; a person labelling true outliers must also see
what neither looks at, or the labels inherit the filters' blindness. The detectors here judge the
pixels of the zone (the points the filters judge) against the measured points around them, with
thresholds taken from the frame's own noise:

- ``residual_up`` / ``residual_down`` — **surface residuals**. The local surface at a pixel is
  continued from each of the 8 directions (the linear continuation ``2 h(p+d) - h(p+2d)`` of the two
  pixels on that side); the pixel's residual is its distance to the best of them. A pixel farther
  than τ from *every* continuation is off the surface: toward the camera (all continuations below
  it: a spike, a ghost's rim) or away from it (all above: a spike away from the camera, flagged
  only where at least ``below_min_directions`` continuations exist). τ = max(min_residual_mm,
  noise_k · σ̂), σ̂ the robust spread of the frame's second differences (:func:`frame_noise_mm`).
  A one-sided continuation follows edges and slopes, where a windowed median or plane would flag
  every occlusion edge of the pile. Blobs: zone pixels mostly surrounded by suspects join them
  (``fill_iterations`` rounds), so a rough ghost is proposed whole.
- ``mixed`` — **mixed (flying) pixels** at depth discontinuities: off the surface, and between two
  surfaces — above the continuation from one side and below the one from the opposite side, or with
  a neighbour nearer and one farther by more than the jump each.
- ``floating`` — **floating components of any depth**: the z-cut (:func:`zcut.cuts.find_clusters`)
  over the zone's whole height range, components smaller than ``floating_rho · a_max``; those
  larger than ``plain_rho · a_max`` only with evidence that they are not a clean measured surface
  (holes inside, rough, or hovering over measured points).
- ``above_rim`` — the points above the rim, which the pipeline's removal flags (given as a mask).

:func:`suspects` runs them all and groups the result for review: per detector, suspects within a
merge radius form one group; the radius of the detector with most groups doubles until the frame
has at most ``max_groups`` groups. Every group says which detectors flagged it, its size, its gap
to the local surface in mm (positive: toward the camera) and a score for ordering.

Each numba kernel has a literal reference beside it (``*_reference``: numpy or plain loops) and the
tests check they agree bit for bit (``tests/zcut/test_suspects.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from scipy import ndimage

from .cloud import Intrinsics, check_mask, check_xyz
from .cuts import MAX_STAGE_LEVELS, find_clusters
from .errors import InputShapeError, ParameterError, describe_array
from .params import SuspectParams, ZCutParams
from .types import XYZ, FloatImage, Labels, Mask

__all__ = [
    "DETECTORS",
    "SuspectGroup",
    "SuspectResult",
    "detector_bits",
    "detector_names",
    "fill_blobs",
    "fill_blobs_reference",
    "floating_evidence",
    "floating_evidence_reference",
    "frame_noise_mm",
    "local_height",
    "NoiseProfile",
    "noise_profile",
    "local_gaps",
    "local_gaps_reference",
    "strength_classes",
    "surface_residuals",
    "surface_residuals_reference",
    "suspects",
]

#: Detector names, in the order of their bits (bit i = 1 << i) and of precedence: a pixel flagged by
#: several detectors is grouped with the first of them here.
DETECTORS = ("above_rim", "floating", "mixed", "residual_down", "residual_up")
ABOVE_RIM, FLOATING, MIXED, RESIDUAL_DOWN, RESIDUAL_UP = (1 << i for i in range(len(DETECTORS)))

# the 8 directions (row, column) and the index of the opposite of each
_DR = (0, 0, 1, -1, 1, 1, -1, -1)
_DC = (1, -1, 0, 0, 1, -1, 1, -1)
_OPP = (1, 0, 3, 2, 7, 6, 5, 4)
# blob completion: a pixel joins when at least this many of its 8 neighbours are suspects
FILL_MIN_NEIGHBOURS = 3
# a hole of a floating component: an unmeasured pixel with at least this many of its 8 neighbours in it
# (6: holes inside it, not the notches of a ragged border)
HOLE_MIN_NEIGHBOURS = 6
# local surface of a suspect pixel: the median of at least this many non-suspect measured pixels in
# the smallest square window (radius 1, 2, 4, ... up to GAP_MAX_RADIUS) that holds them
GAP_MIN_PIXELS = 3
GAP_MAX_RADIUS = 64
# grouping: a detector with more components than this is pre-merged with a larger radius first
MAX_NODES = 1500
# grouping: the bounds of a suspect's strength classes, in |gap| / τ (the median over its component):
# at the noise's edge (below 2 τ), clearly off the surface, far off it (8 τ and more). Suspects of
# different classes are not grouped together while the frame's group budget allows it.
STRENGTH_CLASSES = (2.0, 8.0)
# the floating detector's step: max(floating_step_mm, FLOATING_STEP_SIGMAS * noise): a step below the
# noise of neighbour differences would cut clean surfaces into floating terraces
FLOATING_STEP_SIGMAS = 1.0
# a floating component must clear everything around it by more than this many σ̂ at its height, and
# by more than this many depth steps (on a sensor reporting depth in steps, the top of a dome is a
# terrace one step above its surroundings: it floats, and it is the sensor's rounding)
FLOATING_CLEARANCE_SIGMAS = 1.0
FLOATING_CLEARANCE_STEPS = 1.5
# the noise profile: bins of at least this many second differences, at most this many bins
NOISE_MIN_SAMPLES = 2000
NOISE_MAX_BINS = 32
# ... from at most this many samples (every k-th, in raster order)
NOISE_MAX_SAMPLES = 200_000
# a bin is quantized when at least this share of its neighbour differences are exactly 0
QUANTIZED_ZERO_SHARE = 0.2
# Gaussian quantiles of |x|: median = 0.6745 σ, 75th percentile = 1.1503 σ
_MAD_SCALE = 1.482602218505602
_Q75_SCALE = 1.150349380376008


def detector_bits(names) -> int:
    """The bit mask of detector ``names`` (an iterable of :data:`DETECTORS` entries)."""
    bits = 0
    for n in names:
        if n not in DETECTORS:
            raise ParameterError(f"unknown detector {n!r}; detectors: {', '.join(DETECTORS)}")
        bits |= 1 << DETECTORS.index(n)
    return bits


def detector_names(bits: int) -> tuple[str, ...]:
    """The detector names of a bit mask (the order of :data:`DETECTORS`)."""
    return tuple(n for i, n in enumerate(DETECTORS) if int(bits) >> i & 1)


# --------------------------------------------------------------------------------------------
# The frame's noise
# --------------------------------------------------------------------------------------------


def _median3(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    return np.maximum(np.minimum(a, b), np.minimum(np.maximum(a, b), c))


def _second_differences(height: np.ndarray, judged: Mask) -> tuple[np.ndarray, np.ndarray]:
    """|centred second differences| along rows and columns at judged pixels with both neighbours on
    that axis measured, and the median height of their three pixels (a spike is placed at the
    height of the surface it sticks out of, not at its own)."""
    h = np.asarray(height, dtype=np.float64)
    vals, at = [np.zeros(0)], [np.zeros(0)]
    if h.shape[1] >= 3:
        a, b, c = h[:, :-2], h[:, 1:-1], h[:, 2:]
        e = a - 2.0 * b + c
        sel = judged[:, 1:-1] & np.isfinite(e)
        vals.append(e[sel])
        at.append(_median3(a[sel], b[sel], c[sel]))
    if h.shape[0] >= 3:
        a, b, c = h[:-2, :], h[1:-1, :], h[2:, :]
        e = a - 2.0 * b + c
        sel = judged[1:-1, :] & np.isfinite(e)
        vals.append(e[sel])
        at.append(_median3(a[sel], b[sel], c[sel]))
    return np.abs(np.concatenate(vals)), np.concatenate(at)


def local_height(height: FloatImage) -> np.ndarray:
    """The median of each pixel's height and its 4 neighbours' (measured ones only; NaN where the
    pixel is not measured): the height at which to look up the noise of a pixel, so that a spike
    gets the noise of the surface it sticks out of."""
    h = np.asarray(height, dtype=np.float64)
    stack = np.stack([h] + [_shifted(h, dr, dc, np.nan) for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0))])
    out = np.full(h.shape, np.nan)
    fin = np.isfinite(h)
    if fin.any():
        sub = stack[:, fin]
        sub = np.sort(np.where(np.isfinite(sub), sub, np.inf), axis=0)  # measured values first
        n = np.isfinite(sub).sum(axis=0)
        cols = np.arange(sub.shape[1])
        lo, hi = sub[(n - 1) // 2, cols], sub[n // 2, cols]
        out[fin] = np.where(n % 2 == 1, lo, 0.5 * (lo + hi))
    return out


def _robust_sigma(a: np.ndarray) -> float:
    """max(1.4826 · median, 75th percentile / 1.1503) of |e| (equal for Gaussian noise)."""
    return float(max(_MAD_SCALE * np.median(a), np.quantile(a, 0.75) / _Q75_SCALE))


def frame_noise_mm(height: FloatImage, judged: Mask) -> float:
    """σ̂: the robust spread of the frame's second differences at the judged pixels (mm).

    The residuals of :func:`surface_residuals` are second differences ``h(p) - 2 h(p+d) + h(p+2d)``,
    so their noise is that of the frame's centred second differences along rows and columns, taken
    at every judged pixel whose two neighbours on that axis are measured. σ̂ is the larger of
    1.4826 · median|e| and the 75th percentile of |e| / 1.1503 (equal for Gaussian noise); the
    second keeps σ̂ honest on quantized depth (a sensor reporting whole millimetres has most second
    differences exactly 0, so its median is 0). 0 when no such triple exists.

    Parameters
    ----------
    height : (H, W) float ndarray
        Height (mm, larger = nearer the camera), NaN = unmeasured.
    judged : (H, W) bool ndarray

    Returns
    -------
    float
    """
    a, _ = _second_differences(height, check_mask(judged, name="judged", shape=np.shape(height)))
    return _robust_sigma(a) if a.size else 0.0


@dataclass(frozen=True, slots=True)
class NoiseProfile:
    """The frame's noise as a function of height (:func:`noise_profile`).

    Attributes
    ----------
    heights_mm : (B,) float64 ndarray
        Median height of each bin, increasing (empty: the frame had nothing to measure).
    sigma_mm : (B,) float64 ndarray
        Robust σ̂ of the second differences in each bin (:func:`frame_noise_mm`'s estimator).
    step_mm : (B,) float64 ndarray
        The depth step of each bin, 0 for continuous depth: a sensor reporting depth in steps (whole
        millimetres, or disparity levels that grow with the square of the range) gives many
        neighbours exactly equal depths; where at least 20 % of the neighbour differences in a bin
        are exactly 0, its step is the median of the others.
    """

    heights_mm: np.ndarray
    sigma_mm: np.ndarray
    step_mm: np.ndarray

    def _at(self, values: np.ndarray, height) -> np.ndarray:
        h = np.asarray(height, dtype=np.float64)
        if self.heights_mm.size == 0:
            return np.zeros(h.shape)
        return np.interp(np.nan_to_num(h, nan=float(self.heights_mm[0])), self.heights_mm, values)

    def sigma_at(self, height) -> np.ndarray:
        """σ̂ at each height (linear between bins, constant beyond; 0 without bins)."""
        return self._at(self.sigma_mm, height)

    def step_at(self, height) -> np.ndarray:
        """The depth step at each height (as :meth:`sigma_at`)."""
        return self._at(self.step_mm, height)


def noise_profile(height: FloatImage, judged: Mask) -> NoiseProfile:
    """σ̂ and the depth step as functions of height, measured on the frame itself.

    A sensor's noise grows with range (a structured-light or stereo camera's depth step grows with
    the square of the distance), so one frame-wide σ̂ is too small far away and too large near. The
    second differences of :func:`frame_noise_mm` (every k-th of them, at most 200,000) are sorted by
    the median height of their three pixels and cut into ``min(32, n // 2000)`` bins (at least 1) of equal
    counts; each bin gives its median
    height, its robust σ̂, and the depth step of the neighbour differences |h(p) - h(q)| (rows and
    columns, judged p, measured q) whose height falls in the bin.
    """
    judged = check_mask(judged, name="judged", shape=np.shape(height))
    a, at = _second_differences(height, judged)
    if a.size == 0:
        return NoiseProfile(np.zeros(0), np.zeros(0), np.zeros(0))
    stride = -(-a.size // NOISE_MAX_SAMPLES)  # a regular subsample is plenty for 32 robust spreads
    a, at = a[::stride], at[::stride]
    order = np.argsort(at, kind="stable")
    a, at = a[order], at[order]
    bins = int(min(NOISE_MAX_BINS, max(1, a.size // NOISE_MIN_SAMPLES)))
    edges = np.linspace(0, a.size, bins + 1).astype(np.int64)
    heights = np.array([np.median(at[i:j]) for i, j in zip(edges[:-1], edges[1:])])
    sigmas = np.array([_robust_sigma(a[i:j]) for i, j in zip(edges[:-1], edges[1:])])
    h = np.asarray(height, dtype=np.float64)
    d1, d1_at = [], []
    for dh, at1, where in ((h[:, 1:] - h[:, :-1], h[:, :-1], judged[:, :-1]),
                           (h[1:, :] - h[:-1, :], h[:-1, :], judged[:-1, :])):
        sel = where & np.isfinite(dh)
        d1.append(np.abs(dh[sel]))
        d1_at.append(at1[sel])
    d1, d1_at = np.concatenate(d1), np.concatenate(d1_at)
    stride = -(-d1.size // NOISE_MAX_SAMPLES)
    d1, d1_at = d1[::stride], d1_at[::stride]
    # a first difference belongs to the bin whose range of second-difference heights holds it
    upper = np.array([at[j - 1] for j in edges[1:]])
    which = np.minimum(np.searchsorted(upper, d1_at, side="left"), bins - 1)
    steps = np.zeros(bins)
    for k in range(bins):
        v = d1[which == k]
        nonzero = v[v > 0]
        if v.size and nonzero.size and (v.size - nonzero.size) >= QUANTIZED_ZERO_SHARE * v.size:
            steps[k] = np.median(nonzero)
    return NoiseProfile(heights, sigmas, steps)


# --------------------------------------------------------------------------------------------
# Surface residuals and mixed pixels
# --------------------------------------------------------------------------------------------


@numba.njit(cache=True)
def _residual_kernel(h, judged, taus, jumps, min_below, codes, best):  # type: ignore[no-untyped-def]  # numba kernel
    H, W = h.shape
    e = np.empty(8)
    for i in range(H):
        for j in range(W):
            best[i, j] = np.nan
            codes[i, j] = 0
            if not judged[i, j]:
                continue
            hp = h[i, j]
            if not np.isfinite(hp):
                continue
            n = 0
            rmin = np.inf
            eb = np.inf
            emin = np.inf
            emax = -np.inf
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
            jump = jumps[i, j]
            if n == 0 or not rmin > tau:
                continue
            if emin > tau:
                codes[i, j] = RESIDUAL_UP
                continue
            if emax < -tau:
                if n >= min_below:
                    codes[i, j] = RESIDUAL_DOWN
                continue
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


def _check_residual_args(height, judged, tau, jump, min_below):
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


def surface_residuals(height: FloatImage, judged: Mask, *, tau, jump,
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


def _shifted(a: np.ndarray, dr: int, dc: int, fill) -> np.ndarray:
    """``out[p] = a[p + (dr, dc)]``, ``fill`` beyond the border."""
    H, W = a.shape
    out = np.full_like(a, fill)
    if abs(dr) < H and abs(dc) < W:
        out[max(-dr, 0):H - max(dr, 0), max(-dc, 0):W - max(dc, 0)] = \
            a[max(dr, 0):H - max(-dr, 0), max(dc, 0):W - max(-dc, 0)]
    return out


def surface_residuals_reference(height: FloatImage, judged: Mask, *, tau, jump,
                                min_below: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`surface_residuals` as whole-image numpy operations, one shifted image per direction."""
    h, judged, tau, jump, min_below = _check_residual_args(height, judged, tau, jump, min_below)
    A1 = np.stack([_shifted(h, dr, dc, np.nan) for dr, dc in zip(_DR, _DC)])
    A2 = np.stack([_shifted(h, 2 * dr, 2 * dc, np.nan) for dr, dc in zip(_DR, _DC)])
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


# --------------------------------------------------------------------------------------------
# Blob completion
# --------------------------------------------------------------------------------------------


@numba.njit(cache=True)
def _fill_kernel(seed, judged, valid, iterations, min_nb):  # type: ignore[no-untyped-def]  # numba kernel
    H, W = seed.shape
    cur = seed.copy()
    nxt = seed.copy()
    for _ in range(iterations):
        changed = False
        for i in range(H):
            for j in range(W):
                nxt[i, j] = cur[i, j]
                if cur[i, j] or not judged[i, j]:
                    continue
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
                    nxt[i, j] = True
                    changed = True
        cur, nxt = nxt, cur
        if not changed:
            break
    return cur


def _check_fill_args(seed, judged, valid, iterations):
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
    return _fill_kernel(np.ascontiguousarray(seed), np.ascontiguousarray(judged), np.ascontiguousarray(valid),
                        iterations, FILL_MIN_NEIGHBOURS)


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


# --------------------------------------------------------------------------------------------
# Evidence of a floating component
# --------------------------------------------------------------------------------------------


@numba.njit(cache=True)
def _evidence_kernel(labels, valid, rough, height, n):  # type: ignore[no-untyped-def]  # numba kernel
    H, W = labels.shape
    lowest = np.full(n + 1, np.inf)
    highest_out = np.full(n + 1, -np.inf)
    size = np.zeros(n + 1, np.int64)
    holes = np.zeros(n + 1, np.int64)
    edges = np.zeros(n + 1, np.int64)
    edges_valid = np.zeros(n + 1, np.int64)
    n_rough = np.zeros(n + 1, np.int64)
    cnt = np.zeros(n + 1, np.int64)
    for i in range(H):
        for j in range(W):
            c = labels[i, j]
            if c > 0:
                size[c] += 1
                if rough[i, j]:
                    n_rough[c] += 1
                if height[i, j] < lowest[c]:
                    lowest[c] = height[i, j]
                for k in range(8):
                    i1 = i + _DR[k]
                    j1 = j + _DC[k]
                    if i1 < 0 or i1 >= H or j1 < 0 or j1 >= W or labels[i1, j1] == c:
                        continue
                    edges[c] += 1
                    if valid[i1, j1]:
                        edges_valid[c] += 1
                    hq = height[i1, j1]
                    if np.isfinite(hq) and hq > highest_out[c]:
                        highest_out[c] = hq
            elif not valid[i, j]:
                # an unmeasured pixel is a hole of the component holding most of its neighbours
                best = 0
                bc = 0
                for k in range(8):
                    i1 = i + _DR[k]
                    j1 = j + _DC[k]
                    if i1 < 0 or i1 >= H or j1 < 0 or j1 >= W:
                        continue
                    c1 = labels[i1, j1]
                    if c1 > 0:
                        cnt[c1] += 1
                        if cnt[c1] > best or (cnt[c1] == best and c1 < bc):
                            best = cnt[c1]
                            bc = c1
                for k in range(8):
                    i1 = i + _DR[k]
                    j1 = j + _DC[k]
                    if 0 <= i1 < H and 0 <= j1 < W:
                        cnt[labels[i1, j1]] = 0
                if best >= HOLE_MIN_NEIGHBOURS:
                    holes[bc] += 1
    return size, holes, edges, edges_valid, n_rough, lowest, highest_out


def _check_evidence_args(labels, valid, rough, height):
    lab = np.asarray(labels)
    if lab.ndim != 2 or lab.dtype.kind not in "iu":
        raise InputShapeError(f"labels must be an (H, W) integer array, got {describe_array(lab)}")
    valid = check_mask(valid, name="valid", shape=lab.shape)
    rough = check_mask(rough, name="rough", shape=lab.shape)
    h = np.asarray(height)
    if h.shape != lab.shape or h.dtype.kind != "f":
        raise InputShapeError(f"height must be an (H, W) float array like labels {lab.shape}, got {describe_array(h)}")
    if lab.size and lab.min() < 0:
        raise InputShapeError("labels must be >= 0 (0 = no component)")
    n = int(lab.max()) if lab.size else 0
    return np.ascontiguousarray(lab, dtype=np.int64), valid, rough, np.ascontiguousarray(h, dtype=np.float64), n


def _fractions(size, holes, edges, edges_valid, n_rough, lowest, highest_out):
    with np.errstate(invalid="ignore", divide="ignore"):
        hole_frac = holes / (size + holes)
        rough_frac = n_rough / size
        ring_valid = edges_valid / edges
    return (np.nan_to_num(hole_frac[1:]), np.nan_to_num(rough_frac[1:]), np.nan_to_num(ring_valid[1:]),
            (lowest - highest_out)[1:])


def floating_evidence(labels: Labels, valid: Mask, rough: Mask, height: FloatImage) -> tuple[np.ndarray, ...]:
    """Per component: how patchy, how rough, how much over measured points it is, and its clearance.

    Parameters
    ----------
    labels : (H, W) int ndarray
        Components 1..n (0 = none).
    valid : (H, W) bool ndarray
        Measured pixels (every finite point of the frame, in the zone or not).
    rough : (H, W) bool ndarray
        Residual-inconsistent pixels (|residual| > τ).
    height : (H, W) float ndarray
        The heights the components were cut from (NaN = not part of the cut).

    Returns
    -------
    holes : (n,) float64
        Unmeasured pixels with at least 6 of their 8 neighbours in the component (the component
        holding most of them; the lower label on ties), as a share of component + holes.
    rough : (n,) float64
        Share of the component's pixels in ``rough``.
    ring_valid : (n,) float64
        Share of the 8-neighbour pairs (component pixel, pixel outside it, inside the image) whose
        outer pixel is measured.
    clearance : (n,) float64
        Lowest height in the component minus the highest finite height among those outer pixels
        (+inf when none is finite): how far it floats over everything around it.
    """
    lab, valid, rough, h, n = _check_evidence_args(labels, valid, rough, height)
    return _fractions(*_evidence_kernel(lab, np.ascontiguousarray(valid), np.ascontiguousarray(rough), h, n))


def floating_evidence_reference(labels: Labels, valid: Mask, rough: Mask, height: FloatImage) -> tuple[np.ndarray,
                                                                                                       ...]:
    """:func:`floating_evidence` as a plain loop over the pixels (slow; the tests' oracle)."""
    lab, valid, rough, h, n = _check_evidence_args(labels, valid, rough, height)
    H, W = lab.shape
    lowest = np.full(n + 1, np.inf)
    highest_out = np.full(n + 1, -np.inf)
    size = np.zeros(n + 1, np.int64)
    holes = np.zeros(n + 1, np.int64)
    edges = np.zeros(n + 1, np.int64)
    edges_valid = np.zeros(n + 1, np.int64)
    n_rough = np.zeros(n + 1, np.int64)
    for i in range(H):
        for j in range(W):
            nbrs = [(i + dr, j + dc) for dr, dc in zip(_DR, _DC) if 0 <= i + dr < H and 0 <= j + dc < W]
            c = int(lab[i, j])
            if c > 0:
                size[c] += 1
                n_rough[c] += bool(rough[i, j])
                lowest[c] = min(lowest[c], h[i, j]) if not np.isnan(h[i, j]) else lowest[c]
                for q in nbrs:
                    if lab[q] != c:
                        edges[c] += 1
                        edges_valid[c] += bool(valid[q])
                        if np.isfinite(h[q]):
                            highest_out[c] = max(highest_out[c], h[q])
            elif not valid[i, j]:
                counts: dict[int, int] = {}
                for q in nbrs:
                    if lab[q] > 0:
                        counts[int(lab[q])] = counts.get(int(lab[q]), 0) + 1
                if counts:
                    bc = min(counts, key=lambda c1: (-counts[c1], c1))
                    if counts[bc] >= HOLE_MIN_NEIGHBOURS:
                        holes[bc] += 1
    return _fractions(size, holes, edges, edges_valid, n_rough, lowest, highest_out)


# --------------------------------------------------------------------------------------------
# Gap to the local surface
# --------------------------------------------------------------------------------------------


@numba.njit(cache=True)
def _gap_kernel(h, suspect, surface, min_px, max_radius, out):  # type: ignore[no-untyped-def]  # numba kernel
    H, W = h.shape
    buf = np.empty((2 * max_radius + 1) ** 2)
    for i in range(H):
        for j in range(W):
            out[i, j] = np.nan
            if not suspect[i, j] or not np.isfinite(h[i, j]):
                continue
            r = 1
            while r <= max_radius:
                m = 0
                for a in range(max(i - r, 0), min(i + r + 1, H)):
                    for b in range(max(j - r, 0), min(j + r + 1, W)):
                        if surface[a, b]:
                            buf[m] = h[a, b]
                            m += 1
                if m >= min_px:
                    s = np.sort(buf[:m])
                    med = s[m // 2] if m % 2 == 1 else 0.5 * (s[m // 2 - 1] + s[m // 2])
                    out[i, j] = h[i, j] - med
                    break
                r *= 2


def _check_gap_args(height, suspect, surface):
    h = np.asarray(height)
    if h.ndim != 2 or h.dtype.kind != "f":
        raise InputShapeError(f"height must be an (H, W) real float array, got {describe_array(h)}")
    suspect = check_mask(suspect, name="suspect", shape=h.shape)
    surface = check_mask(surface, name="surface", shape=h.shape)
    h = np.ascontiguousarray(h, dtype=np.float64)
    return h, suspect, surface & np.isfinite(h)


def local_gaps(height: FloatImage, suspect: Mask, surface: Mask) -> np.ndarray:
    """Gap (mm, positive = toward the camera) of every suspect pixel to the local surface.

    The local surface of a suspect pixel is the median height of the ``surface`` pixels (measured,
    not suspects) in the smallest square window of radius 1, 2, 4, …, 64 around it holding at
    least 3 of them; NaN where none does.

    Parameters
    ----------
    height : (H, W) float ndarray
    suspect, surface : (H, W) bool ndarray

    Returns
    -------
    (H, W) float64 ndarray
        NaN outside ``suspect``.
    """
    h, suspect, surface = _check_gap_args(height, suspect, surface)
    out = np.empty(h.shape)
    _gap_kernel(h, np.ascontiguousarray(suspect), np.ascontiguousarray(surface), GAP_MIN_PIXELS, GAP_MAX_RADIUS,
                out)
    return out


def local_gaps_reference(height: FloatImage, suspect: Mask, surface: Mask) -> np.ndarray:
    """:func:`local_gaps` as a plain loop with ``np.median`` (slow; the tests' oracle)."""
    h, suspect, surface = _check_gap_args(height, suspect, surface)
    H, W = h.shape
    out = np.full(h.shape, np.nan)
    for i, j in zip(*np.nonzero(suspect & np.isfinite(h))):
        r = 1
        while r <= GAP_MAX_RADIUS:
            win = (slice(max(i - r, 0), i + r + 1), slice(max(j - r, 0), j + r + 1))
            vals = h[win][surface[win]]
            if vals.size >= GAP_MIN_PIXELS:
                out[i, j] = h[i, j] - np.median(vals)
                break
            r *= 2
    return out


# --------------------------------------------------------------------------------------------
# The union, grouped
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class SuspectGroup:
    """One group of suspects to review (accept or reject as a whole).

    Attributes
    ----------
    label : int
        Its value in :attr:`SuspectResult.groups` (1 = highest score).
    detectors : tuple of str
        The detectors that flagged any of its pixels (:data:`DETECTORS` order); the first is the one it
        was grouped by.
    size_px : int
    gap_mm : float
        Median gap of its pixels to the local surface (mm, positive = toward the camera; NaN when no
        measured surface is near).
    bbox : tuple of int
        (row0, col0, row1, col1), ends exclusive.
    score : float
    """

    label: int
    detectors: tuple[str, ...]
    size_px: int
    gap_mm: float
    bbox: tuple[int, int, int, int]
    score: float


@dataclass(frozen=True, slots=True)
class SuspectResult:
    """The suspects of one frame and their groups.

    Attributes
    ----------
    mask : (H, W) bool ndarray
        Every suspect pixel (inside the zone, or above the rim).
    groups : (H, W) int32 ndarray
        0 = none, g = the g-th group; groups are numbered by decreasing score. ``mask == groups > 0``.
    detectors : (H, W) uint8 ndarray
        Per pixel, the bits (1 << i for :data:`DETECTORS`\\[i]) of the detectors that flagged it.
    gap_mm : (H, W) float64 ndarray
        Per suspect pixel, its gap (mm, positive = toward the camera): its residual for a pixel the
        residual detectors flagged alone, else its gap to the local surface (:func:`local_gaps`);
        NaN elsewhere or when no measured surface is near.
    residual_mm : (H, W) float64 ndarray
        The signed surface residual of every judged pixel (:func:`surface_residuals`); NaN outside
        the zone, +inf where no continuation exists.
    group_detectors : (n,) uint8 ndarray
        Bits of the detectors that flagged any pixel of each group.
    group_primary : (n,) uint8 ndarray
        Index in :data:`DETECTORS` of the detector each group was grouped by.
    group_size : (n,) int64 ndarray
    group_gap_mm : (n,) float64 ndarray
    group_bbox : (n, 4) int32 ndarray
        row0, col0, row1, col1 (ends exclusive).
    group_score : (n,) float64 ndarray
        sqrt(size_px) · |gap_mm| (0 when the gap is unknown): large groups far from the surface first.
    noise_mm : float
        The median over the zone of σ̂ at each pixel's height (:func:`noise_profile`).
    threshold_mm : float
        The median over the zone of τ = max(min_residual_mm, noise_k · σ̂(height)).
    noise_profile : NoiseProfile
        σ̂ and the depth step as functions of height (:func:`noise_profile`).
    floating_step_mm : float
        The floating detector's z-cut step.
    merge_radius_px : (5,) int64 ndarray
        The merge radius each detector ended with.
    """

    mask: Mask
    groups: Labels
    detectors: np.ndarray
    gap_mm: np.ndarray
    residual_mm: np.ndarray
    group_detectors: np.ndarray
    group_primary: np.ndarray
    group_size: np.ndarray
    group_gap_mm: np.ndarray
    group_bbox: np.ndarray
    group_score: np.ndarray
    noise_mm: float
    threshold_mm: float
    noise_profile: NoiseProfile
    floating_step_mm: float
    merge_radius_px: np.ndarray

    @property
    def n_groups(self) -> int:
        return int(self.group_size.size)

    def group(self, label: int) -> SuspectGroup:
        """Group ``label`` (1-based) as a record."""
        if not 1 <= label <= self.n_groups:
            raise ParameterError(f"group label must be in 1..{self.n_groups}, got {label!r}")
        i = label - 1
        p = int(self.group_primary[i])
        names = detector_names(int(self.group_detectors[i]))
        names = (DETECTORS[p],) + tuple(n for n in names if n != DETECTORS[p])
        return SuspectGroup(label, names, int(self.group_size[i]), float(self.group_gap_mm[i]),
                            tuple(int(v) for v in self.group_bbox[i]), float(self.group_score[i]))

    def detector_mask(self, name: str) -> Mask:
        """(H, W) bool: the pixels detector ``name`` flagged."""
        return (self.detectors & detector_bits([name])) > 0


def _floating(height_mm: np.ndarray, zone: Mask, valid: Mask, rough: Mask, params: SuspectParams, a_max: float,
              step: float, profile) -> tuple[Mask, np.ndarray]:
    """The floating detector: z-cut components over the zone's whole height range (see module notes).

    Returns the mask and, on its pixels, their gap (mm) over the median height of the measured
    pixels bordering their component (NaN elsewhere, or when none borders it).
    """
    hz = np.where(zone, height_mm, np.nan)
    fin = np.isfinite(hz)
    gap = np.full(zone.shape, np.nan)
    if not fin.any():
        return np.zeros(zone.shape, bool), gap
    span = float(hz[fin].max() - hz[fin].min())
    step = max(step, span / (MAX_STAGE_LEVELS - 2))  # every level of the range within find_clusters' cap
    depth = span + step
    cut = find_clusters(hz, params=ZCutParams(step=step, max_depth=depth, max_area=params.floating_rho * a_max))
    if cut.n_clusters == 0:
        return np.zeros(zone.shape, bool), gap
    holes, rough_frac, ring, clearance = floating_evidence(cut.clusters, valid, rough, hz)
    lab = cut.clusters
    flat = lab.ravel()
    inside = flat > 0
    lowest = np.full(cut.n_clusters + 1, np.inf)
    np.minimum.at(lowest, flat[inside], hz.ravel()[inside])
    lowest = lowest[1:]
    clear = clearance > np.maximum(FLOATING_CLEARANCE_SIGMAS * profile.sigma_at(lowest),
                                   FLOATING_CLEARANCE_STEPS * profile.step_at(lowest))
    keep = clear & ((cut.areas < params.plain_rho * a_max) | (holes >= params.evidence_holes)
                    | (rough_frac >= params.evidence_inconsistent) | (ring >= params.evidence_ring_valid))
    mask = np.concatenate([[False], keep])[lab] & zone
    if mask.any():
        kept = np.where(mask, lab, 0)
        border = ndimage.maximum_filter(kept, size=3, mode="constant")
        border = np.where((kept == 0) & valid & np.isfinite(height_mm), border, 0)  # measured, outside
        ring_h = _label_medians(height_mm, border, cut.n_clusters)
        gap[mask] = hz[mask] - np.concatenate([[np.nan], ring_h])[kept[mask]]
    return mask, gap


def _components(m: np.ndarray, r: int) -> tuple[np.ndarray, int]:
    """8-connected components of ``m`` grown by ``r`` pixels (labels on ``m``'s pixels only, 1..n)."""
    grown = ndimage.maximum_filter(m.view(np.uint8), size=2 * r + 1, mode="constant") > 0 if r > 0 else m
    lab, n = ndimage.label(grown, structure=np.ones((3, 3), bool))
    lab = np.where(m, lab, 0)
    used = np.unique(lab[m])
    remap = np.zeros(n + 1, np.int32)
    remap[used] = np.arange(1, used.size + 1, dtype=np.int32)
    return remap[lab], int(used.size)


def _union_diagonals(boxes: np.ndarray, i: int) -> np.ndarray:
    """Diagonal (pixels) of the bounding box of box ``i`` united with each box."""
    r0 = np.minimum(boxes[:, 0], boxes[i, 0])
    c0 = np.minimum(boxes[:, 1], boxes[i, 1])
    r1 = np.maximum(boxes[:, 2], boxes[i, 2])
    c1 = np.maximum(boxes[:, 3], boxes[i, 3])
    return np.hypot((r1 - r0).astype(np.float64), (c1 - c0).astype(np.float64))


def _merge_compact(boxes: np.ndarray, kind: np.ndarray, max_groups: int) -> np.ndarray:
    """Agglomerate boxes into at most ``max_groups`` groups, never across kinds: repeatedly merge the
    pair whose united bounding box has the smallest diagonal (lowest indices on ties).

    Returns the group of each box as the index of its representative box.
    """
    n = boxes.shape[0]
    boxes = boxes.astype(np.int64).copy()
    rep = np.arange(n)
    alive = np.ones(n, bool)
    best = np.full(n, np.inf)
    partner = np.full(n, -1)

    def row(i: int) -> np.ndarray:
        d = _union_diagonals(boxes, i)
        d[~alive | (kind != kind[i])] = np.inf
        d[i] = np.inf
        return d

    def refresh(i: int) -> None:
        d = row(i)
        j = int(np.argmin(d))
        best[i], partner[i] = d[j], j

    for i in range(n):
        refresh(i)
    count = n
    while count > max_groups:
        i = int(np.argmin(best))
        if not np.isfinite(best[i]):
            break  # one group per kind left
        j = int(partner[i])
        a, b = min(i, j), max(i, j)
        boxes[a, :2] = np.minimum(boxes[a, :2], boxes[b, :2])
        boxes[a, 2:] = np.maximum(boxes[a, 2:], boxes[b, 2:])
        alive[b] = False
        best[b] = np.inf
        rep[rep == b] = a
        count -= 1
        d = row(a)
        better = alive & (d < best)
        best[better] = d[better]
        partner[better] = a
        for k in np.flatnonzero(alive & ((partner == a) | (partner == b))):
            refresh(int(k))
        refresh(a)
    return rep


def strength_classes(primary: np.ndarray, strength: np.ndarray) -> np.ndarray:
    """The strength class of each suspect pixel (0, 1, 2; -1 where ``primary`` is -1).

    Per detector, the 8-connected components of its pixels take the median of their pixels'
    ``strength`` (|gap| / τ); the class is the number of :data:`STRENGTH_CLASSES` bounds that median
    reaches (NaN, no surface to measure against: the strongest class).

    Parameters
    ----------
    primary : (H, W) int ndarray
        Each pixel's grouping detector (index into :data:`DETECTORS`), -1 for no suspect.
    strength : (H, W) float ndarray
        |gap| / τ of each pixel.
    """
    out = np.full(primary.shape, -1, np.int8)
    s = np.where(np.isfinite(strength), strength, np.inf)
    for i in range(len(DETECTORS)):
        m = primary == i
        if not m.any():
            continue
        lab, n = ndimage.label(m, structure=np.ones((3, 3), bool))
        med = _label_medians(s, lab, n)
        cls = np.searchsorted(np.asarray(STRENGTH_CLASSES), med, side="right").astype(np.int8)
        out[m] = cls[lab[m] - 1]
    return out


def _group(codes: np.ndarray, strength: np.ndarray, params: SuspectParams
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Group labels (unordered), each group's primary detector, and the merge radius of each detector.

    Per detector (a pixel belongs to the first of its detectors in :data:`DETECTORS`) and strength
    class (:func:`strength_classes`: one decision must fit a group, and suspects at the noise's edge
    are not judged like those far off the surface), the suspects within ``merge_radius_px`` form
    components (the radius doubles while one has more than ``MAX_NODES``); then, while the frame has
    more than ``max_groups`` groups, the two groups of one detector and class whose united bounding
    box is smallest merge (:func:`_merge_compact`), and only when that is not enough, groups of one
    detector across classes: groups stay compact regions a person can zoom to, a large blob stays
    alone, specks near each other join.
    """
    primary = np.full(codes.shape, -1, np.int8)
    for i in reversed(range(len(DETECTORS))):  # the first detector in DETECTORS wins
        primary[(codes >> i) & 1 > 0] = i
    cls = strength_classes(primary, strength)
    n_cls = len(STRENGTH_CLASSES) + 1
    radii = np.full(len(DETECTORS), params.merge_radius_px, np.int64)
    limit = max(codes.shape)
    per = []
    fine = []
    for i in range(len(DETECTORS)):
        for c in range(n_cls):
            m = (primary == i) & (cls == c)
            r = int(params.merge_radius_px)
            lab, n = _components(m, r)
            while n > MAX_NODES and r < limit:
                r = min(2 * r + 1, limit)
                lab, n = _components(m, r)
            radii[i] = max(radii[i], r)
            per.append((lab, n))
            fine.append(i * n_cls + c)
    offsets = np.cumsum([0] + [n for _, n in per])
    total = int(offsets[-1])
    boxes = np.zeros((total, 4), np.int64)
    kind = np.zeros(total, np.int64)
    for i, (lab, n) in enumerate(per):
        if n:
            boxes[offsets[i]:offsets[i + 1]] = [[s[0].start, s[1].start, s[0].stop, s[1].stop]
                                                for s in ndimage.find_objects(lab, max_label=n)]
            kind[offsets[i]:offsets[i + 1]] = fine[i]
    rep = _merge_compact(boxes, kind, params.max_groups) if total > params.max_groups else np.arange(total)
    if np.unique(rep).size > params.max_groups:  # more detector-and-class kinds than groups: join classes
        heads = np.unique(rep)
        hb = np.array([[boxes[rep == h, 0].min(), boxes[rep == h, 1].min(), boxes[rep == h, 2].max(),
                        boxes[rep == h, 3].max()] for h in heads], np.int64)
        rep2 = _merge_compact(hb, kind[heads] // n_cls, params.max_groups)
        rep = heads[rep2[np.searchsorted(heads, rep)]]
    kind //= n_cls
    _, dense = np.unique(rep, return_inverse=True)
    node_group = np.concatenate([[0], dense + 1]).astype(np.int32)
    groups = np.zeros(codes.shape, np.int32)
    kinds = np.zeros(int(dense.max()) + 1 if total else 0, np.uint8)
    kinds[dense] = kind
    for i, (lab, n) in enumerate(per):
        if n:
            sel = lab > 0
            groups[sel] = node_group[lab[sel] + offsets[i]]
    return groups, kinds, radii


def suspects(
    xyz: XYZ,
    height_mm: FloatImage,
    zone: Mask,
    above_rim: Mask | None = None,
    *,
    params: SuspectParams,
    intrinsics: Intrinsics | None = None,
) -> SuspectResult:
    """Every suspect of one frame, from all the detectors, grouped for review.

    Parameters
    ----------
    xyz : (H, W, 3) float ndarray
        The frame (metres, camera optical frame, NaN = unmeasured): every measured point is context
        for the residual tests, in the zone or not (a flying pixel between a part and the bin floor is
        judged against the floor's points).
    height_mm : (H, W) float ndarray
        The height image the z-cut is given (mm); only its zone pixels are used (the floating
        detector).
    zone : (H, W) bool ndarray
        The pixels judged (the zone of the pipeline; every valid pixel without the bin stages).
    above_rim : (H, W) bool ndarray, optional
        Points above the rim, flagged by the pipeline's removal (``Zone.easy``); they are suspects,
        and not context for the others.
    params : SuspectParams
    intrinsics : Intrinsics, optional
        The camera; when given, its image size must be the frame's (a check that ``xyz`` is the
        camera's organized grid). The detectors work on the grid and need nothing else from it.

    Returns
    -------
    SuspectResult
    """
    if not isinstance(params, SuspectParams):
        raise ParameterError(f"params must be a SuspectParams, got {type(params).__name__}")
    a = check_xyz(xyz)
    H, W = a.shape[:2]
    h_img = np.asarray(height_mm)
    if h_img.shape != (H, W) or h_img.dtype.kind != "f":
        raise InputShapeError(f"height_mm must be an (H, W) float array like xyz {(H, W)}, got {describe_array(h_img)}")
    zone = check_mask(zone, name="zone", shape=(H, W))
    easy = np.zeros((H, W), bool) if above_rim is None else check_mask(above_rim, name="above_rim", shape=(H, W))
    if intrinsics is not None:
        if not isinstance(intrinsics, Intrinsics):
            raise ParameterError(f"intrinsics must be an Intrinsics, got {type(intrinsics).__name__}")
        if (intrinsics.height, intrinsics.width) != (H, W):
            raise InputShapeError(f"intrinsics are for {intrinsics.height}x{intrinsics.width} images, "
                                  f"the frame is {H}x{W}")
    valid = np.isfinite(a[..., 0]) & np.isfinite(a[..., 1]) & np.isfinite(a[..., 2])
    zone = zone & valid & ~easy
    easy = easy & valid
    context = np.where(valid & ~easy, -1000.0 * a[..., 2].astype(np.float64), np.nan)
    h_zcut = np.ascontiguousarray(h_img, dtype=np.float64)

    profile = noise_profile(context, zone)
    sigma_px = profile.sigma_at(local_height(context))
    sigma = float(np.median(sigma_px[zone])) if zone.any() else 0.0
    tau = np.maximum(params.min_residual_mm, params.noise_k * sigma_px)
    jump = np.maximum(params.jump_mm, params.noise_k * sigma_px)
    step = max(params.floating_step_mm, FLOATING_STEP_SIGMAS * sigma)
    a_max = params.a_max if params.a_max is not None else max(0.01 * H * W, 1.0)

    codes, residual = surface_residuals(context, zone, tau=tau, jump=jump, min_below=params.below_min_directions)
    off = codes > 0
    if params.fill_iterations > 0:
        filled = fill_blobs(off, zone, valid & ~easy, iterations=params.fill_iterations)
        codes[filled & ~off] = RESIDUAL_UP
    rough = zone & ~(np.abs(residual) <= tau)  # in the zone: inf (no continuation) is rough
    floating, floating_gap = _floating(h_zcut, zone, valid & ~easy, rough, params, a_max, step, profile)
    codes[floating] |= FLOATING
    codes[easy] |= ABOVE_RIM
    mask = codes > 0

    # gaps: a floating pixel's over the measured pixels bordering its component; a pixel off the
    # surface, its residual (to the nearest continuation); a blob's or an above-rim pixel's, to the
    # local surface around it
    by_residual = off & ((codes & (FLOATING | ABOVE_RIM)) == 0) & np.isfinite(residual)
    by_border = floating & ~easy
    gap = local_gaps(np.where(valid, -1000.0 * a[..., 2].astype(np.float64), np.nan),
                     mask & ~by_residual & ~by_border, valid & ~mask)
    gap[by_residual] = residual[by_residual]
    gap[by_border] = floating_gap[by_border]
    tau_px = np.where(np.isfinite(tau) & (tau > 0), tau, params.min_residual_mm)
    groups, primary, radii = _group(codes, np.abs(gap) / tau_px, params)
    n = int(primary.size)
    size = np.bincount(groups.ravel(), minlength=n + 1)[1:].astype(np.int64)
    bits = np.zeros(n + 1, np.uint8)
    np.bitwise_or.at(bits, groups.ravel(), codes.ravel())
    bits = bits[1:]
    if n:
        g_gap = _label_medians(gap, groups, n)
        boxes = ndimage.find_objects(groups, max_label=n)
        bbox = np.array([[s[0].start, s[1].start, s[0].stop, s[1].stop] for s in boxes], np.int32)
    else:
        g_gap = np.zeros(0)
        bbox = np.zeros((0, 4), np.int32)
    score = np.sqrt(size) * np.nan_to_num(np.abs(g_gap), nan=0.0)
    order = np.lexsort((np.arange(n), -size, -score))  # score, then size, then first found
    rank = np.zeros(n + 1, np.int32)
    rank[order + 1] = np.arange(1, n + 1, dtype=np.int32)
    groups = rank[groups]
    return SuspectResult(
        mask=mask, groups=groups, detectors=codes, gap_mm=gap, residual_mm=residual,
        group_detectors=bits[order], group_primary=primary[order], group_size=size[order],
        group_gap_mm=g_gap[order], group_bbox=bbox[order], group_score=score[order],
        noise_mm=sigma, threshold_mm=float(np.median(tau[zone])) if zone.any() else float(params.min_residual_mm),
        noise_profile=profile, floating_step_mm=step, merge_radius_px=radii,
    )


def _label_medians(values: np.ndarray, labels: np.ndarray, n: int) -> np.ndarray:
    """Median of the finite ``values`` under each label 1..n (NaN for a label with none)."""
    sel = (labels > 0) & np.isfinite(values)
    g = labels[sel]
    v = values[sel]
    out = np.full(n, np.nan)
    if g.size == 0:
        return out
    order = np.lexsort((v, g))
    g, v = g[order], v[order]
    ids = np.arange(1, n + 1)
    starts = np.searchsorted(g, ids, side="left")
    counts = np.searchsorted(g, ids, side="right") - starts
    has = counts > 0
    lo = starts[has] + (counts[has] - 1) // 2
    hi = starts[has] + counts[has] // 2
    out[has] = np.where(lo == hi, v[lo], 0.5 * (v[lo] + v[hi]))
    return out
