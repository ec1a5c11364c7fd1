"""A log's identity without reading every byte (replay.logs.identity, issue 33: the comparison's planning
hashed every byte of each log, ~86 CPU-ms a 127 MB log): the same file at another path or time is the
same log (the same records written again in another layout may be another: a resume refused, the safe side); a changed message, attachment or metadata is another; a file that cannot vouch for its content
(no index, no CRCs, cut short) is identified by the SHA-256 of every byte; a comparison resumed over a log
changed under the same path is refused (one line), started afresh with --force; `zcut annotate
--disagreement` still tells the compared log."""

from __future__ import annotations

import hashlib
import json
import os
import shutil

import pytest
from cli_helpers import run_cli, synth_logs

from replay.logs.identity import file_sha256, log_identity

SIZE = "120x180"


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    specs = (("old", "rods", 3, 1), ("new", "spheres", 2, 2))
    return synth_logs(tmp_path_factory.mktemp("identity_logs"), specs, size=SIZE)


def _copy(src, dst, *, message=None, attachment=None, metadata=None, **writer):
    """``src`` written again record for record by the mcap library's writer (``writer``: its options),
    each message's, attachment's and metadata's content passed through the given function first."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with open(src, "rb") as f, open(dst, "wb") as g:
        r = make_reader(f)
        header = r.get_header()
        w = Writer(g, **writer)
        w.start(profile=header.profile, library=header.library)
        for m in r.iter_metadata():
            w.add_metadata(m.name, (metadata or dict)(dict(m.metadata)))
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for n, (schema, channel, msg) in enumerate(r.iter_messages(log_time_order=False)):
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding,
                                                          schemas.get(channel.schema_id, 0), dict(channel.metadata))
            data = message(n, channel.topic, msg.data) if message else msg.data
            w.add_message(channels[channel.id], msg.log_time, data, msg.publish_time, msg.sequence)
        for a in r.iter_attachments():
            w.add_attachment(a.create_time, a.log_time, a.name, a.media_type,
                             attachment(a.name, a.data) if attachment else a.data)
        w.finish()


def _flip_last(data: bytes) -> bytes:
    return data[:-1] + bytes([data[-1] ^ 1])


def test_the_same_content_is_the_same_log(logs, tmp_path):
    log = logs / "old.mcap"
    ident = log_identity(log)
    assert len(ident) == 64 and ident != file_sha256(log)  # not every byte: the index and CRCs
    shutil.copy(log, tmp_path / "elsewhere.mcap")
    os.utime(tmp_path / "elsewhere.mcap", ns=(1, 1))
    assert log_identity(tmp_path / "elsewhere.mcap") == ident
    assert log_identity(logs / "new.mcap") != ident


@pytest.mark.parametrize("change", ["one bit of one cloud", "one bit of the last message", "an attachment",
                                    "a metadata value"])
def test_a_changed_content_is_another_log(logs, tmp_path, change):
    """One bit changed anywhere a frame is read from: another identity, also where the file's sizes and
    layout stay the same (uncompressed chunks of equal length)."""
    log = logs / "old.mcap"
    from mcap.writer import CompressionType

    plain = {"compression": CompressionType.NONE}
    _copy(log, tmp_path / "same.mcap", **plain)
    kw: dict = {}
    if change == "one bit of one cloud":
        kw["message"] = lambda n, topic, d: _flip_last(d) if n == 0 else d
    elif change == "one bit of the last message":
        from mcap.reader import make_reader

        with open(log, "rb") as f:
            count = sum(1 for _ in make_reader(f).iter_messages(log_time_order=False))
        kw["message"] = lambda n, topic, d: _flip_last(d) if n == count - 1 else d
    elif change == "an attachment":
        kw["attachment"] = lambda name, d: _flip_last(d)
    else:
        kw["metadata"] = lambda m: {**m, next(iter(m)): m[next(iter(m))] + " "}
    _copy(log, tmp_path / "changed.mcap", **plain, **kw)
    if change.startswith("one bit"):
        assert os.path.getsize(tmp_path / "changed.mcap") == os.path.getsize(tmp_path / "same.mcap")
    assert log_identity(tmp_path / "changed.mcap") != log_identity(tmp_path / "same.mcap")


@pytest.mark.parametrize("how", ["no chunks", "no CRCs", "cut short", "not an MCAP file"])
def test_a_file_that_cannot_vouch_for_its_content_is_hashed_whole(logs, tmp_path, how):
    log, out = logs / "old.mcap", tmp_path / "x.mcap"
    if how == "no chunks":
        _copy(log, out, use_chunking=False)
    elif how == "no CRCs":
        _copy(log, out, enable_crcs=False)
    elif how == "cut short":
        out.write_bytes(log.read_bytes()[:-1000])
    else:
        out.write_bytes(b"not an mcap file at all" * 10)
    assert log_identity(out) == hashlib.sha256(out.read_bytes()).hexdigest()


def test_a_log_changed_under_a_resumed_comparison_is_refused_or_started_afresh(logs, tmp_path, capsys):
    opts = ["--a", "zcut", "--b", "sor", "--workers", "0", "--frames-per-unit", "1", "--no-rrd"]
    log, out = tmp_path / "in" / "log.mcap", tmp_path / "cmp"
    log.parent.mkdir()
    shutil.copy(logs / "old.mcap", log)
    rc, _, err = run_cli(capsys, "compare", log, "-o", out, *opts)
    assert rc == 0, err
    parts = sorted((out / "parts").glob("*.json"))
    parts[-1].unlink()
    parts[-1].with_suffix(".parquet").unlink()
    for p in out.glob("*.*"):
        if p.is_file() and p.name != "run.json":
            p.unlink()  # what a comparison killed midway leaves: the parts done, no outputs
    before = {p.name: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    shutil.copy(logs / "new.mcap", log)  # another log at the same path
    rc, _, err = run_cli(capsys, "compare", log, "-o", out, *opts)
    assert rc == 1, err
    (line,) = [ln for ln in err.splitlines() if not ln.startswith("zcut: compiling")]
    assert line.startswith(f"error: -o {out}: {log} changed since this study began (content sha256 "
                           f"{log_identity(logs / 'old.mcap')[:12]}… then, {log_identity(logs / 'new.mcap')[:12]}… "
                           "now)") and "--force starts it afresh" in line, line
    assert {p.name: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before  # nothing touched
    rc, out_json, err = run_cli(capsys, "compare", log, "-o", out, *opts, "--force", "--json")
    assert rc == 0, err
    assert "starts afresh" in err
    rep = json.loads(out_json)
    assert [f["index"] for f in rep["frames"]] == [0, 1]  # the new log's frames only
    # the disagreement still tells the compared log (by its identity), and not another
    from annotate.disagreement import load

    assert load(out, log).frames
    with pytest.raises(Exception, match="not of old.mcap"):
        load(out, logs / "old.mcap")
