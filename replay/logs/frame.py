"""One organized scan as zcut replays it."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from zcut.cloud import Intrinsics


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
    masks : dict[str, (H, W) bool ndarray]
        mono8 mask topics with the same stamp (e.g. ``/ground_truth/outliers``), 255 -> True.
    codes : dict[str, (H, W) uint8 ndarray]
        mono8 topics whose values are codes (``replay.logs.layout.CODE_TOPICS``, e.g.
        ``/ground_truth/outlier_kind``), as they are.
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
    masks: dict[str, np.ndarray] = field(default_factory=dict)
    codes: dict[str, np.ndarray] = field(default_factory=dict)
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
