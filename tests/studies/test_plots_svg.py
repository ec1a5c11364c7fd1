"""The SVG panels of ``zcut compare``'s report (:func:`studies.plots.svg_figure`) re-implement three pieces of
matplotlib so that the page need not import it: the ticks of ``MaxNLocator`` (``AutoLocator``'s steps, and
``integer=True``), ``ScalarFormatter``'s decimals and the autoscaled view with 5 % margins and sticky edges.
The sweep's report draws with matplotlib itself; these tests hold the SVG path to matplotlib on the same
inputs, so that the two reports cannot drift apart."""
from __future__ import annotations

import math

import numpy as np
import pytest

matplotlib = pytest.importorskip("matplotlib")

from matplotlib.axes import Axes  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402

from studies.plots import _RC, _limits, _tick_format, _ticks  # noqa: E402


def _ranges(seed: int, n: int) -> list[tuple[float, float]]:
    """Views as the compare report meets them: F1 and precision in [0, 1], paired differences around 0,
    frame indices, counts; spans from 1e-3 to 1e4."""
    rng = np.random.default_rng(seed)
    out = [(0.0, 1.0), (-0.05, 0.05), (0.0, 7.0), (-0.119, -0.055), (0.4, 0.41), (1.0, 56.0)]
    for _ in range(n):
        span = 10 ** rng.uniform(-3, 4)
        centre = rng.uniform(-50, 50) * span
        lo = centre - span * rng.uniform(0, 1)
        out.append((float(lo), float(lo + span)))
    return out


@pytest.mark.parametrize("integer", [False, True])
def test_ticks_are_maxnlocators(integer: bool) -> None:
    for vmin, vmax in _ranges(1, 300):
        for nbins in (2, 3, 5, 7, 9):
            loc = MaxNLocator(integer=True) if integer else MaxNLocator(nbins=nbins, steps=[1, 2, 2.5, 5, 10])
            want = loc.tick_values(vmin, vmax)
            got = _ticks(vmin, vmax, nbins, integer=integer)
            assert np.allclose(got, want, rtol=0, atol=1e-9 * (vmax - vmin)), (vmin, vmax, nbins, integer)


def test_tick_labels_are_scalarformatters() -> None:
    """Labels as an axis makes them (``Axis._update_ticks``: the formatter sees every located tick, in
    view or not), against :func:`_tick_format` of the same ticks."""
    checked = 0
    with matplotlib.rc_context(_RC):
        fig = Figure(figsize=(4, 3))
        ax = fig.add_subplot()
        for vmin, vmax in _ranges(2, 120):
            mean, span = abs(vmin + vmax) / 2, vmax - vmin
            if mean / span >= 100 or max(abs(vmin), abs(vmax)) >= 1e4 or span < 1e-2:
                # matplotlib then writes an offset or a power of ten beside the axis, which the SVG panels
                # never need (F1, differences, frame indices): outside what the SVG path claims to draw
                continue
            ax.set_ylim(vmin, vmax)
            for nbins in (3, 5, 9):
                ax.yaxis.set_major_locator(MaxNLocator(nbins=nbins, steps=[1, 2, 2.5, 5, 10]))
                locs = [float(v) for v in ax.yaxis.get_majorticklocs()]
                want = ax.yaxis.get_major_formatter().format_ticks(locs)
                fmt = _tick_format(locs)
                assert [fmt(v) for v in locs] == want, (vmin, vmax, nbins)
                checked += 1
    assert checked >= 150


def _mpl_view(ax: Axes, kind: str, values: list[float]) -> tuple[float, float]:
    """The y view matplotlib autoscales to for a line through ``values`` or bars of those heights."""
    ax.cla()
    if kind == "bar":
        ax.bar(range(len(values)), values)
    else:
        ax.plot(range(len(values)), values)
    lo, hi = ax.get_ylim()
    return float(lo), float(hi)


@pytest.mark.parametrize("kind", ["line", "bar"])
def test_limits_are_the_autoscaled_view(kind: str) -> None:
    rng = np.random.default_rng(3)
    cases: list[list[float]] = [[0.5], [0.0], [-2.0], [0.2, 0.9], [-0.1, 0.3], [3.0, 3.0, 3.0]]
    for _ in range(40):
        n = int(rng.integers(1, 12))
        scale = 10 ** rng.uniform(-2, 2)
        cases.append([float(v) for v in rng.normal(rng.uniform(-1, 1), 1, n) * scale])
    with matplotlib.rc_context(_RC):
        ax = Figure().add_subplot()
        views = [_mpl_view(ax, kind, vals) for vals in cases]
    for vals, want in zip(cases, views, strict=True):
        data = (vals + [0.0]) if kind == "bar" else vals  # a bar spans from 0 to its height
        got = _limits(data, [0.0] if kind == "bar" else [])
        tol = 1e-12 * max(1.0, *(abs(v) for v in vals))
        assert math.isclose(got[0], want[0], abs_tol=tol) and math.isclose(got[1], want[1], abs_tol=tol), (kind, vals)
