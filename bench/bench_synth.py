"""Synthetic scans: CPU time per frame, against the scene and renderer measured in the same run.

    .venv/bin/python bench/bench_synth.py [--size 1920x1200] [--seeds 2] [--kinds spheres,rods] [--quantize-mm Q]

For each part kind and seed: CPU seconds of ``synthesize_frame`` (the whole frame), and, as the
reference, of its first steps alone on the same seed — dropping the pile and rendering it with the
projector's shadow map (``drop_pile``, ``render``, ``measure``), which issue 10 left unchanged. The
ratio total / reference is what the sensor model, the outliers and the colour image cost on top;
it does not move with the machine's load the way seconds do. What the frames hold and what the
filters find in them: ``bench/synth_truth_stats.py``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from replay.presets import PART_KINDS
from replay.synth import synthesize_frame
from replay.synth.scene import drop_pile, make_grid
from replay.synth.sensor import CAMERA_HEIGHT_MM, default_intrinsics, measure, render, view_half_extent_mm
from replay.synth.synthesize import FILL_RANGE_MM, bin_pose_for, frame_rng


def reference_seconds(kind: str, seed: int, size: tuple[int, int]) -> float:
    """CPU seconds of the pile and the renderer alone, drawn as ``synthesize_frame`` draws them."""
    c0 = time.process_time()
    rng = frame_rng(seed, 0, empty=False)
    K = default_intrinsics(size)
    half_x, half_y = view_half_extent_mm(K)
    step = float(np.clip(0.8 * (CAMERA_HEIGHT_MM - 3.0) / K.fx, 0.5, 1.0))
    grid = make_grid(half_x_mm=half_x + 5 * step, half_y_mm=half_y + 5 * step, step_mm=step)
    pose = bin_pose_for(rng, empty=False, index=0)
    scene = drop_pile(grid, pose, kind, rng, fill_mm=float(rng.uniform(*FILL_RANGE_MM)))
    view = render(scene, K)
    measure(scene, view, K)
    return time.process_time() - c0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="1920x1200")
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--kinds", default=",".join(PART_KINDS))
    ap.add_argument("--quantize-mm", type=float, default=0.0)
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    synthesize_frame(kind="spheres", seed=0, size=(60, 80))  # numba compile / cache load
    reference_seconds("spheres", 0, (60, 80))
    print(f"size {w}x{h}, seeds 0..{args.seeds - 1}, quantize {args.quantize_mm:g} mm; seconds per frame")
    print(f"{'kind':13s} {'wall s':>7s} {'cpu s':>6s} {'ref cpu':>8s} {'ratio':>6s} {'parts':>6s} {'truth px':>9s}")
    totals = np.zeros(2)
    for kind in args.kinds.split(","):
        walls, cpus, refs, parts, truth = [], [], [], [], []
        for seed in range(args.seeds):
            t0, c0 = time.perf_counter(), time.process_time()
            sf = synthesize_frame(kind=kind, seed=seed, size=(h, w), quantize_mm=args.quantize_mm)
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
            refs.append(reference_seconds(kind, seed, (h, w)))
            parts.append(len(sf.scene.parts))
            truth.append(int(sf.truth.sum()))
        totals += (sum(cpus), sum(refs))
        print(f"{kind:13s} {np.mean(walls):7.2f} {np.mean(cpus):6.2f} {np.mean(refs):8.2f} "
              f"{sum(cpus) / sum(refs):6.2f} {np.mean(parts):6.0f} {np.mean(truth):9.0f}")
    print(f"{'all':13s} {'':7s} {'':6s} {'':8s} {totals[0] / totals[1]:6.2f}")


if __name__ == "__main__":
    main()
