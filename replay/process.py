"""What belongs to the command-line process, not to the library: the exit statuses (docs/cli.md), the
process-wide settings every command (and every worker process of a study) starts with, and what a
signal does to a command.

Signals: while a command runs (:func:`interrupts_unwind`), SIGINT and SIGTERM raise
:class:`Interrupted` in the main thread, a ``KeyboardInterrupt`` that remembers its signal. The
command unwinds like after Ctrl-C: every ``finally`` runs, so the temporaries of its outputs are
removed, its worker processes are stopped and a study's finished units stay on disk (a rerun goes
on from there). The command line then prints one line and exits 128 + the signal: 130 for SIGINT,
143 for SIGTERM. A second signal while unwinding is not raised (the clean-up finishes); a third
ends the process at once.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager

EXIT_OK = 0
EXIT_USER_ERROR = 1
EXIT_DATA_LOSS = 3
#: 128 + the signal, as a shell reports a process ended by it
EXIT_SIGINT = 128 + signal.SIGINT
EXIT_SIGTERM = 128 + signal.SIGTERM

#: the signals a command handles like Ctrl-C
INTERRUPT_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM arrived while a command ran (see the module docstring).

    Attributes
    ----------
    signum : int
    """

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)

    @property
    def exit_status(self) -> int:
        """128 + the signal (130 for SIGINT, 143 for SIGTERM)."""
        return 128 + self.signum


class InterruptState:
    """The signals received while :func:`interrupts_unwind` was active (the first one decides the
    exit status)."""

    def __init__(self) -> None:
        self.signals: list[int] = []

    @property
    def signum(self) -> int | None:
        return self.signals[0] if self.signals else None

    @property
    def exit_status(self) -> int | None:
        return None if not self.signals else 128 + self.signals[0]


@contextmanager
def interrupts_unwind() -> Iterator[InterruptState]:
    """SIGINT and SIGTERM raise :class:`Interrupted` in the main thread while the block runs.

    Yields the :class:`InterruptState`: after an exception other than :class:`Interrupted` (a
    library that turned the interruption into an error of its own, e.g. numba's ``SystemError``
    from a call back into Python), ``state.signum`` still tells the caller that a signal caused it.
    Outside the main thread (where Python runs no signal handler) this does nothing.
    """
    state = InterruptState()
    if threading.current_thread() is not threading.main_thread():
        yield state
        return

    def handler(signum: int, frame) -> None:
        state.signals.append(signum)
        if len(state.signals) == 1:
            raise Interrupted(signum)
        if len(state.signals) >= 3:  # a clean-up that hangs: leave now (a later run removes the leftovers)
            os._exit(128 + state.signals[0])

    previous = {s: signal.signal(s, handler) for s in INTERRUPT_SIGNALS}
    try:
        yield state
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def interrupted_by(error: BaseException, state: InterruptState | None = None) -> int | None:
    """The exit status when ``error`` comes from an interruption (SIGINT/SIGTERM), else None.

    An :class:`Interrupted`, a plain ``KeyboardInterrupt``, or any error raised after a signal was
    received (``state``) or caused by an interruption (in its chain of causes) is one.
    """
    seen: set[int] = set()
    e: BaseException | None = error
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, Interrupted):
            return e.exit_status
        if isinstance(e, KeyboardInterrupt):
            return EXIT_SIGINT
        e = e.__cause__ or e.__context__
    if state is not None and state.exit_status is not None:
        return state.exit_status
    return None


def configure_process() -> None:
    """Process-wide settings that belong to the command line, not to the library.

    numba's own workqueue threads unless the user chose a layer: OpenMP workers spin after each
    parallel region and steal the CPU on a busy machine (measured 2-3x slower here), and an old TBB
    shipped by other wheels makes numba warn when it probes the "tbb" layer.
    """
    if "NUMBA_THREADING_LAYER" not in os.environ and "NUMBA_THREADING_LAYER_PRIORITY" not in os.environ:
        os.environ["NUMBA_THREADING_LAYER_PRIORITY"] = "workqueue omp tbb"
        if "numba" in sys.modules:  # numba read its config at import: set it there too
            import numba

            numba.config.THREADING_LAYER_PRIORITY = ["workqueue", "omp", "tbb"]
    # a recording that cannot be written is reported in zcut's one line, naming the output; Rerun's
    # own log lines (Rust's format, on stderr) would repeat it, many lines long
    os.environ.setdefault("RUST_LOG", "off")
    # `--spawn` runs `rerun` from PATH: a venv that is not activated has it only beside its python
    here = os.path.dirname(sys.executable)
    if os.path.isfile(os.path.join(here, "rerun")) and here not in os.environ.get("PATH", "").split(os.pathsep):
        os.environ["PATH"] = here + os.pathsep + os.environ.get("PATH", "")


def check_environment() -> str | None:
    """A one-line complaint about a zcut environment variable that is set wrong, or None."""
    from replay.logs.files import CAP_VARIABLES, env_cap

    for name in CAP_VARIABLES:
        if env_cap(name, 1) is None:
            return f"{name} must be a positive integer (a size cap), got {os.environ[name]!r}"
    return None
