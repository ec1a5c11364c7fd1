"""Errors of the replay package (logs, CLI input)."""

from __future__ import annotations

from zcut.errors import ZcutError


class LogFormatError(ZcutError):
    """A log (MCAP, PCD, PLY) cannot be read as zcut expects; the message names the problem."""


class OverCapError(LogFormatError):
    """A message or grid of a log is larger than a size cap (``max_message_bytes``, ``max_pixels``)."""


class LogDamageError(LogFormatError):
    """A log is damaged (truncated, corrupt chunk) so that not one frame could be delivered."""


class ConfigError(ZcutError, ValueError):
    """A configuration file or option is invalid; the message names the field and the value."""
