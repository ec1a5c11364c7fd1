"""The ``zcut`` console script: the one composition root.

It names every command of ``cli/commands/`` (each a module with ``add_arguments(parser)`` and
``run(args) -> int``, importing its heavy dependencies inside ``run`` so that ``zcut --help`` stays
fast) and imports the module of the command a command line runs, none for ``zcut --help``, sets the process-wide settings a command line owns (the numba threading layer), and is the
only place that turns errors into messages and exit codes (docs/cli.md): 0 success, 1 user error (one
line on stderr, no traceback), 3 finished with data loss, 130 / 143 interrupted by SIGINT / SIGTERM
(one line; see :mod:`replay.process`). ``zcut.errors`` is imported inside :func:`main`, after the
signal handlers are in place: importing it loads numba and the kernels (seconds), and a Ctrl-C
then is an interruption like any other.
"""

from __future__ import annotations

import argparse
import errno
import io
import os
import signal
import sys
from collections.abc import Iterator, Sequence
from types import ModuleType
from typing import TYPE_CHECKING, Any, NoReturn, TextIO

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

if TYPE_CHECKING:
    from replay.process import InterruptState

# name -> (module of cli/commands/, one-line help). Order is the order shown by --help. A command's module is
# imported when its parser is built (:func:`command_module`): `zcut --help` imports none of them.
COMMANDS = {
    "demo": ("demo", "the whole job on the bundled synthetic sample: replay, .rrd, true accuracy"),
    "record": ("record", "turn organized .ply/.pcd files (or folders of them) into a ROS 2 MCAP log"),
    "record-stereo": ("record_stereo", "turn rectified stereo pairs with ground truth (Middlebury layout) into a log"),
    "topics": ("topics", "show what a log holds and which topics zcut would use"),
    "synth": ("synth", "synthesise a bin-picking log (six part kinds, empty bin) with exact ground-truth outliers"),
    "replay": ("replay", "run the pipeline (bin removal, z-cut, SOR) on a log; log every stage to Rerun"),
    "bin-model": ("bin_model", "build the bin model (PLY) from empty-bin scans, or import a CAD/PLY model"),
    "accuracy": ("accuracy", "true accuracy of z-cut, SOR, union, intersection against labels or ground truth"),
    "annotate": ("annotate", "label true outliers in a local web page (127.0.0.1, token in the URL)"),
    "labels": ("labels", "list, export (MCAP) and import human labels of a label store"),
    "sweep": ("sweep", "parameter study of the z-cut and SOR scored by true accuracy; tuned parameters, report"),
    "batch": ("batch", "replay many logs on all cores (or a Ray cluster): one table of every frame, scored"),
    "compare": ("compare", "two configs, methods or results files on the same frames: paired verdict, .rrd, report"),
}


def command_module(name: str) -> ModuleType:
    """The module of ``cli/commands/`` that implements command ``name`` (a key of :data:`COMMANDS`),
    imported now: each command's own, explicitly (tests/test_layout.py), and only the one that runs."""
    match COMMANDS[name][0]:
        case "demo":
            from cli.commands import demo

            return demo
        case "record":
            from cli.commands import record

            return record
        case "record_stereo":
            from cli.commands import record_stereo

            return record_stereo
        case "topics":
            from cli.commands import topics

            return topics
        case "synth":
            from cli.commands import synth

            return synth
        case "replay":
            from cli.commands import replay

            return replay
        case "bin_model":
            from cli.commands import bin_model

            return bin_model
        case "accuracy":
            from cli.commands import accuracy

            return accuracy
        case "annotate":
            from cli.commands import annotate

            return annotate
        case "labels":
            from cli.commands import labels

            return labels
        case "sweep":
            from cli.commands import sweep

            return sweep
        case "batch":
            from cli.commands import batch

            return batch
        case "compare":
            from cli.commands import compare

            return compare
        case other:  # pragma: no cover - a COMMANDS entry without its case here
            raise AssertionError(f"no module for command {other!r}")


def version() -> str:
    """The installed distribution's version (read only when ``--version`` is asked)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version

    try:
        return dist_version("zcut")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
        return "unknown"


class _Parser(argparse.ArgumentParser):
    """argparse with docs/cli.md's usage errors: one line naming the option and what was wrong, and
    where the options are listed (no usage block), exit 1 (a user error), not argparse's 2."""

    #: the prog of the command a top-level parser parses (its unrecognized arguments are that command's)
    command_prog: str | None = None

    def error(self, message: str) -> NoReturn:
        prog = self.command_prog if self.command_prog and message.startswith("unrecognized") else self.prog
        self.exit(EXIT_USER_ERROR, f"error: {message} (see `{prog} --help`)\n")


class _Version(argparse.Action):
    """``--version``: the version is looked up only when asked (importlib.metadata costs ~0.1 s)."""

    def __init__(self, option_strings: Sequence[str], dest: str = argparse.SUPPRESS, default: Any = argparse.SUPPRESS,
                 help: str | None = None) -> None:
        super().__init__(option_strings=option_strings, dest=dest, default=default, nargs=0,
                         help=help or "show the version and exit")

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: str | Sequence[Any] | None, option_string: str | None = None) -> None:
        sys.stdout.write(f"zcut {version()}\n")
        parser.exit()


def command_of(argv: list[str]) -> str | None:
    """The command named on a command line (the first word that is not an option), or None."""
    for a in argv:
        if not a.startswith("-"):
            return a if a in COMMANDS else None
    return None


def build_parser(command: str | None = None, *, only: bool = False) -> _Parser:
    """The whole parser; with ``only``, the options of ``command`` alone (of none if it is None).

    Each command's ``add_arguments`` may import what its choices need (numpy, the method table): the
    command line adds only the command it runs, so that ``zcut --version`` and ``zcut --help`` load
    none of it.
    """
    parser = _Parser(
        prog="zcut",
        description="Replay bin-picking scans through the z-cut outlier filter, "
        "log every stage to Rerun, and measure true accuracy against labels.",
    )
    parser.add_argument("--version", action=_Version)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, (_, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if not only or name == command:
            command_module(name).add_arguments(p)
        p.set_defaults(_command=name)
    if command in COMMANDS:
        parser.command_prog = f"zcut {command}"
    return parser


#: commands that run numba kernels (the others never wait for a compilation)
_KERNEL_COMMANDS = {"demo", "replay", "accuracy", "annotate", "sweep", "batch", "synth", "bin-model", "record"}


def announce_compilation(args: argparse.Namespace) -> None:
    """Say so when the numba kernels have never been compiled here (a first run waits minutes).

    ``scripts/install.sh`` compiles them (``python -m replay.warmup``); the cache lives beside the
    modules (``__pycache__/*.nbi``), else in ``NUMBA_CACHE_DIR`` or numba's per-user folder.
    """
    if args.command not in _KERNEL_COMMANDS:
        return
    import glob

    from replay.process import _user_cache_dir, numba_cache_folders

    places = [f for f in numba_cache_folders() if os.path.basename(os.path.dirname(f)) == "zcut"]
    places += [os.path.join(d, "zcut_*") for d in (os.environ.get("NUMBA_CACHE_DIR"), _user_cache_dir()) if d]
    if not any(glob.glob(os.path.join(p, "cut_tree*.nbi")) for p in places):
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
    stdout = _StdoutGuard.install()
    try:
        with interrupts_unwind() as interrupts:
            try:
                status = _main(argv, interrupts)
                signum = interrupts.signum  # None: no signal came (no exit status of one)
                if signum is None:
                    return stdout.status(status)
                raise Interrupted(signum)  # a library swallowed the interruption: it still ends the command
            except BaseException as e:  # noqa: BLE001 - an interruption, whatever a library made of it
                if isinstance(e, SystemExit) and not e.code:  # --help, --version: printed, if stdout took it
                    stdout.flush()
                    if stdout.lost:
                        return stdout.status(EXIT_OK)
                interrupted = interrupted_by(e, interrupts)
                if interrupted is None:
                    raise
                print(f"interrupted ({signal.Signals(interrupted - 128).name})", file=sys.stderr)
                return interrupted
    finally:
        stdout.uninstall()


def _main(argv: list[str] | None, interrupts: InterruptState) -> int:
    configure_process()
    words = sys.argv[1:] if argv is None else argv
    parser = build_parser(command_of(words), only=True)
    args = parser.parse_args(argv)
    if getattr(args, "_command", None) is None:
        parser.print_help()
        return EXIT_USER_ERROR if argv is None and len(sys.argv) <= 1 else EXIT_OK
    announce_compilation(args)
    problem = check_environment()
    if problem is not None:
        print(f"error: {problem}", file=sys.stderr)
        return EXIT_USER_ERROR
    try:
        status = int(command_module(args._command).run(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, not at exit
        return status
    except Exception as e:
        if interrupted_by(e, interrupts) is not None:
            raise  # an error the interruption caused: main reports the interruption
        return _report(e)


class _StdoutGuard(io.TextIOBase):
    """``sys.stdout`` while a command runs (docs/cli.md, "Exit status"): what cannot be written to a
    closed (``>&-``) or full (``>/dev/full``, a full disk) standard output is dropped, so the command
    still finishes and publishes its file outputs; the command line then says so in one line and
    exits 1. A reader that went away (``| head``) still ends the command quietly (BrokenPipeError).
    A closed descriptor 1 gets /dev/null, so that no file the command opens (nor a worker's output)
    takes its place."""

    _saved: TextIO  # sys.stdout before install (set by it)

    def __init__(self, inner: TextIO | None, problem: str | None) -> None:
        super().__init__()
        self._inner = inner
        self.problem = problem  # why stdout could not be written (None: it could)
        self.lost = False  # something was written that did not arrive

    @classmethod
    def install(cls) -> _StdoutGuard:
        inner, problem = sys.stdout, None
        if inner is None or _fd_closed(1):
            _devnull_on(1)
            inner, problem = None, "it is closed"
        if sys.stderr is None or _fd_closed(2):  # nowhere to say anything: keep the descriptor taken
            _devnull_on(2)
            sys.stderr = open(os.devnull, "w")  # noqa: SIM115 - lives as long as the process
        guard = cls(inner, problem)
        guard._saved = sys.stdout
        sys.stdout = guard
        return guard

    def uninstall(self) -> None:
        if sys.stdout is self:
            sys.stdout = self._saved

    def status(self, status: int) -> int:
        """The command's exit status, 1 if its standard output was lost (and it had succeeded)."""
        if self.lost:
            print(f"error: the standard output could not be written ({self.problem}): what the command "
                  "printed is lost; its file outputs are complete", file=sys.stderr)
            return status or EXIT_USER_ERROR
        return status

    def _fail(self, e: OSError | None) -> None:
        self.lost = True
        if e is not None:
            self.problem = "no space left on the device" if e.errno == errno.ENOSPC else (e.strerror or str(e))
            _devnull_on(1)  # the buffered rest goes nowhere, quietly, at exit too
        self._inner = None

    def write(self, s: str) -> int:
        if not s:
            return 0
        if self._inner is None:
            self._fail(None)
            return len(s)
        try:
            return int(self._inner.write(s))
        except BrokenPipeError:
            raise
        except OSError as e:
            self._fail(e)
            return len(s)

    def flush(self) -> None:
        if self._inner is None:
            return
        try:
            self._inner.flush()
        except BrokenPipeError:
            raise
        except OSError as e:
            self._fail(e)

    def writable(self) -> bool:
        return True

    def isatty(self) -> bool:
        return self._inner is not None and self._inner.isatty()

    def fileno(self) -> int:
        return 1 if self._inner is None else self._inner.fileno()

    @property
    def encoding(self) -> str:  # type: ignore[override]
        return getattr(self._inner, "encoding", None) or "utf-8"

    @property
    def buffer(self) -> Any:
        if self._inner is None:
            return io.BytesIO()  # bytes written here go nowhere, like the text
        return self._inner.buffer

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)


def _fd_closed(fd: int) -> bool:
    try:
        os.fstat(fd)
        return False
    except OSError:
        return True


def _devnull_on(fd: int) -> None:
    null = os.open(os.devnull, os.O_WRONLY)
    if null != fd:
        os.dup2(null, fd)
        os.close(null)


def _chain(e: BaseException) -> Iterator[BaseException]:
    seen: set[int] = set()
    cur: BaseException | None = e
    while cur is not None and id(cur) not in seen:
        seen.add(id(cur))
        yield cur
        cur = cur.__cause__ or cur.__context__


def _out_of_memory(e: BaseException) -> str | None:
    """The one line of a failure to get memory: a MemoryError, or a compiled extension that could not
    be loaded for want of address space (``ulimit -v``: "failed to map segment from shared object",
    "cannot allocate memory"), anywhere in the chain of causes; else None."""
    for c in _chain(e):
        if isinstance(c, MemoryError):
            return f"not enough memory ({c})" if str(c) else "not enough memory"
        if isinstance(c, ImportError) and not isinstance(c, ModuleNotFoundError):
            text = str(c).lower()
            if any(k in text for k in ("failed to map segment", "cannot allocate memory", "failed to allocate",
                                       "out of memory", "cannot map", "enomem")):
                lib = str(c).split(":")[0].strip()  # "libOpen3D.so.0.20: failed to map segment ..."
                what = lib if ".so" in lib else (c.name or "a compiled extension")
                return (f"not enough memory to load {what} (a memory limit such as `ulimit -v` "
                        "is lower than the command needs)")
    return None


def _report(e: Exception) -> int:
    """Print the one line of an error a command raised and return its exit status; re-raise an
    error that is not the user's (a bug: its traceback is wanted)."""
    errors = sys.modules.get("zcut.errors")  # a ZcutError was raised only if zcut.errors is loaded
    memory = _out_of_memory(e)
    if errors is not None and isinstance(e, errors.ZcutError):
        print(f"error: {e}", file=sys.stderr)
    elif memory is not None:
        print(f"error: {memory}", file=sys.stderr)
    elif isinstance(e, BrokenPipeError):
        # the reader of stdout went away (`zcut topics LOG | head`): nothing more to say to anyone
        try:
            _devnull_on(1)
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
    elif isinstance(e, (OverflowError, RecursionError)):
        kind = "a number is out of range" if isinstance(e, OverflowError) else "input nested too deeply"
        print(f"error: {kind} ({e})" if str(e) else f"error: {kind}", file=sys.stderr)
    else:
        raise e
    return EXIT_USER_ERROR


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
