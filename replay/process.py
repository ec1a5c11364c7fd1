"""What belongs to the command-line process, not to the library: the exit statuses (SPEC §6) and the
process-wide settings every command (and every worker process of a study) starts with."""

from __future__ import annotations

import os
import sys

EXIT_OK = 0
EXIT_USER_ERROR = 1
EXIT_DATA_LOSS = 3


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
