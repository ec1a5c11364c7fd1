"""Sensor errors with exact ground truth, applied to a rendered depth image (camera z, millimetres).

Kinds of true outliers (values of the ``kind`` image):

- ``OUTLIER_CLUSTER``: multipath / specular ghosts on shiny parts, blobs of a few to hundreds of
  connected pixels floating in front of the surfaces around them by 1-12 mm (some are referenced
  to the surface right under them instead, so they may sit lower than a neighbouring surface in
  the image). They are centred on the exposed top layer (within ``TOP_ZONE_MM`` of the highest
  real part surface), where the projector and camera see the shiny parts most directly;
- ``OUTLIER_SPIKE``: isolated pixels displaced along the ray (mostly toward the camera);
- ``OUTLIER_FLYING``: mixed pixels at depth edges, interpolated between the foreground and the
  background depth.

Not outliers, but traps for a filter: specular dropouts (NaN blobs) and the paper's Figure-11
patches, small pieces of real surface fully surrounded by NaN.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

OUTLIER_NONE = 0
OUTLIER_CLUSTER = 1
OUTLIER_SPIKE = 2
OUTLIER_FLYING = 3


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
    spike_prob : float
        Probability that a valid part pixel is a spike.
    flying_prob : float
        Probability that a background pixel at a depth edge is a mixed (flying) pixel.
    dropouts : float
        Mean number of specular dropout blobs (NaN) per frame.
    """

    clusters: float
    cluster_rho: tuple[float, float]
    cluster_offset_mm: tuple[float, float]
    attached_fraction: float
    spike_prob: float
    flying_prob: float
    dropouts: float


SHINY_RATES = OutlierRates(60.0, (0.002, 0.1), (1.0, 12.0), 0.15, 3e-4, 0.3, 30.0)
MATTE_RATES = OutlierRates(3.0, (0.002, 0.03), (1.0, 8.0), 0.15, 2e-5, 0.05, 3.0)
TOP_ZONE_MM = 15.0  # ghost clusters arise among the exposed top layer of parts
FIG11_PATCHES = 4  # NaN-surrounded real patches per frame
FLYING_MIN_JUMP_MM = 3.0


def blob(shape: tuple[int, int], centre: tuple[int, int], area_px: float, rng: np.random.Generator):
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


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _pick(rng: np.random.Generator, candidates: np.ndarray, shape: tuple[int, int]) -> tuple[int, int] | None:
    if candidates.size == 0:
        return None
    k = int(candidates[rng.integers(candidates.size)])
    return divmod(k, shape[1])


_EIGHT = np.ones((3, 3), bool)


def specular_dropouts(valid: np.ndarray, where: np.ndarray, *, count: int, a_max_px: float, rng: np.random.Generator) -> None:
    """Set ``count`` NaN blobs (``valid`` = False, in place) centred on ``where`` pixels."""
    cand = np.flatnonzero(where)
    for _ in range(count):
        c = _pick(rng, cand, valid.shape)
        if c is None:
            return
        rows, cols, m = blob(valid.shape, c, _log_uniform(rng, 0.01, 0.3) * a_max_px, rng)
        valid[rows, cols][m] = False


def figure11_patches(
    valid: np.ndarray, where: np.ndarray, *, count: int, a_max_px: float, ring_px: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Cut ``count`` small real-surface patches free: a NaN ring around each (``valid`` in place).

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
        rows, cols, m = blob((H, W), c, _log_uniform(rng, 0.01, 0.6) * a_max_px, rng)
        pad = 2 * margin + 3
        r0, r1 = max(rows.start - pad, 0), min(rows.stop + pad, H)
        c0, c1 = max(cols.start - pad, 0), min(cols.stop + pad, W)
        win = (slice(r0, r1), slice(c0, c1))
        full = np.zeros((r1 - r0, c1 - c0), bool)
        full[rows.start - r0:rows.stop - r0, cols.start - c0:cols.stop - c0] = m
        full &= valid[win] & inner[win]
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
        nb = np.full((H, W), np.inf)
        src_r = slice(max(dr, 0), H + min(dr, 0))
        dst_r = slice(max(-dr, 0), H + min(-dr, 0))
        src_c = slice(max(dc, 0), W + min(dc, 0))
        dst_c = slice(max(-dc, 0), W + min(-dc, 0))
        nb[dst_r, dst_c] = z[src_r, src_c]
        fg = np.minimum(fg, nb)
    jump = np.where(np.isfinite(fg) & np.isfinite(clean), clean - np.where(np.isfinite(fg), fg, 0.0), 0.0)
    cand = valid & allowed & (jump > FLYING_MIN_JUMP_MM) & (jump > 3.0 * slope_step_mm)
    pick = cand & (rng.random((H, W)) < prob)
    f = rng.uniform(0.2, 0.8, (H, W))
    depth[pick] = fg[pick] + f[pick] * jump[pick]
    return pick


def spikes(
    depth: np.ndarray, valid: np.ndarray, where: np.ndarray, *, prob: float, rng: np.random.Generator
) -> np.ndarray:
    """Displace random single pixels along the ray (85 % toward the camera, 15 % away, by 1-8 mm).

    Returns
    -------
    (H, W) bool ndarray of the spikes.
    """
    cand = np.flatnonzero(valid & where)
    n = int(rng.binomial(cand.size, prob)) if cand.size else 0
    out = np.zeros(depth.shape, bool)
    if n == 0:
        return out
    idx = rng.choice(cand, size=n, replace=False)
    toward = rng.random(n) < 0.85
    mag = np.exp(rng.uniform(np.log(1.0), np.log(8.0), n))
    flat = depth.reshape(-1)
    flat[idx] += np.where(toward, -mag, mag)
    out.reshape(-1)[idx] = True
    return out


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

    Each cluster is a blob centred on a ``where`` pixel, clipped to ``allowed``, not touching an
    earlier cluster (a blob that would is redrawn, up to ``3 * count`` draws). Its reference depth
    is the nearest surface among the blob's own pixels and its one-pixel ring (or, for an
    "attached" cluster, the nearest surface right under it, ignoring the ring); it floats
    ``offset`` mm in front of that, with a gentle tilt that only brings parts of it nearer, plus
    depth noise. Every cluster pixel is thus in front of the real surface on its own ray.

    Returns
    -------
    (H, W) int32 ndarray: 1-based cluster index, 0 elsewhere (later clusters overwrite earlier ones).
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
        rows, cols, m = blob((H, W), c, _log_uniform(rng, lo, hi) * a_max_px, rng)
        # ring of one pixel around the blob, inside a one-pixel-padded window
        r0, r1 = max(rows.start - 1, 0), min(rows.stop + 1, H)
        c0, c1 = max(cols.start - 1, 0), min(cols.stop + 1, W)
        M = np.zeros((r1 - r0, c1 - c0), bool)
        M[rows.start - r0:rows.stop - r0, cols.start - c0:cols.stop - c0] = m
        M &= allowed[r0:r1, c0:c1]
        if not M.any() or (ids[r0:r1, c0:c1] > 0).any():
            continue  # clusters do not touch each other (each has its own ring)
        k += 1
        ring = ndimage.binary_dilation(M, _EIGHT) & ~M
        win_depth = depth[r0:r1, c0:c1]
        win_valid = valid[r0:r1, c0:c1]
        win_clean = clean[r0:r1, c0:c1]
        under = win_clean[M]
        under = under[np.isfinite(under)]
        if under.size == 0:
            continue
        if rng.random() < rates.attached_fraction:
            ref = float(under.min())
        else:
            near = win_depth[ring & win_valid]
            ref = float(min(under.min(), near.min() if near.size else np.inf))
        offset = _log_uniform(rng, *rates.cluster_offset_mm)
        rr, cc = np.nonzero(M)
        psi = rng.uniform(0, 2 * np.pi)
        proj = (rr - rr.mean()) * np.sin(psi) + (cc - cc.mean()) * np.cos(psi)
        extent = max(float(np.ptp(proj)), 1.0)
        tilt = rng.uniform(0.0, 0.5) * offset * (proj - proj.min()) / extent
        s = sigma_mm[r0:r1, c0:c1][M]
        z = ref - offset - tilt + rng.normal(0.0, 1.0, rr.size) * s
        win_depth[M] = z
        win_valid[M] = True
        ids[r0:r1, c0:c1][M] = k
    return ids
