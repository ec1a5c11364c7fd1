"""The reader thread (``replay.pipeline.session.prefetched``) reads at most ``depth`` frames ahead of the
consumer: a frame read and not taken holds its arrays and chunks (docs/performance.md, round of 2026-12-05c)."""

from __future__ import annotations

import threading
import time

import pytest

from replay.pipeline.session import prefetched


@pytest.mark.parametrize("depth", [1, 2, 3])
def test_never_more_than_depth_frames_read_and_not_taken(depth: int) -> None:
    lock = threading.Lock()
    read = [0]

    def frames():  # type: ignore[no-untyped-def]
        for i in range(12):
            with lock:
                read[0] += 1
            yield i

    taken = 0
    ahead = []
    it = prefetched(frames(), depth=depth)
    for x in it:
        assert x == taken
        taken += 1
        time.sleep(0.02)  # the consumer's work: the thread reads meanwhile, as far as it may
        with lock:
            ahead.append(read[0] - taken)
    assert taken == 12
    assert max(ahead) <= depth
    assert max(ahead[:-depth]) == depth  # and it does read that far ahead


def test_an_early_close_leaves_no_thread_and_drops_what_was_read() -> None:
    closed = []

    def frames():  # type: ignore[no-untyped-def]
        try:
            yield from range(100)
        finally:
            closed.append(True)

    it = prefetched(frames(), depth=1)
    assert next(it) == 0
    time.sleep(0.05)
    it.close()
    assert closed == [True]
    assert not any(t.name == "zcut-frame-reader" for t in threading.enumerate())
