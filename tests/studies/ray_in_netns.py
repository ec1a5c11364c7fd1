"""Run commands against a real, private Ray cluster inside network, PID and mount namespaces of
their own (for the Ray tests and ``bench/bench_batch.py``).

Ray rewrites 127.0.0.1 to the machine's interface address, and test traffic must stay on loopback.
So the cluster runs inside ``unshare --net --pid --fork --mount-proc``: loopback is the only
network interface there (checked), the PID namespace confines the cluster's stop (a SIGKILL to
every process in it, where ``ray stop`` would stop every Ray process of the machine) and guarantees
the cleanup: when the namespace's first process
exits, or is killed with its ``unshare`` (``--kill-child``; ``unshare`` itself is killed when its
caller dies or times out), the kernel kills every process left in it. The cluster's files go to a temporary folder of its own (not the shared ``/tmp/ray``),
removed afterwards.

Outside (the caller)::

    from ray_in_netns import run_with_ray_cluster, netns_unavailable
    why = netns_unavailable()                   # None, or why namespaces cannot be made here
    out = run_with_ray_cluster([{"argv": [...], "env": {...}}, ...], cpus=2)
    out["results"][0]["rc"], out["results"][0]["stderr"], out["results"][0]["wall_s"]
    out["results"][0]["procs"]                  # CPU seconds per process of the namespace (run_measured)

Inside (``python ray_in_netns.py SPEC.json``, run by :func:`run_with_ray_cluster`): bring ``lo``
up, check it is the only interface, ``ray start --head --node-ip-address 127.0.0.1``, run each
command in turn with ``RAY_ADDRESS`` set, kill the cluster (:func:`_stop_cluster`), write the results as JSON.
"""

from __future__ import annotations

import fcntl
import json
import os
import resource
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

RAY_PORT = 6379
ADDRESS = f"127.0.0.1:{RAY_PORT}"
UNSHARE = ("unshare", "--net", "--pid", "--fork", "--mount-proc", "--kill-child")


def netns_unavailable() -> str | None:
    """None when this process may create the namespaces, else why not (one line)."""
    if shutil.which("unshare") is None:
        return "the unshare command (util-linux) is missing"
    try:
        p = subprocess.run([*UNSHARE, "true"], check=False, capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired) as e:
        return f"unshare failed: {e}"
    if p.returncode != 0:
        why = (p.stderr.strip().splitlines() or [f"exit {p.returncode}"])[-1]
        return f"cannot create network/PID namespaces here ({why})"
    return None


def run_with_ray_cluster(commands: list[dict], *, cpus: int = 2, timeout: float = 600.0) -> dict:
    """Start a private Ray cluster of ``cpus`` CPUs in fresh namespaces, run ``commands`` there in
    turn, stop the cluster.

    Parameters
    ----------
    commands : list of dict
        Each ``{"argv": [...], "env": {...} (optional, added to the environment),
        "cwd": str (optional)}``. ``RAY_ADDRESS`` is set to the cluster for every command.
    cpus : int
        The cluster's CPUs (``ray start --num-cpus``).
    timeout : float
        Seconds for the whole run; the namespace (cluster included) is killed after that.

    Returns
    -------
    dict
        ``{"ray_start_s": float, "ray_stop_s": float, "interfaces": [...], "results": [{"argv", "rc",
        "stdout", "stderr", "wall_s", "pid", "procs", "children_cpu_s"}, ...]}`` (see
        :func:`run_measured`).

    Raises
    ------
    RuntimeError
        The namespace or the cluster could not be set up (its stderr in the message).
    """
    with tempfile.TemporaryDirectory(prefix="zcr", dir="/tmp") as tmp:  # short: Ray's socket paths
        spec = Path(tmp) / "spec.json"
        out = Path(tmp) / "out.json"
        spec.write_text(json.dumps({"commands": commands, "cpus": cpus, "temp_dir": str(Path(tmp) / "ray"),
                                    "out": str(out)}))
        log = Path(tmp) / "stderr.txt"
        try:
            with open(log, "w") as err:
                p = subprocess.run([*UNSHARE, sys.executable, __file__, str(spec)], check=False, stdout=err, stderr=err,
                                   timeout=timeout, preexec_fn=_die_with_parent)
        except subprocess.TimeoutExpired:  # unshare killed: --kill-child takes the namespace down
            raise RuntimeError(f"the Ray namespace run took more than {timeout:.0f} s: {_tail(log.read_text())}") from None
        if p.returncode != 0 or not out.is_file():
            raise RuntimeError(f"the Ray namespace run failed (exit {p.returncode}): {_tail(log.read_text())}")
        return json.loads(out.read_text())


def _die_with_parent() -> None:
    """In the child before ``unshare`` runs: killed when the caller dies (even by SIGKILL), which takes
    the namespace and its cluster down (``--kill-child``)."""
    import ctypes
    import signal

    PR_SET_PDEATHSIG = 1
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)


def _tail(text: str, n: int = 3000) -> str:
    return text[-n:]


# --- inside the namespaces --------------------------------------------------------------------

SIOCGIFFLAGS, SIOCSIFFLAGS, IFF_UP = 0x8913, 0x8914, 0x1


def _loopback_up() -> list[str]:
    """Bring ``lo`` up (no ``ip`` command needed); return the interfaces, which must be ``lo`` only."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        req = struct.pack("16sh", b"lo", 0)
        flags = struct.unpack("16sh", fcntl.ioctl(s, SIOCGIFFLAGS, req))[1]
        fcntl.ioctl(s, SIOCSIFFLAGS, struct.pack("16sh", b"lo", flags | IFF_UP))
    names = [name for _, name in socket.if_nameindex()]
    if names != ["lo"]:
        raise SystemExit(f"ray_in_netns: interfaces other than lo in the namespace: {names}")
    return names


_TICK = os.sysconf("SC_CLK_TCK")


def _proc_table() -> dict[tuple[int, int], tuple[int, float]]:
    """``(pid, start time) -> (ppid, CPU seconds)`` of every process in view."""
    out = {}
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat", "rb") as f:
                raw = f.read()
        except OSError:
            continue
        rest = raw[raw.rindex(b")") + 2:].split()
        out[(int(name), int(rest[19]))] = (int(rest[1]), (int(rest[11]) + int(rest[12])) / _TICK)
    return out


def _cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode(errors="replace").strip()[:200]
    except OSError:
        return ""


def run_measured(argv: list[str], *, env: dict | None = None, cwd: str | None = None, scope: str = "tree",
                 interval: float = 0.25) -> dict:
    """Run a command and measure the CPU time of the processes it keeps busy, from ``/proc``.

    Parameters
    ----------
    argv, env, cwd
        The command.
    scope : {"tree", "all"}
        The command and its descendants, or every process in view but this one (inside a PID
        namespace: the command and the Ray cluster it uses).
    interval : float
        Seconds between samples; a process that exits loses at most this much of its CPU time.

    Returns
    -------
    dict
        ``{"argv", "rc", "stdout", "stderr", "wall_s", "pid", "procs": [{"pid", "ppid", "cmd",
        "cpu_s"}, ...]}``: ``procs`` are the processes that used >= 0.05 CPU s during the command.
    """
    before = _proc_table()
    last: dict[tuple[int, int], tuple[int, float]] = {}
    names: dict[tuple[int, int], str] = {}
    stop = threading.Event()

    def sample() -> None:
        while True:
            for k, v in _proc_table().items():
                last[k] = v
                if k not in names:
                    names[k] = _cmdline(k[0])
            if stop.wait(interval):
                return

    t = time.perf_counter()
    p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=cwd)
    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    out, err = p.communicate()
    wall = time.perf_counter() - t
    stop.set()
    sampler.join()
    last.update(_proc_table())
    keep = set(last)
    if scope == "tree":
        keep, grow = set(), {p.pid}
        while grow:
            keep |= {k for k, (ppid, _) in last.items() if k[0] in grow}
            grow = {k[0] for k, (ppid, _) in last.items() if ppid in grow} - {k[0] for k in keep}
    procs = []
    for k in keep:
        if k[0] == os.getpid():
            continue
        ppid, cpu = last[k]
        used = cpu - before.get(k, (0, 0.0))[1]
        if used >= 0.05:
            procs.append({"pid": k[0], "ppid": ppid, "cmd": names.get(k, ""), "cpu_s": round(used, 3)})
    return {"argv": argv, "rc": p.returncode, "stdout": out, "stderr": err, "wall_s": wall, "pid": p.pid,
            "procs": procs}


def _stop_cluster(ray_bin: str, env: dict) -> None:
    """Kill every process of the namespace but this one, and reap them.

    This process is the namespace's PID 1 (``unshare --pid --fork``): the daemons ``ray start`` leaves
    behind are its children once ``ray start`` exits, and ``kill(-1, SIGKILL)`` reaches exactly the
    processes of its PID namespace. ``ray stop --force`` sends the same SIGKILLs, then waits for the
    processes to be gone; here they stay zombies until PID 1 reaps them, so it waited out its whole grace
    period (three rounds of 16 / 3 + 2 s: ~22 s of sleep a run). Outside a PID namespace of its own (never,
    when run by :func:`run_with_ray_cluster`) this falls back to ``ray stop --force``."""
    import signal

    if os.getpid() != 1:
        subprocess.run([ray_bin, "stop", "--force"], check=False, capture_output=True, env=env, timeout=120)
        return
    try:
        os.kill(-1, signal.SIGKILL)  # from PID 1: every other process of this PID namespace
    except ProcessLookupError:  # none left
        return
    while True:
        try:
            os.waitpid(-1, 0)
        except ChildProcessError:  # all reaped
            return
        except InterruptedError:
            continue


def _inside(spec_path: str) -> int:
    spec = json.loads(Path(spec_path).read_text())
    interfaces = _loopback_up()
    ray_bin = str(Path(sys.executable).with_name("ray"))
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    env["RAY_USAGE_STATS_ENABLED"] = "0"
    t0 = time.perf_counter()
    # no autoscaler monitor (a fixed local cluster: nothing to scale) and no log monitor (the drivers ask for no
    # workers' logs: ``log_to_driver=False``): two Python daemons fewer to start and to keep polling
    start = subprocess.run([ray_bin, "start", "--head", "--node-ip-address", "127.0.0.1", "--port", str(RAY_PORT),
                            "--num-cpus", str(spec["cpus"]), "--disable-usage-stats", "--include-dashboard",
                            "false", "--no-monitor", "--include-log-monitor", "false", "--temp-dir", spec["temp_dir"]],
                           check=False, capture_output=True, text=True, env=env, timeout=300)
    ray_start_s = time.perf_counter() - t0
    if start.returncode != 0:
        print(f"ray start failed (exit {start.returncode}):\n{start.stdout}\n{start.stderr}", file=sys.stderr)
        return 2
    env["RAY_ADDRESS"] = ADDRESS
    print(f"ray_in_netns: cluster up in {ray_start_s:.1f} s", file=sys.stderr, flush=True)
    results = []
    try:
        for c in spec["commands"]:
            r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            res = run_measured(c["argv"], env={**env, **c.get("env", {})}, cwd=c.get("cwd"), scope="all")
            print(f"ray_in_netns: exit {res['rc']} after {res['wall_s']:.1f} s: {' '.join(c['argv'][:3])}",
                  file=sys.stderr, flush=True)
            r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            res["children_cpu_s"] = (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)
            results.append(res)
    finally:
        t = time.perf_counter()
        _stop_cluster(ray_bin, env)
        ray_stop_s = time.perf_counter() - t
    Path(spec["out"]).write_text(json.dumps({"ray_start_s": ray_start_s, "ray_stop_s": ray_stop_s,
                                             "interfaces": interfaces,
                                             "results": results}))
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit("usage: ray_in_netns.py SPEC.json   (run by run_with_ray_cluster, inside unshare)")
    sys.exit(_inside(sys.argv[1]))
