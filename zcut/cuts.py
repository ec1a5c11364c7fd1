"""The z-cut outlier filter (paper Section 3, Figure 7; contract in docs/filters.md).

Two implementations with the identical result for every input:

- :func:`zcut_outliers_reference` is the literal loop of the paper: one connected-components
  labelling (``scipy.ndimage.label``) per level, comparing the components of the cuts at levels
  ``k`` and ``k + 1``. It is the oracle of the tests.
- :func:`zcut_outliers` builds the component tree of all the cuts at once, over the quantized level
  ``q`` of every pixel (the smallest ``k`` with the pixel inside the cut at level ``k``). A
  component that neither gains a pixel nor merges between levels ``k`` and ``k + 1`` is exactly a
  pair of identical clusters of the paper. Two numba kernels build the same tree: a flood with a
  bucket queue over the levels (Nistér & Stewénius, "Linear time maximally stable extremal
  regions", ECCV 2008; linear, cache-friendly; used below ``FLOOD_MAX_LEVELS`` (32768) levels, i.e. any
  practical ``max_depth / step`` and every level count :func:`find_clusters` takes) and, beyond, a
  union-find over the pixels sorted by level (:mod:`zcut.cut_tree` holds the kernels). When every pixel
  of the frame is in the cuts (the suspects' floating detector cuts the zone's whole height range), the
  flood leaves the deepest level out (:func:`zcut.cut_tree.flood_whole`: one component, the root).

:func:`find_clusters` runs the same pass and returns the stage view (:class:`CutResult`): the
clusters, their areas and levels, and the component count of every cut. Its ``kernel`` argument
picks the tree kernel explicitly (the tests run every input through both). One tree answers every
``(max_depth, max_area)`` pair at once: :mod:`zcut.cut_grid` (masks and counts). :class:`StageTree` and
:func:`find_clusters_many` answer :func:`find_clusters` itself, bit for bit, for every parameter set of
the same ``step``, ``K`` and ``connectivity`` from one flood tree (``max_area`` only re-tags its nodes,
``a_max`` only scales ``rho``): ``zcut compare`` uses it when A's and B's z-cuts differ only there.

Notation (docs/filters.md): ``z~`` is the height with invalid pixels set to ``z_min``; the cut at level
``k`` is ``S_k = {z~ >= z_max - k * step}`` with the threshold computed in float64 with an integer
``k``; ``K = floor(max_depth / step + 1e-9)``. The thresholds never increase with ``k`` (float
rounding is monotone), so the cuts are nested and a pixel is in ``S_k`` iff ``q <= k``.

The tree: a node is a component of the cut at the level ``b`` where it last changed (a pixel
joined or two components merged); it lives unchanged until the level ``e`` where it next changes
(``e = K + 2`` if never up to ``K + 1``) and becomes part of its parent node, born at ``e``.
The loop of docs/filters.md tags it iff it is a component of both ``S_k`` and ``S_{k+1}`` for some
``1 <= k <= K``, i.e. iff ``max(b, 1) <= min(K, e - 2)``, and it has fewer than ``max_area``
pixels. A pixel is an outlier iff some node holding it is tagged (and it is valid). ``q`` is
found from the guess ``floor((z_max - z~) * (1 / step))`` corrected with the exact comparisons.
With ``Q`` the level of ``z_min`` (the deepest level of any pixel), every level
past ``Q + 1`` changes nothing and ``K`` can be replaced by ``min(K, Q + 1)``: huge ``max_depth /
step`` ratios cost nothing.

:func:`zcut_outliers` floods only the pixels that can be outliers. Two neighbours in the cuts whose
levels differ by at most 1 are joined by a *gentle* edge. A tagged node C is a component of two
cuts ``k, k + 1``: every neighbour of C lies at level ``k + 2`` or deeper, so no gentle edge leaves
C, and C is a union of whole gentle components, each smaller than ``max_area``. The level pass
labels the gentle components (:func:`zcut.cut_tree.gentle_levels`), the pixels of those with
``max_area`` pixels or more are left out (:func:`zcut.cut_tree.gentle_prune`), and the flood over
the rest treats a node that touches a left-out pixel of level ``l`` as ending at ``l`` (it is not
a component of the cut at ``l``). Its tagged nodes are the whole tree's, as pixel sets: each
tagged node of the whole tree is a component of the same two cuts among the kept pixels, and a
kept node tagged with the left-out neighbours' levels accounted for is a component of the same two
whole cuts. The left-out pixels were 86 % of the pile's pixels in the cuts and 95 % of the dense
frame's (docs/performance.md). The labelling costs about half of what the flood costs a pixel,
so it is skipped where it cannot pay: with fewer than ``PRUNE_MIN`` pixels in the cuts, and, after
the first ``PRUNE_CHECK`` pixels (``PRUNE_CHECK_ROWS`` rows' worth) when fewer than half of them
lie in large gentle components (quantised depths: the real Kinect clouds at Δd 0.2 mm keep 69–100
% of their pixels), it labels no further and the flood visits every pixel, as before.

The prune then leaves out more by the same argument (:func:`zcut.cut_tree.gentle_prune`): every
neighbour of a pixel p of a tagged node C whose level is at most ``level(p) + 1`` lies in C (C's
outer neighbours are at ``k + 2`` or deeper), so a kept pixel with a left-out neighbour of such a
level is in no tagged node either, nor is a pixel at level ``K + 1``; one sweep with depth-first
walks takes the closure (*uphill* pixels: on the pile 16,739 kept pixels become 4,454, on the dense
frame 123,419 become 60,785). The pruned path works on the window of rows and segment columns that
hold pixels in the cuts, its scratch arrays sized by it, in one kernel call from the window to the mask
(:func:`zcut.cut_tree.pruned_outliers`).

The gentle components are those of the z-cut's connectivity. With 8-connectivity the *4-connected*
ones would do too (each lies inside an 8-connected one, so a pixel of one of ``max_area`` pixels or
more is in no tagged node either: any set of such pixels may be left out; ``_pruned_outliers``'
``gentle=4``), but since the 8-connected scan reads precomputed gentle-edge codes
(:func:`zcut.cut_tree.gentle_levels`) it costs no more than the 4-connected one and leaves fewer
pixels to the prune (the pile: 16,739 of 117,023 against 30,422), so they are not tried first any more.

With the flood (the default), :func:`zcut_outliers` and :func:`find_clusters` build the tree
straight from the heights (:func:`_flood`): one pass finds the extremes and the largest height of
every 64-pixel row segment, one pass gives the pixels in the cuts their level (a segment wholly
below the lowest cut is not read again, and no other pixel costs more than one comparison), and
the flood and the read-outs visit those pixels only. The tree, hence every output, is the one of
:func:`_tree` (which the union-find kernel and :mod:`zcut.cut_grid` use).
"""

from __future__ import annotations

import math
import operator
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np

from .cut_tree import (
    FLOOD_MAX_LEVELS,
    SEGMENT,
    SHALLOW_LEVELS,
    cluster_labels,
    cuts_window,
    finite_range,
    flood_core,
    flood_core_deep,
    flood_levels,
    flood_tree,
    flood_whole,
    level_counts,
    listed_cluster_labels,
    listed_outlier_mask,
    node_image,
    outlier_mask,
    pixel_levels,
    pruned_clusters,
    pruned_outliers,
    pruned_scratch,
    qlevel,
    retag,
    squeezed_heights,
    union_find_tree,
)
from .errors import InputShapeError, ParameterError, describe_array
from .params import _K_CAP, ZCutParams, n_levels
from .types import FloatImage, Labels, Mask

__all__ = [
    "KERNELS",
    "CutResult",
    "StageTree",
    "cluster_labels_of",
    "find_clusters",
    "find_clusters_many",
    "n_levels",
    "zcut_outliers",
    "zcut_outliers_reference",
]

#: :func:`zcut_outliers` stops labelling the gentle components when, after this many pixels in the
#: cuts (at least), fewer than half of them lie in components of ``max_area`` pixels or more (then the flood
#: would visit most pixels anyway; :func:`zcut.cut_tree.gentle_levels`).
PRUNE_CHECK = 4096
#: ... and at least this many rows' worth of pixels (components need rows to join up).
PRUNE_CHECK_ROWS = 8
#: With fewer pixels in the cuts than this (counted by row segments: an upper bound)
#: the flood visits them all at once: its whole cost is then a few tenths of a ms,
#: below what the labelling's fixed costs and its share of the pixels can win back.
PRUNE_MIN = 65536
#: Largest level count :func:`find_clusters` accepts (``pixel_level`` is int16).
MAX_STAGE_LEVELS = 32766
#: The component-tree kernels: ``"auto"`` floods below ``FLOOD_MAX_LEVELS`` levels and uses the
#: union-find beyond; ``"flood"`` and ``"union-find"`` force one (the result is the same).
KERNELS = ("auto", "flood", "union-find")


# --------------------------------------------------------------------------------------------
# Input checking shared by both implementations
# --------------------------------------------------------------------------------------------


def _check_height(height: FloatImage) -> np.ndarray:
    a = np.asarray(height)
    if a.ndim != 2 or a.dtype.kind != "f":
        raise InputShapeError(
            f"height must be an (H, W) real float array, got {describe_array(a)}"
        )
    return np.ascontiguousarray(a, dtype=np.float64)


def _real(name: str, value: object) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ParameterError(f"{name} must be a real number, got {value!r}")
    return float(value)


def _check_step(step: object) -> float:
    s = _real("step", step)
    if not (math.isfinite(s) and s > 0):
        raise ParameterError(f"step must be a finite number > 0, got {step!r}")
    return s


def _check_depth(max_depth: object, name: str = "max_depth") -> float:
    d = _real(name, max_depth)
    if not (math.isfinite(d) and d >= 0):
        raise ParameterError(f"{name} must be a finite number >= 0, got {max_depth!r}")
    return d


def _check_area(max_area: object, name: str = "max_area") -> float:
    a = _real(name, max_area)
    if not a > 0:  # +inf allowed: no area limit
        raise ParameterError(f"{name} must be a number > 0 (pixels), got {max_area!r}")
    return a


def _check_connectivity(connectivity: object) -> int:
    if isinstance(connectivity, (bool, np.bool_)):
        raise ParameterError(f"connectivity must be 4 or 8, got {connectivity!r}")
    try:
        c = operator.index(connectivity)  # type: ignore[arg-type]
    except TypeError:
        c = None
    if c not in (4, 8):
        raise ParameterError(f"connectivity must be 4 or 8, got {connectivity!r}")
    return c


def _check_kernel(kernel: object) -> str:
    if not isinstance(kernel, str) or kernel not in KERNELS:
        raise ParameterError(f"kernel must be one of {', '.join(map(repr, KERNELS))}, got {kernel!r}")
    return kernel


def _check_params(
    step: object, max_depth: object, max_area: object, connectivity: object
) -> tuple[float, float, float, int]:
    return (_check_step(step), _check_depth(max_depth), _check_area(max_area),
            _check_connectivity(connectivity))


def _valid_range(z: np.ndarray) -> tuple[np.ndarray, float, float] | None:
    """Valid mask (finite heights), z_min, z_max; None when no pixel is valid."""
    valid = np.isfinite(z)
    n, z_min, z_max = _finite_min_max(z)
    if n == 0:
        return None
    return valid, z_min, z_max


def _checked(height: FloatImage, step: object, max_depth: object, max_area: object, connectivity: object
             ) -> tuple[np.ndarray, float, float, int, int, tuple[np.ndarray, float, float] | None]:
    """The checked inputs of a z-cut: ``(z, step, max_area, connectivity, K, range)``, K the number of
    cuts (:func:`n_levels`) and range :func:`_valid_range`'s, None when no pixel is valid or K < 1."""
    z = _check_height(height)
    step, max_depth, max_area, connectivity = _check_params(step, max_depth, max_area, connectivity)
    rng = _valid_range(z)
    K = n_levels(step, max_depth)
    return z, step, max_area, connectivity, K, None if K < 1 else rng


@numba.njit(cache=True)
def _finite_min_max(z):  # type: ignore[no-untyped-def]  # numba kernel
    n = 0
    lo = np.inf
    hi = -np.inf
    for v in z.ravel():
        if np.isfinite(v):
            n += 1
            if v < lo:
                lo = v
            if v > hi:
                hi = v
    return n, lo, hi


def _finite_range(z: np.ndarray) -> tuple[int, float, float, np.ndarray]:
    """:func:`_finite_min_max` with the largest finite height of every row segment
    (:func:`zcut.cut_tree.finite_range`), in one pass; the count is of the row segments holding a
    finite height, not of the heights (0 all the same when none is)."""
    seg_max = np.empty((z.shape[0], -(-z.shape[1] // SEGMENT)))
    n, lo, hi = finite_range(z, seg_max)
    return int(n), float(lo), float(hi), seg_max


# --------------------------------------------------------------------------------------------
# The oracle
# --------------------------------------------------------------------------------------------


def zcut_outliers_reference(height: FloatImage, *, step: float, max_depth: float, max_area: float,
                            connectivity: int = 8) -> Mask:
    """The z-cut filter as the literal loop of docs/filters.md (slow, obviously correct); the parameters
    and the result of :func:`zcut_outliers`.
    """
    z, step, max_area, connectivity, K, rng = _checked(height, step, max_depth, max_area, connectivity)
    out = np.zeros(z.shape, dtype=bool)
    if rng is None:
        return out
    valid, z_min, z_max = rng
    zt = np.where(valid, z, z_min)
    from scipy import ndimage  # here: a replay never loads it (0.15 CPU-s; docs/performance.md)

    structure = ndimage.generate_binary_structure(2, 2 if connectivity == 8 else 1)

    def cut(k: int) -> tuple[np.ndarray, int]:
        return ndimage.label(zt >= z_max - k * step, structure=structure)

    lab_b, n_b = cut(1)
    for k in range(1, K + 1):
        lab_a, n_a = lab_b, n_b  # the cut at level k, labelled in the previous round
        lab_b, n_b = cut(k + 1)
        area_a = np.bincount(lab_a.ravel(), minlength=n_a + 1)
        area_b = np.bincount(lab_b.ravel(), minlength=n_b + 1)
        inside = lab_a > 0
        container = np.zeros(n_a + 1, dtype=np.intp)  # the component of B holding each one of A
        container[lab_a[inside]] = lab_b[inside]
        tagged = (area_a == area_b[container]) & (area_a < max_area)
        tagged[0] = False
        if tagged.any():
            out |= tagged[lab_a]
    return out & valid


def _tree(z: np.ndarray, valid: np.ndarray, z_min: float, z_max: float, step: float, K: int,
          max_area: float, connectivity: int, kernel: str = "auto") -> tuple[Any, ...]:
    """Padded pixel levels and the component tree of the cuts 0 .. min(K, Q + 1) + 1.

    Returns ``(q, k_eff, lab, node_b, node_size, node_parent, tagged, fin)``: ``lab`` (padded,
    flat) is the node holding each pixel at its own level (< 0: none), ``fin`` lists the nodes
    children first. ``kernel`` is one of :data:`KERNELS`.
    """
    K = min(K, _K_CAP)
    q_min = int(qlevel(z_min, z_max, step, np.int64(K + 2)))  # the deepest level of any pixel
    k_eff = min(K, q_min + 1)  # levels past q_min + 1 change nothing (module notes)
    H, W = z.shape
    if (H + 2) * (W + 2) >= 2**31 - 1:
        raise InputShapeError(f"height is too large for zcut (int32 indices), got {describe_array(z)}")
    dtype: type[np.signedinteger[Any]]
    if k_eff + 3 < 2**15 - 1:
        dtype = np.int16
    elif k_eff + 3 < 2**31 - 1:
        dtype = np.int32
    else:
        dtype = np.int64
    sentinel = np.iinfo(dtype).max
    q = np.empty((H + 2) * (W + 2), dtype)
    pixel_levels(z, valid, z_min, z_max, step, np.int64(k_eff + 2), sentinel, q)
    top = k_eff + 1
    if kernel == "flood" and top >= FLOOD_MAX_LEVELS:
        raise ParameterError(
            f"kernel 'flood' builds trees of fewer than {FLOOD_MAX_LEVELS} levels, this one needs "
            f"{top + 1}; use kernel 'auto' or 'union-find'"
        )
    if kernel == "flood" or (kernel == "auto" and top < FLOOD_MAX_LEVELS):
        lab, node_b, node_size, node_parent, tagged, fin = flood_tree(
            q, W, np.int64(k_eff), np.int64(top), connectivity == 8, float(max_area))
    else:
        order, first, node_b, node_size, node_parent, tagged, _, _ = union_find_tree(
            q, W, np.int64(k_eff), q.dtype.type(top), connectivity == 8, float(max_area))
        lab = node_image(order, first, q.size)
        fin = np.arange(node_b.size, dtype=np.int32)  # parents are created after children
    return q, k_eff, lab, node_b, node_size, node_parent, tagged, fin


def _levels(z_min: float, z_max: float, step: float, K: int) -> tuple[int, int]:
    """``(k_eff, top)`` of :func:`_tree`: the cuts 0 .. k_eff + 1 = top hold every change."""
    K = min(K, _K_CAP)
    q_min = int(qlevel(z_min, z_max, step, np.int64(K + 2)))  # the deepest level of any pixel
    k_eff = min(K, q_min + 1)  # levels past q_min + 1 change nothing (module notes)
    return k_eff, k_eff + 1


@dataclass(frozen=True, slots=True)
class _Flood:
    """The flood's tree built straight from the heights (:func:`_flood`), over the pixels in the
    cuts only: ``pix`` (padded) and ``own`` (flat, ``-1 - index`` when invalid) list them in
    raster order, ``lab`` is written at them only."""

    lab: np.ndarray
    pix: np.ndarray
    own: np.ndarray
    node_b: np.ndarray
    node_size: np.ndarray
    node_parent: np.ndarray
    tagged: np.ndarray
    fin: np.ndarray


def _one_block(*parts: tuple[type, int]) -> list[np.ndarray]:
    """Arrays of the given dtypes and lengths, in this order, as views of one block, each starting on a 64-byte
    boundary: a call's scratch freed as one block stays in glibc's heap for the next call (:func:`_scratch`)."""
    sizes = [-(-np.dtype(t).itemsize * k // 64) * 64 for t, k in parts]
    block = np.empty(max(sum(sizes), 1), np.uint8)
    ends = np.cumsum([0, *sizes])
    return [block[int(a):int(a) + np.dtype(t).itemsize * k].view(t) for (t, k), a in zip(parts, ends[:-1], strict=True)]


def _flood_scratch(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_flood`'s frame-sized arrays (``n`` padded pixels): ``st`` (n,) int16, ``pix``, ``own``,
    ``lab`` (n,) int32, views of one block (:func:`_one_block`). The block lives as long as a view of it (the
    :class:`_Flood` keeps ``lab``, ``pix`` and ``own``)."""
    pix, own, lab, st = _one_block((np.int32, n), (np.int32, n), (np.int32, n), (np.int16, n))
    return st, pix, own, lab


def _flood(z: np.ndarray, seg_max: np.ndarray, z_min: float, z_max: float, step: float, K: int, max_area: float,
           connectivity: int, pixel_level: np.ndarray | None = None) -> _Flood | None:
    """The flood kernel's tree without the full-image passes of :func:`_tree` (no valid mask, no
    padded level image, no pass over the pixels outside the cuts but one comparison each): the
    same nodes, tags and closing order. None when it does not apply (too many levels or pixels:
    :func:`_tree` then). ``seg_max``: from :func:`_finite_range`. ``pixel_level``: (H, W) int16,
    filled as :class:`CutResult` has it."""
    k_eff, top = _levels(z_min, z_max, step, K)
    H, W = z.shape
    n = (H + 2) * (W + 2)
    if top >= FLOOD_MAX_LEVELS or n >= 2**31 - 1:
        return None
    st, pix, own, lab = _flood_scratch(n)
    start = np.zeros(top + 2, np.int64)
    want = pixel_level is not None
    levels = pixel_level if pixel_level is not None else np.empty((1, 1), np.int16)
    m = int(flood_levels(z, seg_max, z_min, z_max, step, np.int64(k_eff + 2), np.int64(top), np.int64(K), st, start, pix,
                         own, levels, want))
    pix, own = pix[:m], own[:m]
    # every pixel in the cuts: the deepest level's pixels (the invalid ones among them) are not flooded
    core = flood_whole if m == H * W else flood_core if top < SHALLOW_LEVELS else flood_core_deep
    node_b, node_size, node_parent, tagged, fin = core(st, start, pix, W, np.int64(k_eff), np.int64(top),
                                                       connectivity == 8, float(max_area), lab)
    return _Flood(lab, pix, own, node_b, node_size, node_parent, tagged, fin)


def _window(seg_max: np.ndarray, thr: float, W: int) -> tuple[int, int, int, int, int]:
    """The window of :func:`zcut.cut_tree.gentle_levels` that holds every pixel in the cuts: ``(row,
    column, height, width)``, the column a multiple of SEGMENT, and the number of row segments whose
    largest height (``seg_max``, :func:`_finite_range`'s) is in the cuts (``>= thr``; the invalid pixels
    outside them: :func:`zcut.cut_tree.cuts_window`, which :func:`zcut.cut_tree.pruned_outliers` calls);
    an empty window when none is."""
    wr, wc, wh, ww, n = cuts_window(seg_max, float(thr), W)
    return int(wr), int(wc), int(wh), int(ww), int(n)


def _scratch(n: int, bound: int) -> tuple[np.ndarray, ...]:
    """The pruned flood's scratch arrays (``st, gl, pix, gpar, gcnt, gls``: :func:`zcut.cut_tree.pruned_scratch`,
    one block sized by the window's ``n`` padded pixels and the ``bound`` on the pixels in the cuts), as
    :func:`zcut.cut_tree.pruned_outliers` allocates them in its call; for the passes timed one by one
    (``bench/bench_zcut.py --passes``)."""
    return tuple(pruned_scratch(np.int64(n), np.int64(bound), np.int64(bound)))


def _pruned_outliers(z: np.ndarray, seg_max: np.ndarray, z_min: float, z_max: float, step: float, K: int,
                     max_area: float, connectivity: int, out: np.ndarray, *, minimum: int = PRUNE_MIN,
                     check: int | None = None, gentle: int | str = "auto") -> bool:
    """The outlier mask (into ``out``, zeroed) by the flood over the pixels of the small gentle
    components only (:func:`zcut.cut_tree.gentle_prune`: the same tagged nodes as the whole tree).
    False when it does not apply (too many levels or pixels, or fewer than ``minimum`` in the cuts:
    nothing written). ``check``: when the labelling looks whether it pays (default: at
    ``PRUNE_CHECK`` pixels and ``PRUNE_CHECK_ROWS`` rows' worth). ``gentle``: the connectivity of
    the gentle components labelled: 4, the z-cut's ``connectivity``, or ``"auto"``: the
    z-cut's ``connectivity`` (module notes). The window, the scratch, the labelling, the prune, the
    flood and the read-out are one kernel call (:func:`zcut.cut_tree.pruned_outliers`)."""
    k_eff, top = _levels(z_min, z_max, step, K)
    H, W = z.shape
    n = (H + 2) * (W + 2)
    if top >= SHALLOW_LEVELS or n >= 2**31 - 1 or not max_area <= H * W:
        return False  # (no gentle component reaches max_area: nothing would be left out)
    if gentle not in ("auto", 4, connectivity):
        raise ParameterError(f"gentle must be 'auto', 4 or the connectivity ({connectivity}), got {gentle!r}")
    if check is None:
        check = max(PRUNE_CHECK, PRUNE_CHECK_ROWS * W)
    conn8 = connectivity == 8
    return bool(pruned_outliers(z, seg_max, z_min, z_max, step, np.int64(k_eff), np.int64(top), conn8,
                                conn8 and gentle != 4, float(max_area), np.int64(check), np.int64(minimum),
                                out.reshape(-1)))


def zcut_outliers(
    height: FloatImage,
    *,
    step: float,
    max_depth: float,
    max_area: float,
    connectivity: int = 8,
) -> Mask:
    """The z-cut filter (docs/filters.md): pixels of small clusters floating at least ``step`` apart.

    Same result as :func:`zcut_outliers_reference` for every input, from one pass that builds the
    component tree of all the cuts (module notes).

    Parameters
    ----------
    height : (H, W) float ndarray
        Larger = higher; NaN (or any non-finite value) = invalid. float32 is upcast to float64.
    step, max_depth : float
        Δd > 0 and d_max >= 0, in the unit of ``height``.
    max_area : float
        μ_thr in pixels: only components with fewer pixels are tagged (+inf: no limit).
    connectivity : {8, 4}
        Pixel adjacency of the components.

    Returns
    -------
    (H, W) bool ndarray
        True on the valid pixels of the tagged components.
    """
    z = _check_height(height)
    step, max_depth, max_area, connectivity = _check_params(step, max_depth, max_area, connectivity)
    K = n_levels(step, max_depth)
    out = np.zeros(z.shape, dtype=bool)
    n, z_min, z_max, seg_max = _finite_range(z)
    if n == 0 or K < 1:
        return out
    if _pruned_outliers(z, seg_max, z_min, z_max, step, K, max_area, connectivity, out):
        return out
    tree = _flood(z, seg_max, z_min, z_max, step, K, max_area, connectivity)
    if tree is not None:
        listed_outlier_mask(tree.lab, tree.pix, tree.own, tree.fin, tree.node_parent, tree.tagged, out.reshape(-1))
        return out
    valid = np.isfinite(z)
    _, _, lab, _, _, node_parent, tagged, fin = _tree(
        z, valid, z_min, z_max, step, K, max_area, connectivity
    )
    outlier_mask(lab, fin, node_parent, tagged, valid, out)
    return out


# --------------------------------------------------------------------------------------------
# The stage view
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class CutResult:
    """Everything the z-cut stage found on one height image.

    Attributes
    ----------
    outliers : (H, W) bool ndarray
        Equal to :func:`zcut_outliers` with the same parameters.
    clusters : (H, W) int32 ndarray
        0 = none, i = the i-th cluster (numbered in raster order of first pixel). A cluster is an
        outermost tagged component, restricted to its valid pixels; ``outliers == clusters > 0``.
    areas : (n,) int64 ndarray
        Valid pixels of each cluster (``np.bincount(clusters)[1:]``). The tag test itself compares
        the component's full size, NaN-filled pixels included, with ``max_area``.
    rho : (n,) float64 ndarray
        ``areas / a_max`` (paper eq. 5); NaN when ``a_max`` is unknown.
    levels : (n,) int32 ndarray
        The smallest k at which the cluster (that exact pixel set) is tagged.
    level_counts : (K + 1,) int64 ndarray
        Number of components of the cut at k = 1 .. K + 1 (NaN-filled pixels included).
    pixel_level : (H, W) int16 ndarray
        Smallest k >= 0 with the pixel in the cut at level k; -1 if beyond K + 1.
    z_max, z_min : float
        Extremes of the valid heights (NaN without valid pixels).
    n_levels : int
        K = floor(max_depth / step + 1e-9).
    """

    outliers: Mask
    clusters: Labels
    areas: np.ndarray
    rho: np.ndarray
    levels: np.ndarray
    level_counts: np.ndarray
    pixel_level: np.ndarray
    z_max: float
    z_min: float
    n_levels: int

    @property
    def n_clusters(self) -> int:
        """Number of clusters."""
        return int(self.areas.size)


def find_clusters(height: FloatImage, *, params: ZCutParams, kernel: str = "auto") -> CutResult:
    """Run the z-cut and return the stage view (clusters, areas, levels, per-level counts).

    Parameters
    ----------
    height : (H, W) float ndarray
        Larger = higher; NaN = invalid.
    params : ZCutParams
        step, max_depth, max_area, connectivity and optionally a_max (for ``rho``): every parameter
        of the filter comes from here (no keyword overrides one of them).
    kernel : {"auto", "flood", "union-find"}
        The component-tree kernel (:data:`KERNELS`); every choice gives the same result.

    Returns
    -------
    CutResult
        ``result.outliers`` equals :func:`zcut_outliers` with the same parameters.
    """
    return StageTree(height, params=params, kernel=kernel).answer(params)


def cluster_labels_of(height: FloatImage, *, params: ZCutParams) -> tuple[Labels, np.ndarray, np.ndarray]:
    """``(clusters, areas, levels)`` of :func:`find_clusters` ``(height, params=params)``, bit for bit, without the
    rest of its stage view (no pixel levels, no counts per level), by the pruned flood where it applies, else by
    the whole tree's flood (:func:`_cluster_labels`).

    For a caller that reads only the clusters, e.g. the suspects' floating detector, whose z-cut holds every pixel
    of the frame (the zone's whole height range): there the whole tree's flood visits every pixel above the
    deepest level, the pruned one the pixels of the gentle components smaller than ``max_area`` only
    (docs/performance.md, round 2026-12-07d).
    """
    return _cluster_labels(height, params)


def _cluster_labels(height: FloatImage, params: ZCutParams, *, minimum: int = PRUNE_MIN, check: int | None = None
                    ) -> tuple[Labels, np.ndarray, np.ndarray]:
    """:func:`cluster_labels_of`; ``minimum`` and ``check`` as :func:`_pruned_outliers`' (the tests force the
    pruned flood on small frames with ``minimum=0``).

    **Every pixel in the cuts.** When the cut at the deepest level ``top`` holds every pixel (the lowest height's
    level ``q_min`` is at most ``top``: K >= q_min - 1), the clusters are those of ``K' = q_min - 2`` (when >= 1,
    and ``max_area`` at most the frame's pixels), whose cuts leave out the pixels at ``q_min`` (the invalid ones
    among them: they stand at the lowest height). Why: the cut at ``q_min`` is the whole pixel grid, one
    component, so the tree's root is born at ``q_min`` with every pixel (never tagged: its size is not below
    ``max_area``), a pixel at ``q_min`` is in the root only, and the root's children are the components of the cut
    at ``q_min - 1``, ending at ``q_min`` (:func:`zcut.cut_tree.flood_whole`). With ``K'`` the tree is the same
    below ``q_min`` (the levels are those of ``z_max`` and ``step``, not of K), those children are its roots,
    ending at ``K' + 2 = q_min`` too, and a node is tagged iff ``max(b, 1) <= min(K, e - 2)`` and its size is
    below ``max_area``: for every node ``e <= q_min``, so ``min(K, e - 2) = e - 2 = min(K', e - 2)`` (K >= K').
    Its levels (``max(b, 1)`` of a cluster's node) are the same nodes' too."""
    z = _check_height(height)
    step, max_area, connectivity, K = _stage_params(params)
    H, W = z.shape
    n, z_min, z_max, seg_max = _finite_range(z)
    if n > 0 and K >= 1:
        q_min = int(qlevel(z_min, z_max, step, np.int64(min(K, _K_CAP) + 2)))
        whole = K >= q_min - 1 and q_min >= 3 and max_area <= H * W
        if whole:
            K = q_min - 2  # (above)
        k_eff, top = _levels(z_min, z_max, step, K)
        if whole and top >= SHALLOW_LEVELS and (H + 2) * (W + 2) < 2**31 - 1 and q_min < 2**16 - 1:
            got = _squeezed_clusters(z, seg_max, z_max, step, q_min, max_area, connectivity, minimum, check)
            if got is not None:
                return got
        if top < SHALLOW_LEVELS and (H + 2) * (W + 2) < 2**31 - 1 and max_area <= H * W:
            clusters = np.zeros((H, W), dtype=np.int32)
            conn8 = connectivity == 8
            if check is None:
                check = max(PRUNE_CHECK, PRUNE_CHECK_ROWS * W)
            ok, areas, levels = pruned_clusters(z, seg_max, z_min, z_max, step, np.int64(k_eff), np.int64(top), conn8,
                                                conn8, float(max_area), np.int64(check), np.int64(minimum),
                                                clusters.reshape(-1))
            if ok:
                return clusters, areas, levels.astype(np.int32)
        # the whole tree's flood (find_clusters' own), without the pixel levels and the counts per level
        tree = _flood(z, seg_max, z_min, z_max, step, K, max_area, connectivity)
        if tree is not None:
            clusters = np.zeros((H, W), dtype=np.int32)
            outliers = np.zeros((H, W), dtype=bool)
            tops, areas = listed_cluster_labels(tree.lab, tree.pix, tree.own, tree.fin, tree.node_parent, tree.tagged,
                                                clusters.reshape(-1), outliers.reshape(-1))
            return clusters, areas, np.maximum(tree.node_b[tops], 1).astype(np.int32)
    cut = find_clusters(z, params=params)
    return cut.clusters, cut.areas, cut.levels


def _squeezed_clusters(z: np.ndarray, seg_max: np.ndarray, z_max: float, step: float, q_min: int, max_area: float,
                       connectivity: int, minimum: int, check: int | None) -> tuple[Labels, np.ndarray, np.ndarray] | None:
    """:func:`_cluster_labels` of a cut that holds every pixel, deeper than ``SHALLOW_LEVELS``, by the pruned flood
    on its heights with the bands of empty levels squeezed to at most two (``zcut.cut_tree.squeezed_heights``: the
    same clusters and areas; the levels mapped back), when that leaves fewer than ``SHALLOW_LEVELS`` levels: a
    ray-traced frame's far points spread 1.95 M pixels over 25,990 levels, 3,267 of them occupied (3,826 once
    squeezed). ``seg_max`` is :func:`_finite_range`'s of ``z``; the squeezed heights' range and row segments' maxima
    come from the squeeze itself (:func:`_finite_range` of them equals them: tests/zcut/test_cuts_cluster_labels.py).
    None when it does not apply (the whole tree's flood then)."""
    H, W = z.shape
    zs = np.empty((H, W))
    seg2 = np.empty_like(seg_max)
    fwd, inv = squeezed_heights(z, seg_max, z_max, step, np.int64(q_min), zs, seg2)
    q2 = int(fwd[q_min])
    k2 = q2 - 2  # K' = q_min - 2 of the squeezed heights
    if k2 + 1 >= SHALLOW_LEVELS:
        return None
    lo2, hi2 = 0.0 - float(q2), 0.0  # the lowest pixel's level is q_min, the highest's 0
    k_eff, top = _levels(lo2, hi2, 1.0, k2)
    clusters = np.zeros((H, W), dtype=np.int32)
    conn8 = connectivity == 8
    if check is None:
        check = max(PRUNE_CHECK, PRUNE_CHECK_ROWS * W)
    ok, areas, levels = pruned_clusters(zs, seg2, lo2, hi2, 1.0, np.int64(k_eff), np.int64(top), conn8, conn8,
                                        float(max_area), np.int64(check), np.int64(minimum), clusters.reshape(-1))
    if not ok:
        return None
    return clusters, areas, inv[levels].astype(np.int32)


def _stage_params(params: object) -> tuple[float, float, int, int]:
    """``(step, max_area, connectivity, K)`` of a :func:`find_clusters` parameter set, checked."""
    if not isinstance(params, ZCutParams):
        raise ParameterError(f"params must be a ZCutParams, got {type(params).__name__}")
    step, max_depth, max_area, connectivity = _check_params(
        params.step, params.max_depth, params.max_area, params.connectivity
    )
    K = n_levels(step, max_depth)
    if K > MAX_STAGE_LEVELS:
        raise ParameterError(
            f"max_depth / step gives {K} levels, more than find_clusters supports "
            f"({MAX_STAGE_LEVELS}); use zcut_outliers or a larger step"
        )
    return step, max_area, connectivity, max(K, 0)


class StageTree:
    """The component tree of one height image's cuts, built once, answering :func:`find_clusters` for
    every parameter set that shares it.

    The tree (its nodes, their sizes, birth levels, parents, the pixel levels and the per-level
    component counts) depends on the heights, ``step``, ``K`` (:func:`n_levels` of ``max_depth``) and
    ``connectivity`` only; ``max_area`` decides which nodes are tagged (:func:`zcut.cut_tree.retag`, the
    flood's own rule) and ``a_max`` only ``rho``. :meth:`answer` gives, for any parameter set, exactly
    what :func:`find_clusters` gives (which is :meth:`answer` of a tree of its own): from this tree when
    :meth:`shares` (the clusters read out again with that set's tags), else from a tree of its own.

    The answers share one ``pixel_level`` array, made read-only (``setflags(write=False)``: the same
    values for every set of the tree; a caller that wants to change it copies it); each has its own
    masks, labels and counts.

    Parameters
    ----------
    height : (H, W) float ndarray
        Larger = higher; NaN = invalid.
    params : ZCutParams
        A parameter set whose ``step``, ``max_depth`` and ``connectivity`` the tree is built for
        (its ``max_area`` is the first answer's).
    kernel : {"auto", "flood", "union-find"}
        As :func:`find_clusters`'s. With the union-find (``"union-find"``; ``"auto"`` floods every level
        count :func:`find_clusters` takes) the tree is not kept: every answer is a tree of its own.
    """

    __slots__ = ("_z", "_n", "_z_min", "_z_max", "_seg_max", "_kernel", "_key", "_max_area", "_flood",
                 "_pixel_level", "_counts", "_tagged", "trees")

    def __init__(self, height: FloatImage, *, params: ZCutParams, kernel: str = "auto") -> None:
        if not isinstance(params, ZCutParams):  # the checks in find_clusters' order
            raise ParameterError(f"params must be a ZCutParams, got {type(params).__name__}")
        z = _check_height(height)
        _check_params(params.step, params.max_depth, params.max_area, params.connectivity)
        self._kernel = _check_kernel(kernel)
        step, max_area, connectivity, K = _stage_params(params)
        self._z = z
        self._key = (step, K, connectivity)
        self._max_area = max_area
        n, z_min, z_max, seg_max = _finite_range(z)
        self._n, self._z_min, self._z_max, self._seg_max = n, z_min, z_max, seg_max
        self._flood: _Flood | None = None
        self._pixel_level: np.ndarray | None = None
        self._counts: np.ndarray | None = None
        self._tagged: dict[float, np.ndarray] = {}
        #: Trees built (1 here; +1 for each :meth:`answer` of a set that does not share this one).
        self.trees = 0
        if n == 0 or self._kernel == "union-find":
            return
        pixel_level = np.empty(z.shape, dtype=np.int16)
        tree = _flood(z, seg_max, z_min, z_max, step, K, max_area, connectivity, pixel_level)
        self.trees = 1
        if tree is None:
            return
        counts = np.zeros(K + 1, dtype=np.int64)
        level_counts(tree.node_b, tree.node_parent, counts)
        pixel_level.setflags(write=False)  # shared by every answer: no caller may change another's
        self._flood, self._pixel_level, self._counts = tree, pixel_level, counts
        self._tagged[max_area] = tree.tagged

    def shares(self, params: ZCutParams) -> bool:
        """True when :meth:`answer` reads ``params`` out of this tree (the same ``step``, ``K`` and
        ``connectivity``, and a flood tree was built); else it builds one of its own."""
        step, _, connectivity, K = _stage_params(params)
        return (step, K, connectivity) == self._key and (self._flood is not None or self._n == 0)

    def answer(self, params: ZCutParams) -> CutResult:
        """:func:`find_clusters` ``(height, params=params, kernel=kernel)``, bit for bit."""
        step, max_area, connectivity, K = _stage_params(params)
        z = self._z
        H, W = z.shape
        if (step, K, connectivity) != self._key:
            self.trees += 1
            return StageTree(z, params=params, kernel=self._kernel).answer(params)
        outliers = np.zeros((H, W), dtype=bool)
        clusters = np.zeros((H, W), dtype=np.int32)
        empty_i64 = np.zeros(0, dtype=np.int64)
        if self._n == 0:
            return CutResult(outliers, clusters, empty_i64, np.zeros(0), np.zeros(0, np.int32),
                             np.zeros(K + 1, dtype=np.int64), np.full((H, W), -1, dtype=np.int16), math.nan,
                             math.nan, K)
        tree = self._flood
        if tree is not None:
            assert self._counts is not None and self._pixel_level is not None
            tagged = self._tagged.get(max_area)
            if tagged is None:
                tagged = np.empty(tree.node_b.size, np.bool_)
                k_eff, _ = _levels(self._z_min, self._z_max, step, K)
                retag(tree.node_b, tree.node_size, tree.node_parent, np.int64(k_eff), float(max_area), tagged)
                self._tagged[max_area] = tagged
            tops, areas = empty_i64, empty_i64
            if K >= 1:
                tops, areas = listed_cluster_labels(tree.lab, tree.pix, tree.own, tree.fin, tree.node_parent,
                                                    tagged, clusters.reshape(-1), outliers.reshape(-1))
            return _result(params, outliers, clusters, areas, np.maximum(tree.node_b[tops], 1).astype(np.int32),
                           self._counts.copy(), self._pixel_level, self._z_max, self._z_min, K)
        if self._kernel != "union-find":
            self.trees += 1  # the flood did not apply: the union-find's tree, built for this answer
        return _union_find_answer(z, params, self._z_min, self._z_max, step, K, max_area, connectivity,
                                  self._kernel)


def find_clusters_many(height: FloatImage, *, params: Iterable[ZCutParams], kernel: str = "auto"
                       ) -> list[CutResult]:
    """:func:`find_clusters` of every parameter set in ``params``, in order, each bit for bit as its own
    call, with one component tree per distinct ``(step, K, connectivity)`` (:class:`StageTree`): sets
    that differ only in ``max_area`` or ``a_max`` share it."""
    sets = list(params)
    for p in sets:
        _stage_params(p)
    trees: list[StageTree] = []
    out = []
    for p in sets:
        tree = next((t for t in trees if t.shares(p)), None)
        if tree is None:
            tree = StageTree(height, params=p, kernel=kernel)
            trees.append(tree)
        out.append(tree.answer(p))
    return out


def _union_find_answer(z: np.ndarray, params: ZCutParams, z_min: float, z_max: float, step: float, K: int,
                       max_area: float, connectivity: int, kernel: str) -> CutResult:
    """:func:`find_clusters` by :func:`_tree` (the union-find, or the full-image flood)."""
    H, W = z.shape
    clusters = np.zeros((H, W), dtype=np.int32)
    counts = np.zeros(K + 1, dtype=np.int64)
    empty_i64 = np.zeros(0, dtype=np.int64)
    pixel_level = np.full((H, W), -1, dtype=np.int16)
    valid = np.isfinite(z)
    q, k_eff, lab, node_b, _, node_parent, tagged, fin = _tree(
        z, valid, z_min, z_max, step, K, max_area, connectivity, kernel
    )
    # pixel levels (k_eff >= K or nothing lies deeper than k_eff + 1, so q is exact up to K + 1)
    q2 = q.reshape(H + 2, W + 2)[1:-1, 1:-1]
    inside = q2 <= K + 1
    pixel_level[inside] = q2[inside]
    level_counts(node_b, node_parent, counts)
    if K >= 1:
        tops = cluster_labels(lab, fin, node_parent, tagged, valid, clusters)
        outliers = clusters > 0
    else:
        tops = empty_i64
        outliers = np.zeros((H, W), dtype=bool)
    areas = np.bincount(clusters.ravel(), minlength=tops.size + 1)[1:].astype(np.int64)
    levels = np.maximum(node_b[tops], 1).astype(np.int32)
    return _result(params, outliers, clusters, areas, levels, counts, pixel_level, z_max, z_min, K)


def _result(params: ZCutParams, outliers: Mask, clusters: Labels, areas: np.ndarray, levels: np.ndarray,
            counts: np.ndarray, pixel_level: np.ndarray, z_max: float, z_min: float, K: int) -> CutResult:
    a_max = params.a_max
    rho = areas / float(a_max) if a_max is not None else np.full(areas.size, math.nan)
    return CutResult(outliers, clusters, areas, rho, levels, counts, pixel_level, z_max, z_min, K)
