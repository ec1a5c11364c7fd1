"""What a replay holds while it computes a frame (docs/performance.md, round of 2026-12-05c): the reader
thread (``replay.pipeline.session.prefetched``) reads at most ``depth`` frames ahead of the consumer (a frame
read and not taken holds its arrays and chunks), and ``ReplaySession.run`` does not hold a frame's result
while the next one is computed (its arrays would be added to the next frame's instead of reused)."""

from __future__ import annotations

import threading
import time
import weakref

import pytest

from replay.pipeline import session as session_mod
from replay.pipeline.bin_model import bin_model_for
from replay.pipeline.session import ReplaySession, prefetched
from replay.synth.log import write_synthetic_log


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


def test_a_result_is_not_held_while_the_next_frame_is_computed(tmp_path, monkeypatch) -> None:
    log = write_synthetic_log(tmp_path / "three.mcap", kind="zinc_nuts", frames=3, seed=6321, size=(120, 160))
    session = ReplaySession.open(log, choose_bin_model=lambda r: bin_model_for(r, None))
    previous: list[weakref.ref] = []
    alive_when_computing: list[bool] = []
    run_frame = session_mod.run_frame

    def watched(frame, config, **kw):  # type: ignore[no-untyped-def]
        alive_when_computing.append(any(ref() is not None for ref in previous))
        return run_frame(frame, config, **kw)

    def on_frame(frame, result, row) -> None:  # type: ignore[no-untyped-def]
        previous.append(weakref.ref(result.height_mm))  # an array only this frame's result holds

    monkeypatch.setattr(session_mod, "run_frame", watched)
    summary = session.run(on_frame=on_frame, in_flight=1)
    assert len(summary.rows) == 3 and len(alive_when_computing) == 3
    assert not any(alive_when_computing)
