"""The ray tracer's literal numpy implementation: the reference the fast path must equal bit for bit.

:func:`trace_reference` is the first version of :func:`replay.synth.raytrace.optics.trace`, written
with whole-array numpy operations (every step as the module docstring of ``optics`` says, readable
line by line). ``optics.trace`` does the same arithmetic ray by ray in numba kernels
(:mod:`.kernels`); ``tests/replay/synth/test_raytrace_kernels.py`` checks that both give the same
bits over frames of every part kind and several sensor settings. Keep them in step: a change of the
physics goes into both.

The reference is the oracle of the operations the kernels do: casting rays, lighting points, summing
paths into phasor images (:data:`REFERENCE_OPS`, each in plain numpy, and the first hits, the
direct light and the sub-pixel rays written out here). The specular bounces on the camera and
projector sides (steps 3 and 4) are no kernel's: both paths run ``optics``'s
:func:`~replay.synth.raytrace.optics.camera_bounces` and
:func:`~replay.synth.raytrace.optics.projector_bounces` once, each with its own operations, so that
their physics is written once.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from replay.synth.raytrace.optics import (
    EXPOSURE,
    REFERENCE_MM,
    Measured,
    Ops,
    Phasors,
    Received,
    SensorModel,
    _glare,
    _unit,
    camera_bounces,
    centre_rays,
    decode,
    projector_bounces,
    triangulate_decoded,
)
from replay.synth.raytrace.scene import Hits, TracedScene
from zcut.cloud import Intrinsics


def edge_pixels_reference(depth_mm: np.ndarray, part: np.ndarray, label: np.ndarray, *,
                          jump_mm: float = 1.5) -> np.ndarray:
    """:func:`optics.edge_pixels <replay.synth.raytrace.optics.edge_pixels>` with scipy's 3 x 3
    maximum and minimum filters (its first version)."""
    z = np.where(np.isfinite(depth_mm), depth_mm, 1e9)
    hi = ndimage.maximum_filter(z, size=3, mode="nearest")
    lo = ndimage.minimum_filter(z, size=3, mode="nearest")
    key = part.astype(np.int64) * 16 + label
    khi = ndimage.maximum_filter(key, size=3, mode="nearest")
    klo = ndimage.minimum_filter(key, size=3, mode="nearest")
    return np.asarray((hi - lo > jump_mm) | (khi != klo))


def pixel_directions_reference(K: Intrinsics, du: float = 0.0, dv: float = 0.0) -> np.ndarray:
    """(H*W, 3) unit ray directions through pixel centres shifted by (du, dv) pixels."""
    u = (np.arange(K.width) + du - K.cx) / K.fx
    v = (np.arange(K.height) + dv - K.cy) / K.fy
    d = np.empty((K.height, K.width, 3))
    d[..., 0] = u[None, :]
    d[..., 1] = v[:, None]
    d[..., 2] = 1.0
    return _unit(d.reshape(-1, 3))


def brdf_reference(mat: dict[str, np.ndarray], mid: np.ndarray, n: np.ndarray, wi: np.ndarray, wo: np.ndarray, *,
                   diffuse_only: bool = False) -> np.ndarray:
    """Reflectance (1/sr) for light arriving from ``wi`` and leaving toward ``wo`` (unit vectors, (k, 3))."""
    albedo = mat["albedo"][mid]
    f = albedo / np.pi
    if diffuse_only:
        return np.asarray(f)
    spec = mat["specular"][mid]
    a = mat["roughness"][mid]
    cos_i = np.clip(np.einsum("kj,kj->k", n, wi), 1e-3, 1.0)
    cos_o = np.clip(np.einsum("kj,kj->k", n, wo), 0.05, 1.0)
    h = wi + wo
    h /= np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-12)
    ch = np.clip(np.einsum("kj,kj->k", n, h), 1e-3, 1.0)
    tan2 = (1.0 - ch * ch) / (ch * ch)
    D = np.exp(-tan2 / (a * a)) / (np.pi * a * a * ch**4)
    return np.asarray(f + spec * D / (4.0 * cos_i * cos_o))


def direct_light_reference(scene: TracedScene, model: SensorModel, hits: Hits, idx: np.ndarray, wo: np.ndarray, *,
                           diffuse_only: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`optics.direct_light <replay.synth.raytrace.optics.direct_light>` in whole-array numpy: its
    ``keep``, ``radiance`` and ``code`` (not its reflectance; ``code`` is NaN where not ``keep``)."""
    p = hits.point[idx]
    n = hits.normal[idx]
    ng = hits.geo_normal[idx]
    proj = model.projector_origin
    to_p = proj - p
    d = np.linalg.norm(to_p, axis=1)
    wi = to_p / d[:, None]
    ok = model.in_projector(p) & (np.einsum("kj,kj->k", ng, wi) > 0) & (np.einsum("kj,kj->k", n, wi) > 0)
    radiance = np.zeros(len(idx))
    code = np.full(len(idx), np.nan)
    if not ok.any():
        return ok, radiance, code
    sel = np.flatnonzero(ok)
    # shadow: the projector's ray toward the point must reach it first
    back = -wi[sel]
    seen = scene.cast_reference(np.broadcast_to(proj, back.shape), back)
    lit = seen.t >= d[sel] - 0.05
    sel = sel[lit]
    ok[:] = False
    ok[sel] = True
    cos_i = np.einsum("kj,kj->k", n[sel], wi[sel])
    E = cos_i * (REFERENCE_MM / d[sel]) ** 2
    f = brdf_reference(scene.mat, hits.material[idx][sel], n[sel], wi[sel], wo[sel], diffuse_only=diffuse_only)
    radiance[sel] = EXPOSURE * E * f
    code[sel] = model.code(p[sel])
    return ok, radiance, code


def _cast_reference(scene: TracedScene, origins: np.ndarray, directions: np.ndarray) -> Hits:
    return scene.cast_reference(np.broadcast_to(origins, directions.shape), directions)


def _add_reference(image: Phasors, flat_index: np.ndarray, weight: np.ndarray, value: np.ndarray, code: np.ndarray,
                   periods: tuple[float, ...]) -> None:
    image.add_reference(flat_index, weight * value, code, periods)


def _add_light_reference(image: np.ndarray, flat_index: np.ndarray, weight: np.ndarray, value: np.ndarray) -> None:
    np.add.at(image, flat_index, weight * value)


#: The reference's operations for the steps shared with ``optics`` (its literal numpy).
REFERENCE_OPS = Ops(cast=_cast_reference, light=direct_light_reference, add=_add_reference,
                    add_light=_add_light_reference)


def trace_reference(scene: TracedScene, K: Intrinsics, model: SensorModel, rng: np.random.Generator) -> Received:
    """``optics.trace`` in whole-array numpy (the reference; see the module docstring).

    Pixels at edges (:func:`edge_pixels`) get ``samples x samples`` sub-pixel rays, the others their
    centre ray (they see one smooth surface: more rays would only average the same code).
    """
    H, W = K.height, K.width
    S = int(model.samples)
    d_centre = pixel_directions_reference(K)
    direct, bounce, spec_light, centre, z_centre, sub_depth = centre_rays(scene, K, model, REFERENCE_OPS, d_centre)
    pix_list, dir_list, hit_list, w_list = [], [], [], []
    if S > 1:
        edge = edge_pixels_reference(z_centre, centre.part.reshape(H, W), centre.label.reshape(H, W)).ravel()
        plain = np.flatnonzero(~edge)
        pix_list.append(plain)
        dir_list.append(d_centre[plain])
        hit_list.append(centre.take(plain))
        w_list.append(np.ones(plain.size))
        e = np.flatnonzero(edge)
        offsets = [((i + 0.5) / S - 0.5, (j + 0.5) / S - 0.5) for j in range(S) for i in range(S)]
        for s, (du, dv) in enumerate(offsets):
            d = pixel_directions_reference(K, du, dv)[e]
            hs = scene.cast_reference(np.zeros(3), d)
            sub_depth[s].reshape(-1)[e] = np.where(hs.hit, hs.point[:, 2], np.inf)
            pix_list.append(e)
            dir_list.append(d)
            hit_list.append(hs)
            w_list.append(np.full(e.size, 1.0 / (S * S)))
    else:
        pix_list.append(np.arange(H * W))
        dir_list.append(d_centre)
        hit_list.append(centre)
        w_list.append(np.ones(H * W))
    pix = np.concatenate(pix_list)
    d = np.concatenate(dir_list)
    h0 = Hits.concat(hit_list)
    w_s = np.concatenate(w_list)
    del pix_list, dir_list, hit_list, w_list

    idx = np.flatnonzero(h0.hit)
    ok, rad, code = direct_light_reference(scene, model, h0, idx, -d[idx])
    sel = idx[ok]
    direct.add_reference(pix[sel], w_s[sel] * rad[ok], code[ok], model.periods_px)
    if sel.size:
        # the specular share of the direct light, for the 2-D image's highlights
        wi = _unit(model.projector_origin - h0.point[sel])
        lam = brdf_reference(scene.mat, h0.material[sel], h0.normal[sel], wi, -d[sel], diffuse_only=True)
        full = brdf_reference(scene.mat, h0.material[sel], h0.normal[sel], wi, -d[sel])
        np.add.at(spec_light, pix[sel], w_s[sel] * rad[ok] * (1.0 - lam / full))
    camera_bounces(scene, model, REFERENCE_OPS, h0, idx, d, pix, w_s, rng, bounce, spec_light)
    photons = projector_bounces(scene, K, model, centre, rng, REFERENCE_OPS)
    glare = _glare(direct.plus(bounce).plus(photons), K, model)
    return Received(direct, bounce, photons, glare, sub_depth, centre, spec_light.reshape(H, W))


def measure_reference(rec: Received, K: Intrinsics, model: SensorModel,
                      rng: np.random.Generator) -> Measured:
    """``optics.measure`` as first written (each stage's images summed afresh, not in place): the bits it
    must keep. The depths of the decoded stages are :func:`optics.triangulate_decoded`, shared."""
    stages = [rec.direct, rec.direct.plus(rec.camera_bounce).plus(rec.projector_bounce)]
    stages.append(stages[1].plus(rec.glare))
    return triangulate_decoded([decode(s, model) for s in stages], K, model, rng)
