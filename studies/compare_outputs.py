"""The files of ``zcut compare`` (docs/compare.md): ``compare.json``, ``summary.parquet``, ``report.html``
and ``compare.rrd``, each written beside its final path and renamed into place when the comparison
completes (:class:`replay.outputs.AtomicOutput`); an interrupted or failed comparison leaves none.

:class:`CompareWriter` is the one writer: it takes the frames in log and frame order as soon as the
units before them are done (each frame's comparison and images, :func:`frame_images`, as the units
returned them: the recording's content of the frame too, :func:`frame_view`), streams the recording
and the disagreement, and writes the tables and the page from the report. The page is the Jinja2 template
``studies/templates/compare.html`` (autoescaped; the sweep's stylesheet ``report.css``), its plots
drawn as SVG in the sweep's plot style without matplotlib (:func:`studies.plots.svg_figure`).
"""

from __future__ import annotations

import base64
import io
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from replay.outputs import AtomicOutput, naming
from studies.compare_records import (
    FrameCompare,
    FrameImages,
    FrameView,
    SideFrame,
    SideSpec,
    count_f1,
    sparse_images_bytes,
)
from studies.schemas import COMPARE_SUMMARY_COLUMNS, table_of

if TYPE_CHECKING:
    from replay.logs.frame import Frame
    from replay.pipeline.compare_viz import CompareRecording


def config_markdown(spec_a: SideSpec, spec_b: SideSpec, diff: list[dict[str, Any]], primaries: tuple[str, str]) -> str:
    """The config difference as a Markdown document (the recording's first view)."""
    lines = [f"**A** = `{spec_a.name}` ({spec_a.kind}, primary `{primaries[0]}`) · "
             f"**B** = `{spec_b.name}` ({spec_b.kind}, primary `{primaries[1]}`)", ""]
    if not diff:
        lines.append("No config parameter differs (a results file's config unknown, or the sides differ "
                     "in their inputs only).")
    else:
        lines += ["| parameter | A | B |", "|---|---|---|"]
        lines += [f"| `{d['key']}` | {_v(d['a'])} | {_v(d['b'])} |" for d in diff]
    return "\n".join(lines) + "\n"


def _v(x: Any) -> str:
    if x is None:
        return "—"
    return f"`{x:.6g}`" if isinstance(x, float) else f"`{x}`"


def frame_images(sa: SideFrame, sb: SideFrame, diff: np.ndarray, truth: tuple[np.ndarray, np.ndarray] | None,
                 pa: str, pb: str, frame: Frame | None = None) -> FrameImages:
    """What the writer needs of one compared frame (computed where the frame ran: a worker); with the
    ``frame``, its own part of the recording too (:func:`frame_view`), so that the writer need not
    read it again."""
    where = sa.region | sb.region
    ma, mb = sa.preds[pa], sb.preds[pb]
    who = np.zeros(ma.shape, dtype=np.uint8)
    who[ma & ~mb & where] = 1
    who[mb & ~ma & where] = 2
    return FrameImages(verdict_image(sa.preds[pa] & sa.region, truth), verdict_image(sb.preds[pb] & sb.region, truth),
                       diff, who, None if frame is None else frame_view(frame, diff))


def frame_images_bytes(sa: SideFrame, sb: SideFrame, truth: tuple[np.ndarray, np.ndarray] | None, pa: str, pb: str,
                       frame: Frame | None = None, *, where: np.ndarray | None = None) -> bytes:
    """``frame_images(sa, sb, diff_image(...), truth, pa, pb, frame).to_bytes()`` (the same bytes: the
    images the writer reads back are the same), computed at the pixels that can be set alone: every
    image is 0 outside the two scored regions (``truth``'s scored pixels lie inside them), and inside
    them 0 where neither side removed the pixel and it is not a scored true outlier (a verdict is TP,
    FP or FN only there; B's choice differs from A's, or both are wrong, only there; ``who`` is set
    only where one side removed it). So no whole-frame image is made, nor one of the whole region.
    ``where``: ``sa.region | sb.region``, when the caller has it."""
    if where is None:
        where = sa.region | sb.region
    ma, mb = sa.preds[pa], sb.preds[pb]
    cand = ma | mb
    if truth is not None:
        cand |= truth[0] & truth[1]
    cand &= where
    at_w = np.flatnonzero(cand)
    ma, mb = ma.ravel()[at_w], mb.ravel()[at_w]
    only_a, only_b = ma & ~mb, mb & ~ma
    who = np.zeros(at_w.size, dtype=np.uint8)
    who[only_a] = 1
    who[only_b] = 2
    t_at = None if truth is None else (truth[0].ravel()[at_w], truth[1].ravel()[at_w])
    va = verdict_image(ma & sa.region.ravel()[at_w], t_at)
    vb = verdict_image(mb & sb.region.ravel()[at_w], t_at)
    diff = np.zeros(at_w.size, dtype=np.uint8)
    if t_at is None:
        diff[only_a] = 4
        diff[only_b] = 5
    else:
        lab, scored = t_at
        right_a = (ma == lab) & scored
        right_b = (mb == lab) & scored
        diff[~right_a & right_b] = 1
        diff[right_a & ~right_b] = 2
        diff[~right_a & ~right_b & scored] = 3
    anyset = va | vb
    anyset |= diff
    anyset |= who
    keep = np.flatnonzero(anyset)
    view = None
    if frame is not None:
        on = diff != 0
        view = _frame_view_at(frame, at_w[on], diff[on])
    return sparse_images_bytes(sa.region.shape, at_w[keep], (va[keep], vb[keep], diff[keep], who[keep]), view)


#: JPEG quality of the recording's RGB image (as ``zcut replay``'s recording compresses it).
JPEG_QUALITY = 85


def frame_view(frame: Frame, diff: np.ndarray) -> FrameView:
    """A frame's own content in the recording: its RGB image JPEG-encoded (the bytes Rerun's
    ``Image.compress(85)`` makes: Pillow, quality 85), or a gray height image without RGB (near is
    bright); the points where ``diff`` is set (the disagreement in 3D) with their codes."""
    at = np.flatnonzero(diff)
    return _frame_view_at(frame, at, diff.ravel()[at])


def _frame_view_at(frame: Frame, at: np.ndarray, codes: np.ndarray) -> FrameView:
    """:func:`frame_view` of the difference image set at the flat pixels ``at`` (ascending) to ``codes``."""
    from PIL import Image

    rgb = frame.rgb
    jpeg = image = None
    if rgb is not None and rgb.dtype == np.uint8 and rgb.ndim == 3 and rgb.shape[2] == 3:
        buf = io.BytesIO()
        Image.fromarray(rgb).save(buf, format="JPEG", quality=JPEG_QUALITY)
        jpeg = buf.getvalue()
    elif rgb is not None:
        image = rgb
    else:
        z = frame.xyz[..., 2].astype(np.float64)
        ok = np.isfinite(z)
        image = np.zeros(z.shape, dtype=np.uint8)
        if ok.any():
            lo, hi = float(z[ok].min()), float(z[ok].max())
            image[ok] = (255 * (hi - z[ok]) / max(hi - lo, 1e-9)).astype(np.uint8)
    # the set pixels of diff whose point is valid, in row-major order (the points of only those are read)
    r, c = np.divmod(at, frame.xyz.shape[1])
    pts = frame.xyz[r, c]
    ok = np.isfinite(pts).all(axis=1)
    return FrameView(jpeg, image, pts[ok].astype(np.float32), codes[ok])


def verdict_image(pred: np.ndarray, truth: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """(H, W) uint8: TP 1, FP 2, FN 3 over the scored pixels (``truth`` = (outliers, scored)); without
    truth, removed 4. Of any shape: at some pixels, ``pred`` and ``truth`` given there (1-D)."""
    out = np.zeros(pred.shape, dtype=np.uint8)
    if truth is None:
        out[pred] = 4
        return out
    lab, scored = truth
    out[pred & lab & scored] = 1
    out[pred & ~lab & scored] = 2
    out[~pred & lab & scored] = 3
    return out


class CompareWriter:
    """Streams the recording while frames come, writes the tables and the page at the end.

    Parameters
    ----------
    paths : dict
        ``{"json", "parquet", "report"?, "rrd"?}`` -> final path (planned and locked by the caller).
    """

    def __init__(self, paths: dict[str, Path], *, has_truth: bool | None = None) -> None:
        from annotate.disagreement import DisagreementRecorder
        from replay.pipeline.sinks import RrdFile

        self.paths = paths
        self.files = {k: AtomicOutput(p) for k, p in paths.items() if k != "rrd"}
        #: the pixels where A and B disagree, for ``zcut annotate --disagreement`` (annotate/disagreement.py)
        self.disagreement = DisagreementRecorder() if "disagreement" in paths else None
        self.rrd = RrdFile(paths["rrd"]) if "rrd" in paths else None  # checked per frame, as replay's
        self.rec: CompareRecording | None = None
        self.seq = 0
        self.has_truth = has_truth

    def log(self, path: Path, *, sha256: str | None = None) -> None:
        """The frames that follow are of the log at ``path`` (``sha256``: its content hash, when known)."""
        if self.disagreement is not None:
            self.disagreement.log(path, sha256=sha256)

    def start(self, spec_a: SideSpec, spec_b: SideSpec, diff: list[dict[str, Any]], *, has_truth: bool, primaries: tuple[str, str]) -> None:
        self.has_truth = has_truth
        if self.disagreement is not None:
            self.disagreement.primaries = primaries
        if self.rrd is not None:
            from replay.pipeline.compare_viz import CompareRecording

            self.rec = CompareRecording(self.rrd, label_a=f"{spec_a.name} ({primaries[0]})",
                                        label_b=f"{spec_b.name} ({primaries[1]})",
                                        config_markdown=config_markdown(spec_a, spec_b, diff, primaries))

    def frame(self, fc: FrameCompare, images: FrameImages, pa: str, pb: str, view: FrameView | None = None) -> None:
        """One compared frame, in order: its disagreement, and in the recording its own content (``view``:
        the part's, :attr:`FrameImages.view`, or made from the log's frame read again when the part has
        none; None leaves the frame out of the recording)."""
        if self.disagreement is not None:  # the pixels _score_frame counts as only_a and only_b
            self.disagreement.frame(fc.index, fc.stamp_ns, images.who == 1, images.who == 2)
        if self.rec is None or view is None:
            return
        ca = fc.a[pa] if fc.a is not None else None
        cb = fc.b[pb] if fc.b is not None else None
        scalars: dict[str, float] = {"diff/scalars/only_a_px": fc.only_a, "diff/scalars/only_b_px": fc.only_b}
        for side, c in (("a", ca), ("b", cb)):
            if c is not None:
                for k in ("precision", "recall", "f1"):
                    scalars[f"{side}/scalars/{k}"] = getattr(c, k)
        if ca is not None and cb is not None:
            scalars["diff/scalars/delta_f1"] = count_f1(cb) - count_f1(ca)
        self.rec.frame(self.seq, fc.stamp_ns, jpeg=view.jpeg, image=view.image, points=view.points,
                       point_ids=view.point_ids, verdict_a=images.verdict_a, verdict_b=images.verdict_b,
                       diff=images.diff, scalars=scalars)
        self.seq += 1
        assert self.rrd is not None
        self.rrd.check(self.rec.rec)

    def finish(self, report: dict[str, Any], rows: list[dict[str, Any]]) -> None:
        """Write every file's temporary (committed by :meth:`close`); the recording is closed, read
        back and named last, once everything else was written."""
        import pyarrow.parquet as pq

        from annotate.accuracy import jsonable

        self._write("json", lambda t: t.write_text(json.dumps(jsonable(report), indent=1, allow_nan=False) + "\n",
                                                   encoding="utf-8"))
        table = table_of(rows, COMPARE_SUMMARY_COLUMNS)  # the declared types, whatever the values
        self._write("parquet", lambda t: pq.write_table(table, t))
        if self.disagreement is not None:
            recorder = self.disagreement

            def write_npz(t: Path) -> None:
                with open(t, "wb") as f:
                    recorder.write(f)

            self._write("disagreement", write_npz)
        if "report" in self.files:
            self._write("report", lambda t: t.write_text(render_html(report), encoding="utf-8", errors="backslashreplace"))
        if self.rec is not None:
            rec, self.rec = self.rec, None
            assert self.rrd is not None
            self.rrd.close(rec.rec, completed=True)

    def _write(self, key: str, write: Any) -> None:
        """One file's temporary written; an OSError (a full disk) names the output, not the temporary."""
        f = self.files[key]
        with naming(f.path, f.temp):
            write(f.temp)

    def close(self, *, completed: bool) -> None:
        rec, self.rec = self.rec, None
        if self.rrd is not None:
            if rec is not None:  # not finished: an error, an interruption
                try:
                    self.rrd.close(rec.rec, completed=False)
                except Exception:  # noqa: BLE001 - the comparison failed already; its temporaries go
                    pass
            self.rrd.abort()
        for f in self.files.values():
            if completed:
                f.commit()
            else:
                f.abort()


# --------------------------------------------------------------------------------------- the page
def _num(v: Any, fmt: str = ".3f") -> str:
    return "—" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, fmt)


def _param(v: Any) -> str:
    return "—" if v is None else format(v, ".6g") if isinstance(v, float) else str(v)


def _signed(v: Any) -> str:
    return _num(v, "+.3f")


def _plots(report: dict[str, Any]) -> list[dict[str, Any]]:
    """The page's plots (SVG data URIs, drawn without matplotlib in the sweep's plot style:
    :func:`studies.plots.svg_figure`): per-frame F1 of A and B with ΔF1; the pooled figures with their
    paired Δ and intervals."""
    from studies.plots import SvgPanel, svg_figure

    out = []
    frames = [f for f in report["frames"] if f.get("scored")]
    pa, pb = report["a"]["primary"], report["b"]["primary"]
    if frames:
        x = [float(i) for i in range(len(frames))]
        fa = [_f1_of(f["a"][pa]) for f in frames]
        fb = [_f1_of(f["b"][pb]) for f in frames]
        per_frame = SvgPanel(lines=[(x, fa, "#0072B2", "o", 3.0, 1.5, f"A ({pa})"),
                                    (x, fb, "#D55E00", "s", 3.0, 1.5, f"B ({pb})")],
                             xlabel="frame (in order)", ylabel="F1 per frame", xinteger=True, legend=True)
        d = [b - a for a, b in zip(fa, fb, strict=True)]
        delta = SvgPanel(bars=[(xi, di, "#009E73" if di >= 0 else "#CC3311") for xi, di in zip(x, d, strict=True)],
                         hlines=[(0.0, "black", 0.8)], xlabel="frame (in order)", ylabel="ΔF1 = B − A", xinteger=True)
        svg = svg_figure([per_frame, delta], width_in=9.0, height_in=3.2)
        out.append({"title": "F1 per frame, and B − A", "uri": _uri(svg), "width": 900})
        v = report["verdict"]
        lines = []
        for i, k in enumerate(["precision", "recall", "f1"]):
            e = v["differences"][k]
            lo, hi = e["ci"]
            dk = e["delta"]
            if dk is not None:
                lines.append(([float(dk)], [float(i)], "#D55E00", "o", 6.0, 1.5, ""))
            if lo is not None and hi is not None and math.isfinite(lo) and math.isfinite(hi):
                lines.append(([float(lo), float(hi)], [float(i), float(i)], "#D55E00", "", 0.0, 2.0, ""))
        pooled = SvgPanel(lines=lines, vlines=[(0.0, "black", 0.8)], yticks=([0.0, 1.0, 2.0], ["ΔP", "ΔR", "ΔF1"]),
                          xlabel="B − A, pooled, with the 95 % paired interval")
        svg = svg_figure([pooled], width_in=6.0, height_in=2.8)
        out.append({"title": "Paired differences (B − A)", "uri": _uri(svg), "width": 600})
    return out


def _f1_of(e: dict[str, Any]) -> float:
    den = 2 * e["tp"] + e["fp"] + e["fn"]
    return 1.0 if den == 0 else 2 * e["tp"] / den


def _uri(svg: str) -> str:
    return "data:image/svg+xml;base64," + base64.b64encode(svg.encode("utf-8")).decode("ascii")


def page_context(report: dict[str, Any]) -> dict[str, Any]:
    """What the page shows, as plain strings."""
    v = report["verdict"]
    pa, pb = report["a"]["primary"], report["b"]["primary"]
    diffs = []
    if v.get("truth"):
        for k, name in (("precision", "precision"), ("recall", "recall"), ("f1", "F1")):
            e = v["differences"][k]
            lo, hi = e["ci"]
            diffs.append({"name": name, "a": _num(e["a"]), "b": _num(e["b"]), "delta": _signed(e["delta"]),
                          "ci": f"[{_signed(lo)}, {_signed(hi)}]" if lo is not None and hi is not None
                          else "no interval (too few frames)"})
    classes = []
    for cls, figs in (report.get("per_class") or {}).items():
        for fig, e in figs.items():
            lo, hi = e["ci"]
            classes.append({"name": cls, "figure": fig, "a": _num(e["a"]), "b": _num(e["b"]),
                            "delta": _signed(e["delta"]),
                            "ci": f"[{_signed(lo)}, {_signed(hi)}]" if lo is not None and hi is not None
                            else "no interval (too few frames)"})
    ag = report["agreement"]
    frames = []
    by_key = {(f["log"], f["index"]): f for f in report["frames"]}
    for w in report["frames_worst_first"][:200]:
        f = by_key[(w["log"], w["index"])]
        a = f.get("a", {}).get(pa) if f.get("scored") else None
        b = f.get("b", {}).get(pb) if f.get("scored") else None
        frames.append({"log": f["log"], "index": f["index"], "a": "—" if a is None else f"{a['tp']}/{a['fp']}/{a['fn']}",
                       "b": "—" if b is None else f"{b['tp']}/{b['fp']}/{b['fn']}",
                       "delta": _signed(f.get("delta_f1")), "only_a": f["only_a"], "only_b": f["only_b"],
                       "blobs": f["blobs"],
                       "outcome": {1: "B wins", -1: "B loses", 0: "tie"}.get(f.get("outcome"), "—")})
    blobs = [{**b, "area_mm2": _num(b["area_mm2"], ".2f"), "height_mm": _num(b.get("height_mm"), ".1f"),
              "part_mm": _num(b.get("part_mm"), ".1f"), "consequence": b["consequence"] or "—"}
             for b in report["blobs"][:300]]
    return {
        "a": report["a"], "b": report["b"], "verdict": v["line"], "truth": report["truth"] or "none (agreement only)",
        "region": report["region"], "diff": [{"key": d["key"], "a": _param(d["a"]), "b": _param(d["b"])}
                                             for d in report["config_difference"]],
        "differences": diffs, "classes": classes,
        "wins": v.get("wins"), "losses": v.get("losses"), "ties": v.get("ties"),
        "sign_p": _num(v.get("sign_test_p"), ".3g"),
        "agreement": {"both": ag["both"], "only_a": ag["only_a"], "only_b": ag["only_b"], "alpha": _num(ag["alpha"]),
                      "beta_a": _num(ag["beta_a"]), "beta_b": _num(ag["beta_b"]), "jaccard": _num(ag["jaccard"])},
        "frames": frames, "n_frames": len(report["frames"]), "blobs": blobs, "n_blobs": report["blobs_total"],
        "shared": report["shared"], "stage_runs": report["stage_runs"],
        "cost": {"frames": report["cost"]["frames"], "cpu_s": _num(report["cost"]["cpu_s"], ".1f"),
                 "wall_s": _num(report["cost"]["wall_s"], ".1f")},
        "plots": _plots(report) if v.get("truth") else [],
        "logs": report["logs"],
    }


def render_html(report: dict[str, Any]) -> str:
    """The report page: one self-contained HTML document (plots as data URIs, CSS inline)."""
    import jinja2

    env = jinja2.Environment(loader=jinja2.PackageLoader("studies", "templates"), autoescape=True,
                             trim_blocks=True, lstrip_blocks=True, undefined=jinja2.StrictUndefined)
    return env.get_template("compare.html").render(**page_context(report))
