"""What the synthetic truth holds, and what the paper's two filters find in it, per part kind.

    .venv/bin/python bench/synth_truth_stats.py [--size 1920x1200] [--frames 2] [--seed 0] [--kinds a,b]
        [--quantize-mm Q] [--region whole,zone]

For each part kind, ``--frames`` frames of one seeded log (``synthesize_frame(kind, seed, index)``):

- the true outliers per kind code (docs/formats.md): pixels and 8-connected components, per frame;
- the paper's nominal z-cut, ``zcut_outliers(-1000·z, step=0.2, max_depth=30, max_area=0.07·a_max)``,
  and SOR, ``sor_outliers(xyz, k=4, std_ratio=1.0)``: recall per kind (found / true pixels) and
  false-positive components per frame (8-connected components of the prediction with less than
  half of their pixels true outliers, docs/accuracy.md), on two regions:
  ``whole`` = the whole frame (what ``zcut replay`` does without an RGB image or a bin model);
  ``zone`` = a stand-in for the paper's §5.2 with a perfect bin removal: only pixels whose real
  surface is a part or the bin floor, minus the points above the rim (the removal flags those);
- how many of the zone's z-cut false positives are the Figure-11 patches (``fig11``), the
  generator's calibrated traps (paper §5.4: two such clusters in an M8-screw scan, none in the six
  datasets), and the share of shiny part pixels whose colour saturates (``sat%``);
- the floating clusters' spread: the share at least μ_thr = 0.07·a_max pixels (``>=mu%``, which
  the nominal z-cut cannot tag), the share whose real surface lies more than 30 mm below the
  highest part (``deep%``, beyond the nominal d_max when nothing floats higher), and the pile's
  depth in layers of the part's smallest edge (``layers``: highest part above the floor / p_min).

Counts are totals over the frames divided by the number of frames.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy import ndimage

from replay.logs.layout import OUTLIER_KINDS
from replay.presets import BIN, PART_KINDS
from replay.synth import CAMERA_HEIGHT_MM, LABEL_FLOOR, LABEL_PART, OUTLIER_ABOVE_RIM, synthesize_frame
from zcut.cuts import zcut_outliers
from zcut.sor import sor_outliers

EIGHT = np.ones((3, 3), bool)
CODES = sorted(OUTLIER_KINDS)


def false_positive_components(pred: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, int]:
    """Labels of ``pred``'s components and the ids of those with < 50 % true pixels."""
    lab, n = ndimage.label(pred, structure=EIGHT)
    area = np.bincount(lab.ravel(), minlength=n + 1)
    hit = np.bincount(lab.ravel(), weights=truth.ravel(), minlength=n + 1)
    bad = np.flatnonzero(hit[1:] < 0.5 * area[1:]) + 1
    return lab, bad


def components(mask: np.ndarray) -> int:
    return int(ndimage.label(mask, structure=EIGHT)[1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="1920x1200")
    ap.add_argument("--frames", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--kinds", default=",".join(PART_KINDS))
    ap.add_argument("--quantize-mm", type=float, default=0.0)
    ap.add_argument("--region", default="whole,zone")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    regions = args.region.split(",")
    names = [OUTLIER_KINDS[c] for c in CODES]
    print(f"size {w}x{h}, seed {args.seed}, frames 0..{args.frames - 1}, quantize {args.quantize_mm:g} mm; "
          f"per-frame means; recall = found/true pixels of that kind; fp = false-positive components")
    print()
    print("true outliers per frame: pixels / components")
    print(f"{'kind':13s} " + " ".join(f"{n:>15s}" for n in names)
          + f" {'sat%':>6s} {'>=mu%':>6s} {'deep%':>6s} {'layers':>6s} {'cpu s':>6s}")
    rows = {}
    for kind in args.kinds.split(","):
        acc = {r: {"zc_found": np.zeros(6), "so_found": np.zeros(6), "zc_fp": 0, "so_fp": 0, "fig11": 0,
                   "n": np.zeros(6)} for r in regions}
        px = np.zeros(6)
        comp = np.zeros(6)
        sat, shiny_px, cpu = 0, 0, 0.0
        n_clusters, big, deep, layers = 0, 0, 0, 0.0
        for i in range(args.frames):
            c0 = time.process_time()
            sf = synthesize_frame(kind=kind, seed=args.seed, index=i, size=(h, w), quantize_mm=args.quantize_mm)
            cpu += time.process_time() - c0
            kinds = sf.outlier_kind
            for c in CODES:
                m = kinds == c
                px[c] += m.sum()
                comp[c] += components(m)
            surf_h = CAMERA_HEIGHT_MM - sf.surface_depth_mm.astype(np.float64)
            top = surf_h[sf.surface == LABEL_PART].max()
            layers += (top - BIN.floor_mm) / PART_KINDS[kind].p_min_mm
            ids = np.unique(sf.cluster_id[sf.cluster_id > 0])
            if ids.size:
                area = np.bincount(sf.cluster_id.ravel())[ids]
                under = ndimage.median(surf_h, sf.cluster_id, ids)
                n_clusters += ids.size
                big += int((area >= 0.07 * sf.a_max_px).sum())
                deep += int((top - np.asarray(under) > 30.0).sum())
            if sf.shiny:
                part = sf.surface == LABEL_PART
                sat += int((sf.saturated & part).sum())
                shiny_px += int(part.sum())
            for r in regions:
                xyz = sf.frame.xyz.copy()
                if r == "zone":
                    roi = ((sf.surface == LABEL_PART) | (sf.surface == LABEL_FLOOR)) & (kinds != OUTLIER_ABOVE_RIM)
                    xyz[~roi] = np.nan
                else:
                    roi = np.ones(kinds.shape, bool)
                zc = zcut_outliers(-1000.0 * xyz[..., 2].astype(np.float64), step=0.2, max_depth=30.0,
                                   max_area=0.07 * sf.a_max_px)
                so = sor_outliers(xyz, k=4, std_ratio=1.0)
                a = acc[r]
                truth = sf.truth & roi
                for c in CODES:
                    m = (kinds == c) & roi
                    a["n"][c] += m.sum()
                    a["zc_found"][c] += (zc & m).sum()
                    a["so_found"][c] += (so & m).sum()
                lab, bad = false_positive_components(zc, truth)
                a["zc_fp"] += len(bad)
                a["fig11"] += len(np.intersect1d(bad, np.unique(lab[sf.figure11 & zc])))
                a["so_fp"] += len(false_positive_components(so, truth)[1])
        nf = args.frames
        cells = " ".join(f"{px[c] / nf:8.0f} /{comp[c] / nf:5.0f}" for c in CODES)
        satp = f"{100 * sat / shiny_px:6.2f}" if shiny_px else f"{'-':>6s}"
        spread = (f"{100 * big / n_clusters:6.0f} {100 * deep / n_clusters:6.0f}" if n_clusters
                  else f"{'-':>6s} {'-':>6s}")
        print(f"{kind:13s} {cells} {satp} {spread} {layers / nf:6.1f} {cpu / nf:6.2f}")
        rows[kind] = acc
    for r in regions:
        print()
        print(f"region {r}: recall per kind as z-cut/SOR, false-positive components per frame")
        print(f"{'kind':13s} " + " ".join(f"{n:>11s}" for n in names) + f" | {'zc fp':>6s} {'fig11':>6s} {'sor fp':>7s}")
        for kind, acc in rows.items():
            a = acc[r]

            def rec(found, c, a=a):
                return f"{found[c] / a['n'][c]:.2f}" if a["n"][c] else "-"

            cells = " ".join(f"{rec(a['zc_found'], c) + '/' + rec(a['so_found'], c):>11s}" for c in CODES)
            nf = args.frames
            print(f"{kind:13s} {cells} | {a['zc_fp'] / nf:6.1f} {a['fig11'] / nf:6.1f} {a['so_fp'] / nf:7.1f}")


if __name__ == "__main__":
    main()
