"""Write rosbag2-compatible MCAP logs (profile ``ros2``, ``cdr`` messages, ``ros2msg`` schemas).

What ``ros2 bag record -s mcap`` writes, and what :class:`LogWriter` reproduces:

- header profile ``ros2``; one ``ros2msg`` schema per message type with the full dependency text;
- one channel per topic, message encoding ``cdr``, channel metadata ``offered_qos_profiles`` (the
  YAML list rosbag2 stores);
- zstd-compressed chunks with CRCs, message indexes, statistics and the summary section
  (written by :mod:`replay.logs.mcap_write`);
- a ``rosbag2`` metadata record whose ``serialized_metadata`` key holds the bag info YAML
  (``rosbag2_bagfile_information``: storage identifier, duration, start, message counts per topic).

Messages are logged at ``log_time = publish_time = stamp_ns`` (the header stamp), so replaying the
log keeps the pairing of clouds, images and masks.
"""

from __future__ import annotations

import os
from pathlib import Path
from types import TracebackType

import numpy as np

from replay.logs import layout
from replay.logs import ros2_msgs as rm
from replay.logs.frame import Frame
from replay.logs.mcap_write import McapWriter
from zcut.cloud import Intrinsics
from zcut.errors import InputShapeError, describe_array

#: The QoS profile list rosbag2 stores for a reliable, volatile publisher (Humble YAML layout).
OFFERED_QOS_PROFILES = (
    "- history: 3\n"
    "  depth: 0\n"
    "  reliability: 1\n"
    "  durability: 2\n"
    "  deadline:\n"
    "    sec: 2147483647\n"
    "    nsec: 4294967295\n"
    "  lifespan:\n"
    "    sec: 2147483647\n"
    "    nsec: 4294967295\n"
    "  liveliness: 1\n"
    "  liveliness_lease_duration:\n"
    "    sec: 2147483647\n"
    "    nsec: 4294967295\n"
    "  avoid_ros_namespace_conventions: false"
)

LIBRARY = "zcut replay.logs.writer"


def _text(value: object) -> str:
    """``str(value)``, with what UTF-8 cannot encode (lone surrogates) backslash-escaped."""
    s = str(value)
    try:
        s.encode("utf-8")
    except UnicodeEncodeError:
        s = s.encode("utf-8", "backslashreplace").decode("utf-8")
    return s


def _yaml_str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'


class LogWriter:
    """Context manager writing one rosbag2-style MCAP file.

    Parameters
    ----------
    path : str or Path
        Output ``.mcap``; an existing file is replaced.
    metadata : dict[str, dict[str, str]] or None
        Extra MCAP metadata records, name -> key/value strings (e.g. ``{"zcut.synth": {...}}``).
        Text that UTF-8 cannot hold (a file name with undecodable bytes, kept by Python as lone
        surrogates) is written backslash-escaped (``\\udcff``): metadata describes, it is not data.
    attachments : dict[str, tuple[str, bytes]] or None
        MCAP attachments, name -> (media type, bytes), e.g. the bin model
        (``{layout.BIN_MODEL_ATTACHMENT: (layout.BIN_MODEL_MEDIA_TYPE, ply_bytes)}``); written right
        after the metadata, before any message, so that even a truncated log keeps them.
    chunk_size : int
        Target uncompressed chunk size in bytes (each big cloud gets a chunk of its own).
    zstd_level : int
        Chunk compression level (1: fast; rosbag2 uses a fast level too).
    bag_name : str or None
        The file name the ``rosbag2`` record names (``relative_file_paths``, ``files``); default the
        name of ``path``. A caller writing into a temporary file that is renamed when complete passes
        the final name, so that the log's bytes do not depend on the temporary one.

    Examples
    --------
    >>> with LogWriter(tmp / "x.mcap") as w:                          # doctest: +SKIP
    ...     w.write_cloud(layout.CLOUD, xyz, rgb=rgb, stamp_ns=0, frame_id="camera")
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        metadata: dict[str, dict[str, str]] | None = None,
        attachments: dict[str, tuple[str, bytes]] | None = None,
        chunk_size: int = 4 * 1024 * 1024,
        zstd_level: int = 1,
        bag_name: str | None = None,
    ) -> None:
        self.path = Path(path)
        self.bag_name = self.path.name if bag_name is None else str(bag_name)
        self._meta = {_text(k): {_text(a): _text(b) for a, b in v.items()} for k, v in (metadata or {}).items()}
        self._file = open(self.path, "wb")
        try:
            self._writer = McapWriter(self._file, chunk_size=chunk_size, zstd_level=zstd_level)
            self._writer.start(profile="ros2", library=LIBRARY)
            # user metadata first, so that even a truncated log keeps it
            for name, data in self._meta.items():
                self._writer.add_metadata(name, data)
            for name, (media_type, blob) in (attachments or {}).items():
                self._writer.add_attachment(name, media_type, bytes(blob))
        except BaseException:  # e.g. a metadata string that is not UTF-8: no open file left behind
            self._file.close()
            raise
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str]] = {}
        self._counts: dict[str, int] = {}
        self._seq: dict[str, int] = {}
        self._t_min: int | None = None
        self._t_max: int | None = None
        self._closed = False

    # ---------------------------------------------------------------- plumbing
    def __enter__(self) -> LogWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def _channel(self, topic: str, msg_type: str) -> int:
        got = self._channels.get(topic)
        if got is not None:
            if got[1] != msg_type:
                raise InputShapeError(
                    f"topic {topic} already carries {got[1]}, cannot also write {msg_type}"
                )
            return got[0]
        sid = self._schemas.get(msg_type)
        if sid is None:
            sid = self._writer.register_schema(
                name=msg_type, encoding="ros2msg", data=rm.SCHEMAS[msg_type].encode()
            )
            self._schemas[msg_type] = sid
        cid = self._writer.register_channel(
            topic=topic, message_encoding="cdr", schema_id=sid,
            metadata={"offered_qos_profiles": OFFERED_QOS_PROFILES},
        )
        self._channels[topic] = (cid, msg_type)
        self._counts[topic] = 0
        self._seq[topic] = 0
        return cid

    def _add(self, topic: str, msg_type: str, data: bytes, stamp_ns: int) -> None:
        if self._closed:
            raise ValueError(f"LogWriter for {self.path} is closed")
        stamp_ns = int(stamp_ns)
        if not 0 <= stamp_ns <= rm.MAX_STAMP_NS:
            raise InputShapeError(
                f"stamp_ns must be in the ROS 2 time range 0 .. {rm.MAX_STAMP_NS} (2038-01-19), got {stamp_ns}"
            )
        cid = self._channel(topic, msg_type)
        self._writer.add_message(
            channel_id=cid, log_time=stamp_ns, data=data, publish_time=stamp_ns,
            sequence=self._seq[topic],
        )
        self._seq[topic] += 1
        self._counts[topic] += 1
        self._t_min = stamp_ns if self._t_min is None else min(self._t_min, stamp_ns)
        self._t_max = stamp_ns if self._t_max is None else max(self._t_max, stamp_ns)

    # ---------------------------------------------------------------- messages
    def write_cloud(
        self, topic: str, xyz: np.ndarray, *, rgb: np.ndarray | None = None, stamp_ns: int,
        frame_id: str,
    ) -> None:
        """Write an organized PointCloud2: x, y, z FLOAT32 at 0/4/8, rgba UINT32 at 12.

        Parameters
        ----------
        xyz : (H, W, 3) float ndarray
            Metres, NaN invalid (written as NaN, ``is_dense = false``).
        rgb : (H, W, 3) uint8 ndarray or None
            Packed into ``rgba`` as ``0xAARRGGBB`` with alpha 255; without it the cloud has only
            the x, y, z fields (same point_step 16).
        """
        xyz = np.asarray(xyz)
        if xyz.ndim != 3 or xyz.shape[2] != 3 or not np.issubdtype(xyz.dtype, np.floating):
            raise InputShapeError(f"xyz must be an (H, W, 3) float array, got {describe_array(xyz)}")
        h, w = xyz.shape[:2]
        if h < 1 or w < 1:
            raise InputShapeError(f"xyz must not be empty, got {describe_array(xyz)}")
        if rgb is not None:
            rgb = np.asarray(rgb)
            if rgb.shape != (h, w, 3) or rgb.dtype != np.uint8:
                raise InputShapeError(
                    f"rgb must be an ({h}, {w}, 3) uint8 array like xyz, got {describe_array(rgb)}"
                )
        data = rm.arrays_to_cloud_data(xyz, rgb)
        msg = rm.encode_cloud(
            stamp_ns=stamp_ns, frame_id=frame_id, height=h, width=w,
            fields=rm.XYZRGBA_FIELDS if rgb is not None else rm.XYZ_FIELDS,
            point_step=16, row_step=16 * w, data=data,
            is_dense=bool(np.isfinite(xyz).all()),
        )
        self._add(topic, rm.POINTCLOUD2, msg, stamp_ns)

    def write_image(self, topic: str, rgb: np.ndarray, *, stamp_ns: int, frame_id: str) -> None:
        """Write an (H, W, 3) uint8 RGB image as an ``rgb8`` Image."""
        rgb = np.asarray(rgb)
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8 or rgb.size == 0:
            raise InputShapeError(f"rgb must be an (H, W, 3) uint8 array, got {describe_array(rgb)}")
        self._write_pixels(topic, rgb, "rgb8", stamp_ns=stamp_ns, frame_id=frame_id)

    def write_mask(self, topic: str, mask: np.ndarray, *, stamp_ns: int, frame_id: str, packed: bool = False) -> None:
        """Write an (H, W) bool mask as a ``mono8`` Image, 255 = set; with ``packed`` as zcut's bit-packed
        ``mono1`` Image (:data:`replay.logs.ros2_msgs.PACKED_MASK_ENCODING`: 8 × smaller, what results files
        hold)."""
        mask = np.asarray(mask)
        if mask.ndim != 2 or mask.dtype != np.bool_ or mask.size == 0:
            raise InputShapeError(f"mask must be an (H, W) bool array, got {describe_array(mask)}")
        if not packed:
            self._write_pixels(topic, mask.astype(np.uint8) * np.uint8(255), "mono8", stamp_ns=stamp_ns,
                               frame_id=frame_id)
            return
        bits = rm.mask_to_packed(mask)
        msg = rm.encode_image(stamp_ns=stamp_ns, frame_id=frame_id, height=mask.shape[0], width=mask.shape[1],
                              encoding=rm.PACKED_MASK_ENCODING, step=bits.shape[1], data=bits.tobytes())
        self._add(topic, rm.IMAGE, msg, stamp_ns)

    def write_codes(self, topic: str, codes: np.ndarray, *, stamp_ns: int, frame_id: str) -> None:
        """Write an (H, W) uint8 code image (e.g. ``/ground_truth/outlier_kind``) as a ``mono8`` Image."""
        codes = np.asarray(codes)
        if codes.ndim != 2 or codes.dtype != np.uint8 or codes.size == 0:
            raise InputShapeError(f"codes must be an (H, W) uint8 array, got {describe_array(codes)}")
        self._write_pixels(topic, codes, "mono8", stamp_ns=stamp_ns, frame_id=frame_id)

    def write_depth(self, topic: str, depth_m: np.ndarray, *, stamp_ns: int, frame_id: str) -> None:
        """Write an (H, W) float32 depth image (metres, NaN = none) as a ``32FC1`` Image, little-endian
        (e.g. ``/ground_truth/depth``)."""
        depth_m = np.asarray(depth_m)
        if depth_m.ndim != 2 or depth_m.dtype != np.float32 or depth_m.size == 0:
            raise InputShapeError(f"depth must be an (H, W) float32 array, got {describe_array(depth_m)}")
        self._write_pixels(topic, depth_m.astype("<f4", copy=False), layout.TRUTH_DEPTH_ENCODING, stamp_ns=stamp_ns,
                           frame_id=frame_id)

    def _write_pixels(self, topic: str, pixels: np.ndarray, encoding: str, *, stamp_ns: int, frame_id: str) -> None:
        """An Image of ``encoding`` holding ``pixels`` ((H, W) or (H, W, C), checked) row by row, unpadded."""
        h, w = pixels.shape[:2]
        msg = rm.encode_image(
            stamp_ns=stamp_ns, frame_id=frame_id, height=h, width=w, encoding=encoding,
            step=w * pixels[0, 0].nbytes, data=np.ascontiguousarray(pixels).tobytes(),
        )
        self._add(topic, rm.IMAGE, msg, stamp_ns)

    def write_camera_info(
        self, topic: str, intrinsics: Intrinsics, *, stamp_ns: int, frame_id: str
    ) -> None:
        """Write a ``CameraInfo`` (plumb_bob, zero distortion) from pinhole intrinsics."""
        if not isinstance(intrinsics, Intrinsics):
            raise InputShapeError(f"intrinsics must be a zcut.cloud.Intrinsics, got {type(intrinsics).__name__}")
        msg = rm.encode_camera_info(intrinsics, stamp_ns=stamp_ns, frame_id=frame_id)
        self._add(topic, rm.CAMERAINFO, msg, stamp_ns)

    def write_frame(self, frame: Frame) -> None:
        """Write a :class:`Frame`: cloud on ``/camera/points``, image on ``/camera/image`` (when
        ``frame.rgb`` is set), ``/camera/camera_info`` (when intrinsics are set), and every mask of
        ``frame.masks`` under its own topic, all stamped ``frame.stamp_ns``."""
        stamp_ns, frame_id = frame.stamp_ns, frame.frame_id
        self.write_cloud(layout.CLOUD, frame.xyz, rgb=frame.rgb, stamp_ns=stamp_ns, frame_id=frame_id)
        if frame.rgb is not None:
            self.write_image(layout.IMAGE, frame.rgb, stamp_ns=stamp_ns, frame_id=frame_id)
        if frame.intrinsics is not None:
            self.write_camera_info(layout.CAMERA_INFO, frame.intrinsics, stamp_ns=stamp_ns, frame_id=frame_id)
        for topic, mask in frame.masks.items():
            self.write_mask(topic, mask, stamp_ns=stamp_ns, frame_id=frame_id)

    # ---------------------------------------------------------------- closing
    def _bag_info_yaml(self) -> str:
        start = self._t_min or 0
        duration = (self._t_max - self._t_min) if self._t_min is not None else 0  # type: ignore[operator]  # set together
        total = sum(self._counts.values())
        lines = [
            "rosbag2_bagfile_information:",
            "  version: 5",
            "  storage_identifier: mcap",
            "  duration:",
            f"    nanoseconds: {duration}",
            "  starting_time:",
            f"    nanoseconds_since_epoch: {start}",
            f"  message_count: {total}",
            "  topics_with_message_count:",
        ]
        for topic, (_, msg_type) in self._channels.items():
            lines += [
                "    - topic_metadata:",
                f"        name: {topic}",
                f"        type: {msg_type}",
                "        serialization_format: cdr",
                f"        offered_qos_profiles: {_yaml_str(OFFERED_QOS_PROFILES + chr(10))}",
                f"      message_count: {self._counts[topic]}",
            ]
        lines += [
            '  compression_format: ""',
            '  compression_mode: ""',
            "  relative_file_paths:",
            f"    - {_text(self.bag_name)}",
            "  files:",
            f"    - path: {_text(self.bag_name)}",
            "      starting_time:",
            f"        nanoseconds_since_epoch: {start}",
            "      duration:",
            f"        nanoseconds: {duration}",
            f"      message_count: {total}",
        ]
        return "\n".join(lines) + "\n"

    def close(self) -> None:
        """Write metadata records and the summary, and close the file (idempotent)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.add_metadata("rosbag2", {"serialized_metadata": self._bag_info_yaml()})
            self._writer.finish()
        finally:
            self._file.close()
