"""A log carries its bin model (docs/formats.md, "Bin model attachment"): ``zcut synth`` attaches the
exact model, ``zcut record --bin-model`` and ``zcut bin-model --into`` attach one, and every command
replays a log with its own model when no ``--bin-model`` is given -- or says, in one warning line,
that there is none and what to do. Real files, read back with the independent ``mcap`` library."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest
from cli_helpers import run_cli
from mcap.reader import make_reader
from mcap.writer import Writer

from replay.logs import layout
from replay.logs.mcap_scan import McapFile
from replay.logs.reader import LogReader
from replay.pipeline.bin_model import bin_model_for
from replay.synth.bin_surface import bin_model_points

SIZE = "200x150"
NO_MODEL = "carries no bin model"


def _sha(p) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def _without_attachments(src, dst) -> None:
    """``src`` rewritten by the ``mcap`` library without its attachments (an older or foreign log)."""
    with open(src, "rb") as f, open(dst, "wb") as g:
        r = make_reader(f)
        w = Writer(g)
        w.start(profile="ros2", library="test")
        schemas, channels = {}, {}
        for m in r.iter_metadata():
            w.add_metadata(m.name, m.metadata)
        for schema, channel, msg in r.iter_messages(log_time_order=False):
            if schema.id not in schemas:
                schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding,
                                                          schemas[schema.id], channel.metadata)
            w.add_message(channels[channel.id], msg.log_time, msg.data, msg.publish_time, msg.sequence)
        w.finish()


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("attach")
    synth, empty, bare = d / "rods.mcap", d / "empty.mcap", d / "bare.mcap"
    assert run_cli_plain("synth", "-o", synth, "--parts", "rods", "--frames", "2", "--size", SIZE, "--seed", "4") == 0
    assert run_cli_plain("synth", "-o", empty, "--empty", "--frames", "2", "--size", SIZE, "--seed", "4") == 0
    _without_attachments(synth, bare)
    return d, synth, empty, bare


def run_cli_plain(*argv) -> int:
    from cli.main import main

    return main([str(a) for a in argv])


def test_synth_attaches_the_exact_model(logs):
    _, synth, _, _ = logs
    with open(synth, "rb") as f:  # the independent reader, CRCs checked
        r = make_reader(f, validate_crcs=True)
        att, part = list(r.iter_attachments())  # and the part's mesh (docs/formats.md)
        assert r.get_summary().statistics.attachment_count == 2 and part.name == "part_model.ply"
    assert (att.name, att.media_type) == (layout.BIN_MODEL_ATTACHMENT, layout.BIN_MODEL_MEDIA_TYPE)
    reader = LogReader(synth)
    assert reader.bin_model_ply == att.data and reader.bin_model_problem is None
    points, normals = bin_model_points()
    np.testing.assert_allclose(reader.attached_bin_model.points, points, atol=1e-6)  # float32 in the file
    np.testing.assert_allclose(reader.attached_bin_model.normals, normals, atol=1e-6)
    choice = bin_model_for(reader, None)
    assert choice.source == "log" and choice.warning is None and len(choice.model.points) == len(points)


def test_replay_uses_the_logs_own_model(logs, capsys):
    _, synth, _, _ = logs
    rc, out, err = run_cli(capsys, "replay", synth, "--json")
    assert rc == 0, err
    assert NO_MODEL not in err and "warning:" not in err
    rows = json.loads(out)["frames"]
    assert all(not any("no bin model" in w for w in r["warnings"]) for r in rows)
    # registered with the attached model: the true pose (zcut.synth.poses) within a few mm
    assert all(r["pose_error_mm"] is not None and r["pose_error_mm"] < 3.0 for r in rows), rows


def test_a_log_without_a_model_warns_once_in_each_command(logs, capsys, tmp_path):
    _, _, _, bare = logs
    assert LogReader(bare).bin_model_ply is None and LogReader(bare).bin_model_problem is None
    for argv in (("replay", bare), ("accuracy", bare), ("batch", bare, "-o", tmp_path / "b"),
                 ("sweep", bare, "--step", "0.2", "--max-depth", "30", "--rho", "0.07", "-o", tmp_path / "s",
                  "--no-report")):
        rc, _, err = run_cli(capsys, *argv)
        assert rc == 0, (argv, err)
        lines = [line for line in err.splitlines() if NO_MODEL in line]
        assert len(lines) == 1, (argv[0], err)
        assert lines[0].startswith(f"warning: {bare} carries no bin model (no bin_model.ply attachment)")
        assert f"zcut bin-model EMPTY.mcap --into {bare} -o NEW.mcap" in lines[0] and "--bin-model PLY" in lines[0]
    rc, _, err = run_cli(capsys, "replay", bare, "--bin-model", tmp_path / "none.ply")
    assert rc == 1 and err.startswith("error: no such file")


@pytest.mark.slow
def test_annotate_uses_the_logs_model_and_says_so_on_the_page(logs, tmp_path):
    """``zcut annotate`` (a real server process) replays with the log's own model; without one it prints
    the one warning line and the page lists it among its notes (it shows little to label: now it says why)."""
    import httpx
    from annotate_helpers import ServerProcess

    _, synth, _, bare = logs
    for log, has in ((synth, True), (bare, False)):
        srv = ServerProcess(log, tmp_path / f"{log.stem}.sqlite", annotator="alice")
        try:
            notes = httpx.get(f"{srv.base}/api/session", headers=srv.headers()).json()["notes"]
        finally:
            srv.stop()
        warned = [x for x in srv.stderr_lines if NO_MODEL in x]
        if has:
            assert not warned and not any(NO_MODEL in n for n in notes), (srv.stderr_lines, notes)
        else:
            assert len(warned) == 1 and warned[0].startswith(f"warning: {bare} carries no bin model")
            assert any(n.startswith(f"{bare} carries no bin model") for n in notes), notes


def test_bin_model_into_writes_a_copy_and_never_the_input(logs, tmp_path, capsys):
    _, _, empty, bare = logs
    before = _sha(bare)
    new = tmp_path / "new.mcap"
    rc, out, err = run_cli(capsys, "bin-model", empty, "--into", bare, "-o", new)
    assert rc == 0, err
    assert _sha(bare) == before  # the input is only read
    assert f"wrote {new}: a copy of {bare} carrying its bin model" in err
    with open(bare, "rb") as f, open(new, "rb") as g:  # the same messages, now with the model, CRCs valid
        old = [(c.topic, m.log_time, m.data) for _, c, m in make_reader(f).iter_messages()]
        r = make_reader(g, validate_crcs=True)
        assert [(c.topic, m.log_time, m.data) for _, c, m in r.iter_messages()] == old
        (att,) = list(r.iter_attachments())
        assert att.name == layout.BIN_MODEL_ATTACHMENT and r.get_summary().statistics.attachment_count == 1
    reader = LogReader(new)
    assert reader.attached_bin_model is not None and len(reader.attached_bin_model.points) > 1000
    rc, out, err = run_cli(capsys, "replay", new, "--json")
    assert rc == 0 and NO_MODEL not in err and "warning:" not in err, err
    assert all(r["fitness"] is not None for r in json.loads(out)["frames"])
    # into a log that already carries one: the copy carries the new one only
    newer = tmp_path / "newer.mcap"
    rc, _, err = run_cli(capsys, "bin-model", "--model", tmp_path / "m.ply", "--into", new, "-o", newer)
    assert rc == 1  # no such --model
    ply = tmp_path / "m.ply"
    rc, _, err = run_cli(capsys, "bin-model", empty, "-o", ply)  # beside, as a PLY, as before
    assert rc == 0 and ply.read_bytes()[:3] == b"ply", err
    rc, _, err = run_cli(capsys, "bin-model", "--model", ply, "--into", new, "-o", newer)
    assert rc == 0 and "is replaced in the copy" in err, err
    with McapFile(newer) as mf:
        assert [a.name for a in mf.summary.attachment_indexes] == [layout.BIN_MODEL_ATTACHMENT]
    assert LogReader(newer).attached_bin_model is not None
    # a log whose summary is lost cannot be copied: one line, nothing written
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(bare.read_bytes()[:-200])
    rc, _, err = run_cli(capsys, "bin-model", empty, "--into", cut, "-o", tmp_path / "x.mcap")
    assert rc == 1 and err.count("\n") == 1 and "summary" in err, err
    assert not (tmp_path / "x.mcap").exists()
    rc, _, err = run_cli(capsys, "bin-model", empty, "--into", bare, "-o", bare, "--force")
    assert rc == 1 and _sha(bare) == before  # the output may never be the input


def test_record_attaches_a_bin_model(logs, tmp_path, capsys, real_data):
    _, _, empty, _ = logs
    ply = tmp_path / "bin.ply"
    assert run_cli(capsys, "bin-model", empty, "-o", ply)[0] == 0
    out = tmp_path / "rec.mcap"
    pcds = [real_data / "mosd_test16.pcd", real_data / "mosd_test20.pcd"]
    rc, printed, err = run_cli(capsys, "record", *pcds, "-o", out, "--bin-model", ply)
    assert rc == 0, err
    assert f"with the bin model {ply}" in printed
    reader = LogReader(out)
    assert reader.bin_model_ply == ply.read_bytes()
    rc, printed, err = run_cli(capsys, "topics", out)
    assert "bin model:   its bin_model.ply attachment" in printed
    plain = tmp_path / "plain.mcap"
    assert run_cli(capsys, "record", *pcds, "-o", plain)[0] == 0
    assert LogReader(plain).bin_model_ply is None
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n2\n3\n")
    rc, _, err = run_cli(capsys, "record", *pcds, "-o", tmp_path / "r2.mcap", "--bin-model", bad)
    assert rc == 1 and "has no 'y' property" in err and not (tmp_path / "r2.mcap").exists()


def test_a_damaged_attachment_is_a_named_warning(logs, tmp_path, capsys):
    _, synth, _, _ = logs
    raw = bytearray(synth.read_bytes())
    with McapFile(synth) as mf:
        (a,) = [x for x in mf.summary.attachment_indexes if x.name == layout.BIN_MODEL_ATTACHMENT]
    raw[a.offset + a.length // 2] ^= 0xFF  # inside the PLY data: the attachment's CRC no longer holds
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(raw))
    reader = LogReader(bad)
    assert reader.bin_model_ply is None and "attachment is damaged (fails its CRC check)" in reader.bin_model_problem
    rc, _, err = run_cli(capsys, "replay", bad)
    assert rc == 0 and "Traceback" not in err, err
    (line,) = [x for x in err.splitlines() if "bin_model.ply" in x]
    assert line.startswith(f"warning: {bad}: its bin_model.ply attachment is damaged (fails its CRC check) and no "
                           "--bin-model was given")
    rc, _, err = run_cli(capsys, "replay", bad, "--bin-model", tmp_path / "none.ply")
    assert rc == 1


def test_an_explicit_model_wins_and_each_log_of_a_batch_gets_its_own(logs, tmp_path, capsys):
    _, synth, empty, bare = logs
    ply = tmp_path / "bin.ply"
    assert run_cli(capsys, "bin-model", empty, "-o", ply)[0] == 0
    choice = bin_model_for(LogReader(synth), ply)
    assert choice.source == "explicit" and len(choice.model.points) != len(bin_model_points()[0])
    rc, _, err = run_cli(capsys, "batch", synth, bare, "-o", tmp_path / "b", "--json")
    assert rc == 0, err
    assert err.count(NO_MODEL) == 1 and f"warning: {bare} carries no bin model" in err
    import pyarrow.parquet as pq

    t = pq.read_table(tmp_path / "b" / "frames.parquet").to_pylist()
    by_log = {}
    for r in t:
        by_log.setdefault(r["log"].rsplit("/", 1)[-1], []).append(r["warnings"])
    assert all("no bin model" not in w for w in by_log["rods.mcap"])
    assert all("no bin model" in w for w in by_log["bare.mcap"])


def test_the_raytraced_sensor_attaches_the_same_bin(tmp_path):
    """Both generators draw the same bin (replay.presets.BIN) at the same poses: the same model."""
    from replay.synth.bin_surface import bin_model_ply
    from replay.synth.raytrace import write_raytraced_log

    rt = write_raytraced_log(tmp_path / "rt.mcap", kind="spheres", frames=1, seed=3, size=(40, 64), fill_mm=20.0)
    assert LogReader(rt).bin_model_ply == bin_model_ply()


def test_a_pose_error_only_for_a_model_in_the_truths_frame(logs, capsys, tmp_path):
    """The log's own model, attached or given as the same file: a pose error against the true pose; a
    model turned by 0.5° about the bin's centre (another frame: its own displacement would be read as
    the registration's error) registers as well, but its pose error is null (issue 31)."""
    from replay.pipeline.bin_model import save_bin_model
    from zcut.bin_model import BinModel

    _, synth, _, _ = logs
    own = LogReader(synth).attached_bin_model
    same, turned = tmp_path / "same.ply", tmp_path / "turned.ply"
    save_bin_model(BinModel(own.points.astype(np.float64), own.normals.astype(np.float64), 0.002), same)
    a = np.radians(0.5)
    R = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    c = own.points.mean(axis=0)
    pts = (own.points.astype(np.float64) - c) @ R.T + c
    save_bin_model(BinModel(pts, own.normals.astype(np.float64) @ R.T, 0.002), turned)
    for model, stated in ((None, True), (same, True), (turned, False)):
        argv = ["replay", synth, "--json"] + (["--bin-model", model] if model is not None else [])
        rc, out, err = run_cli(capsys, *argv)
        assert rc == 0, err
        rows = json.loads(out)["frames"]
        assert all(r["rmse_mm"] is not None for r in rows), rows
        if stated:
            assert all(r["pose_error_mm"] is not None and r["pose_error_mm"] < 3.0 for r in rows), (model, rows)
        else:
            assert all(r["pose_error_mm"] is None and r["pose_error_deg"] is None for r in rows), rows
