"""Benchmark: the sensor's truth against the paper's, per generator and part kind (docs/accuracy.md, "Two truths").

Run: ``.venv/bin/python bench/bench_truths.py [--size 300x480] [--frames 3] [--rt-frames 2] [--kinds LIST]``

The sensor's truth (``/ground_truth/outliers``: the point is not what its pixel's footprint saw)
and the paper's (``/ground_truth/off_surface``: the point lies farther than 3 × Err from every true
surface, :mod:`replay.synth.surfaces`) of the same frames, pooled over the frames of each
(generator, kind):

- ``IoU`` of the two masks, their pixel counts ``sensor`` and ``paper``;
- ``within``: the share of the sensor's truth within 3 × Err of a real surface (sensor ∖ paper),
  and which of the sensor's kinds they are;
- ``adds``: the pixels the paper's truth adds (paper ∖ sensor) and the share of them at a depth edge
  (the true depth spans more than 2 mm over the pixel's 3 × 3 neighbourhood);
- ``CPU``: CPU seconds of the new truth per frame (true surfaces and distances) and its share of
  the frame's own CPU time (the hand-made generator: the rest of the frame; the ray-traced: the
  whole frame).

Seeds 7301.. (hand-made) and 7401.. (ray-traced) are used nowhere else and tuned nothing.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy import ndimage

from replay.logs import layout

HANDMADE_SEED = 7301
RAYTRACED_SEED = 7401


class _Clock:
    """CPU seconds spent in the wrapped functions."""

    def __init__(self) -> None:
        self.s = 0.0

    def wrap(self, fn):
        def timed(*a, **k):
            t = time.process_time()
            try:
                return fn(*a, **k)
            finally:
                self.s += time.process_time() - t
        return timed


def _edge(depth_mm: np.ndarray) -> np.ndarray:
    z = np.where(np.isfinite(depth_mm), depth_mm, 1e4)
    return (ndimage.maximum_filter(z, 3) - ndimage.minimum_filter(z, 3)) > 2.0


def _row(stats: list[dict]) -> dict:
    keys = ("sensor", "paper", "both", "within", "adds", "adds_edge", "truth_s", "frame_s")
    tot = {k: sum(s[k] for s in stats) for k in keys}
    kinds: dict[str, int] = {}
    for s in stats:
        for k, v in s["within_kinds"].items():
            kinds[k] = kinds.get(k, 0) + v
    union = tot["sensor"] + tot["paper"] - tot["both"]
    return {
        **tot, "frames": len(stats), "iou": tot["both"] / union if union else float("nan"),
        "within_share": tot["within"] / tot["sensor"] if tot["sensor"] else float("nan"),
        "adds_edge_share": tot["adds_edge"] / tot["adds"] if tot["adds"] else float("nan"),
        "truth_s_per_frame": tot["truth_s"] / len(stats), "share": tot["truth_s"] / tot["frame_s"],
        "within_kinds": kinds,
    }


def _stats(truth, off, kind_img, depth_mm, truth_s, frame_s) -> dict:
    within = truth & ~off
    adds = off & ~truth
    codes, counts = np.unique(kind_img[within], return_counts=True)
    return {"sensor": int(truth.sum()), "paper": int(off.sum()), "both": int((truth & off).sum()),
            "within": int(within.sum()), "adds": int(adds.sum()), "adds_edge": int((adds & _edge(depth_mm)).sum()),
            "within_kinds": {layout.OUTLIER_KINDS[int(c)]: int(n) for c, n in zip(codes, counts)},
            "truth_s": truth_s, "frame_s": frame_s}


def handmade(kind: str, size: tuple[int, int], frames: int) -> dict:
    import replay.synth.synthesize as S

    clock = _Clock()
    plain_off, plain_hs = S.off_surface, S.handmade_surfaces
    S.off_surface, S.handmade_surfaces = clock.wrap(plain_off), clock.wrap(plain_hs)
    try:
        S.synthesize_frame(kind=kind, seed=HANDMADE_SEED - 1, size=(48, 80))  # warm-up (numba, imports)
        out = []
        for i in range(frames):
            clock.s = 0.0
            t = time.process_time()
            sf = S.synthesize_frame(kind=kind, seed=HANDMADE_SEED, index=i, size=size)
            total = time.process_time() - t
            out.append(_stats(sf.truth, sf.off_surface, sf.outlier_kind, sf.surface_depth_mm, clock.s,
                              total - clock.s))
    finally:
        S.off_surface, S.handmade_surfaces = plain_off, plain_hs
    return _row(out)


def raytraced(kind: str, size: tuple[int, int], frames: int) -> dict:
    from replay.synth.raytrace import synthesize_raytraced_frame

    out = []
    for i in range(frames):
        t = time.process_time()
        rf = synthesize_raytraced_frame(kind=kind, seed=RAYTRACED_SEED, index=i, size=size)
        total = time.process_time() - t
        out.append(_stats(rf.truth, rf.off_surface, rf.outlier_kind, rf.depth_true_m * 1000.0,
                          rf.cpu_s["off_surface"], total))
    return _row(out)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--size", default="300x480", help="HxW (default 300x480)")
    p.add_argument("--frames", type=int, default=3, help="hand-made frames per kind (default 3)")
    p.add_argument("--rt-frames", type=int, default=2, help="ray-traced frames per kind (default 2; 0: none)")
    p.add_argument("--kinds", default="zinc_nuts,black_nuts,spheres,rods")
    args = p.parse_args(argv)
    h, w = (int(v) for v in args.size.lower().split("x"))
    print(f"size {w}x{h}; seeds {HANDMADE_SEED} (hand-made), {RAYTRACED_SEED} (ray-traced)")
    print("| generator | kind | frames | IoU | sensor px | paper px | sensor within 3 Err | (of which) | "
          "paper adds | adds at an edge | truth CPU s/frame | share of frame CPU |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for gen, fn, n in (("hand-made", handmade, args.frames), ("ray-traced", raytraced, args.rt_frames)):
        if n <= 0:
            continue
        for kind in args.kinds.split(","):
            r = fn(kind, (h, w), n)
            kinds = ", ".join(f"{k} {v}" for k, v in sorted(r["within_kinds"].items(), key=lambda kv: -kv[1]))
            print(f"| {gen} | {kind} | {r['frames']} | {r['iou']:.2f} | {r['sensor']} | {r['paper']} | "
                  f"{r['within_share']:.0%} ({r['within']}) | {kinds} | {r['adds']} | {r['adds_edge_share']:.0%} | "
                  f"{r['truth_s_per_frame']:.2f} | {r['share']:.0%} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
