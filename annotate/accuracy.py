"""True accuracy of the outlier filters against the truth (docs/accuracy.md): the report and its table.

The report's functions are pure, on arrays: no file I/O, no printing. :func:`run` (at the end) is
``zcut accuracy`` as a library call: ``run(AccuracyOptions(log=path))`` opens the log, computes or
reads the predictions, gathers the truth and returns an :class:`AccuracyResult` (warnings on stderr).
Its callers, and ``zcut demo``, gather per-frame predictions and truth, then::

    frames = [frame_accuracy(i, stamp_ns, {"zcut": z, "sor": s}, truth,
                             reviewed=r, valid=v, region=zone, kinds=kind_image) for ...]
    unscored = [UnscoredFrame(i, stamp_ns, "no /ground_truth/outliers"), ...]
    report = accuracy_report(frames, region="zone", unscored=unscored)  # docs/accuracy.md dict (NaN kept)
    print(report_json(report))                # NaN / inf -> null, every count an int
    print(format_accuracy_table(report))

A method's prediction is an (H, W) bool mask; ``union`` and ``intersection`` are derived from
``zcut`` and ``sor``. Counts are taken over the scored pixels S = R ∩ region (R: the reviewed
pixels, default the valid ones or every pixel; region: the caller's mask of the region it names,
``zone`` or ``valid``, default every pixel). Components of >= 2 pixels are clusters, one-pixel
components singletons, counted apart. With a kind image (``/ground_truth/outlier_kind``, the codes
of :data:`replay.logs.layout.OUTLIER_KINDS`) recall is also given per kind. Pooled figures sum the
counts over frames (micro average); pooled precision, recall and F1 carry a 95 % interval over
frames whose coverage was measured by simulation (:func:`zcut.metrics.pooled_interval_many`: a t
interval on the logit scale; ``docs/accuracy.md``, "Uncertainty"; ``docs/coverage.md``), none
("too few frames") with fewer than 3 frames or no variation between them; the same input gives the
same interval.
Frames the caller could not score are listed under ``unscored`` with the reason, not dropped.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numba
import numpy as np

from replay.logs.layout import OUTLIER_KINDS
from replay.options import PipelineOptions
from replay.pipeline.methods import method_masks as method_masks_of
from replay.pipeline.methods import reported_methods
from zcut.cloud import check_mask
from zcut.errors import InputShapeError, ParameterError
from zcut.metrics import (
    ACCURACY_KEYS,
    INTERVAL_MIN_FRAMES,
    INTERVAL_STATS,
    AccuracyCounts,
    KindCounts,
    ScoredTruth,
    pooled_interval_many,
    ratio,
    scored_truth,
)
from zcut.types import Mask

if TYPE_CHECKING:
    from replay.logs.damage import Damage

#: Methods of the default report (the config's default methods and the derived pair), in the order
#: shown; a report lists the methods its predictions hold (``--methods``).
METHODS: tuple[str, ...] = ("zcut", "sor", "union", "intersection")
#: Keys of one method's entry (docs/accuracy.md), in the order shown; then ``ci95`` (pooled) and ``by_kind``.
COUNT_KEYS: tuple[str, ...] = ("tp", "fp", "fn")
RATE_KEYS: tuple[str, ...] = ACCURACY_KEYS[3:]
METRIC_KEYS: tuple[str, ...] = ACCURACY_KEYS
#: Pooled figures with a 95 % interval (``ci95``).
CI_KEYS: tuple[str, ...] = INTERVAL_STATS
#: Names of the scored regions (docs/accuracy.md) and what each scores.
REGIONS: dict[str, str] = {
    "zone": "the pixels the filters judge: valid minus table and bin, plus the above-the-rim points",
    "valid": "every valid pixel",
}
#: Kind codes of the truth's kind image and their names (docs/formats.md).
KINDS: dict[int, str] = dict(OUTLIER_KINDS)
N_KINDS: int = max(KINDS)
#: What the report's intervals are, and their coverage measured on held-out synthetic frames
#: (``docs/coverage.md``: the worst cell over four filters, three figures and two part kinds).
INTERVAL_NOTE: str = ("95 % logit-t intervals over the frames, measured coverage >= 0.93 at 3-24 frames "
                      "(docs/coverage.md)")
#: Size classes of the truth's components (8-connected components of L ∩ S, in pixels): name -> the
#: smallest size of the class (docs/accuracy.md, "Recall by size").
SIZE_CLASSES: dict[str, int] = {"1px": 1, "2-9px": 2, "10-99px": 10, ">=100px": 100}
#: Displacement classes of the true outliers, |Z − Z_GT| in mm where the log has ``/ground_truth/depth``:
#: name -> the upper bound of the class (docs/accuracy.md, "Recall by displacement").
DISPLACEMENT_CLASSES: dict[str, float] = {"<=1mm": 1.0, "1-5mm": 5.0, "5-30mm": 30.0, ">30mm": math.inf}
#: The families of classes a report may hold per method, and their classes in the order shown.
CLASS_FAMILIES: dict[str, tuple[str, ...]] = {
    "by_size": tuple(SIZE_CLASSES),
    "detectable": ("detectable",),
    "by_displacement": tuple(DISPLACEMENT_CLASSES),
}


@dataclass(frozen=True, slots=True)
class Undecided:
    """How much of a method's verdict fell on pixels the truth left undecided (docs/accuracy.md,
    "Undecided pixels"): of its ``flagged`` outlier pixels in the region (valid ones), ``undecided``
    lie outside R — an annotator's labels did not judge them, so they are in no count."""

    undecided: int
    flagged: int

    def __add__(self, other: Undecided) -> Undecided:
        return Undecided(self.undecided + other.undecided, self.flagged + other.flagged)

    @property
    def share(self) -> float:
        """undecided / flagged (NaN when the method flagged nothing in the region)."""
        return ratio(self.undecided, self.flagged)

    def as_dict(self) -> dict[str, int | float]:
        return {"px": self.undecided, "flagged": self.flagged, "share": self.share}


@dataclass(frozen=True, slots=True)
class FrameAccuracy:
    """Accuracy counts of every method on one frame.

    Attributes
    ----------
    index : int
        0-based index of the frame in its log.
    stamp_ns : int
        Header stamp of the frame's cloud.
    counts : dict[str, AccuracyCounts]
        One entry per reported method, in the order shown; with ``kinds`` when the frame has kind
        truth.
    bin_check : float or None
        The bin check's figure of the frame (``docs/pipeline.md``, "Bin removal"; NaN when the bin
        stages failed); None when unknown (a results file) or the bin stages did not run.
    bin_flagged : bool or None
        Whether the bin check flagged the frame: its scores rest on a bin removal that did not
        work; None when unknown.
    classes : dict[str, dict[str, KindCounts]]
        Per method, per family of :data:`CLASS_FAMILIES` the frame's truth has (``by_size``
        always, ``detectable`` and ``by_displacement`` where the truth says), the true outlier
        pixels of each class (``n``) and those found; entry ``i`` is the family's class ``i``.
    undecided : dict[str, Undecided]
        Per method, its outliers in the region and those of them on pixels the truth left
        undecided (not reviewed: outside R); only when the caller asked (``--labels``).
    labels_vs_fits : LabelsVsFits or None
        The labels' own agreement with ``explained`` on the frame (:func:`labels_vs_fits`); only
        with labels, where ``explained`` could be run (or read from a results file).
    """

    index: int
    stamp_ns: int
    counts: dict[str, AccuracyCounts]
    bin_check: float | None = None
    bin_flagged: bool | None = None
    classes: dict[str, dict[str, KindCounts]] = field(default_factory=dict)
    undecided: dict[str, Undecided] = field(default_factory=dict)
    labels_vs_fits: LabelsVsFits | None = None

    @property
    def methods(self) -> tuple[str, ...]:
        return tuple(self.counts)

    @property
    def has_kinds(self) -> bool:
        return next(iter(self.counts.values())).kinds is not None


@dataclass(frozen=True, slots=True)
class UnscoredFrame:
    """A frame the caller could not score (e.g. its truth is missing), listed in the report.

    Attributes
    ----------
    index : int
        0-based index of the frame in its log.
    stamp_ns : int
        Header stamp of the frame's cloud.
    reason : str
        Why it is not scored, one line (e.g. ``"no /ground_truth/outliers"``).
    """

    index: int
    stamp_ns: int
    reason: str

    def __post_init__(self) -> None:
        for name in ("index", "stamp_ns"):
            v = getattr(self, name)
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
                raise ParameterError(f"UnscoredFrame.{name} must be an integer, got {v!r}")
            object.__setattr__(self, name, int(v))
        if not isinstance(self.reason, str) or not self.reason.strip() or "\n" in self.reason:
            raise ParameterError(f"UnscoredFrame.reason must be a non-empty line of text, got {self.reason!r}")

    def as_dict(self) -> dict[str, int | str]:
        return {"index": self.index, "stamp_ns": self.stamp_ns, "reason": self.reason}


def method_masks(zcut: Mask, sor: Mask) -> dict[str, Mask]:
    """The four predictions of the default report from the two filters' masks.

    Parameters
    ----------
    zcut, sor : (H, W) bool ndarray
        Outliers of the z-cut filter and of statistical outlier removal.

    Returns
    -------
    dict[str, (H, W) bool ndarray]
        Keys :data:`METHODS`: ``zcut``, ``sor``, ``union`` (either), ``intersection`` (both).
    """
    z = check_mask(zcut, name="zcut", shape=None)
    s = check_mask(sor, name="sor", shape=z.shape)
    return {"zcut": z, "sor": s, "union": z | s, "intersection": z & s}


def reported_masks(predictions: Mapping[str, Mask]) -> dict[str, Mask]:
    """Every method a report lists from the predictions given: the given ones in their order, a
    union ``a+b`` from its members' masks when only those are given, and ``union`` and
    ``intersection`` after them when ``zcut`` and ``sor`` are both given (docs/accuracy.md)."""
    if not predictions:
        raise ParameterError("predictions must hold at least one method's mask")
    first = next(iter(predictions.values()))
    shape = check_mask(first, name=f"predictions[{next(iter(predictions))!r}]", shape=None).shape
    base = {m: check_mask(p, name=f"predictions[{m!r}]", shape=shape) for m, p in predictions.items()}
    names = reported_methods(list(base))
    try:
        return method_masks_of(base, names)
    except KeyError as e:
        raise ParameterError(f"predictions lack {e.args[0]!r}, a member of a union they name") from None


def frame_accuracy(
    index: int,
    stamp_ns: int,
    predictions: Mapping[str, Mask],
    outliers: Mask,
    *,
    reviewed: Mask | None = None,
    valid: Mask | None = None,
    region: Mask | None = None,
    kinds: np.ndarray | None = None,
    detectable: Mask | None = None,
    displacement_mm: np.ndarray | None = None,
    undecided: bool = False,
) -> FrameAccuracy:
    """Count pixels, clusters, singletons, kinds and classes of every method on one frame (docs/accuracy.md).

    Parameters
    ----------
    index : int
        0-based frame index.
    stamp_ns : int
        Header stamp of the frame.
    predictions : mapping str -> (H, W) bool ndarray
        Every method to score (base methods, unions ``a+b``); ``union`` and ``intersection`` are
        derived when ``"zcut"`` and ``"sor"`` are both given (:func:`reported_masks`).
    outliers : (H, W) bool ndarray
        True outliers L (labels or synthetic ground truth); L ⊆ R.
    reviewed : (H, W) bool ndarray, optional
        Reviewed pixels R. Default: ``valid`` if given, else every pixel.
    valid : (H, W) bool ndarray, optional
        Valid pixels; when given, R ⊆ valid is checked.
    region : (H, W) bool ndarray, optional
        The scored region's pixels (the mask of the region named in :func:`accuracy_report`):
        counts are taken over S = R ∩ region; labels outside it are not scored. Default: every
        pixel.
    kinds : (H, W) uint8 ndarray, optional
        Kind codes of :data:`KINDS`, nonzero exactly where ``outliers`` is set (restrict it as
        ``outliers`` is restricted, e.g. ``np.where(truth, kind, 0)``). Adds per-kind counts.
    detectable : (H, W) bool ndarray, optional
        The true outliers geometry can tell (``/ground_truth/detectable``): adds the ``detectable``
        class. Pixels outside ``outliers`` are ignored.
    displacement_mm : (H, W) float ndarray, optional
        |Z − Z_GT| (mm) of every pixel (NaN where unknown): adds the ``by_displacement`` classes
        (a true outlier of unknown displacement is in none).
    undecided : bool
        Also count, per method, its outliers in the region (and ``valid``) that lie outside R: the
        pixels the truth left undecided (:class:`Undecided`).

    Returns
    -------
    FrameAccuracy

    Raises
    ------
    ParameterError
        No prediction, or a union's member missing; L ⊄ R or R ⊄ valid; a kind code outside 0..5, or a kind
        where L is not set (or none where it is).
    InputShapeError
        A mask (or the kind image) is not 2-D bool (uint8) of the truth's shape.
    """
    truth = check_mask(outliers, name="outliers", shape=None)
    preds = reported_masks(predictions)
    for m, p in preds.items():
        check_mask(p, name=f"predictions[{m!r}]", shape=truth.shape)
    scored = scored_truth(truth, reviewed=reviewed, valid=valid, region=region, kinds=kinds,
                          n_kinds=N_KINDS)
    counts = {m: scored.counts(p) for m, p in preds.items()}
    codes = truth_classes(scored, detectable=detectable, displacement_mm=displacement_mm)
    classes = {m: {fam: _class_counts(c, preds[m].ravel()[scored.true_index], len(CLASS_FAMILIES[fam]))
                   for fam, c in codes.items()} for m in preds}
    open_ = {}
    if undecided:
        judged = np.ones(truth.shape, dtype=bool)
        for mask, name in ((region, "region"), (valid, "valid")):
            if mask is not None:
                judged &= check_mask(mask, name=name, shape=truth.shape)
        rev = reviewed if reviewed is not None else valid
        left = judged if rev is None else judged & ~check_mask(rev, name="reviewed", shape=truth.shape)
        open_ = {m: Undecided(int(np.count_nonzero(p & left)), int(np.count_nonzero(p & judged)))
                 for m, p in preds.items()}
    return FrameAccuracy(index=int(index), stamp_ns=int(stamp_ns), counts=counts, classes=classes,
                         undecided=open_)


def frame_accuracies(
    index: int,
    stamp_ns: int,
    sides: Sequence[tuple[Mapping[str, Mask], Mask, Mask]],
    outliers: Mask,
    *,
    reviewed: Mask | None = None,
    kinds: np.ndarray | None = None,
    detectable: Mask | None = None,
    displacement_mm: np.ndarray | Displacement | None = None,
) -> list[FrameAccuracy]:
    """:func:`frame_accuracy` of several sides on one frame's truth, each side its ``(predictions,
    valid, region)``: equal, side by side, to ``[frame_accuracy(index, stamp_ns, predictions,
    outliers, reviewed=reviewed, valid=valid, region=region, kinds=kinds, detectable=detectable,
    displacement_mm=displacement_mm) for predictions, valid, region in sides]`` (the same counts and
    classes; the same error, raised by that call, on bad input), at a fraction of their cost (a
    comparison's A and B, ``zcut compare``): the truth is checked once and prepared once for the sides
    whose valid pixels and region are equal (sides that share their bin stages), and the 8-connected
    components of the true outliers and of each prediction are found among their pixels alone
    (:func:`components8`), not by labelling the whole image. ``displacement_mm`` may be a
    :class:`Displacement`: it is then computed at the scored true outliers alone."""
    try:
        fast = _frame_accuracies(index, stamp_ns, sides, outliers, reviewed=reviewed, kinds=kinds,
                                 detectable=detectable, displacement_mm=displacement_mm)
    except (ParameterError, InputShapeError, TypeError, ValueError):
        fast = None
    if fast is not None:
        return fast
    # something is off: frame_accuracy checks it and raises its own error (or scores it, if it can)
    if isinstance(displacement_mm, Displacement):
        displacement_mm = displacement_mm.image()
    return [frame_accuracy(index, stamp_ns, preds, outliers, reviewed=reviewed, valid=valid, region=region,
                           kinds=kinds, detectable=detectable, displacement_mm=displacement_mm)
            for preds, valid, region in sides]


def _is_mask(m: object, shape: tuple[int, ...]) -> bool:
    return isinstance(m, np.ndarray) and m.dtype == np.bool_ and m.shape == shape


def _frame_accuracies(index: int, stamp_ns: int, sides: Sequence[tuple[Mapping[str, Mask], Mask, Mask]],
                      outliers: Mask, *, reviewed: Mask | None, kinds: np.ndarray | None, detectable: Mask | None,
                      displacement_mm: np.ndarray | Displacement | None) -> list[FrameAccuracy] | None:
    """:func:`frame_accuracies` when every check :func:`frame_accuracy` makes passes (cheap whole-image
    checks); None when one would fail (the caller then lets :func:`frame_accuracy` raise)."""
    if not isinstance(outliers, np.ndarray) or outliers.ndim != 2 or outliers.dtype != np.bool_:
        return None
    shape = outliers.shape
    if reviewed is not None and not _is_mask(reviewed, shape):
        return None
    if detectable is not None and not _is_mask(detectable, shape):
        return None
    if isinstance(displacement_mm, Displacement):
        if displacement_mm.shape != shape or displacement_mm.depth.shape != shape:
            return None
    elif displacement_mm is not None and (not isinstance(displacement_mm, np.ndarray)
                                          or displacement_mm.shape != shape or displacement_mm.dtype.kind != "f"):
        return None
    kind_labelled = None
    if kinds is not None:
        if not isinstance(kinds, np.ndarray) or kinds.dtype != np.uint8 or kinds.shape != shape:
            return None
        coded = kinds != 0
        if not np.array_equal(coded, outliers) or int(kinds.max(initial=0)) > N_KINDS:
            return None
        kind_labelled = tuple(int(c) for c in np.bincount(kinds[outliers], minlength=N_KINDS + 1)[1:])
    out: list[FrameAccuracy] = []
    prepared: list[tuple[Mask, Mask, ScoredTruth, dict[str, np.ndarray]]] = []
    for predictions, valid, region in sides:
        if not predictions or not _is_mask(valid, shape) or not _is_mask(region, shape):
            return None
        if not all(_is_mask(p, shape) for p in predictions.values()):
            return None
        preds = reported_masks(predictions)
        st_codes = next(((st, codes) for v, g, st, codes in prepared
                         if (v is valid or np.array_equal(v, valid)) and (g is region or np.array_equal(g, region))),
                        None)
        if st_codes is None:
            r = valid if reviewed is None else reviewed
            if reviewed is not None and reviewed is not valid and np.count_nonzero(reviewed & ~valid):
                return None  # R ⊄ valid
            if np.count_nonzero(outliers & ~r):
                return None  # L ⊄ R
            s = r & region
            n_true, index_t, component = components8(outliers & s)
            st = ScoredTruth(scored=_read_only(s), true_index=_read_only(index_t),
                             true_component=_read_only(component),
                             true_sizes=_read_only(np.bincount(component, minlength=n_true + 1).astype(np.int64)),
                             true_kind=None if kinds is None else _read_only(kinds.ravel()[index_t]),
                             kind_labelled=kind_labelled)
            if isinstance(displacement_mm, Displacement):  # read at the scored true outliers alone
                codes = truth_classes(st, detectable=detectable)
                codes["by_displacement"] = _displacement_codes(displacement_mm.at(st.true_index))
            else:
                codes = truth_classes(st, detectable=detectable, displacement_mm=displacement_mm)
            st_codes = (st, codes)
            prepared.append((valid, region, *st_codes))
        st, codes = st_codes
        counts = {m: _sparse_counts(st, p) for m, p in preds.items()}
        classes = {m: {fam: _class_counts(c, preds[m].ravel()[st.true_index], len(CLASS_FAMILIES[fam]))
                       for fam, c in codes.items()} for m in preds}
        out.append(FrameAccuracy(index=int(index), stamp_ns=int(stamp_ns), counts=counts, classes=classes,
                                 undecided={}))
    return out


def _read_only(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


#: Below this share of set pixels, :func:`components8` labels the set pixels alone (:func:`_label_sparse8`,
#: a union-find in raster order); above it, it labels the whole image (``scipy.ndimage.label``). Either
#: way the components and their numbers are the same; only the cost differs (a 1920 x 1200 image costs
#: ``ndimage.label`` about 6 CPU-ms whatever it holds; 13 000 set pixels cost the union-find ~0.1 ms).
_SPARSE_SHARE = 1 / 32


@numba.njit(cache=True, nogil=True)
def _label_sparse8(index, w):  # type: ignore[no-untyped-def]  # numba kernel
    """The 8-connected components of the pixels at the flat (row-major) indices ``index`` (int64,
    strictly ascending) of an image ``w`` pixels wide: ``(n, label)``, ``label`` (int64) numbered 1..n in
    the order of each component's first pixel. Each pixel is joined (union-find over positions in
    ``index``) to its set neighbours before it in raster order (left; up-left, up, up-right: found by a
    pointer into the row above, which only moves forward as the pixels do), then a pass in raster
    order numbers each root when its first pixel is met."""
    n = index.size
    parent = np.arange(n)
    p = 0
    for i in range(n):
        q = index[i]
        c = q % w
        if c > 0 and i > 0 and index[i - 1] == q - 1:  # left
            _join(parent, i, i - 1)
        lo = q - w - 1 if c > 0 else q - w
        hi = q - w + 1 if c < w - 1 else q - w
        while p < i and index[p] < lo:
            p += 1
        j = p
        while j < i and index[j] <= hi:  # the row above
            _join(parent, i, j)
            j += 1
    label = np.empty(n, dtype=np.int64)
    number = np.zeros(n, dtype=np.int64)
    k = 0
    for i in range(n):
        r = _root(parent, i)
        if number[r] == 0:
            k += 1
            number[r] = k
        label[i] = number[r]
    return k, label


@numba.njit(cache=True, nogil=True, inline="always")
def _root(parent, i):  # type: ignore[no-untyped-def]  # numba kernel
    while parent[i] != i:
        parent[i] = parent[parent[i]]  # path halving
        i = parent[i]
    return i


@numba.njit(cache=True, nogil=True, inline="always")
def _join(parent, i, j):  # type: ignore[no-untyped-def]  # numba kernel
    a, b = _root(parent, i), _root(parent, j)
    if a != b:
        if a < b:
            parent[b] = a
        else:
            parent[a] = b


def components8(mask: Mask) -> tuple[int, np.ndarray, np.ndarray]:
    """The 8-connected components of a 2-D bool mask at its set pixels: ``(n, index, label)``, ``index``
    the flat (row-major) indices of the set pixels, ascending, and ``label`` (int64) the component of
    each, numbered 1..n exactly as ``scipy.ndimage.label(mask, structure=np.ones((3, 3)))`` numbers
    them (in the order of each component's first pixel in row-major order)."""
    index = np.flatnonzero(mask)
    n = index.size
    if n == 0:
        return 0, index, np.zeros(0, dtype=np.int64)
    if n > mask.size * _SPARSE_SHARE:
        from scipy import ndimage

        lab, k = ndimage.label(mask, structure=np.ones((3, 3), dtype=bool))
        return int(k), index, lab.ravel()[index].astype(np.int64)
    k, label = _label_sparse8(index.astype(np.int64, copy=False), int(mask.shape[1]))
    return int(k), index, label


def _sparse_counts(st: ScoredTruth, predicted: Mask) -> AccuracyCounts:
    """``st.counts(predicted)`` (the same counts), the prediction's components found among its pixels
    (:func:`components8`); ``st.true_component`` may number the truth's components in any order."""
    hit = predicted.ravel()[st.true_index]  # P at the pixels of L ∩ S
    n_pred, index_p, comp_p = components8(predicted & st.scored)
    fp = int(index_p.size) - int(np.count_nonzero(hit))
    if n_pred:
        p_size = np.bincount(comp_p, minlength=n_pred + 1)[1:]
        # the true pixels P holds lie in P ∩ S: their components
        at = np.searchsorted(index_p, st.true_index[hit])
        p_inside = np.bincount(comp_p[at], minlength=n_pred + 1)[1:]
    else:
        p_size = p_inside = np.zeros(0, dtype=np.int64)
    return st.counts_of(hit, fp, p_size, p_inside)


def truth_classes(scored: ScoredTruth, *, detectable: Mask | None = None,
                  displacement_mm: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The class of every scored true outlier, per family (docs/accuracy.md, "Recall by size").

    Parameters
    ----------
    scored : ScoredTruth
        The frame's truth as :func:`zcut.metrics.scored_truth` prepared it.
    detectable, displacement_mm : (H, W) ndarray, optional
        As :func:`frame_accuracy` takes them.

    Returns
    -------
    dict[str, (n_true,) uint8 ndarray]
        Family name -> for each pixel of L ∩ S (``scored.true_index`` order) its class code, 1-based
        in the order of :data:`CLASS_FAMILIES`, 0 = in no class of the family.
    """
    sizes = scored.true_sizes[scored.true_component]
    out = {"by_size": (np.searchsorted(np.array(list(SIZE_CLASSES.values())), sizes, side="right"))
           .astype(np.uint8)}
    if detectable is not None:
        det = check_mask(detectable, name="detectable", shape=scored.shape)
        out["detectable"] = det.ravel()[scored.true_index].astype(np.uint8)
    if displacement_mm is not None:
        d = np.asarray(displacement_mm, dtype=np.float64)
        if d.shape != scored.shape:
            raise ParameterError(f"displacement_mm is {d.shape}, the truth {scored.shape}")
        out["by_displacement"] = _displacement_codes(d.ravel()[scored.true_index])
    return out


def _displacement_codes(v: np.ndarray) -> np.ndarray:
    """The ``by_displacement`` class codes of displacements ``v`` (float64 mm; 0 where not finite)."""
    bounds = np.array(list(DISPLACEMENT_CLASSES.values())[:-1])
    code = (np.searchsorted(bounds, v, side="left") + 1).astype(np.uint8)
    code[~np.isfinite(v)] = 0
    return code


def _class_counts(codes: np.ndarray, hit: np.ndarray, n_classes: int) -> KindCounts:
    n = np.bincount(codes, minlength=n_classes + 1)[1:n_classes + 1]
    found = np.bincount(codes[hit], minlength=n_classes + 1)[1:n_classes + 1]
    return KindCounts(tuple(int(v) for v in n), tuple(int(v) for v in n), tuple(int(v) for v in found))


def pooled_classes(frames: Iterable[FrameAccuracy]) -> dict[str, dict[str, KindCounts]]:
    """Per method, the class counts summed over the frames, for each family every frame has (a
    family some frames lack is left out: its pooled ``n`` would not be the frames')."""
    frames = list(frames)
    if not frames:
        return {}
    out: dict[str, dict[str, KindCounts]] = {}
    for m in frames[0].methods:
        fams = [fam for fam in CLASS_FAMILIES if all(fam in f.classes.get(m, {}) for f in frames)]
        out[m] = {fam: sum((f.classes[m][fam] for f in frames[1:]), frames[0].classes[m][fam]) for fam in fams}
    return out


def classes_entry(family: str, counts: KindCounts) -> dict[str, Any]:
    """A family's report entry: ``{CLASS: {"n", "found", "recall"}}`` (``detectable``: the one class's
    ``{"n", "found", "recall"}`` itself)."""
    names = CLASS_FAMILIES[family]
    e = {name: {"n": counts.n[i], "found": counts.found[i], "recall": ratio(counts.found[i], counts.n[i])}
         for i, name in enumerate(names)}
    return e[names[0]] if family == "detectable" else e


def pooled_counts(frames: Iterable[FrameAccuracy]) -> dict[str, AccuracyCounts]:
    """Sum the counts of every method over the frames (micro average); zero counts of
    :data:`METHODS` if there is no frame.

    Raises
    ------
    ParameterError
        Some frames have kind truth and others not; the frames score different methods.
    """
    frames = list(frames)
    with_kinds = sum(f.has_kinds for f in frames)
    if 0 < with_kinds < len(frames):
        raise ParameterError(f"kind truth is given for {with_kinds} of {len(frames)} frames: give it for every "
                             f"scored frame or for none (list the others as unscored)")
    if not frames:
        return {m: AccuracyCounts.zero() for m in METHODS}
    methods = frames[0].methods
    for f in frames[1:]:
        if f.methods != methods:
            raise ParameterError(f"frame {f.index} scores {list(f.methods)}, frame {frames[0].index} "
                                 f"{list(methods)}: every frame must score the same methods")
    return {m: sum((f.counts[m] for f in frames[1:]), frames[0].counts[m]) for m in methods}


def by_kind(kinds: KindCounts) -> dict[str, dict[str, int | float]]:
    """The ``by_kind`` entry: ``{KIND: {"n", "found", "recall"}}`` for the kinds the truth holds.

    Parameters
    ----------
    kinds : KindCounts
        Per-kind counts with the codes of :data:`KINDS`.

    Returns
    -------
    dict
        In code order; ``n`` = true outlier pixels of the kind in the scored region, ``found`` =
        those predicted, ``recall`` = found / n (NaN when n = 0: the kind is held only outside
        the region).
    """
    if kinds.n_kinds != N_KINDS:
        raise ParameterError(f"kinds must count the {N_KINDS} kind codes of the truth, got {kinds.n_kinds}")
    return {KINDS[c]: {"n": kinds.n[c - 1], "found": kinds.found[c - 1], "recall": kinds.recall(c)}
            for c in kinds.held}


def _entry(c: AccuracyCounts, ci: Mapping[str, list[float]] | None = None,
           classes: Mapping[str, KindCounts] | None = None) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in c.as_dict().items():
        out[k] = int(v) if k in COUNT_KEYS else float(v)
    if ci is not None:
        out["ci95"] = {k: list(ci[k]) for k in CI_KEYS}
    if c.kinds is not None:
        out["by_kind"] = by_kind(c.kinds)
    for fam, kc in (classes or {}).items():
        out[fam] = classes_entry(fam, kc)
    return out


def accuracy_report(
    frames: Iterable[FrameAccuracy],
    *,
    region: str = "valid",
    unscored: Iterable[UnscoredFrame] = (),
    left_out: Mapping[str, tuple[Iterable[int], str]] | None = None,
    truth: str | None = None,
) -> dict[str, Any]:
    """The docs/accuracy.md report object.

    Parameters
    ----------
    frames : iterable of FrameAccuracy
        The scored frames, in the order to list them.
    region : {"zone", "valid"}
        Name of the region the frames' ``region`` masks describe; ``"valid"`` when they were
        counted without a region mask over the valid pixels.
    unscored : iterable of UnscoredFrame
        Frames the caller could not score, listed with their reason.
    left_out : mapping of str to (iterable of int, str), optional
        Per method, scored frames (by index) that this method alone was not scored on, and why —
        ``learned`` leaves out the frames its model was trained on. The caller counts nothing for
        the method there (its counts on those frames are 0).

    Returns
    -------
    dict
        ``{"region", "pooled": {METHOD: {tp, fp, fn, precision, recall, f1, iou,
        cluster_precision, cluster_recall, singletons_precision, singletons_recall,
        "ci95": {"precision": [lo, hi], "recall": [lo, hi], "f1": [lo, hi]}, "by_kind": {...},
        "by_size": {CLASS: {"n", "found", "recall"}}, "detectable": {"n", "found", "recall"},
        "by_displacement": {CLASS: {"n", "found", "recall"}},
        "frames_scored": n, "frames_left_out": [index, ...], "left_out_reason": str or None}},
        "frames": [{"index", "stamp_ns", METHOD: {... the same keys but ci95}}],
        "unscored": [{"index", "stamp_ns", "reason"}], "bin_flagged"}`` with METHOD the frames'
        methods; each frame also has ``bin_check`` and ``bin_flagged`` (the bin check, None when
        unknown) and ``bin_flagged`` counts the scored frames it flagged (None when not known for
        every frame);
        ``by_kind`` only with kind truth; ``by_size`` always (:data:`SIZE_CLASSES`), ``detectable``
        and ``by_displacement`` only when every frame's truth has them. Counts are ``int``; rates are ``float`` and may be NaN
        (0/0) — :func:`report_json` writes them as ``null``. An interval is NaN (no interval) where
        :func:`zcut.metrics.pooled_interval_many` gives none: fewer than 3 frames define the figure, or
        they all have the same value.

    Raises
    ------
    ParameterError
        Unknown region name; a frame both scored and unscored; kind truth in some frames only; a
        ``left_out`` method the frames do not hold, or a left-out frame that is not scored, or that
        the method has counts on.

    With ``truth`` (what the frames were scored against, e.g. :data:`annotate.truth.TRUTH_NAMES`'s) the
    report names it (``"truth"``, after ``"region"``). Where every frame counted its undecided pixels
    (:func:`frame_accuracy`'s ``undecided``), each method's entry has ``"undecided": {"px", "flagged",
    "share"}``. Where every frame has the labels' agreement with the fits
    (:attr:`FrameAccuracy.labels_vs_fits`), that frame has ``"labels_vs_fits"``
    (:meth:`LabelsVsFits.as_dict`) and the report its sum over those frames, with ``"frames"``: how many.
    """
    if region not in REGIONS:
        raise ParameterError(f"region must be one of {', '.join(REGIONS)}, got {region!r}")
    frames = list(frames)
    unscored = list(unscored)
    for u in unscored:
        if not isinstance(u, UnscoredFrame):
            raise ParameterError(f"unscored must hold UnscoredFrame entries, got {type(u).__name__}")
    both = sorted({f.index for f in frames} & {u.index for u in unscored})
    if both:
        raise ParameterError(f"frame(s) {both} are listed both as scored and as unscored")
    pooled = pooled_counts(frames)
    pooled_cls = pooled_classes(frames)
    methods = tuple(pooled)
    out_of = _left_out(frames, methods, left_out or {})
    per_frame = {k: np.array([[getattr(f.counts[m], k) for f in frames] for m in methods], dtype=np.int64)
                 .reshape(len(methods), len(frames)) for k in COUNT_KEYS}
    ci = pooled_interval_many(per_frame["tp"], per_frame["fp"], per_frame["fn"])
    open_ = ({m: sum((f.undecided[m] for f in frames), Undecided(0, 0)) for m in methods}
             if frames and all(m in f.undecided for f in frames for m in methods) else {})
    with_fits = [f.labels_vs_fits for f in frames if f.labels_vs_fits is not None]
    vs_fits = sum(with_fits, LabelsVsFits.empty()) if with_fits else None
    return {
        "region": region,
        **({"truth": truth} if truth is not None else {}),
        **({"labels_vs_fits": {**vs_fits.as_dict(), "frames": len(with_fits)}} if vs_fits is not None else {}),
        "pooled": {m: {**_entry(pooled[m], {k: ci[k][i].tolist() for k in CI_KEYS}, pooled_cls.get(m)),
                       **({"undecided": open_[m].as_dict()} if open_ else {}),
                       "frames_scored": len(frames) - len(out_of.get(m, ((), None))[0]),
                       "frames_left_out": list(out_of.get(m, ((), None))[0]),
                       "left_out_reason": out_of.get(m, ((), None))[1]}
                   for i, m in enumerate(methods)},
        "frames": [
            {"index": f.index, "stamp_ns": f.stamp_ns,
             **{m: {**_entry(f.counts[m], None, f.classes.get(m)),
                    **({"undecided": f.undecided[m].as_dict()} if open_ else {})} for m in methods},
             **({"labels_vs_fits": f.labels_vs_fits.as_dict()} if f.labels_vs_fits is not None else {}),
             "bin_check": f.bin_check, "bin_flagged": f.bin_flagged}
            for f in frames
        ],
        "unscored": [u.as_dict() for u in unscored],
        # scored frames the bin check flagged (None: not known for every frame, e.g. a results file)
        "bin_flagged": (sum(bool(f.bin_flagged) for f in frames)
                        if frames and all(f.bin_flagged is not None for f in frames) else None),
    }


def _left_out(frames: list[FrameAccuracy], methods: tuple[str, ...],
              left_out: Mapping[str, tuple[Iterable[int], str]]) -> dict[str, tuple[list[int], str]]:
    """The checked ``left_out`` of :func:`accuracy_report`: method -> (sorted frame indices, reason)."""
    by_index = {f.index: f for f in frames}
    out = {}
    for m, (indices, reason) in left_out.items():
        if m not in methods:
            raise ParameterError(f"left_out names {m!r}, which the frames do not score (they hold {', '.join(methods)})")
        if not isinstance(reason, str) or not reason.strip() or "\n" in reason:
            raise ParameterError(f"left_out[{m!r}]: the reason must be a non-empty line of text, got {reason!r}")
        idx = sorted({int(i) for i in indices})
        for i in idx:
            f = by_index.get(i)
            if f is None:
                raise ParameterError(f"left_out[{m!r}]: frame {i} is not a scored frame")
            c = f.counts[m]
            if c.tp or c.fp or c.fn:
                raise ParameterError(f"left_out[{m!r}]: frame {i} has counts for {m} (a left-out frame counts nothing)")
        if idx:
            out[m] = (idx, reason)
    return out


def jsonable(obj: object) -> object:
    """A copy of ``obj`` (dicts, lists, numbers) with NaN and infinities replaced by ``None``."""
    if isinstance(obj, dict):
        return {k: jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else None
    return obj


def report_json(report: dict[str, Any], *, indent: int | None = None) -> str:
    """Strict JSON text of a report (NaN / inf -> ``null``; never emits ``NaN``)."""
    return json.dumps(jsonable(report), indent=indent, allow_nan=False)


# ------------------------------------------------------------------ text tables
def _fmt_rate(v: float | None) -> str:
    if v is None or not math.isfinite(v):
        return "-"
    return f"{v:.3f}"


def _fmt_ci(v: float | None, ci: list[float | None] | None) -> str:
    lo, hi = (None, None) if ci is None else ci
    if lo is None or hi is None or not (math.isfinite(lo) and math.isfinite(hi)):
        if v is None or not math.isfinite(v):
            return "-"
        return _fmt_rate(v) + (" [too few frames]" if ci is not None else "")
    return f"{_fmt_rate(v)} [{lo:.3f}, {hi:.3f}]"


UNDECIDED_LEGEND = ("undecided: share (pixels) of the method's outliers in the region on pixels the labels left "
                    "undecided, in no count above")
_FRAME_HEADER = ("tp", "fp", "fn", "prec", "recall", "F1", "IoU", "cl.P", "cl.R", "1px.P", "1px.R")
_LEGEND = "cl.P, cl.R: cluster (>= 2 px) precision, recall; 1px.P, 1px.R: singleton (1 px) precision, recall"
_CLUSTER_ROWS = (("cluster precision (>= 2 px)", "cluster_precision"), ("cluster recall", "cluster_recall"),
                 ("singleton precision (1 px)", "singletons_precision"), ("singleton recall", "singletons_recall"))


def _render(header: list[str], rows: list[list[str]], left: int, tight: int | None = None) -> str:
    """Columns ``< left`` left-aligned, the others right-aligned; two spaces between columns, one
    between the columns from ``tight`` on (fixed-width rates)."""
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    lines = []
    for r in [header, *rows]:
        cells = [c.ljust(w) if i < left else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths))]
        line = cells[0]
        for i, c in enumerate(cells[1:], start=1):
            line += (" " if tight is not None and i > tight else "  ") + c
        lines.append(line.rstrip())
    return "\n".join(lines)


def _frame_row(prefix: list[str], e: Mapping[str, Any]) -> list[str]:
    return prefix + [str(e[k]) for k in COUNT_KEYS] + [_fmt_rate(e[k]) for k in RATE_KEYS]


def format_accuracy_table(report: dict[str, Any], *, per_frame: bool = True) -> str:
    """Plain-text tables of a report (at most ~120 columns; ``-`` for undefined rates).

    The region; per frame (optional) every method's counts and rates; pooled counts with the 95 %
    intervals of precision, recall and F1; pooled cluster and singleton rates; pooled recall by
    kind when the truth has kinds; the unscored frames with their reasons.

    Parameters
    ----------
    report : dict
        As returned by :func:`accuracy_report` (or parsed back from :func:`report_json`).
    per_frame : bool
        Include one row per frame and method before the pooled tables.
    """
    region = report["region"]
    parts = [f"region: {region} ({REGIONS.get(region, 'unknown region')})"]
    frames = report["frames"]
    METHODS = tuple(report["pooled"])  # noqa: N806 - the report's own methods
    if per_frame and frames:
        rows = [_frame_row([str(f["index"]), str(f["stamp_ns"]), m], f[m]) for f in frames for m in METHODS]
        table = _render(["frame", "stamp_ns", "method", *_FRAME_HEADER], rows, left=3, tight=6)
        parts.append(f"per frame\n{table}\n{_LEGEND}")
    n = len(frames)
    pooled = report["pooled"]
    note = INTERVAL_NOTE if n >= INTERVAL_MIN_FRAMES else \
        f"no intervals: too few frames (an interval needs {INTERVAL_MIN_FRAMES})"
    rows = [[m, *(str(pooled[m][k]) for k in COUNT_KEYS),
             *(_fmt_ci(pooled[m][k], pooled[m].get("ci95", {}).get(k)) for k in CI_KEYS),
             _fmt_rate(pooled[m]["iou"])] for m in METHODS]
    head = ["method", *COUNT_KEYS, "precision [95 %]", "recall [95 %]", "F1 [95 %]", "IoU"]
    open_ = all("undecided" in pooled[m] for m in METHODS)
    if open_:
        head.append("undecided")
        for r, m in zip(rows, METHODS):
            u = pooled[m]["undecided"]
            r.append(f"{_fmt_rate(u['share'])} ({u['px']})")
    parts.append(f"pooled over {n} frame{'s' if n != 1 else ''} ({note})\n" + _render(head, rows, left=1)
                 + ("\n" + UNDECIDED_LEGEND if open_ else ""))
    rows = [[label, *(_fmt_rate(pooled[m][k]) for m in METHODS)] for label, k in _CLUSTER_ROWS]
    parts.append(_render(["clusters and singletons, pooled", *METHODS], rows, left=1))
    kinds = [k for k in KINDS.values() if any(k in pooled[m].get("by_kind", {}) for m in METHODS)]
    if kinds:
        rows = []
        for k in kinds:
            e = {m: pooled[m]["by_kind"][k] for m in METHODS}
            rows.append([k, str(e[METHODS[0]]["n"]),
                         *(f"{_fmt_rate(e[m]['recall'])} ({e[m]['found']})" for m in METHODS)])
        parts.append("recall by kind, pooled: recall (found) of the n true outlier pixels of each kind in the region\n"
                     + _render(["kind", "n", *METHODS], rows, left=1))
    for fam, title in (("by_size", "recall by size of the truth's 8-connected components"),
                       ("by_displacement", "recall by displacement |Z - Z_GT|")):
        if all(fam in pooled[m] for m in METHODS):
            rows = [[name, str(pooled[METHODS[0]][fam][name]["n"]),
                     *(f"{_fmt_rate(pooled[m][fam][name]['recall'])} ({pooled[m][fam][name]['found']})"
                       for m in METHODS)] for name in CLASS_FAMILIES[fam]]
            if fam == "by_size" and all("detectable" in pooled[m] for m in METHODS):
                rows.append(["detectable", str(pooled[METHODS[0]]["detectable"]["n"]),
                             *(f"{_fmt_rate(pooled[m]['detectable']['recall'])} ({pooled[m]['detectable']['found']})"
                               for m in METHODS)])
            parts.append(f"{title}, pooled: recall (found) of the n true outlier pixels of each class\n"
                         + _render(["class", "n", *METHODS], rows, left=1))
    vs = report.get("labels_vs_fits")
    if vs is not None:
        parts.append(format_labels_vs_fits(vs))
    unscored = report.get("unscored", [])
    if unscored:
        lines = [f"  frame {u['index']} (stamp_ns {u['stamp_ns']}): {u['reason']}" for u in unscored]
        parts.append(f"unscored: {len(unscored)} frame{'s' if len(unscored) != 1 else ''}\n" + "\n".join(lines))
    flagged = [f["index"] for f in report.get("frames", []) if f.get("bin_flagged")]
    if flagged:
        parts.append(f"bin check: {len(flagged)} of the {len(report['frames'])} scored frames flagged (their scores "
                     "rest on a bin removal that did not work): frames " + ", ".join(map(str, flagged)))
    return "\n\n".join(parts)


def format_labels_vs_fits(vs: Mapping[str, Any]) -> str:
    """The lines of a report's ``labels_vs_fits`` (docs/accuracy.md, "Labels against the fits")."""
    n = vs.get("frames")
    on = f" on {n} frame{'s' if n != 1 else ''}" if n is not None else ""
    return (f"labels against the fits (explained, {vs['surfaces'] or 'unknown surfaces'}){on}: over the "
            f"{vs['decided']} decided pixels, zone IoU {_fmt_rate(vs['iou'])} of the labelled outliers with the "
            f"unexplained pixels (kappa {_fmt_rate(vs['kappa'])}); {vs['both']} labelled outlier and unexplained, "
            f"{vs['labelled_outlier_explained']} labelled outlier but explained, "
            f"{vs['labelled_inlier_unexplained']} labelled inlier but unexplained")


# ------------------------------------------------------------------ agreement between annotators
@dataclass(frozen=True, slots=True)
class AgreementCounts:
    """Pixel confusion of two annotators' outlier masks over the pixels both reviewed.

    ``both`` = outlier for A and B, ``only_a``, ``only_b``, ``neither``; they add up over frames.
    """

    both: int
    only_a: int
    only_b: int
    neither: int

    def __add__(self, other: AgreementCounts) -> AgreementCounts:
        return AgreementCounts(self.both + other.both, self.only_a + other.only_a,
                               self.only_b + other.only_b, self.neither + other.neither)

    @property
    def n(self) -> int:
        return self.both + self.only_a + self.only_b + self.neither

    @property
    def iou(self) -> float:
        """|A ∩ B| / |A ∪ B| (NaN when both are empty)."""
        return ratio(self.both, self.both + self.only_a + self.only_b)

    @property
    def kappa(self) -> float:
        """Cohen's kappa, (p_o − p_e) / (1 − p_e) from integer counts (NaN when p_e = 1), as
        :func:`zcut.metrics.cohen_kappa` computes it."""
        n = self.n
        n_a, n_b = self.both + self.only_a, self.both + self.only_b
        agree = self.both + self.neither
        chance = n_a * n_b + (n - n_a) * (n - n_b)
        return ratio(n * agree - chance, n * n - chance)

    def as_dict(self) -> dict[str, int | float]:
        return {"pixels": self.n, "both": self.both, "only_a": self.only_a, "only_b": self.only_b,
                "iou": self.iou, "kappa": self.kappa}


def agreement_counts(outliers_a: Mask, reviewed_a: Mask, outliers_b: Mask, reviewed_b: Mask) -> AgreementCounts:
    """Confusion of two labels over R_A ∩ R_B.

    Parameters
    ----------
    outliers_a, reviewed_a, outliers_b, reviewed_b : (H, W) bool ndarray
        The two annotators' L and R.
    """
    la = check_mask(outliers_a, name="outliers_a", shape=None)
    shape = la.shape
    ra = check_mask(reviewed_a, name="reviewed_a", shape=shape)
    lb = check_mask(outliers_b, name="outliers_b", shape=shape)
    rb = check_mask(reviewed_b, name="reviewed_b", shape=shape)
    r = ra & rb
    a, b = la & r, lb & r
    both = int(np.count_nonzero(a & b))
    na, nb, nr = int(np.count_nonzero(a)), int(np.count_nonzero(b)), int(np.count_nonzero(r))
    return AgreementCounts(both=both, only_a=na - both, only_b=nb - both, neither=nr - na - nb + both)


@dataclass(frozen=True, slots=True)
class LabelsVsFits:
    """The labels' own agreement with the method ``explained`` (docs/accuracy.md, "Labels against the
    fits"): over the decided pixels D (reviewed, in the region), ``counts`` is the confusion of the
    labelled outliers (A) with the pixels no known surface explains (B); ``surfaces`` says what
    explained the parts (``"part fits"``, ``"local surface"``: no part model, or ``"results file"``:
    the mask a results file holds), several joined by ", " once pooled."""

    counts: AgreementCounts
    surfaces: str

    @staticmethod
    def empty() -> LabelsVsFits:
        return LabelsVsFits(AgreementCounts(0, 0, 0, 0), "")

    def __add__(self, other: LabelsVsFits) -> LabelsVsFits:
        names = [n for s in (self.surfaces, other.surfaces) for n in s.split(", ") if n]
        return LabelsVsFits(self.counts + other.counts, ", ".join(dict.fromkeys(names)))

    def as_dict(self) -> dict[str, int | float | str]:
        c = self.counts
        return {"surfaces": self.surfaces, "decided": c.n, "both": c.both,
                "labelled_outlier_explained": c.only_a, "labelled_inlier_unexplained": c.only_b,
                "neither": c.neither, "iou": c.iou, "kappa": c.kappa}


def labels_vs_fits(outliers: Mask, reviewed: Mask, unexplained: Mask, region: Mask, *, surfaces: str) -> LabelsVsFits:
    """The labels' agreement with ``explained`` on one frame: the confusion of the labelled outliers
    with the unexplained pixels over the decided pixels (``reviewed`` ∩ ``region``)."""
    reg = check_mask(region, name="region", shape=None)
    rev = check_mask(reviewed, name="reviewed", shape=reg.shape) & reg
    return LabelsVsFits(agreement_counts(outliers, rev, unexplained, rev), surfaces)


def agreement_report(annotator_a: str, annotator_b: str,
                     frames: Iterable[tuple[int, int, AgreementCounts]]) -> dict[str, Any]:
    """``{"annotators": [A, B], "pooled": {...}, "frames": [{"index", "stamp_ns", ...}]}`` (NaN kept)."""
    frames = list(frames)
    pooled = AgreementCounts(0, 0, 0, 0)
    for _, _, c in frames:
        pooled = pooled + c
    return {"annotators": [annotator_a, annotator_b], "pooled": pooled.as_dict(),
            "frames": [{"index": int(i), "stamp_ns": int(s), **c.as_dict()} for i, s, c in frames]}


def format_agreement_table(report: dict[str, Any]) -> str:
    """Plain-text table of :func:`agreement_report`."""
    a, b = report["annotators"]
    head = ["frame", "stamp_ns", "pixels", "both", f"only {a}", f"only {b}", "IoU", "kappa"]
    rows = [[str(f["index"]), str(f["stamp_ns"]), str(f["pixels"]), str(f["both"]), str(f["only_a"]),
             str(f["only_b"]), _fmt_rate(f["iou"]), _fmt_rate(f["kappa"])] for f in report["frames"]]
    p = report["pooled"]
    rows.append(["pooled", "", str(p["pixels"]), str(p["both"]), str(p["only_a"]), str(p["only_b"]),
                 _fmt_rate(p["iou"]), _fmt_rate(p["kappa"])])
    return f"agreement of {a} and {b} over the pixels both reviewed\n" + _render(head, rows, left=2)


# ------------------------------------------------------------------ true accuracy as a library call


@dataclass(frozen=True, slots=True, kw_only=True)
class AccuracyOptions:
    """What :func:`run` scores (docs/accuracy.md); the defaults are ``zcut accuracy``'s.

    Attributes
    ----------
    log : Path
        A log (predictions computed by the pipeline, resolved as ``zcut replay`` resolves them) or a
        results file of ``zcut replay --out`` (its masks are the predictions).
    labels, annotator :
        Score against this annotator's labels in this label store (default: the log's synthetic truth).
    agreement : (str, str) or None
        Instead: the agreement of two annotators of ``labels``.
    region : {"zone", "valid"}
        The scored region.
    learned : Path or None
        Also score the labelling assistant's newest model in this store (default: the ``labels`` store's, if any).
    by_displacement : bool
        Also give recall by displacement |Z - Z_GT| (a log with ``/ground_truth/depth``).
    truth : {"paper", "sensor"} or None
        Which recorded truth scores the log (docs/accuracy.md, "Two truths"): None (the default) the
        paper's ``/ground_truth/off_surface`` where the log has it, else the sensor's
        ``/ground_truth/outliers`` (the report says so); a truth asked for that the log lacks is an
        error. Not with ``labels``.
    pipeline : PipelineOptions
        The config, its overrides, the topic and the bin model.
    """

    log: Path
    labels: Path | None = None
    annotator: str | None = None
    agreement: tuple[str, str] | None = None
    region: str = "zone"
    learned: Path | None = None
    by_displacement: bool = False
    truth: str | None = None
    pipeline: PipelineOptions = PipelineOptions()


@dataclass(frozen=True, slots=True)
class AccuracyResult:
    """What :func:`run` found.

    Attributes
    ----------
    report : dict
        The docs/accuracy.md report (:func:`accuracy_report`; :func:`format_accuracy_table` prints it).
    truth : str
        What the frames were scored against (the truth source's name).
    predictions : str
        Where the predictions came from ("computed by the pipeline", or the results file's topics).
    from_results : bool
        The predictions were read from a results file (which does not carry the bin check).
    notes : tuple of str
        The resolved config's notes (predictions computed by the pipeline).
    learned : str or None
        The assistant's model scored as ``learned`` (its summary), None when none was.
    learned_left_out : int
        Frames the model was trained on (not scored for it).
    damage : tuple of Damage
        What the pass over the log lost.
    """

    report: dict[str, Any]
    truth: str
    predictions: str
    from_results: bool
    notes: tuple[str, ...] = ()
    learned: str | None = None
    learned_left_out: int = 0
    damage: tuple[Damage, ...] = ()

    @property
    def data_loss(self) -> bool:
        """Frames were lost (``zcut accuracy`` exits 3)."""
        return bool(self.damage)


@dataclass(frozen=True, slots=True)
class AgreementResult:
    """The agreement of two annotators (:func:`agreement_report`; :func:`format_agreement_table` prints it)."""

    report: dict[str, Any]
    damage: tuple[Damage, ...] = ()

    @property
    def data_loss(self) -> bool:
        return bool(self.damage)


def run(options: AccuracyOptions) -> AccuracyResult | AgreementResult:
    """The true accuracy of the methods on ``options.log`` (or, with ``agreement``, two annotators'
    agreement). A frame whose bin check failed is named in a warning on stderr, as is a session
    without a bin model. Raises :class:`~zcut.errors.ZcutError` when nothing can be scored."""
    from annotate.truth import check_region, check_truth

    if not options.log.is_file():
        raise FileNotFoundError(2, "no such file", str(options.log))
    check_region(options.region)
    check_truth(options.truth)
    if options.truth is not None and (options.labels is not None or options.agreement):
        raise ParameterError(f"--truth {options.truth} scores against the log's recorded truth, --labels against "
                             "an annotator's: give one")
    if options.agreement and options.labels is None:
        raise ParameterError("--agreement needs --labels DB")
    if options.labels is not None and not options.labels.is_file():
        raise FileNotFoundError(2, "no such file", str(options.labels))
    overrides = options.pipeline.overrides()  # bad values fail before the log is read
    if options.agreement:
        return _agreement(options)
    return _accuracy(options, overrides)


def _accuracy(options: AccuracyOptions, overrides: dict[str, Any]) -> AccuracyResult:
    from annotate.truth import LabelTruth, SyntheticTruth, synthetic_truth
    from replay.logs import layout
    from replay.logs.reader import LogReader
    from replay.pipeline.methods import base_methods
    from zcut.errors import ZcutError

    log = options.log
    reader = LogReader(log, cloud_topic=options.pipeline.topic, cloudless=True)
    truth_src: LabelTruth | SyntheticTruth
    if options.labels:
        truth_src = LabelTruth(options.labels, log, annotator=options.annotator)
    else:
        found = synthetic_truth(options.truth, reader.mask_topics, log)
        if found is None:
            raise ZcutError(f"{log} has no {layout.TRUTH_OUTLIERS}: give human labels with --labels DB")
        truth_src = found
    try:
        is_results = layout.ZCUT_OUTLIERS in reader.mask_topics
        methods = _results_methods(reader, options) if is_results else None
        session = None
        stream: Any  # the pass over the log (its damage)
        frames: Iterable[tuple[Any, Any]]
        if is_results:
            stream = reader.frames()
            frames = ((f, None) for f in stream)
        else:  # predictions computed as `zcut replay` computes them (the same resolved config)
            session = options.pipeline.open_session(log, overrides=overrides)
            # with labels, explained runs too: the labels' agreement with the fits (not a reported method)
            frames = stream = session.results(config=_with_explained(session) if options.labels else None)
        learned = _learned_model(options, session)
        # |Z - Z_GT| of every pixel where the log has the true depth (recall by displacement)
        # (asked for: a results file cannot give it, and its report otherwise equals the log's)
        if options.by_displacement and (session is None or layout.TRUTH_DEPTH not in reader.topics):
            raise ZcutError(f"--by-displacement needs a log with {layout.TRUTH_DEPTH}"
                            + (" (a results file has lost the z-cut's outliers' depths: give the log)"
                               if session is None else f": {log} has none"))
        results, unscored, learned_seen = _score_frames(options, frames, truth_src, methods, session, learned)
        if not results:
            what = (f"no frame of {log} is labelled by {truth_src.annotator!r} in {options.labels}"
                    if isinstance(truth_src, LabelTruth) else f"no frame of {log} has {truth_src.topic}")
            raise ZcutError(what)
        left_out = ({"learned": (learned_seen, "the assistant's model was trained on these frames")}
                    if learned is not None else None)
        report = accuracy_report(results, region=options.region, unscored=unscored, left_out=left_out,
                                 truth=truth_src.name)
        if session is not None:
            pred = "computed by the pipeline"
        else:
            assert methods is not None  # a results file's
            pred = f"from {', '.join(layout.method_topic(b) for b in base_methods(methods))}"
        return AccuracyResult(report, truth_src.name, pred, from_results=session is None,
                              notes=tuple(session.notes) if session is not None else (),
                              learned=learned.summary() if learned is not None else None,
                              learned_left_out=len(learned_seen), damage=tuple(stream.damage))
    finally:
        if hasattr(truth_src, "close"):
            truth_src.close()


def _score_frames(options: AccuracyOptions, frames: Iterable[tuple[Any, Any]], truth_src: Any, methods: list[str] | None,
                  session: Any, learned: Any) -> tuple[list[FrameAccuracy], list[UnscoredFrame], set[int]]:
    """Each frame's counts (and the learned model's, on the frames it was not trained on)."""
    import dataclasses
    import sys

    from annotate.truth import method_predictions, region_of_results_frame, scored_region
    from replay.logs import layout
    from replay.pipeline.methods import base_methods

    learned_seen: set[int] = set()
    said: set[str] = set()
    results, unscored = [], []
    page_fit = None  # whether the page fits a part model to this log's frames (annotate.assistant.page_fits)
    if learned is not None:
        from annotate.assistant import learned_mask, page_fits

        page_fit = page_fits(session)
    for frame, r in frames:
        if r is None:
            assert methods is not None  # a results file's
            preds = method_masks_of({b: frame.masks[layout.method_topic(b)] for b in base_methods(methods)
                                     if layout.method_topic(b) in frame.masks}, methods)
            # a results file's /zcut/filtered has the outliers set to NaN: its valid pixels plus the
            # predictions are the source's valid pixels
            region = region_of_results_frame(frame, options.region)
            valid = region_of_results_frame(frame, "valid")
        else:
            preds = method_predictions(r, session.config.methods)
            region, valid = scored_region(r, options.region), r.valid
        t = truth_src.truth(frame, valid)
        if isinstance(t, str):
            unscored.append(UnscoredFrame(frame.index, frame.stamp_ns, t))
            continue
        shift = displacement_mm(options.log, frame) if options.by_displacement else None
        open_ = options.labels is not None  # how much of each verdict the labels left undecided
        fa = frame_accuracy(frame.index, frame.stamp_ns, preds, t.outliers, reviewed=t.reviewed,
                            valid=valid, region=region, kinds=t.kind, detectable=t.detectable,
                            displacement_mm=shift, undecided=open_)
        fits = _unexplained(frame, r) if open_ else None
        if fits is not None:
            fa = dataclasses.replace(fa, labels_vs_fits=labels_vs_fits(t.outliers, t.reviewed, fits[0], region,
                                                                       surfaces=fits[1]))
        if r is not None:  # the bin check of the frame (a results file does not carry it)
            check = r.bin_check
            fa = dataclasses.replace(fa, bin_check=None if check is None else float(check.value),
                                     bin_flagged=r.bin_flagged)
            if r.bin_flagged:
                print(f"warning: frame {frame.index}: bin check: {check.reason}", file=sys.stderr)
            # a method that could not judge the frame (a stereo post-filter's mask not in the log): each text once
            for w in r.warnings:
                if w.startswith(tuple(f"{b}: " for b in session.config.base_methods)) and w not in said:
                    said.add(w)
                    print(f"warning: frame {frame.index}: {w}", file=sys.stderr)
        if learned is not None:
            assert page_fit is not None
            seen = (frame.topic, frame.stamp_ns) in learned.frames  # trained on it: not scored
            if seen:
                learned_seen.add(frame.index)
            fb = frame_accuracy(frame.index, frame.stamp_ns, {"learned": learned_mask(learned, frame, r,
                                config=session.config, fits=page_fit)}, t.outliers,
                                reviewed=t.reviewed, valid=valid,
                                region=region & (not seen), kinds=t.kind, detectable=t.detectable,
                                displacement_mm=shift, undecided=open_)
            fa.counts.update(fb.counts)
            fa.classes.update(fb.classes)
            fa.undecided.update(fb.undecided)
        results.append(fa)
    return results, unscored, learned_seen


def _with_explained(session: Any) -> Any:
    """The session's config running ``explained`` too (its part model: the one given, else the log's
    ``part_model.ply``, else none: the local surface), for the labels' agreement with the fits; the
    report still lists only the config's own methods."""
    import dataclasses

    from replay.pipeline.explained import NAME, with_log_part_model

    config = session.config
    if NAME in config.base_methods:
        return config
    more = dataclasses.replace(session.resolved, config=dataclasses.replace(config, methods=(*config.methods, NAME)))
    return with_log_part_model(more, session.path, session.reader).config


def _unexplained(frame: Any, r: Any) -> tuple[Mask, str] | None:
    """``explained``'s outliers on a frame and what explained the parts (:class:`LabelsVsFits`): from
    the pipeline's result, or the mask a results file holds; None when there are none (a results file
    without it, a frame ``explained`` could not judge)."""
    from replay.logs import layout
    from replay.pipeline.explained import NAME, ExplainedDetail

    if r is None:
        mask = frame.masks.get(layout.method_topic(NAME))
        return None if mask is None else (mask, "results file")
    detail = r.details.get(NAME)
    if NAME not in r.outliers or not isinstance(detail, ExplainedDetail):
        return None
    return r.outliers[NAME], detail.surface_model


@dataclass(frozen=True, slots=True, eq=False)
class Displacement:
    """|Z − Z_GT| (mm) of a frame's pixels (:func:`displacement_mm`'s image), computed only where it is
    read (:func:`frame_accuracies` reads it at the scored true outliers): ``xyz`` the frame's points
    (H, W, 3), ``depth`` its true depth (H, W) in metres."""

    xyz: np.ndarray
    depth: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.xyz.shape[0]), int(self.xyz.shape[1]))

    def at(self, index: np.ndarray) -> np.ndarray:
        """The displacement at the flat (row-major) pixels ``index``: the same operations on the same
        values as :func:`displacement_mm` (the same float64 bits)."""
        v: np.ndarray = self.xyz.reshape(-1, 3)[index, 2].astype(np.float64)
        v -= self.depth.reshape(-1)[index]
        np.abs(v, out=v)
        v *= 1000.0
        return v

    def image(self) -> np.ndarray:
        """The whole (H, W) image, as :func:`displacement_mm` gives it."""
        shift: np.ndarray = self.xyz[..., 2].astype(np.float64)
        shift -= self.depth
        np.abs(shift, out=shift)
        shift *= 1000.0
        return shift


def frame_displacement(log: Path, frame: Any) -> Displacement | None:
    """:func:`displacement_mm` of a frame as a :class:`Displacement` (nothing computed yet); None when it
    gives None."""
    depth = getattr(frame, "truth_depth_m", None)
    if depth is None:
        depth = _read_truth_depth(log, frame)
        if depth is None:
            return None
    return Displacement(frame.xyz, depth)


def displacement_mm(log: Path, frame: Any) -> np.ndarray | None:
    """|Z − Z_GT| (mm) of every pixel of a frame from the log's ``/ground_truth/depth`` message of its
    stamp (NaN where either is unknown); None when that message cannot be read (the frame then has no
    displacement classes, and the pooled report none). A frame read with ``LogReader(truth_depth=True)``
    carries that message already decoded (:attr:`~replay.logs.frame.Frame.truth_depth_m`): it is used,
    the log is not read again; else the message is read from ``log``."""
    depth = getattr(frame, "truth_depth_m", None)
    if depth is None:
        depth = _read_truth_depth(log, frame)
        if depth is None:
            return None
    # |Z − Z_GT| · 1000 in float64, in place: the same operations in the same order (the same bits)
    shift: np.ndarray = frame.xyz[..., 2].astype(np.float64)
    shift -= depth
    np.abs(shift, out=shift)
    shift *= 1000.0
    return shift


def _read_truth_depth(log: Path, frame: Any) -> np.ndarray | None:
    """The (H, W) float32 ``/ground_truth/depth`` of the frame's stamp read from the log (a view of the
    message's bytes), None when there is no usable one."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    from replay.errors import LogFormatError
    from replay.logs import layout
    from replay.logs import ros2_msgs as rm

    try:
        with open(log, "rb") as f:
            for _s, _c, message in make_reader(f).iter_messages(topics=[layout.TRUTH_DEPTH], starting_at=frame.stamp_ns,
                                                                 ending_at=frame.stamp_ns):
                msg = rm.decode_image(message.data, where=f"{layout.TRUTH_DEPTH} message")
                if (msg.stamp_ns != frame.stamp_ns or msg.encoding != layout.TRUTH_DEPTH_ENCODING or msg.is_bigendian
                        or (msg.height, msg.width) != frame.shape or len(msg.data) != 4 * msg.width * msg.height):
                    continue
                return np.frombuffer(msg.data, dtype="<f4").reshape(msg.height, msg.width)  # read, not copied
    except (McapError, LogFormatError, ValueError, OSError, EOFError):
        return None
    return None


def _learned_model(options: AccuracyOptions, session: Any) -> Any:
    """The assistant's model to score as ``learned`` (None when there is none to score)."""
    import sys

    from annotate.assistant import load_model
    from annotate.store import LabelStore
    from zcut.errors import ZcutError

    db = options.learned or options.labels
    if db is None:
        return None
    if session is None:
        if options.learned is not None:
            raise ZcutError("--learned scores the assistant on a log, not on a results file: give the log")
        return None
    if not Path(db).is_file():
        raise FileNotFoundError(2, "no such file", str(db))
    with LabelStore(db, read_only=True) as store:
        rec = store.latest_model()
    if rec is None:
        if options.learned is not None:
            raise ZcutError(f"{db} holds no assistant model: train one with zcut labels train")
        return None
    model = load_model(rec)
    if model.part is not None and session.config.part is not None and model.part != session.config.part:
        print(f"warning: learned: the model was trained on {model.part}, this log is {session.config.part}",
              file=sys.stderr)
    return model


def _results_methods(reader: Any, options: AccuracyOptions) -> list[str]:
    """The base methods a results file holds masks of (``/zcut/outliers``, ``/zcut/sor_outliers``,
    ``/zcut/methods/NAME``), restricted to ``--methods`` when given (each must be there)."""
    from replay.logs import layout
    from replay.pipeline.methods import members, parse_methods, registry
    from zcut.errors import ZcutError

    held = [m for m in registry() if layout.method_topic(m) in reader.mask_topics]
    if options.pipeline.methods is None:
        return held
    want = parse_methods(options.pipeline.methods, source="--methods")
    missing = sorted({b for m in want for b in members(m)} - set(held))
    if missing:
        raise ZcutError(f"{options.log} is a results file without the masks of {', '.join(missing)} "
                        f"(it holds {', '.join(held)}): replay the log with --methods, or score the log itself")
    return list(want)


def _agreement(options: AccuracyOptions) -> AgreementResult:
    from annotate.truth import LabelTruth
    from replay.logs.reader import LogReader
    from zcut.errors import ZcutError

    assert options.agreement is not None and options.labels is not None
    a, b = options.agreement
    ta = LabelTruth(options.labels, options.log, annotator=a)
    tb = LabelTruth(options.labels, options.log, annotator=b)
    reader = LogReader(options.log, cloud_topic=options.pipeline.topic, cloudless=True)
    try:
        rows = []
        stream = reader.frames()
        for frame in stream:
            la = ta.store.label(r, annotator=a) if (r := ta.record(frame)) is not None else None
            lb = tb.store.label(r, annotator=b) if (r := tb.record(frame)) is not None else None
            if la is not None and lb is not None:
                rows.append((frame.index, frame.stamp_ns,
                             agreement_counts(la.outliers, la.reviewed, lb.outliers, lb.reviewed)))
        if not rows:
            raise ZcutError(f"no frame of {options.log} is labelled by both {a!r} and {b!r} in {options.labels}")
        return AgreementResult(agreement_report(a, b, rows), tuple(stream.damage))
    finally:
        ta.close()
        tb.close()
