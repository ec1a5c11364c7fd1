"""The fits do not depend on numpy's CPU dispatch (docs/fits.md, "The fits independent of numpy's CPU dispatch"):
the model index's voxel size is a correctly rounded cube root (:func:`zcut.fits.model.cube_root`), not ``np.cbrt``,
whose AVX-512 kernel rounds apart from the AVX2 and baseline kernels (the C library's), so a pinned fit comes out the
same with numpy kept to AVX2 as with numpy as is. The whole pins at every level: bench/bench_fits_dispatch.py."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from fit_digests import DEFAULTS, hand_made, holed, part_model

from zcut.errors import ParameterError
from zcut.fits.model import _angle_deg, cube_root

ROOT = Path(__file__).resolve().parents[3]
#: numpy's dispatch kept to AVX2 (X86_V3) on a CPU with AVX-512 (tests/replay/synth/test_part_meshes_cpu.py's)
NUMPY_AT_AVX2 = {"NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR"}

#: The voxel size (mm) of the hand-made nut's and rod's model index, the correctly rounded cube root every CPU now
#: gives. The start tree took numpy's ``np.cbrt``: these bits on a CPU with AVX-512 and the C library's ``cbrt``
#: elsewhere, 1 ulp (nut: ``...594dp-2``) and 2 ulp (rod: ``...630e7p-2``) off them
INDEX_H = {"zinc_nuts": "0x1.20c367a25594cp-2", "rods": "0x1.aac16410630e9p-2"}

_CHILD = """
import json, math, sys
import numpy as np
from fit_digests import digest, part_model
from zcut.fits import fit_prepared
x = np.linspace(0.01, 50.0, 2001)  # numpy's own cbrt: the C library's unless its AVX-512 kernel runs
cbrt_is_libms = np.cbrt(x).tobytes() == np.array([math.cbrt(v) for v in x]).tobytes()
xyz, zone = np.load(sys.argv[1]), np.load(sys.argv[2])
fits = fit_prepared(xyz, zone, part_model("rods"), intrinsics=tuple(json.loads(sys.argv[3])))
print(json.dumps({"cbrt is libm's": cbrt_is_libms, "fits": [len(fits), digest(fits)]}))
"""


def test_a_pin_is_the_same_with_numpy_kept_to_avx2(tmp_path: Path) -> None:
    """The holed rods' pin (``DEFAULTS[("rods", True)]``, the cheapest that showed the fault: the start tree gave
    ``f7b048be6cb2f3a6`` at AVX2) fitted in a process with numpy kept to AVX2: the model prepared there, the frame
    this session's. ~8 CPU-s (the process's imports and the rod model's preparation ~6.5, the fits ~1)."""
    xyz, zone, _, K = hand_made("rods")
    np.save(tmp_path / "xyz.npy", holed(xyz))
    np.save(tmp_path / "zone.npy", zone)
    path = os.pathsep.join([str(ROOT), str(ROOT / "tests" / "zcut" / "fits"), str(ROOT / "tests")])
    p = subprocess.run([sys.executable, "-c", _CHILD, str(tmp_path / "xyz.npy"), str(tmp_path / "zone.npy"),
                        json.dumps(K)], cwd=ROOT, capture_output=True, text=True, check=False,
                       env={**os.environ, **NUMPY_AT_AVX2, "PYTHONPATH": path})
    assert p.returncode == 0, p.stderr[-3000:]
    out = json.loads(p.stdout.strip().splitlines()[-1])
    assert out["cbrt is libm's"]  # the variable took (on a CPU without AVX-512 it is so anyway)
    assert tuple(out["fits"]) == DEFAULTS[("rods", True)]


@pytest.mark.parametrize("kind", sorted(INDEX_H))
def test_the_index_voxel_size_is_the_correctly_rounded_cube_root(kind: str) -> None:
    model = part_model(kind)  # the session's (test_fits_defaults' too)
    box = np.ptp(model.vertices, axis=0) + 2 * 6.0  # type: ignore[attr-defined]  # prepare_model's default margin
    assert model.index.h == cube_root(float(np.prod(box)) / 1_000_000)  # type: ignore[attr-defined]
    assert model.index.h.hex() == INDEX_H[kind]  # type: ignore[attr-defined]


def _correctly_rounded(x: float, r: float) -> bool:
    """Whether ``r`` is the float64 nearest the real cube root of ``x``: x lies between the cubes of the midpoints
    from ``r`` to its neighbours."""
    below, above = math.nextafter(r, 0.0), math.nextafter(r, math.inf)
    return bool(((Fraction(r) + Fraction(below)) / 2) ** 3 <= Fraction(x) <= ((Fraction(r) + Fraction(above)) / 2) ** 3)


def test_cube_root_is_correctly_rounded(rng: np.random.Generator) -> None:
    """Random values over the whole range (2,000), values near the model indices' (box volume / a million voxels),
    exact cubes and the extremes: the nearest float64 each time, where the C library's cbrt is off in the last bit
    for some of them."""
    xs = [float(v) for v in np.exp(rng.uniform(-690.0, 700.0, 2000))]
    xs += [float(v) for v in rng.uniform(0.005, 0.02, 500)]
    xs += [8.0, 27.0, 0.125, 1.0, 1e-300, 5e-324, float(np.finfo(np.float64).max), 2.0, 3.0, 10.0]
    wrong_in_libm = 0
    for x in xs:
        r = cube_root(x)
        assert _correctly_rounded(x, r), x
        wrong_in_libm += not _correctly_rounded(x, math.cbrt(x))
    assert cube_root(27.0) == 3.0 and cube_root(0.125) == 0.5 and cube_root(1.0) == 1.0
    assert wrong_in_libm > 0  # glibc's cbrt is faithful, not correctly rounded: the check moves some roots


@pytest.mark.parametrize("x", [0.0, -0.0, -8.0, math.inf, math.nan])
def test_cube_root_says_what_is_wrong(x: float) -> None:
    with pytest.raises(ParameterError, match="cube_root needs a positive finite number"):
        cube_root(x)


def test_the_angle_of_a_rotation_is_the_c_librarys_acos() -> None:
    """``_angle_deg`` (the symmetries' merge test, the pose error): acos by the C library, the trace clipped."""
    for deg in (0.0, 1e-6, 0.5, 10.0, 90.0, 179.9, 180.0):
        a = math.radians(deg)
        R = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
        want = math.degrees(math.acos(min(max((float(np.trace(R)) - 1.0) / 2.0, -1.0), 1.0)))
        assert _angle_deg(R) == want and abs(want - deg) < 1e-5
    assert _angle_deg(np.eye(3) * 1.0000001) == 0.0  # a trace above 3 by rounding: clipped, not NaN
