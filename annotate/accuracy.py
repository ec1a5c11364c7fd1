"""True accuracy of the outlier filters against labels (SPEC §4): the report and its table.

Pure functions on arrays: no file I/O, no printing. The callers (``zcut accuracy``, ``zcut demo``)
gather per-frame predictions and truth, then::

    frames = [frame_accuracy(i, stamp_ns, {"zcut": z, "sor": s}, truth, reviewed=r) for ...]
    report = accuracy_report(frames)          # the SPEC §4 dict (floats may be NaN / inf)
    print(report_json(report))                # NaN / inf -> null, every count an int
    print(format_accuracy_table(report))

A method's prediction is an (H, W) bool mask; ``union`` and ``intersection`` are derived from
``zcut`` and ``sor``. Counts are taken over the reviewed pixels (default: every pixel, or the valid
ones when the caller passes them as ``reviewed``); pooled figures sum the counts (micro average).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from zcut.cloud import check_mask
from zcut.errors import ParameterError
from zcut.metrics import AccuracyCounts, accuracy_counts, ratio
from zcut.types import Mask

#: Methods of the report, in the order shown.
METHODS: tuple[str, ...] = ("zcut", "sor", "union", "intersection")
#: Methods a caller predicts; the other two are derived from them.
BASE_METHODS: tuple[str, ...] = ("zcut", "sor")
#: Keys of one method's entry (SPEC §4), in the order shown.
COUNT_KEYS: tuple[str, ...] = ("tp", "fp", "fn")
RATE_KEYS: tuple[str, ...] = ("precision", "recall", "f1", "iou", "cluster_precision", "cluster_recall")
METRIC_KEYS: tuple[str, ...] = COUNT_KEYS + RATE_KEYS


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
        One entry per name in :data:`METHODS`.
    """

    index: int
    stamp_ns: int
    counts: dict[str, AccuracyCounts]


def method_masks(zcut: Mask, sor: Mask) -> dict[str, Mask]:
    """The four predictions of the report from the two filters' masks.

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


def frame_accuracy(
    index: int,
    stamp_ns: int,
    predictions: Mapping[str, Mask],
    outliers: Mask,
    *,
    reviewed: Mask | None = None,
) -> FrameAccuracy:
    """Count TP / FP / FN and clusters of every method on one frame (SPEC §4).

    Parameters
    ----------
    index : int
        0-based frame index.
    stamp_ns : int
        Header stamp of the frame.
    predictions : mapping str -> (H, W) bool ndarray
        At least ``"zcut"`` and ``"sor"``; ``union`` and ``intersection`` are derived.
    outliers : (H, W) bool ndarray
        True outliers L (labels or synthetic ground truth); L must lie inside ``reviewed``.
    reviewed : (H, W) bool ndarray, optional
        Reviewed pixels R; counts are taken over R. Default: every pixel.

    Returns
    -------
    FrameAccuracy
    """
    missing = [m for m in BASE_METHODS if m not in predictions]
    if missing:
        raise ParameterError(f"predictions must hold {list(BASE_METHODS)}, missing {missing}")
    truth = check_mask(outliers, name="outliers", shape=None)
    if reviewed is not None:
        reviewed = check_mask(reviewed, name="reviewed", shape=truth.shape)
    preds = method_masks(
        check_mask(predictions["zcut"], name="predictions['zcut']", shape=truth.shape),
        check_mask(predictions["sor"], name="predictions['sor']", shape=truth.shape),
    )
    counts = {m: accuracy_counts(preds[m], truth, reviewed=reviewed) for m in METHODS}
    return FrameAccuracy(index=int(index), stamp_ns=int(stamp_ns), counts=counts)


def pooled_counts(frames: Iterable[FrameAccuracy]) -> dict[str, AccuracyCounts]:
    """Sum the counts of every method over the frames (micro average); zero counts if none."""
    total = {m: _zero_counts() for m in METHODS}
    for f in frames:
        for m in METHODS:
            total[m] = total[m] + f.counts[m]
    return total


def _zero_counts() -> AccuracyCounts:
    return AccuracyCounts(
        tp=0, fp=0, fn=0, true_clusters=0, true_clusters_found=0, pred_clusters=0, pred_clusters_correct=0
    )


def _entry(c: AccuracyCounts) -> dict[str, int | float]:
    d = c.as_dict()
    out: dict[str, int | float] = {}
    for k in METRIC_KEYS:
        v = d[k]
        out[k] = int(v) if k in COUNT_KEYS else float(v)
    return out


def accuracy_report(frames: Iterable[FrameAccuracy]) -> dict:
    """The SPEC §4 report object.

    Returns
    -------
    dict
        ``{"pooled": {METHOD: {tp, fp, fn, precision, recall, f1, iou, cluster_precision,
        cluster_recall}}, "frames": [{"index", "stamp_ns", METHOD: {...}}]}`` with METHOD in
        :data:`METHODS`. Counts are ``int``; rates are ``float`` and may be NaN (0/0) — use
        :func:`report_json` or :func:`jsonable` to serialise them as ``null``.
    """
    frames = list(frames)
    pooled = pooled_counts(frames)
    return {
        "pooled": {m: _entry(pooled[m]) for m in METHODS},
        "frames": [
            {"index": f.index, "stamp_ns": f.stamp_ns, **{m: _entry(f.counts[m]) for m in METHODS}}
            for f in frames
        ],
    }


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


def report_json(report: dict, *, indent: int | None = None) -> str:
    """Strict JSON text of a report (NaN / inf -> ``null``; never emits ``NaN``)."""
    return json.dumps(jsonable(report), indent=indent, allow_nan=False)


def _fmt_rate(v: float | None) -> str:
    if v is None or not math.isfinite(v):
        return "-"
    return f"{v:.3f}"


_HEADER = ("tp", "fp", "fn", "prec", "recall", "F1", "IoU", "cl.prec", "cl.recall")


def _row(prefix: list[str], e: Mapping[str, float | int | None]) -> list[str]:
    return prefix + [str(e["tp"]), str(e["fp"]), str(e["fn"])] + [_fmt_rate(e[k]) for k in RATE_KEYS]


def _render(header: list[str], rows: list[list[str]], left: int) -> str:
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    lines = []
    for r in [header, *rows]:
        cells = [c.ljust(w) if i < left else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths))]
        lines.append("  ".join(cells).rstrip())
    return "\n".join(lines)


def format_accuracy_table(report: dict, *, per_frame: bool = True) -> str:
    """Plain-text tables of a report: per frame (optional) and pooled, ``-`` for undefined rates.

    Parameters
    ----------
    report : dict
        As returned by :func:`accuracy_report` (or parsed back from :func:`report_json`).
    per_frame : bool
        Include one row per frame and method before the pooled table.
    """
    parts = []
    if per_frame and report["frames"]:
        rows = [
            _row([str(f["index"]), str(f["stamp_ns"]), m], f[m]) for f in report["frames"] for m in METHODS
        ]
        parts.append("per frame\n" + _render(["frame", "stamp_ns", "method", *_HEADER], rows, left=3))
    n = len(report["frames"])
    rows = [_row([m], report["pooled"][m]) for m in METHODS]
    parts.append(f"pooled over {n} frame{'s' if n != 1 else ''}\n" + _render(["method", *_HEADER], rows, left=1))
    return "\n\n".join(parts)


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


def agreement_report(annotator_a: str, annotator_b: str,
                     frames: Iterable[tuple[int, int, AgreementCounts]]) -> dict:
    """``{"annotators": [A, B], "pooled": {...}, "frames": [{"index", "stamp_ns", ...}]}`` (NaN kept)."""
    frames = list(frames)
    pooled = AgreementCounts(0, 0, 0, 0)
    for _, _, c in frames:
        pooled = pooled + c
    return {"annotators": [annotator_a, annotator_b], "pooled": pooled.as_dict(),
            "frames": [{"index": int(i), "stamp_ns": int(s), **c.as_dict()} for i, s, c in frames]}


def format_agreement_table(report: dict) -> str:
    """Plain-text table of :func:`agreement_report`."""
    a, b = report["annotators"]
    head = ["frame", "stamp_ns", "pixels", "both", f"only {a}", f"only {b}", "IoU", "kappa"]
    rows = [[str(f["index"]), str(f["stamp_ns"]), str(f["pixels"]), str(f["both"]), str(f["only_a"]),
             str(f["only_b"]), _fmt_rate(f["iou"]), _fmt_rate(f["kappa"])] for f in report["frames"]]
    p = report["pooled"]
    rows.append(["pooled", "", str(p["pixels"]), str(p["both"]), str(p["only_a"]), str(p["only_b"]),
                 _fmt_rate(p["iou"]), _fmt_rate(p["kappa"])])
    return f"agreement of {a} and {b} over the pixels both reviewed\n" + _render(head, rows, left=2)
