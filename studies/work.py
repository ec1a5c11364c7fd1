"""What one unit of a study computes, in a worker process.

A :class:`Job` says what every unit of a study needs (small and picklable: paths and options,
never arrays); :func:`run_batch_unit` and ``studies.sweep.run_sweep_unit`` take a
:class:`~studies.units.WorkUnit` and the job, open the unit's log as a
:class:`~replay.pipeline.session.ReplaySession` (resolving the same config as ``zcut replay`` does:
the worker checks it against the config the driver resolved), run the frames of the unit, and return
a :class:`UnitResult`: plain rows (dicts) for the tables, the damage met, the time and memory spent.
Any error of a damaged log is caught and returned in the result: one bad log never stops a study.
"""

from __future__ import annotations

import functools
import math
import resource
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from replay.logs.damage import Damage
from zcut.errors import ZcutError

if TYPE_CHECKING:
    from collections.abc import Callable, Collection, Sequence

    from annotate.truth import FrameTruth, LabelTruth, SyntheticTruth
    from replay.logs.frame import Frame
    from replay.pipeline.session import FrameRow, ReplaySession
    from replay.pipeline.sinks import FrameSink
    from replay.pipeline.stages import FrameResult
    from studies.units import WorkUnit
    from zcut.bin_model import BinModel

    #: Where a unit's truth comes from: an annotator's labels or the synthetic ground truth.
    TruthSource = LabelTruth | SyntheticTruth

#: replay --json's per-frame counts, the columns every study table shares
COUNT_COLUMNS = ("valid_px", "zcut", "sor", "both", "above_rim", "clusters")
STAGE_COLUMNS = ("bin_mask", "registration", "removal", "zcut", "sor", "metrics", "total")


@dataclass(frozen=True, slots=True)
class Job:
    """What every unit of a study needs.

    Attributes
    ----------
    config_file : str or None
    overrides : dict
        The command line's config layer.
    bin_model : str or None
        Path of the bin model PLY.
    topic : str or None
    labels : str or None
        Label store (truth from an annotator's labels instead of the synthetic truth).
    annotator : str or None
    region : {"zone", "valid"}
    truth : {"paper", "sensor"} or None
        The recorded truth to score against (:func:`annotate.truth.truth_of_log`; None: the paper's
        where a log has it, else the sensor's).
    configs : dict[str, Resolved]
        Log sha256 -> the config the driver resolved for it: the worker runs exactly that config
        (it never resolves one again).
    extra : dict
        Study-specific options (the sweep's grid, per-log outputs).
    """

    config_file: str | None
    overrides: dict[str, Any]
    bin_model: str | None
    topic: str | None
    labels: str | None
    annotator: str | None
    region: str
    configs: dict[str, Any]
    extra: dict[str, Any] = field(default_factory=dict)
    truth: str | None = None


@dataclass(slots=True)
class UnitResult:
    """What a unit returns to the driver.

    Attributes
    ----------
    unit : WorkUnit
    rows : list of dict
        The table rows (one per frame for a batch; per frame × parameter set × method for a sweep).
    damage : list of replay.logs.damage.Damage
        What the pass over the unit's range lost (every frame that could not be read is named).
    error : str or None
        Why the unit failed as a whole (its frames are then not in ``rows``).
    frames : int
        Frames processed.
    seconds, cpu_seconds : float
    peak_rss_mb : float
        The worker process's peak resident memory.
    unscored : list of dict
        Frames without truth: index, stamp_ns, reason.
    """

    unit: WorkUnit
    rows: list[dict[str, Any]] = field(default_factory=list)
    damage: list[Damage] = field(default_factory=list)
    error: str | None = None
    frames: int = 0
    seconds: float = 0.0
    cpu_seconds: float = 0.0
    peak_rss_mb: float = 0.0
    unscored: list[dict[str, Any]] = field(default_factory=list)

    @classmethod
    def failure(cls, unit: WorkUnit, why: str) -> UnitResult:
        return cls(unit, error=why)


@functools.lru_cache(maxsize=2)
def _bin_model(path: str | Path) -> BinModel:
    from replay.pipeline.bin_model import load_bin_model

    return load_bin_model(path)


#: the sessions this worker process opened (a log's units usually come one after another)
_SESSIONS: dict[tuple[Any, ...], ReplaySession] = {}
_MAX_SESSIONS = 2


def open_unit_session(unit: WorkUnit, job: Job) -> ReplaySession:
    """The unit's log as a replay session running the config the driver resolved for it (never
    resolved again here), with the bin model :func:`replay.pipeline.bin_model.bin_model_for` chooses
    for it (``--bin-model``, else the log's own attachment: each log of a study its own); the worker
    keeps the last two sessions it opened."""
    from replay.pipeline.bin_model import bin_model_for
    from replay.pipeline.config import config_sha256
    from replay.pipeline.session import ReplaySession

    resolved = job.configs.get(unit.sha256)
    if resolved is None:
        raise ZcutError(f"{Path(unit.log).name}: the driver resolved no config for this log")
    key = (unit.log, unit.sha256, config_sha256(resolved.config), job.bin_model, job.topic)
    session = _SESSIONS.get(key)
    if session is None:
        session = ReplaySession.open(unit.log, resolved=resolved, topic=job.topic,
                                     choose_bin_model=lambda r: bin_model_for(r, job.bin_model, load=_bin_model))
        while len(_SESSIONS) >= _MAX_SESSIONS:
            _SESSIONS.pop(next(iter(_SESSIONS)))
        _SESSIONS[key] = session
    return session


def truth_source(unit: WorkUnit, job: Job, mask_topics: Collection[str]) -> TruthSource:
    """The unit's truth: the annotator's labels (``--labels``) or the log's recorded truth that
    :func:`annotate.truth.truth_of_log` chooses from its ``mask_topics`` (``job.truth``)."""
    from annotate.truth import LabelTruth, SyntheticTruth, synthetic_truth

    if job.labels is not None:
        return LabelTruth(job.labels, unit.log, annotator=job.annotator)
    # pixel counts only: no per-kind recall in the tables (a frame without its kind image is scored)
    found = synthetic_truth(job.truth, mask_topics, unit.log, with_kinds=False)
    return found if found is not None else SyntheticTruth()  # no truth: every frame unscored, saying why


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _finite(v: float) -> float | None:
    return v if isinstance(v, float) and math.isfinite(v) else None


def batch_row(unit: WorkUnit, frame: Frame, result: FrameResult, row: FrameRow, truth: FrameTruth | None,
              region: np.ndarray, methods: Sequence[str], *, truth_name: str | None = None) -> dict[str, Any]:
    """One row of ``frames.parquet``: the replay table's counts, fitness, stage timings and, where
    there is truth, which (``truth_name``: ``paper``, ``sensor`` or ``labels``) and TP/FP/FN per
    reported method (``methods``) over S = R ∩ region."""
    from annotate.truth import method_predictions, pixel_counts

    out: dict[str, Any] = {"log": Path(unit.log).name, "log_sha256": unit.sha256, "frame": frame.index,
                 "stamp_ns": frame.stamp_ns}
    for c in COUNT_COLUMNS:
        out[c] = int(getattr(row, c))
    out["fitness"] = _finite(row.fitness)
    out["rmse_mm"] = _finite(row.rmse_mm)
    out["pose_error_mm"] = _finite(row.pose_error_mm)
    out["pose_error_deg"] = _finite(row.pose_error_deg)
    out["bin_check"] = _finite(row.bin_check)  # the bin check's figure (docs/pipeline.md, "Bin removal")
    out["bin_flagged"] = bool(row.bin_flagged)
    others = [m for m in result.outliers if m not in ("zcut", "sor")]
    for m in others:  # the other filter methods' outlier counts, named like the zcut and sor columns
        out[m] = int(np.count_nonzero(result.outliers[m]))
    for s in (*STAGE_COLUMNS, *others):
        out[f"t_{s}_s"] = _finite(float(result.timings[s])) if s in result.timings else None
    check = result.bin_check
    out["warnings"] = "; ".join(result.warnings + ((f"bin check: {check.reason}",)
                                                   if result.bin_flagged and check is not None else ()))
    out["scored"] = truth is not None
    out["truth"] = truth_name if truth is not None else None
    preds = method_predictions(result, methods)
    for m in methods:
        tp = fp = fn = None
        if truth is not None:
            tp, fp, fn = pixel_counts(preds[m], truth, region)
        out[f"{m}_tp"], out[f"{m}_fp"], out[f"{m}_fn"] = tp, fp, fn
    return out


def caught_unit(unit: WorkUnit, body: Callable[[UnitResult, list[Any]], None]) -> UnitResult:
    """Run ``body(result, held)`` for ``unit`` and return the result with the time and memory spent; any
    error of the unit (a damaged log, a bug) is caught into ``result.error``, never raised: one bad unit
    does not stop the others. What ``body`` puts in ``held`` (its truth source) is closed after it."""
    t0, c0 = time.perf_counter(), time.process_time()
    res = UnitResult(unit)
    held: list[Any] = []
    try:
        body(res, held)
    except ZcutError as e:
        res.error = str(e)
    except OSError as e:
        res.error = f"{e.strerror or e}: {e.filename or unit.log}"
    except Exception as e:  # noqa: BLE001 - a bug must not stop the other units; its trace goes to the summary
        res.error = f"{type(e).__name__}: {e} ({traceback.format_exc(limit=3).splitlines()[-1]})"
    finally:
        for h in held:
            if h is not None and hasattr(h, "close"):
                h.close()
    res.seconds = time.perf_counter() - t0
    res.cpu_seconds = time.process_time() - c0
    res.peak_rss_mb = _peak_rss_mb()
    return res


def run_unit(unit: WorkUnit, job: Job, body: Callable[[UnitResult, ReplaySession, TruthSource], None]) -> UnitResult:
    """Open the unit's session and truth, run ``body(result, session, truth)`` on them, and return the
    result with the time and memory spent; any error of the unit (a damaged log, a bug) is caught
    into ``result.error``, never raised: one bad unit does not stop the others (:func:`caught_unit`)."""

    def opened(res: UnitResult, held: list[Any]) -> None:
        session = open_unit_session(unit, job)
        truth_src = truth_source(unit, job, session.reader.mask_topics)
        held.append(truth_src)
        body(res, session, truth_src)

    return caught_unit(unit, opened)


def run_batch_unit(unit: WorkUnit, job: Job) -> UnitResult:
    """Replay the unit's frames; one row per frame (see :func:`batch_row`)."""
    return run_unit(unit, job, functools.partial(_batch_frames, unit, job))


def _batch_frames(unit: WorkUnit, job: Job, res: UnitResult, session: ReplaySession, truth_src: TruthSource) -> None:
    from annotate.truth import scored_region
    from replay.pipeline.session import FrameRow

    sinks = _per_log_sinks(unit, job, session)
    poses = session.true_poses()
    results = session.results(frames=(unit.start, unit.stop))
    completed = False
    try:
        for frame, result in results:
            row = FrameRow.of(result, true_pose=poses.get(frame.stamp_ns))
            for s in sinks:
                s.write(frame, result)
            got = truth_src.truth(frame, result.valid)
            truth = None
            if isinstance(got, str):
                res.unscored.append({"index": frame.index, "stamp_ns": frame.stamp_ns, "reason": got})
            else:
                truth = got
            res.rows.append(batch_row(unit, frame, result, row, truth, scored_region(result, job.region),
                                      session.config.reported_methods, truth_name=truth_src.choice))
            res.frames += 1
        completed = True
    finally:
        results.close()
        res.damage = list(results.damage)
        for s in sinks:
            s.close(completed=completed)


def _per_log_sinks(unit: WorkUnit, job: Job, session: ReplaySession) -> list[FrameSink]:
    """``--results`` / ``--rrd``: one results MCAP and one .rrd per log (a log is then one unit)."""
    out_dir = job.extra.get("out_dir")
    sinks: list[FrameSink] = []
    if out_dir is None:
        return sinks
    from replay.pipeline.sinks import ReplayStart, RerunSink, ResultsSink

    stem = f"{Path(unit.log).stem}-{unit.sha256[:8]}"
    if job.extra.get("results"):
        (Path(out_dir) / "results").mkdir(exist_ok=True)
        sinks.append(ResultsSink(Path(out_dir) / "results" / f"{stem}.results.mcap",
                                 cloud=bool(job.extra.get("results_cloud"))))
    if job.extra.get("rrd"):
        (Path(out_dir) / "rrd").mkdir(exist_ok=True)
        sinks.append(RerunSink(rrd=Path(out_dir) / "rrd" / f"{stem}.rrd"))
    info: ReplayStart = session.start_info()
    for s in sinks:
        s.start(info)
    return sinks
