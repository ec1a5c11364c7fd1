"""``zcut accuracy LOG_OR_RESULTS.mcap``: true accuracy of z-cut, SOR, union and intersection (docs/accuracy.md),
and of ``learned``, the labelling assistant's model (``--learned DB`` or a ``--labels`` store holding one), only
on the frames it was not trained on (docs/labelling.md).

Predictions come from the pipeline, resolved and run as ``zcut replay`` runs it (the same options
resolve the same filter), or from a results file of ``zcut replay --out``; the truth from a
synthetic log's ``/ground_truth/outliers`` (and ``/ground_truth/outlier_kind``) or from an
annotator's labels (``--labels DB``). Counts are taken over the scored region (``--region``: ``zone``,
the pixels the filters judge, by default; ``valid``: every valid pixel).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from replay.logs import layout


def add_arguments(p: argparse.ArgumentParser) -> None:
    from cli.commands.common import add_pipeline_options

    p.add_argument("log", type=Path, metavar="LOG_OR_RESULTS.mcap",
                   help="a log (predictions computed by the pipeline) or a results file of `zcut replay`")
    p.add_argument("--labels", type=Path, default=None, metavar="DB",
                   help="human labels (zcut annotate's SQLite file); default: the log's /ground_truth/outliers")
    p.add_argument("--annotator", default=None, help="whose labels (needed when the DB has several annotators)")
    p.add_argument("--agreement", nargs=2, metavar=("A", "B"), default=None,
                   help="instead: agreement of two annotators (IoU, Cohen's kappa over the pixels both reviewed)")
    p.add_argument("--region", default="zone",
                   help="the scored region: zone (default: what the filters judge) or valid (every valid pixel)")
    p.add_argument("--per-frame", action="store_true", help="also print the per-frame table")
    p.add_argument("--learned", type=Path, default=None, metavar="DB",
                   help="also score `learned`, the labelling assistant's newest model in this label store "
                        "(zcut labels train), on the frames it was not trained on (default: the --labels store, "
                        "when it holds a model)")
    p.add_argument("--by-displacement", action="store_true",
                   help="also give recall by displacement |Z - Z_GT| (<=1, 1-5, 5-30, >30 mm) from the log's "
                        "/ground_truth/depth (a log, not a results file)")
    p.add_argument("--json", action="store_true", help="print the docs/accuracy.md JSON object instead of tables")
    add_pipeline_options(p)


def run(args: argparse.Namespace) -> int:
    from annotate.accuracy import (
        UnscoredFrame,
        accuracy_report,
        format_accuracy_table,
        frame_accuracy,
        report_json,
    )
    from annotate.truth import (
        LabelTruth,
        SyntheticTruth,
        check_region,
        method_predictions,
        region_of_results_frame,
        scored_region,
    )
    from cli.commands.common import open_session, overrides_of
    from replay.logs.reader import LogReader
    from replay.pipeline.methods import base_methods, method_masks
    from zcut.errors import ParameterError, ZcutError

    if not args.log.is_file():
        raise FileNotFoundError(2, "no such file", str(args.log))
    check_region(args.region)
    if args.agreement and args.labels is None:
        raise ParameterError("--agreement needs --labels DB")
    if args.labels is not None and not args.labels.is_file():
        raise FileNotFoundError(2, "no such file", str(args.labels))
    overrides = overrides_of(args)  # bad values fail before the log is read

    if args.agreement:
        return _agreement(args)
    reader = LogReader(args.log, cloud_topic=args.topic, cloudless=True)
    truth_src = (LabelTruth(args.labels, args.log, annotator=args.annotator) if args.labels
                 else SyntheticTruth(with_kinds=layout.TRUTH_OUTLIER_KIND in reader.mask_topics,
                                     with_unknown=layout.TRUTH_UNKNOWN in reader.mask_topics))
    try:
        is_results = layout.ZCUT_OUTLIERS in reader.mask_topics
        methods = _results_methods(reader, args) if is_results else None
        if args.labels is None and layout.TRUTH_OUTLIERS not in reader.mask_topics:
            raise ZcutError(f"{args.log} has no {layout.TRUTH_OUTLIERS}: give human labels with --labels DB")
        session = None
        if is_results:
            stream = reader.frames()
            frames = ((f, None) for f in stream)
        else:  # predictions computed as `zcut replay` computes them (the same resolved config)
            session = open_session(args.log, args, overrides=overrides)
            frames = stream = session.results()
        learned = _learned_model(args, session)
        # |Z - Z_GT| of every pixel where the log has the true depth (recall by displacement)
        # (asked for: a results file cannot give it, and its report otherwise equals the log's)
        with_depth = args.by_displacement
        if with_depth and (session is None or layout.TRUTH_DEPTH not in reader.topics):
            raise ZcutError(f"--by-displacement needs a log with {layout.TRUTH_DEPTH}"
                            + (" (a results file has lost the z-cut's outliers' depths: give the log)"
                               if session is None else f": {args.log} has none"))
        learned_seen: set[int] = set()
        results, unscored = [], []
        for frame, r in frames:
            if r is None:
                preds = method_masks({b: frame.masks[layout.method_topic(b)] for b in base_methods(methods)
                                      if layout.method_topic(b) in frame.masks}, methods)
                # a results file's /zcut/filtered has the outliers set to NaN: its valid pixels plus the
                # predictions are the source's valid pixels
                region = region_of_results_frame(frame, args.region)
                valid = region_of_results_frame(frame, "valid")
            else:
                preds = method_predictions(r, session.config.methods)
                region, valid = scored_region(r, args.region), r.valid
            t = truth_src.truth(frame, valid)
            if isinstance(t, str):
                unscored.append(UnscoredFrame(frame.index, frame.stamp_ns, t))
                continue
            shift = _displacement_mm(args.log, frame) if with_depth else None
            fa = frame_accuracy(frame.index, frame.stamp_ns, preds, t.outliers, reviewed=t.reviewed,
                                valid=valid, region=region, kinds=t.kind, detectable=t.detectable,
                                displacement_mm=shift)
            if r is not None:  # the bin check of the frame (a results file does not carry it)
                check = r.bin_check
                fa = dataclasses.replace(fa, bin_check=None if check is None else float(check.value),
                                         bin_flagged=r.bin_flagged)
                if r.bin_flagged:
                    print(f"warning: frame {frame.index}: bin check: {check.reason}", file=sys.stderr)
            if learned is not None:
                from annotate.assistant import learned_mask

                seen = (frame.topic, frame.stamp_ns) in learned.frames  # trained on it: not scored
                if seen:
                    learned_seen.add(frame.index)
                fb = frame_accuracy(frame.index, frame.stamp_ns, {"learned": learned_mask(learned, frame, r,
                                    config=session.config)}, t.outliers, reviewed=t.reviewed, valid=valid,
                                    region=region & (not seen), kinds=t.kind, detectable=t.detectable,
                                    displacement_mm=shift)
                fa.counts.update(fb.counts)
                fa.classes.update(fb.classes)
            results.append(fa)
        if not results:
            what = (f"no frame of {args.log} is labelled by {truth_src.annotator!r} in {args.labels}"
                    if args.labels else f"no frame of {args.log} has {layout.TRUTH_OUTLIERS}")
            raise ZcutError(what)
        left_out = ({"learned": (learned_seen, "the assistant's model was trained on these frames")}
                    if learned is not None else None)
        report = accuracy_report(results, region=args.region, unscored=unscored, left_out=left_out)
        if args.json:
            print(report_json(report))
        else:
            pred = "computed by the pipeline" if session is not None else \
                f"from {', '.join(layout.method_topic(b) for b in base_methods(methods))}"
            print(f"truth: {truth_src.name}; predictions: {pred}")
            if session is not None:
                for note in session.notes:
                    print(f"zcut: {note}", file=sys.stderr)
            if learned is not None:
                n_seen = len(learned_seen)
                print(f"learned: the assistant's model ({learned.summary()}), scored on the "
                      f"{len(results) - n_seen} frame(s) it was not trained on ({n_seen} left out)")
            print(format_accuracy_table(report, per_frame=args.per_frame))
            if session is None:
                print("bin check: not known (a results file does not carry it; score the log itself to see "
                      "which frames' removal did not work)")
        return _status(stream.damage)
    finally:
        if hasattr(truth_src, "close"):
            truth_src.close()


def _displacement_mm(log: Path, frame):
    """|Z − Z_GT| (mm) of every pixel of a frame from the log's ``/ground_truth/depth`` message of its
    stamp (NaN where either is unknown); None when that message cannot be read (the frame then has no
    displacement classes, and the pooled report none)."""
    import numpy as np
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    from replay.errors import LogFormatError
    from replay.logs import ros2_msgs as rm

    try:
        with open(log, "rb") as f:
            for _s, _c, message in make_reader(f).iter_messages(topics=[layout.TRUTH_DEPTH], starting_at=frame.stamp_ns,
                                                                 ending_at=frame.stamp_ns):
                msg = rm.decode_image(message.data, where=f"{layout.TRUTH_DEPTH} message")
                if (msg.stamp_ns != frame.stamp_ns or msg.encoding != layout.TRUTH_DEPTH_ENCODING or msg.is_bigendian
                        or (msg.height, msg.width) != frame.shape or len(msg.data) != 4 * msg.width * msg.height):
                    continue
                depth = np.frombuffer(bytes(msg.data), dtype="<f4").reshape(msg.height, msg.width)
                return np.abs(frame.xyz[..., 2].astype(np.float64) - depth) * 1000.0
    except (McapError, LogFormatError, ValueError, OSError, EOFError):
        return None
    return None


def _learned_model(args, session):
    """The assistant's model to score as ``learned`` (None when there is none to score)."""
    from annotate.assistant import load_model
    from annotate.store import LabelStore
    from zcut.errors import ZcutError

    db = args.learned or args.labels
    if db is None:
        return None
    if session is None:
        if args.learned is not None:
            raise ZcutError("--learned scores the assistant on a log, not on a results file: give the log")
        return None
    if not Path(db).is_file():
        raise FileNotFoundError(2, "no such file", str(db))
    with LabelStore(db, read_only=True) as store:
        rec = store.latest_model()
    if rec is None:
        if args.learned is not None:
            raise ZcutError(f"{db} holds no assistant model: train one with zcut labels train")
        return None
    model = load_model(rec)
    if model.part is not None and session.config.part is not None and model.part != session.config.part:
        print(f"warning: learned: the model was trained on {model.part}, this log is {session.config.part}",
              file=sys.stderr)
    return model


def _results_methods(reader, args) -> list[str]:
    """The base methods a results file holds masks of (``/zcut/outliers``, ``/zcut/sor_outliers``,
    ``/zcut/methods/NAME``), restricted to ``--methods`` when given (each must be there)."""
    from replay.logs import layout
    from replay.pipeline.methods import members, parse_methods, registry
    from zcut.errors import ZcutError

    held = [m for m in registry() if layout.method_topic(m) in reader.mask_topics]
    if getattr(args, "methods", None) is None:
        return held
    want = parse_methods(args.methods, source="--methods")
    missing = sorted({b for m in want for b in members(m)} - set(held))
    if missing:
        raise ZcutError(f"{args.log} is a results file without the masks of {', '.join(missing)} "
                        f"(it holds {', '.join(held)}): replay the log with --methods, or score the log itself")
    return list(want)


def _agreement(args) -> int:
    from annotate.accuracy import agreement_counts, agreement_report, format_agreement_table, report_json
    from annotate.truth import LabelTruth
    from replay.logs.reader import LogReader
    from zcut.errors import ZcutError

    a, b = args.agreement
    ta = LabelTruth(args.labels, args.log, annotator=a)
    tb = LabelTruth(args.labels, args.log, annotator=b)
    reader = LogReader(args.log, cloud_topic=args.topic, cloudless=True)
    try:
        rows = []
        stream = reader.frames()
        for frame in stream:
            la = ta.store.label(r, annotator=a) if (r := ta.record(frame)) is not None else None
            lb = tb.store.label(r, annotator=b) if (r := tb.record(frame)) is not None else None
            if la is not None and lb is not None:
                rows.append((frame.index, frame.stamp_ns,
                             agreement_counts(la.outliers, la.reviewed, lb.outliers, lb.reviewed)))
        if not rows:
            raise ZcutError(f"no frame of {args.log} is labelled by both {a!r} and {b!r} in {args.labels}")
        rep = agreement_report(a, b, rows)
        print(report_json(rep, indent=None) if args.json else format_agreement_table(rep))
        return _status(stream.damage)
    finally:
        ta.close()
        tb.close()


def _status(damage) -> int:
    """Exit status 3 when the pass over the log lost frames (each loss printed as a warning)."""
    if damage:
        for d in damage:
            print(f"warning: {d.text}", file=sys.stderr)
        return 3
    return 0
