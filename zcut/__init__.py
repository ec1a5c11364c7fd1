"""zcut: pure algorithms on organized (H, W) point clouds — the paper's z-cut filter, SOR, suspects, metrics.

No file I/O, no viewer, no database here: see ``replay`` and ``annotate`` for those.
"""

from .bin_model import BinModel
from .cloud import Intrinsics, height_mm, valid_mask

# the filter bank (docs/filters.md, "The filter bank")
from .components import (
    cluster_outliers,
    cluster_outliers_reference,
    cluster_stage,
    speckle_outliers,
    speckle_outliers_reference,
    speckle_stage,
)
from .cut_grid import ZCutTree, zcut_tree
from .cuts import CutResult, find_clusters, zcut_outliers, zcut_outliers_reference
from .errors import InputShapeError, ParameterError, ZcutError
from .local_rules import (
    mixed_pixel_outliers,
    mixed_pixel_outliers_reference,
    mixed_pixel_stage,
    window_outliers,
    window_outliers_reference,
    window_stage,
)
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
from .params import (
    BinMaskParams,
    ClusterParams,
    MixedPixelParams,
    RadiusParams,
    RegistrationParams,
    RemovalParams,
    SorParams,
    SpeckleParams,
    SuspectParams,
    WindowParams,
    ZCutParams,
)
from .prepared_model import PreparedBinModel, prepare_bin_model
from .radius import radius_outliers, radius_outliers_reference, radius_stage
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
    # the filter bank
    "ClusterParams",
    "MixedPixelParams",
    "RadiusParams",
    "SpeckleParams",
    "WindowParams",
    "cluster_outliers",
    "cluster_outliers_reference",
    "cluster_stage",
    "mixed_pixel_outliers",
    "mixed_pixel_outliers_reference",
    "mixed_pixel_stage",
    "radius_outliers",
    "radius_outliers_reference",
    "radius_stage",
    "speckle_outliers",
    "speckle_outliers_reference",
    "speckle_stage",
    "window_outliers",
    "window_outliers_reference",
    "window_stage",
]
