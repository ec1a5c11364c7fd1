"""One frame of a log through the pipeline's ``explained`` method, saved to compare two trees bit for bit
(docs/labelling.md, "The free-space reading off the rim and edges removed").

The pipeline runs the z-cut and ``explained`` (the log's own part model; one frame in flight) on frame K alone; the
method's outlier mask and every fit's pose (``ExplainedDetail.fits``) are saved to OUT.npz, and one JSON line printed:
the outlier px, the fits and the slivers among them, short SHA-256 digests of the mask and the poses, and the CPU-s
of the frame. Run it in each tree (its own ``PYTHONPATH``) and compare the digests, or the two files.

    cd TREE && PYTHONPATH=. .venv/bin/python bench/explained_frame.py LOG K OUT.npz
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from pathlib import Path

import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log", type=Path, metavar="LOG.mcap")
    ap.add_argument("frame", type=int, metavar="K", help="the frame's 0-based index")
    ap.add_argument("out", type=Path, metavar="OUT.npz")
    args = ap.parse_args()
    if args.frame < 0:
        raise SystemExit(f"error: K must be at least 0, got {args.frame}")
    from replay.options import PipelineOptions

    session = PipelineOptions(methods="zcut,explained").open_session(args.log)
    t = time.process_time()
    got = list(session.results(frames=(args.frame, args.frame + 1), in_flight=1))
    if not got:
        raise SystemExit(f"error: {args.log} has no readable frame {args.frame}")
    frame, res = got[0]
    mask = np.asarray(res.outliers["explained"], bool)
    d = res.details["explained"]
    poses = np.ascontiguousarray(np.stack([f.pose for f in d.fits]) if d.fits else np.zeros((0, 4, 4)))
    np.savez(args.out, outliers=mask, poses=poses)
    print(json.dumps({"frame": frame.index, "outlier_px": int(mask.sum()),
                      "outliers_sha": hashlib.sha256(np.packbits(mask).tobytes()).hexdigest()[:16],
                      "fits": len(d.fits), "slivers": int(d.slivers),
                      "poses_sha": hashlib.sha256(poses.tobytes()).hexdigest()[:16],
                      "cpu_s": round(time.process_time() - t, 1)}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
