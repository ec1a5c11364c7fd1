"""annotate.payload: the page's per-frame data (bundle layout, candidate clusters, images)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from annotate_helpers import pipeline_result, review_frame, spike_frame

from annotate.payload import (
    CANDIDATE_COLUMNS,
    COLUMN,
    FILL_MIN_PX,
    INVALID_GRAY,
    SOR_DEFAULT_MIN_PX,
    SOURCE_SOR,
    SOURCE_ZCUT,
    UNMEASURED_SHADE,
    bundle_with_blobs,
    candidate_clusters,
    candidate_table,
    height_colormap,
    height_limits,
    make_bundle,
    make_geometry,
    make_view,
    mask_kind,
    mask_runs,
    parse_bundle,
    parse_geometry,
    parse_view,
    prepare_frame,
    rgb_picture,
    runs_to_mask,
    turbo_lut,
)
from annotate.store import pack_mask


@pytest.mark.parametrize("n_ids", [3, 300, 70_000])
def test_bundle_roundtrip(rng, n_ids):
    shape = (301, 257)  # pixel count not a multiple of 8
    mask = rng.random(shape) < 0.3
    ids = rng.integers(0, n_ids, shape).astype(np.uint8 if n_ids < 256 else np.uint16 if n_ids < 65536 else np.uint32)
    ids[rng.random(shape) < 0.9] = 0
    data = make_bundle({"height": shape[0], "width": shape[1], "x": 1},
                       [("m", "bits", mask), ("ids", "ids", ids), ("sp", "sparse", ids)])
    raw = make_bundle({"height": shape[0], "width": shape[1]},
                      [("m", "bits", mask), ("ids", "ids", ids), ("sp", "sparse", ids)], compress=False)
    assert all(s["zlib"] is False for s in parse_bundle(raw)[0]["sections"])
    assert all(np.array_equal(a, b) for a, b in zip(parse_bundle(raw)[1].values(), parse_bundle(data)[1].values()))
    header, arrays = parse_bundle(data)
    assert header["x"] == 1 and [s["name"] for s in header["sections"]] == ["m", "ids", "sp"]
    assert header["sections"][2]["count"] == int((ids > 0).sum())
    assert np.array_equal(arrays["m"], mask) and np.array_equal(arrays["ids"], ids)
    assert np.array_equal(arrays["sp"], ids) and arrays["sp"].dtype == ids.dtype
    assert arrays["ids"].dtype == ids.dtype
    empty = parse_bundle(make_bundle({"height": 2, "width": 3}, [("sp", "sparse", np.zeros((2, 3), np.uint8))]))
    assert not empty[1]["sp"].any() and empty[0]["sections"][0]["count"] == 0
    blob = bundle_with_blobs({"height": shape[0], "width": shape[1]}, [("m", pack_mask(mask))])
    assert np.array_equal(parse_bundle(blob)[1]["m"], mask)


@pytest.mark.parametrize("case", ["blob", "starts_true", "all_false", "all_true", "noise"])
def test_runs_roundtrip_and_choice(rng, case):
    shape = (301, 257)
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    mask = {"blob": (yy - 150) ** 2 + (xx - 120) ** 2 < 90 ** 2, "starts_true": (xx < 40) | (yy > 250),
            "all_false": np.zeros(shape, bool), "all_true": np.ones(shape, bool),
            "noise": rng.random(shape) < 0.5}[case]
    runs = mask_runs(mask)
    assert runs.sum() == mask.size and (runs[1:] > 0).all()
    assert (runs[0] == 0) == bool(mask.flat[0])
    data = make_bundle({"height": shape[0], "width": shape[1]}, [("m", "runs", mask)])
    assert np.array_equal(parse_bundle(data)[1]["m"], mask)
    # runs for smooth masks (few runs), packed bits for noise
    assert mask_kind(mask) == ("bits" if case == "noise" else "runs")
    assert np.array_equal(parse_bundle(make_bundle({"height": shape[0], "width": shape[1]},
                                                   [("m", mask_kind(mask), mask)]))[1]["m"], mask)


def test_view_roundtrip():
    parts = [("bundle", b"\x00\x01abc"), ("label", b""), ("image", bytes(range(256)) * 3)]
    assert parse_view(make_view(parts)) == dict(parts)


def test_candidate_clusters():
    z = np.zeros((6, 8), bool)
    cut = np.zeros((6, 8), np.int32)
    z[0, 0:2] = True
    cut[0, 0:2] = 7          # a z-cut cluster with id 7
    cut[5, 5] = 9            # a cluster without outliers: dropped
    z[3, 6] = z[4, 7] = True  # z-cut outliers outside any cluster (above the rim): 8-connected -> one
    s = np.zeros((6, 8), bool)
    s[2, 2] = s[3, 3] = True   # diagonal: one SOR cluster
    s[5, 0] = True
    zi, nz, si, ns = candidate_clusters(z, cut, s)
    assert nz == 2 and ns == 2
    assert zi.dtype == np.uint8 and set(np.unique(zi)) == {0, 1, 2}
    assert zi[0, 0] == zi[0, 1] == 1 and zi[3, 6] == zi[4, 7] == 2 and zi[5, 5] == 0
    assert si[2, 2] == si[3, 3] != si[5, 0]
    assert np.array_equal(zi > 0, z) and np.array_equal(si > 0, s)


def test_height_colormap_marks_invalid_grey():
    fr, _ = spike_frame(0, shape=(30, 40))
    valid = np.isfinite(fr.xyz).all(axis=2)
    bgr = height_colormap(fr.xyz, valid)
    assert bgr.shape == (30, 40, 3) and bgr.dtype == np.uint8
    assert (bgr[~valid] == INVALID_GRAY).all()
    nothing = np.full((4, 5, 3), np.nan, np.float32)
    assert (height_colormap(nothing, np.zeros((4, 5), bool)) == INVALID_GRAY).all()


def test_rgb_picture_greys_a_fill_colour_not_a_picture(rng):
    """A cloud file's one fill colour on its unmeasured pixels (a stereo cloud's dark red) is no picture:
    the page's RGB image shows them grey, as the height map does; the camera's colours there are shaded
    toward that grey (recognisable, and not read as measured)."""
    h, w = 40, 50
    rgb = rng.integers(0, 256, (h, w, 3)).astype(np.uint8)
    valid = rng.random((h, w)) > 0.3
    shaded = rgb_picture(rgb, valid)  # the camera's colours where the depth sensor missed: shaded toward grey
    assert shaded is not rgb and np.array_equal(shaded[valid], rgb[valid])
    want = np.round(UNMEASURED_SHADE * rgb[~valid].astype(np.float64) + (1 - UNMEASURED_SHADE) * INVALID_GRAY)
    assert np.array_equal(shaded[~valid], want.astype(np.uint8))
    assert rgb_picture(rgb, np.ones((h, w), bool)) is rgb  # all measured: the picture as it is
    filled = rgb.copy()
    filled[~valid] = (192, 0, 0)
    out = rgb_picture(filled, valid)
    assert (out[~valid] == INVALID_GRAY).all() and np.array_equal(out[valid], rgb[valid])
    assert (filled[~valid] == (192, 0, 0)).all()  # the frame's own image is left alone
    few = np.ones((h, w), bool)
    few.ravel()[:FILL_MIN_PX - 1] = False  # too few to call one colour a fill
    few_out = rgb_picture(filled, few)  # too few to call one colour a fill: shaded like a picture
    assert np.array_equal(few_out[~few], np.round(UNMEASURED_SHADE * filled[~few].astype(np.float64)
                                                  + (1 - UNMEASURED_SHADE) * INVALID_GRAY).astype(np.uint8))
    assert rgb_picture(filled, np.ones((h, w), bool)) is filled  # nothing unmeasured
    assert rgb_picture(filled, np.zeros((h + 1, w), bool)) is filled  # an image of another size
    # through prepare_frame: the JPEG the page shows
    fr, _ = spike_frame(0, shape=(60, 80))
    fr.xyz[20:40, 20:60] = np.nan  # a region the sensor missed (JPEG blurs lone pixels into their neighbours)
    fr.rgb[~np.isfinite(fr.xyz).all(axis=2)] = (192, 0, 0)
    pf = prepare_frame(fr, pipeline_result(fr))
    img = cv2.imdecode(np.frombuffer(pf.served.rgb_jpeg, np.uint8), cv2.IMREAD_COLOR)[..., ::-1].astype(int)
    inner = img[24:36, 24:56]
    assert np.abs(inner - INVALID_GRAY).max() < 12  # grey, not the fill's red


@pytest.mark.parametrize("rows", [0, 1, 5])
def test_table_roundtrip(rng, rows):
    t = rng.normal(size=(rows, len(CANDIDATE_COLUMNS))).astype(np.float32)
    for compress in (True, False):
        back = parse_bundle(make_bundle({"height": 2, "width": 2}, [("candidates", "table", t)], compress=compress))
        assert back[1]["candidates"].shape == t.shape and np.array_equal(back[1]["candidates"], t)


def test_runs_to_mask_refuses_what_does_not_fit():
    assert np.array_equal(runs_to_mask(np.array([2, 3, 1]), (2, 3)), [[False, False, True], [True, True, False]])
    with pytest.raises(ValueError, match="cover 5 pixels, the frame has 6"):
        runs_to_mask(np.array([2, 3]), (2, 3))
    with pytest.raises(ValueError, match="non-negative"):
        runs_to_mask(np.array([7, -1]), (2, 3))


def test_geometry_roundtrip(rng):
    pts = rng.normal(size=(5, 7, 3)).astype(np.float32)
    pts[1, 2] = np.nan
    header, back = parse_geometry(make_geometry(pts, x0=30, y0=40))
    assert (header["x0"], header["y0"], header["width"], header["height"]) == (30, 40, 7, 5)
    assert header["channels"] == ["x_m", "y_m", "z_m"]
    assert np.array_equal(back, pts, equal_nan=True)


def test_candidate_table_by_hand():
    """Two floating squares on a floor (heights in mm), one flagged by the z-cut, one by SOR."""
    h = np.full((12, 14), 100.0)
    valid = np.ones_like(h, bool)
    h[2:4, 2:4] = 103.5          # 3.5 mm above the floor
    h[1, 1] = 101.0              # a higher point next to it: the surface below is at 101
    h[8:10, 9:12] = 99.0         # a hollow: "gap" below zero
    valid[0, :] = False
    h[0, :] = np.nan
    z = np.zeros(h.shape, bool)
    z[2:4, 2:4] = True
    s = np.zeros(h.shape, bool)
    s[8:10, 9:12] = True
    s[3, 3] = True               # SOR agrees on one pixel of the z-cut cluster...
    s[11, 0] = True              # ...and flags a single pixel (not listed: below SOR_LIST_MIN_PX)
    zi, nz, si, ns = candidate_clusters(z, None, s)
    table = candidate_table(zi, nz, si, ns, heights=h, valid=valid, z_levels=np.array([7]))
    assert table.shape == (2, len(CANDIDATE_COLUMNS)) and table.dtype == np.float32
    row = dict(zip(CANDIDATE_COLUMNS, table[0]))
    assert row["source"] == SOURCE_ZCUT and row["n"] == 4 and row["level"] == 7
    assert (row["x0"], row["y0"], row["x1"], row["y1"], row["cx"], row["cy"]) == (2, 2, 4, 4, 3, 3)
    assert (row["h_min_mm"], row["h_max_mm"], row["below_mm"]) == (103.5, 103.5, 101.0)
    assert row["gap_mm"] == pytest.approx(2.5) and row["both"] == 1
    row = dict(zip(CANDIDATE_COLUMNS, table[1]))
    assert row["source"] == SOURCE_SOR and row["n"] == 6 and row["both"] == 0 and row["level"] == -1
    assert row["below_mm"] == 100.0 and row["gap_mm"] == pytest.approx(-1.0)


def test_height_limits_and_lut():
    h = np.arange(100.0).reshape(10, 10)
    valid = np.ones((10, 10), bool)
    assert height_limits(h, valid) == pytest.approx((0.99, 98.01))
    assert height_limits(h, ~valid) == (0.0, 1.0)
    lut = turbo_lut()
    assert len(lut) == 256 and all(len(c) == 3 for c in lut)
    # the legend's colours are the map's colours: a pixel at the top of the range has the last colour
    xyz = np.zeros((1, 2, 3), np.float32)
    xyz[0, :, 2] = [-0.001, -0.002]  # heights 1 and 2 mm
    bgr = height_colormap(xyz, np.ones((1, 2), bool), limits=(1.0, 2.0))
    assert bgr[0, 1, ::-1].tolist() == lut[255] and bgr[0, 0, ::-1].tolist() == lut[0]


def test_prepare_frame_review_scene():
    """The 13 small floating clusters of the review scene are the z-cut's candidates, with the gap
    to the surface below as built (4..16 mm), and the counts the frame list shows."""
    fr, truth = review_frame(0, shape=(300, 480))
    res = pipeline_result(fr)
    pf = prepare_frame(fr, res)
    sf = pf.served
    header, arrays = parse_bundle(sf.bundle)
    t = arrays["candidates"]
    z = t[t[:, COLUMN["source"]] == SOURCE_ZCUT]
    assert np.array_equal(arrays["zcut"] > 0, truth) and len(z) == 13 == header["n_zcut"]
    assert (z[:, COLUMN["n"]] <= 20).all() and (z[:, COLUMN["gap_mm"]] > 3.5).all()
    # each was built 4 + k mm above the highest point within 3 px (the gap's ring is 2 px: not lower)
    gaps = np.sort(z[:, COLUMN["gap_mm"]])
    assert (gaps >= np.arange(4, 17) - 0.1).all() and (gaps <= np.arange(4, 17) + 1).all()
    assert header["candidate_columns"] == list(CANDIDATE_COLUMNS)
    assert header["height_lo_mm"] < header["height_hi_mm"]
    assert np.array_equal(pf.geometry, fr.xyz, equal_nan=True) and "zone" not in arrays  # no bin stages
    sor = t[t[:, COLUMN["source"]] == SOURCE_SOR]
    assert sf.n_sor_listed == int((sor[:, COLUMN["n"]] >= SOR_DEFAULT_MIN_PX).sum())
    counted = np.concatenate([z, sor[sor[:, COLUMN["n"]] >= SOR_DEFAULT_MIN_PX]])
    assert sf.disagreement == int((2 * counted[:, COLUMN["both"]] < counted[:, COLUMN["n"]]).sum())
    # decisions count the review groups (the list's rows): accepting the 13 clusters decides the groups
    # whose pixels are at least half theirs; the whole frame reviewed decides every group
    L = truth.copy()
    gids = arrays["groups"].astype(np.int64)
    size = np.bincount(gids.ravel(), minlength=sf.n_groups + 1)[1:]
    in_truth = np.bincount(gids.ravel(), weights=truth.ravel(), minlength=sf.n_groups + 1)[1:]
    decided, accepted = sf.decisions(L, L)
    assert decided == accepted == int((2 * in_truth >= size).sum()) >= 1
    assert sf.decisions(L & False, arrays["valid"]) == (sf.n_groups, 0) and sf.n_groups == header["n_groups"]


def test_prepare_frame():
    fr, _ = spike_frame(1, shape=(48, 64))
    valid = np.isfinite(fr.xyz).all(axis=2)
    res = pipeline_result(fr)
    pf = prepare_frame(fr, res)
    header, arrays = parse_bundle(pf.served.bundle)
    assert (header["height"], header["width"], header["index"], header["stamp_ns"]) == (48, 64, 1, fr.stamp_ns)
    assert np.array_equal(arrays["valid"], valid) and header["n_valid"] == int(valid.sum())
    assert np.array_equal(arrays["zcut"] > 0, res.zcut_outliers & valid) and header["n_zcut"] == pf.served.n_zcut
    assert np.array_equal(arrays["sor"] > 0, res.sor_outliers & valid)
    for jpeg in (pf.served.rgb_jpeg, pf.served.height_jpeg):
        img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
        assert img.shape == (48, 64, 3)
    no_rgb = type(fr)(**{**{k: getattr(fr, k) for k in fr.__slots__}, "rgb": None})
    pf2 = prepare_frame(no_rgb, pipeline_result(no_rgb))
    assert pf2.served.rgb_jpeg is None and parse_bundle(pf2.served.bundle)[0]["has_rgb"] is False


def test_the_served_zone_holds_the_points_above_the_rim():
    """Issue 29 item 5 / docs/accuracy.md: the zone is the pixels the filters judge plus the above-the-rim
    points (the removal's own zone leaves them out: it served a zone without them)."""
    fr, _ = review_frame(0, shape=(120, 160))
    res = pipeline_result(fr)
    valid = np.asarray(res.valid, bool)
    judged = valid.copy()
    judged[:, :40] = False  # the bin and the table, say
    easy = np.zeros_like(valid)
    easy[:5, :20] = True  # above the rim

    class WithBin:  # the same result as the bin stages would leave it
        def __getattr__(self, name):
            return {"zone": judged, "easy_outliers": easy}.get(name, getattr(res, name))

    _, arrays = parse_bundle(prepare_frame(fr, WithBin()).served.bundle)
    zone = arrays["zone"].astype(bool)
    assert np.array_equal(zone, (judged | easy) & valid) and (zone & easy).sum() == (easy & valid).sum() > 0
