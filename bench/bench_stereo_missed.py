"""What could show the stereo scenes' true outliers that the labelling page's review groups miss (issue 29; the split
of docs/labelling_real.md, "The sensor's own masks on the page", h/real3).

For every frame of a ``zcut record-stereo`` log the page's review groups are computed as the page computes them
(:func:`bench_stereo_patches.frames_of`: the default methods, zcut and sor, unless ``--methods``), and the true outliers
(``/ground_truth/outliers`` inside the page's zone, ``/ground_truth/unknown`` left out) that no group holds are split
by what the log alone could show of them:

- the sensor's own masks, as recorded (``/stereo/rejected/...``: the uniqueness test, the speckle filter, the
  left-right check of :func:`zcut.stereo.left_right_rejected`), and the page's filter methods;
- the smooth piece each pixel belongs to (:func:`bench_stereo_patches.smooth_patches` at the suspects' own jump, the
  patch detector's pieces): its size in units of a_max (1 % of the frame), whether a depth step bounds at least half
  of its border (else unmeasured pixels or the image's border do), and the frame's largest piece (the main surface);
- the group budget: the suspect pixels the groups leave out.

Per cue: its pixels in the zone, its precision (the truth's share of them), the share of the missed truth it holds
and its precision among the pixels no group holds.

    PYTHONPATH=. .venv/bin/python bench/bench_stereo_missed.py --log STEREO.mcap --scenes A,B,… --frames 1,2,3,9
        [--methods LIST] [--json F]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_stereo_patches import frames_of, smooth_patches  # noqa: E402

#: piece sizes (× a_max) the split reports
SIZE_EDGES = (0.0, 0.3, 1.0, 3.0, 10.0, 30.0, float("inf"))


def split_frame(frame, r, zone, valid, g) -> tuple[dict, list[dict]]:  # type: ignore[no-untyped-def]  # bench helper
    from replay.logs import layout
    from zcut.params import SuspectParams
    from zcut.suspects.noise import noise_profile
    from zcut.suspects.union import _sigma_px

    region = zone & valid & ~frame.masks[layout.TRUTH_UNKNOWN]
    P = frame.masks[layout.TRUTH_OUTLIERS] & region
    held = g.ids > 0
    miss = P & ~held
    head = {"truth_px": int(P.sum()), "held": float((P & held).sum() / max(P.sum(), 1)), "missed_px": int(miss.sum()),
            "groups": g.n, "suspect_px": int(g.n_suspect_px), "group_px": int(held.sum())}
    rows = []

    def cue(name: str, m: np.ndarray) -> None:
        m = m & region
        rows.append({"cue": name, "px": int(m.sum()), "precision": float((m & P).sum() / max(m.sum(), 1)),
                     "missed_share": float((m & miss).sum() / max(miss.sum(), 1)),
                     "precision_not_held": float((m & miss).sum() / max((m & ~held).sum(), 1))})

    for k, v in frame.masks.items():
        if k.startswith("/stereo/rejected/"):
            cue("sensor " + k[len("/stereo/rejected/"):], np.asarray(v, bool))
    for k, v in r.outliers.items():
        cue("method " + k, np.asarray(v, bool))
    h = np.where(valid, -1000.0 * frame.xyz[..., 2].astype(np.float64), np.nan)
    sp = SuspectParams()
    jump = np.maximum(sp.jump_mm, sp.noise_k * _sigma_px(noise_profile(h, zone), h))
    lab = smooth_patches(h, valid, jump)
    H, W = h.shape
    n = int(lab.max())
    size = np.bincount(lab.ravel(), minlength=n + 1)
    size[0] = 0
    steps = np.zeros(n + 1)
    opn = np.zeros(n + 1)
    pl = np.pad(lab, 1)
    for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        nb = pl[1 + dr:1 + dr + H, 1 + dc:1 + dc + W]
        steps += np.bincount(lab[valid & (nb > 0) & (nb != lab)], minlength=n + 1)
        opn += np.bincount(lab[valid & (nb == 0)], minlength=n + 1)
    stepped = (steps >= 0.5 * (steps + opn)) & (steps > 0)
    a_max = 0.01 * H * W
    largest = int(np.argmax(size))
    sz = size[lab] / a_max
    head.update({"a_max_px": a_max, "largest_piece_px": int(size[largest])})
    rest = valid & (lab != largest)
    for lo, hi in zip(SIZE_EDGES[:-1], SIZE_EDGES[1:]):
        for s, tag in ((True, "step ≥ ½ border"), (False, "step < ½ border")):
            cue(f"piece {lo:g}–{hi:g} a_max, {tag}", rest & (sz > lo) & (sz <= hi) & (stepped[lab] == s))
    cue("the largest piece (main surface)", valid & (lab == largest))
    return head, rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", type=Path, required=True, help="a zcut record-stereo log")
    ap.add_argument("--scenes", default="", help="the scenes' names, in the log's frame order")
    ap.add_argument("--frames", default="", help="frame indices (default: all)")
    ap.add_argument("--methods", default="", help="the page's filter methods (zcut annotate --methods)")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args(argv)
    scenes = [s for s in a.scenes.split(",") if s]
    wanted = {int(v) for v in a.frames.split(",") if v} or None
    out = []
    for frame, r, zone, valid, g, _ in frames_of(a.log, wanted, a.methods or None):
        name = scenes[frame.index] if frame.index < len(scenes) else str(frame.index)
        head, rows = split_frame(frame, r, zone, valid, g)
        print(f"\n{name}: truth {head['truth_px']:,} px, held {head['held']:.3f}, missed {head['missed_px']:,}; "
              f"{head['groups']} groups hold {head['group_px']:,} px of {head['suspect_px']:,} suspect px; a_max "
              f"{head['a_max_px']:.0f} px, largest piece {head['largest_piece_px']:,} px")
        print("| cue | px | precision | share of the missed truth | precision outside the groups |")
        print("|---|---|---|---|---|")
        for c in rows:
            if c["px"]:
                print(f"| {c['cue']} | {c['px']:,} | {c['precision']:.2f} | {c['missed_share']:.3f} | "
                      f"{c['precision_not_held']:.2f} |")
        out.append({"scene": name, **head, "cues": rows})
    if a.json:
        a.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
