"""The layout of the packages and the rule it keeps (README, "Layout").

Dependencies point down: zcut <- replay <- annotate <- studies <- cli. zcut imports no I/O, viewer or
database and holds no mutable module state; the console script (``cli.main``) is the one composition
root; ``replay/pipeline/viz.py`` is the only module that imports rerun.
"""

from __future__ import annotations

import ast
import functools
import subprocess
import sys
from pathlib import Path

from subprocess_helpers import run_python

ROOT = Path(__file__).resolve().parents[1]
#: The packages from the bottom up: a package may import those below it, never one above.
LAYERS = ("zcut", "replay", "annotate", "studies", "cli")


@functools.cache
def _parsed(path: Path) -> ast.Module:
    """The syntax tree of a package file, parsed once per session: the checks below only read it (each
    check parsed every file of the packages again, ~1.9 s a check)."""
    return ast.parse(path.read_text(), filename=str(path))


def _imports(path: Path, tree: ast.Module | None = None) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in a file (``tree``: its syntax tree, else parsed
    here): at module level, inside functions, under ``if TYPE_CHECKING`` alike (relative imports stay
    inside their package)."""
    found = []
    for node in ast.walk(tree if tree is not None else ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.lineno, node.module))
    return found


def _package_files():
    for pkg in LAYERS:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            yield pkg, path


@functools.cache
def _package_imports() -> tuple[tuple[str, Path, int, str], ...]:
    """(package, path, line, module) of every import of every package file, found once per session."""
    return tuple((pkg, path, line, module) for pkg, path in _package_files()
                 for line, module in _imports(path, _parsed(path)))


def test_importing_zcut_keeps_io_modules_out():
    code = (
        "import sys, zcut, zcut.cloud\n"
        "import pkgutil, importlib\n"
        "for m in pkgutil.iter_modules(zcut.__path__): importlib.import_module('zcut.' + m.name)\n"
        "bad = [m for m in ('rerun', 'mcap', 'mcap_ros2', 'sqlite3', 'fastapi', 'starlette') if m in sys.modules]\n"
        "print(','.join(bad))\n"
    )
    out = run_python(code, check=True)
    assert out.stdout.strip() == "", f"zcut pulled in: {out.stdout.strip()}"


def test_cli_help_works():
    out = subprocess.run([sys.executable, "-m", "cli", "--help"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "zcut" in out.stdout


def test_cli_usage_error_exits_1_with_one_line():
    out = subprocess.run(
        [sys.executable, "-m", "cli", "synth", "-o", "never.mcap", "--no-such-flag"], capture_output=True, text=True
    )
    assert out.returncode == 1
    assert out.stderr.strip().splitlines()[-1].startswith("error: unrecognized arguments")
    assert "Traceback" not in out.stderr


def test_zcut_modules_hold_no_mutable_module_level_state():
    """zcut is pure: no caches or registries at module level (state an algorithm needs across frames
    is an object built once and passed in, e.g. zcut.bin_model.PreparedBinModel)."""
    code = r'''
import importlib, pkgutil, types, sys
import numpy as np
import zcut
bad = []
for m in pkgutil.iter_modules(zcut.__path__):
    mod = importlib.import_module("zcut." + m.name)
    for name, v in vars(mod).items():
        if name.startswith("__"):
            continue
        if isinstance(v, (dict, list, set, bytearray)) and name != "__all__":
            bad.append(f"{mod.__name__}.{name}: {type(v).__name__}")
        elif isinstance(v, np.ndarray) and v.flags.writeable:
            bad.append(f"{mod.__name__}.{name}: writable ndarray")
print("\n".join(bad))
'''
    out = run_python(code, check=True)
    assert out.stdout.strip() == "", f"mutable module-level state in zcut:\n{out.stdout}"


def test_importing_zcut_changes_no_global_setting():
    code = (
        "import os, numba, numpy, scipy.ndimage, cv2  # third-party imports change what they change\n"
        "before = (dict(os.environ), list(numba.config.THREADING_LAYER_PRIORITY), numba.config.THREADING_LAYER)\n"
        "import pkgutil, importlib, zcut\n"
        "for m in pkgutil.iter_modules(zcut.__path__): importlib.import_module('zcut.' + m.name)\n"
        "after = (dict(os.environ), list(numba.config.THREADING_LAYER_PRIORITY), numba.config.THREADING_LAYER)\n"
        "print(before == after)\n"
    )
    env = {k: v for k, v in __import__("os").environ.items() if not k.startswith("NUMBA_THREADING")}
    out = run_python(code, env=env, check=True)
    assert out.stdout.strip() == "True"


def test_the_console_script_is_the_one_composition_root():
    """cli.main imports every command module of cli/commands/ explicitly (common.py is their shared options)."""
    tree = ast.parse((ROOT / "cli" / "main.py").read_text())
    imported = {f"{n.module}.{a.name}" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module
                for a in n.names}
    commands = {f"cli.commands.{p.stem}" for p in (ROOT / "cli" / "commands").glob("*.py")
                if p.stem not in ("__init__", "common")}
    assert commands <= imported, f"not in the command table: {sorted(commands - imported)}"
    assert "import_module" not in (ROOT / "cli" / "main.py").read_text()


#: The library: what a benchmark, a test or another program calls without a command line.
LIBRARY = ("zcut", "replay", "annotate", "studies")


def _is_command_line(module: str) -> bool:
    """argparse, the cli package, or any package's ``commands`` module."""
    return module.split(".")[0] in ("argparse", "cli") or "commands" in module.split(".")


def test_the_library_imports_no_command_line():
    """Every command and its options live in cli/ (issue 34): the library takes options objects
    (``studies.sweep.SweepOptions``, ``studies.batch.BatchOptions``, ``annotate.accuracy.AccuracyOptions``),
    never an argparse Namespace, and no package of it has a ``commands`` module."""
    found = [f"{path.relative_to(ROOT)}:{line} imports {module}" for pkg, path, line, module in _package_imports()
             if pkg in LIBRARY and _is_command_line(module)]
    assert found == [], "the library imports a command line:\n" + "\n".join(found)
    modules = sorted(str(p.relative_to(ROOT)) for pkg in LIBRARY for p in (ROOT / pkg).rglob("commands*"))
    assert modules == [], f"commands outside cli/: {modules}"


def test_the_command_line_check_sees_argparse_and_commands(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("import argparse\nfrom replay.commands import common\ndef f():\n    from cli.commands import sweep\n")
    assert [m for _, m in _imports(f) if _is_command_line(m)] == ["argparse", "replay.commands", "cli.commands"]


def test_replaying_a_real_log_does_not_import_the_scene_generator():
    code = (
        "import sys\n"
        "from replay.pipeline import config, session, stages, sinks\n"
        "from cli.commands import replay\n"
        "print([m for m in sys.modules if m.startswith('replay.synth')])\n"
    )
    out = run_python(code, check=True)
    assert out.stdout.strip() == "[]"


def test_no_package_imports_one_above_it():
    """zcut < replay < annotate < studies < cli: an import that points up is a cycle waiting to
    happen (and drags a higher layer's dependencies into a lower one's users)."""
    rank = {pkg: i for i, pkg in enumerate(LAYERS)}
    up = [f"{path.relative_to(ROOT)}:{line} imports {module}" for pkg, path, line, module in _package_imports()
          if rank.get(module.split(".")[0], -1) > rank[pkg]]
    assert up == [], "imports that point up the layers:\n" + "\n".join(up)


def test_the_pipeline_imports_nothing_from_the_scene_generator():
    """replay/pipeline sits below replay/synth: the generator may use the pipeline (a sample's bin
    model), never the other way (a frame's true pose is decoded by replay.logs.poses)."""
    up = [f"{path.relative_to(ROOT)}:{line} imports {module}"
          for path in sorted((ROOT / "replay" / "pipeline").rglob("*.py"))
          for line, module in _imports(path, _parsed(path))
          if module == "replay.synth" or module.startswith("replay.synth.")]
    assert up == [], "replay/pipeline imports replay/synth:\n" + "\n".join(up)


def test_the_layout_check_sees_imports_inside_functions(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("import os\ndef f():\n    from studies.grid import x\n    import cli.main\n")
    assert [m for _, m in _imports(f)] == ["os", "studies.grid", "cli.main"]


def test_every_package_is_on_the_layer_list():
    packages = {p.parent.name for p in ROOT.glob("*/__init__.py")}
    assert packages == set(LAYERS), f"packages not on the layer list: {sorted(packages - set(LAYERS))}"


def test_only_the_viewer_module_imports_rerun():
    """Rerun (its SDK, its threads, its 4 GB of address space) stays behind replay/pipeline/viz.py (and
    compare_viz.py, the recording of ``zcut compare``, and rerun_arrow.py, the class tables both log)."""
    importers = sorted({str(path.relative_to(ROOT)) for _, path, _, module in _package_imports()
                        if module.split(".")[0] == "rerun"})
    assert importers == ["replay/pipeline/compare_viz.py", "replay/pipeline/rerun_arrow.py", "replay/pipeline/viz.py"]


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _module_graph() -> dict[str, set[str]]:
    """module -> the modules of the packages it imports (inside functions and under TYPE_CHECKING
    alike). ``from a import b`` counts as an import of ``a.b`` when that is a module. A package's
    ``__init__`` is its face, not a room: an import of it is not followed (it only hands names on)."""
    files = {_module_name(p): p for _, p in _package_files() if p.name != "__init__.py"}
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        edges = set()
        for node in ast.walk(_parsed(path)):
            if isinstance(node, ast.Import):
                edges |= {a.name for a in node.names if a.name in files}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                subs = {f"{node.module}.{a.name}" for a in node.names} & files.keys()
                edges |= subs or ({node.module} & files.keys())
        graph[name] = edges - {name}
    return graph


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_module_imports_itself_back():
    """No import circle between modules (issue 34): what two modules both need moves below both
    (docs/architecture.md, "The floors")."""
    assert _circles(_module_graph()) == []


def test_the_circle_check_sees_a_circle():
    assert _circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _circles({"a": {"b"}, "b": set()}) == []
