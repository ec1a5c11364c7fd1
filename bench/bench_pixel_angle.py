"""Benchmark: the removal's frame tolerance with the pixel angle's kernel against the previous tree's numpy version.

Run: ``.venv/bin/python bench/bench_pixel_angle.py LOG.mcap --against OLD [--repeats N]``

OLD is a ``git archive`` of the previous tree; its ``zcut.removal.pixel_angle`` (numpy) is read from OLD's
``zcut/removal.py`` and run in this process, and :func:`zcut.removal.frame_tolerance` is timed with this
tree's ``pixel_angle`` and with OLD's patched in, alternating frame by frame (``time.process_time``, all
threads; BLAS limited to one thread as the replay session limits it), on the log's frames after the first
(located as the replay locates them, not timed). Prints the medians (CPU ms) and their ratio, the pixel
angle alone both ways, and checks that the two tolerances are equal field for field (bit for bit).
"""

from __future__ import annotations

import argparse
import ast
import os
import statistics
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", "workqueue omp tbb")  # as `zcut` sets it

import numpy as np  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

from replay.pipeline import stages  # noqa: E402
from replay.pipeline.bin_model import bin_model_for  # noqa: E402
from replay.pipeline.session import ReplaySession  # noqa: E402
from zcut import removal as rm  # noqa: E402


def old_pixel_angle(old: Path) -> Any:
    """OLD's ``pixel_angle``, its source executed in this process (it uses numpy only)."""
    src = (old / "zcut" / "removal.py").read_text(encoding="utf-8")
    node = next(n for n in ast.parse(src).body if isinstance(n, ast.FunctionDef) and n.name == "pixel_angle")
    scope: dict[str, Any] = {"np": np}
    exec(compile(ast.Module([node], []), "old_pixel_angle", "exec"), scope)  # noqa: S102 - the previous tree's code
    return scope["pixel_angle"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", type=Path)
    ap.add_argument("--against", type=Path, required=True, help="a git archive of the previous tree")
    ap.add_argument("--repeats", type=int, default=10)
    args = ap.parse_args()
    old = old_pixel_angle(args.against)
    new = rm.pixel_angle
    session = ReplaySession.open(args.log, choose_bin_model=lambda reader: bin_model_for(reader, None))
    cfg, pm = session.config, session.prepared
    assert pm is not None and session.seed is not None, "the log needs its bin model and a registered first frame"
    index = pm.removal
    times: dict[str, list[float]] = {}
    fields = ("tolerance_mm", "residual_mm", "n_pixels", "n_coherent", "reach_mm", "n_off_field", "sigma_mm",
              "pixel_rad")
    with threadpool_limits(1, "blas"):
        frames = []
        for frame in session.reader.frames():
            loc = stages.locate_bin(frame, cfg, bin_model=pm, seed=session.seed)
            if loc.registration is not None and loc.registration.converged:
                frames.append((np.asarray(frame.xyz), loc.ring, loc.registration.T_cam_bin))
        frames = frames[1:]
        for i in range(args.repeats):
            for a, ring, T in frames:
                out = {}
                for name, f in (("new", new), ("old", old)) if i % 2 == 0 else (("old", old), ("new", new)):
                    rm.pixel_angle = f  # frame_tolerance reads the module's name
                    try:
                        t0 = time.process_time()
                        out[name] = rm.frame_tolerance(a, ring, index, T)
                        times.setdefault(f"frame_tolerance {name}", []).append(time.process_time() - t0)
                    finally:
                        rm.pixel_angle = new
                    flat = rm._ring_sample(a, ring)
                    t0 = time.process_time()
                    f(a, flat)
                    times.setdefault(f"pixel_angle {name}", []).append(time.process_time() - t0)
                got = [getattr(out["new"], k) for k in fields]
                want = [getattr(out["old"], k) for k in fields]
                assert np.array_equal(np.array(got, float), np.array(want, float), equal_nan=True), (got, want)
    med = {k: 1000.0 * statistics.median(v) for k, v in times.items()}
    print(f"{args.log.name}: {len(frames)} frames x {args.repeats}, load average {os.getloadavg()[0]:.1f}; "
          "CPU ms, medians (old / new = ratio); the tolerances equal field for field")
    for piece in ("frame_tolerance", "pixel_angle"):
        o, n = med[f"{piece} old"], med[f"{piece} new"]
        print(f"  {piece:16s} {o:6.2f} / {n:6.2f} = {o / n:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
