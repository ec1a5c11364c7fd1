"""``zcut batch`` on a real local Ray cluster (``ray start --head``, no mocks) against local processes
and the sequential ``zcut replay``.

The cluster runs in network, PID and mount namespaces of its own (``ray_in_netns.py``): Ray rewrites
127.0.0.1 to the machine's interface address, and test traffic must stay on loopback, the only
interface there. Needs the ``ray`` extra and ``unshare``: without them the test is skipped with the
reason, except under CI (``CI`` set), where it fails.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from ray_in_netns import ADDRESS

ZCUT = str(Path(sys.executable).with_name("zcut"))
COUNTS = ("valid_px", "zcut", "sor", "both", "above_rim", "clusters")


def _ray_missing() -> str | None:
    try:
        import ray  # noqa: F401
    except ImportError:
        return "the ray package is not installed (pip install 'zcut[ray]')"
    return None


def _require(why: str | None) -> None:
    if why is None:
        return
    if os.environ.get("CI"):
        pytest.fail(f"CI must run the Ray tests: {why}")
    pytest.skip(why)


def _zcut(*args: str, cwd: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([ZCUT, *args], cwd=cwd, check=False, capture_output=True, text=True, env=env)


def _ok(p: subprocess.CompletedProcess) -> subprocess.CompletedProcess:
    assert p.returncode == 0, f"exit {p.returncode}: {p.stderr[-3000:]}"
    return p


def zcut_here(*args: str | Path) -> str:
    """``zcut ARGS`` in this process (the inputs' preparation: the same command without a process start-up
    of ~1.5 CPU s, paths absolute): its stdout; exit status 0 asserted."""
    import contextlib
    import io

    from cli.main import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = main([str(a) for a in args])
    assert rc == 0, args
    return out.getvalue()


def rechunk(src: Path, dst: Path, *, chunk_size: int) -> None:
    """Copy an MCAP log record for record into chunks of about ``chunk_size`` bytes (a long log's
    layout: one cloud per chunk), metadata and attachments included."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with open(src, "rb") as f, open(dst, "wb") as g:
        r = make_reader(f)
        header = r.get_header()
        w = Writer(g, chunk_size=chunk_size)
        w.start(profile=header.profile, library=header.library)
        for m in r.iter_metadata():
            w.add_metadata(m.name, dict(m.metadata))
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, msg in r.iter_messages(log_time_order=False):
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding,
                                                          schemas.get(channel.schema_id, 0), dict(channel.metadata))
            w.add_message(channels[channel.id], msg.log_time, msg.data, msg.publish_time, msg.sequence)
        for a in r.iter_attachments():
            w.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
        w.finish()


def table_differences(a, b, *, rtol: float = 1e-9) -> list[str]:
    """Cells where two frames tables differ: exactly, except float columns (ICP's fitness, RMSE and
    pose error), equal to ``rtol``: the registration's last bits vary from process to process (two
    runs on local processes differ there too), never a count."""
    import pyarrow as pa

    if a.column_names != b.column_names or a.num_rows != b.num_rows:
        return [f"shape: {a.column_names} x {a.num_rows} vs {b.column_names} x {b.num_rows}"]
    out = []
    for name in a.column_names:
        x, y = a.column(name).to_pylist(), b.column(name).to_pylist()
        floating = pa.types.is_floating(a.schema.field(name).type)
        for i, (u, v) in enumerate(zip(x, y)):
            same = u == v or (floating and u is not None and v is not None and abs(u - v) <= rtol * max(abs(u), abs(v)))
            if not same:
                where = f"row {i}" + (f" (frame {a.column('frame')[i]})" if "frame" in a.column_names else "")
                out.append(f"{where} {name}: {u!r} vs {v!r}")
    return out


def _frames(out: Path):
    """frames.parquet without the timing columns (they differ run to run)."""
    t = pq.read_table(out / "frames.parquet")
    return t.drop_columns([c for c in t.column_names if c.startswith("t_") and c.endswith("_s")])


def prepare_batch(d: Path) -> tuple[dict, list[dict]]:
    """Two small synthetic logs (and one rechunked to a chunk per cloud), a bin model; the sequential
    replays, the local batch and sweep; returns them and the commands for the Ray cluster: the batch,
    the batch of the rechunked log in units of one frame, two unreachable addresses and the sweep."""
    logs = ["a.mcap", "b.mcap"]
    for seed, name in enumerate(logs, start=1):
        zcut_here("synth", "-o", d / name, "--parts", "rods", "--frames", "4", "--seed", str(seed), "--size", "120x160")
    zcut_here("synth", "-o", d / "empty.mcap", "--empty", "--frames", "2", "--seed", "3", "--size", "120x160")
    zcut_here("bin-model", d / "empty.mcap", "-o", d / "bin.ply")
    rechunk(d / "a.mcap", d / "a_split.mcap", chunk_size=16 * 1024)
    # sequential replays first: they also warm numba's caches for the workers
    replay = {name: json.loads(zcut_here("replay", d / name, "--bin-model", d / "bin.ply", "--json")) for name in logs}
    local = _zcut("batch", *logs, "-o", "local", "--bin-model", "bin.ply", cwd=d)
    grid = ["--step", "0.2,0.4", "--max-depth", "15,30", "--rho", "0.05,0.07", "--sor-k", "4", "--sor-std", "1,2",
            "--no-report", "--bin-model", "bin.ply"]
    sweep_local = _zcut("sweep", *logs, "-o", "sweep_local", *grid, cwd=d)
    z = {"cwd": str(d)}
    commands = [
        {"argv": [ZCUT, "batch", *logs, "-o", "ray", "--bin-model", "bin.ply", "--ray", ADDRESS], **z},
        {"argv": [ZCUT, "batch", "a_split.mcap", "-o", "ray_split", "--bin-model", "bin.ply", "--ray", "auto",
                  "--frames-per-unit", "1"], **z},  # RAY_ADDRESS is set
        {"argv": [ZCUT, "batch", *logs, "-o", "nowhere", "--ray", "127.0.0.1:1"], **z},
        {"argv": [ZCUT, "batch", *logs, "-o", "nowhere_auto", "--ray", "auto"], "env": {"RAY_ADDRESS": "127.0.0.1:2"},
         **z},
        {"argv": [ZCUT, "sweep", *logs, "-o", "sweep_ray", *grid, "--ray", ADDRESS], **z},
    ]
    return {"dir": d, "logs": logs, "replay": replay, "local": local, "sweep_local": sweep_local}, commands


def collect_batch(prepared: dict, results: list[dict], interfaces: list[str]) -> dict:
    ray, split, nowhere, nowhere_auto, sweep_ray = results
    return {**prepared, "ray": ray, "split": split, "nowhere": [nowhere, nowhere_auto], "interfaces": interfaces,
            "sweep_ray": sweep_ray}


@pytest.fixture(scope="module")
def runs(ray_cluster_runs):
    """The batch's part of the session's one Ray cluster run (tests/studies/conftest.py)."""
    return ray_cluster_runs["batch"]


def test_the_cluster_saw_loopback_only(runs):
    assert runs["interfaces"] == ["lo"]


def test_ray_table_equals_local_processes(runs):
    _ok(runs["local"])
    assert runs["ray"]["rc"] == 0, runs["ray"]["stderr"][-3000:]
    d = runs["dir"]
    local, ray = _frames(d / "local"), _frames(d / "ray")
    assert local.num_rows == ray.num_rows == 8
    assert table_differences(ray, local) == [], "the Ray table differs from the local processes' table"
    summary = json.loads((d / "ray" / "summary.json").read_text())["this_run"]
    assert (summary["executor"], summary["workers"], summary["frames"]) == ("Ray", 2, 8)
    assert json.loads((d / "local" / "summary.json").read_text())["this_run"]["executor"] == "local processes"


def test_counts_equal_sequential_replay(runs):
    assert runs["ray"]["rc"] == 0, runs["ray"]["stderr"][-3000:]
    rows = {(r["log"], r["frame"]): r for r in _frames(runs["dir"] / "ray").to_pylist()}
    n = 0
    for name in runs["logs"]:
        for f in runs["replay"][name]["frames"]:
            row = rows[(name, f["index"])]
            assert {c: row[c] for c in COUNTS} == {c: f[c] for c in COUNTS}, (name, f["index"])
            assert row["stamp_ns"] == f["stamp_ns"]
            assert row["fitness"] == (None if f["fitness"] is None else pytest.approx(f["fitness"], rel=1e-9))
            n += 1
    assert n == len(rows) == 8


def test_a_log_split_over_ray_tasks_gives_the_same_rows(runs):
    split = runs["split"]
    assert split["rc"] == 0, split["stderr"][-3000:]
    d = runs["dir"]
    parts = sorted((d / "ray_split" / "parts").glob("*.json"))
    assert len(parts) == 4, "one unit (one Ray task) per frame of the rechunked log"
    assert sorted((json.loads(p.read_text())["start"]) for p in parts) == [0, 1, 2, 3]
    got = _frames(d / "ray_split").drop_columns(["log", "log_sha256"])
    local = _frames(d / "local")
    want = local.filter(pc.equal(local.column("log"), "a.mcap"))
    assert table_differences(got, want.drop_columns(["log", "log_sha256"])) == [], \
        "units of one frame on Ray differ from one unit on local processes (and so from the replay)"


def test_sweep_on_ray_equals_the_sweep_on_local_processes(runs):
    """``zcut sweep --ray``: the same units on the same executor as batch; every count of every
    parameter set, frame and method equals the local run's, and so do the pooled figures."""
    _ok(runs["sweep_local"])
    assert runs["sweep_ray"]["rc"] == 0, runs["sweep_ray"]["stderr"][-3000:]
    import pyarrow as pa

    d = runs["dir"]

    def table(name):
        t = pq.read_table(d / name / "sweep.parquet")
        t = t.drop_columns([c for c in t.column_names if c.startswith("t_") and c.endswith("_s")])
        keys = [c for c in t.column_names if t.schema.field(c).type in (pa.string(), pa.large_string())
                or pa.types.is_integer(t.schema.field(c).type) or pa.types.is_floating(t.schema.field(c).type)]
        return t.sort_by([(k, "ascending") for k in keys])

    local, ray = table("sweep_local"), table("sweep_ray")
    assert local.num_rows == ray.num_rows > 0
    assert sorted(set(ray.column("frame").to_pylist())) == [0, 1, 2, 3]
    assert table_differences(ray, local) == [], "the Ray sweep differs from the local processes' sweep"
    pooled = [json.loads((d / n / "summary.json").read_text())["sets"] for n in ("sweep_local", "sweep_ray")]
    assert pooled[0] == pooled[1]
    import tomllib

    assert tomllib.loads((d / "sweep_ray" / "tuned.toml").read_text()) == \
        tomllib.loads((d / "sweep_local" / "tuned.toml").read_text())


@pytest.mark.parametrize("case, pattern", [
    (0, r"^error: --ray 127\.0\.0\.1:1: cannot reach a Ray cluster at 127\.0\.0\.1:1 \(Connection refused\)$"),
    (1, r"^error: --ray auto \(127\.0\.0\.1:2\): cannot reach a Ray cluster at 127\.0\.0\.1:2 \(Connection refused\)$"),
])
def test_unreachable_address_is_a_one_line_error_before_any_work(runs, case, pattern):
    import re

    r = runs["nowhere"][case]
    assert r["rc"] == 1, r["stderr"][-3000:]
    lines = r["stderr"].strip().splitlines()
    assert len(lines) == 1 and re.match(pattern, lines[0]), r["stderr"][-3000:]
    assert "Traceback" not in r["stderr"]
    assert not (runs["dir"] / ("nowhere", "nowhere_auto")[case]).exists(), "no output before the address is known good"


@pytest.fixture(scope="module")
def tiny_log(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("tiny")
    zcut_here("synth", "-o", d / "a.mcap", "--frames", "1", "--size", "40x30")
    return d / "a.mcap"


@pytest.mark.parametrize("args, env, message", [
    (["--ray", "auto"], {}, "--ray auto: no cluster found (RAY_ADDRESS is not set and no `ray start` on this machine)"),
    (["--ray", "auto"], {"RAY_ADDRESS": "http://127.0.0.1:8265"},
     "--ray auto (http://127.0.0.1:8265): not a Ray address (HOST:PORT, ray://HOST:PORT or auto)"),
    (["--ray", "head-node"], {}, "--ray head-node: not a Ray address (HOST:PORT, ray://HOST:PORT or auto)"),
    (["--ray", "127.0.0.1:6379", "--workers", "2"], {}, "--workers is for local processes; a Ray cluster has its own CPUs"),
], ids=["auto-without-cluster", "dashboard-url", "no-port", "workers-with-ray"])
def test_bad_ray_options_are_one_line_errors(tiny_log, tmp_path, args, env, message):
    """Refused before any connection (no namespace needed) and before any output."""
    _require(_ray_missing())
    (tmp_path / "raytmp").mkdir()
    base = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    p = _zcut("batch", str(tiny_log), "-o", "out", *args, cwd=tmp_path,
              env={**base, "RAY_TMPDIR": str(tmp_path / "raytmp"), **env})
    assert (p.returncode, p.stderr) == (1, f"error: {message}\n")
    assert not (tmp_path / "out").exists()


@pytest.fixture
def http1_server():
    """A loopback server that answers HTTP/1.1, as a web server on the port would: not gRPC."""
    import socket
    import threading

    srv = socket.create_server(("127.0.0.1", 0))

    def serve() -> None:
        try:
            conn, _ = srv.accept()
        except OSError:
            return
        with conn:
            conn.recv(1024)
            conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    yield srv.getsockname()[1]
    srv.close()
    t.join(timeout=10)


def test_an_address_that_is_not_a_ray_cluster_is_refused(tiny_log, tmp_path, http1_server):
    _require(_ray_missing())
    p = _zcut("batch", str(tiny_log), "-o", "out", "--ray", f"127.0.0.1:{http1_server}", cwd=tmp_path)
    want = f"--ray 127.0.0.1:{http1_server}: 127.0.0.1:{http1_server} answers, but not as a Ray cluster (no gRPC)"
    assert (p.returncode, p.stderr) == (1, f"error: {want}\n")
    assert not (tmp_path / "out").exists()
