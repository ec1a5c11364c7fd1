"""The sweep's grid (studies.grid): values merged with a tolerance, study points switchable, and a
sweep whose --rho range meets the study points scores and lists every set once."""

from __future__ import annotations

import json
from collections import Counter

import pyarrow.parquet as pq
import pytest
from cli_helpers import run_cli

from cli.main import main
from replay.pipeline import config as cfg
from studies.grid import REL_TOL, make_grid, merge_values, parse_list


def test_parse_list_merges_values_that_agree_to_the_tolerance():
    assert parse_list("0.035:0.105:3", name="x") == (0.035, 0.07, 0.105)
    assert parse_list("0.1:0.3:3", name="x") == (0.1, 0.2, 0.3)  # 0.1 + 0.2 is 0.30000000000000004
    assert parse_list("0.105,0.10500000000000001,0.1050000000000001", name="x") == (0.105,)
    assert parse_list("1,2,2,0.5", name="x") == (0.5, 1.0, 2.0)
    assert parse_list("4,8,4", name="k", integer=True) == (4, 8)
    assert parse_list("1,1.0000001", name="x") == (1.0, 1.0000001)  # distinct beyond the tolerance


def test_merge_values_keeps_the_first_spelling():
    assert merge_values([0.105], [0.10500000000000001, 0.035]) == (0.035, 0.105)
    assert merge_values([0.10500000000000001], [0.105]) == (0.10500000000000001,)
    big = 1e6
    assert merge_values([big], [big * (1 + REL_TOL / 2)]) == (big,)
    assert merge_values([], []) == ()


def _config():
    return cfg.from_dict({"part": "zinc_nuts", "zcut": {"a_max_px": 1000.0, "max_area_px": 70.0}}, source="test")


def test_study_points_are_added_once_and_can_be_switched_off():
    base = _config()
    z = base.zcut
    assert (z.step, z.max_depth, z.rho_thr) == (0.2, 30.0, 0.07)
    rhos = parse_list("0.035:0.105:3", name="--rho")
    g = make_grid(steps=None, depths=None, rhos=rhos, sor_ks=None, sor_stds=None, config=base)
    assert g.rhos == (0.035, 0.07, 0.105) and g.depths == (15.0, 30.0, 45.0) and g.study_points
    assert g.as_dict()["study_points"] is True
    off = make_grid(steps=None, depths=None, rhos=rhos, sor_ks=None, sor_stds=None, config=base, study_points=False)
    assert off.rhos == (0.035, 0.07, 0.105) and off.depths == (30.0,) and off.steps == (0.2,)
    assert off.as_dict()["study_points"] is False
    # without study points an axis given is exactly what was given (the chosen value is not added)
    off = make_grid(steps=None, depths=(20.0, 40.0), rhos=(0.05,), sor_ks=None, sor_stds=None, config=base,
                    study_points=False)
    assert off.depths == (20.0, 40.0) and off.rhos == (0.05,)
    # with them, the neighbours of a chosen point whose 1.5x lands on a float boundary merge with a given value
    g = make_grid(steps=None, depths=(45.0,), rhos=(0.105, 0.2), sor_ks=None, sor_stds=None, config=base)
    assert g.depths == (15.0, 30.0, 45.0) and g.rhos == (0.035, 0.07, 0.105, 0.2)


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    p = tmp_path_factory.mktemp("grid_logs") / "nuts.mcap"
    assert main(["synth", "-o", str(p), "--parts", "zinc_nuts", "--frames", "2", "--seed", "5", "--size", "150x240"]) == 0
    return p


def _set_keys(sets):
    return [(e["method"], e["step_mm"], e["max_depth_mm"], e["rho_thr"], e["sor_k"], e["sor_std_ratio"]) for e in sets]


def test_a_sweep_over_the_readmes_rho_range_lists_every_set_once(log, tmp_path, capsys):
    out = tmp_path / "sweep"
    rc, printed, err = run_cli(capsys, "sweep", log, "-o", out, "--rho", "0.035:0.105:3", "--sor-k", "4",
                               "--sor-std", "1", "--workers", "1")
    assert rc == 0, err
    s = json.loads((out / "summary.json").read_text())
    assert s["grid"]["rho_thr"] == [0.035, 0.07, 0.105] and s["grid"]["max_depth_mm"] == [15.0, 30.0, 45.0]
    keys = _set_keys(s["sets"])
    assert not [k for k, n in Counter(keys).items() if n > 1]
    assert sum(k[0] == "zcut" for k in keys) == 3 * 3
    t = pq.read_table(out / "sweep.parquet").to_pylist()
    zc = [r for r in t if r["method"] == "zcut"]
    assert sorted({r["rho_thr"] for r in zc}) == [0.035, 0.07, 0.105]
    assert len(zc) == 2 * 3 * 3  # frames × d_max × ρ_thr: each set once per frame
    # the report page lists each z-cut set once: every (d_max, ρ) row of the sets table is unique
    page = (out / "report.html").read_text()
    assert page.count("0.10500000000000001") == 0
    assert "(study points)" in page
    # the printed summary names the grid's sets once too (chosen and nominal are one set here)
    assert printed.count("ρ 0.105") <= 1


def test_no_study_points_runs_exactly_the_values_given(log, tmp_path, capsys):
    out = tmp_path / "sweep"
    rc, printed, err = run_cli(capsys, "sweep", log, "-o", out, "--rho", "0.05,0.07", "--max-depth", "20,30",
                               "--sor-k", "4", "--sor-std", "1", "--no-study-points", "--workers", "1",
                               "--no-report")
    assert rc == 0, err
    s = json.loads((out / "summary.json").read_text())
    assert s["grid"]["rho_thr"] == [0.05, 0.07] and s["grid"]["max_depth_mm"] == [20.0, 30.0]
    assert s["grid"]["study_points"] is False
    assert sum(e["method"] == "zcut" for e in s["sets"]) == 4
    assert s["sensitivity"]["chosen"] is None  # no 0.5× / 1.5× neighbours in the grid
    assert "--no-study-points" in s["reproduce"]
