"""An output folder removed while zcut writes into it (issue 35 #8): one line naming the output, exit 1,
nothing left behind; never Rerun's RuntimeError traceback."""

from __future__ import annotations

import shutil

import pytest
from cli_helpers import run_cli

from replay.outputs import AtomicOutput, OutputError
from replay.pipeline import sinks
from replay.synth.log import write_synthetic_log


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    return write_synthetic_log(tmp_path_factory.mktemp("logs") / "s.mcap", kind="rods", frames=1, seed=3,
                               size=(120, 160))


class _FolderRemovedAfterTemp(AtomicOutput):
    """The folder is removed just after the temporary is made: the moment Rerun then opens it."""

    def __init__(self, path) -> None:
        super().__init__(path)
        if str(path).endswith(".rrd"):
            shutil.rmtree(self.path.parent)


def test_replay_rrd_into_a_folder_removed_meanwhile_is_one_line(tmp_path, capsys, log, monkeypatch):
    out = tmp_path / "out"
    out.mkdir()
    monkeypatch.setattr(sinks, "AtomicOutput", _FolderRemovedAfterTemp)
    rc, _, err = run_cli(capsys, "replay", log, "--rrd", out / "r.rrd")
    assert rc == 1
    lines = [ln for ln in err.splitlines() if not ln.startswith("zcut: ")]
    assert lines == [f"error: {out / 'r.rrd'}: its folder {out} was removed while zcut wrote it; the output was "
                     "not written and nothing of it is left"], err
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == []


def test_an_atomic_output_whose_folder_went_names_the_output(tmp_path):
    folder = tmp_path / "gone"
    folder.mkdir()
    shutil.rmtree(folder)
    with pytest.raises(OutputError, match=rf"^{folder / 'x.toml'}: its folder {folder} was removed"):
        AtomicOutput(folder / "x.toml")
    folder.mkdir()
    a = AtomicOutput(folder / "y.toml")
    shutil.rmtree(folder)
    with pytest.raises(OutputError, match=rf"^{folder / 'y.toml'}: its folder {folder} was removed"):
        a.commit()
