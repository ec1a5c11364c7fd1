"""Ray-traced synthetic logs: the hand-made generator's layout, made by :mod:`.synthesize`.

The same topics as ``replay.synth.log`` (cloud, colour image, camera info, truth mask, kind codes,
true depth), the same ``zcut.synth`` and ``zcut.synth.poses`` metadata records (the bin poses are
the hand-made generator's for the same seed), the same ``bin_model.ply`` attachment (the bin both
generators draw), the ray-traced part's mesh as ``part_model.ply``, ``/ground_truth/off_surface``
(the paper's truth) and kind codes 5-8. Same arguments, same bytes.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from replay.logs import layout
from replay.logs.writer import LogWriter
from replay.presets import PART_KINDS
from replay.synth.log import part_model_attachment, pose_metadata, synth_metadata
from replay.synth.raytrace.camera_filters import CameraFilters
from replay.synth.raytrace.optics import SensorModel, kept_memory
from replay.synth.raytrace.pile import WALL_TILT_DEG, WALL_TILT_S
from replay.synth.raytrace.synthesize import FILL_RANGE_MM, MAX_PARTS, RaytracedFrame, synthesize_raytraced_frame
from replay.synth.sensor import FULL_SIZE
from replay.synth.synthesize import check_pile_for
from zcut.errors import ParameterError

RAYTRACE_VERSION = "2"  # 2: /ground_truth/off_surface and part_model.ply
ProgressFn = Callable[[int, int, RaytracedFrame, float], None]
#: entries of the hand-made generator's metadata that describe its hand-placed outliers
_HANDMADE_ONLY = ("ghost_clusters_per_frame", "ghost_rho_range", "above_rim_groups_per_frame",
                  "figure11_patches_per_frame", "max_obliquity_deg", "shiny_noise_factor", "quantize_mm")


def raytraced_metadata(*, kind: str, seed: int, frames: int, size: tuple[int, int], empty: bool,
                       model: SensorModel, pile: str = "floor",
                       camera_filters: CameraFilters | None = None) -> dict[str, str]:
    """The ``zcut.synth`` record of a ray-traced log (all values strings).

    With the camera's own filters on, ``camera_filters`` says which ran and their thresholds, and
    ``camera_filter_*`` holds each threshold (``off`` for a filter that did not run); without them
    the record has none of these keys (the log is the bytes it was before the option).
    """
    shiny = False if empty else PART_KINDS[kind].shiny
    meta = synth_metadata(kind=kind, seed=seed, frames=frames, size=size, shiny=shiny, empty=empty, pile=pile)
    for key in _HANDMADE_ONLY:
        meta.pop(key, None)
    meta.update({
        "generator": "zcut replay.synth.raytrace",
        "generator_version": RAYTRACE_VERSION,
        "sensor": "raytraced",
        "outlier_kinds": ",".join(f"{c}={n}" for c, n in sorted(layout.OUTLIER_KINDS.items()) if c >= 5),
        "depth_topic": layout.TRUTH_DEPTH,
        "truth_rule": f"noise-free decoded depth farther than {model.outlier_sigmas:g} noise sigmas from every "
                      "surface the pixel's footprint sees",
        "off_surface_rule": "farther than 3 Err from every triangle of the scene; Err = sqrt(sigma^2 + (z/f)^2/2)",
        "pile": "MuJoCo rigid-body drop" + (
            f", against the walls (gravity tilted {WALL_TILT_DEG:g} deg towards them for {WALL_TILT_S:g} s)"
            if pile == "walls" else ""),
        "fill_range_mm": f"{FILL_RANGE_MM[0]:g}-{FILL_RANGE_MM[1]:g}",
        "max_parts": str(MAX_PARTS),
        **{f"sensor_{k}": repr(getattr(model, k)) for k in model.__dataclass_fields__},
    })
    if pile == "walls":
        meta["pile_tilt_deg"] = f"{WALL_TILT_DEG:g}"
    if camera_filters is not None and camera_filters.enabled:
        meta["camera_filters"] = camera_filters.describe()
        for name in ("noise_snr", "reflection_sigmas", "outlier_mm"):
            v = getattr(camera_filters, name)
            meta[f"camera_filter_{name}"] = "off" if v is None else f"{v:g}"
    return meta


def write_raytraced_log(
    path: str | os.PathLike[str],
    *,
    kind: str = "spheres",
    frames: int = 1,
    seed: int = 0,
    size: tuple[int, int] = FULL_SIZE,
    empty: bool = False,
    fill_mm: float | None = None,
    model: SensorModel | None = None,
    progress: ProgressFn | None = None,
    bag_name: str | None = None,
    pile: str = "floor",
    camera_filters: CameraFilters | None = None,
) -> Path:
    """Ray-trace ``frames`` scans and write them as a ROS 2 MCAP log (see ``replay.synth.write_synthetic_log``).

    ``fill_mm``: mean pile height (default: drawn per frame from ``FILL_RANGE_MM``). ``bag_name``:
    the file name the ``rosbag2`` record names (default: the name of ``path``; ``zcut synth``
    passes the final name of the file it writes through a temporary one). ``pile``: ``walls`` leans
    the parts on one wall or a corner (:func:`.synthesize.synthesize_raytraced_frame`).
    ``camera_filters``: the camera's own filters (:mod:`.camera_filters`), recorded in the metadata;
    None (default): none, and the log is byte for byte what it was before the option.
    """
    if not empty and kind not in PART_KINDS:
        raise ParameterError(f"kind must be one of {', '.join(PART_KINDS)}, got {kind!r}")
    if int(frames) != frames or frames < 1:
        raise ParameterError(f"frames must be a positive integer, got {frames!r}")
    check_pile_for(pile, empty=empty)
    model = SensorModel() if model is None else model
    meta = raytraced_metadata(kind=kind, seed=seed, frames=int(frames), size=size, empty=empty, model=model, pile=pile,
                              camera_filters=camera_filters)
    poses = pose_metadata(seed=seed, frames=int(frames), empty=empty)
    path = Path(path)
    from replay.synth.bin_surface import bin_model_ply

    # the exact bin model travels with the log (docs/formats.md, "Bin model attachment")
    attached = {layout.BIN_MODEL_ATTACHMENT: (layout.BIN_MODEL_MEDIA_TYPE, bin_model_ply())}
    if not empty:  # the part's mesh, as the scene draws it ("Part model attachment")
        attached.update(part_model_attachment(kind, raytraced=True))
    with LogWriter(path, metadata={layout.SYNTH_METADATA: meta, layout.SYNTH_POSES_METADATA: poses},
                   attachments=attached, bag_name=bag_name) as writer, kept_memory():
        # the frames reuse each other's freed memory (optics.kept_memory): no page faults after the first
        for i in range(int(frames)):
            t0 = time.perf_counter()
            rf = synthesize_raytraced_frame(kind=kind, seed=seed, index=i, size=size, empty=empty,
                                            fill_mm=fill_mm, model=model, pile=pile, camera_filters=camera_filters)
            f = rf.frame
            writer.write_frame(f)
            for topic, codes in f.codes.items():
                writer.write_codes(topic, codes, stamp_ns=f.stamp_ns, frame_id=f.frame_id)
            writer.write_depth(layout.TRUTH_DEPTH, rf.depth_true_m.astype(np.float32), stamp_ns=f.stamp_ns,
                               frame_id=f.frame_id)
            if progress is not None:
                progress(i, int(frames), rf, time.perf_counter() - t0)
    return path
