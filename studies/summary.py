"""The typed summaries of ``zcut sweep`` and ``zcut batch``, and their JSON form (``summary.json``).

Built once from the tables (:func:`studies.sweep.pooled_sets`, :func:`studies.sweep.tune`,
:func:`studies.batch.summary`), used as records by the report and the commands' printouts, and
serialised only at the edge: :meth:`SweepSummary.to_json` / :meth:`BatchSummary.to_json` give the
exact ``summary.json`` layout that other tools read (``docs/studies.md``), and
:meth:`SweepSummary.from_json` reads one back (the report of an earlier sweep; a hand-edited or
older file with missing fields gives a summary, never an error).

Conventions: an undefined figure (0/0, x/0, NaN) is None in the records as in JSON; a 95 %
interval is ``(lo, hi)``, each None when undefined; counts are pixels.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from studies.grid import Grid
from studies.validate import Validation

#: The figures that carry an interval, in their JSON order.
METRICS = ("precision", "recall", "f1")
#: The parameter columns of a set (and of the sweep's table), in their JSON order.
PARAMETERS = ("step_mm", "max_depth_mm", "rho_thr", "max_area_px", "sor_k", "sor_std_ratio")

Interval = tuple[float | None, float | None]
Json = dict[str, Any]


def finite_or_none(v: Any) -> float | None:
    """A number as float, None when it is None, NaN or ±inf."""
    if v is None:
        return None
    f = float(v)
    return f if math.isfinite(f) else None


def _number(v: Any) -> Any:
    """A JSON number as it is, None for NaN and ±inf (ints stay ints)."""
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def intervals(ci: Mapping[str, Sequence[Any]] | None) -> dict[str, Interval]:
    """``{figure: (lo, hi)}`` with undefined bounds as None (from an interval or from JSON)."""
    out: dict[str, Interval] = {}
    for k, v in (ci or {}).items():
        lo, hi = (tuple(v) + (None, None))[:2] if v is not None else (None, None)
        out[k] = (finite_or_none(lo), finite_or_none(hi))
    return out


def _intervals_json(ci: Mapping[str, Interval]) -> dict[str, list[float | None]]:
    return {k: [lo, hi] for k, (lo, hi) in ci.items()}


def _opt_int(v: Any) -> int | None:
    return None if v is None else int(v)


def _dict(v: Any) -> Json:
    return v if isinstance(v, dict) else {}


# ------------------------------------------------------------------------------------- a sweep's sets
@dataclass(frozen=True, slots=True)
class Overlap:
    """A z-cut set against SOR at the config's own k and std_ratio (the paper's relative figures).

    ``n_both``: pixels both flag; ``n1``: SOR only; ``n2``: z-cut only; ``alpha = n1 / n2``,
    ``beta_sor = n_both / n1``, ``beta_zcut = n_both / n2`` (None when undefined).
    """

    n_both: int
    n1: int
    n2: int
    alpha: float | None
    beta_sor: float | None
    beta_zcut: float | None


@dataclass(frozen=True, slots=True)
class ParamSet:
    """One parameter set of one method, pooled over every scored frame of a sweep.

    Attributes
    ----------
    method : {"zcut", "sor"}
    step_mm, max_depth_mm, rho_thr, max_area_px : float or None
        The z-cut's Δd, d_max, ρ_thr and μ_thr (μ_thr only when ρ_thr is unknown: across logs of
        other parts one ρ_thr is one set); a SOR set has Δd and d_max when SOR judges the top of the
        pile.
    sor_k : int or None
    sor_std_ratio : float or None
    frames : int
        Frames pooled.
    tp, fp, fn : int
        Pixels of the scored region; ``n_pred``: every pixel flagged.
    precision, recall, f1 : float or None
    ci95 : dict of str to (lo, hi)
        95 % intervals over frames (docs/accuracy.md, Uncertainty) of :data:`METRICS`.
    overlap : Overlap or None
        Z-cut sets only.
    """

    method: str
    step_mm: float | None
    max_depth_mm: float | None
    rho_thr: float | None
    max_area_px: float | None
    sor_k: int | None
    sor_std_ratio: float | None
    frames: int
    tp: int
    fp: int
    fn: int
    n_pred: int
    precision: float | None
    recall: float | None
    f1: float | None
    ci95: dict[str, Interval] = field(default_factory=dict)
    overlap: Overlap | None = None

    def param(self, key: str) -> float | int | None:
        """The value of a parameter column (:data:`PARAMETERS`)."""
        if key not in PARAMETERS:
            raise KeyError(key)
        value: float | int | None = getattr(self, key)
        return value

    def figure(self, key: str) -> float | int | None:
        """A count or figure by its JSON name (``tp``, ``f1``, ``n2``, ``alpha``...), None when undefined
        or absent (the overlap's figures of a SOR set)."""
        if key in ("n_both", "n1", "n2", "alpha", "beta_sor", "beta_zcut"):
            value: float | int | None = getattr(self.overlap, key) if self.overlap is not None else None
        else:
            value = getattr(self, key)
        return value

    def ci(self, metric: str) -> Interval:
        """The 95 % interval of ``metric`` ((None, None) when unknown)."""
        return self.ci95.get(metric, (None, None))

    def to_json(self) -> Json:
        d: Json = {"method": self.method, **{k: getattr(self, k) for k in PARAMETERS}, "frames": self.frames,
                   "tp": self.tp, "fp": self.fp, "fn": self.fn, "n_pred": self.n_pred, "precision": self.precision,
                   "recall": self.recall, "f1": self.f1, "ci95": _intervals_json(self.ci95)}
        if self.overlap is not None:
            o = self.overlap
            d.update(n_both=o.n_both, n1=o.n1, n2=o.n2, alpha=o.alpha, beta_sor=o.beta_sor, beta_zcut=o.beta_zcut)
        return d

    @classmethod
    def from_json(cls, d: Json) -> ParamSet:
        overlap = None
        if d.get("n_both") is not None:
            overlap = Overlap(int(d["n_both"]), int(d.get("n1") or 0), int(d.get("n2") or 0),
                              finite_or_none(d.get("alpha")), finite_or_none(d.get("beta_sor")),
                              finite_or_none(d.get("beta_zcut")))
        return cls(method=str(d.get("method")), step_mm=finite_or_none(d.get("step_mm")),
                   max_depth_mm=finite_or_none(d.get("max_depth_mm")), rho_thr=finite_or_none(d.get("rho_thr")),
                   max_area_px=finite_or_none(d.get("max_area_px")), sor_k=_opt_int(d.get("sor_k")),
                   sor_std_ratio=finite_or_none(d.get("sor_std_ratio")), frames=int(d.get("frames") or 0),
                   tp=int(d.get("tp") or 0), fp=int(d.get("fp") or 0), fn=int(d.get("fn") or 0),
                   n_pred=int(d.get("n_pred") or 0), precision=finite_or_none(d.get("precision")),
                   recall=finite_or_none(d.get("recall")), f1=finite_or_none(d.get("f1")),
                   ci95=intervals(_dict(d.get("ci95"))), overlap=overlap)


def _set_or_none(d: Any) -> ParamSet | None:
    return ParamSet.from_json(d) if isinstance(d, dict) else None


def _set_json(s: ParamSet | None) -> Json | None:
    return None if s is None else s.to_json()


@dataclass(frozen=True, slots=True)
class Tuned:
    """The best sets by the objective (``tuned.toml``): the z-cut's within the paper's §5.4 ranges
    for the part (``ranges``: column -> (lo, hi), None when the part is unknown) and SOR's; ``note``
    says when the ranges could not be applied or no set met the objective's floor."""

    zcut: ParamSet | None
    sor: ParamSet | None
    ranges: dict[str, tuple[float, float]] | None
    note: str | None

    def to_json(self) -> Json:
        return {"zcut": _set_json(self.zcut), "sor": _set_json(self.sor),
                "ranges": None if self.ranges is None else {k: list(v) for k, v in self.ranges.items()},
                "note": self.note}

    @classmethod
    def from_json(cls, d: Any) -> Tuned:
        d = _dict(d)
        ranges = d.get("ranges")
        ranges = ({str(k): (float(v[0]), float(v[1])) for k, v in ranges.items() if isinstance(v, (list, tuple))}
                  if isinstance(ranges, dict) else None)
        note = d.get("note")
        return cls(_set_or_none(d.get("zcut")), _set_or_none(d.get("sor")), ranges,
                   None if note is None else str(note))


@dataclass(frozen=True, slots=True)
class RatioPair:
    """A count's ratios at 0.5× and 1.5× a parameter: the paper's θ (ρ_thr) or ω (d_max); None: x/0 or 0/0."""

    lo: float | None
    hi: float | None


#: θ_1, θ_2 (ρ_thr) and ω_1, ω_2 (d_max) around a point, by name (``theta_1`` ...): those the grid holds.
Sensitivities = dict[str, RatioPair]


def _sensitivities_json(s: Sensitivities | None) -> Json | None:
    return None if s is None else {k: {"lo": v.lo, "hi": v.hi} for k, v in s.items()}


def _sensitivities(d: Any) -> Sensitivities | None:
    if not isinstance(d, dict):
        return None
    return {str(k): RatioPair(finite_or_none(_dict(v).get("lo")), finite_or_none(_dict(v).get("hi")))
            for k, v in d.items()}


# ------------------------------------------------------------------------------------ a sweep's summary
@dataclass(frozen=True, slots=True)
class SweepLog:
    """An input log of a sweep: its path, content hash, why it was left out (None: used) and the truth
    its frames were scored against (``paper``, ``sensor``, ``labels``; None: no frame scored)."""

    log: str
    sha256: str | None
    error: str | None
    truth: str | None = None


def truths_by_log(table: Any) -> dict[str, str]:
    """Per log (content hash), the truth its scored rows were scored against (``paper``, ``sensor``,
    ``labels``; docs/accuracy.md, "Two truths"), from a study table's ``truth`` column."""
    if not table.num_rows or "truth" not in table.column_names:
        return {}
    seen: dict[str, set[str]] = {}
    for sha, t in zip(table.column("log_sha256").to_pylist(), table.column("truth").to_pylist()):
        if t is not None:
            seen.setdefault(sha, set()).add(t)
    return {sha: ", ".join(sorted(ts)) for sha, ts in seen.items()}


#: What each truth of a study's summary is, in words (``synthetic``: summaries written before the paper's truth).
TRUTH_TEXT: dict[str, str] = {
    "paper": "the paper's truth (/ground_truth/off_surface: farther than 3 Err from every true surface)",
    "sensor": "the sensor's truth (/ground_truth/outliers)",
    "labels": "human labels (--labels)",
    "synthetic": "synthetic ground truth (/ground_truth/outliers)",
}


def truth_text(truth: str | None) -> str:
    """A study's truth (:func:`truth_summary`) in words: ``paper, sensor`` says that logs without the
    paper's truth were scored against the sensor's."""
    if not truth:
        return "no truth"
    names = truth.split(", ")
    if set(names) == {"paper", "sensor"}:
        return f"{TRUTH_TEXT['paper']}; the sensor's (/ground_truth/outliers) for the logs without it"
    return "; ".join(TRUTH_TEXT.get(n, n) for n in names)


def truth_summary(by_log: dict[str, str]) -> str:
    """The truth of a study as a whole: ``paper``, ``sensor`` or ``labels`` when every log was scored
    against the same one, else the ones met joined (``paper, sensor``: some logs lack the paper's)."""
    return ", ".join(sorted({t for v in by_log.values() for t in v.split(", ")}))


@dataclass(frozen=True, slots=True)
class DamageNote:
    """Frames a log lost to damage (``log`` None when the summary did not name it)."""

    log: str | None
    note: str

    def __str__(self) -> str:
        return f"{self.log}: {self.note}" if self.log else self.note


@dataclass(frozen=True, slots=True)
class UnscoredFrame:
    """A frame that had no truth to be scored against (``log`` None when the summary did not name it)."""

    log: str | None
    index: int | None
    stamp_ns: int | None
    reason: str

    def __str__(self) -> str:
        where = f"{self.log}: " if self.log else ""
        return f"{where}frame {self.index} (stamp {self.stamp_ns} ns): {self.reason}"


@dataclass(frozen=True, slots=True)
class FlaggedFrame:
    """A scored frame the bin check flagged (``docs/pipeline.md``, "Bin removal"): every parameter
    set's scores on it rest on a bin removal that did not work."""

    log: str
    frame: int

    def __str__(self) -> str:
        return f"{self.log}: frame {self.frame}"


@dataclass(frozen=True, slots=True)
class SweepSummary:
    """What ``zcut sweep`` found (``DIR/summary.json``).

    Attributes
    ----------
    logs : tuple of SweepLog
    frames : int
        Frames scored.
    region, objective, truth : str
        The scored region (``zone`` or ``valid``), the objective (``f1``, ``recall@precision=P``...),
        the truth (:func:`truth_summary`: ``paper``, ``sensor``, ``labels``, or ``paper, sensor`` when
        some logs lack the paper's; ``synthetic`` in summaries written before the paper's truth).
    grid : Grid or None
        The axes and the chosen point (the config's own).
    config : str
        The resolved config of the first log (TOML), which the sweep varied.
    notes : tuple of str
        How that config was resolved.
    sets : tuple of ParamSet
        Every set of both methods, sorted by method and parameters.
    tuned : Tuned
    chosen_zcut, chosen_sor, nominal : ParamSet or None
        The sets at the chosen point (z-cut and SOR) and at the paper's nominal point.
    sensitivity_chosen, sensitivity_tuned : Sensitivities or None
        θ and ω around the chosen and the tuned z-cut points.
    damage : tuple of DamageNote
    errors : tuple of str
        Logs or units that failed.
    unscored : tuple of UnscoredFrame
    bin_flagged : tuple of FlaggedFrame
        The scored frames the bin check flagged.
    reproduce : str
        The command line that reruns the sweep.
    seconds : float or None
        Wall-clock time of the run.
    validation : Validation or None
        The tuning cross-validated (:mod:`studies.validate`): out-of-sample figures, the tuned set
        against the nominal one, the two best sets, the grid's edges.
    """

    logs: tuple[SweepLog, ...]
    frames: int
    region: str
    objective: str
    truth: str
    grid: Grid | None
    config: str
    notes: tuple[str, ...]
    sets: tuple[ParamSet, ...]
    tuned: Tuned
    chosen_zcut: ParamSet | None
    chosen_sor: ParamSet | None
    nominal: ParamSet | None
    sensitivity_chosen: Sensitivities | None
    sensitivity_tuned: Sensitivities | None
    damage: tuple[DamageNote, ...] = ()
    errors: tuple[str, ...] = ()
    unscored: tuple[UnscoredFrame, ...] = ()
    reproduce: str = ""
    seconds: float | None = None
    bin_flagged: tuple[FlaggedFrame, ...] = ()
    validation: Validation | None = None
    #: The filter bank's ranking per part kind (:func:`studies.bank.ranking`), None without a bank.
    ranking: Json | None = None

    @property
    def data_loss(self) -> bool:
        """Frames lost, units failed or logs left out: the command exits 3."""
        return bool(self.damage or self.errors or any(lg.error for lg in self.logs))

    def to_json(self) -> Json:
        """The ``summary.json`` object (keys and values as ``docs/studies.md`` describes them)."""
        d: Json = {
            "logs": [{"log": lg.log, "sha256": lg.sha256, "error": lg.error, "truth": lg.truth} for lg in self.logs],
            "frames": self.frames, "region": self.region, "objective": self.objective, "truth": self.truth,
            "grid": self.grid.as_dict() if self.grid is not None else None, "config": self.config,
            "notes": list(self.notes), "sets": [s.to_json() for s in self.sets], "tuned": self._tuned_json(),
            "chosen": {"zcut": _set_json(self.chosen_zcut), "sor": _set_json(self.chosen_sor)},
            "nominal": _set_json(self.nominal),
            "sensitivity": {"chosen": _sensitivities_json(self.sensitivity_chosen),
                            "tuned": _sensitivities_json(self.sensitivity_tuned)},
            "damage": [{"log": d.log, "note": d.note} if d.log is not None else d.note for d in self.damage],
            "errors": list(self.errors),
            "unscored": [({"log": u.log} if u.log is not None else {}) | {"index": u.index, "stamp_ns": u.stamp_ns,
                                                               "reason": u.reason} for u in self.unscored],
            "reproduce": self.reproduce, "seconds": _number(self.seconds),
            "bin_flagged": [{"log": f.log, "frame": f.frame} for f in self.bin_flagged],
            "validation": None if self.validation is None else self.validation.to_json(),
        }
        if self.ranking is not None:
            d["ranking"] = self.ranking
        return d

    def _tuned_json(self) -> Json:
        """``tuned`` with, on the tuned z-cut set, its out-of-sample figures beside the in-sample ones
        (``f1_out_of_sample``, ``precision_out_of_sample``, ``recall_out_of_sample``, their
        ``ci95_out_of_sample`` and the ``optimism``; ``docs/studies.md``)."""
        d = self.tuned.to_json()
        v = self.validation
        if v is not None and isinstance(d.get("zcut"), dict):
            oos = v.out_of_sample
            d["zcut"] |= {"f1_out_of_sample": oos.get("f1"), "precision_out_of_sample": oos.get("precision"),
                          "recall_out_of_sample": oos.get("recall"),
                          "ci95_out_of_sample": {k: list(ci) for k, ci in v.ci95.items()},
                          "optimism": v.optimism}
        return d

    @classmethod
    def from_json(cls, d: Json) -> SweepSummary:
        """A summary read back from ``summary.json`` (lenient: a missing or malformed field is empty)."""
        chosen = _dict(d.get("chosen"))
        sens = _dict(d.get("sensitivity"))
        seconds = d.get("seconds")
        return cls(
            logs=tuple(SweepLog(str(lg.get("log")), lg.get("sha256"), lg.get("error"), lg.get("truth"))
                       for lg in d.get("logs") or [] if isinstance(lg, dict)),
            frames=int(d.get("frames") or 0), region=str(d.get("region") or "zone"),
            objective=str(d.get("objective") or "f1"), truth=str(d.get("truth") or ""),
            grid=_grid(d.get("grid")), config=str(d.get("config") or ""),
            notes=tuple(str(n) for n in d.get("notes") or []),
            sets=tuple(ParamSet.from_json(e) for e in d.get("sets") or [] if isinstance(e, dict)),
            tuned=Tuned.from_json(d.get("tuned")), chosen_zcut=_set_or_none(chosen.get("zcut")),
            chosen_sor=_set_or_none(chosen.get("sor")), nominal=_set_or_none(d.get("nominal")),
            sensitivity_chosen=_sensitivities(sens.get("chosen")), sensitivity_tuned=_sensitivities(sens.get("tuned")),
            damage=tuple(DamageNote(x.get("log"), str(x.get("note"))) if isinstance(x, dict) else DamageNote(None, str(x))
                         for x in d.get("damage") or []),
            errors=tuple(str(x) for x in d.get("errors") or []),
            unscored=tuple(_unscored(u) for u in d.get("unscored") or []),
            reproduce=str(d.get("reproduce") or ""),
            seconds=float(seconds) if isinstance(seconds, (int, float)) else None,
            bin_flagged=tuple(FlaggedFrame(str(f.get("log")), int(f.get("frame") or 0))
                              for f in d.get("bin_flagged") or [] if isinstance(f, dict)),
            validation=Validation.from_json(d.get("validation")),
            ranking=d["ranking"] if isinstance(d.get("ranking"), dict) else None,
        )


def _unscored(u: Any) -> UnscoredFrame:
    if not isinstance(u, dict):
        return UnscoredFrame(None, None, None, str(u))
    return UnscoredFrame(u.get("log"), _opt_int(u.get("index")), _opt_int(u.get("stamp_ns")), str(u.get("reason")))


_GRID_AXES = ("step_mm", "max_depth_mm", "rho_thr", "sor_k", "sor_std_ratio")


def _grid(d: Any) -> Grid | None:
    if not isinstance(d, dict):
        return None
    chosen = _dict(d.get("chosen"))
    axes = [tuple(d.get(k) or ()) for k in _GRID_AXES]
    return Grid(axes[0], axes[1], axes[2], axes[3], axes[4],
                tuple(chosen.get(k) for k in _GRID_AXES),  # type: ignore[arg-type]
                study_points=bool(d.get("study_points", True)))


# ------------------------------------------------------------------------------------ a batch's summary
@dataclass(frozen=True, slots=True)
class Totals:
    """Sums over every frame of a batch's table (pixels; ``logs`` and ``frames`` counted;
    ``bin_flagged``: frames the bin check flagged, ``bin_flagged_scored`` those of them scored —
    ``docs/pipeline.md``, "Bin removal")."""

    logs: int
    frames: int
    valid_px: int
    zcut: int
    sor: int
    both: int
    above_rim: int
    clusters: int
    bin_flagged: int = 0
    bin_flagged_scored: int = 0

    def to_json(self) -> Json:
        return {k: getattr(self, k) for k in self.__slots__}


@dataclass(frozen=True, slots=True)
class Scores:
    """One method's pooled (micro-averaged) accuracy over the scored frames, with 95 % intervals."""

    tp: int
    fp: int
    fn: int
    precision: float | None
    recall: float | None
    f1: float | None
    ci95: dict[str, Interval]

    def to_json(self) -> Json:
        return {"tp": self.tp, "fp": self.fp, "fn": self.fn, "precision": self.precision, "recall": self.recall,
                "f1": self.f1, "ci95": _intervals_json(self.ci95)}


@dataclass(frozen=True, slots=True)
class BatchLog:
    """One log of a batch: frames done, frames lost (``damage``), frames without truth (``unscored``),
    units or the log that failed (``errors``), the truth its frames were scored against (``truth``:
    ``paper``, ``sensor``, ``labels``; None when none was). ``frames_in_log`` and ``notes`` (how its config was
    resolved) are known for the logs planned in this run (``planned``)."""

    log: str
    sha256: str
    frames: int
    damage: tuple[str, ...]
    unscored: int
    errors: tuple[str, ...]
    frames_in_log: int | None = None
    notes: tuple[str, ...] = ()
    planned: bool = True
    truth: str | None = None

    def to_json(self) -> Json:
        d: Json = {"log": self.log, "sha256": self.sha256}
        if self.planned:
            d["frames_in_log"] = self.frames_in_log
        d.update(frames=self.frames, damage=list(self.damage), unscored=self.unscored, errors=list(self.errors),
                 truth=self.truth)
        if self.planned:
            d["notes"] = list(self.notes)
        return d


@dataclass(frozen=True, slots=True)
class RunCost:
    """What this run of a batch did and cost (units done by an earlier run are not counted)."""

    frames: int
    seconds: float
    frames_per_s: float | None
    cpu_seconds_per_frame: float | None
    peak_rss_mb_per_worker: float | None
    executor: str
    workers: int
    host: str

    def to_json(self) -> Json:
        return {k: _number(getattr(self, k)) for k in self.__slots__}


@dataclass(frozen=True, slots=True)
class BatchSummary:
    """What ``zcut batch`` did (``DIR/summary.json``): totals, pooled accuracy per method over
    ``region`` (empty without truth) against ``truth`` (:func:`truth_summary`; None without truth),
    the logs, whether data was lost, this run's cost."""

    totals: Totals
    region: str | None
    pooled: dict[str, Scores]
    logs: tuple[BatchLog, ...]
    data_loss: bool
    this_run: RunCost
    truth: str | None = None

    def to_json(self) -> Json:
        return {
            "totals": self.totals.to_json(),
            "accuracy": {"region": self.region, "truth": self.truth,
                         "pooled": {m: s.to_json() for m, s in self.pooled.items()}},
            "logs": [lg.to_json() for lg in self.logs],
            "data_loss": self.data_loss,
            "this_run": self.this_run.to_json(),
        }
