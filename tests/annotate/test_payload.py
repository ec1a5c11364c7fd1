"""annotate.payload: the page's per-frame data (bundle layout, candidate clusters, images)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from annotate_helpers import spike_frame

from annotate.payload import (
    INVALID_GRAY,
    bundle_with_blobs,
    candidate_clusters,
    height_colormap,
    make_bundle,
    make_view,
    mask_kind,
    mask_runs,
    parse_bundle,
    parse_view,
    prepare_frame,
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


def test_prepare_frame():
    fr, truth = spike_frame(1, shape=(48, 64))
    valid = np.isfinite(fr.xyz).all(axis=2)
    pf = prepare_frame(fr, zcut_outliers=truth, sor_outliers=truth & False, cut_clusters=None)
    header, arrays = parse_bundle(pf.bundle)
    assert (header["height"], header["width"], header["index"], header["stamp_ns"]) == (48, 64, 1, fr.stamp_ns)
    assert np.array_equal(arrays["valid"], valid)
    assert np.array_equal(arrays["zcut"] > 0, truth & valid) and header["n_zcut"] == pf.n_zcut == 4
    assert header["n_sor"] == 0 and not arrays["sor"].any()
    for jpeg in (pf.rgb_jpeg, pf.height_jpeg):
        img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
        assert img.shape == (48, 64, 3)
    no_rgb = prepare_frame(type(fr)(**{**{k: getattr(fr, k) for k in fr.__slots__}, "rgb": None}),
                           zcut_outliers=truth, sor_outliers=truth, cut_clusters=None)
    assert no_rgb.rgb_jpeg is None and parse_bundle(no_rgb.bundle)[0]["has_rgb"] is False
