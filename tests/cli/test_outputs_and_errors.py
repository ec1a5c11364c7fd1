"""docs/cli.md: outputs never replace inputs, --force, atomic writes; one-line errors for what a user can
cause; what a newcomer tripped over (issue 11)."""

from __future__ import annotations

import hashlib
import os
import stat
import subprocess
import sys

import pytest
from cli_helpers import run_cli

from cli.main import main
from replay.outputs import AtomicOutput, OutputError, OutputPlan

SIZE = "90x120"



def _sha(p) -> str:
    from pathlib import Path

    return hashlib.sha256(Path(p).read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    d = tmp_path_factory.mktemp("out_logs")
    p = d / "log.mcap"
    assert main(["synth", "-o", str(p), "--parts", "rods", "--frames", "2", "--seed", "1", "--size", SIZE]) == 0
    return p


# ------------------------------------------------------------------ the OutputPlan and AtomicOutput


def test_outputs_with_undecodable_names_are_written(tmp_path, log, capsys):
    """A file name with bytes that are not UTF-8 (fuzz: Rerun's writer, in Rust, took only UTF-8
    paths and the run ended in a UnicodeEncodeError): the temporary file has a UTF-8 name and the
    rename gives the output the user's name."""
    name = os.fsdecode(b"\xff\xfeout.rrd")
    run = subprocess.run([sys.executable, "-m", "cli", "replay", str(log), "--frames", "0:1",
                          "--rrd", str(tmp_path / name)], capture_output=True)
    assert run.returncode == 0, run.stderr.decode(errors="replace")
    assert b"wrote rrd" in run.stderr
    assert os.fsencode(tmp_path / name) in [os.fsencode(p) for p in tmp_path.iterdir()]
    assert not [p for p in tmp_path.iterdir() if ".partial" in p.name]


def test_output_plan_refuses_every_alias_of_an_input(tmp_path):
    src = tmp_path / "in.mcap"
    src.write_bytes(b"data")
    hard = tmp_path / "hard.mcap"
    os.link(src, hard)
    soft = tmp_path / "soft.mcap"
    soft.symlink_to(src)
    plan = OutputPlan([src], force=True)
    for alias in (src, hard, soft, tmp_path / "." / "in.mcap"):
        with pytest.raises(OutputError, match="input"):
            plan.add(alias, "the results file")
    plan.add(tmp_path / "out.mcap", "the results file")
    with pytest.raises(OutputError, match="would be the same file"):
        plan.add(tmp_path / "out.mcap", "the .rrd")


@pytest.mark.parametrize("case, match", [
    ("exists", r"exists \(use --force to replace it\)"),
    ("folder", "exists and is a folder"),
    ("fifo", "exists and is not a regular file"),
    ("missing_dir", "does not exist"),
    ("under_file", "is not a folder"),
    ("dangling", "dangling symbolic link"),
])
def test_output_plan_refuses_what_would_destroy_data(tmp_path, case, match):
    target = tmp_path / "out.mcap"
    if case == "exists":
        target.write_text("mine")
    elif case == "folder":
        target.mkdir()
    elif case == "fifo":
        os.mkfifo(target)
    elif case == "missing_dir":
        target = tmp_path / "nope" / "out.mcap"
    elif case == "under_file":
        (tmp_path / "f").write_text("x")
        target = tmp_path / "f" / "out.mcap"
    elif case == "dangling":
        target.symlink_to(tmp_path / "gone")
    with pytest.raises(OutputError, match=match):
        OutputPlan([], force=case != "exists").add(target, "the log")


def test_atomic_output_never_touches_a_users_partial_file_and_cleans_up(tmp_path):
    target = tmp_path / "out.mcap"
    mine = tmp_path / "out.mcap.partial"
    mine.write_text("a user's own file")
    with pytest.raises(RuntimeError):
        with AtomicOutput(target) as out:
            out.temp.write_text("half")
            raise RuntimeError("the work failed")
    assert not target.exists() and mine.read_text() == "a user's own file"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.mcap.partial"]
    with AtomicOutput(target) as out:
        out.temp.write_text("done")
    assert target.read_text() == "done" and stat.S_IMODE(target.stat().st_mode) & 0o044  # readable like any file


# ------------------------------------------------------------------ the commands


@pytest.mark.parametrize("opt", ["--out", "--rrd"])
def test_replay_refuses_an_output_that_is_the_input_before_any_work(log, tmp_path, capsys, opt):
    before = _sha(log)
    link = tmp_path / "link.mcap"
    link.symlink_to(log)
    for target in (log, link):
        rc, out, err = run_cli(capsys, "replay", log, opt, target)
        assert rc == 1 and "input" in err and len(err.strip().splitlines()) == 1 and out == ""
    assert _sha(log) == before


def test_replay_needs_force_to_replace_and_names_the_wrong_path(log, tmp_path, capsys):
    res = tmp_path / "res.mcap"
    res.write_text("old results")
    rc, _, err = run_cli(capsys, "replay", log, "--out", res)
    assert rc == 1 and "use --force" in err and res.read_text() == "old results"
    rc, _, err = run_cli(capsys, "replay", log, "--out", res, "--force")
    assert rc == 0 and res.read_bytes()[:8] == b"\x89MCAP0\r\n"
    rc, _, err = run_cli(capsys, "replay", log, "--rrd", "/nonexistent/x.rrd")
    assert rc == 1 and "/nonexistent" in err and "config.toml" not in err
    # the config written beside an output is an output too
    cfg = tmp_path / "r.config.toml"
    cfg.write_text("[zcut]\nmax_area_px = 5.0\n")
    rc, _, err = run_cli(capsys, "replay", log, "--config", cfg, "--rrd", tmp_path / "r.rrd")
    assert rc == 1 and "input" in err and cfg.read_text() == "[zcut]\nmax_area_px = 5.0\n"


def test_record_and_synth_refuse_to_clobber(log, tmp_path, capsys, real_data):
    out = tmp_path / "x.mcap"
    out.write_text("keep me")
    for argv in (["record", real_data / "mosd_test16.pcd", "-o", out], ["synth", "-o", out, "--size", "8x8"]):
        rc, _, err = run_cli(capsys, *argv)
        assert rc == 1 and "use --force" in err and out.read_text() == "keep me"
    rc, _, err = run_cli(capsys, "record", real_data / "mosd_test16.pcd", "-o", "/dev/null", "--force")
    assert rc == 1 and "not a regular file" in err
    for argv, msg in ((["--period", "1e308"], "--period must be > 0"),
                      (["--stamp-start", "3e9"], "the ROS 2 time range"),
                      (["--stamp-start", "2147483640", "--period", "10"], "goes past the ROS 2 time range")):
        rc, _, err = run_cli(capsys, "record", real_data / "mosd_test16.pcd", real_data / "mosd_test20.pcd",
                          "-o", tmp_path / "y.mcap", *argv)
        assert rc == 1 and msg in err and "Traceback" not in err


def test_bin_model_refuses_a_filled_bin_unless_forced(log, tmp_path, capsys):
    rc, _, err = run_cli(capsys, "bin-model", log, "-o", tmp_path / "b.ply")
    assert rc == 1 and "not of the empty bin" in err and not (tmp_path / "b.ply").exists()


def test_replaying_a_results_file_says_so(log, tmp_path, capsys):
    res = tmp_path / "res.mcap"
    assert run_cli(capsys, "replay", log, "--out", res, "--out-cloud")[0] == 0
    rc, _, err = run_cli(capsys, "replay", res, "--frames", "0")
    assert rc == 0 and "is a results file of zcut replay" in err


def test_labels_import_creates_the_store_and_registers_the_log(log, tmp_path, capsys):
    from annotate_helpers import label_with_truth

    from annotate.label_files import export_labels
    from annotate.store import LabelStore

    db = tmp_path / "a.sqlite"
    with LabelStore(db) as store:
        rec, _ = label_with_truth(store, log)
        export_labels(store, rec, tmp_path / "l.mcap", annotator="ann")
    fresh = tmp_path / "new.sqlite"
    rc, out, err = run_cli(capsys, "labels", "import", tmp_path / "l.mcap", "--db", fresh, "--log", log)
    assert rc == 0, err
    assert "registered" in out and "imported 2 label(s)" in out
    rc, out, _ = run_cli(capsys, "labels", "list", log, "--db", fresh)
    assert rc == 0 and "ann: 2 frame(s) labelled" in out


def test_version_and_a_closed_stdout():
    out = subprocess.run([sys.executable, "-m", "cli", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.startswith("zcut ")
    # `zcut --help | head -1`: the reader goes away; no traceback
    p = subprocess.run(f"{sys.executable} -m cli --help | head -c 10", shell=True, capture_output=True,
                       text=True)
    assert "Traceback" not in p.stderr and "BrokenPipe" not in p.stderr


def test_connect_to_not_a_url_and_a_binary_config(log, tmp_path, capsys):
    rc, _, err = run_cli(capsys, "replay", log, "--connect", "not a url")
    assert rc == 1 and "expected a viewer URL" in err
    b = tmp_path / "b.toml"
    b.write_bytes(os.urandom(256))
    rc, _, err = run_cli(capsys, "replay", log, "--config", b)
    assert rc == 1 and "b.toml" in err and len(err.strip().splitlines()) == 1
