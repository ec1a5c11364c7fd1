"""The disagreement blobs as ``zcut compare`` found them before their nearest kept pixels were searched in
windows: each blob's nearest kept pixel from the Euclidean feature transform of the whole image.

A verbatim copy of ``studies.compare.disagreement_blobs`` and ``_nearest_kept`` at commit 9831702 (the
fast version must give the same blobs, to the bit: tests/studies/test_compare_blobs.py).
"""

from __future__ import annotations

import numpy as np

from studies.compare_records import Blob


def _nearest_kept(kept: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    from scipy import ndimage

    if not kept.any():
        return None
    ri, ci = ndimage.distance_transform_edt(~kept, return_distances=False, return_indices=True)
    return ri, ci


def disagreement_blobs(log: str, index: int, stamp_ns: int, mask_a: np.ndarray, mask_b: np.ndarray,
                       where: np.ndarray, *, truth: tuple[np.ndarray, np.ndarray] | None = None,
                       footprint: np.ndarray | None = None, xyz: np.ndarray | None = None) -> list[Blob]:
    from scipy import ndimage

    blobs: list[Blob] = []
    near = None
    if xyz is not None and ((mask_a ^ mask_b) & where).any():
        kept = where & ~mask_a & ~mask_b & np.isfinite(xyz).all(axis=2)
        near = _nearest_kept(kept)
    for who, m in (("A", mask_a & ~mask_b & where), ("B", mask_b & ~mask_a & where)):
        if not m.any():
            continue
        lab, n = ndimage.label(m, structure=np.ones((3, 3), dtype=bool))
        area = np.bincount(lab.ravel(), minlength=n + 1)[1:]
        rows, cols = np.nonzero(lab)
        ids = lab[rows, cols]
        r = np.bincount(ids, weights=rows, minlength=n + 1)[1:] / np.maximum(area, 1)
        c = np.bincount(ids, weights=cols, minlength=n + 1)[1:] / np.maximum(area, 1)
        mm2 = None
        if footprint is not None:
            fp = np.where(np.isfinite(footprint), footprint, 0.0)
            mm2 = np.bincount(ids, weights=fp[rows, cols], minlength=n + 1)[1:]
        if truth is not None:
            outl, scored = truth
            good = (outl if who == "B" else ~outl) & scored
            bad = (~outl if who == "B" else outl) & scored
            fixes = np.bincount(ids, weights=good[rows, cols], minlength=n + 1)[1:].astype(np.int64)
            breaks = np.bincount(ids, weights=bad[rows, cols], minlength=n + 1)[1:].astype(np.int64)
        height = part = None
        if near is not None and xyz is not None:
            p = 1000.0 * xyz[rows, cols].astype(np.float64)
            q = 1000.0 * xyz[near[0][rows, cols], near[1][rows, cols]].astype(np.float64)
            ok = np.isfinite(p).all(axis=1)
            h = np.where(ok, q[:, 2] - p[:, 2], 0.0)
            d = np.where(ok, np.linalg.norm(p - q, axis=1), np.inf)
            n_ok = np.bincount(ids, weights=ok, minlength=n + 1)[1:]
            height = np.bincount(ids, weights=h, minlength=n + 1)[1:] / np.maximum(n_ok, 1)
            height[n_ok == 0] = np.nan
            part = np.full(n + 1, np.inf)
            np.minimum.at(part, ids, d)
            part = part[1:]
        for k in range(n):
            fx = bk = 0
            consequence = None
            if truth is not None:
                fx, bk = int(fixes[k]), int(breaks[k])
                consequence = ("unscored" if fx + bk == 0 else "B fixes" if bk == 0 else "B breaks" if fx == 0
                               else "mixed")
            blobs.append(Blob(log, index, stamp_ns, who, int(area[k]),
                              None if mm2 is None else round(float(mm2[k]), 3), float(r[k]), float(c[k]), fx, bk,
                              consequence,
                              None if height is None or not np.isfinite(height[k]) else round(float(height[k]), 3),
                              None if part is None or not np.isfinite(part[k]) else round(float(part[k]), 3)))
    blobs.sort(key=lambda b: -b.area_px)
    return blobs
