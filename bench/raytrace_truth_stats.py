"""What the truth of synthetic logs holds, per outlier kind: the table of docs/raytraced.md.

    .venv/bin/python bench/raytrace_truth_stats.py LOG.mcap [LOG.mcap ...]

For each log (hand-made or ray-traced; ``zcut synth [--sensor raytraced]``), per frame means of:
the true outliers per kind code (pixels / 8-connected components), the share of outlier pixels
whose measured point lies toward the camera from the true surface (``toward%``: Figure 1's
"bright pixels ... unusually small depth"), the median component size relative to the part's
a_max (``size/a_max``), the share of outlier pixels in components of at least mu_thr = 0.07 a_max
pixels (``>=mu%``: out of the nominal z-cut's reach), the median |measured - true depth| of the outliers (``|dz| mm``) and the share of them within 1 mm of it (``<1mm%``), the share
of valid pixels that are outliers (``rate%``) and of pixels with no measurement (``nan%``). The
true depth is the log's ``/ground_truth/depth``; a_max is the log's ``zcut.synth`` metadata.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy import ndimage

from replay.logs import layout
from replay.logs.reader import LogReader
from replay.synth.truth_depth import read_truth_depth

EIGHT = np.ones((3, 3), bool)


def log_stats(path: Path) -> dict:
    reader = LogReader(path)
    meta = reader.metadata.get(layout.SYNTH_METADATA, {})
    a_max = float(meta.get("a_max_px", "nan"))
    depth = read_truth_depth(path)
    px: dict[int, float] = {}
    comp: dict[int, float] = {}
    sizes: list[float] = []
    big_px = 0
    toward = n_out = 0
    dz: list[np.ndarray] = []
    valid_n = nan_n = total = 0
    frames = 0
    for f in reader.frames():
        frames += 1
        kinds = f.codes[layout.TRUTH_OUTLIER_KIND]
        z = f.xyz[..., 2].astype(np.float64)
        zt = depth[f.stamp_ns].astype(np.float64)
        valid = np.isfinite(z)
        valid_n += int(valid.sum())
        nan_n += int((~valid).sum())
        total += z.size
        for c in np.unique(kinds[kinds > 0]):
            m = kinds == c
            lab, n = ndimage.label(m, structure=EIGHT)
            px[int(c)] = px.get(int(c), 0) + int(m.sum())
            comp[int(c)] = comp.get(int(c), 0) + n
            area = np.bincount(lab.ravel())[1:]
            sizes.extend(area.tolist())
            big_px += int(area[area >= 0.07 * a_max].sum())
        out = kinds > 0
        n_out += int(out.sum())
        toward += int((z[out] < zt[out]).sum())
        dz.append(np.abs(z[out] - zt[out]) * 1000.0)
    dzs = np.concatenate(dz) if dz else np.zeros(0)
    return {
        "kind": meta.get("part_kind", "?"), "sensor": meta.get("sensor", "handmade"), "frames": frames,
        "px": {c: v / frames for c, v in px.items()}, "comp": {c: v / frames for c, v in comp.items()},
        "toward": 100.0 * toward / n_out if n_out else float("nan"),
        "big": 100.0 * big_px / n_out if n_out else float("nan"),
        "size": float(np.median(sizes)) / a_max if sizes else float("nan"),
        "dz": float(np.median(dzs)) if dzs.size else float("nan"),
        "small": 100.0 * float((dzs < 1.0).mean()) if dzs.size else float("nan"),
        "rate": 100.0 * n_out / valid_n if valid_n else float("nan"),
        "nan": 100.0 * nan_n / total,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("logs", nargs="+", type=Path)
    args = ap.parse_args()
    codes = sorted(layout.OUTLIER_KINDS)
    print("| log | sensor | kind | " + " | ".join(layout.OUTLIER_KINDS[c] for c in codes)
          + " | toward% | size/a_max | >=mu% | abs dz mm | <1mm% | rate% | nan% |")
    print("|---" * (len(codes) + 10) + "|")
    for p in args.logs:
        s = log_stats(p)
        cells = " | ".join(f"{s['px'][c]:.0f} / {s['comp'][c]:.0f}" if c in s["px"] else "-" for c in codes)
        print(f"| {p.name} | {s['sensor']} | {s['kind']} | {cells} | {s['toward']:.0f} | {s['size']:.4f} | {s['big']:.0f} | "
              f"{s['dz']:.2f} | {s['small']:.0f} | {s['rate']:.2f} | {s['nan']:.1f} |")


if __name__ == "__main__":
    main()
