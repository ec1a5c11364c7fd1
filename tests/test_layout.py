"""The dependency direction of the packages (STYLE.md): zcut imports no I/O, viewer or database."""

from __future__ import annotations

import subprocess
import sys


def test_importing_zcut_keeps_io_modules_out():
    code = (
        "import sys, zcut, zcut.cloud\n"
        "import pkgutil, importlib\n"
        "for m in pkgutil.iter_modules(zcut.__path__): importlib.import_module('zcut.' + m.name)\n"
        "bad = [m for m in ('rerun', 'mcap', 'mcap_ros2', 'sqlite3', 'fastapi', 'starlette') if m in sys.modules]\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"zcut pulled in: {out.stdout.strip()}"


def test_cli_help_works():
    out = subprocess.run([sys.executable, "-m", "replay.cli", "--help"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "zcut" in out.stdout


def test_cli_usage_error_exits_1_with_one_line():
    out = subprocess.run(
        [sys.executable, "-m", "replay.cli", "synth", "-o", "never.mcap", "--no-such-flag"], capture_output=True, text=True
    )
    assert out.returncode == 1
    assert out.stderr.strip().splitlines()[-1].startswith("error: unrecognized arguments")
    assert "Traceback" not in out.stderr
