"""A structured-light sensor above the bin: pinhole camera + offset projector, z-buffer rendering.

The height field is rendered as a triangle mesh (two triangles per grid cell) with a z-buffer; the
depth of every pixel is the exact intersection of the pixel's ray with the triangle's plane, so a
point ``xyz = depth * ((u - cx) / fx, (v - cy) / fy, 1)`` projects back onto its pixel centre
(``u`` = column, ``v`` = row). The projector is a second pinhole offset along the camera x axis;
a pixel is measured only where the projector sees the same surface (shadow-map test) and neither
line of sight grazes the surface.

Camera optical frame: x right, y down, z forward; the camera looks straight down at the table, so
camera x = world x, camera y = -world y, camera z = camera height - world z.

Depth noise is spatially correlated (white noise smoothed by a Gaussian of
``NOISE_CORRELATION_PX`` pixels and rescaled to the per-pixel sigma), as a structured-light sensor's
own smoothing makes it; the colour image is lit by a lamp beside the camera plus the projector
itself, whose mirror reflection on shiny parts saturates the image (and the depth there, see
:func:`shade_rgb`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from scipy import ndimage

from replay.synth.scene import LABEL_NONE, LABEL_RIM, LABEL_WALL, Scene
from zcut.cloud import Intrinsics
from zcut.errors import ParameterError

FULL_SIZE = (1200, 1920)  # (height, width)
FULL_FX = 1600.0  # pixels at 1920 wide: ~62 deg horizontal field of view
CAMERA_HEIGHT_MM = 580.0  # camera above the table top
PROJECTOR_BASELINE_MM = 150.0
MAX_OBLIQUITY_DEG = 78.0
NOISE_MM_AT_500 = 0.10  # depth noise sigma at 0.5 m on matte surfaces
SHINY_NOISE_FACTOR = 1.6
#: Gaussian smoothing (pixels) of the depth noise: Zivid One settings files enable a Gaussian filter
#: of sigma 1.5 (zivid-python-samples, settings/*.yml); see docs/synthetic.md
NOISE_CORRELATION_PX = 1.5
#: specular lobes of shiny parts lit by the projector: (amplitude, exponent) of a sharp core that
#: saturates the image and of a broad glow, on the 0..255 scale
SPECULAR_LOBES = ((420.0, 400.0), (70.0, 25.0))


def check_size(size: object) -> tuple[int, int]:
    """``size`` as (height, width) ints in 8..8192, or :class:`ParameterError` naming it."""
    try:
        h, w = (int(v) for v in size)  # type: ignore[attr-defined]  # not iterable: the TypeError below
    except (TypeError, ValueError) as e:
        raise ParameterError(f"size must be (height, width), got {size!r}") from e
    if not (8 <= h <= 8192 and 8 <= w <= 8192):
        raise ParameterError(f"size must be (height, width) between 8 and 8192, got {size!r}")
    return h, w


def default_intrinsics(size: tuple[int, int] = FULL_SIZE) -> Intrinsics:
    """Intrinsics of the simulated camera for an image of ``size`` = (height, width).

    The field of view is the same at every size (focal length scales with the width).
    """
    h, w = check_size(size)
    f = FULL_FX * w / FULL_SIZE[1]
    return Intrinsics(fx=f, fy=f, cx=(w - 1) / 2.0, cy=(h - 1) / 2.0, width=w, height=h)


def view_half_extent_mm(intrinsics: Intrinsics, *, camera_height_mm: float = CAMERA_HEIGHT_MM) -> tuple[float, float]:
    """Half extent (x, y) of the table area the camera sees, in mm."""
    K = intrinsics
    hx = camera_height_mm * max(K.cx, K.width - 1 - K.cx) / K.fx
    hy = camera_height_mm * max(K.cy, K.height - 1 - K.cy) / K.fy
    return hx, hy


@dataclass(frozen=True, slots=True)
class Render:
    """What the z-buffer saw, before the sensor's losses and errors.

    Attributes
    ----------
    depth_mm : (H, W) float64 ndarray
        Camera z of the first surface hit (inf where nothing was hit).
    normal : (H, W, 3) float64 ndarray
        Unit surface normal in the camera frame, facing the camera.
    label : (H, W) uint8 ndarray
        LABEL_* of the surface.
    part_id : (H, W) int32 ndarray
        1-based placed-part index, 0 for non-parts.
    """

    depth_mm: np.ndarray
    normal: np.ndarray
    label: np.ndarray
    part_id: np.ndarray


@numba.njit(cache=True, nogil=True)
def _raster(Xc, Yc, Zc, U, V, node_label, node_pid, fx, fy, cx, cy, depth, normal, label, pid):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover
    ny, nx = Zc.shape
    H, W = depth.shape
    for i in range(ny - 1):
        for j in range(nx - 1):
            # the cell's own normal (its bilinear patch at the centre), shared by its two triangles:
            # the depth is exact per triangle, but normals do not flicker with the triangulation
            gx = 0.5 * (Xc[i, j + 1] + Xc[i + 1, j + 1] - Xc[i, j] - Xc[i + 1, j])
            gy = 0.5 * (Yc[i, j + 1] + Yc[i + 1, j + 1] - Yc[i, j] - Yc[i + 1, j])
            gz = 0.5 * (Zc[i, j + 1] + Zc[i + 1, j + 1] - Zc[i, j] - Zc[i + 1, j])
            hx = 0.5 * (Xc[i + 1, j] + Xc[i + 1, j + 1] - Xc[i, j] - Xc[i, j + 1])
            hy = 0.5 * (Yc[i + 1, j] + Yc[i + 1, j + 1] - Yc[i, j] - Yc[i, j + 1])
            hz = 0.5 * (Zc[i + 1, j] + Zc[i + 1, j + 1] - Zc[i, j] - Zc[i, j + 1])
            cnx = gy * hz - gz * hy
            cny = gz * hx - gx * hz
            cnz = gx * hy - gy * hx
            cnn = np.sqrt(cnx * cnx + cny * cny + cnz * cnz)
            if cnn == 0.0:
                continue
            cnx /= cnn
            cny /= cnn
            cnz /= cnn
            for t in range(2):
                if t == 0:
                    ia, ja, ib, jb, ic, jc = i, j, i, j + 1, i + 1, j + 1
                else:
                    ia, ja, ib, jb, ic, jc = i, j, i + 1, j + 1, i + 1, j
                za, zb, zc = Zc[ia, ja], Zc[ib, jb], Zc[ic, jc]
                if za <= 1.0 or zb <= 1.0 or zc <= 1.0:
                    continue
                ua, va = U[ia, ja], V[ia, ja]
                ub, vb = U[ib, jb], V[ib, jb]
                uc, vc = U[ic, jc], V[ic, jc]
                area = (ub - ua) * (vc - va) - (uc - ua) * (vb - va)
                if abs(area) < 1e-12:
                    continue
                c0 = int(np.ceil(min(ua, ub, uc)))
                c1 = int(np.floor(max(ua, ub, uc)))
                r0 = int(np.ceil(min(va, vb, vc)))
                r1 = int(np.floor(max(va, vb, vc)))
                if c0 < 0:
                    c0 = 0
                if r0 < 0:
                    r0 = 0
                if c1 > W - 1:
                    c1 = W - 1
                if r1 > H - 1:
                    r1 = H - 1
                if c0 > c1 or r0 > r1:
                    continue
                # plane normal (camera frame)
                xa, ya = Xc[ia, ja], Yc[ia, ja]
                xb, yb = Xc[ib, jb], Yc[ib, jb]
                xc_, yc_ = Xc[ic, jc], Yc[ic, jc]
                ex, ey, ez = xb - xa, yb - ya, zb - za
                fx_, fy_, fz_ = xc_ - xa, yc_ - ya, zc - za
                nx_ = ey * fz_ - ez * fy_
                ny_ = ez * fx_ - ex * fz_
                nz_ = ex * fy_ - ey * fx_
                nn = np.sqrt(nx_ * nx_ + ny_ * ny_ + nz_ * nz_)
                if nn == 0.0:
                    continue
                nx_ /= nn
                ny_ /= nn
                nz_ /= nn
                d0 = nx_ * xa + ny_ * ya + nz_ * za
                # label of the vertex nearest the camera
                if za <= zb and za <= zc:
                    lab, pp = node_label[ia, ja], node_pid[ia, ja]
                elif zb <= zc:
                    lab, pp = node_label[ib, jb], node_pid[ib, jb]
                else:
                    lab, pp = node_label[ic, jc], node_pid[ic, jc]
                if lab == LABEL_RIM and abs(cnz) < 0.5:
                    lab = LABEL_WALL  # the steep faces below the rim's edges are walls
                inv = 1.0 / area
                for r in range(r0, r1 + 1):
                    for c in range(c0, c1 + 1):
                        w0 = ((ub - c) * (vc - r) - (uc - c) * (vb - r)) * inv
                        w1 = ((uc - c) * (va - r) - (ua - c) * (vc - r)) * inv
                        w2 = 1.0 - w0 - w1
                        if w0 < -1e-9 or w1 < -1e-9 or w2 < -1e-9:
                            continue
                        rx = (c - cx) / fx
                        ry = (r - cy) / fy
                        den = nx_ * rx + ny_ * ry + nz_
                        if abs(den) < 1e-12:
                            continue
                        z = d0 / den
                        if z > 0.0 and z < depth[r, c]:
                            depth[r, c] = z
                            s = -1.0 if cnx * rx + cny * ry + cnz > 0 else 1.0
                            normal[r, c, 0] = s * cnx
                            normal[r, c, 1] = s * cny
                            normal[r, c, 2] = s * cnz
                            label[r, c] = lab
                            pid[r, c] = pp


def _node_camera_coords(scene: Scene, *, camera_height_mm: float,
                        offset_x_mm: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    g = scene.grid
    X = np.broadcast_to(g.xs[None, :] - offset_x_mm, scene.height.shape)
    Y = np.broadcast_to(-g.ys[:, None], scene.height.shape)
    Z = camera_height_mm - scene.height
    return np.ascontiguousarray(X, np.float64), np.ascontiguousarray(Y, np.float64), np.ascontiguousarray(Z)


def render(scene: Scene, intrinsics: Intrinsics, *, camera_height_mm: float = CAMERA_HEIGHT_MM, offset_x_mm: float = 0.0) -> Render:
    """Z-buffer render of the scene's height field seen by a downward pinhole at (offset_x, 0, height)."""
    K = intrinsics
    X, Y, Z = _node_camera_coords(scene, camera_height_mm=camera_height_mm, offset_x_mm=offset_x_mm)
    H, W = K.height, K.width
    depth = np.full((H, W), np.inf)
    normal = np.zeros((H, W, 3))
    label = np.full((H, W), LABEL_NONE, np.uint8)
    pid = np.zeros((H, W), np.int32)
    with np.errstate(divide="ignore", invalid="ignore"):
        U = K.fx * X / Z + K.cx
        V = K.fy * Y / Z + K.cy
    _raster(X, Y, Z, U, V, scene.label, scene.part_id, float(K.fx), float(K.fy), float(K.cx), float(K.cy), depth, normal, label, pid)
    return Render(depth, normal, label, pid)


def pixel_rays(intrinsics: Intrinsics) -> np.ndarray:
    """(H, W, 3) float64: ``((u - cx) / fx, (v - cy) / fy, 1)`` for every pixel (u = column, v = row)."""
    K = intrinsics
    u = (np.arange(K.width) - K.cx) / K.fx
    v = (np.arange(K.height) - K.cy) / K.fy
    rays = np.empty((K.height, K.width, 3))
    rays[..., 0] = u[None, :]
    rays[..., 1] = v[:, None]
    rays[..., 2] = 1.0
    return rays


def measurable(
    scene: Scene,
    view: Render,
    intrinsics: Intrinsics,
    *,
    camera_height_mm: float = CAMERA_HEIGHT_MM,
    baseline_mm: float = PROJECTOR_BASELINE_MM,
    max_obliquity_deg: float = MAX_OBLIQUITY_DEG,
) -> np.ndarray:
    """(H, W) bool: the projector lights the surface the camera sees, and neither view is too oblique.

    The projector is a pinhole at camera x + ``baseline_mm`` looking the same way; its shadow map is
    rendered with the same rasterizer at the camera's focal length, wide enough for the scene.
    """
    return measure(scene, view, intrinsics, camera_height_mm=camera_height_mm, baseline_mm=baseline_mm,
                   max_obliquity_deg=max_obliquity_deg)[0]


def measure(
    scene: Scene,
    view: Render,
    intrinsics: Intrinsics,
    *,
    camera_height_mm: float = CAMERA_HEIGHT_MM,
    baseline_mm: float = PROJECTOR_BASELINE_MM,
    max_obliquity_deg: float = MAX_OBLIQUITY_DEG,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`measurable` and the grazing cosine it was decided on.

    Returns
    -------
    ok : (H, W) bool ndarray
        As :func:`measurable`.
    cosine : (H, W) float32 ndarray
        The smaller of the cosines between the surface normal and the directions to the camera and
        to the projector (1 = seen head-on by both; -1 where nothing was hit).
    """
    K = intrinsics
    # projector intrinsics covering the whole grid
    X, Y, Z = _node_camera_coords(scene, camera_height_mm=camera_height_mm, offset_x_mm=baseline_mm)
    ux = X / Z
    vy = Y / Z
    f = float(K.fx)
    cxp = -f * float(ux.min()) + 1.0
    cyp = -f * float(vy.min()) + 1.0
    wp = int(np.ceil(f * float(ux.max()) + cxp)) + 2
    hp = int(np.ceil(f * float(vy.max()) + cyp)) + 2
    proj = Intrinsics(fx=f, fy=f, cx=cxp, cy=cyp, width=wp, height=hp)
    shadow = render(scene, proj, camera_height_mm=camera_height_mm, offset_x_mm=baseline_mm).depth_mm
    ok = np.zeros(view.depth_mm.shape, bool)
    cosine = np.full(view.depth_mm.shape, -1.0, np.float32)
    _measurable(
        view.depth_mm, view.normal, shadow, float(K.fx), float(K.fy), float(K.cx), float(K.cy),
        f, cxp, cyp, float(baseline_mm), float(np.cos(np.radians(max_obliquity_deg))), ok, cosine,
    )
    return ok, cosine


@numba.njit(cache=True, nogil=True)
def _measurable(depth, normal, shadow, fx, fy, cx, cy, fp, cxp, cyp, baseline, cos_min, ok, cosine):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover
    H, W = depth.shape
    hp, wp = shadow.shape
    for r in range(H):
        for c in range(W):
            z = depth[r, c]
            if not np.isfinite(z):
                continue
            rx = (c - cx) / fx
            ry = (r - cy) / fy
            nx, ny, nz = normal[r, c, 0], normal[r, c, 1], normal[r, c, 2]
            # towards the camera
            inv = 1.0 / np.sqrt(rx * rx + ry * ry + 1.0)
            cos_c = -(nx * rx + ny * ry + nz) * inv
            # towards the projector (at +baseline on the camera x axis)
            px, py, pz = rx * z - baseline, ry * z, z
            pn = np.sqrt(px * px + py * py + pz * pz)
            cos_p = -(nx * px + ny * py + nz * pz) / pn
            cosine[r, c] = min(cos_c, cos_p)
            if cos_c <= cos_min or cos_p <= cos_min:
                continue
            up = fp * px / pz + cxp
            vp = fp * py / pz + cyp
            c0 = min(max(int(np.floor(up)), 0), wp - 2)
            r0 = min(max(int(np.floor(vp)), 0), hp - 2)
            # the most lenient of the four surrounding shadow-map samples
            d = max(shadow[r0, c0], shadow[r0, c0 + 1], shadow[r0 + 1, c0], shadow[r0 + 1, c0 + 1])
            bias = 0.3 + 2.0 * (pz / fp) / max(cos_p, 0.1)
            ok[r, c] = pz <= d + bias


def depth_noise_sigma_mm(depth_mm: np.ndarray, *, shiny: np.ndarray | bool) -> np.ndarray:
    """Per-pixel depth noise sigma (mm): 0.1 mm at 0.5 m on matte surfaces, growing with depth²."""
    s = NOISE_MM_AT_500 * (np.asarray(depth_mm) / 500.0) ** 2
    return s * np.where(shiny, SHINY_NOISE_FACTOR, 1.0)


def _gaussian_gain(sigma_px: float, truncate: float) -> float:
    """Standard deviation of unit white noise after ``ndimage.gaussian_filter(sigma_px, truncate)``."""
    r = int(truncate * sigma_px + 0.5)
    x = np.arange(-r, r + 1, dtype=np.float64)
    w = np.exp(-0.5 * (x / sigma_px) ** 2)
    w /= w.sum()
    return float(np.sum(w * w))  # separable: the 2-D sum of squares is (sum w²)², its root sum w²


def correlated_noise(
    shape: tuple[int, int], rng: np.random.Generator, *, sigma_px: float = NOISE_CORRELATION_PX
) -> np.ndarray:
    """(H, W) float32 unit-variance noise, smoothed by a Gaussian of ``sigma_px`` pixels (0: white).

    Neighbouring pixels move together (correlation 0.9 one pixel apart at 1.5 px), so the noise
    makes few isolated peaks: a pixel rises above all its neighbours by the z-cut's nominal step
    (0.2 mm) about as rarely as the paper's Figure 20 shows at that step.
    """
    noise = rng.standard_normal(shape, dtype=np.float32)
    if sigma_px <= 0:
        return noise
    truncate = 3.0
    noise = ndimage.gaussian_filter(noise, sigma_px, mode="reflect", truncate=truncate)
    noise *= np.float32(1.0 / _gaussian_gain(sigma_px, truncate))
    smooth: np.ndarray = noise
    return smooth


def quantize_depth(depth_mm: np.ndarray, step_mm: float) -> np.ndarray:
    """Depth rounded to multiples of ``step_mm`` (a sensor reporting z in fixed units; 0: unchanged)."""
    if step_mm <= 0:
        return depth_mm
    return np.round(depth_mm / step_mm) * step_mm


def shade_rgb(
    view: Render,
    intrinsics: Intrinsics,
    colours: np.ndarray,
    shiny: np.ndarray,
    ambient: np.ndarray,
    rng: np.random.Generator,
    *,
    baseline_mm: float = PROJECTOR_BASELINE_MM,
) -> tuple[np.ndarray, np.ndarray]:
    """Colour image: Lambert + ambient, the projector's specular reflection on shiny pixels, noise.

    The 2-D image of a structured-light camera is taken under the projector's white light, so a
    shiny surface whose normal bisects the directions to the camera and to the projector mirrors
    the projector into the camera: a core that saturates (:data:`SPECULAR_LOBES`) in a broad glow.

    Parameters
    ----------
    view : Render
        Depth and normals (camera frame).
    colours : (H, W, 3) float ndarray
        Base colour per pixel (0..255).
    shiny : (H, W) bool ndarray
    ambient : (H, W) float ndarray
        Share of diffuse room light (0..1); the rest is the Lambert term of a lamp by the camera.
    baseline_mm : float
        Projector position on the camera x axis.

    Returns
    -------
    rgb : (H, W, 3) uint8 ndarray
    saturated : (H, W) bool ndarray
        Pixels whose three channels clip at 255 before the image noise (specular highlights).
    """
    K = intrinsics
    img = np.empty(colours.shape, np.float32)
    saturated = np.zeros(shiny.shape, np.bool_)
    lobes = np.asarray(SPECULAR_LOBES, np.float64)
    _shade(view.normal, view.depth_mm, colours, shiny, ambient, float(K.fx), float(K.fy), float(K.cx), float(K.cy),
           float(baseline_mm), lobes, img, saturated)
    img += rng.standard_normal(img.shape, dtype=np.float32) * np.float32(1.5)
    np.rint(img, out=img)
    np.clip(img, 0, 255, out=img)
    return img.astype(np.uint8), saturated


@numba.njit(cache=True, nogil=True)
def _shade(normal, depth, colours, shiny, ambient, fx, fy, cx, cy, baseline, lobes, img, saturated):  # type: ignore[no-untyped-def]  # numba kernel  # pragma: no cover
    H, W = shiny.shape
    lx, ly, lz = -0.25, 0.35, -1.0  # towards a lamp beside the camera
    ln = np.sqrt(lx * lx + ly * ly + lz * lz)
    lx, ly, lz = lx / ln, ly / ln, lz / ln
    for r in range(H):
        for c in range(W):
            nx, ny, nz = normal[r, c, 0], normal[r, c, 1], normal[r, c, 2]
            lam = min(max(nx * lx + ny * ly + nz * lz, 0.0), 1.0)
            k = ambient[r, c] + (1.0 - ambient[r, c]) * lam
            spec = 0.0
            if shiny[r, c] and np.isfinite(depth[r, c]):
                rx = (c - cx) / fx
                ry = (r - cy) / fy
                z = depth[r, c]
                # unit vectors from the surface point to the camera (origin) and to the projector
                px, py, pz = -rx * z, -ry * z, -z
                pn = np.sqrt(px * px + py * py + pz * pz)
                qx, qy, qz = baseline - rx * z, -ry * z, -z
                qn = np.sqrt(qx * qx + qy * qy + qz * qz)
                hx, hy, hz = px / pn + qx / qn, py / pn + qy / qn, pz / pn + qz / qn
                hn = np.sqrt(hx * hx + hy * hy + hz * hz)
                ch = min(max((nx * hx + ny * hy + nz * hz) / hn, 0.0), 1.0)
                for j in range(lobes.shape[0]):
                    spec += lobes[j, 0] * ch ** lobes[j, 1]
            low = 1e9
            for ch_ in range(3):
                v = colours[r, c, ch_] * k + spec
                img[r, c, ch_] = v
                low = min(low, v)
            saturated[r, c] = low >= 255.0
