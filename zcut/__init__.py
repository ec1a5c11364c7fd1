"""zcut: pure algorithms on organized (H, W) point clouds — the paper's z-cut filter, SOR, suspects, metrics.

No file I/O, no viewer, no database here: see ``replay`` and ``annotate`` for those.
"""

from .bin_model import BinModel
from .prepared_model import PreparedBinModel, prepare_bin_model
from .cloud import Intrinsics, height_mm, valid_mask
from .cut_grid import ZCutTree, zcut_tree
from .cuts import CutResult, find_clusters, zcut_outliers, zcut_outliers_reference
from .errors import InputShapeError, ParameterError, ZcutError
from .metrics import (
    AccuracyCounts,
    RelativeMetrics,
    Sensitivity,
    accuracy_counts,
    cohen_kappa,
    mask_iou,
    ratio,
    relative_metrics,
    sensitivity,
    sensitivity_of,
)
from .params import BinMaskParams, RegistrationParams, RemovalParams, SorParams, SuspectParams, ZCutParams
from .sor import sor_mean_distances, sor_outliers, sor_outliers_from_distances
from .suspects import DETECTORS, SuspectGroup, SuspectResult, suspects

__all__ = [
    "BinMaskParams",
    "BinModel",
    "CutResult",
    "PreparedBinModel",
    "RegistrationParams",
    "RemovalParams",
    "SorParams",
    "SuspectParams",
    "ZCutParams",
    "ZCutTree",
    "prepare_bin_model",
    "zcut_tree",
    "find_clusters",
    "zcut_outliers",
    "zcut_outliers_reference",
    "Intrinsics",
    "InputShapeError",
    "ParameterError",
    "ZcutError",
    "AccuracyCounts",
    "RelativeMetrics",
    "Sensitivity",
    "accuracy_counts",
    "cohen_kappa",
    "mask_iou",
    "ratio",
    "relative_metrics",
    "sensitivity",
    "sensitivity_of",
    "sor_mean_distances",
    "sor_outliers",
    "sor_outliers_from_distances",
    "DETECTORS",
    "SuspectGroup",
    "SuspectResult",
    "suspects",
    "height_mm",
    "valid_mask",
]
