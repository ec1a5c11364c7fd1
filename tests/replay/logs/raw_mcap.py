"""A ROS 2 MCAP log written message by message from raw CDR bytes, for tests that need malformed or odd messages
``replay.logs.writer.LogWriter`` would not write (tests/replay/logs is on sys.path for its test modules)."""

from __future__ import annotations

from pathlib import Path

from mcap.writer import CompressionType, Writer

from replay.logs import ros2_msgs as rm


def write_raw_log(path: Path, types: dict[str, str], messages: list[tuple[str, bytes]], *,
                  times: list[int] | None = None, compression: CompressionType = CompressionType.ZSTD) -> None:
    """Write ``messages`` — (topic, CDR bytes), in order, at log times ``times`` (default 1, 2, …) — on one channel
    a topic of ``types`` (topic -> ROS 2 message type, e.g. ``rm.IMAGE``), to ``path``."""
    stamps = times if times is not None else list(range(1, len(messages) + 1))
    with open(path, "wb") as f:
        w = Writer(f, compression=compression)
        w.start(profile="ros2", library="test")
        ids = {}
        for topic, typ in types.items():
            sid = w.register_schema(name=typ, encoding="ros2msg", data=rm.SCHEMAS[typ].encode())
            ids[topic] = w.register_channel(topic=topic, message_encoding="cdr", schema_id=sid)
        for (topic, data), t in zip(messages, stamps, strict=True):
            w.add_message(ids[topic], log_time=t, publish_time=t, data=data)
        w.finish()
