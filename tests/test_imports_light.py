"""The command line loads heavy libraries only where a command uses them (issue 32, fixed costs).

``import cli.main``, ``zcut --help`` and ``zcut --version`` load none of Open3D (~1 CPU-s with the
Dash and Plotly it imports), Rerun, pyarrow or pandas; a command's ``--help`` loads none of them
either (it may load numpy and the method table), and a replay without outputs loads Rerun and
pyarrow not at all. Each is checked in a fresh interpreter (``sys.modules`` at its end).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from subprocess_helpers import run_python

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("open3d", "rerun", "pyarrow", "pandas", "sklearn", "matplotlib", "dash", "plotly")


def _loaded(code: str) -> list[str]:
    """The :data:`HEAVY` modules in ``sys.modules`` after ``code`` ran in a fresh interpreter."""
    probe = (f"{code}\nimport sys\n"
             f"print(','.join(m for m in {HEAVY!r} if m in sys.modules), file=sys.__stderr__)\n")
    out = run_python(probe, cwd=ROOT, timeout=300)
    assert out.returncode == 0, out.stderr
    last = out.stderr.strip().splitlines()[-1] if out.stderr.strip() else ""
    return [m for m in last.split(",") if m]


def _main(*argv: str) -> str:
    return ("import sys\n"
            f"sys.argv = ['zcut', *{list(argv)!r}]\n"
            "import cli.main\n"
            "try:\n    cli.main.main()\nexcept SystemExit:\n    pass\n")


def test_import_cli_main_loads_no_heavy_library() -> None:
    assert _loaded("import cli.main") == []


@pytest.mark.parametrize("argv", [("--help",), ("--version",), ("replay", "--help"), ("batch", "--help"),
                                  ("compare", "--help"), ("synth", "--help")])
def test_help_loads_no_heavy_library(argv: tuple[str, ...]) -> None:
    assert _loaded(_main(*argv)) == []


def test_replay_without_outputs_loads_neither_rerun_nor_pyarrow(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # an empty bin model cache: the first replay prepares the model, with Open3D (a replay whose prepared model
    # comes from the cache loads no Open3D at all: tests/cli/test_startup.py)
    monkeypatch.setenv("ZCUT_CACHE", str(tmp_path / "cache"))
    log = tmp_path / "small.mcap"  # the input, made in this process (what is checked is the replay's process)
    from cli.main import main

    assert main(["synth", "-o", str(log), "--size", "64x48"]) == 0
    loaded = _loaded(_main("replay", str(log)))
    assert not {"rerun", "pyarrow", "pandas", "sklearn", "matplotlib"} & set(loaded), loaded
    # nor the methods it does not run, nor SciPy's graphs (0.05 CPU-s); scipy.ndimage (0.15) is loaded by the
    # bin check when it needs it, as on this tiny frame, not on the 1920 x 1200 ones of docs/performance.md
    unused_parts = ("scipy.sparse.csgraph", "zcut.suspects", "zcut.components", "zcut.local_rules", "zcut.radius")
    probe = (_main("replay", str(log))
             + f"print(sorted(m for m in {unused_parts!r} if m in sys.modules), file=sys.__stderr__)\n")
    unused = run_python(probe, cwd=ROOT, timeout=300)
    assert unused.returncode == 0 and unused.stderr.strip().splitlines()[-1] == "[]", unused.stderr[-2000:]
    # the replay prepared the bin model with Open3D, without the Dash and Plotly its viewer imports
    assert "open3d" in loaded and not {"dash", "plotly"} & set(loaded), loaded


def test_open3d_without_plotly_in_a_commands_process() -> None:
    """After the command line's process settings, Open3D loads without Dash and Plotly, its ICP
    works, and its Plotly viewer says in one error why it is not there."""
    code = ("from replay.process import configure_process\n"
            "configure_process()\n"
            "import numpy as np, open3d as o3d\n"
            "pts = o3d.utility.Vector3dVector(np.random.default_rng(0).random((200, 3)))\n"
            "a = o3d.geometry.PointCloud(pts)\n"
            "b = o3d.geometry.PointCloud(pts).translate((0.01, 0, 0))\n"
            "r = o3d.pipelines.registration.registration_icp(a, b, 0.05)\n"
            "assert abs(r.transformation[0, 3] - 0.01) < 1e-6, r.transformation\n"
            "try:\n    o3d.visualization.draw_plotly([a])\nexcept RuntimeError as e:\n"
            "    assert 'not loaded in a zcut command' in str(e), e\n"
            "else:\n    raise AssertionError('draw_plotly ran')\n")
    loaded = _loaded(code)
    assert "open3d" in loaded and not {"dash", "plotly"} & set(loaded), loaded


def test_open3d_imported_first_keeps_its_plotly_viewer() -> None:
    """A process that imported Open3D before the settings keeps Open3D's own module."""
    code = ("import open3d\n"
            "from replay.process import configure_process\n"
            "configure_process()\n"
            "from open3d.visualization import draw_plotly\n"
            "assert draw_plotly.__module__ == 'open3d.visualization.draw_plotly'\n"
            "import sys\n"
            "assert hasattr(sys.modules['open3d.visualization.draw_plotly'], 'Dash'), 'the stand-in took its place'\n")
    assert {"open3d", "dash"} <= set(_loaded(code))


def test_zcut_names_load_their_module_alone() -> None:
    """``from zcut import ZCutParams`` (and ``import zcut.errors``, which every layer's errors import)
    loads neither numba nor SciPy: ``zcut/__init__.py`` imports each name from its module when it is
    first used (docs/performance.md, "Fixed costs")."""
    code = ("import sys\nimport zcut.errors\nfrom zcut import ZCutParams, ParameterError\n"
            "assert ZCutParams.__module__ == 'zcut.params'\n"
            "print(sorted(m for m in ('numba', 'scipy', 'cv2', 'zcut.cuts', 'zcut.suspects') if m in sys.modules))")
    out = run_python(code, cwd=ROOT, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]", out.stdout


def test_zcut_names_are_their_modules_objects() -> None:
    """Every name the package exports (its ``__all__``) is the object of the module it comes from, whatever was imported
    first; ``zcut.suspects`` stays the function once the subpackage is imported; submodules are
    attributes (``zcut.types`` is zcut's, not the standard library's); an unknown name is an
    AttributeError."""
    code = r'''
import importlib, sys, types
import zcut
assert zcut.types.__name__ == "zcut.types", zcut.types
import zcut.suspects.detectors
from zcut import suspects
assert isinstance(suspects, types.FunctionType) and suspects is zcut.suspects, suspects
from zcut import *  # noqa: F403
for name in zcut.__all__:
    module = importlib.import_module("zcut." + zcut._EXPORTS[name])
    assert getattr(zcut, name) is getattr(module, name), name
    assert globals()[name] is getattr(module, name), name
assert zcut.removal.__name__ == "zcut.removal"
try:
    zcut.no_such_name
except AttributeError as e:
    assert "no_such_name" in str(e), e
else:
    raise AssertionError("zcut.no_such_name")
print("ok")
'''
    out = run_python(code, cwd=ROOT, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"
