"""The check the suspects' tests share: :func:`zcut.suspects.grouping._kind_components` against the reference's
grown-mask labels (``ndimage.label`` numbering) and ``ndimage.find_objects``' boxes."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from zcut.suspects import _reference as ref
from zcut.suspects.grouping import _kind_components


def check_components(m: np.ndarray, r: int) -> None:
    """``_kind_components`` of the pixels of ``m`` at reach ``r`` equals the reference: the same count, the same
    label at every pixel, the same (r0, c0, r1, c1) box per label."""
    lab, n = ref._components_reference(m, r)
    flat = np.flatnonzero(m)
    got, n2, boxes = _kind_components(flat, m.shape, r)
    assert n2 == n
    np.testing.assert_array_equal(got, lab.ravel()[flat])
    want = [[s[0].start, s[1].start, s[0].stop, s[1].stop] for s in ndimage.find_objects(lab, max_label=n)]
    np.testing.assert_array_equal(boxes, np.array(want, np.int64).reshape(-1, 4))
