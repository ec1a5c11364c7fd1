"""Did the bin removal work on this frame? A per-frame figure and a flag (``docs/pipeline.md``).

The registration's fitness does not answer it: it scores the model's rim against the frame within
the fine correspondence distance (3.3 mm by default) and stays at 1.000 with a pose 2 mm off,
where the paper's removal (δ = 0.1 mm) leaves the whole rim in the zone. What breaks the filters is
narrower and can be seen directly: the bin pixels the removal did not explain, where they matter.

The figure counts the frame's *certain bin pixels* — the rim and upper walls the registration was
given (:func:`zcut.binmask.bin_pixels`: bright plastic along the footprint's border; the pile, lying
below the rim and in from the walls, never reaches them) — that the removal left

- in the zone within the z-cut's depth below the zone's top (where the z-cut and SOR look: one such
  pixel above the pile moves the zone's top up to it, and the z-cut, which looks only ``d_max``
  down from the top, no longer reaches the pile), or
- labelled as points above the rim (flagged as outliers by both filters: a tilted pose lifts one
  end of the real rim above the model's).

A frame is flagged when the count exceeds ``RemovalParams.check_threshold_px`` (0 by default:
measured on synthetic piles, a single such pixel at the zone's top cost the frame its whole z-cut
F1, and frames whose removal held had none; see ``docs/bin_robustness.md``), when fewer than
``check_min_ring_px`` certain bin pixels are in view or less than ``check_min_rim_in_view`` of the
model's rim lies in the camera's view (too little of the bin to say), or when the bin stages failed
(:func:`failed_bin_check`: no bin in the image, a registration that did not converge — an
occluded bin, a model of another bin, an empty model).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InputShapeError, ParameterError, describe_array
from .params import RemovalParams
from .removal import RemovalResult
from .types import Mask

__all__ = ["BinCheck", "check_bin_removal", "failed_bin_check"]

#: What a user should do about a flagged frame, by cause.
ADVICE_LEAK = ("the bin model does not fit this frame's bin: look at image/bin_check in Rerun (zcut replay "
               "--rrd); if the model is of another bin or the bin changed, rebuild it from empty scans of this bin "
               "(zcut bin-model); if the registration is only a little off, raise removal.max_tolerance_mm")
ADVICE_PAPER = ("the paper's removal (removal.mode = \"paper\", δ = {delta:g} mm) needs a registration right to a "
                "tenth of a millimetre: use removal.mode = \"robust\" (the default) unless reproducing the paper")
ADVICE_HIDDEN = ("the bin is mostly hidden or out of view: this frame's figures rest on an unchecked removal; "
                 "leave it out or check it in Rerun")


@dataclass(frozen=True, slots=True)
class BinCheck:
    """The bin check of one frame.

    Attributes
    ----------
    value : float
        Certain bin pixels left where the filters judge or called above-the-rim outliers (pixels);
        NaN when the bin stages failed (nothing to count).
    threshold : float
        The frame is flagged when ``value`` exceeds it (``RemovalParams.check_threshold_px``).
    flagged : bool
    reason : str
        Why the frame is flagged and what to do ("" when not flagged).
    offending : (H, W) bool ndarray or None
        The pixels counted in ``value``; None when the bin stages failed.
    ring : (H, W) bool ndarray or None
        The certain bin pixels the check looked at; None when the bin stages failed.
    """

    value: float
    threshold: float
    flagged: bool
    reason: str
    offending: Mask | None = None
    ring: Mask | None = None


def failed_bin_check(reason: str, *, params: RemovalParams) -> BinCheck:
    """The check of a frame whose bin stages failed (no bin found, registration failed): flagged.

    Parameters
    ----------
    reason : str
        What failed and what to do, one line.
    params : RemovalParams
    """
    return BinCheck(float("nan"), float(params.check_threshold_px), True, reason, None)


def check_bin_removal(removal: RemovalResult, ring: Mask, *, params: RemovalParams, band_mm: float,
                      rim_in_view: float = 1.0) -> BinCheck:
    """Count the certain bin pixels the removal left where they matter; flag the frame.

    Parameters
    ----------
    removal : RemovalResult
        The frame's removal (with a registered model).
    ring : (H, W) bool ndarray
        The frame's certain bin pixels (:func:`zcut.binmask.bin_pixels`).
    params : RemovalParams
        ``check_threshold_px``, ``check_min_ring_px``.
    band_mm : float
        How far below the zone's top the filters look (the z-cut's ``d_max``, mm, >= 0).
    rim_in_view : float
        The share of the registered model's rim in the camera's view (``n_rim`` of the
        registration over the model's rim points); below ``check_min_rim_in_view`` the frame is
        flagged.

    Returns
    -------
    BinCheck
    """
    ring = np.asarray(ring)
    if ring.shape != removal.zone.shape or ring.dtype != np.bool_:
        raise InputShapeError(f"ring must be an {removal.zone.shape} bool array, got {describe_array(ring)}")
    if not (np.isfinite(band_mm) and band_mm >= 0):
        raise ParameterError(f"band_mm must be a number >= 0, got {band_mm!r}")
    if not 0.0 <= rim_in_view <= 1.0:
        raise ParameterError(f"rim_in_view must be a number in [0, 1], got {rim_in_view!r}")
    zone = removal.zone
    h = removal.height_mm
    offending = ring & removal.easy_outliers
    if zone.any():
        top = float(np.max(h[zone]))
        with np.errstate(invalid="ignore"):
            offending |= ring & zone & (h >= top - float(band_mm))
    n = int(np.count_nonzero(offending))
    n_ring = int(np.count_nonzero(ring & np.isfinite(h)))
    threshold = float(params.check_threshold_px)
    reasons = []
    if n > threshold:
        where = []
        n_easy = int(np.count_nonzero(ring & removal.easy_outliers))
        if n - n_easy:
            where.append(f"{n - n_easy} in the zone's top {band_mm:g} mm")
        if n_easy:
            where.append(f"{n_easy} called above the rim")
        tol = f"tolerance {removal.tolerance_mm:.2f} mm"
        if np.isfinite(removal.residual_mm) or removal.residual_mm == np.inf:
            tol += f", residuals {removal.residual_mm:.2f} mm"
        advice = ADVICE_LEAK if params.robust else ADVICE_PAPER.format(delta=params.delta_mm)
        reasons.append(f"{n} of the bin's {n_ring} rim and upper-wall pixels not removed ({', '.join(where)}; {tol}): "
                       f"{advice}")
    if n_ring < params.check_min_ring_px:
        reasons.append(f"only {n_ring} of the bin's rim and upper-wall pixels in view (< {params.check_min_ring_px}): "
                       f"{ADVICE_HIDDEN}")
    if rim_in_view < params.check_min_rim_in_view:
        reasons.append(f"only {100 * rim_in_view:.0f} % of the bin's rim in the camera's view "
                       f"(< {100 * params.check_min_rim_in_view:.0f} %): {ADVICE_HIDDEN}")
    return BinCheck(float(n), threshold, bool(reasons), "; ".join(reasons), offending, ring)
