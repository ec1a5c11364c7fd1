"""The suspects as they were before the fast path (issue 32): the oracle of :func:`zcut.suspects.suspects`.

:func:`suspects_reference` is :func:`zcut.suspects.suspects` as it stood before its parts were made fast
(numba kernels for the local height, the noise profile's samples, the edge-aware surface, the grouping's
agglomeration; work on the suspects' bounding boxes instead of whole frames; the edge-aware distance only
where a gap takes it): every function here is the previous code, verbatim but for its name, and
``tests/zcut/test_suspects_fast.py`` checks that both give the same result bit for bit.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from scipy import ndimage

from ..cloud import Intrinsics, check_mask, check_xyz
from ..cuts import MAX_STAGE_LEVELS, find_clusters
from ..edge_surface import EdgeSurfaceParams, _check_args, _reach, _smallest_eigvec, _surfaces
from ..errors import InputShapeError, ParameterError, describe_array
from ..params import SuspectParams, ZCutParams
from ..types import XYZ, FloatImage, Mask
from .detectors import (
    _DC,
    _DR,
    _OPP,
    ABOVE_RIM,
    DETECTORS,
    FLOATING,
    MIXED,
    PATCH,
    RESIDUAL_DOWN,
    RESIDUAL_UP,
    label_medians,
    shifted,
)
from .floating import (
    FLOATING_CLEARANCE_SIGMAS,
    FLOATING_CLEARANCE_STEPS,
    FLOATING_OWNED_RHO,
    FLOATING_STEP_SIGMAS,
    floating_evidence,
)
from .gaps import local_gaps
from .grouping import MAX_NODES, STRENGTH_CLASSES
from .noise import (
    NOISE_MAX_BINS,
    NOISE_MAX_SAMPLES,
    NOISE_MIN_SAMPLES,
    QUANTIZED_ZERO_SHARE,
    NoiseProfile,
    _robust_sigma,
    _second_differences,
)
from .patches import PATCH_RHO, cut_off_patches_reference
from .residuals import FILL_MIN_NEIGHBOURS, _check_fill_args, _check_residual_args
from .union import SuspectResult


# the previous kernels, used only here (the fast path's are in zcut/edge_surface.py, zcut/suspects/residuals.py)
@numba.njit(cache=True)
def _patch_kernel(xyz, valid, r, min_px, reach, floor, cen, nrm, rms):  # type: ignore[no-untyped-def]  # numba kernel
    H, W = valid.shape
    for i in range(H):
        for j in range(W):
            rms[i, j] = np.nan
            if not valid[i, j]:
                continue
            zq = xyz[i, j, 2]
            n = 0
            sx = 0.0
            sy = 0.0
            sz = 0.0
            for a in range(max(i - r, 0), min(i + r + 1, H)):
                for b in range(max(j - r, 0), min(j + r + 1, W)):
                    if valid[a, b] and abs(xyz[a, b, 2] - zq) <= max(abs(a - i), abs(b - j)) * reach[i, j] + floor:
                        n += 1
                        sx += xyz[a, b, 0]
                        sy += xyz[a, b, 1]
                        sz += xyz[a, b, 2]
            if n < min_px:
                continue
            mx = sx / n
            my = sy / n
            mz = sz / n
            c00 = 0.0
            c01 = 0.0
            c02 = 0.0
            c11 = 0.0
            c12 = 0.0
            c22 = 0.0
            for a in range(max(i - r, 0), min(i + r + 1, H)):
                for b in range(max(j - r, 0), min(j + r + 1, W)):
                    if valid[a, b] and abs(xyz[a, b, 2] - zq) <= max(abs(a - i), abs(b - j)) * reach[i, j] + floor:
                        dx = xyz[a, b, 0] - mx
                        dy = xyz[a, b, 1] - my
                        dz = xyz[a, b, 2] - mz
                        c00 += dx * dx
                        c01 += dx * dy
                        c02 += dx * dz
                        c11 += dy * dy
                        c12 += dy * dz
                        c22 += dz * dz
            lam, nx, ny, nz = _smallest_eigvec(c00 / n, c01 / n, c02 / n, c11 / n, c12 / n, c22 / n)
            if not np.isfinite(nx):
                continue
            if nx * mx + ny * my + nz * mz > 0.0:  # face the camera at the origin
                nx, ny, nz = -nx, -ny, -nz
            cen[i, j, 0] = mx
            cen[i, j, 1] = my
            cen[i, j, 2] = mz
            nrm[i, j, 0] = nx
            nrm[i, j, 1] = ny
            nrm[i, j, 2] = nz
            rms[i, j] = math.sqrt(max(lam, 0.0))


@numba.njit(cache=True)
def _nearest_kernel(xyz, valid, surface, cen, nrm, r, radius, max_radius, out):  # type: ignore[no-untyped-def]  # numba kernel
    H, W = valid.shape
    for i in range(H):
        for j in range(W):
            out[i, j] = np.nan
            if not valid[i, j]:
                continue
            px = xyz[i, j, 0]
            py = xyz[i, j, 1]
            pz = xyz[i, j, 2]
            R = radius
            best = np.inf
            signed = np.inf
            while True:
                for a in range(max(i - R, 0), min(i + R + 1, H)):
                    for b in range(max(j - R, 0), min(j + R + 1, W)):
                        if abs(a - i) <= r and abs(b - j) <= r:
                            continue
                        if not surface[a, b]:
                            continue
                        d = (nrm[a, b, 0] * (px - cen[a, b, 0]) + nrm[a, b, 1] * (py - cen[a, b, 1])
                             + nrm[a, b, 2] * (pz - cen[a, b, 2]))
                        if abs(d) < best:
                            best = abs(d)
                            signed = d
                if best < np.inf or R >= max_radius:
                    break
                R = min(2 * R, max_radius)
            out[i, j] = signed


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


@numba.njit(cache=True)
def _residual_kernel_previous(h, judged, taus, jumps, min_below, codes, best):  # type: ignore[no-untyped-def]  # numba kernel
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


def _surface_residuals_previous(height: FloatImage, judged: Mask, *, tau: object, jump: object, min_below: int
                                ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`zcut.suspects.surface_residuals` as it was (its kernel without the interior path)."""
    h, judged, tau_a, jump_a, min_below = _check_residual_args(height, judged, tau, jump, min_below)
    codes = np.zeros(h.shape, np.uint8)
    best = np.empty(h.shape, np.float64)
    _residual_kernel_previous(h, judged, tau_a, jump_a, min_below, codes, best)
    return codes, best


def _signed_edge_distance_reference(xyz_mm: XYZ, valid: Mask, *, params: EdgeSurfaceParams | None = None
                                    ) -> np.ndarray:
    """:func:`zcut.edge_surface.signed_edge_distance` as it was (its numba kernels, whole frame)."""
    a, valid, params = _check_args(xyz_mm, valid, params)
    H, W = valid.shape
    cen = np.zeros((H, W, 3))
    nrm = np.zeros((H, W, 3))
    rms = np.empty((H, W))
    _patch_kernel(a, valid, params.patch_radius_px, params.min_patch_px, _reach(a, valid, params), params.side_step_mm,
                  cen, nrm, rms)
    surface = np.ascontiguousarray(_surfaces(rms, nrm, cen, params))
    out = np.empty((H, W))
    _nearest_kernel(a, valid, surface, cen, nrm, params.patch_radius_px, params.search_radius_px,
                    params.max_search_radius_px, out)
    return out


def _fill_blobs_previous(seed: Mask, judged: Mask, valid: Mask, *, iterations: int) -> Mask:
    """:func:`zcut.suspects.fill_blobs` as it was (its whole-frame rounds)."""
    seed, judged, valid, iterations = _check_fill_args(seed, judged, valid, iterations)
    filled: Mask = _fill_kernel(np.ascontiguousarray(seed), np.ascontiguousarray(judged), np.ascontiguousarray(valid),
                                iterations, FILL_MIN_NEIGHBOURS)
    return filled


def strength_classes_reference(primary: np.ndarray, strength: np.ndarray) -> np.ndarray:
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
        med = label_medians(s, lab, n)
        cls = np.searchsorted(np.asarray(STRENGTH_CLASSES), med, side="right").astype(np.int8)
        out[m] = cls[lab[m] - 1]
    return out


@numba.njit(cache=True)
def _local_height_kernel_previous(h, out):  # type: ignore[no-untyped-def]  # numba kernel
    H, W = h.shape
    v = np.empty(5)
    for i in range(H):
        for j in range(W):
            x = h[i, j]
            if not np.isfinite(x):
                out[i, j] = np.nan
                continue
            # the pixel, then its neighbours E, W, S, N (the previous code's order: a stable sort of
            # equal values keeps it)
            v[0] = x
            n = 1
            for k in range(4):
                i1 = i + (0, 0, 1, -1)[k]
                j1 = j + (1, -1, 0, 0)[k]
                if 0 <= i1 < H and 0 <= j1 < W:
                    y = h[i1, j1]
                    if np.isfinite(y):
                        m = n
                        while m > 0 and v[m - 1] > y:  # insertion: stable
                            v[m] = v[m - 1]
                            m -= 1
                        v[m] = y
                        n += 1
            lo = v[(n - 1) // 2]
            hi = v[n // 2]
            out[i, j] = lo if n % 2 == 1 else 0.5 * (lo + hi)


def local_height_reference(height: FloatImage) -> np.ndarray:
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


def noise_profile_reference(height: FloatImage, judged: Mask) -> NoiseProfile:
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


def _components_reference(m: np.ndarray, r: int) -> tuple[np.ndarray, int]:
    """8-connected components of ``m`` grown by ``r`` pixels (labels on ``m``'s pixels only, 1..n)."""
    grown = ndimage.maximum_filter(m.view(np.uint8), size=2 * r + 1, mode="constant") > 0 if r > 0 else m
    lab, n = ndimage.label(grown, structure=np.ones((3, 3), bool))
    lab = np.where(m, lab, 0)
    used = np.unique(lab[m])
    remap = np.zeros(n + 1, np.int32)
    remap[used] = np.arange(1, used.size + 1, dtype=np.int32)
    return remap[lab], int(used.size)


def _union_diagonals_reference(boxes: np.ndarray, i: int) -> np.ndarray:
    """Diagonal (pixels) of the bounding box of box ``i`` united with each box."""
    r0 = np.minimum(boxes[:, 0], boxes[i, 0])
    c0 = np.minimum(boxes[:, 1], boxes[i, 1])
    r1 = np.maximum(boxes[:, 2], boxes[i, 2])
    c1 = np.maximum(boxes[:, 3], boxes[i, 3])
    diagonal: np.ndarray = np.hypot((r1 - r0).astype(np.float64), (c1 - c0).astype(np.float64))
    return diagonal


def _merge_compact_reference(boxes: np.ndarray, kind: np.ndarray, max_groups: int) -> np.ndarray:
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
        d = _union_diagonals_reference(boxes, i)
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


def group_suspects_reference(codes: np.ndarray, strength: np.ndarray, params: SuspectParams
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
    cls = strength_classes_reference(primary, strength)
    n_cls = len(STRENGTH_CLASSES) + 1
    radii = np.full(len(DETECTORS), params.merge_radius_px, np.int64)
    limit = max(codes.shape)
    per = []
    fine = []
    for i in range(len(DETECTORS)):
        for c in range(n_cls):
            m = (primary == i) & (cls == c)
            r = int(params.merge_radius_px)
            lab, n = _components_reference(m, r)
            while n > MAX_NODES and r < limit:
                r = min(2 * r + 1, limit)
                lab, n = _components_reference(m, r)
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
    rep = _merge_compact_reference(boxes, kind, params.max_groups) if total > params.max_groups else np.arange(total)
    if np.unique(rep).size > params.max_groups:  # more detector-and-class kinds than groups: join classes
        heads = np.unique(rep)
        hb = np.array([[boxes[rep == h, 0].min(), boxes[rep == h, 1].min(), boxes[rep == h, 2].max(),
                        boxes[rep == h, 3].max()] for h in heads], np.int64)
        rep2 = _merge_compact_reference(hb, kind[heads] // n_cls, params.max_groups)
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


def floating_components_reference(height_mm: np.ndarray, zone: Mask, valid: Mask, rough: Mask, params: SuspectParams,
                        a_max: float, step: float, profile: NoiseProfile, *,
                        judged: np.ndarray | None = None) -> tuple[Mask, np.ndarray]:
    """The floating detector: z-cut components over the zone's whole height range (see module notes).

    Returns the mask and, on its pixels, their gap (mm) over the median height of the measured
    pixels bordering their component (NaN elsewhere, or when none borders it). ``judged``: when given, set to
    the pixels of the components the detector judges alone (those of its cut that clear everything around them and
    are smaller than FLOATING_OWNED_RHO · a_max).
    """
    if judged is not None:
        judged[...] = False
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
    if judged is not None:
        judged[...] = np.concatenate([[False], clear & (cut.areas < FLOATING_OWNED_RHO * a_max)])[lab] & zone
    if mask.any():
        kept = np.where(mask, lab, 0)
        border = ndimage.maximum_filter(kept, size=3, mode="constant")
        border = np.where((kept == 0) & valid & np.isfinite(height_mm), border, 0)  # measured, outside
        ring_h = label_medians(height_mm, border, cut.n_clusters)
        gap[mask] = hz[mask] - np.concatenate([[np.nan], ring_h])[kept[mask]]
    return mask, gap


def suspects_reference(
    xyz: XYZ,
    height_mm: FloatImage,
    zone: Mask,
    above_rim: Mask | None = None,
    *,
    params: SuspectParams,
    intrinsics: Intrinsics | None = None,
    edge_surface: EdgeSurfaceParams | None = None,
    patches: bool = True,
) -> SuspectResult:
    """The previous :func:`zcut.suspects.suspects` (same parameters, same result; the oracle)."""
    if not isinstance(params, SuspectParams):
        raise ParameterError(f"params must be a SuspectParams, got {type(params).__name__}")
    a = check_xyz(xyz)
    H, W = a.shape[:2]
    h_img = np.asarray(height_mm)
    if h_img.shape != (H, W) or h_img.dtype.kind != "f":
        raise InputShapeError(f"height_mm must be an (H, W) float array like xyz {(H, W)}, got {describe_array(h_img)}")
    zone = check_mask(zone, name="zone", shape=(H, W))
    easy = np.zeros((H, W), bool) if above_rim is None else check_mask(above_rim, name="above_rim", shape=(H, W))
    if edge_surface is not None and not isinstance(edge_surface, EdgeSurfaceParams):
        raise ParameterError(f"edge_surface must be an EdgeSurfaceParams or None, got {type(edge_surface).__name__}")
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

    profile = noise_profile_reference(context, zone)
    sigma_px = profile.sigma_at(local_height_reference(context))
    sigma = float(np.median(sigma_px[zone])) if zone.any() else 0.0
    tau = np.maximum(params.min_residual_mm, params.noise_k * sigma_px)
    jump = np.maximum(params.jump_mm, params.noise_k * sigma_px)
    step = max(params.floating_step_mm, FLOATING_STEP_SIGMAS * sigma)
    a_max = params.a_max if params.a_max is not None else max(0.01 * H * W, 1.0)

    codes, residual = _surface_residuals_previous(context, zone, tau=tau, jump=jump,
                                                  min_below=params.below_min_directions)
    off = codes > 0
    if params.fill_iterations > 0:
        filled = _fill_blobs_previous(off, zone, valid & ~easy, iterations=params.fill_iterations)
        codes[filled & ~off] = RESIDUAL_UP
    rough = zone & ~(np.abs(residual) <= tau)  # in the zone: inf (no continuation) is rough
    judged = np.zeros((H, W), bool)  # the components the floating detector judges: its own, not patches
    floating, floating_gap = floating_components_reference(h_zcut, zone, valid & ~easy, rough, params, a_max, step,
                                                           profile, judged=judged)
    codes[floating] |= FLOATING
    codes[easy] |= ABOVE_RIM
    if patches:
        codes[cut_off_patches_reference(context, jump, max_px=PATCH_RHO * a_max) & zone & ~judged] |= PATCH
    mask = codes > 0

    # gaps: a floating pixel's over the measured pixels bordering its component; a pixel off the
    # surface, its residual (to the nearest continuation) or, with edge_surface, its distance to the
    # nearest surface fitted on one side of an edge; a blob's or an above-rim pixel's, to the local
    # surface around it
    by_residual = off & ((codes & (FLOATING | ABOVE_RIM)) == 0) & np.isfinite(residual)
    by_border = floating & ~easy
    gap = local_gaps(np.where(valid, -1000.0 * a[..., 2].astype(np.float64), np.nan),
                     mask & ~by_residual & ~by_border, valid & ~mask)
    gap[by_residual] = residual[by_residual]
    gap[by_border] = floating_gap[by_border]
    surface_mm = None
    if edge_surface is not None:  # a pixel off the surface with a surface near: its distance to the nearest one
        surface_mm = _signed_edge_distance_reference(1000.0 * a.astype(np.float64), valid, params=edge_surface)
        near = by_residual & np.isfinite(surface_mm)
        gap[near] = surface_mm[near]
    tau_px = np.where(np.isfinite(tau) & (tau > 0), tau, params.min_residual_mm)
    groups, primary, radii = group_suspects_reference(codes, np.abs(gap) / tau_px, params)
    n = int(primary.size)
    size = np.bincount(groups.ravel(), minlength=n + 1)[1:].astype(np.int64)
    bits = np.zeros(n + 1, np.uint8)
    np.bitwise_or.at(bits, groups.ravel(), codes.ravel())
    bits = bits[1:]
    if n:
        g_gap = label_medians(gap, groups, n)
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
        noise_profile=profile, floating_step_mm=step, merge_radius_px=radii, _surface_mm=surface_mm,
    )
