"""A structured-light sensor by ray tracing: what each camera pixel receives, decodes and measures.

The sensor is a pinhole camera and a pinhole projector beside it (``baseline_mm`` along the camera
x axis, parallel optical axes, the projector's principal point off-centre so that it covers the
camera's view). The projector throws phase-shifted fringes along its columns at a few periods; a
camera pixel integrates every path by which projector light reaches it, and decodes the projector
column ``u`` that lit "its" point; the point is triangulated from ``u`` and the pixel's ray.

Per camera pixel, its centre ray, and ``samples x samples`` sub-pixel rays where its footprint may
straddle an edge (:func:`edge_pixels`):

1. **First hit** P0 of each sub-pixel ray. The centre ray's hit is the truth (its camera z is
   ``/ground_truth/depth``).
2. **Direct light.** P0 is lit when the projector sees it (a ray from the projector reaches P0
   first; else P0 is in the projector's shadow and gets no direct light). Its radiance toward the
   camera follows the material (:mod:`.materials`, diffuse + specular lobe); it carries code u(P0).
3. **Specular bounces, camera side.** On a shiny P0 the sub-pixel ray is reflected (about a normal
   perturbed by the roughness) to P1; the projector light P1 sends toward P0 reaches the pixel
   weighted by P0's specular share, carrying code u(P1); up to ``bounces`` reflections.
4. **Specular bounces, projector side.** Projector rays that hit a shiny surface Q are reflected to
   the surface P they light; P's diffuse reflection of that light reaches the pixel that sees P,
   carrying code u(Q) (photons splatted over the pixel they land in, smoothed over ~1 px).
5. **Glare.** A share of every pixel's light spreads over its neighbours (the lens's point-spread
   tail); beside a highlight a hundred times brighter than the surface, the spilled light carries
   the highlight's code.
6. **Decoding.** Every path adds a phasor ``I * exp(2πi u / T)`` per fringe period T; the pixel's
   phase at each period is that of the sum (the strongest code wins; close codes blend, as
   sub-pixels at an edge do), unwrapped from the coarsest period to the finest. The pixel is
   rejected (NaN) when its signal is too weak, its fringes lost their contrast (paths that cancel),
   or it saturates the shortest exposure of the HDR capture.
7. **Triangulation and noise.** ``z = b / (x_cam - x_proj)`` in normalized coordinates, with the
   decoded column perturbed by spatially correlated noise whose sigma grows as the signal drops.

Not modelled (stated in ``docs/raytraced.md``): diffuse-to-diffuse interreflection (it lowers the
fringe contrast but hardly shifts the phase at high frequencies), projector defocus, lens
distortion, the sensor's own smoothing of the point cloud.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import importlib
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from replay.synth.raytrace import kernels
from replay.synth.raytrace.materials import MIRROR_MIN
from replay.synth.raytrace.scene import Hits, TracedScene
from replay.synth.sensor import FULL_SIZE, PROJECTOR_BASELINE_MM, correlated_noise
from zcut.cloud import Intrinsics
from zcut.errors import ParameterError

#: camera intensity per unit radiance: a white diffuse surface facing the projector at 0.5 m reads 0.5
EXPOSURE = np.pi / 2
#: reference distance (mm) at which the projector's irradiance on a facing surface is 1
REFERENCE_MM = 500.0
#: width (pixels at 1920 across) of the kernel that turns projector-side photons into irradiance
PHOTON_SIGMA_PX = 3.0
#: points lit per chunk of :func:`direct_light` (its per-point arrays of one chunk at a time)
DIRECT_CHUNK = 1 << 18


@contextlib.contextmanager
def small_pages() -> Iterator[None]:
    """Within: numpy asks no transparent huge pages for its arrays (restored on exit; also a decorator).

    numpy ``madvise``s every array of 4 MB or more for huge pages. Where the kernel's THP ``defrag``
    setting is ``madvise`` (Ubuntu's default), each fault on such memory may compact memory first;
    a frame allocates and frees some 5 GB of large arrays, and on the shared 2-core machine that
    cost 5 of 20 CPU-s per 1920 x 1200 frame in the kernel (measured with ``getrusage``: system time
    9.1 s with the advice, 4.1 s without; ``bench/bench_raytrace.py``). Only where the memory comes
    from changes, never a value.
    """
    try:
        setter = importlib.import_module("numpy._core.multiarray")._set_madvise_hugepage
    except (ImportError, AttributeError):  # another numpy: leave its allocator alone
        yield
        return
    previous = setter(False)
    try:
        yield
    finally:
        setter(previous)


#: glibc ``mallopt`` parameters (``malloc.h``) and their defaults
_M_TRIM_THRESHOLD, _M_MMAP_MAX = -1, -4
_DEFAULT_TRIM_THRESHOLD, _DEFAULT_MMAP_MAX = 128 * 1024, 65536
_kept = {"depth": 0}
_kept_lock = threading.Lock()


def _glibc() -> ctypes.CDLL | None:
    """The C library when it is glibc (it has ``mallopt`` and ``malloc_trim``), else None."""
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        libc = ctypes.CDLL(name)
        libc.mallopt.argtypes, libc.malloc_trim.argtypes = [ctypes.c_int, ctypes.c_int], [ctypes.c_size_t]
    except (OSError, AttributeError):  # not glibc (musl, macOS): leave its allocator alone
        return None
    return libc


_LIBC = _glibc()


@contextlib.contextmanager
def kept_memory() -> Iterator[None]:
    """Within: glibc's ``malloc`` keeps freed memory for the next arrays instead of returning it (also a decorator).

    A 1920 x 1200 frame allocates and frees some 5 GB of arrays of 4 MB to 60 MB. glibc serves
    each with a fresh ``mmap`` and ``munmap``s it when freed, so every page of every array is a
    page fault when first written: 1.25 M faults, 2-6.5 of a frame's 10-14 CPU-s in the kernel
    (``bench/bench_raytrace.py``, ``docs/raytraced.md``). Within, large blocks come from the
    heap (``M_MMAP_MAX`` 0) and freed memory stays in it (``M_TRIM_THRESHOLD`` 2 GB), so only
    the frame's peak (about 2.5 GB) is faulted in once per process and the next frame's arrays
    reuse it. Nested uses share the outermost one (a log keeps the memory across its frames); on
    leaving it the defaults are set back (glibc's dynamic mmap threshold stays off, ``mallopt``
    switches it off) and the kept memory is returned (``malloc_trim``). Only where the memory comes
    from changes, never a value; with another C library, nothing.
    """
    libc = _LIBC
    with _kept_lock:
        outer = _kept["depth"] == 0
        _kept["depth"] += 1
        if outer and libc is not None:
            libc.mallopt(_M_MMAP_MAX, 0)
            libc.mallopt(_M_TRIM_THRESHOLD, 2**31 - 1)
    try:
        yield
    finally:
        with _kept_lock:
            _kept["depth"] -= 1
            if _kept["depth"] == 0 and libc is not None:
                libc.mallopt(_M_MMAP_MAX, _DEFAULT_MMAP_MAX)
                libc.mallopt(_M_TRIM_THRESHOLD, _DEFAULT_TRIM_THRESHOLD)
                libc.malloc_trim(0)


@dataclass(frozen=True, slots=True)
class SensorModel:
    """The ray-traced sensor's knobs (assumptions; ``docs/raytraced.md`` gives their sources).

    Attributes
    ----------
    baseline_mm : float
        Projector centre on the camera x axis.
    projector_size : (width, height)
        Projector pixels.
    projector_f_px : float
        Projector focal length (pixels).
    projector_c_px : (cx, cy)
        Projector principal point (pixels).
    periods_px : tuple of float
        Fringe periods, coarsest first (the coarsest spans the projector: no ambiguity).
    samples : int
        Sub-pixel rays per pixel along each axis.
    bounces : int
        Specular bounces traced on the camera side (0: none).
    photon_stride : int
        Projector-side photons every ``photon_stride`` projector pixels (0: none traced).
    hdr_gains : tuple of float
        Exposures of the HDR capture relative to the base one; a pixel reads the longest that
        does not saturate, and is lost if even the shortest saturates.
    sigma_code_px : float
        Noise (projector pixels) of the decoded column at signal ``sigma_signal``.
    sigma_signal : float
        Reference signal for ``sigma_code_px`` (0..1 of full scale).
    min_signal : float
        Weakest readable modulation (full scale).
    min_contrast : float
        Smallest ratio of fringe amplitude to the light received at the finest period.
    glare_share : float
        Share of a pixel's light the lens spreads over its neighbours.
    glare_sigma_px : float
        Width of the spread at 1920 pixels across (scales with the image width).
    outlier_sigmas : float
        The truth rule's threshold in noise sigmas.
    """

    baseline_mm: float = PROJECTOR_BASELINE_MM
    projector_size: tuple[int, int] = (1280, 800)
    projector_f_px: float = 985.0
    projector_c_px: tuple[float, float] = (886.0, 399.5)
    periods_px: tuple[float, ...] = (1280.0, 64.0, 8.0)
    samples: int = 2
    bounces: int = 1
    photon_stride: int = 2
    hdr_gains: tuple[float, ...] = (4.0, 1.0, 0.125)
    sigma_code_px: float = 0.059
    sigma_signal: float = 0.375
    min_signal: float = 0.004
    min_contrast: float = 0.35
    glare_share: float = 0.02
    glare_sigma_px: float = 2.0
    outlier_sigmas: float = 4.0

    def __post_init__(self) -> None:
        def bad(field: str, value: object, need: str) -> ParameterError:
            return ParameterError(f"SensorModel.{field} must be {need}, got {value!r}")

        if not (np.isfinite(self.baseline_mm) and abs(self.baseline_mm) > 1.0):
            raise bad("baseline_mm", self.baseline_mm, "a finite distance of more than 1 mm")
        w, h = self.projector_size
        if not (w >= 8 and h >= 8):
            raise bad("projector_size", self.projector_size, "at least 8 x 8 pixels")
        if not self.projector_f_px > 0:
            raise bad("projector_f_px", self.projector_f_px, "positive")
        if not (len(self.periods_px) >= 1 and all(p > 0 for p in self.periods_px)):
            raise bad("periods_px", self.periods_px, "positive periods, coarsest first")
        if int(self.samples) != self.samples or not 1 <= self.samples <= 4:
            raise bad("samples", self.samples, "an integer 1..4")
        if int(self.bounces) != self.bounces or not 0 <= self.bounces <= 4:
            raise bad("bounces", self.bounces, "an integer 0..4")
        if int(self.photon_stride) != self.photon_stride or self.photon_stride < 0:
            raise bad("photon_stride", self.photon_stride, "a non-negative integer")
        if not (len(self.hdr_gains) >= 1 and all(g > 0 for g in self.hdr_gains)):
            raise bad("hdr_gains", self.hdr_gains, "positive exposures")
        for f in ("sigma_code_px", "sigma_signal", "min_signal", "outlier_sigmas"):
            if not getattr(self, f) > 0:
                raise bad(f, getattr(self, f), "positive")
        if not 0 <= self.min_contrast < 1:
            raise bad("min_contrast", self.min_contrast, "in [0, 1)")
        if not (0 <= self.glare_share < 1 and self.glare_sigma_px > 0):
            raise bad("glare_share", self.glare_share, "in [0, 1) with a positive glare_sigma_px")

    @property
    def projector_origin(self) -> np.ndarray:
        return np.array([self.baseline_mm, 0.0, 0.0])

    def code(self, point: np.ndarray) -> np.ndarray:
        """Projector column (pixels) lighting camera-frame ``point`` (..., 3) mm."""
        return np.asarray(self.projector_f_px * (point[..., 0] - self.baseline_mm) / point[..., 2]
                          + self.projector_c_px[0])

    def in_projector(self, point: np.ndarray) -> np.ndarray:
        """Whether the projector's image covers camera-frame ``point`` (..., 3)."""
        w, h = self.projector_size
        z = point[..., 2]
        with np.errstate(invalid="ignore", divide="ignore"):
            u = self.code(point)
            v = self.projector_f_px * point[..., 1] / z + self.projector_c_px[1]
            return np.asarray((z > 0) & (u >= -0.5) & (u <= w - 0.5) & (v >= -0.5) & (v <= h - 0.5))

    def sigma_code(self, signal: np.ndarray) -> np.ndarray:
        """Noise sigma (projector pixels) of the decoded column at ``signal`` (full scale of the exposure read)."""
        return np.asarray(self.sigma_code_px * np.sqrt(self.sigma_signal / np.maximum(signal, self.min_signal)))

    def depth_per_code_mm(self, z_mm: np.ndarray) -> np.ndarray:
        """Depth change (mm) per projector pixel of code at camera depth ``z_mm``."""
        return z_mm**2 / (self.projector_f_px * abs(self.baseline_mm))


@dataclass(frozen=True, slots=True)
class Phasors:
    """Light received per pixel: one complex fringe sum per period and the total intensity.

    Attributes
    ----------
    z : (P, H, W) complex128 ndarray
        Sum of ``I * exp(2πi u / T)`` for each period T.
    intensity : (H, W) float64 ndarray
        Sum of ``I`` (full scale of the base exposure).
    """

    z: np.ndarray
    intensity: np.ndarray

    @staticmethod
    def zeros(n_periods: int, shape: tuple[int, int]) -> Phasors:
        return Phasors(np.zeros((n_periods,) + shape, np.complex128), np.zeros(shape))

    def add(self, flat_index: np.ndarray, weight: np.ndarray, value: np.ndarray, code: np.ndarray,
            periods: tuple[float, ...]) -> None:
        """Add the paths of intensity ``weight * value`` and projector column ``code`` to the pixels
        ``flat_index`` (repeats allowed): :meth:`add_reference` in a numba kernel, the same bits."""
        kernels.bincount_phasors(
            np.ascontiguousarray(flat_index, np.int64), np.ascontiguousarray(weight, np.float64),
            np.ascontiguousarray(value, np.float64), np.ascontiguousarray(code, np.float64),
            np.asarray(periods, np.float64), self.intensity.reshape(-1),
            self.z.view(np.float64).reshape(self.z.shape[0], self.intensity.size, 2))

    def add_reference(self, flat_index: np.ndarray, intensity: np.ndarray, code: np.ndarray,
                      periods: tuple[float, ...]) -> None:
        """Add the paths ``(intensity, code)`` to the pixels ``flat_index`` (repeats allowed)."""
        n = self.intensity.size
        self.intensity.reshape(-1)[:] += np.bincount(flat_index, weights=intensity, minlength=n)
        for k, T in enumerate(periods):
            ph = 2 * np.pi * code / T
            zk = self.z[k].reshape(-1)
            zk.real += np.bincount(flat_index, weights=intensity * np.cos(ph), minlength=n)
            zk.imag += np.bincount(flat_index, weights=intensity * np.sin(ph), minlength=n)

    def plus(self, other: Phasors) -> Phasors:
        return Phasors(self.z + other.z, self.intensity + other.intensity)

    def add_in_place(self, other: Phasors) -> Phasors:
        """``self`` with ``other`` added into its own arrays (the bits of :meth:`plus`, one image set less)."""
        np.add(self.z, other.z, out=self.z)
        np.add(self.intensity, other.intensity, out=self.intensity)
        return self


def _unit(v: np.ndarray) -> np.ndarray:
    return np.asarray(v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12))


def direct_light(scene: TracedScene, model: SensorModel, hits: Hits, idx: np.ndarray, wo: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Projector light that the points ``hits[idx]`` send toward ``wo`` (unit, (k, 3)).

    Returns
    -------
    keep : (k,) bool ndarray
        The projector lights the point (not in its shadow, inside its image, facing it).
    radiance : (k,) float64 ndarray
        Camera intensity per unit of path weight (0 where not ``keep``).
    code : (k,) float64 ndarray
        Projector column of the point (NaN where not ``keep``).
    reflectance : (k,) float64 ndarray
        The BRDF (1/sr) from the projector toward ``wo`` (NaN where not ``keep``): a Lambert term
        ``albedo / π`` plus a Beckmann-like lobe ``spec D / (4 cos_i cos_o)``.
    """
    idx = np.ascontiguousarray(idx, np.int64)
    k = idx.size
    proj = model.projector_origin
    f_px, b = float(model.projector_f_px), float(model.baseline_mm)
    cx, cy = (float(c) for c in model.projector_c_px)
    wi = np.empty((k, 3))
    dist = np.empty(k)
    ok = np.empty(k, bool)
    kernels.direct_prepare(hits.point, hits.normal, hits.geo_normal, idx, proj, f_px, b, cx, cy,
                           int(model.projector_size[0]), int(model.projector_size[1]), wi, dist, ok)
    radiance = np.zeros(k)
    code = np.full(k, np.nan)
    reflectance = np.full(k, np.nan)
    lit = np.flatnonzero(ok)
    ok[:] = False
    # in chunks of DIRECT_CHUNK points: the shadow rays, Open3D's answers and the BRDF's ten arrays of
    # a chunk, not of all k points at once (a frame's peak memory, what its first frame pays in page
    # faults); every value is a point's own, so the chunks change none
    wo = np.ascontiguousarray(wo, np.float64)
    for c0 in range(0, lit.size, DIRECT_CHUNK):
        sel = lit[c0:c0 + DIRECT_CHUNK]
        # shadow: the projector's ray toward the point must reach it first
        t = scene.cast_t(proj, -wi[sel])
        sel = sel[t >= dist[sel] - 0.05]
        del t
        ok[sel] = True
        m = sel.size
        if m == 0:
            continue
        cos_i, irradiance, cos_o, ch, exponent, pa2, code_s = (np.empty(m) for _ in range(7))
        kernels.brdf_lobe(hits.point, hits.normal, hits.material, idx, sel, wi, dist, wo, scene.mat["roughness"],
                          f_px, b, cx, REFERENCE_MM, cos_i, irradiance, cos_o, ch, exponent, pa2, code_s)
        # numpy's own exp and power (SIMD) differ from the C library's in the last bit: these stay numpy
        lobe = np.exp(exponent) / (pa2 * ch**4)
        rad_s, f_s = np.empty(m), np.empty(m)
        kernels.brdf_finish(hits.material, idx, sel, scene.mat["albedo"], scene.mat["specular"], lobe, cos_i, cos_o,
                            irradiance, EXPOSURE, rad_s, f_s)
        radiance[sel] = rad_s
        code[sel] = code_s
        reflectance[sel] = f_s
    return ok, radiance, code, reflectance


def _perturbed_reflection(d: np.ndarray, n: np.ndarray, roughness: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Reflect directions ``d`` about normals ``n`` tilted at random by the roughness (Beckmann-like)."""
    a = np.where(np.abs(n[:, 0]) < 0.9, 1.0, 0.0)
    helper = np.stack([a, 1.0 - a, np.zeros_like(a)], axis=1)
    t1 = _unit(np.cross(n, helper))
    t2 = np.cross(n, t1)
    g = rng.standard_normal((len(n), 2)) * (roughness / np.sqrt(2.0))[:, None]
    m = _unit(n + g[:, :1] * t1 + g[:, 1:] * t2)
    return _unit(d - 2.0 * np.einsum("kj,kj->k", d, m)[:, None] * m)


@dataclass(frozen=True, slots=True)
class Ops:
    """What the tracing steps cast, light and add with: the numba kernels (:data:`FAST`), or the literal
    numpy of ``reference.py``, which runs the same steps (:func:`camera_bounces`,
    :func:`projector_bounces`) with its own: it is the oracle of these operations, and the steps'
    physics is written once.

    Attributes
    ----------
    cast : (scene, origins, directions) -> Hits
        First hits (``TracedScene.cast``).
    light : (scene, model, hits, idx, wo) -> (keep, radiance, code)
        Projector light the points ``hits[idx]`` send toward ``wo`` (:func:`direct_light`).
    add : (image, flat_index, weight, value, code, periods) -> None
        Paths of intensity ``weight * value`` added to a :class:`Phasors` image (:meth:`Phasors.add`).
    add_light : (image, flat_index, weight, value) -> None
        ``image[flat_index] += weight * value`` (repeats allowed) into a flat float64 image.
    """

    cast: Callable[[TracedScene, np.ndarray, np.ndarray], Hits]
    light: Callable[[TracedScene, SensorModel, Hits, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]
    add: Callable[[Phasors, np.ndarray, np.ndarray, np.ndarray, np.ndarray, tuple[float, ...]], None]
    add_light: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], None]


def _cast(scene: TracedScene, origins: np.ndarray, directions: np.ndarray) -> Hits:
    return scene.cast(origins, directions)


def _light(scene: TracedScene, model: SensorModel, hits: Hits, idx: np.ndarray, wo: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ok, radiance, code, _ = direct_light(scene, model, hits, idx, wo)
    return ok, radiance, code


def _add_light(image: np.ndarray, flat_index: np.ndarray, weight: np.ndarray, value: np.ndarray) -> None:
    kernels.add_at(image, flat_index, weight, value, np.ones(flat_index.size))


#: The fast path's operations: numba kernels.
FAST = Ops(cast=_cast, light=_light, add=Phasors.add, add_light=_add_light)


@dataclass(frozen=True, slots=True)
class Received:
    """Everything a frame's pixels received, by path.

    Attributes
    ----------
    direct, camera_bounce, projector_bounce, glare : Phasors
        Light by path (glare is the spread of the other three).
    sub_depth_mm : (S, H, W) float32 ndarray
        Camera z of each sub-pixel ray's first hit (inf where it hit nothing).
    centre : Hits
        The centre rays' hits (the truth), flattened (H*W).
    specular_light : (H, W) float64 ndarray
        Intensity of the specular part of the light (for the 2-D image's highlights).
    """

    direct: Phasors
    camera_bounce: Phasors
    projector_bounce: Phasors
    glare: Phasors
    sub_depth_mm: np.ndarray
    centre: Hits
    specular_light: np.ndarray


def pixel_coordinates(K: Intrinsics, du: float = 0.0, dv: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Normalized coordinates of the pixel centres shifted by (du, dv) pixels: per column, per row."""
    u = (np.arange(K.width) + du - K.cx) / K.fx
    v = (np.arange(K.height) + dv - K.cy) / K.fy
    return u, v


def pixel_directions(K: Intrinsics, du: float = 0.0, dv: float = 0.0, flat: np.ndarray | None = None) -> np.ndarray:
    """(k, 3) unit ray directions through the pixels ``flat`` (row-major; None: all H*W) shifted by (du, dv)."""
    u, v = pixel_coordinates(K, du, dv)
    flat = np.arange(K.height * K.width) if flat is None else np.ascontiguousarray(flat, np.int64)
    out = np.empty((flat.size, 3))
    kernels.pixel_directions(u, v, flat, out)
    return out


def edge_pixels(depth_mm: np.ndarray, part: np.ndarray, label: np.ndarray, *, jump_mm: float = 1.5) -> np.ndarray:
    """(H, W) bool: pixels whose 8-neighbourhood sees another part, another surface or a depth jump.

    Only these can straddle two surfaces; the others are traced with their centre ray alone. A numba
    kernel (:func:`.kernels.edge_pixels`) doing per pixel what ``reference.edge_pixels_reference``
    does with scipy's 3 x 3 maximum and minimum filters: the same mask.
    """
    z = np.ascontiguousarray(np.where(np.isfinite(depth_mm), depth_mm, 1e9), np.float64)
    key = np.ascontiguousarray(part.astype(np.int64) * 16 + label)
    out = np.empty(z.shape, bool)
    kernels.edge_pixels(z, key, float(jump_mm), out)
    return out


@small_pages()
def trace(scene: TracedScene, K: Intrinsics, model: SensorModel, rng: np.random.Generator) -> Received:
    """Trace the light every camera pixel receives (steps 1-5 of the module docstring).

    Pixels at edges (:func:`edge_pixels`) get ``samples x samples`` sub-pixel rays, the others their
    centre ray (they see one smooth surface: more rays would only average the same code). The
    per-ray arithmetic runs in numba kernels (:mod:`.kernels`); ``reference.trace_reference`` is the
    same in numpy, and the two agree bit for bit.
    """
    H, W = K.height, K.width
    S = int(model.samples)
    origin = np.zeros(3)
    d_centre = pixel_directions(K)
    direct, bounce, spec_light, centre, z_centre, sub_depth = centre_rays(scene, K, model, FAST, d_centre)
    if S > 1:
        # the centre rays of plain pixels, then S x S sub-pixel rays of every edge pixel, offset by offset
        edge = edge_pixels(z_centre, centre.part.reshape(H, W), centre.label.reshape(H, W)).ravel()
        plain = np.flatnonzero(~edge)
        e = np.flatnonzero(edge)
        n_plain, n_e = plain.size, e.size
        h0 = Hits.empty(n_plain + S * S * n_e)
        for f in Hits.__slots__:
            np.take(getattr(centre, f), plain, axis=0, out=getattr(h0, f)[:n_plain])
        d = np.empty((n_plain + S * S * n_e, 3))
        np.take(d_centre, plain, axis=0, out=d[:n_plain])
        pix = np.concatenate([plain] + [e] * (S * S))
        w_s = np.concatenate([np.ones(n_plain), np.full(S * S * n_e, 1.0 / (S * S))])
        offsets = [((i + 0.5) / S - 0.5, (j + 0.5) / S - 0.5) for j in range(S) for i in range(S)]
        for s, (du, dv) in enumerate(offsets):
            at = n_plain + s * n_e
            u, v = pixel_coordinates(K, du, dv)
            kernels.pixel_directions(u, v, e, d[at:at + n_e])
            scene.cast(origin, d[at:at + n_e], out=h0, at=at)
            sub_depth[s].reshape(-1)[e] = np.where(np.isfinite(h0.t[at:at + n_e]), h0.point[at:at + n_e, 2], np.inf)
    else:
        h0, d, pix, w_s = centre, d_centre, np.arange(H * W), np.ones(H * W)
    # arrays are dropped as soon as they are done with: the frame's peak is what its first frame in a
    # process pays in page faults (optics.kept_memory)
    del d_centre

    idx = np.flatnonzero(h0.hit)
    wo = d[idx]
    ok, rad, code, refl = direct_light(scene, model, h0, idx, np.negative(wo, out=wo))  # one (k, 3) array, not two
    del wo
    sel = idx[ok]
    direct.add(pix[sel], w_s[sel], rad[ok], code[ok], model.periods_px)
    if sel.size:
        # the specular share of the direct light, for the 2-D image's highlights
        share = np.empty(sel.size)
        kernels.specular_share(h0.material[sel], scene.mat["albedo"], refl[ok], share)
        kernels.add_at(spec_light, pix[sel], w_s[sel], rad[ok], share)
        del share
    del ok, rad, code, refl, sel
    camera_bounces(scene, model, FAST, h0, idx, d, pix, w_s, rng, bounce, spec_light)
    del h0, d, pix, w_s, idx
    photons = projector_bounces(scene, K, model, centre, rng, FAST)
    glare = _glare(direct.plus(bounce).add_in_place(photons), K, model)
    return Received(direct, bounce, photons, glare, sub_depth, centre, spec_light.reshape(H, W))


def centre_rays(scene: TracedScene, K: Intrinsics, model: SensorModel, ops: Ops, d_centre: np.ndarray
                ) -> tuple[Phasors, Phasors, np.ndarray, Hits, np.ndarray, np.ndarray]:
    """A frame's empty light images and step 1 for its centre rays ``d_centre`` (H*W, 3), cast with ``ops``.

    Returns (direct, camera bounce, specular light (H*W,), the centre hits, their camera z (H, W),
    the sub-pixel depths (S*S, H, W), each its pixel's centre z until its sub-pixel rays are cast).
    """
    H, W = K.height, K.width
    P = len(model.periods_px)
    S = int(model.samples)
    centre = ops.cast(scene, np.zeros(3), d_centre)
    z_centre = np.where(centre.hit, centre.point[:, 2], np.inf).reshape(H, W)
    sub_depth = np.broadcast_to(z_centre.astype(np.float32), (S * S, H, W)).copy()
    return Phasors.zeros(P, (H, W)), Phasors.zeros(P, (H, W)), np.zeros(H * W), centre, z_centre, sub_depth


def camera_bounces(scene: TracedScene, model: SensorModel, ops: Ops, h0: Hits, idx: np.ndarray, d: np.ndarray,
                   pix: np.ndarray, w_s: np.ndarray, rng: np.random.Generator, bounce: Phasors,
                   spec_light: np.ndarray) -> None:
    """Step 3: the specular bounces on the camera side, added into ``bounce`` and ``spec_light``.

    ``h0[idx]`` are the first hits of the rays ``d[idx]`` of pixels ``pix[idx]`` with weights
    ``w_s[idx]``; each bounce casts, lights and adds with ``ops`` (:data:`FAST`, or the reference's).
    """
    cur_hits, cur_idx, cur_dir, cur_pix, weight = h0, idx, d[idx], pix[idx], w_s[idx]
    for _ in range(int(model.bounces)):
        mids = cur_hits.material[cur_idx]
        spec = scene.mat["specular"][mids]
        k = np.flatnonzero(spec >= MIRROR_MIN)
        if k.size == 0:
            break
        n = cur_hits.normal[cur_idx[k]]
        ng = cur_hits.geo_normal[cur_idx[k]]
        r = _perturbed_reflection(cur_dir[k], n, scene.mat["roughness"][mids[k]], rng)
        up = np.einsum("kj,kj->k", ng, r) > 0
        k, r, ng = k[up], r[up], ng[up]
        h1 = ops.cast(scene, cur_hits.point[cur_idx[k]] + 0.01 * ng, r)
        got = h1.hit
        if not got.any():
            break
        k, r = k[got], r[got]
        weight_k = (weight * spec)[k]
        hit_idx = np.flatnonzero(got)
        ok1, rad1, code1 = ops.light(scene, model, h1, hit_idx, -r)
        px = cur_pix[k]
        ops.add(bounce, px[ok1], weight_k[ok1], rad1[ok1], code1[ok1], model.periods_px)
        ops.add_light(spec_light, px[ok1], weight_k[ok1], rad1[ok1])
        cur_hits, cur_idx, cur_dir, cur_pix, weight = h1, hit_idx, r, px, weight_k


def projector_bounces(scene: TracedScene, K: Intrinsics, model: SensorModel, centre: Hits, rng: np.random.Generator,
                      ops: Ops) -> Phasors:
    """Step 4: projector light mirrored by shiny surfaces onto what the camera sees (photon splats),
    cast and added with ``ops`` (:data:`FAST`, or the reference's)."""
    H, W = K.height, K.width
    out = Phasors.zeros(len(model.periods_px), (H, W))
    st = int(model.photon_stride)
    if st == 0:
        return out
    wp, hp = model.projector_size
    u = np.arange(0, wp, st, dtype=np.float64)
    v = np.arange(0, hp, st, dtype=np.float64)
    grid_u, grid_v = np.meshgrid(u, v)
    uu, vv = grid_u.ravel(), grid_v.ravel()
    f = model.projector_f_px
    d = np.stack([(uu - model.projector_c_px[0]) / f, (vv - model.projector_c_px[1]) / f, np.ones_like(uu)], axis=1)
    cos3 = 1.0 / np.linalg.norm(d, axis=1) ** 3
    d = _unit(d)
    proj = model.projector_origin
    q = ops.cast(scene, proj, d)
    spec = np.where(q.hit, scene.mat["specular"][np.maximum(q.material, 0)], 0.0)
    k = np.flatnonzero(q.hit & (spec >= MIRROR_MIN))
    if k.size == 0:
        return out
    r = _perturbed_reflection(d[k], q.normal[k], scene.mat["roughness"][q.material[k]], rng)
    up = np.einsum("kj,kj->k", q.geo_normal[k], r) > 0
    k, r = k[up], r[up]
    p = ops.cast(scene, q.point[k] + 0.01 * q.geo_normal[k], r)
    got = p.hit & (p.point[:, 2] > 1.0)
    k, r = k[got], r[got]
    pt = p.point[got]
    n = p.normal[got]
    mid = p.material[got]
    # the pixel that sees P, and whether P is what it sees
    col = np.rint(K.fx * pt[:, 0] / pt[:, 2] + K.cx).astype(np.int64)
    row = np.rint(K.fy * pt[:, 1] / pt[:, 2] + K.cy).astype(np.int64)
    inside = (col >= 0) & (col < W) & (row >= 0) & (row < H)
    flat = np.where(inside, row * W + col, 0)
    z_seen = np.where(centre.hit, centre.point[:, 2], np.inf)[flat]
    view = -_unit(pt)
    cos_c = np.einsum("kj,kj->k", n, view)
    vis = inside & (np.abs(pt[:, 2] - z_seen) < 1.0 + 0.02 * pt[:, 2] / K.fx / np.maximum(cos_c, 0.05)) & (cos_c > 0.05)
    if not vis.any():
        return out
    # flux of one projector pixel (irradiance 1 at REFERENCE_MM on a facing surface), mirrored,
    # spread over the camera pixel's footprint on P, reflected diffusely toward the camera
    phi = REFERENCE_MM**2 * cos3[k] * st * st / f**2 * scene.mat["specular"][q.material[k]]
    cos_ray = 1.0 / np.linalg.norm(pt / pt[:, 2:3], axis=1)
    area = cos_ray * pt[:, 2] ** 2 / (K.fx * K.fy * np.maximum(cos_c, 0.05))
    radiance = scene.mat["albedo"][mid] / np.pi * phi / area
    code = uu[k]
    ops.add(out, flat[vis], np.ones(int(vis.sum())), (EXPOSURE * radiance)[vis], code[vis], model.periods_px)
    # density estimate: photons are sparse (a projector pixel covers ~3 camera pixels, and convex
    # mirrors spread them further); a kernel of PHOTON_SIGMA_PX (at 1920 across) turns them into
    # the smooth irradiance a rough mirror throws, instead of one-photon speckle
    return _blurred(out, PHOTON_SIGMA_PX * K.width / FULL_SIZE[1] + 0.5)


def _blurred(ph: Phasors, sigma: float) -> Phasors:
    z = np.empty_like(ph.z)
    for k in range(ph.z.shape[0]):
        z[k].real = ndimage.gaussian_filter(ph.z[k].real, sigma, mode="constant")
        z[k].imag = ndimage.gaussian_filter(ph.z[k].imag, sigma, mode="constant")
    return Phasors(z, ndimage.gaussian_filter(ph.intensity, sigma, mode="constant"))


def _glare(ph: Phasors, K: Intrinsics, model: SensorModel) -> Phasors:
    """Step 5: the share of each pixel's light the lens spreads over its neighbours."""
    if model.glare_share == 0:
        return Phasors.zeros(ph.z.shape[0], ph.intensity.shape)
    sigma = model.glare_sigma_px * K.width / FULL_SIZE[1]
    spread = _blurred(ph, sigma)
    g = model.glare_share
    # g * (spread - ph), written into the spread's own images (the same ufuncs: the same bits)
    z, intensity = spread.z, spread.intensity
    np.multiply(g, np.subtract(z, ph.z, out=z), out=z)
    np.multiply(g, np.subtract(intensity, ph.intensity, out=intensity), out=intensity)
    return Phasors(z, intensity)


@dataclass(frozen=True, slots=True)
class Decoded:
    """A decoded pixel image.

    Attributes
    ----------
    code : (H, W) float64 ndarray
        Decoded projector column (NaN where rejected).
    signal : (H, W) float64 ndarray
        Fringe amplitude at the finest period in the exposure read (full scale).
    saturated : (H, W) bool ndarray
        Saturates even the shortest exposure.
    """

    code: np.ndarray
    signal: np.ndarray
    saturated: np.ndarray


def decode(ph: Phasors, model: SensorModel) -> Decoded:
    """Step 6: the projector column each pixel decodes, or NaN where the sensor rejects it.

    Unwrapping goes from the coarsest period to the finest; a pixel is rejected when a finer
    period's phase disagrees with the coarser estimate by more than a quarter of its period
    (the consistency check of multi-frequency phase shifting), when the fringe contrast at any
    period is below ``min_contrast``, when its fringe signal is below ``min_signal`` in the longest
    exposure that does not saturate, or when even the shortest exposure saturates.
    """
    T = model.periods_px
    intensity = ph.intensity
    with np.errstate(invalid="ignore", divide="ignore"):
        contrast = np.abs(ph.z[0]) / intensity
        u = (np.angle(ph.z[0]) / (2 * np.pi)) % 1.0 * T[0]
        consistent = np.ones(intensity.shape, bool)
        for k in range(1, len(T)):
            contrast = np.minimum(contrast, np.abs(ph.z[k]) / intensity)
            frac = (np.angle(ph.z[k]) / (2 * np.pi)) % 1.0 * T[k]
            nxt = np.round((u - frac) / T[k]) * T[k] + frac
            consistent &= np.abs(nxt - u) <= T[k] / 4
            u = nxt
    gains = sorted(model.hdr_gains, reverse=True)
    gain = np.full(intensity.shape, gains[-1])
    for g in gains[::-1]:
        gain = np.where(intensity * g <= 1.0, g, gain)
    saturated = intensity * gains[-1] > 1.0
    amp = np.abs(ph.z[-1])
    signal = amp * gain
    ok = (signal >= model.min_signal) & (contrast >= model.min_contrast) & consistent & ~saturated
    return Decoded(np.where(ok, u, np.nan), signal, saturated)


def triangulate(code: np.ndarray, K: Intrinsics, model: SensorModel) -> np.ndarray:
    """Step 7: camera z (mm) where each pixel's centre ray meets the projector column ``code``.

    NaN where ``code`` is NaN or the two do not meet in front of the camera.
    """
    rx = (np.arange(K.width) - K.cx) / K.fx
    xp = (code - model.projector_c_px[0]) / model.projector_f_px
    with np.errstate(invalid="ignore", divide="ignore"):
        z = model.baseline_mm / (rx[None, :] - xp)
    return np.where(z > 0, z, np.nan)


def footprint_distance_mm(z_mm: np.ndarray, centre_mm: np.ndarray, sub_mm: np.ndarray) -> np.ndarray:
    """|z - the nearest of the pixel's surfaces| along z (NaN where z is NaN): the truth rule's distance.

    ``centre_mm`` the centre ray's camera z, ``sub_mm`` (S, ...) the sub-pixel rays', any shape alike.
    """
    d = np.abs(z_mm - centre_mm)
    for s in sub_mm:
        d = np.fmin(d, np.abs(z_mm - s))
    return np.where(np.isfinite(z_mm), d, np.nan)


@small_pages()
def measure(rec: Received, K: Intrinsics, model: SensorModel, rng: np.random.Generator) -> Measured:
    """Decode and triangulate: (measured z, noise-free z, sigma_z, staged noise-free z, saturated).

    The staged depths decode the light of successively more paths: direct only (differences are
    then sub-pixel mixing), plus the specular bounces (plus the glare: the measured light); they
    attribute an error to the physics that made it, so they are decoded only where the noise-free
    depth fails the truth rule (farther than ``outlier_sigmas`` noise sigmas from every surface
    the pixel's footprint sees, :func:`footprint_distance_mm`) and NaN elsewhere: the pixels the
    attribution judges, and per pixel the values of decoding whole images (``decode`` and
    ``triangulate`` work pixel by pixel), for a third of the decoding.
    """
    staged = [rec.direct, rec.camera_bounce, rec.projector_bounce]
    final = decode(rec.direct.plus(rec.camera_bounce).add_in_place(rec.projector_bounce).add_in_place(rec.glare),
                   model)
    z_meas, z_clean, sigma_z, _, saturated = triangulate_decoded([final], K, model, rng)
    H, W = z_clean.shape
    centre = rec.centre
    z_true = np.where(centre.hit, centre.point[:, 2], np.nan)
    sub = rec.sub_depth_mm.reshape(rec.sub_depth_mm.shape[0], -1)
    with np.errstate(invalid="ignore"):
        fails = np.flatnonzero(footprint_distance_mm(z_clean.reshape(-1), z_true, sub)
                               > model.outlier_sigmas * sigma_z.reshape(-1))
    # the stages at those pixels, summed as the whole images are: direct, then (direct + bounce) + photons
    at = [Phasors(np.ascontiguousarray(p.z.reshape(p.z.shape[0], -1)[:, fails]), p.intensity.reshape(-1)[fails])
          for p in staged]
    cols = fails % W
    depths = []
    for ph in (at[0], at[0].plus(at[1]).add_in_place(at[2])):
        img = np.full(H * W, np.nan)
        img[fails] = triangulate_at(decode(ph, model).code, cols, K, model)
        depths.append(img.reshape(H, W))
    return z_meas, z_clean, sigma_z, depths, saturated


def triangulate_at(code: np.ndarray, cols: np.ndarray, K: Intrinsics, model: SensorModel) -> np.ndarray:
    """:func:`triangulate` of pixels in columns ``cols`` that decoded ``code`` (1-D alike): the same values."""
    rx = (np.arange(K.width) - K.cx) / K.fx
    xp = (code - model.projector_c_px[0]) / model.projector_f_px
    with np.errstate(invalid="ignore", divide="ignore"):
        z = model.baseline_mm / (rx[cols] - xp)
    return np.where(z > 0, z, np.nan)


#: What :func:`measure` returns: measured z, noise-free z, sigma_z, the staged noise-free depths, saturated.
Measured = tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray], np.ndarray]


def triangulate_decoded(decoded: list[Decoded], K: Intrinsics, model: SensorModel,
                        rng: np.random.Generator) -> Measured:
    """The depths of the decoded stages (the last is what the sensor measures, with its noise): as
    :func:`measure` returns them."""
    final = decoded[-1]
    sigma_u = model.sigma_code(final.signal)
    noise = correlated_noise(final.code.shape, rng).astype(np.float64) * sigma_u
    z_clean = triangulate(final.code, K, model)
    z_meas = triangulate(final.code + noise, K, model)
    z_meas[~np.isfinite(z_clean)] = np.nan
    sigma_z = model.depth_per_code_mm(np.where(np.isfinite(z_clean), z_clean, 1.0)) * sigma_u
    staged = [triangulate(dc.code, K, model) for dc in decoded[:-1]]
    return z_meas, z_clean, sigma_z, staged, final.saturated
