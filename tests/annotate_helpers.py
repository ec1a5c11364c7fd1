"""Small real logs and a real server process for the annotate tests."""

from __future__ import annotations

import contextlib
import os
import re
import subprocess
import sys
import threading
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


#: (rows, cols) of the 13 floating clusters of :func:`review_frame`: twelve of at most 4 pixels, one of 20.
REVIEW_CLUSTERS = [(1, 1), (1, 1), (1, 2), (2, 1), (1, 2), (2, 2), (1, 3), (2, 2), (1, 1), (2, 2), (1, 2), (2, 2), (4, 5)]


def review_frame(index: int = 0, *, shape=(1200, 1920), seed: int = 5) -> tuple[Frame, np.ndarray]:
    """A bin-like scan to review by hand: a smooth floor 1 m below the camera with three rounded parts
    on it and 13 small floating clusters (:data:`REVIEW_CLUSTERS`, 4 to 16 mm above the surface), spread
    over the frame so that at the overview zoom each covers at most a few screen pixels.

    Returns the frame (no truth topic) and the (H, W) truth mask of the floating clusters.
    """
    rng = np.random.default_rng(seed + index)
    h, w = shape
    fx = fy = 0.8 * w
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    z = 1.0 + 0.00002 * (xx - w / 2) / 10 + 0.00002 * rng.standard_normal((h, w))
    for cy, cx, r in ((0.3, 0.25, 0.12), (0.65, 0.6, 0.15), (0.35, 0.75, 0.1)):  # parts: spherical caps
        d2 = ((yy - cy * h) ** 2 + (xx - cx * w) ** 2) / (r * w) ** 2
        z -= np.where(d2 < 1, 0.008 * np.sqrt(np.clip(1 - d2, 0, 1)), 0)
    truth = np.zeros((h, w), bool)
    cells = rng.permutation(24)[:len(REVIEW_CLUSTERS)]  # one cluster per cell of a 4 x 6 grid
    for k, ((sh, sw), cell) in enumerate(zip(REVIEW_CLUSTERS, cells)):
        r = int((cell // 6 + rng.uniform(0.2, 0.8)) * h / 4)
        c = int((cell % 6 + rng.uniform(0.2, 0.8)) * w / 6)
        z[r:r + sh, c:c + sw] = z[r - 3:r + sh + 3, c - 3:c + sw + 3].min() - 0.004 - 0.001 * k
        truth[r:r + sh, c:c + sw] = True
    xyz = np.stack([(xx - w / 2) * z / fx, (yy - h / 2) * z / fy, z], axis=2).astype(np.float32)
    shade = np.clip(255 * (1.03 - z) / 0.05, 0, 255)
    rgb = np.stack([0.5 * shade + 60, 0.55 * shade + 60, 0.6 * shade + 70], axis=2)
    rgb += rng.normal(0, 4, rgb.shape)
    rgb = np.clip(rgb, 0, 255).astype(np.uint8)
    frame = Frame(xyz=xyz, rgb=rgb, stamp_ns=2_000_000_000 + index * 100_000_000, frame_id="cam",
                  intrinsics=Intrinsics(fx=fx, fy=fy, cx=w / 2, cy=h / 2, width=w, height=h),
                  topic=layout.CLOUD, index=index, masks={})
    return frame, truth


def write_review_log(path: Path, *, frames=2, shape=(1200, 1920)) -> list[np.ndarray]:
    """Write a log of :func:`review_frame` frames; returns the truth masks."""
    truths = []
    with LogWriter(path) as wr:
        for i in range(frames):
            fr, t = review_frame(i, shape=shape)
            wr.write_frame(fr)
            truths.append(t)
    return truths


def write_spike_log(path: Path, *, frames=3, shape=(120, 160), seed=0) -> list[np.ndarray]:
    """Write a small MCAP log of :func:`spike_frame` frames; returns the truth masks."""
    truths = []
    with LogWriter(path) as w:
        for i in range(frames):
            fr, t = spike_frame(i, shape=shape, seed=seed)
            w.write_frame(fr)
            truths.append(t)
    return truths


def added_frames(store, rec, log: Path):
    """Add every frame of ``log`` to ``store`` under the log record ``rec``, yielding (frame record, frame,
    valid mask) as each is added (a caller labels a frame before the next is added)."""
    from replay.logs.reader import LogReader

    for f in LogReader(log).frames():
        valid = np.isfinite(f.xyz).all(axis=2)
        yield store.add_frame(rec, topic=f.topic, stamp_ns=f.stamp_ns, index=f.index, shape=f.shape,
                              frame_id=f.frame_id, valid=valid), f, valid


def label_with_truth(store, log: Path, *, annotator: str = "ann"):
    """``log`` added to ``store`` and each frame labelled by ``annotator`` with its ground-truth outliers
    (every valid pixel reviewed): (the log's record, [(frame record, valid mask)])."""
    rec = store.add_log(log)
    frames = []
    for fr, f, valid in added_frames(store, rec, log):
        store.save_label(fr, annotator=annotator, outliers=f.masks["/ground_truth/outliers"] & valid,
                         reviewed=valid, base_revision=0)
        frames.append((fr, valid))
    return rec, frames


def label_groups(store, log: Path, *, coin=None, skip=(3,)) -> list[tuple[int, int]]:
    """The frames of ``log`` but ``skip`` labelled by "alice", a person who takes the review groups of
    >= 20 px (or, with ``coin`` (a numpy Generator), each group at even odds): per labelled frame,
    (groups taken, groups listed). (20, not 16 since the suspects' ``patch`` detector: it lists the spike logs' 16 px
    groups beside 36 px ones, and a person who took every group would teach a model nothing.)"""
    from annotate.groups import GCOL
    from annotate.payload import parse_bundle, prepare_frame
    from replay.pipeline.session import ReplaySession

    taken = []
    results = ReplaySession.open(log).results()
    rec = store.add_log(log)
    try:
        for frame, r in results:
            if frame.index in skip:
                continue
            header, a = parse_bundle(prepare_frame(frame, r).served.bundle)
            gids, valid = a["groups"].astype(np.int64), a["valid"]
            t = a["group_table"]
            take = t[:, GCOL["n"]] >= 20 if coin is None else coin.random(len(t)) < 0.5
            out = t[take, GCOL["id"]]
            taken.append((int(out.size), int(header["n_groups"])))
            fr = store.add_frame(rec, topic=frame.topic, stamp_ns=frame.stamp_ns, index=frame.index,
                                 shape=valid.shape, valid=valid)
            store.save_label(fr, annotator="alice", outliers=np.isin(gids, out) & valid, reviewed=valid,
                             base_revision=None)
    finally:
        results.close()
    return taken


def pipeline_result(frame: Frame):
    """The pipeline's result for one frame, as ``zcut annotate`` computes it (no config file, no bin
    model): the frame written alone to a log, opened with ``ReplaySession.open`` and run; what
    :func:`annotate.payload.prepare_frame` takes."""
    import tempfile

    from replay.pipeline.session import ReplaySession

    with tempfile.TemporaryDirectory(prefix="zcut-frame-") as d:
        log = Path(d) / "frame.mcap"
        with LogWriter(log) as w:
            w.write_frame(frame)
        results = ReplaySession.open(log).results()
        try:
            (_, result), = list(results)
        finally:
            results.close()
    return result


def status_line(sock) -> bytes:
    """First line of the server's answer on a raw socket (empty if it closed without one)."""
    got = b""
    while b"\r\n" not in got:
        part = sock.recv(4096)
        if not part:
            break
        got += part
    return got.split(b"\r\n", 1)[0]


@contextlib.contextmanager
def page_client(base: str, token: str, **kw):
    """An httpx client with the page-session cookie of ``GET /?token=`` and this server's Origin."""
    import httpx

    with httpx.Client(base_url=base, headers={"Origin": base}, timeout=kw.pop("timeout", 60), **kw) as c:
        r = c.get("/", params={"token": token})
        assert r.status_code == 200 and "set-cookie" in r.headers, r.text
        yield c


class LiveServer:
    """``annotate.server.make_server`` for a page, in a thread of this process, on a free port of
    127.0.0.1 (``base``): for a gated catalogue or short timeouts. :meth:`stop` also closes the page."""

    def __init__(self, page, **server_kw) -> None:
        import socket
        import threading

        from annotate.server import make_server

        self.page = page
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.base = f"http://127.0.0.1:{self.port}"
        self.token = page.token
        self.server = make_server(page, **server_kw)
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]}, daemon=True)
        self.thread.start()
        deadline = time.monotonic() + 30
        while not self.server.started:
            if time.monotonic() > deadline or not self.thread.is_alive():
                raise RuntimeError("in-process server did not start")
            time.sleep(0.01)

    def headers(self) -> dict[str, str]:
        return {"X-Zcut-Token": self.token}

    def stop(self) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=30)
        self.sock.close()
        self.page.close()


class ServerProcess:
    """``zcut annotate LOG --no-browser`` in a subprocess on a free port; ``url``, ``token``, ``base``."""

    def __init__(self, log: Path, db: Path, *, annotator: str | None = "tester", extra=()) -> None:
        who = [] if annotator is None else ["--annotator", annotator]
        cmd = [sys.executable, "-m", "cli", "annotate", str(log), "--db", str(db), "--port", "0",
               "--no-browser", *who, *extra]
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        self.stderr_lines: list[str] = []  # drained by a thread: a full pipe would stall the server
        self._drain = threading.Thread(target=lambda: self.stderr_lines.extend(self.proc.stderr), daemon=True)
        self._drain.start()
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
            raise RuntimeError(f"server did not start: {''.join(lines)} {''.join(self.stderr_lines)}")
        try:
            self._wait_ready()
        except BaseException:  # a server that never got ready is not left running (it outlived a failed test)
            self.kill()
            raise

    def _wait_ready(self, timeout=300.0) -> None:  # generous: a loaded machine prepares slowly
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
                self._drain.join(timeout=10)
                raise RuntimeError(f"server exited: {''.join(self.stderr_lines)}")
            time.sleep(0.1)
        raise RuntimeError("server did not finish preparing frames")

    def headers(self) -> dict[str, str]:
        return {"X-Zcut-Token": self.token}

    def page_client(self, **kw):
        """An httpx client that behaves like the page: it opened the URL (the token became a cookie) and
        names this server as the Origin of its writes."""
        return page_client(self.base, self.token, **kw)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(timeout=30)
        self._drain.join(timeout=10)
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


# --------------------------------------------------------------------------- the browser
from browser_helpers import CHROMIUM, CHROMIUM_ARGS  # noqa: E402,F401 (re-exported)


def wait_until(page, expr: str, *, timeout_s: float = 60.0) -> None:
    """Poll a JS expression with page.evaluate: the page's CSP forbids the eval that Playwright's
    waiting helper needs, and the tests run under the page's real CSP."""
    deadline = time.monotonic() + timeout_s
    while not page.evaluate(f"(() => {{ try {{ return !!({expr}); }} catch (e) {{ return false; }} }})()"):
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {expr}")
        page.wait_for_timeout(20)


def local_only(page) -> list[str]:
    """Abort every request of the page (and its workers) that is not to 127.0.0.1; returns the list
    the aborted URLs are appended to (the page must need none)."""
    from urllib.parse import urlparse

    blocked: list[str] = []

    def route(r):
        if r.request.url.startswith(("data:", "blob:")) or urlparse(r.request.url).hostname == "127.0.0.1":
            r.continue_()
        else:
            blocked.append(r.request.url)
            r.abort()

    page.context.route("**/*", route)
    return blocked


def open_page(browser, url: str, *, viewport=(1280, 800), ready: bool = True):
    """A new page (own context: own cookies) on ``url``, local requests only; waits for the page to be
    ready. Returns (page, errors, blocked)."""
    ctx = browser.new_context(viewport={"width": viewport[0], "height": viewport[1]})
    page = ctx.new_page()
    blocked = local_only(page)
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url)
    if ready:
        wait_until(page, "window.zcut && window.zcut.ready === true")
    return page, errors, blocked


def close_page(page) -> None:
    ctx = page.context
    page.close()
    ctx.close()


def _content_digest(x, h, seen: set[int]) -> None:
    """Feed ``x``'s content into the hash ``h``: arrays by dtype, shape and bytes, dataclasses, mappings and
    sequences field by field, scalars by their repr, a KD-tree by its points and leaf size. Anything else is
    refused (a key must never fall back on an object's identity)."""
    import dataclasses
    import enum
    from collections.abc import Mapping

    from scipy.spatial import cKDTree

    if isinstance(x, np.ndarray):
        a = np.ascontiguousarray(x)
        h.update(f"a{a.dtype}{a.shape}".encode())
        h.update(a.tobytes() if a.dtype != object else repr(a.tolist()).encode())
    elif x is None or isinstance(x, (bool, int, float, complex, str, bytes, np.generic, enum.Enum, Path)):
        h.update(f"s{type(x).__name__}:{x!r}".encode())
    elif isinstance(x, cKDTree):
        h.update(f"kd{x.leafsize}".encode())
        _content_digest(np.asarray(x.data), h, seen)
    elif id(x) in seen:
        h.update(b"again")
    elif dataclasses.is_dataclass(x) and not isinstance(x, type):
        seen.add(id(x))
        h.update(f"d{type(x).__qualname__}".encode())
        for f in dataclasses.fields(x):
            h.update(f.name.encode())
            _content_digest(getattr(x, f.name), h, seen)
    elif isinstance(x, Mapping):  # a dict, the config's bank
        seen.add(id(x))
        h.update(f"m{len(x)}".encode())
        for k in sorted(x, key=repr):
            _content_digest(k, h, seen)
            _content_digest(x[k], h, seen)
    elif isinstance(x, (list, tuple, frozenset, set)):
        seen.add(id(x))
        h.update(f"l{type(x).__name__}{len(x)}".encode())
        for v in (sorted(x, key=repr) if isinstance(x, (set, frozenset)) else x):
            _content_digest(v, h, seen)
    else:
        raise TypeError(f"no content key for a {type(x).__qualname__}")


def fits_once(monkeypatch, memo: dict) -> None:
    """``annotate.fits.fit_frame`` (a page server's background fits of a frame: ``explained`` with the sliver pass,
    most of a fitted page's time) computed once per distinct call in ``memo`` while ``monkeypatch`` holds: the
    servers of one test module each fitted the same frame of the same log anew. The key is the content of every
    argument (the frame's points and fields, the pipeline's result the fits start from: valid pixels, zone, the
    removal and the registration to the last bit, the config, the bin model), so a call whose inputs differ in
    any bit computes its own fits; an equal call gets a deep copy of the fits the first one made, which is what
    the deterministic fits give again (tests/zcut/fits/ hold them to their digests; the page tests that restart a
    server rely on it). A fit stopped under way (``zcut.cancel``) raises as before and keeps nothing."""
    import copy
    import hashlib

    import annotate.fits as fits

    real = fits.fit_frame

    def fit_frame(frame, job, config, bin_model):
        h = hashlib.sha256()
        _content_digest((frame, job, config, bin_model), h, set())
        key = h.hexdigest()
        if key not in memo:
            memo[key] = real(frame, job, config, bin_model)
        return copy.deepcopy(memo[key])

    monkeypatch.setattr(fits, "fit_frame", fit_frame)
