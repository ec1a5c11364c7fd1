"""``zcut record-stereo SCENE_DIR... -o LOG.mcap``: rectified stereo pairs with ground truth -> a log.

Each scene folder (Middlebury 2014's layout by default: ``im0.png``, ``im1.png``, ``calib.txt``,
optional ``disp0GT.pfm`` and ``mask0nocc.png``; flags for other layouts) is matched by a stereo
matcher (``--matcher sgbm`` by default, or ``bm``; their own post-filters off unless asked) and
becomes one frame: the organized cloud in metres (NaN where unmatched) on ``/camera/points``, the
left image, its CameraInfo and, with a ground truth, ``/ground_truth/depth`` (32FC1),
``/ground_truth/outliers`` (|Z − Z_GT| > τ_d · Z_GT² / (f · B)), ``/ground_truth/unknown`` (truth
unknown or occluded: not scored) and ``/ground_truth/detectable`` (docs/formats.md, docs/real_data.md).
τ_d (``--tau-px``), the matcher and every frame's calibration are in the log's ``zcut.stereo``
metadata.

The matcher's own post-filters are scored as methods (``stereo_uniqueness``, ``stereo_lr``,
``stereo_speckle``, ``stereo_texture``; replay/pipeline/stereo_methods.py): for each post-filter, at
each strength asked for (``--reject-uniqueness`` ...; one default strength each unless told), the
matcher is run again with that filter on, and the pixels of the cloud it invalidates are written as
``/stereo/rejected/<settings>`` (mono8), their settings in the metadata's ``rejected``.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from replay.logs import layout

if TYPE_CHECKING:
    from zcut.stereo import PostFilter


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenes", nargs="+", metavar="SCENE_DIR",
                        help="scene folders (Middlebury layout: im0.png, im1.png, calib.txt, disp0GT.pfm, mask0nocc.png)")
    parser.add_argument("-o", "--output", required=True, metavar="LOG.mcap", help="the log to write")
    parser.add_argument("--force", action="store_true", help="replace the output if it exists")
    g = parser.add_argument_group("other layouts (file names relative to each scene folder, or absolute)")
    g.add_argument("--left", metavar="FILE", help="left image (default im0.png)")
    g.add_argument("--right", metavar="FILE", help="right image (default im1.png)")
    g.add_argument("--calib", metavar="FILE", help="Middlebury calib.txt (default calib.txt)")
    g.add_argument("--gt", metavar="FILE",
                   help="ground-truth disparity of the left view: .pfm, .png (with --gt-scale) or .npy "
                        "(default disp0GT.pfm when present)")
    g.add_argument("--gt-scale", type=float, metavar="S", help="a PNG (or integer NPY) ground truth holds disparity × S")
    g.add_argument("--occlusion", metavar="FILE",
                   help="mask image, 255 where the truth may be judged (default mask0nocc.png when present)")
    g.add_argument("--focal", type=float, metavar="PX", help="focal length (px), instead of calib.txt's cam0")
    g.add_argument("--baseline", type=float, metavar="MM", help="baseline (mm)")
    g.add_argument("--doffs", type=float, metavar="PX", help="x-difference of the principal points (px; default 0)")
    g.add_argument("--cx", type=float, metavar="PX", help="principal point x of the left image (px)")
    g.add_argument("--cy", type=float, metavar="PX", help="principal point y (px)")
    m = parser.add_argument_group("matcher")
    m.add_argument("--matcher", choices=("sgbm", "bm"), default="sgbm", help="OpenCV's StereoSGBM (default) or StereoBM")
    m.add_argument("--num-disparities", type=int, metavar="N",
                   help="search range, a multiple of 16 (default: calib.txt's ndisp rounded up, else 128)")
    m.add_argument("--block-size", type=int, metavar="N", help="block size, odd (default 5 for sgbm, 9 for bm)")
    m.add_argument("--uniqueness", type=int, default=0, metavar="PCT", help="post-filter: uniqueness ratio (default 0: off)")
    m.add_argument("--disp12-max-diff", type=int, default=-1, metavar="PX",
                   help="post-filter: left-right check (default -1: off)")
    m.add_argument("--speckle-window", type=int, default=0, metavar="PX",
                   help="post-filter: speckle filter window (default 0: off)")
    m.add_argument("--speckle-range", type=int, default=2, metavar="PX", help="speckle filter range (default 2)")
    m.add_argument("--texture-threshold", type=int, default=0, metavar="N",
                   help="post-filter (bm only): texture threshold (default 0: off)")
    r = parser.add_argument_group(
        "the matcher's post-filters as methods to score (each LIST: values a,b,c; 'none' records none)")
    r.add_argument("--reject-uniqueness", metavar="LIST",
                   help="uniqueness ratios (%%) whose rejected pixels are recorded, for the method stereo_uniqueness "
                        "(default 10)")
    r.add_argument("--reject-lr", metavar="LIST",
                   help="left-right check tolerances (px: the right view matched on its own, zcut.stereo.left_right_rejected), "
                        "for the method stereo_lr (default 1)")
    r.add_argument("--reject-speckle", metavar="LIST",
                   help="speckle filter settings WINDOW:RANGE (px), for the method stereo_speckle (default 100:2)")
    r.add_argument("--reject-texture", metavar="LIST",
                   help="texture thresholds, for the method stereo_texture (bm only; default 10 with --matcher bm)")
    r.add_argument("--reject-axes", action="store_true",
                   help="also every point of each of these methods' default sweep axes (zcut sweep --grid "
                        "stereo_uniqueness=default ...)")
    r.add_argument("--no-rejected", action="store_true", help="record no post-filter's rejected pixels")
    parser.add_argument("--tau-px", type=float, default=1.0, metavar="PX",
                        help="truth tolerance τ_d in px of disparity: an outlier is |Z - Z_GT| > τ_d·Z²/(f·B) (default 1)")
    parser.add_argument("--frame-id", default="camera_optical_frame", help="header frame_id (default camera_optical_frame)")


def _num_disparities(args: argparse.Namespace, ndisp: int | None) -> int:
    if args.num_disparities is not None:
        return int(args.num_disparities)
    return 128 if ndisp is None else max(16, -(-int(ndisp) // 16) * 16)


#: the flag of each post-filter method (zcut.stereo.POST_FILTERS)
REJECT_FLAGS = {"stereo_uniqueness": "reject_uniqueness", "stereo_lr": "reject_lr", "stereo_speckle": "reject_speckle",
                "stereo_texture": "reject_texture"}


def post_filter_sets(args: argparse.Namespace) -> list[tuple[str, PostFilter]]:
    """``[(method, settings), ...]``: the post-filter strengths whose rejected pixels are recorded, in
    the order of ``zcut.stereo.POST_FILTERS`` and as given, each once.

    Raises
    ------
    ConfigError
        A value that is not integers ``a:b`` of the filter's fields, one its settings class refuses,
        the texture threshold with SGBM.
    """
    from replay.errors import ConfigError
    from replay.pipeline.methods import registry
    from zcut.errors import ParameterError
    from zcut.stereo import POST_FILTERS

    if args.no_rejected:
        given = [f"--{f.replace('_', '-')}" for f in (*REJECT_FLAGS.values(), "reject_axes") if getattr(args, f)]
        if given:
            raise ConfigError(f"--no-rejected records no post-filter: leave out {', '.join(given)}")
        return []
    out: list[tuple[str, PostFilter]] = []
    for name, cls in POST_FILTERS.items():
        flag = "--" + REJECT_FLAGS[name].replace("_", "-")
        text = getattr(args, REJECT_FLAGS[name])
        fields = [f.name for f in dataclasses.fields(cls)]
        applies = name != "stereo_texture" or args.matcher == "bm"
        values: list[dict[str, int]] = []
        if text is None:
            values = [{}] if applies else []
        elif text.strip().lower() != "none":
            for item in text.split(","):
                parts = item.strip().split(":")
                try:
                    ints = [int(v) for v in parts]
                except ValueError:
                    ints = []
                if not ints or len(ints) > len(fields):
                    raise ConfigError(f"{flag}: {item.strip()!r} is not {':'.join(f.upper() for f in fields)} "
                                      "(integers)")
                values.append(dict(zip(fields, ints)))
        if args.reject_axes and applies:
            axes = registry()[name].axes
            default = cls()
            grid = [axes.get(f, (getattr(default, f),)) for f in fields]
            values += [dict(zip(fields, (int(v) for v in combo))) for combo in itertools.product(*grid)]
        if values and not applies:
            raise ConfigError(f"{flag}: the texture threshold is StereoBM's (--matcher bm), not SGBM's")
        for v in values:
            try:
                post = cls(**v)
            except ParameterError as e:
                raise ConfigError(f"{flag}: {e}") from None
            if (name, post) not in out:
                out.append((name, post))
    return out


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from replay.errors import ConfigError
    from replay.logs.writer import LogWriter
    from replay.outputs import AtomicOutput, OutputPlan
    from replay.stereo_scene import SceneOverrides, load_scene
    from zcut.cloud import Intrinsics
    from zcut.errors import ParameterError
    from zcut.params import StereoLrParams
    from zcut.stereo import (
        MatcherParams,
        StereoCalibration,
        disparity_to_depth_mm,
        match,
        match_right,
        rejected_pixels,
        stereo_truth,
        xyz_from_depth_mm,
    )

    if not (np.isfinite(args.tau_px) and args.tau_px > 0):
        raise ConfigError(f"--tau-px must be a positive number, got {args.tau_px}")
    if args.gt_scale is not None and not (np.isfinite(args.gt_scale) and args.gt_scale > 0):
        raise ConfigError(f"--gt-scale must be a positive number, got {args.gt_scale}")
    for flag in ("focal", "baseline", "doffs", "cx", "cy"):
        v = getattr(args, flag)
        if v is not None and not np.isfinite(v):
            raise ConfigError(f"--{flag} must be a finite number, got {v}")
    over = SceneOverrides(left=args.left, right=args.right, calib=args.calib, gt=args.gt, occlusion=args.occlusion,
                          gt_scale=args.gt_scale, focal=args.focal, baseline=args.baseline, doffs=args.doffs,
                          cx=args.cx, cy=args.cy)
    block = args.block_size if args.block_size is not None else (9 if args.matcher == "bm" else 5)

    def params_for(calib: StereoCalibration) -> MatcherParams:
        try:
            return MatcherParams(matcher=args.matcher, num_disparities=_num_disparities(args, calib.ndisp),
                                 block_size=block, uniqueness_ratio=args.uniqueness,
                                 disp12_max_diff=args.disp12_max_diff, speckle_window=args.speckle_window,
                                 speckle_range=args.speckle_range, texture_threshold=args.texture_threshold)
        except ParameterError as e:
            raise ConfigError(f"matcher: {e}") from None

    # every scene is read (and its matcher settings checked) before the output is opened
    scenes = [load_scene(d, over) for d in args.scenes]
    params = [params_for(s.calib) for s in scenes]
    frames_meta = [{"scene": s.name, "sources": s.sources, "calibration": s.calib.as_dict(),
                    "matcher": p.as_dict(), "truth": s.gt_disparity is not None} for s, p in zip(scenes, params)]
    posts = post_filter_sets(args)
    topics = [layout.stereo_rejected_topic(dataclasses.asdict(post)) for _, post in posts]
    meta = {layout.STEREO_METADATA: {
        "tau_px": repr(float(args.tau_px)), "matcher": args.matcher, "frames": json.dumps(frames_meta),
        "rejected": json.dumps([{"method": name, "settings": dataclasses.asdict(post), "topic": topic}
                                for (name, post), topic in zip(posts, topics)])}}
    out = Path(args.output)
    inputs: list[str | os.PathLike[str]] = [v for s in scenes for v in s.sources.values()]
    with OutputPlan(inputs, force=args.force) as plan, AtomicOutput(plan.add(out, "the log")) as target:
        with LogWriter(target.temp, metadata=meta, bag_name=out.name) as w:
            for i, (scene, p) in enumerate(zip(scenes, params)):
                t0 = time.process_time()
                disp = match(scene.left, scene.right, p)
                cal = scene.calib
                xyz = xyz_from_depth_mm(disparity_to_depth_mm(disp, cal), cal)
                # the pixels of the cloud each post-filter would invalidate (the same run, that filter on); the
                # left-right check's right view matched once for all its tolerances
                valid = np.isfinite(xyz[..., 2])
                disp_r = match_right(scene.left, scene.right, p) if any(isinstance(post, StereoLrParams)
                                                                        for _, post in posts) else None
                rejected = [rejected_pixels(scene.left, scene.right, p, post, matched=valid, disparity=disp,
                                            disparity_right=disp_r) for _, post in posts]
                h, wd = xyz.shape[:2]
                stamp = i * 1_000_000_000
                kw = {"stamp_ns": stamp, "frame_id": args.frame_id}
                w.write_cloud(layout.CLOUD, xyz, rgb=scene.left, **kw)
                w.write_image(layout.IMAGE, scene.left, **kw)
                w.write_camera_info(layout.CAMERA_INFO, Intrinsics(fx=cal.focal_px, fy=cal.focal_px, cx=cal.cx,
                                                                   cy=cal.cy, width=wd, height=h), **kw)
                for topic, mask in zip(topics, rejected):
                    w.write_mask(topic, mask, **kw)
                n_valid = int(np.isfinite(xyz[..., 2]).sum())
                line = f"{i:4d} {scene.name}: {h}x{wd}, {n_valid} matched pixels ({args.matcher})"
                if scene.gt_disparity is not None:
                    # the truth of the cloud as written: its float32 z, in mm
                    t = stereo_truth(xyz[..., 2].astype(np.float64) * 1000.0, scene.gt_disparity, cal,
                                     tau_px=args.tau_px, occluded=scene.occluded)
                    w.write_depth(layout.TRUTH_DEPTH, (t.depth_mm / 1000.0).astype(np.float32), **kw)
                    w.write_mask(layout.TRUTH_OUTLIERS, t.outliers, **kw)
                    w.write_mask(layout.TRUTH_UNKNOWN, t.unknown, **kw)
                    w.write_mask(layout.TRUTH_DETECTABLE, t.detectable, **kw)
                    judged = int(np.count_nonzero(np.isfinite(xyz[..., 2]) & ~t.unknown))
                    n_out = int(t.outliers.sum())
                    share = f"{100.0 * n_out / judged:.1f} %" if judged else "-"
                    line += (f", {judged} judged, {n_out} true outliers ({share}; {int(t.detectable.sum())} "
                             f"detectable), {int(t.unknown.sum())} unknown")
                else:
                    line += ", no ground truth"
                print(f"{line}, {time.process_time() - t0:.2f} CPU-s")
                if topics:
                    print("       rejected by the matcher's post-filters: " + ", ".join(
                        f"{t[len(layout.STEREO_REJECTED_PREFIX):]} {int(m.sum())}" for t, m in zip(topics, rejected)))
    n_truth = sum(s.gt_disparity is not None for s in scenes)
    print(f"wrote {len(scenes)} frame{'s' if len(scenes) != 1 else ''} to {out} ({n_truth} with ground truth, "
          f"τ_d = {args.tau_px:g} px)")
    if n_truth < len(scenes):
        print(f"warning: {len(scenes) - n_truth} scene(s) without ground truth: `zcut accuracy` cannot score them",
              file=sys.stderr)
    return 0
