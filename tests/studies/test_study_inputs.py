"""A study's inputs checked like every other command's (issue 35 items 5 and 22): a `.mcap` symlink
that leads nowhere (dangling, or a loop) in a folder of logs is left out with a warning naming it and
exit 3, as an unreadable log is, never dropped silently."""

from __future__ import annotations

import json
import os
import shutil

import pytest
from cli_helpers import run_cli

from cli.main import main

SIZE = "120x180"


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    p = tmp_path_factory.mktemp("input_logs") / "a.mcap"
    assert main(["synth", "-o", str(p), "--parts", "rods", "--frames", "2", "--seed", "1", "--size", SIZE]) == 0
    return p


def _folder(tmp_path, log):
    d = tmp_path / "in"
    d.mkdir()
    shutil.copy(log, d / "a.mcap")
    os.symlink("/nonexistent/share/b.mcap", d / "b.mcap")  # a log on an unmounted share
    os.symlink("c.mcap", d / "c.mcap")  # a loop
    return d


def _warnings(err):
    return [ln for ln in err.splitlines() if ln.startswith("warning:")]


@pytest.mark.parametrize("command", ["batch", "sweep"])
def test_a_symlink_to_no_log_in_a_folder_is_a_warning_and_exit_3(log, tmp_path, capsys, command):
    d = _folder(tmp_path, log)
    opts = ["--step", "0.2", "--rho", "0.07", "--no-report"] if command == "sweep" else []
    rc, _, err = run_cli(capsys, command, d, "-o", tmp_path / "out", "--workers", "0", *opts)
    assert rc == 3, err
    assert "Traceback" not in err
    warned = "\n".join(_warnings(err))
    assert (f"warning: {d / 'b.mcap'}: cannot be read: a dangling symlink: /nonexistent/share/b.mcap does not "
            "exist (left out; exit 3 at the end)") in warned, err
    assert f"warning: {d / 'c.mcap'}: cannot be read: a symlink loop (left out; exit 3 at the end)" in warned, err
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    errors = {e["log"].rsplit("/", 1)[-1]: e.get("errors") or e.get("error") for e in summary["logs"]}
    assert set(errors) == {"a.mcap", "b.mcap", "c.mcap"} and not errors["a.mcap"] and errors["b.mcap"] and errors["c.mcap"]
    assert (summary["totals"]["frames"] if command == "batch" else summary["frames"]) == 2


def test_a_symlink_to_no_log_named_alone_is_a_one_line_error(log, tmp_path, capsys):
    os.symlink(tmp_path / "gone.mcap", tmp_path / "x.mcap")
    rc, _, err = run_cli(capsys, "batch", tmp_path / "x.mcap", "-o", tmp_path / "out", "--workers", "0")
    assert rc == 1 and err.strip().splitlines()[-1] == (f"error: no usable log among 1 input(s): cannot be read: "
                                                         f"a dangling symlink: {tmp_path / 'gone.mcap'} does not exist")


def _two_annotators(db, log):
    import numpy as np
    from annotate_helpers import added_frames

    from annotate.store import LabelStore

    with LabelStore(db) as s:
        for rec, fr, valid in added_frames(s, s.add_log(log), log):
            for who in ("ann", "bob"):
                s.save_label(rec, annotator=who, outliers=np.zeros(fr.shape, bool), reviewed=valid, base_revision=0)


@pytest.mark.parametrize("command", ["batch", "sweep"])
def test_a_label_store_of_two_annotators_needs_annotator_before_any_work(log, tmp_path, capsys, command):
    """As `zcut accuracy`: one line and exit 1 before any work, not exit 3 from every unit (issue 35
    item 22)."""
    db = tmp_path / "labels.sqlite"
    _two_annotators(db, log)
    rc, _, acc_err = run_cli(capsys, "accuracy", log, "--labels", db)
    assert rc == 1
    opts = ["--step", "0.2", "--rho", "0.07", "--no-report"] if command == "sweep" else []
    for extra, said in (([], acc_err.strip().splitlines()[-1]),
                        (["--annotator", "zoe"], "error: --annotator 'zoe': no labels by them in")):
        rc, _, err = run_cli(capsys, command, log, "-o", tmp_path / f"out{len(extra)}", "--workers", "0",
                             "--labels", db, *opts, *extra)
        assert rc == 1, err
        assert err.strip().splitlines()[-1].startswith(said), err
        assert not (tmp_path / f"out{len(extra)}").exists()  # refused before any work
    assert acc_err.strip().splitlines()[-1] == (f"error: {db} has labels by 2 annotators (ann, bob): "
                                                "choose one with --annotator")
    rc, _, err = run_cli(capsys, command, log, "-o", tmp_path / "ok", "--workers", "0", "--labels", db,
                         "--annotator", "bob", *opts)
    assert rc == 0, err
