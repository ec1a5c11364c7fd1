"""``--size`` in ``zcut synth`` and ``zcut record``: one convention, WIDTHxHEIGHT (columns x rows, as a
camera's 1920x1200), and a size no zcut reader could read refused before anything is written."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest
from cli_helpers import run_cli

from replay.logs.reader import LogReader


def _one_error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if not ln.startswith("zcut: compiling")]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in err, err
    return lines[0]


def test_synth_refuses_more_pixels_than_the_readers_cap_at_once(tmp_path, capsys):
    t0 = time.monotonic()
    rc, _, err = run_cli(capsys, "synth", "-o", tmp_path / "big.mcap", "--size", "4097x4096")
    assert rc == 1 and time.monotonic() - t0 < 30
    line = _one_error_line(err)
    assert "--size 4097x4096" in line and "16777216" in line and "ZCUT_MAX_PIXELS" in line, line
    assert os.listdir(tmp_path) == []


def test_synth_refuses_a_cloud_over_the_message_cap(tmp_path, capsys):
    rc, _, err = run_cli(capsys, "synth", "-o", tmp_path / "big.mcap", "--size", "4096x4096")
    assert rc == 1
    line = _one_error_line(err)
    assert "--size 4096x4096" in line and "ZCUT_MAX_MESSAGE_BYTES" in line, line
    assert os.listdir(tmp_path) == []


def _zcut(*argv, env) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cli", *map(str, argv)], capture_output=True, text=True,
                          timeout=300, env={**os.environ, **env})


def test_synth_and_the_readers_share_the_pixel_cap_of_the_environment(tmp_path):
    """With ``ZCUT_MAX_PIXELS=10000`` a 128x96 log (12288 pixels) is one synth refuses and topics cannot read."""
    capped = {"ZCUT_MAX_PIXELS": "10000"}
    r = _zcut("synth", "-o", tmp_path / "capped.mcap", "--size", "128x96", env=capped)
    assert r.returncode == 1, r.stderr
    assert "more than the cap of 10000" in _one_error_line(r.stderr)
    assert not (tmp_path / "capped.mcap").exists()
    assert _zcut("synth", "-o", tmp_path / "s.mcap", "--size", "128x96", env={}).returncode == 0
    r = _zcut("topics", tmp_path / "s.mcap", "--check", env=capped)
    assert r.returncode != 0 and "ZCUT_MAX_PIXELS" in r.stderr + r.stdout  # what synth now refuses up front


def test_synth_size_is_width_by_height_and_a_portrait_frame_says_so(tmp_path, capsys):
    rc, _, err = run_cli(capsys, "synth", "-o", tmp_path / "p.mcap", "--size", "48x64")
    assert rc == 0
    assert "zcut: --size 48x64 is WIDTHxHEIGHT: a portrait frame 48 wide and 64 high (64x48 makes the landscape one)" \
        in err
    assert next(LogReader(tmp_path / "p.mcap").frames()).shape == (64, 48)
    rc, _, err = run_cli(capsys, "synth", "-o", tmp_path / "l.mcap", "--size", "64x48")
    assert rc == 0 and "portrait" not in err
    assert next(LogReader(tmp_path / "l.mcap").frames()).shape == (48, 64)


def _unorganized_ply(path, rows: int, cols: int) -> None:
    """A PLY of rows*cols points, row-major, with no grid information; z = 1 m + the column in mm."""
    r, c = np.mgrid[0:rows, 0:cols]
    xyz = np.stack([c * 0.001, r * 0.001, 1.0 + c * 0.001], axis=-1).astype("<f4").reshape(-1, 3)
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {rows * cols}\n"
            "property float x\nproperty float y\nproperty float z\nend_header\n").encode()
    path.write_bytes(head + xyz.tobytes())


def test_record_size_is_width_by_height_as_in_synth(tmp_path, capsys):
    _unorganized_ply(tmp_path / "c.ply", rows=2, cols=3)
    rc, _, err = run_cli(capsys, "record", tmp_path / "c.ply", "-o", tmp_path / "a.mcap", "--size", "3x2")
    assert rc == 0, err
    f = next(LogReader(tmp_path / "a.mcap").frames())
    assert f.shape == (2, 3)
    np.testing.assert_allclose(f.xyz[0, :, 2], [1.0, 1.001, 1.002], atol=1e-6)  # a row runs along the columns


def test_record_shape_keeps_its_old_meaning_and_says_it(tmp_path, capsys):
    _unorganized_ply(tmp_path / "c.ply", rows=2, cols=3)
    rc, _, err = run_cli(capsys, "record", tmp_path / "c.ply", "-o", tmp_path / "b.mcap", "--shape", "2x3")
    assert rc == 0, err
    assert "--shape 2x3 is HEIGHTxWIDTH: a grid 3 wide and 2 high (--size 3x2 says the same" in err
    assert next(LogReader(tmp_path / "b.mcap").frames()).shape == (2, 3)


def test_record_refuses_both_spellings(tmp_path, capsys):
    _unorganized_ply(tmp_path / "c.ply", rows=2, cols=3)
    rc, _, err = run_cli(capsys, "record", tmp_path / "c.ply", "-o", tmp_path / "b.mcap", "--shape", "2x3",
                         "--size", "3x2")
    assert rc == 1 and "not allowed with argument" in err
    assert not (tmp_path / "b.mcap").exists()


@pytest.mark.parametrize("size", ["3x1", "3"])
def test_record_size_that_is_not_an_organized_grid_is_refused(tmp_path, capsys, size):
    _unorganized_ply(tmp_path / "c.ply", rows=1, cols=3)
    rc, _, err = run_cli(capsys, "record", tmp_path / "c.ply", "-o", tmp_path / "b.mcap", "--size", size)
    assert rc == 1 and "Traceback" not in err
    assert not (tmp_path / "b.mcap").exists()
