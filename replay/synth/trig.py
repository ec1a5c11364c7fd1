"""The hand-made generator's part geometry takes its sines, cosines and polar angles from here.

numpy's transcendental ufuncs are dispatched by CPU: on a CPU with AVX-512, ``np.arctan2``, ``np.exp``,
``np.tan``, ``np.log`` (numpy 2.4, float64) run SIMD kernels whose last bits differ from the AVX2
path's, which is the C library's scalar function; ``np.sin`` and ``np.cos`` of float64 call the C
library today, and numpy has SIMD versions of them in the works. A part's vertices
made with them would change in the last bit with the CPU (and the numpy release), and so would a
log's ``part_model.ply`` and the fits made on it (docs/fits.md, "The part meshes built the same on every CPU").
These functions call Python's :mod:`math` (the C library's scalar ``sin``, ``cos``, ``atan2``)
element by element: the same bits whatever numpy dispatches, on every CPU where the C library picks
the same variant (glibc has FMA and non-FMA variants of each, chosen by CPU: one for every x86-64 with
AVX2 and FMA).

The arrays they take are a part's outline (tens of angles, hundreds for a frame's batch of parts):
a Python loop over them costs microseconds.
"""

from __future__ import annotations

import math

import numpy as np


def cos_sin(angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(cos(angles), sin(angles))`` by :func:`math.cos` and :func:`math.sin`, element by element.

    Parameters
    ----------
    angles : float ndarray
        Radians, any shape.

    Returns
    -------
    cos, sin : float64 ndarray
        The shape of ``angles``.
    """
    a = np.asarray(angles, np.float64)
    flat = a.ravel().tolist()
    c = np.array([math.cos(x) for x in flat], np.float64).reshape(a.shape)
    s = np.array([math.sin(x) for x in flat], np.float64).reshape(a.shape)
    return c, s


def atan2(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``arctan2(y, x)`` by :func:`math.atan2`, element by element (``y`` and ``x`` of one shape).

    Parameters
    ----------
    y, x : float ndarray
        Of one shape.

    Returns
    -------
    float64 ndarray
        Radians in [-π, π], the shape of ``y``.
    """
    yy, xx = np.asarray(y, np.float64), np.asarray(x, np.float64)
    if yy.shape != xx.shape:
        raise ValueError(f"atan2 takes y and x of one shape, got {yy.shape} and {xx.shape}")
    out = [math.atan2(b, a) for b, a in zip(yy.ravel().tolist(), xx.ravel().tolist())]
    return np.array(out, np.float64).reshape(yy.shape)
