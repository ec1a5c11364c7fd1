"""Coverage of `zcut compare`'s paired interval (ΔP, ΔR, ΔF1 of B − A), measured by simulation.

The estimand: the difference of two filters' pooled (micro-averaged) precision, recall and F1 over
the population of frames of one part kind (one camera), both filters scored on the same frames. A
comparison sees n frames of that population and prints Δ with an interval
(:func:`zcut.paired.paired_interval_many`); this benchmark measures how often the interval holds the
population's Δ, as ``bench/interval_coverage.py`` does for one filter's pooled figure.

1. **Populations** (``generate``). Per part kind, ``zcut synth`` logs of independent frames (every
   frame has its own generator state), replayed with the logs' own bin models through
   :class:`studies.compare.PairRunner`: config A (the paper's nominal z-cut, SOR, radius, mixed
   pixels) and config B (z-cut ρ_thr 0.035, SOR std_ratio 2.0, the same others) on the same frames, the
   shared stages once; TP, FP, FN of every method of both over the zone, per frame, against the
   synthetic truth. Cached in ``WORK/paired_KIND_SIZE.npz``.
2. **Coverage** (``simulate``). For each pair of filters (a parameter change of one filter, and two
   different filters), draw samples of n = 6, 12, 24 frames with replacement from the population,
   compute the interval, count how often it holds the population's Δ (among the samples that get
   one).

    python bench/compare_coverage.py generate [--kinds rods,spheres] [--logs 12] [--size 160x256]
    python bench/compare_coverage.py simulate [--draws 4000] [--markdown docs/compare_coverage.md]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

A_LAYER = {"methods": ["zcut", "sor", "radius", "mixed_pixel"]}
B_LAYER = {"methods": ["zcut", "sor", "radius", "mixed_pixel"], "zcut": {"rho_thr": 0.035}, "sor": {"std_ratio": 2.0}}
#: (name, A's variant, B's variant): a parameter change of one filter, and different filters
PAIRS = (("z-cut ρ 0.07 → 0.035", "a:zcut", "b:zcut"), ("SOR std 1 → 2", "a:sor", "b:sor"),
         ("z-cut → SOR", "a:zcut", "a:sor"), ("z-cut → radius", "a:zcut", "a:radius"),
         ("z-cut → z-cut ∪ mixed pixels", "a:zcut", "a:zcut+mixed_pixel"), ("SOR → radius", "a:sor", "a:radius"))
NS = (6, 12, 24)
SEED0 = 730_000


def _population_path(work: Path, kind: str, size: str) -> Path:
    return work / f"paired_{kind}_{size}.npz"


def count_log(path: Path) -> dict[str, np.ndarray]:
    """Per-frame (tp, fp, fn) of every variant ``a:METHOD`` / ``b:METHOD`` of one log."""
    from annotate.truth import SyntheticTruth, pixel_counts, scored_region
    from replay.pipeline import config as cfg
    from replay.pipeline.bin_model import bin_model_for
    from replay.pipeline.methods import method_masks
    from replay.pipeline.session import open_log
    from studies.compare import PairRunner

    reader, first, _ = open_log(path)
    facts = cfg.log_facts(reader.metadata, first, intrinsics=getattr(reader, "intrinsics", None))
    ra, rb = cfg.resolve(facts, cli=A_LAYER), cfg.resolve(facts, cli=B_LAYER)
    runner = PairRunner(path, reader, first, ra, rb, bin_model_for(reader, None).model)
    truth = SyntheticTruth()
    rows: dict[str, list[tuple[int, int, int]]] = {}
    names = ("zcut", "sor", "radius", "mixed_pixel", "zcut+mixed_pixel")
    for frame, res_a, res_b in runner.frames((0, None)):
        for side, r in (("a", res_a), ("b", res_b)):
            t = truth.truth(frame, r.valid)
            assert not isinstance(t, str)
            masks = method_masks(r.outliers, names)
            region = scored_region(r, "zone")
            for m in names:
                rows.setdefault(f"{side}:{m}", []).append(pixel_counts(masks[m], t, region))
    return {k: np.array(v, dtype=np.int64).T for k, v in rows.items()}


def generate(args) -> int:
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    for ki, kind in enumerate(args.kinds.split(",")):
        dest = _population_path(work, kind, args.size)
        if dest.is_file():
            continue
        pop: dict[str, list[np.ndarray]] = {}
        t0 = time.perf_counter()
        for j in range(args.logs):
            log = work / f"{kind}_{j}.mcap"
            if not log.is_file():
                subprocess.run([sys.executable, "-m", "cli", "synth", "-o", str(log), "--parts", kind, "--frames",
                                str(args.frames_per_log), "--seed", str(SEED0 + 1000 * ki + j), "--size", args.size,
                                "--force"], cwd=ROOT, check=True, stdout=subprocess.DEVNULL)
            for k, v in count_log(log).items():
                pop.setdefault(k, []).append(v)
            log.unlink()
            print(f"{kind}: {j + 1}/{args.logs} logs, {time.perf_counter() - t0:.0f} s", file=sys.stderr)
        np.savez(dest, **{k.replace(":", "__").replace("+", "_plus_"): np.concatenate(v, axis=1)
                          for k, v in pop.items()})
    return 0


def load(work: Path, kind: str, size: str) -> dict[str, np.ndarray]:
    z = np.load(_population_path(work, kind, size))
    return {k.replace("__", ":").replace("_plus_", "+"): z[k] for k in z.files}


def _ratio(num: np.ndarray, den: np.ndarray) -> float:
    return float(num.sum() / den.sum()) if den.sum() > 0 else float("nan")


def coverage(pop: dict[str, np.ndarray], a: str, b: str, n: int, draws: int, rng) -> dict[str, dict[str, float]]:
    from zcut.paired import FIGURES, figure_parts, paired_interval_many

    A, B = pop[a], pop[b]
    n_pop = A.shape[1]
    idx = rng.integers(0, n_pop, size=(draws, n))
    got = paired_interval_many(tuple(A[k][idx] for k in range(3)), tuple(B[k][idx] for k in range(3)))
    out = {}
    for fig in FIGURES:
        truth = _ratio(*figure_parts(fig, *B)) - _ratio(*figure_parts(fig, *A))
        lo, hi = got[fig][:, 1], got[fig][:, 2]
        ok = np.isfinite(lo) & np.isfinite(hi)
        held = (lo[ok] <= truth + 1e-12) & (truth - 1e-12 <= hi[ok])
        out[fig] = {"truth": truth, "coverage": float(held.mean()) if ok.any() else float("nan"),
                    "none": float(1 - ok.mean()), "width": float((hi[ok] - lo[ok]).mean()) if ok.any() else float("nan"),
                    "reject0": float(((lo[ok] > 0) | (hi[ok] < 0)).mean()) if ok.any() else float("nan")}
    return out


def simulate(args) -> int:
    work = Path(args.work)
    rng = np.random.default_rng(args.seed)
    lines = ["| kind | frames in population | pair (A → B) | figure | population Δ | "
             + " | ".join(f"n = {n}: coverage (no interval), mean width" for n in NS) + " |",
             "|---|---|---|---|---|" + "---|" * len(NS)]
    worst = {n: (1.0, "") for n in NS}
    for kind in args.kinds.split(","):
        pop = load(work, kind, args.size)
        n_pop = next(iter(pop.values())).shape[1]
        for name, a, b in PAIRS:
            res = {n: coverage(pop, a, b, n, args.draws, rng) for n in NS}
            for fig in ("precision", "recall", "f1"):
                cells = []
                for n in NS:
                    r = res[n][fig]
                    cells.append(f"{r['coverage']:.3f} ({r['none']:.1%}), {r['width']:.3f}")
                    if r["coverage"] == r["coverage"] and r["coverage"] < worst[n][0]:
                        worst[n] = (r["coverage"], f"{kind} {name} {fig}")
                lines.append(f"| {kind} | {n_pop} | {name} | {fig} | {res[NS[0]][fig]['truth']:+.4f} | "
                             + " | ".join(cells) + " |")
    lines += ["", "| n | worst coverage (cell) |", "|---|---|"]
    lines += [f"| {n} | {worst[n][0]:.3f} ({worst[n][1]}) |" for n in NS]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.markdown:
        Path(args.markdown).write_text(text)
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    g = sub.add_parser("generate")
    g.add_argument("--kinds", default="rods,spheres")
    g.add_argument("--logs", type=int, default=12)
    g.add_argument("--frames-per-log", type=int, default=8)
    g.add_argument("--size", default="160x256")
    g.add_argument("--work", default="/tmp/zcut_compare_coverage")
    s = sub.add_parser("simulate")
    s.add_argument("--kinds", default="rods,spheres")
    s.add_argument("--size", default="160x256")
    s.add_argument("--draws", type=int, default=4000)
    s.add_argument("--seed", type=int, default=1)
    s.add_argument("--markdown")
    s.add_argument("--work", default="/tmp/zcut_compare_coverage")
    args = ap.parse_args()
    return {"generate": generate, "simulate": simulate}[args.cmd](args)


if __name__ == "__main__":
    sys.exit(main())
