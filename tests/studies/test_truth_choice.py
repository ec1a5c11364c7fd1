"""Which truth scores a log (docs/accuracy.md, "Two truths"): the paper's ``/ground_truth/off_surface`` by
default where the log has it, the sensor's ``/ground_truth/outliers`` on request (the counts of before) or
where the log lacks the paper's (and the report says so); ``--truth paper`` of such a log is one line; the
choice reaches a batch's spawned worker."""

from __future__ import annotations

import json

import pyarrow.parquet as pq
import pytest
from cli_helpers import run_cli, synth_log

from cli.main import main
from replay.logs import layout
from replay.logs.reader import LogReader
from replay.logs.writer import LogWriter

METHODS = ("zcut", "sor", "union", "intersection")
PAPER = "the paper's truth /ground_truth/off_surface"
FALLBACK = "the sensor's truth /ground_truth/outliers (the log has no /ground_truth/off_surface)"


def _without_paper_truth(src, dest):
    """The log as written before the paper's truth: every frame, kind image, metadata and attachment
    but ``/ground_truth/off_surface``."""
    reader = LogReader(src)
    att = {layout.BIN_MODEL_ATTACHMENT: (layout.BIN_MODEL_MEDIA_TYPE, reader.bin_model_ply)}
    with LogWriter(dest, metadata={k: dict(v) for k, v in reader.metadata.items()}, attachments=att) as w:
        for f in reader.frames():
            assert f.masks.pop(layout.TRUTH_OFF_SURFACE) is not None
            w.write_frame(f)
            for topic, codes in f.codes.items():
                w.write_codes(topic, codes, stamp_ns=f.stamp_ns, frame_id=f.frame_id)


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("truth_choice")
    log = synth_log(d / "nuts.mcap", parts="zinc_nuts", frames=2, seed=29, size="200x160")
    old = d / "old.mcap"
    _without_paper_truth(log, old)
    results = d / "results.mcap"
    assert main(["replay", str(log), "--out", str(results)]) == 0
    return log, old, results


def _manual(log, results, topic):
    """Per frame, per method, (tp, fp, fn) over S = zone ∩ valid against ``topic``, from the replay's masks."""
    truth = {f.stamp_ns: f.masks[topic] for f in LogReader(log).frames()}
    out = []
    for f in LogReader(results, cloudless=True).frames():
        s = f.masks[layout.ZONE] & f.masks[layout.VALID]
        z, o = f.masks[layout.ZCUT_OUTLIERS], f.masks[layout.SOR_OUTLIERS]
        lab = truth[f.stamp_ns] & s
        row = {}
        for m, p in (("zcut", z), ("sor", o), ("union", z | o), ("intersection", z & o)):
            p = p & s
            row[m] = (int((p & lab).sum()), int((p & ~lab).sum()), int((lab & ~p).sum()))
        out.append(row)
    return out


def _counts(rep):
    return [{m: (fr[m]["tp"], fr[m]["fp"], fr[m]["fn"]) for m in METHODS} for fr in rep["frames"]]


def _json(capsys, *argv):
    rc, out, err = run_cli(capsys, *argv)
    assert rc == 0, err
    return json.loads(out)


def test_accuracy_scores_the_paper_truth_by_default(logs, capsys):
    log, _, results = logs
    rep = _json(capsys, "accuracy", log, "--json")
    assert rep["truth"].startswith(PAPER)
    assert _counts(rep) == _manual(log, results, layout.TRUTH_OFF_SURFACE)
    assert "by_kind" not in rep["pooled"]["zcut"]  # the kinds say what made a sensor's outlier
    # asked for by name: the same report; the table says which truth
    assert _json(capsys, "accuracy", log, "--json", "--truth", "paper") == rep
    rc, out, err = run_cli(capsys, "accuracy", log)
    assert rc == 0 and out.startswith(f"truth: {PAPER}"), err


def test_truth_sensor_gives_the_counts_of_before(logs, capsys):
    log, old, results = logs
    sensor = _json(capsys, "accuracy", log, "--json", "--truth", "sensor")
    before = _json(capsys, "accuracy", old, "--json")  # a log without the paper's truth: scored as before
    assert sensor.pop("truth") == "the sensor's truth /ground_truth/outliers"
    assert before.pop("truth") == FALLBACK
    assert sensor == before
    assert _counts(sensor) == _manual(log, results, layout.TRUTH_OUTLIERS)
    assert "by_kind" in sensor["pooled"]["zcut"]
    assert _counts(sensor) != _counts(_json(capsys, "accuracy", log, "--json"))  # the two truths differ here
    rc, out, err = run_cli(capsys, "accuracy", old)
    assert rc == 0 and out.startswith(f"truth: {FALLBACK}"), err


def test_truth_paper_of_a_log_without_it_is_one_line(logs, tmp_path, capsys):
    _, old, _ = logs
    for argv in (("accuracy", old), ("sweep", old, "-o", tmp_path / "s"), ("batch", old, "-o", tmp_path / "b",
                 "--workers", "0"), ("compare", old, "--a", "zcut", "--b", "sor", "-o", tmp_path / "c")):
        rc, _, err = run_cli(capsys, *argv, "--truth", "paper")
        assert rc == 1 and len(err.strip().splitlines()) == 1, (argv[0], err)
        assert "old.mcap has no /ground_truth/off_surface (--truth paper): score it with --truth sensor" in err, err
    assert not any((tmp_path / n).exists() for n in "sbc")
    rc, _, err = run_cli(capsys, "accuracy", old, "--truth", "sensor", "--labels", old)
    assert rc == 1 and len(err.strip().splitlines()) == 1 and "give one" in err, err


def test_the_choice_reaches_a_spawned_batch_worker(logs, tmp_path, capsys):
    log, _, _ = logs
    for truth, argv in (("sensor", ("--truth", "sensor")), ("paper", ())):
        out = tmp_path / truth
        s = _json(capsys, "batch", log, "-o", out, "--workers", "1", "--json", *argv)  # a spawned process
        assert s["accuracy"]["truth"] == truth and [lg["truth"] for lg in s["logs"]] == [truth]
        rows = sorted(pq.read_table(out / "frames.parquet").to_pylist(), key=lambda r: r["frame"])
        assert {r["truth"] for r in rows} == {truth}
        rep = _json(capsys, "accuracy", log, "--json", *argv)
        assert [{m: (r[f"{m}_tp"], r[f"{m}_fp"], r[f"{m}_fn"]) for m in METHODS} for r in rows] == _counts(rep)
        rc, text, err = run_cli(capsys, "batch", log, "-o", out, "--workers", "1", *argv)  # resumed: the same truth
        assert rc == 0 and "1 already done" in err and f"against the {truth}'s truth" in text, err
    # the other truth over the same folder is another study, refused as other options are
    rc, _, err = run_cli(capsys, "batch", log, "-o", tmp_path / "paper", "--truth", "sensor", "--workers", "1")
    assert rc == 1 and "other options" in err, err


def test_compare_names_its_truth(logs, tmp_path, capsys):
    log, old, _ = logs
    for path, want in ((log, PAPER), (old, FALLBACK)):
        rc, out, err = run_cli(capsys, "compare", path, "--a", "zcut", "--b", "sor", "-o", tmp_path / path.stem,
                               "--no-rrd")
        assert rc == 0, err
        assert json.loads((tmp_path / path.stem / "compare.json").read_text())["truth"].startswith(want)
        assert f"truth: {want}" in out
