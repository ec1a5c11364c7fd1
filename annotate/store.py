"""The label store: one SQLite file per labelling project.

Design
------
- **Durability.** WAL journal with ``synchronous=FULL``: a commit returns only after the WAL is
  fsync'ed, so an acknowledged label survives a process kill *and* a power cut. (``NORMAL`` with WAL
  survives a crash of the process but may lose the last commits on power loss; label edits are
  small and rare, so the extra fsync per commit costs nothing that matters.) ``save_label`` returns
  only after its transaction committed; the server acknowledges an edit only after that.
- **Concurrency.** Every write runs in ``BEGIN IMMEDIATE`` (one writer at a time, readers go on);
  ``busy_timeout`` lets other processes (``zcut accuracy`` while the page runs) wait instead of
  failing. One connection per store object, guarded by a lock (the server calls from a thread pool).
- **Schema versioning.** ``PRAGMA user_version`` holds the schema version; :data:`MIGRATIONS` step it
  up one version at a time inside a transaction. A file from a newer zcut is refused.
- **Identity.** A log is its content: the sha256 of the file (streamed), so a renamed or copied log
  keeps its labels. A frame is (log, topic, stamp_ns).
- **Append-only labels.** Every save appends a revision (1, 2, ...) per (frame, annotator);
  triggers forbid UPDATE and DELETE on the label table. The current label of an annotator is the
  latest revision. A save names the revision it was based on; if another save for the same
  frame and annotator landed in between, it is refused (:class:`LabelConflictError`).
- **Masks** are stored as ``zlib(packbits(mask.ravel()))`` with their shape; L ⊆ R ⊆ valid is
  checked before anything is written.
- **One page, a sequence of full states.** A save from the labelling page names the page (``client``,
  a random id per browser tab) and its sequence number. A page's saves are whole labels, not diffs,
  so a save whose base is stale only because *the same page* saved since (two of its requests in
  flight, e.g. the last one sent as the tab closed) is not a conflict: it is appended if it is the
  newer state, and dropped (:class:`LabelSupersededError`, nothing written) if a newer state of that
  page is stored already. Saves of any other page or tool in between are a conflict as before.
- **Names.** An annotator name is stored in NFKC form, stripped, with letters, digits and
  ``space . - _ '`` only, in one script (Han may go with Latin, kana, Hangul or Bopomofo);
  :func:`normalize_annotator` refuses anything else, so a Cyrillic ``а`` cannot hide in ``alice``.
  :meth:`LabelStore.check_new_annotator` also refuses a name whose :func:`annotator_skeleton`
  (look-alike letters, case and separators folded) equals an existing annotator's.
- **Full disk, read-only folders.** A write that finds no space is refused with
  :class:`StoreFullError` ("no space left"), nothing written (the transaction rolls back; the file
  is not damaged), so the page keeps the edit and saves it again. A store in a folder this user
  cannot write (a read-only mount, another user's folder) is still read: SQLite cannot make the
  WAL's index file (``-shm``) there, so it is opened ``immutable`` — safe, as no writer can be at
  work where no ``-wal`` file exists.
- **Servers.** Each ``zcut annotate`` registers itself in the ``servers`` table and updates its
  heartbeat every few seconds (this table is the only one with updates); :meth:`LabelStore.live_servers`
  tells a server (and through it the page) that another one serves the same store. Both may run:
  every write is still a transaction and conflicts are still detected, but two people labelling
  as the same annotator in two servers will meet conflicts.
"""

from __future__ import annotations

import os
import socket
import sqlite3
import threading
import time
import unicodedata
import urllib.parse
import zlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Self

import numpy as np

from zcut.errors import InputShapeError, ZcutError, describe_array

SCHEMA_VERSION = 5
BUSY_TIMEOUT_MS = 10_000
#: Largest mask the store accepts (pixels), a guard against absurd shapes from a client.
MAX_PIXELS = 64_000_000
MAX_ANNOTATOR_LEN = 64
#: A server whose heartbeat is older than this is taken for gone (it was killed).
SERVER_STALE_S = 20.0

# Each entry moves the schema from version i to i + 1 (a list of statements, run in one transaction).
MIGRATIONS: list[list[str]] = [
    [
        """CREATE TABLE logs (
            id INTEGER PRIMARY KEY,
            sha256 TEXT NOT NULL UNIQUE CHECK (length(sha256) = 64),
            name TEXT NOT NULL,
            size_bytes INTEGER NOT NULL,
            added_ns INTEGER NOT NULL
        )""",
        """CREATE TABLE frames (
            id INTEGER PRIMARY KEY,
            log_id INTEGER NOT NULL REFERENCES logs(id),
            topic TEXT NOT NULL,
            stamp_ns INTEGER NOT NULL,
            frame_index INTEGER NOT NULL,
            frame_id TEXT NOT NULL DEFAULT '',
            height INTEGER NOT NULL CHECK (height > 0),
            width INTEGER NOT NULL CHECK (width > 0),
            valid BLOB,
            UNIQUE (log_id, topic, stamp_ns)
        )""",
        """CREATE TABLE labels (
            id INTEGER PRIMARY KEY,
            frame_id INTEGER NOT NULL REFERENCES frames(id),
            annotator TEXT NOT NULL CHECK (length(annotator) BETWEEN 1 AND 64),
            revision INTEGER NOT NULL CHECK (revision >= 1),
            created_ns INTEGER NOT NULL,
            height INTEGER NOT NULL,
            width INTEGER NOT NULL,
            outliers BLOB NOT NULL,
            reviewed BLOB NOT NULL,
            n_outliers INTEGER NOT NULL,
            n_reviewed INTEGER NOT NULL,
            source TEXT NOT NULL DEFAULT 'page',
            UNIQUE (frame_id, annotator, revision)
        )""",
        "CREATE INDEX labels_current ON labels (frame_id, annotator, revision DESC)",
        """CREATE TRIGGER labels_append_only_update BEFORE UPDATE ON labels
            BEGIN SELECT RAISE(ABORT, 'labels are append-only'); END""",
        """CREATE TRIGGER labels_append_only_delete BEFORE DELETE ON labels
            BEGIN SELECT RAISE(ABORT, 'labels are append-only'); END""",
    ],
    [
        "ALTER TABLE labels ADD COLUMN client TEXT",
        "ALTER TABLE labels ADD COLUMN client_seq INTEGER",
        """CREATE TABLE servers (
            id INTEGER PRIMARY KEY,
            pid INTEGER NOT NULL,
            host TEXT NOT NULL,
            port INTEGER,
            log_sha256 TEXT NOT NULL,
            started_ns INTEGER NOT NULL,
            heartbeat_ns INTEGER NOT NULL,
            stopped_ns INTEGER
        )""",
    ],
    [
        # the labelling assistant's models (annotate.assistant): append-only like the labels
        """CREATE TABLE models (
            id INTEGER PRIMARY KEY,
            created_ns INTEGER NOT NULL,
            log_sha256 TEXT NOT NULL,
            part TEXT,
            backend TEXT NOT NULL,
            meta TEXT NOT NULL,
            model BLOB NOT NULL
        )""",
    ],
    [
        # the page's verdicts on part fits (docs/labelling.md, "Judging fits"): append-only, the latest row
        # of a (frame, annotator, fit) says whether that fit is rejected; the fit's position (mm) tells a
        # fit found again from one found otherwise
        """CREATE TABLE fit_decisions (
            id INTEGER PRIMARY KEY,
            frame_id INTEGER NOT NULL REFERENCES frames(id),
            annotator TEXT NOT NULL,
            fit INTEGER NOT NULL CHECK (fit >= 0),
            x_mm REAL NOT NULL,
            y_mm REAL NOT NULL,
            z_mm REAL NOT NULL,
            rejected INTEGER NOT NULL CHECK (rejected IN (0, 1)),
            created_ns INTEGER NOT NULL
        )""",
        "CREATE INDEX fit_decisions_frame ON fit_decisions (frame_id, annotator, fit, id DESC)",
    ],
    [
        # the instances a person seeded on the page (Ctrl+click, docs/labelling.md, "Judging fits"): per
        # (frame, annotator), in the order clicked; replayed on the frame's fits by a restarted server.
        # ``found`` is how many instances the click found (a click that found none is not stored)
        """CREATE TABLE fit_seeds (
            id INTEGER PRIMARY KEY,
            frame_id INTEGER NOT NULL REFERENCES frames(id),
            annotator TEXT NOT NULL,
            x INTEGER NOT NULL CHECK (x >= 0),
            y INTEGER NOT NULL CHECK (y >= 0),
            found INTEGER NOT NULL CHECK (found >= 1),
            created_ns INTEGER NOT NULL
        )""",
        "CREATE INDEX fit_seeds_frame ON fit_seeds (frame_id, annotator, id)",
        """CREATE TRIGGER fit_seeds_append_only_update BEFORE UPDATE ON fit_seeds
            BEGIN SELECT RAISE(ABORT, 'fit seeds are append-only'); END""",
        """CREATE TRIGGER fit_seeds_append_only_delete BEFORE DELETE ON fit_seeds
            BEGIN SELECT RAISE(ABORT, 'fit seeds are append-only'); END""",
    ],
]


class StoreError(ZcutError):
    """The label store cannot be opened or used; the message names the file and the problem."""


class StoreFullError(StoreError):
    """No space left on the store's device: nothing was written (free some space, then save again)."""


class StoreBusyError(StoreError):
    """Another writer (another process or connection) held the store past the busy timeout:
    nothing of this write was done; everything committed before it stays."""


class LabelConflictError(StoreError):
    """A save was based on a revision that is no longer the latest (someone saved in between)."""

    def __init__(self, message: str, *, latest: int) -> None:
        super().__init__(message)
        self.latest = latest


class LabelValidationError(StoreError, ValueError):
    """A label breaks L ⊆ R ⊆ valid, or its masks have the wrong shape, or its annotator name is refused."""


class LabelSupersededError(StoreError):
    """A page's save arrived after a newer state of the same page was stored: nothing was written."""

    def __init__(self, message: str, *, latest: int) -> None:
        super().__init__(message)
        self.latest = latest


@dataclass(frozen=True, slots=True)
class ServerRecord:
    """A running ``zcut annotate`` registered in the store (``port`` None when unknown)."""

    id: int
    pid: int
    host: str
    port: int | None
    log_sha256: str
    started_ns: int
    heartbeat_ns: int


@dataclass(frozen=True, slots=True)
class LogRecord:
    """A registered log: ``id`` in the store, ``sha256`` of its bytes, file ``name``, ``size_bytes``."""

    id: int
    sha256: str
    name: str
    size_bytes: int


@dataclass(frozen=True, slots=True)
class FrameRecord:
    """A registered frame of a log, keyed by (log, topic, stamp_ns); shape (height, width)."""

    id: int
    log_id: int
    topic: str
    stamp_ns: int
    index: int
    frame_id: str
    height: int
    width: int


@dataclass(frozen=True, slots=True)
class Label:
    """One label revision.

    Attributes
    ----------
    frame : int
        Store id of the frame.
    annotator : str
    revision : int
        1, 2, ... per (frame, annotator).
    outliers : (H, W) bool ndarray
        L, the true outliers.
    reviewed : (H, W) bool ndarray
        R, the pixels the annotator reviewed; L ⊆ R.
    created_ns : int
        Wall-clock time of the commit.
    source : str
        ``page``, ``import`` ...
    """

    frame: int
    annotator: str
    revision: int
    outliers: np.ndarray
    reviewed: np.ndarray
    created_ns: int
    source: str


@dataclass(frozen=True, slots=True)
class LabelSummary:
    """The current label of one annotator on one frame, without its masks."""

    frame: int
    annotator: str
    revision: int
    n_outliers: int
    n_reviewed: int
    created_ns: int


#: digests already computed in this process, by (device, inode, size, mtime_ns) of the file
_DIGESTS: dict[tuple[int, int, int, int], str] = {}


def file_sha256(path: str | os.PathLike[str], *, chunk_bytes: int = 1 << 20) -> str:
    """Hex sha256 of a file's bytes (:func:`replay.logs.identity.sha256_of_stream`). A file hashed
    before in this process, unchanged since (same device, inode, size and modification time, taken
    from the open file, and older than 2 s when hashed), is not read again (``zcut annotate --disagreement`` checks the log's hash,
    and the session hashes it too)."""
    from replay.logs.identity import sha256_of_stream

    with open(path, "rb") as f:
        st = os.fstat(f.fileno())
        key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
        if key in _DIGESTS:
            return _DIGESTS[key]
        digest = sha256_of_stream(f, chunk_bytes=chunk_bytes)
        # kept only when not changed while read, and last modified over 2 s ago: file times tick
        # coarsely (a few ms), so a file rewritten at the same size within a tick keeps its mtime
        if os.fstat(f.fileno()).st_mtime_ns == key[3] and time.time_ns() - key[3] > 2_000_000_000:
            _DIGESTS[key] = digest
    return digest


def pack_mask(mask: np.ndarray) -> bytes:
    """``zlib(packbits(mask.ravel()))`` of an (H, W) bool mask (MSB first, like numpy)."""
    return zlib.compress(np.packbits(np.ascontiguousarray(mask, dtype=bool).ravel()).tobytes(), 6)


def unpack_mask(blob: bytes, shape: tuple[int, int]) -> np.ndarray:
    """Inverse of :func:`pack_mask`; raises :class:`LabelValidationError` if the blob does not fit."""
    h, w = shape
    n = h * w
    try:
        d = zlib.decompressobj()
        raw = d.decompress(blob, (n + 7) // 8 + 1)
        if not d.eof or d.unconsumed_tail:
            raise LabelValidationError(f"mask blob does not decompress to {(n + 7) // 8} bytes for shape {shape}")
    except zlib.error as e:
        raise LabelValidationError(f"mask blob is not zlib data: {e}") from None
    if len(raw) != (n + 7) // 8:
        raise LabelValidationError(f"mask blob holds {len(raw)} bytes, shape {shape} needs {(n + 7) // 8}")
    bits = np.unpackbits(np.frombuffer(raw, np.uint8), count=n)
    return bits.view(bool).reshape(h, w)


def check_label(outliers: np.ndarray, reviewed: np.ndarray, *, valid: np.ndarray | None) -> None:
    """Raise :class:`LabelValidationError` unless L ⊆ R ⊆ valid with equal (H, W) bool shapes."""
    for name, m in (("outliers", outliers), ("reviewed", reviewed)):
        if not isinstance(m, np.ndarray) or m.ndim != 2 or m.dtype != np.bool_:
            raise LabelValidationError(f"{name} must be an (H, W) bool array, got {describe_array(m)}")
    if outliers.shape != reviewed.shape:
        raise LabelValidationError(f"outliers {outliers.shape} and reviewed {reviewed.shape} differ in shape")
    if outliers.size > MAX_PIXELS:
        raise LabelValidationError(f"label shape {outliers.shape} exceeds {MAX_PIXELS} pixels")
    if (outliers & ~reviewed).any():
        n = int((outliers & ~reviewed).sum())
        raise LabelValidationError(f"outliers must lie inside reviewed: {n} outlier pixels are not reviewed")
    if valid is not None:
        if valid.shape != reviewed.shape:
            raise LabelValidationError(f"label shape {reviewed.shape} differs from the frame's {valid.shape}")
        if (reviewed & ~valid).any():
            n = int((reviewed & ~valid).sum())
            raise LabelValidationError(f"reviewed must lie inside the valid pixels: {n} reviewed pixels are invalid")


# Letters of other scripts that look like Latin ones (from Unicode's confusables.txt, the common
# Cyrillic, Greek and Armenian ones) and digits that look like letters.
_LOOKALIKE = str.maketrans({
    **dict(zip("авеһіјкӏмнорсѕтуԁԛԝхүѵ", "abehijklmhopcstydqwxyv")),
    **dict(zip("АВЕНІЈКМОРСЅТХУҮԀԌԜ", "ABEHIJKMOPCSTXYYDGW")),
    **dict(zip("αβεικνορτυχγ", "abeikvoptuxy")),
    **dict(zip("ΑΒΕΖΗΙΚΜΝΟΡΤΥΧ", "ABEZHIKMNOPTYX")),
    **dict(zip("օսհոզ", "ouhnq")),
    "0": "o", "1": "l", "|": "l",
})
_SEPARATORS = " .-_'"
# Han goes with these scripts in one name (Unicode TS 39, "highly restrictive").
_SCRIPT_SETS = ({"LATIN", "CJK", "HIRAGANA", "KATAKANA"}, {"LATIN", "CJK", "HANGUL"}, {"LATIN", "CJK", "BOPOMOFO"})


def _script(ch: str) -> str:
    """The script of a letter, from its Unicode name's first word (``LATIN``, ``CYRILLIC``, ``CJK`` ...)."""
    name = unicodedata.name(ch, "")
    return name.split(" ", 1)[0] if name else f"U+{ord(ch):04X}"


def normalize_annotator(name: object) -> str:
    """The stored form of an annotator name: NFKC, stripped, inner white space as one space.

    Raises
    ------
    LabelValidationError
        If the name is empty or longer than :data:`MAX_ANNOTATOR_LEN` characters, holds anything but
        letters, digits, combining marks and ``space . - _ '``, or mixes scripts (a Cyrillic ``а``
        in ``alice``); the message names the character or the scripts.
    """
    if not isinstance(name, str):
        raise LabelValidationError(f"annotator must be a string, got {type(name).__name__}")
    s = " ".join(unicodedata.normalize("NFKC", name).split())
    if not 1 <= len(s) <= MAX_ANNOTATOR_LEN:
        raise LabelValidationError(f"annotator must be 1..{MAX_ANNOTATOR_LEN} characters, got {len(s)}: {name!r:.80}")
    scripts: dict[str, list[str]] = {}
    prev_letter = False
    for ch in s:
        cat = unicodedata.category(ch)
        if cat.startswith("L"):
            scripts.setdefault(_script(ch), []).append(ch)
            prev_letter = True
        elif cat.startswith("M") and prev_letter:
            pass
        elif cat == "Nd" or ch in _SEPARATORS:
            prev_letter = False
        else:
            label = unicodedata.name(ch, "unnamed")
            raise LabelValidationError(
                f"annotator {name!r:.80}: character U+{ord(ch):04X} ({label}) is not allowed "
                "(letters, digits, space . - _ ' only)")
    if len(scripts) > 1 and not any(set(scripts) <= allowed for allowed in _SCRIPT_SETS):
        odd = min(scripts.values(), key=len)[0]  # a letter of the rarest script
        raise LabelValidationError(
            f"annotator {name!r:.80} mixes scripts ({', '.join(sorted(scripts)).lower()}): "
            f"U+{ord(odd):04X} is {unicodedata.name(odd, '?')}; look-alike letters are refused")
    return s


def annotator_skeleton(name: str) -> str:
    """What a name looks like: look-alike letters mapped to Latin, case folded, separators dropped.

    Two different names with one skeleton (``alice``, ``Alice``, ``a1ice``, all-Cyrillic ``аӏісе``)
    would pass for one person in agreement figures.
    """
    s = unicodedata.normalize("NFKC", name).translate(_LOOKALIKE).casefold()
    s = "".join(ch for ch in s if ch not in _SEPARATORS)
    return s.replace("rn", "m").replace("vv", "w").replace("cl", "d")


def _check_annotator(annotator: object) -> str:
    if not isinstance(annotator, str) or normalize_annotator(annotator) != annotator:
        raise LabelValidationError(
            f"annotator {annotator!r:.80} is not in normal form (NFKC, stripped): use normalize_annotator"
        )
    return annotator


class LabelStore:
    """A labelling project in one SQLite file (see the module docstring for the guarantees).

    Parameters
    ----------
    path : path-like
        The SQLite file; created (with the current schema) if absent.
    read_only : bool
        Open for reading only (``labels list``/``export``, ``accuracy``, ``sweep``, ``batch``): the
        file must exist at the current schema version and is never written.

    Use as a context manager or call :meth:`close`.
    """

    def __init__(self, path: str | os.PathLike[str], *, read_only: bool = False) -> None:
        self.path = Path(path)
        self.read_only = read_only
        self._lock = threading.RLock()
        try:
            if read_only:  # the file is never written, not even to switch its journal or migrate it
                if not self.path.is_file():
                    raise FileNotFoundError(2, "no such file", str(self.path))
                self._db = self._open_read_only()
            else:
                self._db = sqlite3.connect(
                    self.path, timeout=BUSY_TIMEOUT_MS / 1000, isolation_level=None, check_same_thread=False
                )
        except sqlite3.Error as e:
            raise StoreError(f"cannot open label store {self.path}: {e}") from e
        try:
            self._refuse_foreign()
            if read_only:
                self._db.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_MS}")
                version = self.schema_version
                if version == 0:
                    raise StoreError(f"{self.path} holds no label store yet (label a log with zcut annotate "
                                     "or zcut labels import first)")
                if version != SCHEMA_VERSION:
                    raise StoreError(
                        f"label store {self.path} has schema version {version}, this zcut reads {SCHEMA_VERSION}"
                        + (" (open it once with zcut annotate or zcut labels import to upgrade it)"
                           if version < SCHEMA_VERSION else ""))
            else:
                self._configure()
                self._migrate()
        except sqlite3.DatabaseError as e:
            self._db.close()
            busy = self._busy(e)
            if busy is not None:
                raise busy from e
            raise StoreError(f"cannot use {self.path} as a label store: {e}") from e
        except BaseException:
            self._db.close()
            raise

    def _open_read_only(self) -> sqlite3.Connection:
        """A read-only connection; ``immutable`` in a folder where SQLite cannot make the WAL's index
        (``-shm``) and no ``-wal`` file shows a writer (see the module docstring)."""
        base = "file:" + urllib.parse.quote(os.path.abspath(self.path))
        db = sqlite3.connect(base + "?mode=ro", uri=True, timeout=BUSY_TIMEOUT_MS / 1000, isolation_level=None,
                             check_same_thread=False)
        try:
            db.execute("PRAGMA user_version").fetchone()
            return db
        except sqlite3.OperationalError as e:
            db.close()
            code = getattr(e, "sqlite_errorcode", None)  # extended codes (SQLITE_READONLY_DIRECTORY = 1544)
            if (code is None or code & 0xFF not in (sqlite3.SQLITE_CANTOPEN, sqlite3.SQLITE_READONLY)) \
                    and "unable to open" not in str(e):
                raise
            if os.path.exists(f"{self.path}-wal"):
                raise StoreError(f"cannot read label store {self.path}: its folder cannot be written here and "
                                 f"{self.path.name}-wal holds commits not yet in the file; open it once where it "
                                 "can be written (or copy both files to such a folder)") from None
        return sqlite3.connect(base + "?mode=ro&immutable=1", uri=True, isolation_level=None,
                               check_same_thread=False)

    def _refuse_foreign(self) -> None:
        """An SQLite file of another application (tables but no zcut schema version) is never touched."""
        if self.schema_version == 0:
            tables = [r[0] for r in self._db.execute(
                "SELECT name FROM sqlite_master WHERE type = 'table' ORDER BY name LIMIT 4").fetchall()]
            if tables:
                raise StoreError(f"{self.path} is an SQLite database of something else (tables "
                                 f"{', '.join(tables)}), not a zcut label store; it was left unchanged")

    # ------------------------------------------------------------------ setup
    def _configure(self) -> None:
        db = self._db
        db.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_MS}")
        mode = db.execute("PRAGMA journal_mode = WAL").fetchone()[0]
        if mode.lower() != "wal":
            raise StoreError(f"label store {self.path}: cannot switch to WAL journal (got {mode})")
        db.execute("PRAGMA synchronous = FULL")
        db.execute("PRAGMA foreign_keys = ON")

    def _migrate(self) -> None:
        with self._lock:
            version = self.schema_version
            if version > SCHEMA_VERSION:
                raise StoreError(
                    f"label store {self.path} has schema version {version}; this zcut knows up to {SCHEMA_VERSION}"
                )
            while version < SCHEMA_VERSION:
                with self._write():
                    # re-read inside the write lock: another process may have migrated meanwhile
                    current = self._db.execute("PRAGMA user_version").fetchone()[0]
                    if current == version:
                        for stmt in MIGRATIONS[version]:
                            self._db.execute(stmt)
                        self._db.execute(f"PRAGMA user_version = {version + 1}")
                version = self.schema_version

    @property
    def schema_version(self) -> int:
        """The file's ``PRAGMA user_version``."""
        return int(self._db.execute("PRAGMA user_version").fetchone()[0])

    def close(self) -> None:
        """Close the connection (committed data is on disk already)."""
        with self._lock:
            self._db.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    class _Tx:
        def __init__(self, store: LabelStore) -> None:
            self.store = store

        def __enter__(self) -> sqlite3.Connection:
            self.store._lock.acquire()
            try:
                self.store._db.execute("BEGIN IMMEDIATE")
            except BaseException as e:
                self.store._lock.release()
                busy = self.store._busy(e)
                if busy is not None:
                    raise busy from e
                raise
            return self.store._db

        def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                     tb: TracebackType | None) -> None:
            try:
                if exc_type is None:
                    self.store._db.execute("COMMIT")
                else:
                    self.store._db.execute("ROLLBACK")
            except sqlite3.DatabaseError as e:
                raise (self.store._full(e) or self.store._busy(e) or self.store._damaged(e)) from e
            finally:
                self.store._lock.release()
            if exc is None:
                return
            if issubclass(type(exc), sqlite3.DatabaseError) and self.store._full(exc):
                raise self.store._full(exc) from exc  # type: ignore[misc]  # not None: tested above
            if issubclass(type(exc), sqlite3.DatabaseError) and self.store._busy(exc):
                raise self.store._busy(exc) from exc  # type: ignore[misc]  # not None: tested above
            if type(exc) is sqlite3.DatabaseError:  # not its subclasses (conflicts, a busy file)
                raise self.store._damaged(exc) from exc

    def _damaged(self, e: BaseException) -> StoreError:
        """A damaged file (a malformed schema, a corrupt page) found by a query: one line naming it."""
        return StoreError(f"label store {self.path} is damaged: {e}")

    def _full(self, e: BaseException) -> StoreFullError | None:
        """The error of a write that found no space (SQLITE_FULL), else None: the file is not damaged."""
        if getattr(e, "sqlite_errorcode", None) == sqlite3.SQLITE_FULL:
            return StoreFullError(f"label store {self.path}: no space left on the device; nothing was saved "
                                  "(free some space, then save again)")
        return None

    def _busy(self, e: BaseException) -> StoreBusyError | None:
        """The error of a statement that waited the whole busy timeout for another writer's lock
        (SQLITE_BUSY, SQLITE_LOCKED), else None: one line naming the store."""
        code = getattr(e, "sqlite_errorcode", None)
        if isinstance(e, sqlite3.OperationalError) and code is not None \
                and code & 0xFF in (sqlite3.SQLITE_BUSY, sqlite3.SQLITE_LOCKED):
            return StoreBusyError(f"label store {self.path} is held by another writer (waited "
                                  f"{BUSY_TIMEOUT_MS / 1000:g} s for its lock); run this again once it is done")
        return None

    def _write(self) -> LabelStore._Tx:
        return LabelStore._Tx(self)

    def _query(self, sql: str, params: Sequence[object] = ()) -> list[tuple[Any, ...]]:
        with self._lock:
            try:
                return self._db.execute(sql, params).fetchall()
            except sqlite3.DatabaseError as e:
                if self._full(e):
                    raise self._full(e) from e  # type: ignore[misc]  # not None: tested above
                if self._busy(e):
                    raise self._busy(e) from e  # type: ignore[misc]  # not None: tested above
                if type(e) is sqlite3.DatabaseError:
                    raise self._damaged(e) from e
                raise

    # ------------------------------------------------------------------- logs
    def add_log(self, path: str | os.PathLike[str], *, sha256: str | None = None) -> LogRecord:
        """Register a log by its content hash (idempotent); returns its record."""
        p = Path(path)
        digest = sha256 or file_sha256(p)
        size = p.stat().st_size
        with self._write() as db:
            db.execute(
                "INSERT OR IGNORE INTO logs (sha256, name, size_bytes, added_ns) VALUES (?, ?, ?, ?)",
                (digest, p.name, size, time.time_ns()),
            )
        rec = self.log_by_sha(digest)
        assert rec is not None
        return rec

    def log_by_sha(self, sha256: str) -> LogRecord | None:
        rows = self._query("SELECT id, sha256, name, size_bytes FROM logs WHERE sha256 = ?", (sha256,))
        return LogRecord(*rows[0]) if rows else None

    def logs(self) -> list[LogRecord]:
        return [LogRecord(*r) for r in self._query("SELECT id, sha256, name, size_bytes FROM logs ORDER BY id")]

    # ----------------------------------------------------------------- frames
    def add_frame(
        self,
        log: LogRecord,
        *,
        topic: str,
        stamp_ns: int,
        index: int,
        shape: tuple[int, int],
        frame_id: str = "",
        valid: np.ndarray | None = None,
    ) -> FrameRecord:
        """Register a frame (idempotent on (log, topic, stamp_ns)); ``valid`` is its (H, W) bool mask."""
        h, w = (int(shape[0]), int(shape[1]))
        if valid is not None and (valid.shape != (h, w) or valid.dtype != np.bool_):
            raise InputShapeError(f"valid must be a ({h}, {w}) bool array, got {describe_array(valid)}")
        with self._write() as db:
            db.execute(
                "INSERT OR IGNORE INTO frames (log_id, topic, stamp_ns, frame_index, frame_id, height, width, valid)"
                " VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (log.id, topic, int(stamp_ns), int(index), frame_id, h, w, None if valid is None else pack_mask(valid)),
            )
        rec = self.frame(log, topic=topic, stamp_ns=stamp_ns)
        assert rec is not None
        if (rec.height, rec.width) != (h, w):
            raise StoreError(
                f"frame {topic}@{stamp_ns} is registered as {rec.height}x{rec.width}, not {h}x{w}"
            )
        return rec

    _FRAME_COLS = "id, log_id, topic, stamp_ns, frame_index, frame_id, height, width"

    def frame(self, log: LogRecord, *, topic: str, stamp_ns: int) -> FrameRecord | None:
        rows = self._query(
            f"SELECT {self._FRAME_COLS} FROM frames WHERE log_id = ? AND topic = ? AND stamp_ns = ?",
            (log.id, topic, int(stamp_ns)),
        )
        return FrameRecord(*rows[0]) if rows else None

    def frames(self, log: LogRecord) -> list[FrameRecord]:
        rows = self._query(
            f"SELECT {self._FRAME_COLS} FROM frames WHERE log_id = ? ORDER BY frame_index, stamp_ns", (log.id,)
        )
        return [FrameRecord(*r) for r in rows]

    def frames_at_stamp(self, stamp_ns: int) -> list[FrameRecord]:
        """Frames of any log and topic with this stamp (a results file re-publishes its source's stamps)."""
        rows = self._query(f"SELECT {self._FRAME_COLS} FROM frames WHERE stamp_ns = ? ORDER BY id", (int(stamp_ns),))
        return [FrameRecord(*r) for r in rows]

    def valid_mask(self, frame: FrameRecord) -> np.ndarray | None:
        rows = self._query("SELECT valid FROM frames WHERE id = ?", (frame.id,))
        if not rows or rows[0][0] is None:
            return None
        return unpack_mask(rows[0][0], (frame.height, frame.width))

    # ----------------------------------------------------------------- labels
    def save_label(
        self,
        frame: FrameRecord,
        *,
        annotator: str,
        outliers: np.ndarray,
        reviewed: np.ndarray,
        base_revision: int | None,
        source: str = "page",
        client: str | None = None,
        client_seq: int | None = None,
    ) -> int:
        """Append a label revision and commit it; returns the new revision number.

        Parameters
        ----------
        frame : FrameRecord
        annotator : str
            In normal form (:func:`normalize_annotator`).
        outliers, reviewed : (H, W) bool ndarray
            L and R with L ⊆ R ⊆ the frame's valid pixels (when the store knows them).
        base_revision : int or None
            The annotator's revision this edit started from (None or 0: none yet). If a later revision
            exists, nothing is written and :class:`LabelConflictError` is raised — unless every later
            revision came from the same ``client`` (see the module docstring).
        source : str
            Where the label came from (``page``, ``import``, ...).
        client : str, optional
            The page that sent the label (a random id per browser tab), with ``client_seq``.
        client_seq : int, optional
            The page's sequence number of this save (increasing per page).

        Returns
        -------
        int
            The committed revision.

        Raises
        ------
        LabelConflictError
            Someone else saved since ``base_revision``.
        LabelSupersededError
            The same page saved a newer state since ``base_revision``: nothing is written.
        """
        _check_annotator(annotator)
        if (client is None) != (client_seq is None):
            raise LabelValidationError("client and client_seq come together")
        if (frame.height, frame.width) != tuple(np.shape(outliers)):
            raise LabelValidationError(
                f"label shape {tuple(np.shape(outliers))} differs from frame {frame.height}x{frame.width}"
            )
        valid = self.valid_mask(frame)
        check_label(outliers, reviewed, valid=valid)
        blob_l, blob_r = pack_mask(outliers), pack_mask(reviewed)
        n_l, n_r = int(outliers.sum()), int(reviewed.sum())
        base = int(base_revision or 0)
        with self._write() as db:
            latest: int = db.execute(
                "SELECT COALESCE(MAX(revision), 0) FROM labels WHERE frame_id = ? AND annotator = ?",
                (frame.id, annotator),
            ).fetchone()[0]
            if latest != base:
                since = db.execute(
                    "SELECT client, client_seq FROM labels WHERE frame_id = ? AND annotator = ? AND revision > ?",
                    (frame.id, annotator, base),
                ).fetchall()
                if client is None or base > latest or any(c != client for c, _ in since):
                    raise LabelConflictError(
                        f"frame {frame.index}: {annotator!r} is at revision {latest}, the edit was based on {base}",
                        latest=latest,
                    )
                if any(seq >= client_seq for _, seq in since):
                    raise LabelSupersededError(
                        f"frame {frame.index}: a newer state of this page is stored already (revision {latest})",
                        latest=latest,
                    )
            db.execute(
                "INSERT INTO labels (frame_id, annotator, revision, created_ns, height, width, outliers, reviewed,"
                " n_outliers, n_reviewed, source, client, client_seq) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (frame.id, annotator, latest + 1, time.time_ns(), frame.height, frame.width, blob_l, blob_r, n_l, n_r,
                 source, client, client_seq),
            )
        return latest + 1

    _LABEL_COLS = "frame_id, annotator, revision, outliers, reviewed, created_ns, source, height, width"

    def _label_from_row(self, row: tuple[Any, ...]) -> Label:
        fid, ann, rev, bl, br, created, source, h, w = row
        return Label(fid, ann, rev, unpack_mask(bl, (h, w)), unpack_mask(br, (h, w)), created, source)

    def label(self, frame: FrameRecord, *, annotator: str, revision: int | None = None) -> Label | None:
        """The annotator's latest label of the frame (or a given revision); None if there is none."""
        if revision is None:
            rows = self._query(
                f"SELECT {self._LABEL_COLS} FROM labels WHERE frame_id = ? AND annotator = ?"
                " ORDER BY revision DESC LIMIT 1",
                (frame.id, annotator),
            )
        else:
            rows = self._query(
                f"SELECT {self._LABEL_COLS} FROM labels WHERE frame_id = ? AND annotator = ? AND revision = ?",
                (frame.id, annotator, int(revision)),
            )
        return self._label_from_row(rows[0]) if rows else None

    def label_blobs(self, frame: FrameRecord, *, annotator: str) -> tuple[int, bytes, bytes] | None:
        """(revision, packed outliers, packed reviewed) of the latest label, as stored (for the page)."""
        rows = self._query(
            "SELECT revision, outliers, reviewed FROM labels WHERE frame_id = ? AND annotator = ?"
            " ORDER BY revision DESC LIMIT 1",
            (frame.id, annotator),
        )
        return (rows[0][0], bytes(rows[0][1]), bytes(rows[0][2])) if rows else None

    def revisions(self, frame: FrameRecord, *, annotator: str) -> list[int]:
        rows = self._query(
            "SELECT revision FROM labels WHERE frame_id = ? AND annotator = ? ORDER BY revision", (frame.id, annotator)
        )
        return [r[0] for r in rows]

    def annotators(self, log: LogRecord | None = None) -> list[str]:
        if log is None:
            rows = self._query("SELECT DISTINCT annotator FROM labels ORDER BY annotator")
        else:
            rows = self._query(
                "SELECT DISTINCT l.annotator FROM labels l JOIN frames f ON f.id = l.frame_id"
                " WHERE f.log_id = ? ORDER BY l.annotator",
                (log.id,),
            )
        return [r[0] for r in rows]

    def current_labels(self, log: LogRecord, *, annotator: str) -> dict[int, LabelSummary]:
        """Frame id -> summary of the annotator's latest label, for every labelled frame of the log."""
        rows = self._query(
            "SELECT l.frame_id, l.annotator, l.revision, l.n_outliers, l.n_reviewed, l.created_ns"
            " FROM labels l JOIN frames f ON f.id = l.frame_id"
            " WHERE f.log_id = ? AND l.annotator = ? AND l.revision ="
            " (SELECT MAX(revision) FROM labels m WHERE m.frame_id = l.frame_id AND m.annotator = l.annotator)",
            (log.id, annotator),
        )
        return {r[0]: LabelSummary(*r) for r in rows}

    # ------------------------------------------------------------------ fits
    def save_fit_decision(self, frame: FrameRecord, *, annotator: str, fit: int,
                          position_mm: Sequence[float], rejected: bool) -> None:
        """Append whether ``annotator`` rejects part fit ``fit`` of the frame (its position, mm, in the
        camera frame: the translation of its pose); the latest row of a fit counts."""
        who = _check_annotator(annotator)
        x, y, z = (float(v) for v in position_mm)
        if not (int(fit) >= 0 and np.isfinite([x, y, z]).all()):
            raise LabelValidationError(f"a fit decision needs a fit index >= 0 and a finite position, got "
                                       f"{fit!r} at {position_mm!r}")
        with self._write() as db:
            db.execute("INSERT INTO fit_decisions (frame_id, annotator, fit, x_mm, y_mm, z_mm, rejected, created_ns)"
                       " VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                       (frame.id, who, int(fit), x, y, z, int(bool(rejected)), time.time_ns()))

    def rejected_fits(self, frame: FrameRecord, *, annotator: str) -> dict[int, tuple[float, float, float]]:
        """The fits ``annotator`` rejects on the frame (their latest decision): fit index -> its
        position (mm) when rejected."""
        rows = self._query(
            "SELECT d.fit, d.x_mm, d.y_mm, d.z_mm, d.rejected FROM fit_decisions d WHERE d.frame_id = ? AND"
            " d.annotator = ? AND d.id = (SELECT MAX(id) FROM fit_decisions m WHERE m.frame_id = d.frame_id"
            " AND m.annotator = d.annotator AND m.fit = d.fit)", (frame.id, annotator))
        return {int(r[0]): (float(r[1]), float(r[2]), float(r[3])) for r in rows if r[4]}

    def save_fit_seed(self, frame: FrameRecord, *, annotator: str, x: int, y: int, found: int) -> None:
        """Append that ``annotator`` seeded a missed instance at pixel (``x``, ``y``) of the frame (a Ctrl+click
        on the page) and that it found ``found`` >= 1 instances; :meth:`fit_seeds` gives them back in order."""
        who = _check_annotator(annotator)
        if not (isinstance(x, int) and isinstance(y, int) and 0 <= x < frame.width and 0 <= y < frame.height
                and isinstance(found, int) and found >= 1):
            raise LabelValidationError(f"a fit seed needs a pixel of the {frame.width}x{frame.height} frame and "
                                       f"found >= 1, got ({x!r}, {y!r}), found {found!r}")
        with self._write() as db:
            db.execute("INSERT INTO fit_seeds (frame_id, annotator, x, y, found, created_ns) VALUES (?, ?, ?, ?, ?, ?)",
                       (frame.id, who, x, y, found, time.time_ns()))

    def fit_seeds(self, frame: FrameRecord, *, annotator: str) -> tuple[tuple[int, int], ...]:
        """The pixels (x, y) where ``annotator`` seeded instances on the frame, in the order clicked."""
        rows = self._query("SELECT x, y FROM fit_seeds WHERE frame_id = ? AND annotator = ? ORDER BY id",
                           (frame.id, annotator))
        return tuple((int(r[0]), int(r[1])) for r in rows)

    def label_count(self) -> int:
        """Number of label revisions in the store (all annotators, all revisions)."""
        return int(self._query("SELECT COUNT(*) FROM labels")[0][0])

    # ------------------------------------------------------------------ names
    def check_new_annotator(self, name: object, *, also: Iterable[str] = ()) -> str:
        """The normal form of ``name``, refused if it looks like another annotator's.

        Parameters
        ----------
        name : str
        also : iterable of str
            Names in use that the store may not hold yet (other pages of a running server).

        Raises
        ------
        LabelValidationError
            :func:`normalize_annotator` refuses it, or its :func:`annotator_skeleton` equals that of
            a different name in the store or in ``also`` (the message names that one).
        """
        s = normalize_annotator(name)
        skel = annotator_skeleton(s)
        for other in [*self.annotators(), *also]:
            if other != s and annotator_skeleton(other) == skel:
                raise LabelValidationError(
                    f"annotator {s!r} looks like the existing annotator {other!r}: use {other!r} if that is you, "
                    "else a name that looks different")
        return s

    # ---------------------------------------------------------------- servers
    def register_server(self, *, log_sha256: str, port: int | None = None) -> ServerRecord:
        """Record this process as a server of the store (see :meth:`live_servers`)."""
        now = time.time_ns()
        with self._write() as db:
            cur = db.execute(
                "INSERT INTO servers (pid, host, port, log_sha256, started_ns, heartbeat_ns) VALUES (?, ?, ?, ?, ?, ?)",
                (os.getpid(), socket.gethostname(), port, log_sha256, now, now),
            )
            sid = int(cur.lastrowid)  # type: ignore[arg-type]  # an INSERT sets it
        return ServerRecord(sid, os.getpid(), socket.gethostname(), port, log_sha256, now, now)

    def heartbeat_server(self, server_id: int) -> None:
        """Tell the others that the server ``server_id`` still runs."""
        with self._write() as db:
            db.execute("UPDATE servers SET heartbeat_ns = ? WHERE id = ?", (time.time_ns(), int(server_id)))

    def unregister_server(self, server_id: int) -> None:
        """The server ``server_id`` stopped."""
        with self._write() as db:
            db.execute("UPDATE servers SET stopped_ns = ? WHERE id = ?", (time.time_ns(), int(server_id)))

    def save_model(self, *, log_sha256: str, part: str | None, backend: str, meta: str, model: bytes) -> int:
        """Append an assistant model; returns its id."""
        with self._write() as db:
            cur = db.execute("INSERT INTO models (created_ns, log_sha256, part, backend, meta, model)"
                             " VALUES (?, ?, ?, ?, ?, ?)", (time.time_ns(), log_sha256, part, backend, meta, model))
            return int(cur.lastrowid)  # type: ignore[arg-type]  # an INSERT sets it

    def latest_model(self, *, log_sha256: str | None = None) -> ModelRecord | None:
        """The newest stored model (of one log's labels, or of any)."""
        where, params = ("WHERE log_sha256 = ?", (log_sha256,)) if log_sha256 else ("", ())
        rows = self._query("SELECT id, created_ns, log_sha256, part, backend, meta, model FROM models "
                           f"{where} ORDER BY id DESC LIMIT 1", params)
        if not rows:
            return None
        r = rows[0]
        return ModelRecord(int(r[0]), int(r[1]), r[2], r[3], r[4], r[5], bytes(r[6]))

    def live_servers(self, *, stale_after_s: float = SERVER_STALE_S) -> list[ServerRecord]:
        """Servers of this store that have not stopped and beat within ``stale_after_s`` seconds (on
        this host: whose process still exists), oldest first."""
        since = time.time_ns() - int(stale_after_s * 1e9)
        rows = self._query(
            "SELECT id, pid, host, port, log_sha256, started_ns, heartbeat_ns FROM servers"
            " WHERE stopped_ns IS NULL AND heartbeat_ns >= ? ORDER BY id", (since,))
        here = socket.gethostname()
        return [ServerRecord(*r) for r in rows if r[2] != here or _pid_alive(r[1])]


@dataclass(frozen=True, slots=True)
class ModelRecord:
    """A stored assistant model (:mod:`annotate.assistant`).

    Attributes
    ----------
    id, created_ns : int
    log_sha256 : str
        The log whose labels trained it.
    part : str or None
        The part kind of that log's config.
    backend : str
        The library that trained it (its text format is ``model``).
    meta : str
        JSON: features, trained frames, annotators, held-out figures.
    model : bytes
        The model in its library's own text format (never a pickle).
    """

    id: int
    created_ns: int
    log_sha256: str
    part: str | None
    backend: str
    meta: str
    model: bytes


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


def iter_current_labels(store: LabelStore, log: LogRecord, *, annotator: str) -> Iterable[tuple[FrameRecord, Label]]:
    """(frame, latest label) for every frame of the log the annotator labelled, in frame order."""
    current = store.current_labels(log, annotator=annotator)
    for fr in store.frames(log):
        if fr.id in current:
            lab = store.label(fr, annotator=annotator)
            if lab is not None:
                yield fr, lab
