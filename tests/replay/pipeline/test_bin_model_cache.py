"""The bin model cache (issue 32, fixed costs): a model loaded or prepared from the cache folder gives
every frame's results bit for bit as the one made anew, and a damaged, stale or other entry is never used.

Classes of model: a synthetic log's own attachment (cloud with normals), the synthetic bin's CAD mesh
(sampled), a cloud without normals (normals estimated); two part kinds and seeds.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial import cKDTree

from replay.logs.ply import ply_model_bytes
from replay.logs.reader import LogReader
from replay.pipeline import bin_model as bm
from replay.pipeline.session import ReplaySession
from replay.pipeline.stages import locate_bin, run_frame
from replay.synth.log import write_bin_cad, write_synthetic_log
from zcut.prepared_model import PreparedBinModel, prepare_bin_model, prepared_arrays, prepared_from_arrays

SIZE = (200, 320)


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("ZCUT_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache" / "bin_models"


def _same(a: Any, b: Any, where: str = "", *, floats_exact: bool = True) -> None:
    """Equal bit for bit (NaN equals NaN), recursively through dataclasses, dicts and sequences; stage
    timings are not compared. With ``floats_exact`` False, float figures within 1e-9 (relative):
    Open3D's ICP sums over its threads in no fixed order, so two runs of one prepared model give
    poses that differ by ~1e-17 and heights that follow them; masks, labels and counts stay exact."""
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        assert type(a) is type(b), where
        for f in dataclasses.fields(a):
            if f.name != "timings":
                _same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}", floats_exact=floats_exact)
    elif isinstance(a, cKDTree):  # a removal result keeps its model's search structures: same state
        assert isinstance(b, cKDTree), where
        # its node buffer holds the nodes' pointers (set again when a tree is unpickled): the rest of its
        # state, and the answers to a query of its own points
        _same(a.__getstate__()[1:], b.__getstate__()[1:], f"{where}.state", floats_exact=floats_exact)
        q = a.data[:: max(1, len(a.data) // 500)]
        _same(a.query(q, k=3), b.query(q, k=3), f"{where}.query", floats_exact=floats_exact)
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            _same(a[k], b[k], f"{where}[{k}]", floats_exact=floats_exact)
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{i}]", floats_exact=floats_exact)
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape, where
        if a.dtype.kind in "fc" and not floats_exact:
            assert np.allclose(a, b, rtol=1e-9, atol=1e-12, equal_nan=True), where
        else:
            assert np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"), where
    elif isinstance(a, float):
        assert isinstance(b, float), where
        if math.isnan(a):
            assert math.isnan(b), where
        else:
            assert a == b if floats_exact else math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12), where
    else:
        assert a == b, where


def _arrays(p: PreparedBinModel) -> dict[str, np.ndarray]:
    """:func:`prepared_arrays` but the KD-trees' node buffers, which hold the nodes' addresses in
    memory (scipy fixes them up when it loads a tree); the trees' data, indices and bounds stay, and
    their answers are compared in :func:`test_arrays_round_trip_answers_the_same_queries`."""
    arrays = prepared_arrays(p)
    assert arrays is not None
    return {k: v for k, v in arrays.items() if not k.endswith(".buffer")}


def _frames_with(log: Path, prepared: PreparedBinModel) -> list[Any]:
    session = ReplaySession.open(log, bin_model=prepared.model)
    config = session.config
    out = []
    for frame in LogReader(log).frames():
        located = locate_bin(frame, config, bin_model=prepared)
        out.append(run_frame(frame, config, bin_model=prepared, located=located))
    return out


@pytest.mark.parametrize("kind,seed", [("zinc_nuts", 1), ("spheres", 4)])
def test_cached_models_give_the_same_frames(tmp_path: Path, cache: Path, kind: str, seed: int) -> None:
    log = tmp_path / f"{kind}.mcap"
    write_synthetic_log(log, kind=kind, frames=2, seed=seed, size=SIZE)
    cad = write_bin_cad(tmp_path / "cad.ply")
    config = ReplaySession.open(log).config
    params = {"registration": config.registration, "removal": config.removal}
    attached = LogReader(log).attached_bin_model
    assert attached is not None
    bare = tmp_path / "no_normals.ply"
    bare.write_bytes(ply_model_bytes(attached.points[::3]))
    made = {"attachment": lambda: bm.bin_model_for(LogReader(log), None).model,
            "cad": lambda: bm.load_bin_model(cad), "no normals": lambda: bm.load_bin_model(bare)}
    for what, make in made.items():
        before = set(cache.glob("*.npz")) if cache.is_dir() else set()
        first = make()  # made, then written
        assert first is not None
        fresh = prepare_bin_model(first, **params)
        written = bm.prepared_bin_model(first, **params)
        _same(_arrays(written), _arrays(fresh), what)
        assert len(set(cache.glob("*.npz")) - before) == 2, what  # the model and its preparation
        again = make()  # read back
        _same(again, first, what)
        cached = bm.prepared_bin_model(again, **params)
        assert cached.icp.fine is not fresh.icp.fine
        _same(_arrays(cached), _arrays(fresh), what)
        _same(_frames_with(log, cached), _frames_with(log, fresh), what, floats_exact=False)


def test_arrays_round_trip_answers_the_same_queries(tmp_path: Path) -> None:
    log = tmp_path / "nuts.mcap"
    write_synthetic_log(log, kind="zinc_nuts", frames=1, seed=2, size=SIZE)
    config = ReplaySession.open(log).config
    model = bm.bin_model_for(LogReader(log), None).model
    assert model is not None
    p = prepare_bin_model(model, registration=config.registration, removal=config.removal)
    arrays = prepared_arrays(p)
    assert arrays is not None
    q = prepared_from_arrays(arrays, registration=config.registration, removal=config.removal)
    probe = np.random.default_rng(0).uniform(model.points.min(0) - 0.01, model.points.max(0) + 0.01, (2000, 3))
    for t, u in ((p.icp.tree, q.icp.tree), (p.removal.tree, q.removal.tree)):
        for k in (1, 4):
            _same(t.query(probe, k=k), u.query(probe, k=k))
    _same(np.asarray(q.icp.fine.points), np.asarray(p.icp.fine.points))
    _same(np.asarray(q.icp.coarse.normals), np.asarray(p.icp.coarse.normals))
    _same(q.removal.bin, p.removal.bin)
    _same(q.removal.straggler, p.removal.straggler)


def test_damaged_or_foreign_entries_are_made_again(tmp_path: Path, cache: Path) -> None:
    log = tmp_path / "spheres.mcap"
    write_synthetic_log(log, kind="spheres", frames=1, seed=3, size=SIZE)
    config = ReplaySession.open(log).config
    params = {"registration": config.registration, "removal": config.removal}
    model = bm.bin_model_for(LogReader(log), None).model
    assert model is not None
    fresh = _arrays(prepare_bin_model(model, **params))
    bm.prepared_bin_model(model, **params)
    (entry,) = cache.glob("prepared-*.npz")
    entry.write_bytes(b"not a zip")  # damaged
    _same(_arrays(bm.prepared_bin_model(model, **params)), fresh)
    np.savez(entry, other=np.zeros(3))  # written by other code: missing arrays
    _same(_arrays(bm.prepared_bin_model(model, **params)), fresh)
    # other parameters or another model: another entry
    moved = dataclasses.replace(model, points=model.points + 1e-9)
    bm.prepared_bin_model(moved, **params)
    assert len(list(cache.glob("prepared-*.npz"))) == 2


def test_a_cache_that_cannot_be_written_is_skipped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("a file where the cache folder would be")
    monkeypatch.setenv("ZCUT_CACHE", str(blocker))
    log = tmp_path / "spheres.mcap"
    write_synthetic_log(log, kind="spheres", frames=1, seed=3, size=SIZE)
    config = ReplaySession.open(log).config
    model = bm.bin_model_for(LogReader(log), None).model
    assert model is not None
    p = bm.prepared_bin_model(model, registration=config.registration, removal=config.removal)
    _same(_arrays(p), _arrays(prepare_bin_model(model, registration=config.registration,
                                                                  removal=config.removal)))
