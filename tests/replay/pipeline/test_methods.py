"""The methods registry: names in the config and on the command line, what a replay runs, what a
report lists, and the same masks through replay, its results file and accuracy."""

from __future__ import annotations

import json

import numpy as np
import pytest
from cli_helpers import run_cli

from replay.errors import ConfigError
from replay.logs import layout
from replay.logs.reader import LogReader
from replay.pipeline import config as cfg
from replay.pipeline.methods import (
    base_methods,
    method_mask,
    parse_methods,
    registry,
    reported_methods,
)


def test_registry_holds_the_papers_two_filters_with_their_sections():
    reg = registry()
    assert list(reg)[:2] == ["zcut", "sor"]
    for m in reg.values():
        assert m.section in cfg.section_names() or m.section in cfg.stage_sections(), m
    with pytest.raises(TypeError):
        reg["x"] = reg["zcut"]  # read-only


@pytest.mark.parametrize("text, want", [
    ("zcut", ("zcut",)),
    ("zcut,sor", ("zcut", "sor")),
    (" sor , zcut ,sor", ("sor", "zcut")),
    ("zcut+sor,zcut", ("zcut+sor", "zcut")),
    ("union,intersection", ("union", "intersection")),
    (["zcut", "sor"], ("zcut", "sor")),
])
def test_parse_methods(text, want):
    assert parse_methods(text) == want


@pytest.mark.parametrize("text, match", [
    ("", "empty method name"),
    ("zcut,,sor", "empty method name"),
    ("zcut,radiuss", r"unknown method 'radiuss' in 'radiuss' \(known: zcut, sor"),
    ("zcut+", "an empty member in 'zcut\\+'"),
    ("zcut+nope", "unknown method 'nope' in 'zcut\\+nope'"),
    (3, "must be a list of method names"),
    ([1], "empty method name"),
])
def test_parse_methods_refuses_bad_lists(text, match):
    with pytest.raises(ConfigError, match=match):
        parse_methods(text)


def test_base_and_reported_methods():
    assert base_methods(["sor"]) == ("zcut", "sor")  # the z-cut always runs (cuts, SOR's top region)
    assert base_methods(["zcut"]) == ("zcut",)
    assert base_methods(["zcut+sor"]) == ("zcut", "sor")
    assert reported_methods(["zcut", "sor"]) == ("zcut", "sor", "union", "intersection")
    assert reported_methods(["zcut"]) == ("zcut",)
    assert reported_methods(["sor", "zcut+sor"]) == ("sor", "zcut+sor")


def test_method_mask_derives_unions_and_the_pair():
    z = np.array([[True, False, True]])
    s = np.array([[False, False, True]])
    out = {"zcut": z, "sor": s}
    assert np.array_equal(method_mask(out, "zcut+sor"), z | s)
    assert np.array_equal(method_mask(out, "union"), z | s)
    assert np.array_equal(method_mask(out, "intersection"), z & s)
    assert method_mask(out, "zcut") is z
    m = method_mask(out, "sor+zcut")
    m[:] = False
    assert z.any() and s.any()  # a derived mask is a new array


def test_methods_in_the_config_file_and_on_the_command_line(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text('methods = ["zcut", "zcut+sor"]\n')
    facts = cfg.LogFacts(None, None, None, (10, 10))
    r = cfg.resolve(facts, file_layer=cfg.load_toml(p))
    assert r.config.methods == ("zcut", "zcut+sor")
    assert any("methods: zcut, zcut+sor" in n for n in r.notes)
    r2 = cfg.resolve(facts, file_layer=cfg.load_toml(p), cli=cfg.cli_layer(methods="sor"))
    assert r2.config.methods == ("sor",)  # the command line wins
    # the resolved config written as TOML reads back to the same config
    back = cfg.from_dict(__import__("tomllib").loads(cfg.to_toml(r.config)))
    assert back == r.config and cfg.config_sha256(back) == cfg.config_sha256(r.config)
    assert cfg.config_sha256(r2.config) != cfg.config_sha256(r.config)
    p.write_text('methods = ["zcut", "bogus"]\n')
    with pytest.raises(ConfigError, match=r"c.toml: methods: unknown method 'bogus'"):
        cfg.load_toml(p)
    p.write_text('methods = "zcut"\n')
    assert cfg.load_toml(p)["methods"] == "zcut"  # a string is a comma list too


@pytest.fixture(scope="module")
def small_log(tmp_path_factory):
    from cli_helpers import synth_log

    return synth_log(tmp_path_factory.mktemp("methods") / "s.mcap", parts="rods", frames=2, seed=11, size="120x192")


def test_replay_and_accuracy_score_the_methods_asked_for(small_log, tmp_path, capsys):
    res = tmp_path / "r.mcap"
    rc, out, err = run_cli(capsys, "replay", small_log, "--methods", "sor,zcut+sor", "--out", res, "--json")
    assert rc == 0, err
    frames = json.loads(out)["frames"]
    config_back = (tmp_path / "r.config.toml").read_text()
    assert 'methods = ["sor", "zcut+sor"]' in config_back
    # accuracy computes the same methods from the log, and reads them back from the results file
    rc, out, err = run_cli(capsys, "accuracy", small_log, "--methods", "sor,zcut+sor", "--json", "--region", "valid", "--truth", "sensor")
    assert rc == 0, err
    rep = json.loads(out)
    assert list(rep["pooled"]) == ["sor", "zcut+sor"]
    rc, out2, err = run_cli(capsys, "accuracy", res, "--methods", "sor,zcut+sor", "--json", "--region", "valid", "--truth", "sensor")
    assert rc == 0, err
    rep2 = json.loads(out2)
    for f in rep2["frames"]:  # a results file does not carry the bin check (docs/pipeline.md, "Bin removal")
        assert (f.pop("bin_check"), f.pop("bin_flagged")) == (None, None)
    for f in rep["frames"]:  # the synthetic log carries its own bin model: the log's frames are checked
        check, flagged = f.pop("bin_check"), f.pop("bin_flagged")
        assert isinstance(check, float) and check >= 0 and isinstance(flagged, bool)
    assert rep2["pooled"] == rep["pooled"] and rep2["frames"] == rep["frames"]
    # the union's counts are those of the replay's two masks
    masks = {f.index: f for f in LogReader(res, cloudless=True).frames()}
    for fr in rep["frames"]:
        f = masks[fr["index"]]
        u = f.masks[layout.ZCUT_OUTLIERS] | f.masks[layout.SOR_OUTLIERS]
        truth = f.masks[layout.TRUTH_OUTLIERS]
        tp = int((u & truth).sum())
        assert fr["zcut+sor"]["tp"] == tp
    assert {r["index"] for r in frames} == {fr["index"] for fr in rep["frames"]}
    # the default report: zcut, sor and the derived pair
    rc, out, err = run_cli(capsys, "accuracy", small_log, "--json")
    assert rc == 0, err
    assert list(json.loads(out)["pooled"]) == ["zcut", "sor", "union", "intersection"]


def test_bad_methods_are_one_line_errors(small_log, tmp_path, capsys):
    rc, out, err = run_cli(capsys, "replay", small_log, "--methods", "zcut,nope")
    assert rc == 1 and err.strip().splitlines()[-1].startswith("error: --methods: unknown method 'nope'")
    assert "Traceback" not in err
    res = tmp_path / "r.mcap"
    assert run_cli(capsys, "replay", small_log, "--methods", "zcut", "--out", res, "--frames", "1")[0] == 0
    assert layout.SOR_OUTLIERS not in LogReader(res, cloudless=True).mask_topics  # SOR did not run: no empty mask of it
    rc, out, err = run_cli(capsys, "accuracy", res, "--methods", "sor")
    assert rc == 1 and "results file without the masks of sor (it holds zcut)" in err
    rc, out, err = run_cli(capsys, "accuracy", small_log, "--methods", "zcut+")
    assert rc == 1 and "an empty member" in err
