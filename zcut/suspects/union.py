"""The union of the detectors, grouped: :func:`suspects` runs them all on one frame (:mod:`zcut.suspects`)."""

from __future__ import annotations

import dataclasses
import threading
from dataclasses import dataclass

import numba
import numpy as np

from ..cloud import Intrinsics, check_mask, check_xyz
from ..edge_surface import EdgeSurfaceParams, _check_args
from ..errors import InputShapeError, ParameterError, describe_array
from ..params import SuspectParams
from ..sor_workspace import SorWorkspace
from ..types import XYZ, FloatImage, Labels, Mask
from .detectors import (
    ABOVE_RIM,
    DETECTORS,
    FLOATING,
    PATCH,
    RESIDUAL_UP,
    detector_bits,
    detector_names,
    label_medians,
)
from .floating import FLOATING_STEP_SIGMAS, floating_components
from .gaps import GAP_MAX_RADIUS, GAP_MIN_PIXELS, _gap_kernel
from .grouping import group_suspects
from .noise import NoiseProfile, local_height, noise_profile
from .patches import PATCH_RHO, cut_off_patches
from .residuals import fill_blobs, surface_residuals
from .select import order_pair_large
from .surfaces import LazySurfaces, gate_arrays, lazy_surfaces


@dataclass(frozen=True, slots=True)
class SuspectGroup:
    """One group of suspects to review (accept or reject as a whole).

    Attributes
    ----------
    label : int
        Its value in :attr:`SuspectResult.groups` (1 = highest score).
    detectors : tuple of str
        The detectors that flagged any of its pixels (:data:`DETECTORS` order); the first is the one it
        was grouped by.
    size_px : int
    gap_mm : float
        Median gap of its pixels to the local surface (mm, positive = toward the camera; NaN when no
        measured surface is near).
    bbox : tuple of int
        (row0, col0, row1, col1), ends exclusive.
    score : float
    """

    label: int
    detectors: tuple[str, ...]
    size_px: int
    gap_mm: float
    bbox: tuple[int, int, int, int]
    score: float


@dataclass(frozen=True, slots=True)
class SuspectResult:
    """The suspects of one frame and their groups.

    Attributes
    ----------
    mask : (H, W) bool ndarray
        Every suspect pixel (inside the zone, or above the rim).
    groups : (H, W) int32 ndarray
        0 = none, g = the g-th group; groups are numbered by decreasing score. ``mask == groups > 0``.
    detectors : (H, W) uint8 ndarray
        Per pixel, the bits (1 << i for :data:`DETECTORS`\\[i]) of the detectors that flagged it.
    gap_mm : (H, W) float64 ndarray
        Per suspect pixel, its gap (mm, positive = toward the camera): its residual for a pixel the
        residual detectors flagged alone, else its gap to the local surface (:func:`local_gaps`);
        NaN elsewhere or when no measured surface is near.
    residual_mm : (H, W) float64 ndarray
        The signed surface residual of every judged pixel (:func:`surface_residuals`); NaN outside
        the zone, +inf where no continuation exists.
    group_detectors : (n,) uint8 ndarray
        Bits of the detectors that flagged any pixel of each group.
    group_primary : (n,) uint8 ndarray
        Index in :data:`DETECTORS` of the detector each group was grouped by.
    group_size : (n,) int64 ndarray
    group_gap_mm : (n,) float64 ndarray
    group_bbox : (n, 4) int32 ndarray
        row0, col0, row1, col1 (ends exclusive).
    group_score : (n,) float64 ndarray
        sqrt(size_px) · |gap_mm| (0 when the gap is unknown): large groups far from the surface first.
    noise_mm : float
        The median over the zone of σ̂ at each pixel's height (:func:`noise_profile`).
    threshold_mm : float
        The median over the zone of τ = max(min_residual_mm, noise_k · σ̂(height)).
    noise_profile : NoiseProfile
        σ̂ and the depth step as functions of height (:func:`noise_profile`).
    floating_step_mm : float
        The floating detector's z-cut step.
    merge_radius_px : (5,) int64 ndarray
        The merge radius each detector ended with.
    surface_mm : (H, W) float64 ndarray or None
        With ``edge_surface``: every valid pixel's signed distance to the nearest surface fitted on
        one side of an edge (:func:`zcut.edge_surface.signed_edge_distance`; mm, positive = toward
        the camera, NaN where unmeasured, +inf where no surface is near); else None. Measured on
        first access (the suspects need it only at the pixels whose gap it gives); until then the
        result holds the frame's surfaces (:class:`zcut.suspects.surfaces.LazySurfaces`: the frame in
        mm, the frame's gate, the patches decided and the planes fitted so far; ~80 MB at 1920 × 1200).

    Notes
    -----
    The result owns the frame in mm its surfaces hold (55 MB at 1920 × 1200) until :meth:`release` hands it back
    to the calling thread, whose next call with ``edge_surface`` then writes its own frame into it instead of
    mapping a fresh one (:func:`release_frame_mm`). A result never released keeps its frame until it is dropped,
    and the next call maps a fresh one. ``with suspects(...) as res:`` releases on leaving the block. After
    :meth:`release` every field reads as before, and so does :attr:`surface_mm` when it was read before; read
    first, it raises :class:`~zcut.errors.ZcutError`.
    """

    mask: Mask
    groups: Labels
    detectors: np.ndarray
    gap_mm: np.ndarray
    residual_mm: np.ndarray
    group_detectors: np.ndarray
    group_primary: np.ndarray
    group_size: np.ndarray
    group_gap_mm: np.ndarray
    group_bbox: np.ndarray
    group_score: np.ndarray
    noise_mm: float
    threshold_mm: float
    noise_profile: NoiseProfile
    floating_step_mm: float
    merge_radius_px: np.ndarray
    _surface_mm: np.ndarray | None = None
    _surfaces: LazySurfaces | None = dataclasses.field(default=None, repr=False, compare=False)

    @property
    def surface_mm(self) -> np.ndarray | None:
        if self._surface_mm is None and self._surfaces is not None:
            object.__setattr__(self, "_surface_mm", self._surfaces.distance())
        return self._surface_mm

    def release(self) -> None:
        """Hand the frame in mm this result's surfaces hold back to the calling thread, for its next call
        (:func:`release_frame_mm`; nothing without ``edge_surface``, or when released already). Call it when
        :attr:`surface_mm` will not be read (again): the labelling page's groups do
        (``annotate/groups.py``)."""
        if self._surfaces is not None:
            a_mm = self._surfaces.release_frame()
            if a_mm is not None:
                _give_back_frame_mm(a_mm)

    def __enter__(self) -> SuspectResult:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    @property
    def n_groups(self) -> int:
        return int(self.group_size.size)

    def group(self, label: int) -> SuspectGroup:
        """Group ``label`` (1-based) as a record."""
        if not 1 <= label <= self.n_groups:
            raise ParameterError(f"group label must be in 1..{self.n_groups}, got {label!r}")
        i = label - 1
        p = int(self.group_primary[i])
        names = detector_names(int(self.group_detectors[i]))
        names = (DETECTORS[p],) + tuple(n for n in names if n != DETECTORS[p])
        r0, c0, r1, c1 = (int(v) for v in self.group_bbox[i])
        return SuspectGroup(label, names, int(self.group_size[i]), float(self.group_gap_mm[i]), (r0, c0, r1, c1),
                            float(self.group_score[i]))

    def detector_mask(self, name: str) -> Mask:
        """(H, W) bool: the pixels detector ``name`` flagged."""
        return (self.detectors & detector_bits([name])) > 0


@numba.njit(cache=True)
def _prepare_kernel(a, zone_in, easy_in, valid, zone, easy, h_all, context):  # type: ignore[no-untyped-def]  # numba kernel
    H, W = valid.shape
    for i in range(H):
        for j in range(W):
            z = a[i, j, 2]
            v = np.isfinite(a[i, j, 0]) and np.isfinite(a[i, j, 1]) and np.isfinite(z)
            e = easy_in[i, j]
            valid[i, j] = v
            zone[i, j] = zone_in[i, j] and v and not e
            easy[i, j] = e and v
            h = -1000.0 * np.float64(z) if v else np.nan
            h_all[i, j] = h
            context[i, j] = np.nan if (e and v) else h


@numba.njit(cache=True)
def _frame_mm(a, out):  # type: ignore[no-untyped-def]  # numba kernel
    """``out = a.astype(np.float64) * 1000.0`` (the same products, NaN's too) in one pass."""
    f = a.reshape(-1)
    o = out.reshape(-1)
    for q in range(f.size):
        o[q] = np.float64(f[q]) * 1000.0


def _prepare(a: np.ndarray, zone: Mask, easy: Mask) -> tuple[Mask, Mask, Mask, np.ndarray, np.ndarray]:
    """(valid, zone & valid & ~easy, easy & valid, every measured point's height -1000 z (NaN elsewhere),
    the context: those heights but above the rim) in one sweep of the frame."""
    if a.dtype not in (np.float32, np.float64):  # float16, longdouble: whole-frame numpy
        valid = np.isfinite(a[..., 0]) & np.isfinite(a[..., 1]) & np.isfinite(a[..., 2])
        h_all = np.where(valid, -1000.0 * a[..., 2].astype(np.float64), np.nan)
        return valid, zone & valid & ~easy, easy & valid, h_all, np.where(easy & valid, np.nan, h_all)
    H, W = zone.shape
    out_valid, out_zone, out_easy = np.empty((H, W), bool), np.empty((H, W), bool), np.empty((H, W), bool)
    h_all, context = np.empty((H, W)), np.empty((H, W))
    _prepare_kernel(a, zone, easy, out_valid, out_zone, out_easy, h_all, context)
    return out_valid, out_zone, out_easy, h_all, context


@numba.njit(cache=True, inline="always")
def _np_maximum(a, b):  # type: ignore[no-untyped-def]  # numba kernel
    """``np.maximum(a, b)`` of two doubles: NaN if either is, else the larger, ``a`` on a tie (-0.0, 0.0)."""
    if a != a or b != b:
        return a + b
    return a if a >= b else b


@numba.njit(cache=True)
def _nan_to_num(a, nan):  # type: ignore[no-untyped-def]  # numba kernel
    """``np.nan_to_num(a, nan=nan)`` in place (±inf to the largest finite doubles)."""
    big = np.finfo(np.float64).max
    f = a.reshape(-1)
    for q in range(f.size):
        x = f[q]
        if x != x:
            f[q] = nan
        elif x == np.inf:
            f[q] = big
        elif x == -np.inf:
            f[q] = -big


@numba.njit(cache=True, error_model="numpy")  # IEEE division
def _interp_in_place(a, xp, fp):  # type: ignore[no-untyped-def]  # numba kernel
    """``a[:] = np.interp(np.nan_to_num(a, nan=xp[0]), xp, fp)`` (``xp`` non-decreasing, at least one entry),
    numpy's arithmetic: j the last index with xp[j] <= x (what numpy's ``binary_search_with_guess`` finds);
    fp[0] left of xp[0], fp[-1] from xp[-1] on and where xp[j] == x, else slope · (x - xp[j]) + fp[j] with
    the slope (fp[j+1] - fp[j]) / (xp[j+1] - xp[j]), and where that is NaN, slope · (x - xp[j+1]) + fp[j+1],
    and fp[j] where that is NaN too and fp[j] == fp[j+1]. One entry: fp[0] everywhere.

    A block of values at a time: their j counted without a branch (for xp[0] <= x < xp[-1], j is the count
    of xp[1 .. n-2] <= x), a compare per height and value in the processor's vector lanes (the local heights
    of neighbouring pixels jump between bins: a search per value mispredicts), then each value's case."""
    big = np.finfo(np.float64).max
    n = xp.size
    f = a.reshape(-1)
    slopes = np.empty(max(n - 1, 0))
    for k in range(n - 1):
        slopes[k] = (fp[k + 1] - fp[k]) / (xp[k + 1] - xp[k])
    lo = xp[0]
    hi = xp[n - 1]
    B = 1024
    xb = np.empty(B)
    jb = np.empty(B, np.int64)
    for s0 in range(0, f.size, B):
        m = min(B, f.size - s0)
        for t in range(m):
            x = f[s0 + t]
            if x != x:
                x = lo
            elif x == np.inf:
                x = big
            elif x == -np.inf:
                x = -big
            xb[t] = x
            jb[t] = 0
        for k in range(1, n - 1):
            xk = xp[k]
            for t in range(m):
                jb[t] += xk <= xb[t]
        for t in range(m):
            x = xb[t]
            if n == 1 or x < lo:
                f[s0 + t] = fp[0]
                continue
            if x >= hi:  # x > xp[-1]: fp[-1]; x == xp[-1]: j = n - 1, fp[n - 1]
                f[s0 + t] = fp[n - 1]
                continue
            j = jb[t]
            if xp[j] == x:
                f[s0 + t] = fp[j]
                continue
            sl = slopes[j]
            v = sl * (x - xp[j]) + fp[j]
            if v != v:
                v = sl * (x - xp[j + 1]) + fp[j + 1]
                if v != v and fp[j] == fp[j + 1]:
                    v = fp[j]
            f[s0 + t] = v


def _sigma_px(profile: NoiseProfile, context: np.ndarray, *, out: np.ndarray | None = None) -> np.ndarray:
    """``profile.sigma_at(local_height(context))``, the lookup in place of the local heights (in ``out`` when
    given: :func:`local_height`'s)."""
    lh = local_height(context, out=out)
    if profile.heights_mm.size == 0:
        return np.zeros(lh.shape)
    xp = np.ascontiguousarray(profile.heights_mm, np.float64)
    fp = np.ascontiguousarray(profile.sigma_mm, np.float64)
    if not (np.isfinite(xp).all() and (xp[1:] >= xp[:-1]).all()):  # not a profile's heights: numpy's lookup
        _nan_to_num(lh, float(xp[0]))
        looked_up: np.ndarray = np.interp(lh, xp, fp)
        return looked_up
    _interp_in_place(lh, xp, fp)
    return lh


@numba.njit(cache=True)
def _thresholds(sigma_px, k, min_residual, jump_mm, tau, jump):  # type: ignore[no-untyped-def]  # numba kernel
    """τ = np.maximum(min_residual, k · σ̂) and the jump np.maximum(jump_mm, k · σ̂) of every pixel, one pass."""
    s = sigma_px.reshape(-1)
    t = tau.reshape(-1)
    u = jump.reshape(-1)
    for q in range(s.size):
        x = k * s[q]
        t[q] = _np_maximum(min_residual, x)
        u[q] = _np_maximum(jump_mm, x)


@numba.njit(cache=True, error_model="numpy")  # IEEE division
def _rough(zone, residual, tau, out):  # type: ignore[no-untyped-def]  # numba kernel
    """zone & ~(|residual| <= τ): in the zone, off the surface or without a continuation (inf, NaN)."""
    z = zone.reshape(-1)
    r = residual.reshape(-1)
    t = tau.reshape(-1)
    o = out.reshape(-1)
    for q in range(z.size):
        o[q] = z[q] and not abs(r[q]) <= t[q]


@numba.njit(cache=True, error_model="numpy")  # IEEE division
def _gap_ratio(gap, tau, min_residual, out):  # type: ignore[no-untyped-def]  # numba kernel
    """|gap| / τ_px, τ_px = τ where finite and > 0, else min_residual (the grouping's strength)."""
    g = gap.reshape(-1)
    t = tau.reshape(-1)
    o = out.reshape(-1)
    for q in range(g.size):
        x = t[q]
        o[q] = abs(g[q]) / (x if np.isfinite(x) and x > 0 else min_residual)


@numba.njit(cache=True)
def _codes_and_masks(codes, off, filled, floating, easy, patch, residual, valid, h, mask, by_residual, gap_at, surface):  # type: ignore[no-untyped-def]  # numba kernel
    """One pass of what ``suspects()`` did with whole-frame numpy between the detectors and the gaps:
    ``codes[filled & ~off] = RESIDUAL_UP``, ``codes[floating] |= FLOATING``, ``codes[easy] |= ABOVE_RIM``,
    ``codes[patch] |= PATCH``,
    ``mask = codes > 0``, ``by_residual = off & (codes & (FLOATING | ABOVE_RIM) == 0) & isfinite(residual)``,
    :func:`local_gaps`' suspects ``mask & ~by_residual & ~floating`` and its surface ``valid & ~mask &
    isfinite(h)``. Returns the count of ``by_residual``."""
    c_ = codes.reshape(-1)
    o_ = off.reshape(-1)
    f_ = filled.reshape(-1)
    fl = floating.reshape(-1)
    e_ = easy.reshape(-1)
    p_ = patch.reshape(-1)
    r_ = residual.reshape(-1)
    v_ = valid.reshape(-1)
    h_ = h.reshape(-1)
    m_ = mask.reshape(-1)
    b_ = by_residual.reshape(-1)
    g_ = gap_at.reshape(-1)
    s_ = surface.reshape(-1)
    n = 0
    for q in range(c_.size):
        c = c_[q]
        if f_[q] and not o_[q]:
            c = RESIDUAL_UP
        if fl[q]:
            c |= FLOATING
        if e_[q]:
            c |= ABOVE_RIM
        if p_[q]:
            c |= PATCH
        c_[q] = c
        m = c > 0
        m_[q] = m
        b = o_[q] and (c & (FLOATING | ABOVE_RIM)) == 0 and np.isfinite(r_[q])
        b_[q] = b
        n += b
        g_[q] = m and not b and not fl[q]
        s_[q] = v_[q] and not m and np.isfinite(h_[q])
    return n


@numba.njit(cache=True)
def _residual_gaps(by_residual, residual, gap, n):  # type: ignore[no-untyped-def]  # numba kernel
    """``gap[by_residual] = residual[by_residual]``; returns the flat indices of ``by_residual`` (``n`` of them,
    raster order)."""
    b_ = by_residual.reshape(-1)
    r_ = residual.reshape(-1)
    g_ = gap.reshape(-1)
    idx = np.empty(n, np.int64)
    k = 0
    for q in range(b_.size):
        if b_[q]:
            g_[q] = r_[q]
            idx[k] = q
            k += 1
    return idx


@numba.njit(cache=True)
def _group_tables(groups, codes, n):  # type: ignore[no-untyped-def]  # numba kernel
    """Per group 1..n of ``groups``: its size (``np.bincount``), the OR of its pixels' codes, its bounding
    box (row0, col0, row1, col1, as ``ndimage.find_objects``; every label has pixels); and the flat indices
    of the grouped pixels in raster order."""
    H, W = groups.shape
    size = np.zeros(n, np.int64)
    bits = np.zeros(n, np.uint8)
    bbox = np.empty((n, 4), np.int32)
    for g in range(n):
        bbox[g, 0] = H
        bbox[g, 1] = W
        bbox[g, 2] = 0
        bbox[g, 3] = 0
    m = 0
    for i in range(H):
        for j in range(W):
            if groups[i, j] > 0:
                m += 1
    idx = np.empty(m, np.int64)
    m = 0
    for i in range(H):
        for j in range(W):
            g = groups[i, j] - 1
            if g < 0:
                continue
            idx[m] = i * W + j
            m += 1
            size[g] += 1
            bits[g] |= codes[i, j]
            bbox[g, 0] = min(bbox[g, 0], i)
            bbox[g, 1] = min(bbox[g, 1], j)
            bbox[g, 2] = max(bbox[g, 2], i + 1)
            bbox[g, 3] = max(bbox[g, 3], j + 1)
    return size, bits, bbox, idx


@numba.njit(cache=True)
def _in_zone(a, zone, out):  # type: ignore[no-untyped-def]  # numba kernel
    """``a[zone]`` into ``out`` (H · W entries: each value written at the next free entry, kept when in the zone,
    without a branch); their count."""
    f = a.reshape(-1)
    z = zone.reshape(-1)
    n = 0
    for q in range(f.size):
        out[n] = f[q]
        n += z[q]
    return n


def _sigma_and_tau_medians(sigma_px: np.ndarray, params: SuspectParams) -> tuple[float, float]:
    """The medians of σ̂ and of τ = max(min_residual_mm, noise_k · σ̂) over the zone (``sigma_px``: σ̂ there,
    not modified), from one selection: τ is a non-decreasing function of σ̂
    (noise_k >= 0, IEEE products and maximum are monotone), so its middle order statistics are those
    of σ̂ mapped. The values of ``_median_of_temporary`` of each, NaN (both) when any σ̂ is NaN."""
    n = sigma_px.size
    if np.isnan(sigma_px).any():
        return float("nan"), float("nan")

    def tau(x: float) -> float:
        return float(np.maximum(params.min_residual_mm, params.noise_k * x))

    h = n // 2
    if n % 2:
        x = order_pair_large(sigma_px, h, h)[0]
        return x, tau(x)
    a, b = order_pair_large(sigma_px, h - 1, h)
    return (a + b) / 2.0, (tau(a) + tau(b)) / 2.0


def suspects(
    xyz: XYZ,
    height_mm: FloatImage,
    zone: Mask,
    above_rim: Mask | None = None,
    *,
    params: SuspectParams,
    intrinsics: Intrinsics | None = None,
    edge_surface: EdgeSurfaceParams | None = None,
    patches: bool = True,
) -> SuspectResult:
    """Every suspect of one frame, from all the detectors, grouped for review.

    Parameters
    ----------
    xyz : (H, W, 3) float ndarray
        The frame (metres, camera optical frame, NaN = unmeasured): every measured point is context
        for the residual tests, in the zone or not (a flying pixel between a part and the bin floor is
        judged against the floor's points).
    height_mm : (H, W) float ndarray
        The height image the z-cut is given (mm); only its zone pixels are used (the floating
        detector).
    zone : (H, W) bool ndarray
        The pixels judged (the zone of the pipeline; every valid pixel without the bin stages).
    above_rim : (H, W) bool ndarray, optional
        Points above the rim, flagged by the pipeline's removal (``Zone.easy``); they are suspects,
        and not context for the others.
    params : SuspectParams
    intrinsics : Intrinsics, optional
        The camera; when given, its image size must be the frame's (a check that ``xyz`` is the
        camera's organized grid). The detectors work on the grid and need nothing else from it.
    edge_surface : EdgeSurfaceParams, optional
        When given, the gap of a pixel the residual detectors flagged (surface residuals up and
        down, mixed pixels; not a floating component, a completed blob or a point above the rim,
        which keep their gaps) is its signed distance to the nearest surface fitted on one side of
        an edge (:func:`zcut.edge_surface.signed_edge_distance`) where one lies within reach,
        instead of its residual to the nearest one-sided continuation: a part's real edge is then
        on the surface (the labelling page's gaps, ``docs/labelling.md``). A floating component
        keeps its height over the points around it: a flat one of 4 × 4 pixels would be a surface
        of its own. The suspects themselves do not change; the groups follow the gaps (their
        strength classes).
    patches : bool
        Run the patch detector (:mod:`~zcut.suspects.patches`; default). It was built for the labelling page
        without a part model (real scans, stereo scenes); where the page fits a part model its proposals come
        from the fits and it calls this with False (``annotate/groups.py``): no pixel is a patch. The bank's
        ``suspects`` method runs every detector.

    Returns
    -------
    SuspectResult
    """
    if not isinstance(params, SuspectParams):
        raise ParameterError(f"params must be a SuspectParams, got {type(params).__name__}")
    a = check_xyz(xyz)
    H, W = a.shape[:2]
    h_img = np.asarray(height_mm)
    if h_img.shape != (H, W) or h_img.dtype.kind != "f":
        raise InputShapeError(f"height_mm must be an (H, W) float array like xyz {(H, W)}, got {describe_array(h_img)}")
    zone = check_mask(zone, name="zone", shape=(H, W))
    easy = np.zeros((H, W), bool) if above_rim is None else check_mask(above_rim, name="above_rim", shape=(H, W))
    if edge_surface is not None and not isinstance(edge_surface, EdgeSurfaceParams):
        raise ParameterError(f"edge_surface must be an EdgeSurfaceParams or None, got {type(edge_surface).__name__}")
    if intrinsics is not None:
        if not isinstance(intrinsics, Intrinsics):
            raise ParameterError(f"intrinsics must be an Intrinsics, got {type(intrinsics).__name__}")
        if (intrinsics.height, intrinsics.width) != (H, W):
            raise InputShapeError(f"intrinsics are for {intrinsics.height}x{intrinsics.width} images, "
                                  f"the frame is {H}x{W}")
    try:
        with scratch_workspace().call() as ws:
            return _suspects(a, h_img, zone, easy, params, edge_surface, ws, patches=bool(patches))
    finally:
        _bound_kept_frame_mm()


#: the call's scratch images (τ; the jump, then the zone's heights of the floating cut, then the gate's lower ends;
#: σ̂ per pixel, then the gate's upper ends, then the grouping's strength; σ̂ in the zone, then the gate's pixels:
#: H · W doubles each, ~74 MB at 1920 × 1200), kept between calls, one workspace per thread
#: (:func:`scratch_workspace`): made fresh each call, their pages were faulted in afresh (docs/performance.md, the
#: suspects' tenth, eleventh and thirteenth rounds)
_SCRATCH = threading.local()

#: what a thread's :func:`scratch_workspace` keeps between calls at most (its ``max_bytes``): the images of a frame
#: of up to ~4.2 M pixels; after a call on a larger frame it drops them
SCRATCH_KEPT_BYTES = 128 << 20


def scratch_workspace() -> SorWorkspace:
    """The calling thread's workspace of :func:`suspects`' scratch images (made on first use, dropped with the
    thread; it keeps the images of the largest frame seen, up to :data:`SCRATCH_KEPT_BYTES`, until
    ``scratch_workspace().release()``). A call that finds it in use works in fresh arrays. Nothing a call
    returns is one of them."""
    ws: SorWorkspace | None = getattr(_SCRATCH, "workspace", None)
    if ws is None:
        ws = SorWorkspace(max_bytes=SCRATCH_KEPT_BYTES)
        _SCRATCH.workspace = ws
    return ws


#: the frame in mm (``a.astype(np.float64) * 1000.0``, H · W · 3 doubles, ~55 MB at 1920 × 1200) a result of this
#: thread handed back (:meth:`SuspectResult.release`); the thread's next call with edge surfaces takes it and its
#: result owns it. Its owner is explicit: a result's surfaces until released, then this slot, then the next call's
#: result; no reference count is read. Made fresh each call, an image that large was mapped anew, its pages faulted
#: in at every call (docs/performance.md, the suspects' thirteenth and fourteenth rounds)
_FRAME = threading.local()


def _frame_mm_array(shape: tuple[int, ...]) -> np.ndarray:
    """An uninitialized float64 array of ``shape`` for the frame in mm: the one a result of this thread handed back
    (:data:`_FRAME`) when it has that shape, else a fresh one. Either way the thread's slot is empty after it: the
    array belongs to the call's result."""
    held = getattr(_FRAME, "a_mm", None)
    _FRAME.a_mm = None
    if held is not None and held.shape == shape:
        return held
    del held
    return np.empty(shape)


#: a frame in mm handed back is kept (:func:`_give_back_frame_mm`) from this size on: glibc's largest mmap threshold,
#: above which a fresh array is mapped anew at every call; a smaller one comes from the heap, whose block the next
#: call's takes again (the real 640 × 480 scans, 7.4 MB: 1.0-1.1 CPU ms fresh, 1.2-1.5 written into the kept one)
FRAME_KEPT_MIN_BYTES = 32 << 20


def _give_back_frame_mm(a_mm: np.ndarray) -> None:
    """Keep ``a_mm`` (a frame in mm no result owns any more) as the calling thread's (:data:`_FRAME`, in place of
    the one kept) when it holds at least :data:`FRAME_KEPT_MIN_BYTES`, and it and the thread's scratch images at
    most :data:`SCRATCH_KEPT_BYTES` together: what the thread keeps between calls stays bounded."""
    _FRAME.a_mm = None
    if (a_mm.base is None and a_mm.dtype == np.float64 and a_mm.flags.c_contiguous
            and FRAME_KEPT_MIN_BYTES <= a_mm.nbytes <= SCRATCH_KEPT_BYTES - scratch_workspace().nbytes):
        _FRAME.a_mm = a_mm


def _bound_kept_frame_mm() -> None:
    """Drop the thread's kept frame in mm when it and the scratch images (grown by a call on a larger frame)
    hold more than :data:`SCRATCH_KEPT_BYTES` together."""
    held = getattr(_FRAME, "a_mm", None)
    if held is not None and held.nbytes > SCRATCH_KEPT_BYTES - scratch_workspace().nbytes:
        _FRAME.a_mm = None


def kept_frame_mm_bytes() -> int:
    """Bytes of the frame in mm the calling thread keeps for its next call (0: none)."""
    held = getattr(_FRAME, "a_mm", None)
    return 0 if held is None else int(held.nbytes)


def release_frame_mm() -> None:
    """Drop the frame in mm the calling thread keeps (:meth:`SuspectResult.release` handed it back); the results
    are not affected."""
    _FRAME.a_mm = None


def _suspects(a: np.ndarray, h_img: np.ndarray, zone: Mask, easy: Mask, params: SuspectParams,
              edge_surface: EdgeSurfaceParams | None, ws: SorWorkspace, *, patches: bool) -> SuspectResult:
    """:func:`suspects` after its checks, its scratch images taken from ``ws``."""
    H, W = zone.shape
    valid, zone, easy, h_all, context = _prepare(a, zone, easy)
    h_zcut = np.ascontiguousarray(h_img, dtype=np.float64)

    profile = noise_profile(context, zone)
    # profile.sigma_at(local_height(context)), in the strength's array (not written until after the gate; σ̂ is
    # read by the thresholds and its medians only)
    sigma_px = _sigma_px(profile, context, out=ws.empty("strength", (H, W)))
    sigma_px = np.ascontiguousarray(sigma_px, dtype=np.float64)
    tau, jump = ws.empty("tau", (H, W)), ws.empty("jump", (H, W))
    _thresholds(sigma_px, params.noise_k, params.min_residual_mm, params.jump_mm, tau, jump)
    # σ̂ in the zone (sigma_px[zone]), in the gate's pixels' array (not in use until the gate; the gate's size: one
    # array kept, not grown)
    in_zone = ws.empty("gate_at", (H * W,))
    n_zone = int(_in_zone(sigma_px, zone, in_zone))
    sigma, threshold = (_sigma_and_tau_medians(in_zone[:n_zone], params) if n_zone
                        else (0.0, float(params.min_residual_mm)))
    del in_zone
    step = max(params.floating_step_mm, FLOATING_STEP_SIGMAS * sigma)
    a_max = params.a_max if params.a_max is not None else max(0.01 * H * W, 1.0)

    codes, residual = surface_residuals(context, zone, tau=tau, jump=jump, min_below=params.below_min_directions)
    off = codes > 0
    judged_ctx = valid & ~easy
    filled = (fill_blobs(off, zone, judged_ctx, iterations=params.fill_iterations) if params.fill_iterations > 0
              else off)
    # the patches cut off by depth steps, from the jumps (before the floating detector takes their array); none
    # without the patch detector
    if patches:
        patch = cut_off_patches(context, jump, max_px=PATCH_RHO * a_max)
        patch &= zone
        judged: np.ndarray | None = np.empty((H, W), bool)
    else:
        patch, judged = np.zeros((H, W), bool), None
    rough = np.empty((H, W), bool)
    _rough(zone, residual, tau, rough)  # in the zone: inf (no continuation) is rough
    # the zone's heights in the jump's array (surface_residuals, its only reader, is done; the gate takes it later)
    floating, floating_at, floating_gap = floating_components(h_zcut, zone, judged_ctx, rough, params, a_max,
                                                              step, profile, hz=ws.empty("jump", (H, W)),
                                                              judged=judged)
    if judged is not None:  # the components the floating detector judges are its own (zcut.suspects.floating)
        np.greater(patch, judged, out=patch)  # patch & ~judged

    # the codes, and the gaps: a floating pixel's over the measured pixels bordering its component; a
    # pixel off the surface, its residual (to the nearest continuation) or, with edge_surface, its distance
    # to the nearest surface fitted on one side of an edge; a blob's or an above-rim pixel's, to the local
    # surface around it (a floating pixel is in the zone, never above the rim: its gap is the one over its
    # component's border)
    mask, by_residual = np.empty((H, W), bool), np.empty((H, W), bool)
    gap_at, surface_px = np.empty((H, W), bool), np.empty((H, W), bool)
    n_res = _codes_and_masks(codes, off, filled, floating, easy, patch, residual, valid, h_all, mask, by_residual, gap_at,
                             surface_px)
    gap = np.empty((H, W))
    _gap_kernel(h_all, gap_at, surface_px, GAP_MIN_PIXELS, GAP_MAX_RADIUS, gap)  # local_gaps(h_all, ...)
    at_res = _residual_gaps(by_residual, residual, gap, n_res)
    np.put(gap, floating_at, floating_gap)
    surfaces = None
    if edge_surface is not None:  # a pixel off the surface with a surface near: its distance to the nearest one
        # the frame in mm: a.astype(np.float64) * 1000.0, in one pass (numpy's casting loop of
        # np.multiply(a, 1000.0, dtype=np.float64) took 3 x as long as a copy then the product in place,
        # which take two); a float32 frame's valid points stay finite in mm, so only a float64 one needs
        # edge_surfaces' check
        a_mm = _frame_mm_array(a.shape)
        if a.dtype in (np.float32, np.float64) and a.flags.c_contiguous:
            _frame_mm(a, a_mm)  # one pass
        else:
            a_mm[...] = a
            np.multiply(a_mm, 1000.0, out=a_mm)
        if a.dtype != np.float32:
            a_mm, _, _ = _check_args(a_mm, valid, edge_surface)
        # the gate's arrays: the jump's (read by surface_residuals only), the strength's (not written yet) and one
        # more; the gate is done with them when lazy_surfaces returns
        gate = gate_arrays(ws, H * W, ("jump", "strength", "gate_at"))
        surfaces = lazy_surfaces(a_mm, np.ascontiguousarray(valid), edge_surface, gate=gate)
        del gate
        d = surfaces.distance_at(at_res)  # by_residual is in the zone, so measured
        near = np.isfinite(d)
        gap.ravel()[at_res[near]] = d[near]
    strength = ws.empty("strength", (H, W))
    _gap_ratio(gap, tau, params.min_residual_mm, strength)
    groups, primary, radii = group_suspects(codes, strength, params)
    n = int(primary.size)
    size, bits, bbox, in_group = _group_tables(groups, codes, n)
    if n:
        g_gap = label_medians(gap.ravel()[in_group], groups.ravel()[in_group], n)
    else:
        g_gap = np.zeros(0)
    score = np.sqrt(size) * np.nan_to_num(np.abs(g_gap), nan=0.0)
    order = np.lexsort((np.arange(n), -size, -score))  # score, then size, then first found
    rank = np.zeros(n + 1, np.int32)
    rank[order + 1] = np.arange(1, n + 1, dtype=np.int32)
    g_flat = groups.reshape(-1)
    g_flat[in_group] = rank[g_flat[in_group]]
    return SuspectResult(
        mask=mask, groups=groups, detectors=codes, gap_mm=gap, residual_mm=residual,
        group_detectors=bits[order], group_primary=primary[order], group_size=size[order],
        group_gap_mm=g_gap[order], group_bbox=bbox[order], group_score=score[order],
        noise_mm=sigma, threshold_mm=threshold,
        noise_profile=profile, floating_step_mm=step, merge_radius_px=radii, _surfaces=surfaces,
    )
