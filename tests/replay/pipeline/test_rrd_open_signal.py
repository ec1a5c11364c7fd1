"""A signal while Rerun's ``save`` opens the .rrd's temporary leaves nothing behind.

Rerun creates the file at the temporary's path itself; removed while its ``save`` still ran, the
temporary was made again after the clean-up (h/trim4 saw a ``.o.XXXXXXXX.partial.rrd`` left by a
replay given SIGTERM at its first note, once, under load). Here Rerun's real ``save`` is
reached 0.4 s late, so the signal lands inside that window every time.
"""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest

from replay.process import Interrupted


class _LateSave:
    """A real recording whose ``save`` starts 0.4 s late (the window a signal must hit)."""

    def __init__(self, rec):
        self.rec = rec

    def save(self, path, default_blueprint=None):
        time.sleep(0.4)
        self.rec.save(path, default_blueprint=default_blueprint)

    def __getattr__(self, name):
        return getattr(self.rec, name)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT, signal.SIGHUP], ids=["SIGTERM", "SIGINT", "SIGHUP"])
def test_a_signal_while_rerun_opens_the_rrd_leaves_no_temporary(tmp_path, sig):
    from replay.pipeline import viz
    from replay.pipeline.sinks import RrdFile
    from replay.process import interrupts_unwind

    rec = viz.new_recording()
    late = _LateSave(rec)
    f = RrdFile(tmp_path / "o.rrd")
    assert [p.name for p in tmp_path.iterdir()] == [f.temp.name]  # ours, before Rerun's
    timer = threading.Timer(0.1, os.kill, (os.getpid(), sig))
    t0 = time.monotonic()
    with pytest.raises(Interrupted):
        with interrupts_unwind():
            timer.start()
            try:
                f.save(late, None)  # type: ignore[arg-type]
            except BaseException:
                f.close(rec, completed=False)  # what RerunSink.start does on the way out
                raise
    assert time.monotonic() - t0 >= 0.4  # Rerun's save was let finish before the clean-up
    time.sleep(0.3)  # nothing is made later either
    assert list(tmp_path.iterdir()) == []
