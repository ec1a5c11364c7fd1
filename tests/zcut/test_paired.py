"""zcut.paired: the paired difference of two filters' pooled figures, its interval, wins and the sign test."""

from __future__ import annotations

import math

import numpy as np
import pytest

from zcut.errors import InputShapeError, ParameterError
from zcut.paired import frame_outcomes, paired_differences, paired_interval_many, sign_test


def _counts(rng, n):
    tp = rng.integers(0, 200, n)
    return tp, rng.integers(0, 100, n), rng.integers(0, 150, n)


def test_the_difference_is_of_the_pooled_figures(rng):
    a, b = _counts(rng, 12), _counts(rng, 12)
    d = paired_differences(a, b)
    ra = a[0].sum() / (a[0].sum() + a[1].sum())
    rb = b[0].sum() / (b[0].sum() + b[1].sum())
    assert d["precision"].delta == pytest.approx(rb - ra)
    f1 = lambda c: 2 * c[0].sum() / (2 * c[0].sum() + c[1].sum() + c[2].sum())  # noqa: E731
    assert d["f1"].delta == pytest.approx(f1(b) - f1(a))
    for k in ("precision", "recall", "f1"):
        assert d[k].lo <= d[k].delta <= d[k].hi
    # swapping A and B mirrors the interval
    e = paired_differences(b, a)
    for k in ("precision", "recall", "f1"):
        assert e[k].delta == pytest.approx(-d[k].delta)
        assert (e[k].lo, e[k].hi) == pytest.approx((-d[k].hi, -d[k].lo))


def test_a_batch_row_gives_the_interval_of_that_sample_alone(rng):
    a, b = _counts(rng, 30), _counts(rng, 30)
    idx = rng.integers(0, 30, size=(5, 8))
    many = paired_interval_many(tuple(x[idx] for x in a), tuple(x[idx] for x in b))
    for i in range(5):
        one = paired_differences(tuple(x[idx[i]] for x in a), tuple(x[idx[i]] for x in b))
        for k in ("precision", "recall", "f1"):
            assert many[k][i].tolist() == pytest.approx([one[k].delta, one[k].lo, one[k].hi])


def test_no_interval_for_too_few_frames_or_no_variation(rng):
    a, b = _counts(rng, 2), _counts(rng, 2)
    assert not paired_differences(a, b)["f1"].has_interval
    same = _counts(rng, 10)
    d = paired_differences(same, same)["f1"]
    assert d.delta == 0 and not d.has_interval
    empty = tuple(np.zeros(10, dtype=np.int64) for _ in range(3))
    assert math.isnan(paired_differences(empty, same)["precision"].delta)


def test_a_paired_interval_is_narrower_than_the_unpaired_spread(rng):
    """B = A plus a small shift on every frame: the frames' own variation cancels in the pair."""
    tp = rng.integers(50, 2000, 20)
    fp = rng.integers(0, 500, 20)
    fn = rng.integers(10, 1500, 20)
    d = paired_differences((tp, fp, fn), (tp + 5, fp, np.maximum(fn - 5, 0)))["recall"]
    assert d.lo > 0 and d.hi - d.lo < 0.02


def test_wins_are_exact_on_counts():
    a = (np.array([1, 2, 0, 0]), np.array([1, 0, 0, 1]), np.array([0, 2, 0, 0]))
    b = (np.array([2, 1, 0, 0]), np.array([2, 0, 0, 0]), np.array([0, 3, 0, 0]))
    # frame 0: 2/3 vs 4/6 tie; frame 1: 4/6 vs 2/5 loss; frame 2: 0/0 both (1 = 1) tie; frame 3: 0/1 vs 0/0 win
    assert frame_outcomes(a, b).tolist() == [0, -1, 0, 1]


def test_sign_test():
    assert sign_test(0, 0) == 1.0
    assert sign_test(4, 0) == pytest.approx(0.125)
    assert sign_test(41, 9) < 1e-5
    assert sign_test(5, 5) == pytest.approx(1.0)


@pytest.mark.parametrize(("a", "b", "level", "error", "match"), [
    ((np.ones(3, dtype=float),) * 3, (np.ones(3, dtype=np.int64),) * 3, 0.95, InputShapeError, "integer"),
    ((np.ones(3, dtype=np.int64),) * 3, (np.ones(4, dtype=np.int64),) * 3, 0.95, InputShapeError, "shape"),
    ((-np.ones(3, dtype=np.int64),) * 3, (np.ones(3, dtype=np.int64),) * 3, 0.95, ParameterError, "negative"),
    ((np.ones(3, dtype=np.int64),) * 3, (np.ones(3, dtype=np.int64),) * 3, 1.5, ParameterError, "level"),
])
def test_bad_input(a, b, level, error, match):
    with pytest.raises(error, match=match):
        paired_interval_many(a, b, level=level)
