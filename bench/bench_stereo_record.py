"""``zcut record-stereo``'s CPU time in two trees, alternating, and its output compared message by message
(docs/labelling_real.md, h/stereo4: the right view matched once a frame).

Each repeat runs ``python -m cli record-stereo SCENES -o LOG`` (with ``--reject-axes`` by default: four left-right
tolerances, every post-filter's default axes) once in this tree and once in ``--against`` (a ``git archive`` of the
tree before), the order alternating, each a child process whose CPU time (user + system) is read with ``os.wait4``.
Then every message of every topic of the two logs is compared (topic, log time, publish time, bytes), and the
metadata records.

    PYTHONPATH=. .venv/bin/python bench/bench_stereo_record.py --against OLD --data MIDDLEBURY --scenes A,B,…
        [--repeats 5] [--flags="--reject-axes"] [--work DIR]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run_child(tree: Path, args: list[str]) -> float:
    """CPU seconds (user + system) of ``python -m cli ARGS`` run in ``tree``."""
    env = {**os.environ, "PYTHONPATH": str(tree), "PYTHONDONTWRITEBYTECODE": "1"}
    p = subprocess.Popen([sys.executable, "-m", "cli", *args], cwd=tree, env=env, stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE)
    _, status, ru = os.wait4(p.pid, 0)
    p.returncode = os.waitstatus_to_exitcode(status)
    err = p.stderr.read().decode() if p.stderr else ""
    if p.returncode:
        raise SystemExit(f"error: record-stereo in {tree} failed ({p.returncode}): {err.strip()}")
    return ru.ru_utime + ru.ru_stime


def messages(log: Path) -> tuple[dict[tuple[str, int, int], bytes], dict[str, dict[str, str]]]:
    from mcap.reader import make_reader

    out: dict[tuple[str, int, int], bytes] = {}
    with open(log, "rb") as f:
        r = make_reader(f)
        for _schema, channel, msg in r.iter_messages():
            key = (channel.topic, msg.log_time, msg.publish_time)
            if key in out:
                raise SystemExit(f"error: {log}: two messages on {key}")
            out[key] = bytes(msg.data)
        meta = {m.name: dict(m.metadata) for m in r.iter_metadata()}
    return out, meta


def compare(a: Path, b: Path) -> list[str]:
    """What differs between two logs' messages and metadata (empty: every message the same)."""
    ma, da = messages(a)
    mb, db = messages(b)
    diff = [f"only in {a}: {k}" for k in ma.keys() - mb.keys()] + [f"only in {b}: {k}" for k in mb.keys() - ma.keys()]
    diff += [f"differs: {k}" for k in ma.keys() & mb.keys() if ma[k] != mb[k]]
    if da != db:
        diff.append(f"metadata differs: {sorted(k for k in da.keys() | db.keys() if da.get(k) != db.get(k))}")
    return sorted(diff)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", type=Path, required=True, help="the tree before (a git archive)")
    ap.add_argument("--data", type=Path, required=True, help="the folder of the scenes (docs/real_data.md)")
    ap.add_argument("--scenes", required=True, help="scene folder names, comma-separated")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--flags", default="--reject-axes", help="record-stereo's flags (default --reject-axes)")
    ap.add_argument("--work", type=Path, default=Path("/tmp/bench_stereo_record"))
    a = ap.parse_args(argv)
    for d in (a.against, a.data):
        if not d.is_dir():
            raise SystemExit(f"error: {d}: no such folder")
    scenes = [str(a.data / s) for s in a.scenes.split(",") if s]
    for side in ("old", "new"):
        (a.work / side).mkdir(parents=True, exist_ok=True)
    trees = {"old": a.against.resolve(), "new": ROOT}
    cpu: dict[str, list[float]] = {"old": [], "new": []}
    loads = []
    for i in range(a.repeats):
        order = ("old", "new") if i % 2 == 0 else ("new", "old")
        for side in order:
            out = a.work / side / "stereo.mcap"  # one name: the log's metadata holds it
            cpu[side].append(run_child(trees[side], ["record-stereo", *scenes, "-o", str(out), "--force", *a.flags.split()]))
        loads.append(os.getloadavg()[0])
        print(f"repeat {i}: old {cpu['old'][-1]:.2f} CPU-s, new {cpu['new'][-1]:.2f} CPU-s, load {loads[-1]:.1f}",
              flush=True)
    mo, mn = statistics.median(cpu["old"]), statistics.median(cpu["new"])
    print(f"median CPU-s: old {mo:.2f}, new {mn:.2f} ({mn / mo:.3f} ×); load {min(loads):.1f}–{max(loads):.1f}")
    diff = compare(a.work / "old" / "stereo.mcap", a.work / "new" / "stereo.mcap")
    n = len(messages(a.work / "new" / "stereo.mcap")[0])
    print(f"messages: {n}; " + ("every message of every topic and the metadata the same" if not diff
                                else f"{len(diff)} differences: " + "; ".join(diff[:10])))
    return 1 if diff else 0


if __name__ == "__main__":
    sys.exit(main())
