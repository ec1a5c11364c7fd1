"""A memory limit (``ulimit -v``) that a compiled extension cannot load under (Open3D, imported when
first needed) is one line and exit 1, like a MemoryError, not an ImportError's traceback."""

from __future__ import annotations

import resource
import subprocess
import sys

from cli.main import _out_of_memory, main


def test_an_extension_that_cannot_map_its_library_is_out_of_memory():
    try:
        try:
            raise ImportError("libOpen3D.so.0.20: failed to map segment from shared object", name="open3d.pybind")
        except ImportError as e:
            raise RuntimeError("while building the bin model") from e
    except RuntimeError as e:
        line = _out_of_memory(e)
    assert line is not None and line.startswith("not enough memory to load libOpen3D.so.0.20")
    assert _out_of_memory(ModuleNotFoundError("No module named 'open3d'")) is None  # a missing install stays a bug
    assert _out_of_memory(MemoryError()) == "not enough memory"


def test_bin_model_under_a_low_address_space_limit_is_one_line(tmp_path):
    log = tmp_path / "empty.mcap"
    assert main(["synth", "-o", str(log), "--empty", "--frames", "2", "--size", "128x96"]) == 0
    limit = 1_000_000 * 1024  # `ulimit -v 1000000`: numba and the kernels load, Open3D's library does not

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    r = subprocess.run([sys.executable, "-m", "cli", "bin-model", str(log), "-o", str(tmp_path / "b.ply")],
                       capture_output=True, text=True, timeout=600, preexec_fn=cap)
    assert "Traceback" not in r.stderr, r.stderr
    errors = [ln for ln in r.stderr.splitlines() if ln.startswith("error:")]
    assert r.returncode == 1 and len(errors) == 1 and "not enough memory" in errors[0], r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty.mcap"]
