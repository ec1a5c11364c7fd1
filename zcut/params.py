"""Parameters of the z-cut filter and how to derive them (paper Section 5.4).

The filter takes three numbers: the step Δd and depth d_max (mm, in the unit of the height image)
and the area threshold μ_thr (pixels), usually given as ρ_thr · a_max (paper eq. 5) where a_max is
the pixel count of the part's largest face seen by the sensor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .errors import ParameterError

__all__ = [
    "NOMINAL_MAX_DEPTH_MM",
    "NOMINAL_RHO_THR",
    "NOMINAL_STEP_MM",
    "MAX_DEPTH_RANGE",
    "RHO_THR_RANGE",
    "STEP_RANGE",
    "ZCutParams",
    "a_max_from_camera",
    "n_levels",
]

#: Paper nominal values (Section 5.4): Δd* = 0.2 mm, d*_max = 30 mm, ρ*_thr = 0.07.
NOMINAL_STEP_MM = 0.2
NOMINAL_MAX_DEPTH_MM = 30.0
NOMINAL_RHO_THR = 0.07

#: Suggested ranges (Section 5.4): Δd ∈ [0.01, 0.04]·p_min; d_max ∈ [p_min, 0.7·b_h];
#: μ_thr ∈ [0.05, 0.075]·a_max.
STEP_RANGE = (0.01, 0.04)  # × p_min
MAX_DEPTH_RANGE = (1.0, 0.7)  # (× p_min, × bin height)
RHO_THR_RANGE = (0.05, 0.075)  # × a_max

#: Defaults of :meth:`ZCutParams.from_geometry`, inside the ranges above.
DEFAULT_STEP_FRACTION = 0.02  # × p_min: the middle of the range (0.2 mm for a 10 mm part)
DEFAULT_MAX_DEPTH_FRACTION = 3.0  # × p_min, clipped into [p_min, 0.7·b_h]


# K beyond this is treated as "every level" (more than any float64 range / step can need).
_K_CAP = 1 << 60


def n_levels(step: float, max_depth: float) -> int:
    """K = floor(max_depth / step + 1e-9), the number of level pairs the filter checks (SPEC §1).

    Capped at 2**60 (beyond any level a float64 height range can reach).
    """
    x = max_depth / step + 1e-9
    if not x < _K_CAP:
        return _K_CAP
    return math.floor(x)


def _positive(name: str, value: object, *, allow_inf: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) and not hasattr(value, "__float__"):
        raise ParameterError(f"{name} must be a number > 0, got {value!r}")
    v = float(value)  # type: ignore[arg-type]
    if not (v > 0 and (allow_inf or math.isfinite(v))):
        raise ParameterError(f"{name} must be a {'' if allow_inf else 'finite '}number > 0, got {value!r}")
    return v


@dataclass(frozen=True, slots=True)
class ZCutParams:
    """The z-cut parameters.

    Attributes
    ----------
    step : float
        Δd > 0, in the unit of the height image (mm in the pipeline).
    max_depth : float
        d_max >= 0, same unit.
    max_area : float
        μ_thr > 0 in pixels; components with at least this many pixels are never tagged
        (+inf: no limit).
    a_max : float or None
        Pixel count of the part's largest face (for ρ = area / a_max); None if unknown.
    """

    step: float
    max_depth: float
    max_area: float
    a_max: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "step", _positive("ZCutParams.step", self.step))
        md = self.max_depth
        if isinstance(md, bool) or not isinstance(md, (int, float)) and not hasattr(md, "__float__"):
            raise ParameterError(f"ZCutParams.max_depth must be a finite number >= 0, got {md!r}")
        if not (math.isfinite(float(md)) and float(md) >= 0):
            raise ParameterError(f"ZCutParams.max_depth must be a finite number >= 0, got {md!r}")
        object.__setattr__(self, "max_depth", float(md))
        object.__setattr__(self, "max_area", _positive("ZCutParams.max_area", self.max_area, allow_inf=True))
        if self.a_max is not None:
            object.__setattr__(self, "a_max", _positive("ZCutParams.a_max", self.a_max))

    @property
    def n_levels(self) -> int:
        """K = floor(max_depth / step + 1e-9), the number of level pairs checked."""
        return n_levels(self.step, self.max_depth)

    @property
    def rho_thr(self) -> float | None:
        """ρ_thr = max_area / a_max, or None when a_max is unknown."""
        return None if self.a_max is None else self.max_area / self.a_max

    @classmethod
    def nominal(cls, *, a_max: float) -> ZCutParams:
        """The paper's nominal parameters (0.2 mm, 30 mm, ρ_thr 0.07) for a part with ``a_max``."""
        return cls.from_rho(step=NOMINAL_STEP_MM, max_depth=NOMINAL_MAX_DEPTH_MM,
                            rho_thr=NOMINAL_RHO_THR, a_max=a_max)

    @classmethod
    def from_rho(cls, *, step: float, max_depth: float, rho_thr: float, a_max: float) -> ZCutParams:
        """Parameters with μ_thr = ρ_thr · a_max (paper eq. 5)."""
        r = _positive("rho_thr", rho_thr)
        a = _positive("a_max", a_max)
        return cls(step=step, max_depth=max_depth, max_area=r * a, a_max=a)

    @classmethod
    def from_geometry(
        cls,
        *,
        p_min_mm: float,
        bin_height_mm: float,
        a_max_px: float,
        step_mm: float | None = None,
        max_depth_mm: float | None = None,
        rho_thr: float | None = None,
        strict: bool = False,
    ) -> ZCutParams:
        """Parameters from the part and bin geometry, following the paper's Section 5.4.

        Ranges: Δd ∈ [0.01, 0.04]·p_min, d_max ∈ [p_min, 0.7·b_h], μ_thr ∈ [0.05, 0.075]·a_max.
        Defaults: Δd = 0.02·p_min, d_max = 3·p_min clipped into its range (p_min if the range is
        empty, i.e. 0.7·b_h < p_min), ρ_thr = 0.07 (the paper's nominal value).

        Parameters
        ----------
        p_min_mm : float
            Smallest edge of the part's bounding box (mm).
        bin_height_mm : float
            Bin height b_h (mm).
        a_max_px : float
            Pixel count of the part's largest face seen by the sensor (see
            :func:`a_max_from_camera`).
        step_mm, max_depth_mm, rho_thr : float, optional
            Overrides of the defaults.
        strict : bool
            Raise :class:`ParameterError` when an override (or the d_max range itself) lies
            outside the suggested ranges; otherwise such values are accepted as given.
        """
        p_min = _positive("p_min_mm", p_min_mm)
        b_h = _positive("bin_height_mm", bin_height_mm)
        a_max = _positive("a_max_px", a_max_px)
        eps = 1e-12

        step_lo, step_hi = STEP_RANGE[0] * p_min, STEP_RANGE[1] * p_min
        if step_mm is None:
            step = DEFAULT_STEP_FRACTION * p_min
        else:
            step = _positive("step_mm", step_mm)
            if strict and not (step_lo * (1 - eps) <= step <= step_hi * (1 + eps)):
                raise ParameterError(
                    f"step_mm={step_mm!r} is outside the suggested range "
                    f"[{step_lo:g}, {step_hi:g}] mm (0.01..0.04 x p_min={p_min:g})"
                )

        depth_lo, depth_hi = MAX_DEPTH_RANGE[0] * p_min, MAX_DEPTH_RANGE[1] * b_h
        if strict and depth_hi < depth_lo:
            raise ParameterError(
                f"bin_height_mm={bin_height_mm!r} gives an empty max_depth range "
                f"[p_min={depth_lo:g}, 0.7 x b_h={depth_hi:g}] mm"
            )
        if max_depth_mm is None:
            depth = min(max(DEFAULT_MAX_DEPTH_FRACTION * p_min, depth_lo), depth_hi)
            depth = max(depth, depth_lo)  # an empty range falls back to p_min
        else:
            depth = float(max_depth_mm)
            if strict and not (depth_lo * (1 - eps) <= depth <= depth_hi * (1 + eps)):
                raise ParameterError(
                    f"max_depth_mm={max_depth_mm!r} is outside the suggested range "
                    f"[{depth_lo:g}, {depth_hi:g}] mm (p_min .. 0.7 x bin height)"
                )

        if rho_thr is None:
            rho = NOMINAL_RHO_THR
        else:
            rho = _positive("rho_thr", rho_thr)
            if strict and not (RHO_THR_RANGE[0] * (1 - eps) <= rho <= RHO_THR_RANGE[1] * (1 + eps)):
                raise ParameterError(
                    f"rho_thr={rho_thr!r} is outside the suggested range "
                    f"[{RHO_THR_RANGE[0]}, {RHO_THR_RANGE[1]}]"
                )
        return cls(step=step, max_depth=depth, max_area=rho * a_max, a_max=a_max)


def a_max_from_camera(face_area_mm2: float, *, distance_mm: float, fx_px: float, fy_px: float) -> float:
    """Pixel count of a face of ``face_area_mm2`` facing a pinhole camera at ``distance_mm``.

    One pixel covers (distance / fx) × (distance / fy) mm² at that distance, so the count is
    ``face_area · fx · fy / distance²`` (fronto-parallel face; no rounding).
    """
    area = _positive("face_area_mm2", face_area_mm2)
    d = _positive("distance_mm", distance_mm)
    fx = _positive("fx_px", fx_px)
    fy = _positive("fy_px", fy_px)
    return area * fx * fy / (d * d)
