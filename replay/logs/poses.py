"""A synthetic log's true bin poses, decoded from its ``zcut.synth.poses`` metadata record.

The record (``docs/formats.md``; written by :func:`replay.synth.log.pose_metadata`) maps
``str(stamp_ns)`` to the 16 row-major floats of ``T_cam_bin``. Decoding it needs no scene
generator, so the replay (a frame's pose error) reads it from here.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from replay.errors import LogFormatError
from replay.logs import layout


def true_poses(metadata: Mapping[str, Mapping[str, str]]) -> dict[int, np.ndarray]:
    """Every frame's true ``T_cam_bin`` from a synthetic log's metadata (``LogReader.metadata``).

    Parameters
    ----------
    metadata : mapping
        MCAP metadata records, name -> key/value strings.

    Returns
    -------
    dict[int, (4, 4) float64 ndarray]
        Header stamp (ns) -> bin frame to camera optical frame, metres (see
        :func:`replay.synth.synthesize.T_cam_bin`); empty when the log carries no poses.
    """
    record = metadata.get(layout.SYNTH_POSES_METADATA)
    if record is None:
        return {}
    poses: dict[int, np.ndarray] = {}
    for key, value in record.items():
        where = f"{layout.SYNTH_POSES_METADATA}[{key!r}]"
        try:
            stamp = int(key)
            T = np.array([float(v) for v in value.split(",")], dtype=np.float64)
        except ValueError:
            raise LogFormatError(f"{where}: expected an integer stamp and 16 comma-separated floats") from None
        if T.size != 16 or not np.isfinite(T).all():
            raise LogFormatError(f"{where}: expected 16 finite comma-separated floats, got {T.size} values")
        poses[stamp] = T.reshape(4, 4)
    return poses
