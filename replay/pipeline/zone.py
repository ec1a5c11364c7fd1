"""The zone of a frame, what the bin stages leave for the filters, and the helpers the filter methods
use on it: its bounding box and crop, and the points SOR judges (``sor.region``).

Below both the engine (:mod:`replay.pipeline.stages`, which computes the zone) and the methods
(:mod:`replay.pipeline.methods`, which judge it): a method reads the zone and these helpers, never the
engine that calls it. No I/O, no viewer.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

if TYPE_CHECKING:  # the records' field types only: importing this module loads no numba, OpenCV nor Open3D
    from replay.logs.frame import Frame
    from zcut.bin_check import BinCheck
    from zcut.bin_model import BinModel
    from zcut.binmask import BinMaskResult
    from zcut.cuts import CutResult
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
    return _at_or_above(height_mm, zone, z_max - zcut.n_levels * zcut.step)


def sor_region_of_cut(height_mm: np.ndarray, zone: np.ndarray, zcut: ZCutParams, cut: CutResult) -> np.ndarray:
    """:func:`sor_region` ``(height_mm, zone, zcut)`` from the z-cut's own result on these heights with these
    parameters (``cut = zcut.cuts.find_clusters(height_mm, params=zcut)``), bit for bit: ``cut.z_max`` is
    the largest finite height (NaN when there is none, and the region is then empty), the value of
    :func:`sor_region`'s masked maximum but for the sign of a zero, which no comparison tells apart (a
    threshold of -0.0 or +0.0 keeps the same heights). What is left is the zone's pixels at or above the
    threshold: no pass over the heights for their finiteness and maximum."""
    if not cut.z_max == cut.z_max:  # NaN: no finite height
        return np.zeros_like(zone)
    return _at_or_above(height_mm, zone, cut.z_max - zcut.n_levels * zcut.step)


def _at_or_above(height_mm: np.ndarray, zone: np.ndarray, threshold: float) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        out: np.ndarray = zone & (height_mm >= threshold)
        return out


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
    _cuts: _Memo = field(default_factory=lambda: _Memo(), init=False, repr=False, compare=False)

    def cut(self, params: ZCutParams) -> CutResult:
        """The z-cut of this zone's heights, ``zcut.cuts.find_clusters(height_mm, params=params)``, computed
        once per parameter set by whichever caller asks first (the method ``zcut``, SOR's top region) and
        shared: a frame's quantity, not one method's side effect: each caller alone gets the same result.
        Its arrays are not to be written (the callers read them; ``pixel_level`` is read-only). An error of
        the z-cut (e.g. too many levels) is raised to every caller and not kept."""
        cut: CutResult = self._cuts.get(params, lambda: _find_clusters(self.height_mm, params))
        return cut


class _Memo:
    """A zone's shared results by parameter set, each computed once (under a lock: the first caller
    computes, a concurrent one waits for it)."""

    __slots__ = ("_lock", "_got")

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._got: dict[Any, Any] = {}

    def __reduce__(self) -> tuple[type[_Memo], tuple[()]]:  # a copied or pickled zone computes its own again
        return _Memo, ()

    def get(self, key: Any, make: Any) -> Any:
        with self._lock:
            if key not in self._got:
                self._got[key] = make()
            return self._got[key]


def _find_clusters(height_mm: np.ndarray, params: ZCutParams) -> CutResult:
    from zcut.cuts import find_clusters  # numba's kernels, loaded where used

    return find_clusters(height_mm, params=params)


def sor_judged(zone: Zone, config: SorConfig) -> np.ndarray:
    """(H, W) bool: the points SOR judges for ``config.sor.region``: with ``"top"``, :func:`sor_region`,
    from the zone's z-cut (:meth:`Zone.cut`) when the z-cut takes these parameters (the same region)."""
    if config.sor.region == "zone":
        return zone.zone
    from zcut.errors import ZcutError

    try:
        cut = zone.cut(config.zcut)
    except ZcutError:  # the z-cut refuses these parameters (e.g. too many levels): the region all the same
        return sor_region(zone.height_mm, zone.zone, config.zcut)
    return sor_region_of_cut(zone.height_mm, zone.zone, config.zcut, cut)


def sor_on_zone(frame: Frame, zone: Zone, config: SorConfig) -> np.ndarray:
    """(H, W) bool: SOR's outliers among the points it judges (easy outliers not included)."""
    s = config.sor
    return _sor_on_zone(frame.xyz, sor_judged(zone, config),
                        whole=zone.removal is None and s.region == "zone", k=s.k, std_ratio=s.std_ratio,
                        convention=s.convention)


