"""Benchmark: where one call of :func:`zcut.suspects.suspects` spends its CPU, step by step, two trees in one process.

    PYTHONPATH=. .venv/bin/python bench/bench_suspects_steps.py --work W [--against OLD_TREE] [--real DIR]
        [--repeat 5] [--frames GLOB] [--fits]

The frames are the .npy files of ``--work`` (``bench_suspects.py --speed --against`` writes them: the
synthetic 1920 × 1200 frames of several kinds, a ray-traced one, one with large invalid regions) and the
organized PCD scans of ``--real``; the call is the labelling page's (``edge_surface=EdgeSurfaceParams()``,
zone = every valid pixel). With ``--against``, that tree's ``zcut`` is loaded beside this one as the package
``zcut_old`` (its own numba caches) and its calls alternate with this tree's; the results of both are
checked equal field by field (and against :func:`zcut.suspects.suspects_reference` of this tree once per
frame with ``--reference``). ``--fits``: the call is the page's with a part model (``patches=False``: no patch
detector, docs/labelling_real.md), in both trees. The process first takes the settings every ``zcut`` command
takes (:func:`replay.process.configure_process`: numba's threading layer, one malloc arena, the freed memory kept),
as the labelling page's own process does; ``--bare`` leaves glibc's and numba's defaults (what this bench measured
before the round of 2026-12-07f: 7-9 k page faults a call on the hand-made frames).

Each step is a function the call makes from Python (the module globals ``suspects()`` and its helpers
look up are replaced by wrappers while timing): per step, the median over ``--repeat`` calls of its CPU
ms (``time.process_time``: every thread), of its system ms and of its minor page faults
(``getrusage``), the steps nested (a wrapper's time includes the wrapped steps it calls). The line
``whole`` is the call; ``own`` is the whole less the top-level steps.
The last lines sum the whole calls' medians over the synthetic frames but the held-out one (``HELD_OUT``): the six
classes of the suspects' bar (docs/performance.md), with the ratio old / new; and over the ray-traced frames (the
held-out one too), the bar's second sum.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import resource
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

#: (module under the package, attribute [, parent step]) of every step timed; a dotted attribute is a
#: method of a class of that module. The order is the table's.
STEPS = (
    ("suspects.union", "_prepare", None),
    ("suspects.union", "noise_profile", None),
    ("suspects.noise", "_sampled_both", "noise_profile"),
    ("suspects.noise", "stable_argsort", "noise_profile"),
    ("suspects.union", "_sigma_px", None),
    ("suspects.union", "_thresholds", None),
    ("suspects.union", "_sigma_and_tau_medians", None),
    ("suspects.union", "surface_residuals", None),
    ("suspects.union", "fill_blobs", None),
    ("suspects.union", "cut_off_patches", None),  # the patch detector (without a part model; 2026-12-07b)
    ("suspects.union", "_rough", None),
    ("suspects.union", "floating_components", None),
    ("suspects.floating", "_zone_heights", "floating_components"),
    ("suspects.floating", "find_clusters", "floating_components"),
    ("suspects.floating", "cluster_labels_of", "floating_components"),  # its clusters only (2026-12-07d)
    ("suspects.floating", "_evidence_kernel", "floating_components"),
    ("suspects.floating", "_kept_ring", "floating_components"),
    ("suspects.union", "_codes_and_masks", None),
    ("suspects.union", "local_gaps", None),
    ("suspects.union", "_gap_kernel", None),
    ("suspects.union", "_residual_gaps", None),
    ("suspects.union", "_frame_mm", None),
    ("suspects.union", "lazy_surfaces", None),
    ("suspects.surfaces", "reach_median", "lazy_surfaces"),
    ("suspects.surfaces", "_gate_median", "lazy_surfaces"),
    ("suspects.surfaces", "_gate_median_in", "lazy_surfaces"),  # the gate in given arrays (suspects' since 2026-12-06c)
    ("suspects.surfaces", "_ratio_brackets", "_gate_median"),
    ("suspects.surfaces", "_window_exact", "_gate_median"),
    ("suspects.surfaces", "LazySurfaces.distance", None),
    ("suspects.surfaces", "LazySurfaces.distance_at", None),
    ("suspects.union", "_gap_ratio", None),
    ("suspects.union", "group_suspects", None),
    ("suspects.grouping", "strength_classes", "group_suspects"),
    ("suspects.grouping", "_kind_components", "group_suspects"),
    ("suspects.grouping", "_merge_compact", "group_suspects"),
    ("suspects.union", "_group_tables", None),
    ("suspects.union", "label_medians", None),
)


def load_tree(root: Path, name: str):  # type: ignore[no-untyped-def]
    """The package ``zcut`` of tree ``root`` imported as ``name`` (this tree's: ``zcut`` itself)."""
    if name == "zcut":
        return importlib.import_module("zcut")
    spec = importlib.util.spec_from_file_location(name, root / "zcut" / "__init__.py",
                                                  submodule_search_locations=[str(root / "zcut")])
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


class Steps:
    """Wrappers on one tree's steps, accumulating CPU s, system s and minor faults per step and call."""

    def __init__(self, pkg: str) -> None:
        self.acc: dict[str, np.ndarray] = defaultdict(lambda: np.zeros(3))
        self.names: list[str] = []
        for mod_name, attr, _parent in STEPS:
            mod = importlib.import_module(f"{pkg}.{mod_name}")
            owner, key = mod, attr
            if "." in attr:
                cls, key = attr.split(".")
                owner = getattr(mod, cls)
            if not hasattr(owner, key):
                continue  # a step this tree does not have
            fn = getattr(owner, key)
            setattr(owner, key, self._wrap(attr.split(".")[-1], fn))
            self.names.append(attr.split(".")[-1])

    def _wrap(self, name: str, fn):  # type: ignore[no-untyped-def]
        acc = self.acc

        def timed(*a, **k):  # type: ignore[no-untyped-def]
            r0 = resource.getrusage(resource.RUSAGE_SELF)
            c0 = time.process_time()
            try:
                return fn(*a, **k)
            finally:
                c1 = time.process_time()
                r1 = resource.getrusage(resource.RUSAGE_SELF)
                acc[name] += (c1 - c0, r1.ru_stime - r0.ru_stime, r1.ru_minflt - r0.ru_minflt)

        return timed

    def call(self, fn):  # type: ignore[no-untyped-def]
        """One call of ``fn``: (its result, {step: (cpu, sys, faults)} with 'whole')."""
        self.acc.clear()
        r0 = resource.getrusage(resource.RUSAGE_SELF)
        c0 = time.process_time()
        res = fn()
        c1 = time.process_time()
        r1 = resource.getrusage(resource.RUSAGE_SELF)
        out = {k: v.copy() for k, v in self.acc.items()}
        out["whole"] = np.array([c1 - c0, r1.ru_stime - r0.ru_stime, r1.ru_minflt - r0.ru_minflt])
        return res, out


#: Frames of ``--work`` left out of the classes' sum: the held-out ray-traced seed (h/sus15's table sums six classes).
HELD_OUT = ("raytraced_q0_s6",)

FIELDS = ("mask", "groups", "detectors", "gap_mm", "residual_mm", "group_detectors", "group_primary", "group_size",
          "group_gap_mm", "group_bbox", "group_score", "merge_radius_px")


def same(a, b) -> bool:  # type: ignore[no-untyped-def]
    """Every array field, the scalars and the noise profile of two results equal bit for bit (NaN = NaN)."""
    for f in FIELDS:
        x, y = np.asarray(getattr(a, f)), np.asarray(getattr(b, f))
        if x.dtype != y.dtype or x.shape != y.shape:
            return False
        if x.dtype.kind == "f":
            if not np.array_equal(x.view(np.uint64 if x.itemsize == 8 else np.uint32),
                                  y.view(np.uint64 if y.itemsize == 8 else np.uint32)):
                # NaN payloads may differ only where both are NaN
                if not (np.array_equal(x, y, equal_nan=True)
                        and np.array_equal(np.signbit(x), np.signbit(y))):
                    return False
        elif not np.array_equal(x, y):
            return False
    for f in ("noise_mm", "threshold_mm", "floating_step_mm"):
        if not np.array_equal(np.float64(getattr(a, f)), np.float64(getattr(b, f)), equal_nan=True):
            return False
    pa, pb = a.noise_profile, b.noise_profile
    return all(np.array_equal(getattr(pa, f), getattr(pb, f), equal_nan=True)
               for f in ("heights_mm", "sigma_mm", "step_mm"))


def _released(res):  # type: ignore[no-untyped-def]
    """``res`` after handing its frame in mm back (:meth:`zcut.suspects.union.SuspectResult.release`), as the labelling page
    does; a tree before 2026-12-06f has no ``release`` (it reused the frame once nothing held the result)."""
    release = getattr(res, "release", None)
    if release is not None:
        release()
    return res


def frames(work: Path, pattern: str, real: Path | None):  # type: ignore[no-untyped-def]
    from replay.logs.pcd import read_pcd

    for f in sorted(work.glob(pattern)):
        yield f.stem, np.load(f)
    if real is not None:
        for f in sorted(real.glob("*.pcd")):
            yield f.stem[:28], read_pcd(f).xyz


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=Path("/tmp/zcut_bench_suspects"))
    ap.add_argument("--frames", default="speed_*.npy", help="glob of the .npy frames in --work")
    ap.add_argument("--real", type=Path)
    ap.add_argument("--against", type=Path, help="another tree, loaded beside this one as zcut_old")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--reference", action="store_true", help="also check this tree against suspects_reference")
    ap.add_argument("--steps", action="store_true", help="print every step (default: the whole call only)")
    ap.add_argument("--fits", action="store_true",
                    help="call as the page does with a part model: patches=False (no patch detector)")
    ap.add_argument("--bare", action="store_true",
                    help="without the process settings of every zcut command (replay.process.configure_process)")
    args = ap.parse_args()
    if not args.bare:
        from replay.process import configure_process

        configure_process()  # as `zcut annotate`'s process (cli.main): before numba and the threads start
    kw = {"patches": False} if args.fits else {}

    trees = [("new", load_tree(Path(__file__).resolve().parents[1], "zcut"))]
    if args.against is not None:
        trees.insert(0, ("old", load_tree(args.against.resolve(), "zcut_old")))
    steps = {tag: Steps(pkg.__name__) for tag, pkg in trees}
    wholes: dict[str, dict[str, float]] = {}  # label -> tree -> the whole call's median CPU s
    print(f"CPU ms per call{' (patches=False: the page with a part model)' if args.fits else ''} "
          f"(median of {args.repeat}, the trees alternating in one process); "
          f"sys ms and minor page faults (k) beside; load average {' '.join(f'{v:.1f}' for v in __import__('os').getloadavg())}")
    for label, xyz in frames(args.work, args.frames, args.real):
        h = -1000.0 * xyz[..., 2].astype(np.float64)
        zone = np.isfinite(xyz).all(axis=2)
        calls = {}
        for tag, pkg in trees:
            sp = importlib.import_module(f"{pkg.__name__}.params").SuspectParams()
            es = importlib.import_module(f"{pkg.__name__}.edge_surface").EdgeSurfaceParams()
            fn = importlib.import_module(f"{pkg.__name__}.suspects").suspects
            calls[tag] = (lambda fn=fn, sp=sp, es=es, xyz=xyz, h=h, zone=zone:
                          _released(fn(xyz, h, zone, params=sp, edge_surface=es, **kw)))
        results = {tag: calls[tag]() for tag, _ in trees}  # warm-up (numba's caches), and the check
        if args.against is not None and not same(results["old"], results["new"]):
            raise SystemExit(f"{label}: the two trees' results differ")
        if args.reference:
            here = trees[-1][1].__name__
            ref = importlib.import_module(f"{here}.suspects").suspects_reference(
                xyz, h, zone, params=importlib.import_module(f"{here}.params").SuspectParams(),
                edge_surface=importlib.import_module(f"{here}.edge_surface").EdgeSurfaceParams(), **kw)
            if not same(ref, results["new"]):
                raise SystemExit(f"{label}: this tree's result differs from suspects_reference")
        del results
        got: dict[str, list[dict[str, np.ndarray]]] = {tag: [] for tag, _ in trees}
        for _ in range(args.repeat):
            for tag, _ in trees:
                got[tag].append(steps[tag].call(calls[tag])[1])

        def med(tag: str, name: str, got: dict = got) -> np.ndarray:
            return np.median([g.get(name, np.full(3, np.nan)) for g in got[tag]], axis=0)

        tags = [t for t, _ in trees]
        wholes[label] = {t: float(med(t, "whole")[0]) for t in tags}
        print(f"{label}  ({xyz.shape[1]}x{xyz.shape[0]}, {int(zone.sum())} valid)")
        names = ["whole"]
        if args.steps:
            names += list(dict.fromkeys(n for t in tags for n in steps[t].names))
        for name in names:
            parent = next((p for _, a, p in STEPS if a.split(".")[-1] == name), None)
            cells = []
            for t in tags:
                c, s, f = med(t, name)
                cells.append(f"{1000 * c:7.1f} {1000 * s:5.1f} {f / 1000:6.1f}k")
            ratio = ""
            if len(tags) == 2:
                o, n = med("old", name)[0], med("new", name)[0]
                ratio = f"{o / n:6.2f}" if n > 0 else ""
            print(f"  {('  ' if parent else '') + name:26s} " + " | ".join(cells) + f" {ratio}")
        if args.steps:
            for t in tags:
                tops = [n for _, a, p in STEPS if p is None for n in [a.split(".")[-1]]]
                own = [g["whole"][0] - sum(g.get(n, np.zeros(3))[0] for n in tops) for g in got[t]]
                print(f"  own ({t}): {1000 * float(np.median(own)):.1f}")
        sys.stdout.flush()
    summed = [lab for lab in wholes if lab.startswith("speed_") and not any(h in lab for h in HELD_OUT)]
    if summed:
        sums = {t: sum(wholes[lab][t] for lab in summed) for t in wholes[summed[0]]}
        line = " -> ".join(f"{1000 * v:,.1f}" for v in sums.values())
        ratio = f", ratio {sums['old'] / sums['new']:.3f}" if len(sums) == 2 else ""
        print(f"sum of the whole calls over {len(summed)} classes (CPU ms, old -> new): {line}{ratio}; "
              f"load average {' '.join(f'{v:.1f}' for v in __import__('os').getloadavg())}")
    traced = [lab for lab in wholes if lab.startswith("speed_") and "raytraced" in lab]
    if traced:  # the lead's second sum (round 2026-12-07f): the ray-traced frames, the held-out one too
        sums = {t: sum(wholes[lab][t] for lab in traced) for t in wholes[traced[0]]}
        line = " -> ".join(f"{1000 * v:,.1f}" for v in sums.values())
        ratio = f", ratio {sums['old'] / sums['new']:.3f}" if len(sums) == 2 else ""
        print(f"sum of the whole calls over the {len(traced)} ray-traced frames (CPU ms, old -> new): {line}{ratio}; "
              f"load average {' '.join(f'{v:.1f}' for v in __import__('os').getloadavg())}")


if __name__ == "__main__":
    main()
