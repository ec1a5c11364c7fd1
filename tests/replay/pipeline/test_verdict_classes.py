"""method_verdict (no masked stores, no bincount) gives the classes and counts of its literal definition
(the previous code: TP, FP, FN painted one after the other, counted by bincount) on several classes of
masks: random, empty, full, disjoint, equal, one pixel, tiny."""

from __future__ import annotations

import numpy as np
import pytest

from replay.pipeline.verdicts import FN, FP, TP, method_verdict


def _literal(predicted, outliers, scored):
    p = np.asarray(predicted, bool) & scored
    lab = np.asarray(outliers, bool) & scored
    classes = np.zeros(p.shape, np.uint8)
    classes[p & lab] = TP
    classes[p & ~lab] = FP
    classes[lab & ~p] = FN
    counts = np.bincount(classes.ravel(), minlength=4)
    return classes, int(counts[TP]), int(counts[FP]), int(counts[FN])


def _cases():
    rng = np.random.default_rng(5)
    for shape in [(1, 1), (3, 3), (40, 64), (120, 193)]:
        def r(q: float, shape: tuple[int, int] = shape) -> np.ndarray:
            return rng.random(shape) < q

        yield r(0.3), r(0.2), r(0.8)
        yield np.zeros(shape, bool), r(0.5), np.ones(shape, bool)
        yield np.ones(shape, bool), np.ones(shape, bool), r(0.5)
        a = r(0.5)
        yield a, ~a, np.ones(shape, bool)
        yield a, a, r(0.9)
        one = np.zeros(shape, bool)
        one.flat[-1] = True
        yield one, one, one
        yield r(0.5), r(0.5), np.zeros(shape, bool)


@pytest.mark.parametrize("case", list(_cases()))
def test_method_verdict_is_the_literal_one(case):
    p, lab, scored = case
    v = method_verdict(p, lab, scored)
    classes, tp, fp, fn = _literal(p, lab, scored)
    assert v.classes.dtype == np.uint8 and v.classes.shape == p.shape
    assert np.array_equal(v.classes, classes) and (v.tp, v.fp, v.fn) == (tp, fp, fn)
