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
from ray_in_netns import ADDRESS, netns_unavailable, run_with_ray_cluster
from test_batch_ray import _ok, _ray_missing, _require, _zcut, rechunk
from test_compare_workers import _rrd_rows, _same_outputs

ZCUT = str(Path(sys.executable).with_name("zcut"))


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two small synthetic logs of a frame per chunk; the comparison in one process, and on a 2-CPU Ray
    cluster in units of one frame, and an unreachable address."""
    _require(_ray_missing() or netns_unavailable())
    d = tmp_path_factory.mktemp("compare_ray")
    for name, parts, seed in (("a", "rods", 1), ("b", "spheres", 2)):
        _ok(_zcut("synth", "-o", f"{name}_whole.mcap", "--parts", parts, "--frames", "3", "--seed", str(seed),
                  "--size", "120x160", cwd=d))
        rechunk(d / f"{name}_whole.mcap", d / f"{name}.mcap", chunk_size=16 * 1024)
    (d / "rho.toml").write_text("[zcut]\nrho_thr = 0.035\n")
    args = ["compare", "a.mcap", "b.mcap", "--a", "zcut", "--b", "rho.toml", "--frames-per-unit", "1"]
    local = _zcut(*args, "-o", "local", "--workers", "0", cwd=d)  # also warms numba's caches for the workers
    cluster = run_with_ray_cluster([
        {"argv": [ZCUT, *args, "-o", "ray", "--ray", ADDRESS, "--json"], "cwd": str(d)},
        {"argv": [ZCUT, *args, "-o", "nowhere", "--ray", "127.0.0.1:1"], "cwd": str(d)},
    ], cpus=2, timeout=900)
    ray, nowhere = cluster["results"]
    return {"dir": d, "local": local, "ray": ray, "nowhere": nowhere, "interfaces": cluster["interfaces"]}


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
