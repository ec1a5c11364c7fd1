"""The knobs of :func:`zcut.fits.fit_parts`, one frozen dataclass validated in its constructor."""

from __future__ import annotations

from dataclasses import dataclass

from zcut.params import _boolean, _number  # the house's checks (their messages name FitParams.field)

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
    seed_shifts : int
        The second pass (:func:`zcut.fits.fit_prepared`, step 4: the zone's pixels no fit of the
        first pass explains, segmented again, each region fitted as a partly visible instance): the
        guesses of a general part put this many spread points of the model's facing side on the
        region's centroid, besides its whole facing side's centroid. 0: no second pass.
    seed_min_share : float
        The second pass fits a region of unexplained pixels only when it holds at least
        ``min_region_px`` pixels and this share of the model's projected area (π (extent · f / z)²
        at the region's depth): smaller pieces of a part are too ambiguous to pose.
    seed_err_ratio : float
        A fit of the second pass is accepted only when its Err is at most this many times the
        median Err of the first pass's fits (the frame's own noise, at least ``err_floor_mm``; at most
        ``max_err_mm``): a small
        piece fits many poses, and the wrong ones (or a fit of floating points) leave a larger residual.
    seed_min_support : float
        ... and when its support is at least this (``min_support`` for the first pass).
    claim : bool
        True (the default): no duplicates (docs/fits.md, "Sixth round"). An accepted fit **claims** every
        zone pixel within k × max(Err, floor) of it in its window, not only those of its region: a region
        (or a leftover, or a region of the second pass) is fitted on its pixels no fit claimed; a
        candidate whose solid shares more than ``max_overlap`` of its volume, or of an accepted fit's,
        with an accepted fit's is not accepted; a sphere region's candidates are tried in order of the
        region's points each explains within a common tolerance. False (with ``fine_points`` 0): the fits
        of the fifth round, to the bit.
    max_overlap : float
        See ``claim``: the share (0..1) of a solid's volume another may hold (the vetting's
        :data:`zcut.fit_vetting.MAX_OVERLAP`, measured on the same inside samples).
    first_err_ratio : float
        With ``claim``: after the first pass, a fit whose Err exceeds this many times the median Err of the
        first pass's live fits (at least ``err_floor_mm``) is dropped — a pose between two parts, or pulled
        by a neighbour's face or ghosts, whose wide band claimed a part's pixels and whose solid refused that
        part's own fit — and its pixels are fitted again by the second pass (docs/fits.md, "Eighth round").
        0: off (the seventh round's fits).
    fine_points : int
        A general part's pose is refined last on up to this many of its region's points within k × Err of
        it (trimmed; all of them, not the ``max_points`` of the search) and kept when its Err does not grow
        (docs/fits.md, "Eighth round"). 0: off.
    fine_window : bool
        True (the default): the last refinement (``fine_points``) takes the zone's points in the posed model's
        window within k × Err of it, not only its region's (docs/fits.md, "Eleventh round"). False, with
        ``fine_robust`` 0: the tenth round's fits.
    fine_robust : float
        The last refinement weighs its points by Tukey's biweight of their distance at this many times
        max(Err, ``err_floor_mm``) (none beyond it); 0: unweighted (the tenth round's).
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
    seed_shifts: int = 4
    seed_min_share: float = 0.025
    seed_err_ratio: float = 1.5
    seed_min_support: float = 0.5
    claim: bool = True
    max_overlap: float = 0.05
    first_err_ratio: float = 3.0
    fine_points: int = 3000
    fine_window: bool = True
    fine_robust: float = 3.0

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
        _number(self, "seed_shifts", ge=0, integer=True)
        _number(self, "seed_min_share", ge=0, le=1)
        _number(self, "seed_err_ratio", gt=0)
        _number(self, "seed_min_support", ge=0, le=1)
        _boolean(self, "claim")
        _number(self, "max_overlap", ge=0, le=1)
        _number(self, "first_err_ratio", ge=0)
        _number(self, "fine_points", ge=0, integer=True)
        _boolean(self, "fine_window")
        _number(self, "fine_robust", ge=0)
