"""An MCAP zcut writes through a temporary (replay's results, record's log) names its own file in its
``rosbag2`` record, never the temporary: the bytes of two runs into different folders are the same, as
``zcut synth``'s already are (tests/replay/synth/test_synth_log.py)."""

from __future__ import annotations

from pathlib import Path

from cli_helpers import run_cli
from mcap.reader import make_reader

from replay.synth.log import write_synthetic_log


def _bag(path: Path) -> str:
    """The ``rosbag2`` record's text (a results file has no cloud for a LogReader: read the MCAP itself)."""
    with open(path, "rb") as f:
        return next(dict(m.metadata)["serialized_metadata"] for m in make_reader(f).iter_metadata()
                    if m.name == "rosbag2")


def test_replay_results_name_their_own_file(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    log = write_synthetic_log(tmp_path / "scan.mcap", kind="zinc_nuts", frames=1, seed=5, size=(96, 128))
    outs = []
    for d in ("a", "b"):
        (tmp_path / d).mkdir()
        out = tmp_path / d / "res.mcap"
        rc, _, err = run_cli(capsys, "replay", log, "--out", out)
        assert rc == 0, err
        outs.append(out)
    bag = _bag(outs[0])
    assert "partial" not in bag
    assert "relative_file_paths:\n    - res.mcap\n" in bag and "    - path: res.mcap\n" in bag
    assert outs[0].read_bytes() == outs[1].read_bytes()


def test_recorded_log_names_its_own_file(tmp_path: Path, real_data: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    outs = []
    for d in ("a", "b"):
        (tmp_path / d).mkdir()
        out = tmp_path / d / "kinect.mcap"
        rc, _, err = run_cli(capsys, "record", real_data / "mosd_test16.pcd", "-o", out)
        assert rc == 0, err
        outs.append(out)
    bag = _bag(outs[0])
    assert "partial" not in bag
    assert "relative_file_paths:\n    - kinect.mcap\n" in bag and "    - path: kinect.mcap\n" in bag
    assert outs[0].read_bytes() == outs[1].read_bytes()
