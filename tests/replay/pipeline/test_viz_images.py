"""The class images the recording holds at full detail (bin mask, removal, bin check, outliers, z-cut
levels, verdicts) and the verdicts' points (their indices now from a bool view) are those of the literal
formulas: a real .rrd written and read back with rr.chunk.RrdReader (default detail holds their 2 x 2
block maxima: test_viz_overlays.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pipeline_scene as ps
import pytest
import rerun as rr
from test_viz import H, W, setup  # noqa: F401 - test_viz's scene and bin model fixture, reused

from replay.pipeline import viz
from replay.pipeline.stages import run_frame
from replay.pipeline.verdicts import method_verdict


def _u8(m):
    return np.asarray(m, bool).astype(np.uint8)


def _literal_max(*layers):
    """The previous code: max of mask * class over the layers."""
    c = np.zeros(layers[0][1].shape, np.uint8)
    for k, m in layers:
        c = np.maximum(c, _u8(m) * np.uint8(k))
    return c


def _literal_cuts(pixel_level, m):
    lvl = pixel_level.astype(np.int32)
    return np.where(lvl >= 0, (lvl + m - 1) // m + 1, 0).astype(np.uint16)


def _images(path):
    """entity -> list of (shape, buffer as bytes) of its SegmentationImages, in order."""
    out: dict[str, list] = {}
    for chunk in rr.chunk.RrdReader(str(path)).stream():
        rb = chunk.to_record_batch()
        if "SegmentationImage:buffer" not in rb.schema.names:
            continue
        for b in rb.column("SegmentationImage:buffer").to_pylist():
            if b:
                out.setdefault(chunk.entity_path, []).append(np.asarray(b[0], np.uint8))
    return out


def _points(path, entity):
    out = []
    for chunk in rr.chunk.RrdReader(str(path)).stream():
        if chunk.entity_path != entity:
            continue
        rb = chunk.to_record_batch()
        if "Points3D:positions" in rb.schema.names:
            pos = rb.column("Points3D:positions").to_pylist()
            ids = rb.column("Points3D:class_ids").to_pylist()
            out += [(np.asarray(p, np.float32), np.asarray(i)) for p, i in zip(pos, ids) if p is not None]
    return out


@pytest.fixture(scope="module")
def logged(setup, tmp_path_factory):  # noqa: F811 - the fixture of test_viz
    resolved, model = setup
    config = resolved.config
    path = tmp_path_factory.mktemp("rrd_images") / "t.rrd"
    rec = viz.new_recording(recording_id="images")
    viz.open_sink(rec, rrd=str(path))
    frame, _ = ps.scene(h=H, w=W, shift=(0.004, 0.0, 0.0), specks=6, seed=3)
    frame = dataclasses.replace(frame, index=0, stamp_ns=1_000)
    r = run_frame(frame, config, bin_model=ps.prepared(model, config))
    full = viz.VizOptions.full()
    viz.log_frame(rec, frame, r, step_mm=config.zcut.step, opts=full)
    truth = np.random.default_rng(4).random((H, W)) < 0.05
    verdicts = {"zcut": method_verdict(r.zcut_outliers, truth, r.valid),
                "sor": method_verdict(r.sor_outliers, truth, r.valid)}
    viz.log_verdicts(rec, frame, verdicts, ("zcut", "sor"), full)
    rec.flush()
    rec.disconnect()
    return path, frame, r, verdicts, config


def test_the_class_images_are_the_literal_ones(logged):
    path, frame, r, _, config = logged
    imgs = _images(path)
    assert r.bin_mask is not None and r.removal is not None and r.bin_check is not None
    want = {
        "/image/bin_mask": _literal_max((1, r.bin_mask.mask), (2, r.bin_mask.walls)),
        "/image/removal": _literal_max((1, r.removal.table), (2, r.removal.bin_points),
                                       (3, r.removal.easy_outliers), (4, r.removal.zone)),
        "/image/outliers": np.maximum(_u8(r.zcut_outliers) + 2 * _u8(r.sor_outliers),
                                      _u8(r.easy_outliers) * np.uint8(4)).astype(np.uint8),
    }
    check = r.bin_check
    if check.offending is not None:
        ring = np.zeros((H, W), bool) if check.ring is None else check.ring
        want["/image/bin_check"] = _literal_max((1, ring), (2, check.offending))
    for entity, w in want.items():
        assert np.array_equal(imgs[entity][0].reshape(H, W), w), entity
    m, _ = viz.scrub_levels(r.cut.n_levels, viz.VizOptions.full())
    cuts = imgs["/zcut/cuts"][0].view(np.uint16).reshape(H, W)
    assert np.array_equal(cuts, _literal_cuts(r.cut.pixel_level, m))


def test_the_verdicts_points_are_the_literal_ones(logged):
    path, frame, r, verdicts, _ = logged
    for name, v in verdicts.items():
        (pos, ids), = _points(path, f"/world/verdicts/{name}")
        rows, cols = np.nonzero(v.classes)  # the previous code: every nonzero class, row-major
        assert np.array_equal(pos, frame.xyz[rows, cols]) and np.array_equal(ids, v.classes[rows, cols])
        assert np.array_equal(_images(path)[f"/image/verdicts/{name}"][0].reshape(H, W), v.classes)

