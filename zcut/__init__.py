"""zcut: pure algorithms on organized (H, W) point clouds — the paper's z-cut filter, SOR, suspects, metrics.

No file I/O, no viewer, no database here: see ``replay`` and ``annotate`` for those.

The names below are imported from their modules when first used (PEP 562): ``import zcut.params``
or ``from zcut import ZCutParams`` loads that module alone, not numba, SciPy and every kernel of the
package (docs/performance.md, "Fixed costs"). A name read from the package or imported from it is the same
object as before; ``zcut.suspects`` stays the function (the package ``zcut.suspects`` is in
``sys.modules``), as when this file imported everything.
"""

from __future__ import annotations

# the standard library under private names: a submodule of zcut (``zcut.types``) is set as an
# attribute of this package when imported, and must not replace what this file uses
import importlib as _importlib
import sys as _sys
import types as _types
from typing import TYPE_CHECKING as _TYPE_CHECKING
from typing import Any as _Any

if _TYPE_CHECKING:
    from .bin_model import BinModel
    from .cloud import Intrinsics, height_mm, valid_mask
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

#: (module of zcut, the public names it gives), each name imported from its module when first used
_MODULES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("bin_model", ("BinModel",)),
    ("cloud", ("Intrinsics", "height_mm", "valid_mask")),
    ("components", (
        "cluster_outliers",
        "cluster_outliers_reference",
        "cluster_stage",
        "speckle_outliers",
        "speckle_outliers_reference",
        "speckle_stage",
    )),
    ("cut_grid", ("ZCutTree", "zcut_tree")),
    ("cuts", ("CutResult", "find_clusters", "zcut_outliers", "zcut_outliers_reference")),
    ("errors", ("InputShapeError", "ParameterError", "ZcutError")),
    ("local_rules", (
        "mixed_pixel_outliers",
        "mixed_pixel_outliers_reference",
        "mixed_pixel_stage",
        "window_outliers",
        "window_outliers_reference",
        "window_stage",
    )),
    ("metrics", (
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
    )),
    ("params", (
        "BinMaskParams",
        "ClusterParams",
        "MixedPixelParams",
        "RadiusParams",
        "RegistrationParams",
        "RemovalParams",
        "SorParams",
        "SpeckleParams",
        "SuspectParams",
        "WindowParams",
        "ZCutParams",
    )),
    ("prepared_model", ("PreparedBinModel", "prepare_bin_model")),
    ("radius", ("radius_outliers", "radius_outliers_reference", "radius_stage")),
    ("sor", ("sor_mean_distances", "sor_outliers", "sor_outliers_from_distances")),
    ("suspects", ("DETECTORS", "SuspectGroup", "SuspectResult", "suspects")),
)
_EXPORTS: _types.MappingProxyType[str, str] = _types.MappingProxyType(
    {name: module for module, names in _MODULES for name in names})

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


def __getattr__(name: str) -> _Any:
    module = _EXPORTS.get(name)
    if module is None:
        if name.startswith("__"):
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
        try:  # a submodule not imported yet (``zcut.removal`` after ``import zcut``)
            return _importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as e:
            if e.name != f"{__name__}.{name}":
                raise
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    value = getattr(_importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))


class _Package(_types.ModuleType):
    """The package's module: ``zcut.suspects`` is the function :func:`zcut.suspects.suspects` (the name
    this package exports), also once the import system has set the subpackage ``zcut.suspects`` as an
    attribute here (it does so when the subpackage is first imported)."""

    def __setattr__(self, name: str, value: _Any) -> None:
        if name == "suspects" and isinstance(value, _types.ModuleType):
            value = value.suspects
        super().__setattr__(name, value)


_sys.modules[__name__].__class__ = _Package
