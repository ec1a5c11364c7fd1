"""The replay session: open a log and resolve its config once, then run the pipeline into sinks.

In the manner of KISS-ICP's pipeline, a replay is a few named steps::

    session = ReplaySession.open(log, config_file=..., overrides=..., bin_model=...)  # read + resolve
    summary = session.run(sink, frames=(0, None), on_frame=...)                      # pipeline -> sink

:meth:`ReplaySession.open` resolves the config from the log's metadata and its first readable frame
(:func:`open_log`), whatever frame range is run later, so every command that opens a session runs the
same filter on a log; it prepares the bin model once for that config. That first frame is read and
located once: the run delivers the same object (and takes over the chunks read at open), and its bin
location is the seed's (every other frame's registration starts from that pose).
:meth:`ReplaySession.results` yields ``(frame, result)`` for a frame range, in log order, reading the
next frame in a background thread (:func:`prefetched`), locating the bin of the next frames in another
and computing two frames at once (:func:`frames_in_flight`: by default where numba's threading layer lets
two frames' bin stages overlap; under its workqueue layer they run one at a time, :data:`PARALLEL_KERNELS`);
:meth:`ReplaySession.run` feeds them to a sink (:mod:`replay.pipeline.sinks`) and returns a
:class:`ReplaySummary`. Library code: it never prints; commands pass an ``on_frame`` callback.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Generator, Iterator, Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from replay.errors import ConfigError, LogDamageError
from replay.logs.damage import Damage
from replay.logs.frame import Frame
from replay.logs.poses import true_poses
from replay.logs.stream import DerivedStream, FrameStream
from replay.pipeline import config as cfg
from replay.pipeline.explained import with_log_part_model
from replay.pipeline.sinks import FrameSink, NullSink, ReplayStart
from replay.pipeline.stages import FrameResult, bin_zone, judge_zone, locate_bin, run_frame
from replay.pipeline.zone import BinLocation, Zone
from replay.process import raise_if_interrupted
from zcut.bin_model import BinModel
from zcut.prepared_model import PreparedBinModel
from zcut.registration import RegistrationResult

if TYPE_CHECKING:
    from replay.logs.reader import LogReader
    from replay.pipeline.verdicts import FrameJudge


@dataclass(frozen=True, slots=True)
class FrameRow:
    """One line of the per-frame table (and of the JSON summary).

    ``bin_check`` is the bin check's figure (:class:`zcut.bin_check.BinCheck`: certain bin pixels
    the removal left where the filters judge, NaN when the bin stages failed or did not run) and
    ``bin_flagged`` whether it flagged the frame (also when the bin stages failed): its counts
    then rest on a removal that did not work.
    """

    index: int
    stamp_ns: int
    valid_px: int
    zcut: int
    sor: int
    both: int
    above_rim: int
    clusters: int
    alpha: float
    beta_sor: float
    beta_zcut: float
    fitness: float
    rmse_mm: float
    time_s: float
    warnings: tuple[str, ...]
    pose_error_mm: float = math.nan
    pose_error_deg: float = math.nan
    icp_fitness: float = math.nan
    others: dict[str, int] = field(default_factory=dict)  # outliers of every other base method, by name
    bin_check: float = math.nan
    bin_flagged: bool = False

    @classmethod
    def of(cls, result: FrameResult, *, true_pose: np.ndarray | None = None) -> FrameRow:
        """The row of a result; ``true_pose``: the frame's true ``T_cam_bin`` (a synthetic log's), for
        the registration's pose error."""
        reg = result.registration
        m = result.metrics
        err_mm = err_deg = math.nan
        if true_pose is not None and reg is not None:
            err_mm, err_deg = pose_error(reg.T_cam_bin, true_pose)
        zcut, sor = result.outliers["zcut"], result.outliers.get("sor")
        # np.count_nonzero: the same counts as .sum() of a bool image, without its int64 pass (4-5 ms a
        # 1920 x 1200 frame); no all-False images for a SOR or a removal that did not run
        return cls(
            index=result.index, stamp_ns=result.stamp_ns, valid_px=int(np.count_nonzero(result.valid)),
            zcut=int(np.count_nonzero(zcut)), sor=int(np.count_nonzero(sor)) if sor is not None else 0,
            both=int(np.count_nonzero(zcut & sor)) if sor is not None else 0,
            above_rim=int(np.count_nonzero(result.removal.easy_outliers)) if result.removal is not None else 0,
            clusters=result.cut.n_clusters, alpha=float(m.alpha), beta_sor=float(m.beta1),
            beta_zcut=float(m.beta2),
            fitness=float(reg.fitness) if reg is not None else math.nan,
            rmse_mm=float(reg.inlier_rmse) * 1000.0 if reg is not None else math.nan,
            time_s=float(result.timings["total"]), warnings=result.warnings, pose_error_mm=err_mm,
            pose_error_deg=err_deg, icp_fitness=float(reg.icp_fitness) if reg is not None else math.nan,
            others={m: int(np.count_nonzero(o)) for m, o in result.outliers.items() if m not in ("zcut", "sor")},
            bin_check=float(result.bin_check.value) if result.bin_check is not None else math.nan,
            bin_flagged=result.bin_flagged,
        )

    def as_dict(self) -> dict[str, Any]:
        """The row as replay --json writes it: the other methods' counts under their own names."""
        d = {k: getattr(self, k) for k in self.__slots__ if k != "others"}
        d["warnings"] = list(self.warnings)
        d.update(self.others)
        return {k: _json_number(v) for k, v in d.items()}


def pose_error(T: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """(translation error in mm, rotation error in degrees) of a pose against the true one."""
    dt = 1000.0 * float(np.linalg.norm(T[:3, 3] - T_true[:3, 3]))
    c = (np.trace(T[:3, :3].T @ T_true[:3, :3]) - 1.0) / 2.0
    return dt, float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def true_poses_of(metadata: Mapping[str, Mapping[str, str]]) -> dict[int, np.ndarray]:
    """A synthetic log's true bin poses by stamp (empty for other logs): :func:`replay.logs.poses.true_poses`."""
    return true_poses(metadata)


def _json_number(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


@dataclass(slots=True)
class ReplaySummary:
    """What a replay did (mutable while it runs; final when :meth:`ReplaySession.run` returns)."""

    log: str
    resolved: cfg.Resolved | None = None
    rows: list[FrameRow] = field(default_factory=list)
    damage: list[Damage] = field(default_factory=list)  # what the pass over the log lost
    outputs: dict[str, str] = field(default_factory=dict)
    part_kind: str | None = None
    viewer_error: str | None = None  # --spawn/--connect: the viewer did not take the data
    n_log_frames: int | None = None  # clouds in the log, when its summary says

    def as_dict(self) -> dict[str, Any]:
        total = {k: sum(getattr(r, k) for r in self.rows)
                 for k in ("valid_px", "zcut", "sor", "both", "above_rim", "clusters")}
        for r in self.rows:
            for m, n in r.others.items():
                total[m] = total.get(m, 0) + n
        t = sum(r.time_s for r in self.rows)
        return {
            "log": self.log,
            "part_kind": self.part_kind,
            "notes": list(self.resolved.notes) if self.resolved else [],
            "config": cfg.to_dict(self.resolved.config) if self.resolved else None,
            "frames": [r.as_dict() for r in self.rows],
            "totals": {**total, "frames": len(self.rows), "bin_flagged": sum(r.bin_flagged for r in self.rows),
                       "time_s": t,
                       "frames_per_s": _json_number(len(self.rows) / t if t > 0 else math.nan)},
            "damage": [d.text for d in self.damage],
            "outputs": dict(self.outputs),
        }


def parse_frames(text: str | None) -> tuple[int, int | None]:
    """``"A:B"``, ``"A:"``, ``":B"`` or ``"N"`` (one frame) -> (start, stop)."""
    if text is None or text == "":
        return 0, None
    try:
        if ":" in text:
            a, b = text.split(":", 1)
            start = int(a) if a.strip() else 0
            stop = int(b) if b.strip() else None
        else:
            start = int(text)
            stop = start + 1
    except ValueError:
        raise ConfigError(f"--frames must look like A:B, A:, :B or N, got {text!r}") from None
    if start < 0 or (stop is not None and stop <= start):
        raise ConfigError(f"--frames must satisfy 0 <= A < B, got {text!r}")
    return start, stop


#: Held while a frame's bin stages run (:meth:`ReplaySession.results` with two frames in flight) when numba's
#: threading layer is its "workqueue" (:func:`parallel_kernels`): the removal and the bin check run numba's
#: ``parallel=True`` kernels, and that layer aborts the process when two threads launch such kernels at once.
#: OpenMP's layer (the one ``zcut`` chooses, ``replay.process.THREADING_LAYER_PRIORITY``) and TBB's take them
#: from any thread: then nothing is held and two frames' bin stages overlap. The other stages run serial kernels
#: (and SOR its own threads), free to overlap under any layer.
PARALLEL_KERNELS = threading.Lock()

#: numba's threading layers whose parallel kernels two threads may launch at once
THREADSAFE_LAYERS = frozenset({"omp", "tbb"})


def _threadsafe_layer() -> bool | None:
    """Whether numba's threading layer takes parallel kernels from two threads at once: True or False once a
    parallel kernel has run in this process (the layer is chosen then), else None."""
    import numba

    try:
        return numba.threading_layer() in THREADSAFE_LAYERS  # type: ignore[attr-defined]  # numba exports it untyped
    except ValueError:  # no parallel kernel has run yet
        return None


def parallel_kernels() -> AbstractContextManager[object]:
    """What a frame worker holds while its bin stages run: :data:`PARALLEL_KERNELS` unless numba's layer is known
    to take parallel kernels from two threads at once (:data:`THREADSAFE_LAYERS`; until the first parallel kernel
    has run the layer is not known, and the lock is held)."""
    return nullcontext() if _threadsafe_layer() else PARALLEL_KERNELS


#: The variable that sets :func:`frames_in_flight` (a whole number >= 1).
FRAMES_IN_FLIGHT_VARIABLE = "ZCUT_FRAMES_IN_FLIGHT"


def frames_in_flight() -> int:
    """Frames :meth:`ReplaySession.results` computes at once by default: ``$ZCUT_FRAMES_IN_FLIGHT``, else
    :func:`default_frames_in_flight`.

    Raises
    ------
    ConfigError
        The variable is not a whole number >= 1.
    """
    import os

    text = os.environ.get(FRAMES_IN_FLIGHT_VARIABLE, "").strip()
    if not text:
        return default_frames_in_flight()
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise ConfigError(f"{FRAMES_IN_FLIGHT_VARIABLE} must be a whole number >= 1, got {text!r}")
    return n


def default_frames_in_flight() -> int:
    """2 where numba runs at least two threads (``NUMBA_NUM_THREADS``: the cores, or a study worker's share of
    them) under a threading layer that takes parallel kernels from two threads at once (OpenMP's, the one the
    command line chooses, or TBB's), else 1.

    Under such a layer two frames' bin stages overlap; one frame alone keeps ~1.4 of two quiet cores busy
    (docs/performance.md, "Both cores busy"). Under numba's workqueue layer the bin stages of two frames run one
    at a time (:data:`PARALLEL_KERNELS`) and two frames in flight cost 10-30 % more CPU a frame for no wall gain
    that was measured (docs/performance.md, "Two frames in flight"): 1. Before the first parallel kernel the layer
    is not chosen yet: it is predicted from numba's settings (``NUMBA_THREADING_LAYER``, else the first of
    ``NUMBA_THREADING_LAYER_PRIORITY``).
    """
    import numba

    if int(numba.config.NUMBA_NUM_THREADS) < 2:  # type: ignore[attr-defined]  # numba.config sets it at import
        return 1
    safe = _threadsafe_layer()
    if safe is None:
        chosen = str(numba.config.THREADING_LAYER)  # type: ignore[attr-defined]  # numba.config sets it at import
        if chosen == "default":
            chosen = str(numba.config.THREADING_LAYER_PRIORITY[0])  # type: ignore[attr-defined]  # (also set at import)
        safe = chosen in THREADSAFE_LAYERS or chosen == "threadsafe"
    return 2 if safe else 1


def prefetched(frames: Iterator[Frame], *, depth: int = 1) -> Generator[Frame, None, None]:
    """Iterate ``frames`` in a background thread, up to ``depth`` frames ahead of the consumer.

    Decoding the next frame (zstd and the cloud unpacking release the GIL) then overlaps the
    pipeline on the current one. At most ``depth`` frames are read and not yet taken: the thread
    reads the next one once the consumer has taken one (a queue of ``depth`` frames alone would let
    it hold one more, read and waiting for room: a 1920 x 1200 frame's arrays and chunks, ~100 MB
    more memory to fault in, for no gain when the consumer takes a frame every ~100 ms and one is
    read in ~10). Exceptions of the iterator are raised to the consumer where they happened in the
    sequence; closing this generator (or an exception in the consumer, once the caller closes it)
    stops and joins the thread and closes ``frames``.
    """
    q: queue.SimpleQueue[tuple[str, Any]] = queue.SimpleQueue()  # (kind, frame or exception or None)
    room = threading.Semaphore(depth)  # frames the thread may read before the consumer takes one
    stop = threading.Event()

    def wait_for_room() -> bool:
        while not stop.is_set():
            if room.acquire(timeout=0.05):
                return not stop.is_set()
        return False

    def produce() -> None:
        try:
            while wait_for_room():
                try:
                    f = next(frames)
                except StopIteration:
                    q.put(("end", None))
                    return
                q.put(("frame", f))
        except BaseException as e:  # noqa: BLE001 - handed to the consumer, raised there
            q.put(("error", e))
        finally:
            close = getattr(frames, "close", None)
            if close is not None:
                close()

    worker = threading.Thread(target=produce, name="zcut-frame-reader", daemon=True)
    worker.start()
    try:
        while True:
            kind, item = q.get()
            if kind == "frame":
                room.release()  # taken: the thread may read the next one
                yield item
            elif kind == "error":
                raise item
            else:
                return
    finally:
        stop.set()
        room.release()  # wake a thread waiting for room
        while worker.is_alive():
            worker.join(timeout=0.05)
        while not q.empty():  # frames read and never taken
            q.get_nowait()




def open_log(path: Path, *, file_layer: dict[str, Any] | None = None, overrides: dict[str, Any] | None = None,
             topic: str | None = None, reader_options: dict[str, Any] | None = None,
             resolved: cfg.Resolved | None = None) -> tuple[LogReader, Frame, cfg.Resolved]:
    """Open a log, read its first readable frame and resolve its config (docs/accuracy.md: the one place a
    log's parameters come from; :meth:`ReplaySession.open` and the study planner both call it).

    ``resolved``: the config already resolved for this log (a study's worker gets the driver's):
    it is used as it is, nothing is resolved again.

    Returns
    -------
    (LogReader, Frame, Resolved)
        The reader, the first readable frame, the resolved config with its notes.

    Raises
    ------
    LogFormatError, LogDamageError (no readable frame), ConfigError
    """
    from replay.logs.reader import LogReader

    reader = LogReader(path, cloud_topic=topic, **(reader_options or {}))
    it = reader.frames(start=0, peek=True)  # the run takes over the chunks read at open: parsed once
    try:
        first = next(it, None)
    finally:
        it.close()
    if first is None:
        raise LogDamageError(f"{path.name}: no readable frame on {reader.cloud_topic}"
                             + (f" ({it.damage[0].text})" if it.damage else ""))
    if resolved is None:
        facts = cfg.log_facts(reader.metadata, first, intrinsics=getattr(reader, "intrinsics", None))
        resolved = cfg.resolve(facts, file_layer=file_layer, cli=overrides)
        resolved = with_log_part_model(resolved, path, reader)
    return reader, first, resolved


class ReplaySession:
    """A log opened for replay, with its config resolved once and its bin model prepared once.

    Use :meth:`open`. Attributes: ``path``, ``reader`` (a :class:`replay.logs.reader.LogReader`),
    ``resolved`` (config and notes), ``bin_model`` (the :class:`BinModel` or None) and ``prepared``
    (its :class:`PreparedBinModel` for this config, or None).

    Each frame is read and located once: the first readable frame, read to resolve the config and
    located for the :attr:`seed`, is kept until the first pass over it, which delivers that frame
    object instead of decoding it again; its bin location is the seed's own (the full coarse-to-fine
    registration, which every other frame starts from), taken by every pass over that frame with the
    session's bin stages' parameters.
    """

    def __init__(self, path: Path, reader: LogReader, resolved: cfg.Resolved, bin_model: BinModel | None,
                 first_frame: Frame | None = None) -> None:
        self.path = path
        self.reader = reader
        self.resolved = resolved
        self.bin_model = bin_model
        self.bin_model_choice = None  # how the model was chosen (ReplaySession.open's choose_bin_model)
        c = resolved.config
        self.prepared: PreparedBinModel | None = None
        self.seed: RegistrationResult | None = None
        #: the first readable frame, kept for the first pass over it (see :meth:`located`), then
        #: dropped; its bin location, the seed's, kept for every pass
        self._first: Frame | None = first_frame
        self._first_location: BinLocation | None = None
        self._first_index = -1
        if bin_model is not None:
            from replay.pipeline.bin_model import prepared_bin_model  # cached by the model's content

            self.prepared = prepared_bin_model(bin_model, registration=c.registration, removal=c.removal)
            if first_frame is not None and c.registration.seed_from_first_frame:
                # the log's first frame's pose seeds every frame (a static bin): each frame's result
                # then depends on that frame alone, whatever order or split the frames run in
                # that frame's own location: located once, not again from its own pose
                self._first_location = locate_bin(first_frame, c, bin_model=self.prepared)
                self.seed = self._first_location.registration
                self._first_index = first_frame.index

    @classmethod
    def open(cls, path: str | Path, *, config_file: str | Path | None = None,
             overrides: dict[str, Any] | None = None, topic: str | None = None,
             bin_model: BinModel | None = None, reader_options: dict[str, Any] | None = None,
             resolved: cfg.Resolved | None = None,
             choose_bin_model: Callable[[Any], Any] | None = None) -> ReplaySession:
        """Open a log and resolve its config from its metadata and first readable frame.

        Parameters
        ----------
        path : path
            ROS 2 MCAP log.
        config_file : path, optional
            TOML config (``--config``).
        overrides : dict, optional
            The command line's layer (:func:`replay.pipeline.config.cli_layer`).
        topic : str, optional
            Cloud topic (when the log has several).
        bin_model : BinModel, optional
            Without it the bin stages are skipped (each result carries the warning).
        reader_options : dict, optional
            Keyword arguments of :class:`~replay.logs.reader.LogReader` (e.g. resource caps).
        resolved : Resolved, optional
            The config already resolved for this log (a study's worker gets the driver's); then
            ``config_file`` and ``overrides`` are not read.
        choose_bin_model : callable, optional
            Called with the opened reader when ``bin_model`` is None; returns a
            :class:`~replay.pipeline.bin_model.BinModelChoice` (e.g. ``partial(bin_model_for,
            explicit_path=...)``), kept as :attr:`bin_model_choice`.

        Raises
        ------
        LogFormatError, LogDamageError, ConfigError
        """
        path = Path(path)
        file_layer = cfg.load_toml(config_file) if config_file is not None and resolved is None else None
        reader, first, resolved = open_log(path, file_layer=file_layer, overrides=overrides, topic=topic,
                                           reader_options=reader_options, resolved=resolved)
        choice = None
        if bin_model is None and choose_bin_model is not None:
            choice = choose_bin_model(reader)
            bin_model = choice.model
        session = cls(path, reader, resolved, bin_model, first)
        session.bin_model_choice = choice
        return session

    @property
    def config(self) -> cfg.PipelineConfig:
        return self.resolved.config

    @property
    def notes(self) -> tuple[str, ...]:
        return self.resolved.notes

    def start_info(self, judge: FrameJudge | None = None) -> ReplayStart:
        return ReplayStart(self.path.name, self.resolved, self.reader.metadata, self.bin_model, judge)

    def located(self, *, frames: tuple[int, int | None] = (0, None), config: cfg.PipelineConfig | None = None,
                hold: bool = True) -> DerivedStream[tuple[Frame, Future[BinLocation]]]:
        """``(frame, future of its BinLocation)`` for every readable frame in ``frames``.

        The next frame is read in a background thread while this one runs; the bin mask and
        registration (OpenCV, Open3D: no numba) of each frame start in another thread as soon as the
        frame is read, so they overlap the numba stages the caller runs on the frame before. Every
        frame's registration starts from the log's first frame's pose (:attr:`seed`), so a frame's
        result does not depend on which frames ran before it. BLAS is limited to one thread meanwhile
        (its spinning workers otherwise steal the cores from those threads). Closing the generator
        stops and joins both threads. Its ``damage`` is the frame stream's (final once it has ended).
        ``hold``: a frame is given once the next one has been read and its location started (a caller
        that works on one frame at a time); False: as soon as its own location has started (a caller
        with frames in flight, whose workers wait on the futures).
        """
        config = self._check(config)
        start, stop = frames
        first, location = self._first, self._first_location
        if first is not None and start <= first.index and (stop is None or first.index < stop):
            self._first = None  # this pass delivers it
        else:
            first = None
        if location is not None and (config.bin_mask, config.registration) != (self.config.bin_mask,
                                                                              self.config.registration):
            location = None
        stream = self.reader.frames(start=start, stop=stop, decoded=first)
        return DerivedStream(self._located(stream, config, location, hold=hold), stream)

    def _located(self, stream: FrameStream, config: cfg.PipelineConfig, first_location: BinLocation | None = None,
                 *, hold: bool = True) -> Iterator[tuple[Frame, Future[BinLocation]]]:
        from threadpoolctl import threadpool_limits

        bin_model, seed = self.prepared, self.seed
        frame_iter = prefetched(stream)
        locator = ThreadPoolExecutor(max_workers=1, thread_name_prefix="zcut-locate")
        blas = threadpool_limits(limits=1, user_api="blas")
        pending: tuple[Frame, Future[BinLocation]] | None = None
        early = False
        try:
            while True:
                try:
                    frame = next(frame_iter)
                except StopIteration:
                    break
                except BaseException:
                    if pending is not None:  # the frames before the reader's error still count
                        yield pending
                        pending = None
                    raise
                if first_location is not None and frame.index == self._first_index:
                    done: Future[BinLocation] = Future()
                    done.set_result(first_location)  # the seed's: located when the session opened
                    ahead = (frame, done)
                else:
                    ahead = (frame, locator.submit(locate_bin, frame, config, bin_model=bin_model, seed=seed))
                if pending is not None:
                    yield pending
                pending = ahead
                if not hold:
                    yield pending
                    pending = None
            if pending is not None:
                yield pending
                pending = None
        except GeneratorExit:  # closed early: the locations not started are not needed
            early = True
            raise
        finally:
            # else every frame given has its location computed (frames in flight wait on them)
            locator.shutdown(wait=True, cancel_futures=early)
            blas.restore_original_limits()
            frame_iter.close()  # joins the reader thread: the stream's damage is final

    def _check(self, config: cfg.PipelineConfig | None) -> cfg.PipelineConfig:
        config = self.config if config is None else config
        if self.prepared is not None and (config.registration != self.config.registration
                                          or config.removal != self.config.removal):
            raise ConfigError("another config must keep the registration and removal parameters "
                              "the bin model was prepared with")
        return config

    def results(self, *, frames: tuple[int, int | None] = (0, None),
                config: cfg.PipelineConfig | None = None,
                in_flight: int | None = None) -> DerivedStream[tuple[Frame, FrameResult]]:
        """``(frame, result)`` of every readable frame in ``frames`` (start, stop exclusive or None),
        in log order, computed as :meth:`located` describes; its ``damage`` names the frames lost.
        ``config``: run another config than the resolved one (it must keep the resolved registration
        and removal parameters, which the bin model was prepared with).

        ``in_flight``: frames computed at once (default :func:`frames_in_flight`: ``$ZCUT_FRAMES_IN_FLIGHT``,
        else 2 under numba's OpenMP layer on two or more cores, else 1). With 2, frame k + 1 runs in a second
        worker while frame k finishes (each frame's result depends on that frame alone: see :attr:`seed`), so
        one frame's stages overlap the other's (under numba's workqueue layer all but the bin stages,
        :func:`parallel_kernels`) and both cores stay busy; the results are
        the same bit for bit and come in the same order. A frame whose computation raises raises here
        after the frames before it; an error of the reader, after the frames read before it.
        """
        config = self._check(config)
        n = frames_in_flight() if in_flight is None else in_flight
        if n < 1:
            raise ConfigError(f"in_flight must be >= 1, got {n}")
        located = self.located(frames=frames, config=config, hold=n <= 1)
        return DerivedStream(self._results(located, config, n), located)

    def _results(self, located: DerivedStream[tuple[Frame, Future[BinLocation]]], config: cfg.PipelineConfig,
                 in_flight: int = 1) -> Iterator[tuple[Frame, FrameResult]]:
        if in_flight <= 1:
            try:
                for frame, future in located:
                    yield frame, run_frame(frame, config, bin_model=self.prepared, located=future.result())
            finally:
                located.close()
            return
        pool = ThreadPoolExecutor(max_workers=in_flight, thread_name_prefix="zcut-frame")
        running: deque[tuple[Frame, Future[FrameResult]]] = deque()
        try:
            while True:
                try:
                    frame, future = next(located)
                except StopIteration:
                    break
                except BaseException:
                    while running:  # the frames before the reader's error still count, in order
                        done_frame, work = running.popleft()
                        yield done_frame, work.result()
                    raise
                running.append((frame, pool.submit(self._frame_result, frame, config, future)))
                if len(running) > in_flight:  # one more frame queued: its location runs meanwhile
                    done_frame, work = running.popleft()
                    yield done_frame, work.result()
            while running:
                done_frame, work = running.popleft()
                yield done_frame, work.result()
        finally:
            for _, work in running:
                work.cancel()
            pool.shutdown(wait=True, cancel_futures=True)
            located.close()

    def _frame_result(self, frame: Frame, config: cfg.PipelineConfig, future: Future[BinLocation]) -> FrameResult:
        """:func:`run_frame` of one frame as a worker of :meth:`results` runs it: its bin stages (the
        removal and the bin check run numba's ``parallel=True`` kernels) under :func:`parallel_kernels`,
        its methods (serial kernels, SOR's own threads) beside the other frame's."""
        location = future.result()
        with parallel_kernels():
            t_start = time.perf_counter()  # the frame's own work: not the wait for the other frame's kernels
            z = bin_zone(frame, config, bin_model=self.prepared, located=location)
        return judge_zone(frame, z, config, t_start=t_start)

    def zones(self, *, frames: tuple[int, int | None] = (0, None)) -> DerivedStream[tuple[Frame, Zone]]:
        """``(frame, zone)``: the bin stages only, for callers that filter a zone many ways (a sweep);
        its ``damage`` names the frames lost."""
        located = self.located(frames=frames)
        return DerivedStream(self._zones(located), located)

    def _zones(self, located: DerivedStream[tuple[Frame, Future[BinLocation]]]) -> Iterator[tuple[Frame, Zone]]:
        try:
            for frame, future in located:
                yield frame, bin_zone(frame, self.config, bin_model=self.prepared, located=future.result())
        finally:
            located.close()

    def true_poses(self) -> dict[int, np.ndarray]:
        """The log's true bin poses by stamp (a synthetic log's, :func:`true_poses_of`) when the bin
        model is in the truth's frame — the log's own attachment, or a model with the same points —
        else none: another model's frame differs from the truth's by the model's own displacement (a
        model turned by 0.5° showed a 4.6 mm "pose error" under a perfect removal), so a frame's
        ``pose_error_mm`` is then null and the registration's RMSE (model to scan) stands for it."""
        poses = true_poses_of(self.reader.metadata)
        if not poses or self.bin_model is None:
            return {}
        if self.bin_model_choice is not None and getattr(self.bin_model_choice, "source", None) == "log":
            return poses
        own = self.reader.attached_bin_model
        if own is None:
            return {}
        a, b = np.asarray(self.bin_model.points, np.float64), np.asarray(own.points, np.float64)
        return poses if a.shape == b.shape and np.allclose(a, b, rtol=0.0, atol=1e-6) else {}

    def run(self, sink: FrameSink | None = None, *, frames: tuple[int, int | None] = (0, None),
            on_frame: Callable[[Frame, FrameResult, FrameRow], None] | None = None,
            judge: FrameJudge | None = None, in_flight: int | None = None) -> ReplaySummary:
        """Run the pipeline over ``frames`` into ``sink``; returns the summary. ``judge``: what the
        frames are scored against, handed to the sinks (the recording shows where each filter is wrong).
        ``in_flight``: frames computed at once (:meth:`results`); the sink and ``on_frame`` see them
        one at a time, in log order, in this thread.

        ``summary.damage`` is non-empty when frames were lost (the command exits 3).
        """
        sink = NullSink() if sink is None else sink
        summary = ReplaySummary(log=str(self.path), resolved=self.resolved, part_kind=self.config.part)
        reader = self.reader
        summary.n_log_frames = reader.n_frames
        completed = False
        poses = self.true_poses()
        sink.start(self.start_info(judge))
        results = None
        try:
            results = self.results(frames=frames, in_flight=in_flight)
            try:
                for frame, result in results:
                    raise_if_interrupted()  # a signal a library swallowed: stop here, not at the end
                    sink.write(frame, result)
                    row = FrameRow.of(result, true_pose=poses.get(frame.stamp_ns))
                    summary.rows.append(row)
                    if on_frame is not None:
                        on_frame(frame, result, row)
                    # not held while the next frame is computed: its arrays (~100 MB at 1920 x 1200) are
                    # reused by the next one's, not added to them (unless a sink or on_frame keeps them)
                    del frame, result
            finally:
                results.close()
            completed = True
        finally:
            summary.damage = list(results.damage) if results is not None else []
            sink.close(completed=completed)
            summary.outputs = sink.outputs()
            summary.viewer_error = getattr(sink, "viewer_error", None)
        return summary

