"""`zcut sweep`: counts equal replay's at every grid point, tuned.toml replays, bad input refused."""

from __future__ import annotations

import json
import tomllib

import pyarrow.parquet as pq
import pytest
from cli_helpers import run_cli

from cli.main import main
from replay.logs import layout
from replay.logs.reader import LogReader
from studies.grid import parse_list


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    d = tmp_path_factory.mktemp("sweep_logs")
    p = d / "nuts.mcap"
    assert main(["synth", "-o", str(p), "--parts", "zinc_nuts", "--frames", "2", "--seed", "3", "--size", "150x240"]) == 0
    return p


@pytest.fixture(scope="module")
def swept(log, tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "out"
    assert main(["sweep", str(log), "-o", str(out), "--step", "0.2,0.5", "--max-depth", "10:40:4",
                 "--rho", "0.03,0.07", "--sor-k", "4,6", "--sor-std", "0.5,1", "--workers", "2", "--no-report"]) == 0
    return out


def test_counts_equal_replay_at_grid_points(log, swept, capsys):
    t = pq.read_table(swept / "sweep.parquet").to_pylist()
    # the paper's truth by default (the log has /ground_truth/off_surface), and every row says so
    assert {r["truth"] for r in t} == {"paper"}
    truth = {f.index: f.masks[layout.TRUTH_OFF_SURFACE] for f in LogReader(log).frames()}
    for step, depth, rho in [(0.2, 20.0, 0.07), (0.5, 40.0, 0.03), (0.5, 10.0, 0.07)]:
        rc, out, err = run_cli(capsys, "replay", log, "--step", step, "--max-depth", depth, "--rho", rho, "--out",
                            swept.parent / f"r{step}_{depth}_{rho}.mcap", "--json")
        assert rc == 0, err
        res = {f.index: f for f in LogReader(swept.parent / f"r{step}_{depth}_{rho}.mcap", cloudless=True).frames()}
        for fr in json.loads(out)["frames"]:
            row = [r for r in t if r["method"] == "zcut" and r["frame"] == fr["index"] and r["step_mm"] == step
                   and r["max_depth_mm"] == depth and abs(r["rho_thr"] - rho) < 1e-12]
            assert len(row) == 1
            row = row[0]
            assert row["n_pred"] == fr["zcut"]
            f = res[fr["index"]]
            # S = valid ∩ zone: the pixels the filters judged (the log's own bin model removed table and bin)
            zone = f.masks[layout.ZONE]
            L = truth[fr["index"]] & zone
            P = f.masks[layout.ZCUT_OUTLIERS]
            assert (row["tp"], row["fp"], row["fn"]) == (int((P & L).sum()), int((P & ~L).sum()), int((L & ~P).sum()))
            sor = [r for r in t if r["method"] == "sor" and r["frame"] == fr["index"] and r["sor_k"] == 4
                   and r["sor_std_ratio"] == 1.0 and r["step_mm"] == step and r["max_depth_mm"] == depth]
            assert len(sor) == 1 and sor[0]["n_pred"] == fr["sor"]


def test_summary_tuned_config_and_resume(log, swept, capsys):
    s = json.loads((swept / "summary.json").read_text())
    zc = [e for e in s["sets"] if e["method"] == "zcut"]
    # 2 steps × (10, 20, 30, 40 and the chosen 30's neighbours 15, 45) × (0.03, 0.07 and 0.07's 0.035, 0.105)
    assert len(zc) == 2 * 6 * 4 and all(set(e["ci95"]) == {"precision", "recall", "f1"} for e in zc)
    assert s["chosen"]["zcut"] is not None and s["sensitivity"]["chosen"] is not None
    assert {"theta_1", "theta_2", "omega_1", "omega_2"} <= set(s["sensitivity"]["chosen"])
    tuned = s["tuned"]["zcut"]
    # the best set by F1 within the ranges; the tuned one is the rule's pick (docs/studies.md, "Out of
    # sample"): the best, or a set within one standard error of it
    best = s["validation"]["best"]
    (b,) = [e for e in zc if all(e[k] == best[k] for k in ("step_mm", "max_depth_mm", "rho_thr"))]
    assert b["f1"] == max(e["f1"] for e in zc if _inside(e, s["tuned"]["ranges"]))
    assert all(tuned[k] == s["validation"]["tuned"][k] for k in ("step_mm", "max_depth_mm", "rho_thr"))
    assert tuned["f1"] <= b["f1"] and tuned["f1_out_of_sample"] == s["validation"]["f1_out_of_sample"]
    # tuned.toml is a config zcut replay accepts, with the tuned values
    cfg = tomllib.loads((swept / "tuned.toml").read_text())
    assert cfg["zcut"]["step_mm"] == tuned["step_mm"] and cfg["zcut"]["max_depth_mm"] == tuned["max_depth_mm"]
    rc, out, err = run_cli(capsys, "replay", log, "--config", swept / "tuned.toml", "--json")
    assert rc == 0, err
    assert sum(f["zcut"] for f in json.loads(out)["frames"]) == tuned["n_pred"]
    # rerunning continues (nothing left to do) and gives the same table
    before = pq.read_table(swept / "sweep.parquet")
    rc, _, err = run_cli(capsys, "sweep", log, "-o", swept, "--step", "0.2,0.5", "--max-depth", "10:40:4",
                      "--rho", "0.03,0.07", "--sor-k", "4,6", "--sor-std", "0.5,1", "--no-report")
    assert rc == 0 and "already done" in err
    assert pq.read_table(swept / "sweep.parquet").equals(before)


def _inside(e, ranges) -> bool:
    if ranges is None:
        return True
    return all(lo * (1 - 1e-9) <= e[c] <= hi * (1 + 1e-9) for c, (lo, hi) in ranges.items())


@pytest.mark.parametrize("argv, msg", [
    (["--max-depth", "40:10:4"], "an inverted range"),
    (["--max-depth", "10:40:0"], "the count must be >= 1"),
    (["--rho", ""], "an empty list"),
    (["--rho", "0.1,1.5"], "--rho values must be in (0, 1]"),
    (["--step", "0,0.2"], "--step values must be > 0 mm"),
    (["--sor-k", "4.5"], "--sor-k must be integers"),
    (["--step", "0.1:0.5:40", "--max-depth", "5:50:40"], "more than 5000): narrow it, or use --force"),
    (["--objective", "auc"], "--objective must be f1"),
    (["--step", "a,b"], "--step must be a,b,c or start:stop:count"),
])
def test_bad_grids_are_one_line_errors_before_any_work(log, tmp_path, capsys, argv, msg):
    rc, _, err = run_cli(capsys, "sweep", log, "-o", tmp_path / "out", *argv)
    assert rc == 1 and msg in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "out").exists()


def test_a_log_without_truth_is_refused(tmp_path, capsys, real_data):
    real = tmp_path / "real.mcap"
    assert main(["record", str(real_data / "mosd_test16.pcd"), "-o", str(real)]) == 0
    capsys.readouterr()
    rc, _, err = run_cli(capsys, "sweep", real, "-o", tmp_path / "out")
    assert rc == 1 and "no /ground_truth/outliers" in err and "--labels" in err


def test_parse_list():
    assert parse_list("1,2,2,0.5", name="x") == (0.5, 1.0, 2.0)
    assert parse_list("10:40:4", name="x") == (10.0, 20.0, 30.0, 40.0)
    assert parse_list("3:3:1", name="x") == (3.0,)
    assert parse_list(None, name="x") is None
