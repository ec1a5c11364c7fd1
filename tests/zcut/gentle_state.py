"""The pruned z-cut's kernels driven by hand, for the tests of the level pass and the prune
(tests/zcut/test_cuts_fast.py, tests/zcut/test_cuts_uphill.py): the level set-up of
zcut.cuts._pruned_outliers over the whole frame (no window), the gentle components labelled by
zcut.cut_tree.gentle_levels, then zcut.cut_tree.gentle_prune, with the kernels' own arrays returned."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zcut.cut_tree import gentle_levels, gentle_prune
from zcut.cuts import _finite_range, _levels
from zcut.params import n_levels


@dataclass(frozen=True)
class GentleState:
    """The kernels' arrays after :func:`gentle_labelled` (padded ``(H + 2) * (W + 2)`` where it says so).

    ``st`` (padded int16): levels, -1 outside the cuts; ``gl`` (padded int32): the provisional labels;
    ``pix``, ``gpar``, ``gcnt`` (H * W int32); ``m``: pixels in the cuts; ``nl``: labels; ``labelled``:
    gentle_levels labelled every pixel; ``top``: the deepest level in the cuts (K + 1 or less); ``H, W``."""

    st: np.ndarray
    gl: np.ndarray
    pix: np.ndarray
    gpar: np.ndarray
    gcnt: np.ndarray
    m: int
    nl: int
    labelled: bool
    top: int
    H: int
    W: int

    def levels(self) -> np.ndarray:
        """(H, W) int64: ``st``'s interior as it is now."""
        return self.st.reshape(self.H + 2, self.W + 2)[1:-1, 1:-1].astype(np.int64)

    def prune(self, *, max_area: float, connectivity: int) -> int:
        """Run gentle_prune on these arrays (in place); returns the number of pixels kept."""
        return int(gentle_prune(self.st, self.pix, self.m, self.gl, self.gpar, self.gcnt, self.nl, max_area,
                                np.zeros(self.top + 2, np.int64), self.labelled, self.W, connectivity == 8,
                                np.int64(self.top)))


def gentle_labelled(z: np.ndarray, *, step: float, max_depth: float, max_area: float, gentle: int,
                    check: int = 2**40) -> GentleState:
    """The level pass of z with its ``gentle``-connected (4 or 8) gentle components labelled over the
    whole frame (``check``: when it looks whether the labelling pays; default: never)."""
    z = np.ascontiguousarray(z, dtype=np.float64)
    H, W = z.shape
    _, lo, hi, seg = _finite_range(z)
    k_eff, top = _levels(lo, hi, step, n_levels(step, max_depth))
    size = (H + 2) * (W + 2)
    st, gl = np.empty(size, np.int16), np.empty(size, np.int32)
    pix, gpar, gcnt = (np.empty(H * W, np.int32) for _ in range(3))
    m, nl, labelled = gentle_levels(z, seg, lo, hi, step, np.int64(k_eff + 2), np.int64(top), gentle == 8, max_area,
                                    np.int64(check), st, pix, gl, gpar, gcnt)
    return GentleState(st, gl, pix, gpar, gcnt, int(m), int(nl), bool(labelled), int(top), H, W)
