"""``zcut topics LOG.mcap``: what a log holds and what zcut would use."""

from __future__ import annotations

import argparse
import datetime as _dt
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", metavar="LOG.mcap", help="ROS 2 MCAP log")
    parser.add_argument("--topic", help="the PointCloud2 topic to use (when several are organized)")
    parser.add_argument("--image-topic", help="the colour Image topic to use (when several)")
    parser.add_argument(
        "--check", action="store_true",
        help="also decode every frame; exit 3 if the log is damaged (frames lost)",
    )


def _stamp(ns: int) -> str:
    t = _dt.datetime.fromtimestamp(ns / 1e9, tz=_dt.UTC)
    return t.strftime("%Y-%m-%d %H:%M:%S.%f")[:-3] + " UTC"


def run(args: argparse.Namespace) -> int:
    from replay.errors import LogFormatError
    from replay.logs import layout
    from replay.logs.reader import LogReader, inspect_log

    info = inspect_log(args.log)
    print(f"{info.path}  (profile {info.profile or '-'}, written by {info.library or '-'})")
    if info.start_ns is not None and info.end_ns is not None:
        span = (info.end_ns - info.start_ns) / 1e9
        print(f"time span: {_stamp(info.start_ns)} .. {_stamp(info.end_ns)}  ({span:.3f} s)")
    else:
        print("time span: unknown (the file has no summary)")
    rows = []
    for t in info.topics.values():
        size = f"{t.height}x{t.width}" if t.height is not None else "-"
        extra = t.encoding or (" ".join(t.fields) if t.fields else "")
        rows.append((t.topic, t.msg_type, t.message_encoding, "?" if t.count is None else str(t.count), size, extra))
    head = ("topic", "type", "encoding", "messages", "HxW", "image encoding / fields")
    widths = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]
    for cells in [head, *rows]:
        print("  ".join(c.ljust(w) for c, w in zip(cells, widths, strict=True)).rstrip())
    for name, kv in info.metadata.items():
        print(f"metadata '{name}':")
        for k, v in kv.items():
            first = v.splitlines()[0] if v else ""
            more = f" … ({len(v.splitlines())} lines)" if "\n" in v.strip() else ""
            print(f"  {k}: {first}{more}")
    for note in info.notes + [d.text for d in info.peek_damage]:
        print(f"warning: {note}")
    try:
        r = LogReader(args.log, cloud_topic=args.topic, image_topic=args.image_topic, cloudless=True)
    except LogFormatError:
        print("zcut would use: nothing (see the error below)", flush=True)
        raise
    for note in r.notes:
        if note not in info.notes:
            print(f"note: {note}")
    for name, media_type, n_bytes in r.attachments():
        print(f"attachment '{name}': {media_type}" + (f", {n_bytes} bytes" if n_bytes is not None else ""))
    print("zcut would use:")
    n = "?" if r.n_frames is None else r.n_frames
    print(f"  cloud:       {r.cloud_topic}  ({n} frames)")
    print(f"  image:       {r.image_topic or '- (colours from the cloud, if any)'}")
    print(f"  camera info: {r.info_topic or '-'}")
    print(f"  masks:       {', '.join(r.mask_topics) or '-'}")
    if r.attached_bin_model is not None:
        n = len(r.attached_bin_model.points)
        print(f"  bin model:   its {layout.BIN_MODEL_ATTACHMENT} attachment ({n} points)")
    elif r.bin_model_problem:
        print(f"  bin model:   - ({r.bin_model_problem})")
    else:
        print(f"  bin model:   - (no {layout.BIN_MODEL_ATTACHMENT} attachment: give --bin-model PLY, or attach one "
              "with zcut bin-model --into)")
    if not args.check:
        return 0
    n_ok = 0
    with_image = 0
    stream = r.frames()
    for frame in stream:
        n_ok += 1
        with_image += frame.rgb is not None
    print(f"check: {n_ok} frames decoded ({with_image} with colour)")
    if stream.damage:
        for d in stream.damage:
            print(f"warning: {d.text}", file=sys.stderr)
        print(f"warning: {args.log} is damaged; {n_ok} intact frames were read", file=sys.stderr)
        return 3
    return 0
