"""Where each filter is wrong on a frame: its true positives, false positives and misses against the
frame's truth, as the recording shows them (:mod:`replay.pipeline.viz`, ``image/verdicts/NAME``).

The pipeline does not know what a frame is scored against (that is :mod:`annotate.truth`, a floor
above); a command that has truth hands the replay a :class:`FrameJudge` (``annotate.judge.TruthJudge``),
and :class:`replay.pipeline.sinks.RerunSink` asks it for each frame's :class:`MethodVerdict` of every
method. The counts are ``zcut accuracy``'s (docs/accuracy.md): over S = R ∩ region, TP = |P∩L∩S|,
FP = |P∩S∖L|, FN = |L∩S∖P|.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

if TYPE_CHECKING:
    from replay.logs.frame import Frame
    from replay.pipeline.stages import FrameResult

#: The classes of a verdict image (0: not flagged and not a true outlier, or not scored);
#: :func:`method_verdict` computes them as (2·P + 3·L) mod 4.
TP, FP, FN = 1, 2, 3


@dataclass(frozen=True, slots=True)
class MethodVerdict:
    """One method's verdict on one frame.

    Attributes
    ----------
    classes : (H, W) uint8 ndarray
        :data:`TP` (flagged, a true outlier), :data:`FP` (flagged, not one), :data:`FN` (a true
        outlier it missed) over the scored pixels; 0 elsewhere.
    tp, fp, fn : int
        The pixels of each class.
    """

    classes: np.ndarray
    tp: int
    fp: int
    fn: int

    @property
    def precision(self) -> float:
        """TP / (TP + FP); NaN when nothing was flagged."""
        return self.tp / (self.tp + self.fp) if self.tp + self.fp else math.nan

    @property
    def recall(self) -> float:
        """TP / (TP + FN); NaN when there was nothing to find."""
        return self.tp / (self.tp + self.fn) if self.tp + self.fn else math.nan


def method_verdict(predicted: np.ndarray, outliers: np.ndarray, scored: np.ndarray) -> MethodVerdict:
    """The verdict of a prediction P against the true outliers L over the scored pixels S."""
    p = np.asarray(predicted, bool) & scored
    lab = np.asarray(outliers, bool) & scored
    # with x = P, y = L (0 / 1): TP (1, 1) -> 1, FP (1, 0) -> 2, FN (0, 1) -> 3, nothing (0, 0) -> 0 is
    # (2x + 3y) mod 4: four passes over bytes instead of TP, FP, FN's masks painted one by one
    classes = p.view(np.uint8) * np.uint8(2)
    classes += lab.view(np.uint8) * np.uint8(3)
    classes &= np.uint8(3)
    tp = int(np.count_nonzero(p & lab))
    return MethodVerdict(classes, tp, int(np.count_nonzero(p)) - tp, int(np.count_nonzero(lab)) - tp)


class FrameJudge(Protocol):
    """What a replay's frames are scored against, for the recording.

    Attributes
    ----------
    source : str
        What the truth is ("ground truth /ground_truth/outliers", "labels by alice (labels.sqlite)").
    methods : tuple of str
        The methods it judges, in order.
    """

    source: str
    methods: tuple[str, ...]

    def judge(self, frame: Frame, result: FrameResult) -> dict[str, MethodVerdict] | str:
        """Every method's verdict on the frame, or why the frame is not scored (one line)."""
        ...
