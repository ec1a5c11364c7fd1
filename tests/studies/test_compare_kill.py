"""A real ``zcut compare --workers 2`` killed mid-run (issue 33 item 7, resumable): SIGTERM ends it
with 143 and leaves only its resumable state; SIGKILL of the driver leaves its locks and temporaries,
which the rerun takes over. Either way the rerun runs only the units not done and writes the outputs
of an uninterrupted comparison."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import pytest
from test_batch_ray import rechunk
from test_compare_workers import OUTPUTS, _rrd_content, _same_outputs

from cli.main import main

SIZE = "120x180"
UNITS = 7  # one frame per unit: 4 + 3


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    d = tmp_path_factory.mktemp("compare_kill")
    for name, frames, seed in (("rods", 4, 15), ("spheres", 3, 16)):
        whole = d / f"{name}_whole.mcap"
        assert main(["synth", "-o", str(whole), "--parts", name, "--frames", str(frames), "--seed", str(seed),
                     "--size", SIZE]) == 0
        rechunk(whole, d / f"{name}.mcap", chunk_size=16 * 1024)
    (d / "rho.toml").write_text("[zcut]\nrho_thr = 0.035\n")
    ref = d / "ref"
    assert main(_argv(d, ref, "0")) == 0  # uninterrupted
    return d


def _argv(d, out, workers: str) -> list[str]:
    return ["compare", str(d / "rods.mcap"), str(d / "spheres.mcap"), "--a", "zcut", "--b", str(d / "rho.toml"),
            "-o", str(out), "--frames-per-unit", "1", "--workers", workers]


def _kill_after_the_first_part(data, out, sig: signal.Signals) -> tuple[int, str]:
    """Start the comparison on two workers, send ``sig`` once the first unit's part exists."""
    p = subprocess.Popen([sys.executable, "-m", "cli", *_argv(data, out, "2")], stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 300
        # a finished part: not the temporary it is written to (``.KEY.xxxxxxxx.partial.json``, which the glob
        # matches too: a SIGTERM sent then found no part done, the rerun's 1 <= done failed)
        while not _finished_parts(out):
            assert p.poll() is None and time.monotonic() < deadline, p.stderr.read().decode(errors="replace")
            time.sleep(0.01)
        p.send_signal(sig)
        err = p.stderr.read().decode(errors="replace")
        p.wait(timeout=120)
    finally:
        p.kill()
        p.wait()
        p.stderr.close()
    return p.returncode, err


def _finished_parts(out) -> list:
    """The units' finished parts: not the temporaries they are written to (``.KEY.xxxxxxxx.partial.json``, which the
    glob matches too). A SIGKILL can leave one behind: counted as done, the rerun's cost read one unit too many."""
    return [q for q in (out / "parts").glob("*.json") if not q.name.startswith(".")]


def _resume(data, out, capsys) -> None:
    done = len(_finished_parts(out))
    assert 1 <= done <= UNITS
    assert main([*_argv(data, out, "0"), "--json"]) == 0
    captured = capsys.readouterr()
    cost = json.loads(captured.out)["cost"]
    assert (cost["units"], cost["units_this_run"], cost["frames_this_run"]) == (UNITS, UNITS - done, UNITS - done)
    assert (f", {done} already done in " in captured.err) == (done > 0), captured.err
    _same_outputs(out, data / "ref")
    assert _rrd_content(out / "compare.rrd") == _rrd_content(data / "ref" / "compare.rrd")
    # nothing left behind: the outputs and the resumable state only
    assert sorted(q.name for q in out.iterdir()) == sorted([*OUTPUTS, "parts", "run.json"])
    assert all(not q.name.startswith(".") and ".partial" not in q.name for q in (out / "parts").iterdir())


def test_sigterm_mid_run_is_143_and_the_rerun_runs_only_the_rest(data, tmp_path, capsys):
    out = tmp_path / "t"
    rc, err = _kill_after_the_first_part(data, out, signal.SIGTERM)
    assert rc == 143, err
    assert err.rstrip().endswith("interrupted (SIGTERM)") and "Traceback" not in err, err
    assert sorted(q.name for q in out.iterdir()) == ["parts", "run.json"]  # no output, no temporary, no lock
    _resume(data, out, capsys)


def test_sigkill_of_the_driver_leaves_locks_the_rerun_takes_over(data, tmp_path, capsys):
    out = tmp_path / "k"
    rc, err = _kill_after_the_first_part(data, out, signal.SIGKILL)
    assert rc == -signal.SIGKILL, err
    left = sorted(q.name for q in out.iterdir())
    assert set(left) - {"parts", "run.json"}, left  # its lock and its recording's temporary
    _resume(data, out, capsys)
