"""Metrics: the paper's relative metrics (docs/accuracy.md), true accuracy (docs/accuracy.md), annotator agreement.

True accuracy: :func:`scored_truth` checks one frame's truth (L ⊆ R ⊆ valid, the scored region,
the kind image) once and labels its components; :meth:`ScoredTruth.counts` scores a predicted
mask against it (pixels, clusters of >= 2 pixels, singletons, kinds) as :class:`AccuracyCounts`,
which add up over frames (micro average). :func:`pooled_interval` / :func:`pooled_interval_many`
give the 95 % intervals over frames of the pooled precision, recall and F1 from per-frame counts —
a t interval on the logit scale whose coverage was measured by simulation (``docs/accuracy.md``,
"Uncertainty"; ``docs/coverage.md``), NaN where too few frames make any interval meaningless.
:func:`bootstrap_ci` / :func:`bootstrap_ci_many` are the former percentile bootstrap (it covers
0.6–0.8 at 3 frames), kept as the baseline of ``bench/interval_coverage.py``.

All functions are pure. Ratios follow one rule: x / 0 is +inf for x > 0 (-inf for x < 0) and NaN
for 0 / 0 (JSON writers turn both into ``null``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from .cloud import check_mask
from .errors import InputShapeError, ParameterError, describe_array
from .types import Mask

__all__ = [
    "ACCURACY_KEYS",
    "BOOTSTRAP_STATS",
    "INTERVAL_MIN_FRAMES",
    "INTERVAL_STATS",
    "AccuracyCounts",
    "KindCounts",
    "RelativeMetrics",
    "ScoredTruth",
    "Sensitivity",
    "accuracy_counts",
    "bootstrap_ci",
    "bootstrap_ci_many",
    "bootstrap_weights",
    "cohen_kappa",
    "mask_iou",
    "pooled_interval",
    "pooled_interval_many",
    "ratio",
    "relative_metrics",
    "scored_truth",
    "sensitivity",
    "sensitivity_of",
]

#: The keys of :meth:`AccuracyCounts.as_dict`, in docs/accuracy.md order.
ACCURACY_KEYS = ("tp", "fp", "fn", "precision", "recall", "f1", "iou", "cluster_precision", "cluster_recall",
                 "singletons_precision", "singletons_recall")

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
# docs/accuracy.md: relative metrics (paper eqs. 3, 4, 6, 7)
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
    """N_both, N1, N2, α, β1, β2 of two outlier masks (docs/accuracy.md).

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
# docs/accuracy.md: true accuracy
# ------------------------------------------------------------------------------------------------
def _count(v: object, name: str) -> int:
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or v < 0:
        raise ParameterError(f"{name} must be a non-negative integer, got {v!r}")
    return int(v)


@dataclass(frozen=True, slots=True)
class KindCounts:
    """True outlier pixels of each kind and how many of them a prediction found (docs/accuracy.md, Kinds).

    Entry ``c - 1`` of each tuple belongs to kind code ``c`` (codes ``1 .. n_kinds``; the names are
    the caller's, e.g. ``replay.logs.layout.OUTLIER_KINDS``). ``+`` pools two frames.

    Attributes
    ----------
    labelled : (n_kinds,) tuple of int
        |L ∩ {kind = c}|: true outliers of the kind anywhere in the frame (scored or not); a kind
        is *held* by the truth iff this is > 0.
    n : (n_kinds,) tuple of int
        |L ∩ S ∩ {kind = c}|: those in the scored pixels S.
    found : (n_kinds,) tuple of int
        |P ∩ L ∩ S ∩ {kind = c}|: those the prediction P found.
    """

    labelled: tuple[int, ...]
    n: tuple[int, ...]
    found: tuple[int, ...]

    def __post_init__(self) -> None:
        size = len(self.labelled)
        if size == 0:
            raise ParameterError("KindCounts needs at least one kind, got none")
        for name in ("labelled", "n", "found"):
            values = tuple(getattr(self, name))
            if len(values) != size:
                raise ParameterError(f"KindCounts.{name} has {len(values)} entries, labelled has {size}")
            object.__setattr__(self, name, tuple(_count(v, f"KindCounts.{name}[{i}]") for i, v in enumerate(values)))
        for i, (lab, n, found) in enumerate(zip(self.labelled, self.n, self.found)):
            if not found <= n <= lab:
                raise ParameterError(f"KindCounts of kind code {i + 1} must have found <= n <= labelled, "
                                     f"got found {found}, n {n}, labelled {lab}")

    def __add__(self, other: object) -> KindCounts:
        if not isinstance(other, KindCounts):
            return NotImplemented
        if len(other.labelled) != len(self.labelled):
            raise ParameterError(f"cannot pool KindCounts of {len(self.labelled)} and {len(other.labelled)} kinds")
        return KindCounts(*(tuple(a + b for a, b in zip(getattr(self, k), getattr(other, k)))
                            for k in ("labelled", "n", "found")))

    @property
    def n_kinds(self) -> int:
        return len(self.labelled)

    @property
    def held(self) -> tuple[int, ...]:
        """The kind codes the truth holds (``labelled > 0``), ascending."""
        return tuple(i + 1 for i, lab in enumerate(self.labelled) if lab > 0)

    def recall(self, code: int) -> float:
        """found / n of kind ``code`` (NaN when no pixel of the kind is scored)."""
        if not 1 <= code <= self.n_kinds:
            raise ParameterError(f"kind code must be in 1..{self.n_kinds}, got {code!r}")
        return ratio(self.found[code - 1], self.n[code - 1])


_PAIRS = (("true_clusters_found", "true_clusters"), ("pred_clusters_correct", "pred_clusters"),
          ("true_singletons_found", "true_singletons"), ("pred_singletons_correct", "pred_singletons"))


@dataclass(frozen=True, slots=True)
class AccuracyCounts:
    """Pixel and cluster counts of one prediction P against the truth L over the scored pixels S.

    ``+`` and ``sum()`` pool frames (micro average: the rates of a sum are the pooled rates).
    Components are 8-connected; a component of two or more pixels is a *cluster*, a one-pixel
    component a *singleton*; the two are counted apart (docs/accuracy.md).

    Attributes
    ----------
    tp, fp, fn : int
        |P ∩ L ∩ S|, |P ∩ S ∖ L|, |L ∩ S ∖ P|.
    true_clusters, true_clusters_found : int
        Components of L ∩ S with >= 2 pixels, and those with >= 50 % of their pixels in P.
    pred_clusters, pred_clusters_correct : int
        Components of P ∩ S with >= 2 pixels, and those with >= 50 % of their pixels in L.
    true_singletons, true_singletons_found : int
        One-pixel components of L ∩ S, and those whose pixel is in P.
    pred_singletons, pred_singletons_correct : int
        One-pixel components of P ∩ S, and those whose pixel is in L.
    kinds : KindCounts or None
        Per-kind counts when the truth says what each outlier is; None otherwise. Counts with and
        without kinds cannot be pooled.
    """

    tp: int
    fp: int
    fn: int
    true_clusters: int
    true_clusters_found: int
    pred_clusters: int
    pred_clusters_correct: int
    true_singletons: int
    true_singletons_found: int
    pred_singletons: int
    pred_singletons_correct: int
    kinds: KindCounts | None = None

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name != "kinds":
                object.__setattr__(self, f.name, _count(getattr(self, f.name), f"AccuracyCounts.{f.name}"))
        for part, whole in _PAIRS:
            if getattr(self, part) > getattr(self, whole):
                raise ParameterError(f"AccuracyCounts.{part} ({getattr(self, part)}) exceeds "
                                     f"{whole} ({getattr(self, whole)})")
        if self.kinds is not None and not isinstance(self.kinds, KindCounts):
            raise ParameterError(f"AccuracyCounts.kinds must be a KindCounts or None, got {type(self.kinds).__name__}")

    @classmethod
    def zero(cls) -> AccuracyCounts:
        """All counts 0 and no kinds (the neutral element of ``+`` for counts without kinds)."""
        return cls(0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)

    def __add__(self, other: object) -> AccuracyCounts:
        if not isinstance(other, AccuracyCounts):
            return NotImplemented
        if (self.kinds is None) != (other.kinds is None):
            raise ParameterError("cannot pool accuracy counts with and without kind truth")
        kinds = None if self.kinds is None or other.kinds is None else self.kinds + other.kinds
        summed = {f.name: getattr(self, f.name) + getattr(other, f.name) for f in fields(self) if f.name != "kinds"}
        return AccuracyCounts(**summed, kinds=kinds)

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
        """Predicted clusters (>= 2 px) that are correct / predicted clusters."""
        return ratio(self.pred_clusters_correct, self.pred_clusters)

    @property
    def cluster_recall(self) -> float:
        """True clusters (>= 2 px) found / true clusters."""
        return ratio(self.true_clusters_found, self.true_clusters)

    @property
    def singletons_precision(self) -> float:
        """One-pixel predicted components that are correct / one-pixel predicted components."""
        return ratio(self.pred_singletons_correct, self.pred_singletons)

    @property
    def singletons_recall(self) -> float:
        """One-pixel true components found / one-pixel true components."""
        return ratio(self.true_singletons_found, self.true_singletons)

    def as_dict(self) -> dict[str, int | float]:
        """The numeric keys of a docs/accuracy.md entry (:data:`ACCURACY_KEYS`): counts as ``int``, rates as
        ``float`` (NaN for 0/0). ``ci95`` and ``by_kind`` are the report's (``annotate.accuracy``)."""
        return {k: getattr(self, k) for k in ACCURACY_KEYS}


@dataclass(frozen=True, slots=True, eq=False)
class ScoredTruth:
    """One frame's truth, checked once and prepared to score any number of predictions.

    Build it with :func:`scored_truth`; :meth:`counts` scores one predicted mask. The arrays are
    read-only.

    Attributes
    ----------
    scored : (H, W) bool ndarray
        The scored pixels S = R ∩ region.
    true_index : (n_true,) int64 ndarray
        Flat (row-major) indices of the pixels of L ∩ S, ascending.
    true_component : (n_true,) int64 ndarray
        The 8-connected component (1-based) of L ∩ S each of those pixels belongs to.
    true_sizes : (n_components + 1,) int64 ndarray
        Pixels per component; entry 0 is 0.
    true_kind : (n_true,) uint8 ndarray or None
        Kind code of each pixel of L ∩ S, when kinds were given.
    kind_labelled : (n_kinds,) tuple of int or None
        |L ∩ {kind = c}| for c = 1 .. n_kinds (the whole truth, scored or not).
    """

    scored: Mask
    true_index: np.ndarray
    true_component: np.ndarray
    true_sizes: np.ndarray
    true_kind: np.ndarray | None
    kind_labelled: tuple[int, ...] | None

    @property
    def shape(self) -> tuple[int, int]:
        return self.scored.shape

    def counts(self, predicted: Mask) -> AccuracyCounts:
        """Score one predicted outlier mask P (docs/accuracy.md).

        Parameters
        ----------
        predicted : (H, W) bool ndarray
            P, on the truth's grid. Pixels outside S are ignored.

        Returns
        -------
        AccuracyCounts
            With ``kinds`` when the truth has kinds.
        """
        p = check_mask(predicted, name="predicted", shape=self.shape)
        hit = p.ravel()[self.true_index]  # P at the pixels of L ∩ S
        ps = p & self.scored
        fp = int(np.count_nonzero(ps)) - int(np.count_nonzero(hit))
        # predicted components: correct iff >= 50 % of their pixels are in L (⇔ in L ∩ S: they lie in S)
        from scipy import ndimage  # here: a replay never loads it (0.15 CPU-s; docs/performance.md)

        labels, n_pred = ndimage.label(ps, structure=_EIGHT)
        if n_pred:
            flat = labels.ravel()
            p_size = np.bincount(flat[ps.ravel()], minlength=n_pred + 1)[1:]
            p_inside = np.bincount(flat[self.true_index], minlength=n_pred + 1)[1:]
        else:
            p_size = p_inside = np.zeros(0, dtype=np.int64)
        return self.counts_of(hit, fp, p_size, p_inside)

    def counts_of(self, hit: np.ndarray, fp: int, p_size: np.ndarray, p_inside: np.ndarray) -> AccuracyCounts:
        """The counts of one prediction P given where it lies; :meth:`counts` finds these by labelling
        the image, ``annotate.accuracy.frame_accuracies`` among P's pixels alone.

        Parameters
        ----------
        hit : (n_true,) bool ndarray
            P at the pixels of L ∩ S (:attr:`true_index`).
        fp : int
            |P ∩ S ∖ L|.
        p_size, p_inside : (n_pred,) int ndarray
            Pixels of each 8-connected component of P ∩ S (any order), and how many of them lie in L.

        Returns
        -------
        AccuracyCounts
            With ``kinds`` when the truth has kinds.
        """
        n_true = int(self.true_index.size)
        tp = int(np.count_nonzero(hit))
        # true components: found iff >= 50 % of their pixels are in P
        t_size = self.true_sizes[1:]
        t_inside = np.bincount(self.true_component[hit], minlength=t_size.size + 1)[1:]
        t_found = 2 * t_inside >= t_size
        t_single = t_size == 1
        # predicted components: correct iff >= 50 % of their pixels are in L
        p_correct = 2 * p_inside >= p_size
        p_single = p_size == 1
        kinds = None
        if self.true_kind is not None and self.kind_labelled is not None:
            n_kinds = len(self.kind_labelled)
            n = np.bincount(self.true_kind, minlength=n_kinds + 1)[1:]
            found = np.bincount(self.true_kind[hit], minlength=n_kinds + 1)[1:]
            kinds = KindCounts(self.kind_labelled, tuple(int(v) for v in n), tuple(int(v) for v in found))
        return AccuracyCounts(
            tp=tp, fp=fp, fn=n_true - tp,
            true_clusters=int(np.count_nonzero(~t_single)),
            true_clusters_found=int(np.count_nonzero(t_found & ~t_single)),
            pred_clusters=int(np.count_nonzero(~p_single)),
            pred_clusters_correct=int(np.count_nonzero(p_correct & ~p_single)),
            true_singletons=int(np.count_nonzero(t_single)),
            true_singletons_found=int(np.count_nonzero(t_found & t_single)),
            pred_singletons=int(np.count_nonzero(p_single)),
            pred_singletons_correct=int(np.count_nonzero(p_correct & p_single)),
            kinds=kinds,
        )


def _readonly(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def _check_kinds(kinds: object, truth: Mask, n_kinds: object) -> np.ndarray:
    if isinstance(n_kinds, (bool, np.bool_)) or not isinstance(n_kinds, (int, np.integer)) or not 1 <= n_kinds <= 255:
        raise ParameterError(f"n_kinds must be an integer in 1..255 when kinds are given, got {n_kinds!r}")
    k = np.asarray(kinds)
    if k.ndim != 2 or k.dtype != np.uint8 or k.shape != truth.shape:
        raise InputShapeError(f"kinds must be an (H, W) uint8 array of shape {truth.shape} like the outliers, "
                              f"got {describe_array(k)}")
    bad = k > n_kinds
    if bad.any():
        codes = np.unique(k[bad])
        raise ParameterError(f"kinds holds code(s) {codes.tolist()} outside 0..{int(n_kinds)} "
                             f"at {int(np.count_nonzero(bad))} pixel(s)")
    coded = k != 0
    extra = int(np.count_nonzero(coded & ~truth))
    if extra:
        raise ParameterError(f"kinds must be nonzero exactly where outliers is set: "
                             f"{extra} pixel(s) have a kind but are not outliers")
    missing = int(np.count_nonzero(truth & ~coded))
    if missing:
        raise ParameterError(f"kinds must be nonzero exactly where outliers is set: "
                             f"{missing} outlier pixel(s) have kind 0")
    return k


def scored_truth(
    outliers: Mask,
    *,
    reviewed: Mask | None = None,
    valid: Mask | None = None,
    region: Mask | None = None,
    kinds: np.ndarray | None = None,
    n_kinds: int | None = None,
) -> ScoredTruth:
    """Check one frame's truth and prepare it for scoring (docs/accuracy.md).

    The scored pixels are S = R ∩ region. Labels outside the region are not scored (no error);
    labels outside R are an error (L ⊆ R ⊆ valid).

    Parameters
    ----------
    outliers : (H, W) bool ndarray
        True outliers L (human labels or synthetic ground truth).
    reviewed : (H, W) bool ndarray, optional
        Reviewed pixels R. Default: ``valid`` if given, else every pixel.
    valid : (H, W) bool ndarray, optional
        Valid pixels of the frame; when given, R must lie inside it.
    region : (H, W) bool ndarray, optional
        The scored region (the caller's ``zone`` or ``valid`` mask). Default: every pixel (S = R).
    kinds : (H, W) uint8 ndarray, optional
        Kind code of each true outlier, 0 elsewhere: nonzero exactly where ``outliers`` is set,
        codes in ``0 .. n_kinds``. Restrict it as ``outliers`` is restricted (e.g. to the valid
        pixels) before passing both.
    n_kinds : int, optional
        The highest kind code (1..255); needed with ``kinds``, ignored without.

    Returns
    -------
    ScoredTruth

    Raises
    ------
    InputShapeError
        A mask is not 2-D bool of the outliers' shape; ``kinds`` is not (H, W) uint8 of that shape.
    ParameterError
        L is not inside R; R is not inside ``valid``; ``kinds`` holds a code above ``n_kinds``, a
        code where L is not set or 0 where it is; ``n_kinds`` is missing or out of range.
    """
    lab = check_mask(outliers, name="outliers")
    shape = lab.shape
    v = None if valid is None else check_mask(valid, name="valid", shape=shape)
    if reviewed is None:
        r = np.ones(shape, dtype=bool) if v is None else v
    else:
        r = check_mask(reviewed, name="reviewed", shape=shape)
        if v is not None:
            outside = int(np.count_nonzero(r & ~v))
            if outside:
                raise ParameterError(f"reviewed must lie inside valid: {outside} reviewed pixel(s) are invalid")
    outside = int(np.count_nonzero(lab & ~r))
    if outside:
        raise ParameterError(f"outliers must lie inside reviewed: {outside} labelled pixel(s) are not reviewed")
    s = r if region is None else r & check_mask(region, name="region", shape=shape)
    k = None if kinds is None else _check_kinds(kinds, lab, n_kinds)
    truth = lab & s
    from scipy import ndimage  # here: a replay never loads it (0.15 CPU-s; docs/performance.md)

    components, n = ndimage.label(truth, structure=_EIGHT)
    index = np.flatnonzero(truth)
    component = components.ravel()[index].astype(np.int64)
    sizes = np.bincount(component, minlength=n + 1).astype(np.int64)
    true_kind = kind_labelled = None
    if k is not None:
        assert n_kinds is not None  # _check_kinds refused kinds without n_kinds
        true_kind = _readonly(k.ravel()[index])
        kind_labelled = tuple(int(c) for c in np.bincount(k[lab], minlength=int(n_kinds) + 1)[1:])
    return ScoredTruth(
        scored=_readonly(s.copy()), true_index=_readonly(index), true_component=_readonly(component),
        true_sizes=_readonly(sizes), true_kind=true_kind, kind_labelled=kind_labelled,
    )


def accuracy_counts(
    predicted: Mask,
    outliers: Mask,
    *,
    reviewed: Mask | None = None,
    valid: Mask | None = None,
    region: Mask | None = None,
    kinds: np.ndarray | None = None,
    n_kinds: int | None = None,
) -> AccuracyCounts:
    """True accuracy counts of one predicted outlier mask (docs/accuracy.md).

    ``scored_truth(outliers, ...).counts(predicted)``; to score several predictions against one
    truth, build the :class:`ScoredTruth` once.

    Parameters
    ----------
    predicted : (H, W) bool ndarray
        Predicted outliers P.
    outliers, reviewed, valid, region, kinds, n_kinds
        As in :func:`scored_truth`.

    Returns
    -------
    AccuracyCounts
        Over S = R ∩ region: TP = |P ∩ L ∩ S|, FP = |P ∩ S ∖ L|, FN = |L ∩ S ∖ P|; the
        8-connected components of L ∩ S (found iff >= 50 % of their pixels are in P) and of
        P ∩ S (correct iff >= 50 % of their pixels are in L), components of >= 2 pixels as
        clusters and one-pixel components as singletons; per-kind counts with ``kinds``.

    Raises
    ------
    InputShapeError, ParameterError
        As :func:`scored_truth`; ``predicted`` not 2-D bool of the outliers' shape.
    """
    p = check_mask(predicted, name="predicted")
    check_mask(outliers, name="outliers", shape=p.shape)
    truth = scored_truth(outliers, reviewed=reviewed, valid=valid, region=region, kinds=kinds, n_kinds=n_kinds)
    return truth.counts(p)


# ------------------------------------------------------------------------------------------------
# docs/accuracy.md: bootstrap intervals over frames
# ------------------------------------------------------------------------------------------------
#: The pooled figures that carry an interval, in docs/accuracy.md order.
BOOTSTRAP_STATS: tuple[str, ...] = ("precision", "recall", "f1")
_CHUNK_ELEMENTS = 1 << 21  # rows x resamples handled at once (bounded memory for big sweeps)


def _check_int(v: object, name: str, lo: int) -> int:
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or v < lo:
        raise ParameterError(f"{name} must be an integer >= {lo}, got {v!r}")
    return int(v)


def bootstrap_weights(n_frames: int, *, n_boot: int = 2000, seed: int = 0) -> np.ndarray:
    """How often each frame is drawn in each bootstrap resample.

    Resample ``b`` draws ``n_frames`` frame indices uniformly with replacement: the rows of
    ``np.random.default_rng(seed).integers(0, n_frames, size=(n_boot, n_frames))``. The result
    depends only on ``(n_frames, n_boot, seed)``, so every method and every parameter set scored
    on the same frames is resampled the same way (paired comparisons).

    Parameters
    ----------
    n_frames : int
        Number of frames (>= 1).
    n_boot : int
        Number of resamples (>= 1).
    seed : int
        Seed of the generator (>= 0).

    Returns
    -------
    (n_boot, n_frames) float64 ndarray
        Entry ``[b, i]`` = how many times frame ``i`` is in resample ``b``; every row sums to
        ``n_frames``.
    """
    n = _check_int(n_frames, "n_frames", 1)
    b = _check_int(n_boot, "n_boot", 1)
    idx = np.random.default_rng(_check_int(seed, "seed", 0)).integers(0, n, size=(b, n))
    idx += (n * np.arange(b, dtype=idx.dtype))[:, None]
    return np.bincount(idx.ravel(), minlength=b * n).reshape(b, n).astype(np.float64)


def _frame_counts(a: object, name: str, shape: tuple[int, ...] | None) -> np.ndarray:
    arr = np.asarray(a)
    if arr.dtype.kind not in "iu" or arr.ndim < 1:
        raise InputShapeError(f"{name} must be an integer array of per-frame counts (frames on the last axis), "
                              f"got {describe_array(arr)}")
    if shape is not None and arr.shape != shape:
        raise InputShapeError(f"{name} must have shape {shape} like tp, got {describe_array(arr)}")
    if arr.size and arr.min() < 0:
        raise ParameterError(f"{name} must hold non-negative counts, got {arr.min()}")
    return arr


def _percentile_rows(x: np.ndarray, qs: tuple[float, ...]) -> list[np.ndarray]:
    """Percentiles (numpy's ``linear`` method) of each row of ``x`` over its non-NaN entries."""
    s = np.sort(x, axis=-1)  # NaN sort last
    k = x.shape[-1] - np.count_nonzero(np.isnan(x), axis=-1)
    last = np.maximum(k - 1, 0)
    out = []
    for q in qs:
        pos = q * last
        i0 = np.minimum(np.floor(pos).astype(np.int64), last)
        i1 = np.minimum(i0 + 1, last)
        t = pos - i0
        a = np.take_along_axis(s, i0[:, None], axis=-1)[:, 0]
        b = np.take_along_axis(s, i1[:, None], axis=-1)[:, 0]
        diff = b - a
        v = np.where(t >= 0.5, b - diff * (1.0 - t), a + diff * t)
        v = np.where(a == b, a, v)
        v[k == 0] = np.nan
        out.append(v)
    return out


def bootstrap_ci_many(
    tp: np.ndarray, fp: np.ndarray, fn: np.ndarray, *, n_boot: int = 2000, seed: int = 0, level: float = 0.95
) -> dict[str, np.ndarray]:
    """Percentile bootstrap intervals over frames of pooled precision, recall and F1, for a batch.

    The pooled (micro) figures of a set of frames are ratios of summed counts, e.g. precision =
    ΣTP / (ΣTP + ΣFP). A resample draws the frames with replacement (:func:`bootstrap_weights`)
    and recomputes the pooled figures from its summed counts; the interval is the
    ``(1 - level) / 2`` and ``(1 + level) / 2`` percentiles (numpy's ``linear`` method) of the
    resampled figures (the percentile method). Resamples where a figure is 0/0 (no predicted
    pixel in the resample, for precision; no true one, for recall) are left out of its
    percentiles; when no resample defines it the interval is (NaN, NaN) — always so when the
    pooled figure itself is 0/0. With one frame every resample is that frame: the interval is
    degenerate, lo = hi = the pooled figure. Every row of the batch uses the same resamples.

    Vectorised: the resampled sums are ``counts @ weights.T`` (exact: integers below 2**53 in
    float64), so a batch of parameter sets × methods costs one matrix product and one sort per
    figure.

    Parameters
    ----------
    tp, fp, fn : (..., n_frames) int ndarray
        Per-frame TP, FP, FN counts, frames on the last axis, the same shape each; the leading
        axes are a batch (methods, parameter sets...).
    n_boot : int
        Number of resamples (>= 1; docs/accuracy.md asks for >= 1000).
    seed : int
        Seed of the resampling (>= 0): the same input and seed give the same interval.
    level : float
        Confidence level, in (0, 1).

    Returns
    -------
    dict of str to (..., 2) float64 ndarray
        Keys :data:`BOOTSTRAP_STATS`; ``[..., 0]`` = lo, ``[..., 1]`` = hi; NaN where undefined
        (and everywhere when ``n_frames`` is 0).
    """
    t = _frame_counts(tp, "tp", None)
    f_p = _frame_counts(fp, "fp", t.shape)
    f_n = _frame_counts(fn, "fn", t.shape)
    lvl = float(level) if isinstance(level, (int, float, np.floating)) and not isinstance(level, bool) else math.nan
    if not 0.0 < lvl < 1.0:
        raise ParameterError(f"level must be a number in (0, 1), got {level!r}")
    n_boot = _check_int(n_boot, "n_boot", 1)
    seed = _check_int(seed, "seed", 0)
    batch, n = t.shape[:-1], t.shape[-1]
    out = {k: np.full((*batch, 2), np.nan) for k in BOOTSTRAP_STATS}
    if n == 0:
        return out
    wt = np.ascontiguousarray(bootstrap_weights(n, n_boot=n_boot, seed=seed).T)  # (n, n_boot)
    rows = int(np.prod(batch, dtype=np.int64))
    T, F, N = (a.reshape(rows, n).astype(np.float64) for a in (t, f_p, f_n))
    flat = {k: v.reshape(rows, 2) for k, v in out.items()}
    qs = ((1.0 - lvl) / 2.0, (1.0 + lvl) / 2.0)
    step = max(1, _CHUNK_ELEMENTS // n_boot)
    for start in range(0, rows, step):
        sl = slice(start, start + step)
        st, sf, sn = T[sl] @ wt, F[sl] @ wt, N[sl] @ wt  # (rows, n_boot) resampled sums
        for key, num, den in (("precision", st, st + sf), ("recall", st, st + sn),
                              ("f1", 2.0 * st, 2.0 * st + sf + sn)):
            stat = np.divide(num, den, out=np.full_like(num, np.nan), where=den > 0)
            lo, hi = _percentile_rows(stat, qs)
            flat[key][sl, 0] = lo
            flat[key][sl, 1] = hi
    return out


def bootstrap_ci(
    tp: np.ndarray, fp: np.ndarray, fn: np.ndarray, *, n_boot: int = 2000, seed: int = 0, level: float = 0.95
) -> dict[str, tuple[float, float]]:
    """Percentile bootstrap interval over frames of pooled precision, recall and F1 (one method).

    :func:`bootstrap_ci_many` for one set of per-frame counts; read its notes.

    Parameters
    ----------
    tp, fp, fn : (n_frames,) int ndarray
        Per-frame TP, FP, FN counts.
    n_boot, seed, level
        As in :func:`bootstrap_ci_many`.

    Returns
    -------
    dict of str to (float, float)
        ``{"precision": (lo, hi), "recall": (lo, hi), "f1": (lo, hi)}``; (NaN, NaN) where
        undefined; lo = hi = the pooled figure with one frame.
    """
    for name, a in (("tp", tp), ("fp", fp), ("fn", fn)):
        arr = np.asarray(a)
        if arr.ndim != 1:
            raise InputShapeError(f"{name} must be a 1-D array of per-frame counts, got {describe_array(arr)}")
    got = bootstrap_ci_many(tp, fp, fn, n_boot=n_boot, seed=seed, level=level)
    return {k: (float(v[0]), float(v[1])) for k, v in got.items()}


# ------------------------------------------------------------------------------------------------
# intervals over frames whose coverage is measured (docs/accuracy.md, "Uncertainty")
# ------------------------------------------------------------------------------------------------
#: The pooled figures that carry an interval, in report order.
INTERVAL_STATS: tuple[str, ...] = BOOTSTRAP_STATS
#: The fewest frames that must define a figure (a non-zero denominator) for it to get an interval.
INTERVAL_MIN_FRAMES = 3


def _figure_parts(key: str, t: np.ndarray, f_p: np.ndarray, f_n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame numerator and denominator of a pooled figure: precision TP / (TP + FP), recall
    TP / (TP + FN), F1 2TP / (2TP + FP + FN)."""
    if key == "precision":
        return t, t + f_p
    if key == "recall":
        return t, t + f_n
    return 2.0 * t, 2.0 * t + f_p + f_n


def _logit_t_rows(num: np.ndarray, den: np.ndarray, level: float) -> tuple[np.ndarray, np.ndarray]:
    """The interval of :func:`pooled_interval_many` for each row of ``num / den`` ((rows, n) float64)."""
    n_rows = num.shape[0]
    sd = den.sum(axis=-1)
    sn = num.sum(axis=-1)
    defined = sd > 0
    safe_sd = np.where(defined, sd, 1.0)
    r = np.where(defined, sn / safe_sd, np.nan)
    h = den / safe_sd[:, None]  # each frame's leverage; 0 for frames that do not define the ratio
    z = num - np.where(defined, r, 0.0)[:, None] * den  # residuals of the linearised ratio; Σ z = 0
    lone = (h >= 1.0).any(axis=-1)  # one frame holds the whole denominator
    one_minus = np.where(h < 1.0, 1.0 - h, 1.0)
    c = 1.0 / (one_minus * one_minus)  # hc3 weights
    v = c * z * z
    var_sum = v.sum(axis=-1)
    se = np.sqrt(var_sum) / safe_sd
    # Bell–McCaffrey degrees of freedom of that variance: tr(A)² / tr(A²) for A = M diag(h c) M,
    # M = I − √h √h'; both traces are sums over frames (bench/interval_coverage.py checks them
    # against the matrix)
    hc = h * c  # the diagonal of C
    s = (h * hc).sum(axis=-1)
    tr = hc.sum(axis=-1) - s
    diag = hc + h * (s[:, None] - 2.0 * hc)
    tr2 = ((diag * diag).sum(axis=-1) + 2.0 * (h * hc * hc).sum(axis=-1) - s * s
           - (h * h * (s[:, None] - 2.0 * hc) ** 2).sum(axis=-1))
    ok_bm = tr2 > 0
    df = np.where(ok_bm, tr * tr / np.where(ok_bm, tr2, 1.0), np.nan)
    # ... and no more than the frames that hold the variance: (Σ v)² / Σ v² · (m − 1) / m, m the frames
    # that define the ratio (m − 1, as Bell–McCaffrey's, when every frame holds an equal share)
    n_defined = np.count_nonzero(den > 0, axis=-1)
    vv = (v * v).sum(axis=-1)
    held = var_sum * var_sum / np.where(vv > 0, vv, 1.0) * (n_defined - 1) / np.maximum(n_defined, 1)
    df = np.where(vv > 0, np.fmin(df, held), df)
    ok = defined & ~lone & (n_defined >= INTERVAL_MIN_FRAMES) & (se > 0) & (r > 0) & (r < 1) & (df > 0)
    lo = np.full(n_rows, np.nan)
    hi = np.full(n_rows, np.nan)
    if ok.any():
        from scipy import special, stats  # scipy.stats costs ~1.3 CPU-s to import: only when an interval is asked

        ro, so = r[ok], se[ok]
        q = stats.t.ppf(0.5 + 0.5 * level, df[ok])
        g = np.log(ro) - np.log1p(-ro)
        sg = so / (ro * (1.0 - ro))
        lo[ok] = special.expit(g - q * sg)
        hi[ok] = special.expit(g + q * sg)
    return lo, hi


def pooled_interval_many(
    tp: np.ndarray, fp: np.ndarray, fn: np.ndarray, *, level: float = 0.95
) -> dict[str, np.ndarray]:
    """Intervals over frames of the pooled precision, recall and F1, for a batch; coverage measured.

    A pooled figure is a ratio of summed counts R = Σ num_i / Σ den_i over the frames (precision:
    num = TP, den = TP + FP; recall: TP, TP + FN; F1: 2TP, 2TP + FP + FN). The frames are a sample
    of a population of frames (one part kind, camera and config); the interval is for the figure
    pooled over that population:

    - the ratio linearised over frames: residuals z_i = num_i − R·den_i, variance
      Σ c_i z_i² / (Σ den)² with c_i = 1 / (1 − h_i)² (hc3: a frame's weight grows with its
      leverage h_i = den_i / Σ den, the share of the denominator it holds);
    - built on the logit scale, logit(R) ± q · se / (R (1 − R)), and mapped back (inside (0, 1));
    - q the t quantile of df degrees of freedom: the smaller of Bell and McCaffrey's
      (Satterthwaite's approximation for that variance under equal, independent frame errors: m − 1
      for m frames of equal weight, fewer when a few frames hold most of Σ den) and the number of
      frames that hold the variance, (Σ v_i)² / Σ v_i² · (m − 1) / m with v_i = c_i z_i² (fewer when
      a few frames hold most of the variance; m − 1 when all hold an equal share), m the frames
      that define the figure.

    No interval (NaN, NaN) when the figure is 0/0, when fewer than :data:`INTERVAL_MIN_FRAMES`
    frames define it (den_i > 0), or when every frame that defines it has the same value (e.g.
    precision 1 in every frame): the caller says "too few frames". Measured coverage of the 95 %
    interval by simulation over independent synthetic frames (``bench/interval_coverage.py``,
    held-out seeds): ``docs/coverage.md``. No randomness: the same input gives the same interval,
    and a row of a batch the same interval as alone.

    Parameters
    ----------
    tp, fp, fn : (..., n_frames) int ndarray
        Per-frame TP, FP, FN counts, frames on the last axis, the same shape each; the leading
        axes are a batch (methods, parameter sets...).
    level : float
        Confidence level, in (0, 1).

    Returns
    -------
    dict of str to (..., 2) float64 ndarray
        Keys :data:`INTERVAL_STATS`; ``[..., 0]`` = lo, ``[..., 1]`` = hi, 0 <= lo <= R <= hi <= 1
        (inside (0, 1) but for rounding); NaN where there is no interval.

    Raises
    ------
    InputShapeError
        Counts not integer arrays of one shape with a frame axis.
    ParameterError
        Negative counts; ``level`` outside (0, 1).
    """
    t = _frame_counts(tp, "tp", None)
    f_p = _frame_counts(fp, "fp", t.shape)
    f_n = _frame_counts(fn, "fn", t.shape)
    lvl = float(level) if isinstance(level, (int, float, np.floating)) and not isinstance(level, bool) else math.nan
    if not 0.0 < lvl < 1.0:
        raise ParameterError(f"level must be a number in (0, 1), got {level!r}")
    batch, n = t.shape[:-1], t.shape[-1]
    out = {k: np.full((*batch, 2), np.nan) for k in INTERVAL_STATS}
    if n == 0:
        return out
    rows = int(np.prod(batch, dtype=np.int64))
    T, F, N = (a.reshape(rows, n).astype(np.float64) for a in (t, f_p, f_n))
    flat = {k: v.reshape(rows, 2) for k, v in out.items()}
    step = max(1, _CHUNK_ELEMENTS // (8 * n))
    for start in range(0, rows, step):
        sl = slice(start, start + step)
        for key in INTERVAL_STATS:
            num, den = _figure_parts(key, T[sl], F[sl], N[sl])
            lo, hi = _logit_t_rows(num, den, lvl)
            flat[key][sl, 0] = lo
            flat[key][sl, 1] = hi
    return out


def pooled_interval(
    tp: np.ndarray, fp: np.ndarray, fn: np.ndarray, *, level: float = 0.95
) -> dict[str, tuple[float, float]]:
    """The interval of :func:`pooled_interval_many` for one set of per-frame counts; read its notes.

    Parameters
    ----------
    tp, fp, fn : (n_frames,) int ndarray
        Per-frame TP, FP, FN counts.
    level : float
        Confidence level, in (0, 1).

    Returns
    -------
    dict of str to (float, float)
        ``{"precision": (lo, hi), "recall": (lo, hi), "f1": (lo, hi)}``; (NaN, NaN) where there is
        no interval (too few frames, or no variation between them).
    """
    for name, a in (("tp", tp), ("fp", fp), ("fn", fn)):
        arr = np.asarray(a)
        if arr.ndim != 1:
            raise InputShapeError(f"{name} must be a 1-D array of per-frame counts, got {describe_array(arr)}")
    got = pooled_interval_many(tp, fp, fn, level=level)
    return {k: (float(v[0]), float(v[1])) for k, v in got.items()}


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
