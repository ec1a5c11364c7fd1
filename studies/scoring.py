"""The scoring of a study's tables: their column names, one mask's counts against the truth, and the
objective a parameter set is ranked by.

Below the sweep (:mod:`studies.sweep`) and the filter bank (:mod:`studies.bank`), which both write
rows of ``sweep.parquet`` and rank their sets by the same objective.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from replay.errors import ConfigError

#: The z-cut's parameter columns of ``sweep.parquet``.
ZCUT_COLUMNS = ("step_mm", "max_depth_mm", "rho_thr", "max_area_px")
#: SOR's parameter columns of ``sweep.parquet``.
SOR_COLUMNS = ("sor_k", "sor_std_ratio")
#: Columns of the filter bank's rows (``studies.bank``), None on the z-cut's and SOR's except
#: ``seconds`` and ``part`` when the sweep has a bank.
BANK_COLUMNS = ("params", "seconds", "part", "kind_tp", "kind_n")


@dataclass(frozen=True, slots=True)
class Counts:
    """The count columns of a ``sweep.parquet`` row (its field names are the column names).

    Attributes
    ----------
    tp, fp, fn : int
        The method's mask against the truth over the scored region S: true positives, false
        positives, false negatives.
    n_pred : int
        The mask's pixels (anywhere, not only in S).
    n_both, n_sor_only, n_zcut_only : int or None
        A z-cut row's overlap with SOR at the config's own k and std_ratio (N_both, N1, N2 of
        docs/accuracy.md); None on the other methods' rows.
    """

    tp: int
    fp: int
    fn: int
    n_pred: int
    n_both: int | None = None
    n_sor_only: int | None = None
    n_zcut_only: int | None = None

    @classmethod
    def of(cls, pred: np.ndarray, truth: np.ndarray, scored: np.ndarray) -> Counts:
        """The counts of a mask ``pred`` against ``truth`` over ``scored`` (all (H, W) bool)."""
        p = pred & scored
        lab = truth & scored
        tp = int(np.count_nonzero(p & lab))
        return cls(tp=tp, fp=int(np.count_nonzero(p)) - tp, fn=int(np.count_nonzero(lab)) - tp,
                   n_pred=int(np.count_nonzero(pred)))

    def columns(self) -> dict[str, int | None]:
        """``{column: value}``, the overlap columns left out when not known (a row's missing column
        is None)."""
        return {f: v for f in COUNT_COLUMNS if (v := getattr(self, f)) is not None}


#: The count columns of ``sweep.parquet``, in the table's order: :class:`Counts`' fields.
COUNT_COLUMNS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(Counts))
#: The counts a set's precision, recall and F1 are pooled from: ``tp``, ``fp``, ``fn``.
CONFUSION_COLUMNS: tuple[str, ...] = COUNT_COLUMNS[:3]

class Scored(Protocol):
    """What :func:`score` reads of a pooled set (``studies.summary.ParamSet``, ``studies.bank.BankSet``)."""

    @property
    def precision(self) -> float | None: ...

    @property
    def recall(self) -> float | None: ...

    @property
    def f1(self) -> float | None: ...


def parse_objective(text: str) -> tuple[str, float | None]:
    """``f1``, ``recall@precision=0.9`` or ``precision@recall=0.8`` -> (kind, floor)."""
    t = text.strip()
    if t == "f1":
        return "f1", None
    for kind in ("recall@precision", "precision@recall"):
        if t.startswith(kind + "="):
            try:
                v = float(t.split("=", 1)[1])
            except ValueError:
                break
            if not 0 < v <= 1:
                raise ConfigError(f"--objective {text!r}: the floor must be in (0, 1]")
            return kind, v
    raise ConfigError(f"--objective must be f1, recall@precision=P or precision@recall=R, got {text!r}")


def score(e: Scored, objective: tuple[str, float | None]) -> float:
    """The objective's value of a set (-inf when it misses the floor or is undefined)."""
    kind, floor = objective
    p, r, f = e.precision, e.recall, e.f1
    if kind == "f1":
        return f if f is not None else -math.inf
    if kind == "recall@precision":
        return r if (p is not None and r is not None and floor is not None and p >= floor) else -math.inf
    return p if (p is not None and r is not None and floor is not None and r >= floor) else -math.inf
