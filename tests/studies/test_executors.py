"""Local workers (docs/studies.md): a worker death costs only the unit it ran; workers die with
their driver (kill -9 or SIGTERM); an interrupted batch is resumable and leaves no temporary."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from worker_helpers import die_on

from cli.main import main
from studies.executors import LocalExecutor


def test_a_worker_death_is_charged_to_the_unit_it_ran(tmp_path):
    """Two workers, eight units: one kills its worker every time, one the first time only. The
    first fails ("died twice"), the second succeeds on its retry, the six others run once."""
    units = [(f"u{i}", "ok") for i in range(8)]
    units[2] = ("u2", "always")
    units[5] = ("u5", "once")
    results = dict(LocalExecutor(2).run(die_on, units, str(tmp_path)))
    assert set(results) == set(units)
    failed = {u: r for u, r in results.items() if not isinstance(r, str)}
    assert list(failed) == [("u2", "always")]
    assert "died twice on this unit" in failed[("u2", "always")].error
    assert "SIGKILL" in failed[("u2", "always")].error
    assert {r for u, r in results.items() if isinstance(r, str)} == {f"u{i}" for i in range(8) if i != 2}


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("exec_logs")
    for i, kind in enumerate(("rods", "spheres")):
        assert main(["synth", "-o", str(d / f"{kind}.mcap"), "--parts", kind, "--frames", "6", "--seed", str(i),
                     "--size", "480x640"]) == 0
    return d


def _children(pid: int) -> list[int]:
    out = subprocess.run(["ps", "-o", "pid=", "--ppid", str(pid)], capture_output=True, text=True).stdout
    return [int(x) for x in out.split()]


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[-1][0] != "Z"
    except FileNotFoundError:
        return False


def _start_batch(logs: Path, out: Path) -> tuple[subprocess.Popen, list[int]]:
    """A batch driver on two workers, once its workers and the resource tracker run; its children."""
    p = subprocess.Popen([sys.executable, "-m", "cli", "batch", str(logs), "-o", str(out), "--workers", "2",
                          "--frames-per-unit", "1", "--results"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 300
    while len(_children(p.pid)) < 3:  # two workers and multiprocessing's resource tracker
        assert p.poll() is None and time.monotonic() < deadline
        time.sleep(0.1)
    while not list((out / "parts").glob("*.json")):  # work is under way
        assert p.poll() is None and time.monotonic() < deadline
        time.sleep(0.1)
    return p, _children(p.pid)


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["kill -9", "SIGTERM"])
def test_workers_die_with_their_driver(logs, tmp_path, sig):
    p, children = _start_batch(logs, tmp_path / "b")
    try:
        p.send_signal(sig)
        p.wait(timeout=120)
        deadline = time.monotonic() + 5
        while any(_alive(c) for c in children) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not [c for c in children if _alive(c)], "workers or the resource tracker outlived their driver"
    finally:
        err = p.stderr.read().decode(errors="replace")
        p.stderr.close()
        for c in children:
            if _alive(c):
                os.kill(c, signal.SIGKILL)
    if sig == signal.SIGTERM:
        assert p.returncode == 143 and err.rstrip().endswith("interrupted (SIGTERM)") and "Traceback" not in err, err


def test_an_interrupted_batch_leaves_nothing_and_resumes(logs, tmp_path, capsys):
    """SIGTERM: exit 143, no temporary and no lock left in the study folder; the rerun skips the
    finished units and its table equals an uninterrupted run's."""
    out = tmp_path / "b"
    p, _ = _start_batch(logs, out)
    p.send_signal(signal.SIGTERM)
    p.wait(timeout=120)
    p.stderr.close()
    assert p.returncode == 143
    done = {q.name for q in (out / "parts").glob("*.json")}
    assert done and not [q for q in out.rglob("*") if ".partial" in q.name or q.name.endswith(".lock")]
    assert main(["batch", str(logs), "-o", str(out), "--workers", "2", "--frames-per-unit", "1", "--results"]) == 0
    err = capsys.readouterr().err
    assert f"{len(done)} already done" in err
    import pyarrow.parquet as pq

    assert pq.read_table(out / "frames.parquet").num_rows == 12
    assert len(list((out / "results").glob("*.results.mcap"))) == 2  # both logs' results, complete
    assert not [q for q in out.rglob("*") if q.name.startswith(".")]
