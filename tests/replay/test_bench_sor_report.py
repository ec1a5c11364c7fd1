"""bench/bench_sor.py finds the real clouds as tests/conftest.py does, and never calls a minimum over the
synthetic classes only "smallest" (issue 35 #25)."""

from __future__ import annotations

import pytest
from bench_helpers import bench_module


@pytest.fixture(scope="module")
def bench():
    yield from bench_module("bench_sor.py")


def test_the_real_data_beside_the_checkout_is_found_without_the_variable(bench, tmp_path):
    checkout = tmp_path / "zcut"
    checkout.mkdir()
    real = tmp_path / "shared" / "data" / "real"
    real.mkdir(parents=True)
    (real / "a.pcd").write_bytes(b"")
    assert bench.real_data_folder(checkout, {}) == (real, None)
    assert bench.real_data_folder(checkout, {"ZCUT_REAL_DATA": str(tmp_path / "elsewhere")}) == (real, None)


def test_the_variable_is_used_when_nothing_is_beside_the_checkout(bench, tmp_path):
    checkout = tmp_path / "zcut"
    checkout.mkdir()
    other = tmp_path / "other"
    other.mkdir()
    (other / "b.pcd").write_bytes(b"")
    assert bench.real_data_folder(checkout, {"ZCUT_REAL_DATA": str(other)}) == (other, None)
    folder, why = bench.real_data_folder(checkout, {})
    assert why is not None and "no real data folder" in why and str(tmp_path / "shared" / "data" / "real") in why
    (other / "b.pcd").unlink()
    _, why = bench.real_data_folder(checkout, {"ZCUT_REAL_DATA": str(other)})
    assert "holds no .pcd file" in why


def test_a_minimum_over_synthetic_classes_is_not_called_the_smallest(bench):
    lines = bench.summary(["pile", "walls"], {"synth": "ImportError: x"}, 7.25, real_problem="no real data folder: …")
    text = "\n".join(lines)
    assert "smallest" not in text.replace("not the smallest", "")
    assert "real-data classes run (0): NONE" in text
    assert "WARNING: no real-data class ran: no real data folder: …" in text
    assert lines[-1].startswith("minimum ratio over the synthetic classes only: 7.2x")
    assert "not run: synth: ImportError: x" in text
    lines = bench.summary(["pile", "kinect/mosd_test16"], {}, 5.0, real_problem=None)
    assert lines[-1] == "smallest ratio: 5.0x (over 2 classes, 1 of real data)"


def test_this_checkout_finds_the_real_clouds_where_the_tests_do(bench):
    from real_data_path import REAL_DATA

    if not REAL_DATA.is_dir():
        pytest.skip("no real data on this machine")
    folder, why = bench.real_data_folder()
    assert why is None and folder.resolve() == REAL_DATA.resolve()
    assert any(bench.is_real(c) for c in bench.cloud_classes(0))
