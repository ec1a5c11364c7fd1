"""Synthetic bin-picking scans with exact ground truth (paper Figure 8 parts, Zivid-like sensor).

Modules: ``parts`` (the six part kinds as solids), ``scene`` (table, bin, settled pile as a height
field), ``sensor`` (pinhole camera + offset projector, z-buffer rendering, noise, colour),
``outliers`` (ghost clusters, spikes, flying pixels, points above the rim, Figure-11 patches),
``synthesize`` (one frame with its truth and its true bin pose), ``log`` (MCAP logs, their true
poses, the demo's sample). The generator's assumptions and their sources: ``docs/synthetic.md``.
"""

from replay.presets import BIN, PART_KINDS, BinGeometry, PartKind
from replay.synth.log import (
    GENERATOR_VERSION,
    SAMPLE_FRAMES,
    SAMPLE_KIND,
    SAMPLE_SEED,
    SAMPLE_SIZE,
    ensure_sample_log,
    sample_log_path,
    synth_metadata,
    true_poses,
    write_bin_cad,
    write_synthetic_log,
)
from replay.synth.outliers import (
    OUTLIER_ABOVE_RIM,
    OUTLIER_FLOATING,
    OUTLIER_FLYING,
    OUTLIER_NONE,
    OUTLIER_SPIKE_DOWN,
    OUTLIER_SPIKE_UP,
)
from replay.synth.parts import face_area_px
from replay.synth.scene import (
    LABEL_FLOOR,
    LABEL_NONE,
    LABEL_PART,
    LABEL_RIM,
    LABEL_TABLE,
    LABEL_WALL,
    BinPose,
    BinShape,
)
from replay.synth.sensor import (
    CAMERA_HEIGHT_MM,
    FULL_SIZE,
    PROJECTOR_BASELINE_MM,
    default_intrinsics,
)
from replay.synth.synthesize import (
    EMPTY_POSITIONS_MM,
    SynthFrame,
    T_cam_bin,
    camera_distance_m,
    frame_pose,
    pile_distance_m,
    stamp_ns,
    synthesize_frame,
)

__all__ = [
    "BIN",
    "CAMERA_HEIGHT_MM",
    "EMPTY_POSITIONS_MM",
    "FULL_SIZE",
    "GENERATOR_VERSION",
    "LABEL_FLOOR",
    "LABEL_NONE",
    "LABEL_PART",
    "LABEL_RIM",
    "LABEL_TABLE",
    "LABEL_WALL",
    "OUTLIER_ABOVE_RIM",
    "OUTLIER_FLOATING",
    "OUTLIER_FLYING",
    "OUTLIER_NONE",
    "OUTLIER_SPIKE_DOWN",
    "OUTLIER_SPIKE_UP",
    "PART_KINDS",
    "PROJECTOR_BASELINE_MM",
    "SAMPLE_FRAMES",
    "SAMPLE_KIND",
    "SAMPLE_SEED",
    "SAMPLE_SIZE",
    "BinGeometry",
    "BinPose",
    "BinShape",
    "PartKind",
    "SynthFrame",
    "T_cam_bin",
    "camera_distance_m",
    "default_intrinsics",
    "ensure_sample_log",
    "face_area_px",
    "frame_pose",
    "pile_distance_m",
    "sample_log_path",
    "stamp_ns",
    "synth_metadata",
    "synthesize_frame",
    "true_poses",
    "write_bin_cad",
    "write_synthetic_log",
]
