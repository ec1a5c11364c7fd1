"""Two frames in flight (issue 32, both cores busy): :meth:`ReplaySession.results` with ``in_flight=2``
gives every frame's result as the one-frame-at-a-time run does (``in_flight=1``, the previous code's
loop), in log order, and the sinks see the frames in that order, one at a time.

Classes of log: synthetic ones of two part kinds and seeds (the bin stages on, their own bin model
attachment), the same without the bin stages, frames with large invalid regions and a frame with
almost nothing valid, a real Kinect log (no bin: the z-cut and SOR on the whole frame), a frame range,
and a truncated log (the frames before the damage, and the damage, the same).
"""

from __future__ import annotations

import math
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from log_helpers import invalid_blobs, writer_like

from replay.logs.frame import Frame
from replay.logs.reader import LogReader
from replay.pipeline.bin_model import bin_model_for
from replay.pipeline.session import FrameRow, ReplaySession
from replay.pipeline.sinks import FrameSink, ReplayStart
from replay.pipeline.stages import FrameResult
from replay.synth.log import write_synthetic_log


def _open(log: Path, tmp_path: Path, *, bin_stages: bool = True) -> ReplaySession:
    config_file = None
    if not bin_stages:
        config_file = tmp_path / "no_bin.toml"
        config_file.write_text("[bin_mask]\nenabled = false\n")
    return ReplaySession.open(log, config_file=config_file, choose_bin_model=lambda r: bin_model_for(r, None))


def _masks(r: FrameResult) -> dict[str, np.ndarray]:
    """Every mask and label image of a result (exact), by name."""
    out = {"valid": r.valid, "zone": r.zone, "easy": r.easy_outliers, "clusters": r.cut.clusters,
           **{f"outliers.{m}": o for m, o in r.outliers.items()}}
    if r.bin_mask is not None:
        out["bin_mask"] = r.bin_mask.mask
    if r.removal is not None:
        out.update({"table": r.removal.table, "bin_points": r.removal.bin_points})
    return out


def _floats(r: FrameResult) -> list[float]:
    """The figures that follow the registration's pose: Open3D's multithreaded ICP does not give the
    same last bits from one run to the next (with one frame in flight as with two)."""
    reg = r.registration
    out = [float(r.metrics.alpha), float(r.metrics.beta1), float(r.metrics.beta2)]
    if reg is not None:
        out += [float(reg.fitness), float(reg.inlier_rmse), *np.asarray(reg.T_cam_bin, float).ravel()]
    return out


def _run(session: ReplaySession, in_flight: int, frames: tuple[int, int | None] = (0, None)) -> dict[str, Any]:
    stream = session.results(frames=frames, in_flight=in_flight)
    got: list[tuple[int, int, dict[str, np.ndarray], FrameRow, list[float], tuple[str, ...], np.ndarray]] = []
    try:
        for frame, r in stream:
            assert r.index == frame.index
            row = FrameRow.of(r)
            got.append((frame.index, frame.stamp_ns, _masks(r), row, _floats(r), r.warnings,
                        r.height_mm))
    finally:
        stream.close()
    return {"frames": got, "damage": [d.text for d in stream.damage]}


def _same_runs(a: dict[str, Any], b: dict[str, Any]) -> None:
    assert a["damage"] == b["damage"]
    assert [g[:2] for g in a["frames"]] == [g[:2] for g in b["frames"]]  # the same frames, in order
    for (i, _, ma, ra, fa, wa, ha), (_, _, mb, rb, fb, wb, hb) in zip(a["frames"], b["frames"]):
        assert ma.keys() == mb.keys(), i
        for k in ma:
            assert ma[k].dtype == mb[k].dtype and np.array_equal(ma[k], mb[k]), (i, k)
        counts = ("valid_px", "zcut", "sor", "both", "above_rim", "clusters", "others", "bin_flagged")
        assert [getattr(ra, c) for c in counts] == [getattr(rb, c) for c in counts], i
        assert wa == wb, i
        assert np.allclose(fa, fb, rtol=1e-9, atol=1e-12, equal_nan=True), i
        assert np.allclose(ha, hb, rtol=1e-9, atol=1e-9, equal_nan=True), i
        if ra.bin_check == ra.bin_check:
            assert math.isclose(ra.bin_check, rb.bin_check, rel_tol=1e-9, abs_tol=1e-12), i


def _compare(log: Path, tmp_path: Path, *, bin_stages: bool = True,
             frames: tuple[int, int | None] = (0, None)) -> dict[str, Any]:
    one = _run(_open(log, tmp_path, bin_stages=bin_stages), 1, frames)
    two = _run(_open(log, tmp_path, bin_stages=bin_stages), 2, frames)
    _same_runs(one, two)
    # a second pass of the same session (frame 0 decoded and located anew) too
    session = _open(log, tmp_path, bin_stages=bin_stages)
    _run(session, 2, frames)
    _same_runs(one, _run(session, 2, frames))
    return one


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("two_cores")
    return {
        "zinc_nuts": write_synthetic_log(d / "zn.mcap", kind="zinc_nuts", frames=5, seed=17, size=(150, 200)),
        "spheres": write_synthetic_log(d / "sp.mcap", kind="spheres", frames=4, seed=4, size=(200, 320)),
    }


@pytest.mark.parametrize("kind", ["zinc_nuts", "spheres"])
def test_two_frames_in_flight_give_the_one_at_a_time_results(logs, tmp_path, kind):
    one = _compare(logs[kind], tmp_path)
    assert len(one["frames"]) >= 4 and any(g[3].zcut for g in one["frames"])
    assert all(g[2].get("bin_points") is not None for g in one["frames"])  # the bin stages ran


def test_without_the_bin_stages_and_on_a_frame_range(logs, tmp_path):
    _compare(logs["zinc_nuts"], tmp_path, bin_stages=False)
    one = _compare(logs["zinc_nuts"], tmp_path, frames=(1, 4))
    assert [g[0] for g in one["frames"]] == [1, 2, 3]


def test_large_invalid_regions_and_an_almost_empty_frame(logs, tmp_path):
    reader = LogReader(logs["spheres"])
    frames = list(reader.frames())
    rng = np.random.default_rng(5)
    out = tmp_path / "holes.mcap"
    with writer_like(reader, out) as w:
        for k, f in enumerate(frames):
            xyz = f.xyz.copy()
            h, wd = f.shape
            if k == 1:  # blobs of invalid pixels over ~40 % of the image
                invalid_blobs(xyz, rng)
            elif k == 2:  # almost nothing valid: a few scattered points
                keep = rng.random((h, wd)) < 0.002
                xyz[~keep] = np.nan
            elif k == 3:  # the left half invalid
                xyz[:, : wd // 2] = np.nan
            w.write_frame(Frame(xyz=xyz, rgb=f.rgb, stamp_ns=f.stamp_ns, frame_id=f.frame_id,
                                intrinsics=f.intrinsics, topic=f.topic, index=f.index, masks=f.masks))
    one = _compare(out, tmp_path)
    assert len(one["frames"]) == len(frames)


def test_a_real_kinect_log(real_data, tmp_path):
    _compare(real_data / "mosd_clutter_kinect_ros2.mcap", tmp_path)


def test_a_truncated_log_keeps_the_frames_before_the_damage(logs, tmp_path):
    reader = LogReader(logs["zinc_nuts"])
    whole = tmp_path / "whole.mcap"
    with writer_like(reader, whole, chunk_size=1024) as w:  # a chunk per message
        for f in reader.frames():
            w.write_frame(f)
    raw = whole.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(raw[: int(len(raw) * 0.7)])
    one = _compare(cut, tmp_path)
    assert one["damage"] and 1 <= len(one["frames"]) < 5


class _Recorder(FrameSink):
    """Records the frames written, the thread that wrote each, and whether two writes overlapped."""

    def __init__(self) -> None:
        self.indices: list[int] = []
        self.threads: set[str] = set()
        self.inside = 0
        self.overlapped = False
        self.closed = False

    def start(self, info: ReplayStart) -> None:
        self.indices.clear()

    def write(self, frame: Frame, result: FrameResult) -> None:
        self.inside += 1
        self.overlapped |= self.inside > 1
        self.indices.append(frame.index)
        self.threads.add(threading.current_thread().name)
        self.inside -= 1

    def close(self, *, completed: bool) -> None:
        self.closed = completed

    def outputs(self) -> dict[str, str]:
        return {}


def test_the_sinks_see_the_frames_in_order_one_at_a_time(logs, tmp_path):
    sink, seen = _Recorder(), []
    summary = _open(logs["zinc_nuts"], tmp_path).run(sink, in_flight=2,
                                                      on_frame=lambda f, r, row: seen.append(f.index))
    assert sink.indices == seen == [0, 1, 2, 3, 4] == [r.index for r in summary.rows]
    assert sink.threads == {threading.current_thread().name} and not sink.overlapped and sink.closed
    serial = _open(logs["zinc_nuts"], tmp_path).run(in_flight=1)
    counts = ("valid_px", "zcut", "sor", "both", "above_rim", "clusters")
    assert [[getattr(r, c) for c in counts] for r in summary.rows] == [[getattr(r, c) for c in counts]
                                                                        for r in serial.rows]


def test_in_flight_must_be_positive(logs, tmp_path):
    from replay.errors import ConfigError

    with pytest.raises(ConfigError, match="in_flight"):
        _open(logs["zinc_nuts"], tmp_path).results(in_flight=0)


def test_a_consumer_that_stops_early_leaves_no_thread(logs, tmp_path):
    session = _open(logs["zinc_nuts"], tmp_path)
    stream = session.results(in_flight=2)
    got = [next(stream)[0].index, next(stream)[0].index]
    stream.close()
    assert got == [0, 1]
    names = {t.name.rsplit("_", 1)[0] for t in threading.enumerate()}
    assert not names & {"zcut-frame", "zcut-locate", "zcut-frame-reader"}
    # the session still runs a whole pass afterwards, the same as one frame at a time
    _same_runs(_run(session, 2), _run(_open(logs["zinc_nuts"], tmp_path), 1))


def test_a_frame_that_fails_raises_after_the_frames_before_it(logs, tmp_path, monkeypatch):
    import replay.pipeline.session as session_mod

    judge = session_mod.judge_zone

    def failing(frame, z, config, **kw):  # frame 2's methods fail (in its worker)
        if frame.index == 2:
            raise RuntimeError("frame 2 failed")
        return judge(frame, z, config, **kw)

    monkeypatch.setattr(session_mod, "judge_zone", failing)
    stream = _open(logs["zinc_nuts"], tmp_path).results(in_flight=2)
    got = []
    with pytest.raises(RuntimeError, match="frame 2 failed"):
        for frame, _ in stream:
            got.append(frame.index)
    stream.close()
    assert got == [0, 1]


def test_the_default_is_the_layers_unless_the_variable_says(logs, tmp_path, monkeypatch):
    """Unset, the layer's default (:func:`default_frames_in_flight`: 1 under the suite's workqueue layer, 2 under
    OpenMP's on two cores, tests/replay/pipeline/test_threading_layers.py); set, the variable's."""
    import numba

    from replay.errors import ConfigError
    from replay.pipeline.session import default_frames_in_flight, frames_in_flight

    monkeypatch.delenv("ZCUT_FRAMES_IN_FLIGHT", raising=False)
    assert frames_in_flight() == default_frames_in_flight()
    if numba.config.THREADING_LAYER_PRIORITY[0] == "workqueue" and numba.config.THREADING_LAYER == "default":
        assert frames_in_flight() == 1
    monkeypatch.setenv("ZCUT_FRAMES_IN_FLIGHT", "2")
    assert frames_in_flight() == 2
    sink = _Recorder()
    _open(logs["zinc_nuts"], tmp_path).run(sink)  # the variable's two frames in flight
    assert sink.indices == [0, 1, 2, 3, 4]
    for bad in ("0", "two", "-1"):
        monkeypatch.setenv("ZCUT_FRAMES_IN_FLIGHT", bad)
        with pytest.raises(ConfigError, match="ZCUT_FRAMES_IN_FLIGHT"):
            _open(logs["zinc_nuts"], tmp_path).results()
