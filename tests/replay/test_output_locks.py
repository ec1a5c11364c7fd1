"""One writer per output (docs/cli.md, outputs): a planned output is locked while its command writes
it, a second writer is refused in one line, a lock or a temporary left by a killed process is taken
over by the next run; ``--rrd r.rrd --out r.mcap`` share one config beside them."""

from __future__ import annotations

import gc
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cli_helpers import run_cli, synth_with_bin_model

from replay.outputs import (
    AtomicOutput,
    OutputBusyError,
    OutputLock,
    OutputPlan,
    lock_path_for,
    remove_stale_temporaries,
)

SIZE = "90x120"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A small synthetic log, an empty-bin log, its bin model and a label store with labels."""
    from annotate_helpers import label_with_truth

    from annotate.store import LabelStore

    d = tmp_path_factory.mktemp("lock_inputs")
    log, empty, model = synth_with_bin_model(d, parts="rods", seed=1, size=SIZE, empty_seed=2)
    db = d / "labels.sqlite"
    with LabelStore(db) as store:
        label_with_truth(store, log)
    return {"log": log, "empty": empty, "model": model, "db": db, "pcd": None}


def _leftovers(folder: Path) -> list[str]:
    """zcut's hidden files in ``folder``: temporaries and lock files."""
    return sorted(p.name for p in folder.iterdir() if p.name.startswith(".")
                  and (".partial" in p.name or p.name.endswith(".zcut.lock")))


# ------------------------------------------------------------------ the lock itself


def test_a_planned_output_is_locked_until_its_plan_closes(tmp_path):
    out = tmp_path / "r.mcap"
    with OutputPlan([]) as first:
        first.add(out, "the results file")
        assert lock_path_for(out).is_file()
        with pytest.raises(OutputBusyError, match=rf"{out}: another zcut process \(pid {os.getpid()}\) is writing "
                                                  r"the results file"):
            OutputPlan([]).add(out, "the results file")
    assert not lock_path_for(out).exists()  # the holder removes its lock file
    with OutputPlan([]) as again:
        again.add(out, "the results file")


def _hold_and_wait(code: str) -> subprocess.Popen:
    """A python process that runs ``code`` (holding outputs), prints "held" and sleeps."""
    p = subprocess.Popen([sys.executable, "-c", code + "\nprint('held', flush=True)\nimport time\ntime.sleep(600)"],
                         stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "held"
    return p


def test_a_lock_and_temporaries_left_by_kill_9_are_taken_over(tmp_path):
    """kill -9 leaves the lock file and the temporary: the kernel dropped the lock with the process,
    so the next writer takes the lock file over, removes the dead writer's temporary (and not a live
    writer's, nor another output's, nor a user's file) and its own lock file when done."""
    out = tmp_path / "o.rrd"
    dead = _hold_and_wait(f"from replay.outputs import OutputPlan, AtomicOutput\n"
                          f"p = OutputPlan([]); p.add({str(out)!r}, 'the .rrd')\n"
                          f"a = AtomicOutput({str(out)!r}); a.temp.write_bytes(b'half')")
    alive = _hold_and_wait(f"from replay.outputs import AtomicOutput\n"
                           f"a = AtomicOutput({str(tmp_path / 'o.rrd')!r})")  # a live writer's temporary
    other = _hold_and_wait(f"from replay.outputs import AtomicOutput\n"
                           f"a = AtomicOutput({str(tmp_path / 'o.x.rrd')!r})")
    (tmp_path / "o.rrd.partial").write_text("a user's own file")
    try:
        with pytest.raises(OutputBusyError):
            OutputPlan([]).add(out, "the .rrd")
        dead.send_signal(signal.SIGKILL)
        dead.wait()
        before = _leftovers(tmp_path)
        assert lock_path_for(out).name in before and len([n for n in before if ".partial" in n]) == 3
        with OutputPlan([]) as plan:
            plan.add(out, "the .rrd")  # takes the dead writer's lock over, removes its temporary
            left = _leftovers(tmp_path)
            assert len([n for n in left if ".partial" in n]) == 2  # the live writers' ones
            with AtomicOutput(out) as w:
                w.temp.write_bytes(b"complete")
        assert out.read_bytes() == b"complete" and (tmp_path / "o.rrd.partial").read_text() == "a user's own file"
        assert not lock_path_for(out).exists()
    finally:
        for p in (dead, alive, other):
            p.kill()
            p.wait()
            p.stdout.close()
    assert len(remove_stale_temporaries(out)) == 1 and len(remove_stale_temporaries(tmp_path / "o.x.rrd")) == 1
    assert _leftovers(tmp_path) == []


# ------------------------------------------------------------------ every command that writes

PCD = """# .PCD v0.7
VERSION 0.7
FIELDS x y z
SIZE 4 4 4
TYPE F F F
COUNT 1 1 1
WIDTH 2
HEIGHT 2
VIEWPOINT 0 0 0 1 0 0 0
POINTS 4
DATA ascii
0 0 1
0.01 0 1
0 0.01 1
0.01 0.01 1
"""


def _commands(f, out: Path) -> dict:
    """command -> (argv, the output another process holds, its lock file)."""
    def file(p):
        return p, lock_path_for(p)

    def folder(p):
        p.mkdir(exist_ok=True)
        return p, p / ".zcut.lock"

    return {
        "replay --out": (["replay", f["log"], "--out", out / "r.mcap"], *file(out / "r.mcap")),
        "replay --rrd": (["replay", f["log"], "--rrd", out / "o.rrd"], *file(out / "o.rrd")),
        "replay config beside": (["replay", f["log"], "--rrd", out / "o.rrd"], *file(out / "o.config.toml")),
        "synth": (["synth", "-o", out / "s.mcap", "--size", "8x8"], *file(out / "s.mcap")),
        "record": (["record", out / "in.pcd", "-o", out / "rec.mcap"], *file(out / "rec.mcap")),
        "bin-model": (["bin-model", f["empty"], "-o", out / "b.ply"], *file(out / "b.ply")),
        "labels export": (["labels", "export", f["log"], "--db", f["db"], "-o", out / "l.mcap"], *file(out / "l.mcap")),
        "batch -o": (["batch", f["log"], "-o", out / "batch", "--workers", "1"], *folder(out / "batch")),
        "sweep -o": (["sweep", f["log"], "-o", out / "sweep", "--workers", "1"], *folder(out / "sweep")),
        "demo": (["demo", "--out-dir", out / "demo"], *file(out / "demo" / "zcut_demo.rrd")),
    }


COMMANDS = ["replay --out", "replay --rrd", "replay config beside", "synth", "record", "bin-model", "labels export",
            "batch -o", "sweep -o", "demo"]


@pytest.mark.parametrize("command", COMMANDS)
def test_every_command_that_writes_refuses_an_output_another_process_writes(files, tmp_path, capsys, command,
                                                                           monkeypatch):
    """The lock of the output is held (as another zcut process would hold it): the command exits 1
    with one line naming the output, before any work, and leaves the output and the lock alone."""
    monkeypatch.setenv("ZCUT_CACHE", str(tmp_path / "cache"))  # the demo refuses before it synthesises
    out = tmp_path / "out"
    (out / "demo").mkdir(parents=True)
    (out / "in.pcd").write_text(PCD)
    argv, held, lock_file = _commands(files, out)[command]
    with OutputLock(held, lock_file=lock_file):
        rc, _, err = run_cli(capsys, *argv)
        assert lock_file.is_file()
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert rc == 1 and len(lines) == 1, err
    assert str(held) in lines[0] and "another zcut process" in lines[0] and "Traceback" not in err
    assert not (held.exists() and held.is_file()) and not (tmp_path / "cache").exists()
    assert [p for p in out.rglob("*") if ".partial" in p.name] == []


def test_two_replays_of_one_output_at_once_one_is_refused(files, tmp_path):
    """Two real processes, the second started while the first writes: the second exits 1 in one line,
    the first completes its outputs."""
    argv = [sys.executable, "-m", "cli", "replay", str(files["log"]), "--out", str(tmp_path / "r.mcap"),
            "--rrd", str(tmp_path / "o.rrd")]
    first = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not lock_path_for(tmp_path / "r.mcap").exists():  # it holds its outputs
        assert first.poll() is None and time.monotonic() < deadline
        time.sleep(0.02)
    second = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    _, err1 = first.communicate(timeout=300)
    assert first.returncode == 0, err1
    assert second.returncode == 1 and second.stderr.count("\n") == 1, second.stderr
    assert "another zcut process" in second.stderr and "is writing" in second.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.config.toml", "o.rrd", "r.config.toml", "r.mcap"]


def test_rrd_and_results_of_one_stem_share_one_config(files, tmp_path, capsys):
    """``--rrd r.rrd --out r.mcap``: the config beside both is one file (the same resolved config),
    written once, instead of a refusal."""
    rc, _, err = run_cli(capsys, "replay", files["log"], "--rrd", tmp_path / "r.rrd", "--out", tmp_path / "r.mcap")
    assert rc == 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.config.toml", "r.mcap", "r.rrd"]
    assert err.count("r.config.toml") == 1 and "[zcut]" in (tmp_path / "r.config.toml").read_text()
    # the same stem in two folders is two files, as before
    (tmp_path / "b").mkdir()
    rc, _, err = run_cli(capsys, "replay", files["log"], "--rrd", tmp_path / "b" / "r.rrd", "--out",
                         tmp_path / "r.mcap", "--force")
    assert rc == 0 and (tmp_path / "b" / "r.config.toml").is_file(), err


def test_a_writer_cut_off_before_its_descriptor_is_deleted_quietly(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A signal raising inside ``AtomicOutput.__init__`` before the descriptor's attribute exists (a batch's
    worker at SIGTERM): the half-made object's ``__del__`` says nothing (it printed an AttributeError after
    "interrupted (SIGTERM)", the full run of 2026-12-07b) and nothing is left in the folder."""
    import replay.outputs as outputs

    def cut(*a: object) -> Path:
        raise KeyboardInterrupt

    monkeypatch.setattr(outputs, "Path", cut)
    seen: list[object] = []
    monkeypatch.setattr(sys, "unraisablehook", seen.append)
    with pytest.raises(KeyboardInterrupt):
        AtomicOutput(tmp_path / "o.rrd")
    for cls in (AtomicOutput, OutputLock):  # the lock's __del__ reads its descriptor the same way
        half = cls.__new__(cls)
        half.__del__()
        del half
    gc.collect()
    assert seen == []
    assert list(tmp_path.iterdir()) == []
