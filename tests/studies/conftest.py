"""The Ray tests' one cluster: ``zcut batch``, ``zcut sweep`` and ``zcut compare`` on a real local Ray
cluster (tests/studies/test_batch_ray.py, test_compare_ray.py). Starting a cluster in its namespaces
costs tens of seconds, so the session starts one and runs both modules' commands on it, in turn."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def ray_cluster_runs(tmp_path_factory):
    """Both modules' inputs and local runs, then every command of both on one 2-CPU cluster."""
    from ray_in_netns import netns_unavailable, run_with_ray_cluster
    from test_batch_ray import _ray_missing, _require, collect_batch, prepare_batch
    from test_compare_ray import collect_compare, prepare_compare

    _require(_ray_missing() or netns_unavailable())
    batch, batch_cmds = prepare_batch(tmp_path_factory.mktemp("batch_ray"))
    compare, compare_cmds = prepare_compare(tmp_path_factory.mktemp("compare_ray"))
    cluster = run_with_ray_cluster([*batch_cmds, *compare_cmds], cpus=2, timeout=1500)
    results = cluster["results"]
    return {"batch": collect_batch(batch, results[:len(batch_cmds)], cluster["interfaces"]),
            "compare": collect_compare(compare, results[len(batch_cmds):], cluster["interfaces"])}
