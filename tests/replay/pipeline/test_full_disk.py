"""A full disk under ``zcut replay``'s outputs (docs/cli.md, outputs): never a hang, never a
traceback, never a truncated output under its final name; one line naming the output that had no
space, and nothing left behind. The disks are real small tmpfs mounts."""

from __future__ import annotations

import shutil
import subprocess
import sys
import time

import pytest
from disk_helpers import small_disk
from session_logs import synth_once

from cli.main import main


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    # a 1.5 MB .rrd and a 17 MB results file; the log of tests/replay/test_signals.py too: made once per session
    return synth_once(tmp_path_factory, parts="zinc_nuts", frames=4, seed=3, size="480x640")


@pytest.fixture(scope="module")
def empty(tmp_path_factory):
    """An empty bin's log and its bin model made on a disk with room (what the full disk's run would have written)."""
    d = tmp_path_factory.mktemp("full_empty")
    assert main(["synth", "-o", str(d / "e.mcap"), "--empty", "--frames", "2", "--seed", "3", "--size", "240x320"]) == 0
    assert main(["bin-model", str(d / "e.mcap"), "-o", str(d / "b.ply")]) == 0
    return d / "e.mcap", d / "b.ply"


@pytest.fixture(scope="module")
def rods(tmp_path_factory):
    log = tmp_path_factory.mktemp("full_rods") / "s.mcap"
    assert main(["synth", "-o", str(log), "--parts", "rods", "--frames", "3", "--seed", "5", "--size", "320x200"]) == 0
    return log


@pytest.mark.parametrize(("outputs", "size", "short"), [
    (("rrd",), "64k", "o.rrd"), (("rrd",), "700k", "o.rrd"), (("rrd",), "1400k", "o.rrd"),
    (("out",), "2m", "r.mcap"), (("out",), "12m", "r.mcap"), (("rrd", "out"), "8m", "r.mcap"),
])
def test_replay_on_a_full_disk_is_one_line_and_leaves_nothing(log, tmp_path, outputs, size, short):
    with small_disk(tmp_path / "disk", size) as disk:
        argv = [sys.executable, "-m", "cli", "replay", str(log)]
        if "rrd" in outputs:
            argv += ["--rrd", str(disk / "o.rrd")]
        if "out" in outputs:
            argv += ["--out", str(disk / "r.mcap"), "--out-cloud"]
        t0 = time.monotonic()
        run = subprocess.run(argv, capture_output=True, text=True, timeout=600)  # a hang fails here
        errors = [ln for ln in run.stderr.splitlines() if ln.startswith("error:")]
        assert run.returncode == 1, run.stderr
        assert len(errors) == 1 and "Traceback" not in run.stderr, run.stderr
        assert "no space left on the device" in errors[0] and str(disk / short) in errors[0], errors
        assert sorted(p.name for p in disk.iterdir()) == []  # no truncated output, no temporary, no lock
        assert time.monotonic() - t0 < 600


def test_a_recording_is_checked_complete_before_it_takes_its_name(log, tmp_path, capsys):
    """``viz.rrd_problem`` reads a recording back with Rerun's own reader: a complete one passes,
    every truncation of it is named as incomplete (what a writer that met a full disk leaves)."""
    from replay.pipeline.viz import rrd_problem

    assert main(["replay", str(log), "--frames", "0:2", "--rrd", str(tmp_path / "o.rrd")]) == 0
    data = (tmp_path / "o.rrd").read_bytes()
    assert rrd_problem(str(tmp_path / "o.rrd")) is None
    for cut in (len(data) // 3, len(data) - 100, len(data) - 1):
        (tmp_path / "t.rrd").write_bytes(data[:cut])
        assert rrd_problem(str(tmp_path / "t.rrd")) is not None, cut
    shutil.copy(tmp_path / "o.rrd", tmp_path / "c.rrd")
    assert rrd_problem(str(tmp_path / "c.rrd")) is None


@pytest.mark.parametrize("size", ["64k", "1m"])
def test_bin_model_on_a_full_disk_is_one_line_and_leaves_nothing(tmp_path, empty, size):
    """Open3D's PLY writer reports success on a full disk and leaves a truncated file: ``zcut
    bin-model`` checks the space before and the file after, and names the output."""
    from replay.pipeline.bin_model import _check_complete_ply

    empty, ok = empty
    with small_disk(tmp_path / "disk", size) as disk:
        run = subprocess.run([sys.executable, "-m", "cli", "bin-model", str(empty), "-o", str(disk / "b.ply")],
                             capture_output=True, text=True, timeout=600)
        errors = [ln for ln in run.stderr.splitlines() if ln.startswith("error:")]
        assert run.returncode == 1, run.stderr
        assert len(errors) == 1 and "Traceback" not in run.stderr and "RPly" not in run.stderr, run.stderr
        assert "no space left on the device" in errors[0] and str(disk / "b.ply") in errors[0], errors
        assert sorted(p.name for p in disk.iterdir()) == []
    _check_complete_ply(ok)  # a complete file passes
    data = ok.read_bytes()
    cut = tmp_path / "cut.ply"
    cut.write_bytes(data[: len(data) - 8])
    with pytest.raises(OSError, match="cut short"):
        _check_complete_ply(cut)


@pytest.mark.parametrize(("size", "short"), [("64k", ("compare.rrd", "parts")),
                                             # which output meets the full disk first depends on their sizes
                                             ("400k", ("compare.rrd", "compare.json", "report.html", "disagreement.npz"))])
def test_compare_on_a_full_disk_is_one_line_and_leaves_nothing(tmp_path, rods, size, short):
    """``zcut compare``'s recording goes through replay's checked .rrd file (a full disk met by Rerun's
    writer was a RuntimeError traceback)."""
    log = rods
    with small_disk(tmp_path / "disk", size) as disk:
        run = subprocess.run([sys.executable, "-m", "cli", "compare", str(log), "--a", "zcut", "--b", "sor", "-o",
                              str(disk / "o")], capture_output=True, text=True, timeout=600)
        errors = [ln for ln in run.stderr.splitlines() if ln.startswith("error:")]
        assert run.returncode == 1, run.stderr
        assert len(errors) == 1 and "Traceback" not in run.stderr, run.stderr
        assert "no space left on the device" in errors[0] and any(str(disk / "o" / n) in errors[0] for n in short), errors
        # no output, no temporary, no lock: only the units done, for a rerun to continue (docs/compare.md)
        assert sorted(p.name for p in (disk / "o").iterdir()) == ["parts", "run.json"]
        assert all(p.suffix in (".json", ".parquet") and not p.name.startswith(".")
                   for p in (disk / "o" / "parts").iterdir())
