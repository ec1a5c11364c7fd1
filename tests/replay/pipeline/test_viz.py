"""Rerun logging: a real .rrd written and read back with rr.chunk.RrdReader."""

from __future__ import annotations

import dataclasses
import math
from collections import defaultdict

import numpy as np
import pipeline_scene as ps
import pytest
import rerun as rr

from replay.pipeline import config as cfg
from replay.pipeline import viz
from replay.pipeline.bin_model import build_bin_model
from replay.pipeline.stages import run_frame

H, W = 120, 160
LAYER = {"zcut": {"step_mm": 1.0, "max_depth_mm": 40.0, "max_area_px": 30.0},
         "removal": {"delta_mm": 2.0, "search_radius_mm": 5.0},
         "registration": {"voxel_mm": 2.0}}


def read_rrd(path):
    """entity path -> list of (timeline values dict, {column: python list}) per chunk."""
    out = defaultdict(list)
    for chunk in rr.chunk.RrdReader(path).stream():
        rb = chunk.to_record_batch()
        cols = {}
        for name in rb.schema.names:
            if name in ("rerun.controls.RowId", "log_time", "stamp"):
                continue
            cols[name] = rb.column(name).to_pylist()
        out[chunk.entity_path].append((chunk.is_static, cols))
    return out


def _any2(mask):
    """Whether any pixel of each 2 x 2 block is set (the overlays' resolution at default detail)."""
    return np.asarray(mask, bool).reshape(mask.shape[0] // 2, 2, mask.shape[1] // 2, 2).any(axis=(1, 3))


def column(entries, name):
    vals = []
    for _, cols in entries:
        vals += cols.get(name, [])
    return vals


@pytest.fixture(scope="module")
def setup():
    resolved = cfg.resolve(cfg.LogFacts(None, None, None, (H, W)), file_layer=LAYER)
    config = resolved.config
    frames = []
    for i, s in enumerate([(0, 0, 0), (0.02, 0, 0), (-0.02, 0, 0), (0, 0.02, 0), (0, -0.02, 0)]):
        f, _ = ps.scene(h=H, w=W, shift=s, parts=False)
        frames.append(dataclasses.replace(f, index=i))
    model = build_bin_model(frames, bin_mask_params=config.bin_mask, registration=config.registration,
                            voxel_mm=2.0)[0]
    return resolved, model


@pytest.fixture(scope="module")
def recording(setup, tmp_path_factory):
    resolved, model = setup
    config = resolved.config
    path = tmp_path_factory.mktemp("rrd") / "t.rrd"
    rec = viz.new_recording(recording_id="test")
    viz.open_sink(rec, rrd=str(path))
    toml = cfg.to_toml(config)
    viz.log_static(rec, config_toml=toml, notes=resolved.notes, bin_model=model, source="log: test")
    results = []
    for i in range(2):
        frame, _ = ps.scene(h=H, w=W, shift=(0.004 * i, 0.0, 0.0), specks=6, seed=i)
        frame = dataclasses.replace(frame, index=i, stamp_ns=1_000 + i)
        if i == 1:
            frame = dataclasses.replace(frame, rgb=None)  # second frame: bin stages skipped
        r = run_frame(frame, config, bin_model=ps.prepared(model, config))
        viz.log_frame(rec, frame, r, step_mm=config.zcut.step)
        results.append((frame, r))
    rec.flush()
    rec.disconnect()
    return path, read_rrd(str(path)), results, toml


def test_every_stage_has_its_entity(recording):
    _, data, _, _ = recording
    for e in ("/image/rgb", "/image/bin_mask", "/image/removal", "/image/clusters", "/image/outliers",
              "/zcut/cuts", "/world/cloud", "/world/outliers", "/world/bin_model", "/world/bin_model/points",
              "/world/bin_model/status", "/counts/zcut", "/counts/sor", "/counts/both", "/metrics/alpha",
              "/metrics/beta_sor", "/metrics/beta_zcut", "/timings_ms/zcut", "/timings_ms/registration",
              "/registration/fitness", "/registration/rmse_mm", "/config", "/log", "/image/bin_check",
              "/bin_check/pixels", "/bin_check/threshold", "/bin_check/flagged", "/bin_check/tolerance_mm"):
        assert e in data, e


def test_the_bin_check_is_a_scalar_and_an_image(recording):
    _, data, results, _ = recording
    check = results[0][1].bin_check
    assert [v[0] for v in column(data["/bin_check/pixels"], "Scalars:scalars")] == [check.value]
    assert [v[0] for v in column(data["/bin_check/flagged"], "Scalars:scalars")] == [float(check.flagged)]
    images = [v for v in column(data["/image/bin_check"], "SegmentationImage:buffer") if v is not None]
    assert len(images) == 1  # the second frame (no RGB) clears it
    classes = np.asarray(images[0], np.uint8).reshape(H // 2, W // 2)  # default detail: 2 x 2 blocks
    assert np.array_equal(classes == 2, _any2(check.offending))
    assert np.array_equal(classes == 1, _any2(check.ring) & ~_any2(check.offending))


def test_counts_match_the_masks(recording):
    _, data, results, _ = recording
    zc = [v[0] for v in column(data["/counts/zcut"], "Scalars:scalars")]
    sr = [v[0] for v in column(data["/counts/sor"], "Scalars:scalars")]
    both = [v[0] for v in column(data["/counts/both"], "Scalars:scalars")]
    assert zc == [float(r.zcut_outliers.sum()) for _, r in results]
    assert sr == [float(r.sor_outliers.sum()) for _, r in results]
    assert both == [float((r.zcut_outliers & r.sor_outliers).sum()) for _, r in results]
    assert zc[0] > 0
    alpha = [v[0] for v in column(data["/metrics/alpha"], "Scalars:scalars")]
    for a, (_, r) in zip(alpha, results):
        assert (math.isnan(a) and math.isnan(r.metrics.alpha)) or a == pytest.approx(r.metrics.alpha)
    fit = column(data["/registration/fitness"], "Scalars:scalars")
    assert len(fit) == 1 and fit[0][0] == pytest.approx(results[0][1].registration.fitness)


def test_outlier_classes_in_2d_and_3d(recording):
    _, data, results, _ = recording
    frame, r = results[0]
    n = int((r.zcut_outliers | r.sor_outliers).sum())
    pts = column(data["/world/outliers"], "Points3D:positions")
    assert len(pts[0]) == n
    ids = column(data["/world/outliers"], "Points3D:class_ids")[0]
    exp = np.where(r.zcut_outliers & r.sor_outliers, 3, np.where(r.zcut_outliers, 1, 2))[r.zcut_outliers | r.sor_outliers]
    assert sorted(ids) == sorted(exp.tolist())
    static_ctx = [c for s, c in data["/image/outliers"] if s]
    assert static_ctx, "the outlier classes' AnnotationContext is static"
    seg = column(data["/image/outliers"], "SegmentationImage:buffer")
    assert len(seg) == 2
    buf = np.asarray(seg[0], np.uint8).reshape(H // 2, W // 2)  # default detail: 2 x 2 blocks, highest class
    assert np.array_equal(buf > 0, _any2(r.zcut_outliers | r.sor_outliers))
    assert np.array_equal(buf >= 2, _any2(r.sor_outliers))


def test_cuts_are_scrubbable_on_the_depth_timeline(recording):
    path, _, results, _ = recording
    n_ctx = 0
    timelines = set()
    depths = set()
    for chunk in rr.chunk.RrdReader(str(path)).stream():
        if chunk.entity_path != "/zcut/cuts":
            continue
        rb = chunk.to_record_batch()
        timelines |= set(chunk.timeline_names)
        if "AnnotationContext:context" in rb.schema.names:
            depth = rb.column("depth_um").to_pylist()
            ctx = rb.column("AnnotationContext:context").to_pylist()
            n_ctx += sum(1 for c in ctx if c is not None)
            depths |= {d for d, c in zip(depth, ctx) if c is not None}
    assert "depth_um" in timelines and "frame" in timelines
    # one context per level 0 .. K + 1 per frame
    K = results[0][1].cut.n_levels
    m, levels = viz.scrub_levels(K, viz.VizOptions())
    assert levels[0] == 0 and levels[-1] == K + 1 and len(levels) <= 33
    assert n_ctx == 2 * len(levels)
    assert depths == {k * 1000 for k in levels}  # depth_um = k * step (1 mm)


@pytest.mark.parametrize("K, full, expect", [
    (40, True, list(range(42))),
    (40, False, list(range(0, 42, 2))),          # 42 levels > 32: every 2nd, 0 .. 40 and 41
    (10, False, list(range(12))),
    (150, False, list(range(0, 152, 5)) + [151]),
])
def test_scrub_levels(K, full, expect):
    m, levels = viz.scrub_levels(K, viz.VizOptions.full() if full else viz.VizOptions())
    assert levels == (expect if expect[-1] == K + 1 else expect + [K + 1])


def test_a_shown_cut_is_exactly_the_cut(recording):
    """The level image's classes visible at level k are exactly the pixels with pixel_level <= k."""
    path, _, results, _ = recording
    r = results[-1][1]
    m, levels = viz.scrub_levels(r.cut.n_levels, viz.VizOptions())
    seg = None
    for chunk in rr.chunk.RrdReader(str(path)).stream():
        if chunk.entity_path == "/zcut/cuts":
            rb = chunk.to_record_batch()
            if "SegmentationImage:buffer" in rb.schema.names:
                bufs = [b for b in rb.column("SegmentationImage:buffer").to_pylist() if b]
                seg = np.asarray(bufs[-1][0], np.uint8).reshape(H // 2, W // 2)  # uint8 at default detail
    assert seg is not None
    pl = r.cut.pixel_level[::2, ::2].astype(np.int32)
    for k in levels:
        q = (k + m - 1) // m
        shown = (seg >= 1) & (seg <= q + 1)
        assert np.array_equal(shown, (pl >= 0) & (pl <= k))


def test_clusters_carry_area_and_level(recording):
    _, data, results, _ = recording
    _, r = results[0]
    ctx = column(data["/image/clusters"], "AnnotationContext:context")[0][0]
    infos = [c["class_description"]["info"] for c in ctx]
    labels = [i["label"] for i in infos if i["label"] and i["label"].startswith("cluster")]
    assert len(labels) == r.cut.n_clusters > 0
    assert labels[0] == f"cluster 1: {r.cut.areas[0]} px, level {r.cut.levels[0]}"


def test_config_document_is_static_and_complete(recording):
    _, data, _, toml = recording
    (static, cols), = data["/config"]
    assert static
    text = cols["TextDocument:text"][0][0]
    assert toml in text and "max_area_px = 30.0" in text


def test_skipped_bin_stages_are_cleared_and_warned(recording):
    _, data, _, _ = recording
    logs = column(data["/log"], "TextLog:text")
    assert any("frame 1" in t[0] and "no RGB image" in t[0] for t in logs)
    assert any("Clear:is_recursive" in cols for _, cols in data["/image/bin_mask"])
    status = [lab[0] for lab in column(data["/world/bin_model/status"], "Points3D:labels")]
    assert status[0].startswith("fitness ") and "RMSE" in status[0]
    assert status[1].startswith("not registered: no RGB image")


def test_default_detail_downsamples_the_cloud(recording):
    _, data, results, _ = recording
    frame, _ = results[0]
    pts = column(data["/world/cloud"], "Points3D:positions")[0]
    assert len(pts) == np.isfinite(frame.xyz[::4, ::4]).all(axis=2).sum()
    rgb = column(data["/image/rgb"], "EncodedImage:blob")
    assert rgb, "the RGB image is JPEG-encoded at default detail"


def test_full_detail_logs_everything(setup, tmp_path):
    resolved, model = setup
    frame, _ = ps.scene(h=H, w=W, specks=3)
    r = run_frame(frame, resolved.config, bin_model=ps.prepared(model, resolved.config))
    path = tmp_path / "full.rrd"
    rec = viz.new_recording()
    viz.open_sink(rec, rrd=str(path))
    viz.log_frame(rec, frame, r, step_mm=1.0, opts=viz.VizOptions.full())
    rec.flush()
    rec.disconnect()
    data = read_rrd(str(path))
    assert len(column(data["/world/cloud"], "Points3D:positions")[0]) == np.isfinite(frame.xyz).all(axis=2).sum()
    assert column(data["/image/rgb"], "Image:buffer")
    seg = column(data["/zcut/cuts"], "SegmentationImage:buffer")[0][0]
    assert len(seg) == H * W * 2  # uint16 level image at full resolution


def test_the_default_blueprint_is_in_the_file(recording):
    path, _, _, _ = recording
    reader = rr.chunk.RrdReader(str(path))
    (bp,) = reader.blueprints()
    views = {ch.entity_path for ch in reader.stream(store=bp) if ch.entity_path.startswith("/view/")
             and not ch.entity_path.endswith("ViewContents")}
    assert len(views) == 13  # 5 image views, 3D, 5 time series, config and warnings (default_blueprint)


#: a process that prints the local address (hex, as /proc/net shows it) of every socket it sees
#: listening on the port argv[1], until it is stopped: a separate process, so that it looks often
#: enough to see a viewer that listens only for a moment
WATCH = """
import sys
port = int(sys.argv[1])
seen = set()
while True:
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with open(table) as f:
            for row in f.read().splitlines()[1:]:
                fields = row.split()
                address, hex_port = fields[1].split(":")
                if fields[3] == "0A" and int(hex_port, 16) == port and address not in seen:
                    seen.add(address)
                    print(address, flush=True)
"""


def test_a_spawned_viewer_listens_on_this_machine_only():
    """``--spawn`` starts Rerun's viewer with its server bound to 127.0.0.1 (Rerun's own default and
    ``rr.spawn``'s is 0.0.0.0). The native viewer cannot open a window on a machine without a
    display and exits soon after it starts listening: its listening socket is watched meanwhile."""
    import socket
    import subprocess
    import sys
    import time

    from replay.errors import ConfigError

    seen: list[str] = []
    exits: list[str] = []
    for _ in range(6):  # a loaded machine may not let the watcher look while the viewer listens
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        watcher = subprocess.Popen([sys.executable, "-c", WATCH, str(port)], stdout=subprocess.PIPE, text=True)
        time.sleep(0.5)
        proc = None
        try:
            proc = viz.spawn_viewer(port=port, timeout_s=60)
        except ConfigError as e:  # it exited (no display) after it listened
            exits.append(str(e))
        finally:
            time.sleep(0.5)
            if proc is not None:
                proc.kill()
                proc.wait()
            watcher.kill()
            seen += watcher.communicate()[0].split()
        if seen:
            break
    assert seen and set(seen) == {"0100007F"}, (seen, exits)  # 127.0.0.1, and nothing on 0.0.0.0 or ::
    assert all("exited as it started" in e for e in exits), exits
    assert viz.viewer_args(port)[:2] == ["--bind", "127.0.0.1"]


def _blueprint_column(path, entity: str, name: str) -> list:
    reader = rr.chunk.RrdReader(str(path))
    (bp,) = reader.blueprints()
    out = []
    for ch in reader.stream(store=bp):
        rb = ch.to_record_batch()
        if ch.entity_path == entity and name in rb.schema.names:
            out += rb.column(name).to_pylist()
    return out


def test_the_recording_opens_on_the_frame_timeline(recording):
    """Issue 35 #21: on ``depth_um`` at #0 the z-cuts view was empty and every per-frame series one point."""
    path, _, _, _ = recording
    assert _blueprint_column(path, "/time_panel", "TimePanelBlueprint:timeline") == [["frame"]]
    reader = rr.chunk.RrdReader(str(path))
    names = []
    for ch in reader.stream(store=reader.blueprints()[0]):
        rb = ch.to_record_batch()
        if "ViewBlueprint:display_name" in rb.schema.names:
            names += [n[0] for n in rb.column("ViewBlueprint:display_name").to_pylist() if n]
    assert viz.ZCUTS_VIEW in names and "depth_um" in viz.ZCUTS_VIEW, names  # the scrub, one click away, said


def test_on_the_frame_timeline_every_view_has_data_at_every_frame(recording):
    """What the viewer shows at a frame of the frame timeline: the z-cuts' level image and the context of
    the deepest level (every level coloured) at that frame, and a per-frame series with one point a frame."""
    path, data, results, _ = recording
    images, contexts = defaultdict(int), {}
    for chunk in rr.chunk.RrdReader(str(path)).stream():
        if chunk.entity_path != "/zcut/cuts" or chunk.is_static:
            continue
        rb = chunk.to_record_batch()
        frames = rb.column("frame").to_pylist()
        depth = rb.column("depth_um").to_pylist()
        if "SegmentationImage:buffer" in rb.schema.names:
            for f, img in zip(frames, rb.column("SegmentationImage:buffer").to_pylist()):
                images[f] += img is not None
        if "AnnotationContext:context" in rb.schema.names:
            for f, d, c in zip(frames, depth, rb.column("AnnotationContext:context").to_pylist()):
                if c is not None and d >= contexts.get(f, (-1, None))[0]:
                    contexts[f] = (d, c)
    assert set(images) == {0, 1} and all(images.values())
    for i, (_, r) in enumerate(results):
        deepest, ctx = contexts[i]
        assert deepest == (r.cut.n_levels + 1) * 1000  # the last context of the frame: every level shown
    counts = [v for _, cols in data["/counts/zcut"] for v in cols.get("frame", [])]
    assert sorted(counts) == [0, 1]


def test_the_config_document_says_how_to_scrub_the_zcuts(recording):
    _, data, _, _ = recording
    (text,) = [t for t in column(data["/config"], "TextDocument:text") if t]
    assert viz.TIMELINES_HINT in (text[0] if isinstance(text, list) else text)


def _view_names(container) -> list[str]:
    """Every view's name in a blueprint container, depth first."""
    import rerun.blueprint as rrb

    out: list[str] = []
    for c in container.contents:
        out += [c.name] if isinstance(c, rrb.View) else _view_names(c)
    return out


def test_the_explained_method_shows_its_surfaces_and_distances():
    """With ``explained`` run, the method tabs also show ``image/explained`` (each pixel's nearest known
    surface, the fallback's "local surface" included) and ``image/explained_distance``; without it, not."""
    from replay.pipeline.viz import default_blueprint

    with_it = _view_names(default_blueprint(("zcut", "sor", "explained")).root_container)
    assert {"Outliers: explained", "Explained: nearest surface", "Explained: distance (mm)"} <= set(with_it)
    without = _view_names(default_blueprint(("zcut", "sor", "radius")).root_container)
    assert "Outliers: radius" in without and not any(n.startswith("Explained") for n in without)
