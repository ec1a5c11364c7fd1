"""zcut.binmask's fast paths against the code they replaced (issue 32): bin_mask against
bin_mask_reference and bin_pixels against bin_pixels_reference, bit for bit, on hand-made synthetic
frames (several part kinds and seeds), a ray-traced frame, the real Kinect PCDs, frames with large
invalid regions and degenerate ones; the bounded distance transform on random footprints; the
registration's target preparation against its previous code."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from zcut.binmask import (
    BinMaskResult,
    _row_distances,
    bin_mask,
    bin_mask_reference,
    bin_pixels,
    bin_pixels_reference,
)
from zcut.params import BinMaskParams

REAL = Path("/work/shared/data/real")
if not REAL.is_dir():
    REAL = Path(__file__).resolve().parents[2] / "data" / "real"


def assert_same_mask(a: BinMaskResult, b: BinMaskResult) -> None:
    for name in BinMaskResult.__slots__:
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y), name
        else:
            assert repr(x) == repr(y), (name, x, y)


RING_CASES = ((0.2, 10.0), (0.05, 0.0), (0.5, 3.0), (1.0, 10.0), (0.01, 40.0))


def assert_same_pixels(result: BinMaskResult, xyz: np.ndarray) -> None:
    for frac, least in RING_CASES:
        got = bin_pixels(result, xyz, ring_frac=frac, min_ring_px=least)
        want = bin_pixels_reference(result, xyz, ring_frac=frac, min_ring_px=least)
        assert got.dtype == want.dtype and np.array_equal(got, want), (frac, least)


def check_frame(rgb: np.ndarray, xyz: np.ndarray, params: BinMaskParams = BinMaskParams()) -> BinMaskResult:
    fast = bin_mask(rgb, params=params)
    assert_same_mask(fast, bin_mask_reference(rgb, params=params))
    assert_same_pixels(fast, xyz)
    return fast


@pytest.mark.parametrize("kind, seed", [("zinc_nuts", 3), ("spheres", 7), ("rods", 11), ("black_nuts", 5)])
def test_hand_made_synthetic_frames(kind, seed):
    from replay.synth.synthesize import synthesize_frame

    for index, size in ((0, (300, 480)), (1, (480, 640))):
        f = synthesize_frame(kind=kind, seed=seed, index=index, size=size).frame
        r = check_frame(f.rgb, f.xyz)
        assert r.found
        for params in (BinMaskParams(dilate_px=0), BinMaskParams(prefer_centre=False), BinMaskParams(threshold=90.5)):
            check_frame(f.rgb, f.xyz, params)


def test_an_empty_bin_and_a_larger_frame():
    from replay.synth.synthesize import synthesize_frame

    f = synthesize_frame(empty=True, seed=4, index=2, size=(600, 960)).frame
    assert check_frame(f.rgb, f.xyz).found
    f = synthesize_frame(kind="zinc_nuts", seed=21, index=0, size=(600, 960)).frame
    check_frame(f.rgb, f.xyz)


def test_a_ray_traced_frame():
    from replay.synth.raytrace import synthesize_raytraced_frame

    f = synthesize_raytraced_frame(kind="spheres", seed=9502, index=0, size=(150, 240)).frame
    assert check_frame(f.rgb, f.xyz).found


@pytest.mark.parametrize("name", ["mosd_test16.pcd", "mosd_test44.pcd", "table_scene_mug_stereo_textured.pcd",
                                  "frame_20121214T142255.814212.pcd", "milk_cartoon_all_small_clorox.pcd"])
def test_real_kinect_clouds(name):
    from replay.logs.pcd import read_pcd

    path = REAL / name
    if not path.is_file():
        pytest.skip(f"{path} is not here")
    cloud = read_pcd(path)
    if cloud.rgb is None:
        pytest.skip(f"{name} has no colour")
    for threshold in (60.0, 120.0, 150.0, 200.0):
        check_frame(cloud.rgb, cloud.xyz, BinMaskParams(threshold=threshold, min_area_frac=0.001))


def test_large_invalid_regions_and_degenerate_clouds():
    from replay.synth.synthesize import synthesize_frame

    f = synthesize_frame(kind="spheres", seed=13, index=0, size=(300, 480)).frame
    r = check_frame(f.rgb, f.xyz)
    xyz = f.xyz.copy()
    xyz[:, :200] = np.nan                      # a third of the frame lost
    xyz[100:250, 250:] = np.inf
    xyz[::3, ::5, 1] = np.nan                  # one coordinate of a point
    assert_same_pixels(r, xyz)
    assert_same_pixels(r, np.full_like(f.xyz, np.nan))          # all invalid
    one = np.full_like(f.xyz, np.nan)
    one[150, 240] = 0.5
    assert_same_pixels(r, one)                                   # one valid pixel
    assert_same_pixels(r, f.xyz.astype(np.float64))
    assert_same_pixels(r, f.xyz[:, :, ::-1])                     # a strided view
    assert_same_pixels(r, f.xyz.astype(np.float16))              # a float type the fast path leaves to the oracle
    # masks not as bin_mask makes them (bytes, 0/2): the oracle's arithmetic
    import dataclasses

    odd = dataclasses.replace(r, mask=r.mask.astype(np.uint8) * 3, walls=r.walls.astype(np.uint8) * 2)
    assert_same_pixels(odd, f.xyz)


@pytest.mark.parametrize("shape", [(3, 3), (1, 1), (1, 7), (5, 1), (0, 4)])
def test_tiny_images(shape):
    rng = np.random.default_rng(sum(shape))
    for _ in range(10):
        rgb = (rng.random((*shape, 3)) * 255).astype(np.uint8)
        xyz = rng.random((*shape, 3)).astype(np.float32)
        for params in (BinMaskParams(min_area_frac=0.0), BinMaskParams(dilate_px=0, min_area_frac=0.0)):
            r = check_frame(rgb, xyz, params)
            if r.found:
                assert_same_pixels(r, np.full_like(xyz, np.nan))


def test_random_and_whole_images():
    rng = np.random.default_rng(1)
    for _ in range(40):
        h, w = (int(v) for v in rng.integers(5, 260, 2))
        rgb = (rng.random((h, w, 3)) * 255).astype(np.uint8)
        params = BinMaskParams(threshold=float(rng.integers(50, 250)), dilate_px=int(rng.integers(0, 4)),
                               min_area_frac=float(rng.choice([0.0, 0.001, 0.05])),
                               prefer_centre=bool(rng.integers(0, 2)))
        xyz = rng.random((h, w, 3)).astype(np.float32)
        xyz[rng.random((h, w)) < 0.3] = np.nan
        check_frame(rgb, xyz, params)
    # the whole image bright: the footprint is the image, no border to measure from
    whole = np.full((200, 300, 3), 230, np.uint8)
    r = check_frame(whole, np.ones((200, 300, 3), np.float32))
    assert r.mask.all() and bin_pixels(r, np.ones((200, 300, 3), np.float32)).all()
    # two components of equal area: the tie goes the same way
    twin = np.zeros((100, 200, 3), np.uint8)
    twin[20:40, 20:60] = 230
    twin[60:80, 120:160] = 230
    for centre in (True, False):
        check_frame(twin, np.ones((100, 200, 3), np.float32), BinMaskParams(dilate_px=1, prefer_centre=centre))


def test_the_components_without_statistics_are_labelled_the_same():
    rng = np.random.default_rng(2)
    for _ in range(20):
        h, w = (int(v) for v in rng.integers(20, 400, 2))
        img = (rng.random((h, w)) < rng.random()).astype(np.uint8)
        n1, lab1 = cv2.connectedComponents(img, connectivity=8, ltype=cv2.CV_32S)
        n2, lab2, _, _ = cv2.connectedComponentsWithStats(img, connectivity=8, ltype=cv2.CV_32S)
        assert n1 == n2 and np.array_equal(lab1, lab2)


def _footprints(rng: np.random.Generator):
    """Footprints a bin can have, and worse: rectangles, tilted and rounded ones, with notches,
    holes and islands, cut by the image's edges, portrait and landscape, up to 1447 px wide."""
    for h, w in ((200, 300), (300, 200), (150, 1447), (1200, 1400), (700, 900), (128, 128), (400, 1000)):
        yy, xx = np.mgrid[0:h, 0:w]
        for k in range(4):
            if k == 0:
                m = (yy > h * 0.1) & (yy < h * 0.9) & (xx > w * 0.05) & (xx < w * 0.97)
            elif k == 1:   # a tilted ellipse
                a = np.radians(rng.uniform(0, 180))
                u = (xx - w / 2) * np.cos(a) + (yy - h / 2) * np.sin(a)
                v = -(xx - w / 2) * np.sin(a) + (yy - h / 2) * np.cos(a)
                m = (u / (0.45 * w)) ** 2 + (v / (0.4 * h)) ** 2 < 1
            elif k == 2:   # cut by the top and left edges, notched
                m = (yy < h * 0.8) & (xx < w * 0.7)
                m[int(h * 0.3):int(h * 0.35), int(w * 0.5):] = False
            else:          # random blobs
                m = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 6) > 0.5
            m = m.copy()
            holes = rng.random((h, w)) < 0.0005
            m[holes] = False
            yield m


def _footprint_cases(rng: np.random.Generator):
    """Each footprint of :func:`_footprints` (the empty ones left out) as ``bin_mask`` would report it, its
    walls 70 % of its pixels, and a cloud of ones with 5 % NaN: ``(result, xyz)``."""
    for m in _footprints(rng):
        if not m.any():
            continue
        rows, cols = np.nonzero(m)
        bbox = (int(rows.min()), int(cols.min()), int(rows.max()) + 1, int(cols.max()) + 1)
        walls = m & (rng.random(m.shape) < 0.7)
        r = BinMaskResult(m, walls, True, int(m.sum()), 1, (rows.mean(), cols.mean()), bbox, True)
        xyz = np.ones((*m.shape, 3), np.float32)
        xyz[rng.random(m.shape) < 0.05] = np.nan
        yield r, xyz


def test_the_bounded_distance_transform_on_random_footprints(opencv_threads):
    rng = np.random.default_rng({"default": 3, "one": 7}[opencv_threads])
    n = 0
    for r, xyz in _footprint_cases(rng):
        for frac, least in ((0.2, 10.0), (0.07, 0.0), (0.6, 1.0), (1.0, 0.0), (0.01, 10.0)):
            got = bin_pixels(r, xyz, ring_frac=frac, min_ring_px=least)
            want = bin_pixels_reference(r, xyz, ring_frac=frac, min_ring_px=least)
            assert np.array_equal(got, want), (r.mask.shape, frac)
        n += 1
    assert n >= 25


def test_the_row_pass_is_opencvs():
    rng = np.random.default_rng(4)
    for h, w in ((300, 500), (1000, 1447), (257, 64)):
        fp = (cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 4) > 0.45).astype(np.uint8)
        fp[rng.random((h, w)) < 0.001] = 0
        want = cv2.distanceTransform(fp, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        col = np.full((h, w), np.inf)
        for c in range(w):  # squared distance to the nearest zero of the column
            zeros = np.flatnonzero(fp[:, c] == 0)
            if len(zeros):
                col[:, c] = (np.abs(np.arange(h)[:, None] - zeros[None]).min(axis=1)) ** 2
        sqr = (np.arange(w) ** 2).astype(np.float32)
        inv = np.zeros(w, np.float32)
        inv[1:] = (0.5 / np.arange(1, w)).astype(np.float32)
        out = np.empty(w, np.float32)
        for r in range(0, h, 7):
            f = np.where(np.isfinite(col[r]), col[r], 1e15).astype(np.float32)
            best = _row_distances(f, sqr, inv, out)
            assert out.tobytes() == want[r].tobytes() and best == want[r].max()


def test_the_target_is_prepared_as_before():
    from scipy.spatial import cKDTree

    from zcut.registration import prepare_target

    rng = np.random.default_rng(5)
    pts = rng.normal(0.0, 0.1, (5000, 3)) + (0, 0, 0.8)
    for p in (pts, pts.astype(np.float32), np.where(rng.random((5000, 1)) < 0.1, np.nan, pts)):
        t = prepare_target(p, voxel_m=0.003)
        a = np.asarray(p)
        old = np.ascontiguousarray(a[np.isfinite(a).all(axis=1)], dtype=np.float64)
        assert t.points.dtype == np.float64 and t.points.flags.c_contiguous
        assert t.points.tobytes() == old.tobytes() and t.points is not p
        q = rng.normal(0.0, 0.1, (300, 3)) + (0, 0, 0.8)
        d_new, _ = t.tree.query(q, k=1, distance_upper_bound=0.01)
        d_old, _ = cKDTree(np.asarray(t.cloud.points)).query(q, k=1, distance_upper_bound=0.01)
        assert d_new.tobytes() == d_old.tobytes()


@pytest.fixture
def one_opencv_thread():
    """OpenCV on one thread, as on a one-core machine: its precise distance transform is Intel IPP's there,
    within a float32 ulp or two of the exact one, not the exact one."""
    n = cv2.getNumThreads()
    cv2.setNumThreads(1)
    yield
    cv2.setNumThreads(n)


def _exact_distances(fp: np.ndarray) -> np.ndarray:
    """float32 square roots of the exact squared distances to the nearest zero (scipy's EDT)."""
    from scipy import ndimage

    e2 = np.rint(ndimage.distance_transform_edt(fp) ** 2).astype(np.int64)
    return np.sqrt(e2.astype(np.float32))


def test_one_opencv_thread_ipps_distances_are_within_the_bound(one_opencv_thread):
    from zcut.binmask import _IPP_REL_ERROR

    rng = np.random.default_rng(6)
    worst = 0.0
    n = 0
    for m in _footprints(rng):
        fp = np.pad(m.astype(np.uint8), 1)[:m.shape[0] + 1, :m.shape[1] + 1]
        if fp.all() or not fp.any():
            continue
        got = cv2.distanceTransform(fp, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        exact = _exact_distances(fp)
        rel = np.abs(got.astype(np.float64) - exact) / np.maximum(exact, 1.0)
        worst = max(worst, float(rel.max()))
        n += 1
    assert n >= 25
    # bin_pixels relies on this bound (with a margin of 4 x what was measured on the replay's frames)
    assert worst <= _IPP_REL_ERROR / 4, worst


@pytest.mark.parametrize("kind, seed, size", [("zinc_nuts", 12, (480, 640)), ("spheres", 31, (800, 1280)),
                                              ("black_nuts", 17, (300, 480))])
def test_one_opencv_thread_synthetic_frames(one_opencv_thread, kind, seed, size):
    from replay.synth.synthesize import synthesize_frame

    f = synthesize_frame(kind=kind, seed=seed, index=1, size=size).frame
    r = bin_mask(f.rgb)
    assert r.found
    assert_same_pixels(r, f.xyz)
    xyz = f.xyz.copy()
    xyz[:, : size[1] // 3] = np.nan  # a large invalid region
    assert_same_pixels(r, xyz)


def test_one_opencv_thread_a_pixel_at_the_threshold_is_left_to_opencv(one_opencv_thread):
    """A bright pixel exactly 10 px from the border with min_ring_px = 10: IPP may put it at 10 plus or
    minus an ulp, so the bounds do not decide it and OpenCV's transform does."""
    from zcut.binmask import _column_distances, _largest_distance, _near_bounds, _ring_bounded

    h, w = 300, 400
    m = np.zeros((h, w), bool)
    m[40:260, 50:350] = True
    r = BinMaskResult(m, m.copy(), True, int(m.sum()), 1, (150.0, 200.0), (40, 50, 260, 350), True)
    xyz = np.ones((h, w, 3), np.float32)
    fp = np.ascontiguousarray(m[39:261, 49:351], dtype=np.uint8)
    g, row_max = _column_distances(fp)
    largest = _largest_distance(g, row_max, np.argsort(-row_max, kind="stable"))
    vin, vout = _near_bounds(largest, 0.01, 10.0)
    assert vin < 100 <= vout
    out = np.zeros((h, w), np.uint8)
    assert _ring_bounded(g, vin, vout, m.view(np.uint8), xyz, 39, 49, out) == 1
    for frac, least in ((0.01, 10.0), (0.2, 10.0)):
        want = bin_pixels_reference(r, xyz, ring_frac=frac, min_ring_px=least)
        assert np.array_equal(bin_pixels(r, xyz, ring_frac=frac, min_ring_px=least), want)


def test_the_component_is_filled_as_fill_holes_fills_it():
    """``_fill_component`` (the comparison written straight into the padded image) against
    ``fill_holes(labels[box] == chosen)``: random labels, boxes at the image's edges, one pixel, one row,
    one column, a label absent from the box, rings with holes."""
    from zcut.binmask import _fill_component, fill_holes

    rng = np.random.default_rng(11)
    n = 0
    for h, w in ((1, 1), (1, 9), (9, 1), (7, 13), (40, 60), (97, 131)):
        for k in (2, 3, 6):
            labels = rng.integers(0, k, (h, w)).astype(np.int32)
            if h > 6 and w > 6:  # a ring of label 1 around holes of other labels
                labels[1:-1, 1] = labels[1:-1, -2] = labels[1, 1:-1] = labels[-2, 1:-1] = 1
            for _ in range(6):
                y, x = int(rng.integers(0, h)), int(rng.integers(0, w))
                bh, bw = int(rng.integers(1, h - y + 1)), int(rng.integers(1, w - x + 1))
                for chosen in (0, 1, k):  # k: absent
                    got = _fill_component(labels, (x, y, bw, bh), chosen)
                    want = fill_holes(labels[y:y + bh, x:x + bw] == chosen)
                    assert got.dtype == want.dtype and np.array_equal(got, want), (h, w, x, y, bw, bh, chosen)
                    n += 1
            got = _fill_component(labels, (0, 0, w, h), 1)
            assert np.array_equal(got, fill_holes(labels == 1))
    assert n > 300
