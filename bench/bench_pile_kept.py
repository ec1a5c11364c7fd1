"""Ray-traced piles: how many parts a pile keeps, where the others went, and what keeping them costs.

    PYTHONPATH=. .venv/bin/python bench/bench_pile_kept.py [--seeds 0:12] [--kinds rods,sprockets,...] \\
        [--pile floor|walls] [--against DIR] [--set NAME=VALUE ...] [--json OUT]

Each pile is the one ``zcut synth --sensor raytraced`` drops for that kind, seed and frame 0 (the draws of
``replay.synth.raytrace.synthesize.synthesize_raytraced_frame``: the bin pose, the fill, the part count, the walls),
made by ``replay.synth.raytrace.pile.drop_parts`` and nothing else (no ray tracing). Every simulation the pile ran
(``pile._settle``, wrapped) is looked at: its floor, its step, whether it went unstable, and the parts it lost by
where they ended (under the floor: origin deeper than 1 mm under its surface; beside the bin: farther out than the
floor's half size plus 10 mm a degree of draft; above: higher than the rim by 3 bounding radii) and by the layer of
the starting column they fell from (layer 0 the lowest; the column is one part's cell a layer).

Per kind and tree it prints: piles, parts asked, parts kept, lost (under the floor / beside / above), piles that
lost any, piles simulated more than once, simulations a pile (mean), the pile's CPU seconds (``time.process_time``
in the worker: median, largest, sum), and the first simulation's losses by the column's layer (the lower and the
upper half of the column).

``--set NAME=VALUE`` sets a constant of ``replay.synth.raytrace.pile`` in the workers of every tree (a Python
literal: ``--set FLOOR_THICKNESS_MM=100.0 --set "RETRIES=()"``), to measure what the floor, the step and the
retries do. ``--against DIR`` (a ``git archive`` of another tree): the same piles by DIR's code too, each kind in
two worker processes, old and new in turns; it then counts the piles whose poses are identical to the bit in both
trees (sha256 of ``R`` and ``t_mm``: identical poses, identical frame).
"""

from __future__ import annotations

import argparse
import ast
import hashlib
import json
import os
import re
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


def make_piles(kind: str, seeds: list[int], pile_kind: str, sets: list[str]) -> list[dict[str, Any]]:
    """One record per seed: the pile of frame 0 as the ray-traced sensor drops it, and every simulation it ran."""
    import numpy as np

    from replay.presets import BIN, PART_KINDS
    from replay.synth.raytrace import pile as P
    from replay.synth.raytrace.synthesize import FILL_RANGE_MM, MAX_PARTS, raytrace_rng
    from replay.synth.scene import lean_walls
    from replay.synth.synthesize import bin_pose_for, frame_rng
    from zcut.errors import ParameterError

    for item in sets:
        name, _, value = item.partition("=")
        setattr(P, name, ast.literal_eval(value))
    r = PART_KINDS[kind].bounding_radius_mm
    fx, fy = BIN.floor_half
    cell = 2.0 * r * 1.05
    per_layer = max(1, int((2 * fx - 2) // cell)) * max(1, int((2 * fy - 2) // cell))
    settle = P._settle
    runs: list[dict[str, Any]] = []

    def wrapped(world: str, n: int, vel: Any, **kw: Any) -> Any:
        c0 = time.process_time()
        run = settle(world, n, vel, **kw)
        half_m = float(re.search(r'<geom type="box" size="[^ ]+ [^ ]+ ([^"]+)"', world).group(1))  # type: ignore[union-attr]
        p = run.qpos[:, :3] * 1000.0
        margin = 10 * BIN.draft_deg
        under = p[:, 2] <= BIN.floor_mm - 1.0
        beside = ~under & ((np.abs(p[:, 0]) >= fx + margin) | (np.abs(p[:, 1]) >= fy + margin))
        above = ~under & ~beside & (p[:, 2] >= BIN.height_mm + 3 * r)
        lost = under | beside | above
        runs.append({"step_ms": 1000 * kw["time_step_s"], "floor_mm": round(2000 * half_m, 6),
                     "unstable": getattr(run, "unstable", None) is not None, "cpu_s": time.process_time() - c0,
                     "sim_s": run.sim_s, "rested": bool(run.rested), "under": int(under.sum()),
                     "beside": int(beside.sum()), "above": int(above.sum()),
                     "lost_layers": (np.flatnonzero(lost) // per_layer).tolist(), "layers": -(-n // per_layer)})
        return run

    P._settle = wrapped
    out = []
    for seed in seeds:
        pose = bin_pose_for(frame_rng(seed, 0, empty=False), empty=False, index=0)
        rng = raytrace_rng(seed, 0, empty=False)
        fill_mm = float(rng.uniform(*FILL_RANGE_MM))
        count = min(P.part_count(kind, fill_mm), MAX_PARTS)
        walls = lean_walls(seed, 0) if pile_kind == "walls" else ()
        rec: dict[str, Any] = {"kind": kind, "seed": seed, "pile": pile_kind, "count": count}
        runs.clear()
        c0 = time.process_time()
        try:
            heap = P.drop_parts(kind, pose, rng, count=count, walls=walls)
        except ParameterError as e:
            rec.update(cpu_s=time.process_time() - c0, refused=str(e), n=0, escaped=count, digest="",
                       runs=list(runs))
            out.append(rec)
            continue
        cpu_s = time.process_time() - c0
        h = hashlib.sha256()
        h.update(np.ascontiguousarray(heap.R).tobytes())
        h.update(np.ascontiguousarray(heap.t_mm).tobytes())
        rec.update(cpu_s=cpu_s, refused="", n=len(heap), escaped=int(heap.escaped), digest=h.hexdigest()[:16],
                   step_ms=1000 * float(getattr(heap, "time_step_s", P.TIME_STEP_S)),
                   floor_mm=float(getattr(heap, "floor_thickness_mm", 10.0)), rested=bool(heap.rested),
                   sim_s=float(heap.sim_s), runs=list(runs))
        out.append(rec)
    return out


def _worker(tree: Path, kind: str, args: argparse.Namespace) -> list[dict[str, Any]]:
    env = dict(os.environ, PYTHONPATH=str(tree))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", kind, "--seeds", args.seeds, "--pile", args.pile]
    for item in args.set:
        cmd += ["--set", item]
    got = subprocess.run(cmd, env=env, cwd=str(tree), check=True, capture_output=True, text=True)
    return [json.loads(line) for line in got.stdout.splitlines() if line.startswith("{")]


def _lost_where(rec: dict[str, Any]) -> tuple[int, int, int]:
    """(under, beside, above) of the simulation the pile kept: the stable one whose losses are the pile's."""
    kept = [r for r in rec["runs"] if not r["unstable"] and r["under"] + r["beside"] + r["above"] == rec["escaped"]
            and r["step_ms"] == rec.get("step_ms") and r["floor_mm"] == rec.get("floor_mm")]
    if not kept:
        return (0, 0, 0) if rec["escaped"] == 0 else (-1, -1, -1)
    k = kept[-1]
    return k["under"], k["beside"], k["above"]


def _summary(recs: list[dict[str, Any]]) -> str:
    cpu = [r["cpu_s"] for r in recs]
    where = [_lost_where(r) for r in recs]
    lost = sum(r["escaped"] for r in recs)
    first = [r["runs"][0] for r in recs if r["runs"]]
    low = sum(sum(1 for x in f["lost_layers"] if x < f["layers"] / 2) for f in first if not f["unstable"])
    high = sum(sum(1 for x in f["lost_layers"] if x >= f["layers"] / 2) for f in first if not f["unstable"])
    return (f"{len(recs):5d} {sum(r['count'] for r in recs):6d} {sum(r['n'] for r in recs):6d} {lost:5d} "
            f"{sum(w[0] for w in where):5d}/{sum(w[1] for w in where):d}/{sum(w[2] for w in where):d} "
            f"{sum(r['escaped'] > 0 for r in recs):6d} {sum(len(r['runs']) > 1 for r in recs):6d} "
            f"{sum(bool(r['refused']) for r in recs):4d} {statistics.mean(len(r['runs']) for r in recs):5.2f} "
            f"{statistics.median(cpu):6.2f} {max(cpu):6.2f} {sum(cpu):7.1f}   {low:4d} {high:4d}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0:12", help="a:b (b excluded) or a,b,c")
    ap.add_argument("--kinds", default="rods,sprockets,black_screws,zinc_nuts,spheres")
    ap.add_argument("--pile", choices=("floor", "walls"), default="floor")
    ap.add_argument("--against", type=Path, default=None, help="another tree (a git archive) measured in turns")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="set a constant of replay.synth.raytrace.pile in every tree's workers (a Python literal)")
    ap.add_argument("--json", type=Path, default=None, help="write every pile's record here")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker is not None:
        for rec in make_piles(args.worker, _seeds(args.seeds), args.pile, args.set):
            print(json.dumps(rec), flush=True)
        return
    kinds = args.kinds.split(",")
    trees = [("new", ROOT)] + ([("old", args.against.resolve())] if args.against is not None else [])
    print(f"seeds {args.seeds}, frame 0, pile {args.pile}, set {args.set or 'nothing'}; load {os.getloadavg()[0]:.1f}")
    print(f"{'kind':13s} {'tree':4s} {'piles':>5s} {'asked':>6s} {'kept':>6s} {'lost':>5s} {'und/bes/abv':>11s} "
          f"{'losing':>6s} {'again':>6s} {'refd':>4s} {'sims':>5s} {'med s':>6s} {'max s':>6s} {'sum s':>7s}   "
          f"first sim's lost from the column's lower / upper half")
    every: dict[str, list[dict[str, Any]]] = {name: [] for name, _ in trees}
    for j, kind in enumerate(kinds):
        order = trees if j % 2 == 0 else trees[::-1]  # old and new in turns
        got = {name: _worker(tree, kind, args) for name, tree in order}
        for name, _ in trees:
            every[name] += got[name]
            print(f"{kind:13s} {name:4s} {_summary(got[name])}", flush=True)
        if args.against is not None:
            old = {r["seed"]: r for r in got["old"]}
            same = sum(r["digest"] == old[r["seed"]]["digest"] for r in got["new"])
            print(f"{kind:13s} piles identical to the old tree's to the bit: {same} of {len(got['new'])}", flush=True)
    if args.json is not None:
        args.json.write_text(json.dumps(every, indent=1))


if __name__ == "__main__":
    main()
