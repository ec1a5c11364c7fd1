"""Seeded generators of hostile inputs for ``zcut``, and the corpus of valid files they mutate.

Every generator is a function ``gen(rng, corpus, case_id) -> Case`` (see :data:`GENERATORS`); the
same (seed, generator, index) always gives the same case (:func:`make_cases`), so a case is
reproduced from its id alone.

``mcap_bytes``
    byte-level mutants of valid logs: bit flips, truncations, absurd 4- and 8-byte values,
    inserted/deleted runs, zero-filled regions.
``mcap_struct``
    record-aware mutants: truncation at or near a record boundary, record-length lies, wrong
    opcodes, zeroed, duplicated, deleted or swapped records, a dropped, duplicated or lying
    summary (footer, statistics, chunk index), lying chunk headers (sizes, compression, CRC),
    records inside a chunk mutated and the chunk recompressed to its old size.
``mcap_bomb``
    chunk and message compression bombs: a small zstd/lz4 chunk that claims or expands to a huge
    size, rosbag2 per-message zstd frames that do, clouds at and over the size caps.
``cloud``
    valid MCAP holding a PointCloud2 with hostile fields: huge/zero/"negative" dimensions,
    point_step/row_step lies, field offsets and types out of range, big-endian flags,
    NaN/inf/denormal/huge coordinates, identical points, all-invalid clouds, tiny grids, stamps past
    2038 or negative, non-UTF-8 strings, short or long data.
``image``
    the same for Image, CameraInfo and mono8 masks: sizes that differ from the cloud, odd
    encodings, step lies, NaN/inf/zero intrinsics, huge distortion lists, unpaired stamps.
``pcd`` / ``ply``
    headers and bodies for ``zcut record`` (and PLY bin models): huge WIDTH x HEIGHT, lying
    POINTS, unknown types, binary_compressed with lying sizes, element counts that ask for 74 GB,
    inf in a camera element, ascii garbage, a same-named PNG that is garbage or claims 1 Gpx.
``cli``
    random option values: negative/huge/NaN/1e308 numbers, ``--period 1e308``, stamps past 2038,
    frame ranges, sizes, seeds, unknown flags, ``--connect 'not a url'``.
``paths``
    nonexistent paths, folders, FIFOs, ``/dev/zero``, symlink loops, dangling links, over-long
    and non-UTF-8 names; an output that is an input (same path, hard link, symlink, the config
    written beside an output), an output under a regular file, two outputs on one path.
``config``
    ``--config`` files: binary, deeply nested, huge or non-finite numbers, wrong types, unknown
    keys, syntax errors, special files.
``labels``
    ``labels export/import``: mutated and hostile label MCAPs, damaged label stores, odd
    annotator names, outputs that alias inputs.

The corpus (:func:`build_corpus`) is written by a separate process (``python fuzzgen.py corpus
DIR``): some of it goes through numba kernels (``LogWriter``, ``zcut synth``), which must not run
in a process that forks cases. The generators themselves only use numpy, struct and the ``mcap``
writer.
"""

from __future__ import annotations

import io
import json
import os
import struct
import subprocess
import sys
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from fuzzlib import PYTHON, REPO, Case

# ----------------------------------------------------------------------------------------------- corpus
CORPUS_VERSION = 2
H, W = 12, 16  # the hand-made logs' grid


@dataclass
class Corpus:
    """Valid inputs, read into memory (name -> bytes), with what the mutants need to know."""

    dir: Path
    files: dict[str, bytes]
    frames: dict[str, int]  # log name -> clouds on its cloud topic
    cache: dict[str, bytes] = field(default_factory=dict)  # generated inputs reused by later cases

    def __getitem__(self, name: str) -> bytes:
        return self.files[name]


#: The logs mutated by mcap_bytes / mcap_struct, with their number of frames (filled by build_corpus).
MCAP_SEEDS = ("w3.mcap", "m3z.mcap", "m3n.mcap", "m3l.mcap", "m3u.mcap", "synth.mcap", "results.mcap", "w20.mcap")


def load_corpus(folder: Path) -> Corpus:
    meta = json.loads((folder / "corpus.json").read_text())
    files = {name: (folder / name).read_bytes() for name in meta["files"]}
    return Corpus(folder, files, meta["frames"])


def ensure_corpus(folder: Path, *, warmed_up: bool = False) -> Corpus:
    """Build the corpus in ``folder`` (in a separate process) unless it is there already. ``warmed_up``: the
    caller has run ``python -m replay.warmup`` to its end in this checkout (every kernel compiled into numba's
    cache), so the corpus process does not run it again."""
    done = folder / "corpus.json"
    if not done.is_file() or json.loads(done.read_text()).get("version") != CORPUS_VERSION:
        folder.mkdir(parents=True, exist_ok=True)
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), str(Path(__file__).parent)]))
        argv = [PYTHON, __file__, "corpus", str(folder), *(["--warmed-up"] if warmed_up else [])]
        proc = subprocess.run(argv, env=env, cwd=str(folder), capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"building the fuzz corpus in {folder} failed:\n{proc.stderr[-4000:]}")
    return load_corpus(folder)


def _scene(rng: np.random.Generator, h: int = H, w: int = W) -> tuple[np.ndarray, np.ndarray]:
    """A small organized scene: a tilted plane at ~0.5 m with bumps, some NaN; and its colours."""
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    z = 0.5 + 0.002 * u + 0.001 * v + 0.003 * rng.standard_normal((h, w))
    z[rng.random((h, w)) < 0.05] -= 0.02  # a few floating points
    x = (u - w / 2) * z / 300.0
    y = (v - h / 2) * z / 300.0
    xyz = np.stack([x, y, z], axis=-1).astype(np.float32)
    xyz[rng.random((h, w)) < 0.08] = np.nan
    rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    return xyz, rgb


def cloud_bytes(xyz: np.ndarray, rgb: np.ndarray | None = None) -> bytes:
    """x, y, z FLOAT32 at 0/4/8 and rgba UINT32 at 12, little-endian (numpy only, no kernel)."""
    h, w = xyz.shape[:2]
    out = np.zeros((h, w, 4), dtype="<f4")
    out[..., :3] = xyz
    if rgb is not None:
        r = rgb.astype(np.uint32)
        out.view("<u4")[..., 3] = np.uint32(0xFF000000) | (r[..., 0] << 16) | (r[..., 1] << 8) | r[..., 2]
    return out.tobytes()


def _mcap(messages, *, compression: str = "zstd", chunk_size: int = 4096, chunked: bool = True,
          crcs: bool = True, profile: str = "ros2", sequence: bool = True, metadata=None) -> bytes:
    """A valid MCAP (the ``mcap`` library's writer) of [(topic, type, cdr bytes, log_time)]."""
    from mcap.writer import CompressionType, Writer

    from replay.logs import ros2_msgs as rm

    buf = io.BytesIO()
    comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}[compression]
    w = Writer(buf, chunk_size=chunk_size, compression=comp, use_chunking=chunked, enable_crcs=crcs)
    w.start(profile=profile, library="zcut fuzz")
    schemas: dict[str, int] = {}
    channels: dict[str, int] = {}
    seq: dict[str, int] = {}
    for name, data in (metadata or {}).items():
        w.add_metadata(name, data)
    for topic, msg_type, data, t in messages:
        if topic not in channels:
            if msg_type not in schemas:
                text = rm.SCHEMAS.get(msg_type, "string data\n").encode()
                schemas[msg_type] = w.register_schema(name=msg_type, encoding="ros2msg", data=text)
            channels[topic] = w.register_channel(topic=topic, message_encoding="cdr", schema_id=schemas[msg_type])
            seq[topic] = 0
        w.add_message(channels[topic], log_time=t, publish_time=t, data=data,
                      sequence=seq[topic] if sequence else 0)
        seq[topic] += 1
    w.finish()
    return buf.getvalue()


def frame_messages(rng: np.random.Generator, n: int, *, h: int = H, w: int = W, image: str | None = "rgb8",
                   info: bool = True, mask: bool = True, step32: bool = False, t0: int = 10**9):
    """Messages of n valid frames: [(topic, type, bytes, log_time)] in recording order."""
    from replay.logs import ros2_msgs as rm
    from zcut.cloud import Intrinsics

    out = []
    for i in range(n):
        stamp = t0 + i * 100_000_000
        xyz, rgb = _scene(rng, h, w)
        if step32:  # PCL-like: x y z at 0/4/8, rgb FLOAT32-packed at 16, point_step 32
            arr = np.zeros((h, w, 8), dtype="<f4")
            arr[..., :3] = xyz
            r = rgb.astype(np.uint32)
            arr.view("<u4")[..., 4] = (r[..., 0] << 16) | (r[..., 1] << 8) | r[..., 2]
            fields = (*rm.XYZ_FIELDS, rm.PointField("rgb", 16, rm.FLOAT32, 1))
            cloud = rm.encode_cloud(stamp_ns=stamp, frame_id="cam", height=h, width=w, fields=fields,
                                    point_step=32, row_step=32 * w, data=arr.tobytes(), is_dense=False)
        else:
            cloud = rm.encode_cloud(stamp_ns=stamp, frame_id="cam", height=h, width=w, fields=rm.XYZRGBA_FIELDS,
                                    point_step=16, row_step=16 * w, data=cloud_bytes(xyz, rgb), is_dense=False)
        if image is not None:
            ch = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1}[image]
            px = np.concatenate([rgb, np.full((h, w, max(ch - 3, 0)), 255, np.uint8)], axis=2)[..., :ch]
            out.append(("/camera/image", rm.IMAGE, rm.encode_image(
                stamp_ns=stamp, frame_id="cam", height=h, width=w, encoding=image, step=w * ch,
                data=np.ascontiguousarray(px).tobytes()), stamp))
        out.append(("/camera/points", rm.POINTCLOUD2, cloud, stamp))
        if info:
            k = Intrinsics(300.0, 300.0, w / 2 - 0.5, h / 2 - 0.5, w, h)
            out.append(("/camera/camera_info", rm.CAMERAINFO, rm.encode_camera_info(k, stamp_ns=stamp, frame_id="cam"),
                        stamp))
        if mask:
            m = (rng.random((h, w)) < 0.1).astype(np.uint8) * 255
            out.append(("/ground_truth/outliers", rm.IMAGE, rm.encode_image(
                stamp_ns=stamp, frame_id="cam", height=h, width=w, encoding="mono8", step=w, data=m.tobytes()),
                stamp))
    return out


def build_corpus(folder: Path, *, warmed_up: bool = False) -> None:  # runs in its own process (kernels)
    """Write the corpus: hand-made logs (LogWriter and the mcap library, every compression), a
    synthetic log, its results file, an empty-bin log and its bin model, a label store and its
    export, PCD and PLY files. First the kernels' warm-up, unless ``warmed_up`` (the caller ran it)."""
    from cli.main import main
    from replay.logs.frame import Frame
    from replay.logs.writer import LogWriter
    from zcut.cloud import Intrinsics

    folder = Path(folder)
    os.chdir(folder)
    try:  # compile every kernel once here, not in the first cases (a compile can outlast a case's time cap)
        from replay.warmup import main as warmup
    except ImportError:  # pragma: no cover - an older tree
        warmup = None
    if warmed_up:
        warmup = None
    if warmup is not None:
        warmup()
    frames: dict[str, int] = {}
    rng = np.random.default_rng(20250101)
    with LogWriter(folder / "w3.mcap", chunk_size=1024) as w:
        for i in range(3):
            xyz, rgb = _scene(rng)
            w.write_frame(Frame(xyz=xyz, rgb=rgb, stamp_ns=10**9 + i * 10**8, frame_id="cam",
                                intrinsics=Intrinsics(300.0, 300.0, W / 2 - 0.5, H / 2 - 0.5, W, H),
                                topic="/camera/points", index=i,
                                masks={"/ground_truth/outliers": rng.random((H, W)) < 0.1}))
    frames["w3.mcap"] = 3
    with LogWriter(folder / "w20.mcap", chunk_size=512) as w:  # many small chunks: resynchronisation
        for i in range(20):
            xyz, rgb = _scene(rng, 6, 8)
            w.write_frame(Frame(xyz=xyz, rgb=rgb if i % 3 else None, stamp_ns=10**9 + i * 10**8, frame_id="cam",
                                intrinsics=None, topic="/camera/points", index=i,
                                masks={"/ground_truth/outliers": rng.random((6, 8)) < 0.1}))
    frames["w20.mcap"] = 20
    for name, kw in (("m3z.mcap", dict(compression="zstd", chunk_size=2048)),
                     ("m3n.mcap", dict(compression="none", chunk_size=2048, crcs=False)),
                     ("m3l.mcap", dict(compression="lz4", chunk_size=2048)),
                     ("m3u.mcap", dict(chunked=False, sequence=False))):
        msgs = frame_messages(rng, 3, step32=name == "m3z.mcap", image="bgr8" if name == "m3l.mcap" else "rgb8")
        (folder / name).write_bytes(_mcap(msgs, **kw))
        frames[name] = 3

    def cli(*argv: str) -> None:
        rc = main(list(argv))
        if rc != 0:
            raise RuntimeError(f"corpus: zcut {' '.join(argv)} exited {rc}")

    cli("synth", "-o", "synth.mcap", "--size", "32x24", "--frames", "2", "--seed", "3")
    frames["synth.mcap"] = 2
    cli("replay", "synth.mcap", "--out", "results.mcap")
    frames["results.mcap"] = 2
    cli("synth", "-o", "empty.mcap", "--size", "48x32", "--frames", "2", "--seed", "4", "--empty")
    frames["empty.mcap"] = 2
    cli("bin-model", "empty.mcap", "-o", "bin.ply")
    _label_store(folder)
    cli("labels", "export", "synth.mcap", "--db", "labels.sqlite", "-o", "labels.mcap")
    for name, data in cloud_files(np.random.default_rng(7)).items():
        (folder / name).write_bytes(data)
    (folder / "good.toml").write_text('part = "spheres"\n[zcut]\nstep_mm = 0.5\nmax_depth_mm = 20.0\n[sor]\nk = 6\n')
    names = sorted(p.name for p in folder.iterdir() if p.is_file() and p.name != "corpus.json"
                   and not p.name.endswith(("-wal", "-shm")))
    (folder / "corpus.json").write_text(json.dumps({"version": CORPUS_VERSION, "files": names, "frames": frames}))


def _label_store(folder: Path) -> None:
    from annotate.store import LabelStore
    from replay.logs.reader import LogReader

    rng = np.random.default_rng(11)
    with LabelStore(folder / "labels.sqlite") as store:
        log = store.add_log(folder / "synth.mcap")
        for f in LogReader(folder / "synth.mcap").frames():
            valid = np.isfinite(f.xyz).all(axis=2)
            rec = store.add_frame(log, topic=f.topic, stamp_ns=f.stamp_ns, index=f.index, shape=f.shape,
                                  frame_id=f.frame_id, valid=valid)
            out = valid & (rng.random(f.shape) < 0.05)
            store.save_label(rec, annotator="alice", outliers=out, reviewed=valid, base_revision=None)
    for suffix in ("-wal", "-shm"):  # a closed WAL store leaves none; be sure the file stands alone
        (folder / f"labels.sqlite{suffix}").unlink(missing_ok=True)


# ----------------------------------------------------------------------------------------------- PCD / PLY
def pcd_bytes(xyz: np.ndarray, rgb: np.ndarray | None, kind: str, *, header_extra: str = "") -> bytes:
    """An organized PCD (v0.7) of ``xyz`` (H, W, 3) float32 [+ rgb] as ascii/binary/binary_compressed."""
    h, w = xyz.shape[:2]
    cols = [xyz[..., 0], xyz[..., 1], xyz[..., 2]]
    names, sizes, types = ["x", "y", "z"], ["4"] * 3, ["F"] * 3
    if rgb is not None:
        r = rgb.astype(np.uint32)
        packed = ((r[..., 0] << 16) | (r[..., 1] << 8) | r[..., 2]).view(np.float32)
        cols.append(packed)
        names.append("rgb")
        sizes.append("4")
        types.append("F")
    head = (f"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {' '.join(names)}\n"
            f"SIZE {' '.join(sizes)}\nTYPE {' '.join(types)}\nCOUNT {' '.join('1' for _ in names)}\n"
            f"WIDTH {w}\nHEIGHT {h}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {h * w}\n{header_extra}DATA {kind}\n")
    arr = np.stack([c.reshape(-1) for c in cols], axis=-1).astype("<f4")
    if kind == "ascii":
        lines = []
        for row in arr:
            vals = [repr(float(v)) if i < 3 else str(int(row[i:i + 1].view("<u4")[0])) for i, v in enumerate(row)]
            lines.append(" ".join("nan" if v == "nan" else v for v in vals))
        body = ("\n".join(lines) + "\n").encode()
    elif kind == "binary":
        body = arr.tobytes()
    else:
        import lzf

        raw = np.ascontiguousarray(arr.T).tobytes()  # column-major, as PCL writes it
        comp = lzf.compress(raw) or b""
        body = struct.pack("<II", len(comp), len(raw)) + comp
    return head.encode() + body


def ply_bytes(xyz: np.ndarray, rgb: np.ndarray | None, fmt: str, *, org: str = "obj_info",
              camera: dict | None = None, extra_header: str = "") -> bytes:
    """An organized PLY: ``org`` = obj_info / comment / camera / none (then the caller needs --shape)."""
    h, w = xyz.shape[:2]
    n = h * w
    head = [f"ply\nformat {fmt} 1.0\n"]
    if org == "obj_info":
        head.append(f"obj_info num_cols {w}\nobj_info num_rows {h}\n")
    elif org == "comment":
        head.append(f"comment num_rows {h}\ncomment num_cols {w}\n")
    head.append(extra_header)
    head.append(f"element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n")
    if rgb is not None:
        head.append("property uchar red\nproperty uchar green\nproperty uchar blue\n")
    cam = None
    if org == "camera" or camera is not None:
        cam = {"viewportx": float(w), "viewporty": float(h), **(camera or {})}
        head.append("element camera 1\n" + "".join(f"property float {k}\n" for k in cam))
    head.append("end_header\n")
    flat = xyz.reshape(-1, 3)
    if fmt == "ascii":
        rows = []
        for i in range(n):
            vals = [repr(float(v)) for v in flat[i]]
            if rgb is not None:
                vals += [str(int(c)) for c in rgb.reshape(-1, 3)[i]]
            rows.append(" ".join(vals))
        body = "\n".join(rows) + "\n"
        if cam is not None:
            body += " ".join(repr(float(v)) for v in cam.values()) + "\n"
        return "".join(head).encode() + body.encode()
    bo = "<" if fmt == "binary_little_endian" else ">"
    fields = [("x", bo + "f4"), ("y", bo + "f4"), ("z", bo + "f4")]
    if rgb is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    arr = np.empty(n, dtype=fields)
    arr["x"], arr["y"], arr["z"] = flat[:, 0], flat[:, 1], flat[:, 2]
    if rgb is not None:
        c = rgb.reshape(-1, 3)
        arr["red"], arr["green"], arr["blue"] = c[:, 0], c[:, 1], c[:, 2]
    body = arr.tobytes()
    if cam is not None:
        body += np.array(list(cam.values()), dtype=bo + "f4").tobytes()
    return "".join(head).encode() + body


def ply_range_grid(xyz: np.ndarray, fmt: str) -> bytes:
    """PCL's organized PLY: the valid vertices, then a range_grid of 0/1-long index lists."""
    h, w = xyz.shape[:2]
    flat = xyz.reshape(-1, 3)
    ok = np.isfinite(flat).all(axis=1)
    verts = flat[ok]
    head = (f"ply\nformat {fmt} 1.0\nobj_info num_cols {w}\nobj_info num_rows {h}\n"
            f"element vertex {len(verts)}\nproperty float x\nproperty float y\nproperty float z\n"
            f"element range_grid {h * w}\nproperty list uchar int vertex_indices\nend_header\n")
    idx = np.cumsum(ok) - 1
    if fmt == "ascii":
        body = "".join(" ".join(repr(float(v)) for v in p) + "\n" for p in verts)
        body += "".join(f"1 {idx[i]}\n" if ok[i] else "0\n" for i in range(h * w))
        return head.encode() + body.encode()
    bo = "<" if fmt == "binary_little_endian" else ">"
    body = verts.astype(bo + "f4").tobytes()
    parts = [struct.pack(bo + "Bi", 1, int(idx[i])) if ok[i] else b"\x00" for i in range(h * w)]
    return head.encode() + body + b"".join(parts)


def png_bytes(rgb: np.ndarray) -> bytes:
    """A PNG of an (H, W, 3) uint8 image (zlib + struct, no OpenCV)."""
    h, w = rgb.shape[:2]
    raw = b"".join(b"\x00" + rgb[i].tobytes() for i in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def cloud_files(rng: np.random.Generator) -> dict[str, bytes]:
    """The PCD/PLY seeds: every encoding, with and without colour (millimetre and metre units)."""
    out = {}
    xyz, rgb = _scene(rng, 6, 8)
    for kind in ("ascii", "binary", "binary_compressed"):
        out[f"c_{kind}.pcd"] = pcd_bytes(xyz, rgb, kind)
    out["c_nocolor.pcd"] = pcd_bytes(xyz * 1000, None, "binary")
    for fmt in ("ascii", "binary_little_endian", "binary_big_endian"):
        out[f"c_{fmt}.ply"] = ply_bytes(xyz, rgb, fmt)
        out[f"g_{fmt}.ply"] = ply_range_grid(xyz, fmt)
    out["c_camera.ply"] = ply_bytes(xyz, None, "binary_little_endian", org="camera")
    out["c_comment.ply"] = ply_bytes(xyz, rgb, "ascii", org="comment")
    out["c_noorg.ply"] = ply_bytes(xyz, None, "binary_little_endian", org="none")
    out["c_binary.png"] = png_bytes(rgb)
    return out



# ----------------------------------------------------------------------------------------------- helpers
def _pick(rng: np.random.Generator, seq):
    return seq[int(rng.integers(len(seq)))]


def _weighted(rng: np.random.Generator, table):
    """A value of [(weight, value), ...]."""
    w = np.array([t[0] for t in table], dtype=float)
    return table[int(rng.choice(len(table), p=w / w.sum()))][1]


#: what a command on a log is, and how it reports frames (the loss oracle)
LOG_COMMANDS = (
    (6, "topics"), (10, "topics-check"), (16, "replay-json"), (5, "replay-out"), (3, "replay-frames"),
    (1, "replay-rrd"), (5, "accuracy"), (3, "bin-model"), (1, "replay-bin"),
)


def log_command(rng: np.random.Generator, name: str, n_frames: int | None, *, kind: str | None = None):
    """(argv, count, expect_frames, extra files) of a command reading the log ``name``."""
    kind = kind or _weighted(rng, LOG_COMMANDS)
    extra: dict[str, bytes] = {}
    if kind == "topics":
        return ["topics", name], None, None, extra
    if kind == "topics-check":
        return ["topics", "--check", name], "check", n_frames, extra
    if kind == "replay-json":
        return ["replay", name, "--json"], "json", n_frames, extra
    if kind == "replay-out":
        return ["replay", name, "--out", "out.mcap", "--json"], "json", n_frames, extra
    if kind == "replay-frames":
        return ["replay", name, "--frames", "1:3"], "table", None if n_frames is None else max(min(n_frames, 3) - 1, 0), extra
    if kind == "replay-rrd":
        return ["replay", name, "--rrd", "out.rrd"], "table", n_frames, extra
    if kind == "accuracy":
        return ["accuracy", name, "--json"], None, None, extra
    if kind == "bin-model":
        return ["bin-model", name, "-o", "model_out.ply"], None, None, extra
    if kind == "replay-bin":
        return ["replay", name, "--bin-model", "bin.ply", "--json"], "json", n_frames, {"bin.ply": b""}
    raise ValueError(kind)


def _log_case(cid: str, gen: str, what: str, corpus: Corpus, rng, name: str, data: bytes, n_frames: int | None,
              kind: str | None = None, **kw) -> Case:
    argv, count, expect, extra = log_command(rng, name, n_frames, kind=kind)
    files = {name: data}
    for k in extra:
        files[k] = corpus[k]
    return Case(cid, gen, f"{what} | {argv[0]}", argv, files=files, count=count, expect_frames=expect, **kw)


_ABSURD8 = (0, 1, 2**31, 2**32 - 1, 2**32, 2**40, 2**62, 2**63, 2**64 - 1)
_ABSURD4 = (0, 1, 2**16, 2**24, 2**31 - 1, 2**31, 2**32 - 1)


def mutate_bytes(rng: np.random.Generator, raw: bytes) -> tuple[bytes, str]:
    """One byte-level mutation of ``raw``: (mutant, description)."""
    b = bytearray(raw)
    n = len(b)
    kind = _pick(rng, ("flip", "flips", "trunc", "abs8", "abs4", "delete", "insert", "zero", "ones", "dup"))
    pos = int(rng.integers(0, max(n - 8, 1)))
    if kind == "flip":
        b[pos] ^= 1 << int(rng.integers(8))
    elif kind == "flips":
        for p in rng.integers(0, n, int(rng.integers(2, 17))):
            b[int(p)] ^= int(rng.integers(1, 256))
    elif kind == "trunc":
        pos = int(rng.integers(0, n))
        del b[pos:]
    elif kind == "abs8":
        b[pos:pos + 8] = struct.pack("<Q", _pick(rng, _ABSURD8))
    elif kind == "abs4":
        b[pos:pos + 4] = struct.pack("<I", _pick(rng, _ABSURD4))
    elif kind == "delete":
        del b[pos:pos + int(rng.integers(1, 256))]
    elif kind == "insert":
        b[pos:pos] = rng.integers(0, 256, int(rng.integers(1, 256)), dtype=np.uint8).tobytes()
    elif kind == "zero":
        ln = int(rng.integers(1, 4096))
        b[pos:pos + ln] = bytes(len(b[pos:pos + ln]))
    elif kind == "ones":
        ln = int(rng.integers(1, 512))
        b[pos:pos + ln] = b"\xff" * len(b[pos:pos + ln])
    else:  # duplicate a run
        ln = int(rng.integers(1, 2048))
        b[pos:pos] = b[pos:pos + ln]
    return bytes(b), f"{kind} at {pos}"


# ----------------------------------------------------------------------------------------------- MCAP records
@dataclass
class Rec:
    offset: int
    op: int
    length: int  # of the body

    @property
    def end(self) -> int:
        return self.offset + 9 + self.length


def records(raw: bytes) -> list[Rec]:
    """The top-level records of an intact MCAP file, in file order."""
    out = []
    pos = 8
    while pos + 9 <= len(raw) - 8:
        op, ln = struct.unpack_from("<BQ", raw, pos)
        if pos + 9 + ln > len(raw):
            break
        out.append(Rec(pos, op, ln))
        pos += 9 + ln
    return out


def _u64_fields(raw: bytes, rec: Rec) -> dict[str, int]:
    """Byte offsets of the fixed fields zcut's structural mutants lie about."""
    b = rec.offset + 9
    if rec.op == 0x06:  # Chunk
        clen = struct.unpack_from("<I", raw, b + 28)[0]
        return {"message_start_time": b, "message_end_time": b + 8, "uncompressed_size": b + 16,
                "records_length": b + 32 + clen}
    if rec.op == 0x08:  # ChunkIndex
        return {"chunk_start_offset": b + 16, "chunk_length": b + 24}
    if rec.op == 0x0B:  # Statistics: then u16, 4 x u32, 2 x u64 times, the per-channel counts map
        m = b + 8 + 2 + 16 + 16
        end = m + 4 + struct.unpack_from("<I", raw, m)[0]
        counts = {f"channel_count[{i}]": at + 2 for i, at in enumerate(range(m + 4, end, 10))}
        return {"message_count": b, "message_start_time": b + 30, "message_end_time": b + 38, **counts}
    if rec.op == 0x02:  # Footer
        return {"summary_start": b, "summary_offset_start": b + 8}
    if rec.op == 0x0E:  # SummaryOffset
        return {"group_start": b + 1, "group_length": b + 9}
    if rec.op == 0x0D:  # MetadataIndex
        return {"metadata_offset": b, "metadata_length": b + 8}
    return {}


def _chunk_parts(raw: bytes, rec: Rec):
    """(header fields, compression, compressed data span) of a Chunk record."""
    b = rec.offset + 9
    t0, t1, usize, crc, clen = struct.unpack_from("<QQQII", raw, b)
    comp = raw[b + 32:b + 32 + clen].decode()
    dlen = struct.unpack_from("<Q", raw, b + 32 + clen)[0]
    d0 = b + 40 + clen
    return usize, crc, comp, d0, dlen


def _compress(comp: str, data: bytes) -> bytes:
    if comp == "zstd":
        import zstandard

        return zstandard.ZstdCompressor(level=19).compress(data)
    if comp == "lz4":
        import lz4.frame

        return lz4.frame.compress(data, compression_level=16)
    return data


def _decompress(comp: str, data: bytes, size: int) -> bytes:
    if comp == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if comp == "lz4":
        import lz4.frame

        return lz4.frame.decompress(data)
    return data


def _mutate_chunk_inside(rng, raw: bytes, rec: Rec) -> tuple[bytes, str] | None:
    """Mutate a record inside a chunk, recompress, and fit the chunk into its old record (the
    data length shrinks, zero padding follows it; sizes and CRC say the truth): the offsets of
    everything else stay right."""
    usize, crc, comp, d0, dlen = _chunk_parts(raw, rec)
    inner = bytearray(_decompress(comp, raw[d0:d0 + dlen], usize))
    recs = []
    pos = 0
    while pos + 9 <= len(inner):
        op, ln = struct.unpack_from("<BQ", inner, pos)
        recs.append((pos, op, ln))
        pos += 9 + ln
    if not recs:
        return None
    pos, op, ln = _pick(rng, recs)
    kind = _pick(rng, ("len", "op", "flip", "cut", "zero", "field"))
    if kind == "len":
        inner[pos + 1:pos + 9] = struct.pack("<Q", _pick(rng, (0, 1, ln - 1, ln + 1, 2**32, 2**63, len(inner))))
    elif kind == "op":
        inner[pos] = _pick(rng, (0x00, 0x03, 0x04, 0x05, 0x06, 0x10, 0x7F, 0x80, 0xFF))
    elif kind == "flip":
        for _ in range(int(rng.integers(1, 5))):
            p = pos + int(rng.integers(0, 9 + ln))
            inner[p] ^= 1 << int(rng.integers(8))
    elif kind == "cut":
        del inner[pos + int(rng.integers(1, 9 + ln)):]
    elif kind == "zero":
        inner[pos:pos + 9 + ln] = bytes(9 + ln)
    else:  # a field of the record's body: channel id, sequence, times, string lengths
        at = pos + 9 + int(rng.integers(0, max(min(ln, 32), 1)))
        inner[at:at + 4] = struct.pack("<I", _pick(rng, _ABSURD4))
    new = _compress(comp, bytes(inner))
    if len(new) > dlen:
        return None
    b = bytearray(raw)
    b0 = rec.offset + 9
    struct.pack_into("<QI", b, b0 + 16, len(inner), zlib.crc32(inner) if crc else 0)
    clen = struct.unpack_from("<I", b, b0 + 28)[0]
    struct.pack_into("<Q", b, b0 + 32 + clen, len(new))
    b[d0:d0 + dlen] = new + bytes(dlen - len(new))
    return bytes(b), f"chunk at {rec.offset}: inner record at {pos} (op 0x{op:02x}): {kind}"


_OPS = {0x01: "header", 0x02: "footer", 0x03: "schema", 0x04: "channel", 0x05: "message", 0x06: "chunk",
        0x07: "message_index", 0x08: "chunk_index", 0x0B: "statistics", 0x0C: "metadata",
        0x0D: "metadata_index", 0x0E: "summary_offset", 0x0F: "data_end"}


def mutate_structure(rng: np.random.Generator, raw: bytes) -> tuple[bytes, str]:
    """One record-aware mutation of an intact MCAP file."""
    recs = records(raw)
    footer = next((r for r in recs if r.op == 0x02), None)
    s_start = struct.unpack_from("<Q", raw, footer.offset + 9)[0] if footer else 0
    for _ in range(20):
        kind = _pick(rng, ("trunc", "len", "op", "zero", "dup", "del", "swap", "drop-summary", "dup-summary",
                           "field", "field", "summary-field", "summary-field", "chunk-header", "chunk-inside",
                           "chunk-inside"))
        r = _pick(rng, recs)
        if kind == "summary-field":  # the records whose numbers the reader trusts: the summary's
            summary = [x for x in recs if x.op in (0x02, 0x08, 0x0B, 0x0D, 0x0E)]
            if not summary:
                continue
            r, kind = _pick(rng, summary), "field"
        name = _OPS.get(r.op, hex(r.op))
        b = bytearray(raw)
        if kind == "trunc":
            cut = r.offset + _pick(rng, (0, 1, 8, 9, 9 + r.length // 2, 9 + r.length - 1))
            return raw[:cut], f"truncated at byte {cut} ({name} at {r.offset})"
        if kind == "len":
            v = _pick(rng, (0, 1, r.length - 1, r.length + 1, r.length + 9, 2**31, 2**63, 2**64 - 1, len(raw)))
            b[r.offset + 1:r.offset + 9] = struct.pack("<Q", max(v, 0))
            return bytes(b), f"{name} at {r.offset}: length {r.length} -> {v}"
        if kind == "op":
            v = _pick(rng, (0x00, 0x01, 0x02, 0x05, 0x06, 0x07, 0x0F, 0x10, 0x7F, 0x80, 0xFF))
            b[r.offset] = v
            return bytes(b), f"{name} at {r.offset}: opcode -> 0x{v:02x}"
        if kind == "zero":
            a = r.offset + _pick(rng, (0, 9))
            b[a:r.end] = bytes(r.end - a)
            return bytes(b), f"{name} at {r.offset}: zero-filled from byte {a}"
        if kind == "dup":
            return raw[:r.end] + raw[r.offset:r.end] + raw[r.end:], f"{name} at {r.offset} duplicated"
        if kind == "del" and r.op != 0x01:
            return raw[:r.offset] + raw[r.end:], f"{name} at {r.offset} deleted"
        if kind == "swap":
            chunks = [c for c in recs if c.op == 0x06]
            if len(chunks) >= 2:
                i = int(rng.integers(len(chunks) - 1))
                a, c = chunks[i], chunks[i + 1]
                if a.end <= c.offset:
                    out = raw[:a.offset] + raw[c.offset:c.end] + raw[a.end:c.offset] + raw[a.offset:a.end] + raw[c.end:]
                    return out, f"chunks at {a.offset} and {c.offset} swapped"
        if kind == "drop-summary" and footer and s_start:
            end = raw[:s_start] + struct.pack("<BQQQI", 0x02, 20, 0, 0, 0) + raw[-8:]
            return end, "summary section dropped (footer says none)"
        if kind == "dup-summary" and footer and s_start:
            section = raw[s_start:footer.offset]
            where = _pick(rng, ("first", "second"))
            second = footer.offset
            new_start = s_start if where == "first" else second
            out = raw[:footer.offset] + section + struct.pack("<BQQQI", 0x02, 20, new_start, 0, 0) + raw[-8:]
            return out, f"summary section duplicated, the footer points to the {where} copy"
        if kind == "field":
            fields = _u64_fields(raw, r)
            if fields:
                fname = _pick(rng, sorted(fields))
                v = _pick(rng, (0, 1, 2, 4, 8, 2**31, 2**62, 2**63, 2**64 - 1, len(raw), len(raw) - 8, s_start or 9,
                                int(rng.integers(0, len(raw)))))
                b[fields[fname]:fields[fname] + 8] = struct.pack("<Q", v)
                return bytes(b), f"{name} at {r.offset}: {fname} -> {v}"
        if kind == "chunk-header" and r.op == 0x06:
            usize, crc, comp, d0, dlen = _chunk_parts(raw, r)
            what = _pick(rng, ("usize", "crc", "compression"))
            b0 = r.offset + 9
            if what == "usize":
                v = _pick(rng, (0, 1, usize - 1, usize + 1, 2 * usize, 2**31, 2**40, 2**64 - 1, (320 << 20) + 1))
                b[b0 + 16:b0 + 24] = struct.pack("<Q", max(v, 0))
                return bytes(b), f"chunk at {r.offset}: uncompressed_size {usize} -> {v}"
            if what == "crc":
                b[b0 + 24:b0 + 28] = struct.pack("<I", int(rng.integers(1, 2**32)))
                return bytes(b), f"chunk at {r.offset}: wrong CRC"
            if comp:
                other = _pick(rng, [c for c in ("zstd", "lz4 ", "gzip", "ZSTD", "\x00\x00\x00\x00", "lz4\x00", "nope")
                                    if len(c) >= len(comp)])[:len(comp)]
                b[b0 + 32:b0 + 32 + len(comp)] = other.encode()
                return bytes(b), f"chunk at {r.offset}: compression {comp!r} -> {other!r}"
        if kind == "chunk-inside" and r.op == 0x06:
            got = _mutate_chunk_inside(rng, raw, r)
            if got is not None:
                return got
    return mutate_bytes(rng, raw)


def gen_mcap_bytes(rng: np.random.Generator, corpus: Corpus, cid: str) -> Case:
    name = _pick(rng, MCAP_SEEDS)
    data, what = mutate_bytes(rng, corpus[name])
    return _log_case(cid, "mcap_bytes", f"{name}: {what}", corpus, rng, name, data, corpus.frames[name])


def gen_mcap_struct(rng: np.random.Generator, corpus: Corpus, cid: str) -> Case:
    name = _pick(rng, MCAP_SEEDS)
    data, what = mutate_structure(rng, corpus[name])
    return _log_case(cid, "mcap_struct", f"{name}: {what}", corpus, rng, name, data, corpus.frames[name])


# ----------------------------------------------------------------------------------------------- bombs
def _rec(op: int, body: bytes) -> bytes:
    return struct.pack("<BQ", op, len(body)) + body


def _s(b: bytes) -> bytes:
    return struct.pack("<I", len(b)) + b


def _schema_channel(msg_type: str, topic: str, sid: int = 1, cid: int = 1) -> bytes:
    from replay.logs import ros2_msgs as rm

    text = rm.SCHEMAS[msg_type].encode()
    return (_rec(0x03, struct.pack("<H", sid) + _s(msg_type.encode()) + _s(b"ros2msg") + _s(text))
            + _rec(0x04, struct.pack("<HH", cid, sid) + _s(topic.encode()) + _s(b"cdr") + struct.pack("<I", 0)))


def _cloud_prefix(h: int, w: int, n_data: int, stamp_ns: int = 10**9) -> tuple[bytes, bytes]:
    """(CDR bytes before the data, after it) of an xyz+rgba PointCloud2 with n_data data bytes."""
    from replay.logs import ros2_msgs as rm

    pre = rm.encode_cloud(stamp_ns=stamp_ns, frame_id="cam", height=h, width=w, fields=rm.XYZRGBA_FIELDS,
                          point_step=16, row_step=(16 * w) & 0xFFFFFFFF, data=b"", is_dense=False)
    return pre[:-5] + struct.pack("<I", n_data & 0xFFFFFFFF), b"\x00"


def _stream(pieces, comp: str):
    """(compressed bytes, uncompressed size, crc32) of an iterable of byte pieces, streamed."""
    size = 0
    crc = 0
    if comp == "zstd":
        import zstandard

        c = zstandard.ZstdCompressor(level=3).compressobj()
        out = []
        for p in pieces:
            size += len(p)
            crc = zlib.crc32(p, crc)
            out.append(c.compress(p))
        out.append(c.flush())
    elif comp == "lz4":
        import lz4.frame

        c = lz4.frame.LZ4FrameCompressor(compression_level=3)
        out = [c.begin()]
        for p in pieces:
            size += len(p)
            crc = zlib.crc32(p, crc)
            out.append(c.compress(p))
        out.append(c.flush())
    else:
        raise ValueError(comp)
    return b"".join(out), size, crc


def _fill(n: int, point: bytes | None):
    """n bytes of zeros (invalid points) or of one point repeated, in 16 MiB pieces."""
    piece = bytes(16 << 20) if point is None else point * ((16 << 20) // len(point))
    while n > 0:
        k = min(n, len(piece))
        yield piece[:k]
        n -= k


def bomb_log(h: int, w: int, *, comp: str = "zstd", point: bytes | None = None, claim: int | None = None,
             per_message: bool = False, image: bool = False) -> bytes:
    """A small MCAP (no summary) whose one chunk holds an h x w cloud (and an rgb8 image): zstd or
    lz4 chunk compression, or rosbag2 per-message zstd in an uncompressed chunk. ``claim``: the
    chunk's uncompressed size says this instead of the truth."""
    import zstandard

    n = 16 * h * w
    pre, post = _cloud_prefix(h, w, n)
    head = _schema_channel("sensor_msgs/msg/PointCloud2", "/camera/points")
    if image:
        head += _schema_channel("sensor_msgs/msg/Image", "/camera/image", sid=2, cid=2)
    msg_head = struct.pack("<HIQQ", 1, 0, 10**9, 10**9)

    def message_pieces():
        yield pre
        yield from _fill(n, point)
        yield post

    if per_message:
        c = zstandard.ZstdCompressor(level=3, write_content_size=True).compressobj(size=len(pre) + n + len(post))
        data = b"".join(c.compress(p) for p in message_pieces()) + c.flush()
        inner = head + _rec(0x05, msg_head + data)
        body = struct.pack("<QQQI", 10**9, 10**9, len(inner), zlib.crc32(inner)) + _s(b"") + struct.pack("<Q", len(inner)) + inner
    else:
        def pieces():
            yield head
            total = len(pre) + n + len(post)
            yield struct.pack("<BQ", 0x05, len(msg_head) + total) + msg_head
            yield from message_pieces()
            if image:
                from replay.logs import ros2_msgs as rm

                ipre = rm.encode_image(stamp_ns=10**9, frame_id="cam", height=h, width=w, encoding="rgb8",
                                       step=3 * w, data=b"")
                ipre = ipre[:-4] + struct.pack("<I", 3 * h * w)
                mh = struct.pack("<HIQQ", 2, 0, 10**9, 10**9)
                yield struct.pack("<BQ", 0x05, len(mh) + len(ipre) + 3 * h * w) + mh + ipre
                yield from _fill(3 * h * w, None)

        data, size, crc = _stream(pieces(), comp)
        body = (struct.pack("<QQQI", 10**9, 10**9, size if claim is None else claim, crc) + _s(comp.encode())
                + struct.pack("<Q", len(data)) + data)
    out = b"\x89MCAP0\r\n" + _rec(0x01, _s(b"ros2") + _s(b"zcut fuzz bomb")) + _rec(0x06, body)
    out += _rec(0x0F, struct.pack("<I", 0)) + _rec(0x02, struct.pack("<QQI", 0, 0, 0)) + b"\x89MCAP0\r\n"
    return out


_POINT = struct.pack("<fffI", 0.01, 0.02, 0.5, 0xFF808080)
#: (description, bomb_log keyword arguments); the caps: 2**24 px, 256 MiB a message, +64 MiB a chunk
BOMBS = (
    ("zstd chunk: 4096x4095 invalid points (just under the caps)", dict(h=4096, w=4095)),
    ("zstd chunk: 5000x5000 invalid points (over the chunk cap)", dict(h=5000, w=5000)),
    ("zstd chunk: 2048x2048 invalid points + rgb8 image", dict(h=2048, w=2048, image=True)),
    ("zstd chunk: 1024x1024 identical points", dict(h=1024, w=1024, point=_POINT)),
    ("zstd chunk: 4096x4096 identical points (at the pixel cap)", dict(h=4096, w=4096, point=_POINT)),
    ("lz4 chunk: 2048x2048 invalid points", dict(h=2048, w=2048, comp="lz4")),
    ("zstd chunk claiming 2**40 bytes", dict(h=64, w=64, claim=2**40)),
    ("zstd chunk claiming 1 MiB, expanding to 64 MiB", dict(h=2048, w=2048, claim=1 << 20)),
    ("zstd chunk claiming 320 MiB + 1", dict(h=64, w=64, claim=(320 << 20) + 1)),
    ("per-message zstd: 4096x4095 invalid points", dict(h=4096, w=4095, per_message=True)),
    ("per-message zstd: 5000x5000 invalid points (over the message cap)", dict(h=5000, w=5000, per_message=True)),
    ("per-message zstd: 512x512 identical points", dict(h=512, w=512, per_message=True, point=_POINT)),
)


#: the bombs that a reader must refuse or read at once (over a cap, a lying size, moderate sizes)
CHEAP_BOMBS = (1, 5, 6, 7, 8, 10)


def bomb_case(corpus: Corpus, i: int, kind: str, cid: str, *, timeout_s: float | None = 120.0) -> Case:
    """The case of bomb ``BOMBS[i]`` read by the log command ``kind`` (see :func:`log_command`)."""
    what, kw = BOMBS[i]
    key = f"bomb{i}"
    if key not in corpus.cache:
        corpus.cache[key] = bomb_log(**kw)
    data = corpus.cache[key]
    return _log_case(cid, "mcap_bomb", f"{what} ({len(data)} bytes)", corpus, np.random.default_rng(0), "bomb.mcap",
                     data, 1, kind=kind, timeout_s=timeout_s)


def gen_mcap_bomb(rng: np.random.Generator, corpus: Corpus, cid: str) -> Case:
    i = int(rng.integers(len(BOMBS)))
    kind = _weighted(rng, ((3, "topics-check"), (4, "replay-json"), (1, "topics"), (1, "accuracy"), (1, "bin-model")))
    return bomb_case(corpus, i, kind, cid)


# ----------------------------------------------------------------------------------------------- CDR, raw
class Cdr:
    """An XCDR1 writer that writes what it is told: any u32 (wrapped), raw bytes for strings."""

    def __init__(self, *, big: bool = False) -> None:
        self.b = bytearray(b"\x00\x00\x00\x00" if big else b"\x00\x01\x00\x00")
        self.e = ">" if big else "<"

    def align(self, n: int) -> None:
        self.b += bytes((-(len(self.b) - 4)) % n)

    def u8(self, v: int) -> None:
        self.b += struct.pack("B", v & 0xFF)

    def u32(self, v: int) -> None:
        self.align(4)
        self.b += struct.pack(self.e + "I", v & 0xFFFFFFFF)

    def i32(self, v: int) -> None:
        self.align(4)
        self.b += struct.pack(self.e + "i", ((v + 2**31) % 2**32) - 2**31)

    def f64s(self, vals) -> None:
        if vals:
            self.align(8)
            self.b += struct.pack(f"{self.e}{len(vals)}d", *vals)

    def string(self, s: bytes, *, length: int | None = None) -> None:
        self.u32(len(s) + 1 if length is None else length)
        self.b += s + b"\x00"

    def blob(self, data: bytes, *, length: int | None = None) -> None:
        self.u32(len(data) if length is None else length)
        self.b += data


XYZRGBA = [(b"x", 0, 7, 1), (b"y", 4, 7, 1), (b"z", 8, 7, 1), (b"rgba", 12, 6, 1)]


def cloud_msg(*, h: int, w: int, data: bytes, sec: int = 1, nsec: int = 0, frame_id: bytes = b"cam",
              fields=XYZRGBA, be_flag: int = 0, point_step: int = 16, row_step: int | None = None,
              is_dense: int = 0, blob_len: int | None = None, frame_id_len: int | None = None,
              n_fields: int | None = None, big: bool = False, trailer: bytes = b"", cut: int | None = None) -> bytes:
    c = Cdr(big=big)
    c.i32(sec)
    c.u32(nsec)
    c.string(frame_id, length=frame_id_len)
    c.u32(h)
    c.u32(w)
    c.u32(len(fields) if n_fields is None else n_fields)
    for name, off, dt, cnt in fields:
        c.string(name)
        c.u32(off)
        c.u8(dt)
        c.u32(cnt)
    c.u8(be_flag)
    c.u32(point_step)
    c.u32(point_step * w if row_step is None else row_step)
    c.blob(data, length=blob_len)
    c.u8(is_dense)
    out = bytes(c.b) + trailer
    return out if cut is None else out[:cut]


def image_msg(*, h: int, w: int, data: bytes, encoding: bytes = b"rgb8", sec: int = 1, nsec: int = 0,
              frame_id: bytes = b"cam", be: int = 0, step: int | None = None, blob_len: int | None = None,
              trailer: bytes = b"", cut: int | None = None) -> bytes:
    c = Cdr()
    c.i32(sec)
    c.u32(nsec)
    c.string(frame_id)
    c.u32(h)
    c.u32(w)
    c.string(encoding)
    c.u8(be)
    c.u32(3 * w if step is None else step)
    c.blob(data, length=blob_len)
    out = bytes(c.b) + trailer
    return out if cut is None else out[:cut]


def camera_info_msg(*, h: int, w: int, k=None, sec: int = 1, nsec: int = 0, model: bytes = b"plumb_bob",
                    d=(0.0,) * 5, d_len: int | None = None, r=None, p=None, cut: int | None = None) -> bytes:
    k = list(k) if k is not None else [300.0, 0.0, w / 2, 0.0, 300.0, h / 2, 0.0, 0.0, 1.0]
    c = Cdr()
    c.i32(sec)
    c.u32(nsec)
    c.string(b"cam")
    c.u32(h)
    c.u32(w)
    c.string(model)
    c.u32(len(d) if d_len is None else d_len)
    c.f64s(list(d))
    c.f64s(k)
    c.f64s(list(r) if r is not None else [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0])
    c.f64s(list(p) if p is not None else [k[0], 0, k[2], 0, 0, k[4], k[5], 0, 0, 0, 1.0, 0])
    for _ in range(6):
        c.u32(0)
    c.u8(0)
    out = bytes(c.b)
    return out if cut is None else out[:cut]


_SPECIAL_F32 = np.array([np.nan, np.inf, -np.inf, 1e-45, -1e-45, 3.4e38, -3.4e38, 0.0, -0.0, 1e-38], np.float32)


def _xyz_variant(rng: np.random.Generator, h: int, w: int) -> tuple[np.ndarray, str]:
    """Coordinates of an h x w grid with hostile values."""
    xyz, _ = _scene(rng, h, w)
    kind = _pick(rng, ("nan", "zero", "inf", "special-mix", "denormal", "huge", "identical", "two-points",
                       "one-valid", "negative-z", "far", "duplicates", "plane-exact", "nan-z-only"))
    if kind == "nan":
        xyz[:] = np.nan
    elif kind == "zero":
        xyz[:] = 0
    elif kind == "inf":
        xyz[..., 2] = np.inf
    elif kind == "special-mix":
        xyz = rng.choice(_SPECIAL_F32, size=(h, w, 3))
    elif kind == "denormal":
        xyz = (rng.random((h, w, 3)) * 1e-40).astype(np.float32)
    elif kind == "huge":
        xyz = (rng.choice([-1, 1], (h, w, 3)) * 3e38).astype(np.float32)
    elif kind == "identical":
        xyz[:] = np.array([0.01, 0.02, 0.5], np.float32)
    elif kind == "two-points":
        xyz[:] = np.array([0.01, 0.02, 0.5], np.float32)
        xyz[::2] = np.array([0.0, 0.0, 0.6], np.float32)
    elif kind == "one-valid":
        xyz[:] = np.nan
        xyz[h // 2, w // 2] = (0.0, 0.0, 0.5)
    elif kind == "negative-z":
        xyz[..., 2] *= -1
    elif kind == "far":
        xyz *= 1e6
    elif kind == "duplicates":
        xyz = np.round(xyz, 1)
    elif kind == "plane-exact":
        xyz[..., 2] = 0.5
    else:
        xyz[..., 2] = np.nan
    return xyz.astype(np.float32), kind


def hostile_cloud(rng: np.random.Generator, h: int = H, w: int = W) -> tuple[bytes, str]:
    """A PointCloud2 with one family of hostile fields."""
    xyz, rgb = _scene(rng, h, w)
    data = cloud_bytes(xyz, rgb)
    fam = _pick(rng, ("dims", "steps", "fields", "endian", "values", "values", "values", "big-identical", "stamp",
                      "frame_id", "data", "tiny", "float64"))
    if fam == "dims":
        hh, ww = _pick(rng, ((0, 0), (0, w), (h, 0), (2**32 - 1, w), (h, 2**32 - 1), (2**31, 2**31), (1, h * w),
                             (h * w, 1), (w, h), (h + 1, w), (h, w - 1), (65536, 65536), (2, 1), (1, 1)))
        return cloud_msg(h=hh, w=ww, data=data, row_step=(16 * ww) & 0xFFFFFFFF), f"dims {hh}x{ww} (data for {h}x{w})"
    if fam == "steps":
        ps = _pick(rng, (16, 0, 1, 3, 4, 8, 11, 12, 15, 17, 2**31, 2**32 - 1))
        rs = _pick(rng, (None, 0, 1, 16 * w - 1, 16 * w + 1, 2**32 - 1, 32 * w))
        return cloud_msg(h=h, w=w, data=data, point_step=ps, row_step=rs), f"point_step {ps}, row_step {rs}"
    if fam == "fields":
        fields = [list(f) for f in XYZRGBA]
        what = _pick(rng, ("drop", "dup", "offset", "datatype", "count", "name", "empty", "many", "rgb"))
        i = int(rng.integers(4))
        if what == "drop":
            del fields[int(rng.integers(3))]
        elif what == "dup":
            fields.append([b"x", int(rng.integers(0, 16)), 7, 1])
        elif what == "offset":
            fields[i][1] = _pick(rng, (2**32 - 1, 2**31, 13, 14, 15, 16, 2**32 - 4))
        elif what == "datatype":
            fields[i][2] = _pick(rng, (0, 1, 2, 3, 4, 5, 6, 8, 9, 255))
        elif what == "count":
            fields[i][3] = _pick(rng, (0, 2, 2**32 - 1))
        elif what == "name":
            fields[i][0] = _pick(rng, (b"\xff\xfe", b"", b"x\x00y", b"X", b"n" * 65536))
        elif what == "empty":
            fields = []
        elif what == "many":
            fields += [[f"f{k}".encode(), 12, 6, 1] for k in range(5000)]
        else:
            fields[3] = [b"rgb", _pick(rng, (12, 13, 16, 2**32 - 1)), _pick(rng, (7, 8, 1, 6)), 1]
        return cloud_msg(h=h, w=w, data=data, fields=[tuple(f) for f in fields]), f"fields: {what} {i}"
    if fam == "endian":
        what = _pick(rng, ("flag", "cdr", "both"))
        if what == "flag":
            return cloud_msg(h=h, w=w, data=data, be_flag=_pick(rng, (1, 255))), "is_bigendian set on LE data"
        be = np.zeros((h, w, 4), ">f4")
        be[..., :3] = xyz
        return (cloud_msg(h=h, w=w, data=be.tobytes() if what == "both" else data, big=True,
                          be_flag=1 if what == "both" else 0), f"big-endian CDR ({what})")
    if fam in ("values", "big-identical"):
        if fam == "big-identical":
            h, w = _pick(rng, ((64, 64), (128, 128), (256, 256), (100, 300)))
            xyz = np.empty((h, w, 3), np.float32)
            xyz[:] = (0.01, 0.02, 0.5)
            if rng.random() < 0.5:
                xyz[rng.random((h, w)) < 0.5] = (0.0, 0.0, 0.6)
            kind = f"identical {h}x{w}"
        else:
            xyz, kind = _xyz_variant(rng, h, w)
        rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
        return cloud_msg(h=h, w=w, data=cloud_bytes(xyz, rgb), is_dense=int(rng.integers(2))), f"values: {kind}"
    if fam == "stamp":
        sec = _pick(rng, (2**31 - 1, -1, -(2**31), 0, 1))
        nsec = _pick(rng, (0, 999_999_999, 10**9, 2**32 - 1))
        return cloud_msg(h=h, w=w, data=data, sec=sec, nsec=nsec), f"stamp sec {sec} nanosec {nsec}"
    if fam == "frame_id":
        fid = _pick(rng, (b"\xff\xfe\xfd", b"", b"cam\n\x1b[31mred", b"f" * (1 << 20), b"caf\xc3"))
        lie = _pick(rng, (None, None, 2**31, 0))
        return cloud_msg(h=h, w=w, data=data, frame_id=fid, frame_id_len=lie), f"frame_id {fid[:12]!r} length {lie}"
    if fam == "data":
        what = _pick(rng, ("short1", "half", "empty", "long", "blob-lie", "trailer", "cut", "dense"))
        if what == "short1":
            return cloud_msg(h=h, w=w, data=data[:-1]), "data 1 byte short"
        if what == "half":
            return cloud_msg(h=h, w=w, data=data[: len(data) // 2]), "data half"
        if what == "empty":
            return cloud_msg(h=h, w=w, data=b""), "no data"
        if what == "long":
            return cloud_msg(h=h, w=w, data=data + bytes(1000)), "data 1000 bytes long"
        if what == "blob-lie":
            return cloud_msg(h=h, w=w, data=data, blob_len=_pick(rng, (len(data) + 1, 2**31, 2**32 - 1))), "data length lies"
        if what == "trailer":
            return cloud_msg(h=h, w=w, data=data, trailer=rng.bytes(int(rng.integers(1, 100)))), "garbage after"
        if what == "cut":
            full = cloud_msg(h=h, w=w, data=data)
            k = int(rng.integers(0, len(full)))
            return full[:k], f"message cut at {k}"
        return cloud_msg(h=h, w=w, data=data, is_dense=1), "is_dense with NaN"
    if fam == "tiny":
        hh, ww = _pick(rng, ((2, 1), (2, 2), (3, 1), (2, 3), (3, 3)))
        xyz, kind = _xyz_variant(rng, hh, ww)
        return cloud_msg(h=hh, w=ww, data=cloud_bytes(xyz, None)), f"tiny {hh}x{ww} {kind}"
    # float64 coordinates at point_step 32
    arr = np.zeros((h, w, 4), "<f8")
    arr[..., :3] = xyz
    vals = _pick(rng, (None, 1e300, -1e300, 5e-324, np.nan, 1e39))
    if vals is not None:
        arr[rng.random((h, w)) < 0.5, 2] = vals
    f64 = [(b"x", 0, 8, 1), (b"y", 8, 8, 1), (b"z", 16, 8, 1)]
    return cloud_msg(h=h, w=w, data=arr.tobytes(), fields=f64, point_step=32), f"float64 with {vals}"


def gen_cloud(rng: np.random.Generator, corpus: Corpus, cid: str) -> Case:
    msgs = frame_messages(rng, 3)
    k = int(rng.integers(3))
    bad, what = hostile_cloud(rng)
    clouds = [i for i, m in enumerate(msgs) if m[0] == "/camera/points"]
    every = rng.random() < 0.15  # every frame hostile (the first frame resolves the config)
    for j, i in enumerate(clouds):
        if j == k or every:
            t, ty, _, lt = msgs[i]
            msgs[i] = (t, ty, bad if j == k else hostile_cloud(rng)[0], lt)
    data = _mcap(msgs, compression=_pick(rng, ("zstd", "none", "lz4")))
    where = "every frame" if every else f"frame {k}"
    kind = _weighted(rng, ((3, "replay-json"), (2, "topics-check"), (1, "accuracy"), (1, "replay-out"),
                           (1, "bin-model"), (1, "topics")))
    return _log_case(cid, "cloud", f"{where}: {what}", corpus, rng, "cloud.mcap", data, 3, kind=kind)


def hostile_companion(rng: np.random.Generator, h: int = H, w: int = W) -> tuple[str, bytes, str]:
    """(topic, message, what) of a hostile Image, CameraInfo or mask for an h x w frame stamped 1.0 s."""
    which = _pick(rng, ("image", "image", "info", "mask"))
    rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    if which == "image":
        what = _pick(rng, ("dims", "encoding", "step", "data", "endian", "stamp", "cut"))
        if what == "dims":
            hh, ww = _pick(rng, ((h + 1, w), (h, w + 1), (0, 0), (2**32 - 1, w), (w, h), (h, 2**31)))
            return "/camera/image", image_msg(h=hh, w=ww, data=rgb.tobytes(), step=3 * ww & 0xFFFFFFFF), f"image {hh}x{ww}"
        if what == "encoding":
            enc = _pick(rng, (b"", b"rgb8 ", b"RGB8", b"16UC1", b"mono16", b"bayer_rggb8", b"yuv422", b"\xff\xfe",
                              b"rgb8\x00x", b"32FC1", b"e" * 65536, b"mono8", b"rgba8", b"bgra8"))
            return "/camera/image", image_msg(h=h, w=w, data=rgb.tobytes(), encoding=enc), f"image encoding {enc[:16]!r}"
        if what == "step":
            st = _pick(rng, (0, 1, 3 * w - 1, 2**32 - 1, 3 * w + 1, 6 * w))
            return "/camera/image", image_msg(h=h, w=w, data=rgb.tobytes(), step=st), f"image step {st}"
        if what == "data":
            d = _pick(rng, (rgb.tobytes()[:-1], b"", rgb.tobytes() + bytes(99)))
            return "/camera/image", image_msg(h=h, w=w, data=d), f"image data of {len(d)} bytes"
        if what == "endian":
            return "/camera/image", image_msg(h=h, w=w, data=rgb.tobytes(), be=_pick(rng, (1, 255))), "image is_bigendian"
        if what == "stamp":
            sec = _pick(rng, (2, 1000, -1, 2**31 - 1))
            return "/camera/image", image_msg(h=h, w=w, data=rgb.tobytes(), sec=sec), f"image stamp sec {sec}"
        full = image_msg(h=h, w=w, data=rgb.tobytes())
        k = int(rng.integers(0, len(full)))
        return "/camera/image", full[:k], f"image cut at {k}"
    if which == "info":
        what = _pick(rng, ("k", "dims", "d", "model", "cut", "stamp"))
        if what == "k":
            v = _pick(rng, (np.nan, np.inf, 0.0, -300.0, 1e308, 1e-308, -np.inf))
            k = [300.0, 0.0, w / 2, 0.0, 300.0, h / 2, 0.0, 0.0, 1.0]
            for i in rng.choice([0, 2, 4, 5], int(rng.integers(1, 5)), replace=False):
                k[int(i)] = v
            return "/camera/camera_info", camera_info_msg(h=h, w=w, k=k), f"camera K with {v}"
        if what == "dims":
            hh, ww = _pick(rng, ((0, 0), (h + 1, w), (2**32 - 1, 2**32 - 1), (w, h)))
            return "/camera/camera_info", camera_info_msg(h=hh, w=ww), f"camera info {hh}x{ww}"
        if what == "d":
            n = _pick(rng, (2**30, 2**32 - 1, 1000))
            return "/camera/camera_info", camera_info_msg(h=h, w=w, d_len=n), f"camera info claims {n} coefficients"
        if what == "model":
            m = _pick(rng, (b"\xff\xfe", b"", b"m" * 100000))
            return "/camera/camera_info", camera_info_msg(h=h, w=w, model=m), f"distortion model {m[:8]!r}"
        if what == "stamp":
            return "/camera/camera_info", camera_info_msg(h=h, w=w, sec=-1, nsec=2**32 - 1), "camera info stamp"
        full = camera_info_msg(h=h, w=w)
        k = int(rng.integers(0, len(full)))
        return "/camera/camera_info", full[:k], f"camera info cut at {k}"
    m = (rng.random((h, w)) < 0.2).astype(np.uint8) * 255
    what = _pick(rng, ("dims", "encoding", "step", "data", "all", "stamp"))
    if what == "dims":
        hh, ww = _pick(rng, ((h + 1, w), (h, w - 1), (0, 0), (1, 1)))
        return "/ground_truth/outliers", image_msg(h=hh, w=ww, data=bytes(hh * ww), encoding=b"mono8", step=ww), f"mask {hh}x{ww}"
    if what == "encoding":
        enc = _pick(rng, (b"rgb8", b"16UC1", b"mono16", b""))
        return "/ground_truth/outliers", image_msg(h=h, w=w, data=m.tobytes(), encoding=enc, step=w), f"mask encoding {enc!r}"
    if what == "step":
        st = _pick(rng, (0, w - 1, 2**32 - 1))
        return "/ground_truth/outliers", image_msg(h=h, w=w, data=m.tobytes(), encoding=b"mono8", step=st), f"mask step {st}"
    if what == "data":
        return "/ground_truth/outliers", image_msg(h=h, w=w, data=m.tobytes()[:-3], encoding=b"mono8", step=w), "mask short"
    if what == "all":
        return "/ground_truth/outliers", image_msg(h=h, w=w, data=b"\xff" * (h * w), encoding=b"mono8", step=w), "mask all set"
    return "/ground_truth/outliers", image_msg(h=h, w=w, data=m.tobytes(), encoding=b"mono8", step=w, sec=77), "mask unpaired"


def gen_image(rng: np.random.Generator, corpus: Corpus, cid: str) -> Case:
    msgs = frame_messages(rng, 3)
    k = int(rng.integers(3))
    stamp = 10**9 + k * 100_000_000
    topic, bad, what = hostile_companion(rng)
    # restamp: hostile messages are written for stamp 1.0 s; frame k's stamp unless the stamp is the point
    if "stamp" not in what and "unpaired" not in what and "cut" not in what:
        sec, nsec = divmod(stamp, 10**9)
        bad = bad[:4] + struct.pack("<iI", sec, nsec) + bad[12:]
    mode = _pick(rng, ("replace", "replace", "extra", "every"))
    out = []
    for t, ty, d, lt in msgs:
        if t == topic and (mode == "every" or (mode == "replace" and lt == stamp)):
            d = bad
        out.append((t, ty, d, lt))
        if mode == "extra" and t == topic and lt == stamp:
            out.append((t, ty, bad, lt))
    data = _mcap(out, compression=_pick(rng, ("zstd", "none")))
    kind = _weighted(rng, ((3, "replay-json"), (2, "topics-check"), (2, "accuracy"), (1, "replay-out"), (1, "topics")))
    return _log_case(cid, "image", f"{mode} frame {k}: {what}", corpus, rng, "image.mcap", data, 3, kind=kind)


# ----------------------------------------------------------------------------------------------- PCD / PLY
_HUGE_INTS = ("0", "-1", "1", "2147483648", "4294967296", "1000000000000", "99999999999999999999999", "abc", "1e3",
              "", "0x10", "-0", "3.5", "nan")


def _split_header(raw: bytes, end_marker: bytes) -> tuple[list[bytes], bytes]:
    at = raw.find(end_marker)
    nl = raw.find(b"\n", at)
    return raw[:nl + 1].split(b"\n")[:-1], raw[nl + 1:]


def mutate_pcd(rng: np.random.Generator, raw: bytes) -> tuple[bytes, str]:
    lines, body = _split_header(raw, b"\nDATA ")
    keys = [ln.split(b" ")[0].decode() for ln in lines]
    kind = _pick(rng, ("value", "value", "value", "line", "body", "body", "compressed", "whole"))
    if kind == "value":
        key = _pick(rng, ("WIDTH", "HEIGHT", "POINTS", "SIZE", "TYPE", "COUNT", "FIELDS", "DATA", "VIEWPOINT", "VERSION"))
        i = keys.index(key) if key in keys else None
        if key in ("WIDTH", "HEIGHT", "POINTS"):
            v = _pick(rng, _HUGE_INTS)
            both = rng.random() < 0.3 and key != "POINTS"
            new = f"{key} {v}".encode()
            if both:  # a consistent lie: POINTS follows
                w = int(lines[keys.index("WIDTH")].split()[1])
                hh = int(lines[keys.index("HEIGHT")].split()[1])
                try:
                    n = int(v) * (hh if key == "WIDTH" else w)
                    lines[keys.index("POINTS")] = f"POINTS {n}".encode()
                except ValueError:
                    pass
        elif key == "SIZE":
            new = b"SIZE " + b" ".join(_pick(rng, (b"4", b"3", b"0", b"8", b"16", b"-4", b"1")) for _ in range(4))
        elif key == "TYPE":
            new = b"TYPE " + b" ".join(_pick(rng, (b"F", b"U", b"I", b"X", b"f", b"")) for _ in range(4))
        elif key == "COUNT":
            new = b"COUNT " + b" ".join(_pick(rng, (b"1", b"0", b"2", b"4294967296", b"-1")) for _ in range(4))
        elif key == "FIELDS":
            new = _pick(rng, (b"FIELDS x y", b"FIELDS x x x rgb", b"FIELDS a b c d", b"FIELDS", b"FIELDS x y z rgb extra",
                              b"FIELDS \xff\xfe y z rgb", b"FIELDS z y x rgb"))
        elif key == "DATA":
            new = _pick(rng, (b"DATA binary", b"DATA ascii", b"DATA binary_compressed", b"DATA zip", b"DATA", b"DATA BINARY"))
        elif key == "VIEWPOINT":
            new = _pick(rng, (b"VIEWPOINT nan nan nan nan nan nan nan", b"VIEWPOINT 1", b"VIEWPOINT a b c d e f g"))
        else:
            new = _pick(rng, (b"VERSION 9.9", b"VERSION", b"VERSION .7"))
        if i is None:
            lines.insert(-1, new)
        else:
            lines[i] = new
        what = f"header {new[:50]!r}"
    elif kind == "line":
        op = _pick(rng, ("drop", "dup", "garbage", "crlf", "nonascii", "long-comment"))
        i = int(rng.integers(len(lines)))
        if op == "drop":
            del lines[i]
        elif op == "dup":
            lines.insert(i, lines[i])
        elif op == "garbage":
            lines.insert(i, rng.bytes(20).replace(b"\n", b" "))
        elif op == "crlf":
            lines = [ln + b"\r" for ln in lines]
        elif op == "nonascii":
            lines.insert(i, b"# caf\xe9 \xff")
        else:
            lines.insert(1, b"#" + b"c" * 70000)
        what = f"header line: {op} {i}"
    elif kind == "body":
        b, w = mutate_bytes(rng, body)
        body = b
        what = f"body: {w}"
    elif kind == "compressed":
        if b"binary_compressed" in lines[-1] and len(body) >= 8:
            cs, us = struct.unpack_from("<II", body)
            which = _pick(rng, ("csize", "usize", "lzf"))
            v = _pick(rng, (0, 1, cs - 1, cs + 1, us - 1, us + 1, 2**31, 2**32 - 1))
            b = bytearray(body)
            if which == "csize":
                struct.pack_into("<I", b, 0, max(v, 0))
            elif which == "usize":
                struct.pack_into("<I", b, 4, max(v, 0))
            else:
                for p in rng.integers(8, len(b), 4):
                    b[int(p)] ^= 0xFF
                v = "flipped"
            body = bytes(b)
            what = f"binary_compressed {which} -> {v}"
        else:
            body = body.replace(b"\n", b" ", int(rng.integers(1, 5)))
            what = "ascii rows joined"
    else:
        out = _pick(rng, (b"", b"DATA ascii\n", rng.bytes(200), b"VERSION 0.7\n" * 3, b"# only a comment\n",
                          b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 4\nHEIGHT 2\nPOINTS 8\nDATA ascii\n"
                          + b"nan inf -inf\n1e999 -1e999 abc\n" * 4))
        return out, f"whole file {out[:24]!r}"
    return b"\n".join(lines) + b"\n" + body, what


def mutate_ply(rng: np.random.Generator, raw: bytes) -> tuple[bytes, str]:
    lines, body = _split_header(raw, b"end_header")
    kind = _pick(rng, ("count", "count", "org", "property", "camera", "grid", "format", "header", "body", "whole"))
    idx = {ln.split(b" ")[1].decode(): i for i, ln in enumerate(lines) if ln.startswith(b"element ")}
    if kind == "count" and "vertex" in idx:
        v = _pick(rng, ("8589934592", "0", "1", "47", "49", "-1", "abc", "4294967295", "99999999999", "1e9"))
        lines[idx["vertex"]] = b"element vertex " + v.encode()
        what = f"element vertex {v}"
    elif kind == "org":
        v = _pick(rng, ("0", "1", "2147483647", "1000000000000", "96", "3", "x"))
        which = _pick(rng, ("rows", "cols"))
        i = next((i for i, ln in enumerate(lines) if f"num_{which}".encode() in ln), None)
        if i is None:
            lines.insert(2, f"obj_info num_{which} {v}".encode())
        else:
            lines[i] = lines[i].rsplit(b" ", 1)[0] + b" " + v.encode()
        what = f"num_{which} {v}"
    elif kind == "property":
        i = next(i for i, ln in enumerate(lines) if ln.startswith(b"property"))
        new = _pick(rng, (b"property float128 x", b"property half x", b"property list uchar float x",
                          b"property char x", b"property double x", b"property float", b"property float y"))
        lines[i] = new
        what = f"vertex property {new!r}"
    elif kind == "camera":
        v = _pick(rng, ("inf", "nan", "-1", "0", "1e308", "2147483648", "1e9", "-inf"))
        at = idx.get("camera")
        head = b"element camera 1\nproperty float viewportx\nproperty float viewporty\n"
        if at is None:  # add a camera element after the vertices (ascii and binary alike)
            end = max(i for i, ln in enumerate(lines) if ln.startswith(b"property")) + 1
            if "range_grid" in idx:
                end = idx["range_grid"]
            lines[end:end] = head.strip().split(b"\n")
        fmt = lines[1].split(b" ")[1]
        vals = [float(v), float(_pick(rng, ("8", "6", v)))]
        if fmt == b"ascii":
            extra = (" ".join(repr(x) for x in vals) + "\n").encode()
        else:
            with np.errstate(over="ignore"):  # 1e300 as float32 is inf, on purpose
                extra = np.array(vals, dtype=("<" if fmt == b"binary_little_endian" else ">") + "f4").tobytes()
        if at is None and "range_grid" not in idx:
            body = body + extra
        elif at is not None and fmt != b"ascii":
            body = body[: len(body) - len(extra)] + extra
        elif at is not None:
            body = b"\n".join(body.rstrip(b"\n").split(b"\n")[:-1] + [extra.rstrip(b"\n")]) + b"\n"
        what = f"camera viewport {vals}"
    elif kind == "grid" and "range_grid" in idx:
        v = _pick(rng, ("0", "1", "47", "49", "8589934592", "-1"))
        lines[idx["range_grid"]] = b"element range_grid " + v.encode()
        what = f"range_grid {v}"
    elif kind == "format":
        new = _pick(rng, (b"format binary_middle_endian 1.0", b"format ascii 2.0", b"format", b"format ascii",
                          b"format binary_little_endian 1.0", b"format binary_big_endian 1.0"))
        lines[1] = new
        what = f"{new!r}"
    elif kind == "header":
        op = _pick(rng, ("no-end", "long", "nonascii", "face-first", "dup-element"))
        if op == "no-end":
            return b"\n".join(lines[:-1]) + b"\n" + body, "no end_header"
        if op == "long":
            lines.insert(2, b"comment " + b"c" * 70000)
        elif op == "nonascii":
            lines.insert(2, b"comment caf\xe9 \xff\xfe")
        elif op == "face-first":
            lines[2:2] = [b"element face 3", b"property list uchar int vertex_indices"]
        else:
            lines.insert(len(lines) - 1, b"element vertex 3")
        what = f"header: {op}"
    elif kind == "body":
        body, w = mutate_bytes(rng, body)
        what = f"body: {w}"
    else:
        out = _pick(rng, (b"", b"ply\n", b"ply\nformat ascii 1.0\nend_header\n", rng.bytes(300),
                          b"ply\nformat ascii 1.0\nelement vertex 8\nproperty float x\nproperty float y\nproperty float z\n"
                          b"obj_info num_rows 2\nobj_info num_cols 4\nend_header\n" + b"nan inf -inf\n1e999 x 2\n" * 4))
        return out, f"whole file {out[:24]!r}"
    return b"\n".join(lines) + b"\n" + body, what


def _record_options(rng: np.random.Generator) -> list[str]:
    opts: list[str] = []
    if rng.random() < 0.3:
        opts += ["--unit", _pick(rng, ("auto", "m", "mm"))]
    if rng.random() < 0.15:
        opts += ["--period", _pick(rng, ("1", "0.001", "1e308", "1e-9"))]
    if rng.random() < 0.15:
        opts += ["--stamp-start", _pick(rng, ("0", "1700000000", "2147483647.9", "2147483648", "1e18"))]
    return opts


def gen_pcd(rng: np.random.Generator, corpus: Corpus, cid: str) -> Case:
    seed = _pick(rng, ("c_ascii.pcd", "c_binary.pcd", "c_binary_compressed.pcd", "c_nocolor.pcd"))
    data, what = mutate_pcd(rng, corpus[seed])
    files = {"cloud.pcd": data}
    argv = ["record", "cloud.pcd", "-o", "out.mcap", *_record_options(rng)]
    extra = _pick(rng, ("", "", "", "png", "png-bad", "png-small", "png-huge", "two", "folder"))
    if extra == "png":
        files["cloud.png"] = corpus["c_binary.png"]
    elif extra == "png-bad":
        files["cloud.png"] = rng.bytes(100)
    elif extra == "png-small":
        files["cloud.png"] = png_bytes(np.zeros((3, 5, 3), np.uint8))
    elif extra == "png-huge":
        files["cloud.png"] = huge_png()
    elif extra == "two":
        files["good.pcd"] = corpus["c_binary.pcd"]
        argv[1:2] = ["good.pcd", "cloud.pcd"] if rng.random() < 0.5 else ["cloud.pcd", "good.pcd"]
    elif extra == "folder":
        files = {f"in/{k}": v for k, v in files.items()}
        argv[1] = "in"
    return Case(cid, "pcd", f"{seed}: {what}" + (f" + {extra}" if extra else ""), argv, files=files)


def huge_png() -> bytes:
    """A PNG whose header claims 100000 x 100000 pixels (30 GB decoded); the data is tiny."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 100000, 100000, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(bytes(100001) * 4)) + chunk(b"IEND", b""))


PLY_SEEDS = ("c_ascii.ply", "c_binary_little_endian.ply", "c_binary_big_endian.ply", "g_ascii.ply",
             "g_binary_little_endian.ply", "g_binary_big_endian.ply", "c_camera.ply", "c_comment.ply", "c_noorg.ply")


def gen_ply(rng: np.random.Generator, corpus: Corpus, cid: str) -> Case:
    seed = _pick(rng, PLY_SEEDS)
    data, what = mutate_ply(rng, corpus[seed])
    use = _weighted(rng, ((6, "record"), (1, "bin-model"), (1, "replay-bin")))
    files = {"cloud.ply": data}
    if use == "record":
        argv = ["record", "cloud.ply", "-o", "out.mcap", *_record_options(rng)]
        if seed == "c_noorg.ply" or rng.random() < 0.2:
            argv += ["--shape", _pick(rng, ("6x8", "8x6", "2x24", "1x48", "0x0", "99999x99999", "6x8x1", "axb", "-6x-8"))]
    elif use == "bin-model":
        argv = ["bin-model", "--model", "cloud.ply", "-o", "model_out.ply"]
    else:
        files["synth.mcap"] = corpus["synth.mcap"]
        argv = ["replay", "synth.mcap", "--bin-model", "cloud.ply", "--json"]
    return Case(cid, "ply", f"{seed}: {what} | {use}", argv, files=files, timeout_s=60.0)


# ----------------------------------------------------------------------------------------------- command lines
NUMBERS = ("-1", "0", "-0", "1e308", "-1e308", "1e309", "nan", "NaN", "inf", "-inf", "1e-320", "4.9e-324",
           "2147483648", "9223372036854775808", "1e18", "0x10", "", " ", "1_0", "abc", "1,5", "\u0661\u0662",
           "+5", "3.0e", "--1", "0.2", "30", "1e-9")
INTS = ("-1", "0", "1", "2", "3", "2147483648", "99999999999999999999", "1e3", "", "abc", "0x10", "-99999999999")
FRAMES = ("0", "1", "-1", "3:2", "a:b", "99999999999999999999", "0:0", ":", "1e3", "0:1", "1:", ":2", "2:99",
          "0:18446744073709551616", " 1 : 2 ", "1:2:3")
SIZES = ("8x8", "7x7", "0x0", "-8x8", "8x", "axb", "8192x8193", "1e3x8", "16x12", "8x8x8", "x", "99999999999x8")
URLS = ("not a url", "http://", "rerun+http://127.0.0.1:1/proxy", "rerun+http://[::1", "127.0.0.1:9876",
        "rerun+http://127.0.0.1:99999/proxy", "rerun+http://localhost:abc/proxy", "file:///etc/passwd", "",
        "rerun+https://127.0.0.1:1/proxy", "rerun+http://0.0.0.0:0/proxy")
TOPICS = ("", "/nope", "/camera/image", "/camera/camera_info", "/ground_truth/outliers", "camera/points", "/" * 1000,
          "/camera/points\n", "\udcff")
NAMES = ("", " ", "alice", "bob", "\x1b[31mred", "a" * 10000, "\udcff\udcfe", "../../x", "Alice ")


def _opt(rng, name: str, pool) -> list[str]:
    v = _pick(rng, pool)
    return [f"{name}={v}"] if rng.random() < 0.2 else [name, v]


def gen_cli(rng: np.random.Generator, corpus: Corpus, cid: str) -> Case:
    cmd = _weighted(rng, ((5, "replay"), (2, "record"), (2, "synth"), (2, "topics"), (2, "accuracy"),
                          (2, "bin-model"), (1, "labels"), (1, "top")))
    files: dict[str, bytes] = {}
    n_opts = int(rng.integers(1, 4))
    argv: list[str]
    if cmd == "replay":
        files["synth.mcap"] = corpus["synth.mcap"]
        argv = ["replay", "synth.mcap", "--json"]
        table = [("--step", NUMBERS), ("--max-depth", NUMBERS), ("--max-area", NUMBERS), ("--rho", NUMBERS),
                 ("--frames", FRAMES), ("--part", ("spheres", "rods", "nope", "")),
                 ("--parameters", ("nominal", "geometry", "x")), ("--preset", ("rods", "sprockets", "zz")),
                 ("--topic", TOPICS), ("--connect", URLS)]
    elif cmd == "record":
        files["c.pcd"] = corpus["c_binary.pcd"]
        files["c.ply"] = corpus["c_noorg.ply"]
        argv = ["record", _pick(rng, ("c.pcd", "c.ply")), "-o", "out.mcap"]
        table = [("--stamp-start", NUMBERS + ("2147483647.999999999", "2147483648", "1e10")),
                 ("--period", NUMBERS + ("1e308", "1e-308")), ("--shape", SIZES + ("6x8", "8x6", "48x1", "2x24")),
                 ("--unit", ("m", "mm", "auto", "km")), ("--frame-id", NAMES)]
    elif cmd == "synth":
        argv = ["synth", "-o", "out.mcap", "--size", _pick(rng, ("8x8", "16x12", "24x16")), "--frames", "1"]
        table = [("--frames", ("-1", "0", "abc", "", "1e3", "2")), ("--size", SIZES), ("--seed", INTS),
                 ("--parts", ("rods", "nope", "", "spheres")), ("--shiny", None), ("--matte", None), ("--empty", None)]
    elif cmd == "topics":
        files["w3.mcap"] = corpus["w3.mcap"]
        argv = ["topics", "w3.mcap"]
        table = [("--topic", TOPICS), ("--image-topic", TOPICS), ("--check", None)]
    elif cmd == "accuracy":
        files["synth.mcap"] = corpus["synth.mcap"]
        files["labels.sqlite"] = corpus["labels.sqlite"]
        argv = ["accuracy", "synth.mcap"]
        table = [("--labels", ("labels.sqlite", "synth.mcap", "nope.sqlite", "")), ("--annotator", NAMES),
                 ("--agreement", None), ("--json", None), ("--step", NUMBERS), ("--topic", TOPICS)]
    elif cmd == "bin-model":
        files["empty.mcap"] = corpus["empty.mcap"]
        files["bin.ply"] = corpus["bin.ply"]
        argv = ["bin-model", "empty.mcap", "-o", "model_out.ply"]
        if rng.random() < 0.5:
            argv = ["bin-model", "--model", "bin.ply", "-o", "model_out.ply"]
        table = [("--voxel", NUMBERS), ("--scale", NUMBERS), ("--frames", FRAMES), ("--topic", TOPICS),
                 ("--z-up", None), ("--model", ("bin.ply", "empty.mcap", "nope.ply"))]
    elif cmd == "labels":
        files["synth.mcap"] = corpus["synth.mcap"]
        files["labels.sqlite"] = corpus["labels.sqlite"]
        files["labels.mcap"] = corpus["labels.mcap"]
        argv = _pick(rng, (["labels", "export", "synth.mcap", "--db", "labels.sqlite", "-o", "out.mcap"],
                           ["labels", "import", "labels.mcap", "--db", "labels.sqlite"],
                           ["labels", "list", "synth.mcap", "--db", "labels.sqlite"]))
        table = [("--annotator", NAMES), ("--db", ("labels.sqlite", "synth.mcap", "nope.sqlite"))]
    else:
        argv = []
        table = [("--version", None), ("--help", None), ("nope", None), ("-x", None), ("replay", None),
                 ("--", None), ("labels", None)]
    for _ in range(n_opts):
        name, pool = _pick(rng, table)
        if name == "--agreement":
            argv += ["--agreement", _pick(rng, NAMES), _pick(rng, NAMES)]
        elif pool is None:
            argv.append(name)
        else:
            argv += _opt(rng, name, pool)
    if rng.random() < 0.1:
        argv.insert(int(rng.integers(0, len(argv) + 1)), _pick(rng, ("--nope", "-z", "--json", "--step", "extra.mcap",
                                                                      "--frames=", "-o")))
    mutable = {"labels.sqlite"} if argv[:2] == ["labels", "import"] else set()
    return Case(cid, "cli", f"{cmd}: {' '.join(argv)[:120]}", argv, files=files, mutable=mutable, timeout_s=60.0)


# ----------------------------------------------------------------------------------------------- paths
#: hostile things a path on the command line can name: (kind, the path, special entries to create)
def _hostile_path(rng: np.random.Generator, base: str) -> tuple[str, list, dict, str]:
    kind = _pick(rng, ("missing", "dir", "fifo", "devzero", "devnull", "loop", "dangling", "long-name", "long-path",
                       "non-utf8", "newline", "dash", "dot", "empty", "socket-like", "under-file"))
    special: list = []
    files: dict[str, bytes] = {}
    if kind == "missing":
        return "nope/" + base, special, files, kind
    if kind == "dir":
        special.append(("dir", "adir", ""))
        return "adir", special, files, kind
    if kind == "fifo":
        special.append(("fifo", "pipe" + Path(base).suffix, ""))
        return "pipe" + Path(base).suffix, special, files, kind
    if kind == "devzero":
        return "/dev/zero", special, files, kind
    if kind == "devnull":
        return "/dev/null", special, files, kind
    if kind == "loop":
        special.append(("symlink", "loop" + Path(base).suffix, "loop" + Path(base).suffix))
        return "loop" + Path(base).suffix, special, files, kind
    if kind == "dangling":
        special.append(("symlink", "dangling" + Path(base).suffix, "nowhere/x"))
        return "dangling" + Path(base).suffix, special, files, kind
    if kind == "long-name":
        return "n" * 300 + Path(base).suffix, special, files, kind
    if kind == "long-path":
        return "/".join(["d" * 200] * 30) + "/" + base, special, files, kind
    if kind == "non-utf8":
        name = os.fsdecode(b"\xff\xfe" + base.encode())
        return name, special, files, kind
    if kind == "newline":
        return "new\nline" + Path(base).suffix, special, files, kind
    if kind == "dash":
        return "-" + base, special, files, kind
    if kind == "dot":
        return _pick(rng, (".", "..", "./", "/")), special, files, kind
    if kind == "empty":
        return "", special, files, kind
    if kind == "socket-like":
        return "/proc/self/fd/0", special, files, kind
    files["afile"] = b"a regular file\n"
    return "afile/" + base, special, files, kind


#: commands with (argv template, input slots, output slots); {i}/{o} are filled with paths
PATH_COMMANDS = (
    (["topics", "{log}"], ["log"], []),
    (["topics", "--check", "{log}"], ["log"], []),
    (["replay", "{log}", "--json"], ["log"], []),
    (["replay", "{log}", "--out", "{out}"], ["log"], ["out"]),
    (["replay", "{log}", "--rrd", "{rrd}"], ["log"], ["rrd"]),
    (["replay", "{log}", "--out", "{out}", "--rrd", "{rrd}"], ["log"], ["out", "rrd"]),
    (["replay", "{log}", "--config", "{cfg}", "--json"], ["log", "cfg"], []),
    (["replay", "{log}", "--bin-model", "{ply}", "--json"], ["log", "ply"], []),
    (["accuracy", "{log}", "--labels", "{db}"], ["log", "db"], []),
    (["record", "{pcd}", "-o", "{out}"], ["pcd"], ["out"]),
    (["synth", "-o", "{out}", "--size", "8x8"], [], ["out"]),
    (["bin-model", "{empty}", "-o", "{model}"], ["empty"], ["model"]),
    (["bin-model", "--model", "{ply}", "-o", "{model}"], ["ply"], ["model"]),
    (["labels", "export", "{log}", "--db", "{db}", "-o", "{out}"], ["log", "db"], ["out"]),
    (["labels", "import", "{lab}", "--db", "{db}"], ["lab", "db"], []),
    (["labels", "list", "{log}", "--db", "{db}"], ["log", "db"], []),
)
_SLOT_FILES = {"log": ("synth.mcap", "synth.mcap"), "cfg": ("good.toml", "good.toml"), "ply": ("bin.ply", "bin.ply"),
               "db": ("labels.sqlite", "labels.sqlite"), "pcd": ("c.pcd", "c_binary.pcd"),
               "empty": ("empty.mcap", "empty.mcap"), "lab": ("labels.mcap", "labels.mcap")}
_OUT_NAMES = {"out": "out.mcap", "rrd": "out.rrd", "model": "model_out.ply"}


def gen_paths(rng: np.random.Generator, corpus: Corpus, cid: str) -> Case:
    template, ins, outs = _pick(rng, PATH_COMMANDS)
    files: dict[str, bytes] = {}
    special: list = []
    mutable: set[str] = set()
    values: dict[str, str] = {}
    for slot in ins:
        name, src = _SLOT_FILES[slot]
        files[name] = corpus[src]
        values[slot] = name
    for slot in outs:
        values[slot] = _OUT_NAMES[slot]
    force = rng.random() < 0.3
    target = _pick(rng, ins + outs) if (ins or outs) else None
    what = ""
    if target in outs and ins and rng.random() < 0.6:
        # an output that is an input, or collides with what is written beside an output
        src = values[_pick(rng, ins)]
        how = _pick(rng, ("same", "dot-slash", "absolute", "hardlink", "symlink", "config-beside", "partial",
                          "existing", "under-input"))
        if how == "same":
            values[target] = src
        elif how == "dot-slash":
            values[target] = "./" + src
        elif how == "absolute":
            values[target] = "{CASE}/" + src
        elif how == "hardlink":
            special.append(("hardlink", "link_" + src, src))
            values[target] = "link_" + src
        elif how == "symlink":
            special.append(("symlink", "sym_" + src, src))
            values[target] = "sym_" + src
        elif how == "config-beside":  # OUT.config.toml is the --config input
            files["x.config.toml"] = corpus["good.toml"]
            values[target] = "x" + Path(_OUT_NAMES[target]).suffix
            if template[0] == "replay" and "{cfg}" not in template:
                template = [*template, "--config", "x.config.toml"]
        elif how == "partial":  # a user's own file named like a temporary output
            files[_OUT_NAMES[target] + ".partial"] = b"the user's own file\n"
        elif how == "existing":
            files[_OUT_NAMES[target]] = b"an existing output\n"
            if force:
                mutable.add(_OUT_NAMES[target])
        else:
            values[target] = src + "/" + _OUT_NAMES[target]
        what = f"output {target} {how} ({values[target]})"
    elif target is not None:
        base = values[target]
        path, sp, fl, kind = _hostile_path(rng, base)
        special += sp
        files.update(fl)
        values[target] = path
        if target in ins and kind in ("non-utf8", "newline", "dash"):  # the input exists under that name
            files[path] = files.pop(base)
        what = f"{'input' if target in ins else 'output'} {target} is {kind}"
    argv = [a.format(**values) if "{" in a else a for a in template]
    if template[0] == "replay" and len(outs) == 2 and rng.random() < 0.3:
        argv[argv.index("--rrd") + 1] = Path(argv[argv.index("--out") + 1]).with_suffix(".rrd").name
        what += "; --rrd beside --out (one config file for both)"
    if force and template[0] in ("replay", "record", "bin-model", "synth") or (force and template[:2] == ["labels", "export"]):
        argv.append("--force")
    if template[:2] == ["labels", "import"]:  # the store is what import writes to, under its name of the case
        mutable.add(values["db"])
    return Case(cid, "paths", what or "plain", argv, files=files, special=special, mutable=mutable, timeout_s=60.0)


# ----------------------------------------------------------------------------------------------- --config
_CONFIG_KEYS = {
    "zcut": ("step_mm", "max_depth_mm", "max_area_px", "a_max_px", "rho_thr", "connectivity"),
    "sor": ("enabled", "k", "std_ratio", "convention", "region"),
    "bin_mask": ("enabled", "threshold", "dilate_px", "min_area_frac"),
    "registration": ("method", "voxel_mm", "max_correspondence_mm", "max_iterations", "min_fitness", "max_rmse_mm",
                     "use_previous"),
    "removal": ("delta_mm", "rim_offset_mm", "straggler_mm", "straggler_neighbours"),
}
_TOML_VALUES = ("nan", "inf", "-inf", "0", "-1", "1e308", "-1e308", "1e-308", "5e-324", '"0.2"', "true", "[]", "{}",
                "18446744073709551616", "1" + "0" * 400, "2147483648", "0.5", "8", "4", '"pcl"', '"open3d"', '"x"',
                "1000000000", "[1, 2]", "1979-05-27", '"\\u0000"')


def hostile_config(rng: np.random.Generator) -> tuple[bytes, str]:
    kind = _pick(rng, ("values", "values", "values", "nested-array", "nested-table", "nested-header", "binary",
                       "encoding", "syntax", "unknown", "types", "big", "empty"))
    if kind == "values":
        table: dict[str, dict[str, str]] = {}
        for _ in range(int(rng.integers(1, 4))):
            sec = _pick(rng, sorted(_CONFIG_KEYS))
            table.setdefault(sec, {})[_pick(rng, _CONFIG_KEYS[sec])] = _pick(rng, _TOML_VALUES)
        text = "".join(f"[{sec}]\n" + "".join(f"{k} = {v}\n" for k, v in kv.items()) for sec, kv in table.items())
        return text.encode(), f"values: {text.strip()[:80]!r}"
    if kind == "nested-array":
        n = _pick(rng, (100, 1000, 10000, 100000))
        return f"a = {'[' * n}{']' * n}\n".encode(), f"array nested {n} deep"
    if kind == "nested-table":
        n = _pick(rng, (100, 1000, 10000))
        return ("a = " + "{b = " * n + "1" + "}" * n + "\n").encode(), f"inline table nested {n} deep"
    if kind == "nested-header":
        n = _pick(rng, (100, 10000))
        return ("[" + ".".join(["t"] * n) + "]\nx = 1\n").encode(), f"table header {n} deep"
    if kind == "binary":
        return rng.bytes(int(rng.integers(1, 5000))), "random bytes"
    if kind == "encoding":
        text = '[zcut]\nstep_mm = 0.5\n'
        e = _pick(rng, ("utf16", "bom", "latin1", "nul"))
        if e == "utf16":
            return text.encode("utf-16"), "UTF-16"
        if e == "bom":
            return b"\xef\xbb\xbf" + text.encode(), "UTF-8 BOM"
        if e == "latin1":
            return b'part = "caf\xe9"\n', "Latin-1 string"
        return b"[zcut]\x00\nstep_mm = 1\n", "NUL byte"
    if kind == "syntax":
        return _pick(rng, (b"[zcut\n", b"step_mm = \n", b"[zcut]\nstep_mm = 1\nstep_mm = 2\n", b"= 1\n", b"[[zcut]]\n",
                           b'a = "unterminated\n', b"[zcut]\n[zcut]\n")), "syntax error"
    if kind == "unknown":
        return _pick(rng, (b"[nope]\nx = 1\n", b"[zcut]\nnope = 1\n", b"nope = 1\n", b"[sor.deeper]\nk = 1\n")), "unknown key"
    if kind == "types":
        return _pick(rng, (b"part = 5\n", b'parameters = "x"\n', b'preset = "nope"\n', b"zcut = 5\n", b'sor = "a"\n',
                           b"part = []\n", b'[zcut]\nconnectivity = "8"\n', b"[bin_mask]\nenabled = 1\n")), "wrong types"
    if kind == "big":
        n = _pick(rng, (1, 20))
        return (b"# " + b"c" * (n << 20) + b"\n[zcut]\nstep_mm = 0.5\n"), f"{n} MiB comment"
    return b"", "empty"


def gen_config(rng: np.random.Generator, corpus: Corpus, cid: str) -> Case:
    data, what = hostile_config(rng)
    files = {"synth.mcap": corpus["synth.mcap"], "c.toml": data}
    special: list = []
    if rng.random() < 0.1:
        kind = _pick(rng, ("fifo", "dir", "devzero", "loop", "missing"))
        files.pop("c.toml")
        what = kind
        if kind == "fifo":
            special.append(("fifo", "c.toml", ""))
        elif kind == "dir":
            special.append(("dir", "c.toml", ""))
        elif kind == "loop":
            special.append(("symlink", "c.toml", "c.toml"))
    cfg = "/dev/zero" if what == "devzero" else "c.toml"
    use = _weighted(rng, ((5, "replay"), (1, "accuracy"), (1, "bin-model"), (1, "replay-bin")))
    if use == "replay":
        argv = ["replay", "synth.mcap", "--config", cfg, "--json"]
    elif use == "accuracy":
        argv = ["accuracy", "synth.mcap", "--config", cfg, "--json"]
    elif use == "bin-model":
        files["empty.mcap"] = corpus["empty.mcap"]
        argv = ["bin-model", "empty.mcap", "--config", cfg, "-o", "model_out.ply"]
    else:
        files["bin.ply"] = corpus["bin.ply"]
        argv = ["replay", "synth.mcap", "--config", cfg, "--bin-model", "bin.ply", "--json"]
    return Case(cid, "config", f"{what} | {use}", argv, files=files, special=special, timeout_s=60.0)


# ----------------------------------------------------------------------------------------------- labels
def label_bomb(sha: str, *, n: int = 80, h: int = 4096, w: int = 4096) -> bytes:
    """A label export of ``n`` stamps whose masks are h x w zeros: a few hundred KB that decode to
    n x 2 x h x w mask pixels."""
    from replay.logs import layout

    meta = {"log_sha256": sha, "log_name": "synth.mcap", "annotator": "alice", "cloud_topics": "/camera/points",
            "schema_version": "2"}
    zeros = bytes(h * w)
    msgs = ((topic, "sensor_msgs/msg/Image", image_msg(h=h, w=w, data=zeros, encoding=b"mono8", step=w, sec=1 + i), 0)
            for i in range(n) for topic in (layout.LABEL_OUTLIERS, layout.LABEL_REVIEWED))
    return _mcap(msgs, metadata={layout.LABELS_METADATA: meta}, chunk_size=1 << 20)


def _label_mcap(rng: np.random.Generator, corpus: Corpus) -> tuple[bytes, str]:
    """A hostile label export of synth.mcap."""
    import hashlib

    from replay.logs import layout

    sha = hashlib.sha256(corpus["synth.mcap"]).hexdigest()
    if rng.random() < 0.05:
        if "label_bomb" not in corpus.cache:
            corpus.cache["label_bomb"] = label_bomb(sha)
        return corpus.cache["label_bomb"], "80 x 2 masks of 4096x4096 zeros"
    h, w = 24, 32
    stamps = [1706140800000000000, 1706140800500000000]
    meta = {"log_sha256": sha, "log_name": "synth.mcap", "annotator": "alice", "cloud_topics": "/camera/points",
            "schema_version": "2"}
    kind = _pick(rng, ("size", "encoding", "stamp", "dup", "missing-reviewed", "meta", "meta", "not-subset", "many"))
    what = kind
    pairs = []
    for st in stamps:
        out = (rng.random((h, w)) < 0.05).astype(np.uint8) * 255
        rev = np.full((h, w), 255, np.uint8)
        pairs.append([st, out, rev, b"mono8", b"mono8"])
    if kind == "size":
        hh, ww = _pick(rng, ((h + 1, w), (1, 1), (w, h), (4096, 4096)))
        pairs[0][1] = np.zeros((hh, ww), np.uint8)
        pairs[0][2] = np.zeros((hh, ww), np.uint8)
        what = f"labels {hh}x{ww}"
    elif kind == "encoding":
        pairs[0][3] = _pick(rng, (b"rgb8", b"16UC1", b""))
    elif kind == "stamp":
        pairs[0][0] = _pick(rng, (0, 1, 2**63 - 1, stamps[1]))
    elif kind == "dup":
        pairs.append(list(pairs[0]))
    elif kind == "meta":
        key = _pick(rng, sorted(meta))
        meta[key] = _pick(rng, ("", "x" * 100000, "\x1b[31m", "0" * 64, ",,,", "/camera/points,/camera/points"))
        what = f"metadata {key} = {meta[key][:12]!r}"
    elif kind == "not-subset":  # outliers outside reviewed
        pairs[0][2] = np.zeros((h, w), np.uint8)
    elif kind == "many":
        pairs = pairs * 200
    msgs = []
    for st, out, rev, e1, e2 in pairs:
        for topic, m, enc in ((layout.LABEL_OUTLIERS, out, e1), (layout.LABEL_REVIEWED, rev, e2)):
            if kind == "missing-reviewed" and topic == layout.LABEL_REVIEWED:
                continue
            hh, ww = m.shape
            sec, nsec = divmod(st, 10**9)
            msgs.append((topic, "sensor_msgs/msg/Image",
                         image_msg(h=hh, w=ww, data=m.tobytes(), encoding=enc, step=ww, sec=sec, nsec=nsec), 0))
    return _mcap(msgs, metadata={layout.LABELS_METADATA: meta}), what


def _damaged_db(rng: np.random.Generator, corpus: Corpus) -> tuple[bytes, str]:
    import sqlite3
    import tempfile

    kind = _pick(rng, ("garbage", "truncated", "empty", "flip", "other-schema", "future"))
    db = corpus["labels.sqlite"]
    if kind == "garbage":
        return rng.bytes(4096), kind
    if kind == "truncated":
        return db[: int(rng.integers(1, len(db)))], kind
    if kind == "empty":
        return b"", kind
    if kind == "flip":
        b, w = mutate_bytes(rng, db)
        return b, f"flip: {w}"
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "x.sqlite"
        if kind == "future":
            p.write_bytes(db)
        con = sqlite3.connect(p)
        if kind == "future":
            con.execute("PRAGMA user_version = 999")
        else:
            con.execute("CREATE TABLE other (a, b)")
        con.commit()
        con.close()
        return p.read_bytes(), kind


def gen_labels(rng: np.random.Generator, corpus: Corpus, cid: str) -> Case:
    files = {"synth.mcap": corpus["synth.mcap"], "labels.sqlite": corpus["labels.sqlite"]}
    action = _weighted(rng, ((4, "import"), (2, "export"), (1, "list")))
    what_db = ""
    if rng.random() < 0.3:
        files["labels.sqlite"], what_db = _damaged_db(rng, corpus)
    if action == "import":
        if rng.random() < 0.4:
            data, w = mutate_bytes(rng, corpus["labels.mcap"])
            what = f"mutated export: {w}"
        else:
            data, what = _label_mcap(rng, corpus)
        files["in.mcap"] = data
        argv = ["labels", "import", "in.mcap", "--db", "labels.sqlite"]
        if rng.random() < 0.3:
            argv += ["--annotator", _pick(rng, NAMES)]
        mutable = {"labels.sqlite"}
    else:
        log = "synth.mcap"
        what = "intact log"
        if rng.random() < 0.3:
            files["synth.mcap"], w = mutate_bytes(rng, corpus["synth.mcap"])
            what = f"mutated log: {w}"
        argv = ["labels", action, log, "--db", "labels.sqlite"]
        if action == "export":
            argv += ["-o", "out.mcap"]
        if rng.random() < 0.3:
            argv += ["--annotator", _pick(rng, NAMES)]
        mutable = set()
    if what_db:
        what += f"; db: {what_db}"
    return Case(cid, "labels", f"{action}: {what}", argv, files=files, mutable=mutable, timeout_s=60.0)


# ----------------------------------------------------------------------------------------------- registry
GENERATORS = {
    "mcap_bytes": gen_mcap_bytes,
    "mcap_struct": gen_mcap_struct,
    "mcap_bomb": gen_mcap_bomb,
    "cloud": gen_cloud,
    "image": gen_image,
    "pcd": gen_pcd,
    "ply": gen_ply,
    "cli": gen_cli,
    "paths": gen_paths,
    "config": gen_config,
    "labels": gen_labels,
}
#: shares of the long run (10,000 cases)
WEIGHTS = {"mcap_bytes": 1500, "mcap_struct": 1500, "mcap_bomb": 200, "cloud": 1500, "image": 1000, "pcd": 900,
           "ply": 900, "cli": 1000, "paths": 600, "config": 500, "labels": 400}


def make_case(corpus: Corpus, generator: str, seed: int, k: int) -> Case:
    """The k-th case of ``generator`` for ``seed`` (the same every time)."""
    gid = sorted(GENERATORS).index(generator)
    rng = np.random.default_rng([seed, gid, k])
    return GENERATORS[generator](rng, corpus, f"{generator}-{seed}-{k:05d}")


def make_cases(corpus: Corpus, counts: dict[str, int], seed: int):
    """Cases of every generator, interleaved (so that a partial run covers them all)."""
    order = []
    for g, n in counts.items():
        order += [(k / max(n, 1), g, k) for k in range(n)]
    for _, g, k in sorted(order):
        yield make_case(corpus, g, seed, k)


def scaled(total: int) -> dict[str, int]:
    """:data:`WEIGHTS` scaled to ``total`` cases."""
    s = sum(WEIGHTS.values())
    counts = {g: int(total * w / s) for g, w in WEIGHTS.items()}
    for g in sorted(WEIGHTS, key=WEIGHTS.get, reverse=True)[: total - sum(counts.values())]:
        counts[g] += 1
    return counts

if __name__ == "__main__":
    if len(sys.argv) in (3, 4) and sys.argv[1] == "corpus" and sys.argv[3:] in ([], ["--warmed-up"]):
        build_corpus(Path(sys.argv[2]), warmed_up=sys.argv[3:] == ["--warmed-up"])
    else:
        sys.exit(f"usage: {sys.argv[0]} corpus DIR [--warmed-up]")
