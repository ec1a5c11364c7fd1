"""Helpers shared by the log tests (tests/ is on sys.path, like annotate_helpers)."""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path

import numpy as np


def mutations(raw: bytes, rng: np.random.Generator, n: int) -> Iterator[tuple[int, bytes]]:
    """``n`` seeded mutants of ``raw``: (kind, bytes); kinds cycle through flips, truncation,
    absurd 8-byte and 4-byte values, inserted/deleted runs and zeroed runs."""
    for k in range(n):
        b = bytearray(raw)
        kind = k % 6
        if kind == 0:  # flip a few bytes anywhere
            for pos in rng.integers(0, len(b), int(rng.integers(1, 9))):
                b[pos] ^= int(rng.integers(1, 256))
        elif kind == 1:  # truncate
            b = b[: int(rng.integers(0, len(b)))]
        elif kind == 2:  # absurd 8-byte value (a length, a size, a count)
            pos = int(rng.integers(0, len(b) - 8))
            b[pos : pos + 8] = struct.pack("<Q", [2**31, 2**32 - 1, 2**40, 2**63, 2**64 - 1][int(rng.integers(5))])
        elif kind == 3:  # absurd 4-byte value
            pos = int(rng.integers(0, len(b) - 4))
            b[pos : pos + 4] = struct.pack("<I", [0, 2**31, 2**32 - 1, 1 << 24][int(rng.integers(4))])
        elif kind == 4:  # delete or insert a run of bytes
            pos = int(rng.integers(0, len(b)))
            if rng.random() < 0.5:
                del b[pos : pos + int(rng.integers(1, 64))]
            else:
                b[pos:pos] = bytes(rng.integers(0, 256, int(rng.integers(1, 64)), dtype=np.uint8))
        else:  # zero a range
            pos = int(rng.integers(0, len(b)))
            b[pos : pos + int(rng.integers(1, 512))] = bytes(min(len(b) - pos, 512))[: len(b[pos : pos + 512])]
        yield kind, bytes(b)


def read_frames(path, *, start: int = 0, stop: int | None = None, **reader_options) -> tuple[list, list[str]]:
    """One pass over a log: (its frames, the texts of the pass's damage records, as a user reads them)."""
    from replay.logs.damage import damage_lines
    from replay.logs.reader import LogReader

    stream = LogReader(path, **reader_options).frames(start=start, stop=stop)
    got = list(stream)
    return got, damage_lines(stream.damage)


def without_truth(src: Path, dest: Path) -> None:
    """The log's frames without any truth topic (its bin model attached as before)."""
    from replay.logs import layout
    from replay.logs.reader import LogReader
    from replay.logs.writer import LogWriter

    reader = LogReader(src)
    att = {layout.BIN_MODEL_ATTACHMENT: (layout.BIN_MODEL_MEDIA_TYPE, reader.bin_model_ply)}
    with LogWriter(dest, attachments=att) as w:
        for f in reader.frames():
            f.masks.clear()
            w.write_frame(f)


def writer_like(reader, dest: Path, **writer_options):
    """A :class:`~replay.logs.writer.LogWriter` to ``dest`` with ``reader``'s metadata and its bin model attached."""
    from replay.logs import layout
    from replay.logs.writer import LogWriter

    return LogWriter(dest, metadata=reader.metadata, **writer_options,
                     attachments={layout.BIN_MODEL_ATTACHMENT: (layout.BIN_MODEL_MEDIA_TYPE, reader.bin_model_ply)})


def invalid_blobs(xyz: np.ndarray, rng: np.random.Generator) -> None:
    """Blobs of invalid pixels over ~40 % of an (H, W, 3) cloud's image, in place (12 boxes of up to 50 x 60
    pixels about seeded centres)."""
    h, w = xyz.shape[:2]
    for _ in range(12):
        r, c = rng.integers(0, h), rng.integers(0, w)
        xyz[max(0, r - 25):r + 25, max(0, c - 30):c + 30] = np.nan


def decoded_in_full(path: Path) -> tuple[dict[int, tuple[np.ndarray, np.ndarray | None]], dict[int, np.ndarray]]:
    """The log's clouds and images decoded message by message into fresh arrays, the oracle of the
    reader's fast decoding: (stamp -> (xyz, the cloud's own colours or None), stamp -> the Image's rgb)."""
    from replay.logs import ros2_msgs as rm
    from replay.logs.mcap_scan import OP_CHANNEL, OP_MESSAGE, McapFile
    from replay.logs.reader import LogReader
    from replay.logs.stream import message_payload

    reader = LogReader(path)
    clouds: dict[int, tuple[np.ndarray, np.ndarray | None]] = {}
    images: dict[int, np.ndarray] = {}
    topics: dict[int, str] = {}
    with McapFile(path) as mf:
        for op, rec in mf.records([], prefetch=0):
            if op == OP_CHANNEL:
                topics[rec.id] = rec.topic
            elif op == OP_MESSAGE and topics.get(rec.channel_id) == reader.cloud_topic:
                msg = rm.decode_cloud(message_payload(rec.data, "cloud"))
                clouds[msg.stamp_ns] = rm.cloud_to_arrays(msg, where="cloud")
            elif op == OP_MESSAGE and reader.image_topic and topics.get(rec.channel_id) == reader.image_topic:
                img = rm.decode_image(message_payload(rec.data, "image"))
                images[img.stamp_ns] = rm.image_to_rgb(img, where="image")
    return clouds, images


def rrd_rows(path: str | Path, *, static: bool = False) -> dict[str, list[str]]:
    """Every row of a recording (.rrd) by entity, sorted: its timelines and components as JSON (not its row ids,
    log times or the recording's properties, which differ from run to run); ``static``: each row's static flag
    too."""
    import json

    import pyarrow as pa
    import rerun as rr

    out: dict[str, list[str]] = {}
    for chunk in rr.chunk.RrdReader(str(path)).stream():
        if chunk.entity_path == "/__properties":
            continue
        rb = chunk.to_record_batch()
        cols = {}
        for n in rb.schema.names:
            if "rowid" in n.lower().replace("_", "") or n == "log_time":
                continue
            c = rb.column(n)
            cols[n] = (c.cast(pa.int64()) if pa.types.is_timestamp(c.type) else c).to_pylist()
        flag = {"static": chunk.is_static} if static else {}
        out.setdefault(chunk.entity_path, []).extend(
            json.dumps({**flag, **{n: v[i] for n, v in cols.items()}}, sort_keys=True, default=str)
            for i in range(rb.num_rows))
    return {k: sorted(v) for k, v in out.items()}
