"""A results file without its cloud (the default of ``zcut replay --out``): ``/zcut/valid`` drives its
frames, ``zcut accuracy`` scores it as it scores the log and a results file with the cloud, and the
commands that need the points refuse it in one line saying how to get them (docs/formats.md)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from cli_helpers import accuracy_report, run_cli
from mcap.reader import make_reader

from annotate.truth import region_of_results_frame
from replay.errors import LogFormatError
from replay.logs import layout
from replay.logs.reader import LogReader


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    from session_logs import replay_out_once, synth_once

    from cli.main import main

    # the log and its lean results file are tests/replay/logs/test_packed_results.py's too: made once per session
    log = synth_once(tmp_path_factory, parts="rods", frames=2, seed=11, size="240x384")
    lean = replay_out_once(tmp_path_factory, log)
    full = tmp_path_factory.mktemp("cloudless") / "full.mcap"
    assert main(["replay", str(log), "--out", str(full), "--out-cloud"]) == 0
    return log, lean, full


def _topics(path):
    with open(path, "rb") as f:
        return {ch.topic for _, ch, _ in make_reader(f).iter_messages()}


def test_the_default_results_file_has_the_valid_mask_and_no_cloud(files):
    log, lean, full = files
    assert layout.VALID in _topics(lean) and layout.VALID in _topics(full)
    assert not {layout.FILTERED, layout.IMAGE} & _topics(lean)
    assert {layout.FILTERED, layout.IMAGE} <= _topics(full)
    assert lean.stat().st_size < 0.1 * full.stat().st_size


def test_its_frames_are_driven_by_the_valid_mask(files):
    log, lean, full = files
    src = list(LogReader(log).frames())
    got = list(LogReader(lean, cloudless=True).frames())
    assert [(f.index, f.stamp_ns, f.shape) for f in got] == [(f.index, f.stamp_ns, f.shape) for f in src]
    for g, s in zip(got, src, strict=True):
        assert not g.has_points and s.has_points and g.rgb is None
        assert g.topic == layout.VALID and np.isnan(g.xyz).all() and not g.xyz.flags.writeable
        assert np.array_equal(g.masks[layout.VALID], np.isfinite(s.xyz).all(axis=2))
        assert np.array_equal(g.masks[layout.TRUTH_OUTLIERS], s.masks[layout.TRUTH_OUTLIERS])
    # a results file with its cloud is read as before, with the mask beside it
    with_cloud = LogReader(full, cloudless=True)
    assert with_cloud.cloud_topic == layout.FILTERED and not with_cloud.cloudless
    assert layout.VALID in with_cloud.mask_topics


@pytest.mark.parametrize("region", ["zone", "valid"])
def test_its_region_is_that_of_the_results_file_with_the_cloud(files, region):
    _, lean, full = files
    for g, f in zip(LogReader(lean, cloudless=True).frames(), LogReader(full).frames(), strict=True):
        want = region_of_results_frame(f, region)
        assert want.any()
        assert np.array_equal(region_of_results_frame(g, region), want)
        # a results file written before /zcut/valid: the filtered cloud plus the z-cut's outliers
        old = dataclasses.replace(f, masks={k: v for k, v in f.masks.items() if k != layout.VALID})
        assert np.array_equal(region_of_results_frame(old, region), want)


@pytest.mark.parametrize("region", ["zone", "valid"])
def test_accuracy_scores_it_as_the_log_and_the_file_with_the_cloud(files, capsys, region):
    log, lean, full = files
    reps = [accuracy_report(capsys, p, "--region", region) for p in (log, full, lean)]
    assert reps[0]["frames"]
    for rep in reps[1:]:
        assert rep["pooled"] == reps[0]["pooled"] and rep["frames"] == reps[0]["frames"]


def test_commands_that_need_the_points_refuse_it_in_one_line(files, capsys):
    _, lean, _ = files
    with pytest.raises(LogFormatError, match="written without its cloud .*zcut replay --out-cloud"):
        LogReader(lean)
    for argv in (["replay", lean], ["bin-model", lean, "-o", lean.with_name("m.ply")]):
        rc, _, err = run_cli(capsys, *argv)
        lines = err.strip().splitlines()
        assert rc == 1 and lines[-1].startswith("error: ") and "--out-cloud" in lines[-1], err
        assert "Traceback" not in err


def test_topics_shows_the_valid_mask_driving_it(files, capsys):
    _, lean, _ = files
    rc, out, err = run_cli(capsys, "topics", lean, "--check")
    assert rc == 0, err
    assert f"cloud:       {layout.VALID}  (2 frames)" in out
