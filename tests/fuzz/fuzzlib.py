"""Run hostile cases as the real ``zcut`` command under a time and a memory cap, and classify them.

A :class:`Case` is a command line (``argv`` for ``zcut``) plus the files it needs, laid out in a
folder of its own (:meth:`Case.materialize`): regular files, folders, FIFOs, symbolic and hard
links. :func:`run_cases` runs many cases, ``jobs`` at a time, and classifies each one
(:func:`classify`) into one of :data:`CLASSES`:

``clean``
    exit 0 or 3, or exit 1 with exactly one ``error: `` line on stderr; no traceback anywhere.
``traceback``
    a Python traceback on stderr (``Traceback (most recent call last)``, also from a thread).
``hang``
    still running at the time cap (killed with its whole process group).
``crash``
    killed by a signal (segfault, abort) that is not the memory cap.
``memory``
    the memory cap was hit: resident memory over ``mem_bytes`` (a watchdog polls the child every
    50 ms and kills it), or the address-space backstop (``RLIMIT_AS``: ``MemoryError``,
    ``std::bad_alloc``, "not enough memory", ENOMEM).
``loss-exit0``
    exit 0 although frames were lost: the command reported fewer frames than the intact source
    holds in the requested range (``Case.expect_frames``, counted from its own output).
``input-modified``
    an input file (or folder entry) was changed, replaced or removed (hashed before and after).
``bad-exit``
    an exit status outside 0, 1, 3, or exit 1 without exactly one ``error: `` line.
``leftover``
    a temporary file (``*.partial*``) was left beside an output.

Two ways to run a case (``mode``):

``fork``
    A *warm server*: a fresh interpreter (started once with ``subprocess``) imports the command
    line and the libraries its commands import lazily, and fills numba's target and typing contexts
    — never running or loading a numba kernel, so that no numba worker thread exists in it — then
    forks one child per case (one server may serve several :func:`run_cases` calls: ``runner``). The child sets its limits
    (``RLIMIT_AS`` = the server's address space + the budget, ``RLIMIT_FSIZE``, no core), points
    fds 0/1/2 at /dev/null and two files, and runs ``cli.main.main(argv)`` as the console script
    would (an uncaught exception prints its traceback and exits 1; non-daemon threads are joined and
    ``atexit`` functions run before ``os._exit``). The server lives in its own process, not in the
    test process, because pytest's process may already hold numba or Rerun threads. The server
    also watches the time and the resident memory of its children.
``subprocess``
    ``python -m cli ARGV`` per case, the same limits set in ``preexec_fn``.

The caller's process never imports the project's kernels for a case: it writes the case folder,
hashes the inputs, hands the command to the runner and classifies what came back.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import select
import shutil
import signal
import stat
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

CLASSES = ("clean", "traceback", "hang", "crash", "memory", "loss-exit0", "input-modified", "bad-exit", "leftover")
#: Default per-case caps: wall-clock seconds; resident memory (a watchdog polls the child's RSS every
#: 50 ms and kills it above this); address space on top of the warm process (``RLIMIT_AS``, a
#: backstop: Rerun alone reserves about 4 GB of address space for a tiny recording).
DEFAULT_TIMEOUT_S = 30.0
DEFAULT_MEM_BYTES = 3 << 30
DEFAULT_AS_BYTES = 8 << 30
_POLL_S = 0.05
#: Between the stack dump asked of a case at a cap (SIGUSR1) and its kill.
_DUMP_S = 0.25
#: What a subprocess case runs: the console script, with faulthandler dumping its stacks on SIGUSR1.
_SUBPROCESS_MAIN = ("import faulthandler, runpy, signal, sys; faulthandler.register(signal.SIGUSR1, all_threads=True); "
                    "sys.argv[0] = 'zcut'; runpy.run_module('cli.main', run_name='__main__', alter_sys=True)")
#: Largest file a case may write (RLIMIT_FSIZE): a small input must not fill the disk.
DEFAULT_FSIZE_BYTES = 1 << 30
#: What a case's stdout/stderr keep (the rest is cut).
KEEP_OUTPUT = 64 << 10

REPO = Path(__file__).resolve().parents[2]
PYTHON = sys.executable

#: Modules the warm server imports before forking (those the commands import inside ``run``);
#: none of them starts a thread at import, nothing here runs a numba kernel. Rerun starts threads
#: when imported: every child imports it for itself.
WARM_IMPORTS = (
    "cli.main", "numpy", "scipy.spatial", "scipy.ndimage", "cv2", "open3d", "threadpoolctl", "tomllib",
    "mcap.writer", "mcap.reader", "mcap_ros2.decoder", "zstandard", "lz4.frame", "isal.isal_zlib", "pypcd4",
    "plyfile", "sqlite3", "replay.logs.reader", "replay.logs.writer", "replay.logs.pcd", "replay.logs.ply",
    "replay.outputs", "replay.pipeline.config", "replay.pipeline.stages", "replay.pipeline.session",
    "replay.pipeline.bin_model", "annotate.store", "annotate.label_files", "annotate.accuracy", "replay.synth",
    "replay.synth.log",
    # what the commands' ``run`` imports in its turn (every case but the .rrd's, which import Rerun, paid these
    # imports, ~0.1-0.3 CPU s a case with no bytecode written)
    "cli.commands.common", "cli.commands.replay", "cli.commands.accuracy", "cli.commands.topics",
    "cli.commands.record", "cli.commands.bin_model", "cli.commands.labels", "cli.commands.synth", "scipy.optimize",
    "annotate.assistant", "annotate.budget", "annotate.groups", "annotate.judge", "annotate.truth",
    "replay.logs.part_model", "replay.pipeline.verdicts", "zcut.sor", "zcut.icp_fast", "zcut.columns",
    "zcut.components", "zcut.edge_surface", "zcut.grid_input", "zcut.suspects",
)


# ---------------------------------------------------------------------------------------------- cases
@dataclass
class Case:
    """One hostile run of ``zcut``.

    Attributes
    ----------
    id : str
        Unique and file-name safe, e.g. ``mcap_bytes-7-00012``.
    generator : str
        The generator that made it (a row of the report).
    what : str
        One line: what is hostile about it.
    argv : list of str
        ``zcut``'s arguments; paths are relative to the case folder (the command runs there).
    files : dict of str to bytes
        Regular files to create (relative path -> content).
    special : list of (kind, name, target)
        ``("dir", name, "")``, ``("fifo", name, "")``, ``("symlink", name, target)``,
        ``("hardlink", name, existing_name)``, created after ``files``.
    mutable : set of str
        Files the command may change (a label store on import, an output replaced with --force).
    expect_frames : int or None
        Frames in the requested range of the intact source log: exit 0 must report this many.
    count : str or None
        How the command reports frames: ``"check"`` (topics --check), ``"json"`` (replay --json),
        ``"table"`` (replay's table).
    timeout_s : float or None
        A longer cap for a case known to be slow (None: the run's cap).
    """

    id: str
    generator: str
    what: str
    argv: list[str]
    files: dict[str, bytes] = field(default_factory=dict)
    special: list[tuple[str, str, str]] = field(default_factory=list)
    mutable: set[str] = field(default_factory=set)
    expect_frames: int | None = None
    count: str | None = None
    timeout_s: float | None = None

    def materialize(self, folder: Path) -> None:
        """Create the case's files in ``folder`` (which must exist and be empty)."""
        for name, data in self.files.items():
            p = folder / name
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_bytes(data)
        for kind, name, target in self.special:
            p = folder / name
            p.parent.mkdir(parents=True, exist_ok=True)
            if kind == "dir":
                p.mkdir(exist_ok=True)
            elif kind == "fifo":
                os.mkfifo(p)
            elif kind == "symlink":
                os.symlink(target, p)
            elif kind == "hardlink":
                os.link(folder / target, p)
            else:
                raise ValueError(f"unknown special file kind {kind!r}")

    def command_line(self, folder: Path | str = ".") -> str:
        """The shell command that reproduces the case from its folder."""
        import shlex

        return "zcut " + " ".join(shlex.quote(a.replace("{CASE}", str(folder))) for a in self.argv)

    def as_json(self) -> dict:
        return {"id": self.id, "generator": self.generator, "what": self.what, "argv": self.argv,
                "files": sorted(self.files), "special": self.special, "mutable": sorted(self.mutable),
                "expect_frames": self.expect_frames, "count": self.count}


@dataclass
class Outcome:
    """What running a case gave."""

    case: Case
    klass: str
    rc: int | None
    signal: int | None
    wall_s: float
    cpu_s: float
    maxrss_mb: float
    detail: str
    stdout: str
    stderr: str
    signature: str = ""


# ---------------------------------------------------------------------------------------------- hashing
def snapshot(folder: Path) -> dict[str, tuple]:
    """Every entry under ``folder``: relative path -> (kind, identity, content hash or link target)."""
    out: dict[str, tuple] = {}
    for root, dirs, files in os.walk(folder):
        for name in dirs + files:
            p = Path(root) / name
            rel = str(p.relative_to(folder))
            st = os.lstat(p)
            if stat.S_ISLNK(st.st_mode):
                out[rel] = ("link", os.readlink(p))
            elif stat.S_ISREG(st.st_mode):
                h = hashlib.sha256()
                with open(p, "rb") as f:
                    for block in iter(lambda: f.read(1 << 20), b""):
                        h.update(block)
                out[rel] = ("file", st.st_ino, h.hexdigest())
            elif stat.S_ISDIR(st.st_mode):
                out[rel] = ("dir",)
            else:
                out[rel] = ("other", stat.S_IFMT(st.st_mode), st.st_ino)
    return out


def modified_inputs(before: dict[str, tuple], after: dict[str, tuple], mutable: set[str]) -> list[str]:
    """Inputs that changed, were replaced (another inode) or disappeared."""
    bad = []
    for name, was in before.items():
        if name in mutable or any(name.startswith(m.rstrip("/") + "/") for m in mutable):
            continue
        now = after.get(name)
        if now is None:
            bad.append(f"{name} removed")
        elif now != was:
            bad.append(f"{name} changed" if now[0] == was[0] else f"{name} replaced by a {now[0]}")
    return bad


def leftovers(before: dict[str, tuple], after: dict[str, tuple]) -> list[str]:
    return sorted(n for n in after if n not in before and ".partial" in Path(n).name)


# ---------------------------------------------------------------------------------------------- classify
_TRACEBACK = "Traceback (most recent call last)"
_MEMORY = re.compile(r"MemoryError|std::bad_alloc|not enough memory|Cannot allocate memory|out of memory|"
                     r"Unable to allocate|needs more memory than available", re.I)


def _count_frames(kind: str, stdout: str) -> int | None:
    """Frames a command reported in its stdout (None: it did not say)."""
    if kind == "check":
        m = re.search(r"^check: (\d+) frames decoded", stdout, re.M)
        return int(m.group(1)) if m else None
    if kind == "json":
        start = stdout.find("{")
        if start < 0:
            return None
        try:
            return len(json.loads(stdout[start:])["frames"])
        except (ValueError, KeyError, TypeError):
            return None
    if kind == "table":
        return sum(1 for line in stdout.splitlines() if re.match(r"^\s*\d+\s+-?\d+\s+\d+\s", line))
    raise ValueError(kind)


_EXC_LINE = re.compile(r"^([A-Za-z_][\w.]*(?:Error|Exception|Warning|Exit|Interrupt|error))(?::|$)")


def _exception_line(stderr: str) -> str:
    """The last ``SomeError: message`` line of a traceback (else the last unindented line)."""
    lines = [ln for ln in stderr.strip().splitlines() if ln and not ln.startswith(" ")]
    exc = [ln for ln in lines if _EXC_LINE.match(ln)]
    return (exc or lines or [""])[-1]


def _short(path: str) -> str:
    return path.replace(str(REPO) + "/", "")


def _dump_frame(stderr: str) -> str:
    """``file:line (function)`` of the innermost project frame of the main thread in a faulthandler
    dump (what a case was doing when a cap was hit), or ""."""
    blocks = re.split(r"^(?=(?:Current thread|Thread) 0x)", stderr, flags=re.MULTILINE)
    for block in blocks:
        if not re.match(r"(?:Current thread|Thread) 0x", block) or "cli/main.py" not in block:
            continue
        for path, line, func in re.findall(r'File "([^"]+)", line (\d+) in (\S+)', block):
            if "/site-packages/" not in path and "/lib/python" not in path and not path.startswith("<"):
                return f"{_short(path)}:{line} ({func})"
    return ""


def signature_of(klass: str, case: Case, stderr: str, detail: str) -> str:
    """What makes two non-clean outcomes the same finding: the class, the command, and the
    innermost project frame and exception type of a traceback (or the error text without numbers)."""
    cmd = next((a for a in case.argv if not a.startswith("-")), "?")
    if case.argv[:1] == ["labels"] and len(case.argv) > 1:
        cmd = "labels " + case.argv[1]
    dumped = _dump_frame(stderr)
    if klass in ("hang", "memory") and dumped:
        return f"{klass} | {cmd} | in {dumped}"
    if klass in ("traceback", "memory") and _TRACEBACK in stderr:
        frames = re.findall(r'File "([^"]+)", line (\d+), in (\S+)', stderr)
        own = [f for f in frames if "/site-packages/" not in f[0] and "/lib/python" not in f[0]]
        where = own[-1] if own else (frames[-1] if frames else ("?", "?", "?"))
        exc = _exception_line(stderr).split(":")[0] or "?"
        path = where[0]
        for root in (str(REPO) + "/",):
            path = path.replace(root, "")
        return f"{klass} | {cmd} | {exc} at {path}:{where[1]} ({where[2]})"
    text = re.sub(r"\d+", "N", detail)
    text = re.sub(r"'[^']*'|\"[^\"]*\"", "'…'", text)
    return f"{klass} | {cmd} | {text[:140]}"


def classify(case: Case, *, rc: int | None, sig: int | None, timed_out: bool, stdout: str, stderr: str,
             modified: list[str], left: list[str], rss_killed: int = 0) -> tuple[str, str]:
    """(class, one-line detail) of a finished case (see the module docstring for the classes)."""
    errors = [ln for ln in stderr.splitlines() if ln.startswith("error: ")]
    last = stderr.strip().splitlines()[-1] if stderr.strip() else ""
    if modified:
        return "input-modified", "; ".join(modified)
    where = _dump_frame(stderr)
    where = f"in {where}" if where else f"last stderr line: {last[:120]}"
    if rss_killed:
        return "memory", f"killed at {rss_killed / 2**20:.0f} MB resident (over the cap); {where}"
    if timed_out:
        return "hang", f"still running after the time cap; {where}"
    if _MEMORY.search(stderr):
        m = _MEMORY.search(stderr)
        line = next((ln for ln in stderr.splitlines() if m.group(0) in ln), m.group(0))
        return "memory", line.strip()[:200]
    if sig is not None:
        return "crash", f"killed by signal {sig} ({signal.Signals(sig).name}); last stderr line: {last[:160]}"
    if _TRACEBACK in stderr:
        return "traceback", _exception_line(stderr)[:200]
    if rc not in (0, 1, 3):
        return "bad-exit", f"exit {rc}; last stderr line: {last[:160]}"
    if rc == 1 and len(errors) != 1:
        return "bad-exit", f"exit 1 with {len(errors)} 'error: ' lines; last stderr line: {last[:160]}"
    if rc == 0 and case.expect_frames is not None and case.count is not None:
        got = _count_frames(case.count, stdout)
        if got is not None and got < case.expect_frames:
            return "loss-exit0", f"exit 0 with {got} of {case.expect_frames} frames"
    if left:
        return "leftover", "left behind: " + ", ".join(left)
    return "clean", (errors[0] if errors else f"exit {rc}")[:200]


# ---------------------------------------------------------------------------------------------- runners
@dataclass
class _Job:
    case: Case
    folder: Path
    before: dict[str, tuple]
    start: float


def _limits(mem_total: int, fsize: int) -> None:
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (mem_total, mem_total))
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))


class ForkServer:
    """The warm server (``python fuzzlib.py --serve``), spoken to over its stdin/stdout (JSON lines)."""

    def __init__(self, *, jobs: int) -> None:
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
        self.proc = subprocess.Popen([PYTHON, __file__, "--serve", str(jobs)], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, text=True, env=env, cwd=str(REPO))
        self.deadlines: dict[str, float] = {}
        self._buf = b""
        hello = json.loads(self.proc.stdout.readline())  # nothing else is sent before it is read
        self.vm_bytes = hello["vm_bytes"]
        self.warm_s = hello["warm_s"]
        self.threads = hello["threads"]

    def submit(self, key: str, argv: list[str], cwd: Path, *, timeout_s: float, rss: int, vm: int, fsize: int) -> None:
        self.deadlines[key] = time.monotonic() + timeout_s
        self.proc.stdin.write(json.dumps({"key": key, "argv": argv, "cwd": str(cwd), "timeout": timeout_s,
                                          "rss": rss, "vm": vm, "fsize": fsize}) + "\n")
        self.proc.stdin.flush()

    def wait(self) -> dict:
        """The next finished case's report (the server kills a case at its cap; if no report comes
        long after every outstanding cap, the server is broken: raise rather than wait forever)."""
        limit = max(self.deadlines.values(), default=time.monotonic()) + 120.0
        fd = self.proc.stdout.fileno()
        while not self._buffer_has_line():
            ready, _, _ = select.select([fd], [], [], max(limit - time.monotonic(), 0.0))
            if not ready:
                raise RuntimeError("the fuzz fork server stopped answering")
            data = os.read(fd, 1 << 16)
            if not data:
                raise RuntimeError("the fuzz fork server died")
            self._buf += data
        line, self._buf = self._buf.split(b"\n", 1)
        rep = json.loads(line)
        self.deadlines.pop(rep["key"], None)
        return rep

    def _buffer_has_line(self) -> bool:
        return b"\n" in self._buf

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.stdin.close()
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        for f in (self.proc.stdin, self.proc.stdout):
            if not f.closed:
                f.close()


class SubprocessPool:
    """One ``python -m cli`` process per case; same interface as :class:`ForkServer`."""

    def __init__(self, *, jobs: int) -> None:
        self.running: dict[int, _Running] = {}
        self.vm_bytes = _fresh_vm_bytes()
        self.warm_s = 0.0
        self.threads = 1

    def submit(self, key: str, argv: list[str], cwd: Path, *, timeout_s: float, rss: int, vm: int, fsize: int) -> None:
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
        total = self.vm_bytes + vm

        def pre() -> None:
            os.setsid()
            _limits(total, fsize)

        out = open(cwd.parent / f"{cwd.name}.stdout", "wb")
        err = open(cwd.parent / f"{cwd.name}.stderr", "wb")
        args = [PYTHON, "-c", _SUBPROCESS_MAIN, *[os.fsencode(a) for a in argv]]
        proc = subprocess.Popen(args, cwd=cwd, stdin=subprocess.DEVNULL, stdout=out, stderr=err, env=env,
                                preexec_fn=pre)
        out.close()
        err.close()
        self.running[proc.pid] = _Running(key, proc.pid, time.monotonic(), timeout_s, rss, proc=proc)

    def wait(self) -> dict:
        while True:
            for pid, r in list(self.running.items()):
                got = os.wait4(pid, os.WNOHANG)
                if got[0] == pid:
                    del self.running[pid]
                    r.proc.returncode = 0  # reaped here
                    return _report(r, got[1], got[2])
                r.watch()
            time.sleep(_POLL_S)

    def close(self) -> None:
        for pid in list(self.running):
            _kill_group(pid)
            os.waitpid(pid, 0)


@dataclass
class _Running:
    """A running case, watched for its time and resident-memory caps."""

    key: str
    pid: int
    start: float
    timeout_s: float
    rss_cap: int
    pidfd: int = -1
    proc: object = None
    killed: str = ""  # "time" or "memory" once a cap is hit
    peak_rss: int = 0
    dumped_at: float = 0.0  # when the stack dump was asked for (the kill follows)

    def watch(self) -> None:
        """At the time cap or above the RSS cap: ask the case for a stack dump (SIGUSR1, faulthandler),
        then kill its process group :data:`_DUMP_S` later."""
        now = time.monotonic()
        if self.killed:
            if self.dumped_at and now - self.dumped_at > _DUMP_S:
                self.dumped_at = 0.0
                _kill_group(self.pid)
            return
        if now - self.start > self.timeout_s:
            self.killed = "time"
        else:
            rss = _rss_bytes(self.pid)
            self.peak_rss = max(self.peak_rss, rss)
            if rss > self.rss_cap:
                self.killed = "memory"
        if self.killed:
            try:
                os.kill(self.pid, signal.SIGUSR1)
                self.dumped_at = now
            except ProcessLookupError:
                pass


def _rss_bytes(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, IndexError, ValueError):
        return 0


_FRESH_VM: list[int] = []


def _fresh_vm_bytes() -> int:
    """Address space of a fresh interpreter that imported the command line (measured once)."""
    if not _FRESH_VM:
        code = ("import cli.main\nfor l in open('/proc/self/status'):\n"
                "    if l.startswith('VmSize'): print(int(l.split()[1]) * 1024)")
        env = dict(os.environ, PYTHONPATH=str(REPO))
        _FRESH_VM.append(int(subprocess.run([PYTHON, "-c", code], capture_output=True, text=True, env=env,
                                            cwd=str(REPO), check=True).stdout))
    return _FRESH_VM[0]


def _vm_bytes() -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    return 0


def _kill_group(pid: int) -> None:
    try:
        os.killpg(pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    except PermissionError:  # pragma: no cover
        os.kill(pid, signal.SIGKILL)


def _report(r: _Running, status: int, ru) -> dict:
    rc = os.waitstatus_to_exitcode(status)
    return {"key": r.key, "rc": rc if rc >= 0 else None, "signal": -rc if rc < 0 else None,
            "timed_out": r.killed == "time", "rss_killed": r.peak_rss if r.killed == "memory" else 0,
            "wall": time.monotonic() - r.start, "cpu": ru.ru_utime + ru.ru_stime, "maxrss_kb": ru.ru_maxrss}


# ---------------------------------------------------------------------------------------------- the server
def _serve(jobs: int) -> None:  # pragma: no cover - runs in the server process
    """Warm up, then fork a child per request, ``jobs`` at a time (JSON lines on stdin/stdout)."""
    import importlib

    t0 = time.perf_counter()
    for name in WARM_IMPORTS:
        importlib.import_module(name)
    _numba_context()
    warm = time.perf_counter() - t0
    _assert_no_numba_threads()
    out = sys.stdout
    out.write(json.dumps({"vm_bytes": _vm_bytes(), "warm_s": warm,
                          "threads": len(os.listdir("/proc/self/task"))}) + "\n")
    out.flush()
    fd_in = sys.stdin.fileno()  # read raw: a buffered readline would hide a second request from select
    pending_input = b""
    running: dict[int, _Running] = {}
    waiting: list[dict] = []
    eof = False
    while not eof or running or waiting:
        while waiting and len(running) < jobs:
            req = waiting.pop(0)
            _assert_no_numba_threads()
            sys.stdout.flush()
            sys.stderr.flush()
            pid = os.fork()
            if pid == 0:
                _child(req)  # never returns
            running[pid] = _Running(req["key"], pid, time.monotonic(), float(req["timeout"]), int(req["rss"]),
                                    pidfd=os.pidfd_open(pid))
        fds = [r.pidfd for r in running.values()]
        if not eof:
            fds.append(fd_in)
        ready, _, _ = select.select(fds, [], [], _POLL_S if running else None)
        if fd_in in ready:
            data = os.read(fd_in, 1 << 16)
            if not data:
                eof = True
            pending_input += data
            *lines, pending_input = pending_input.split(b"\n")
            waiting += [json.loads(line) for line in lines if line.strip()]
        for pid, r in list(running.items()):
            if r.pidfd in ready:
                _, status, ru = os.wait4(pid, 0)
                os.close(r.pidfd)
                del running[pid]
                out.write(json.dumps(_report(r, status, ru)) + "\n")
                out.flush()
            else:
                r.watch()


def _numba_context() -> None:
    """numba's CPU target and typing contexts filled (their registries, the NRT), as the first kernel a process
    calls or loads from the cache fills them (~0.4 CPU s): once here, not in every case. Neither loads a kernel
    nor starts a thread (a cached parallel kernel would start the threading layer when loaded: none is)."""
    from numba.core.registry import cpu_target

    cpu_target.target_context.refresh()
    cpu_target.typing_context.refresh()


def _assert_no_numba_threads() -> None:
    mod = sys.modules.get("numba.np.ufunc.parallel")
    if mod is not None and getattr(mod, "_is_initialized", False):
        raise RuntimeError("numba's threading layer is running in the fuzz server: no kernel may run before fork")


def _child(req: dict) -> None:  # pragma: no cover - runs in a forked child
    """Become ``zcut ARGV`` in the case folder, under the limits, and exit with its status."""
    import io
    import traceback

    code = 125
    try:
        os.setsid()
        cwd = Path(req["cwd"])
        os.chdir(cwd)
        for fd, path, flags in ((0, os.devnull, os.O_RDONLY),
                                (1, cwd.parent / f"{cwd.name}.stdout", os.O_WRONLY | os.O_CREAT | os.O_TRUNC),
                                (2, cwd.parent / f"{cwd.name}.stderr", os.O_WRONLY | os.O_CREAT | os.O_TRUNC)):
            new = os.open(path, flags, 0o644)
            os.dup2(new, fd)
            os.close(new)
        enc = sys.__stdout__.encoding or "utf-8"
        sys.stdin = sys.__stdin__ = io.TextIOWrapper(io.FileIO(0, "r", closefd=False), encoding=enc)
        sys.stdout = sys.__stdout__ = io.TextIOWrapper(io.FileIO(1, "w", closefd=False), encoding=enc,
                                                       errors=sys.__stdout__.errors or "strict")
        sys.stderr = sys.__stderr__ = io.TextIOWrapper(io.FileIO(2, "w", closefd=False), encoding=enc,
                                                       errors="backslashreplace", line_buffering=True)
        for s in (signal.SIGTERM, signal.SIGALRM, signal.SIGCHLD):
            signal.signal(s, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        import faulthandler

        faulthandler.register(signal.SIGUSR1, file=sys.stderr, all_threads=True)  # the runner asks at a cap
        sys.argv = ["zcut", *req["argv"]]
        _limits(_vm_bytes() + int(req["vm"]), int(req["fsize"]))
        from cli.main import main
    except BaseException:
        os._exit(code)
    try:
        code = main(req["argv"])
    except SystemExit as e:
        code = e.code
    except BaseException:
        try:
            traceback.print_exc()
        except BaseException:
            pass
        code = 1
    if code is None:
        code = 0
    elif not isinstance(code, int):
        try:
            print(code, file=sys.stderr)
        except BaseException:
            pass
        code = 1
    try:  # what the interpreter does at exit
        import threading

        threading._shutdown()
        import atexit

        atexit._run_exitfuncs()
    except BaseException:
        try:
            traceback.print_exc()
        except BaseException:
            pass
    for s in (sys.stdout, sys.stderr):
        try:
            s.flush()
        except BaseException:
            code = 120
    os._exit(code & 0xFF)


# ---------------------------------------------------------------------------------------------- running many
def run_cases(cases: Iterable[Case], work: Path, *, jobs: int = 2, mode: str = "fork",
              timeout_s: float = DEFAULT_TIMEOUT_S, mem_bytes: int = DEFAULT_MEM_BYTES,
              as_bytes: int = DEFAULT_AS_BYTES, fsize_bytes: int = DEFAULT_FSIZE_BYTES, keep: Path | None = None,
              on_outcome: Callable[[Outcome], None] | None = None,
              runner: ForkServer | SubprocessPool | None = None) -> Iterator[Outcome]:
    """Run ``cases`` (``jobs`` at a time) in folders under ``work``; yield their outcomes in
    completion order.

    ``runner``: a runner the caller started (and closes), e.g. one warm server for several calls
    (started with at least ``jobs`` jobs); ``mode`` is then not used. None: one of ``mode`` is started
    for this call and closed at its end.

    Each case runs in ``work/<id>/`` (removed afterwards unless it is not clean and ``keep`` is
    given: then it is moved to ``keep/<id>/`` with ``cmd.sh``, ``case.json``, ``stdout`` and
    ``stderr``, a reproducer).
    """
    work.mkdir(parents=True, exist_ok=True)
    own = runner is None
    if runner is None:
        runner = ForkServer(jobs=jobs) if mode == "fork" else SubprocessPool(jobs=jobs)
    pending: dict[str, _Job] = {}
    it = iter(cases)
    exhausted = False
    try:
        while True:
            while not exhausted and len(pending) < jobs:
                case = next(it, None)
                if case is None:
                    exhausted = True
                    break
                folder = work / case.id
                if folder.exists():
                    shutil.rmtree(folder)
                folder.mkdir()
                case.materialize(folder)
                job = _Job(case, folder, snapshot(folder), time.monotonic())
                pending[case.id] = job
                argv = [a.replace("{CASE}", str(folder)) for a in case.argv]
                runner.submit(case.id, argv, folder, timeout_s=case.timeout_s or timeout_s, rss=mem_bytes,
                              vm=as_bytes, fsize=fsize_bytes)
            if not pending:
                break
            rep = runner.wait()
            job = pending.pop(rep["key"])
            outcome = _finish(job, rep, keep)
            if on_outcome is not None:
                on_outcome(outcome)
            yield outcome
    finally:
        if own:
            runner.close()


def _read(path: Path) -> str:
    try:
        with open(path, "rb") as f:
            data = f.read(KEEP_OUTPUT + 1)
    except FileNotFoundError:
        return ""
    text = data[:KEEP_OUTPUT].decode("utf-8", "replace")
    return text + ("\n[… cut]" if len(data) > KEEP_OUTPUT else "")


def _raw(text: str) -> bytes:
    """Text that may hold file names from the command line (undecodable bytes kept as surrogates)."""
    return text.encode("utf-8", "surrogateescape")


def _finish(job: _Job, rep: dict, keep: Path | None) -> Outcome:
    folder = job.folder
    out_p, err_p = folder.parent / f"{folder.name}.stdout", folder.parent / f"{folder.name}.stderr"
    stdout, stderr = _read(out_p), _read(err_p)
    after = snapshot(folder)
    modified = modified_inputs(job.before, after, job.case.mutable)
    left = leftovers(job.before, after)
    klass, detail = classify(job.case, rc=rep["rc"], sig=rep["signal"], timed_out=rep["timed_out"],
                             stdout=stdout, stderr=stderr, modified=modified, left=left,
                             rss_killed=rep.get("rss_killed", 0))
    outcome = Outcome(job.case, klass, rep["rc"], rep["signal"], rep["wall"], rep["cpu"], rep["maxrss_kb"] / 1024,
                      detail, stdout, stderr)
    if klass != "clean":
        outcome.signature = signature_of(klass, job.case, stderr, detail)
    if klass != "clean" and keep is not None:
        dest = keep / job.case.id
        for old in (dest, dest.with_name(dest.name + ".after")):  # a previous run's reproducer
            if old.exists():
                shutil.rmtree(old)
        dest.parent.mkdir(parents=True, exist_ok=True)
        # the inputs as they were (the run may have changed them): recreate, then keep the outputs aside
        shutil.move(str(folder), str(dest.with_name(dest.name + ".after")))
        dest.mkdir()
        job.case.materialize(dest)
        (dest.with_name(dest.name + ".after") / "stdout").write_bytes(_raw(stdout))
        (dest.with_name(dest.name + ".after") / "stderr").write_bytes(_raw(stderr))
        what = job.case.what.replace("\n", "\\n")
        (dest.parent / f"{job.case.id}.cmd.sh").write_bytes(_raw(
            f"#!/bin/sh\n# {what}\n# class: {klass}: {detail}\ncd '{dest}' && {job.case.command_line(dest)}\n"))
        (dest.parent / f"{job.case.id}.json").write_text(json.dumps(
            {**job.case.as_json(), "class": klass, "detail": detail, "rc": rep["rc"], "signal": rep["signal"],
             "signature": outcome.signature}, indent=1))
    else:
        shutil.rmtree(folder, ignore_errors=True)
    for p in (out_p, err_p):
        p.unlink(missing_ok=True)
    return outcome


# ---------------------------------------------------------------------------------------------- reports
def table(outcomes: list[Outcome]) -> str:
    """Counts per generator x class, as a fixed-width table with a total row."""
    gens = sorted({o.case.generator for o in outcomes})
    cols = [c for c in CLASSES]
    counts = {(g, c): 0 for g in gens for c in cols}
    for o in outcomes:
        counts[(o.case.generator, o.klass)] += 1
    w0 = max([len("generator"), *map(len, gens), len("total")])
    head = f"{'generator':<{w0}} " + " ".join(f"{c:>{max(len(c), 5)}}" for c in cols) + f" {'cases':>6}"
    lines = [head, "-" * len(head)]
    for g in [*gens, "total"]:
        row = [sum(counts[(x, c)] for x in gens) if g == "total" else counts[(g, c)] for c in cols]
        lines.append(f"{g:<{w0}} " + " ".join(f"{n:>{max(len(c), 5)}}" for n, c in zip(row, cols, strict=True))
                     + f" {sum(row):>6}")
    return "\n".join(lines)


def findings(outcomes: list[Outcome]) -> list[tuple[str, list[Outcome]]]:
    """Non-clean outcomes grouped by signature, most frequent first."""
    groups: dict[str, list[Outcome]] = {}
    for o in outcomes:
        if o.klass != "clean":
            groups.setdefault(o.signature, []).append(o)
    return sorted(groups.items(), key=lambda kv: (-len(kv[1]), kv[0]))


if __name__ == "__main__":  # the warm server
    if len(sys.argv) == 3 and sys.argv[1] == "--serve":
        _serve(int(sys.argv[2]))
    else:
        sys.exit(f"usage: {sys.argv[0]} --serve JOBS (started by run_cases)")
