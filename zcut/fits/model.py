"""The part model prepared for fitting: checked, classified (sphere or general), sampled.

A mesh whose vertices and faces' centres all lie at one radius from their centroid (within
``sphere_tolerance`` of it; a box's corners alone do) is a **sphere**: its instances are fitted in closed
form (:mod:`zcut.fits.sphere`). Any other mesh is fitted by initial guesses and ICP (:mod:`zcut.fits.icp`)
against area-weighted samples of its surface (points with their face normals) and the exact
point-to-triangle distances of an Open3D ``RaycastingScene`` built once on the mesh in its own frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Any

import numba
import numpy as np

from zcut.errors import InputShapeError, ParameterError, describe_array
from zcut.fit_vetting import Solid
from zcut.ray_hits import mesh_hit_t

from .kernels import ModelIndex, build_index

__all__ = ["PartModel", "cube_root", "prepare_model", "projected_area_px"]


@dataclass(frozen=True, slots=True, eq=False)
class PartModel:
    """A checked part mesh (model frame, mm) and what the fits need of it.

    Attributes
    ----------
    vertices, triangles : (n, 3) float64, (m, 3) int64 ndarray
    centroid : (3,) float64 ndarray
        Area-weighted centroid of the surface.
    sphere_radius : float or None
        The radius when the mesh is a sphere (centred on ``centroid``), else None.
    samples, normals : (s, 3) float64 ndarray
        Points on the surface (area-weighted, deterministic) and their outward face normals.
    axes : (3, 3) float64 ndarray
        Principal axes of the surface samples (columns, descending variance, right-handed).
    extent_mm : float
        Largest distance of a vertex from the centroid.
    symmetries : (k, 3, 3) float64 ndarray
        Rotations about the centroid that map the surface onto itself (identity first), found
        among a fixed set of candidates (:func:`_symmetries`); ``continuous_axis`` when the surface
        is a body of revolution.
    continuous_axis : (3,) float64 ndarray or None
    edges : (e, 3) float64 ndarray
        Points along the mesh's sharp edges (faces meeting at more than 30°, or open edges): where
        the part's silhouette lies, matched by the occluding boundary of a region in the ICP.
    index : ModelIndex or None
        The voxel index the ICP and the guesses' scores match points through
        (:mod:`zcut.fits.kernels`), built once here; None for a sphere.
    guesses : (g, 3, 3) float64 ndarray
        The initial rotations up to the region's principal axes (:func:`zcut.fits.icp.initial_rotations`
        returns ``axes_of_the_region @ guesses[i]``), those equivalent under the symmetries dropped:
        computed once per model.
    front_probe : (p, 3), (p, 3) float64 ndarrays
        An even subsample of ``samples`` and ``normals`` for the initial translations.
    solid : zcut.fit_vetting.Solid
        The inside of the mesh (:func:`zcut.fit_vetting.solid_of`: points drawn inside it and its
        occupancy grid, a ball's closed form), the one the vetting of the fits measures overlaps on: two
        fits whose solids share more than :attr:`FitParams.max_overlap <zcut.fits.FitParams>` of either's
        volume are not both accepted (:func:`zcut.fit_vetting.pose_overlaps`). ``inside``,
        ``occupancy`` and :meth:`contains` are its.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    centroid: np.ndarray
    sphere_radius: float | None
    samples: np.ndarray
    normals: np.ndarray
    axes: np.ndarray
    extent_mm: float
    symmetries: np.ndarray
    continuous_axis: np.ndarray | None
    edges: np.ndarray
    index: ModelIndex | None
    guesses: np.ndarray
    probe_samples: np.ndarray
    probe_normals: np.ndarray
    solid: Solid
    _scene: Any = field(repr=False)
    _tree: Any = field(repr=False)
    _edge_tree: Any = field(repr=False)

    def distance(self, points_model: np.ndarray) -> np.ndarray:
        """Exact distance (mm) of each of ``points_model`` (n, 3), model frame, to the surface."""
        p = np.asarray(points_model, np.float64).reshape(-1, 3)
        if len(p) == 0:
            return np.zeros(0)
        if self.sphere_radius is not None:
            return np.abs(np.linalg.norm(p - self.centroid, axis=1) - self.sphere_radius)
        import open3d as o3d

        d: np.ndarray = self._scene.compute_distance(o3d.core.Tensor(p.astype(np.float32))).numpy()  # type: ignore[call-overload]  # Open3D's stub makes dtype and device required
        return d.astype(np.float64)

    def ray_depths(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Distance along each ray (model frame, unit directions) to the first hit of the surface,
        inf where none (a sphere: the closed form).

        Open3D's ray casting (Embree) says which rays hit and which triangle; the distance is Möller–Trumbore's in
        float64 on that triangle (:func:`zcut.ray_hits.mesh_hit_t`), not Embree's float32 ``t_hit``, whose last bits
        differ between CPUs (docs/fits.md, "The fits' ray casts exact")."""
        if self.sphere_radius is not None:
            oc = origins - self.centroid
            b = np.einsum("ij,ij->i", oc, directions)
            disc = b * b - (np.einsum("ij,ij->i", oc, oc) - self.sphere_radius ** 2)
            with np.errstate(invalid="ignore"):
                hit = -b - np.sqrt(disc)
            return np.where((disc >= 0) & (hit > 0), hit, np.inf)
        import open3d as o3d

        out = np.full(len(origins), np.inf)
        hits = _box_hits(origins, directions, self.vertices.min(axis=0), self.vertices.max(axis=0))
        if not hits.any():
            return out
        o = np.ascontiguousarray(origins[hits], np.float64)
        d = np.ascontiguousarray(directions[hits], np.float64)
        rays = np.concatenate([o, d], axis=1).astype(np.float32)
        res = self._scene.cast_rays(o3d.core.Tensor(rays))  # type: ignore[call-overload]  # Open3D's stub makes dtype and device required
        t = np.empty(len(o))
        mesh_hit_t(res["t_hit"].numpy(), res["primitive_ids"].numpy(), o, d, self.vertices, self.triangles, t)
        out[hits] = t
        return out

    @property
    def inside(self) -> np.ndarray:
        """(q, 3) points drawn uniformly inside the solid (:attr:`solid`), none when the mesh is not closed."""
        return self.solid.inside

    @property
    def occupancy(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The solid's occupancy grid (:attr:`zcut.fit_vetting.Solid.occupancy`)."""
        return self.solid.occupancy

    def contains(self, points_model: np.ndarray) -> np.ndarray:
        """(n,) bool: whether each of ``points_model`` (model frame) lies inside the solid
        (:meth:`zcut.fit_vetting.Solid.contains`: a sphere in closed form, else at the occupancy grid's
        resolution, a 64th of the box)."""
        return self.solid.contains(points_model)

    def nearest_edges(self, points_model: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distance, index into ``edges``) of the nearest edge point of each point (model frame)."""
        if self._edge_tree is None:
            n = len(points_model)
            return np.full(n, np.inf), np.zeros(n, np.int64)
        d, i = self._edge_tree.query(points_model, k=1)
        return np.asarray(d, np.float64), np.asarray(i, np.int64)

    def nearest_samples(self, points_model: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distance, index) of the nearest surface sample of each point (model frame)."""
        d, i = self._tree.query(points_model, k=1)
        return np.asarray(d, np.float64), np.asarray(i, np.int64)


def projected_area_px(model: PartModel, z_mm: np.ndarray | float, f_px: float) -> np.ndarray:
    """π (extent · f / z)²: the pixels a whole instance of ``model`` at depth ``z_mm`` covers at most (``extent`` the
    model's largest distance of a vertex from its centroid, ``f_px`` the focal length in pixels). The fits' second pass
    reads it (:mod:`zcut.fits.params` ``seed_min_share``), and so does the sliver pass's size floor
    (:mod:`zcut.sliver_fits`, ``SliverParams.min_area_share``): one definition."""
    r = float(model.extent_mm) * float(f_px) / np.maximum(np.asarray(z_mm, np.float64), 1e-6)
    return np.asarray(np.pi * r * r)


def _box_hits(origins: np.ndarray, directions: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Whether each ray may meet the box [lo, hi] grown by 0.01 mm (the slab test; a ray that misses it
    misses every triangle inside it, also in the float32 of the ray casts): :func:`_box_hits_kernel`."""
    return _box_hits_kernel(np.ascontiguousarray(origins, np.float64), np.ascontiguousarray(directions, np.float64),
                            np.asarray(lo, np.float64) - 0.01, np.asarray(hi, np.float64) + 0.01)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _box_hits_kernel(origins: np.ndarray, directions: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The slab test per ray in IEEE arithmetic (1 / 0 = inf; a ray parallel to a slab starting on its
    plane gives NaN there and leaves that slab free): :func:`_box_hits_reference`'s answers."""
    out = np.empty(len(origins), np.bool_)
    for i in range(len(origins)):
        near = -np.inf
        far = np.inf
        for a in range(3):
            inv = 1.0 / directions[i, a]
            t0 = (lo[a] - origins[i, a]) * inv
            t1 = (hi[a] - origins[i, a]) * inv
            if np.isnan(t0) or np.isnan(t1):
                continue
            near = max(near, min(t0, t1))
            far = min(far, max(t0, t1))
        out[i] = far >= max(near, 0.0)
    return out


def _box_hits_reference(origins: np.ndarray, directions: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The slab test in NumPy (the oracle of :func:`_box_hits_kernel`): whether each ray may meet the box [lo, hi] grown by 0.01 mm (the slab test; a ray that misses it
    misses every triangle inside it, also in the float32 of the ray casts)."""
    lo = lo - 0.01
    hi = hi + 0.01
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / directions
        t0 = (lo - origins) * inv
        t1 = (hi - origins) * inv
    free = np.isnan(t0) | np.isnan(t1)  # a ray parallel to a slab starting on its plane
    tmin = np.where(free, -np.inf, np.minimum(t0, t1))
    tmax = np.where(free, np.inf, np.maximum(t0, t1))
    near = tmin.max(axis=1)
    far = tmax.min(axis=1)
    return np.asarray((far >= np.maximum(near, 0.0)), bool)


def _check_mesh(vertices: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices)
    t = np.asarray(triangles)
    if v.ndim != 2 or v.shape[1] != 3 or not np.issubdtype(v.dtype, np.number):
        raise InputShapeError(f"vertices_mm must be (n, 3) numbers, got {describe_array(v)}")
    if t.ndim != 2 or t.shape[1] != 3 or not np.issubdtype(t.dtype, np.integer):
        raise InputShapeError(f"triangles must be (m, 3) integers, got {describe_array(t)}")
    v = v.astype(np.float64)
    t = t.astype(np.int64)
    if len(v) < 4 or len(t) < 4:
        raise ParameterError(f"part model is degenerate: {len(v)} vertices and {len(t)} triangles (need at least 4 of each)")
    if not np.isfinite(v).all():
        raise ParameterError("part model is degenerate: a vertex is not finite")
    if t.min() < 0 or t.max() >= len(v):
        raise ParameterError(f"part model is degenerate: a triangle index is outside 0..{len(v) - 1}")
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    scale = float(np.ptp(v, axis=0).max())
    if not scale > 0 or area.sum() <= 1e-9 * scale * scale:
        raise ParameterError("part model is degenerate: its triangles have no area")
    sv = np.linalg.svd(v - v.mean(axis=0), compute_uv=False)
    if sv[2] <= 1e-6 * sv[0]:
        raise ParameterError("part model is degenerate: its vertices are flat (all in one plane)")
    return v, t


def _sample_surface(v: np.ndarray, t: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Area-weighted deterministic samples (points, unit normals) and the area-weighted centroid."""
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    cr = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(cr, axis=1)
    keep = area > 0
    a, b, c, cr, area = a[keep], b[keep], c[keep], cr[keep], area[keep]
    centroid = ((a + b + c) / 3.0 * area[:, None]).sum(axis=0) / area.sum()
    nrm = cr / (2.0 * area[:, None])
    rng = np.random.default_rng(0)
    face = rng.choice(len(area), size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    u, w = 1 - s, s * (1 - r2)
    pts = u[:, None] * a[face] + w[:, None] * b[face] + (s * r2)[:, None] * c[face]
    normals = nrm[face]
    # orient outward where the mesh's winding is inconsistent: away from the centroid on average
    out = np.einsum("ij,ij->i", normals, pts - centroid)
    if (out < 0).mean() > 0.5:
        normals = -normals
    return pts, normals, centroid


def _sharp_edges(v: np.ndarray, t: np.ndarray, spacing: float,
                 angle_deg: float = 30.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points every ``spacing`` along the edges where faces meet at more than ``angle_deg`` (or
    which only one face has), the edges' first ends, their second ends)."""
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    cr = np.cross(b - a, c - a)
    nrm = cr / np.maximum(np.linalg.norm(cr, axis=1, keepdims=True), 1e-300)
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    face = np.tile(np.arange(len(t)), 3)
    key = np.sort(e, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    key, face = key[order], face[order]
    same = np.all(key[1:] == key[:-1], axis=1)
    sharp: list[np.ndarray] = []
    i = 0
    n = len(key)
    cos_thr = np.cos(np.radians(angle_deg))
    while i < n:
        j = i + 1
        while j < n and same[j - 1]:
            j += 1
        fs = face[i:j]
        if j - i == 1 or np.min(nrm[fs] @ nrm[fs].T) < cos_thr:
            sharp.append(key[i])
        i = j
    if not sharp:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3))
    E = np.array(sharp)
    p0, p1 = v[E[:, 0]], v[E[:, 1]]
    L = np.linalg.norm(p1 - p0, axis=1)
    pts = []
    for k in range(len(E)):
        m = max(2, int(np.ceil(L[k] / spacing)) + 1)
        s = np.linspace(0.0, 1.0, m)[:, None]
        pts.append(p0[k] + s * (p1[k] - p0[k]))
    out: np.ndarray = np.unique(np.round(np.concatenate(pts), 9), axis=0)
    return out, p0, p1


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R: np.ndarray = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * (K @ K)
    return R


def _maps_onto_itself(R: np.ndarray, samples: np.ndarray, centroid: np.ndarray, tree: Any, tol: float) -> bool:
    q = (samples - centroid) @ R.T + centroid
    d, _ = tree.query(q, k=1)
    return bool(np.percentile(d, 95) <= tol)


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation R minimising Σ |R a_i − b_i|² (both centred already)."""
    U, _, Vt = np.linalg.svd(b.T @ a)
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)))])
    R: np.ndarray = U @ D @ Vt
    return R


def _refine_symmetry(R: np.ndarray, points: np.ndarray, centroid: np.ndarray, tree: Any,
                     targets: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Refine an approximate symmetry rotation by nearest-point Kabsch steps taking ``points`` to
    ``targets`` (the points ``tree`` holds; default ``points``: the vertices, which a symmetric mesh
    maps onto vertices); (R, RMS nearest distance)."""
    targets = points if targets is None else targets
    a = points - centroid
    for _ in range(8):
        _, i = tree.query(a @ R.T + centroid, k=1)
        R = _kabsch(a, targets[i] - centroid)
    d, _ = tree.query(a @ R.T + centroid, k=1)
    return R, float(np.sqrt(np.mean(d * d)))


#: Two symmetries of a part (at most 12-fold about an axis: 30° apart at least) lie farther apart than this (degrees).
MERGE_DEG = 10.0


def _angle_deg(R: np.ndarray) -> float:
    """The angle of the rotation ``R`` in degrees (the C library's ``acos``, not NumPy's SIMD kernel: see
    :func:`cube_root`)."""
    return math.degrees(math.acos(min(max((float(np.trace(R)) - 1.0) / 2.0, -1.0), 1.0)))


def cube_root(x: float) -> float:
    """The cube root of ``x`` (positive, finite), correctly rounded: the same bits on every CPU and C library.

    ``np.cbrt`` is a SIMD kernel whose last bit depends on the CPU NumPy dispatches to (on a CPU with AVX-512 it
    differs from the AVX2 and baseline kernels, which are the C library's, for about half of all values:
    docs/fits.md, "The fits independent of numpy's CPU dispatch"), and the C library's ``cbrt`` is faithful, not
    correctly rounded. The C library's root is moved to the neighbour whose rounding interval holds ``x``: the
    interval's ends are the midpoints to the neighbours, cubed exactly (:class:`fractions.Fraction`); a midpoint's
    cube is never a float64, so there is no tie.
    """
    if not (math.isfinite(x) and x > 0.0):
        raise ParameterError(f"cube_root needs a positive finite number, got {x!r}")
    r = math.cbrt(x)
    want = Fraction(x)
    while True:
        below, above = math.nextafter(r, 0.0), math.nextafter(r, math.inf)
        if want < ((Fraction(r) + Fraction(below)) / 2) ** 3:
            r = below
        elif want > ((Fraction(r) + Fraction(above)) / 2) ** 3:
            r = above
        else:
            return r


def _symmetries(samples: np.ndarray, vertices: np.ndarray, centroid: np.ndarray, axes: np.ndarray, tree: Any,
                tol: float) -> tuple[np.ndarray, np.ndarray | None]:
    """Rotations about the principal axes (n-fold, n = 2..12, and continuous) and the half-turns
    about axes perpendicular to a symmetry axis which map the surface samples onto themselves within
    ``tol``; each refined on the vertices (nearest-vertex Kabsch) when they map onto themselves, and
    the set closed into a group by products."""
    from scipy.spatial import cKDTree

    found = [np.eye(3)]
    cont = None
    probe = samples[:: max(1, len(samples) // 1500)]
    vtree = cKDTree(vertices)
    for j in range(3):
        ax = axes[:, j]
        if all(_maps_onto_itself(_rot(ax, a), probe, centroid, tree, tol) for a in (0.37, 1.1, 2.3)):
            cont = ax
            found += [_rot(ax, 2 * np.pi * k / 12) for k in range(1, 12)]
            break
        for n in range(12, 1, -1):
            R = _rot(ax, 2 * np.pi / n)
            if _maps_onto_itself(R, probe, centroid, tree, tol):
                found += [_rot(ax, 2 * np.pi * k / n) for k in range(1, n)]
                break
    # half-turns about axes perpendicular to the principal ones (a nut upside down)
    for j in range(3):
        ax = axes[:, j]
        perp = axes[:, (j + 1) % 3]
        for a in np.linspace(0, np.pi, 72, endpoint=False):
            h = _rot(ax, a) @ perp
            R = _rot(h, np.pi)
            if _maps_onto_itself(R, probe, centroid, tree, tol):
                found.append(R)
    exact = 1e-4 * float(np.linalg.norm(vertices - centroid, axis=1).max())
    refined: list[tuple[np.ndarray, bool]] = []  # (rotation, maps the vertices onto themselves)
    for R in found:
        Rv, rms = _refine_symmetry(R, vertices, centroid, vtree)
        if rms <= exact:
            R = Rv
        elif cont is None:
            R, _ = _refine_symmetry(R, samples[:: max(1, len(samples) // 4000)], centroid, tree, samples)
        refined.append((R, rms <= exact))
    # a rotation refined on the samples only is no symmetry of its own when it lies within MERGE_DEG of an exact
    # one or of one taken before it: a half-turn about an axis 2° off a ray-traced nut's own passed the samples'
    # tolerance, and the products of such made 36 false symmetries (48, the closure's cap, not 12)
    taken: list[np.ndarray] = []
    exacts = [R for R, ok in refined if ok]
    for R, ok in refined:
        if ok or not any(_angle_deg(G.T @ R) < MERGE_DEG for G in exacts + taken):
            taken.append(R)
    group: list[np.ndarray] = []
    for R in taken:
        if not any(np.abs(R - G).max() < 1e-3 for G in group):
            group.append(R)
    changed = True
    while changed and len(group) < 48:  # inexact rotations would make a closure without end
        changed = False
        for A in list(group):
            for B in list(group):
                C = A @ B
                if len(group) < 48 and not any(np.abs(C - G).max() < 1e-3 for G in group):
                    group.append(C)
                    changed = True
    return np.stack(group), cont


def _triangle_normals(v: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Unit normals per triangle, outward as :func:`_sample_surface` orients them (away from the
    centroid for most of the area); zero for a triangle without area."""
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    cr = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(cr, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        nrm = np.where(area[:, None] > 0, cr / (2.0 * area[:, None]), 0.0)
    centroid = ((a + b + c) / 3.0 * area[:, None]).sum(axis=0) / area.sum()
    out = np.einsum("ij,ij->i", nrm, (a + b + c) / 3.0 - centroid)
    if area[out < 0].sum() > 0.5 * area.sum():
        nrm = -nrm
    return nrm


def _guess_templates(axes: np.ndarray, sym: np.ndarray, cont: np.ndarray | None) -> np.ndarray:
    """The initial rotations up to the region's axes X (the guess is X @ M): M = Rz(turn) P Aᵀ for
    the 24 proper signed permutations P, turns 0 and 45° about the region's least-variance axis, A
    the model's axes; those with the model's least-variance axis on the region's first; one of each
    class equivalent under the symmetries (M1 S ≈ M2; a body of revolution: the axis goes to the
    same place). Left-multiplying by X changes no equivalence, so the classes are the model's."""
    import itertools

    first: list[np.ndarray] = []
    rest: list[np.ndarray] = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            P = np.zeros((3, 3))
            for i, j in enumerate(perm):
                P[i, j] = signs[i]
            if np.linalg.det(P) < 0:
                continue
            for turn in (0.0, np.pi / 4):
                M = _rot(np.array([0.0, 0.0, 1.0]), turn) @ P @ axes.T
                (first if perm[2] == 2 else rest).append(M)
    kept: list[np.ndarray] = []
    variants = np.zeros((0, 3, 3))
    ax_seen = np.zeros((0, 3))
    for M in first + rest:
        if len(variants) and np.abs(variants - M).max(axis=(1, 2)).min() < 0.15:
            continue
        if cont is not None and len(ax_seen) and float((ax_seen @ (M @ cont)).max()) > 0.99:
            continue
        kept.append(M)
        variants = np.concatenate([variants, np.einsum("ij,kjl->kil", M, sym)])
        if cont is not None:
            ax_seen = np.concatenate([ax_seen, np.einsum("ij,kjl,l->ki", M, sym, cont)])
    return np.stack(kept)


def prepare_model(vertices_mm: np.ndarray, triangles: np.ndarray, *, sphere_tolerance: float = 0.01,
                  n_samples: int = 20000, index_margin_mm: float = 6.0, index_voxels: int = 1_000_000) -> PartModel:
    """Check and prepare a part mesh; raise :class:`~zcut.errors.ParameterError` (one line) when it
    is degenerate (too few vertices or triangles, no area, flat, indices out of range).

    The voxel index of a general model (:class:`~zcut.fits.kernels.ModelIndex`) covers the bounding
    box grown by ``index_margin_mm`` (points farther out match nothing: keep it above
    :attr:`FitParams.gate_mm <zcut.fits.FitParams>`) in about ``index_voxels`` voxels."""
    from scipy.spatial import cKDTree

    v, t = _check_mesh(vertices_mm, triangles)
    samples, normals, centroid = _sample_surface(v, t, n_samples)
    r = np.linalg.norm(v - centroid, axis=1)
    extent = float(r.max())
    # a sphere: its vertices and its faces' centres at one radius (a box's corners alone are: the same rule as
    # the vetting's solid, zcut.fit_vetting.solid_of)
    rc = np.linalg.norm(v[t].mean(axis=1) - centroid, axis=1)
    tol = sphere_tolerance * float(r.mean())
    sphere = float(r.mean()) if max(float(np.abs(r - r.mean()).max()), float(np.abs(rc - r.mean()).max())) <= tol \
        else None
    cov = np.cov((samples - centroid).T)
    w, axes = np.linalg.eigh(cov)
    axes = axes[:, ::-1]
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    tree = cKDTree(samples)
    edges, seg0, seg1 = _sharp_edges(v, t, spacing=extent / 150.0)
    edge_tree = cKDTree(edges) if len(edges) else None
    scene = None
    if sphere is None:
        import open3d as o3d

        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(t.astype(np.uint32)))  # type: ignore[call-overload]  # Open3D's stub makes dtype and device required
        spacing = np.sqrt(4 * np.pi * extent * extent / n_samples)
        sym, cont = _symmetries(samples, v, centroid, axes, tree, tol=max(0.02 * extent, 2 * spacing))
        box = np.ptp(v, axis=0) + 2 * index_margin_mm
        h = max(cube_root(float(np.prod(box)) / index_voxels), extent / 400.0)
        index = build_index(v, t, _triangle_normals(v, t), seg0, seg1, scene, margin_mm=index_margin_mm, h_mm=h)
    else:
        sym, cont, index = np.eye(3)[None], None, None
    probe = slice(None, None, max(1, n_samples // 2000))
    from zcut.fit_vetting import solid_of

    # the vetting's solid of the same mesh (the one overlap rule): a ball when this is a sphere
    solid = solid_of(v, t, sphere_tolerance=sphere_tolerance)

    return PartModel(vertices=v, triangles=t, centroid=centroid, sphere_radius=sphere, samples=samples,
                     normals=normals, axes=axes, extent_mm=extent, symmetries=sym, continuous_axis=cont,
                     edges=edges, index=index, guesses=_guess_templates(axes, sym, cont),
                     probe_samples=samples[probe], probe_normals=normals[probe], solid=solid,
                     _scene=scene, _tree=tree, _edge_tree=edge_tree)
