"""The records of a comparison (``zcut compare``), below the engine (:mod:`studies.compare`) and its
writer (:mod:`studies.compare_outputs`), which both use them: what a side is, one side's view of a
frame, a disagreement blob, one frame's comparison, and ``summary.parquet``'s row of a frame.

A unit of a comparison's work (:func:`studies.compare.run_compare_unit`, in a worker process or on a
Ray node) returns each frame as one row of its part file (:data:`PART_COLUMNS`): the frame's
comparison as JSON (:func:`frame_to_json`, read back exactly by :func:`frame_from_json`) and the
images the one writer needs (:class:`FrameImages`, an ``.npz`` of their set pixels, without pickled objects).
"""

from __future__ import annotations

import io
import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np


@dataclass(frozen=True, slots=True)
class SideSpec:
    """What one side of the comparison is.

    Attributes
    ----------
    label : {"A", "B"}
    text : str
        As given (``--a`` / ``--b``).
    kind : {"config", "method", "results"}
    path : Path or None
        The config file or results file.
    layer : dict
        The config layer it stands for (a config file's, or ``{"methods": [name]}``); empty for a
        results file.
    """

    label: str
    text: str
    kind: str
    path: Path | None
    layer: dict[str, Any]

    @property
    def name(self) -> str:
        return self.path.name if self.path is not None else self.text

    def as_dict(self) -> dict[str, Any]:
        return {"spec": self.text, "kind": self.kind, "name": self.name,
                "path": str(self.path) if self.path is not None else None}


@dataclass(frozen=True, slots=True)
class SideFrame:
    """One side's view of one frame: its reported methods' masks, valid pixels and scored region;
    ``result`` the pipeline's result (None for a results file)."""

    preds: dict[str, np.ndarray]
    valid: np.ndarray
    region: np.ndarray
    result: Any = None


@dataclass(frozen=True, slots=True)
class Blob:
    """One connected component (8-connected) of the pixels only one side removed.

    ``consequence``: with truth, ``"B fixes"`` / ``"B breaks"`` (all its scored pixels one way),
    ``"mixed"``, or ``"unscored"`` (outside the reviewed pixels); without truth ``None``.
    ``height_mm``: the mean over its pixels of their height above the nearest pixel (in the image) that
    neither side removed in the scored region — the local surface, parts or bin floor (positive: nearer
    the camera); ``part_mm``: the smallest 3D distance from one of its pixels to that nearest kept pixel;
    both None when no pixel was kept or its pixels have no depth.
    """

    log: str
    frame: int
    stamp_ns: int
    who: str  # "A" or "B": the side that removed it
    area_px: int
    area_mm2: float | None
    row: float
    col: float
    fixes_px: int
    breaks_px: int
    consequence: str | None
    height_mm: float | None = None
    part_mm: float | None = None

    def as_dict(self) -> dict[str, Any]:
        return {"log": self.log, "frame": self.frame, "stamp_ns": self.stamp_ns, "who": self.who,
                "area_px": self.area_px, "area_mm2": self.area_mm2, "row": round(self.row, 1),
                "col": round(self.col, 1), "fixes_px": self.fixes_px, "breaks_px": self.breaks_px,
                "consequence": self.consequence, "height_mm": self.height_mm, "part_mm": self.part_mm}


@dataclass(frozen=True, slots=True)
class FrameCompare:
    """The comparison of one frame.

    ``a``, ``b``: every reported method's counts (:class:`zcut.metrics.AccuracyCounts`) of each side,
    None without truth; ``both``, ``only_a``, ``only_b``: pixels of the primary masks in the union
    of the two scored regions; ``diff``: the (H, W) uint8 difference image (:data:`DIFF_CODES`).
    ``classes``: where the frame's truth has them, the true outlier pixels per class of each side's
    primary method, ``{"a" | "b": {FAMILY: {"n": [...], "found": [...]}}}`` (a family of
    :data:`annotate.accuracy.CLASS_FAMILIES`, today ``by_displacement``; entry ``i`` its class ``i``);
    None when the frame has none.
    """

    log: str
    index: int
    stamp_ns: int
    a: dict[str, Any] | None
    b: dict[str, Any] | None
    both: int
    only_a: int
    only_b: int
    blobs: tuple[Blob, ...]
    unscored: str | None = None
    classes: dict[str, dict[str, dict[str, list[int]]]] | None = None

    @property
    def scored(self) -> bool:
        return self.a is not None


def count_f1(c: Any) -> float:
    """F1 of a frame's counts, 1.0 when there is nothing to find and nothing was flagged (a frame
    both sides got right), so a per-frame difference is defined on every scored frame."""
    den = 2 * c.tp + c.fp + c.fn
    return 1.0 if den == 0 else 2 * c.tp / den


def _frame_row(f: FrameCompare, pa: str, pb: str, outcome: int | None) -> dict[str, Any]:
    row: dict[str, Any] = {"log": f.log, "frame": f.index, "stamp_ns": f.stamp_ns, "scored": f.scored,
                           "both": f.both, "only_a": f.only_a, "only_b": f.only_b, "blobs": len(f.blobs),
                           "blobs_a": sum(b.who == "A" for b in f.blobs), "blobs_b": sum(b.who == "B" for b in f.blobs)}
    for side, counts, prim in (("a", f.a, pa), ("b", f.b, pb)):
        c = counts[prim] if counts is not None else None
        for k in ("tp", "fp", "fn"):
            row[f"{side}_{k}"] = getattr(c, k) if c is not None else None
        for k in ("precision", "recall", "f1"):
            v = getattr(c, k) if c is not None else None
            row[f"{side}_{k}"] = v if v is not None and math.isfinite(v) else None
    row["delta_f1"] = (None if f.a is None or f.b is None else count_f1(f.b[pb]) - count_f1(f.a[pa]))
    row["outcome"] = outcome
    return row


def summary_rows(report: dict[str, Any], frames: list[FrameCompare]) -> list[dict[str, Any]]:
    """``summary.parquet``'s rows: one per frame."""
    pa, pb = report["a"]["primary"], report["b"]["primary"]
    outcomes = {(f["log"], f["index"]): f.get("outcome") for f in report["frames"]}
    return [_frame_row(f, pa, pb, outcomes.get((f.log, f.index))) for f in frames]


# ------------------------------------------------------------------------- a unit's rows (parts)
#: The columns of a comparison unit's part file (one row per frame): ``record`` the frame's
#: :class:`FrameCompare` as JSON (null on a frame skipped, whose reason is ``skipped``), ``truth``
#: the name of what scored it, ``stage_runs`` the stage calls it took (JSON), ``images`` its
#: :class:`FrameImages` (``.npz`` bytes).
PART_COLUMNS: dict[str, str] = {"log": "string", "log_sha256": "string", "frame": "int64", "stamp_ns": "int64",
                                "record": "string", "skipped": "string", "truth": "string",
                                "stage_runs": "string", "images": "binary"}


def part_schema() -> Any:
    """:data:`PART_COLUMNS` as an Arrow schema."""
    import pyarrow as pa

    types = {"string": pa.string(), "int64": pa.int64(), "binary": pa.binary()}
    return pa.schema([(k, types[v]) for k, v in PART_COLUMNS.items()])


def _counts_from(d: dict[str, Any] | None) -> Any:
    from zcut.metrics import AccuracyCounts, KindCounts

    if d is None:
        return None
    kinds = d.get("kinds")
    return AccuracyCounts(**{**d, "kinds": None if kinds is None else
                             KindCounts(**{k: tuple(v) for k, v in kinds.items()})})


def frame_to_json(f: FrameCompare) -> str:
    """One frame's comparison as JSON text (every count and figure exactly; :func:`frame_from_json`)."""
    def side(counts: dict[str, Any] | None) -> dict[str, Any] | None:
        return None if counts is None else {m: asdict(c) for m, c in counts.items()}

    return json.dumps({"log": f.log, "index": f.index, "stamp_ns": f.stamp_ns, "a": side(f.a), "b": side(f.b),
                       "both": f.both, "only_a": f.only_a, "only_b": f.only_b,
                       "blobs": [asdict(b) for b in f.blobs], "unscored": f.unscored, "classes": f.classes})


def frame_from_json(text: str) -> FrameCompare:
    """The :class:`FrameCompare` :func:`frame_to_json` wrote (equal to it)."""
    d = json.loads(text)

    def side(counts: dict[str, Any] | None) -> dict[str, Any] | None:
        return None if counts is None else {m: _counts_from(c) for m, c in counts.items()}

    return FrameCompare(d["log"], d["index"], d["stamp_ns"], side(d["a"]), side(d["b"]), d["both"], d["only_a"],
                        d["only_b"], tuple(Blob(**b) for b in d["blobs"]), d["unscored"], d.get("classes"))


@dataclass(frozen=True, slots=True)
class FrameImages:
    """The (H, W) uint8 images of one compared frame that the writer needs: each side's verdict image
    (``verdict_a``, ``verdict_b``: TP 1, FP 2, FN 3, or removed 4 without truth), the difference image
    ``diff`` (its codes: docs/compare.md, ``compare.rrd``) and ``who`` (1 where only A removed a pixel,
    2 where only B did: ``disagreement.npz``'s pixels).

    With a recording, also the frame's own part of it (:attr:`view`, None without: a comparison
    without ``compare.rrd``, whose writer then reads the frame again if a later run asks for one):
    ``jpeg`` the frame's RGB image as the recording holds it (JPEG, quality 85: the bytes
    ``rr.Image(rgb).compress(85)`` gives), or ``image`` (the gray height image of a frame without
    RGB, or an RGB image JPEG does not take), ``points`` the disagreement's points (N, 3) float32 and
    ``point_ids`` their codes of ``diff``.
    """

    verdict_a: np.ndarray
    verdict_b: np.ndarray
    diff: np.ndarray
    who: np.ndarray
    view: FrameView | None = None

    def to_bytes(self) -> bytes:
        """The images as an ``.npz`` (stored, not deflated: the part file compresses its columns) of their
        set pixels only: ``shape`` (H, W), ``at`` the flat row-major indices (uint32, ascending) where any
        of the four is set, and each image's values there; with the view, its ``points``, ``point_ids``
        and ``jpeg`` or ``image``. Far cheaper than the dense images deflated (they are mostly zeros)."""
        images = (self.verdict_a, self.verdict_b, self.diff, self.who)
        anyset = self.verdict_a | self.verdict_b
        anyset |= self.diff
        anyset |= self.who
        at = np.flatnonzero(anyset)
        return sparse_images_bytes(self.diff.shape, at, tuple(img.ravel()[at] for img in images), self.view)

    @classmethod
    def from_bytes(cls, data: bytes) -> FrameImages:
        """:meth:`to_bytes` read back (also the dense, deflated images a part written before it held)."""
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            view = None
            if "points" in z.files:
                view = FrameView(z["jpeg"].tobytes() if "jpeg" in z.files else None,
                                 z["image"] if "image" in z.files else None, z["points"], z["point_ids"])
            if "at" not in z.files:  # a part of a comparison run before the sparse images
                return cls(z["verdict_a"], z["verdict_b"], z["diff"], z["who"], view)
            shape = tuple(int(x) for x in z["shape"])
            at = z["at"]
            out = []
            for k in _IMAGES:
                img = np.zeros(shape, dtype=np.uint8)
                img.ravel()[at] = z[k]
                out.append(img)
            return cls(out[0], out[1], out[2], out[3], view)


#: The images of :class:`FrameImages`, in order.
_IMAGES = ("verdict_a", "verdict_b", "diff", "who")


def sparse_images_bytes(shape: tuple[int, ...], at: np.ndarray, values: tuple[np.ndarray, ...],
                        view: FrameView | None) -> bytes:
    """:meth:`FrameImages.to_bytes` of images given by their set pixels: ``at`` the flat row-major indices
    (ascending) where any of the four images of :data:`_IMAGES` is set, ``values`` each image's values
    there, in that order (the same bytes as the dense images give)."""
    buf = io.BytesIO()
    arrays: dict[str, Any] = {"shape": np.array(shape, dtype=np.int64), "at": at.astype(np.uint32)}
    arrays.update(dict(zip(_IMAGES, values, strict=True)))
    if view is not None:
        arrays.update({"points": view.points, "point_ids": view.point_ids})
        if view.jpeg is not None:
            arrays["jpeg"] = np.frombuffer(view.jpeg, dtype=np.uint8)
        if view.image is not None:
            arrays["image"] = view.image
    np.savez(buf, **arrays)
    return buf.getvalue()


@dataclass(frozen=True, slots=True)
class FrameView:
    """A compared frame's own content in the recording (:class:`FrameImages`' ``view``): ``jpeg`` or
    ``image`` (one of them), the disagreement's ``points`` (N, 3) float32 and ``point_ids`` (N,) uint8."""

    jpeg: bytes | None
    image: np.ndarray | None
    points: np.ndarray
    point_ids: np.ndarray
