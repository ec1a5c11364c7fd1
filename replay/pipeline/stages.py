"""The paper's pipeline on one frame (§5.2-§5.3): no I/O, no viewer.

bin mask (RGB) -> registration of the bin model (ICP) -> removal of table, easy outliers and bin ->
z-cut clusters and outliers on the remaining zone -> SOR on the same zone -> α, β.

With no RGB image, no bin model, or no bin found in the image, the bin stages are skipped (a
warning is recorded in the result) and the z-cut runs on the whole frame: then
``result.zcut_outliers == zcut.zcut_outliers(-1000 * z, ...)`` exactly (docs/formats.md).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from replay.logs.frame import Frame
from replay.pipeline.config import PipelineConfig
from replay.pipeline.methods import MethodOutput, registry
from replay.pipeline.zone import BinLocation, Zone  # the zone's records (and its helpers) live in zone.py
from zcut.bin_check import BinCheck, check_bin_removal, failed_bin_check
from zcut.binmask import BinMaskResult, bin_mask, bin_pixels
from zcut.cuts import CutResult
from zcut.errors import InputShapeError, ParameterError, ZcutError
from zcut.metrics import RelativeMetrics, relative_metrics
from zcut.prepared_model import PreparedBinModel
from zcut.registration import (
    RegistrationResult,
    pose_fitness_at_least,
    prepare_target,
    register_bin,
    subsampled_points,
)
from zcut.removal import RemovalResult, remove_table_and_bin, valid_pixels

STAGES = ("bin_mask", "registration", "removal", "zcut", "sor", "metrics")
REGISTRATION_MAX_POINTS = 150_000
# the seed pose (the log's first frame's) is refined with the fine pass only when, on this frame, it
# already fits at least this fraction as well as it did there; else the full coarse-to-fine runs
SEED_FITNESS_KEPT = 0.9


@dataclass(frozen=True, slots=True)
class FrameResult:
    """Everything the pipeline computed for one frame.

    Attributes
    ----------
    index : int
    stamp_ns : int
    valid : (H, W) bool ndarray
        Pixels with a finite point.
    bin_mask : BinMaskResult or None
        None when the bin stages were skipped.
    registration : RegistrationResult or None
        None when the bin stages were skipped before it.
    removal : RemovalResult or None
        None when the bin stages were skipped.
    zone : (H, W) bool ndarray
        Pixels the filters judge (valid minus table, easy outliers and bin).
    height_mm : (H, W) float64 ndarray
        The height image given to the z-cut.
    cut : CutResult
        Clusters and levels of the z-cut.
    outliers : dict[str, (H, W) bool ndarray]
        Every base method's outliers (``config.base_methods``: the z-cut always, SOR and the other
        filters when the config's methods name them), each in the zone plus the easy outliers above
        the rim; unions and the report's derived methods come from
        :func:`replay.pipeline.methods.method_mask`.
    metrics : RelativeMetrics
        α, β of the zone-only z-cut and SOR masks (paper eqs. 3-4): the easy outliers are common to
        both and left out.
    timings : dict[str, float]
        Seconds per stage (keys from :data:`STAGES` and the method names that ran) and ``"total"``.
    warnings : tuple of str
        Stages skipped or failed, for the user to see.
    bin_check : BinCheck or None
        Whether the bin removal worked (:func:`zcut.bin_check.check_bin_removal`); flagged when it
        did not or when the bin stages failed; None when they did not run (no RGB image, no bin
        model, disabled).
    details : dict[str, object]
        The other base methods' own results for the viewer (``MethodOutput.detail``, e.g. the
        ``explained`` method's fits and distance image), by method; the z-cut's is :attr:`cut`.
    """

    index: int
    stamp_ns: int
    valid: np.ndarray
    bin_mask: BinMaskResult | None
    registration: RegistrationResult | None
    removal: RemovalResult | None
    zone: np.ndarray
    height_mm: np.ndarray
    cut: CutResult
    outliers: dict[str, np.ndarray]
    metrics: RelativeMetrics
    timings: dict[str, float]
    warnings: tuple[str, ...]
    bin_check: BinCheck | None = None
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def bin_flagged(self) -> bool:
        """The bin check flagged this frame (its figures rest on a removal that did not work)."""
        return self.bin_check is not None and self.bin_check.flagged

    @property
    def zcut_outliers(self) -> np.ndarray:
        """(H, W) bool: z-cut outliers in the zone, plus the easy outliers above the rim."""
        return self.outliers["zcut"]

    @property
    def sor_outliers(self) -> np.ndarray:
        """(H, W) bool: SOR outliers in the zone, plus the easy outliers (all False when SOR did not
        run: disabled, or not among the config's methods)."""
        s = self.outliers.get("sor")
        return s if s is not None else np.zeros_like(self.valid)

    @property
    def easy_outliers(self) -> np.ndarray:
        """(H, W) bool: points above the rim (all False when the bin stages were skipped)."""
        if self.removal is None:
            return np.zeros_like(self.valid)
        return self.removal.easy_outliers

    @property
    def both_outliers(self) -> np.ndarray:
        """(H, W) bool: found by both the z-cut and SOR."""
        return np.asarray(self.zcut_outliers & self.sor_outliers)

    @property
    def T_cam_bin(self) -> np.ndarray | None:
        """The converged registration's pose, else None."""
        r = self.registration
        return r.T_cam_bin if r is not None and r.converged else None


def locate_bin(
    frame: Frame,
    config: PipelineConfig,
    *,
    bin_model: PreparedBinModel | None = None,
    seed: RegistrationResult | None = None,
) -> BinLocation:
    """Bin mask and registration of one frame (the first stages of :func:`run_frame`).

    No numba-parallel kernels run here (OpenCV, Open3D, scipy and the registration's serial numba ICP,
    which releases the GIL: :mod:`zcut.icp_fast`), so that this may run in another thread while
    :func:`run_frame` finishes another frame. The result depends on this frame and the seed only (no
    other frame), so frames may be processed in any order or split.

    Parameters
    ----------
    frame : Frame
    config : PipelineConfig
    bin_model : PreparedBinModel, optional
        Prepared with ``config``'s registration and removal parameters; without it the bin stages
        are skipped.
    seed : RegistrationResult, optional
        The log's first frame's registration (:meth:`~replay.pipeline.session.ReplaySession.open`);
        when converged (and ``config.registration.seed_from_first_frame``) its pose seeds this one.

    Returns
    -------
    BinLocation
    """
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    warnings: list[str] = []
    xyz = frame.xyz
    valid = frame.known_valid  # the decoder's, written while it unpacked xyz
    if valid is None:
        valid = valid_pixels(xyz)

    bm: BinMaskResult | None = None
    reg: RegistrationResult | None = None
    if not config.bin_mask.enabled:
        warnings.append("bin stages disabled (bin_mask.enabled = false): z-cut on the whole frame")
    elif frame.rgb is None:
        warnings.append("no RGB image: bin stages skipped, z-cut on the whole frame")
    elif bin_model is None:
        warnings.append("no bin model (--bin-model): bin stages skipped, z-cut on the whole frame")
    else:
        t = time.perf_counter()
        bm = bin_mask(frame.rgb, params=config.bin_mask)
        timings["bin_mask"] = time.perf_counter() - t
        if not bm.found:
            failure = "no bin found in the RGB image: bin stages skipped, z-cut on the whole frame"
            warnings.append(failure)
            return BinLocation(valid, None, None, timings, time.perf_counter() - t_start, tuple(warnings),
                               failure=failure)
    if bm is not None:
        assert bin_model is not None
        t = time.perf_counter()
        c = config.registration
        use = seed is not None and seed.converged and c.seed_from_first_frame
        init = seed.T_cam_bin if use and seed is not None else None
        # the bin itself (rim and upper walls), not the shiny parts as bright as its plastic
        pixels = bin_pixels(bm, xyz, ring_frac=c.ring_frac)
        # the ICP downsamples to voxel_mm anyway: a regular subgrid of at most ~150k pixels is enough
        s = max(1, int(np.ceil(np.sqrt(np.count_nonzero(pixels) / REGISTRATION_MAX_POINTS))))
        try:
            target = prepare_target(subsampled_points(xyz, pixels, step=s), voxel_m=c.voxel_m,
                                    intrinsics=frame.intrinsics)
        except InputShapeError as e:  # e.g. garbage coordinates no voxel grid can hold
            failure = f"bin registration impossible ({e}): bin stages skipped, z-cut on the whole frame"
            warnings.append(failure)
            return BinLocation(valid, None, None, timings, time.perf_counter() - t_start, tuple(warnings),
                               failure=failure)
        reg = None
        if init is not None:
            assert seed is not None  # init is its pose
            # a static bin: the seed pose needs only the fine pass (a moved bin: the full one); whether its
            # fitness still holds is all the stage needs (counted until that is decided)
            if pose_fitness_at_least(bin_model.icp, target, init, max_correspondence_m=c.fine_correspondence_m,
                                     fitness=SEED_FITNESS_KEPT * seed.fitness):
                reg = register_bin(bin_model.icp, target, params=c, init=init, coarse=False)
                if not reg.converged:
                    reg = None
        if reg is None:
            reg = register_bin(bin_model.icp, target, params=c)
        timings["registration"] = time.perf_counter() - t
        return BinLocation(valid, bm, reg, timings, time.perf_counter() - t_start, tuple(warnings), pixels,
                           bin_model=bin_model.model)
    return BinLocation(valid, bm, reg, timings, time.perf_counter() - t_start, tuple(warnings))


def bin_zone(frame: Frame, config: PipelineConfig, *, bin_model: PreparedBinModel | None = None,
             seed: RegistrationResult | None = None, located: BinLocation | None = None) -> Zone:
    """The bin stages of :func:`run_frame`: bin mask, registration and removal, up to the zone and
    its height image (shared by ``run_frame`` and a sweep, which filters one zone many times)."""
    if located is None:
        located = locate_bin(frame, config, bin_model=bin_model, seed=seed)
    timings = dict(located.timings)
    warnings = list(located.warnings)
    xyz = frame.xyz
    valid = located.valid
    bm = located.bin_mask
    reg = located.registration
    rem: RemovalResult | None = None
    check: BinCheck | None = None
    if located.failure:
        check = failed_bin_check(f"the bin stages failed ({located.failure}): this frame's figures judge the "
                                 "bin and the table as parts; check the RGB image, the bin_mask parameters and "
                                 "the bin model", params=config.removal)
    if bm is not None:
        assert bin_model is not None and reg is not None
        t = time.perf_counter()
        if bin_model.removal.params != config.removal:
            raise ParameterError("run_frame: the bin model was prepared with other removal parameters than "
                                 "the config's (prepare it with zcut.bin_model.prepare_bin_model)")
        if reg.converged:
            rem = remove_table_and_bin(xyz, bm.mask, index=bin_model.removal, T_cam_bin=reg.T_cam_bin,
                                       ring=located.ring)
            rim_in_view = min(reg.n_rim / len(bin_model.icp.rim), 1.0) if len(bin_model.icp.rim) else 0.0
            check = check_bin_removal(rem, located.ring if located.ring is not None else np.zeros_like(valid),
                                      params=config.removal, band_mm=config.zcut.max_depth, rim_in_view=rim_in_view,
                                      xyz=xyz, index=bin_model.removal, T_cam_bin=reg.T_cam_bin)
        else:
            warnings.append(f"bin registration failed ({reg.reason}): only the table removed")
            rem = remove_table_and_bin(xyz, bm.mask)
            check = failed_bin_check(f"the bin registration failed ({reg.reason}): only the table was removed, "
                                     "the filters judged the bin as parts; is the bin model of this bin "
                                     "(zcut bin-model from empty scans of it) and is the bin in view?",
                                     params=config.removal)
        timings["removal"] = time.perf_counter() - t
    if rem is None:
        return Zone(located, None, valid, -1000.0 * xyz[..., 2].astype(np.float64), np.zeros_like(valid),
                    timings, tuple(warnings), check)
    return Zone(located, rem, rem.zone, rem.height_mm, rem.easy_outliers, timings, tuple(warnings), check)


def run_frame(
    frame: Frame,
    config: PipelineConfig,
    *,
    bin_model: PreparedBinModel | None = None,
    seed: RegistrationResult | None = None,
    located: BinLocation | None = None,
) -> FrameResult:
    """Run every stage on one frame.

    Parameters
    ----------
    frame : Frame
    config : PipelineConfig
        Resolved (:func:`replay.pipeline.config.resolve`).
    bin_model : PreparedBinModel, optional
        Prepared with ``config``'s registration and removal parameters; without it the bin stages
        are skipped.
    seed : RegistrationResult, optional
        The log's first frame's registration; its converged pose seeds this frame's when
        ``config.registration.seed_from_first_frame``.
    located : BinLocation, optional
        :func:`locate_bin` of this frame, already computed (e.g. in another thread, while the
        previous frame finished); then ``seed`` is not used.

    Returns
    -------
    FrameResult
    """
    t_start = time.perf_counter()
    z = bin_zone(frame, config, bin_model=bin_model, seed=seed, located=located)
    return judge_zone(frame, z, config, t_start=t_start)


def judge_zone(frame: Frame, z: Zone, config: PipelineConfig, *, t_start: float,
               done: Mapping[str, tuple[MethodOutput, float]] | None = None) -> FrameResult:
    """The stages of :func:`run_frame` after :func:`bin_zone`: every base method of ``config`` on the
    zone, α and β, the result.

    ``t_start``: the ``time.perf_counter()`` at which the frame's own work began (for the total).
    ``done``: ``{method: (its output, its seconds)}`` of base methods already run on this same zone
    with the same parameters (a comparison of two configs shares them, ``studies/compare.py``):
    they are taken as they are, not run again.
    """
    located = z.located
    timings = dict(z.timings)
    warnings = list(z.warnings)
    valid, zone, easy = located.valid, z.zone, z.easy

    found = run_methods(frame, z, config, timings=timings, warnings=warnings, done=done)
    cut = found["zcut"].detail
    zone_only = {name: out.outliers for name, out in found.items()}

    t = time.perf_counter()
    sor_zone = zone_only.get("sor")
    metrics = relative_metrics(sor_zone if sor_zone is not None else np.zeros_like(valid), zone_only["zcut"])
    timings["metrics"] = time.perf_counter() - t
    timings["total"] = located.seconds + time.perf_counter() - t_start
    return FrameResult(
        index=frame.index,
        stamp_ns=frame.stamp_ns,
        valid=valid,
        bin_mask=located.bin_mask,
        registration=located.registration,
        removal=z.removal,
        zone=zone,
        height_mm=z.height_mm,
        cut=cut,
        outliers={name: m | easy for name, m in zone_only.items()},
        metrics=metrics,
        timings=timings,
        warnings=tuple(warnings),
        bin_check=z.bin_check,
        details={name: out.detail for name, out in found.items() if name != "zcut" and out.detail is not None},
    )


def run_methods(frame: Frame, zone: Zone, config: PipelineConfig, *, timings: dict[str, float],
                warnings: list[str], done: Mapping[str, tuple[MethodOutput, float]] | None = None,
                ) -> dict[str, MethodOutput]:
    """Every base method of ``config`` on a zone (:mod:`replay.pipeline.methods`), timed.

    Adds each method's seconds to ``timings`` under its name and its warning, if any, to
    ``warnings``; a method that needs the camera model on a frame without one returns no outliers
    and says so. ``done``: ``{method: (output, seconds)}`` already computed on this zone with the
    same parameters, taken as they are (in the same order, with the same warnings).
    """
    known = registry()
    out: dict[str, MethodOutput] = {}
    for name in config.base_methods:
        method = known[name]
        t = time.perf_counter()
        if done is not None and name in done:
            res, seconds = done[name]
            timings[name] = seconds
            if res.warning:
                warnings.append(res.warning)
            out[name] = res
            continue
        if method.needs_intrinsics and frame.intrinsics is None:
            res = MethodOutput(np.zeros_like(zone.zone),
                               warning=f"{name}: needs the camera model and this frame has none (no CameraInfo): "
                                       f"no outliers")
        else:
            try:
                res = method.run(frame, zone, config)
            except ZcutError as e:  # e.g. a camera model of another size than this frame
                res = MethodOutput(np.zeros_like(zone.zone), warning=f"{name}: {e}: no outliers")
        timings[name] = time.perf_counter() - t
        if res.warning:
            warnings.append(res.warning)
        out[name] = res
    return out
