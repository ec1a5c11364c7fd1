"""Review groups: what the labelling page asks a person to accept or reject, one decision per group.

A person cannot judge a 1920 x 1200 frame pixel by pixel, and the filters' own clusters miss most of
what a person must judge (flying pixels along occlusion edges, ghosts larger than μ_thr, spikes away
from the camera). The page therefore proposes *groups* (``docs/labelling.md``):

- the suspect groups of :func:`zcut.suspects.suspects` — filter-independent detectors (surface
  residuals up and down, mixed pixels, floating components of any depth, points above the rim, and
  without a part model patches cut off by depth steps), grouped by detector and merged until a frame has
  at most ``SuspectParams.max_groups`` (40) of them;
- for every filter method the replay ran (``zcut``, ``sor``, the bank), the pixels it flags that no
  suspect group holds, grouped by strength class (:func:`zcut.suspects.strength_classes`, with the
  frame's τ) and proximity into at most :data:`~annotate.budget.METHOD_GROUPS_MAX` groups per method
  (a filter's proposal is never hidden, but it never floods the list either, and the few pixels it
  flags far off the surface are not decided with its thousands at the noise's edge). The page's
  budget, both shares, is :mod:`annotate.budget`.

Every group carries why it is a suspect: the detector (or method) it was grouped by, every detector
and method that flags any of its pixels, its size, its gap to the local surface in mm (positive:
toward the camera) and its score. :func:`review_groups` computes them and the per-group features
the assistant learns from (:data:`FEATURES`, :mod:`annotate.assistant`), from the frame and its
pipeline result alone.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from annotate.budget import METHOD_GROUPS_MAX, class_budgets, merged_components
from zcut.edge_surface import EdgeSurfaceParams
from zcut.params import SuspectParams
from zcut.suspects import DETECTORS, local_gaps, strength_classes, suspects

#: Methods whose share of a group's pixels is a feature (the others are in the table's method bits).
FEATURE_METHODS = ("zcut", "sor")
#: The gap below which a group is shown as "on the surface" (|gap| under this many mm).
#: Columns of the group table (float32), in the bundle's ``groups`` section:
#: ``id`` (its value in the ``group_ids`` image), ``n`` pixels, box ``x0 y0 x1 y1`` (ends exclusive),
#: centroid ``cx cy``, ``gap_mm`` (median gap of its pixels to the local surface; NaN when unknown),
#: ``h_min_mm h_max_mm``, ``source`` (index into the header's ``group_sources``: the detector or
#: method it was grouped by), ``detectors`` (bits of :data:`zcut.suspects.DETECTORS` flagging any
#: pixel), ``methods`` (bits of the header's ``methods`` flagging any pixel), ``score``.
GROUP_COLUMNS = ("id", "n", "x0", "y0", "x1", "y1", "cx", "cy", "gap_mm", "h_min_mm", "h_max_mm", "source",
                 "detectors", "methods", "score")
GCOL = {name: i for i, name in enumerate(GROUP_COLUMNS)}
#: The assistant's per-group features (:mod:`annotate.assistant`), in this order.
FEATURES = (
    "log_size", "gap_mm", "abs_gap_mm", "gap_over_tau", "extent_mm", "resid_med_mm", "resid_off_frac",
    *(f"det_{d}" for d in DETECTORS), "primary", *(f"method_{m}" for m in FEATURE_METHODS),
    "edge_px", "ring_std_mm", "gray", "gray_contrast", "fill", "aspect", "above_rim_frac", "noise_mm", "tau_mm",
)


@dataclass(frozen=True, slots=True)
class ReviewGroups:
    """The review groups of one frame.

    Attributes
    ----------
    ids : (H, W) int32 ndarray
        0 = no group, g = group g (1-based; suspect groups first, by decreasing score).
    table : (n, len(GROUP_COLUMNS)) float64 ndarray
        One row per group (:data:`GROUP_COLUMNS`).
    features : (n, len(FEATURES)) float32 ndarray
        The assistant's features of each group (:data:`FEATURES`).
    sources : tuple of str
        What the ``source`` column indexes: :data:`zcut.suspects.DETECTORS`, then the methods.
    methods : tuple of str
        The methods whose bits the ``methods`` column holds.
    rise_mm : (H, W) float32 ndarray
        How far each judged pixel stands above the surface around it (mm; 0 where it does not): a
        group pixel's gap to the local surface, elsewhere its positive surface residual. What the
        height-gap wand and the residual brush select by.
    noise_mm, threshold_mm : float
        The frame's noise σ̂ and the suspects' residual threshold τ (mm).
    n_suspect_px : int
        Pixels the suspect detectors flagged.
    """

    ids: np.ndarray
    table: np.ndarray
    features: np.ndarray
    sources: tuple[str, ...]
    methods: tuple[str, ...]
    rise_mm: np.ndarray
    noise_mm: float
    threshold_mm: float
    n_suspect_px: int

    @property
    def n(self) -> int:
        return int(self.table.shape[0])

    def pixels(self) -> tuple[np.ndarray, np.ndarray]:
        """(flat pixel indices grouped by group, (n + 1,) starts): group g owns ``pix[starts[g-1]:starts[g]]``."""
        flat = self.ids.ravel()
        pix = np.flatnonzero(flat)
        lab = flat[pix].astype(np.int64)
        order = np.argsort(lab, kind="stable")
        counts = np.bincount(lab, minlength=self.n + 1)[1:]
        return pix[order].astype(np.int64), np.concatenate(([0], np.cumsum(counts))).astype(np.int64)


def group_targets(pixels: np.ndarray, starts: np.ndarray, outliers: np.ndarray, reviewed: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Per group: (decided, share of its pixels labelled outliers) under a label (L, R).

    A group is decided when at least half of its pixels are reviewed.

    Parameters
    ----------
    pixels, starts : (k,) and (n + 1,) int ndarray
        The groups' flat pixel indices, grouped (:meth:`ReviewGroups.pixels`).
    outliers, reviewed : (H, W) bool ndarray

    Returns
    -------
    decided : (n,) bool ndarray
    outlier_share : (n,) float64 ndarray
    """
    n = starts.size - 1
    if n <= 0:
        return np.zeros(0, bool), np.zeros(0)
    seg = np.repeat(np.arange(n), np.diff(starts))
    size = np.maximum(np.diff(starts), 1)
    in_r = np.bincount(seg, weights=reviewed.ravel()[pixels], minlength=n)
    in_l = np.bincount(seg, weights=outliers.ravel()[pixels], minlength=n)
    return 2 * in_r >= size, in_l / size


def _per_group(values: np.ndarray, ids: np.ndarray, n: int, fn: Callable[[np.ndarray], object]) -> np.ndarray:
    """``fn`` of the finite values of each group 1..n (NaN where a group has none)."""
    out = np.full(n, np.nan)
    sel = (ids > 0) & np.isfinite(values)
    if not sel.any():
        return out
    g, v = ids[sel], values[sel]
    order = np.argsort(g, kind="stable")
    g, v = g[order], v[order]
    bounds = np.searchsorted(g, np.arange(1, n + 2))
    for k in range(n):
        if bounds[k + 1] > bounds[k]:
            out[k] = fn(v[bounds[k]:bounds[k + 1]])
    return out


#: The sources of the groups of a disagreement (``review_groups(focus=...)``): the pixels only A removed,
#: only B removed (codes 1 and 2 of ``focus``, annotate/disagreement.py).
FOCUS_SOURCES = ("removed only by A", "removed only by B")


def review_groups(xyz: np.ndarray, rgb: np.ndarray | None, *, height_mm: np.ndarray, valid: np.ndarray,
                  zone: np.ndarray, above_rim: np.ndarray, outliers: dict[str, np.ndarray],
                  params: SuspectParams, focus: np.ndarray | None = None, fits: bool = False) -> ReviewGroups:
    """The review groups of a frame and their features.

    Parameters
    ----------
    xyz : (H, W, 3) float ndarray
        The frame's points (metres, camera frame, NaN where unmeasured).
    rgb : (H, W, 3) uint8 ndarray or None
        Its colour image (intensity features; NaN features without one).
    height_mm : (H, W) float ndarray
        The height image the pipeline gave the z-cut.
    valid, zone, above_rim : (H, W) bool ndarray
        Measured pixels, the pixels the filters judge, the points above the rim.
    outliers : dict of str to (H, W) bool ndarray
        Every base method's outliers (``FrameResult.outliers``).
    params : SuspectParams
    focus : (H, W) uint8 ndarray, optional
        Review only these pixels (``zcut annotate --disagreement``: 1 where only A removed a pixel, 2
        where only B did): the groups are their components by code, merged by proximity to at most
        half of ``params.max_groups`` each (sources :data:`FOCUS_SOURCES`), and nothing else.
    fits : bool
        The page fits a part model to this frame (``zcut annotate`` with a part model: the config's
        ``explained.part_model`` or the log's ``part_model.ply``, :func:`annotate.fits.fitter_for`). Its
        proposals then come from the fits, and the suspects' patch detector, built for the page without a
        part model (real scans, stereo scenes, docs/labelling_real.md), does not run: no review group is a
        patch. False (the default): every detector runs.

    Returns
    -------
    ReviewGroups
    """
    H, W = valid.shape
    # the suspects' gaps on one side of an edge: a part's real edge is on the surface (docs/labelling.md)
    res = suspects(xyz, height_mm, zone, above_rim, params=params, edge_surface=EdgeSurfaceParams(),
                   patches=not fits)
    res.release()  # surface_mm is not read here: its frame in mm goes to the next call (SuspectResult.release)
    ids = res.groups.astype(np.int32).copy()
    methods = tuple(outliers)
    sources = tuple(DETECTORS) + methods
    primary = [int(p) for p in res.group_primary]
    judged = (zone | above_rim) & valid
    h_all = np.where(valid, -1000.0 * np.asarray(xyz[..., 2], np.float64), np.nan)
    gap = np.asarray(res.gap_mm, np.float64).copy()
    taken = ids > 0
    tau = float(res.threshold_mm) if np.isfinite(res.threshold_mm) and res.threshold_mm > 0 else 1.0
    if focus is not None:  # only the pixels asked for, grouped by who removed them
        sources += FOCUS_SOURCES
        ids[:] = 0
        primary = []
        asked = (focus > 0) & valid
        gap_f = local_gaps(h_all, asked, valid & ~asked)
        gap = np.where(asked, gap_f, np.nan)
        for k in range(len(FOCUS_SOURCES)):
            lab, n = merged_components(asked & (focus == k + 1), max(int(params.max_groups) // 2, 1))
            ids = np.where(lab > 0, lab + ids.max(), ids)
            primary += [len(DETECTORS) + len(methods) + k] * n
        taken = asked
    for j, name in enumerate(methods if focus is None else ()):
        rest = np.asarray(outliers[name], bool) & judged & ~taken
        if not rest.any():
            continue
        gap_m = local_gaps(h_all, rest, valid & ~rest & ~taken)
        cls = strength_classes(np.where(rest, 0, -1).astype(np.int8), np.abs(gap_m) / tau)
        for c, budget in class_budgets(cls, METHOD_GROUPS_MAX):
            lab, n = merged_components(rest & (cls == c), budget)
            ids = np.where(lab > 0, lab + ids.max(), ids)
            primary += [len(DETECTORS) + j] * n
        gap[rest] = gap_m[rest]
        taken |= rest
    n = int(ids.max())
    table = np.zeros((n, len(GROUP_COLUMNS)))
    features = np.full((n, len(FEATURES)), np.nan, np.float32)
    resid = np.asarray(res.residual_mm, np.float64)
    rise = np.where(judged & np.isfinite(resid) & (resid > 0), resid, 0.0)
    in_group = (ids > 0) & np.isfinite(gap)
    rise = np.where(in_group, np.maximum(gap, 0.0), rise).astype(np.float32)
    if n == 0:
        return ReviewGroups(ids, table, features, sources, methods, rise, float(res.noise_mm),
                            float(res.threshold_mm), int(res.mask.sum()))
    flat = ids.ravel()
    pix = np.flatnonzero(flat)
    lab = flat[pix].astype(np.int64)
    ys, xs = np.divmod(pix, W)
    cnt = np.bincount(lab, minlength=n + 1)[1:].astype(np.float64)
    safe = np.maximum(cnt, 1)
    x0 = np.full(n + 1, W)
    y0 = np.full(n + 1, H)
    x1 = np.zeros(n + 1, np.int64)
    y1 = np.zeros(n + 1, np.int64)
    np.minimum.at(x0, lab, xs)
    np.minimum.at(y0, lab, ys)
    np.maximum.at(x1, lab, xs)
    np.maximum.at(y1, lab, ys)
    x0, y0, x1, y1 = x0[1:], y0[1:], x1[1:] + 1, y1[1:] + 1
    g_gap = _per_group(gap, ids, n, np.median)
    h_min = _per_group(h_all, ids, n, np.min)
    h_max = _per_group(h_all, ids, n, np.max)
    det_bits = np.zeros(n + 1, np.int64)
    np.bitwise_or.at(det_bits, lab, res.detectors.ravel()[pix].astype(np.int64))
    meth_bits = np.zeros(n + 1, np.int64)
    meth_frac = {}
    for j, name in enumerate(methods):
        m = np.asarray(outliers[name], bool).ravel()[pix]
        np.bitwise_or.at(meth_bits, lab, (m.astype(np.int64) << j))
        meth_frac[name] = np.bincount(lab, weights=m, minlength=n + 1)[1:] / safe
    score = np.sqrt(cnt) * np.nan_to_num(np.abs(g_gap), nan=0.0)
    table[:, GCOL["id"]] = np.arange(1, n + 1)
    table[:, GCOL["n"]] = cnt
    table[:, GCOL["x0"]], table[:, GCOL["y0"]], table[:, GCOL["x1"]], table[:, GCOL["y1"]] = x0, y0, x1, y1
    table[:, GCOL["cx"]] = np.bincount(lab, weights=xs + 0.5, minlength=n + 1)[1:] / safe
    table[:, GCOL["cy"]] = np.bincount(lab, weights=ys + 0.5, minlength=n + 1)[1:] / safe
    table[:, GCOL["gap_mm"]] = g_gap
    table[:, GCOL["h_min_mm"]], table[:, GCOL["h_max_mm"]] = h_min, h_max
    table[:, GCOL["source"]] = primary
    table[:, GCOL["detectors"]] = det_bits[1:]
    table[:, GCOL["methods"]] = meth_bits[1:]
    table[:, GCOL["score"]] = score

    # ---- the assistant's features
    f = {name: np.full(n, np.nan) for name in FEATURES}
    f["log_size"] = np.log1p(cnt)
    f["gap_mm"] = g_gap
    f["abs_gap_mm"] = np.abs(g_gap)
    f["gap_over_tau"] = g_gap / tau
    f["extent_mm"] = h_max - h_min
    absr = np.where(np.isfinite(resid), np.abs(resid), np.nan)
    f["resid_med_mm"] = _per_group(np.minimum(absr, 1e3), ids, n, np.median)
    off = (absr > tau).ravel()[pix]
    f["resid_off_frac"] = np.bincount(lab, weights=off, minlength=n + 1)[1:] / safe
    dets = res.detectors.ravel()[pix].astype(np.int64)
    for i, d in enumerate(DETECTORS):
        f[f"det_{d}"] = np.bincount(lab, weights=(dets >> i) & 1, minlength=n + 1)[1:] / safe
    f["primary"] = np.asarray(primary, np.float64)
    for name in FEATURE_METHODS:
        if name in meth_frac:
            f[f"method_{name}"] = meth_frac[name]
    # distance to the nearest unmeasured pixel (occlusion edges, shadows)
    edge = cv2.distanceTransform(valid.astype(np.uint8), cv2.DIST_L2, 3)
    f["edge_px"] = _per_group(edge.astype(np.float64), ids, n, np.median)
    gray = None
    if rgb is not None and rgb.shape[:2] == (H, W):
        gray = cv2.cvtColor(np.ascontiguousarray(rgb, np.uint8), cv2.COLOR_RGB2GRAY).astype(np.float64)
        f["gray"] = np.bincount(lab, weights=gray.ravel()[pix], minlength=n + 1)[1:] / safe
    for k in range(n):  # the ring around each group: local roughness and contrast
        r0, c0 = max(int(y0[k]) - 3, 0), max(int(x0[k]) - 3, 0)
        r1, c1 = min(int(y1[k]) + 3, H), min(int(x1[k]) + 3, W)
        ring = valid[r0:r1, c0:c1] & (ids[r0:r1, c0:c1] != k + 1)
        if ring.sum() >= 3:
            f["ring_std_mm"][k] = float(np.std(h_all[r0:r1, c0:c1][ring]))
            if gray is not None:
                f["gray_contrast"][k] = f["gray"][k] - float(np.mean(gray[r0:r1, c0:c1][ring]))
    box = (x1 - x0) * (y1 - y0)
    f["fill"] = cnt / np.maximum(box, 1)
    f["aspect"] = np.maximum(x1 - x0, y1 - y0) / np.maximum(np.minimum(x1 - x0, y1 - y0), 1)
    f["above_rim_frac"] = np.bincount(lab, weights=above_rim.ravel()[pix], minlength=n + 1)[1:] / safe
    f["noise_mm"] = np.full(n, float(res.noise_mm))
    f["tau_mm"] = np.full(n, tau)
    features = np.stack([np.asarray(f[name], np.float64) for name in FEATURES], axis=1).astype(np.float32)
    return ReviewGroups(ids, table, features, sources, methods, rise, float(res.noise_mm), float(res.threshold_mm),
                        int(res.mask.sum()))
