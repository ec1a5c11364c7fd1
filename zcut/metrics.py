"""Metrics: the paper's relative metrics (SPEC §3), true accuracy (SPEC §4), annotator agreement.

All functions are pure. Ratios follow one rule: x / 0 is +inf for x > 0 (-inf for x < 0) and NaN
for 0 / 0 (JSON writers turn both into ``null``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
from scipy import ndimage

from .cloud import check_mask
from .errors import ParameterError
from .types import Mask

__all__ = [
    "ACCURACY_KEYS",
    "AccuracyCounts",
    "RelativeMetrics",
    "Sensitivity",
    "accuracy_counts",
    "cohen_kappa",
    "mask_iou",
    "ratio",
    "relative_metrics",
    "sensitivity",
    "sensitivity_of",
]

#: The keys of :meth:`AccuracyCounts.as_dict`, in SPEC §4 order.
ACCURACY_KEYS = ("tp", "fp", "fn", "precision", "recall", "f1", "iou", "cluster_precision", "cluster_recall")

_EIGHT = np.ones((3, 3), dtype=bool)
_EIGHT.setflags(write=False)


def ratio(num: float, den: float) -> float:
    """``num / den`` as a float, with x / 0 = +inf (x > 0), -inf (x < 0) and 0 / 0 = NaN.

    Integers are divided exactly (``int / int`` rounds once), so count ratios are reproducible.
    """
    if den == 0:
        if num == 0 or (isinstance(num, float) and math.isnan(num)):
            return math.nan
        return math.inf if num > 0 else -math.inf
    return float(num / den)


# ------------------------------------------------------------------------------------------------
# SPEC §3: relative metrics (paper eqs. 3, 4, 6, 7)
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class RelativeMetrics:
    """Outlier counts shared by and exclusive to SOR (n = 1) and the z-cut (n = 2).

    Attributes
    ----------
    n_both : int
        Outliers found by both methods.
    n1, n2 : int
        Outliers found by SOR only, by the z-cut only.
    alpha : float
        N1 / N2 (eq. 3).
    beta1, beta2 : float
        N_both / N1 and N_both / N2 (eq. 4).
    """

    n_both: int
    n1: int
    n2: int
    alpha: float
    beta1: float
    beta2: float

    @classmethod
    def from_counts(cls, n_both: int, n1: int, n2: int) -> RelativeMetrics:
        """Derive α, β1, β2 from the three counts (each a non-negative integer)."""
        for name, v in (("n_both", n_both), ("n1", n1), ("n2", n2)):
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or v < 0:
                raise ParameterError(f"{name} must be a non-negative integer, got {v!r}")
        n_both, n1, n2 = int(n_both), int(n1), int(n2)
        return cls(n_both, n1, n2, ratio(n1, n2), ratio(n_both, n1), ratio(n_both, n2))


def relative_metrics(sor_mask: Mask, zcut_mask: Mask) -> RelativeMetrics:
    """N_both, N1, N2, α, β1, β2 of two outlier masks (SPEC §3).

    Parameters
    ----------
    sor_mask : (H, W) bool ndarray
        Outliers of SOR (method n = 1).
    zcut_mask : (H, W) bool ndarray
        Outliers of the z-cut (method n = 2).

    Returns
    -------
    RelativeMetrics
    """
    s = check_mask(sor_mask, name="sor_mask")
    z = check_mask(zcut_mask, name="zcut_mask", shape=s.shape)
    n_both = int(np.count_nonzero(s & z))
    return RelativeMetrics.from_counts(n_both, int(np.count_nonzero(s)) - n_both, int(np.count_nonzero(z)) - n_both)


@dataclass(frozen=True, slots=True)
class Sensitivity:
    """Low and high ratios of a count at 0.5x and 1.5x a nominal parameter (paper eqs. 6, 7).

    For ρ_thr these are θ_n,Lo and θ_n,Hi; for d_max, ω_n,Lo and ω_n,Hi.
    """

    lo: float
    hi: float


def sensitivity(n_lo: int, n_nominal: int, n_hi: int) -> Sensitivity:
    """θ (or ω) from the counts N_n at 0.5x, 1x and 1.5x the nominal parameter.

    Parameters
    ----------
    n_lo, n_nominal, n_hi : int
        N_n(0.5·p*), N_n(p*), N_n(1.5·p*) for p = ρ_thr (θ) or p = d_max (ω).

    Returns
    -------
    Sensitivity
        ``lo = n_lo / n_nominal``, ``hi = n_hi / n_nominal`` (x/0 = inf, 0/0 = NaN).
    """
    for name, v in (("n_lo", n_lo), ("n_nominal", n_nominal), ("n_hi", n_hi)):
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or v < 0:
            raise ParameterError(f"{name} must be a non-negative integer, got {v!r}")
    return Sensitivity(ratio(int(n_lo), int(n_nominal)), ratio(int(n_hi), int(n_nominal)))


def sensitivity_of(
    lo: RelativeMetrics, nominal: RelativeMetrics, hi: RelativeMetrics
) -> tuple[Sensitivity, Sensitivity]:
    """(θ1, θ2) — or (ω1, ω2) — from the relative metrics of three z-cut runs.

    Parameters
    ----------
    lo, nominal, hi : RelativeMetrics
        SOR against the z-cut run at 0.5x, 1x and 1.5x the nominal parameter.

    Returns
    -------
    tuple of Sensitivity
        For n = 1 (N1, SOR only) and n = 2 (N2, z-cut only).
    """
    return (
        sensitivity(lo.n1, nominal.n1, hi.n1),
        sensitivity(lo.n2, nominal.n2, hi.n2),
    )


# ------------------------------------------------------------------------------------------------
# SPEC §4: true accuracy
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class AccuracyCounts:
    """Pixel and cluster counts of one prediction against labels; ``+`` and ``sum()`` pool them.

    Attributes
    ----------
    tp, fp, fn : int
        |P ∩ L|, |P ∩ R ∖ L|, |L ∖ P| over the reviewed pixels R.
    true_clusters, true_clusters_found : int
        8-connected components of L, and those with >= 50 % of their pixels in P.
    pred_clusters, pred_clusters_correct : int
        8-connected components of P ∩ R, and those with >= 50 % of their pixels in L.
    """

    tp: int
    fp: int
    fn: int
    true_clusters: int
    true_clusters_found: int
    pred_clusters: int
    pred_clusters_correct: int

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or v < 0:
                raise ParameterError(f"AccuracyCounts.{f.name} must be a non-negative integer, got {v!r}")
            object.__setattr__(self, f.name, int(v))
        if self.true_clusters_found > self.true_clusters:
            raise ParameterError(
                f"AccuracyCounts.true_clusters_found ({self.true_clusters_found}) exceeds "
                f"true_clusters ({self.true_clusters})"
            )
        if self.pred_clusters_correct > self.pred_clusters:
            raise ParameterError(
                f"AccuracyCounts.pred_clusters_correct ({self.pred_clusters_correct}) exceeds "
                f"pred_clusters ({self.pred_clusters})"
            )

    @classmethod
    def zero(cls) -> AccuracyCounts:
        """All counts 0 (the neutral element of ``+``)."""
        return cls(0, 0, 0, 0, 0, 0, 0)

    def __add__(self, other: object) -> AccuracyCounts:
        if not isinstance(other, AccuracyCounts):
            return NotImplemented
        return AccuracyCounts(*(getattr(self, f.name) + getattr(other, f.name) for f in fields(self)))

    def __radd__(self, other: object) -> AccuracyCounts:
        if isinstance(other, int) and not isinstance(other, bool) and other == 0:  # sum() starts at 0
            return self
        return NotImplemented

    @property
    def precision(self) -> float:
        return ratio(self.tp, self.tp + self.fp)

    @property
    def recall(self) -> float:
        return ratio(self.tp, self.tp + self.fn)

    @property
    def f1(self) -> float:
        return ratio(2 * self.tp, 2 * self.tp + self.fp + self.fn)

    @property
    def iou(self) -> float:
        return ratio(self.tp, self.tp + self.fp + self.fn)

    @property
    def cluster_precision(self) -> float:
        return ratio(self.pred_clusters_correct, self.pred_clusters)

    @property
    def cluster_recall(self) -> float:
        return ratio(self.true_clusters_found, self.true_clusters)

    def as_dict(self) -> dict[str, int | float]:
        """The SPEC §4 entry: counts as ``int``, rates as ``float`` (NaN for 0/0)."""
        return {
            "tp": self.tp,
            "fp": self.fp,
            "fn": self.fn,
            "precision": self.precision,
            "recall": self.recall,
            "f1": self.f1,
            "iou": self.iou,
            "cluster_precision": self.cluster_precision,
            "cluster_recall": self.cluster_recall,
        }


def _clusters_hit(components: np.ndarray, other: np.ndarray) -> tuple[int, int]:
    """(number of 8-connected components of ``components``, those with >= 50 % inside ``other``)."""
    labels, n = ndimage.label(components, structure=_EIGHT)
    if n == 0:
        return 0, 0
    size = np.bincount(labels.ravel(), minlength=n + 1)[1:]
    inside = np.bincount(labels[other], minlength=n + 1)[1:]
    return int(n), int(np.count_nonzero(2 * inside >= size))


def accuracy_counts(
    predicted: Mask, outliers: Mask, *, reviewed: Mask | None = None, valid: Mask | None = None
) -> AccuracyCounts:
    """True accuracy counts of a predicted outlier mask against labels (SPEC §4).

    Parameters
    ----------
    predicted : (H, W) bool ndarray
        Predicted outliers P.
    outliers : (H, W) bool ndarray
        Labelled true outliers L; must lie inside the reviewed pixels R.
    reviewed : (H, W) bool ndarray, optional
        Reviewed pixels R. Default: ``valid`` if given, else every pixel.
    valid : (H, W) bool ndarray, optional
        Valid pixels of the frame; when given, R must lie inside it.

    Returns
    -------
    AccuracyCounts
        TP = |P ∩ L|, FP = |P ∩ R ∖ L|, FN = |L ∖ P|; true clusters = 8-connected components of L
        (found iff >= 50 % of their pixels are in P); predicted clusters = components of P ∩ R
        (correct iff >= 50 % of their pixels are in L).

    Raises
    ------
    InputShapeError
        A mask is not 2-D bool or its shape differs from ``predicted``'s.
    ParameterError
        L is not inside R, or R is not inside ``valid``.
    """
    p = check_mask(predicted, name="predicted")
    lab = check_mask(outliers, name="outliers", shape=p.shape)
    v = None if valid is None else check_mask(valid, name="valid", shape=p.shape)
    if reviewed is None:
        r = np.ones(p.shape, dtype=bool) if v is None else v
    else:
        r = check_mask(reviewed, name="reviewed", shape=p.shape)
        if v is not None:
            outside = int(np.count_nonzero(r & ~v))
            if outside:
                raise ParameterError(f"reviewed must lie inside valid: {outside} reviewed pixel(s) are invalid")
    outside = int(np.count_nonzero(lab & ~r))
    if outside:
        raise ParameterError(f"outliers must lie inside reviewed: {outside} labelled pixel(s) are not reviewed")
    pr = p & r
    tp = int(np.count_nonzero(pr & lab))
    fp = int(np.count_nonzero(pr & ~lab))
    fn = int(np.count_nonzero(lab & ~p))
    true_n, true_found = _clusters_hit(lab, p)
    pred_n, pred_correct = _clusters_hit(pr, lab)
    return AccuracyCounts(tp, fp, fn, true_n, true_found, pred_n, pred_correct)


# ------------------------------------------------------------------------------------------------
# inter-annotator agreement
# ------------------------------------------------------------------------------------------------
def _pair(a: Mask, b: Mask, where: Mask | None) -> tuple[np.ndarray, np.ndarray]:
    ma = check_mask(a, name="a")
    mb = check_mask(b, name="b", shape=ma.shape)
    if where is None:
        return ma.ravel(), mb.ravel()
    w = check_mask(where, name="where", shape=ma.shape)
    return ma[w], mb[w]


def cohen_kappa(a: Mask, b: Mask, *, where: Mask | None = None) -> float:
    """Cohen's κ of two binary masks over the pixels in ``where`` (default: all).

    Parameters
    ----------
    a, b : (H, W) bool ndarray
        The two annotators' outlier masks.
    where : (H, W) bool ndarray, optional
        Pixels both annotators reviewed.

    Returns
    -------
    float
        (p_o − p_e) / (1 − p_e), computed from integer counts; NaN when p_e = 1 and p_o = 1
        (both annotators constant and equal, or no pixel), as 0/0.
    """
    va, vb = _pair(a, b, where)
    n = int(va.size)
    n_a = int(np.count_nonzero(va))
    n_b = int(np.count_nonzero(vb))
    agree = int(np.count_nonzero(va == vb))
    chance = n_a * n_b + (n - n_a) * (n - n_b)  # p_e · n²
    return ratio(n * agree - chance, n * n - chance)


def mask_iou(a: Mask, b: Mask, *, where: Mask | None = None) -> float:
    """|a ∩ b| / |a ∪ b| over the pixels in ``where`` (default: all); 0/0 = NaN.

    Parameters
    ----------
    a, b : (H, W) bool ndarray
    where : (H, W) bool ndarray, optional

    Returns
    -------
    float
    """
    va, vb = _pair(a, b, where)
    return ratio(int(np.count_nonzero(va & vb)), int(np.count_nonzero(va | vb)))
