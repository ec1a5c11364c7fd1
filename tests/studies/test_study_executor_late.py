"""``zcut batch`` and ``zcut sweep``: bad input is one line before the executor is made (no worker started,
no Ray cluster connected to: an unreachable one is not even reached) and before DIR is created — as ``zcut
compare`` (tests/studies/test_compare.py)."""

from __future__ import annotations

import pytest
from annotate_helpers import write_spike_log
from cli_helpers import run_cli

from annotate.store import LabelStore


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("late")
    log, other = d / "scan.mcap", d / "other.mcap"
    write_spike_log(log, frames=2)
    write_spike_log(other, frames=2, seed=5)
    db = d / "labels.sqlite"
    with LabelStore(db) as s:  # the store holds the other log only
        s.add_log(other)
    return log, db


@pytest.mark.parametrize("command", ["batch", "sweep"])
@pytest.mark.parametrize("extra, message", [
    (("--labels", "DB"), "no labels of scan.mcap"),
    (("--truth", "paper"), "--truth paper"),
])
@pytest.mark.parametrize("where", [("--workers", "1"), ("--ray", "127.0.0.1:1")])
def test_bad_input_is_one_line_before_anything_starts(logs, tmp_path, capsys, monkeypatch, command, extra, message,
                                                      where):
    from studies import executors

    log, db = logs
    made = []
    real = executors.make_executor
    monkeypatch.setattr(executors, "make_executor", lambda **kw: made.append(kw) or real(**kw))
    args = [str(db) if x == "DB" else x for x in extra]
    rc, _, err = run_cli(capsys, command, log, "-o", tmp_path / "x", *where, *args)
    assert rc == 1, err
    lines = [ln for ln in err.strip().splitlines() if ln.startswith("error: ")]
    assert len(lines) == 1 and message in lines[0], err
    assert made == []  # nothing started
    assert not (tmp_path / "x").exists()  # nothing left
