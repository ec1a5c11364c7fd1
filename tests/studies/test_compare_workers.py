"""``zcut compare`` scales as ``zcut batch`` (issue 33 item 7): its frames run in units on local worker
processes, the one writer assembles the outputs, equal to those of one process running the units one
after another; a rerun over an interrupted folder runs only the units not done; another config or log
set over the same folder is one line."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from cli_helpers import run_cli
from log_helpers import rrd_rows
from test_batch_ray import rechunk

from cli.main import main

SIZE = "120x180"
OUTPUTS = ("compare.json", "summary.parquet", "disagreement.npz", "report.html", "compare.rrd")


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """Two synthetic logs with one frame per chunk (a unit per frame: 3 + 2 units), a config B."""
    d = tmp_path_factory.mktemp("compare_workers")
    for name, parts, frames, seed in (("rods", "rods", 3, 5), ("spheres", "spheres", 2, 6)):
        whole = d / f"{name}_whole.mcap"
        assert main(["synth", "-o", str(whole), "--parts", parts, "--frames", str(frames), "--seed", str(seed),
                     "--size", SIZE]) == 0
        rechunk(whole, d / f"{name}.mcap", chunk_size=16 * 1024)
    (d / "rho.toml").write_text("[zcut]\nrho_thr = 0.035\n")
    (d / "rho5.toml").write_text("[zcut]\nrho_thr = 0.05\n")
    return d


def _compare(capsys, data, out, *extra):
    return run_cli(capsys, "compare", data / "rods.mcap", data / "spheres.mcap", "--a", "zcut", "--b",
                   data / "rho.toml", "-o", out, "--frames-per-unit", "1", *extra)


def _report(out):
    """compare.json without what differs from run to run (the cost, the outputs' paths)."""
    rep = json.loads((out / "compare.json").read_text())
    del rep["cost"], rep["outputs"]
    return rep


def _same_outputs(x, y) -> None:
    assert _report(x) == _report(y)
    assert pq.read_table(x / "summary.parquet").equals(pq.read_table(y / "summary.parquet"))
    with np.load(x / "disagreement.npz") as zx, np.load(y / "disagreement.npz") as zy:
        assert sorted(zx.files) == sorted(zy.files)
        for k in zx.files:
            assert np.array_equal(zx[k], zy[k]), k


def _rrd_content(path) -> dict[str, list[str]]:
    """Every row of the recording by entity (:func:`log_helpers.rrd_rows`)."""
    return rrd_rows(path)


def _rrd_rows(path) -> dict[str, int]:
    import rerun as rr

    rows: dict[str, int] = {}
    for chunk in rr.chunk.RrdReader(str(path)).stream():
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    return rows


@pytest.fixture(scope="module")
def runs(data, tmp_path_factory):
    """The comparison in this process (``--workers 0``) and on two local worker processes."""
    d = tmp_path_factory.mktemp("compare_runs")
    out = {}
    for workers in ("0", "2"):
        argv = ["compare", str(data / "rods.mcap"), str(data / "spheres.mcap"), "--a", "zcut", "--b",
                str(data / "rho.toml"), "-o", str(d / f"w{workers}"), "--frames-per-unit", "1", "--workers", workers]
        assert main(argv) == 0
        out[workers] = d / f"w{workers}"
    return out


def test_workers_give_the_outputs_of_one_process(runs):
    one, two = runs["0"], runs["2"]
    _same_outputs(one, two)
    rep = json.loads((two / "compare.json").read_text())
    assert [f["index"] for f in rep["frames"]] == [0, 1, 2, 0, 1]  # log order, frame order
    assert [lg["frames"] for lg in rep["logs"]] == [3, 2]
    assert len(list((two / "parts").glob("*.parquet"))) == 5  # a unit per frame
    cost = rep["cost"]
    assert (cost["executor"], cost["workers"], cost["units"], cost["units_this_run"]) == ("local processes", 2, 5, 5)
    assert cost["frames_this_run"] == 5 and cost["cpu_s_per_frame"] > 0
    # the stages each frame ran, summed over the units: A and B share the bin stages
    assert rep["stage_runs"] == {"bin_zone": 5, "locate_bin": 5, "method:zcut": 10, "method:sor": 5}
    # the recording: the same rows (the same images, points, scalars at the same times)
    assert _rrd_content(one / "compare.rrd") == _rrd_content(two / "compare.rrd")
    assert _rrd_rows(two / "compare.rrd")["/image/rgb"] == 5  # every frame, from its unit's part


def test_an_interrupted_comparison_resumes_where_it_stopped(data, runs, tmp_path, capsys):
    out = tmp_path / "r"
    shutil.copytree(runs["0"], out)
    # what a comparison killed during its fourth unit leaves: three units' parts, no output
    for name in OUTPUTS:
        (out / name).unlink()
    parts = sorted((out / "parts").glob("*.json"))
    for p in parts[3:]:
        p.unlink()
        p.with_suffix(".parquet").unlink()
    rc, text, err = _compare(capsys, data, out, "--workers", "0", "--json")
    assert rc == 0, err
    assert "5 unit(s) of work, 3 already done" in err, err
    cost = json.loads(text)["cost"]
    assert (cost["units_this_run"], cost["frames_this_run"], cost["frames"]) == (2, 2, 5)
    _same_outputs(out, runs["0"])
    assert _rrd_rows(out / "compare.rrd") == _rrd_rows(runs["0"] / "compare.rrd")
    # finished: a rerun is refused without --force; with it, nothing runs again
    rc, _, err = _compare(capsys, data, out, "--workers", "0")
    assert rc == 1 and "use --force" in err, err
    rc, text, err = _compare(capsys, data, out, "--workers", "0", "--force", "--json")
    assert rc == 0 and "5 already done" in err, err
    assert json.loads(text)["cost"]["units_this_run"] == 0
    _same_outputs(out, runs["0"])


@pytest.mark.parametrize(("change", "message"), [
    (("--b", "rho5.toml"), "other options (b)"),
    (("--logs", "rods.mcap"), "other options (logs)"),
    (("--frames-per-unit", "2"), "other options (frames_per_unit)"),
])
def test_another_comparison_in_the_same_folder_is_one_line(data, runs, tmp_path, capsys, change, message):
    out = tmp_path / "x"
    shutil.copytree(runs["0"], out)
    for name in OUTPUTS:  # interrupted: no outputs yet
        (out / name).unlink()
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    logs = [data / "rods.mcap", data / "spheres.mcap"]
    b, fpu = data / "rho.toml", "1"
    if change[0] == "--b":
        b = data / change[1]
    elif change[0] == "--logs":
        logs = [data / change[1]]
    else:
        fpu = change[1]
    rc, _, err = run_cli(capsys, "compare", *logs, "--a", "zcut", "--b", b, "-o", out, "--frames-per-unit", fpu,
                         "--workers", "0")
    assert rc == 1, err
    lines = [ln for ln in err.strip().splitlines() if not ln.startswith("zcut: compiling")]
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before  # nothing touched


@pytest.mark.parametrize(("extra", "message"), [
    (("--workers", "-1"), "--workers must be >= 0"),
    (("--frames-per-unit", "0"), "--frames-per-unit must be >= 1"),
    (("--workers", "2", "--ray", "127.0.0.1:1"), "--workers is for local processes"),
])
def test_bad_executor_options_are_one_line(data, tmp_path, capsys, extra, message):
    rc, _, err = run_cli(capsys, "compare", data / "rods.mcap", "--a", "zcut", "--b", data / "rho.toml", "-o",
                         tmp_path / "b", *extra)
    assert rc == 1, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], err
    assert not (tmp_path / "b").exists()


def _damaged_copy(src, dst, chunk: int) -> None:
    """``src`` with the middle of its ``chunk``-th chunk overwritten (its CRC fails: its frame is lost)."""
    from mcap.reader import make_reader

    with open(src, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    idx = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)[chunk]
    data = bytearray(src.read_bytes())
    mid = idx.chunk_start_offset + idx.chunk_length // 2
    data[mid:mid + 64] = bytes(64)
    dst.write_bytes(bytes(data))


def test_a_damaged_log_loses_its_frames_not_the_comparison(data, tmp_path, capsys):
    log = tmp_path / "damaged.mcap"
    _damaged_copy(data / "rods.mcap", log, 1)
    reps = []
    for workers in ("0", "2"):
        rc, text, err = run_cli(capsys, "compare", log, data / "spheres.mcap", "--a", "zcut", "--b", data / "rho.toml",
                                "-o", tmp_path / workers, "--frames-per-unit", "1", "--workers", workers, "--json",
                                "--no-rrd")
        assert rc == 3, err  # data loss
        assert "warning: data loss: " in err and "Traceback" not in err, err
        reps.append(json.loads(text))
    for rep in reps:
        del rep["cost"], rep["outputs"]
    assert reps[0] == reps[1]
    damaged = reps[0]["logs"][0]
    assert damaged["frames"] == 2 and damaged["damage"], damaged
    kept = [f["index"] for f in reps[0]["frames"] if f["log"] == "damaged.mcap"]
    assert len(kept) == 2 and set(kept) < {0, 1, 2}  # one frame lost with its chunk
    assert [f["index"] for f in reps[0]["frames"] if f["log"] == "spheres.mcap"] == [0, 1]


def test_the_writer_takes_each_frame_as_soon_as_the_units_before_it_are_done(data, runs, tmp_path, monkeypatch):
    """The recording is written while the units run, in log and frame order, each frame from its unit's
    part (the log is not read again); the outputs are those of the comparison's other runs."""
    import studies.compare as compare
    from studies.compare_outputs import CompareWriter

    out = tmp_path / "w"
    written: list[tuple[str, int, int]] = []
    frame = CompareWriter.frame

    def frame_seen(self, fc, images, pa, pb, view=None):
        assert view is not None and images.view is not None  # from the part
        written.append((fc.log, fc.index, len(list((out / "parts").glob("*.json")))))
        return frame(self, fc, images, pa, pb, view)

    def no_reread(*args, **kwargs):
        raise AssertionError("a frame read again from its log")

    monkeypatch.setattr(CompareWriter, "frame", frame_seen)
    monkeypatch.setattr(compare, "_Reread", no_reread)
    assert main(["compare", str(data / "rods.mcap"), str(data / "spheres.mcap"), "--a", "zcut", "--b",
                 str(data / "rho.toml"), "-o", str(out), "--frames-per-unit", "1", "--workers", "0"]) == 0
    # a unit per frame, one after another: frame k written when its unit, the k-th, is done
    assert written == [("rods.mcap", 0, 1), ("rods.mcap", 1, 2), ("rods.mcap", 2, 3), ("spheres.mcap", 0, 4),
                       ("spheres.mcap", 1, 5)]
    _same_outputs(out, runs["0"])
    assert _rrd_content(out / "compare.rrd") == _rrd_content(runs["0"] / "compare.rrd")


def test_parts_without_the_recording_read_their_frames_again(data, runs, tmp_path, capsys):
    """Parts written by a comparison without compare.rrd hold no image: a later --force that writes the
    recording reads those frames again from the logs; the recording is the same."""
    out = tmp_path / "n"
    rc, _, err = _compare(capsys, data, out, "--workers", "0", "--no-rrd")
    assert rc == 0, err
    assert not (out / "compare.rrd").exists()
    rc, _, err = _compare(capsys, data, out, "--workers", "0", "--force")
    assert rc == 0 and "5 already done" in err, err
    _same_outputs(out, runs["0"])
    assert _rrd_content(out / "compare.rrd") == _rrd_content(runs["0"] / "compare.rrd")


def test_in_one_process_the_planning_s_reader_serves_the_sides_and_the_first_log(data, runs, tmp_path, monkeypatch):
    """Each log is opened by the planning only, its reader resolving A and B; in this process the units
    take it too (up to three logs; the second log's first unit opened its own before): the same outputs."""
    import replay.pipeline.session as session

    real, opened = session.open_log, []

    def counting(path, *args, **kwargs):
        opened.append(Path(path).name)
        return real(path, *args, **kwargs)

    monkeypatch.setattr(session, "open_log", counting)
    out = tmp_path / "once"
    assert main(["compare", str(data / "rods.mcap"), str(data / "spheres.mcap"), "--a", "zcut", "--b",
                 str(data / "rho.toml"), "-o", str(out), "--frames-per-unit", "1", "--workers", "0"]) == 0
    assert sorted(opened) == ["rods.mcap", "spheres.mcap"]  # before: three times each, then the second twice
    _same_outputs(out, runs["0"])
