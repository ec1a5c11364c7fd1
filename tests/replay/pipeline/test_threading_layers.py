"""numba's threading layer of the command line (issue 32 item 1, both cores busy): a replay gives the same
results bit for bit (every mask, label image, height image and count) under OpenMP's layer, the one
``replay.process.configure_process`` chooses, as under numba's workqueue layer (the previous choice), with one
frame in flight or two, and whatever the number of numba threads (the parallel kernels split the rows among
them: a kernel whose result depended on the split would show here).

The layer is chosen once per process, so every run is a subprocess set up as ``zcut replay`` sets itself up;
one subprocess per (layer, frames in flight, threads) replays every log that setting is checked on, one after
the other (the real log, which runs no parallel kernel, first: the layer is read after each log).
Classes of log: synthetic zinc nuts and spheres (the bin stages on), frames with large invalid regions, an
all-invalid frame and a frame with one valid pixel, and the real Kinect log (no bin). The parallel kernels are
also driven alone on empty, 1 x 1 and 1 x N images.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from log_helpers import invalid_blobs, writer_like
from subprocess_helpers import run_python

from replay.logs.frame import Frame
from replay.logs.reader import LogReader
from replay.synth.log import write_synthetic_log

ROOT = Path(__file__).resolve().parents[3]

#: replays of argv[2:] in turn with argv[1] frames in flight; per log the layer after it, and per frame its index,
#: a digest of every mask, label and height image, the row's counts, the bin check's figure and the registration's
#: pose
_REPLAY = r'''
import hashlib, json, sys
from replay.process import configure_process
configure_process()
from pathlib import Path
import numba
import numpy as np
from replay.pipeline.bin_model import bin_model_for
from replay.pipeline.session import FrameRow, ReplaySession

logs = []
for log in sys.argv[2:]:
    session = ReplaySession.open(Path(log), choose_bin_model=lambda r: bin_model_for(r, None))
    out = []
    for frame, r in session.results(in_flight=int(sys.argv[1])):
        images = {"valid": r.valid, "zone": r.zone, "easy": r.easy_outliers, "clusters": r.cut.clusters,
                  "height": r.height_mm, **{"outliers." + m: o for m, o in r.outliers.items()}}
        if r.bin_mask is not None:
            images["bin_mask"] = r.bin_mask.mask
        if r.removal is not None:
            images.update(table=r.removal.table, bin_points=r.removal.bin_points, removal_height=r.removal.height_mm,
                          removal_xyz=r.removal.xyz)
        digest = {k: hashlib.sha256(str(v.dtype).encode() + str(v.shape).encode() + np.ascontiguousarray(v).tobytes())
                  .hexdigest() for k, v in images.items()}
        row = FrameRow.of(r)
        counts = [row.valid_px, row.zcut, row.sor, row.both, row.above_rim, row.clusters, row.others, row.bin_flagged]
        reg = r.registration
        out.append({"index": frame.index, "images": digest, "counts": counts, "bin_check": repr(row.bin_check),
                    "warnings": list(r.warnings),
                    "pose": np.asarray(reg.T_cam_bin, float).ravel().tolist() if reg is not None else None})
    try:
        layer = numba.threading_layer()
    except ValueError:  # no parallel kernel ran yet (a log without the bin stages)
        layer = None
    logs.append({"layer": layer, "threads": numba.get_num_threads(), "frames": out})
print(json.dumps(logs))
'''


def _replay(logs: list[Path], *, layer: str, in_flight: int, threads: int | None = None) -> list[dict[str, Any]]:
    """The digests of replays of ``logs``, one after the other, in a process whose numba threading layer is
    ``layer`` ("default": ``configure_process``'s choice) and whose numba runs ``threads`` threads (None: one
    per core)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_THREADING", "NUMBA_NUM_THREADS"))}
    env["PYTHONPATH"] = str(ROOT)
    if layer != "default":
        env["NUMBA_THREADING_LAYER"] = layer
    if threads is not None:
        env["NUMBA_NUM_THREADS"] = str(threads)
    out = run_python(_REPLAY, str(in_flight), *map(str, logs), cwd=ROOT, env=env)
    assert out.returncode == 0, out.stderr[-3000:]
    got: list[dict[str, Any]] = json.loads(out.stdout.strip().splitlines()[-1])
    assert len(got) == len(logs)
    return got


def _same(a: dict[str, Any], b: dict[str, Any]) -> None:
    fa, fb = a["frames"], b["frames"]
    assert [f["index"] for f in fa] == [f["index"] for f in fb] and fa
    for x, y in zip(fa, fb):
        i = x["index"]
        assert x["images"] == y["images"], (i, {k for k in x["images"] if x["images"][k] != y["images"].get(k)})
        assert x["counts"] == y["counts"], i
        assert x["bin_check"] == y["bin_check"], i
        assert x["warnings"] == y["warnings"], i
        assert (x["pose"] is None) == (y["pose"] is None), i
        if x["pose"] is not None:
            assert np.allclose(x["pose"], y["pose"], rtol=0.0, atol=1e-12), i


#: the oracle: the previous layer, one frame at a time
ORACLE = ("workqueue", 1, None)
ALL_RUNS = [("default", 1, None), ("default", 2, None), ("omp", 2, 1), ("omp", 1, 3), ("omp", 2, 3)]
#: the runs (layer, in flight, threads) each class of log is checked with, against the oracle
RUNS = {"zinc_nuts": ALL_RUNS, "spheres": ALL_RUNS,
        "holes": [("default", 2, None), ("omp", 1, 1), ("omp", 2, 3)],
        "real": [("default", 2, None), ("omp", 1, 1), ("omp", 2, 3)]}


def _check_layers(replays: dict[tuple[tuple[str, int, int | None], str], dict[str, Any]], kind: str) -> dict[str, Any]:
    """The oracle's replay of log ``kind`` against each of its runs (:data:`RUNS`)."""
    assert (ORACLE, kind) in replays, f"no replay of the {kind} log"
    oracle = replays[(ORACLE, kind)]
    assert oracle["layer"] in ("workqueue", None)
    for layer, in_flight, threads in RUNS[kind]:
        got = replays[((layer, in_flight, threads), kind)]
        if layer == "default" and oracle["layer"] is not None:
            assert got["layer"] == "omp"  # configure_process's choice
        if threads is not None:
            assert got["threads"] == threads
        _same(oracle, got)
    return oracle


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("layers")
    out = {
        "zinc_nuts": write_synthetic_log(d / "zn.mcap", kind="zinc_nuts", frames=4, seed=29, size=(150, 200)),
        "spheres": write_synthetic_log(d / "sp.mcap", kind="spheres", frames=3, seed=8, size=(200, 320)),
    }
    reader = LogReader(out["spheres"])
    rng = np.random.default_rng(41)
    holes = d / "holes.mcap"
    with writer_like(reader, holes) as w:
        for k, f in enumerate(list(reader.frames()) * 2):
            xyz = f.xyz.copy()
            h, wd = f.shape
            if k == 1:  # blobs of invalid pixels over ~40 % of the image
                invalid_blobs(xyz, rng)
            elif k == 2:  # the top half invalid
                xyz[: h // 2] = np.nan
            elif k == 3:  # nothing valid
                xyz[:] = np.nan
            elif k == 4:  # one valid pixel (the middle one of the valid pixels, in the bin)
                rows, cols = np.nonzero(np.isfinite(xyz).all(axis=2))
                r, c = rows[len(rows) // 2], cols[len(rows) // 2]
                keep = xyz[r, c].copy()
                xyz[:] = np.nan
                xyz[r, c] = keep
            w.write_frame(Frame(xyz=xyz, rgb=f.rgb, stamp_ns=f.stamp_ns + k, frame_id=f.frame_id,
                                intrinsics=f.intrinsics, topic=f.topic, index=k, masks=f.masks))
    out["holes"] = holes
    return out


@pytest.fixture(scope="module")
def replays(logs: dict[str, Path]) -> dict[tuple[tuple[str, int, int | None], str], dict[str, Any]]:
    """(run, kind of log) -> its replay's digests: the oracle and every run of :data:`RUNS`, one subprocess per
    run for all the logs it is checked on (the real Kinect log first, when the real data is here:
    ``test_a_real_kinect_log`` asks for it, and skips or fails without it as every real-data test does)."""
    from real_data_path import REAL_DATA

    paths = dict(logs)
    real = REAL_DATA / "mosd_clutter_kinect_ros2.mcap"
    if real.is_file():
        paths["real"] = real
    kinds = ["real", "zinc_nuts", "spheres", "holes"]  # the real log first: no parallel kernel runs before it
    wanted: dict[tuple[str, int, int | None], list[str]] = {}
    for kind in kinds:
        if kind in paths:
            for run in (ORACLE, *RUNS[kind]):
                wanted.setdefault(run, []).append(kind)
    out = {}
    for run, these in wanted.items():
        layer, in_flight, threads = run
        for kind, got in zip(these, _replay([paths[k] for k in these], layer=layer, in_flight=in_flight,
                                            threads=threads)):
            out[(run, kind)] = got
    return out


@pytest.mark.parametrize("kind", ["zinc_nuts", "spheres"])
def test_openmp_gives_the_workqueue_results_in_flight_and_thread_counts(replays, kind):
    oracle = _check_layers(replays, kind)
    assert any(f["counts"][1] for f in oracle["frames"])  # z-cut outliers found
    assert all("bin_points" in f["images"] for f in oracle["frames"])  # the bin stages ran


def test_invalid_regions_an_empty_frame_and_one_pixel(replays):
    oracle = _check_layers(replays, "holes")
    assert [f["counts"][0] for f in oracle["frames"]][3:5] == [0, 1]  # the all-invalid and the one-pixel frame


def test_a_real_kinect_log(real_data, replays):  # no bin model: no parallel kernel runs, the frames in flight differ
    _check_layers(replays, "real")


#: the parallel kernels of the bin check alone, on degenerate shapes, under each thread count of argv[1:]
_KERNELS = r'''
import json, sys
from replay.process import configure_process
configure_process()
import numba
import numpy as np
from zcut import bin_check

out = []
for n in map(int, sys.argv[1:]):
    numba.set_num_threads(n)
    rng = np.random.default_rng(3)
    for shape in ((0, 0), (1, 1), (1, 57), (57, 1), (5, 0), (31, 17)):
        zone = rng.random(shape) < 0.5
        h = rng.normal(0.0, 10.0, shape)
        h[rng.random(shape) < 0.2] = np.nan
        ring, easy = rng.random(shape) < 0.5, rng.random(shape) < 0.2
        top = bin_check._zone_top(zone, h)
        o = np.zeros(shape, np.bool_)
        counts = bin_check._offending(ring, easy, zone, h, True, 1.5, o)
        out.append([n, list(shape), [bool(top[0]), repr(float(top[1]))], counts.tolist(), o.tolist()])
print(json.dumps({"layer": numba.threading_layer(), "out": out}))
'''


@pytest.mark.parametrize("layer", ["default", "workqueue"])
def test_the_parallel_kernels_on_degenerate_shapes_whatever_the_threads(layer):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_THREADING", "NUMBA_NUM_THREADS"))}
    env.update(PYTHONPATH=str(ROOT), NUMBA_NUM_THREADS="3")
    if layer != "default":
        env["NUMBA_THREADING_LAYER"] = layer
    out = run_python(_KERNELS, "1", "2", "3", cwd=ROOT, env=env)
    assert out.returncode == 0, out.stderr[-3000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["layer"] == ("omp" if layer == "default" else layer)
    per_n: dict[int, list[Any]] = {}
    for n, *rest in got["out"]:
        per_n.setdefault(n, []).append(rest)
    assert per_n[1] == per_n[2] == per_n[3] and len(per_n[1]) == 6


#: the layer, the default frames in flight before and after a parallel kernel ran, and what a frame worker holds
_DEFAULTS = r'''
import json
from replay.process import configure_process
configure_process()
import numba
import numpy as np
from replay.pipeline import session
from zcut import bin_check

before = session.default_frames_in_flight()
a = np.zeros((4, 4), np.bool_)
bin_check._zone_top(a, np.zeros((4, 4)))  # a parallel kernel: the layer is chosen
print(json.dumps({"layer": numba.threading_layer(), "before": before, "after": session.frames_in_flight(),
                  "holds_lock": session.parallel_kernels() is session.PARALLEL_KERNELS}))
'''


@pytest.mark.parametrize(("env", "layer", "in_flight", "holds_lock"), [
    ({"NUMBA_NUM_THREADS": "2"}, "omp", 2, False),
    ({"NUMBA_NUM_THREADS": "1"}, "omp", 1, False),  # a study worker's share of one core
    ({"NUMBA_NUM_THREADS": "2", "NUMBA_THREADING_LAYER": "workqueue"}, "workqueue", 1, True),
    ({"NUMBA_NUM_THREADS": "2", "NUMBA_THREADING_LAYER_PRIORITY": "workqueue omp tbb"}, "workqueue", 1, True),
    ({"NUMBA_NUM_THREADS": "2", "ZCUT_FRAMES_IN_FLIGHT": "3"}, "omp", 3, False),
])
def test_the_command_lines_layer_and_frames_in_flight(env, layer, in_flight, holds_lock):
    full = {k: v for k, v in os.environ.items()
            if not k.startswith(("NUMBA_THREADING", "NUMBA_NUM_THREADS", "ZCUT_FRAMES_IN_FLIGHT"))}
    full.update(PYTHONPATH=str(ROOT), **env)
    out = run_python(_DEFAULTS, cwd=ROOT, env=full)
    assert out.returncode == 0, out.stderr[-3000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got == {"layer": layer, "before": min(in_flight, 2), "after": in_flight, "holds_lock": holds_lock}


@pytest.mark.parametrize(("given", "expected"), [({}, ["PASSIVE", "0", "omp workqueue tbb"]),
                                                 ({"OMP_WAIT_POLICY": "ACTIVE", "GOMP_SPINCOUNT": "10",
                                                   "NUMBA_THREADING_LAYER": "workqueue"}, ["ACTIVE", "10", "-"])])
def test_openmp_workers_do_not_spin_unless_the_user_says(given, expected):
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("NUMBA_THREADING", "OMP_WAIT_POLICY", "GOMP_SPINCOUNT"))}
    env.update(PYTHONPATH=str(ROOT), **given)
    code = ("import os\nfrom replay.process import configure_process\nconfigure_process()\n"
            "print('|'.join(os.environ.get(n, '-') for n in ('OMP_WAIT_POLICY', 'GOMP_SPINCOUNT',"
            " 'NUMBA_THREADING_LAYER_PRIORITY')))")
    out = run_python(code, cwd=ROOT, env=env, check=True)
    assert out.stdout.strip().split("|") == expected
