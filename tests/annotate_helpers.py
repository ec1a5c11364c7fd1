"""Small real logs and a real server process for the annotate tests."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from replay.logs import layout
from replay.logs.frame import Frame
from replay.logs.writer import LogWriter
from zcut.cloud import Intrinsics


def spike_frame(index: int, *, shape=(120, 160), seed=0, n_spikes=4) -> tuple[Frame, np.ndarray]:
    """A flat floor 1 m below the camera with square spikes (true outliers) and a few invalid pixels.

    Returns the frame (truth on ``/ground_truth/outliers``) and the truth mask.
    """
    rng = np.random.default_rng(seed + index)
    h, w = shape
    fx = fy = 0.8 * w
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    z = np.full((h, w), 1.0)
    z += 0.0002 * rng.standard_normal((h, w))
    truth = np.zeros((h, w), bool)
    for k in range(n_spikes):
        s = int(rng.integers(3, 7))
        r = int(rng.integers(5, h - s - 5))
        c = int(rng.integers(5 + k * (w - 10) // n_spikes, 5 + (k + 1) * (w - 10) // n_spikes - s))
        z[r:r + s, c:c + s] = 1.0 - 0.05 - 0.01 * k  # 50-80 mm above the floor: a flying cluster
        truth[r:r + s, c:c + s] = True
    xyz = np.stack([(xx - w / 2) * z / fx, (yy - h / 2) * z / fy, z], axis=2).astype(np.float32)
    invalid = rng.random((h, w)) < 0.01
    invalid &= ~truth
    xyz[invalid] = np.nan
    rgb = np.zeros((h, w, 3), np.uint8)
    rgb[...] = (90, 110, 130)
    rgb[truth] = (230, 230, 60)
    frame = Frame(xyz=xyz, rgb=rgb, stamp_ns=1_000_000_000 + index * 100_000_000, frame_id="cam",
                  intrinsics=Intrinsics(fx=fx, fy=fy, cx=w / 2, cy=h / 2, width=w, height=h),
                  topic=layout.CLOUD, index=index, masks={layout.TRUTH_OUTLIERS: truth})
    return frame, truth


def write_spike_log(path: Path, *, frames=3, shape=(120, 160), seed=0) -> list[np.ndarray]:
    """Write a small MCAP log of :func:`spike_frame` frames; returns the truth masks."""
    truths = []
    with LogWriter(path) as w:
        for i in range(frames):
            fr, t = spike_frame(i, shape=shape, seed=seed)
            w.write_frame(fr)
            truths.append(t)
    return truths


class ServerProcess:
    """``zcut annotate LOG --no-browser`` in a subprocess on a free port; ``url``, ``token``, ``base``."""

    def __init__(self, log: Path, db: Path, *, annotator: str = "tester", extra=()) -> None:
        cmd = [sys.executable, "-m", "replay.cli", "annotate", str(log), "--db", str(db), "--port", "0",
               "--no-browser", "--annotator", annotator, *extra]
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        self.url = None
        deadline = time.monotonic() + 60
        lines = []
        while time.monotonic() < deadline:
            line = self.proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            m = re.match(r"(http://127\.0\.0\.1:(\d+))/\?token=(\S+)", line.strip())
            if m:
                self.base, self.port, self.token = m.group(1), int(m.group(2)), m.group(3)
                self.url = line.strip()
                break
        if self.url is None:
            self.kill()
            raise RuntimeError(f"server did not start: {''.join(lines)} {self.proc.stderr.read()}")
        self._wait_ready()

    def _wait_ready(self, timeout=120.0) -> None:
        import httpx

        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                r = httpx.get(f"{self.base}/api/session", headers={"X-Zcut-Token": self.token}, timeout=5)
                if r.status_code == 200 and r.json()["done"]:
                    return
            except httpx.TransportError:
                pass
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited: {self.proc.stderr.read()}")
            time.sleep(0.1)
        raise RuntimeError("server did not finish preparing frames")

    def headers(self) -> dict[str, str]:
        return {"X-Zcut-Token": self.token}

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(timeout=30)
        for s in (self.proc.stdout, self.proc.stderr):
            if s:
                s.close()

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                pass
        self.kill()
