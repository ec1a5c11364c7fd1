"""Benchmark: the page's local surface against the edge-aware one (``zcut.edge_surface``), on the paper's truth.

Run: ``.venv/bin/python bench/bench_edge_surface.py [--work DIR] [--set tune|report|all] [--real DIR] [--png DIR]``

Synthetic 960 × 600 logs (``zcut synth``, two frames each; hand-made and ``--sensor raytraced``) of
seeds used nowhere else: 8711-8713 tuned the defaults of :class:`zcut.edge_surface.EdgeSurfaceParams`,
8721-8724 are reported. Each frame goes through the pipeline's bin stages (``ReplaySession.zones``,
the log's own bin model) and then, on the zone:

- **old**: the page's distance to the surface before this module, per pixel: a suspect's gap
  (``SuspectResult.gap_mm``: its residual to the nearest one-sided continuation, or for a mixed
  pixel, a blob's or an above-rim pixel, its gap to the median of the window around it), elsewhere
  the pixel's surface residual (``residual_mm``, what the page's ``rise`` shows);
- **new**: :func:`zcut.edge_surface.edge_aware_distance` of the frame (every valid point fits).

Pixels: the paper's truth (``/ground_truth/off_surface``) in the zone; **edge inliers** are the zone
pixels it calls inliers whose true depth (``/ground_truth/depth``) spans more than 2 mm over their
3 × 3 neighbourhood (a depth discontinuity of the true scene runs through them: a part's edge).
Printed per log: |old| and |new| of the edge inliers and of the outliers (median, 90th percentile)
and the IoU with the paper's truth (in the zone) of the best single threshold on each distance;
CPU ms per frame of ``edge_aware_distance``. Then the page itself: the gaps
(``SuspectResult.gap_mm``) of the suspects at edges the truth calls inliers and of the suspects it
calls outliers, without and with ``suspects(edge_surface=EdgeSurfaceParams())`` (median, 90th
percentile, share above τ), and for the groups the best IoU of one threshold on their gap and of
any per-group decision (zone and above-rim points).

``--real DIR``: the organized PCDs in DIR (the Kinect scans), recorded with ``zcut record``; zone =
every valid pixel; per scan the pixels each model puts farther than the suspects' τ from the
surface; ``--png DIR`` writes a side-by-side picture of both (outside the repository).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

ROOT = Path(__file__).resolve().parents[1]
SIZE = "960x600"
TUNE = (("zinc_nuts", 8711, "handmade"), ("black_nuts", 8712, "handmade"), ("spheres", 8713, "raytraced"))
REPORT = (("zinc_nuts", 8721, "handmade"), ("black_nuts", 8722, "handmade"), ("spheres", 8723, "raytraced"),
          ("zinc_nuts", 8724, "raytraced"))


def make_log(work: Path, kind: str, seed: int, sensor: str) -> Path:
    out = work / f"{kind}_{seed}_{sensor}.mcap"
    if not out.exists():
        subprocess.run([sys.executable, "-m", "cli", "synth", "-o", str(out), "--parts", kind, "--seed", str(seed),
                        "--size", SIZE, "--frames", "2", "--sensor", sensor], check=True, cwd=ROOT)
    return out


def true_depth_mm(log: Path, frame) -> np.ndarray | None:
    from mcap.reader import make_reader

    from replay.logs import layout
    from replay.logs import ros2_msgs as rm

    with open(log, "rb") as f:
        for _s, _c, message in make_reader(f).iter_messages(topics=[layout.TRUTH_DEPTH], starting_at=frame.stamp_ns,
                                                             ending_at=frame.stamp_ns):
            msg = rm.decode_image(message.data, where="depth")
            if msg.stamp_ns == frame.stamp_ns:
                return np.frombuffer(bytes(msg.data), dtype="<f4").reshape(msg.height, msg.width) * 1000.0
    return None


def edge_of(depth_mm: np.ndarray) -> np.ndarray:
    z = np.where(np.isfinite(depth_mm), depth_mm, 1e4)
    return (ndimage.maximum_filter(z, 3) - ndimage.minimum_filter(z, 3)) > 2.0


def old_distance(res) -> np.ndarray:
    """|the page's gap| where a suspect has one, else |surface residual| (inf: no continuation)."""
    gap = np.where(res.mask & np.isfinite(res.gap_mm), res.gap_mm, res.residual_mm)
    return np.abs(gap)


def best_iou(dist: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(IoU, threshold) of the best single threshold ``dist > t`` against ``truth`` (1-D, same pixels)."""
    d = np.where(np.isnan(dist), -np.inf, dist)
    order = np.argsort(-d, kind="stable")
    tp = np.cumsum(truth[order])
    k = np.arange(1, d.size + 1)
    iou = tp / (truth.sum() + k - tp)
    # a threshold can only fall between different values
    last = np.r_[d[order][1:] != d[order][:-1], True]
    iou = np.where(last, iou, -1.0)
    i = int(np.argmax(iou))
    nxt = d[order][i + 1] if i + 1 < d.size else -np.inf
    return float(iou[i]), float(0.5 * (d[order][i] + nxt)) if np.isfinite(nxt) else float(d[order][i])


def pct(a: np.ndarray) -> str:
    a = a[~np.isnan(a)]
    if a.size == 0:
        return "–"
    return f"{np.median(a):.2f} / {np.percentile(a, 90):.2f}"


def group_iou(res, truth: np.ndarray, region: np.ndarray) -> tuple[float, float]:
    """(best IoU of one threshold on the groups' |gap|, best IoU of any per-group decision) in ``region``."""
    g = np.where(region, res.groups, 0)
    n = res.n_groups
    size = np.bincount(g.ravel(), minlength=n + 1)[1:]
    hit = np.bincount(g.ravel(), weights=truth.ravel() & region.ravel(), minlength=n + 1)[1:]
    total = int((truth & region).sum())
    gap = np.where(np.isnan(res.group_gap_mm), np.inf, np.abs(res.group_gap_mm))
    order = np.argsort(-gap, kind="stable")
    tp = np.cumsum(hit[order])
    k = np.cumsum(size[order])
    iou = tp / np.maximum(total + k - tp, 1)
    last = np.r_[gap[order][1:] != gap[order][:-1], True] if n else np.zeros(0, bool)
    best = float(max(iou[last].max(initial=0.0), 0.0))
    take = 2 * hit >= size
    oracle = float(hit[take].sum() / max(total + size[take].sum() - hit[take].sum(), 1))
    return best, oracle


def run_log(log: Path, params) -> dict:
    from replay.logs import layout
    from replay.pipeline.session import ReplaySession
    from zcut.edge_surface import edge_aware_distance
    from zcut.params import SuspectParams
    from zcut.suspects import suspects

    session = ReplaySession.open(log)
    acc: dict = {"ei_old": [], "ei_new": [], "out_old": [], "out_new": [], "old": [], "new": [], "truth": [],
                 "cpu": [], "tau": [], "ei_tau": [], "groups": [], "sei_old": [], "sei_new": [], "so_old": [],
                 "so_new": []}
    for frame, z in session.zones():
        valid = np.isfinite(frame.xyz).all(axis=2)
        zone = z.zone & valid
        truth = frame.masks[layout.TRUTH_OFF_SURFACE] & valid
        depth = true_depth_mm(log, frame)
        edge = edge_of(depth) if depth is not None else np.zeros_like(zone)
        res = suspects(frame.xyz, z.height_mm, z.zone, z.easy, params=SuspectParams(a_max=session.config.zcut.a_max))
        old = old_distance(res)
        xyz_mm = frame.xyz.astype(np.float64) * 1000.0
        c = time.process_time()
        new = edge_aware_distance(xyz_mm, valid, params=params)
        acc["cpu"].append(time.process_time() - c)
        ei = zone & edge & ~truth
        acc["ei_old"].append(old[ei])
        acc["ei_new"].append(new[ei])
        acc["out_old"].append(old[zone & truth])
        acc["out_new"].append(new[zone & truth])
        acc["old"].append(old[zone])
        acc["new"].append(new[zone])
        acc["truth"].append(truth[zone])
        acc["tau"].append(res.threshold_mm)
        acc["ei_tau"].append(((old[ei] > res.threshold_mm).sum(), (new[ei] > res.threshold_mm).sum(), int(ei.sum())))
        res_new = suspects(frame.xyz, z.height_mm, z.zone, z.easy, params=SuspectParams(a_max=session.config.zcut.a_max),
                           edge_surface=params)
        region = (z.zone | z.easy) & valid
        acc["groups"].append((*group_iou(res, truth, region), *group_iou(res_new, truth, region)))
        sus = res.mask & region
        sei, so = sus & edge & ~truth, sus & truth
        acc["sei_old"].append(np.abs(res.gap_mm[sei]))
        acc["sei_new"].append(np.abs(res_new.gap_mm[sei]))
        acc["so_old"].append(np.abs(res.gap_mm[so]))
        acc["so_new"].append(np.abs(res_new.gap_mm[so]))
    skip = ("cpu", "tau", "ei_tau", "groups")
    out = {k: np.concatenate(v) for k, v in acc.items() if k not in skip}
    out["groups"] = np.mean(acc["groups"], axis=0)
    out["cpu_ms"] = 1000.0 * float(np.mean(acc["cpu"]))
    out["tau"] = float(np.mean(acc["tau"]))
    s = np.sum(acc["ei_tau"], axis=0)
    out["ei_above_tau"] = (s[0] / max(s[2], 1), s[1] / max(s[2], 1))
    return out


def report(name: str, r: dict) -> None:
    io, to = best_iou(r["old"], r["truth"])
    inw, tn = best_iou(r["new"], r["truth"])
    print(f"| {name} | {r['ei_old'].size} | {pct(r['ei_old'])} | {pct(r['ei_new'])} | "
          f"{r['out_old'].size} | {pct(r['out_old'])} | {pct(r['out_new'])} | "
          f"{io:.3f} (t {to:.2f}) | {inw:.3f} (t {tn:.2f}) | {r['cpu_ms']:.0f} |", flush=True)


def report_page(name: str, r: dict) -> None:
    tau = r["tau"]

    def above(a: np.ndarray) -> str:
        return f"{np.mean(a > tau):.0%}" if a.size else "–"

    print(f"| {name} | {r['sei_old'].size} | {pct(r['sei_old'])} → {pct(r['sei_new'])} | "
          f"{above(r['sei_old'])} → {above(r['sei_new'])} | {r['so_old'].size} | {pct(r['so_old'])} → "
          f"{pct(r['so_new'])} | {above(r['so_old'])} → {above(r['so_new'])} | "
          f"{r['groups'][0]:.3f} → {r['groups'][2]:.3f} | {r['groups'][1]:.3f} → {r['groups'][3]:.3f} |", flush=True)


def run_real(src: Path, work: Path, png: Path | None, params) -> None:
    from replay.logs.reader import LogReader
    from zcut.edge_surface import edge_aware_distance
    from zcut.params import SuspectParams
    from zcut.suspects import suspects

    log = work / "real_scans.mcap"
    if not log.exists():
        pcds = sorted(str(p) for p in src.glob("*.pcd"))
        subprocess.run([sys.executable, "-m", "cli", "record", *pcds, "-o", str(log)], check=True, cwd=ROOT)
    print(f"\nreal scans ({src}, no truth; zone = every valid pixel): pixels farther than the suspects' τ")
    print("| scan | size | valid | σ̂ mm | τ mm | old > τ | new > τ | new inf | both | CPU ms |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for frame in LogReader(log).frames():
        valid = np.isfinite(frame.xyz).all(axis=2)
        height = -1000.0 * frame.xyz[..., 2].astype(np.float64)
        res = suspects(frame.xyz, height, valid, params=SuspectParams())
        old = old_distance(res)
        c = time.process_time()
        new = edge_aware_distance(frame.xyz.astype(np.float64) * 1000.0, valid, params=params)
        cpu = 1000.0 * (time.process_time() - c)
        tau = res.threshold_mm
        o, n = valid & (old > tau), valid & (new > tau)
        H, W = valid.shape
        print(f"| {frame.index} | {W}x{H} | {int(valid.sum())} | {res.noise_mm:.2f} | {tau:.2f} | {int(o.sum())} | "
              f"{int(n.sum())} | {int((valid & np.isinf(new)).sum())} | {int((o & n).sum())} | {cpu:.0f} |", flush=True)
        if png is not None:
            import cv2

            png.mkdir(parents=True, exist_ok=True)
            h = np.where(valid, height, np.nan)
            lo, hi = np.nanpercentile(h, [1, 99])
            g = np.clip((np.nan_to_num(h, nan=lo) - lo) / max(hi - lo, 1e-9) * 200, 0, 200).astype(np.uint8)
            tiles = []
            for m in (o, n):
                t = cv2.cvtColor(g, cv2.COLOR_GRAY2BGR)
                t[m] = (0, 0, 255)
                tiles.append(t)
            cv2.imwrite(str(png / f"real_{frame.index:02d}.png"), np.concatenate(tiles, axis=1))


def main(argv: list[str] | None = None) -> int:
    from zcut.edge_surface import EdgeSurfaceParams, edge_aware_distance

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--work", type=Path, default=Path("/tmp/edge_work"))
    p.add_argument("--set", choices=("tune", "report", "all"), default="report")
    p.add_argument("--real", type=Path, default=None)
    p.add_argument("--png", type=Path, default=None)
    p.add_argument("--param", action="append", default=[], help="NAME=VALUE of EdgeSurfaceParams (tuning)")
    args = p.parse_args(argv)
    kw = {}
    for item in args.param:
        k, v = item.split("=")
        kw[k] = float(v) if "." in v else int(v)
    params = EdgeSurfaceParams(**kw)
    args.work.mkdir(parents=True, exist_ok=True)
    edge_aware_distance(np.zeros((8, 8, 3)) + 1.0, np.ones((8, 8), bool))  # compile / load the kernels
    sets = {"tune": TUNE, "report": REPORT, "all": TUNE + REPORT}[args.set]
    print(f"{SIZE}, {params}")
    print("\nPer pixel, in the zone (|distance| mm: median / 90th percentile):")
    print("| log | edge inliers | old | new | outliers | old | new | best IoU old | best IoU new | CPU ms/frame |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    results = []
    for kind, seed, sensor in sets:
        log = make_log(args.work, kind, seed, sensor)
        r = run_log(log, params)
        results.append((f"{kind} {seed} {sensor}", r))
        report(results[-1][0], r)
    print("\nThe page: the suspects' gaps (|gap| mm: median / 90th percentile, old → new; share above τ) and "
          "the groups (zone + above-rim points):")
    print("| log | suspect edge inliers | gap | > τ | suspect outliers | gap | > τ | "
          "best gap threshold IoU | best per-group decision IoU |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, r in results:
        report_page(name, r)
    if args.real is not None:
        run_real(args.real, args.work, args.png, params)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
