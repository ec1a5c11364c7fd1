"""bench/wall_recall.py's pure helpers: item 2's headline (what the removal keeps near a wall against elsewhere,
per truth) and the classes of `explained`'s near-wall misses (issue 31 item 2, docs/bin_robustness.md)."""

from __future__ import annotations

import pytest
from bench_helpers import bench_module


@pytest.fixture(scope="module")
def bench():
    yield from bench_module("wall_recall.py")


def _row(bench, truth, *, n, kept, found):
    """A frame's row as frame_rows writes it: n, kept and every method's finds as (near, far) pairs."""
    return {"truth": truth, "sensor": "raytraced", "pile": "walls", "pose": "registered",
            "n": {"near": n[0], "far": n[1]}, "kept_near": kept[0], "kept_far": kept[1],
            "found": {m: {"near": found[0], "far": found[1]} for m in bench.SCORED}}


def test_the_headline_pools_frames_and_reads_the_removal_not_the_methods(bench):
    rows = [_row(bench, "paper", n=(10, 100), kept=(9, 100), found=(0, 50)),
            _row(bench, "paper", n=(10, 100), kept=(10, 99), found=(10, 50)),
            _row(bench, "sensor", n=(20, 100), kept=(10, 100), found=(20, 100))]
    table = bench.headline_table(rows, "registered")
    paper = next(line for line in table if line.startswith("| paper |")).split(" | ")
    sensor = next(line for line in table if line.startswith("| sensor |")).split(" | ")
    # paper: kept 19 / 20 near, 199 / 200 elsewhere: Δ = 0.950 - 0.995; the methods' Δ 0.5 - 0.5
    assert paper[3:8] == ["20", "200", "0.950 / 0.995", "-0.045", "yes"]
    assert paper[8:] and all(cell.strip(" |") == "+0.000" for cell in paper[8:])
    assert sensor[5:8] == ["0.500 / 1.000", "-0.500", "**no**"]
    assert len(paper) == 8 + len(bench.SCORED)
    assert bench.headline_table(rows, "true")[2:] == []  # no row at a pose not run


@pytest.mark.parametrize(("delta", "within"), [(0.0, "yes"), (-0.05, "yes"), (0.05, "yes"), (-0.0501, "**no**"),
                                               (0.0501, "**no**"), (float("nan"), "–")])
def test_within_is_two_sided(bench, delta, within):
    assert bench._within(delta) == within


@pytest.mark.parametrize(("mesh_mm", "err_fit", "d_in_err", "cls"), [
    (1.5, 1.0, 3.2, "off"),          # the fit misplaced: whatever the rest
    (float("nan"), 1.0, 3.2, "off"),  # no measure of the pose: not called right
    (0.3, 1.6, 3.2, "inflated"),     # right pose, Err above 1.5 x the truth's
    (0.3, 1.2, 3.9, "just_beyond"),
    (0.3, 1.2, 4.0, "just_beyond"),
    (0.3, 1.2, 4.1, "beyond"),
])
def test_miss_classes(bench, mesh_mm, err_fit, d_in_err, cls):
    pt = {"err_fit_mm": err_fit, "err_true_mm": 1.0, "d_true_in_err": d_in_err}
    assert bench.miss_class(pt, {"mesh_mean_mm": mesh_mm}) == cls


def test_fits_table_counts_each_class_and_splits_fits_by_wall(bench):
    fit = {"mesh_mean_mm": 0.2, "mesh_max_mm": 0.4, "sigma_mm": 0.5, "err_p50_mm": 1.2, "truth_err_p50_mm": 1.0,
           "wall_mm": 3.0, "misses": 2}
    off = {**fit, "mesh_mean_mm": 2.0, "wall_mm": 30.0, "misses": 1}
    pts = [{"fit": 0, "err_fit_mm": 1.0, "err_true_mm": 1.0, "d_true_in_err": 3.5},
           {"fit": 0, "err_fit_mm": 2.0, "err_true_mm": 1.0, "d_true_in_err": 5.0},
           {"fit": 1, "err_fit_mm": 1.0, "err_true_mm": 1.0, "d_true_in_err": 3.1}]
    rows = [{"seed": 9601, "kind": "spheres", "frame": 0, "near": 10, "missed_near": 4, "missed_part": 3,
             "fits": [fit, off], "points": pts}]
    table = bench.fits_table(rows)
    total = next(line for line in table if line.startswith("| all |")).split(" | ")
    assert total[5:9] == ["1 (33%)", "1 (33%)", "1 (33%)", "0 (0%)"]
    wall = next(line for line in table if line.startswith("| all, beside a wall")).split(" | ")
    assert wall[1:6] == ["1", "0.20 (0.20)", "0", "0.50", "1.20"]
    far = next(line for line in table if line.startswith("| all, elsewhere")).split(" | ")
    assert far[1:4] == ["1", "2.00 (2.00)", "1"]
    assert any(line.startswith("| spheres, elsewhere | 1 |") for line in table)
