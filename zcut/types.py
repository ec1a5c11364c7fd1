"""Array type aliases shared by the stages (documentation only; shapes are in the docstrings)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

Mask = npt.NDArray[np.bool_]          # (H, W) bool on the organized grid
Labels = npt.NDArray[np.int32]        # (H, W) int32, 0 = none, k = k-th component
FloatImage = npt.NDArray[np.floating]  # (H, W) float, NaN = invalid
XYZ = npt.NDArray[np.floating]        # (H, W, 3) float, NaN = invalid
RGB = npt.NDArray[np.uint8]           # (H, W, 3) uint8
