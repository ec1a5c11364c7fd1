"""The labelling page's review groups on a real Kinect scan, where no generator made the frame and no bin
is in view (docs/labelling_real.md): recorded with ``zcut record``, prepared as ``zcut annotate`` prepares
it, the groups stay within the page's budget and each says why it is a suspect."""

from __future__ import annotations

import numpy as np
from cli_helpers import run_cli

from annotate.budget import METHOD_GROUPS_MAX, review_budget
from annotate.groups import GCOL
from annotate.payload import parse_bundle, prepare_frame
from replay.pipeline.session import ReplaySession
from zcut.params import SuspectParams
from zcut.suspects import DETECTORS

SCAN = "mosd_test55.pcd"  # the complex mOSD scene: every suspect detector but above_rim proposes something


def test_real_kinect_scan_groups_within_budget_each_with_its_why(real_data, tmp_path, capsys):
    log = tmp_path / "scan.mcap"
    rc, out, err = run_cli(capsys, "record", real_data / SCAN, "-o", log)
    assert rc == 0, err
    assert "480x640" in out
    session = ReplaySession.open(log)
    config = session.config
    results = session.results()
    try:
        (frame, result), = list(results)
    finally:
        results.close()
    params = SuspectParams(a_max=config.zcut.a_max)  # what the page's catalogue gives the detectors
    served = prepare_frame(frame, result, suspect_params=params, part=config.part).served
    header, arrays = parse_bundle(served.bundle)

    # no bin model, no bin: the frame says so, and the groups still cover the whole frame
    assert header["bin_stages"] is False and not served.bin_stages
    assert any("no bin model" in w for w in header["warnings"])
    assert "zone" not in arrays  # the zone is every valid pixel

    table, ids = arrays["group_table"], arrays["groups"].astype(np.int64)
    n = header["n_groups"]
    assert n == table.shape[0] == served.n_groups
    sources = header["group_sources"]
    assert tuple(sources[:len(DETECTORS)]) == DETECTORS and header["detectors"] == list(DETECTORS)
    src = [sources[int(s)] for s in table[:, GCOL["source"]]]
    methods = header["methods"]
    # the page's budget: at most max_groups suspect groups, METHOD_GROUPS_MAX per filter method
    n_suspect_groups = sum(s in DETECTORS for s in src)
    assert 5 <= n_suspect_groups <= params.max_groups
    for m in methods:
        assert src.count(m) <= METHOD_GROUPS_MAX
    assert n <= review_budget(params, len(methods))
    assert len({s for s in src if s in DETECTORS}) >= 3  # not one detector's specks only

    # each group: its size is its pixels, its detector or method flags it, its gap is a number
    sizes = np.bincount(ids.ravel(), minlength=n + 1)[1:]
    assert np.array_equal(sizes, table[:, GCOL["n"]].astype(np.int64)) and (sizes > 0).all()
    for g in range(n):
        s = src[g]
        if s in DETECTORS:
            assert int(table[g, GCOL["detectors"]]) >> DETECTORS.index(s) & 1, (g, s)
        else:
            assert int(table[g, GCOL["methods"]]) >> methods.index(s) & 1, (g, s)
        assert np.isfinite(table[g, GCOL["gap_mm"]]), (g, s)
        x0, y0, x1, y1 = (int(table[g, GCOL[c]]) for c in ("x0", "y0", "x1", "y1"))
        inside = ids[y0:y1, x0:x1] == g + 1
        assert inside.sum() == sizes[g]  # its box holds all of it
    # sensible groups on a scan no generator made: neither the whole table as one nor a flood of specks
    valid = int(header["n_valid"])
    assert sizes.max() < 0.05 * valid
    assert (sizes == 1).sum() <= n // 2
    assert header["n_suspect_px"] == int(served.cand_pixels.size) - int(
        sum(sizes[g] for g in range(n) if src[g] not in DETECTORS))
