"""The binary PLY model reader (``np.frombuffer`` of each element) against plyfile's row-by-row read,
which stays the oracle: same points, normals and faces, or the same one-line error."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from replay.errors import LogFormatError
from replay.logs import ply


def _slow(monkeypatch, data: bytes):
    with monkeypatch.context() as m:
        m.setattr(ply, "_binary_elements", lambda *a: None)  # plyfile reads every element
        return _outcome(data)


def _outcome(data: bytes):
    try:
        return ply.read_ply_model_bytes(data, name="m.ply")
    except LogFormatError as e:
        return str(e)


def _same(a, b) -> None:
    if isinstance(a, str) or isinstance(b, str):
        assert a == b
        return
    for x, y in ((a.points, b.points), (a.normals, b.normals), (a.faces, b.faces)):
        assert (x is None) == (y is None)
        if x is not None:
            assert x.dtype == y.dtype
            np.testing.assert_array_equal(x, y)


def _mesh_bytes(tmp_path, fmt: str, *, quads: bool = False, mixed: bool = False) -> bytes:
    from plyfile import PlyData, PlyElement

    rng = np.random.default_rng(5)
    n = 40
    v = np.empty(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f8"), ("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4"),
                           ("red", "u1")])
    for k in v.dtype.names:
        v[k] = rng.uniform(0, 255, n)
    k = 4 if quads else 3
    rows = [rng.integers(0, n, (k + (i % 2 if mixed else 0))).astype(np.int32) for i in range(30)]
    f = np.empty(len(rows), dtype=[("vertex_indices", "O"), ("flag", "u1")])
    f["vertex_indices"] = rows
    f["flag"] = 7
    el = [PlyElement.describe(v, "vertex"),
          PlyElement.describe(f, "face", val_types={"vertex_indices": "i4"}, len_types={"vertex_indices": "u1"})]
    p = tmp_path / "mesh.ply"
    PlyData(el, text=False, byte_order=fmt).write(str(p))
    return p.read_bytes()


@pytest.mark.parametrize("fmt", ["<", ">"])
@pytest.mark.parametrize("kind", ["tri", "quad", "mixed"])
def test_binary_mesh_matches_plyfile(tmp_path, monkeypatch, fmt, kind):
    data = _mesh_bytes(tmp_path, fmt, quads=kind == "quad", mixed=kind == "mixed")
    fast = _outcome(data)
    assert not isinstance(fast, str)
    _same(fast, _slow(monkeypatch, data))


def test_open3d_files_and_mutants_match_plyfile(tmp_path, monkeypatch, rng):
    from log_helpers import mutations

    mesh = o3d.geometry.TriangleMesh.create_box(0.4, 0.3, 0.12)
    mesh.compute_vertex_normals()
    o3d.io.write_triangle_mesh(str(tmp_path / "box.ply"), mesh, write_ascii=False)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(rng.normal(size=(50, 3))))
    o3d.io.write_point_cloud(str(tmp_path / "pc.ply"), pc, write_ascii=False)
    seen = {"ok": 0, "error": 0}
    for name in ("box.ply", "pc.ply"):
        raw = (tmp_path / name).read_bytes()
        _same(_outcome(raw), _slow(monkeypatch, raw))
        for _, data in mutations(raw, rng, 80):
            fast = _outcome(data)
            _same(fast, _slow(monkeypatch, data))
            seen["error" if isinstance(fast, str) else "ok"] += 1
    assert seen["ok"] > 10 and seen["error"] > 20, seen


def test_attachment_sized_model_never_reaches_plyfiles_row_read(monkeypatch):
    """A log's bin model attachment (65k points with normals) is read by ``np.frombuffer``, never by
    plyfile's read of a file held in memory (row by row: 0.8-5 CPU-s; bench/bench_replay.py measures
    the time, a test only the path taken)."""
    from plyfile import PlyData

    from replay.synth.bin_surface import bin_model_ply

    def refuse(*a, **k):
        raise AssertionError("plyfile's row-by-row read was used for a binary model")

    monkeypatch.setattr(PlyData, "read", staticmethod(refuse))
    m = ply.read_ply_model_bytes(bin_model_ply(), name="m.ply")
    assert len(m.points) > 50_000 and m.normals is not None
