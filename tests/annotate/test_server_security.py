"""What the labelling server answers to requests it must refuse: token and cookie, Origin, the
annotator's name, frames not prepared yet, slow clients, malformed requests, a second server."""

from __future__ import annotations

import base64
import json
import socket
import threading
import time

import httpx
import pytest
from annotate_helpers import LiveServer, ServerProcess, page_client, status_line, write_spike_log

from annotate.catalogue import Catalogue, GeometrySpill
from annotate.guard import cookie_name, new_token
from annotate.payload import parse_bundle
from annotate.routes import Page
from annotate.server import open_page
from annotate.store import LabelStore, file_sha256, pack_mask
from replay.pipeline.session import ReplaySession

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    d = tmp_path_factory.mktemp("security")
    log = d / "scan.mcap"
    write_spike_log(log, frames=2)
    srv = ServerProcess(log, d / "labels.sqlite", annotator="alice")
    yield srv, log, d / "labels.sqlite"
    srv.stop()


def _valid(srv, index=0):
    return parse_bundle(httpx.get(f"{srv.base}/api/frames/{index}/bundle", headers=srv.headers()).content)[1]["valid"]


def _body(valid, **extra):
    return {"base_revision": 0, "height": valid.shape[0], "width": valid.shape[1],
            "outliers": base64.b64encode(pack_mask(valid & False)).decode(),
            "reviewed": base64.b64encode(pack_mask(valid)).decode(), **extra}


def _count(db):
    with LabelStore(db) as s:
        return s.label_count()


def test_the_token_becomes_a_same_site_http_only_cookie(served):
    srv = served[0]
    r = httpx.get(srv.url)
    cookie = r.headers["set-cookie"]
    name, rest = cookie.split("=", 1)
    sid, *attrs = [a.strip() for a in rest.split(";")]
    assert name == cookie_name(srv.token) != cookie_name(new_token())  # servers on one host keep theirs apart
    assert sorted(attrs) == ["HttpOnly", "Path=/", "SameSite=Strict"]  # a session cookie: no Expires, no Domain
    assert srv.token not in r.text and sid not in r.text and len(sid) >= 40
    # the cookie alone opens the page again (no new session) and the API
    again = httpx.get(f"{srv.base}/", headers={"Cookie": f"{name}={sid}"})
    assert again.status_code == 200 and "set-cookie" not in again.headers
    assert httpx.get(f"{srv.base}/api/session", headers={"Cookie": f"{name}={sid}"}).status_code == 200
    # another server's cookie name, or a made-up session id, is nothing
    assert httpx.get(f"{srv.base}/api/session", headers={"Cookie": f"{cookie_name(new_token())}={sid}"}).status_code == 403
    assert httpx.get(f"{srv.base}/api/session", headers={"Cookie": f"{name}={sid[:-2]}xx"}).status_code == 403
    # the token in the URL is taken by the page only
    assert httpx.get(f"{srv.base}/api/session", params={"token": srv.token}).status_code == 403


def test_writes_check_origin(served):
    srv, _, db = served
    valid = _valid(srv, 1)
    port = srv.port
    before = _count(db)
    cases = [  # (extra headers, via the cookie?, status)
        ({}, True, 403),
        ({"Origin": "http://evil.example"}, True, 403),
        ({"Origin": f"http://127.0.0.1:{port + 1}"}, True, 403),
        ({"Origin": "null"}, True, 403),
        ({"Origin": f"http://127.0.0.1:{port}", "Sec-Fetch-Site": "cross-site"}, True, 403),
        ({"Origin": f"http://127.0.0.1:{port}", "Sec-Fetch-Site": "same-site"}, True, 403),
        ({"Origin": "http://evil.example"}, False, 403),
        ({"Origin": f"http://127.0.0.1:{port}", "Sec-Fetch-Site": "same-origin"}, True, 200),
        ({"Origin": f"http://localhost:{port}"}, True, 200),
        ({}, False, 200),  # the token in a header: a script, not a browser (no other site can set it)
    ]
    with page_client(srv.base, srv.token) as c:
        cookie = {"Cookie": "; ".join(f"{k}={v}" for k, v in c.cookies.items())}
    base = 0
    for extra, via_cookie, status in cases:
        h = {**(cookie if via_cookie else srv.headers()), **extra}
        r = httpx.put(f"{srv.base}/api/frames/1/label", json=_body(valid, base_revision=base), headers=h)
        assert r.status_code == status, (extra, via_cookie, r.text)
        if status == 200:
            base = r.json()["revision"]
    assert _count(db) == before + 3
    r = httpx.post(f"{srv.base}/api/annotator", json={"name": "eve"}, headers=cookie)
    assert r.status_code == 403 and "Origin" in r.text


def test_the_annotator_is_never_taken_from_the_request(served):
    srv, log, db = served
    valid = _valid(srv)
    before = _count(db)
    for who in ("bob", "\u0430lice", "alice "):
        r = httpx.put(f"{srv.base}/api/frames/0/label", json=_body(valid, annotator=who), headers=srv.headers())
        assert r.status_code == 403 and "never taken from a request" in r.json()["error"]
    with page_client(srv.base, srv.token) as c:
        r = c.post("/api/annotator", json={"name": "bob"})  # the server was started for alice
        assert r.status_code == 409 and "alice" in r.json()["error"]
        r = c.put("/api/frames/0/label", json=_body(valid))
        assert r.status_code == 200 and r.json()["annotator"] == "alice"
    assert _count(db) == before + 1
    with LabelStore(db) as s:
        assert s.annotators(s.log_by_sha(file_sha256(log))) == ["alice"]


def test_each_page_session_chooses_its_name_once(tmp_path):
    log = tmp_path / "scan.mcap"
    write_spike_log(log, frames=1)
    db = tmp_path / "labels.sqlite"
    with LabelStore(db) as s:  # an earlier alice
        s.add_log(log)
    srv = ServerProcess(log, db, annotator=None, extra=["--ask-annotator"])
    try:
        valid = _valid(srv)
        # a script with the token has no page session: it cannot choose, nor label
        r = httpx.post(f"{srv.base}/api/annotator", json={"name": "carl"}, headers=srv.headers())
        assert r.status_code == 403
        assert httpx.put(f"{srv.base}/api/frames/0/label", json=_body(valid), headers=srv.headers()).status_code == 403
        with page_client(srv.base, srv.token) as a, page_client(srv.base, srv.token) as b:
            assert a.get("/api/frames").status_code == 403  # no name yet
            assert a.put("/api/frames/0/label", json=_body(valid)).status_code == 403
            refused = [("\u0430lice", "mixes scripts"), ("al\u200bice", "U+200B"), ("", "1..64"), (7, "string"),
                       ("x" * 70, "1..64")]
            for name, why in refused:
                r = a.post("/api/annotator", json={"name": name})
                assert r.status_code == 422 and why in r.json()["error"], (name, r.text)
            assert a.post("/api/annotator", json={"name": "ａｌｉｃｅ"}).json() == {"annotator": "alice"}
            r = a.post("/api/annotator", json={"name": "bob"})  # once only
            assert r.status_code == 409 and r.json()["annotator"] == "alice"
            r = b.post("/api/annotator", json={"name": "ALICE"})  # looks like a name in use
            assert r.status_code == 422 and "looks like the existing annotator 'alice'" in r.json()["error"]
            assert b.post("/api/annotator", json={"name": "bob"}).json() == {"annotator": "bob"}
            assert a.put("/api/frames/0/label", json=_body(valid)).json()["annotator"] == "alice"
            assert b.put("/api/frames/0/label", json=_body(valid)).json()["annotator"] == "bob"
            assert a.get("/api/session").json()["annotator"] == "alice"
    finally:
        srv.stop()


def _gated_page(tmp_path, gate: threading.Event, *, lose: int | None = None) -> Page:
    """A page whose frames after the first are prepared only once ``gate`` is set (or, with
    ``lose``, that loses that frame, as a damaged log does, and stops before its end until ``gate``)."""
    log = tmp_path / "scan.mcap"
    write_spike_log(log, frames=4)
    replay = ReplaySession.open(log)
    store = LabelStore(tmp_path / "labels.sqlite")
    lg = store.add_log(log)

    def results():
        for fr, res in replay.results():
            if lose is None and fr.index >= 1 or fr.index == 3:
                gate.wait(120)
            if fr.index != lose:
                yield fr, res

    catalogue = Catalogue(results=results, store=store, log=lg, geometry=GeometrySpill(),
                          total_hint=replay.reader.n_frames)
    page = Page(log_path=log, store=store, log=lg, catalogue=catalogue, token=new_token(), annotator="alice",
                replay=replay)
    catalogue.start()
    return page


def test_frames_not_prepared_yet_answer_at_once_with_503(tmp_path):
    gate = threading.Event()
    srv = LiveServer(_gated_page(tmp_path, gate))
    try:
        with httpx.Client(base_url=srv.base, headers=srv.headers(), timeout=10) as c:
            deadline = time.monotonic() + 60
            while c.get("/api/session").json()["prepared"] < 1:
                assert time.monotonic() < deadline
                time.sleep(0.05)
            valid = parse_bundle(c.get("/api/frames/0/bundle").content)[1]["valid"]
            # 45 requests for a frame still being prepared: each answered at once (the old server held a
            # worker for each, up to 300 s, and 40 of them stalled every other request)
            for path in ["/api/frames/1/view", "/api/frames/2/bundle", "/api/frames/1/geometry?x0=0&y0=0&x1=4&y1=4"] * 15:
                r = c.get(path)
                assert r.status_code == 503 and 1 <= int(r.headers["retry-after"]) <= 30, r.text
            r = c.put("/api/frames/1/label", json=_body(valid))
            assert r.status_code == 503 and "retry-after" in r.headers
            assert c.get("/api/frames/4/bundle").status_code == 404  # the log has 4 frames
            assert c.get("/api/frames/0/view").status_code == 200
            assert [f["index"] for f in c.get("/api/frames").json()["frames"]] == [0]
            gate.set()
            while c.get("/api/frames/1/view").status_code == 503:
                assert time.monotonic() < deadline
                time.sleep(0.05)
            valid1 = parse_bundle(c.get("/api/frames/1/bundle").content)[1]["valid"]
            assert c.put("/api/frames/1/label", json=_body(valid1)).status_code == 200
    finally:
        gate.set()
        srv.stop()


def test_a_frame_lost_to_damage_is_404_while_the_rest_is_prepared(tmp_path):
    gate = threading.Event()
    srv = LiveServer(_gated_page(tmp_path, gate, lose=1))
    try:
        with httpx.Client(base_url=srv.base, headers=srv.headers(), timeout=10) as c:
            deadline = time.monotonic() + 60
            while c.get("/api/session").json()["prepared"] < 2:
                assert time.monotonic() < deadline
                time.sleep(0.05)
            assert not c.get("/api/session").json()["done"]
            assert c.get("/api/frames/1/view").status_code == 404  # frame 2 came: 1 is lost, not coming
            assert c.get("/api/frames/2/view").status_code == 200
            assert c.get("/api/frames/3/view").status_code == 503
            assert [f["index"] for f in c.get("/api/frames").json()["frames"]] == [0, 2]
    finally:
        gate.set()
        srv.stop()


def _closed(sock: socket.socket) -> bool:
    try:
        while sock.recv(4096):
            pass
        return True
    except (ConnectionResetError, TimeoutError):
        return False


def test_slow_headers_and_bodies_are_timed_out(tmp_path):
    log = tmp_path / "scan.mcap"
    write_spike_log(log, frames=1)
    srv = LiveServer(open_page(log, tmp_path / "labels.sqlite", annotator="alice"),
                     header_timeout_s=0.5, body_timeout_s=0.5)
    head = f"PUT /api/frames/0/label HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Zcut-Token: {srv.token}\r\n"
    try:
        srv.page.catalogue.wait_until_done(60)
        cases = {
            "nothing sent": b"",
            "headers never finished": f"GET /api/session HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Zcut-Token: {srv.token}\r\n".encode(),
            "one byte": b"G",
            "body never finished": f"{head}Content-Type: application/json\r\nContent-Length: 100\r\n\r\n{{\"a\":".encode(),
            "chunked body never finished": f"{head}Content-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n5\r\n{{\"a\":".encode(),
        }
        for name, data in cases.items():
            with socket.create_connection(("127.0.0.1", srv.port), timeout=10) as s:
                s.sendall(data)
                assert status_line(s).startswith(b"HTTP/1.1 408"), name
                assert _closed(s), name
        # a kept-alive connection: the next request's headers are timed out as well
        with socket.create_connection(("127.0.0.1", srv.port), timeout=10) as s:
            s.sendall(f"GET /api/session HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Zcut-Token: {srv.token}\r\n\r\n".encode())
            assert status_line(s).startswith(b"HTTP/1.1 200")
            time.sleep(0.1)
            s.sendall(b"GET /api/session HTTP/1.1\r\nHost: 127.0.0.1\r\n")
            got = b""
            while b"408" not in got:
                part = s.recv(65536)
                assert part, got[-200:]
                got += part
        # and a prompt client is served
        assert httpx.get(f"{srv.base}/api/session", headers=srv.headers()).status_code == 200
    finally:
        srv.stop()


def _raw(port: int, data: bytes) -> bytes:
    with socket.create_connection(("127.0.0.1", port), timeout=30) as s:
        s.sendall(data)
        return status_line(s)


def test_malformed_requests_are_4xx_never_500(served):
    srv, _, db = served
    before = _count(db)
    tok = srv.token
    get = lambda target, extra="": f"GET {target} HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Zcut-Token: {tok}\r\n{extra}\r\n".encode()

    def put(body: bytes, path="/api/frames/0/label", ctype="application/json", extra=""):
        return (f"PUT {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Zcut-Token: {tok}\r\nContent-Type: {ctype}\r\n"
                f"Content-Length: {len(body)}\r\n{extra}\r\n").encode() + body

    valid = _valid(srv)
    good = json.dumps(_body(valid))
    cases = {
        "5,000-digit frame index": get(f"/api/frames/{'9' * 5000}/bundle"),
        "5,000-digit index, label": put(good.encode(), path=f"/api/frames/{'7' * 5000}/label"),
        "negative index": get("/api/frames/-1/view"),
        "hex index": get("/api/frames/0x1/bundle"),
        "index beyond the log": get("/api/frames/99/bundle"),
        "no such image": get("/api/frames/0/image/..%2f..%2fserver.py"),
        "bad image kind": get("/api/frames/0/view?image=%ff%fe"),
        "geometry without bounds": get("/api/frames/0/geometry"),
        "geometry not a number": get("/api/frames/0/geometry?x0=a&y0=0&x1=1&y1=1"),
        "geometry negative": get("/api/frames/0/geometry?x0=-4&y0=0&x1=1&y1=1"),
        "geometry 5,000 digits": get(f"/api/frames/0/geometry?x0=0&y0=0&x1={'9' * 5000}&y1=1"),
        "geometry empty": get("/api/frames/0/geometry?x0=5&y0=5&x1=5&y1=9"),
        "deeply nested JSON": put(b"[" * 200_000),
        "deeply nested object": put(b'{"a":' * 50_000 + b"1" + b"}" * 50_000),
        "5,000-digit number": put(b'{"base_revision": 1' + b"0" * 5000 + b"}"),
        "NaN revision": put(good.replace('"base_revision": 0', '"base_revision": NaN').encode()),
        "huge revision": put(good.replace('"base_revision": 0', '"base_revision": 1e400').encode()),
        "bad UTF-8": put(b'{"base_revision": "\xff\xfe"}'),
        "not JSON": put(b"\x00\x01\x02"),
        "JSON list": put(b"[1, 2, 3]"),
        "text/plain": put(good.encode(), ctype="text/plain"),
        "no content type": (f"PUT /api/frames/0/label HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Zcut-Token: {tok}\r\n"
                            "Content-Length: 2\r\n\r\n{}").encode(),
        "negative Content-Length": (f"PUT /api/frames/0/label HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Zcut-Token: {tok}\r\n"
                                    "Content-Type: application/json\r\nContent-Length: -1\r\n\r\n").encode(),
        "Content-Length and chunked": put(b"{}", extra="Transfer-Encoding: chunked\r\n"),
        "DELETE a label": f"DELETE /api/frames/0/label HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Zcut-Token: {tok}\r\n\r\n".encode(),
        "POST a label": put(good.encode()).replace(b"PUT", b"POST", 1),
        "PUT the frame list": put(good.encode(), path="/api/frames"),
        "choose a name on a fixed server": put(b'{"name": "x"}', path="/api/annotator").replace(b"PUT", b"POST", 1),
        "no Host": f"GET /api/session HTTP/1.1\r\nX-Zcut-Token: {tok}\r\n\r\n".encode(),
        "foreign Host": f"GET /api/session HTTP/1.1\r\nHost: evil.example\r\nX-Zcut-Token: {tok}\r\n\r\n".encode(),
        "garbage request line": b"HELLO THERE\r\n\r\n",
        "header without colon": f"GET /api/session HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Zcut-Token {tok}\r\n\r\n".encode(),
        "raw byte in the path": b"GET /api/frames/\xff/bundle HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Zcut-Token: " + tok.encode() + b"\r\n\r\n",
        "raw byte in the query": b"GET /api/frames/0/view?image=\xff HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Zcut-Token: " + tok.encode() + b"\r\n\r\n",
        "huge header": get("/api/session", extra=f"X-Junk: {'j' * 200_000}\r\n"),
        "cookie garbage": b"GET /api/session HTTP/1.1\r\nHost: 127.0.0.1\r\nCookie: \x01;;=;zcut-=\r\n\r\n",
        "unknown path": get("/etc/passwd"),
        "static file outside the list": get("/static/../server.py"),
    }
    for name, data in cases.items():
        line = _raw(srv.port, data)
        assert line.startswith(b"HTTP/1.1 4"), (name, line)
    assert _count(db) == before
    assert httpx.get(f"{srv.base}/api/session", headers=srv.headers()).status_code == 200  # still serving


def test_a_second_server_on_the_store_is_detected(tmp_path):
    log = tmp_path / "scan.mcap"
    write_spike_log(log, frames=1)
    db = tmp_path / "labels.sqlite"
    first = ServerProcess(log, db, annotator="alice")
    second = third = None
    try:
        assert httpx.get(f"{first.base}/api/session", headers=first.headers()).json()["other_servers"] == []
        second = ServerProcess(log, db, annotator="bob")
        warning = "".join(second.stderr_lines)
        assert f"warning: zcut annotate (pid {first.proc.pid} on" in warning and f"port {first.port}" in warning
        assert str(db) in warning
        others = httpx.get(f"{first.base}/api/session", headers=first.headers()).json()["other_servers"]
        assert len(others) == 1 and f"pid {second.proc.pid}" in others[0]
        others = httpx.get(f"{second.base}/api/session", headers=second.headers()).json()["other_servers"]
        assert len(others) == 1 and f"pid {first.proc.pid}" in others[0]
        # a server killed without a word is gone too (its process is)
        third = ServerProcess(log, db, annotator="carl")
        assert len(httpx.get(f"{first.base}/api/session", headers=first.headers()).json()["other_servers"]) == 2
        third.kill()
        second.stop()
        assert httpx.get(f"{first.base}/api/session", headers=first.headers()).json()["other_servers"] == []
    finally:
        for s in (second, third, first):
            if s is not None:
                s.stop()
    with LabelStore(db) as s:
        assert s.live_servers() == []
