"""The method ``explained``: the zone's points no known surface explains (paper §2; issue 29 item 4).

The known surfaces of a frame: the part instances :func:`zcut.fits.fit_prepared` finds in the zone
with the part's mesh, the registered bin model at the pose the bin stages found, and the table
plane fitted to the pixels the removal labelled table. :mod:`zcut.explained` gives every zone pixel
its distance to the nearest of them and Err; the method's outliers are the zone's pixels farther
than ``k`` × Err (``[explained]`` section, :class:`zcut.params.ExplainedParams`).

- **Part instances**: σ_s is the fit's residual measured robustly on the zone pixels it is the
  nearest surface of, never above the residual the fit states (``PartFit.err_mm``, an RMS that a
  shiny part's attached ghosts inflate): :func:`zcut.explained.fit_sigmas`.
- **Vetting** (:mod:`zcut.fit_vetting`): two parts never share volume. The fits are ranked by the
  zone pixels each explains (its nearest-surface pixels within ``k`` × Err) and a fit whose solid
  overlaps a better-ranked kept fit's by more than ``fit_max_overlap`` (5 %) of its volume is left out: no known surface
  (:attr:`ExplainedDetail.vetted_out`). Before that, a fit more than ``MAX_BEHIND`` of whose solid lies
  behind the registered bin model or the table plane (:func:`zcut.fit_vetting.behind_shares`: a part never
  lies inside the bin's walls or below its floor) is left out and suppresses no other fit
  (:attr:`ExplainedDetail.vetted_behind`). The pixels whose nearest surface it was are judged again
  against the surfaces left, and the kept fits' residuals are measured again.
- **Missed instances on top** (:mod:`zcut.top_pieces`, :data:`TOP_PIECES`): after the vetting, the zone's
  unexplained pieces are fitted again; an instance found there joins the fits when it lies on top of what
  surrounds it (a piece framed by nearer surfaces is left out), overlaps no fit's solid and lies behind neither
  the bin nor the table; the pixels it is
  nearer to take it and the residuals are measured again (:attr:`ExplainedDetail.top_pieces`).
- **Slivers no fit took** (:mod:`zcut.sliver_fits`, :data:`SLIVER_MIN_PX`): last, the part is posed on the zone's
  unexplained regions, cut at the scan's depth steps of more than :data:`SLIVER_SPLIT_STEPS` footprints, of
  :data:`SLIVER_MIN_PX` pixels and :data:`SLIVER_MIN_AREA_SHARE` of a whole part's projected area at their depth or
  more (at most :data:`SLIVER_MAX_REGIONS` of them, the largest first), guessed from the fitted neighbours' orientations; a pose that enters a fit's solid or lies in
  front of what the camera saw is refused. A sliver fit joins the fits as the pieces on top do
  (:attr:`ExplainedDetail.slivers`); the labelling page's fits are these (annotate/fits.py), so its proposals stay
  the method's outliers.
- **The bin**: the registered model cloud with its normals (the pipeline's bin model), posed by the
  registration; σ_s is the robust residual (:func:`zcut.explained.residual_sigma`) of up to 20,000 of
  the pixels the removal labelled bin.
- **The table**: the plane :func:`zcut.explained.fit_plane` fits to up to 20,000 of the pixels the
  removal labelled table, with its robust residual.

**The part model** is ``explained.part_model``: a mesh file (PLY, STL or OBJ, in
``explained.part_model_unit``) or an MCAP log whose ``part_model.ply`` attachment it takes. The
command line's ``--part-model FILE`` sets it; when it is empty and the replayed log carries a
``part_model.ply``, :func:`with_log_part_model` (called where the config is resolved) sets it to the
log itself, so that a study's worker processes read the same model. With a part model but without
the bin stages (no bin model or no image: the bin and the table would be unexplained), the method
returns a named warning and no outliers.

**Without a part model** (issue 29 item 3) the parts' pixels are judged against the edge-aware local
surface (:func:`zcut.explained.local_surface_distance`: planes fitted on each side of an edge to the
frame's valid pixels, the page's suspects' surface, a patch being a surface when it fits within 0.1
of the zone's median footprint too, :func:`zcut.explained.local_surface_params`) while the bin model and the table plane still
explain theirs: a pixel is unexplained when it is farther than ``k`` × Err from the bin, the table
and the local surface (code ``SURFACE_LOCAL``). The local surface's σ_s is the robust residual of
the zone pixels it explains (:func:`zcut.explained.local_sigma`: 1.4826 × the median distance,
re-taken over the distances within 5 σ, three times). Without the bin stages either (a scan with no
bin model) every valid pixel is judged against the local surface alone. Each frame carries the
warning :data:`FALLBACK_WARNING` (:data:`FALLBACK_ALONE_WARNING`) naming the surface model used.

What it leaves for the viewer (:class:`ExplainedDetail`): the fits and the posed part mesh, the
distance image, the nearest surface's code, Err, the unexplained pixels, the surface model used and
the local surface's σ.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from replay.logs.frame import Frame
from replay.pipeline.zone import Zone

if TYPE_CHECKING:
    from replay.logs.reader import LogReader
    from zcut.fits import PartFit
    from zcut.fits.model import PartModel as PreparedPart

#: the method's name and config section
NAME = "explained"
#: :attr:`ExplainedDetail.surface_model`: the parts' pixels explained by the part model's fits, or by
#: the edge-aware local surface (no part model)
PART_FITS = "part fits"
LOCAL_SURFACE = "local surface"
#: the method's warning on every frame it judges without a part model (with the bin stages, and without)
FALLBACK_WARNING = (f"{NAME}: no part model (the log has no part_model.ply; give --part-model FILE): the parts are "
                    "judged against the edge-aware local surface, the bin and the table against their models")
FALLBACK_ALONE_WARNING = (f"{NAME}: no part model and no bin stages: every pixel is judged against the edge-aware "
                          "local surface alone")
#: at most this many of the removal's bin (table) pixels measure the bin's residual (fit the table)
SAMPLE_PX = 20_000
#: fit the part again on the unexplained pieces that lie on top of the pile (:mod:`zcut.top_pieces`;
#: docs/labelling.md, "Third round: what the label holds beside the truth"); False: the fits as found
TOP_PIECES = True
#: the sliver pass (:mod:`zcut.sliver_fits`, :func:`_with_slivers`): the part posed on the zone's unexplained regions
#: of this many pixels or more after the fits and the pieces on top (docs/labelling.md, "Fourteenth round"; 10, the fits'
#: second pass's ``SEED_MIN_PX``, with :data:`SLIVER_MIN_AREA_SHARE` since the "Twenty-fourth round"); 0: off
SLIVER_MIN_PX = 10
#: (mm) :func:`_join` tests the pixels whose nearest surface lies within this only near a new instance's box
JOIN_SLAB_MM = 5.0
#: ... at most this many of those regions tried, the largest first, and per region every guess a few wide ICP
#: iterations (:attr:`zcut.sliver_fits.SliverParams.coarse`; 0: all of them) and only the best few
#: (:attr:`zcut.sliver_fits.SliverParams.refine`) on: the pass's CPU bound
SLIVER_MAX_REGIONS = 12
SLIVER_COARSE = 2
SLIVER_REFINE = 8
#: ... and a pose whose silhouette the camera saw through on more than this share of its pixels is refused (free
#: space: :attr:`zcut.sliver_fits.SliverParams.max_see_through`; docs/labelling.md, "Eighteenth round")
SLIVER_MAX_SEE_THROUGH = 0.05
#: ... and, when > 0, the regions cut at the scan's depth steps of more than this many footprints before they are sized
#: and posed (:attr:`zcut.sliver_fits.SliverParams.split_steps`; docs/labelling.md, "Twenty-third round", 3 since the
#: "Twenty-fourth round": the fits' own segmentation's ``jump_px``; 0: no cut)
SLIVER_SPLIT_STEPS = 3.0
#: ... and, when > 0, a region is tried only when it also holds this share of a whole part's projected area at its
#: depth (:attr:`zcut.sliver_fits.SliverParams.min_area_share`; docs/labelling.md, "Twenty-fourth round": the fits'
#: second pass's ``seed_min_share``, about 86-100 px for the zinc nuts at 1920 x 1200; 0: :data:`SLIVER_MIN_PX` alone)
SLIVER_MIN_AREA_SHARE = 0.025


@dataclass(frozen=True, slots=True)
class ExplainedDetail:
    """What ``explained`` found on a frame, for the viewer.

    Attributes
    ----------
    fits : tuple of PartFit
        The part instances fitted in the zone.
    vertices_mm, triangles : ndarray
        The part's mesh (its own frame, mm): instance i is ``vertices_mm @ R_i.T + t_i``.
    dist_mm : (H, W) float32 ndarray
        Distance to the nearest known surface (mm), NaN outside the zone.
    surface : (H, W) int32 ndarray
        The nearest surface's code (:mod:`zcut.explained`: part index, ``SURFACE_BIN``, ...).
    err_mm : (H, W) float64 ndarray
        Err of each zone pixel.
    unexplained : (H, W) bool ndarray
        The method's outliers.
    surface_model : str
        What explained the parts' pixels: :data:`PART_FITS` (the part model's fitted instances) or
        :data:`LOCAL_SURFACE` (no part model: the edge-aware local surface, code ``SURFACE_LOCAL``).
    local_err_mm : float
        The local surface's residual σ (mm; NaN with part fits).
    vetted_out : tuple of PartFit
        The fits vetted out (:mod:`zcut.fit_vetting`: their solid overlaps a better-supported fit's, or lies
        behind the bin or the table): no known surface, not in ``fits``.
    vetted_behind : tuple of PartFit
        Those of ``vetted_out`` that lie behind the registered bin or the table
        (:func:`zcut.fit_vetting.behind_shares` above ``MAX_BEHIND``).
    top_pieces : int
        How many of ``fits`` (the last ones) were found on the unexplained pieces on top of the pile
        (:mod:`zcut.top_pieces`).
    slivers : int
        How many of ``fits`` (the very last ones, after the pieces on top) the sliver pass posed on the zone's
        unexplained regions (:mod:`zcut.sliver_fits`, :data:`SLIVER_MIN_PX`).
    """

    fits: tuple[PartFit, ...]
    vertices_mm: np.ndarray
    triangles: np.ndarray
    dist_mm: np.ndarray
    surface: np.ndarray
    err_mm: np.ndarray
    unexplained: np.ndarray
    surface_model: str = "part fits"
    local_err_mm: float = float("nan")
    vetted_out: tuple[PartFit, ...] = ()
    top_pieces: int = 0
    vetted_behind: tuple[PartFit, ...] = ()
    slivers: int = 0

    def instance_mesh(self, i: int) -> np.ndarray:
        """The vertices (n, 3) of fit ``i`` posed in the camera frame (mm)."""
        T = self.fits[i].pose
        out: np.ndarray = self.vertices_mm @ T[:3, :3].T + T[:3, 3]
        return out


@functools.lru_cache(maxsize=4)
def _load(path: str, unit: str, stamp: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, PreparedPart]:
    """The part mesh (mm) of ``path`` and its prepared fit model, read once per file version."""
    from replay.logs.part_model import UNITS, load_part_mesh, read_part_model, read_part_model_bytes
    from zcut.errors import ParameterError
    from zcut.fits import prepare_model

    if path.lower().endswith(".mcap"):
        model = read_part_model(path)
        if model is None:
            raise ParameterError(f"{path}: the log carries no part_model.ply attachment")
    else:
        model = read_part_model_bytes(load_part_mesh(path, unit=unit), name=path)
    v = np.asarray(model.vertices, np.float64) * (UNITS[model.unit] / UNITS["mm"])
    t = np.asarray(model.triangles, np.int64)
    return v, t, prepare_model(v, t)


def part_model(path: str, unit: str) -> tuple[np.ndarray, np.ndarray, PreparedPart]:
    """(vertices mm, triangles, prepared model) of ``explained.part_model`` (a mesh file or a log).

    Raises
    ------
    ParameterError, LogFormatError
        One line: not a file, not a mesh, a log without a part model.
    """
    from zcut.errors import ParameterError

    try:
        st = os.stat(path)
    except OSError as e:
        raise ParameterError(f"{path}: no such part model file ({e.strerror})") from None
    return _load(str(Path(path).resolve()), unit, (st.st_mtime_ns, st.st_size))


def with_part_model(resolved: Any, path: str | os.PathLike[str], *, unit: str = "mm", note: str = "") -> Any:
    """``resolved`` (a :class:`replay.pipeline.config.Resolved`, not imported: the config imports the
    registry, which imports this module) with ``explained.part_model`` = ``path`` (a mesh file in
    ``unit``, or a log) and ``note`` added to its notes."""
    config = resolved.config
    p = dataclasses.replace(config.bank[NAME], part_model=str(Path(path).resolve()), part_model_unit=unit)
    config = dataclasses.replace(config, bank={**config.bank, NAME: p})
    return dataclasses.replace(resolved, config=config, notes=(*resolved.notes, note) if note else resolved.notes)


def with_log_part_model(resolved: Any, log: str | os.PathLike[str], reader: LogReader) -> Any:
    """``resolved`` with ``explained.part_model`` set to ``log`` when the config runs ``explained``,
    names no part model and the log carries a ``part_model.ply`` attachment; else as it is."""
    from replay.logs.part_model import PART_MODEL_ATTACHMENT, carries_part_model

    config = resolved.config
    if NAME not in config.base_methods or config.bank[NAME].part_model:
        return resolved
    if not carries_part_model(reader):
        return resolved
    return with_part_model(resolved, log, note=f"explained: the part model is the log's {PART_MODEL_ATTACHMENT}")


def _no_outliers(zone: Zone, why: str) -> tuple[np.ndarray, None, str]:
    return np.zeros_like(zone.zone), None, f"{NAME}: {why}: no outliers"


def _sample(mask: np.ndarray, n: int) -> np.ndarray:
    idx = np.flatnonzero(mask)
    if len(idx) > n:
        idx = idx[np.linspace(0, len(idx) - 1, n).astype(np.int64)]
    return idx


def run_explained(frame: Frame, zone: Zone, config: Any, *, judge_above_rim: bool = False,
                  judge_removed_bin: bool = False) -> tuple[np.ndarray, ExplainedDetail | None, str | None]:
    """The method on one frame (module docstring): (outliers in the zone, detail, warning), the
    fields of the ``MethodOutput`` its registry entry returns.

    ``judge_above_rim``: the detail's distances, surfaces and Err also cover the points above the rim
    (``zone.easy``), judged against the same known surfaces (the fits, found in the zone, the bin,
    the table; not the local surface): the labelling page serves them (annotate/fits.py). The method's
    outliers and everything in the zone are the same with and without it.

    ``judge_removed_bin``: with a part model, the pixels the removal labelled bin are judged too, in the same
    search as the zone's, against the same known surfaces: those farther than ``k`` × Err from all of them —
    the bin model at the bin's own Err, the fits, the table — are outliers as well, outside the zone (the
    paper's definition does not drop a point because the removal's tolerance took it: issue 31,
    docs/bin_robustness.md, "piles leaning on the walls — `explained`"). Everything in the zone is the
    same with and without it.
    """
    from zcut import explained as ex
    from zcut.cancel import stop_point
    from zcut.fit_vetting import MAX_BEHIND, behind_shares, explained_px, instance_overlaps, vet_fits, without_fits

    p = config.bank[NAME]
    rem = zone.removal
    reg = zone.located.registration
    model = zone.located.bin_model
    bin_stages = rem is not None and reg is not None and model is not None
    if p.part_model and not bin_stages:
        return _no_outliers(zone, "no bin stages (the bin and the table are then no known surfaces)")
    xyz = frame.xyz.astype(np.float64) * 1000.0
    K = frame.intrinsics
    intr = None if K is None or (K.height, K.width) != zone.zone.shape else (K.fx, K.fy, K.cx, K.cy)
    fits: tuple[PartFit, ...] = ()
    v, t = np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    solid = None  # the prepared model's inside: the vetting measures overlap as its fitting did
    if p.part_model:
        from zcut.fits import FitParams, fit_prepared

        v, t, prepared = part_model(p.part_model, p.part_model_unit)
        solid = prepared.solid
        fits = tuple(fit_prepared(xyz, zone.zone, prepared, intrinsics=intr,
                                  params=FitParams(k=p.k, max_err_mm=p.fit_max_err_mm,
                                                   min_support=p.fit_min_support)))
    surfaces = ex.KnownSurfaces(parts=[(v @ f.pose[:3, :3].T + f.pose[:3, 3], t) for f in fits],
                                part_err_mm=[f.err_mm for f in fits])
    # a caller's stop (zcut.cancel) is seen between the steps after the fits too (the fits' own stop points: their
    # loops; the sliver pass's: its regions and guesses)
    stop_point()
    if bin_stages:
        assert rem is not None and reg is not None and model is not None
        surfaces = bin_and_table_surfaces(xyz, rem, reg, model, surfaces)
        stop_point()
    warning = None
    f_px = 0.5 * (K.fx + K.fy) if intr is not None and K is not None else ex.focal_px(xyz)
    footprint = ex.footprint_mm(xyz, f_px)
    local = None
    if not p.part_model:  # the fallback: the edge-aware local surface explains the parts
        valid = np.asarray(np.isfinite(xyz).all(axis=2))
        local = ex.local_surface_distance(xyz, valid, where=zone.zone,
                                          params=ex.local_surface_params(footprint, zone.zone))
    judged = zone.zone | np.asarray(zone.easy, bool) if judge_above_rim else zone.zone
    scored = zone.zone  # where the method's outliers may lie
    if judge_removed_bin and p.part_model:  # the removal's bin pixels judged in the same search
        assert rem is not None
        scored = zone.zone | (rem.bin_points & ~judged)
        judged = judged | scored
    near = ex.nearest_surface(xyz, surfaces, where=judged, within_mm=local)
    stop_point()
    vetted_out: tuple[PartFit, ...] = ()
    vetted_behind: tuple[PartFit, ...] = ()
    zone_err: np.ndarray | None = None  # the zone's Err image, while it holds for ``surfaces`` and ``near``
    if fits:  # each fit's residual measured robustly on its zone pixels (ghosts inflate the stated RMS)
        stated = surfaces.part_err_mm
        surfaces = dataclasses.replace(surfaces, part_err_mm=ex.fit_sigmas(near, stated, where=zone.zone))
        kept = np.ones(len(fits), bool)
        if p.fit_max_overlap < 1:  # 1: every fit kept, no vetting
            # Err over the zone: the ranking reads it where a fit is nearest, the missed instances on top
            # (below) over the whole zone when no fit is vetted out
            zone_err = ex.err_image(near, surfaces, footprint, floor_mm=p.err_floor_mm, where=zone.zone)
            # a part never lies behind the bin or the table (the registered model, the table plane)
            behind = (behind_shares(solid, [f.pose for f in fits], surfaces, f_px=f_px, floor_mm=p.err_floor_mm)
                      if bin_stages and solid is not None and np.isfinite(f_px) else None)
            stop_point()
            vetting = vet_fits(instance_overlaps(v, t, [f.pose for f in fits], solid=solid),
                               explained_px(near, zone_err, len(fits), k=p.k, where=zone.zone),
                               max_overlap=p.fit_max_overlap, behind=behind, max_behind=MAX_BEHIND)
            kept = vetting.kept
            vetted_behind = tuple(f for f, b in zip(fits, vetting.behind) if b > MAX_BEHIND)
        if not kept.all():  # the fits vetted out are no known surface: their pixels judged again
            zone_err = None
            vetted_out = tuple(f for f, k in zip(fits, kept) if not k)
            fits = tuple(f for f, k in zip(fits, kept) if k)
            surfaces, near = without_fits(xyz, near, dataclasses.replace(surfaces, part_err_mm=stated), kept)
            surfaces = dataclasses.replace(surfaces, part_err_mm=ex.fit_sigmas(near, surfaces.part_err_mm,
                                                                               where=zone.zone))
    stop_point()
    top = 0
    if p.part_model and TOP_PIECES:  # the unexplained pieces on top of the pile fitted again (zcut.top_pieces)
        fits, surfaces, near, top = _with_top_pieces(xyz, zone, near, surfaces, fits, v, t, prepared, intr, footprint,
                                                     judged, p, zone_err=zone_err)
    stop_point()
    slivers = 0
    if p.part_model and SLIVER_MIN_PX > 0 and fits:  # the slivers no fit took (zcut.sliver_fits)
        fits, surfaces, near, slivers = _with_slivers(xyz, zone, near, surfaces, fits, v, t, prepared, intr,
                                                      footprint, judged, p)
    if local is not None:
        near = ex.with_local_surface(near, local)
        surfaces = dataclasses.replace(surfaces, local_err_mm=ex.local_sigma(
            near.dist_mm[near.surface == ex.SURFACE_LOCAL]))
        warning = FALLBACK_WARNING if bin_stages else FALLBACK_ALONE_WARNING
    err = ex.err_image(near, surfaces, footprint, floor_mm=p.err_floor_mm)
    out = ex.unexplained(near.dist_mm, err, p.k) & scored
    return out, ExplainedDetail(fits, v, t, near.dist_mm, near.surface, err, out,
                                surface_model=PART_FITS if p.part_model else LOCAL_SURFACE,
                                local_err_mm=surfaces.local_err_mm, vetted_out=vetted_out, top_pieces=top,
                                vetted_behind=vetted_behind, slivers=slivers), warning


def _with_top_pieces(xyz: np.ndarray, zone: Zone, near: Any, surfaces: Any, fits: tuple[PartFit, ...], v: np.ndarray,
                     t: np.ndarray, prepared: Any, intr: Any, footprint: np.ndarray, judged: np.ndarray,
                     p: Any, *, zone_err: np.ndarray | None = None) -> tuple[tuple[PartFit, ...], Any, Any, int]:
    """(fits, surfaces, nearest, how many were added) with the instances :func:`zcut.top_pieces.top_pieces` finds on
    the zone's unexplained pieces: a found instance whose solid overlaps a fit's by more than ``fit_max_overlap``
    is left out; the judged pixels a new instance is nearer to than their nearest surface take it (exact: a pixel
    farther from a new instance's box than from its nearest surface keeps it), and every fit's residual is
    measured again (:func:`zcut.explained.fit_sigmas`, from the residuals the fits state). ``zone_err``: the zone's
    Err image of ``near`` and ``surfaces`` when the caller has it (the vetting's, when it left every fit in),
    else it is computed."""
    from zcut import explained as ex
    from zcut.fit_vetting import MAX_BEHIND, behind_shares, instance_overlaps, vet_fits
    from zcut.fits import FitParams
    from zcut.top_pieces import top_pieces

    err = zone_err if zone_err is not None else ex.err_image(near, surfaces, footprint, floor_mm=p.err_floor_mm,
                                                             where=zone.zone)
    un = ex.unexplained(near.dist_mm, err, p.k) & zone.zone
    more = top_pieces(xyz, un, prepared, intrinsics=intr,
                      params=FitParams(k=p.k, max_err_mm=p.fit_max_err_mm, min_support=p.fit_min_support))
    if more and p.fit_max_overlap < 1:  # a found instance that lies behind the bin or overlaps a fit is left out
        n = len(fits)
        f_px = 0.5 * (intr[0] + intr[1]) if intr is not None else ex.focal_px(xyz)
        behind = (np.concatenate([np.zeros(n), behind_shares(prepared.solid, [f.pose for f in more], surfaces, f_px=f_px,
                                                              floor_mm=p.err_floor_mm)])
                  if surfaces.bin_points is not None and np.isfinite(f_px) else None)
        if fits or (behind is not None and (behind > MAX_BEHIND).any()):
            support = np.concatenate([np.full(n, np.inf), np.asarray([len(f.pixels) for f in more], np.float64)])
            kept = vet_fits(instance_overlaps(v, t, [f.pose for f in (*fits, *more)], solid=prepared.solid), support,
                            max_overlap=p.fit_max_overlap, behind=behind, max_behind=MAX_BEHIND).kept[n:]
            more = [f for f, k in zip(more, kept) if k]
    if not more:
        return fits, surfaces, near, 0
    fits, surfaces, near = _join(xyz, zone, near, surfaces, fits, more, v, t, judged)
    return fits, surfaces, near, len(more)


def _with_slivers(xyz: np.ndarray, zone: Zone, near: Any, surfaces: Any, fits: tuple[PartFit, ...], v: np.ndarray,
                  t: np.ndarray, prepared: Any, intr: Any, footprint: np.ndarray, judged: np.ndarray,
                  p: Any) -> tuple[tuple[PartFit, ...], Any, Any, int]:
    """(fits, surfaces, nearest, how many were added) with the slivers :func:`zcut.sliver_fits.fit_slivers` poses on
    the zone's unexplained regions, cut at the depth steps of :data:`SLIVER_SPLIT_STEPS`, of :data:`SLIVER_MIN_PX` (and
    :data:`SLIVER_MIN_AREA_SHARE` of a whole part's projected area at their depth) to its ``max_px`` pixels (at most
    :data:`SLIVER_MAX_REGIONS`, the largest first), guessed from the fits' orientations, kept out of their solids and
    of the free space the camera saw. A sliver fit states the frame's median fit residual σ (the one its acceptance
    used) and joins the fits as the pieces on top do (:func:`_join`): the judged pixels nearer to it take it."""
    from zcut import explained as ex
    from zcut.fits import PartFit
    from zcut.sliver_fits import SliverParams, fit_slivers

    err = ex.err_image(near, surfaces, footprint, floor_mm=p.err_floor_mm, where=zone.zone)
    un = ex.unexplained(near.dist_mm, err, p.k) & zone.zone
    sig = np.asarray(surfaces.part_err_mm, np.float64)
    sig = sig[np.isfinite(sig)]
    if not un.any() or not sig.size:
        return fits, surfaces, near, 0
    sigma = float(np.median(sig))
    found = fit_slivers(xyz, np.isfinite(xyz).all(axis=2), un, prepared, np.stack([f.pose for f in fits]),
                        sigma_mm=sigma, intrinsics=intr,
                        params=SliverParams(min_px=SLIVER_MIN_PX, max_regions=SLIVER_MAX_REGIONS, coarse=SLIVER_COARSE,
                                            refine=SLIVER_REFINE, max_see_through=SLIVER_MAX_SEE_THROUGH,
                                            split_steps=SLIVER_SPLIT_STEPS, min_area_share=SLIVER_MIN_AREA_SHARE,
                                            k=float(p.k),
                                            floor_mm=float(p.err_floor_mm)))
    if not found:
        return fits, surfaces, near, 0
    more = [PartFit(s.pose, sigma, s.share, s.pixels) for s in found]
    fits, surfaces, near = _join(xyz, zone, near, surfaces, fits, more, v, t, judged)
    return fits, surfaces, near, len(more)


def _join(xyz: np.ndarray, zone: Zone, near: Any, surfaces: Any, fits: tuple[PartFit, ...], more: Sequence[PartFit],
          v: np.ndarray, t: np.ndarray, judged: np.ndarray) -> tuple[tuple[PartFit, ...], Any, Any]:
    """(fits, surfaces, nearest) with the instances ``more`` joined after ``fits``: the judged pixels a new instance
    is nearer to than their nearest surface take it (exact: a pixel farther from a new instance's box than from its
    nearest surface keeps it), and every fit's residual is measured again (:func:`zcut.explained.fit_sigmas`, from
    the residuals the fits state)."""
    from zcut import explained as ex

    posed = [(v @ f.pose[:3, :3].T + f.pose[:3, 3], t) for f in more]
    d = np.asarray(near.dist_mm, np.float64)
    cand = judged & np.isfinite(xyz).all(axis=2) & ~(d <= 0.0)
    pts = xyz[cand]
    dc = d[cand]
    hit = np.zeros(len(pts), bool)
    # a pixel can be nearer to an instance only when it is nearer to its box. The pixels whose surface lies within
    # JOIN_SLAB_MM are tested only in the instance's slab along x widened by that much (outside it the box lies
    # farther than their surface along x alone: the same answer); the others, all of them
    near_ = dc <= JOIN_SLAB_MM
    far = np.flatnonzero(~near_)
    close = np.flatnonzero(near_)
    close = close[np.argsort(pts[close, 0], kind="stable")]
    xs = pts[close, 0]
    widen = JOIN_SLAB_MM * (1.0 + 1e-6)
    for pv, _ in posed:
        lo, hi = pv.min(axis=0), pv.max(axis=0)
        a, b = np.searchsorted(xs, [lo[0] - widen, hi[0] + widen], side="left")
        for idx in (far, close[a:b]):
            q = pts[idx]
            gap = np.linalg.norm(np.maximum(0.0, np.maximum(lo - q, q - hi)), axis=1)
            hit[idx] |= ~(gap >= dc[idx])  # NaN (not judged) and inf (no surface): searched
    where = np.zeros(cand.shape, bool)
    where.reshape(-1)[np.flatnonzero(cand.ravel())[hit]] = True
    add = ex.nearest_surface(xyz, ex.KnownSurfaces(parts=posed, part_err_mm=[f.err_mm for f in more]), where=where)
    with np.errstate(invalid="ignore"):
        closer = where & (add.dist_mm < near.dist_mm)
    n = len(fits)
    near = ex.Nearest(np.where(closer, add.dist_mm, near.dist_mm).astype(np.float32),
                      np.where(closer, add.surface + n, near.surface).astype(np.int32))
    fits = (*fits, *more)
    stated = [float(f.err_mm) for f in fits]
    surfaces = dataclasses.replace(surfaces, parts=[*surfaces.parts, *posed], part_err_mm=stated)
    surfaces = dataclasses.replace(surfaces, part_err_mm=ex.fit_sigmas(near, stated, where=zone.zone))
    return fits, surfaces, near



def bin_and_table_surfaces(xyz: np.ndarray, rem: Any, reg: Any, model: Any, surfaces: Any) -> Any:
    """``surfaces`` with the registered bin model (its residual measured on up to :data:`SAMPLE_PX`
    of the removal's bin pixels) and the table plane fitted to up to as many of its table pixels."""
    from zcut import explained as ex

    T = np.asarray(reg.T_cam_bin, np.float64)
    bin_points = (1000.0 * (model.points @ T[:3, :3].T) + 1000.0 * T[:3, 3],
                  np.zeros_like(model.points) if model.normals is None else model.normals @ T[:3, :3].T)
    flat = xyz.reshape(-1, 3)
    table = None
    tab = _sample(rem.table, SAMPLE_PX)
    if len(tab) >= 3:
        table = ex.fit_plane(flat[tab])
    surfaces = dataclasses.replace(surfaces, bin_points=bin_points, bin_spacing_mm=1000.0 * model.spacing_m,
                                   table=table)
    bins = _sample(rem.bin_points, SAMPLE_PX)
    if len(bins):
        d_bin = ex.nearest_surface(flat[bins][:, None, :], dataclasses.replace(surfaces, parts=(), part_err_mm=(),
                                                                                table=None)).dist_mm
        surfaces = dataclasses.replace(surfaces, bin_err_mm=ex.residual_sigma(d_bin, gate_mm=_gate(d_bin)))
    return surfaces


def _gate(d: np.ndarray) -> float:
    """The gate of the bin's residual: 3 × the median distance (outliers and parts resting on the
    bin's floor left out)."""
    finite = d[np.isfinite(d)]
    return 3.0 * float(np.median(finite)) if finite.size else 0.0
