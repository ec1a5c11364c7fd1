"""zcut: pure algorithms on organized (H, W) point clouds — the paper's z-cut filter, SOR, metrics.

No file I/O, no viewer, no database here: see ``replay`` and ``annotate`` for those.
"""

from .cloud import Intrinsics, height_mm, valid_mask
from .errors import InputShapeError, ParameterError, ZcutError

__all__ = [
    "Intrinsics",
    "InputShapeError",
    "ParameterError",
    "ZcutError",
    "height_mm",
    "valid_mask",
]
