"""The labelling server run for real (``zcut annotate`` in a subprocess on 127.0.0.1), spoken to over HTTP."""

from __future__ import annotations

import base64
import json
import signal
import socket
import threading
import zlib

import httpx
import numpy as np
import pytest
from annotate_helpers import ServerProcess, status_line, write_spike_log

from annotate.guard import MAX_BODY_BYTES
from annotate.payload import mask_runs, parse_bundle, parse_view
from annotate.store import LabelStore, file_sha256, pack_mask
from replay.logs.reader import LogReader

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    d = tmp_path_factory.mktemp("served")
    log = d / "scan.mcap"
    truths = write_spike_log(log, frames=3)
    srv = ServerProcess(log, d / "labels.sqlite", annotator="alice")
    yield srv, log, d / "labels.sqlite", truths
    srv.stop()


def _b64(mask):
    return base64.b64encode(pack_mask(mask)).decode()


def _body(mask_l, mask_r, *, base=0):
    h, w = mask_l.shape
    return {"base_revision": base, "height": h, "width": w, "outliers": _b64(mask_l), "reviewed": _b64(mask_r)}


def _valid(srv, index):
    r = httpx.get(f"{srv.base}/api/frames/{index}/bundle", headers=srv.headers())
    assert r.status_code == 200
    return parse_bundle(r.content)


def _label_count(db):
    with LabelStore(db) as s:
        return s.label_count()


@pytest.mark.parametrize("path", ["/", "/static/app.js", "/static/view3d.js", "/api/session", "/api/frames",
                                  "/api/frames/0/bundle", "/api/frames/0/image/rgb", "/api/frames/0/label",
                                  "/api/frames/0/view", "/api/frames/0/geometry?x0=0&y0=0&x1=8&y1=8"])
def test_every_request_needs_the_token(served, path):
    """The token in the header (scripts) or the page session's cookie; in the URL only for the page."""
    srv = served[0]
    assert httpx.get(srv.base + path).status_code == 403
    assert httpx.get(srv.base + path, params={"token": "wrong"}).status_code == 403
    assert httpx.get(srv.base + path, headers={"X-Zcut-Token": srv.token[:-1]}).status_code == 403
    assert httpx.get(srv.base + path, headers={"Cookie": "zcut-0123456789abcdef=made-up"}).status_code == 403
    assert httpx.get(srv.base + path, headers=srv.headers()).status_code == 200
    with srv.page_client() as c:
        assert c.get(path).status_code == 200
    in_url = httpx.get(srv.base + path + ("&" if "?" in path else "?") + f"token={srv.token}")
    assert in_url.status_code == (200 if path == "/" else 403)


def test_put_without_token_is_refused_and_stores_nothing(served):
    srv, _, db, _ = served
    before = _label_count(db)
    m = np.zeros((120, 160), bool)
    r = httpx.put(f"{srv.base}/api/frames/0/label", json=_body(m, m))
    assert r.status_code == 403
    assert _label_count(db) == before


def test_page_and_frames(served):
    srv, log, _, _ = served
    r = httpx.get(srv.url)
    assert r.status_code == 200 and "zcut annotate" in r.text and srv.token not in r.text
    assert "default-src 'self'" in r.headers["content-security-policy"] and r.headers["x-frame-options"] == "DENY"
    j = httpx.get(f"{srv.base}/api/frames", headers=srv.headers()).json()
    assert j["total"] == 3 and j["done"] and [f["index"] for f in j["frames"]] == [0, 1, 2]
    frames = list(LogReader(log).frames())
    for fr in frames:
        header, arrays = _valid(srv, fr.index)
        assert header["stamp_ns"] == fr.stamp_ns and (header["height"], header["width"]) == fr.shape
        assert np.array_equal(arrays["valid"], np.isfinite(fr.xyz).all(axis=2))
        # candidates are valid pixels only, and the flying spikes are among the z-cut's
        assert not (arrays["zcut"].astype(bool) & ~arrays["valid"]).any()
        assert (arrays["zcut"] > 0).sum() > 0
    img = httpx.get(f"{srv.base}/api/frames/0/image/height", headers=srv.headers())
    assert img.headers["content-type"] == "image/jpeg" and img.content[:2] == b"\xff\xd8"
    assert httpx.get(f"{srv.base}/api/frames/9/bundle", headers=srv.headers()).status_code == 404
    assert httpx.get(f"{srv.base}/static/../server.py", headers=srv.headers()).status_code == 404


def test_view_is_bundle_label_and_image_in_one(served):
    srv = served[0]
    for kind in ("rgb", "height"):
        r = httpx.get(f"{srv.base}/api/frames/2/view", params={"image": kind}, headers=srv.headers())
        assert r.status_code == 200 and r.headers["content-type"] == "application/octet-stream"
        parts = parse_view(r.content)
        assert sorted(parts) == ["bundle", "image", "label"]
        assert parts["bundle"] == httpx.get(f"{srv.base}/api/frames/2/bundle", headers=srv.headers()).content
        assert parts["image"] == httpx.get(f"{srv.base}/api/frames/2/image/{kind}", headers=srv.headers()).content
        label = httpx.get(f"{srv.base}/api/frames/2/label", headers=srv.headers())
        assert parts["label"] == label.content
    bare = parse_view(httpx.get(f"{srv.base}/api/frames/2/view", params={"image": "none"}, headers=srv.headers()).content)
    assert sorted(bare) == ["bundle", "label"]
    bad = httpx.get(f"{srv.base}/api/frames/2/view", params={"image": "../x"}, headers=srv.headers())
    assert bad.status_code == 400
    assert httpx.get(f"{srv.base}/api/frames/9/view", headers=srv.headers()).status_code == 404
    # the annotator comes from the server, never from the request
    other = httpx.get(f"{srv.base}/api/frames/2/view", params={"annotator": "mallory"}, headers=srv.headers())
    assert parse_bundle(parse_view(other.content)["label"])[0]["annotator"] == "alice"


def test_save_reload_and_conflict(served):
    srv, log, db, truths = served
    _, arrays = _valid(srv, 1)
    valid = arrays["valid"]
    L = truths[1] & valid
    r = httpx.put(f"{srv.base}/api/frames/1/label", json=_body(L, valid), headers=srv.headers())
    assert r.status_code == 200, r.text
    rev = r.json()["revision"]
    assert rev == 1
    # stored and served back
    got = httpx.get(f"{srv.base}/api/frames/1/label", headers=srv.headers())
    header, back = parse_bundle(got.content)
    assert header["revision"] == 1 and np.array_equal(back["outliers"], L) and np.array_equal(back["reviewed"], valid)
    with LabelStore(db) as s:
        lg = s.log_by_sha(file_sha256(log))
        fr = s.frames(lg)[1]
        assert np.array_equal(s.label(fr, annotator="alice").outliers, L)
    # a second edit on a stale base is a conflict, nothing stored
    before = _label_count(db)
    r = httpx.put(f"{srv.base}/api/frames/1/label", json=_body(L & False, valid, base=0), headers=srv.headers())
    assert r.status_code == 409 and r.json()["latest"] == 1
    assert _label_count(db) == before
    frames = httpx.get(f"{srv.base}/api/frames", headers=srv.headers()).json()
    assert frames["reviewed"] >= 1 and frames["frames"][1]["revision"] == 1


def _raw_put(srv, body: bytes, *, content_type="application/json", extra_headers=()):
    h = {"X-Zcut-Token": srv.token, "Content-Type": content_type, **dict(extra_headers)}
    return httpx.put(f"{srv.base}/api/frames/0/label", content=body, headers=h, timeout=30)


def test_malformed_payloads_are_4xx_and_store_nothing(served):
    srv, _, db, _ = served
    _, arrays = _valid(srv, 0)
    valid = arrays["valid"]
    h, w = valid.shape
    good = _body(valid & False, valid)
    runs = {k: v for k, v in good.items() if k not in ("outliers", "reviewed")}
    u32 = lambda *a: base64.b64encode(np.array(a, "<u4").tobytes()).decode()
    cases = [
        (b"{not json", 400),
        (json.dumps([1, 2]).encode(), 422),
        (json.dumps({**good, "outliers": "!!!notbase64"}).encode(), 422),
        (json.dumps({**good, "outliers": base64.b64encode(b"zzz").decode()}).encode(), 422),
        (json.dumps({**good, "outliers": base64.b64encode(zlib.compress(b"\xff" * 10)).decode()}).encode(), 422),
        (json.dumps({**good, "height": h + 1}).encode(), 422),
        (json.dumps({**good, "annotator": ""}).encode(), 403),        # never from the body
        (json.dumps({**good, "annotator": "mallory"}).encode(), 403),
        (json.dumps({**good, "annotator": 5}).encode(), 403),
        (json.dumps({**good, "client": "x"}).encode(), 422),
        (json.dumps({**good, "client": "tab-00000001", "seq": -1}).encode(), 422),
        (json.dumps({**good, "base_revision": 10 ** 30}).encode(), 422),
        (json.dumps({**runs, "outliers_runs": u32(h * w), "unreviewed_runs": u32(h * w - 1)}).encode(), 422),
        (json.dumps({**runs, "outliers_runs": u32(h * w)[:-4] + "AAA=", "unreviewed_runs": u32(h * w)}).encode(), 422),
        (json.dumps({**runs, "outliers_runs": u32(0, h * w), "unreviewed_runs": u32(h * w)}).encode(), 422),  # L ⊄ R
        (json.dumps({**runs, "outliers_runs": u32(h * w), "unreviewed_runs": u32(0, h * w)}).encode(), 422),  # invalid
        (json.dumps({**good, "base_revision": -1}).encode(), 422),
        (json.dumps({**good, "base_revision": "1"}).encode(), 422),
        (json.dumps(_body(valid, valid & False)).encode(), 422),  # L not in R
        (json.dumps(_body(valid & False, np.ones_like(valid))).encode(), 422),  # R not in valid
    ]
    before = _label_count(db)
    for body, status in cases:
        r = _raw_put(srv, body)
        assert r.status_code == status, (body[:80], r.status_code, r.text)
    assert _raw_put(srv, json.dumps(good).encode(), content_type="text/plain").status_code == 415
    # a zip bomb: a small body that inflates far beyond the frame's size
    bomb = base64.b64encode(zlib.compress(b"\x00" * 50_000_000, 9)).decode()
    assert _raw_put(srv, json.dumps({**good, "outliers": bomb}).encode()).status_code == 422
    assert _label_count(db) == before
    # the good bodies are accepted (so the rejections above were about the defects): packed bits, and
    # runs of L and of the valid pixels not reviewed (what the page sends)
    r = _raw_put(srv, json.dumps(good).encode())
    assert r.status_code == 200 and r.json()["annotator"] == "alice"
    L = np.zeros_like(valid)
    L[5:9, 5:9] = valid[5:9, 5:9]
    R = valid.copy()
    R[50:60] = False
    page = {**runs, "base_revision": r.json()["revision"], "outliers_runs": base64.b64encode(
        mask_runs(L).astype("<u4").tobytes()).decode(),
        "unreviewed_runs": base64.b64encode(mask_runs(valid & ~R).astype("<u4").tobytes()).decode()}
    assert _raw_put(srv, json.dumps(page).encode()).json()["n_reviewed"] == int(R.sum())
    assert _label_count(db) == before + 2
    with LabelStore(db) as s:
        lab = s.label(s.frames(s.logs()[0])[0], annotator="alice")
    assert np.array_equal(lab.outliers, L) and np.array_equal(lab.reviewed, R)


def test_oversized_bodies_get_413_before_being_read(served):
    """Raw sockets, so that the client never has unread bytes in flight when the server closes:
    a 413 sent while a client is still uploading can be lost to the TCP reset of the close (as with
    any server that does not linger), which would make this test flaky rather than wrong."""
    srv, _, db, _ = served
    before = _label_count(db)
    head = (f"PUT /api/frames/0/label HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Zcut-Token: {srv.token}\r\n"
            "Content-Type: application/json\r\n")
    # an honest Content-Length over the limit (and a lying, absurd one): 413 from the headers alone
    for length in (MAX_BODY_BYTES + 1, 9 * 1024 * 1024, 999999999999):
        with socket.create_connection(("127.0.0.1", srv.port), timeout=10) as s:
            s.sendall(f"{head}Content-Length: {length}\r\n\r\n".encode())
            assert status_line(s).startswith(b"HTTP/1.1 413"), length
    # no Content-Length (chunked): counted while it streams; one byte over the limit is refused
    with socket.create_connection(("127.0.0.1", srv.port), timeout=10) as s:
        s.sendall(f"{head}Transfer-Encoding: chunked\r\n\r\n".encode())
        piece = b"y" * (1024 * 1024)
        left = MAX_BODY_BYTES + 1
        while left:
            n = min(left, len(piece))
            s.sendall(f"{n:x}\r\n".encode() + piece[:n] + b"\r\n")
            left -= n
        assert status_line(s).startswith(b"HTTP/1.1 413")
    # exactly at the limit is not refused for its size (it is refused as malformed JSON instead)
    body = b"z" * MAX_BODY_BYTES
    r = httpx.put(f"{srv.base}/api/frames/0/label", content=body, timeout=30,
                  headers={"X-Zcut-Token": srv.token, "Content-Type": "application/json"})
    assert r.status_code == 400
    assert _label_count(db) == before


def test_foreign_host_header_is_refused(served):
    srv = served[0]
    r = httpx.get(f"{srv.base}/api/session", headers={**srv.headers(), "Host": "evil.example"})
    assert r.status_code == 400


def test_four_annotators_at_once_lose_nothing(tmp_path):
    """One server, four page sessions that each chose their name (``--ask-annotator``), saving at once."""
    log = tmp_path / "scan.mcap"
    write_spike_log(log, frames=3)
    db = tmp_path / "labels.sqlite"
    srv = ServerProcess(log, db, annotator=None, extra=["--ask-annotator"])
    try:
        _run_four(srv, log, db)
    finally:
        srv.stop()


def _run_four(srv, log, db):
    _, arrays = _valid(srv, 2)
    valid = arrays["valid"]
    rng = np.random.default_rng(4)
    n_edits = 12
    plans = {f"ann{k}": [valid & (rng.random(valid.shape) < 0.05) for _ in range(n_edits)] for k in range(4)}
    acks: dict[str, list[int]] = {a: [] for a in plans}
    errors = []

    def work(annotator):
        with srv.page_client() as c:
            assert c.post("/api/annotator", json={"name": annotator}).json() == {"annotator": annotator}
            base = 0
            for L in plans[annotator]:
                r = c.put("/api/frames/2/label", json=_body(L, valid, base=base))
                if r.status_code != 200:
                    errors.append((annotator, r.status_code, r.text))
                    return
                base = r.json()["revision"]
                acks[annotator].append(base)

    threads = [threading.Thread(target=work, args=(a,)) for a in plans]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    with LabelStore(db) as s:
        lg = s.log_by_sha(file_sha256(log))
        fr = s.frames(lg)[2]
        for a, masks in plans.items():
            assert acks[a] == list(range(1, n_edits + 1))
            assert s.revisions(fr, annotator=a) == acks[a]
            for rev, L in zip(acks[a], masks):
                assert np.array_equal(s.label(fr, annotator=a, revision=rev).outliers, L)


def test_kill_9_during_a_burst_keeps_every_acknowledged_edit(tmp_path):
    log = tmp_path / "scan.mcap"
    write_spike_log(log, frames=2)
    db = tmp_path / "labels.sqlite"
    srv = ServerProcess(log, db, annotator="bob")
    try:
        _, arrays = _valid(srv, 0)
        valid = arrays["valid"]
        rng = np.random.default_rng(9)
        acked: list[tuple[int, np.ndarray]] = []
        stop = threading.Event()

        def burst():
            base = 0
            with httpx.Client(base_url=srv.base, headers=srv.headers(), timeout=10) as c:
                while not stop.is_set():
                    L = valid & (rng.random(valid.shape) < 0.1)
                    try:
                        r = c.put("/api/frames/0/label", json=_body(L, valid, base=base))
                    except httpx.TransportError:
                        return  # the server died mid-request: that edit was never acknowledged
                    if r.status_code == 200:
                        base = r.json()["revision"]
                        acked.append((base, L))

        t = threading.Thread(target=burst)
        t.start()
        while len(acked) < 15 and t.is_alive():
            threading.Event().wait(0.01)
        srv.proc.send_signal(signal.SIGKILL)
        srv.proc.wait(timeout=30)
        stop.set()
        t.join(timeout=30)
    finally:
        srv.kill()
    assert len(acked) >= 15
    with LabelStore(db) as s:
        fr = s.frames(s.log_by_sha(file_sha256(log)))[0]
        revs = s.revisions(fr, annotator="bob")
        for rev, L in acked:
            assert rev in revs
            assert np.array_equal(s.label(fr, annotator="bob", revision=rev).outliers, L)
        assert revs == list(range(1, len(revs) + 1))


def test_annotate_command_errors(tmp_path, capsys):
    from cli.main import main

    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"this is not an mcap file" * 10)
    log = tmp_path / "ok.mcap"
    write_spike_log(log, frames=1, shape=(40, 60))
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen(1)
    try:
        cases = [
            (["annotate", str(tmp_path / "missing.mcap"), "--no-browser"], "no such file"),
            (["annotate", str(junk), "--no-browser", "--db", str(tmp_path / "j.sqlite")], "junk.mcap"),
            (["annotate", str(log), "--no-browser", "--port", "70000"], "--port"),
            (["annotate", str(log), "--no-browser", "--port", str(busy.getsockname()[1])], "cannot listen"),
            (["annotate", str(log), "--no-browser", "--annotator", "\u0430lice"], "mixes scripts"),
            (["annotate", str(log), "--no-browser", "--annotator", ""], "1..64 characters"),
        ]
        for argv, msg in cases:
            assert main(argv) == 1, argv
            assert msg in capsys.readouterr().err
        with pytest.raises(SystemExit):  # one annotator for all, or each page its own: not both
            main(["annotate", str(log), "--no-browser", "--annotator", "bob", "--ask-annotator"])
        assert "not allowed with" in capsys.readouterr().err
    finally:
        busy.close()
    assert not (tmp_path / "j.sqlite").exists()  # nothing created for a log that cannot be read
