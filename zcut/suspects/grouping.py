"""Grouping the suspects of one frame for review: per detector and strength class, by proximity, within
``SuspectParams.max_groups`` groups (:func:`group_suspects`; the page's share of the budget beside it is
:mod:`annotate.budget`).
"""

from __future__ import annotations

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


def _union_diagonals(boxes: np.ndarray, i: int) -> np.ndarray:
    """Diagonal (pixels) of the bounding box of box ``i`` united with each box."""
    r0 = np.minimum(boxes[:, 0], boxes[i, 0])
    c0 = np.minimum(boxes[:, 1], boxes[i, 1])
    r1 = np.maximum(boxes[:, 2], boxes[i, 2])
    c1 = np.maximum(boxes[:, 3], boxes[i, 3])
    diagonal: np.ndarray = np.hypot((r1 - r0).astype(np.float64), (c1 - c0).astype(np.float64))
    return diagonal


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
        med = label_medians(s, lab, n)
        cls = np.searchsorted(np.asarray(STRENGTH_CLASSES), med, side="right").astype(np.int8)
        out[m] = cls[lab[m] - 1]
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
