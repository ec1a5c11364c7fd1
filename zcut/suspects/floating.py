"""The floating detector: z-cut components of any depth, kept on evidence that they are not a clean surface.

``floating`` (see :mod:`zcut.suspects`): the z-cut (:func:`zcut.cuts.find_clusters`) over the zone's
whole height range; components smaller than ``floating_rho · a_max``, those larger than
``plain_rho · a_max`` only with evidence (:func:`floating_evidence`: holes inside, rough, hovering over
measured points), and only those clearing everything around them.
"""

from __future__ import annotations

import numba
import numpy as np
from scipy import ndimage

from ..cloud import check_mask
from ..cuts import MAX_STAGE_LEVELS, find_clusters
from ..errors import InputShapeError, describe_array
from ..params import SuspectParams, ZCutParams
from ..types import FloatImage, Labels, Mask
from .detectors import _DC, _DR, label_medians
from .noise import NoiseProfile

# a hole of a floating component: an unmeasured pixel with at least this many of its 8 neighbours in it
# (6: holes inside it, not the notches of a ragged border)
HOLE_MIN_NEIGHBOURS = 6
# the floating detector's step: max(floating_step_mm, FLOATING_STEP_SIGMAS * noise): a step below the
# noise of neighbour differences would cut clean surfaces into floating terraces
FLOATING_STEP_SIGMAS = 1.0
# a floating component must clear everything around it by more than this many σ̂ at its height, and
# by more than this many depth steps (on a sensor reporting depth in steps, the top of a dome is a
# terrace one step above its surroundings: it floats, and it is the sensor's rounding)
FLOATING_CLEARANCE_SIGMAS = 1.0
FLOATING_CLEARANCE_STEPS = 1.5


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


def _check_evidence_args(labels: object, valid: object, rough: object, height: object
                         ) -> tuple[np.ndarray, Mask, Mask, np.ndarray, int]:
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


def _fractions(size: np.ndarray, holes: np.ndarray, edges: np.ndarray, edges_valid: np.ndarray, n_rough: np.ndarray,
               lowest: np.ndarray, highest_out: np.ndarray) -> tuple[np.ndarray, ...]:
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


@numba.njit(cache=True)
def _finite_range(h):  # type: ignore[no-untyped-def]  # numba kernel
    """(min, max) of the finite values of h ((inf, -inf) when none), without a masked copy."""
    lo = np.inf
    hi = -np.inf
    for v in h.ravel():
        if np.isfinite(v):
            if v < lo:
                lo = v
            if v > hi:
                hi = v
    return lo, hi


def floating_components(height_mm: np.ndarray, zone: Mask, valid: Mask, rough: Mask, params: SuspectParams,
                        a_max: float, step: float, profile: NoiseProfile) -> tuple[Mask, np.ndarray]:
    """The floating detector: z-cut components over the zone's whole height range (see module notes).

    Returns the mask and, on its pixels, their gap (mm) over the median height of the measured
    pixels bordering their component (NaN elsewhere, or when none borders it).
    """
    hz = np.where(zone, height_mm, np.nan)
    gap = np.full(zone.shape, np.nan)
    lo, hi = _finite_range(hz)
    if not lo <= hi:  # no finite height in the zone
        return np.zeros(zone.shape, bool), gap
    span = float(hi - lo)  # (a zero's sign may differ from hz[fin]'s max / min: the step and depth do not)
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
        rows = np.flatnonzero(mask.any(axis=1))
        cols = np.flatnonzero(mask.any(axis=0))
        box = (slice(max(int(rows[0]) - 1, 0), int(rows[-1]) + 2), slice(max(int(cols[0]) - 1, 0), int(cols[-1]) + 2))
        m, h = mask[box], height_mm[box]  # the components and the pixels bordering them
        kept = np.where(m, lab[box], 0)
        border = ndimage.maximum_filter(kept, size=3, mode="constant")
        border = np.where((kept == 0) & valid[box] & np.isfinite(h), border, 0)  # measured, outside
        ring_h = label_medians(h, border, cut.n_clusters)
        gap[box][m] = hz[box][m] - np.concatenate([[np.nan], ring_h])[kept[m]]
    return mask, gap
