"""The knobs of :func:`zcut.fits.fit_parts`, one frozen dataclass validated in its constructor."""

from __future__ import annotations

from dataclasses import dataclass

from zcut.params import _number  # the house's range check (its message names FitParams.field)

__all__ = ["FitParams"]


@dataclass(frozen=True, slots=True)
class FitParams:
    """Parameters of the part fits (lengths in mm, pixels in pixels).

    Attributes
    ----------
    jump_mm : float
        Segmentation: two neighbouring pixels belong to one candidate region when their 3-D distance
        is at most ``jump_mm`` plus ``jump_px`` pixel footprints (the footprint at their depth).
    jump_px : float
        See ``jump_mm`` (a slope allowance: on a surface tilted by θ neighbours lie 1 / cos θ
        footprints apart).
    min_region_px : int
        Candidate regions (and leftovers of a region after a fit) smaller than this are not fitted.
    icp_iterations : int
        Point-to-plane ICP iterations of the refinement of the best initial guess.
    coarse_iterations : int
        ICP iterations run from every initial guess before the best one is refined.
    max_points : int
        At most this many points of a region take part in the ICP (an even subsample).
    gate_mm : float
        ICP correspondences farther than this from the model are ignored at the start; the gate
        then shrinks to max(``k`` × the running residual, ``err_floor_mm`` × ``k``).
    err_floor_mm : float
        The smallest Err used to decide which pixels a fit explains (a noise-free cloud has Err ≈ 0).
    k : float
        A pixel is explained by a fit when it lies within ``k`` × max(Err, ``err_floor_mm``) of it
        (paper §2: 3).
    max_err_mm : float
        A fit is accepted only when its residual Err is at most this.
    min_support : float
        ... and when at least this share (0..1) of its predicted visible pixels is supported (and
        it explains at least ``min_region_px`` pixels of its region).
    max_instances_per_region : int
        At most this many fits are tried in one candidate region (touching parts).
    sphere_tolerance : float
        The mesh is treated as a sphere (closed-form fits) when every vertex lies within this share
        of the mean radius from the vertices' centroid.
    """

    jump_mm: float = 1.5
    jump_px: float = 3.0
    min_region_px: int = 40
    icp_iterations: int = 30
    coarse_iterations: int = 4
    max_points: int = 600
    gate_mm: float = 4.0
    err_floor_mm: float = 0.1
    k: float = 3.0
    max_err_mm: float = 1.5
    min_support: float = 0.5
    max_instances_per_region: int = 40
    sphere_tolerance: float = 0.01

    def __post_init__(self) -> None:
        _number(self, "jump_mm", gt=0)
        _number(self, "jump_px", ge=0)
        _number(self, "min_region_px", ge=4, integer=True)
        _number(self, "icp_iterations", ge=1, integer=True)
        _number(self, "coarse_iterations", ge=1, integer=True)
        _number(self, "max_points", ge=10, integer=True)
        _number(self, "gate_mm", gt=0)
        _number(self, "err_floor_mm", gt=0)
        _number(self, "k", gt=0)
        _number(self, "max_err_mm", gt=0)
        _number(self, "min_support", ge=0, le=1)
        _number(self, "max_instances_per_region", ge=1, integer=True)
        _number(self, "sphere_tolerance", gt=0, le=0.5)
