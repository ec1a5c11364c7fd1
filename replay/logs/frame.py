"""One organized scan as zcut replays it."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator, Mapping, MutableMapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from zcut.cloud import Intrinsics


class LazyArrays(MutableMapping[str, np.ndarray]):
    """A frame's masks or codes by topic, each array decoded from its message the first time it is read.

    A log's ground-truth masks and outlier kinds are read by the results file, the scoring and the
    labelling, not by a replay's stages: :class:`~replay.logs.stream.FrameStream` checks each message when
    it pairs the frame (a bad one skips the frame as before) and leaves its decoding (a pass over its
    pixels) to the first reader of ``frame.masks[topic]``. A value is an array or a function returning it
    (called once, under a lock: two threads reading the same topic get the same array); the message's
    bytes it reads stay alive until then. Reading a value (``[]``, ``get``, ``items``, ``values``) decodes
    it; the keys, ``in`` and ``len`` do not. Otherwise a dict of arrays (assignment, ``pop``, ``clear``,
    ``==`` as dicts compare, a copy or pickle decodes every value).

    Parameters
    ----------
    items : mapping of str to ndarray or to a function returning one
    """

    __slots__ = ("_items", "_lock")

    def __init__(self, items: Mapping[str, np.ndarray | Callable[[], np.ndarray]] | None = None) -> None:
        self._items: dict[str, np.ndarray | Callable[[], np.ndarray]] = dict(items or {})
        self._lock = threading.Lock()

    def __getitem__(self, key: str) -> np.ndarray:
        v = self._items[key]
        if isinstance(v, np.ndarray):
            return v
        with self._lock:
            v = self._items[key]
            if not isinstance(v, np.ndarray):
                v = v()
                self._items[key] = v
            return v

    def __setitem__(self, key: str, value: np.ndarray) -> None:
        self._items[key] = value

    def __delitem__(self, key: str) -> None:
        del self._items[key]

    def __contains__(self, key: object) -> bool:
        return key in self._items

    def __iter__(self) -> Iterator[str]:
        return iter(self._items)

    def __len__(self) -> int:
        return len(self._items)

    def __repr__(self) -> str:
        return f"LazyArrays({dict(self.items())!r})"

    def __reduce__(self) -> tuple[Any, ...]:
        return LazyArrays, (dict(self.items()),)


@dataclass(frozen=True, slots=True)
class Frame:
    """An organized cloud with what was recorded beside it (paired by header stamp).

    Attributes
    ----------
    xyz : (H, W, 3) float32 ndarray
        Metres, camera optical frame; NaN where invalid ((0, 0, 0) points are turned into NaN). A frame of a
        results file written without its cloud has no points: a read-only all-NaN view (``has_points``
        False), its valid pixels in ``masks['/zcut/valid']``.
    rgb : (H, W, 3) uint8 ndarray or None
        Colour image (from the Image topic, else from the cloud's rgb/rgba field).
    stamp_ns : int
        Header stamp of the cloud in nanoseconds.
    frame_id : str
    intrinsics : Intrinsics or None
        From a paired CameraInfo.
    topic : str
        The cloud's topic.
    index : int
        0-based index of the frame in the log.
    masks : mutable mapping of str to (H, W) bool ndarray
        mono8 mask topics with the same stamp (e.g. ``/ground_truth/outliers``), 255 -> True. A frame read
        from a log holds a :class:`LazyArrays` (each mask decoded when first read), a made one a dict.
    codes : mutable mapping of str to (H, W) uint8 ndarray
        mono8 topics whose values are codes (``replay.logs.layout.CODE_TOPICS``, e.g.
        ``/ground_truth/outlier_kind``), as they are (a :class:`LazyArrays` too when read from a log).
    has_points : bool
        False for a frame of a results file written without its cloud (``LogReader(cloudless=True)``).
    truth_depth_m : (H, W) float32 ndarray or None
        The log's ``/ground_truth/depth`` of this frame (camera z in metres of the first surface hit, NaN
        where nothing is hit), a read-only view of the message's bytes, when the reader was asked for it
        (``LogReader(truth_depth=True)``) and the log holds a usable one paired by stamp; else None.
    decoded_valid : tuple of two ndarrays or None
        ``(xyz, valid)``: the (H, W) bool mask of the pixels with three finite coordinates that the decoder
        wrote in the pass that unpacked ``xyz`` (:func:`replay.logs.ros2_msgs.cloud_to_arrays_valid`), with
        the array it is of. Read it through :attr:`known_valid`, which gives it only for that very ``xyz`` (a
        frame made from this one with other points, ``dataclasses.replace(frame, xyz=...)``, has none). None:
        not known (other layouts, frames not read from a log).
    """

    xyz: np.ndarray
    rgb: np.ndarray | None
    stamp_ns: int
    frame_id: str
    intrinsics: Intrinsics | None
    topic: str
    index: int
    masks: MutableMapping[str, np.ndarray] = field(default_factory=dict)
    codes: MutableMapping[str, np.ndarray] = field(default_factory=dict)
    has_points: bool = True
    truth_depth_m: np.ndarray | None = None
    decoded_valid: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False, compare=False)

    @property
    def known_valid(self) -> np.ndarray | None:
        """(H, W) bool: the pixels whose three coordinates are finite, as the decoder found them for this
        frame's ``xyz`` (``zcut.removal.valid_pixels(frame.xyz)``, not computed again); None when not known. A
        frame's arrays are not written after it was read (the replay's stages read them only)."""
        d = self.decoded_valid
        return d[1] if d is not None and d[0] is self.xyz else None

    @property
    def shape(self) -> tuple[int, int]:
        return self.xyz.shape[0], self.xyz.shape[1]
