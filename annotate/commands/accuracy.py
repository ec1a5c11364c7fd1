"""``zcut accuracy LOG_OR_RESULTS.mcap``: true accuracy of z-cut, SOR, union and intersection (SPEC §4)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from replay.logs import layout


def add_arguments(p: argparse.ArgumentParser) -> None:
    from replay.commands.common import add_pipeline_options

    p.add_argument("log", type=Path, metavar="LOG_OR_RESULTS.mcap",
                   help="a log (predictions computed by the pipeline) or a results file of `zcut replay`")
    p.add_argument("--labels", type=Path, default=None, metavar="DB",
                   help="human labels (zcut annotate's SQLite file); default: the log's /ground_truth/outliers")
    p.add_argument("--annotator", default=None, help="whose labels (needed when the DB has several annotators)")
    p.add_argument("--agreement", nargs=2, metavar=("A", "B"), default=None,
                   help="instead: agreement of two annotators (IoU, Cohen's kappa over the pixels both reviewed)")
    p.add_argument("--json", action="store_true", help="print the SPEC §4 JSON object instead of tables")
    add_pipeline_options(p)


def _match(store, log, frame):
    """The store's frame for a log frame: by (log, topic, stamp), else by a unique stamp (results files)."""
    if log is not None:
        rec = store.frame(log, topic=frame.topic, stamp_ns=frame.stamp_ns)
        if rec is not None:
            return rec
    recs = store.frames_at_stamp(frame.stamp_ns)
    if log is not None:
        recs = [r for r in recs if r.log_id == log.id] or recs
    return recs[0] if len(recs) == 1 else None


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from annotate.accuracy import (
        accuracy_report,
        agreement_counts,
        agreement_report,
        format_accuracy_table,
        format_agreement_table,
        frame_accuracy,
        report_json,
    )
    from annotate.store import LabelStore, file_sha256
    from replay.commands.common import load_model, open_session, overrides_of
    from replay.logs.reader import LogReader
    from zcut.errors import ParameterError, ZcutError

    if not args.log.is_file():
        raise FileNotFoundError(2, "no such file", str(args.log))
    if args.agreement and args.labels is None:
        raise ParameterError("--agreement needs --labels DB")
    if args.labels is not None and not args.labels.is_file():
        raise FileNotFoundError(2, "no such file", str(args.labels))
    overrides = overrides_of(args)  # bad values fail before the log is read

    reader = LogReader(args.log, cloud_topic=args.topic)
    store = LabelStore(args.labels) if args.labels is not None else None
    try:
        log = store.log_by_sha(file_sha256(args.log)) if store is not None else None
        annotator = None
        if store is not None and not args.agreement:
            known = store.annotators(log) if log is not None else store.annotators()
            if args.annotator is not None:
                if args.annotator not in known:
                    raise ParameterError(f"--annotator {args.annotator!r}: no labels by them in {args.labels} "
                                         f"(annotators: {', '.join(known) or 'none'})")
                annotator = args.annotator
            elif len(known) == 1:
                annotator = known[0]
            else:
                raise ParameterError(f"{args.labels} has labels by {len(known)} annotators "
                                     f"({', '.join(known) or 'none'}): choose one with --annotator")

        if args.agreement:
            a, b = args.agreement
            rows = []
            for frame in reader.frames():
                rec = _match(store, log, frame)
                la = store.label(rec, annotator=a) if rec else None
                lb = store.label(rec, annotator=b) if rec else None
                if la is not None and lb is not None:
                    rows.append((frame.index, frame.stamp_ns,
                                 agreement_counts(la.outliers, la.reviewed, lb.outliers, lb.reviewed)))
            if not rows:
                raise ZcutError(f"no frame of {args.log} is labelled by both {a!r} and {b!r} in {args.labels}")
            rep = agreement_report(a, b, rows)
            print(report_json(rep, indent=None) if args.json else format_agreement_table(rep))
            return _status(reader)

        is_results = layout.ZCUT_OUTLIERS in reader.mask_topics and layout.SOR_OUTLIERS in reader.mask_topics
        session = None
        if is_results:
            frames = ((f, None) for f in reader.frames())
        else:  # predictions computed as `zcut replay` computes them (the same resolved config)
            session = open_session(args.log, args, bin_model=load_model(args), overrides=overrides)
            reader = session.reader
            frames = session.results()
        results, skipped = [], 0
        for frame, r in frames:
            if store is not None:
                rec = _match(store, log, frame)
                lab = store.label(rec, annotator=annotator) if rec is not None else None
                if lab is None:
                    skipped += 1
                    continue
                if lab.outliers.shape != frame.shape:
                    raise ZcutError(f"labels of frame {frame.index} are {lab.outliers.shape}, the frame is {frame.shape}")
                truth, reviewed = lab.outliers, lab.reviewed
            else:
                gt = frame.masks.get(layout.TRUTH_OUTLIERS)
                if gt is None:
                    skipped += 1
                    continue
                truth, reviewed = gt, None
            if r is None:
                preds = {"zcut": frame.masks[layout.ZCUT_OUTLIERS], "sor": frame.masks[layout.SOR_OUTLIERS]}
            else:
                preds = {"zcut": r.zcut_outliers, "sor": r.sor_outliers}
            if reviewed is None:
                # ground truth counts over the valid pixels (R = valid, L = truth ∩ valid). A results
                # file's /zcut/filtered cloud has the outliers set to NaN: its valid pixels plus the
                # predictions are the source's valid pixels.
                reviewed = np.isfinite(frame.xyz).all(axis=2) | preds["zcut"] | preds["sor"]
                truth = truth & reviewed
            results.append(frame_accuracy(frame.index, frame.stamp_ns, preds, truth, reviewed=reviewed))
        computed = session is not None
        if not results:
            what = (f"no frame of {args.log} is labelled by {annotator!r} in {args.labels}" if store is not None
                    else f"{args.log} has no {layout.TRUTH_OUTLIERS}: give human labels with --labels DB")
            raise ZcutError(what)
        report = accuracy_report(results)
        if args.json:
            print(report_json(report))
        else:
            src = f"labels by {annotator} ({args.labels})" if store is not None else f"ground truth {layout.TRUTH_OUTLIERS}"
            pred = "computed by the pipeline" if computed else f"from {layout.ZCUT_OUTLIERS}, {layout.SOR_OUTLIERS}"
            print(f"truth: {src}; predictions: {pred}")
            if skipped:
                print(f"{skipped} frame(s) without truth skipped")
            print(format_accuracy_table(report))
        return _status(reader)
    finally:
        if store is not None:
            store.close()


def _status(reader) -> int:
    if reader.damage:
        for d in reader.damage:
            print(f"warning: {d}", file=sys.stderr)
        return 3
    return 0
