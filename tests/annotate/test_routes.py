"""The labelling server's route handlers called directly, without HTTP: each is a plain function of
the page (a real log opened for replay, a real SQLite store) and a Starlette request."""

from __future__ import annotations

import asyncio
import base64
import json

import numpy as np
import pytest
from annotate_helpers import write_spike_log
from starlette.requests import Request

from annotate import routes
from annotate.inputs import BadRequest
from annotate.payload import parse_bundle
from annotate.server import open_page
from annotate.store import pack_mask


def _request(*, path_params=None, query=b"", zcut=None, method="GET", body=b"", content_type=None) -> Request:
    headers = [(b"content-type", content_type.encode())] if content_type else []
    scope = {"type": "http", "method": method, "path": "/", "headers": headers, "query_string": query,
             "path_params": path_params or {}, "zcut": zcut or {}}

    async def receive():
        return {"type": "http.request", "body": body, "more_body": False}

    return Request(scope, receive)


def _json(response) -> dict:
    return json.loads(response.body)


@pytest.fixture
def page(tmp_path):
    log = tmp_path / "scan.mcap"
    write_spike_log(log, frames=2, shape=(48, 64))
    p = open_page(log, tmp_path / "labels.sqlite", annotator="alice")
    assert p.catalogue.wait_until_done(120)
    yield p
    p.close()


@pytest.fixture
def open_choice_page(tmp_path):
    log = tmp_path / "scan.mcap"
    write_spike_log(log, frames=1, shape=(48, 64))
    p = open_page(log, tmp_path / "labels.sqlite", annotator=None)
    assert p.catalogue.wait_until_done(120)
    yield p
    p.close()


def _label(valid: np.ndarray, **extra) -> dict:
    return {"base_revision": 0, "height": valid.shape[0], "width": valid.shape[1],
            "outliers": base64.b64encode(pack_mask(valid & False)).decode(),
            "reviewed": base64.b64encode(pack_mask(valid)).decode(), **extra}


def test_frame_handlers(page):
    frames = _json(routes.api_frames(page, _request()))
    assert [f["index"] for f in frames["frames"]] == [0, 1] and frames["total"] == 2 and frames["done"]
    header, arrays = parse_bundle(routes.api_bundle(page, _request(path_params={"index": "1"})).body)
    assert header["index"] == 1 and arrays["valid"].shape == (48, 64)
    geometry = routes.api_geometry(page, _request(path_params={"index": "0"}, query=b"x0=0&y0=0&x1=4&y1=3"))
    assert geometry.headers["cache-control"] == "no-store" and len(geometry.body) > 4 * 3 * 3 * 4
    for raw, status in (("2", 404), ("1" * 10, 404), ("-1", 404)):
        with pytest.raises(BadRequest) as e:
            routes.requested_frame(page, _request(path_params={"index": raw}))
        assert e.value.status == status, raw
    for query in (b"x0=4&y0=0&x1=4&y1=3", b"x0=0&y0=5&x1=4&y1=5", b"x0=a&y0=0&x1=4&y1=3"):
        with pytest.raises(BadRequest) as e:
            routes.api_geometry(page, _request(path_params={"index": "0"}, query=query))
        assert e.value.status == 400 and len(str(e.value)) < 120


def test_save_label_commits_and_refuses_stale_or_foreign_labels(page):
    _, arrays = parse_bundle(routes.api_bundle(page, _request(path_params={"index": "0"})).body)
    valid = arrays["valid"]
    first = routes.save_label(page, 0, "alice", _label(valid))
    assert first.status_code == 200 and _json(first)["revision"] == 1 and _json(first)["reviewed"]
    stale = routes.save_label(page, 0, "alice", _label(valid))  # based on revision 0 again
    assert stale.status_code == 409 and _json(stale)["latest"] == 1
    with pytest.raises(BadRequest) as e:
        routes.save_label(page, 0, "alice", _label(valid, base_revision=1, annotator="bob"))
    assert e.value.status == 403
    with pytest.raises(BadRequest) as e:
        routes.save_label(page, 0, "alice", _label(valid, base_revision=1, width=63))
    assert e.value.status == 422
    rows = _json(routes.api_frames(page, _request()))["frames"]
    assert (rows[0]["revision"], rows[0]["reviewed"], rows[1]["revision"]) == (1, True, 0)
    assert page.store.label_count() == 1


def test_a_page_session_chooses_its_annotator_once(open_choice_page):
    page = open_choice_page
    with pytest.raises(BadRequest) as e:
        routes.annotator_of(page, _request())
    assert e.value.status == 403
    sid = page.clients.new(None)
    cookie = {"via": "cookie", "sid": sid}

    def choose(name: str):
        body = json.dumps({"name": name}).encode()
        return asyncio.run(routes.api_annotator(page, _request(method="POST", body=body, zcut=cookie)))

    assert _json(choose("bob")) == {"annotator": "bob"}
    assert routes.annotator_of(page, _request(zcut=cookie)) == "bob"
    again = choose("carol")
    assert again.status_code == 409 and _json(again)["annotator"] == "bob"
    with pytest.raises(BadRequest) as e:  # the token header has no page session to bind
        asyncio.run(routes.api_annotator(page, _request(method="POST", body=b'{"name": "dave"}',
                                                        zcut={"via": "header", "sid": None})))
    assert e.value.status == 403
    session = _json(routes.api_session(page, _request(zcut=cookie)))
    assert (session["mode"], session["annotator"], session["prepared"], session["damage"]) == ("choose", "bob", 1, [])
    assert session["notes"] == list(page.replay.notes) and session["notes"]
