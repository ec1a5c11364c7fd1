"""A sweep, a batch and true accuracy run as library calls, without a command line (issue 34): the
options objects carry the command line's defaults, and the results are what the commands print."""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from cli_helpers import run_cli

from annotate.accuracy import AccuracyOptions, AccuracyResult, format_accuracy_table, report_json
from annotate.accuracy import run as accuracy
from cli.main import build_parser, main
from studies import batch, sweep


@pytest.fixture(scope="module")
def log(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("library_calls") / "nuts.mcap"
    assert main(["synth", "-o", str(p), "--parts", "zinc_nuts", "--frames", "2", "--seed", "5", "--size", "150x240"]) == 0
    return p


def _parsed(*argv: str):
    return build_parser(argv[0], only=True).parse_args(list(argv))


def test_the_options_defaults_are_the_command_lines():
    from cli.commands import accuracy as accuracy_cmd
    from cli.commands import batch as batch_cmd
    from cli.commands import sweep as sweep_cmd

    assert sweep_cmd.options_of(_parsed("sweep", "a.mcap", "-o", "d")) == sweep.SweepOptions(inputs=("a.mcap",), out="d")
    assert batch_cmd.options_of(_parsed("batch", "a.mcap", "-o", "d")) == batch.BatchOptions(inputs=("a.mcap",), out="d")
    assert accuracy_cmd.options_of(_parsed("accuracy", "a.mcap")) == AccuracyOptions(log=Path("a.mcap"))
    given = sweep_cmd.options_of(_parsed("sweep", "a.mcap", "-o", "d", "--step", "0.1,0.2", "--grid", "radius=default",
                                         "--part", "zinc_nuts", "--no-report", "--no-study-points"))
    assert (given.step, given.grid, given.pipeline.part, given.report, given.study_points) == \
        ("0.1,0.2", ("radius=default",), "zinc_nuts", False, False)
    with pytest.raises(AttributeError):
        given.step = "0.3"  # type: ignore[misc]  # frozen


def test_a_sweep_as_a_library_call_is_the_commands(log, tmp_path, capsys):
    rc, out, err = run_cli(capsys, "sweep", log, "-o", tmp_path / "cmd", "--step", "0.2,0.5", "--workers", "0",
                           "--no-report")
    assert rc == 0, err
    result = sweep.run(sweep.SweepOptions(inputs=(str(log),), out=str(tmp_path / "lib"), step="0.2,0.5", workers=0,
                                          report=False))
    capsys.readouterr()
    assert result.summary is not None and not result.data_loss and result.out == tmp_path / "lib"
    assert result.tuned_path == tmp_path / "lib" / "tuned.toml"
    from cli.commands.sweep import _print

    _print(result.summary, result.tuned_path)
    printed = capsys.readouterr().out
    assert printed.replace(str(tmp_path / "lib"), str(tmp_path / "cmd")) == out
    assert "chosen" in out and "tuned config:" in out
    cmd_json = json.loads((tmp_path / "cmd" / "summary.json").read_text())
    lib_json = result.summary.to_json()
    for k in ("seconds", "reproduce"):
        cmd_json.pop(k), lib_json.pop(k)
    assert json.loads(json.dumps(lib_json)) == cmd_json
    t_cmd, t_lib = (pq.read_table(tmp_path / d / "sweep.parquet") for d in ("cmd", "lib"))
    assert t_lib.equals(t_cmd)


def test_a_batch_as_a_library_call_is_the_commands(log, tmp_path, capsys):
    rc, out, err = run_cli(capsys, "batch", log, "-o", tmp_path / "cmd", "--workers", "0")
    assert rc == 0, err
    result = batch.run(batch.BatchOptions(inputs=(str(log),), out=str(tmp_path / "lib"), workers=0))
    capsys.readouterr()
    assert not result.data_loss and result.table.num_rows == 2
    assert (result.frames_path, result.summary_path) == (tmp_path / "lib" / "frames.parquet",
                                                         tmp_path / "lib" / "summary.json")
    from cli.commands.batch import _print_table

    _print_table(result.summary)
    printed = capsys.readouterr().out

    def table(text: str) -> list[str]:  # the cost of this run (seconds, frames/s) differs between runs
        return [line for line in text.splitlines() if not line.startswith("this run:")]

    assert table(printed) == table(out) and "true accuracy over the scored region (zone) against " in out
    cmd_json = json.loads((tmp_path / "cmd" / "summary.json").read_text())
    lib_json = json.loads(json.dumps(result.summary.to_json()))
    assert (lib_json["totals"], lib_json["accuracy"]) == (cmd_json["totals"], cmd_json["accuracy"])


def test_accuracy_as_a_library_call_is_the_commands(log, capsys):
    rc, out, err = run_cli(capsys, "accuracy", log)
    assert rc == 0, err
    result = accuracy(AccuracyOptions(log=log))
    assert isinstance(result, AccuracyResult) and not result.data_loss and not result.from_results
    assert out == (f"truth: {result.truth}; predictions: {result.predictions}\n"
                   + format_accuracy_table(result.report, per_frame=False) + "\n")
    rc, out, err = run_cli(capsys, "accuracy", log, "--json")
    assert rc == 0 and out == report_json(result.report) + "\n"
