"""One synthetic scan: scene -> render -> sensor losses and errors -> Frame + exact ground truth.

:func:`synthesize_frame` reads as its steps: place the bin and drop the pile, render it, shade the
colour image, lose what the sensor loses (shadows, grazing views, saturated highlights, specular
dropouts, Figure-11 patches), add the depth noise, then the outliers of each kind, quantize when
asked, and assemble the cloud with its truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from replay.logs import layout
from replay.logs.frame import Frame
from replay.presets import BIN, PART_KINDS
from replay.synth import outliers as out
from replay.synth.parts import PART_COLOURS, face_area_px
from replay.synth.scene import (
    BIN_COLOUR,
    LABEL_FLOOR,
    LABEL_PART,
    LABEL_RIM,
    LABEL_WALL,
    TABLE_COLOUR,
    BinPose,
    BinShape,
    Scene,
    check_pile,
    drop_pile,
    empty_scene,
    lean_walls,
    make_grid,
)
from replay.synth.sensor import (
    CAMERA_HEIGHT_MM,
    FULL_SIZE,
    Render,
    check_size,
    correlated_noise,
    default_intrinsics,
    depth_noise_sigma_mm,
    measure,
    pixel_rays,
    quantize_depth,
    render,
    shade_rgb,
    view_half_extent_mm,
)
from replay.synth.surfaces import err_mm, handmade_surfaces, off_surface
from zcut.cloud import Intrinsics
from zcut.errors import ParameterError

FRAME_ID = "zivid_optical_frame"
STAMP_BASE_NS = 1_706_140_800_000_000_000  # 2024-01-25T00:00:00Z (the paper's publication date)
FRAME_PERIOD_NS = 500_000_000
# the 5-position empty-bin series (paper §4): bin centre offsets in mm
EMPTY_POSITIONS_MM = ((0.0, 0.0), (45.0, 0.0), (-45.0, 0.0), (0.0, 35.0), (0.0, -35.0))
#: mean pile height above the floor is drawn uniformly from this range (mm)
FILL_RANGE_MM = (35.0, 55.0)
#: the largest depth step a quantizing sensor may be given (mm)
MAX_QUANTIZE_MM = 10.0


def camera_distance_m() -> float:
    """Distance from the camera to the centre of the bin volume (metres), about 0.5 m."""
    return (CAMERA_HEIGHT_MM - BIN.height_mm / 2) / 1000.0


def pile_distance_m(fill_mm: float = 45.0) -> float:
    """Distance from the camera to the top of a pile of ``fill_mm`` (metres): where ``a_max`` is measured."""
    return (CAMERA_HEIGHT_MM - BIN.floor_mm - fill_mm) / 1000.0


def stamp_ns(seed: int, index: int) -> int:
    """Fixed header stamp of frame ``index`` of the log synthesised with ``seed``."""
    return STAMP_BASE_NS + (int(seed) % 1_000_000) * 1_000_000_000 + int(index) * FRAME_PERIOD_NS


def T_cam_bin(pose: BinPose) -> np.ndarray:
    """(4, 4) float64: bin frame -> camera optical frame, metres, for the bin at ``pose``.

    The bin frame is the camera optical frame when the bin stands at its nominal pose (centred
    below the camera, yaw 0) — the frame of the first scan of a synthetic empty-bin series, which
    is exactly at the nominal pose, so a bin model built from it (``zcut bin-model``) is in this
    frame and a registration's ``T_cam_bin`` compares directly. The camera looks straight down:
    camera = D·world + (0, 0, h) with D = diag(1, -1, -1), h = the camera height.
    """
    c, s = np.cos(pose.yaw_rad), np.sin(pose.yaw_rad)
    Rw = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    D = np.diag([1.0, -1.0, -1.0])
    cam = np.array([0.0, 0.0, CAMERA_HEIGHT_MM / 1000.0])
    tw = np.array([pose.x_mm, pose.y_mm, 0.0]) / 1000.0
    R = D @ Rw @ D
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ cam + D @ tw + cam
    return T


@dataclass(frozen=True, slots=True)
class SynthFrame:
    """A synthetic scan with everything known about it.

    Attributes
    ----------
    frame : Frame
        What a log holds (xyz float32 metres NaN-invalid, rgb, intrinsics, the truth under
        ``/ground_truth/outliers`` in its masks and the kinds under ``/ground_truth/outlier_kind``
        in its codes).
    truth : (H, W) bool ndarray
        Exact outliers (every one a finite point).
    outlier_kind : (H, W) uint8 ndarray
        Code of each true outlier (``OUTLIER_*``, docs/formats.md: 1 floating, 2 spike up, 3 spike down,
        4 flying, 5 above the rim), 0 elsewhere; nonzero exactly where ``truth`` is set. Written
        to ``/ground_truth/outlier_kind``.
    cluster_id : (H, W) int32 ndarray
        1-based index of the floating cluster a pixel belongs to (0 elsewhere).
    surface : (H, W) uint8 ndarray
        LABEL_* of the real surface on each pixel's ray.
    surface_depth_mm : (H, W) float32 ndarray
        Camera z (mm) of that real surface, noise-free (inf where the ray hits nothing).
    figure11 : (H, W) bool ndarray
        Real-surface patches fully surrounded by NaN (not outliers).
    saturated : (H, W) bool ndarray
        Specular highlights that clip the colour image (their depth is lost too).
    scene : Scene
    shiny : bool
    a_max_px : float
        Pixel area of the part's largest face at the pile top (NaN for an empty bin).
    T_cam_bin : (4, 4) float64 ndarray
        True bin pose (see :func:`T_cam_bin`).
    quantize_mm : float
        Depth step of the simulated sensor (0: continuous).
    off_surface : (H, W) bool ndarray
        The paper's truth (``/ground_truth/off_surface``): the valid points farther than 3 × Err from
        every true surface of the scene (:mod:`replay.synth.surfaces`).
    err_mm : (H, W) float32 ndarray
        Err of each pixel: ``sqrt(σ² + c²/2 + q²/12)``, σ its noise sigma, c the larger of its
        footprint z / f and the height-field step, q the depth step (:func:`~replay.synth.surfaces.err_mm`).
    """

    frame: Frame
    truth: np.ndarray
    outlier_kind: np.ndarray
    cluster_id: np.ndarray
    surface: np.ndarray
    surface_depth_mm: np.ndarray
    figure11: np.ndarray
    saturated: np.ndarray
    scene: Scene
    shiny: bool
    a_max_px: float
    T_cam_bin: np.ndarray
    quantize_mm: float
    off_surface: np.ndarray
    err_mm: np.ndarray


def frame_rng(seed: int, index: int, *, empty: bool) -> np.random.Generator:
    """The generator every random draw of a frame comes from."""
    return np.random.default_rng([int(seed) % (2**63), int(index), int(empty)])


def bin_pose_for(rng: np.random.Generator, *, empty: bool, index: int) -> BinPose:
    """Bin pose of a frame: small random yaw and offset.

    The empty series cycles the 5 positions with a small jitter, except its first scan, which is
    exactly at the nominal pose (the frame a bin model built from the series is in).
    """
    if empty:
        dx, dy = EMPTY_POSITIONS_MM[index % len(EMPTY_POSITIONS_MM)]
        yaw, jx, jy = np.radians(rng.uniform(-2.0, 2.0)), rng.uniform(-3, 3), rng.uniform(-3, 3)
        if index == 0:
            return BinPose(0.0, 0.0, 0.0)
        return BinPose(yaw, dx + jx, dy + jy)
    return BinPose(np.radians(rng.uniform(-3.0, 3.0)), rng.uniform(-10, 10), rng.uniform(-10, 10))


def shape_rng(seed: int, index: int, *, empty: bool) -> np.random.Generator:
    """The generator of a frame's bin deformation (:class:`BinShape`), apart from :func:`frame_rng`
    so that a deformed bin holds the same pile, noise and outliers as the nominal one."""
    return np.random.default_rng([int(seed) % (2**63), int(index), int(empty), 0xB15])


def frame_pose(seed: int, index: int, *, empty: bool = False) -> np.ndarray:
    """True ``T_cam_bin`` (4, 4) of frame ``index`` of the log synthesised with ``seed`` (cheap)."""
    return T_cam_bin(bin_pose_for(frame_rng(seed, index, empty=empty), empty=empty, index=index))


def check_quantize(quantize_mm: object) -> float:
    """``quantize_mm`` as a float in [0, MAX_QUANTIZE_MM], or :class:`ParameterError` naming it."""
    try:
        q = float(quantize_mm)  # type: ignore[arg-type]
    except (TypeError, ValueError) as e:
        raise ParameterError(f"quantize_mm must be a number of millimetres, got {quantize_mm!r}") from e
    if not (0.0 <= q <= MAX_QUANTIZE_MM):
        raise ParameterError(f"quantize_mm must be between 0 and {MAX_QUANTIZE_MM:g} mm, got {quantize_mm!r}")
    return q


def check_pile_for(pile: object, *, empty: bool, bin_shape: object = None) -> str:
    """``pile`` (:data:`~replay.synth.scene.PILES`) if it goes with the rest of the scan, else
    :class:`ParameterError`: a pile against the walls needs parts and the nominal bin."""
    p = check_pile(pile)
    if p == "walls" and empty:
        raise ParameterError("pile 'walls' needs parts to pile, not an empty bin")
    if p == "walls" and isinstance(bin_shape, BinShape) and not bin_shape.nominal:
        raise ParameterError("pile 'walls' needs the nominal bin (no bin scale, bulge or deformation)")
    return p


def _colour_image(view: Render, K: Intrinsics, part_colour: tuple[int, int, int] | None, shiny_px: np.ndarray,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(rgb, saturated) of :func:`shade_rgb` with the table, bin and part colours of each pixel."""
    surface = view.label
    colours = np.empty(surface.shape + (3,))
    colours[:] = TABLE_COLOUR
    bin_px = (surface == LABEL_FLOOR) | (surface == LABEL_WALL) | (surface == LABEL_RIM)
    colours[bin_px] = BIN_COLOUR
    if part_colour is not None:
        colours[surface == LABEL_PART] = part_colour
    # plastic scatters the room light: the bin stays bright even on its steep walls (paper §5.1
    # thresholds the gray image to find it)
    ambient = np.where(bin_px, 0.8, 0.6)
    return shade_rgb(view, K, colours, shiny_px, ambient, rng)


def synthesize_frame(
    *,
    kind: str = "spheres",
    seed: int = 0,
    index: int = 0,
    size: tuple[int, int] = FULL_SIZE,
    shiny: bool | None = None,
    empty: bool = False,
    fill_mm: float | None = None,
    quantize_mm: float = 0.0,
    bin_shape: BinShape = BinShape(),
    pile: str = "floor",
) -> SynthFrame:
    """Synthesise frame ``index`` of a log with ``seed``: a bin of ``kind`` parts (or an empty bin).

    Parameters
    ----------
    kind : str
        Key of :data:`PART_KINDS` (ignored when ``empty``).
    seed, index : int
        Everything random comes from :func:`frame_rng` ``(seed, index)``.
    size : (height, width)
    shiny : bool or None
        Override the kind's surface finish (None: the kind's own).
    empty : bool
        Scan the empty bin (position ``index % 5`` of the 5-position series).
    fill_mm : float or None
        Mean pile height above the floor (default: random in :data:`FILL_RANGE_MM`).
    quantize_mm : float
        Depth step of a quantizing sensor (consumer stereo / ToF: 1-2 mm); 0 = continuous depth.
        A true outlier that the rounding brings within one step of its real surface is no longer
        one (its pixel shows the surface).
    bin_shape : BinShape
        How the bin differs from the nominal one (scale, wall bulge, a deformation drawn per scan
        from :func:`shape_rng`); the pile, the noise and the outliers are those of the nominal bin's
        frame with the same seed and index. The true pose stays that of the bin's frame.
    pile : {"floor", "walls"}
        ``floor``: the parts keep off the walls; ``walls``: they lean on the walls of
        :func:`~replay.synth.scene.lean_walls` ``(seed, index)`` (:func:`~replay.synth.scene.drop_pile`),
        with the bin pose and fill of the ``floor`` pile of the same seed. Needs parts and the nominal bin.
    """
    if not empty and kind not in PART_KINDS:
        raise ParameterError(f"kind must be one of {', '.join(PART_KINDS)}, got {kind!r}")
    h, w = check_size(size)
    q = check_quantize(quantize_mm)
    check_pile_for(pile, empty=empty, bin_shape=bin_shape)
    rng = frame_rng(seed, index, empty=empty)
    K = default_intrinsics((h, w))

    # the scene: bin pose, pile
    half_x, half_y = view_half_extent_mm(K)
    fp_floor = (CAMERA_HEIGHT_MM - BIN.floor_mm) / K.fx
    grid_step = float(np.clip(0.8 * fp_floor, 0.5, 1.0))
    grid = make_grid(half_x_mm=half_x + 5 * grid_step, half_y_mm=half_y + 5 * grid_step, step_mm=grid_step)
    pose = bin_pose_for(rng, empty=empty, index=index)
    if not isinstance(bin_shape, BinShape):
        raise ParameterError(f"bin_shape must be a BinShape, got {bin_shape!r}")
    deformation = bin_shape.realise(shape_rng(seed, index, empty=empty) if bin_shape.deform_mm > 0 else None)
    rim_depth_mm = CAMERA_HEIGHT_MM - deformation.rim_top_mm(BIN)
    if fill_mm is None:
        fill_mm = float(rng.uniform(*FILL_RANGE_MM))
    if empty:
        scene = empty_scene(grid, pose, deformation=deformation)
        part = None
        is_shiny = False if shiny is None else bool(shiny)
    else:
        walls = lean_walls(seed, index) if pile == "walls" else ()
        scene = drop_pile(grid, pose, kind, rng, fill_mm=fill_mm, deformation=deformation, walls=walls)
        part = PART_KINDS[kind]
        is_shiny = part.shiny if shiny is None else bool(shiny)
    rates = out.SHINY_RATES if is_shiny else out.MATTE_RATES
    a_max = face_area_px(part, fx=K.fx, fy=K.fy, distance_m=pile_distance_m(fill_mm)) if part else float("nan")

    # what the camera sees, and the colour image (the projector's highlights saturate it)
    view = render(scene, K)
    clean = view.depth_mm
    surface = view.label
    on_part = surface == LABEL_PART
    shiny_px = on_part & is_shiny
    rgb, saturated = _colour_image(view, K, PART_COLOURS[part.name] if part else None, shiny_px, rng)

    # what the sensor loses: shadows and grazing views, saturated highlights, specular dropouts;
    # the renderer's NaN-fenced slivers are healed, Figure-11 patches made at the paper's rate
    valid, cosine = measure(scene, view, K)
    valid &= ~saturated
    surface_id = np.where(on_part, view.part_id, -surface.astype(np.int32))
    out.drop_steep_fragments(valid, cosine, clean, surface_id, steep_cos=float(np.cos(np.radians(out.STEEP_DEG))))
    out.drop_surface_fragments(valid, surface_id, max_px=out.HEAL_RHO * a_max if part else 50.0)
    figure11 = np.zeros((h, w), bool)
    keep_out = np.zeros((h, w), bool)
    if part is not None:
        out.specular_dropouts(valid, on_part, count=int(rng.poisson(rates.dropouts)), a_max_px=a_max, rng=rng)
        out.heal_islands(valid, max_px=out.HEAL_RHO * a_max)
        ring_px = max(1, round(2 * w / FULL_SIZE[1]))
        figure11, keep_out = out.figure11_patches(
            valid, on_part, count=int(rng.poisson(rates.figure11)), a_max_px=a_max, ring_px=ring_px, rng=rng
        )
    else:
        out.heal_islands(valid, max_px=out.HEAL_RHO * 200.0 * (w / FULL_SIZE[1]) ** 2)
    allowed = ~keep_out & np.isfinite(clean)

    # depth noise, spatially correlated
    sigma = depth_noise_sigma_mm(np.where(np.isfinite(clean), clean, CAMERA_HEIGHT_MM), shiny=shiny_px)
    depth0 = clean + correlated_noise((h, w), rng) * sigma
    depth = depth0.copy()
    valid0 = valid.copy()

    # the outliers, kind by kind (a later kind overwrites an earlier one on the same pixel)
    n = view.normal
    nz = np.maximum(np.abs(n[..., 2]), 1e-3)
    slope_step = np.where(np.isfinite(clean), clean, 0.0) / K.fx * np.maximum(np.abs(n[..., 0]), np.abs(n[..., 1])) / nz
    flying = out.flying_pixels(depth, clean, valid, allowed, slope_step, prob=rates.flying_prob, rng=rng)
    spike_where = on_part if part is not None else (surface == LABEL_FLOOR)
    up, down = out.spikes(depth, valid, spike_where & allowed & ~flying, prob=rates.spike_prob,
                          up_fraction=rates.spike_up_fraction, rng=rng)
    if part is not None:
        cluster_id = out.floating_clusters(
            depth, clean, valid, on_part, allowed, sigma,
            count=int(rng.poisson(rates.clusters)), rates=rates, a_max_px=a_max, rng=rng,
        )
        above = out.above_rim_groups(
            depth, valid, on_part | (surface == LABEL_FLOOR), allowed, sigma,
            count=int(rng.poisson(rates.above_rim)), rates=rates, a_max_px=a_max,
            rim_depth_mm=rim_depth_mm, rng=rng,
        )
    else:
        cluster_id = np.zeros((h, w), np.int32)
        above = np.zeros((h, w), bool)
    kind_img = np.zeros((h, w), np.uint8)
    kind_img[flying] = out.OUTLIER_FLYING
    kind_img[up] = out.OUTLIER_SPIKE_UP
    kind_img[down] = out.OUTLIER_SPIKE_DOWN
    kind_img[cluster_id > 0] = out.OUTLIER_FLOATING
    kind_img[above] = out.OUTLIER_ABOVE_RIM

    # a sensor with depth steps: an outlier rounded to within one step of its surface is gone
    if q > 0:
        depth = quantize_depth(depth, q)
        with np.errstate(invalid="ignore"):
            lost = (kind_img > 0) & ~(np.abs(depth - clean) >= q)
        depth[lost] = quantize_depth(depth0[lost], q)
        valid[lost] = valid0[lost]
        kind_img[lost] = out.OUTLIER_NONE

    valid &= np.isfinite(depth)
    kind_img[~valid] = out.OUTLIER_NONE
    # anything higher than the rim is an easy outlier (paper Figure 3a), whatever made it
    with np.errstate(invalid="ignore"):
        kind_img[(kind_img > 0) & (depth < rim_depth_mm)] = out.OUTLIER_ABOVE_RIM
    cluster_id[kind_img != out.OUTLIER_FLOATING] = 0
    truth = kind_img > 0

    rays = pixel_rays(K)
    xyz = (rays * (np.where(valid, depth, np.nan) / 1000.0)[..., None]).astype(np.float32)

    # the paper's truth: farther than 3 Err from every true surface (replay.synth.surfaces)
    xyz_mm = xyz.astype(np.float64) * 1000.0
    err = err_mm(xyz_mm[..., 2], sigma, K.fx, cell_mm=grid_step, quantize_mm=q)
    off = off_surface(xyz_mm, err, handmade_surfaces(scene, camera_height_mm=CAMERA_HEIGHT_MM))
    frame = Frame(
        xyz=xyz,
        rgb=rgb,
        stamp_ns=stamp_ns(seed, index),
        frame_id=FRAME_ID,
        intrinsics=K,
        topic=layout.CLOUD,
        index=int(index),
        masks={layout.TRUTH_OUTLIERS: truth, layout.TRUTH_OFF_SURFACE: off},
        codes={layout.TRUTH_OUTLIER_KIND: kind_img},
    )
    return SynthFrame(
        frame, truth, kind_img, cluster_id, surface, clean.astype(np.float32), figure11, saturated, scene,
        is_shiny, a_max, T_cam_bin(pose), q, off, err.astype(np.float32),
    )
