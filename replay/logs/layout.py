"""The log layout's names (SPEC §5): topics zcut reads and writes, and its MCAP metadata records.

The one place these strings live; every reader, writer and command imports them from here.
"""

from __future__ import annotations

# what a recorded log holds (``zcut record`` writes these; any organized PointCloud2 is accepted)
CLOUD = "/camera/points"
IMAGE = "/camera/image"
CAMERA_INFO = "/camera/camera_info"

# results of the pipeline (``zcut replay --out``): mono8 masks, 255 = set, and the filtered cloud
ZCUT_OUTLIERS = "/zcut/outliers"
SOR_OUTLIERS = "/zcut/sor_outliers"
BIN_MASK = "/zcut/bin_mask"
FILTERED = "/zcut/filtered"
#: the pixels the filters judged (valid minus table and bin, plus the above-the-rim points)
ZONE = "/zcut/zone"
RESULTS_PREFIX = "/zcut/"
#: the outliers of a filter method other than the z-cut and SOR (``zcut replay --methods``): mono8
METHODS_PREFIX = "/zcut/methods/"


def method_topic(name: str) -> str:
    """The results topic of a base method's outliers: ``/zcut/outliers`` for the z-cut,
    ``/zcut/sor_outliers`` for SOR, ``/zcut/methods/NAME`` for the others."""
    return {"zcut": ZCUT_OUTLIERS, "sor": SOR_OUTLIERS}.get(name, METHODS_PREFIX + name)

# synthetic truth: mono8, 255 = true outlier; the kind image holds the codes of OUTLIER_KINDS
TRUTH_OUTLIERS = "/ground_truth/outliers"
TRUTH_OUTLIER_KIND = "/ground_truth/outlier_kind"

#: ``/ground_truth/outlier_kind`` codes (SPEC §5); 0 = not an outlier.
OUTLIER_KINDS: dict[int, str] = {
    1: "floating",   # a specular ghost separated from the surface below
    2: "spike_up",   # spike toward the camera
    3: "spike_down",  # spike away from the camera
    4: "flying",     # flying pixel between two surfaces at a depth edge
    5: "above_rim",  # above the bin's rim
}

#: mono8 topics whose values are codes, not a mask: a Frame holds them in ``Frame.codes`` (uint8)
CODE_TOPICS = (TRUTH_OUTLIER_KIND,)

# exported human labels (``zcut labels export``): mono8
LABEL_OUTLIERS = "/labels/outliers"
LABEL_REVIEWED = "/labels/reviewed"

# MCAP metadata record names
SYNTH_METADATA = "zcut.synth"
#: true bin pose of every synthetic frame: key = str(stamp_ns), value = the 16 row-major floats of
#: ``T_cam_bin`` (metres, camera optical frame <- bin frame) joined by commas
SYNTH_POSES_METADATA = "zcut.synth.poses"
RESULTS_METADATA = "zcut.results"
LABELS_METADATA = "zcut.labels"
