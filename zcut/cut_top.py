"""The z-cut with its window anchored on the pile's top instead of the single highest point (issue 31).

The paper's z-cut (:mod:`zcut.cuts`) cuts the height image at ``z_max - k * step`` for ``k = 1 ..
K + 1``, ``K = floor(d_max / step)``, with ``z_max`` the highest valid point of the zone (paper eq. 2).
One tall outlier sets ``z_max``: on the ray-traced shiny frames a ghost just under the rim, 63–92 mm
above the pile, so the window of d_max = 30 mm holds only ghosts (docs/raytraced.md, "A robust top
for the z-cut's window"). This variant measures d_max from a top of the pile that a few ghost
pixels cannot set:

- **The pile's top level** ``k_top`` is the smallest ``k >= 0`` at which the cut
  ``S_k = {z~ >= z_max - k * step}`` holds a connected component of at least ``top_area`` pixels
  (a part's footprint: ``ZCutTopParams.top_faces`` × a_max in the pipeline), with the z-cut's own
  ``z~`` (invalid pixels at ``z_min``), levels and connectivity. Nothing above that level is as
  large as a part; its height ``z_top = z_max - k_top * step`` is the pile's top. When no cut holds
  such a component (the whole image is smaller than a part), ``k_top = 0``: the paper's window.
- **The window** is the paper's loop over the cuts ``k = 1 .. k_top + K + 1``: from ``z_max`` down
  to d_max below the pile's top. The points above ``z_top`` are cut level by level as the paper
  cuts them, so a small cluster floating above the pile (a ghost under the rim, a splinter above the
  top part) is an outlier exactly when the paper's z-cut would call it one with a window that deep;
  the pile's own top is a component of at least ``top_area`` pixels and never tagged when
  ``top_area >= max_area``.

So the variant is the paper's z-cut with ``K`` replaced by ``k_top + K``: with ``top_area <= 1``
(``k_top = 0``) it is the paper's z-cut, bit for bit. :func:`zcut_top_outliers_reference` is the
literal loop of both steps (``scipy.ndimage.label`` per cut) and the oracle of the tests;
:func:`zcut_top_outliers` finds ``k_top`` with a union-find over the pixels in level order, gathered
in rounds of doubling depth, that stops at the first level holding a large enough component
(:func:`pile_top_level`) and then runs the fast z-cut (:func:`zcut.cuts.zcut_outliers`) with a depth of exactly ``k_top + K`` levels.
:func:`find_clusters_top` is the stage view (:class:`TopCutResult`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numba
import numpy as np

from .cut_tree import qlevel
from .cuts import (
    CutResult,
    _check_area,
    _check_connectivity,
    _check_depth,
    _check_height,
    _check_step,
    _finite_min_max,
    find_clusters,
    zcut_outliers,
)
from .errors import ParameterError
from .params import _K_CAP, ZCutParams, n_levels
from .types import FloatImage, Mask

__all__ = [
    "TopCutResult",
    "find_clusters_top",
    "pile_top_level",
    "pile_top_level_reference",
    "window_depth",
    "zcut_top_outliers",
    "zcut_top_outliers_reference",
]


# --------------------------------------------------------------------------------------------
# The oracle
# --------------------------------------------------------------------------------------------


def pile_top_level_reference(height: FloatImage, *, step: float, top_area: float, connectivity: int = 8) -> int:
    """The pile's top level ``k_top`` (module notes) as the literal loop: label the cuts ``S_0, S_1,
    ...`` one by one and stop at the first holding a component of at least ``top_area`` pixels.

    Returns 0 when no pixel is valid or no cut holds such a component.
    """
    z = _check_height(height)
    step, top_area, connectivity = _check_step(step), _check_area(top_area, "top_area"), \
        _check_connectivity(connectivity)
    valid = np.isfinite(z)
    if not valid.any() or z.size < top_area:
        return 0
    z_min, z_max = float(z[valid].min()), float(z[valid].max())
    zt = np.where(valid, z, z_min)
    from scipy import ndimage

    structure = ndimage.generate_binary_structure(2, 2 if connectivity == 8 else 1)
    k = 0
    while True:
        cut = zt >= z_max - k * step
        lab, n = ndimage.label(cut, structure=structure)
        if n and np.bincount(lab.ravel())[1:].max() >= top_area:
            return k
        if cut.all():  # every pixel is in: no deeper cut differs
            return 0
        k += 1


def zcut_top_outliers_reference(height: FloatImage, *, step: float, max_depth: float, max_area: float,
                                top_area: float, connectivity: int = 8) -> Mask:
    """The variant as the literal loop of docs/filters.md over the cuts ``k = 1 .. k_top + K + 1``
    (``k_top`` from :func:`pile_top_level_reference`); the parameters and result of
    :func:`zcut_top_outliers`."""
    z = _check_height(height)
    step, max_depth = _check_step(step), _check_depth(max_depth)
    max_area, connectivity = _check_area(max_area), _check_connectivity(connectivity)
    top_area = _check_area(top_area, "top_area")
    out = np.zeros(z.shape, dtype=bool)
    valid = np.isfinite(z)
    if not valid.any():
        return out
    k_top = pile_top_level_reference(z, step=step, top_area=top_area, connectivity=connectivity)
    n_cuts = k_top + n_levels(step, max_depth)
    z_min, z_max = float(z[valid].min()), float(z[valid].max())
    zt = np.where(valid, z, z_min)
    from scipy import ndimage

    structure = ndimage.generate_binary_structure(2, 2 if connectivity == 8 else 1)

    def cut(k: int) -> tuple[np.ndarray, int]:
        return ndimage.label(zt >= z_max - k * step, structure=structure)

    lab_b, n_b = cut(1)
    for k in range(1, n_cuts + 1):
        lab_a, n_a = lab_b, n_b
        lab_b, n_b = cut(k + 1)
        area_a = np.bincount(lab_a.ravel(), minlength=n_a + 1)
        area_b = np.bincount(lab_b.ravel(), minlength=n_b + 1)
        inside = lab_a > 0
        container = np.zeros(n_a + 1, dtype=np.intp)
        container[lab_a[inside]] = lab_b[inside]
        tagged = (area_a == area_b[container]) & (area_a < max_area)
        tagged[0] = False
        if tagged.any():
            out |= tagged[lab_a]
    return out & valid


# --------------------------------------------------------------------------------------------
# The fast path
# --------------------------------------------------------------------------------------------


@numba.njit(cache=True)
def _find(parent, i):  # type: ignore[no-untyped-def]  # numba kernel
    root = i
    while parent[root] != root:
        root = parent[root]
    while parent[i] != root:  # path compression
        nxt = parent[i]
        parent[i] = root
        i = nxt
    return root


#: The first round of :func:`_top_level` gathers the pixels of the cuts down to this level; each further
#: round doubles it (most piles' tops lie within a few hundred levels of z_max at Δd 0.2 mm).
FIRST_ROUND_LEVELS = 128


@numba.njit(cache=True)
def _top_level(z, z_min, z_max, step, q_min, conn8, top_area):  # type: ignore[no-untyped-def]  # numba kernel
    """k_top of :func:`pile_top_level` (-1: none): the pixels in level order (``q_min`` the level of
    ``z_min``, the deepest), joined to their already-added neighbours by a union-find; after each
    level, the largest component is compared with ``top_area``. The pixels are gathered in rounds:
    those of the cuts down to level ``b`` (one comparison each with the cut's threshold, then their
    exact level), sorted by level, added; ``b`` doubles until the top is found, so the pixels far
    below it cost one comparison per round."""
    H, W = z.shape
    n = H * W
    flat = z.ravel()
    parent = np.empty(n, np.int64)
    size = np.zeros(n, np.int64)
    active = np.zeros(n, np.bool_)
    got = np.empty(n, np.int64)
    got_lev = np.empty(n, np.int64)
    order = np.empty(n, np.int64)
    order_lev = np.empty(n, np.int64)
    largest = 0
    lo = np.int64(0)
    b = min(q_min, np.int64(FIRST_ROUND_LEVELS - 1))
    while True:
        thr = z_max - b * step  # the cut at level b, as qlevel tests it
        m = 0
        for i in range(n):
            if active[i]:
                continue
            v = flat[i]
            zt = v if np.isfinite(v) else z_min
            if zt >= thr:
                got[m] = i
                got_lev[m] = qlevel(zt, z_max, step, b + 1)
                m += 1
        if b - lo < 4 * m + 65536:  # counting sort of the round's pixels by level
            start = np.zeros(b - lo + 2, np.int64)
            for j in range(m):
                start[got_lev[j] - lo + 1] += 1
            for k in range(b - lo + 1):
                start[k + 1] += start[k]
            for j in range(m):
                s = got_lev[j] - lo
                order[start[s]] = got[j]
                order_lev[start[s]] = got_lev[j]
                start[s] += 1
        else:  # too many levels to count (a tiny step): sort
            idx = np.argsort(got_lev[:m])
            for j in range(m):
                order[j] = got[idx[j]]
                order_lev[j] = got_lev[idx[j]]
        j = 0
        while j < m:
            k = order_lev[j]
            while j < m and order_lev[j] == k:
                p = order[j]
                j += 1
                parent[p] = p
                size[p] = 1
                active[p] = True
                r, c = p // W, p % W
                root = p
                for dr in range(-1, 2):
                    for dc in range(-1, 2):
                        if dr == 0 and dc == 0:
                            continue
                        if not conn8 and dr != 0 and dc != 0:
                            continue
                        rr, cc = r + dr, c + dc
                        if rr < 0 or rr >= H or cc < 0 or cc >= W:
                            continue
                        nb = rr * W + cc
                        if not active[nb]:
                            continue
                        other = _find(parent, nb)
                        if other != root:
                            if size[other] > size[root]:
                                root, other = other, root
                            parent[other] = root
                            size[root] += size[other]
                if size[root] > largest:
                    largest = size[root]
            if largest >= top_area:
                return k
        if b >= q_min:
            return np.int64(-1)
        lo = b + 1
        b = min(q_min, 2 * b + 1)


def pile_top_level(height: FloatImage, *, step: float, top_area: float, connectivity: int = 8) -> int:
    """The pile's top level ``k_top`` (module notes): the smallest ``k >= 0`` whose cut ``{z~ >= z_max -
    k * step}`` holds a connected component of at least ``top_area`` pixels.

    Parameters
    ----------
    height : (H, W) float ndarray
        Larger = higher; NaN = invalid.
    step : float
        Δd > 0, in the unit of ``height``.
    top_area : float
        The least footprint of the pile's top, in pixels (> 0; +inf: never found).
    connectivity : {8, 4}
        Pixel adjacency of the components.

    Returns
    -------
    int
        ``k_top``; 0 when no pixel is valid or no cut holds a component that large (the paper's
        ``z_max``). Equal to :func:`pile_top_level_reference` for every input.
    """
    z = _check_height(height)
    step, top_area, connectivity = _check_step(step), _check_area(top_area, "top_area"), \
        _check_connectivity(connectivity)
    n, z_min, z_max = _finite_min_max(z)
    if n == 0 or z.size < top_area:
        return 0
    q_min = int(qlevel(z_min, z_max, step, np.int64(_K_CAP)))
    k = int(_top_level(z, z_min, z_max, step, np.int64(q_min), connectivity == 8, float(top_area)))
    return max(k, 0)


def window_depth(step: float, n_cuts: int) -> float:
    """A depth ``d`` with ``n_levels(step, d) == n_cuts`` (``n_cuts >= 0``): the z-cut's ``max_depth``
    that checks exactly ``n_cuts`` level pairs."""
    d = n_cuts * step
    while n_levels(step, d) < n_cuts:
        d = math.nextafter(d, math.inf)
    while d > 0 and n_levels(step, d) > n_cuts:
        d = math.nextafter(d, -math.inf)
    return d


def zcut_top_outliers(height: FloatImage, *, step: float, max_depth: float, max_area: float, top_area: float,
                      connectivity: int = 8) -> Mask:
    """The z-cut with d_max measured from the pile's top (module notes).

    Parameters
    ----------
    height : (H, W) float ndarray
        Larger = higher; NaN = invalid.
    step, max_depth, max_area, connectivity
        The z-cut's Δd, d_max (below the pile's top), μ_thr and adjacency (:func:`zcut.cuts.zcut_outliers`).
    top_area : float
        The least footprint of the pile's top in pixels (:func:`pile_top_level`).

    Returns
    -------
    (H, W) bool ndarray
        Equal to :func:`zcut_top_outliers_reference` for every input; equal to
        :func:`zcut.cuts.zcut_outliers` when ``top_area <= 1``.
    """
    z = _check_height(height)
    step, max_depth = _check_step(step), _check_depth(max_depth)
    max_area, connectivity = _check_area(max_area), _check_connectivity(connectivity)
    k_top = pile_top_level(z, step=step, top_area=top_area, connectivity=connectivity)
    n_cuts = min(k_top + n_levels(step, max_depth), _K_CAP)
    return zcut_outliers(z, step=step, max_depth=window_depth(step, n_cuts), max_area=max_area,
                         connectivity=connectivity)


@dataclass(frozen=True, slots=True)
class TopCutResult:
    """What the anchored z-cut found on one height image.

    Attributes
    ----------
    cut : CutResult
        The z-cut's stage view over the cuts ``1 .. k_top + K + 1`` (``cut.outliers`` equals
        :func:`zcut_top_outliers`; ``cut.n_levels`` is ``k_top + K``).
    k_top : int
        The pile's top level (:func:`pile_top_level`).
    z_top : float
        The pile's top ``z_max - k_top * step`` (NaN without valid pixels).
    floor : float
        The window's lowest level ``z_max - (k_top + K) * step``, d_max below the pile's top (NaN
        without valid pixels).
    """

    cut: CutResult
    k_top: int
    z_top: float
    floor: float

    @property
    def outliers(self) -> Mask:
        """(H, W) bool: the outliers (``cut.outliers``)."""
        return self.cut.outliers


def find_clusters_top(height: FloatImage, *, params: ZCutParams, top_area: float) -> TopCutResult:
    """:func:`zcut.cuts.find_clusters` over the anchored window: the stage view of
    :func:`zcut_top_outliers` with the parameters ``params`` and the pile's top of ``top_area`` pixels.

    Raises
    ------
    ParameterError
        ``params`` is not a :class:`ZCutParams`, ``top_area`` is not > 0, or the window needs more
        levels than :func:`zcut.cuts.find_clusters` supports.
    """
    if not isinstance(params, ZCutParams):
        raise ParameterError(f"params must be a ZCutParams, got {type(params).__name__}")
    z = _check_height(height)
    K = params.n_levels
    k_top = pile_top_level(z, step=params.step, top_area=top_area, connectivity=params.connectivity)
    n_cuts = min(k_top + K, _K_CAP)
    cut = find_clusters(z, params=dataclasses.replace(params, max_depth=window_depth(params.step, n_cuts)))
    return TopCutResult(cut, k_top, cut.z_max - k_top * params.step, cut.z_max - n_cuts * params.step)
