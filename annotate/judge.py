"""The truth a replay's recording shows each filter's mistakes against (docs/compare.md, "Where each
filter is wrong"): a :class:`replay.pipeline.verdicts.FrameJudge` built on :mod:`annotate.truth`,
so that the recording's counts are ``zcut accuracy``'s.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from annotate.truth import LabelTruth, check_region, method_predictions, scored_region, synthetic_truth
from replay.pipeline.verdicts import MethodVerdict, method_verdict

if TYPE_CHECKING:
    from replay.logs.frame import Frame
    from replay.pipeline.stages import FrameResult


class TruthJudge:
    """Each method's TP / FP / FN of a frame against a truth source of :mod:`annotate.truth`, over the
    scored region ``region`` (``zone`` or ``valid``, docs/accuracy.md), as ``zcut accuracy`` counts them.

    Parameters
    ----------
    truth : SyntheticTruth or LabelTruth
        What a frame is scored against (``.truth(frame, valid)``, ``.name``).
    methods : tuple of str
        The methods judged (the config's ``methods``: base methods and unions ``a+b``).
    region : str
    """

    def __init__(self, truth: Any, methods: tuple[str, ...], *, region: str = "zone") -> None:
        self.truth = truth
        self.methods = tuple(methods)
        self.region = check_region(region)
        self.source: str = truth.name

    def judge(self, frame: Frame, result: FrameResult) -> dict[str, MethodVerdict] | str:
        t = self.truth.truth(frame, result.valid)
        if isinstance(t, str):
            return t
        scored = t.reviewed & scored_region(result, self.region)
        preds = method_predictions(result, self.methods)
        return {m: method_verdict(p, t.outliers, scored) for m, p in preds.items()}

    def close(self) -> None:
        close = getattr(self.truth, "close", None)
        if close is not None:
            close()


def judge_for_log(log: str | os.PathLike[str], mask_topics: Any, methods: tuple[str, ...], *,
                  labels: str | os.PathLike[str] | None = None, annotator: str | None = None,
                  truth: str | None = None, region: str = "zone") -> TruthJudge | None:
    """The judge of a log's replay: an annotator's labels with ``labels`` (``--labels DB``), else the
    log's recorded truth as ``zcut accuracy`` picks it (``truth``: ``--truth paper|sensor``, None the
    paper's where the log has it, :func:`annotate.truth.synthetic_truth`; ``mask_topics``: the log's
    mask topics), else None (no truth: the recording shows nothing more).

    Raises
    ------
    FileNotFoundError, ParameterError
        ``labels`` missing; no labels by ``annotator`` (or several annotators and none chosen); a
        ``truth`` asked for that the log does not have.
    """
    if labels is not None:
        if not Path(labels).is_file():
            raise FileNotFoundError(2, "no such file", str(labels))
        return TruthJudge(LabelTruth(labels, log, annotator=annotator), methods, region=region)
    found = synthetic_truth(truth, set(mask_topics), log)
    return None if found is None else TruthJudge(found, methods, region=region)
