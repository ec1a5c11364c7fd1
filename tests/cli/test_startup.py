"""Every command's options are listed without the libraries its run loads (issue 32, fixed costs).

A command's ``--help``, and a usage error, build that command's parser only: its ``--methods`` help
names every method of the registry (:func:`replay.pipeline.methods.registry`), which is read without
importing the methods' kernels, so no numba, SciPy, OpenCV or Open3D is loaded (0.5-0.8 CPU-s a
process before; docs/performance.md, "Fixed costs, round of 2026-12-05"). Each case runs in a fresh
interpreter and reads ``sys.modules`` at its end; the test suite spawns hundreds of ``zcut`` processes.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import pytest

from cli.commands.annotate import GATE_HELP, add_gate_option, check_gate
from cli.main import build_parser
from replay.pipeline.methods import registry

ROOT = Path(__file__).resolve().parents[2]
#: what a parser must not load: numba (and its LLVM), SciPy, OpenCV, Open3D and the kernels' modules
RUN_ONLY = ("numba", "llvmlite", "scipy", "cv2", "open3d", "zcut.bin_check", "zcut.removal", "zcut.registration",
            "zcut.sor", "zcut.cuts", "annotate.assistant", "replay.pipeline.zone")


def _fresh(code: str, env: dict[str, str] | None = None) -> tuple[list[str], str]:
    """(the :data:`RUN_ONLY` modules loaded, stdout) after ``code`` ran in a fresh interpreter."""
    from subprocess_helpers import run_python  # here: a child imports this module as a plug-in, tests/ not on its path

    probe = f"{code}\nimport sys\nprint('loaded:' + ','.join(m for m in {RUN_ONLY!r} if m in sys.modules), file=sys.__stderr__)\n"
    out = run_python(probe, cwd=ROOT, env=env, timeout=300)
    assert out.returncode == 0, out.stderr
    last = out.stderr.strip().splitlines()[-1]
    assert last.startswith("loaded:"), out.stderr
    return [m for m in last.removeprefix("loaded:").split(",") if m], out.stdout


def _main(*argv: str) -> str:
    return ("import sys\n"
            "import cli.main\n"
            "try:\n"
            f"    status = cli.main.main({list(argv)!r})\n"
            "except SystemExit as e:  # a usage error: argparse's exit, status 1\n"
            "    status = e.code\n"
            "assert status in (0, 1), status\n")


@pytest.mark.parametrize("argv", [("replay", "--help"), ("accuracy", "--help"), ("annotate", "--help"),
                                  ("labels", "train", "--help"), ("sweep", "--help"), ("batch", "--help"),
                                  ("demo", "--help"), ("record-stereo", "--help"), ("replay", "--no-such-option"),
                                  ("accuracy",)])
def test_a_commands_parser_loads_none_of_its_run(argv: tuple[str, ...]) -> None:
    loaded, _ = _fresh(_main(*argv))
    assert loaded == [], loaded


def test_the_registry_is_read_without_the_kernels() -> None:
    loaded, out = _fresh("from replay.pipeline.methods import registry\nprint(','.join(registry()))")
    assert loaded == []
    assert out.strip().split(",") == list(registry())


@pytest.mark.parametrize("command", ["replay", "accuracy", "sweep", "batch", "annotate"])
def test_methods_help_names_every_method(command: str) -> None:
    parser = build_parser(command, only=True)
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    methods = next(a for a in sub.choices[command]._actions if "--methods" in a.option_strings)
    assert methods.help is not None
    for name in registry():
        assert f" {name}," in methods.help or f" {name};" in methods.help, (name, methods.help)


def test_a_plugged_in_method_is_listed_by_a_fresh_parser() -> None:
    """``ZCUT_METHODS`` reaches the help of a new process (the registry's plug-ins, read on each call)."""
    here = str(Path(__file__).parent)  # this module, by its import name
    env = dict(os.environ, ZCUT_METHODS=f"{__name__}:TOY_FOR_HELP",
               PYTHONPATH=os.pathsep.join(p for p in (here, os.environ.get("PYTHONPATH")) if p))
    code = ("import contextlib, io\n"
            "import cli.main\n"
            "buf = io.StringIO()\n"
            "with contextlib.redirect_stdout(buf), contextlib.suppress(SystemExit):\n"
            "    cli.main.main(['replay', '--help'])\n"
            "print(' '.join(buf.getvalue().split()))\n")
    _, out = _fresh(code, env=env)
    assert "toy_for_help" in out, out


def _frames(out: str) -> list[dict[str, object]]:
    """The per-frame figures of a ``zcut replay --json`` run, without their wall time."""
    frames = json.loads(out)["frames"]
    return [{k: v for k, v in f.items() if k != "time_s"} for f in frames]


def test_a_replay_with_its_prepared_model_cached_never_imports_open3d(tmp_path: Path) -> None:
    """Open3D (~0.3 CPU-s to import) computes only when a bin model is prepared (its voxel grid with
    normals, normal estimation) or on the ICP's reference path: a replay whose prepared model comes from
    the cache keeps every cloud as arrays (:class:`zcut.registration.Points`) and gives the same figures
    (docs/performance.md, "Open3D out of the replay, round of 2026-12-05")."""
    from replay.synth.log import write_synthetic_log

    log = tmp_path / "nuts.mcap"
    write_synthetic_log(log, kind="zinc_nuts", frames=3, seed=23, size=(200, 320))
    env = dict(os.environ, ZCUT_CACHE=str(tmp_path / "cache"))
    first, out_first = _fresh(_main("replay", str(log), "--json"), env=env)
    assert "open3d" in first, first  # the model was prepared (and cached) by this run, with Open3D
    again, out_again = _fresh(_main("replay", str(log), "--json"), env=env)
    assert "open3d" not in again, again
    assert {"numba", "scipy"} <= set(again)  # a run that did run the pipeline
    frames = _frames(out_again)
    assert len(frames) == 3 and all(f["fitness"] >= 0.9 and not f["warnings"] for f in frames), frames
    assert frames == _frames(out_first)


def test_the_gate_in_the_help_is_the_assistants() -> None:
    from annotate.assistant import GATE

    assert GATE_HELP == GATE
    p = argparse.ArgumentParser()
    add_gate_option(p)
    assert check_gate(p.parse_args([])) == GATE  # not given: the assistant's own
    assert check_gate(p.parse_args(["--assistant-gate", "0.5"])) == 0.5
    assert f"(default {GATE})" in " ".join(p.format_help().split())


def _toy_for_help() -> object:
    from dataclasses import dataclass

    from replay.pipeline.methods import Method, MethodOutput

    @dataclass(frozen=True, slots=True)
    class ToyParams:
        band_mm: float = 1.0

    def run(frame: object, zone: object, config: object) -> MethodOutput:  # pragma: no cover - never run
        raise AssertionError("a help test runs no method")

    return Method(name="toy_for_help", params=ToyParams, run=run, summary="a help test's method")


TOY_FOR_HELP = _toy_for_help()
