"""What the known surfaces explain: every valid pixel's distance to the nearest one, and which it is.

The paper (§2) calls a point an outlier when its distance to the fitted CAD model exceeds 3 × Err,
Err the fit's residual. In a bin-picking cell the known surfaces are the fitted part instances,
the registered bin model and the table plane: a point farther than ``k`` × Err from every one of
them is *unexplained* (:func:`unexplained`), and the method ``explained`` reports those points.

**Distances** (:func:`nearest_surface`) are exact: point-to-triangle distances to the posed part
meshes and to a bin mesh (Open3D's ``RaycastingScene``, float32 in mm: within 1e-4 mm at a camera's
coordinates, as :mod:`replay.synth.surfaces` computes the synthetic scenes' truth), the
point-to-plane distance to the table, and — when the bin is a registered model *cloud* with
normals (the pipeline's ``bin_model.ply``) — the point-to-plane distance to the nearest model point
when that point lies within ``2 × spacing``, else the distance to that point.
The nearest surface is recorded as a code (:data:`SURFACE_TABLE`, :data:`SURFACE_BIN`,
:data:`SURFACE_NONE`, or the part instance's 0-based index).

**Err** (:func:`err_image`) is, per pixel, the residual a fit of the surface that explains it has
there: ``Err = max(floor, sqrt(σ_s² + c²/2))``, with σ_s the residual of that surface's fit (a
part instance: its ``PartFit.err_mm``; the bin: the registration's residual on the frame's certain
bin pixels; the table: the robust residual of the plane fit, :func:`fit_plane`) and c the side
of the pixel's footprint at its depth (z / f, :func:`footprint_mm`; c·√2/2 is half its diagonal,
how far a point the footprint measured can lie from the surface point on its centre ray). It is
the form of the synthetic truth's Err (:func:`replay.synth.surfaces.err_mm`) with the generator's
known noise sigma replaced by what a fit measures. A pixel no surface explains takes the largest
σ_s. :func:`residual_sigma` is the robust residual of a surface's supporting pixels, for a
surface whose fit states none.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .errors import InputShapeError, ParameterError, describe_array

if TYPE_CHECKING:
    from .edge_surface import EdgeSurfaceParams

#: the paper's factor: a point farther than K × Err from every known surface is an outlier
K_ERR = 3.0
#: the surface codes of :attr:`Nearest.surface` that are not part instances (those are 0, 1, ...)
SURFACE_NONE = -1
SURFACE_TABLE = -2
SURFACE_BIN = -3
#: the code of the edge-aware local surface (:mod:`zcut.edge_surface`), the parts' surface where no part model is known
SURFACE_LOCAL = -4
#: the edge-aware local surface's patch is a surface when its RMS residual is within this share of the
#: zone's median footprint (or within the frame's own gate, :func:`local_surface_params`)
LOCAL_FIT_FOOTPRINTS = 0.1
#: 1 / Φ⁻¹(3/4): the normal σ of a median absolute value (the half-normal's median is 0.6745 σ)
MAD_TO_SIGMA = 1.482602218505602


@dataclass(frozen=True, slots=True)
class Plane:
    """A plane ``normal · p = offset`` in the camera frame (mm), with its fit's residual.

    Attributes
    ----------
    normal : (3,) float64 ndarray
        Unit normal.
    offset : float
        mm.
    residual_mm : float
        Robust σ of the fit's inliers' distances (NaN when unknown).
    """

    normal: np.ndarray
    offset: float
    residual_mm: float = float("nan")

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Unsigned distance (mm) of each of ``points`` (n, 3) to the plane."""
        return np.abs(np.asarray(points, np.float64) @ self.normal - self.offset)


@dataclass(frozen=True, slots=True)
class KnownSurfaces:
    """The surfaces that explain a frame, all posed in the camera frame (mm).

    Attributes
    ----------
    parts : sequence of (vertices (n, 3), triangles (m, 3))
        The fitted part instances' meshes, each at its pose; instance i has code i.
    part_err_mm : sequence of float
        Each instance's residual σ (``PartFit.err_mm``), one per part.
    bin_mesh : (vertices, triangles) or None
        The bin as a mesh (a CAD model at its registered pose).
    bin_points : (vertices (n, 3), normals (n, 3)) or None
        The bin as a registered model cloud with unit normals (the pipeline's bin model).
    bin_spacing_mm : float
        Typical spacing of ``bin_points`` (their point-to-plane distance holds within 2 × it).
    bin_err_mm : float
        The bin's residual σ (NaN: unknown).
    table : Plane or None
    local_err_mm : float
        The residual σ of the edge-aware local surface (:data:`SURFACE_LOCAL`, :func:`with_local_surface`;
        NaN: unknown or not used).
    """

    parts: Sequence[tuple[np.ndarray, np.ndarray]] = ()
    part_err_mm: Sequence[float] = ()
    bin_mesh: tuple[np.ndarray, np.ndarray] | None = None
    bin_points: tuple[np.ndarray, np.ndarray] | None = None
    bin_spacing_mm: float = 1.0
    bin_err_mm: float = float("nan")
    table: Plane | None = None
    local_err_mm: float = float("nan")

    def __post_init__(self) -> None:
        if len(self.part_err_mm) != len(self.parts):
            raise InputShapeError(f"KnownSurfaces: {len(self.parts)} parts but {len(self.part_err_mm)} residuals")
        for i, (v, t) in enumerate(self.parts):
            _check_mesh(v, t, f"part {i}")
        if self.bin_mesh is not None:
            _check_mesh(*self.bin_mesh, "the bin mesh")
        if self.bin_points is not None:
            p, n = (np.asarray(a) for a in self.bin_points)
            if p.ndim != 2 or p.shape[1] != 3 or n.shape != p.shape:
                raise InputShapeError(f"KnownSurfaces.bin_points must be two (n, 3) arrays, got "
                                      f"{describe_array(p)} and {describe_array(n)}")

    def sigma(self, code: int) -> float:
        """The residual σ (mm) of the surface ``code`` (NaN when unknown)."""
        if code >= 0:
            return float(self.part_err_mm[code])
        if code == SURFACE_BIN:
            return float(self.bin_err_mm)
        if code == SURFACE_TABLE and self.table is not None:
            return float(self.table.residual_mm)
        if code == SURFACE_LOCAL:
            return float(self.local_err_mm)
        return float("nan")


def _check_mesh(v: np.ndarray, t: np.ndarray, what: str) -> None:
    v, t = np.asarray(v), np.asarray(t)
    if v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all():
        raise InputShapeError(f"{what}: vertices must be a finite (n, 3) array, got {describe_array(v)}")
    if t.ndim != 2 or t.shape[1] != 3 or len(t) == 0 or t.min() < 0 or t.max() >= len(v):
        raise InputShapeError(f"{what}: triangles must be (m, 3) indices of its vertices, got {describe_array(t)}")


@dataclass(frozen=True, slots=True)
class Nearest:
    """Every judged pixel's nearest known surface.

    Attributes
    ----------
    dist_mm : (H, W) float32 ndarray
        Distance to the nearest known surface (mm); NaN where not judged (invalid or outside
        ``where``), inf where no surface is known.
    surface : (H, W) int32 ndarray
        Its code: a part instance's index, :data:`SURFACE_BIN`, :data:`SURFACE_TABLE`, or
        :data:`SURFACE_NONE` (not judged, or no surface known).
    """

    dist_mm: np.ndarray
    surface: np.ndarray


def _cloud(xyz_mm: np.ndarray) -> np.ndarray:
    a = np.asarray(xyz_mm)
    if a.ndim != 3 or a.shape[2] != 3 or not np.issubdtype(a.dtype, np.floating):
        raise InputShapeError(f"xyz_mm must be an (H, W, 3) float array, got {describe_array(a)}")
    return a


def nearest_surface(xyz_mm: np.ndarray, surfaces: KnownSurfaces, *, where: np.ndarray | None = None,
                    within_mm: np.ndarray | None = None) -> Nearest:
    """The distance of every valid pixel (in ``where``) to the nearest known surface, and which it is.

    Parameters
    ----------
    xyz_mm : (H, W, 3) float ndarray
        The organized cloud in the camera frame (mm), NaN where invalid.
    surfaces : KnownSurfaces
    where : (H, W) bool ndarray, optional
        The pixels to judge (default: every valid one).
    within_mm : (H, W) float ndarray, optional
        Each pixel's distance to a surface the caller combines with the result afterwards, keeping
        the nearer (:func:`with_local_surface`; NaN: none). Where the bin model's samples are farther
        than it (and than the other surfaces) the bin cannot be the nearest, and the search for them
        stops early: the combined result is the same, this one alone may then say "none" or
        another surface where the bin was nearer.
    """
    a = _cloud(xyz_mm)
    H, W = a.shape[:2]
    valid = np.isfinite(a).all(axis=2)
    if where is not None:
        if np.shape(where) != (H, W):
            raise InputShapeError(f"where must be ({H}, {W}) bool, got {describe_array(where)}")
        valid &= np.asarray(where, bool)
    p = a[valid].astype(np.float64)
    dist = np.full(len(p), np.inf)
    code = np.full(len(p), SURFACE_NONE, np.int32)

    def better(d: np.ndarray, c: np.ndarray | int) -> None:
        b = d < dist
        dist[b] = d[b]
        code[b] = c[b] if isinstance(c, np.ndarray) else c

    meshes = [(v, t, i) for i, (v, t) in enumerate(surfaces.parts)]
    if surfaces.bin_mesh is not None:
        meshes.append((*surfaces.bin_mesh, SURFACE_BIN))
    if len(p) and meshes:
        import open3d as o3d

        scene = o3d.t.geometry.RaycastingScene()
        codes = {}
        for v, t, c in meshes:
            gid = scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(v, np.float32)),  # type: ignore[call-overload]  # Open3D's stub makes dtype and device required
                                      o3d.core.Tensor(np.ascontiguousarray(t, np.uint32)))  # type: ignore[call-overload]  # Open3D's stub makes dtype and device required
            codes[int(gid)] = c
        ans = scene.compute_closest_points(o3d.core.Tensor(p.astype(np.float32)))  # type: ignore[call-overload]  # Open3D's stub makes dtype and device required
        q = ans["points"].numpy().astype(np.float64)
        gids = ans["geometry_ids"].numpy().astype(np.int64)
        lut = np.full(max(codes) + 1, SURFACE_NONE, np.int32)
        for g, c in codes.items():
            lut[g] = c
        ok = (gids >= 0) & (gids < len(lut))
        d = np.where(ok, np.linalg.norm(p - q, axis=1), np.inf)
        better(d, np.where(ok, lut[np.clip(gids, 0, len(lut) - 1)], SURFACE_NONE).astype(np.int32))
    d_table = surfaces.table.distance(p) if len(p) and surfaces.table is not None else None
    if len(p) and surfaces.bin_points is not None and len(surfaces.bin_points[0]):
        # the bin is the nearest only where it is nearer than the meshes and the table
        others = dist if d_table is None else np.minimum(dist, d_table)
        if within_mm is not None:
            w = np.asarray(within_mm, np.float64)
            if w.shape != (H, W):
                raise InputShapeError(f"within_mm must be ({H}, {W}), got {describe_array(w)}")
            w = w[valid]
            others = np.where(w < others, w, others)  # NaN: none
        better(_point_model_distance(p, *surfaces.bin_points, spacing_mm=surfaces.bin_spacing_mm, within=others),
               SURFACE_BIN)
    if d_table is not None:
        better(d_table, SURFACE_TABLE)
    dist_img = np.full((H, W), np.nan, np.float32)
    dist_img[valid] = dist
    code_img = np.full((H, W), SURFACE_NONE, np.int32)
    code_img[valid] = code
    return Nearest(dist_img, code_img)


#: the bin model's nearest-point search is bounded at this many mm (at least 4 × its spacing) first
BIN_SEARCH_MM = 10.0


def _point_model_distance(p: np.ndarray, points: np.ndarray, normals: np.ndarray, *, spacing_mm: float,
                          within: np.ndarray | None = None) -> np.ndarray:
    """Distance of ``p`` (n, 3) to a surface sampled by ``points`` with unit ``normals``: point-to-plane
    to the nearest sample when it lies within 2 × ``spacing_mm``, else the distance to that sample.

    ``within``: each point's distance to the other surfaces; where the surface is farther than that it
    cannot be the nearest and its distance is given as +inf. The search is then bounded at
    max(:data:`BIN_SEARCH_MM`, 4 × spacing) and repeated unbounded only for the points that found no
    sample within the bound and whose ``within`` reaches it: a point of a part high above the bin
    floor costs the unbounded search 30 µs, the bounded one 1.5 µs. Beyond the bound (> 2 × spacing)
    the distance is that to the sample, at least the bound, so the points left at +inf are those the
    unbounded search would give a distance ≥ the bound > ``within``: the nearest surface is the same.
    """
    from scipy.spatial import cKDTree

    pts = np.asarray(points, np.float64)
    tree = cKDTree(pts)
    if within is None:
        e, j = tree.query(p, k=1)
    else:
        bound = max(BIN_SEARCH_MM, 4.0 * float(spacing_mm))
        e, j = tree.query(p, k=1, distance_upper_bound=bound)
        again = ~np.isfinite(e) & ~(np.asarray(within, np.float64) < bound)
        if again.any():
            e[again], j[again] = tree.query(p[again], k=1)
        j = np.where(np.isfinite(e), j, 0)  # no sample within the bound: its distance stays +inf
    m = pts[j]
    n = np.asarray(normals, np.float64)[j]
    plane = np.abs(np.einsum("ij,ij->i", p - m, n))
    out: np.ndarray = np.where(e <= 2.0 * spacing_mm, plane, e)
    return out


def focal_px(xyz_mm: np.ndarray) -> float:
    """The focal length (pixels) of an organized cloud, read off the cloud itself: the median of
    1 / Δ(x / z) between horizontally adjacent valid pixels (NaN when none)."""
    a = _cloud(xyz_mm)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = a[..., 0] / a[..., 2]
        du = np.abs(np.diff(u, axis=1))
    du = du[np.isfinite(du) & (du > 0)]
    return float(1.0 / np.median(du)) if du.size else float("nan")


def footprint_mm(xyz_mm: np.ndarray, f_px: float) -> np.ndarray:
    """(H, W) side of each pixel's footprint at its depth, |z| / f (mm); NaN where invalid."""
    if not (np.isfinite(f_px) and f_px > 0):
        raise ParameterError(f"the focal length must be a positive number of pixels, got {f_px!r}")
    return np.abs(np.asarray(_cloud(xyz_mm)[..., 2], np.float64)) / float(f_px)


def err_image(nearest: Nearest, surfaces: KnownSurfaces, footprint: np.ndarray, *, floor_mm: float = 0.0,
              default_sigma_mm: float = 0.0, where: np.ndarray | None = None) -> np.ndarray:
    """(H, W) Err of each judged pixel: ``max(floor, sqrt(σ_s² + c²/2))``, σ_s the residual of its
    nearest surface (:meth:`KnownSurfaces.sigma`; a surface whose residual is unknown and a pixel no
    surface explains take the largest known one, else ``default_sigma_mm``), c its footprint
    (:func:`footprint_mm`). NaN where not judged, and outside ``where`` (default: everywhere judged;
    the values inside are those of the whole image)."""
    code = nearest.surface
    n = len(surfaces.parts)
    codes = [*range(n), SURFACE_BIN, SURFACE_TABLE, SURFACE_LOCAL]
    known = [s for s in (surfaces.sigma(c) for c in codes) if np.isfinite(s)]
    fallback = max(known) if known else float(default_sigma_mm)
    lut = np.array([fallback if not np.isfinite(surfaces.sigma(c)) else surfaces.sigma(c) for c in codes]
                   + [fallback])  # the last entry: SURFACE_NONE
    if where is not None:
        if np.shape(where) != np.shape(code):
            raise InputShapeError(f"where must be {np.shape(code)} bool, got {describe_array(where)}")
        sel = np.flatnonzero(np.asarray(where, bool).ravel() & ~np.isnan(np.asarray(nearest.dist_mm).ravel()))
        out = np.full(np.shape(code), np.nan)
        c_sel = np.asarray(code).ravel()[sel]
        idx = np.where(c_sel >= 0, c_sel, np.select([c_sel == SURFACE_BIN, c_sel == SURFACE_TABLE,
                                                     c_sel == SURFACE_LOCAL], [n, n + 1, n + 2], n + 3))
        sigma = lut[idx]
        f = np.asarray(footprint, np.float64).ravel()[sel]
        out.ravel()[sel] = np.maximum(float(floor_mm), np.sqrt(sigma * sigma + 0.5 * f * f))
        return out
    idx = np.where(code >= 0, code, np.where(code == SURFACE_BIN, n, np.where(code == SURFACE_TABLE, n + 1,
                                                                              np.where(code == SURFACE_LOCAL, n + 2,
                                                                                       n + 3))))
    sigma = lut[idx]
    c = np.asarray(footprint, np.float64)
    err = np.maximum(float(floor_mm), np.sqrt(sigma * sigma + 0.5 * c * c))
    result: np.ndarray = np.where(np.isnan(nearest.dist_mm), np.nan, err)
    return result


def unexplained(dist: np.ndarray, err: np.ndarray, k: float = K_ERR) -> np.ndarray:
    """(H, W) bool: the judged pixels farther than ``k`` × ``err`` from every known surface
    (``dist`` NaN: not judged, never unexplained; inf: no surface known, always unexplained)."""
    if not (np.isfinite(k) and k > 0):
        raise ParameterError(f"k must be a positive number, got {k!r}")
    d = np.asarray(dist, np.float64)
    e = np.asarray(err, np.float64)
    if d.shape != e.shape:
        raise InputShapeError(f"dist and err must have one shape, got {d.shape} and {e.shape}")
    with np.errstate(invalid="ignore"):
        out: np.ndarray = ~np.isnan(d) & ~(d <= float(k) * e)
    return out


def residual_sigma(dist: np.ndarray, *, gate_mm: float | None = None) -> float:
    """The robust residual σ (mm) of a surface's supporting pixels from their unsigned distances:
    1.4826 × their median (a normal residual's |d| has median 0.6745 σ), over the distances at most
    ``gate_mm`` (outliers left out); NaN when none."""
    d = np.asarray(dist, np.float64)
    d = d[np.isfinite(d)]
    if gate_mm is not None:
        d = d[d <= gate_mm]
    return float(MAD_TO_SIGMA * np.median(d)) if d.size else float("nan")


def surface_sigmas(nearest: Nearest, n_parts: int, footprint: np.ndarray, *, min_pixels: int = 100,
                   gate: float = 3.0) -> tuple[list[float], float, float]:
    """The residual σ of every surface measured on the frame: (parts (n_parts,), bin, table), for
    surfaces whose fit states none (the check with true meshes; the table and bin of the pipeline).

    A surface's σ is :func:`residual_sigma` of the distances of the pixels it explains, gated at
    ``gate`` × the median footprint (outliers left out); one with fewer than ``min_pixels`` such
    pixels (a part barely seen, which would explain only stray points) takes the σ pooled over every
    pixel within the gate. NaN where nothing is known.
    """
    d = nearest.dist_mm
    code = nearest.surface
    c = np.asarray(footprint, np.float64)
    judged = np.isfinite(d)
    g = gate * float(np.nanmedian(c[judged])) if judged.any() else 0.0
    inside = judged & (d <= g)
    pooled = residual_sigma(d[inside])
    counts = np.bincount((code[inside] - SURFACE_BIN).ravel(), minlength=n_parts - SURFACE_BIN)
    order = np.argsort(code[inside], kind="stable")
    ds = d[inside][order]
    bounds = np.concatenate([[0], np.cumsum(counts)])

    def sigma(c_: int) -> float:
        j = c_ - SURFACE_BIN
        if counts[j] < min_pixels:
            return pooled
        return residual_sigma(ds[bounds[j]:bounds[j + 1]])

    return [sigma(i) for i in range(n_parts)], sigma(SURFACE_BIN), sigma(SURFACE_TABLE)


#: a part instance's robust residual is measured on at least this many of the pixels it explains
FIT_SIGMA_MIN_PX = 20
#: the robust residual's gate, in σ (:func:`fit_sigmas`): chosen on the ray-traced and hand-made
#: 1920 × 1200 frames of seed 8531 (zinc nuts, spheres), reported on seed 8541 (docs/labelling.md,
#: "Proposals on shiny parts")
FIT_SIGMA_GATE = 3.0


def fit_sigmas(nearest: Nearest, stated_mm: Sequence[float], *, where: np.ndarray | None = None,
               min_pixels: int = FIT_SIGMA_MIN_PX, gate: float = FIT_SIGMA_GATE) -> list[float]:
    """Each part instance's residual σ (mm) measured robustly on the pixels it is the nearest surface
    of, never above the residual its fit states.

    A fit's stated residual (``PartFit.err_mm``) is the RMS distance of the points it matched: a
    shiny part's interreflection ghosts that stay attached to it (within k × that residual) inflate
    it, and an inflated Err explains a wider band of ghosts around the part. Here σ_i is
    :func:`local_sigma` (1.4826 × the median distance, re-taken over the distances within ``gate`` σ
    three times) of the distances of the pixels in ``where`` (default: every judged one) whose
    nearest surface is instance i, and the instance keeps ``min(σ_i, stated_i)``: the band never
    widens. An instance nearest to fewer than ``min_pixels`` of them keeps its stated residual.

    Parameters
    ----------
    nearest : Nearest
    stated_mm : sequence of float
        The fits' stated residuals, one per instance (the instances' codes are 0, 1, ...).
    where : (H, W) bool ndarray, optional
    """
    d = np.asarray(nearest.dist_mm, np.float64)
    code = np.asarray(nearest.surface)
    sel = (code >= 0) & np.isfinite(d)
    if where is not None:
        if np.shape(where) != d.shape:
            raise InputShapeError(f"where must be {d.shape} bool, got {describe_array(where)}")
        sel &= np.asarray(where, bool)
    n = len(stated_mm)
    out = [float(v) for v in stated_mm]
    c, v = code[sel].astype(np.int64), d[sel]
    if c.size and int(c.max()) >= n:
        raise InputShapeError(f"the nearest surfaces name instance {int(c.max())} but {n} residuals are given")
    order = np.argsort(c, kind="stable")
    c, v = c[order], v[order]
    bounds = np.searchsorted(c, np.arange(n + 1))
    for i in range(n):
        a, b = bounds[i], bounds[i + 1]
        if b - a >= min_pixels:
            s = local_sigma(v[a:b], gate=gate)
            if s < out[i]:
                out[i] = s
    return out


#: :func:`refine_poses`: a fit's pose is refined on the pixels it is the nearest surface of within this many mm
#: (its fringe included: the pixels farther than k × Err from it that no other surface is nearer to)
REFINE_REACH_MM = 3.0
#: ... with this many point-to-plane ICP steps, each point weighted by Tukey's biweight of its distance
REFINE_STEPS = 4
#: ... on at most this many of its pixels (an even subsample); a fit nearest to fewer keeps its pose
REFINE_MAX_POINTS = 500
REFINE_MIN_POINTS = 30
#: ... and the refined pose is kept when it explains at least this share of those points more than the fitted one
REFINE_MIN_GAIN = 0.0
#: ... the biweight's scale going from the reach (first step) toward each point's k × Err (last step) by this share
REFINE_ANNEAL = 1.4
#: ... leaving out the pixels at a depth step: their 8-neighbours' depths span more than this many footprints
#: (:func:`between_steps`; issue 29's second and third tries, docs/accuracy.md: what the refined fits took there was
#: truth, at a 4-footprint step on the second try's report frame)
REFINE_STEP_FOOTPRINTS = 4.0
#: ... refining only the instances whose unexplained points within the reach are at least this share of their points
REFINE_MIN_FRINGE = 0.03
#: (mm) :func:`with_refined_poses` tests the pixels whose nearest surface lies within this only near a refined box
REFINE_SLAB_MM = 5.0


def between_steps(xyz_mm: np.ndarray, margin_mm: np.ndarray, *, step_footprints: float = 10.0,
                  at: np.ndarray | None = None, footprint: np.ndarray | None = None) -> np.ndarray:
    """(H, W) bool: the valid pixels at a depth step — their valid 8-neighbours' depths span more than
    ``step_footprints`` footprints (|z| / f, f read off the cloud: :func:`focal_px`; or ``footprint``, (H, W)) — whose
    own depth lies more than ``margin_mm`` inside that span from both ends: a blend of the two sides, or a strip that
    runs down the step (a mixed pixel, a renderer's curtain), not a point of either side. Reads the cloud only.
    ``at``: flat pixel indices; the same test of those pixels only, (len(at),) bool."""
    a = _cloud(xyz_mm)
    H, W = a.shape[:2]
    m = np.asarray(margin_mm, np.float64)
    if at is not None:
        at = np.asarray(at, np.int64)
        y, x = np.divmod(at, W)
        flat = a.reshape(-1, 3)
        zz = np.where(np.isfinite(flat[at]).all(axis=1), flat[at, 2].astype(np.float64), np.nan)
        fp = (np.abs(zz) / focal_px(a) if footprint is None
              else np.asarray(footprint, np.float64).ravel()[at])
        mm = m.ravel()[at] if m.ndim else m
        lo = np.full(at.size, np.inf)
        hi = np.full(at.size, -np.inf)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dy or dx:
                    yy, xx = y + dy, x + dx
                    inside = (yy >= 0) & (yy < H) & (xx >= 0) & (xx < W)
                    j = np.where(inside, yy * W + xx, 0)
                    pn = flat[j]
                    nb = np.where(inside & np.isfinite(pn).all(axis=1), pn[:, 2].astype(np.float64), np.nan)
                    lo = np.fmin(lo, nb)
                    hi = np.fmax(hi, nb)
        with np.errstate(invalid="ignore"):
            sub: np.ndarray = ((hi - lo > step_footprints * fp) & (zz - lo > mm) & (hi - zz > mm))
        return sub
    z = np.where(np.isfinite(a).all(axis=2), a[..., 2].astype(np.float64), np.nan)
    f = focal_px(a)
    fpi = np.abs(z) / f if footprint is None else np.asarray(footprint, np.float64)
    pad = np.pad(z, 1, constant_values=np.nan)
    lo2 = np.full((H, W), np.inf)
    hi2 = np.full((H, W), -np.inf)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                nb2 = pad[1 + dy:1 + dy + H, 1 + dx:1 + dx + W]
                lo2 = np.fmin(lo2, nb2)
                hi2 = np.fmax(hi2, nb2)
    with np.errstate(invalid="ignore"):
        out: np.ndarray = ((hi2 - lo2 > step_footprints * fpi) & (z - lo2 > m) & (hi2 - z > m))
    return out


def refine_poses(xyz_mm: np.ndarray, nearest: Nearest, poses: Sequence[np.ndarray], mesh: tuple[np.ndarray, np.ndarray],
                 err: np.ndarray, *, k: float = K_ERR, reach_mm: float | None = None, steps: int | None = None,
                 max_points: int | None = None, min_points: int | None = None,
                 min_gain: float | None = None, min_fringe: float | None = None,
                 footprint: np.ndarray | None = None) -> list[np.ndarray]:
    """Each fitted instance's pose refined on the pixels it is the nearest surface of, its fringe included.

    A fit's own search matches the points within k × its Err (a trimmed ICP): a pose off by a turn about a face's
    normal or a slide along it keeps the face's points within the band and leaves the points of the faces beside it
    — the part's fringe, at its depth edges — outside, where nothing pulls it back. Here instance i's points are the
    valid pixels whose nearest known surface it is, within ``reach_mm`` (``nearest``), an even subsample of at most
    ``max_points``; ``steps`` point-to-plane steps (Gauss-Newton on the closest points of the part's ``mesh``, each
    point weighted by Tukey's biweight of its distance at a scale going from ``reach_mm`` toward its k × Err) move the
    pose, which is kept only when more of those pixels lie within ``k`` × their ``err`` of the refined mesh than of the
    fitted one. The pixels at a depth step (their 8-neighbours' depths span more than ``REFINE_STEP_FOOTPRINTS``
    footprints: ``footprint``, else read off the cloud) neither pull nor count: a fit slid onto a blend or a renderer's
    curtain down the step explains what lies off every surface. ``min_fringe``: an instance whose unexplained points
    within the reach are fewer than this share of its points keeps its pose. Pure: reads the cloud, the fits and the
    distances; the truth never.

    Parameters
    ----------
    xyz_mm : (H, W, 3) float ndarray
    nearest : Nearest
        Every judged pixel's nearest known surface with the fits posed at ``poses`` (instance i has code i).
    poses : sequence of (4, 4) float ndarray
        Model (mm) -> camera (mm).
    mesh : (vertices (n, 3), triangles (m, 3))
        The part's mesh in its own frame (mm).
    err : (H, W) float ndarray
        Each pixel's Err (:func:`err_image`).

    Returns
    -------
    list of (4, 4) float64 ndarray
        The poses, refined where that explains more of the instance's pixels, else as given.
    """
    reach_mm = REFINE_REACH_MM if reach_mm is None else float(reach_mm)
    steps = REFINE_STEPS if steps is None else int(steps)
    max_points = REFINE_MAX_POINTS if max_points is None else int(max_points)
    min_points = REFINE_MIN_POINTS if min_points is None else int(min_points)
    min_gain = REFINE_MIN_GAIN if min_gain is None else float(min_gain)
    min_fringe = REFINE_MIN_FRINGE if min_fringe is None else float(min_fringe)
    a = _cloud(xyz_mm)
    out = [np.asarray(T, np.float64).copy() for T in poses]
    n = len(out)
    code = np.asarray(nearest.surface).ravel()
    d = np.asarray(nearest.dist_mm, np.float64).ravel()
    e = np.asarray(err, np.float64).ravel()
    if not n or steps < 1:
        return out
    with np.errstate(invalid="ignore"):
        sel = np.flatnonzero((code >= 0) & (code < n) & (d <= reach_mm) & np.isfinite(e))
    if sel.size:
        sel = sel[~between_steps(a, np.float64(-np.inf), at=sel, step_footprints=REFINE_STEP_FOOTPRINTS,
                                 footprint=footprint)]
    sel = sel[np.argsort(code[sel], kind="stable")]
    bounds = np.searchsorted(code[sel], np.arange(n + 1))
    if min_fringe > 0:
        fringe = np.bincount(code[sel], weights=d[sel] > float(k) * e[sel], minlength=n)
    # each instance's points: an even subsample of at most max_points, the instances with fewer than min_points left out
    take, group = [], []
    for i in range(n):
        c = int(bounds[i + 1] - bounds[i])
        if c < min_points or (min_fringe > 0 and fringe[i] < min_fringe * c):
            continue
        j = np.arange(c) if c <= max_points else np.linspace(0, c - 1, max_points).astype(np.int64)
        take.append(sel[bounds[i] + j])
        group.append(np.full(j.size, i))
    if not take:
        return out
    idx, g = np.concatenate(take), np.concatenate(group)
    ids, start = np.unique(g, return_index=True)  # g is sorted: the instances refined and where each begins
    gi = np.searchsorted(ids, g)
    p = a.reshape(-1, 3)[idx].astype(np.float64)
    tol = float(k) * e[idx]
    T0 = np.stack([out[i] for i in ids])
    q0 = np.einsum("nj,njk->nk", p - T0[gi, :3, 3], T0[gi, :3, :3])  # in the part's frame: R^T (p - t)
    import open3d as o3d

    v, t = (np.asarray(x) for x in mesh)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(v, np.float32)),  # type: ignore[call-overload]  # Open3D's stub makes dtype and device required
                        o3d.core.Tensor(np.ascontiguousarray(t, np.uint32)))  # type: ignore[call-overload]  # Open3D's stub makes dtype and device required

    def closest(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ans = scene.compute_closest_points(o3d.core.Tensor(np.ascontiguousarray(q, np.float32)))  # type: ignore[call-overload]  # Open3D's stub makes dtype and device required
        return ans["points"].numpy().astype(np.float64), ans["primitive_normals"].numpy().astype(np.float64)

    m = len(ids)
    c0, n0 = closest(q0)
    d0 = np.linalg.norm(q0 - c0, axis=1)
    before = np.bincount(gi, weights=d0 <= tol, minlength=m)
    Rm = np.repeat(np.eye(3)[None], m, axis=0)  # D_i: q -> Rm q + tm, the motion that brings the points onto the mesh
    tm = np.zeros((m, 3))
    for step in range(int(steps)):
        # the biweight's scale shrinks from the reach to each point's k x Err: the fringe moves the pose out of a
        # trimmed fit's minimum, the last steps fit the band as the fit did
        f = REFINE_ANNEAL * step / max(int(steps) - 1, 1)
        scale = reach_mm ** (1.0 - f) * np.maximum(tol, 1e-6) ** f
        q = np.einsum("njk,nk->nj", Rm[gi], q0) + tm[gi]
        c, nrm = (c0, n0) if step == 0 else closest(q)
        r = np.einsum("ij,ij->i", q - c, nrm)
        dist = np.linalg.norm(q - c, axis=1)
        w = np.where(dist < scale, (1.0 - (dist / scale) ** 2) ** 2, 0.0)
        J = np.hstack([np.cross(q, nrm), nrm])
        A = np.add.reduceat(np.einsum("ni,nj->nij", J * w[:, None], J), start, axis=0) + 1e-9 * np.eye(6)
        b = np.add.reduceat(-(J * (w * r)[:, None]), start, axis=0)
        x = np.linalg.solve(A, b[..., None])[..., 0]
        th = np.linalg.norm(x[:, :3], axis=1)
        kx = x[:, :3] / np.where(th > 0, th, 1.0)[:, None]
        K = np.zeros((m, 3, 3))
        K[:, 0, 1], K[:, 0, 2], K[:, 1, 0] = -kx[:, 2], kx[:, 1], kx[:, 2]
        K[:, 1, 2], K[:, 2, 0], K[:, 2, 1] = -kx[:, 0], -kx[:, 1], kx[:, 0]
        dR = np.eye(3) + np.sin(th)[:, None, None] * K + (1.0 - np.cos(th))[:, None, None] * (K @ K)
        Rm, tm = dR @ Rm, np.einsum("mjk,mk->mj", dR, tm) + x[:, 3:]
    q = np.einsum("njk,nk->nj", Rm[gi], q0) + tm[gi]
    c, _ = closest(q)
    now = np.linalg.norm(q - c, axis=1) <= tol
    after = np.bincount(gi, weights=now, minlength=m)
    count = np.bincount(gi, minlength=m)
    for j, i in enumerate(ids.tolist()):
        if after[j] > before[j] and after[j] - before[j] >= min_gain * count[j]:  # p = T q0 and D q0 lies on the mesh: the refined pose is T D^-1
            Dinv = np.eye(4)
            Dinv[:3, :3] = Rm[j].T
            Dinv[:3, 3] = -Rm[j].T @ tm[j]
            out[i] = out[i] @ Dinv
    return out


def with_refined_poses(xyz_mm: np.ndarray, nearest: Nearest, surfaces: KnownSurfaces, poses: Sequence[np.ndarray],
                       mesh: tuple[np.ndarray, np.ndarray], stated_mm: Sequence[float], footprint: np.ndarray, *,
                       k: float = K_ERR, floor_mm: float = 0.0, zone: np.ndarray | None = None
                       ) -> tuple[list[np.ndarray], KnownSurfaces, Nearest]:
    """(poses, surfaces, nearest) with every fit's pose refined on its pixels, its fringe included (:func:`refine_poses`,
    on the Err :func:`err_image` gives ``nearest`` and ``surfaces``): the refined instances posed in ``surfaces``, the
    judged pixels' nearest surface searched again where a refined instance was or may now be the nearest (the result of
    a full search with the refined poses, :func:`nearest_surface`), and every instance's residual measured again from
    the residuals the fits state (``stated_mm``; :func:`fit_sigmas` over ``zone``). Unchanged when no pose moves.

    Parameters
    ----------
    xyz_mm : (H, W, 3) float ndarray
    nearest : Nearest
        The judged pixels' nearest surfaces with the fits at ``poses`` (instance i is ``surfaces.parts[i]``).
    surfaces : KnownSurfaces
    poses : sequence of (4, 4) float ndarray
    mesh : (vertices (n, 3), triangles (m, 3))
        The part's mesh in its own frame (mm): instance i is ``vertices @ R_i.T + t_i``.
    stated_mm : sequence of float
        The residuals the fits state (``PartFit.err_mm``).
    footprint : (H, W) float ndarray
        :func:`footprint_mm`.
    """
    err = err_image(nearest, surfaces, footprint, floor_mm=floor_mm)
    new = refine_poses(xyz_mm, nearest, poses, mesh, err, k=k, footprint=footprint)
    moved = [i for i, (a, b) in enumerate(zip(new, poses)) if not np.array_equal(a, np.asarray(b, np.float64))]
    if not moved:
        return [np.asarray(T, np.float64) for T in poses], surfaces, nearest
    v, t = (np.asarray(x) for x in mesh)
    posed = [(v @ new[i][:3, :3].T + new[i][:3, 3], t) for i in moved]
    parts = list(surfaces.parts)
    for i, m in zip(moved, posed):
        parts[i] = m
    surfaces = dataclasses.replace(surfaces, parts=parts)
    a = _cloud(xyz_mm)
    H, W = a.shape[:2]
    d = np.asarray(nearest.dist_mm, np.float64)
    code = np.asarray(nearest.surface)
    judged = ~np.isnan(d)
    was = np.zeros(len(poses) + 1, bool)
    was[moved] = True
    mine = judged & was[np.where((code >= 0) & (code < len(poses)), code, len(poses))]
    # a pixel of another surface may now be nearer to a refined instance only when it is nearer to its box
    pts = a.reshape(-1, 3)
    cand = np.flatnonzero((judged & ~mine).ravel())
    hit = np.zeros(cand.size, bool)
    dc = d.ravel()[cand]
    # the pixels whose surface lies within REFINE_SLAB_MM are tested only in the instance's slab along x widened by
    # that much (outside it the box lies farther than their surface along x alone: the same answer); the others, all
    qc = pts[cand]
    near_ = dc <= REFINE_SLAB_MM
    far = np.flatnonzero(~near_)
    close = np.flatnonzero(near_)
    close = close[np.argsort(qc[close, 0], kind="stable")]
    xs = qc[close, 0]
    widen = REFINE_SLAB_MM * (1.0 + 1e-6)
    for pv, _ in posed:
        lo, hi = pv.min(axis=0), pv.max(axis=0)
        i0, i1 = np.searchsorted(xs, [lo[0] - widen, hi[0] + widen], side="left")
        for ix in (far, close[i0:i1]):
            q = qc[ix]
            gap = np.linalg.norm(np.maximum(0.0, np.maximum(lo - q, q - hi)), axis=1)
            hit[ix] |= ~(gap >= dc[ix])
    others = np.zeros(H * W, bool)
    others[cand[hit]] = True
    lut = np.asarray(moved, np.int32)
    dist, surf = d.astype(np.float32).copy(), code.astype(np.int32).copy()
    # the refined instances' distances of both sets; a pixel of a refined instance that is no nearer to them than it was
    # to its own before may be nearest to any surface: searched again among every one
    look = (mine | others.reshape(H, W))
    got = nearest_surface(a, KnownSurfaces(parts=posed, part_err_mm=[0.0] * len(posed)), where=look)
    gd = np.asarray(got.dist_mm, np.float64)
    gc = np.where(got.surface >= 0, lut[np.maximum(got.surface, 0)], SURFACE_NONE)
    with np.errstate(invalid="ignore"):
        closer = others.reshape(H, W) & (gd < d)
        keep_own = mine & (gd <= d)
    dist[closer | keep_own] = gd[closer | keep_own]
    surf[closer | keep_own] = gc[closer | keep_own]
    again = mine & ~keep_own
    if again.any():
        full = nearest_surface(a, surfaces, where=again)
        dist[again] = full.dist_mm[again]
        surf[again] = full.surface[again]
    near = Nearest(dist, surf)
    surfaces = dataclasses.replace(surfaces, part_err_mm=fit_sigmas(near, stated_mm, where=zone))
    return new, surfaces, near


def local_surface_distance(xyz_mm: np.ndarray, valid: np.ndarray, *, where: np.ndarray | None = None,
                           params: EdgeSurfaceParams | None = None) -> np.ndarray:
    """(H, W) distance (mm) of the pixels in ``where`` (default: every valid one) to the edge-aware
    local surface (:func:`zcut.edge_surface.edge_surfaces`: planes fitted on each side of an edge to the
    ``valid`` pixels, a pixel judged by the patches that do not hold it); NaN where not judged, inf
    where no surface lies within the search radius."""
    from .edge_surface import edge_surfaces

    out: np.ndarray = np.abs(edge_surfaces(np.asarray(xyz_mm, np.float64), valid, params=params).distance(where))
    return out


def local_surface_params(footprint: np.ndarray, where: np.ndarray) -> EdgeSurfaceParams:
    """The edge-aware surface's parameters for ``explained``: the page's defaults
    (:class:`zcut.edge_surface.EdgeSurfaceParams`) with ``min_fit_mm`` at least
    :data:`LOCAL_FIT_FOOTPRINTS` × the median footprint (mm) of the pixels in ``where``.

    The frame's own gate (3 × its median patch residual) is far below Err on a frame whose flat
    surfaces are almost noise-free: a curved part a few pixels across then has no patch that is a
    surface, and its pixels would be judged against the bin. Err allows ~0.7 footprints, so a patch
    that fits its points within 0.1 footprint still explains them. (Chosen on synthetic frames of
    seeds 9901-9914 at 640 × 400 and 9905 at 320 × 200: mean IoU with the paper's truth 0.261 → 0.267
    at 640 × 400, 0.006 → 0.088 on the 320 × 200 spheres.)
    """
    from .edge_surface import EdgeSurfaceParams

    c = np.asarray(footprint, np.float64)[np.asarray(where, bool)]
    c = c[np.isfinite(c)]
    base = EdgeSurfaceParams()
    if not c.size:
        return base
    return EdgeSurfaceParams(min_fit_mm=max(base.min_fit_mm, LOCAL_FIT_FOOTPRINTS * float(np.median(c))))


def with_local_surface(nearest: Nearest, local_mm: np.ndarray) -> Nearest:
    """``nearest`` with the local surface (:data:`SURFACE_LOCAL`) where its distance ``local_mm`` (NaN:
    not judged) is smaller than the known surfaces' (a tie keeps the known surface). The pixels
    ``nearest`` does not judge stay unjudged."""
    d = np.asarray(nearest.dist_mm)
    loc = np.asarray(local_mm, np.float64)
    if loc.shape != d.shape:
        raise InputShapeError(f"local_mm must have the distances' shape {d.shape}, got {describe_array(loc)}")
    with np.errstate(invalid="ignore"):
        closer = ~np.isnan(d) & (loc < d)
    dist = np.where(closer, loc, d).astype(np.float32)
    code = np.where(closer, np.int32(SURFACE_LOCAL), nearest.surface).astype(np.int32)
    return Nearest(dist, code)


def local_sigma(dist: np.ndarray, *, gate: float = 5.0, iterations: int = 3) -> float:
    """The robust residual σ (mm) of the local surface from the distances of the pixels it explains.

    :func:`residual_sigma` (1.4826 × the median |d|) of every finite distance, then again over those
    within ``gate`` × the last σ, ``iterations`` times: the points off every surface (up to half of
    them) inflate only the first median, and a normal residual's median moves by less than 0.1 %
    when it is cut at 5 σ. NaN when there is no finite distance.
    """
    if not (np.isfinite(gate) and gate > 0):
        raise ParameterError(f"gate must be a positive number, got {gate!r}")
    d = np.abs(np.asarray(dist, np.float64))
    d = d[np.isfinite(d)]
    sigma = residual_sigma(d)
    for _ in range(max(0, int(iterations))):
        if not sigma > 0:
            break
        sigma = residual_sigma(d, gate_mm=gate * sigma)
    return sigma


def fit_plane(points: np.ndarray, *, iterations: int = 3, gate_sigmas: float = 3.0) -> Plane:
    """The least-squares plane of ``points`` (n ≥ 3, mm), refitted ``iterations`` times to the points
    within ``gate_sigmas`` robust σ of the last fit; its residual is that robust σ (:func:`residual_sigma`).

    Raises
    ------
    InputShapeError
        Fewer than 3 finite points.
    """
    p = np.asarray(points, np.float64).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1)]
    if len(p) < 3:
        raise InputShapeError(f"a plane needs at least 3 points, got {len(p)}")
    keep = np.ones(len(p), bool)
    n, off, sigma = np.array([0.0, 0.0, 1.0]), 0.0, float("nan")
    for _ in range(max(1, iterations)):
        q = p[keep] if keep.sum() >= 3 else p
        c = q.mean(axis=0)
        _, _, vt = np.linalg.svd(q - c, full_matrices=False)
        n = vt[-1] / np.linalg.norm(vt[-1])
        if n[2] < 0:
            n = -n
        off = float(n @ c)
        d = np.abs(p @ n - off)
        sigma = residual_sigma(d)
        keep = d <= gate_sigmas * max(sigma, 1e-9)
    return Plane(n, off, sigma)


__all__ = [
    "K_ERR",
    "SURFACE_BIN",
    "SURFACE_LOCAL",
    "SURFACE_NONE",
    "SURFACE_TABLE",
    "KnownSurfaces",
    "Nearest",
    "Plane",
    "err_image",
    "FIT_SIGMA_GATE",
    "FIT_SIGMA_MIN_PX",
    "fit_plane",
    "fit_sigmas",
    "focal_px",
    "footprint_mm",
    "LOCAL_FIT_FOOTPRINTS",
    "local_sigma",
    "local_surface_params",
    "local_surface_distance",
    "nearest_surface",
    "refine_poses",
    "residual_sigma",
    "surface_sigmas",
    "unexplained",
    "with_local_surface",
    "with_refined_poses",
]
