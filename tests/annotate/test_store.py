"""annotate.store on a real SQLite file: revisions, conflicts, validation, schema, MCAP round trip."""

from __future__ import annotations

import hashlib
import sqlite3

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis.extra.numpy import array_shapes, arrays
from subprocess_helpers import run_python

from annotate.label_files import export_labels, import_labels, read_label_masks
from annotate.store import (
    MIGRATIONS,
    SCHEMA_VERSION,
    LabelConflictError,
    LabelStore,
    LabelSupersededError,
    LabelValidationError,
    StoreError,
    annotator_skeleton,
    file_sha256,
    normalize_annotator,
    pack_mask,
    unpack_mask,
)

SHAPE = (12, 17)


@pytest.fixture
def log_file(tmp_path):
    p = tmp_path / "scan.mcap"
    p.write_bytes(b"not really a log, but content is what identifies it" * 100)
    return p


@pytest.fixture
def valid(rng):
    v = rng.random(SHAPE) > 0.1
    return v


@pytest.fixture
def store_frame(tmp_path, log_file, valid):
    store = LabelStore(tmp_path / "labels.sqlite")
    log = store.add_log(log_file)
    fr = store.add_frame(log, topic="/camera/points", stamp_ns=1_000, index=0, shape=SHAPE, valid=valid)
    yield store, log, fr
    store.close()


def _label(rng, valid):
    reviewed = valid & (rng.random(SHAPE) > 0.2)
    outliers = reviewed & (rng.random(SHAPE) > 0.7)
    return outliers, reviewed


def _one_label(path, log_file, rng, valid):
    """A store at ``path`` with one frame of ``log_file`` labelled by "ann": its outliers."""
    with LabelStore(path) as store:
        log = store.add_log(log_file)
        fr = store.add_frame(log, topic="/c", stamp_ns=5, index=0, shape=SHAPE, valid=valid)
        outliers, reviewed = _label(rng, valid)
        store.save_label(fr, annotator="ann", outliers=outliers, reviewed=reviewed, base_revision=0)
    return outliers


def test_pack_roundtrip(rng):
    for shape in [(1, 1), (3, 5), (7, 8), (120, 160)]:
        m = rng.random(shape) > 0.5
        assert np.array_equal(unpack_mask(pack_mask(m), shape), m)


def test_unpack_rejects_bad_blobs():
    with pytest.raises(LabelValidationError, match="zlib"):
        unpack_mask(b"garbage", (4, 4))
    with pytest.raises(LabelValidationError, match="bytes"):
        unpack_mask(pack_mask(np.ones((4, 4), bool)), (8, 8))


def test_file_sha256_streams_the_content(log_file):
    assert file_sha256(log_file, chunk_bytes=7) == hashlib.sha256(log_file.read_bytes()).hexdigest()


def test_log_identity_is_content(tmp_path, log_file):
    with LabelStore(tmp_path / "l.sqlite") as store:
        a = store.add_log(log_file)
        copy = tmp_path / "renamed.mcap"
        copy.write_bytes(log_file.read_bytes())
        assert store.add_log(copy).id == a.id
        other = tmp_path / "other.mcap"
        other.write_bytes(b"x")
        assert store.add_log(other).id != a.id


def test_revisions_append_and_latest_wins(store_frame, rng, valid):
    store, log, fr = store_frame
    l1, r1 = _label(rng, valid)
    l2, r2 = _label(rng, valid)
    assert store.save_label(fr, annotator="ann", outliers=l1, reviewed=r1, base_revision=None) == 1
    assert store.save_label(fr, annotator="ann", outliers=l2, reviewed=r2, base_revision=1) == 2
    assert store.save_label(fr, annotator="bob", outliers=l1, reviewed=r1, base_revision=0) == 1
    cur = store.label(fr, annotator="ann")
    assert cur.revision == 2 and np.array_equal(cur.outliers, l2) and np.array_equal(cur.reviewed, r2)
    old = store.label(fr, annotator="ann", revision=1)
    assert np.array_equal(old.outliers, l1)
    assert store.revisions(fr, annotator="ann") == [1, 2]
    assert store.annotators(log) == ["ann", "bob"]
    summ = store.current_labels(log, annotator="ann")
    assert summ[fr.id].revision == 2 and summ[fr.id].n_outliers == int(l2.sum())


def test_stale_base_revision_is_a_conflict(store_frame, rng, valid):
    store, _, fr = store_frame
    l1, r1 = _label(rng, valid)
    store.save_label(fr, annotator="ann", outliers=l1, reviewed=r1, base_revision=0)
    with pytest.raises(LabelConflictError, match="revision 1") as e:
        store.save_label(fr, annotator="ann", outliers=l1, reviewed=r1, base_revision=0)
    assert e.value.latest == 1
    assert store.revisions(fr, annotator="ann") == [1]


def test_labels_are_append_only_in_sql(store_frame, rng, valid, tmp_path):
    store, _, fr = store_frame
    l1, r1 = _label(rng, valid)
    store.save_label(fr, annotator="ann", outliers=l1, reviewed=r1, base_revision=0)
    db = sqlite3.connect(tmp_path / "labels.sqlite")
    with pytest.raises(sqlite3.IntegrityError, match="append-only"):
        db.execute("UPDATE labels SET annotator = 'x'")
    with pytest.raises(sqlite3.IntegrityError, match="append-only"):
        db.execute("DELETE FROM labels")
    db.close()


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda v: (v.copy(), np.zeros_like(v)), "outliers must lie inside reviewed"),
        (lambda v: (np.zeros_like(v), np.ones_like(v)), "inside the valid pixels"),
        (lambda v: (np.zeros((3, 3), bool), np.zeros((3, 3), bool)), "differs from frame"),
        (lambda v: (v.astype(np.uint8), v), "bool"),
    ],
)
def test_invalid_labels_store_nothing(store_frame, valid, make, match):
    store, _, fr = store_frame
    outliers, reviewed = make(valid)
    with pytest.raises(LabelValidationError, match=match):
        store.save_label(fr, annotator="ann", outliers=outliers, reviewed=reviewed, base_revision=0)
    assert store.label_count() == 0


@pytest.mark.parametrize("name", ["", "x" * 65, "tab\there", 7, " alice", "ａｌｉｃｅ", "a\u0430lice"])
def test_bad_annotator_names(store_frame, valid, name):
    store, _, fr = store_frame
    with pytest.raises(LabelValidationError, match="annotator"):
        store.save_label(fr, annotator=name, outliers=valid & False, reviewed=valid, base_revision=0)


def test_reopen_keeps_everything_and_pragmas(tmp_path, log_file, rng, valid):
    path = tmp_path / "p.sqlite"
    l1 = _one_label(path, log_file, rng, valid)
    with LabelStore(path) as store:
        assert store.schema_version == SCHEMA_VERSION
        log = store.log_by_sha(file_sha256(log_file))
        fr = store.frame(log, topic="/c", stamp_ns=5)
        assert np.array_equal(store.label(fr, annotator="ann").outliers, l1)
        assert np.array_equal(store.valid_mask(fr), valid)
    db = sqlite3.connect(path)
    assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert db.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION
    db.close()


def test_newer_schema_is_refused(tmp_path):
    path = tmp_path / "future.sqlite"
    db = sqlite3.connect(path)
    db.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    db.close()
    with pytest.raises(StoreError, match="schema version"):
        LabelStore(path)


def test_not_a_database_is_a_store_error(tmp_path):
    path = tmp_path / "junk.sqlite"
    path.write_bytes(b"hello, this is not sqlite at all" * 200)
    with pytest.raises(StoreError, match="junk.sqlite"):
        LabelStore(path)


def test_a_database_of_another_application_is_never_touched(tmp_path):
    """Fuzz: ``labels list`` on another program's SQLite file created zcut's tables in it."""
    path = tmp_path / "other.sqlite"
    db = sqlite3.connect(path)
    db.execute("CREATE TABLE inventory (id INTEGER PRIMARY KEY, name TEXT)")
    db.execute("INSERT INTO inventory (name) VALUES ('bolt')")
    db.commit()
    db.close()
    before = path.read_bytes()
    for read_only in (False, True):
        with pytest.raises(StoreError, match="SQLite database of something else .tables inventory."):
            LabelStore(path, read_only=read_only)
    assert path.read_bytes() == before


def test_a_damaged_store_found_by_a_query_is_a_store_error(tmp_path, log_file, rng, valid):
    """Fuzz: one flipped byte in the schema (an orphan index) opened fine and failed at the first
    query with a bare sqlite3.DatabaseError traceback."""
    path = tmp_path / "d.sqlite"
    with LabelStore(path) as store:
        log = store.add_log(log_file)
        store.add_frame(log, topic="/c", stamp_ns=5, index=0, shape=SHAPE, valid=valid)
    data = path.read_bytes()
    assert b"sqlite_autoindex_labels_1" in data
    path.write_bytes(data.replace(b"sqlite_autoindex_labels_1", b"sqlite_autoindex_labe4s_1"))
    for read_only in (True, False):
        try:
            store = LabelStore(path, read_only=read_only)
        except StoreError as e:  # found at open: fine too
            assert "d.sqlite" in str(e)
            continue
        with store, pytest.raises(StoreError, match=r"d\.sqlite is damaged: malformed database schema"):
            store.log_by_sha(file_sha256(log_file))


def test_read_only_stores_are_never_written(tmp_path, log_file, rng, valid):
    path = tmp_path / "p.sqlite"
    l1 = _one_label(path, log_file, rng, valid)
    files = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.name.startswith("p.sqlite")}
    with LabelStore(path, read_only=True) as store:
        fr = store.frame(store.log_by_sha(file_sha256(log_file)), topic="/c", stamp_ns=5)
        assert np.array_equal(store.label(fr, annotator="ann").outliers, l1)
        with pytest.raises(sqlite3.OperationalError, match="readonly"):
            store.add_log(tmp_path / "p.sqlite")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.name.startswith("p.sqlite")
            and p.name in files} == files
    empty = tmp_path / "empty.sqlite"
    empty.touch()
    with pytest.raises(StoreError, match="holds no label store yet"):
        LabelStore(empty, read_only=True)
    assert empty.stat().st_size == 0
    with pytest.raises(FileNotFoundError):
        LabelStore(tmp_path / "nope.sqlite", read_only=True)
    assert not (tmp_path / "nope.sqlite").exists()


def test_export_import_roundtrip(store_frame, rng, valid, tmp_path):
    store, log, fr0 = store_frame
    fr1 = store.add_frame(log, topic="/camera/points", stamp_ns=2_000, index=1, shape=SHAPE, valid=valid)
    labels = {}
    for fr in (fr0, fr1):
        labels[fr.stamp_ns] = _label(rng, valid)
        store.save_label(fr, annotator="ann", outliers=labels[fr.stamp_ns][0], reviewed=labels[fr.stamp_ns][1], base_revision=0)
    out = tmp_path / "labels.mcap"
    assert export_labels(store, log, out, annotator="ann") == 2
    meta, masks = read_label_masks(out)
    assert meta["log_sha256"] == log.sha256 and meta["annotator"] == "ann"
    assert np.array_equal(masks[2_000]["/labels/outliers"], labels[2_000][0])
    assert np.array_equal(masks[2_000]["/labels/reviewed"], labels[2_000][1])

    # import into a fresh store as another annotator: same masks, source 'import'
    with LabelStore(tmp_path / "fresh.sqlite") as fresh:
        flog = fresh.add_log(tmp_path / "scan.mcap")
        for i, stamp in enumerate((1_000, 2_000)):
            fresh.add_frame(flog, topic="/camera/points", stamp_ns=stamp, index=i, shape=SHAPE, valid=valid)
        assert import_labels(fresh, out, annotator="carol") == 2
        fr = fresh.frame(flog, topic="/camera/points", stamp_ns=1_000)
        lab = fresh.label(fr, annotator="carol")
        assert lab.source == "import" and np.array_equal(lab.outliers, labels[1_000][0])
    # importing again on top of existing labels appends revisions
    assert import_labels(store, out) == 2
    assert store.revisions(fr0, annotator="ann") == [1, 2]


def test_import_needs_the_log(tmp_path, store_frame, rng, valid):
    store, log, fr = store_frame
    l1, r1 = _label(rng, valid)
    store.save_label(fr, annotator="ann", outliers=l1, reviewed=r1, base_revision=0)
    export_labels(store, log, tmp_path / "x.mcap", annotator="ann")
    with LabelStore(tmp_path / "empty.sqlite") as other, pytest.raises(StoreError, match="not registered"):
        import_labels(other, tmp_path / "x.mcap")


@settings(max_examples=100, deadline=None)
@given(arrays(np.bool_, array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=40)))
def test_pack_roundtrip_any_shape(m):
    assert np.array_equal(unpack_mask(pack_mask(m), m.shape), m)


def test_damaged_label_export_is_refused_and_stores_nothing(store_frame, rng, valid, tmp_path):
    from replay.errors import LogFormatError

    store, log, fr = store_frame
    l1, r1 = _label(rng, valid)
    store.save_label(fr, annotator="ann", outliers=l1, reviewed=r1, base_revision=0)
    out = tmp_path / "labels.mcap"
    export_labels(store, log, out, annotator="ann")
    data = out.read_bytes()
    for cut in (len(data) // 3, len(data) // 2, len(data) - 40):
        bad = tmp_path / f"cut{cut}.mcap"
        bad.write_bytes(data[:cut])
        with pytest.raises(LogFormatError, match=bad.name):
            import_labels(store, bad)
    assert store.revisions(fr, annotator="ann") == [1]


@pytest.mark.parametrize(("name", "stored"), [
    ("alice", "alice"),
    ("  alice  ", "alice"),
    ("ａｌｉｃｅ", "alice"),                  # fullwidth: NFKC
    ("Anne  Marie", "Anne Marie"),           # inner white space: one space
    ("O'Neil-Smith_2", "O'Neil-Smith_2"),
    ("José", "José"),                         # e + combining acute: composed
    ("Ольга", "Ольга"),                       # one script, not Latin
    ("山田はなこ", "山田はなこ"),               # Han with Hiragana
    ("Zoë Ø", "Zoë Ø"),
])
def test_annotator_names_are_normalised(name, stored):
    assert normalize_annotator(name) == stored


@pytest.mark.parametrize(("name", "match"), [
    ("", "1..64 characters"),
    ("x" * 65, "1..64 characters"),
    (None, "must be a string"),
    ("\u0430lice", "mixes scripts \\(cyrillic, latin\\)"),   # Cyrillic а in alice
    ("bοb", "mixes scripts \\(greek, latin\\)"),            # Greek ο
    ("al\u200bice", "U\\+200B"),                             # zero-width space
    ("alice\u202e", "U\\+202E"),                             # right-to-left override
    ("bob\tsmith\x00", "U\\+0000"),
    ("bob@example", "U\\+0040"),
    ("Ͱ\u0301a", "mixes scripts"),
])
def test_annotator_names_refused(name, match):
    with pytest.raises(LabelValidationError, match=match):
        normalize_annotator(name)


def test_look_alikes_of_existing_annotators_are_refused(store_frame, valid):
    store, _, fr = store_frame
    store.save_label(fr, annotator="alice", outliers=valid & False, reviewed=valid, base_revision=0)
    assert store.check_new_annotator("alice") == "alice"       # the same person again
    assert store.check_new_annotator("bob") == "bob"
    for twin in ["Alice", "ALICE", "a1ice", "al.ice", "\u0430\u04cf\u0456\u0441\u0435", "ａｌｉｃｅ "[:-1] + "_"]:
        with pytest.raises(LabelValidationError, match="looks like the existing annotator 'alice'"):
            store.check_new_annotator(twin)
    with pytest.raises(LabelValidationError, match="looks like the existing annotator 'rn'"):
        store.check_new_annotator("m", also=["rn"])
    assert annotator_skeleton("\u0430\u04cf\u0456\u0441\u0435") == annotator_skeleton("alice") == "alice"


def test_one_page_saving_full_states_is_not_a_conflict(store_frame, rng, valid):
    """A page's saves in flight together (the last one as the tab closes) land in the order of the
    page's own sequence numbers; another page's save in between is a conflict."""
    store, _, fr = store_frame
    states = [_label(rng, valid) for _ in range(4)]
    save = lambda k, base, client="tab-aaaa1", seq=None: store.save_label(
        fr, annotator="ann", outliers=states[k][0], reviewed=states[k][1], base_revision=base, client=client,
        client_seq=k if seq is None else seq)
    assert save(0, 0) == 1
    # seq 2 (sent as the tab closed) arrives before seq 1, both based on revision 1
    assert save(2, 1) == 2
    with pytest.raises(LabelSupersededError, match="newer state") as e:
        save(1, 1)
    assert e.value.latest == 2 and store.revisions(fr, annotator="ann") == [1, 2]
    assert np.array_equal(store.label(fr, annotator="ann").outliers, states[2][0])
    # in order: seq 3 on base 1 follows seq 2 of the same page
    assert save(3, 1) == 3
    # another page (or a save without a page id) based on an old revision: a conflict
    with pytest.raises(LabelConflictError):
        save(0, 2, client="tab-bbbb2", seq=9)
    with pytest.raises(LabelConflictError):
        store.save_label(fr, annotator="ann", outliers=states[0][0], reviewed=states[0][1], base_revision=1)
    with pytest.raises(LabelConflictError):  # a base from the future
        save(0, 7, seq=10)
    with pytest.raises(LabelValidationError, match="together"):
        store.save_label(fr, annotator="ann", outliers=states[0][0], reviewed=states[0][1], base_revision=3,
                         client="tab-aaaa1")
    assert store.revisions(fr, annotator="ann") == [1, 2, 3]


def test_servers_register_beat_and_leave(tmp_path, log_file):
    import os

    with LabelStore(tmp_path / "s.sqlite") as a, LabelStore(tmp_path / "s.sqlite") as b:
        me = a.register_server(log_sha256="0" * 64, port=8000)
        other = b.register_server(log_sha256="1" * 64, port=8001)
        live = a.live_servers()
        assert [s.id for s in live] == [me.id, other.id] and live[0].pid == os.getpid() and live[1].port == 8001
        b.unregister_server(other.id)
        assert [s.id for s in a.live_servers()] == [me.id]
        # a server that stopped beating (killed) is gone after the stale time
        stale = b.register_server(log_sha256="1" * 64, port=8002)
        assert stale.id in [s.id for s in a.live_servers(stale_after_s=60)]
        import time
        time.sleep(0.05)
        a.heartbeat_server(me.id)
        assert [s.id for s in a.live_servers(stale_after_s=0.03)] == [me.id]
        # on this host, a server whose process is gone is gone at once
        done = run_python("import os; print(os.getpid())", check=True)
        dead = int(done.stdout)
        b._db.execute("UPDATE servers SET pid = ? WHERE id = ?", (dead, stale.id))
        assert stale.id not in [s.id for s in a.live_servers(stale_after_s=60)]


def test_a_version_1_store_is_migrated_and_keeps_its_labels(tmp_path, log_file, rng, valid):
    path = tmp_path / "v1.sqlite"
    db = sqlite3.connect(path)
    for stmt in MIGRATIONS[0]:
        db.execute(stmt)
    db.execute("PRAGMA user_version = 1")
    db.execute("INSERT INTO logs (sha256, name, size_bytes, added_ns) VALUES (?, 'scan.mcap', 1, 0)",
               (file_sha256(log_file),))
    db.execute("INSERT INTO frames (log_id, topic, stamp_ns, frame_index, height, width, valid)"
               " VALUES (1, '/c', 5, 0, ?, ?, ?)", (*SHAPE, pack_mask(valid)))
    l1, r1 = _label(rng, valid)
    db.execute("INSERT INTO labels (frame_id, annotator, revision, created_ns, height, width, outliers, reviewed,"
               " n_outliers, n_reviewed) VALUES (1, 'ann', 1, 0, ?, ?, ?, ?, ?, ?)",
               (*SHAPE, pack_mask(l1), pack_mask(r1), int(l1.sum()), int(r1.sum())))
    db.commit()
    db.close()
    with LabelStore(path) as store:
        assert store.schema_version == SCHEMA_VERSION == 5
        fr = store.frame(store.log_by_sha(file_sha256(log_file)), topic="/c", stamp_ns=5)
        assert np.array_equal(store.label(fr, annotator="ann").outliers, l1)
        assert store.save_label(fr, annotator="ann", outliers=l1, reviewed=r1, base_revision=1,
                                client="tab-cccc3", client_seq=1) == 2
        assert store.register_server(log_sha256="0" * 64).id == 1


def test_fit_seeds_are_kept_per_frame_and_annotator_in_order(tmp_path, store_frame):
    store, log, fr = store_frame
    other = store.add_frame(log, topic="/camera/points", stamp_ns=2_000, index=1, shape=SHAPE, valid=None)
    store.save_fit_seed(fr, annotator="ann", x=16, y=0, found=1)
    store.save_fit_seed(fr, annotator="bob", x=3, y=4, found=2)
    store.save_fit_seed(fr, annotator="ann", x=0, y=11, found=1)
    store.save_fit_seed(other, annotator="ann", x=5, y=5, found=1)
    assert store.fit_seeds(fr, annotator="ann") == ((16, 0), (0, 11))
    assert store.fit_seeds(fr, annotator="bob") == ((3, 4),)
    assert store.fit_seeds(other, annotator="ann") == ((5, 5),)
    assert store.fit_seeds(other, annotator="bob") == ()
    store.close()
    with LabelStore(tmp_path / "labels.sqlite") as again:  # reopened: the same, in the same order
        fr2 = again.frames(again.logs()[0])[0]
        assert again.fit_seeds(fr2, annotator="ann") == ((16, 0), (0, 11))
    db = sqlite3.connect(tmp_path / "labels.sqlite")
    with pytest.raises(sqlite3.IntegrityError, match="append-only"):
        db.execute("DELETE FROM fit_seeds")
    db.close()


@pytest.mark.parametrize(("x", "y", "found"), [(17, 0, 1), (0, 12, 1), (-1, 0, 1), (0, 0, 0), (1.5, 0, 1), ("1", 0, 1)])
def test_bad_fit_seeds_store_nothing(store_frame, x, y, found):
    store, _, fr = store_frame
    with pytest.raises(LabelValidationError, match="a fit seed needs a pixel of the 17x12 frame and found >= 1"):
        store.save_fit_seed(fr, annotator="ann", x=x, y=y, found=found)
    assert store.fit_seeds(fr, annotator="ann") == ()


def test_a_version_4_store_gets_the_fit_seeds_and_keeps_its_fit_decisions(tmp_path, log_file, valid):
    path = tmp_path / "v4.sqlite"
    db = sqlite3.connect(path)
    for version in MIGRATIONS[:4]:
        for stmt in version:
            db.execute(stmt)
    db.execute("PRAGMA user_version = 4")
    db.execute("INSERT INTO logs (sha256, name, size_bytes, added_ns) VALUES (?, 'scan.mcap', 1, 0)",
               (file_sha256(log_file),))
    db.execute("INSERT INTO frames (log_id, topic, stamp_ns, frame_index, height, width, valid)"
               " VALUES (1, '/c', 5, 0, ?, ?, ?)", (*SHAPE, pack_mask(valid)))
    db.execute("INSERT INTO fit_decisions (frame_id, annotator, fit, x_mm, y_mm, z_mm, rejected, created_ns)"
               " VALUES (1, 'ann', 3, 1.0, 2.0, 700.0, 1, 0)")
    db.commit()
    db.close()
    with LabelStore(path) as store:
        assert store.schema_version == SCHEMA_VERSION == 5
        fr = store.frame(store.log_by_sha(file_sha256(log_file)), topic="/c", stamp_ns=5)
        assert store.rejected_fits(fr, annotator="ann") == {3: (1.0, 2.0, 700.0)}
        assert store.fit_seeds(fr, annotator="ann") == ()
        store.save_fit_seed(fr, annotator="ann", x=1, y=2, found=1)
        assert store.fit_seeds(fr, annotator="ann") == ((1, 2),)
