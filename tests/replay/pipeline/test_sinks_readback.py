"""The outputs read back the same after the round of 2026-12-05d (docs/performance.md, "The outputs, round of
2026-12-05d"): the class tables' AnnotationContexts are built in Arrow instead of by the SDK's converter, and the
sinks load their libraries when they are made. The previous way (the SDK's ``rr.AnnotationContext`` of
``rr.AnnotationInfo`` s, every sink fed in the calling thread) is kept here as the reference, and a replay of two
part kinds is written both ways: every row of the .rrd (its entities, timelines and component arrays) and every
message of the results file (its masks and codes, byte for byte) read back equal.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import rerun as rr
from log_helpers import rrd_rows as log_rrd_rows
from mcap.reader import make_reader
from subprocess_helpers import run_python

from replay.logs import layout
from replay.logs import ros2_msgs as rm
from replay.pipeline import compare_viz, rerun_arrow, viz
from replay.pipeline.bin_model import bin_model_for
from replay.pipeline.session import ReplaySession
from replay.pipeline.sinks import BackgroundSinks, FrameSink, RerunSink, ResultsSink

ROOT = Path(__file__).resolve().parents[3]
TABLES = ("OUTLIER_CLASSES", "REMOVAL_CLASSES", "METHOD_CLASSES", "BIN_MASK_CLASSES", "BIN_CHECK_CLASSES",
          "VERDICT_CLASSES", "EXPLAINED_CLASSES")


def sdk_ctx(classes):
    """The SDK's own converter, which ``rerun_arrow.class_context`` replaces."""
    return rr.AnnotationContext([rr.AnnotationInfo(id=0, label="none", color=(0, 0, 0, 0))]
                                + [rr.AnnotationInfo(id=i, label=name, color=col) for i, name, col in classes])


@pytest.mark.parametrize("table", [(viz, t) for t in TABLES]
                         + [(compare_viz, "VERDICT_CLASSES"), (compare_viz, "DIFF_CLASSES")],
                         ids=lambda t: f"{t[0].__name__.rsplit('.', 1)[1]}.{t[1]}")
def test_a_class_table_context_is_the_sdks(table):
    classes = getattr(*table)
    ours, theirs = rerun_arrow.class_context(classes).as_component_batches(), sdk_ctx(classes).as_component_batches()
    assert len(ours) == len(theirs) == 1
    a, b = ours[0].as_arrow_array(), theirs[0].as_arrow_array()
    assert a.type == b.type
    assert a.equals(b), (a.to_pylist(), b.to_pylist())
    assert ours[0].component_descriptor() == theirs[0].component_descriptor()


def test_an_empty_and_a_one_class_table():
    for classes in ((), ((7, "seven", (1, 2, 3)),)):
        assert rerun_arrow.class_context(classes).as_component_batches()[0].as_arrow_array().equals(
            sdk_ctx(classes).as_component_batches()[0].as_arrow_array())


class InOrder:
    """The sinks fed one after the other in the calling thread (no worker thread)."""

    def __init__(self, sinks: list[FrameSink]) -> None:
        self.sinks = sinks

    def start(self, info):
        for s in self.sinks:
            s.start(info)

    def write(self, frame, result):
        for s in self.sinks:
            s.write(frame, result)

    def close(self, *, completed):
        for s in self.sinks:
            s.close(completed=completed)

    def outputs(self):
        return {k: v for s in self.sinks for k, v in s.outputs().items()}


def rrd_rows(path) -> dict[str, list[str]]:
    """The recording's rows by entity, each with its static flag (:func:`log_helpers.rrd_rows`)."""
    return log_rrd_rows(path, static=True)


def results_messages(path) -> list[tuple[str, int, bytes]]:
    with open(path, "rb") as f:
        return [(ch.topic, m.log_time, bytes(m.data)) for _, ch, m in make_reader(f).iter_messages()]


class Keep(InOrder):
    """Keeps every frame and result (to feed both ways the same ones: the stage timings differ from run to run)."""

    def __init__(self) -> None:
        super().__init__([])
        self.pairs: list = []

    def write(self, frame, result):
        self.pairs.append((frame, result))


@pytest.fixture(scope="module", params=["spheres", "zinc_nuts"])
def written(request, tmp_path_factory):
    """A replay of a two-frame log of the kind, its frames and results written both ways: {way: (rrd, results)}."""
    from cli_helpers import synth_log

    d = tmp_path_factory.mktemp(f"readback_{request.param}")
    log = synth_log(d / "s.mcap", parts=request.param, frames=2, seed=6421, size="384x240")
    session = ReplaySession.open(log, choose_bin_model=lambda r: bin_model_for(r, None))
    kept = Keep()
    session.run(kept)
    assert len(kept.pairs) == 2
    info = session.start_info(None)
    out = {}
    with pytest.MonkeyPatch.context() as mp:
        for way in ("previous", "now"):
            if way == "previous":
                mp.setattr(viz, "class_context", sdk_ctx)
            else:
                mp.undo()
            paths = (d / f"{way}.rrd", d / f"{way}.mcap")
            sinks: list[FrameSink] = [RerunSink(rrd=paths[0]), ResultsSink(paths[1])]
            both = InOrder(sinks) if way == "previous" else BackgroundSinks(sinks)
            both.start(info)
            for frame, result in kept.pairs:
                both.write(frame, result)
            both.close(completed=True)
            assert set(both.outputs()) == {"rrd", "results"}
            out[way] = paths
    return out


def test_the_recording_reads_back_the_same(written):
    before, now = rrd_rows(written["previous"][0]), rrd_rows(written["now"][0])
    assert set(before) == set(now)
    for entity in before:
        assert before[entity] == now[entity], entity
    # the class tables among them (static), and the per-frame images
    assert any('"static": true' in row for row in now["/image/outliers"])
    assert "/image/rgb" in now and "/world/cloud" in now


def test_the_results_file_reads_back_the_same(written):
    before, now = results_messages(written["previous"][1]), results_messages(written["now"][1])
    assert before == now
    masks = [rm.image_to_mask(rm.decode_image(data, where="x"), where="x")
             for topic, _, data in now if topic == layout.ZCUT_OUTLIERS]
    assert len(masks) == 2 and all(m.shape == (240, 384) for m in masks)


def test_a_compare_recording_does_not_load_pyarrow_compute(tmp_path):
    """``zcut compare``'s recording logs its class tables, images, points and series without the SDK's
    converter that imports ``pyarrow.compute`` (the previous ``compare_viz`` did: ~30 CPU ms a process)."""
    code = ("import sys\nimport numpy as np\nfrom replay.pipeline.sinks import RrdFile\n"
            "from replay.pipeline.compare_viz import CompareRecording\n"
            f"rrd = RrdFile({str(tmp_path / 'c.rrd')!r})\n"
            "rec = CompareRecording(rrd, label_a='A', label_b='B', config_markdown='x')\n"
            "v = np.zeros((4, 5), np.uint8)\n"
            "rec.frame(0, 0, jpeg=None, image=v, points=np.zeros((2, 3), np.float32), point_ids=np.ones(2, np.uint8),\n"
            "          verdict_a=v, verdict_b=v, diff=v, scalars={'a/scalars/f1': 0.5})\n"
            "print('pyarrow.compute' in sys.modules)\n")
    out = run_python(code, cwd=ROOT, timeout=300)
    assert out.returncode == 0 and out.stdout.strip() == "False", out.stderr


def test_a_rerun_sink_loads_rerun_when_it_is_made():
    code = ("import sys\nfrom replay.pipeline.sinks import RerunSink, ResultsSink\n"
            "assert 'rerun' not in sys.modules and 'replay.logs.writer' not in sys.modules\n"
            "RerunSink(rrd='never_written.rrd')\nResultsSink('never_written.mcap')\n"
            "assert 'rerun' in sys.modules and 'replay.logs.writer' in sys.modules\n"
            "print('ok')\n")
    out = run_python(code, cwd=ROOT, timeout=300)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr
