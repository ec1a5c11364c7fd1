"""Benchmark: the suspects (``zcut.suspects``) against the synthetic truth, and what they propose on real scans.

    .venv/bin/python bench/bench_suspects.py [--work DIR] [--kinds zinc_nuts,...] [--frames 3]
        [--tune-seeds 1] [--report-seeds 2,3] [--tune] [--real DIR] [--png DIR]
    .venv/bin/python bench/bench_suspects.py --speed [--sizes 1920x1200,960x600] [--real DIR] [--repeat 3]
        [--against OLD_TREE [--fits]] [--rounds 2]

1. Synthetic logs (``zcut synth``, 1920 × 1200) of each part kind and seed, and a bin model built from
   an empty-bin series (``zcut synth --empty``, ``zcut bin-model``), in ``--work`` (reused when
   present; the zones the bin stages leave are cached there too). Every frame goes through the
   pipeline's bin stages (``ReplaySession.zones``: bin mask, ICP registration, removal) and then
   :func:`zcut.suspects.suspects` with ``SuspectParams(a_max=<the resolved config's a_max>)``.
2. Scoring, in the default scored region of ``zcut accuracy`` (the zone plus the points above the
   rim, ``annotate.truth.scored_region``): recall of the suspects mask against
   ``/ground_truth/outliers``, the flagged ratio (suspect pixels / true pixels; target ≤ 5 with
   recall ≥ 0.95), recall per outlier kind (``/ground_truth/outlier_kind``), groups per frame
   (target ≤ ~40) and the CPU time of ``suspects`` per frame against the pipeline's nominal z-cut
   on the same zone (``find_clusters``, measured in the same run).
3. ``--tune``: a grid of parameter variants on the tuning seeds (the defaults were chosen this way,
   on seed 1); the report seeds are held out. Per kind, totals over frames.
4. ``--real DIR``: organized PCD scans (e.g. the Kinect scans of the real data folder, docs/real_data.md) recorded
   into a log (``zcut record``) and replayed without bin stages (zone = every valid pixel): per frame,
   σ̂, τ, the pixels each detector proposes and the groups. ``--png DIR`` writes overlays of the
   groups (outside the repository) to look at.
5. ``--speed``: CPU ms per frame of each part of :func:`zcut.suspects.suspects` as the labelling
   page calls it (``edge_surface=EdgeSurfaceParams()``), the previous code
   (:func:`zcut.suspects.suspects_reference`) against the fast path in the same run, and their
   ratio: hand-made synthetic frames of several kinds (one quantized), a ray-traced frame, at each
   ``--sizes``, and the real scans of ``--real``; zone = every valid pixel (no bin stages: the
   most pixels to judge). Whole calls: the median of ``--repeat`` calls' CPU time; parts: the CPU
   time cProfile gives each part's function in one more call. Each frame's two results are checked
   equal field by field first.
6. ``--speed --against OLD_TREE [--fits]`` (e.g. ``git archive <commit> | tar -x -C /tmp/sus_old``): instead,
   the whole call of the fast path of that tree against this one's, each in its own process (the
   same frames, written once to ``--work`` as .npy), alternating ``--rounds`` times; per frame the
   median CPU ms of ``--repeat`` calls of each round, and whether the two trees' results are equal
   (mask, groups, detectors, gaps, residuals, group scores). Besides the frames of ``--speed``, one
   with large invalid regions (the zinc-nut frame, its top half and a third of the rest unmeasured).
   ``--fits``: both trees call it as the labelling page does with a part model (``patches=False``, in a tree that
   has the option; an older tree runs every detector, as its page did); printed beside the times: the suspect
   pixels, the patch detector's pixels, the groups grouped by ``patch`` and all groups, old / new.
   Every worker, and this process with ``--speed`` alone or ``--parts``, runs in the process settings of every
   ``zcut`` command (:func:`replay.process.configure_process`, as the labelling page's process); ``--bare`` leaves
   glibc's and numba's defaults (what this bench measured before 2026-12-07g: 7–13 % more CPU a call).
7. ``--speed --against OLD_TREE --parts``: the parts the fifth round changed (docs/performance.md,
   "Suspects ... fifth round"), ``OLD_TREE``'s code loaded beside this tree's in one process,
   alternating, outputs checked equal, on the .npy frames of ``--work`` (made by 6) and the scans of
   ``--real``.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
from timing import WORKER_SETTINGS, worker_env

from zcut.cuts import find_clusters
from zcut.params import SuspectParams, ZCutParams
from zcut.suspects import DETECTORS, suspects

KINDS = ("zinc_nuts", "spheres", "rods", "black_nuts", "black_screws", "sprockets")
SIZE = (1200, 1920)
OUTLIER_CODES = {1: "floating", 2: "spike_up", 3: "spike_down", 4: "flying", 5: "above_rim"}

#: --tune: variants of the defaults (name, changes)
VARIANTS = (
    ("defaults", {}),
    ("min_residual 0.4", {"min_residual_mm": 0.4}),
    ("min_residual 0.7", {"min_residual_mm": 0.7}),
    ("noise_k 8", {"noise_k": 8.0}),
    ("jump 1", {"jump_mm": 1.0}),
    ("jump 3", {"jump_mm": 3.0}),
    ("below dirs 4", {"below_min_directions": 4}),
    ("below dirs 6", {"below_min_directions": 6}),
    ("no fill", {"fill_iterations": 0}),
    ("floating rho 0.1", {"floating_rho": 0.1}),
    ("floating rho 0.2", {"floating_rho": 0.2}),
    ("no evidence (plain = floating rho)", {"plain_rho": 0.15}),
    ("plain rho 0.05", {"plain_rho": 0.05}),
    ("ring valid 0.25", {"evidence_ring_valid": 0.25}),
    ("ring valid 0.5", {"evidence_ring_valid": 0.5}),
    ("holes 0.08", {"evidence_holes": 0.08}),
)


# --------------------------------------------------------------------------------------------
# Inputs
# --------------------------------------------------------------------------------------------


def prepare(work: Path, kinds, seeds, frames: int) -> tuple[dict, Path]:
    """Synthetic logs {(kind, seed): path} and the bin model, made when missing."""
    from replay.logs.reader import LogReader
    from replay.pipeline.bin_model import build_bin_model, save_bin_model
    from replay.synth.log import write_synthetic_log

    work.mkdir(parents=True, exist_ok=True)
    ply = work / "bin.ply"
    if not ply.exists():
        empty = work / "empty.mcap"
        if not empty.exists():
            print(f"making {empty}", flush=True)
            write_synthetic_log(empty, empty=True, frames=5, seed=0, size=SIZE)
        model, _ = build_bin_model(LogReader(empty).frames())
        save_bin_model(model, ply)
    logs = {}
    for kind in kinds:
        for seed in seeds:
            p = work / f"{kind}_s{seed}_f{frames}.mcap"
            if not p.exists():
                print(f"making {p.name}", flush=True)
                write_synthetic_log(p, kind=kind, frames=frames, seed=seed, size=SIZE)
            logs[(kind, seed)] = p
    return logs, ply


def zones(log: Path, ply: Path, cache: Path):
    """``(frame, zone, easy, height_mm, a_max)`` of every frame, the bin stages cached in ``cache``."""
    from replay.logs.reader import LogReader
    from replay.pipeline.bin_model import load_bin_model
    from replay.pipeline.session import ReplaySession

    files = sorted(cache.glob(f"{log.stem}.*.npz"))
    if files:
        frames = {f.index: f for f in LogReader(log).frames()}
        for f in files:
            d = np.load(f)
            yield frames[int(d["index"])], d["zone"], d["easy"], d["height"], float(d["a_max"])
        return
    cache.mkdir(parents=True, exist_ok=True)
    session = ReplaySession.open(log, bin_model=load_bin_model(ply))
    a_max = session.config.zcut.a_max
    for frame, z in session.zones():
        if z.warnings:
            print(f"  {log.name} frame {frame.index}: {'; '.join(z.warnings)}")
        np.savez_compressed(cache / f"{log.stem}.{frame.index:04d}.npz", index=frame.index, zone=z.zone,
                            easy=z.easy, height=z.height_mm, a_max=a_max)
        yield frame, z.zone, z.easy, z.height_mm, a_max


# --------------------------------------------------------------------------------------------
# Scoring
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass
class Tally:
    frames: int = 0
    truth: int = 0
    flagged: int = 0
    found: int = 0
    by_kind_truth: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(6, np.int64))
    by_kind_found: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(6, np.int64))
    groups: list = dataclasses.field(default_factory=list)
    cpu: float = 0.0
    cpu_zcut: float = 0.0
    frame_recall: list = dataclasses.field(default_factory=list)
    frame_ratio: list = dataclasses.field(default_factory=list)

    def add(self, res, truth, kind, region) -> None:
        t = truth & region
        m = res.mask & region
        self.frames += 1
        self.truth += int(t.sum())
        self.flagged += int(m.sum())
        self.found += int((m & t).sum())
        kc = np.where(t, kind, 0)
        self.by_kind_truth += np.bincount(kc[t], minlength=6)[:6]
        self.by_kind_found += np.bincount(kc[t & m], minlength=6)[:6]
        self.groups.append(res.n_groups)
        if t.sum():
            self.frame_recall.append((m & t).sum() / t.sum())
            self.frame_ratio.append(m.sum() / t.sum())

    @property
    def recall(self) -> float:
        return self.found / self.truth if self.truth else float("nan")

    @property
    def ratio(self) -> float:
        return self.flagged / self.truth if self.truth else float("nan")


def score_logs(logs, ply: Path, cache: Path, variants) -> dict:
    """{variant name: {kind: Tally}} over the given logs."""
    from replay.logs import layout

    out = {name: {} for name, _ in variants}
    for (kind, _seed), log in logs.items():
        for frame, zone, easy, height, a_max in zones(log, ply, cache):
            truth = frame.masks[layout.TRUTH_OUTLIERS]
            kcode = frame.codes[layout.TRUTH_OUTLIER_KIND]
            region = zone | easy
            c0 = time.process_time()
            find_clusters(np.where(zone, height, np.nan), params=ZCutParams.nominal(a_max=a_max))
            t_zcut = time.process_time() - c0
            for name, changes in variants:
                params = dataclasses.replace(SuspectParams(a_max=a_max), **changes)
                c0 = time.process_time()
                res = suspects(frame.xyz, height, zone, easy, params=params, intrinsics=frame.intrinsics)
                cpu = time.process_time() - c0
                t = out[name].setdefault(kind, Tally())
                t.add(res, truth & np.isfinite(frame.xyz).all(axis=2), kcode, region)
                t.cpu += cpu
                t.cpu_zcut += t_zcut
            print(f"  {log.name} frame {frame.index} scored", flush=True)
    return out


def print_table(title: str, tallies: dict) -> None:
    print(title)
    print(f"{'kind':13s} {'frames':>6s} {'true/fr':>8s} {'flag/fr':>8s} {'ratio':>6s} {'recall':>6s} "
          f"{'worst fr (rec/ratio)':>21s} " + " ".join(f"{n:>11s}" for n in OUTLIER_CODES.values())
          + f" {'groups mean/max':>15s} {'cpu s/fr':>8s} {'x zcut':>6s}")
    for kind, t in tallies.items():
        cells = []
        for c in OUTLIER_CODES:
            n = t.by_kind_truth[c]
            cells.append(f"{t.by_kind_found[c] / n:.3f}/{n / t.frames:5.0f}" if n else f"{'-':>11s}")
        worst = f"{min(t.frame_recall):.3f}/{max(t.frame_ratio):5.2f}" if t.frame_recall else "-"
        print(f"{kind:13s} {t.frames:6d} {t.truth / t.frames:8.0f} {t.flagged / t.frames:8.0f} {t.ratio:6.2f} "
              f"{t.recall:6.3f} {worst:>21s} " + " ".join(f"{c:>11s}" for c in cells)
              + f" {np.mean(t.groups):9.1f}/{max(t.groups):3d} {t.cpu / t.frames:8.2f} "
                f"{t.cpu / max(t.cpu_zcut, 1e-9):6.1f}")
    tot = Tally()
    for t in tallies.values():
        tot.truth += t.truth
        tot.flagged += t.flagged
        tot.found += t.found
    ok = all(t.recall >= 0.95 and t.ratio <= 5 for t in tallies.values())
    print(f"all kinds pooled: recall {tot.recall:.3f}, ratio {tot.ratio:.2f}; every kind recall >= 0.95 "
          f"and ratio <= 5: {'yes' if ok else 'NO'}")
    print("(per outlier kind: recall/true pixels per frame)")


# --------------------------------------------------------------------------------------------
# Real scans
# --------------------------------------------------------------------------------------------


def overlay(frame, res, path: Path) -> None:
    """A PNG: the height image in grey, each group's pixels in a colour per detector, its box and label."""
    import cv2

    h = -1000.0 * frame.xyz[..., 2].astype(np.float64)
    fin = np.isfinite(h)
    img = np.zeros((*h.shape, 3), np.uint8)
    if fin.any():
        lo, hi = np.percentile(h[fin], [1, 99])
        g = np.clip((h - lo) / max(hi - lo, 1e-9) * 200 + 40, 0, 255)
        img[fin] = g[fin, None].astype(np.uint8)
    colours = {"above_rim": (255, 0, 255), "floating": (0, 0, 255), "mixed": (0, 255, 255),
               "residual_down": (255, 128, 0), "residual_up": (0, 200, 0)}  # BGR
    scale = max(1, 1280 // h.shape[1])
    big = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    for g in range(1, res.n_groups + 1):
        grp = res.group(g)
        sel = np.repeat(np.repeat(res.groups == g, scale, 0), scale, 1)
        big[sel] = colours[grp.detectors[0]]
        r0, c0, r1, c1 = grp.bbox
        cv2.rectangle(big, (c0 * scale, r0 * scale), (c1 * scale, r1 * scale), colours[grp.detectors[0]], 1)
        cv2.putText(big, str(g), (c0 * scale, max(r0 * scale - 2, 10)), cv2.FONT_HERSHEY_SIMPLEX, 0.4,
                    (255, 255, 255), 1)
    cv2.imwrite(str(path), big)


def record_real(src: Path, work: Path) -> Path:
    """``zcut record`` of every PCD in ``src`` into one log in ``work``."""
    import subprocess
    import sys

    out = work / "real_scans.mcap"
    if not out.exists():
        pcds = sorted(str(p) for p in src.glob("*.pcd"))
        subprocess.run([sys.executable, "-m", "cli", "record", *pcds, "-o", str(out)], check=True)
    return out


def run_real(src: Path, work: Path, png: Path | None) -> None:
    from replay.logs.reader import LogReader

    log = record_real(src, work)
    print(f"real scans ({log.name}, from {src}): no truth; zone = every valid pixel (no bin stages)")
    print(f"{'frame':>5s} {'size':>9s} {'valid':>7s} {'sigma mm':>8s} {'tau mm':>6s} "
          + " ".join(f"{d:>13s}" for d in DETECTORS) + f" {'suspects':>8s} {'%valid':>6s} {'groups':>6s} {'cpu s':>6s}")
    if png is not None:
        png.mkdir(parents=True, exist_ok=True)
    for frame in LogReader(log).frames():
        xyz = frame.xyz
        valid = np.isfinite(xyz).all(axis=2)
        height = -1000.0 * xyz[..., 2].astype(np.float64)
        c0 = time.process_time()
        res = suspects(xyz, height, valid, params=SuspectParams(), intrinsics=frame.intrinsics)
        cpu = time.process_time() - c0
        counts = [int((res.detectors >> i & 1).astype(bool).sum()) for i in range(len(DETECTORS))]
        n = int(res.mask.sum())
        print(f"{frame.index:5d} {xyz.shape[1]:4d}x{xyz.shape[0]:<4d} {int(valid.sum()):7d} {res.noise_mm:8.2f} "
              f"{res.threshold_mm:6.2f} " + " ".join(f"{c:13d}" for c in counts)
              + f" {n:8d} {100 * n / max(valid.sum(), 1):6.2f} {res.n_groups:6d} {cpu:6.2f}")
        if png is not None:
            overlay(frame, res, png / f"real_{frame.index:02d}.png")
            with open(png / f"real_{frame.index:02d}.txt", "w") as f:
                for g in range(1, res.n_groups + 1):
                    f.write(f"{res.group(g)}\n")



# --------------------------------------------------------------------------------------------
# Speed: the previous code against the fast path, per part (issue 32)
# --------------------------------------------------------------------------------------------

#: (part, the fast path's functions, the previous code's): CPU time of a part = the sum of its functions'
#: cumulative times in one profiled call
PARTS = (
    ("noise", ("noise_profile", "local_height"), ("noise_profile_reference", "local_height_reference")),
    ("residuals", ("surface_residuals", "fill_blobs"), ("surface_residuals", "fill_blobs")),
    ("floating", ("floating_components",), ("floating_components_reference",)),
    ("gaps", ("local_gaps",), ("local_gaps",)),
    ("edge surface", ("_edge_surfaces", "edge_surfaces", "distance"), ("_signed_edge_distance_reference",)),
    ("grouping", ("group_suspects",), ("group_suspects_reference",)),
)
#: the frames of --speed: (name, kind, sensor, quantize_mm, seed)
SPEED_FRAMES = (("zinc_nuts", "zinc_nuts", "handmade", 0.0, 1), ("black_nuts", "black_nuts", "handmade", 0.0, 2),
                ("spheres q1mm", "spheres", "handmade", 1.0, 3), ("sprockets", "sprockets", "handmade", 0.0, 4),
                ("zinc_nuts ray-traced", "zinc_nuts", "raytraced", 0.0, 5))


def with_raytraced_seeds(seeds: str) -> None:
    """--raytraced-seeds: the ray-traced zinc-nut frame of each seed (comma-separated) in SPEED_FRAMES, in place
    of seed 5's (a seed the defaults do not use, to report on; written to --work as the others)."""
    global SPEED_FRAMES
    rt = tuple(("zinc_nuts ray-traced" + ("" if int(s) == 5 else f" s{int(s)}"), "zinc_nuts", "raytraced", 0.0, int(s))
               for s in seeds.split(","))
    SPEED_FRAMES = tuple(f for f in SPEED_FRAMES if f[2] != "raytraced") + rt


def speed_frame(work: Path, name: str, kind: str, sensor: str, quantize: float, seed: int, size: tuple[int, int]):
    """(xyz, height_mm) of one frame of a synthetic log made once in ``work``."""
    from replay.logs.reader import LogReader

    log = work / f"speed_{kind}_{sensor}_q{quantize:g}_s{seed}_{size[1]}x{size[0]}.mcap"
    if not log.exists():
        print(f"making {log.name}", flush=True)
        if sensor == "raytraced":
            from replay.synth.raytrace import write_raytraced_log
            write_raytraced_log(log, kind=kind, frames=1, seed=seed, size=size)
        else:
            from replay.synth.log import write_synthetic_log
            write_synthetic_log(log, kind=kind, frames=1, seed=seed, size=size, quantize_mm=quantize)
    frame = next(iter(LogReader(log).frames()))
    return frame.xyz, -1000.0 * frame.xyz[..., 2].astype(np.float64)


def _parts_cpu(fn, names_per_part) -> list[float]:
    """CPU seconds of each part (sum of its functions' cumulative times) in one profiled call of fn."""
    import cProfile
    import pstats

    prof = cProfile.Profile(time.process_time)
    prof.runcall(fn)
    stats = pstats.Stats(prof).stats  # type: ignore[attr-defined]
    out = []
    for names in names_per_part:
        out.append(sum(v[3] for (path, _line, func), v in stats.items()
                       if func in names and ("zcut" in path or "edge_surface" in path)))
    return out


def time_frame(label: str, xyz: np.ndarray, height: np.ndarray, repeat: int) -> tuple[float, float]:
    """Print one frame's row of parts, old / new / ratio; return the whole calls' CPU ms (old, new)."""
    from zcut.edge_surface import EdgeSurfaceParams
    from zcut.suspects import suspects_reference

    zone = np.isfinite(xyz).all(axis=2)
    params = SuspectParams()  # a_max: 1 % of the frame
    es = EdgeSurfaceParams()

    def new():
        res = suspects(xyz, height, zone, params=params, edge_surface=es)
        res.release()  # the frame in mm handed back for the next call, as the labelling page does
        return res

    def old():
        return suspects_reference(xyz, height, zone, params=params, edge_surface=es)

    a, b = new(), old()  # warm-up (numba's cache), and the check
    for f in ("mask", "groups", "detectors", "gap_mm", "residual_mm", "group_score", "group_bbox", "group_gap_mm"):
        if not np.array_equal(getattr(a, f), getattr(b, f), equal_nan=True):
            raise SystemExit(f"{label}: the fast path's {f} differs from the previous code's")
    whole = []
    for fn in (old, new):
        cpu = []
        for _ in range(repeat):
            c0 = time.process_time()
            fn()
            cpu.append(time.process_time() - c0)
        whole.append(1000.0 * float(np.median(cpu)))
    p_old = _parts_cpu(old, [p[2] for p in PARTS])
    p_new = _parts_cpu(new, [p[1] for p in PARTS])
    cells = " ".join(f"{1000 * o:6.0f}/{1000 * n:4.0f} {o / max(n, 1e-9):4.1f}x" for o, n in zip(p_old, p_new))
    print(f"{label:34s} {int(zone.sum()):8d} {cells} {whole[0]:7.0f}/{whole[1]:5.0f} {whole[0] / whole[1]:5.1f}x",
          flush=True)
    return whole[0], whole[1]


def run_speed(work: Path, sizes: list[tuple[int, int]], real: Path | None, repeat: int) -> None:
    work.mkdir(parents=True, exist_ok=True)
    print("CPU ms per frame (process time, all threads; the machine may be shared: read the ratios), "
          "old = the previous code (suspects_reference) / new = the fast path, and old / new")
    print(f"{'frame':34s} {'judged':>8s} " + " ".join(f"{p[0]:>17s}" for p in PARTS) + f" {'whole old/new':>13s} "
          f"{'ratio':>6s}")
    for H, W in sizes:
        for name, kind, sensor, q, seed in SPEED_FRAMES:
            xyz, height = speed_frame(work, name, kind, sensor, q, seed, (H, W))
            time_frame(f"{name} {W}x{H}", xyz, height, repeat)
    if real is not None:
        from replay.logs.pcd import read_pcd

        for pcd in sorted(real.glob("*.pcd")):
            xyz = read_pcd(pcd).xyz
            time_frame(f"{pcd.stem[:24]} {xyz.shape[1]}x{xyz.shape[0]}", xyz,
                       -1000.0 * xyz[..., 2].astype(np.float64), repeat)


#: the worker of --against: times suspects() as the labelling page calls it on .npy / .pcd frames
_WORKER = WORKER_SETTINGS + """
import inspect, sys, time
import numpy as np
from zcut.params import SuspectParams
from zcut.edge_surface import EdgeSurfaceParams
from zcut.suspects import suspects
from replay.logs.pcd import read_pcd
repeat, out, mode = int(sys.argv[1]), sys.argv[2], sys.argv[3]
# --fits: as the page calls it with a part model (no patch detector), where the tree has the option
kw = {"patches": False} if mode == "fits" and "patches" in inspect.signature(suspects).parameters else {}
for k, path in enumerate(sys.argv[4:]):
    xyz = read_pcd(path).xyz if path.endswith(".pcd") else np.load(path)
    h = -1000.0 * xyz[..., 2].astype(np.float64)
    zone = np.isfinite(xyz).all(axis=2)
    def call():
        r = suspects(xyz, h, zone, params=SuspectParams(), edge_surface=EdgeSurfaceParams(), **kw)
        getattr(r, "release", lambda: None)()  # the frame in mm handed back, as the page does (trees since 2026-12-06f)
        return r
    r = call()
    ts = []
    for _ in range(repeat):
        c0 = time.process_time()
        call()
        ts.append(time.process_time() - c0)
    np.savez(f"{out}.{k}.npz", mask=r.mask, groups=r.groups, detectors=r.detectors, gap=r.gap_mm,
             residual=r.residual_mm, score=r.group_score, primary=r.group_primary)
    print(1000.0 * float(np.median(ts)), flush=True)
"""


def run_against(work: Path, old: Path, sizes: list[tuple[int, int]], real: Path | None, repeat: int,
                rounds: int, *, fits: bool = False, bare: bool = False) -> None:
    """The fast path of tree ``old`` against this one's, whole calls in alternating processes; ``fits``: as the page
    calls it with a part model (``patches=False``) in a tree that has the option."""
    import subprocess
    import sys

    work.mkdir(parents=True, exist_ok=True)
    here = Path(__file__).resolve().parents[1]
    files, labels = [], []
    for H, W in sizes:
        for name, kind, sensor, q, seed in SPEED_FRAMES:
            f = work / f"speed_{kind}_{sensor}_q{q:g}_s{seed}_{W}x{H}.npy"
            if not f.exists():
                np.save(f, speed_frame(work, name, kind, sensor, q, seed, (H, W))[0])
            files.append(str(f))
            labels.append(f"{name} {W}x{H}")
        # large invalid regions: the zinc-nut frame with its top half and a third of the rest unmeasured
        f = work / f"speed_holes_{W}x{H}.npy"
        if not f.exists():
            xyz = np.load(work / f"speed_zinc_nuts_handmade_q0_s1_{W}x{H}.npy").copy()
            xyz[: H // 2] = np.nan
            xyz[np.random.default_rng(7).random((H, W)) < 0.3] = np.nan
            np.save(f, xyz)
        files.append(str(f))
        labels.append(f"zinc_nuts holes {W}x{H}")
    if real is not None:
        for pcd in sorted(real.glob("*.pcd")):
            files.append(str(pcd))
            labels.append(pcd.stem[:24])
    cpu: dict[str, list[list[float]]] = {"old": [], "new": []}
    for _ in range(rounds):
        for tag, tree in (("old", old.resolve()), ("new", here)):
            res = subprocess.run([sys.executable, "-c", _WORKER, str(repeat), str(work / f"against_{tag}"),
                                  "fits" if fits else "all", *files],
                                 cwd=tree, env=worker_env(str(tree), bare=bare),
                                 check=True, capture_output=True, text=True)
            cpu[tag].append([float(v) for v in res.stdout.split()])
    print(f"CPU ms per call, suspects(edge_surface=EdgeSurfaceParams(){', patches=False' if fits else ''}), zone = "
          f"every valid pixel; old = {old}, new = {here}; median of {repeat} calls, each of {rounds} alternating "
          f"rounds; {'bare processes' if bare else 'the page process settings'}; "
          f"load {__import__('os').getloadavg()[0]:.1f}")
    print(f"{'frame':34s} {'old':>15s} {'new':>15s} {'old/new':>7s} same  suspect px old/new, patch px old/new, "
          f"patch groups old/new, groups old/new")
    patch = DETECTORS.index("patch")
    for k, label in enumerate(labels):
        o = [r[k] for r in cpu["old"]]
        n = [r[k] for r in cpu["new"]]
        a, b = np.load(work / f"against_old.{k}.npz"), np.load(work / f"against_new.{k}.npz")
        same = all(np.array_equal(a[f], b[f], equal_nan=True) for f in a.files if f in b.files)
        counts = [(int(z["mask"].sum()), int((z["detectors"] >> patch & 1).sum()),
                   int((z["primary"] == patch).sum()) if "primary" in z.files else -1, int(z["groups"].max()))
                  for z in (a, b)]
        print(f"{label:34s} {'/'.join(f'{v:.0f}' for v in o):>15s} {'/'.join(f'{v:.0f}' for v in n):>15s} "
              f"{np.median(o) / np.median(n):7.2f} {'yes' if same else 'NO ':4s} "
              + ", ".join(f"{x}/{y}" for x, y in zip(*counts)), flush=True)


def run_parts(work: Path, old: Path, real: Path | None, repeat: int) -> None:
    """--parts: the parts the fifth round changed, the previous tree's code (``old``'s
    zcut/suspects/floating.py loaded beside this tree's, as a module of this ``zcut.suspects``) against
    this tree's in one process, alternating, after checking their outputs equal: the floating detector,
    the reach's median, the thresholds' numpy (τ, the jump, rough, |gap| / τ_px) against the kernels."""
    import importlib
    import importlib.util

    from replay.logs.pcd import read_pcd
    from zcut.edge_surface import _reach_samples
    from zcut.suspects import noise_profile
    from zcut.suspects.noise import local_height
    from zcut.suspects.select import median

    spec = importlib.util.spec_from_file_location("zcut.suspects._old_floating",
                                                  old / "zcut" / "suspects" / "floating.py")
    assert spec is not None and spec.loader is not None
    fl_old = importlib.util.module_from_spec(spec)
    fl_old.__package__ = "zcut.suspects"
    spec.loader.exec_module(fl_old)
    fl_new = importlib.import_module("zcut.suspects.floating")
    surfaces = importlib.import_module("zcut.suspects.surfaces")
    union = importlib.import_module("zcut.suspects.union")

    def ab(fo, fn) -> tuple[float, float]:
        fo()
        fn()
        to, tn = [], []
        for _ in range(repeat):
            c0 = time.process_time()
            fo()
            to.append(time.process_time() - c0)
            c0 = time.process_time()
            fn()
            tn.append(time.process_time() - c0)
        return 1000.0 * float(np.median(to)), 1000.0 * float(np.median(tn))

    files = sorted(work.glob("speed_*.npy")) + (sorted(real.glob("*.pcd")) if real is not None else [])
    print(f"CPU ms, old = {old} / new = this tree, one process, alternating, median of {repeat}")
    print(f"{'frame':40s} {'floating':>15s} {'reach median':>15s} {'thresholds':>15s}")
    params = SuspectParams()
    for path in files:
        xyz = read_pcd(path).xyz if path.suffix == ".pcd" else np.load(path)
        H, W = xyz.shape[:2]
        valid = np.isfinite(xyz).all(axis=2)
        h = np.ascontiguousarray(-1000.0 * xyz[..., 2].astype(np.float64))
        h[~valid] = np.nan
        zone = valid.copy()
        profile = noise_profile(h, zone)
        sigma_px = profile.sigma_at(local_height(h))
        rng = np.random.default_rng(0)
        rough = zone & (rng.random(zone.shape) < 0.05)
        step = max(params.floating_step_mm, float(np.median(sigma_px[zone])))
        args = (h, zone, valid, rough, params, 0.01 * H * W, step, profile)
        mo, go = fl_old.floating_components(*args)
        mn, at, gn = fl_new.floating_components(*args)
        if not (np.array_equal(mo, mn) and np.array_equal(np.flatnonzero(mo), at)
                and np.array_equal(go.ravel()[at], gn, equal_nan=True)):
            raise SystemExit(f"{path.name}: the floating detectors differ")
        cells = [ab(lambda args=args: fl_old.floating_components(*args),
                    lambda args=args: fl_new.floating_components(*args))]
        a = xyz.astype(np.float64) * 1000.0

        def reach_old(a=a, valid=valid) -> float:
            samples = _reach_samples(a, valid)
            return median(samples) if samples.size else 0.0

        if reach_old() != surfaces.reach_median(a, valid):
            raise SystemExit(f"{path.name}: the reach's medians differ")
        cells.append(ab(reach_old, lambda a=a, valid=valid: surfaces.reach_median(a, valid)))
        residual, gap = rng.normal(0, 1, zone.shape), rng.normal(0, 1, zone.shape)

        def thr_old(sigma_px=sigma_px, zone=zone, residual=residual, gap=gap) -> tuple[np.ndarray, ...]:
            tau = params.noise_k * sigma_px
            np.maximum(params.min_residual_mm, tau, out=tau)
            jump = params.noise_k * sigma_px
            np.maximum(params.jump_mm, jump, out=jump)
            tau_px = np.where(np.isfinite(tau) & (tau > 0), tau, params.min_residual_mm)
            return tau, jump, zone & ~(np.abs(residual) <= tau), np.abs(gap) / tau_px

        def thr_new(sigma_px=sigma_px, zone=zone, residual=residual, gap=gap, H=H, W=W) -> tuple[np.ndarray, ...]:
            tau, jump, rough, strength = np.empty((H, W)), np.empty((H, W)), np.empty((H, W), bool), np.empty((H, W))
            union._thresholds(sigma_px, params.noise_k, params.min_residual_mm, params.jump_mm, tau, jump)
            union._rough(zone, residual, tau, rough)
            union._gap_ratio(gap, tau, params.min_residual_mm, strength)
            return tau, jump, rough, strength

        if not all(np.array_equal(x, y) for x, y in zip(thr_old(), thr_new())):
            raise SystemExit(f"{path.name}: the thresholds differ")
        cells.append(ab(thr_old, thr_new))
        print(f"{path.stem[:40]:40s} " + " ".join(f"{o:7.1f}/{n:7.1f}" for o, n in cells), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=Path("/tmp/zcut_bench_suspects"))
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--tune-seeds", default="1")
    ap.add_argument("--report-seeds", default="4,5")
    ap.add_argument("--tune", action="store_true", help="score the parameter variants on the tuning seeds")
    ap.add_argument("--real", type=Path, help="folder of organized PCD scans (no truth)")
    ap.add_argument("--png", type=Path, help="write overlays of the real scans' groups here")
    ap.add_argument("--skip-synthetic", action="store_true")
    ap.add_argument("--speed", action="store_true", help="CPU time per part, previous code against the fast path")
    ap.add_argument("--sizes", default="1920x1200", help="--speed: frame sizes WxH, comma-separated")
    ap.add_argument("--repeat", type=int, default=3, help="--speed: calls per frame and path (median)")
    ap.add_argument("--against", type=Path, help="--speed: another tree's fast path against this one's")
    ap.add_argument("--raytraced-seeds", default="5",
                    help="--speed: the seeds of the ray-traced frames, comma-separated (5: the default's)")
    ap.add_argument("--rounds", type=int, default=2, help="--against: alternating rounds")
    ap.add_argument("--fits", action="store_true",
                    help="--against: as the page calls it with a part model (patches=False where the tree has it)")
    ap.add_argument("--parts", action="store_true",
                    help="--against: the fifth round's parts, old / new in one process (frames of --work)")
    ap.add_argument("--bare", action="store_true",
                    help="--speed: without the process settings of every zcut command (replay.process.configure_process)")
    args = ap.parse_args()
    if args.speed and not args.bare and (args.against is None or args.parts):  # in this process
        from replay.process import configure_process

        configure_process()  # as `zcut annotate`'s process (cli.main): before numba and the threads start
    if args.speed:
        with_raytraced_seeds(args.raytraced_seeds)
        sizes = [tuple(int(v) for v in s.split("x"))[::-1] for s in args.sizes.split(",")]
        if args.against is not None and args.parts:
            run_parts(args.work, args.against, args.real, args.repeat)
            return
        if args.against is not None:
            run_against(args.work, args.against, sizes, args.real, args.repeat, args.rounds,  # type: ignore[arg-type]
                        fits=args.fits, bare=args.bare)
            return
        run_speed(args.work, sizes, args.real, args.repeat)  # type: ignore[arg-type]
        return
    kinds = args.kinds.split(",")
    cache = args.work / "zones"
    print(f"defaults: {SuspectParams()}")
    if not args.skip_synthetic:
        if args.tune:
            seeds = [int(s) for s in args.tune_seeds.split(",")]
            logs, ply = prepare(args.work, kinds, seeds, args.frames)
            res = score_logs(logs, ply, cache, VARIANTS)
            for name, tallies in res.items():
                print()
                print_table(f"TUNING seeds {seeds}, variant: {name}", tallies)
        seeds = [int(s) for s in args.report_seeds.split(",")]
        logs, ply = prepare(args.work, kinds, seeds, args.frames)
        res = score_logs(logs, ply, cache, VARIANTS[:1])
        print()
        print_table(f"HELD OUT seeds {seeds}, defaults, 1920x1200, scored region = zone + above-rim points",
                    res["defaults"])
    if args.real is not None:
        print()
        run_real(args.real, args.work, args.png)


if __name__ == "__main__":
    main()
