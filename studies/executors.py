"""Run a study's units: on local processes (the default) or as Ray tasks on a cluster (``--ray``).

Both executors take the same picklable work function and units and yield ``(unit, result)`` as units
complete, so a slow log never holds back the others' results. A unit whose work raised returns the
error in its result (the work functions catch what a damaged log can throw); a worker process that
dies (a crash, the memory cap) is replaced and the one unit it was running is retried once, then
reported as failed — the units the other workers run, and those still queued, are not touched.

Local workers die with their driver: each asks the kernel for SIGKILL when its parent dies
(``prctl(PR_SET_PDEATHSIG)``, Linux) and watches its parent's pid besides; they ignore SIGINT,
SIGTERM and SIGHUP (a Ctrl-C or a hang-up in a terminal, or ``kill -PGID``, reaches the whole process
group: the driver decides, and stops them). When the
driver stops early (an interruption, an error), it kills its workers and waits for them before it
returns, so nothing of the study keeps running and the study folder's leftovers can be removed.

Every worker owns its share of the cores: its thread pools (numba, OpenMP, BLAS) get
``cores // workers`` threads (1 on a Ray task of one CPU), so that workers do not oversubscribe the
machine; a variable the user set is kept. Ray workers also get the driver's ``ZCUT_*`` variables
and numba threading layer (they do not inherit the driver's environment), so a unit computes the
same on both executors.

Memory: a worker replaying the sensor's frames needs about 1.5 GB (:data:`WORKER_MEMORY_MB`). The
default number of local workers is what the free memory holds (at most the cores), and a Ray task
asks for that much of Ray's ``memory`` resource, so that Ray places no more tasks on a node than
its memory holds.

Ray is an optional extra (``.venv/bin/pip install -e '.[ray]'`` in a checkout): imported only by
:class:`RayExecutor`.
An address is checked before Ray is asked to connect (Ray itself retries an unreachable cluster
for minutes): nothing listening, or something that does not speak gRPC, is a one-line error.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.connection import wait as wait_ready
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from replay.errors import ConfigError

if TYPE_CHECKING:
    from studies.units import WorkUnit
    from studies.work import Job, UnitResult

#: What an executor runs for every unit (:func:`studies.work.run_batch_unit`, :func:`studies.sweep.run_sweep_unit`).
UnitFn = Callable[["WorkUnit", "Job"], "UnitResult"]

#: the thread pools a worker sizes to its share of the cores
THREAD_VARIABLES = ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
#: seconds to wait for a Ray address to answer
CONNECT_TIMEOUT_S = 10.0
#: memory a worker may need: the measured peak of a worker replaying the sensor's 1920 x 1200 frames
#: with a bin model is 1.1-1.5 GB (1.9 GB as a Ray worker; bench/bench_batch.py)
WORKER_MEMORY_MB = 1600


class Executor(Protocol):
    """Runs ``fn(unit, job)`` for every unit; yields ``(unit, result)`` in completion order."""

    name: str
    workers: int

    def run(self, fn: UnitFn, units: list[WorkUnit], job: Job) -> Iterator[tuple[WorkUnit, UnitResult]]: ...

    def close(self) -> None: ...


def default_workers() -> int:
    """The cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def available_memory_mb() -> float | None:
    """The memory the machine can still give (``MemAvailable``), or None where unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        return None
    return None


def worker_environment(threads: int) -> dict[str, str]:
    """The variables a worker starts with: thread pools of ``threads`` threads (unless the user set
    them), the readers' caps (``ZCUT_*``) and numba's threading layer, as the driver has them."""
    env = {k: os.environ.get(k, str(threads)) for k in THREAD_VARIABLES}
    env.update({k: v for k, v in os.environ.items()
                if k.startswith("ZCUT_") or k in ("NUMBA_THREADING_LAYER", "NUMBA_THREADING_LAYER_PRIORITY")})
    return env


@contextmanager
def _environ(values: Mapping[str, str]) -> Iterator[None]:
    """``os.environ`` with ``values`` while worker processes are started (they copy it), then as before."""
    old = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


#: seconds between two looks of a worker at its parent's pid (the kernel's PDEATHSIG is immediate)
PARENT_WATCH_S = 1.0
#: seconds a worker may take to finish after it was told to stop, before it is killed
WORKER_STOP_S = 10.0
_PR_SET_PDEATHSIG = 1


def die_with_parent(parent_pid: int, *, interval_s: float = PARENT_WATCH_S) -> None:
    """Make this process die when the process ``parent_pid`` (its parent) dies, even by SIGKILL.

    The kernel sends SIGKILL on the parent's death (``PR_SET_PDEATHSIG``; Linux), and a daemon
    thread checks the parent's pid every ``interval_s`` seconds (the parent may have died before the
    request, or the kernel may not offer it).
    """
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    except (OSError, AttributeError):  # pragma: no cover - not Linux: the watcher alone
        pass
    if os.getppid() != parent_pid:  # the parent died before the request took effect
        os.kill(os.getpid(), signal.SIGKILL)

    def watch() -> None:
        while True:
            time.sleep(interval_s)
            if os.getppid() != parent_pid:
                os.kill(os.getpid(), signal.SIGKILL)

    threading.Thread(target=watch, name="zcut-parent-watch", daemon=True).start()


def _worker_main(conn: Connection, parent_pid: int, fn: UnitFn, job: Job) -> None:
    """A local worker: run the units the driver sends (``(key, unit)``) until it sends None or is
    gone; answer ``(key, result)`` for each."""
    die_with_parent(parent_pid)
    from replay.process import INTERRUPT_SIGNALS, configure_process  # (workers start fresh)

    for s in INTERRUPT_SIGNALS:  # a terminal or `kill -PGID` reaches the group: the driver stops its workers
        signal.signal(s, signal.SIG_IGN)
    configure_process()
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):  # the driver is gone
            return
        if msg is None:
            return
        key, unit = msg
        try:
            res = fn(unit, job)
        except Exception as e:  # noqa: BLE001 - the work functions catch their own; this is a last guard
            res = _failed(unit, f"{type(e).__name__}: {e}")
        conn.send((key, res))


@dataclass(eq=False)
class _Worker:
    process: Any  # multiprocessing's SpawnProcess
    conn: Connection
    running: tuple[int, WorkUnit] | None = None  # (key, unit) it runs


def _death(process: Any) -> str:
    code = process.exitcode
    if code is not None and code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit status {code}"


class LocalExecutor:
    """Units on ``workers`` local processes (started fresh: no inherited threads or files), each
    with ``cores // workers`` threads, one unit at a time per worker.

    Parameters
    ----------
    workers : int
        Processes (default: the cores, as many as the available memory holds at
        :data:`WORKER_MEMORY_MB` each: a many-core machine with little memory would otherwise have its
        workers killed for memory, over and over).
    """

    name = "local processes"

    def __init__(self, workers: int | None = None) -> None:
        if workers is not None and (isinstance(workers, bool) or workers < 1):
            raise ConfigError(f"--workers must be >= 1, got {workers!r}")
        if workers is None:
            workers = default_workers()
            mem = available_memory_mb()
            if mem is not None and workers > max(1, int(mem // WORKER_MEMORY_MB)):
                workers = max(1, int(mem // WORKER_MEMORY_MB))
                self.name = f"local processes (as many as {mem / 1024:.0f} GB of free memory hold)"
        self.workers = workers
        self.threads = max(1, default_workers() // self.workers)
        self._live: list[_Worker] = []

    def _start_worker(self, fn: UnitFn, job: Job) -> _Worker:
        ctx = multiprocessing.get_context("spawn")
        mine, theirs = ctx.Pipe(duplex=True)
        p = ctx.Process(target=_worker_main, args=(theirs, os.getpid(), fn, job), daemon=True,
                        name="zcut-worker")
        with _environ(worker_environment(self.threads)):  # the worker copies the environment at its start
            p.start()
        theirs.close()
        w = _Worker(p, mine)
        self._live.append(w)
        return w

    def run(self, fn: UnitFn, units: list[WorkUnit], job: Job) -> Iterator[tuple[WorkUnit, UnitResult]]:
        """Yield ``(unit, result)`` as units finish. A worker that dies costs only the unit it ran
        (retried once in a new worker, then failed)."""
        queue: deque[tuple[int, WorkUnit]] = deque(enumerate(units))
        deaths: dict[int, int] = {}
        workers = self._live
        finished = False
        try:
            while queue or any(w.running for w in workers):
                idle = [w for w in workers if w.running is None]
                while queue and idle:
                    self._give(idle.pop(), queue)
                while queue and len(workers) < self.workers:
                    self._give(self._start_worker(fn, job), queue)
                waiting: dict[object, _Worker] = {w.conn: w for w in workers if w.running is not None}
                waiting.update({w.process.sentinel: w for w in workers})
                for ready in wait_ready(list(waiting)):  # type: ignore[arg-type]  # connections and sentinels
                    w = waiting[ready]
                    if w not in workers:
                        continue  # its connection and its sentinel both fired: handled
                    if ready is w.conn and w.running is not None:
                        try:
                            _, res = w.conn.recv()
                        except Exception:  # noqa: BLE001 - a worker that died while answering
                            w.process.join(timeout=WORKER_STOP_S)
                        else:
                            u = w.running[1]
                            w.running = None
                            yield u, res
                            continue
                    # the worker died: the unit it ran (if any) is charged, once
                    self._forget(w)
                    if w.running is not None:
                        key, u = w.running
                        deaths[key] = deaths.get(key, 0) + 1
                        if deaths[key] >= 2:
                            yield u, _failed(u, "the worker process died twice on this unit "
                                                f"({_death(w.process)}: a crash or out of memory)")
                        else:
                            queue.appendleft((key, u))
            finished = True
        finally:
            self._stop(graceful=finished)

    @staticmethod
    def _give(w: _Worker, queue: deque[tuple[int, WorkUnit]]) -> None:
        item = queue.popleft()
        try:
            w.conn.send(item)
        except OSError:  # the worker is gone (its sentinel tells): the unit never reached it
            queue.appendleft(item)
            return
        w.running = item

    def _forget(self, w: _Worker) -> None:
        w.process.join(timeout=WORKER_STOP_S)
        if w.process.is_alive():
            w.process.kill()
            w.process.join()
        w.conn.close()
        self._live.remove(w)

    def _stop(self, *, graceful: bool) -> None:
        """Stop every worker: told to stop after a finished run, killed otherwise; waited for."""
        workers, self._live = list(self._live), []
        for w in workers:
            if graceful:
                try:
                    w.conn.send(None)
                except OSError:
                    pass
            else:
                w.process.kill()
        deadline = time.monotonic() + WORKER_STOP_S
        for w in workers:
            w.process.join(timeout=max(0.0, deadline - time.monotonic()))
            if w.process.is_alive():
                w.process.kill()
                w.process.join()
            w.conn.close()

    def close(self) -> None:
        """Kill the workers still running (an interrupted study) and wait for them."""
        self._stop(graceful=False)


def _failed(unit: WorkUnit, why: str) -> UnitResult:
    from studies.work import UnitResult

    return UnitResult.failure(unit, why)


# --- Ray ---------------------------------------------------------------------------------------

#: an HTTP/2 client preface and an empty SETTINGS frame: a gRPC server (Ray's GCS, its client
#: server) answers with a SETTINGS frame (type 4)
_H2_HELLO = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + b"\x00\x00\x00\x04\x00\x00\x00\x00\x00"
_H2_SETTINGS = 0x04


def _ray_current_cluster() -> Path:
    """The file in which ``ray start`` leaves its cluster's address (Ray's default temp dir)."""
    tmp = os.environ.get("RAY_TMPDIR") or os.environ.get("TMPDIR") or "/tmp"
    return Path(tmp) / "ray" / "ray_current_cluster"


def resolve_ray_address(address: str) -> str:
    """``--ray``'s address: as given, or for ``auto`` ``RAY_ADDRESS`` / the local ``ray start``.

    Raises :class:`ConfigError` when ``auto`` finds no cluster.
    """
    if address != "auto":
        return address
    env = os.environ.get("RAY_ADDRESS", "").strip()
    if env and env != "auto":
        return env
    f = _ray_current_cluster()
    try:
        found = f.read_text().strip() if f.is_file() else ""
    except OSError:
        found = ""
    if not found:
        raise ConfigError("--ray auto: no cluster found (RAY_ADDRESS is not set and no `ray start` on this machine)")
    return found


def _host_port(address: str, target: str) -> tuple[str, int]:
    rest = target.removeprefix("ray://")
    host, sep, port = rest.rpartition(":")
    host = host.strip("[]")
    if "://" in rest or not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        shown = address if address == target else f"{address} ({target})"
        raise ConfigError(f"--ray {shown}: not a Ray address (HOST:PORT, ray://HOST:PORT or auto)")
    return host, int(port)


def check_ray_address(address: str, target: str, *, timeout: float = CONNECT_TIMEOUT_S) -> None:
    """Refuse, in seconds and in one line, an address where no Ray cluster answers: nothing listens,
    the host is unknown or unreachable, or the server does not speak gRPC (HTTP/2)."""
    host, port = _host_port(address, target)
    where = f"{host}:{port}"
    shown = address if address == target else f"{address} ({target})"
    tls = os.environ.get("RAY_USE_TLS", "0").lower() in ("1", "true")
    try:
        with socket.create_connection((host, port), timeout=timeout) as s:
            if tls:
                return  # a TLS cluster does not answer cleartext HTTP/2: that it listens is all we check
            s.settimeout(timeout)
            s.sendall(_H2_HELLO)
            head = b""
            while len(head) < 9:
                got = s.recv(9 - len(head))
                if not got:
                    break
                head += got
    except OSError as e:
        why = "timed out" if isinstance(e, TimeoutError) else (e.strerror or str(e) or type(e).__name__)
        raise ConfigError(f"--ray {shown}: cannot reach a Ray cluster at {where} ({why})") from None
    if len(head) < 9 or head[3] != _H2_SETTINGS:
        raise ConfigError(f"--ray {shown}: {where} answers, but not as a Ray cluster (no gRPC)")


class RayExecutor:
    """Units as Ray tasks (one CPU each) on an existing cluster.

    Parameters
    ----------
    address : str
        The cluster (``ray://HOST:PORT``, ``HOST:PORT``), or ``auto`` for ``RAY_ADDRESS`` / the local
        cluster ``ray start`` made.
    timeout : float
        Seconds the address may take to answer.
    """

    name = "Ray"

    def __init__(self, address: str, *, timeout: float = CONNECT_TIMEOUT_S) -> None:
        try:
            import ray
        except ImportError:
            raise ConfigError("--ray needs the ray package: in a checkout, `bash scripts/install.sh --test` installs "
                              "it, or `.venv/bin/pip install -e '.[ray]'` (an installed zcut: pip install 'zcut[ray]')"
                              ) from None
        target = resolve_ray_address(address)
        check_ray_address(address, target, timeout=timeout)
        try:
            ray.init(address=target, ignore_reinit_error=True, log_to_driver=False, logging_level=logging.ERROR,
                     runtime_env={"env_vars": worker_environment(1)})
        except Exception as e:  # noqa: BLE001 - ray raises ConnectionError, RuntimeError, ValueError...
            raise ConfigError(f"--ray {address}: cannot connect to the Ray cluster ({type(e).__name__}: "
                              f"{str(e).splitlines()[0] if str(e) else ''})") from None
        self._ray: Any = ray  # the ray module (untyped)
        self.workers = int(self._ray.cluster_resources().get("CPU", 1))

    def _task_memory(self) -> int | None:
        """Bytes of Ray's ``memory`` resource a task asks for: a worker's need, or what the largest
        node has (asking more than any node has would leave the tasks waiting for ever)."""
        nodes = [n.get("Resources", {}).get("memory", 0) for n in self._ray.nodes() if n.get("Alive")]
        largest = max(nodes, default=0)
        return int(min(WORKER_MEMORY_MB * 2**20, largest)) or None

    def run(self, fn: UnitFn, units: list[WorkUnit], job: Job) -> Iterator[tuple[WorkUnit, UnitResult]]:
        ray = self._ray
        remote = ray.remote(num_cpus=1, memory=self._task_memory(), max_retries=1)(_in_folder)
        job_ref = ray.put(job)
        cwd = os.getcwd()
        refs = {remote.remote(cwd, fn, u, job_ref): u for u in units}
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            if pending:  # and whatever else finished meanwhile
                more, pending = ray.wait(pending, num_returns=len(pending), timeout=0)
                done += more
            for r in done:
                u = refs.pop(r)
                try:
                    yield u, ray.get(r)
                except Exception as e:  # noqa: BLE001 - a task that died twice or could not run (ray.exceptions.*)
                    yield u, _failed(u, f"the Ray task failed: {_last_line(e)}")

    def close(self) -> None:
        if self._ray.is_initialized():
            self._ray.shutdown()


def _in_folder(cwd: str, fn: UnitFn, unit: WorkUnit, job: Job) -> UnitResult:
    """A Ray task: ``fn(unit, job)`` in the driver's working folder, so that the paths the driver was
    given (logs, bin model, config, labels), relative or not, name the same files on the node (which
    must mount them at the same place)."""
    try:
        os.chdir(cwd)
    except OSError:  # absolute paths may still name the files
        res = fn(unit, job)
        if res.error is not None:
            res.error += (f" (the driver's folder {cwd} is not on this Ray node: the logs must be on storage every "
                          "node mounts at the same place)")
        return res
    return fn(unit, job)


def _last_line(e: BaseException) -> str:
    lines = [line.strip() for line in str(e).splitlines() if line.strip()]
    return f"{type(e).__name__}: {lines[-1]}" if lines else type(e).__name__


class InlineExecutor:
    """Units run one after another in this process (``--workers 0``): no worker to start, the same
    results; for debugging a unit and for small runs where starting workers costs more than the work."""

    name = "this process"
    workers = 0

    def run(self, fn: UnitFn, units: list[WorkUnit], job: Job) -> Iterator[tuple[WorkUnit, UnitResult]]:
        for u in units:
            yield u, fn(u, job)

    def close(self) -> None:
        pass


def make_executor(*, workers: int | None, ray: str | None) -> Executor:
    """The executor the options choose: ``--ray ADDRESS``, ``--workers 0`` (this process) or local
    processes."""
    if ray is not None:
        if workers is not None:
            raise ConfigError("--workers is for local processes; a Ray cluster has its own CPUs")
        return RayExecutor(ray)
    if workers is not None and (isinstance(workers, bool) or workers < 0):
        raise ConfigError(f"--workers must be >= 0 (0: run in this process), got {workers!r}")
    if workers == 0:
        return InlineExecutor()
    return LocalExecutor(workers)
