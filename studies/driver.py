"""The driver of a study: find the logs, resolve each one's config, plan the units, run the ones not
done yet on an executor, keep every finished unit, show progress.

Named steps, shared by ``zcut batch`` and ``zcut sweep``::

    logs = plan_logs(inputs, job_options)            # hash, resolve, split into units (bad logs noted)
    store = PartStore(out_dir, identity(...))        # refuses another config's run before any work
    results = execute(units, job, executor, store)   # runs what is not done, writes each part

(:func:`run_planned` is the last two, with the executor and the progress.)
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Protocol

from replay.errors import ConfigError
from replay.logs.identity import file_sha256
from replay.options import PipelineOptions
from replay.pipeline.config import Resolved, config_sha256
from studies.units import WorkUnit, broken_link, expand_logs, plan_log
from studies.work import Job, UnitResult
from zcut.errors import ZcutError

if TYPE_CHECKING:
    from collections.abc import Callable
    from contextlib import ExitStack

    import pyarrow as pa

    from studies.executors import Executor, UnitFn
    from studies.parts import PartStore


@dataclass(frozen=True, slots=True, kw_only=True)
class StudyOptions:
    """What ``zcut batch`` and ``zcut sweep`` share (:class:`studies.batch.BatchOptions`,
    :class:`studies.sweep.SweepOptions`); the defaults are the command line's.

    Attributes
    ----------
    inputs : tuple of str
        Logs, or folders of them (their ``*.mcap`` files).
    out : str
        The output folder (created; a rerun over it continues where it stopped).
    pipeline : PipelineOptions
        The config, its overrides, the topic and the bin model, resolved per log as ``zcut replay`` does.
    labels, annotator : str or None
        Score against this annotator's labels in this label store (default: the logs' synthetic truth).
    region : {"zone", "valid"}
        The scored region.
    truth : {"paper", "sensor"} or None
        The logs' recorded truth to score against (docs/accuracy.md, "Two truths"); None: the paper's
        where a log has it, else the sensor's.
    workers : int or None
        Local processes (None: the cores; 0: this process, one unit after another).
    ray : str or None
        A Ray cluster's address, or ``auto``, instead of local processes.
    frames_per_unit : int
        Frames per unit of work.
    force : bool
        Start afresh when an input log changed content since the study in ``out`` began.
    """

    inputs: tuple[str, ...]
    out: str
    pipeline: PipelineOptions = PipelineOptions()
    labels: str | None = None
    annotator: str | None = None
    region: str = "zone"
    truth: str | None = None
    workers: int | None = None
    ray: str | None = None
    frames_per_unit: int  # each study's own default
    force: bool = False


@dataclass(slots=True)
class LogPlan:
    """One input log: its identity, resolved config and units (or why it cannot be used)."""

    path: Path
    sha256: str = ""  # its identity: the SHA-256 of its bytes, or what plan_logs' identify says
    content_hashed: bool = True  # sha256 is the SHA-256 of every byte (a label store's key of the log)
    n_frames: int | None = None
    resolved: Resolved | None = None
    bin_model_warning: str | None = None  # no bin model for this log (bin_model_source's warning)
    units: list[WorkUnit] = field(default_factory=list)
    error: str | None = None

    @property
    def notes(self) -> tuple[str, ...]:
        return self.resolved.notes if self.resolved is not None else ()

    @property
    def config_toml(self) -> str:
        """The resolved config as TOML (for the study's outputs)."""
        if self.resolved is None:
            return ""
        from replay.pipeline import config as cfg

        return cfg.to_toml(self.resolved.config, header=f"zcut resolved config for {self.path.name}")




def plan_logs(inputs: list[str], *, config_file: str | None, overrides: dict[str, Any], topic: str | None,
              frames_per_unit: int, whole: bool,
              progress: Callable[[int, int, Path], None] | None = None,
              bin_model: str | None = None,
              opened: Callable[[LogPlan, Any, Any], None] | None = None,
              reader_options: dict[str, Any] | None = None,
              identify: Callable[[Path], str] | None = None) -> list[LogPlan]:
    """Every input log with its resolved config and units; a log that cannot be opened keeps its
    error (a warning and exit 3 at the end) unless no log at all can be used (an error). A log that
    gets no bin model (no ``bin_model``, no attachment of its own) keeps the warning that says so.
    ``opened(plan, reader, first)``: called with each usable log as opened here (its reader and first
    readable frame), so that a caller needs not open it again (it must not raise). Each log is read
    once for its hash and opened once (:func:`~replay.pipeline.session.open_log`, with
    ``reader_options``: :class:`~replay.logs.reader.LogReader`'s keywords), its units split from that
    reader's index. ``identify``: what identifies a log (its units, a resumed study's check that it did
    not change): by default the SHA-256 of every byte; ``zcut compare`` passes
    :func:`replay.logs.identity.log_identity` (the MCAP summary and CRCs, without reading every byte)."""
    from replay.pipeline import config as cfg
    from replay.pipeline.bin_model import bin_model_source
    from replay.pipeline.session import open_log

    # absolute: units run in other folders and nodes (a symlink that leads nowhere: as it stands)
    paths = [Path(os.path.abspath(p)) if broken_link(p) else p.resolve() for p in expand_logs(inputs)]
    file_layer = cfg.load_toml(config_file) if config_file is not None else None
    plans: list[LogPlan] = []
    for i, path in enumerate(paths):
        if progress is not None:
            progress(i, len(paths), path)
        plan = LogPlan(path)
        if (why := broken_link(path)) is not None:  # left out with a warning, as an unreadable log
            plan.error = f"cannot be read: {why}"
            plans.append(plan)
            continue
        try:
            plan.sha256 = (identify or file_sha256)(path)
            plan.content_hashed = identify is None
            reader, first, plan.resolved = open_log(path, file_layer=file_layer, overrides=overrides, topic=topic,
                                                    reader_options=reader_options)
            # the units from the same reader: the log is opened (its first chunks decompressed) once
            plan.units, plan.n_frames = plan_log(path, sha256=plan.sha256, frames_per_unit=frames_per_unit,
                                                 whole=whole, topic=topic, reader=reader)
            plan.bin_model_warning = bin_model_source(reader, bin_model)[1]
            if opened is not None:
                opened(plan, reader, first)
        except ConfigError:
            raise  # the options are wrong for every log: an error before any work
        except (ZcutError, OSError) as e:
            plan.error = str(e) if isinstance(e, ZcutError) else f"{e.strerror or e}: {path}"
            plan.units = []
        plans.append(plan)
    if not any(p.units for p in plans):
        first_error = next((p.error for p in plans if p.error), "no frames")
        raise ZcutError(f"no usable log among {len(plans)} input(s): {first_error}")
    return plans


def check_labels(labels: str | None, annotator: str | None, plans: list[LogPlan], *,
                 labelled: bool = False) -> None:
    """Refuse before any work what every unit's :class:`annotate.truth.LabelTruth` would refuse (an
    annotator who did not label a log, or none named where a log has several), with ``zcut
    accuracy``'s words: a usage error (exit 1), not a failed unit per log (exit 3). The logs are
    looked up by the content hash the planning computed (not hashed again; hashed here where the planning
    identified them otherwise: ``plan_logs``' ``identify``). A log the store
    does not hold is refused (it would be scored against another log's labels of the same stamps); a results
    file is matched by stamp, unless ``labelled`` (``zcut compare``, whose inputs are logs, never results
    files)."""
    if labels is None:
        return
    from annotate.store import LabelStore
    from annotate.store import file_sha256 as content_sha256  # kept for the units' LabelTruth in this process
    from annotate.truth import is_results_file
    from zcut.errors import ParameterError

    store = LabelStore(Path(labels), read_only=True)
    try:
        for p in plans:
            if not p.units:
                continue
            log = store.log_by_sha(p.sha256 if p.content_hashed else content_sha256(p.path))
            if log is None and (labelled or not is_results_file(p.path)):
                held = ", ".join(r.name for r in store.logs()) or "none"
                raise ParameterError(f"--labels {labels}: no labels of {p.path.name} (its content is not in the "
                                     f"store; labelled logs: {held})")
            known = store.annotators(log) if log is not None else store.annotators()
            if annotator is not None and annotator not in known:
                raise ParameterError(f"--annotator {annotator!r}: no labels by them in {labels} "
                                     f"(annotators: {', '.join(known) or 'none'})")
            if annotator is None and len(known) != 1:
                raise ParameterError(f"{labels} has labels by {len(known)} annotators "
                                     f"({', '.join(known) or 'none'}): choose one with --annotator")
    finally:
        store.close()


def absolute(path: str | None) -> str | None:
    """An absolute path for the workers (they may run in another folder, on another node)."""
    return None if path is None else str(Path(path).resolve())


def check_study_options(options: StudyOptions) -> None:
    """The options ``zcut batch`` and ``zcut sweep`` share, checked before any work."""
    from annotate.truth import check_region

    check_region(options.region)
    if options.frames_per_unit < 1:
        raise ConfigError(f"--frames-per-unit must be >= 1, got {options.frames_per_unit}")
    for path in (options.pipeline.config, options.pipeline.bin_model, options.labels):
        if path is not None and not Path(path).is_file():
            raise FileNotFoundError(2, "no such file", str(path))


def study_options(options: StudyOptions, overrides: dict[str, Any]) -> dict[str, Any]:
    """The options that identify a study in its folder (with the inputs' content hashes)."""
    pipe = options.pipeline
    return {"config_sha256": file_identity(pipe.config), "overrides": overrides,
            "bin_model_sha256": file_identity(pipe.bin_model), "topic": pipe.topic, "labels": options.labels,
            "annotator": options.annotator, "region": options.region, "frames_per_unit": options.frames_per_unit,
            # the truth's choice (a study begun before it scored the sensor's truth: "sensor" keeps its identity)
            **({"truth": options.truth or "paper"} if options.labels is None and options.truth != "sensor" else {})}


def study_job(options: StudyOptions, overrides: dict[str, Any], plans: list[LogPlan],
              extra: dict[str, Any]) -> Job:
    """The :class:`~studies.work.Job` of a study: its options with absolute paths (the workers may run in
    another folder, on another node) and the config resolved per log."""
    pipe = options.pipeline
    return Job(config_file=absolute(pipe.config), overrides=overrides, bin_model=absolute(pipe.bin_model),
               topic=pipe.topic, labels=absolute(options.labels), annotator=options.annotator,
               region=options.region, configs={p.sha256: p.resolved for p in plans if p.units}, extra=extra,
               truth=options.truth)


def start_units(plans: list[LogPlan], store: PartStore, *, what: str, executor: Executor,
                stream: IO[str] | None = None) -> tuple[list[WorkUnit], list[WorkUnit]]:
    """Warn about the logs left out; the units and those not done yet; say what will run."""
    err = sys.stderr if stream is None else stream
    for p in plans:
        if p.error:
            print(f"warning: {p.path}: {p.error} (left out; exit 3 at the end)", file=err)
        elif p.bin_model_warning:
            print(f"warning: {p.bin_model_warning}", file=err)
    units = [u for p in plans for u in p.units]
    todo = [u for u in units if not store.done(u.key)]
    done = len(units) - len(todo)
    print(f"zcut: {len(plans)} log(s), {what}{len(units)} unit(s) of work"
          + (f", {done} already done in {store.root}" if done else "")
          + f"; {executor.name}: {executor.workers} worker(s)", file=err, flush=True)
    return units, todo


def identity(kind: str, options: dict[str, Any], plans: list[LogPlan]) -> dict[str, Any]:
    """What identifies a study in its output folder (``run.json``): its kind and options, the resolved
    config per log's content hash, and the content hash per input path (a changed log is refused,
    not mixed: :class:`studies.parts.PartStore`)."""
    return {"kind": kind, "options": options,
            "logs": {p.sha256: config_sha256(p.resolved.config) for p in plans if p.units and p.resolved},
            "paths": {str(p.path): p.sha256 for p in plans if p.sha256}}


def named_as_now(table: pa.Table, plans: list[LogPlan]) -> pa.Table:
    """``table`` with its ``log`` column naming each log as this run's inputs do (a unit done in an
    earlier run keeps the name its log had then: a log renamed since would be named twice)."""
    import pyarrow as pa

    names = {p.sha256: p.path.name for p in plans if p.sha256}
    if not table.num_rows or "log" not in table.column_names or "log_sha256" not in table.column_names:
        return table
    logs = [names.get(sha, log) for sha, log in zip(table.column("log_sha256").to_pylist(),
                                                     table.column("log").to_pylist())]
    i = table.column_names.index("log")
    return table.set_column(i, table.schema.field(i), pa.array(logs, type=table.schema.field(i).type))


def file_identity(path: str | None) -> str | None:
    """A file's content hash for the study's identity (None without a file)."""
    return None if path is None else file_sha256(Path(path))


class Progress:
    """A one-line progress bar on stderr: frames done, rate, time left (a line per update when
    stderr is not a terminal, at most every few seconds)."""

    def __init__(self, total: int | None, *, what: str = "frames", stream: IO[str] | None = None) -> None:
        self.total, self.what = total, what
        self.stream = sys.stderr if stream is None else stream
        self.done = 0
        self.t0 = time.perf_counter()
        self._last = 0.0
        self._shown = -1
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()

    def update(self, n: int, *, note: str = "", force: bool = False) -> None:
        self.done += n
        now = time.perf_counter()
        if not force and not self.tty and now - self._last < 5.0:
            return
        self._last = now
        self._shown = self.done
        dt = now - self.t0
        rate = self.done / dt if dt > 0 else 0.0
        if self.total:
            frac = min(self.done / self.total, 1.0)
            bar = "#" * int(30 * frac) + "-" * (30 - int(30 * frac))
            left = (self.total - self.done) / rate if rate > 0 else float("nan")
            eta = _hms(left) if left == left else "?"
            text = f"[{bar}] {self.done}/{self.total} {self.what}  {rate:.2f}/s  {eta} left"
        else:
            text = f"{self.done} {self.what}  {rate:.2f}/s"
        if note:
            text += f"  {note}"
        end = "\r" if self.tty else "\n"
        print(text, file=self.stream, end=end, flush=True)

    def finish(self) -> None:
        if self._shown != self.done:
            self.update(0, force=True)
        if self.tty:
            print(file=self.stream)


def _hms(s: float) -> str:
    s = int(round(s))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


class ProgressSink(Protocol):
    """What :func:`execute` reports each finished unit's frames to (a :class:`Progress`, or a scaled one)."""

    def update(self, n: int, *, note: str = "", force: bool = False) -> None: ...


class Scaled:
    """A progress counting ``scale`` steps a unit's frame (a sweep's frames × Δd)."""

    def __init__(self, progress: ProgressSink, scale: int) -> None:
        self.progress, self.scale = progress, scale

    def update(self, n: int, *, note: str = "", force: bool = False) -> None:
        self.progress.update(n * self.scale, note=note, force=force)


def execute(units: list[WorkUnit], job: Job, fn: UnitFn, executor: Executor, store: PartStore, *,
            progress: ProgressSink | None = None, schema: pa.Schema | None = None) -> list[UnitResult]:
    """Run the units not done yet; write each finished unit's part at once; return this run's
    results (failed units are not marked done: a rerun tries them again)."""
    todo = [u for u in units if not store.done(u.key)]
    out: list[UnitResult] = []
    try:
        for unit, res in executor.run(fn, todo, job):
            out.append(res)
            if res.error is None:
                store.write(unit.key, res.rows, meta_of(res), schema=schema)
            if progress is not None:
                note = f"{Path(unit.log).name} failed: {res.error.splitlines()[0][:60]}" if res.error else ""
                progress.update(res.frames, note=note, force=bool(note))
    finally:
        executor.close()
    return out


def run_planned(kind: str, options: StudyOptions, stack: ExitStack, plans: list[LogPlan], ident: dict[str, Any], *,
                overrides: dict[str, Any], extra: dict[str, Any], fn: UnitFn, what: str = "", per_frame: int = 1,
                progress_what: str = "frames") -> tuple[PartStore, list[UnitResult], Executor]:
    """Run the units of a planned, checked study: make the executor the options choose (a Ray cluster is
    connected to here), lock ``options.out`` (``stack`` holds the lock), say what will run and run every
    unit not done yet with ``fn``, showing the progress.

    Parameters
    ----------
    kind : str
        The study's kind in its identity (:func:`identity`).
    ident : dict
        The options that identify the study (:func:`study_options` and the study's own).
    overrides, extra : dict
        The job's (:func:`study_job`).
    fn : UnitFn
        What runs a unit.
    what : str
        Said before the count of units (:func:`start_units`).
    per_frame, progress_what : int, str
        The progress counts ``per_frame`` steps a frame and names them ``progress_what``.

    Returns
    -------
    store : PartStore
    results : list of UnitResult
        This run's units'.
    executor : Executor
        The one that ran them, closed.
    """
    from studies.executors import make_executor
    from studies.parts import PartStore

    executor = make_executor(workers=options.workers, ray=options.ray)  # an unreachable cluster fails here
    try:
        store = stack.enter_context(PartStore(options.out, identity(kind, ident, plans),
                                              start_afresh=options.force))
        units, todo = start_units(plans, store, what=what, executor=executor)
        job = study_job(options, overrides, plans, extra)
        progress = Progress(sum(u.n_frames or 0 for u in todo) * per_frame or None, what=progress_what)
        results = execute(units, job, fn, executor, store, progress=Scaled(progress, per_frame))
        progress.finish()
    finally:
        executor.close()
    return store, results, executor


def meta_of(res: UnitResult) -> dict[str, Any]:
    u = res.unit
    return {"log": u.log, "sha256": u.sha256, "start": u.start, "stop": u.stop, "frames": res.frames,
            "damage": [d.text for d in res.damage], "unscored": res.unscored, "seconds": res.seconds,
            "cpu_seconds": res.cpu_seconds,
            "peak_rss_mb": res.peak_rss_mb}
