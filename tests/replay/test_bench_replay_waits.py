"""bench/bench_replay.py --threads: the estimate for quiet cores of a traced run (a pure function of its samples)
and the names it groups and places threads by (docs/performance.md, "Where the last core-fraction waits")."""

from __future__ import annotations

import sys
import threading

import pytest
from bench_helpers import bench_module


@pytest.fixture(scope="module")
def bench():
    yield from bench_module("bench_replay.py")


def test_work_with_two_threads_ready_takes_half_its_cpu_on_two_cores(bench):
    # 20 samples of 5 ms, 10 ms of CPU each (two threads running), two ready at every sample
    samples = [(0.005 * (i + 1), 0.010, 2.0) for i in range(20)]
    q = bench.quiet_estimate(samples, [(1, 0.05), (2, 0.1)], cores=2)
    assert q["wall_ms"] == pytest.approx(1000 * 0.2 / 2 / 2)  # 0.2 CPU-s on two cores, 2 frames
    assert q["cores_busy"] == pytest.approx(2.0)
    assert q["short_share"] == 0.0
    assert [i for i, _ in q["delivered_ms"]] == [1, 2]
    assert q["delivered_ms"][-1][1] == pytest.approx(100.0)


def test_work_with_one_thread_ready_takes_its_whole_cpu(bench):
    # the first half: one thread ready (5 ms of CPU a sample), the second: three ready (at most two run)
    samples = [(0.005 * (i + 1), 0.005, 1.0) for i in range(10)] + [
        (0.05 + 0.005 * (i + 1), 0.010, 3.0) for i in range(10)]
    q = bench.quiet_estimate(samples, [(7, 0.1)], cores=2, window=10)
    assert q["wall_ms"] == pytest.approx(1000 * (0.05 / 1 + 0.1 / 2))
    assert q["cores_busy"] == pytest.approx(0.15 / 0.1)
    assert q["short_share"] == pytest.approx(0.5)
    # a window where fewer than one thread was seen ready still did its work on one core at least
    q = bench.quiet_estimate([(0.005, 0.002, 0.0)], [], cores=2, window=1)
    assert q["wall_ms"] == pytest.approx(2.0)


def test_thread_groups_and_places(bench):
    assert bench._group("zcut-frame_0") == "zcut-frame"
    assert bench._group("mcap-chunks_12") == "mcap-chunks"
    assert bench._group("MainThread") == "MainThread"
    assert bench._group("zcut-sor-3") == "zcut-sor"
    # a thread blocked in threading's code is placed at its innermost line of zcut's code, with the wait named
    from replay.pipeline import session

    ready, stop = threading.Event(), threading.Event()
    q = session.prefetched(iter(lambda: (ready.set(), stop.wait())[0], 1), depth=1)
    consumer = threading.Thread(target=lambda: next(q, None), name="test-consumer")
    consumer.start()
    ready.wait()
    frames = sys._current_frames()
    reader = next(t for t in threading.enumerate() if t.name == "zcut-frame-reader")
    place = bench._where(frames[reader.ident])
    del frames
    stop.set()
    consumer.join()
    q.close()
    assert place.startswith("session.py:produce:"), place  # the frame reader's loop, in zcut's code
    assert "`f = next(frames)`" in place and place.endswith(" <- wait"), place  # blocked in threading's wait
