"""What a pass over a log's frames knows of the log: :class:`LogIndex`.

:class:`~replay.logs.reader.LogReader` opens a log, chooses its topics and builds a :class:`LogIndex`
for every pass (:meth:`~replay.logs.reader.LogReader.frames`); the
:class:`~replay.logs.stream.FrameStream` reads the file through it alone. So the stream needs nothing
of the reader, and the chunk index the reader answers ``chunk_frame_ranges`` from is the one a pass
seeks with.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from mcap.records import Channel, Schema

from replay.logs.damage import Damage
from replay.logs.files import CHUNK_SLACK_BYTES
from replay.logs.mcap_scan import BufferPool, McapFile, _Bad


def open_mcap(path: Path, max_message_bytes: int, pool: BufferPool | None = None) -> McapFile:
    """The log opened for scanning, a chunk capped at ``max_message_bytes`` plus
    :data:`~replay.logs.files.CHUNK_SLACK_BYTES` uncompressed; its buffers from ``pool`` when given."""
    return McapFile(path, max_chunk_bytes=max_message_bytes + CHUNK_SLACK_BYTES, pool=pool)


@dataclass(frozen=True, slots=True)
class LogIndex:
    """A log as one pass over its frames reads it: the file, the topics chosen, the records known
    from opening it and the resource caps.

    Attributes
    ----------
    path : Path
    cloud_topic : str
        The topic driving the frames (``/zcut/valid`` when ``cloudless``).
    image_topic, info_topic : str or None
    mask_topics : tuple[str, ...]
    cloudless : bool
        A results file without its cloud: its frames are driven by ``/zcut/valid`` and have no points.
    max_pixels, max_message_bytes : int
        The caps of :class:`~replay.logs.reader.LogReader`.
    schemas, channels : mapping
        Known at open (from the summary, or the records scanned to find the first messages).
    has_summary : bool
        The log has an intact summary (its message counts are trusted).
    n_frames : int or None
        Clouds on ``cloud_topic`` according to the summary.
    open_damage : tuple[Damage, ...]
        Damage found at open: every pass starts its records with it.
    metadata : dict
        The reader's MCAP metadata records; a pass over a log without a summary fills it as it
        meets them (the reader sees them).
    chunks : dict
        Chunks parsed while opening, by (offset, record length), handed to the first pass only.
    depth_topic : str or None
        A ``32FC1`` Image topic whose message of each frame's stamp the pass delivers in
        :attr:`~replay.logs.frame.Frame.truth_depth_m` (``LogReader(truth_depth=True)``), else None.
    pool : BufferPool or None
        The reader's buffers (its chunks' and its frames' images), shared by its passes; None: each
        pass its own.
    """

    path: Path
    cloud_topic: str
    image_topic: str | None
    info_topic: str | None
    mask_topics: tuple[str, ...]
    cloudless: bool
    max_pixels: int
    max_message_bytes: int
    schemas: Mapping[int, Schema]
    channels: Mapping[int, Channel]
    has_summary: bool
    n_frames: int | None
    open_damage: tuple[Damage, ...]
    metadata: dict[str, dict[str, str]]
    chunks: dict[tuple[int, int], list[tuple[int, object]]] = field(default_factory=dict)
    depth_topic: str | None = None
    pool: BufferPool | None = None

    def open(self) -> McapFile:
        """The log opened for scanning (a context manager)."""
        return open_mcap(self.path, self.max_message_bytes, self.pool)

    def _cloud_counts(self, mf: McapFile) -> Iterator[tuple[int, int] | None]:
        """(chunk offset, clouds in it) per chunk of the summary's chunk index, in file order, read
        lazily from the message indexes; None when a count cannot be read (then stop)."""
        cloud_ids = {cid for cid, ch in self.channels.items() if ch.topic == self.cloud_topic}
        assert mf.summary is not None
        for ci in mf.summary.chunk_indexes:
            n = 0
            for cid, off in ci.message_index_offsets.items():
                if cid in cloud_ids:
                    got = mf.message_index_count(off)
                    if got is None:
                        yield None
                        return
                    n += got
            yield ci.chunk_start_offset, n

    def chunk_frame_ranges(self) -> list[tuple[int, int]] | None:
        """The cloud index range ``(start, stop)`` of every chunk that holds clouds, in file order,
        from the summary's chunk and message indexes; None when the log has no usable index."""
        out: list[tuple[int, int]] = []
        try:
            with self.open() as mf:
                if mf.summary is None or not mf.summary.chunk_indexes:
                    return None
                before = 0
                for got in self._cloud_counts(mf):
                    if got is None:
                        return None
                    n = got[1]
                    if n:
                        out.append((before, before + n))
                    before += n
        except _Bad:
            return None
        return out

    def seek(self, k: int) -> tuple[int | None, int]:
        """(file offset of the chunk holding the k-th cloud, number of clouds before that chunk),
        from the summary's chunk and message indexes; (None, 0) = scan from the start."""
        try:
            with self.open() as mf:
                if mf.summary is None or not mf.summary.chunk_indexes:
                    return None, 0
                before = 0
                for got in self._cloud_counts(mf):
                    if got is None:
                        return None, 0
                    offset, n = got
                    if before + n > k:
                        return offset, before
                    before += n
        except _Bad:
            pass
        return None, 0
