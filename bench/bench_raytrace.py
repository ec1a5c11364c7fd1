"""CPU time per frame of the ray-traced sensor, against the hand-made generator in the same run.

    .venv/bin/python bench/bench_raytrace.py [--size 1920x1200] [--kinds spheres,black_nuts] [--seed 200] [--frames 2] \\
        [--variant base|filters|spec_half|bounces2|strict]

Prints, per part kind and frame, the CPU seconds (``time.process_time``: every thread of the
process, so Open3D's parallel ray casting counts in full) of one ray-traced frame split into its
steps (pile, scene, trace, measure incl. the camera's filters when they run, the paper's truth
``off_surface``), the total, its user and system parts (``getrusage``; system time is the kernel's,
page faults of fresh arrays mostly), the page faults, the wall time, and the ratio to one frame of
the hand-made generator (``replay.synth.synthesize_frame``, the reference) of the same kind, size
and seed. ``--frames N`` makes frames 0..N-1 of the kind one after the other as ``zcut synth``
writes a log (within ``optics.kept_memory`` when the code under test has it, so the frames after
the first reuse the first one's memory); frame 0 is what a process making one frame pays. The
issue's target: at most ~10 s per frame at 1920 x 1200 on two cores.

``--variant``: the sensor variants of the sensitivity study (``bench/raytrace_paper.py``):
``filters`` (``--camera-filters``), ``spec_half`` (every part's specular share halved, in this
process only), ``bounces2`` (two camera-side bounces), ``strict`` (fringe contrast >= 0.5, signal
>= 0.008).

To compare with an older tree, run this script with ``PYTHONPATH`` at that tree (a ``git archive``
of it): the same measurement of the other code.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import resource
import time
from collections.abc import Iterator
from typing import Any

from replay.synth import synthesize_frame
from replay.synth.raytrace import SensorModel, optics, synthesize_raytraced_frame

VARIANTS = ("base", "filters", "spec_half", "bounces2", "strict")


def variant_options(name: str) -> dict[str, Any]:
    """The keyword arguments of ``synthesize_raytraced_frame`` for sensor variant ``name``."""
    if name == "filters":
        from replay.synth.raytrace.camera_filters import CameraFilters

        return {"camera_filters": CameraFilters()}
    if name == "bounces2":
        return {"model": SensorModel(bounces=2)}
    if name == "strict":
        return {"model": SensorModel(min_contrast=0.5, min_signal=0.008)}
    return {}


def variant_specular(name: str) -> float:
    """The factor on every part material's specular share for sensor variant ``name``
    (:func:`specular_scaled`)."""
    return 0.5 if name == "spec_half" else 1.0


@contextlib.contextmanager
def specular_scaled(scale: float) -> Iterator[None]:
    """Within: every part material's specular share times ``scale`` (this process only; also
    ``bench/raytrace_paper.py``'s)."""
    from replay.synth.raytrace import scene

    saved = dict(scene.PART_MATERIALS)
    try:
        for k, m in saved.items():
            scene.PART_MATERIALS[k] = dataclasses.replace(m, specular=m.specular * scale)
        yield
    finally:
        scene.PART_MATERIALS.clear()
        scene.PART_MATERIALS.update(saved)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="1920x1200")
    ap.add_argument("--kinds", default="spheres,black_nuts")
    ap.add_argument("--seed", type=int, default=200)
    ap.add_argument("--frames", type=int, default=1)
    ap.add_argument("--variant", choices=VARIANTS, default="base")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    opts = variant_options(args.variant)
    # warm both up (numba kernels, Open3D and MuJoCo imports) on a tiny frame
    synthesize_frame(kind="rods", seed=0, size=(24, 40))
    synthesize_raytraced_frame(kind="rods", seed=0, size=(24, 40), fill_mm=2.0, **opts)
    kept = getattr(optics, "kept_memory", contextlib.nullcontext)  # an older tree has none
    print(f"size {w}x{h}, seed {args.seed}, variant {args.variant}; CPU seconds per frame (process_time, all threads)")
    print(f"{'kind':13s} {'frame':>5s} {'parts':>5s} {'pile':>6s} {'scene':>6s} {'trace':>6s} {'measure':>7s} "
          f"{'off':>5s} {'total':>6s} {'user':>6s} {'sys':>5s} {'faults':>7s} {'wall':>6s} {'handmade':>8s} {'ratio':>6s}")
    for kind in args.kinds.split(","):
        c0 = time.process_time()
        synthesize_frame(kind=kind, seed=args.seed, size=(h, w))
        ref = time.process_time() - c0
        with kept(), specular_scaled(variant_specular(args.variant)):
            for index in range(args.frames):
                r0 = resource.getrusage(resource.RUSAGE_SELF)
                c0, w0 = time.process_time(), time.perf_counter()
                rf = synthesize_raytraced_frame(kind=kind, seed=args.seed, index=index, size=(h, w), **opts)
                cpu, wall = time.process_time() - c0, time.perf_counter() - w0
                r1 = resource.getrusage(resource.RUSAGE_SELF)
                s = rf.cpu_s
                print(f"{kind:13s} {index:5d} {len(rf.pile or ()):5d} {s['pile']:6.2f} {s['scene']:6.2f} {s['trace']:6.2f} "
                      f"{s['measure']:7.2f} {s.get('off_surface', float('nan')):5.2f} {cpu:6.2f} "
                      f"{r1.ru_utime - r0.ru_utime:6.2f} {r1.ru_stime - r0.ru_stime:5.2f} "
                      f"{(r1.ru_minflt - r0.ru_minflt) / 1e6:6.2f}M {wall:6.1f} {ref:8.2f} {cpu / ref:6.1f}", flush=True)


if __name__ == "__main__":
    main()
