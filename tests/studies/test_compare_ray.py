"""``zcut compare --ray`` on a real local Ray cluster (``ray start --head``, no mocks), as
``tests/studies/test_batch_ray.py`` runs ``zcut batch``: its outputs equal those of the comparison run
in one process.

The cluster runs in network, PID and mount namespaces of its own (``ray_in_netns.py``): Ray rewrites
127.0.0.1 to the machine's interface address, and test traffic must stay on loopback. Needs the
``ray`` extra and ``unshare``: without them the test is skipped with the reason, except under CI
(``CI`` set), where it fails.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from ray_in_netns import ADDRESS
from test_batch_ray import _ok, _zcut, rechunk, zcut_here
from test_compare_workers import _rrd_rows, _same_outputs

ZCUT = str(Path(sys.executable).with_name("zcut"))


def prepare_compare(d: Path) -> tuple[dict, list[dict]]:
    """Two small synthetic logs of a frame per chunk; the comparison in one process; the commands for
    the Ray cluster: the comparison in units of one frame, and an unreachable address."""
    for name, parts, seed in (("a", "rods", 1), ("b", "spheres", 2)):
        zcut_here("synth", "-o", d / f"{name}_whole.mcap", "--parts", parts, "--frames", "3", "--seed", str(seed),
                  "--size", "120x160")
        rechunk(d / f"{name}_whole.mcap", d / f"{name}.mcap", chunk_size=16 * 1024)
    (d / "rho.toml").write_text("[zcut]\nrho_thr = 0.035\n")
    args = ["compare", "a.mcap", "b.mcap", "--a", "zcut", "--b", "rho.toml", "--frames-per-unit", "1"]
    local = _zcut(*args, "-o", "local", "--workers", "0", cwd=d)  # also warms numba's caches for the workers
    commands = [
        {"argv": [ZCUT, *args, "-o", "ray", "--ray", ADDRESS, "--json"], "cwd": str(d)},
        {"argv": [ZCUT, *args, "-o", "nowhere", "--ray", "127.0.0.1:1"], "cwd": str(d)},
    ]
    return {"dir": d, "local": local}, commands


def collect_compare(prepared: dict, results: list[dict], interfaces: list[str]) -> dict:
    ray, nowhere = results
    return {**prepared, "ray": ray, "nowhere": nowhere, "interfaces": interfaces}


@pytest.fixture(scope="module")
def runs(ray_cluster_runs):
    """The comparison's part of the session's one Ray cluster run (tests/studies/conftest.py), on a
    2-CPU cluster in units of one frame, and an unreachable address."""
    return ray_cluster_runs["compare"]


def test_the_cluster_saw_loopback_only(runs):
    assert runs["interfaces"] == ["lo"]


def test_compare_on_ray_equals_one_process(runs):
    _ok(runs["local"])
    assert runs["ray"]["rc"] == 0, runs["ray"]["stderr"][-3000:]
    d = runs["dir"]
    _same_outputs(d / "ray", d / "local")
    assert _rrd_rows(d / "ray" / "compare.rrd") == _rrd_rows(d / "local" / "compare.rrd")
    cost = json.loads(runs["ray"]["stdout"])["cost"]
    assert (cost["executor"], cost["workers"], cost["units"], cost["units_this_run"]) == ("Ray", 2, 6, 6)
    assert len(list((d / "ray" / "parts").glob("*.json"))) == 6  # a Ray task per frame


def test_an_unreachable_cluster_is_one_line_before_any_work(runs):
    nowhere = runs["nowhere"]
    assert nowhere["rc"] == 1
    lines = nowhere["stderr"].strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: --ray 127.0.0.1:1: cannot reach a Ray cluster"), lines
    assert not (runs["dir"] / "nowhere").exists()
