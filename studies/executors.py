"""Run a study's units: on local processes (the default) or as Ray tasks on a cluster (``--ray``).

Both executors take the same picklable work function and units and yield ``(unit, result)`` as units
complete, so a slow log never holds back the others' results. A unit whose work raised returns the
error in its result (the work functions catch what a damaged log can throw); a worker process that
dies (a crash, the memory cap) is replaced and its unit retried once, then reported as failed.

Every worker owns its share of the cores: its thread pools (numba, OpenMP, BLAS) get
``cores // workers`` threads (1 on a Ray task of one CPU), so that workers do not oversubscribe the
machine; a variable the user set is kept. Ray workers also get the driver's ``ZCUT_*`` variables
and numba threading layer (they do not inherit the driver's environment), so a unit computes the
same on both executors.

Memory: a worker replaying the sensor's frames needs about 1.5 GB (:data:`WORKER_MEMORY_MB`). The
default number of local workers is what the free memory holds (at most the cores), and a Ray task
asks for that much of Ray's ``memory`` resource, so that Ray places no more tasks on a node than
its memory holds.

Ray is an optional extra (``pip install 'zcut[ray]'``): imported only by :class:`RayExecutor`.
An address is checked before Ray is asked to connect (Ray itself retries an unreachable cluster
for minutes): nothing listening, or something that does not speak gRPC, is a one-line error.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import socket
from collections.abc import Callable, Iterator, Mapping
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
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


def _worker_init() -> None:
    # the command line's process settings, in every worker (they start fresh: spawn)
    from replay.process import configure_process

    configure_process()


class LocalExecutor:
    """Units on ``workers`` local processes (started fresh: no inherited threads or files), each
    with ``cores // workers`` threads.

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
        self._pool: ProcessPoolExecutor | None = None

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(max_workers=self.workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_worker_init)

    def run(self, fn: UnitFn, units: list[WorkUnit], job: Job) -> Iterator[tuple[WorkUnit, UnitResult]]:
        pending = list(units)
        tries: dict[int, int] = {}
        while pending:
            futures: dict[Future[UnitResult], tuple[int, WorkUnit]] = {}
            with _environ(worker_environment(self.threads)):  # the workers start during the submits
                self._pool = self._new_pool()
                for i, u in enumerate(pending):
                    futures[self._pool.submit(fn, u, job)] = (i, u)
            retry: list[WorkUnit] = []
            broken = False
            while futures:
                done, _ = wait(futures, return_when=FIRST_COMPLETED)
                for f in done:
                    i, u = futures.pop(f)
                    try:
                        yield u, f.result()
                    except BrokenProcessPool:
                        broken = True
                        key = id(u)
                        tries[key] = tries.get(key, 0) + 1
                        if tries[key] >= 2:
                            yield u, _failed(u, "the worker process died twice on this unit (a crash or out of memory)")
                        else:
                            retry.append(u)
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
            pending = retry if broken else []

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None


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
            raise ConfigError("--ray needs the ray package: pip install 'zcut[ray]'") from None
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
