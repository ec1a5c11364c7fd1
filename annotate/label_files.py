"""Human labels as MCAP files (docs/formats.md): ``zcut labels export`` and ``zcut labels import``.

An export holds, per labelled frame, two mono8 images stamped like the frame's cloud:
``/labels/outliers`` (L) and ``/labels/reviewed`` (R), plus a ``zcut.labels`` metadata record that
names the log (sha256, file name), the cloud topics and the annotator, so that an import puts the
labels back on the same frames. The masks are read with the log reader's own MCAP scanner and Image
codec (:func:`replay.logs.reader.read_mask_topics`).
"""

from __future__ import annotations

import os

import numpy as np

from annotate.store import (
    SCHEMA_VERSION,
    LabelStore,
    LogRecord,
    StoreError,
    iter_current_labels,
    normalize_annotator,
)
from replay.logs import layout


def export_labels(store: LabelStore, log: LogRecord, path: str | os.PathLike[str], *, annotator: str,
                  bag_name: str | None = None) -> int:
    """Write an annotator's current labels of a log to MCAP (``bag_name``: the file name its ``rosbag2``
    record names, when ``path`` is a temporary renamed into place; default ``path``'s name).

    Returns
    -------
    int
        Number of frames written.
    """
    from replay.logs.writer import LogWriter

    pairs = list(iter_current_labels(store, log, annotator=annotator))
    cloud_topics = sorted({fr.topic for fr, _ in pairs})
    meta = {
        layout.LABELS_METADATA: {
            "log_sha256": log.sha256,
            "log_name": log.name,
            "annotator": annotator,
            "cloud_topics": ",".join(cloud_topics),
            "schema_version": str(SCHEMA_VERSION),
        }
    }
    with LogWriter(path, metadata=meta, bag_name=bag_name) as w:
        for fr, lab in pairs:
            w.write_mask(layout.LABEL_OUTLIERS, lab.outliers, stamp_ns=fr.stamp_ns, frame_id=fr.frame_id)
            w.write_mask(layout.LABEL_REVIEWED, lab.reviewed, stamp_ns=fr.stamp_ns, frame_id=fr.frame_id)
    return len(pairs)


def read_label_masks(path: str | os.PathLike[str]) -> tuple[dict[str, str], dict[int, dict[str, np.ndarray]]]:
    """(``zcut.labels`` metadata, stamp_ns -> {topic: (H, W) bool}) of an exported label MCAP.

    A damaged file is a :class:`~replay.errors.LogFormatError` (labels are imported whole or not at
    all), as is a file without the ``zcut.labels`` record.
    """
    from replay.errors import LogFormatError
    from replay.logs.reader import read_mask_topics

    metadata, masks = read_mask_topics(path, (layout.LABEL_OUTLIERS, layout.LABEL_REVIEWED))
    meta = metadata.get(layout.LABELS_METADATA, {})
    if not meta:
        raise LogFormatError(f"{path}: no {layout.LABELS_METADATA!r} metadata record; not a zcut label export")
    return meta, masks


def import_labels(store: LabelStore, path: str | os.PathLike[str], *, annotator: str | None = None) -> int:
    """Append the labels of an exported MCAP as new revisions (``source='import'``).

    Frames are found by the log's sha256 and (cloud topic, stamp_ns); the log must be registered
    in the store (``zcut labels import --log LOG.mcap`` or :meth:`LabelStore.add_log`). Each imported
    label goes on top of the annotator's current revision (nothing is overwritten).

    Returns
    -------
    int
        Number of labels imported.
    """
    meta, masks = read_label_masks(path)
    log = store.log_by_sha(meta.get("log_sha256", ""))
    if log is None:
        raise StoreError(
            f"{path}: labels are for log {meta.get('log_name', '?')} (sha256 {meta.get('log_sha256', '?')[:12]}…), "
            f"which is not registered in {store.path}"
        )
    who = normalize_annotator(annotator or meta.get("annotator", ""))  # before any query uses it
    cloud_topics = [t for t in meta.get("cloud_topics", "").split(",") if t]
    n = 0
    for stamp, pair in sorted(masks.items()):
        if layout.LABEL_OUTLIERS not in pair or layout.LABEL_REVIEWED not in pair:
            raise StoreError(f"{path}: stamp {stamp} lacks one of {layout.LABEL_OUTLIERS}, {layout.LABEL_REVIEWED}")
        frames = [fr for t in cloud_topics if (fr := store.frame(log, topic=t, stamp_ns=stamp)) is not None]
        if len(frames) != 1:
            raise StoreError(f"{path}: stamp {stamp} matches {len(frames)} frames of {log.name}, expected 1")
        fr = frames[0]
        latest = store.revisions(fr, annotator=who)
        store.save_label(
            fr,
            annotator=who,
            outliers=pair[layout.LABEL_OUTLIERS],
            reviewed=pair[layout.LABEL_REVIEWED],
            base_revision=latest[-1] if latest else 0,
            source="import",
        )
        n += 1
    return n
