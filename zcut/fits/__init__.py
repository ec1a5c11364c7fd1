"""Fits: the instances of a known part in a frame's zone, their poses, residuals and support.

Issue 29 item 2, on the paper's definition (§2): for a part whose CAD model is known, a point is an
outlier when its distance to the *fitted* model exceeds 3 × Err, Err the fit's residual.
:func:`fit_parts` finds the fits (the method is in :mod:`zcut.fits.fit`'s docstring: segmentation at
depth discontinuities, symmetry-aware initial guesses, point-to-plane ICP, a closed form for
spheres, acceptance by residual and support, pixel reassignment). Pure: arrays in, arrays out; it
reads only the cloud, the zone, the mesh and the intrinsics.

The modules: :mod:`~zcut.fits.params` (:class:`FitParams`), :mod:`~zcut.fits.model` (the mesh
checked, classified, sampled, its symmetries), :mod:`~zcut.fits.segment` (candidate regions),
:mod:`~zcut.fits.sphere` (closed-form sphere fits), :mod:`~zcut.fits.icp` (initial guesses, ICP),
:mod:`~zcut.fits.fit` (:func:`fit_parts`, :class:`PartFit`).
"""

from __future__ import annotations

from .fit import PartFit, estimate_intrinsics, fit_parts, fit_prepared
from .model import PartModel, prepare_model
from .params import FitParams
from .score import pose_error

__all__ = ["FitParams", "PartFit", "PartModel", "estimate_intrinsics", "fit_parts", "fit_prepared", "pose_error", "prepare_model"]
