"""A sweep's pooled sets arranged on its grid: a set by its parameters, the sets along one axis, the
chosen point. What the plots (:mod:`studies.plots`), the findings (:mod:`studies.findings`) and the
report page (:mod:`studies.report`) look the sets up with.

Grid values are compared as :func:`key` (rounded to 9 decimals): a grid value like
0.10500000000000001 and 0.105 are one.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from studies.summary import PARAMETERS, ParamSet, SweepSummary

#: A parameter value as a lookup key (None stays None).
Key = float | None


def key(v: Any) -> Key:
    """A parameter value as a lookup key (grid values like 0.10500000000000001 and 0.105 are one)."""
    return None if v is None else round(float(v), 9)


def as_summary(summary: SweepSummary | Mapping[str, Any]) -> SweepSummary:
    """The typed summary of a summary given either way (a dict is ``summary.json``'s object)."""
    return summary if isinstance(summary, SweepSummary) else SweepSummary.from_json(dict(summary))


def same_set(a: ParamSet | None, b: ParamSet | None) -> bool:
    """True when ``a`` and ``b`` are the same method at the same parameters."""
    if a is None or b is None:
        return False
    return a.method == b.method and all(key(a.param(k)) == key(b.param(k)) for k in PARAMETERS)


def _parse(config_toml: str) -> dict[str, Any]:
    try:
        return tomllib.loads(config_toml)
    except (tomllib.TOMLDecodeError, TypeError):
        return {}


def _sor_table(config: dict[str, Any]) -> dict[str, Any]:
    t = config.get("sor")
    return t if isinstance(t, dict) else {}


@dataclass(frozen=True)
class SetGrid:
    """The summary seen as a grid: which parameters each method's sets vary, the chosen point, and a
    lookup of a set by its parameters. Build it with :meth:`of`.

    Attributes
    ----------
    summary : SweepSummary
    zsets, ssets : tuple of ParamSet
        The z-cut's and SOR's sets.
    area : str
        ``"rho_thr"``, or ``"max_area_px"`` when a_max was unknown (μ_thr swept in pixels).
    zparams : (str, str, str)
        Δd, d_max and the area column.
    sparams : tuple of str
        k, std_ratio (and Δd, d_max when SOR judges the top of the pile).
    chosen : dict of str
        Every parameter at the config's own point.
    a_max : float or None
        Pixels, when one log (one a_max) was swept.
    sor_enabled : bool
    """

    summary: SweepSummary
    zsets: tuple[ParamSet, ...]
    ssets: tuple[ParamSet, ...]
    area: str
    zparams: tuple[str, ...]
    sparams: tuple[str, ...]
    chosen: dict[str, Any]
    a_max: float | None
    sor_enabled: bool
    index: dict[tuple[Any, ...], ParamSet]

    @classmethod
    def of(cls, summary: SweepSummary | Mapping[str, Any]) -> SetGrid:
        s = as_summary(summary)
        zsets = tuple(e for e in s.sets if e.method == "zcut")
        ssets = tuple(e for e in s.sets if e.method == "sor")
        area = "rho_thr" if any(e.rho_thr is not None for e in zsets) or not zsets else "max_area_px"
        top = any(e.step_mm is not None for e in ssets)
        config = _parse(s.config)
        names = ("step_mm", "max_depth_mm", "rho_thr", "sor_k", "sor_std_ratio")
        chosen: dict[str, Any] = dict(zip(names, s.grid.chosen)) if s.grid is not None else dict.fromkeys(names)
        chosen["max_area_px"] = s.chosen_zcut.max_area_px if s.chosen_zcut is not None else None
        if area == "max_area_px" and chosen["max_area_px"] is None:
            areas = {key(e.max_area_px) for e in zsets}
            chosen["max_area_px"] = areas.pop() if len(areas) == 1 else None
        zcut_table = config.get("zcut")
        a_max = zcut_table.get("a_max_px") if isinstance(zcut_table, dict) else None
        if len(s.logs) != 1 or not isinstance(a_max, (int, float)):
            a_max = None
        sor_enabled = bool(ssets) and _sor_table(config).get("enabled", True) is not False
        zparams = ("step_mm", "max_depth_mm", area)
        sparams = ("sor_k", "sor_std_ratio") + (("step_mm", "max_depth_mm") if top else ())
        index: dict[tuple[Any, ...], ParamSet] = {}
        for method, group, params in (("zcut", zsets, zparams), ("sor", ssets, sparams)):
            for e in group:
                index.setdefault((method, *(key(e.param(k)) for k in params)), e)
        return cls(s, zsets, ssets, area, zparams, sparams, chosen,
                   float(a_max) if a_max is not None else None, sor_enabled, index)

    def params(self, method: str) -> tuple[str, ...]:
        """The parameters ``method``'s sets vary."""
        return self.zparams if method == "zcut" else self.sparams

    def sets(self, method: str) -> tuple[ParamSet, ...]:
        return self.zsets if method == "zcut" else self.ssets

    def values(self, method: str, name: str) -> list[float]:
        """The sorted distinct values of parameter ``name`` among ``method``'s sets."""
        vals = {key(e.param(name)) for e in self.sets(method)} - {None}
        return sorted(v for v in vals if v is not None)

    def series(self, method: str, vary: str, fixed: dict[str, Any]) -> list[tuple[float, ParamSet]]:
        """The sets of ``method`` along ``vary``, the other parameters at ``fixed`` (sorted by ``vary``)."""
        want = {k: key(v) for k, v in fixed.items() if k in self.params(method) and k != vary}
        out: dict[float, ParamSet] = {}
        for e in self.sets(method):
            x = key(e.param(vary))
            if x is None or any(key(e.param(k)) != v for k, v in want.items()):
                continue
            out.setdefault(x, e)
        return sorted(out.items(), key=lambda t: t[0])

    def find(self, method: str, **params: Any) -> ParamSet | None:
        """The set of ``method`` with these parameters (the first match when some are not given)."""
        want = {k: key(v) for k, v in params.items() if k in self.params(method)}
        if len(want) == len(self.params(method)):
            return self.index.get((method, *(want[k] for k in self.params(method))))
        for e in self.sets(method):
            if all(key(e.param(k)) == v for k, v in want.items()):
                return e
        return None

    def chosen_at(self, method: str) -> dict[str, Any]:
        """The chosen point's values of ``method``'s parameters."""
        return {k: self.chosen.get(k) for k in self.params(method)}

    @property
    def ranges(self) -> dict[str, tuple[float, float]] | None:
        """The paper's §5.4 ranges the tuned z-cut set was chosen within (None: unknown part)."""
        return self.summary.tuned.ranges
