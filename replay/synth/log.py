"""Synthetic logs in the SPEC §5 layout, and the bundled sample the demo replays.

A synthetic log holds, per frame and all with the same header stamp: the organized cloud with
``rgba`` on ``/camera/points``, the colour image on ``/camera/image``, ``/camera/camera_info``, and
the exact outliers on ``/ground_truth/outliers`` (mono8, 255 = outlier). An MCAP metadata record
``zcut.synth`` describes how it was made (part kind, seed, finish, camera distance, bin geometry,
size, ...). The same arguments give the same bytes.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

from replay.logs import layout
from replay.logs.writer import LogWriter
from replay.presets import BIN, PART_KINDS
from replay.synth.outliers import TOP_ZONE_MM
from replay.synth.parts import face_area_px
from replay.synth.sensor import (
    CAMERA_HEIGHT_MM,
    FULL_SIZE,
    MAX_OBLIQUITY_DEG,
    NOISE_MM_AT_500,
    PROJECTOR_BASELINE_MM,
    SHINY_NOISE_FACTOR,
    default_intrinsics,
)
from replay.synth.synthesize import (
    SynthFrame,
    camera_distance_m,
    pile_distance_m,
    synthesize_frame,
)
from zcut.errors import ParameterError

GENERATOR_VERSION = "1"

#: The sample the demo replays: three frames of M16 rods (the paper's Figures 13 and 14 show rods)
#: at half the sensor's resolution, so that synthesising and replaying it take seconds.
SAMPLE_KIND = "rods"
SAMPLE_SEED = 2024
SAMPLE_FRAMES = 3
SAMPLE_SIZE = (600, 960)

ProgressFn = Callable[[int, int, SynthFrame, float], None]


def synth_metadata(
    *, kind: str, seed: int, frames: int, size: tuple[int, int], shiny: bool, empty: bool
) -> dict[str, str]:
    """The ``zcut.synth`` metadata record (all values strings)."""
    K = default_intrinsics(size)
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
        "ghost_top_zone_mm": f"{TOP_ZONE_MM:g}",
        "truth_topic": layout.TRUTH_OUTLIERS,
        **BIN.as_metadata(),
    }
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


def write_synthetic_log(
    path: str | os.PathLike,
    *,
    kind: str = "spheres",
    frames: int = 1,
    seed: int = 0,
    size: tuple[int, int] = FULL_SIZE,
    empty: bool = False,
    shiny: bool | None = None,
    progress: ProgressFn | None = None,
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
    progress : callable or None
        Called as ``progress(index, frames, synth_frame, seconds)`` after each frame is written.

    Returns
    -------
    Path of the written log.
    """
    if not empty and kind not in PART_KINDS:
        raise ParameterError(f"kind must be one of {', '.join(PART_KINDS)}, got {kind!r}")
    if int(frames) != frames or frames < 1:
        raise ParameterError(f"frames must be a positive integer, got {frames!r}")
    is_shiny = (False if empty else PART_KINDS[kind].shiny) if shiny is None else bool(shiny)
    meta = synth_metadata(kind=kind, seed=seed, frames=int(frames), size=size, shiny=is_shiny, empty=empty)
    path = Path(path)
    with LogWriter(path, metadata={layout.SYNTH_METADATA: meta}) as writer:
        for i in range(int(frames)):
            t0 = time.perf_counter()
            sf = synthesize_frame(kind=kind, seed=seed, index=i, size=size, shiny=shiny, empty=empty)
            writer.write_frame(sf.frame)
            if progress is not None:
                progress(i, int(frames), sf, time.perf_counter() - t0)
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


def ensure_sample_log(path: str | os.PathLike | None = None, *, progress: ProgressFn | None = None) -> Path:
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
