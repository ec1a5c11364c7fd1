"""docs/accuracy.md "Same filter everywhere": for one log, config file and overrides, `zcut replay`, `accuracy`,
`annotate`, `sweep` and `batch` resolve the same parameters and produce the same masks.

Three kinds of log: a synthetic one (metadata and CameraInfo), real recorded PCDs (no metadata, no
CameraInfo), and a log with CameraInfo but no metadata. Each command runs for real (the console
script's `main`; for annotate, the replay session its frame catalogue runs) and what it resolved and counted is compared.
"""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pyarrow.parquet as pq
import pytest

from cli.main import main
from replay.logs import layout
from replay.logs.reader import LogReader
from replay.logs.writer import LogWriter

CONFIG = "[zcut]\nmax_depth_mm = 25.0\n[sor]\nk = 6\n"
OVERRIDES = ["--rho", "0.05", "--step", "0.25"]


def _cli(*argv) -> int:
    return main([str(a) for a in argv])


@pytest.fixture(scope="module")
def logs(tmp_path_factory, real_data):
    d = tmp_path_factory.mktemp("same")
    synth = d / "synth.mcap"
    assert _cli("synth", "-o", synth, "--parts", "zinc_nuts", "--frames", "3", "--seed", "5", "--size", "180x288") == 0
    real = d / "real.mcap"
    assert _cli("record", real_data / "mosd_test16.pcd", real_data / "mosd_test20.pcd", "-o", real) == 0
    # CameraInfo but no zcut metadata: the synthetic frames rewritten without their metadata record
    plain = d / "plain.mcap"
    with LogWriter(plain) as w:
        for f in LogReader(synth).frames():
            kw = {"stamp_ns": f.stamp_ns, "frame_id": f.frame_id}
            w.write_cloud(layout.CLOUD, f.xyz, rgb=f.rgb, **kw)
            w.write_camera_info(layout.CAMERA_INFO, f.intrinsics, **kw)
            w.write_mask(layout.TRUTH_OUTLIERS, f.masks[layout.TRUTH_OUTLIERS], **kw)
    config = d / "c.toml"
    config.write_text(CONFIG)
    return d, {"synth": synth, "real": real, "plain": plain}, config


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["synth", "real", "plain"])
def test_every_command_resolves_the_same_config_and_masks(logs, kind, tmp_path, capsys):
    from replay.pipeline.session import ReplaySession

    d, paths, config = logs
    log = paths[kind]
    # replay: the resolved config beside the results, the masks in them
    res = tmp_path / "res.mcap"
    assert _cli("replay", log, "--config", config, *OVERRIDES, "--out", res, "--json") == 0
    replay_summary = json.loads(capsys.readouterr().out)
    replay_toml = (tmp_path / "res.config.toml").read_text()
    z = tomllib.loads(replay_toml)["zcut"]
    assert (z["step_mm"], z["max_depth_mm"]) == (0.25, 25.0)
    assert tomllib.loads(replay_toml)["sor"]["k"] == 6
    masks = {f.index: (f.masks[layout.ZCUT_OUTLIERS], f.masks[layout.SOR_OUTLIERS]) for f in LogReader(res, cloudless=True).frames()}
    assert len(masks) >= 2

    # annotate: the log opened as `zcut annotate` opens it (annotate.server.open_page), frames in log
    # order as its catalogue prepares them (Catalogue.of_replay: the session's results)
    from replay.pipeline import config as cfg
    from replay.pipeline.bin_model import bin_model_for

    replay = ReplaySession.open(log, config_file=config, overrides=cfg.cli_layer(rho=0.05, step=0.25),
                                choose_bin_model=lambda reader: bin_model_for(reader, None))  # as every command
    for f, r in replay.results():
        assert np.array_equal(r.zcut_outliers, masks[f.index][0]), f"annotate, frame {f.index}"
        assert np.array_equal(r.sor_outliers, masks[f.index][1]), f"annotate, frame {f.index}"
    replay_config = cfg.from_dict(tomllib.loads(replay_toml))
    assert replay.config == replay_config

    # batch: the per-log config it resolved, and every frame's counts
    out = tmp_path / "batch"
    assert _cli("batch", log, "-o", out, "--config", config, *OVERRIDES, "--workers", "2",
                "--frames-per-unit", "1") == 0
    run = json.loads((out / "run.json").read_text())
    assert list(run["logs"].values()) == [cfg.config_sha256(replay_config)]
    rows = {r["frame"]: r for r in pq.read_table(out / "frames.parquet").to_pylist()}
    for row in replay_summary["frames"]:
        b = rows[row["index"]]
        assert (b["zcut"], b["sor"], b["both"], b["above_rim"], b["clusters"]) == \
            (row["zcut"], row["sor"], row["both"], row["above_rim"], row["clusters"])
    capsys.readouterr()

    if kind == "real":
        return  # no truth: accuracy and sweep need truth (their refusal is tested elsewhere)

    # accuracy: its counts over the valid region equal the replay masks' counts
    assert _cli("accuracy", log, "--config", config, *OVERRIDES, "--region", "valid", "--json") == 0
    rep = json.loads(capsys.readouterr().out)
    truth = {f.index: f.masks[layout.TRUTH_OUTLIERS] & np.isfinite(f.xyz).all(axis=2) for f in LogReader(log).frames()}
    for fr in rep["frames"]:
        zmask = masks[fr["index"]][0]
        tp = int((zmask & truth[fr["index"]]).sum())
        assert (fr["zcut"]["tp"], fr["zcut"]["fp"]) == (tp, int(zmask.sum()) - tp)

    # sweep: at the config's own point, the z-cut's and SOR's counts are the replay's
    sw = tmp_path / "sweep"
    assert _cli("sweep", log, "-o", sw, "--config", config, "--step", "0.25", "--max-depth", "20,25",
                "--rho", "0.05,0.1", "--sor-k", "6", "--workers", "2", "--no-report") == 0
    summary = json.loads((sw / "summary.json").read_text())
    # the sweep's base config is the file's (its grid replaces Δd and ρ): the same a_max, part and SOR
    base = tomllib.loads(summary["config"])
    assert base["zcut"]["a_max_px"] == z["a_max_px"] and base["sor"] == tomllib.loads(replay_toml)["sor"]
    t = pq.read_table(sw / "sweep.parquet").to_pylist()
    for row in replay_summary["frames"]:
        zc = [r for r in t if r["frame"] == row["index"] and r["method"] == "zcut" and r["step_mm"] == 0.25
              and r["max_depth_mm"] == 25.0 and abs(r["rho_thr"] - 0.05) < 1e-12]
        so = [r for r in t if r["frame"] == row["index"] and r["method"] == "sor" and r["sor_k"] == 6
              and r["sor_std_ratio"] == 1.0 and r["step_mm"] == 0.25 and r["max_depth_mm"] == 25.0]
        assert len(zc) == 1 and zc[0]["n_pred"] == row["zcut"]
        assert len(so) == 1 and so[0]["n_pred"] == row["sor"]
    capsys.readouterr()
