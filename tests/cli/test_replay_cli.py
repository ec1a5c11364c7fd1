"""``zcut replay``, ``zcut bin-model``, ``zcut demo`` end to end on real small MCAP files."""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest
import rerun as rr
from cli_helpers import run_cli

from cli.main import main
from replay.logs.reader import LogReader
from replay.logs.writer import LogWriter
from replay.synth.log import write_synthetic_log
from replay.synth.scene import BinShape
from zcut.cuts import zcut_outliers

SIZE = (300, 480)  # at 240 x 150 a pixel spans ~3.7 mm: the nominal 0.2 mm step cuts the noise into slivers


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("logs")
    filled = write_synthetic_log(d / "rods.mcap", kind="rods", frames=2, seed=7, size=SIZE)
    empty = write_synthetic_log(d / "empty.mcap", empty=True, frames=5, seed=7, size=SIZE)
    return d, filled, empty


@pytest.fixture(scope="module")
def bin_ply(logs):
    d, _, empty = logs
    out = d / "bin.ply"
    assert main(["bin-model", str(empty), "-o", str(out)]) == 0
    return out



def test_bin_model_from_empty_scans(bin_ply, logs):
    from replay.pipeline.bin_model import load_bin_model

    m = load_bin_model(bin_ply)
    assert len(m.points) > 1000 and m.normals is not None
    # a bin of 400 x 300 mm: the model spans about that (metres)
    ext = m.points.max(axis=0) - m.points.min(axis=0)
    assert 0.3 < ext[0] < 0.5 and 0.2 < ext[1] < 0.4


def test_bin_model_from_one_scan_warns_and_from_two_does_not(tmp_path, capsys, logs):
    _, _, empty = logs
    rc, _, err = run_cli(capsys, "bin-model", empty, "--frames", "0:1", "-o", tmp_path / "one.ply")
    assert rc == 0 and (tmp_path / "one.ply").is_file()
    warnings = [ln for ln in err.splitlines() if ln.startswith("warning:")]
    assert len(warnings) == 1 and "built from 1 scan" in warnings[0] and "2 or more" in warnings[0], err
    rc, _, err = run_cli(capsys, "bin-model", empty, "--frames", "0:2", "-o", tmp_path / "two.ply")
    assert rc == 0 and "warning:" not in err, err


def test_replay_with_bin_model_writes_rrd_results_and_config(tmp_path, capsys, logs, bin_ply):
    _, filled, _ = logs
    rrd, res = tmp_path / "r.rrd", tmp_path / "res.mcap"
    rc, out, err = run_cli(capsys, "replay", filled, "--bin-model", bin_ply, "--rrd", rrd, "--out", res, "--json",
                           "--out-cloud")
    assert rc == 0, err
    assert "part: rods (from the log's zcut.synth metadata)" in err
    assert "the paper's nominal values" in err
    summary = json.loads(out)
    assert [f["index"] for f in summary["frames"]] == [0, 1]
    assert all(f["fitness"] is not None and f["fitness"] > 0.3 for f in summary["frames"])
    assert summary["config"]["part"] == "rods" and summary["config"]["parameters"] == "nominal"
    # the resolved config is beside the outputs and reads back to the same values
    for p in (tmp_path / "r.config.toml", tmp_path / "res.config.toml"):
        assert tomllib.loads(p.read_text())["zcut"] == summary["config"]["zcut"]
    # results: docs/formats.md topics, ground truth passed through, counts as in the summary
    r = LogReader(res)
    assert {"/zcut/outliers", "/zcut/sor_outliers", "/zcut/bin_mask", "/ground_truth/outliers"} <= set(r.mask_topics)
    assert "/zcut/filtered" in r.topics
    frames = list(r.frames())
    for f, row in zip(frames, summary["frames"]):
        assert f.masks["/zcut/outliers"].sum() == row["zcut"]
        assert f.masks["/zcut/sor_outliers"].sum() == row["sor"]
        assert f.masks["/zcut/bin_mask"].any()
    # with the bin removed, most z-cut outliers are true ones (the noisy rim is not in the zone)
    tp = sum(int((f.masks["/zcut/outliers"] & f.masks["/ground_truth/outliers"]).sum()) for f in frames)
    assert tp >= 0.5 * sum(row["zcut"] for row in summary["frames"]) > 0
    src = list(LogReader(filled).frames())
    for f, s in zip(frames, src):
        assert np.array_equal(f.masks["/ground_truth/outliers"], s.masks["/ground_truth/outliers"])
        assert np.isnan(f.xyz[f.masks["/zcut/outliers"]]).all()  # /zcut/filtered has the outliers NaN
        keep = ~f.masks["/zcut/outliers"] & np.isfinite(s.xyz).all(axis=2)
        assert np.array_equal(f.xyz[keep], s.xyz[keep])
    # the .rrd holds both frames' counts
    counts = []
    for ch in rr.chunk.RrdReader(str(rrd)).stream():
        if ch.entity_path == "/counts/zcut":
            counts += [v[0] for v in ch.to_record_batch().column("Scalars:scalars").to_pylist()]
    assert counts == [float(f["zcut"]) for f in summary["frames"]]


def test_the_bin_check_in_the_table_the_json_the_rrd_and_a_warning_naming_the_frame(tmp_path, capsys, logs,
                                                                                    bin_ply):
    """The paper's removal on a bin 1 mm bigger than its model: every frame flagged, with what to do; the
    default removal: none."""
    d, _, _ = logs
    big = write_synthetic_log(d / "big.mcap", kind="rods", frames=2, seed=7, size=SIZE,
                              bin_shape=BinShape(scale=1.005))
    paper = tmp_path / "paper.toml"
    paper.write_text('[removal]\nmode = "paper"\n')
    rrd = tmp_path / "p.rrd"
    rc, out, err = run_cli(capsys, "replay", big, "--bin-model", bin_ply, "--config", paper, "--rrd", rrd)
    assert rc == 0, err
    head, *rows = out.strip().splitlines()
    col = head.index("bin chk")
    assert all(r[col - 1:col + 7].strip().endswith("!") for r in rows)
    for i in (0, 1):
        assert f"warning: frame {i}: bin check: " in err
    assert 'use removal.mode = "robust"' in err
    assert "warning: 2 of 2 frame(s) flagged by the bin check" in err
    flagged, pixels = [], []
    for ch in rr.chunk.RrdReader(str(rrd)).stream():
        cols = ch.to_record_batch()
        if ch.entity_path == "/bin_check/flagged":
            flagged += [v[0] for v in cols.column("Scalars:scalars").to_pylist()]
        if ch.entity_path == "/bin_check/pixels":
            pixels += [v[0] for v in cols.column("Scalars:scalars").to_pylist()]
    assert flagged == [1.0, 1.0] and all(p > 0 for p in pixels)
    rc, out, err = run_cli(capsys, "replay", big, "--bin-model", bin_ply, "--json")
    assert rc == 0, err
    summary = json.loads(out)
    assert [(f["bin_check"], f["bin_flagged"]) for f in summary["frames"]] == [(0.0, False), (0.0, False)]
    assert summary["totals"]["bin_flagged"] == 0 and "bin check" not in err
    assert summary["config"]["removal"]["mode"] == "robust"


def test_table_and_overrides_and_one_frame(tmp_path, capsys, logs):
    _, filled, _ = logs
    rrd = tmp_path / "one.rrd"
    rc, out, err = run_cli(capsys, "replay", filled, "--frames", "1:2", "--step", "0.5", "--max-depth", "20",
                           "--max-area", "77", "--rrd", rrd)
    assert rc == 0, err
    lines = out.strip().splitlines()
    assert lines[0].split()[:5] == ["frame", "stamp_ns", "valid", "px", "z-cut"]
    assert len(lines) == 2 and lines[1].split()[0] == "1"
    assert "no bin model" not in err  # the synthetic log carries its own (test_bin_model_attachment: the warning)
    z = tomllib.loads((tmp_path / "one.config.toml").read_text())["zcut"]
    assert (z["step_mm"], z["max_depth_mm"], z["max_area_px"]) == (0.5, 20.0, 77.0)
    assert f"rerun --bind 127.0.0.1 {rrd}" in err  # the viewer it names listens on this machine only


def test_config_file_and_its_errors(tmp_path, capsys, logs):
    _, filled, _ = logs
    good = tmp_path / "c.toml"
    good.write_text("[zcut]\nmax_area_px = 55.0\n[sor]\nk = 6\n")
    rc, out, err = run_cli(capsys, "replay", filled, "--frames", "0", "--config", good, "--json")
    assert rc == 0, err
    c = json.loads(out)["config"]
    assert c["zcut"]["max_area_px"] == 55.0 and c["sor"]["k"] == 6
    bad = tmp_path / "bad.toml"
    bad.write_text("[zcut]\nstepmm = 1\n")
    rc, out, err = run_cli(capsys, "replay", filled, "--config", bad)
    assert rc == 1 and err.startswith("error: ") and "unknown key zcut.stepmm" in err and "Traceback" not in err


@pytest.mark.parametrize("argv, msg", [
    (["--frames", "3:1"], "--frames must satisfy"),
    (["--frames", "x"], "--frames must look like"),
    (["--step", "-1"], "zcut.step_mm must be a number > 0, got -1.0"),
    (["--bin-model", "/nonexistent/bin.ply"], "no such file"),
    (["--frames", "5:9"], "in --frames 5:9 (it has 2 frames, indices 0..1)"),
])
def test_bad_options_are_one_line_errors(capsys, logs, argv, msg):
    _, filled, _ = logs
    rc, _, err = run_cli(capsys, "replay", filled, *argv)
    assert rc == 1 and msg in err and len(err.strip().splitlines()) == 1


def test_truncated_log_processes_intact_frames_and_exits_3(tmp_path, capsys, rng):
    from replay.logs.frame import Frame

    path = tmp_path / "t.mcap"
    with LogWriter(path, chunk_size=1024) as w:  # a chunk per message: a cut loses only the tail
        for i in range(4):
            xyz = np.stack(np.meshgrid(np.linspace(-0.1, 0.1, 64), np.linspace(-0.1, 0.1, 48)), -1)
            z = 0.5 + 0.002 * rng.standard_normal((48, 64))
            z[10, 10] -= 0.05
            xyz = np.concatenate([xyz, z[..., None]], -1).astype(np.float32)
            w.write_frame(Frame(xyz, None, 1000 + i, "cam", None, "/camera/points", i))
    data = path.read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: int(len(data) * 0.6)])
    rc, out, err = run_cli(capsys, "replay", tmp_path / "cut.mcap", "--json", "--max-area", "5")
    assert rc == 3, err
    summary = json.loads(out)
    assert 1 <= len(summary["frames"]) < 4 and summary["damage"]
    assert "data loss" in err
    assert all(f["zcut"] >= 1 for f in summary["frames"])  # the lifted pixel is found in every intact frame


def test_real_kinect_log_without_bin_equals_bare_zcut(tmp_path, capsys, real_data):
    log = real_data / "mosd_clutter_kinect_ros2.mcap"
    res = tmp_path / "res.mcap"
    rc, out, err = run_cli(capsys, "replay", log, "--out", res, "--json", "--step", "0.5", "--max-depth", "40",
                           "--max-area", "200")
    assert rc == 0, err
    assert "no RGB image" in err or "no bin model" in err
    summary = json.loads(out)
    assert len(summary["frames"]) == 2
    got = {f.stamp_ns: f.masks["/zcut/outliers"] for f in LogReader(res, cloudless=True).frames()}
    for f in LogReader(log).frames():
        expect = zcut_outliers(-1000.0 * f.xyz[..., 2].astype(np.float64), step=0.5, max_depth=40.0, max_area=200.0)
        assert np.array_equal(got[f.stamp_ns], expect)
        assert expect.any()


def test_real_pcd_recorded_then_replayed(tmp_path, capsys, real_data):
    log = tmp_path / "mug.mcap"
    assert main(["record", str(real_data / "table_scene_mug_stereo_textured.pcd"), "-o", str(log)]) == 0
    capsys.readouterr()
    rrd = tmp_path / "mug.rrd"
    rc, out, err = run_cli(capsys, "replay", log, "--rrd", rrd, "--json")
    assert rc == 0, err
    row = json.loads(out)["frames"][0]
    assert row["valid_px"] > 50_000 and row["zcut"] > 0 and row["sor"] > 0
    assert "no bin model" in err
    assert rrd.stat().st_size > 0


def test_bin_model_from_a_given_ply(tmp_path, capsys, bin_ply):
    out = tmp_path / "copy.ply"
    rc, _, err = run_cli(capsys, "bin-model", "--model", bin_ply, "-o", out)
    assert rc == 0 and "points from" in err
    rc, _, err = run_cli(capsys, "bin-model", "-o", out)
    assert rc == 1 and "give either EMPTY.mcap or --model PLY" in err
    notply = tmp_path / "x.ply"
    notply.write_text("hello")
    rc, _, err = run_cli(capsys, "bin-model", "--model", notply, "-o", out, "--force")
    assert rc == 1 and "not a PLY file" in err


@pytest.mark.slow
def test_demo_end_to_end(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("ZCUT_CACHE", str(tmp_path / "cache"))
    rc, out, err = run_cli(capsys, "demo", "--out-dir", tmp_path / "out")
    assert rc == 0, err
    assert "True accuracy against the sample's exact truth, the paper's truth /ground_truth/off_surface" in out
    assert "rerun --bind 127.0.0.1 " + str(tmp_path / "out" / "zcut_demo.rrd") in out
    # the next steps are exact commands on the demo's own outputs: each parses, and one runs
    import shlex

    from cli.main import build_parser

    steps = {}
    for line in out[out.index("Next steps on the demo's own outputs:"):].splitlines()[1:]:
        if line.lstrip().startswith("#"):
            continue
        words = shlex.split(line.replace('"$USER"', "someone"))
        if len(words) > 1 and words[0].endswith("zcut"):
            steps[words[1]] = words[1:]
    assert set(steps) == {"annotate", "accuracy", "sweep", "batch"}
    for argv in steps.values():
        build_parser().parse_args(argv)
    assert str(tmp_path / "out" / "zcut_demo_results.mcap") in steps["accuracy"]
    rc, acc, acc_err = run_cli(capsys, *steps["accuracy"])
    assert rc == 0 and "recall" in acc, acc_err
    assert "part: rods (from the log's zcut.synth metadata)" in err
    rows = [ln for ln in out.splitlines() if ln.split() and ln.split()[0] in ("zcut", "sor")]
    assert len(rows) == 2
    assert (tmp_path / "out" / "zcut_demo.rrd").stat().st_size < 10 * 1024 * 1024 * 3


def test_preset_on_a_real_log_estimates_the_camera(capsys, real_data):
    log = real_data / "mosd_clutter_kinect_ros2.mcap"
    rc, out, err = run_cli(capsys, "replay", log, "--preset", "black_nuts", "--frames", "0", "--json")
    assert rc == 0, err
    assert "part: black_nuts (from the command line)" in err and "§5.4 ranges for black_nuts" in err
    assert "fitted to the first frame's organized cloud: fx 525.0" in err  # the Kinect's focal length
    z = json.loads(out)["config"]["zcut"]
    assert z["max_area_px"] == pytest.approx(0.07 * z["a_max_px"])
    rc, _, err = run_cli(capsys, "replay", log, "--preset", "bolts")
    assert rc == 1 and "invalid choice: 'bolts'" in err


def test_intrinsics_from_an_organized_cloud():
    import pipeline_scene as ps

    from replay.pipeline.config import intrinsics_from_cloud

    frame, _ = ps.scene(h=60, w=80)
    K = intrinsics_from_cloud(frame.xyz)
    true = ps.intrinsics(60, 80)
    assert K.fx == pytest.approx(true.fx, rel=1e-4) and K.cy == pytest.approx(true.cy, abs=1e-3)
    assert intrinsics_from_cloud(np.full((20, 20, 3), np.nan, np.float32)) is None


@pytest.mark.slow
def test_connect_to_a_missing_viewer_does_not_hang(capsys, real_data):
    import socket

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    log = real_data / "mosd_clutter_kinect_ros2.mcap"
    rc, out, err = run_cli(capsys, "replay", log, "--connect", f"rerun+http://127.0.0.1:{port}/proxy", "--frames", "0")
    assert rc == 1 and out == ""
    assert err.startswith("error: --connect") and "no viewer" in err and len(err.strip().splitlines()) == 1
    rc, out, err = run_cli(capsys, "replay", log, "--connect", "not a url")
    assert rc == 1 and "expected a viewer URL like rerun+http://" in err


def test_bin_model_from_a_cad_mesh_in_millimetres_with_z_up(tmp_path, capsys):
    import open3d as o3d

    from replay.pipeline.bin_model import load_bin_model

    box = o3d.geometry.TriangleMesh.create_box(400.0, 300.0, 120.0)  # mm, +z up, origin at a corner
    cad = tmp_path / "bin_cad.ply"
    o3d.io.write_triangle_mesh(str(cad), box)
    out = tmp_path / "bin.ply"
    rc, _, err = run_cli(capsys, "bin-model", "--model", cad, "--z-up", "--scale", "0.001", "--voxel", "5", "-o", out)
    assert rc == 0, err
    m = load_bin_model(out)
    assert np.allclose(m.points.min(axis=0), [0.0, -0.3, -0.12], atol=0.006)
    assert np.allclose(m.points.max(axis=0), [0.4, 0.0, 0.0], atol=0.006)
    top = m.points[:, 2] < -0.119  # the box's top face (z = 120 mm) is now the nearest to a camera
    assert top.any() and np.median(np.abs(m.normals[top][:, 2])) > 0.99


# ------------------------------------------------------------------ the reader thread (replay.pipeline.session.prefetched)

def test_prefetched_yields_in_order_and_raises_where_the_iterator_did():
    import threading

    from replay.pipeline.session import prefetched

    def gen():
        yield from range(5)
        raise ValueError("frame 5 is broken")

    got = []
    with pytest.raises(ValueError, match="frame 5 is broken"):
        for x in prefetched(gen(), depth=2):
            got.append(x)  # noqa: PERF402 - the items before the error
    assert got == [0, 1, 2, 3, 4]
    assert not any(t.name == "zcut-frame-reader" for t in threading.enumerate())


def test_prefetched_close_stops_the_thread_and_closes_the_iterator():
    import threading

    from replay.pipeline.session import prefetched

    closed = []

    def gen():
        try:
            yield from range(1000)
        finally:
            closed.append(True)

    it = prefetched(gen())
    assert [next(it), next(it)] == [0, 1]
    it.close()
    assert closed == [True]
    assert not any(t.name == "zcut-frame-reader" for t in threading.enumerate())


def test_background_sinks_run_in_order_in_one_thread_and_report_errors():
    import threading

    from replay.pipeline.sinks import BackgroundSinks

    class Recorder:
        def __init__(self, fail_at=None):
            self.seen, self.closed, self.fail_at = [], None, fail_at

        def start(self, info):
            pass

        def write(self, frame, result):
            if frame == self.fail_at:
                raise OSError("disk full")
            self.seen.append((frame, threading.current_thread().name))

        def close(self, *, completed):
            self.closed = completed

        def outputs(self):
            return {}

    rec = Recorder()
    sinks = BackgroundSinks([rec])
    for i in range(5):
        sinks.write(i, None)
    sinks.close(completed=True)
    assert [i for i, _ in rec.seen] == list(range(5)) and rec.closed is True
    assert all(name.startswith("zcut-sinks") for _, name in rec.seen)
    rec = Recorder(fail_at=1)
    sinks = BackgroundSinks([rec])
    sinks.write(0, None)
    sinks.write(1, None)
    with pytest.raises(OSError, match="disk full"):
        sinks.write(2, None)  # raised at the next frame
    sinks.close(completed=False)
    assert rec.closed is False and [i for i, _ in rec.seen] == [0]
    rec = Recorder(fail_at=0)
    sinks = BackgroundSinks([rec])
    sinks.write(0, None)
    with pytest.raises(OSError, match="disk full"):
        sinks.close(completed=True)  # or at the close, and the file sinks leave nothing behind
    assert rec.closed is False


def test_frames_are_0_based_and_help_and_error_say_so(tmp_path, capsys, logs):
    """Issue 35 #13: ``--frames 3`` of a 3-frame log is past its end; the help and the error say why."""
    _, filled, _ = logs  # 2 frames
    rc, _, err = run_cli(capsys, "replay", filled, "--frames", "2")
    assert rc == 1 and err.strip().endswith("(it has 2 frames, indices 0..1)"), err
    with pytest.raises(SystemExit):
        main(["replay", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "by their 0-based index in the log (the first is 0)" in text
    assert "or N for frame N alone" in text
