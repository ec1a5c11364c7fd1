"""Grouping the suspects of one frame for review: per detector and strength class, by proximity, within
``SuspectParams.max_groups`` groups (:func:`group_suspects`; the page's share of the budget beside it is
:mod:`annotate.budget`).
"""

from __future__ import annotations

import numba
import numpy as np
from scipy import ndimage

from ..params import SuspectParams
from .detectors import DETECTORS, label_medians

# grouping: a detector with more components than this is pre-merged with a larger radius first
MAX_NODES = 1500
# grouping: the bounds of a suspect's strength classes, in |gap| / τ (the median over its component):
# at the noise's edge (below 2 τ), clearly off the surface, far off it (8 τ and more). Suspects of
# different classes are not grouped together while the frame's group budget allows it.
STRENGTH_CLASSES = (2.0, 8.0)


def _components(m: np.ndarray, r: int) -> tuple[np.ndarray, int]:
    """8-connected components of ``m`` grown by ``r`` pixels (labels on ``m``'s pixels only, 1..n)."""
    grown = ndimage.maximum_filter(m.view(np.uint8), size=2 * r + 1, mode="constant") > 0 if r > 0 else m
    lab, n = ndimage.label(grown, structure=np.ones((3, 3), bool))
    lab = np.where(m, lab, 0)
    used = np.unique(lab[m])
    remap = np.zeros(n + 1, np.int32)
    remap[used] = np.arange(1, used.size + 1, dtype=np.int32)
    return remap[lab], int(used.size)


# the sparse components of a kind are found by linking its pixels directly up to this radius; beyond,
# by growing a cropped mask (_components) as before
SPARSE_MAX_RADIUS = 16


@numba.njit(cache=True)
def _sparse_components(flat, W, r, index):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_components` of the pixels ``flat`` (raster order, one kind) without growing a mask.

    Two pixels are in one component of the grown mask when a chain of them joins them, each within
    Chebyshev distance 2r + 1 of the next (their grown squares touch or overlap); ``ndimage.label``
    numbers the components by their first grown pixel in raster order: row max(top - r, 0), column
    max(c - r, 0) for c the leftmost column among the pixels whose square reaches that row.
    ``index`` is an (H, W) int32 image of -1, left so. Returns the label (1..n) of each pixel, n and
    the (n, 4) bounding boxes (row0, col0, row1, col1; ends exclusive) of the labels' pixels.
    """
    m = flat.size
    parent = np.arange(m)
    reach = 2 * r + 1
    for k in range(m):
        i = flat[k] // W
        j = flat[k] % W
        index[i, j] = k
    for k in range(m):
        i = flat[k] // W
        j = flat[k] % W
        for a in range(max(i - reach, 0), i + 1):
            b1 = min(j + reach + 1, W) if a < i else j
            for b in range(max(j - reach, 0), b1):
                q = index[a, b]
                if q >= 0:  # union: the smaller index is the root (a component's root is its first pixel)
                    x = k
                    while parent[x] != x:
                        parent[x] = parent[parent[x]]
                        x = parent[x]
                    y = q
                    while parent[y] != y:
                        parent[y] = parent[parent[y]]
                        y = parent[y]
                    if x < y:
                        parent[y] = x
                    elif y < x:
                        parent[x] = y
    for k in range(m):
        index[flat[k] // W, flat[k] % W] = -1
    root = np.empty(m, np.int64)
    for k in range(m):
        x = k
        while parent[x] != x:
            x = parent[x]
        root[k] = x
    # pixels in raster order: a root is its component's first pixel, so its row is the top one
    top_row = np.empty(m, np.int64)
    for k in range(m):
        top_row[k] = flat[root[k]] // W
    left = np.full(m, np.iinfo(np.int64).max)
    for k in range(m):
        i = flat[k] // W
        x = root[k]
        r0 = max(top_row[k] - r, 0)
        if i <= r0 + r:
            left[x] = min(left[x], flat[k] % W)
    roots = np.empty(m, np.int64)
    n = 0
    for k in range(m):
        if root[k] == k:
            roots[n] = k
            n += 1
    roots = roots[:n]
    key = np.empty(n, np.int64)
    for g in range(n):
        x = roots[g]
        key[g] = max(flat[x] // W - r, 0) * (W + 1) + max(left[x] - r, 0)
    order = np.argsort(key)
    rank = np.empty(m, np.int64)
    for g in range(n):
        rank[roots[order[g]]] = g + 1
    labels = np.empty(m, np.int64)
    boxes = np.empty((n, 4), np.int64)
    boxes[:, 0] = np.iinfo(np.int64).max
    boxes[:, 1] = np.iinfo(np.int64).max
    boxes[:, 2] = -1
    boxes[:, 3] = -1
    for k in range(m):
        g = rank[root[k]]
        labels[k] = g
        i = flat[k] // W
        j = flat[k] % W
        boxes[g - 1, 0] = min(boxes[g - 1, 0], i)
        boxes[g - 1, 1] = min(boxes[g - 1, 1], j)
        boxes[g - 1, 2] = max(boxes[g - 1, 2], i + 1)
        boxes[g - 1, 3] = max(boxes[g - 1, 3], j + 1)
    return labels, n, boxes


def _kind_components(flat: np.ndarray, shape: tuple[int, int], r: int, index: np.ndarray
                     ) -> tuple[np.ndarray, int, np.ndarray]:
    """Labels (1..n, per pixel of ``flat``), n and bounding boxes of :func:`_components` of the
    pixels ``flat`` (flat indices in raster order)."""
    if flat.size == 0:
        return np.zeros(0, np.int64), 0, np.zeros((0, 4), np.int64)
    if r <= SPARSE_MAX_RADIUS:
        labels, n, boxes = _sparse_components(flat, shape[1], r, index)
        return labels, int(n), boxes
    rows, cols = np.divmod(flat, shape[1])
    r0, r1 = max(int(rows.min()) - r, 0), min(int(rows.max()) + r + 1, shape[0])
    c0, c1 = max(int(cols.min()) - r, 0), min(int(cols.max()) + r + 1, shape[1])
    m = np.zeros((r1 - r0, c1 - c0), bool)  # the crop that holds the grown mask
    m[rows - r0, cols - c0] = True
    lab, n = _components(m, r)
    boxes = np.array([[s[0].start + r0, s[1].start + c0, s[0].stop + r0, s[1].stop + c0]
                      for s in ndimage.find_objects(lab, max_label=n)], np.int64).reshape(-1, 4)
    return lab[rows - r0, cols - c0].astype(np.int64), n, boxes


@numba.njit(cache=True)
def _merge_kernel(boxes, kind, max_groups):  # type: ignore[no-untyped-def]  # numba kernel
    """:func:`_merge_compact` (see there); distances compared as squared integer diagonals, whose
    order is the order of their square roots (the previous code's ``np.hypot``), and each box only
    with the boxes of its kind (in increasing index: the lowest index on ties, as ``np.argmin``)."""
    n = boxes.shape[0]
    rep = np.arange(n)
    alive = np.ones(n, np.bool_)
    inf = np.iinfo(np.int64).max
    best = np.full(n, inf)
    partner = np.zeros(n, np.int64)  # a box with no partner: 0, as np.argmin of a row of inf
    r0 = boxes[:, 0].copy()
    c0 = boxes[:, 1].copy()
    r1 = boxes[:, 2].copy()
    c1 = boxes[:, 3].copy()
    by_kind = np.argsort(kind, kind="mergesort")  # each kind's boxes in increasing index
    start = np.zeros(n, np.int64)  # of each box's kind in by_kind
    stop = np.zeros(n, np.int64)
    s = 0
    while s < n:
        e = s
        while e < n and kind[by_kind[e]] == kind[by_kind[s]]:
            e += 1
        for q in range(s, e):
            start[by_kind[q]] = s
            stop[by_kind[q]] = e
        s = e

    def refresh(i):  # type: ignore[no-untyped-def]
        b = inf
        bj = 0
        for q in range(start[i], stop[i]):
            k = by_kind[q]
            if k == i or not alive[k]:
                continue
            dr = max(r1[k], r1[i]) - min(r0[k], r0[i])
            dc = max(c1[k], c1[i]) - min(c0[k], c0[i])
            d = dr * dr + dc * dc
            if d < b:
                b = d
                bj = k
        best[i] = b
        partner[i] = bj

    for i in range(n):
        refresh(i)  # type: ignore[no-untyped-call]  # numba closure
    count = n
    while count > max_groups:
        i = 0
        for k in range(1, n):
            if best[k] < best[i]:
                i = k
        if best[i] == inf:
            break  # one group per kind left
        j = partner[i]
        a = min(i, j)
        b = max(i, j)
        r0[a] = min(r0[a], r0[b])
        c0[a] = min(c0[a], c0[b])
        r1[a] = max(r1[a], r1[b])
        c1[a] = max(c1[a], c1[b])
        alive[b] = False
        best[b] = inf
        for k in range(n):
            if rep[k] == b:
                rep[k] = a
        count -= 1
        for q in range(start[a], stop[a]):
            k = by_kind[q]
            if k == a or not alive[k]:
                continue
            dr = max(r1[k], r1[a]) - min(r0[k], r0[a])
            dc = max(c1[k], c1[a]) - min(c0[k], c0[a])
            d = dr * dr + dc * dc
            if d < best[k]:
                best[k] = d
                partner[k] = a
        # the boxes whose partner was a or b (boxes of other kinds keep theirs: their rows did not change)
        for q in range(start[a], stop[a]):
            k = by_kind[q]
            if alive[k] and (partner[k] == a or partner[k] == b):
                refresh(k)  # type: ignore[no-untyped-call]  # numba closure
        refresh(a)  # type: ignore[no-untyped-call]  # numba closure
    return rep


def _merge_compact(boxes: np.ndarray, kind: np.ndarray, max_groups: int) -> np.ndarray:
    """Agglomerate boxes into at most ``max_groups`` groups, never across kinds: repeatedly merge the
    pair whose united bounding box has the smallest diagonal (lowest indices on ties).

    Returns the group of each box as the index of its representative box.
    """
    rep: np.ndarray = _merge_kernel(np.ascontiguousarray(boxes, dtype=np.int64),
                                    np.ascontiguousarray(kind, dtype=np.int64), int(max_groups))
    return rep


def strength_classes(primary: np.ndarray, strength: np.ndarray, *, _index: np.ndarray | None = None) -> np.ndarray:
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
    primary = np.asarray(primary)
    out = np.full(primary.shape, -1, np.int8)
    flat_p = primary.reshape(-1)
    sus = np.flatnonzero(flat_p >= 0)
    if sus.size == 0:
        return out
    det = flat_p[sus]
    by_det = np.argsort(det, kind="stable")  # each detector's pixels in raster order
    ends = np.searchsorted(det[by_det], np.arange(len(DETECTORS) + 1), side="left")
    s = np.asarray(strength, np.float64).reshape(-1)[sus]
    s = np.where(np.isfinite(s), s, np.inf)
    index = np.full(primary.shape, -1, np.int32) if _index is None else _index
    flat_out = out.reshape(-1)
    for i in range(len(DETECTORS)):
        sel = by_det[ends[i]:ends[i + 1]]
        if sel.size == 0:
            continue
        lab, n, _ = _kind_components(sus[sel], primary.shape, 0, index)  # ndimage.label's 8-connected components
        med = label_medians(s[sel], lab, n)
        cls = np.searchsorted(np.asarray(STRENGTH_CLASSES), med, side="right").astype(np.int8)
        flat_out[sus[sel]] = cls[lab - 1]
    return out


def group_suspects(codes: np.ndarray, strength: np.ndarray, params: SuspectParams
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
    index = np.full(codes.shape, -1, np.int32)  # the components' work image, left all -1 by each use
    cls = strength_classes(primary, strength, _index=index)
    n_cls = len(STRENGTH_CLASSES) + 1
    radii = np.full(len(DETECTORS), params.merge_radius_px, np.int64)
    limit = max(codes.shape)
    # the suspects' flat indices by detector and class, each in raster order
    sus = np.flatnonzero(primary.ravel() >= 0)
    fine_of = primary.ravel()[sus].astype(np.int64) * n_cls + cls.ravel()[sus]
    by_kind = np.argsort(fine_of, kind="stable")
    ends = np.searchsorted(fine_of[by_kind], np.arange(len(DETECTORS) * n_cls + 1), side="left")
    per = []
    fine = []
    for i in range(len(DETECTORS)):
        for c in range(n_cls):
            f = i * n_cls + c
            flat = sus[by_kind[ends[f]:ends[f + 1]]]
            r = int(params.merge_radius_px)
            lab, n, bx = _kind_components(flat, codes.shape, r, index)
            while n > MAX_NODES and r < limit:
                r = min(2 * r + 1, limit)
                lab, n, bx = _kind_components(flat, codes.shape, r, index)
            radii[i] = max(radii[i], r)
            per.append((flat, lab, n, bx))
            fine.append(f)
    offsets = np.cumsum([0] + [n for _, _, n, _ in per])
    total = int(offsets[-1])
    boxes = np.zeros((total, 4), np.int64)
    kind = np.zeros(total, np.int64)
    for i, (_, _, n, bx) in enumerate(per):
        if n:
            boxes[offsets[i]:offsets[i + 1]] = bx
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
    flat_groups = groups.reshape(-1)
    for i, (flat, lab, n, _) in enumerate(per):
        if n:
            flat_groups[flat] = node_group[lab + offsets[i]]
    return groups, kinds, radii
