"""z-cut: the pruned flood when every pixel of the frame is in the cuts (``raster`` of zcut.cut_tree.gentle_levels
and zcut.cut_tree.gentle_prune: the pixels in the cuts are not listed in ``pix``, they are the raster's, and the
kept ones are written to ``gcnt``'s slots), against the same kernels listing them (every array equal), the whole
tree's flood and the literal loop: crops and a full frame of the dense kind at seeds the benchmark does not use,
the labelling given up, 4-connectivity, invalid pixels inside the cuts, degenerate frames; and the scratch block
(``pruned_scratch``'s ``n_pix``)."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest
from bench_frames import bench_kinds
from test_cuts_fast import pruned_outliers

from zcut import zcut_outliers, zcut_outliers_reference
from zcut.cut_tree import gentle_levels, gentle_prune, pruned_scratch
from zcut.cuts import _finite_range, _levels, find_clusters
from zcut.params import ZCutParams, n_levels

NOMINAL = dict(step=0.2, max_depth=30.0, max_area=210.0)


@lru_cache(maxsize=2)
def dense(seed: int) -> np.ndarray:
    """The benchmark's dense kind (1920 x 1200, every pixel in the cuts) at ``seed``, made once (not to be
    written: the tests copy what they change)."""
    return bench_kinds()["dense"](seed)


def both_ways(z: np.ndarray, *, step: float = 0.2, max_depth: float = 30.0, max_area: float = 210.0,
              gentle8: bool = True, conn8: bool = True, check: int = 2**40) -> tuple[dict, dict]:
    """The level pass and the prune of z (every pixel in the cuts) on fresh arrays filled with junk, the pixels
    listed in ``pix`` and then ``raster`` (``pix`` not written, the kept pixels into ``gcnt``); each run's
    results and arrays. ``check``: when the labelling looks whether it pays (default: never)."""
    z = np.ascontiguousarray(z, dtype=np.float64)
    H, W = z.shape
    _, lo, hi, seg = _finite_range(z)
    k_eff, top = _levels(lo, hi, step, n_levels(step, max_depth))
    assert not lo < hi - top * step  # every pixel (z_min too) in the cuts: the one call's raster case
    runs = []
    for raster in (False, True):
        size = (H + 2) * (W + 2)
        st, gl = np.full(size, 77, np.int16), np.full(size, -5, np.int32)
        pix, gpar, gcnt = np.full(H * W, -3, np.int32), np.full(H * W, -4, np.int32), np.full(H * W, -6, np.int32)
        args = (z, seg, lo, hi, step, np.int64(k_eff + 2), np.int64(top), gentle8, max_area, np.int64(check),
                st, pix, gl, gpar, gcnt, 0.5, 0, 0, -1, -1)
        m, nl, labelled = gentle_levels(*args, None, True) if raster else gentle_levels(*args)
        if raster:
            assert (pix == -3).all()  # nothing listed
        inside = st.reshape(H + 2, W + 2)[1:-1, 1:-1] >= 0
        run = dict(m=int(m), nl=int(nl), labelled=bool(labelled), levels_st=st.copy(),
                   gl=gl.reshape(H + 2, W + 2)[1:-1, 1:-1][inside].copy(), gpar=gpar[:nl].copy(),
                   gcnt=gcnt[:nl].copy())
        start = np.zeros(top + 2, np.int64)
        if raster:
            keep = int(gentle_prune(st, gcnt, m, gl, gpar, gcnt, nl, max_area, start, labelled, W, conn8,
                                    np.int64(top), None, True))
            kept = gcnt[:keep].copy()
        else:
            keep = int(gentle_prune(st, pix, m, gl, gpar, gcnt, nl, max_area, start, labelled, W, conn8,
                                    np.int64(top)))
            kept = pix[:keep].copy()
        run.update(keep=keep, kept=kept, st=st.copy(), start=start)
        runs.append(run)
    return runs[0], runs[1]


def check_frame(z: np.ndarray, *, literal: bool = True, **kw: object) -> dict:
    """Both ways equal, array for array; the pruned flood's mask (which takes the raster case) against the
    literal loop (``literal``) or the whole tree's flood, and zcut_outliers' too; returns the listed run."""
    listed, raster = both_ways(z, **kw)  # type: ignore[arg-type]
    H, W = z.shape
    assert listed["m"] == raster["m"] == H * W
    for key in ("nl", "labelled", "keep"):
        assert listed[key] == raster[key], key
    for key in ("levels_st", "gl", "gpar", "gcnt", "kept", "st", "start"):
        np.testing.assert_array_equal(listed[key], raster[key], err_msg=key)
    params = {k: kw.get(k, v) for k, v in NOMINAL.items()}
    connectivity = 8 if kw.get("conn8", True) else 4
    if literal:
        want = zcut_outliers_reference(z, connectivity=connectivity, **params)  # type: ignore[arg-type]
    else:
        want = find_clusters(z, params=ZCutParams(connectivity=connectivity, **params)).outliers  # type: ignore[arg-type]
    gentle = "auto" if kw.get("gentle8", True) or not kw.get("conn8", True) else 4
    np.testing.assert_array_equal(pruned_outliers(z, connectivity=connectivity, gentle=gentle, **params), want)  # type: ignore[arg-type]
    np.testing.assert_array_equal(zcut_outliers(z, connectivity=connectivity, **params), want)  # type: ignore[arg-type]
    return listed


@pytest.mark.parametrize("seed", [41, 43])
def test_dense_crops(seed: int) -> None:
    """Crops of the dense kind (every pixel in the cuts) at unused seeds, widths on and off the segments' 64,
    8- and 4-connected, the 4-connected gentle components under an 8-connected z-cut."""
    z = dense(seed)
    for crop in (np.s_[300:420, 200:456], np.s_[10:47, 1500:1801], np.s_[600:601, 100:700], np.s_[200:500, 900:901]):
        sub = np.ascontiguousarray(z[crop])
        listed = check_frame(sub)
        assert listed["labelled"]
        check_frame(sub, conn8=False, gentle8=False)
        check_frame(sub, gentle8=False)


def test_full_dense_frame() -> None:
    """A whole 1920 x 1200 dense frame at an unused seed (the literal loop takes seconds there: the whole
    tree's flood is the oracle), many pixels kept and flooded."""
    listed = check_frame(dense(43), literal=False)
    assert listed["labelled"] and 10_000 < listed["keep"] < listed["m"] // 10


def test_labelling_given_up() -> None:
    """Few gentle edges (levels two apart at random): the labelling looks after the first rows, gives up, and every
    pixel is kept, listed from the raster."""
    rng = np.random.default_rng(18)
    z = -0.4 * rng.integers(0, 60, (160, 300)).astype(np.float64)
    listed = check_frame(z, check=4096)
    assert not listed["labelled"] and listed["keep"] == listed["m"]
    check_frame(z, check=4096, conn8=False, gentle8=False)


def test_invalid_pixels_inside_the_cuts() -> None:
    """NaN pixels stand at z_min, inside the cuts when every valid height is: never outliers, in every set."""
    rng = np.random.default_rng(7)
    z = np.array(dense(41)[500:640, 300:620])
    z[rng.random(z.shape) < 0.06] = np.nan
    z[40:70, 100:160] = np.nan
    check_frame(z)
    check_frame(z, max_area=12.0)


@pytest.mark.parametrize("case", ["one_pixel", "one_row", "one_column", "constant", "one_valid", "spikes"])
def test_degenerate_frames(case: str) -> None:
    """Degenerate frames with every pixel in the cuts, at two max_area."""
    rng = np.random.default_rng(11)
    spikes = rng.uniform(0.0, 4.0, (50, 70))
    spikes[rng.random(spikes.shape) < 0.05] += 3.0
    z = {
        "one_pixel": np.array([[3.0]]),
        "one_row": rng.normal(0.0, 0.3, (1, 300)),
        "one_column": rng.normal(0.0, 0.3, (300, 1)),
        "constant": np.full((40, 70), 2.5),
        "one_valid": np.where(np.arange(600).reshape(20, 30) == 317, 1.0, np.nan),
        "spikes": spikes,
    }[case]
    check_frame(z, max_area=4.0)
    check_frame(z)


def test_scratch_without_the_pixel_list() -> None:
    """``pruned_scratch``'s ``n_pix``: 0 gives an empty ``pix`` and the other views as before (each on a 64-byte
    boundary, disjoint); -1 (the default) is ``bound``. The block of a 1920 x 1200 frame with every pixel in the cuts
    is then below glibc's largest mmap threshold (32 MiB), which the listed pixels put it over."""
    n, bound = 1202 * 1922, 1200 * 1920
    for n_pix, want in ((-1, bound), (0, 0), (5, 5)):
        views = pruned_scratch(np.int64(n), np.int64(bound), np.int64(0), np.int64(n_pix))
        st, gl, pix, gpar, gcnt, gls = views
        assert (st.size, gl.size, pix.size, gpar.size, gcnt.size, gls.size) == (n, n, want, bound, bound, 0)
        starts = [v.__array_interface__["data"][0] for v in views]
        assert all((s - starts[1]) % 64 == 0 for s in starts)
        spans = sorted((s, s + v.nbytes) for s, v in zip(starts, views, strict=True) if v.nbytes)
        assert all(a[1] <= b[0] for a, b in zip(spans, spans[1:], strict=False))
        if n_pix <= 0:
            assert (spans[-1][1] - starts[1] < 32 << 20) == (n_pix == 0)
    default = pruned_scratch(np.int64(100), np.int64(40), np.int64(8))
    assert default[2].size == 40
