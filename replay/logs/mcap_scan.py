"""Damage-tolerant MCAP reading built on the ``mcap`` library's record parsing.

Division of work. The ``mcap`` library parses every record body (``mcap.records``: Header,
Footer, Schema, Channel, Message, Chunk, MessageIndex, ChunkIndex, Statistics, Metadata,
MetadataIndex) through :func:`parse_record`, which hands it a bounds-checked view of the body so
that a field can never run past its record and a message's data stays a view of its chunk (no
copy). What zcut adds is what the library's readers do not do (``mcap.reader`` stops at the
first bad record, takes a corrupt length at its word and decompresses lz4 chunks without a
bound):

- regular files only (a FIFO or device is refused before a byte is read);
- the record framing: every length is checked against the bytes that are really there and
  against ``max_chunk_bytes`` before reading;
- chunks are decompressed (zstd, lz4, none) incrementally, never past the declared
  ``uncompressed_size`` (itself checked against ``max_chunk_bytes`` before any allocation), and
  CRC-checked with ISA-L's CRC-32 (the zlib polynomial, about 4x faster than ``zlib.crc32``);
- the next chunks are read, decompressed and checked in worker threads while the caller decodes
  the current one (zstd and the CRC release the GIL), into reused buffers (:class:`BufferPool`);
- on a corrupt chunk a damage record (:class:`~replay.logs.damage.Damage`), then the scan goes on
  at the next chunk, using the summary's chunk index when the file has one (so a corrupt record
  length does not lose the rest, nor swallow the chunks it claims to cover), and says which
  messages were lost (per channel, their log times, from the chunk's message indexes: a
  :class:`Lost`);
- on a truncated file every complete record before the cut, then a damage record.

``bench/bench_logread.py`` (3) credits this scanner and the PointCloud2 codec separately: the
scanner alone costs about what ``mcap``'s own reader with CRC checks costs (it is kept for the
damage handling above, not for speed); the zero-copy codec is the speed-up.

Format reference: https://mcap.dev/spec (all integers little-endian).
"""

from __future__ import annotations

import bisect
import os
import struct
import threading
import weakref
from collections import deque
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from isal.isal_zlib import crc32
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    Chunk,
    ChunkIndex,
    Footer,
    Header,
    Message,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
)

from replay.errors import LogFormatError
from replay.logs.damage import Damage, DamageKind
from replay.logs.files import CHUNK_SLACK_BYTES, DEFAULT_MAX_MESSAGE_BYTES, open_input

MAGIC = b"\x89MCAP0\r\n"

OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_ATTACHMENT, OP_ATTACHMENT_INDEX = 0x07, 0x08, 0x09, 0x0A
OP_STATISTICS, OP_METADATA, OP_METADATA_INDEX, OP_SUMMARY_OFFSET, OP_DATA_END = (
    0x0B, 0x0C, 0x0D, 0x0E, 0x0F,
)

#: Default largest chunk (uncompressed), record or summary section zcut will hold in memory.
MAX_CHUNK_BYTES = DEFAULT_MAX_MESSAGE_BYTES + CHUNK_SLACK_BYTES
_READ_PIECE = 16 << 20
_FIRST_BUF = 16 << 20
#: pseudo opcode yielded by :meth:`McapFile.records` after a lost chunk: a :class:`Lost`
OP_LOST = 0x100
#: Chunks read ahead of the caller by :meth:`McapFile.records` (one worker thread each, at most
#: the number of CPUs), and the most uncompressed bytes they may hold beyond the first. Four: a frame's
#: chunks of a log that splits each frame's topics over a few chunks (a synthetic 1920 x 1200 log: the
#: cloud's 37 MB, 30 ms of zstd, then the image's, the masks', the kind codes' and depth's, 10 ms in all),
#: so that while one thread decompresses a cloud's chunk the others decompress the chunks after it, the
#: next cloud's among them (a frame is delivered once the next cloud has been read). With two, the second
#: thread idled while the first decompressed a cloud and the next cloud's chunk waited for it: the start
#: of a pass read its first frame ~25 ms later with one core idle (docs/performance.md, "Where the last
#: core-fraction waits").
PREFETCH = 4
PREFETCH_BYTES = 256 << 20
_OP_NOTE = -1  # internal: a damage record queued among the records


class _Bad(Exception):
    """Internal: a record does not parse (turned into LogFormatError or a damage record)."""


class BufferPool:
    """Large byte buffers that are handed out again once nothing references them.

    A 37 MB chunk is read and decompressed per 1920 x 1200 cloud; fresh buffers cost their page
    faults (the kernel zeroing every page) each time. :meth:`get` returns an array whose memory
    goes back to the pool when that array -- and so every memoryview made from it, which keeps it
    alive -- is gone (``weakref.finalize``). Hand out only memoryviews of it: a numpy slice of
    the array would not keep it alive.

    Parameters
    ----------
    max_free_bytes : int
        Free buffers kept beyond this many bytes are dropped (oldest first).
    """

    MIN_BYTES = 1 << 20  # smaller requests are plain np.empty

    def __init__(self, *, max_free_bytes: int = 384 << 20) -> None:
        self._free: list[np.ndarray] = []
        self._lock = threading.RLock()
        self._max_free = max_free_bytes
        self._closed = False

    def get(self, n: int) -> np.ndarray:
        """(n,) uint8 array (uninitialised): a free buffer of n to 2 n bytes, or a new one."""
        if n < self.MIN_BYTES:
            return np.empty(n, dtype=np.uint8)
        base = None
        with self._lock:
            fits = [i for i, a in enumerate(self._free) if n <= a.size <= 2 * n]
            if fits:
                base = self._free.pop(min(fits, key=lambda i: self._free[i].size))
        if base is None:
            base = np.empty(n, dtype=np.uint8)
        out = base[:n]
        weakref.finalize(out, self._release, base).atexit = False
        return out

    def array(self, shape: tuple[int, ...], dtype: Any) -> np.ndarray:
        """An uninitialised array of ``shape`` and ``dtype`` (a frame's decoded image) whose memory goes
        back to the pool once it and every array made from it are gone.

        The array is a view of a memoryview of a pooled buffer: numpy keeps that memoryview (not the
        pooled array, which is never handed out) as the base of every slice, view or reshape of it, so
        the buffer is released only after the last of them. A reused buffer is not written to by the
        kernel again (no page faults, docs/performance.md "The replay outside its stages").
        """
        dt = np.dtype(dtype)
        n = int(np.prod(shape, dtype=np.int64)) * dt.itemsize
        if n < self.MIN_BYTES:
            return np.empty(shape, dtype=dt)
        return np.frombuffer(memoryview(self.get(n)), dtype=dt).reshape(shape)  # type: ignore[arg-type]  # an ndarray is a buffer

    def _release(self, base: np.ndarray) -> None:
        with self._lock:
            if self._closed:
                return
            self._free.append(base)
            while sum(a.size for a in self._free) > self._max_free:
                self._free.pop(0)

    def close(self) -> None:
        """Drop the free buffers; buffers in use are freed normally when released."""
        with self._lock:
            self._closed = True
            self._free.clear()


class _View:
    """A stream over ``mv[pos:end]`` for mcap's record parsers (``mcap.records.X.read``).

    ``read(n)`` returns a slice of the buffer (no copy: a message's data stays a view of its
    chunk) and refuses to read past the record (mcap's ``ReadDataStream`` accepts a short read
    and would return a truncated string).
    """

    __slots__ = ("mv", "pos", "end")

    def __init__(self, mv: memoryview, pos: int = 0, end: int | None = None) -> None:
        self.mv = mv
        self.pos = pos
        self.end = len(mv) if end is None else end

    def read(self, n: int) -> memoryview:
        s = self.pos
        if n < 0 or s + n > self.end:
            raise _Bad(f"field of {n} bytes at {s} runs past the record end {self.end}")
        self.pos = s + n
        return self.mv[s : s + n]


_INNER = (OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_METADATA)  # the records zcut uses in the data section
_PARSERS = {
    OP_HEADER: Header.read, OP_FOOTER: Footer.read, OP_SCHEMA: Schema.read, OP_CHANNEL: Channel.read,
    OP_MESSAGE_INDEX: MessageIndex.read, OP_CHUNK_INDEX: ChunkIndex.read, OP_STATISTICS: Statistics.read,
    OP_METADATA: Metadata.read, OP_METADATA_INDEX: MetadataIndex.read, OP_CHUNK: Chunk.read,
    OP_ATTACHMENT: Attachment.read, OP_ATTACHMENT_INDEX: AttachmentIndex.read,
}


def parse_record(op: int, mv: memoryview, start: int = 0, end: int | None = None) -> Any:  # the class of op
    """mcap's record class (``mcap.records``) parsed from the body ``mv[start:end]``, or raise
    :class:`_Bad` (any field past the body, bad UTF-8, …)."""
    view = _View(mv, start, end)
    stream = ReadDataStream(view)  # type: ignore[arg-type]  # a duck-typed stream over the buffer
    try:
        if op == OP_MESSAGE:
            return Message.read(stream, view.end - start)
        rec = _PARSERS[op](stream)
        if op == OP_SCHEMA:
            rec.data = bytes(rec.data)  # small; a record that does not pin its chunk's buffer
        return rec
    except _Bad:
        raise
    except (McapError, struct.error, UnicodeDecodeError, ValueError, OverflowError) as e:
        raise _Bad(f"does not parse ({type(e).__name__}: {e})") from None


@dataclass(frozen=True, slots=True)
class Lost:
    """What a lost chunk held, from its message indexes.

    Attributes
    ----------
    offset : int
        File offset of the chunk.
    log_times : dict[int, list[int]] or None
        channel id -> log times of its messages in the chunk, in file order; None when unknown
        (no intact message index).
    """

    offset: int
    log_times: dict[int, list[int]] | None


@dataclass(frozen=True, slots=True)
class _ChunkRef:
    """Where a chunk record is (read later, in a worker thread)."""

    offset: int
    length: int  # of the record body
    usize: int  # uncompressed size its header claims (for the read-ahead budget; unchecked)


@dataclass
class Summary:
    """What the summary section says (empty containers when the file has none)."""

    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    chunk_indexes: list[ChunkIndex] = field(default_factory=list)
    metadata_offsets: list[tuple[str, int, int]] = field(default_factory=list)
    attachment_indexes: list[AttachmentIndex] = field(default_factory=list)
    channel_message_counts: dict[int, int] | None = None
    message_start_time: int | None = None
    message_end_time: int | None = None
    #: False when the footer says the file has no summary section (nothing above is then known)
    indexed: bool = True


def decompress(
    compression: str, data: memoryview, size: int, *, pool: BufferPool | None = None,
    max_size: int = MAX_CHUNK_BYTES,
) -> memoryview:
    """Decompress a chunk's records to exactly ``size`` bytes or raise :class:`_Bad`.

    ``size`` is checked against ``max_size`` before anything is allocated. The output buffer
    (from ``pool`` when given) starts at the declared size or, if that is much larger than the
    compressed data suggests, smaller, and grows as data really arrives, never past ``size``.
    """
    new = pool.get if pool is not None else (lambda n: np.empty(n, dtype=np.uint8))
    if size > max_size:
        raise _Bad(f"claims {size} uncompressed bytes, more than the cap of {max_size}")
    if compression == "":
        if len(data) != size:
            raise _Bad(f"holds {len(data)} bytes but claims {size}")
        return data
    # grow the output as real data arrives (doubling), never past the declared size: a lying
    # header costs nothing, a decompression bomb stops at ``size``
    buf = new(min(size, _FIRST_BUF + 64 * len(data)))
    total = 0
    extra = 0
    try:
        if compression == "zstd":
            import zstandard

            reader = zstandard.ZstdDecompressor().stream_reader(data, read_across_frames=True)
            while total < size:
                if total == len(buf):
                    bigger = new(min(size, 2 * len(buf)))
                    bigger[:total] = buf
                    buf = bigger
                n = reader.readinto(memoryview(buf)[total:])  # type: ignore[arg-type]  # an ndarray is a buffer
                if n == 0:
                    break
                total += n
            if total == size:
                extra = len(reader.read(1))
        elif compression == "lz4":
            import lz4.frame

            dec = lz4.frame.LZ4FrameDecompressor()
            pending = bytes(data)
            while total <= size and not dec.eof:
                piece = dec.decompress(pending, max_length=min(_READ_PIECE, size + 1 - total))
                pending = b""
                if not piece:
                    if dec.needs_input:
                        break
                    continue
                if total + len(piece) > size:
                    extra = 1
                    break
                if total + len(piece) > len(buf):
                    bigger = new(min(size, max(2 * len(buf), total + len(piece))))
                    bigger[:total] = buf[:total]
                    buf = bigger
                buf[total : total + len(piece)] = np.frombuffer(piece, dtype=np.uint8)
                total += len(piece)
        else:
            raise _Bad(f"uses unknown compression '{compression}'")
    except _Bad:
        raise
    except MemoryError as e:
        raise _Bad(f"needs more memory than available to decompress {size} bytes") from e
    except Exception as e:  # zstd / lz4 errors on corrupt data
        raise _Bad(f"does not decompress ({compression}: {e})") from e
    if total != size or extra:
        raise _Bad(f"decompresses to {'more than ' if extra else ''}{total} bytes, not {size}")
    return memoryview(buf)  # type: ignore[arg-type]  # an ndarray is a buffer


class McapFile:
    """An MCAP file opened for defensive scanning.

    Parameters
    ----------
    path : Path
    max_chunk_bytes : int
        Largest record, uncompressed chunk or summary section read into memory; larger ones are
        damage (the scan goes on at the next chunk).
    pool : BufferPool, optional
        Where the chunks' buffers come from and go back to: a :class:`~replay.logs.reader.LogReader`'s,
        shared by every pass over the log (a second pass reuses the first one's memory), and left open
        by :meth:`close`; else a pool of this file's own, closed with it.

    Raises
    ------
    LogFormatError
        Not a regular file, not MCAP, or a damaged header record.
    """

    def __init__(self, path: str | Path, *, max_chunk_bytes: int = MAX_CHUNK_BYTES,
                 pool: BufferPool | None = None) -> None:
        self.path = Path(path)
        self.max_chunk_bytes = int(max_chunk_bytes)
        self._f, self.size = open_input(self.path, "an MCAP log")
        #: the buffers of this file's chunks: ``pool`` (a reader's, kept across its passes) or its own
        self.pool = BufferPool() if pool is None else pool
        self._own_pool = pool is None
        head = self._f.read(8)
        if head != MAGIC:
            self._f.close()
            what = "is empty" if self.size == 0 else "does not start with the MCAP magic"
            raise LogFormatError(f"{self.path} is not an MCAP file ({what})")
        self.profile = ""
        self.library = ""
        rec = self._read_record_at(8)
        if rec is None or rec[0] != OP_HEADER:
            self._f.close()
            raise LogFormatError(f"{self.path}: damaged MCAP header record")
        try:
            header = parse_record(OP_HEADER, rec[1])
            self.profile, self.library = header.profile, header.library
        except _Bad as e:
            self._f.close()
            raise LogFormatError(f"{self.path}: damaged MCAP header record ({e})") from e
        self.data_start = 8 + 9 + len(rec[1])
        self.data_end: int | None = None  # known when the footer is intact
        self.summary_damage: Damage | None = None
        self.summary: Summary | None = None
        try:
            self.summary = self._read_summary()
        except _Bad as e:
            self.summary_damage = Damage(DamageKind.DAMAGED_SUMMARY,
                                         f"the summary section is damaged ({e}); read sequentially")
            self.summary = None

    def close(self) -> None:
        self._f.close()
        if self._own_pool:
            self.pool.close()

    def __enter__(self) -> McapFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ low level
    def _read_record_at(self, offset: int, *, expect_len: int | None = None) -> tuple[int, memoryview] | None:
        """(opcode, body) of the record at ``offset``, or None if it runs past the end of file."""
        if offset + 9 > self.size:
            return None
        self._f.seek(offset)
        head = self._f.read(9)
        if len(head) < 9:
            return None
        op, length = struct.unpack("<BQ", head)
        if offset + 9 + length > self.size:
            return None
        if expect_len is not None and 9 + length != expect_len:
            raise _Bad(f"record at {offset} is {9 + length} bytes, the index says {expect_len}")
        if length > self.max_chunk_bytes:
            raise _Bad(f"record at {offset} claims {length} bytes, more than the cap of {self.max_chunk_bytes}")
        body = memoryview(self.pool.get(length))  # type: ignore[arg-type]  # an ndarray is a buffer
        if self._f.readinto(body) != length:  # type: ignore[attr-defined]  # a file opened for binary reading
            return None
        return op, body

    def _read_summary(self) -> Summary | None:
        footer_at = self.size - 8 - 29
        if footer_at < self.data_start:
            return None
        self._f.seek(self.size - 8)
        if self._f.read(8) != MAGIC:
            return None
        rec = self._read_record_at(footer_at)
        if rec is None or rec[0] != OP_FOOTER or len(rec[1]) != 20:
            raise _Bad("the footer record is damaged")
        summary_start = parse_record(OP_FOOTER, rec[1]).summary_start
        s = Summary()
        if summary_start == 0:
            self.data_end = footer_at
            s.indexed = False
            return s
        if not (self.data_start <= summary_start <= footer_at):
            raise _Bad(f"the footer points at offset {summary_start}, outside the file")
        self.data_end = summary_start
        n = footer_at - summary_start
        if n > self.max_chunk_bytes:
            raise _Bad(f"summary section of {n} bytes, more than the cap of {self.max_chunk_bytes}")
        self._f.seek(summary_start)
        mv = memoryview(self._f.read(n))
        pos = 0
        while pos + 9 <= n:
            op, length = struct.unpack_from("<BQ", mv, pos)
            if pos + 9 + length > n:
                raise _Bad(f"summary record at {summary_start + pos} runs past the footer")
            if op in (OP_SCHEMA, OP_CHANNEL, OP_CHUNK_INDEX, OP_METADATA_INDEX, OP_STATISTICS, OP_ATTACHMENT_INDEX):
                rec = parse_record(op, mv, pos + 9, pos + 9 + length)
                if op == OP_SCHEMA:
                    s.schemas[rec.id] = rec
                elif op == OP_CHANNEL:
                    s.channels[rec.id] = rec
                elif op == OP_CHUNK_INDEX:
                    s.chunk_indexes.append(rec)
                elif op == OP_METADATA_INDEX:
                    s.metadata_offsets.append((rec.name, rec.offset, rec.length))
                elif op == OP_ATTACHMENT_INDEX:
                    s.attachment_indexes.append(rec)
                else:
                    s.message_start_time, s.message_end_time = rec.message_start_time, rec.message_end_time
                    s.channel_message_counts = dict(rec.channel_message_counts)
            pos += 9 + length
        s.chunk_indexes.sort(key=lambda c: c.chunk_start_offset)
        return s

    def read_metadata(self) -> tuple[dict[str, dict[str, str]], list[Damage]]:
        """Metadata records listed in the summary: (name -> key/values, damage records)."""
        out: dict[str, dict[str, str]] = {}
        notes: list[Damage] = []
        for name, off, ln in self.summary.metadata_offsets if self.summary else []:
            try:
                rec = self._read_record_at(off, expect_len=ln)
                if rec is None or rec[0] != OP_METADATA:
                    raise _Bad(f"no metadata record at offset {off}")
                meta = parse_record(OP_METADATA, rec[1])
                out[meta.name] = meta.metadata
            except _Bad as e:
                notes.append(Damage(DamageKind.DAMAGED_METADATA, f"metadata record '{name}' is damaged ({e})",
                                    byte=off))
        return out, notes

    def attachment_indexes(self, *, max_records: int = 1 << 20) -> list[AttachmentIndex]:
        """Where the file's attachments are, in file order: the summary's attachment indexes, or, for
        a file without a summary, what a walk over the data section's record headers finds (chunk
        bodies are skipped, not read; the walk stops at the first damaged record or after
        ``max_records`` records). Never raises for damage: a damaged part simply lists nothing."""
        if self.summary is not None and self.summary.indexed:
            return sorted(self.summary.attachment_indexes, key=lambda a: a.offset)
        out: list[AttachmentIndex] = []
        pos = self.data_start
        limit = self.size if self.data_end is None else self.data_end
        for _ in range(max_records):
            if pos + 9 > limit:
                break
            self._f.seek(pos)
            head = self._f.read(9)
            op, length = struct.unpack("<BQ", head)
            if op in (OP_DATA_END, OP_FOOTER) or op == 0 or 0x10 <= op < 0x80 or pos + 9 + length > limit:
                break
            if op == OP_ATTACHMENT and length >= 8 + 8 + 4:
                head = self._f.read(min(length, 8 + 8 + 4 + 1024 + 4 + 1024))
                try:
                    lt, ct = struct.unpack_from("<QQ", head)
                    n = struct.unpack_from("<I", head, 16)[0]
                    name = bytes(head[20:20 + n]).decode("utf-8") if 20 + n <= len(head) else ""
                    m = struct.unpack_from("<I", head, 20 + n)[0]
                    media = bytes(head[24 + n:24 + n + m]).decode("utf-8") if 24 + n + m <= len(head) else ""
                except (struct.error, UnicodeDecodeError):
                    name = media = ""
                    lt = ct = 0
                if name:
                    out.append(AttachmentIndex(offset=pos, length=9 + length, log_time=lt, create_time=ct,
                                               data_size=-1, name=name, media_type=media))
            pos += 9 + length
        return out

    def read_attachment(self, index: AttachmentIndex, *, max_bytes: int) -> Attachment:
        """The attachment record ``index`` points at, its CRC checked, or :class:`_Bad` saying why not
        (runs past the file, over ``max_bytes``, does not parse, fails its CRC check)."""
        if index.length > max_bytes + (1 << 16):  # the data, plus its name, media type and times
            raise _Bad(f"is a record of {index.length} bytes, more than the cap of {max_bytes}")
        rec = self._read_record_at(index.offset, expect_len=index.length)
        if rec is None:
            raise _Bad("runs past the end of the file")
        op, body = rec
        if op != OP_ATTACHMENT:
            raise _Bad(f"no attachment record at byte {index.offset} (opcode 0x{op:02x})")
        att: Attachment = parse_record(OP_ATTACHMENT, body)
        if len(att.data) > max_bytes:
            raise _Bad(f"holds {len(att.data)} bytes, more than the cap of {max_bytes}")
        crc = struct.unpack_from("<I", body, len(body) - 4)[0]
        if crc != 0 and crc32(body[: len(body) - 4]) != crc:
            raise _Bad("fails its CRC check")
        att.data = bytes(att.data)  # not a view of the pooled buffer
        return att

    def _chunk_at(self, ref: _ChunkRef) -> list[tuple[int, object]]:
        """Read (``os.pread``: safe from any thread), decompress, CRC-check and parse a chunk."""
        body = memoryview(self.pool.get(ref.length))  # type: ignore[arg-type]  # an ndarray is a buffer
        if hasattr(os, "preadv"):
            got = os.preadv(self._f.fileno(), [body], ref.offset + 9)
        else:  # pragma: no cover - Windows: a handle of its own
            with open(self.path, "rb") as f:
                f.seek(ref.offset + 9)
                got = f.readinto(body)
        if got != ref.length:
            raise _Bad(f"runs past the end of the file ({got} of {ref.length} bytes)")
        return self._chunk_records(body)

    def _chunk_records(self, body: memoryview, where: str = "") -> list[tuple[int, object]]:
        """Decompress, CRC-check and parse one chunk: [(opcode, record)], or raise :class:`_Bad`."""
        chunk = parse_record(OP_CHUNK, body)
        crc = chunk.uncompressed_crc
        mv = decompress(chunk.compression, chunk.data, chunk.uncompressed_size, pool=self.pool,
                        max_size=self.max_chunk_bytes)
        if crc != 0 and crc32(mv) != crc:
            raise _Bad("fails its CRC check")
        records = []
        pos = 0
        end = len(mv)
        while pos < end:
            if pos + 9 > end:
                raise _Bad(f"has a partial record at {pos}")
            op, length = struct.unpack_from("<BQ", mv, pos)
            if pos + 9 + length > end:
                raise _Bad(f"record at {pos} claims {length} bytes, past the chunk end")
            if op in (OP_MESSAGE, OP_SCHEMA, OP_CHANNEL):
                records.append((op, parse_record(op, mv, pos + 9, pos + 9 + length)))
            pos += 9 + length
        return records

    # ------------------------------------------------------------------ scanning
    def records(
        self, damage: list[Damage], *, prefetch: int = PREFETCH, start_offset: int | None = None,
        cached: dict[tuple[int, int], list[tuple[int, object]]] | None = None, ahead_until: int | None = None,
    ) -> Iterator[tuple[int, object]]:
        """Yield (opcode, parsed record) for Schema, Channel, Message and Metadata records in file
        order, chunk contents included.

        Damage is appended to ``damage`` as :class:`~replay.logs.damage.Damage` records; the scan
        then resumes at the next chunk the summary knows about, or stops. ``start_offset`` starts
        the scan at a record (a chunk found through the summary) instead of the beginning. Up to
        ``prefetch`` chunks (and at most :data:`PREFETCH_BYTES` uncompressed bytes beyond the first)
        are read, decompressed and CRC-checked ahead in worker threads, overlapping with the
        caller's work; 0 does all of it in the calling thread. ``cached`` maps (offset, record
        length) of chunks already parsed by :meth:`chunk_records_at` to their records (used instead
        of reading them again; entries are removed as they are used). ``ahead_until``: a chunk that starts
        after this byte is not read ahead but in the calling thread when the caller comes to it (a pass
        that ends before it, e.g. a frame range, never reads it); the records are the same.
        """
        queue: deque[tuple[int, int, object, int]] = deque()
        workers = max(1, min(prefetch, os.cpu_count() or 1))
        pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="mcap-chunks") if prefetch > 0 else None
        ahead = 0  # uncompressed bytes of the queued chunks
        notes: list[Damage] = []  # the scan's damage records, queued so they keep their place in file order
        try:
            for pos, op, body in self._outer(notes, start_offset, lazy=pool is not None):
                queue.extend((pos, _OP_NOTE, note, 0) for note in notes)
                notes.clear()
                size = 0
                if op == OP_CHUNK:
                    key = (pos, body.length if isinstance(body, _ChunkRef) else len(body))
                    job: object = cached.pop(key, None) if cached else None  # None: not kept
                    if job is None and pool is not None and (ahead_until is None or pos <= ahead_until):
                        job = pool.submit(self._chunk_at, body)  # type: ignore[arg-type]  # lazy: a _ChunkRef
                        size = min(body.usize, self.max_chunk_bytes)  # type: ignore[union-attr]  # lazy: a _ChunkRef
                    elif job is None:
                        job = body  # read when the caller comes to it (a _ChunkRef when lazy)
                else:
                    job = body
                queue.append((pos, op, job, size))
                ahead += size
                while len(queue) > max(prefetch, 0) or (len(queue) > 1 and ahead - queue[0][3] > PREFETCH_BYTES):
                    pos0, op0, job0, size0 = queue.popleft()
                    ahead -= size0
                    yield from self._finish(pos0, op0, job0, damage)
            queue.extend((0, _OP_NOTE, note, 0) for note in notes)
            while queue:
                pos0, op0, job0, _ = queue.popleft()
                yield from self._finish(pos0, op0, job0, damage)
        finally:
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)

    def chunk_records_at(self, offset: int, length: int) -> list[tuple[int, object]]:
        """Records of the chunk at ``offset`` whose record is ``length`` bytes long (from a chunk
        index): [(opcode, record)] or raise :class:`_Bad`."""
        rec = self._read_record_at(offset, expect_len=length)
        if rec is None:
            raise _Bad("chunk runs past the end of the file")
        if rec[0] != OP_CHUNK:
            raise _Bad(f"no chunk record at offset {offset} (opcode 0x{rec[0]:02x})")
        return self._chunk_records(rec[1])

    def _finish(self, pos: int, op: int, job: object, damage: list[Damage]) -> Iterator[tuple[int, object]]:
        if op == _OP_NOTE:
            damage.append(job)  # type: ignore[arg-type]  # the op names the job's type
            return
        if op == OP_LOST:
            yield OP_LOST, Lost(pos, self.lost_messages(pos))
            return
        try:
            if op == OP_CHUNK:
                if isinstance(job, Future):
                    recs = job.result()
                elif isinstance(job, list):
                    recs = job
                elif isinstance(job, _ChunkRef):  # not read ahead (past ``ahead_until``)
                    recs = self._chunk_at(job)
                else:
                    recs = self._chunk_records(job)  # type: ignore[arg-type]  # the op names the job's type
            else:
                recs = [(op, parse_record(op, job))] if op in _INNER else []  # type: ignore[arg-type]  # the op names the job's type
        except _Bad as e:
            what = "chunk" if op == OP_CHUNK else "record"
            damage.append(Damage(DamageKind.DAMAGED_CHUNK,
                                 f"{what} at byte {pos} is corrupt ({e}); its messages are lost", byte=pos))
            if op == OP_CHUNK:
                yield OP_LOST, Lost(pos, self.lost_messages(pos))
            return
        yield from recs

    def message_index(self, offset: int) -> tuple[int, list[int]] | None:
        """(channel id, log times) of the MessageIndex record at ``offset``; None if damaged."""
        try:
            rec = self._read_record_at(offset)
            if rec is None or rec[0] != OP_MESSAGE_INDEX:
                return None
            mi = parse_record(OP_MESSAGE_INDEX, rec[1])
        except _Bad:
            return None
        return mi.channel_id, [t for t, _ in mi.records]

    def message_index_count(self, offset: int) -> int | None:
        """Number of entries of the MessageIndex record at ``offset`` (None if it is damaged)."""
        got = self.message_index(offset)
        return None if got is None else len(got[1])

    def lost_messages(self, chunk_start: int) -> dict[int, list[int]] | None:
        """Log times of the messages per channel in the chunk at ``chunk_start``, from its
        message indexes (the summary's chunk index, else the MessageIndex records right after
        the chunk); None if unknown."""
        out: dict[int, list[int]] = {}
        try:
            offsets: list[int] = []
            known = self.summary.chunk_indexes if self.summary else []
            ci = next((c for c in known if c.chunk_start_offset == chunk_start), None)
            if ci is not None:
                offsets = sorted(ci.message_index_offsets.values())
            else:
                self._f.seek(chunk_start)
                head = self._f.read(9)
                if len(head) < 9:
                    return None
                at = chunk_start + 9 + struct.unpack_from("<Q", head, 1)[0]
                while True:
                    rec = self._read_record_at(at)
                    if rec is None or rec[0] != OP_MESSAGE_INDEX:
                        break
                    offsets.append(at)
                    at += 9 + len(rec[1])
                if not offsets:
                    return None
            for off in offsets:
                got = self.message_index(off)
                if got is None:
                    return None
                out.setdefault(got[0], []).extend(got[1])
        except _Bad:
            return None
        return out

    def _outer(
        self, damage: list[Damage], start_offset: int | None = None, *, lazy: bool = False,
    ) -> Iterator[tuple[int, int, memoryview | _ChunkRef]]:
        """(offset, opcode, body) of the data-section records zcut needs, with damage handling.
        With ``lazy``, a chunk's body is not read: a :class:`_ChunkRef` says where it is."""
        resume = sorted(c.chunk_start_offset for c in self.summary.chunk_indexes) if self.summary else []
        resume_set = set(resume)
        pos = self.data_start if start_offset is None else start_offset
        limit = self.size if self.data_end is None else self.data_end

        def bad(at: int, message: str, kind: DamageKind = DamageKind.DAMAGED_CHUNK) -> None:
            damage.append(Damage(kind, message, byte=at))

        while True:
            if pos + 9 > limit:
                if self.data_end is None:
                    bad(pos, f"{self.path.name} is truncated: it ends at byte {self.size} inside the "
                        "data section (no DataEnd/Footer record)", DamageKind.TRUNCATED)
                return
            self._f.seek(pos)
            head = self._f.read(33)  # opcode, length and (for a chunk) the uncompressed size
            op, length = struct.unpack_from("<BQ", head)
            nxt = pos + 9 + length
            i = bisect.bisect_right(resume, pos)  # the next chunk the summary knows about
            later = resume[i : i + 1]
            if op in (OP_DATA_END, OP_FOOTER):
                if self.data_end is None or nxt >= self.data_end:
                    return
                bad(
                    pos, f"unexpected end-of-data record at byte {pos}"
                    + (f"; skipped to the next chunk at byte {later[0]}" if later else "")
                )
                if not later:
                    return
                if pos in resume_set:
                    yield pos, OP_LOST, memoryview(b"")
                pos = later[0]
                continue
            if op == 0 or 0x10 <= op < 0x80:  # reserved opcodes: not MCAP, the bytes are damaged
                bad(
                    pos, f"invalid record opcode 0x{op:02x} at byte {pos}"
                    + (f"; skipped to the next chunk at byte {later[0]}" if later else "; the rest is lost")
                )
                if not later:
                    return
                if pos in resume_set:  # a chunk the summary knows: count what it held
                    yield pos, OP_LOST, memoryview(b"")
                pos = later[0]
                continue
            wanted = op in (OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_METADATA, OP_CHUNK)
            if nxt <= limit and length > self.max_chunk_bytes and wanted and not (later and nxt > later[0]):
                # an intact-looking record too large to hold: skip it whole (the next one follows)
                what = "chunk" if op == OP_CHUNK else "record"
                bad(
                    pos, f"{what} at byte {pos} holds {length} bytes, more than the cap of "
                    f"{self.max_chunk_bytes}; skipped"
                )
                if op == OP_CHUNK:
                    yield pos, OP_LOST, memoryview(b"")
                pos = nxt
                continue
            if later and nxt > later[0] and nxt <= limit:
                # a (corrupt) length that would swallow a chunk the summary knows about
                bad(
                    pos, f"record at byte {pos} claims {length} bytes, over the chunk at byte {later[0]}; "
                    f"skipped to the next chunk at byte {later[0]}"
                )
                if pos in resume_set:
                    yield pos, OP_LOST, memoryview(b"")
                pos = later[0]
                continue
            if nxt > limit:
                if later:
                    bad(
                        pos, f"record at byte {pos} claims {length} bytes, past the end of the data; "
                        f"skipped to the next chunk at byte {later[0]}"
                    )
                    if pos in resume_set:  # a chunk the summary knows: count what it held
                        yield pos, OP_LOST, memoryview(b"")
                    pos = later[0]
                    continue
                if self.data_end is None:
                    bad(pos, f"{self.path.name} is truncated: the record at byte {pos} needs {length} "
                        f"bytes but only {max(self.size - pos - 9, 0)} remain", DamageKind.TRUNCATED)
                else:
                    bad(
                        pos, f"record at byte {pos} claims {length} bytes, past the end of the data "
                        "section; the rest of the data section is lost"
                    )
                return
            if op == OP_CHUNK and lazy:
                usize = struct.unpack_from("<Q", head, 25)[0] if len(head) == 33 and length >= 24 else 0
                yield pos, op, _ChunkRef(pos, length, usize)
            elif wanted:
                self._f.seek(pos + 9)
                yield pos, op, memoryview(self._f.read(length))
            pos = nxt
