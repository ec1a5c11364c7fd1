"""The frame catalogue of the labelling page: a log's frames run through the pipeline and prepared for
the page, in log order, by one background thread.

The frames come from a :class:`replay.pipeline.session.ReplaySession` (:meth:`Catalogue.of_replay`),
the one way every command opens a log for replay: its config resolved from the log's first readable
frame, its bin model prepared once and that first frame's pose seeding every frame's registration,
so the page shows the masks ``zcut replay`` writes for the same log, config file and overrides.
Each ``(frame, result)`` is turned into the page's payloads (:func:`annotate.payload.prepare_frame`),
registered in the label store with its valid mask, its points spilled to disk
(:class:`GeometrySpill`) and kept as a :class:`~annotate.payload.ServedFrame` under the frame's own
index (a frame lost to damage leaves a gap).

A request for a frame not prepared yet is never held: :meth:`Catalogue.get` raises
:class:`FrameNotReady` with an estimate of when to ask again (the server answers 503 with
``Retry-After``).
"""

from __future__ import annotations

import math
import shutil
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from annotate.payload import ServedFrame, prepare_frame
from annotate.store import FrameRecord, LabelStore, LogRecord
from zcut.params import SuspectParams

if TYPE_CHECKING:
    from annotate.fits import Fitter
    from replay.logs.damage import Damage
    from replay.logs.frame import Frame
    from replay.pipeline.session import ReplaySession
    from replay.pipeline.stages import FrameResult

#: What the catalogue prepares: ``(frame, pipeline result)`` in log order.
Results = Callable[[], Iterator[tuple["Frame", "FrameResult"]]]


class FrameNotReady(Exception):
    """The frame is still being prepared: ask again in ``retry_after_s`` seconds."""

    def __init__(self, index: int, retry_after_s: int) -> None:
        super().__init__(f"frame {index} is being prepared: retry in {retry_after_s} s")
        self.retry_after_s = retry_after_s


class GeometrySpill:
    """The frames' points on disk, one ``.npy`` per frame (x, y, z float32), read by rectangles.

    A 1920 x 1200 frame takes 27.6 MB in a temporary directory that :meth:`close` removes; the
    server keeps no dense arrays in memory.
    """

    def __init__(self) -> None:
        self.dir = Path(tempfile.mkdtemp(prefix="zcut-annotate-"))

    def _path(self, index: int) -> Path:
        return self.dir / f"frame{index}.npy"

    def put(self, index: int, xyz: np.ndarray) -> None:
        """Write the (H, W, 3) points of frame ``index``."""
        tmp = self.dir / f"frame{index}.part.npy"
        np.save(tmp, np.ascontiguousarray(xyz, dtype=np.float32))
        tmp.replace(self._path(index))

    def points(self, index: int) -> np.ndarray:
        """The (H, W, 3) float32 points of frame ``index``, memory-mapped (read-only)."""
        arr: np.ndarray = np.load(self._path(index), mmap_mode="r")
        return arr

    def rect(self, index: int, x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
        """(y1 - y0, x1 - x0, 3) float32 points of frame ``index`` (bounds already clipped)."""
        arr = np.load(self._path(index), mmap_mode="r")
        return np.array(arr[y0:y1, x0:x1])

    def close(self) -> None:
        shutil.rmtree(self.dir, ignore_errors=True)


@dataclass
class Catalogue:
    """Frames of the log prepared for the page, in log order, by one background thread (:meth:`start`).

    Attributes
    ----------
    results : callable
        Returns an iterator of ``(frame, result)`` in log order (:meth:`of_replay`: the replay
        session's :meth:`~replay.pipeline.session.ReplaySession.results`); called once, in the thread.
    store, log : LabelStore, LogRecord
        Every prepared frame is registered there (with its valid mask).
    geometry : GeometrySpill
        Where the frames' points go.
    total_hint : int or None
        Frames in the log, when its summary says (a frame index beyond it is not coming).
    frames, records : dict of int
        The prepared frames and their store records, by frame index.
    done, error : bool, str or None
        Preparation ended (and why, when it failed: the frames prepared so far stay usable).
    suspect_params : SuspectParams
        The review groups' suspect detectors (:mod:`annotate.groups`), with the config's a_max.
    part : str or None
        The part kind the config names.
    focus : callable or None
        Given a frame, the only pixels to list as its review groups (``zcut annotate --disagreement``:
        :meth:`annotate.disagreement.Disagreement.focus`); None: the usual groups.
    fitter : Fitter or None
        With a part model, every prepared frame goes to it to be fitted in the background
        (:mod:`annotate.fits`).
    """

    results: Results
    store: LabelStore
    log: LogRecord
    geometry: GeometrySpill
    total_hint: int | None = None
    frames: dict[int, ServedFrame] = field(default_factory=dict)
    records: dict[int, FrameRecord] = field(default_factory=dict)
    done: bool = False
    error: str | None = None
    seconds_per_frame: float = 1.0
    suspect_params: SuspectParams = field(default_factory=SuspectParams)
    part: str | None = None
    focus: Callable[[Frame], np.ndarray] | None = None
    fitter: Fitter | None = None
    _cond: threading.Condition = field(default_factory=threading.Condition)
    _thread: threading.Thread | None = None
    _stop: threading.Event = field(default_factory=threading.Event)
    _results: object | None = None  # the pass over the log: its ``damage`` names what a damaged log lost

    @classmethod
    def of_replay(cls, replay: ReplaySession, store: LabelStore, log: LogRecord, *,
                  focus: Callable[[Frame], np.ndarray] | None = None) -> Catalogue:
        """The catalogue of a log opened for replay (not started; its points spill to a new temporary
        directory); ``focus``: see the class."""
        config = replay.config
        return cls(results=replay.results, store=store, log=log, geometry=GeometrySpill(),
                   total_hint=replay.reader.n_frames, suspect_params=SuspectParams(a_max=config.zcut.a_max),
                   part=config.part, focus=focus)

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="zcut-annotate-prepare", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=30)

    def _run(self) -> None:
        results = None
        try:
            t = time.monotonic()
            results = self._results = self.results()
            for frame, result in results:
                if self._stop.is_set():
                    return
                sf, rec = self._prepare(frame, result)
                now = time.monotonic()
                with self._cond:
                    self.frames[sf.index] = sf
                    self.records[sf.index] = rec
                    self.seconds_per_frame = 0.5 * self.seconds_per_frame + 0.5 * (now - t)
                    self._cond.notify_all()
                t = now
        except Exception as e:  # noqa: BLE001 - shown on the page; the frames prepared so far stay usable
            with self._cond:
                self.error = f"{type(e).__name__}: {e}"
        finally:
            if results is not None:
                close = getattr(results, "close", None)
                if close is not None:
                    close()  # joins the session's reader threads
            with self._cond:
                self.done = True
                self._cond.notify_all()

    def _prepare(self, frame: Frame, result: FrameResult) -> tuple[ServedFrame, FrameRecord]:
        """The page's payloads of one frame, its points spilled, the frame registered in the store."""
        pf = prepare_frame(frame, result, suspect_params=self.suspect_params, part=self.part,
                           focus=None if self.focus is None else self.focus(frame), fits=self.fitter is not None)
        sf = pf.served
        self.geometry.put(sf.index, pf.geometry)
        rec = self.store.add_frame(
            self.log, topic=sf.topic, stamp_ns=sf.stamp_ns, index=sf.index,
            shape=(sf.height, sf.width), frame_id=sf.frame_id, valid=pf.valid,
        )
        if self.fitter is not None:
            self.fitter.submit(frame, result)
        return sf, rec

    def wait_until_done(self, timeout: float) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: self.done, timeout=timeout)

    def get(self, index: int) -> tuple[ServedFrame, FrameRecord] | None:
        """The prepared frame ``index``; None if the log has none.

        Raises
        ------
        FrameNotReady
            The frame may still come (preparation goes on): never waits for it.
        """
        with self._cond:
            if index in self.frames:
                return self.frames[index], self.records[index]
            if self.done or (self.total_hint is not None and index >= self.total_hint):
                return None
            if self.frames and index < max(self.frames):  # frames come in order: this one was lost
                return None
            ahead = max(1, index - max(self.frames, default=-1))
            wait = ahead * self.seconds_per_frame
        raise FrameNotReady(index, int(min(30, max(1, math.ceil(wait)))))

    def snapshot(self) -> list[tuple[ServedFrame, FrameRecord]]:
        """The prepared frames so far, in index order."""
        with self._cond:
            return [(self.frames[i], self.records[i]) for i in sorted(self.frames)]

    @property
    def damage(self) -> tuple[Damage, ...]:
        """The damage records (:class:`replay.logs.damage.Damage`) of the pass over the log so far."""
        return tuple(getattr(self._results, "damage", ()))

    @property
    def prepared(self) -> int:
        """Frames prepared so far."""
        with self._cond:
            return len(self.frames)

    @property
    def total(self) -> int | None:
        with self._cond:
            return len(self.frames) if self.done else self.total_hint
