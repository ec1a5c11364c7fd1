"""Benchmark: the bin stages' CPU cost per frame (bin mask, then registration), before and after, in one run.

Run: ``.venv/bin/python bench/bench_binmask.py [--sizes 480x640,1200x1920,2400x3840] [--frames 4]
[--repeats 3] [--kind zinc_nuts] [--dir DIR] [--opencv-threads 1]``

Per size, synthesises (once, cached in ``--dir``) two empty-bin scans and builds the bin model from
them, then ``--frames`` + 1 frames of ``--kind`` (hand-made sensor, fixed seeds, in memory). The
first frame is located without a seed and its registration seeds the others, as a replay does
(:class:`replay.pipeline.session.ReplaySession`). Every seeded frame then runs
:func:`replay.pipeline.stages.locate_bin` with the previous code (``old``:
:func:`zcut.binmask.bin_mask_reference`, :func:`zcut.binmask.bin_pixels_reference` and the previous
``prepare_target``, copied below) and with this tree's (``new``), alternately, ``--repeats`` times.
It prints the CPU milliseconds (``time.process_time``: every thread) of the ``bin_mask`` stage and of
the ``registration`` stage (everything ``locate_bin`` does after the mask: the ring of bin pixels,
the target, the seed's fitness, the ICP), medians over frames and repeats, their ratio, the CPU of
``register_bin`` (Open3D's ICP and the bin fitness, code this change leaves alone) and of the rest,
the cost per megapixel, and whether every output is the same (the masks, the ring, hence the points ICP is
given; the registration's counts and verdict), with the largest pose difference old vs new beside
that of two runs of the old code (Open3D's ICP is not bit-reproducible from run to run).

The first, unseeded frame (coarse and fine ICP from the translation-only guess) is timed the same
way on its own line.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

import replay.pipeline.stages as stages
import zcut.registration as registration
from replay.pipeline import config as cfg
from replay.pipeline.bin_model import build_bin_model, load_bin_model, save_bin_model
from replay.synth.synthesize import synthesize_frame
from zcut.binmask import bin_mask, bin_mask_reference, bin_pixels, bin_pixels_reference
from zcut.prepared_model import prepare_bin_model
from zcut.registration import TargetPoints, prepare_target

EMPTY_SEED = 11
KIND_SEED = 21


def _old_check_points(p: np.ndarray, name: str) -> np.ndarray:
    """``zcut.registration._check_points`` before this change (a row-wise finite test and a gather)."""
    a = np.asarray(p)
    a = a[np.isfinite(a).all(axis=1)]
    return np.ascontiguousarray(a, dtype=np.float64)


def old_prepare_target(target: np.ndarray, *, voxel_m: float, intrinsics: Any = None) -> TargetPoints:
    """``zcut.registration.prepare_target`` before this change: the row-wise finite test and Open3D's own
    voxel grid (the same points as ``voxel_down_points``; tests/zcut/test_registration_voxels.py)."""
    t = _old_check_points(target, "target")
    if voxel_m > 0:
        down = registration.voxel_down(registration.to_open3d(registration.Points(t)), voxel_m, "the target")
        cloud = registration.Points(np.asarray(down.points, dtype=np.float64))
    else:
        cloud = registration.Points(t)
    return TargetPoints(t, cloud, float(voxel_m), intrinsics)


VARIANTS: dict[str, dict[str, Callable[..., Any]]] = {
    "old": {"bin_mask": bin_mask_reference, "bin_pixels": bin_pixels_reference, "prepare_target": old_prepare_target},
    "new": {"bin_mask": bin_mask, "bin_pixels": bin_pixels, "prepare_target": prepare_target},
}


def parse_sizes(text: str) -> list[tuple[int, int]]:
    out = []
    for part in text.split(","):
        h, w = (int(v) for v in part.lower().split("x"))
        out.append((h, w))
    return out


def bin_model_for(d: Path, size: tuple[int, int]):  # type: ignore[no-untyped-def]
    h, w = size
    path = d / f"bin_model_empty{EMPTY_SEED}_{w}x{h}.ply"
    if not path.is_file():
        print(f"  building the bin model from 2 empty {w}x{h} scans -> {path}", flush=True)
        empties = [synthesize_frame(empty=True, seed=EMPTY_SEED, index=i, size=size).frame for i in range(2)]
        model, _ = build_bin_model(empties)
        save_bin_model(model, path)
    return load_bin_model(path)


def locate(variant: str, frame, config, prepared, seed):  # type: ignore[no-untyped-def]
    """(BinLocation, CPU s of the bin mask, CPU s of the registration stage, CPU s of its ICP calls)
    with ``variant``'s code."""
    fns = VARIANTS[variant]
    marks: list[float] = []
    icp = [0.0]
    register = stages.register_bin

    def timed_register(*a: Any, **k: Any) -> Any:
        c0 = time.process_time()
        out = register(*a, **k)
        icp[0] += time.process_time() - c0
        return out

    def timed_mask(*a: Any, **k: Any) -> Any:
        out = fns["bin_mask"](*a, **k)
        marks.append(time.process_time())
        return out

    saved = {name: getattr(stages, name) for name in (*fns, "register_bin")}
    try:
        stages.register_bin = timed_register
        stages.bin_mask = timed_mask
        stages.bin_pixels = fns["bin_pixels"]
        stages.prepare_target = fns["prepare_target"]
        # the mask's cost alone: valid = finite_xyz(xyz) runs before it in locate_bin
        rgb = frame.rgb
        c0 = time.process_time()
        fns["bin_mask"](rgb, params=config.bin_mask)
        t_mask = time.process_time() - c0
        marks.clear()
        icp[0] = 0.0
        out = stages.locate_bin(frame, config, bin_model=prepared, seed=seed)
        t_reg = time.process_time() - marks[0]
    finally:
        for name, fn in saved.items():
            setattr(stages, name, fn)
    return out, t_mask, t_reg, icp[0]


def same_location(a, b) -> list[str]:  # type: ignore[no-untyped-def]
    """Names of the outputs that differ: the mask, the ring (hence the points handed to ICP, in the
    same order), and the registration's counts and verdict. The pose itself is compared apart
    (:func:`pose_gap`): Open3D's ICP sums its correspondences over threads in no fixed order, so two
    runs of the same code on the same points differ in the last bits."""
    bad = []
    for f in a.bin_mask.__slots__:
        x, y = getattr(a.bin_mask, f), getattr(b.bin_mask, f)
        if (not np.array_equal(x, y)) if isinstance(x, np.ndarray) else repr(x) != repr(y):
            bad.append(f"bin_mask.{f}")
    if not np.array_equal(a.ring, b.ring):
        bad.append("ring")
    for f in ("n_model", "n_target", "n_rim", "converged", "T_init"):
        x, y = getattr(a.registration, f), getattr(b.registration, f)
        if (x.tobytes() != y.tobytes()) if isinstance(x, np.ndarray) else x != y:
            bad.append(f"registration.{f}")
    return bad


def pose_gap(a, b) -> float:  # type: ignore[no-untyped-def]
    """Largest difference between two poses' entries (metres, or rotation matrix entries)."""
    return float(np.abs(a.registration.T_cam_bin - b.registration.T_cam_bin).max())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="480x640,1200x1920", type=parse_sizes, help="HxW,HxW,... (default 480x640,1200x1920)")
    ap.add_argument("--frames", type=int, default=4, help="seeded frames per size (after the seed frame)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--kind", default="zinc_nuts")
    ap.add_argument("--dir", default=str(Path(tempfile.gettempdir()) / "zcut_bench_binmask"))
    ap.add_argument("--opencv-threads", type=int, default=0,
                    help="run OpenCV on this many threads (1: as on one core, where its precise distance transform "
                         "is Intel IPP's; 0: OpenCV's default)")
    args = ap.parse_args()
    if args.opencv_threads:
        import cv2

        cv2.setNumThreads(args.opencv_threads)
    d = Path(args.dir)
    d.mkdir(parents=True, exist_ok=True)
    rows = []
    for size in args.sizes:
        h, w = size
        config = cfg.resolve(cfg.LogFacts(None, None, None, size)).config  # the defaults
        print(f"{w}x{h}:", flush=True)
        prepared = prepare_bin_model(bin_model_for(d, size), registration=config.registration, removal=config.removal)
        frames = [synthesize_frame(kind=args.kind, seed=KIND_SEED, index=i, size=size).frame
                  for i in range(args.frames + 1)]
        first, _, _, _ = locate("new", frames[0], config, prepared, None)
        seed = first.registration
        print(f"  seed: converged {seed.converged}, fitness {seed.fitness:.3f}", flush=True)
        for label, todo, s in (("first frame (unseeded)", frames[:1], None), ("seeded frames", frames[1:], seed)):
            times: dict[str, dict[str, list[float]]] = {v: {"mask": [], "reg": [], "icp": []} for v in VARIANTS}
            differ: set[str] = set()
            gap_new, gap_old = 0.0, 0.0
            for frame in todo:
                previous_old = None
                for _ in range(args.repeats):
                    got = {}
                    for v in VARIANTS:
                        loc, tm, tr, ti = locate(v, frame, config, prepared, s)
                        times[v]["mask"].append(tm * 1000)
                        times[v]["reg"].append(tr * 1000)
                        times[v]["icp"].append(ti * 1000)
                        got[v] = loc
                    differ.update(same_location(got["old"], got["new"]))
                    gap_new = max(gap_new, pose_gap(got["old"], got["new"]))
                    if previous_old is not None:
                        gap_old = max(gap_old, pose_gap(previous_old, got["old"]))
                    previous_old = got["old"]
            med = {v: {k: statistics.median(x) for k, x in t.items()} for v, t in times.items()}
            mpx = h * w / 1e6
            o, n = med["old"], med["new"]
            tot_o, tot_n = o["mask"] + o["reg"], n["mask"] + n["reg"]
            rows.append((f"{w}x{h}", label, o, n, tot_o, tot_n, mpx, differ, gap_new, gap_old))
            print(f"  {label:24s} bin mask {o['mask']:6.1f} -> {n['mask']:5.1f} ms ({o['mask'] / n['mask']:.2f}x)  "
                  f"registration {o['reg']:6.1f} -> {n['reg']:5.1f} ms ({o['reg'] / n['reg']:.2f}x)  "
                  f"both {tot_o:6.1f} -> {tot_n:5.1f} ms ({tot_o / tot_n:.2f}x), of which register_bin (ICP, "
                  f"untouched) {o['icp']:5.1f} / {n['icp']:5.1f}, the rest {tot_o - o['icp']:5.1f} -> "
                  f"{tot_n - n['icp']:5.1f} ms ({(tot_o - o['icp']) / (tot_n - n['icp']):.2f}x); "
                  f"per Mpx {tot_o / mpx:5.1f} -> {tot_n / mpx:5.1f} ms; "
                  + ("identical" if not differ else f"DIFFER: {sorted(differ)}")
                  + f"; pose old vs new {gap_new:.1e}, old vs old {gap_old:.1e}", flush=True)
    print()
    print("| size | frames | bin mask old | new | registration old | new | both old | new | old / new | "
          "ICP old | new | both without ICP old | new | old / new | "
          "new per Mpx | masks, ring, counts identical | pose old vs new | old vs old |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|")
    for size_s, label, o, n, tot_o, tot_n, mpx, differ, gap_new, gap_old in rows:
        print(f"| {size_s} | {label} | {o['mask']:.1f} | {n['mask']:.1f} | {o['reg']:.1f} | {n['reg']:.1f} | "
              f"{tot_o:.1f} | {tot_n:.1f} | {tot_o / tot_n:.2f} | {o['icp']:.1f} | {n['icp']:.1f} | "
              f"{tot_o - o['icp']:.1f} | {tot_n - n['icp']:.1f} | {(tot_o - o['icp']) / (tot_n - n['icp']):.2f} | "
              f"{tot_n / mpx:.1f} | {'yes' if not differ else 'NO'} | "
              f"{gap_new:.1e} | {gap_old:.1e} |")


if __name__ == "__main__":
    main()
