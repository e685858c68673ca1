"""The wire's bounds and constants, its error type, and :func:`brief` for untrusted values in messages."""

from __future__ import annotations

from typing import Any

import numpy as np

SCHEMA_VERSION = 2
MAX_PAYLOAD_BYTES = 2 * 1024 * 1024
MAX_ARRAY_ELEMENTS = 4096
MAX_MAGNITUDE = 1e100  # no quantity of the contract comes near; squares stay finite

MAX_DETECTIONS = 2048
MAX_STRING_LENGTH = 256
MAX_LIST_ITEMS = 64
MAX_MAP_ITEMS = 32
SYMMETRY_RTOL = 1e-9
PD_RTOL = 1e-12
FLOAT_EPS = float(np.finfo(np.float64).eps)  # a measurement's noise is at least its own rounding (_check_resolvable)
MEASUREMENT_KINDS = ("position", "radar", "sonar", "scan")
MAX_TRACKS = 2048  # tracks in one multi-target report or picture
MAX_BATCH_ELEMENTS = MAX_TRACKS * 36  # a batched array: MAX_TRACKS 6x6 covariances
# a message whose batch exceeds a bound goes in at most MAX_PARTS parts, each within every bound
# (:func:`parts`, :func:`join`; docs/wire.md, "Messages in parts"): 64 x 2048 = 131,072 tracks in one
# picture, above issue 27's national picture of 10^5; the receivers' reassembly holds at most
# MAX_PARTS x MAX_PAYLOAD_BYTES = 128 MiB of one message
MAX_PARTS = 64
# bounds of the msgpack structure itself, checked before any field is looked at (docs/wire.md, "Limits"):
# the deepest message is 5 containers deep (Measurement -> detections -> detection -> z -> shape)
MAX_DEPTH = 8
MAX_CONTAINER_ITEMS = max(MAX_DETECTIONS, MAX_TRACKS)  # a list's items (a map's: 2 * MAX_MAP_ITEMS)
MAX_ITEMS = MAX_TRACKS * (MAX_LIST_ITEMS + 16)  # items of all containers together (a picture's sensor lists)
BRIEF_CHARS = 40  # an untrusted value in an error message: at most this much of it (:func:`brief`)
EVENT_KINDS = ("onset", "new-ca", "end")
WIRE_DTYPES = {"float64": np.dtype("<f8"), "int64": np.dtype("<i8")}
_INT64_MAX = 2**63 - 1
_ENVELOPE = ("schema", "type")


class WireError(ValueError):
    """A message that cannot be encoded or decoded; ``field`` names the offending field."""

    def __init__(self, field_name: str, reason: str) -> None:
        super().__init__(f"{field_name}: {reason}")
        self.field = field_name
        self.reason = reason


def brief(value: Any, limit: int = BRIEF_CHARS) -> str:
    """A bounded description of an untrusted value for an error message or a log line: a
    container by its type and size only (never its contents, so never a recursion), a string or
    bytes by its first ``limit`` characters, anything else by at most ``limit`` characters of its repr."""
    if isinstance(value, (dict, list, tuple, set)):
        return f"<{type(value).__name__} of {len(value)}>"
    if isinstance(value, (str, bytes, bytearray)):
        more = f"... ({len(value)} in all)" if len(value) > limit else ""
        return repr(value[:limit]) + more
    if isinstance(value, (bool, int, float, np.integer, np.floating)) or value is None:
        text = repr(value)
        return text if len(text) <= limit else f"{text[:limit]}..."
    return f"<{type(value).__name__}>"
