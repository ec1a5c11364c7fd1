"""The exact bin model of the synthetic scenes: the bin's surfaces sampled, in the bin frame.

The generator knows its bin (:class:`replay.presets.BinGeometry`, the height field of
:func:`replay.synth.scene.bin_height_field`): a flat rim ring at ``height_mm``, inner walls drafted by
``draft_deg`` down to a flat floor ``floor_mm`` above the table. :func:`bin_model_points` samples
those surfaces on a regular grid (rim and floor) and along the walls (in height and along the
outline), with their normals, in the frame a bin model lives in (``docs/formats.md``, "Bin model
attachment"): the camera optical frame with the bin at its nominal pose (centred below the camera,
yaw 0; :func:`replay.synth.synthesize.T_cam_bin`), metres, up = -z. Every synthetic log carries it as
its ``bin_model.ply`` attachment (:func:`bin_model_ply`), so a synthetic log replays with its bin
stages without a ``--bin-model``.
"""

from __future__ import annotations

import numpy as np

from replay.presets import BIN, BinGeometry
from replay.synth.sensor import CAMERA_HEIGHT_MM

#: Distance between neighbouring model points (mm): below the registration's 3 mm voxel.
MODEL_SPACING_MM = 2.0


def _axis(lo: float, hi: float, step: float) -> np.ndarray:
    n = max(int(np.floor((hi - lo) / step)) + 1, 1)
    return lo + step * np.arange(n)


def bin_model_points(geometry: BinGeometry = BIN, *,
                     spacing_mm: float = MODEL_SPACING_MM) -> tuple[np.ndarray, np.ndarray]:
    """Points and normals of the bin surfaces a camera above it sees (rim top, inner walls, floor).

    Returns
    -------
    points : (N, 3) float64 ndarray
        Metres, bin frame (camera optical frame at the nominal pose: x right, y down, z forward = down).
    normals : (N, 3) float64 ndarray
        Unit normals pointing out of the material into the bin's opening (towards the camera).
    """
    g = geometry
    s = float(spacing_mm)
    ox, oy = g.outer_length_mm / 2, g.outer_width_mm / 2
    ix, iy = g.inner_top_half
    fx, fy = g.floor_half
    t = np.tan(np.radians(g.draft_deg))
    pts, nrm = [], []

    # rim top: the ring between the outer edge and the inner top edge
    X, Y = np.meshgrid(_axis(-ox, ox, s), _axis(-oy, oy, s))
    ring = (np.abs(X) >= ix) | (np.abs(Y) >= iy)
    pts.append(np.column_stack([X[ring], Y[ring], np.full(int(ring.sum()), g.height_mm)]))
    nrm.append(np.tile([0.0, 0.0, 1.0], (int(ring.sum()), 1)))

    # floor
    X, Y = np.meshgrid(_axis(-fx, fx, s), _axis(-fy, fy, s))
    pts.append(np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, g.floor_mm)]))
    nrm.append(np.tile([0.0, 0.0, 1.0], (X.size, 1)))

    # inner walls: at height z the opening is |x| <= fx + (z - floor) t, |y| <= fy + (z - floor) t
    dz = s * np.cos(np.radians(g.draft_deg))  # spacing s along the slope
    for z in _axis(g.floor_mm + dz / 2, g.height_mm, dz):
        hx, hy = fx + (z - g.floor_mm) * t, fy + (z - g.floor_mm) * t
        along_y, along_x = _axis(-hy, hy, s), _axis(-hx, hx, s)
        n = 1.0 / np.hypot(1.0, t)
        for sign in (1.0, -1.0):
            pts.append(np.column_stack([np.full(len(along_y), sign * hx), along_y, np.full(len(along_y), z)]))
            nrm.append(np.tile([-sign * n, 0.0, t * n], (len(along_y), 1)))
            pts.append(np.column_stack([along_x, np.full(len(along_x), sign * hy), np.full(len(along_x), z)]))
            nrm.append(np.tile([0.0, -sign * n, t * n], (len(along_x), 1)))

    world = np.concatenate(pts)
    nw = np.concatenate(nrm)
    # world (x, y, z up, mm; table at z = 0) -> bin frame: the camera at height h looking down
    points = np.column_stack([world[:, 0], -world[:, 1], CAMERA_HEIGHT_MM - world[:, 2]]) / 1000.0
    normals = np.column_stack([nw[:, 0], -nw[:, 1], -nw[:, 2]])
    return points, normals


def bin_model_ply(geometry: BinGeometry = BIN, *, spacing_mm: float = MODEL_SPACING_MM) -> bytes:
    """:func:`bin_model_points` as the PLY bytes of a log's ``bin_model.ply`` attachment."""
    from replay.logs.ply import ply_model_bytes

    points, normals = bin_model_points(geometry, spacing_mm=spacing_mm)
    return ply_model_bytes(points, normals)
