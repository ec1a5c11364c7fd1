"""A study's work split into units: a range of whole MCAP chunks of one log.

One long log spreads over many workers, and each worker reads its own frames from the file itself
(a unit is a path and a frame range, never pickled clouds). A log whose summary has no chunk index
is one unit. Frame indices are the log's own.
"""

from __future__ import annotations

import errno
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from replay.errors import ConfigError

LOG_SUFFIXES = (".mcap",)


@dataclass(frozen=True, slots=True)
class WorkUnit:
    """Frames ``start`` (inclusive) to ``stop`` (exclusive, None = to the end) of one log.

    Attributes
    ----------
    log : str
        Path of the log.
    sha256 : str
        The log's content hash (identifies it across runs and renames).
    start, stop : int, int or None
        The frame range: whole chunks of the log.
    n_frames : int or None
        Frames in the range, when the log's index says.
    """

    log: str
    sha256: str
    start: int
    stop: int | None
    n_frames: int | None

    @property
    def key(self) -> str:
        """A name for the unit's part file: the log's hash and the frame range."""
        return f"{self.sha256[:16]}-{self.start:08d}-{'end' if self.stop is None else f'{self.stop:08d}'}"


def broken_link(path: Path) -> str | None:
    """Why ``path`` is a symlink that leads to no file (dangling, or a loop), None otherwise."""
    if not path.is_symlink():
        return None
    try:
        os.stat(path)
    except OSError as e:
        if e.errno == errno.ELOOP:
            return "a symlink loop"
        if e.errno == errno.ENOENT:
            return f"a dangling symlink: {os.readlink(path)} does not exist"
        return f"a symlink that cannot be followed: {e.strerror or e}"
    return None


def expand_logs(inputs: list[str]) -> list[Path]:
    """Logs as given, folders expanded to their sorted ``*.mcap`` files (not recursive).

    A ``.mcap`` symlink that leads to no file (dangling: a log on an unmounted share; or a loop) is
    kept, as an unreadable log is: the planning leaves it out with a warning that names it (exit 3),
    never silently. Raises :class:`ConfigError` for a missing path, a folder without logs, or a file
    that is not a ``.mcap``; duplicates (the same file twice) are dropped.
    """
    out: list[Path] = []
    seen: set[tuple[int, int]] = set()
    for raw in inputs:
        p = Path(raw)
        if p.is_dir():
            found = sorted(q for q in p.iterdir() if q.suffix.lower() in LOG_SUFFIXES
                           and (q.is_file() or broken_link(q) is not None))
            if not found:
                raise ConfigError(f"folder {p} holds no .mcap log")
        elif p.is_file() or (broken_link(p) is not None and p.suffix.lower() in LOG_SUFFIXES):
            if p.suffix.lower() not in LOG_SUFFIXES:
                raise ConfigError(f"{p}: not an MCAP log (.mcap)")
            found = [p]
        elif p.exists():
            raise ConfigError(f"{p}: not a file or folder")
        else:
            raise ConfigError(f"no such file or folder: {p}")
        for q in found:
            st = os.lstat(q) if broken_link(q) is not None else os.stat(q)
            if (st.st_dev, st.st_ino) not in seen:
                seen.add((st.st_dev, st.st_ino))
                out.append(q)
    if not out:
        raise ConfigError("no logs found")
    return out


def plan_log(path: Path, *, sha256: str, frames_per_unit: int, whole: bool = False,
             topic: str | None = None, reader: Any = None) -> tuple[list[WorkUnit], int | None]:
    """Split one log into units of whole chunks holding about ``frames_per_unit`` frames.

    Returns the units and the number of frames the log's summary counts (None if unknown).
    ``whole``: one unit for the log (per-log outputs such as a results MCAP need one writer).
    ``reader``: the log already opened (a :class:`~replay.logs.reader.LogReader` of ``topic``), else it
    is opened here.
    """
    from replay.logs.reader import LogReader

    if reader is None:
        reader = LogReader(path, cloud_topic=topic)
    n = reader.n_frames
    ranges = None if whole else reader.chunk_frame_ranges()
    if not ranges:
        return [WorkUnit(str(path), sha256, 0, None, n)], n
    units: list[WorkUnit] = []
    start = ranges[0][0]
    count = 0
    for a, b in ranges:
        if count and count + (b - a) > frames_per_unit:
            units.append(WorkUnit(str(path), sha256, start, a, count))
            start, count = a, 0
        count += b - a
    units.append(WorkUnit(str(path), sha256, start, None, count))
    return units, n
