"""The stereo matcher's own post-filters as methods to score (docs/real_data.md, "The matcher's
post-filters as methods").

A stereo log of ``zcut record-stereo`` holds, beside its cloud, the pixels each post-filter of the
matcher would have invalidated at each strength it was asked for (``/stereo/rejected/...``,
:func:`replay.logs.layout.stereo_rejected_topic`): the uniqueness test (``stereo_uniqueness``), the
left-right check (``stereo_lr``), the speckle filter on the disparity (``stereo_speckle``) and StereoBM's
texture test (``stereo_texture``). Such a method's parameters (:mod:`zcut.params`, named as
:class:`zcut.stereo.MatcherParams`' fields) select one recorded strength; its outliers are that mask
inside the zone. A frame without the mask (a log of another kind, or the strength not recorded) gets a
warning naming the topic and what the frame holds, and no outliers. Sweeping the strength is sweeping
the parameters over strengths the log holds (``zcut record-stereo --reject-axes`` records every point
of the default axes).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from replay.logs import layout
from replay.logs.frame import Frame
from replay.pipeline.zone import Zone
from zcut.stereo import PostFilter

__all__ = ["rejected"]


def rejected(frame: Frame, zone: Zone, name: str, params: PostFilter) -> tuple[np.ndarray, str | None]:
    """The recorded rejections of method ``name`` at ``params`` inside the zone, and a warning (or None).

    Returns
    -------
    (H, W) bool ndarray
        The pixels of ``/stereo/rejected/<settings>`` inside ``zone.zone``; none when the frame has
        no such mask.
    str or None
        Why there are none: the topic is not in the frame (naming the strengths it holds).
    """
    topic = layout.stereo_rejected_topic(dataclasses.asdict(params))
    mask = frame.masks.get(topic)
    if mask is None:
        held = sorted(t[len(layout.STEREO_REJECTED_PREFIX):] for t in frame.masks
                      if t.startswith(layout.STEREO_REJECTED_PREFIX))
        settings = ", ".join(f"{k} = {v}" for k, v in dataclasses.asdict(params).items())
        return np.zeros_like(zone.zone), (
            f"{name}: this frame has no {topic} (the matcher's rejections at {settings}; it holds "
            f"{', '.join(held) if held else 'none'}; record them with zcut record-stereo): no outliers")
    return mask & zone.zone, None
