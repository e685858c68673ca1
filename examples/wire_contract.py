"""The fedtrack wire contract (docs/wire.md) with nothing but zenoh and msgpack.

Shared by the two example programs of this folder; it imports no fedtrack module, so a
third party can copy it as it is.
"""

from __future__ import annotations

import json
import struct
from typing import Any

import msgpack
import zenoh

SCHEMA = 2  # fedtrack.wire.SCHEMA_VERSION
ENCODING = "application/msgpack"


def session(endpoint: str, wait_s: float = 30.0, config_file: str | None = None) -> zenoh.Session:
    """A Zenoh client of the deployment's router: explicit endpoint, no multicast, no shm; ``config_file``:
    a Zenoh JSON5 file loaded first, e.g. the mutual TLS of an authenticated deployment (its certificates)."""
    conf = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
    for key, value in {"mode": "client", "connect/endpoints": [endpoint], "listen/endpoints": [],
                       "connect/timeout_ms": int(wait_s * 1000),
                       "connect/retry": {"period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 2},
                       "scouting/multicast/enabled": False,
                       "transport/shared_memory/enabled": False}.items():
        conf.insert_json5(key, json.dumps(value))
    return zenoh.open(conf)


def array(values: list[float], shape: tuple[int, ...]) -> dict[str, Any]:
    """A wire array: float64, little-endian, row-major."""
    return {"dtype": "float64", "shape": list(shape), "data": struct.pack(f"<{len(values)}d", *values)}


def from_array(a: dict[str, Any]) -> list[float]:
    """The flat values of a wire array (float64 or int64)."""
    n = len(a["data"]) // 8
    return list(struct.unpack(f"<{n}{'d' if a['dtype'] == 'float64' else 'q'}", a["data"]))


def encode(type_name: str, **fields: Any) -> bytes:
    """A payload: one msgpack map with ``schema`` and ``type`` and every field of the message."""
    return msgpack.packb({"schema": SCHEMA, "type": type_name, **fields}, use_bin_type=True)


def decode(payload: bytes, type_name: str) -> dict[str, Any]:
    """The fields of a payload of ``type_name``; ValueError for anything else."""
    obj = msgpack.unpackb(payload, raw=False)
    if not isinstance(obj, dict) or obj.get("schema") != SCHEMA or obj.get("type") != type_name:
        raise ValueError(f"not a schema-{SCHEMA} {type_name}")
    return obj
