"""A hand-made zinc nut seen as a sliver past an occluding box, ray cast (test helper of the sliver fits)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent / "fits"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from explained_helpers import box_mesh  # noqa: E402
from fit_scenes import K_TEST, hex_nut_mesh, pose, render, rotation  # noqa: E402
from prepared_models import prepared  # noqa: E402

from zcut.fits import PartModel  # noqa: E402

FLOOR_Z = 400.0
FX, FY, CX, CY = K_TEST


def nut() -> tuple[np.ndarray, np.ndarray, PartModel]:
    """(vertices, triangles, prepared model) of the hand-made zinc nut (the session's model,
    tests/zcut/fits/prepared_models.py: the fits tests prepare the same nut)."""
    v, t = hex_nut_mesh()
    return v, t, prepared(v, t)


def true_pose() -> np.ndarray:
    return pose(rotation((0.3, 1.0, 0.2), 35.0) @ rotation((1.0, 0.0, 0.0), 20.0), (4.0, 2.0, 370.0))


def occluded_scene(nut: tuple[np.ndarray, np.ndarray, PartModel], hide: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xyz, the nut's visible pixels, all its pixels unoccluded) of the nut at :func:`true_pose` on a floor, a
    box in front of it (z 330-335 mm) hiding the ``hide`` share of its image width from the left."""
    v, t, _ = nut
    T = true_pose()
    _, ids = render([(v, t, T)], floor_z_mm=FLOOR_Z)
    cols = np.flatnonzero((ids == 1).any(axis=0))
    edge_px = cols[0] + hide * (cols[-1] - cols[0])
    x_edge = (edge_px - CX) / FX * 330.0  # the box's right side, at its front face's depth
    box = box_mesh(np.array([-200.0, -200.0, 330.0]), np.array([x_edge, 200.0, 335.0]))
    xyz, ids2 = render([(v, t, T), (*box, np.eye(4))], floor_z_mm=FLOOR_Z)
    return xyz, ids2 == 1, ids == 1
