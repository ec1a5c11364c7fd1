"""Benchmark: fast z-cut (component tree, numba) vs the literal per-level loop, 1920 x 1200.

The fast version's default kernel is the flood (bucket queue over the levels); the union-find
kernel (sorted pixels; the default before, now used beyond 4095 levels) is timed as well, through
``find_clusters(..., kernel=...)`` (the stage view: the same tree, more read-outs), next to the flood
through the same function.

Run: ``.venv/bin/python bench/bench_zcut.py [--repeat-fast N] [--repeat-ref N] [--against OLD_TREE]``

``--against OLD_TREE`` (a checkout of the previous code, e.g. ``git archive HEAD~1 | tar -x -C
/tmp/old``) times that tree's ``zcut_outliers`` and ``find_clusters`` on the same frames in the same
run (a child process with OLD_TREE first on its path) and prints the ratio old / new, and whether
its masks are identical. ``--alternate`` (with ``--against``) times both trees in this one process
instead, calls alternating (a child process on a loaded machine reads slower than the same code
here), and skips the reference and the passes; it prints each tree's minor page faults a
``zcut_outliers`` call too (medians; the trees share one heap there).

Frames, heights in mm (larger = higher), seeded; nominal parameters step 0.2 mm, max_depth 30 mm,
max_area = 0.07 * a_max (a_max = 3000 px):
- ``pile``: a top-down view of a bin (floor, walls, rim) with parts piled ~100 mm deep, floating
  specular clusters above the parts and NaN holes (shadows).
- ``dense``: a gently curved surface with noise whose whole range lies inside the cut range, so
  every pixel takes part in every level.
- ``holes``: the pile with large invalid regions (a third of the width, and big blocks).
- ``zinc`` (``--synth``): a synthetic 1920 x 1200 zinc-nut frame (``replay.synth``), the whole
  height image the sensor gives (bin and walls included).
- ``kinect16``, ``mug`` (``--real DIR``, e.g. /work/shared/data/real): the real 480 x 640 Kinect and
  stereo clouds ``mosd_test16.pcd`` and ``table_scene_mug_stereo_textured.pcd`` as the pipeline sees
  them (h = -1000 z), then every other organised 480 x 640 cloud of DIR (named by its file).

Prints the times, the ratio reference / fast and checks that the masks are identical.
``--passes`` also prints where ``zcut_outliers``' CPU time goes (the extremes pass, the level pass with
the gentle components of the z-cut's connectivity, as ``zcut_outliers``, the prune: the large gentle components and the pixels below them left out, the
flood of the kept pixels, the read-out) beside the floor of
reading the heights and writing a mask, and the extremes pass again with the heights out of the caches
(``EVICT_BYTES`` streamed before each call: as in a call of ``zcut_outliers``, where they seldom are cached).
``--held-out pile:21,dense:31,...`` adds frames of those kinds at seeds the default frames do not use.
``--suspects-call DIR`` times instead the ``find_clusters`` call of the suspects' floating detector (its
arguments captured on the xyz frames of DIR: a step of 0.1 mm over the zone's whole height range, 1,200–17,000
levels, every pixel in the cuts), this tree alone or, with ``--against``, alternating with the old tree.
``--faults`` also prints ``find_clusters``' minor page faults, system ms and CPU ms a call (medians, this
tree, each result dropped before the next call); with ``--against``, the old tree's faults a call in its
own process. (Not with ``--alternate``: both trees share one heap there, and the allocator keeps for the
old tree's arrays what the new tree's block left it.)
CPU time (process_time) is the figure to quote on a shared machine.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from zcut.cuts import find_clusters, zcut_outliers, zcut_outliers_reference
from zcut.params import NOMINAL_MAX_DEPTH_MM, NOMINAL_RHO_THR, NOMINAL_STEP_MM, ZCutParams

H, W = 1200, 1920
A_MAX = 3000.0  # pixels of a part's largest face
#: ``--passes``: the bytes streamed before each call of the extremes pass timed with the heights out of the
#: caches (in a call of ``zcut_outliers`` they seldom are in them: the previous call, or the stage before,
#: streamed other memory through them; docs/performance.md)
EVICT_BYTES = 64 << 20


def pile_frame(seed: int = 7) -> np.ndarray:
    """Heights (mm) of a bin seen from above, parts piled ~100 mm deep on the floor (0 mm).

    The table and the bin walls (200 mm) are set to NaN, as the pipeline's bin stage does before
    the z-cut (paper Section 5.2).
    """
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    z = np.full((H, W), -50.0)  # table below the bin
    r0, r1, c0, c1 = 100, H - 100, 150, W - 150
    inside = (yy >= r0) & (yy < r1) & (xx >= c0) & (xx < c1)
    z[inside] = 0.0  # bin floor
    wall = inside & ((yy < r0 + 20) | (yy >= r1 - 20) | (xx < c0 + 20) | (xx >= c1 - 20))
    z[wall] = 200.0  # bin walls and rim
    floor = inside & ~wall
    # a heap: higher in the middle, ~100 mm at the top
    cy, cx = (r0 + r1) / 2, (c0 + c1) / 2
    heap = 100.0 * np.clip(1.0 - ((yy - cy) / (0.55 * (r1 - r0))) ** 2
                           - ((xx - cx) / (0.55 * (c1 - c0))) ** 2, 0.0, 1.0)
    surface = np.where(floor, heap, z)
    # parts: ellipsoidal caps (15..45 px radii, 8..20 mm tall) resting on the heap
    for _ in range(1500):
        py = rng.uniform(r0 + 20, r1 - 20)
        px = rng.uniform(c0 + 20, c1 - 20)
        ry, rx = rng.uniform(15, 45, 2)
        h = rng.uniform(8, 20)
        y0, y1 = int(max(py - ry, r0 + 20)), int(min(py + ry + 1, r1 - 20))
        x0, x1 = int(max(px - rx, c0 + 20)), int(min(px + rx + 1, c1 - 20))
        sy, sx = yy[y0:y1, x0:x1], xx[y0:y1, x0:x1]
        e = 1.0 - ((sy - py) / ry) ** 2 - ((sx - px) / rx) ** 2
        rest = heap[int(py), int(px)] + rng.uniform(-5.0, 5.0)
        cap = np.where(e > 0, rest + h * np.sqrt(np.clip(e, 0.0, 1.0)), -np.inf)
        surface[y0:y1, x0:x1] = np.maximum(surface[y0:y1, x0:x1], cap)
    z = surface + rng.normal(0.0, 0.05, (H, W))  # sensor noise 0.05 mm
    # floating specular clusters: small patches 1..15 mm above the local surface
    for _ in range(400):
        py, px = rng.integers(r0 + 30, r1 - 30), rng.integers(c0 + 30, c1 - 30)
        ry, rx = rng.integers(1, 6, 2)
        sl = (slice(py - ry, py + ry + 1), slice(px - rx, px + rx + 1))
        z[sl] = z[sl].max() + rng.uniform(1.0, 15.0) + rng.normal(0.0, 0.05, z[sl].shape)
    # NaN holes (shadows next to parts) and scattered dropouts
    for _ in range(600):
        py, px = rng.integers(0, H), rng.integers(0, W)
        ry, rx = rng.integers(2, 25, 2)
        z[max(py - ry, 0):py + ry, max(px - rx, 0):px + rx] = np.nan
    z[rng.random((H, W)) < 0.01] = np.nan
    # the table and the bin walls are removed before the z-cut (paper Section 5.2)
    z[~floor] = np.nan
    return z


def dense_frame(seed: int = 11) -> np.ndarray:
    """Every pixel within max_depth of the top: a 25 mm deep curved surface plus noise."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    z = 12.0 * np.sin(yy / 90.0) * np.cos(xx / 130.0) + rng.normal(0.0, 0.3, (H, W))
    return np.clip(z, -12.0, 12.0)


def holes_frame(seed: int = 13) -> np.ndarray:
    """The pile with large invalid regions: a band of a third of the width and 40 big blocks."""
    rng = np.random.default_rng(seed)
    z = pile_frame(seed)
    z[:, W // 3: 2 * W // 3] = np.nan
    for _ in range(40):
        py, px = rng.integers(0, H), rng.integers(0, W)
        ry, rx = rng.integers(30, 120, 2)
        z[max(py - ry, 0):py + ry, max(px - rx, 0):px + rx] = np.nan
    return z


def real_frames(folder: Path) -> dict[str, np.ndarray]:
    """The real Kinect and stereo clouds as height images (mm, h = -1000 z)."""
    import open3d as o3d

    out = {}
    named = {"mosd_test16.pcd": "kinect16", "table_scene_mug_stereo_textured.pcd": "mug"}
    files = [folder / f for f in named] + sorted(f for f in folder.glob("*.pcd") if f.name not in named)
    for file in files:
        cloud = o3d.io.read_point_cloud(str(file), remove_nan_points=False, remove_infinite_points=False)
        points = np.asarray(cloud.points)
        if points.shape[0] == 480 * 640:  # the organised 640 x 480 clouds
            out[named.get(file.name, file.stem[:16])] = -1000.0 * points.reshape(480, 640, 3)[..., 2].astype(np.float64)
    return out


def synth_frame(seed: int = 3) -> np.ndarray:
    """The height (mm, h = -1000 z) of a synthetic 1920 x 1200 zinc-nut frame of ``replay.synth`` (the bin,
    its walls and the pile as the sensor sees them, before the bin stages)."""
    from replay.synth import synthesize_frame

    xyz = synthesize_frame(kind="zinc_nuts", seed=seed, size=(H, W)).frame.xyz
    return -1000.0 * np.asarray(xyz[..., 2], dtype=np.float64)


def passes(z: np.ndarray, params: dict, repeat: int) -> dict[str, float]:
    """Median CPU ms of each pass of ``zcut_outliers`` on z (the pruned flood, taken whatever the frame's
    size: ``zcut_outliers`` floods frames of fewer than ``PRUNE_MIN`` pixels in the cuts whole), and of
    the floor; each pass timed on fresh copies of what it writes (the copies made outside the timing)."""
    from zcut.cut_tree import flood_core_left_out, gentle_levels, gentle_prune, pruned_outlier_mask
    from zcut.cuts import PRUNE_CHECK, PRUNE_CHECK_ROWS, _finite_range, _levels, _scratch, _window
    from zcut.params import n_levels

    step, max_area = params["step"], float(params["max_area"])
    K = n_levels(step, params["max_depth"])
    n, lo, hi, seg = _finite_range(z)
    k_eff, top = _levels(lo, hi, step, K)
    Hz, Wz = z.shape
    thr = hi - top * step  # as zcut_outliers: the window of the pixels in the cuts
    window, bound = ((0, 0, Hz, Wz), Hz * Wz) if not lo < thr else (_window(seg, thr, Wz)[:4], Hz * Wz)
    st, gl, pix, gpar, gcnt, gls = _scratch((window[2] + 2) * (window[3] + 2), bound)
    # as pruned_outliers: the labels in pix's order when at most half the frame may be in the cuts
    if lo < thr:
        wn = _window(seg, thr, Wz)
        labels = (gls,) if 2 * min(wn[4] * 64, wn[2] * wn[3]) <= Hz * Wz else ()
    else:
        labels = ()

    def levels() -> tuple:
        # as zcut_outliers: the 8-connected gentle components (the z-cut's connectivity)
        args = (z, seg, lo, hi, step, np.int64(k_eff + 2), np.int64(top))
        rest = (max_area, np.int64(max(PRUNE_CHECK, PRUNE_CHECK_ROWS * Wz)), st, pix, gl, gpar, gcnt)
        return (*gentle_levels(*args, True, *rest, 0.5, *window, *labels), 8)

    m, nl, labelled, gentle = levels()
    state = (st.copy(), pix.copy(), gpar.copy(), gcnt.copy())

    def prune_inputs() -> tuple:
        return tuple(a.copy() for a in state) + (np.zeros(top + 2, np.int64),)

    def prune(a: tuple) -> int:
        return gentle_prune(a[0], a[1], m, gl, a[2], a[3], nl, max_area, a[4], labelled, window[3], True,
                            np.int64(top), *labels)

    a = prune_inputs()
    keep = int(prune(a))
    st_kept, kept, start = a[0], a[1][:keep].copy(), a[4]
    lab = gl.copy()

    def flood(b: tuple) -> tuple:
        return flood_core_left_out(b[0], b[1], kept, window[3], np.int64(k_eff), np.int64(top), True, max_area, lab)

    _, _, node_parent, tagged, fin = flood((st_kept.copy(), start.copy()))
    other = np.ones(EVICT_BYTES, np.uint8)  # streamed before each call of the next row: the heights out of the caches
    res = {
        "floor (read heights, write a mask)": timed(lambda: (z.sum(), np.zeros(z.shape, bool).fill(False)), repeat)[1],
        "extremes pass": timed(lambda: _finite_range(z), repeat)[1],
        "extremes pass, heights not cached": timed_on(lambda: other.sum(), lambda _: _finite_range(z), repeat),
        "level pass + gentle components": timed(levels, repeat)[1],
        "prune (gentle + uphill)": timed_on(prune_inputs, prune, repeat),
        "flood": timed_on(lambda: (st_kept.copy(), start.copy()), flood, repeat),
        "read-out": timed(lambda: pruned_outlier_mask(z, lab, kept, fin, node_parent, tagged,
                                                      np.zeros(z.size, bool), window[0], window[1], window[3]),
                          repeat)[1],
    }
    res["pixels in the cuts"] = float(m)
    res["pixels flooded"] = float(keep)
    res["pixels flooded (labelling kept: 1)"] = float(labelled)
    res["gentle components' connectivity"] = float(gentle)
    return res


def timed_on(prepare, fn, repeat: int) -> float:
    """Median CPU time of ``fn(prepare())``, ``prepare`` left out of the timing."""
    cpu = []
    for _ in range(repeat):
        args = prepare()
        c0 = time.process_time()
        fn(args)
        cpu.append(time.process_time() - c0)
    return statistics.median(cpu)


def faults(fn, repeat: int) -> tuple[float, float, float]:
    """Median minor page faults, system CPU ms and CPU ms (process_time) of ``repeat`` calls of ``fn``, the
    result dropped before the next call (as the replay drops a frame's): a full-frame array freed and
    allocated again is faulted in page by page unless the allocator kept it (docs/performance.md)."""
    flt, sys_ms, cpu = [], [], []
    for _ in range(repeat):
        u0, c0 = resource.getrusage(resource.RUSAGE_SELF), time.process_time()
        out = fn()
        c1, u1 = time.process_time(), resource.getrusage(resource.RUSAGE_SELF)
        del out
        flt.append(u1.ru_minflt - u0.ru_minflt)
        sys_ms.append((u1.ru_stime - u0.ru_stime) * 1e3)
        cpu.append((c1 - c0) * 1e3)
    return statistics.median(flt), statistics.median(sys_ms), statistics.median(cpu)


def timed(fn, repeat: int) -> tuple[float, float, np.ndarray]:
    """Median wall-clock and median CPU time (process_time: less disturbed by other processes
    on a shared machine) of ``repeat`` calls, and the last result."""
    wall, cpu = [], []
    out = None
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - t0)
    return statistics.median(wall), statistics.median(cpu), out


_OLD_SNIPPET = """
import json, resource, statistics, sys, time
import numpy as np
from zcut.cuts import find_clusters, zcut_outliers
from zcut.params import ZCutParams
frames, params, repeat, out = sys.argv[1], json.loads(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
zcut_outliers(np.zeros((3, 3)), **params)
zp = ZCutParams(params["step"], params["max_depth"], params["max_area"])
res = {}
for name in frames.split(","):
    z = np.load(out + "/" + name + ".npy")
    find_clusters(z, params=zp)
    cpu = {"zcut_outliers": [], "find_clusters": [], "find_clusters_faults": []}
    for _ in range(repeat):
        for key, fn in (("zcut_outliers", lambda: zcut_outliers(z, **params)),
                        ("find_clusters", lambda: find_clusters(z, params=zp))):
            f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            c0 = time.process_time()
            m = fn()
            cpu[key].append(time.process_time() - c0)
            if key == "find_clusters":
                cpu["find_clusters_faults"].append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
            del m
    np.save(out + "/" + name + ".old.npy", zcut_outliers(z, **params))
    res[name] = {k: statistics.median(v) for k, v in cpu.items()}
print(json.dumps(res))
"""


def time_old_tree(tree: Path, frames: dict[str, np.ndarray], params: dict, repeat: int
                  ) -> tuple[dict[str, dict[str, float]], dict[str, np.ndarray]]:
    """Median CPU seconds of the old tree's zcut_outliers and find_clusters per frame, and its masks."""
    with tempfile.TemporaryDirectory() as tmp:
        for name, z in frames.items():
            np.save(f"{tmp}/{name}.npy", z)
        env = dict(os.environ, PYTHONPATH=str(tree))
        run = subprocess.run([sys.executable, "-c", _OLD_SNIPPET, ",".join(frames), json.dumps(params), str(repeat), tmp],
                             env=env, cwd=str(tree), capture_output=True, text=True, check=True)
        times = json.loads(run.stdout.strip().splitlines()[-1])
        masks = {name: np.load(f"{tmp}/{name}.old.npy") for name in frames}
    return times, masks


def old_modules(tree: Path):  # type: ignore[no-untyped-def]
    """The old tree's ``zcut.cuts`` and ``zcut.params``, imported first and kept as module objects (this tree's
    ``zcut`` modules put back in ``sys.modules`` after)."""
    import importlib

    here = {k: v for k, v in sys.modules.items() if k == "zcut" or k.startswith("zcut.")}
    for k in here:
        del sys.modules[k]
    sys.path.insert(0, str(tree))
    try:
        old_cuts = importlib.import_module("zcut.cuts")
        old_params = importlib.import_module("zcut.params")
    finally:
        sys.path.pop(0)
        for k in [k for k in sys.modules if k == "zcut" or k.startswith("zcut.")]:
            del sys.modules[k]
        sys.modules.update(here)
    if not str(old_cuts.__file__).startswith(str(tree.resolve())) and not str(old_cuts.__file__).startswith(str(tree)):
        raise SystemExit(f"--alternate: {tree} did not provide zcut (got {old_cuts.__file__})")
    return old_cuts, old_params


def alternate(tree: Path, frames: dict[str, np.ndarray], params: dict, repeat: int) -> bool:
    """``--alternate``: the old tree's and this tree's ``zcut_outliers`` and ``find_clusters`` in this
    one process, calls alternating (the old package imported first and kept as module objects, then
    this one); prints median CPU ms and the ratios, returns whether every result is identical."""
    old_cuts, old_params = old_modules(tree)
    zp_old = old_params.ZCutParams(params["step"], params["max_depth"], params["max_area"])
    zp_new = ZCutParams(params["step"], params["max_depth"], params["max_area"])
    calls = {
        "zo": lambda z: old_cuts.zcut_outliers(z, **params), "zn": lambda z: zcut_outliers(z, **params),
        "fo": lambda z: old_cuts.find_clusters(z, params=zp_old), "fn": lambda z: find_clusters(z, params=zp_new),
    }
    ok = True
    print(f"alternating in one process against {tree} (median CPU ms of {repeat} calls each):")
    for name, z in frames.items():
        fo, fn = calls["fo"](z), calls["fn"](z)
        same = (np.array_equal(calls["zo"](z), calls["zn"](z)) and np.array_equal(fo.clusters, fn.clusters)
                and np.array_equal(fo.level_counts, fn.level_counts) and np.array_equal(fo.pixel_level, fn.pixel_level))
        ok &= same
        cpu: dict[str, list[float]] = {k: [] for k in calls}
        flt: dict[str, list[int]] = {k: [] for k in calls}
        for _ in range(repeat):
            for key, fnc in calls.items():
                f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
                c0 = time.process_time()
                fnc(z)
                cpu[key].append(time.process_time() - c0)
                flt[key].append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
        m = {k: statistics.median(v) * 1e3 for k, v in cpu.items()}
        f = {k: statistics.median(v) for k, v in flt.items()}
        print(f"    {name:8s} zcut_outliers {m['zo']:7.2f} -> {m['zn']:7.2f} ms ({m['zo'] / m['zn']:4.2f}x), "
              f"find_clusters {m['fo']:7.2f} -> {m['fn']:7.2f} ms ({m['fo'] / m['fn']:4.2f}x); identical: {same}; "
              f"zcut_outliers' page faults a call {f['zo']:.0f} -> {f['zn']:.0f}")
    return ok


def suspects_calls(folder: Path, pattern: str) -> dict[str, tuple[np.ndarray, ZCutParams]]:
    """The arguments of the ``find_clusters`` call of :func:`zcut.suspects.suspects`' floating detector (a fine
    step over the zone's whole height range: every pixel in the cuts) on the xyz frames (.npy, H x W x 3, metres)
    of ``folder`` (``bench/bench_suspects.py --speed --against`` writes them), captured by a spy on the
    detector's module (the labelling page's call: ``edge_surface=EdgeSurfaceParams()``, zone = the valid pixels)."""
    import importlib

    from zcut.edge_surface import EdgeSurfaceParams
    from zcut.params import SuspectParams
    from zcut.suspects import suspects

    floating = importlib.import_module("zcut.suspects.floating")
    real = floating.find_clusters
    got: list[tuple[np.ndarray, ZCutParams]] = []

    def spy(h: np.ndarray, *, params: ZCutParams):  # type: ignore[no-untyped-def]
        got.append((h.copy(), params))
        return real(h, params=params)

    out = {}
    floating.find_clusters = spy
    try:
        for f in sorted(folder.glob(pattern)):
            xyz = np.load(f)
            h = -1000.0 * xyz[..., 2].astype(np.float64)
            zone = np.isfinite(xyz).all(axis=2)
            got.clear()
            suspects(xyz, h, zone, params=SuspectParams(), edge_surface=EdgeSurfaceParams())
            name = f.stem.removeprefix("speed_").removesuffix(f"_{xyz.shape[1]}x{xyz.shape[0]}")
            out[name] = got[0]
    finally:
        floating.find_clusters = real
    return out


def same_stage(a, b) -> bool:  # type: ignore[no-untyped-def]
    """Every field of two CutResults equal bit for bit (NaN = NaN in rho)."""
    return (all(np.array_equal(getattr(a, f), getattr(b, f)) and getattr(a, f).dtype == getattr(b, f).dtype
                for f in ("outliers", "clusters", "areas", "levels", "level_counts", "pixel_level"))
            and np.array_equal(a.rho, b.rho, equal_nan=True)
            and np.array([a.z_max, a.z_min]).tobytes() == np.array([b.z_max, b.z_min]).tobytes()
            and a.n_levels == b.n_levels)


def suspects_bench(folder: Path, pattern: str, tree: Path | None, repeat: int) -> bool:
    """``--suspects-call``: the suspects' ``find_clusters`` on each frame of ``folder``: this tree's CPU ms
    (median of ``repeat``) with its levels, pixels and clusters; with ``--against``, the old tree's calls
    alternating in this process, the ratio, and whether every field is identical."""
    calls = suspects_calls(folder, pattern)
    old = old_modules(tree) if tree is not None else None
    print(f"the suspects' find_clusters (median CPU ms of {repeat} calls{', alternating' if old else ''}; "
          f"load average {' '.join(f'{v:.1f}' for v in os.getloadavg())}):")
    ok = True
    for name, (hz, p) in calls.items():
        fns = {"new": lambda hz=hz, p=p: find_clusters(hz, params=p)}
        if old is not None:
            p_old = old[1].ZCutParams(step=p.step, max_depth=p.max_depth, max_area=p.max_area,
                                      connectivity=p.connectivity, a_max=p.a_max)
            fns = {"old": lambda hz=hz, p=p_old: old[0].find_clusters(hz, params=p), **fns}
        res = {k: fn() for k, fn in fns.items()}
        same = same_stage(res["old"], res["new"]) if old is not None else True
        ok &= same
        cpu: dict[str, list[float]] = {k: [] for k in fns}
        for _ in range(repeat):
            for k, fn in fns.items():
                c0 = time.process_time()
                fn()
                cpu[k].append(time.process_time() - c0)
        m = {k: statistics.median(v) * 1e3 for k, v in cpu.items()}
        r = res["new"]
        head = f"    {name:36s} {p.n_levels:6d} levels, {np.isfinite(hz).mean():5.1%} valid, {r.n_clusters:6d} clusters:"
        if old is not None:
            print(f"{head} {m['old']:7.1f} -> {m['new']:7.1f} ms ({m['old'] / m['new']:4.2f}x); identical: {same}")
        else:
            print(f"{head} {m['new']:7.1f} ms")
    return ok


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat-fast", type=int, default=7)
    ap.add_argument("--repeat-ref", type=int, default=2)
    ap.add_argument("--against", type=Path, default=None, help="a checkout of the previous code to time beside")
    ap.add_argument("--alternate", action="store_true",
                    help="with --against: time both trees in this process, calls alternating (no reference, no passes)")
    ap.add_argument("--real", type=Path, default=None, help="the folder of the real clouds (adds kinect16, mug)")
    ap.add_argument("--synth", action="store_true", help="add zinc: a synthetic 1920 x 1200 zinc-nut frame")
    ap.add_argument("--frames", default=None, help="comma-separated frame names to run (default: all)")
    ap.add_argument("--held-out", default=None, metavar="KIND:SEED,...",
                    help="add frames of the kinds pile, dense, holes, zinc at other seeds (e.g. pile:21,dense:31)")
    ap.add_argument("--passes", action="store_true", help="print the CPU time of each pass of zcut_outliers")
    ap.add_argument("--faults", action="store_true",
                    help="print find_clusters' page faults, system and CPU ms a call (this tree, in this process)")
    ap.add_argument("--suspects-call", type=Path, default=None, metavar="DIR",
                    help="time the suspects' find_clusters call on the xyz frames (.npy) of DIR instead "
                         "(bench/bench_suspects.py --speed --against writes them); with --against, alternating")
    ap.add_argument("--suspects-frames", default="speed_*.npy", help="with --suspects-call: the frames' glob")
    args = ap.parse_args()
    if args.suspects_call is not None:
        return 0 if suspects_bench(args.suspects_call, args.suspects_frames, args.against, args.repeat_fast) else 1

    params = dict(step=NOMINAL_STEP_MM, max_depth=NOMINAL_MAX_DEPTH_MM,
                  max_area=NOMINAL_RHO_THR * A_MAX)
    t0 = time.perf_counter()
    zcut_outliers(np.zeros((3, 3)), **params)  # numba: load the cache or compile
    warm = time.perf_counter() - t0
    print(f"numba warm-up (compile or cache load): {warm:.2f} s")

    frames = {"pile": pile_frame(), "dense": dense_frame(), "holes": holes_frame()}
    if args.synth:
        frames["zinc"] = synth_frame()
    if args.real is not None:
        frames.update(real_frames(args.real))
    if args.held_out is not None:
        kinds = {"pile": pile_frame, "dense": dense_frame, "holes": holes_frame, "zinc": synth_frame}
        for item in args.held_out.split(","):
            kind, seed = item.split(":")
            frames[f"{kind}{seed}"] = kinds[kind](int(seed))
    if args.frames is not None:
        frames = {k: v for k, v in frames.items() if k in args.frames.split(",")}
    if args.alternate:
        if args.against is None:
            raise SystemExit("--alternate needs --against OLD_TREE")
        return 0 if alternate(args.against, frames, params, args.repeat_fast) else 1
    old: dict[str, dict[str, float]] = {}
    old_masks: dict[str, np.ndarray] = {}
    if args.against is not None:
        old, old_masks = time_old_tree(args.against, frames, params, args.repeat_fast)
    ok = True
    for name, z in frames.items():
        valid = np.isfinite(z)
        in_range = valid & (z >= np.nanmax(z) - params["max_depth"] - params["step"])
        w_fast, c_fast, m_fast = timed(lambda z=z: zcut_outliers(z, **params), args.repeat_fast)
        w_ref, c_ref, m_ref = timed(lambda z=z: zcut_outliers_reference(z, **params), args.repeat_ref)
        zp = ZCutParams(params["step"], params["max_depth"], params["max_area"])
        stage = {
            kernel: timed(lambda k=kernel, z=z, zp=zp: find_clusters(z, params=zp, kernel=k), args.repeat_fast)
            for kernel in ("flood", "union-find")
        }
        same = np.array_equal(m_fast, m_ref) and all(
            np.array_equal(res.outliers, m_ref) for _, _, res in stage.values())
        ok &= same
        print(f"{name:6s} {z.shape[0]}x{z.shape[1]}: {in_range.mean():5.1%} of pixels in the cut range, "
              f"{int(m_ref.sum())} outliers, identical: {same}")
        print(f"    wall: reference {w_ref * 1e3:8.1f} ms, fast {w_fast * 1e3:7.1f} ms, "
              f"ratio {w_ref / w_fast:6.1f}x")
        print(f"    cpu:  reference {c_ref * 1e3:8.1f} ms, fast {c_fast * 1e3:7.1f} ms, "
              f"ratio {c_ref / c_fast:6.1f}x")
        for kernel, (w_k, c_k, _) in stage.items():
            print(f"    find_clusters, {kernel + ' kernel:':18s} wall {w_k * 1e3:7.1f} ms, "
                  f"cpu {c_k * 1e3:7.1f} ms, cpu ratio {c_ref / c_k:6.1f}x")
        if args.passes:
            for what, ms in passes(z, params, args.repeat_fast).items():
                print(f"    {what:36s} {ms:10.0f}" if what.startswith(("pixels", "gentle")) else
                      f"    {what:36s} {ms * 1e3:7.2f} ms cpu")
        if args.faults:
            f, s_ms, c_ms = faults(lambda z=z, zp=zp: find_clusters(z, params=zp), args.repeat_fast)
            print(f"    find_clusters: {f:6.0f} page faults, system {s_ms:5.2f} ms, cpu {c_ms:6.2f} ms a call (medians)")
        if name in old:
            c_stage = timed(lambda z=z, zp=zp: find_clusters(z, params=zp), args.repeat_fast)[1]
            same_old = bool(np.array_equal(old_masks[name], m_fast))
            ok &= same_old
            o = old[name]
            print(f"    against {args.against}: zcut_outliers cpu {o['zcut_outliers'] * 1e3:7.1f} -> {c_fast * 1e3:7.1f} ms "
                  f"({o['zcut_outliers'] / c_fast:4.1f}x), find_clusters cpu {o['find_clusters'] * 1e3:7.1f} -> "
                  f"{c_stage * 1e3:7.1f} ms ({o['find_clusters'] / c_stage:4.1f}x); identical: {same_old}")
            print(f"        the old tree's find_clusters: {o['find_clusters_faults']:.0f} page faults a call (its own process)")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
