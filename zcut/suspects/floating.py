"""The floating detector: z-cut components of any depth, kept on evidence that they are not a clean surface.

``floating`` (see :mod:`zcut.suspects`): the z-cut (:func:`zcut.cuts.find_clusters`) over the zone's
whole height range; components smaller than ``floating_rho · a_max``, those larger than
``plain_rho · a_max`` only with evidence (:func:`floating_evidence`: holes inside, rough, hovering over
measured points), and only those clearing everything around them.

**The small floating components are this detector's.** A component of its cut that clears everything around it
and is smaller than :data:`FLOATING_OWNED_RHO` · a_max is *judged* here alone, kept or not by its size
(``plain_rho``) and its evidence: the patch detector (:mod:`zcut.suspects.patches`) takes none of its pixels
(:func:`floating_components`' ``judged``). So ``plain_rho`` moves the suspects' union on its own (a small component
this detector leaves is a patch too: a depth step bounds it on every side), and at the defaults (``plain_rho`` =
:data:`FLOATING_OWNED_RHO`) the union is what both detectors flagged before: every judged component is kept by its
size. The larger ones (up to ``floating_rho``) both detectors may flag: one without evidence stays a patch.
"""

from __future__ import annotations

import numba
import numpy as np

from ..cloud import check_mask
from ..cuts import MAX_STAGE_LEVELS, cluster_labels_of
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
#: the floating components (clear of everything around them) smaller than this × a_max are the floating detector's
#: alone: the patch detector takes none of their pixels (module notes). 0.07: the paper's nominal ρ_thr, the
#: default ``plain_rho``
FLOATING_OWNED_RHO = 0.07


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
                # an unmeasured pixel is a hole of the component holding most of its neighbours; most
                # have no component around them (one look at the 8 labels, no counting: the same result)
                if 0 < i < H - 1 and 0 < j < W - 1:
                    if (labels[i - 1, j - 1] | labels[i - 1, j] | labels[i - 1, j + 1] | labels[i, j - 1]
                            | labels[i, j + 1] | labels[i + 1, j - 1] | labels[i + 1, j] | labels[i + 1, j + 1]) == 0:
                        continue
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
def _zone_heights(h, zone, hz):  # type: ignore[no-untyped-def]  # numba kernel
    """hz = the heights in the zone, NaN elsewhere (``np.where(zone, h, nan)``), and (min, max) of its
    finite values ((inf, -inf) when none; a tie keeps the first in raster order, as a scan of hz would)."""
    H, W = h.shape
    lo = np.inf
    hi = -np.inf
    for i in range(H):
        for j in range(W):
            v = h[i, j] if zone[i, j] else np.nan
            hz[i, j] = v
            if np.isfinite(v):
                if v < lo:
                    lo = v
                if v > hi:
                    hi = v
    return lo, hi


@numba.njit(cache=True)
def _kept_ring(lab, keep, zone, valid, h, n_max, mask):  # type: ignore[no-untyped-def]  # numba kernel
    """The kept components' pixels (``mask`` = keep[lab] & zone; their flat indices in raster order, at
    most ``n_max``) and the measured pixels bordering them (valid, finite h, not kept, with a kept pixel
    among their 8 neighbours: the largest such label, as a 3 × 3 maximum filter of the kept labels
    gives it), in raster order: (kept indices, ring labels, ring heights)."""
    H, W = lab.shape
    idx = np.empty(n_max, np.int64)
    n = 0
    r0 = H
    r1 = -1
    for i in range(H):
        for j in range(W):
            c = lab[i, j]
            k = keep[c] and zone[i, j]
            mask[i, j] = k
            if k:
                idx[n] = i * W + j
                n += 1
                if r0 == H:
                    r0 = i
                r1 = i
    cap = max(1024, 2 * n)
    rl = np.empty(cap, np.int64)
    rh = np.empty(cap)
    m = 0
    # each row's kept pixels: idx[first[i] : first[i + 1]] (raster order, so their columns increase)
    first = np.zeros(H + 1, np.int64)
    for k in range(n):
        first[idx[k] // W + 1] += 1
    for i in range(H):
        first[i + 1] += first[i]
    for i in range(max(r0 - 1, 0), min(r1 + 2, H)):
        # the ring's candidates of row i: the columns within 1 of a kept pixel of rows i - 1 .. i + 1, as
        # merged intervals [c - 1, c + 1] from the three rows' increasing columns, left to right
        a0 = first[max(i - 1, 0)]
        a1 = first[min(i + 2, H)]  # the kept pixels of rows i - 1 .. i + 1: three runs of idx
        p0 = a0
        e0 = first[i] if i > 0 else a0
        p1 = first[i]
        e1 = first[i + 1]
        p2 = first[i + 1]
        e2 = a1 if i + 1 < H else p2
        lo = -1
        hi = -2
        while True:
            # the smallest column among the three runs' heads (W: none left)
            c = W
            if p0 < e0:
                c = idx[p0] - (i - 1) * W
            if p1 < e1:
                c = min(c, idx[p1] - i * W)
            if p2 < e2:
                c = min(c, idx[p2] - (i + 1) * W)
            if c < W and c - 1 <= hi + 1:  # joins the current interval
                hi = max(hi, min(c + 1, W - 1))
            else:
                for j in range(max(lo, 0), hi + 1):  # the interval's pixels, in order
                    if mask[i, j] or not valid[i, j]:
                        continue
                    v = h[i, j]
                    if not np.isfinite(v):
                        continue
                    best = 0
                    for a in range(max(i - 1, 0), min(i + 2, H)):
                        for b in range(max(j - 1, 0), min(j + 2, W)):
                            if mask[a, b] and lab[a, b] > best:
                                best = lab[a, b]
                    if best == 0:  # pragma: no cover - every candidate has a kept neighbour
                        continue
                    if m == cap:
                        cap *= 2
                        rl2 = np.empty(cap, np.int64)
                        rh2 = np.empty(cap)
                        rl2[:m] = rl[:m]
                        rh2[:m] = rh[:m]
                        rl = rl2
                        rh = rh2
                    rl[m] = best
                    rh[m] = v
                    m += 1
                if c == W:
                    break
                lo = max(c - 1, 0)
                hi = min(c + 1, W - 1)
            if p0 < e0 and idx[p0] - (i - 1) * W == c:
                p0 += 1
            elif p1 < e1 and idx[p1] - i * W == c:
                p1 += 1
            else:
                p2 += 1
    return idx[:n], rl[:m], rh[:m]


@numba.njit(cache=True)
def _judged_pixels(lab, judged_lab, zone, out):  # type: ignore[no-untyped-def]  # numba kernel
    """``out = judged_lab[lab] & zone`` (``judged_lab`` per label 0..n, False at 0), in one pass."""
    H, W = lab.shape
    for i in range(H):
        for j in range(W):
            out[i, j] = judged_lab[lab[i, j]] and zone[i, j]


def floating_components(height_mm: np.ndarray, zone: Mask, valid: Mask, rough: Mask, params: SuspectParams,
                        a_max: float, step: float, profile: NoiseProfile, *, hz: np.ndarray | None = None,
                        judged: np.ndarray | None = None) -> tuple[Mask, np.ndarray, np.ndarray]:
    """The floating detector: z-cut components over the zone's whole height range (see module notes).

    ``height_mm`` C-contiguous float64. Returns the mask, the flat indices of its pixels (raster order)
    and there their gap (mm) over the median height of the measured pixels bordering their component
    (NaN when none borders it). Without frame-sized temporaries but the zone's heights and the mask; ``hz``:
    an (H, W) float64 C-contiguous array for the zone's heights (a caller's scratch; nothing returned is a view
    of it), else a fresh one. ``judged``: an (H, W) bool C-contiguous array, when given, set to the pixels of
    the components the detector judges alone (those of its cut that clear everything around them and are smaller
    than :data:`FLOATING_OWNED_RHO` · a_max, kept or not: the module notes).
    """
    H, W = zone.shape
    if hz is None:
        hz = np.empty((H, W))
    elif hz.shape != (H, W) or hz.dtype != np.float64 or not hz.flags.c_contiguous:
        raise InputShapeError(f"hz must be an (H, W) C-contiguous float64 array like zone {(H, W)}, "
                              f"got {describe_array(hz)}")
    if judged is not None:
        if judged.shape != (H, W) or judged.dtype != np.bool_ or not judged.flags.c_contiguous:
            raise InputShapeError(f"judged must be an (H, W) C-contiguous bool array like zone {(H, W)}, "
                                  f"got {describe_array(judged)}")
        judged[...] = False
    lo, hi = _zone_heights(height_mm, zone, hz)
    none = (np.zeros(zone.shape, bool), np.zeros(0, np.int64), np.zeros(0))
    if not lo <= hi:  # no finite height in the zone
        return none
    span = float(hi - lo)  # (a zero's sign may differ from hz[fin]'s max / min: the step and depth do not)
    step = max(step, span / (MAX_STAGE_LEVELS - 2))  # every level of the range within find_clusters' cap
    depth = span + step
    # find_clusters' clusters and areas, by the pruned flood where it applies (zcut.cuts.cluster_labels_of)
    lab, areas, _ = cluster_labels_of(hz, params=ZCutParams(step=step, max_depth=depth,
                                                           max_area=params.floating_rho * a_max))
    n = int(areas.size)
    if n == 0:
        return none
    # lab: int32, 1..n, C-contiguous (cluster_labels_of's own array)
    size, holes_n, edges, edges_valid, n_rough, lowest, highest_out = _evidence_kernel(
        lab, np.ascontiguousarray(valid), np.ascontiguousarray(rough), hz, n)
    holes, rough_frac, ring, clearance = _fractions(size, holes_n, edges, edges_valid, n_rough, lowest, highest_out)
    # the lowest height of each component (np.minimum.at's value: a tie of -0.0 and 0.0 may keep the other
    # zero, which σ̂(height) and the step there do not tell apart)
    lowest = lowest[1:]
    clear = clearance > np.maximum(FLOATING_CLEARANCE_SIGMAS * profile.sigma_at(lowest),
                                   FLOATING_CLEARANCE_STEPS * profile.step_at(lowest))
    keep = clear & ((areas < params.plain_rho * a_max) | (holes >= params.evidence_holes)
                    | (rough_frac >= params.evidence_inconsistent) | (ring >= params.evidence_ring_valid))
    owned = clear & (areas < FLOATING_OWNED_RHO * a_max)
    if judged is not None and owned.any():
        _judged_pixels(lab, np.concatenate([[False], owned]), zone, judged)
    mask = np.empty((H, W), bool)
    idx, ring_lab, ring_h = _kept_ring(lab, np.concatenate([[False], keep]), zone, valid, height_mm,
                                       int(areas.sum()), mask)
    if idx.size == 0:
        return mask, idx, np.zeros(0)
    ring_med = label_medians(ring_h, ring_lab, n)
    gap = hz.ravel()[idx] - np.concatenate([[np.nan], ring_med])[lab.ravel()[idx]]
    return mask, idx, gap
