"""The label store on a full disk and in a read-only folder (annotate/store.py, "Full disk,
read-only folders"): "no space left", not "damaged"; the page says so, keeps the edit and saves it
once there is space; a store that cannot be written here can still be read."""

from __future__ import annotations

import base64
import shutil
import sqlite3

import numpy as np
import pytest
from annotate_helpers import ServerProcess, close_page, label_with_truth, open_page, wait_until, write_spike_log
from cli_helpers import run_cli
from disk_helpers import fill, remount, small_disk

from annotate.store import LabelStore, StoreError, StoreFullError, file_sha256, pack_mask


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    p = tmp_path_factory.mktemp("store_fault_logs") / "scan.mcap"
    write_spike_log(p, frames=3)
    return p


def _store_with_labels(db, log) -> list:
    with LabelStore(db) as store:
        return label_with_truth(store, log)[1]


def test_a_full_disk_is_no_space_not_damage(log, tmp_path):
    with small_disk(tmp_path / "disk", "1m") as disk:
        frames = _store_with_labels(disk / "l.sqlite", log)
        with LabelStore(disk / "l.sqlite") as store:
            filler = fill(disk)
            fr, valid = frames[0]
            rng = np.random.default_rng(7)
            for _ in range(3):
                with pytest.raises(StoreFullError, match=r"no space left on the device; nothing was saved"):
                    store.save_label(fr, annotator="ann", outliers=(rng.random(valid.shape) < 0.3) & valid,
                                     reviewed=valid, base_revision=1)
            filler.unlink()
            assert store.save_label(fr, annotator="ann", outliers=valid & False, reviewed=valid, base_revision=1) == 2
        db = sqlite3.connect(disk / "l.sqlite")
        assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        db.close()


@pytest.mark.browser
@pytest.mark.slow
def test_the_page_keeps_an_edit_the_full_disk_refused_and_saves_it_later(log, tmp_path, browser):
    with small_disk(tmp_path / "disk", "2m") as disk:
        srv = ServerProcess(log, disk / "labels.sqlite", annotator="erin")
        page = None
        try:
            page, errors, blocked = open_page(browser, srv.url)
            filler = fill(disk)
            page.keyboard.press("Tab")
            page.keyboard.press("a")  # an outlier accepted: saved at once
            wait_until(page, "document.getElementById('savestate').textContent.includes('disk full')")
            assert page.evaluate("window.zcut.unsaved()") == [0]
            # the server's answer: 507, one line, nothing stored
            with srv.page_client() as c:
                none = base64.b64encode(pack_mask(np.zeros((120, 160), bool))).decode()
                r = c.put("/api/frames/1/label", json={"base_revision": 0, "height": 120, "width": 160,
                                                     "outliers": none, "reviewed": none})
            assert r.status_code == 507 and "no space left" in r.json()["error"] and "damaged" not in r.text
            page.wait_for_timeout(3000)  # it keeps trying
            assert page.evaluate("window.zcut.unsaved()") == [0]
            filler.unlink()
            wait_until(page, "window.zcut.unsaved().length === 0")
            with LabelStore(disk / "labels.sqlite", read_only=True) as s:
                fr = s.frames(s.log_by_sha(file_sha256(log)))[0]
                assert s.label(fr, annotator="erin").outliers.sum() > 0
            assert not blocked
        finally:
            if page is not None:
                close_page(page)
            srv.stop()


def test_a_store_in_a_folder_that_cannot_be_written_is_read(log, tmp_path, capsys):
    """A read-only mount: SQLite cannot make the WAL's index beside the store; `labels list`,
    `labels export` and `accuracy --labels` still read it. A -wal beside it (commits not yet in the
    file) is a clear error instead of a silently older store."""
    with small_disk(tmp_path / "ro", "4m") as ro:
        _store_with_labels(ro / "l.sqlite", log)
        remount(ro, "ro")
        try:
            rc, out, err = run_cli(capsys, "labels", "list", log, "--db", ro / "l.sqlite")
            assert rc == 0 and "ann: 3 frame(s) labelled" in out, err
            rc, out, err = run_cli(capsys, "labels", "export", log, "--db", ro / "l.sqlite", "-o", tmp_path / "x.mcap")
            assert rc == 0 and (tmp_path / "x.mcap").is_file(), err
            rc, out, err = run_cli(capsys, "accuracy", log, "--labels", ro / "l.sqlite", "--json")
            assert rc == 0 and '"pooled"' in out, err
            assert sorted(p.name for p in ro.iterdir()) == ["l.sqlite"]
        finally:
            remount(ro, "rw")
    # a store with commits still in its -wal (copied while a writer had it open)
    with small_disk(tmp_path / "ro2", "4m") as ro2:
        _store_with_labels(tmp_path / "w.sqlite", log)
        writer = sqlite3.connect(tmp_path / "w.sqlite")
        writer.execute("PRAGMA wal_autocheckpoint = 0")
        writer.execute("INSERT INTO logs (sha256, name, size_bytes, added_ns) VALUES (?, 'x', 1, 1)", ("0" * 64,))
        writer.commit()
        for suffix in ("", "-wal"):
            shutil.copy(f"{tmp_path / 'w.sqlite'}{suffix}", f"{ro2 / 'l.sqlite'}{suffix}")
        writer.close()
        remount(ro2, "ro")
        try:
            with pytest.raises(StoreError, match=r"l.sqlite-wal holds commits not yet in the file"):
                LabelStore(ro2 / "l.sqlite", read_only=True)
        finally:
            remount(ro2, "rw")


@pytest.fixture
def held_store(log, tmp_path, monkeypatch):
    """A store with labels and its export, then held by another connection's ``BEGIN EXCLUSIVE``
    (the busy timeout cut to 0.2 s so the test does not wait 10 s)."""
    import annotate.store as store_module

    db = tmp_path / "held.sqlite"
    _store_with_labels(db, log)
    export = tmp_path / "labels.mcap"
    with LabelStore(db, read_only=True) as store:
        from annotate.label_files import export_labels

        export_labels(store, store.logs()[0], export, annotator="ann")
    monkeypatch.setattr(store_module, "BUSY_TIMEOUT_MS", 200)
    other = sqlite3.connect(db, isolation_level=None)
    other.execute("BEGIN EXCLUSIVE")
    yield db, export
    other.rollback()
    other.close()


def _labels_in(db) -> int:
    with LabelStore(db, read_only=True) as store:
        return store.label_count()


def test_labels_import_into_a_store_another_writer_holds_is_one_line(log, held_store, capsys):
    db, export = held_store
    rc, _, err = run_cli(capsys, "labels", "import", export, "--db", db, "--annotator", "bob")
    assert rc == 1
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert f"error: label store {db} is held by another writer" in err
    assert "nothing of" in err and "was imported" in err


def test_annotate_on_a_store_another_writer_holds_is_one_line(log, held_store, capsys):
    db, _ = held_store
    rc, out, err = run_cli(capsys, "annotate", log, "--db", db, "--no-browser", "--port", "0")
    assert rc == 1
    lines = [ln for ln in err.splitlines() if not ln.startswith("zcut: ")]
    assert len(lines) == 1 and lines[0].startswith(f"error: label store {db} is held by another writer"), err
    assert "http://" not in out


def test_a_held_store_loses_nothing_already_saved(log, held_store, capsys):
    db, export = held_store
    run_cli(capsys, "labels", "import", export, "--db", db, "--annotator", "bob")
    assert _labels_in(db) == 3  # readable under the other writer's lock (WAL), and unchanged
    chk = sqlite3.connect(db)
    assert chk.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    chk.close()


def test_a_file_hashed_twice_is_read_once_and_a_changed_one_again(tmp_path):
    """``file_sha256`` keeps the digest of a file it read (same device, inode, size, mtime); a file
    changed since is read again."""
    import hashlib
    import os

    from annotate import store

    p = tmp_path / "f.bin"
    p.write_bytes(b"a" * 3000)
    assert file_sha256(p) == hashlib.sha256(b"a" * 3000).hexdigest()
    p.write_bytes(b"b" * 3000)  # same size, rewritten within the file system's time tick: read again
    assert file_sha256(p) == hashlib.sha256(b"b" * 3000).hexdigest()
    old = os.stat(p).st_mtime_ns - 10_000_000_000
    os.utime(p, ns=(old, old))  # last changed 10 s ago: its digest is kept
    assert file_sha256(p) == hashlib.sha256(b"b" * 3000).hexdigest()
    assert any(k[3] == old for k in store._DIGESTS)
    p.write_bytes(b"c" * 3000)  # changed since: read again
    assert file_sha256(p) == hashlib.sha256(b"c" * 3000).hexdigest()
