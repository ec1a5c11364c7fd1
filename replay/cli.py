"""The ``zcut`` console script.

Each subcommand lives in its own module (``replay.commands.<name>`` or ``annotate.commands``) with
``add_arguments(parser)`` and ``run(args) -> int``; modules import their heavy dependencies inside
``run`` so that ``zcut --help`` stays fast. This is the only place that turns errors into messages
and exit codes (SPEC §6): 0 success, 1 user error (one line on stderr), 3 finished with data loss.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from zcut.errors import ZcutError

EXIT_OK = 0
EXIT_USER_ERROR = 1
EXIT_DATA_LOSS = 3

# name -> (module, one-line help). Order is the order shown by --help.
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("replay.commands.demo", "the whole job on the bundled synthetic sample: replay, .rrd, true accuracy"),
    "record": ("replay.commands.record", "turn organized .ply/.pcd files (or folders of them) into a ROS 2 MCAP log"),
    "topics": ("replay.commands.topics", "show what a log holds and which topics zcut would use"),
    "synth": ("replay.commands.synth", "synthesise a bin-picking log (six part kinds, empty bin) with exact ground-truth outliers"),
    "replay": ("replay.commands.replay", "run the pipeline (bin removal, z-cut, SOR) on a log; log every stage to Rerun"),
    "bin-model": ("replay.commands.bin_model", "build the bin model (PLY) from empty-bin scans, or import a CAD/PLY model"),
    "accuracy": ("annotate.commands.accuracy", "true accuracy of z-cut, SOR, union, intersection against labels or ground truth"),
    "annotate": ("annotate.commands.annotate", "label true outliers in a local web page (127.0.0.1, token in the URL)"),
    "labels": ("annotate.commands.labels", "list, export (MCAP) and import human labels of a label store"),
}


class _Parser(argparse.ArgumentParser):
    """argparse with SPEC §6 exit status: a usage error is a user error (1), not argparse's 2."""

    def error(self, message: str):  # type: ignore[override]
        self.print_usage(sys.stderr)
        self.exit(EXIT_USER_ERROR, f"error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="zcut",
        description="Replay bin-picking scans through the z-cut outlier filter, "
        "log every stage to Rerun, and measure true accuracy against labels.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, (module_name, help_text) in COMMANDS.items():
        module = importlib.import_module(module_name)
        p = sub.add_parser(name, help=help_text, description=help_text)
        module.add_arguments(p)
        p.set_defaults(_module=module)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "_module", None) is None:
        parser.print_help()
        return EXIT_USER_ERROR if argv is None and len(sys.argv) <= 1 else EXIT_OK
    try:
        return int(args._module.run(args) or 0)
    except ZcutError as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_USER_ERROR
    except FileNotFoundError as e:
        print(f"error: no such file: {e.filename}", file=sys.stderr)
        return EXIT_USER_ERROR
    except (IsADirectoryError, PermissionError) as e:
        print(f"error: {e.strerror}: {e.filename}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
