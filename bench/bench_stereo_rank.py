"""Benchmark: the filter bank ranked on real truth — Middlebury 2014 stereo scenes (docs/real_data.md,
"Stereo scenes"; docs/filters.md, "The bank on real stereo truth").

Every scene folder is turned into one frame by ``zcut record-stereo`` (OpenCV's StereoSGBM, its own
post-filters off; truth |Z − Z_GT| > τ_d · Z_GT² / (f · B), τ_d = 1 px; pixels of unknown or occluded
truth not scored). Each method of the bank (``--methods``) is run at every point of its grid on the
five *tune* scenes and the set with the best pooled F1 is kept; it is then scored, with its default
set, on the five *report* scenes (scenes that share a ground truth — Motorcycle and MotorcycleE,
Piano and PianoL, Playtable and PlaytableP — are on the same side). Reported per method on the report
scenes: pooled precision, recall and F1 with the 95 % intervals of ``zcut accuracy`` (logit-t over
frames; five frames: wide), the per-frame F1 difference against the z-cut (mean, min..max, frames
won), recall per size class of the truth's components and on the detectable subset, and CPU seconds
per frame. Two trivial baselines are scored alike: ``zone`` flags every scored pixel; ``edges`` flags
the depth discontinuities (a pixel with a valid 8-neighbour whose depth differs by more than r · Z,
r tuned like the others). The matcher's own post-filters (uniqueness ratio, left-right check,
speckle filter) are scored as the methods ``stereo_uniqueness``, ``stereo_lr``, ``stereo_speckle``
(replay/pipeline/stereo_methods.py): the logs are recorded with ``--reject-axes``, so that every point of
their default axes is in the log as the pixels the plain matcher matched and the post-filter
invalidates, and they are tuned alike; their CPU time is a whole matcher run with the post-filter,
measured here (what recording the mask costs). The union of the z-cut and the best other cloud
method, of the two best cloud methods, and of the best post-filter with the best cloud method, at
their tuned sets, are scored too.

The truth is passive stereo matching errors on real images, not a phase-shift structured-light
camera's: say so wherever its figures are used.

    PYTHONPATH=. .venv/bin/python bench/bench_stereo_rank.py [--data DIR] [--methods zcut,sor,...]
                                                            [--markdown] [--out LOG_DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "middlebury"
if not DATA.is_dir():
    DATA = Path(os.environ.get("ZCUT_MIDDLEBURY", DATA))
TUNE = ("Adirondack", "ArtL", "Motorcycle", "MotorcycleE", "Teddy")
REPORT = ("Piano", "PianoL", "Playroom", "Playtable", "PlaytableP")
METHODS = ("zcut", "zcut_top", "sor", "radius", "cluster", "speckle", "window", "mixed_pixel", "stereo_uniqueness",
           "stereo_lr", "stereo_speckle")
#: The matcher's post-filters among the methods: their grids are their registry axes, all recorded in the logs.
POST = ("stereo_uniqueness", "stereo_lr", "stereo_speckle")
#: The grid of each method: wider than the bank's default axes (studies.bank.default_axes()) — these scenes
#: are 0.5-3 m deep with points 1-5 mm apart, where the bin-picking defaults sit at the grids' edges.
AXES: dict[str, dict[str, tuple]] = {
    "zcut": {"max_depth": (10.0, 30.0, 100.0, 300.0, 1000.0, 3000.0),
             "max_area": (50.0, 258.0, 1000.0, 4000.0, 16000.0, 64000.0, 256000.0)},
    "sor": {"k": (4, 8, 16, 32, 64), "std_ratio": (0.25, 0.5, 1.0, 2.0), "region": ("top", "zone")},
    "radius": {"radius_mm": (1.0, 2.0, 4.0, 8.0, 16.0), "min_points": (2, 4, 8, 16)},
    "cluster": {"max_neighbour_mm": (1.0, 3.0, 6.0, 12.0, 24.0), "min_area_mm2": (10.0, 50.0, 200.0, 800.0, 3200.0)},
    "speckle": {"max_diff_mm": (0.5, 2.0, 5.0, 10.0, 20.0), "max_size_px": (25, 100, 400, 1600, 6400)},
    "window": {"min_inliers": (1, 3, 5, 7), "rel_tolerance": (0.001, 0.005, 0.02, 0.05)},
    "mixed_pixel": {"min_angle_deg": (2.0, 5.0, 8.0, 12.0, 20.0, 30.0, 45.0)},
}
#: zcut_top runs the z-cut of the ``zcut`` section with its window anchored on the top: its grid is its own
#: axis (the registry's ``top_faces``) times the z-cut's grid above, whose keys carry the section they set (the
#: z-cut section's, a prefix and a dot before the field).
AXES["zcut_top"] = {"top_faces": (0.25, 1.0, 4.0), **{f"zcut.{k}": v for k, v in AXES["zcut"].items()}}
EDGE_AXIS = (0.0025, 0.005, 0.01, 0.02, 0.05, 0.1)
SIZE_NAMES = ("1px", "2-9px", "10-99px", ">=100px")
class MatcherClock:
    """CPU seconds of one matcher run with a post-filter's settings on scene i (what recording its mask costs)."""

    def __init__(self, data: Path, scenes: tuple[str, ...]) -> None:
        self.data, self.scenes = data, scenes
        self._scenes: dict[int, object] = {}

    def seconds(self, index: int, settings: dict) -> float:
        from replay.stereo_scene import load_scene
        from zcut.stereo import MatcherParams, match

        if index not in self._scenes:
            self._scenes[index] = load_scene(self.data / self.scenes[index])
        sc = self._scenes[index]
        nd = 128 if sc.calib.ndisp is None else max(16, -(-int(sc.calib.ndisp) // 16) * 16)
        t = time.process_time()
        match(sc.left, sc.right, MatcherParams(num_disparities=nd, **settings))
        return time.process_time() - t


def record(data: Path, scenes: tuple[str, ...], out: Path) -> Path:
    from cli.main import main

    log = out / "stereo-axes.mcap"
    if not log.exists():
        rc = main(["record-stereo", *(str(data / s) for s in scenes), "-o", str(log), "--reject-axes"])
        if rc != 0:
            raise SystemExit(f"record-stereo failed ({rc})")
    return log


def sets_of(method: str, config) -> list[dict]:
    from replay.pipeline.methods import registry

    axes = dict(registry()[method].axes) if method in POST else AXES.get(method, {})
    names = list(axes)
    out = [{}]  # {} = the config's own (default) set
    for combo in itertools.product(*(axes[n] for n in names)):
        d = dict(zip(names, combo))
        if all(getattr(getattr(config, sec), f) == v for (sec, f), v in ((_field(method, k), v) for k, v in d.items())):
            continue
        out.append(d)
    return out


def _field(method: str, key: str) -> tuple[str, str]:
    """(section, field) of a grid key: ``FIELD`` is the method's own section's, ``SECTION.FIELD`` another's."""
    sec, _, f = key.rpartition(".")
    return (sec or method), f


def edges(xyz: np.ndarray, r: float) -> np.ndarray:
    """Pixels with a valid 8-neighbour whose depth differs by more than r · Z."""
    z = xyz[..., 2].astype(np.float64)
    h, w = z.shape
    pad = np.full((h + 2, w + 2), np.nan)
    pad[1:-1, 1:-1] = z
    out = np.zeros((h, w), bool)
    for dy, dx in itertools.product((-1, 0, 1), repeat=2):
        if dy or dx:
            q = pad[1 + dy:h + 1 + dy, 1 + dx:w + 1 + dx]
            with np.errstate(invalid="ignore"):
                out |= np.abs(q - z) > r * z
    return out & np.isfinite(z)


@dataclasses.dataclass
class Scored:
    tp: int
    fp: int
    fn: int
    secs: float
    size_found: tuple[int, ...]
    det_found: int


def frame_truth(frame, zone):
    """(scored S, L ∩ S, size class code per pixel (0 outside L ∩ S), detectable ∩ L ∩ S)."""
    from scipy import ndimage

    from annotate.truth import SyntheticTruth

    t = SyntheticTruth(with_unknown=True).truth(frame, zone.located.valid)
    if isinstance(t, str):
        raise SystemExit(f"frame {frame.index}: {t}")
    s = t.reviewed & (zone.zone | zone.easy)
    lab = t.outliers & s
    comp, _ = ndimage.label(lab, structure=np.ones((3, 3), bool))
    size = np.bincount(comp.ravel())[comp]
    code = np.where(lab, np.searchsorted(np.array([1, 2, 10, 100]), size, side="right"), 0)
    det = (t.detectable if t.detectable is not None else np.zeros_like(lab)) & lab
    return s, lab, code, det


def score(pred: np.ndarray, s: np.ndarray, lab: np.ndarray, code: np.ndarray, det: np.ndarray, secs: float) -> Scored:
    p = pred & s
    tp = int(np.count_nonzero(p & lab))
    found = np.bincount(code[p & lab], minlength=5)[1:5]
    return Scored(tp, int(np.count_nonzero(p)) - tp, int(np.count_nonzero(lab)) - tp, secs,
                  tuple(int(v) for v in found), int(np.count_nonzero(det & p)))


def run_method(known, m, frame, zone, config, params):
    by: dict[str, dict] = {}
    for k, v in params.items():
        sec, f = _field(m, k)
        by.setdefault(sec, {})[f] = v
    c = config.replace(**{s: dataclasses.replace(getattr(config, s), **d) for s, d in by.items()}) if by else config
    t = time.process_time()
    mask = known[m].run(frame, zone, c).outliers
    return mask | zone.easy, time.process_time() - t


def run_extra(m: str, frame, params: dict) -> tuple[np.ndarray, float]:
    """A baseline on one frame: (mask, CPU seconds)."""
    assert m == "edges"
    t0 = time.process_time()
    return edges(frame.xyz, params["r"]), time.process_time() - t0


def f1(tp, fp, fn):
    d = 2 * tp + fp + fn
    return 2 * tp / d if d else math.nan


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--out", type=Path, default=None, help="folder for the two logs (default: a temporary one)")
    ap.add_argument("--markdown", action="store_true")
    args = ap.parse_args(argv)
    if not args.data.is_dir():
        print(f"error: {args.data} not found (docs/real_data.md, 'Stereo scenes')", file=sys.stderr)
        return 1
    from replay.pipeline.methods import registry
    from replay.pipeline.session import ReplaySession
    from zcut.metrics import pooled_interval_many

    known = registry()
    methods = [m for m in args.methods.split(",") if m]
    tmp = tempfile.TemporaryDirectory(prefix="zcut-stereo-") if args.out is None else None
    out = args.out if args.out is not None else Path(tmp.name)
    out.mkdir(parents=True, exist_ok=True)
    logs = {}
    for side, scenes in (("tune", TUNE), ("report", REPORT)):
        (out / side).mkdir(exist_ok=True)
        logs[side] = record(args.data, scenes, out / side)

    # --- tune: every set of every method on the tune frames
    session = ReplaySession.open(logs["tune"])
    config = session.config
    grids = {m: sets_of(m, config) for m in methods}
    grids["edges"] = [{"r": r} for r in EDGE_AXIS]
    extras = ["edges"]
    clock = MatcherClock(args.data, REPORT)
    tune: dict[str, list[list[Scored]]] = {m: [[] for _ in g] for m, g in grids.items()}
    for frame, zone in session.zones():
        s, lab, code, det = frame_truth(frame, zone)
        for m in methods:
            for i, params in enumerate(grids[m]):
                mask, secs = run_method(known, m, frame, zone, config, params)
                tune[m][i].append(score(mask, s, lab, code, det, secs))
        for m in extras:
            for i, params in enumerate(grids[m]):
                mask, secs = run_extra(m, frame, params)
                tune[m][i].append(score(mask, s, lab, code, det, secs))
        print(f"tuned on frame {frame.index} ({time.process_time():.0f} CPU-s so far)", file=sys.stderr, flush=True)
    best = {}
    for m, rows in tune.items():
        f = [f1(sum(r.tp for r in fr), sum(r.fp for r in fr), sum(r.fn for r in fr)) for fr in rows]
        i = int(np.nanargmax(np.where(np.isnan(f), -1, f)))
        best[m] = (grids[m][i], f[i])

    # --- report: the tuned and default sets on the report frames
    session = ReplaySession.open(logs["report"])
    config = session.config
    rep: dict[str, list[Scored]] = {}
    masks_keep: dict[str, list[np.ndarray]] = {}
    truths = []
    for frame, zone in session.zones():
        s, lab, code, det = frame_truth(frame, zone)
        truths.append((s, lab, code, det))
        for m in methods:
            for label, params in (("tuned", best[m][0]), ("default", {})):
                mask, secs = run_method(known, m, frame, zone, config, params)
                if m in POST:  # a recorded mask: its cost is the matcher's run with the post-filter
                    secs = clock.seconds(frame.index, dataclasses.asdict(
                        dataclasses.replace(getattr(config, m), **params)))
                rep.setdefault(f"{m}|{label}", []).append(score(mask, s, lab, code, det, secs))
                if label == "tuned":
                    masks_keep.setdefault(m, []).append(mask)
        for m in extras:
            mask, secs = run_extra(m, frame, best[m][0])
            rep.setdefault(f"{m}|tuned", []).append(score(mask, s, lab, code, det, secs))
        rep.setdefault("zone|-", []).append(score(s.copy(), s, lab, code, det, 0.0))
    # unions at the tuned sets: z-cut + the best other cloud method, the two best cloud methods, the best
    # post-filter + the best cloud method
    ranked = sorted((m for m in methods if m not in POST), key=lambda m: -np.nan_to_num(best[m][1], nan=-1))
    unions = []
    others = [m for m in ranked if m != "zcut"]
    if "zcut" in methods and others:
        unions.append(("zcut", others[0]))
    if len(ranked) >= 2 and tuple(ranked[:2]) not in unions and tuple(ranked[1::-1]) not in unions:
        unions.append(tuple(ranked[:2]))
    posts = sorted((m for m in methods if m in POST), key=lambda m: -np.nan_to_num(best[m][1], nan=-1))
    if posts and ranked:
        unions.append((posts[0], ranked[0]))
    for a, b in unions:
        for i, (s, lab, code, det) in enumerate(truths):
            rep.setdefault(f"{a}+{b}|tuned", []).append(
                score(masks_keep[a][i] | masks_keep[b][i], s, lab, code, det,
                      rep[f"{a}|tuned"][i].secs + rep[f"{b}|tuned"][i].secs))

    # --- table
    names = list(rep)
    tp = np.array([[r.tp for r in rep[n]] for n in names])
    fp = np.array([[r.fp for r in rep[n]] for n in names])
    fn = np.array([[r.fn for r in rep[n]] for n in names])
    ci = pooled_interval_many(tp, fp, fn)
    base = "zcut|tuned" if "zcut|tuned" in rep else None
    n_true = np.array([[int(np.count_nonzero(code == c)) for (_, _, code, _) in truths] for c in (1, 2, 3, 4)]).sum(axis=1)
    n_det = sum(int(det.sum()) for (_, _, _, det) in truths)

    def fmt(v, lo, hi):
        if not math.isfinite(v):
            return "-"
        return f"{v:.2f} [{lo:.2f}, {hi:.2f}]" if math.isfinite(lo) and math.isfinite(hi) else f"{v:.2f}"

    head = ["method", "set", "precision [95 %]", "recall [95 %]", "F1 [95 %]", "ΔF1 vs z-cut (min..max, won)",
            *(f"R {n}" for n in SIZE_NAMES), "R detectable", "CPU s/frame"]
    rows = []
    order = sorted(range(len(names)), key=lambda i: -np.nan_to_num(f1(tp[i].sum(), fp[i].sum(), fn[i].sum()), nan=-1))
    for i in order:
        n = names[i]
        m, label = n.split("|")
        P = tp[i].sum() / max(tp[i].sum() + fp[i].sum(), 1) if tp[i].sum() + fp[i].sum() else math.nan
        R = tp[i].sum() / (tp[i].sum() + fn[i].sum()) if tp[i].sum() + fn[i].sum() else math.nan
        F = f1(tp[i].sum(), fp[i].sum(), fn[i].sum())
        if base is not None and n != base:
            j = names.index(base)
            d = np.array([f1(tp[i, k], fp[i, k], fn[i, k]) - f1(tp[j, k], fp[j, k], fn[j, k]) for k in range(tp.shape[1])])
            diff = f"{np.nanmean(d):+.2f} ({np.nanmin(d):+.2f}..{np.nanmax(d):+.2f}, {int((d > 0).sum())}/{d.size})"
        else:
            diff = "-"
        found = np.array([r.size_found for r in rep[n]]).sum(axis=0)
        size_r = [f"{found[c] / n_true[c]:.2f}" if n_true[c] else "-" for c in range(4)]
        det_r = f"{sum(r.det_found for r in rep[n]) / n_det:.2f}" if n_det else "-"
        params = best[m][0] if label == "tuned" and m in best else {}
        set_txt = label if label != "tuned" else ("tuned " + ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}"
                                                                       for k, v in params.items())).strip()
        if label == "tuned" and m in best and not params:
            set_txt = "tuned (the default set)"
        rows.append([m, set_txt, fmt(P, *ci["precision"][i]), fmt(R, *ci["recall"][i]), fmt(F, *ci["f1"][i]), diff,
                     *size_r, det_r, f"{np.mean([r.secs for r in rep[n]]):.2f}"])
    scored = sum(int(s.sum()) for (s, _, _, _) in truths)
    n_lab = sum(int(lab.sum()) for (_, lab, _, _) in truths)
    print(f"report scenes: {', '.join(REPORT)}; tuned on {', '.join(TUNE)} (best pooled F1 of each method's grid)")
    print(f"{scored} scored pixels, {n_lab} true outliers ({100 * n_lab / scored:.1f} %): by component size "
          + ", ".join(f"{n} {100 * n_true[c] / n_lab:.0f} %" for c, n in enumerate(SIZE_NAMES))
          + f"; detectable {100 * n_det / n_lab:.1f} %")
    if args.markdown:
        print("| " + " | ".join(head) + " |")
        print("|" + "---|" * len(head))
        for r in rows:
            print("| " + " | ".join(r) + " |")
    else:
        widths = [max(len(r[k]) for r in [head, *rows]) for k in range(len(head))]
        for r in [head, *rows]:
            print("  ".join(c.ljust(w) for c, w in zip(r, widths)))
    print(f"CPU: {time.process_time():.0f} s in all")
    if tmp is not None:
        tmp.cleanup()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
