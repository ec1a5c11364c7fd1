"""The zone of a frame, what the bin stages leave for the filters, and the helpers the filter methods
use on it: its bounding box and crop, and the points SOR judges (``sor.region``).

Below both the engine (:mod:`replay.pipeline.stages`, which computes the zone) and the methods
(:mod:`replay.pipeline.methods`, which judge it): a method reads the zone and these helpers, never the
engine that calls it. No I/O, no viewer.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
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


def sor_region(height_mm: np.ndarray, zone: np.ndarray, zcut: ZCutParams) -> np.ndarray:
    """(H, W) bool: the top part of the pile SOR judges (``sor.region = "top"``, paper §5.3).

    The zone's pixels at or above the z-cut's lowest cut: height ≥ z_max − K·Δd, with z_max the
    highest valid height and K = floor(d_max / Δd + 1e-9), computed as the z-cut computes its
    thresholds (docs/filters.md). SOR and the z-cut then judge the same top portion of the data.
    """
    finite = np.isfinite(height_mm)
    if not finite.any():
        return np.zeros_like(zone)
    z_max = float(np.max(height_mm, where=finite, initial=-np.inf))  # no copy of the finite heights
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


def sor_judged(zone: Zone, config: SorConfig) -> np.ndarray:
    """(H, W) bool: the points SOR judges for ``config.sor.region``."""
    if config.sor.region == "zone":
        return zone.zone
    return sor_region(zone.height_mm, zone.zone, config.zcut)


def sor_on_zone(frame: Frame, zone: Zone, config: SorConfig) -> np.ndarray:
    """(H, W) bool: SOR's outliers among the points it judges (easy outliers not included)."""
    s = config.sor
    return _sor_on_zone(frame.xyz, sor_judged(zone, config),
                        whole=zone.removal is None and s.region == "zone", k=s.k, std_ratio=s.std_ratio,
                        convention=s.convention)


