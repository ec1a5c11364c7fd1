"""A log's identity without reading every byte: the SHA-256 of what the MCAP file says about its own
content (its summary section, and the CRC each chunk and attachment carries of its bytes).

``zcut compare`` plans its logs with it (``studies.driver.plan_logs(identify=log_identity)``): a resumed
comparison whose log changed under the same path is refused, and ``zcut annotate --disagreement`` tells
the compared log by it, without hashing the whole file (~86 CPU-ms for a 127 MB log of four 1920 x 1200
frames, before the first frame ran).

What is hashed, in this order (``zcut-log-identity-1`` first):

- the file's size;
- the data section's end record (its ``data_section_crc``, when the writer computed one, covers every
  byte of the data section);
- the whole summary section and footer (schemas, channels, statistics, and per chunk its offset, length,
  time range, sizes and compression; the attachment and metadata indexes);
- each chunk record's header as it stands in the data section, its ``uncompressed_crc`` included (the
  CRC-32 of the chunk's records: any changed message changes it);
- each attachment's CRC-32 (an attachment without one: its whole record), each metadata record whole.

Where the file cannot vouch for its content that way (no summary, no chunk index, a chunk or record
whose CRC is 0 = not computed, anything that does not parse), the identity is the SHA-256 of every
byte, as :func:`file_sha256` computes it. Limit: a chunk's compressed bytes overwritten in place
while its recorded CRC stays the same keep the identity; reading that chunk then fails its CRC (the
frame is lost with a warning, as any damaged chunk).
"""

from __future__ import annotations

import hashlib
import io
import os
import struct
from typing import Any, BinaryIO

__all__ = ["IDENTITY_VERSION", "file_sha256", "log_identity", "sha256_of_stream"]

#: Hashed first: another recipe is another identity.
IDENTITY_VERSION = b"zcut-log-identity-1"

_MAGIC = b"\x89MCAP0\r\n"
_FOOTER = 1 + 8 + 8 + 8 + 4  # opcode, length, summary_start, summary_offset_start, summary_crc
_DATA_END = 1 + 8 + 4  # opcode, length, data_section_crc
_CHUNK_HEAD = 1 + 8 + 8 + 8 + 8 + 4  # opcode, length, start and end time, uncompressed size and CRC
_OP_DATA_END, _OP_CHUNK, _OP_ATTACHMENT, _OP_METADATA = 0x0F, 0x06, 0x09, 0x0C


def sha256_of_stream(f: BinaryIO, *, chunk_bytes: int = 1 << 22) -> str:
    """Hex SHA-256 of the bytes of an open binary file from its position to its end, read in pieces of
    ``chunk_bytes`` (never the whole file in memory)."""
    h = hashlib.sha256()
    while b := f.read(chunk_bytes):
        h.update(b)
    return h.hexdigest()


def file_sha256(path: str | os.PathLike[str]) -> str:
    """Hex SHA-256 of every byte of the file (read in 4 MB pieces)."""
    with open(path, "rb") as f:
        return sha256_of_stream(f)


def log_identity(path: str | os.PathLike[str]) -> str:
    """Hex SHA-256 identifying the log at ``path`` by its MCAP summary and CRCs (module notes); the
    SHA-256 of every byte where the file cannot vouch for its content.

    Raises
    ------
    OSError
        The file cannot be read.
    """
    with open(path, "rb") as f:
        got = _indexed_identity(f, os.fstat(f.fileno()).st_size)
    return got if got is not None else file_sha256(path)


def _indexed_identity(f: io.BufferedReader, size: int) -> str | None:
    from mcap.exceptions import McapError
    from mcap.records import AttachmentIndex, ChunkIndex, MetadataIndex
    from mcap.stream_reader import StreamReader

    tail = _FOOTER + len(_MAGIC)
    if size < len(_MAGIC) + tail:
        return None
    f.seek(size - tail)
    footer = f.read(tail)
    if footer[_FOOTER:] != _MAGIC or footer[0] != 0x02:
        return None
    summary_start = struct.unpack_from("<Q", footer, 9)[0]
    if not len(_MAGIC) + _DATA_END <= summary_start < size - tail:
        return None
    f.seek(summary_start - _DATA_END)
    data_end = f.read(_DATA_END)
    summary = f.read(size - summary_start)
    if data_end[0] != _OP_DATA_END:
        return None
    try:
        records = list(StreamReader(io.BytesIO(summary), skip_magic=True, emit_chunks=True).records)
    except (McapError, ValueError, struct.error, EOFError):
        return None
    chunks = [r for r in records if isinstance(r, ChunkIndex)]
    if not chunks:
        return None
    h = hashlib.sha256(IDENTITY_VERSION)
    h.update(struct.pack("<Q", size))
    h.update(data_end)
    h.update(summary)
    for c in sorted(chunks, key=lambda c: c.chunk_start_offset):
        f.seek(c.chunk_start_offset)
        head = f.read(_CHUNK_HEAD)
        if len(head) < _CHUNK_HEAD or head[0] != _OP_CHUNK or struct.unpack_from("<I", head, 33)[0] == 0:
            return None  # not a chunk where the index says, or its CRC not computed
        h.update(head)
    for r in records:
        if isinstance(r, AttachmentIndex):
            f.seek(r.offset + r.length - 4)
            crc = f.read(4)
            if len(crc) < 4:
                return None
            if crc == b"\0\0\0\0":  # no CRC: the attachment itself
                if not _whole_record(f, h, r.offset, r.length, _OP_ATTACHMENT):
                    return None
            else:
                h.update(crc)
        elif isinstance(r, MetadataIndex) and not _whole_record(f, h, r.offset, r.length, _OP_METADATA):
            return None
    return h.hexdigest()


def _whole_record(f: io.BufferedReader, h: Any, offset: int, length: int, opcode: int) -> bool:
    f.seek(offset)
    rec = f.read(length)
    if len(rec) < length or not rec or rec[0] != opcode:
        return False
    h.update(rec)
    return True

