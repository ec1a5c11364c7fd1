"""The results file's size: without the cloud, a frame is its masks (chunk-compressed, bit-packed mono1 images)."""

from __future__ import annotations

import numpy as np
import pytest
from mcap.reader import make_reader

from replay.logs import layout
from replay.logs import ros2_msgs as rm
from replay.pipeline.bin_model import bin_model_for
from replay.pipeline.session import ReplaySession
from replay.pipeline.sinks import BackgroundSinks, ResultsSink


@pytest.fixture(scope="module")
def small_log(tmp_path_factory):
    from session_logs import synth_once

    # the log of tests/replay/logs/test_packed_results.py and test_cloudless_results.py too: made once per session
    return synth_once(tmp_path_factory, parts="rods", frames=2, seed=11, size="240x384")


def _messages(path):
    with open(path, "rb") as f:
        return [(ch.topic, m) for _, ch, m in make_reader(f).iter_messages()]


def test_results_without_the_cloud_hold_the_same_masks(small_log, tmp_path):
    session = ReplaySession.open(small_log, choose_bin_model=lambda r: bin_model_for(r, None))
    paths = {c: tmp_path / f"r_{c}.mcap" for c in (True, False)}
    for cloud, path in paths.items():
        session.run(BackgroundSinks([ResultsSink(path, cloud=cloud)]))
    full, lean = _messages(paths[True]), _messages(paths[False])
    assert {t for t, _ in full} - {t for t, _ in lean} == {layout.FILTERED, layout.IMAGE}
    kept = [(t, m.log_time, m.data) for t, m in full if t not in (layout.FILTERED, layout.IMAGE)]
    assert kept == [(t, m.log_time, m.data) for t, m in lean]  # the same mask messages, byte for byte
    masks = [rm.image_to_mask(rm.decode_image(m.data, where="x"), where="x")
             for t, m in lean if t == layout.ZCUT_OUTLIERS]
    assert len(masks) == 2 and all(mk.dtype == np.bool_ for mk in masks)
    # the masks compress to almost nothing: the cloud and image were ~all of the file
    assert paths[False].stat().st_size < 0.1 * paths[True].stat().st_size
