"""The fits' literal pins at every CPU dispatch level this machine can play, one process per level and tree.

    PYTHONPATH=. .venv/bin/python bench/bench_fits_dispatch.py [--levels as-is,numpy-avx2,...] [--pins ...] \\
        [--against /tmp/old] [--numba-cache DIR]

Each level is a set of environment variables (``LEVELS``): numpy kept to AVX2 or to its baseline
(``NPY_DISABLE_CPU_FEATURES``), OpenBLAS's Haswell or Sandy Bridge kernels (``OPENBLAS_CORETYPE``: numpy's and
SciPy's copies, the latter the numba kernels' LAPACK and matrix products), numba compiling for Haswell
(``NUMBA_CPU_NAME``, its own cache: ``--numba-cache``, else a temporary folder; the first run compiles every kernel,
minutes), glibc's libm without its FMA variants (``GLIBC_TUNABLES``). Per tree (this one and ``--against``, a ``git
archive`` of another) and level, a process prepares the hand-made models and fits the pins of
tests/zcut/fits/fit_digests.py (``DEFAULTS``, ``DEFAULTS_REAL``) and tests/zcut/fits/test_fits_pose.py (``NINTH``),
and prints (number of fits, digest, CPU s of ``fit_prepared``). The table: per pin, the literal, and per level
``=`` where the digest is the literal's. docs/fits.md, "The fits independent of numpy's CPU dispatch".
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_AVX2 = "X86_V4 AVX512_ICL AVX512_SPR"
_BASELINE = "X86_V3 X86_V4 AVX512_ICL AVX512_SPR"
#: name -> environment (``{numba_cache}`` is replaced by the numba cache folder)
LEVELS: dict[str, dict[str, str]] = {
    "as-is": {"NPY_DISABLE_CPU_FEATURES": ""},
    "numpy-avx2": {"NPY_DISABLE_CPU_FEATURES": _AVX2},
    "numpy-baseline": {"NPY_DISABLE_CPU_FEATURES": _BASELINE},
    "blas-haswell": {"OPENBLAS_CORETYPE": "Haswell"},
    "blas-sandybridge": {"OPENBLAS_CORETYPE": "Sandybridge"},
    "numba-haswell": {"NUMBA_CPU_NAME": "haswell", "NUMBA_CACHE_DIR": "{numba_cache}"},
    "libm-no-fma": {"GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX2,-FMA,-FMA4"},
}
PINS = ("zinc_nuts", "zinc_nuts holed", "spheres", "spheres holed", "rods", "rods holed", "black_nuts",
        "black_nuts holed", "real", "ninth")

_CHILD = """
import json, sys, time
from pathlib import Path
from fit_digests import DEFAULTS, DEFAULTS_REAL, digest, hand_made, holed, real_crop
from test_fits_pose import NINTH
from tests.real_data_path import REAL_DATA
from zcut.fits import FitParams, fit_prepared
out = {}
for pin in sys.argv[1].split(","):
    kind = pin.split()[0]
    if pin == "real":
        xyz, zone, model, K = real_crop(Path(REAL_DATA))
        want = DEFAULTS_REAL
    else:
        xyz, zone, model, K = hand_made("zinc_nuts" if pin == "ninth" else kind)
        want = NINTH if pin == "ninth" else DEFAULTS[(kind, pin.endswith("holed"))]
    params = FitParams(fine_window=False, fine_robust=0.0) if pin == "ninth" else FitParams()
    t0 = time.process_time()
    fits = fit_prepared(holed(xyz) if pin.endswith("holed") else xyz, zone, model, intrinsics=K, params=params)
    out[pin] = [len(fits), digest(fits), time.process_time() - t0, list(want)]
print(json.dumps(out))
"""


def _run(tree: Path, level: str, pins: str, numba_cache: str) -> dict[str, list[object]]:
    env = {**os.environ, **{k: v.format(numba_cache=numba_cache) for k, v in LEVELS[level].items()},
           "PYTHONPATH": os.pathsep.join(str(tree / p) for p in ("", "tests/zcut/fits", "tests"))}
    p = subprocess.run([sys.executable, "-c", _CHILD, pins], cwd=tree, env=env, capture_output=True, text=True,
                       check=False)
    if p.returncode != 0:
        raise SystemExit(f"{tree} {level}: {p.stderr.strip()[-2000:]}")
    res: dict[str, list[object]] = json.loads(p.stdout.strip().splitlines()[-1])
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--levels", default=",".join(LEVELS), help=f"comma-separated, of {', '.join(LEVELS)}")
    ap.add_argument("--pins", default=",".join(PINS), help=f"comma-separated, of {', '.join(PINS)}")
    ap.add_argument("--against", type=Path, default=None, help="an older tree (a git archive) run the same way")
    ap.add_argument("--numba-cache", default=None, help="numba's cache for numba-haswell (default: a temporary one)")
    args = ap.parse_args()
    levels = args.levels.split(",")
    unknown = [v for v in levels if v not in LEVELS] + [p for p in args.pins.split(",") if p not in PINS]
    if unknown:
        raise SystemExit(f"unknown level or pin: {', '.join(unknown)}")
    trees = {"new": ROOT} if args.against is None else {"old": args.against.resolve(), "new": ROOT}
    with tempfile.TemporaryDirectory() as tmp:
        res: dict[tuple[str, str], dict[str, list[object]]] = {}
        for level in levels:
            for name, tree in trees.items():
                cache = args.numba_cache or str(Path(tmp) / f"numba-{name}")
                res[name, level] = _run(tree, level, args.pins, cache)
                cpu = sum(float(v[2]) for v in res[name, level].values())  # type: ignore[arg-type]
                print(f"{name} {level}: fits' CPU {cpu:.2f} s, load {os.getloadavg()[0]:.1f}", flush=True)
    for name in trees:
        print(f"\n{name} tree ({trees[name]}): the literal, then per level '=' where the fits' digest is it; "
              f"'{levels[0]}=' where it is not but equals the first level's")
        print(f"{'pin':18s} {'literal':>22s} " + " ".join(f"{v:>21s}" for v in levels))
        for pin in args.pins.split(","):
            want = res[name, levels[0]][pin][3]
            first = res[name, levels[0]][pin][:2]
            cells = []
            for k, level in enumerate(levels):
                got = res[name, level][pin]
                cells.append("=" if got[:2] == want else f"{levels[0]}=" if k and got[:2] == first
                             else f"{got[0]} {got[1]}")
            print(f"{pin:18s} {want[0]:>5} {want[1]:>16s} " + " ".join(f"{c:>21s}" for c in cells))


if __name__ == "__main__":
    main()
