"""Benchmark: a log's frames read and their valid pixels found, as a replay's reader and locator do.

Run: ``PYTHONPATH=. .venv/bin/python bench/bench_read_valid.py --log LOG.mcap [--against OLD] [--repeats N]
[--frames N] [--read-masks]``

Each measuring child (this script run with a source tree's code: its ``PYTHONPATH`` and working folder, its process
set up as ``zcut replay`` sets it, ``replay.process.configure_process``) opens the log, makes one pass over its first
``--frames`` frames to warm up (numba's cached kernels, the reader's pooled buffers), then one measured pass: every
frame read (``LogReader.frames``: the chunk readers' zstd and CRC, the frame's decoding; with ``--read-masks`` its
masks and codes read too, as a results file's writer reads them) and its valid pixels taken
as ``replay.pipeline.stages.locate_bin`` takes them (a frame's ``known_valid``, the decoder's, where the tree and the
layout have one: the lever of docs/performance.md's section below, at commit 046cc60; else ``zcut.removal.valid_pixels``'
pass). It prints, a frame: the process's CPU ms of the pass
(every thread), the CPU ms of the valid pixels' step in its thread, the frame reader's part in the consuming
thread (the scan's parsing, the pairing and the frame's decoding: the ``next`` of the frame stream), the masks'
reading (``--read-masks``), and a checksum of the valid masks (the trees must agree). With ``--against OLD`` this tree's child and
OLD's alternate ``--repeats`` times; the medians and OLD / this are printed with the load average. CPU time only:
the machine is shared (docs/performance.md, "The frame's valid pixels from its decoding").
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path


def child(log: Path, n_frames: int, read_masks: bool = False) -> dict[str, float]:
    """One tree's figures (run with that tree's code)."""
    from replay.process import configure_process

    configure_process()
    import numpy as np

    from replay.logs.reader import LogReader
    from zcut.removal import valid_pixels

    reader = LogReader(log)

    def one_pass() -> tuple[float, float, float, float, int, int]:
        t0 = time.process_time()
        step = 0.0
        dec = 0.0
        masks = 0.0
        check = 0
        n = 0
        frames = reader.frames(stop=n_frames)
        while True:
            d0 = time.thread_time()
            frame = next(frames, None)  # the consuming thread's part of the read: parse, pair, decode the frame
            dec += time.thread_time() - d0
            if frame is None:
                break
            if read_masks:  # as a results file's writer reads them (a frame's truth masks and codes)
                m0 = time.thread_time()
                for m in (*frame.masks.values(), *frame.codes.values()):
                    check = (check * 31 + int(m.reshape(-1)[:: 4099].sum())) % (1 << 61)
                masks += time.thread_time() - m0
            s0 = time.thread_time()
            valid = getattr(frame, "known_valid", None)
            if valid is None:
                valid = valid_pixels(frame.xyz)
            step += time.thread_time() - s0
            check = (check * 1_000_003 + int(np.count_nonzero(valid)) * 7 + int(np.flatnonzero(valid[::97, ::89]).sum())) % (1 << 61)
            n += 1
        return time.process_time() - t0, step, dec, masks, n, check

    one_pass()  # warm: kernels loaded, buffers pooled
    total, step, dec, masks, n, check = one_pass()
    return {"pass_ms": 1000 * total / n, "valid_ms": 1000 * step / n, "decode_ms": 1000 * dec / n,
            "masks_ms": 1000 * masks / n, "frames": n, "check": check}


def run_child(tree: Path, log: Path, n_frames: int, read_masks: bool = False) -> dict[str, float]:
    env = dict(os.environ, PYTHONPATH=str(tree))
    out = subprocess.run([sys.executable, os.path.abspath(__file__), "--child", str(log), "--frames", str(n_frames)]
                         + (["--read-masks"] if read_masks else []),
                         env=env, cwd=str(tree), check=True, capture_output=True, text=True).stdout
    result: dict[str, float] = json.loads(out.strip().splitlines()[-1])
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--log", type=Path, required=False)
    ap.add_argument("--against", type=Path, help="source tree measured in the same run (alternating)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--frames", type=int, default=25, help="the log's first N frames")
    ap.add_argument("--read-masks", action="store_true",
                    help="read every frame's masks and codes too, as a results file's writer does")
    ap.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child is not None:
        print(json.dumps(child(a.child, a.frames, a.read_masks)))
        return
    if a.log is None:
        ap.error("--log is required")
    here = Path(__file__).resolve().parents[1]
    trees = [("this", here)] + ([("old", a.against.resolve())] if a.against else [])
    runs: dict[str, list[dict[str, float]]] = {name: [] for name, _ in trees}
    loads = [os.getloadavg()[0]]
    for i in range(a.repeats):
        order = trees if i % 2 == 0 else trees[::-1]
        for name, tree in order:
            r = run_child(tree, a.log.resolve(), a.frames, a.read_masks)
            runs[name].append(r)
            loads.append(os.getloadavg()[0])
            print(f"  run {i + 1} {name:4s}: pass {r['pass_ms']:7.2f} CPU ms a frame, valid pixels {r['valid_ms']:6.2f}, "
                  f"frame reader {r.get('decode_ms', float('nan')):6.2f}, masks read {r.get('masks_ms', 0.0):6.2f}, "
                  f"{int(r['frames'])} frames, check {int(r['check'])}", flush=True)
    print(f"{a.log.name}: CPU ms a frame, medians of {a.repeats}; load average {min(loads):.1f}-{max(loads):.1f} "
          f"on {os.cpu_count()} cores" + ("; every mask and code read" if a.read_masks else ""))
    keys = ("pass_ms", "valid_ms", "decode_ms", "masks_ms")
    med = {name: {k: statistics.median(r.get(k, float("nan")) for r in rs) for k in keys} for name, rs in runs.items()}
    print(f"  {'tree':6s} {'read + valid':>13s} {'valid step':>11s} {'frame reader':>13s} {'masks read':>11s}")
    for name, m in med.items():
        print(f"  {name:6s} {m['pass_ms']:13.2f} {m['valid_ms']:11.2f} {m['decode_ms']:13.2f} {m['masks_ms']:11.2f}")
    if a.against:
        o, n = med["old"], med["this"]
        print(f"  old / this: read + valid {o['pass_ms'] / n['pass_ms']:.3f} x ({o['pass_ms'] - n['pass_ms']:+.2f} ms "
              f"saved), valid step {o['valid_ms'] - n['valid_ms']:+.2f} ms saved, frame reader "
              f"{o['decode_ms'] / n['decode_ms']:.3f} x ({o['decode_ms'] - n['decode_ms']:+.2f} ms saved)")
        same = {int(r["check"]) for rs in runs.values() for r in rs}
        print(f"  valid masks' checksum {'the same in every run' if len(same) == 1 else 'DIFFERS: ' + str(sorted(same))}")


if __name__ == "__main__":
    main()
