"""Register a bin model to the bin points of a frame with Open3D ICP (paper §5.2, ``pcregistericp``).

The model is an (N, 3) float64 point set in its own frame ("bin"); the result is ``T_cam_bin``, the
4 x 4 transform taking model points into the camera frame. A registration whose fitness or RMSE is
out of bounds is returned with ``converged=False`` and the reason, never silently accepted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InputShapeError, ParameterError, describe_array

METHODS = ("point_to_point", "point_to_plane")


@dataclass(frozen=True, slots=True)
class RegistrationResult:
    """Outcome of one ICP registration.

    Attributes
    ----------
    T_cam_bin : (4, 4) float64 ndarray
        Model (bin) frame -> camera frame. The initial guess when the registration failed early.
    fitness : float
        Fraction of the frame's (downsampled) bin points with a model point within the final
        correspondence distance (Open3D's ``fitness``); 0 when not run.
    inlier_rmse : float
        RMSE of those correspondences in metres; NaN when not run.
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
    """

    T_cam_bin: np.ndarray
    fitness: float
    inlier_rmse: float
    converged: bool
    reason: str
    n_model: int
    n_target: int
    T_init: np.ndarray


def _check_points(p: np.ndarray, name: str) -> np.ndarray:
    a = np.asarray(p)
    if a.ndim != 2 or a.shape[1] != 3 or not np.issubdtype(a.dtype, np.floating):
        raise InputShapeError(f"{name} must be an (N, 3) float array, got {describe_array(a)}")
    a = a[np.isfinite(a).all(axis=1)]
    return np.ascontiguousarray(a, dtype=np.float64)


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4 x 4 transform to (N, 3) points; returns (N, 3) float64."""
    p = np.asarray(points, dtype=np.float64)
    return p @ T[:3, :3].T + T[:3, 3]


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
    m = _model_points(model)
    t = _check_points(target, "target")
    T = np.eye(4)
    if len(m) == 0 or len(t) == 0:
        return T
    mc, mtop = _top_and_centre(m, cache=True)
    tc, ttop = _top_and_centre(t, cache=False)
    T[:2, 3] = tc - mc
    T[2, 3] = ttop - mtop
    return T


_STATS: dict[int, tuple[np.ndarray, tuple[np.ndarray, float]]] = {}
_MODELS: dict[int, np.ndarray] = {}


def _top_and_centre(p: np.ndarray, *, cache: bool) -> tuple[np.ndarray, float]:
    """(x, y) centre of the 1..99 % bounding box and the 1st percentile of z (the top)."""
    hit = _STATS.get(id(p)) if cache else None
    if hit is not None and hit[0] is p:
        return hit[1]
    lo = np.percentile(p, 1, axis=0)
    hi = np.percentile(p[:, :2], 99, axis=0)
    out = (0.5 * (lo[:2] + hi), float(lo[2]))
    if cache:
        if len(_STATS) >= 4:
            _STATS.pop(next(iter(_STATS)))
        _STATS[id(p)] = (p, out)
    return out


def _model_points(model: np.ndarray) -> np.ndarray:
    """The model as a finite (N, 3) float64 array, checked once per array (models are reused)."""
    if isinstance(model, np.ndarray) and _MODELS.get(id(model)) is model:
        return model
    m = _check_points(model, "model")
    if m.shape[0] != np.shape(model)[0]:
        raise InputShapeError("model must not contain non-finite points")
    if isinstance(model, np.ndarray) and model.dtype == np.float64 and model.flags.c_contiguous:
        if len(_MODELS) >= 4:
            _MODELS.pop(next(iter(_MODELS)))
        _MODELS[id(model)] = model
        return model
    return m


def _cloud(points: np.ndarray, voxel_m: float):
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    if voxel_m > 0:
        pc = pc.voxel_down_sample(voxel_m)
    return pc


_TARGET: list = []  # [(target array, voxel_m, checked points, downsampled cloud)]: the last target


def _target_cloud(target: np.ndarray, voxel_m: float):
    """(checked points, downsampled cloud) of a frame's target; the last one is kept, so that
    :func:`pose_fitness` and :func:`register_bin` on the same array downsample it once."""
    if _TARGET and _TARGET[0][0] is target and _TARGET[0][1] == voxel_m:
        return _TARGET[0][2], _TARGET[0][3]
    t = _check_points(target, "target")
    pc = _cloud(t, voxel_m)
    _TARGET[:] = [(target, voxel_m, t, pc)]
    return t, pc


_MODEL_CLOUDS: dict[tuple[int, float], tuple[np.ndarray, object]] = {}
_MODEL_TREES: dict[int, tuple[object, object]] = {}


def _model_tree(pc):
    """A scipy KD-tree of a (cached) model cloud's points, built once per cloud."""
    from scipy.spatial import cKDTree

    hit = _MODEL_TREES.get(id(pc))
    if hit is not None and hit[0] is pc:
        return hit[1]
    tree = cKDTree(np.asarray(pc.points, dtype=np.float64))
    if len(_MODEL_TREES) >= 4:
        _MODEL_TREES.pop(next(iter(_MODEL_TREES)))
    _MODEL_TREES[id(pc)] = (pc, tree)
    return tree


def _model_cloud(model: np.ndarray, normals: np.ndarray | None, voxel_m: float, normal_radius: float):
    """The downsampled model with normals, built once per (model array, voxel)."""
    import open3d as o3d

    key = (id(model), float(voxel_m))
    hit = _MODEL_CLOUDS.get(key)
    if hit is not None and hit[0] is model:
        return hit[1]
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(model, np.float64)))
    if normals is not None:
        pc.normals = o3d.utility.Vector3dVector(np.ascontiguousarray(normals, np.float64))
    if voxel_m > 0:
        pc = pc.voxel_down_sample(voxel_m)
    if normals is None or not pc.has_normals():
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=normal_radius, max_nn=30))
    else:
        pc.normalize_normals()
    if len(_MODEL_CLOUDS) >= 4:
        _MODEL_CLOUDS.pop(next(iter(_MODEL_CLOUDS)))
    _MODEL_CLOUDS[key] = (model, pc)
    return pc


def register_bin(
    model: np.ndarray,
    target: np.ndarray,
    *,
    model_normals: np.ndarray | None = None,
    init: np.ndarray | None = None,
    method: str = "point_to_plane",
    voxel_m: float = 0.003,
    max_correspondence_m: float = 0.01,
    max_iterations: int = 30,
    min_fitness: float = 0.3,
    max_rmse_m: float = 0.005,
    min_points: int = 50,
    coarse: bool = True,
) -> RegistrationResult:
    """ICP-register a bin model to the bin points of a frame.

    The frame's points are aligned to the model (whose downsampled copy and normals are built once
    per model array and reused frame after frame) and the transform inverted. Runs twice, coarse
    (``max_correspondence_m``) then fine (a third of it), on voxel-downsampled copies; fitness and
    RMSE are those of the fine pass.

    Parameters
    ----------
    model : (N, 3) float ndarray
        Bin model points in the bin frame, metres. Pass the same array every frame (the cache
        is keyed on it).
    target : (M, 3) float ndarray
        Bin points of the frame (camera frame, metres); non-finite rows are dropped.
    model_normals : (N, 3) float ndarray, optional
        Normals of the model (estimated when absent).
    init : (4, 4) float ndarray, optional
        Initial ``T_cam_bin`` (e.g. the previous frame's); default :func:`initial_guess`.
    method : {"point_to_plane", "point_to_point"}
    voxel_m : float
        Voxel size of the downsampling (0: none).
    max_correspondence_m : float
        Correspondence distance of the coarse pass.
    max_iterations : int
        Per pass.
    min_fitness, max_rmse_m : float
        Bounds for ``converged``.
    min_points : int
        Fewer model or target points than this after downsampling: not run, reported as failed.
    coarse : bool
        Run the coarse pass (skip it when ``init`` is already close, e.g. the previous frame's pose).

    Returns
    -------
    RegistrationResult
        ``fitness``: the fraction of the frame's (downsampled) bin points with a model point
        within the fine correspondence distance.
    """
    import open3d as o3d

    if method not in METHODS:
        raise ParameterError(f"method must be one of {METHODS}, got {method!r}")
    for name, v in (("voxel_m", voxel_m), ("max_correspondence_m", max_correspondence_m)):
        if not (np.isfinite(v) and v >= 0):
            raise ParameterError(f"{name} must be a non-negative number, got {v!r}")
    if max_correspondence_m <= 0:
        raise ParameterError(f"max_correspondence_m must be > 0, got {max_correspondence_m!r}")
    if int(max_iterations) != max_iterations or max_iterations < 1:
        raise ParameterError(f"max_iterations must be a positive integer, got {max_iterations!r}")
    m = _model_points(model)
    if model_normals is not None and np.shape(model_normals) != np.shape(m):
        raise InputShapeError(f"model_normals must match model {np.shape(m)}, got {describe_array(model_normals)}")
    t, src = _target_cloud(target, voxel_m)
    if init is None:
        T0 = initial_guess(m, t)
    else:
        T0 = np.asarray(init, dtype=np.float64)
        if T0.shape != (4, 4) or not np.isfinite(T0).all():
            raise InputShapeError(f"init must be a finite (4, 4) array, got {describe_array(T0)}")
    normal_radius = max(3.0 * voxel_m, 2.0 * max_correspondence_m / 3.0)
    dst = _model_cloud(m, model_normals, voxel_m, normal_radius)
    n_m, n_t = len(dst.points), len(src.points)
    # the coarse pass runs on twice the voxel (a quarter of the points); the fine pass on voxel_m
    coarse_voxel = 2.0 * voxel_m
    src_c = src.voxel_down_sample(coarse_voxel) if (coarse and voxel_m > 0) else src
    dst_c = _model_cloud(m, model_normals, coarse_voxel, 2.0 * normal_radius) if (coarse and voxel_m > 0) else dst
    if n_m < min_points or n_t < min_points:
        return RegistrationResult(
            T0.copy(), 0.0, float("nan"), False,
            f"too few points (model {n_m}, target {n_t}, need {min_points})", n_m, n_t, T0.copy(),
        )
    if method == "point_to_plane":
        est = o3d.pipelines.registration.TransformationEstimationPointToPlane()
    else:
        est = o3d.pipelines.registration.TransformationEstimationPointToPoint()
    crit = o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=int(max_iterations))
    T = np.linalg.inv(T0)  # frame -> model
    reg = None
    passes = [(src, dst, max_correspondence_m / 3.0)]
    if coarse:
        passes.insert(0, (src_c, dst_c, max_correspondence_m))
    for s_pc, d_pc, dist in passes:
        reg = o3d.pipelines.registration.registration_icp(s_pc, d_pc, dist, T, est, crit)
        T = np.asarray(reg.transformation, dtype=np.float64).copy()
    assert reg is not None
    T_cam_bin = np.linalg.inv(T)
    fitness = float(reg.fitness)
    rmse = float(reg.inlier_rmse) if fitness > 0 else float("nan")
    reasons = []
    if fitness < min_fitness:
        reasons.append(f"fitness {fitness:.3f} < {min_fitness:g}")
    if not (rmse <= max_rmse_m):
        reasons.append(f"RMSE {rmse * 1000:.2f} mm > {max_rmse_m * 1000:g} mm")
    return RegistrationResult(T_cam_bin, fitness, rmse, not reasons, "; ".join(reasons), n_m, n_t, T0.copy())


def pose_fitness(
    model: np.ndarray,
    target: np.ndarray,
    T_cam_bin: np.ndarray,
    *,
    model_normals: np.ndarray | None = None,
    voxel_m: float = 0.003,
    max_correspondence_m: float = 0.01,
) -> float:
    """Fitness of a given pose without running ICP (one nearest-neighbour pass).

    The fraction of the frame's (downsampled) bin points with a model point within
    ``max_correspondence_m`` once the model is placed at ``T_cam_bin``; 0 without target points.
    Used to decide whether the previous frame's pose is still close (a static bin).

    Parameters
    ----------
    model : (N, 3) float ndarray
    target : (M, 3) float ndarray
    T_cam_bin : (4, 4) float ndarray
    model_normals, voxel_m, max_correspondence_m
        As for :func:`register_bin` (the same model cache is used).
    """
    T = np.asarray(T_cam_bin, dtype=np.float64)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise InputShapeError(f"T_cam_bin must be a finite (4, 4) array, got {describe_array(T)}")
    m = _model_points(model)
    t, src = _target_cloud(target, voxel_m)
    if len(t) == 0 or len(m) == 0:
        return 0.0
    dst = _model_cloud(m, model_normals, voxel_m, max(3.0 * voxel_m, 2.0 * max_correspondence_m / 3.0))
    # Open3D's evaluate_registration, with the model's KD-tree built once instead of every call
    p = transform_points(np.linalg.inv(T), np.asarray(src.points))
    if len(p) == 0:
        return 0.0
    d, _ = _model_tree(dst).query(p, k=1, distance_upper_bound=max_correspondence_m, workers=-1)
    return float(np.count_nonzero(d <= max_correspondence_m)) / len(p)
