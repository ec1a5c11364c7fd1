"""``zcut sweep``: the z-cut and SOR over a parameter grid, every grid point scored by true accuracy.

Speed comes from reuse, not brute force. Per frame, the bin stages (bin mask, registration, removal)
run once. Per frame and Δd, one component tree (:func:`zcut.zcut_tree`) answers every (d_max, μ_thr)
pair, and scores them without building a mask. Per frame, k and judged region, one d̄ computation
answers every std_ratio (:func:`replay.pipeline.zone.sor_masks_on_zone`). The counts at any grid
point equal those of ``zcut replay`` with the same parameters (the tests check it).

Rows (``sweep.parquet``): one per log × frame × parameter set × method. A z-cut row's parameters
are Δd, d_max, ρ_thr (μ_thr = ρ_thr·a_max); a SOR row's are k and std_ratio, with Δd and d_max
when SOR judges the top of the pile (``sor.region = "top"``: the points within the z-cut's depth).
Besides TP/FP/FN over S = R ∩ region, a z-cut row holds its overlap with SOR at the config's own k
and std_ratio (N_both, N1, N2 of docs/accuracy.md), for the paper's relative figures.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from studies.grid import Grid
from studies.scoring import (
    BANK_COLUMNS,
    CONFUSION_COLUMNS,
    COUNT_COLUMNS,
    SOR_COLUMNS,
    ZCUT_COLUMNS,
    Counts,
    parse_objective,
    score,
)
from studies.summary import Overlap, ParamSet, RatioPair, Sensitivities, Tuned, finite_or_none, intervals
from studies.work import Job, UnitResult, run_unit

if TYPE_CHECKING:
    from annotate.truth import FrameTruth
    from replay.logs.frame import Frame
    from replay.pipeline.config import PipelineConfig
    from replay.pipeline.session import ReplaySession
    from replay.pipeline.zone import Zone
    from studies.units import WorkUnit
    from studies.validate import FrameCounts, Validation
    from studies.work import TruthSource

def grid_of(job: Job) -> Grid:
    g = job.extra["grid"]
    return Grid(tuple(g["steps"]), tuple(g["depths"]), tuple(g["rhos"]), tuple(g["sor_ks"]), tuple(g["sor_stds"]),
                tuple(g["chosen"]))


def grid_dict(grid: Grid) -> dict[str, Any]:
    return dataclasses.asdict(grid)


def _row(unit: WorkUnit, frame: Frame, method: str, **kw: Any) -> dict[str, Any]:
    out: dict[str, Any] = {"log": Path(unit.log).name, "log_sha256": unit.sha256, "frame": frame.index,
           "stamp_ns": frame.stamp_ns, "method": method}
    for c in ZCUT_COLUMNS + SOR_COLUMNS + COUNT_COLUMNS:
        out[c] = kw.get(c)
    for c in BANK_COLUMNS:  # the filter bank's (studies.bank)
        out[c] = kw.get(c)
    return out


def sweep_frame(unit: WorkUnit, frame: Frame, zone: Zone, config: PipelineConfig, grid: Grid, truth: FrameTruth,
                region: np.ndarray, bank: dict[str, list[dict[str, Any]]] | None = None) -> list[dict[str, Any]]:
    """Every grid point of one frame (see the module docstring); ``bank``: the filter bank's sets
    (:func:`studies.bank.make_bank_grid`)."""
    from replay.pipeline.zone import sor_masks_on_zone, sor_region
    from zcut import zcut_tree

    rows: list[dict[str, Any]] = []
    z = config.zcut
    L = truth.outliers
    S = truth.reviewed & region
    easy = zone.easy
    a_max = z.a_max
    areas = [r * a_max for r in grid.rhos] if a_max is not None else [z.max_area]
    rhos = list(grid.rhos) if a_max is not None else [None]
    whole = zone.removal is None and config.sor.region == "zone"
    top = config.sor.region == "top"
    sor_cache: dict[Any, np.ndarray] = {}

    def sor_masks(k: int, judged: np.ndarray) -> np.ndarray:
        key = (k, judged.tobytes()) if top else (k, None)
        if key not in sor_cache:
            sor_cache[key] = sor_masks_on_zone(frame.xyz, judged, whole=whole, k=k,
                                               convention=config.sor.convention, std_ratios=grid.sor_stds)
        return sor_cache[key]

    def counts(pred: np.ndarray) -> dict[str, int | None]:
        return Counts.of(pred, L, S).columns()

    k0, std0 = config.sor.k, config.sor.std_ratio
    with_sor = config.sor.enabled and "sor" in config.base_methods  # SOR as the replay runs it, or not at all
    for step in grid.steps:
        tree = zcut_tree(zone.height_mm, step=step, max_depth=max(grid.depths), connectivity=z.connectivity)
        c = tree.counts(grid.depths, areas, truth=L, scored=S, within=zone.zone, plus=easy)
        for i, depth in enumerate(grid.depths):
            params = dataclasses.replace(z, step=step, max_depth=depth)
            judged = sor_region(zone.height_mm, zone.zone, params) if top else zone.zone
            # SOR at the config's own k and std_ratio, for the relative figures (zone-only masks,
            # as the replay computes α and β)
            if not with_sor:
                s_ref = np.zeros_like(zone.zone)
            elif std0 in grid.sor_stds and k0 in grid.sor_ks:
                s_ref = sor_masks(k0, judged)[grid.sor_stds.index(std0)]
            else:
                s_ref = sor_masks_on_zone(frame.xyz, judged, whole=whole, k=k0, convention=config.sor.convention,
                                          std_ratios=[std0])[0]
            ov = tree.counts([depth], areas, truth=s_ref, scored=zone.zone, within=zone.zone)
            n_sor = int(np.count_nonzero(s_ref))
            for j, (rho, area) in enumerate(zip(rhos, areas)):
                both = int(ov["tp"][0, j])
                counted = Counts(tp=int(c["tp"][i, j]), fp=int(c["fp"][i, j]), fn=int(c["fn"][i, j]),
                                 n_pred=int(c["n_pred"][i, j]), n_both=both, n_sor_only=n_sor - both,
                                 n_zcut_only=int(ov["fp"][0, j]))
                rows.append(_row(unit, frame, "zcut", step_mm=step, max_depth_mm=depth, rho_thr=rho, max_area_px=area,
                                 **counted.columns()))
            if with_sor and (top or (step == grid.steps[0] and i == 0)):
                for k in grid.sor_ks:
                    masks = sor_masks(k, judged)
                    for std, m in zip(grid.sor_stds, masks):
                        extra = {"step_mm": step, "max_depth_mm": depth} if top else {}
                        rows.append(_row(unit, frame, "sor", sor_k=k, sor_std_ratio=std, **extra,
                                         **counts(m | easy)))
    bank = bank or {}
    if bank or any("+" in m for m in config.methods):
        from studies.bank import bank_rows

        base_seconds: dict[str, float] = {}
        rows += bank_rows(lambda m, **kw: _row(unit, frame, m, **kw), frame, zone, config, bank, truth, S,
                          base_seconds)
        for r in rows:
            r["part"] = config.part
            if r["method"] in base_seconds:
                r["seconds"] = base_seconds[r["method"]]
    # the bin check of the frame, on each of its rows (the bin stages run once per frame: every
    # parameter set rests on the same removal)
    check = zone.bin_check
    for r in rows:
        r["bin_check"] = None if check is None or not np.isfinite(check.value) else float(check.value)
        r["bin_flagged"] = check is not None and check.flagged
    return rows


def run_sweep_unit(unit: WorkUnit, job: Job) -> UnitResult:
    """The grid over the unit's frames (``job.extra["grid"]``)."""
    grid = grid_of(job)

    def body(res: UnitResult, session: ReplaySession, truth_src: TruthSource) -> None:
        zones = session.zones(frames=(unit.start, unit.stop))
        try:
            for frame, zone in zones:
                t = truth_src.truth(frame, zone.located.valid)
                res.frames += 1
                if isinstance(t, str):
                    res.unscored.append({"index": frame.index, "stamp_ns": frame.stamp_ns, "reason": t})
                    continue
                rows = sweep_frame(unit, frame, zone, session.config, grid, t, _region(zone, job.region),
                                   job.extra.get("bank"))
                for r in rows:  # which truth scored it (docs/accuracy.md, "Two truths")
                    r["truth"] = truth_src.choice
                res.rows += rows
        finally:
            zones.close()
            res.damage = list(zones.damage)

    return run_unit(unit, job, body)


def _region(zone: Zone, name: str) -> np.ndarray:
    """The scored region of :func:`annotate.truth.scored_region`, from the zone (before the filters)."""
    valid: np.ndarray = zone.located.valid
    if name == "valid":
        return valid
    judged: np.ndarray = zone.zone | zone.easy
    return judged


# ----------------------------------------------------------------------------------- the summary


def _set_key(cols: dict[str, list[Any]], i: int) -> tuple[Any, ...]:
    """A parameter set: the method and its parameters (μ_thr only when ρ_thr is not known: across logs
    of other parts, one ρ_thr is one set whatever a_max each log has)."""
    key = [cols["method"][i]] + [cols[c][i] for c in ZCUT_COLUMNS + SOR_COLUMNS]
    if key[3] is not None:  # rho_thr known: max_area_px is per log
        key[4] = None
    return tuple(key)


def pooled_sets(table: Any) -> list[ParamSet]:
    """Per parameter set and method: pooled counts, precision/recall/F1 with 95 % intervals over frames
    (:func:`zcut.metrics.pooled_interval_many`; None where too few frames, the same rule for every
    set), and for the z-cut the relative figures N_both, N1, N2, α, β (docs/accuracy.md); sorted by method and
    parameters."""
    from zcut.metrics import pooled_interval_many, ratio

    cols = table.to_pydict()
    n = table.num_rows
    groups: dict[tuple[Any, ...], list[int]] = {}
    for i in range(n):
        if cols["method"][i] not in ("zcut", "sor"):  # the filter bank's sets: studies.bank
            continue
        groups.setdefault(_set_key(cols, i), []).append(i)
    out = []
    by_frames: dict[int, list[tuple[tuple[Any, ...], list[int]]]] = {}
    for key, idx in groups.items():
        by_frames.setdefault(len(idx), []).append((key, idx))
    for n_frames, items in by_frames.items():
        arr = {c: np.array([[cols[c][i] for i in idx] for _, idx in items], dtype=np.int64)
               for c in CONFUSION_COLUMNS}
        cis = pooled_interval_many(arr["tp"], arr["fp"], arr["fn"])
        for j, (key, idx) in enumerate(items):
            T, F, N = (int(arr[c][j].sum()) for c in CONFUSION_COLUMNS)
            overlap = None
            if key[0] == "zcut":
                both = sum(cols["n_both"][i] for i in idx)
                n1 = sum(cols["n_sor_only"][i] for i in idx)
                n2 = sum(cols["n_zcut_only"][i] for i in idx)
                overlap = Overlap(both, n1, n2, finite_or_none(ratio(n1, n2)), finite_or_none(ratio(both, n1)),
                                  finite_or_none(ratio(both, n2)))
            params = dict(zip(ZCUT_COLUMNS + SOR_COLUMNS, key[1:]))
            out.append(ParamSet(
                method=key[0], **params, frames=n_frames, tp=T, fp=F, fn=N,
                n_pred=sum(cols["n_pred"][i] for i in idx), precision=_r(T, T + F), recall=_r(T, T + N),
                f1=_r(2 * T, 2 * T + F + N), ci95=intervals({k: v[j] for k, v in cis.items()}), overlap=overlap))
    out.sort(key=lambda e: (e.method, *[(-1 if e.param(c) is None else e.param(c)) for c in ZCUT_COLUMNS + SOR_COLUMNS]))
    return out


def _r(a: int, b: int) -> float | None:
    return a / b if b else None


def section_5_4_ranges(part: str | None) -> dict[str, tuple[float, float]] | None:
    """The paper's §5.4 ranges for the part (None when the part is unknown)."""
    if part is None:
        return None
    from replay.presets import BIN, PART_KINDS
    from zcut.params import MAX_DEPTH_RANGE, RHO_THR_RANGE, STEP_RANGE

    p = PART_KINDS[part].p_min_mm
    return {"step_mm": (STEP_RANGE[0] * p, STEP_RANGE[1] * p),
            "max_depth_mm": (MAX_DEPTH_RANGE[0] * p, max(MAX_DEPTH_RANGE[1] * BIN.height_mm, p)),
            "rho_thr": RHO_THR_RANGE}


def _inside(e: ParamSet, ranges: dict[str, tuple[float, float]] | None) -> bool:
    if ranges is None:
        return True
    eps = 1e-9
    return all((v := e.param(c)) is not None and lo * (1 - eps) <= v <= hi * (1 + eps)
               for c, (lo, hi) in ranges.items())


def tune(sets: list[ParamSet], objective: tuple[str, float | None], *, part: str | None) -> Tuned:
    """The best z-cut set within the §5.4 ranges (all sets when none lies inside, said so) and the best
    SOR set, by the objective."""
    ranges = section_5_4_ranges(part)
    zc = [e for e in sets if e.method == "zcut"]
    inside = [e for e in zc if _inside(e, ranges)]
    note = None
    if ranges is None:
        note = "the part is unknown: the §5.4 ranges cannot be applied, every z-cut set was a candidate"
        pool = zc
    elif not inside:
        note = "no z-cut set of the grid lies within the §5.4 ranges: every set was a candidate"
        pool = zc
    else:
        pool = inside
    best_z = max(pool, key=lambda e: score(e, objective), default=None)
    best_s = max((e for e in sets if e.method == "sor"), key=lambda e: score(e, objective), default=None)
    if best_z is not None and score(best_z, objective) == -math.inf:
        note = (note + "; " if note else "") + "no z-cut set meets the objective's floor"
        best_z = None
    if best_z is not None and pool is inside:
        anywhere = max(zc, key=lambda e: score(e, objective))
        if anywhere is not best_z and score(anywhere, objective) > score(best_z, objective):
            note = (note + "; " if note else "") + outside_note(anywhere, best_z, ranges, objective)
    return Tuned(best_z, best_s, ranges, note)


def outside_note(anywhere: ParamSet, inside: ParamSet, ranges: dict[str, tuple[float, float]] | None,
                 objective: tuple[str, float | None]) -> str:
    """What the tuned z-cut set leaves out: the grid's best set lies outside the paper's §5.4 ranges
    (which of them, and what it scores against the set within them). The ranking of the filter bank
    takes each method's best set anywhere in the grid, so its z-cut row is that set."""
    names = {"step_mm": "Δd", "max_depth_mm": "d_max", "rho_thr": "ρ"}
    out = [f"{names[c]} {v:g}" + ("" if ranges is None or lo * (1 - 1e-9) <= v <= hi * (1 + 1e-9)
                                  else f" (range {lo:g}–{hi:g})")
           for c, (lo, hi) in (ranges or {}).items() for v in (anywhere.param(c),) if v is not None]

    def fig(e: ParamSet) -> str:
        f1 = e.figure("f1")
        return "F1 -" if f1 is None else f"F1 {float(f1):.3f}"

    by = "" if objective[0] == "f1" else f" by {objective[0]}"
    return (f"the grid's best z-cut set{by} lies outside the paper's §5.4 ranges — {', '.join(out)} — {fig(anywhere)} "
            f"against {fig(inside)} for the set within them (tuned.toml keeps the set within the ranges; the "
            "ranking's z-cut row is the set outside them)")


def sensitivity_at(sets: list[ParamSet], point: tuple[float | None, float | None, float | None]) -> Sensitivities | None:
    """θ (ρ_thr) and ω (d_max) of docs/accuracy.md around a z-cut point (step, depth, rho), for both methods,
    from the grid's sets at 0.5× and 1.5× (None when the grid lacks them)."""
    from zcut.metrics import sensitivity

    step, depth, rho = point
    mid = find_set(sets, "zcut", step, depth, rho)
    if mid is None or mid.overlap is None or depth is None:
        return None
    out: Sensitivities = {}
    pairs = [("omega", find_set(sets, "zcut", step, 0.5 * depth, rho), find_set(sets, "zcut", step, 1.5 * depth, rho))]
    if rho is not None:  # θ needs ρ_thr (a_max known); ω does not
        pairs.insert(0, ("theta", find_set(sets, "zcut", step, depth, 0.5 * rho),
                         find_set(sets, "zcut", step, depth, 1.5 * rho)))
    for name, lo, hi in pairs:
        if lo is None or hi is None or lo.overlap is None or hi.overlap is None:
            continue
        for n, key in ((1, "n1"), (2, "n2")):
            s = sensitivity(getattr(lo.overlap, key), getattr(mid.overlap, key), getattr(hi.overlap, key))
            out[f"{name}_{n}"] = RatioPair(finite_or_none(s.lo), finite_or_none(s.hi))
    return out or None


def find_set(sets: list[ParamSet] | tuple[ParamSet, ...], method: str, step: float | None, depth: float | None,
             rho: float | None) -> ParamSet | None:
    """The ``method`` set at (Δd, d_max, ρ_thr) (the first one: a SOR set judging the whole zone has none)."""
    for e in sets:
        if e.method == method and _close(e.step_mm, step) and _close(e.max_depth_mm, depth) and _close(e.rho_thr, rho):
            return e
    return None


def find_sor_set(sets: list[ParamSet] | tuple[ParamSet, ...], k: int, std: float, step: float | None,
                 depth: float | None) -> ParamSet | None:
    """The SOR set (k, std_ratio), at (Δd, d_max) when SOR judges the top of the pile."""
    for e in sets:
        if e.method == "sor" and e.sor_k == k and _close(e.sor_std_ratio, std) \
                and (e.step_mm is None or (_close(e.step_mm, step) and _close(e.max_depth_mm, depth))):
            return e
    return None


def _close(a: float | None, b: float | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return abs(a - b) <= 1e-9 * max(1.0, abs(a), abs(b))


# ------------------------------------------------------------------------- out of sample (validate.py)
def frame_counts(table: Any, zsets: list[ParamSet] | tuple[ParamSet, ...]) -> FrameCounts:
    """The z-cut sets' per-frame counts of the sweep's table, sets in the order of ``zsets`` (the
    frames: every scored (log, frame), in log and frame order; a set without a row for a frame counts 0)."""
    from studies.validate import FrameCounts

    cols = table.to_pydict()
    frame_ids = sorted({(cols["log_sha256"][i], cols["frame"][i]) for i in range(table.num_rows)})
    col_of = {f: j for j, f in enumerate(frame_ids)}
    row_of = {_set_key_of(e): i for i, e in enumerate(zsets)}
    counts = np.zeros((3, len(zsets), len(frame_ids)), dtype=np.int64)
    name = {}
    for i in range(table.num_rows):
        if cols["method"][i] != "zcut":
            continue
        r = row_of.get(_set_key(cols, i))
        if r is None:
            continue
        j = col_of[(cols["log_sha256"][i], cols["frame"][i])]
        counts[:, r, j] = cols["tp"][i], cols["fp"][i], cols["fn"][i]
        name[cols["log_sha256"][i]] = cols["log"][i]
    return FrameCounts(tuple(_zparams(zsets)), tuple(name.get(sha, sha) for sha, _ in frame_ids), tuple(int(f) for _, f in frame_ids),
                       counts[0], counts[1], counts[2])


def _set_key_of(e: ParamSet) -> tuple[Any, ...]:
    """:func:`_set_key` of a pooled set."""
    return (e.method, e.step_mm, e.max_depth_mm, e.rho_thr, e.max_area_px if e.rho_thr is None else None, e.sor_k,
            e.sor_std_ratio)


def validate_tuning(table: Any, sets: list[ParamSet], tuned: Tuned, objective: tuple[str, float | None], *,
                    point: tuple[float | None, ...], rule: str | None = None) -> tuple[Tuned, Validation]:
    """Cross-validate the z-cut's tuning over the table's frames (:mod:`studies.validate`) and pick the
    tuned z-cut set by its rule (``tuned.zcut`` replaced; the SOR set as it was).

    ``point``: the config's own (Δd, d_max, ρ_thr, μ_thr); the reference is the paper's nominal set
    when the grid holds it, else the config's own."""
    from studies.validate import RULE, cross_validate

    zsets = [e for e in sets if e.method == "zcut"]
    ranges = tuned.ranges
    cand = np.array([_inside(e, ranges) for e in zsets], dtype=bool)
    if not cand.any():  # as tune(): every set is a candidate when none lies inside the ranges
        cand[:] = True
    ref_set, ref_name = find_set(zsets, "zcut", 0.2, 30.0, 0.07), "nominal"
    if ref_set is None:
        ref_set, ref_name = find_set(zsets, "zcut", point[0], point[1], point[2]), "chosen"
    ref = next((i for i, e in enumerate(zsets) if e is ref_set), None)
    v = cross_validate(frame_counts(table, zsets), objective=objective, candidates=cand, point=point, reference=ref,
                       reference_name=ref_name if ref is not None else None, rule=rule or RULE)
    if v.tuned is None or tuned.zcut is None:
        return tuned, v
    pick = next(e for e, p in zip(zsets, _zparams(zsets)) if p == v.tuned)
    return dataclasses.replace(tuned, zcut=pick), v


def _zparams(zsets: list[ParamSet] | tuple[ParamSet, ...]) -> list[tuple[float | None, ...]]:
    """(Δd, d_max, ρ_thr, μ_thr) of each z-cut set, as :class:`studies.validate.FrameCounts` holds them."""
    return [(e.step_mm, e.max_depth_mm, e.rho_thr, e.max_area_px) for e in zsets]


# ------------------------------------------------------------------ the sweep as a library call
# (below the scoring it calls; the steps that need none of it are studies/sweep_run.py)
from studies.sweep_run import SweepOptions as SweepOptions  # noqa: E402 - run's options and result
from studies.sweep_run import SweepResult as SweepResult  # noqa: E402

if TYPE_CHECKING:
    from contextlib import ExitStack

    from studies.driver import LogPlan
    from studies.parts import PartStore
    from studies.summary import SweepSummary


def run(options: SweepOptions) -> SweepResult:
    """Run the parameter study ``options`` describe (docs/studies.md), continuing one begun in its folder.

    Writes ``sweep.parquet``, ``summary.json``, ``tuned.toml`` and (``options.report``) the plots and
    ``report.html`` into ``options.out``; says on stderr what runs and how far it is. The output folder
    stays locked until the tables are written. Raises :class:`~zcut.errors.ZcutError` for options or
    inputs no work can start from (``zcut sweep`` exits 1)."""
    from contextlib import ExitStack

    with ExitStack() as stack:
        return _run(options, stack)


def _run(options: SweepOptions, stack: ExitStack) -> SweepResult:
    import time

    from replay.errors import ConfigError
    from studies.driver import check_study_options, named_as_now
    from studies.schemas import SWEEP_COLUMNS, conform
    from studies.sweep_run import check_truth, grid_axes, sweep_logs

    t0 = time.perf_counter()
    check_study_options(options)
    objective = parse_objective(options.objective)
    axes, bank_axes = grid_axes(options)
    overrides = options.pipeline.overrides()
    logs = sweep_logs(options.inputs)  # results files: their source log (the filtered cloud lost its outliers)
    check_truth(logs, labels=options.labels, topic=options.pipeline.topic,
                truth=options.truth)  # the truth exists before any work
    plans, store, grid, bank, results = _run_units(options, stack, logs, overrides, axes, bank_axes)
    table = conform(named_as_now(store.table(), plans), SWEEP_COLUMNS)
    if table.num_rows:
        table = table.sort_by([("log_sha256", "ascending"), ("frame", "ascending"), ("method", "ascending")])
    store.write_table("sweep.parquet", table)
    if not table.num_rows:
        failed = [f"{Path(str(r.unit.log)).name}: {r.error}" for r in results if r.error]
        failed += [f"{Path(str(p.path)).name}: {p.error}" for p in plans if p.error]
        if failed:  # the frames were lost, not truthless: data loss (as batch), naming what failed
            more = f" (and {len(failed) - 1} more)" if len(failed) > 1 else ""
            return SweepResult(store.root, None, failure=f"{failed[0]}{more}")
        raise ConfigError("no frame was scored (no truth in any frame): nothing to sum up")
    summary, tuned_path = _sum_up(options, objective, store, plans, grid, bank, results, table, t0)
    return SweepResult(store.root, summary, tuned_path)


def _run_units(options: SweepOptions, stack: ExitStack, logs: list[str], overrides: dict[str, Any],
               axes: dict[str, Any], bank_axes: dict[str, dict[str, tuple[float, ...]]]
               ) -> tuple[list[LogPlan], PartStore, Grid, dict[str, Any], list[UnitResult]]:
    """Plan the logs, make the grid, lock the folder and run every unit not done yet: (plans, store, grid,
    bank, this run's unit results)."""
    from replay.errors import ConfigError
    from studies.bank import make_bank_grid, n_bank_sets
    from studies.driver import check_labels, plan_logs, run_planned, study_options
    from studies.grid import make_grid

    plans = plan_logs(logs, config_file=options.pipeline.config, overrides=overrides, topic=options.pipeline.topic,
                      frames_per_unit=options.frames_per_unit, whole=False, bin_model=options.pipeline.bin_model)
    check_labels(options.labels, options.annotator, plans)  # as zcut accuracy: before any work
    base = _first_config(plans)
    grid = make_grid(**axes, config=base, max_points=options.max_points, force=options.force,
                     study_points=options.study_points)
    bank = make_bank_grid(bank_axes, base)
    ident = study_options(options, overrides) | {"grid": grid.as_dict()} | ({"bank": bank} if bank else {})
    with_sor = base.sor.enabled and "sor" in base.base_methods
    n_sets = grid.n_zcut + (grid.n_sor(per_depth=base.sor.region == "top") if with_sor else 0)
    n_bank = n_bank_sets(bank)
    if n_sets + n_bank > options.max_points and not options.force:
        raise ConfigError(f"the grid has {n_sets + n_bank} parameter sets (more than {options.max_points}): "
                          "narrow it, or use --force")
    # the executor is made once every input is checked (a Ray cluster is connected to then): bad input is one
    # line before anything starts
    store, results, _ = run_planned(
        "sweep", options, stack, plans, ident, overrides=overrides, fn=run_sweep_unit,
        extra={"grid": grid_dict(grid), "bank": bank}, per_frame=len(grid.steps), progress_what="frames × Δd",
        what=f"{n_sets + n_bank} parameter sets ({grid.n_zcut} z-cut, {n_sets - grid.n_zcut} "
             f"SOR{f', {n_bank} of the filter bank' if n_bank else ''}), ")
    return plans, store, grid, bank, results


def _first_config(plans: list[LogPlan]) -> PipelineConfig:
    """The resolved config of the first log with units (the grid's base)."""
    first = next(p for p in plans if p.units)
    assert first.resolved is not None  # a log with units was resolved
    config: PipelineConfig = first.resolved.config
    return config


def _sum_up(options: SweepOptions, objective: tuple[str, float | None], store: PartStore, plans: list[LogPlan],
            grid: Grid, bank: dict[str, Any], results: list[UnitResult], table: Any, t0: float
            ) -> tuple[SweepSummary, Path | None]:
    """Pool, tune and validate; write ``summary.json``, ``tuned.toml`` and the report."""
    import time

    from threadpoolctl import threadpool_limits

    from studies.bank import ranking
    from studies.summary import DamageNote, SweepLog, SweepSummary, UnscoredFrame, truth_summary, truths_by_log
    from studies.sweep_run import flagged_frames, reproduce, write_tuned

    first = next(p for p in plans if p.units)
    base = _first_config(plans)
    with threadpool_limits(limits=1, user_api="blas"):  # OpenBLAS's spinning threads cost ~20x here
        sets = pooled_sets(table)
    tuned = tune(sets, objective, part=base.part)
    chosen = grid.chosen
    point = (chosen[0], chosen[1], chosen[2], base.zcut.max_area if chosen[2] is None else None)
    tuned, validation = validate_tuning(table, sets, tuned, objective, point=point)
    metas = store.metas().values()
    by_log = truths_by_log(table)
    summary = SweepSummary(
        logs=tuple(SweepLog(str(p.path), p.sha256, p.error, by_log.get(p.sha256)) for p in plans),
        frames=len(set(zip(table.column("log_sha256").to_pylist(), table.column("frame").to_pylist()))),
        region=options.region, objective=options.objective, truth=truth_summary(by_log),
        grid=grid, config=first.config_toml, notes=tuple(first.notes), sets=tuple(sets), tuned=tuned,
        chosen_zcut=find_set(sets, "zcut", chosen[0], chosen[1], chosen[2]),
        chosen_sor=find_sor_set(sets, chosen[3], chosen[4], chosen[0], chosen[1]),
        nominal=find_set(sets, "zcut", 0.2, 30.0, 0.07),
        sensitivity_chosen=sensitivity_at(sets, chosen[:3]),
        sensitivity_tuned=(sensitivity_at(sets, (tuned.zcut.step_mm, tuned.zcut.max_depth_mm, tuned.zcut.rho_thr))
                           if tuned.zcut else None),
        damage=tuple(DamageNote(Path(m["log"]).name, d) for m in metas for d in m["damage"]),
        errors=tuple(f"{r.unit.log}: {r.error}" for r in results if r.error),
        unscored=tuple(UnscoredFrame(Path(m["log"]).name, u.get("index"), u.get("stamp_ns"), u.get("reason"))
                       for m in metas for u in m["unscored"]),
        reproduce=reproduce(options), seconds=time.perf_counter() - t0, bin_flagged=flagged_frames(table),
        validation=validation,
        ranking=ranking(table, objective) if (bank or any("+" in m for m in base.methods)) else None,
    )
    store.write_json("summary.json", summary.to_json())
    tuned_path = write_tuned(store, base, tuned, options.objective, validation, summary.ranking)
    if options.report:
        from studies.report import write_report

        write_report(store.root, summary)
    return summary, tuned_path
