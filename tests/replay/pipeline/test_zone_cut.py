"""The zone's z-cut (``Zone.cut``: ``find_clusters`` on the zone's heights, computed once by whichever of the method
``zcut`` and SOR's top region asks first) and SOR's top region from it (``sor_region_of_cut``): the same region as
``sor_region`` scanning the heights, on height images with NaN, +-inf, signed zeros and values exactly on the
threshold, degenerate images (one pixel, one row, one column, none finite), the real organized clouds' heights; the
same masks through the pipeline whichever method runs first or alone.
"""

from __future__ import annotations

import dataclasses
import os
import pickle
import threading
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from replay.pipeline.zone import Zone, sor_judged, sor_region, sor_region_of_cut
from zcut.cuts import MAX_STAGE_LEVELS, find_clusters
from zcut.errors import ParameterError
from zcut.params import ZCutParams

PARAMS = ZCutParams(step=0.5, max_depth=3.0, max_area=40.0)


def _heights(h: int, w: int, seed: int, params: ZCutParams = PARAMS) -> np.ndarray:
    rng = np.random.default_rng(seed)
    z = rng.uniform(-20.0, 20.0, (h, w))
    pick = rng.random((h, w))
    z[pick < 0.15] = np.nan
    z[(pick >= 0.15) & (pick < 0.18)] = np.inf
    z[(pick >= 0.18) & (pick < 0.20)] = -np.inf
    z[(pick >= 0.20) & (pick < 0.23)] = -0.0
    z[(pick >= 0.23) & (pick < 0.26)] = 0.0
    fin = np.isfinite(z)
    if fin.any():  # values exactly on the lowest cut, and just either side of it
        top = float(np.max(z, where=fin, initial=-np.inf))
        thr = top - params.n_levels * params.step
        z[(pick >= 0.26) & (pick < 0.30)] = thr
        z[(pick >= 0.30) & (pick < 0.31)] = np.nextafter(thr, -np.inf)
        z[(pick >= 0.31) & (pick < 0.32)] = np.nextafter(thr, np.inf)
    return z


def _zone(z: np.ndarray, zone: np.ndarray) -> Zone:
    return Zone(None, None, zone, z, np.zeros(z.shape, bool), {}, ())  # type: ignore[arg-type]  # no bin stages


def _same_region(z: np.ndarray, zone: np.ndarray, params: ZCutParams = PARAMS) -> np.ndarray:
    cut = find_clusters(z, params=params)
    want = sor_region(z, zone, params)
    got = sor_region_of_cut(z, zone, params, cut)
    assert got.dtype == want.dtype == np.bool_ and np.array_equal(got, want)
    assert np.array_equal(_zone(z, zone).cut(params).outliers, cut.outliers)
    return want


@pytest.mark.parametrize("shape", [(1, 1), (1, 17), (13, 1), (40, 60), (121, 97)])
def test_random_heights(shape):
    for seed in range(4):
        z = _heights(*shape, seed=seed)
        zone = np.random.default_rng(seed + 50).random(shape) < 0.7
        _same_region(z, zone)
        _same_region(z.astype(np.float32), zone)  # float32 heights: find_clusters reads them as float64


@pytest.mark.parametrize("params", [ZCutParams(step=1.0, max_depth=0.0, max_area=5.0),  # K = 0: z_max - 0
                                    ZCutParams(step=0.3, max_depth=0.9, max_area=5.0),   # 0.9 / 0.3 + 1e-9
                                    ZCutParams(step=2.0, max_depth=60.0, max_area=5.0)])  # every height in the cuts
def test_other_parameters(params):
    for seed in range(3):
        z = _heights(30, 40, seed=seed + 10, params=params)
        _same_region(z, np.random.default_rng(seed).random(z.shape) < 0.8, params)


@pytest.mark.parametrize("fill", [np.nan, np.inf, -np.inf])
def test_no_finite_height(fill):
    z = np.full((6, 8), fill)
    zone = np.ones((6, 8), bool)
    assert not _same_region(z, zone).any()


def test_one_finite_height_among_signed_zeros():
    z = np.full((5, 5), np.nan)
    z[2, 2] = -0.0
    z[0, 0] = 0.0
    z[4, 4] = np.inf
    assert _same_region(z, np.ones((5, 5), bool)).sum() == 3  # +inf is at or above any threshold


def test_real_clouds_heights():
    from replay.logs.pcd import read_pcd

    root = Path(os.environ.get("ZCUT_REAL_DATA", "/work/shared/data/real"))
    clouds = sorted(root.glob("*.pcd")) if root.is_dir() else []
    if not clouds:
        pytest.skip("no real clouds")
    params = ZCutParams(step=2.0, max_depth=40.0, max_area=100.0)
    for path in clouds:
        z = -1000.0 * read_pcd(path).xyz[..., 2].astype(np.float64)
        fin = np.isfinite(z)
        assert _same_region(z, fin, params).any()
        _same_region(np.where(np.arange(z.shape[0])[:, None] < z.shape[0] // 2, np.nan, z), fin, params)


def test_computed_once_per_parameter_set_and_only_for_the_zones_own_heights():
    z = _heights(20, 30, seed=9)
    zone = _zone(z, np.isfinite(z))
    first = zone.cut(PARAMS)
    assert zone.cut(PARAMS) is first and zone.cut(dataclasses.replace(PARAMS)) is first  # equal parameters
    other = dataclasses.replace(PARAMS, max_area=3.0)
    assert zone.cut(other) is not first and zone.cut(other) is zone.cut(other)
    assert np.array_equal(zone.cut(other).outliers, find_clusters(z, params=other).outliers)
    moved = dataclasses.replace(zone, height_mm=z + 1.0)  # another zone: its own
    assert moved.cut(PARAMS) is not first and moved.cut(PARAMS).z_max == first.z_max + 1.0
    copied = pickle.loads(pickle.dumps(zone))  # a copy computes its own
    assert copied.cut(PARAMS) is not first and np.array_equal(copied.cut(PARAMS).clusters, first.clusters)


def test_concurrent_callers_share_one_result():
    z = _heights(60, 80, seed=3)
    zone = _zone(z, np.isfinite(z))
    got: list[object] = []
    threads = [threading.Thread(target=lambda: got.append(zone.cut(PARAMS))) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(got) == 4 and all(g is got[0] for g in got)


def test_a_refused_zcut_leaves_the_region_as_it_was():
    """Too many levels for find_clusters: the z-cut raises (to every caller, nothing kept), SOR's region is
    sor_region's all the same."""
    deep = ZCutParams(step=0.001, max_depth=0.001 * (MAX_STAGE_LEVELS + 5), max_area=40.0)
    z = _heights(20, 30, seed=4, params=deep)
    zone = _zone(z, np.isfinite(z))
    for _ in range(2):
        with pytest.raises(ParameterError, match="levels"):
            zone.cut(deep)
    config = SimpleNamespace(sor=SimpleNamespace(region="top"), zcut=deep)  # what sor_judged reads
    assert np.array_equal(sor_judged(zone, config), sor_region(z, zone.zone, deep))


@pytest.mark.parametrize("order", [("zcut", "sor"), ("sor", "zcut"), ("sor",)])
def test_through_the_pipeline(tmp_path, order):
    """A synthetic frame's methods (the registry's run functions) in either order or SOR alone: the z-cut and
    SOR's masks are those of find_clusters and of SOR on sor_region computed apart; a replay's own order (the
    z-cut first, always: ``base_methods``) gives them too."""
    from replay.logs.reader import LogReader
    from replay.pipeline import config as cfg
    from replay.pipeline.methods import registry
    from replay.pipeline.stages import bin_zone, run_methods
    from replay.pipeline.zone import _sor_on_zone
    from replay.synth.log import write_synthetic_log

    path = write_synthetic_log(tmp_path / "one.mcap", kind="zinc_nuts", frames=1, seed=31, size=(90, 120))
    frame = next(iter(LogReader(path).frames()))
    config = cfg.resolve(cfg.log_facts({}, frame)).config
    assert config.sor.region == "top" and config.base_methods[:2] == ("zcut", "sor")
    s = config.sor
    zone = bin_zone(frame, config)  # no bin model: the whole frame's heights
    want_sor = _sor_on_zone(frame.xyz, sor_region(zone.height_mm, zone.zone, config.zcut), whole=False, k=s.k,
                            std_ratio=s.std_ratio, convention=s.convention)
    want = find_clusters(zone.height_mm, params=config.zcut)
    assert want_sor.any() and want.outliers.any()
    zone = bin_zone(frame, config)  # a fresh zone: nothing computed on it yet
    out = {name: registry()[name].run(frame, zone, config) for name in order}
    assert np.array_equal(out["sor"].outliers, want_sor)
    if "zcut" in out:
        assert np.array_equal(out["zcut"].outliers, want.outliers & zone.zone)
        assert np.array_equal(out["zcut"].detail.clusters, want.clusters)
    replayed = run_methods(frame, bin_zone(frame, config), config, timings={}, warnings=[])
    assert np.array_equal(replayed["sor"].outliers, want_sor)
    assert np.array_equal(replayed["zcut"].outliers, want.outliers & zone.zone)
