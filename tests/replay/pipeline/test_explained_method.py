"""The method ``explained`` in the pipeline: its part model (the log's attachment or ``--part-model``),
its mask in ``replay --out``, the local surface and its named warning without a part model, a
study's spawn workers.

Real MCAP logs from ``zcut synth`` (spheres at 320 × 200: the part fits are closed forms there).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from cli_helpers import run_cli, synth_log
from log_helpers import without_truth
from mcap.reader import make_reader

from replay.logs import layout
from replay.logs.part_model import read_part_model
from replay.logs.ros2_msgs import decode_image, image_to_mask

METHODS = "zcut,explained"


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    return synth_log(tmp_path_factory.mktemp("explained") / "spheres.mcap", parts="spheres", frames=1, seed=9601,
                     size="320x200")


@pytest.fixture(scope="module")
def replayed(tmp_path_factory, log):
    """``zcut replay LOG --methods zcut,explained --out r.mcap --rrd e.rrd --json`` once for the tests that read its
    results file, its recording or its messages: (folder, exit status, stdout, stderr)."""
    import contextlib
    import io

    from cli.main import main

    d = tmp_path_factory.mktemp("explained_replay")
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(["replay", str(log), "--methods", METHODS, "--out", str(d / "r.mcap"), "--rrd", str(d / "e.rrd"),
                   "--json"])
    return d, rc, out.getvalue(), err.getvalue()


def _mask(results, topic: str) -> np.ndarray:
    """The one frame's mask on ``topic`` of a results MCAP (its records read with the mcap library)."""
    with open(results, "rb") as f:
        msgs = [m for _, _, m in make_reader(f).iter_messages(topics=[topic])]
    assert len(msgs) == 1
    return image_to_mask(decode_image(msgs[0].data), where=topic)


def _replay(capsys, log, out, *extra) -> tuple[int, str, str]:
    return run_cli(capsys, "replay", log, "--methods", METHODS, "--out", out, "--json", *extra)


def test_replay_writes_the_explained_mask_from_the_logs_part_model(replayed):
    d, rc, out, err = replayed
    assert rc == 0, err
    mask = _mask(d / "r.mcap", layout.method_topic("explained"))
    scored = _mask(d / "r.mcap", layout.ZONE)  # the zone and the points above the rim
    assert mask.sum() > 20 and not (mask & ~scored).any()
    assert "explained: the part model is the log's part_model.ply" in (out + err)
    assert "explained: no part model" not in (out + err)


def test_part_model_option_gives_the_same_mask(capsys, tmp_path, log, replayed):
    """The log's mesh written as an STL in metres and given with --part-model: the same outliers."""
    import open3d as o3d

    model = read_part_model(log)
    assert model is not None and model.unit == "mm"
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(model.vertices / 1000.0),
                                     o3d.utility.Vector3iVector(model.triangles.astype(np.int32)))
    mesh.compute_triangle_normals()
    stl = tmp_path / "ball.stl"
    assert o3d.io.write_triangle_mesh(str(stl), mesh)
    assert replayed[1] == 0  # the log's own part model: the module's replay
    rc, out, err = _replay(capsys, log, tmp_path / "b.mcap", "--part-model", stl, "--part-model-unit", "m")
    assert rc == 0, err
    a = _mask(replayed[0] / "r.mcap", layout.method_topic("explained"))
    b = _mask(tmp_path / "b.mcap", layout.method_topic("explained"))
    assert (a ^ b).sum() <= max(2, 0.02 * a.sum())  # the STL stores float32 vertices


def test_a_bad_part_model_is_one_line(capsys, tmp_path, log):
    bad = tmp_path / "bad.stl"
    bad.write_text("solid nothing\nendsolid nothing\n")
    rc, out, err = _replay(capsys, log, tmp_path / "r.mcap", "--part-model", bad)
    assert rc == 1
    assert err.startswith("error: ") and err.count("\n") == 1 and "bad.stl" in err
    rc, out, err = _replay(capsys, log, tmp_path / "r.mcap", "--part-model", tmp_path / "missing.ply")
    assert rc == 1 and err.startswith("error: ") and err.count("\n") == 1


def test_without_a_part_model_the_local_surface_judges_the_parts(capsys, tmp_path, log):
    """No part model: a named warning, and the parts' pixels judged against the edge-aware local
    surface (before: no outliers but the points above the rim)."""
    from replay.logs.reader import LogReader

    bare = tmp_path / "bare.mcap"
    without_truth(log, bare)  # its frames and bin model, no part_model.ply
    rc, out, err = _replay(capsys, bare, tmp_path / "r.mcap")
    assert rc == 0, err
    assert "explained: no part model" in err and "edge-aware local surface" in err
    mask = _mask(tmp_path / "r.mcap", layout.method_topic("explained"))
    scored = _mask(tmp_path / "r.mcap", layout.ZONE)
    zcut = _mask(tmp_path / "r.mcap", layout.method_topic("zcut"))
    assert not (mask & ~scored).any()
    assert (mask & ~zcut).sum() > 20  # its own outliers, not only the points above the rim
    truth = next(iter(LogReader(log).frames())).masks[layout.TRUTH_OFF_SURFACE] & scored
    tp = int((mask & truth).sum())
    print(f"fallback: flagged {int(mask.sum())}, truth {int(truth.sum())}, tp {tp}")
    # 320 × 200 (balls ~10 px across) is coarse for local planes: a few of the truth, few false alarms
    assert tp >= 0.2 * truth.sum() and mask.sum() <= 0.05 * scored.sum()


@pytest.mark.slow
def test_batch_workers_read_the_same_part_model(capsys, tmp_path, log):
    """A batch on spawn worker processes scores explained as the in-process accuracy does."""
    rc, out, err = run_cli(capsys, "accuracy", log, "--methods", METHODS, "--json")
    assert rc == 0, err
    acc = json.loads(out)
    rc, out, err = run_cli(capsys, "batch", log, "-o", tmp_path / "b", "--workers", "1", "--methods", METHODS,
                           "--json")
    assert rc == 0, err
    import pyarrow.parquet as pq

    table = pq.read_table(tmp_path / "b" / "frames.parquet").to_pylist()
    assert len(table) == 1
    text = json.dumps(acc)
    assert "explained" in text and any("explained" in k for k in table[0])
    tp = [v for k, v in table[0].items() if k.startswith("explained") and k.endswith("tp")]
    assert tp and tp[0] > 0


def test_the_recording_shows_the_fits_the_distances_and_the_unexplained(replayed):
    import rerun as rr

    d, rc, out, err = replayed
    rrd = d / "e.rrd"
    assert rc == 0, err
    entities = {chunk.entity_path for chunk in rr.chunk.RrdReader(str(rrd)).stream()}
    for path in ("/image/explained", "/image/explained_distance", "/world/explained/fits",
                 "/world/explained/labels", "/image/methods/explained"):
        assert path in entities, sorted(entities)


def test_the_recording_shows_the_local_surface_without_a_part_model(capsys, tmp_path, log):
    import rerun as rr

    from replay.pipeline.viz import EXPLAINED_CLASSES

    bare = tmp_path / "bare.mcap"
    without_truth(log, bare)
    rrd = tmp_path / "e.rrd"
    rc, out, err = run_cli(capsys, "replay", bare, "--methods", METHODS, "--rrd", rrd)
    assert rc == 0, err
    entities = {chunk.entity_path for chunk in rr.chunk.RrdReader(str(rrd)).stream()}
    for path in ("/image/explained", "/image/explained_distance", "/image/methods/explained"):
        assert path in entities, sorted(entities)
    assert (5, "local surface") in [(c, name) for c, name, _ in EXPLAINED_CLASSES]


def test_compare_runs_explained_with_the_logs_part_model(capsys, tmp_path, log):
    rc, out, err = run_cli(capsys, "compare", log, "--a", "zcut", "--b", "explained", "-o", tmp_path / "c", "--no-rrd",
                           "--json")
    assert rc == 0, err
    assert "no part model" not in out + err
    bad = tmp_path / "bad.obj"
    bad.write_text("# nothing\n")
    rc, out, err = run_cli(capsys, "compare", log, "--a", "zcut", "--b", "explained", "-o", tmp_path / "d",
                           "--no-rrd", "--part-model", bad)
    assert rc == 1 and err.startswith("error: ") and err.count("\n") == 1


def test_the_recording_shows_the_fits_the_vetting_left_out(tmp_path):
    """A fit the vetting left out is drawn apart from the kept ones (``world/explained/vetted_out``, with
    its Err and support), counted per frame, and cleared on a frame that has none."""
    import types

    import rerun as rr

    from replay.pipeline.explained import ExplainedDetail
    from replay.pipeline.viz import log_explained
    from zcut.fits import PartFit

    verts = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0]], float)
    tris = np.array([[0, 1, 2]], np.int64)
    h, w = 4, 5
    pose = np.eye(4)
    pose[:3, 3] = (0, 0, 600)
    kept = PartFit(pose, 0.12, 0.9, np.arange(3))
    moved = pose.copy()
    moved[0, 3] = 2.5
    out = PartFit(moved, 0.31, 0.4, np.arange(3, 5))
    img = np.zeros((h, w))

    def detail(vetted: tuple[PartFit, ...]) -> types.SimpleNamespace:
        d = ExplainedDetail((kept,), verts, tris, img, np.zeros((h, w), np.int64), img, np.zeros((h, w), bool),
                            vetted_out=vetted)
        return types.SimpleNamespace(details={"explained": d})

    rrd = tmp_path / "v.rrd"
    rec = rr.RecordingStream("zcut-test")
    rec.save(str(rrd))
    for i, vetted in enumerate([(out,), ()]):
        rec.set_time("frame", sequence=i)
        log_explained(rec, detail(vetted))
    rec.flush()
    rec.disconnect()
    cols: dict[tuple[str, str], list] = {}
    logged: set[tuple[str, int, str]] = set()  # (entity, frame, archetype): chunks come in no fixed order
    for chunk in rr.chunk.RrdReader(str(rrd)).stream():
        batch = chunk.to_record_batch()
        if "frame" in batch.schema.names:
            kinds = {n.split(":")[0] for n in batch.schema.names if ":" in n}
            logged |= {(chunk.entity_path, f, k) for f in batch.column("frame").to_pylist() for k in kinds}
        for name in batch.schema.names:
            if name not in ("log_time", "rerun.controls.RowId"):
                cols.setdefault((chunk.entity_path, name), []).extend(batch.column(name).to_pylist())
    mesh = cols[("/world/explained/vetted_out", "Mesh3D:vertex_positions")]
    assert len(mesh) == 1 and np.allclose(np.array(mesh[0]), (verts + moved[:3, 3]) / 1000.0, atol=1e-6)
    assert cols[("/world/explained/vetted_out_labels", "Points3D:labels")] == [["vetted out 0: Err 0.31 mm, support 0.40"]]
    assert cols[("/world/explained/labels", "Points3D:labels")] == [["fit 0: Err 0.12 mm, support 0.90"]] * 2
    assert [v[0] for v in cols[("/counts/explained_vetted_out", "Scalars:scalars")]] == [1.0, 0.0]
    # frame 1 has none: its mesh and labels are cleared, so the viewer does not keep frame 0's
    assert {(f, k) for e, f, k in logged if e == "/world/explained/vetted_out"} == {(0, "Mesh3D"), (1, "Clear")}
    assert {(f, k) for e, f, k in logged if e == "/world/explained/fits"} == {(0, "Mesh3D"), (1, "Mesh3D")}
