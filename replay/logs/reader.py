"""Stream organized scans out of a ROS 2 MCAP log (docs/formats.md).

:class:`LogReader` opens a log, finds the topics zcut uses (the organized ``PointCloud2``, a colour
``Image`` and a ``CameraInfo`` of the same size, and every ``mono8`` Image of that size as a mask)
and then streams :class:`~replay.logs.frame.Frame` objects (:meth:`LogReader.frames` returns a
:class:`~replay.logs.stream.FrameStream`), pairing each cloud with the other topics by header stamp.
The file is never loaded whole: it is scanned chunk by chunk (see :mod:`replay.logs.mcap_scan`), and
only a bounded window of messages is buffered for the pairing.

The exit-status contract of ``docs/cli.md`` is kept here: damage (a truncated file, a corrupt or
missing chunk, a malformed message, a mask of the wrong size, a cloud over the size caps) does not
stop the stream. A frame that cannot be read is skipped, every intact frame is delivered with the
log's own index (a lost frame leaves a gap), and the stream's ``damage`` holds one
:class:`~replay.logs.damage.Damage` record per loss, naming the frame (index, and its stamp or log
time when known); their texts read, e.g.::

    chunk at byte 5120 is corrupt (fails its CRC check); its messages are lost
    frame 2 (log time 3.000000000) lost with the chunk at byte 5120
    frame 4 (stamp 5.000000000) skipped: topic /camera/points: PointCloud2 row_step 16 is smaller ...
    frame 1 lost: /camera/points message sequence jumps from 0 to 2 (a chunk is missing)

Lost frames are counted from what the file still holds: the summary's chunk indexes and message
counts, the MessageIndex records after each chunk, and the per-channel message sequence numbers
(when they count up, as zcut's writer and recent rosbag2 write them). Anything that makes the log
unusable as a whole (not MCAP, not a regular file, a ROS 1 log, no organized cloud, an ambiguous
cloud topic, an image topic whose size differs from the cloud topic) raises
:class:`~replay.errors.LogFormatError` with a one-line message at open.

Log-level facts that the config resolution needs (:attr:`LogReader.intrinsics`,
:attr:`LogReader.first_shape`) are read once at open from the first intact messages anywhere in
the log, so they do not depend on which frames survive.

Sizes are bounded (see :mod:`replay.logs.files`): ``max_message_bytes`` caps a message, a
compressed message's content and (plus a slack) a chunk before decompression; ``max_pixels`` caps
a cloud's or image's grid before any array is allocated.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, cast

from mcap.records import Channel, Message, Metadata, Schema

from replay.errors import LogDamageError, LogFormatError
from replay.logs import layout
from replay.logs import ros2_msgs as rm
from replay.logs.damage import Damage, DamageKind, stamp_text
from replay.logs.files import CHUNK_SLACK_BYTES, DEFAULT_MAX_MESSAGE_BYTES, DEFAULT_MAX_PIXELS, check_caps
from replay.logs.frame import Frame
from replay.logs.index import LogIndex, open_mcap
from replay.logs.mcap_scan import (
    OP_CHANNEL,
    OP_LOST,
    OP_MESSAGE,
    OP_METADATA,
    OP_SCHEMA,
    BufferPool,
    Lost,
    McapFile,
    _Bad,
)
from replay.logs.ply import PlyModel, read_ply_model_bytes
from replay.logs.stream import PAIRING_WINDOW, FrameStream, message_payload
from zcut.cloud import Intrinsics

if TYPE_CHECKING:
    import numpy as np

__all__ = ["PAIRING_WINDOW", "FrameStream", "LogInfo", "LogReader", "TopicInfo", "inspect_log", "read_mask_topics",
           "stamp_text"]
_PEEK_AFTER_FIRST_CLOUD = 64  # messages scanned past the first cloud when the file has no summary
#: Chunks parsed while opening a log are kept (up to this many uncompressed bytes) for the first
#: :meth:`LogReader.frames` iteration, so that opening and reading the first frame decompress them once.
KEEP_PEEKED_BYTES = 128 << 20
_TYPES = (rm.POINTCLOUD2, rm.IMAGE, rm.CAMERAINFO)


@dataclass
class TopicInfo:
    """What :class:`LogReader` learned about one topic (for ``zcut topics``)."""

    topic: str
    msg_type: str
    message_encoding: str
    count: int | None
    height: int | None = None
    width: int | None = None
    encoding: str | None = None  # Image encoding of the first message
    fields: tuple[str, ...] = ()  # PointCloud2 field names of the first message
    channel_ids: list[int] = field(default_factory=list)
    error: str | None = None  # why no message could be decoded (the first error met)
    first: object | None = None  # the first decodable message (CloudMsg, ImageMsg, CameraInfoMsg)


def _ns(topic: str) -> str:
    return topic.rsplit("/", 1)[0]


def _peek(
    mf: McapFile, schemas: dict[int, Schema], channels: dict[int, Channel],
    metadata: dict[str, dict[str, str]], keep: dict[tuple[int, int], list[tuple[int, object]]] | None = None,
    *, max_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
) -> tuple[dict[int, object], list[Damage]]:
    """First decodable message (header only) of every PointCloud2/Image/CameraInfo channel, or
    the first error when none decodes (channel id -> message or LogFormatError).

    A message that does not decode does not end the search: the next one of its channel is tried
    (in intact chunks anywhere in the log when it has a summary). With ``keep``, the parsed chunks
    (intact ones, up to :data:`KEEP_PEEKED_BYTES`) are stored there by (offset, record length)
    for :meth:`McapFile.records`.
    """
    firsts: dict[int, object] = {}
    errors: dict[int, LogFormatError] = {}
    damage: list[Damage] = []

    def wanted(cid: int) -> bool:
        ch = channels.get(cid)
        if ch is None or ch.message_encoding != "cdr":
            return False
        sc = schemas.get(ch.schema_id)
        return sc is not None and sc.name in _TYPES

    def take(msg: Message) -> None:
        ch = channels[msg.channel_id]
        name = schemas[ch.schema_id].name
        where = f"{mf.path.name}: topic {ch.topic}, message at log time {stamp_text(msg.log_time)}"
        try:
            data = message_payload(msg.data, where, max_bytes)
            if name == rm.POINTCLOUD2:
                firsts[msg.channel_id] = rm.decode_cloud(data, where=where)
            elif name == rm.IMAGE:
                firsts[msg.channel_id] = rm.decode_image(data, where=where)
            else:
                firsts[msg.channel_id] = rm.decode_camera_info(data, where=where)
        except LogFormatError as e:
            errors.setdefault(msg.channel_id, e)

    summary = mf.summary
    if summary is not None and summary.chunk_indexes:
        todo = {cid for cid in channels if wanted(cid)}
        kept = 0
        for ci in summary.chunk_indexes:
            need = todo & set(ci.message_index_offsets)
            if not need:
                continue
            try:
                recs = mf.chunk_records_at(ci.chunk_start_offset, ci.chunk_length)
                for op, rec in recs:
                    msg = cast(Message, rec)  # the op names the record's type
                    if op == OP_MESSAGE and msg.channel_id in need and msg.channel_id not in firsts:
                        take(msg)
                size = sum(len(cast(Message, m).data) for op, m in recs if op == OP_MESSAGE)
                if keep is not None and kept + size <= KEEP_PEEKED_BYTES:
                    keep[(ci.chunk_start_offset, ci.chunk_length - 9)] = recs
                    kept += size
            except _Bad as e:
                at = ci.chunk_start_offset
                damage.append(Damage(DamageKind.DAMAGED_CHUNK, f"chunk at byte {at} is corrupt ({e})", byte=at))
                continue
            todo -= set(firsts)
            if not todo:
                break
        return {**errors, **firsts}, damage
    # no summary (or an unchunked file): scan from the start to a little past the first cloud
    # (at least _PEEK_AFTER_FIRST_CLOUD messages and one second of log time after it)
    after = None
    t_cloud = 0
    for op, rec in mf.records(damage, prefetch=0):  # the op names the record's type
        if op == OP_LOST:
            continue
        if op == OP_SCHEMA:
            schema = cast(Schema, rec)
            schemas[schema.id] = schema
        elif op == OP_CHANNEL:
            channel = cast(Channel, rec)
            channels[channel.id] = channel
        elif op == OP_METADATA:
            meta = cast(Metadata, rec)
            metadata[meta.name] = meta.metadata
        elif op == OP_MESSAGE:
            msg = cast(Message, rec)
            if msg.channel_id not in firsts and wanted(msg.channel_id):
                take(msg)
                if after is None and isinstance(firsts.get(msg.channel_id), rm.CloudMsg):
                    after, t_cloud = 0, msg.log_time
            if after is not None:
                after += 1
                if after > _PEEK_AFTER_FIRST_CLOUD and (
                    msg.log_time > t_cloud + 1_000_000_000 or after > 64 * _PEEK_AFTER_FIRST_CLOUD
                ):
                    break
    return {**errors, **firsts}, damage


@dataclass
class LogInfo:
    """What a log holds, before zcut chooses topics (see :func:`inspect_log`)."""

    path: Path
    profile: str
    library: str
    topics: dict[str, TopicInfo]
    metadata: dict[str, dict[str, str]]
    start_ns: int | None
    end_ns: int | None
    has_summary: bool
    #: what a user is told about the log (the texts of ``damage`` among them)
    notes: list[str]
    #: damage met while finding the first messages
    peek_damage: list[Damage]
    schemas: dict[int, Schema]
    channels: dict[int, Channel]
    #: a damaged summary or metadata record
    damage: list[Damage] = field(default_factory=list)
    #: chunks parsed while peeking, by (offset, record length) (only with ``keep_chunks``)
    chunks: dict[tuple[int, int], list[tuple[int, object]]] = field(default_factory=dict)


def inspect_log(
    path: str | os.PathLike[str], *, keep_chunks: bool = False,
    max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES, pool: BufferPool | None = None,
) -> LogInfo:
    """List the topics of an MCAP log with the size of their first decodable message (no topic
    choice).

    With ``keep_chunks``, :attr:`LogInfo.chunks` keeps the chunks read to find the first messages
    (up to :data:`KEEP_PEEKED_BYTES`) for a following scan; ``pool``: where their buffers come from
    (the reader's, so that they go back to the pool its passes use). ``max_message_bytes`` caps a message
    (and, plus a slack of :data:`~replay.logs.files.CHUNK_SLACK_BYTES`, a chunk). Raises
    :class:`LogFormatError` if the file is not a regular file or not MCAP.
    """
    kept: dict[tuple[int, int], list[tuple[int, object]]] = {}
    path = Path(path)
    metadata: dict[str, dict[str, str]] = {}
    notes: list[str] = []
    damage: list[Damage] = []
    start_ns = end_ns = None
    with McapFile(path, max_chunk_bytes=max_message_bytes + CHUNK_SLACK_BYTES, pool=pool) as mf:
        if mf.summary_damage:
            notes.append(mf.summary_damage.text)
            damage.append(mf.summary_damage)
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        summary = mf.summary
        if summary is not None:
            schemas.update(summary.schemas)
            channels.update(summary.channels)
            metadata, more = mf.read_metadata()
            notes += [d.text for d in more]
            damage += more
            start_ns, end_ns = summary.message_start_time, summary.message_end_time
        firsts, peek_damage = _peek(
            mf, schemas, channels, metadata, kept if keep_chunks else None, max_bytes=max_message_bytes
        )
    counts = summary.channel_message_counts if summary is not None else None
    topics: dict[str, TopicInfo] = {}
    for cid, ch in sorted(channels.items()):
        sc = schemas.get(ch.schema_id)
        msg_type = sc.name if sc is not None else "?"
        info = topics.get(ch.topic)
        n = counts.get(cid, 0) if counts is not None else None
        if info is None:
            info = topics[ch.topic] = TopicInfo(ch.topic, msg_type, ch.message_encoding, n)
        elif n is not None and info.count is not None:
            info.count += n
        info.channel_ids.append(cid)
        got = firsts.get(cid)
        if isinstance(got, LogFormatError):
            if info.first is None and info.error is None:
                info.error = str(got)
            continue
        if got is None or info.first is not None:
            continue
        info.first, info.error = got, None
        if isinstance(got, rm.CloudMsg):
            info.height, info.width = got.height, got.width
            info.fields = tuple(f.name for f in got.fields)
        elif isinstance(got, rm.ImageMsg):
            info.height, info.width, info.encoding = got.height, got.width, got.encoding
        elif isinstance(got, rm.CameraInfoMsg):
            info.height, info.width = got.height, got.width
    return LogInfo(
        path, mf.profile, mf.library, topics, metadata, start_ns, end_ns,
        counts is not None, notes, peek_damage, schemas, channels, damage, kept,
    )


class LogReader:
    """Read organized frames from a ROS 2 MCAP log.

    Parameters
    ----------
    path : str or Path
    cloud_topic, image_topic, info_topic : str or None
        Choose topics explicitly (``--topic``, ``--image-topic``); found automatically when None.
    max_pixels : int
        Largest cloud or image grid (H x W) decoded; a larger one is a skipped frame (checked
        before any array is allocated). Default :data:`~replay.logs.files.DEFAULT_MAX_PIXELS`
        (2**24 = 16.8 Mpx).
    max_message_bytes : int
        Largest message (and decompressed content of a compressed message) read; a chunk may
        hold this plus :data:`~replay.logs.files.CHUNK_SLACK_BYTES` (64 MiB) uncompressed, checked
        before decompressing. Default :data:`~replay.logs.files.DEFAULT_MAX_MESSAGE_BYTES`
        (256 MiB).
    cloudless : bool
        Accept a results file written without its cloud (``zcut replay --out`` without
        ``--out-cloud``, docs/formats.md): its frames are driven by its ``/zcut/valid`` masks, have no
        points (``Frame.has_points`` False, ``xyz`` a read-only all-NaN view) and carry their valid
        pixels in ``masks['/zcut/valid']``. Without it such a file is refused in one line saying how
        to get the cloud (for the commands that need the points).
    truth_depth : bool
        Deliver each frame's ``/ground_truth/depth`` (synthetic and stereo logs) in
        :attr:`Frame.truth_depth_m <replay.logs.frame.Frame>`, paired by stamp like a mask, when the log
        has that topic: decoded from the chunk the pass reads anyway (``zcut compare`` scores the
        displacement classes with it). A frame whose depth message is missing or unusable (not a
        little-endian ``32FC1`` Image of the cloud's size) has None there; it is not skipped for it.

    Attributes
    ----------
    cloud_topic : str
        The topic driving the frames: the organized cloud, or ``/zcut/valid`` when :attr:`cloudless`.
    cloudless : bool
        The file is a results file without its cloud, read with ``cloudless=True``.
    image_topic, info_topic : str or None
    mask_topics : list[str]
        mono8 Image topics of the cloud's size; delivered in :attr:`Frame.masks`.
    depth_topic : str or None
        ``/ground_truth/depth`` when ``truth_depth`` was asked and the log has it as an Image topic.
    metadata : dict[str, dict[str, str]]
        MCAP metadata records (from the summary; for a file without one, filled while iterating).
    n_frames : int or None
        Number of clouds on ``cloud_topic`` according to the summary.
    open_damage : tuple[Damage, ...]
        Damage found at open (a damaged summary or metadata record); each :meth:`frames` pass
        starts its own ``damage`` with it.
    intrinsics : Intrinsics or None
        From the first decodable CameraInfo of ``info_topic`` (anywhere in the log), when it is
        calibrated (K not all zero) and of the cloud's size; the same whatever frames survive.
    first_shape : (int, int)
        (H, W) of the first decodable cloud of ``cloud_topic`` (anywhere in the log).
    topics : dict[str, TopicInfo]
    start_ns, end_ns : int or None
        Log time span from the summary statistics.
    profile, library : str
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        cloud_topic: str | None = None,
        image_topic: str | None = None,
        info_topic: str | None = None,
        max_pixels: int = DEFAULT_MAX_PIXELS,
        max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
        cloudless: bool = False,
        truth_depth: bool = False,
    ) -> None:
        check_caps(max_pixels, max_message_bytes)
        #: the buffers of every pass over this log: its chunks (read, decompressed) and its frames'
        #: decoded images, reused once a frame is gone (fresh ones cost their page faults every frame)
        self.pool = BufferPool()
        self.allow_cloudless = cloudless
        #: a results file written without its cloud, its frames driven by ``/zcut/valid`` (see ``cloudless``)
        self.cloudless = False
        self.max_pixels, self.max_message_bytes = max_pixels, max_message_bytes
        info = inspect_log(path, keep_chunks=True, max_message_bytes=max_message_bytes, pool=self.pool)
        self._chunks = info.chunks  # for the first frames() scan
        #: damage found at open (a damaged summary or metadata record): every pass starts with it
        self.open_damage: tuple[Damage, ...] = tuple(info.damage)
        self._has_summary = info.has_summary
        self.path = info.path
        self.profile, self.library = info.profile, info.library
        self.topics = info.topics
        self.metadata = info.metadata
        self.notes = info.notes
        self.start_ns, self.end_ns = info.start_ns, info.end_ns
        self._schemas, self._channels = info.schemas, info.channels
        self._choose_topics(cloud_topic, image_topic, info_topic, info.peek_damage)
        self.n_frames: int | None = self.topics[self.cloud_topic].count if info.has_summary else None
        t = self.topics[self.cloud_topic]
        # the chosen cloud topic has a decoded first message (_choose_topics refuses one without)
        self.first_shape: tuple[int, int] = cast(tuple[int, int], (t.height, t.width))
        self.intrinsics: Intrinsics | None = self._first_intrinsics()
        depth = self.topics.get(layout.TRUTH_DEPTH)
        self.depth_topic: str | None = (
            layout.TRUTH_DEPTH if truth_depth and not self.cloudless and depth is not None
            and depth.msg_type == rm.IMAGE and depth.message_encoding == "cdr" else None)

    def _mcap(self) -> McapFile:
        return open_mcap(self.path, self.max_message_bytes, self.pool)

    def _first_intrinsics(self) -> Intrinsics | None:
        if self.info_topic is None:
            return None
        msg = self.topics[self.info_topic].first
        if not isinstance(msg, rm.CameraInfoMsg) or not any(msg.k):
            return None
        where = f"{self.path.name}: topic {self.info_topic}, stamp {stamp_text(msg.stamp_ns)}"
        if (msg.height, msg.width) != self.first_shape:
            self.notes.append(
                f"{where}: camera info is for {msg.height}x{msg.width} but the cloud is "
                f"{self.first_shape[0]}x{self.first_shape[1]}; intrinsics not used"
            )
            return None
        try:
            return rm.camera_info_to_intrinsics(msg, where=where)
        except LogFormatError as e:
            self.notes.append(f"{e}; intrinsics not used")
            return None

    # ------------------------------------------------------------------ opening
    def _choose_topics(
        self, cloud_topic: str | None, image_topic: str | None, info_topic: str | None,
        peek_damage: list[Damage],
    ) -> None:
        name = self.path.name
        topics = self.topics
        encodings = {t.message_encoding for t in topics.values()}
        if self.profile == "ros1" or (encodings and encodings <= {"ros1"}):
            raise LogFormatError(
                f"{name} is a ROS 1 log (message encoding ros1); zcut reads ROS 2 logs "
                "(profile ros2, cdr). Convert it first, e.g. with rosbags-convert"
            )
        clouds = [t for t in topics.values() if t.msg_type == rm.POINTCLOUD2 and t.message_encoding == "cdr"]
        organized = [t for t in clouds if t.height is not None and t.height > 1]

        def desc(t: TopicInfo) -> str:
            return f"{t.topic} ({t.height}x{t.width})" if t.height is not None else f"{t.topic} (no messages)"

        if cloud_topic is not None:
            t = topics.get(cloud_topic)
            if t is None or t.msg_type != rm.POINTCLOUD2:
                have = ", ".join(desc(c) for c in clouds) or "none"
                raise LogFormatError(
                    f"{name} has no PointCloud2 topic '{cloud_topic}' (PointCloud2 topics: {have})"
                )
            if t.height is None:
                raise LogFormatError(t.error or f"{name}: topic {cloud_topic} has no readable message")
            if t.height <= 1:
                raise LogFormatError(
                    f"{name}: topic {cloud_topic} holds unorganized clouds (height {t.height}, "
                    f"width {t.width}); zcut needs organized clouds (height > 1)"
                )
            chosen = t
        elif len(organized) == 1:
            chosen = organized[0]
        elif len([t for t in organized if not t.topic.startswith(layout.RESULTS_PREFIX)]) == 1:
            # a results log: the input cloud, not zcut's own /zcut/filtered output
            chosen = next(t for t in organized if not t.topic.startswith(layout.RESULTS_PREFIX))
        elif len(organized) > 1:
            raise LogFormatError(
                f"{name} has several organized PointCloud2 topics: "
                f"{', '.join(desc(t) for t in organized)}; choose one with --topic"
            )
        elif (valid := self._valid_driver()) is not None:
            chosen = valid
            if not self.allow_cloudless:
                raise LogFormatError(
                    f"{name} is a results file written without its cloud ({layout.FILTERED}): this command "
                    "needs the points; give the log, or write the results with zcut replay --out-cloud"
                )
            self.cloudless = True
        else:
            if not topics and peek_damage:
                raise LogDamageError(f"{name} is damaged before its first message: {peek_damage[0].text}")
            if clouds:
                raise LogFormatError(
                    f"{name} has no organized PointCloud2: "
                    + ", ".join(
                        f"{t.topic} has height {t.height} (width {t.width})" if t.height is not None
                        else f"{t.topic} has no readable message" + (f" ({t.error})" if t.error else "")
                        for t in clouds
                    )
                    + "; zcut needs organized clouds (height > 1)"
                )
            if peek_damage and not any(t.msg_type == rm.POINTCLOUD2 for t in topics.values()):
                raise LogDamageError(f"{name} is damaged before its first cloud: {peek_damage[0].text}")
            have = ", ".join(f"{t.topic} [{t.msg_type}]" for t in topics.values()) or "none"
            raise LogFormatError(f"{name} has no sensor_msgs/msg/PointCloud2 topic (topics: {have})")
        self.cloud_topic = chosen.topic
        shape = (chosen.height, chosen.width)

        images = [
            t for t in topics.values()
            if t.msg_type == rm.IMAGE and t.message_encoding == "cdr" and t.encoding in rm.COLOR_ENCODINGS
        ]
        if self.cloudless:
            images = []  # a results file without its cloud has no image either
        if image_topic is not None:
            t = topics.get(image_topic)
            if t is None or t.msg_type != rm.IMAGE:
                have = ", ".join(i.topic for i in images) or "none"
                raise LogFormatError(f"{name} has no Image topic '{image_topic}' (colour images: {have})")
            if t.encoding not in rm.COLOR_ENCODINGS:
                raise LogFormatError(
                    f"{name}: image topic {image_topic} has encoding '{t.encoding}'; "
                    f"zcut pairs colour images ({', '.join(rm.COLOR_ENCODINGS)})"
                )
            img = t
        elif len(images) == 1:
            img = images[0]
        elif len(images) > 1:
            # the cloud's size first, then the cloud's namespace, then the first name
            same = [t for t in images if (t.height, t.width) == shape] or images
            near = [t for t in same if _ns(t.topic) == _ns(self.cloud_topic)] or same
            img = sorted(near, key=lambda t: t.topic)[0]
            self.notes.append(
                f"several colour Image topics ({', '.join(desc(t) for t in images)}); using {img.topic} "
                "(choose with --image-topic)"
            )
        else:
            img = None
        if img is not None and (img.height, img.width) != shape:
            raise LogFormatError(
                f"{name}: image topic {img.topic} is {img.height}x{img.width} but cloud topic "
                f"{self.cloud_topic} is {shape[0]}x{shape[1]}; zcut pairs images of the cloud's size"
            )
        self.image_topic = img.topic if img is not None else None

        infos = [t for t in topics.values() if t.msg_type == rm.CAMERAINFO and t.message_encoding == "cdr"]
        if info_topic is not None:
            if info_topic not in {t.topic for t in infos}:
                have = ", ".join(t.topic for t in infos) or "none"
                raise LogFormatError(f"{name} has no CameraInfo topic '{info_topic}' (CameraInfo topics: {have})")
            self.info_topic: str | None = info_topic
        else:
            fit = [t for t in infos if (t.height, t.width) == shape] or infos
            pref = [_ns(self.image_topic)] if self.image_topic else []
            pref.append(_ns(self.cloud_topic))
            choice = None
            for ns in pref:
                near = [t for t in fit if _ns(t.topic) == ns]
                if near:
                    choice = near[0]
                    break
            if choice is None and fit:
                choice = sorted(fit, key=lambda t: t.topic)[0]
            self.info_topic = choice.topic if choice is not None else None

        self.mask_topics = sorted(
            t.topic for t in topics.values()
            if t.msg_type == rm.IMAGE and t.message_encoding == "cdr" and t.encoding in rm.MASK_ENCODINGS
            and ((t.height, t.width) == shape or t.topic.startswith(layout.MASK_PREFIXES))
            and t.topic != self.cloud_topic
        )

    def _valid_driver(self) -> TopicInfo | None:
        """The ``/zcut/valid`` topic of a results file without an organized cloud, else None."""
        t = self.topics.get(layout.VALID)
        if (t is not None and t.msg_type == rm.IMAGE and t.message_encoding == "cdr" and t.encoding in rm.MASK_ENCODINGS and t.height is not None and t.height > 1):
            return t
        return None

    # ------------------------------------------------------------------ attachments
    def attachments(self) -> list[tuple[str, str, int | None]]:
        """(name, media type, bytes or None when unknown) of every attachment, in file order (from
        the summary; for a log without one, from a walk over its record headers)."""
        with self._mcap() as mf:
            return [(a.name, a.media_type, a.data_size if a.data_size >= 0 else None) for a in mf.attachment_indexes()]

    @functools.cached_property
    def _bin_model_attachment(self) -> tuple[bytes | None, PlyModel | None, str | None]:
        name = layout.BIN_MODEL_ATTACHMENT
        try:
            with self._mcap() as mf:
                found = [a for a in mf.attachment_indexes() if a.name == name]
                if not found:
                    return None, None, None
                att = mf.read_attachment(found[-1], max_bytes=self.max_message_bytes)  # the last one wins
        except _Bad as e:
            return None, None, f"its {name} attachment is damaged ({e})"
        try:
            model = read_ply_model_bytes(att.data, name=f"{self.path.name}: attachment {name}",
                                         max_points=self.max_pixels, max_message_bytes=self.max_message_bytes)
        except LogFormatError as e:
            return None, None, f"its {name} attachment is not a usable bin model ({e})"
        return att.data, model, None

    @property
    def bin_model_ply(self) -> bytes | None:
        """The bin model the log carries: the bytes of its ``bin_model.ply`` attachment (the last one when
        there are several), None when it has none or it cannot be used (see :attr:`bin_model_problem`).
        Read once, on first use: CRC-checked, bounded by ``max_message_bytes`` and parsed by
        :func:`~replay.logs.ply.read_ply_model_bytes` (``docs/formats.md``, "Bin model attachment")."""
        return self._bin_model_attachment[0]

    @property
    def attached_bin_model(self) -> PlyModel | None:
        """:attr:`bin_model_ply` as read by :func:`~replay.logs.ply.read_ply_model_bytes` (points, normals, faces)."""
        return self._bin_model_attachment[1]

    @property
    def bin_model_problem(self) -> str | None:
        """Why the log's ``bin_model.ply`` attachment cannot be used (damaged, not a PLY), else None."""
        return self._bin_model_attachment[2]

    # ------------------------------------------------------------------ streaming
    def frames(self, *, start: int = 0, stop: int | None = None, decoded: Frame | None = None,
               peek: bool = False) -> FrameStream:
        """The intact frames with ``start <= index < stop`` in log order, as a :class:`FrameStream`.

        Each cloud is paired with the image, camera info and masks of the same header stamp that
        arrive within :data:`PAIRING_WINDOW` clouds of it. A frame that cannot be read (its chunk
        lost, a malformed cloud or companion message, a mask of the wrong size, a grid over
        ``max_pixels``, a header stamp another cloud shares) is skipped with a
        :class:`~replay.logs.damage.Damage` record in the stream's ``damage`` that names it; indices
        stay the log's own. Each call is a pass of its own, with its own records (starting with
        :attr:`open_damage`). The stream raises :class:`LogDamageError` if the log is damaged so
        that not one frame of the range could be delivered. ``decoded``: a frame an earlier pass over
        this reader delivered, delivered again as it is (not decoded again) when this pass reaches it.
        ``peek``: a pass that reads a first frame only, before the run: no chunk is decompressed ahead,
        and the chunks parsed while opening serve it and are left to the next pass too.
        """
        return FrameStream(self.index(keep_chunks=peek), start=start, stop=stop, decoded=decoded,
                           prefetch=0 if peek else None)

    def chunk_frame_ranges(self) -> list[tuple[int, int]] | None:
        """The cloud index range ``(start, stop)`` of every chunk that holds clouds, in file order,
        from the summary's chunk and message indexes; None when the log has no usable index (then
        only a scan from the start can number its frames). Used to split a long log into units of
        whole chunks that read independently (``zcut batch``)."""
        return self.index(first_pass=False).chunk_frame_ranges()

    def index(self, *, first_pass: bool = True, keep_chunks: bool = False) -> LogIndex:
        """What a pass over the frames reads the log with (:class:`~replay.logs.index.LogIndex`): the
        topics chosen, the caps, the records known at open. With ``first_pass`` the chunks parsed
        while opening go with it (once: a later index has none, unless ``keep_chunks`` leaves them to
        the next one too)."""
        chunks: dict[tuple[int, int], list[tuple[int, object]]] = {}
        if first_pass:
            chunks = dict(self._chunks)
            if not keep_chunks:
                self._chunks = {}
        return LogIndex(
            path=self.path, cloud_topic=self.cloud_topic, image_topic=self.image_topic, info_topic=self.info_topic,
            mask_topics=tuple(self.mask_topics), cloudless=self.cloudless, max_pixels=self.max_pixels,
            max_message_bytes=self.max_message_bytes, schemas=self._schemas, channels=self._channels,
            has_summary=self._has_summary, n_frames=self.n_frames, open_damage=self.open_damage,
            metadata=self.metadata, chunks=chunks, depth_topic=self.depth_topic, pool=self.pool,
        )


#: Largest total of mask pixels :func:`read_mask_topics` returns from one file (2**30: 1 GiB of bool masks).
MAX_MASK_FILE_PIXELS = 1 << 30


def read_mask_topics(
    path: str | os.PathLike[str], wanted: tuple[str, ...], *, max_pixels: int = DEFAULT_MAX_PIXELS,
    max_total_pixels: int = MAX_MASK_FILE_PIXELS,
) -> tuple[dict[str, dict[str, str]], dict[int, dict[str, np.ndarray]]]:
    """Every mono8 mask of the ``wanted`` topics in a small MCAP file (e.g. a label export).

    The file is read whole with the same defensive scanner and Image codec as :class:`LogReader`;
    any damage is a :class:`LogFormatError` (such files are taken whole or not at all). A mask is
    at most ``max_pixels``, and all of them together at most ``max_total_pixels``: zstd chunks of
    zeros make a file of a few KB decode to gigabytes of masks. The masks are held bit-packed
    while the file is read, so such a file is refused having held an eighth of the cap at most.

    Returns
    -------
    (metadata, masks)
        ``metadata``: the MCAP metadata records, name -> key/value strings; ``masks``:
        stamp_ns -> {topic: (H, W) bool ndarray}.
    """
    import numpy as np

    check_caps(max_pixels, max_total_pixels)
    packed: dict[int, dict[str, tuple[tuple[int, int], np.ndarray]]] = {}
    damage: list[Damage] = []
    total = 0
    with McapFile(Path(path)) as f:
        metadata, notes = f.read_metadata()
        damage += notes
        chosen: dict[int, str] = {}
        for op, rec in f.records(damage, prefetch=0):  # the op names the record's type
            channel, message = cast(Channel, rec), cast(Message, rec)
            if op == OP_CHANNEL and channel.topic in wanted:
                chosen[channel.id] = channel.topic
            elif op == OP_MESSAGE and message.channel_id in chosen:
                topic = chosen[message.channel_id]
                where = f"{path}: {topic}"
                msg = rm.decode_image(message.data, where=where)
                mask = rm.image_to_mask(msg, where=where, max_pixels=max_pixels)
                old = packed.get(msg.stamp_ns, {}).get(topic)
                total += mask.size - (0 if old is None else old[0][0] * old[0][1])
                if total > max_total_pixels:
                    raise LogFormatError(f"{path}: its masks hold more than {max_total_pixels} pixels in all "
                                         "(the cap of one label file); split it")
                packed.setdefault(msg.stamp_ns, {})[topic] = (mask.shape, np.packbits(mask))
            elif op == OP_LOST:
                lost = cast(Lost, rec)
                damage.append(Damage(DamageKind.DAMAGED_CHUNK,
                                     f"messages were lost with the chunk at byte {lost.offset}", byte=lost.offset))
    if damage:
        raise LogFormatError(f"{path}: damaged file: {damage[0].text}")
    masks = {stamp: {topic: np.unpackbits(bits, count=shape[0] * shape[1]).view(np.bool_).reshape(shape)
                     for topic, (shape, bits) in pair.items()} for stamp, pair in packed.items()}
    return metadata, masks
