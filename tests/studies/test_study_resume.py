"""A resumed study whose input log changed content (issue 35 item 1): refused with one line naming the
log (its old and new frames would mix), started afresh with --force; a log renamed beside the new
content is not a change."""

from __future__ import annotations

import hashlib
import json
import shutil

import pyarrow.parquet as pq
import pytest
from cli_helpers import run_cli, synth_logs

SIZE = "120x180"


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    specs = (("old", "rods", 3, 1), ("new", "spheres", 2, 2))
    return synth_logs(tmp_path_factory.mktemp("resume_logs"), specs, size=SIZE)


def _sha(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _interrupt(out):
    """What a study killed midway leaves: its last unit's part missing."""
    parts = sorted((out / "parts").glob("*.json"))
    assert parts
    parts[-1].unlink()
    parts[-1].with_suffix(".parquet").unlink()


@pytest.mark.parametrize("command", ["batch", "sweep"])
def test_a_log_changed_under_a_resumed_study_is_refused_or_started_afresh(logs, tmp_path, capsys, command):
    opts = ["--workers", "0", "--frames-per-unit", "1"]
    if command == "sweep":
        opts += ["--step", "0.2", "--rho", "0.07", "--no-report"]
    table = "frames.parquet" if command == "batch" else "sweep.parquet"
    log, out = tmp_path / "in" / "log.mcap", tmp_path / "study"
    log.parent.mkdir()
    shutil.copy(logs / "old.mcap", log)
    rc, _, err = run_cli(capsys, command, log, "-o", out, *opts)
    assert rc == 0, err
    _interrupt(out)
    before = {p.name: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    shutil.copy(logs / "new.mcap", log)  # another log at the same path
    rc, _, err = run_cli(capsys, command, log, "-o", out, *opts)
    assert rc == 1, err
    (line,) = [ln for ln in err.splitlines() if not ln.startswith("zcut: compiling")]
    assert line.startswith(f"error: -o {out}: {log} changed since this study began (content sha256 "
                           f"{_sha(logs / 'old.mcap')[:12]}… then, {_sha(logs / 'new.mcap')[:12]}… now)"), line
    assert "--force starts it afresh" in line
    assert {p.name: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before  # nothing touched
    # --force: the study starts afresh, holding the new content's frames only
    rc, _, err = run_cli(capsys, command, log, "-o", out, *opts, "--force")
    assert rc == 0, err
    assert "changed since this study began" in err and "starts afresh" in err
    rows = pq.read_table(out / table).to_pylist()
    assert {r["log_sha256"] for r in rows} == {_sha(logs / "new.mcap")}
    assert sorted({r["frame"] for r in rows}) == [0, 1]
    run = json.loads((out / "run.json").read_text())
    assert run["paths"] == {str(log): _sha(logs / "new.mcap")} and list(run["logs"]) == [_sha(logs / "new.mcap")]
    summary = json.loads((out / "summary.json").read_text())
    assert [e["sha256"] for e in summary["logs"]] == [_sha(logs / "new.mcap")]
    # and it resumes as before
    rc, _, err = run_cli(capsys, command, log, "-o", out, *opts)
    assert rc == 0 and "already done" in err, err


def test_a_log_renamed_beside_new_content_is_not_a_change(logs, tmp_path, capsys):
    d, out = tmp_path / "in", tmp_path / "study"
    d.mkdir()
    shutil.copy(logs / "old.mcap", d / "log.mcap")
    rc, _, err = run_cli(capsys, "batch", d, "-o", out, "--workers", "0")
    assert rc == 0, err
    (d / "log.mcap").rename(d / "earlier.mcap")
    shutil.copy(logs / "new.mcap", d / "log.mcap")
    rc, _, err = run_cli(capsys, "batch", d, "-o", out, "--workers", "0")
    assert rc == 0, err
    rows = pq.read_table(out / "frames.parquet").to_pylist()
    assert sorted((r["log"], r["frame"]) for r in rows) == [("earlier.mcap", 0), ("earlier.mcap", 1),
                                                          ("earlier.mcap", 2), ("log.mcap", 0), ("log.mcap", 1)]
