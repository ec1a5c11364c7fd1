"""The parameters of every stage, each a frozen dataclass validated once, in its constructor.

- :class:`ZCutParams`: the z-cut filter (paper §3). It takes three numbers: the step Δd and depth
  d_max (in the unit of the height image: mm in the pipeline) and the area threshold μ_thr
  (pixels), usually given as ρ_thr · a_max (paper eq. 5) where a_max is the pixel count of the
  part's largest face seen by the sensor; how to derive them from geometry (§5.4) is here too.
- :class:`BinMaskParams`, :class:`RegistrationParams`, :class:`RemovalParams`, :class:`SorParams`:
  the other stages of the pipeline (paper §5.1-§5.3). Lengths are given in millimetres, as a user
  writes them in a config file; the stage functions, which work on clouds in metres, read them
  through the ``*_m`` properties: the one place where units are converted.

``replay.pipeline.config.PipelineConfig`` nests one of each; an invalid value raises
:class:`~zcut.errors.ParameterError` naming the class, the field and the value.
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
    "BinMaskParams",
    "RegistrationParams",
    "RemovalParams",
    "SorParams",
    "SuspectParams",
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
    """K = floor(max_depth / step + 1e-9), the number of level pairs the filter checks (docs/filters.md).

    Capped at 2**60 (beyond any level a float64 height range can reach).
    """
    x = max_depth / step + 1e-9
    if not x < _K_CAP:
        return _K_CAP
    return math.floor(x)


def _positive(name: str, value: object, *, allow_inf: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) and not hasattr(value, "__float__"):
        raise ParameterError(f"{name} must be a number > 0, got {value!r}")
    v = float(value)
    if not (v > 0 and (allow_inf or math.isfinite(v))):
        raise ParameterError(f"{name} must be a number > 0, got {value!r}")
    return v


def _number(obj: object, name: str, *, gt: float | None = None, ge: float | None = None,
            le: float | None = None, integer: bool = False, optional: bool = False) -> None:
    """Check ``obj.name`` is a finite number in range (an ``int`` when ``integer``; None when
    ``optional``); raise :class:`ParameterError` naming the class, the field and the value."""
    v = getattr(obj, name)
    if v is None and optional:
        return
    bad = isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
    if not bad and integer and int(v) != v:
        bad = True
    if not bad and ((gt is not None and not v > gt) or (ge is not None and not v >= ge)
                    or (le is not None and not v <= le)):
        bad = True
    if bad:
        rng = [f"> {gt:g}"] if gt is not None else []
        rng += [f">= {ge:g}"] if ge is not None else []
        rng += [f"<= {le:g}"] if le is not None else []
        kind = "an integer" if integer else "a number"
        raise ParameterError(f"{type(obj).__name__}.{name} must be {' '.join([kind, ' and '.join(rng)]).strip()}, "
                             f"got {v!r}")


def _boolean(obj: object, name: str) -> None:
    v = getattr(obj, name)
    if not isinstance(v, bool):
        raise ParameterError(f"{type(obj).__name__}.{name} must be true or false, got {v!r}")


def _choice(obj: object, name: str, choices: tuple[str, ...]) -> None:
    v = getattr(obj, name)
    if not isinstance(v, str) or v not in choices:
        raise ParameterError(f"{type(obj).__name__}.{name} must be one of {', '.join(choices)}, got {v!r}")


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
    connectivity : {8, 4}
        Pixel connectivity of the cuts' components.
    """

    step: float
    max_depth: float
    max_area: float
    a_max: float | None = None
    connectivity: int = 8

    def __post_init__(self) -> None:
        object.__setattr__(self, "step", _positive("ZCutParams.step", self.step))
        md = self.max_depth
        if isinstance(md, bool) or not isinstance(md, (int, float)) and not hasattr(md, "__float__"):
            raise ParameterError(f"ZCutParams.max_depth must be a number >= 0, got {md!r}")
        if not (math.isfinite(float(md)) and float(md) >= 0):
            raise ParameterError(f"ZCutParams.max_depth must be a number >= 0, got {md!r}")
        object.__setattr__(self, "max_depth", float(md))
        object.__setattr__(self, "max_area", _positive("ZCutParams.max_area", self.max_area, allow_inf=True))
        if self.a_max is not None:
            object.__setattr__(self, "a_max", _positive("ZCutParams.a_max", self.a_max))
        c = self.connectivity
        if isinstance(c, bool) or c not in (4, 8):
            raise ParameterError(f"ZCutParams.connectivity must be 4 or 8, got {c!r}")
        object.__setattr__(self, "connectivity", int(c))

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


#: The SOR conventions (docs/filters.md) and the regions SOR may judge in the pipeline.
SOR_CONVENTIONS = ("pcl", "open3d")
SOR_REGIONS = ("top", "zone")
REGISTRATION_METHODS = ("point_to_plane", "point_to_point")
#: The bin removal's modes: the paper's rule as written, or the one that tolerates a real registration.
REMOVAL_MODES = ("robust", "paper")
STRAGGLER_BOUNDS = ("below_rim", "global", "off")


__all__ += ["ZCutTopParams"]


@dataclass(frozen=True, slots=True)
class ZCutTopParams:
    """The z-cut with its window anchored on the pile's top (method ``zcut_top``, :mod:`zcut.cut_top`).

    It runs the z-cut of :class:`ZCutParams` (Δd, d_max, μ_thr, connectivity: the ``zcut`` section)
    with d_max measured from the pile's top instead of the zone's highest point: the highest cut
    holding a connected component as large as ``top_faces`` of the part's largest faces.

    Attributes
    ----------
    top_faces : float
        The pile's top is the first cut, from the highest point down, holding a connected component
        of at least ``top_faces · a_max`` pixels (a_max: the part's largest face, ``zcut.a_max_px``),
        > 0. Default 1: a part's footprint; a cluster of ghosts smaller than a part cannot set it.
    """

    top_faces: float = 1.0

    def __post_init__(self) -> None:
        _number(self, "top_faces", gt=0)
        object.__setattr__(self, "top_faces", float(self.top_faces))


@dataclass(frozen=True, slots=True)
class BinMaskParams:
    """The RGB bin footprint (:func:`zcut.binmask.bin_mask`, paper §5.1).

    Attributes
    ----------
    enabled : bool
        False: the pipeline skips the bin stages (the z-cut judges the whole frame).
    threshold : float
        Gray level (0-255) above which a pixel is bin plastic.
    dilate_px : int
        Radius of the closing of the walls.
    min_area_frac : float
        Smallest bin component, as a fraction of the image.
    prefer_centre : bool
        Take the component covering the image centre after filling when there is one (a bin is
        usually centred); otherwise, or when none covers it, the largest.
    """

    enabled: bool = True
    threshold: float = 150.0
    dilate_px: int = 3
    min_area_frac: float = 0.01
    prefer_centre: bool = True

    def __post_init__(self) -> None:
        _boolean(self, "enabled")
        _number(self, "threshold", ge=0, le=255)
        _number(self, "dilate_px", ge=0, integer=True)
        _number(self, "min_area_frac", ge=0, le=1)
        _boolean(self, "prefer_centre")


@dataclass(frozen=True, slots=True)
class RegistrationParams:
    """ICP of the bin model (:func:`zcut.registration.register_bin`, paper §5.2).

    Attributes
    ----------
    method : {"point_to_plane", "point_to_point"}
    voxel_mm : float
        Voxel size of the downsampling (0: none).
    max_correspondence_mm : float
        Correspondence distance of the coarse pass; the fine pass uses a third of it.
    max_iterations : int
        ICP iterations per pass.
    min_fitness : float
        A registration whose bin fitness (the share of the bin's rim, in the camera's view, that the
        frame confirms within the fine correspondence distance) is lower failed.
    max_rmse_mm : float
        A registration whose RMSE is higher failed.
    ring_frac : float
        Width of the ring of bin pixels registered to (:func:`zcut.binmask.bin_pixels`), as a
        fraction of the footprint's inradius; 1 = every bright pixel of the bin component.
    seed_from_first_frame : bool
        Seed every frame's registration with the converged pose of the log's first frame (a static
        bin: a fine pass only, when that pose still fits the frame). Every frame is then
        registered independently of the others, so a frame gets the same result whatever order or
        split the frames are processed in (``zcut replay``, ``batch``, ``sweep``).
    """

    method: str = "point_to_plane"
    voxel_mm: float = 3.0
    max_correspondence_mm: float = 10.0
    max_iterations: int = 30
    min_fitness: float = 0.9
    max_rmse_mm: float = 5.0
    ring_frac: float = 0.2
    seed_from_first_frame: bool = True

    def __post_init__(self) -> None:
        _choice(self, "method", REGISTRATION_METHODS)
        _number(self, "voxel_mm", ge=0)
        _number(self, "max_correspondence_mm", gt=0)
        _number(self, "max_iterations", ge=1, integer=True)
        _number(self, "min_fitness", ge=0, le=1)
        _number(self, "max_rmse_mm", gt=0)
        _number(self, "ring_frac", gt=0, le=1)
        _boolean(self, "seed_from_first_frame")

    @property
    def voxel_m(self) -> float:
        return self.voxel_mm / 1000.0

    @property
    def max_correspondence_m(self) -> float:
        """Correspondence distance of the coarse pass (metres)."""
        return self.max_correspondence_mm / 1000.0

    @property
    def fine_correspondence_m(self) -> float:
        """Correspondence distance of the fine pass: a third of the coarse one (metres)."""
        return self.max_correspondence_mm / 3000.0

    @property
    def max_rmse_m(self) -> float:
        return self.max_rmse_mm / 1000.0


@dataclass(frozen=True, slots=True)
class RemovalParams:
    """Table, easy outliers and bin points (:func:`zcut.removal.remove_table_and_bin`, paper §5.2).

    The removal modes and the bin check are described in ``docs/pipeline.md`` ("Bin removal").

    Attributes
    ----------
    delta_mm : float
        δ: a point this close to the registered model is bin (paper: 0.1 mm). In the robust mode
        the tolerance is never smaller.
    rim_offset_mm : float
        A point higher than the rim by more than this is an easy outlier (paper Fig. 3a).
    search_radius_mm : float or None
        Nearest-model-point search radius of the point-to-plane test (None: 1.5 × the model's
        point spacing; in the robust mode never less than the tolerance).
    straggler_mm : float
        The looser second test for the bin surface's noise tail (0: off). In the robust mode it is
        added to the tolerance.
    straggler_neighbours : int
        Labelled neighbours (of 8) a straggler needs.
    straggler_bound : {"below_rim", "global", "off"}
        Robust mode: ``"global"``: a straggler is bin only within 3 of the bin's Err of the model
        (:func:`zcut.removal.straggler_bound_m`), the Err's σ_bin the residual scale of the frame's certain bin
        pixels — it keeps every near-wall outlier on the walls piles but costs the z-cut's F1 with a model off the
        bin by about 1 mm, whose rim pixels it leaves in the zone; ``"below_rim"`` (default): the same bound, but
        not within ``rim_offset_mm`` of the model's rim height (the rim's band: there a straggler reaches τ +
        ``straggler_mm`` as with ``"off"``), which keeps both (docs/bin_robustness.md); ``"off"``: τ +
        ``straggler_mm``, no bound.
    mode : {"robust", "paper"}
        ``"paper"``: the paper's §5.2 rule as written, δ = ``delta_mm`` (0.1 mm), which removes the
        bin only when the registration is right to about a tenth of a millimetre. ``"robust"``
        (default): the tolerance τ comes from the frame itself, from how far the frame's rim and
        upper walls lie from the registered model (their residuals), and a point within τ of the
        model is bin before it can be an easy outlier.
    tolerance_mm : float or None
        Robust mode: a fixed τ instead of the one derived from the residuals (None: derived).
    residual_quantile : float
        Robust mode: τ = this percentile of the residuals (percent) + ``residual_margin_mm``.
    residual_margin_mm : float
        Robust mode: added to the residuals' percentile (the noise of the wall pixels the
        percentile leaves out, and the model's own thickness).
    min_tolerance_mm, max_tolerance_mm : float
        Robust mode: bounds of the derived τ. A frame whose residuals ask for more than the
        maximum is removed at the maximum and the bin check says so.
    check_threshold_px : float
        The bin check (:func:`zcut.bin_check.check_bin_removal`) flags a frame when more of the
        frame's certain bin pixels (rim and upper walls) than this are left where the filters
        judge (the z-cut's depth below the zone's top) or called above-the-rim outliers.
    check_min_ring_px : int
        The bin check flags a frame whose certain bin pixels are fewer than this (too little of the
        bin in view to check the removal).
    check_min_rim_in_view : float
        The bin check flags a frame where a smaller share of the registered model's rim lies in the
        camera's view (most of the bin out of view: the registration held on to a corner of it).
    """

    delta_mm: float = 0.1
    rim_offset_mm: float = 5.0
    search_radius_mm: float | None = None
    straggler_mm: float = 2.0
    straggler_neighbours: int = 3
    straggler_bound: str = "below_rim"
    mode: str = "robust"
    tolerance_mm: float | None = None
    residual_quantile: float = 99.0
    residual_margin_mm: float = 1.0
    min_tolerance_mm: float = 1.0
    max_tolerance_mm: float = 8.0
    check_threshold_px: float = 0.0
    check_min_ring_px: int = 200
    check_min_rim_in_view: float = 0.5

    def __post_init__(self) -> None:
        _number(self, "delta_mm", ge=0)
        _number(self, "rim_offset_mm", ge=0)
        _number(self, "search_radius_mm", gt=0, optional=True)
        _number(self, "straggler_mm", ge=0)
        _number(self, "straggler_neighbours", ge=0, le=8, integer=True)
        _choice(self, "mode", REMOVAL_MODES)
        _choice(self, "straggler_bound", STRAGGLER_BOUNDS)
        _number(self, "tolerance_mm", ge=0, optional=True)
        _number(self, "residual_quantile", gt=0, le=100)
        _number(self, "residual_margin_mm", ge=0)
        _number(self, "min_tolerance_mm", ge=0)
        _number(self, "max_tolerance_mm", gt=0)
        if self.min_tolerance_mm > self.max_tolerance_mm:
            raise ParameterError(f"RemovalParams.min_tolerance_mm must be <= max_tolerance_mm "
                                 f"({self.max_tolerance_mm!r}), got {self.min_tolerance_mm!r}")
        _number(self, "check_threshold_px", ge=0)
        _number(self, "check_min_ring_px", ge=0, integer=True)
        _number(self, "check_min_rim_in_view", ge=0, le=1)

    @property
    def delta_m(self) -> float:
        return self.delta_mm / 1000.0

    @property
    def rim_offset_m(self) -> float:
        return self.rim_offset_mm / 1000.0

    @property
    def search_radius_m(self) -> float | None:
        return None if self.search_radius_mm is None else self.search_radius_mm / 1000.0

    @property
    def straggler_m(self) -> float:
        return self.straggler_mm / 1000.0

    @property
    def robust(self) -> bool:
        """The robust mode (the tolerance from the frame's residuals)."""
        return self.mode == "robust"


@dataclass(frozen=True, slots=True)
class SorParams:
    """Statistical outlier removal (:func:`zcut.sor.sor_outliers`), the paper's comparison.

    Attributes
    ----------
    enabled : bool
        False: the pipeline skips SOR.
    k : int
        Neighbours.
    std_ratio : float
        Outlier iff d̄ > μ + std_ratio·σ.
    convention : {"pcl", "open3d"}
        docs/filters.md.
    region : {"top", "zone"}
        Which points SOR judges in the pipeline: ``"top"`` the top part of the pile, the points
        within the z-cut's depth d_max of the zone's highest point, as the paper ran it (§5.3);
        ``"zone"`` every point the bin stages left.
    """

    enabled: bool = True
    k: int = 4
    std_ratio: float = 1.0
    convention: str = "pcl"
    region: str = "top"

    def __post_init__(self) -> None:
        _boolean(self, "enabled")
        _number(self, "k", ge=1, integer=True)
        _number(self, "std_ratio", gt=0)
        _choice(self, "convention", SOR_CONVENTIONS)
        _choice(self, "region", SOR_REGIONS)


# --------------------------------------------------------------------------------------------
# The filter bank (docs/filters.md, "The filter bank"): RadiusParams, ClusterParams, SpeckleParams,
# WindowParams, MixedPixelParams. Defaults are for a 1920 x 1200
# structured-light camera about 1 m above the parts (fx ≈ fy ≈ 1700 px: one pixel covers about
# 0.6 mm x 0.6 mm at 1 m, and neighbouring pixels on a surface tilted 60 deg differ by ~1 mm in depth).
# --------------------------------------------------------------------------------------------
__all__ += ["ClusterParams", "MixedPixelParams", "RadiusParams", "SpeckleParams", "WindowParams"]


def _as_int(obj: object, name: str) -> None:
    """Store a validated integral field as an ``int`` (``8.0`` -> ``8``)."""
    object.__setattr__(obj, name, int(getattr(obj, name)))


def _as_float(obj: object, name: str) -> None:
    object.__setattr__(obj, name, float(getattr(obj, name)))


@dataclass(frozen=True, slots=True)
class RadiusParams:
    """Radius outlier removal (:func:`zcut.radius.radius_outliers`), Open3D's
    ``remove_radius_outlier(nb_points, radius)``.

    Attributes
    ----------
    radius_mm : float
        Radius of the ball around each point, > 0 (mm). Default 2 mm: about 3 pixel footprints at
        1 m, so a point of a surface has some 15 to 35 other points within it.
    min_points : int
        A point is kept iff at least this many OTHER points lie strictly inside the ball (Open3D's
        ``nb_points``), >= 1. Default 8.
    """

    radius_mm: float = 2.0
    min_points: int = 8

    def __post_init__(self) -> None:
        _number(self, "radius_mm", gt=0)
        _number(self, "min_points", ge=1, integer=True)
        _as_float(self, "radius_mm")
        _as_int(self, "min_points")

    @property
    def radius_m(self) -> float:
        return self.radius_mm / 1000.0


CLUSTER_CONNECTIVITIES = (4, 8)


@dataclass(frozen=True, slots=True)
class ClusterParams:
    """Cluster removal in the style of Zivid's Cluster Filter (:func:`zcut.components.cluster_outliers`).

    Attributes
    ----------
    max_neighbour_mm : float
        Two neighbouring valid pixels belong to the same cluster when their points are at most this
        far apart in 3D, > 0 (mm). Default 3 mm (five pixel footprints at 1 m: a surface tilted up to
        ~80 deg stays one cluster).
    min_area_mm2 : float
        Clusters whose area, the sum of each pixel's footprint (z/fx)·(z/fy) at its depth, is
        smaller are removed, >= 0 (mm²). Default 50 mm² (about 140 pixels at 1 m).
    connectivity : {8, 4}
        Pixel adjacency of the clusters. Default 8.
    """

    max_neighbour_mm: float = 3.0
    min_area_mm2: float = 50.0
    connectivity: int = 8

    def __post_init__(self) -> None:
        _number(self, "max_neighbour_mm", gt=0)
        _number(self, "min_area_mm2", ge=0)
        c = self.connectivity
        if isinstance(c, bool) or c not in CLUSTER_CONNECTIVITIES:
            raise ParameterError(f"ClusterParams.connectivity must be 4 or 8, got {c!r}")
        _as_float(self, "max_neighbour_mm")
        _as_float(self, "min_area_mm2")
        _as_int(self, "connectivity")

    @property
    def max_neighbour_m(self) -> float:
        return self.max_neighbour_mm / 1000.0


@dataclass(frozen=True, slots=True)
class SpeckleParams:
    """Speckle removal in the style of OpenCV's ``filterSpeckles`` and Ensenso's SpeckleRemoval
    (:func:`zcut.components.speckle_outliers`).

    Attributes
    ----------
    max_diff_mm : float
        4-neighbouring valid pixels whose depths differ by at most this belong to the same region,
        >= 0 (mm; OpenCV's ``maxDiff``). Default 2 mm (twice the depth step between neighbours of a
        surface tilted 60 deg at 1 m).
    max_size_px : int
        Regions of at most this many pixels are removed, >= 0 (OpenCV's ``maxSpeckleSize``;
        Ensenso's RegionSize is this + 1; 0 removes nothing). Default 100 pixels (about 36 mm² at 1 m).
    """

    max_diff_mm: float = 2.0
    max_size_px: int = 100

    def __post_init__(self) -> None:
        _number(self, "max_diff_mm", ge=0)
        _number(self, "max_size_px", ge=0, integer=True)
        _as_float(self, "max_diff_mm")
        _as_int(self, "max_size_px")


@dataclass(frozen=True, slots=True)
class WindowParams:
    """The 3 x 3 rule of Basler's OutlierRemoval (:func:`zcut.local_rules.window_outliers`).

    Attributes
    ----------
    min_inliers : int
        A valid pixel is kept iff at least this many of its 8 neighbours are inliers, 0..8
        (Basler's OutlierRemovalThreshold; 0 removes nothing). Default 3: the pixel at a convex
        right-angled corner of a surface keeps its 3 neighbours on the surface.
    rel_tolerance : float
        A neighbour is an inlier when its depth differs from the centre's by at most this fraction
        of the centre's depth, >= 0 (Basler's OutlierRemovalTolerance). Default 0.005 (5 mm at 1 m).
    """

    min_inliers: int = 3
    rel_tolerance: float = 0.005

    def __post_init__(self) -> None:
        _number(self, "min_inliers", ge=0, le=8, integer=True)
        _number(self, "rel_tolerance", ge=0)
        _as_int(self, "min_inliers")
        _as_float(self, "rel_tolerance")


@dataclass(frozen=True, slots=True)
class MixedPixelParams:
    """The mixed-pixel (jump-edge) test (:func:`zcut.local_rules.mixed_pixel_outliers`), ifm's
    mixed-pixel filter.

    Attributes
    ----------
    min_angle_deg : float
        A pixel is a mixed pixel when, along one image axis, the segments to its valid neighbours
        all make an angle smaller than this with its viewing ray, 0..90 (degrees; 0 removes
        nothing). Default 8 deg (ifm gives the threshold in radians: 0.14 rad).
    """

    min_angle_deg: float = 8.0

    def __post_init__(self) -> None:
        _number(self, "min_angle_deg", ge=0, le=90)
        _as_float(self, "min_angle_deg")

@dataclass(frozen=True, slots=True)
class SuspectParams:
    """The filter-independent suspect detectors (:func:`zcut.suspects.suspects`, ``docs/filters.md``,
    section "Suspects"): what the labelling page proposes so that no outlier escapes a person.

    The defaults were chosen on synthetic logs of seed 1 (six part kinds, 1920 × 1200) and are
    reported on other seeds by ``bench/bench_suspects.py``; each is justified in ``docs/filters.md``.

    Attributes
    ----------
    min_residual_mm : float
        Floor of the residual threshold τ (mm): a pixel farther than τ from every one-sided
        continuation of the surface around it is a suspect. 0.5 mm: 2.5 × the paper's nominal
        Δd, the size of the smallest displacement worth a person's look on a sensor of
        σ ≈ 0.1 mm.
    noise_k : float
        τ = max(min_residual_mm, noise_k · σ̂), σ̂ the frame's own noise (robust spread of its
        second differences). 5: a pixel at 5 σ̂ is rare under any bell-shaped noise; only
        frames noisier than σ̂ = 0.1 mm (e.g. Kinect-class sensors) raise τ above the floor.
    jump_mm : float
        Floor of the depth discontinuity (mm): a mixed (flying) pixel has a neighbour nearer and a
        neighbour farther by more than max(jump_mm, noise_k · σ̂) each. 2 mm.
    below_min_directions : int
        A pixel below every continuation of the surface (a spike away from the camera) is flagged
        only when at least this many of the 8 directions give a continuation (1-8): the last pixels
        of a convex silhouette are also below every continuation they have. 5.
    fill_iterations : int
        Rounds of blob completion (0-64): a zone pixel whose valid neighbours are mostly suspects
        (at least 3 of its 8) joins them, so that a rough blob is proposed whole. 5.
    floating_step_mm : float
        Floor of the z-cut step Δd of the floating detector (mm); the step used is
        max(floating_step_mm, σ̂). 0.1 mm: the low end of the paper's range for a 10 mm part
        (0.01 · p_min); half the nominal Δd finds tilted ghosts whose low end comes within 0.4 mm
        of the surface's highest point around them (measured: 0.2 mm misses 7 % of the ghost
        pixels of rods, 0.05 mm doubles the false floating pixels of matte kinds).
    floating_rho : float
        The floating detector tags z-cut components of any depth smaller than
        ``floating_rho · a_max`` pixels (0 < ρ ≤ 1000; paper eq. 5). 0.15: twice the paper's
        nominal ρ_thr. Without an area limit the whole top of the pile floats.
    plain_rho : float
        Floating components smaller than ``plain_rho · a_max`` are suspects as they are; larger
        ones (up to ``floating_rho``) need one piece of evidence below. 0.07: the paper's nominal
        ρ_thr. Must not exceed ``floating_rho``.
    evidence_holes : float
        Evidence: at least this share of the component's area is unmeasured pixels inside it
        (a decoding ghost is patchy, a real face is dense). 0.04.
    evidence_inconsistent : float
        Evidence: at least this share of its pixels are residual-inconsistent (rough). 0.03.
    evidence_ring_valid : float
        Evidence: at least this share of its outer boundary touches measured points (it hovers over
        a measured surface; a real part on top is bordered by its own shadow and grazing
        silhouette, which are unmeasured). 0.35.
    a_max : float or None
        Pixel count of the part's largest face (``ZCutParams.a_max``); None: 1 % of the image.
    merge_radius_px : int
        Suspects of one detector closer than about 2 · merge_radius_px + 1 pixels form one group
        (0-4096). 3: a run of flying pixels along an edge with gaps of a few pixels is one group.
    max_groups : int
        At most this many groups per frame (≥ 5, one per detector): the merge radius of the
        detector with most groups doubles until the frame has no more. 40.
    """

    min_residual_mm: float = 0.5
    noise_k: float = 5.0
    jump_mm: float = 2.0
    below_min_directions: int = 5
    fill_iterations: int = 5
    floating_step_mm: float = 0.1
    floating_rho: float = 0.15
    plain_rho: float = 0.07
    evidence_holes: float = 0.04
    evidence_inconsistent: float = 0.03
    evidence_ring_valid: float = 0.35
    a_max: float | None = None
    merge_radius_px: int = 3
    max_groups: int = 40

    def __post_init__(self) -> None:
        _number(self, "min_residual_mm", gt=0)
        _number(self, "noise_k", ge=0)
        _number(self, "jump_mm", gt=0)
        _number(self, "below_min_directions", ge=1, le=8, integer=True)
        _number(self, "fill_iterations", ge=0, le=64, integer=True)
        _number(self, "floating_step_mm", gt=0)
        _number(self, "floating_rho", gt=0, le=1000)
        _number(self, "plain_rho", ge=0, le=1000)
        if self.plain_rho > self.floating_rho:
            raise ParameterError(f"SuspectParams.plain_rho must be <= floating_rho ({self.floating_rho!r}), "
                                 f"got {self.plain_rho!r}")
        _number(self, "evidence_holes", ge=0, le=1)
        _number(self, "evidence_inconsistent", ge=0, le=1)
        _number(self, "evidence_ring_valid", ge=0, le=1)
        _number(self, "a_max", gt=0, optional=True)
        _number(self, "merge_radius_px", ge=0, le=4096, integer=True)
        _number(self, "max_groups", ge=5, integer=True)
        for name in ("below_min_directions", "fill_iterations", "merge_radius_px", "max_groups"):
            object.__setattr__(self, name, int(getattr(self, name)))
        for name in ("min_residual_mm", "noise_k", "jump_mm", "floating_step_mm", "floating_rho", "plain_rho",
                     "evidence_holes", "evidence_inconsistent", "evidence_ring_valid"):
            object.__setattr__(self, name, float(getattr(self, name)))
        if self.a_max is not None:
            object.__setattr__(self, "a_max", float(self.a_max))


# --------------------------------------------------------------------------------------------
__all__ += ["StereoLrParams", "StereoSpeckleParams", "StereoTextureParams", "StereoUniquenessParams"]

# The stereo matcher's own post-filters scored as methods (replay/pipeline/stereo_methods.py): each class
# holds the one filter's settings under the names of zcut.stereo.MatcherParams, so that a set of its
# parameters is the matcher's settings of that filter; `zcut record-stereo` records, per set it is asked
# for, the pixels the filter at that strength invalidates, and the method scores the set its parameters
# name (docs/real_data.md, "The matcher's post-filters as methods").


@dataclass(frozen=True, slots=True)
class StereoUniquenessParams:
    """The matcher's uniqueness test (OpenCV's ``uniquenessRatio``), method ``stereo_uniqueness``.

    Attributes
    ----------
    uniqueness_ratio : int
        Margin (%) by which the best matching cost must beat the second best, 1..100. Default 10
        (OpenCV: "a value within the 5-15 range is good enough").
    """

    uniqueness_ratio: int = 10

    def __post_init__(self) -> None:
        _number(self, "uniqueness_ratio", ge=1, le=100, integer=True)
        _as_int(self, "uniqueness_ratio")


@dataclass(frozen=True, slots=True)
class StereoLrParams:
    """The matcher's left-right consistency check, method ``stereo_lr``: the right view matched on its own
    (:func:`zcut.stereo.left_right_rejected`; OpenCV's ``disp12MaxDiff``, which reuses the left view's costs,
    invalidated no pixel on the Middlebury scenes).

    Attributes
    ----------
    disp12_max_diff : int
        Largest difference (px) between the left disparity and the right one at its match, >= 0.
        Default 1.
    """

    disp12_max_diff: int = 1

    def __post_init__(self) -> None:
        _number(self, "disp12_max_diff", ge=0, integer=True)
        _as_int(self, "disp12_max_diff")


@dataclass(frozen=True, slots=True)
class StereoSpeckleParams:
    """The matcher's speckle filter on the disparity (OpenCV's ``speckleWindowSize`` and
    ``speckleRange``), method ``stereo_speckle``.

    Attributes
    ----------
    speckle_window : int
        Regions of the disparity of at most this many pixels are invalidated, >= 1. Default 100
        (OpenCV: "somewhere in the 50-200 range").
    speckle_range : int
        Largest disparity step (px) inside one region, >= 0. Default 2 (OpenCV: "1 or 2").
    """

    speckle_window: int = 100
    speckle_range: int = 2

    def __post_init__(self) -> None:
        _number(self, "speckle_window", ge=1, integer=True)
        _number(self, "speckle_range", ge=0, integer=True)
        _as_int(self, "speckle_window")
        _as_int(self, "speckle_range")


@dataclass(frozen=True, slots=True)
class StereoTextureParams:
    """StereoBM's texture test (OpenCV's ``textureThreshold``), method ``stereo_texture`` (BM only).

    Attributes
    ----------
    texture_threshold : int
        Least sum of the pre-filtered image's absolute values over the block, >= 1. Default 10
        (OpenCV's StereoBM default; on a textured scene it rejects nothing: a 9 × 9 block of a
        pre-filter capped at 31 sums to at most 2511, and hundreds are where it starts to act).
    """

    texture_threshold: int = 10

    def __post_init__(self) -> None:
        _number(self, "texture_threshold", ge=1, integer=True)
        _as_int(self, "texture_threshold")


#: the units a part model file may be stated in (``ExplainedParams.part_model_unit``)
PART_MODEL_UNITS = ("mm", "m")


@dataclass(frozen=True, slots=True)
class ExplainedParams:
    """The method ``explained`` (paper §2; :mod:`zcut.explained`): the points farther than ``k`` × Err
    from every known surface (the fitted part instances, the registered bin, the table plane).

    Attributes
    ----------
    k : float
        The paper's factor: 3.
    err_floor_mm : float
        Err is never below this (mm): a noise-free cloud's fits have Err ≈ 0. 0.05.
    part_model : str
        The part's mesh: a PLY, STL or OBJ file, or an MCAP log whose ``part_model.ply`` it takes;
        "" (default): the replayed log's own attachment (``--part-model FILE`` sets it).
    part_model_unit : {"mm", "m"}
        The unit of a mesh file's vertices (a log's attachment states its own).
    fit_max_err_mm : float
        A part fit is accepted only when its residual Err is at most this (``FitParams.max_err_mm``). 1.5.
    fit_min_support : float
        ... and when at least this share of its predicted visible pixels is measured on it
        (``FitParams.min_support``). 0.5.
    fit_max_overlap : float
        Two parts never share volume: a fit whose solid overlaps a better-supported fit's by more than
        this share of its volume is no known surface (:mod:`zcut.fit_vetting`; docs/labelling.md,
        "Vetting the fits"). 0.05; 1 keeps every fit (no vetting).
    """

    k: float = 3.0
    err_floor_mm: float = 0.05
    part_model: str = ""
    part_model_unit: str = "mm"
    fit_max_err_mm: float = 1.5
    fit_min_support: float = 0.5
    fit_max_overlap: float = 0.05

    def __post_init__(self) -> None:
        _number(self, "k", gt=0)
        _number(self, "err_floor_mm", ge=0)
        if not isinstance(self.part_model, str):
            raise ParameterError(f"ExplainedParams.part_model must be a file path (a string), got {self.part_model!r}")
        _choice(self, "part_model_unit", PART_MODEL_UNITS)
        _number(self, "fit_max_err_mm", gt=0)
        _number(self, "fit_min_support", ge=0, le=1)
        _number(self, "fit_max_overlap", ge=0, le=1)
        for name in ("k", "err_floor_mm", "fit_max_err_mm", "fit_min_support", "fit_max_overlap"):
            object.__setattr__(self, name, float(getattr(self, name)))
