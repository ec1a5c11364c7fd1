"""Run a study's units: on local processes (the default) or as Ray tasks on a cluster (``--ray``).

Both executors take the same picklable work function and units and yield ``(unit, result)`` as units
complete, so a slow log never holds back the others' results. A unit whose work raised returns the
error in its result (the work functions catch what a damaged log can throw); a worker process that
dies (a crash, the memory cap) is replaced and its unit retried once, then reported as failed.

Ray is an optional extra (``pip install 'zcut[ray]'``): imported only by :class:`RayExecutor`.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Protocol

from replay.errors import ConfigError


class Executor(Protocol):
    """Runs ``fn(unit, job)`` for every unit; yields ``(unit, result)`` in completion order."""

    name: str
    workers: int

    def run(self, fn: Callable[[Any, Any], Any], units: list, job: Any) -> Iterator[tuple[Any, Any]]: ...

    def close(self) -> None: ...


def default_workers() -> int:
    """The cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def _worker_init() -> None:
    # the command line's process settings, in every worker (they start fresh: spawn)
    from replay.process import configure_process

    configure_process()


class LocalExecutor:
    """Units on ``workers`` local processes (started fresh: no inherited threads or files).

    Parameters
    ----------
    workers : int
        Processes (default: the cores).
    """

    name = "local processes"

    def __init__(self, workers: int | None = None) -> None:
        if workers is not None and (isinstance(workers, bool) or workers < 1):
            raise ConfigError(f"--workers must be >= 1, got {workers!r}")
        self.workers = workers or default_workers()
        self._pool: ProcessPoolExecutor | None = None

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(max_workers=self.workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_worker_init)

    def run(self, fn, units, job):
        pending = list(units)
        tries: dict[int, int] = {}
        while pending:
            self._pool = self._new_pool()
            futures: dict[Future, tuple[int, Any]] = {}
            for i, u in enumerate(pending):
                futures[self._pool.submit(fn, u, job)] = (i, u)
            retry: list = []
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


def _failed(unit, why: str):
    from studies.work import UnitResult

    return UnitResult.failure(unit, why)


class RayExecutor:
    """Units as Ray tasks on an existing cluster.

    Parameters
    ----------
    address : str
        The cluster (``ray://HOST:PORT``, ``HOST:PORT``), or ``auto`` for ``RAY_ADDRESS`` / the local
        cluster ``ray start`` made.
    """

    name = "Ray"

    def __init__(self, address: str) -> None:
        try:
            import ray
        except ImportError:
            raise ConfigError("--ray needs the ray package: pip install 'zcut[ray]'") from None
        if address == "auto" and not os.environ.get("RAY_ADDRESS") and not _local_ray_running():
            raise ConfigError("--ray auto: no cluster found (RAY_ADDRESS is not set and no local `ray start`)")
        try:
            ray.init(address=address, ignore_reinit_error=True, log_to_driver=False, include_dashboard=False,
                     logging_level="ERROR")
        except Exception as e:  # ray raises ConnectionError, RuntimeError, ValueError...
            raise ConfigError(f"--ray {address}: cannot connect to the Ray cluster ({type(e).__name__}: "
                              f"{str(e).splitlines()[0] if str(e) else ''})") from None
        self._ray = ray
        self.workers = int(ray.cluster_resources().get("CPU", 1))

    def run(self, fn, units, job):
        ray = self._ray
        remote = ray.remote(num_cpus=1, max_retries=1)(fn)
        job_ref = ray.put(job)
        refs = {remote.remote(u, job_ref): u for u in units}
        while refs:
            done, _ = ray.wait(list(refs), num_returns=1)
            for r in done:
                u = refs.pop(r)
                try:
                    yield u, ray.get(r)
                except Exception as e:  # a task that died twice (ray.exceptions.*)
                    yield u, _failed(u, f"the Ray task failed: {type(e).__name__}")

    def close(self) -> None:
        self._ray.shutdown()


def _local_ray_running() -> bool:
    from pathlib import Path

    return Path("/tmp/ray/ray_current_cluster").is_file()


def make_executor(*, workers: int | None, ray: str | None) -> Executor:
    """The executor the options choose: ``--ray ADDRESS`` or local processes."""
    if ray is not None:
        if workers is not None:
            raise ConfigError("--workers is for local processes; a Ray cluster has its own CPUs")
        return RayExecutor(ray)
    return LocalExecutor(workers)
