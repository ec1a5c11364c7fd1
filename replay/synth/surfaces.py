"""The scene's true surfaces and the paper's truth: the points farther than 3 × Err from every one.

The paper (§2) calls a point an outlier when its distance to the fitted CAD model exceeds 3 × Err,
Err the fit's residual. A synthetic scene knows its true geometry, so a perfect fit is at hand: the
parts with all their faces (hidden ones included), the bin (rim, inner and outer walls, floor) and
the table. :func:`off_surface` flags the valid points farther than ``k`` × Err (k = 3) from every
one of them; it is written as ``/ground_truth/off_surface`` beside the sensor's own truth
(``/ground_truth/outliers``: "the point is not what its pixel's footprint saw").

**Err** (:func:`err_mm`) is the residual a perfect fit would have at the pixel: its depth noise and
its footprint, ``Err = sqrt(σ² + (c·√2/2)² + q²/12)`` with σ the pixel's own depth-noise sigma as
the generator drew it, c the side of the pixel's resolution cell at the point's depth (the larger
of the pixel footprint z / f and, for the hand-made generator, the step of the height field the
scene is rendered from), c·√2/2 half its diagonal (how far a point the footprint measured can lie
from the surface point on its centre ray), and q the depth step of a quantizing sensor.

**Distances** are exact point-to-triangle distances (Open3D's ``RaycastingScene``, float32: within
1e-4 mm at the scene's coordinates) to meshes that are the solids themselves, and closed forms for
spheres (of equal radius r, from the nearest centre: a point outside every ball is nearest to the
ball of the nearest centre, and a point inside a ball is nearest to that ball's own surface as long
as the balls do not overlap; the generator drops each ball onto the others' height field, checked
at its grid nodes only, so two may share a thin lens between nodes, and a point inside such a lens
is judged by the nearer centre's ball alone: an error no larger than the lens is thick).
The hand-made parts are prisms of convex polygons (a bore subtracted, teeth added): their meshes
(:func:`solid_mesh`) are exact, as the ray-traced generator's meshes are its scene. Their polar angles,
sines and cosines are the C library's (:mod:`replay.synth.trig`), not numpy's SIMD kernels, whose
last bits move with the CPU: a log's ``part_model.ply`` has the same bytes on every machine.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numba
import numpy as np

from replay.synth.trig import atan2, cos_sin

if TYPE_CHECKING:
    import open3d as o3d

    from replay.synth.parts import Primitive, Solid
    from replay.synth.scene import Scene

#: the paper's factor: an outlier lies farther than K × Err from every true surface
OFF_SURFACE_K = 3.0


def err_mm(z_mm: np.ndarray, sigma_mm: np.ndarray | float, f_px: float, *, cell_mm: float = 0.0,
           quantize_mm: float = 0.0) -> np.ndarray:
    """The residual a perfect fit would have at each pixel (mm): ``sqrt(σ² + (c·√2/2)² + q²/12)``.

    Parameters
    ----------
    z_mm : ndarray
        Camera z of the point (mm).
    sigma_mm : ndarray or float
        The pixel's depth-noise sigma (mm).
    f_px : float
        Focal length (pixels): the footprint of a pixel at depth z is z / f.
    cell_mm : float
        Smallest resolution cell of the scene itself (the hand-made generator's height-field step);
        c = max(z / f, cell_mm).
    quantize_mm : float
        Depth step of a quantizing sensor (its rounding error has variance q² / 12).
    """
    c = np.maximum(np.asarray(z_mm, np.float64) / float(f_px), float(cell_mm))
    return np.sqrt(np.asarray(sigma_mm, np.float64) ** 2 + 0.5 * c * c + float(quantize_mm) ** 2 / 12.0)


# ------------------------------------------------------------------------------------------------
# exact meshes of the hand-made parts (replay.synth.parts primitives)


def _exit_distance(poly: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Where each ray from the origin at ``angles`` (P, A) leaves the convex counter-clockwise
    ``poly`` (P, n, 2) of its row (-inf: the ray misses it)."""
    edge = np.roll(poly, -1, axis=1) - poly
    normal = np.stack([edge[..., 1], -edge[..., 0]], axis=-1)  # outward, (P, n, 2)
    offset = np.einsum("pij,pij->pi", normal, poly)  # (P, n)
    c, s = cos_sin(angles)
    dn = c[:, :, None] * normal[:, None, :, 0] + s[:, :, None] * normal[:, None, :, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = offset[:, None, :] / dn
    t_exit = np.where(dn > 1e-15, t, np.inf).min(axis=2)
    t_enter = np.where(dn < -1e-15, t, -np.inf).max(axis=2)
    outside = ((np.abs(dn) <= 1e-15) & (offset[:, None, :] < 0)).any(axis=2)  # parallel to an edge, beyond it
    through = (t_enter <= t_exit + 1e-9) & np.isfinite(t_exit) & (t_exit > 0) & ~outside
    return np.where(through, t_exit, -np.inf)


def _segment_crossings(polys: Sequence[np.ndarray]) -> np.ndarray:
    """Points where an edge of one polygon crosses an edge of another (k, 2)."""
    a = np.concatenate(list(polys))
    b = np.concatenate([np.roll(p, -1, axis=0) for p in polys])
    owner = np.concatenate([np.full(len(p), i) for i, p in enumerate(polys)])
    r = b - a
    qa, qr = a[None, :, :], r[None, :, :]
    pa, pr = a[:, None, :], r[:, None, :]
    den = pr[..., 0] * qr[..., 1] - pr[..., 1] * qr[..., 0]
    w = qa - pa
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * qr[..., 1] - w[..., 1] * qr[..., 0]) / den
        u = (w[..., 0] * pr[..., 1] - w[..., 1] * pr[..., 0]) / den
    ok = (owner[:, None] != owner[None, :]) & (np.abs(den) > 1e-12) & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
    i, _ = np.nonzero(ok)
    points: np.ndarray = a[i] + t[ok][:, None] * r[i]
    return points


def _angles(points: np.ndarray) -> np.ndarray | None:
    """Sorted polar angles (P, A) of the points (P, k, 2) of each row, the breakpoints of star-shaped
    outlines; None when a row holds two (nearly) equal angles (the rows then differ in count)."""
    ang = np.sort(np.mod(atan2(points[..., 1], points[..., 0]), 2 * np.pi), axis=1)
    gaps = np.diff(np.concatenate([ang, ang[:, :1] + 2 * np.pi], axis=1), axis=1)
    if (gaps <= 1e-10).any():
        if len(ang) > 1:
            return None
        return ang[:, gaps[0] > 1e-10]  # one row: the distinct angles
    return ang


def _outline(polys: Sequence[np.ndarray], angles: np.ndarray) -> np.ndarray:
    """Radius (P, A) of the star-shaped union of ``polys`` (each (P, n, 2)) about the origin."""
    r = np.max([_exit_distance(p, angles) for p in polys], axis=0)
    if not np.isfinite(r).all():
        raise ValueError("the outline is not star-shaped about the part's axis")
    radius: np.ndarray = r
    return radius


#: longest wall triangle along a prism's axis (mm): long slivers (an 80 mm rod's sides) slow the
#: distance queries' bounding-volume tree down; cutting them costs nothing in exactness
WALL_SEGMENT_MM = 12.0


def _extrusion(angles: np.ndarray, outer: np.ndarray, z0: float, z1: float, *, bore: np.ndarray | None = None,
               cap0: bool = True, cap1_hole: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (P, nv, 3) and triangles (m, 3) of P prisms whose outlines are ``outer`` (P, A) at
    ``angles`` (P, A) (exact: every breakpoint is one of the angles), from z0 to z1, with an optional
    through bore, an optional hole in the top cap (where another prism continues) and the bottom cap
    left out when ``cap0`` is False. Walls are cut every :data:`WALL_SEGMENT_MM` along the axis."""
    P, n = angles.shape
    c, s = cos_sin(angles)
    zs = np.linspace(z0, z1, max(1, int(np.ceil((z1 - z0) / WALL_SEGMENT_MM))) + 1)
    rings = [(outer, z) for z in zs]
    if bore is not None:
        rings += [(bore, z) for z in zs]
    if cap1_hole is not None:
        rings += [(cap1_hole, z1)]
    v = np.empty((P, len(rings) * n + 2, 3))
    for k, (r, z) in enumerate(rings):
        v[:, k * n:(k + 1) * n, 0] = r * c
        v[:, k * n:(k + 1) * n, 1] = r * s
        v[:, k * n:(k + 1) * n, 2] = z
    v[:, -2] = (0.0, 0.0, z0)
    v[:, -1] = (0.0, 0.0, z1)
    i = np.arange(n)
    j = (i + 1) % n
    m = len(zs)

    def band(a: int, b: int) -> list[np.ndarray]:  # quads (a+i, a+j, b+j, b+i)
        return [np.stack([a + i, a + j, b + j], 1), np.stack([a + i, b + j, b + i], 1)]

    o0, o1 = 0, (m - 1) * n
    centre0, centre1 = v.shape[1] - 2, v.shape[1] - 1
    tri: list[np.ndarray] = []
    for k in range(m - 1):
        tri += band(k * n, (k + 1) * n)  # outer wall
    if bore is not None:
        b0, b1 = m * n, (2 * m - 1) * n
        for k in range(m - 1):
            tri += band((m + k + 1) * n, (m + k) * n)  # bore wall, facing the axis
        tri += band(o1, b1)  # top annulus
        tri += band(b0, o0)  # bottom annulus
    else:
        if cap1_hole is not None:
            tri += band(o1, len(rings) * n - n)
        else:
            tri += [np.stack([np.full(n, centre1), o1 + i, o1 + j], 1)]
        if cap0:
            tri += [np.stack([np.full(n, centre0), o0 + j, o0 + i], 1)]
    return v, np.concatenate(tri).astype(np.int64)


def _signature(solid: Solid) -> tuple[object, ...]:
    prims, hole = solid
    R = prims[0][8]
    return (tuple((p[0], len(p[5]) if p[0] == "poly" else 0, p[6] if p[0] == "poly" else 0,
                   p[7] if p[0] == "poly" else 0) for p in prims),
            None if hole is None else (len(hole[5]), hole[6], hole[7]),
            None if R is None else np.asarray(R).tobytes())


def solid_meshes(solids: Sequence[Solid]) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`solid_mesh` of each of ``solids`` ((primitives, hole) pairs), those of one shape at once."""
    out: list[tuple[np.ndarray, np.ndarray]] = [None] * len(solids)  # type: ignore[list-item]  # all set below
    groups: dict[tuple[object, ...], list[int]] = {}
    same: dict[bytes, int] = {}  # parts drawn without a random phase (sprockets) are one solid
    copies: list[tuple[int, int]] = []
    for k, (prims, hole) in enumerate(solids):
        key = b"".join(np.asarray(p[5]).tobytes() for p in prims if p[0] == "poly") + \
            (b"" if hole is None else np.asarray(hole[5]).tobytes())
        if key in same:
            copies.append((k, same[key]))
            continue
        same[key] = k
        groups.setdefault(_signature((prims, hole)), []).append(k)
    for idx in groups.values():
        try:
            batch = _solid_mesh_batch([solids[k] for k in idx])
        except _Uneven:
            batch = [_solid_mesh_batch([solids[k]])[0] for k in idx]
        for k, m in zip(idx, batch):
            out[k] = m
    for k, first in copies:
        out[k] = out[first]
    return out


class _Uneven(Exception):
    """Rows of a batch whose outlines have different numbers of breakpoints."""


def solid_mesh(primitives: list[Primitive], hole: Primitive | None) -> tuple[np.ndarray, np.ndarray]:
    """The exact closed surface of a hand-made part (:func:`replay.synth.parts.part_solid`), local frame, mm.

    Handles the kinds the generator makes: co-axial prisms of one height whose union is star-shaped
    about the axis (nuts, rods, sprockets), with a through bore; two co-axial prisms stacked end to
    end, the narrower continuing the wider (screws: the shaft leaves the head's face). Spheres have
    no mesh (their distance is a closed form).

    Returns
    -------
    vertices : (n, 3) float64 ndarray
    triangles : (m, 3) int64 ndarray
        Counter-clockwise seen from outside.
    """
    try:
        return _solid_mesh_batch([(primitives, hole)])[0]
    except _Uneven:
        raise ValueError("solid_mesh: two breakpoints of the outline coincide") from None


def _solid_mesh_batch(solids: Sequence[Solid]) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`solid_mesh` of solids of one signature (:func:`_signature`)."""
    primitives, hole = solids[0]
    if any(p[0] != "poly" for p in primitives) or (hole is not None and hole[0] != "poly"):
        raise ValueError("solid_mesh takes prisms (a sphere's distance is a closed form)")
    R = np.eye(3) if primitives[0][8] is None else np.asarray(primitives[0][8], np.float64)
    for p in primitives[1:]:
        if not np.allclose(np.eye(3) if p[8] is None else p[8], R):
            raise ValueError("solid_mesh takes co-axial prisms")
    P = len(solids)
    polys = [np.stack([s[0][k][5] for s in solids]) for k in range(len(primitives))]  # each (P, n, 2)
    spans = {(p[6], p[7]) for p in primitives}
    if len(spans) == 1:
        (z0, z1), = spans
        pts = list(polys)
        if len(polys) > 1:  # where the outlines of the union cross (one row at a time: counts may differ)
            if P > 1:
                raise _Uneven
            pts.append(_segment_crossings([p[0] for p in polys])[None])
        if hole is not None:
            if not (hole[6] <= z0 and hole[7] >= z1):
                raise ValueError("solid_mesh takes a bore through the whole part")
            holes = np.stack([s[1][5] for s in solids])  # type: ignore[index]  # one signature: each has a hole
            pts.append(holes)
        ang = _angles(np.concatenate(pts, axis=1))
        if ang is None:
            raise _Uneven
        bore = _outline([holes], ang) if hole is not None else None
        v, t = _extrusion(ang, _outline(polys, ang), z0, z1, bore=bore)
    elif len(primitives) == 2 and hole is None:
        order = np.argsort([p[6] for p in primitives])
        a, b = (primitives[k] for k in order)
        pa, pb = (polys[k] for k in order)  # a below b along the axis
        if abs(a[7] - b[6]) > 1e-9:
            raise ValueError("solid_mesh takes two prisms that meet end to end")
        ang = _angles(np.concatenate([pa, pb], axis=1))
        if ang is None:
            raise _Uneven
        ra, rb = _outline([pa], ang), _outline([pb], ang)
        if not (rb <= ra + 1e-9).all():
            raise ValueError("solid_mesh takes a narrower prism on top of a wider one")
        va, ta = _extrusion(ang, ra, a[6], a[7], cap1_hole=rb)
        vb, tb = _extrusion(ang, rb, b[6], b[7], cap0=False)
        v, t = np.concatenate([va, vb], axis=1), np.concatenate([ta, tb + va.shape[1]])
        # one ring where they meet (the hole of a's cap is b's bottom edge): weld equal vertices
        _, first, inverse = np.unique(v[0], axis=0, return_index=True, return_inverse=True)
        v, t = v[:, first], inverse.reshape(-1)[t]
    else:
        raise ValueError("solid_mesh: an arrangement of prisms it does not know")
    v = v @ R.T
    return [(v[k], t) for k in range(P)]


def kind_model_mesh(kind: str) -> tuple[np.ndarray, np.ndarray]:
    """The hand-made generator's part of ``kind`` as a mesh (local frame, mm), its random phases at 0:
    the ``part_model.ply`` its logs carry. Spheres: an icosphere of 5,120 faces (within 0.008 mm of
    the ball)."""
    from replay.synth.parts import part_solid

    class _Zero:  # draws 0 wherever part_solid draws a phase
        def uniform(self, lo: float, hi: float | None = None) -> float:
            return 0.0

    prims, hole = part_solid(kind, _Zero())  # type: ignore[arg-type]
    if prims[0][0] == "sphere":
        from replay.synth.raytrace.meshes import _icosphere

        m = _icosphere(float(prims[0][2]), 4)
        return m.vertices + prims[0][1], m.triangles
    return solid_mesh(prims, hole)


# ------------------------------------------------------------------------------------------------
# distances


class TrueSurfaces:
    """The scene's true surfaces in the camera frame (mm): triangles and spheres, queried for the
    nearest surface point.

    Parameters
    ----------
    vertices : (n, 3) float ndarray
    triangles : (m, 3) int ndarray
    sphere_centres : (s, 3) float ndarray or None
    sphere_radius : float
    scene : open3d RaycastingScene or None
        One already built on exactly these triangles (the ray-traced generator's), reused.
    """

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, *, sphere_centres: np.ndarray | None = None,
                 sphere_radius: float = 0.0, scene: o3d.t.geometry.RaycastingScene | None = None) -> None:
        import open3d as o3d

        self.n_triangles = int(len(triangles))
        if scene is None and self.n_triangles:
            scene = o3d.t.geometry.RaycastingScene()
            scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(vertices, np.float32)),  # type: ignore[call-overload]  # Open3D's stub makes dtype and device required
                                o3d.core.Tensor(np.ascontiguousarray(triangles, np.uint32)))  # type: ignore[call-overload]  # Open3D's stub makes dtype and device required
        self._scene = scene
        self._centres = None if sphere_centres is None or len(sphere_centres) == 0 else \
            np.asarray(sphere_centres, np.float64)
        self._radius = float(sphere_radius)
        self._tree = None
        if self._centres is not None:
            from scipy.spatial import cKDTree

            self._tree = cKDTree(self._centres)

    def closest(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distance (n,), nearest surface point (n, 3)) of each of ``points`` (n, 3), mm."""
        import open3d as o3d

        p = np.asarray(points, np.float64).reshape(-1, 3)
        dist = np.full(len(p), np.inf)
        near = np.full((len(p), 3), np.nan)
        if len(p) == 0:
            return dist, near
        if self._scene is not None:
            q = self._scene.compute_closest_points(o3d.core.Tensor(p.astype(np.float32)))["points"].numpy()  # type: ignore[call-overload]  # Open3D's stub makes dtype and device required
            near = q.astype(np.float64)
            dist = np.linalg.norm(p - near, axis=1)
        if self._tree is not None:
            assert self._centres is not None
            n, idx = self._tree.query(p, k=1)
            d = np.abs(n - self._radius)
            better = np.nonzero(d < dist)[0]
            if len(better):
                c = self._centres[idx[better]]
                v = p[better] - c
                nb = n[better, None]
                u = np.where(nb > 0, v / np.maximum(nb, 1e-300), np.array([0.0, 0.0, -1.0]))
                near[better] = c + self._radius * u
                dist[better] = d[better]
        return dist, near

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Distance (mm) of each of ``points`` (n, 3) to the nearest true surface."""
        import open3d as o3d

        p = np.asarray(points, np.float64).reshape(-1, 3)
        dist = np.full(len(p), np.inf)
        if len(p) and self._scene is not None:
            dist = self._scene.compute_distance(o3d.core.Tensor(p.astype(np.float32))).numpy().astype(np.float64)  # type: ignore[call-overload]  # Open3D's stub makes dtype and device required
        if len(p) and self._tree is not None:
            assert self._centres is not None
            near, _ = self._tree.query(p, k=1)
            dist = np.minimum(dist, np.abs(near - self._radius))
        return dist


#: how far inside its threshold a point must lie from a known surface point (``on_surface``) to be
#: decided without a query (mm): the float32 error of Open3D's distances and of a ray's hit point
#: (~1e-4 mm at the scene's 600 mm) is far smaller, so such a point is never one a query would flag
ON_SURFACE_MARGIN_MM = 0.01


@numba.njit(cache=True, nogil=True)
def _undecided(xyz, near, thr, valid, anchor):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """The valid non-anchor points none of whose four nearest anchors' nearest surface points lies
    within their threshold."""
    H, W = valid.shape
    out = np.zeros((H, W), np.bool_)
    for r in range(H):
        for c in range(W):
            if not valid[r, c] or anchor[r, c]:
                continue
            best = np.inf
            for dr in (0, 2):
                rr = min(r - r % 2 + dr, H - 1)
                for dc in (0, 2):
                    cc = min(c - c % 2 + dc, W - 1)
                    if not anchor[rr, cc]:
                        continue
                    dx = xyz[r, c, 0] - near[rr, cc, 0]
                    dy = xyz[r, c, 1] - near[rr, cc, 1]
                    dz = xyz[r, c, 2] - near[rr, cc, 2]
                    d = np.sqrt(dx * dx + dy * dy + dz * dz)
                    if d < best:
                        best = d
            out[r, c] = not (best <= thr[r, c])
    return out


@numba.njit(cache=True, nogil=True)
def _near_known(xyz, known, thr, valid, margin):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """The valid points within their threshold less ``margin`` of their own known surface point
    (False where that point is NaN)."""
    H, W = valid.shape
    out = np.zeros((H, W), np.bool_)
    for r in range(H):
        for c in range(W):
            if not valid[r, c]:
                continue
            dx = xyz[r, c, 0] - known[r, c, 0]
            dy = xyz[r, c, 1] - known[r, c, 1]
            dz = xyz[r, c, 2] - known[r, c, 2]
            out[r, c] = np.sqrt(dx * dx + dy * dy + dz * dz) <= thr[r, c] - margin
    return out


@numba.njit(cache=True, nogil=True)
def _anchors_of(todo, anchor):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """The anchors :func:`off_surface` queries: those in ``todo`` and every anchor among the four
    that :func:`_undecided` consults for a non-anchor point in ``todo``."""
    H, W = todo.shape
    out = np.zeros((H, W), np.bool_)
    for r in range(H):
        for c in range(W):
            if not todo[r, c]:
                continue
            if anchor[r, c]:
                out[r, c] = True
                continue
            for dr in (0, 2):
                rr = min(r - r % 2 + dr, H - 1)
                for dc in (0, 2):
                    cc = min(c - c % 2 + dc, W - 1)
                    if anchor[rr, cc]:
                        out[rr, cc] = True
    return out


def off_surface(xyz_mm: np.ndarray, err: np.ndarray, surfaces: TrueSurfaces, *, k: float = OFF_SURFACE_K,
                on_surface: np.ndarray | None = None) -> np.ndarray:
    """(H, W) bool: the valid points farther than ``k`` × ``err`` from every true surface.

    The valid points on even rows and columns are queried first (their nearest surface points);
    a point within ``k`` × Err of one of its four nearest such neighbours' nearest surface points
    is within it of a surface (that distance bounds its own from above), and only the other points
    are queried: the same mask as querying every point, for about a third of the queries.

    ``on_surface``: a point on the true surfaces per pixel (NaN where none is known; the ray
    tracer's centre-ray hits), another such bound: a point within ``k`` × Err less
    :data:`ON_SURFACE_MARGIN_MM` of its own is decided without a query (the margin covers the
    float32 error of both, so a query would not have flagged it either), and of the anchors only
    those that a point still undecided consults are queried: the same mask as without it, for a
    fraction of the queries (most points of a scan lie on the surface their pixel sees).

    Parameters
    ----------
    xyz_mm : (H, W, 3) float ndarray
        The cloud in the camera frame (mm), NaN where invalid.
    err : (H, W) float ndarray
        Err of each pixel (:func:`err_mm`).
    surfaces : TrueSurfaces
    on_surface : (H, W, 3) float ndarray or None
        A known point of the true surfaces per pixel (mm, NaN: none).
    """
    xyz = np.ascontiguousarray(xyz_mm, np.float64)
    H, W = xyz.shape[:2]
    valid: np.ndarray = np.isfinite(xyz).all(axis=2)  # type: ignore[assignment]  # an array for a 3-D input
    thr = float(k) * np.ascontiguousarray(err, np.float64)
    anchor = np.zeros((H, W), bool)
    anchor[::2, ::2] = valid[::2, ::2]
    todo = valid
    if on_surface is not None:
        known = np.ascontiguousarray(on_surface, np.float64)
        if known.shape != xyz.shape:
            raise ValueError(f"on_surface must have the cloud's shape {xyz.shape}, got {known.shape}")
        todo = valid & ~_near_known(xyz, known, thr, valid, ON_SURFACE_MARGIN_MM)
        queried = _anchors_of(todo, anchor)
    else:
        queried = anchor
    out = np.zeros((H, W), bool)
    d, q = surfaces.closest(xyz[queried])
    out[queried] = d > thr[queried]
    near = np.zeros((H, W, 3))
    near[queried] = q
    undecided = _undecided(xyz, near, thr, todo, anchor)
    out[undecided] = surfaces.distance(xyz[undecided]) > thr[undecided]
    return out


# ------------------------------------------------------------------------------------------------
# the hand-made generator's scene


def _to_camera(world: np.ndarray, camera_height_mm: float) -> np.ndarray:
    return np.column_stack([world[:, 0], -world[:, 1], camera_height_mm - world[:, 2]])


def handmade_surfaces(scene: Scene, *, camera_height_mm: float) -> TrueSurfaces:
    """The true surfaces of a hand-made :class:`~replay.synth.scene.Scene`, camera frame (mm).

    Parts: their exact solids (:func:`solid_mesh`; spheres as closed forms). The bin: its CAD mesh
    at the scan's pose and scale (rim, drafted inner walls, floor, vertical outer walls) — or, when
    its walls bulge or it twists, the height field it was rendered from, over its outline and one
    grid step around. The table: the plane z = 0 over the whole grid.
    """
    from replay.presets import BIN
    from replay.synth.raytrace.meshes import bin_mesh

    verts: list[np.ndarray] = []
    tris: list[np.ndarray] = []
    n = 0

    def add(v: np.ndarray, t: np.ndarray) -> None:
        nonlocal n
        verts.append(_to_camera(v, camera_height_mm))
        tris.append(t + n)
        n += len(v)

    centres = []
    radius = 0.0
    prisms = []
    for part in scene.parts:
        if part.solid is None:
            raise ValueError("a placed part without its solid (made before replay.synth.surfaces)")
        prims = part.solid[0]
        if prims[0][0] == "sphere":
            centres.append(part.R @ prims[0][1] + part.centre_mm)
            radius = float(prims[0][2])
        else:
            prisms.append(part)
    for part, (v, t) in zip(prisms, solid_meshes([p.solid for p in prisms])):  # type: ignore[misc]  # each checked above
        add(v @ part.R.T + part.centre_mm, t)
    g = scene.grid
    d = scene.deformation
    if not any(d.bulges_mm) and d.twist_mm == 0:
        m = bin_mesh(scene.bin_pose, d.geometry(BIN))
        add(m.vertices, m.triangles)
    else:
        add(*_bin_height_field_mesh(scene))
    x0, x1, y0, y1 = g.x0, g.x0 + g.step * (g.nx - 1), g.y0, g.y0 + g.step * (g.ny - 1)
    add(np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]]), np.array([[0, 1, 2], [0, 2, 3]]))
    return TrueSurfaces(np.concatenate(verts), np.concatenate(tris),
                        sphere_centres=_to_camera(np.array(centres), camera_height_mm) if centres else None,
                        sphere_radius=radius)


def _bin_height_field_mesh(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """The bin part of the scene's height field (``bin_height``) as triangles, world frame: the grid
    cells within the bin's outline grown by two steps (the renderer's own triangulation)."""
    from replay.presets import BIN

    g = scene.grid
    geo = scene.deformation.geometry(BIN)
    pose = scene.bin_pose
    half = np.hypot(geo.outer_length_mm, geo.outer_width_mm) / 2 + 2 * g.step
    j0 = max(int(np.floor((pose.x_mm - half - g.x0) / g.step)), 0)
    j1 = min(int(np.ceil((pose.x_mm + half - g.x0) / g.step)) + 1, g.nx)
    i0 = max(int(np.floor((pose.y_mm - half - g.y0) / g.step)), 0)
    i1 = min(int(np.ceil((pose.y_mm + half - g.y0) / g.step)) + 1, g.ny)
    Z = scene.bin_height[i0:i1, j0:j1]
    X, Y = np.meshgrid(g.xs[j0:j1], g.ys[i0:i1])
    v = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    ny, nx = Z.shape
    a = (np.arange(ny - 1)[:, None] * nx + np.arange(nx - 1)[None, :]).ravel()
    t = np.concatenate([np.c_[a, a + 1, a + nx + 1], np.c_[a, a + nx + 1, a + nx]])
    return v, t
