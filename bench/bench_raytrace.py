"""CPU time per frame of the ray-traced sensor, against the hand-made generator in the same run.

    .venv/bin/python bench/bench_raytrace.py [--size 1920x1200] [--kinds spheres,black_nuts] [--seed 200]

Prints, per part kind, the CPU seconds (``time.process_time``: every thread of the process, so
Open3D's parallel ray casting counts in full) of one ray-traced frame split into its steps (pile,
scene, trace, measure), the total, the part of it spent in the kernel (``sys``: page faults of
fresh arrays, mostly), the wall time, and the ratio to one frame of the hand-made
generator (``replay.synth.synthesize_frame``, the reference) of the same kind, size and seed.
The issue's target: at most ~10 s per frame at 1920 x 1200 on two cores.
"""

from __future__ import annotations

import argparse
import resource
import time

from replay.synth import synthesize_frame
from replay.synth.raytrace import synthesize_raytraced_frame


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="1920x1200")
    ap.add_argument("--kinds", default="spheres,black_nuts")
    ap.add_argument("--seed", type=int, default=200)
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    # warm both up (numba kernels, Open3D and MuJoCo imports) on a tiny frame
    synthesize_frame(kind="rods", seed=0, size=(24, 40))
    synthesize_raytraced_frame(kind="rods", seed=0, size=(24, 40), fill_mm=2.0)
    print(f"size {w}x{h}, seed {args.seed}; CPU seconds per frame (process_time, all threads)")
    print(f"{'kind':13s} {'parts':>5s} {'pile':>6s} {'scene':>6s} {'trace':>6s} {'measure':>7s} {'total':>6s} "
          f"{'sys':>5s} {'wall':>6s} {'handmade':>8s} {'ratio':>6s}")
    for kind in args.kinds.split(","):
        c0 = time.process_time()
        synthesize_frame(kind=kind, seed=args.seed, size=(h, w))
        ref = time.process_time() - c0
        c0, w0, s0 = time.process_time(), time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF).ru_stime
        rf = synthesize_raytraced_frame(kind=kind, seed=args.seed, size=(h, w))
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        sys_s = resource.getrusage(resource.RUSAGE_SELF).ru_stime - s0
        s = rf.cpu_s
        print(f"{kind:13s} {len(rf.pile):5d} {s['pile']:6.2f} {s['scene']:6.2f} {s['trace']:6.2f} {s['measure']:7.2f} "
              f"{cpu:6.2f} {sys_s:5.2f} {wall:6.1f} {ref:8.2f} {cpu / ref:6.1f}")


if __name__ == "__main__":
    main()
