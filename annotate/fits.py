"""The part fits the labelling page judges (docs/labelling.md, "Judging fits"; issue 29 item 5).

When the part's mesh is known (``zcut annotate --part-model FILE``, else the log's ``part_model.ply``
attachment), a :class:`Fitter` thread runs the method ``explained``
(:func:`replay.pipeline.explained.run_explained`: the part instances fitted in the zone, the
distance of every pixel the page serves — the zone and the points above the rim, as
docs/accuracy.md scores them — to the nearest known surface — fitted instances, registered bin,
table plane — and the pixels farther than k × Err from all of them) on every frame the catalogue
prepared, in log order, the frame the page asks for first. The method's sliver pass is part of it (the part posed on
the unexplained regions no fit took, :mod:`zcut.sliver_fits`), so the page's proposals are the method's outliers
there too. The page is usable meanwhile: a frame not fitted yet is
answered with its status (``waiting``, ``fitting``), never by holding a worker. Closing the page
(:meth:`Fitter.stop`) ends a fit under way at its next stop point (:mod:`zcut.cancel`: between the fits' regions
and candidates, and between the sliver pass's regions and guesses): that frame stays unfitted, no frame's fits are
partial.

What a frame's fits give the page (:meth:`FrameFits.bundle`, a bundle of :mod:`annotate.payload`):

- ``fit_ids`` (sparse): which fitted instance (1-based) explains each zone pixel (its nearest surface,
  within k × Err), and ``fit_table`` (:data:`FIT_COLUMNS`, one row per instance: its pixels, box, Err,
  support, pose, whether the annotator rejected it);
- ``proposals`` (sparse ids) and ``proposal_table`` (:data:`PROPOSAL_COLUMNS`): the review groups of
  the fits — the unexplained pixels, as groups of pixels within two pixels of each other, each with
  its distance to the nearest known surface (median and largest, mm), its Err and its heights; and
  the pixels of every rejected fit that no surface left explains, which return to review as groups
  of their own (``fit`` names the rejected instance), with their distances like any unexplained one.

**A rejected fit is no known surface** (:meth:`FrameFits.remeasure`): the pixels whose nearest surface
it was — the pixels it explained and the unexplained ones nearest to it — are judged again against
the surfaces left (the other fits, the bin, the table: :func:`zcut.fit_vetting.without_fits`), each
with the Err of its new nearest surface (the surfaces keep the residuals measured with every fit:
a rejection changes no other pixel). Those another surface explains within k × Err are not proposed;
the rest are, with their distance to that surface. The result is a function of the set of rejected
fits: taking a rejection back gives the bundle it had before, to the byte.

A rejection is stored with the labels (:meth:`annotate.store.LabelStore.save_fit_decision`), with the
fit's position: a fit found again at that position (within :data:`SAME_FIT_MM`) on a reopened page
is the same fit. A seed (a person's Ctrl+click, :meth:`FrameFits.seeded`) is stored too
(:meth:`annotate.store.LabelStore.save_fit_seed`: frame, annotator, pixel): the frame's fits as an
annotator sees them are the background fits with that annotator's seeds applied in the order clicked
(:meth:`Fitter.fits_for`), so a reloaded page and a restarted server show the same fits, and one
annotator's seeds are not another's.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import ndimage

from annotate.payload import EIGHT, _cluster_stats, _small_uint, make_bundle
from zcut.cancel import stop_when
from zcut.errors import Cancelled

if TYPE_CHECKING:
    from replay.logs.frame import Frame
    from replay.pipeline.stages import FrameResult
    from zcut.bin_model import BinModel
    from zcut.explained import KnownSurfaces
    from zcut.registration import RegistrationResult
    from zcut.removal import RemovalResult

#: Columns of the fit table (float32): ``fit`` its 0-based index; ``n`` the zone pixels it explains;
#: ``x0, y0, x1, y1`` their box (end exclusive), ``cx, cy`` their centroid; ``err_mm`` its residual
#: (the paper's Err); ``support`` the share of its predicted visible pixels that measured points
#: support; ``rejected`` 1 when the annotator rejected it; ``r00 .. t2`` its pose (model mm -> camera mm,
#: rotation row-major then translation); ``seeded`` 1 for an instance found from a person's click
#: (:meth:`FrameFits.seeded`); ``proposed``: of a rejected fit's pixels, those no surface left explains
#: (proposed again), else 0.
FIT_COLUMNS = ("fit", "n", "x0", "y0", "x1", "y1", "cx", "cy", "err_mm", "support", "rejected",
               "r00", "r01", "r02", "r10", "r11", "r12", "r20", "r21", "r22", "t0", "t1", "t2", "seeded", "proposed")
#: Columns of the proposal table (float32): ``id`` (in ``proposals``), ``n``, box, centroid, heights
#: and the gap to the surface around it as the candidate table's (:data:`annotate.payload.CANDIDATE_COLUMNS`);
#: ``dist_mm``, ``dist_max_mm``: median and largest distance of its pixels to the nearest known surface;
#: ``err_mm``: their median Err; ``fit``: -1 for unexplained pixels, else the rejected fit they came from.
PROPOSAL_COLUMNS = ("id", "n", "x0", "y0", "x1", "y1", "cx", "cy", "h_min_mm", "h_max_mm", "below_mm", "gap_mm",
                    "dist_mm", "dist_max_mm", "err_mm", "fit")
#: Unexplained pixels this close (pixels, 8-connected after a dilation of this many) form one proposal.
JOIN_PX = 1
#: A stored rejection applies to the fit of the same index whose position lies this close (mm).
SAME_FIT_MM = 2.0
#: The half side (pixels) of the window a seed click refits, when the frame has no fits to size it by.
SEED_WINDOW = 40
#: A rejected fit's pixels are first judged against the fits whose box lies this close (mm) to theirs
#: (:meth:`FrameFits.remeasure`; exact whatever its value: a pixel farther from those is searched again).
REACH_MM = 30.0
#: At most this many seeded states of frames (an annotator's seeds on a frame's fits) are kept in memory.
SEEDED_KEPT = 64
#: At most this many of the part model's surface samples go to the page's 3D view.
MODEL_POINTS = 400
#: (s) :meth:`Fitter.stop` waits at most this long for the fitting thread to end: a fit under way stops at its
#: next stop point (:mod:`zcut.cancel`), a step between two of them that outlasts this is not waited for
STOP_WAIT_S = 5.0


@dataclass(frozen=True, slots=True)
class Remeasured:
    """What rejecting some fits changes (:meth:`FrameFits.remeasure`): their pixels judged again against
    the surfaces left.

    Attributes
    ----------
    pix : (r,) int64 ndarray
        The rejected fits' pixels no surface left explains within k × Err (flat, increasing), with the
        rejected fit they came from (``fit``), their distance to the nearest surface left and its Err (mm).
    fit : (r,) int32 ndarray
    dist, err : (r,) float32 ndarray
    un_dist, un_err : (u,) float32 ndarray
        The unexplained pixels' distances and Err with the rejected fits gone (the frame's own where
        their nearest surface was another).
    """

    pix: np.ndarray
    fit: np.ndarray
    dist: np.ndarray
    err: np.ndarray
    un_dist: np.ndarray
    un_err: np.ndarray


@dataclass(frozen=True, slots=True)
class FrameFits:
    """What ``explained`` found on one frame, kept compact (sparse pixel lists), or why it did not.

    Attributes
    ----------
    index : int
    status : str
        ``"ready"`` or ``"error"`` (``message`` says why: no bin stages, a failed fit).
    message : str
    shape : (int, int)
    fits : tuple of dict
        Per instance: ``err_mm``, ``support``, ``pose`` (4 x 4 list), ``seeded`` (found from a click), ``sliver``
        (posed by the method's sliver pass, :data:`replay.pipeline.explained.SLIVER_MIN_PX`: ``support`` is the share
        of its region it explains).
    fit_pix, fit_of : (k,) int64, (k,) int32 ndarray
        The zone pixels a fit explains (flat indices, increasing) and which fit (0-based).
    un_pix : (u,) int64 ndarray
        The unexplained pixels (flat, increasing), with ``un_dist`` and ``un_err`` (mm) there, and their
        nearest surface's code (``un_code``: a fit's index, or a :mod:`zcut.explained` ``SURFACE_*``).
    un_dist, un_err : (u,) float32 ndarray
    un_code : (u,) int32 ndarray
    seconds : float
        CPU seconds the fits took.
    surfaces : KnownSurfaces or None
        The known surfaces the distances were measured to but the fits (``parts`` empty): the registered
        bin, the table. With ``part_mesh`` (the part's mesh in its own frame, mm: the arrays every frame
        shares), each fit's pose and ``part_err_mm`` (the residual σ its pixels' Err came from), what
        :meth:`remeasure` judges a rejected fit's pixels against (:meth:`known`): the fits are posed when
        needed, not kept posed (a sphere's mesh posed 350 times is 22 MB a frame).
    part_mesh : (vertices (n, 3), triangles (m, 3)) or None
    part_err_mm : tuple of float
    f_px, floor_mm, k : float
        The focal length (pixels) the footprints came from, Err's floor (mm) and k: Err = max(floor,
        sqrt(σ² + c² / 2)), c = |z| / f_px.
    """

    index: int
    status: str
    message: str = ""
    shape: tuple[int, int] = (0, 0)
    fits: tuple[dict[str, Any], ...] = ()
    fit_pix: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    fit_of: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    un_pix: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    un_dist: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    un_err: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    seconds: float = 0.0
    un_code: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    surfaces: KnownSurfaces | None = None
    part_mesh: tuple[np.ndarray, np.ndarray] | None = None
    part_err_mm: tuple[float, ...] = ()
    f_px: float = float("nan")
    floor_mm: float = 0.0
    k: float = 3.0

    def rejected(self, stored: dict[int, tuple[float, float, float]]) -> set[int]:
        """The fits a store's rejections (:meth:`annotate.store.LabelStore.rejected_fits`) name: same
        index, position within :data:`SAME_FIT_MM`."""
        out = set()
        for i, pos in stored.items():
            if 0 <= i < len(self.fits):
                t = np.asarray(self.fits[i]["pose"], np.float64)[:3, 3]
                if float(np.linalg.norm(t - np.asarray(pos))) <= SAME_FIT_MM:
                    out.add(i)
        return out

    def posed(self, fit: int) -> tuple[np.ndarray, np.ndarray]:
        """Fit ``fit``'s mesh posed in the camera frame (mm): (vertices, triangles)."""
        assert self.part_mesh is not None
        v, t = self.part_mesh
        T = np.asarray(self.fits[fit]["pose"], np.float64)
        out: np.ndarray = v @ T[:3, :3].T + T[:3, 3]
        return out, t

    def known(self, fits: Sequence[int] | None = None) -> KnownSurfaces:
        """The known surfaces with the ``fits`` given (default: every one) posed, in that order."""
        assert self.surfaces is not None
        ids = range(len(self.fits)) if fits is None else [int(i) for i in fits]
        return dataclasses.replace(self.surfaces, parts=[self.posed(i) for i in ids],
                                   part_err_mm=[self.part_err_mm[i] for i in ids])

    def position_mm(self, fit: int) -> tuple[float, float, float]:
        t = np.asarray(self.fits[fit]["pose"], np.float64)[:3, 3]
        return float(t[0]), float(t[1]), float(t[2])

    def remeasure(self, rejected: set[int], xyz_mm: np.ndarray) -> Remeasured:
        """The pixels whose nearest surface was a ``rejected`` fit, judged again against the surfaces left
        (module docstring): those of its explained pixels no surface left explains within k × Err, and
        every unexplained pixel's distance and Err with the rejected fits gone.

        Only the fits whose box lies within :data:`REACH_MM` of those pixels' box are searched first; a
        pixel whose distance so found is not below the gap to the nearest box left out is searched again
        among every fit left (a fit is never nearer than its box), so the result is the full search's (the
        same pixels proposed; a distance may differ in its float32 last bit: Open3D's closest point found in
        another tree).

        Parameters
        ----------
        rejected : set of int
            Fit indices (0-based).
        xyz_mm : (H, W, 3) float64 ndarray
            The frame's points (mm), as the fits measured them.
        """
        from zcut import explained as ex

        n = len(self.fits)
        gone = np.zeros(n + 1, bool)  # the last entry: any code < 0 (bin, table, none)
        gone[[f for f in rejected if 0 <= f < n]] = True
        if not gone.any() or self.surfaces is None or self.part_mesh is None:
            return Remeasured(np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros(0, np.float32),
                              np.zeros(0, np.float32), self.un_dist, self.un_err)
        # the pixels judged again: the rejected fits' own and the unexplained ones nearest to one of them
        mine = gone[np.where(self.fit_of >= 0, self.fit_of, n)]
        un_lost = gone[np.where(self.un_code >= 0, self.un_code, n)]
        pix = np.concatenate([self.fit_pix[mine], self.un_pix[un_lost]])
        src = np.concatenate([self.fit_of[mine], self.un_code[un_lost]])
        pts = np.asarray(xyz_mm, np.float64).reshape(-1, 3)[pix]
        rej, left = np.flatnonzero(gone[:n]), np.flatnonzero(~gone[:n])
        gap = np.full(left.size, np.inf)
        if pix.size and left.size:
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            v = self.part_mesh[0]
            box = []
            for i in left.tolist():  # each fit's posed mesh's box
                T = np.asarray(self.fits[i]["pose"], np.float64)
                c = v @ T[:3, :3].T + T[:3, 3]
                box.append([c.min(axis=0), c.max(axis=0)])
            boxes = np.asarray(box)
            gap = np.linalg.norm(np.maximum(0.0, np.maximum(boxes[:, 0] - hi, lo - boxes[:, 1])), axis=1)
        near = gap <= REACH_MM
        d, c, err = self._against(pix, src, rej, left[near], xyz_mm)
        far = ~(d < (float(gap[~near].min()) if (~near).any() else np.inf))
        if far.any():
            d[far], c[far], err[far] = self._against(pix[far], src[far], rej, left, xyz_mm)
        m = int(mine.sum())
        off = ex.unexplained(d[None, :m], err[None, :m], self.k)[0]
        order = np.argsort(pix[:m][off], kind="stable")
        un_dist, un_err = self.un_dist.copy(), self.un_err.copy()
        un_dist[un_lost], un_err[un_lost] = d[m:], err[m:]
        return Remeasured(pix[:m][off][order], self.fit_of[mine][off][order], d[:m][off][order].astype(np.float32),
                          err[:m][off][order].astype(np.float32), un_dist, un_err)

    def _against(self, pix: np.ndarray, src: np.ndarray, rej: np.ndarray, use: np.ndarray,
                 xyz_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(distance, nearest surface's code, Err) of pixels ``pix`` (whose nearest was rejected fit ``src``)
        judged against the fits ``use``, the bin and the table (:func:`zcut.fit_vetting.without_fits`)."""
        from zcut import explained as ex
        from zcut.fit_vetting import without_fits

        H, W = self.shape
        ids = [*(int(i) for i in rej), *(int(i) for i in use)]
        sub = self.known(ids)
        lut = np.full(len(self.fits), ex.SURFACE_NONE, np.int32)
        lut[rej] = np.arange(rej.size, dtype=np.int32)
        code = np.full(H * W, ex.SURFACE_NONE, np.int32)
        code[pix] = lut[src]
        kept = np.arange(len(ids)) >= rej.size
        left, again = without_fits(xyz_mm, ex.Nearest(np.zeros((H, W), np.float32), code.reshape(H, W)), sub, kept)
        d = again.dist_mm.ravel()[pix].astype(np.float32)
        c = again.surface.ravel()[pix]
        foot = np.abs(np.asarray(xyz_mm, np.float64).reshape(-1, 3)[pix, 2]) / self.f_px
        err = ex.err_image(ex.Nearest(d[None], c[None]), left, foot[None], floor_mm=self.floor_mm)[0]
        # the codes named in the full list of fits (the bin, the table and none as they are)
        full = np.concatenate([np.asarray(use, np.int32), np.zeros(1, np.int32)])
        return d, np.where(c >= 0, full[np.maximum(c, 0)], c).astype(np.int32), err.astype(np.float32)

    def seeded(self, x: int, y: int, xyz_mm: np.ndarray, config: Any) -> FrameFits:
        """These fits with the instances a click at pixel (``x``, ``y``) finds: the part is fitted again on
        the unexplained pixels of a window around it (1.5 × the typical fit's side + 8 px, 16-200 px; else
        :data:`SEED_WINDOW`); each instance found joins the fits (``seeded``, its residual the one its fit
        states) and its pixels leave the proposals. ``self`` when none is found."""
        from replay.pipeline.explained import NAME, part_model
        from zcut.fits import FitParams, fit_prepared

        H, W = self.shape
        p = config.bank[NAME]
        areas = np.bincount(self.fit_of, minlength=len(self.fits)) if len(self.fits) else np.zeros(0)
        r = int(np.clip(1.5 * np.sqrt(np.median(areas)) + 8, 16, 200)) if areas.size else SEED_WINDOW
        flat_un = np.zeros(H * W, bool)
        flat_un[self.un_pix] = True
        local = np.zeros((H, W), bool)
        local[max(0, y - r):y + r + 1, max(0, x - r):x + r + 1] = True
        local &= flat_un.reshape(H, W)
        if local.sum() < 10:
            return self
        _, _, prepared = part_model(p.part_model, p.part_model_unit)
        # the click's window is fitted by the first pass alone (seed_shifts=0): it finds the instance clicked,
        # not the other pieces in the window the frame's own second pass already judged
        found = fit_prepared(xyz_mm, local, prepared, params=FitParams(k=p.k, max_err_mm=p.fit_max_err_mm,
                                                                       min_support=p.fit_min_support, seed_shifts=0))
        if not found:
            return self
        new_pix, new_of = [self.fit_pix], [self.fit_of]
        taken = np.zeros(H * W, bool)
        for j, f in enumerate(found):
            px = np.asarray(f.pixels, np.int64)
            px = px[flat_un[px] & ~taken[px]]
            taken[px] = True
            new_pix.append(px)
            new_of.append(np.full(px.size, len(self.fits) + j, np.int32))
        keep = ~taken[self.un_pix]
        fits = self.fits + tuple({"err_mm": float(f.err_mm), "support": float(f.support),
                                  "pose": np.asarray(f.pose).tolist(), "seeded": True} for f in found)
        # a seeded instance is a known surface too, its residual the one its fit states
        sigmas = (*self.part_err_mm, *(float(f.err_mm) for f in found))
        pix, of = np.concatenate(new_pix), np.concatenate(new_of)
        order = np.argsort(pix, kind="stable")
        return dataclasses.replace(self, fits=fits, fit_pix=pix[order], fit_of=of[order], un_pix=self.un_pix[keep],
                                   un_dist=self.un_dist[keep], un_err=self.un_err[keep], un_code=self.un_code[keep],
                                   part_err_mm=sigmas, message=f"{len(fits)} fits, {int(keep.sum())} unexplained px")

    def bundle(self, *, heights_mm: np.ndarray | None, valid: np.ndarray | None, rejected: set[int],
               header: dict[str, Any], xyz_mm: np.ndarray | None = None) -> bytes:
        """The page's bundle of these fits with ``rejected`` fits' pixels judged again (:meth:`remeasure`, on
        ``xyz_mm``; without it they are not: every pixel of a rejected fit is proposed, with no distance);
        ``heights_mm`` and ``valid`` (H, W) give the proposals' heights and gaps."""
        H, W = self.shape
        head = {**header, "status": self.status, "message": self.message, "height": H, "width": W,
                "n_fits": len(self.fits), "n_rejected": len(rejected), "fit_columns": list(FIT_COLUMNS),
                "proposal_columns": list(PROPOSAL_COLUMNS), "seconds": round(self.seconds, 3)}
        if self.status != "ready" or heights_mm is None or valid is None:
            return make_bundle(head, [], compress=False)
        n_fit = len(self.fits)
        flat_fit = np.zeros(H * W, np.int64)
        flat_fit[self.fit_pix] = self.fit_of + 1
        fit_ids = flat_fit.reshape(H, W)
        if xyz_mm is not None:
            again = self.remeasure(rejected, xyz_mm)
        else:  # not judged again: every pixel of a rejected fit is proposed, with no distance
            mine = np.isin(self.fit_of, sorted(rejected))
            again = Remeasured(self.fit_pix[mine], self.fit_of[mine], np.full(int(mine.sum()), np.nan, np.float32),
                               np.full(int(mine.sum()), np.nan, np.float32), self.un_dist, self.un_err)
        # the proposals: unexplained pixels joined within JOIN_PX, then each rejected fit's pixels left unexplained
        ids = np.zeros((H, W), np.int64)
        n = 0
        src_fit: list[int] = []
        for f, px in [(-1, self.un_pix), *((f, again.pix[again.fit == f]) for f in sorted(rejected))]:
            if not px.size:
                continue
            flat = np.zeros(H * W, bool)
            flat[px] = True
            m = flat.reshape(H, W)
            joined, _ = ndimage.label(ndimage.binary_dilation(m, EIGHT, iterations=JOIN_PX), structure=EIGHT)
            used, inv = np.unique(joined[m], return_inverse=True)  # renumbered in order (a dilated component
            ids[m] = inv.reshape(-1) + 1 + n                          # always holds a pixel of its own)
            n += int(used.size)
            src_fit += [f] * int(used.size)
        table = np.zeros((n, len(PROPOSAL_COLUMNS)), np.float32)
        if n:
            st = _cluster_stats(ids, n, heights_mm, valid, np.zeros((H, W), bool))
            allpix = np.concatenate([self.un_pix, again.pix])
            g = ids.ravel()[allpix]
            dist_med = np.full(n, np.nan)
            dist_max = np.full(n, np.nan)
            err_med = np.full(n, np.nan)
            order = np.argsort(g, kind="stable")
            gs = g[order]
            ds = np.concatenate([again.un_dist, again.dist]).astype(np.float64)[order]
            es = np.concatenate([again.un_err, again.err]).astype(np.float64)[order]
            bounds = np.searchsorted(gs, np.arange(1, n + 2))
            for j in range(n):
                a, b = bounds[j], bounds[j + 1]
                if b > a and not np.isnan(ds[a:b]).all():
                    d = ds[a:b]
                    d = d[np.isfinite(d)] if np.isfinite(d).any() else d
                    dist_med[j], dist_max[j] = float(np.median(d)), float(np.max(d))
                    err_med[j] = float(np.nanmedian(es[a:b]))
            cols = {"id": np.arange(1, n + 1, dtype=np.float64), **st, "dist_mm": dist_med, "dist_max_mm": dist_max,
                    "err_mm": err_med, "fit": np.asarray(src_fit, np.float64)}
            table = np.stack([np.asarray(cols[c], np.float64) for c in PROPOSAL_COLUMNS], axis=1).astype(np.float32)
        ft = np.zeros((n_fit, len(FIT_COLUMNS)), np.float32)
        if n_fit:
            st = _cluster_stats(fit_ids, n_fit, heights_mm, valid, np.zeros((H, W), bool))
            poses = np.asarray([f["pose"] for f in self.fits], np.float64)
            cols = {"fit": np.arange(n_fit, dtype=np.float64), "n": st["n"], "x0": st["x0"], "y0": st["y0"],
                    "x1": st["x1"], "y1": st["y1"], "cx": st["cx"], "cy": st["cy"],
                    "err_mm": np.array([f["err_mm"] for f in self.fits]),
                    "support": np.array([f["support"] for f in self.fits]),
                    "rejected": np.array([float(i in rejected) for i in range(n_fit)]),
                    "seeded": np.array([float(bool(f.get("seeded"))) for f in self.fits]),
                    "proposed": np.bincount(again.fit, minlength=n_fit).astype(np.float64)}
            for r in range(3):
                for c in range(3):
                    cols[f"r{r}{c}"] = poses[:, r, c]
                cols[f"t{r}"] = poses[:, r, 3]
            ft = np.stack([np.asarray(cols[c], np.float64) for c in FIT_COLUMNS], axis=1).astype(np.float32)
        head["n_proposals"] = n
        return make_bundle(head, [("fit_ids", "sparse", _small_uint(fit_ids, n_fit)), ("fit_table", "table", ft),
                                  ("proposals", "sparse", _small_uint(ids, n)), ("proposal_table", "table", table)],
                           compress=False)


@dataclass(frozen=True, slots=True)
class Job:
    """What a frame waiting to be fitted keeps of its pipeline result: the zone and the bin stages'
    masks and pose (not the points, the height image or the filters' outputs)."""

    valid: np.ndarray
    zone: np.ndarray
    removal: RemovalResult | None
    registration: RegistrationResult | None

    @classmethod
    def of(cls, result: FrameResult) -> Job:
        rem = result.removal
        if rem is not None:  # its cloud and height image are the frame's: not kept twice
            rem = dataclasses.replace(rem, cloud=np.zeros((0, 0, 3), np.float32), height_mm=np.zeros((0, 0)))
        return cls(np.asarray(result.valid, bool), np.asarray(result.zone, bool), rem, result.registration)


def fit_frame(frame: Frame, job: Job, config: Any, bin_model: BinModel | None) -> FrameFits:
    """Run ``explained`` on one prepared frame (its pipeline result's zone) and keep what the page needs."""
    from replay.pipeline.explained import NAME, run_explained
    from replay.pipeline.zone import BinLocation, Zone
    from zcut import explained as ex

    H, W = np.shape(job.valid)
    t = time.process_time()
    if job.removal is None or job.registration is None or bin_model is None:
        return FrameFits(frame.index, "error", "no fits: the bin stages did not run on this frame (the bin and "
                         "the table would be no known surfaces)", (H, W))
    located = BinLocation(job.valid, None, job.registration, {}, 0.0, (), bin_model=bin_model)
    zone = Zone(located, job.removal, job.zone, np.zeros((0, 0)), np.asarray(job.removal.easy_outliers, bool), {}, ())
    out, detail, warning = run_explained(frame, zone, config, judge_above_rim=True)
    if detail is None:
        return FrameFits(frame.index, "error", warning or "no fits", (H, W), seconds=time.process_time() - t)
    p = config.bank[NAME]
    surfaces, f_px = known_surfaces(frame, job, detail, bin_model)
    seconds = time.process_time() - t
    # the zone the page serves: the filters' zone and the points above the rim (docs/accuracy.md)
    served = (job.zone | np.asarray(job.removal.easy_outliers, bool)) & job.valid
    un = np.asarray(out, bool) | (ex.unexplained(detail.dist_mm, detail.err_mm, p.k) & served)
    judged = served & ~un & np.isfinite(detail.dist_mm)
    code = np.where(judged, detail.surface, -1).ravel()
    fit_pix = np.flatnonzero(code >= 0)
    un_pix = np.flatnonzero(un.ravel())
    first_sliver = len(detail.fits) - detail.slivers  # the sliver pass's fits come last (zcut.sliver_fits)
    fits = tuple({"err_mm": float(f.err_mm), "support": float(f.support), "pose": np.asarray(f.pose).tolist(),
                  **({"sliver": True} if i >= first_sliver else {})} for i, f in enumerate(detail.fits))
    vetted = f" ({len(detail.vetted_out)} vetted out: their solids overlap a better-supported fit's)" \
        if detail.vetted_out else ""
    if detail.top_pieces:
        vetted += f" ({detail.top_pieces} found again on unexplained pieces on top of the pile)"
    if detail.slivers:
        vetted += f" ({detail.slivers} posed on slivers no fit took)"
    return FrameFits(frame.index, "ready", f"{len(fits)} fits{vetted}, {un_pix.size} unexplained px", (H, W), fits,
                     fit_pix, code[fit_pix].astype(np.int32), un_pix,
                     detail.dist_mm.ravel()[un_pix].astype(np.float32), detail.err_mm.ravel()[un_pix].astype(np.float32),
                     seconds, un_code=detail.surface.ravel()[un_pix].astype(np.int32),
                     surfaces=dataclasses.replace(surfaces, parts=(), part_err_mm=()), f_px=f_px,
                     floor_mm=float(p.err_floor_mm), k=float(p.k), part_mesh=(detail.vertices_mm, detail.triangles),
                     part_err_mm=tuple(float(e) for e in surfaces.part_err_mm))


def known_surfaces(frame: Frame, job: Job, detail: Any, bin_model: BinModel) -> tuple[KnownSurfaces, float]:
    """The known surfaces ``explained`` measured a frame's distances to (its :class:`ExplainedDetail`
    ``detail``), and the focal length (pixels) of its footprints: the kept fits posed, each with the
    robust residual of the pixels it is the nearest surface of
    (:func:`zcut.explained.fit_sigmas`), the registered bin and the table plane as the method fits them
    (``replay.pipeline.explained.bin_and_table_surfaces``, called, not copied). ``err_image`` of the detail's
    nearest surfaces with these gives the detail's Err to the bit (tests/annotate/test_page_fits_remeasure.py)."""
    from replay.pipeline.explained import bin_and_table_surfaces
    from zcut import explained as ex

    xyz = frame.xyz.astype(np.float64) * 1000.0
    v, t = detail.vertices_mm, detail.triangles
    stated = [float(f.err_mm) for f in detail.fits]
    surfaces = ex.KnownSurfaces(parts=[(v @ f.pose[:3, :3].T + f.pose[:3, 3], t) for f in detail.fits],
                                part_err_mm=stated)
    surfaces = bin_and_table_surfaces(xyz, job.removal, job.registration, bin_model, surfaces)
    surfaces = dataclasses.replace(surfaces, part_err_mm=ex.fit_sigmas(ex.Nearest(detail.dist_mm, detail.surface),
                                                                       stated, where=job.zone))
    K = frame.intrinsics
    f_px = 0.5 * (K.fx + K.fy) if K is not None and (K.height, K.width) == np.shape(job.zone) else ex.focal_px(xyz)
    return surfaces, float(f_px)


class Fitter:
    """Fits the frames the catalogue prepared, one at a time in a background thread: the frame the
    page wants first (:meth:`want`), else the lowest index waiting.

    ``points(index)`` gives a frame's points (the catalogue's spill, memory-mapped): the frames
    waiting keep their zone, not their cloud.
    """

    def __init__(self, config: Any, bin_model: BinModel | None, points: Any, *, model_name: str,
                 model_points: list[list[float]], k: float) -> None:
        self.config = config
        self.bin_model = bin_model
        self.points = points
        self.model_name = model_name
        self.model_points = model_points
        self.k = k
        self.results: dict[int, FrameFits] = {}
        #: (index, seeds) -> (the background fits they were applied to, the fits with them): :meth:`fits_for`
        self._seeded: dict[tuple[int, tuple[tuple[int, int], ...]], tuple[FrameFits, FrameFits]] = {}
        self._pending: dict[int, tuple[Frame, Job]] = {}
        self._running: int | None = None
        self._wanted: int | None = None
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="zcut-annotate-fits", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop fitting: a fit under way stops at its next stop point (:mod:`zcut.cancel`: between the fits'
        regions and candidates, the sliver pass's regions and guesses) and its frame stays unfitted; returns when
        the thread has ended (or after :data:`STOP_WAIT_S`: the thread is a daemon, a step longer than that is not
        waited for)."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=STOP_WAIT_S)

    @property
    def stopped(self) -> bool:
        """Whether :meth:`stop` was called and the fitting thread has ended (or never started)."""
        return self._stop.is_set() and (self._thread is None or not self._thread.is_alive())

    def submit(self, frame: Frame, result: FrameResult) -> None:
        """Queue a prepared frame (its points are read from ``points`` when its turn comes)."""
        light = dataclasses.replace(frame, xyz=np.zeros((0, 0, 3), np.float32), rgb=None, masks={}, codes={})
        job = Job.of(result)
        with self._cond:
            self._pending[frame.index] = (light, job)
            self._cond.notify_all()

    def want(self, index: int) -> None:
        """The page shows frame ``index``: fit it next."""
        with self._cond:
            if index not in self.results and index != self._running:
                self._wanted = index
                self._cond.notify_all()

    def status(self, index: int) -> tuple[str, FrameFits | None]:
        """(``"ready"`` / ``"error"`` with its fits, ``"fitting"``, ``"waiting"``) of a frame."""
        with self._cond:
            got = self.results.get(index)
            if got is not None:
                return got.status, got
            return ("fitting" if index == self._running else "waiting"), None

    def _next(self) -> tuple[int, tuple[Frame, Job]] | None:
        with self._cond:
            while not self._stop.is_set():
                if self._pending:
                    i = self._wanted if self._wanted in self._pending else min(self._pending)
                    assert i is not None
                    if i == self._wanted:
                        self._wanted = None
                    self._running = i
                    return i, self._pending.pop(i)
                self._cond.wait(timeout=1.0)
        return None

    def _run(self) -> None:
        while True:
            job = self._next()
            if job is None:
                return
            i, (light, work) = job
            try:
                frame = dataclasses.replace(light, xyz=self.points(i))
                with stop_when(self._stop.is_set):  # stop() ends a fit under way (zcut.cancel)
                    got = fit_frame(frame, work, self.config, self.bin_model)
            except Cancelled:  # stopped: the frame is not fitted (it waits again), no result is kept
                with self._cond:
                    self._pending[i] = (light, work)
                    self._running = None
                    self._cond.notify_all()
                return
            except Exception as e:  # noqa: BLE001 - shown on the page for this frame; the others go on
                H, W = np.shape(work.valid)
                got = FrameFits(i, "error", f"the fits failed: {type(e).__name__}: {e}", (H, W))
            with self._cond:
                self.results[i] = got
                self._running = None
                self._cond.notify_all()

    def fits_for(self, index: int, seeds: Sequence[tuple[int, int]] = ()) -> FrameFits | None:
        """The frame's fits as an annotator sees them: the background fits (None before they are ready)
        with that annotator's ``seeds`` (pixels (x, y), in the order clicked) applied one after the other
        (:meth:`FrameFits.seeded`). Each step is kept (:data:`SEEDED_KEPT` of them, the least recently used
        out first) and the walk starts from the longest kept prefix of ``seeds``, so a new seed costs one
        refit however many came before it."""
        with self._cond:
            root = self.results.get(index)
        if root is None or root.status != "ready" or not seeds:
            return root
        seeds = [(int(x), int(y)) for x, y in seeds]
        ff, start = root, 0
        with self._cond:
            for j in range(len(seeds), 0, -1):  # the longest prefix kept, applied to these background fits
                key = (index, tuple(seeds[:j]))
                got = self._seeded.get(key)
                if got is not None and got[0] is root:
                    self._seeded[key] = self._seeded.pop(key)  # the most recently used last
                    ff, start = got[1], j
                    break
        xyz = None
        for j in range(start, len(seeds)):
            if xyz is None:
                xyz = np.asarray(self.points(index), np.float64) * 1000.0
            x, y = seeds[j]
            ff = ff.seeded(x, y, xyz, self.config)
            with self._cond:
                while len(self._seeded) >= SEEDED_KEPT:  # the least recently used out first
                    self._seeded.pop(next(iter(self._seeded)))
                self._seeded[(index, tuple(seeds[:j + 1]))] = (root, ff)
        return ff

    def seed(self, index: int, seeds: Sequence[tuple[int, int]], x: int, y: int) -> tuple[FrameFits, int]:
        """Seed a missed instance at pixel (``x``, ``y``) of a fitted frame on top of an annotator's earlier
        ``seeds`` (:meth:`fits_for`): (the fits with it, how many instances it found). Raises ValueError
        when the frame has no fits yet."""
        before = self.fits_for(index, seeds)
        if before is None or before.status != "ready":
            raise ValueError(f"frame {index} has no fits yet")
        after = self.fits_for(index, (*seeds, (int(x), int(y))))
        assert after is not None
        return after, len(after.fits) - len(before.fits)

    def wait(self, index: int, timeout: float) -> FrameFits | None:
        """Block until frame ``index`` is fitted (tests, tools); None on timeout."""
        with self._cond:
            self._cond.wait_for(lambda: index in self.results or self._stop.is_set(), timeout=timeout)
            return self.results.get(index)


def model_points(prepared: Any, n: int = MODEL_POINTS) -> list[list[float]]:
    """Up to ``n`` of the part model's surface samples (mm, model frame), evenly taken, for the 3D view."""
    s = np.asarray(prepared.samples, np.float64)
    if len(s) > n:
        s = s[np.linspace(0, len(s) - 1, n).astype(np.int64)]
    out: list[list[float]] = np.round(s, 3).tolist()
    return out


def fitter_for(replay: Any, log_path: str | Path, points: Any) -> tuple[Fitter | None, str]:
    """The page's :class:`Fitter` for a log opened for replay (a
    :class:`replay.pipeline.session.ReplaySession`), or None and why not: its part model is the config's
    ``explained.part_model`` (``--part-model FILE``), else the log's ``part_model.ply`` attachment.

    Raises
    ------
    ParameterError, LogFormatError
        One line: a part model that is not a readable mesh.
    """
    from replay.logs.part_model import PART_MODEL_ATTACHMENT, carries_part_model
    from replay.pipeline.explained import NAME, part_model, with_part_model

    resolved = replay.resolved
    p = resolved.config.bank[NAME]
    if not p.part_model:
        if not carries_part_model(replay.reader):
            return None, (f"no part model: the page shows no fits (give --part-model FILE; the log carries no "
                          f"{PART_MODEL_ATTACHMENT})")
        resolved = with_part_model(resolved, log_path)
        p = resolved.config.bank[NAME]
    _, _, prepared = part_model(p.part_model, p.part_model_unit)
    bin_model = replay.prepared.model if getattr(replay, "prepared", None) is not None else None
    name = Path(p.part_model).name
    if name.lower().endswith(".mcap"):
        name = f"{name}'s {PART_MODEL_ATTACHMENT}"
    return Fitter(resolved.config, bin_model, points, model_name=name, model_points=model_points(prepared),
                  k=float(p.k)), ""
