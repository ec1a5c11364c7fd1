"""The parameter grid of a sweep (docs/studies.md): LIST options and the grid they make.

A LIST is ``a,b,c`` or ``start:stop:count`` (inclusive, evenly spaced). The z-cut axes are Δd
(``--step``), d_max (``--max-depth``) and ρ_thr (``--rho``, μ_thr = ρ_thr · a_max); the SOR axes are k
(``--sor-k``) and std_ratio (``--sor-std``). An axis not given holds the resolved config's value.

*Study points* (on by default, off with ``study_points=False`` / ``zcut sweep --no-study-points``):
the config's own d_max and ρ_thr (of the "chosen point", the config's own parameters) and 0.5× and
1.5× each (ρ_thr ≤ 1) are added to those axes, for the paper's sensitivity ratios ω and θ (eqs. 6,
7). Off, the grid is exactly the values given, and the config's value on the axes not given.

Values are one value when they agree to :data:`REL_TOL` (relative): every value is first rounded to
12 significant digits (``0.035 + 2 · 0.035`` and ``1.5 · 0.07`` both become 0.105), then values that
still agree to the tolerance are merged, keeping the one given on the command line.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from replay.errors import ConfigError

if TYPE_CHECKING:
    from collections.abc import Iterable

    from replay.pipeline.config import PipelineConfig

#: Grid points a sweep runs without --force.
DEFAULT_MAX_POINTS = 5000
#: Relative tolerance under which two values of an axis are one value (as ``studies.sweep`` finds sets).
REL_TOL = 1e-9


def _tidy(v: float) -> float:
    """``v`` rounded to 12 significant digits (removes the last-bit noise of ``start + step · i``)."""
    return float(f"{v:.12g}")


def _agree(a: float, b: float) -> bool:
    """``a`` and ``b`` are one value: they agree to :data:`REL_TOL` (relative, at least absolute)."""
    return abs(a - b) <= REL_TOL * max(1.0, abs(a), abs(b))


class _SortedFloats:
    """A sorted list of floats in blocks of at most ``2 · BLOCK``: find the neighbours of a value and
    insert it in O(√n) (a plain list's insert moves half the list: quadratic over n values)."""

    BLOCK = 512

    def __init__(self) -> None:
        self.blocks: list[list[float]] = []
        self.maxes: list[float] = []

    def neighbours(self, v: float) -> tuple[float | None, float | None]:
        """The largest value < ``v`` and the smallest >= ``v`` (None where there is none)."""
        i = bisect.bisect_left(self.maxes, v)
        if i == len(self.blocks):
            return (self.maxes[-1] if self.maxes else None), None
        block = self.blocks[i]
        j = bisect.bisect_left(block, v)
        below = block[j - 1] if j else (self.maxes[i - 1] if i else None)
        return below, block[j]

    def insert(self, v: float) -> None:
        if not self.blocks:
            self.blocks.append([v])
            self.maxes.append(v)
            return
        i = min(bisect.bisect_left(self.maxes, v), len(self.blocks) - 1)
        block = self.blocks[i]
        bisect.insort(block, v)
        self.maxes[i] = block[-1]
        if len(block) > 2 * self.BLOCK:
            self.blocks[i:i + 1] = [block[:self.BLOCK], block[self.BLOCK:]]
            self.maxes[i:i + 1] = [block[self.BLOCK - 1], block[-1]]

    def values(self) -> list[float]:
        return [v for block in self.blocks for v in block]


def merge_values(*groups: Iterable[float]) -> tuple[float, ...]:
    """The values of ``groups`` (iterables, first group first), sorted, each kept once: a value within
    :data:`REL_TOL` (relative) of one kept before it is dropped, so an earlier group's spelling wins.

    The values within the tolerance of ``v`` form an interval around it (the distance grows faster
    than the tolerance), so only the kept neighbours of ``v`` on either side need a look: O(n √n)
    at worst, O(n log n) for values given in order (a ``start:stop:count`` range).

    >>> merge_values([0.105], [0.035, 0.10500000000000001])
    (0.035, 0.105)
    """
    kept = _SortedFloats()
    for group in groups:
        for v in group:
            below, above = kept.neighbours(v)
            if not ((below is not None and _agree(v, below)) or (above is not None and _agree(v, above))):
                kept.insert(v)
    return tuple(kept.values())


def parse_list(text: str | None, *, name: str, integer: bool = False,
               max_values: int | None = None) -> tuple[float, ...] | None:
    """``a,b,c`` or ``start:stop:count`` -> sorted values, each once (:func:`merge_values`, after rounding
    to 12 significant digits); None when not given.

    ``max_values``: refuse a list of more values than that before expanding it (a sweep's
    ``--max-points``: one axis of more values is a grid of more points)."""
    if text is None:
        return None
    t = text.strip()
    bad = ConfigError(f"{name} must be a,b,c or start:stop:count, got {text!r}")
    if ":" in t:
        parts = t.split(":")
        if len(parts) != 3:
            raise bad
        try:
            start, stop, count = float(parts[0]), float(parts[1]), int(parts[2])
        except ValueError:
            raise bad from None
        if not (math.isfinite(start) and math.isfinite(stop)):
            raise ConfigError(f"{name} {text!r}: start and stop must be finite numbers")
        if count < 1:
            raise ConfigError(f"{name} {text!r}: the count must be >= 1, got {count}")
        if stop < start:
            raise ConfigError(f"{name} {text!r}: an inverted range (stop {stop:g} < start {start:g})")
        if count == 1 and stop != start:
            raise ConfigError(f"{name} {text!r}: one value cannot span {start:g}..{stop:g} (count >= 2)")
        _check_count(count, name=name, max_values=max_values)
        values = [start + (stop - start) * i / (count - 1) for i in range(count)] if count > 1 else [start]
    else:
        items = [x for x in t.split(",") if x.strip()]
        if not items:
            raise ConfigError(f"{name}: an empty list")
        _check_count(len(items), name=name, max_values=max_values)
        try:
            values = [float(x) for x in items]
        except ValueError:
            raise bad from None
    if integer:
        if any(v != int(v) for v in values):
            raise ConfigError(f"{name} must be integers, got {text!r}")
        return tuple(sorted({int(v) for v in values}))
    for v in values:
        if not math.isfinite(v):
            raise ConfigError(f"{name}: {v!r} is not a finite number")
    return merge_values(_tidy(v) for v in values)


def _check_count(n: int, *, name: str, max_values: int | None) -> None:
    if max_values is not None and n > max_values:
        raise ConfigError(f"{name} has {n} values (more than --max-points {max_values}): narrow it, or use --force")


@dataclass(frozen=True, slots=True)
class Grid:
    """The values of every axis; the z-cut grid is steps × depths × rhos, SOR's ks × stds (per
    step and depth when SOR judges the top of the pile, which depends on them).

    Attributes
    ----------
    steps, depths, rhos : tuple of float
        Δd (mm), d_max (mm), ρ_thr.
    sor_ks : tuple of int
    sor_stds : tuple of float
    chosen : (step, depth, rho, k, std)
        The config's own point (rho None when a_max is unknown: μ_thr is then the config's own).
    study_points : bool
        Whether the chosen point and 0.5×, 1.5× its d_max and ρ_thr were added.
    """

    steps: tuple[float, ...]
    depths: tuple[float, ...]
    rhos: tuple[float, ...]
    sor_ks: tuple[int, ...]
    sor_stds: tuple[float, ...]
    chosen: tuple[float, float, float | None, int, float]
    study_points: bool = True

    @property
    def n_zcut(self) -> int:
        return len(self.steps) * len(self.depths) * len(self.rhos)

    def n_sor(self, *, per_depth: bool) -> int:
        scale = len(self.steps) * len(self.depths) if per_depth else 1
        return scale * len(self.sor_ks) * len(self.sor_stds)

    def as_dict(self) -> dict[str, Any]:
        return {"step_mm": list(self.steps), "max_depth_mm": list(self.depths), "rho_thr": list(self.rhos),
                "sor_k": list(self.sor_ks), "sor_std_ratio": list(self.sor_stds),
                "chosen": dict(zip(("step_mm", "max_depth_mm", "rho_thr", "sor_k", "sor_std_ratio"), self.chosen)),
                "study_points": self.study_points}


def make_grid(*, steps: tuple[float, ...] | None, depths: tuple[float, ...] | None, rhos: tuple[float, ...] | None,
              sor_ks: tuple[float, ...] | None, sor_stds: tuple[float, ...] | None, config: PipelineConfig,
              max_points: int = DEFAULT_MAX_POINTS, force: bool = False, study_points: bool = True) -> Grid:
    """Check the axes against the stage types' rules; with ``study_points``, add the chosen point and
    0.5×, 1.5× its d_max and ρ_thr (see the module docstring). The values given win over an added
    value they equal to :data:`REL_TOL`.

    Raises
    ------
    ConfigError
        A value out of range (Δd ≤ 0, d_max ≤ 0, ρ outside (0, 1], k < 1, std_ratio ≤ 0), ρ without a
        known a_max, or more than ``max_points`` grid points without ``force``.
    """
    z = config.zcut
    if z.a_max is None and rhos is not None:
        raise ConfigError("--rho needs a_max (the part's face in pixels): give part = KIND, --part or zcut.a_max_px")
    rho0 = z.rho_thr if z.rho_thr is not None else None
    chosen = (z.step, z.max_depth, rho0, config.sor.k, config.sor.std_ratio)
    d0 = z.max_depth
    steps = steps or (z.step,)

    def around(v: float) -> list[float]:
        return [_tidy(f * v) for f in (1.0, 0.5, 1.5)] if study_points else []

    depths = merge_values(depths or (d0,), around(d0))
    rhos = () if rho0 is None else merge_values(rhos or (rho0,), [r for r in around(rho0) if r <= 1])
    sor_ks = sor_ks or (config.sor.k,)
    sor_stds = sor_stds or (config.sor.std_ratio,)
    for v in steps:
        if not v > 0:
            raise ConfigError(f"--step values must be > 0 mm, got {v:g}")
    for v in depths:
        if not v > 0:
            raise ConfigError(f"--max-depth values must be > 0 mm, got {v:g}")
    for v in rhos:
        if not 0 < v <= 1:
            raise ConfigError(f"--rho values must be in (0, 1], got {v:g}")
    for v in sor_ks:
        if v < 1:
            raise ConfigError(f"--sor-k values must be integers >= 1, got {v}")
    for v in sor_stds:
        if not v > 0:
            raise ConfigError(f"--sor-std values must be > 0, got {v:g}")
    grid = Grid(tuple(steps), depths, rhos, tuple(int(k) for k in sor_ks), tuple(sor_stds), chosen, study_points)
    n = grid.n_zcut + grid.n_sor(per_depth=config.sor.region == "top")
    if n > max_points and not force:
        raise ConfigError(f"the grid has {n} parameter sets (more than {max_points}): narrow it, or use --force")
    return grid
