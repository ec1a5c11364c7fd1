"""Fits of the slivers no fit finds: the part model posed on a small unexplained region (issue 29).

A partly occluded part shows a sliver (a few per cent of its surface) that the frame's fits
(:func:`zcut.fits.fit_parts`) do not take: too few pixels for a global initial guess. This pass tries
each unexplained region of at least :attr:`SliverParams.min_px` pixels once more, with guesses a pile
makes likely and a constraint the scan gives for free:

1. *Guesses.* The rotations of the frame's fitted instances nearest to the region (parts in a pile rest
   in few orientations; up to :attr:`SliverParams.neighbours` of them, one of each class under the
   model's symmetries), each translated so that spread points of the model's camera-facing side land on
   the region's centroid (:func:`zcut.fits.icp.shifted_guesses`, :func:`zcut.fits.icp.guess_translations`).
2. *ICP on the region's pixels only* (:func:`zcut.fits.icp.icp`, a wide gate first), then the
   region's distances to the posed model (:meth:`zcut.fits.model.PartModel.distance`): the pixels within k × Err of it (Err = max(floor,
   √(σ² + c²/2)), σ the frame's median fit residual, c the pixel's footprint) are the ones it explains;
   its residual is their RMS distance.
3. *Solids and free space.* A pose whose solid enters a fitted instance's (more than
   :attr:`SliverParams.max_overlap` of either's volume, :func:`zcut.fit_vetting.pose_overlaps`) is
   refused: parts do not interpenetrate, and a part hiding its body inside another behind a patch
   would. The camera saw every valid pixel's point: a posed model may lie behind a measured point
   (occluded by it) but not in front of it. Over the posed model's silhouette (the valid pixels whose
   ray meets it, :meth:`zcut.fits.model.PartModel.ray_depths`), a pixel whose point lies farther than
   k × Err behind the model's first hit saw through the model; a pose whose share of such pixels
   exceeds :attr:`SliverParams.max_see_through` is refused.
   With :attr:`SliverParams.split_steps` N > 0 the regions are cut at the scan's depth steps before anything else:
   the unexplained pixels with a valid 4-neighbour more than N footprints off in depth (:func:`depth_steps`; an
   invalid neighbour does not cut) take part in no region, so a region no longer joins two things at different depths
   (docs/labelling.md, "Twenty-second round": cut at every depth edge, invalid neighbours too, the regions were
   shredded by the ray-traced scan's dropouts; "Twenty-third round"); the pixels left out are judged against the
   poses found as every pixel is (the method's join).
4. *Acceptance.* The pose of lowest residual among those with residual ≤ :attr:`SliverParams.max_residual`
   × the frame's median Err, a share of the region explained ≥ :attr:`SliverParams.min_share` and free
   space kept. Its explained pixels become explained.

Pure: arrays in, arrays out. It reads the scan, the unexplained mask and the frame's fitted poses; never
a truth or a generator's pose. Inside a :func:`zcut.cancel.stop_when` scope whose check says stop it raises
:class:`zcut.errors.Cancelled` at its next stop point (before each region, and before each guess refined): the
labelling page's fitter stops it part-way (``annotate.fits.Fitter.stop``); outside a scope, or while the check says
go on, the result is the same.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from zcut.cancel import stop_point
from zcut.errors import InputShapeError
from zcut.fits import PartModel
from zcut.fits.icp import guess_translations, icp, pose_matrix, shifted_guesses
from zcut.fits.model import projected_area_px

__all__ = ["SliverFit", "SliverParams", "depth_steps", "fit_slivers", "projected_area_px", "see_through_share"]

EIGHT = np.ones((3, 3), bool)
EIGHT.setflags(write=False)
#: The first ICP of a guess runs with this many times the gate.
WIDE = 2.5


@dataclass(frozen=True, slots=True)
class SliverParams:
    """Options of :func:`fit_slivers` (lengths in mm).

    Attributes
    ----------
    min_px : int
        Unexplained regions (8-connected) of fewer pixels are not tried.
    max_px : int
        Nor those of more (a region that large is no sliver; the frame's fits had their chance).
    neighbours : int
        The rotations of at most this many fitted instances nearest to the region (by their centres) are tried.
    shifts : int
        Per rotation, this many spread camera-facing model points put on the region's centroid (and the
        facing side's centroid).
    iterations : int
        ICP iterations per guess.
    gate_mm : float
        The ICP's correspondence gate.
    k : float
        A pixel is explained within k × Err.
    floor_mm : float
        Err's floor.
    max_residual : float
        Accept when the residual is at most this many times the frame's median Err.
    min_share : float
        ... and the pose explains at least this share of the region's pixels.
    max_see_through : float
        ... and at most this share of its silhouette was seen through (free space).
    split_steps : float
        When > 0, the unexplained pixels at a depth step of more than this many footprints (:func:`depth_steps`) take
        part in no region: the regions are cut there before they are counted, sized and posed (0: no cut).
    min_area_share : float
        When > 0, a region is tried only when it also holds at least this share of a whole part's projected area at
        its depth, π (extent · f / z)² pixels (:func:`projected_area_px`; extent the model's largest distance of a
        vertex from its centroid, f the mean of fx and fy, z the region's median depth): the floor means the same at
        every resolution and depth (the fits' second pass's ``seed_min_share`` rule, :mod:`zcut.fits.params`); 0:
        :attr:`min_px` alone.
    max_points : int
        At most this many of a region's points (an even subsample) take part in the ICP.
    free_checks : int
        At most this many of a region's distinct poses (guesses that converged to one placement count once) that
        pass the residual and the share are checked for free space, lowest residual first (a sliver fits several
        poses as well: free space tells them apart).
    max_overlap : float
        A pose whose solid shares more than this share of its volume with a fitted instance's (or a sliver
        fitted before it), either way, is refused (:func:`zcut.fit_vetting.pose_overlaps`, the fits' own rule
        and default): a part cannot lie inside another, as a part hiding behind a patch of another would.
    max_regions : int
        At most this many regions are tried, the largest first (ties: raster order): the pass's CPU bound.
    coarse : int
        0: every guess runs the full ICP (wide gate, then the gate). Else every guess runs this many of the wide
        iterations first and only the :attr:`refine` guesses that match the most points (then the lowest RMS)
        go on with the rest: the pass's CPU per region.
    refine : int
        With :attr:`coarse`, the guesses that go on.
    """

    min_px: int = 30
    max_px: int = 2000
    neighbours: int = 6
    shifts: int = 12
    iterations: int = 20
    gate_mm: float = 4.0
    k: float = 3.0
    floor_mm: float = 0.1
    max_residual: float = 1.5
    min_share: float = 0.8
    max_see_through: float = 0.05
    split_steps: float = 0.0
    min_area_share: float = 0.0
    max_points: int = 400
    free_checks: int = 8
    max_overlap: float = 0.05
    max_regions: int = 1_000_000
    coarse: int = 0
    refine: int = 6

    def __post_init__(self) -> None:
        for name in ("min_px", "max_px", "neighbours", "iterations", "max_points", "free_checks", "max_regions",
                     "refine"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"SliverParams.{name} must be at least 1, got {getattr(self, name)!r}")
        if not float(self.split_steps) >= 0:
            raise ValueError(f"SliverParams.split_steps must be at least 0, got {self.split_steps!r}")
        if not 0 <= int(self.coarse) <= int(self.iterations):
            raise ValueError(f"SliverParams.coarse must lie in [0, iterations], got {self.coarse!r}")
        for name in ("gate_mm", "k", "max_residual"):
            if not float(getattr(self, name)) > 0:
                raise ValueError(f"SliverParams.{name} must be positive, got {getattr(self, name)!r}")
        for name in ("min_share", "max_see_through", "max_overlap", "min_area_share"):
            v = float(getattr(self, name))
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"SliverParams.{name} must lie in [0, 1], got {v!r}")


@dataclass(frozen=True, slots=True)
class SliverFit:
    """One sliver fitted.

    Attributes
    ----------
    pose : (4, 4) float64 ndarray
        Model (mm) -> camera (mm).
    err_mm : float
        RMS distance of the pixels it explains to the posed model.
    share : float
        Share of the region's pixels it explains.
    see_through : float
        Share of its silhouette the camera saw through.
    pixels : (n,) int64 ndarray
        The region's pixels it explains (flat indices, increasing).
    """

    pose: np.ndarray
    err_mm: float
    share: float
    see_through: float
    pixels: np.ndarray


def _intrinsics(xyz_mm: np.ndarray, valid: np.ndarray) -> tuple[float, float, float, float] | None:
    from zcut.fits import estimate_intrinsics

    return estimate_intrinsics(np.where(valid[..., None], xyz_mm, np.nan))


def see_through_share(xyz_mm: np.ndarray, valid: np.ndarray, model: PartModel, pose: np.ndarray, *,
                      intrinsics: tuple[float, float, float, float], sigma_mm: float, k: float = 3.0,
                      floor_mm: float = 0.1) -> tuple[float, int]:
    """(share, silhouette px): of the valid pixels whose camera ray meets the model posed at ``pose``, the share
    whose point lies more than k × Err behind the model's first hit (the camera saw through the model there).

    Parameters
    ----------
    xyz_mm : (H, W, 3) float ndarray
        The organized cloud (camera frame, mm).
    valid : (H, W) bool ndarray
    model : PartModel
    pose : (4, 4) float ndarray
        Model -> camera.
    intrinsics : (fx, fy, cx, cy)
        To find the model's window in the image.
    sigma_mm : float
        The σ of Err = max(floor, √(σ² + c²/2)), c the pixel's footprint.
    """
    H, W = valid.shape
    fx, fy, cx, cy = intrinsics
    R, t = pose[:3, :3], pose[:3, 3]
    v = model.vertices @ R.T + t
    if not (v[:, 2] > 0).all():
        return 1.0, 0
    u, w = fx * v[:, 0] / v[:, 2] + cx, fy * v[:, 1] / v[:, 2] + cy
    c0, c1 = max(int(np.floor(u.min())) - 1, 0), min(int(np.ceil(u.max())) + 2, W)
    r0, r1 = max(int(np.floor(w.min())) - 1, 0), min(int(np.ceil(w.max())) + 2, H)
    if c0 >= c1 or r0 >= r1:
        return 0.0, 0
    win = valid[r0:r1, c0:c1]
    p = np.asarray(xyz_mm[r0:r1, c0:c1], np.float64)[win]
    if not len(p):
        return 0.0, 0
    rng = np.linalg.norm(p, axis=1)
    d = p / rng[:, None]
    hit = model.ray_depths(np.repeat((-R.T @ t)[None], len(p), axis=0), d @ R)
    seen = np.isfinite(hit)
    if not seen.any():
        return 0.0, 0
    foot = np.abs(p[seen, 2]) / fx
    err = np.maximum(floor_mm, np.sqrt(sigma_mm ** 2 + foot ** 2 / 2.0))
    behind = (rng[seen] - hit[seen]) > k * err
    return float(behind.mean()), int(seen.sum())


def _camera(xyz_mm: np.ndarray, valid: np.ndarray,
            intrinsics: tuple[float, float, float, float] | None) -> tuple[float, float, float, float] | None:
    """(fx, fy, cx, cy): the caller's ``intrinsics``, or estimated from the cloud (:func:`_intrinsics`; None when it
    cannot be)."""
    if intrinsics is None:
        return _intrinsics(xyz_mm, valid)
    return float(intrinsics[0]), float(intrinsics[1]), float(intrinsics[2]), float(intrinsics[3])


def depth_steps(xyz_mm: np.ndarray, valid: np.ndarray, fx: float, n: float) -> np.ndarray:
    """(H, W) bool: the valid pixels at a depth step of the scan — a 4-neighbour in ``valid`` more than ``n``
    footprints (the pixel's depth / ``fx``) off in depth. An invalid neighbour (or the image's border) is no step."""
    H, W = valid.shape
    z = np.full((H + 2, W + 2), np.nan)
    z[1:-1, 1:-1] = np.where(valid, np.asarray(xyz_mm[..., 2], np.float64), np.nan)
    mid = z[1:-1, 1:-1]
    tol = float(n) * np.abs(mid) / float(fx)
    step = np.zeros(mid.shape, bool)
    with np.errstate(invalid="ignore"):
        for nb in (z[1:-1, 2:], z[1:-1, :-2], z[2:, 1:-1], z[:-2, 1:-1]):
            step |= np.abs(nb - mid) > tol  # NaN (an invalid pixel or neighbour) compares False
    return step


def _distinct(rotations: list[np.ndarray], model: PartModel, tol: float = 0.05) -> list[np.ndarray]:
    """The rotations, one of each class equal up to the model's symmetries (Frobenius distance below ``tol``)."""
    out: list[np.ndarray] = []
    for R in rotations:
        if not any(min(float(np.linalg.norm(R @ S - Q)) for S in model.symmetries) < tol for Q in out):
            out.append(R)
    return out


def _ball_pose(pts: np.ndarray, model: PartModel, T0: np.ndarray, *, iterations: int = 20) -> np.ndarray:
    """The ball's pose (no rotation) whose sphere of ``model.sphere_radius`` fits ``pts`` best (Gauss-Newton on the
    centre from ``T0``'s)."""
    r = float(model.sphere_radius or 0.0)
    c = T0[:3, :3] @ model.centroid + T0[:3, 3]
    for _ in range(iterations):
        d = pts - c
        n = np.maximum(np.linalg.norm(d, axis=1), 1e-9)
        step = np.linalg.lstsq(-d / n[:, None], r - n, rcond=None)[0]
        c = c + step
        if not np.isfinite(c).all() or float(np.linalg.norm(step)) < 1e-7:
            break
    return pose_matrix(np.eye(3), c - model.centroid)


def _same_pose(model: PartModel, A: np.ndarray, B: np.ndarray, *, mm: float = 0.5, tol: float = 0.05) -> bool:
    """Whether the model posed at ``A`` and at ``B`` is one placement: centroids within ``mm`` and rotations equal up
    to the model's symmetries (Frobenius distance below ``tol``; a ball: any rotation)."""
    ca = A[:3, :3] @ model.centroid + A[:3, 3]
    cb = B[:3, :3] @ model.centroid + B[:3, 3]
    if float(np.linalg.norm(ca - cb)) > mm:
        return False
    if model.sphere_radius is not None:
        return True
    return min(float(np.linalg.norm(A[:3, :3] @ S - B[:3, :3])) for S in model.symmetries) < tol


def _overlap(model: PartModel, T: np.ndarray, poses: np.ndarray) -> float:
    """The largest share of volume the model posed at ``T`` shares with one posed at any of ``poses`` (either way,
    :func:`zcut.fit_vetting.pose_overlaps`: the fitting's one overlap rule), those whose centres lie within two
    extents of its only."""
    from zcut.fit_vetting import pose_overlaps

    c = T[:3, :3] @ model.centroid + T[:3, 3]
    cs = poses[:, :3, :3] @ model.centroid + poses[:, :3, 3]
    near = poses[np.linalg.norm(cs - c, axis=1) <= 2.0 * model.extent_mm]
    if not len(near):
        return 0.0
    Ts = np.repeat(T[None], len(near), axis=0)
    return float(max(pose_overlaps(model.solid, Ts, near).max(), pose_overlaps(model.solid, near, Ts).max()))


def fit_slivers(xyz_mm: np.ndarray, valid: np.ndarray, unexplained: np.ndarray, model: PartModel,
                poses: np.ndarray, *, sigma_mm: float, params: SliverParams | None = None,
                intrinsics: tuple[float, float, float, float] | None = None) -> list[SliverFit]:
    """The slivers of ``unexplained`` the part model explains (module docstring), at most one fit a region.

    Parameters
    ----------
    xyz_mm : (H, W, 3) float ndarray
        The organized cloud (camera frame, mm).
    valid : (H, W) bool ndarray
    unexplained : (H, W) bool ndarray
        The pixels no known surface explains (only the valid ones are used).
    model : PartModel
        The prepared part model (:func:`zcut.fits.prepare_model`).
    poses : (n, 4, 4) float ndarray
        The frame's fitted instances (model -> camera): their rotations are the guesses. None fitted: no sliver.
    sigma_mm : float
        The frame's median fit residual (the σ of Err; the acceptance's median Err is Err at the region's depth).
    params : SliverParams, optional
    intrinsics : (fx, fy, cx, cy), optional
        The camera's; default: estimated from the cloud (:func:`zcut.fits.estimate_intrinsics`).

    Returns
    -------
    list of SliverFit
        In the order the regions were tried: the largest first, ties in raster order.

    Raises
    ------
    zcut.errors.Cancelled
        Inside a :func:`zcut.cancel.stop_when` scope whose check said stop (no fits: none is partial).
    """
    p = params or SliverParams()
    xyz_mm = np.asarray(xyz_mm)
    valid = np.asarray(valid, bool)
    unexplained = np.asarray(unexplained, bool)
    if xyz_mm.ndim != 3 or xyz_mm.shape[2] != 3 or valid.shape != xyz_mm.shape[:2] or unexplained.shape != valid.shape:
        raise InputShapeError(f"fit_slivers: xyz_mm (H, W, 3), valid and unexplained (H, W) expected, got "
                              f"{xyz_mm.shape}, {valid.shape}, {unexplained.shape}")
    poses = np.asarray(poses, np.float64).reshape(-1, 4, 4)
    valid = valid & np.isfinite(xyz_mm).all(axis=2) & (xyz_mm[..., 2] > 0)
    mask = unexplained & valid
    if not mask.any() or not len(poses) or not np.isfinite(sigma_mm):
        return []
    intr: tuple[float, float, float, float] | None = None
    if p.split_steps > 0:  # the regions cut at the scan's depth steps: the step pixels take part in none
        intr = _camera(xyz_mm, valid, intrinsics)
        if intr is None:
            return []
        mask &= ~depth_steps(xyz_mm, valid, intr[0], p.split_steps)
    labels, n = ndimage.label(mask, structure=EIGHT)
    sizes = np.bincount(labels.ravel(), minlength=n + 1)
    keep = np.flatnonzero((sizes >= p.min_px) & (sizes <= p.max_px))
    keep = keep[keep > 0]
    if p.min_area_share > 0 and keep.size:  # the floor as a share of a whole part's projected area at its depth
        if intr is None:
            intr = _camera(xyz_mm, valid, intrinsics)
            if intr is None:
                return []
        z_med = np.asarray(ndimage.median(np.asarray(xyz_mm[..., 2], np.float64), labels, keep), np.float64)
        floor = np.ceil(p.min_area_share * projected_area_px(model, z_med, 0.5 * (intr[0] + intr[1])))
        keep = keep[sizes[keep] >= floor]
    keep = keep[np.argsort(-sizes[keep], kind="stable")][:p.max_regions]  # the largest first, at most max_regions
    if not keep.size:
        return []
    if intr is None:
        intr = _camera(xyz_mm, valid, intrinsics)
    if intr is None:
        return []
    flat_xyz = np.asarray(xyz_mm, np.float64).reshape(-1, 3)
    lit = np.flatnonzero(labels.ravel())  # the regions' pixels only, increasing: sorted by region, stable
    lab = labels.ravel()[lit]
    srt = np.argsort(lab, kind="stable")
    order = lit[srt]
    bounds = np.searchsorted(lab[srt], np.arange(n + 2))  # region j: order[bounds[j]:bounds[j + 1]]
    centres = poses[:, :3, 3]
    taken = poses  # the solids a sliver's part may not enter: the fits', then the slivers' fitted before it
    out: list[SliverFit] = []
    for j in keep.tolist():
        stop_point()  # a caller's stop (zcut.cancel) is seen before each region and each guess refined
        pix = order[bounds[j]:bounds[j + 1]]
        pts = flat_xyz[pix]
        c = pts.mean(axis=0)
        near = np.argsort(np.linalg.norm(centres - c, axis=1), kind="stable")[:p.neighbours]
        # a ball's orientation is no guess: one rotation
        Rs = [np.eye(3)] if model.sphere_radius is not None else \
            _distinct([poses[i, :3, :3] for i in near.tolist()], model)
        if not Rs:
            continue
        R_all = np.stack(Rs)
        ball = model.sphere_radius is not None
        R_sh, t_sh = shifted_guesses(pts, R_all, model, 0 if ball else p.shifts)
        t_c = guess_translations(pts, R_all, model)
        guesses = [pose_matrix(R, t) for R, t in zip(R_all, t_c)] + [pose_matrix(R, t) for R, t in zip(R_sh, t_sh)]
        use = pts[np.linspace(0, len(pts) - 1, min(len(pts), p.max_points)).astype(np.int64)]
        foot = np.abs(pts[:, 2]) / intr[0]
        err_px = np.maximum(p.floor_mm, np.sqrt(sigma_mm ** 2 + foot ** 2 / 2.0))
        med_err = float(np.median(err_px))
        best: tuple[float, np.ndarray, np.ndarray, float] | None = None
        tried = []
        refined: list[np.ndarray] = []
        if ball:  # a ball: its centre by least squares at its radius from the facing guess, no ICP
            refined = [_ball_pose(use, model, guesses[0])]
            starts: list[tuple[np.ndarray, int]] = []
        elif p.coarse:  # every guess a few wide iterations; the refine best (most points matched, then rms) go on
            first = [icp(use, model, T0, iterations=p.coarse, gate_mm=WIDE * p.gate_mm, k=p.k, floor_mm=p.floor_mm)
                     for T0 in guesses]
            rank = sorted((i for i, (_, r, m) in enumerate(first) if np.isfinite(r) and m >= 3),
                          key=lambda i: (-first[i][2], first[i][1], i))
            starts = [(first[i][0], p.iterations - p.coarse) for i in rank[:p.refine]]
        else:
            starts = [(T0, p.iterations) for T0 in guesses]
        for T0, wide_left in starts:
            stop_point()
            # a wide gate first (a sliver's centroid may lie far from the guess's point), then the gate
            T = T0
            if wide_left > 0:
                T, rms, m = icp(use, model, T0, iterations=wide_left, gate_mm=WIDE * p.gate_mm, k=p.k,
                                floor_mm=p.floor_mm)
            T, rms, m = icp(use, model, T, iterations=p.iterations, gate_mm=p.gate_mm, k=p.k, floor_mm=p.floor_mm)
            if np.isfinite(rms) and m >= 3:
                refined.append(T)
        for T in refined:
            d = model.distance((pts - T[:3, 3]) @ T[:3, :3])
            inl = d <= p.k * err_px
            share = float(inl.mean())
            if share < p.min_share:
                continue
            res = float(np.sqrt(np.mean(d[inl] ** 2)))
            if res > p.max_residual * med_err:
                continue
            tried.append((res, T, inl, share))
        tried.sort(key=lambda r: r[0])
        checked: list[np.ndarray] = []
        for res, T, inl, _share in tried:  # the solid and free-space checks, lowest residual first
            if len(checked) >= p.free_checks:
                break
            if any(_same_pose(model, T, Q) for Q in checked):  # guesses that converged to one pose: checked once
                continue
            checked.append(T)
            if _overlap(model, T, taken) > p.max_overlap:
                continue
            st, sil = see_through_share(xyz_mm, valid, model, T, intrinsics=intr, sigma_mm=sigma_mm, k=p.k,
                                        floor_mm=p.floor_mm)
            if sil and st <= p.max_see_through:
                best = (res, T, inl, st)
                break
        if best is None:
            continue
        res, T, inl, st = best
        out.append(SliverFit(T, res, float(inl.mean()), st, np.sort(pix[inl])))
        taken = np.concatenate([taken, T[None]])
    return out
