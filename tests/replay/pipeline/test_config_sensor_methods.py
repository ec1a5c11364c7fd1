"""A stereo log's default methods (docs/labelling_real.md, h/stereo4): the matcher's post-filter masks the log
records at the config's strengths join ``zcut, sor`` when no layer names ``methods``; a log without them resolves to
the config it resolved to before, to the bit; a real ``zcut record-stereo`` log opens with them."""

from __future__ import annotations

import dataclasses
import json

import pytest

from replay.logs import layout
from replay.pipeline import config as cfg
from replay.pipeline.config import LogFacts
from replay.pipeline.methods import DEFAULT_METHODS

SHAPE = (40, 60)


def _meta(*settings: tuple[str, dict[str, int]]) -> dict[str, dict[str, str]]:
    return {layout.STEREO_METADATA: {"tau_px": "1.0", "matcher": "sgbm", "frames": "[]", "rejected": json.dumps(
        [{"method": m, "settings": s, "topic": layout.stereo_rejected_topic(s)} for m, s in settings])}}


RECORDED = _meta(("stereo_uniqueness", {"uniqueness_ratio": 10}), ("stereo_lr", {"disp12_max_diff": 1}),
                 ("stereo_speckle", {"speckle_window": 100, "speckle_range": 2}))


def _facts(metadata) -> LogFacts:
    return LogFacts(None, 800.0, None, SHAPE, recorded_masks=cfg.recorded_masks(metadata))


def test_recorded_masks_join_the_defaults_in_the_registry_order():
    r = cfg.resolve(_facts(RECORDED))
    assert r.config.methods == (*DEFAULT_METHODS, "stereo_uniqueness", "stereo_lr", "stereo_speckle")
    (note,) = [n for n in r.notes if n.startswith("methods:")]
    assert "post-filter masks the log records" in note and "--methods" in note
    # recorded in another order: the registry's order all the same
    rev = _meta(("stereo_speckle", {"speckle_window": 100, "speckle_range": 2}), ("stereo_lr", {"disp12_max_diff": 1}))
    assert cfg.resolve(_facts(rev)).config.methods == (*DEFAULT_METHODS, "stereo_lr", "stereo_speckle")


def test_only_the_strength_the_config_selects():
    only25 = _meta(("stereo_uniqueness", {"uniqueness_ratio": 25}), ("stereo_lr", {"disp12_max_diff": 1}))
    assert cfg.resolve(_facts(only25)).config.methods == (*DEFAULT_METHODS, "stereo_lr")
    file_layer = cfg.check_layer({"stereo_uniqueness": {"uniqueness_ratio": 25}}, source="f")
    assert cfg.resolve(_facts(only25), file_layer=file_layer).config.methods == (
        *DEFAULT_METHODS, "stereo_uniqueness", "stereo_lr")
    assert cfg.resolve(_facts(RECORDED), file_layer=file_layer).config.methods == (
        *DEFAULT_METHODS, "stereo_lr", "stereo_speckle")


@pytest.mark.parametrize("layer", ["file", "cli"])
def test_methods_named_by_a_layer_win(layer):
    named = {"methods": ["zcut", "stereo_lr"]}
    kw = {"file_layer": cfg.check_layer(named, source="f")} if layer == "file" else {"cli": cfg.cli_layer(methods="zcut,stereo_lr")}
    r = cfg.resolve(_facts(RECORDED), **kw)
    assert r.config.methods == ("zcut", "stereo_lr")
    assert [n for n in r.notes if n.startswith("methods:")] == ["methods: zcut, stereo_lr"]
    kw = {"file_layer": cfg.check_layer({"methods": ["zcut", "sor"]}, source="f")} if layer == "file" else {
        "cli": cfg.cli_layer(methods="zcut,sor")}
    assert cfg.resolve(_facts(RECORDED), **kw).config.methods == DEFAULT_METHODS


@pytest.mark.parametrize("metadata", [
    {},  # a Kinect-class or ROS log
    {layout.SYNTH_METADATA: {"part_kind": "zinc_nuts", "camera_distance_mm": "900"}},
    {layout.STEREO_METADATA: {"tau_px": "1.0", "matcher": "sgbm", "frames": "[]"}},  # before the masks existed
    {layout.STEREO_METADATA: {"tau_px": "1.0", "rejected": "[]"}},  # --no-rejected
    {layout.STEREO_METADATA: {"rejected": "not json"}},
    {layout.STEREO_METADATA: {"rejected": json.dumps([{"method": 3}, "x"])}},
])
def test_logs_without_recorded_masks_resolve_as_before(metadata):
    f = _facts(metadata)
    assert f.recorded_masks == ()
    before = dataclasses.replace(f, recorded_masks=())
    new, old = cfg.resolve(f), cfg.resolve(before)
    assert new.config.methods == DEFAULT_METHODS
    assert cfg.config_sha256(new.config) == cfg.config_sha256(old.config) and new.notes == old.notes
    assert cfg.to_toml(new.config) == cfg.to_toml(old.config)


def test_a_recorded_stereo_log_opens_with_its_masks(tmp_path):
    from stereo_helpers import motorcycle, write_scene

    from cli.main import main
    from replay.pipeline.session import open_log

    d = write_scene(tmp_path / "Motorcycle", motorcycle(4))
    log, bare = tmp_path / "m.mcap", tmp_path / "bare.mcap"
    assert main(["record-stereo", str(d), "-o", str(log)]) == 0
    assert main(["record-stereo", str(d), "-o", str(bare), "--no-rejected"]) == 0
    _, _, r = open_log(log)
    assert r.config.methods == ("zcut", "sor", "stereo_uniqueness", "stereo_lr", "stereo_speckle")
    _, _, b = open_log(bare)
    assert b.config.methods == DEFAULT_METHODS
    assert not [n for n in b.notes if n.startswith("methods:")]
