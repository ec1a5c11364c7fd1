"""How far a fitted pose is from a true one, modulo the part's symmetries (for tests and benchmarks)."""

from __future__ import annotations

import math

import numpy as np

from .model import PartModel, _angle_deg

__all__ = ["pose_error"]


def pose_error(T_fit: np.ndarray, T_true: np.ndarray, model: PartModel) -> tuple[float, float]:
    """(translation error mm, rotation error degrees) of ``T_fit`` against ``T_true``.

    The translation error is the distance between the model's centroid under both poses; the
    rotation error the smallest angle of R_trueᵀ R_fit S over the model's symmetry rotations S
    (about the centroid). A body of revolution (``continuous_axis``) compares only where the axis
    goes (the angle between the posed axes, either sign when a symmetry flips it); a sphere has no
    rotation error.
    """
    c = model.centroid
    dt = float(np.linalg.norm((T_fit[:3, :3] @ c + T_fit[:3, 3]) - (T_true[:3, :3] @ c + T_true[:3, 3])))
    if model.sphere_radius is not None:
        return dt, 0.0
    Rf, Rt = T_fit[:3, :3], T_true[:3, :3]
    if model.continuous_axis is not None:
        a = model.continuous_axis
        best = np.inf
        for S in model.symmetries:
            cosang = float(np.clip((Rf @ S @ a) @ (Rt @ a), -1.0, 1.0))
            best = min(best, math.degrees(math.acos(cosang)))  # the C library's, not NumPy's SIMD kernel
        return dt, best
    return dt, min(_angle_deg(Rt.T @ Rf @ S) for S in model.symmetries)
