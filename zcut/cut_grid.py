"""Every (d_max, μ_thr) pair of a parameter sweep answered from one component tree.

For one height image and one step Δd, :func:`zcut_tree` builds the component tree of the cuts
once (for the largest d_max of the sweep) and returns a frozen :class:`ZCutTree`.
``tree.outliers(max_depth, max_area)`` is then one look-up per pixel and equals
``zcut_outliers(height, step=step, max_depth=max_depth, max_area=max_area, ...)`` exactly, for
every ``max_depth`` up to the tree's and every ``max_area``; ``tree.counts(...)`` scores a whole
grid of them against labels (docs/accuracy.md pixel counts) without building any mask.

Why one tree answers everything (notation of :mod:`zcut.cuts`: a node ``a`` is born at level
``b``, has ``|a|`` pixels, next changes at level ``e``; the loop with K levels tags it iff
``max(b, 1) <= min(K, e - 2)`` and ``|a| < max_area``):

1. *One tree for every K.* The cuts ``S_k`` do not depend on K or on ``max_area``, so the tree
   built for K_T, cut off below level ``K + 1``, is the tree for any ``K <= K_T``: the same nodes,
   sizes and ends, except that a node living past ``K + 1`` ends at ``K + 2`` there, which changes
   nothing in ``min(K, e - 2)``. With ``kmin = max(b, 1)`` the tag at ``K <= K_T`` is
   ``kmin <= K`` and ``kmin <= min(K_T, e - 2)`` and ``|a| < max_area``. The middle condition
   (the node is *taggable*) depends neither on K nor on ``max_area``: it is the tag of the K_T
   tree built with ``max_area = inf``. (The kernels stop at level ``Q + 1``, one past the
   deepest pixel, when ``K > Q``; every node is born at ``b <= Q``, so ``kmin <= Q + 1`` and
   stopping there changes no tag either.)
2. *Nesting.* Let ``x`` be a taggable node and ``y`` a taggable node above it (y holds x). ``y``
   is born where a node between them changed, at or after ``e_x >= kmin_x + 2``, so
   ``kmin_y > kmin_x``; and ``y`` holds every pixel of ``x`` and more, ``|y| > |x|``. So ``y``
   tagged at ``(K, A)`` implies ``x`` tagged at ``(K, A)``: a pixel is an outlier at ``(K, A)``
   iff the *lowest* taggable node holding it (``node_of_pixel``) has ``kmin <= K`` and
   ``size < A`` and the pixel is valid (docs/filters.md: the result is ANDed with the valid mask).
3. *Counting.* A grid count is therefore a sum over the forest nodes of the node's pixel
   weights times ``[kmin <= K] [size < A]``: each node's weights go to the grid cell of the
   smallest K and smallest A that tag it, and a 2-D cumulative sum gives every grid point
   (:func:`zcut.cut_tree.grid_counts`). No node is counted twice: each pixel has one lowest node.
4. *Clusters.* A cluster (:class:`zcut.cuts.CutResult`) is an outermost tagged node with a valid
   pixel; by 2 a tagged node is outermost iff its nearest taggable ancestor is not tagged.

K of a ``max_depth`` is ``floor(max_depth / step + 1e-9)`` (docs/filters.md), computed for each value
exactly as :func:`zcut.zcut_outliers` does.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .cloud import check_mask
from .cut_tree import forest_mask, grid_counts, taggable_forest
from .cuts import (
    _check_area,
    _check_connectivity,
    _check_depth,
    _check_height,
    _check_kernel,
    _check_step,
    _tree,
    _valid_range,
)
from .errors import ParameterError
from .params import n_levels
from .types import FloatImage, Mask

__all__ = ["COUNT_KEYS", "ZCutTree", "zcut_tree"]

#: The keys of :meth:`ZCutTree.counts`.
COUNT_KEYS = ("tp", "fp", "fn", "n_pred")


@dataclass(frozen=True, slots=True)
class ZCutTree:
    """The z-cut of one height image for every ``max_depth <= self.max_depth`` and ``max_area``.

    Built by :func:`zcut_tree`; the arrays are read-only. The forest holds the m nodes of the
    component tree that some ``(max_depth, max_area)`` tags (module notes).

    Attributes
    ----------
    step : float
        Δd of the cuts.
    max_depth : float
        The largest d_max the tree answers.
    n_levels : int
        K of ``max_depth`` (docs/filters.md); every ``max_depth`` with at most this K is answered.
    connectivity : int
        8 or 4.
    node_of_pixel : (H, W) int32 ndarray
        The lowest forest node holding each valid pixel; -1 where none does, and on invalid pixels.
    node_kmin : (m,) int64 ndarray
        The smallest K at which each node is tagged (if smaller than ``max_area``).
    node_size : (m,) int64 ndarray
        Pixels of each node (NaN-filled ones included: the size the tag compares).
    node_parent : (m,) int32 ndarray
        The nearest forest node above each one, -1 if none.
    node_valid : (m,) bool ndarray
        The node holds a valid pixel.
    """

    step: float
    max_depth: float
    n_levels: int
    connectivity: int
    node_of_pixel: np.ndarray
    node_kmin: np.ndarray
    node_size: np.ndarray
    node_parent: np.ndarray
    node_valid: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the height image."""
        return self.node_of_pixel.shape

    def _levels(self, max_depth: object, name: str = "max_depth") -> int:
        d = _check_depth(max_depth, name)
        K = n_levels(self.step, d)
        if K > self.n_levels:
            raise ParameterError(
                f"{name} {max_depth!r} gives K = {K} levels, more than this tree's "
                f"{self.n_levels} (built for max_depth {self.max_depth!r}, step {self.step!r})"
            )
        return K

    def _tagged(self, K: int, max_area: float) -> np.ndarray:
        return (self.node_kmin <= K) & (self.node_size < max_area)

    def outliers(self, max_depth: float, max_area: float) -> Mask:
        """The outlier mask of one parameter pair.

        Parameters
        ----------
        max_depth : float
            d_max, at most the tree's (more precisely: K at most :attr:`n_levels`).
        max_area : float
            μ_thr in pixels (> 0; +inf: no limit).

        Returns
        -------
        (H, W) bool ndarray
            Identical to :func:`zcut.zcut_outliers` with this tree's step and connectivity.
        """
        K = self._levels(max_depth)
        tagged = self._tagged(K, _check_area(max_area))
        out = np.empty(self.shape, dtype=bool)
        forest_mask(self.node_of_pixel, tagged, out)
        return out

    def n_clusters(self, max_depth: float, max_area: float) -> int:
        """Number of clusters of one parameter pair (``find_clusters(...).n_clusters``)."""
        K = self._levels(max_depth)
        tagged = self._tagged(K, _check_area(max_area))
        parent = self.node_parent
        above = np.zeros(tagged.shape, dtype=bool)
        has_parent = parent >= 0
        above[has_parent] = tagged[parent[has_parent]]
        return int(np.count_nonzero(tagged & ~above & self.node_valid))

    def counts(
        self,
        max_depths: Sequence[float] | np.ndarray,
        max_areas: Sequence[float] | np.ndarray,
        *,
        truth: Mask,
        scored: Mask,
        within: Mask | None = None,
        plus: Mask | None = None,
    ) -> dict[str, np.ndarray]:
        """docs/accuracy.md pixel counts of every grid point ``(max_depths[i], max_areas[j])``.

        The predicted mask of a grid point is ``P = (outliers(d, a) & within) | plus`` (the
        pipeline's final mask: z-cut inside the zone, plus the easy outliers); it is scored
        against ``L = truth`` over ``S = scored``. No mask is built (module notes).

        Parameters
        ----------
        max_depths : (n_d,) sequence of float
            d_max values, each within the tree's (any order, repeats allowed).
        max_areas : (n_a,) sequence of float
            μ_thr values in pixels, each > 0 (+inf: no limit).
        truth, scored : (H, W) bool ndarray
            L and S.
        within : (H, W) bool ndarray, optional
            Where the z-cut's outliers count (default: everywhere).
        plus : (H, W) bool ndarray, optional
            Pixels predicted at every grid point (default: none).

        Returns
        -------
        dict of str to (n_d, n_a) int64 ndarray
            ``"tp"`` = |P ∩ L ∩ S|, ``"fp"`` = |P ∩ S ∖ L|, ``"fn"`` = |L ∩ S ∖ P|,
            ``"n_pred"`` = |P| (every predicted pixel, scored or not).
        """
        ks = np.array([self._levels(d, "max_depths") for d in _values(max_depths, "max_depths")],
                      dtype=np.int64)
        areas = np.array([_check_area(a, "max_areas") for a in _values(max_areas, "max_areas")],
                         dtype=np.float64)
        shape = self.shape
        truth = check_mask(truth, name="truth", shape=shape)
        scored = check_mask(scored, name="scored", shape=shape)
        none = np.zeros((0, 0), dtype=bool)
        w = none if within is None else check_mask(within, name="within", shape=shape)
        p = none if plus is None else check_mask(plus, name="plus", shape=shape)
        od = np.argsort(ks, kind="stable")
        oa = np.argsort(areas, kind="stable")
        sorted_counts = [np.zeros((ks.size, areas.size), dtype=np.int64) for _ in range(3)]
        n_ls = grid_counts(self.node_of_pixel, self.node_kmin, self.node_size, ks[od], areas[oa],
                           truth, scored, w, within is not None, p, plus is not None,
                           *sorted_counts)
        out = {}
        for key, c in zip(("tp", "fp", "n_pred"), sorted_counts):
            a = np.empty_like(c)
            a[np.ix_(od, oa)] = c
            out[key] = a
        out["fn"] = n_ls - out["tp"]
        return {key: out[key] for key in COUNT_KEYS}


def _values(values: object, name: str) -> list[object]:
    a = np.asarray(values, dtype=object) if not isinstance(values, np.ndarray) else values
    if a.ndim != 1:
        raise ParameterError(f"{name} must be a 1-D sequence of numbers, got shape {a.shape}")
    return [v.item() if isinstance(v, np.generic) else v for v in a]


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def zcut_tree(
    height: FloatImage,
    *,
    step: float,
    max_depth: float,
    connectivity: int = 8,
    kernel: str = "auto",
) -> ZCutTree:
    """Build the component tree of the cuts once, for every ``max_depth`` up to the given one.

    Parameters
    ----------
    height : (H, W) float ndarray
        Larger = higher; NaN (or any non-finite value) = invalid. float32 is upcast to float64.
    step : float
        Δd > 0, in the unit of ``height``.
    max_depth : float
        The largest d_max to be asked (>= 0).
    connectivity : {8, 4}
        Pixel adjacency of the components.
    kernel : {"auto", "flood", "union-find"}
        The component-tree kernel (:data:`zcut.cuts.KERNELS`); every choice gives the same tree
        read-outs.

    Returns
    -------
    ZCutTree
        ``tree.outliers(d, a)`` equals ``zcut_outliers(height, step=step, max_depth=d,
        max_area=a, connectivity=connectivity)`` for every ``d <= max_depth`` and ``a > 0``.
    """
    z = _check_height(height)
    step = _check_step(step)
    max_depth_f = _check_depth(max_depth)
    connectivity = _check_connectivity(connectivity)
    kernel = _check_kernel(kernel)
    K = n_levels(step, max_depth_f)
    node_of_pixel = np.full(z.shape, -1, dtype=np.int32)
    empty = np.zeros(0, dtype=np.int64)
    kmin, size, parent, has_valid = empty, empty.copy(), np.zeros(0, np.int32), np.zeros(0, bool)
    rng = _valid_range(z)
    if rng is not None and K >= 1:
        valid, z_min, z_max = rng
        _, _, lab, node_b, node_size, node_parent, taggable, fin = _tree(
            z, valid, z_min, z_max, step, K, math.inf, connectivity, kernel
        )
        kmin, size, parent, has_valid = taggable_forest(
            lab, fin, node_b, node_size, node_parent, taggable, valid, node_of_pixel
        )
    return ZCutTree(
        step=step,
        max_depth=max_depth_f,
        n_levels=K,
        connectivity=connectivity,
        node_of_pixel=_readonly(node_of_pixel),
        node_kmin=_readonly(kmin),
        node_size=_readonly(size),
        node_parent=_readonly(parent),
        node_valid=_readonly(has_valid),
    )
