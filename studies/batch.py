"""``zcut batch``: every frame of many logs, counted and scored, in one table (docs/studies.md).

``frames.parquet`` has one row per frame (:func:`studies.work.batch_row`: the replay table's counts,
fitness, stage timings, and TP/FP/FN per method over the scored region where truth exists);
``summary.json`` the totals, the per-log losses, the pooled accuracy with intervals and the cost
(:func:`summary`: a :class:`studies.summary.BatchSummary`, serialised by its ``to_json``).
:func:`run` is the whole batch as a library call: ``run(BatchOptions(inputs=(log,), out=folder))``.
"""

from __future__ import annotations

import platform
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from studies.driver import LogPlan, StudyOptions
from studies.summary import BatchLog, BatchSummary, RunCost, Scores, Totals, intervals, truth_summary, truths_by_log
from studies.work import COUNT_COLUMNS, UnitResult

if TYPE_CHECKING:
    from contextlib import ExitStack

    from studies.executors import Executor
    from studies.parts import PartStore


def frames_table(store: PartStore) -> Any:
    """Every finished unit's rows, sorted by log and frame."""
    t = store.table()
    if t.num_rows:
        t = t.sort_by([("log_sha256", "ascending"), ("frame", "ascending")])
    return t


def pooled(table: Any) -> dict[str, Scores]:
    """Pooled accuracy per method over the scored frames (micro average) with 95 % intervals over
    frames (:func:`zcut.metrics.pooled_interval`; None where too few frames)."""
    from zcut.metrics import pooled_interval

    if not table.num_rows or "scored" not in table.column_names:
        return {}
    rows = [r for r in table.to_pylist() if r["scored"]]
    if not rows:
        return {}
    out: dict[str, Scores] = {}
    methods = [c[:-3] for c in table.column_names if c.endswith("_tp")]
    for m in methods:
        tp = [r[f"{m}_tp"] for r in rows]
        fp = [r[f"{m}_fp"] for r in rows]
        fn = [r[f"{m}_fn"] for r in rows]
        T, F, N = sum(tp), sum(fp), sum(fn)
        out[m] = Scores(T, F, N, _ratio(T, T + F), _ratio(T, T + N), _ratio(2 * T, 2 * T + F + N),
                        intervals(pooled_interval(np.asarray(tp, dtype=np.int64), np.asarray(fp, dtype=np.int64),
                                                  np.asarray(fn, dtype=np.int64))))
    return out


def _ratio(a: int, b: int) -> float | None:
    return a / b if b else None


def summary(plans: list[LogPlan], store: PartStore, table: Any, results: list[UnitResult], *, executor_name: str,
            workers: int, seconds: float, region: str | None = None) -> BatchSummary:
    """``summary.json``: totals, per-log frames, losses and errors, pooled accuracy over ``region``, cost."""
    metas = store.metas()
    by_log: dict[str, dict[str, Any]] = {}
    for p in plans:
        by_log[p.sha256 or str(p.path)] = {"log": str(p.path), "sha256": p.sha256, "frames_in_log": p.n_frames,
                                           "frames": 0, "damage": [], "unscored": 0,
                                           "errors": [p.error] if p.error else [], "notes": tuple(p.notes),
                                           "planned": True}
    for m in metas.values():
        e = by_log.setdefault(m["sha256"], {"log": m["log"], "sha256": m["sha256"], "frames": 0, "damage": [],
                                            "unscored": 0, "errors": [], "planned": False})
        e["frames"] += m["frames"]
        e["damage"] += m["damage"]
        e["unscored"] += len(m["unscored"])
    for r in results:
        if r.error is not None:
            by_log[r.unit.sha256]["errors"].append(f"frames {r.unit.start}-{r.unit.stop or 'end'}: {r.error}")
    truths = truths_by_log(table)  # which truth scored each log (docs/accuracy.md, "Two truths")
    for sha, e in by_log.items():
        e["truth"] = truths.get(sha)
    logs = tuple(BatchLog(**{**e, "damage": tuple(e["damage"]), "errors": tuple(e["errors"])})
                 for e in sorted(by_log.values(), key=lambda e: e["log"]))
    sums = {c: int(sum(table.column(c).to_pylist())) if table.num_rows else 0
            for c in COUNT_COLUMNS}
    # frames whose bin removal did not work (their counts rest on it: docs/pipeline.md, "Bin removal")
    flagged = table.column("bin_flagged").to_pylist() if "bin_flagged" in table.column_names else []
    scored = table.column("scored").to_pylist() if "scored" in table.column_names else [False] * len(flagged)
    sums["bin_flagged"] = sum(bool(f) for f in flagged)
    sums["bin_flagged_scored"] = sum(bool(f) and bool(sc) for f, sc in zip(flagged, scored))
    this_run = [r for r in results if r.error is None]
    frames_now = sum(r.frames for r in this_run)
    cpu = sum(r.cpu_seconds for r in this_run)
    return BatchSummary(
        totals=Totals(logs=len(plans), frames=int(table.num_rows), **sums),
        region=region, pooled=pooled(table), logs=logs, truth=truth_summary(truths) or None,
        data_loss=any(lg.damage or lg.errors for lg in logs),
        this_run=RunCost(frames=frames_now, seconds=seconds, frames_per_s=frames_now / seconds if seconds else None,
                         cpu_seconds_per_frame=cpu / frames_now if frames_now else None,
                         peak_rss_mb_per_worker=max((r.peak_rss_mb for r in this_run), default=None),
                         executor=executor_name, workers=workers, host=platform.node()),
    )


# ------------------------------------------------------------------ the batch as a library call

#: Frames per unit of work of a batch: whole chunks of one log.
FRAMES_PER_UNIT = 8


@dataclass(frozen=True, slots=True, kw_only=True)
class BatchOptions(StudyOptions):
    """Every frame of many logs replayed, counted and scored (docs/studies.md); the defaults are ``zcut batch``'s.

    Attributes
    ----------
    results : bool
        Also write a results MCAP per log (``out/results``).
    results_cloud : bool
        With ``results``: also write the filtered cloud and the image.
    rrd : bool
        Also write a Rerun .rrd per log (``out/rrd``).
    """

    frames_per_unit: int = FRAMES_PER_UNIT
    results: bool = False
    results_cloud: bool = False
    rrd: bool = False


@dataclass(frozen=True, slots=True)
class BatchResult:
    """What :func:`run` wrote: ``frames.parquet`` (its table) and ``summary.json`` (its summary)."""

    summary: BatchSummary
    table: Any
    frames_path: Path
    summary_path: Path

    @property
    def data_loss(self) -> bool:
        """Frames or logs were lost (``zcut batch`` exits 3)."""
        return self.summary.data_loss


def run(options: BatchOptions) -> BatchResult:
    """Replay every frame of ``options.inputs`` on the executor the options choose, skipping the frames
    done in an earlier run over the same folder; write ``frames.parquet`` and ``summary.json``.

    Says on stderr what runs and how far it is. The output folder stays locked until the tables are
    written. Raises :class:`~zcut.errors.ZcutError` for options or inputs no work can start from."""
    from contextlib import ExitStack

    with ExitStack() as stack:
        return _run(options, stack)


def _run(options: BatchOptions, stack: ExitStack) -> BatchResult:
    import time

    from threadpoolctl import threadpool_limits

    from studies.driver import check_study_options, named_as_now
    from studies.schemas import conform, frames_columns

    t0 = time.perf_counter()
    check_study_options(options)
    overrides = options.pipeline.overrides()
    store, plans, results, executor = _run_units(options, stack, overrides)
    table = named_as_now(frames_table(store), plans)
    config = next((p.resolved.config for p in plans if p.resolved is not None), None)
    if config is not None:  # the declared columns (studies/schemas.py), whatever the values
        others = [m for m in config.base_methods if m not in ("zcut", "sor")]
        table = conform(table, frames_columns(config.reported_methods, others))
    frames_path = store.write_table("frames.parquet", table)
    with threadpool_limits(limits=1, user_api="blas"):  # the bootstrap's product: OpenBLAS threads spin
        summ = summary(plans, store, table, results, executor_name=executor.name, workers=executor.workers,
                       seconds=time.perf_counter() - t0, region=options.region)
    summ_path = store.write_json("summary.json", summ.to_json())
    return BatchResult(summ, table, frames_path, summ_path)


def _run_units(options: BatchOptions, stack: ExitStack, overrides: dict[str, Any]
               ) -> tuple[PartStore, list[LogPlan], list[UnitResult], Executor]:
    """Plan the logs, lock the folder, run every unit not done yet: (store, plans, this run's results,
    the executor, closed)."""
    import sys

    from studies.driver import check_labels, plan_logs, run_planned, study_options
    from studies.work import run_batch_unit

    err = sys.stderr

    def planning(i: int, n: int, path: Path) -> None:
        if n > 5 and (i % 20 == 0 or i == n - 1):
            print(f"zcut: reading {n} logs: {i + 1}/{n} {path.name}", file=err, flush=True)

    pipe = options.pipeline
    plans = plan_logs(list(options.inputs), config_file=pipe.config, overrides=overrides, topic=pipe.topic,
                      frames_per_unit=options.frames_per_unit, whole=options.results or options.rrd,
                      progress=planning, bin_model=pipe.bin_model)
    check_labels(options.labels, options.annotator, plans)  # as zcut accuracy: before any work
    if options.truth is not None:  # the truth asked for is in every log, before any work
        from studies.sweep_run import check_truth

        check_truth([str(p.path) for p in plans if p.units], labels=options.labels, topic=pipe.topic,
                    truth=options.truth)
    ident = study_options(options, overrides) | {"results": options.results, "rrd": options.rrd}
    if options.results_cloud:  # only then: a study begun before the option keeps its identity
        ident["results_cloud"] = True
    # the executor is made once every input is checked (a Ray cluster is connected to then): bad input is one
    # line before anything starts
    store, results, executor = run_planned(
        "batch", options, stack, plans, ident, overrides=overrides, fn=run_batch_unit,
        extra={"out_dir": str(Path(options.out)) if (options.results or options.rrd) else None,  # the store's root
               "results": options.results, "results_cloud": options.results_cloud, "rrd": options.rrd})
    return store, plans, results, executor
