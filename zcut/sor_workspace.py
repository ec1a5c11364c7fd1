"""Scratch arrays of :mod:`zcut.sor` kept between calls, one workspace per thread.

Why: a call on a 1920 × 1200 frame needs about a dozen full-frame temporaries (the float64 x, y, z
planes, the valid mask, d̄, the band tables, the columns: ~18 MB each, ~170 MB in all; the
statistics' terms were one more until 2026-12-05h, now summed a row at a time). Made fresh each call, glibc hands such blocks back to the kernel when they are freed
and the next call faults every page in again (≈ 2–3 µs per 4 KiB page: up to a quarter of a call,
docs/performance.md). A workspace keeps them: a call takes its arrays by name, sized for its frame.

Rules (where this module's work stops):

- One workspace per thread (:func:`thread_workspace`): two calls in two threads never share a
  buffer. A call that finds its thread's workspace busy (re-entry) works in a fresh one.
- An array a call takes is valid until the call ends; nothing a call returns to its caller is a
  workspace array or a view of one (:mod:`zcut.sor` copies d̄ and makes the masks fresh).
- An array grows to the largest size asked (by at least a quarter, so that a run of slightly
  growing crops does not reallocate every call) and never shrinks by itself; after a call, a
  workspace holding more than ``max_bytes`` drops everything. A thread's workspace is made with
  :data:`KEPT_BYTES` (0: nothing is kept between calls, the behaviour before workspaces);
  ``max_bytes = None`` keeps everything (~170 MB for a full frame) until :meth:`SorWorkspace.release`.
- The exception: the arrays named in ``keep`` (a thread's workspace: :data:`KEPT_NAMES`, the column search's)
  stay after a call whatever ``max_bytes`` says, as long as they hold at most ``keep_bytes`` together
  (:data:`KEPT_NAMES_BYTES`, 128 MiB); above that they are dropped with the rest, as before.
  :meth:`SorWorkspace.release` drops them too.
- Taken arrays are uninitialized (like ``np.empty``); :meth:`SorWorkspace.full` fills.
- The workspace also keeps the thread pool a call runs its kernels on (:meth:`SorWorkspace.pool`:
  starting one per call cost ≈ 0.4 CPU ms); ``max_bytes`` leaves it, :meth:`SorWorkspace.release`
  stops it, and it ends by itself when the workspace is dropped with its thread.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import numpy as np
from numpy.typing import DTypeLike

__all__ = ["SorWorkspace", "thread_workspace"]


class SorWorkspace:
    """Named scratch arrays reused across calls (see the module docstring).

    Parameters
    ----------
    max_bytes : int, optional
        After a call, everything is dropped when the workspace holds more than this; None (the
        default): keep everything until :meth:`release`.
    keep : frozenset of str
        Names of arrays kept after a call even when the rest is dropped, ...
    keep_bytes : int
        ... as long as they hold at most this many bytes together (else they are dropped too).
    """

    __slots__ = ("_arrays", "_busy", "_pool", "_threads", "keep", "keep_bytes", "max_bytes")

    def __init__(self, max_bytes: int | None = None, *, keep: frozenset[str] = frozenset(), keep_bytes: int = 0) -> None:
        self.max_bytes = max_bytes
        self.keep = keep
        self.keep_bytes = keep_bytes
        self._arrays: dict[str, np.ndarray] = {}
        self._busy = False
        self._pool: ThreadPoolExecutor | None = None
        self._threads = 0

    @property
    def nbytes(self) -> int:
        """Bytes held between calls."""
        return sum(a.nbytes for a in self._arrays.values())

    def _bound(self) -> None:
        # after a call: over max_bytes, drop everything but the kept names, and those too when
        # they hold more than keep_bytes together
        if self.max_bytes is None or self.nbytes <= self.max_bytes:
            return
        kept = {name: a for name, a in self._arrays.items() if name in self.keep}
        self._arrays.clear()
        if sum(a.nbytes for a in kept.values()) <= self.keep_bytes:
            self._arrays.update(kept)

    def release(self) -> None:
        """Drop every array (they are freed once no call uses them) and stop the thread pool."""
        self._arrays.clear()
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def pool(self, n_threads: int) -> ThreadPoolExecutor:
        """A pool of ``n_threads`` worker threads, the same from call to call (a new one when the
        number changes)."""
        if self._pool is None or self._threads != n_threads:
            if self._pool is not None:
                self._pool.shutdown()
            self._pool = ThreadPoolExecutor(max_workers=n_threads, thread_name_prefix="zcut-sor")
            self._threads = n_threads
        return self._pool

    def empty(self, name: str, shape: tuple[int, ...], dtype: DTypeLike = np.float64) -> np.ndarray:
        """A C-contiguous uninitialized array ``shape`` of ``dtype``, the one ``name`` names.

        The array is the previous one of that name when it is large enough, else a new one that
        replaces it; two names never share memory."""
        kind = np.dtype(dtype)
        size = math.prod(shape)
        held = self._arrays.get(name)
        if held is None or held.dtype != kind or held.size < size:
            grown = 0 if held is None or held.dtype != kind else held.size + held.size // 4
            self._arrays.pop(name, None)  # freed before its successor is made
            held = np.empty(max(size, grown), kind)
            self._arrays[name] = held
        return held[:size].reshape(shape)

    def full(self, name: str, shape: tuple[int, ...], value: object, dtype: DTypeLike = np.float64) -> np.ndarray:
        """:meth:`empty`, every element set to ``value``."""
        out = self.empty(name, shape, dtype)
        out.fill(value)
        return out

    @contextmanager
    def call(self) -> Iterator[SorWorkspace]:
        """This workspace for one call (a fresh one that keeps nothing if it is in use), bounded
        by ``max_bytes`` when the call ends."""
        if self._busy:
            fresh = SorWorkspace(max_bytes=0)
            try:
                yield fresh
            finally:
                fresh.release()
            return
        self._busy = True
        try:
            yield self
        finally:
            self._busy = False
            self._bound()


_LOCAL = threading.local()

#: what a thread's workspace keeps between calls unless told otherwise (its ``max_bytes``): nothing. Measured in
#: the replay (docs/performance.md, SOR round of 2026-12-05c, "the lead's decision"): ~190 MB kept per thread
#: moved the page faults into the z-cut's temporaries (its stage 8 -> 21-34 CPU ms a 1920 x 1200 frame, system
#: time) and a whole replay cost 0.239 against 0.225 CPU-s a frame without it; a process that runs SOR alone in a
#: loop may keep them (``thread_workspace().max_bytes = None``).
KEPT_BYTES: int | None = 0

#: ... except the column search's arrays (``zcut.sor._column_stage``: the columns' entries, their starts, the marked
#: columns), kept between calls while they hold at most :data:`KEPT_NAMES_BYTES` together (above that, freed after
#: the call like the rest). They are made only on frames with many pixels the image windows leave (tall parts on
#: end: ~85 MB on a 1920 x 1200 frame of the bench's ``steep``), and made fresh each call they were faulted in
#: afresh (docs/performance.md, SOR round of 2026-12-06a).
KEPT_NAMES = frozenset({"col_x", "col_y", "col_z", "col_mult", "col_slab", "col_start", "col_fill", "marked"})
KEPT_NAMES_BYTES = 128 << 20


def thread_workspace() -> SorWorkspace:
    """The calling thread's workspace (made on first use, dropped with the thread).

    ``thread_workspace().release()`` frees what a thread holds; ``thread_workspace().max_bytes =
    n`` bounds what it keeps between calls."""
    ws: SorWorkspace | None = getattr(_LOCAL, "workspace", None)
    if ws is None:
        ws = SorWorkspace(max_bytes=KEPT_BYTES, keep=KEPT_NAMES, keep_bytes=KEPT_NAMES_BYTES)
        _LOCAL.workspace = ws
    return ws
