"""Fixtures the algorithms' tests share."""

from __future__ import annotations

import pytest


@pytest.fixture(params=["default", "one"])
def opencv_threads(request):
    """OpenCV on its default threads, then on one (a one-core machine: its precise transform is IPP's)."""
    import cv2

    n = cv2.getNumThreads()
    if request.param == "one":
        cv2.setNumThreads(1)
    yield request.param
    cv2.setNumThreads(n)
