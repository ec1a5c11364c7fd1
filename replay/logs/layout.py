"""The log layout's names (docs/formats.md): topics zcut reads and writes, and its MCAP metadata records.

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
#: the source's valid pixels (255 = a valid point): in every results file, so that one written without
#: its cloud (the default) still tells which pixels were scored; such a file's frames are driven by it
VALID = "/zcut/valid"
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
#: the paper's truth (synthetic logs): mono8, 255 = farther than 3 × Err from every true surface of the scene
TRUTH_OFF_SURFACE = "/ground_truth/off_surface"

#: synthetic truth: sensor_msgs/Image ``32FC1``, the camera-frame z (metres) of the first surface each
#: pixel's centre ray hits, NaN where it hits nothing (``docs/formats.md``, ground-truth topics)
TRUTH_DEPTH = "/ground_truth/depth"
TRUTH_DEPTH_ENCODING = "32FC1"
#: mono8, 255 = the truth of this pixel is unknown (no ground truth, or occluded in it): the pixel is not
#: scored by any command (``zcut record-stereo``; docs/accuracy.md, "Truth that cannot be judged")
TRUTH_UNKNOWN = "/ground_truth/unknown"
#: mono8, 255 = a true outlier that geometry alone can tell (``zcut record-stereo``; docs/accuracy.md,
#: "Detectable outliers"); a subset of ``/ground_truth/outliers``
TRUTH_DETECTABLE = "/ground_truth/detectable"

#: ``/ground_truth/outlier_kind`` codes of the hand-made generator (docs/formats.md); 0 = not an outlier.
HANDMADE_OUTLIER_KINDS: dict[int, str] = {
    1: "floating",   # a specular ghost separated from the surface below
    2: "spike_up",   # spike toward the camera
    3: "spike_down",  # spike away from the camera
    4: "flying",     # flying pixel between two surfaces at a depth edge
    5: "above_rim",  # above the bin's rim
}
#: codes >= 6: what made an outlier of the ray-traced sensor (``zcut synth --sensor raytraced``,
#: ``docs/formats.md``); it also writes 5 for any outlier above the rim, whatever made it
RAYTRACED_OUTLIER_KINDS: dict[int, str] = {
    6: "interreflection",  # light that reached the pixel by a specular bounce decided its code
    7: "mixed_pixel",      # the pixel's footprint straddles surfaces whose codes blended
    8: "saturation_edge",  # light spilled from a highlight (lens glare) decided its code
}
#: every ``/ground_truth/outlier_kind`` code and its name; 0 = not an outlier.
OUTLIER_KINDS: dict[int, str] = {**HANDMADE_OUTLIER_KINDS, **RAYTRACED_OUTLIER_KINDS}

#: mono8, 255 = a pixel the stereo matcher's cloud holds and one of its post-filters, at one strength, would
#: invalidate (``zcut record-stereo``; docs/formats.md, "Stereo post-filters"): one topic per post-filter and
#: strength, named by :func:`stereo_rejected_topic`; read by the methods ``stereo_uniqueness``, ``stereo_lr``,
#: ``stereo_speckle``, ``stereo_texture`` (``replay/pipeline/stereo_methods.py``)
STEREO_REJECTED_PREFIX = "/stereo/rejected/"


def stereo_rejected_topic(settings: dict[str, int]) -> str:
    """The topic of a post-filter's rejected pixels at these settings (its matcher fields and their
    values, in order): ``{"speckle_window": 100, "speckle_range": 2}`` ->
    ``/stereo/rejected/speckle_window_100_speckle_range_2``."""
    return STEREO_REJECTED_PREFIX + "_".join(f"{k}_{int(v)}" for k, v in settings.items())


#: mono8 topics whose values are codes, not a mask: a Frame holds them in ``Frame.codes`` (uint8)
CODE_TOPICS = (TRUTH_OUTLIER_KIND,)

#: mono8 topics under these prefixes are zcut's own masks (truth, labels, results, stereo rejections): a frame is paired with
#: them whatever their size, so that one of the wrong size is reported as ``wrong_size`` damage (its frame
#: skipped), never taken for a missing topic. Other mono8 topics are masks only when of the cloud's size.
MASK_PREFIXES = ("/ground_truth/", "/labels/", RESULTS_PREFIX, STEREO_REJECTED_PREFIX)

# exported human labels (``zcut labels export``): mono8
LABEL_OUTLIERS = "/labels/outliers"
LABEL_REVIEWED = "/labels/reviewed"

# MCAP attachments: the bin model a log carries (docs/formats.md, "Bin model attachment"); a PLY point
# cloud with normals or a mesh, metres, in the bin frame (up = -z), as `zcut bin-model` writes it
BIN_MODEL_ATTACHMENT = "bin_model.ply"
BIN_MODEL_MEDIA_TYPE = "application/x-ply"

# MCAP metadata record names
SYNTH_METADATA = "zcut.synth"
#: ``zcut record-stereo``: the matcher, τ_d (``tau_px``), every frame's scene and calibration, and the
#: post-filter settings whose rejected pixels it recorded (``rejected``)
STEREO_METADATA = "zcut.stereo"
#: true bin pose of every synthetic frame: key = str(stamp_ns), value = the 16 row-major floats of
#: ``T_cam_bin`` (metres, camera optical frame <- bin frame) joined by commas
SYNTH_POSES_METADATA = "zcut.synth.poses"
RESULTS_METADATA = "zcut.results"
LABELS_METADATA = "zcut.labels"
