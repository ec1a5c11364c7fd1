"""What belongs to the command-line process, not to the library: the exit statuses (docs/cli.md), the
process-wide settings every command (and every worker process of a study) starts with, and what a
signal does to a command.

Signals: while a command runs (:func:`interrupts_unwind`), SIGINT, SIGTERM and SIGHUP (a closed
terminal or SSH session) raise :class:`Interrupted` in the main thread, a ``KeyboardInterrupt`` that
remembers its signal. The command unwinds like after Ctrl-C: every ``finally`` runs, so the
temporaries of its outputs are removed, its worker processes are stopped and a study's finished
units stay on disk (a rerun goes on from there). The command line then prints one line and exits
128 + the signal: 130 for SIGINT, 143 for SIGTERM, 129 for SIGHUP. A second signal while unwinding
is not raised (the clean-up finishes); a third ends the process at once. A signal whose exception
Python cannot raise where it lands (a weakref callback or a ``__del__``, which Python would report
as "Exception ignored" and go on from) is delivered again, so it raises at the next ordinary line;
one a library swallowed (a bare ``except``) raises again between frames and before an output is
published (:func:`raise_if_interrupted`).

numba's cache: the kernels are cached beside their modules, else (a shared install the user cannot
write) in numba's per-user folder; when neither can be written, :func:`configure_process` points
``NUMBA_CACHE_DIR`` at a private folder of the temporary directory before numba is imported (numba
itself would fail at import, in every command).
"""

from __future__ import annotations

import _thread
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

EXIT_OK = 0
EXIT_USER_ERROR = 1
EXIT_DATA_LOSS = 3
#: 128 + the signal, as a shell reports a process ended by it
EXIT_SIGINT = 128 + signal.SIGINT

#: the signals a command handles like Ctrl-C
INTERRUPT_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class Interrupted(KeyboardInterrupt):
    """SIGINT, SIGTERM or SIGHUP arrived while a command ran (see the module docstring).

    Attributes
    ----------
    signum : int
    """

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)

    @property
    def exit_status(self) -> int:
        """128 + the signal (130 for SIGINT, 143 for SIGTERM, 129 for SIGHUP)."""
        return 128 + self.signum


class InterruptState:
    """The signals received while :func:`interrupts_unwind` was active (the first one decides the
    exit status)."""

    def __init__(self) -> None:
        self.signals: list[int] = []
        #: an Interrupted was raised for the first signal (later ones are counted, not raised)
        self.raised = False
        #: :func:`interrupts_deferred` blocks running, and whether a signal waits for their end
        self.deferring = 0
        self.pending = False

    @property
    def signum(self) -> int | None:
        return self.signals[0] if self.signals else None

    @property
    def exit_status(self) -> int | None:
        return None if not self.signals else 128 + self.signals[0]


#: the states of the :func:`interrupts_unwind` blocks running (innermost last)
_active: list[InterruptState] = []


def raise_if_interrupted() -> None:
    """Raise :class:`Interrupted` when a signal came during :func:`interrupts_unwind` but the work
    went on as if it had not: a library swallowed its exception (a bare ``except`` around an import,
    ...). Called before what cannot be undone (publishing an output) and between frames. Does nothing
    while an exception is being handled (the unwinding after the signal, whose clean-up must finish),
    outside such a block, and in a study's worker processes (they ignore the signals)."""
    if _active and _active[-1].signals and sys.exc_info()[1] is None:
        raise Interrupted(_active[-1].signals[0])


@contextmanager
def interrupts_unwind() -> Iterator[InterruptState]:
    """SIGINT, SIGTERM and SIGHUP raise :class:`Interrupted` in the main thread while the block runs.

    Yields the :class:`InterruptState`: after an exception other than :class:`Interrupted` (a
    library that turned the interruption into an error of its own, e.g. numba's ``SystemError``
    from a call back into Python), ``state.signum`` still tells the caller that a signal caused it.
    Outside the main thread (where Python runs no signal handler) this does nothing.
    """
    state = InterruptState()
    if threading.current_thread() is not threading.main_thread():
        yield state
        return
    def handler(signum: int, frame: FrameType | None) -> None:
        state.signals.append(signum)
        if not state.raised and state.deferring:  # raised when the deferring block ends
            state.pending = True
            if len(state.signals) >= 3:
                os._exit(128 + state.signals[0])
            return
        if not state.raised:
            state.raised = True
            raise Interrupted(signum)
        if len(state.signals) >= 3:  # a clean-up that hangs: leave now (a later run removes the leftovers)
            os._exit(128 + state.signals[0])

    in_hook = [False]

    def redeliver(signum: int) -> None:
        while in_hook[0]:  # (the handler must not run inside the hook: its exception would be ignored again)
            time.sleep(0.0005)
        _thread.interrupt_main(signal.Signals(signum))

    def swallowed(unraisable: sys.UnraisableHookArgs) -> None:
        # The handler's exception landed where Python cannot raise it (a weakref callback, such as
        # importlib's module-lock one, or a __del__): Python would print "Exception ignored in ..." and
        # go on. Deliver the same signal again from a thread once this hook has returned, so that it
        # raises at the main thread's next ordinary line instead.
        e = unraisable.exc_value
        if not (isinstance(e, Interrupted) and state.raised and state.signals):
            previous_hook(unraisable)
            return
        in_hook[0] = True
        state.raised = False
        state.signals.pop()
        threading.Thread(target=redeliver, args=(e.signum,), name="zcut-redeliver", daemon=True).start()
        in_hook[0] = False

    previous_hook = sys.unraisablehook
    previous = {s: signal.signal(s, handler) for s in INTERRUPT_SIGNALS}
    sys.unraisablehook = swallowed
    _active.append(state)
    try:
        yield state
    finally:
        _active.remove(state)
        sys.unraisablehook = previous_hook
        for s, h in previous.items():
            signal.signal(s, h)


@contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Inside :func:`interrupts_unwind`, a signal that comes while this block runs waits for its end:
    :class:`Interrupted` is raised when the block has finished, not in its middle.

    For a library object whose construction an exception must not cut in two: Rerun's
    ``RecordingStream.__init__`` interrupted before it set its native half leaves an object whose
    ``__del__`` prints a traceback after the one-line "interrupted". A third signal still ends the
    process at once. Outside an :func:`interrupts_unwind` block, or outside the main thread, this does
    nothing."""
    state = _active[-1] if _active and threading.current_thread() is threading.main_thread() else None
    if state is None:
        yield
        return
    state.deferring += 1
    try:
        yield
    finally:
        state.deferring -= 1
    if not state.deferring and state.pending:
        state.pending = False
        if not state.raised and sys.exc_info()[1] is None:
            state.raised = True
            raise Interrupted(state.signals[0])


def interrupted_by(error: BaseException, state: InterruptState | None = None) -> int | None:
    """The exit status when ``error`` comes from an interruption (SIGINT/SIGTERM/SIGHUP), else None.

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


#: numba's threading layers in the order :func:`configure_process` asks for them: OpenMP's (GNU libgomp, with
#: :data:`OPENMP_NO_SPIN`), whose parallel kernels two threads may launch at once (two frames in flight run their
#: bin stages side by side), else numba's own workqueue, which aborts the process when two threads do
#: (``replay.pipeline.session.PARALLEL_KERNELS`` then runs them one at a time). TBB last: an old TBB shipped by
#: other wheels makes numba warn when it probes it. The previous choice, workqueue first: set
#: ``NUMBA_THREADING_LAYER=workqueue`` (docs/performance.md, "Both cores busy").
THREADING_LAYER_PRIORITY = ("omp", "workqueue", "tbb")

#: GNU OpenMP's settings (read when libgomp loads): its idle workers sleep at once instead of spinning
#: (by default for up to ~300,000 rounds after every parallel region: on a shared machine they stole the CPU,
#: 2-3 x slower here, which is why workqueue was chosen before). :func:`configure_process` sets them unless the
#: user did; the same results, the threads only wait differently.
OPENMP_NO_SPIN = {"OMP_WAIT_POLICY": "PASSIVE", "GOMP_SPINCOUNT": "0"}


#: OpenCV's settings of how long its thread pool spins waiting (read when cv2 loads); :func:`configure_process`
#: sets them to 0 unless the user set them
OPENCV_NO_SPIN = ("OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER", "OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN")


#: glibc's ``mallopt`` parameters: the most malloc arenas the threads of a process may have, the free bytes at
#: the top of the heap beyond which they are given back to the kernel, the most chunks served by ``mmap``
_M_ARENA_MAX, _M_TRIM_THRESHOLD, _M_MMAP_MAX = -8, -1, -4

#: the environment variables by which a user tunes glibc's malloc: :func:`keep_freed_memory` then leaves it be
MALLOC_VARIABLES = ("MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_MAX_", "MALLOC_MMAP_THRESHOLD_", "MALLOC_TOP_PAD_")

#: the free bytes at the top of the heap kept by :func:`keep_freed_memory` (the most ``mallopt`` takes: an int)
KEPT_FREE_BYTES = 2**31 - 1


def _mallopt() -> Any:
    """glibc's ``mallopt`` (``int mallopt(int, int)``), or None (not Linux, not glibc)."""
    if not sys.platform.startswith("linux"):
        return None
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # not glibc
        return None
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return mallopt


def one_malloc_arena() -> bool:
    """Let every thread allocate from glibc's main arena (``mallopt(M_ARENA_MAX, 1)``), unless the user set
    ``MALLOC_ARENA_MAX``; True when set (glibc only, and only for arenas not made yet: call it before
    threads start).

    A replay's threads (the reader, the locator, SOR's, numba's) allocate frame-sized arrays. In arenas
    of their own (heaps of at most 64 MB each) the heaps that a frame's arrays filled are given back to
    the kernel when the frame is freed, and the next frame faults them in again (3,700-4,300 minor faults,
    40-60 system CPU ms a 1920 x 1200 frame at load 20); the main arena keeps freed memory for reuse
    (106 faults, 9-15 ms; docs/performance.md, "The replay outside its stages").
    """
    mallopt = None if "MALLOC_ARENA_MAX" in os.environ else _mallopt()
    return mallopt is not None and bool(mallopt(_M_ARENA_MAX, 1))


def keep_freed_memory() -> bool:
    """Keep the memory a frame frees for the next frame (glibc's main arena): no ``mmap`` for large
    allocations (``mallopt(M_MMAP_MAX, 0)``) and no trimming of the heap's top below
    :data:`KEPT_FREE_BYTES` (``M_TRIM_THRESHOLD``), unless the user tunes malloc (:data:`MALLOC_VARIABLES`,
    ``glibc.malloc`` in ``GLIBC_TUNABLES``). True when set (glibc only).

    By default glibc serves an allocation above its ``mmap`` threshold (which it raises as such chunks are
    freed, up to 32 MB) with fresh pages and unmaps them at ``free``, and it gives the top of the heap back
    when more than twice that is free there: which happens depends on the order in which a replay's threads
    allocate and free a frame's arrays, so a whole replay faulted 400-1,400 pages a frame back in (the
    kernel zeroing each: 10-21 system CPU ms a 1920 x 1200 frame) where the same stages run one after the
    other faulted 2 (docs/performance.md, "The replay outside its stages, round of 2026-12-05c"). A
    process so set keeps its largest heap until it ends, as a replay's does anyway (its frames are alike).
    """
    tuned = any(v in os.environ for v in MALLOC_VARIABLES) or "glibc.malloc." in os.environ.get("GLIBC_TUNABLES", "")
    mallopt = None if tuned else _mallopt()
    return mallopt is not None and bool(mallopt(_M_MMAP_MAX, 0)) and bool(mallopt(_M_TRIM_THRESHOLD, KEPT_FREE_BYTES))


def configure_process() -> None:
    """Process-wide settings that belong to the command line, not to the library.

    numba's threading layer (:data:`THREADING_LAYER_PRIORITY`) unless the user chose one
    (``NUMBA_THREADING_LAYER`` or ``NUMBA_THREADING_LAYER_PRIORITY``; ``NUMBA_THREADING_LAYER=workqueue``
    is the previous choice), and OpenMP's workers set not to spin (:data:`OPENMP_NO_SPIN`). OpenCV's pool threads do
    not spin either (:data:`OPENCV_NO_SPIN`; the bin mask's calls left one of them yielding the CPU
    ~1,900 times a frame). Every thread allocates from one malloc arena (:func:`one_malloc_arena`), and the
    memory a frame frees is kept for the next (:func:`keep_freed_memory`).
    """
    if "NUMBA_THREADING_LAYER" not in os.environ and "NUMBA_THREADING_LAYER_PRIORITY" not in os.environ:
        os.environ["NUMBA_THREADING_LAYER_PRIORITY"] = " ".join(THREADING_LAYER_PRIORITY)
        if "numba" in sys.modules:  # numba read its config at import: set it there too
            import numba

            numba.config.THREADING_LAYER_PRIORITY = list(THREADING_LAYER_PRIORITY)  # type: ignore[attr-defined]  # set at import
    # read when libgomp loads (numba loads it at the first parallel kernel): set before
    for name, value in OPENMP_NO_SPIN.items():
        os.environ.setdefault(name, value)
    # OpenCV's pool threads spin (sched_yield) for 2000 rounds after every parallel call before they sleep,
    # and its calling thread 10000 rounds for them: read when cv2 loads, so set before (docs/performance.md,
    # "The replay outside its stages"); the same results, the threads only wait differently
    for name in OPENCV_NO_SPIN:
        os.environ.setdefault(name, "0")
    one_malloc_arena()
    keep_freed_memory()
    # a recording that cannot be written is reported in zcut's one line, naming the output; Rerun's
    # own log lines (Rust's format, on stderr) would repeat it, many lines long
    os.environ.setdefault("RUST_LOG", "off")
    ensure_numba_cache()
    open3d_without_plotly()
    # `--spawn` runs `rerun` from PATH: a venv that is not activated has it only beside its python
    here = os.path.dirname(sys.executable)
    if os.path.isfile(os.path.join(here, "rerun")) and here not in os.environ.get("PATH", "").split(os.pathsep):
        os.environ["PATH"] = here + os.pathsep + os.environ.get("PATH", "")


#: the module of Open3D that imports Dash and Plotly (0.6-0.9 CPU-s) at ``import open3d``
_PLOTLY_MODULE = "open3d.visualization.draw_plotly"


def _plotly_unavailable(*args: object, **kwargs: object) -> None:
    raise RuntimeError("open3d.visualization.draw_plotly is not loaded in a zcut command's process "
                       "(replay.process.open3d_without_plotly): call it from a Python session of your own")


def open3d_without_plotly() -> None:
    """Let ``import open3d`` skip Dash and Plotly in a command's process (docs/performance.md, "Fixed costs").

    Open3D's ``visualization`` package imports ``draw_plotly`` whatever is used, and that module
    imports Dash and Plotly: 0.6-0.9 of the 1.4-1.7 CPU-s Open3D's import costs, paid by every
    command and every worker process, for a viewer zcut never calls. Before Open3D is imported, a
    stand-in takes that module's place: its three functions raise a ``RuntimeError`` saying why.
    Nothing is done when Open3D is already imported (its real module stays), nor for a library user
    (only the command line and the study workers call :func:`configure_process`).
    """
    if "open3d" in sys.modules or _PLOTLY_MODULE in sys.modules:
        return
    import types

    stand_in = types.ModuleType(_PLOTLY_MODULE, "Stand-in for Open3D's Plotly viewer (not loaded by zcut's commands).")
    for name in ("get_plotly_fig", "draw_plotly", "draw_plotly_server"):
        setattr(stand_in, name, _plotly_unavailable)
    sys.modules[_PLOTLY_MODULE] = stand_in


#: the packages whose modules hold numba kernels cached on disk (``@njit(cache=True)``)
_KERNEL_PACKAGES = ("zcut", "replay")


def _writable_folder(path: str) -> bool:
    """numba's own test of a cache folder: it can be made and a file created in it."""
    import tempfile

    try:
        os.makedirs(path, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
        return True
    except OSError:
        return False


def numba_cache_folders() -> list[str]:
    """Where numba caches the kernels of :data:`_KERNEL_PACKAGES` unless told otherwise: the
    ``__pycache__`` beside each of their modules (found without importing them, which would load
    numba)."""
    import importlib.util

    folders = []
    for name in _KERNEL_PACKAGES:
        spec = importlib.util.find_spec(name)
        for loc in (spec.submodule_search_locations or []) if spec is not None else []:
            for here, dirs, files in os.walk(loc):
                dirs[:] = [d for d in dirs if d != "__pycache__" and not d.startswith(".")]
                if any(f.endswith(".py") for f in files):
                    folders.append(os.path.join(here, "__pycache__"))
    return folders


def _user_cache_dir() -> str:
    """numba's per-user cache folder (numba.misc.appdirs on Linux: $XDG_CACHE_HOME or ~/.cache)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache")
    return os.path.join(base, "numba")


def ensure_numba_cache() -> str | None:
    """Make sure numba has a folder it can write its compiled kernels to, before it is imported.

    numba tries ``NUMBA_CACHE_DIR``, then the ``__pycache__`` beside the module, then its per-user
    folder; when none can be written (a shared install and a read-only or missing home) it raises at
    import, in every command. Then this points ``NUMBA_CACHE_DIR`` at a private folder of the
    temporary directory (``zcut-numba-UID``). Returns the folder it chose, or None when numba's own
    choice works (or numba is imported already, too late to choose)."""
    if "numba" in sys.modules:
        return None
    chosen = os.environ.get("NUMBA_CACHE_DIR")
    if chosen and _writable_folder(chosen):
        return None
    if all(_writable_folder(f) for f in numba_cache_folders()) or _writable_folder(_user_cache_dir()):
        return None
    import tempfile

    fallback = os.path.join(tempfile.gettempdir(), f"zcut-numba-{os.getuid()}")
    try:
        os.makedirs(fallback, mode=0o700, exist_ok=True)
        st = os.stat(fallback)
        if st.st_uid != os.getuid() or st.st_mode & 0o022:  # another user's folder: not ours to load code from
            return None
    except OSError:
        return None
    if not _writable_folder(fallback):
        return None
    os.environ["NUMBA_CACHE_DIR"] = fallback
    return fallback


def check_environment() -> str | None:
    """A one-line complaint about a zcut environment variable that is set wrong, or None."""
    from replay.logs.files import CAP_VARIABLES, env_cap

    for name in CAP_VARIABLES:
        if env_cap(name, 1) is None:
            return f"{name} must be a positive integer (a size cap), got {os.environ[name]!r}"
    if "numba" not in sys.modules and not any(
            _writable_folder(f) for f in [os.environ.get("NUMBA_CACHE_DIR") or "", *numba_cache_folders(),
                                          _user_cache_dir()] if f):
        return ("no folder can hold numba's compiled kernels (beside the modules, ~/.cache/numba, "
                "the temporary directory): set NUMBA_CACHE_DIR to a folder you can write")
    return None
