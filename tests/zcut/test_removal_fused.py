"""The fast removal's classes, masks and heights in one pass (``zcut.removal._classify_finish``), the straggler
test's bin pixels moved out of the zone after it (``zcut.removal._relabel_bin``), and the zone's top it hands the
bin check: the same bits as the reference (``reference=True``) and as the bin check's own scan of the zone.

Inputs: hand-made synthetic logs of several part kinds (piles on the floor and against the walls), a small
ray-traced frame, the straggler settings that label the most pixels, frames with large invalid regions,
degenerate ones, and a bin seen from the side (the floor not a plane: the two-pass path).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from removal_inputs import located_frames

from replay.synth.log import write_synthetic_log
from replay.synth.raytrace import write_raytraced_log
from zcut.bin_check import _zone_top, check_bin_removal
from zcut.removal import _relabel_bin, prepare_removal_index, remove_table_and_bin

SIZE = (150, 200)
FIELDS = ("table", "easy_outliers", "bin_points", "zone", "height_mm", "xyz", "rim_m", "floor_m", "tolerance_mm",
          "residual_mm", "radius_mm", "up_cam")
#: the settings whose straggler test labels many pixels (wide reach, few labelled neighbours needed)
PARAMS = {
    "default": {},
    "many-stragglers": {"straggler_mm": 4.0, "straggler_neighbours": 2},
    "deep-band": {"straggler_bound": "below_rim", "rim_offset_mm": 40.0},
    "no-stragglers": {"straggler_mm": 0.0},
    "paper": {"mode": "paper", "straggler_mm": 2.0, "straggler_neighbours": 3},
}


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("removal_fused")
    made = {}
    for kind, seed, pile in (("zinc_nuts", 31, "floor"), ("sprockets", 37, "floor"), ("spheres", 41, "walls")):
        made[f"{kind}-{seed}"] = located_frames(write_synthetic_log(d / f"{kind}.mcap", kind=kind, frames=2,
                                                                    seed=seed, size=SIZE, pile=pile))
    made["raytraced"] = located_frames(write_raytraced_log(d / "rt.mcap", kind="zinc_nuts", frames=1, seed=43,
                                                           size=(120, 160)))
    return made


def _same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def _check(xyz, fp, index, T, ring, config, what):
    fast = remove_table_and_bin(xyz, fp, index=index, T_cam_bin=T, ring=ring)
    ref = remove_table_and_bin(xyz, fp, index=index, T_cam_bin=T, ring=ring, reference=True)
    for f in FIELDS:
        assert _same(getattr(fast, f), getattr(ref, f)), f"{what}: {f}"
    # the zone's top handed to the bin check is the one its own scan of these arrays finds
    assert fast.zone_top is not None
    seen, top = _zone_top(fast.zone, fast.height_mm)
    assert (fast.zone_top.seen, np.float64(fast.zone_top.top).tobytes()) == (seen, np.float64(top).tobytes()), what
    # and the check reads the same verdict from it as from a result that does not carry it
    bare = dataclasses.replace(fast, zone_top=None)
    kw = {"params": index.params, "band_mm": config.zcut.max_depth, "xyz": xyz, "index": index, "T_cam_bin": T}
    a, b = check_bin_removal(fast, ring, **kw), check_bin_removal(bare, ring, **kw)
    assert (a.value, a.flagged, a.reason) == (b.value, b.flagged, b.reason), what
    return fast


@pytest.mark.parametrize("name", list(PARAMS))
def test_one_pass_equals_the_reference(logs, name):
    labelled = 0
    for log, (model, config, frames) in logs.items():
        index = prepare_removal_index(model, dataclasses.replace(config.removal, **PARAMS[name]))
        for i, (xyz, fp, ring, T) in enumerate(frames):
            fast = _check(xyz, fp, index, T, ring, config, f"{log} frame {i} {name}")
            labelled += int(fast.bin_points.sum())
    assert labelled > 0


def test_one_pass_with_holes_and_degenerate_frames(logs):
    model, config, frames = logs["zinc_nuts-31"]
    xyz, fp, ring, T = frames[0]
    rng = np.random.default_rng(47)
    for name in ("default", "many-stragglers"):
        index = prepare_removal_index(model, dataclasses.replace(config.removal, **PARAMS[name]))
        cases = {}
        a = xyz.copy()
        a[:, : a.shape[1] // 2] = np.nan
        cases["left half"] = (a, fp, ring)
        a = xyz.copy()
        a[rng.random(a.shape[:2]) < 0.4] = np.nan
        a[rng.random(a.shape[:2]) < 0.02, 0] = np.inf
        cases["speckle"] = (a, fp, ring)
        cases["all NaN"] = (np.full_like(xyz, np.nan), fp, ring)
        r, c = np.argwhere(ring)[len(np.argwhere(ring)) // 2]
        one = np.full_like(xyz, np.nan)
        one[r, c] = xyz[r, c]
        cases["one pixel"] = (one, fp, ring)
        cases["3 x 3"] = (np.ascontiguousarray(xyz[r - 1:r + 2, c - 1:c + 2]), np.ones((3, 3), bool),
                          np.ones((3, 3), bool))
        cases["one row"] = (np.ascontiguousarray(xyz[r:r + 1]), np.ascontiguousarray(fp[r:r + 1]),
                            np.ascontiguousarray(ring[r:r + 1]))
        cases["no footprint"] = (xyz, np.zeros_like(fp), np.zeros_like(ring))
        for what, (a, f, g) in cases.items():
            with np.errstate(invalid="ignore"):
                _check(a, f, index, T, g, config, f"{what} {name}")


def test_a_bin_seen_from_the_side_takes_the_two_passes(logs):
    """The frame and the pose turned so that the bin's up is the camera's x axis: it lies across the view, the
    floor is the farthest point (known only after the classes), and the fast path still equals the reference."""
    model, config, frames = logs["sprockets-37"]
    xyz, fp, ring, T = frames[0]
    up = T[:3, :3] @ np.array([0.0, 0.0, -1.0])
    across = np.cross(up, [1.0, 0.0, 0.0])
    across /= np.linalg.norm(across)
    Q = np.eye(4)
    Q[:3, :3] = [up, np.cross(across, up), across]  # a rotation taking up to the camera's x axis
    turned = np.ascontiguousarray((xyz.astype(np.float64) @ Q[:3, :3].T).astype(xyz.dtype))
    T2 = Q @ T
    assert abs((T2[:3, :3] @ np.array([0.0, 0.0, -1.0]))[2]) <= 1e-6
    for name in ("default", "many-stragglers"):
        index = prepare_removal_index(model, dataclasses.replace(config.removal, **PARAMS[name]))
        _check(turned, fp, index, T2, ring, config, f"side {name}")


def _rows_literal(zone, height):
    """``(seen, nan, top)`` per row as ``zcut.removal._finish_codes`` scans them."""
    H = zone.shape[0]
    seen, nan, top = np.zeros(H, bool), np.zeros(H, bool), np.full(H, -np.inf)
    for r in range(H):
        v = height[r][zone[r]]
        seen[r] = v.size > 0
        nan[r] = bool(np.isnan(v).any())
        m = -np.inf
        for x in v:  # the first of equal maxima, as the kernel keeps it
            if not np.isnan(x) and x > m:
                m = x
        top[r] = m
    return seen, nan, top


@pytest.mark.parametrize("seed", range(40))
def test_relabel_bin_rescans_the_rows_that_lost_their_top(seed):
    """Random zones and heights with ties, ±0, NaN; the relabelled pixels drawn from the zone with a bias to the
    rows' tops (every top in some cases, every zone pixel of a row in others): the masks, heights and each row's
    ``(seen, nan, top)`` as a scan of the final arrays gives them."""
    rng = np.random.default_rng(seed)
    H, W = int(rng.integers(1, 12)), int(rng.integers(1, 30))
    a = rng.normal(0.0, 0.3, (H, W, 3)).astype(np.float32)
    a[..., 2] = np.abs(a[..., 2]) + 0.5
    zone = rng.random((H, W)) < rng.uniform(0.1, 1.0)
    height = np.where(zone, np.round(rng.normal(0, 2, (H, W)), int(rng.integers(0, 2))), 7.0)
    height[rng.random((H, W)) < 0.1] = -0.0
    if seed % 5 == 0:
        height[zone & (rng.random((H, W)) < 0.05)] = np.nan
    binp = ~zone & (rng.random((H, W)) < 0.5)
    seen, nan, top = _rows_literal(zone, height)
    flat = np.flatnonzero(zone)
    if seed % 4 == 0:  # every row's top pixel (the first of them)
        pick = [r * W + int(np.flatnonzero(zone[r] & (height[r] == top[r]))[0]) for r in range(H)
                if seen[r] and np.isfinite(top[r]) and (zone[r] & (height[r] == top[r])).any()]
    elif seed % 4 == 1:  # whole rows
        pick = [q for q in flat if (q // W) % 2 == 0]
    else:
        pick = [q for q in flat if rng.random() < 0.3]
    done = np.array(sorted(set(int(q) for q in pick)), np.int64)
    floor, up = 0.8, np.array([0.1, -0.2, -0.97])
    want_zone, want_bin, want_h = zone.copy(), binp.copy(), height.copy()
    for q in done:
        r, c = divmod(int(q), W)
        want_zone[r, c], want_bin[r, c] = False, True
        zf = (floor - np.float64(a[r, c, 0]) * up[0] - np.float64(a[r, c, 1]) * up[1]) / up[2]
        want_h[r, c] = -1000.0 * zf
    _relabel_bin(a, done, floor, up, binp, zone, height, seen, nan, top)
    assert _same(zone, want_zone) and _same(binp, want_bin) and _same(height, want_h)
    for got, want in zip((seen, nan, top), _rows_literal(want_zone, want_h), strict=True):
        assert _same(got, want)
