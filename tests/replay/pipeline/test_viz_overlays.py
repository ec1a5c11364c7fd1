"""The recording's overlays at default detail: half resolution (each pixel the highest class of its 2 x 2
block of the full-detail image, scaled back onto the image by a static Transform3D), the z-cut level
image in uint8, the cloud capped at ~80,000 grid points, and the images' components built directly in
Arrow equal to Rerun's own. Real .rrd files written and read back with rr.chunk.RrdReader; the
full-detail recording of the same frame is the reference."""

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

#: the class images over image/rgb, and the z-cut levels (their own space)
OVERLAY_ENTITIES = ("/image/bin_mask", "/image/removal", "/image/bin_check", "/image/clusters", "/image/outliers",
                    "/image/methods/other", "/image/verdicts/zcut", "/image/verdicts/sor")


def _block_max(a: np.ndarray, s: int) -> np.ndarray:
    """The literal definition: each pixel the max of its s x s block (cut at the border)."""
    h, w = a.shape
    out = np.zeros((-(-h // s), -(-w // s)), a.dtype)
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            out[i, j] = a[i * s:(i + 1) * s, j * s:(j + 1) * s].max()
    return out


_DTYPES = {"U8": np.uint8, "U16": np.uint16, "U32": np.uint32}


def _read(path):
    """entity -> {"images": [(H, W) ndarray], "scale": [static Transform3D scales], "points": [(n, 3)]}."""
    out: dict[str, dict[str, list]] = {}
    for chunk in rr.chunk.RrdReader(str(path)).stream():
        rb = chunk.to_record_batch()
        e = out.setdefault(chunk.entity_path, {"images": [], "scale": [], "points": []})
        names = rb.schema.names
        if "SegmentationImage:buffer" in names:
            fmts = rb.column("SegmentationImage:format").to_pylist()
            for buf, fmt in zip(rb.column("SegmentationImage:buffer").to_pylist(), fmts):
                if buf:
                    f = fmt[0]
                    dt = _DTYPES[rr.encodings.ChannelDatatype(f["channel_datatype"]).name]
                    e["images"].append(np.frombuffer(bytes(buf[0]), dt).reshape(f["height"], f["width"]))
        if "Transform3D:scale" in names and chunk.is_static:
            e["scale"] += [v[0] for v in rb.column("Transform3D:scale").to_pylist() if v]
        if "Points3D:positions" in names:
            e["points"] += [np.asarray(p, np.float32) for p in rb.column("Points3D:positions").to_pylist() if p]
    return out


def _record(path, frame, r, opts, config, verdicts):
    rec = viz.new_recording(recording_id=path.stem)
    viz.open_sink(rec, rrd=str(path))
    viz.log_static(rec, config_toml="", opts=opts)
    viz.log_verdicts_static(rec, ("zcut", "sor"), source="test", opts=opts)
    viz.log_frame(rec, frame, r, step_mm=config.zcut.step, opts=opts)
    viz.log_verdicts(rec, frame, verdicts, ("zcut", "sor"), opts)
    rec.flush()
    rec.disconnect()
    return _read(path)


@pytest.fixture(scope="module")
def both(setup, tmp_path_factory):  # noqa: F811 - the fixture of test_viz
    resolved, model = setup
    config = resolved.config
    frame, _ = ps.scene(h=H, w=W, shift=(0.004, 0.0, 0.0), specks=8, seed=5)
    frame = dataclasses.replace(frame, index=0, stamp_ns=1_000)
    r = run_frame(frame, config, bin_model=ps.prepared(model, config))
    other = np.random.default_rng(9).random((H, W)) < 0.03  # a third method: image/methods/other
    r = dataclasses.replace(r, outliers={**r.outliers, "other": other})
    truth = np.random.default_rng(4).random((H, W)) < 0.05
    verdicts = {"zcut": method_verdict(r.zcut_outliers, truth, r.valid),
                "sor": method_verdict(r.sor_outliers, truth, r.valid)}
    d = tmp_path_factory.mktemp("rrd_overlays")
    default = _record(d / "default.rrd", frame, r, viz.VizOptions(), config, verdicts)
    full = _record(d / "full.rrd", frame, r, viz.VizOptions.full(), config, verdicts)
    return frame, r, verdicts, default, full


def test_the_overlays_are_the_block_maxima_of_the_full_detail_ones(both):
    frame, r, verdicts, default, full = both
    assert r.bin_check is not None and r.bin_check.offending is not None and r.cut.n_clusters > 0
    for e in OVERLAY_ENTITIES:
        (big,), (small,) = full[e]["images"], default[e]["images"]
        assert big.shape == (H, W) and small.shape == (H // 2, W // 2), e
        assert small.dtype == big.dtype, e
        assert np.array_equal(small, _block_max(big, 2)), e
    # the full-detail images are those of the literal formulas (test_viz_images), the verdicts' own classes
    assert np.array_equal(full["/image/verdicts/zcut"]["images"][0], verdicts["zcut"].classes)
    assert np.array_equal(full["/image/clusters"]["images"][0], r.cut.clusters)
    # one outlier pixel still shows: a block holding an outlier is an outlier block
    outl = default["/image/outliers"]["images"][0]
    assert np.array_equal(outl > 0, _block_max(r.zcut_outliers | r.sor_outliers | r.easy_outliers, 2))


def test_a_static_scale_puts_the_overlays_on_the_image_at_default_detail_only(both):
    _, _, _, default, full = both
    scaled = {e for e, v in default.items() if v["scale"]}
    assert scaled == {"/" + e for e in viz.OVERLAYS} | {"/image/verdicts"}
    assert all(s == [2.0, 2.0, 2.0] for e in scaled for s in default[e]["scale"])
    assert not any(v["scale"] for v in full.values())
    assert "/image/rgb" not in scaled and "/zcut/cuts" not in scaled


def test_the_entity_paths_are_those_of_full_detail(both):
    _, _, _, default, full = both
    assert set(default) == set(full)


def test_the_level_image_is_uint8_at_default_detail_and_exact(both):
    _, r, _, default, full = both
    (small,), (big,) = default["/zcut/cuts"]["images"], full["/zcut/cuts"]["images"]
    assert small.dtype == np.uint8 and big.dtype == np.uint16 and small.shape == (H // 2, W // 2)
    m, _ = viz.scrub_levels(r.cut.n_levels, viz.VizOptions())
    lvl = r.cut.pixel_level[::2, ::2].astype(np.int32)
    assert np.array_equal(small, np.where(lvl >= 0, (lvl + m - 1) // m + 1, 0))


def test_the_cloud_keeps_every_point_at_full_detail_and_every_4th_of_a_small_frame(both):
    frame, _, _, default, full = both
    (pts,), (all_pts,) = default["/world/cloud"]["points"], full["/world/cloud"]["points"]
    assert len(all_pts) == np.isfinite(frame.xyz).all(axis=2).sum()
    assert np.array_equal(pts, frame.xyz[::4, ::4][np.isfinite(frame.xyz[::4, ::4]).all(axis=2)])


@pytest.mark.parametrize("hw, step", [((120, 160), 4), ((480, 640), 4), ((800, 1280), 4), ((1200, 1920), 6),
                                      ((2400, 3840), 11), ((1, 1), 4)])
def test_the_cloud_step_caps_the_points(hw, step):
    o = viz.VizOptions()
    assert o.cloud_step(*hw) == step
    assert -(-hw[0] // step) * -(-hw[1] // step) <= max(o.max_cloud_points, 16 * 16)
    assert viz.VizOptions.full().cloud_step(*hw) == 1


def _pool_cases():
    rng = np.random.default_rng(1)
    for dt in (bool, np.uint8, np.uint16, np.uint32, np.int32):
        for shape in ((4, 6), (5, 7), (1, 1), (2, 2), (1, 8), (30, 41), (64, 64)):
            for s in (1, 2, 3):
                top = 2 if dt is bool else int(min(np.iinfo(dt).max, 70_000))
                yield (rng.integers(0, top, shape).astype(dt), s)


@pytest.mark.parametrize("a, s", list(_pool_cases()))
def test_pool_max_is_the_block_maximum(a, s):
    out = viz.pool_max(a, s)
    assert out.dtype == a.dtype and np.array_equal(out, _block_max(a, s))


def test_pool_max_of_a_non_contiguous_view():
    a = np.random.default_rng(2).integers(0, 200, (40, 60)).astype(np.uint8)
    assert np.array_equal(viz.pool_max(a[:, 2:50], 2), _block_max(a[:, 2:50], 2))
    assert np.array_equal(viz.pool_max(a.T, 2), _block_max(a.T, 2))


def _cut_cases():
    rng = np.random.default_rng(3)
    for shape in ((4, 6), (5, 8), (5, 7), (1, 2), (120, 160)):
        for top in (3, 40, 150, 600, 5000):
            for m in (1, 2, 5, 20):
                pl = rng.integers(-1, top + 2, shape).astype(np.int16)
                yield pl, m
    odd = np.full((4, 6), 3, np.int16)
    odd[0, 0] = -7  # not a level the z-cut writes: the general formula takes it
    yield odd, 1
    yield np.asfortranarray(rng.integers(-1, 30, (6, 8)).astype(np.int16)), 2


@pytest.mark.parametrize("pl, m", list(_cut_cases()))
@pytest.mark.parametrize("s", [1, 2, 3])
def test_cut_classes_are_the_literal_ones(pl, m, s):
    lvl = pl[::s, ::s].astype(np.int32)
    want = np.where(lvl >= 0, (lvl + m - 1) // m + 1, 0)
    assert np.array_equal(viz.cut_classes(pl, s, m), want) and viz.cut_classes(pl, s, m).dtype == np.uint16
    small = viz.cut_classes(pl, s, m, small=True)
    assert np.array_equal(small, want) and small.dtype == (np.uint8 if want.max() < 256 else np.uint16)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.uint32])
@pytest.mark.parametrize("opacity", [None, 0.35])
def test_the_direct_segmentation_image_is_rerun_s_own(dtype, opacity):
    img = np.random.default_rng(6).integers(0, 9, (7, 11)).astype(dtype)
    ours = viz._segmentation(img, opacity=opacity).as_component_batches()
    theirs = rr.SegmentationImage(img, opacity=opacity).as_component_batches()
    assert [b.component_descriptor() for b in ours] == [b.component_descriptor() for b in theirs]
    for a, b in zip(ours, theirs):
        assert a.as_arrow_array().type == b.as_arrow_array().type
        assert a.as_arrow_array().equals(b.as_arrow_array())


def test_the_direct_jpeg_is_rerun_s_own():
    rgb = np.random.default_rng(7).integers(0, 255, (8, 10, 3)).astype(np.uint8)
    ours = viz._image(rgb, viz.VizOptions()).as_component_batches()
    import cv2

    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 85])
    theirs = rr.EncodedImage(contents=buf.tobytes(), media_type="image/jpeg").as_component_batches()
    for a, b in zip(ours, theirs, strict=True):
        assert a.component_descriptor() == b.component_descriptor()
        assert a.as_arrow_array().equals(b.as_arrow_array())


def _scatter_cases():
    rng = np.random.default_rng(11)
    for dt in (np.uint8, np.uint16):
        for shape in ((4, 6), (5, 7), (1, 1), (1, 9), (30, 41), (64, 64)):
            for density in (0.0, 0.02, 0.3, 1.0):
                img = np.where(rng.random(shape) < density, rng.integers(1, 5, shape), 0).astype(dt)
                for s in (1, 2, 3):
                    yield img, s


@pytest.mark.parametrize("img, s", list(_scatter_cases()))
def test_scatter_pool_max_is_the_block_maximum_of_the_scattered_image(img, s):
    idx = np.flatnonzero(img)
    out = viz.scatter_pool_max(img.shape, idx, img.ravel()[idx], s)
    assert out.dtype == img.dtype and np.array_equal(out, _block_max(img, s))


def _outlier_masks():
    rng = np.random.default_rng(12)
    shape = (37, 52)
    for pz, ps_, pe in ((0.05, 0.05, 0.02), (0.5, 0.5, 0.3), (0.0, 0.0, 0.0), (1.0, 1.0, 0.0), (1.0, 0.0, 1.0),
                        (0.0, 0.2, 0.0)):
        yield (rng.random(shape) < pz, rng.random(shape) < ps_, rng.random(shape) < pe)
    z, s, e = (rng.random((60, 40)) < 0.2 for _ in range(3))
    yield np.asfortranarray(z), s[:, ::-1], e  # views of other layouts


@pytest.mark.parametrize("z, s, e", list(_outlier_masks()))
def test_the_outlier_pixels_are_those_of_the_whole_frame_masks(z, s, e):
    r = type("R", (), {"zcut_outliers": z, "sor_outliers": s, "easy_outliers": e})()
    px = viz.outlier_pixels(r)
    literal = np.where(e, 4, np.where(z & s, 3, np.where(z, 1, np.where(s, 2, 0)))).astype(np.uint8)
    assert np.array_equal(px.idx, np.flatnonzero(z | s | e))
    assert np.array_equal(px.classes, literal.ravel()[px.idx]) and px.classes.dtype == np.uint8
    # the counts the recording logs, from these pixels alone
    assert (np.count_nonzero(px.zcut), np.count_nonzero(px.sor), np.count_nonzero(px.zcut & px.sor),
            np.count_nonzero(px.above_rim)) == (z.sum(), s.sum(), (z & s).sum(), e.sum())
    for k in (1, 2):
        assert np.array_equal(viz.scatter_pool_max(z.shape, px.idx, px.classes, k), _block_max(literal, k))


def test_the_logged_counts_and_outlier_points_are_the_whole_frame_ones(both):
    frame, r, _, default, full = both
    literal = np.where(r.easy_outliers, 4, np.where(r.zcut_outliers & r.sor_outliers, 3,
                                                    np.where(r.zcut_outliers, 1, np.where(r.sor_outliers, 2, 0))))
    assert np.array_equal(full["/image/outliers"]["images"][0], literal)
    assert np.array_equal(default["/image/outliers"]["images"][0], _block_max(literal.astype(np.uint8), 2))
    any_ = r.zcut_outliers | r.sor_outliers | r.easy_outliers
    for rec in (default, full):
        (pts,) = rec["/world/outliers"]["points"]
        assert np.array_equal(pts, frame.xyz[any_], equal_nan=True)
