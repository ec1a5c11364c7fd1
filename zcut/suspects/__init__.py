"""Suspects: outliers no filter chose, proposed to a person in groups (``docs/filters.md``, "Suspects").

The z-cut and SOR find what their own rules define; a person labelling true outliers must also see
what neither looks at, or the labels inherit the filters' blindness. The detectors here judge the
pixels of the zone (the points the filters judge) against the measured points around them, with
thresholds taken from the frame's own noise:

- ``residual_up`` / ``residual_down`` — **surface residuals**. The local surface at a pixel is
  continued from each of the 8 directions (the linear continuation ``2 h(p+d) - h(p+2d)`` of the two
  pixels on that side); the pixel's residual is its distance to the best of them. A pixel farther
  than τ from *every* continuation is off the surface: toward the camera (all continuations below
  it: a spike, a ghost's rim) or away from it (all above: a spike away from the camera, flagged
  only where at least ``below_min_directions`` continuations exist). τ = max(min_residual_mm,
  noise_k · σ̂), σ̂ the robust spread of the frame's second differences (:func:`frame_noise_mm`).
  A one-sided continuation follows edges and slopes, where a windowed median or plane would flag
  every occlusion edge of the pile. Blobs: zone pixels mostly surrounded by suspects join them
  (``fill_iterations`` rounds), so a rough ghost is proposed whole.
- ``mixed`` — **mixed (flying) pixels** at depth discontinuities: off the surface, and between two
  surfaces — above the continuation from one side and below the one from the opposite side, or with
  a neighbour nearer and one farther by more than the jump each.
- ``floating`` — **floating components of any depth**: the z-cut (:func:`zcut.cuts.find_clusters`)
  over the zone's whole height range, components smaller than ``floating_rho · a_max``; those
  larger than ``plain_rho · a_max`` only with evidence that they are not a clean measured surface
  (holes inside, rough, or hovering over measured points).
- ``above_rim`` — the points above the rim, which the pipeline's removal flags (given as a mask).
- ``patch`` — **patches cut off by depth steps** (:mod:`~zcut.suspects.patches`): small pieces of the depth
  image that a depth step, not a hole, bounds on most of their border — a surface at another depth than all
  the measured surface around it (a stereo matcher's wrong match over a whole patch). The small floating
  components are the floating detector's: a pixel of a component its cut judges alone (one that clears
  everything around it, smaller than ``FLOATING_OWNED_RHO`` · a_max, kept or not) is never a patch, so
  ``plain_rho`` moves the union on its own (:mod:`~zcut.suspects.floating`). The labelling page runs the patch detector only without a part
  model (``suspects(..., patches=False)`` where it fits one:
  ``annotate/groups.py``).

:func:`suspects` runs them all and groups the result for review: per detector, suspects within a
merge radius form one group; the radius of the detector with most groups doubles until the frame
has at most ``max_groups`` groups. Every group says which detectors flagged it, its size, its gap
to the local surface in mm (positive: toward the camera) and a score for ordering.

Each numba kernel has a literal reference beside it (``*_reference``: numpy or plain loops) and the
tests check they agree bit for bit (``tests/zcut/test_suspects.py``). The whole of :func:`suspects`
has one too: :func:`suspects_reference` (:mod:`~zcut.suspects._reference`) is the code as it stood
before it was made fast (issue 32: whole-frame numpy, scipy's labelling per detector and class, the
agglomeration in Python, the edge-aware distance of every pixel), and every field of their results
is equal bit for bit (``tests/zcut/test_suspects_fast.py``). The fast path labels each detector's
pixels directly (no grown mask), gathers the noise samples and the local heights in numba, completes
blobs from the pixels that joined last, and measures the edge-aware distance only at the pixels whose
gap takes it (:attr:`SuspectResult.surface_mm` measures the rest when read).

The modules, one per part: :mod:`~zcut.suspects.detectors` (the names, their bits, the grid helpers
they share), :mod:`~zcut.suspects.noise` (σ̂ and the depth step by height),
:mod:`~zcut.suspects.residuals` (surface residuals, mixed pixels, blob completion),
:mod:`~zcut.suspects.floating` (the floating detector and its evidence), :mod:`~zcut.suspects.gaps`
(the gap to the local surface), :mod:`~zcut.suspects.grouping` (groups within ``max_groups``) and
:mod:`~zcut.suspects.union` (:func:`suspects`, its result). The labelling page's budget of review
groups, the suspects' share and the filters', lives beside the page (:mod:`annotate.budget`).
"""

from __future__ import annotations

from ._reference import suspects_reference  # noqa: E402  (the previous code, after the modules it uses)
from .detectors import (
    ABOVE_RIM,
    DETECTORS,
    FLOATING,
    MIXED,
    PATCH,
    RESIDUAL_DOWN,
    RESIDUAL_UP,
    detector_bits,
    detector_names,
)
from .floating import (
    FLOATING_CLEARANCE_SIGMAS,
    FLOATING_CLEARANCE_STEPS,
    FLOATING_OWNED_RHO,
    FLOATING_STEP_SIGMAS,
    HOLE_MIN_NEIGHBOURS,
    floating_evidence,
    floating_evidence_reference,
)
from .gaps import GAP_MAX_RADIUS, GAP_MIN_PIXELS, local_gaps, local_gaps_reference
from .grouping import MAX_NODES, STRENGTH_CLASSES, strength_classes
from .noise import (
    NOISE_MAX_BINS,
    NOISE_MAX_SAMPLES,
    NOISE_MIN_SAMPLES,
    QUANTIZED_ZERO_SHARE,
    NoiseProfile,
    frame_noise_mm,
    local_height,
    noise_profile,
)
from .patches import (
    PATCH_JUMP_FACTOR,
    PATCH_MIN_STEP_SHARE,
    PATCH_RHO,
    cut_off_patches,
    cut_off_patches_reference,
)
from .residuals import (
    FILL_MIN_NEIGHBOURS,
    fill_blobs,
    fill_blobs_reference,
    surface_residuals,
    surface_residuals_reference,
)
from .union import SuspectGroup, SuspectResult, suspects

__all__ = [
    "DETECTORS",
    "SuspectGroup",
    "SuspectResult",
    "detector_bits",
    "detector_names",
    "cut_off_patches",
    "cut_off_patches_reference",
    "fill_blobs",
    "fill_blobs_reference",
    "floating_evidence",
    "floating_evidence_reference",
    "frame_noise_mm",
    "local_height",
    "NoiseProfile",
    "noise_profile",
    "local_gaps",
    "local_gaps_reference",
    "strength_classes",
    "surface_residuals",
    "surface_residuals_reference",
    "suspects",
    "suspects_reference",
    # the detectors' bits and the constants the docs name
    "ABOVE_RIM",
    "FLOATING",
    "MIXED",
    "PATCH",
    "RESIDUAL_DOWN",
    "RESIDUAL_UP",
    "FILL_MIN_NEIGHBOURS",
    "FLOATING_CLEARANCE_SIGMAS",
    "FLOATING_CLEARANCE_STEPS",
    "FLOATING_OWNED_RHO",
    "FLOATING_STEP_SIGMAS",
    "GAP_MAX_RADIUS",
    "GAP_MIN_PIXELS",
    "HOLE_MIN_NEIGHBOURS",
    "MAX_NODES",
    "NOISE_MAX_BINS",
    "NOISE_MAX_SAMPLES",
    "NOISE_MIN_SAMPLES",
    "PATCH_JUMP_FACTOR",
    "PATCH_RHO",
    "PATCH_MIN_STEP_SHARE",
    "QUANTIZED_ZERO_SHARE",
    "STRENGTH_CLASSES",
]
