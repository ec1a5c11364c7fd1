"""Vetting the part fits before ``explained`` trusts them as known surfaces (issue 29).

A fitted instance is a known surface for the rule of :mod:`zcut.explained`: every point within
k × Err of it is explained. A wrong fit therefore hides the points it sits on. On the synthetic
1920 × 1200 frames most wrong fits are **duplicates**: a second (third, ...) instance fitted a few
millimetres off a part that already has a fit — on a shiny part's interreflection ghosts, on a
mixed-pixel fringe, on the piece of a part the second pass fitted again (ray-traced spheres of seed
8531: 630 fits for 250 parts, the median distance between a fit's centre and the nearest other fit's
2.5 mm for balls of 20 mm). Each duplicate's band explains the off-surface points around its part.

What a real scan shows, and needs no truth: **two parts never share volume.** Two fits whose solids
overlap cannot both be parts. :func:`vet_fits` ranks the fits by the number of pixels each explains
(the pixels whose nearest known surface it is, within k × Err: its measured support) and keeps them
greedily: a fit whose solid overlaps a kept fit's by more than ``max_overlap`` of its volume is vetted
out (non-maximum suppression on volume). The fits are then no known surface; their pixels are judged
against the surfaces left (:func:`replay.pipeline.explained.run_explained`), so a duplicate's pixels
on its part are explained by the part's kept fit and the off-surface points it hid become
unexplained.

**A part never lies behind the bin or the table** (:func:`behind_shares`; docs/labelling.md, "Fifth round: fits
of ghosts beside the walls"): the share of a fit's inside samples that lie farther than ``BEHIND_ERRS`` of the bin's
Err behind the registered bin model (the nearest model sample within ``BEHIND_SEARCH_MM``, its normal turned towards
the camera) or beyond the table plane. A fit more than ``MAX_BEHIND`` of whose volume lies there is vetted out first:
it is no part, and it takes no part in the overlap rule (it suppresses no other fit). On piles leaning on the walls
the interreflections between the pile and a wall make ghost points behind the wall's face, and the fitting fits
parts to them; the rule reads only the registered bin model, its measured residual, the table plane and the fit's
solid — never the truth. Without the bin stages (no model) nothing is behind anything.

**One rule for the fitting and the vetting** (:class:`Solid`, :func:`pose_overlaps`): the share of one
instance's inside samples that lie inside another instance of the same part, looked up in the part's
occupancy grid (``OCCUPANCY_VOXELS`` a side of its box; a sphere: the closed form). The fitting
(:mod:`zcut.fits`, ``FitParams.claim``) refuses a candidate by it and :func:`instance_overlaps` vets by it,
on the same samples and the same grid (:func:`solid_of`, built once per mesh: the prepared model's
``PartModel.solid``, passed to :func:`instance_overlaps`): the two can no longer disagree near a face by a
voxel. The vetting stays the guard for fits the fitting did not make (instances
a person seeded, a results file).

**Volume overlap of different meshes** (:func:`part_overlaps`): each part mesh is sampled inside by ``samples`` points
drawn uniformly (Open3D's ``RaycastingScene.compute_occupancy``, ray parity: the mesh must
be closed — every edge shared by exactly two triangles once coincident vertices are welded; a mesh
that is not closed has no inside and its fits are never vetted out, :func:`is_closed`); the overlap of fit i with fit j is the share of i's
inside samples that lie inside j. Only pairs whose bounding boxes meet are tested. Touching parts
fitted within a few tenths of a millimetre overlap by far less than the threshold (two balls of 20 mm
that interpenetrate by 0.3 mm share 0.07 % of their volume; two flat nuts stacked, 2 % per 0.2 mm).

Chosen on the frames of seed 8531 (1920 × 1200, zinc nuts and spheres, ray-traced and hand-made)
among thresholds and orderings (docs/labelling.md, "Vetting the fits"); the true meshes of a scene
as fits are never vetted out (their overlap is below the threshold: ``bench/bench_explained.py``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .errors import InputShapeError, ParameterError, describe_array
from .explained import SURFACE_NONE, KnownSurfaces, Nearest, nearest_surface, unexplained

#: a fit is vetted out when more than this share of its volume lies inside a better-supported kept fit
MAX_OVERLAP = 0.05
#: this many points drawn inside each part measure the overlaps
INSIDE_SAMPLES = 400
#: a fit is vetted out when more than this share of its volume lies behind the registered bin or the table
#: (:func:`behind_shares`; chosen on the walls piles of seeds 9601 / 9621 and 7601 / 7621 and checked on the floor
#: piles of seed 8571: docs/labelling.md, "Fifth round"; 15 % vetted out mis-posed fits of parts sunk into the floor)
MAX_BEHIND = 0.5
#: behind: farther than this many of the bin's (the table's) Err behind its surface (3 and 5 vetted out mis-posed
#: fits of real parts near the floor, whose pixels then cost precision: the same docs section)
BEHIND_ERRS = 8.0
#: a point is judged against the bin model only when a model sample lies within its tolerance (``BEHIND_ERRS`` of
#: the bin's Err) plus this (mm): the band behind the bin's inner faces; beyond it (a point the sampled surface does
#: not reach) the table alone judges it
BEHIND_SEARCH_MM = 10.0
#: :attr:`Solid.occupancy`: voxels a side of the mesh's bounding box
OCCUPANCY_VOXELS = 64
#: a mesh whose vertices and faces' centres all lie within this share of the vertices' mean distance from the
#: surface's centroid is a ball (:attr:`Solid.ball`; ``FitParams.sphere_tolerance``'s default)
SPHERE_TOLERANCE = 0.01


@dataclass(frozen=True, slots=True)
class FitVetting:
    """Which fits stay known surfaces, and why the others do not.

    Attributes
    ----------
    kept : (n,) bool ndarray
        True: the fit stays a known surface.
    overlap : (n,) float64 ndarray
        The largest share of the fit's volume inside a better-ranked kept fit (0 when none).
    by : (n,) int64 ndarray
        That kept fit's index (-1 when none).
    behind : (n,) float64 ndarray
        The share of the fit's volume behind the registered bin or the table (:func:`behind_shares`; 0 when not
        measured): above ``max_behind`` the fit is vetted out whatever its overlaps (``by`` is then -1).
    """

    kept: np.ndarray
    overlap: np.ndarray
    by: np.ndarray
    behind: np.ndarray

    @property
    def dropped(self) -> np.ndarray:
        """(m,) int64: the indices of the fits vetted out, increasing."""
        out: np.ndarray = np.flatnonzero(~self.kept)
        return out


def is_closed(vertices: np.ndarray, triangles: np.ndarray) -> bool:
    """Whether a triangle mesh is closed: every (undirected) edge is shared by exactly two triangles,
    vertices at one position (to 1e-6 of the mesh's size) being one vertex (a mesh split along its
    sharp edges for flat shading, as the ray-traced parts' are, is closed)."""
    v = np.asarray(vertices, np.float64).reshape(-1, 3)
    t = np.asarray(triangles, np.int64).reshape(-1, 3)
    if not len(t) or not len(v):
        return False
    scale = max(float(np.ptp(v, axis=0).max()), 1e-12) * 1e-6
    _, weld = np.unique(np.round(v / scale).astype(np.int64), axis=0, return_inverse=True)
    t = weld.reshape(-1)[t]
    e = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return bool((counts == 2).all())


def _scene(v: np.ndarray, t: np.ndarray):  # type: ignore[no-untyped-def]  # Open3D's scene is untyped
    import open3d as o3d

    s = o3d.t.geometry.RaycastingScene()
    s.add_triangles(o3d.core.Tensor(np.ascontiguousarray(v, np.float32)),  # type: ignore[call-overload]  # Open3D's stub makes dtype and device required
                    o3d.core.Tensor(np.ascontiguousarray(t, np.uint32)))  # type: ignore[call-overload]  # Open3D's stub makes dtype and device required
    return s


def _inside(scene, points: np.ndarray) -> np.ndarray:  # type: ignore[no-untyped-def]  # Open3D's scene is untyped
    import open3d as o3d

    if not len(points):
        return np.zeros(0, bool)
    occ = scene.compute_occupancy(o3d.core.Tensor(np.ascontiguousarray(points, np.float32)))  # type: ignore[call-overload]  # Open3D's stub makes dtype and device required
    out: np.ndarray = occ.numpy() > 0
    return out


def inside_samples(vertices: np.ndarray, triangles: np.ndarray, *, samples: int = INSIDE_SAMPLES) -> np.ndarray:
    """(m, 3) points drawn uniformly inside a closed mesh (a fixed seed: the same mesh gives the same
    points), ``samples`` of them or fewer (none when the mesh is not closed or encloses nothing).

    Uniform, not a grid: a grid's layers make the share of a volume jump by a whole layer (1/7 of a
    20 mm box at 400 points); drawn points estimate it with a binomial error (±0.011 at 5 %)."""
    v = np.asarray(vertices, np.float64)
    if not is_closed(v, triangles) or samples <= 0:
        return np.zeros((0, 3))
    lo, hi = v.min(axis=0), v.max(axis=0)
    scene = _scene(v, triangles)
    rng = np.random.default_rng(0)
    got: list[np.ndarray] = []
    n = 0
    for _ in range(8):  # a solid fills 1/8 of its box or more: 8 rounds of 4 x samples draw enough
        g = lo + (hi - lo) * rng.random((4 * samples, 3))
        g = g[_inside(scene, g)]
        got.append(g)
        n += len(g)
        if n >= samples:
            break
    out: np.ndarray = np.concatenate(got)[:samples]
    return out


@dataclass(frozen=True, slots=True, eq=False)
class Solid:
    """The inside of a part mesh (its model frame, mm), as the fitting and the vetting measure overlaps.

    Attributes
    ----------
    inside : (q, 3) float64 ndarray
        Points drawn uniformly inside the solid (:func:`inside_samples`); none when the mesh is not closed.
    occupancy : (origin (3,), voxel (3,), (n, n, n) bool ndarray) or None
        Whether each voxel centre of the bounding box (``OCCUPANCY_VOXELS`` a side) lies inside the solid
        (Open3D's occupancy, once); None when the mesh is not closed or is a ball.
    ball : (centre (3,), radius) or None
        The mesh is a ball (``SPHERE_TOLERANCE``; the fits' sphere): inside is the closed form.
    """

    inside: np.ndarray
    occupancy: tuple[np.ndarray, np.ndarray, np.ndarray] | None
    ball: tuple[np.ndarray, float] | None

    def contains(self, points_model: np.ndarray) -> np.ndarray:
        """(n,) bool: whether each of ``points_model`` (model frame) lies inside the solid (a ball: the closed
        form; else the voxel of ``occupancy`` it falls in, at the voxel's resolution: a 64th of the box; a
        mesh that is not closed contains nothing)."""
        p = np.asarray(points_model, np.float64).reshape(-1, 3)
        if len(p) == 0:
            return np.zeros(0, bool)
        if self.ball is not None:
            out: np.ndarray = np.linalg.norm(p - self.ball[0], axis=1) <= self.ball[1]
            return out
        if self.occupancy is None:
            return np.zeros(len(p), bool)
        origin, h, grid = self.occupancy
        ijk = np.floor((p - origin) / h).astype(np.int64)
        inside = ((ijk >= 0) & (ijk < np.asarray(grid.shape))).all(axis=1)
        res = np.zeros(len(p), bool)
        i = ijk[inside]
        res[inside] = grid[i[:, 0], i[:, 1], i[:, 2]]
        return res


def surface_centroid(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The area-weighted centroid of a mesh's surface (its triangles of positive area)."""
    v = np.asarray(vertices, np.float64)
    t = np.asarray(triangles, np.int64)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    keep = area > 0
    a, b, c, area = a[keep], b[keep], c[keep], area[keep]
    out: np.ndarray = ((a + b + c) / 3.0 * area[:, None]).sum(axis=0) / area.sum()
    return out


def solid_of(vertices: np.ndarray, triangles: np.ndarray, *, sphere_tolerance: float = SPHERE_TOLERANCE,
             samples: int = INSIDE_SAMPLES) -> Solid:
    """The :class:`Solid` of a mesh (model frame, mm): build it once per mesh and pass it on (the prepared
    model's, :attr:`PartModel.solid <zcut.fits.PartModel>`, is the one its fits were made with;
    ``instance_overlaps`` builds one when given none)."""
    v = np.ascontiguousarray(vertices, np.float64)
    t = np.ascontiguousarray(triangles, np.int64)
    inside = inside_samples(v, t, samples=samples)
    ball = None
    occupancy = None
    if len(v) and len(t):
        # a ball: its vertices and its faces' centres at one radius (a box's corners alone are)
        centre = surface_centroid(v, t)
        r = np.linalg.norm(v - centre, axis=1)
        rc = np.linalg.norm(v[t].mean(axis=1) - centre, axis=1)
        tol = sphere_tolerance * float(r.mean())
        if float(np.abs(r - r.mean()).max()) <= tol and float(np.abs(rc - r.mean()).max()) <= tol:
            ball = (centre, float(r.mean()))
    if ball is None and is_closed(v, t):
        lo, hi = v.min(axis=0), v.max(axis=0)
        h = (hi - lo) / OCCUPANCY_VOXELS
        axes = [lo[a] + h[a] * (np.arange(OCCUPANCY_VOXELS) + 0.5) for a in range(3)]
        centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        occupancy = (lo, h, _inside(_scene(v, t), centres).reshape((OCCUPANCY_VOXELS,) * 3))
    return Solid(inside=inside, occupancy=occupancy, ball=ball)


def pose_overlaps(solid: Solid, Ta: np.ndarray, Tb: np.ndarray) -> np.ndarray:
    """(n,) the share of the solid posed at ``Ta[i]``'s inside samples that lie inside the solid posed at
    ``Tb[i]`` ((n, 4, 4) model -> frame, rigid): the one overlap rule of the fitting and the vetting (module
    docstring)."""
    Ta = np.asarray(Ta, np.float64).reshape(-1, 4, 4)
    Tb = np.asarray(Tb, np.float64).reshape(-1, 4, 4)
    q = solid.inside
    if not len(Ta) or not len(q):
        return np.zeros(len(Ta))
    Rb_T = Tb[:, :3, :3].transpose(0, 2, 1)
    R = Rb_T @ Ta[:, :3, :3]  # R_b^T R_a
    t = (Rb_T @ (Ta[:, :3, 3] - Tb[:, :3, 3])[:, :, None])[:, :, 0]  # R_b^T (t_a - t_b)
    moved = q @ R.transpose(0, 2, 1) + t[:, None, :]  # a's samples in b's model frame
    out: np.ndarray = solid.contains(moved.reshape(-1, 3)).reshape(len(Ta), len(q)).mean(axis=1)
    return out


def part_overlaps(parts: Sequence[tuple[np.ndarray, np.ndarray]], *,
                  samples: int = INSIDE_SAMPLES) -> tuple[np.ndarray, np.ndarray]:
    """The volume overlaps of posed part meshes: ((p, 2) int64 ordered pairs (i, j), (p,) share of
    i's inside samples (:func:`inside_samples`) inside j), for the pairs whose bounding boxes meet
    (both orders). A mesh that is not closed overlaps nothing."""
    n = len(parts)
    if n < 2:
        return np.zeros((0, 2), np.int64), np.zeros(0)
    lo = np.array([np.asarray(v, np.float64).min(axis=0) for v, _ in parts])
    hi = np.array([np.asarray(v, np.float64).max(axis=0) for v, _ in parts])
    closed = np.array([is_closed(v, t) for v, t in parts])
    order = np.argsort(lo[:, 0], kind="stable")
    pairs = []
    for a, i in enumerate(order):  # sweep along x, then test the other two axes
        for j in order[a + 1:]:
            if lo[j, 0] > hi[i, 0]:
                break
            if (lo[i] <= hi[j]).all() and (lo[j] <= hi[i]).all() and closed[i] and closed[j]:
                pairs.append((min(i, j), max(i, j)))
    if not pairs:
        return np.zeros((0, 2), np.int64), np.zeros(0)
    pairs.sort()
    involved = sorted({k for p in pairs for k in p})
    scenes = {k: _scene(*parts[k]) for k in involved}
    inside = {k: inside_samples(*parts[k], samples=samples) for k in involved}
    out_pairs, share = [], []
    for i, j in pairs:
        for a, b in ((i, j), (j, i)):
            s = inside[a]
            out_pairs.append((a, b))
            share.append(float(_inside(scenes[b], s).mean()) if len(s) else 0.0)
    return np.asarray(out_pairs, np.int64), np.asarray(share, np.float64)


def instance_overlaps(vertices: np.ndarray, triangles: np.ndarray, poses: Sequence[np.ndarray], *,
                      samples: int = INSIDE_SAMPLES, solid: Solid | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The volume overlaps of instances of one mesh at ``poses`` ((4, 4) model -> frame, rigid) by the
    fitting's rule (:func:`pose_overlaps` on the mesh's :class:`Solid`: ``solid``, the prepared model's, or
    :func:`solid_of` the mesh, built here): its
    inside samples drawn once, each ordered pair (a, b) whose bounding spheres meet tests a's samples moved
    into b's model frame against the model's occupancy (a ball: the closed form). The same pairs and, within
    a voxel near a face, the same shares as :func:`part_overlaps` of the posed meshes."""
    v = np.asarray(vertices, np.float64)
    T = np.asarray(poses, np.float64).reshape(-1, 4, 4)
    n = len(T)
    empty = (np.zeros((0, 2), np.int64), np.zeros(0))
    if n < 2:
        return empty
    solid = solid_of(v, triangles, samples=samples) if solid is None else solid
    if not len(solid.inside):
        return empty
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    radius = float(np.linalg.norm(v - centre, axis=1).max())
    c = T[:, :3, :3] @ centre + T[:, :3, 3]
    from scipy.spatial import cKDTree

    pairs = cKDTree(c).query_pairs(2.0 * radius, output_type="ndarray")
    if not len(pairs):
        return empty
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    ordered = np.empty((2 * len(pairs), 2), np.int64)
    ordered[0::2], ordered[1::2] = pairs, pairs[:, ::-1]
    share = pose_overlaps(solid, T[ordered[:, 0]], T[ordered[:, 1]])
    return ordered, share.astype(np.float64)


def behind_shares(solid: Solid, poses: Sequence[np.ndarray], surfaces: KnownSurfaces, *, f_px: float,
                  k: float = BEHIND_ERRS, floor_mm: float = 0.0, search_mm: float = BEHIND_SEARCH_MM) -> np.ndarray:
    """(n,) the share of the solid posed at each of ``poses`` ((4, 4) model -> camera frame, mm, rigid) that lies
    behind the registered bin or below the table: **a part never lies inside the bin's walls or below its floor**.

    An inside sample (:attr:`Solid.inside`) at p is behind the bin when the nearest sample q of the bin model
    (``surfaces.bin_points``: points and unit normals turned towards the camera, as the pipeline's model is) lies
    within ``k`` × Err + ``search_mm`` of it and (p − q) · n < −``k`` × the bin's Err at p (``max(floor_mm, sqrt(σ_bin² + c²/2))``, c =
    |z| / ``f_px`` the footprint at p's depth, σ_bin = ``surfaces.bin_err_mm``; 0 when unknown); behind the table when
    it lies farther than ``k`` × the table's Err (its ``residual_mm``, the same footprint) beyond the plane, away from
    the camera. The shares are 0 without a bin model and a table, and for a mesh that is not closed (no inside)."""
    T = np.asarray(poses, np.float64).reshape(-1, 4, 4)
    q = solid.inside
    if not len(T) or not len(q) or (surfaces.bin_points is None and surfaces.table is None):
        return np.zeros(len(T))
    if not (np.isfinite(f_px) and f_px > 0):
        raise ParameterError(f"the focal length must be a positive number of pixels, got {f_px!r}")
    p = (q @ T[:, :3, :3].transpose(0, 2, 1) + T[:, None, :3, 3]).reshape(-1, 3)  # (n × q, 3) camera frame
    c = np.abs(p[:, 2]) / float(f_px)
    behind = np.zeros(len(p), bool)

    def err(sigma: float) -> np.ndarray:
        s = sigma if np.isfinite(sigma) else 0.0
        out: np.ndarray = np.maximum(float(floor_mm), np.sqrt(s * s + 0.5 * c * c))
        return out

    if surfaces.bin_points is not None and len(surfaces.bin_points[0]):
        from scipy.spatial import cKDTree

        pts, nrm = (np.asarray(a, np.float64) for a in surfaces.bin_points)
        tol = k * err(float(surfaces.bin_err_mm))
        e, j = cKDTree(pts).query(p, k=1, distance_upper_bound=float(tol.max()) + float(search_mm))
        near = e <= tol + float(search_mm)
        j = np.where(near, j, 0)
        signed = np.einsum("ij,ij->i", p - pts[j], nrm[j])
        behind |= near & (signed < -tol)
    if surfaces.table is not None:  # the camera (the origin) lies on the side where normal · p − offset has −offset's sign
        t = surfaces.table
        away = 1.0 if float(t.offset) > 0 else -1.0
        beyond = away * (p @ np.asarray(t.normal, np.float64) - float(t.offset))
        behind |= beyond > k * err(float(t.residual_mm))
    out: np.ndarray = behind.reshape(len(T), len(q)).mean(axis=1)
    return out


def vet_fits(overlaps: tuple[np.ndarray, np.ndarray], support_px: np.ndarray, *,
             max_overlap: float = MAX_OVERLAP, behind: np.ndarray | None = None,
             max_behind: float = MAX_BEHIND) -> FitVetting:
    """The fits kept as known surfaces (module docstring): a fit more than ``max_behind`` of whose volume lies
    behind the bin or the table (``behind``, :func:`behind_shares`; None: none) is vetted out first, and takes no
    part in the rest; the others ranked by ``support_px`` (more first; a tie keeps the lower index first), a fit is
    vetted out when more than ``max_overlap`` of its volume, or of the other's, lies inside a kept fit ranked
    before it.

    Parameters
    ----------
    overlaps : ((p, 2) int ndarray, (p,) float ndarray)
        Ordered pairs of fits (i, j) and the share of i's volume inside j (:func:`part_overlaps`,
        :func:`instance_overlaps`); a pair not listed does not overlap.
    support_px : (n,) int or float ndarray
        Each fit's measured support: the pixels it explains (:func:`explained_px`).
    """
    s = np.asarray(support_px, np.float64)
    if s.ndim != 1:
        raise InputShapeError(f"support_px must be one value per fit (n,), got {describe_array(s)}")
    n = len(s)
    pairs = np.asarray(overlaps[0], np.int64).reshape(-1, 2)
    share = np.asarray(overlaps[1], np.float64).reshape(-1)
    if len(share) != len(pairs) or (pairs.size and (pairs.min() < 0 or pairs.max() >= n)):
        raise InputShapeError(f"overlaps must be pairs of the {n} fits and one share each, got "
                              f"{describe_array(pairs)} and {describe_array(share)}")
    if not (np.isfinite(max_overlap) and 0 <= max_overlap < 1):
        raise ParameterError(f"max_overlap must be a share in [0, 1), got {max_overlap!r}")
    if not (np.isfinite(max_behind) and 0 <= max_behind < 1):
        raise ParameterError(f"max_behind must be a share in [0, 1), got {max_behind!r}")
    shares = np.zeros(n) if behind is None else np.asarray(behind, np.float64)
    if shares.shape != (n,):
        raise InputShapeError(f"behind must be one share per fit ({n},), got {describe_array(shares)}")
    wall = shares > max_behind  # no part: out first, and it suppresses nothing
    # ordered pairs (a, b): share of a inside b; a pair conflicts when either share exceeds the threshold
    conflict: list[list[tuple[int, float]]] = [[] for _ in range(n)]
    for (a, b), v in zip(pairs.tolist(), share.tolist()):
        if v > max_overlap:
            conflict[a].append((b, v))
            conflict[b].append((a, v))
    order = np.lexsort((np.arange(n), -s))
    kept = np.zeros(n, bool)
    overlap = np.zeros(n)
    by = np.full(n, -1, np.int64)
    for i in order:
        if wall[i]:
            continue
        worst = max(((v, j) for j, v in conflict[i] if kept[j]), default=None)
        if worst is None:
            kept[i] = True
        else:
            overlap[i], by[i] = worst
    return FitVetting(kept, overlap, by, shares.copy())


def explained_px(nearest: Nearest, err: np.ndarray, n_parts: int, *, k: float,
                 where: np.ndarray | None = None) -> np.ndarray:
    """(n_parts,) int64: the pixels (in ``where``, default every judged one) each part instance
    explains — it is their nearest surface and they lie within ``k`` × ``err`` of it: the ranking of
    :func:`vet_fits`."""
    code = np.asarray(nearest.surface)
    mine = (code >= 0) & ~unexplained(nearest.dist_mm, err, k)
    if where is not None:
        if np.shape(where) != code.shape:
            raise InputShapeError(f"where must be {code.shape} bool, got {describe_array(where)}")
        mine &= np.asarray(where, bool)
    c = code[mine]
    if c.size and int(c.max()) >= n_parts:
        raise InputShapeError(f"the nearest surfaces name instance {int(c.max())} but there are {n_parts} parts")
    out: np.ndarray = np.bincount(c, minlength=n_parts).astype(np.int64)
    return out


def without_fits(xyz_mm: np.ndarray, nearest: Nearest, surfaces: KnownSurfaces,
                 kept: np.ndarray) -> tuple[KnownSurfaces, Nearest]:
    """``surfaces`` with the ``kept`` part instances only (renumbered 0, 1, ... in their order) and
    ``nearest`` (computed with every instance, :func:`zcut.explained.nearest_surface`) without the
    others: the pixels whose nearest surface was an instance left out are judged again against the surfaces left; the other pixels keep theirs, as
    a full recomputation would (taking surfaces away makes none of the others nearer).
    """
    keep = np.asarray(kept, bool)
    n = len(surfaces.parts)
    if keep.shape != (n,):
        raise InputShapeError(f"kept must be one bool per part ({n},), got {describe_array(keep)}")
    idx = np.flatnonzero(keep)
    ids = [int(i) for i in idx]
    left = KnownSurfaces(parts=[surfaces.parts[i] for i in ids], part_err_mm=[float(surfaces.part_err_mm[i]) for i in ids],
                         bin_mesh=surfaces.bin_mesh, bin_points=surfaces.bin_points,
                         bin_spacing_mm=surfaces.bin_spacing_mm, bin_err_mm=surfaces.bin_err_mm,
                         table=surfaces.table, local_err_mm=surfaces.local_err_mm)
    lut = np.full(n, SURFACE_NONE, np.int32)
    lut[idx] = np.arange(idx.size, dtype=np.int32)
    code = np.asarray(nearest.surface)
    lost = code >= 0
    lost[lost] = ~keep[code[lost]]
    if not lost.any() and keep.all():
        return left, nearest
    again = nearest_surface(xyz_mm, left, where=lost)
    dist = np.where(lost, again.dist_mm, nearest.dist_mm).astype(np.float32)
    code = np.where(lost, again.surface, np.where(code >= 0, lut[np.maximum(code, 0)], code)).astype(np.int32)
    return left, Nearest(dist, code)


__all__ = ["BEHIND_ERRS", "BEHIND_SEARCH_MM", "INSIDE_SAMPLES", "MAX_BEHIND", "MAX_OVERLAP", "OCCUPANCY_VOXELS", "SPHERE_TOLERANCE", "FitVetting", "Solid", "behind_shares", "explained_px",
           "inside_samples", "instance_overlaps", "is_closed", "part_overlaps", "pose_overlaps", "solid_of",
           "surface_centroid", "vet_fits", "without_fits"]
