"""Replay a log through the pipeline: read, resolve the config, run, log to Rerun, write results.

Library code: it never prints. The command modules (``zcut replay``, ``zcut demo``) pass callbacks
to show progress and the per-frame table.
"""

from __future__ import annotations

import math
import queue
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from replay.errors import ConfigError
from replay.logs import layout
from replay.logs.frame import Frame
from replay.pipeline import config as cfg
from replay.pipeline.stages import FrameResult, locate_bin, run_frame
from zcut.removal import BinModel

VIEWER_FLUSH_TIMEOUT_S = 10.0


@dataclass(frozen=True, slots=True)
class FrameRow:
    """One line of the per-frame table (and of the JSON summary)."""

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

    @classmethod
    def of(cls, result: FrameResult) -> FrameRow:
        reg = result.registration
        m = result.metrics
        return cls(
            index=result.index, stamp_ns=result.stamp_ns, valid_px=int(result.valid.sum()),
            zcut=int(result.zcut_outliers.sum()), sor=int(result.sor_outliers.sum()),
            both=int(result.both_outliers.sum()), above_rim=int(result.easy_outliers.sum()),
            clusters=result.cut.n_clusters, alpha=float(m.alpha), beta_sor=float(m.beta1),
            beta_zcut=float(m.beta2),
            fitness=float(reg.fitness) if reg is not None else math.nan,
            rmse_mm=float(reg.inlier_rmse) * 1000.0 if reg is not None else math.nan,
            time_s=float(result.timings["total"]), warnings=result.warnings,
        )

    def as_dict(self) -> dict[str, Any]:
        d = {k: getattr(self, k) for k in self.__slots__}
        d["warnings"] = list(self.warnings)
        return {k: _json_number(v) for k, v in d.items()}


def _json_number(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


@dataclass(slots=True)
class ReplaySummary:
    """What a replay did (mutable while it runs; final when :func:`replay_log` returns)."""

    log: str
    resolved: cfg.Resolved | None = None
    rows: list[FrameRow] = field(default_factory=list)
    damage: list[str] = field(default_factory=list)
    outputs: dict[str, str] = field(default_factory=dict)
    part_kind: str | None = None
    n_planned: int | None = None  # frames in the requested range, when the log's summary says
    viewer_error: str | None = None  # --spawn/--connect: the viewer did not take the data
    n_log_frames: int | None = None  # clouds in the log, when its summary says

    def as_dict(self) -> dict[str, Any]:
        total = {k: sum(getattr(r, k) for r in self.rows)
                 for k in ("valid_px", "zcut", "sor", "both", "above_rim", "clusters")}
        t = sum(r.time_s for r in self.rows)
        return {
            "log": self.log,
            "part_kind": self.part_kind,
            "notes": list(self.resolved.notes) if self.resolved else [],
            "config": cfg.to_dict(self.resolved.config) if self.resolved else None,
            "frames": [r.as_dict() for r in self.rows],
            "totals": {**total, "frames": len(self.rows), "time_s": t,
                       "frames_per_s": _json_number(len(self.rows) / t if t > 0 else math.nan)},
            "damage": list(self.damage),
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


def synth_info(metadata: dict[str, dict[str, str]]) -> tuple[str | None, float | None]:
    """(part_kind, camera distance in mm) from a log's ``zcut.synth`` metadata (None when absent)."""
    meta = metadata.get(layout.SYNTH_METADATA, {})
    kind = meta.get("part_kind") or None
    if kind == "empty":  # an empty-bin log has no parts to derive a preset from
        kind = None
    dist = None
    for key, scale in (("a_max_distance_mm", 1.0), ("pile_distance_mm", 1.0), ("camera_distance_mm", 1.0),
                       ("pile_distance_m", 1000.0), ("camera_distance_m", 1000.0)):
        if key in meta:
            try:
                dist = float(meta[key]) * scale
                break
            except ValueError:
                continue
    return kind, dist


def intrinsics_from_cloud(xyz: np.ndarray):
    """Pinhole intrinsics fitted to an organized cloud (x/z = (u - cx)/fx, y/z = (v - cy)/fy).

    Least squares over the valid points with z > 0; None when fewer than 100 such points or a
    non-positive focal length comes out.
    """
    from zcut.cloud import Intrinsics

    h, w = xyz.shape[:2]
    z = xyz[..., 2].astype(np.float64)
    ok = np.isfinite(xyz).all(axis=2) & (z > 0)
    if ok.sum() < 100:
        return None
    v, u = np.nonzero(ok)
    fits = []
    for coord, pix in ((xyz[..., 0][ok] / z[ok], u), (xyz[..., 1][ok] / z[ok], v)):
        slope, intercept = np.polyfit(pix.astype(np.float64), coord.astype(np.float64), 1)
        if not slope > 0:
            return None
        fits.append((1.0 / slope, -intercept / slope))
    (fx, cx), (fy, cy) = fits
    return Intrinsics(fx=fx, fy=fy, cx=cx, cy=cy, width=w, height=h)


def _median_depth_mm(frame: Frame) -> float | None:
    """Median z of the valid points (mm): the camera distance a preset's a_max is measured at."""
    z = frame.xyz[..., 2]
    z = z[np.isfinite(z)]
    return float(np.median(z)) * 1000.0 if z.size else None


def prefetched(frames: Iterator[Frame], *, depth: int = 1) -> Iterator[Frame]:
    """Iterate ``frames`` in a background thread, up to ``depth`` frames ahead of the consumer.

    Decoding the next frame (zstd and the cloud unpacking release the GIL) then overlaps the
    pipeline on the current one. Exceptions of the iterator are raised to the consumer where they
    happened in the sequence; closing this generator (or an exception in the consumer, once the
    caller closes it) stops and joins the thread and closes ``frames``.
    """
    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(item) -> bool:
        while not stop.is_set():
            try:
                q.put(item, timeout=0.05)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        try:
            for f in frames:
                if not put(("frame", f)):
                    return
            put(("end", None))
        except BaseException as e:  # noqa: BLE001 - handed to the consumer, raised there
            put(("error", e))
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
                yield item
            elif kind == "error":
                raise item
            else:
                return
    finally:
        stop.set()
        while worker.is_alive():
            try:  # unblock a producer waiting on a full queue
                q.get_nowait()
            except queue.Empty:
                pass
            worker.join(timeout=0.05)


def config_path_for(output: str | Path) -> Path:
    """Where the resolved config goes beside an output: ``OUT.rrd`` -> ``OUT.config.toml``."""
    p = Path(output)
    return p.with_name(p.stem + ".config.toml")


def replay_log(
    path: str | Path,
    *,
    config_file: str | Path | None = None,
    overrides: dict[str, Any] | None = None,
    frames: tuple[int, int | None] = (0, None),
    topic: str | None = None,
    bin_model: BinModel | None = None,
    rrd: str | Path | None = None,
    spawn: bool = False,
    connect: str | None = None,
    out: str | Path | None = None,
    full_detail: bool = False,
    on_start: Callable[[ReplaySummary], None] | None = None,
    on_frame: Callable[[Frame, FrameResult, FrameRow], None] | None = None,
    keep_results: bool = False,
) -> tuple[ReplaySummary, list[tuple[Frame, FrameResult]]]:
    """Replay a log.

    Parameters
    ----------
    path : str or Path
        ROS 2 MCAP log.
    config_file : path, optional
        TOML config (:func:`replay.pipeline.config.load_toml`).
    overrides : dict, optional
        Command-line layer (:func:`replay.pipeline.config.cli_layer`).
    frames : (start, stop)
        Frame index range, ``stop`` exclusive or None.
    topic : str, optional
        Cloud topic.
    bin_model : BinModel, optional
        Without it the bin stages are skipped (each result carries the warning).
    rrd, spawn, connect
        Rerun sinks (any one; none: no Rerun logging).
    out : path, optional
        Results MCAP (SPEC §5 topics).
    full_detail : bool
        Rerun logging at full detail.
    on_start : callable, optional
        Called once the config is resolved (after the first frame is read).
    on_frame : callable, optional
        Called after each frame.
    keep_results : bool
        Return every (frame, result) (memory!) for callers that score them.

    Returns
    -------
    (ReplaySummary, list of (Frame, FrameResult))
        ``summary.damage`` is non-empty when the log was damaged after intact frames.
    """
    from threadpoolctl import threadpool_limits

    from replay.logs.reader import LogReader

    file_layer = cfg.load_toml(config_file) if config_file is not None else {}
    reader = LogReader(path, cloud_topic=topic)
    part_kind, distance_mm = synth_info(reader.metadata)
    summary = ReplaySummary(log=str(path), part_kind=part_kind)
    summary.n_log_frames = reader.n_frames
    if reader.n_frames is not None:
        end = reader.n_frames if frames[1] is None else min(frames[1], reader.n_frames)
        summary.n_planned = max(end - frames[0], 0)
    kept: list[tuple[Frame, FrameResult]] = []
    rec = None
    writer = None
    use_viz = rrd is not None or spawn or connect is not None
    start, stop = frames
    opts = None
    frame_iter = prefetched(reader.frames(start=start, stop=stop))
    outputs = _Outputs()
    completed = False
    # the bin mask and registration of frame k + 1 (OpenCV, Open3D: no numba) run in a thread
    # while the removal, z-cut and SOR (numba) finish frame k
    locator = ThreadPoolExecutor(max_workers=1, thread_name_prefix="zcut-locate")
    pending: tuple[Frame, Future] | None = None

    def finish(frame: Frame, located) -> None:
        config = summary.resolved.config
        result = run_frame(frame, config, bin_model=bin_model, located=located)
        if rec is not None or writer is not None:
            outputs.submit(_log_and_write, rec, writer, frame, result, step_mm=config.zcut.step_mm,
                           opts=opts)
        row = FrameRow.of(result)
        summary.rows.append(row)
        if keep_results:
            kept.append((frame, result))
        if on_frame is not None:
            on_frame(frame, result, row)

    # BLAS is only used for tiny products here, and its spinning worker threads steal the cores
    # from the numba and Open3D threads that overlap during a replay: one BLAS thread
    blas = threadpool_limits(limits=1, user_api="blas")
    try:
        while True:
            try:
                frame = next(frame_iter)
            except StopIteration:
                break
            except BaseException:
                if pending is not None:  # the frames before the reader's error still count
                    finish(pending[0], pending[1].result())
                    pending = None
                raise
            if summary.resolved is None:
                K = frame.intrinsics
                wants_preset = (overrides or {}).get("preset") or file_layer.get("preset")
                extra: list[str] = []
                if wants_preset and distance_mm is None:
                    distance_mm = _median_depth_mm(frame)
                    if distance_mm is not None:
                        extra.append(f"camera distance for the preset's a_max: the median depth, {distance_mm:.0f} mm")
                if wants_preset and K is None:
                    K = intrinsics_from_cloud(frame.xyz)
                    if K is not None:
                        extra.append(f"intrinsics estimated from the organized cloud: fx {K.fx:.1f}, fy {K.fy:.1f} px")
                summary.resolved = cfg.resolve(
                    file_layer=file_layer, cli=overrides, part_kind=part_kind,
                    camera_distance_mm=distance_mm, fx=K.fx if K else None, fy=K.fy if K else None,
                    image_shape=frame.shape)
                if extra:
                    r = summary.resolved
                    summary.resolved = cfg.Resolved(r.config, tuple(extra) + r.notes)
                config = summary.resolved.config
                toml = cfg.to_toml(config, header=f"zcut resolved config for {Path(path).name}")
                for o in (rrd, out):
                    if o is not None:
                        cp = config_path_for(o)
                        cp.write_text(toml)
                        summary.outputs["config"] = str(cp)
                if use_viz:
                    from replay.pipeline import viz

                    opts = viz.VizOptions.full() if full_detail else viz.VizOptions()
                    rec = viz.new_recording()
                    viz.open_sink(rec, rrd=None if rrd is None else str(rrd), spawn=spawn, connect=connect)
                    viz.log_static(rec, config_toml=toml, notes=summary.resolved.notes,
                                   bin_model=bin_model, source=f"log: {Path(path).name}")
                    if rrd is not None:
                        summary.outputs["rrd"] = str(rrd)
                if out is not None:
                    from replay.logs.writer import LogWriter

                    meta = {layout.RESULTS_METADATA: {"source": str(Path(path).name), "config_toml": toml}}
                    if layout.SYNTH_METADATA in reader.metadata:
                        meta[layout.SYNTH_METADATA] = dict(reader.metadata[layout.SYNTH_METADATA])
                    writer = LogWriter(out, metadata=meta)
                    summary.outputs["results"] = str(out)
                if on_start is not None:
                    on_start(summary)
            config = summary.resolved.config
            if pending is None:
                pending = (frame, locator.submit(locate_bin, frame, config, bin_model=bin_model))
            else:
                before, future = pending
                located = future.result()
                pending = (frame, locator.submit(locate_bin, frame, config, bin_model=bin_model,
                                                 previous=located.registration))
                finish(before, located)
        if pending is not None:
            finish(pending[0], pending[1].result())
            pending = None
        completed = True
    finally:
        locator.shutdown(wait=True, cancel_futures=True)
        blas.restore_original_limits()
        frame_iter.close()  # joins the reader thread: reader.damage is final
        summary.damage = list(reader.damage)
        try:
            outputs.close(raise_errors=completed)  # every frame logged and written
        finally:
            if writer is not None:
                writer.close()
            if rec is not None:
                if rrd is not None:
                    rec.flush()
                else:  # a viewer that is gone must not hang the replay
                    try:
                        rec.flush(timeout_sec=VIEWER_FLUSH_TIMEOUT_S)
                    except Exception as e:  # rerun raises a plain exception on timeout
                        summary.viewer_error = f"the viewer did not take the data within {VIEWER_FLUSH_TIMEOUT_S:g} s ({e})"
                rec.disconnect()
    return summary, kept


class _Outputs:
    """Runs the Rerun logging and results writing of frame k in one worker thread, in frame order,
    while the pipeline runs on frame k + 1 (at most one frame pending: memory stays bounded).

    An error of the worker is raised at the next :meth:`submit` or at :meth:`close`.
    """

    def __init__(self) -> None:
        self._pool: ThreadPoolExecutor | None = None
        self._pending: Future | None = None

    def submit(self, fn: Callable[..., None], *args: Any, **kw: Any) -> None:
        self._wait()
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="zcut-outputs")
        self._pending = self._pool.submit(fn, *args, **kw)

    def _wait(self) -> None:
        if self._pending is not None:
            f, self._pending = self._pending, None
            f.result()

    def close(self, *, raise_errors: bool) -> None:
        """Wait for the last job and stop the thread; ``raise_errors=False`` when another error is
        already on its way (that one is the one to report)."""
        try:
            self._wait()
        except Exception:
            if raise_errors:
                raise
        finally:
            if self._pool is not None:
                self._pool.shutdown(wait=True)
                self._pool = None


def _log_and_write(rec, writer, frame: Frame, result: FrameResult, *, step_mm: float, opts) -> None:
    if rec is not None:
        from replay.pipeline import viz

        viz.log_frame(rec, frame, result, step_mm=step_mm, opts=opts)
    if writer is not None:
        _write_results(writer, frame, result)


def _write_results(writer, frame: Frame, result: FrameResult) -> None:
    kw = {"stamp_ns": frame.stamp_ns, "frame_id": frame.frame_id}
    writer.write_mask(layout.ZCUT_OUTLIERS, result.zcut_outliers, **kw)
    writer.write_mask(layout.SOR_OUTLIERS, result.sor_outliers, **kw)
    if result.bin_mask is not None:
        writer.write_mask(layout.BIN_MASK, result.bin_mask.mask, **kw)
    filtered = frame.xyz.copy()
    filtered[result.zcut_outliers] = np.nan
    writer.write_cloud(layout.FILTERED, filtered, rgb=frame.rgb, **kw)
    if frame.rgb is not None:
        writer.write_image(layout.IMAGE, frame.rgb, **kw)
    if frame.intrinsics is not None:
        writer.write_camera_info(layout.CAMERA_INFO, frame.intrinsics, **kw)
    for topic, mask in frame.masks.items():
        if not topic.startswith(layout.RESULTS_PREFIX):
            writer.write_mask(topic, mask, **kw)
