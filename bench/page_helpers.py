"""What the labelling-page benchmarks share: the server they start and the waits they need."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path


def start_server(log: Path, db: Path) -> tuple[subprocess.Popen, str, str]:
    cmd = [sys.executable, "-m", "cli", "annotate", str(log), "--db", str(db), "--port", "0", "--no-browser",
           "--annotator", "bench"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    for line in proc.stdout:
        m = re.match(r"(http://127\.0\.0\.1:\d+)/\?token=(\S+)", line.strip())
        if m:
            return proc, m.group(1), m.group(2)
    raise SystemExit(f"server did not start (exit {proc.wait()})")


def wait_prepared(base: str, token: str) -> float:
    import httpx

    t0 = time.perf_counter()
    while True:
        try:
            j = httpx.get(f"{base}/api/session", headers={"X-Zcut-Token": token}, timeout=10).json()
            if j["done"]:
                if j["error"]:
                    raise SystemExit(f"preparing frames failed: {j['error']}")
                return time.perf_counter() - t0
        except httpx.TransportError:
            pass
        time.sleep(0.5)


def wait_until(page, expr: str, *, timeout_s: float = 120.0) -> None:
    """Poll a JS expression (the page's CSP forbids the eval behind Playwright's own waiting)."""
    deadline = time.monotonic() + timeout_s
    while not page.evaluate(f"(() => {{ try {{ return !!({expr}); }} catch (e) {{ return false; }} }})()"):
        if time.monotonic() > deadline:
            raise SystemExit(f"timed out waiting for {expr}")
        page.wait_for_timeout(5)
