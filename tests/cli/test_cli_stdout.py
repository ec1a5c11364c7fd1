"""A standard output that cannot be written (docs/cli.md, "Exit status"): closed (``>&-``) or full
(``>/dev/full``). The command still finishes and publishes its file outputs; what it printed is lost,
which is one line ``error: …`` and exit 1 (0 when it printed nothing). A reader that goes away
(``| head``) still ends it quietly with 0."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from cli.main import main


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("stdout")
    log = d / "log.mcap"
    assert main(["synth", "-o", str(log), "--parts", "rods", "--frames", "1", "--seed", "2", "--size", "128x96"]) == 0
    from annotate.store import LabelStore

    with LabelStore(d / "labels.sqlite") as store:
        store.add_log(log)
    return log, d / "labels.sqlite"


def _commands(log: Path, db: Path, out: Path) -> dict[str, tuple[list[str], list[Path], int]]:
    """name -> (argv, file outputs, exit status when stdout is lost)"""
    return {
        "topics": (["topics", str(log)], [], 1),
        "labels list": (["labels", "list", str(log), "--db", str(db)], [], 1),
        "--version": (["--version"], [], 1),
        "synth --help": (["synth", "--help"], [], 1),
        "synth": (["synth", "-o", str(out / "s.mcap"), "--size", "128x96"], [out / "s.mcap"], 0),
        "replay --out": (["replay", str(log), "--out", str(out / "r.mcap")], [out / "r.mcap", out / "r.config.toml"], 1),
    }


def _run(argv: list[str], how: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "cli", *argv]
    if how == "closed":
        return subprocess.run(["sh", "-c", 'exec "$@" >&-', "sh", *cmd], stderr=subprocess.PIPE, text=True,
                              timeout=600)
    with open("/dev/full", "w") as full:
        return subprocess.run(cmd, stdout=full, stderr=subprocess.PIPE, text=True, timeout=600)


@pytest.mark.parametrize("how", ["closed", "full"])
@pytest.mark.parametrize("name", ["topics", "labels list", "--version", "synth --help", "synth", "replay --out"])
def test_an_unwritable_stdout_is_one_line_after_the_file_outputs(files, tmp_path, name, how):
    log, db = files
    argv, outputs, status = _commands(log, db, tmp_path)[name]
    r = _run(argv, how)
    assert "Traceback" not in r.stderr and "Exception ignored" not in r.stderr, r.stderr
    assert r.returncode == status, r.stderr
    errors = [ln for ln in r.stderr.splitlines() if ln.startswith("error:")]
    if status:
        reason = "it is closed" if how == "closed" else "no space left on the device"
        assert errors == [f"error: the standard output could not be written ({reason}): what the command printed "
                          "is lost; its file outputs are complete"], r.stderr
    else:
        assert errors == []
    for out in outputs:  # complete, under their final names
        if out.suffix == ".mcap":
            assert main(["topics", str(out), "--check"]) == 0
        else:
            assert out.stat().st_size > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in outputs)  # nothing else


def test_a_reader_that_goes_away_is_still_quiet(files):
    log, _ = files
    r = subprocess.run(f'"{sys.executable}" -m cli topics "{log}" | head -c 1 >/dev/null; echo "${{PIPESTATUS[0]}}"',
                       shell=True, executable="/bin/bash", capture_output=True, text=True, timeout=600)
    assert r.stdout.strip() == "0" and r.stderr == "", r
