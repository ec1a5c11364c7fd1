"""A ray-traced structured-light sensor for the synthetic scans (``zcut synth --sensor raytraced``).

Where the hand-made generator (:mod:`replay.synth`) places every outlier by hand, this one makes
them with optics: a pinhole camera and projector with a baseline, triangle meshes of the six part
kinds, the bin and the table with a material each, a pile dropped by a rigid-body simulation, and
per pixel the light of every path (direct, specular bounces on either side, lens glare) decoded as
a phase-shifting sensor does. Truth comes from geometry. Modules: ``meshes``, ``materials``,
``pile`` (MuJoCo), ``scene`` (Open3D ``RaycastingScene``), ``optics`` (the sensor), ``synthesize``
(one frame and its truth), ``log`` (MCAP logs). What it assumes and what it says:
``docs/raytraced.md``.
"""

from replay.synth.raytrace.log import RAYTRACE_VERSION, write_raytraced_log
from replay.synth.raytrace.optics import SensorModel
from replay.synth.raytrace.synthesize import RaytracedFrame, synthesize_raytraced_frame

__all__ = ["RAYTRACE_VERSION", "RaytracedFrame", "SensorModel", "synthesize_raytraced_frame", "write_raytraced_log"]
