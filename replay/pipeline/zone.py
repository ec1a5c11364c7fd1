"""The zone of a frame, what the bin stages leave for the filters, and the helpers the filter methods
use on it: its bounding box and crop, and the points SOR judges (``sor.region``).

Below both the engine (:mod:`replay.pipeline.stages`, which computes the zone) and the methods
(:mod:`replay.pipeline.methods`, which judge it): a method reads the zone and these helpers, never the
engine that calls it. No I/O, no viewer.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

if TYPE_CHECKING:  # the records' field types only: importing this module loads no numba, OpenCV nor Open3D
    from replay.logs.frame import Frame
    from zcut.bin_check import BinCheck
    from zcut.bin_model import BinModel
    from zcut.binmask import BinMaskResult
    from zcut.params import SorParams, ZCutParams
    from zcut.registration import RegistrationResult
    from zcut.removal import RemovalResult


class SorConfig(Protocol):
    """What the SOR helpers read of a :class:`~replay.pipeline.config.PipelineConfig`."""

    @property
    def sor(self) -> SorParams: ...

    @property
    def zcut(self) -> ZCutParams: ...


@dataclass(frozen=True, slots=True)
class BinLocation:
    """The bin stages of one frame: bin mask and registration (:func:`replay.pipeline.stages.locate_bin`).

    Attributes
    ----------
    valid : (H, W) bool ndarray
        Pixels with a finite point.
    bin_mask : BinMaskResult or None
        None when the bin stages were skipped.
    registration : RegistrationResult or None
        None when the bin stages were skipped.
    timings : dict[str, float]
        Seconds of ``"bin_mask"`` and ``"registration"`` (those that ran).
    seconds : float
        Their total, with the glue.
    warnings : tuple of str
    ring : (H, W) bool ndarray or None
        The frame's certain bin pixels, the rim and upper walls the model was registered to
        (:func:`zcut.binmask.bin_pixels`); None when no bin was found.
    failure : str
        Why the bin stages failed although a bin model and an RGB image were given (no bin in the
        image, coordinates no registration can take); "" otherwise.
    bin_model : BinModel or None
        The bin model registered (the method ``explained`` poses it by ``registration``); None
        when the bin stages did not register one.
    """

    valid: np.ndarray
    bin_mask: BinMaskResult | None
    registration: RegistrationResult | None
    timings: dict[str, float]
    seconds: float
    warnings: tuple[str, ...]
    ring: np.ndarray | None = None
    failure: str = ""
    bin_model: BinModel | None = None


def sor_region(height_mm: np.ndarray, zone: np.ndarray, zcut: ZCutParams, *, z_max: float | None = None) -> np.ndarray:
    """(H, W) bool: the top part of the pile SOR judges (``sor.region = "top"``, paper §5.3).

    The zone's pixels at or above the z-cut's lowest cut: height ≥ z_max − K·Δd, with z_max the
    highest valid height and K = floor(d_max / Δd + 1e-9), computed as the z-cut computes its
    thresholds (docs/filters.md). SOR and the z-cut then judge the same top portion of the data.
    ``z_max``: that highest finite height of ``height_mm`` when a stage found it already (the z-cut's
    ``CutResult.z_max`` of this very image, NaN when no height is finite: :func:`known_z_max`); else it is found
    here (two passes over the heights fewer when given).
    """
    if z_max is None:
        finite = np.isfinite(height_mm)
        if not finite.any():
            return np.zeros_like(zone)
        z_max = float(np.max(height_mm, where=finite, initial=-np.inf))  # no copy of the finite heights
    elif z_max != z_max:  # NaN: no finite height
        return np.zeros_like(zone)
    threshold = z_max - zcut.n_levels * zcut.step
    with np.errstate(invalid="ignore"):
        return zone & (height_mm >= threshold)


def zone_crop(xyz: np.ndarray, zone: np.ndarray, *, whole: bool
              ) -> tuple[tuple[slice, slice], np.ndarray] | None:
    """(crop slices, the zone's points with everything else NaN) on the zone's bounding box; None
    when the zone is empty. ``whole``: the zone is every valid pixel, ``xyz`` is used as it is.

    SOR sees only the zone's points, so it runs on the zone's bounding box: the same point set in
    the same row-major order, hence the same result as on the whole NaN-masked frame, with less
    to scan.
    """
    if whole:
        return (slice(None), slice(None)), xyz
    sl = zone_box(zone)
    if sl is None:
        return None
    z = zone[sl]
    return sl, np.where(z[..., None], xyz[sl], np.float32(np.nan)).astype(xyz.dtype, copy=False)


def zone_box(zone: np.ndarray) -> tuple[slice, slice] | None:
    """The slices of the zone's bounding box; None when the zone is empty."""
    rows = np.flatnonzero(zone.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(zone.any(axis=0))
    return slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1)


def _sor_on_zone(xyz: np.ndarray, zone: np.ndarray, *, whole: bool, **kw: Any) -> np.ndarray:
    """(H, W) bool: SOR outliers among the zone's points only (as on the frame with the rest set to
    NaN: SOR's ``mask`` on the zone's bounding box, no masked copy)."""
    from zcut.sor import sor_outliers  # numba's kernels, loaded where used

    out = np.zeros_like(zone)
    if whole:
        return np.asarray(sor_outliers(xyz, **kw) & zone)
    sl = zone_box(zone)
    if sl is None:
        return out
    z = zone[sl]
    out[sl] = sor_outliers(xyz[sl], mask=z, **kw) & z
    return out


def sor_masks_on_zone(xyz: np.ndarray, zone: np.ndarray, *, whole: bool, k: int, convention: str,
                      std_ratios: Iterable[float]) -> np.ndarray:
    """(n, H, W) bool: :func:`_sor_on_zone` for every std_ratio from one d̄ computation (a sweep),
    exactly equal to it for each ratio."""
    from zcut.sor import sor_mean_distances, sor_outliers_from_distances

    ratios = list(std_ratios)
    out = np.zeros((len(ratios), *zone.shape), dtype=bool)
    if whole:
        dbar = sor_mean_distances(xyz, k=k, convention=convention)
        return np.asarray(sor_outliers_from_distances(dbar, k=k, std_ratios=ratios, convention=convention) & zone[None])
    sl = zone_box(zone)
    if sl is None:
        return out
    dbar = sor_mean_distances(xyz[sl], k=k, convention=convention, mask=zone[sl])
    out[(slice(None), *sl)] = sor_outliers_from_distances(dbar, k=k, std_ratios=ratios, convention=convention) \
        & zone[sl][None]
    return out


@dataclass(frozen=True, slots=True)
class Zone:
    """What the bin stages leave for the filters (:func:`replay.pipeline.stages.bin_zone`).

    Attributes
    ----------
    located : BinLocation
    removal : RemovalResult or None
        None when the bin stages were skipped.
    zone : (H, W) bool ndarray
        Pixels the z-cut and SOR judge (valid minus table, easy outliers and bin).
    height_mm : (H, W) float64 ndarray
        The height image given to the z-cut.
    easy : (H, W) bool ndarray
        The points above the rim (all False when the bin stages were skipped).
    timings : dict[str, float]
        Seconds of the bin stages that ran.
    warnings : tuple of str
    bin_check : BinCheck or None
        As :attr:`replay.pipeline.stages.FrameResult.bin_check`.
    """

    located: BinLocation
    removal: RemovalResult | None
    zone: np.ndarray
    height_mm: np.ndarray
    easy: np.ndarray
    timings: dict[str, float]
    warnings: tuple[str, ...]
    bin_check: BinCheck | None = None
    #: what a method found out about ``height_mm`` while it read it, for the others (:func:`note_z_max`); not
    #: part of the zone's value
    found: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)


def note_z_max(zone: Zone, height_mm: np.ndarray, z_max: float) -> None:
    """Remember the highest finite height of ``height_mm`` (NaN: none is finite), found by a method that read
    it (the z-cut: ``CutResult.z_max``), when it is the zone's own height image; :func:`known_z_max` gives it."""
    if height_mm is zone.height_mm:
        zone.found["z_max"] = (height_mm, float(z_max))


def known_z_max(zone: Zone) -> float | None:
    """The highest finite height of the zone's height image noted by :func:`note_z_max` (NaN: none is finite),
    None when no method noted it for this very array."""
    known = zone.found.get("z_max")
    return known[1] if known is not None and known[0] is zone.height_mm else None


def sor_judged(zone: Zone, config: SorConfig) -> np.ndarray:
    """(H, W) bool: the points SOR judges for ``config.sor.region`` (with the z-cut's z_max when it ran
    first on this zone: :func:`known_z_max`)."""
    if config.sor.region == "zone":
        return zone.zone
    return sor_region(zone.height_mm, zone.zone, config.zcut, z_max=known_z_max(zone))


def sor_on_zone(frame: Frame, zone: Zone, config: SorConfig) -> np.ndarray:
    """(H, W) bool: SOR's outliers among the points it judges (easy outliers not included)."""
    s = config.sor
    return _sor_on_zone(frame.xyz, sor_judged(zone, config),
                        whole=zone.removal is None and s.region == "zone", k=s.k, std_ratio=s.std_ratio,
                        convention=s.convention)


