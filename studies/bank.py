"""The filter bank in a sweep: each filter's own parameter axes, its sets scored like the z-cut's and
SOR's, and the ranking per part kind (docs/filters.md, "The bank in a sweep").

Axes are given as ``--grid SECTION.FIELD=LIST`` (``--grid radius.radius_mm=1,2,3 --grid
radius.min_points=4,8``), or ``--grid SECTION=default`` for the filter's default axes
(:func:`default_axes`, from each filter's registry entry). An axis not given holds the config's value. Every filter the config's
``methods`` names (other than ``zcut`` and ``sor``, swept by their own axes) is run at every point of
the product of its axes, on the same zone the replay gives it (:func:`replay.pipeline.methods`), and a
union ``a+b`` of the methods list is scored at the config's own parameters of its members.

Rows (in ``sweep.parquet``, beside the z-cut's and SOR's): ``method``, ``params`` (the set's
parameters as JSON, ``{"radius_mm": 2.0, "min_points": 8}``; ``{}`` for a union), TP/FP/FN and
``n_pred`` over the scored region, ``seconds`` (the filter's CPU time on the frame), ``part`` and, per
outlier kind of the synthetic truth, ``kind_tp`` / ``kind_n`` (JSON: true pixels found / true pixels
per kind code). The z-cut's and SOR's rows get ``seconds`` too: their time at the config's own
parameters on the frame (the same on every one of their sets: the sweep computes them by reuse,
not one by one).
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from replay.errors import ConfigError
from studies.scoring import CONFUSION_COLUMNS, SOR_COLUMNS, ZCUT_COLUMNS, Counts, score

if TYPE_CHECKING:
    from annotate.truth import FrameTruth
    from replay.logs.frame import Frame
    from replay.pipeline.config import PipelineConfig
    from replay.pipeline.zone import Zone

def default_axes() -> dict[str, dict[str, tuple[float, ...]]]:
    """Each filter's default axes (``--grid NAME=default``), as its registry entry declares them
    (:attr:`replay.pipeline.methods.Method.axes`): a few values around the defaults of
    ``zcut.params``, from a light to a strong filter; ``{}`` for a filter that declares none."""
    from replay.pipeline.methods import registry

    return {m.section: dict(m.axes) for m in registry().values() if m.section in bank_sections()}


def bank_sections() -> tuple[str, ...]:
    from replay.pipeline.config import bank_sections

    return bank_sections()


def _field_types(section: str) -> dict[str, type]:
    from replay.pipeline.config import stage_sections

    cls = stage_sections()[section]
    defaults = cls()
    return {f.name: type(getattr(defaults, f.name)) for f in dataclasses.fields(cls)}


def parse_grid_options(items: Sequence[str] | None, *,
                       max_values: int | None = None) -> dict[str, dict[str, tuple[float, ...]]]:
    """``["radius.radius_mm=1,2", "cluster=default"]`` -> ``{section: {field: values}}``; an axis of
    more than ``max_values`` values is refused before it is expanded.

    Raises
    ------
    ConfigError
        One line: not ``SECTION.FIELD=LIST``, an unknown section or field, a value the parameters
        refuse (checked by the section's params class), an axis given twice.
    """
    from studies.grid import parse_list

    out: dict[str, dict[str, tuple[float, ...]]] = {}
    for item in items or ():
        name, eq, values = item.partition("=")
        name = name.strip()
        if not eq or not values.strip():
            raise ConfigError(f"--grid {item!r}: expected SECTION.FIELD=LIST or SECTION=default")
        section, dot, fld = name.partition(".")
        known = bank_sections()
        if section not in known:
            raise ConfigError(f"--grid {item!r}: unknown section {section!r} (filters: {', '.join(known)}; "
                              "the z-cut and SOR have --step/--max-depth/--rho/--sor-k/--sor-std)")
        axes = out.setdefault(section, {})
        if not dot:
            if values.strip() != "default":
                raise ConfigError(f"--grid {item!r}: expected {section}.FIELD=LIST or {section}=default")
            for f, v in default_axes().get(section, {}).items():
                axes.setdefault(f, v)
            continue
        types = _field_types(section)
        if fld not in types:
            raise ConfigError(f"--grid {item!r}: unknown field {section}.{fld} (known: {', '.join(sorted(types))})")
        if fld in axes:
            raise ConfigError(f"--grid: {section}.{fld} given twice")
        vals = parse_list(values, name=f"--grid {section}.{fld}", integer=types[fld] is int,
                          max_values=max_values)
        assert vals is not None
        axes[fld] = vals
    return out


def make_bank_grid(axes: Mapping[str, Mapping[str, Sequence[float]]], config: PipelineConfig) -> dict[str, list[dict[str, Any]]]:
    """``{method: [params dict, ...]}``: the product of each swept filter's axes (the config's value
    on the axes not given), for every filter of ``config.base_methods`` other than zcut and sor.

    Raises
    ------
    ConfigError
        A grid for a filter the methods do not name; a grid point its params class refuses (one line
        naming ``section.field`` and the value).
    """
    from replay.pipeline.config import _config_error, stage_sections
    from zcut.errors import ParameterError

    known = bank_sections()
    classes = stage_sections()
    base = [m for m in config.base_methods if m in known]
    for section in axes:
        if section not in base:
            raise ConfigError(f"--grid {section}.*: {section} is not among the methods ({', '.join(config.methods)}): "
                              f"add it with --methods")
    out: dict[str, list[dict[str, Any]]] = {}
    for m in base:
        own = getattr(config, m)
        names = [f.name for f in dataclasses.fields(own)]
        given = axes.get(m, {})
        values = [tuple(given[n]) if n in given else (getattr(own, n),) for n in names]
        sets = []
        for combo in itertools.product(*values):
            d = dict(zip(names, combo))
            try:
                p = classes[m](**d)
            except ParameterError as e:
                raise _config_error(e, "--grid") from None
            sets.append({k: getattr(p, k) for k in names if getattr(p, k) is not None})
        out[m] = sets
    return out


def n_bank_sets(grid: Mapping[str, Sequence[dict[str, Any]]]) -> int:
    return sum(len(v) for v in grid.values())


def unions_of(config: PipelineConfig) -> tuple[str, ...]:
    """The unions ``a+b`` of the config's methods list (scored at the config's own parameters)."""
    return tuple(m for m in config.methods if "+" in m)


# ------------------------------------------------------------------------------------------ rows
def _kind_counts(pred: np.ndarray, truth_kind: np.ndarray | None, lab: np.ndarray) -> tuple[str | None, str | None]:
    if truth_kind is None:
        return None, None
    k = truth_kind[lab]
    found = truth_kind[lab & pred]
    n = np.bincount(k, minlength=256)
    tp = np.bincount(found, minlength=256)
    codes = [int(c) for c in np.flatnonzero(n)]
    return json.dumps({str(c): int(tp[c]) for c in codes}), json.dumps({str(c): int(n[c]) for c in codes})


def bank_rows(row: Callable[..., dict[str, Any]], frame: Frame, zone: Zone, config: PipelineConfig,
              grid: Mapping[str, Sequence[dict[str, Any]]], truth: FrameTruth, scored: np.ndarray,
              base_seconds: dict[str, float]) -> list[dict[str, Any]]:
    """The rows of every bank set on one frame (``row(method, **columns)`` makes a row of the sweep's
    table). When there is a bank, the z-cut and SOR also run once at the config's own point: their
    CPU seconds go into ``base_seconds`` (for their rows) and their masks into the unions."""
    from replay.pipeline.methods import members, registry

    known = registry()
    L = truth.outliers
    lab = L & scored
    easy = zone.easy
    rows = []
    own: dict[str, np.ndarray] = {}

    def counts(pred: np.ndarray) -> dict[str, Any]:
        ktp, kn = _kind_counts(pred & scored, truth.kind, lab)
        return {**Counts.of(pred, L, scored).columns(), "kind_tp": ktp, "kind_n": kn}

    if grid or unions_of(config):  # the z-cut's and SOR's time (and masks) at the config's own point
        for m in ("zcut", "sor"):
            if m in config.base_methods:
                t = time.process_time()
                own[m] = known[m].run(frame, zone, config).outliers
                base_seconds[m] = time.process_time() - t
    for m, sets in grid.items():
        method = known[m]
        for params in sets:
            c = config.replace(**{m: dataclasses.replace(getattr(config, m), **params)})
            t = time.process_time()
            if method.needs_intrinsics and frame.intrinsics is None:
                mask = np.zeros_like(zone.zone)
            else:
                try:
                    mask = method.run(frame, zone, c).outliers
                except Exception as e:  # a filter's ZcutError on one frame: no outliers, as the replay
                    from zcut.errors import ZcutError

                    if not isinstance(e, ZcutError):
                        raise
                    mask = np.zeros_like(zone.zone)
            seconds = time.process_time() - t
            if params == own_params(config, m):
                own[m] = mask
            rows.append(row(m, params=json.dumps(params, sort_keys=True), seconds=seconds, **counts(mask | easy)))
    for u in unions_of(config):
        if not all(p in own for p in members(u)):
            continue
        mask = np.zeros_like(zone.zone)
        for p in members(u):
            mask |= own[p]
        rows.append(row(u, params="{}", seconds=None, **counts(mask | easy)))
    return rows


def own_params(config: PipelineConfig, method: str) -> dict[str, Any]:
    """The config's own parameters of a bank method, as a set's ``params`` (None values left out)."""
    p = getattr(config, method)
    return {f.name: getattr(p, f.name) for f in dataclasses.fields(p) if getattr(p, f.name) is not None}


# ------------------------------------------------------------------------------------ pooled sets
@dataclass(frozen=True, slots=True)
class BankSet:
    """One parameter set of one filter of the bank (or a union), pooled over a sweep's frames.

    Attributes
    ----------
    method : str
    params : dict
        The set's parameters (the swept fields and the config's values of the others).
    part : str or None
        The part kind of the logs pooled (None: every log).
    frames, tp, fp, fn, n_pred : int
    precision, recall, f1 : float or None
    ci95 : dict of str to (lo, hi)
        95 % intervals over frames (docs/accuracy.md), as the z-cut's sets.
    seconds : float or None
        Mean CPU seconds per frame.
    kind_recall : dict of str to float
        Recall per outlier kind code of the synthetic truth (``docs/formats.md``, kind codes).
    """

    method: str
    params: dict[str, Any]
    part: str | None
    frames: int
    tp: int
    fp: int
    fn: int
    n_pred: int
    precision: float | None
    recall: float | None
    f1: float | None
    ci95: dict[str, tuple[float | None, float | None]]
    seconds: float | None
    kind_recall: dict[str, float | None]

    def to_json(self) -> dict[str, Any]:
        return {"method": self.method, "params": self.params, "part": self.part, "frames": self.frames,
                "tp": self.tp, "fp": self.fp, "fn": self.fn, "n_pred": self.n_pred, "precision": self.precision,
                "recall": self.recall, "f1": self.f1, "ci95": {k: list(v) for k, v in self.ci95.items()},
                "seconds": self.seconds, "kind_recall": self.kind_recall}


def _r(a: int, b: int) -> float | None:
    return a / b if b else None


def _set_params(method: str, cols: Mapping[str, list[Any]], i: int) -> dict[str, Any]:
    p = cols.get("params", [None] * (i + 1))[i]
    if p is not None:
        return dict(json.loads(p))
    out = {}
    for c in ZCUT_COLUMNS + SOR_COLUMNS:
        v = cols[c][i]
        if v is not None and not (c == "max_area_px" and cols["rho_thr"][i] is not None):
            out[c] = v
    return out


def kind_names() -> dict[str, str]:
    """Kind code (as a string) -> name (``docs/formats.md``)."""
    from replay.logs import layout

    return {str(k): str(v) for k, v in layout.OUTLIER_KINDS.items()}


def pooled_bank_sets(table: Any, *, by_part: bool) -> list[BankSet]:
    """Every method's sets (bank, unions, and the z-cut's and SOR's), pooled per set (and per part
    kind with ``by_part``), with intervals, mean time per frame and recall per outlier kind."""
    from studies.summary import intervals
    from zcut.metrics import pooled_interval_many

    cols = table.to_pydict()
    n = table.num_rows
    have = set(cols)
    groups: dict[tuple[Any, ...], list[int]] = {}
    for i in range(n):
        params = _set_params(cols["method"][i], cols, i)
        part = cols["part"][i] if (by_part and "part" in have) else None
        groups.setdefault((cols["method"][i], json.dumps(params, sort_keys=True), part), []).append(i)
    out = []
    for (method, ptext, part), idx in groups.items():
        arr = {c: np.array([[cols[c][i] for i in idx]], dtype=np.int64) for c in CONFUSION_COLUMNS}
        ci = pooled_interval_many(arr["tp"], arr["fp"], arr["fn"])
        T, F, N = (int(arr[c].sum()) for c in CONFUSION_COLUMNS)
        secs = [cols["seconds"][i] for i in idx if "seconds" in have and cols["seconds"][i] is not None]
        ktp: dict[str, int] = {}
        kn: dict[str, int] = {}
        for i in idx:
            if "kind_n" in have and cols["kind_n"][i]:
                for k, v in json.loads(cols["kind_n"][i]).items():
                    kn[k] = kn.get(k, 0) + int(v)
                for k, v in json.loads(cols["kind_tp"][i]).items():
                    ktp[k] = ktp.get(k, 0) + int(v)
        out.append(BankSet(method, json.loads(ptext), part, len(idx), T, F, N,
                           sum(int(cols["n_pred"][i]) for i in idx), _r(T, T + F), _r(T, T + N),
                           _r(2 * T, 2 * T + F + N), intervals({k: v[0] for k, v in ci.items()}),
                           float(np.mean(secs)) if secs else None,
                           {k: _r(ktp.get(k, 0), kn[k]) for k in sorted(kn, key=int)}))
    out.sort(key=lambda s: (str(s.part), s.method, json.dumps(s.params, sort_keys=True)))
    return out


def ranking(table: Any, objective: tuple[str, float | None]) -> dict[str, Any]:
    """The ranking per part kind (and over every log, ``"all"``): each method's best set by the
    objective, best first; ``summary.json``'s ``ranking``."""
    out: dict[str, Any] = {}
    for by_part in (False, True):
        sets = pooled_bank_sets(table, by_part=by_part)
        parts = sorted({s.part for s in sets}, key=str)
        for part in parts:
            best: dict[str, BankSet] = {}
            for s in (s for s in sets if s.part == part):
                if s.method not in best or _score(s, objective) > _score(best[s.method], objective):
                    best[s.method] = s
            ranked = sorted(best.values(), key=lambda s: -_finite(_score(s, objective)))
            key = "all" if not by_part else (part if part is not None else "unknown")
            if by_part and len(parts) == 1 and part is None:
                continue
            out[key] = [s.to_json() for s in ranked]
    return {"kinds": kind_names(), "by_part": out}


def _score(s: BankSet, objective: tuple[str, float | None]) -> float:
    """:func:`studies.scoring.score` of a bank's set (it reads precision, recall and F1 only)."""
    return score(s, objective)


def _finite(v: float) -> float:
    return v if math.isfinite(v) else -1e300
