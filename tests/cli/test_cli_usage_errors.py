"""argparse's own errors (docs/cli.md, "Exit status"): one line naming the option and what was wrong,
and where the options are listed; exit 1; no usage block. ``zcut --version`` and ``zcut --help`` read
their arguments before loading numpy, numba or scipy."""

from __future__ import annotations

import subprocess
import sys

import pytest
from cli_helpers import run_cli
from subprocess_helpers import run_python

MISTAKES = {
    "bad choice": (["synth", "-o", "x.mcap", "--parts", "bolts"], "zcut synth", "argument --parts: invalid choice"),
    "wrong type": (["synth", "-o", "x.mcap", "--frames", "many"], "zcut synth", "argument --frames: invalid int value"),
    "missing option": (["synth", "--frames", "2"], "zcut synth", "required: -o/--output"),
    "missing positional": (["replay"], "zcut replay", "required: LOG"),
    "clashing options": (["synth", "-o", "x.mcap", "--shiny", "--matte"], "zcut synth",
                         "argument --matte: not allowed with argument --shiny"),
    "clashing sinks": (["replay", "x.mcap", "--spawn", "--rrd", "o.rrd"], "zcut replay", "not allowed with argument"),
    "missing value": (["batch", "x.mcap", "-o", "b", "--workers"], "zcut batch", "argument --workers: expected one"),
    "unknown option": (["topics", "x.mcap", "--colour"], "zcut topics", "unrecognized arguments: --colour"),
    "unknown command": (["replays", "x.mcap"], "zcut", "argument COMMAND: invalid choice: 'replays'"),
    "unknown action": (["labels", "lst"], "zcut labels", "invalid choice: 'lst'"),
    "action's missing option": (["labels", "export", "x.mcap", "--db", "l.sqlite"], "zcut labels export",
                                "required: -o/--out"),
    "bad port": (["annotate", "x.mcap", "--port", "http"], "zcut annotate", "argument --port: invalid int value"),
}


@pytest.mark.parametrize("argv, prog, what", MISTAKES.values(), ids=MISTAKES.keys())
def test_a_usage_error_is_one_line_naming_the_option(capsys, argv, prog, what):
    rc, out, err = run_cli(capsys, *argv)
    assert rc == 1
    assert out == ""
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("error: ") and what in lines[0], err
    assert lines[0].endswith(f"(see `{prog} --help`)"), err
    assert "usage:" not in err


def test_a_usage_error_from_the_console_script_is_one_line():
    out = subprocess.run([sys.executable, "-m", "cli", "batch", "x.mcap", "-o", "b", "--workers", "two"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 1
    assert out.stderr.splitlines() == [out.stderr.strip()] and out.stderr.startswith("error: argument --workers"), out
    assert "(see `zcut batch --help`)" in out.stderr


@pytest.mark.parametrize("argv", [["--version"], ["--help"], ["synth", "--help"], []], ids=str)
def test_version_and_help_load_no_numerics(argv):
    """Building only the parser of the command named (none for ``--version``/``--help``) keeps numba,
    scipy and the kernels out (numpy too, but for a command whose options need it): ~0.2 CPU-s
    instead of ~2.2 (docs/cli.md)."""
    code = ("import sys\n"
            f"sys.argv = ['zcut', *{argv!r}]\n"
            "from cli.main import main\n"
            "try:\n    status = main()\nexcept SystemExit as e:\n    status = e.code\n"
            "heavy = sorted(m for m in ('numpy', 'numba', 'scipy', 'zcut') if m in sys.modules)\n"
            "print('LOADED', heavy, status, file=sys.stderr)\n")
    out = run_python(code, timeout=300)
    loaded = out.stderr.strip().splitlines()[-1]
    # a command's own options may need numpy (its choices); never numba, scipy or the kernels
    allowed = "LOADED ['numpy']" if argv[:1] == ["synth"] else "LOADED []"
    assert loaded.startswith(("LOADED []", allowed)), out.stderr
    assert loaded.endswith(" 1" if argv == [] else " 0"), out.stderr
    if argv == ["--version"]:
        assert out.stdout.startswith("zcut ")
    elif argv:
        assert "usage: zcut" in out.stdout


def test_the_full_parser_still_knows_every_command(capsys):
    from cli.main import COMMANDS, build_parser

    parser = build_parser()
    for name in COMMANDS:
        with pytest.raises(SystemExit) as e:
            parser.parse_args([name, "--help"])
        assert e.value.code == 0
        assert f"usage: zcut {name}" in capsys.readouterr().out
