"""A synthetic scene's true surfaces as the fits of ``zcut.explained`` (the part instances, bin, table).

Built as the generators build their truth (:mod:`replay.synth.surfaces`): the hand-made parts'
exact solids (:func:`replay.synth.surfaces.solid_meshes`; a ball as the 5,120-face icosphere of
:func:`replay.synth.surfaces.kind_model_mesh`, within 0.008 mm of it), the ray-traced parts' own
meshes, the bin's CAD mesh at the scan's pose, the table top as the plane z = camera height. Used
by ``tests/zcut/test_explained.py`` and ``bench/bench_explained.py``: the check that the method's
rule and the paper's truth are one definition; :func:`box_mesh` by the explained tests.
"""

from __future__ import annotations

import numpy as np

from replay.presets import BIN
from replay.synth.raytrace.meshes import bin_mesh, part_mesh
from replay.synth.raytrace.synthesize import RaytracedFrame
from replay.synth.scene import BinPose
from replay.synth.sensor import CAMERA_HEIGHT_MM
from replay.synth.surfaces import kind_model_mesh, solid_meshes
from replay.synth.synthesize import SynthFrame, bin_pose_for, frame_rng
from zcut.explained import KnownSurfaces, Plane

_D = np.diag([1.0, -1.0, -1.0])  # world -> camera axes (replay.synth.raytrace.scene)


def _cam(v: np.ndarray) -> np.ndarray:
    return np.asarray(v, np.float64) @ _D.T + np.array([0.0, 0.0, CAMERA_HEIGHT_MM])


def _table() -> Plane:
    return Plane(np.array([0.0, 0.0, 1.0]), CAMERA_HEIGHT_MM)


def handmade_true_surfaces(sf: SynthFrame) -> tuple[list[tuple[np.ndarray, np.ndarray]], KnownSurfaces]:
    """(the part meshes in the camera frame, KnownSurfaces without residuals) of a hand-made frame
    whose bin is not deformed."""
    scene = sf.scene
    parts: list[tuple[np.ndarray, np.ndarray]] = []
    prisms = [p for p in scene.parts if p.solid is not None and p.solid[0][0][0] != "sphere"]
    balls = [p for p in scene.parts if p.solid is not None and p.solid[0][0][0] == "sphere"]
    for part, (v, t) in zip(prisms, solid_meshes([p.solid for p in prisms])):  # type: ignore[misc]
        parts.append((_cam(v @ part.R.T + part.centre_mm), t))
    if balls:
        v0, t0 = kind_model_mesh("spheres")
        for part in balls:
            parts.append((_cam(v0 @ part.R.T + part.centre_mm), t0))
    m = bin_mesh(scene.bin_pose, scene.deformation.geometry(BIN))
    return parts, KnownSurfaces(parts=parts, part_err_mm=[float("nan")] * len(parts),
                                bin_mesh=(_cam(m.vertices), m.triangles), table=_table())


def raytraced_true_surfaces(rf: RaytracedFrame, *, seed: int, index: int) -> tuple[list[tuple[np.ndarray, np.ndarray]],
                                                                                    KnownSurfaces]:
    """The same for a ray-traced frame of log ``seed`` (its bin pose drawn as the generator draws it)."""
    pose: BinPose = bin_pose_for(frame_rng(seed, index, empty=False), empty=False, index=index)
    parts: list[tuple[np.ndarray, np.ndarray]] = []
    if rf.pile is not None:
        local = part_mesh(rf.pile.kind)
        for i in range(len(rf.pile)):
            m = local.transformed(rf.pile.R[i], rf.pile.t_mm[i])
            parts.append((_cam(m.vertices), m.triangles))
    b = bin_mesh(pose, BIN)
    return parts, KnownSurfaces(parts=parts, part_err_mm=[float("nan")] * len(parts),
                                bin_mesh=(_cam(b.vertices), b.triangles), table=_table())


def box_mesh(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A closed axis-aligned box mesh (vertices, outward triangles)."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    v = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                  [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], float)
    t = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
                  [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])
    return v, t
