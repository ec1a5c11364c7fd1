"""Outputs that never replace an input, and that one process writes at a time (docs/cli.md).

Every command that writes files plans them first with an :class:`OutputPlan`: an output that is an
input (the same path, a hard link, a symlink: compared by device and inode as well as by path), two
outputs on one path, an output under a regular file or in a missing folder, an existing output
without ``--force``, or an existing output that is not a regular file (a device, a FIFO, a folder)
is refused before any work, with a one-line :class:`OutputError` naming the path.

A planned output is **locked** for as long as the plan is open (:class:`OutputLock`: an OS lock,
``flock``, on a small file ``.NAME.zcut.lock`` beside it, which the lock's holder removes when it is
done): a second process that plans the same output while the first one writes it is refused with
:class:`OutputBusyError`. The lock belongs to the open file, so it dies with its process — a process
killed with ``kill -9`` leaves at most an empty lock file, which the next writer takes over.

A planned output is then written by :class:`AtomicOutput`: into a temporary file with a unique name
beside its final path (``.NAME.XXXXXXXX.partial.SUFFIX``, never a name a user's file may have),
renamed into place only when complete and only over a regular file, and removed if the work fails.
The temporary is locked too while it is written: a later run that plans the same output removes the
temporaries of that output that no live process holds (:func:`remove_stale_temporaries`), the
leftovers of a process that was killed.
"""

from __future__ import annotations

import errno
import fcntl
import os
import re
import secrets
import stat
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType

from replay.process import interrupts_deferred, raise_if_interrupted
from zcut.errors import ZcutError

__all__ = ["AtomicOutput", "OutputBusyError", "OutputError", "OutputLock", "OutputPlan", "config_path_for",
           "lock_path_for", "naming", "remove_stale_temporaries", "remove_stale_temporaries_in"]

#: the suffix of an output's lock file, ``.NAME.zcut.lock`` beside it
LOCK_SUFFIX = ".zcut.lock"


class OutputError(ZcutError):
    """An output path would destroy data or cannot be written; the message names the path."""


def folder_gone(path: str | os.PathLike[str]) -> OutputError:
    """The error of an output whose folder was removed (or replaced) while zcut wrote it."""
    folder = Path(path).parent if str(Path(path).parent) else Path(".")
    return OutputError(f"{path}: its folder {folder} was removed while zcut wrote it; the output was not "
                       "written and nothing of it is left")


class OutputBusyError(OutputError):
    """Another process is writing the output (it holds the output's lock)."""


def config_path_for(output: str | os.PathLike[str]) -> Path:
    """Where the resolved config goes beside an output: ``OUT.rrd`` -> ``OUT.config.toml``."""
    p = Path(output)
    return p.with_name(p.stem + ".config.toml")


def lock_path_for(output: str | os.PathLike[str]) -> Path:
    """The lock file of an output: ``DIR/NAME`` -> ``DIR/.NAME.zcut.lock``."""
    p = Path(output)
    return p.with_name(f".{p.name}{LOCK_SUFFIX}")


@contextmanager
def naming(output: str | os.PathLike[str], *temporaries: str | os.PathLike[str]) -> Iterator[None]:
    """An ``OSError`` raised while writing ``output`` names it: a write to an open file (a full disk)
    raises one without a file name, and one naming a temporary would name a file that is gone."""
    try:
        yield
    except OSError as e:
        if e.filename is None or str(e.filename) in {str(t) for t in temporaries}:
            raise OSError(e.errno, e.strerror or str(e), str(output)) from e
        raise


def _identity(path: Path) -> tuple[int, int] | None:
    """(device, inode) of what ``path`` names (links followed), None when it does not exist."""
    try:
        st = os.stat(path)
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as e:  # e.g. a symlink loop, a permission problem
        raise OutputError(f"{path}: cannot check the output path: {e.strerror}") from None
    return st.st_dev, st.st_ino


def _same_file(fd: int, path: Path) -> bool:
    """True when ``path`` (not followed) is still the file open as ``fd``."""
    try:
        st = os.stat(path, follow_symlinks=False)
    except OSError:
        return False
    fst = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (fst.st_dev, fst.st_ino)


class OutputLock:
    """An exclusive OS lock (``flock``) on an output, held while one process writes it.

    The lock is taken on a lock file (default ``.NAME.zcut.lock`` beside the output, see
    :func:`lock_path_for`), created if absent and removed by :meth:`release`. A lock file left by a
    killed process is free (the kernel drops a lock with its process) and is taken over. Taking it
    never waits: a held lock is a :class:`OutputBusyError` at once.

    Parameters
    ----------
    output : path
        The output (a file, or a study's folder), named in the messages.
    what : str
        What the output is ("the .rrd"), for the messages.
    lock_file : path, optional
        Where the lock lives (default :func:`lock_path_for` ``(output)``).
    """

    _fd: int | None = None  # on the class: ``__del__`` of an object a signal cut off in ``__init__`` reads it

    def __init__(self, output: str | os.PathLike[str], *, what: str = "the output",
                 lock_file: str | os.PathLike[str] | None = None) -> None:
        self.output = Path(output)
        self.what = what
        self.lock_file = lock_path_for(output) if lock_file is None else Path(lock_file)
        self._fd = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> OutputLock:
        """Take the lock (idempotent); returns self.

        Raises
        ------
        OutputBusyError
            Another process holds it.
        OutputError
            The lock file cannot be made (no space, no permission, a symbolic link in its place).
        """
        if self._fd is not None:
            return self
        lp = self.lock_file
        for _ in range(100):  # a race with a releasing holder (it removes the file) is retried
            writable = True
            try:
                fd = os.open(lp, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o666)
            except PermissionError:  # another user's lock file, left behind: reading is enough to lock it
                writable = False
                try:
                    fd = os.open(lp, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
                except OSError as e:
                    raise self._cannot(e) from None
            except OSError as e:
                raise self._cannot(e) from None
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                os.close(fd)
                raise OutputError(f"{self.output}: its lock file {lp} is not a regular file; remove it")
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _read_pid(fd)
                os.close(fd)
                who = f"another zcut process (pid {holder})" if holder else "another zcut process"
                raise OutputBusyError(f"{self.output}: {who} is writing {self.what}; wait for it to finish "
                                      "or choose another output") from None
            if _same_file(fd, lp):
                break
            os.close(fd)  # the holder removed the file between our open and our lock: take the new one
        else:  # pragma: no cover - 100 lost races in a row
            raise OutputBusyError(f"{self.output}: another zcut process keeps taking {self.what}'s lock")
        if writable:
            try:
                os.ftruncate(fd, 0)
                os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            except OSError:  # a full disk: the pid is only for the message of a refused writer
                pass
        self._fd = fd
        return self

    def _cannot(self, e: OSError) -> OutputError:
        why = "no space left on the device" if e.errno == errno.ENOSPC else (
            "a symbolic link is in its place" if e.errno == errno.ELOOP else (e.strerror or str(e)))
        return OutputError(f"{self.output}: cannot lock {self.what} ({self.lock_file.name}): {why}")

    def release(self) -> None:
        """Remove the lock file and drop the lock (idempotent)."""
        fd, self._fd = self._fd, None
        if fd is None:
            return
        try:
            if _same_file(fd, self.lock_file):  # removed while held: a waiting process retries
                os.unlink(self.lock_file)
        except OSError:  # a folder where we may lock but not remove (another user's sticky /tmp)
            pass
        finally:
            os.close(fd)

    def __enter__(self) -> OutputLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()

    def __del__(self) -> None:
        _close_quietly(self._fd)


def _close_quietly(fd: int | None) -> None:
    """Close ``fd`` (None: nothing), ignoring the error (what a collected owner still holds)."""
    if fd is not None:
        try:
            os.close(fd)
        except OSError:
            pass


def _read_pid(fd: int) -> int | None:
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def _temp_parts(path: Path) -> tuple[str, str]:
    """(stem, suffix) in a temporary's name: valid UTF-8 even when the final name is not (writers in
    Rust, e.g. Rerun's, take only UTF-8 paths); the rename to the final name takes any bytes."""
    stem, suffix = path.stem, path.suffix
    return (stem if _utf8(stem) else "output"), (suffix if _utf8(suffix) else "")


def _temp_pattern(path: Path) -> re.Pattern[str]:
    """The names of ``path``'s temporaries (this module's ``secrets`` names and the 8 characters of
    older zcut's ``tempfile.mkstemp``), and nothing else: not another output's."""
    stem, suffix = _temp_parts(path)
    return re.compile(rf"\.{re.escape(stem)}\.[a-z0-9_]{{8}}\.partial{re.escape(suffix)}")


def _remove_if_unheld(path: Path) -> bool:
    """Remove a temporary unless a live process holds its lock; True when removed."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK)
    except OSError:
        return False
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return False
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return False  # a live writer
        if not _same_file(fd, path):
            return False
        try:
            os.unlink(path)
        except OSError:
            return False
        return True
    finally:
        os.close(fd)


def _remove_unheld_matching(folder: str | os.PathLike[str], pattern: re.Pattern[str]) -> list[Path]:
    """Remove the entries of ``folder`` whose names match ``pattern`` and that no live process holds."""
    removed: list[Path] = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for e in entries:
        if pattern.fullmatch(e.name) and _remove_if_unheld(Path(e.path)):
            removed.append(Path(e.path))
    return removed


def remove_stale_temporaries(output: str | os.PathLike[str]) -> list[Path]:
    """Remove the temporaries of ``output`` (``.NAME.XXXXXXXX.partial.SUFFIX`` beside it) that no
    live process holds: what a killed writer left. Returns the paths removed.

    Call it while holding the output's :class:`OutputLock` (an :class:`OutputPlan` does).
    """
    p = Path(output)
    folder = p.parent if str(p.parent) else Path(".")
    pattern = _temp_pattern(p)
    return _remove_unheld_matching(folder, pattern)


def remove_stale_temporaries_in(folder: str | os.PathLike[str]) -> list[Path]:
    """Remove every zcut temporary (``.*.XXXXXXXX.partial*``) in ``folder`` that no live process
    holds: for a folder that one locked process owns (a study's output folder)."""
    pattern = re.compile(r"\..+\.[a-z0-9_]{8}\.partial(\.[^/]*)?")
    return _remove_unheld_matching(folder, pattern)


@dataclass
class OutputPlan:
    """The outputs of one command, checked together against its inputs before any work, and locked
    while the plan is open (use it as a context manager, or call :meth:`close`).

    Parameters
    ----------
    inputs : list of path
        Every file the command reads (logs, config files, bin models, label stores).
    force : bool
        Replace existing outputs (``--force``).
    """

    inputs: list[str | os.PathLike[str]] = field(default_factory=list)
    force: bool = False
    outputs: dict[Path, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._inputs: dict[tuple[int, int], Path] = {}
        self._input_paths: dict[Path, Path] = {}
        self._locks: list[OutputLock] = []
        for p in self.inputs:
            self.add_input(p)

    def add_input(self, path: str | os.PathLike[str]) -> None:
        """Register a file the command reads."""
        p = Path(path)
        ident = _identity(p)
        if ident is not None:
            self._inputs[ident] = p
        self._input_paths[Path(os.path.abspath(p))] = p

    def add(self, path: str | os.PathLike[str], what: str) -> Path:
        """Register an output (``what``: e.g. "the .rrd"), check it and lock it; returns the path.

        The temporaries a killed writer of this output left beside it are removed.

        Raises
        ------
        OutputError
            One line naming the path and what is wrong with it.
        OutputBusyError
            Another process is writing it.
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
        lock = OutputLock(p, what=what).acquire()  # before the existence check: a writer may be renaming
        try:
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
        except BaseException:
            lock.release()
            raise
        self._locks.append(lock)
        remove_stale_temporaries(p)
        self.outputs[absolute] = what
        return p

    def close(self) -> None:
        """Release the outputs' locks (their lock files are removed)."""
        locks, self._locks = self._locks, []
        for lock in reversed(locks):
            lock.release()

    def __enter__(self) -> OutputPlan:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _utf8(name: str) -> bool:
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:  # undecodable bytes of a file name (surrogate escapes)
        return False
    return True


class AtomicOutput:
    """Write a file beside its final path and rename it into place when complete.

    ``temp`` is a fresh, uniquely named file in the target folder (it keeps the final suffix, for
    writers that choose the format by extension), locked while this object lives so that a later
    run can tell it from a killed writer's leftover. :meth:`commit` renames it over the final path;
    :meth:`abort` (also on leaving a ``with`` block with an exception, an interruption included)
    removes it.

    Parameters
    ----------
    path : path
        The final path (checked by an :class:`OutputPlan`).
    """

    # on the class, not only the instance: a signal can raise before ``__init__`` sets it, and ``__del__`` of that
    # half-made object then reads this (a batch's worker printed an AttributeError after "interrupted (SIGTERM)")
    _fd: int | None = None

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.done = False
        self._fd = None
        try:
            # a signal waits for the temporary and its lock to be whole: one that cut in after the file was
            # made left it, and its lock held by this process's open descriptor, so that no clean-up of
            # this process could remove it (a study's folder kept a temporary after SIGTERM)
            with interrupts_deferred():
                self._create()
        except BaseException:
            if self._fd is not None:  # made, then the signal raised at the block's end: nothing is left
                self.abort()
            raise

    def _create(self) -> None:
        folder = self.path.parent if str(self.path.parent) else Path(".")
        stem, suffix = _temp_parts(self.path)
        for _ in range(100):
            tmp = folder / f".{stem}.{secrets.token_hex(4)}.partial{suffix}"
            try:  # the mode a new file gets (0666 less the umask): a finished output is like any new file
                fd = os.open(tmp, os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o666)
            except FileExistsError:  # pragma: no cover - 2**32 names
                continue
            except (FileNotFoundError, NotADirectoryError):  # planned in a folder that was there
                raise folder_gone(self.path) from None
            break
        else:  # pragma: no cover
            raise OutputError(f"{self.path}: no free temporary name beside it")
        self.temp = tmp
        self._fd = fd
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:  # pragma: no cover - a file system without locks: the temporary is still unique
            pass

    def _close_fd(self) -> None:
        fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)

    def commit(self) -> Path:
        """Rename the finished file into place (only over a regular file); returns the final path.
        After a signal whose exception a library swallowed, raises :class:`~replay.process.Interrupted`
        instead (the temporary is removed): an interrupted command publishes nothing."""
        try:
            raise_if_interrupted()
        except BaseException:
            self.abort()
            raise
        try:
            st = os.lstat(self.path)
        except FileNotFoundError:
            st = None
        if st is not None and not stat.S_ISREG(st.st_mode) and not stat.S_ISLNK(st.st_mode):
            self.abort()
            raise OutputError(f"{self.path}: became something other than a regular file meanwhile; not replaced")
        target = self.path.resolve() if st is not None and stat.S_ISLNK(st.st_mode) else self.path
        try:
            os.replace(self.temp, target)
        except (FileNotFoundError, NotADirectoryError):
            self.abort()
            raise folder_gone(self.path) from None
        except BaseException:
            self.abort()
            raise
        self.done = True
        self._close_fd()
        return self.path

    def abort(self) -> None:
        """Remove the temporary file (idempotent)."""
        if not self.done:
            try:
                os.unlink(self.temp)
            except FileNotFoundError:
                pass
            self.done = True
        self._close_fd()

    def __enter__(self) -> AtomicOutput:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            if not self.done:
                self.commit()
        else:
            self.abort()

    def __del__(self) -> None:
        _close_quietly(self._fd)
