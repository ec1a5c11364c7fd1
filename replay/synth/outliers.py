"""Sensor errors with exact ground truth, applied to a rendered depth image (camera z, millimetres).

Kinds of true outliers, with the codes of ``/ground_truth/outlier_kind`` (docs/formats.md,
:data:`replay.logs.layout.OUTLIER_KINDS`):

- ``OUTLIER_FLOATING`` (1): multipath / specular ghosts, ragged patches of one to thousands of
  pixels (both sides of the paper's area threshold) on parts at every depth of the pile, displaced
  toward the camera, with a depth texture of their own (tilt, scatter, holes). Half are displaced
  from the nearest surface around them (they float above it), half from the surface right under
  them only (beside a higher part they do not float, in the z-cut's sense);
- ``OUTLIER_SPIKE_UP`` / ``OUTLIER_SPIKE_DOWN`` (2 / 3): isolated pixels displaced along the ray
  toward / away from the camera;
- ``OUTLIER_FLYING`` (4): mixed pixels at depth edges, interpolated between the foreground and the
  background depth;
- ``OUTLIER_ABOVE_RIM`` (5): sparse groups of ghost points over the bin's opening, higher than its
  rim (the paper's Figure 3a: the outliers a depth threshold removes).

Not outliers, but traps for a filter: specular dropouts (NaN blobs, and the saturated highlights),
and the paper's Figure-11 patches, small pieces of real surface fully surrounded by NaN, made at a
calibrated rate; the renderer's own NaN-fenced slivers are removed first
(:func:`drop_steep_fragments`, :func:`drop_surface_fragments`, :func:`heal_islands`).
Where every number comes from: ``docs/synthetic.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from scipy import ndimage

from replay.logs.layout import OUTLIER_KINDS

_CODE = {name: code for code, name in OUTLIER_KINDS.items()}
OUTLIER_NONE = 0
OUTLIER_FLOATING = _CODE["floating"]
OUTLIER_SPIKE_UP = _CODE["spike_up"]
OUTLIER_SPIKE_DOWN = _CODE["spike_down"]
OUTLIER_FLYING = _CODE["flying"]
OUTLIER_ABOVE_RIM = _CODE["above_rim"]


@dataclass(frozen=True, slots=True)
class OutlierRates:
    """How much goes wrong on one kind of surface (per frame / per pixel / per edge pixel).

    Attributes
    ----------
    clusters : float
        Mean number of floating clusters per frame (Poisson).
    cluster_rho : tuple of float
        Range of cluster area relative to the part's largest face ``a_max`` (log-uniform).
    cluster_offset_mm : tuple of float
        Range of the displacement toward the camera (log-uniform).
    attached_fraction : float
        Fraction of clusters displaced from the surface right under them rather than from
        everything around them.
    roughness_mm : tuple of float
        Range of a cluster's own depth scatter, pixel to pixel (log-uniform; added to the
        sensor's noise).
    hole_fraction : float
        Largest share of a cluster's pixels that read NaN (uniform in [0, hole_fraction]).
    spike_prob : float
        Probability that a valid part pixel is a spike.
    spike_up_fraction : float
        Share of spikes displaced toward the camera.
    flying_prob : float
        Probability that a background pixel at a depth edge is a mixed (flying) pixel.
    dropouts : float
        Mean number of specular dropout blobs (NaN) per frame.
    above_rim : float
        Mean number of groups of points above the rim per frame (Poisson).
    above_rim_mm : tuple of float
        Range of a group's height above the rim (log-uniform).
    above_rim_rho : tuple of float
        Range of a group's area relative to ``a_max`` (log-uniform; before its holes).
    figure11 : float
        Mean number of Figure-11 patches per frame (Poisson).
    """

    clusters: float
    cluster_rho: tuple[float, float]
    cluster_offset_mm: tuple[float, float]
    attached_fraction: float
    roughness_mm: tuple[float, float]
    hole_fraction: float
    spike_prob: float
    spike_up_fraction: float
    flying_prob: float
    dropouts: float
    above_rim: float
    above_rim_mm: tuple[float, float]
    above_rim_rho: tuple[float, float]
    figure11: float


SHINY_RATES = OutlierRates(
    clusters=60.0, cluster_rho=(0.002, 0.15), cluster_offset_mm=(1.0, 15.0), attached_fraction=0.5,
    roughness_mm=(0.03, 1.5), hole_fraction=0.4, spike_prob=3e-4, spike_up_fraction=0.85, flying_prob=0.3,
    dropouts=30.0, above_rim=6.0, above_rim_mm=(10.0, 100.0), above_rim_rho=(0.0005, 0.05), figure11=0.5,
)
MATTE_RATES = OutlierRates(
    clusters=3.0, cluster_rho=(0.002, 0.1), cluster_offset_mm=(1.0, 8.0), attached_fraction=0.5,
    roughness_mm=(0.03, 1.0), hole_fraction=0.4, spike_prob=2e-5, spike_up_fraction=0.85, flying_prob=0.05,
    dropouts=3.0, above_rim=0.3, above_rim_mm=(10.0, 100.0), above_rim_rho=(0.0005, 0.02), figure11=0.5,
)
FLYING_MIN_JUMP_MM = 3.0
#: a ghost pixel lies at least this much (plus three noise sigmas) in front of its own surface
MIN_SEPARATION_MM = 0.5
#: points above the rim are at least this much higher than its top (the pipeline's rim offset is 5 mm)
ABOVE_RIM_MIN_MM = 6.0
#: NaN-fenced islands of the renderer smaller than this share of ``a_max`` are removed
HEAL_RHO = 0.15
#: a view more grazing than this (camera or projector) is steep (see :func:`drop_steep_fragments`)
STEEP_DEG = 65.0

_EIGHT = np.ones((3, 3), bool)


def blob(shape: tuple[int, int], centre: tuple[int, int], area_px: float,
         rng: np.random.Generator) -> tuple[slice, slice, np.ndarray]:
    """A random compact blob of about ``area_px`` pixels around ``centre`` (row, col).

    Returns
    -------
    rows, cols : slice
        Window in the image.
    mask : (h, w) bool ndarray
        The blob inside the window (always contains the centre pixel).
    """
    radius = np.sqrt(max(area_px, 1.0) / np.pi)
    ecc = rng.uniform(1.0, 2.5)
    a, b = radius * np.sqrt(ecc), radius / np.sqrt(ecc)
    theta = rng.uniform(0, np.pi)
    amps = rng.uniform(0.0, 0.15, 3)
    phases = rng.uniform(0, 2 * np.pi, 3)
    half = int(np.ceil(1.5 * a)) + 1
    r0, c0 = centre
    rows = slice(max(r0 - half, 0), min(r0 + half + 1, shape[0]))
    cols = slice(max(c0 - half, 0), min(c0 + half + 1, shape[1]))
    dv, du = np.mgrid[rows, cols]
    dv = dv - r0
    du = du - c0
    x = du * np.cos(theta) + dv * np.sin(theta)
    y = -du * np.sin(theta) + dv * np.cos(theta)
    phi = np.arctan2(y, x)
    rho = 1.0 + sum(amps[k] * np.cos((k + 2) * phi + phases[k]) for k in range(3))
    mask = (x / a) ** 2 + (y / b) ** 2 <= rho**2
    mask[r0 - rows.start, c0 - cols.start] = True
    return rows, cols, mask


def log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    """One draw, uniform in log between ``lo`` and ``hi``."""
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _pick(rng: np.random.Generator, candidates: np.ndarray, shape: tuple[int, int]) -> tuple[int, int] | None:
    if candidates.size == 0:
        return None
    k = int(candidates[rng.integers(candidates.size)])
    return divmod(k, shape[1])


def specular_dropouts(valid: np.ndarray, where: np.ndarray, *, count: int, a_max_px: float, rng: np.random.Generator) -> None:
    """Set ``count`` NaN blobs (``valid`` = False, in place) centred on ``where`` pixels."""
    cand = np.flatnonzero(where)
    for _ in range(count):
        c = _pick(rng, cand, valid.shape)
        if c is None:
            return
        rows, cols, m = blob(valid.shape, c, log_uniform(rng, 0.01, 0.3) * a_max_px, rng)
        valid[rows, cols][m] = False


def heal_islands(valid: np.ndarray, *, max_px: float) -> int:
    """Invalidate (in place) every 8-connected island of valid pixels smaller than ``max_px``.

    The renderer's hard shadow and obliquity limits cut hundreds of slivers of real surface free
    per frame; a sensor's own filtering and its softer limits leave far fewer (the paper's §5.4
    saw about none). Removing them leaves the Figure-11 traps to :func:`figure11_patches`, whose
    rate is set explicitly.

    Parameters
    ----------
    valid : (H, W) bool ndarray
        Measured pixels; updated in place.
    max_px : float
        Islands of fewer pixels are removed.

    Returns
    -------
    int
        Number of pixels invalidated.
    """
    labels, n = ndimage.label(valid, structure=_EIGHT)
    if n == 0:
        return 0
    area = np.bincount(labels.ravel(), minlength=n + 1)
    small = area < max_px
    small[0] = False
    drop = small[labels]
    valid[drop] = False
    return int(drop.sum())


def drop_steep_fragments(
    valid: np.ndarray, cosine: np.ndarray, depth_mm: np.ndarray, surface_id: np.ndarray, *, steep_cos: float
) -> int:
    """Invalidate (in place) steep valid pixels that do not continue a firmly measured face downhill.

    A pixel is steep when ``cosine`` (the grazing cosine of the camera or projector view) is below
    ``steep_cos``. A steep pixel is kept when a path of valid pixels of its own surface (equal
    ``surface_id``) leads to it from a non-steep one without ever rising (``depth_mm``, the
    noise-free camera z, never decreasing along it). On the renderer's faceted height field the
    hard obliquity limit flickers along part flanks and leaves steep fragments whose uphill
    neighbours are NaN: each is higher than every valid pixel around it, a trap for the z-cut
    (paper Figure 11). A real sensor's validity falls off smoothly with the angle, so its steep
    points continue the face above them; the paper saw almost no such traps (§5.4).

    Parameters
    ----------
    valid : (H, W) bool ndarray
        Measured pixels; updated in place.
    cosine : (H, W) float ndarray
        Grazing cosine of each pixel (:func:`replay.synth.sensor.measure`).
    depth_mm : (H, W) float ndarray
        Noise-free camera z of each pixel's surface.
    surface_id : (H, W) int ndarray
        Which surface each pixel shows (a part, or one kind of bin surface).
    steep_cos : float
        Pixels with a smaller cosine are steep.

    Returns
    -------
    int
        Number of pixels invalidated.
    """
    sid = np.ascontiguousarray(surface_id, dtype=np.int64)
    return int(_drop_steep(valid, np.ascontiguousarray(cosine, np.float32), np.ascontiguousarray(depth_mm, np.float64),
                           sid, float(steep_cos)))


@numba.njit(cache=True, nogil=True)
def _drop_steep(valid, cosine, depth, sid, steep_cos):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    H, W = valid.shape
    reached = np.zeros((H, W), np.bool_)
    stack = np.empty(H * W, np.int64)
    top = 0
    for r in range(H):
        for c in range(W):
            if valid[r, c] and cosine[r, c] >= steep_cos:
                reached[r, c] = True
                stack[top] = r * W + c
                top += 1
    while top > 0:
        top -= 1
        k = stack[top]
        r, c = k // W, k % W
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                rr, cc = r + dr, c + dc
                if rr < 0 or cc < 0 or rr >= H or cc >= W or reached[rr, cc] or not valid[rr, cc]:
                    continue
                if sid[rr, cc] != sid[r, c] or depth[rr, cc] < depth[r, c]:
                    continue
                reached[rr, cc] = True
                stack[top] = rr * W + cc
                top += 1
    dropped = 0
    for r in range(H):
        for c in range(W):
            if valid[r, c] and not reached[r, c]:
                valid[r, c] = False
                dropped += 1
    return dropped


def drop_surface_fragments(valid: np.ndarray, surface_id: np.ndarray, *, max_px: float) -> int:
    """Invalidate (in place) the small pieces of a surface cut off from its main visible region.

    The valid pixels of one surface (equal ``surface_id``: a part, or one kind of bin surface) fall
    into 8-connected pieces; every piece but the surface's largest one that is smaller than
    ``max_px`` pixels is removed. On the renderer's faceted height field the hard obliquity and
    shadow limits leave many such slivers on steep flanks and in creases, each fenced off by NaN
    from the face it continues (a trap for the z-cut, paper Figure 11); a real sensor's validity
    falls off smoothly, and the paper saw almost none of these traps (§5.4).

    Parameters
    ----------
    valid : (H, W) bool ndarray
        Measured pixels; updated in place.
    surface_id : (H, W) int ndarray
        Which surface each pixel shows.
    max_px : float
        Pieces of fewer pixels (other than each surface's largest) are removed.

    Returns
    -------
    int
        Number of pixels invalidated.
    """
    sid = np.ascontiguousarray(surface_id, dtype=np.int64)
    sid = sid - sid.min()
    return int(_drop_fragments(valid, sid, float(max_px)))


@numba.njit(cache=True, nogil=True)
def _find(parent, x):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    while parent[x] != x:
        parent[x] = parent[parent[x]]
        x = parent[x]
    return x


@numba.njit(cache=True, nogil=True)
def _drop_fragments(valid, sid, max_px):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover - numba
    H, W = valid.shape
    parent = np.arange(H * W)
    for r in range(H):
        for c in range(W):
            if not valid[r, c]:
                continue
            i = r * W + c
            for dr, dc in ((-1, -1), (-1, 0), (-1, 1), (0, -1)):
                rr, cc = r + dr, c + dc
                if rr < 0 or cc < 0 or cc >= W or not valid[rr, cc] or sid[rr, cc] != sid[r, c]:
                    continue
                a, b = _find(parent, i), _find(parent, rr * W + cc)
                if a != b:
                    if a < b:
                        parent[b] = a
                    else:
                        parent[a] = b
    area = np.zeros(H * W, np.int64)
    for r in range(H):
        for c in range(W):
            if valid[r, c]:
                area[_find(parent, r * W + c)] += 1
    best = np.full(sid.max() + 1, -1)
    for i in range(H * W):
        if area[i] > 0:
            s = sid[i // W, i % W]
            if best[s] < 0 or area[i] > area[best[s]]:
                best[s] = i
    dropped = 0
    for r in range(H):
        for c in range(W):
            if valid[r, c]:
                root = parent[r * W + c]
                if root != best[sid[r, c]] and area[root] < max_px:
                    valid[r, c] = False
                    dropped += 1
    return dropped


def figure11_patches(
    valid: np.ndarray, where: np.ndarray, *, count: int, a_max_px: float, ring_px: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Cut ``count`` real-surface patches free: a NaN ring around each (``valid`` in place).

    Patch areas are log-uniform in [0.01, 0.6]·a_max (the paper's Figure 11 shows two, at
    ρ ≈ 0.063 and ρ ≈ 0.51).

    Returns
    -------
    patches : (H, W) bool ndarray
        Valid pixels of the patches (real surface, NOT outliers).
    keep_out : (H, W) bool ndarray
        Patches, rings and a margin, where no outlier may be placed.
    """
    H, W = valid.shape
    patches = np.zeros((H, W), bool)
    keep_out = np.zeros((H, W), bool)
    margin = ring_px + 3
    inner = np.zeros((H, W), bool)
    inner[margin:H - margin, margin:W - margin] = True
    cand = np.flatnonzero(where & valid & inner)
    tries = 0
    made = 0
    while made < count and tries < 20 * count:
        tries += 1
        c = _pick(rng, cand, (H, W))
        if c is None:
            break
        rows, cols, m = blob((H, W), c, log_uniform(rng, 0.01, 0.6) * a_max_px, rng)
        pad = 2 * margin + 3
        r0, r1 = max(rows.start - pad, 0), min(rows.stop + pad, H)
        c0, c1 = max(cols.start - pad, 0), min(cols.stop + pad, W)
        win = (slice(r0, r1), slice(c0, c1))
        full = np.zeros((r1 - r0, c1 - c0), bool)
        full[rows.start - r0:rows.stop - r0, cols.start - c0:cols.stop - c0] = m
        full &= valid[win] & where[win] & inner[win]
        if not full.any() or (keep_out[win] & ndimage.binary_dilation(full, _EIGHT, iterations=margin)).any():
            continue
        grown = ndimage.binary_dilation(full, _EIGHT, iterations=ring_px)
        ring = grown & ~full
        valid[win][ring] = False
        patches[win] |= full
        keep_out[win] |= ndimage.binary_dilation(grown, _EIGHT, iterations=3)
        made += 1
    return patches, keep_out


def flying_pixels(
    depth: np.ndarray,
    clean: np.ndarray,
    valid: np.ndarray,
    allowed: np.ndarray,
    slope_step_mm: np.ndarray,
    *,
    prob: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """Turn background pixels at depth edges into mixed pixels (``depth`` in place).

    A pixel is a candidate when a 4-neighbour is valid and nearer, in the clean depth, by more than
    ``FLYING_MIN_JUMP_MM`` and more than three times ``slope_step_mm`` (the depth change from one
    pixel to the next that the pixel's own surface slope explains): an occlusion edge, not a steep
    surface. A chosen one gets ``fg + f * (bg - fg)``, f ~ U(0.2, 0.8).

    Returns
    -------
    (H, W) bool ndarray of the flying pixels.
    """
    H, W = depth.shape
    fg = np.full((H, W), np.inf)
    z = np.where(valid, clean, np.inf)
    for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        src_r = slice(max(dr, 0), H + min(dr, 0))
        dst_r = slice(max(-dr, 0), H + min(-dr, 0))
        src_c = slice(max(dc, 0), W + min(dc, 0))
        dst_c = slice(max(-dc, 0), W + min(-dc, 0))
        np.minimum(fg[dst_r, dst_c], z[src_r, src_c], out=fg[dst_r, dst_c])
    with np.errstate(invalid="ignore"):
        jump = clean - fg  # NaN / -inf where either is not finite: never a candidate
        cand = valid & allowed & (jump > FLYING_MIN_JUMP_MM) & (jump > 3.0 * slope_step_mm) & np.isfinite(jump)
    idx = np.flatnonzero(cand)
    idx = idx[rng.random(idx.size) < prob]
    f = rng.uniform(0.2, 0.8, idx.size)
    flat = depth.reshape(-1)
    flat[idx] = fg.reshape(-1)[idx] + f * jump.reshape(-1)[idx]
    pick = np.zeros((H, W), bool)
    pick.reshape(-1)[idx] = True
    return pick


def spikes(
    depth: np.ndarray, valid: np.ndarray, where: np.ndarray, *, prob: float, up_fraction: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Displace random single pixels along the ray by 1-8 mm (``depth`` in place).

    Returns
    -------
    up, down : (H, W) bool ndarray
        Spikes toward the camera and away from it.
    """
    cand = np.flatnonzero(valid & where)
    n = int(rng.binomial(cand.size, prob)) if cand.size else 0
    up = np.zeros(depth.shape, bool)
    down = np.zeros(depth.shape, bool)
    if n == 0:
        return up, down
    idx = rng.choice(cand, size=n, replace=False)
    toward = rng.random(n) < up_fraction
    mag = np.exp(rng.uniform(np.log(1.0), np.log(8.0), n))
    flat = depth.reshape(-1)
    flat[idx] += np.where(toward, -mag, mag)
    up.reshape(-1)[idx[toward]] = True
    down.reshape(-1)[idx[~toward]] = True
    return up, down


def _window(shape: tuple[int, int], rows: slice, cols: slice, pad: int) -> tuple[slice, slice]:
    return (slice(max(rows.start - pad, 0), min(rows.stop + pad, shape[0])),
            slice(max(cols.start - pad, 0), min(cols.stop + pad, shape[1])))


def _ghost_depth(
    M: np.ndarray, base_mm: float, offset_mm: float, sigma_mm: np.ndarray, roughness_mm: float, rng: np.random.Generator
) -> np.ndarray:
    """Depths of the ``M`` pixels of a ghost: ``base - offset``, a tilt that only brings parts of it
    nearer (up to half the offset), and scatter (the sensor's sigma and the ghost's roughness)."""
    rr, cc = np.nonzero(M)
    psi = rng.uniform(0, 2 * np.pi)
    proj = (rr - rr.mean()) * np.sin(psi) + (cc - cc.mean()) * np.cos(psi)
    extent = max(float(np.ptp(proj)), 1.0)
    tilt = rng.uniform(0.0, 0.5) * offset_mm * (proj - proj.min()) / extent
    scatter = np.sqrt(sigma_mm[M] ** 2 + roughness_mm**2)
    depth: np.ndarray = base_mm - offset_mm - tilt + rng.normal(0.0, 1.0, rr.size) * scatter
    return depth


def floating_clusters(
    depth: np.ndarray,
    clean: np.ndarray,
    valid: np.ndarray,
    where: np.ndarray,
    allowed: np.ndarray,
    sigma_mm: np.ndarray,
    *,
    count: int,
    rates: OutlierRates,
    a_max_px: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """Paint ``count`` ghost clusters into ``depth`` / ``valid`` (in place).

    Each cluster is a blob centred on a ``where`` pixel (any visible part, at any depth), clipped to
    ``allowed``, not touching an earlier cluster (a blob that would is redrawn, up to ``3 * count``
    draws). Its reference depth is the nearest surface among the blob's own pixels and its
    one-pixel ring, or, for an "attached" cluster, the nearest surface right under it. It lies
    ``offset`` mm in front of that, tilted, with its own roughness; a random share of its pixels
    read NaN (holes), and a pixel that would come within :data:`MIN_SEPARATION_MM` plus three noise
    sigmas of its own real surface is left alone (the ghost dips into the surface there).

    Returns
    -------
    (H, W) int32 ndarray: 1-based cluster index, 0 elsewhere.
    """
    H, W = depth.shape
    ids = np.zeros((H, W), np.int32)
    cand = np.flatnonzero(where & allowed)
    lo, hi = rates.cluster_rho
    k = 0
    for _ in range(3 * count):
        if k == count:
            break
        c = _pick(rng, cand, (H, W))
        if c is None:
            break
        rows, cols, m = blob((H, W), c, log_uniform(rng, lo, hi) * a_max_px, rng)
        win = _window((H, W), rows, cols, 1)
        M = np.zeros((win[0].stop - win[0].start, win[1].stop - win[1].start), bool)
        M[rows.start - win[0].start:rows.stop - win[0].start, cols.start - win[1].start:cols.stop - win[1].start] = m
        M &= allowed[win]
        if not M.any() or (ids[win] > 0).any():
            continue  # clusters do not touch each other (each has its own ring)
        k += 1
        win_depth, win_valid, win_clean = depth[win], valid[win], clean[win]
        under = win_clean[M]
        attached = rng.random() < rates.attached_fraction
        offset = log_uniform(rng, *rates.cluster_offset_mm)
        roughness = log_uniform(rng, *rates.roughness_mm)
        holes = rng.uniform(0.0, rates.hole_fraction)
        if attached:
            ref = float(under.min())
        else:
            ring = ndimage.binary_dilation(M, _EIGHT) & ~M
            near = win_depth[ring & win_valid]
            ref = float(min(under.min(), near.min() if near.size else np.inf))
        sig = sigma_mm[win]
        z = _ghost_depth(M, ref, offset, sig, roughness, rng)
        hole = rng.random(z.size) < holes
        keep = ~hole & (z <= under - MIN_SEPARATION_MM - 3.0 * sig[M])
        rr, cc = np.nonzero(M)
        win_valid[rr[hole], cc[hole]] = False
        rr, cc = rr[keep], cc[keep]
        win_depth[rr, cc] = z[keep]
        win_valid[rr, cc] = True
        ids[win][rr, cc] = k
    return ids


def above_rim_groups(
    depth: np.ndarray,
    valid: np.ndarray,
    where: np.ndarray,
    allowed: np.ndarray,
    sigma_mm: np.ndarray,
    *,
    count: int,
    rates: OutlierRates,
    a_max_px: float,
    rim_depth_mm: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """Paint ``count`` sparse groups of ghost points higher than the rim (``depth`` / ``valid`` in place).

    A group is a blob centred on a ``where`` pixel (inside the bin's opening), its points
    ``log_uniform(above_rim_mm)`` above the rim's top (camera depth ``rim_depth_mm``), tilted and
    rough like a floating cluster, with up to 80 % of its pixels reading NaN (scattered dots in a
    patch the sensor could not decode, rather than a solid patch); none comes within
    :data:`ABOVE_RIM_MIN_MM` of the rim's height.

    Returns
    -------
    (H, W) bool ndarray of the points placed.
    """
    H, W = depth.shape
    out = np.zeros((H, W), bool)
    cand = np.flatnonzero(where & allowed)
    lo, hi = rates.above_rim_rho
    for _ in range(count):
        c = _pick(rng, cand, (H, W))
        if c is None:
            break
        rows, cols, m = blob((H, W), c, log_uniform(rng, lo, hi) * a_max_px, rng)
        M = m & allowed[rows, cols]
        if not M.any():
            continue
        rise = log_uniform(rng, *rates.above_rim_mm)
        roughness = log_uniform(rng, *rates.roughness_mm)
        holes = rng.uniform(0.0, 0.8)
        z = _ghost_depth(M, rim_depth_mm, rise, sigma_mm[rows, cols], roughness, rng)
        hole = rng.random(z.size) < holes
        keep = ~hole & (z <= rim_depth_mm - ABOVE_RIM_MIN_MM)
        rr, cc = np.nonzero(M)
        rr, cc = rr + rows.start, cc + cols.start
        valid[rr[hole], cc[hole]] = False
        rr, cc = rr[keep], cc[keep]
        depth[rr, cc] = z[keep]
        valid[rr, cc] = True
        out[rr, cc] = True
    return out
