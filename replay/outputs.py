"""Outputs that never replace an input (SPEC §6).

Every command that writes files plans them first with an :class:`OutputPlan`: an output that is an
input (the same path, a hard link, a symlink: compared by device and inode as well as by path), two
outputs on one path, an output under a regular file or in a missing folder, an existing output
without ``--force``, or an existing output that is not a regular file (a device, a FIFO, a folder)
is refused before any work, with a one-line :class:`OutputError` naming the path.

A planned output is then written by :class:`AtomicOutput`: into a temporary file with a unique name
beside its final path (never a name a user's file may have), renamed into place only when complete
and only over a regular file, and removed if the work fails.
"""

from __future__ import annotations

import os
import stat
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from zcut.errors import ZcutError

__all__ = ["AtomicOutput", "OutputError", "OutputPlan", "config_path_for"]


class OutputError(ZcutError):
    """An output path would destroy data or cannot be written; the message names the path."""


def config_path_for(output: str | os.PathLike) -> Path:
    """Where the resolved config goes beside an output: ``OUT.rrd`` -> ``OUT.config.toml``."""
    p = Path(output)
    return p.with_name(p.stem + ".config.toml")


def _identity(path: Path) -> tuple[int, int] | None:
    """(device, inode) of what ``path`` names (links followed), None when it does not exist."""
    try:
        st = os.stat(path)
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as e:  # e.g. a symlink loop, a permission problem
        raise OutputError(f"{path}: cannot check the output path: {e.strerror}") from None
    return st.st_dev, st.st_ino


@dataclass
class OutputPlan:
    """The outputs of one command, checked together against its inputs before any work.

    Parameters
    ----------
    inputs : list of path
        Every file the command reads (logs, config files, bin models, label stores).
    force : bool
        Replace existing outputs (``--force``).
    """

    inputs: list[str | os.PathLike] = field(default_factory=list)
    force: bool = False
    outputs: dict[Path, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._inputs: dict[tuple[int, int], Path] = {}
        self._input_paths: dict[Path, Path] = {}
        for p in self.inputs:
            self.add_input(p)

    def add_input(self, path: str | os.PathLike) -> None:
        """Register a file the command reads."""
        p = Path(path)
        ident = _identity(p)
        if ident is not None:
            self._inputs[ident] = p
        self._input_paths[Path(os.path.abspath(p))] = p

    def add(self, path: str | os.PathLike, what: str) -> Path:
        """Register an output (``what``: e.g. "the .rrd") and check it; returns the path.

        Raises
        ------
        OutputError
            One line naming the path and what is wrong with it.
        """
        p = Path(path)
        if str(p) == "" or p.name in ("", ".", ".."):
            raise OutputError(f"{what}: {str(path)!r} is not a file name")
        absolute = Path(os.path.abspath(p))
        for q, other in self.outputs.items():
            if q == absolute or (_identity(q) is not None and _identity(q) == _identity(absolute)):
                raise OutputError(f"{p}: {what} and {other} would be the same file")
        if absolute in self._input_paths:
            raise OutputError(f"{p}: {what} would replace the input {self._input_paths[absolute]} (refused)")
        ident = _identity(p)
        if ident is not None and ident in self._inputs:
            raise OutputError(f"{p}: {what} is the input {self._inputs[ident]} (the same file through a link); refused")
        parent = absolute.parent
        try:
            pst = os.stat(parent)
        except FileNotFoundError:
            raise OutputError(f"{p}: the folder {parent} of {what} does not exist") from None
        except NotADirectoryError:
            raise OutputError(f"{p}: a part of the folder {parent} of {what} is a file, not a folder") from None
        except OSError as e:
            raise OutputError(f"{p}: cannot use the folder of {what}: {e.strerror}") from None
        if not stat.S_ISDIR(pst.st_mode):
            raise OutputError(f"{p}: {parent} is not a folder")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise OutputError(f"{p}: no permission to write {what} in {parent}")
        try:
            st = os.lstat(p)
        except FileNotFoundError:
            st = None
        if st is not None:
            target = os.stat(p) if stat.S_ISLNK(st.st_mode) and ident is not None else st
            if stat.S_ISLNK(st.st_mode) and ident is None:
                raise OutputError(f"{p}: {what} is a dangling symbolic link; refused")
            if not stat.S_ISREG(target.st_mode):
                kind = "a folder" if stat.S_ISDIR(target.st_mode) else "not a regular file"
                raise OutputError(f"{p}: {what} exists and is {kind}; refused")
            if not self.force:
                raise OutputError(f"{p}: {what} exists (use --force to replace it)")
        self.outputs[absolute] = what
        return p


def _umask() -> int:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except OSError:
        pass
    return 0o022


def _utf8(name: str) -> bool:
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:  # undecodable bytes of a file name (surrogate escapes)
        return False
    return True


class AtomicOutput:
    """Write a file beside its final path and rename it into place when complete.

    ``temp`` is a fresh, uniquely named file in the target folder (it keeps the final suffix, for
    writers that choose the format by extension). :meth:`commit` renames it over the final path;
    :meth:`abort` (also on leaving a ``with`` block with an exception) removes it.

    Parameters
    ----------
    path : path
        The final path (checked by an :class:`OutputPlan`).
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        # the temporary name is valid UTF-8 even when the final one is not (writers in Rust, e.g.
        # Rerun's, take only UTF-8 paths); the rename to the final name takes any bytes
        stem, suffix = (n if _utf8(n) else "output" for n in (self.path.stem, self.path.suffix))
        fd, tmp = tempfile.mkstemp(prefix=f".{stem}.", suffix=f".partial{suffix if _utf8(suffix) else ''}",
                                   dir=self.path.parent if str(self.path.parent) else ".")
        os.close(fd)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes it 0600; a finished output is like any new file
        self.temp = Path(tmp)
        self.done = False

    def commit(self) -> Path:
        """Rename the finished file into place (only over a regular file); returns the final path."""
        try:
            st = os.lstat(self.path)
        except FileNotFoundError:
            st = None
        if st is not None and not stat.S_ISREG(st.st_mode) and not stat.S_ISLNK(st.st_mode):
            self.abort()
            raise OutputError(f"{self.path}: became something other than a regular file meanwhile; not replaced")
        target = self.path.resolve() if st is not None and stat.S_ISLNK(st.st_mode) else self.path
        os.replace(self.temp, target)
        self.done = True
        return self.path

    def abort(self) -> None:
        """Remove the temporary file (idempotent)."""
        if not self.done:
            try:
                os.unlink(self.temp)
            except FileNotFoundError:
                pass
            self.done = True

    def __enter__(self) -> AtomicOutput:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            if not self.done:
                self.commit()
        else:
            self.abort()
