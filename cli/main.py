"""The ``zcut`` console script: the one composition root.

It imports every package's commands explicitly (each a module with ``add_arguments(parser)`` and
``run(args) -> int``, importing its heavy dependencies inside ``run`` so that ``zcut --help`` stays
fast), sets the process-wide settings a command line owns (the numba threading layer), and is the
only place that turns errors into messages and exit codes (docs/cli.md): 0 success, 1 user error (one
line on stderr, no traceback), 3 finished with data loss, 130 / 143 interrupted by SIGINT / SIGTERM
(one line; see :mod:`replay.process`). ``zcut.errors`` is imported inside :func:`main`, after the
signal handlers are in place: importing it loads numba and the kernels (seconds), and a Ctrl-C
then is an interruption like any other.
"""

from __future__ import annotations

import argparse
import errno
import os
import signal
import sys

from annotate.commands import accuracy as accuracy_cmd
from annotate.commands import annotate as annotate_cmd
from annotate.commands import labels as labels_cmd
from replay.commands import bin_model as bin_model_cmd
from replay.commands import record as record_cmd
from replay.commands import record_stereo as record_stereo_cmd
from replay.commands import replay as replay_cmd
from replay.commands import synth as synth_cmd
from replay.commands import topics as topics_cmd
from replay.process import (  # noqa: F401
    EXIT_DATA_LOSS,
    EXIT_OK,
    EXIT_USER_ERROR,
    Interrupted,
    check_environment,
    configure_process,
    interrupted_by,
    interrupts_unwind,
)
from studies.commands import batch as batch_cmd
from studies.commands import compare as compare_cmd
from studies.commands import demo as demo_cmd
from studies.commands import sweep as sweep_cmd

# name -> (module, one-line help). Order is the order shown by --help.
COMMANDS = {
    "demo": (demo_cmd, "the whole job on the bundled synthetic sample: replay, .rrd, true accuracy"),
    "record": (record_cmd, "turn organized .ply/.pcd files (or folders of them) into a ROS 2 MCAP log"),
    "record-stereo": (record_stereo_cmd, "turn rectified stereo pairs with ground truth (Middlebury layout) into a log"),
    "topics": (topics_cmd, "show what a log holds and which topics zcut would use"),
    "synth": (synth_cmd, "synthesise a bin-picking log (six part kinds, empty bin) with exact ground-truth outliers"),
    "replay": (replay_cmd, "run the pipeline (bin removal, z-cut, SOR) on a log; log every stage to Rerun"),
    "bin-model": (bin_model_cmd, "build the bin model (PLY) from empty-bin scans, or import a CAD/PLY model"),
    "accuracy": (accuracy_cmd, "true accuracy of z-cut, SOR, union, intersection against labels or ground truth"),
    "annotate": (annotate_cmd, "label true outliers in a local web page (127.0.0.1, token in the URL)"),
    "labels": (labels_cmd, "list, export (MCAP) and import human labels of a label store"),
    "sweep": (sweep_cmd, "parameter study of the z-cut and SOR scored by true accuracy; tuned parameters, report"),
    "batch": (batch_cmd, "replay many logs on all cores (or a Ray cluster): one table of every frame, scored"),
    "compare": (compare_cmd, "two configs, methods or results files on the same frames: paired verdict, .rrd, report"),
}


def version() -> str:
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version

    try:
        return dist_version("zcut")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
        return "unknown"


class _Parser(argparse.ArgumentParser):
    """argparse with docs/cli.md exit status: a usage error is a user error (1), not argparse's 2."""

    def error(self, message: str):  # type: ignore[override]
        self.print_usage(sys.stderr)
        self.exit(EXIT_USER_ERROR, f"error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="zcut",
        description="Replay bin-picking scans through the z-cut outlier filter, "
        "log every stage to Rerun, and measure true accuracy against labels.",
    )
    parser.add_argument("--version", action="version", version=f"zcut {version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        module.add_arguments(p)
        p.set_defaults(_module=module)
    return parser


#: commands that run numba kernels (the others never wait for a compilation)
_KERNEL_COMMANDS = {"demo", "replay", "accuracy", "annotate", "sweep", "batch", "synth", "bin-model", "record"}


def announce_compilation(args: argparse.Namespace) -> None:
    """Say so when the numba kernels have never been compiled here (a first run waits ~1 min).

    ``scripts/install.sh`` compiles them (``python -m replay.warmup``); the cache lives beside the
    modules (``__pycache__/*.nbi``).
    """
    if args.command not in _KERNEL_COMMANDS:
        return
    from pathlib import Path

    import zcut

    cache = Path(zcut.__file__).parent / "__pycache__"
    if not any(cache.glob("cut_tree*.nbi")):
        print("zcut: compiling the numba kernels (first run only; `bash scripts/install.sh` does it ahead)…",
              file=sys.stderr, flush=True)


def _os_error_message(e: OSError) -> str:
    what = e.strerror or str(e)
    if e.errno == errno.ENOSPC:
        what = "no space left on the device"
    elif e.errno == errno.ENOTDIR:
        what = "a part of the path is a file, not a folder"
    name = e.filename if e.filename is not None else ""
    return f"{what}: {name}" if name else what


def main(argv: list[str] | None = None) -> int:
    with interrupts_unwind() as interrupts:
        try:
            status = _main(argv, interrupts)
            if interrupts.exit_status is None:
                return status
            raise Interrupted(interrupts.signum)  # a library swallowed the interruption: it still ends the command
        except BaseException as e:  # noqa: BLE001 - an interruption, whatever a library made of it
            status = interrupted_by(e, interrupts)
            if status is None:
                raise
            print(f"interrupted ({signal.Signals(status - 128).name})", file=sys.stderr)
            return status


def _main(argv: list[str] | None, interrupts) -> int:
    configure_process()
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "_module", None) is None:
        parser.print_help()
        return EXIT_USER_ERROR if argv is None and len(sys.argv) <= 1 else EXIT_OK
    announce_compilation(args)
    problem = check_environment()
    if problem is not None:
        print(f"error: {problem}", file=sys.stderr)
        return EXIT_USER_ERROR
    try:
        status = int(args._module.run(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, not at exit
        return status
    except Exception as e:
        if interrupted_by(e, interrupts) is not None:
            raise  # an error the interruption caused: main reports the interruption
        return _report(e)


def _report(e: Exception) -> int:
    """Print the one line of an error a command raised and return its exit status; re-raise an
    error that is not the user's (a bug: its traceback is wanted)."""
    from zcut.errors import ZcutError

    if isinstance(e, ZcutError):
        print(f"error: {e}", file=sys.stderr)
    elif isinstance(e, BrokenPipeError):
        # the reader of stdout went away (`zcut topics LOG | head`): nothing more to say to anyone
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
        except OSError:
            pass
        return EXIT_OK
    elif isinstance(e, FileNotFoundError):
        print(f"error: no such file: {e.filename}", file=sys.stderr)
    elif isinstance(e, OSError):
        print(f"error: {_os_error_message(e)}", file=sys.stderr)
    elif isinstance(e, UnicodeEncodeError):  # undecodable bytes of a file name or argument, where text is needed
        print(f"error: {e.object[:80]!r} is not valid UTF-8 text, which is needed here "
              "(a file name or an argument with undecodable bytes?)", file=sys.stderr)
    elif isinstance(e, (OverflowError, RecursionError, MemoryError)):
        kind = next(k for t, k in ((OverflowError, "a number is out of range"),
                                   (RecursionError, "input nested too deeply"),
                                   (MemoryError, "not enough memory")) if isinstance(e, t))
        print(f"error: {kind} ({e})" if str(e) else f"error: {kind}", file=sys.stderr)
    else:
        raise e
    return EXIT_USER_ERROR


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
