"""A study's output folder: what was asked (``run.json``), one part file per finished unit, and the
merged tables.

Each finished unit is written at once, atomically, as ``parts/UNIT.parquet`` (its rows) and
``parts/UNIT.json`` (its damage, unscored frames and cost). Running the same study again over the
same folder skips the units whose parts exist, so an interrupted run (even ``kill -9`` of the driver)
loses at most the units in flight. ``run.json`` holds what identifies the study: the kind of study,
its options, per log (by content hash) the resolved config, and per input path the content hash it
had; a folder holding another config's run is refused before any work, never mixed, and so is a
folder whose input log changed content since (the old and the new frames would mix): with
``start_afresh`` (``--force``) the study's files are removed and the study starts again.

One process at a time writes a study's folder: the store locks it (:class:`replay.outputs.OutputLock`
on ``DIR/.zcut.lock``) from its opening to :meth:`PartStore.close`, and a second ``zcut batch`` or
``zcut sweep`` on the same folder meanwhile is refused. Opening and closing the store remove the
temporaries that no live process holds (what a killed driver or worker left).
"""

from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from replay.errors import ConfigError
from replay.outputs import AtomicOutput, OutputLock, remove_stale_temporaries_in

if TYPE_CHECKING:
    import pyarrow as pa

RUN_FILE = "run.json"
PARTS = "parts"
#: the study folder's lock file (inside it)
LOCK_FILE = ".zcut.lock"
#: the folders of a study where units write (per-log outputs of ``zcut batch --results/--rrd`` too)
WRITTEN_FOLDERS = (".", PARTS, "results", "rrd")
#: what a study writes in its folder (removed when it starts afresh): files, then folders
STUDY_FILES = (RUN_FILE, "frames.parquet", "sweep.parquet", "summary.json", "tuned.toml", "report.html")
STUDY_FOLDERS = (PARTS, "results", "rrd", "plots")


class PartStore:
    """The output folder of one study.

    Parameters
    ----------
    root : path
        The folder (created if missing; its parent must exist).
    identity : dict
        What the study is: ``{"kind": ..., "options": {...}, "logs": {sha256: config_sha},
        "paths": {path: sha256}}``.
    start_afresh : bool
        When an input path holds other content than in the folder's run (``--force``): remove the
        study's files and start again, instead of refusing.
    stream : text stream, optional
        Where to say that it starts afresh (stderr).
    """

    def __init__(self, root: str | os.PathLike[str], identity: dict[str, Any], *, start_afresh: bool = False,
                 stream: IO[str] | None = None) -> None:
        self.root = Path(root)
        if self.root.exists() and not self.root.is_dir():
            raise ConfigError(f"-o {self.root}: exists and is not a folder")
        if not self.root.parent.is_dir():
            raise ConfigError(f"-o {self.root}: the folder {self.root.parent} does not exist")
        self.identity = identity
        self.start_afresh = start_afresh
        self.stream = sys.stderr if stream is None else stream
        self._lock = self._lock_folder()
        try:
            self._open()
        except BaseException:
            self.close()
            raise

    def _lock_folder(self) -> OutputLock:
        try:
            self.root.mkdir(exist_ok=True)
        except OSError as e:
            raise ConfigError(f"-o {self.root}: cannot create the folder: {e.strerror or e}") from None
        lock = OutputLock(self.root, what="this study folder", lock_file=self.root / LOCK_FILE)
        return lock.acquire()

    def remove_stale_temporaries(self) -> list[Path]:
        """Remove the temporaries in the study's folders that no live process holds."""
        return [p for sub in WRITTEN_FOLDERS for p in remove_stale_temporaries_in(self.root / sub)]

    def _open(self) -> None:
        self.remove_stale_temporaries()
        identity = self.identity
        run = self.root / RUN_FILE
        if run.is_file():
            try:
                old = json.loads(run.read_text())
            except (OSError, ValueError):
                raise ConfigError(f"{run}: not a zcut study's run file (delete the folder or choose another)") from None
            if old.get("kind") != identity.get("kind"):
                raise ConfigError(f"-o {self.root}: holds a {old.get('kind')} run, not a {identity.get('kind')}: "
                                  "choose another folder")
            changed = self._changed_inputs(old)
            if changed and self.start_afresh:
                print(f"zcut: {changed}; --force: the study starts afresh (its earlier results removed)",
                      file=self.stream, flush=True)
                self._remove_study()
            elif changed:
                raise ConfigError(f"-o {self.root}: {changed}: its old and new frames would mix in one study; "
                                  "--force starts it afresh (or choose another folder)")
            else:
                self._check_compatible(old)
                merged = dict(old)
                merged["logs"] = {**old.get("logs", {}), **identity.get("logs", {})}
                merged["paths"] = {**old.get("paths", {}), **identity.get("paths", {})}
                self.identity = merged
        elif any(p.name != LOCK_FILE for p in self.root.iterdir()):
            raise ConfigError(f"-o {self.root}: the folder holds other files and no {RUN_FILE}: "
                              "choose an empty or new folder")
        (self.root / PARTS).mkdir(exist_ok=True)
        self._write_json(run, self.identity)

    def close(self) -> None:
        """Remove what no live process holds of the temporaries and release the folder's lock
        (idempotent). The executor must have stopped its workers before."""
        if self._lock.held:
            try:
                self.remove_stale_temporaries()
            finally:
                self._lock.release()

    def __enter__(self) -> PartStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _changed_inputs(self, old: dict[str, Any]) -> str | None:
        """What says that an input path holds other content than in the folder's run (None when
        none does): the first such log, its content hash then and now. A path whose old content is
        still an input (under another name) has not lost its frames: not a change."""
        had = old.get("paths") or {}
        now = self.identity.get("paths") or {}
        contents = set(now.values())
        changed = [(path, had[path], sha) for path, sha in now.items()
                   if had.get(path) not in (None, sha) and had[path] not in contents]
        if not changed:
            return None
        path, then, sha = changed[0]
        more = f" (and {len(changed) - 1} more log(s))" if len(changed) > 1 else ""
        return (f"{path} changed since this study began (content sha256 {then[:12]}… then, {sha[:12]}… now)"
                + more)

    def _remove_study(self) -> None:
        """Remove what a study wrote in the folder (the folder is locked: no live writer)."""
        for name in STUDY_FILES:
            (self.root / name).unlink(missing_ok=True)
        for name in STUDY_FOLDERS:
            if (self.root / name).is_dir():
                shutil.rmtree(self.root / name)

    def _check_compatible(self, old: dict[str, Any]) -> None:
        new = self.identity
        if old.get("options") != new.get("options"):
            diff = sorted(k for k in set(old.get("options", {})) | set(new.get("options", {}))
                          if old.get("options", {}).get(k) != new.get("options", {}).get(k))
            raise ConfigError(f"-o {self.root}: holds a run with other options ({', '.join(diff)}): "
                              "choose another folder (a different config is a new run, not a mix)")
        for sha, cfg in new.get("logs", {}).items():
            had = old.get("logs", {}).get(sha)
            if had is not None and had != cfg:
                raise ConfigError(f"-o {self.root}: holds a run of log {sha[:12]}… with another resolved config: "
                                  "choose another folder (a different config is a new run, not a mix)")

    def _write_json(self, path: Path, obj: Any) -> None:
        with AtomicOutput(path) as out:
            out.temp.write_text(json.dumps(obj, indent=1, sort_keys=True) + "\n")

    def done(self, key: str) -> bool:
        """True when the unit ``key`` finished in an earlier (or this) run."""
        return (self.root / PARTS / f"{key}.json").is_file()

    def write(self, key: str, rows: list[dict[str, Any]], meta: dict[str, Any], *, schema: pa.Schema | None = None) -> None:
        """Write a finished unit: its rows (parquet), then its meta (the marker of a finished unit)."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        table = pa.Table.from_pylist(rows, schema=schema)
        with AtomicOutput(self.root / PARTS / f"{key}.parquet") as out:
            pq.write_table(table, out.temp)
        self._write_json(self.root / PARTS / f"{key}.json", meta)

    def metas(self) -> dict[str, dict[str, Any]]:
        out = {}
        for p in sorted((self.root / PARTS).glob("*.json")):
            try:
                out[p.stem] = json.loads(p.read_text())
            except (OSError, ValueError):
                continue  # an unreadable marker: the unit runs again
        return out

    def table(self, keys: list[str] | None = None, *, schema: pa.Schema | None = None) -> pa.Table:
        """The rows of the finished units (of ``keys``, default all) as one pyarrow Table."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        metas = self.metas()
        keys = sorted(metas) if keys is None else [k for k in keys if k in metas]
        tables = [pq.read_table(self.root / PARTS / f"{k}.parquet") for k in keys
                  if (self.root / PARTS / f"{k}.parquet").is_file()]
        tables = [t for t in tables if t.num_rows]
        if not tables:
            return pa.Table.from_pylist([], schema=schema)
        return pa.concat_tables(tables, promote_options="default")

    def write_table(self, name: str, table: pa.Table) -> Path:
        import pyarrow.parquet as pq

        path = self.root / name
        with AtomicOutput(path) as out:
            pq.write_table(table, out.temp)
        return path

    def write_json(self, name: str, obj: Any) -> Path:
        path = self.root / name
        self._write_json(path, obj)
        return path
