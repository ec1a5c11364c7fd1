"""One synthetic scan: scene -> render -> sensor losses and errors -> Frame + exact ground truth."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from replay.logs import layout
from replay.logs.frame import Frame
from replay.presets import PART_KINDS
from replay.synth import outliers as out
from replay.synth.parts import PART_COLOURS, face_area_px
from replay.synth.scene import (
    BIN,
    BIN_COLOUR,
    LABEL_FLOOR,
    LABEL_PART,
    LABEL_RIM,
    LABEL_WALL,
    TABLE_COLOUR,
    BinPose,
    Scene,
    drop_pile,
    empty_scene,
    make_grid,
)
from replay.synth.sensor import (
    CAMERA_HEIGHT_MM,
    FULL_SIZE,
    check_size,
    default_intrinsics,
    depth_noise_sigma_mm,
    measurable,
    pixel_rays,
    render,
    shade_rgb,
    view_half_extent_mm,
)
from zcut.errors import ParameterError

FRAME_ID = "zivid_optical_frame"
STAMP_BASE_NS = 1_706_140_800_000_000_000  # 2024-01-25T00:00:00Z (the paper's publication date)
FRAME_PERIOD_NS = 500_000_000
# the 5-position empty-bin series (paper §4): bin centre offsets in mm
EMPTY_POSITIONS_MM = ((0.0, 0.0), (45.0, 0.0), (-45.0, 0.0), (0.0, 35.0), (0.0, -35.0))


def camera_distance_m() -> float:
    """Distance from the camera to the centre of the bin volume (metres), about 0.5 m."""
    return (CAMERA_HEIGHT_MM - BIN.height_mm / 2) / 1000.0


def pile_distance_m(fill_mm: float = 45.0) -> float:
    """Distance from the camera to the top of a pile of ``fill_mm`` (metres): where ``a_max`` is measured."""
    return (CAMERA_HEIGHT_MM - BIN.floor_mm - fill_mm) / 1000.0


def stamp_ns(seed: int, index: int) -> int:
    """Fixed header stamp of frame ``index`` of the log synthesised with ``seed``."""
    return STAMP_BASE_NS + (int(seed) % 1_000_000) * 1_000_000_000 + int(index) * FRAME_PERIOD_NS


@dataclass(frozen=True, slots=True)
class SynthFrame:
    """A synthetic scan with everything known about it.

    Attributes
    ----------
    frame : Frame
        What a log holds (xyz float32 metres NaN-invalid, rgb, intrinsics, masks with the truth
        under ``/ground_truth/outliers``).
    truth : (H, W) bool ndarray
        Exact outliers (every one a finite point).
    outlier_kind : (H, W) uint8 ndarray
        OUTLIER_* of each true outlier (0 elsewhere).
    cluster_id : (H, W) int32 ndarray
        1-based index of the floating cluster a pixel belongs to (0 elsewhere).
    surface : (H, W) uint8 ndarray
        LABEL_* of the real surface on each pixel's ray.
    surface_depth_mm : (H, W) float32 ndarray
        Camera z (mm) of that real surface, noise-free (inf where the ray hits nothing).
    figure11 : (H, W) bool ndarray
        Real-surface patches fully surrounded by NaN (not outliers).
    scene : Scene
    shiny : bool
    a_max_px : float
        Pixel area of the part's largest face at the pile top (NaN for an empty bin).
    """

    frame: Frame
    truth: np.ndarray
    outlier_kind: np.ndarray
    cluster_id: np.ndarray
    surface: np.ndarray
    surface_depth_mm: np.ndarray
    figure11: np.ndarray
    scene: Scene
    shiny: bool
    a_max_px: float


def bin_pose_for(rng: np.random.Generator, *, empty: bool, index: int) -> BinPose:
    """Bin pose of a frame: small random yaw and offset; the empty series cycles the 5 positions."""
    if empty:
        dx, dy = EMPTY_POSITIONS_MM[index % len(EMPTY_POSITIONS_MM)]
        return BinPose(np.radians(rng.uniform(-2.0, 2.0)), dx + rng.uniform(-3, 3), dy + rng.uniform(-3, 3))
    return BinPose(np.radians(rng.uniform(-3.0, 3.0)), rng.uniform(-10, 10), rng.uniform(-10, 10))


def synthesize_frame(
    *,
    kind: str = "spheres",
    seed: int = 0,
    index: int = 0,
    size: tuple[int, int] = FULL_SIZE,
    shiny: bool | None = None,
    empty: bool = False,
    fill_mm: float | None = None,
) -> SynthFrame:
    """Synthesise frame ``index`` of a log with ``seed``: a bin of ``kind`` parts (or an empty bin).

    Parameters
    ----------
    kind : str
        Key of :data:`PART_KINDS` (ignored when ``empty``).
    seed, index : int
        Everything random comes from ``np.random.default_rng([seed, index])``.
    size : (height, width)
    shiny : bool or None
        Override the kind's surface finish (None: the kind's own).
    empty : bool
        Scan the empty bin (position ``index % 5`` of the 5-position series).
    fill_mm : float or None
        Mean pile height above the floor (default: random in [35, 55] mm).
    """
    if not empty and kind not in PART_KINDS:
        raise ParameterError(f"kind must be one of {', '.join(PART_KINDS)}, got {kind!r}")
    h, w = check_size(size)
    rng = np.random.default_rng([int(seed) % (2**63), int(index), int(empty)])
    K = default_intrinsics((h, w))
    half_x, half_y = view_half_extent_mm(K)
    fp_floor = (CAMERA_HEIGHT_MM - BIN.floor_mm) / K.fx
    grid_step = float(np.clip(0.8 * fp_floor, 0.5, 1.0))
    grid = make_grid(half_x_mm=half_x + 5 * grid_step, half_y_mm=half_y + 5 * grid_step, step_mm=grid_step)
    pose = bin_pose_for(rng, empty=empty, index=index)
    if fill_mm is None:
        fill_mm = float(rng.uniform(35.0, 55.0))
    if empty:
        scene = empty_scene(grid, pose)
        part = None
        is_shiny = False if shiny is None else bool(shiny)
    else:
        scene = drop_pile(grid, pose, kind, rng, fill_mm=fill_mm)
        part = PART_KINDS[kind]
        is_shiny = part.shiny if shiny is None else bool(shiny)

    view = render(scene, K)
    clean = view.depth_mm
    valid = measurable(scene, view, K)
    surface = view.label
    on_part = surface == LABEL_PART
    shiny_px = on_part & is_shiny
    rates = out.SHINY_RATES if is_shiny else out.MATTE_RATES
    if part is not None:
        a_max = face_area_px(part, fx=K.fx, fy=K.fy, distance_m=pile_distance_m(fill_mm))
    else:
        a_max = float("nan")
    sigma = depth_noise_sigma_mm(np.where(np.isfinite(clean), clean, CAMERA_HEIGHT_MM), shiny=shiny_px)

    figure11 = np.zeros((h, w), bool)
    keep_out = np.zeros((h, w), bool)
    if part is not None:
        out.specular_dropouts(valid, on_part, count=int(rng.poisson(rates.dropouts)), a_max_px=a_max, rng=rng)
        ring_px = max(1, int(round(2 * w / FULL_SIZE[1])))
        figure11, keep_out = out.figure11_patches(
            valid, on_part, count=out.FIG11_PATCHES, a_max_px=a_max, ring_px=ring_px, rng=rng
        )
    allowed = ~keep_out & np.isfinite(clean)

    depth = clean + rng.normal(0.0, 1.0, (h, w)) * sigma
    n = view.normal
    nz = np.maximum(np.abs(n[..., 2]), 1e-3)
    slope_step = np.where(np.isfinite(clean), clean, 0.0) / K.fx * np.maximum(np.abs(n[..., 0]), np.abs(n[..., 1])) / nz
    flying = out.flying_pixels(depth, clean, valid, allowed, slope_step, prob=rates.flying_prob, rng=rng)
    spike_where = on_part if part is not None else (surface == LABEL_FLOOR)
    spiked = out.spikes(depth, valid, spike_where & allowed & ~flying, prob=rates.spike_prob, rng=rng)
    if part is not None:
        part_z = np.where(on_part & np.isfinite(clean), clean, np.inf)
        top_zone = part_z <= float(np.percentile(part_z[on_part], 0.5)) + out.TOP_ZONE_MM if on_part.any() else on_part
        cluster_id = out.floating_clusters(
            depth, clean, valid, on_part & top_zone, allowed, sigma,
            count=int(rng.poisson(rates.clusters)), rates=rates, a_max_px=a_max, rng=rng,
        )
    else:
        cluster_id = np.zeros((h, w), np.int32)

    kind_img = np.zeros((h, w), np.uint8)
    kind_img[flying] = out.OUTLIER_FLYING
    kind_img[spiked] = out.OUTLIER_SPIKE
    kind_img[cluster_id > 0] = out.OUTLIER_CLUSTER
    valid &= np.isfinite(depth)
    kind_img[~valid] = out.OUTLIER_NONE
    cluster_id[~valid] = 0
    truth = kind_img > 0

    rays = pixel_rays(K)
    xyz = (rays * (np.where(valid, depth, np.nan) / 1000.0)[..., None]).astype(np.float32)

    colours = np.empty((h, w, 3))
    colours[:] = TABLE_COLOUR
    bin_px = (surface == LABEL_FLOOR) | (surface == LABEL_WALL) | (surface == LABEL_RIM)
    colours[bin_px] = BIN_COLOUR
    if part is not None:
        colours[on_part] = PART_COLOURS[part.name]
    # plastic scatters the room light: the bin stays bright even on its steep walls (paper §5.1
    # thresholds the gray image to find it)
    ambient = np.where(bin_px, 0.8, 0.6)
    rgb = shade_rgb(view, K, colours, shiny_px, ambient, rng)

    frame = Frame(
        xyz=xyz,
        rgb=rgb,
        stamp_ns=stamp_ns(seed, index),
        frame_id=FRAME_ID,
        intrinsics=K,
        topic=layout.CLOUD,
        index=int(index),
        masks={layout.TRUTH_OUTLIERS: truth},
    )
    return SynthFrame(
        frame, truth, kind_img, cluster_id, surface, clean.astype(np.float32), figure11, scene, is_shiny, a_max
    )


