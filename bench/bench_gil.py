"""Benchmark: how long each stage of a replay holds the GIL (issue 32 item 1: what serialises two frames in flight).

Run: ``.venv/bin/python bench/bench_gil.py --log LOG.mcap [--repeats N]``

The stages of every frame after a warm-up one run one after the other in the main thread (as the stage table
runs them: the read, then ``locate_bin``'s pieces, the removal and its check, every base method, the metrics),
while a probe thread sleeps 0.2 ms at a time, again and again. Waking from a sleep, the probe must take the GIL
back: while another thread holds it (Python code, or a C call that does not release it) the probe waits, so
the time by which its sleeps overshoot, beyond the overshoot of an idle process (measured first, the
``baseline``) and less the time the probe waited for a core (``/proc/thread-self/schedstat``: the machine's
load, not the GIL), is time during which the GIL was held by someone else. Each overshoot is credited to the stage
whose window (wall clock, in the main thread) it falls in; the reader's own threads (the chunks' and the
records') are counted with the stage that runs meanwhile, mostly the read.

What it prints, per stage: wall ms a frame, GIL-held ms a frame (medians over the frames) and their ratio.
Two frames in flight on two cores can overlap only what does not hold the GIL: the whole replay's GIL-held
ms a frame bounds its frames/s at 1000 / (GIL-held ms) whatever the cores. The process is set up as
``zcut replay`` sets it up (``replay.process.configure_process``). The probe's own wake-ups cost the stages
a little (a Python stage must hand the GIL over every switch interval); on a loaded machine a thread
that holds the GIL may itself wait for a core meanwhile (counted as held): read the figures as an attribution,
not a clock.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from replay.process import configure_process

configure_process()

from replay.pipeline import stages  # noqa: E402
from replay.pipeline.bin_model import bin_model_for  # noqa: E402
from replay.pipeline.session import FrameRow, ReplaySession  # noqa: E402

#: the probe's sleep, s
SLEEP_S = 0.0002

#: the functions of replay.pipeline.stages whose windows are timed (the stages' pieces, in the order they run)
PIECES = ("valid_pixels", "bin_mask", "bin_pixels", "subsampled_points", "prepare_target", "pose_fitness_at_least",
          "register_bin", "remove_table_and_bin", "check_bin_removal", "relative_metrics")


class Probe:
    """The probe thread: its sleeps' start and end times (perf_counter) and durations less its waits for a core."""

    def __init__(self) -> None:
        self.events: list[tuple[float, float, float]] = []  # start, end, duration less the wait for a core
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="gil-probe", daemon=True)

    def _run(self) -> None:
        import os

        sleep, now, add, pread = time.sleep, time.perf_counter, self.events.append, os.pread
        fd = os.open("/proc/thread-self/schedstat", os.O_RDONLY)  # run ns, runqueue wait ns, slices
        try:
            queued = int(pread(fd, 128, 0).split()[1])
            while not self._stop.is_set():
                t0 = now()
                sleep(SLEEP_S)
                t1 = now()
                q = int(pread(fd, 128, 0).split()[1])
                # the time spent waiting for a core (the machine's load), not for the GIL, taken off the sleep
                add((t0, t1, t1 - t0 - (q - queued) * 1e-9))
                queued = q
        finally:
            os.close(fd)

    def __enter__(self) -> Probe:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()

    def held(self, t0: float, t1: float, baseline: float) -> float:
        """Seconds of GIL held by others within [t0, t1]: the overshoots beyond ``baseline`` of the sleeps
        that end in it."""
        return sum(max(0.0, d - SLEEP_S - baseline) for a, b, d in self.events if t0 <= b < t1)


def windows_of(log: Path) -> tuple[list[dict[str, list[tuple[float, float]]]], float, Probe]:
    """Run the log's frames (frame 0 warms up) with the probe; returns per frame the windows of every piece,
    the baseline overshoot (s) and the probe."""
    session = ReplaySession.open(log, choose_bin_model=lambda reader: bin_model_for(reader, None))
    session.run(frames=(0, 1), in_flight=1)  # warm-up: the kernels
    current: dict[str, list[tuple[float, float]]] = {}

    def timed(name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            t = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                current.setdefault(name, []).append((t, time.perf_counter()))
        return wrapper

    for name in PIECES:
        setattr(stages, name, timed(name, getattr(stages, name)))
    known = stages.registry()
    methods = {k: dataclasses.replace(m, run=timed(k, m.run)) for k, m in known.items()}
    stages.registry = lambda: methods  # type: ignore[assignment]  # the same methods, timed

    frames = session.reader.frames(start=1)
    per_frame: list[dict[str, list[tuple[float, float]]]] = []
    with Probe() as probe:
        time.sleep(0.5)
        t_idle = time.perf_counter()
        time.sleep(1.0)
        idle = [d - SLEEP_S for a, b, d in probe.events if a >= t_idle]
        baseline = statistics.median(idle) if idle else 0.0
        while True:
            current = {}
            t = time.perf_counter()
            frame = next(frames, None)
            current["read"] = [(t, time.perf_counter())]
            if frame is None:
                break
            t = time.perf_counter()
            located = stages.locate_bin(frame, session.config, bin_model=session.prepared, seed=session.seed)
            z = stages.bin_zone(frame, session.config, bin_model=session.prepared, located=located)
            result = stages.judge_zone(frame, z, session.config, t_start=t)
            t_row = time.perf_counter()
            FrameRow.of(result)
            current["row"] = [(t_row, time.perf_counter())]
            current["frame"] = [(current["read"][0][0], time.perf_counter())]
            per_frame.append(current)
            del frame, located, z, result
    return per_frame, baseline, probe


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", type=Path, required=True)
    ap.add_argument("--repeats", type=int, default=1, help="passes (each a fresh session); medians over all frames")
    args = ap.parse_args()
    import os

    rows: dict[str, list[tuple[float, float]]] = {}
    baselines = []
    loads = [os.getloadavg()[0]]
    for _ in range(max(args.repeats, 1)):
        per_frame, baseline, probe = windows_of(args.log)
        baselines.append(baseline)
        for frame in per_frame:
            for name, ws in frame.items():
                wall = sum(b - a for a, b in ws)
                held = sum(probe.held(a, b, baseline) for a, b in ws)
                rows.setdefault(name, []).append((wall, held))
        loads.append(os.getloadavg()[0])
    n = len(rows["frame"])
    print(f"GIL held per stage, {args.log.name}: medians over {n} frames ({args.repeats} pass(es)), ms a frame; "
          f"probe baseline overshoot {1e3 * statistics.median(baselines):.3f} ms; load average "
          f"{min(loads):.1f}-{max(loads):.1f} on {os.cpu_count()} cores")
    print(f"  {'stage':22s} {'wall ms':>9s} {'GIL held ms':>12s} {'held/wall':>10s}")
    order = ["read", *PIECES[:-1], *[k for k in rows if k not in PIECES and k not in ("read", "row", "frame")],
             "relative_metrics", "row", "frame"]
    seen = set()
    for name in order:
        if name in seen or name not in rows:
            continue
        seen.add(name)
        wall = 1e3 * statistics.median(w for w, _ in rows[name])
        held = 1e3 * statistics.median(h for _, h in rows[name])
        print(f"  {name:22s} {wall:9.1f} {held:12.1f} {held / wall if wall else float('nan'):10.2f}")
    print("  (frame: the whole frame, its pieces and what runs between them; medians of each row taken alone, so the\n"
          "  rows do not add up exactly)")


if __name__ == "__main__":
    main()
