"""`zcut sweep` over the filter bank (docs/filters.md, "The bank in a sweep"): each filter's own
axes, counts equal to replay's at every set, the ranking per part kind in summary.json, the report's
section and chart, tuned.toml, and bad --grid values as one line."""

from __future__ import annotations

import json
import tomllib

import pyarrow.parquet as pq
import pytest
from cli_helpers import run_cli

from cli.main import main
from replay.logs import layout
from replay.logs.reader import LogReader

METHODS = "zcut,sor,radius,speckle,mixed_pixel,zcut+mixed_pixel"


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("bank_sweep_logs")
    out = []
    for kind, seed in (("zinc_nuts", 5), ("black_nuts", 6)):
        p = d / f"{kind}.mcap"
        assert main(["synth", "-o", str(p), "--parts", kind, "--frames", "2", "--seed", str(seed),
                     "--size", "150x200"]) == 0
        out.append(p)
    return out


@pytest.fixture(scope="module")
def swept(logs, tmp_path_factory):
    out = tmp_path_factory.mktemp("bank_sweep") / "out"
    assert main(["sweep", *map(str, logs), "-o", str(out), "--methods", METHODS, "--grid", "radius.radius_mm=2,4",
                 "--grid", "radius.min_points=2,8", "--grid", "mixed_pixel=default", "--workers", "0"]) == 0
    return out


def test_every_set_of_the_bank_equals_replay(logs, swept, capsys):
    t = pq.read_table(swept / "sweep.parquet").to_pylist()
    radius = [r for r in t if r["method"] == "radius"]
    assert {json.dumps(json.loads(r["params"]), sort_keys=True) for r in radius} == {
        json.dumps({"radius_mm": a, "min_points": b}, sort_keys=True) for a in (2.0, 4.0) for b in (2, 8)}
    assert {json.loads(r["params"])["min_angle_deg"] for r in t if r["method"] == "mixed_pixel"} == {2.0, 5.0, 8.0,
                                                                                                     12.0, 20.0}
    assert all(r["seconds"] is not None and r["part"] in ("zinc_nuts", "black_nuts") for r in radius)
    log = logs[0]
    # the paper's truth by default (the log has /ground_truth/off_surface), and every row says so
    assert {r["truth"] for r in t} == {"paper"}
    truth = {f.index: f.masks[layout.TRUTH_OFF_SURFACE] for f in LogReader(log).frames()}
    cfg = swept.parent / "c.toml"
    cfg.write_text("[radius]\nradius_mm = 4.0\nmin_points = 2\n[mixed_pixel]\nmin_angle_deg = 12.0\n")
    res = swept.parent / "r.mcap"
    rc, out, err = run_cli(capsys, "replay", log, "--config", cfg, "--methods", METHODS, "--out", res, "--json")
    assert rc == 0, err
    frames = {f.index: f for f in LogReader(res, cloudless=True).frames()}
    for fr in json.loads(out)["frames"]:
        f = frames[fr["index"]]
        S = f.masks[layout.ZONE]
        L = truth[fr["index"]] & S
        for m, params in (("radius", {"radius_mm": 4.0, "min_points": 2}), ("mixed_pixel", {"min_angle_deg": 12.0}),
                          ("speckle", {"max_diff_mm": 2.0, "max_size_px": 100})):
            row = [r for r in t if r["method"] == m and r["log"] == log.name and r["frame"] == fr["index"]
                   and json.loads(r["params"]) == params]
            assert len(row) == 1, m
            P = f.masks[layout.method_topic(m)]
            assert row[0]["n_pred"] == fr[m]
            assert (row[0]["tp"], row[0]["fp"], row[0]["fn"]) == (int((P & L).sum()), int((P & ~L & S).sum()),
                                                                  int((L & ~P).sum())), m
    union = [r for r in t if r["method"] == "zcut+mixed_pixel"]
    assert len(union) == 4 and all(r["params"] == "{}" for r in union)


def test_ranking_report_and_tuned(swept):
    s = json.loads((swept / "summary.json").read_text())
    by = s["ranking"]["by_part"]
    assert set(by) == {"all", "zinc_nuts", "black_nuts"}
    for part, rows in by.items():
        methods = [r["method"] for r in rows]
        assert sorted(methods) == sorted(["zcut", "sor", "radius", "speckle", "mixed_pixel", "zcut+mixed_pixel"])
        f1 = [r["f1"] if r["f1"] is not None else -1 for r in rows]
        assert f1 == sorted(f1, reverse=True), part
        for r in rows:
            assert {"precision", "recall", "f1", "ci95", "seconds", "kind_recall", "params", "frames"} <= set(r)
        assert all(r["frames"] == (4 if part == "all" else 2) for r in rows)
    assert set(s["ranking"]["kinds"]) >= {"1", "2"}
    # pooled sets of the z-cut and SOR are unchanged by the bank's rows
    assert {e["method"] for e in s["sets"]} == {"zcut", "sor"}
    html = (swept / "report.html").read_text()
    assert "id='ranking'" in html and "Part: zinc_nuts" in html and (swept / "plots" / "ranking.png").is_file()
    tuned = tomllib.loads((swept / "tuned.toml").read_text())
    best_radius = next(r for r in by["all"] if r["method"] == "radius")
    assert tuned["radius"] == {**tuned["radius"], **best_radius["params"]}
    assert "best of the ranking" in (swept / "tuned.toml").read_text()


@pytest.mark.parametrize("grid, match", [
    ("radius.radius_mm=0,1", r"--grid: radius\.radius_mm must be a number > 0, got 0"),
    ("radius.radius=1", r"unknown field radius\.radius \(known: min_points, radius_mm\)"),
    ("bogus.x=1", r"unknown section 'bogus'"),
    ("cluster.min_area_mm2=10", r"cluster is not among the methods"),
    ("radius.min_points=1.5", r"must be integers"),
    ("radius", r"expected SECTION\.FIELD=LIST"),
])
def test_bad_grids_are_one_line(logs, tmp_path, capsys, grid, match):
    import re

    rc, out, err = run_cli(capsys, "sweep", logs[0], "-o", tmp_path / "o", "--methods", "zcut,radius", "--grid", grid,
                           "--workers", "0", "--no-report")
    assert rc == 1 and "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert last.startswith("error: ") and re.search(match, last), last
