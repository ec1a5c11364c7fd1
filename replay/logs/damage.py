"""Typed records of the damage met while reading a log (``docs/formats.md``, "Damage").

A damaged log does not stop a command: the frames that can be read are delivered, and every loss is
one :class:`Damage` record, made where the loss is found (the MCAP scanner for the file's records,
the frame stream for frames and their messages) and kept by the iteration that met it
(:attr:`replay.logs.stream.FrameStream.damage`). Exit status 3 and the studies look at the records;
the one-line text a user reads is rendered from a record (:attr:`Damage.text`) where it is shown,
never parsed back.
"""

from __future__ import annotations

import enum
from collections.abc import Iterable
from dataclasses import dataclass


class DamageKind(enum.Enum):
    """What went wrong (the value is the stable name used in JSON)."""

    #: the file ends inside its data section (every complete record before the cut was read)
    TRUNCATED = "truncated"
    #: a chunk or record that cannot be used (corrupt, fails its CRC, a length past the data, an
    #: invalid opcode, over the size cap); the scan went on at the next chunk the file knows of
    DAMAGED_CHUNK = "damaged_chunk"
    #: the summary section is damaged: the log is read sequentially
    DAMAGED_SUMMARY = "damaged_summary"
    #: a metadata record listed in the summary is damaged
    DAMAGED_METADATA = "damaged_metadata"
    #: frames lost without being read: with a lost chunk, a gap in the message sequence numbers, or
    #: fewer clouds than the summary lists
    LOST_FRAMES = "lost_frames"
    #: a chunk of unknown content was lost: frame indices after ``frame_index`` may be shifted
    UNKNOWN_LOSS = "unknown_loss"
    #: a message (the cloud, or an image, camera info or mask) that does not decode
    MALFORMED_MESSAGE = "malformed_message"
    #: a message or grid over the size caps (``max_message_bytes``, ``max_pixels``)
    OVER_CAP = "over_cap"
    #: an image, camera info or mask whose size is not its cloud's
    WRONG_SIZE = "wrong_size"
    #: the frame's image, camera info or mask message was lost with a damaged chunk
    LOST_COMPANION = "lost_companion"
    #: a cloud of height 1 (zcut needs organized clouds)
    UNORGANIZED = "unorganized"
    #: two clouds share a header stamp: their images, camera info and masks cannot be told apart
    DUPLICATE_STAMP = "duplicate_stamp"


#: the kinds whose frame was read but skipped (rendered "frame N (stamp S) skipped: ...")
SKIPPED_KINDS = frozenset({DamageKind.MALFORMED_MESSAGE, DamageKind.OVER_CAP, DamageKind.WRONG_SIZE,
                           DamageKind.LOST_COMPANION, DamageKind.UNORGANIZED, DamageKind.DUPLICATE_STAMP})


def stamp_text(ns: int) -> str:
    """Nanoseconds as exact seconds, ``1700000000.100000000``."""
    sign = "-" if ns < 0 else ""
    q, r = divmod(abs(int(ns)), 1_000_000_000)
    return f"{sign}{q}.{r:09d}"


@dataclass(frozen=True, slots=True)
class Damage:
    """One loss met while reading a log.

    Attributes
    ----------
    kind : DamageKind
    message : str
        What happened, in words, without the frame it names (that is rendered from the fields).
    frame_index : int or None
        The log's own index of the (first) frame lost or skipped; None when no frame is known.
    n_frames : int
        How many frames (``frame_index``, ``frame_index + 1``, …) this loss took; 0 when it names
        none (e.g. a damaged chunk, whose frames get a :attr:`DamageKind.LOST_FRAMES` record of
        their own).
    stamp_ns : int or None
        Header stamp of the frame (or message) when it was read.
    log_time_ns, last_log_time_ns : int or None
        MCAP log time of the (first, and last when several) lost message, when no stamp is known.
    topic : str or None
        The topic of the message concerned.
    byte : int or None
        File offset of the damaged record.
    """

    kind: DamageKind
    message: str
    frame_index: int | None = None
    n_frames: int = 0
    stamp_ns: int | None = None
    log_time_ns: int | None = None
    last_log_time_ns: int | None = None
    topic: str | None = None
    byte: int | None = None

    @property
    def frames(self) -> range:
        """The frame indices this loss took (empty when it names none)."""
        if self.frame_index is None:
            return range(0)
        return range(self.frame_index, self.frame_index + self.n_frames)

    @property
    def text(self) -> str:
        """The one line shown to a user, e.g. ``frame 2 (log time 3.000000000) lost with the chunk at
        byte 5120`` or ``frame 4 (stamp 5.000000000) skipped: …``."""
        if self.kind is DamageKind.UNKNOWN_LOSS or self.frame_index is None or self.n_frames < 1:
            return self.message
        lo = self.frame_index
        what = f"frame {lo}" if self.n_frames == 1 else f"frames {lo}-{lo + self.n_frames - 1}"
        if self.stamp_ns is not None:
            what += f" (stamp {stamp_text(self.stamp_ns)})"
        elif self.log_time_ns is not None:
            last = self.last_log_time_ns
            what += (f" (log time {stamp_text(self.log_time_ns)})" if last is None
                     else f" (log times {stamp_text(self.log_time_ns)} .. {stamp_text(last)})")
        if self.kind in SKIPPED_KINDS:
            return f"{what} skipped: {self.message}"
        return f"{what} {self.message}"

    def __str__(self) -> str:
        return self.text

    def as_dict(self) -> dict[str, object]:
        """The record as JSON-ready fields (``kind`` by its name), with its rendered ``text``."""
        return {"kind": self.kind.value, "frame_index": self.frame_index, "n_frames": self.n_frames,
                "stamp_ns": self.stamp_ns, "log_time_ns": self.log_time_ns, "last_log_time_ns": self.last_log_time_ns,
                "topic": self.topic, "byte": self.byte, "message": self.message, "text": self.text}


def damage_lines(records: Iterable[Damage]) -> list[str]:
    """The one-line texts of ``records``, in order (what commands print and summaries store)."""
    return [d.text for d in records]


def frames_lost(records: Iterable[Damage]) -> int:
    """How many frames the records name as lost or skipped (a lower bound: a damaged chunk of
    unknown content names none)."""
    return sum(d.n_frames for d in records if d.frame_index is not None)
