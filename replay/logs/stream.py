"""One pass over a log's frames: :class:`FrameStream`, what :meth:`LogReader.frames` returns.

The stream scans the log (:meth:`replay.logs.mcap_scan.McapFile.records`), pairs every cloud with
the image, camera info and masks of the same header stamp, and yields :class:`~replay.logs.frame.Frame`
objects in log order. Each loss it meets -- and each one the scanner meets -- is a
:class:`~replay.logs.damage.Damage` record in :attr:`FrameStream.damage`, owned by this pass: a second
pass over the same reader has its own. The records are final once the stream has ended (or been
closed).

The pass is a few named steps, one per kind of record the scan yields::

    _message   a Message: _cloud (number it, decode its header, note a shared stamp) or
               _companion (pair it with a waiting cloud of its stamp, else keep it for a later one)
    _lost_chunk   a lost chunk: name the frames it held (and its companions, whose frames then fail)
    _emit      deliver the waiting frames that are complete (_build: decode the arrays, check sizes)
    _finish    the frames the summary lists but the file does not hold; no frame at all -> error

Pairing (``docs/formats.md``, "Pairing"): a companion belongs to the cloud of its header stamp. A
frame waits for its companions until :data:`PAIRING_WINDOW` later clouds have been read; a complete
frame is delivered once the next cloud has been read (or the log ends), so that a cloud sharing its
stamp is seen while it still waits. Two clouds within :data:`PAIRING_WINDOW` of each other with the
same header stamp cannot be told apart by their companions: when the log has companion topics, both
frames are skipped (:attr:`~replay.logs.damage.DamageKind.DUPLICATE_STAMP`; the later one alone when
the earlier one was already delivered, two clouds back). Clouds before the range and just past it
are read for their stamps, so a frame is paired (or skipped) the same whatever range is read.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from collections.abc import Callable, Generator, Iterator
from dataclasses import dataclass, field
from typing import Any, Self, TypeVar, cast

import numpy as np
from mcap.records import Channel, Message, Metadata, Schema

from replay.errors import LogDamageError, LogFormatError, OverCapError
from replay.logs import layout
from replay.logs import ros2_msgs as rm
from replay.logs.damage import Damage, DamageKind, stamp_text
from replay.logs.files import DEFAULT_MAX_MESSAGE_BYTES
from replay.logs.frame import Frame, LazyArrays
from replay.logs.index import LogIndex
from replay.logs.mcap_scan import (
    OP_CHANNEL,
    OP_LOST,
    OP_MESSAGE,
    OP_METADATA,
    OP_SCHEMA,
    PREFETCH,
    Lost,
    _Bad,
    decompress,
)
from zcut.cloud import Intrinsics
from zcut.errors import ParameterError

T = TypeVar("T")

#: A frame waits for its image, camera info and masks until this many later clouds have arrived.
PAIRING_WINDOW = 2

_ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"


def message_payload(
    data: bytes | memoryview, where: str, max_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
) -> bytes | memoryview:
    """The CDR bytes of a message; rosbag2's per-message compression (``--compression-mode
    message``, zstd) is undone here. The message and its content size are checked against
    ``max_bytes`` first (:class:`~replay.errors.OverCapError`)."""
    if len(data) > max_bytes:
        raise OverCapError(f"{where}: message of {len(data)} bytes, more than the cap of {max_bytes}")
    if bytes(data[:4]) != _ZSTD_MAGIC:
        return data
    import zstandard

    try:
        size = zstandard.frame_content_size(data)
    except zstandard.ZstdError as e:
        raise LogFormatError(f"{where}: damaged zstd-compressed message ({e})") from e
    if size < 0:
        raise LogFormatError(f"{where}: zstd-compressed message without a content size")
    try:
        return decompress("zstd", memoryview(data), size, max_size=max_bytes)
    except _Bad as e:
        raise LogFormatError(f"{where}: zstd-compressed message {e}") from e


#: the PointCloud2 fields :func:`replay.logs.ros2_msgs.cloud_to_arrays` reads colours from
COLOUR_FIELDS = ("rgb", "rgba")


def without_colour(cloud: rm.CloudMsg) -> rm.CloudMsg:
    """The cloud without its colour fields (:data:`COLOUR_FIELDS`), for a decoding of x, y, z only: the
    same bytes, the same checks, the same points (a colour field never makes a cloud unreadable)."""
    if not any(f.name in COLOUR_FIELDS for f in cloud.fields):
        return cloud
    return dataclasses.replace(cloud, fields=tuple(f for f in cloud.fields if f.name not in COLOUR_FIELDS))


def _kind_of(e: LogFormatError) -> DamageKind:
    return DamageKind.OVER_CAP if isinstance(e, OverCapError) else DamageKind.MALFORMED_MESSAGE


#: the decoder of each message type a companion channel may carry, to read its header stamp
_DECODERS: dict[str, Callable[..., rm.CloudMsg | rm.ImageMsg | rm.CameraInfoMsg]] = {
    rm.POINTCLOUD2: rm.decode_cloud, rm.IMAGE: rm.decode_image, rm.CAMERAINFO: rm.decode_camera_info}


def _wrong_schema(have: str | None, expected: str, channel: int) -> str:
    """Why a message of schema ``have`` (None: its channel has none) is not one of its topic's."""
    what = f"a {have} message" if have else "a message without a schema"
    return f"{what} (channel {channel}), not a {expected}"


def _stamp_of(data: bytes | memoryview, schema: str | None, where: str) -> int:
    """The header stamp of a message decoded by its own ``schema``; :class:`LogFormatError` saying
    ``where`` when it is not a type zcut decodes or does not decode."""
    decode = _DECODERS.get(schema or "")
    try:
        if decode is not None:
            return decode(data, where=where).stamp_ns
    except LogFormatError:
        pass
    raise LogFormatError(where)


@dataclass(frozen=True)
class _WrongSchema:
    """Internal: a message on a companion topic whose channel carries another schema than the topic's
    (e.g. an Image on the camera info topic): its frame is skipped (``message`` says why)."""

    stamp_ns: int
    message: str


#: what a waiting frame holds of a companion topic
_Part = rm.ImageMsg | rm.CameraInfoMsg | _WrongSchema


class _Skip(Exception):
    """Internal: a frame that was read cannot be delivered (kind, message, topic)."""

    def __init__(self, kind: DamageKind, message: str, topic: str | None) -> None:
        super().__init__(message)
        self.kind, self.message, self.topic = kind, message, topic


@dataclass
class _Pending:
    """A cloud waiting for its companions (``cloud`` None: a placeholder past the range)."""

    index: int
    stamp: int | None
    cloud: rm.CloudMsg | rm.ImageMsg | None  # an ImageMsg: the /zcut/valid of a results file without its cloud
    log_time: int
    parts: dict[str, _Part] = field(default_factory=dict)
    shares_stamp_with: int | None = None  # another cloud within the window with this header stamp

    def complete(self, companions: list[str]) -> bool:
        return all(t in self.parts for t in companions)

    def missing(self, image: str | None, info: str | None, masks: tuple[str, ...]) -> list[str]:
        return [t for t in (image, info, *masks) if t and t not in self.parts]


class _Sequences:
    """Per-channel message sequence numbers, trusted to find lost messages only while they count
    0, 1, 2, … from the first message of the log (zcut's writer; rosbag2 writes all zeros, which
    turns the check off at the second message)."""

    def __init__(self, *, enabled: bool) -> None:
        self.enabled = enabled
        self.expected: dict[int, int | None] = {}  # None: not trusted

    def gap(self, cid: int, s: int) -> int:
        """Messages missing on channel ``cid`` before one with sequence ``s``."""
        if not self.enabled:
            return 0
        exp = self.expected.get(cid, 0)
        if exp is None:
            return 0
        if s < exp or (cid not in self.expected and s != 0):
            self.expected[cid] = None
            return 0
        self.expected[cid] = s + 1
        return s - exp

    def skip(self, cid: int, n: int) -> None:
        """``n`` messages of ``cid`` were accounted for (a lost chunk's message index)."""
        exp = self.expected.get(cid, 0)
        if exp is not None:
            self.expected[cid] = exp + n


class FrameStream(Iterator[Frame]):
    """The intact frames of a log with ``start <= index < stop``, in log order, read through the
    ``index`` its :class:`~replay.logs.reader.LogReader` built (:meth:`~replay.logs.reader.LogReader.index`).

    Iterate it (or ``next``); :attr:`damage` holds the records of what this pass lost (final once
    the iteration has ended or :meth:`close` was called). Raises :class:`LogDamageError` at the end
    when not one frame of a non-empty range could be delivered. ``decoded``: a frame an earlier pass
    over the same log delivered (the one a session resolved its config from); when this pass comes to
    it (same index and stamp, its checks passed), it is delivered as it is instead of decoded again.
    ``prefetch``: chunks decompressed ahead (the scanner's default when None; 0 for a pass that
    reads a first frame only).
    """

    def __init__(self, index: LogIndex, *, start: int = 0, stop: int | None = None,
                 decoded: Frame | None = None, prefetch: int | None = None) -> None:
        if start < 0 or (stop is not None and stop < start):
            raise ParameterError(f"frames: need 0 <= start <= stop, got start={start}, stop={stop}")
        self._r = index
        self.start, self.stop = start, stop
        self._damage: list[Damage] = list(index.open_damage)
        self._companions = [t for t in (index.image_topic, index.info_topic) if t] + list(index.mask_topics)
        # what a frame waits for: its companions and, when asked, its true depth (never a reason to skip it)
        self._waits = self._companions + ([index.depth_topic] if index.depth_topic else [])
        self._want = {index.cloud_topic, *self._waits}
        self._orphan_limit = 4 * len(self._waits) + 4
        self._pending: list[_Pending] = []
        self._orphans: list[tuple[int, str, _Part]] = []  # (stamp, topic, decoded)
        self._lost_parts: dict[str, set[int]] = {}  # companion topic -> log times of its lost messages
        self._recent: deque[tuple[int, int]] = deque(maxlen=PAIRING_WINDOW)  # (index, stamp) of the last clouds
        self._schemas = dict(index.schemas)
        self._channels = dict(index.channels)
        self.delivered = 0
        self._stopped = False  # left the scan before the end of the log
        # seek: begin at the chunk holding cloud start - PAIRING_WINDOW (companions may precede)
        self._begin, self._next_index = index.seek(max(0, start - PAIRING_WINDOW)) if start > 0 else (None, 0)
        # and no chunk past the one holding cloud stop + 1 is read ahead: the pass has ended by then (its last
        # frame is due once the next cloud has been read, or the window after it is full), unless a frame
        # still waits, and then those chunks are read as it comes to them
        self._ahead_until = index.seek(stop + 1)[0] if stop is not None and stop >= start else None
        # sequence numbers find clouds lost without a trace when there is no intact summary
        self._seq = _Sequences(enabled=not index.has_summary and self._begin is None)
        # a chunk of unknown content was lost after this frame: its record, until a sequence gap says more
        self._unknown_loss: list[Damage] = []
        self._decoded = decoded
        # a frame's images are decoded into the reader's pooled memory (reused once a frame is gone)
        self._alloc: rm.Alloc = index.pool.array if index.pool is not None else np.empty
        self._prefetch = PREFETCH if prefetch is None else prefetch
        self._gen = self._scan()

    # ------------------------------------------------------------------ iteration
    @property
    def damage(self) -> tuple[Damage, ...]:
        """What this pass lost so far, in the order met (final once it has ended)."""
        return tuple(self._damage)

    def __iter__(self) -> Self:
        return self

    def __next__(self) -> Frame:
        return next(self._gen)

    def close(self) -> None:
        """Stop reading (the file is closed); :attr:`damage` is then final."""
        self._gen.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ the steps
    def _scan(self) -> Generator[Frame, None, None]:
        r = self._r
        with r.open() as mf:
            cached = dict(r.chunks)  # this pass's alone: not held once the scan has ended
            r.chunks.clear()
            if self._begin is not None:  # chunks before the seek target are never reached
                cached = {k: v for k, v in cached.items() if k[0] >= self._begin}
            for op, rec in mf.records(self._damage, prefetch=self._prefetch, start_offset=self._begin,
                                      cached=cached, ahead_until=self._ahead_until):  # the op names the record's type
                if op == OP_MESSAGE:
                    yield from self._message(cast(Message, rec))
                    if self._stopped:
                        break
                elif op == OP_LOST:
                    self._lost_chunk(cast(Lost, rec))
                elif op == OP_CHANNEL:
                    channel = cast(Channel, rec)
                    self._channels[channel.id] = channel
                elif op == OP_SCHEMA:
                    schema = cast(Schema, rec)
                    self._schemas[schema.id] = schema
                elif op == OP_METADATA:
                    meta = cast(Metadata, rec)
                    r.metadata.setdefault(meta.name, meta.metadata)
            yield from self._emit(final=True)
        self._finish()

    def _message(self, rec: Message) -> Iterator[Frame]:
        ch = self._channels.get(rec.channel_id)
        if ch is None or ch.topic not in self._want:
            return
        if ch.topic == self._r.cloud_topic:
            yield from self._cloud(rec, ch)
        else:
            self._companion(rec, ch)
            yield from self._emit(final=False)

    def _cloud(self, rec: Message, ch: Channel) -> Iterator[Frame]:
        """Number the cloud (a sequence gap first names the clouds lost before it), decode its header
        and wait for its companions. A message whose channel carries another schema than the topic's is
        a frame that does not decode."""
        topic = ch.topic
        gap = self._seq.gap(rec.channel_id, rec.sequence)
        if gap:
            self._lose(self._next_index, gap, f"lost: {topic} message sequence jumps from "
                       f"{rec.sequence - gap - 1} to {rec.sequence} (a chunk is missing)")
            self._next_index += gap
            if self._unknown_loss:  # the gap says how many the unknown chunk held
                note = self._unknown_loss.pop()
                self._damage[:] = [d for d in self._damage if d is not note]
        idx = self._next_index
        self._next_index += 1
        if idx < self.start - PAIRING_WINDOW:
            return
        where = f"{self._r.path.name}: topic {topic}, message {idx}"
        try:
            data = message_payload(rec.data, where, self._r.max_message_bytes)
            expected = rm.IMAGE if self._r.cloudless else rm.POINTCLOUD2
            sc = self._schemas.get(ch.schema_id)
            have = sc.name if sc is not None else None
            if have != expected:
                raise LogFormatError(f"{where}: {_wrong_schema(have, expected, ch.id)}")
            cloud = rm.decode_image(data, where=where) if self._r.cloudless else rm.decode_cloud(data, where=where)
        except LogFormatError as e:
            cloud = None
            if self._in_range(idx):
                self._damage.append(Damage(_kind_of(e), str(e), frame_index=idx, n_frames=1,
                                           log_time_ns=rec.log_time, topic=topic))
                return
        stamp = None if cloud is None else cloud.stamp_ns
        shares = None if cloud is None else self._note_stamp(idx, cloud.stamp_ns)
        if idx < self.start:
            return  # read for its stamp only
        if self.stop is not None and idx >= self.stop:
            # past the range: only counts towards the pairing window
            self._pending.append(_Pending(idx, stamp, None, rec.log_time))
            yield from self._emit(final=False)
            if self._pending[0].cloud is None:
                self._stopped = True
            return
        assert cloud is not None  # in range: a cloud that does not decode returned above
        p = _Pending(idx, cloud.stamp_ns, cloud, rec.log_time, shares_stamp_with=shares)
        keep = []
        for o in self._orphans:
            if o[0] == cloud.stamp_ns and (o[1] not in p.parts or isinstance(o[2], _WrongSchema)):
                p.parts[o[1]] = o[2]
            else:
                keep.append(o)
        self._orphans[:] = keep
        self._pending.append(p)
        yield from self._emit(final=False)

    def _note_stamp(self, idx: int, stamp: int) -> int | None:
        """Remember the cloud's stamp; the index of an earlier cloud within the window with the same
        stamp (the waiting one, if any, is marked as sharing it too), else None. Only a log with
        companion topics pairs by stamp: without them a shared stamp harms nothing."""
        other = None
        if self._companions:
            for i, s in self._recent:
                if s == stamp:
                    other = i
            if other is not None:
                for p in self._pending:
                    if p.stamp == stamp and p.shares_stamp_with is None:
                        p.shares_stamp_with = idx
        self._recent.append((idx, stamp))
        return other

    def _companion(self, rec: Message, ch: Channel) -> None:
        """Decode an image, camera info or mask and give it to the waiting cloud of its stamp, or keep
        it for a cloud still to come. A message whose channel carries another schema than the topic's
        (the topics were chosen by the schema of their first channel) is given as a :class:`_WrongSchema`:
        its frame is skipped, whichever message of its topic and stamp came first."""
        topic = ch.topic
        r = self._r
        if topic == r.depth_topic:
            self._depth(rec, ch)
            return
        where = f"{r.path.name}: topic {topic}, message at log time {stamp_text(rec.log_time)}"
        sc = self._schemas.get(ch.schema_id)
        expected = rm.CAMERAINFO if topic == r.info_topic else rm.IMAGE
        have = sc.name if sc is not None else None
        msg: _Part
        try:
            data = message_payload(rec.data, where, r.max_message_bytes)
            if have == rm.CAMERAINFO == expected:
                msg = rm.decode_camera_info(data, where=where)
            elif have == rm.IMAGE == expected:
                msg = rm.decode_image(data, where=where)
            else:
                why = _wrong_schema(have, expected, ch.id)
                stamp = _stamp_of(data, have, f"{where}: {why}")
                msg = _WrongSchema(stamp, f"{r.path.name}: topic {topic}, stamp {stamp_text(stamp)}: {why}")
        except LogFormatError as e:
            self._damage.append(Damage(_kind_of(e), f"{e}; its frame cannot be told (not paired)", topic=topic,
                                       log_time_ns=rec.log_time))
            self._lost_parts.setdefault(topic, set()).add(rec.log_time)
            return
        wrong = isinstance(msg, _WrongSchema)
        for p in self._pending:
            if p.stamp == msg.stamp_ns and (topic not in p.parts or wrong):
                p.parts[topic] = msg
                return
        self._orphans.append((msg.stamp_ns, topic, msg))
        if len(self._orphans) > self._orphan_limit:
            self._orphans.pop(0)

    def _depth(self, rec: Message, ch: Channel) -> None:
        """A true depth image (``index.depth_topic``): given to the waiting cloud of its stamp, or kept for
        a cloud still to come, when it is a little-endian ``32FC1`` Image whose data fills its grid. A
        message that is not is passed over, neither damage nor a reason to skip a frame (the frame has no
        true depth then, as when its log holds none)."""
        sc = self._schemas.get(ch.schema_id)
        if sc is None or sc.name != rm.IMAGE:
            return
        try:
            msg = rm.decode_image(message_payload(rec.data, ch.topic, self._r.max_message_bytes), where=ch.topic)
        except LogFormatError:
            return
        if (msg.encoding != layout.TRUTH_DEPTH_ENCODING or msg.is_bigendian
                or len(msg.data) != 4 * msg.width * msg.height):
            return
        topic = ch.topic
        for p in self._pending:
            if p.stamp == msg.stamp_ns and topic not in p.parts:
                p.parts[topic] = msg
                return
        self._orphans.append((msg.stamp_ns, topic, msg))
        if len(self._orphans) > self._orphan_limit:
            self._orphans.pop(0)

    def _lost_chunk(self, rec: Lost) -> None:
        """Name the frames (and companion messages) of a lost chunk."""
        if rec.log_times is None:
            after = self._next_index - 1
            note = Damage(DamageKind.UNKNOWN_LOSS, f"the number of clouds in the lost chunk is unknown: frame "
                          f"indices after frame {after} may be shifted", frame_index=after, byte=rec.offset)
            self._unknown_loss.append(note)
            self._damage.append(note)
            return
        n = 0
        times: list[int] = []
        for cid, ts in rec.log_times.items():
            ch = self._channels.get(cid)
            if ch is None:
                continue
            self._seq.skip(cid, len(ts))
            if ch.topic == self._r.cloud_topic:
                n += len(ts)
                times += ts
            else:
                self._lost_parts.setdefault(ch.topic, set()).update(ts)
        if n:
            self._lose(self._next_index, n, f"lost with the chunk at byte {rec.offset}", sorted(times),
                       byte=rec.offset)
        self._next_index += n

    def _lose(self, first: int, n: int, why: str, times: list[int] | None = None, *, byte: int | None = None) -> None:
        """Frames ``first .. first + n - 1`` are lost: one record for those in range. ``n`` comes from
        the file (a summary count, a sequence number) and may be absurd: it is never iterated."""
        lo = max(first, self.start)
        hi = first + n if self.stop is None else min(first + n, self.stop)
        if lo >= hi:
            return
        t0 = t1 = None
        if times:
            a, b = lo - first, min(hi - first, len(times))  # their log times
            if a < b:
                t0 = times[a]
                t1 = times[b - 1] if b - a > 1 else None
        self._damage.append(Damage(DamageKind.LOST_FRAMES, why, frame_index=lo, n_frames=hi - lo, log_time_ns=t0,
                                   last_log_time_ns=t1, topic=self._r.cloud_topic, byte=byte))

    def _in_range(self, idx: int) -> bool:
        return idx >= self.start and (self.stop is None or idx < self.stop)

    def _ready(self, final: bool) -> bool:
        """Whether the first waiting frame is due: the log ended, its window is full, or it is complete
        and the next cloud has been read (so that a cloud sharing its stamp is seen first)."""
        pending = self._pending
        if final or len(pending) > PAIRING_WINDOW:
            return True
        if not self._waits:
            return True
        return len(pending) > 1 and pending[0].complete(self._waits)

    def _emit(self, final: bool) -> Iterator[Frame]:
        """Deliver the waiting frames that are due (or name why one cannot be)."""
        while self._pending and self._ready(final):
            if self._pending[0].cloud is None:
                return
            p = self._pending.pop(0)
            if not self._in_range(p.index):
                continue
            try:
                frame = self._build(p)
            except _Skip as e:
                self._damage.append(Damage(e.kind, e.message, frame_index=p.index, n_frames=1, stamp_ns=p.stamp,
                                           topic=e.topic))
                continue
            self.delivered += 1
            yield frame

    def _finish(self) -> None:
        r = self._r
        expected = r.n_frames
        if not self._stopped and self._begin is None and expected is not None and self._next_index < expected:
            self._lose(self._next_index, expected - self._next_index,
                       f"lost: the summary lists {expected} messages on {r.cloud_topic}, "
                       f"the file holds {self._next_index}")
        if self.delivered == 0 and self._damage and (self.stop is None or self.stop > self.start):
            raise LogDamageError(f"{r.path.name}: no frame could be read: "
                                 + "; ".join(d.text for d in self._damage))

    def _build(self, p: _Pending) -> Frame:
        """The frame of a waiting cloud, or :class:`_Skip` naming why it cannot be delivered."""
        r = self._r
        idx = p.index
        cloud = p.cloud
        assert cloud is not None  # _emit delivers no placeholder
        ctopic = r.cloud_topic
        where = f"{r.path.name}: topic {ctopic}, message {idx}"
        if p.shares_stamp_with is not None:
            raise _Skip(DamageKind.DUPLICATE_STAMP,
                        f"its header stamp is also frame {p.shares_stamp_with}'s: images, camera info and masks are "
                        "paired by stamp, so the two frames' cannot be told apart", ctopic)
        if cloud.height <= 1:
            raise _Skip(DamageKind.UNORGANIZED,
                        f"{where}: unorganized cloud (height {cloud.height}, width {cloud.width}); "
                        "zcut needs organized clouds (height > 1)", ctopic)
        shape = (cloud.height, cloud.width)
        parts = p.parts
        for topic in p.missing(r.image_topic, r.info_topic, r.mask_topics):
            gone = self._lost_parts.get(topic, ())
            if p.stamp in gone or p.log_time in gone:
                raise _Skip(DamageKind.LOST_COMPANION, f"{where}: its {topic} message was lost", topic)
        for topic, part in parts.items():
            if isinstance(part, _WrongSchema):
                raise _Skip(DamageKind.MALFORMED_MESSAGE, part.message, topic)
        if self._decoded is not None and (self._decoded.index, self._decoded.stamp_ns) == (idx, p.stamp):
            frame, self._decoded = self._decoded, None  # the same bytes, already decoded and checked
            return frame
        # the masks and codes are checked here and decoded when first read (LazyArrays): a replay's stages read none
        masks: dict[str, np.ndarray | Callable[[], np.ndarray]] = {}
        codes: dict[str, np.ndarray | Callable[[], np.ndarray]] = {}
        # every part is now of its topic's schema (_companion): an Image on the image and mask topics, a
        # CameraInfo on the camera info topic
        img = cast(rm.ImageMsg | None, parts.get(r.image_topic) if r.image_topic else None)
        try:
            valid = None
            if isinstance(cloud, rm.ImageMsg):  # a results file without its cloud: no points
                masks[ctopic] = rm.image_to_mask(cloud, where=where, max_pixels=r.max_pixels)
                xyz, rgb = np.broadcast_to(np.float32(np.nan), (*shape, 3)), None
            else:
                # with an Image paired the frame's colours are the image's (below, or the frame is
                # skipped): the cloud's own colour field is not decoded, only x, y, z (and the valid
                # pixels, in the same pass where the layout allows: the locator reads them)
                xyz, rgb, valid = rm.cloud_to_arrays_valid(cloud if img is None else without_colour(cloud),
                                                           where=where, max_pixels=r.max_pixels, alloc=self._alloc)
        except LogFormatError as e:
            raise _Skip(_kind_of(e), str(e), ctopic) from None
        if img is not None:
            iwhere = f"{r.path.name}: topic {r.image_topic}, stamp {stamp_text(img.stamp_ns)}"
            if (img.height, img.width) != shape:
                raise _Skip(DamageKind.WRONG_SIZE,
                            f"{iwhere}: image is {img.height}x{img.width} but its cloud ({ctopic}, "
                            f"message {idx}) is {shape[0]}x{shape[1]}", r.image_topic)
            try:
                rgb = rm.image_to_rgb(img, where=iwhere, max_pixels=r.max_pixels, alloc=self._alloc)
            except LogFormatError as e:
                raise _Skip(_kind_of(e), str(e), r.image_topic) from None
        intrinsics: Intrinsics | None = None
        info = cast(rm.CameraInfoMsg | None, parts.get(r.info_topic) if r.info_topic else None)
        if info is not None and any(info.k):
            iwhere = f"{r.path.name}: topic {r.info_topic}, stamp {stamp_text(info.stamp_ns)}"
            if (info.height, info.width) != shape:
                raise _Skip(DamageKind.WRONG_SIZE,
                            f"{iwhere}: camera info is for {info.height}x{info.width} but its cloud "
                            f"({ctopic}, message {idx}) is {shape[0]}x{shape[1]}", r.info_topic)
            try:
                intrinsics = rm.camera_info_to_intrinsics(info, where=iwhere)
            except LogFormatError as e:
                raise _Skip(_kind_of(e), str(e), r.info_topic) from None
        for topic in r.mask_topics:
            m = cast(rm.ImageMsg | None, parts.get(topic))
            if m is None:
                continue
            mwhere = f"{r.path.name}: topic {topic}, stamp {stamp_text(m.stamp_ns)}"
            if (m.height, m.width) != shape:
                raise _Skip(DamageKind.WRONG_SIZE,
                            f"{mwhere}: mask is {m.height}x{m.width} but its cloud is {shape[0]}x{shape[1]}", topic)
            try:
                if topic in layout.CODE_TOPICS:
                    codes[topic] = rm.codes_decoding(m, where=mwhere, max_pixels=r.max_pixels, alloc=self._alloc)
                else:
                    masks[topic] = rm.mask_decoding(m, where=mwhere, max_pixels=r.max_pixels, alloc=self._alloc)
            except LogFormatError as e:
                raise _Skip(_kind_of(e), str(e), topic) from None
        depth = None
        d = cast(rm.ImageMsg | None, parts.get(r.depth_topic) if r.depth_topic else None)
        if d is not None and (d.height, d.width) == shape:  # _depth checked its encoding and size
            depth = np.frombuffer(d.data, dtype="<f4").reshape(shape)  # read, not copied
            depth.flags.writeable = False
        return Frame(
            xyz=xyz, rgb=rgb, stamp_ns=cloud.stamp_ns, frame_id=cloud.frame_id,
            intrinsics=intrinsics, topic=ctopic, index=idx, masks=LazyArrays(masks), codes=LazyArrays(codes),
            has_points=not r.cloudless, truth_depth_m=depth,
            decoded_valid=(xyz, valid) if valid is not None else None,
        )


class DerivedStream(Iterator[T]):
    """What is computed from a frame stream (a pipeline result per frame, …), carrying that stream's
    :attr:`damage`: the caller of a derived iteration sees the losses of the pass below it.

    Parameters
    ----------
    items : iterator
        The derived items (a generator over the source; closed by :meth:`close`).
    source : FrameStream or DerivedStream
        Where :attr:`damage` comes from.
    """

    def __init__(self, items: Iterator[T], source: FrameStream | DerivedStream[Any]) -> None:
        self._items = items
        self._source = source

    @property
    def damage(self) -> tuple[Damage, ...]:
        return self._source.damage

    def __iter__(self) -> DerivedStream[T]:
        return self

    def __next__(self) -> T:
        return next(self._items)

    def close(self) -> None:
        close = getattr(self._items, "close", None)
        if close is not None:
            close()
        self._source.close()
