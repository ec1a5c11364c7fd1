"""Register a bin model to the bin points of a frame with Open3D ICP (paper §5.2, ``pcregistericp``).

The model is a :class:`~zcut.bin_model.BinModel` (an (N, 3) float64 point set in its own frame,
"bin"), prepared once per replay (:func:`prepare_icp_model`: downsampled copies with normals, a
KD-tree, and the model's rim); the frame's bin points (:func:`zcut.binmask.bin_pixels`: the rim and
upper walls) are prepared once per frame (:func:`prepare_target`). The result is ``T_cam_bin``, the
4 x 4 transform taking model points into the camera frame. A registration whose fitness or RMSE is
out of bounds is returned with ``converged=False`` and the reason, never silently accepted.

Fitness
-------
The fitness measures the bin, not the frame: the fraction of the model's **rim** in the camera's
view that the frame confirms, i.e. that has a frame bin point within the fine correspondence
distance once the model is placed at ``T_cam_bin`` (:func:`pose_fitness`). The rim is the model's
upward-facing top surface (:func:`rim_points`): nothing in a bin lies above it, so at the right pose
every rim point is seen, whatever the pile hides, and a pose that is off puts rim points over the
table or into the bin, where the frame has nothing at their place. Open3D's own fitness (the
fraction of the frame's points with a model point within the distance) stays available as
``icp_fitness``; it counts every target point that is not bin, so it says how clean the target was,
not whether the pose is right (0.52-0.69 on synthetic shiny piles with a pose 0.06 mm from the
truth, when the target was the whole bright component).

How far off a pose must be to show: on the synthetic bin (400 x 300 mm, rim 15 mm) at the fine
distance of 3.3 mm, the true pose scores 1.000, a pose moved 5 mm sideways 0.93, 1 cm 0.78, turned
2 degrees 0.91, 5 degrees 0.67; a pose slid 5 cm along the bin's length keeps the long sides of its
rim on the real ones and scores about 0.5. A rim hidden by something above the bin (an arm, a
cable) lowers it by the share hidden.

The walls are left out of the fitness on purpose: the projector's shadow hides the top of the wall
facing it (4-7 % of the model's top 10 mm on the synthetic bin at the true pose) and the pile hides
the lower walls, so a wall point the frame does not show proves nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numba
import numpy as np

from .bin_model import BinModel
from .cloud import Intrinsics
from .errors import InputShapeError, ParameterError, describe_array
from .params import RegistrationParams

if TYPE_CHECKING:
    import open3d as o3d
    from scipy.spatial import cKDTree

    from .icp_fast import IcpGrid

__all__ = [
    "PIXEL_REACH",
    "RIM_BAND_MM",
    "RIM_MAX_TILT_DEG",
    "IcpModel",
    "Points",
    "RegistrationResult",
    "TargetPoints",
    "initial_guess",
    "pose_fitness",
    "pose_fitness_at_least",
    "prepare_icp_model",
    "prepare_target",
    "register_bin",
    "rim_points",
    "subsampled_points",
    "to_open3d",
    "transform_points",
]

#: A model point is rim when it faces up (within :data:`RIM_MAX_TILT_DEG`) and lies no more than
#: this below (or above) the top of the model's upward-facing points (millimetres).
RIM_BAND_MM = 3.0
#: Largest angle between a rim point's normal and the model's up direction (degrees).
RIM_MAX_TILT_DEG = 30.0
#: With the camera's intrinsics known, a rim point is confirmed within the correspondence distance
#: or this many pixel footprints at its depth, whichever is larger: a frame whose pixels are coarser
#: than the distance (a 160 px wide test image: 3.5 mm at 0.5 m) has a sample that close to only
#: part of a true rim (its edge pixels, half rim and half table, are not bright: at the true pose the
#: farthest rim point was 1.7 px from a sample there). At 1920 x 1200 (0.3 mm) it changes nothing.
PIXEL_REACH = 2.0


@dataclass(frozen=True, slots=True)
class RegistrationResult:
    """Outcome of one ICP registration.

    Attributes
    ----------
    T_cam_bin : (4, 4) float64 ndarray
        Model (bin) frame -> camera frame. The initial guess when the registration failed early.
    fitness : float
        The bin fitness (:func:`pose_fitness`): the fraction of the model's rim points in the
        camera's view with a frame bin point within the fine correspondence distance, at
        ``T_cam_bin``; 0 when not run. ``params.min_fitness`` applies to it.
    inlier_rmse : float
        RMSE of the fine pass's correspondences in metres; NaN when not run.
    converged : bool
        True when the fitness and RMSE are within the configured bounds.
    reason : str
        Empty when converged, else why not (too few points, low fitness, large RMSE).
    n_model : int
        Model points used (after downsampling).
    n_target : int
        Target points used (after downsampling).
    T_init : (4, 4) float64 ndarray
        The initial guess ICP started from.
    icp_fitness : float
        Open3D's fitness of the fine pass: the fraction of the frame's (downsampled) bin points
        with a model point within the fine correspondence distance; 0 when not run. It falls with
        every target point that is not bin (parts in the target), whatever the pose.
    n_rim : int
        Model rim points in the camera's view at ``T_cam_bin``: the denominator of ``fitness``.
    iterations : tuple of int
        ICP iterations of each pass run (coarse, fine; the fine only without the coarse pass); -1
        for a pass that Open3D ran (``reference=True``, which does not say); empty when not run.
    """

    T_cam_bin: np.ndarray
    fitness: float
    inlier_rmse: float
    converged: bool
    reason: str
    n_model: int
    n_target: int
    T_init: np.ndarray
    icp_fitness: float
    n_rim: int
    iterations: tuple[int, ...] = ()


def _check_points(p: np.ndarray, name: str) -> np.ndarray:
    a = np.asarray(p)
    if a.ndim != 2 or a.shape[1] != 3 or not np.issubdtype(a.dtype, np.floating):
        raise InputShapeError(f"{name} must be an (N, 3) float array, got {describe_array(a)}")
    if np.isfinite(a).all():  # the usual case: one flat reduction, not a row-wise one and a gather (5 -> 0.3 ms)
        return np.array(a, dtype=np.float64, order="C")
    a = a[np.isfinite(a).all(axis=1)]
    return np.ascontiguousarray(a, dtype=np.float64)


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4 x 4 transform to (N, 3) points; returns (N, 3) float64."""
    p = np.asarray(points, dtype=np.float64)
    return p @ T[:3, :3].T + T[:3, 3]


#: Points sampled (evenly spaced rows) to bracket an order statistic in :func:`_order_pairs`.
_SAMPLE = 1024


@numba.njit(cache=True, nogil=True)
def _select(a, lo, hi, k):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """Rearrange ``a[lo:hi]`` so that ``a[k]`` holds its (k - lo)-th smallest value, none greater before it
    and none smaller after it (Hoare's quickselect, the median of three as pivot)."""
    hi -= 1
    while hi > lo:
        mid = (lo + hi) >> 1
        if a[mid] < a[lo]:
            a[mid], a[lo] = a[lo], a[mid]
        if a[hi] < a[lo]:
            a[hi], a[lo] = a[lo], a[hi]
        if a[hi] < a[mid]:
            a[hi], a[mid] = a[mid], a[hi]
        pivot = a[mid]
        i, j = lo, hi
        while i <= j:
            while a[i] < pivot:
                i += 1
            while pivot < a[j]:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            return


@numba.njit(cache=True, nogil=True)
def _sorted_column(p, col):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    a = np.empty(p.shape[0])
    for i in range(p.shape[0]):
        a[i] = p[i, col]
    a.sort()
    return a


@numba.njit(cache=True, nogil=True)
def _order_pairs(p, cols, ks):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """For each j, the ``ks[j]``-th and ``ks[j] + 1``-th smallest values of column ``cols[j]`` of ``p``
    ((N >= 2, 3), finite; ``ks[j] + 1 < N``), as (len(ks), 2): the values ``np.partition`` puts there.

    An evenly spaced sample of :data:`_SAMPLE` rows of the column, sorted, brackets the rank between
    two of its values (4 standard deviations of the sample rank and 4 more either side); one pass over
    the rows counts the values below each bracket and another keeps those inside; a quickselect of the
    kept ones finds the rank, the least after it the next. A bracket that misses (it cannot on any but
    contrived orders) sorts the whole column instead. The values are exact order statistics whatever the
    way (equal values are equal). The three columns are copied out once, so that the passes read contiguous
    values (0.46 -> 0.39 CPU ms on a 640 x 480 frame's 45k bin points, 0.96 -> 0.72 on 104k)."""
    n = p.shape[0]
    m = ks.shape[0]
    out = np.empty((m, 2))
    if n <= 4 * _SAMPLE:
        for j in range(m):
            a = _sorted_column(p, cols[j])
            out[j, 0], out[j, 1] = a[ks[j]], a[ks[j] + 1]
        return out
    colv = np.empty((3, n))  # the columns, each contiguous
    for i in range(n):
        colv[0, i] = p[i, 0]
        colv[1, i] = p[i, 1]
        colv[2, i] = p[i, 2]
    step = n // _SAMPLE
    lo = np.empty(m)
    hi = np.empty(m)
    sample = np.empty(_SAMPLE)
    for j in range(m):
        if j == 0 or cols[j] != cols[j - 1]:  # one sorted sample per column
            for i in range(_SAMPLE):
                sample[i] = colv[cols[j], i * step]
            sample.sort()
        q = (ks[j] + 1.0) / n
        r = q * _SAMPLE
        d = 4.0 * math.sqrt(_SAMPLE * q * (1.0 - q)) + 4.0
        a0, a1 = int(math.floor(r - d)), int(math.ceil(r + d))
        lo[j] = sample[a0] if a0 > 0 else -np.inf
        hi[j] = sample[a1] if a1 < _SAMPLE - 1 else np.inf
    below = np.zeros(m, np.int64)
    first = np.zeros(m + 1, np.int64)
    for j in range(m):  # branch-free counts, one column at a time
        c, lj, hj = cols[j], lo[j], hi[j]
        col = colv[c]
        nb = 0
        nk = 0
        for i in range(n):
            v = col[i]
            nb += v < lj
            nk += (v >= lj) & (v <= hj)
        below[j] = nb
        first[j + 1] = first[j] + nk
        if not (nb <= ks[j] and ks[j] + 1 < nb + nk):  # a bracket missed: the column sorted
            a = _sorted_column(p, c)
            lo[j], hi[j] = np.inf, -np.inf  # keeps nothing
            below[j] = ks[j] + 2
            first[j + 1] = first[j]
            out[j, 0], out[j, 1] = a[ks[j]], a[ks[j] + 1]
    buf = np.empty(first[m])
    for j in range(m):
        c, lj, hj = cols[j], lo[j], hi[j]
        col = colv[c]
        w = first[j]
        for i in range(n):
            v = col[i]
            if lj <= v <= hj:
                buf[w] = v
                w += 1
    for j in range(m):
        if below[j] <= ks[j]:
            k = first[j] + ks[j] - below[j]
            _select(buf, first[j], first[j + 1], k)
            nxt = buf[k + 1]
            for i in range(k + 2, first[j + 1]):
                nxt = min(nxt, buf[i])
            out[j, 0], out[j, 1] = buf[k], nxt
    return out


def _percentiles(p: np.ndarray, cols: tuple[int, ...], qs: tuple[float, ...]) -> list[float] | None:
    """``np.percentile(p[:, cols[j]], qs[j])`` for each j ("linear": the order statistics around ``(n -
    1) q / 100``, interpolated as NumPy's ``_lerp`` does, in the same float64 operations), from
    :func:`_order_pairs`; None where a selected value is zero (whose sign NumPy's partition may pick
    otherwise) or ``p`` has fewer than 2 rows: the caller asks NumPy."""
    n = p.shape[0]
    if n < 2:
        return None
    virtual = [(n - 1) * (q / 100) for q in qs]  # numpy: true_divide(q, 100), then (n - 1) * q
    ks = np.array([min(int(math.floor(v)), n - 2) for v in virtual], np.int64)
    pairs = _order_pairs(p, np.array(cols, np.int64), ks)
    if not np.all(pairs != 0.0):
        return None
    out = []
    for v, k, (a, b) in zip(virtual, ks, pairs.tolist(), strict=True):
        if v >= n - 1:  # numpy takes the last value for both
            out.append(b)
            continue
        t = v - float(k)
        diff = b - a
        out.append(b - diff * (1 - t) if t >= 0.5 else a + diff * t)
    return out


def _top_and_centre(p: np.ndarray) -> tuple[np.ndarray, float]:
    """(x, y) centre of the 1..99 % bounding box and the 1st percentile of z (the top).

    The same values as ``np.percentile(p, 1, axis=0)`` and ``np.percentile(p[:, :2], 99, axis=0)``
    (tests/zcut/test_registration_fast.py compares them), from the order statistics of a sampled
    bracket (:func:`_percentiles`): 0.39 instead of 0.63 CPU ms on a 640 x 480 frame's 45k bin points,
    0.55 / 1.1 instead of 2.4 / 5.7 on 45k / 104k random ones (NumPy also partitions each column around
    its minimum and maximum)."""
    got = _percentiles(p, (0, 0, 1, 1, 2), (1, 99, 1, 99, 1))
    if got is None:  # NumPy's own
        got = [*np.percentile(p[:, 0], [1, 99]), *np.percentile(p[:, 1], [1, 99]), np.percentile(p[:, 2], 1)]
    x, y, z = [float(got[0]), float(got[1])], [float(got[2]), float(got[3])], [float(got[4])]
    return 0.5 * (np.array([x[0], y[0]]) + np.array([x[1], y[1]])), z[0]


def initial_guess(model: np.ndarray, target: np.ndarray) -> np.ndarray:
    """A translation-only guess: bounding-box centres matched in x, y; tops (near z) matched in z.

    The target is the visible part of a filled bin (walls and rim, the floor hidden by parts), so
    centroids would disagree in depth; the rim, nearest to a top-down camera, is visible in both.

    Parameters
    ----------
    model, target : (N, 3) float ndarray

    Returns
    -------
    (4, 4) float64 ndarray
    """
    m = _check_points(model, "model")
    t = _check_points(target, "target")
    return _guess(_top_and_centre(m) if len(m) else None, t)


def _guess(model_top_centre: tuple[np.ndarray, float] | None, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    if model_top_centre is None or len(t) == 0:
        return T
    mc, mtop = model_top_centre
    tc, ttop = _top_and_centre(t)
    T[:2, 3] = tc - mc
    T[2, 3] = ttop - mtop
    return T


#: Open3D indexes voxels with 32-bit integers: an extent of more voxels than this along an axis
#: makes ``voxel_down_sample`` throw (``voxel_size is too small``).
_MAX_VOXELS_PER_AXIS = 2**30


def voxel_down(pc: o3d.geometry.PointCloud, voxel_m: float, what: str) -> o3d.geometry.PointCloud:
    """``pc.voxel_down_sample(voxel_m)``, after checking that the cloud's extent fits Open3D's voxel
    index: a cloud spanning ~1e38 m (garbage coordinates) is an :class:`InputShapeError`, not a
    RuntimeError from C++."""
    if len(pc.points):
        extent = np.asarray(pc.get_max_bound()) - np.asarray(pc.get_min_bound())
        if not np.all(np.isfinite(extent)) or float(extent.max()) / voxel_m > _MAX_VOXELS_PER_AXIS:
            raise InputShapeError(f"{what} spans {float(extent.max()):.3g} m, too large for a {voxel_m * 1000:g} mm "
                                  "voxel grid: its coordinates are not those of a bin seen by a camera")
    return pc.voxel_down_sample(voxel_m)


#: Bucket counts an ``std::unordered_map`` of libstdc++ goes through as it grows (the prime rehash policy,
#: maximum load factor 1: the count after inserting element k > count): Open3D 0.20's ``VoxelDownSample``
#: lists its voxels in the order of such a map (tests/zcut/test_registration_voxels.py holds
#: :func:`voxel_down_points` to Open3D's own). Read from the library by inserting keys one by one.
_LIBSTDCXX_BUCKETS = (1, 13, 29, 59, 127, 257, 541, 1109, 2357, 5087, 10273, 20753, 42043, 85229, 172933, 351061,
                      712697, 1447153, 2938679, 5967347, 12117689, 24607243, 49969847, 101473717, 206062531)


@numba.njit(cache=True, nogil=True, inline="always")
def _voxel_slot(ix, iy, iz, size):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """A voxel's first slot in a table of ``size`` (a power of two) slots: Fibonacci hashing of a
    combination of its indices (the top bits of the product)."""
    h = np.uint64(ix * 73856093 + iy * 19349663 + iz * 83492791) * np.uint64(0x9E3779B97F4A7C15)
    return np.int64((h >> np.uint64(32)) & np.uint64(size - 1))


@numba.njit(cache=True, nogil=True, inline="always")
def _find_slot(table, keys, ix, iy, iz):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """The slot of voxel ``(ix, iy, iz)`` in an open-addressing ``table`` (a power of two slots, each -1 or
    a row of ``keys``): where it is, or the empty slot (-1) where it would go (linear probing from
    :func:`_voxel_slot`). The voxel pass and the fitness's cell grid both look up and insert with it."""
    size = table.shape[0]
    slot = _voxel_slot(ix, iy, iz, size)
    while True:
        j = table[slot]
        if j < 0 or (keys[j, 0] == ix and keys[j, 1] == iy and keys[j, 2] == iz):
            return slot
        slot = (slot + 1) & (size - 1)


@numba.njit(cache=True, nogil=True)
def _voxel_table(keys, k, size):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """An open-addressing table (``size`` slots, a power of two) of the first ``k`` voxel keys."""
    table = np.full(size, -1, np.int64)
    for j in range(k):
        slot = _voxel_slot(keys[j, 0], keys[j, 1], keys[j, 2], size)
        while table[slot] >= 0:
            slot = (slot + 1) & (size - 1)
        table[slot] = j
    return table


@numba.njit(cache=True, nogil=True)
def _voxel_pass(points, i, vmin, voxel, table, keys, sums, counts, k, j):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """:func:`_voxel_ids`' loop from point ``i`` with ``k`` voxels so far (``j`` the previous point's):
    ``(the point it stopped at, k, j)``; it stops before a new voxel that does not fit."""
    n = points.shape[0]
    cap = keys.shape[0]
    while i < n:
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        ix = np.int64(math.floor((x - vmin[0]) / voxel))
        iy = np.int64(math.floor((y - vmin[1]) / voxel))
        iz = np.int64(math.floor((z - vmin[2]) / voxel))
        if not (j >= 0 and keys[j, 0] == ix and keys[j, 1] == iy and keys[j, 2] == iz):
            slot = _find_slot(table, keys, ix, iy, iz)
            j = table[slot]
            if j < 0:
                if k == cap:
                    return i, k, -1
                table[slot] = k
                keys[k, 0], keys[k, 1], keys[k, 2] = ix, iy, iz
                j = k
                k += 1
        sums[j, 0] += x
        sums[j, 1] += y
        sums[j, 2] += z
        counts[j] += 1
        i += 1
    return i, k, j


@numba.njit(cache=True, nogil=True)
def _voxel_ids(points, vmin, voxel):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """Each point's voxel (Open3D's ``int(floor((p - min_bound) / voxel))`` per axis) as an id in the
    order of first occurrence; per voxel, its index triple, the sums of its points (in point order)
    and its count. ``(keys (K, 3) int64, sums (K, 3), counts (K,))``. The arrays start small and
    double (a frame's points are far more than its voxels; large fresh arrays cost their page faults),
    and a point in the previous point's voxel (a neighbouring pixel) skips the table."""
    n = points.shape[0]
    cap = max(1024, n // 16)
    size = 16
    while size < 2 * cap:
        size *= 2
    table = np.full(size, -1, np.int64)
    keys = np.empty((cap, 3), np.int64)
    sums = np.zeros((cap, 3))
    counts = np.zeros(cap, np.int64)
    i, k, j = _voxel_pass(points, 0, vmin, voxel, table, keys, sums, counts, 0, -1)
    while i < n:  # full: twice the room, the table rebuilt
        cap *= 2
        size *= 2
        keys2 = np.empty((cap, 3), np.int64)
        keys2[:k] = keys[:k]
        sums2 = np.zeros((cap, 3))
        sums2[:k] = sums[:k]
        counts2 = np.zeros(cap, np.int64)
        counts2[:k] = counts[:k]
        keys, sums, counts = keys2, sums2, counts2
        table = _voxel_table(keys, k, size)
        i, k, j = _voxel_pass(points, i, vmin, voxel, table, keys, sums, counts, k, j)
    return keys[:k], sums[:k], counts[:k]


@numba.njit(cache=True, nogil=True)
def _bounds(points):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """(min, max) of each column of an (N >= 1, 3) array (numpy's axis-0 reductions of a 3-column
    array cost 5 ms on 100k rows)."""
    lo = points[0].copy()
    hi = points[0].copy()
    for i in range(1, points.shape[0]):
        for a in range(3):
            v = points[i, a]
            if v < lo[a]:
                lo[a] = v
            if v > hi[a]:
                hi[a] = v
    return lo, hi


@numba.njit(cache=True, nogil=True)
def _unordered_map_order(keys, buckets):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """The iteration order of a libstdc++ ``std::unordered_map<Eigen::Vector3i, ...,
    open3d::utility::hash_eigen>`` after inserting ``keys`` in their order (unique keys): each new
    node goes to the front of its bucket, or to the front of the list when its bucket is empty; the
    table grows to the next count of ``buckets`` when an insertion would exceed the current one, the
    nodes relinked in list order (``_Hashtable::_M_insert_bucket_begin``, ``_M_rehash_aux``).

    The rehash and the insertion link a node the same way, written twice on purpose: one helper for both
    (``inline="always"`` or not, tracking the head's bucket or taking its hash again) gave the same order
    in 2.0-2.8 x the time (0.10 -> 0.21-0.28 CPU ms on a frame's ~7k voxels, 3.5 -> 5.0 on 100k; both
    kernels in one process, docs/performance.md "Registration, round of 2026-12-05b")."""
    k = keys.shape[0]
    code = np.empty(k, np.uint64)
    for i in range(k):  # hash_eigen: seed ^= hash<int>(v) + 0x9e3779b9 + (seed << 6) + (seed >> 2)
        seed = np.uint64(0)
        for a in range(3):
            seed ^= np.uint64(keys[i, a]) + np.uint64(0x9E3779B9) + (seed << np.uint64(6)) + (seed >> np.uint64(2))
        code[i] = seed
    nxt = np.full(k, -1, np.int64)
    head = -1  # _M_before_begin._M_nxt
    nb = 1
    bucket = np.full(1, -1, np.int64)  # the node before the bucket's first: -1 none, -2 _M_before_begin
    grow = 0
    resize = 0
    for i in range(k):
        if i + 1 > resize:
            grow += 1
            nb = buckets[grow]
            resize = nb
            bucket = np.full(nb, -1, np.int64)
            p = head
            head = -1
            bbegin = np.int64(0)
            while p >= 0:
                pn = nxt[p]
                b = np.int64(code[p] % np.uint64(nb))
                if bucket[b] == -1:
                    nxt[p] = head
                    head = p
                    bucket[b] = -2
                    if nxt[p] >= 0:
                        bucket[bbegin] = p
                    bbegin = b
                else:
                    before = bucket[b]
                    if before == -2:
                        nxt[p] = head
                        head = p
                    else:
                        nxt[p] = nxt[before]
                        nxt[before] = p
                p = pn
        b = np.int64(code[i] % np.uint64(nb))
        before = bucket[b]
        if before != -1:
            if before == -2:
                nxt[i] = head
                head = i
            else:
                nxt[i] = nxt[before]
                nxt[before] = i
        else:
            nxt[i] = head
            head = i
            if nxt[i] >= 0:
                bucket[np.int64(code[nxt[i]] % np.uint64(nb))] = i
            bucket[b] = -2
    order = np.empty(k, np.int64)
    p = head
    for j in range(k):
        order[j] = p
        p = nxt[p]
    return order


@numba.njit(cache=True, nogil=True)
def _averages(sums, counts, order):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """Open3D's ``AccumulatedPoint::GetAveragePoint`` (sum / count) of each voxel, in ``order``."""
    out = np.empty((order.shape[0], 3))
    for j in range(order.shape[0]):
        v = order[j]
        c = np.float64(counts[v])
        out[j, 0] = sums[v, 0] / c
        out[j, 1] = sums[v, 1] / c
        out[j, 2] = sums[v, 2] / c
    return out


def voxel_down_points(points: np.ndarray, voxel_m: float, what: str = "the target") -> np.ndarray:
    """Open3D 0.20's ``PointCloud.voxel_down_sample(voxel_m)`` of a cloud without normals or colours,
    bit for bit and in its order, without Open3D: the points of each voxel (indices ``floor((p -
    (min - voxel / 2)) / voxel)``) averaged, the voxels listed in the order of the ``std::unordered_map``
    Open3D collects them in (:func:`_unordered_map_order`). 0.4 against 2.5 CPU ms on a 1920 x 1200
    frame's ~104k bin points.

    Parameters
    ----------
    points : (N, 3) float64 ndarray
        Finite points (C order).
    voxel_m : float
        > 0.
    what : str
        Names the cloud in the error a garbage extent raises (as :func:`voxel_down`).

    Returns
    -------
    (K, 3) float64 ndarray
    """
    p = np.ascontiguousarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputShapeError(f"points must be an (N, 3) float array, got {describe_array(p)}")
    if not voxel_m > 0:
        raise ParameterError(f"voxel_down_points: voxel_m must be > 0, got {voxel_m!r}")
    if len(p) == 0:
        return np.empty((0, 3))
    lo, hi = _bounds(p)
    extent = hi - lo
    if not np.all(np.isfinite(extent)) or float(extent.max()) / voxel_m > _MAX_VOXELS_PER_AXIS:
        raise InputShapeError(f"{what} spans {float(extent.max()):.3g} m, too large for a {voxel_m * 1000:g} mm "
                              "voxel grid: its coordinates are not those of a bin seen by a camera")
    half = np.full(3, voxel_m) * 0.5
    keys, sums, counts = _voxel_ids(p, lo - half, float(voxel_m))
    if len(keys) >= _LIBSTDCXX_BUCKETS[-1]:  # pragma: no cover - more voxels than the table follows
        return np.asarray(voxel_down(to_open3d(Points(p)), voxel_m, what).points, dtype=np.float64)
    order = _unordered_map_order(keys, np.array(_LIBSTDCXX_BUCKETS, np.int64))
    return _averages(sums, counts, order)


@dataclass(frozen=True, slots=True)
class Points:
    """A point cloud as plain arrays: what registration keeps of a cloud between calls (the frame's
    downsampled bin points, the model's downsampled copies). Open3D's ``PointCloud`` is built from it
    only where Open3D computes something (:func:`to_open3d`): importing Open3D costs ~0.3 CPU-s a
    process, and a replay whose prepared bin model comes from its cache calls none of it.

    Attributes
    ----------
    points : (N, 3) float64 ndarray
        C order (made so, without a copy when it already is).
    normals : (N, 3) float64 ndarray or None
        C order.
    """

    points: np.ndarray
    normals: np.ndarray | None = None

    def __post_init__(self) -> None:
        p = np.ascontiguousarray(self.points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise InputShapeError(f"Points.points must be an (N, 3) float array, got {describe_array(p)}")
        object.__setattr__(self, "points", p)
        if self.normals is not None:
            n = np.ascontiguousarray(self.normals, dtype=np.float64)
            if n.shape != p.shape:
                raise InputShapeError(f"Points.normals must match points {p.shape}, got {describe_array(n)}")
            object.__setattr__(self, "normals", n)

    def __len__(self) -> int:
        return len(self.points)

    def has_normals(self) -> bool:
        """Open3D's ``PointCloud.has_normals()``: normals for a non-empty cloud."""
        return self.normals is not None and len(self.points) > 0


def to_open3d(cloud: Points) -> o3d.geometry.PointCloud:
    """An Open3D ``PointCloud`` of ``cloud``'s points (and normals): the only place registration imports
    Open3D for a cloud, on the paths that run Open3D (its ICP, its voxel grid beyond
    :func:`voxel_down_points`' table, normal estimation)."""
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud.points))
    if cloud.normals is not None:
        pc.normals = o3d.utility.Vector3dVector(cloud.normals)
    return pc


def _points_of(pc: o3d.geometry.PointCloud) -> Points:
    """The arrays of an Open3D cloud (copied out of it)."""
    points = np.asarray(pc.points, dtype=np.float64).copy()
    return Points(points, np.asarray(pc.normals, dtype=np.float64).copy() if pc.has_normals() else None)


def _model_cloud(model: np.ndarray, normals: np.ndarray | None, voxel_m: float,
                 normal_radius: float) -> Points:
    """The downsampled model with unit normals (estimated when the model has none)."""
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(model, np.float64)))
    if normals is not None:
        pc.normals = o3d.utility.Vector3dVector(np.ascontiguousarray(normals, np.float64))
    if voxel_m > 0:
        pc = voxel_down(pc, voxel_m, "the bin model")
    if normals is None or not pc.has_normals():
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=normal_radius, max_nn=30))
    else:
        pc.normalize_normals()
    return _points_of(pc)


@dataclass(frozen=True, slots=True)
class IcpModel:
    """A bin model prepared for ICP with one :class:`~zcut.params.RegistrationParams` (read-only).

    Attributes
    ----------
    points : (N, 3) float64 ndarray
        The model's points (bin frame, metres).
    top_centre : ((2,) float64 ndarray, float)
        The model's (x, y) centre and top z, for :func:`initial_guess` (None for an empty model).
    fine, coarse : Points
        Downsampled at the voxel (fine pass) and twice the voxel (coarse pass), with unit normals.
    tree : scipy.spatial.cKDTree
        Over the points of ``fine``.
    params : RegistrationParams
    rim : (R, 3) float64 ndarray
        The rim points of ``fine`` (:func:`rim_points`), which :func:`pose_fitness` scores.
    up : (3,) float64 ndarray
        The model's up direction (unit vector, bin frame): the mean normal of its horizontal
        surfaces, pointing to the camera side (-z in a camera-like frame).
    fine_grid, coarse_grid : zcut.icp_fast.IcpGrid
        The points and normals of ``fine`` and ``coarse`` sorted into cells as wide as the fine and
        the coarse correspondence distance: the search structures of :func:`register_bin`'s ICP,
        built here once (a few ms) rather than by every call. Derived, not passed.
    """

    points: np.ndarray
    top_centre: tuple[np.ndarray, float] | None
    fine: Points
    coarse: Points
    tree: cKDTree
    params: RegistrationParams
    rim: np.ndarray
    up: np.ndarray
    fine_grid: IcpGrid = field(init=False, repr=False, compare=False)
    coarse_grid: IcpGrid = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        p = self.params
        object.__setattr__(self, "fine_grid", _grid_of(self.fine, p.fine_correspondence_m))
        object.__setattr__(self, "coarse_grid", _grid_of(self.coarse, p.max_correspondence_m))


def _grid_of(pc: Points, radius_m: float) -> IcpGrid:
    from .icp_fast import build_grid  # numba's kernels, loaded where used

    return build_grid(pc.points, pc.normals if pc.has_normals() else None, radius=radius_m)


def rim_points(points: np.ndarray, normals: np.ndarray, *, band_m: float = RIM_BAND_MM / 1000.0,
               max_tilt_deg: float = RIM_MAX_TILT_DEG) -> tuple[np.ndarray, np.ndarray]:
    """The rim of a bin model: its upward-facing points at the top.

    The up direction is the mean of the normals within ``max_tilt_deg`` of the frame's -z (the
    floor and the rim, whatever the normals' signs), so a camera that looked at the bin a little
    obliquely when the model was scanned tilts it accordingly. Heights are taken along it; the top
    is the 99th percentile of the upward-facing points' heights (a few stray points above the rim
    do not move it); the rim is the upward-facing points within ``band_m`` of the top.

    Parameters
    ----------
    points, normals : (N, 3) float ndarray
        The model (bin frame, up roughly -z) and its normals (unit, any sign).
    band_m : float
        Half height of the rim band (metres).
    max_tilt_deg : float
        Largest angle between an upward-facing normal and the up direction.

    Returns
    -------
    rim : (R, 3) float64 ndarray
    up : (3,) float64 ndarray
        Unit vector; (0, 0, -1) when no normal is near vertical.
    """
    p = _check_points(points, "points")
    n = np.asarray(normals, dtype=np.float64)
    if n.shape != np.asarray(points).shape:
        raise InputShapeError(f"normals must match points {np.asarray(points).shape}, got {describe_array(n)}")
    if not (band_m >= 0 and 0 < max_tilt_deg < 90):
        raise ParameterError(f"rim_points: band_m must be >= 0 and max_tilt_deg in (0, 90), "
                             f"got {band_m!r}, {max_tilt_deg!r}")
    n = n[np.isfinite(np.asarray(points)).all(axis=1)]
    cos_max = float(np.cos(np.radians(max_tilt_deg)))
    up = np.array([0.0, 0.0, -1.0])
    if len(p) == 0:
        return p, up
    aligned = n * np.where(n[:, 2] > 0, -1.0, 1.0)[:, None]  # every normal on the camera side
    horizontal = aligned[:, 2] <= -cos_max
    if horizontal.any():
        m = aligned[horizontal].mean(axis=0)
        up = m / np.linalg.norm(m)
    facing = aligned @ up >= cos_max
    if not facing.any():
        return p[:0], up
    h = p @ up
    top = float(np.percentile(h[facing], 99))
    rim = facing & (np.abs(h - top) <= band_m)
    return p[rim], up


def prepare_icp_model(model: BinModel, params: RegistrationParams, *,
                      rim_band_mm: float = RIM_BAND_MM) -> IcpModel:
    """Downsample the model (fine and coarse voxels), give it normals, index it, find its rim (once
    per replay).

    Parameters
    ----------
    model : BinModel
    params : RegistrationParams
    rim_band_mm : float
        Half height of the rim band (:func:`rim_points`).
    """
    from scipy.spatial import cKDTree

    m = model.points
    voxel = params.voxel_m
    normal_radius = max(3.0 * voxel, 2.0 * params.max_correspondence_m / 3.0)
    fine = _model_cloud(m, model.normals, voxel, normal_radius)
    coarse = _model_cloud(m, model.normals, 2.0 * voxel, 2.0 * normal_radius) if voxel > 0 else fine
    fine_points = fine.points
    tree = cKDTree(fine_points)
    rim, up = rim_points(fine_points, fine.normals if fine.normals is not None else np.empty((0, 3)),
                         band_m=rim_band_mm / 1000.0)
    return IcpModel(m, _top_and_centre(m) if len(m) else None, fine, coarse, tree, params, rim, up)


@numba.njit(cache=True, nogil=True)
def _subsampled(xyz, pixels, step):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    H, W = pixels.shape
    n = 0
    for r in range(0, H, step):
        for c in range(0, W, step):
            if pixels[r, c]:
                n += 1
    out = np.empty((n, 3))
    n = 0
    for r in range(0, H, step):
        for c in range(0, W, step):
            if pixels[r, c]:
                out[n, 0] = np.float64(xyz[r, c, 0])
                out[n, 1] = np.float64(xyz[r, c, 1])
                out[n, 2] = np.float64(xyz[r, c, 2])
                n += 1
    return out


def subsampled_points(xyz: np.ndarray, pixels: np.ndarray, *, step: int) -> np.ndarray:
    """The points of the ``pixels`` of every ``step``-th row and column, as float64: ``xyz[::step,
    ::step][pixels[::step, ::step]].astype(np.float64)`` (the same rows in the same order) in one serial pass
    (numpy's strided boolean index and cast: 2.6 CPU ms on a 1920 x 1200 frame's ring at step 2).

    Parameters
    ----------
    xyz : (H, W, 3) float ndarray
    pixels : (H, W) bool ndarray
    step : int >= 1

    Returns
    -------
    (M, 3) float64 ndarray
    """
    a, m = np.asarray(xyz), np.asarray(pixels)
    if a.ndim != 3 or a.shape[2] != 3 or m.shape != a.shape[:2] or m.dtype != np.bool_:
        raise InputShapeError(f"xyz must be an (H, W, 3) array and pixels an (H, W) bool array of its size, got "
                              f"{describe_array(a)} and {describe_array(m)}")
    if int(step) != step or step < 1:
        raise ParameterError(f"subsampled_points: step must be an integer >= 1, got {step!r}")
    if a.dtype not in (np.float32, np.float64):
        return a[::step, ::step][m[::step, ::step]].astype(np.float64)
    return _subsampled(a, m, int(step))


@dataclass(frozen=True, slots=True)
class TargetPoints:
    """A frame's bin points prepared once for :func:`register_bin` and :func:`pose_fitness`.

    Attributes
    ----------
    points : (M, 3) float64 ndarray
        The finite target points (camera frame, metres).
    cloud : Points
        Downsampled at ``voxel_m``.
    voxel_m : float
    intrinsics : Intrinsics or None
        The camera's: model rim points outside its image are out of view and not scored. None:
        every rim point is scored.
    tree : scipy.spatial.cKDTree
        Over the points of ``cloud``, built on first use (:func:`pose_fitness` searches a cell grid
        of them instead, :func:`_confirmed`, with the same answers). Derived, not passed.

    The cell grid :func:`pose_fitness` searches is built on its first call and kept for the next ones
    (a frame's seed check and its final fitness), rebuilt only when a call needs wider cells
    (:func:`_cells_for`).
    """

    points: np.ndarray
    cloud: Points
    voxel_m: float
    intrinsics: Intrinsics | None
    _tree: cKDTree | None = field(default=None, init=False, repr=False, compare=False)
    _cells: _CellGrid | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def tree(self) -> cKDTree:
        if self._tree is None:
            from scipy.spatial import cKDTree

            # an unbalanced tree without shrunk boxes builds in half the time; its nearest distances are the same
            object.__setattr__(self, "_tree", cKDTree(self.cloud.points,
                                                      balanced_tree=False, compact_nodes=False))
        assert self._tree is not None  # built above
        return self._tree


def prepare_target(target: np.ndarray, *, voxel_m: float, intrinsics: Intrinsics | None = None) -> TargetPoints:
    """Check, downsample and index a frame's bin points.

    Parameters
    ----------
    target : (M, 3) float ndarray
        The frame's bin points (camera frame, metres), e.g. ``xyz[bin_pixels(...)]``; they must
        include the rim, which the fitness looks for. Non-finite rows are dropped.
    voxel_m : float
        Downsampling voxel (0: none).
    intrinsics : Intrinsics, optional
        The camera's (the frame's), so that the fitness scores only the rim in view.

    Returns
    -------
    TargetPoints
    """
    t = _check_points(target, "target")
    if intrinsics is not None and not isinstance(intrinsics, Intrinsics):
        raise InputShapeError(f"intrinsics must be a zcut.cloud.Intrinsics or None, got {type(intrinsics).__name__}")
    cloud = Points(voxel_down_points(t, voxel_m) if voxel_m > 0 else t)
    return TargetPoints(t, cloud, float(voxel_m), intrinsics)


def register_bin(
    model: IcpModel,
    target: TargetPoints,
    *,
    params: RegistrationParams | None = None,
    init: np.ndarray | None = None,
    coarse: bool = True,
    min_points: int = 50,
    reference: bool = False,
) -> RegistrationResult:
    """ICP-register a prepared bin model to the prepared bin points of a frame.

    The frame's points are aligned to the model and the transform inverted. Runs twice, coarse
    (``params.max_correspondence_mm`` on twice the voxel) then fine (a third of it, on the voxel);
    the RMSE and ``icp_fitness`` are those of the fine pass, ``fitness`` the bin fitness of the
    final pose (:func:`pose_fitness`, at the fine correspondence distance).

    Parameters
    ----------
    model : IcpModel
        From :func:`prepare_icp_model`.
    target : TargetPoints
        From :func:`prepare_target` (downsampled at ``params.voxel_m``).
    params : RegistrationParams, optional
        Default: those the model was prepared with; others must keep its voxel and correspondence
        distance (which its structures depend on).
    init : (4, 4) float ndarray, optional
        Initial ``T_cam_bin`` (e.g. the previous frame's); default :func:`initial_guess`.
    coarse : bool
        Run the coarse pass (skip it when ``init`` is already close, e.g. the previous frame's pose).
    min_points : int
        Fewer model or target points than this after downsampling: not run, reported as failed.
    reference : bool
        Run Open3D's ``registration_icp`` (the oracle the tests hold the default to) instead of
        :func:`zcut.icp_fast.icp`, which runs the same iterations on the model's grids built once
        (``model.fine_grid``, ``model.coarse_grid``) rather than a KD-tree of the model per call:
        the same pose within ~1e-15 (Open3D's own calls differ by as much), the same iterations.

    Returns
    -------
    RegistrationResult
        ``converged`` False, with the reason, when too few points, the bin fitness is below
        ``params.min_fitness`` or the RMSE above ``params.max_rmse_mm``.
    """
    from .icp_fast import icp

    params = model.params if params is None else params
    if (params.voxel_mm, params.max_correspondence_mm) != (model.params.voxel_mm, model.params.max_correspondence_mm):
        raise ParameterError("register_bin: params must keep the voxel and correspondence distance the model was "
                             f"prepared with ({model.params.voxel_mm} mm, {model.params.max_correspondence_mm} mm)")
    if target.voxel_m != params.voxel_m:
        raise InputShapeError(f"target was prepared with voxel {target.voxel_m} m, the model with {params.voxel_m} m")
    src = target.cloud
    if init is None:
        T0 = _guess(model.top_centre, target.points)
    else:
        T0 = np.asarray(init, dtype=np.float64)
        if T0.shape != (4, 4) or not np.isfinite(T0).all():
            raise InputShapeError(f"init must be a finite (4, 4) array, got {describe_array(T0)}")
    dst = model.fine
    n_m, n_t = len(dst.points), len(src.points)
    if n_m < min_points or n_t < min_points:
        return RegistrationResult(
            T0.copy(), 0.0, float("nan"), False,
            f"too few points (model {n_m}, target {n_t}, need {min_points})", n_m, n_t, T0.copy(), 0.0, 0,
        )
    T = np.linalg.inv(T0)  # frame -> model
    passes = [(src, dst, model.fine_grid, params.fine_correspondence_m)]
    if coarse:
        if params.voxel_m <= 0:
            src_c = src
        elif reference:
            src_c = _points_of(voxel_down(to_open3d(src), 2.0 * params.voxel_m, "the target"))
        else:  # Open3D's voxel grid, bit for bit and in its order (voxel_down_points)
            src_c = Points(voxel_down_points(src.points, 2.0 * params.voxel_m))
        passes.insert(0, (src_c, model.coarse, model.coarse_grid, params.max_correspondence_m))
    point_to_plane = params.method == "point_to_plane"
    iterations = []
    fit = inlier_rmse = 0.0
    for s_pc, d_pc, grid, dist in passes:
        if reference:
            fit, inlier_rmse, T = _open3d_pass(s_pc, d_pc, dist, T, point_to_plane, int(params.max_iterations))
            iterations.append(-1)
        else:
            out = icp(s_pc.points, grid, max_distance=dist, init=T, point_to_plane=point_to_plane,
                      max_iteration=int(params.max_iterations))
            fit, inlier_rmse, T = out.fitness, out.inlier_rmse, out.transformation
            iterations.append(out.iterations)
    T_cam_bin = np.linalg.inv(T)
    icp_fitness = float(fit)
    rmse = float(inlier_rmse) if icp_fitness > 0 else float("nan")
    fitness, n_rim = _rim_fitness(model, target, T_cam_bin, params.fine_correspondence_m)
    reasons = []
    if n_rim == 0:
        reasons.append("no rim point of the model in the camera's view")
    if fitness < params.min_fitness:
        reasons.append(f"fitness {fitness:.3f} < {params.min_fitness:g} (the share of the bin's rim the frame "
                       f"confirms within {params.fine_correspondence_m * 1000:.1f} mm)")
    if not (rmse <= params.max_rmse_m):
        reasons.append(f"RMSE {rmse * 1000:.2f} mm > {params.max_rmse_mm:g} mm")
    return RegistrationResult(T_cam_bin, fitness, rmse, not reasons, "; ".join(reasons), n_m, n_t, T0.copy(),
                              icp_fitness, n_rim, tuple(iterations))


def _open3d_pass(src: Points, dst: Points, dist: float, T: np.ndarray,
                 point_to_plane: bool, max_iterations: int) -> tuple[float, float, np.ndarray]:
    """One ICP pass by Open3D's ``registration_icp``: (fitness, inlier RMSE, source -> target)."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    est: o3d.pipelines.registration.TransformationEstimation
    est = reg.TransformationEstimationPointToPlane() if point_to_plane else reg.TransformationEstimationPointToPoint()
    r = reg.registration_icp(to_open3d(src), to_open3d(dst), dist, T, est, reg.ICPConvergenceCriteria(max_iteration=max_iterations))
    return float(r.fitness), float(r.inlier_rmse), np.asarray(r.transformation, dtype=np.float64).copy()


def _in_view(points: np.ndarray, K: Intrinsics) -> np.ndarray:
    """(N,) bool: camera-frame points in front of the camera that project inside its image."""
    z = points[:, 2]
    front = z > 0
    zs = np.where(front, z, 1.0)
    u = K.fx * points[:, 0] / zs + K.cx
    v = K.fy * points[:, 1] / zs + K.cy
    return front & (u >= -0.5) & (u < K.width - 0.5) & (v >= -0.5) & (v < K.height - 0.5)


def _rim_reach(model: IcpModel, target: TargetPoints, T_cam_bin: np.ndarray,
               max_distance_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The rim of ``model`` placed at ``T_cam_bin``, those of its points :func:`pose_fitness` scores (in the
    camera's view when the target has intrinsics) and each one's reach: ``(rim (R, 3), reach (R,))``."""
    rim = transform_points(T_cam_bin, model.rim)
    K = target.intrinsics
    if K is None:
        return rim, np.full(len(rim), max_distance_m)
    # the rim in view (_in_view) and, since a frame sampled coarser than the distance cannot confirm
    # it, each point's reach: the distance or PIXEL_REACH pixel footprints at its depth
    out: tuple[np.ndarray, np.ndarray] = _rim_in_view(rim, float(K.fx), float(K.fy), float(K.cx), float(K.cy),
                                                      float(K.width), float(K.height), float(max_distance_m),
                                                      min(K.fx, K.fy))
    return out


def _rim_fitness(model: IcpModel, target: TargetPoints, T_cam_bin: np.ndarray,
                 max_distance_m: float) -> tuple[float, int]:
    """(bin fitness, rim points scored) of a pose; see :func:`pose_fitness`."""
    rim, reach = _rim_reach(model, target, T_cam_bin, max_distance_m)
    if len(rim) == 0:
        return 0.0, 0
    pts = target.cloud.points
    if len(pts) == 0:
        return 0.0, len(rim)
    # cKDTree(pts).query(rim, k=1, distance_upper_bound=reach.max()) and d <= reach, counted (_confirmed)
    ub = float(reach.max())
    cells = _cells_for(target, ub)
    return float(_confirmed_in(np.ascontiguousarray(rim), reach, ub, pts, *cells)) / len(rim), len(rim)


def _least_count(n: int, fitness: float) -> int:
    """The least count k in 0..n with ``float(k) / n >= fitness`` (the bin fitness of k confirmed rim points of
    n, as :func:`_rim_fitness` divides), n + 1 when none (``fitness`` above 1, or NaN). ``n`` >= 1."""
    if math.isnan(fitness) or fitness > 1.0:
        return n + 1
    if fitness <= 0.0:
        return 0
    k = min(max(int(math.ceil(fitness * n)), 0), n)  # within one of the answer: the product rounds
    while k > 0 and float(k - 1) / n >= fitness:
        k -= 1
    while k <= n and not float(k) / n >= fitness:
        k += 1
    return k


def _finite_pose(T_cam_bin: np.ndarray) -> np.ndarray:
    """``T_cam_bin`` as a (4, 4) float64 array; a one-line error when it is not a finite one."""
    T = np.asarray(T_cam_bin, dtype=np.float64)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise InputShapeError(f"T_cam_bin must be a finite (4, 4) array, got {describe_array(T)}")
    return T


def pose_fitness_at_least(model: IcpModel, target: TargetPoints, T_cam_bin: np.ndarray, *,
                          max_correspondence_m: float, fitness: float) -> bool:
    """``pose_fitness(model, target, T_cam_bin, max_correspondence_m=...) >= fitness``, exactly, counting the rim
    points only until the answer is decided: as soon as enough of them are confirmed, or too many are not
    (:func:`_confirmed_reaches`). The pipeline asks it whether the seed pose still holds on a frame
    (``replay.pipeline.stages.locate_bin``): on a moved bin a third of the rim settles it, and the rim points
    the frame does not confirm are those whose search reads all 27 cells around them.

    Parameters
    ----------
    model : IcpModel
    target : TargetPoints
    T_cam_bin : (4, 4) float ndarray
    max_correspondence_m : float
    fitness : float
        The bin fitness asked for.

    Returns
    -------
    bool
    """
    T = _finite_pose(T_cam_bin)
    want = float(fitness)
    rim, reach = _rim_reach(model, target, T, float(max_correspondence_m))
    pts = target.cloud.points
    if len(rim) == 0 or len(pts) == 0:
        return 0.0 >= want  # pose_fitness is 0 there
    need = _least_count(len(rim), want)
    if need == 0 or need > len(rim):
        return need == 0
    ub = float(reach.max())
    cells = _cells_for(target, ub)  # the grid the final fitness reuses, as pose_fitness keeps it
    return bool(_confirmed_reaches(np.ascontiguousarray(rim), reach, ub, pts, *cells, need))


@numba.njit(cache=True, nogil=True)
def _rim_in_view(rim, fx, fy, cx, cy, width, height, max_distance, f_min):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """``(rim[_in_view(rim, K)], np.maximum(max_distance, PIXEL_REACH * z / f_min))`` of those rows, in one
    pass and in :func:`_in_view`'s and that expression's float64 operations (the same bits)."""
    n = rim.shape[0]
    keep = np.empty(n, np.int64)
    k = 0
    for i in range(n):
        z = rim[i, 2]
        front = z > 0
        zs = z if front else 1.0
        u = fx * rim[i, 0] / zs + cx
        v = fy * rim[i, 1] / zs + cy
        if front and u >= -0.5 and u < width - 0.5 and v >= -0.5 and v < height - 0.5:
            keep[k] = i
            k += 1
    out = np.empty((k, 3))
    reach = np.empty(k)
    for j in range(k):
        i = keep[j]
        out[j, 0], out[j, 1], out[j, 2] = rim[i, 0], rim[i, 1], rim[i, 2]
        r = PIXEL_REACH * rim[i, 2] / f_min
        reach[j] = r if r > max_distance else max_distance
    return out, reach


#: A cell grid of a target's points (:func:`_cell_grid`): (cell width, origin, table, keys, start, members).
_CellGrid = tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
#: The kept grid's cells are this much wider than the first call needs, so that the next call's reach (a
#: pose a little deeper) usually fits them; wider cells change no count, only the points a search reads.
_CELL_HEADROOM = 1.02


def _cells_for(target: TargetPoints, ub: float) -> _CellGrid:
    """The target's cell grid (:attr:`TargetPoints._cells`) with cells at least ``ub (1 + 1e-6)`` wide:
    the kept one, or a new one kept instead."""
    cells = target._cells
    if cells is None or not cells[0] >= ub * (1.0 + 1e-6):
        cells = (ub * (1.0 + 1e-6) * _CELL_HEADROOM, *_cell_grid(target.cloud.points, ub * (1.0 + 1e-6) * _CELL_HEADROOM))
        object.__setattr__(target, "_cells", cells)
    return cells


def _confirmed(rim: np.ndarray, reach: np.ndarray, ub: float, pts: np.ndarray) -> int:
    """How many rim points have a nearest point of ``pts`` within their ``reach``, as cKDTree answers
    ``query(rim, k=1, distance_upper_bound=ub)`` and ``d <= reach`` counts it (``ub`` >= every reach):
    :func:`_confirmed_in` on a grid of cells ``ub (1 + 1e-6)`` wide."""
    cell = ub * (1.0 + 1e-6)
    return int(_confirmed_in(rim, reach, ub, pts, cell, *_cell_grid(pts, cell)))


@numba.njit(cache=True, nogil=True)
def _cell_grid(pts, cell):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """``pts`` (M >= 1, 3) in a hashed grid of cells ``cell`` wide from their least coordinates:
    ``(origin (3,), table, keys (K, 3), start (K + 1,), members (M,))``, the points of cell ``table[slot]``
    (:func:`_find_slot`) being ``members[start[j]:start[j + 1]]``, in point order."""
    m = pts.shape[0]
    ox, oy, oz = pts[0, 0], pts[0, 1], pts[0, 2]
    for i in range(m):
        ox = min(ox, pts[i, 0])
        oy = min(oy, pts[i, 1])
        oz = min(oz, pts[i, 2])
    size = 16
    while size < 2 * m:
        size *= 2
    table = np.full(size, -1, np.int64)
    keys = np.empty((m, 3), np.int64)
    cell_of = np.empty(m, np.int64)
    counts = np.zeros(m + 1, np.int64)
    k = 0
    for i in range(m):
        ix = np.int64(math.floor((pts[i, 0] - ox) / cell))
        iy = np.int64(math.floor((pts[i, 1] - oy) / cell))
        iz = np.int64(math.floor((pts[i, 2] - oz) / cell))
        slot = _find_slot(table, keys, ix, iy, iz)
        j = table[slot]
        if j < 0:
            table[slot] = k
            keys[k, 0], keys[k, 1], keys[k, 2] = ix, iy, iz
            j = k
            k += 1
        cell_of[i] = j
        counts[j + 1] += 1
    for j in range(k):
        counts[j + 1] += counts[j]
    fill = counts[:k].copy()
    members = np.empty(m, np.int64)
    for i in range(m):
        members[fill[cell_of[i]]] = i
        fill[cell_of[i]] += 1
    origin = np.empty(3)
    origin[0], origin[1], origin[2] = ox, oy, oz
    return origin, table, keys, counts, members


@numba.njit(cache=True, nogil=True, inline="always")
def _rim_point_confirmed(x, y, z, rr, ub2, ox, oy, oz, pts, cell, table, keys, counts, members):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """Has the rim point (x, y, z) a point of ``pts`` with d2 < ``ub2`` and sqrt(d2) <= ``rr``? The search of
    :func:`_confirmed_in` for one point (its own grid cell first, then the other 26; the first such point
    ends it)."""
    fx = math.floor((x - ox) / cell)
    fy = math.floor((y - oy) / cell)
    fz = math.floor((z - oz) / cell)
    if not (-2.0 < fx < 2.0**62 and -2.0 < fy < 2.0**62 and -2.0 < fz < 2.0**62):
        return False  # no cell of the points within reach
    cx, cy, cz = np.int64(fx), np.int64(fy), np.int64(fz)
    for t in range(27):
        # the own cell first (t = 0 is offset (0, 0, 0)), then the other 26
        ax = cx + (t // 9 + 1) % 3 - 1
        ay = cy + (t // 3 + 1) % 3 - 1
        az = cz + (t + 1) % 3 - 1
        j = table[_find_slot(table, keys, ax, ay, az)]
        if j < 0:
            continue
        for q in range(counts[j], counts[j + 1]):
            p = members[q]
            dx = x - pts[p, 0]
            dy = y - pts[p, 1]
            dz = z - pts[p, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 < ub2 and math.sqrt(d2) <= rr:
                return True
    return False


@numba.njit(cache=True, nogil=True)
def _confirmed_in(rim, reach, ub, pts, cell, origin, table, keys, counts, members):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """:func:`_confirmed` in a grid of ``pts`` (:func:`_cell_grid`) with cells ``cell`` >= ``ub (1 + 1e-6)``
    wide.

    cKDTree keeps a point whose squared distance, summed (dx² + dy²) + dz², is below ub²; d is the
    square root of the least. So a rim point counts iff some point has d2 < ub² and sqrt(d2) <= its
    reach (the least d2 then does too): the search stops at the first such point, its own grid cell
    first (where it usually is), in cells at least ``ub`` wide (hashed: a frame's bin spans ~10^6 of
    them); the margin of 1e-6 keeps rounding in (x - origin) / cell from putting a point within ub two
    cells away. Any such width gives the same count (:func:`_rim_point_confirmed`)."""
    ox, oy, oz = origin[0], origin[1], origin[2]
    ub2 = ub * ub
    n = 0
    for r in range(rim.shape[0]):
        if _rim_point_confirmed(rim[r, 0], rim[r, 1], rim[r, 2], reach[r], ub2, ox, oy, oz, pts, cell, table, keys,
                                counts, members):
            n += 1
    return n


@numba.njit(cache=True, nogil=True)
def _confirmed_reaches(rim, reach, ub, pts, cell, origin, table, keys, counts, members, need):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """``_confirmed_in(rim, ...) >= need`` (1 <= ``need`` <= len(rim)), the rim points searched in the same
    order until the answer is decided: ``need`` confirmed (True), or more than ``len(rim) - need`` not (False)."""
    ox, oy, oz = origin[0], origin[1], origin[2]
    ub2 = ub * ub
    spare = rim.shape[0] - need  # the rim points that may go unconfirmed
    n = 0
    for r in range(rim.shape[0]):
        if _rim_point_confirmed(rim[r, 0], rim[r, 1], rim[r, 2], reach[r], ub2, ox, oy, oz, pts, cell, table, keys,
                                counts, members):
            n += 1
            if n >= need:
                return True
        elif r + 1 - n > spare:
            return False
    return n >= need


def pose_fitness(model: IcpModel, target: TargetPoints, T_cam_bin: np.ndarray, *,
                 max_correspondence_m: float) -> float:
    """The bin fitness of a given pose, without running ICP.

    The model's rim (:attr:`IcpModel.rim`) is placed at ``T_cam_bin``; of its points in the
    camera's view (all of them when the target has no intrinsics), the fraction with a point of the
    target's downsampled cloud within ``max_correspondence_m`` (or, with intrinsics, within
    :data:`PIXEL_REACH` pixel footprints at the point's depth when that is more). 0 when no rim
    point is in view or the target is empty. This is :attr:`RegistrationResult.fitness` at that
    pose; the pipeline uses it to decide whether the seed pose still holds (a static bin).

    Parameters
    ----------
    model : IcpModel
    target : TargetPoints
    T_cam_bin : (4, 4) float ndarray
    max_correspondence_m : float

    Returns
    -------
    float in [0, 1]
    """
    T = _finite_pose(T_cam_bin)
    return _rim_fitness(model, target, T, float(max_correspondence_m))[0]
