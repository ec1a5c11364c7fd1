"""numba kernels of the ray tracer's per-ray arithmetic: the same numbers as the numpy reference, faster.

Each kernel does, ray by ray, what :mod:`replay.synth.raytrace.reference` does with whole-array
numpy operations, in the same order of floating-point operations, so that a frame comes out with
the same bytes (``tests/replay/synth/test_raytrace.py`` checks it over many frames). What that
takes, measured against numpy 2 on x86-64:

- a 3-vector dot product of C-ordered (n, 3) rows with ``np.einsum("kj,kj->k")`` sums the
  products as ``(x0 y0 + x2 y2) + x1 y1``; ``np.linalg.norm(axis=1)`` as ``sqrt((x0² + x1²) + x2²)``;
  the barycentric blend ``np.einsum("nk,nkj->nj")`` as ``(w0 c0 + w1 c1) + w2 c2``;
- ``np.cos`` and ``np.sin`` of float64 give the C library's results, as numba's ``math.cos`` and
  ``math.sin`` do; ``np.exp`` and ``np.power`` do not (numpy has SIMD versions of its own), so the
  BRDF's ``exp`` and ``ch**4`` stay numpy passes between two kernels;
- ``np.bincount`` and ``np.add.at`` add in input order, starting from zero and from the target.

No ``fastmath`` (it would reorder and fuse), serial loops (the budget is CPU seconds on two
shared cores, where threads add overhead but save none).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

# the float64 hit (Möller–Trumbore on the triangle Embree found) is zcut's, shared with the fits' ray casts;
# hit_t is re-exported for TracedScene.cast_t
from zcut.ray_hits import hit_t as hit_t
from zcut.ray_hits import hit_tuv

_TWO_PI = 2 * np.pi


@nb.njit(cache=True, error_model="numpy")
def _dot(ax: float, ay: float, az: float, bx: float, by: float, bz: float) -> float:
    # the summation order of np.einsum("kj,kj->k") over C-ordered rows of three
    return (ax * bx + az * bz) + ay * by


@nb.njit(cache=True, error_model="numpy")
def _norm_floor(x: float, y: float, z: float) -> float:
    """max(|v|, 1e-12) as ``np.maximum(np.linalg.norm(v, axis=1), 1e-12)`` (NaN stays NaN)."""
    n = math.sqrt((x * x + y * y) + z * z)
    return 1e-12 if n < 1e-12 else n


@nb.njit(cache=True, error_model="numpy")
def pixel_directions(u: np.ndarray, v: np.ndarray, flat: np.ndarray, out: np.ndarray) -> None:
    """Unit rays through pixels ``flat`` (row-major over ``len(v) x len(u)``) into ``out`` (k, 3).

    ``u``, ``v``: the pixel centres' normalized coordinates per column and row.
    """
    w = u.shape[0]
    for i in range(flat.shape[0]):
        x = u[flat[i] % w]
        y = v[flat[i] // w]
        den = _norm_floor(x, y, 1.0)
        out[i, 0] = x / den
        out[i, 1] = y / den
        out[i, 2] = 1.0 / den


@nb.njit(cache=True, error_model="numpy")
def ray_array(origins: np.ndarray, directions: np.ndarray, out: np.ndarray) -> None:
    """The (n, 6) float32 rays Open3D casts; ``origins`` (1, 3) for all rays or (n, 3)."""
    one = origins.shape[0] == 1
    for i in range(directions.shape[0]):
        o = 0 if one else i
        for j in range(3):
            out[i, j] = np.float32(origins[o, j])
            out[i, 3 + j] = np.float32(directions[i, j])


@nb.njit(cache=True, error_model="numpy")
def finish_hits(t32: np.ndarray, prim: np.ndarray, uv32: np.ndarray, geo32: np.ndarray, origins: np.ndarray,
                directions: np.ndarray, v0: np.ndarray, e1: np.ndarray, e2: np.ndarray, face_normals: np.ndarray,
                corner_normals: np.ndarray, material_id: np.ndarray, label_id: np.ndarray, part_id: np.ndarray,
                t: np.ndarray, point: np.ndarray, shade: np.ndarray, geo: np.ndarray, material: np.ndarray,
                label: np.ndarray, part: np.ndarray) -> None:
    """Open3D's raw answers -> the fields of ``Hits`` (see ``TracedScene.cast``), written into the outputs.

    Open3D (Embree) says only whether a ray hits and which triangle: the hit's ``t`` and barycentric
    ``u, v`` are Möller–Trumbore's in float64 on that triangle (:func:`zcut.ray_hits.hit_tuv`), its geometric normal the
    triangle's (``face_normals``), so that no bit of a hit comes from Embree's float32 SIMD kernels,
    which differ between CPUs. A ray in the triangle's plane (``det`` 0) or a non-finite result keeps
    Embree's float32 ``t``, ``uv`` and normal. Shading normal: the corner normals blended by the
    barycentric coordinates, made unit; both normals turned to face the ray's origin; a shading
    normal turned away from the viewer replaced by the face's. Misses: point NaN, normals 0,
    material -1, label and part 0.
    """
    one = origins.shape[0] == 1
    for i in range(t32.shape[0]):
        ti = np.float64(t32[i])
        if not np.isfinite(ti):
            t[i] = ti
            for j in range(3):
                point[i, j] = np.nan
                shade[i, j] = 0.0
                geo[i, j] = 0.0
            material[i] = -1
            label[i] = 0
            part[i] = 0
            continue
        p = np.int64(prim[i])
        o = 0 if one else i
        det, tm, bu, bv = hit_tuv(i, p, o, origins, directions, v0, e1, e2)
        if det != 0.0 and np.isfinite(tm) and np.isfinite(bu) and np.isfinite(bv):
            ti = np.float64(tm)
            g0, g1, g2 = face_normals[p, 0], face_normals[p, 1], face_normals[p, 2]
        else:
            bu = np.float64(uv32[i, 0])
            bv = np.float64(uv32[i, 1])
            g0 = np.float64(geo32[i, 0])
            g1 = np.float64(geo32[i, 1])
            g2 = np.float64(geo32[i, 2])
        t[i] = ti
        w0 = (1.0 - bu) - bv
        s0 = (w0 * corner_normals[p, 0, 0] + bu * corner_normals[p, 1, 0]) + bv * corner_normals[p, 2, 0]
        s1 = (w0 * corner_normals[p, 0, 1] + bu * corner_normals[p, 1, 1]) + bv * corner_normals[p, 2, 1]
        s2 = (w0 * corner_normals[p, 0, 2] + bu * corner_normals[p, 1, 2]) + bv * corner_normals[p, 2, 2]
        den = _norm_floor(s0, s1, s2)
        s0 /= den
        s1 /= den
        s2 /= den
        dx, dy, dz = directions[i, 0], directions[i, 1], directions[i, 2]
        if _dot(g0, g1, g2, dx, dy, dz) > 0:
            g0, g1, g2 = g0 * -1.0, g1 * -1.0, g2 * -1.0
            s0, s1, s2 = s0 * -1.0, s1 * -1.0, s2 * -1.0
        if _dot(s0, s1, s2, dx, dy, dz) >= 0:
            s0, s1, s2 = g0, g1, g2
        point[i, 0] = origins[o, 0] + ti * dx
        point[i, 1] = origins[o, 1] + ti * dy
        point[i, 2] = origins[o, 2] + ti * dz
        shade[i, 0], shade[i, 1], shade[i, 2] = s0, s1, s2
        geo[i, 0], geo[i, 1], geo[i, 2] = g0, g1, g2
        material[i] = material_id[p]
        label[i] = label_id[p]
        part[i] = part_id[p]


@nb.njit(cache=True, error_model="numpy")
def direct_prepare(point: np.ndarray, normal: np.ndarray, geo: np.ndarray, idx: np.ndarray, proj: np.ndarray,
                   f_px: float, baseline_mm: float, cx: float, cy: float, width: int, height: int,
                   wi: np.ndarray, dist: np.ndarray, ok: np.ndarray) -> None:
    """Per point ``idx[i]``: the unit direction ``wi`` toward the projector, the distance to it, and
    whether the projector can light it (inside its image, in front, facing it on both normals)."""
    u_hi = width - 0.5
    v_hi = height - 0.5
    for i in range(idx.shape[0]):
        k = idx[i]
        px, py, pz = point[k, 0], point[k, 1], point[k, 2]
        tx, ty, tz = proj[0] - px, proj[1] - py, proj[2] - pz
        d = math.sqrt((tx * tx + ty * ty) + tz * tz)
        wx, wy, wz = tx / d, ty / d, tz / d
        wi[i, 0], wi[i, 1], wi[i, 2] = wx, wy, wz
        dist[i] = d
        u = f_px * (px - baseline_mm) / pz + cx
        v = f_px * py / pz + cy
        inside = (pz > 0) and (u >= -0.5) and (u <= u_hi) and (v >= -0.5) and (v <= v_hi)
        ok[i] = (inside and _dot(geo[k, 0], geo[k, 1], geo[k, 2], wx, wy, wz) > 0
                 and _dot(normal[k, 0], normal[k, 1], normal[k, 2], wx, wy, wz) > 0)


@nb.njit(cache=True, error_model="numpy")
def brdf_lobe(point: np.ndarray, normal: np.ndarray, material: np.ndarray, idx: np.ndarray, sel: np.ndarray,
              wi: np.ndarray, dist: np.ndarray, wo: np.ndarray, roughness: np.ndarray, f_px: float,
              baseline_mm: float, cx: float, reference_mm: float, cos_i: np.ndarray, irradiance: np.ndarray,
              cos_o: np.ndarray, ch: np.ndarray, exponent: np.ndarray, pa2: np.ndarray, code: np.ndarray) -> None:
    """First half of the direct light of the lit points ``idx[sel[i]]``, up to the BRDF's ``exp``.

    Writes the clipped cosines, the irradiance ``cos_i (reference / d)²``, the half-vector cosine
    ``ch``, the exponent ``-tan²/a²`` and ``π a²`` of the lobe, and the projector column.
    """
    for i in range(sel.shape[0]):
        s = sel[i]
        k = idx[s]
        nx, ny, nz = normal[k, 0], normal[k, 1], normal[k, 2]
        wx, wy, wz = wi[s, 0], wi[s, 1], wi[s, 2]
        ox, oy, oz = wo[s, 0], wo[s, 1], wo[s, 2]
        c = _dot(nx, ny, nz, wx, wy, wz)
        r = reference_mm / dist[s]
        irradiance[i] = c * (r * r)
        cos_i[i] = min(max(c, 1e-3), 1.0)
        cos_o[i] = min(max(_dot(nx, ny, nz, ox, oy, oz), 0.05), 1.0)
        hx, hy, hz = wx + ox, wy + oy, wz + oz
        den = _norm_floor(hx, hy, hz)
        hx /= den
        hy /= den
        hz /= den
        c_h = min(max(_dot(nx, ny, nz, hx, hy, hz), 1e-3), 1.0)
        ch[i] = c_h
        a = roughness[material[k]]
        tan2 = (1.0 - c_h * c_h) / (c_h * c_h)
        exponent[i] = -tan2 / (a * a)
        pa2[i] = np.pi * a * a
        code[i] = f_px * (point[k, 0] - baseline_mm) / point[k, 2] + cx


@nb.njit(cache=True, error_model="numpy")
def brdf_finish(material: np.ndarray, idx: np.ndarray, sel: np.ndarray, albedo: np.ndarray, specular: np.ndarray,
                lobe: np.ndarray, cos_i: np.ndarray, cos_o: np.ndarray, irradiance: np.ndarray, exposure: float,
                radiance: np.ndarray, f_out: np.ndarray) -> None:
    """Second half: reflectance ``albedo/π + spec D / (4 cos_i cos_o)`` and radiance ``exposure E f``."""
    for i in range(sel.shape[0]):
        m = material[idx[sel[i]]]
        f = albedo[m] / np.pi + specular[m] * lobe[i] / (4.0 * cos_i[i] * cos_o[i])
        f_out[i] = f
        radiance[i] = exposure * irradiance[i] * f


@nb.njit(cache=True, error_model="numpy")
def _all_positive_zero(a: np.ndarray) -> bool:
    """Every element is +0.0 (not -0.0, not NaN)."""
    for x in a:
        if x != 0.0 or math.copysign(1.0, x) < 0.0:
            return False
    return True


@nb.njit(cache=True, error_model="numpy")
def bincount_phasors(flat: np.ndarray, weight: np.ndarray, value: np.ndarray, code: np.ndarray,
                     periods: np.ndarray, intensity: np.ndarray, z: np.ndarray) -> None:
    """Add the paths ``(weight * value, code)`` to pixels ``flat`` as ``Phasors.add_reference`` does.

    As there: per period, ``np.bincount`` of ``I cos(2π u / T)`` and ``I sin(...)`` (sums from zero
    in input order), then added to the image: ``intensity`` (n,), ``z`` (P, n, 2) the real and
    imaginary parts of the complex phasor images.

    Images that are all +0.0 (the usual case: each image of a frame gets one call) take the sums
    directly: ``+0.0 + s`` is ``s`` for every sum ``s`` that starts at +0.0, so the bits are the
    same, without the (1 + 2P) image-sized buffers, their zeroing and the pass that adds them.
    """
    n = intensity.shape[0]
    P = periods.shape[0]
    if _all_positive_zero(intensity) and _all_positive_zero(z.reshape(-1)):
        for i in range(flat.shape[0]):
            p = flat[i]
            val = weight[i] * value[i]
            intensity[p] += val
            for k in range(P):
                ph = _TWO_PI * code[i] / periods[k]
                z[k, p, 0] += val * math.cos(ph)
                z[k, p, 1] += val * math.sin(ph)
        return
    acc_i = np.zeros(n)
    acc_re = np.zeros((P, n))
    acc_im = np.zeros((P, n))
    for i in range(flat.shape[0]):
        p = flat[i]
        val = weight[i] * value[i]
        acc_i[p] += val
        for k in range(P):
            ph = _TWO_PI * code[i] / periods[k]
            acc_re[k, p] += val * math.cos(ph)
            acc_im[k, p] += val * math.sin(ph)
    for p in range(n):
        intensity[p] += acc_i[p]
    for k in range(P):
        for p in range(n):
            z[k, p, 0] += acc_re[k, p]
            z[k, p, 1] += acc_im[k, p]


@nb.njit(cache=True, error_model="numpy")
def add_at(out: np.ndarray, flat: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> None:
    """``np.add.at(out, flat, a * b * c)`` (the products left to right)."""
    for i in range(flat.shape[0]):
        out[flat[i]] += a[i] * b[i] * c[i]


@nb.njit(cache=True, error_model="numpy")
def specular_share(material: np.ndarray, albedo: np.ndarray, f: np.ndarray, out: np.ndarray) -> None:
    """``1 - (albedo/π) / f`` per point of ``material``: the share of the reflectance ``f`` that is
    not Lambertian."""
    for i in range(material.shape[0]):
        out[i] = 1.0 - (albedo[material[i]] / np.pi) / f[i]


@nb.njit(cache=True, error_model="numpy")
def edge_pixels(z: np.ndarray, key: np.ndarray, jump_mm: float, out: np.ndarray) -> None:
    """``out``: the 3 x 3 neighbourhood's (clamped at the border, as scipy's ``nearest``) depth span
    ``max - min`` exceeds ``jump_mm``, or its ``key`` differs (``optics.edge_pixels``; ``z`` finite)."""
    H, W = z.shape
    for r in range(H):
        r0, r1 = max(r - 1, 0), min(r + 2, H)
        for c in range(W):
            c0, c1 = max(c - 1, 0), min(c + 2, W)
            hi = z[r, c]
            lo = hi
            khi = key[r, c]
            klo = khi
            for rr in range(r0, r1):
                for cc in range(c0, c1):
                    v = z[rr, cc]
                    if v > hi:
                        hi = v
                    if v < lo:
                        lo = v
                    k = key[rr, cc]
                    if k > khi:
                        khi = k
                    if k < klo:
                        klo = k
            out[r, c] = (hi - lo > jump_mm) or (khi != klo)
