"""Compile zcut's numba kernels ahead (``python -m replay.warmup``; ``scripts/install.sh`` runs it).

The kernels are compiled on first use and cached beside their modules; a first ``zcut demo`` would
otherwise wait minutes in silence (the whole set: 1.5-9 min measured; 1055 s on two cores shared by
five other jobs, load average 10). One line per kernel group says what is being compiled and how
long it took. This runs every kernel once on tiny inputs: each method's own warm-up, as its registry
entry declares it (:attr:`replay.pipeline.methods.Method.warmup`: the z-cut's kernels, SOR in both
conventions, the filter bank, the suspect detectors of the labelling page), a small synthetic log with its bin model through the whole pipeline (the
scene generator and the readers too), the removal of a float64 cloud and of a bin seen from the side, the labelling page's part fits and review groups, and the ray-traced sensor (``zcut synth --sensor raytraced``).
"""

from __future__ import annotations

import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np


def groups() -> list[tuple[str, Callable[[Path], None]]]:
    """(what, compile it) per line of the warm-up: the paper's z-cut and SOR a line each, the other
    methods of the registry together (each runs its own entry's warm-up), then the whole pipeline, the
    removal's other inputs, the labelling page and the ray-traced sensor."""
    from replay.pipeline.methods import DEFAULT_METHODS, registry

    known = registry()

    def one(method: Callable[[], None]) -> Callable[[Path], None]:
        return lambda d: method()

    out: list[tuple[str, Callable[[Path], None]]] = []
    for name in DEFAULT_METHODS:
        warm = known[name].warmup
        if warm is not None:
            out.append((f"{name}: {known[name].summary}", one(warm)))
    rest = [m for m in known.values() if m.name not in DEFAULT_METHODS and m.warmup is not None]
    if rest:
        def bank(d: Path) -> None:
            for m in rest:
                assert m.warmup is not None
                m.warmup()

        out.append((f"the filter bank and the suspects ({', '.join(m.name for m in rest)})", bank))
    out += [("the synthetic scenes, the readers and the whole pipeline", _pipeline),
            ("the removal of a float64 cloud and of a bin seen from the side", _removal_inputs),
            ("SOR with k = 6 (its windows' eight slots)", _sor_eight),
            ("the labelling page: the part model's fits (`explained`) and the page's suspects", _labelling),
            ("the ray-traced sensor", _raytraced)]
    return out


def _pipeline(d: Path) -> None:
    from replay.logs.reader import LogReader
    from replay.pipeline.bin_model import build_bin_model
    from replay.pipeline.session import ReplaySession
    from replay.synth.log import write_synthetic_log

    log, empty = d / "w.mcap", d / "e.mcap"
    write_synthetic_log(log, kind="rods", frames=1, seed=1, size=(60, 96))
    write_synthetic_log(empty, empty=True, frames=2, seed=1, size=(60, 96))
    model, _ = build_bin_model(LogReader(empty).frames())
    for bm in (model, None):
        ReplaySession.open(log, bin_model=bm).run()


def _removal_inputs(d: Path) -> None:
    """The removal's kernels for the inputs the pipeline does not give it (the replay's clouds are float32 and
    its bins seen from above): a float64 cloud (its classes and stragglers) and a bin seen from the side (no
    floor plane: the classes' codes, then the heights), and their floored clouds. Library callers may pass
    either, and the tests do: tests/zcut/test_removal.py compiled them for 36 s and 16 s (2026-12-07)."""
    from replay.logs.reader import LogReader
    from replay.pipeline.bin_model import build_bin_model
    from replay.pipeline.session import ReplaySession
    from replay.pipeline.stages import locate_bin
    from replay.synth.log import write_synthetic_log
    from zcut.prepared_model import prepare_bin_model
    from zcut.removal import remove_table_and_bin

    log, empty = d / "removal.mcap", d / "removal_empty.mcap"
    write_synthetic_log(log, kind="rods", frames=1, seed=1, size=(60, 96))
    write_synthetic_log(empty, empty=True, frames=2, seed=1, size=(60, 96))
    model, _ = build_bin_model(LogReader(empty).frames())
    config = ReplaySession.open(log, bin_model=model).config
    prepared = prepare_bin_model(model, registration=config.registration, removal=config.removal)
    frame = next(iter(LogReader(log).frames()))
    located = locate_bin(frame, config, bin_model=prepared)
    if located.bin_mask is None or located.registration is None:
        raise RuntimeError(f"warm-up: the bin was not located in its own synthetic log ({located.failure})")
    T = np.asarray(located.registration.T_cam_bin, np.float64)
    side = T.copy()
    side[:3, :3] = [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]  # the bin's up along the image's x axis
    for xyz, pose in ((np.ascontiguousarray(frame.xyz, np.float64), T), (frame.xyz, side)):
        rem = remove_table_and_bin(xyz, located.bin_mask.mask, index=prepared.removal, T_cam_bin=pose,
                                   ring=located.ring)
        assert rem.xyz.shape == xyz.shape  # the floored cloud is made when it is first read


def _sor_eight(d: Path) -> None:
    """SOR's window kernels keep the nearest distances in a tuple of four slots for a small k (the default 4,
    which the SOR group compiles) and of eight for a larger one (``zcut.sor_window``): ``[sor] k = 6`` in a
    config or ``--sor-k 6`` compiled them in the user's first replay (tests/cli/test_replay_cli.py's config
    test: 22.6 s, 2026-12-07). The SOR group's clouds again with k = 6, in both conventions."""
    from replay.pipeline.methods import _tiny
    from zcut.sor import sor_outliers

    _, xyz, scattered = _tiny()
    for convention in ("pcl", "open3d"):
        sor_outliers(xyz, k=6, convention=convention)
        sor_outliers(xyz.astype(np.float64) * [1, 1, -1], k=6, convention=convention)
        sor_outliers(scattered, k=6, convention=convention)


def _labelling(d: Path) -> None:
    """The kernels only the labelling page and the ``explained`` method run: the part model's fits, the
    sliver fits, the edge-aware surface of the review groups (135 of the 331 kernels the suite compiled were
    not compiled by the other groups, measured 2026-12-07; the fits and the groups' surfaces among them)."""
    from replay.options import PipelineOptions
    from replay.synth.log import write_synthetic_log
    from zcut.edge_surface import EdgeSurfaceParams
    from zcut.params import SuspectParams
    from zcut.suspects import suspects

    log = d / "p.mcap"
    write_synthetic_log(log, kind="zinc_nuts", frames=1, seed=1, size=(200, 320))
    results = PipelineOptions(methods="zcut,explained").open_session(log).results()
    try:
        for frame, res in results:
            valid = np.asarray(res.valid, bool)  # the page's suspects (annotate.groups.review_groups' call)
            suspects(frame.xyz, res.height_mm, res.zone & valid, res.easy_outliers & valid, params=SuspectParams(),
                     edge_surface=EdgeSurfaceParams()).release()
    finally:
        results.close()


def _raytraced(d: Path) -> None:
    from replay.synth.raytrace import write_raytraced_log

    write_raytraced_log(d / "r.mcap", kind="rods", frames=1, seed=1, size=(60, 96))


def main() -> int:
    groups_ = groups()
    t0 = time.perf_counter()
    print(f"zcut: compiling the numba kernels in {len(groups_)} groups (once; cached beside the modules; "
          "1.5-9 min measured, 18 min on 2 busy cores)", file=sys.stderr, flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for i, (what, compile_group) in enumerate(groups_, 1):
            t = time.perf_counter()
            print(f"zcut: [{i}/{len(groups_)}] {what}…", end="", file=sys.stderr, flush=True)
            compile_group(Path(tmp))
            print(f" {time.perf_counter() - t:.0f} s", file=sys.stderr, flush=True)
    print(f"zcut: kernels compiled in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":  # pragma: no cover
    from replay.process import configure_process

    configure_process()
    sys.exit(main())
