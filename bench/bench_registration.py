"""Benchmark: bin registration before and after registering to bin pixels only, on the six synthetic kinds.

Run: ``.venv/bin/python bench/bench_registration.py [--size 1200x1920] [--frames 3] [--dir DIR]``

Synthesises (once, cached in ``--dir``) five empty-bin scans and, per part kind, a log of
``--frames`` filled-bin frames (fixed seeds), builds the bin model from the empty scans with
:func:`replay.pipeline.bin_model.build_bin_model`, then registers every frame two ways, as
``locate_bin`` does (the pixels subsampled to at most 150 000, the target prepared, coarse then fine
ICP from the translation-only initial guess):

- ``before``: the target is every bright pixel of the bin component (``bin_mask(...).walls & valid``)
  and the fitness Open3D's (the fraction of target points with a model point within the fine
  correspondence distance): the measure ``RegistrationResult.fitness`` had;
- ``after``: the target is :func:`zcut.binmask.bin_pixels` (the rim and upper walls) and the
  fitness the bin fitness (the share of the model's rim in view that the frame confirms within the
  fine correspondence distance, :func:`zcut.registration.pose_fitness`).

Per kind: the fitness before and after, the share of part pixels in each target (from the
synthesis truth, frames re-synthesised in memory), the pose error of each against the true pose
the log carries (``zcut.synth.poses``: translation of the model's centre in mm, rotation in
degrees), and the CPU time of each (target selection + preparation + ICP + fitness; median of
``--repeats``), with the ratio after/before. ``before`` runs today's ``register_bin``, so its time
includes the bin fitness too (the ``fit s`` column: about a millisecond), which the old code did
not compute. ``CPU o3d s`` times the ``after`` registration by Open3D's own ICP (``register_bin(...,
reference=True)``, the oracle of the default :mod:`zcut.icp_fast` kernel) and ``dT`` is the largest entry of
the difference of the two poses. Then a deliberately wrong start: the true pose moved
5 cm and turned 20 degrees, refined by the fine pass only (as when the previous frame's pose
seeds a moved bin): its bin fitness, whether it is reported as converged, and its reason.

The replay's budget is about 0.5 CPU-s per 1920 x 1200 frame for every stage together.

``--pieces LOG [--against TREE] [--repeats N]``: where the registration stage of a replay spends its CPU
on each frame of LOG after the first (the seed), piece by piece as ``locate_bin`` runs them (the ring
``bin_pixels``, the subgrid's gather, ``prepare_target``, the seed pose's fitness, ``register_bin`` on the
path the stage took, and within it the translation guess, the coarse voxel grid, the two ICP passes and
the bin fitness), each the least of N runs, medians over the frames; with ``--against`` the same in a
subprocess on that source tree's code (e.g. ``git archive OLD | tar -x -C /tmp/old``), side by side.
OpenCV runs on one thread (the one-core case); pin the process (``taskset -c 0``) for one core.

``--alternate LOG... --against TREE [--repeats N]``: the bin mask and the registration of each frame after the
first as ``locate_bin`` runs them, by this tree's ``zcut`` and by TREE's (imported as another package from a copy),
alternating N times a frame in one process, after comparing every result bit for bit (:func:`alternate`). The seed
check is each tree's own: ``pose_fitness_at_least`` where the tree has it, else ``pose_fitness`` compared with the
threshold; the two trees' answers must agree. The process is set up as a replay's (``configure_process``: one malloc
arena, freed memory kept; BLAS on one thread), OpenCV on one thread; it prints each log's medians, the median of the
runs' paired ratios, the means (a replay's CPU a frame is the mean: a few dear frames move it, not the median) and the
CPU ms per Mpx.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from replay.logs.reader import LogReader
from replay.pipeline.bin_model import build_bin_model
from replay.presets import PART_KINDS
from replay.synth.log import GENERATOR_VERSION, true_poses, write_synthetic_log
from replay.synth.scene import LABEL_PART
from replay.synth.synthesize import synthesize_frame
from zcut.binmask import bin_mask, bin_pixels
from zcut.params import RegistrationParams
from zcut.registration import pose_fitness, prepare_icp_model, prepare_target, register_bin

MAX_POINTS = 150_000  # replay.pipeline.stages.REGISTRATION_MAX_POINTS
EMPTY_SEED = 11
KIND_SEED = 21
MIN_FITNESS = 0.9  # the proposed RegistrationParams.min_fitness for the bin fitness


def parse_size(text: str) -> tuple[int, int]:
    h, w = (int(v) for v in text.lower().split("x"))
    return h, w


def prepare_logs(d: Path, size: tuple[int, int], frames: int, quantize_mm: float) -> tuple[Path, dict[str, Path]]:
    d.mkdir(parents=True, exist_ok=True)
    h, w = size
    tag = f"{w}x{h}_v{GENERATOR_VERSION}"
    qtag = f"_q{quantize_mm:g}mm" if quantize_mm else ""
    empty = d / f"empty_seed{EMPTY_SEED}_{tag}.mcap"
    if not empty.is_file():
        print(f"synthesising 5 empty-bin scans -> {empty}", flush=True)
        write_synthetic_log(empty, empty=True, frames=5, seed=EMPTY_SEED, size=size)
    logs = {}
    for i, kind in enumerate(PART_KINDS):
        log = d / f"{kind}_seed{KIND_SEED + i}_{frames}f_{tag}{qtag}.mcap"
        if not log.is_file():
            print(f"synthesising {frames} frames of {kind} -> {log}", flush=True)
            write_synthetic_log(log, kind=kind, frames=frames, seed=KIND_SEED + i, size=size, quantize_mm=quantize_mm)
        logs[kind] = log
    return empty, logs


def pose_error(T: np.ndarray, T_true: np.ndarray, centre: np.ndarray) -> tuple[float, float]:
    """(mm, degrees): where the model's centre lands, and the rotation between the two poses."""
    p = T[:3, :3] @ centre + T[:3, 3]
    q = T_true[:3, :3] @ centre + T_true[:3, 3]
    R = T_true[:3, :3].T @ T[:3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))
    return float(np.linalg.norm(p - q) * 1000.0), float(angle)


def select_before(bm, xyz: np.ndarray) -> np.ndarray:
    return bm.walls & np.isfinite(xyz).all(axis=2)


def select_after(bm, xyz: np.ndarray, ring_frac: float) -> np.ndarray:
    return bin_pixels(bm, xyz, ring_frac=ring_frac)


def target_from(xyz: np.ndarray, sel: np.ndarray, params: RegistrationParams, intrinsics):
    """What locate_bin does with the chosen pixels: a regular subgrid of at most MAX_POINTS, prepared."""
    s = max(1, int(np.ceil(np.sqrt(sel.sum() / MAX_POINTS))))
    pts = xyz[::s, ::s][sel[::s, ::s]].astype(np.float64)
    return prepare_target(pts, voxel_m=params.voxel_m, intrinsics=intrinsics)


def timed(fn, repeats: int):
    """(result of the last call, median CPU seconds)."""
    times, out = [], None
    for _ in range(max(repeats, 1)):
        c0 = time.process_time()
        out = fn()
        times.append(time.process_time() - c0)
    return out, statistics.median(times)


def wrong_start(T_true: np.ndarray, *, shift_m: float = 0.05, turn_deg: float = 20.0) -> np.ndarray:
    """The true pose turned about the camera's optical axis and moved sideways."""
    c, s = np.cos(np.radians(turn_deg)), np.sin(np.radians(turn_deg))
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    T = T_true.copy()
    T[:3, :3] = R @ T_true[:3, :3]
    T[:3, 3] = R @ T_true[:3, 3] + [shift_m, 0.0, 0.0]
    return T


def measure(icp, params: RegistrationParams, frame, bm, T_true: np.ndarray, on_part: np.ndarray,
            centre: np.ndarray, args) -> dict:
    """One frame registered before and after, timed; the wrong start; one row of the table."""
    xyz, K = frame.xyz, frame.intrinsics
    sel_b, sel_a = select_before(bm, xyz), select_after(bm, xyz, args.ring_frac)
    rb, tb = timed(lambda: register_bin(icp, target_from(xyz, select_before(bm, xyz), params, K)), args.repeats)
    ra, ta = timed(lambda: register_bin(icp, target_from(xyz, select_after(bm, xyz, args.ring_frac), params, K)),
                   args.repeats)
    tgt_a, tgt_b = target_from(xyz, sel_a, params, K), target_from(xyz, sel_b, params, K)
    ro, to = timed(lambda: register_bin(icp, target_from(xyz, select_after(bm, xyz, args.ring_frac), params, K),
                                        reference=True), args.repeats)
    dist = params.fine_correspondence_m
    _, tf = timed(lambda: pose_fitness(icp, tgt_a, ra.T_cam_bin, max_correspondence_m=dist), args.repeats)
    rw = register_bin(icp, tgt_a, init=wrong_start(T_true), coarse=False)
    return {
        "frame": frame.index,
        "fit_before": rb.icp_fitness,  # what RegistrationResult.fitness was
        "fit_after": ra.fitness,
        "new_at_before": pose_fitness(icp, tgt_b, rb.T_cam_bin, max_correspondence_m=dist),
        "icp_after": ra.icp_fitness,
        "parts_before": float(on_part[sel_b].mean()),
        "parts_after": float(on_part[sel_a].mean()),
        "err_before": pose_error(rb.T_cam_bin, T_true, centre),
        "err_after": pose_error(ra.T_cam_bin, T_true, centre),
        "cpu_before": tb,
        "cpu_after": ta,
        "cpu_fitness": tf,
        "cpu_open3d": to,
        "dT": float(np.abs(ra.T_cam_bin - ro.T_cam_bin).max()),
        "iterations": ra.iterations,
        "converged": ra.converged,
        "reason": ra.reason,
        "wrong_fitness": rw.fitness,
        "wrong_converged": rw.converged,
        "wrong_reason": rw.reason,
    }


PIECES = ("bin_pixels", "gather", "prepare_target", "seed_fitness", "register_bin", "  guess", "  voxel_coarse",
          "  icp_coarse", "  icp_fine", "  bin_fitness", "locate_bin")


def pieces_of_log(log: Path, repeats: int) -> dict[str, float]:
    """The medians over the frames after the first of each piece's least CPU ms of ``repeats`` runs
    (:data:`PIECES`; ``locate_bin`` is the whole call: the bin mask, the valid points and the registration)."""
    import cv2

    from replay.pipeline import stages
    from replay.pipeline.bin_model import bin_model_for
    from replay.pipeline.session import ReplaySession
    from zcut.icp_fast import icp as icp_pass
    from zcut.registration import _guess, _rim_fitness, subsampled_points, voxel_down_points

    cv2.setNumThreads(1)
    session = ReplaySession.open(log, choose_bin_model=lambda reader: bin_model_for(reader, None))
    cfg, prepared = session.config, session.prepared
    assert prepared is not None, f"{log} has no bin model"
    c, model = cfg.registration, prepared.icp
    got: dict[str, list[float]] = {k: [] for k in PIECES}

    def least(key, fn):  # type: ignore[no-untyped-def]
        best, out = float("inf"), None
        for _ in range(repeats):
            t = time.process_time()
            out = fn()
            best = min(best, time.process_time() - t)
        got[key].append(1000 * best)
        return out

    def one_frame(frame, seed):  # type: ignore[no-untyped-def]
        loc = least("locate_bin", lambda: stages.locate_bin(frame, cfg, bin_model=prepared, seed=seed))
        xyz, bm = frame.xyz, loc.bin_mask
        px = least("bin_pixels", lambda: bin_pixels(bm, xyz, ring_frac=c.ring_frac))
        step = max(1, int(np.ceil(np.sqrt(np.count_nonzero(px) / stages.REGISTRATION_MAX_POINTS))))
        pts = least("gather", lambda: subsampled_points(xyz, px, step=step))
        tgt = least("prepare_target", lambda: prepare_target(pts, voxel_m=c.voxel_m, intrinsics=frame.intrinsics))
        least("seed_fitness", lambda: pose_fitness(model, tgt, seed.T_cam_bin,
                                                    max_correspondence_m=c.fine_correspondence_m))
        src = np.asarray(tgt.cloud.points)
        if len(loc.registration.iterations) == 1:  # the seed pose, refined by the fine pass
            reg = least("register_bin", lambda: register_bin(model, tgt, params=c, init=seed.T_cam_bin, coarse=False))
            T = np.linalg.inv(seed.T_cam_bin)
            for k in ("  guess", "  voxel_coarse", "  icp_coarse"):
                got[k].append(0.0)
        else:
            reg = least("register_bin", lambda: register_bin(model, tgt, params=c))
            T0 = least("  guess", lambda: _guess(model.top_centre, tgt.points))
            coarse = least("  voxel_coarse", lambda: voxel_down_points(src, 2.0 * c.voxel_m))
            out = least("  icp_coarse", lambda: icp_pass(coarse, model.coarse_grid,
                                                         max_distance=c.max_correspondence_m, init=np.linalg.inv(T0),
                                                         point_to_plane=True, max_iteration=int(c.max_iterations)))
            T = out.transformation
        least("  icp_fine", lambda: icp_pass(src, model.fine_grid, max_distance=c.fine_correspondence_m, init=T,
                                             point_to_plane=True, max_iteration=int(c.max_iterations)))
        least("  bin_fitness", lambda: _rim_fitness(model, tgt, reg.T_cam_bin, c.fine_correspondence_m))

    first = None
    for i, frame in enumerate(session.reader.frames()):
        if i == 0:
            first = stages.locate_bin(frame, cfg, bin_model=prepared).registration
        else:
            one_frame(frame, first)
    out_ = {k: float(statistics.median(v)) for k, v in got.items()}
    out_["frames"] = float(len(got["locate_bin"]))
    return out_


def pieces_table(log: Path, against: Path | None, repeats: int) -> None:
    """Print :func:`pieces_of_log` of this tree and of ``against`` (subprocesses, this tree's first)."""
    import json
    import os
    import subprocess
    import sys

    trees = {"this tree": Path(__file__).resolve().parents[1]} | ({"previous": against} if against else {})
    res = {}
    loads = []
    for name, tree in trees.items():
        loads.append(os.getloadavg()[0])
        env = dict(os.environ, PYTHONPATH=str(tree))
        out = subprocess.run([sys.executable, __file__, "--pieces-json", str(log), "--repeats", str(repeats)],
                             env=env, cwd=str(tree), check=True, capture_output=True, text=True).stdout
        res[name] = json.loads(out.strip().splitlines()[-1])
    print(f"registration of {log.name}, {int(res['this tree']['frames'])} frames after the seed, CPU ms per frame "
          f"(medians of each frame's least of {repeats}); load average {min(loads):.1f}-{max(loads):.1f}")
    print(f"  {'piece':16s} " + " ".join(f"{n:>10s}" for n in trees) + ("  previous/this" if against else ""))
    for k in PIECES:
        line = f"  {k:16s} " + " ".join(f"{res[n][k]:10.2f}" for n in trees)
        if against and res["this tree"][k] > 0:
            line += f"  {res['previous'][k] / res['this tree'][k]:13.2f}"
        print(line)


def _tree_as(tree: Path, name: str):  # type: ignore[no-untyped-def]
    """``tree``'s ``zcut`` package imported as ``name`` (a copy without ``tree``'s own numba cache files, which
    are keyed by the module's name): the two trees' kernels side by side in one process. The copy lives in a
    folder named after ``tree``'s path under the temporary directory and is refreshed file by file with the
    sources' times kept (``shutil.copy2``), so numba's cache of the copy, written by the first run, is valid
    for the next ones (a run no longer compiles the other tree's kernels again: 2-7 minutes under load)."""
    import hashlib
    import importlib
    import shutil
    import sys

    key = hashlib.sha1(str(tree.resolve()).encode()).hexdigest()[:12]
    root = Path(tempfile.gettempdir()) / f"zcut_against_{key}"
    shutil.copytree(tree / "zcut", root / name, ignore=shutil.ignore_patterns("*.nbi", "*.nbc", "__pycache__"),
                    dirs_exist_ok=True)
    sys.path.insert(0, str(root))
    return importlib.import_module(name)


def alternate(logs: list[Path], against: Path, repeats: int) -> None:
    """The bin mask and the registration of every frame after the first, as ``locate_bin`` runs them (the
    valid points, ``bin_mask``, ``bin_pixels``, the subgrid, ``prepare_target``, the seed pose's fitness, the
    fine pass from it and the full registration when it does not hold), by this tree's ``zcut`` and by
    ``against``'s, alternating ``repeats`` times a frame; every result compared bit for bit first (the masks,
    the ring, the seed fitness, the pose, T_init, fitness, RMSE, counts, iterations, reason). CPU ms a frame,
    medians over the frames and runs."""
    import dataclasses
    import importlib
    import os

    from replay.process import configure_process

    configure_process()  # as a replay sets its process up: one malloc arena, the freed memory kept for the next frame
    import cv2
    from threadpoolctl import threadpool_limits

    from replay.pipeline import stages
    from replay.pipeline.bin_model import bin_model_for
    from replay.pipeline.session import ReplaySession

    threadpool_limits(limits=1, user_api="blas")  # as ReplaySession.run
    cv2.setNumThreads(1)
    _tree_as(against, "zcut_against")
    trees = {}
    for label, pkg in (("this", "zcut"), ("previous", "zcut_against")):
        trees[label] = {m: importlib.import_module(f"{pkg}.{m}") for m in ("registration", "binmask", "removal",
                                                                          "params", "cloud")}

    def same_type(obj, mods):  # type: ignore[no-untyped-def]  # a frozen dataclass rebuilt from that tree's class
        cls = getattr(mods["params" if "Params" in type(obj).__name__ else "cloud"], type(obj).__name__)
        return cls(**{f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)})

    for log in logs:
        session = ReplaySession.open(log, choose_bin_model=lambda reader: bin_model_for(reader, None))
        cfg, prepared = session.config, session.prepared
        assert prepared is not None, f"{log} has no bin model"
        c, model = cfg.registration, prepared.icp
        frames = list(session.reader.frames())

        def run(mods, f, seed, cfg=cfg, c=c, model=model):  # type: ignore[no-untyped-def]
            R, B = mods["registration"], mods["binmask"]
            valid = mods["removal"].finite_xyz(f.xyz)
            bm = B.bin_mask(f.rgb, params=same_type(cfg.bin_mask, mods))
            px = B.bin_pixels(bm, f.xyz, ring_frac=c.ring_frac)
            step = max(1, int(np.ceil(np.sqrt(np.count_nonzero(px) / stages.REGISTRATION_MAX_POINTS))))
            K = None if f.intrinsics is None else same_type(f.intrinsics, mods)
            tgt = R.prepare_target(R.subsampled_points(f.xyz, px, step=step), voxel_m=c.voxel_m, intrinsics=K)
            reg, holds = None, None
            if seed is not None:
                kept = stages.SEED_FITNESS_KEPT * seed.fitness
                if hasattr(R, "pose_fitness_at_least"):  # the seed check counted until decided (h/px3)
                    holds = R.pose_fitness_at_least(model, tgt, seed.T_cam_bin,
                                                    max_correspondence_m=c.fine_correspondence_m, fitness=kept)
                else:
                    holds = R.pose_fitness(model, tgt, seed.T_cam_bin, max_correspondence_m=c.fine_correspondence_m) >= kept
                if holds:
                    reg = R.register_bin(model, tgt, params=c, init=seed.T_cam_bin, coarse=False)
                    reg = reg if reg.converged else None
            if reg is None:
                reg = R.register_bin(model, tgt, params=c)
            return valid, bm, px, holds, reg

        seed = run(trees["this"], frames[0], None)[4]
        times: dict[str, list[float]] = {k: [] for k in trees}
        loads = [os.getloadavg()[0]]
        for f in frames[1:]:
            got = {k: run(mods, f, seed) for k, mods in trees.items()}
            a, b = got["this"], got["previous"]
            assert np.array_equal(a[0], b[0]) and np.array_equal(a[2], b[2]) and a[3] == b[3], f.index
            for name in ("mask", "walls", "found", "area_px", "bbox_rc"):
                assert np.array_equal(getattr(a[1], name), getattr(b[1], name)), (f.index, name)
            ra, rb = a[4], b[4]
            assert ra.T_cam_bin.tobytes() == rb.T_cam_bin.tobytes() and ra.T_init.tobytes() == rb.T_init.tobytes()
            for name in ("fitness", "inlier_rmse", "converged", "reason", "n_model", "n_target", "icp_fitness",
                         "n_rim", "iterations"):
                x, y = getattr(ra, name), getattr(rb, name)
                assert x == y or (x != x and y != y), (f.index, name, x, y)
            for r in range(repeats):
                for k in (("this", "previous") if r % 2 == 0 else ("previous", "this")):
                    t = time.process_time()
                    run(trees[k], f, seed)
                    times[k].append(1000 * (time.process_time() - t))
        loads.append(os.getloadavg()[0])
        this, prev = statistics.median(times["this"]), statistics.median(times["previous"])
        mpx = frames[0].xyz.shape[0] * frames[0].xyz.shape[1] / 1e6
        # the runs paired as they alternated (run r of one tree beside run r of the other): their ratios' median
        paired = statistics.median(p / t for p, t in zip(times["previous"], times["this"], strict=True))
        print(f"{log.name}: {len(frames) - 1} frames after the seed, every result identical; bin mask + registration "
              f"CPU ms a frame (medians of {repeats} alternating runs a frame): previous {prev:.2f}, this {this:.2f}, "
              f"previous / this {prev / this:.3f} (paired {paired:.3f}; means {statistics.mean(times['previous']):.2f} -> "
              f"{statistics.mean(times['this']):.2f}, {statistics.mean(times['previous']) / statistics.mean(times['this']):.3f}); "
              f"per Mpx {prev / mpx:.1f} -> {this / mpx:.1f} "
              f"({frames[0].xyz.shape[1]}x{frames[0].xyz.shape[0]}); load {min(loads):.1f}-{max(loads):.1f}",
              flush=True)


#: What ``--steps`` times inside ``locate_bin``, by module: each name's Python-level calls (a numba kernel called
#: from another kernel is its caller's time).
STEP_NAMES = {
    "replay.pipeline.stages": ("bin_mask", "bin_pixels", "subsampled_points", "prepare_target", "pose_fitness_at_least",
                               "register_bin", "valid_pixels"),
    "zcut.binmask": ("_check_rgb", "_component_stats", "_row_words", "_flooded", "_pad_component", "_assemble",
                     "_column_distances", "_largest_distance", "_ring_bounded", "_check_pixels_args", "_ring",
                     "_near_bounds", "_ring_threshold", "_vmax"),
    "zcut.registration": ("_check_points", "_checked_copy", "voxel_down_points", "_voxel_down_bounded", "_bounds",
                          "_voxel_ids", "_unordered_map_order", "_averages", "_guess", "_top_and_centre", "_percentiles",
                          "_order_pairs", "_rim_fitness", "_rim_reach", "_rim_in_view", "transform_points", "_cells_for",
                          "_cell_grid", "_confirmed_in", "_confirmed_reaches", "_least_count", "_finite_pose",
                          "_subsampled"),
    "zcut.icp_fast": ("icp", "_check_icp_args", "_icp_plane", "_icp_point"),
    "cv2": ("cvtColor", "dilate", "erode", "connectedComponents", "floodFill", "getStructuringElement",
            "distanceTransform"),
    "numpy.linalg": ("inv",),
}


def steps(log: Path, passes: int, max_frames: int) -> None:
    """``--steps``: the exclusive CPU ms a frame of every call of :data:`STEP_NAMES` inside ``locate_bin`` (each
    name wrapped; a call's time less its wrapped callees'), over ``passes`` passes of the frames after the seed,
    and per Mpx; the rest of ``locate_bin`` as one line. The process is set up as a replay's, OpenCV and BLAS on
    one thread. The wrappers cost ~1-2 microseconds a call: compare sizes, not the total with ``--alternate``."""
    import functools
    import importlib
    import os
    from collections import defaultdict

    from replay.process import configure_process

    configure_process()
    import cv2
    from threadpoolctl import threadpool_limits

    from replay.pipeline import stages
    from replay.pipeline.bin_model import bin_model_for
    from replay.pipeline.session import ReplaySession

    threadpool_limits(limits=1, user_api="blas")
    cv2.setNumThreads(1)
    excl: dict[str, float] = defaultdict(float)
    calls: dict[str, int] = defaultdict(int)
    stack: list[list] = []  # [name, start, callees' time]

    def wrap(name, fn):  # type: ignore[no-untyped-def]
        @functools.wraps(fn)
        def w(*a, **k):  # type: ignore[no-untyped-def]
            stack.append([name, time.process_time(), 0.0])
            try:
                return fn(*a, **k)
            finally:
                nm, t0, inner = stack.pop()
                total = time.process_time() - t0
                excl[nm] += total - inner
                calls[nm] += 1
                if stack:
                    stack[-1][2] += total
        return w

    for mod_name, names in STEP_NAMES.items():
        mod = importlib.import_module(mod_name)
        short = mod_name.rsplit(".", 1)[-1]
        for n in names:
            if hasattr(mod, n):
                setattr(mod, n, wrap(f"{short}.{n}", getattr(mod, n)))
    session = ReplaySession.open(log, choose_bin_model=lambda reader: bin_model_for(reader, None))
    cfg, prepared = session.config, session.prepared
    assert prepared is not None, f"{log} has no bin model"
    frames = list(session.reader.frames())[: (max_frames + 1) if max_frames else None]
    seed = stages.locate_bin(frames[0], cfg, bin_model=prepared).registration
    for f in frames[1:]:  # warm
        stages.locate_bin(f, cfg, bin_model=prepared, seed=seed)
    excl.clear()
    calls.clear()
    totals = []
    for _ in range(passes):
        for f in frames[1:]:
            t = time.process_time()
            stages.locate_bin(f, cfg, bin_model=prepared, seed=seed)
            totals.append(time.process_time() - t)
    n = len(totals)
    h, w = frames[0].xyz.shape[:2]
    mpx = h * w / 1e6
    mean = 1000 * sum(totals) / n
    print(f"{log.name} ({w}x{h}): locate_bin CPU ms a frame, mean {mean:.2f}, median "
          f"{1000 * statistics.median(totals):.2f} ({len(frames) - 1} frames x {passes}); load {os.getloadavg()[0]:.1f}")
    print(f"  {'step':34s} {'ms':>8s} {'ms/Mpx':>8s} {'calls':>6s}")
    for k, v in sorted(excl.items(), key=lambda kv: -kv[1]):
        print(f"  {k:34s} {1000 * v / n:8.3f} {1000 * v / n / mpx:8.2f} {calls[k] / n:6.2f}")
    rest = mean - 1000 * sum(excl.values()) / n
    print(f"  {'(the rest of locate_bin)':34s} {rest:8.3f} {rest / mpx:8.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pieces", type=Path, help="a log (with its bin model): the registration stage piece by piece")
    ap.add_argument("--pieces-json", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--against", type=Path, help="--pieces, --alternate: a source tree measured alongside")
    ap.add_argument("--alternate", type=Path, nargs="+", help="logs: the bin mask and registration of this tree and "
                    "--against's, alternating in one process, every result compared bit for bit")
    ap.add_argument("--steps", type=Path, help="a log: locate_bin's exclusive CPU ms a frame by call (and per Mpx)")
    ap.add_argument("--passes", type=int, default=3, help="--steps: passes over the frames")
    ap.add_argument("--max-frames", type=int, default=0, help="--steps: frames after the seed (0: all)")
    ap.add_argument("--size", default="1200x1920", type=parse_size, help="HxW (default 1200x1920)")
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per frame and method; medians")
    ap.add_argument("--ring-frac", type=float, default=0.2)
    ap.add_argument("--min-fitness", type=float, default=MIN_FITNESS)
    ap.add_argument("--quantize-mm", type=float, default=0.0, help="depth step of the filled scans (0: continuous)")
    ap.add_argument("--dir", default=str(Path(tempfile.gettempdir()) / "zcut_bench_registration"))
    args = ap.parse_args()
    if args.pieces_json is not None:
        import json

        print(json.dumps(pieces_of_log(args.pieces_json, args.repeats)))
        return
    if args.pieces is not None:
        pieces_table(args.pieces, args.against, args.repeats)
        return
    if args.steps is not None:
        steps(args.steps, args.passes, args.max_frames)
        return
    if args.alternate:
        if args.against is None:
            ap.error("--alternate needs --against TREE")
        alternate(args.alternate, args.against, args.repeats)
        return
    size = args.size
    empty, logs = prepare_logs(Path(args.dir), size, args.frames, args.quantize_mm)

    params = RegistrationParams(min_fitness=args.min_fitness)
    c0 = time.process_time()
    model, reports = build_bin_model(LogReader(empty).frames())
    print(f"bin model: {len(model.points)} points from {len(reports)} empty scans "
          f"({time.process_time() - c0:.1f} CPU-s); scans: "
          + ", ".join(f"{r.index}: " + (f"fitness {r.registration.fitness:.3f} icp {r.registration.icp_fitness:.3f}"
                                        if r.registration else (r.skipped or "reference")) for r in reports))
    icp = prepare_icp_model(model, params)
    centre = 0.5 * (model.points.min(axis=0) + model.points.max(axis=0))
    print(f"rim: {len(icp.rim)} of {len(icp.fine.points)} model points at the {params.voxel_mm:g} mm voxel; "
          f"up {np.round(icp.up, 4).tolist()}; min_fitness {params.min_fitness:g}, ring_frac {args.ring_frac:g}, "
          f"size {size[1]}x{size[0]}, depth step {args.quantize_mm:g} mm")
    print()
    head = (f"{'kind':13s} {'frm':>3s} | {'fit bef':>7s} {'fit aft':>7s} {'new@bef':>7s} {'icp aft':>7s} | "
            f"{'parts bef':>9s} {'parts aft':>9s} | {'err bef mm/deg':>15s} {'err aft mm/deg':>15s} | "
            f"{'CPU bef s':>9s} {'CPU aft s':>9s} {'ratio':>5s} {'fit s':>6s} {'CPU o3d s':>9s} {'dT':>7s} {'its':>7s} | "
            f"wrong start: fitness, converged")
    print(head)
    print("-" * len(head))
    rows = []
    for k, (kind, log) in enumerate(logs.items()):
        reader = LogReader(log)
        poses = true_poses(reader.metadata)
        for frame in reader.frames():
            T_true = poses[frame.stamp_ns]
            truth = synthesize_frame(kind=kind, seed=KIND_SEED + k, index=frame.index, size=size,
                                     quantize_mm=args.quantize_mm)
            assert np.allclose(truth.T_cam_bin, T_true)
            on_part = truth.surface == LABEL_PART
            bm = bin_mask(frame.rgb)
            row = measure(icp, params, frame, bm, T_true, on_part, centre, args)
            rows.append(row)
            row["kind"] = kind
            eb, ea = row["err_before"], row["err_after"]
            print(f"{kind:13s} {frame.index:3d} | {row['fit_before']:7.3f} {row['fit_after']:7.3f} "
                  f"{row['new_at_before']:7.3f} {row['icp_after']:7.3f} | {row['parts_before']:9.3f} "
                  f"{row['parts_after']:9.3f} | {eb[0]:7.3f}/{eb[1]:6.4f} {ea[0]:7.3f}/{ea[1]:6.4f} | "
                  f"{row['cpu_before']:9.3f} {row['cpu_after']:9.3f} {row['cpu_after'] / row['cpu_before']:5.2f} "
                  f"{row['cpu_fitness']:6.4f} {row['cpu_open3d']:9.3f} {row['dT']:7.1e} "
                  f"{'/'.join(map(str, row['iterations'])):>7s} | {row['wrong_fitness']:.3f}, {row['wrong_converged']}"
                  + ("" if row["converged"] else f"   AFTER NOT CONVERGED: {row['reason']}"), flush=True)
    print()
    print("per kind (mean over frames):")
    print(f"{'kind':13s} | {'fit bef':>7s} {'fit aft':>7s} | {'err bef mm':>10s} {'err aft mm':>10s} "
          f"{'err aft deg':>11s} | {'CPU bef s':>9s} {'CPU aft s':>9s} {'ratio':>5s} | {'wrong fit':>9s}")
    for kind in logs:
        rs = [r for r in rows if r["kind"] == kind]

        def mean(key, i=None, rs=rs):
            return float(np.mean([r[key] if i is None else r[key][i] for r in rs]))

        print(f"{kind:13s} | {mean('fit_before'):7.3f} {mean('fit_after'):7.3f} | {mean('err_before', 0):10.3f} "
              f"{mean('err_after', 0):10.3f} {mean('err_after', 1):11.4f} | {mean('cpu_before'):9.3f} "
              f"{mean('cpu_after'):9.3f} {mean('cpu_after') / mean('cpu_before'):5.2f} | {mean('wrong_fitness'):9.3f}")
    ok = all(r["fit_after"] >= 0.95 and r["converged"] for r in rows)
    wrong_ok = all(not r["wrong_converged"] for r in rows)
    print()
    print(f"after: fitness >= 0.95 and converged on every frame: {ok}; min {min(r['fit_after'] for r in rows):.3f}")
    print(f"the after registration by Open3D's ICP (reference=True): largest pose difference "
          f"{max(r['dT'] for r in rows):.1e}; CPU s (median) {statistics.median(r['cpu_open3d'] for r in rows):.3f} "
          f"against {statistics.median(r['cpu_after'] for r in rows):.3f}")
    print(f"wrong start (5 cm, 20 deg, fine pass only): never converged: {wrong_ok}; "
          f"max fitness {max(r['wrong_fitness'] for r in rows):.3f}; e.g. reason: {rows[0]['wrong_reason']}")


if __name__ == "__main__":
    main()
