"""The count columns of sweep.parquet are one dataclass (studies.scoring.Counts): its fields name the
columns, in the table's order, and it counts a mask as the sweep and the bank did."""

from __future__ import annotations

import numpy as np

from studies.scoring import CONFUSION_COLUMNS, COUNT_COLUMNS, Counts


def test_the_fields_are_the_table_columns():
    assert COUNT_COLUMNS == ("tp", "fp", "fn", "n_pred", "n_both", "n_sor_only", "n_zcut_only")
    assert CONFUSION_COLUMNS == ("tp", "fp", "fn")


def test_counts_of_a_mask(rng):
    pred, truth, scored = (rng.random((30, 40)) < p for p in (0.3, 0.2, 0.7))
    c = Counts.of(pred, truth, scored)
    assert c.tp == int((pred & truth & scored).sum())
    assert c.fp == int((pred & ~truth & scored).sum())
    assert c.fn == int((~pred & truth & scored).sum())
    assert c.n_pred == int(pred.sum())  # anywhere, not only in the scored region
    assert c.columns() == {"tp": c.tp, "fp": c.fp, "fn": c.fn, "n_pred": c.n_pred}  # no overlap: left out
    assert Counts(1, 2, 3, 4, n_both=0, n_sor_only=5, n_zcut_only=6).columns() == dict(
        zip(COUNT_COLUMNS, (1, 2, 3, 4, 0, 5, 6)))
    assert Counts.of(np.zeros((2, 2), bool), np.ones((2, 2), bool), np.ones((2, 2), bool)).fn == 4
