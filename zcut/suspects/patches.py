"""The patch detector: pieces of the depth image cut off from everything measured around them by depth steps.

``patch`` (see :mod:`zcut.suspects`): the measured pixels are joined into 4-connected pieces, two neighbours
joined when their heights differ by at most :data:`PATCH_JUMP_FACTOR` × the smaller of their jumps (the suspects'
``max(jump_mm, noise_k · σ̂)`` at each, σ̂ the frame's noise at their height). A piece is a suspect patch when it
is small — at most :data:`PATCH_RHO` · a_max pixels, a_max the part's largest face (``SuspectParams.a_max``; 1 %
of the frame without one) — and a depth step, not an unmeasured pixel or
the image's border, bounds at least :data:`PATCH_MIN_STEP_SHARE` of its border: a patch of surface at another
depth than all the measured surface around it. A stereo matcher's wrong matches are such patches (a smooth
surface at the wrong disparity inside a right one, docs/labelling_real.md); a real object standing free in front
of a surface is one too, which is why the patch is proposed for review and not removed.

:func:`cut_off_patches` is the numba kernel's entry, :func:`cut_off_patches_reference` its literal version
(scipy's connected components of the joined pairs, then ``np.bincount``); they agree bit for bit
(``tests/zcut/test_suspects_patches.py``).
"""

from __future__ import annotations

import numba
import numpy as np

from ..components import find_root, union_roots
from ..errors import InputShapeError, describe_array

#: two measured 4-neighbours belong to one piece when their heights differ by at most this many times the
#: smaller of their jumps
PATCH_JUMP_FACTOR = 1.0
#: a patch holds at most this many times a_max pixels (the part's largest face; 1 % of the frame without one)
PATCH_RHO = 0.3
#: at least this share of a patch's border (its 4-neighbour sides that leave it) lies against measured pixels
#: across a depth step; the rest is unmeasured pixels or the image's border
PATCH_MIN_STEP_SHARE = 0.5


def _check(h: np.ndarray, jump: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    h = np.asarray(h)
    jump = np.asarray(jump)
    if h.ndim != 2 or h.dtype.kind != "f":
        raise InputShapeError(f"height_mm must be an (H, W) float array, got {describe_array(h)}")
    if jump.shape != h.shape or jump.dtype.kind != "f":
        raise InputShapeError(f"jump_mm must be a float array of the heights' shape {h.shape}, got {describe_array(jump)}")
    return np.ascontiguousarray(h, np.float64), np.ascontiguousarray(jump, np.float64)


@numba.njit(cache=True)
def _joined(h, jump, factor, p, q):  # type: ignore[no-untyped-def]  # numba kernel
    """Whether flat pixels p and q (both measured) are one piece (``np.minimum`` of the jumps: NaN if either is)."""
    a = jump[p]
    b = jump[q]
    if a != a or b != b:
        return False
    return abs(h[p] - h[q]) <= factor * (a if a <= b else b)


@numba.njit(cache=True)
def _patch_labels(h2, jump2, factor, lab2, eq):  # type: ignore[no-untyped-def]  # numba kernel
    """Pass 1 of :func:`_patch_kernel`: each measured pixel's provisional label (int32, -1 where not measured), in
    raster order, the label of its left neighbour when joined to it, else of its upper one, else a new one; two
    labels met by one pixel are joined in the union-find ``eq`` (:func:`~zcut.components.union_roots`: the later
    root linked to the earlier, so ``eq[k] <= k``). Returns the number of labels."""
    H, W = h2.shape
    h = h2.reshape(-1)
    jump = jump2.reshape(-1)
    lab = lab2.reshape(-1)
    n = 0
    for i in range(H):
        for j in range(W):
            p = i * W + j
            if not np.isfinite(h[p]):
                lab[p] = -1
                continue
            k = -1
            if j > 0 and lab[p - 1] >= 0 and _joined(h, jump, factor, p - 1, p):
                k = lab[p - 1]
            if i > 0 and lab[p - W] >= 0 and _joined(h, jump, factor, p - W, p):
                u = lab[p - W]
                if k < 0:
                    k = u
                elif u != k:
                    union_roots(eq, k, u)
            if k < 0:
                eq[n] = n
                k = n
                n += 1
            lab[p] = k
    return n


@numba.njit(cache=True)
def _patch_counts(lab2, eq, n, size, steps, open_):  # type: ignore[no-untyped-def]  # numba kernel
    """Pass 2 of :func:`_patch_kernel`: every label's root (``eq[k] <= k``: resolved in order), each measured
    pixel's label replaced by its piece's root, and per root its pixels, its sides against another piece (a
    step; counted for both pieces at the later pixel of the pair) and its open sides (an unmeasured neighbour or
    the image's border)."""
    for k in range(n):
        eq[k] = find_root(eq, k)  # its parent's root: eq[eq[k]], resolved already
    H, W = lab2.shape
    lab = lab2.reshape(-1)
    for i in range(H):
        for j in range(W):
            p = i * W + j
            k = lab[p]
            if k < 0:
                continue
            r = eq[k]
            lab[p] = r
            size[r] += 1
            o = 0
            if j > 0:  # the left neighbour: its root is written already
                q = lab[p - 1]
                if q < 0:
                    o += 1
                elif q != r:
                    steps[r] += 1
                    steps[q] += 1
            else:
                o += 1
            if i > 0:  # the upper one likewise
                q = lab[p - W]
                if q < 0:
                    o += 1
                elif q != r:
                    steps[r] += 1
                    steps[q] += 1
            else:
                o += 1
            if j + 1 >= W or lab[p + 1] < 0:  # right and lower: open here, a step at their own pixel
                o += 1
            if i + 1 >= H or lab[p + W] < 0:
                o += 1
            open_[r] += o


@numba.njit(cache=True)
def _patch_out(lab2, size, out2):  # type: ignore[no-untyped-def]  # numba kernel
    """Pass 3 of :func:`_patch_kernel`: ``out2`` set at the measured pixels whose root is a patch (``size`` > 0)."""
    lab = lab2.reshape(-1)
    out = out2.reshape(-1)
    for p in range(lab.size):
        r = lab[p]
        out[p] = r >= 0 and size[r] > 0


@numba.njit(cache=True)
def _patch_keep(n, eq, size, steps, open_, max_px, min_step_share):  # type: ignore[no-untyped-def]  # numba kernel
    """The rule of the module docstring per root (the labels ``eq[r] == r``): a root that is no patch gets size -1;
    returns the number of patches."""
    count = 0
    for r in range(n):
        if eq[r] != r:
            continue
        if size[r] <= max_px and steps[r] > 0 and steps[r] >= min_step_share * (steps[r] + open_[r]):
            count += 1
        else:
            size[r] = -1  # not a patch
    return count


def _patch_kernel(h2: np.ndarray, jump2: np.ndarray, factor: float, max_px: float, min_step_share: float,
                  out2: np.ndarray) -> int:
    """:func:`cut_off_patches_reference` into ``out2`` (bool, (H, W)); returns the number of patches.

    A two-pass labelling (:func:`_patch_labels`, :func:`_patch_counts`): the union-find is over the provisional
    labels, not the pixels, and each pair of neighbours is read once when the pieces' sides are counted (the
    union-find over every pixel and four sides a pixel before 2026-12-07c: docs/performance.md). The pieces, and
    so the pixels flagged, do not depend on how they are numbered."""
    H, W = h2.shape
    lab = np.empty((H, W), np.int32)
    eq = np.empty(H * W, np.int32)  # only its first n entries are written
    n = int(_patch_labels(h2, jump2, factor, lab, eq))
    size = np.zeros(n, np.int64)
    steps = np.zeros(n, np.int64)
    open_ = np.zeros(n, np.int64)
    _patch_counts(lab, eq, n, size, steps, open_)
    count = int(_patch_keep(n, eq, size, steps, open_, max_px, min_step_share))
    _patch_out(lab, size, out2)
    return count


def cut_off_patches(height_mm: np.ndarray, jump_mm: np.ndarray, *, max_px: float, factor: float = PATCH_JUMP_FACTOR,
                    min_step_share: float = PATCH_MIN_STEP_SHARE) -> np.ndarray:
    """The pixels of the patches cut off by depth steps (module docstring).

    Parameters
    ----------
    height_mm : (H, W) float ndarray
        Heights (mm; NaN = not measured, or not context: those pixels bound a patch as unmeasured ones do).
    jump_mm : (H, W) float ndarray
        The depth step at each pixel (mm): neighbours differing by more than ``factor`` × the smaller of
        theirs are cut apart.
    max_px : float
        The largest patch (pixels; :func:`zcut.suspects.suspects` gives :data:`PATCH_RHO` · a_max).
    factor, min_step_share : float
        :data:`PATCH_JUMP_FACTOR`, :data:`PATCH_MIN_STEP_SHARE`.

    Returns
    -------
    (H, W) bool ndarray
    """
    h, jump = _check(height_mm, jump_mm)
    out = np.zeros(h.shape, bool)
    if h.size:
        _patch_kernel(h, jump, float(factor), float(max_px), float(min_step_share), out)
    return out


def cut_off_patches_reference(height_mm: np.ndarray, jump_mm: np.ndarray, *, max_px: float,
                              factor: float = PATCH_JUMP_FACTOR,
                              min_step_share: float = PATCH_MIN_STEP_SHARE) -> np.ndarray:
    """:func:`cut_off_patches` with scipy's connected components of the joined neighbour pairs and whole-frame
    numpy."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    h, jump = _check(height_mm, jump_mm)
    H, W = h.shape
    m = np.isfinite(h)
    if h.size == 0:
        return np.zeros(h.shape, bool)
    idx = np.arange(H * W).reshape(H, W)
    i_all, j_all = [], []
    pairs = (((slice(None), slice(0, W - 1)), (slice(None), slice(1, W))),
             ((slice(0, H - 1), slice(None)), (slice(1, H), slice(None))))
    for a, b in pairs:
        ok = m[a] & m[b]
        with np.errstate(invalid="ignore"):
            ok &= np.abs(h[a] - h[b]) <= factor * np.minimum(jump[a], jump[b])
        i_all.append(idx[a][ok])
        j_all.append(idx[b][ok])
    i = np.concatenate(i_all)
    j = np.concatenate(j_all)
    graph = coo_matrix((np.ones(i.size, np.int8), (i, j)), shape=(H * W, H * W))
    _, lab = connected_components(graph, directed=False)
    lab = lab.reshape(H, W)
    n = int(lab.max()) + 1
    size = np.bincount(lab[m], minlength=n)
    steps = np.zeros(n, np.int64)
    open_ = np.zeros(n, np.int64)
    # every side of a measured pixel that leaves its piece: to a measured pixel of another piece (a step), or
    # to an unmeasured pixel or the image's border (open)
    padded_m = np.pad(m, 1, constant_values=False)
    padded_lab = np.pad(lab, 1, constant_values=-1)
    for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        nb_m = padded_m[1 + dr:1 + dr + H, 1 + dc:1 + dc + W]
        nb_lab = padded_lab[1 + dr:1 + dr + H, 1 + dc:1 + dc + W]
        steps += np.bincount(lab[m & nb_m & (nb_lab != lab)], minlength=n)
        open_ += np.bincount(lab[m & ~nb_m], minlength=n)
    patch = ((size <= float(max_px)) & (steps > 0)
             & (steps >= min_step_share * (steps + open_)) & (size > 0))
    return m & patch[lab]
