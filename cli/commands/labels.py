"""``zcut labels``: list, export (MCAP ``/labels/outliers``, ``/labels/reviewed``) and import human labels, and
train the labelling assistant on them (``zcut labels train``, :mod:`annotate.assistant`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from annotate.store import LabelStore


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    ls = sub.add_parser("list", help="annotators and labelled frames of a log")
    ls.add_argument("log", type=Path, metavar="LOG.mcap")
    ls.add_argument("--db", type=Path, required=True, metavar="LABELS.sqlite")
    ex = sub.add_parser("export", help="write an annotator's current labels of a log to MCAP")
    ex.add_argument("log", type=Path, metavar="LOG.mcap")
    ex.add_argument("--db", type=Path, required=True, metavar="LABELS.sqlite")
    ex.add_argument("-o", "--out", type=Path, required=True, metavar="LABELS.mcap")
    ex.add_argument("--force", action="store_true", help="replace the output if it exists")
    ex.add_argument("--annotator", default=None, help="needed when the log has labels by several annotators")
    im = sub.add_parser("import", help="append the labels of an exported MCAP as new revisions")
    im.add_argument("labels", type=Path, metavar="LABELS.mcap")
    im.add_argument("--db", type=Path, required=True, metavar="LABELS.sqlite")
    im.add_argument("--annotator", default=None, help="store them under this name (default: the exporter's)")
    im.add_argument("--log", type=Path, default=None, metavar="LOG.mcap",
                    help="the labelled log: registered in the store (created if missing) before the import")
    _add_train(sub)


def _add_train(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    tr = sub.add_parser("train", help="train the labelling assistant on a log's labels and store the model")
    tr.add_argument("log", type=Path, metavar="LOG.mcap")
    tr.add_argument("--db", type=Path, required=True, metavar="LABELS.sqlite")
    tr.add_argument("--annotator", action="append", default=None,
                    help="whose labels (repeat for several; default: every annotator of the log)")
    from cli.commands.annotate import add_gate_option

    add_gate_option(tr)
    from cli.commands.common import add_pipeline_options

    add_pipeline_options(tr)


def train(args: argparse.Namespace) -> int:
    """``zcut labels train``: replay the labelled frames, fit the assistant, store it, print its figures."""
    import sys

    from annotate.assistant import train as fit
    from annotate.assistant import training_set_of_log
    from annotate.store import LabelStore, StoreError, file_sha256
    from cli.commands.annotate import check_gate
    from cli.commands.common import open_session, overrides_of

    for path in (args.log, args.db):
        if not path.is_file():
            raise FileNotFoundError(2, "no such file", str(path))
    gate = check_gate(args)
    overrides = overrides_of(args)
    session = open_session(args.log, args, overrides=overrides)
    with LabelStore(args.db) as store:
        log = store.log_by_sha(file_sha256(args.log))
        if log is None:
            raise StoreError(f"{args.log} is not registered in {args.db} (label it with zcut annotate first)")
        for note in session.notes:
            print(f"zcut: {note}", file=sys.stderr)
        ts = training_set_of_log(session, store, log, annotators=args.annotator,
                                 progress=lambda i, n: print(f"frame {i}: {n} groups", file=sys.stderr, flush=True))
        if ts.disagreements:
            print(f"warning: {ts.disagreements} group(s) left out: the annotators label them differently",
                  file=sys.stderr)
        model = fit(ts, part=session.config.part, log_sha256=log.sha256)
        import json

        mid = store.save_model(log_sha256=log.sha256, part=model.part, backend=model.backend,
                               meta=json.dumps(model.meta()), model=model.dumps())
    print(f"model {mid} in {args.db}: {model.summary()}")
    below = model.below_gate(gate)
    if below is not None:
        print(f"warning: {below}", file=sys.stderr)
    return 0


def run(args: argparse.Namespace) -> int:
    if args.action == "train":
        return train(args)
    creating = args.action == "import" and args.log is not None
    for path in (getattr(args, "log", None), getattr(args, "labels", None), None if creating else args.db):
        if path is not None and not path.is_file():
            raise FileNotFoundError(2, "no such file", str(path))
    from replay.outputs import OutputPlan

    with OutputPlan([args.log, args.db] if args.action == "export" else [], force=getattr(args, "force", False)) as plan:
        if args.action == "export":
            plan.add(args.out, "the label export")  # locked until it is written
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    from annotate.label_files import export_labels, import_labels
    from annotate.store import LabelStore, StoreBusyError, StoreError, file_sha256
    from zcut.errors import ParameterError

    with LabelStore(args.db, read_only=args.action != "import") as store:
        if args.action == "import":
            if args.log is not None:
                n_frames = register_log(store, args.log)
                print(f"registered {args.log} ({n_frames} frame(s)) in {args.db}")
            before = store.label_count()
            try:
                n = import_labels(store, args.labels, annotator=args.annotator)
            except StoreBusyError as e:  # each label is its own transaction: those saved stay
                try:
                    done = store.label_count() - before
                except StoreError:
                    raise e from None
                raise StoreBusyError(
                    f"{e} (nothing of {args.labels} was imported)" if done == 0 else
                    f"{e} ({done} label(s) of {args.labels} were imported before it and stay; importing again "
                    "appends them once more, as new revisions)") from None
            print(f"imported {n} label(s) from {args.labels} into {args.db}")
            return 0
        log = store.log_by_sha(file_sha256(args.log))
        if log is None:
            raise StoreError(f"{args.log} is not registered in {args.db} (open it once with zcut annotate)")
        known = store.annotators(log)
        if args.action == "list":
            frames = store.frames(log)
            print(f"{log.name}  sha256 {log.sha256[:16]}…  {len(frames)} frame(s) registered")
            for who in known:
                cur = store.current_labels(log, annotator=who)
                n_out = sum(c.n_outliers for c in cur.values())
                print(f"  {who}: {len(cur)} frame(s) labelled, {n_out} outlier pixels")
            return 0
        if args.annotator is None:
            if len(known) != 1:
                raise ParameterError(f"{args.log} has labels by {len(known)} annotators "
                                     f"({', '.join(known) or 'none'}): choose one with --annotator")
            who = known[0]
        elif args.annotator not in known:
            raise ParameterError(f"--annotator {args.annotator!r}: no labels by them for {args.log}")
        else:
            who = args.annotator
        from replay.outputs import AtomicOutput

        with AtomicOutput(args.out) as out:
            n = export_labels(store, log, out.temp, annotator=who, bag_name=Path(args.out).name)
        print(f"wrote {n} labelled frame(s) by {who} to {args.out}")
        return 0


def register_log(store: LabelStore, log: Path) -> int:
    """Register a log and its frames in a store (as ``zcut annotate`` does when it opens it)."""
    import numpy as np

    from replay.logs.reader import LogReader

    rec = store.add_log(log)
    n = 0
    for f in LogReader(log).frames():
        store.add_frame(rec, topic=f.topic, stamp_ns=f.stamp_ns, index=f.index, shape=f.shape,
                        frame_id=f.frame_id, valid=np.isfinite(f.xyz).all(axis=2))
        n += 1
    return n
