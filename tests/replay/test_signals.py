"""SIGINT, SIGTERM and SIGHUP (docs/cli.md, exit status): one line, exit 130, 143 or 129, no temporary
file and no lock left, whenever the signal lands — during start-up, while frames run, while outputs
close."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from session_logs import synth_once
from subprocess_helpers import run_python

from replay.process import Interrupted, InterruptState, interrupted_by


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    # the log of tests/replay/pipeline/test_full_disk.py too: made once per session
    return synth_once(tmp_path_factory, parts="zinc_nuts", frames=4, seed=3, size="480x640")


def _start(log: Path, out: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "cli", "replay", str(log), "--rrd", str(out / "o.rrd"),
                             "--out", str(out / "r.mcap")], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def _wait_for(p: subprocess.Popen, needle: bytes, seen: bytearray) -> None:
    """Read stderr until ``needle`` appears."""
    deadline = time.monotonic() + 300
    while needle not in seen:
        chunk = p.stderr.read1(4096)
        assert chunk and time.monotonic() < deadline, seen.decode(errors="replace")
        seen += chunk


SIGNALS = [signal.SIGINT, signal.SIGTERM, signal.SIGHUP]
SIGNAL_IDS = ["SIGINT", "SIGTERM", "SIGHUP"]


@pytest.mark.parametrize("sig", SIGNALS, ids=SIGNAL_IDS)
@pytest.mark.parametrize("moment", ["start-up", "first note", "first frame", "second frame"])
def test_a_signal_ends_replay_in_one_line_with_no_leftovers(log, tmp_path, sig, moment):
    p = _start(log, tmp_path)
    seen = bytearray()
    try:
        if moment == "start-up":  # loading numba and the kernels (seconds; after the handlers are in place)
            deadline = time.monotonic() + 300
            while "numba" not in Path(f"/proc/{p.pid}/maps").read_text():
                assert p.poll() is None and time.monotonic() < deadline
                time.sleep(0.01)
        else:
            _wait_for(p, {"first note": b"zcut:", "first frame": b"] frame 0:", "second frame": b"] frame 1:"}[moment],
                      seen)
        p.send_signal(sig)
        seen += p.stderr.read()
        p.wait(timeout=300)
    finally:
        p.kill()
        p.stderr.close()
    err = seen.decode(errors="replace")
    assert p.returncode == 128 + sig, err
    # (the signal may land between a progress line and its newline)
    assert err.rstrip().endswith(f"interrupted ({signal.Signals(sig).name})") and err.count("interrupted") == 1, err
    assert "Traceback" not in err and "Error" not in err, err
    assert sorted(q.name for q in tmp_path.iterdir()) == []  # no temporary, no lock, no half output


def test_the_command_line_handles_signals_before_it_loads_the_kernels():
    """Importing the console script loads no numba (nor zcut): the handlers are in place before
    the seconds of loading the kernels, so a Ctrl-C then is one line too (and ``--help`` is fast)."""
    code = "import sys, cli.main; print(sorted(m for m in ('numba', 'zcut', 'numpy') if m in sys.modules))"
    out = run_python(code, check=True)
    assert out.stdout.strip() == "[]"


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_a_signal_while_the_command_line_loads_is_one_line_and_128_plus_it(tmp_path, sig):
    """The program entry (cli/entry.py) handles SIGTERM and SIGHUP before the command's modules are
    imported: a signal landing while ``cli.main`` loads ends with 143 (129) and one line, not killed
    by it (-15, -1)."""
    code = ("import builtins, os, signal, sys\n"
            "real = builtins.__import__\n"
            "def imp(name, *a, **k):\n"
            "    if name == 'cli.main':\n"
            f"        os.kill(os.getpid(), {int(sig)})\n"
            "    return real(name, *a, **k)\n"
            "builtins.__import__ = imp\n"
            "sys.argv = ['zcut', '--help']\n"
            "from cli.entry import run\n"
            "sys.exit(run())\n")
    out = run_python(code, timeout=300)
    assert out.returncode == 128 + sig, out
    assert out.stderr.strip() == f"interrupted ({signal.Signals(sig).name})"


@pytest.mark.parametrize("sig", SIGNALS, ids=SIGNAL_IDS)
def test_a_signal_after_the_command_finished_keeps_its_status(log, sig):
    """Once the command returned, its outputs are published: a signal during the interpreter's teardown
    (where Python restores the default disposition) leaves the command's own exit status."""
    code = ("import os, signal, sys, time\n"
            f"sys.argv = ['zcut', 'topics', {str(log)!r}]\n"
            "from cli.entry import command, end\n"
            "status = command()\n"
            f"os.kill(os.getpid(), {int(sig)})\n"
            "time.sleep(0.2)\n"
            "end(status)\n")
    out = run_python(code, timeout=300)
    assert out.returncode == 0, out
    assert "/camera/points" in out.stdout and "interrupted" not in out.stderr


def test_the_end_of_the_process_waits_for_threads_and_runs_the_exit_handlers(tmp_path):
    """The entry ends the process with ``os._exit`` once the command returned (cli/entry.py, "The end of
    the process"), after what Python's finalisation does that anyone can see: a thread that is not a
    daemon finishes its work, the ``atexit`` handlers and ``weakref.finalize`` clean-ups run (a
    ``tempfile`` folder is removed), buffered output is flushed, and the status is the command's."""
    code = ("import atexit, sys, tempfile, threading, time\n"
            "import cli.main\n"
            "from pathlib import Path\n"
            f"out = Path({str(tmp_path)!r})\n"
            "def main():\n"
            "    def late():\n"
            "        time.sleep(0.3)\n"
            "        (out / 'thread').write_text('done')\n"
            "    threading.Thread(target=late).start()\n"
            "    atexit.register(lambda: (out / 'atexit').write_text('ran'))\n"
            "    keep = tempfile.TemporaryDirectory(dir=out)\n"
            "    (out / 'tmpname').write_text(keep.name)\n"
            "    main.keep = keep\n"
            "    sys.stdout.write('buffered, no newline')\n"
            "    return 3\n"
            "cli.main.main = main\n"
            "sys.argv = ['zcut']\n"
            "from cli.entry import run\n"
            "run()\n"
            "raise SystemExit('run() returned')\n")
    out = run_python(code, timeout=300)
    assert out.returncode == 3, out
    assert out.stdout == "buffered, no newline" and out.stderr == ""
    assert (tmp_path / "thread").read_text() == "done"
    assert (tmp_path / "atexit").read_text() == "ran"
    assert not Path((tmp_path / "tmpname").read_text()).exists()


def test_an_error_the_interruption_caused_is_the_interruption():
    """A library may turn the interruption into an error of its own (numba: ``SystemError: ...
    returned a result with an exception set``, from the KeyboardInterrupt): still 130/143, and any
    error after a signal arrived is one too."""
    try:
        try:
            raise Interrupted(signal.SIGTERM)
        except KeyboardInterrupt as e:
            raise SystemError("<built-in function x> returned a result with an exception set") from e
    except SystemError as e:
        assert interrupted_by(e) == 143
    assert interrupted_by(RuntimeError("plain")) is None
    state = InterruptState()
    state.signals.append(signal.SIGINT)
    assert interrupted_by(RuntimeError("after the signal"), state) == 130
    assert interrupted_by(KeyboardInterrupt()) == 130


def test_sinks_interrupted_while_starting_leave_nothing(log, tmp_path):
    """An interruption while the sinks start (the recording's temporary made, the viewer stream being
    set up): the sinks already started are closed, their temporaries removed."""
    from replay.pipeline.session import ReplaySession
    from replay.pipeline.sinks import BackgroundSinks, NullSink, RerunSink, ResultsSink

    class Interrupting(NullSink):
        def start(self, info):
            raise Interrupted(signal.SIGINT)

    info = ReplaySession.open(log).start_info()
    sinks = BackgroundSinks([RerunSink(rrd=tmp_path / "o.rrd"), ResultsSink(tmp_path / "r.mcap"), Interrupting()])
    with pytest.raises(Interrupted):
        sinks.start(info)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("where", ["weakref callback", "__del__"])
def test_a_signal_landing_where_python_ignores_exceptions_still_interrupts(where):
    """The handler's exception may land in a weakref callback (CI: importlib's module-lock ``cb``
    while replay imported a module) or a ``__del__``, where Python prints "Exception ignored in ..."
    and goes on: the signal is delivered again and raises at the next ordinary line, with nothing
    printed (it was the replay that ran to its end, printed a traceback and then 'interrupted')."""
    code = (
        "import os, signal, time, weakref\n"
        "from replay.process import Interrupted, interrupts_unwind\n"
        "class Thing:\n"
        "    def __del__(self):\n"
        "        if WHERE == '__del__':\n"
        "            os.kill(os.getpid(), signal.SIGHUP)\n"
        "            for _ in range(1000): pass\n"
        "def cb(ref):\n"
        "    os.kill(os.getpid(), signal.SIGHUP)\n"
        "    for _ in range(1000): pass\n"
        "try:\n"
        "    with interrupts_unwind() as state:\n"
        "        t = Thing()\n"
        "        r = weakref.ref(t, cb if WHERE == 'weakref callback' else None)\n"
        "        del t\n"
        "        deadline = time.monotonic() + 30\n"
        "        while time.monotonic() < deadline: pass\n"
        "        print('not interrupted')\n"
        "except Interrupted as e:\n"
        "    print('interrupted', e.signum, state.signals)\n"
    ).replace("WHERE", repr(where))
    out = run_python(code, timeout=300)
    assert out.returncode == 0, out
    assert out.stdout.strip() == f"interrupted {int(signal.SIGHUP)} [{int(signal.SIGHUP)}]", out
    assert out.stderr == "", out


def test_a_signal_a_library_swallowed_still_publishes_nothing(tmp_path):
    """A library may swallow the interruption (a bare ``except`` around an import: CI saw a replay
    that ran to its end and wrote its outputs after a SIGHUP at start-up): the next output to be
    published raises it instead and its temporary is removed; during the unwinding that follows, the
    clean-up runs (nothing raises again); outside a command's block nothing is checked."""
    from replay.outputs import AtomicOutput
    from replay.process import interrupts_unwind, raise_if_interrupted

    target = tmp_path / "out.bin"
    raise_if_interrupted()  # no block: nothing
    with pytest.raises(Interrupted) as caught:
        with interrupts_unwind() as state:
            try:
                signal.raise_signal(signal.SIGHUP)
            except BaseException:  # noqa: BLE001,S110 - the library that swallows it
                pass
            assert state.signals == [signal.SIGHUP]
            out = AtomicOutput(target)
            out.temp.write_bytes(b"x")
            try:
                out.commit()
            finally:
                raise_if_interrupted()  # unwinding: the clean-up is not interrupted again
    assert caught.value.signum == signal.SIGHUP
    assert list(tmp_path.iterdir()) == []
    with interrupts_unwind():  # no signal: publishes
        out = AtomicOutput(target)
        out.temp.write_bytes(b"x")
        out.commit()
    assert target.read_bytes() == b"x"


def test_a_signal_inside_a_deferred_block_raises_when_the_block_ends():
    """``interrupts_deferred``: the block finishes, then Interrupted is raised once; outside a command's
    block it does nothing; an exception of the block itself is not replaced."""
    from replay.process import interrupts_deferred, interrupts_unwind

    steps = []
    with pytest.raises(Interrupted) as caught:
        with interrupts_unwind() as state:
            with interrupts_deferred():
                with interrupts_deferred():  # nested: the outer end raises
                    signal.raise_signal(signal.SIGHUP)
                    for _ in range(1000):  # the handler runs here and must not raise
                        pass
                    steps.append("inner done")
                steps.append("outer done")
            steps.append("after")
    assert steps == ["inner done", "outer done"]
    assert caught.value.signum == signal.SIGHUP and state.signals == [signal.SIGHUP]
    assert not state.pending and state.raised

    with interrupts_deferred():  # no command block: nothing
        steps.append("outside")
    with pytest.raises(ValueError):
        with interrupts_unwind() as state:
            with interrupts_deferred():
                signal.raise_signal(signal.SIGHUP)
                for _ in range(1000):
                    pass
                raise ValueError("the block's own error")
    assert state.signals == [signal.SIGHUP] and interrupted_by(ValueError(), state) == 128 + signal.SIGHUP


def test_a_signal_inside_rerun_s_constructor_leaves_no_traceback():
    """CI: a SIGHUP that landed inside ``rr.RecordingStream.__init__`` (the sink is made before the log
    opens) left a stream without its native half, whose ``__del__`` printed an AttributeError after
    'interrupted (SIGHUP)'. The signal now waits for the constructor: the stream is whole, and nothing
    is printed."""
    code = (
        "import os, signal, gc\n"
        "import rerun as rr\n"
        "from replay.pipeline import viz\n"
        "from replay.process import Interrupted, interrupts_unwind\n"
        "real = rr.RecordingStream.__init__\n"
        "def init(self, *a, **k):\n"
        "    os.kill(os.getpid(), signal.SIGHUP)\n"
        "    for _ in range(1000): pass\n"
        "    real(self, *a, **k)\n"
        "rr.RecordingStream.__init__ = init\n"
        "try:\n"
        "    with interrupts_unwind() as state:\n"
        "        viz.new_recording()\n"
        "        print('not interrupted')\n"
        "except Interrupted as e:\n"
        "    print('interrupted', e.signum)\n"
        "gc.collect()\n"
    )
    out = run_python(code, timeout=300)
    assert out.returncode == 0, out
    assert out.stdout.strip() == f"interrupted {int(signal.SIGHUP)}", out
    assert "Exception ignored" not in out.stderr and "Traceback" not in out.stderr, out.stderr


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_a_signal_while_an_output_makes_its_temporary_leaves_nothing_locked(tmp_path, monkeypatch, sig):
    """A signal that lands just after the temporary file was made (its handler runs when ``os.open``
    returns): the temporary and its lock are made whole first, then the interruption is raised and the
    temporary removed. It used to be left behind with its lock held by this process's open descriptor,
    so no clean-up of the same process could remove it (a batch's parts folder kept one after SIGTERM)."""
    import os as os_module

    import replay.outputs as outputs
    from replay.process import interrupts_unwind

    real_open = os_module.open
    made: list[int] = []

    def open_then_signal(path, flags, *args):  # type: ignore[no-untyped-def]
        fd = real_open(path, flags, *args)
        if ".partial" in str(path):
            made.append(fd)
            signal.raise_signal(sig)  # the handler runs here, before the caller has the descriptor
        return fd

    monkeypatch.setattr(outputs.os, "open", open_then_signal)
    with pytest.raises(Interrupted) as caught:
        with interrupts_unwind():
            outputs.AtomicOutput(tmp_path / "part.parquet")
    monkeypatch.undo()
    assert caught.value.signum == sig and len(made) == 1
    assert list(tmp_path.iterdir()) == []  # no temporary left
    with pytest.raises(OSError):
        os_module.fstat(made[0])  # and its descriptor (which held the lock) closed
    assert outputs.remove_stale_temporaries_in(tmp_path) == []
