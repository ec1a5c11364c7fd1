"""Paired comparison of two filters on the same frames (docs/compare.md): the difference of their
pooled precision, recall and F1 with an interval over frames, and per-frame wins, losses and ties
with a sign test.

Pure functions on per-frame counts: no I/O.

The difference. A pooled figure of a filter is a ratio of counts summed over the frames,
R = Σ num_i / Σ den_i (precision: num = TP, den = TP + FP; recall: TP, TP + FN; F1: 2TP,
2TP + FP + FN). For two filters A and B scored on the same frames, Δ = R_B − R_A. The frames are the
unit of sampling: both filters see the same frame, so the two ratios move together and the
interval is built on the paired per-frame residual of the linearised difference,

    z_i = (num_B,i − R_B den_B,i) / Σ den_B − (num_A,i − R_A den_A,i) / Σ den_A,   Σ z_i = 0,

with the variance Σ c_i z_i², c_i = 1 / (1 − h_i)² (hc3, as :func:`zcut.metrics.pooled_interval_many`:
a frame's weight grows with its leverage h_i, here the mean of its shares of the two denominators),
and a t quantile on the frames that hold that variance, (Σ v)² / Σ v² · (m − 1) / m with
v_i = c_i z_i² (m − 1 when every frame holds an equal share, fewer when a few frames hold most of it),
m the frames that define both figures. The interval is Δ ± q·se, clipped to [−1, 1]. Its coverage
is measured by simulation over frames (``bench/compare_coverage.py``, docs/compare.md).

No interval (NaN, NaN) when either figure is 0/0, when fewer than :data:`PAIRED_MIN_FRAMES` frames
define both, when one frame holds a whole denominator, or when the residuals are all zero (the two
filters differ in the same way on every frame).

Wins, losses, ties. Per frame, B wins when its figure is higher than A's, compared exactly on the
integer counts (no rounding); a figure that is 0/0 on a frame (nothing to find and nothing flagged,
for F1) counts as 1 — the filter made no error there. The sign test is the exact two-sided binomial
test of wins against losses (ties left out).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from zcut.errors import InputShapeError, ParameterError

#: The figures compared, in report order.
FIGURES: tuple[str, ...] = ("precision", "recall", "f1")
#: The fewest frames that must define both figures for the difference to get an interval.
PAIRED_MIN_FRAMES = 3
#: Per-frame (TP, FP, FN) of one filter: three integer arrays of one shape, frames on the last axis.
Counts = tuple[np.ndarray, np.ndarray, np.ndarray]


def figure_parts(figure: str, tp: np.ndarray, fp: np.ndarray, fn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame numerator and denominator of a pooled figure (float64)."""
    t, f, n = (np.asarray(a, dtype=np.float64) for a in (tp, fp, fn))
    if figure == "precision":
        return t, t + f
    if figure == "recall":
        return t, t + n
    if figure == "f1":
        return 2.0 * t, 2.0 * t + f + n
    raise ParameterError(f"figure must be one of {', '.join(FIGURES)}, got {figure!r}")


def _counts(a: object, name: str, shape: tuple[int, ...] | None) -> np.ndarray:
    arr = np.asarray(a)
    if arr.ndim < 1 or not np.issubdtype(arr.dtype, np.integer) or (shape is not None and arr.shape != shape):
        raise InputShapeError(f"{name} must be an integer array of per-frame counts"
                              + (f" of shape {shape}" if shape is not None else "")
                              + f", got {arr.dtype} {arr.shape}")
    if (arr < 0).any():
        raise ParameterError(f"{name} holds negative counts")
    return arr.astype(np.int64)


def paired_interval_many(a: Counts, b: Counts, *, level: float = 0.95) -> dict[str, np.ndarray]:
    """Δ = R_B − R_A and its interval for every figure, for a batch of samples (rows).

    Parameters
    ----------
    a, b : (tp, fp, fn), each (..., n_frames) int ndarray
        Per-frame counts of A and of B on the same frames, frames on the last axis.
    level : float
        Confidence level, in (0, 1).

    Returns
    -------
    dict of str to (..., 3) float64 ndarray
        Keys :data:`FIGURES`; ``[..., 0]`` = Δ, ``[..., 1]`` = lo, ``[..., 2]`` = hi; NaN where
        undefined (Δ: either figure 0/0; the interval: see the module's notes).
    """
    ta = _counts(a[0], "a.tp", None)
    shape = ta.shape
    fa, na = _counts(a[1], "a.fp", shape), _counts(a[2], "a.fn", shape)
    tb, fb, nb = (_counts(x, f"b.{k}", shape) for x, k in zip(b, ("tp", "fp", "fn")))
    lvl = float(level) if isinstance(level, (int, float)) and not isinstance(level, bool) else math.nan
    if not 0.0 < lvl < 1.0:
        raise ParameterError(f"level must be a number in (0, 1), got {level!r}")
    from scipy import stats

    out = {}
    for fig in FIGURES:
        num_a, den_a = figure_parts(fig, ta, fa, na)
        num_b, den_b = figure_parts(fig, tb, fb, nb)
        sa, sb = den_a.sum(-1), den_b.sum(-1)
        ok_a, ok_b = sa > 0, sb > 0
        ra = np.where(ok_a, num_a.sum(-1) / np.where(ok_a, sa, 1.0), np.nan)
        rb = np.where(ok_b, num_b.sum(-1) / np.where(ok_b, sb, 1.0), np.nan)
        delta = rb - ra
        za = (num_a - np.nan_to_num(ra)[..., None] * den_a) / np.where(ok_a, sa, 1.0)[..., None]
        zb = (num_b - np.nan_to_num(rb)[..., None] * den_b) / np.where(ok_b, sb, 1.0)[..., None]
        z = zb - za
        ha = den_a / np.where(ok_a, sa, 1.0)[..., None]
        hb = den_b / np.where(ok_b, sb, 1.0)[..., None]
        h = 0.5 * (ha + hb)
        lone = (ha >= 1.0).any(-1) | (hb >= 1.0).any(-1)
        one_minus = np.where(h < 1.0, 1.0 - h, 1.0)
        v = z * z / (one_minus * one_minus)
        var = v.sum(-1)
        m = np.count_nonzero((den_a > 0) & (den_b > 0), axis=-1)
        vv = (v * v).sum(-1)
        df = np.where(vv > 0, var * var / np.where(vv > 0, vv, 1.0) * (m - 1) / np.maximum(m, 1), np.nan)
        ok = ok_a & ok_b & ~lone & (m >= PAIRED_MIN_FRAMES) & (var > 0) & (df > 0)
        se = np.sqrt(var)
        q = np.where(ok, stats.t.ppf(0.5 + 0.5 * lvl, np.where(ok, df, 1.0)), np.nan)
        lo = np.where(ok, np.clip(delta - q * se, -1.0, 1.0), np.nan)
        hi = np.where(ok, np.clip(delta + q * se, -1.0, 1.0), np.nan)
        out[fig] = np.stack([delta, lo, hi], axis=-1)
    return out


@dataclass(frozen=True, slots=True)
class PairedDifference:
    """Δ = R_B − R_A of one pooled figure with its interval (NaN: none)."""

    figure: str
    a: float
    b: float
    delta: float
    lo: float
    hi: float

    @property
    def has_interval(self) -> bool:
        return not (math.isnan(self.lo) or math.isnan(self.hi))


def paired_differences(a: Counts, b: Counts, *, level: float = 0.95) -> dict[str, PairedDifference]:
    """:func:`paired_interval_many` for one set of frames ((n_frames,) counts), as records."""
    got = paired_interval_many(a, b, level=level)
    out = {}
    for fig in FIGURES:
        num_a, den_a = figure_parts(fig, *a)
        num_b, den_b = figure_parts(fig, *b)
        ra = float(num_a.sum() / den_a.sum()) if den_a.sum() > 0 else math.nan
        rb = float(num_b.sum() / den_b.sum()) if den_b.sum() > 0 else math.nan
        d, lo, hi = (float(x) for x in got[fig])
        out[fig] = PairedDifference(fig, ra, rb, d, lo, hi)
    return out


def frame_outcomes(a: Counts, b: Counts, *, figure: str = "f1") -> np.ndarray:
    """(n_frames,) int8: +1 where B's figure beats A's on the frame, −1 where it loses, 0 a tie.

    Compared exactly on the integer counts (num_B · den_A vs num_A · den_B); a 0/0 figure counts as 1.
    """
    num_a, den_a = (x.astype(np.int64) for x in figure_parts(figure, *a))
    num_b, den_b = (x.astype(np.int64) for x in figure_parts(figure, *b))
    na = np.where(den_a > 0, num_a, 1)
    da = np.where(den_a > 0, den_a, 1)
    nb = np.where(den_b > 0, num_b, 1)
    db = np.where(den_b > 0, den_b, 1)
    return np.sign(nb * da - na * db).astype(np.int8)


def sign_test(wins: int, losses: int) -> float:
    """Exact two-sided binomial p-value of ``wins`` against ``losses`` (p = 1/2; 1.0 with none)."""
    n = int(wins) + int(losses)
    if n == 0:
        return 1.0
    from scipy import stats

    return float(stats.binomtest(int(wins), n, 0.5, alternative="two-sided").pvalue)
