"""One ray-traced scan: bin pose -> physics pile -> meshes -> light paths -> decoded cloud + truth.

:func:`synthesize_raytraced_frame` reads as its steps: the bin pose (the hand-made generator's, so
that both generators put the bin in the same place for the same seed and frame), the pile dropped
by the rigid-body simulation, the scene's meshes, the traced light, the decoded and triangulated
cloud, the colour image, and the truth from geometry:

- **Truth rule.** A measured pixel is a true outlier when its noise-free decoded depth lies farther
  than ``outlier_sigmas`` (4) noise sigmas of that pixel from every surface its footprint sees
  (the centre ray's first hit and each sub-pixel ray's), measured along z. The sigma is the
  pixel's own (it grows as its fringe signal weakens), so the rule is "farther than the sensor
  noise explains", and a pixel made wrong by noise alone is never an outlier.
- **The paper's truth** (``/ground_truth/off_surface``, :mod:`replay.synth.surfaces`): a measured
  point farther than 3 × Err from every triangle of the scene, Err = sqrt(sigma² + (z / f)² / 2)
  (the pixel's noise sigma and half the diagonal of its footprint).
- **Kinds** (``replay.logs.layout.RAYTRACED_OUTLIER_KINDS``): the depth decoded from the direct
  light alone already fails the rule -> ``mixed_pixel`` (7: sub-pixels on different surfaces);
  else adding the specular bounces makes it fail -> ``interreflection`` (6); else the glare did ->
  ``saturation_edge`` (8). Any outlier higher than the bin's rim is ``above_rim`` (5), as in the
  hand-made generator (the pipeline removes those itself).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from replay.logs import layout
from replay.logs.frame import Frame
from replay.presets import BIN, PART_KINDS
from replay.synth.parts import face_area_px
from replay.synth.raytrace import optics
from replay.synth.raytrace.camera_filters import CameraFilters, apply_camera_filters
from replay.synth.raytrace.pile import Pile, drop_parts, part_count
from replay.synth.raytrace.scene import build_scene
from replay.synth.scene import LABEL_FLOOR, LABEL_RIM, LABEL_WALL, lean_walls
from replay.synth.sensor import (
    CAMERA_HEIGHT_MM,
    FULL_SIZE,
    Render,
    check_size,
    default_intrinsics,
    pixel_rays,
    shade_rgb,
)
from replay.synth.surfaces import err_mm, off_surface
from replay.synth.synthesize import (
    FRAME_ID,
    T_cam_bin,
    bin_pose_for,
    check_pile_for,
    frame_rng,
    pile_distance_m,
    stamp_ns,
)
from zcut.errors import ParameterError

_CODE = {name: code for code, name in layout.OUTLIER_KINDS.items()}
OUTLIER_INTERREFLECTION = _CODE["interreflection"]
OUTLIER_MIXED_PIXEL = _CODE["mixed_pixel"]
OUTLIER_SATURATION_EDGE = _CODE["saturation_edge"]
OUTLIER_ABOVE_RIM = _CODE["above_rim"]

#: mean pile height above the floor, drawn uniformly (mm): lower than the hand-made generator's
#: 35-55 mm so that the simulation of the pile fits the time budget of a frame (docs/raytraced.md)
FILL_RANGE_MM = (25.0, 40.0)
#: most parts one pile may hold (the simulation's cost grows with the contacts)
MAX_PARTS = 250


@dataclass(frozen=True, slots=True)
class RaytracedFrame:
    """A ray-traced scan with everything known about it.

    Attributes
    ----------
    frame : Frame
        What a log holds (xyz float32 metres NaN-invalid, rgb, intrinsics, truth mask and kind codes).
    truth : (H, W) bool ndarray
        True outliers (the rule of the module docstring).
    outlier_kind : (H, W) uint8 ndarray
        Codes of ``layout.OUTLIER_KINDS`` (5-8), nonzero exactly where ``truth`` is set.
    depth_true_m : (H, W) float32 ndarray
        Camera z (m) of the centre ray's first hit, NaN where it hits nothing (``/ground_truth/depth``).
    error_mm : (H, W) float64 ndarray
        Noise-free decoded depth minus the true depth (NaN where not measured).
    sigma_mm : (H, W) float64 ndarray
        The pixel's depth noise sigma.
    surface : (H, W) uint8 ndarray
        ``LABEL_*`` of the centre ray's surface.
    saturated : (H, W) bool ndarray
        Pixels lost because even the shortest exposure saturates.
    pile : Pile or None
    a_max_px : float
        Pixel area of the part's largest face at the pile top (NaN for an empty bin).
    T_cam_bin : (4, 4) float64 ndarray
    off_surface : (H, W) bool ndarray
        The paper's truth (``/ground_truth/off_surface``): the valid points farther than 3 × Err
        from every triangle of the scene (parts with all their faces, bin, table), Err =
        ``sqrt(sigma² + (z / f)² / 2)`` (:func:`replay.synth.surfaces.err_mm`).
    err_mm : (H, W) float32 ndarray
        That Err (NaN where not measured).
    cpu_s : dict[str, float]
        CPU seconds of each step (``pile``, ``scene``, ``trace``, ``measure``, ``off_surface``, and
        ``camera_filters`` when they ran).
    camera_removed : (H, W) uint8 ndarray or None
        Where the camera's own filters discarded a measured point, which filter
        (:mod:`.camera_filters` codes: 1 noise, 2 reflection, 3 outlier; 0 kept); None when they did
        not run.
    """

    frame: Frame
    truth: np.ndarray
    outlier_kind: np.ndarray
    depth_true_m: np.ndarray
    error_mm: np.ndarray
    sigma_mm: np.ndarray
    surface: np.ndarray
    saturated: np.ndarray
    pile: Pile | None
    a_max_px: float
    T_cam_bin: np.ndarray
    off_surface: np.ndarray
    err_mm: np.ndarray
    cpu_s: dict[str, float] = field(default_factory=dict)
    camera_removed: np.ndarray | None = None


def raytrace_rng(seed: int, index: int, *, empty: bool) -> np.random.Generator:
    """The generator of the ray tracer's own draws (pile, fill, roughness samples, noise)."""
    return np.random.default_rng([int(seed) % (2**63), int(index), int(empty), 0x52415954])


def check_pile(pile: Pile, *, seed: int, index: int) -> Pile:
    """``pile`` if it holds a part, else :class:`ParameterError`: an empty pile is no scan of parts."""
    if len(pile) == 0:
        raise ParameterError(f"seed {seed}, frame {index}: the simulation left no part in the bin "
                             f"({pile.escaped} fell out); try another seed")
    return pile


@optics.kept_memory()
@optics.small_pages()
def synthesize_raytraced_frame(
    *,
    kind: str = "spheres",
    seed: int = 0,
    index: int = 0,
    size: tuple[int, int] = FULL_SIZE,
    empty: bool = False,
    fill_mm: float | None = None,
    model: optics.SensorModel | None = None,
    pile: str = "floor",
    camera_filters: CameraFilters | None = None,
) -> RaytracedFrame:
    """Ray-trace frame ``index`` of a log with ``seed``: a bin of ``kind`` parts (or the empty bin).

    ``pile="walls"``: the parts lean on the walls of :func:`replay.synth.scene.lean_walls` ``(seed,
    index)`` (the hand-made generator's for the same seed and frame), see
    :func:`~replay.synth.raytrace.pile.drop_parts`. ``camera_filters``: the camera's own filters
    (:mod:`.camera_filters`) on the decoded depth before the cloud is made; None (default) or all
    off: none, and the frame is what it was without the option, bit for bit.

    Raises
    ------
    ParameterError
        Unknown kind, bad size, a pile the simulation left empty, a projector that lights nothing
        the camera sees.
    """
    if not empty and kind not in PART_KINDS:
        raise ParameterError(f"kind must be one of {', '.join(PART_KINDS)}, got {kind!r}")
    h, w = check_size(size)
    pile_kind = check_pile_for(pile, empty=empty)
    model = optics.SensorModel() if model is None else model
    K = default_intrinsics((h, w))
    pose = bin_pose_for(frame_rng(seed, index, empty=empty), empty=empty, index=index)
    rng = raytrace_rng(seed, index, empty=empty)
    cpu: dict[str, float] = {}

    # the pile
    t0 = time.process_time()
    heap = None
    part = None
    if not empty:
        part = PART_KINDS[kind]
        if fill_mm is None:
            fill_mm = float(rng.uniform(*FILL_RANGE_MM))
        count = min(part_count(kind, fill_mm), MAX_PARTS)
        walls = lean_walls(seed, index) if pile_kind == "walls" else ()
        heap = check_pile(drop_parts(kind, pose, rng, count=count, walls=walls), seed=seed, index=index)
    cpu["pile"] = time.process_time() - t0

    # the scene and its light
    t0 = time.process_time()
    scene = build_scene(pose, heap)
    cpu["scene"] = time.process_time() - t0
    t0 = time.process_time()
    rec = optics.trace(scene, K, model, rng)
    cpu["trace"] = time.process_time() - t0
    if not (rec.direct.intensity > 0).any():
        raise ParameterError(
            f"the projector lights nothing the camera sees (baseline {model.baseline_mm:g} mm, "
            f"projector {model.projector_size[0]}x{model.projector_size[1]} px); check the sensor model")

    # decode, triangulate, judge
    t0 = time.process_time()
    z_meas, z_clean, sigma_z, staged, saturated = optics.measure(rec, K, model, rng)
    removed = None
    if camera_filters is not None and camera_filters.enabled:
        t1 = time.process_time()
        filtered = apply_camera_filters(z_meas, rec, pixel_rays(K), model, camera_filters)
        z_meas, removed = filtered.z_mm, filtered.removed
        cpu["camera_filters"] = time.process_time() - t1
    centre = rec.centre
    z_true = np.where(centre.hit, centre.point[:, 2], np.nan).reshape(h, w)
    valid = np.isfinite(z_meas)
    thr = model.outlier_sigmas * sigma_z
    err_final = optics.footprint_distance_mm(z_clean, z_true, rec.sub_depth_mm)
    with np.errstate(invalid="ignore"):
        truth = valid & (err_final > thr)
    # the stages decoded only where the noise-free depth fails the rule (optics.measure): judged at the outliers
    at = np.flatnonzero(truth)
    sub_at = rec.sub_depth_mm.reshape(rec.sub_depth_mm.shape[0], -1)[:, at]
    thr_at, z_true_at = thr.reshape(-1)[at], z_true.reshape(-1)[at]
    with np.errstate(invalid="ignore"):
        wrong_direct = optics.footprint_distance_mm(staged[0].reshape(-1)[at], z_true_at, sub_at) > thr_at
        wrong_bounce = optics.footprint_distance_mm(staged[1].reshape(-1)[at], z_true_at, sub_at) > thr_at
    kind_img = np.zeros((h, w), np.uint8)
    kinds = np.full(at.size, OUTLIER_SATURATION_EDGE, np.uint8)
    kinds[wrong_bounce] = OUTLIER_INTERREFLECTION
    kinds[wrong_direct] = OUTLIER_MIXED_PIXEL
    kind_img.reshape(-1)[at] = kinds
    with np.errstate(invalid="ignore"):
        kind_img[truth & (z_meas < CAMERA_HEIGHT_MM - BIN.height_mm)] = OUTLIER_ABOVE_RIM
    cpu["measure"] = time.process_time() - t0

    # the colour image: the lamp and room light of the hand-made generator, plus the projector's
    # specular light as traced (highlights clip)
    label = centre.label.reshape(h, w)
    normal = centre.normal.reshape(h, w, 3)
    mid = np.maximum(centre.material, 0)
    colours = scene.mat["colour"][mid].reshape(h, w, 3)
    view = Render(np.where(np.isfinite(z_true), z_true, np.inf), normal, label, centre.part.reshape(h, w))
    bin_px = (label == LABEL_FLOOR) | (label == LABEL_WALL) | (label == LABEL_RIM)
    rgb, _ = shade_rgb(view, K, colours, np.zeros((h, w), bool), np.where(bin_px, 0.8, 0.6), rng)
    rgb = np.clip(rgb.astype(np.float64) + 400.0 * rec.specular_light[..., None], 0, 255).astype(np.uint8)

    xyz = (pixel_rays(K) * (z_meas / 1000.0)[..., None]).astype(np.float32)

    # the paper's truth: farther than 3 Err from every triangle of the scene (replay.synth.surfaces)
    t0 = time.process_time()
    xyz_mm = xyz.astype(np.float64) * 1000.0
    err = err_mm(xyz_mm[..., 2], np.where(np.isfinite(sigma_z), sigma_z, 0.0), K.fx)
    # the centre rays' hits lie on those triangles: most points are decided by them without a query
    off = off_surface(xyz_mm, err, scene.surfaces(), on_surface=centre.point.reshape(h, w, 3))
    cpu["off_surface"] = time.process_time() - t0
    frame = Frame(
        xyz=xyz, rgb=rgb, stamp_ns=stamp_ns(seed, index), frame_id=FRAME_ID, intrinsics=K, topic=layout.CLOUD,
        index=int(index), masks={layout.TRUTH_OUTLIERS: truth, layout.TRUTH_OFF_SURFACE: off},
        codes={layout.TRUTH_OUTLIER_KIND: kind_img},
    )
    a_max = (face_area_px(part, fx=K.fx, fy=K.fy, distance_m=pile_distance_m(fill_mm)) if part is not None  # type: ignore[arg-type]  # drawn with the part
             else float("nan"))
    depth_true_m = (z_true / 1000.0).astype(np.float32)
    return RaytracedFrame(
        frame, truth, kind_img, depth_true_m, z_clean - z_true, sigma_z, label, saturated & ~valid, heap, a_max,
        T_cam_bin(pose), off, np.where(np.isfinite(xyz_mm[..., 2]), err, np.nan).astype(np.float32), cpu, removed,
    )
