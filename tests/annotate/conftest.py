"""Fixtures of the page's tests."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="module")
def fits_memo() -> dict:
    """A module's page fits, by the content of their inputs (``fits_once``)."""
    return {}


@pytest.fixture
def fits_once(fits_memo, monkeypatch) -> None:
    """A page server's background fits of a frame made once for the servers of a test module
    (tests/annotate_helpers.py, ``fits_once``: keyed by the content of every input, so a call whose inputs differ in
    any bit computes its own). A module asks for it per test, or for every test with
    ``pytest.mark.usefixtures("fits_once")``; not for a test of a page used while its frames are fitted, whose fits
    must take their time."""
    from annotate_helpers import fits_once as memoize

    memoize(monkeypatch, fits_memo)
