"""How well a sweep's tuning holds on frames it was not tuned on: cross-validation of the tuning.

A set's F1 pooled over the frames it was chosen on is optimistic: out of many sets, the best one is
the best partly by luck. This module estimates what tuning gives on new frames by doing it again
without some of the frames and scoring the choice on them:

- **Folds.** With several logs, the frames of each log form a fold (leave one log out; logs are
  grouped round-robin into :data:`MAX_FOLDS` folds when there are more). With one log, its frames
  in order are cut into up to :data:`MAX_FOLDS` blocks of consecutive frames (neighbouring frames
  of a log look alike: a random split would score a choice on near copies of its training frames).
- **Out of sample.** For each fold, the tuning rule runs on the other folds' pooled counts and the
  set it picks is scored on the fold's frames. Each frame is held out once, so the held-out counts
  form one per-frame table, pooled like any other (``f1_out_of_sample``), with the interval of
  :func:`zcut.metrics.pooled_interval`. Optimism = in-sample F1 of the tuned set − out-of-sample F1.
  (A fixed set pooled over its held-out folds has its in-sample figure: what is estimated is the
  *tuning*, not a set.)
- **The rule** (:data:`RULE`, measured in ``docs/paper_study.md``): ``"best"`` (the default) takes
  the best candidate; ``"one_se"`` takes, among the candidate sets whose objective figure is within
  one standard error of the best's (the standard error of the paired difference over frames), the
  set nearest the config's own values (in grid steps). On the six synthetic part kinds, tuned on
  one seed set and scored on another, ``one_se`` gained nothing (mean test F1 0.597 against 0.604).
- **Against the reference** (the paper's nominal set, else the config's): the paired per-frame
  difference of F1 between the held-out choices and the reference, with a t interval over frames;
  when it holds 0, tuning is indistinguishable from the reference.
- **The two best sets** (by the objective on every frame, the runner-up being the best set whose
  counts differ from the best's on some frame): their paired difference and its standard error; the
  frames that would separate them: the fewest n at which d lies outside its t interval when the
  standard error shrinks as √(m/n) (about m·(1.96·se/d)²).
- **Edges.** When the tuned set is on the end of a swept axis, the grid should be widened that way.

Frames are treated as independent, as the intervals of ``docs/accuracy.md`` do: frames of one log
that look alike make every standard error here too small (``docs/studies.md``).

Pure functions of arrays: no files, no table library, no printing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Folds at most (logs grouped round-robin, or blocks of consecutive frames of one log).
MAX_FOLDS = 5
#: The tuning rule: ``"one_se"`` or ``"best"`` (module docstring; measured in docs/paper_study.md).
RULE = "best"
RULES = ("one_se", "best")
#: Quantile used to plan how many frames separate two sets (normal, 95 % two-sided).
SEPARATE_Q = 1.959963984540054
#: The parameter columns of a z-cut set, in the order :class:`FrameCounts` holds them.
ZCUT_PARAMS = ("step_mm", "max_depth_mm", "rho_thr", "max_area_px")
_OPTION = {"step_mm": "--step", "max_depth_mm": "--max-depth", "rho_thr": "--rho", "max_area_px": "--max-area"}
_UNIT = {"step_mm": " mm", "max_depth_mm": " mm", "rho_thr": "", "max_area_px": " px"}
_SHORT = {"step_mm": "Δd", "max_depth_mm": "d_max", "rho_thr": "ρ_thr", "max_area_px": "μ_thr"}

Params = tuple[float | None, ...]
Json = dict[str, Any]


# ------------------------------------------------------------------------------------------ inputs
@dataclass(frozen=True, slots=True)
class FrameCounts:
    """The z-cut sets' counts per frame (a sweep's table reshaped).

    Attributes
    ----------
    params : tuple of (step_mm, max_depth_mm, rho_thr, max_area_px)
        One per set (:data:`ZCUT_PARAMS`; None where the set has no value).
    logs : tuple of str
        One per frame: the frame's log (its name or content hash).
    frames : tuple of int
        One per frame: its index in the log.
    tp, fp, fn : (n_sets, n_frames) int64 ndarray
    """

    params: tuple[Params, ...]
    logs: tuple[str, ...]
    frames: tuple[int, ...]
    tp: np.ndarray
    fp: np.ndarray
    fn: np.ndarray

    @property
    def n_sets(self) -> int:
        return len(self.params)

    @property
    def n_frames(self) -> int:
        return len(self.frames)


def _params_json(p: Params) -> dict[str, float | None]:
    return dict(zip(ZCUT_PARAMS, p))


def _params_of(d: Any) -> Params:
    d = d if isinstance(d, dict) else {}
    return tuple(_num(d.get(k)) for k in ZCUT_PARAMS)


def _num(v: Any) -> float | None:
    if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
        return float(v)
    return None


def params_text(p: Params) -> str:
    """``Δd 0.2 mm, d_max 30 mm, ρ_thr 0.07`` (μ_thr when ρ_thr is unknown)."""
    parts = []
    for name, v in zip(ZCUT_PARAMS, p):
        if v is None or (name == "max_area_px" and p[2] is not None):
            continue
        parts.append(f"{_SHORT[name]} {v:g}{_UNIT[name]}")
    return ", ".join(parts)


# ------------------------------------------------------------------------------------------ records
@dataclass(frozen=True, slots=True)
class Fold:
    """One fold: the frames held out, the set the rule picked on the others and its held-out F1."""

    logs: tuple[str, ...]
    frames: int
    chosen: Params | None
    f1: float | None
    note: str | None = None

    def to_json(self) -> Json:
        return {"logs": list(self.logs), "frames": self.frames,
                "chosen": None if self.chosen is None else _params_json(self.chosen), "f1": self.f1,
                "note": self.note}

    @classmethod
    def from_json(cls, d: Any) -> Fold:
        d = d if isinstance(d, dict) else {}
        note = d.get("note")
        return cls(tuple(str(x) for x in d.get("logs") or []), int(d.get("frames") or 0),
                   _params_of(d["chosen"]) if isinstance(d.get("chosen"), dict) else None, _num(d.get("f1")),
                   None if note is None else str(note))


@dataclass(frozen=True, slots=True)
class Difference:
    """A paired difference of a figure between two choices over the same frames.

    ``value`` = a − b; ``se`` its standard error over frames; ``ci95`` its 95 % t interval (None when
    fewer than 3 frames or no variation); ``frames_needed``: total frames at which the 95 % interval
    would exclude 0 at this difference and per-frame spread (:func:`frames_to_separate`; None when
    it already does, or never can: equal figures, no spread).
    """

    a: Params
    b: Params
    value: float | None
    se: float | None
    ci95: tuple[float | None, float | None]
    frames: int
    frames_needed: int | None

    @property
    def separated(self) -> bool:
        lo, hi = self.ci95
        return (lo is not None and lo > 0) or (hi is not None and hi < 0)

    def to_json(self) -> Json:
        return {"a": _params_json(self.a), "b": _params_json(self.b), "value": self.value, "se": self.se,
                "ci95": list(self.ci95), "frames": self.frames, "frames_needed": self.frames_needed,
                "separated": self.separated}

    @classmethod
    def from_json(cls, d: Any) -> Difference | None:
        if not isinstance(d, dict):
            return None
        ci = list(d.get("ci95") or [None, None]) + [None, None]
        need = d.get("frames_needed")
        return cls(_params_of(d.get("a")), _params_of(d.get("b")), _num(d.get("value")), _num(d.get("se")),
                   (_num(ci[0]), _num(ci[1])), int(d.get("frames") or 0),
                   int(need) if isinstance(need, int) and not isinstance(need, bool) else None)


@dataclass(frozen=True, slots=True)
class Edge:
    """The tuned set at the end of a swept axis: ``side`` ``"upper"``, ``"lower"`` or ``"both"`` (the
    only value of the axis within the paper's ranges, the grid going on both ways); ``by_ranges``:
    the end of the candidates (the paper's §5.4 ranges), the grid goes on beyond; ``widen_to``: a
    value to add (None when the axis cannot go further, e.g. ρ_thr = 1)."""

    axis: str
    side: str
    value: float
    by_ranges: bool
    widen_to: float | None

    def __str__(self) -> str:
        v = f"{self.value:g}{_UNIT[self.axis]}"
        name = _SHORT[self.axis]
        if self.by_ranges:
            which = {"upper": "largest", "lower": "smallest"}.get(self.side, "only")
            return f"{name} {v} is the {which} value within the paper's §5.4 range: the best may lie outside it"
        how = f"widen {_OPTION[self.axis]} {'upward' if self.side == 'upper' else 'downward'}"
        if self.widen_to is not None:
            how += f" (e.g. add {self.widen_to:g}{_UNIT[self.axis]})"
        return f"{name} {v} is the {'largest' if self.side == 'upper' else 'smallest'} value swept: {how}"

    def to_json(self) -> Json:
        return {"axis": self.axis, "side": self.side, "value": self.value, "by_ranges": self.by_ranges,
                "widen_to": self.widen_to, "text": str(self)}

    @classmethod
    def from_json(cls, d: Any) -> Edge | None:
        if not isinstance(d, dict) or d.get("axis") not in _SHORT or _num(d.get("value")) is None:
            return None
        return cls(str(d["axis"]), d["side"] if d.get("side") in ("upper", "both") else "lower", float(d["value"]),
                   bool(d.get("by_ranges")), _num(d.get("widen_to")))


@dataclass(frozen=True, slots=True)
class Validation:
    """The cross-validation of a sweep's tuning (``summary.json`` ``"validation"``).

    Attributes
    ----------
    rule : str
        :data:`RULE` as run.
    split : {"logs", "frames", "none"}
        Folds of logs, blocks of consecutive frames of one log, or no cross-validation (``note``).
    folds : tuple of Fold
    tuned : Params or None
        The set the rule picks on every frame (the sweep's tuned set).
    best : Params or None
        The set of the best objective figure on every frame.
    f1_in_sample : float or None
        The tuned set's F1 over every frame.
    out_of_sample : dict of str to float or None
        Pooled precision, recall, F1 of the held-out choices.
    ci95 : dict of str to (lo, hi)
        Their 95 % intervals (None bounds: too few frames).
    optimism : float or None
        ``f1_in_sample`` − out-of-sample F1.
    reference_name : str or None
        ``"nominal"`` (the paper's set) or ``"chosen"`` (the config's).
    vs_reference : Difference or None
        Out-of-sample F1 of the held-out choices − the reference's F1, paired over frames.
    two_best : Difference or None
        The best set − the runner-up, in the objective's figure, over every frame.
    edges : tuple of Edge
    note : str or None
        Why there is no cross-validation, or what a fold could not do.
    """

    rule: str
    split: str
    folds: tuple[Fold, ...]
    tuned: Params | None
    best: Params | None
    f1_in_sample: float | None
    out_of_sample: dict[str, float | None]
    ci95: dict[str, tuple[float | None, float | None]]
    optimism: float | None
    reference_name: str | None
    vs_reference: Difference | None
    two_best: Difference | None
    edges: tuple[Edge, ...] = ()
    note: str | None = None

    @property
    def f1_out_of_sample(self) -> float | None:
        return self.out_of_sample.get("f1")

    @property
    def indistinguishable(self) -> bool | None:
        """Tuning does not beat (nor lose to) the reference out of sample (None: not measured)."""
        d = self.vs_reference
        if d is None or d.value is None:
            return None
        if self.tuned is not None and self.tuned == d.b:
            return True
        return not d.separated

    def messages(self) -> list[str]:
        """What the sweep tells the user about its tuning, one sentence each."""
        out = []
        if self.split == "none":
            return [f"no cross-validation: {self.note}"] if self.note else []
        how = (f"{len(self.folds)} folds of logs" if self.split == "logs"
               else f"{len(self.folds)} blocks of consecutive frames")
        f1 = self.f1_out_of_sample
        lo, hi = self.ci95.get("f1", (None, None))
        ci = f" [{lo:.3f}, {hi:.3f}]" if lo is not None and hi is not None else " [too few frames]"
        if f1 is not None and self.f1_in_sample is not None and self.optimism is not None:
            out.append(f"tuned z-cut F1 {self.f1_in_sample:.3f} in sample, {f1:.3f}{ci} out of sample "
                       f"(cross-validated over {how}, rule {self.rule}): optimism {self.optimism:+.3f}")
        d = self.vs_reference
        if d is not None and d.value is not None and self.reference_name:
            name = self.reference_name
            if self.tuned is not None and self.tuned == d.b:
                out.append(f"the tuned set is the {name} set")
            else:
                dlo, dhi = d.ci95
                dci = (f" [{dlo:+.3f}, {dhi:+.3f}]" if dlo is not None and dhi is not None
                       else " (too few frames for an interval)")
                if d.separated:
                    verdict = "beats" if d.value > 0 else "loses to"
                    out.append(f"out of sample, tuning {verdict} the {name} set: F1 {d.value:+.3f}{dci}")
                else:
                    out.append(f"the tuned set is indistinguishable from the {name} one out of sample: "
                               f"F1 {d.value:+.3f}{dci}")
        t = self.two_best
        if t is not None and t.value is not None:
            pair = f"the two best sets ({params_text(t.a)}; {params_text(t.b)}) differ by {t.value:.3f}"
            if t.separated:
                lo, hi = t.ci95
                out.append(pair + f" [{lo:+.3f}, {hi:+.3f}]: the frames separate them")
            elif t.frames_needed is not None:
                out.append(pair + f" ± {t.se or 0:.3f}: about {max(t.frames_needed - t.frames, 1)} more frames "
                           f"({t.frames_needed} in all) would separate them")
            elif t.value == 0 or not t.se:
                out.append(pair + ": no number of frames would separate them at this difference")
            else:
                out.append(pair + f" ± {t.se:.3f}: too few frames to tell")
        out += [str(e) for e in self.edges]
        if self.note:
            out.append(self.note)
        return out

    def to_json(self) -> Json:
        return {"rule": self.rule, "split": self.split, "folds": [f.to_json() for f in self.folds],
                "tuned": None if self.tuned is None else _params_json(self.tuned),
                "best": None if self.best is None else _params_json(self.best),
                "f1_in_sample": self.f1_in_sample, "f1_out_of_sample": self.f1_out_of_sample,
                "out_of_sample": dict(self.out_of_sample), "ci95": {k: list(v) for k, v in self.ci95.items()},
                "optimism": self.optimism, "reference": self.reference_name,
                "vs_reference": None if self.vs_reference is None else self.vs_reference.to_json(),
                "indistinguishable": self.indistinguishable,
                "two_best": None if self.two_best is None else self.two_best.to_json(),
                "edges": [e.to_json() for e in self.edges], "note": self.note, "messages": self.messages()}

    @classmethod
    def from_json(cls, d: Any) -> Validation | None:
        if not isinstance(d, dict):
            return None
        ci: Json = d["ci95"] if isinstance(d.get("ci95"), dict) else {}
        oos: Json = d["out_of_sample"] if isinstance(d.get("out_of_sample"), dict) else {}
        note = d.get("note")
        ref = d.get("reference")
        return cls(
            rule=str(d.get("rule") or RULE), split=str(d.get("split") or "none"),
            folds=tuple(Fold.from_json(f) for f in d.get("folds") or []),
            tuned=_params_of(d["tuned"]) if isinstance(d.get("tuned"), dict) else None,
            best=_params_of(d["best"]) if isinstance(d.get("best"), dict) else None,
            f1_in_sample=_num(d.get("f1_in_sample")), out_of_sample={str(k): _num(v) for k, v in oos.items()},
            ci95={str(k): _pair(v) for k, v in ci.items()}, optimism=_num(d.get("optimism")),
            reference_name=None if ref is None else str(ref),
            vs_reference=Difference.from_json(d.get("vs_reference")), two_best=Difference.from_json(d.get("two_best")),
            edges=tuple(e for e in (Edge.from_json(x) for x in d.get("edges") or []) if e is not None),
            note=None if note is None else str(note))


def _pair(v: Any) -> tuple[float | None, float | None]:
    lo, hi = (list(v) + [None, None])[:2] if isinstance(v, (list, tuple)) else (None, None)
    return _num(lo), _num(hi)


# ------------------------------------------------------------------------------------------ figures
def _parts(metric: str, tp: np.ndarray, fp: np.ndarray, fn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(numerator, denominator) of a figure, per element."""
    if metric == "precision":
        return tp, tp + fp
    if metric == "recall":
        return tp, tp + fn
    return 2 * tp, 2 * tp + fp + fn


def _ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / np.where(den > 0, den, 1), np.nan)


def _scores(T: np.ndarray, F: np.ndarray, N: np.ndarray, objective: tuple[str, float | None]) -> np.ndarray:
    """The objective's value per set from pooled counts (-inf: undefined or below the floor), as
    ``studies.scoring.score`` computes it for one set."""
    T, F, N = (np.asarray(a, dtype=np.float64) for a in (T, F, N))
    p, r, f = _ratio(*_parts("precision", T, F, N)), _ratio(*_parts("recall", T, F, N)), _ratio(*_parts("f1", T, F, N))
    kind, floor = objective
    if kind == "f1":
        out = f
    elif kind == "recall@precision":
        out = np.where(np.isfinite(p) & np.isfinite(r) & (p >= (floor if floor is not None else np.inf)), r, np.nan)
    else:
        out = np.where(np.isfinite(p) & np.isfinite(r) & (r >= (floor if floor is not None else np.inf)), p, np.nan)
    return np.where(np.isfinite(out), out, -np.inf)


def objective_metric(objective: tuple[str, float | None]) -> str:
    """The figure an objective maximises: ``f1``, ``recall`` or ``precision``."""
    return {"f1": "f1", "recall@precision": "recall", "precision@recall": "precision"}.get(objective[0], "f1")


def paired_difference(num_a: np.ndarray, den_a: np.ndarray, num_b: np.ndarray,
                      den_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R_a − R_b of two pooled ratios over the same frames and its standard error over frames.

    R = Σ num / Σ den; linearised, frame i moves R by z_i = (num_i − R·den_i) / Σ den, and the
    difference's variance is m / (m − 1) · Σ (z_a,i − z_b,i)² over the m frames.

    Parameters
    ----------
    num_a, den_a, num_b, den_b : (..., m) float ndarray
        Per-frame numerators and denominators (broadcast against each other).

    Returns
    -------
    (d, se) : (...) float ndarray
        NaN where either ratio is 0/0; se NaN when m < 2.
    """
    sa, sb = den_a.sum(axis=-1), den_b.sum(axis=-1)
    ra, rb = _ratio(num_a.sum(axis=-1), sa), _ratio(num_b.sum(axis=-1), sb)
    with np.errstate(invalid="ignore", divide="ignore"):
        za = (num_a - ra[..., None] * den_a) / sa[..., None]
        zb = (num_b - rb[..., None] * den_b) / sb[..., None]
    z = za - zb
    m = z.shape[-1]
    se = np.sqrt(m / (m - 1) * (z * z).sum(axis=-1)) if m >= 2 else np.full(z.shape[:-1], np.nan)
    return ra - rb, se


def _difference(a: Params, b: Params, num_a: np.ndarray, den_a: np.ndarray, num_b: np.ndarray,
                den_b: np.ndarray) -> Difference:
    from scipy import stats

    d, se = (float(x) for x in paired_difference(num_a.astype(np.float64), den_a.astype(np.float64),
                                                 num_b.astype(np.float64), den_b.astype(np.float64)))
    m = int(num_a.shape[-1])
    ci: tuple[float | None, float | None] = (None, None)
    need = None
    if math.isfinite(d) and math.isfinite(se):
        if m >= 3 and se > 0:
            q = float(stats.t.ppf(0.975, m - 1))
            ci = (d - q * se, d + q * se)
        lo, hi = ci
        if d != 0 and se > 0 and not ((lo is not None and lo > 0) or (hi is not None and hi < 0)):
            need = frames_to_separate(abs(d), se, m)
    return Difference(a, b, d if math.isfinite(d) else None, se if math.isfinite(se) else None, ci, m, need)


def frames_to_separate(d: float, se: float, m: int, *, level: float = 0.95) -> int:
    """The fewest frames n >= 3 at which a difference ``d`` (> 0) whose standard error is ``se`` over
    ``m`` frames would lie outside its t interval, the standard error shrinking as sqrt(m / n)."""
    from scipy import stats

    q = 0.5 + 0.5 * level
    n = max(3, math.ceil(m * (SEPARATE_Q * se / d) ** 2))
    while float(stats.t.ppf(q, n - 1)) * se * math.sqrt(m / n) >= d:
        n += 1
    return n


# ------------------------------------------------------------------------------------------ folds
def folds_of(logs: Sequence[str], frames: Sequence[int], *, max_folds: int = MAX_FOLDS) -> tuple[str, np.ndarray]:
    """The fold of each frame: ``("logs", fold)`` with several logs (one log per fold, round-robin
    into ``max_folds`` folds when more, logs in sorted order), ``("frames", fold)`` with one log
    (blocks of consecutive frames, as even as they go), ``("none", [])`` with fewer than 2 frames."""
    m = len(frames)
    names = sorted(set(logs))
    if len(names) >= 2:
        fold_of = {name: i % max_folds for i, name in enumerate(names)}
        return "logs", np.array([fold_of[lg] for lg in logs], dtype=np.int64)
    if m < 2:
        return "none", np.zeros(0, dtype=np.int64)
    k = min(max_folds, m)
    order = np.argsort(np.asarray(frames), kind="stable")
    fold = np.empty(m, dtype=np.int64)
    fold[order] = (np.arange(m) * k) // m
    return "frames", fold


# ------------------------------------------------------------------------------------------ the rule
def grid_distance(params: Sequence[Params], point: Params) -> np.ndarray:
    """Per set, the grid steps between it and ``point`` (summed over the axes; a value off the grid
    counts from the nearest one)."""
    out = np.zeros(len(params), dtype=np.float64)
    for j in range(len(ZCUT_PARAMS)):
        vals = sorted({v for p in params if (v := p[j]) is not None})
        target = point[j] if j < len(point) else None
        if len(vals) < 2 or target is None:
            continue
        t = int(np.argmin([abs(v - target) for v in vals]))
        idx = {v: i for i, v in enumerate(vals)}
        out += np.array([abs(idx[v] - t) if (v := p[j]) is not None else 0 for p in params], dtype=np.float64)
    return out


def select(tp: np.ndarray, fp: np.ndarray, fn: np.ndarray, *, objective: tuple[str, float | None],
           candidates: np.ndarray, distance: np.ndarray, rule: str = RULE) -> int | None:
    """The set the rule picks on these frames (None when no candidate has a defined figure).

    Parameters
    ----------
    tp, fp, fn : (n_sets, m) int ndarray
        Per-frame counts of every set.
    objective : (kind, floor)
        As ``studies.scoring.parse_objective`` returns it.
    candidates : (n_sets,) bool ndarray
        Sets the rule may pick (within the paper's ranges).
    distance : (n_sets,) float ndarray
        :func:`grid_distance` to the config's point (ties: nearer first).
    rule : {"one_se", "best"}
    """
    if rule not in RULES:
        raise ValueError(f"rule must be one of {RULES}, got {rule!r}")
    T, F, N = tp.sum(axis=1), fp.sum(axis=1), fn.sum(axis=1)
    s = np.where(candidates, _scores(T, F, N, objective), -np.inf)
    if not np.isfinite(s).any():
        return None
    # best: the highest figure, nearest the config among equals
    best = int(np.lexsort((distance, -s))[0])
    if rule == "best" or tp.shape[1] < 2:
        return best
    num, den = _parts(objective_metric(objective), tp.astype(np.float64), fp.astype(np.float64),
                      fn.astype(np.float64))
    d, se = paired_difference(num[best][None, :], den[best][None, :], num, den)
    within = np.isfinite(s) & (np.nan_to_num(d, nan=np.inf) <= np.nan_to_num(se, nan=0.0))
    within[best] = True
    idx = np.flatnonzero(within)
    return int(idx[np.lexsort((-s[idx], distance[idx]))[0]])


# ------------------------------------------------------------------------------------------ edges
def grid_edges(params: Sequence[Params], candidates: np.ndarray, tuned: int) -> tuple[Edge, ...]:
    """Where the tuned set lies on the end of a swept axis (an axis of one value is not swept)."""
    out = []
    p0 = params[tuned]
    for j, axis in enumerate(ZCUT_PARAMS):
        v = p0[j]
        if v is None or (axis == "max_area_px" and p0[2] is not None):
            continue
        same = [p for p in params if all(p[i] == p0[i] for i in range(len(ZCUT_PARAMS)) if i != j)]
        vals = sorted({x for p in same if (x := p[j]) is not None})
        cands = sorted({x for i in np.flatnonzero(candidates) if (x := params[int(i)][j]) is not None})
        if len(vals) < 2:
            continue
        if cands and cands[0] == cands[-1] == v and vals[0] < v < vals[-1]:
            out.append(Edge(axis, "both", float(v), True, None))  # the only candidate: one sentence, not two
            continue
        for side, end, cend in (("upper", vals[-1], cands[-1] if cands else None),
                                ("lower", vals[0], cands[0] if cands else None)):
            if v == end:
                k = len(vals) - 1 if side == "upper" else 0
                nb = vals[k - 1] if side == "upper" else vals[1]
                widen: float | None = v + (v - nb) if side == "upper" else v - (nb - v)
                if widen is not None and (widen <= 0 or (axis == "rho_thr" and widen > 1)):
                    widen = min(1.0, v * 1.5) if side == "upper" else v / 2
                if axis == "rho_thr" and side == "upper" and v >= 1:
                    widen = None
                out.append(Edge(axis, side, float(v), False, None if widen is None else float(f"{widen:.6g}")))
            elif v == cend:
                out.append(Edge(axis, side, float(v), True, None))
    return tuple(out)


# ------------------------------------------------------------------------------------------ the whole
def cross_validate(counts: FrameCounts, *, objective: tuple[str, float | None], candidates: np.ndarray,
                   point: Params, reference: int | None, reference_name: str | None = None, rule: str = RULE,
                   max_folds: int = MAX_FOLDS) -> Validation:
    """Cross-validate the tuning of a sweep's z-cut sets (see the module docstring).

    Parameters
    ----------
    counts : FrameCounts
        Every z-cut set's counts on every scored frame.
    objective : (kind, floor)
    candidates : (n_sets,) bool ndarray
        The sets tuning may pick (the paper's §5.4 ranges, as ``studies.sweep.tune``).
    point : (step_mm, max_depth_mm, rho_thr, max_area_px)
        The config's own values (the rule prefers sets near them).
    reference : int or None
        Index of the set tuning is compared with (the paper's nominal set, else the config's).
    reference_name : str, optional
        What to call it (``"nominal"``, ``"chosen"``).
    rule : {"one_se", "best"}
    max_folds : int

    Returns
    -------
    Validation
    """
    from zcut.metrics import pooled_interval

    cand = np.asarray(candidates, dtype=bool)
    n, m = counts.n_sets, counts.n_frames
    tp, fp, fn = (np.asarray(a, dtype=np.int64).reshape(n, m) for a in (counts.tp, counts.fp, counts.fn))
    dist = grid_distance(counts.params, point)
    tuned = select(tp, fp, fn, objective=objective, candidates=cand, distance=dist, rule=rule) if n else None
    best = select(tp, fp, fn, objective=objective, candidates=cand, distance=dist, rule="best") if n else None
    params = counts.params
    f1_all = _ratio(*_parts("f1", tp.sum(axis=1).astype(np.float64), fp.sum(axis=1), fn.sum(axis=1)))
    f1_in = float(f1_all[tuned]) if tuned is not None and math.isfinite(f1_all[tuned]) else None
    edges = grid_edges(params, cand, tuned) if tuned is not None else ()
    two_best = _two_best(tp, fp, fn, params, objective, cand, dist, best)
    split, fold = folds_of(counts.logs, counts.frames, max_folds=max_folds)
    tuned_p = None if tuned is None else params[tuned]
    best_p = None if best is None else params[best]
    if split == "none" or tuned is None:
        why = ("no z-cut set has a defined figure on these frames" if tuned is None
               else f"{m} frame(s) scored: cross-validation needs at least 2")
        return Validation(rule, "none", (), tuned_p, best_p, f1_in, {}, {}, None, reference_name, None, two_best,
                          edges, why)
    held = np.zeros((3, m), dtype=np.int64)
    folds = []
    for k in range(int(fold.max()) + 1):
        test = fold == k
        train = ~test
        sel = select(tp[:, train], fp[:, train], fn[:, train], objective=objective, candidates=cand, distance=dist,
                     rule=rule)
        note = None
        if sel is None:  # nothing to tune on without this fold: the reference (or the config's) set stands
            sel = reference if reference is not None else int(np.argmin(dist))
            note = "no candidate had a defined figure on the other folds: the reference set stands"
        held[:, test] = tp[sel, test], fp[sel, test], fn[sel, test]
        f = _ratio(*_parts("f1", held[0, test].sum(), held[1, test].sum(), held[2, test].sum()))
        folds.append(Fold(tuple(sorted(set(np.asarray(counts.logs)[test].tolist()))), int(test.sum()), params[sel],
                          float(f) if math.isfinite(f) else None, note))
    T, F, N = held
    oos = {}
    sums = np.array([T.sum(), F.sum(), N.sum()], dtype=np.float64)
    for metric in ("precision", "recall", "f1"):
        r = float(_ratio(*_parts(metric, sums[0:1], sums[1:2], sums[2:3]))[0])
        oos[metric] = r if math.isfinite(r) else None
    ci = {k: (_num(lo), _num(hi)) for k, (lo, hi) in pooled_interval(T, F, N).items()}
    f1_out = oos["f1"]
    vs_ref = None
    if reference is not None:
        num_a, den_a = _parts("f1", T, F, N)
        num_b, den_b = _parts("f1", tp[reference], fp[reference], fn[reference])
        vs_ref = _difference(params[tuned], params[reference], num_a, den_a, num_b, den_b)
    notes = [f.note for f in folds if f.note]
    return Validation(rule, split, tuple(folds), tuned_p, best_p, f1_in, oos, ci,
                      None if f1_in is None or f1_out is None else f1_in - f1_out, reference_name, vs_ref, two_best,
                      edges, f"{len(notes)} fold(s): {notes[0]}" if notes else None)


def _two_best(tp: np.ndarray, fp: np.ndarray, fn: np.ndarray, params: Sequence[Params],
              objective: tuple[str, float | None], cand: np.ndarray, dist: np.ndarray,
              best: int | None) -> Difference | None:
    """The best set against the best one whose counts differ from it on some frame."""
    if best is None:
        return None
    same = (tp == tp[best]).all(axis=1) & (fp == fp[best]).all(axis=1) & (fn == fn[best]).all(axis=1)
    s = np.where(cand & ~same, _scores(tp.sum(axis=1), fp.sum(axis=1), fn.sum(axis=1), objective), -np.inf)
    if not np.isfinite(s).any():
        return None
    second = int(np.lexsort((dist, -s))[0])
    num, den = _parts(objective_metric(objective), tp, fp, fn)
    return _difference(params[best], params[second], num[best], den[best], num[second], den[second])
