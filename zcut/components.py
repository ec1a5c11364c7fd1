"""Two component filters of the filter bank: speckle removal and cluster removal.

Both split the image into regions of neighbouring valid pixels that are "close" and remove the small
regions:

- :func:`speckle_outliers` (OpenCV's ``filterSpeckles``, Ensenso's SpeckleRemoval): 4-neighbours
  are joined when their depths differ by at most ``max_diff_mm``; regions of at most
  ``max_size_px`` pixels are removed.
- :func:`cluster_outliers` (Zivid's Cluster Filter): 8- (or 4-) neighbours are joined when their
  points are at most ``max_neighbour_mm`` apart in 3D; clusters whose area, summed from each
  pixel's footprint at its depth, is below ``min_area_mm2`` are removed.

The fast path is one pass over the pixels in raster order (numba) with provisional labels: a valid
pixel takes the label of a visited neighbour (left, then the row above) that passes the test, a new
label if none does, and two different labels that meet are merged in a union-find over the labels
(the later root linked to the earlier one, so a label's parent never follows it and one forward
pass resolves every root). A neighbour that already carries the pixel's label needs no test: on a
smooth surface almost every pixel costs one test and no union. The sizes (areas) are then summed
per root in raster order. The reference builds the graph
of every joined pair with numpy and labels it with ``scipy.sparse.csgraph.connected_components``;
its areas are ``np.bincount`` sums, also in raster order, so both agree bit for bit (tests).

``xyz`` is an (H, W, 3) organized cloud in the camera optical frame (metres); a pixel is valid iff
its three coordinates are finite. Invalid pixels belong to no region and are never outliers. The
region sizes only grow with the image, so a region touching the border is judged on what is seen.
docs/filters.md, "The filter bank", describes both filters.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import numba as nb
import numpy as np

from .cloud import Intrinsics
from .errors import InputShapeError, ParameterError, describe_array
from .grid_input import as_cloud, depth_plane_reference, plain_number, valid_at
from .params import ClusterParams, SpeckleParams
from .types import XYZ, Mask

__all__ = [
    "cluster_outliers",
    "cluster_outliers_reference",
    "cluster_stage",
    "find_root",
    "union_roots",
    "speckle_outliers",
    "speckle_outliers_reference",
    "speckle_stage",
]


# --------------------------------------------------------------------------------------------
# union-find over provisional labels, in raster order
# --------------------------------------------------------------------------------------------
@nb.njit(cache=True, nogil=True, inline="always")
def find_root(parent, i):  # type: ignore[no-untyped-def]  # numba kernel
    """The root of ``i`` in the union-find ``parent`` (a numba kernel), the path compressed on the way; also
    :mod:`zcut.fits.segment`'s."""
    root = i
    while parent[root] != root:
        root = parent[root]
    while parent[i] != root:  # path compression
        nxt = parent[i]
        parent[i] = root
        i = nxt
    return root


@nb.njit(cache=True, nogil=True, inline="always")
def _union(parent, i, j):  # type: ignore[no-untyped-def]  # numba kernel
    # link the later root to the earlier one: parent[l] <= l for every label l
    a = find_root(parent, i)
    b = find_root(parent, j)
    if a < b:
        parent[b] = a
    elif b < a:
        parent[a] = b


#: the union of the sets of ``i`` and ``j`` in the union-find ``parent`` (a numba kernel): the later root linked to
#: the earlier one, so a set's root is its smallest member whatever the order of the unions and of the path
#: compressions (:func:`find_root`); also :mod:`zcut.suspects.patches`' and :mod:`zcut.suspects.grouping`'s
union_roots = _union


@nb.njit(cache=True, nogil=True)
def _resolve(parent, n):  # type: ignore[no-untyped-def]  # numba kernel
    # every label's root: its parent precedes it and is resolved already
    for i in range(1, n + 1):
        parent[i] = parent[parent[i]]


# --------------------------------------------------------------------------------------------
# speckles
# --------------------------------------------------------------------------------------------
def _speckle_params(max_diff_mm: object, max_size_px: object) -> SpeckleParams:
    return SpeckleParams(max_diff_mm=plain_number(max_diff_mm), max_size_px=plain_number(max_size_px))


@nb.njit(cache=True, nogil=True)
def _speckle_kernel(a, max_diff, max_size, out):  # type: ignore[no-untyped-def]  # numba kernel
    # lab: the pixel's provisional label (0: invalid); a new label where no visited 4-neighbour
    # joins; the depth test is skipped for a neighbour that already carries the same label. The
    # depths of the current and the previous row (mm, NaN where invalid) are kept in two buffers.
    H, W = a.shape[0], a.shape[1]
    lab = np.zeros((H, W), np.int32)
    parent = np.empty(H * W + 1, np.int32)
    parent[0] = 0  # the label of invalid pixels
    n = 0
    dprev = np.full(W, np.nan)
    dcur = np.empty(W)
    for r in range(H):
        row, lr, lp = a[r], lab[r], lab[max(r - 1, 0)]
        for c in range(W):
            dcur[c] = 1000.0 * np.float64(row[c, 2]) if valid_at(row, c) else np.nan
        for c in range(W):
            v = dcur[c]
            if np.isnan(v):
                continue
            cur = 0
            if c > 0 and abs(v - dcur[c - 1]) <= max_diff:  # False for a NaN (invalid) neighbour
                cur = lr[c - 1]
            lq = lp[c]
            if lq != cur and abs(v - dprev[c]) <= max_diff:
                if cur:
                    _union(parent, cur, lq)
                else:
                    cur = lq
            if not cur:
                n += 1
                parent[n] = n
                cur = n
            lr[c] = cur
        dprev, dcur = dcur, dprev
    _resolve(parent, n)
    size = np.zeros(n + 1, np.int64)
    for r in range(H):
        lr = lab[r]
        for c in range(W):
            size[parent[lr[c]]] += 1
    small = np.empty(n + 1, np.bool_)  # per label: its region is small
    small[0] = False
    for i in range(1, n + 1):
        small[i] = size[parent[i]] <= max_size
    for r in range(H):
        lr, o = lab[r], out[r]
        for c in range(W):
            o[c] = small[lr[c]]


def speckle_outliers(xyz: XYZ, *, max_diff_mm: float, max_size_px: int) -> Mask:
    """Speckles: small regions of pixels at similar depths, cut off at depth jumps.

    OpenCV's ``filterSpeckles(img, newVal, maxSpeckleSize, maxDiff)`` (calib3d, written for
    disparity maps) grows blobs of 4-connected pixels whose values differ by at most ``maxDiff``
    between neighbours and paints every blob of at most ``maxSpeckleSize`` pixels with ``newVal``.
    Ensenso's SpeckleRemoval does the same in two passes: the map is split into regions at invalid
    pixels and at discontinuities larger than ComponentThreshold, then regions smaller than
    RegionSize pixels are removed. Here the value is the depth in millimetres, ``1000 * z``
    (float64): 4-neighbours join iff both are valid and ``|d_p - d_q| <= max_diff_mm``; the
    pixels of regions with at most ``max_size_px`` pixels are outliers. On a depth image of whole
    millimetres (``z = mm / 1000`` and ``1000 * z`` gives the integer back) with whole-millimetre
    ``max_diff_mm``, this is ``cv2.filterSpeckles`` on the int16 depth image with ``newVal = 0``
    (tests).

    Parameters
    ----------
    xyz : (H, W, 3) float ndarray
        Organized cloud, camera optical frame (metres); NaN (any non-finite coordinate) = invalid.
    max_diff_mm : float
        >= 0, largest depth step inside a region (mm).
    max_size_px : int
        >= 0, regions of at most this many pixels are removed (0: no outliers).

    Returns
    -------
    (H, W) bool ndarray
        True at the pixels of the small regions.
    """
    p = _speckle_params(max_diff_mm, max_size_px)
    a = _as_grid(xyz)
    out = np.empty(a.shape[:2], dtype=bool)
    _speckle_kernel(a, p.max_diff_mm, p.max_size_px, out)
    return out


def _as_grid(xyz: XYZ) -> np.ndarray:
    """as_cloud, with at most 2**31 - 2 pixels (int32 labels)."""
    a = as_cloud(xyz)
    if a.shape[0] * a.shape[1] > 2**31 - 2:
        raise InputShapeError(f"xyz has too many pixels for the component filters (int32 labels), got "
                              f"{describe_array(a)}")
    return a


def _labels(n: int, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Connected-component label of each of n nodes, given the joined pairs (i, j)."""
    # imported here: the reference path alone needs SciPy's graphs (~0.13 CPU-s to import)
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(i.size, dtype=np.int8), (i, j)), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def _joined_pairs(H: int, W: int, steps: Iterable[tuple[int, int]],
                  joined: Callable[[int, int], np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Flat indices (i, j) of the pixel pairs (r, c), (r + dr, c + dc) for which ``joined(dr, dc)``
    (an (H, W) bool array over the first pixels, False where the second is outside) holds."""
    idx = np.arange(H * W).reshape(H, W)
    ii, jj = [], []
    for dr, dc in steps:
        ok = joined(dr, dc)
        r, c = np.nonzero(ok)
        ii.append(idx[r, c])
        jj.append(idx[r + dr, c + dc])
    return np.concatenate(ii), np.concatenate(jj)


def _shifted(a: np.ndarray, dr: int, dc: int, fill: float = np.nan) -> np.ndarray:
    """``a[r + dr, c + dc]`` at every (r, c), ``fill`` outside the image."""
    H, W = a.shape[:2]
    out = np.full(a.shape, fill)
    rs, re = max(0, -dr), min(H, H - dr)
    cs, ce = max(0, -dc), min(W, W - dc)
    out[rs:re, cs:ce] = a[rs + dr:re + dr, cs + dc:ce + dc]
    return out


def speckle_outliers_reference(xyz: XYZ, *, max_diff_mm: float, max_size_px: int) -> Mask:
    """:func:`speckle_outliers` by scipy's connected components (slow, obviously correct)."""
    p = _speckle_params(max_diff_mm, max_size_px)
    a = as_cloud(xyz)
    d, valid = depth_plane_reference(a, 1000.0)
    H, W = d.shape

    def joined(dr: int, dc: int) -> np.ndarray:
        with np.errstate(invalid="ignore"):  # inf - inf at overflowed depths: NaN, not joined
            return np.abs(_shifted(d, dr, dc) - d) <= p.max_diff_mm

    i, j = _joined_pairs(H, W, ((0, 1), (1, 0)), joined)
    labels = _labels(H * W, i, j)
    size = np.bincount(labels)
    return valid & (size[labels] <= p.max_size_px).reshape(H, W)


def speckle_stage(xyz: XYZ, *, params: SpeckleParams) -> Mask:
    """:func:`speckle_outliers` with the parameters of a :class:`~zcut.params.SpeckleParams`."""
    if not isinstance(params, SpeckleParams):
        raise ParameterError(f"params must be a SpeckleParams, got {type(params).__name__}")
    return speckle_outliers(xyz, max_diff_mm=params.max_diff_mm, max_size_px=params.max_size_px)


# --------------------------------------------------------------------------------------------
# clusters
# --------------------------------------------------------------------------------------------
def _cluster_params(max_neighbour_mm: object, min_area_mm2: object, connectivity: object) -> ClusterParams:
    return ClusterParams(max_neighbour_mm=plain_number(max_neighbour_mm), min_area_mm2=plain_number(min_area_mm2),
                         connectivity=plain_number(connectivity))


def _pixel_area(K: Intrinsics) -> float:
    """1 / (fx · fy): a pixel's footprint at depth z mm is (z · z) · this, in mm²."""
    return 1.0 / (float(K.fx) * float(K.fy))


def _check_intrinsics(intrinsics: object) -> Intrinsics:
    if intrinsics is None:
        raise ParameterError(
            "the cluster filter needs the camera intrinsics (fx, fy) to measure areas in mm², got none "
            "(a log without camera info): pass intrinsics= or leave the cluster filter out"
        )
    if not isinstance(intrinsics, Intrinsics):
        raise ParameterError(f"intrinsics must be a zcut.Intrinsics, got {type(intrinsics).__name__}")
    return intrinsics


@nb.njit(cache=True, nogil=True, inline="always")
def _close(row, j, px, py, pz, thr2):  # type: ignore[no-untyped-def]  # numba kernel
    # the point of pixel j of the row within the distance: (dx² + dy²) + dz² <= thr², metres
    dx = np.float64(row[j, 0]) - px
    dy = np.float64(row[j, 1]) - py
    dz = np.float64(row[j, 2]) - pz
    return (dx * dx + dy * dy) + dz * dz <= thr2


@nb.njit(cache=True, nogil=True)
def _cluster_kernel(a, thr2, reach, min_area, k_area, out):  # type: ignore[no-untyped-def]  # numba kernel
    # as _speckle_kernel, with the 3D distance test and, for 8-connectivity (reach 1), the up-left
    # and up-right neighbours
    H, W = a.shape[0], a.shape[1]
    lab = np.zeros((H, W), np.int32)
    parent = np.empty(H * W + 1, np.int32)
    parent[0] = 0  # the label of invalid pixels
    n = 0
    for r in range(H):
        row, lr = a[r], lab[r]
        prev, lp = a[max(r - 1, 0)], lab[max(r - 1, 0)]
        for c in range(W):
            px = np.float64(row[c, 0])
            py = np.float64(row[c, 1])
            pz = np.float64(row[c, 2])
            if not px * 0.0 + py * 0.0 + pz * 0.0 == 0.0:  # invalid
                continue
            cur = 0
            if c > 0:
                lq = lr[c - 1]
                if lq and _close(row, c - 1, px, py, pz, thr2):
                    cur = lq
            if r > 0:
                for cc in range(max(c - reach, 0), min(c + reach + 1, W)):
                    lq = lp[cc]
                    if lq and lq != cur and _close(prev, cc, px, py, pz, thr2):
                        if cur:
                            _union(parent, cur, lq)
                        else:
                            cur = lq
            if not cur:
                n += 1
                parent[n] = n
                cur = n
            lr[c] = cur
    _resolve(parent, n)
    area = np.zeros(n + 1)
    for r in range(H):
        row, lr = a[r], lab[r]
        for c in range(W):
            if lr[c]:
                zmm = 1000.0 * np.float64(row[c, 2])
                area[parent[lr[c]]] += (zmm * zmm) * k_area
    small = np.empty(n + 1, np.bool_)  # per label: its cluster is small
    small[0] = False
    for i in range(1, n + 1):
        small[i] = area[parent[i]] < min_area
    for r in range(H):
        lr, o = lab[r], out[r]
        for c in range(W):
            o[c] = small[lr[c]]


def cluster_outliers(xyz: XYZ, *, max_neighbour_mm: float, min_area_mm2: float,
                     intrinsics: Intrinsics | None, connectivity: int = 8) -> Mask:
    """Clusters: groups of neighbouring pixels close in 3D whose total area is small.

    Zivid's Cluster Filter removes floating points and isolated clusters: neighbouring points at
    most MaxNeighborDistance apart belong to the same cluster, and clusters with an area below
    MinArea (mm²) are removed. Zivid states the distance normalized (by the point spacing); here
    it is a 3D distance in millimetres, ``max_neighbour_mm``: two 8- (or 4-) neighbouring valid
    pixels join iff ``(dx² + dy²) + dz² <= (max_neighbour_mm / 1000)²`` (float64, metres). A
    cluster's area is the sum over its pixels of the pixel's footprint at its depth,
    ``(z / fx) · (z / fy)`` mm² with z in mm (a fronto-parallel patch; a tilted surface covers more
    than it counts), computed as ``(z · z) · (1 / (fx · fy))`` and summed in raster order;
    clusters with an area ``< min_area_mm2`` are outliers.

    Parameters
    ----------
    xyz : (H, W, 3) float ndarray
        Organized cloud, camera optical frame (metres); NaN (any non-finite coordinate) = invalid.
    max_neighbour_mm : float
        > 0, largest 3D step between neighbouring pixels of a cluster (mm).
    min_area_mm2 : float
        >= 0, clusters with a smaller area are removed (mm²; 0: no outliers).
    intrinsics : Intrinsics
        The camera's focal lengths ``fx``, ``fy`` (pixels) turn pixels into areas; None is an error.
    connectivity : {8, 4}
        Pixel adjacency of the clusters.

    Returns
    -------
    (H, W) bool ndarray
        True at the pixels of the small clusters.

    Raises
    ------
    ParameterError
        A parameter out of range, or no intrinsics.
    """
    p = _cluster_params(max_neighbour_mm, min_area_mm2, connectivity)
    K = _check_intrinsics(intrinsics)
    a = _as_grid(xyz)
    out = np.empty(a.shape[:2], dtype=bool)
    thr = p.max_neighbour_m
    _cluster_kernel(a, thr * thr, int(p.connectivity == 8), p.min_area_mm2, _pixel_area(K), out)
    return out


def cluster_outliers_reference(xyz: XYZ, *, max_neighbour_mm: float, min_area_mm2: float,
                               intrinsics: Intrinsics | None, connectivity: int = 8) -> Mask:
    """:func:`cluster_outliers` by scipy's connected components (slow, obviously correct)."""
    p = _cluster_params(max_neighbour_mm, min_area_mm2, connectivity)
    K = _check_intrinsics(intrinsics)
    a = as_cloud(xyz)
    H, W = a.shape[:2]
    valid = np.isfinite(a).all(axis=2)
    P = np.where(valid[..., None], a.astype(np.float64), np.nan)
    thr = p.max_neighbour_m
    thr2 = thr * thr

    def joined(dr: int, dc: int) -> np.ndarray:
        with np.errstate(over="ignore", invalid="ignore"):
            Q = np.stack([_shifted(P[..., k], dr, dc) for k in range(3)], axis=-1)
            dx, dy, dz = Q[..., 0] - P[..., 0], Q[..., 1] - P[..., 1], Q[..., 2] - P[..., 2]
            return (dx * dx + dy * dy) + dz * dz <= thr2

    steps = ((0, 1), (1, 0), (1, 1), (1, -1)) if p.connectivity == 8 else ((0, 1), (1, 0))
    i, j = _joined_pairs(H, W, steps, joined)
    labels = _labels(H * W, i, j)
    with np.errstate(over="ignore", invalid="ignore"):
        zmm = 1000.0 * P[..., 2]
        footprint = np.where(valid, (zmm * zmm) * _pixel_area(K), 0.0).ravel()
        area = np.bincount(labels, weights=footprint)
    return valid & (area[labels] < p.min_area_mm2).reshape(H, W)


def cluster_stage(xyz: XYZ, *, params: ClusterParams, intrinsics: Intrinsics | None) -> Mask:
    """:func:`cluster_outliers` with the parameters of a :class:`~zcut.params.ClusterParams`."""
    if not isinstance(params, ClusterParams):
        raise ParameterError(f"params must be a ClusterParams, got {type(params).__name__}")
    return cluster_outliers(xyz, max_neighbour_mm=params.max_neighbour_mm, min_area_mm2=params.min_area_mm2,
                            intrinsics=intrinsics, connectivity=params.connectivity)
