"""The frame's noise, measured on the frame itself: σ̂ and the depth step as functions of height.

The thresholds of every detector (:mod:`zcut.suspects`) are taken from it: τ = max(min_residual_mm,
noise_k · σ̂(height)), the floating detector's step and clearance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..cloud import check_mask
from ..types import FloatImage, Mask
from .detectors import shifted

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


def _median3(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    median: np.ndarray = np.maximum(np.minimum(a, b), np.minimum(np.maximum(a, b), c))
    return median


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
    stack = np.stack([h] + [shifted(h, dr, dc, np.nan) for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0))])
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

    def _at(self, values: np.ndarray, height: ArrayLike) -> np.ndarray:
        h = np.asarray(height, dtype=np.float64)
        if self.heights_mm.size == 0:
            return np.zeros(h.shape)
        at: np.ndarray = np.interp(np.nan_to_num(h, nan=float(self.heights_mm[0])), self.heights_mm, values)
        return at

    def sigma_at(self, height: ArrayLike) -> np.ndarray:
        """σ̂ at each height (linear between bins, constant beyond; 0 without bins)."""
        return self._at(self.sigma_mm, height)

    def step_at(self, height: ArrayLike) -> np.ndarray:
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
    parts: list[np.ndarray] = []
    parts_at: list[np.ndarray] = []
    for dh, at1, where in ((h[:, 1:] - h[:, :-1], h[:, :-1], judged[:, :-1]),
                           (h[1:, :] - h[:-1, :], h[:-1, :], judged[:-1, :])):
        sel = where & np.isfinite(dh)
        parts.append(np.abs(dh[sel]))
        parts_at.append(at1[sel])
    d1, d1_at = np.concatenate(parts), np.concatenate(parts_at)
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
