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
    "residual_sigma",
    "surface_sigmas",
    "unexplained",
    "with_local_surface",
]
