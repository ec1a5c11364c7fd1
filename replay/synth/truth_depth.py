"""Read ``/ground_truth/depth`` back from a synthetic log (``docs/formats.md``, ground-truth topics).

The frame reader (:class:`replay.logs.reader.LogReader`) pairs only mono8 masks and codes with a
cloud; the true depth is a ``32FC1`` Image, read here by header stamp, so that any truth rule other
than the generator's can be recomputed from the measured cloud and the true surface.
"""

from __future__ import annotations

import os

import numpy as np

from replay.errors import LogFormatError
from replay.logs import layout
from replay.logs import ros2_msgs as rm


def read_truth_depth(path: str | os.PathLike[str], *, topic: str = layout.TRUTH_DEPTH) -> dict[int, np.ndarray]:
    """Every true-depth image of a log: header stamp (ns) -> (H, W) float32 camera z in metres (NaN: no hit).

    Raises
    ------
    LogFormatError
        A message on ``topic`` that is not a little-endian ``32FC1`` Image of consistent size.
    """
    from mcap.reader import make_reader

    out: dict[int, np.ndarray] = {}
    with open(path, "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages(topics=[topic]):
            msg = rm.decode_image(message.data, where=f"{channel.topic} message")
            if msg.encoding != layout.TRUTH_DEPTH_ENCODING or msg.is_bigendian:
                raise LogFormatError(
                    f"{channel.topic}: expected a little-endian {layout.TRUTH_DEPTH_ENCODING} Image, "
                    f"got '{msg.encoding}' (big-endian {bool(msg.is_bigendian)})")
            if msg.step != 4 * msg.width or len(msg.data) != msg.step * msg.height:
                raise LogFormatError(f"{channel.topic}: {msg.height}x{msg.width} 32FC1 needs step {4 * msg.width} "
                                     f"and {4 * msg.width * msg.height} bytes, got step {msg.step}, {len(msg.data)}")
            out[msg.stamp_ns] = np.frombuffer(bytes(msg.data), dtype="<f4").reshape(msg.height, msg.width).copy()
    return out
