"""The pixels the straggler bound gives back to the zone (:func:`zcut.removal.unbounded_stragglers`; docs/labelling.md,
"Tenth round").

The oracle: the removal run twice, with the bound and with ``straggler_bound = "off"`` — the pixels in the first's
zone and not in the second's. On a hand-made frame (300 x 480, registered as the replay does) with inner-wall
stragglers moved beyond the bound, with large invalid regions, on degenerate frames, and with the bound off
(nothing given back). The result is read-only: the removal's result is not changed.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from replay.pipeline import stages
from replay.pipeline.bin_model import bin_model_for
from replay.pipeline.session import ReplaySession
from replay.synth.log import write_synthetic_log
from replay.synth.scene import LABEL_WALL
from replay.synth.synthesize import synthesize_frame
from zcut.params import RemovalParams
from zcut.removal import (
    frame_tolerance,
    prepare_removal_index,
    remove_table_and_bin,
    straggler_bound_m,
    unbounded_stragglers,
)

H, W = 300, 480
KIND, SEED = "spheres", 31


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """(xyz, footprint, ring, T, model, picks): a hand-made frame located as the replay does, and inner-wall
    pixels labelled bin every 9th pixel (isolated stragglers once moved)."""
    path = write_synthetic_log(tmp_path_factory.mktemp("putback") / "s.mcap", kind=KIND, frames=1, seed=SEED,
                               size=(H, W))
    s = ReplaySession.open(path, choose_bin_model=lambda reader: bin_model_for(reader, None))
    frame = next(iter(s.reader.frames()))
    loc = stages.locate_bin(frame, s.config, bin_model=s.prepared, seed=s.seed)
    assert loc.registration is not None and loc.registration.converged and s.prepared is not None
    surface = synthesize_frame(kind=KIND, seed=SEED, index=0, size=(H, W)).surface
    T = loc.registration.T_cam_bin
    model = s.prepared.model
    rem = remove_table_and_bin(frame.xyz, loc.bin_mask.mask, index=prepare_removal_index(model, RemovalParams()),
                               T_cam_bin=T, ring=loc.ring)
    wall = (surface == LABEL_WALL) & rem.bin_points
    inner = wall.copy()
    for dr in range(-3, 4):
        for dc in range(-3, 4):
            inner &= np.roll(np.roll(wall, dr, axis=0), dc, axis=1)
    grid = np.zeros((H, W), bool)
    grid[5::9, 5::9] = True
    picks = np.argwhere(inner & grid)
    assert len(picks) >= 40
    return frame.xyz, loc.bin_mask.mask, loc.ring, T, model, picks


def _moved(xyz, T, model, picks, dist_m):
    """``xyz`` with each pick moved along its ray to ``dist_m`` from the tangent plane of its nearest model point,
    towards the camera (as tests/zcut/test_removal_straggler_bound.py moves them)."""
    from scipy.spatial import cKDTree

    out = xyz.copy()
    R, t = T[:3, :3], T[:3, 3]
    tree = cKDTree(model.points)
    camera = (-t) @ R
    for (r, c), d in zip(picks, dist_m, strict=True):
        p = xyz[r, c].astype(np.float64)
        ray = p / np.linalg.norm(p)
        q = (p - t) @ R
        _, j = tree.query(q)
        n, m = model.normals[j], model.points[j]
        side = 1.0 if n @ (camera - m) >= 0 else -1.0
        step = (side * d - n @ (q - m)) / (n @ (ray @ R))
        out[r, c] = (p + step * ray).astype(np.float32)
    return out


def _beyond_the_bound(scene, p):
    """The frame with every pick moved half-way between the frame's bound and τ + ``straggler_mm``."""
    xyz, fp, ring, T, model, picks = scene
    index = prepare_removal_index(model, p)
    tol = frame_tolerance(xyz, ring, index, T)
    tau = tol.tolerance_mm / 1000.0
    z = xyz[picks[:, 0], picks[:, 1], 2].astype(np.float64)
    bound = straggler_bound_m(z, tol.sigma_mm / 1000.0, tol.pixel_rad, tau + p.straggler_m)
    return _moved(xyz, T, model, picks, 0.5 * (bound + tau + p.straggler_m))


def _oracle(a, fp, ring, T, model, p):
    """(the removal with ``p``, its index, the pixels in its zone that ``straggler_bound = "off"`` labels bin)."""
    index = prepare_removal_index(model, p)
    got = remove_table_and_bin(a, fp, index=index, T_cam_bin=T, ring=ring)
    off = remove_table_and_bin(a, fp, index=prepare_removal_index(model, dataclasses.replace(p, straggler_bound="off")),
                               T_cam_bin=T, ring=ring)
    assert not (off.zone & ~got.zone).any()  # the bound only gives pixels back
    return got, index, got.zone & ~off.zone


def _frozen(r):
    return {f: getattr(r, f).copy() for f in ("table", "easy_outliers", "bin_points", "zone")}


@pytest.mark.parametrize("p", [RemovalParams(straggler_bound="global"), RemovalParams()], ids=["global", "below_rim"])
def test_the_given_back_pixels_are_those_the_unbounded_removal_takes(scene, p):
    xyz, fp, ring, T, model, picks = scene
    a = _beyond_the_bound(scene, p)
    got, index, want = _oracle(a, fp, ring, T, model, p)
    before = _frozen(got)
    put_back = unbounded_stragglers(a, got, index, T)
    assert put_back.dtype == np.bool_ and put_back.shape == (H, W)
    np.testing.assert_array_equal(put_back, want)
    if p.straggler_bound == "global":  # the moved picks are given back (but a few a nearer face's plane takes)
        assert put_back[picks[:, 0], picks[:, 1]].mean() >= 0.85
    assert want.sum() > 0
    for f, v in before.items():  # read-only
        np.testing.assert_array_equal(getattr(got, f), v)


@pytest.mark.parametrize("case", ["half NaN", "bands", "all NaN", "one pixel"])
def test_invalid_regions_and_degenerate_frames(scene, case):
    xyz, fp, ring, T, model, picks = scene
    p = RemovalParams(straggler_bound="global")
    a = _beyond_the_bound(scene, p)
    if case == "half NaN":
        a[:, : W // 2] = np.nan
    elif case == "bands":
        a[::5] = np.nan
        a[:, 100:220] = np.nan
    else:
        keep = a[picks[0, 0], picks[0, 1]].copy()
        a[:] = np.nan
        if case == "one pixel":
            a[picks[0, 0], picks[0, 1]] = keep
    got, index, want = _oracle(a, fp, ring, T, model, p)
    put_back = unbounded_stragglers(a, got, index, T)
    np.testing.assert_array_equal(put_back, want)
    assert not (put_back & ~got.zone).any()
    if case in ("all NaN", "one pixel"):
        assert not put_back.any()


@pytest.mark.parametrize("p", [RemovalParams(straggler_bound="off"), RemovalParams(straggler_mm=0.0),
                               RemovalParams(mode="paper")], ids=["off", "no straggler pass", "paper"])
def test_nothing_is_given_back_without_the_bound(scene, p):
    xyz, fp, ring, T, model, picks = scene
    a = _beyond_the_bound(scene, RemovalParams())
    index = prepare_removal_index(model, p)
    got = remove_table_and_bin(a, fp, index=index, T_cam_bin=T, ring=ring)
    assert not unbounded_stragglers(a, got, index, T).any()
