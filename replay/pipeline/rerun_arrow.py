"""Rerun's class tables (AnnotationContexts) built directly in Arrow, for the two recordings:
:mod:`replay.pipeline.viz` (``zcut replay``) and :mod:`replay.pipeline.compare_viz` (``zcut compare``).

The SDK's own converter (``rr.AnnotationInfo``) costs ~75 µs a class and its first call imports
``pyarrow.compute`` (~30 CPU ms a process); these build the same component
(tests/replay/pipeline/test_sinks_readback.py compares them with the SDK's).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pyarrow as pa
import rerun as rr


def rgba32(rgb: np.ndarray, alpha: int | np.ndarray = 255) -> np.ndarray:
    """(n, 3) uint8 -> (n,) uint32 packed 0xRRGGBBAA (Rerun's colour layout; no per-value Python)."""
    c = np.asarray(rgb).astype(np.uint32)
    return (c[:, 0] << 24) | (c[:, 1] << 16) | (c[:, 2] << 8) | np.asarray(alpha, np.uint32)


_CTX_TYPE = rr.components.AnnotationContextBatch._ARROW_DATATYPE
_ELEM_TYPE = _CTX_TYPE.value_type
_DESC_TYPE = _ELEM_TYPE.field("class_description").type
_INFO_TYPE = _DESC_TYPE.field("info").type


def contexts_arrow(ids: np.ndarray, labels: list[str | None], colours: np.ndarray,
                    offsets: np.ndarray) -> pa.Array:
    """AnnotationContexts built directly in Arrow (``rr.AnnotationInfo`` costs ~75 µs per class).

    Parameters
    ----------
    ids : (n,) integer ndarray
        Class ids of all contexts, concatenated.
    labels : list of n str or None
    colours : (n,) uint32 ndarray
        Packed RGBA colours.
    offsets : (m + 1,) integer ndarray
        Context j holds entries ``offsets[j] .. offsets[j + 1]``.

    Returns
    -------
    pyarrow.Array
        m rows of Rerun's AnnotationContext component type.
    """
    n = len(ids)
    id16 = pa.array(np.asarray(ids, np.uint16), pa.uint16())
    info = pa.StructArray.from_arrays([id16, pa.array(labels, pa.string()), pa.array(colours, pa.uint32())],
                                      fields=list(_INFO_TYPE))
    no_offsets = pa.array(np.zeros(n + 1, np.int32))
    kp = [pa.ListArray.from_arrays(no_offsets, pa.array([], _DESC_TYPE.field(name).type.value_type),
                                   type=_DESC_TYPE.field(name).type)
          for name in ("keypoint_annotations", "keypoint_connections")]
    desc = pa.StructArray.from_arrays([info, *kp], fields=list(_DESC_TYPE))
    elem = pa.StructArray.from_arrays([id16, desc], fields=list(_ELEM_TYPE))
    return pa.ListArray.from_arrays(pa.array(np.asarray(offsets, np.int32)), elem, type=_CTX_TYPE)


def class_context(classes: Iterable[tuple[int, str, tuple[int, int, int]]]) -> rr.AnnotationContext:
    """The context of a class table: 0 "none" (transparent), then each ``(id, label, (r, g, b))`` opaque.

    Built in Arrow (:func:`contexts_arrow`): the same component as ``rr.AnnotationContext([rr.AnnotationInfo(
    id=0, label="none", color=(0, 0, 0, 0)), rr.AnnotationInfo(id=i, label=name, color=col), ...])``
    (tests/replay/pipeline/test_sinks_readback.py), without the SDK's converter, whose first call imports
    ``pyarrow.compute`` (~30 CPU ms a recording, before its first frame)."""
    table = list(classes)
    ids = np.array([0] + [i for i, _, _ in table], np.int64)
    labels: list[str | None] = ["none", *(name for _, name, _ in table)]
    rgb = np.array([(0, 0, 0)] + [col for _, _, col in table], np.uint8).reshape(-1, 3)
    alpha = np.array([0] + [255] * len(table), np.uint32)
    return rr.AnnotationContext(contexts_arrow(ids, labels, rgba32(rgb, alpha), np.array([0, len(ids)])))
