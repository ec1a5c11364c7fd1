"""bench/bench_replay.py --stages-only --against --repeats: the paired ratios a lever's bar reads."""

from __future__ import annotations

import pytest
from bench_helpers import bench_module


@pytest.fixture(scope="module")
def bench():
    yield from bench_module("bench_replay.py")


def test_paired_ratios_pair_run_i_of_each_tree(bench):
    previous = [{"total": 42.0}, {"total": 40.0}, {"total": 44.0}]
    this = [{"total": 40.0}, {"total": 40.0}, {"total": 40.0}]
    ratios, median, least = bench.paired_ratios(previous, this, "total")
    assert ratios == pytest.approx([1.05, 1.0, 1.1])
    assert median == pytest.approx(1.05)
    assert least == pytest.approx(1.0)


@pytest.mark.parametrize(("previous", "this"), [([], []), ([{"total": 1.0}], [])])
def test_paired_ratios_need_as_many_runs_of_each(bench, previous, this):
    with pytest.raises(ValueError, match="as many runs of each tree"):
        bench.paired_ratios(previous, this, "total")
