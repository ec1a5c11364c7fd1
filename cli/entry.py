"""The program entry of ``zcut`` (the console script and ``python -m cli``): signals before and after the command.

:func:`cli.main.main` turns SIGINT / SIGTERM into exit status 130 / 143 while a command runs
(docs/cli.md, "Exit status"). Around it there are two windows where Python's default disposition
would let the signal kill the process (exit -2 / -15, which the documented statuses exclude): while
the command's modules are imported, and while the interpreter tears down after the command returned
(Python puts the default disposition back early in its teardown, which lasts ~0.5 s with numba and
Open3D loaded). Before the command a signal ends it with 128 + the signal's number (nothing was
written yet); after it, the command has finished and published its outputs, so the signal is
ignored and the exit status is the command's own. The first ~20 ms of the interpreter's start,
before this module runs, stay Python's.

Nothing in the library imports this; tests call :func:`cli.main.main` in-process, where the test
runner's own signal handling must stay as it is.
"""

from __future__ import annotations

import os
import signal
import sys

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


def run() -> int:
    """Run the ``zcut`` command line on ``sys.argv``; returns its exit status."""
    for s in _SIGNALS:
        signal.signal(s, _before)
    from cli.main import main

    status = main()
    for s in _SIGNALS:  # ignored (not a Python handler): Python's teardown leaves SIG_IGN in place
        signal.signal(s, signal.SIG_IGN)
    for stream in (sys.stdout, sys.stderr):  # None when closed (`>&-`): cli.main said what was lost
        try:
            if stream is not None:
                stream.flush()
        except OSError:
            pass
    return status
