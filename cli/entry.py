"""The program entry of ``zcut`` (the console script and ``python -m cli``): signals before and after the command.

:func:`cli.main.main` turns SIGINT / SIGTERM into exit status 130 / 143 while a command runs
(docs/cli.md, "Exit status"). Around it there are two windows where Python's default disposition
would let the signal kill the process (exit -2 / -15, which the documented statuses exclude): while
the command's modules are imported, and while the interpreter tears down after the command returned
(Python puts the default disposition back early in its teardown). Before the command a signal ends
it with 128 + the signal's number (nothing was written yet); after it, the command has finished and
published its outputs, so the signal is ignored and the exit status is the command's own. The first
~20 ms of the interpreter's start, before this module runs, stay Python's.

**The end of the process.** Once the command returned, :func:`run` does what Python's own finalisation
does that anybody can observe -- it waits for the threads that are not daemons, runs the ``atexit``
handlers (Rerun's shutdown, ``weakref.finalize`` clean-ups such as ``tempfile``'s, multiprocessing's
and Ray's) and flushes the standard streams -- and then ends with ``os._exit``, skipping the
interpreter's teardown of its modules, which costs 0.4 CPU-s with numba, Open3D and SciPy loaded
(a 0.3 CPU-s frame's worth; docs/performance.md, "Fixed costs"). That teardown does nothing a command
relies on: every output is written, closed and renamed by the command itself (``replay.outputs``),
and the label store commits its transactions.

Nothing in the library imports this; tests call :func:`cli.main.main` in-process, where the test
runner's own signal handling must stay as it is.
"""

from __future__ import annotations

import atexit
import os
import signal
import sys
import threading
from typing import NoReturn

_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def _before(signum: int, frame: object) -> None:
    # Nothing is written yet, so the process ends here at once: an exception (SystemExit) could land in
    # an import's weakref callback, where Python prints "Exception ignored" and goes on importing.
    try:
        sys.stderr.write(f"interrupted ({signal.Signals(signum).name})\n")
        sys.stderr.flush()
    except (AttributeError, OSError):  # stderr closed or gone (a hung-up terminal): the status says it
        pass
    os._exit(128 + signum)


def run() -> NoReturn:
    """Run the ``zcut`` command line on ``sys.argv`` and end the process with its exit status."""
    end(command())


def end(status: int) -> NoReturn:
    """End the process with ``status`` as Python's finalisation would, minus the teardown of the modules."""
    shutdown = getattr(threading, "_shutdown", None)  # what the interpreter calls first: joins non-daemons
    if shutdown is not None:
        shutdown()
    atexit._run_exitfuncs()
    _flush()
    os._exit(int(status) & 0xFF)


def command() -> int:
    """Run the ``zcut`` command line on ``sys.argv``; returns its exit status."""
    for s in _SIGNALS:
        signal.signal(s, _before)
    from cli.main import main

    status = main()
    for s in _SIGNALS:  # ignored (not a Python handler): Python's teardown leaves SIG_IGN in place
        signal.signal(s, signal.SIG_IGN)
    _flush()
    return status


def _flush() -> None:
    for stream in (sys.stdout, sys.stderr):  # None when closed (`>&-`): cli.main said what was lost
        try:
            if stream is not None:
                stream.flush()
        except (OSError, ValueError):  # ValueError: a stream a library closed
            pass
