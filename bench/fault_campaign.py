"""A held-out fault campaign against zcut's command-line contract (README: outputs, one writer per
output, exit status), with generators of its own (not the fuzz suite's):

- **full disk**: every writing command with its outputs on real tmpfs mounts of several sizes
  (and the labelling server with its store on a full disk);
- **signals**: SIGINT, SIGTERM and SIGKILL at random moments of replay, batch, sweep, synth, record,
  bin-model and annotate; after a SIGKILL the same command is run again (it must take the lock over,
  remove the leftovers and, for a study, resume);
- **concurrent writers**: two processes writing one output at once;
- **unprivileged user**: ``setpriv`` to ``nobody`` (its own HOME and numba cache), outputs in folders
  it cannot write, a label store in a folder it cannot write, logs it cannot read;
- **hostile-but-valid logs**, written by an independent writer (the ``mcap`` library and
  ``mcap_ros2``'s CDR serializer from message definitions written here, not zcut's writer):
  reordered and padded point fields, big-endian and float64 clouds, rows with padding, an
  unorganized cloud, NaN everywhere, one point, identical points, duplicate and unordered stamps,
  unchunked and index-less files, lz4 and uncompressed chunks, foreign image encodings and sizes, an
  all-zero CameraInfo, two organized clouds, an empty log, a huge frame_id;

and issue 35's second campaign:

- **stop/cont**: SIGSTOP then SIGCONT (a job suspended and resumed), and SIGTERM to a stopped job;
- **SIGHUP** at random moments of every long command (a closed terminal: 129, as SIGTERM's clean-up);
- **process group**: SIGINT, SIGTERM, SIGHUP to the whole group of a batch, a sweep, a replay;
- **stdout** closed (``>&-``) or full (``>/dev/full``): file outputs complete, one line, exit 1;
- **ulimit** ``-v`` (address space), ``-n`` (descriptors), ``-f`` (file size), set in the child;
- **names** with spaces, unicode, a newline, 255 bytes, for inputs and outputs;
- **links/FIFOs**: symlink loops and FIFOs as inputs and outputs (never a hang), a batch of a folder
  with a dangling and a looping ``.mcap`` link;
- **argparse**: a mistake of every kind (choice, type, missing value or argument, clash, unknown
  option or command) is exactly one line naming it;
- **issue 35 (others)**: a study resumed after its input changed, a ground-truth mask of the wrong
  size, a label store held by another writer (``BEGIN EXCLUSIVE``), the output folder removed while
  ``replay --rrd`` writes.

Every case gives one row: the case, the exit status, the one-line message (the ``error:`` line, else
the last line), whether the inputs are intact (SHA-256 before and after), the leftovers (zcut's
temporaries and lock files, and processes of the case still alive), whether every output present
under its final name is complete (read back: MCAP to its footer with CRCs, .rrd with Rerun's own
reader, PLY, TOML, Parquet, JSON, SQLite integrity) and whether the row is clean (the exit status
is one the contract allows, at most one ``error:`` line, no traceback, inputs intact, no leftovers,
outputs complete).

    .venv/bin/python bench/fault_campaign.py --work /tmp/campaign [--seed 1] [--only GROUP ...] [--size 128x96]

Needs root (tmpfs mounts, ``setpriv``); on a machine that refuses them those groups are skipped and
say so. Prints the table as Markdown and the number of clean rows; exit status 0 when all are clean.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import random
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ZCUT = [sys.executable, "-m", "cli"]
SIZE = "480x640"


# --------------------------------------------------------------------------------- the rows


@dataclass
class Row:
    group: str
    case: str
    exit: str
    message: str
    inputs_intact: bool
    leftovers: list[str] = field(default_factory=list)
    outputs_complete: bool = True
    allowed: bool = True
    one_line: bool = True

    @property
    def clean(self) -> bool:
        return self.allowed and self.one_line and self.inputs_intact and not self.leftovers and self.outputs_complete


@dataclass
class Run:
    rc: int
    out: str
    err: str
    seconds: float


def run(argv, *, timeout: float = 1200, env: dict | None = None, user: str | None = None) -> Run:
    """Run ``zcut ARGV`` (a hang is a failure: rc 'timeout')."""
    cmd = [*ZCUT, *map(str, argv)]
    full_env = dict(os.environ, **(env or {}))
    if user is not None:
        cmd = ["setpriv", f"--reuid={user}", f"--regid={user_group(user)}", "--clear-groups", *cmd]
    t0 = time.monotonic()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=full_env, cwd="/")
        return Run(p.returncode, p.stdout, p.stderr, time.monotonic() - t0)
    except subprocess.TimeoutExpired as e:
        return Run(-999, e.stdout or "", f"HANG after {timeout:g} s", time.monotonic() - t0)


def user_group(user: str) -> str:
    import grp
    import pwd

    return grp.getgrgid(pwd.getpwnam(user).pw_gid).gr_name


def message_of(err: str) -> tuple[bool, str]:
    """(at most one error line and no traceback, the line to show)."""
    lines = [ln for ln in err.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("error:")]
    ok = len(errors) <= 1 and "Traceback" not in err and "HANG" not in err
    shown = errors[0] if errors else (lines[-1] if lines else "-")
    return ok, shown[:150]


def digest(paths) -> dict[str, str]:
    out = {}
    for p in map(Path, paths):
        files = sorted(q for q in p.rglob("*") if q.is_file()) if p.is_dir() else [p]
        for f in files:
            try:
                out[str(f)] = hashlib.sha256(f.read_bytes()).hexdigest()
            except OSError as e:
                out[str(f)] = f"unreadable: {e.strerror}"
    return out


def leftovers(*folders) -> list[str]:
    """zcut's temporaries and lock files under ``folders``."""
    found = []
    for folder in map(Path, folders):
        if not folder.exists():
            continue
        for q in folder.rglob(".*"):
            if ".partial" in q.name or q.name.endswith(".zcut.lock") or q.name == ".zcut.lock":
                found.append(q.name)
    return sorted(found)


def live_processes(marker: str) -> list[str]:
    """Processes (other than this one) whose command line names ``marker``: workers left behind."""
    found = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit() or int(d.name) == os.getpid():
            continue
        try:
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            state = (d / "stat").read_text().split(") ")[-1][0]
        except OSError:
            continue
        if marker in cmd and state != "Z":
            found.append(f"pid {d.name}")
    return found


def wait_gone(marker: str, seconds: float = 5.0) -> list[str]:
    deadline = time.monotonic() + seconds
    while (left := live_processes(marker)) and time.monotonic() < deadline:
        time.sleep(0.1)
    return left


def complete(path: Path) -> bool:
    """The output at ``path`` (a file or a folder of them) reads back whole."""
    if path.is_dir():
        return all(complete(q) for q in path.rglob("*") if q.is_file() and not q.name.startswith("."))
    try:
        suffix = path.suffix.lower()
        if suffix == ".mcap":
            from mcap.records import Footer
            from mcap.stream_reader import StreamReader

            with open(path, "rb") as f:
                last = None
                for rec in StreamReader(f, skip_magic=False, emit_chunks=False, validate_crcs=True).records:
                    last = rec
            return isinstance(last, Footer)
        if suffix == ".rrd":
            sys.path.insert(0, str(REPO))
            from replay.pipeline.viz import rrd_problem

            return rrd_problem(str(path)) is None
        if suffix == ".ply":
            from plyfile import PlyData

            PlyData.read(str(path))
            return True
        if suffix == ".toml":
            tomllib.loads(path.read_text())
            return True
        if suffix == ".parquet":
            import pyarrow.parquet as pq

            pq.read_table(path)
            return True
        if suffix == ".json":
            json.loads(path.read_text())
            return True
        if suffix == ".sqlite":
            db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
            try:
                return db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
            finally:
                db.close()
        if suffix == ".png":
            return path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        return path.stat().st_size > 0 or suffix in (".html",)
    except Exception:  # noqa: BLE001 - any failure to read it back is an incomplete output
        return False


def outputs_complete(folder: Path) -> bool:
    if not folder.exists():
        return True
    return all(complete(q) for q in folder.rglob("*") if q.is_file() and not q.name.startswith(".")
               and q.name not in ("filler",) and not q.name.endswith(("-wal", "-shm", "-journal")))  # SQLite's


# --------------------------------------------------------------------------------- mounts


class Tmpfs:
    """A real small file system (tmpfs) mounted on ``folder`` for a case."""

    def __init__(self, folder: Path, size: str) -> None:
        self.folder, self.size = folder, size

    def __enter__(self) -> Path:
        self.folder.mkdir(parents=True, exist_ok=True)
        subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={self.size},mode=1777", "tmpfs", str(self.folder)],
                       check=True, capture_output=True)
        return self.folder

    def __exit__(self, *exc) -> None:
        subprocess.run(["umount", "-l", str(self.folder)], capture_output=True)


def can_mount(work: Path) -> str | None:
    probe = work / "probe"
    try:
        with Tmpfs(probe, "64k"):
            pass
    except subprocess.CalledProcessError as e:
        return f"cannot mount a tmpfs: {e.stderr.decode(errors='replace').strip()}"
    return None


def fill(folder: Path) -> Path:
    filler = folder / "filler"
    with open(filler, "wb") as f:
        try:
            while True:
                f.write(b"\0" * (1 << 16))
                f.flush()
        except OSError:
            pass
    return filler


# --------------------------------------------------------------------------------- the inputs


def pcd_bytes(h: int, w: int, rng: random.Random) -> bytes:
    """An organized binary PCD (x y z rgb) written here: a tilted plane with a few flying points."""
    import numpy as np

    r = np.random.default_rng(rng.randrange(1 << 30))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    z = 1.0 + 0.0005 * xx + 0.001 * r.standard_normal((h, w)).astype(np.float32)
    fly = r.random((h, w)) < 0.002
    z[fly] -= 0.05
    z[r.random((h, w)) < 0.01] = np.nan
    xyz = np.stack([(xx - w / 2) * z / 500, (yy - h / 2) * z / 500, z], axis=2).astype(np.float32)
    rgb = np.full((h, w), (90 << 16) | (110 << 8) | 130, np.uint32).view(np.float32)
    data = np.concatenate([xyz, rgb[..., None]], axis=2).astype(np.float32).tobytes()
    head = (f"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
            f"WIDTH {w}\nHEIGHT {h}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {h * w}\nDATA binary\n")
    return head.encode() + data


def prepare(work: Path, rng: random.Random) -> dict:
    """The campaign's inputs (made once): synthetic logs, an empty-bin log and its model, a label
    store, organized PCD scans, and the hostile logs."""
    inp = work / "inputs"
    marker = inp / "ready.json"
    if marker.is_file():
        return json.loads(marker.read_text())
    inp.mkdir(parents=True, exist_ok=True)
    f = {"parts": inp / "parts.mcap", "rods": inp / "rods.mcap", "empty": inp / "empty.mcap",
         "bin": inp / "bin.ply", "db": inp / "labels.sqlite", "scans": inp / "scans", "labels_mcap": inp / "l.mcap"}
    for key, extra in (("parts", ["--parts", "zinc_nuts", "--frames", "3"]), ("rods", ["--parts", "rods", "--frames", "2"]),
                       ("empty", ["--empty", "--frames", "5"])):
        r = run(["synth", "-o", f[key], "--size", SIZE, "--seed", str(rng.randrange(1000)), *extra])
        assert r.rc == 0, r.err
    assert run(["bin-model", f["empty"], "-o", f["bin"]]).rc == 0
    f["scans"].mkdir(exist_ok=True)
    for i in range(2):
        (f["scans"] / f"scan{i}.pcd").write_bytes(pcd_bytes(240, 320, rng))
    sys.path.insert(0, str(REPO))
    import numpy as np

    from annotate.label_files import export_labels
    from annotate.store import LabelStore
    from replay.logs.reader import LogReader

    with LabelStore(f["db"]) as store:
        rec = store.add_log(f["parts"])
        for fr in LogReader(f["parts"]).frames():
            valid = np.isfinite(fr.xyz).all(axis=2)
            r = store.add_frame(rec, topic=fr.topic, stamp_ns=fr.stamp_ns, index=fr.index, shape=fr.shape,
                                frame_id=fr.frame_id, valid=valid)
            store.save_label(r, annotator="ann", outliers=fr.masks["/ground_truth/outliers"] & valid,
                             reviewed=valid, base_revision=0)
        export_labels(store, rec, f["labels_mcap"], annotator="ann")
    f["hostile"] = [str(p) for p in write_hostile_logs(inp / "hostile", rng)]
    out = {k: (v if isinstance(v, list) else str(v)) for k, v in f.items()}
    marker.write_text(json.dumps(out))
    return out


# ------------------------------------------------------------------ hostile logs, written here

HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"
TIME = "int32 sec\nuint32 nanosec\n"
POINTFIELD = ("uint8 INT8=1\nuint8 UINT8=2\nuint8 INT16=3\nuint8 UINT16=4\nuint8 INT32=5\nuint8 UINT32=6\n"
              "uint8 FLOAT32=7\nuint8 FLOAT64=8\nstring name\nuint32 offset\nuint8 datatype\nuint32 count\n")
SEP = "=" * 80 + "\n"
PC2 = ("std_msgs/Header header\nuint32 height\nuint32 width\nsensor_msgs/PointField[] fields\nbool is_bigendian\n"
       "uint32 point_step\nuint32 row_step\nuint8[] data\nbool is_dense\n"
       + SEP + "MSG: std_msgs/Header\n" + HEADER + SEP + "MSG: builtin_interfaces/Time\n" + TIME
       + SEP + "MSG: sensor_msgs/PointField\n" + POINTFIELD)
IMAGE = ("std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\n"
         "uint8[] data\n" + SEP + "MSG: std_msgs/Header\n" + HEADER + SEP + "MSG: builtin_interfaces/Time\n" + TIME)
CAMINFO = ("std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] d\n"
           "float64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\nuint32 binning_y\n"
           "sensor_msgs/RegionOfInterest roi\n" + SEP + "MSG: std_msgs/Header\n" + HEADER + SEP
           + "MSG: builtin_interfaces/Time\n" + TIME + SEP + "MSG: sensor_msgs/RegionOfInterest\n"
           "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n")


def _cloud_msg(xyz, *, stamp_ns: int, frame_id="cam", order=("x", "y", "z"), pad=0, dtype="<f4",
               row_pad=0, extra_rgb=None) -> dict:
    """A PointCloud2 dict: fields in ``order``, ``pad`` bytes of padding field, row padding."""
    import numpy as np

    h, w, _ = xyz.shape
    size = np.dtype(dtype).itemsize
    fields, offset = [], 0
    for name in order:
        fields.append({"name": name, "offset": offset, "datatype": 8 if size == 8 else 7, "count": 1})
        offset += size
    if extra_rgb is not None:
        fields.append({"name": "rgb", "offset": offset, "datatype": 7, "count": 1})
        offset += 4
    point_step = offset + pad
    row_step = point_step * w + row_pad
    buf = bytearray(row_step * h)
    arr = np.frombuffer(buf, np.uint8).reshape(h, row_step)
    for k, name in enumerate(order):
        col = np.ascontiguousarray(xyz[..., "xyz".index(name)].astype(dtype))
        for c in range(size):
            arr[:, k * size + c: k * size + c + w * point_step: point_step] = col.view(np.uint8).reshape(h, w, size)[..., c]
    if extra_rgb is not None:
        rgbf = np.ascontiguousarray(extra_rgb.astype("<u4")).view(np.uint8).reshape(h, w, 4)
        base = len(order) * size
        for c in range(4):
            arr[:, base + c: base + c + w * point_step: point_step] = rgbf[..., c]
    return {"header": {"stamp": {"sec": stamp_ns // 10**9, "nanosec": stamp_ns % 10**9}, "frame_id": frame_id},
            "height": h, "width": w, "fields": fields, "is_bigendian": dtype.startswith(">"),
            "point_step": point_step, "row_step": row_step, "data": bytes(buf), "is_dense": False}


def _image_msg(h, w, *, stamp_ns, encoding="rgb8") -> dict:
    import numpy as np

    ch = {"rgb8": 3, "bgr8": 3, "mono8": 1, "rgba8": 4}[encoding]
    data = (np.arange(h * w * ch) % 251).astype(np.uint8).tobytes()
    return {"header": {"stamp": {"sec": stamp_ns // 10**9, "nanosec": stamp_ns % 10**9}, "frame_id": "cam"},
            "height": h, "width": w, "encoding": encoding, "is_bigendian": 0, "step": w * ch, "data": data}


def _scene(h, w, rng):
    import numpy as np

    r = np.random.default_rng(rng.randrange(1 << 30))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    z = 1.0 + 0.0002 * r.standard_normal((h, w))
    for _ in range(6):
        cy, cx, s = r.integers(10, h - 10), r.integers(10, w - 10), int(r.integers(2, 5))
        z[cy:cy + s, cx:cx + s] -= 0.03  # floating clusters
    return np.stack([(xx - w / 2) * z / (0.8 * w), (yy - h / 2) * z / (0.8 * w), z], axis=2)


def write_hostile_logs(folder: Path, rng: random.Random) -> list[Path]:
    """Valid ROS 2 MCAP logs written with the mcap library and mcap_ros2's serializer, each one hostile
    in its own way."""
    import numpy as np
    from mcap.writer import CompressionType, IndexType
    from mcap.writer import Writer as McapWriter
    from mcap_ros2._dynamic import serialize_dynamic

    folder.mkdir(parents=True, exist_ok=True)
    enc = {"sensor_msgs/msg/PointCloud2": serialize_dynamic("sensor_msgs/msg/PointCloud2", PC2),
           "sensor_msgs/msg/Image": serialize_dynamic("sensor_msgs/msg/Image", IMAGE),
           "sensor_msgs/msg/CameraInfo": serialize_dynamic("sensor_msgs/msg/CameraInfo", CAMINFO)}
    text = {"sensor_msgs/msg/PointCloud2": PC2, "sensor_msgs/msg/Image": IMAGE, "sensor_msgs/msg/CameraInfo": CAMINFO}
    h, w = 96, 128

    def write(name, messages, **writer_kw):
        path = folder / f"{name}.mcap"
        with open(path, "wb") as f:
            wr = McapWriter(f, **writer_kw)
            wr.start(profile="ros2", library="zcut fault campaign (mcap + mcap_ros2)")
            schemas, channels = {}, {}
            for topic, typ, msg, log_time in messages:
                if typ not in schemas:
                    schemas[typ] = wr.register_schema(typ, "ros2msg", text[typ].encode())
                if topic not in channels:
                    channels[topic] = wr.register_channel(topic, "cdr", schemas[typ])
                wr.add_message(channels[topic], log_time=log_time, publish_time=log_time, data=enc[typ][typ](msg))
            wr.finish()
        return path

    t0 = 1_700_000_000_000_000_000
    frames = [(t0 + i * 10**8, _scene(h, w, rng)) for i in range(3)]
    cloud = "/camera/points"
    logs = []
    logs.append(write("reordered_padded", [(cloud, "sensor_msgs/msg/PointCloud2",
                                            _cloud_msg(x, stamp_ns=t, order=("z", "x", "y"), pad=7, row_pad=13), t)
                                           for t, x in frames]))
    logs.append(write("bigendian", [(cloud, "sensor_msgs/msg/PointCloud2", _cloud_msg(x, stamp_ns=t, dtype=">f4"), t)
                                    for t, x in frames]))
    logs.append(write("float64", [(cloud, "sensor_msgs/msg/PointCloud2", _cloud_msg(x, stamp_ns=t, dtype="<f8"), t)
                                  for t, x in frames]))
    flat = [(t, x.reshape(1, h * w, 3)) for t, x in frames]
    logs.append(write("unorganized", [(cloud, "sensor_msgs/msg/PointCloud2", _cloud_msg(x, stamp_ns=t), t) for t, x in flat]))
    logs.append(write("all_nan", [(cloud, "sensor_msgs/msg/PointCloud2", _cloud_msg(np.full_like(x, np.nan), stamp_ns=t), t)
                                  for t, x in frames]))
    logs.append(write("one_point", [(cloud, "sensor_msgs/msg/PointCloud2", _cloud_msg(x[:1, :1], stamp_ns=t), t)
                                    for t, x in frames]))
    logs.append(write("identical_points", [(cloud, "sensor_msgs/msg/PointCloud2",
                                            _cloud_msg(np.broadcast_to(x[h // 2, w // 2], x.shape).copy(), stamp_ns=t), t)
                                           for t, x in frames]))
    dup = [(t0, x) for _, x in frames]
    logs.append(write("duplicate_unordered_stamps", [(cloud, "sensor_msgs/msg/PointCloud2", _cloud_msg(x, stamp_ns=t), lt)
                                                     for (t, x), lt in zip(dup, (t0 + 5, t0 + 1, t0 + 3))]))
    logs.append(write("unchunked_no_index", [(cloud, "sensor_msgs/msg/PointCloud2", _cloud_msg(x, stamp_ns=t), t)
                                             for t, x in frames],
                      use_chunking=False, index_types=IndexType.NONE, repeat_channels=False, repeat_schemas=False,
                      use_statistics=False, use_summary_offsets=False))
    logs.append(write("lz4", [(cloud, "sensor_msgs/msg/PointCloud2", _cloud_msg(x, stamp_ns=t), t) for t, x in frames],
                      compression=CompressionType.LZ4))
    logs.append(write("uncompressed", [(cloud, "sensor_msgs/msg/PointCloud2", _cloud_msg(x, stamp_ns=t), t)
                                       for t, x in frames], compression=CompressionType.NONE))
    msgs = []
    for (t, x), encoding in zip(frames, ("bgr8", "mono8", "rgba8")):
        msgs += [(cloud, "sensor_msgs/msg/PointCloud2", _cloud_msg(x, stamp_ns=t), t),
                 ("/camera/image", "sensor_msgs/msg/Image", _image_msg(h, w, stamp_ns=t, encoding=encoding), t)]
    logs.append(write("foreign_image_encodings", msgs))
    msgs = []
    for t, x in frames:
        msgs += [(cloud, "sensor_msgs/msg/PointCloud2", _cloud_msg(x, stamp_ns=t), t),
                 ("/camera/image", "sensor_msgs/msg/Image", _image_msg(h // 2, w // 2, stamp_ns=t), t)]
    logs.append(write("image_of_another_size", msgs))
    zero_info = {"header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""}, "height": 0, "width": 0,
                 "distortion_model": "", "d": [], "k": [0.0] * 9, "r": [0.0] * 9, "p": [0.0] * 12, "binning_x": 0,
                 "binning_y": 0, "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False}}
    msgs = []
    for t, x in frames:
        msgs += [(cloud, "sensor_msgs/msg/PointCloud2", _cloud_msg(x, stamp_ns=t), t),
                 ("/camera/camera_info", "sensor_msgs/msg/CameraInfo", zero_info, t)]
    logs.append(write("zero_camera_info", msgs))
    msgs = []
    for t, x in frames:
        msgs += [(cloud, "sensor_msgs/msg/PointCloud2", _cloud_msg(x, stamp_ns=t), t),
                 ("/other/points", "sensor_msgs/msg/PointCloud2", _cloud_msg(x[::2, ::2].copy(), stamp_ns=t), t)]
    logs.append(write("two_organized_clouds", msgs))
    logs.append(write("no_messages", []))
    logs.append(write("huge_frame_id", [(cloud, "sensor_msgs/msg/PointCloud2",
                                         _cloud_msg(x, stamp_ns=t, frame_id="f" * 20000 + "é"), t) for t, x in frames]))
    rgb = np.full((h, w), (200 << 16) | (100 << 8) | 50, np.uint32)
    logs.append(write("cloud_colours_packed", [(cloud, "sensor_msgs/msg/PointCloud2",
                                                _cloud_msg(x, stamp_ns=t, extra_rgb=rgb), t) for t, x in frames]))
    return logs


# --------------------------------------------------------------------------------- the groups


def case_row(group, case, r: Run, *, allowed, inputs_before, inputs, folders, outputs=None, procs=()) -> Row:
    ok, msg = message_of(r.err)
    left = leftovers(*folders) + list(procs)
    return Row(group, case, "hang" if r.rc == -999 else str(r.rc), msg, digest(inputs) == inputs_before, left,
               all(outputs_complete(Path(f)) for f in (outputs or folders)), r.rc in allowed, ok)


def writing_commands(f: dict, d: Path) -> dict[str, list]:
    return {
        "replay --rrd": ["replay", f["parts"], "--bin-model", f["bin"], "--rrd", d / "o.rrd"],
        "replay --out": ["replay", f["parts"], "--bin-model", f["bin"], "--out", d / "r.mcap"],
        "replay --rrd --out": ["replay", f["parts"], "--bin-model", f["bin"], "--rrd", d / "o.rrd", "--out", d / "r.mcap"],
        "synth": ["synth", "-o", d / "s.mcap", "--size", SIZE, "--frames", "2"],
        "record": ["record", f["scans"], "-o", d / "rec.mcap"],
        "bin-model": ["bin-model", f["empty"], "-o", d / "b.ply"],
        "labels export": ["labels", "export", f["parts"], "--db", f["db"], "-o", d / "l.mcap"],
        "labels import": ["labels", "import", f["labels_mcap"], "--db", d / "new.sqlite", "--log", f["parts"]],
        "batch --results --rrd": ["batch", f["parts"], f["rods"], "--bin-model", f["bin"], "-o", d / "b",
                                  "--workers", "2", "--results", "--rrd"],
        "sweep": ["sweep", f["parts"], "--bin-model", f["bin"], "-o", d / "s", "--workers", "2",
                  "--step", "0.2", "--rho", "0.05,0.07"],
        "demo": ["demo", "--out-dir", d / "demo"],
    }


def group_full_disk(f, work, rng, rows, env) -> None:
    inputs = [f["parts"], f["rods"], f["empty"], f["bin"], f["db"], f["scans"], f["labels_mcap"]]
    before = digest(inputs)
    sizes = ["64k", "1m", "3m", "12m"]
    for name in writing_commands(f, work).keys():
        for size in rng.sample(sizes, 3):
            with Tmpfs(work / "disk", size) as d:
                argv = writing_commands(f, d)[name]
                r = run(argv, env=env)
                allowed = {0, 1, 3} if name.startswith(("batch", "sweep")) else {0, 1}
                rows.append(case_row("full disk", f"{name} on {size}", r, allowed=allowed, inputs_before=before,
                                     inputs=inputs, folders=[d], procs=wait_gone(str(d))))
    # the labelling server with its store on a full disk: 507, the store intact, a save after freeing
    with Tmpfs(work / "disk", "2m") as d:
        rows.append(annotate_full_disk(f, d, inputs, before, env))


def annotate_full_disk(f, d: Path, inputs, before, env) -> Row:
    import base64
    import re

    import httpx
    import numpy as np

    sys.path.insert(0, str(REPO))
    from annotate.store import pack_mask

    p = subprocess.Popen([*ZCUT, "annotate", f["parts"], "--db", d / "l.sqlite", "--port", "0", "--no-browser",
                          "--annotator", "campaign"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env=dict(os.environ, **env))
    base = token = None
    for line in p.stdout:
        m = re.match(r"(http://127\.0\.0\.1:\d+)/\?token=(\S+)", line.strip())
        if m:
            base, token = m.groups()
            break
    statuses = []
    try:
        with httpx.Client(base_url=base, headers={"Origin": base}, timeout=120) as c:
            c.get("/", params={"token": token})
            for _ in range(600):
                if c.get("/api/session").json().get("done"):
                    break
                time.sleep(0.5)
            frames = c.get("/api/frames").json()["frames"]
            h, w = frames[0]["height"], frames[0]["width"]
            none = base64.b64encode(pack_mask(np.zeros((h, w), bool))).decode()
            body = {"base_revision": 0, "height": h, "width": w, "outliers": none, "reviewed": none}
            filler = fill(d)
            r = c.put("/api/frames/0/label", json=body)
            statuses.append(r.status_code)
            msg = r.json().get("error", "")
            filler.unlink()
            statuses.append(c.put("/api/frames/0/label", json=body).status_code)
    finally:
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=120)
    run_ = Run(p.returncode, "", err, 0.0)
    row = case_row("full disk", "annotate: store on a full disk, PUT then PUT after freeing", run_, allowed={143},
                   inputs_before=before, inputs=inputs, folders=[d])
    row.exit = f"{statuses[0]}, {statuses[1]}; {p.returncode}"
    row.message = msg[:150]
    row.allowed = row.allowed and statuses == [507, 200] and "no space left" in msg
    return row


def signal_commands(f: dict, d: Path) -> dict[str, list]:
    return {
        "replay": ["replay", f["parts"], "--bin-model", f["bin"], "--rrd", d / "o.rrd", "--out", d / "r.mcap", "--force"],
        "batch": ["batch", f["parts"], f["rods"], "--bin-model", f["bin"], "-o", d / "b", "--workers", "2",
                  "--frames-per-unit", "1"],
        "batch --results": ["batch", f["parts"], f["rods"], "-o", d / "br", "--workers", "2", "--results"],
        "sweep": ["sweep", f["parts"], f["rods"], "-o", d / "s", "--workers", "2", "--step", "0.2,0.4",
                  "--frames-per-unit", "1"],
        "synth": ["synth", "-o", d / "s.mcap", "--size", SIZE, "--frames", "3", "--force"],
        "record": ["record", f["scans"], "-o", d / "rec.mcap", "--force"],
        "bin-model": ["bin-model", f["empty"], "-o", d / "b.ply", "--force"],
    }


def group_signals(f, work, rng, rows, env) -> None:
    inputs = [f["parts"], f["rods"], f["empty"], f["bin"], f["scans"]]
    before = digest(inputs)
    d = work / "sig"
    for name in signal_commands(f, d):
        shutil.rmtree(d, ignore_errors=True)
        d.mkdir(parents=True)
        ref = run(signal_commands(f, d)[name], env=env)  # the reference: a clean run, and its duration
        rows.append(case_row("signals", f"{name}: reference run ({ref.seconds:.0f} s)", ref, allowed={0},
                             inputs_before=before, inputs=inputs, folders=[d]))
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            shutil.rmtree(d, ignore_errors=True)
            d.mkdir(parents=True)
            delay = rng.uniform(0.3, max(1.0, ref.seconds))
            argv = signal_commands(f, d)[name]
            p = subprocess.Popen([*ZCUT, *map(str, argv)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                 text=True, env=dict(os.environ, **env))
            time.sleep(delay)
            p.send_signal(sig)
            try:
                _, err = p.communicate(timeout=600)
            except subprocess.TimeoutExpired:
                p.kill()
                _, err = p.communicate()
                err += "\nHANG after the signal"
            procs = wait_gone(str(d))
            case = f"{name}: {signal.Signals(sig).name} at {delay:.1f} s"
            if sig == signal.SIGKILL:
                # the same command again: it takes the lock over, removes the leftovers, resumes
                again = run(argv, env=env)
                row = case_row("signals", case + ", then run again", again, allowed={0}, inputs_before=before,
                               inputs=inputs, folders=[d], procs=procs + wait_gone(str(d)))
                row.exit = f"{p.returncode}; again {again.rc}"
            else:
                row = case_row("signals", case, Run(p.returncode, "", err, delay), allowed={0, 128 + sig},
                               inputs_before=before, inputs=inputs, folders=[d], procs=procs)
                if p.returncode == 128 + sig:  # the one line says so
                    row.one_line = row.one_line and err.rstrip().endswith(f"interrupted ({signal.Signals(sig).name})")
            rows.append(row)
    # the labelling server: SIGINT/SIGTERM while it serves
    for sig in (signal.SIGINT, signal.SIGTERM):
        shutil.rmtree(d, ignore_errors=True)
        d.mkdir(parents=True)
        p = subprocess.Popen([*ZCUT, "annotate", f["parts"], "--db", d / "l.sqlite", "--port", "0", "--no-browser",
                              "--annotator", "c"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             env=dict(os.environ, **env))
        p.stdout.readline()
        delay = rng.uniform(1.0, 15.0)
        time.sleep(delay)
        p.send_signal(sig)
        out, err = p.communicate(timeout=120)
        rows.append(case_row("signals", f"annotate: {signal.Signals(sig).name} at {delay:.1f} s",
                             Run(p.returncode, out, err, delay), allowed={128 + sig}, inputs_before=before,
                             inputs=inputs, folders=[d], procs=wait_gone(str(d))))


def group_concurrent(f, work, rng, rows, env) -> None:
    inputs = [f["parts"], f["rods"], f["bin"], f["db"]]
    before = digest(inputs)
    d = work / "conc"
    pairs = {
        "replay / replay, one --out": ["replay", f["parts"], "--out", d / "r.mcap", "--force"],
        "replay / replay, one --rrd": ["replay", f["parts"], "--rrd", d / "o.rrd", "--force"],
        "synth / synth, one -o": ["synth", "-o", d / "s.mcap", "--size", SIZE, "--frames", "2", "--force"],
        "labels export / labels export": ["labels", "export", f["parts"], "--db", f["db"], "-o", d / "l.mcap", "--force"],
        "batch / batch, one -o": ["batch", f["parts"], "-o", d / "b", "--workers", "1"],
        "sweep / sweep, one -o": ["sweep", f["parts"], "-o", d / "s", "--workers", "1", "--step", "0.2"],
    }
    for name, argv in pairs.items():
        shutil.rmtree(d, ignore_errors=True)
        d.mkdir(parents=True)
        procs = [subprocess.Popen([*ZCUT, *map(str, argv)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                  text=True, env=dict(os.environ, **env))]
        time.sleep(rng.uniform(0.0, 3.0))
        procs.append(subprocess.Popen([*ZCUT, *map(str, argv)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                      text=True, env=dict(os.environ, **env)))
        results = [(p.wait(timeout=1200), p.stderr.read()) for p in procs]
        for p in procs:
            p.stderr.close()
        rcs = sorted(rc for rc, _ in results)
        refused = [e for rc, e in results if rc == 1]
        row = case_row("concurrent", name, Run(rcs[-1], "", "\n".join(refused), 0), allowed={0, 1},
                       inputs_before=before, inputs=inputs, folders=[d])
        row.exit = ", ".join(map(str, rcs))
        # one of them wrote, the other was refused (or they did not overlap: both 0)
        row.allowed = rcs in ([0, 1], [0, 0]) and all("another zcut process" in e for e in refused)
        row.message = (refused[0].strip().splitlines()[-1] if refused else "both ran, one after the other")[:150]
        rows.append(row)


def group_unprivileged(f, work, rng, rows, env) -> None:
    import pwd

    user = "nobody"
    uid = pwd.getpwnam(user).pw_uid
    home = work / "nobody-home"
    home.mkdir(exist_ok=True)
    mine = work / "nobody-out"
    mine.mkdir(exist_ok=True)
    for p in (home, mine):
        os.chown(p, uid, -1)
    # numba's cache for that user: the kernels compiled by root, copied where NUMBA_CACHE_DIR puts them
    cache = home / "numba"
    if not cache.exists():
        sys.path.insert(0, str(REPO))
        from numba.core.caching import _CacheLocator

        for src in REPO.rglob("__pycache__"):
            files = list(src.glob("*.nbi")) + list(src.glob("*.nbc"))
            if not files:
                continue
            dst = cache / _CacheLocator.get_suitable_cache_subpath(str(src.parent / "x.py"))
            dst.mkdir(parents=True, exist_ok=True)
            for q in files:
                shutil.copy2(q, dst / q.name)
        subprocess.run(["chown", "-R", f"{uid}", str(home)], check=True)
    uenv = dict(env, HOME=str(home), NUMBA_CACHE_DIR=str(cache), ZCUT_CACHE=str(home / "zcut"))
    # root-owned, not writable for nobody: a folder of logs with one unreadable, and a label store
    closed = work / "root-only"
    closed.mkdir(exist_ok=True)
    os.chmod(closed, 0o755)
    logs = closed / "logs"
    logs.mkdir(exist_ok=True)
    shutil.copy(f["parts"], logs / "parts.mcap")
    shutil.copy(f["rods"], logs / "secret.mcap")
    os.chmod(logs / "secret.mcap", 0o600)
    shutil.copy(f["db"], closed / "labels.sqlite")
    for p in (logs / "parts.mcap", closed / "labels.sqlite"):
        os.chmod(p, 0o644)
    inputs = [logs, closed / "labels.sqlite"]
    before = digest(inputs)
    cases = {
        "replay --out into a folder it cannot write": (["replay", logs / "parts.mcap", "--out", closed / "r.mcap"], {1}),
        "replay --rrd into its own folder": (["replay", logs / "parts.mcap", "--rrd", mine / "o.rrd", "--force"], {0}),
        "topics of a log it cannot read": (["topics", logs / "secret.mcap"], {1}),
        "labels list, store in a folder it cannot write": (["labels", "list", logs / "parts.mcap", "--db",
                                                            closed / "labels.sqlite"], {0}),
        "accuracy --labels, store in a folder it cannot write": (["accuracy", logs / "parts.mcap", "--labels",
                                                                  closed / "labels.sqlite"], {0}),
        "batch -o a folder it cannot write": (["batch", logs, "-o", closed / "b", "--workers", "1"], {1}),
        "batch of a folder with a log it cannot read": (["batch", logs, "-o", mine / "b", "--workers", "1"], {3}),
        "sweep of a folder with a log it cannot read": (["sweep", logs, "-o", mine / "s", "--workers", "1",
                                                         "--step", "0.2"], {3}),
    }
    for name, (argv, allowed) in cases.items():
        r = run(argv, env=uenv, user=user)
        rows.append(case_row("unprivileged", name, r, allowed=allowed, inputs_before=before, inputs=inputs,
                             folders=[closed, mine], outputs=[mine]))


def group_hostile(f, work, rng, rows, env) -> None:
    d = work / "hostile-out"
    for log in map(Path, f["hostile"]):
        before = digest([log])
        for what, argv in (("topics", ["topics", log]),
                           ("replay --out --rrd", ["replay", log, "--out", d / "r.mcap", "--rrd", d / "o.rrd", "--force"]),
                           ("batch", ["batch", log, "-o", d / "b", "--workers", "1"])):
            shutil.rmtree(d, ignore_errors=True)
            d.mkdir(parents=True)
            r = run(argv, env=env)
            rows.append(case_row("hostile log", f"{log.stem}: {what}", r, allowed={0, 1, 3}, inputs_before=before,
                                 inputs=[log], folders=[d]))


# ------------------------------------------------------- issue 35: the second campaign's cases
#
# Generators written here, independent of the code under test: signals sent with os.kill/os.killpg,
# descriptors closed or pointed at /dev/full by the shell, limits set with resource.setrlimit in the
# child, names, links and FIFOs made with os.*, logs written with the mcap library.


def run_raw(cmd: list, *, timeout: float = 600, env: dict | None = None, stdout="pipe", preexec=None,
            shell_redirect: str | None = None, new_session: bool = False) -> Run:
    """Run ``zcut CMD`` with stdout as asked: "pipe", "closed" (the shell's ``>&-``), "full"
    (``>/dev/full``) or "devnull"; ``preexec`` runs in the child (limits)."""
    argv = [*ZCUT, *map(str, cmd)]
    if stdout == "closed":
        argv = ["sh", "-c", 'exec "$@" >&-', "sh", *argv]
    out = {"pipe": subprocess.PIPE, "devnull": subprocess.DEVNULL, "closed": None}.get(stdout)
    full = open("/dev/full", "w") if stdout == "full" else None  # noqa: SIM115
    t0 = time.monotonic()
    try:
        p = subprocess.run(argv, stdout=full or out, stderr=subprocess.PIPE, text=True, timeout=timeout,
                           env=dict(os.environ, **(env or {})), cwd="/", preexec_fn=preexec,
                           start_new_session=new_session)
        return Run(p.returncode, p.stdout or "", p.stderr, time.monotonic() - t0)
    except subprocess.TimeoutExpired as e:
        err = e.stderr.decode(errors="replace") if isinstance(e.stderr, bytes) else (e.stderr or "")
        return Run(-999, "", err + f"\nHANG after {timeout:g} s", time.monotonic() - t0)
    finally:
        if full:
            full.close()


def _spawn(cmd: list, env: dict, *, new_session: bool = False) -> subprocess.Popen:
    return subprocess.Popen([*ZCUT, *map(str, cmd)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, **env), cwd="/", start_new_session=new_session)


def _finish(p: subprocess.Popen, timeout: float = 600) -> tuple[int, str]:
    try:
        _, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        p.kill()
        _, err = p.communicate()
        err += "\nHANG after the signal"
        return -999, err
    return p.returncode, err


def _wait_line(p: subprocess.Popen, needle: str, seconds: float = 300) -> str:
    """Read the child's stderr until a line holds ``needle`` (what was read is returned)."""
    seen = ""
    deadline = time.monotonic() + seconds
    while needle not in seen and time.monotonic() < deadline and p.poll() is None:
        line = p.stderr.readline()
        if not line:
            break
        seen += line
    return seen


def _fresh(d: Path) -> Path:
    shutil.rmtree(d, ignore_errors=True)
    d.mkdir(parents=True)
    return d


def group_stop_cont(f, work, rng, rows, env) -> None:
    """SIGSTOP then SIGCONT (a job suspended with Ctrl-Z and resumed): the command finishes normally;
    SIGTERM to a stopped command (the shell's `kill %1`), then SIGCONT: it unwinds (143)."""
    inputs = [f["parts"], f["rods"], f["bin"]]
    before = digest(inputs)
    d = work / "stopcont"
    cmds = {
        "replay": lambda d: ["replay", f["parts"], "--bin-model", f["bin"], "--rrd", d / "o.rrd", "--out", d / "r.mcap"],
        "batch": lambda d: ["batch", f["parts"], f["rods"], "-o", d / "b", "--workers", "2", "--frames-per-unit", "1"],
    }
    for name, argv in cmds.items():
        for then_term in (False, True):
            _fresh(d)
            p = _spawn(argv(d), env)
            delay = rng.uniform(0.5, 4.0)
            time.sleep(delay)
            os.kill(p.pid, signal.SIGSTOP)
            time.sleep(rng.uniform(0.5, 2.0))
            if then_term:
                os.kill(p.pid, signal.SIGTERM)
            os.kill(p.pid, signal.SIGCONT)
            rc, err = _finish(p)
            case = f"{name}: SIGSTOP at {delay:.1f} s, " + ("SIGTERM, SIGCONT" if then_term else "SIGCONT")
            rows.append(case_row("stop/cont", case, Run(rc, "", err, delay), allowed={0, 143} if then_term else {0},
                                 inputs_before=before, inputs=inputs, folders=[d], procs=wait_gone(str(d))))


def group_sighup(f, work, rng, rows, env) -> None:
    """SIGHUP (a closed terminal or SSH session) at random moments: 129, one line, nothing left."""
    inputs = [f["parts"], f["rods"], f["empty"], f["bin"], f["scans"]]
    before = digest(inputs)
    d = work / "hup"
    for name in ("replay", "batch", "sweep", "synth", "record", "bin-model"):
        for _ in range(2):
            _fresh(d)
            argv = signal_commands(f, d)[name]
            p = _spawn(argv, env)
            delay = rng.uniform(0.3, 6.0)
            time.sleep(delay)
            p.send_signal(signal.SIGHUP)
            rc, err = _finish(p)
            row = case_row("SIGHUP", f"{name}: SIGHUP at {delay:.1f} s", Run(rc, "", err, delay), allowed={0, 129},
                           inputs_before=before, inputs=inputs, folders=[d], procs=wait_gone(str(d)))
            if rc == 129:
                row.one_line = row.one_line and err.rstrip().endswith("interrupted (SIGHUP)")
            rows.append(row)


def group_process_group(f, work, rng, rows, env) -> None:
    """A signal to the whole process group (a terminal's Ctrl-C or hang-up, `kill -TERM -PGID`): the
    driver and its workers all receive it; the driver decides (128 + signal), no worker is left."""
    inputs = [f["parts"], f["rods"], f["bin"]]
    before = digest(inputs)
    d = work / "pgrp"
    for name in ("batch", "sweep", "replay"):
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            _fresh(d)
            p = _spawn(signal_commands(f, d)[name], env, new_session=True)
            delay = rng.uniform(1.0, 8.0)
            time.sleep(delay)
            try:
                os.killpg(p.pid, sig)
            except ProcessLookupError:
                pass
            rc, err = _finish(p)
            case = f"{name}: {signal.Signals(sig).name} to the group at {delay:.1f} s"
            row = case_row("process group", case, Run(rc, "", err, delay), allowed={0, 128 + sig},
                           inputs_before=before, inputs=inputs, folders=[d], procs=wait_gone(str(d)))
            if rc == 128 + sig:
                row.one_line = row.one_line and err.rstrip().endswith(f"interrupted ({signal.Signals(sig).name})")
            rows.append(row)


def group_stdout(f, work, rng, rows, env) -> None:
    """A closed (`>&-`) or full (`>/dev/full`) stdout: the file outputs are complete; what was printed
    and lost is one `error:` line and exit 1 (0 when nothing was printed to stdout)."""
    inputs = [f["parts"], f["db"], f["bin"]]
    before = digest(inputs)
    d = work / "stdout"
    cases = {
        "topics": (lambda d: ["topics", f["parts"]], {1}),
        "labels list": (lambda d: ["labels", "list", f["parts"], "--db", f["db"]], {1}),
        "--version": (lambda d: ["--version"], {1}),
        "replay --help": (lambda d: ["replay", "--help"], {1}),
        "synth -o": (lambda d: ["synth", "-o", d / "s.mcap", "--size", SIZE], {0}),
        "replay --out --rrd": (lambda d: ["replay", f["parts"], "--bin-model", f["bin"], "--out", d / "r.mcap",
                                          "--rrd", d / "o.rrd"], {1}),
        "batch --json": (lambda d: ["batch", f["parts"], "-o", d / "b", "--workers", "1", "--json"], {1}),
    }
    for how in ("closed", "full"):
        for name, (argv, allowed) in cases.items():
            _fresh(d)
            r = run_raw(argv(d), env=env, stdout=how)
            row = case_row("stdout", f"{name} >{'&-' if how == 'closed' else '/dev/full'}", r, allowed=allowed,
                           inputs_before=before, inputs=inputs, folders=[d])
            if 1 in allowed:  # the one line says that stdout was lost
                row.one_line = row.one_line and "standard output" in row.message
            row.one_line = row.one_line and "Exception ignored" not in r.err
            rows.append(row)


def _limit(kind: int, value: int):
    def set_it() -> None:
        import resource

        resource.setrlimit(kind, (value, value))
    return set_it


def group_ulimit(f, work, rng, rows, env) -> None:
    """Resource limits set in the child (`ulimit -v / -n / -f`): one line, exit 1 (or success), never
    a traceback nor a death by a signal."""
    import resource

    inputs = [f["parts"], f["rods"], f["empty"], f["bin"]]
    before = digest(inputs)
    d = work / "ulimit"
    cases = {
        "-v 1000000: bin-model": (resource.RLIMIT_AS, 1_000_000 * 1024, lambda d: ["bin-model", f["empty"], "-o", d / "b.ply"]),
        "-v 1000000: synth --sensor raytraced": (resource.RLIMIT_AS, 1_000_000 * 1024,
                                                 lambda d: ["synth", "-o", d / "r.mcap", "--size", SIZE, "--sensor", "raytraced"]),
        "-v 1000000: topics": (resource.RLIMIT_AS, 1_000_000 * 1024, lambda d: ["topics", f["parts"]]),
        "-v 3000000: replay --out": (resource.RLIMIT_AS, 3_000_000 * 1024,
                                     lambda d: ["replay", f["parts"], "--bin-model", f["bin"], "--out", d / "r.mcap"]),
        "-n 24: replay --out --rrd": (resource.RLIMIT_NOFILE, 24,
                                      lambda d: ["replay", f["parts"], "--out", d / "r.mcap", "--rrd", d / "o.rrd"]),
        "-n 24: batch": (resource.RLIMIT_NOFILE, 24, lambda d: ["batch", f["parts"], f["rods"], "-o", d / "b", "--workers", "2"]),
        "-f 64 KB: synth": (resource.RLIMIT_FSIZE, 64 * 1024, lambda d: ["synth", "-o", d / "s.mcap", "--size", SIZE]),
        "-f 64 KB: replay --out --rrd": (resource.RLIMIT_FSIZE, 64 * 1024,
                                         lambda d: ["replay", f["parts"], "--out", d / "r.mcap", "--rrd", d / "o.rrd"]),
        "-f 64 KB: batch": (resource.RLIMIT_FSIZE, 64 * 1024, lambda d: ["batch", f["parts"], "-o", d / "b", "--workers", "1"]),
    }
    for name, (kind, value, argv) in cases.items():
        _fresh(d)
        r = run_raw(argv(d), env=env, stdout="devnull", preexec=_limit(kind, value))
        rows.append(case_row("ulimit", name, r, allowed={0, 1, 3} if "batch" in name else {0, 1},
                             inputs_before=before, inputs=inputs, folders=[d], procs=wait_gone(str(d))))


def group_names(f, work, rng, rows, env) -> None:
    """Inputs and outputs named with spaces, unicode, a newline, 255 bytes: the same contract."""
    d = work / "names"
    names = {"spaces": "a log with spaces", "unicode": "ñame-日本語-Ω", "newline": "two\nlines",
             "255 bytes": "n" * (255 - len(".mcap"))}
    for what, stem in names.items():
        _fresh(d)
        log = d / f"{stem}.mcap"
        shutil.copy(f["parts"], log)
        inputs = [log, f["bin"]]
        before = digest(inputs)
        out = d / ("out " + what)
        out.mkdir()
        cases = {
            "topics": (["topics", log], {0}),
            "replay --out --rrd": (["replay", log, "--bin-model", f["bin"], "--out", out / f"{stem}.r.mcap"[-255:],
                                    "--rrd", out / f"{stem}.rrd"[-255:]], {0, 1}),
            "synth -o": (["synth", "-o", out / f"{stem}.s.mcap"[-255:], "--size", SIZE], {0, 1}),
            "batch": (["batch", log, "-o", out / f"{stem}.b"[-255:], "--workers", "1"], {0, 1}),
        }
        for name, (argv, allowed) in cases.items():
            r = run(argv, env=env)
            rows.append(case_row("names", f"{what}: {name}", r, allowed=allowed, inputs_before=before, inputs=inputs,
                                 folders=[d], outputs=[out], procs=wait_gone(str(d))))


def group_links_fifos(f, work, rng, rows, env) -> None:
    """Symlink loops and FIFOs as inputs and outputs: refused in one line, never a hang."""
    d = _fresh(work / "links")
    loop_a, loop_b = d / "loop_a.mcap", d / "loop_b.mcap"
    os.symlink(loop_b, loop_a)
    os.symlink(loop_a, loop_b)
    fifo_in, fifo_out = d / "in.mcap", d / "out.mcap"
    os.mkfifo(fifo_in)
    os.mkfifo(fifo_out)
    out = d / "out"
    out.mkdir()
    inputs = [f["parts"], f["bin"]]
    before = digest(inputs)
    cases = {
        "topics of a symlink loop": (["topics", loop_a], {1}),
        "replay of a symlink loop": (["replay", loop_a], {1}),
        "replay --out onto a symlink loop": (["replay", f["parts"], "--out", loop_a], {1}),
        "synth -o onto a symlink loop": (["synth", "-o", loop_b, "--size", SIZE], {1}),
        "topics of a FIFO (no writer)": (["topics", fifo_in], {1}),
        "replay of a FIFO (no writer)": (["replay", fifo_in, "--out", out / "r.mcap"], {1}),
        "replay --out onto a FIFO": (["replay", f["parts"], "--out", fifo_out], {1}),
        "synth -o onto a FIFO": (["synth", "-o", fifo_out, "--size", SIZE, "--force"], {1}),
        "bin-model -o onto a FIFO": (["bin-model", f["empty"], "-o", fifo_out], {1}),
    }
    for name, (argv, allowed) in cases.items():
        r = run(argv, env=env, timeout=120)
        rows.append(case_row("links/FIFOs", name, r, allowed=allowed, inputs_before=before, inputs=inputs,
                             folders=[d], outputs=[out], procs=wait_gone(str(d))))
    # a folder of logs with a looping and a dangling .mcap symlink (issue 35 item 5, another helper's)
    logs = _fresh(work / "links-batch")
    shutil.copy(f["parts"], logs / "a.mcap")
    os.symlink(logs / "gone.mcap", logs / "dangling.mcap")
    os.symlink(logs / "loop2.mcap", logs / "loop1.mcap")
    os.symlink(logs / "loop1.mcap", logs / "loop2.mcap")
    b = work / "links-batch-out"
    shutil.rmtree(b, ignore_errors=True)
    r = run(["batch", logs, "-o", b, "--workers", "1"], env=env)
    rows.append(case_row("links/FIFOs", "batch of a folder with a dangling and a looping .mcap symlink", r,
                         allowed={1, 3}, inputs_before=before, inputs=inputs, folders=[logs, b],
                         procs=wait_gone(str(b))))


#: (argv, what the one line must name): mistakes of every kind on several commands
ARGPARSE_MISTAKES = [
    (["replay", "x.mcap", "--methods", "telepathy"], "--methods"),
    (["synth", "-o", "x.mcap", "--parts", "bolts"], "--parts"),
    (["synth", "-o", "x.mcap", "--frames", "three"], "--frames"),
    (["synth", "-o", "x.mcap", "--size"], "--size"),
    (["synth"], "--output"),
    (["replay"], "LOG"),
    (["replay", "x.mcap", "--spawn", "--rrd", "o.rrd"], "--rrd"),
    (["synth", "-o", "x.mcap", "--shiny", "--matte"], "--matte"),
    (["batch", "x.mcap", "-o", "b", "--workers", "many"], "--workers"),
    (["batch", "x.mcap"], "--out"),
    (["sweep", "x.mcap", "-o", "s", "--workers"], "--workers"),
    (["annotate", "x.mcap", "--port", "http"], "--port"),
    (["labels"], "ACTION"),
    (["labels", "export", "x.mcap", "--db", "l.sqlite"], "--out"),
    (["topics", "x.mcap", "--colour"], "--colour"),
    (["replays", "x.mcap"], "replays"),
    (["--verison"], "--verison"),
]


def group_argparse(f, work, rng, rows, env) -> None:
    """Command-line mistakes: exactly one line naming what was wrong, exit 1, nothing written."""
    d = _fresh(work / "argparse")
    for argv, names in ARGPARSE_MISTAKES:
        r = run([*argv], env=env, timeout=120)
        row = case_row("argparse", " ".join(argv), r, allowed={1}, inputs_before={}, inputs=[], folders=[d])
        lines = [ln for ln in r.err.splitlines() if ln.strip()]
        row.one_line = row.one_line and len(lines) == 1 and lines[0].startswith("error:") and names in lines[0]
        rows.append(row)


def group_issue35_others(f, work, rng, rows, env) -> None:
    """The second campaign's cases that other parts of the code own: a study resumed after its input
    changed, a ground-truth mask of the wrong size, a label store held by another writer, the output
    folder removed while a recording is written."""
    from mcap.writer import Writer as McapWriter
    from mcap_ros2._dynamic import serialize_dynamic

    # a study resumed after its input changed (the same path, other content): refused, or a fresh start
    d = _fresh(work / "resume")
    log = d / "log.mcap"
    shutil.copy(f["parts"], log)
    argv = ["batch", log, "-o", d / "b", "--workers", "1", "--frames-per-unit", "1"]
    first = run(argv, env=env)
    shutil.copy(f["rods"], log)
    before = digest([log])
    again = run(argv, env=env)
    row = case_row("issue 35 (others)", "batch resumed after its input changed", again, allowed={1},
                   inputs_before=before, inputs=[log], folders=[d])
    row.exit = f"{first.rc}; again {again.rc}"
    rows.append(row)
    # a ground-truth mask of the wrong size (48 x 64 for 96 x 128 clouds), written here
    d = _fresh(work / "wrongsize")
    enc = {t: serialize_dynamic(t, s)[t] for t, s in (("sensor_msgs/msg/PointCloud2", PC2),
                                                      ("sensor_msgs/msg/Image", IMAGE))}
    path = d / "wrong_size_truth.mcap"
    with open(path, "wb") as fh:
        wr = McapWriter(fh)
        wr.start(profile="ros2", library="zcut fault campaign")
        sc = wr.register_schema("sensor_msgs/msg/PointCloud2", "ros2msg", PC2.encode())
        si = wr.register_schema("sensor_msgs/msg/Image", "ros2msg", IMAGE.encode())
        cc = wr.register_channel("/camera/points", "cdr", sc)
        ct = wr.register_channel("/ground_truth/outliers", "cdr", si)
        for i in range(2):
            t = 1_700_000_000_000_000_000 + i * 10**8
            wr.add_message(cc, log_time=t, publish_time=t,
                           data=enc["sensor_msgs/msg/PointCloud2"](_cloud_msg(_scene(96, 128, rng), stamp_ns=t)))
            wr.add_message(ct, log_time=t, publish_time=t,
                           data=enc["sensor_msgs/msg/Image"](_image_msg(48, 64, stamp_ns=t, encoding="mono8")))
        wr.finish()
    before = digest([path])
    out = _fresh(work / "wrongsize-out")
    for name, argv in (("replay", ["replay", path, "--out", out / "r.mcap"]),
                       ("batch", ["batch", path, "-o", out / "b", "--workers", "1"])):
        r = run(argv, env=env)
        row = case_row("issue 35 (others)", f"ground truth of the wrong size: {name}", r, allowed={1, 3},
                       inputs_before=before, inputs=[path], folders=[out])
        row.allowed = row.allowed and ("wrong_size" in r.err + r.out or "size" in row.message)
        rows.append(row)
    # a label store held by another writer (BEGIN EXCLUSIVE)
    d = _fresh(work / "locked")
    db = d / "labels.sqlite"
    shutil.copy(f["db"], db)
    holder = sqlite3.connect(db, isolation_level=None)
    holder.execute("BEGIN EXCLUSIVE")
    runs = []
    try:
        for name, argv in (("labels import", ["labels", "import", f["labels_mcap"], "--db", db, "--log", f["parts"]]),
                           ("labels list", ["labels", "list", f["parts"], "--db", db])):
            runs.append((name, run(argv, env=env, timeout=300)))
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    for name, r in runs:  # the store read back once the other writer let go; a reader may read (WAL)
        rows.append(case_row("issue 35 (others)", f"label store locked by another writer: {name}", r,
                             allowed={1} if name == "labels import" else {0, 1}, inputs_before={}, inputs=[],
                             folders=[d]))
    # the output folder removed while replay --rrd writes
    d = _fresh(work / "removed")
    target = d / "sub"
    target.mkdir()
    p = _spawn(["replay", f["parts"], "--rrd", target / "o.rrd", "--out", target / "r.mcap"], env)
    _wait_line(p, "frame 0")
    shutil.rmtree(target, ignore_errors=True)
    rc, err = _finish(p)
    rows.append(case_row("issue 35 (others)", "output folder removed while replay --rrd writes", Run(rc, "", err, 0),
                         allowed={1}, inputs_before={}, inputs=[], folders=[d]))


GROUPS = {"full disk": group_full_disk, "signals": group_signals, "concurrent": group_concurrent,
          "unprivileged": group_unprivileged, "hostile": group_hostile,
          # issue 35's second campaign
          "stop/cont": group_stop_cont, "SIGHUP": group_sighup, "process group": group_process_group,
          "stdout": group_stdout, "ulimit": group_ulimit, "names": group_names, "links/FIFOs": group_links_fifos,
          "argparse": group_argparse, "issue 35 (others)": group_issue35_others}


def table(rows: list[Row]) -> str:
    head = "| group | case | exit | one-line message | inputs intact | leftovers | outputs complete | clean |\n" \
           "|---|---|---|---|---|---|---|---|\n"
    cells = []
    for r in rows:
        msg = r.message.replace("|", "\\|")
        cells.append(f"| {r.group} | {r.case} | {r.exit} | {msg} | {'yes' if r.inputs_intact else 'NO'} | "
                     f"{', '.join(r.leftovers) or 'none'} | {'yes' if r.outputs_complete else 'NO'} | "
                     f"{'yes' if r.clean else 'NO'} |")
    return head + "\n".join(cells)


def main(argv: list[str] | None = None) -> int:
    global SIZE
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, required=True, help="a folder for the inputs, mounts and outputs")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--only", nargs="*", choices=list(GROUPS), help="run only these groups")
    ap.add_argument("--size", default=SIZE, metavar="WxH",
                    help=f"size of the synthetic scans (default {SIZE}; 128x96 keeps a run short)")
    args = ap.parse_args(argv)
    SIZE = args.size
    rng = random.Random(args.seed)
    args.work.mkdir(parents=True, exist_ok=True)
    os.chmod(args.work, 0o755)
    env = {"ZCUT_CACHE": str(args.work / "cache"), "RUST_LOG": "off"}
    f = prepare(args.work, rng)
    rows: list[Row] = []
    needs_root = {"full disk", "unprivileged"}
    problem = can_mount(args.work) if os.geteuid() == 0 else "not root"
    for name, group in GROUPS.items():
        if args.only and name not in args.only:
            continue
        if name in needs_root and problem:
            print(f"skipped {name}: {problem}", file=sys.stderr)
            continue
        t0 = time.monotonic()
        n = len(rows)
        group(f, args.work, rng, rows, env)
        print(f"{name}: {len(rows) - n} case(s) in {time.monotonic() - t0:.0f} s, "
              f"{sum(r.clean for r in rows[n:])} clean", file=sys.stderr, flush=True)
    print(table(rows))
    clean = sum(r.clean for r in rows)
    print(f"\n{clean} of {len(rows)} rows clean (seed {args.seed})")
    return 0 if clean == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
