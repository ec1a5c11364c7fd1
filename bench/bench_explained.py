"""Benchmark: the method ``explained`` against the paper's truth (issue 29 item 4).

Run: ``.venv/bin/python bench/bench_explained.py [--size 960x600] [--kinds LIST] [--frames N] [--method]``

**The rule and the truth are one definition.** Per (generator, kind), frames synthesised with seeds
used nowhere else (hand-made 9701.., ray-traced 9801..), the scene's true meshes standing in for the
fits (``tests/explained_helpers.py``: built as the generators build their truth), the frame's every
valid pixel judged by :mod:`zcut.explained`:

- ``IoU gen-Err``: the unexplained pixels with the generator's own Err against
  ``/ground_truth/off_surface`` (the distance and the rule alone);
- ``IoU own-Err``: the same with the Err the method estimates (:func:`zcut.explained.surface_sigmas`:
  each surface's robust residual, the pixel's footprint), as on a real scan, where no generator
  states the noise;
- ``CPU s``: CPU seconds of the distances (:func:`zcut.explained.nearest_surface`) per frame.

``--method``: also the whole method on a log of each (``zcut synth`` in a temporary folder; the
part fits of :mod:`zcut.fits`, the registered bin, the table plane): precision, recall and IoU of its
outliers with the paper's truth inside the zone, the share of the zone's pixels its fits explain and
its CPU seconds per frame.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from explained_helpers import handmade_true_surfaces, raytraced_true_surfaces  # noqa: E402

from zcut import explained as ex  # noqa: E402

HANDMADE_SEED, RAYTRACED_SEED = 9701, 9801


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    u = int((a | b).sum())
    return float((a & b).sum() / u) if u else 1.0


def rule_check(generator: str, kind: str, seed: int, size: tuple[int, int]) -> dict[str, float]:
    """IoU of the rule with the paper's truth on one frame, with the generator's Err and the method's own."""
    if generator == "handmade":
        from replay.synth.synthesize import synthesize_frame

        sf = synthesize_frame(kind=kind, seed=seed, index=0, size=size)
        parts, surfaces = handmade_true_surfaces(sf)
    else:
        from replay.synth.raytrace import synthesize_raytraced_frame

        sf = synthesize_raytraced_frame(kind=kind, seed=seed, index=0, size=size)
        parts, surfaces = raytraced_true_surfaces(sf, seed=seed, index=0)
    xyz = sf.frame.xyz.astype(np.float64) * 1000.0
    t = time.process_time()
    near = ex.nearest_surface(xyz, surfaces)
    cpu = time.process_time() - t
    truth = sf.off_surface
    gen = ex.unexplained(near.dist_mm, sf.err_mm.astype(np.float64), ex.K_ERR)
    c = ex.footprint_mm(xyz, ex.focal_px(xyz))
    sig, bin_sigma, table_sigma = ex.surface_sigmas(near, len(parts), c)
    assert surfaces.table is not None
    own_surfaces = dataclasses.replace(surfaces, part_err_mm=sig, bin_err_mm=bin_sigma,
                                       table=dataclasses.replace(surfaces.table, residual_mm=table_sigma))
    own = ex.unexplained(near.dist_mm, ex.err_image(near, own_surfaces, c), ex.K_ERR)
    return {"truth": float(truth.sum()), "iou_gen": _iou(gen, truth), "iou_own": _iou(own, truth), "cpu": cpu}


def method_check(generator: str, kind: str, seed: int, size: tuple[int, int]) -> dict[str, float]:
    """The whole method on a one-frame log: precision, recall, IoU in the zone, fits' share, CPU s."""
    from cli.main import main
    from replay.logs import layout
    from replay.options import PipelineOptions
    from replay.pipeline.explained import run_explained
    from replay.pipeline.stages import bin_zone

    with tempfile.TemporaryDirectory() as d:
        log = Path(d) / "log.mcap"
        args = ["synth", "-o", str(log), "--parts", kind, "--seed", str(seed), "--size", f"{size[1]}x{size[0]}"]
        if generator == "raytraced":
            args += ["--sensor", "raytraced"]
        assert main(args) == 0
        session = PipelineOptions(methods="zcut,explained").open_session(log)
        frame = next(iter(session.reader.frames()))
        zone = bin_zone(frame, session.resolved.config, bin_model=session.prepared)
        t = time.process_time()
        mask, detail, warning = run_explained(frame, zone, session.resolved.config)
        cpu = time.process_time() - t
    truth = frame.masks[layout.TRUTH_OFF_SURFACE] & zone.zone
    tp = int((mask & truth).sum())
    explained = np.zeros(zone.zone.size, bool)
    for f in detail.fits if detail is not None else ():
        explained[f.pixels] = True
    return {"precision": tp / max(int(mask.sum()), 1), "recall": tp / max(int(truth.sum()), 1),
            "iou": _iou(mask, truth), "fits": len(detail.fits) if detail is not None else 0,
            "fit_share": float((explained.reshape(zone.zone.shape) & zone.zone).sum() / max(int(zone.zone.sum()), 1)),
            "cpu": cpu, "warning": warning or ""}  # type: ignore[dict-item]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", default="960x600", help="WIDTHxHEIGHT (default 960x600)")
    ap.add_argument("--kinds", default="zinc_nuts,black_nuts,spheres,rods")
    ap.add_argument("--frames", type=int, default=1, help="frames (seeds) per generator and kind")
    ap.add_argument("--generators", default="handmade,raytraced")
    ap.add_argument("--method", action="store_true", help="also run the whole method (part fits) on a log of each")
    a = ap.parse_args()
    w, h = (int(v) for v in a.size.split("x"))
    print(f"true meshes as fits, {w}x{h}; IoU with /ground_truth/off_surface (every valid pixel)")
    print(f"{'generator':<10} {'kind':<11} {'seed':>5} {'truth px':>8} {'IoU gen-Err':>11} {'IoU own-Err':>11} {'CPU s':>6}")
    rows = []
    for g in a.generators.split(","):
        for k_i, kind in enumerate(a.kinds.split(",")):
            for f in range(a.frames):
                seed = (HANDMADE_SEED if g == "handmade" else RAYTRACED_SEED) + 10 * k_i + f
                r = rule_check(g, kind, seed, (h, w))
                rows.append(r)
                print(f"{g:<10} {kind:<11} {seed:>5} {r['truth']:>8.0f} {r['iou_gen']:>11.4f} {r['iou_own']:>11.4f} "
                      f"{r['cpu']:>6.2f}", flush=True)
    print(f"min IoU gen-Err {min(r['iou_gen'] for r in rows):.4f}, own-Err {min(r['iou_own'] for r in rows):.4f}")
    if not a.method:
        return
    print(f"\nthe method with its part fits ({w}x{h}), in the zone, against /ground_truth/off_surface")
    print(f"{'generator':<10} {'kind':<11} {'seed':>5} {'fits':>5} {'fit share':>9} {'precision':>9} {'recall':>7} "
          f"{'IoU':>6} {'CPU s':>6}")
    for g in a.generators.split(","):
        for k_i, kind in enumerate(a.kinds.split(",")):
            seed = (HANDMADE_SEED if g == "handmade" else RAYTRACED_SEED) + 10 * k_i
            try:
                m = method_check(g, kind, seed, (h, w))
            except Exception as e:  # noqa: BLE001 - a failing fit is a row of the table, not the end of it
                print(f"{g:<10} {kind:<11} {seed:>5} failed: {type(e).__name__}: {e}", flush=True)
                continue
            print(f"{g:<10} {kind:<11} {seed:>5} {m['fits']:>5} {m['fit_share']:>9.3f} {m['precision']:>9.3f} "
                  f"{m['recall']:>7.3f} {m['iou']:>6.3f} {m['cpu']:>6.1f} {m['warning']}", flush=True)


if __name__ == "__main__":
    main()
