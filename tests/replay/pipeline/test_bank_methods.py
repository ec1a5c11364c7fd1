"""The filter bank and the suspects as methods (docs/filters.md, "In the pipeline"): their config
sections, what each sees, the same masks through replay, its results file, accuracy, batch and
Rerun, and degenerate frames."""

from __future__ import annotations

import dataclasses
import json
import tomllib

import numpy as np
import pyarrow.parquet as pq
import pytest
import rerun as rr
from cli_helpers import run_cli, synth_with_bin_model

from replay.errors import ConfigError
from replay.logs import layout
from replay.logs.frame import Frame
from replay.logs.reader import LogReader
from replay.pipeline import config as cfg
from replay.pipeline.methods import registry, suspect_params
from replay.pipeline.stages import bin_zone, run_methods
from replay.pipeline.zone import Zone
from zcut import (
    Intrinsics,
    cluster_stage,
    mixed_pixel_stage,
    radius_stage,
    speckle_stage,
    suspects,
    window_stage,
)

BANK = ("radius", "cluster", "speckle", "window", "mixed_pixel", "suspects")
ALL = ("zcut", "sor", *BANK)


def test_every_bank_method_is_registered_with_its_section():
    reg = registry()
    for name in BANK:
        assert name in reg and reg[name].section == name and name in cfg.stage_sections()
        assert name in cfg.section_names()
    assert [m for m in reg if reg[m].needs_intrinsics] == ["cluster"]


@pytest.mark.parametrize("text, match", [
    ("[radius]\nradius_mm = 0\n", r"radius\.radius_mm must be a number > 0, got 0"),
    ("[radius]\nmin_points = 2.5\n", r"radius\.min_points"),
    ("[cluster]\nmin_area_mm2 = -1.0\n", r"cluster\.min_area_mm2"),
    ("[cluster]\nconnectivity = 6\n", r"cluster\.connectivity must be 4 or 8, got 6"),
    ("[speckle]\nmax_size_px = -1\n", r"speckle\.max_size_px"),
    ("[window]\nmin_inliers = 9\n", r"window\.min_inliers"),
    ("[mixed_pixel]\nmin_angle_deg = 91.0\n", r"mixed_pixel\.min_angle_deg"),
    ("[suspects]\nplain_rho = 0.5\n", r"suspects\.plain_rho must be <= floating_rho"),
    ("[radius]\nradius = 2.0\n", r"unknown key radius\.radius \(known: min_points, radius_mm\)"),
    ('methods = ["zcut+radiuss"]\n', r"unknown method 'radiuss' in 'zcut\+radiuss'"),
])
def test_bad_bank_values_are_one_line_config_errors(tmp_path, text, match):
    p = tmp_path / "c.toml"
    p.write_text(text)
    with pytest.raises(ConfigError, match=match) as e:
        cfg.load_toml(p)
    assert "\n" not in str(e.value) and str(e.value).startswith(str(p))


def test_bank_sections_resolve_and_read_back(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text('methods = ["zcut", "radius", "speckle+mixed_pixel"]\n[radius]\nradius_mm = 3.0\nmin_points = 4\n'
                 "[suspects]\nnoise_k = 4.0\n[window]\nrel_tolerance = 0.01\n")
    K = Intrinsics(fx=500.0, fy=500.0, cx=5.0, cy=5.0, width=10, height=10)
    r = cfg.resolve(cfg.LogFacts(None, None, K, (10, 10)), file_layer=cfg.load_toml(p))
    c = r.config
    assert (c.radius.radius_mm, c.radius.min_points, c.suspects.noise_k, c.window.rel_tolerance) == (3.0, 4, 4.0, 0.01)
    assert c.base_methods == ("zcut", "radius", "speckle", "mixed_pixel")
    text = cfg.to_toml(c)
    assert "[radius]\nradius_mm = 3.0\nmin_points = 4\n" in text and "[mixed_pixel]" in text
    back = cfg.from_dict(tomllib.loads(text))
    assert back == c and cfg.config_sha256(back) == cfg.config_sha256(c)


def test_cluster_needs_the_camera_model_of_the_log():
    K = Intrinsics(fx=500.0, fy=500.0, cx=5.0, cy=5.0, width=10, height=10)
    layer = cfg.cli_layer(methods="zcut,cluster")
    for facts in (cfg.LogFacts(None, None, None, (10, 10)),
                  cfg.LogFacts(None, None, K, (10, 10), intrinsics_fitted=True)):
        with pytest.raises(ConfigError, match=r"^cluster needs the camera model \(fx, fy\) and the log has none") as e:
            cfg.resolve(facts, cli=layer)
        assert "\n" not in str(e.value)
    layer_union = cfg.cli_layer(methods="zcut+cluster")
    with pytest.raises(ConfigError, match="cluster needs the camera model"):
        cfg.resolve(cfg.LogFacts(None, None, None, (10, 10)), cli=layer_union)
    assert cfg.resolve(cfg.LogFacts(None, None, K, (10, 10)), cli=layer).config.methods == ("zcut", "cluster")
    # without cluster, a log without a camera model is fine
    cfg.resolve(cfg.LogFacts(None, None, None, (10, 10)), cli=cfg.cli_layer(methods="radius,speckle"))


def _frame(xyz, K=None) -> Frame:
    return Frame(xyz=xyz, rgb=None, stamp_ns=1, frame_id="cam", intrinsics=K, topic="/c", index=0)


def _config(methods=ALL, **sections) -> cfg.PipelineConfig:
    c = cfg.resolve(cfg.LogFacts(None, None, None, (8, 9)), cli=cfg.cli_layer(methods=",".join(
        m for m in methods if m != "cluster"))).config
    return c.replace(methods=tuple(methods), **sections)


@pytest.mark.parametrize("kind", ["all_nan", "identical", "one_point", "empty_rows"])
def test_degenerate_frames_give_masks_and_no_error(kind):
    H, W = (8, 9) if kind != "empty_rows" else (0, 9)
    xyz = np.full((H, W, 3), np.nan, np.float32)
    if kind == "identical":
        xyz[...] = (0.01, -0.02, 0.8)
    elif kind == "one_point":
        xyz[3, 4] = (0.0, 0.0, 1.0)
    K = Intrinsics(fx=500.0, fy=500.0, cx=4.0, cy=4.0, width=W, height=H) if H else None
    frame = _frame(xyz, K)
    config = _config()
    zone = bin_zone(frame, config)
    timings: dict[str, float] = {}
    warnings: list[str] = []
    out = run_methods(frame, zone, config, timings=timings, warnings=warnings)
    assert set(out) == set(ALL) and set(ALL) <= set(timings)
    for name, res in out.items():
        assert res.outliers.shape == (H, W) and res.outliers.dtype == bool
        assert not (res.outliers & ~zone.zone).any(), name
    if kind in ("all_nan", "empty_rows"):
        assert not any(r.outliers.any() for r in out.values())
    if kind == "identical":  # a heap of one point: every point has every other as a neighbour
        assert not out["radius"].outliers.any() and not out["window"].outliers.any()
        assert out["speckle"].outliers.all()  # one region of 72 px, at most speckle.max_size_px (100)
    if kind == "one_point":
        assert out["radius"].outliers[3, 4]  # alone in its ball
    if H == 0:
        assert any("cluster" in w for w in warnings)  # no camera model on this frame: a named warning
        assert not out["cluster"].outliers.any()


def test_a_frame_without_camera_model_warns_for_cluster_only():
    rng = np.random.default_rng(0)
    xyz = np.dstack([rng.normal(0, 0.01, (8, 9)), rng.normal(0, 0.01, (8, 9)), 1 + rng.normal(0, 0.001, (8, 9))])
    frame = _frame(xyz.astype(np.float32))
    config = _config()
    warnings: list[str] = []
    run_methods(frame, bin_zone(frame, config), config, timings={}, warnings=warnings)
    assert warnings == ["cluster: needs the camera model and this frame has none (no CameraInfo): no outliers"]


def test_a_camera_model_of_another_size_is_a_named_warning():
    xyz = np.zeros((8, 9, 3), np.float32) + np.float32(1.0)
    K = Intrinsics(fx=500.0, fy=500.0, cx=4.0, cy=4.0, width=90, height=80)
    frame = _frame(xyz, K)
    config = _config()
    warnings: list[str] = []
    out = run_methods(frame, bin_zone(frame, config), config, timings={}, warnings=warnings)
    assert not out["suspects"].warning  # the detectors need nothing of the camera
    assert all(not w.startswith(("zcut", "sor", "radius", "speckle", "window", "mixed_pixel")) for w in warnings)


# ------------------------------------------------------------------------------- on real MCAP files
@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("bank_methods")
    log, _, model = synth_with_bin_model(d, parts="zinc_nuts", seed=17, size="150x200", names=("s.mcap", "e.mcap"))
    return d, log, model


def _expected(frame: Frame, zone: Zone, config: cfg.PipelineConfig) -> dict[str, np.ndarray]:
    """Each filter's outliers as docs/filters.md says the pipeline computes them, from zcut directly."""
    z, easy = zone.zone, zone.easy
    sub = np.where(z[..., None], frame.xyz, np.nan).astype(frame.xyz.dtype)
    out = {
        "radius": radius_stage(sub, params=config.radius) & z,
        "cluster": cluster_stage(frame.xyz, params=config.cluster, intrinsics=frame.intrinsics) & z,
        "speckle": speckle_stage(frame.xyz, params=config.speckle) & z,
        "window": window_stage(frame.xyz, params=config.window) & z,
        "mixed_pixel": mixed_pixel_stage(frame.xyz, params=config.mixed_pixel) & z,
        "suspects": suspects(frame.xyz, zone.height_mm, z, easy, params=suspect_params(config),
                             intrinsics=frame.intrinsics).mask & z,
    }
    return {k: v | easy for k, v in out.items()}


METHODS = "zcut,sor,radius,cluster,speckle,window,mixed_pixel,suspects,zcut+mixed_pixel"


def test_every_method_through_replay_results_accuracy_and_rerun(logs, capsys):
    from replay.pipeline.bin_model import load_bin_model
    from replay.pipeline.session import ReplaySession

    d, log, model = logs
    res, rrd = d / "r.mcap", d / "r.rrd"
    rc, out, err = run_cli(capsys, "replay", log, "--bin-model", model, "--methods", METHODS, "--out", res,
                           "--rrd", rrd, "--json", "--force")
    assert rc == 0, err
    rows = json.loads(out)["frames"]
    session = ReplaySession.open(log, overrides=cfg.cli_layer(methods=METHODS), bin_model=load_bin_model(model))
    config = session.config
    written = {f.index: f for f in LogReader(res, cloudless=True).frames()}
    zones = session.zones(frames=(0, 2))
    try:
        for frame, zone in zones:
            want = _expected(frame, zone, config)
            row = next(r for r in rows if r["index"] == frame.index)
            for name, mask in want.items():
                got = written[frame.index].masks[layout.method_topic(name)]
                assert np.array_equal(got, mask), name
                assert row[name] == int(mask.sum()), name
            assert zone.removal is not None  # the bin stages ran: the zone is not every valid pixel
    finally:
        zones.close()
    # accuracy scores each under its name, from the log and from the results file alike (the sensor's truth:
    # its kind image gives by_kind)
    rc, out, err = run_cli(capsys, "accuracy", log, "--bin-model", model, "--methods", METHODS, "--json", "--truth", "sensor")
    assert rc == 0, err
    rep = json.loads(out)
    assert list(rep["pooled"]) == METHODS.split(",") + ["union", "intersection"]
    for name in METHODS.split(","):
        entry = rep["pooled"][name]
        assert {"tp", "fp", "fn", "precision", "recall", "ci95", "by_kind"} <= set(entry)
    frames = {f.index: f for f in LogReader(log).frames()}
    for fr in rep["frames"]:
        truth = frames[fr["index"]].masks[layout.TRUTH_OUTLIERS]
        for name in BANK:
            mask = written[fr["index"]].masks[layout.method_topic(name)]
            assert fr[name]["tp"] == int((mask & truth).sum()), name  # the mask lies in the scored region
    rc, out2, err = run_cli(capsys, "accuracy", res, "--methods", METHODS, "--json", "--truth", "sensor")
    assert rc == 0, err
    rep2 = json.loads(out2)
    for name in METHODS.split(","):
        assert rep2["pooled"][name]["tp"] == rep["pooled"][name]["tp"], name
    # Rerun: one image view per method other than the z-cut and SOR, and its time
    paths = {chunk.entity_path for chunk in rr.chunk.RrdReader(str(rrd)).stream()}
    for name in BANK:
        assert f"/image/methods/{name}" in paths, name


def test_batch_counts_every_method(logs, capsys):
    d, log, model = logs
    out = d / "batch"
    rc, _, err = run_cli(capsys, "batch", log, "--bin-model", model, "--methods", METHODS, "-o", out,
                         "--workers", "0")
    assert rc == 0, err
    t = pq.read_table(out / "frames.parquet")
    for name in BANK:
        assert name in t.column_names and f"{name}_tp" in t.column_names, name
        assert f"t_{name}_s" in t.column_names, name
    assert "zcut+mixed_pixel_tp" in t.column_names


def test_cluster_on_a_log_without_camera_info_is_one_line(tmp_path, capsys):
    rng = np.random.default_rng(1)
    scans = tmp_path / "scans"
    scans.mkdir()
    for i in range(2):  # organized ASCII PCDs of a plane 1 m away (no camera info in them)
        z = 1.0 + rng.normal(0, 0.001, (40, 50))
        v, u = np.mgrid[0:40, 0:50]
        pts = np.dstack([(u - 25) * z / 500.0, (v - 20) * z / 500.0, z]).reshape(-1, 3)
        head = ("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 50\nHEIGHT 40\n"
                "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2000\nDATA ascii\n")
        (scans / f"s{i}.pcd").write_text(head + "\n".join(" ".join(f"{c:.6f}" for c in p) for p in pts) + "\n")
    log = tmp_path / "rec.mcap"
    rc, _, err = run_cli(capsys, "record", scans, "-o", log)
    assert rc == 0, err
    rc, out, err = run_cli(capsys, "replay", log, "--methods", "zcut,cluster")
    assert rc == 1 and "Traceback" not in err
    assert err.strip().splitlines()[-1].startswith("error: cluster needs the camera model")
    rc, out, err = run_cli(capsys, "replay", log, "--methods", "zcut,speckle,radius", "--json")
    assert rc == 0, err


def test_dataclass_fields_of_every_bank_section_have_defaults():
    for name in BANK:
        cls = cfg.stage_sections()[name]
        cls()  # every field has its default
        assert all(f.default is not dataclasses.MISSING for f in dataclasses.fields(cls))
