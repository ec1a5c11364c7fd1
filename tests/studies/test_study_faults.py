"""What breaks studies in the field (docs/studies.md): a full disk names the output that had no
space; an unreadable log is left out by `zcut sweep` as by `zcut batch` (a warning, exit 3)."""

from __future__ import annotations

import json

import pytest
from cli_helpers import run_cli
from disk_helpers import small_disk

from cli.main import main


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    p = tmp_path_factory.mktemp("study_fault_logs") / "log.mcap"
    assert main(["synth", "-o", str(p), "--parts", "zinc_nuts", "--frames", "2", "--seed", "3",
                 "--size", "480x640"]) == 0  # its results file: ~8.6 MB
    return p


def test_batch_results_on_a_full_disk_name_the_results_file(log, tmp_path, capsys):
    with small_disk(tmp_path / "disk", "3m") as disk:
        rc, _, err = run_cli(capsys, "batch", log, "-o", disk / "b", "--workers", "1", "--results",
                               "--results-cloud")
        assert rc == 3, err
        warnings = [ln for ln in err.splitlines() if ln.startswith("warning:")]
        assert len(warnings) == 1 and "No space left on device" in warnings[0], err
        assert f"{disk / 'b' / 'results'}/log-" in warnings[0] and warnings[0].endswith(".results.mcap")
        assert not [p for p in disk.rglob("*") if p.name.startswith(".")]  # no temporary, no lock


def test_sweep_leaves_an_unreadable_log_out_and_goes_on(log, tmp_path, capsys):
    bad = tmp_path / "in"
    bad.mkdir()
    (bad / "c.mcap").write_bytes(b"not an mcap file at all")
    rc, out, err = run_cli(capsys, "sweep", log, bad / "c.mcap", "-o", tmp_path / "s", "--workers", "1",
                           "--step", "0.2", "--rho", "0.07", "--no-report")
    assert rc == 3, err
    assert f"warning: {bad / 'c.mcap'}:" in err and "left out; exit 3" in err and "Traceback" not in err
    summary = json.loads((tmp_path / "s" / "summary.json").read_text())
    assert summary["frames"] == 2 and (tmp_path / "s" / "tuned.toml").is_file()
    assert [e["log"] for e in summary["logs"] if e["error"]] == [str(bad / "c.mcap")]


def test_a_sweep_whose_every_unit_failed_is_data_loss_naming_the_failure(log, tmp_path, capsys, monkeypatch):
    """Workers that die on every unit (as an unprivileged user's did, unable to start) leave no frame to
    score: the sweep says the units failed and exits 3 like batch, not "no truth in any frame" (exit 1)."""
    from worker_helpers import kill_worker

    import studies.executors as executors

    class Dying(executors.LocalExecutor):
        def run(self, fn, units, job):
            return super().run(kill_worker, units, job)

    monkeypatch.setattr(executors, "make_executor", lambda workers, ray=False: Dying(1))
    rc, _, err = run_cli(capsys, "sweep", log, "-o", tmp_path / "s", "--workers", "1", "--step", "0.2",
                         "--rho", "0.07", "--no-report")
    assert rc == 3, err
    errors = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1 and "a unit of work failed" in errors[0] and "died twice" in errors[0], err
    assert "no truth" not in err and "Traceback" not in err
