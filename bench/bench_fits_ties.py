"""The fits' choice among near-tied guesses under several sign conventions of the principal axes, against an older
tree's fits, on the same frames in one process (issue 29: docs/fits.md, "The fits' choice among near-tied guesses").

    PYTHONPATH=. .venv/bin/python bench/bench_fits_ties.py --old /tmp/old [--seed 7751] [--frames 0,1,2] \\
        [--sensors handmade,raytraced] [--conventions lapack,pos,neg,first] [--settings 0.01:2] [--repeat 3] \\
        [--cache DIR] [--json OUT]

The axes' signs are an arbitrary choice of the eigen-decomposition: the fits take them from ``np.linalg.eigh`` of a
3 × 3 covariance (the model's axes in ``prepare_model``, each region's in ``_fit_general``). A **convention** here
replaces ``numpy.linalg.eigh`` in this process (no library switch) by LAPACK's decomposition with each eigenvector's
sign set by a rule, for every 3 × 3 input:

- ``lapack``: as LAPACK gives it (main's);
- ``pos`` / ``neg``: the vector's entry of largest magnitude positive / negative;
- ``first``: its first nonzero entry (x) positive;
- ``mix``: as ``pos``, the middle vector (second of ascending eigenvalues) then negated.

``--old``: a ``git archive`` of the older tree; its ``zcut/fits`` is imported as bench/bench_fits_blas.py does (a copy
kept in ``--oldpkg``, so numba's cache of it lasts between runs). This tree's fits as they are (``--settings this``,
the default), or, in a checkout of the reverted lever (h/blas3 56d1a8d: every candidate's last refinement; fa87438:
the kept one's only, docs/fits.md), ``--settings D:K,...``: with the params module's ``TIE_MARGIN`` = D and
``TIE_CANDIDATES`` = K.
Frames: bench/bench_fits.py's generators at the seed and frame index of a ``zcut synth --seed S --frames N`` log
(bench/bench_fits_blas.py's ``_truth``; ``--cache``), its oracle zone. Each tree prepares its model under each
convention. Under the first convention each frame is fitted ``--repeat`` times, under the others once, the trees alternating
(their order reversed on odd repeat + convention index): the CPU-s of ``fit_prepared`` (``time.process_time``, the
median of the first convention's repeats; ``cpu_all`` in the JSON).
Scored by bench/bench_fits.py's ``score``; per sensor: found (sum), explained (mean of frames), rotation median / p90
and translation median (medians of the frames' values), fits on no instance (sum), CPU (sum of the medians); then
each tree's spread over the conventions (max − min) of the explained share and of the p90 rotation.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_fits as BF  # noqa: E402
import bench_fits_blas as BB  # noqa: E402

_EIGH = np.linalg.eigh


def _signed(rule: str) -> Callable[[np.ndarray], np.ndarray]:
    """The sign (±1) of each column of an eigenvector matrix under ``rule`` (see the module docstring)."""
    def big(V: np.ndarray) -> np.ndarray:
        j = np.argmax(np.abs(V), axis=0)
        return np.where(V[j, np.arange(V.shape[1])] < 0, -1.0, 1.0)

    def first(V: np.ndarray) -> np.ndarray:
        out = np.ones(V.shape[1])
        for col in range(V.shape[1]):
            nz = np.flatnonzero(V[:, col] != 0)
            if len(nz) and V[nz[0], col] < 0:
                out[col] = -1.0
        return out

    def mix(V: np.ndarray) -> np.ndarray:
        s = big(V)
        s[1] = -s[1]
        return s

    rules: dict[str, Callable[[np.ndarray], np.ndarray]] = {
        "pos": big, "neg": lambda V: -big(V), "first": first, "mix": mix}
    return rules[rule]


def convention(rule: str) -> None:
    """Make ``numpy.linalg.eigh`` follow ``rule`` for 3 × 3 inputs (``lapack``: LAPACK's own)."""
    if rule == "lapack":
        np.linalg.eigh = _EIGH
        return
    sign = _signed(rule)

    def eigh(a: Any, *args: Any, **kw: Any) -> Any:
        w, V = _EIGH(a, *args, **kw)
        if np.shape(a) == (3, 3):
            V = V * sign(V)[None, :]
        return w, V

    np.linalg.eigh = eigh


def summary(rows: list[dict[str, Any]], sensor: str, tree: str, conv: str) -> dict[str, float]:
    """The per-sensor figures of one tree under one convention (the module docstring)."""
    rs = [r for r in rows if r["sensor"] == sensor and r["tree"] == tree and r["conv"] == conv]
    return {"found": sum(r["found_visible"] for r in rs), "explained": float(np.mean([r["explained_top"] for r in rs])),
            "med_deg": float(np.median([r["median_deg"] for r in rs])),
            "p90_deg": float(np.median([r["p90_deg"] for r in rs])),
            "med_mm": float(np.median([r["median_mm"] for r in rs])), "nomatch": sum(r["nomatch"] for r in rs),
            "fits": sum(r["fits"] for r in rs), "full": sum(r["matched"] for r in rs),
            "cpu": sum(r["cpu_s"] for r in rs), "frames": len(rs)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", type=Path, required=True, help="a git archive of the older tree")
    ap.add_argument("--oldpkg", type=Path, default=Path("/tmp/bench_fits_ties_old"),
                    help="where the older tree's zcut/fits is copied (kept: numba's cache)")
    ap.add_argument("--seed", type=int, default=7751)
    ap.add_argument("--frames", default="0,1,2")
    ap.add_argument("--sensors", default="handmade,raytraced")
    ap.add_argument("--kind", default="zinc_nuts")
    ap.add_argument("--size", default="1920x1200")
    ap.add_argument("--conventions", default="lapack,pos,neg,first")
    ap.add_argument("--settings", default="this",
                    help="this: this tree as it is; else TIE_MARGIN:TIE_CANDIDATES, comma separated (a tree with them)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--cache", default=None, metavar="DIR", help="keep the synthesized frames in DIR")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    from replay.process import configure_process

    configure_process()  # the process settings of every zcut command (bench_fits.py's default)
    if not (args.old / "zcut" / "fits" / "__init__.py").is_file():
        raise SystemExit(f"--old {args.old}: no zcut/fits/__init__.py there (a git archive of a zcut tree?)")
    import zcut.fits as new
    import zcut.fits.params as P
    from replay.logs.part_model import PART_MODEL_ATTACHMENT, read_part_model_bytes
    from replay.synth.log import part_model_attachment

    args.oldpkg.mkdir(parents=True, exist_ok=True)
    old = BB._load_old(args.old, args.oldpkg)
    settings: list[tuple[str, float | None, int | None]] = []
    for item in args.settings.split(","):
        d, _, k = item.partition(":")
        if item != "this" and not (k and hasattr(P, "TIE_MARGIN")):
            raise SystemExit(f"--settings {item}: give D:K, in a tree whose zcut/fits/params.py has TIE_MARGIN")
        settings.append((item, float(d), int(k)) if item != "this" else (item, None, None))
    convs = args.conventions.split(",")
    w, h = (int(v) for v in args.size.split("x"))
    rows: list[dict[str, Any]] = []
    print(f"{'sensor':9s} {'fr':>2s} {'conv':6s} {'tree':9s} {'found':>9s} {'full':>7s} {'med mm':>7s} {'med deg':>7s} "
          f"{'p90 deg':>7s} {'expl':>6s} {'nomat':>5s} {'fits':>4s} {'cpu s':>6s}  load", flush=True)
    for sensor in args.sensors.split(","):
        data = part_model_attachment(args.kind, raytraced=sensor == "raytraced")[PART_MODEL_ATTACHMENT][1]
        pm = read_part_model_bytes(data)
        scale = 1000.0 if pm.unit == "m" else 1.0
        models: dict[tuple[str, str], Any] = {}
        for conv in convs:
            convention(conv)
            for name, mod in (("main", old), ("branch", new)):
                models[conv, name] = mod.prepare_model(pm.vertices * scale, pm.triangles,
                                                       sphere_tolerance=mod.FitParams().sphere_tolerance)
            print(f"{sensor} {conv}: guess classes main {len(models[conv, 'main'].guesses)}, branch "
                  f"{len(models[conv, 'branch'].guesses)}", flush=True)
        convention("lapack")
        for index in (int(v) for v in args.frames.split(",")):
            truth = BB._truth(sensor, args.kind, args.seed, index, (h, w), args.cache)
            valid = np.isfinite(truth.xyz_mm).all(axis=2)
            zone = valid & ((truth.label == BF.LABEL_PART) | truth.outliers | truth.off)
            for ci, conv in enumerate(convs):
                trees: list[tuple[str, ModuleType, float | None, int | None]] = [("main", old, None, None)]
                trees += [(label, new, d, k) for label, d, k in settings]
                cpus: dict[str, list[float]] = {t[0]: [] for t in trees}
                fits_of: dict[str, Any] = {}
                for r in range(max(1, args.repeat) if ci == 0 else 1):
                    for label, mod, d, k in (trees if (r + ci) % 2 == 0 else trees[::-1]):
                        if d is not None:
                            vars(P).update(TIE_MARGIN=d, TIE_CANDIDATES=k)
                        model = models[conv, "main" if mod is old else "branch"]
                        convention(conv)
                        c0 = time.process_time()
                        fits = mod.fit_prepared(truth.xyz_mm, zone, model, intrinsics=truth.K, params=mod.FitParams())
                        cpus[label].append(time.process_time() - c0)
                        convention("lapack")
                        fits_of[label] = fits
                for label, mod, _, _ in trees:
                    model = models[conv, "main" if mod is old else "branch"]
                    s = BB.scored(truth, fits_of[label], model, zone, mod, cpus[label], sensor=sensor, frame=index,
                                  seed=args.seed, tree=label, conv=conv)
                    rows.append(s)
                    print(f"{sensor:9s} {index:2d} {conv:6s} {label:9s} {s['found_visible']:4d}/{s['visible']:<4d} "
                          f"{s['matched']:3d}/{s['fully_visible']:<3d} {s['median_mm']:7.3f} {s['median_deg']:7.3f} "
                          f"{s['p90_deg']:7.3f} {s['explained_top']:6.4f} {s['nomatch']:5d} {s['fits']:4d} "
                          f"{s['cpu_s']:6.2f}  {s['load']:.1f}", flush=True)
                if args.json:
                    with open(args.json, "w") as fh:
                        json.dump(rows, fh, indent=1)
    labels = ["main"] + [s[0] for s in settings]
    print("\nper sensor and convention: found, explained (mean), rotation median / p90 °, translation median mm, "
          "nomatch, fits, full matched; CPU-s (sum of medians) under the first convention")
    for sensor in args.sensors.split(","):
        for label in labels:
            for conv in convs:
                m = summary(rows, sensor, label, conv)
                print(f"{sensor:9s} {label:9s} {conv:6s} found {m['found']:4d} explained {m['explained']:.4f} "
                      f"rot {m['med_deg']:.3f} / {m['p90_deg']:.3f} mm {m['med_mm']:.3f} nomatch {m['nomatch']:3d} "
                      f"fits {m['fits']:4d} full {m['full']:3d} cpu {m['cpu']:.2f}")
            ms = [summary(rows, sensor, label, conv) for conv in convs]
            ex = [m["explained"] for m in ms]
            p9 = [m["p90_deg"] for m in ms]
            print(f"{sensor:9s} {label:9s} spread over {len(convs)} conventions: explained {max(ex) - min(ex):.4f}, "
                  f"p90 {max(p9) - min(p9):.3f}°")


if __name__ == "__main__":
    main()
