"""Error types of zcut. Every error the library raises on bad input is a :class:`ZcutError`."""

from __future__ import annotations


class ZcutError(Exception):
    """Base class of every error zcut raises on purpose."""


class InputShapeError(ZcutError, ValueError):
    """An array argument has the wrong shape or dtype; the message names both."""


class ParameterError(ZcutError, ValueError):
    """A scalar parameter is out of range; the message names the argument and the value."""


class Cancelled(ZcutError):
    """The caller asked a long computation to stop (:func:`zcut.cancel.stop_when`) and it stopped part-way:
    there is no result, not a partial one."""


def describe_array(a: object) -> str:
    """Return ``"shape (H, W) float32"`` style text for messages."""
    shape = getattr(a, "shape", None)
    dtype = getattr(a, "dtype", None)
    if shape is None:
        return f"a {type(a).__name__}"
    return f"shape {tuple(shape)} {dtype}"
