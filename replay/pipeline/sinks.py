"""Where a replay's results go: sinks behind one small protocol.

A sink is told once that the replay starts (:meth:`FrameSink.start`, with the resolved config and
its notes), then gets every frame with its result (:meth:`FrameSink.write`) in frame order, then
:meth:`FrameSink.close` (``completed=False`` when the replay failed: a file sink then leaves no
output behind). :class:`NullSink` does nothing; :class:`RerunSink` logs every stage to Rerun (a
file, a spawned viewer or a running one); :class:`ResultsSink` writes the docs/formats.md results MCAP.
:class:`BackgroundSinks` runs a list of sinks in one worker thread (``zcut-sinks``), at most one
frame behind the pipeline, so that writing frame k overlaps computing frame k + 1; closing a
recording runs in a thread of its own (``zcut-rrd-close``) so that it never waits without bound.
A replay's other threads: the session's frame reader and bin locator (``zcut-frame-reader``,
``zcut-locate``, :mod:`replay.pipeline.session`), the MCAP scanner's chunk readers
(``mcap-chunks``, :mod:`replay.logs.mcap_scan`) and SOR's kernels (``zcut-sor``, :mod:`zcut.sor`):
six kinds in four files (docs/architecture.md, "Threads").

File sinks write through :class:`replay.outputs.AtomicOutput` (a unique temporary name, renamed
into place when complete) and write the resolved config beside their output
(``OUT.config.toml``); the paths must have been checked with an :class:`replay.outputs.OutputPlan`.
Whatever ends a replay early — an error, a full disk, an interruption (SIGINT, SIGTERM) — the close
paths remove the temporaries; an error while writing names the output, not the log. A recording
(.rrd) takes its final name only once Rerun's own reader reads it back complete (its writer only
logs a write error and goes on), and closing it never waits without bound.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from replay.logs import layout
from replay.logs.frame import Frame
from replay.outputs import AtomicOutput, OutputError, config_path_for, folder_gone, naming
from replay.pipeline.config import PipelineConfig, Resolved, to_toml
from replay.pipeline.stages import FrameResult
from replay.process import interrupts_deferred
from zcut.bin_model import BinModel

if TYPE_CHECKING:
    from replay.logs.writer import LogWriter
    from replay.pipeline.verdicts import FrameJudge
    from replay.pipeline.viz import RecordingStream, VizOptions

VIEWER_FLUSH_TIMEOUT_S = 10.0
#: seconds Rerun's file writer may take to write the last frames of a recording (a writer that
#: stalls longer has failed: the recording is not complete)
RRD_FLUSH_TIMEOUT_S = 120.0
#: seconds closing a recording (its footer) may take (Rerun waits for ever on a writer that failed)
RRD_CLOSE_TIMEOUT_S = 30.0
#: seconds a frame's data may take to reach the file before the next frame goes on regardless
RRD_FRAME_FLUSH_S = 0.5
#: free bytes under which a failed write is said to have met a full disk
FULL_DISK_BYTES = 1 << 20
#: seconds Rerun's ``save`` may wait on a full disk before the file is said not to open (it writes
#: the blueprint at once, and waits for ever on a writer that failed doing so)
RRD_OPEN_FULL_S = 1.0


@dataclass(frozen=True, slots=True)
class ReplayStart:
    """What a sink learns when a replay starts.

    Attributes
    ----------
    log : str
        The log's file name.
    resolved : Resolved
        The resolved config and the notes on how it was resolved.
    metadata : dict
        The log's MCAP metadata records.
    bin_model : BinModel or None
    judge : FrameJudge or None
        What the frames are scored against when the command has truth (the log's, or labels): the
        recording then shows where each filter is wrong (:mod:`replay.pipeline.verdicts`).
    """

    log: str
    resolved: Resolved
    metadata: dict[str, dict[str, str]]
    bin_model: BinModel | None
    judge: FrameJudge | None = None

    @property
    def config(self) -> PipelineConfig:
        return self.resolved.config

    @property
    def notes(self) -> tuple[str, ...]:
        return self.resolved.notes

    def config_toml(self) -> str:
        """The resolved config as TOML (written beside outputs and logged to Rerun), headed with
        the log's name."""
        return to_toml(self.resolved.config, header=f"zcut resolved config for {self.log}")


class FrameSink(Protocol):
    """The protocol every sink follows."""

    def start(self, info: ReplayStart) -> None: ...

    def write(self, frame: Frame, result: FrameResult) -> None: ...

    def close(self, *, completed: bool) -> None: ...

    def outputs(self) -> dict[str, str]:
        """What the sink wrote, name -> path (after a completed close)."""
        ...


class NullSink:
    """Writes nothing (``zcut replay`` without ``--rrd/--spawn/--connect/--out``, sweeps, scoring)."""

    def start(self, info: ReplayStart) -> None:
        pass

    def write(self, frame: Frame, result: FrameResult) -> None:
        pass

    def close(self, *, completed: bool) -> None:
        pass

    def outputs(self) -> dict[str, str]:
        return {}


def _write_config_beside(path: Path, info: ReplayStart) -> Path:
    cp = config_path_for(path)
    with AtomicOutput(cp) as out, naming(cp, out.temp):
        out.temp.write_text(info.config_toml(), encoding="utf-8", errors="backslashreplace")  # undecodable log names
    return cp


def _disk_full(path: Path) -> bool:
    """True when the file system of ``path`` has (almost) no space left."""
    try:
        st = os.statvfs(path.parent if str(path.parent) else ".")
    except OSError:
        return False
    return st.f_bavail * st.f_frsize < FULL_DISK_BYTES


def _within(fn: Callable[[], object], timeout_s: float) -> bool:
    """Run ``fn()`` in a daemon thread; True when it returned within ``timeout_s`` (its error is
    raised here), False when it still runs (it is left behind)."""
    error: list[BaseException] = []

    def target() -> None:
        try:
            fn()
        except BaseException as e:  # noqa: BLE001 - handed to the caller
            error.append(e)

    t = threading.Thread(target=target, name="zcut-rrd-close", daemon=True)
    t.start()
    t.join(timeout_s)
    if t.is_alive():
        return False
    if error:
        raise error[0]
    return True


def _first_line(e: BaseException) -> str:
    lines = [line.strip() for line in str(e).splitlines() if line.strip()]
    return lines[0] if lines else type(e).__name__


class RrdFile:
    """An .rrd written by Rerun's file sink through an atomic output: checked after every frame (a
    full disk stops the command at once), closed within bounds, read back complete, then given its
    name; every failure is one :class:`OutputError` naming the output, with nothing left under it.
    Used by :class:`RerunSink` and by ``zcut compare``'s recording.

    Parameters
    ----------
    path : path
        The .rrd's final path (planned and locked by the caller).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.file = AtomicOutput(self.path)

    @property
    def temp(self) -> Path:
        """Where Rerun writes (renamed to :attr:`path` by :meth:`close`)."""
        return self.file.temp

    def opening_failure(self, e: RuntimeError) -> OutputError:
        """What Rerun's "could not create the file" means here."""
        if not self.temp.parent.is_dir() or not self.temp.exists():
            return folder_gone(self.path)
        return OutputError(f"{self.path}: Rerun could not open the .rrd for writing ({_first_line(e)}); "
                           "nothing was left under its name")

    def save(self, rec: RecordingStream, blueprint: Any) -> None:
        """Start Rerun's file sink on :attr:`temp` with the default ``blueprint``, bounded: Rerun's
        ``save`` writes the blueprint before it returns and waits for ever when that write meets a
        full disk (seen on a 64 KiB disk), so it runs in a daemon thread that is given up (and the
        recording with it, :func:`replay.pipeline.viz.abandon`) once the disk is full or
        :data:`RRD_CLOSE_TIMEOUT_S` have passed. Every failure is one :class:`OutputError`."""
        from replay.pipeline import viz

        error: list[BaseException] = []
        # when the save is over: an Event, not the thread's join, which an exception raised inside it (a
        # signal's) leaves believing the thread has ended (CPython 3.11's _wait_for_tstate_lock)
        opened = threading.Event()

        def target() -> None:
            try:
                rec.save(str(self.temp), default_blueprint=blueprint)
            except BaseException as e:  # noqa: BLE001 - handed to the caller
                error.append(e)
            finally:
                opened.set()

        t = threading.Thread(target=target, name="zcut-rrd-open", daemon=True)
        t0 = time.monotonic()
        t.start()
        try:
            while not opened.wait(0.1):
                waited = time.monotonic() - t0
                if (waited > RRD_OPEN_FULL_S and _disk_full(self.temp)) or waited > RRD_CLOSE_TIMEOUT_S:
                    viz.abandon(rec)
                    raise self._failure("its file writer did not start: "
                                        + ("the disk is full" if _disk_full(self.temp) else
                                           f"waited {RRD_CLOSE_TIMEOUT_S:g} s"))
        except OutputError:
            raise
        except BaseException:
            # an interruption while Rerun's save runs: Rerun creates the file at :attr:`temp` itself
            # (truncating ours), so a temporary removed now could be made again after the removal and
            # left behind (seen: SIGTERM at a replay's first note). The save is let finish (bounded: a
            # full disk can hold it for ever; then the recording is given up) before the caller's
            # clean-up removes the file.
            with interrupts_deferred():
                if not opened.wait(RRD_OPEN_FULL_S):
                    viz.abandon(rec)
            raise
        if error:
            if isinstance(error[0], RuntimeError):  # Rerun's file sink could not create the file
                raise self.opening_failure(error[0]) from None
            raise error[0]

    def check(self, rec: RecordingStream) -> None:
        """Stop at the first frame after Rerun's file writer failed (a full disk): it only logs the
        error, and the frames logged after it would pile up in memory."""
        problem = self._flush(rec, RRD_FRAME_FLUSH_S, slow_ok=True)
        if problem is not None:
            raise self._failure(problem)

    def _flush(self, rec: RecordingStream, timeout_s: float, *, slow_ok: bool = False) -> str | None:
        """Flush the recording to its file within ``timeout_s``; what went wrong, or None.

        Rerun's flush says "timed out" both for a slow disk and for a writer that died on a full
        one (it then waits for ever), so a full disk is checked while it waits. ``slow_ok``: a
        flush still running after ``timeout_s`` on a disk with space is not a problem (the next
        frame goes on; the last flush has the longer bound).
        """
        from replay.pipeline import viz

        deadline = time.monotonic() + timeout_s
        while True:
            try:
                rec.flush(timeout_sec=max(0.0, min(1.0, deadline - time.monotonic())))
                return None
            except Exception as e:  # noqa: BLE001 - rerun raises RuntimeError
                slow = "timed out" in str(e)
                if slow and not _disk_full(self.temp) and time.monotonic() < deadline:
                    continue
                if slow and slow_ok and not _disk_full(self.temp):
                    return None
                viz.abandon(rec)  # never flushed again, not even at exit
                return _first_line(e)

    def _failure(self, why: str) -> OutputError:
        if not self.temp.parent.is_dir():
            return folder_gone(self.path)
        if _disk_full(self.temp):
            return OutputError(f"{self.path}: no space left on the device; the .rrd was not written (Rerun: {why})")
        return OutputError(f"{self.path}: the .rrd could not be written completely (Rerun: {why}); nothing was "
                           "left under its name")

    def close(self, rec: RecordingStream, *, completed: bool) -> Path | None:
        """Flush and close the recording (bounded), check it complete, then give it its name (returned;
        None when not ``completed``: the temporary is removed). Never leaves the temporary behind."""
        from replay.pipeline import viz

        try:
            # a writer that failed is not disconnected (that would wait for it for ever); an
            # interrupted command does not wait long for a recording it throws away
            problem = self._flush(rec, RRD_FLUSH_TIMEOUT_S if completed else RRD_FRAME_FLUSH_S)
            if problem is None:
                try:
                    if not _within(rec.disconnect, RRD_CLOSE_TIMEOUT_S):  # writes the footer
                        problem = f"closing the file took more than {RRD_CLOSE_TIMEOUT_S:g} s"
                        viz.abandon(rec)
                except RuntimeError as e:  # Rerun's writer failed at the end
                    problem = _first_line(e)
            if not completed:
                return None
            if problem is None:
                problem = viz.rrd_problem(str(self.temp))
            if problem is not None:
                raise self._failure(problem)
            return self.file.commit()
        finally:
            if not self.file.done:
                self.file.abort()

    def abort(self) -> None:
        """No recording was started: the temporary goes."""
        if not self.file.done:
            self.file.abort()


class RerunSink:
    """Log every stage to Rerun: to an .rrd file, a spawned viewer, or a running viewer.

    Parameters
    ----------
    rrd : path, optional
        Write a recording (through a temporary file renamed into place when complete).
    spawn : bool
        Spawn a viewer.
    connect : str, optional
        A running viewer's URL (``rerun+http://127.0.0.1:9876/proxy``).
    full_detail : bool
        Log full-resolution images and clouds.
    """

    def __init__(self, *, rrd: str | Path | None = None, spawn: bool = False, connect: str | None = None,
                 full_detail: bool = False) -> None:
        # Rerun and pyarrow load here (~0.2-0.3 CPU-s, once a process), when the command plans its outputs
        # before it opens the log, not in :meth:`start`, which runs when the frames do: a replay's frames do
        # not wait for them (docs/performance.md, "The outputs, round of 2026-12-05d")
        from replay.pipeline import viz  # noqa: F401

        self.rrd = None if rrd is None else Path(rrd)
        self.spawn, self.connect, self.full_detail = spawn, connect, full_detail
        self._rec: RecordingStream | None = None
        self._file: RrdFile | None = None
        self._opts: VizOptions | None = None
        self._step = 0.0
        self._judge: FrameJudge | None = None
        self._outputs: dict[str, str] = {}
        self.viewer_error: str | None = None

    def start(self, info: ReplayStart) -> None:
        from replay.pipeline import viz

        self._opts = viz.VizOptions.full() if self.full_detail else viz.VizOptions()
        self._step = info.config.zcut.step
        self._judge = info.judge
        self._rec = viz.new_recording()
        if self.rrd is not None:
            self._file = RrdFile(self.rrd)
        try:
            judged = () if self._judge is None else self._judge.methods
            note = None
            if self._file is not None:  # bounded: Rerun's save waits for ever on a full disk
                self._file.save(self._rec, viz.default_blueprint(info.config.base_methods, judged))
            else:
                note = viz.open_sink(self._rec, spawn=self.spawn, connect=self.connect,
                                     methods=info.config.base_methods, judged=judged)
            if note is not None:
                print(f"zcut: {note}", file=sys.stderr, flush=True)
            viz.log_static(self._rec, config_toml=info.config_toml(), notes=info.notes, bin_model=info.bin_model,
                           source=f"log: {info.log}", opts=self._opts)
            if self._judge is not None:
                viz.log_verdicts_static(self._rec, self._judge.methods, source=self._judge.source, opts=self._opts)
        except BaseException:
            self.close(completed=False)
            raise

    def write(self, frame: Frame, result: FrameResult) -> None:
        from replay.pipeline import viz

        viz.log_frame(self._rec, frame, result, step_mm=self._step, opts=self._opts)  # type: ignore[arg-type]  # started
        if self._judge is not None:
            viz.log_verdicts(self._rec, frame, self._judge.judge(frame, result), self._judge.methods,  # type: ignore[arg-type]  # started
                             self._opts)  # type: ignore[arg-type]  # started
        if self._file is not None:
            self._file.check(self._rec)  # type: ignore[arg-type]  # started

    def close(self, *, completed: bool) -> None:
        rec, self._rec = self._rec, None
        file = self._file
        if rec is None:
            if file is not None:
                file.abort()
            return
        if file is None:
            self._close_viewer(rec)
            return
        done = file.close(rec, completed=completed)
        if done is not None:
            self._outputs["rrd"] = str(done)

    def _close_viewer(self, rec: RecordingStream) -> None:
        # a viewer that is gone must not hang the replay
        try:
            rec.flush(timeout_sec=VIEWER_FLUSH_TIMEOUT_S)
        except Exception as e:  # noqa: BLE001 - rerun raises a plain exception on timeout
            self.viewer_error = (f"the viewer did not take the data within {VIEWER_FLUSH_TIMEOUT_S:g} s "
                                 f"({e})")
            return  # disconnecting would wait for it
        if not _within(rec.disconnect, RRD_CLOSE_TIMEOUT_S):
            self.viewer_error = f"the viewer did not close the stream within {RRD_CLOSE_TIMEOUT_S:g} s"

    def outputs(self) -> dict[str, str]:
        return dict(self._outputs)


class ResultsSink:
    """The results MCAP (docs/formats.md): ``/zcut/outliers``, ``/zcut/sor_outliers``, ``/zcut/methods/NAME``
    (every other base method the config runs), ``/zcut/bin_mask``, ``/zcut/zone``, ``/zcut/valid`` (the
    source's valid pixels), the source's camera info and masks (ground truth) passed through, and with
    ``cloud`` ``/zcut/filtered`` and the source's image. Every mask is a bit-packed ``mono1`` Image (one
    bit a pixel; files of the previous releases hold ``mono8`` masks, read alike), in zstd chunks.

    Parameters
    ----------
    path : path
    cloud : bool
        Also write the filtered cloud and the image (``zcut replay --out-cloud``): ~33 MB of a
        1920 x 1200 frame, which chunk compression cannot shrink (measured noise); without them (the
        default) a frame takes ~0.1-0.2 MB (bench/bench_outputs.py). ``zcut accuracy`` scores either alike (the valid pixels are
        ``/zcut/valid``); the commands that need the points refuse a file without them.
    """

    def __init__(self, path: str | Path, *, cloud: bool = False) -> None:
        from replay.logs import writer  # noqa: F401  # the MCAP writer and zstd load with the sink, as Rerun does

        self.path = Path(path)
        self.cloud = cloud
        self._file: AtomicOutput | None = None
        self._writer: LogWriter | None = None
        self._outputs: dict[str, str] = {}

    def start(self, info: ReplayStart) -> None:
        from replay.logs.writer import LogWriter

        meta = {layout.RESULTS_METADATA: {"source": info.log, "config_toml": info.config_toml()}}
        for name, record in info.metadata.items():  # the synthetic truth's records travel along
            if name.startswith(layout.SYNTH_METADATA):
                meta[name] = dict(record)
        self._file = AtomicOutput(self.path)
        try:
            with naming(self.path, self._file.temp):
                self._writer = LogWriter(self._file.temp, metadata=meta, bag_name=self.path.name)
        except BaseException:
            self._file.abort()
            raise

    def write(self, frame: Frame, result: FrameResult) -> None:
        with naming(self.path, self._file.temp):  # type: ignore[union-attr]  # started
            self._write(frame, result)

    def _write(self, frame: Frame, result: FrameResult) -> None:
        w: LogWriter = self._writer  # type: ignore[assignment]  # started
        kw: dict[str, Any] = {"stamp_ns": frame.stamp_ns, "frame_id": frame.frame_id}
        kw_mask = {**kw, "packed": True}  # one bit a pixel (docs/formats.md, "Results")
        for name, mask in result.outliers.items():  # the z-cut first, then SOR and the others that ran
            w.write_mask(layout.method_topic(name), mask, **kw_mask)
        if result.bin_mask is not None:
            w.write_mask(layout.BIN_MASK, result.bin_mask.mask, **kw_mask)
        w.write_mask(layout.VALID, result.valid, **kw_mask)
        if self.cloud:
            filtered = frame.xyz.copy()
            filtered[result.zcut_outliers] = np.nan
            w.write_cloud(layout.FILTERED, filtered, rgb=frame.rgb, **kw)
            if frame.rgb is not None:
                w.write_image(layout.IMAGE, frame.rgb, **kw)
        if frame.intrinsics is not None:
            w.write_camera_info(layout.CAMERA_INFO, frame.intrinsics, **kw)
        for topic, mask in frame.masks.items():
            if not topic.startswith(layout.RESULTS_PREFIX):
                w.write_mask(topic, mask, **kw_mask)
        for topic, codes in frame.codes.items():
            w.write_codes(topic, codes, **kw)
        if result.removal is not None:  # the scored region of `zcut accuracy` (docs/accuracy.md "zone")
            w.write_mask(layout.ZONE, result.zone | result.easy_outliers, **kw_mask)

    def close(self, *, completed: bool) -> None:
        writer, self._writer = self._writer, None
        if writer is None:
            return
        file: AtomicOutput = self._file  # type: ignore[assignment]  # opened with the writer
        try:
            with naming(self.path, file.temp):
                writer.close()
            if completed:
                self._outputs["results"] = str(file.commit())
        finally:
            if not file.done:
                file.abort()  # an error, an interruption: no temporary left

    def outputs(self) -> dict[str, str]:
        return dict(self._outputs)


class ConfigBeside:
    """Writes the resolved config beside an output path (``OUT.config.toml``) when a replay
    completes; a replay that fails leaves none."""

    def __init__(self, output: str | Path) -> None:
        self.output = Path(output)
        self._info: ReplayStart | None = None
        self._outputs: dict[str, str] = {}

    def start(self, info: ReplayStart) -> None:
        self._info = info

    def write(self, frame: Frame, result: FrameResult) -> None:
        pass

    def close(self, *, completed: bool) -> None:
        if completed and self._info is not None:
            self._outputs[f"config of {self.output.name}"] = str(_write_config_beside(self.output, self._info))

    def outputs(self) -> dict[str, str]:
        return dict(self._outputs)


class BackgroundSinks:
    """Several sinks fed in one worker thread, in frame order, at most one frame behind.

    An error of a sink is raised at the next :meth:`write` or at :meth:`close`.
    """

    def __init__(self, sinks: list[FrameSink]) -> None:
        self.sinks = list(sinks)
        self._pool: ThreadPoolExecutor | None = None
        self._pending: Future[None] | None = None

    def start(self, info: ReplayStart) -> None:
        """Start every sink; if one fails (or an interruption arrives), close those started with
        ``completed=False`` (nothing left behind) and raise."""
        started = []
        try:
            for s in self.sinks:
                s.start(info)
                started.append(s)
        except BaseException:
            for s in started:
                try:
                    s.close(completed=False)
                except Exception:  # noqa: BLE001 - the first error is the one reported
                    pass
            raise

    def _wait(self) -> None:
        if self._pending is not None:
            f, self._pending = self._pending, None
            f.result()

    def write(self, frame: Frame, result: FrameResult) -> None:
        if not any(not isinstance(s, (NullSink, ConfigBeside)) for s in self.sinks):
            return
        self._wait()
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="zcut-sinks")
        self._pending = self._pool.submit(self._write_all, frame, result)

    def _write_all(self, frame: Frame, result: FrameResult) -> None:
        for s in self.sinks:
            s.write(frame, result)

    def close(self, *, completed: bool) -> None:
        """Wait for the last frame, then close every sink (``completed=False`` when another error is
        already on its way: that one is reported, and the file sinks leave nothing behind).

        Every sink is closed whatever happens meanwhile, an interruption included."""
        error: BaseException | None = None
        try:
            self._wait()
        except BaseException as e:  # noqa: BLE001 - raised after every sink is closed
            if completed or not isinstance(e, Exception):
                error = e
            completed = False
        finally:
            if self._pool is not None:
                self._pool.shutdown(wait=True)
                self._pool = None
        for s in self.sinks:
            try:
                s.close(completed=completed)
            except BaseException as e:  # noqa: BLE001 - the others are still closed
                if error is None and (completed or not isinstance(e, Exception)):
                    error = e
                completed = False
        if error is not None:
            raise error

    def outputs(self) -> dict[str, str]:
        out: dict[str, str] = {}
        for s in self.sinks:
            out.update(s.outputs())
        return out

    @property
    def viewer_error(self) -> str | None:
        for s in self.sinks:
            e: str | None = getattr(s, "viewer_error", None)
            if e:
                return e
        return None
