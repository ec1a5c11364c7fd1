"""Opening input files defensively, and the size caps every reader of :mod:`replay.logs` applies.

A log or cloud file is read only when it is a regular file: a FIFO would block ``open`` until a
writer appears, ``/dev/zero`` never ends, a directory or a socket cannot be read. :func:`open_input`
opens without blocking and checks with ``fstat`` before reading a byte, and names the path and what it is in a one-line
:class:`~replay.errors.LogFormatError`.

The caps bound what a hostile or damaged file can make zcut allocate. Every decoded size (a cloud,
an image, a PCD or PLY grid) is checked against the bytes really present *and* against the caps
before anything of that size is allocated.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import BinaryIO

from replay.errors import LogFormatError

#: The environment variables that set the caps (the command line checks them: ``replay.process``).
CAP_VARIABLES = ("ZCUT_MAX_PIXELS", "ZCUT_MAX_MESSAGE_BYTES")


def env_cap(name: str, default: int) -> int | None:
    """A cap from the environment: ``default`` when unset, None when not a positive integer.

    Read once, at import: every command and every worker process of a study sees the same caps.
    """
    raw = os.environ.get(name)
    if raw is None:
        return default
    try:
        v = int(raw)
    except ValueError:
        return None
    return v if v >= 1 else None


def _env_cap(name: str, default: int) -> int:
    v = env_cap(name, default)
    return default if v is None else v


#: Default largest grid (H x W) of a cloud, image or PCD/PLY file: 2**24 = 16.8 Mpx (4096 x 4096;
#: a 1920 x 1200 Zivid frame is 2.3 Mpx, a 2448 x 2048 Zivid 2+ frame 5 Mpx). Environment:
#: ``ZCUT_MAX_PIXELS``.
DEFAULT_MAX_PIXELS = _env_cap("ZCUT_MAX_PIXELS", 1 << 24)
#: Default largest single message (or PCD/PLY data section): 256 MiB (a 1920 x 1200 xyz+rgba
#: PointCloud2 is 37 MB; 5 Mpx at 32 bytes a point is 160 MB). Environment: ``ZCUT_MAX_MESSAGE_BYTES``.
DEFAULT_MAX_MESSAGE_BYTES = _env_cap("ZCUT_MAX_MESSAGE_BYTES", 256 << 20)
#: A chunk may hold one message of the largest size plus this much of smaller ones.
CHUNK_SLACK_BYTES = 64 << 20

_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
)


def check_caps(max_pixels: int, max_message_bytes: int) -> None:
    """Raise ValueError unless both caps are positive integers."""
    for name, v in (("max_pixels", max_pixels), ("max_message_bytes", max_message_bytes)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise ValueError(f"{name} must be a positive integer, got {v!r}")


def _check_kind(mode: int, p: Path, what: str) -> None:
    for test, kind in _KINDS:
        if test(mode):
            raise LogFormatError(f"{p} is {kind}, not {what} (zcut reads regular files only)")
    if not stat.S_ISREG(mode):
        raise LogFormatError(f"{p} is not a regular file, not {what}")


def open_input(path: str | os.PathLike[str], what: str) -> tuple[BinaryIO, int]:
    """Open a regular file for reading: (binary file object, size in bytes).

    Parameters
    ----------
    path : str or Path
    what : str
        What the file should be, for messages ("an MCAP log", "a PCD file").

    Raises
    ------
    LogFormatError
        The path is a directory, FIFO, socket or device (opened non-blocking and checked before
        any read, so a FIFO never blocks).
    FileNotFoundError, PermissionError
        As ``open`` raises them.
    """
    p = Path(path)
    _check_kind(os.stat(p).st_mode, p, what)  # a socket cannot even be opened
    # non-blocking: opening a FIFO for reading would otherwise wait for a writer
    fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
    try:
        st = os.fstat(fd)
        _check_kind(st.st_mode, p, what)  # again: it may have been replaced in between
        f = os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise
    return f, st.st_size
