"""What the labelling-page benchmarks share: the server they start and the waits they need."""

from __future__ import annotations

import contextlib
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path


def start_server(log: Path, db: Path, *extra: str, quiet: bool = False) -> tuple[subprocess.Popen, str, str]:
    """``zcut annotate LOG`` on a free port as annotator "bench" (``extra``: more options, e.g. ``--bin-model``);
    returns (process, base URL, token). ``quiet``: its notes on stderr are dropped."""
    cmd = [sys.executable, "-m", "cli", "annotate", str(log), "--db", str(db), "--port", "0", "--no-browser",
           "--annotator", "bench", *map(str, extra)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL if quiet else None, text=True)
    for line in proc.stdout:
        m = re.match(r"(http://127\.0\.0\.1:\d+)/\?token=(\S+)", line.strip())
        if m:
            return proc, m.group(1), m.group(2)
    raise SystemExit(f"server did not start (exit {proc.wait()})")


@contextlib.contextmanager
def serving(log: Path, db: Path, *extra: str, quiet: bool = False) -> Iterator[tuple[str, str]]:
    """:func:`start_server` for the ``with`` block: (base URL, token); the server is stopped on leaving."""
    proc, base, token = start_server(log, db, *extra, quiet=quiet)
    try:
        yield base, token
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def get_bundle(base: str, token: str, index: int, what: str = "bundle") -> tuple[dict, dict]:
    """(header, arrays) of frame ``index``'s ``/api/frames/{index}/{what}`` (``bundle`` or ``label``), as the page reads it."""
    import httpx

    from annotate.payload import parse_bundle

    r = httpx.get(f"{base}/api/frames/{index}/{what}", headers={"X-Zcut-Token": token}, timeout=60)
    r.raise_for_status()
    return parse_bundle(r.content)


def synthetic_bin_model(work: Path) -> Path:
    """``work/bin.ply``: the bin model of a 5-scan synthetic empty-bin log at 1200 x 1920 (built once, then reused)."""
    from replay.logs.reader import LogReader
    from replay.pipeline.bin_model import build_bin_model, save_bin_model
    from replay.synth.log import write_synthetic_log

    work.mkdir(parents=True, exist_ok=True)
    ply = work / "bin.ply"
    if not ply.exists():
        empty = work / "empty.mcap"
        if not empty.exists():
            write_synthetic_log(empty, empty=True, frames=5, seed=0, size=(1200, 1920))
        model, _ = build_bin_model(LogReader(empty).frames())
        save_bin_model(model, ply)
    return ply


def synthetic_log(work: Path, kind: str, seed: int, frames: int) -> Path:
    """``work/KIND_sSEED_fFRAMES.mcap``: a synthetic 1200 x 1920 log (written once, then reused)."""
    from replay.synth.log import write_synthetic_log

    log = work / f"{kind}_s{seed}_f{frames}.mcap"
    if not log.exists():
        print(f"synthesising {log.name}", flush=True)
        write_synthetic_log(log, kind=kind, frames=frames, seed=seed, size=(1200, 1920))
    return log


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


def open_page(browser, base: str, token: str, viewport: tuple[int, int], errors: list[str] | None = None):
    """A page in a context of its own (``viewport``: width, height) on the server at ``base``, local requests
    only (the tests' ``local_only``), once it is ready: (page, the blocked requests). ``errors``: the page's
    errors are appended to it."""
    from annotate_helpers import local_only

    page = browser.new_context(viewport={"width": viewport[0], "height": viewport[1]}).new_page()
    blocked = local_only(page)
    if errors is not None:
        page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(f"{base}/?token={token}")
    wait_until(page, "window.zcut && window.zcut.ready === true")
    return page, blocked


def wait_until(page, expr: str, *, timeout_s: float = 120.0) -> None:
    """Poll a JS expression (the page's CSP forbids the eval behind Playwright's own waiting)."""
    deadline = time.monotonic() + timeout_s
    while not page.evaluate(f"(() => {{ try {{ return !!({expr}); }} catch (e) {{ return false; }} }})()"):
        if time.monotonic() > deadline:
            raise SystemExit(f"timed out waiting for {expr}")
        page.wait_for_timeout(5)
