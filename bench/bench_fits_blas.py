"""The fits with their own linear algebra against an older tree's, on the same frames in one process (issue 29, the
fits' bytes the same under every OpenBLAS kernel: docs/fits.md).

    PYTHONPATH=. .venv/bin/python bench/bench_fits_blas.py --old /tmp/old [--seed 7751] [--frames 0,1,2] \\
        [--sensors handmade,raytraced] [--kind zinc_nuts] [--size 1920x1200] [--repeat 3] [--cache DIR] [--json OUT]

``--old``: a ``git archive`` of the older tree; its ``zcut/fits`` package is copied to a temporary folder and
imported under another name (its absolute imports — ``zcut.errors``, ``zcut.fit_vetting``, ... — are this tree's:
only ``zcut/fits`` differs between the two). Per frame (the generators of bench/bench_fits.py at the seed and frame
index of a ``zcut synth --seed S --frames N`` log, its zone the oracle one of bench/bench_fits.py) each tree's model
prepared by its own ``prepare_model`` fits the frame ``--repeat`` times, the trees alternating (old first on even
repeats, new first on odd), and bench/bench_fits.py's ``score`` scores the fits: instances of >= 40 visible px found,
fully visible instances matched, their pose error (median, p90), the explained share of the top layer, the fits on no
instance (``nomatch``), the CPU-s of ``fit_prepared`` (``time.process_time``, the median of the repeats).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_fits as BF  # noqa: E402


def _load_old(tree: Path, where: Path) -> ModuleType:
    """The older tree's ``zcut/fits`` as the package ``zcut_fits_old``, copied to ``where`` when not there yet (a kept
    copy keeps numba's cache of its kernels; bench/bench_fits_ties.py, bench/bench_fits_signs.py call it too)."""
    dst = where / "zcut_fits_old"
    if not dst.is_dir():
        shutil.copytree(tree / "zcut" / "fits", dst, ignore=shutil.ignore_patterns("__pycache__"))
    spec = importlib.util.spec_from_file_location("zcut_fits_old", dst / "__init__.py",
                                                  submodule_search_locations=[str(dst)])
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["zcut_fits_old"] = mod
    spec.loader.exec_module(mod)
    return mod


def scored(truth: BF.Truth, fits: Any, model: Any, zone: np.ndarray, mod: ModuleType, cpus: list[float],
           **fields: Any) -> dict[str, Any]:
    """One tree's fits of a frame scored by bench/bench_fits.py's ``score`` with that tree's own ``pose_error`` (``mod``,
    its ``zcut.fits``: its model's symmetries), with ``fields``, the median and every CPU-s of its runs and the load average."""
    BF.pose_error = mod.pose_error
    s = BF.score(truth, fits, model, zone, with_proposals=False)
    s.update(fields, cpu_s=float(np.median(cpus)), cpu_all=cpus, load=os.getloadavg()[0])
    return s


def _truth(sensor: str, kind: str, seed: int, index: int, size: tuple[int, int], cache: str | None) -> BF.Truth:
    """bench/bench_fits.py's scene of the frame ``index`` of the seed (cached in ``cache``)."""
    import pickle

    path = None if cache is None else os.path.join(cache, f"{sensor}_{kind}_{seed}_{index}_{size[1]}x{size[0]}.pkl")
    if path is not None and os.path.exists(path):
        with open(path, "rb") as fh:
            return BF.Truth(**pickle.load(fh))
    import replay.synth as S
    import replay.synth.raytrace as RT

    orig = (S.synthesize_frame, RT.synthesize_raytraced_frame)
    S.synthesize_frame = lambda **kw: orig[0](index=index, **kw)  # type: ignore[assignment]
    RT.synthesize_raytraced_frame = lambda **kw: orig[1](index=index, **kw)  # type: ignore[assignment]
    try:
        truth = BF.handmade(kind, seed, size) if sensor == "handmade" else BF.raytraced(kind, seed, size)
    finally:
        S.synthesize_frame, RT.synthesize_raytraced_frame = orig  # type: ignore[assignment]
    if path is not None:
        os.makedirs(cache, exist_ok=True)  # type: ignore[arg-type]
        with open(path, "wb") as fh:
            pickle.dump(vars(truth), fh)
    return truth


KEYS = ("found_visible", "visible", "matched", "fully_visible", "median_mm", "p90_mm", "median_deg", "p90_deg",
        "explained_top", "nomatch", "fits")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", type=Path, required=True, help="a git archive of the older tree")
    ap.add_argument("--seed", type=int, default=7751)
    ap.add_argument("--frames", default="0,1,2")
    ap.add_argument("--sensors", default="handmade,raytraced")
    ap.add_argument("--kind", default="zinc_nuts")
    ap.add_argument("--size", default="1920x1200")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--cache", default=None, metavar="DIR", help="keep the synthesized frames in DIR")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    from replay.process import configure_process

    configure_process()  # the process settings of every zcut command, the page's fits' process (bench_fits.py's default)
    if not (args.old / "zcut" / "fits" / "__init__.py").is_file():
        raise SystemExit(f"--old {args.old}: no zcut/fits/__init__.py there (a git archive of a zcut tree?)")
    import zcut.fits as new
    from replay.logs.part_model import PART_MODEL_ATTACHMENT, read_part_model_bytes
    from replay.synth.log import part_model_attachment

    w, h = (int(v) for v in args.size.split("x"))
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        old = _load_old(args.old, Path(tmp))
        trees = {"old": old, "new": new}
        print(f"{'sensor':9s} {'fr':>2s} {'tree':4s} {'found':>9s} {'full':>7s} {'med mm':>7s} {'p90 mm':>7s} "
              f"{'med deg':>7s} {'p90 deg':>7s} {'expl':>6s} {'nomat':>5s} {'fits':>4s} {'cpu s':>6s}  load",
              flush=True)
        for sensor in args.sensors.split(","):
            data = part_model_attachment(args.kind, raytraced=sensor == "raytraced")[PART_MODEL_ATTACHMENT][1]
            pm = read_part_model_bytes(data)
            scale = 1000.0 if pm.unit == "m" else 1.0
            models = {}
            for name, mod in trees.items():
                c0 = time.process_time()
                models[name] = mod.prepare_model(pm.vertices * scale, pm.triangles,
                                                 sphere_tolerance=mod.FitParams().sphere_tolerance)
                print(f"{sensor} {name}: prepare_model {time.process_time() - c0:.2f} CPU-s", flush=True)
            for index in (int(v) for v in args.frames.split(",")):
                truth = _truth(sensor, args.kind, args.seed, index, (h, w), args.cache)
                valid = np.isfinite(truth.xyz_mm).all(axis=2)
                zone = valid & ((truth.label == BF.LABEL_PART) | truth.outliers | truth.off)
                cpus: dict[str, list[float]] = {"old": [], "new": []}
                fits_of: dict[str, Any] = {}
                for r in range(max(1, args.repeat)):
                    for name in (("old", "new") if r % 2 == 0 else ("new", "old")):
                        mod = trees[name]
                        c0 = time.process_time()
                        fits = mod.fit_prepared(truth.xyz_mm, zone, models[name], intrinsics=truth.K,
                                                params=mod.FitParams())
                        cpus[name].append(time.process_time() - c0)
                        fits_of[name] = fits
                for name in ("old", "new"):
                    # each tree's fits scored with its own model (its symmetries: the same group up to last bits)
                    s = scored(truth, fits_of[name], models[name], zone, trees[name], cpus[name], sensor=sensor,
                               frame=index, seed=args.seed, tree=name)
                    rows.append(s)
                    print(f"{sensor:9s} {index:2d} {name:4s} {s['found_visible']:4d}/{s['visible']:<4d} "
                          f"{s['matched']:3d}/{s['fully_visible']:<3d} {s['median_mm']:7.3f} {s['p90_mm']:7.3f} "
                          f"{s['median_deg']:7.3f} {s['p90_deg']:7.3f} {s['explained_top']:6.4f} {s['nomatch']:5d} "
                          f"{s['fits']:4d} {s['cpu_s']:6.2f}  {s['load']:.1f}", flush=True)
                if args.json:
                    with open(args.json, "w") as fh:
                        json.dump(rows, fh, indent=1)
    by = {(r["sensor"], r["frame"], r["tree"]): r for r in rows}
    print("\nper sensor, summed over the frames (pose errors: medians of the frames' values); CPU new / old")
    for sensor in args.sensors.split(","):
        for name in ("old", "new"):
            rs = [r for r in rows if r["sensor"] == sensor and r["tree"] == name]
            print(f"{sensor:9s} {name:4s} found {sum(r['found_visible'] for r in rs)}/{sum(r['visible'] for r in rs)}"
                  f", full matched {sum(r['matched'] for r in rs)}/{sum(r['fully_visible'] for r in rs)}, med mm "
                  f"{np.median([r['median_mm'] for r in rs]):.3f}, p90 mm {np.median([r['p90_mm'] for r in rs]):.3f}"
                  f", med deg {np.median([r['median_deg'] for r in rs]):.3f}, p90 deg "
                  f"{np.median([r['p90_deg'] for r in rs]):.3f}, explained {np.mean([r['explained_top'] for r in rs]):.4f}"
                  f", nomatch {sum(r['nomatch'] for r in rs)}, fits {sum(r['fits'] for r in rs)}, CPU "
                  f"{sum(r['cpu_s'] for r in rs):.2f} s")
        ratios = [by[sensor, f, "new"]["cpu_s"] / by[sensor, f, "old"]["cpu_s"]
                  for f in sorted({r["frame"] for r in rows if r["sensor"] == sensor})]
        print(f"{sensor:9s} CPU new / old per frame: " + ", ".join(f"{x:.3f}" for x in ratios))


if __name__ == "__main__":
    main()
