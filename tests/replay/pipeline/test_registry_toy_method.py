"""A filter added in one place reaches every command (issue 34, "one registry entry per filter").

The toy method below is declared once, as a :class:`replay.pipeline.methods.Method` with its params
class, default axes and run function; the fixture plugs it in through ``ZCUT_METHODS`` (the one
switch, which also reaches the batch's worker processes). Nothing else names it: the config's
sections and bank, the sweep's default axes, the results file, accuracy, the batch table, the page's
methods list and the Rerun recording all see it through the registry.
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass

import numpy as np
import pyarrow.parquet as pq
import pytest
import rerun as rr
from cli_helpers import run_cli

from cli.main import main
from replay.logs import layout
from replay.logs.reader import LogReader
from replay.pipeline import config as cfg
from replay.pipeline.methods import PLUGINS_ENV, Method, MethodOutput, registry
from zcut.errors import ParameterError


@dataclass(frozen=True, slots=True)
class ToyParams:
    """The toy filter's parameters: the zone's points within ``band_mm`` of its highest point."""

    band_mm: float = 1.0

    def __post_init__(self) -> None:
        if isinstance(self.band_mm, bool) or not isinstance(self.band_mm, (int, float)) or not self.band_mm > 0:
            raise ParameterError(f"ToyParams.band_mm must be a number > 0, got {self.band_mm!r}")


def _run_toy(frame, zone, config) -> MethodOutput:
    h = np.where(zone.zone, zone.height_mm, np.nan)
    if not np.isfinite(h).any():
        return MethodOutput(np.zeros_like(zone.zone))
    with np.errstate(invalid="ignore"):
        return MethodOutput(zone.zone & (h >= np.nanmax(h) - config.toy.band_mm))


def _warm_toy() -> None:
    """The toy compiles nothing; a filter with numba kernels runs them here on tiny inputs."""


#: The one place the toy filter is declared.
TOY = Method(name="toy", params=ToyParams, run=_run_toy, axes={"band_mm": (0.5, 1.0, 2.0)}, warmup=_warm_toy,
             summary="toy: the zone's top band (a test's filter)")
METHODS = "zcut,sor,toy"


@pytest.fixture
def toy(monkeypatch):
    """The toy method plugged into the registry (this module, by its import name)."""
    monkeypatch.setenv(PLUGINS_ENV, f"{__name__}:TOY")


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    p = tmp_path_factory.mktemp("toy_log") / "rods.mcap"
    assert main(["synth", "-o", str(p), "--parts", "rods", "--frames", "2", "--seed", "3", "--size", "120x160"]) == 0
    return p


def test_without_the_plug_in_the_toy_is_unknown(log, capsys):
    assert "toy" not in registry()
    rc, _, err = run_cli(capsys, "replay", log, "--methods", METHODS)
    assert rc == 1 and err.strip().startswith("error:") and "unknown method 'toy'" in err


def test_the_config_its_axes_and_its_warm_up(toy):
    from replay.warmup import groups
    from studies.bank import default_axes

    assert registry()["toy"] is TOY
    assert default_axes()["toy"] == {"band_mm": (0.5, 1.0, 2.0)}
    assert any("toy" in what for what, _ in groups())
    assert "toy" in cfg.section_names() and cfg.stage_sections()["toy"] is ToyParams
    assert "toy" in cfg.bank_sections()
    c = cfg.resolve(cfg.LogFacts(None, None, None, (8, 9)), cli=cfg.cli_layer(methods=METHODS)).config
    assert c.toy == ToyParams() and c.replace(toy=ToyParams(band_mm=3.0)).toy.band_mm == 3.0
    text = cfg.to_toml(c)
    assert "[toy]\nband_mm = 1.0\n" in text
    assert cfg.from_dict(tomllib.loads(text)) == c
    with pytest.raises(cfg.ConfigError, match=r"toy\.band_mm must be a number > 0"):
        cfg.check_layer({"toy": {"band_mm": -1.0}}, source="f.toml")


def test_replay_results_rerun_and_accuracy(toy, log, tmp_path, capsys):
    res, rrd = tmp_path / "r.mcap", tmp_path / "r.rrd"
    rc, out, err = run_cli(capsys, "replay", log, "--methods", METHODS, "--out", res, "--rrd", rrd, "--json")
    assert rc == 0, err
    frames = {f.index: f for f in LogReader(res, cloudless=True).frames()}
    for fr in json.loads(out)["frames"]:
        mask = frames[fr["index"]].masks[layout.method_topic("toy")]
        assert fr["toy"] == int(mask.sum()) > 0
    # the Rerun recording: the toy's view of the outliers
    entities = {chunk.entity_path for chunk in rr.chunk.RrdReader(str(rrd)).stream()}
    assert "/image/methods/toy" in entities
    # accuracy of the results file (the masks it holds) and of the log (the pipeline run again)
    for source, extra in ((res, ()), (log, ("--methods", METHODS))):
        rc, out, err = run_cli(capsys, "accuracy", source, *extra, "--json")
        assert rc == 0, err
        assert "toy" in json.loads(out)["pooled"], source


def test_sweep_with_its_default_axes(toy, log, tmp_path, capsys):
    out = tmp_path / "sweep"
    rc, _, err = run_cli(capsys, "sweep", log, "-o", out, "--methods", METHODS, "--grid", "toy=default",
                         "--workers", "0")
    assert rc == 0, err
    rows = [r for r in pq.read_table(out / "sweep.parquet").to_pylist() if r["method"] == "toy"]
    assert {json.loads(r["params"])["band_mm"] for r in rows} == {0.5, 1.0, 2.0}
    assert all(r["tp"] is not None and r["n_pred"] > 0 for r in rows)
    rc, _, err = run_cli(capsys, "sweep", log, "-o", tmp_path / "bad", "--methods", METHODS, "--grid",
                         "toy.band_mm=0", "--workers", "0")
    assert rc == 1 and len(err.strip().splitlines()) == 1 and "toy.band_mm" in err, err


def test_a_method_without_axes_sweeps_at_its_config_values(log, tmp_path, capsys):
    out = tmp_path / "sweep"
    rc, _, err = run_cli(capsys, "sweep", log, "-o", out, "--methods", "zcut,sor,suspects", "--grid",
                         "suspects=default", "--workers", "0")
    assert rc == 0, err
    assert len({r["params"] for r in pq.read_table(out / "sweep.parquet").to_pylist()
                if r["method"] == "suspects"}) == 1


def test_batch_in_a_worker_process(toy, log, tmp_path, capsys):
    out = tmp_path / "batch"
    rc, _, err = run_cli(capsys, "batch", log, "-o", out, "--methods", METHODS, "--workers", "1")
    assert rc == 0, err
    t = pq.read_table(out / "frames.parquet")
    assert "toy_tp" in t.column_names and t.num_rows == 2


def test_the_page_lists_it(toy, log):
    from annotate.payload import parse_bundle, prepare_frame
    from replay.pipeline.session import ReplaySession

    session = ReplaySession.open(log, overrides=cfg.cli_layer(methods=METHODS))
    results = session.results(frames=(0, 1))
    try:
        frame, result = next(iter(results))
    finally:
        results.close()
    header, _ = parse_bundle(prepare_frame(frame, result).served.bundle)
    assert "toy" in header["methods"]


@pytest.mark.parametrize("spec, match", [("no_such_module_zcut:TOY", "cannot load 'no_such_module_zcut:TOY'"),
                                         ("replay.pipeline.methods:BUILTIN", "method 'zcut' .* already taken"),
                                         ("replay.pipeline.methods", "expected module:NAME")])
def test_a_bad_plug_in_is_one_line(log, monkeypatch, capsys, spec, match):
    import re

    monkeypatch.setenv(PLUGINS_ENV, spec)
    rc, _, err = run_cli(capsys, "replay", log)
    assert rc == 1 and len(err.strip().splitlines()) == 1 and re.search(match, err), err
    assert err.startswith(f"error: {PLUGINS_ENV}: ")
