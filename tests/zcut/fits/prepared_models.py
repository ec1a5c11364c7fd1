"""The part models the fits tests prepare, prepared once per test session: :func:`zcut.fits.prepare_model` costs
~2.5 CPU s a mesh (its samples, symmetries, voxel index and ray-casting scene), the same for a 12-triangle box
as for the nut, and the fits tests prepare the same few meshes again and again. The preparation is deterministic
(the same mesh gives the same arrays to the bit), so a test given the session's model sees what a fresh
preparation gives it. The tests only read a model; a test that needs a model of its own options calls
:func:`zcut.fits.prepare_model` itself."""

from __future__ import annotations

import numpy as np

from zcut.fits import prepare_model
from zcut.fits.model import PartModel

_PREPARED: dict[tuple[bytes, ...], PartModel] = {}


def prepared(vertices_mm: np.ndarray, triangles: np.ndarray) -> PartModel:
    """``prepare_model(vertices_mm, triangles)``, made once per session for each mesh (keyed by the two arrays'
    dtypes, shapes and bytes)."""
    v, t = np.asarray(vertices_mm), np.asarray(triangles)
    key = (str(v.dtype).encode(), repr(v.shape).encode(), v.tobytes(), str(t.dtype).encode(), repr(t.shape).encode(),
           t.tobytes())
    if key not in _PREPARED:
        _PREPARED[key] = prepare_model(v, t)
    return _PREPARED[key]
