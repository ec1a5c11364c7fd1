"""One test helper of the removal's tests: a log's frames located as the replay locates them.

Used by tests/zcut/test_removal_fast.py and tests/zcut/test_removal_fused.py, which run the removal (fast and
``reference=True``) on those frames.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from replay.pipeline import stages
from replay.pipeline.bin_model import bin_model_for
from replay.pipeline.session import ReplaySession

#: One located frame: (xyz, the bin mask's footprint, the ring, T_cam_bin).
Located = tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]


def located_frames(path: Path) -> tuple[Any, Any, list[Located]]:
    """(the bin model, the session's whole config, [(xyz, footprint, ring, T)]) of every frame of the log at
    ``path``, each located as the replay does (its registration converged)."""
    s = ReplaySession.open(path, choose_bin_model=lambda reader: bin_model_for(reader, None))
    out = []
    for frame in s.reader.frames():
        loc = stages.locate_bin(frame, s.config, bin_model=s.prepared, seed=s.seed)
        assert loc.registration is not None and loc.registration.converged
        out.append((frame.xyz, loc.bin_mask.mask, loc.ring, loc.registration.T_cam_bin))
    assert s.prepared is not None
    return s.prepared.model, s.config, out


def located_removal(path: Path) -> tuple[Any, Any, list[Located]]:
    """:func:`located_frames` with the removal's parameters (``config.removal``) in place of the whole config."""
    model, config, frames = located_frames(path)
    return model, config.removal, frames
