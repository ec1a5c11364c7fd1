"""What `zcut demo` says and refuses (issue 35 items 18 and 22): a missing parent of --out-dir is
refused like every other command's output folder; an interval that holds nearly all of [0, 1] at the
demo's 3 frames is said to be uninformative; the suggested --annotator is never an empty string."""

from __future__ import annotations

import getpass
import shlex
from pathlib import Path

from cli_helpers import run_cli

from cli.commands import demo


def test_a_missing_parent_of_out_dir_is_refused_in_one_line(tmp_path, capsys):
    rc, _, err = run_cli(capsys, "demo", "--out-dir", tmp_path / "missing" / "x")
    assert rc == 1 and err.strip().splitlines()[-1] == (f"error: --out-dir {tmp_path / 'missing' / 'x'}: "
                                                         f"the folder {tmp_path / 'missing'} does not exist"), err
    assert not (tmp_path / "missing").exists()
    (tmp_path / "file").write_text("x")
    rc, _, err = run_cli(capsys, "demo", "--out-dir", tmp_path / "file")
    assert rc == 1 and err.strip().endswith("exists and is not a folder"), err


def _report(precision_ci, n=3):
    return {"frames": [{}] * n, "pooled": {
        "zcut": {"ci95": {"precision": precision_ci, "recall": [0.099, 0.722], "f1": [0.163, 0.845]}},
        "sor": {"ci95": {"precision": precision_ci, "recall": [0.042, 0.36], "f1": [None, None]}}}}


def test_an_interval_over_nearly_all_of_0_1_is_said_uninformative():
    note = demo.uninformative_note(_report([0.0, 1.0]))
    assert note == ("note: intervals uninformative at 3 frames (precision of zcut, sor: each holds 90 % or more "
                    "of [0, 1]); more frames narrow them, see docs/coverage.md")
    assert demo.uninformative_note(_report([0.6, 0.98])) is None


def _annotator(monkeypatch, tmp_path):
    for name in ("USER", "LOGNAME", "LNAME", "USERNAME"):  # a container's environment
        monkeypatch.delenv(name, raising=False)
    text = demo.next_steps(sample=Path("/s.mcap"), bin_model=None, rrd=tmp_path / "d.rrd",
                           results=tmp_path / "r.mcap", out_dir=tmp_path)
    line = next(ln for ln in text.splitlines() if " annotate " in ln)
    words = shlex.split(line)
    return words[words.index("--annotator") + 1]


def test_the_suggested_annotator_is_never_empty(monkeypatch, tmp_path):
    assert _annotator(monkeypatch, tmp_path) == getpass.getuser() != ""  # from the passwd entry

    def no_user():
        raise KeyError("getpwuid(): uid not found: 4242")

    monkeypatch.setattr(getpass, "getuser", no_user)
    assert _annotator(monkeypatch, tmp_path) == "me"
