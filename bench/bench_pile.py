"""Ray-traced piles: how many simulations go unstable, how many parts fall out, what the retries cost.

    PYTHONPATH=. .venv/bin/python bench/bench_pile.py [--seeds 0:30] [--frames 1] [--kinds rods,spheres,...] \\
        [--pile floor|walls|both] [--against DIR] [--json OUT]

Each pile is the one ``zcut synth --sensor raytraced`` drops for that kind, seed and frame
(``replay.synth.raytrace.synthesize.synthesize_raytraced_frame``'s draws: the bin pose, the fill, the part count, the
walls), by ``replay.synth.raytrace.pile.drop_parts``; the pile is all that is made (no ray tracing: the size of the
frame plays no part in it). Per kind it prints the piles, those whose first simulation went unstable (MuJoCo's
"The simulation is unstable"), those refused (``UnstablePile``), the parts that fell out of the bin (in all, and the
piles that lost any) and the pile's CPU seconds (``time.process_time`` in the process that made it: median, largest,
sum).

``--against DIR`` (a ``git archive`` of another tree): the same piles by DIR's code too, each kind in two worker
processes (``PYTHONPATH`` at each tree), old and new in turns; the table then has both, and the count of the piles
whose first simulation was stable that are not identical in both trees to the bit (sha256 of the poses; must be 0).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def _seeds(text: str) -> list[int]:
    if ":" in text:
        a, b = text.split(":")
        return list(range(int(a), int(b)))
    return [int(x) for x in text.split(",")]


def make_piles(kind: str, seeds: list[int], frames: int, piles: list[str]) -> list[dict[str, Any]]:
    """One record per (seed, frame, pile): the pile as the ray-traced sensor drops it, with what it cost."""
    import numpy as np

    from replay.synth.raytrace import pile as P
    from replay.synth.raytrace.synthesize import FILL_RANGE_MM, MAX_PARTS, raytrace_rng
    from replay.synth.scene import lean_walls
    from replay.synth.synthesize import bin_pose_for, frame_rng
    from zcut.errors import ParameterError

    out = []
    for pile_kind in piles:
        for seed in seeds:
            for index in range(frames):
                pose = bin_pose_for(frame_rng(seed, index, empty=False), empty=False, index=index)
                rng = raytrace_rng(seed, index, empty=False)
                fill_mm = float(rng.uniform(*FILL_RANGE_MM))
                count = min(P.part_count(kind, fill_mm), MAX_PARTS)
                walls = lean_walls(seed, index) if pile_kind == "walls" else ()
                rec: dict[str, Any] = {"kind": kind, "seed": seed, "frame": index, "pile": pile_kind, "count": count}
                c0 = time.process_time()
                try:
                    heap = P.drop_parts(kind, pose, rng, count=count, walls=walls)
                except ParameterError as e:
                    rec.update(cpu_s=time.process_time() - c0, refused=str(e), n=0, escaped=count, unstable=True,
                               kept_unstable=False, retries=len(getattr(e, "runs", ())), digest="", time_step_s=None,
                               rested=False, warnings=[])
                    out.append(rec)
                    continue
                cpu_s = time.process_time() - c0
                thrown = getattr(heap, "unstable", ())
                h = hashlib.sha256()
                h.update(np.ascontiguousarray(heap.R).tobytes())
                h.update(np.ascontiguousarray(heap.t_mm).tobytes())
                rec.update(cpu_s=cpu_s, refused="", n=len(heap), escaped=int(heap.escaped),
                           # the old tree keeps an unstable first simulation: its warning says so
                           unstable=bool(thrown) or any("unstable" in w for w in heap.warnings),
                           kept_unstable=any("unstable" in w for w in heap.warnings),
                           retries=len(thrown), digest=h.hexdigest()[:16],
                           time_step_s=float(getattr(heap, "time_step_s", P.TIME_STEP_S)), rested=bool(heap.rested),
                           warnings=list(heap.warnings))
                out.append(rec)
    return out


def _worker(tree: Path, kind: str, args: argparse.Namespace) -> list[dict[str, Any]]:
    env = dict(os.environ, PYTHONPATH=str(tree))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", kind, "--seeds", args.seeds, "--frames",
           str(args.frames), "--pile", args.pile]
    got = subprocess.run(cmd, env=env, cwd=str(tree), check=True, capture_output=True, text=True)
    return [json.loads(line) for line in got.stdout.splitlines() if line.startswith("{")]


def _summary(recs: list[dict[str, Any]]) -> str:
    cpu = [r["cpu_s"] for r in recs]
    lost = sum(r["escaped"] for r in recs)
    losing = sum(r["escaped"] > 0 for r in recs)
    return (f"{len(recs):5d} {sum(r['unstable'] for r in recs):8d} {sum(bool(r['refused']) for r in recs):7d} "
            f"{lost:6d} {losing:6d} {statistics.median(cpu):7.2f} {max(cpu):7.2f} {sum(cpu):7.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0:30", help="a:b (b excluded) or a,b,c")
    ap.add_argument("--frames", type=int, default=1)
    ap.add_argument("--kinds", default="spheres,zinc_nuts,rods,black_screws,sprockets")
    ap.add_argument("--pile", choices=("floor", "walls", "both"), default="floor")
    ap.add_argument("--against", type=Path, default=None, help="another tree (a git archive) measured in turns")
    ap.add_argument("--json", type=Path, default=None, help="write every pile's record here")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    piles = ["floor", "walls"] if args.pile == "both" else [args.pile]
    if args.worker is not None:
        for rec in make_piles(args.worker, _seeds(args.seeds), args.frames, piles):
            print(json.dumps(rec), flush=True)
        return
    kinds = args.kinds.split(",")
    trees = [("new", ROOT)] + ([("old", args.against.resolve())] if args.against is not None else [])
    print(f"seeds {args.seeds}, frames {args.frames}, pile {args.pile}; load {os.getloadavg()[0]:.1f}")
    print(f"{'kind':13s} {'tree':4s} {'piles':>5s} {'unstable':>8s} {'refused':>7s} {'fell':>6s} {'losing':>6s} "
          f"{'med s':>7s} {'max s':>7s} {'sum s':>7s}")
    every: dict[str, list[dict[str, Any]]] = {name: [] for name, _ in trees}
    for j, kind in enumerate(kinds):
        order = trees if j % 2 == 0 else trees[::-1]  # old and new in turns
        got = {name: _worker(tree, kind, args) for name, tree in order}
        for name, _ in trees:
            every[name] += got[name]
            print(f"{kind:13s} {name:4s} {_summary(got[name])}", flush=True)
    for name, _ in trees:
        print(f"{'all':13s} {name:4s} {_summary(every[name])}")
    if args.against is not None:
        key = ("kind", "seed", "frame", "pile")
        old = {tuple(r[k] for k in key): r for r in every["old"]}
        stable = [r for r in every["new"] if not r["unstable"]]
        differ = [r for r in stable if old[tuple(r[k] for k in key)]["digest"] != r["digest"]]
        print(f"stable first simulations: {len(stable)}, not identical to the old tree's: {len(differ)}")
        fixed = [(r, old[tuple(r[k] for k in key)]) for r in every["new"] if r["unstable"]]
        for r, o in fixed:
            print(f"  {r['kind']} seed {r['seed']} frame {r['frame']} {r['pile']}: old {o['n']} kept, {o['escaped']} "
                  f"fell out; new {r['n']} kept, {r['escaped']} fell out at {1000 * (r['time_step_s'] or 0):g} ms "
                  f"({r['retries']} thrown away){'; refused' if r['refused'] else ''}")
    if any(r.get("kept_unstable") for r in every["new"]):
        print("a kept simulation of the new tree went unstable: see --json")
    if args.json is not None:
        args.json.write_text(json.dumps(every, indent=1))


if __name__ == "__main__":
    main()
