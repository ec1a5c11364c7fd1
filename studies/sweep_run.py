"""The sweep as a library call: its options, its result, and the steps of :func:`studies.sweep.run` that
need none of the scoring (the inputs, the truth check, the grid's axes, ``tuned.toml``, the command
that reruns it). ``zcut sweep`` (``cli/commands/sweep.py``) reads its options into a
:class:`SweepOptions` and prints the :class:`SweepResult`; a benchmark or a test calls
``studies.sweep.run(SweepOptions(inputs=(log,), out=folder, step="0.1,0.2"))``.
"""

from __future__ import annotations

import shlex
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from studies.driver import StudyOptions
from studies.grid import DEFAULT_MAX_POINTS

if TYPE_CHECKING:
    from replay.pipeline.config import PipelineConfig
    from studies.parts import PartStore
    from studies.summary import FlaggedFrame, SweepSummary, Tuned
    from studies.validate import Validation


@dataclass(frozen=True, slots=True, kw_only=True)
class SweepOptions(StudyOptions):
    """A parameter study (docs/studies.md); the defaults are ``zcut sweep``'s.

    Attributes
    ----------
    step, max_depth, rho, sor_k, sor_std : str or None
        The grid's axes as the command line spells them: ``a,b,c`` or ``start:stop:count`` (None: the
        config's value, and for d_max and ρ_thr the study points).
    grid : tuple of str
        Axes of the filter bank, ``SECTION.FIELD=LIST`` or ``SECTION=default``.
    study_points : bool
        Add the config's value and 0.5× and 1.5× it on the d_max and ρ_thr axes (θ and ω need them).
    max_points : int
        Refuse a larger grid unless ``force``.
    objective : str
        What ``tuned.toml`` maximises: ``f1``, ``recall@precision=P`` or ``precision@recall=R``.
    report : bool
        Write the plots and ``report.html``.
    """

    frames_per_unit: int = 4
    step: str | None = None
    max_depth: str | None = None
    rho: str | None = None
    sor_k: str | None = None
    sor_std: str | None = None
    grid: tuple[str, ...] = ()
    study_points: bool = True
    max_points: int = DEFAULT_MAX_POINTS
    objective: str = "f1"
    report: bool = True


@dataclass(frozen=True, slots=True)
class SweepResult:
    """What :func:`studies.sweep.run` wrote and found.

    Attributes
    ----------
    out : Path
        The output folder (``sweep.parquet``, ``summary.json``, ``tuned.toml``, the report).
    summary : SweepSummary or None
        ``summary.json``; None when no frame was scored because units of work failed (``failure``).
    tuned_path : Path or None
        ``tuned.toml`` (None when no z-cut set was tuned).
    failure : str or None
        Why no frame was scored: the first failed unit or log, and how many more.
    """

    out: Path
    summary: SweepSummary | None
    tuned_path: Path | None = None
    failure: str | None = None

    @property
    def data_loss(self) -> bool:
        """Frames were lost (``zcut sweep`` exits 3)."""
        return self.failure is not None or (self.summary is not None and self.summary.data_loss)


def source_of_results(path: Path) -> Path | None:
    """The source log a results file names (beside it), when it is one; the path itself otherwise."""
    from annotate.truth import results_metadata

    meta = results_metadata(path)
    if meta is None:
        return path
    src = path.parent / meta.get("source", "")
    return src if meta.get("source") and src.is_file() and src != path else None


def sweep_logs(inputs: tuple[str, ...], *, stream: IO[str] | None = None) -> list[str]:
    """The logs to sweep: the inputs (folders expanded), a results file replaced by its source log."""
    from replay.errors import ConfigError
    from studies.units import expand_logs
    from zcut.errors import ZcutError

    err = sys.stderr if stream is None else stream
    logs = []
    for p in expand_logs(list(inputs)):
        try:
            src = source_of_results(p)
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
    return logs


def check_truth(logs: list[str], *, labels: str | None, topic: str | None, truth: str | None = None) -> None:
    """Without ``labels``, every readable log must carry a recorded truth, and the one asked for
    (``truth``: :func:`annotate.truth.truth_of_log`) when one is (before any work)."""
    from annotate.truth import check_truth as check_truth_name
    from annotate.truth import truth_of_log
    from replay.errors import ConfigError
    from replay.logs import layout
    from replay.logs.reader import LogReader
    from zcut.errors import ZcutError

    check_truth_name(truth)
    if labels is not None:
        if truth is not None:
            raise ConfigError(f"--truth {truth} scores against the logs' recorded truth, --labels against an "
                              "annotator's: give one")
        return
    for log in logs:
        try:
            topics = LogReader(log, cloud_topic=topic).mask_topics
        except ConfigError:
            raise
        except (ZcutError, OSError):
            continue  # unreadable: left out by the planning, with a warning
        if truth_of_log(truth, topics, log) is None:
            raise ConfigError(f"{log} has no {layout.TRUTH_OUTLIERS} (not a synthetic log): label it "
                              "(zcut annotate) and give --labels DB")


def grid_axes(options: SweepOptions) -> tuple[dict[str, Any], dict[str, dict[str, tuple[float, ...]]]]:
    """The z-cut and SOR axes (for :func:`studies.grid.make_grid`) and the filter bank's; an axis of more
    values than ``max_points`` is a grid of more points: refused before it is expanded."""
    from studies.bank import parse_grid_options
    from studies.grid import parse_list

    limit = None if options.force else options.max_points
    axes = dict(steps=parse_list(options.step, name="--step", max_values=limit),
                depths=parse_list(options.max_depth, name="--max-depth", max_values=limit),
                rhos=parse_list(options.rho, name="--rho", max_values=limit),
                sor_ks=parse_list(options.sor_k, name="--sor-k", integer=True, max_values=limit),
                sor_stds=parse_list(options.sor_std, name="--sor-std", max_values=limit))
    return axes, parse_grid_options(options.grid, max_values=limit)


def flagged_frames(table: Any) -> tuple[FlaggedFrame, ...]:
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


def reproduce(options: SweepOptions) -> str:
    """The command line that reruns this sweep."""
    parts = ["zcut", "sweep", *options.inputs, "-o", options.out]
    pipe = options.pipeline
    values = {"step": options.step, "max_depth": options.max_depth, "rho": options.rho, "sor_k": options.sor_k,
              "sor_std": options.sor_std, "objective": options.objective, "labels": options.labels,
              "annotator": options.annotator, "region": options.region, "truth": options.truth, "config": pipe.config,
              "bin_model": pipe.bin_model, "part": pipe.part, "parameters": pipe.parameters, "preset": pipe.preset,
              "topic": pipe.topic, "methods": pipe.methods}
    for opt, v in values.items():
        if v is not None and not (opt == "objective" and v == "f1") and not (opt == "region" and v == "zone"):
            parts += ["--" + opt.replace("_", "-"), str(v)]
    for g in options.grid:
        parts += ["--grid", g]
    if not options.study_points:
        parts.append("--no-study-points")
    return " ".join(shlex.quote(str(p)) for p in parts)


def write_tuned(store: PartStore, base: PipelineConfig, tuned: Tuned, objective: str,
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
        if m in cfg.bank_sections() and row.get("params"):
            tuned_cfg = tuned_cfg.replace(**{m: dataclasses.replace(getattr(base, m), **row["params"])})

    def f(v: float | None) -> str:
        return "-" if v is None else f"{v:.3f}"

    header = (f"zcut sweep: tuned by {objective} over {store.root}\n"
              f"z-cut: precision {f(z.precision)}, recall {f(z.recall)}, F1 {f(z.f1)}"
              + (f"\nz-cut out of sample: F1 {f(validation.f1_out_of_sample)} (cross-validated; rule "
                 f"{validation.rule})" if validation is not None and validation.f1_out_of_sample is not None else "")
              + (f"\nSOR: precision {f(s.precision)}, recall {f(s.recall)}, F1 {f(s.f1)}" if s else "")
              + (f"\nnote: {tuned.note}" if tuned.note else "")
              + (f"\nbest of the ranking by {objective}: {ranked[0]['method']} (precision {f(ranked[0].get('precision'))}, "
                 f"recall {f(ranked[0].get('recall'))}, F1 {f(ranked[0].get('f1'))}); run it with --methods "
                 f"{ranked[0]['method']}" if ranked else ""))
    path = store.root / "tuned.toml"
    from replay.outputs import AtomicOutput

    with AtomicOutput(path) as out:
        out.temp.write_text(cfg.to_toml(tuned_cfg, header=header), encoding="utf-8", errors="backslashreplace")
    return path
