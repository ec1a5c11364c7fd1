"""What made the ray-traced frame cheaper changed no byte: whole frames against the reference path,
the phasor sums' shortcut for images still at zero, the huge-page switch, the kept memory
(docs/raytraced.md, cost)."""

from __future__ import annotations

import ctypes
import importlib

import numpy as np
import pytest

from replay.synth import surfaces as surfaces_mod
from replay.synth.raytrace import optics, reference, synthesize_raytraced_frame
from replay.synth.raytrace.optics import Phasors, SensorModel, kept_memory, small_pages
from replay.synth.raytrace.pile import drop_parts, part_count
from replay.synth.raytrace.scene import build_scene
from replay.synth.raytrace.synthesize import raytrace_rng
from replay.synth.sensor import default_intrinsics
from replay.synth.synthesize import bin_pose_for, frame_rng

SIZE = (40, 64)
FILL = 5.0  # mm: a few parts, a fraction of a second of simulation


def same(a: np.ndarray, b: np.ndarray) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


@pytest.mark.parametrize(("kind", "seed", "chunk"), [
    ("spheres", 5, None), ("zinc_nuts", 6, None), ("rods", 7, None), ("black_nuts", 8, None),
    ("spheres", 9, 1000), ("sprockets", 10, 333),
])
def test_a_frame_is_the_reference_paths_frame(kind, seed, chunk, monkeypatch):
    """The frame of the fast path has the bytes of the frame of the literal numpy tracer and decoder
    (``chunk``: the direct light lit in chunks of that many points, many per frame)."""
    if chunk is not None:
        monkeypatch.setattr(optics, "DIRECT_CHUNK", chunk)
    a = synthesize_raytraced_frame(kind=kind, seed=seed, size=SIZE, fill_mm=FILL)
    monkeypatch.setattr(optics, "trace", reference.trace_reference)
    monkeypatch.setattr(optics, "measure", reference.measure_reference)
    b = synthesize_raytraced_frame(kind=kind, seed=seed, size=SIZE, fill_mm=FILL)
    assert a.frame.xyz.tobytes() == b.frame.xyz.tobytes()
    assert np.isfinite(a.frame.xyz).any()  # a comparison of clouds, not of NaN images
    assert same(a.frame.rgb, b.frame.rgb)
    for name in ("truth", "outlier_kind", "depth_true_m", "error_mm", "sigma_mm", "surface", "saturated"):
        assert same(getattr(a, name), getattr(b, name)), name
    for key in a.frame.masks:
        assert same(a.frame.masks[key], b.frame.masks[key]), key
    for key in a.frame.codes:
        assert same(a.frame.codes[key], b.frame.codes[key]), key


@pytest.mark.parametrize(("kind", "seed", "model"), [
    (None, 9, SensorModel()), ("spheres", 5, SensorModel()), ("zinc_nuts", 6, SensorModel(bounces=2)),
    ("rods", 7, SensorModel(min_contrast=0.5, min_signal=0.008)), ("sprockets", 8, SensorModel(samples=3)),
])
def test_measure_is_the_reference(kind, seed, model):
    """Decoding sums the stages in place and decodes the attribution stages only where the noise-free
    depth fails the truth rule: there they are the reference's whole-image values, NaN elsewhere;
    the rest is the reference's; the images it was given stay as they were."""
    pose = bin_pose_for(frame_rng(seed, 0, empty=kind is None), empty=kind is None, index=0)
    pile = None
    if kind is not None:
        pile = drop_parts(kind, pose, raytrace_rng(seed, 0, empty=False), count=min(part_count(kind, FILL), 40))
    scene = build_scene(pose, pile)
    K = default_intrinsics((80, 128))
    rec = optics.trace(scene, K, model, np.random.default_rng(2))
    before = [p.z.copy() for p in (rec.direct, rec.camera_bounce, rec.projector_bounce, rec.glare)]
    a = optics.measure(rec, K, model, np.random.default_rng(3))
    b = reference.measure_reference(rec, K, model, np.random.default_rng(3))
    for x, y in zip(a[:3] + a[4:], b[:3] + b[4:]):
        assert same(x, y)
    assert np.isfinite(a[0]).any()
    z_true = np.where(rec.centre.hit, rec.centre.point[:, 2], np.nan).reshape(a[1].shape)
    with np.errstate(invalid="ignore"):
        fails = optics.footprint_distance_mm(b[1], z_true, rec.sub_depth_mm) > model.outlier_sigmas * b[2]
    assert len(a[3]) == len(b[3]) == 2
    for x, y in zip(a[3], b[3]):
        assert same(x[fails], y[fails])
        assert np.isnan(x[~fails]).all()
    if kind is not None:  # shiny piles: outliers whose stages decode otherwise than the final light
        assert fails.sum() > 20
        assert (a[3][0][fails] != b[1][fails]).any()
    for p, z in zip((rec.direct, rec.camera_bounce, rec.projector_bounce, rec.glare), before):
        assert same(p.z, z)


@pytest.mark.parametrize(("kind", "seed", "size"), [
    ("spheres", 21, (120, 192)), ("zinc_nuts", 22, (120, 192)), ("rods", 23, (75, 120)),
    ("black_screws", 24, (120, 192)), ("sprockets", 25, (75, 120)), (None, 26, (75, 120)),
])
def test_off_surface_with_the_centre_hits_is_the_mask_without(kind, seed, size, monkeypatch):
    """The paper's truth decided by the centre rays' hits (``on_surface``) is the mask of the anchors
    alone, over frames of every kind with their outliers, and with a third of the hits unknown (NaN)."""
    from replay.synth import surfaces
    from replay.synth.raytrace import synthesize as synth_mod

    seen = []

    def both(xyz_mm, err, surf, *, on_surface=None):
        with_hits = surfaces.off_surface(xyz_mm, err, surf, on_surface=on_surface)
        seen.append((with_hits, surfaces.off_surface(xyz_mm, err, surf)))
        hits = on_surface.copy()
        hits[::3] = np.nan  # no known point: decided as before
        seen.append((surfaces.off_surface(xyz_mm, err, surf, on_surface=hits), seen[-1][1]))
        return with_hits

    monkeypatch.setattr(synth_mod, "off_surface", both)
    rf = synthesize_raytraced_frame(kind=kind or "spheres", empty=kind is None, seed=seed, size=size,
                                    fill_mm=None if kind is None else FILL)
    assert len(seen) == 2
    for got, want in seen:
        assert same(got, want)
    valid = np.isfinite(rf.frame.xyz).all(axis=2)
    assert valid.sum() > 0.5 * valid.size
    if kind in ("spheres", "zinc_nuts", "rods"):
        assert rf.off_surface.any()  # shiny: a mask with outliers, not only the all-False one


def test_off_surface_hints_on_a_box():
    """On a box: a point decided by its known surface point, one at the threshold left to the query,
    NaN hints, and a hint of the wrong shape refused."""
    box_v = np.array([[x, y, z] for x in (0, 10) for y in (0, 10) for z in (100, 110)], float)
    box_t = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    s = surfaces_mod.TrueSurfaces(box_v, box_t)
    xyz = np.full((3, 4, 3), np.nan)
    xyz[0, 0] = (5.0, 5.0, 100.0 - 0.2)  # 0.2 off the top face, within 0.3
    xyz[0, 1] = (5.0, 5.0, 100.0 - 0.3 - 1e-3)  # beyond 3 x 0.1
    xyz[0, 2] = (5.0, 5.0, 100.0 - 0.3 + 1e-3)  # within, but within the margin of its hint
    xyz[1, 0] = (5.0, 5.0, 100.0 - 0.25)
    xyz[2, 3] = (2.0, 3.0, 100.0 - 5.0)  # 5 above the box: far from everything
    err = np.full((3, 4), 0.1)
    hints = np.full((3, 4, 3), np.nan)
    hints[0, :3] = (5.0, 5.0, 100.0)  # the points' own feet on the face
    hints[2, 3] = (2.0, 3.0, 100.0)
    plain = surfaces_mod.off_surface(xyz, err, s)
    assert plain.tolist() == [[False, True, False, False], [False, False, False, False], [False, False, False, True]]
    assert surfaces_mod.off_surface(xyz, err, s, on_surface=hints).tolist() == plain.tolist()
    assert surfaces_mod.off_surface(xyz, err, s, on_surface=np.full_like(hints, np.nan)).tolist() == plain.tolist()
    with pytest.raises(ValueError, match="on_surface must have the cloud's shape"):
        surfaces_mod.off_surface(xyz, err, s, on_surface=hints[:2])


def _paths(rng: np.random.Generator, n: int, shape: tuple[int, int], periods: tuple[float, ...]):
    flat = rng.integers(0, shape[0] * shape[1], n)
    weight = rng.choice([1.0, 0.25, 1 / 9], n)
    value = rng.exponential(0.3, n)
    code = rng.uniform(-10, 1300, n)
    code[:40] = np.array(periods * 13 + (0.0,))
    value[40:60] = 0.0  # products of -0.0 where the cosine or sine is negative
    code[40:60] = rng.uniform(300, 900, 20)
    return flat, weight, value, code


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("start", ["zeros", "a negative zero", "a NaN"])
def test_phasor_sums_into_zero_images_are_the_reference(seed, start):
    """Images still at +0.0 take the sums directly; one -0.0 or NaN sends them the buffered way: same bits."""
    rng = np.random.default_rng(seed)
    periods = (1280.0, 64.0, 8.0)
    shape = (13, 17)
    flat, weight, value, code = _paths(rng, 5000, shape, periods)
    flat[flat == 3] = 4
    flat[40:60] = 3  # pixel 3 gets only zero-light paths, some of whose products are -0.0
    z0 = np.zeros((3,) + shape, np.complex128)
    i0 = np.zeros(shape)
    if start == "a negative zero":
        z0.real[1, 0, 5] = -0.0
        i0[0, 9] = -0.0
        flat[flat == 9] = 10  # pixel 9 gets no path: the reference's -0.0 + 0.0 makes it +0.0
    elif start == "a NaN":
        i0[2, 2] = np.nan
    a = Phasors(z0.copy(), i0.copy())
    b = Phasors(z0.copy(), i0.copy())
    a.add(flat, weight, value, code, periods)
    b.add_reference(flat, weight * value, code, periods)
    assert same(a.z, b.z) and same(a.intensity, b.intensity)
    # a second batch onto what the first left
    a.add(flat[::-1], weight, value, code, periods)
    b.add_reference(flat[::-1], weight * value, code, periods)
    assert same(a.z, b.z) and same(a.intensity, b.intensity)
    # empty batches leave zero images as the reference does
    c, d = Phasors.zeros(3, shape), Phasors.zeros(3, shape)
    c.add(flat[:0], weight[:0], value[:0], code[:0], periods)
    d.add_reference(flat[:0], weight[:0] * value[:0], code[:0], periods)
    assert same(c.z, d.z) and same(c.intensity, d.intensity)


def test_small_pages_switches_numpys_advice_off_and_back():
    setter = importlib.import_module("numpy._core.multiarray")._set_madvise_hugepage
    before = setter(True)
    try:
        with small_pages():
            assert setter(False) is False  # off inside
        assert setter(True) is True  # restored on exit
        with pytest.raises(RuntimeError):
            with small_pages():
                raise RuntimeError("boom")
        assert setter(True) is True  # restored on an error too
    finally:
        setter(before)


class _Mallinfo2(ctypes.Structure):
    _fields_ = [(f, ctypes.c_size_t) for f in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                                "fsmblks", "uordblks", "fordblks", "keepcost")]


def _mallinfo() -> _Mallinfo2:
    libc = optics._LIBC
    if libc is None or not hasattr(libc, "mallinfo2"):
        pytest.skip("not glibc 2.33 or later: kept_memory leaves the allocator alone")
    libc.mallinfo2.restype = _Mallinfo2
    info: _Mallinfo2 = libc.mallinfo2()
    return info


def test_kept_memory_serves_large_arrays_from_the_heap_and_keeps_them():
    """Outside, a 64 MB array is a fresh mmap; inside, it comes from the heap and its memory stays
    there when freed (the next array reuses it), until the outermost use ends. In a fresh process: once
    a process has used kept memory, its heap holds free chunks that glibc serves before it maps new
    memory (``malloc_trim`` returns their pages, not the chunks), so "outside" means a process that never
    kept any (the full suite's process has made ray-traced frames before this test)."""
    import subprocess
    import sys

    code = f"import runpy; runpy.run_path({__file__!r})['_kept_memory_check']()"
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]  # the child ran this file's check (an assertion fails it)


def _kept_memory_check() -> None:
    big = 8 << 20  # float64: 64 MB
    before = _mallinfo()
    a = np.ones(big)
    assert _mallinfo().hblkhd >= before.hblkhd + 8 * big  # mmapped
    del a
    with kept_memory():
        with kept_memory():  # nested: the outer one decides
            before = _mallinfo()
            a = np.ones(big)
            inside = _mallinfo()
            assert inside.hblkhd < before.hblkhd + 8 * big  # not mmapped: the heap
            assert inside.uordblks >= before.uordblks + 8 * big
            del a
            assert _mallinfo().fordblks >= 8 * big  # freed, kept
        assert optics._kept["depth"] == 1
        assert _mallinfo().fordblks >= 8 * big  # still kept: the outer use is on
        b = np.ones(big)
        assert _mallinfo().hblkhd < before.hblkhd + 8 * big
        del b
    assert optics._kept["depth"] == 0
    with pytest.raises(RuntimeError):
        with kept_memory():
            raise RuntimeError("boom")
    assert optics._kept["depth"] == 0  # left on an error too
    before = _mallinfo()
    c = np.ones(big)
    assert _mallinfo().hblkhd >= before.hblkhd + 8 * big  # the defaults are back: mmapped again
    del c


def test_frames_in_kept_memory_are_the_frames_made_alone():
    """A frame made after another in the same kept memory (as a log makes them) has the bytes of the
    frame made alone."""
    alone = synthesize_raytraced_frame(kind="zinc_nuts", seed=11, size=SIZE, fill_mm=FILL)
    with kept_memory():
        synthesize_raytraced_frame(kind="spheres", seed=12, size=SIZE, fill_mm=FILL)
        kept = synthesize_raytraced_frame(kind="zinc_nuts", seed=11, size=SIZE, fill_mm=FILL)
    assert kept.frame.xyz.tobytes() == alone.frame.xyz.tobytes()
    assert np.isfinite(alone.frame.xyz).any()
    assert same(kept.frame.rgb, alone.frame.rgb)
    for name in ("truth", "outlier_kind", "depth_true_m", "error_mm", "sigma_mm", "surface", "saturated"):
        assert same(getattr(kept, name), getattr(alone, name)), name
