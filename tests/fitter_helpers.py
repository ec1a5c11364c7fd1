"""What the labelling page's fitter did (tests/ is on sys.path): how each of its fits ended."""

from __future__ import annotations

from typing import Any

import pytest

import annotate.fits


def ends_of_fits(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """How each fit an :class:`annotate.fits.Fitter` runs (:func:`annotate.fits.fit_frame`, looked up at each call)
    ends, in order: ``returned``, or its exception's name (``Cancelled``: stopped part-way, :mod:`zcut.cancel`)."""
    ends: list[str] = []
    inner = annotate.fits.fit_frame

    def noted(*args: Any, **kw: Any) -> Any:
        try:
            got = inner(*args, **kw)
        except BaseException as e:
            ends.append(type(e).__name__)
            raise
        ends.append("returned")
        return got

    monkeypatch.setattr(annotate.fits, "fit_frame", noted)
    return ends
