"""``zcut sweep LOG… -o DIR``: a parameter study of the z-cut and SOR scored by true accuracy (docs/studies.md).

Writes ``DIR/sweep.parquet`` (one row per log × frame × parameter set × method), ``DIR/summary.json``
(pooled figures per set with 95 % intervals, the paper's relative figures, the tuned and the chosen
points), ``DIR/tuned.toml`` (a config ``zcut replay --config`` accepts), the plots (PNG) and
``DIR/report.html``. Running it again over the same DIR continues where it stopped.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from replay.pipeline.config import PipelineConfig
    from studies.driver import ProgressSink
    from studies.parts import PartStore
    from studies.summary import FlaggedFrame, ParamSet, SweepSummary, Tuned
    from studies.validate import Validation


def add_arguments(p: argparse.ArgumentParser) -> None:
    from cli.commands.common import add_pipeline_options
    from studies.grid import DEFAULT_MAX_POINTS

    p.add_argument("inputs", nargs="+", metavar="LOG_OR_RESULTS.mcap", help="logs (or folders of them) with "
                   "synthetic truth, logs labelled in --labels, or results files of `zcut replay --out`")
    p.add_argument("-o", "--out", required=True, metavar="DIR", help="output folder (created; rerun to continue)")
    g = p.add_argument_group(
        "the grid", "LIST: a,b,c or start:stop:count (inclusive, evenly spaced); values that agree to 1e-9 "
        "(relative, after rounding to 12 significant digits) are one value. An axis not given holds the "
        "config's value. Study points: unless --no-study-points, the d_max and ρ_thr axes also hold the "
        "config's own value and 0.5× and 1.5× it (ρ_thr ≤ 1), for the paper's sensitivity ratios ω and θ; so "
        "these two axes have three values when not given.")
    g.add_argument("--step", metavar="LIST", help="z-cut Δd values, mm")
    g.add_argument("--max-depth", metavar="LIST", help="z-cut d_max values, mm")
    g.add_argument("--rho", metavar="LIST", help="z-cut ρ_thr values (μ_thr = ρ_thr·a_max)")
    g.add_argument("--sor-k", metavar="LIST", help="SOR k values")
    g.add_argument("--sor-std", metavar="LIST", help="SOR std_ratio values")
    g.add_argument("--grid", action="append", metavar="SECTION.FIELD=LIST", default=None,
                   help="an axis of a filter of the bank (repeatable): e.g. radius.radius_mm=1,2,3, "
                   "radius.min_points=4,8; SECTION=default for the filter's default axes. The filter must be among "
                   "--methods; its other fields hold the config's values (docs/filters.md, 'The bank in a sweep')")
    g.add_argument("--no-study-points", dest="study_points", action="store_false",
                   help="the grid is exactly the values given (and the config's value on the axes not given): "
                   "no 0.5×/1.5× points (θ, ω and the paper's findings need them)")
    g.add_argument("--max-points", type=int, default=DEFAULT_MAX_POINTS, metavar="N",
                   help=f"refuse grids larger than this without --force (default {DEFAULT_MAX_POINTS}); a LIST of "
                   "more values is refused before it is expanded")
    g.add_argument("--force", action="store_true", help="run a grid larger than --max-points; start afresh when "
                   "an input log changed content since the study in DIR began (its earlier results are removed)")
    p.add_argument("--objective", default="f1",
                   help="what tuned.toml maximises: f1 (default), recall@precision=P or precision@recall=R")
    p.add_argument("--labels", metavar="DB", help="score against an annotator's labels (default: synthetic truth)")
    p.add_argument("--annotator", help="whose labels (when the store has several)")
    p.add_argument("--region", default="zone", help="scored region: zone (default) or valid")
    p.add_argument("--workers", type=int, default=None, metavar="N", help="local processes (default: the cores; 0: run in this process, one unit after another)")
    p.add_argument("--ray", metavar="ADDRESS", help="run on a Ray cluster: its address, or `auto`")
    p.add_argument("--frames-per-unit", type=int, default=4, metavar="N", help="frames per unit of work (default 4)")
    p.add_argument("--no-report", action="store_true", help="skip the plots and report.html")
    add_pipeline_options(p, zcut=False)


def _source_of_results(path: Path) -> Path | None:
    """The source log a results file names (beside it), when it is one; the path itself otherwise."""
    from replay.logs import layout
    from replay.logs.reader import inspect_log

    meta = inspect_log(path).metadata.get(layout.RESULTS_METADATA)
    if not meta:
        return path
    src = path.parent / meta.get("source", "")
    return src if meta.get("source") and src.is_file() and src != path else None


def run(args: argparse.Namespace) -> int:
    with ExitStack() as stack:  # the output folder stays locked until the tables are written
        return _run(args, stack)


def _run(args: argparse.Namespace, stack: ExitStack) -> int:
    from cli.commands.common import overrides_of
    from replay.errors import ConfigError
    from replay.logs import layout
    from replay.logs.reader import LogReader
    from replay.process import EXIT_DATA_LOSS
    from studies import sweep
    from studies.bank import make_bank_grid, n_bank_sets, parse_grid_options, ranking
    from studies.driver import (
        Progress,
        absolute,
        check_labels,
        check_study_options,
        execute,
        identity,
        named_as_now,
        plan_logs,
        start_units,
        study_options,
    )
    from studies.executors import make_executor
    from studies.grid import make_grid, parse_list
    from studies.parts import PartStore
    from studies.summary import DamageNote, SweepLog, SweepSummary, UnscoredFrame
    from studies.units import expand_logs
    from studies.work import Job
    from zcut.errors import ZcutError

    t0 = time.perf_counter()
    err = sys.stderr
    check_study_options(args)
    objective = sweep.parse_objective(args.objective)
    # an axis of more values than --max-points is a grid of more points: refused before it is expanded
    limit = None if args.force else args.max_points
    axes = dict(steps=parse_list(args.step, name="--step", max_values=limit),
                depths=parse_list(args.max_depth, name="--max-depth", max_values=limit),
                rhos=parse_list(args.rho, name="--rho", max_values=limit),
                sor_ks=parse_list(args.sor_k, name="--sor-k", integer=True, max_values=limit),
                sor_stds=parse_list(args.sor_std, name="--sor-std", max_values=limit))
    bank_axes = parse_grid_options(args.grid, max_values=limit)
    overrides = overrides_of(args)
    # results files: their source log (the filtered cloud has its outliers removed)
    logs = []
    for p in expand_logs(args.inputs):
        try:
            src = _source_of_results(p)
        except ConfigError:
            raise
        except (ZcutError, OSError):  # unreadable: planning reports it and the others go on (exit 3), as in batch
            logs.append(str(p))
            continue
        if src is None:
            raise ConfigError(f"{p} is a results file whose source log (named in it) is not beside it: "
                              "sweep the source log")
        if src != p:
            print(f"zcut: {p.name} is a results file: sweeping its source log {src}", file=err)
        logs.append(str(src))
    # the truth must exist before any work
    if args.labels is None:
        for log in logs:
            try:
                topics = LogReader(log, cloud_topic=args.topic).mask_topics
            except ConfigError:
                raise
            except (ZcutError, OSError):
                continue  # unreadable: left out by the planning, with a warning
            if layout.TRUTH_OUTLIERS not in topics:
                raise ConfigError(f"{log} has no {layout.TRUTH_OUTLIERS} (not a synthetic log): label it "
                                  "(zcut annotate) and give --labels DB")
    executor = make_executor(workers=args.workers, ray=args.ray)
    try:
        plans = plan_logs(logs, config_file=args.config, overrides=overrides, topic=args.topic,
                          frames_per_unit=args.frames_per_unit, whole=False, bin_model=args.bin_model)
        check_labels(args.labels, args.annotator, plans)  # as zcut accuracy: before any work
        first = next(p for p in plans if p.units)
        assert first.resolved is not None  # a log with units was resolved
        base = first.resolved.config
        grid = make_grid(**axes, config=base, max_points=args.max_points, force=args.force,
                         study_points=args.study_points)
        bank = make_bank_grid(bank_axes, base)
        options = study_options(args, overrides) | {"grid": grid.as_dict()} | ({"bank": bank} if bank else {})
        store = stack.enter_context(PartStore(args.out, identity("sweep", options, plans),
                                                     start_afresh=args.force))
        with_sor = base.sor.enabled and "sor" in base.base_methods
        n_sets = grid.n_zcut + (grid.n_sor(per_depth=base.sor.region == "top") if with_sor else 0)
        n_bank = n_bank_sets(bank)
        if n_sets + n_bank > args.max_points and not args.force:
            raise ConfigError(f"the grid has {n_sets + n_bank} parameter sets (more than {args.max_points}): "
                              "narrow it, or use --force")
        units, todo = start_units(plans, store, executor=executor,
                                  what=f"{n_sets + n_bank} parameter sets ({grid.n_zcut} z-cut, {n_sets - grid.n_zcut} "
                                       f"SOR{f', {n_bank} of the filter bank' if n_bank else ''}), ")
        job = Job(config_file=absolute(args.config), overrides=overrides, bin_model=absolute(args.bin_model), topic=args.topic,
                  labels=absolute(args.labels), annotator=args.annotator, region=args.region,
                  configs={p.sha256: p.resolved for p in plans if p.units},
                  extra={"grid": sweep.grid_dict(grid), "bank": bank})
        per_frame = len(grid.steps)
        total = sum((u.n_frames or 0) for u in todo) * per_frame or None
        progress = Progress(total, what="frames × Δd")
        progress_scale = _Scaled(progress, per_frame)
        results = execute(units, job, sweep.run_sweep_unit, executor, store, progress=progress_scale)
        progress.finish()
    finally:
        executor.close()
    table = named_as_now(store.table(), plans)
    if table.num_rows:
        table = table.sort_by([("log_sha256", "ascending"), ("frame", "ascending"), ("method", "ascending")])
    store.write_table("sweep.parquet", table)
    if not table.num_rows:
        failed = [f"{Path(str(r.unit.log)).name}: {r.error}" for r in results if r.error]
        failed += [f"{Path(str(p.path)).name}: {p.error}" for p in plans if p.error]
        if failed:  # the frames were lost, not truthless: data loss (as batch), naming what failed
            more = f" (and {len(failed) - 1} more)" if len(failed) > 1 else ""
            print(f"error: no frame was scored, because a unit of work failed: {failed[0]}{more}", file=sys.stderr)
            return EXIT_DATA_LOSS
        raise ConfigError("no frame was scored (no truth in any frame): nothing to sum up")
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):  # OpenBLAS's spinning threads cost ~20x here
        sets = sweep.pooled_sets(table)
    tuned = sweep.tune(sets, objective, part=base.part)
    chosen = grid.chosen
    point = (chosen[0], chosen[1], chosen[2], base.zcut.max_area if chosen[2] is None else None)
    tuned, validation = sweep.validate_tuning(table, sets, tuned, objective, point=point)
    metas = store.metas().values()
    summary = SweepSummary(
        logs=tuple(SweepLog(str(p.path), p.sha256, p.error) for p in plans),
        frames=len(set(zip(table.column("log_sha256").to_pylist(), table.column("frame").to_pylist()))),
        region=args.region, objective=args.objective, truth="labels" if args.labels else "synthetic",
        grid=grid, config=first.config_toml, notes=tuple(first.notes), sets=tuple(sets), tuned=tuned,
        chosen_zcut=sweep.find_set(sets, "zcut", chosen[0], chosen[1], chosen[2]),
        chosen_sor=sweep.find_sor_set(sets, chosen[3], chosen[4], chosen[0], chosen[1]),
        nominal=sweep.find_set(sets, "zcut", 0.2, 30.0, 0.07),
        sensitivity_chosen=sweep.sensitivity_at(sets, chosen[:3]),
        sensitivity_tuned=(sweep.sensitivity_at(sets, (tuned.zcut.step_mm, tuned.zcut.max_depth_mm, tuned.zcut.rho_thr))
                           if tuned.zcut else None),
        damage=tuple(DamageNote(Path(m["log"]).name, d) for m in metas for d in m["damage"]),
        errors=tuple(f"{r.unit.log}: {r.error}" for r in results if r.error),
        unscored=tuple(UnscoredFrame(Path(m["log"]).name, u.get("index"), u.get("stamp_ns"), u.get("reason"))
                       for m in metas for u in m["unscored"]),
        reproduce=_reproduce(args), seconds=time.perf_counter() - t0, bin_flagged=_flagged_frames(table),
        validation=validation,
        ranking=ranking(table, objective) if (bank or any("+" in m for m in base.methods)) else None,
    )
    store.write_json("summary.json", summary.to_json())
    tuned_path = _write_tuned(store, base, tuned, args, validation, summary.ranking)
    if not args.no_report:
        from studies.report import write_report

        write_report(store.root, summary)
    _print(summary, tuned_path)
    return EXIT_DATA_LOSS if summary.data_loss else 0


def _flagged_frames(table: Any) -> tuple[FlaggedFrame, ...]:
    """The scored frames the bin check flagged (docs/pipeline.md, "Bin removal"): every parameter set's
    scores on them rest on a bin removal that did not work."""
    from studies.summary import FlaggedFrame

    if "bin_flagged" not in table.column_names:
        return ()
    seen: dict[tuple[str, int], FlaggedFrame] = {}
    for log, frame, flagged in zip(table.column("log").to_pylist(), table.column("frame").to_pylist(),
                                   table.column("bin_flagged").to_pylist()):
        if flagged:
            seen.setdefault((log, frame), FlaggedFrame(log, int(frame)))
    return tuple(seen.values())


def _reproduce(args: argparse.Namespace) -> str:
    """The command line that reruns this sweep."""
    parts = ["zcut", "sweep", *args.inputs, "-o", args.out]
    for opt in ("step", "max_depth", "rho", "sor_k", "sor_std", "objective", "labels", "annotator", "region",
                "config", "bin_model", "part", "parameters", "preset", "topic", "methods"):
        v = getattr(args, opt, None)
        if v is not None and not (opt == "objective" and v == "f1") and not (opt == "region" and v == "zone"):
            parts += ["--" + opt.replace("_", "-"), str(v)]
    for g in getattr(args, "grid", None) or ():
        parts += ["--grid", g]
    if not getattr(args, "study_points", True):
        parts.append("--no-study-points")
    return " ".join(shlex.quote(str(p)) for p in parts)


class _Scaled:
    """Progress in frames × Δd from units' frames."""

    def __init__(self, progress: ProgressSink, scale: int) -> None:
        self.progress, self.scale = progress, scale

    def update(self, n: int, *, note: str = "", force: bool = False) -> None:
        self.progress.update(n * self.scale, note=note, force=force)


def _write_tuned(store: PartStore, base: PipelineConfig, tuned: Tuned, args: argparse.Namespace,
                 validation: Validation | None = None, ranking: dict[str, Any] | None = None) -> Path | None:
    """``tuned.toml``: the base config with the tuned z-cut and SOR parameters, and each swept filter of
    the bank at its tuned set; its header names the ranking's best method or combination."""
    import dataclasses

    from replay.pipeline import config as cfg

    z, s = tuned.zcut, tuned.sor
    if z is None:
        return None
    # a z-cut set has Δd, d_max and ρ_thr (a_max known) or μ_thr; a SOR set has k and std_ratio
    assert z.step_mm is not None and z.max_depth_mm is not None
    if z.rho_thr is not None and base.zcut.a_max is not None:
        max_area = z.rho_thr * base.zcut.a_max
    else:
        assert z.max_area_px is not None
        max_area = z.max_area_px
    zc = dataclasses.replace(base.zcut, step=z.step_mm, max_depth=z.max_depth_mm, max_area=max_area)
    if s is not None:
        assert s.sor_k is not None and s.sor_std_ratio is not None
        sor = dataclasses.replace(base.sor, k=s.sor_k, std_ratio=s.sor_std_ratio)
    else:
        sor = base.sor
    tuned_cfg = base.replace(zcut=zc, sor=sor)
    ranked = ((ranking or {}).get("by_part") or {}).get("all") or []
    for row in ranked:
        m = row.get("method")
        if m in cfg.BANK_SECTIONS and row.get("params"):
            tuned_cfg = tuned_cfg.replace(**{m: dataclasses.replace(getattr(base, m), **row["params"])})

    def f(v: float | None) -> str:
        return "-" if v is None else f"{v:.3f}"

    header = (f"zcut sweep: tuned by {args.objective} over {store.root}\n"
              f"z-cut: precision {f(z.precision)}, recall {f(z.recall)}, F1 {f(z.f1)}"
              + (f"\nz-cut out of sample: F1 {f(validation.f1_out_of_sample)} (cross-validated; rule "
                 f"{validation.rule})" if validation is not None and validation.f1_out_of_sample is not None else "")
              + (f"\nSOR: precision {f(s.precision)}, recall {f(s.recall)}, F1 {f(s.f1)}" if s else "")
              + (f"\nnote: {tuned.note}" if tuned.note else "")
              + (f"\nbest of the ranking by {args.objective}: {ranked[0]['method']} (precision {f(ranked[0].get('precision'))}, "
                 f"recall {f(ranked[0].get('recall'))}, F1 {f(ranked[0].get('f1'))}); run it with --methods "
                 f"{ranked[0]['method']}" if ranked else ""))
    path = store.root / "tuned.toml"
    from replay.outputs import AtomicOutput

    with AtomicOutput(path) as out:
        out.temp.write_text(cfg.to_toml(tuned_cfg, header=header), encoding="utf-8", errors="backslashreplace")
    return path


def _print(summary: SweepSummary, tuned_path: Path | None) -> None:
    def row(name: str, e: ParamSet | None) -> str:
        if e is None:
            return f"  {name:10s} -"
        cells = []
        for k in ("precision", "recall", "f1"):
            v, (lo, hi) = e.figure(k), e.ci(k)
            cells.append("-" if v is None else f"{v:.3f} [{lo:.3f}, {hi:.3f}]" if lo is not None and hi is not None
                         else f"{v:.3f} [too few frames]")
        params = (f"Δd {e.step_mm:g} d_max {e.max_depth_mm:g} ρ {e.rho_thr:g}" if e.method == "zcut"
                  else f"k {e.sor_k} std {e.sor_std_ratio:g}")
        return f"  {name:10s} {params:32s} " + "  ".join(f"{c:>22s}" for c in cells)

    print(f"{summary.frames} frame(s) scored over the {summary.region} region; objective {summary.objective}")
    if summary.bin_flagged:
        shown = ", ".join(str(f) for f in summary.bin_flagged[:10])
        print(f"warning: {len(summary.bin_flagged)} scored frame(s) flagged by the bin check (their scores rest on "
              f"a bin removal that did not work): {shown}" + (" …" if len(summary.bin_flagged) > 10 else ""),
              file=sys.stderr)
    print(f"  {'':10s} {'parameters':32s} " + "  ".join(f"{h:>22s}" for h in ("precision", "recall", "F1")))
    print(row("chosen", summary.chosen_zcut))
    print(row("nominal", summary.nominal))
    print(row("tuned", summary.tuned.zcut))
    print(row("SOR chosen", summary.chosen_sor))
    print(row("SOR tuned", summary.tuned.sor))
    if summary.tuned.note:
        print(f"note: {summary.tuned.note}")
    for line in summary.validation.messages() if summary.validation is not None else ():
        print(f"tuning: {line}")
    if tuned_path is not None:
        print(f"tuned config: {tuned_path}")
