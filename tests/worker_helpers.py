"""Work functions for the executor tests, importable by spawned worker processes (tests/ is on
sys.path, and a spawned worker gets its driver's sys.path)."""

from __future__ import annotations

import os
import signal
from pathlib import Path


def die_on(unit, job):
    """Unit ``(name, mode)``: ``ok`` returns ``name``; ``always`` kills its worker every time;
    ``once`` kills it the first time (a marker file in the folder ``job`` remembers) and returns
    ``name`` on the retry."""
    name, mode = unit
    marker = Path(job) / f"{name}.seen"
    if mode == "always" or (mode == "once" and not marker.exists()):
        marker.write_text("")
        os.kill(os.getpid(), signal.SIGKILL)
    return name


def kill_worker(unit, job):
    """Any unit: kills its worker (a crash the driver must charge to the unit, e.g. a worker that cannot start)."""
    os.kill(os.getpid(), signal.SIGKILL)
