"""A camera's own filters on the ray-traced sensor's raw cloud (``zcut synth --camera-filters``).

A real structured-light camera delivers its point cloud after its own filters; the ray-traced
sensor's decoder alone (:func:`.optics.decode`) is what such a camera does before them. The three
filters here follow what Zivid documents for its cameras (``docs/raytraced.md``, "The camera's own
filters", cites the pages); the algorithms behind them are not public, so each is the plainest
reading of the documented rule on what the ray-traced sensor knows about a pixel:

- **Noise filter** (Zivid ``Processing.Filters.Noise.Removal``: "discard points with
  signal-to-noise ratio (SNR) values below a threshold"; Zivid's hint: a threshold of 7). The SNR of
  a pixel is taken as ``1 / sigma_phase``, the phase noise (radians) of phase shifting at the finest
  period: ``SNR = T_fine / (2π sigma_code(signal))`` with the sensor's own code noise
  (:meth:`.optics.SensorModel.sigma_code`). At the default sensor: SNR 21.6 at the reference signal
  0.375, 7 at signal 0.039, 2.2 at the readable minimum 0.004.
- **Reflection filter** (Zivid ``Processing.Filters.Reflection.Removal``: "discard points likely
  introduced by reflections", seen as "ghost planes"). A pixel that integrates paths with different
  codes (a direct path and a mirrored one) decodes phases that no single code explains at every
  period (the error detection of decoding one pixel with several codes, Gupta et al., "A practical
  approach to 3D scanning in the presence of interreflections, subsurface scattering and
  defocus", IJCV 2013). Here: the wrapped phase of every coarser period against the code unwrapped
  from the finest, in units of that period's code noise (``sigma_code(signal) T_k / T_fine``); the
  pixel is discarded when any exceeds ``reflection_sigmas``. A ghost strong enough to own every
  period decodes consistently and passes, as documented ghost planes do in part.
- **Outlier filter** (Zivid ``Processing.Filters.Outlier.Removal``: "discard point if Euclidean
  distance to neighboring points is above a threshold"; 5 mm in Zivid's examples). Read literally on
  the organized cloud: a point is discarded when no valid point of its 8-neighbourhood lies within
  ``outlier_mm`` of it (isolated points; a patch of two or more points close together survives it,
  which is what Zivid's separate cluster filter is for, not modelled).

Order: noise, reflection, then outlier on what the first two left. A discarded point becomes NaN, as
a camera delivers it; the scene's truth (``/ground_truth/depth``) is untouched, and the truth masks
only judge the points the camera delivers. The filters draw no random numbers: the rest of a frame
(its noise, its colour image) is the same bytes with or without them.

Not modelled: Zivid's noise suppression and repair, hole repair, Gaussian smoothing and contrast
distortion correction (they move or add points; they do not discard), the cluster filter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from replay.synth.raytrace.optics import Decoded, Phasors, Received, SensorModel, decode
from zcut.errors import ParameterError

#: code values of :attr:`CameraFiltered.removed`
KEPT, NOISE, REFLECTION, OUTLIER = 0, 1, 2, 3
FILTER_NAMES = {NOISE: "noise", REFLECTION: "reflection", OUTLIER: "outlier"}


@dataclass(frozen=True, slots=True)
class CameraFilters:
    """Which of the camera's filters run and their thresholds (None: that filter off).

    Attributes
    ----------
    noise_snr : float or None
        Noise filter: discard pixels whose SNR (module docstring) is below this (Zivid's hint: 7).
    reflection_sigmas : float or None
        Reflection filter: discard pixels whose phases disagree with their decoded code by more than
        this many code-noise sigmas at any coarser period.
    outlier_mm : float or None
        Outlier filter: discard points with no valid 8-neighbour within this Euclidean distance (mm).
    """

    noise_snr: float | None = 7.0
    reflection_sigmas: float | None = 4.0
    outlier_mm: float | None = 5.0

    def __post_init__(self) -> None:
        for name in ("noise_snr", "reflection_sigmas", "outlier_mm"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ParameterError(f"CameraFilters.{name} must be a positive number or None, got {v!r}")

    @property
    def enabled(self) -> bool:
        """Any filter runs."""
        return not (self.noise_snr is None and self.reflection_sigmas is None and self.outlier_mm is None)

    def describe(self) -> str:
        """One line for the log's metadata: the filters that run and their thresholds."""
        parts = []
        if self.noise_snr is not None:
            parts.append(f"noise: SNR < {self.noise_snr:g}")
        if self.reflection_sigmas is not None:
            parts.append(f"reflection: phase residual > {self.reflection_sigmas:g} code-noise sigmas")
        if self.outlier_mm is not None:
            parts.append(f"outlier: no 8-neighbour within {self.outlier_mm:g} mm")
        return "; ".join(parts) if parts else "off"


@dataclass(frozen=True, slots=True)
class CameraFiltered:
    """What the filters did to one frame.

    Attributes
    ----------
    z_mm : (H, W) float64 ndarray
        The measured depth after the filters (NaN where discarded or never measured).
    removed : (H, W) uint8 ndarray
        Which filter discarded a pixel that the decoder had measured (:data:`NOISE`,
        :data:`REFLECTION`, :data:`OUTLIER`), else :data:`KEPT`.
    snr : (H, W) float64 ndarray
        The pixel's SNR (module docstring).
    residual_sigmas : (H, W) float64 ndarray
        The largest phase residual over the coarser periods, in code-noise sigmas (NaN where not decoded).
    """

    z_mm: np.ndarray
    removed: np.ndarray
    snr: np.ndarray
    residual_sigmas: np.ndarray


def snr_of(signal: np.ndarray, model: SensorModel) -> np.ndarray:
    """SNR = 1 / sigma_phase at the finest period: ``T_fine / (2π sigma_code(signal))``."""
    return np.asarray(model.periods_px[-1] / (2.0 * np.pi * model.sigma_code(signal)))


def phase_residual_sigmas(ph: Phasors, decoded: Decoded, model: SensorModel) -> np.ndarray:
    """(H, W): the largest disagreement, over the periods coarser than the finest, between the
    period's wrapped phase and the decoded code, in that period's code-noise sigmas.

    A pixel lit by one path (one code) has zero residual whatever its noise-free signal; one that
    sums paths of different codes has phases that no single code explains.
    """
    T = model.periods_px
    code = decoded.code
    out = np.zeros(code.shape)
    if len(T) < 2:
        return np.where(np.isfinite(code), out, np.nan)
    sigma_fine = model.sigma_code(decoded.signal)
    with np.errstate(invalid="ignore"):
        for k in range(len(T) - 1):
            frac = (np.angle(ph.z[k]) / (2 * np.pi)) % 1.0 * T[k]
            d = (frac - code) % T[k]
            d = np.minimum(d, T[k] - d)
            out = np.fmax(out, d / (sigma_fine * T[k] / T[-1]))
    return np.where(np.isfinite(code), out, np.nan)


def isolated_points(xyz_mm: np.ndarray, *, within_mm: float) -> np.ndarray:
    """(H, W) bool: valid points with no valid 8-neighbour within ``within_mm`` (Euclidean).

    A numba kernel doing per point what :func:`isolated_points_reference` does with eight shifted
    copies of the cloud: the squared distance summed as numpy sums the last axis,
    ``((dx² + dy²) + dz²)``, against ``within_mm²`` (the same bits, without the cloud-sized
    temporaries: 0.42 of a 1920 x 1200 frame's 0.84 CPU-s of filters).

    Parameters
    ----------
    xyz_mm : (H, W, 3) float ndarray
        The organized cloud, NaN where invalid.
    """
    xyz = np.ascontiguousarray(xyz_mm, np.float64)
    out = np.empty(xyz.shape[:2], bool)
    _isolated(xyz, float(within_mm) ** 2, out)
    return out


@nb.njit(cache=True, error_model="numpy")
def _isolated(xyz: np.ndarray, within2: float, out: np.ndarray) -> None:  # pragma: no cover - numba
    h, w = out.shape
    for r in range(h):
        for c in range(w):
            x0, x1, x2 = xyz[r, c, 0], xyz[r, c, 1], xyz[r, c, 2]
            if not (np.isfinite(x0) and np.isfinite(x1) and np.isfinite(x2)):
                out[r, c] = False
                continue
            near = False
            for rr in range(max(r - 1, 0), min(r + 2, h)):
                for cc in range(max(c - 1, 0), min(c + 2, w)):
                    if rr == r and cc == c:
                        continue
                    d0 = xyz[rr, cc, 0] - x0
                    d1 = xyz[rr, cc, 1] - x1
                    d2 = xyz[rr, cc, 2] - x2
                    if (d0 * d0 + d1 * d1) + d2 * d2 <= within2:
                        near = True
            out[r, c] = not near


def isolated_points_reference(xyz_mm: np.ndarray, *, within_mm: float) -> np.ndarray:
    """:func:`isolated_points` in whole-array numpy (the reference the kernel equals bit for bit).

    Parameters
    ----------
    xyz_mm : (H, W, 3) float ndarray
        The organized cloud, NaN where invalid.
    """
    h, w = xyz_mm.shape[:2]
    valid = np.isfinite(xyz_mm).all(axis=2)
    pad = np.full((h + 2, w + 2, 3), np.nan)
    pad[1:-1, 1:-1] = xyz_mm
    near = np.zeros((h, w), bool)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr == 0 and dc == 0:
                continue
            other = pad[1 + dr:1 + dr + h, 1 + dc:1 + dc + w]
            with np.errstate(invalid="ignore"):
                near |= np.sum((other - xyz_mm) ** 2, axis=2) <= within_mm**2
    return np.asarray(valid & ~near)


def final_phasors(rec: Received) -> Phasors:
    """The light the sensor decodes (direct, both bounces and the glare), as :func:`.optics.measure` sums it."""
    return rec.direct.plus(rec.camera_bounce).add_in_place(rec.projector_bounce).add_in_place(rec.glare)


def apply_camera_filters(z_mm: np.ndarray, rec: Received, rays: np.ndarray, model: SensorModel,
                         filters: CameraFilters) -> CameraFiltered:
    """Run ``filters`` on the measured depth ``z_mm`` (H, W; NaN invalid) of the light ``rec``.

    ``rays`` : (H, W, 3) the pixels' rays scaled to z = 1 (``replay.synth.sensor.pixel_rays``).
    """
    ph = final_phasors(rec)
    decoded = decode(ph, model)
    snr = snr_of(decoded.signal, model)
    residual = phase_residual_sigmas(ph, decoded, model)
    valid = np.isfinite(z_mm)
    removed = np.zeros(z_mm.shape, np.uint8)
    with np.errstate(invalid="ignore"):
        if filters.noise_snr is not None:
            removed[valid & (snr < filters.noise_snr)] = NOISE
        if filters.reflection_sigmas is not None:
            removed[valid & (removed == KEPT) & (residual > filters.reflection_sigmas)] = REFLECTION
    z = np.where(removed == KEPT, z_mm, np.nan)
    if filters.outlier_mm is not None:
        lone = isolated_points(rays * z[..., None], within_mm=filters.outlier_mm)
        removed[lone] = OUTLIER
        z = np.where(lone, np.nan, z)
    return CameraFiltered(z, removed, snr, residual)
