"""The labelling page's budget of review groups: how many groups a frame may list, and how a share is kept.

A person decides one group at a time, so the page bounds what it lists (``docs/labelling.md``):

- the suspect groups (:func:`zcut.suspects.suspects`) are at most ``SuspectParams.max_groups`` (40);
  the detectors keep that share themselves (:mod:`zcut.suspects.grouping`), since the suspects'
  groups are part of their result;
- the pixels a filter method flags that no suspect group holds are at most :data:`METHOD_GROUPS_MAX`
  groups per method, shared among their strength classes (:func:`class_budgets`), each class's
  pixels merged by proximity until they fit (:func:`merged_components`).

A frame therefore lists at most :func:`review_budget` groups.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from zcut.params import SuspectParams

EIGHT = np.ones((3, 3), bool)
#: At most this many groups per method for the pixels a filter flags that no suspect group holds.
METHOD_GROUPS_MAX = 4


def review_budget(params: SuspectParams, n_methods: int) -> int:
    """The most review groups a frame may list: the suspects' ``max_groups`` and
    :data:`METHOD_GROUPS_MAX` for each of ``n_methods`` filter methods."""
    return int(params.max_groups) + METHOD_GROUPS_MAX * int(n_methods)


def merged_components(mask: np.ndarray, budget: int) -> tuple[np.ndarray, int]:
    """8-connected components of ``mask``, merged by proximity (components closer than ~2 r pixels join,
    r doubling from 1) until there are at most ``budget`` of them."""
    lab, n = ndimage.label(mask, structure=EIGHT)
    r = 1
    while n > budget:
        grown = cv2.dilate(mask.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_RECT, (2 * r + 1, 2 * r + 1)))
        big, n = ndimage.label(grown > 0, structure=EIGHT)
        lab = np.where(mask, big, 0)
        used = np.unique(lab[lab > 0])
        lut = np.zeros(int(big.max()) + 1, np.int64)
        lut[used] = np.arange(1, used.size + 1)
        lab, n = lut[lab], int(used.size)
        r *= 2
    return lab.astype(np.int32), int(n)


def class_budgets(cls: np.ndarray, total: int) -> list[tuple[int, int]]:
    """(class, groups it may have) for each strength class present in ``cls`` (-1 = none): one group
    each, the rest of ``total`` handed out in turn, the class with most pixels first."""
    counts = np.bincount(cls[cls >= 0].astype(np.int64))
    present = [int(c) for c in np.flatnonzero(counts)]
    budget = dict.fromkeys(present, 1)
    by_size = sorted(present, key=lambda c: (-counts[c], c))
    for k in range(max(total - len(present), 0) if present else 0):
        budget[by_size[k % len(by_size)]] += 1
    return [(c, budget[c]) for c in present]
