"""Did the bin removal work on this frame? A per-frame figure and a flag (``docs/pipeline.md``).

The registration's fitness does not answer it: it scores the model's rim against the frame within
the fine correspondence distance (3.3 mm by default) and stays at 1.000 with a pose 2 mm off,
where the paper's removal (δ = 0.1 mm) leaves the whole rim in the zone. What breaks the filters is
narrower and can be seen directly: the bin pixels the removal did not explain, where they matter.

The figure counts the frame's *certain bin pixels* — the rim and upper walls the registration was
given (:func:`zcut.binmask.bin_pixels`: bright plastic along the footprint's border; the pile, lying
below the rim and in from the walls, never reaches them) — that the removal left

- in the zone within the z-cut's depth below the zone's top (where the z-cut and SOR look: one such
  pixel above the pile moves the zone's top up to it, and the z-cut, which looks only ``d_max``
  down from the top, no longer reaches the pile), or
- labelled as points above the rim (flagged as outliers by both filters: a tilted pose lifts one
  end of the real rim above the model's),

and that lie on the bin's surface: given the model and its pose, a pixel counts only when its
residual to the model is finite (within ``max_tolerance_mm``) and coherent with its ring neighbours'
(:func:`zcut.removal.coherent_residuals`: within ``COHERENCE_MM`` of their median). A rim pixel
left behind — by a pose a little off, a model with a hole — lies on the surface its neighbours
form, and counts; a sensor's ghost floating above the rim or a mixed pixel along its edge (the
ray-traced sensor's shiny frames have hundreds on the rim, in clusters) lies millimetres off it, and
does not. A coherent pixel counts only when it lies, too, on the surface the registered bin forms:
its signed residual within ``COHERENCE_MM`` of the residual field a small pose error and a model of a
slightly different size make over the whole ring (:func:`residual_field`, seven numbers fitted to the
ring's residuals). Bin left behind by a pose or a model a little off lies on that field; the face of a
part leaning on an upper wall, a few millimetres in front of it and coherent with its neighbours, does
not. A pixel off the field at its nearest model point still counts when the model has no
point on its line of sight (:meth:`ResidualField.modelled`): over a gap of the model (a wall a few empty
scans did not see) the nearest model point is on another face, the rim's top straight above, and the
model has nothing there to judge the pixel by; a part's face in front of a wall has the wall's model
behind it (issue 31: on piles heaped against a wall the check counted 14–39 such pixels a frame and flagged
every hand-made walls frame; ``docs/bin_robustness.md``). Pixels beyond ``max_tolerance_mm`` of the model (no residual) are judged by clumps: a
clump counts when the surface around it runs out to that distance (a neighbour's residual within
``COHERENCE_MM`` of it: the far end of a rim tilted by 2°); a ghost cluster above the rim, ringed by
pixels that fit the model or by other ghosts, does not (counting clumps with nothing finite around
them brought back 153 of the 197 ghosts of a ray-traced sphere frame). A pose so far off that the bin's own surface
lies beyond ``max_tolerance_mm`` is caught apart: the frame is flagged when more than
:data:`zcut.removal.MAX_FAR_SHARE` of its certain bin pixels lie that far among neighbours that do too
(:func:`zcut.removal.far_share`; the ray-traced ghost clusters are about 1 % of them on sphere frames).

A frame is flagged when the count exceeds ``RemovalParams.check_threshold_px`` (0 by default:
measured on synthetic piles, a single such pixel at the zone's top cost the frame its whole z-cut
F1, and frames whose removal held had none; see ``docs/bin_robustness.md``), when fewer than
``check_min_ring_px`` certain bin pixels are in view or less than ``check_min_rim_in_view`` of the
model's rim lies in the camera's view (too little of the bin to say), or when the bin stages failed
(:func:`failed_bin_check`: no bin in the image, a registration that did not converge — an
occluded bin, a model of another bin, an empty model).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from .errors import InputShapeError, ParameterError, describe_array
from .params import RemovalParams
from .removal import (
    COHERENCE_MM,
    MAX_FAR_SHARE,
    MAX_RESIDUAL_PX,
    RemovalIndex,
    RemovalResult,
    _ZoneTop,
    coherent_residuals,
    far_share,
    fit_residual_field,
    surface_nearest,
    surface_residuals,
)
from .removal import field_design as _design
from .types import XYZ, Mask

__all__ = ["BinCheck", "ResidualField", "check_bin_removal", "failed_bin_check", "residual_field", "signed_residuals"]

#: What a user should do about a flagged frame, by cause.
ADVICE_LEAK = ("the bin model does not fit this frame's bin: look at image/bin_check in Rerun (zcut replay "
               "--rrd); if the model is of another bin or the bin changed, rebuild it from empty scans of this bin "
               "(zcut bin-model); if the registration is only a little off, raise removal.max_tolerance_mm")
ADVICE_PAPER = ("the paper's removal (removal.mode = \"paper\", δ = {delta:g} mm) needs a registration right to a "
                "tenth of a millimetre: use removal.mode = \"robust\" (the default) unless reproducing the paper")
ADVICE_HIDDEN = ("the bin is mostly hidden or out of view: this frame's figures rest on an unchecked removal; "
                 "leave it out or check it in Rerun")


@dataclass(frozen=True, slots=True)
class BinCheck:
    """The bin check of one frame.

    Attributes
    ----------
    value : float
        Certain bin pixels left where the filters judge or called above-the-rim outliers (pixels);
        NaN when the bin stages failed (nothing to count).
    threshold : float
        The frame is flagged when ``value`` exceeds it (``RemovalParams.check_threshold_px``).
    flagged : bool
    reason : str
        Why the frame is flagged and what to do ("" when not flagged).
    offending : (H, W) bool ndarray or None
        The pixels counted in ``value``; None when the bin stages failed.
    ghosts : int
        Candidates (certain bin pixels left in the band or above the rim) not counted: their residual
        to the model is not coherent with their neighbours' (a sensor's ghosts); 0 without a model.
    off_surface : int
        Candidates not counted because, coherent with their neighbours, they lie off the surface the
        registered bin forms: their signed residual misses the ring's residual field
        (:func:`residual_field`) by more than ``COHERENCE_MM`` (the face of a part leaning on a wall,
        a few millimetres in front of it), or, beyond ``max_tolerance_mm`` of the model in a clump
        whose surface runs out to there, the field does not reach that far at the clump (a part's
        face curving away from the wall); never when the model has no point on its line of sight (a gap
        of the model, :meth:`ResidualField.modelled`); 0 without a model or when the model has no normals.
    ring : (H, W) bool ndarray or None
        The certain bin pixels the check looked at; None when the bin stages failed.
    """

    value: float
    threshold: float
    flagged: bool
    reason: str
    offending: Mask | None = None
    ring: Mask | None = None
    ghosts: int = 0
    off_surface: int = 0


#: The model covers a pixel when one of its points is seen within this many pixel pitches of the
#: pixel's line of sight (a model built from scans at the frame's size has about one point per pixel).
COVER_PITCHES = 2.0


def _pixel_pitch(a: np.ndarray) -> float:
    """The angle (radians) between the lines of sight of neighbouring pixels of the organized cloud ``a``
    (the median over a sample of horizontally adjacent pixels with finite points). The distances are
    :func:`_pitch_distances`' (numpy's on float32 or float64 input, :func:`_pixel_pitch_numpy`: the same
    values, 3.8 -> ~0.5 CPU ms on 20k pairs)."""
    v = a.reshape(-1, 3)
    if v.dtype not in (np.float32, np.float64):
        return _pixel_pitch_numpy(a)
    w = a.shape[1]
    i = np.arange(0, len(v) - 1, max(1, len(v) // 20_000))
    i = i[(i % w) < w - 1]
    d = _pitch_distances(np.ascontiguousarray(v), i)
    if len(d) == 0:
        return float("inf")
    return float(np.median(d))


@numba.njit(cache=True, nogil=True, error_model="numpy")  # a zero point divides as numpy does: NaN
def _pitch_distances(v, i):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """``np.linalg.norm(p - q, axis=1)`` of the pairs ``v[i]``, ``v[i + 1]`` (float64) whose six coordinates are
    finite, each point divided by its ``np.linalg.norm`` first, as :func:`_pixel_pitch_numpy` computes them
    (its ``add.reduce`` over three values sums them in order; products, quotients and roots are IEEE's)."""
    out = np.empty(i.shape[0])
    m = 0
    for k in range(i.shape[0]):
        px = np.float64(v[i[k], 0])
        py = np.float64(v[i[k], 1])
        pz = np.float64(v[i[k], 2])
        qx = np.float64(v[i[k] + 1, 0])
        qy = np.float64(v[i[k] + 1, 1])
        qz = np.float64(v[i[k] + 1, 2])
        if not (np.isfinite(px) and np.isfinite(py) and np.isfinite(pz) and np.isfinite(qx) and np.isfinite(qy)
                and np.isfinite(qz)):
            continue
        npn = np.sqrt(px * px + py * py + pz * pz)
        nqn = np.sqrt(qx * qx + qy * qy + qz * qz)
        dx = px / npn - qx / nqn
        dy = py / npn - qy / nqn
        dz = pz / npn - qz / nqn
        out[m] = np.sqrt(dx * dx + dy * dy + dz * dz)
        m += 1
    return out[:m]


@numba.njit(cache=True, nogil=True, error_model="numpy")  # a zero row divides as numpy does: NaN
def _unit_rows(v):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """(N, 3) float64: ``v / np.linalg.norm(v, axis=1, keepdims=True)`` of an (N, 3) float64 array, the same values
    (numpy's norm sums the three squares in order, then takes the root; ~2 -> ~0.3 CPU ms on a model's 65k rows)."""
    out = np.empty_like(v)
    for i in range(v.shape[0]):
        x = v[i, 0]
        y = v[i, 1]
        z = v[i, 2]
        n = np.sqrt(x * x + y * y + z * z)
        out[i, 0] = x / n
        out[i, 1] = y / n
        out[i, 2] = z / n
    return out


def _pixel_pitch_numpy(a: np.ndarray) -> float:
    """:func:`_pixel_pitch` in numpy, as first written (the tests' oracle, and any input the kernel does not
    take)."""
    v = a.reshape(-1, 3).astype(np.float64)
    w = a.shape[1]
    i = np.arange(0, len(v) - 1, max(1, len(v) // 20_000))
    i = i[(i % w) < w - 1]
    p, q = v[i], v[i + 1]
    ok = np.isfinite(p).all(axis=1) & np.isfinite(q).all(axis=1)
    if not ok.any():
        return float("inf")
    p = p[ok] / np.linalg.norm(p[ok], axis=1, keepdims=True)
    q = q[ok] / np.linalg.norm(q[ok], axis=1, keepdims=True)
    return float(np.median(np.linalg.norm(p - q, axis=1)))


def signed_residuals(xyz: XYZ, pixels: np.ndarray, index: RemovalIndex, T_cam_bin: np.ndarray, *,
                     removal: RemovalResult | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(r, p, n)`` of the flat ``pixels``: the signed distance (m) of each point to the tangent plane of
    its nearest model point, along that point's normal (NaN where the point is not finite or no model
    point lies within ``max_tolerance_mm``), the point in the bin frame (m) and that normal (NaN rows).
    All NaN when the model has no normals. ``removal``: the frame's removal; the nearest model points of the
    pixels its frame tolerance queried are read from it (:func:`zcut.removal.surface_nearest`), not queried
    again (the same points)."""
    a = np.asarray(xyz)
    flat = np.asarray(pixels, dtype=np.int64)
    T = np.asarray(T_cam_bin, dtype=np.float64)
    m = len(flat)
    r = np.full(m, np.nan)
    p = np.full((m, 3), np.nan)
    n = np.full((m, 3), np.nan)
    model = index.model
    if m == 0 or len(model.points) == 0 or model.normals is None or index.tree is None:
        return r, p, n
    pts = a.reshape(-1, 3)[flat].astype(np.float64)
    ok = np.isfinite(pts).all(axis=1)
    p[ok] = (pts[ok] - T[:3, 3]) @ T[:3, :3]
    known = surface_nearest(removal, index, flat[ok], p[ok])
    if known is None:
        d, j = index.tree.query(p[ok], k=1, distance_upper_bound=index.params.max_tolerance_mm / 1000.0)
        hit = np.isfinite(d)
    else:
        j, hit = known, known >= 0
    found = np.flatnonzero(ok)[hit]
    jj = j[hit]
    n[found] = model.normals[jj]
    r[found] = np.einsum("ij,ij->i", p[found] - model.points[jj], n[found])
    return r, p, n


@dataclass(frozen=True, slots=True)
class ResidualField:
    """Where the registered bin's surface lies, seen through the model: the signed residual a small pose
    error and a model of a slightly different size make at each point of the bin.

    A pose off by a translation ``t`` and a small turn ``ω`` moves a bin point ``p`` by ``t + ω × p``, a
    model scaled by ``1 + s`` by ``s p``: the point's signed residual along the model's normal ``n`` is
    ``n·t + ω·(p × n) + s n·p``, seven numbers for the whole bin, fitted (least squares, trimmed to
    3 robust sigmas :data:`zcut.removal.FIELD_TRIMS` times) to the certain bin pixels' signed residuals (a regular
    subsample of at most :data:`zcut.removal.MAX_RESIDUAL_PX`). A bin pixel the removal left behind —
    the tail of a pose error the tolerance did not cover, a wall where the model has a hole — lies on
    that field; the face of a part leaning on a wall, a few millimetres in front of it, does not.

    Attributes
    ----------
    coef : (7,) float64 ndarray
        ``t`` (m), ``ω`` (rad), ``s``, about ``centre``.
    centre : (3,) float64 ndarray
        The fitted pixels' mean point (bin frame, m).
    sigma_mm : float
        The robust scale (1.4826 × MAD) of the kept pixels' misfit (mm).
    n_pixels : int
        Pixels fitted (after the trims).
    index : RemovalIndex
    T : (4, 4) float64 ndarray
        The registered pose.
    """

    coef: np.ndarray
    centre: np.ndarray
    sigma_mm: float
    n_pixels: int
    index: RemovalIndex
    T: np.ndarray

    def misfit_mm(self, xyz: XYZ, pixels: np.ndarray) -> np.ndarray:
        """(M,) float64: each pixel's signed residual minus the field's there (mm); NaN where the point
        is not finite or no model point lies within ``max_tolerance_mm``."""
        r, p, n = signed_residuals(np.asarray(xyz), np.asarray(pixels, dtype=np.int64), self.index, self.T)
        return 1000.0 * (r - _design(p, n, self.centre) @ self.coef)

    def predicted_mm(self, xyz: XYZ, pixels: np.ndarray) -> np.ndarray:
        """(M,) float64: the field's signed residual (mm) at each pixel's point, along the normal of its
        nearest model point however far (NaN where the point is not finite)."""
        a = np.asarray(xyz)
        flat = np.asarray(pixels, dtype=np.int64)
        out = np.full(len(flat), np.nan)
        pts = a.reshape(-1, 3)[flat].astype(np.float64)
        ok = np.isfinite(pts).all(axis=1)
        model = self.index.model
        if not ok.any() or model.normals is None or self.index.tree is None:
            return out
        p = (pts[ok] - self.T[:3, 3]) @ self.T[:3, :3]
        _, j = self.index.tree.query(p, k=1)
        out[ok] = 1000.0 * (_design(p, model.normals[j], self.centre) @ self.coef)
        return out

    def modelled(self, xyz: XYZ, pixels: np.ndarray) -> np.ndarray:
        """(M,) bool: the model has a point on the pixel's line of sight, in front of the pixel or behind
        it (seen within :data:`COVER_PITCHES` pixel pitches of it). Where it has none the model has nothing
        there to judge the pixel by: a wall a few empty scans did not see (a ray-traced 320 x 200 model from
        two scans lacks a whole upper wall, whose pixels' nearest model points are the rim's top above
        them); the face of a part in front of a wall has the wall's model behind it. True where the point
        is not finite."""
        a = np.asarray(xyz)
        flat = np.asarray(pixels, dtype=np.int64)
        out = np.ones(len(flat), bool)
        model = self.index.model
        pts = a.reshape(-1, 3)[flat].astype(np.float64)
        ok = np.isfinite(pts).all(axis=1)
        if not ok.any() or len(model.points) == 0:
            return out
        cam = model.points @ self.T[:3, :3].T + self.T[:3, 3]
        rays = _unit_rows(np.ascontiguousarray(cam, dtype=np.float64))  # cam / np.linalg.norm(cam, axis=1), bit for bit
        mine = pts[ok] / np.linalg.norm(pts[ok], axis=1, keepdims=True)
        out[ok] = _rays_within(rays, mine, COVER_PITCHES * _pixel_pitch(a))
        return out

    def fits(self, xyz: XYZ, pixels: np.ndarray) -> np.ndarray:
        """(M,) bool: the pixel lies on the field, within ``COHERENCE_MM`` (True where it has no residual:
        nothing to tell)."""
        e = self.misfit_mm(xyz, pixels)
        with np.errstate(invalid="ignore"):
            return ~(np.abs(e) > COHERENCE_MM)


def _rays_within(rays: np.ndarray, mine: np.ndarray, ub: float) -> np.ndarray:
    """(M,) bool: a row of ``rays`` (N, 3) lies within ``ub`` of each row of ``mine`` (M, 3), as
    ``np.isfinite(cKDTree(rays).query(mine, k=1, distance_upper_bound=ub)[0])`` says it (that tree's test: the
    squared distance, summed over x, y, z in that order, below ``ub * ub``), from a grid of the rays' x and y
    (:func:`_rays_grid`: cells at least ``ub`` wide, the 3 x 3 around each query; a frame's model is
    ~65k points at 640 x 480, whose tree took ~15 CPU ms to build for a few hundred queries). A query whose
    nearest squared distance lies within a relative 1e-9 of ``ub * ub`` (where the tree's pruning, summed in
    another order, might round the other way), and any input with a non-finite value, goes to the tree."""
    rays = np.ascontiguousarray(rays, dtype=np.float64)
    mine = np.ascontiguousarray(mine, dtype=np.float64)
    if len(mine) == 0:
        return np.zeros(0, bool)
    if len(rays) and np.isfinite(ub) and ub > 0 and np.isfinite(rays).all() and np.isfinite(mine).all():
        ub2 = ub * ub
        state = _rays_grid(rays, mine, ub, ub2 * (1.0 - 1e-9), ub2 * (1.0 + 1e-9))
        if (state < 2).all():
            return state == 1
        from scipy.spatial import cKDTree

        unsure = state == 2
        state[unsure] = np.isfinite(cKDTree(rays).query(mine[unsure], k=1, distance_upper_bound=ub)[0])
        return state == 1
    from scipy.spatial import cKDTree

    return np.isfinite(cKDTree(rays).query(mine, k=1, distance_upper_bound=ub)[0])


@numba.njit(cache=True, nogil=True)
def _rays_grid(rays, mine, ub, lo2, hi2):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """Per row of ``mine``: 1 when a row of ``rays`` lies at a squared distance below ``lo2`` (summed as the
    tree sums it), 0 when none lies below ``hi2``, 2 otherwise (unsure). A ray within ``ub`` of a query differs
    from it by less than ``ub`` in x and in y: the rays are binned by x and y in square cells at least ``ub``
    wide (wider when the rays' extent would need more cells than four per ray), and the 3 x 3 cells around the
    query's are searched."""
    n = rays.shape[0]
    x0 = rays[0, 0]
    x1 = x0
    y0 = rays[0, 1]
    y1 = y0
    for i in range(n):
        x0 = min(x0, rays[i, 0])
        x1 = max(x1, rays[i, 0])
        y0 = min(y0, rays[i, 1])
        y1 = max(y1, rays[i, 1])
    cell = 1.01 * ub
    cell = max(cell, np.sqrt((x1 - x0) * (y1 - y0) / (4.0 * n + 16.0)))
    nx = int((x1 - x0) / cell) + 1
    ny = int((y1 - y0) / cell) + 1
    key = np.empty(n, np.int64)
    start = np.zeros(nx * ny + 1, np.int64)
    for i in range(n):
        k = min(int((rays[i, 0] - x0) / cell), nx - 1) * ny + min(int((rays[i, 1] - y0) / cell), ny - 1)
        key[i] = k
        start[k + 1] += 1
    for k in range(nx * ny):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    order = np.empty(n, np.int64)
    for i in range(n):
        order[fill[key[i]]] = i
        fill[key[i]] += 1
    m = mine.shape[0]
    out = np.zeros(m, np.int8)
    for q in range(m):
        mx = mine[q, 0]
        my = mine[q, 1]
        mz = mine[q, 2]
        fx = (mx - x0) / cell
        fy = (my - y0) / cell
        if fx < -1.0 or fy < -1.0 or fx >= nx + 1.0 or fy >= ny + 1.0:
            continue  # farther than a cell from every ray in x or y
        cx = int(np.floor(fx))
        cy = int(np.floor(fy))
        state = 0
        for gx in range(max(cx - 1, 0), min(cx + 2, nx)):
            for gy in range(max(cy - 1, 0), min(cy + 2, ny)):
                k = gx * ny + gy
                for s in range(start[k], start[k + 1]):
                    i = order[s]
                    d = rays[i, 0] - mx
                    d2 = d * d
                    d = rays[i, 1] - my
                    d2 = d2 + d * d
                    d = rays[i, 2] - mz
                    d2 = d2 + d * d
                    if d2 < lo2:
                        state = 1
                        break
                    if d2 < hi2:
                        state = 2
                if state == 1:
                    break
            if state == 1:
                break
        out[q] = state
    return out


def residual_field(xyz: XYZ, ring: Mask, index: RemovalIndex, T_cam_bin: np.ndarray, *,
                   removal: RemovalResult | None = None) -> ResidualField | None:
    """The :class:`ResidualField` of a frame's certain bin pixels ``ring`` at the registered pose.

    ``removal``: the frame's removal, whose frame tolerance queried the same sample of ``ring`` (its nearest
    model points are read from it, :func:`signed_residuals`: the same field).

    None when the model has no normals, when fewer than :data:`zcut.removal.FIELD_MIN_PX` of the pixels have a model
    point within ``max_tolerance_mm``, or when the fit's misfit is too wide to tell a surface
    ``COHERENCE_MM`` off the bin's (3 robust sigmas beyond it): the residuals then form no such field —
    a pose several millimetres off, whose nearest model points lie on the wrong faces (the inner wall's
    pixels nearer the wall's outer face or the rim's top).
    """
    a = np.asarray(xyz)
    T = np.asarray(T_cam_bin, dtype=np.float64)
    flat = np.flatnonzero(np.asarray(ring, dtype=bool))
    flat = flat[:: max(1, -(-len(flat) // MAX_RESIDUAL_PX))]
    fit = fit_residual_field(*signed_residuals(a, flat, index, T, removal=removal))
    if fit is None:
        return None
    coef, centre, sigma, kept = fit
    return ResidualField(coef, centre, 1000.0 * sigma, kept, index, T)


@numba.njit(cache=True, nogil=True, inline="always")
def _root(parent, x):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """The root of ``x`` in the union-find ``parent``, halving the path on the way (not ``zcut.components.find_root``:
    that module loads SciPy's csgraph, which a replay never needs; tests/test_imports_light.py)."""
    while parent[x] != x:
        parent[x] = parent[parent[x]]
        x = parent[x]
    return x


@numba.njit(cache=True, nogil=True)
def _clumps(flat, H, W):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """(M,) int64: the 8-connected clump of each of the pixels ``flat`` (sorted flat indices of an H x W image),
    numbered from 1 in the order of their first pixel: the labels ``ndimage.label(image, np.ones((3, 3)))`` gives
    those pixels (the check used it on the whole frame: 5-6 CPU ms at 1920 x 1200 for a few hundred pixels), from a
    union-find over the pixels themselves (each joined to its neighbours before it in raster order, found by
    binary search)."""
    m = flat.shape[0]
    parent = np.arange(m)
    for i in range(m):
        q = flat[i]
        r = q // W
        c = q - r * W
        for k in range(4):  # the neighbours before it: up-left, up, up-right, left
            rr = r - 1 if k < 3 else r
            cc = c - 1 + k if k < 3 else c - 1
            if rr < 0 or cc < 0 or cc >= W:
                continue
            t = rr * W + cc
            j = np.searchsorted(flat[:i], t)
            if j < i and flat[j] == t:  # join the two clumps under the smaller root (each root its clump's first pixel)
                a = _root(parent, i)
                b = _root(parent, j)
                if a != b:
                    parent[max(a, b)] = min(a, b)
    out = np.empty(m, np.int64)
    name = np.zeros(m, np.int64)
    n = 0
    for i in range(m):
        a = _root(parent, i)
        if name[a] == 0:
            n += 1
            name[a] = n
        out[i] = name[a]
    return out


def failed_bin_check(reason: str, *, params: RemovalParams) -> BinCheck:
    """The check of a frame whose bin stages failed (no bin found, registration failed): flagged.

    Parameters
    ----------
    reason : str
        What failed and what to do, one line.
    params : RemovalParams
    """
    return BinCheck(float("nan"), float(params.check_threshold_px), True, reason, None)


@numba.njit(parallel=True, cache=True, nogil=True)
def _zone_top(zone, h):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """``(any zone pixel, np.max(h[zone]))``: NaN when some zone pixel's height is NaN (as ``np.max``)."""
    H, W = zone.shape
    top = np.full(H, -np.inf)
    seen = np.zeros(H, np.bool_)
    nan = np.zeros(H, np.bool_)
    for r in numba.prange(H):
        m = -np.inf
        for c in range(W):
            if zone[r, c]:
                v = h[r, c]
                seen[r] = True
                if np.isnan(v):
                    nan[r] = True
                elif v > m:
                    m = v
        top[r] = m
    best = -np.inf
    for r in range(H):
        if top[r] > best:
            best = top[r]
    return seen.any(), (np.nan if nan.any() else best)


@numba.njit(parallel=True, cache=True, nogil=True)
def _offending(ring, easy, zone, h, has_zone, threshold, out):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    """``out = ring & (easy | zone & (h >= threshold))`` (the zone term only with ``has_zone``); the counts of
    ``out`` and of ``ring & isfinite(h)`` per row."""
    H, W = ring.shape
    counts = np.zeros((H, 2), np.int64)
    for r in numba.prange(H):
        n = 0
        k = 0
        for c in range(W):
            o = False
            if ring[r, c]:
                o = easy[r, c] or (has_zone and zone[r, c] and h[r, c] >= threshold)
                if np.isfinite(h[r, c]):
                    k += 1
            out[r, c] = o
            n += o
        counts[r, 0] = n
        counts[r, 1] = k
    return counts


def _candidates(ring: Mask, easy: Mask, zone: Mask, h: np.ndarray, band_mm: float,
                known: _ZoneTop | None = None) -> tuple[Mask, int, int]:
    """The check's candidates, ``ring & easy | ring & zone & (h >= top - band_mm)`` with ``top`` the zone's
    highest height, their count and that of the ring's pixels with a finite height: two passes over the
    frame (the masks, the zone's boolean index and the counts in numpy were nine: 5.7 CPU ms at 1920 x 1200);
    one when the removal found the top as it wrote these very ``zone`` and ``h`` (``known``,
    :attr:`RemovalResult.zone_top`: 1.5-2 CPU ms less at 1920 x 1200)."""
    h = np.asarray(h)
    easy, zone = np.asarray(easy), np.asarray(zone)
    if h.dtype not in (np.float32, np.float64) or easy.dtype != np.bool_ or zone.dtype != np.bool_ \
            or not h.shape == easy.shape == zone.shape == ring.shape:
        return _candidates_numpy(ring, easy, zone, h, band_mm)
    has_zone, top = _zone_top(np.ascontiguousarray(zone), np.ascontiguousarray(h)) if known is None \
        or known.zone is not zone or known.height is not h else (known.seen, known.top)
    out = np.empty(ring.shape, bool)
    # numpy compares the heights with the Python float in their own type (NEP 50): so does the kernel
    threshold = h.dtype.type(float(top) - band_mm)
    counts = _offending(np.ascontiguousarray(ring), np.ascontiguousarray(easy), np.ascontiguousarray(zone),
                        np.ascontiguousarray(h), bool(has_zone), threshold, out)
    total = counts.sum(axis=0)
    return out, int(total[0]), int(total[1])


def _candidates_numpy(ring: Mask, easy: Mask, zone: Mask, h: np.ndarray, band_mm: float) -> tuple[Mask, int, int]:
    """:func:`_candidates` in numpy, as first written (the tests' oracle, and any input the kernels do not take)."""
    offending = ring & easy
    if zone.any():
        top = float(np.max(h[zone]))
        with np.errstate(invalid="ignore"):
            offending |= ring & zone & (h >= top - float(band_mm))
    return offending, int(np.count_nonzero(offending)), int(np.count_nonzero(ring & np.isfinite(h)))


def check_bin_removal(removal: RemovalResult, ring: Mask, *, params: RemovalParams, band_mm: float,
                      rim_in_view: float = 1.0, xyz: XYZ | None = None, index: RemovalIndex | None = None,
                      T_cam_bin: np.ndarray | None = None) -> BinCheck:
    """Count the certain bin pixels the removal left where they matter; flag the frame.

    Parameters
    ----------
    removal : RemovalResult
        The frame's removal (with a registered model).
    ring : (H, W) bool ndarray
        The frame's certain bin pixels (:func:`zcut.binmask.bin_pixels`).
    params : RemovalParams
        ``check_threshold_px``, ``check_min_ring_px``.
    band_mm : float
        How far below the zone's top the filters look (the z-cut's ``d_max``, mm, >= 0).
    rim_in_view : float
        The share of the registered model's rim in the camera's view (``n_rim`` of the
        registration over the model's rim points); below ``check_min_rim_in_view`` the frame is
        flagged.
    xyz, index, T_cam_bin : optional, all three or none
        The frame's points, the prepared model and its registered pose: a candidate pixel then
        counts only when its residual to the model is coherent with its neighbours' (not a ghost).
        Without them every candidate counts.

    Returns
    -------
    BinCheck
    """
    ring = np.asarray(ring)
    if ring.shape != removal.zone.shape or ring.dtype != np.bool_:
        raise InputShapeError(f"ring must be an {removal.zone.shape} bool array, got {describe_array(ring)}")
    if not (np.isfinite(band_mm) and band_mm >= 0):
        raise ParameterError(f"band_mm must be a number >= 0, got {band_mm!r}")
    if not 0.0 <= rim_in_view <= 1.0:
        raise ParameterError(f"rim_in_view must be a number in [0, 1], got {rim_in_view!r}")
    given = [v is not None for v in (xyz, index, T_cam_bin)]
    if any(given) and not all(given):
        raise ParameterError("check_bin_removal: xyz, index and T_cam_bin go together")
    zone = removal.zone
    h = removal.height_mm
    offending, n_offending, n_ring = _candidates(ring, removal.easy_outliers, zone, h, float(band_mm), removal.zone_top)
    ghosts = 0
    off_surface = 0
    far = 0.0
    if all(given):
        assert xyz is not None and index is not None and T_cam_bin is not None
        a = np.asarray(xyz)
        if a.shape[:2] != ring.shape:
            raise InputShapeError(f"xyz must be an {ring.shape} image of points, got {describe_array(a)}")
        res, around, _ = surface_residuals(a, ring, index, T_cam_bin, removal=removal)  # measured once
        far = far_share(res, around)
    if all(given) and n_offending:
        assert xyz is not None and index is not None and T_cam_bin is not None
        cand = np.flatnonzero(offending)
        own, around, coherent = coherent_residuals(a, ring, cand, index, T_cam_bin, neighbours=8)
        ghost = ~coherent  # off the surface its neighbours form
        beyond = np.isinf(own)
        off = np.zeros(len(cand), bool)
        field: ResidualField | None = None
        fitted = False
        if beyond.any():  # beyond max_tolerance_mm: by clumps, bin if the surface around runs out to there
            lab = _clumps(cand[beyond], ring.shape[0], ring.shape[1])
            near_reach = np.isfinite(around[beyond]) & (around[beyond] >= params.max_tolerance_mm - COHERENCE_MM)
            runs_out = np.bincount(lab, near_reach, int(lab.max()) + 1) > 0
            ghost[beyond] = ~runs_out[lab]
            if runs_out.any():
                # ... and when the bin's surface reaches that far there: the residual field says so (a part's
                # face curving away from a wall runs out to max_tolerance_mm too, where the field is ~0)
                field, fitted = residual_field(a, ring, index, T_cam_bin, removal=removal), True
                if field is not None:
                    reach = np.abs(field.predicted_mm(a, cand[beyond])) >= params.max_tolerance_mm - COHERENCE_MM
                    reach |= ~field.modelled(a, cand[beyond])  # over a gap of the model
                    reaches = np.bincount(lab, reach, int(lab.max()) + 1) > 0
                    off[np.flatnonzero(beyond)] = runs_out[lab] & ~reaches[lab]
        ghosts = int(np.count_nonzero(ghost))
        # coherent, finite: on a surface; but on the bin's only when that surface is where the pose's and
        # the model's error put the bin (the residual field fitted over the ring), not a part's face a few
        # millimetres in front of a wall it leans on
        test = ~ghost & np.isfinite(own)
        if test.any():
            if not fitted:
                field = residual_field(a, ring, index, T_cam_bin, removal=removal)
            if field is not None:
                at = np.flatnonzero(test)
                miss = ~field.fits(a, cand[at])
                at = at[miss]
                off[at] = field.modelled(a, cand[at])  # over a gap of the model: it counts, as before
        off_surface = int(np.count_nonzero(off))
        offending = offending.copy()
        offending.reshape(-1)[cand[ghost | off]] = False
    n = int(np.count_nonzero(offending)) if all(given) and n_offending else n_offending
    threshold = float(params.check_threshold_px)
    reasons = []
    if n > threshold:
        where = []
        n_easy = int(np.count_nonzero(offending & removal.easy_outliers))
        if n - n_easy:
            where.append(f"{n - n_easy} in the zone's top {band_mm:g} mm")
        if n_easy:
            where.append(f"{n_easy} called above the rim")
        if ghosts:
            where.append(f"{ghosts} more off the bin's surface, not counted: ghosts")
        if off_surface:
            where.append(f"{off_surface} more on a surface off the registered bin's, not counted: parts against "
                         "a wall")
        tol = f"tolerance {removal.tolerance_mm:.2f} mm"
        if np.isfinite(removal.residual_mm) or removal.residual_mm == np.inf:
            tol += f", residuals {removal.residual_mm:.2f} mm"
        advice = ADVICE_LEAK if params.robust else ADVICE_PAPER.format(delta=params.delta_mm)
        reasons.append(f"{n} of the bin's {n_ring} rim and upper-wall pixels not removed ({', '.join(where)}; {tol}): "
                       f"{advice}")
    if far > MAX_FAR_SHARE:
        reasons.append(f"{100 * far:.0f} % of the bin's rim and upper-wall pixels lie more than "
                       f"{params.max_tolerance_mm:g} mm from the registered model (> {100 * MAX_FAR_SHARE:.0f} %): "
                       f"{ADVICE_LEAK if params.robust else ADVICE_PAPER.format(delta=params.delta_mm)}")
    if n_ring < params.check_min_ring_px:
        reasons.append(f"only {n_ring} of the bin's rim and upper-wall pixels in view (< {params.check_min_ring_px}): "
                       f"{ADVICE_HIDDEN}")
    if rim_in_view < params.check_min_rim_in_view:
        reasons.append(f"only {100 * rim_in_view:.0f} % of the bin's rim in the camera's view "
                       f"(< {100 * params.check_min_rim_in_view:.0f} %): {ADVICE_HIDDEN}")
    return BinCheck(float(n), threshold, bool(reasons), "; ".join(reasons), offending, ring, ghosts, off_surface)
