"""Synthetic logs in the docs/formats.md layout, and the bundled sample the demo replays.

A synthetic log holds, per frame and all with the same header stamp: the organized cloud with
``rgba`` on ``/camera/points``, the colour image on ``/camera/image``, ``/camera/camera_info``, the
exact outliers on ``/ground_truth/outliers`` (mono8, 255 = outlier) and their kinds on
``/ground_truth/outlier_kind`` (mono8, docs/formats.md codes), and the true depth on
``/ground_truth/depth`` (32FC1, metres). The MCAP metadata record ``zcut.synth``
describes how it was made (part kind, seed, finish, camera distance, bin geometry, size, ...), and
``zcut.synth.poses`` holds every frame's true bin pose (:func:`replay.logs.poses.true_poses` reads it
back). The log carries the generator's exact bin model as its ``bin_model.ply`` attachment
(:mod:`replay.synth.bin_surface`; ``docs/formats.md``, "Bin model attachment") and the part's mesh
as its ``part_model.ply`` attachment (millimetres; "Part model attachment"). The paper's truth, the
points farther than 3 × Err from every true surface, is on ``/ground_truth/off_surface`` (mono8;
:mod:`replay.synth.surfaces`). The same arguments give the same bytes.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from replay.logs import layout
from replay.logs.poses import true_poses as true_poses  # moved: see replay/logs/poses.py
from replay.logs.writer import LogWriter
from replay.presets import BIN, PART_KINDS
from replay.synth import outliers as out
from replay.synth.parts import face_area_px
from replay.synth.scene import WALL_TILT_DEG, BinShape, bin_mesh_mm, lean_walls
from replay.synth.sensor import (
    CAMERA_HEIGHT_MM,
    FULL_SIZE,
    MAX_OBLIQUITY_DEG,
    NOISE_CORRELATION_PX,
    NOISE_MM_AT_500,
    PROJECTOR_BASELINE_MM,
    SHINY_NOISE_FACTOR,
    default_intrinsics,
)
from replay.synth.synthesize import (
    SynthFrame,
    camera_distance_m,
    check_pile_for,
    check_quantize,
    frame_pose,
    pile_distance_m,
    stamp_ns,
    synthesize_frame,
)
from zcut.errors import ParameterError

#: Version of the hand-made generator's output; it names the demo sample's cache file, so a change
#: of what a log holds (3: ``/ground_truth/depth``; 4: ``/ground_truth/off_surface`` and the
#: ``part_model.ply`` attachment) makes stale samples be generated anew.
GENERATOR_VERSION = "4"

#: The sample the demo replays: three frames of M16 rods (the paper's Figures 13 and 14 show rods)
#: at half the sensor's resolution, so that synthesising and replaying it take seconds.
SAMPLE_KIND = "rods"
SAMPLE_SEED = 2024
SAMPLE_FRAMES = 3
SAMPLE_SIZE = (600, 960)

ProgressFn = Callable[[int, int, SynthFrame, float], None]


def synth_metadata(
    *, kind: str, seed: int, frames: int, size: tuple[int, int], shiny: bool, empty: bool, quantize_mm: float = 0.0,
    bin_shape: BinShape = BinShape(),
    pile: str = "floor",
) -> dict[str, str]:
    """The ``zcut.synth`` metadata record (all values strings); a bin that is not the nominal one adds
    ``bin_scale``, ``bin_bulge_mm`` and ``bin_deform_mm``, a pile against the walls ``pile`` and
    ``pile_walls`` (the walls of each frame, ``;``-separated)."""
    K = default_intrinsics(size)
    rates = out.SHINY_RATES if shiny else out.MATTE_RATES
    meta = {
        "generator": "zcut replay.synth",
        "generator_version": GENERATOR_VERSION,
        "part_kind": "empty" if empty else kind,
        "seed": str(int(seed)),
        "frames": str(int(frames)),
        "empty": "true" if empty else "false",
        "shiny": "true" if shiny else "false",
        "width": str(K.width),
        "height": str(K.height),
        "size": f"{K.width}x{K.height}",
        "fx": repr(float(K.fx)),
        "fy": repr(float(K.fy)),
        "cx": repr(float(K.cx)),
        "cy": repr(float(K.cy)),
        "camera_distance_m": f"{camera_distance_m():.3f}",
        "camera_height_m": f"{CAMERA_HEIGHT_MM / 1000:.3f}",
        "pile_distance_m": f"{pile_distance_m():.3f}",
        "projector_baseline_m": f"{PROJECTOR_BASELINE_MM / 1000:.3f}",
        "max_obliquity_deg": f"{MAX_OBLIQUITY_DEG:g}",
        "noise_mm_at_0.5m": f"{NOISE_MM_AT_500:g}",
        "shiny_noise_factor": f"{SHINY_NOISE_FACTOR:g}",
        "noise_correlation_px": f"{NOISE_CORRELATION_PX:g}",
        "quantize_mm": f"{quantize_mm:g}",
        "ghost_clusters_per_frame": f"{rates.clusters:g}",
        "ghost_rho_range": f"{rates.cluster_rho[0]:g}-{rates.cluster_rho[1]:g}",
        "above_rim_groups_per_frame": f"{rates.above_rim:g}",
        "figure11_patches_per_frame": f"{rates.figure11:g}",
        "truth_topic": layout.TRUTH_OUTLIERS,
        "outlier_kind_topic": layout.TRUTH_OUTLIER_KIND,
        "off_surface_topic": layout.TRUTH_OFF_SURFACE,
        "off_surface_rule": "farther than 3 Err from every true surface; Err = sqrt(sigma^2 + c^2/2 + q^2/12), "
                            "c = max(z/f, height-field step)",
        "outlier_kinds": ",".join(f"{code}={name}" for code, name in sorted(layout.HANDMADE_OUTLIER_KINDS.items())),
        "poses_metadata": layout.SYNTH_POSES_METADATA,
        "bin_frame": "camera optical frame with the bin at its nominal pose (centred below the camera, yaw 0)",
        **BIN.as_metadata(),
    }
    if not bin_shape.nominal:
        meta.update({"bin_scale": f"{bin_shape.scale:g}", "bin_bulge_mm": f"{bin_shape.bulge_mm:g}",
                     "bin_deform_mm": f"{bin_shape.deform_mm:g}"})
    if pile != "floor":
        meta.update({"pile": pile, "pile_tilt_deg": f"{WALL_TILT_DEG:g}",
                     "pile_walls": ";".join(",".join(lean_walls(seed, i)) for i in range(int(frames)))})
    if not empty:
        part = PART_KINDS[kind]
        meta.update(
            {
                "part_label": part.label,
                "p_min_mm": f"{part.p_min_mm:g}",
                "face_area_mm2": f"{part.face_area_mm2:.3f}",
                "a_max_px": f"{face_area_px(part, fx=K.fx, fy=K.fy, distance_m=pile_distance_m()):.1f}",
            }
        )
    return meta


def pose_metadata(*, seed: int, frames: int, empty: bool) -> dict[str, str]:
    """The ``zcut.synth.poses`` record: ``str(stamp_ns)`` -> the 16 floats of ``T_cam_bin``, row-major."""
    return {
        str(stamp_ns(seed, i)): ",".join(repr(float(v)) for v in frame_pose(seed, i, empty=empty).ravel())
        for i in range(int(frames))
    }


def _write_frame(writer: LogWriter, sf: SynthFrame) -> None:
    """The frame's cloud, image, camera info and truth mask, then its code images
    (``/ground_truth/outlier_kind``) and its true depth (``/ground_truth/depth``: the real surface's
    camera z before noise and outliers, metres, NaN where the ray hits nothing), all stamped like
    the cloud."""
    f = sf.frame
    writer.write_frame(f)
    for topic, codes in f.codes.items():
        writer.write_codes(topic, codes, stamp_ns=f.stamp_ns, frame_id=f.frame_id)
    depth_m = np.where(np.isfinite(sf.surface_depth_mm), sf.surface_depth_mm / np.float32(1000.0), np.float32(np.nan))
    writer.write_depth(layout.TRUTH_DEPTH, depth_m.astype(np.float32), stamp_ns=f.stamp_ns, frame_id=f.frame_id)


def write_synthetic_log(
    path: str | os.PathLike[str],
    *,
    kind: str = "spheres",
    frames: int = 1,
    seed: int = 0,
    size: tuple[int, int] = FULL_SIZE,
    empty: bool = False,
    shiny: bool | None = None,
    quantize_mm: float = 0.0,
    progress: ProgressFn | None = None,
    bin_shape: BinShape = BinShape(),
    bag_name: str | None = None,
    pile: str = "floor",
) -> Path:
    """Synthesise ``frames`` scans and write them as a ROS 2 MCAP log.

    Parameters
    ----------
    path : str or PathLike
        Output ``.mcap`` (replaced if it exists).
    kind : str
        Key of :data:`PART_KINDS`; ignored for ``empty``.
    frames : int
        Number of scans (each a new pile, bin pose jittered; for ``empty`` the 5-position series
        repeats every 5 frames).
    seed : int
    size : (height, width)
    empty : bool
        Empty-bin scans (to build the bin model, paper §5.1).
    shiny : bool or None
        Override the kind's finish.
    quantize_mm : float
        Depth step of a quantizing sensor (e.g. 1 or 2 mm, as consumer stereo and ToF cameras
        give); 0 (default) = continuous depth.
    progress : callable or None
        Called as ``progress(index, frames, synth_frame, seconds)`` after each frame is written.
    bin_shape : BinShape
        A bin that is not the nominal one (scaled, bulging, deforming from scan to scan), see
        :func:`replay.synth.synthesize.synthesize_frame`; the nominal bin is what
        :func:`write_bin_cad` writes.
    bag_name : str or None
        The file name the ``rosbag2`` record names (default: the name of ``path``); ``zcut synth``
        passes the final name of the file it writes through a temporary one, so that the same
        arguments give the same bytes.
    pile : {"floor", "walls"}
        ``walls``: the parts lean on one wall or a corner of each frame's bin (see
        :func:`replay.synth.synthesize.synthesize_frame`).

    Returns
    -------
    Path of the written log.
    """
    if not empty and kind not in PART_KINDS:
        raise ParameterError(f"kind must be one of {', '.join(PART_KINDS)}, got {kind!r}")
    if int(frames) != frames or frames < 1:
        raise ParameterError(f"frames must be a positive integer, got {frames!r}")
    q = check_quantize(quantize_mm)
    check_pile_for(pile, empty=empty, bin_shape=bin_shape)
    is_shiny = (False if empty else PART_KINDS[kind].shiny) if shiny is None else bool(shiny)
    meta = synth_metadata(kind=kind, seed=seed, frames=int(frames), size=size, shiny=is_shiny, empty=empty,
                          quantize_mm=q, bin_shape=bin_shape, pile=pile)
    poses = pose_metadata(seed=seed, frames=int(frames), empty=empty)
    path = Path(path)
    from replay.synth.bin_surface import bin_model_ply

    # the exact bin model travels with the log: replayed without --bin-model, it runs the bin stages;
    # and so does the part's mesh (docs/formats.md, "Part model attachment")
    model = {layout.BIN_MODEL_ATTACHMENT: (layout.BIN_MODEL_MEDIA_TYPE, bin_model_ply())}
    if not empty:
        model.update(part_model_attachment(kind))
    with LogWriter(path, metadata={layout.SYNTH_METADATA: meta, layout.SYNTH_POSES_METADATA: poses},
                   attachments=model, bag_name=bag_name) as writer:
        for i in range(int(frames)):
            t0 = time.perf_counter()
            sf = synthesize_frame(kind=kind, seed=seed, index=i, size=size, shiny=shiny, empty=empty, quantize_mm=q,
                                  bin_shape=bin_shape, pile=pile)
            _write_frame(writer, sf)
            if progress is not None:
                progress(i, int(frames), sf, time.perf_counter() - t0)
    return path


def part_model_attachment(kind: str, *, raytraced: bool = False) -> dict[str, tuple[str, bytes]]:
    """The ``part_model.ply`` attachment of a log of ``kind`` parts: the hand-made generator's part
    (:func:`replay.synth.surfaces.kind_model_mesh`, its random phases at 0) or the ray-traced one's
    (:func:`replay.synth.raytrace.meshes.part_mesh`), millimetres, the part's local frame."""
    from replay.logs.part_model import PART_MODEL_ATTACHMENT, PART_MODEL_MEDIA_TYPE, part_model_ply_bytes

    if raytraced:
        from replay.synth.raytrace.meshes import part_mesh

        m = part_mesh(kind)
        v, t, who = m.vertices, m.triangles, "zcut replay.synth.raytrace"
    else:
        from replay.synth.surfaces import kind_model_mesh

        v, t = kind_model_mesh(kind)
        who = "zcut replay.synth (hand-made; each part turned by its own random phase about its axis)"
    data = part_model_ply_bytes(v, t, unit="mm", comment=f"{kind}: {who}, part frame")
    return {PART_MODEL_ATTACHMENT: (PART_MODEL_MEDIA_TYPE, data)}


def write_bin_cad(path: str | os.PathLike[str]) -> Path:
    """Write the nominal synthetic bin as a CAD mesh PLY, in the bin frame of the synthetic logs.

    The bin frame is the camera optical frame with the bin at its nominal pose (metres, up = -z, see
    :func:`replay.synth.synthesize.T_cam_bin`), which is what ``zcut bin-model --model PLY`` takes:
    a model made from it registers to the true poses a synthetic log carries. It has no noise and
    the nominal size, as a bin's CAD file has; a log made with a :class:`BinShape` differs from it.
    """
    from plyfile import PlyData, PlyElement

    v_mm, faces = bin_mesh_mm(BIN)
    xyz = np.column_stack([v_mm[:, 0], -v_mm[:, 1], CAMERA_HEIGHT_MM - v_mm[:, 2]]) / 1000.0
    vertex = np.empty(len(xyz), dtype=[("x", "f8"), ("y", "f8"), ("z", "f8")])
    vertex["x"], vertex["y"], vertex["z"] = xyz.T
    face = np.empty(len(faces), dtype=[("vertex_indices", "i4", (3,))])
    face["vertex_indices"] = faces
    path = Path(path)
    PlyData([PlyElement.describe(vertex, "vertex"), PlyElement.describe(face, "face")],
            comments=["zcut synthetic bin, nominal (CAD): bin frame, metres, up = -z"]).write(str(path))
    return path


def sample_log_path() -> Path:
    """Where the demo's sample log lives: ``$ZCUT_CACHE`` or ``$XDG_CACHE_HOME/zcut`` or ``~/.cache/zcut``.

    The file name carries the sample's parameters and the generator version, so a changed
    generator never reuses a stale sample.
    """
    root = os.environ.get("ZCUT_CACHE")
    if root:
        base = Path(root)
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "zcut"
    h, w = SAMPLE_SIZE
    return base / f"sample_{SAMPLE_KIND}_seed{SAMPLE_SEED}_{SAMPLE_FRAMES}x{w}x{h}_v{GENERATOR_VERSION}.mcap"


def ensure_sample_log(path: str | os.PathLike[str] | None = None, *, progress: ProgressFn | None = None) -> Path:
    """Return the sample log, synthesising it first if it does not exist.

    It is written in a private temporary folder and renamed into place, so an interrupted run
    never leaves a partial sample behind.
    """
    target = Path(path) if path is not None else sample_log_path()
    if target.is_file():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    # a private folder, same file name (the name is recorded inside the log), then an atomic rename
    tmp_dir = target.parent / f".{target.name}.tmp{os.getpid()}"
    tmp_dir.mkdir(exist_ok=True)
    tmp = tmp_dir / target.name
    try:
        write_synthetic_log(
            tmp, kind=SAMPLE_KIND, frames=SAMPLE_FRAMES, seed=SAMPLE_SEED, size=SAMPLE_SIZE, progress=progress
        )
        os.replace(tmp, target)
    finally:
        if tmp.exists():
            tmp.unlink()
        tmp_dir.rmdir()
    return target


def ensure_sample_bin_model(*, progress: ProgressFn | None = None) -> Path:
    """The bin model of the demo's sample: built once from a synthetic empty-bin log, then cached.

    Five empty-bin scans (the paper's five positions, §4) at the sample's size are synthesised
    next to the sample log, turned into a model (:func:`replay.pipeline.bin_model.build_bin_model`)
    and saved as PLY; an interrupted run leaves no partial file behind.

    Parameters
    ----------
    progress : callable, optional
        Passed to :func:`write_synthetic_log`.
    """
    from replay.logs.reader import LogReader
    from replay.pipeline.bin_model import build_bin_model, save_bin_model

    h, w = SAMPLE_SIZE
    base = sample_log_path().parent
    target = base / f"sample_bin_model_seed{SAMPLE_SEED}_{w}x{h}_v{GENERATOR_VERSION}.ply"
    if target.is_file():
        return target
    base.mkdir(parents=True, exist_ok=True)
    empty = base / f".sample_empty_{os.getpid()}.mcap"
    tmp = base / f".{target.stem}.tmp{os.getpid()}.ply"
    try:
        write_synthetic_log(empty, empty=True, frames=5, seed=SAMPLE_SEED, size=SAMPLE_SIZE, progress=progress)
        model, _ = build_bin_model(LogReader(empty).frames())
        save_bin_model(model, tmp)
        os.replace(tmp, target)
    finally:
        for p in (empty, tmp):
            if p.exists():
                p.unlink()
    return target
