"""``zcut replay --spawn`` with something already listening on the viewer's port (issue 35 #14): the
recording streams into it, and the replay says so, naming the address."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cli_helpers import run_cli

from replay.pipeline import viz
from replay.synth.log import write_synthetic_log


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    return write_synthetic_log(tmp_path_factory.mktemp("logs") / "s.mcap", kind="rods", frames=1, seed=3,
                               size=(120, 160))


@pytest.fixture
def running_viewer_server():
    """A real Rerun gRPC server (``rerun --serve-grpc``, what a viewer listens with) on a free port."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    exe = Path(sys.executable).with_name("rerun")
    # the venv's ``rerun`` is a wrapper that starts the real binary as its child: its own process group,
    # stopped whole
    proc = subprocess.Popen([str(exe), "--serve-grpc", "--bind", "127.0.0.1", "--port", str(port)],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while not viz._listening(port):
            assert proc.poll() is None and time.monotonic() < deadline, "rerun --serve-grpc did not listen"
            time.sleep(0.1)
        yield port
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        deadline = time.monotonic() + 10
        while viz._listening(port) and time.monotonic() < deadline:  # the binary is gone too
            time.sleep(0.1)
        assert not viz._listening(port)


def test_spawn_into_a_viewer_already_listening_says_so(log, capsys, monkeypatch, running_viewer_server):
    port = running_viewer_server
    monkeypatch.setattr(viz, "VIEWER_PORT", port)
    rc, _, err = run_cli(capsys, "replay", log, "--spawn")
    assert rc == 0, err
    said = [ln for ln in err.splitlines() if "--spawn" in ln]
    assert said == [f"zcut: --spawn: something already listens on 127.0.0.1:{port} (a Rerun viewer started "
                    "before?): streaming into it, no new viewer started"], err
