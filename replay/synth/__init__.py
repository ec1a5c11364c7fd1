"""Synthetic bin-picking scans with exact ground truth (paper Figure 8 parts, Zivid-like sensor).

Modules: ``parts`` (the six part kinds as solids), ``scene`` (table, bin, settled pile as a height
field), ``sensor`` (pinhole camera + offset projector, z-buffer rendering, noise, colour),
``outliers`` (ghost clusters, spikes, flying pixels, Figure-11 patches), ``synthesize`` (one frame
with its truth), ``log`` (MCAP logs and the demo's sample).
"""

from replay.presets import BIN, PART_KINDS, BinGeometry, PartKind
from replay.synth.log import (
    SAMPLE_FRAMES,
    SAMPLE_KIND,
    SAMPLE_SEED,
    SAMPLE_SIZE,
    ensure_sample_log,
    sample_log_path,
    synth_metadata,
    write_synthetic_log,
)
from replay.synth.outliers import (
    OUTLIER_CLUSTER,
    OUTLIER_FLYING,
    OUTLIER_NONE,
    OUTLIER_SPIKE,
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
    camera_distance_m,
    pile_distance_m,
    stamp_ns,
    synthesize_frame,
)

__all__ = [
    "BIN",
    "CAMERA_HEIGHT_MM",
    "EMPTY_POSITIONS_MM",
    "FULL_SIZE",
    "LABEL_FLOOR",
    "LABEL_NONE",
    "LABEL_PART",
    "LABEL_RIM",
    "LABEL_TABLE",
    "LABEL_WALL",
    "OUTLIER_CLUSTER",
    "OUTLIER_FLYING",
    "OUTLIER_NONE",
    "OUTLIER_SPIKE",
    "PART_KINDS",
    "PROJECTOR_BASELINE_MM",
    "SAMPLE_FRAMES",
    "SAMPLE_KIND",
    "SAMPLE_SEED",
    "SAMPLE_SIZE",
    "BinGeometry",
    "BinPose",
    "PartKind",
    "SynthFrame",
    "camera_distance_m",
    "default_intrinsics",
    "ensure_sample_log",
    "face_area_px",
    "pile_distance_m",
    "sample_log_path",
    "stamp_ns",
    "synth_metadata",
    "synthesize_frame",
    "write_synthetic_log",
]
