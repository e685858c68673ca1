"""Encoding and decoding: a message as a msgpack map, checked whole on decoding (docs/wire.md); the
union of message types."""

from __future__ import annotations

import math
from typing import Any, TypeVar

import msgpack
import numpy as np

import fedtrack.wire.limits as limits
from fedtrack.wire.batches import _BATCH_CHECKS, HandOver, TrackPicture, TrackReport, TrackResets
from fedtrack.wire.fields import _sequence
from fedtrack.wire.limits import (
    _ENVELOPE,
    BRIEF_CHARS,
    MAX_ARRAY_ELEMENTS,
    MAX_BATCH_ELEMENTS,
    MAX_CONTAINER_ITEMS,
    MAX_DEPTH,
    MAX_DETECTIONS,
    MAX_ITEMS,
    MAX_MAGNITUDE,
    MAX_MAP_ITEMS,
    MAX_PAYLOAD_BYTES,
    MAX_STRING_LENGTH,
    SCHEMA_VERSION,
    WIRE_DTYPES,
    WireError,
    brief,
)
from fedtrack.wire.records import (
    Detection,
    FusedTrack,
    Health,
    LocalEstimate,
    ManeuverEvent,
    Measurement,
    Reset,
    _Record,
    _record_fields,
)

M = TypeVar("M", bound=_Record)
Message = (Measurement | LocalEstimate | Reset | FusedTrack | ManeuverEvent | Health | TrackReport | TrackResets
           | TrackPicture | HandOver)
MESSAGE_TYPES: tuple[type[_Record], ...] = (Measurement, LocalEstimate, Reset, FusedTrack, ManeuverEvent, Health,
                                            TrackReport, TrackResets, TrackPicture, HandOver)


def _encode_array(arr: np.ndarray) -> dict[str, Any]:
    """The wire map of ``arr``: its values as little-endian float64, row-major (``tobytes`` copies
    in C order, so an array already of that dtype needs no conversion first)."""
    data = arr.tobytes() if arr.dtype == WIRE_DTYPES["float64"] else arr.astype("<f8").tobytes()
    return {"dtype": "float64", "shape": list(arr.shape), "data": data}


def _encode_record(rec: _Record) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for f in _record_fields(type(rec)):
        value = getattr(rec, f.name)
        if f.name in rec._omitted and (value is None or value == () or value == f.default) and not (
                f.name == "part" and rec.parts > 1):  # type: ignore[attr-defined]
            continue
        if value is None:
            out[f.name] = None
        elif f.name in rec._arrays:
            out[f.name] = _encode_array(value)
        elif f.name in rec._records:
            out[f.name] = ([_encode_record(v) for v in value] if isinstance(value, tuple)
                           else _encode_record(value))
        elif isinstance(value, tuple):
            out[f.name] = list(value)
        elif isinstance(value, dict):
            out[f.name] = {k: list(v) if isinstance(v, tuple) else v for k, v in value.items()}
        else:
            out[f.name] = value
    return out


def _pack(msg: Message) -> bytes:
    """The msgpack bytes of ``msg``, its envelope first (no bound checked)."""
    return msgpack.packb({"schema": SCHEMA_VERSION, "type": type(msg).__name__, **_encode_record(msg)},
                         use_bin_type=True)


def encode(msg: Message) -> bytes:
    """msgpack bytes of ``msg``; WireError if a batch of it exceeds its bound in one message
    (:func:`payloads` sends such a message in parts) or the bytes exceed MAX_PAYLOAD_BYTES."""
    if not isinstance(msg, MESSAGE_TYPES):
        raise WireError("message", f"not a wire message type: {type(msg).__name__}")
    name = type(msg).__name__
    _check_counts(msg, " (send it in parts: fedtrack.wire.multipart)")
    payload = _pack(msg)
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise WireError(name, f"encoded size {len(payload)} bytes exceeds the limit of {MAX_PAYLOAD_BYTES}")
    return payload


def _decode_array(value: Any, path: str, limit: int = MAX_ARRAY_ELEMENTS) -> np.ndarray | None:
    if value is None:
        return None
    if not isinstance(value, dict) or set(value) != {"dtype", "shape", "data"}:
        raise WireError(path, "expected an array map {dtype, shape, data}")
    dtype = WIRE_DTYPES.get(value["dtype"]) if isinstance(value["dtype"], str) else None
    if dtype is None:
        raise WireError(f"{path}.dtype", f"expected 'float64' or 'int64', got {brief(value['dtype'])}")
    shape = value["shape"]
    if (not isinstance(shape, list) or len(shape) > 2
            or not all(isinstance(d, int) and not isinstance(d, bool) and 0 <= d <= limit for d in shape)):
        raise WireError(f"{path}.shape", f"expected a list of at most 2 sizes in [0, {limit}], got {brief(shape)}")
    size = math.prod(shape)
    if size > limit:
        raise WireError(path, f"{size} elements exceed the limit of {limit}")
    data = value["data"]
    if not isinstance(data, bytes) or len(data) != size * dtype.itemsize:
        got = f"{len(data)} bytes" if isinstance(data, bytes) else type(data).__name__
        raise WireError(f"{path}.data", f"expected {size * dtype.itemsize} bytes for shape {shape}, got {got}")
    return np.frombuffer(data, dtype=dtype).reshape(shape)


_DETECTION_KEYS = {"z", "amplitude"}
_ARRAY_KEYS = {"dtype", "shape", "data"}


def _regular_detections(items: list[Any]) -> list[Detection] | None:
    """The detections of a regular, valid wire list decoded at once, or None to take the per-item
    path (:func:`_decode_record` on each, which then raises the error of the first bad one).

    Regular: at least one item; every item a map of exactly ``z`` and ``amplitude``; every ``z`` an
    array map of exactly ``dtype``, ``shape``, ``data`` with the same wire dtype and the same 1-D
    shape, and its data of the right length; every amplitude a real within +-MAX_MAGNITUDE. The ``z`` data are
    joined and checked with one magnitude reduction (as :func:`_array`); the records are built
    without re-running their field checks, so that they equal the per-item path's: read-only
    float64 ``z`` (a row of one array), float ``amplitude``."""
    first = items[0].get("z") if items and type(items[0]) is dict else None
    if type(first) is not dict:
        return None
    name, shape = first.get("dtype"), first.get("shape")
    dtype = WIRE_DTYPES.get(name) if type(name) is str else None
    if (dtype is None or type(shape) is not list or len(shape) != 1 or type(shape[0]) is not int
            or not 0 <= shape[0] <= MAX_ARRAY_ELEMENTS):
        return None
    nbytes = shape[0] * dtype.itemsize
    if not all(type(item) is dict and item.keys() == _DETECTION_KEYS
               and type(z := item["z"]) is dict and z.keys() == _ARRAY_KEYS and z["dtype"] == name
               and type(s := z["shape"]) is list and s == shape and type(s[0]) is int
               and type(data := z["data"]) is bytes and len(data) == nbytes
               and (type(a := item["amplitude"]) is float or type(a) is int) for item in items):
        return None
    amplitudes = [float(item["amplitude"]) for item in items]
    if not all(abs(a) <= MAX_MAGNITUDE for a in amplitudes):  # NaN fails too: the per-item path names it
        return None
    block = np.frombuffer(b"".join([item["z"]["data"] for item in items]), dtype=dtype).reshape(len(items), shape[0])
    block = block.astype(np.float64, copy=False)
    if block.size and not np.abs(block).max() <= MAX_MAGNITUDE:
        return None
    block.setflags(write=False)
    new, put = object.__new__, object.__setattr__
    out = []
    for z, amplitude in zip(block, amplitudes):  # rows of the read-only block: read-only views
        det = new(Detection)
        put(det, "z", z)
        put(det, "amplitude", amplitude)
        out.append(det)
    return out


def _decode_record(cls: type[M], obj: Any, path: str, envelope: tuple[str, ...] = ()) -> M:
    if not isinstance(obj, dict):
        raise WireError(path, f"expected a map, got {type(obj).__name__}")
    names = [f.name for f in _record_fields(cls)]
    unknown = sorted((str(k) for k in obj if k not in names and k not in envelope))
    if unknown:
        raise WireError(f"{path}.{unknown[0][:BRIEF_CHARS]}", "unknown field")
    missing = [n for n in names if n not in obj and n not in cls._omitted]
    if missing:
        raise WireError(f"{path}.{missing[0]}", "missing field")
    kwargs: dict[str, Any] = {}
    for name in names:
        if name not in obj:  # an omitted field: its default
            continue
        value = obj[name]
        where = f"{path}.{name}"
        if name in cls._arrays:
            limit = MAX_BATCH_ELEMENTS if cls._fields[name] in _BATCH_CHECKS else MAX_ARRAY_ELEMENTS
            value = _decode_array(value, where, limit)
        elif name in cls._records and value is not None:
            sub = cls._records[name]
            if isinstance(value, list):
                items = _sequence(value, where, MAX_DETECTIONS)
                regular = _regular_detections(items) if sub is Detection else None
                value = regular if regular is not None else [_decode_record(sub, v, f"{where}[{i}]")
                                                             for i, v in enumerate(items)]
            else:
                value = _decode_record(sub, value, where)
        kwargs[name] = value
    try:
        return cls(**kwargs)
    except WireError as exc:
        if cls._top_level:
            raise
        raise WireError(f"{path}.{exc.field}", exc.reason) from None


def unpack(payload: bytes | bytearray | memoryview) -> Any:
    """The msgpack structure of an untrusted payload, within the limits: at most MAX_PAYLOAD_BYTES,
    strings of at most 4 MAX_STRING_LENGTH bytes, byte strings of at most the largest array's data,
    MAX_CONTAINER_ITEMS items in a list, 2 MAX_MAP_ITEMS entries in a map, no extension types
    (msgpack's own limits, checked while it parses, without recursion), then nesting at most
    MAX_DEPTH containers deep and MAX_ITEMS items in all (an iterative walk). WireError otherwise,
    its message a bounded summary (never the payload)."""
    if not isinstance(payload, (bytes, bytearray, memoryview)):
        raise WireError("payload", f"expected bytes, got {type(payload).__name__}")
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise WireError("payload", f"{len(payload)} bytes exceed the limit of {MAX_PAYLOAD_BYTES}")
    try:
        obj = msgpack.unpackb(payload, raw=False, strict_map_key=True, use_list=True,
                              max_str_len=4 * MAX_STRING_LENGTH, max_bin_len=8 * MAX_BATCH_ELEMENTS,
                              max_array_len=MAX_CONTAINER_ITEMS, max_map_len=2 * MAX_MAP_ITEMS, max_ext_len=0)
    except Exception as exc:  # msgpack raises many types (ExtraData, StackError, ValueError, ...)
        raise WireError("payload", f"not valid msgpack within the limits ({type(exc).__name__}: "
                                   f"{brief(str(exc), 2 * BRIEF_CHARS)})") from None
    _check_structure(obj)
    return obj


def _check_structure(obj: Any) -> None:
    """WireError if ``obj`` nests containers more than MAX_DEPTH deep or holds more than MAX_ITEMS
    items in all. A walk level by level (no recursion on untrusted data) finds a structure
    within both limits; one beyond either is walked again by :func:`_structure_error`, whose
    depth-first order decides which limit the error names."""
    level = [obj] if isinstance(obj, (dict, list)) else []
    items = 0
    for _ in range(MAX_DEPTH):
        items += sum(map(len, level))
        if items > MAX_ITEMS:
            break
        level = [child for value in level for child in (value.values() if type(value) is dict else value)
                 if type(child) is dict or type(child) is list]
        if not level:
            return
    _structure_error(obj)


def _structure_error(obj: Any) -> None:
    """WireError if ``obj`` nests containers more than MAX_DEPTH deep or holds more than MAX_ITEMS
    items in all, naming the limit met first depth-first (an explicit stack: no recursion)."""
    if not isinstance(obj, (dict, list)):
        return
    stack: list[tuple[Any, int]] = [(obj, 1)]
    items = 0
    while stack:
        value, depth = stack.pop()
        if depth > MAX_DEPTH:
            raise WireError("payload", f"containers nested more than {MAX_DEPTH} deep")
        children = value.values() if type(value) is dict else value
        items += len(children)
        if items > MAX_ITEMS:
            raise WireError("payload", f"more than {MAX_ITEMS} items in all")
        kinds = set(map(type, children))  # msgpack builds exactly dict and list; most lists hold none
        if dict in kinds or list in kinds:
            stack.extend((child, depth + 1) for child in children if type(child) is dict or type(child) is list)


def decode(payload: bytes | bytearray | memoryview, expected_type: type[M]) -> M:
    """Decode and validate a payload that must hold a message of ``expected_type``.

    Raises WireError (naming the field) for anything else: garbage bytes, a structure beyond
    the limits of :func:`unpack` (checked first), a different schema version or type,
    unknown/missing fields, wrong types, shapes or dtypes, NaN/inf, non-symmetric or non-PD
    covariances, size bounds. Its message quotes no more than :func:`brief` of any value.
    """
    name = expected_type.__name__
    obj = unpack(payload)
    if not isinstance(obj, dict):
        raise WireError("payload", f"expected a msgpack map, got {type(obj).__name__}")
    schema = obj.get("schema")
    if "schema" not in obj:
        raise WireError(f"{name}.schema", "missing field")
    if isinstance(schema, bool) or schema != SCHEMA_VERSION:
        raise WireError(f"{name}.schema", f"unsupported schema version {brief(schema)} (expected {SCHEMA_VERSION})")
    if obj.get("type") != name:
        raise WireError(f"{name}.type", f"expected {name!r}, got {brief(obj.get('type'))}")
    msg = _decode_record(expected_type, obj, name, _ENVELOPE)
    _check_counts(msg)
    return msg




def _count_over(msg: _Record) -> tuple[str, int, int] | None:
    """The first batch of ``msg`` beyond its bound in one message: (field, items, bound); else None."""
    for items in msg._items:
        n, limit = len(getattr(msg, items.fields[0])), getattr(limits, items.limit)
        if n > limit:
            return items.fields[0], n, limit
    return None


def _check_counts(msg: _Record, hint: str = "") -> None:
    """WireError naming the field when a batch of ``msg`` exceeds its bound in one message."""
    over = _count_over(msg)
    if over is not None:
        name, n, limit = over
        raise WireError(f"{type(msg).__name__}.{name}", f"{n} items exceed the limit of {limit} per message{hint}")
