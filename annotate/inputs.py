"""What a request to the labelling server carries, parsed and bounded before anything uses it.

A malformed request is a 4xx with a one-line reason (:class:`BadRequest`), never a 500: frame
indices and rectangle bounds are parsed by bounded patterns (a 5,000-digit index is 404), a JSON
body that nests deeper than :data:`MAX_JSON_DEPTH` or holds absurd numbers is 400 before the parser
recurses, and a label's masks must decode to the frame's shape (422). Pure functions of their
inputs: no server, no store.
"""

from __future__ import annotations

import base64
import binascii
import json
import re
from typing import Any

import numpy as np

from annotate.payload import runs_to_mask
from annotate.store import LabelValidationError, unpack_mask

MAX_JSON_DEPTH = 8
_INDEX = re.compile(r"[0-9]{1,9}")
_UINT = re.compile(r"[0-9]{1,9}")
_CLIENT_ID = re.compile(r"[A-Za-z0-9_-]{8,64}")


class BadRequest(Exception):
    """A request refused with ``status`` and a one-line message (and optional response headers)."""

    def __init__(self, status: int, message: str, *, headers: dict[str, str] | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.headers = headers or {}


def frame_index(raw: str) -> int:
    """A frame index from the URL path (404 unless 1 to 9 digits)."""
    if not _INDEX.fullmatch(raw):
        raise BadRequest(404, f"no frame {raw[:20]!r}")
    return int(raw)


def uint(value: str | None, name: str, *, hi: int) -> int:
    """A query parameter holding an integer in ``0..hi`` (400 otherwise)."""
    if value is None or not _UINT.fullmatch(value) or int(value) > hi:
        raise BadRequest(400, f"{name} must be an integer in 0..{hi}, got {str(value)[:20]!r}")
    return int(value)


def json_depth_ok(body: bytes, limit: int) -> bool:
    """True if no JSON nesting in ``body`` goes deeper than ``limit`` (strings skipped), checked
    before parsing: the parser's recursion is never reached."""
    depth, in_str, esc = 0, False, False
    for b in body:
        if in_str:
            if esc:
                esc = False
            elif b == 0x5C:
                esc = True
            elif b == 0x22:
                in_str = False
        elif b == 0x22:
            in_str = True
        elif b in (0x5B, 0x7B):
            depth += 1
            if depth > limit:
                return False
        elif b in (0x5D, 0x7D):
            depth -= 1
    return True


def parse_json_body(body: bytes) -> dict[str, Any]:
    """The JSON object of a request body; :class:`BadRequest` (400/422) for anything else."""
    if not json_depth_ok(body, MAX_JSON_DEPTH):
        raise BadRequest(400, f"body nests deeper than {MAX_JSON_DEPTH} levels")
    try:
        d = json.loads(body)
    except (ValueError, RecursionError):  # JSONDecodeError, bad UTF-8, a 5,000-digit number ...
        raise BadRequest(400, "body is not JSON") from None
    if not isinstance(d, dict):
        raise BadRequest(422, "body must be a JSON object")
    return d


def _nonneg_int(v: object) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and 0 <= v < 1 << 53


def base_revision(d: dict[str, Any]) -> int:
    """The revision a label body was edited from (0 when absent or null; 422 unless a non-negative integer)."""
    base = d.get("base_revision", 0)
    if base is None:
        return 0
    if not _nonneg_int(base):
        raise BadRequest(422, "base_revision must be a non-negative integer")
    return int(base)


def client_seq(d: dict[str, Any]) -> tuple[str | None, int | None]:
    """A label body's ``(client, seq)``: the page's id and its save counter, both or neither (422)."""
    client, seq = d.get("client"), d.get("seq")
    if client is not None or seq is not None:
        if not isinstance(client, str) or not _CLIENT_ID.fullmatch(client):
            raise BadRequest(422, "client must be 8..64 characters of A-Z a-z 0-9 _ -")
        if not _nonneg_int(seq):
            raise BadRequest(422, "seq must be a non-negative integer")
    return client, seq


def _decode_b64(value: object, name: str) -> bytes:
    if not isinstance(value, str):
        raise BadRequest(422, f"{name} must be a base64 string")
    try:
        return base64.b64decode(value, validate=True)
    except (binascii.Error, ValueError):
        raise BadRequest(422, f"{name} is not valid base64") from None


def _decode_mask(value: object, shape: tuple[int, int], name: str) -> np.ndarray:
    try:
        return unpack_mask(_decode_b64(value, name), shape)
    except LabelValidationError as e:
        raise BadRequest(422, f"{name}: {e}") from None


def _decode_runs(value: object, shape: tuple[int, int], name: str) -> np.ndarray:
    blob = _decode_b64(value, name)
    if len(blob) % 4:
        raise BadRequest(422, f"{name}: {len(blob)} bytes is not a whole number of uint32 runs")
    try:
        return runs_to_mask(np.frombuffer(blob, "<u4"), shape)
    except ValueError as e:
        raise BadRequest(422, f"{name}: {e}") from None


def label_masks(d: dict[str, Any], shape: tuple[int, int], valid: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """(L, R) from a label body: ``outliers``/``reviewed`` (zlib packed bits) or ``outliers_runs``/
    ``unreviewed_runs`` (uint32 runs of L and of valid ∧ ¬R).

    Parameters
    ----------
    d : dict
        The label body.
    shape : (int, int)
        The frame's (H, W).
    valid : (H, W) bool ndarray or None
        The frame's valid mask (the runs form needs it).

    Returns
    -------
    outliers, reviewed : (H, W) bool ndarray
    """
    if "outliers_runs" in d or "unreviewed_runs" in d:
        if valid is None:
            raise BadRequest(422, "unreviewed_runs needs the frame's valid mask, which the store lacks")
        L = _decode_runs(d.get("outliers_runs"), shape, "outliers_runs")
        unrev = _decode_runs(d.get("unreviewed_runs"), shape, "unreviewed_runs")
        if (unrev & ~valid).any():
            raise BadRequest(422, "unreviewed_runs marks invalid pixels")
        return L, valid & ~unrev
    return _decode_mask(d.get("outliers"), shape, "outliers"), _decode_mask(d.get("reviewed"), shape, "reviewed")
