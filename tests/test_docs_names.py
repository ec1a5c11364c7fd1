"""Every name the docs cite as code exists, and is used (docs/architecture.md; issue 34).

The pages of ``docs/`` and the README cite code two ways: a dotted name in backticks
(``replay.pipeline.config.resolve``, ``zcut.cuts.find_clusters``) and a file path
(``replay/pipeline/session.py``, ``bench/bench_sor.py``, ``annotate/static/``). A cited path must
exist; a cited dotted name must resolve — a module of the checkout, then a name defined or imported
at its top level, then a member of a class there — and the name must be referenced somewhere in the
code besides its definition (a function no one calls is not "the resolver every command calls").

Names are resolved statically (the files are parsed, not imported), so the test needs no optional
dependency and runs in a fraction of a second.
"""

from __future__ import annotations

import ast
import re
import subprocess
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("zcut", "replay", "annotate", "studies", "cli")
#: Folders whose files the docs cite by path.
CITED_FOLDERS = (*PACKAGES, "tests", "bench", "scripts")
#: The suffixes a cited path may end with (or a folder's ``/``).
PATH_SUFFIXES = (".py", ".sh", ".html", ".toml", "/")
#: Dotted names ending with these are file names (``cli.md``), not code.
FILE_SUFFIXES = {"md", "py", "toml", "mcap", "rrd", "json", "parquet", "html", "ply", "pcd", "lock", "sqlite"}

#: Cited names that are not code: keys of the config file's ``[zcut]`` table (docs/pipeline.md) and
#: of ZCutParams. The MCAP metadata records' names (``zcut.synth``, ...) are read from
#: replay/logs/layout.py.
CONFIG_KEYS = {f"zcut.{key}" for key in ("step_mm", "max_depth_mm", "rho_thr", "max_area_px", "a_max_px",
                                        "connectivity", "step", "max_depth", "max_area", "a_max")}
#: Paths of another repository that a page names as such (docs/real_data.md: the file the Ouster
#: log was re-encoded from, in ``virtual-vehicle/pointcloudset``).
FOREIGN_PATHS = {"tests/testdata/test.mcap"}

#: Cited names that exist only once the other branches of issue 34 are merged (the registry's zone
#: module and default axes, the pipeline's options, the log index, the studies' count columns, every
#: command in cli/commands/, the studies and accuracy as library calls, zcut/suspects/ as a package,
#: the page's group budget). Missing today, they are not failures; once
#: present, ``test_pending_names_are_still_pending`` asks for them to be taken off this list, so
#: that after the merge the list is empty and every name is checked.
PENDING: set[str] = set()

_PACKAGE = "|".join(PACKAGES)
_FOLDER = "|".join(CITED_FOLDERS)
_DOTTED = re.compile(rf"(?<![\w./\-])((?:{_PACKAGE})(?:\.[A-Za-z_]\w*)+)(?![\w/])")
_PATH = re.compile(rf"(?<![\w./\-])((?:{_FOLDER})/[\w./\-]*)")
_CODE_SPAN = re.compile(r"`([^`\n]+)`")


def _pages() -> list[Path]:
    return [*sorted((ROOT / "docs").glob("*.md")), ROOT / "README.md"]


def cited(text: str) -> tuple[set[str], set[str]]:
    """(dotted names in backticks, file paths anywhere) that ``text`` cites."""
    dotted = {m.group(1) for span in _CODE_SPAN.findall(text) for m in _DOTTED.finditer(span)
              if m.group(1).rsplit(".", 1)[1] not in FILE_SUFFIXES}
    paths = {p.rstrip(".") for p in _PATH.findall(text)}
    return dotted, {p for p in paths if p.endswith(PATH_SUFFIXES)}


def _citations() -> dict[str, list[str]]:
    """Every cited name -> the page:line places citing it."""
    where: dict[str, list[str]] = {}
    for page in _pages():
        for lineno, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1):
            dotted, paths = cited(line)
            for name in dotted | paths:
                where.setdefault(name, []).append(f"{page.relative_to(ROOT)}:{lineno}")
    return where


def _code_words(tree: ast.AST) -> set[str]:
    """The names a module's code uses: names read, attributes, imported modules and names, and
    identifier-like strings (a registry key, a ``getattr``) — not what it defines, not its docstrings
    or comments."""
    docstrings = {id(n.body[0].value) for n in ast.walk(tree)
                  if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                  and n.body and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)}
    words: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name) and not isinstance(node.ctx, ast.Store):
            words.add(node.id)
        elif isinstance(node, ast.Attribute):
            words.add(node.attr)
        elif isinstance(node, ast.Import):
            words.update(w for a in node.names for w in a.name.split("."))
        elif isinstance(node, ast.ImportFrom):
            words.update((node.module or "").split("."))
            words.update(a.name for a in node.names)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings:
            words.update(re.findall(r"\w+", node.value) if len(node.value) < 200 else ())
    return words


@cache
def _word_users() -> dict[str, set[str]]:
    """Every name the tracked code uses -> the files using it (Python files by their syntax tree;
    scripts, configs and the page's files by their words)."""
    out = subprocess.run(["git", "ls-files", "-z", "*.py", "*.sh", "*.toml", "*.html", "*.js"], cwd=ROOT,
                         capture_output=True, check=True)
    users: dict[str, set[str]] = {}
    for name in out.stdout.decode().split("\0"):
        path = ROOT / name
        if not (name and path.is_file()) or path == Path(__file__).resolve():  # its names are examples
            continue
        text = path.read_text(encoding="utf-8", errors="replace")
        words = _code_words(ast.parse(text)) if name.endswith(".py") else set(re.findall(r"\w+", text))
        for word in words:
            users.setdefault(word, set()).add(name)
    return users


@cache
def _parse(path: Path) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"), filename=str(path))


def _module_file(dotted: str) -> Path | None:
    base = ROOT.joinpath(*dotted.split("."))
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _defined(body: list[ast.stmt], name: str) -> int | None:
    """The line defining (or importing) ``name`` among ``body``'s statements, or None."""
    for node in body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and node.name == name:
            return node.lineno
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == name for t in node.targets):
            return node.lineno
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and node.target.id == name:
            return node.lineno
        if isinstance(node, (ast.Import, ast.ImportFrom)) and any(
                (a.asname or a.name.split(".")[0]) == name for a in node.names):
            return node.lineno
        if isinstance(node, ast.If):  # e.g. TYPE_CHECKING or a platform switch
            line = _defined(node.body + node.orelse, name)
            if line is not None:
                return line
    return None


def resolve(dotted: str) -> tuple[Path, int | None] | str:
    """(defining file, line — None for a module) of a dotted name, or why it does not resolve."""
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        module = _module_file(".".join(parts[:i]))
        if module is None:
            continue
        rest = parts[i:]
        if not rest:
            return module, None
        body = _parse(module).body
        line = _defined(body, rest[0])
        if line is None:
            return f"{'.'.join(parts[:i])} has no {rest[0]}"
        if len(rest) == 1:
            return module, line
        cls = next((n for n in body if isinstance(n, ast.ClassDef) and n.name == rest[0]), None)
        if cls is None or len(rest) > 2:
            return f"cannot look inside {'.'.join(parts[:i + 1])}"
        line = _defined(cls.body, rest[1])
        return (module, line) if line is not None else f"{'.'.join(parts[:i + 1])} has no {rest[1]}"
    return "no such module"


def used(dotted: str, module: Path, line: int | None) -> bool:
    """Whether the code uses the last part of ``dotted`` (a module: outside the module itself)."""
    files = _word_users().get(dotted.rsplit(".", 1)[1], set())
    return bool(files - {str(module.relative_to(ROOT))}) if line is None else bool(files)


def _metadata_names() -> set[str]:
    """The MCAP metadata records' names (``zcut.synth`` ...): strings, not code."""
    tree = _parse(ROOT / "replay" / "logs" / "layout.py")
    return {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)
            and n.value.startswith(PACKAGES)}


def problem(name: str) -> str | None:
    """Why a cited name is wrong, or None."""
    if "/" in name:
        if name in FOREIGN_PATHS:
            return None
        return None if (ROOT / name).exists() else "no such file"
    if name in CONFIG_KEYS or name in _metadata_names():
        return None
    found = resolve(name)
    if isinstance(found, str):
        return found
    module, line = found
    return None if used(name, module, line) else "defined but used nowhere"


def test_every_name_the_docs_cite_as_code_exists_and_is_used():
    wrong = [f"{name}: {why} (cited at {', '.join(places)})"
             for name, places in sorted(_citations().items()) if name not in PENDING
             if (why := problem(name)) is not None]
    assert wrong == [], "names the docs cite as code that are wrong:\n" + "\n".join(wrong)


#: Docstrings that cite a name that is gone or unused, in files other branches of issue 34 own (each
#: with its fix): taken off as they are fixed (``test_known_stale_docstrings_are_still_stale``).
KNOWN_STALE: set[str] = set()

_ROLE = re.compile(rf":(?:func|class|mod|meth|data|attr|exc):`~?(?:[^`<]*<)?((?:{_PACKAGE})\.[\w.]+)>?`")
_LITERAL = re.compile(rf"``((?:{_PACKAGE})(?:\.[A-Za-z_]\w*)+)``")


def _docstring_citations() -> dict[str, list[str]]:
    """Every fully qualified name the code's docstrings and comments cite (a Sphinx role, or a
    ``pkg.module.name`` literal) -> the file:line places citing it."""
    out = subprocess.run(["git", "ls-files", "-z", "*.py"], cwd=ROOT, capture_output=True, check=True)
    where: dict[str, list[str]] = {}
    for name in out.stdout.decode().split("\0"):
        if not name.endswith(".py") or not (ROOT / name).is_file():
            continue
        for lineno, line in enumerate((ROOT / name).read_text(encoding="utf-8").splitlines(), 1):
            for cite in {*_ROLE.findall(line), *_LITERAL.findall(line)}:
                cite = cite.rstrip(".")
                if cite.rsplit(".", 1)[1] not in FILE_SUFFIXES:
                    where.setdefault(cite, []).append(f"{name}:{lineno}")
    return where


def test_every_name_the_docstrings_cite_exists_and_is_used():
    wrong = [f"{name}: {why} (cited at {', '.join(places)})"
             for name, places in sorted(_docstring_citations().items()) if name not in KNOWN_STALE
             if (why := problem(name)) is not None]
    assert wrong == [], "names the docstrings cite that are wrong:\n" + "\n".join(wrong)


def test_known_stale_docstrings_are_still_stale():
    """A name of :data:`KNOWN_STALE` no docstring cites any more, or that is now right: take it off."""
    cites = _docstring_citations()
    fixed = sorted(name for name in KNOWN_STALE if name not in cites or problem(name) is None)
    assert fixed == [], f"fixed: remove them from KNOWN_STALE: {fixed}"


def test_pending_names_are_still_pending():
    """A name of :data:`PENDING` that now exists has arrived: take it off the list."""
    arrived = sorted(name for name in PENDING if problem(name) is None)
    assert arrived == [], f"these cited names exist now: remove them from PENDING: {arrived}"


def test_pending_names_are_cited():
    assert PENDING <= set(_citations()), sorted(PENDING - set(_citations()))


@pytest.mark.parametrize(("text", "dotted", "paths"), [
    ("by `replay.pipeline.config.resolve` (from `zcut/cuts.py`)", {"replay.pipeline.config.resolve"},
     {"zcut/cuts.py"}),
    ("topics `/zcut/outliers` and `/zcut/valid`, file `DIR/.zcut.lock`", set(), set()),
    ("see `cli.md` and docs/cli.md; `tuned.zcut.f1` is a key", set(), set()),
    ("plain zcut/binmask.py, a folder `replay/synth/`, `zcut.params.ZCutParams`", {"zcut.params.ZCutParams"},
     {"zcut/binmask.py", "replay/synth/"}),
])
def test_what_counts_as_a_citation(text, dotted, paths):
    assert cited(text) == (dotted, paths)


def test_a_stale_name_is_caught():
    assert problem("replay.pipeline.config.no_such_function") == "replay.pipeline.config has no no_such_function"
    assert problem("replay/pipeline/no_such_module.py") == "no such file"
    assert problem("zcut.cuts.find_clusters") is None
    assert problem("zcut.params.ZCutParams.step") is None  # a dataclass field
