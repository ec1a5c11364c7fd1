"""The access gate and the body guard alone (annotate.guard), around a small ASGI app that answers
what it was given: the layers are plain ASGI callables, driven here with the ASGI messages a server
would send them."""

from __future__ import annotations

import asyncio
import json

from annotate.guard import AccessGate, BodyGuard, Clients, cookie_name, new_token


async def _echo(scope, receive, send) -> None:
    """An app that answers 200 with the caller the gate put in the scope and the body's length."""
    got = b""
    while True:
        msg = await receive()
        if msg["type"] != "http.request":
            break
        got += msg.get("body", b"")
        if not msg.get("more_body"):
            break
    body = json.dumps({"zcut": scope.get("zcut"), "body": len(got)}).encode()
    await send({"type": "http.response.start", "status": 200, "headers": [(b"content-type", b"application/json")]})
    await send({"type": "http.response.body", "body": body})


def _call(app, *, path="/api/session", method="GET", headers=(), query=b"", chunks=(b"",)) -> tuple[int, dict, bytes]:
    sent: list[dict] = []
    pending = list(chunks)

    async def receive():
        if not pending:
            await asyncio.sleep(3600)  # a client that stops sending
        body = pending.pop(0)
        return {"type": "http.request", "body": body, "more_body": bool(pending)}

    async def send(msg):
        sent.append(msg)

    scope = {"type": "http", "method": method, "path": path, "query_string": query, "server": ("127.0.0.1", 8123),
             "headers": [(k.encode(), v.encode()) for k, v in headers]}
    asyncio.run(app(scope, receive, send))
    start = next(m for m in sent if m["type"] == "http.response.start")
    body = b"".join(m.get("body", b"") for m in sent if m["type"] == "http.response.body")
    return start["status"], {k.decode(): v.decode() for k, v in start["headers"]}, body


def test_access_gate_token_cookie_and_origin():
    token, clients = new_token(), Clients()
    gate = AccessGate(_echo, token=token, clients=clients, fixed_annotator="alice", allowed_hosts=("127.0.0.1",))
    assert _call(gate)[0] == 403
    assert _call(gate, headers=[("x-zcut-token", token + "x")])[0] == 403
    status, _, body = _call(gate, headers=[("x-zcut-token", token)])
    assert status == 200 and json.loads(body)["zcut"] == {"via": "header", "sid": None}
    assert _call(gate, path="/api/session", query=f"token={token}".encode())[0] == 403  # only the page takes it
    status, headers, body = _call(gate, path="/", query=f"token={token}".encode())
    sid = json.loads(body)["zcut"]["sid"]
    assert status == 200 and headers["set-cookie"].startswith(f"{cookie_name(token)}={sid};")
    assert clients.get(sid).annotator == "alice"
    cookie = ("cookie", f"{cookie_name(token)}={sid}")
    assert json.loads(_call(gate, headers=[cookie])[2])["zcut"] == {"via": "cookie", "sid": sid}
    # writes: the cookie alone is not enough, the Origin must be this server
    assert _call(gate, method="PUT", headers=[cookie])[0] == 403
    assert _call(gate, method="PUT", headers=[cookie, ("origin", "http://evil.example")])[0] == 403
    assert _call(gate, method="PUT", headers=[cookie, ("origin", "http://127.0.0.1:8123"),
                                              ("sec-fetch-site", "cross-site")])[0] == 403
    assert _call(gate, method="PUT", headers=[cookie, ("origin", "http://127.0.0.1:8123")])[0] == 200


def test_body_guard_limits_size_and_time():
    guard = BodyGuard(_echo, limit=10, timeout_s=0.2)
    status, _, body = _call(guard, method="PUT", headers=[("content-length", "8")], chunks=(b"12345678",))
    assert status == 200 and json.loads(body)["body"] == 8
    assert _call(guard, method="PUT", headers=[("content-length", "11")])[0] == 413
    assert _call(guard, method="PUT", headers=[("content-length", "x")])[0] == 400
    assert _call(guard, method="PUT", headers=[("content-length", "3"), ("transfer-encoding", "chunked")])[0] == 400
    assert _call(guard, method="PUT", chunks=(b"123456", b"789012"))[0] == 413  # chunked, no length: counted
    status, _, body = _call(guard, method="PUT", chunks=(b"1234", b"5"))
    assert status == 200 and json.loads(body)["body"] == 5
    # a body that stops arriving: 408 within the time limit
    stalled = BodyGuard(_echo, limit=10, timeout_s=0.2)

    async def run():
        sent = []

        async def receive():
            await asyncio.sleep(3600)

        async def send(msg):
            sent.append(msg)

        scope = {"type": "http", "method": "PUT", "path": "/", "query_string": b"", "headers": []}
        await asyncio.wait_for(stalled(scope, receive, send), 5)
        return sent

    sent = asyncio.run(run())
    assert sent[0]["status"] == 408 and b"0.2 s" in sent[1]["body"]
