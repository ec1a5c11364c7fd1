"""`zcut batch` on local processes: one table of every frame, resumable, damage per log, bad input."""

from __future__ import annotations

import json
import re
import shutil

import pyarrow.parquet as pq
import pytest
from cli_helpers import run_cli, synth_logs

SIZE = "120x180"



@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    return synth_logs(tmp_path_factory.mktemp("batch_logs"), (("a", "rods", 3, 1), ("b", "spheres", 2, 2)), size=SIZE)


def test_batch_table_resume_and_summary(logs, tmp_path, capsys):
    out = tmp_path / "out"
    rc, _, err = run_cli(capsys, "batch", logs, "-o", out, "--workers", "2", "--frames-per-unit", "1", "--json")
    assert rc == 0, err
    t = pq.read_table(out / "frames.parquet")
    rows = t.to_pylist()
    assert sorted((r["log"], r["frame"]) for r in rows) == [("a.mcap", 0), ("a.mcap", 1), ("a.mcap", 2),
                                                          ("b.mcap", 0), ("b.mcap", 1)]
    for c in ("stamp_ns", "valid_px", "zcut", "sor", "both", "above_rim", "clusters", "fitness",
              "zcut_tp", "zcut_fp", "zcut_fn", "sor_tp", "union_fn", "intersection_tp", "t_zcut_s"):
        assert c in t.column_names
    assert all(r["scored"] for r in rows)
    s = json.loads((out / "summary.json").read_text())
    assert s["totals"]["frames"] == 5 and not s["data_loss"]
    assert set(s["accuracy"]["pooled"]) == {"zcut", "sor", "union", "intersection"}
    ci = s["accuracy"]["pooled"]["zcut"]["ci95"]["recall"]
    assert ci[0] <= s["accuracy"]["pooled"]["zcut"]["recall"] <= ci[1]
    # the same counts as a sequential replay of each log
    for name in ("a", "b"):
        rc, outp, _ = run_cli(capsys, "replay", logs / f"{name}.mcap", "--json")
        for fr in json.loads(outp)["frames"]:
            r = next(r for r in rows if r["log"] == f"{name}.mcap" and r["frame"] == fr["index"])
            assert (r["zcut"], r["sor"], r["both"]) == (fr["zcut"], fr["sor"], fr["both"])
    # a rerun skips everything already done and gives the same table
    rc, _, err = run_cli(capsys, "batch", logs, "-o", out, "--workers", "1", "--frames-per-unit", "1")
    n = int(re.search(r"(\d+) unit\(s\) of work", err).group(1))  # whole chunks: small logs have one
    assert rc == 0 and f"{n} unit(s) of work, {n} already done" in err
    t2 = pq.read_table(out / "frames.parquet").drop_columns([c for c in t.column_names if c.startswith("t_")])
    assert t2.equals(t.drop_columns([c for c in t.column_names if c.startswith("t_")]))
    # an interrupted run (a unit's part lost) redoes only that unit
    part = sorted((out / "parts").glob("*.json"))[0]
    part.unlink()
    rc, _, err = run_cli(capsys, "batch", logs, "-o", out, "--workers", "1", "--frames-per-unit", "1")
    assert rc == 0 and f"{n - 1} already done" in err and pq.read_table(out / "frames.parquet").num_rows == 5
    # another config is a new run, not a mix
    rc, _, err = run_cli(capsys, "batch", logs, "-o", out, "--step", "0.3", "--frames-per-unit", "1")
    assert rc == 1 and "other options" in err and len(err.strip().splitlines()) == 1


def test_a_damaged_log_does_not_stop_the_others(logs, tmp_path, capsys):
    d = tmp_path / "in"
    d.mkdir()
    shutil.copy(logs / "a.mcap", d / "a.mcap")
    data = (logs / "b.mcap").read_bytes()
    (d / "b.mcap").write_bytes(data[: len(data) * 2 // 3])  # truncated: its last frame is lost
    (d / "c.mcap").write_bytes(b"not an mcap file at all")
    rc, out, err = run_cli(capsys, "batch", d, "-o", tmp_path / "out", "--workers", "2", "--json")
    assert rc == 3, err
    s = json.loads(out)
    by = {e["log"].rsplit("/", 1)[-1]: e for e in s["logs"]}
    assert by["a.mcap"]["frames"] == 3 and not by["a.mcap"]["damage"] and not by["a.mcap"]["errors"]
    assert by["b.mcap"]["damage"] or by["b.mcap"]["errors"]
    assert by["c.mcap"]["errors"] and "warning:" in err and "Traceback" not in err


@pytest.mark.parametrize("argv, msg", [
    (["{empty}"], "holds no .mcap log"),
    (["{nothing}"], "no such file or folder"),
    (["{text}"], "not an MCAP log"),
    (["{a}", "--workers", "-1"], "--workers must be >= 0 (0: run in this process), got -1"),
    (["{a}", "--region", "table"], "--region must be one of zone, valid"),
    (["{a}", "--ray", "127.0.0.1:1", "--workers", "2"], "--workers is for local processes"),
])
def test_bad_input_is_a_one_line_error_before_any_work(logs, tmp_path, capsys, argv, msg):
    (tmp_path / "empty").mkdir()
    (tmp_path / "notes.txt").write_text("x")
    subst = {"{empty}": tmp_path / "empty", "{nothing}": tmp_path / "nope", "{text}": tmp_path / "notes.txt",
             "{a}": logs / "a.mcap"}
    args = [str(subst.get(a, a)) for a in argv]
    rc, _, err = run_cli(capsys, "batch", *args, "-o", tmp_path / "out")
    assert rc == 1 and msg in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "out" / "frames.parquet").exists()
