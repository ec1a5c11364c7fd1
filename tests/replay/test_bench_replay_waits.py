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


def test_wait_kinds(bench):
    # blocked in threading's code below a line of zcut's: a wait at that line
    assert bench.wait_kind("session.py:_frame_result:640 `location = future.result()` <- wait") == (
        "waits at session.py:_frame_result `location = future.result()`")
    # a C call that blocks without a Python frame of its own (SimpleQueue.get): a wait too
    assert bench.wait_kind("session.py:prefetched:330 `kind, item = q.get()`") == (
        "waits at session.py:prefetched `kind, item = q.get()`")
    # off the CPU at any other line of zcut's code: the GIL or a native call
    assert bench.wait_kind("zone.py:_at_or_above:90 `out = zone & (h >= t)`") == (
        "GIL or native call at zone.py:_at_or_above `out = zone & (h >= t)`")
    assert bench.wait_kind("thread.py:_worker:89") == "idle in its pool"
    assert bench.wait_kind("native") == "native"


def _sample(dt, *rows):
    return (0.0, dt, [(tid, run, queued, True, place) for tid, run, queued, place in rows])


def test_idle_causes_credits_the_missing_core_to_the_workers_states(bench):
    names = {"1": "MainThread", "2": "zcut-frame_0", "3": "zcut-frame_1"}
    wait = "session.py:_frame_result:640 `location = future.result()` <- wait"
    records = [
        # both workers ran the whole 10 ms: no idle, 10 ms of wall on two cores
        _sample(0.010, (2, 0.010, 0.0, "x"), (3, 0.010, 0.0, "x"), (1, 0.0, 0.0, "thread.py:_worker:89")),
        # one ran, the other waited for its location: one core idle for 10 ms
        _sample(0.010, (2, 0.010, 0.0, "x"), (3, 0.0, 0.0, wait), (1, 0.0, 0.0, "thread.py:_worker:89")),
        # a loaded machine: both ready all the time but each ran half of it (waited on a run queue): on quiet
        # cores 5 ms, none idle
        _sample(0.010, (2, 0.005, 0.005, "x"), (3, 0.005, 0.005, "x")),
    ]
    got = bench.idle_causes(records, names, cores=2)
    assert got["wall_s"] == pytest.approx(0.010 + 0.010 + 0.005)
    assert got["idle_s"] == pytest.approx(0.010)
    assert got["idle_share"] == pytest.approx(0.010 / (2 * 0.025))
    assert got["by"] == {"1 frame worker(s) busy; the other(s): waits at session.py:_frame_result "
                         "`location = future.result()`": pytest.approx(0.010)}
    # nothing ran at all: the sample keeps its length and both cores idle
    got = bench.idle_causes([_sample(0.004, (2, 0.0, 0.0, wait), (3, 0.0, 0.0, wait))], names, cores=2)
    assert got["idle_s"] == pytest.approx(0.008) and got["idle_share"] == pytest.approx(1.0)


def test_print_timeline_draws_each_thread_and_the_cores_used(bench, capsys):
    names = {"1": "MainThread", "2": "zcut-frame_0", "3": "zcut-frame_1"}
    wait = "session.py:_frame_result:640 `location = future.result()` <- wait"
    records = [(0.010 * (i + 1), 0.010, [(1, 0.0, 0.0, False, "session.py:_results:600 `work.result()` <- wait"),
                                         (2, 0.010, 0.0, True, "x"),
                                         (3, 0.010 if i % 2 else 0.0, 0.0, bool(i % 2), "x" if i % 2 else wait)])
               for i in range(8)]
    run = {"names": names, "records": records, "frames": 2, "in_flight": 2, "layer": "omp", "cpu_ms": 60.0,
           "delivered": [(1, 0.03), (2, 0.06), (3, 0.08)]}
    bench.print_timeline(run, "this tree")
    out = capsys.readouterr().out
    # half the samples one worker waited for its location: a quarter of two cores idle
    assert "= 25.0 % of the cores" in out, out
    assert "waits at session.py:_frame_result `location = future.result()`" in out
    lines = {ln.split()[0]: ln.split()[-1] for ln in out.splitlines() if ln.startswith("    ") and len(ln.split()) >= 2}
    assert lines["zcut-frame_0"].startswith("####")  # ran every bin
    assert lines["MainThread"].startswith("wwww")  # blocked in a wait throughout
