"""What a frame is scored against (docs/accuracy.md): the true outliers L, the reviewed pixels R, the scored
region, and the kind of every true outlier where the truth says it.

Two sources of truth, one interface (:meth:`TruthSource.truth` -> :class:`FrameTruth`, or a string
saying why the frame is unscored):

- :class:`SyntheticTruth`: a log's recorded truth, one of :data:`TRUTHS` (docs/accuracy.md, "Two
  truths"): the paper's ``/ground_truth/off_surface`` (the points farther than 3 × Err from every true
  surface) or the sensor's ``/ground_truth/outliers`` with its ``/ground_truth/outlier_kind`` and
  ``/ground_truth/detectable``; R = the valid pixels minus ``/ground_truth/unknown`` (the pixels whose
  truth cannot be judged). :func:`truth_of_log` chooses between them: the paper's where the log has
  it, else the sensor's (stereo logs, older synthetic logs), unless the caller asks for one;
- :class:`LabelTruth`: an annotator's labels in a label store (``--labels DB``), matched to the frame
  by the log's content hash, the cloud topic and the stamp.

:func:`scored_region` gives the region S is taken in (``zone``: the pixels the filters judge, the
default; ``valid``: every valid pixel). ``zcut accuracy``, ``zcut batch`` and ``zcut sweep`` all score
through this module, so they score alike.
"""

from __future__ import annotations

import os
from collections.abc import Collection, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from replay.logs import layout
from zcut.errors import ParameterError

if TYPE_CHECKING:
    from annotate.store import FrameRecord
    from replay.logs.frame import Frame
    from replay.pipeline.stages import FrameResult

REGIONS = ("zone", "valid")
#: The recorded truths a log may be scored against (docs/accuracy.md, "Two truths"): name -> its topic.
TRUTHS: dict[str, str] = {"paper": layout.TRUTH_OFF_SURFACE, "sensor": layout.TRUTH_OUTLIERS}
#: What each truth is, for the reports.
TRUTH_NAMES: dict[str, str] = {
    "paper": f"the paper's truth {layout.TRUTH_OFF_SURFACE} (farther than 3 Err from every true surface)",
    "sensor": f"the sensor's truth {layout.TRUTH_OUTLIERS}",
}


@dataclass(frozen=True, slots=True)
class FrameTruth:
    """The truth of one frame.

    Attributes
    ----------
    outliers : (H, W) bool ndarray
        L, inside ``reviewed``.
    reviewed : (H, W) bool ndarray
        R, inside the valid pixels.
    kind : (H, W) uint8 ndarray or None
        ``/ground_truth/outlier_kind`` codes where the truth has them.
    source : str
        What the truth is, for the tables ("the paper's truth /ground_truth/off_surface (...)", "labels by alice").
    detectable : (H, W) bool ndarray or None
        ``/ground_truth/detectable`` (inside ``outliers``) where the truth has it.
    """

    outliers: np.ndarray
    reviewed: np.ndarray
    kind: np.ndarray | None
    source: str
    detectable: np.ndarray | None = None


def check_region(name: str) -> str:
    if name not in REGIONS:
        raise ParameterError(f"--region must be one of {', '.join(REGIONS)}, got {name!r}")
    return name


def check_truth(name: str | None) -> str | None:
    """``name`` when it is one of :data:`TRUTHS` or None (the default: the paper's where the log has it)."""
    if name is not None and name not in TRUTHS:
        raise ParameterError(f"--truth must be one of {', '.join(TRUTHS)}, got {name!r}")
    return name


def truth_of_log(requested: str | None, mask_topics: Collection[str], log: str | os.PathLike[str]) -> str | None:
    """Which recorded truth scores ``log`` (docs/accuracy.md, "Two truths"): ``"paper"`` or ``"sensor"``,
    None when the log has neither topic (the caller says what to do then).

    Parameters
    ----------
    requested : {"paper", "sensor"} or None
        What was asked for; None: the paper's truth where the log has ``/ground_truth/off_surface``,
        else the sensor's ``/ground_truth/outliers`` (stereo logs, older synthetic logs).
    mask_topics : collection of str
        The log's mask topics (``LogReader.mask_topics``).
    log : path
        The log, named in the error.

    Raises
    ------
    ParameterError
        A truth asked for that the log does not have (one line naming the log and the topic).
    """
    check_truth(requested)
    if requested is None:
        held = [name for name, topic in TRUTHS.items() if topic in mask_topics]
        return held[0] if held else None
    if TRUTHS[requested] not in mask_topics:
        other = next(n for n in TRUTHS if n != requested)
        hint = (f": score it with --truth {other}" if TRUTHS[other] in mask_topics
                else ": give human labels with --labels DB")
        raise ParameterError(f"{log} has no {TRUTHS[requested]} (--truth {requested}){hint}")
    return requested


def synthetic_truth(requested: str | None, mask_topics: Collection[str], log: str | os.PathLike[str], *,
                    with_kinds: bool = True) -> SyntheticTruth | None:
    """The :class:`SyntheticTruth` of a log (:func:`truth_of_log` chooses which), None when the log has
    no recorded truth. ``with_kinds``: a frame without its kind image is unscored where the log has
    kinds (the sensor's truth only; the paper's has no kinds)."""
    chosen = truth_of_log(requested, mask_topics, log)
    if chosen is None:
        return None
    return SyntheticTruth(chosen, with_kinds=with_kinds and layout.TRUTH_OUTLIER_KIND in mask_topics,
                          with_unknown=layout.TRUTH_UNKNOWN in mask_topics,
                          fallback=requested is None and chosen != "paper")


def scored_region(result: FrameResult, name: str) -> np.ndarray:
    """(H, W) bool: the region of a :class:`~replay.pipeline.stages.FrameResult` that is scored.

    ``zone``: the zone the z-cut and SOR judged plus the above-the-rim points (which the pipeline
    flags itself); when the bin stages were skipped that is every valid pixel. ``valid``: every
    valid pixel.
    """
    check_region(name)
    if name == "valid":
        return result.valid
    region: np.ndarray = result.zone | result.easy_outliers
    return region


def region_of_results_frame(frame: Frame, name: str) -> np.ndarray:
    """The scored region of a frame of a results file: ``/zcut/zone`` when the replay wrote one (the
    bin stages ran), else every valid pixel of the source: ``/zcut/valid`` (every results file has it;
    one written without its cloud has only it), else, in a file written before it, the filtered cloud's
    valid pixels plus the z-cut's outliers."""
    check_region(name)
    valid = frame.masks.get(layout.VALID)
    if valid is None:
        # /zcut/filtered has the z-cut's outliers set to NaN: they were valid in the source
        valid = np.isfinite(frame.xyz).all(axis=2) | frame.masks[layout.ZCUT_OUTLIERS]
    if name == "zone" and layout.ZONE in frame.masks:
        zone: np.ndarray = frame.masks[layout.ZONE] & valid
        return zone
    return valid


class SyntheticTruth:
    """A log's recorded truth (synthetic, or ``zcut record-stereo``'s): R = valid minus
    ``/ground_truth/unknown`` (when the log has it: pixels whose truth cannot be judged, docs/accuracy.md),
    L = the truth's topic ∩ R.

    Parameters
    ----------
    truth : {"sensor", "paper"}
        Which of :data:`TRUTHS`: the sensor's ``/ground_truth/outliers`` (with its kinds and
        ``/ground_truth/detectable``) or the paper's ``/ground_truth/off_surface`` (no kinds: those
        say what made a sensor's outlier).
    with_kinds : bool
        The log has ``/ground_truth/outlier_kind``: a frame without its kind image is unscored (the
        report's per-kind recall needs every frame's kinds). The sensor's truth only.
    with_unknown : bool
        The log has ``/ground_truth/unknown``: a frame without its unknown mask is unscored (its
        unjudgeable pixels would be scored).
    fallback : bool
        The sensor's truth stands in for the paper's, which the log lacks (its name says so).
    """

    def __init__(self, truth: str = "sensor", *, with_kinds: bool = False, with_unknown: bool = False,
                 fallback: bool = False) -> None:
        if truth not in TRUTHS:
            raise ParameterError(f"truth must be one of {', '.join(TRUTHS)}, got {truth!r}")
        self.choice = truth
        self.topic = TRUTHS[truth]
        self.with_kinds = with_kinds and truth == "sensor"
        self.with_unknown = with_unknown
        self.fallback = fallback
        self.name = TRUTH_NAMES[truth] + (f" (the log has no {layout.TRUTH_OFF_SURFACE})" if fallback else "")

    def truth(self, frame: Frame, valid: np.ndarray) -> FrameTruth | str:
        gt = frame.masks.get(self.topic)
        if gt is None:
            return f"no {self.topic} message with this frame"
        if self.choice == "paper":  # no kinds, no detectable: they describe the sensor's truth
            unknown = frame.masks.get(layout.TRUTH_UNKNOWN)
            if unknown is None and self.with_unknown:
                return f"no {layout.TRUTH_UNKNOWN} message with this frame"
            reviewed = valid if unknown is None else valid & ~unknown
            return FrameTruth(gt & reviewed, reviewed, None, self.name)
        kind = frame.codes.get(layout.TRUTH_OUTLIER_KIND)
        if kind is None and self.with_kinds:
            return f"no {layout.TRUTH_OUTLIER_KIND} message with this frame"
        if kind is not None and kind.shape != gt.shape:
            return f"{layout.TRUTH_OUTLIER_KIND} is {kind.shape}, the truth {gt.shape}"
        unknown = frame.masks.get(layout.TRUTH_UNKNOWN)
        if unknown is None and self.with_unknown:
            return f"no {layout.TRUTH_UNKNOWN} message with this frame"
        reviewed = valid if unknown is None else valid & ~unknown
        lab = gt & reviewed
        det = frame.masks.get(layout.TRUTH_DETECTABLE)
        return FrameTruth(lab, reviewed, None if kind is None else np.where(reviewed, kind, 0).astype(np.uint8),
                          self.name, detectable=None if det is None else det & lab)


class LabelTruth:
    """An annotator's labels of a log in a label store.

    Parameters
    ----------
    db : path
        The label store (``zcut annotate``'s SQLite file).
    log : path
        The log (found in the store by its content hash; a results file is matched by stamp, a log the
        store does not hold is a :class:`ParameterError`).
    annotator : str, optional
        Whose labels; needed when the log has several annotators.
    """

    def __init__(self, db: str | os.PathLike[str], log: str | os.PathLike[str], *, annotator: str | None = None) -> None:
        from annotate.store import LabelStore, file_sha256

        self.db = Path(db)
        if not self.db.is_file():
            raise FileNotFoundError(2, "no such file", str(db))
        self.store = LabelStore(self.db, read_only=True)
        self.log = self.store.log_by_sha(file_sha256(log))
        if self.log is None and not is_results_file(log):
            # only a results file (whose bytes are not the labelled log's) is matched by stamp: a log the store
            # does not hold would be scored against another log's labels of the same stamps
            held = ", ".join(r.name for r in self.store.logs()) or "none"
            self.close()
            raise ParameterError(f"--labels {db}: no labels of {Path(log).name} (its content is not in the store; "
                                 f"labelled logs: {held})")
        known = self.store.annotators(self.log) if self.log is not None else self.store.annotators()
        if annotator is not None:
            if annotator not in known:
                self.close()
                raise ParameterError(f"--annotator {annotator!r}: no labels by them in {db} "
                                     f"(annotators: {', '.join(known) or 'none'})")
        elif len(known) == 1:
            annotator = known[0]
        else:
            self.close()
            raise ParameterError(f"{db} has labels by {len(known)} annotators "
                                 f"({', '.join(known) or 'none'}): choose one with --annotator")
        self.annotator = annotator
        self.name = f"labels by {annotator} ({self.db})"
        self.choice = "labels"

    def record(self, frame: Frame) -> FrameRecord | None:
        """The store's frame record for a log frame: by (log, topic, stamp), else by a unique stamp."""
        if self.log is not None:
            rec = self.store.frame(self.log, topic=frame.topic, stamp_ns=frame.stamp_ns)
            if rec is not None:
                return rec
        recs = self.store.frames_at_stamp(frame.stamp_ns)
        if self.log is not None:
            recs = [r for r in recs if r.log_id == self.log.id] or recs
        return recs[0] if len(recs) == 1 else None

    def truth(self, frame: Frame, valid: np.ndarray) -> FrameTruth | str:
        rec = self.record(frame)
        lab = self.store.label(rec, annotator=self.annotator) if rec is not None else None
        if lab is None:
            return "not labelled"
        if lab.outliers.shape != frame.shape:
            raise ParameterError(f"labels of frame {frame.index} are {lab.outliers.shape[0]}x{lab.outliers.shape[1]}, "
                                 f"the frame is {frame.shape[0]}x{frame.shape[1]}: labels of another log?")
        return FrameTruth(lab.outliers, lab.reviewed, None, self.name)

    def close(self) -> None:
        self.store.close()


def results_metadata(path: str | os.PathLike[str]) -> dict[str, str] | None:
    """The ``zcut.results`` metadata of a results file of ``zcut replay --out`` (its ``source`` log,
    its ``config_toml``), or None for a log that is not one.

    Raises
    ------
    OSError, ZcutError
        The file cannot be read as MCAP.
    """
    from replay.logs.reader import inspect_log

    meta = inspect_log(path).metadata.get(layout.RESULTS_METADATA)
    return None if meta is None else dict(meta)


def is_results_file(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is a results file of ``zcut replay --out`` (:func:`results_metadata`)."""
    from zcut.errors import ZcutError

    try:
        return results_metadata(path) is not None
    except (OSError, ZcutError):  # not MCAP, unreadable: the replay of it says what is wrong
        return False


def method_predictions(result: FrameResult, methods: Iterable[str]) -> dict[str, np.ndarray]:
    """The masks of the reported ``methods`` (``config.reported_methods``) of a
    :class:`~replay.pipeline.stages.FrameResult` (docs/accuracy.md)."""
    from replay.pipeline.methods import method_masks

    return method_masks(result.outliers, methods)


def pixel_counts(predicted: np.ndarray, truth: FrameTruth, region: np.ndarray) -> tuple[int, int, int]:
    """(TP, FP, FN) over S = R ∩ region (docs/accuracy.md): |P∩L∩S|, |P∩S∖L|, |L∩S∖P|."""
    s = truth.reviewed & region
    p = predicted & s
    lab = truth.outliers & s
    tp = int(np.count_nonzero(p & lab))
    return tp, int(np.count_nonzero(p)) - tp, int(np.count_nonzero(lab)) - tp
