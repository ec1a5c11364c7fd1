"""Register a bin model to the bin points of a frame with Open3D ICP (paper §5.2, ``pcregistericp``).

The model is a :class:`~zcut.bin_model.BinModel` (an (N, 3) float64 point set in its own frame,
"bin"), prepared once per replay (:func:`prepare_icp_model`: downsampled copies with normals and a
KD-tree); the frame's bin points are prepared once per frame (:func:`prepare_target`). The result is
``T_cam_bin``, the 4 x 4 transform taking model points into the camera frame. A registration whose
fitness or RMSE is out of bounds is returned with ``converged=False`` and the reason, never
silently accepted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .bin_model import BinModel
from .errors import InputShapeError, ParameterError, describe_array
from .params import RegistrationParams

__all__ = [
    "IcpModel",
    "RegistrationResult",
    "TargetPoints",
    "initial_guess",
    "pose_fitness",
    "prepare_icp_model",
    "prepare_target",
    "register_bin",
    "transform_points",
]


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


def _top_and_centre(p: np.ndarray) -> tuple[np.ndarray, float]:
    """(x, y) centre of the 1..99 % bounding box and the 1st percentile of z (the top)."""
    lo = np.percentile(p, 1, axis=0)
    hi = np.percentile(p[:, :2], 99, axis=0)
    return 0.5 * (lo[:2] + hi), float(lo[2])


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


def _cloud(points: np.ndarray, voxel_m: float):
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    if voxel_m > 0:
        pc = pc.voxel_down_sample(voxel_m)
    return pc


def _model_cloud(model: np.ndarray, normals: np.ndarray | None, voxel_m: float, normal_radius: float):
    """The downsampled model with unit normals (estimated when the model has none)."""
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(model, np.float64)))
    if normals is not None:
        pc.normals = o3d.utility.Vector3dVector(np.ascontiguousarray(normals, np.float64))
    if voxel_m > 0:
        pc = pc.voxel_down_sample(voxel_m)
    if normals is None or not pc.has_normals():
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=normal_radius, max_nn=30))
    else:
        pc.normalize_normals()
    return pc


@dataclass(frozen=True, slots=True)
class IcpModel:
    """A bin model prepared for ICP with one :class:`~zcut.params.RegistrationParams` (read-only).

    Attributes
    ----------
    points : (N, 3) float64 ndarray
        The model's points (bin frame, metres).
    top_centre : ((2,) float64 ndarray, float)
        The model's (x, y) centre and top z, for :func:`initial_guess`.
    fine, coarse : open3d.geometry.PointCloud
        Downsampled at the voxel (fine pass) and twice the voxel (coarse pass), with unit normals.
    tree : scipy.spatial.cKDTree
        Over the points of ``fine``, for :func:`pose_fitness`.
    params : RegistrationParams
    """

    points: np.ndarray
    top_centre: tuple[np.ndarray, float]
    fine: object
    coarse: object
    tree: object
    params: RegistrationParams


def prepare_icp_model(model: BinModel, params: RegistrationParams) -> IcpModel:
    """Downsample the model (fine and coarse voxels), give it normals, index it (once per replay)."""
    from scipy.spatial import cKDTree

    m = model.points
    voxel = params.voxel_m
    normal_radius = max(3.0 * voxel, 2.0 * params.max_correspondence_m / 3.0)
    fine = _model_cloud(m, model.normals, voxel, normal_radius)
    coarse = _model_cloud(m, model.normals, 2.0 * voxel, 2.0 * normal_radius) if voxel > 0 else fine
    tree = cKDTree(np.asarray(fine.points, dtype=np.float64))
    return IcpModel(m, _top_and_centre(m) if len(m) else None, fine, coarse, tree, params)


@dataclass(frozen=True, slots=True)
class TargetPoints:
    """A frame's bin points prepared once for :func:`register_bin` and :func:`pose_fitness`.

    Attributes
    ----------
    points : (M, 3) float64 ndarray
        The finite target points (camera frame, metres).
    cloud : open3d.geometry.PointCloud
        Downsampled at ``voxel_m``.
    voxel_m : float
    """

    points: np.ndarray
    cloud: object
    voxel_m: float


def prepare_target(target: np.ndarray, *, voxel_m: float) -> TargetPoints:
    """Check and downsample a frame's bin points: (M, 3) float array, non-finite rows dropped."""
    t = _check_points(target, "target")
    return TargetPoints(t, _cloud(t, voxel_m), float(voxel_m))


def register_bin(
    model: IcpModel,
    target: TargetPoints,
    *,
    params: RegistrationParams | None = None,
    init: np.ndarray | None = None,
    coarse: bool = True,
    min_points: int = 50,
) -> RegistrationResult:
    """ICP-register a prepared bin model to the prepared bin points of a frame.

    The frame's points are aligned to the model and the transform inverted. Runs twice, coarse
    (``params.max_correspondence_mm`` on twice the voxel) then fine (a third of it, on the voxel);
    fitness and RMSE are those of the fine pass.

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

    Returns
    -------
    RegistrationResult
        ``fitness``: the fraction of the frame's (downsampled) bin points with a model point
        within the fine correspondence distance.
    """
    import open3d as o3d

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
            f"too few points (model {n_m}, target {n_t}, need {min_points})", n_m, n_t, T0.copy(),
        )
    if params.method == "point_to_plane":
        est = o3d.pipelines.registration.TransformationEstimationPointToPlane()
    else:
        est = o3d.pipelines.registration.TransformationEstimationPointToPoint()
    crit = o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=int(params.max_iterations))
    T = np.linalg.inv(T0)  # frame -> model
    reg = None
    passes = [(src, dst, params.fine_correspondence_m)]
    if coarse:
        src_c = src.voxel_down_sample(2.0 * params.voxel_m) if params.voxel_m > 0 else src
        passes.insert(0, (src_c, model.coarse, params.max_correspondence_m))
    for s_pc, d_pc, dist in passes:
        reg = o3d.pipelines.registration.registration_icp(s_pc, d_pc, dist, T, est, crit)
        T = np.asarray(reg.transformation, dtype=np.float64).copy()
    assert reg is not None
    T_cam_bin = np.linalg.inv(T)
    fitness = float(reg.fitness)
    rmse = float(reg.inlier_rmse) if fitness > 0 else float("nan")
    reasons = []
    if fitness < params.min_fitness:
        reasons.append(f"fitness {fitness:.3f} < {params.min_fitness:g}")
    if not (rmse <= params.max_rmse_m):
        reasons.append(f"RMSE {rmse * 1000:.2f} mm > {params.max_rmse_mm:g} mm")
    return RegistrationResult(T_cam_bin, fitness, rmse, not reasons, "; ".join(reasons), n_m, n_t, T0.copy())


def pose_fitness(model: IcpModel, target: TargetPoints, T_cam_bin: np.ndarray, *,
                 max_correspondence_m: float) -> float:
    """Fitness of a given pose without running ICP (one nearest-neighbour pass).

    The fraction of the frame's (downsampled) bin points with a model point within
    ``max_correspondence_m`` once the model is placed at ``T_cam_bin`` (Open3D's
    ``evaluate_registration``, with the model's KD-tree built once); 0 without target points. Used
    to decide whether the previous frame's pose is still close (a static bin).

    Parameters
    ----------
    model : IcpModel
    target : TargetPoints
    T_cam_bin : (4, 4) float ndarray
    max_correspondence_m : float
    """
    T = np.asarray(T_cam_bin, dtype=np.float64)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise InputShapeError(f"T_cam_bin must be a finite (4, 4) array, got {describe_array(T)}")
    p = transform_points(np.linalg.inv(T), np.asarray(target.cloud.points))
    if len(p) == 0 or len(model.points) == 0:
        return 0.0
    d, _ = model.tree.query(p, k=1, distance_upper_bound=max_correspondence_m, workers=-1)
    return float(np.count_nonzero(d <= max_correspondence_m)) / len(p)
