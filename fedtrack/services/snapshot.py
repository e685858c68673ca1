"""A service's state file for its restarts within a run (the fusion centre's state, the picture
merger's last merged time): written whole (:func:`fedtrack.atomic.write_atomic`: a kill leaves the
previous one), behind a BLAKE2b digest of its data that is checked before anything reads the data,
so a file cut or corrupted on disk is refused, never half-read; and its data only data (docs/deploy.md,
"Snapshot format"): a record of numpy arrays as msgpack maps ``{dtype, shape, data}``, rebuilt only
into the arrays of a template the reader makes itself (:func:`record_maps`, :func:`record_from_maps`),
never an object the file names (a pickle would run whatever code its writer put in it)."""

from __future__ import annotations

from hashlib import blake2b
from pathlib import Path
from typing import Any, NamedTuple, TypeVar

import numpy as np

from fedtrack.atomic import write_atomic
from fedtrack.config import read_small_file
from fedtrack.wire import MAX_PAYLOAD_BYTES

DIGEST_BYTES = 32
MAX_SNAPSHOT_BYTES = MAX_PAYLOAD_BYTES  # a larger file is refused unread
STATE_DTYPES = {"float64": np.dtype("<f8"), "int64": np.dtype("<i8"), "bool": np.dtype("?")}
R = TypeVar("R", bound=NamedTuple)


class SnapshotError(ValueError):
    """A snapshot that this build does not take; the message names the field and the reason."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(f"{field}: {reason}")
        self.field = field


def write_sealed(path: Path, magic: bytes, data: bytes) -> None:
    """Write ``magic``, the digest of ``data`` and ``data`` to ``path``, atomically
    (:func:`fedtrack.atomic.write_atomic`, not fsync'ed: a snapshot serves a restart of its process, and
    is written after every scan or picture); on an OSError (the disk full, the file size limit, no file
    descriptor left), raised as it came, ``path`` is as it was and no temporary file is left."""
    write_atomic(path, magic + blake2b(data, digest_size=DIGEST_BYTES).digest() + data, durable=False)


def read_sealed(path: Path, magic: bytes) -> bytes:
    """The data of the file ``path`` written by :func:`write_sealed` (:func:`unsealed`); a ValueError for
    one missing, not a regular file or larger than MAX_SNAPSHOT_BYTES (read no further:
    :func:`~fedtrack.config.read_small_file`)."""
    raw = read_small_file(path, MAX_SNAPSHOT_BYTES, "snapshot")
    if raw is None:
        raise SnapshotError("file", f"{path} does not exist")
    return unsealed(raw, magic)


def unsealed(raw: bytes, magic: bytes) -> bytes:
    """The data of a file's bytes ``raw`` written by :func:`write_sealed` with ``magic`` (a name and
    a version, ``b"fedtrack-centre-2\\n"``); ValueError when it is not one, is of another version, or
    its digest does not match (a corrupted or cut file)."""
    head = len(magic) + DIGEST_BYTES
    name = magic.decode(errors="replace").strip()
    if not raw.startswith(magic):
        first, newline, _ = raw[:64].partition(b"\n")
        kind, _, version = first.rpartition(b"-")
        if newline and kind == magic.rstrip(b"\n").rpartition(b"-")[0]:
            raise ValueError(f"version {version.decode(errors='replace')!r} of the format: this build reads {name}")
        raise ValueError(f"not a {name} file")
    if len(raw) < head:
        raise ValueError(f"cut short: {len(raw)} bytes, less than its {head}-byte head")
    data = raw[head:]
    if blake2b(data, digest_size=DIGEST_BYTES).digest() != raw[len(magic):head]:
        raise ValueError("checksum mismatch (a corrupted or cut file)")
    return data


def record_maps(record: NamedTuple) -> dict[str, Any]:
    """``record`` (a NamedTuple of numpy arrays, records nested) as msgpack-ready maps: each array
    ``{"dtype": "float64" | "int64" | "bool", "shape": [...], "data": little-endian C-order bytes}``."""
    out: dict[str, Any] = {}
    for name, value in record._asdict().items():
        if isinstance(value, tuple):
            out[name] = record_maps(value)  # type: ignore[arg-type]
            continue
        arr = np.asarray(value)
        dtype = next(k for k, d in STATE_DTYPES.items() if d.kind == arr.dtype.kind)
        out[name] = {"dtype": dtype, "shape": list(arr.shape), "data": arr.astype(STATE_DTYPES[dtype]).tobytes()}
    return out


def record_from_maps(obj: Any, template: R, path: str) -> R:
    """The record of :func:`record_maps`'s ``obj``, every field of ``template`` (a record the reader
    made: its fields, arrays' dtypes and shapes are what ``obj`` must hold exactly) and nothing else,
    floats finite, booleans 0 or 1; SnapshotError naming the field (``path.name``) otherwise. The
    arrays are writeable copies."""
    fields = template._asdict()
    if not isinstance(obj, dict):
        raise SnapshotError(path, f"expected a map, got {type(obj).__name__}")
    if set(obj) != set(fields):
        extra, missing = sorted(map(str, set(obj) - set(fields))), sorted(set(fields) - set(obj))
        raise SnapshotError(path, f"fields {missing} missing, {extra} unknown"[:200])
    values = []
    for name, like in fields.items():
        where = f"{path}.{name}"
        values.append(record_from_maps(obj[name], like, where) if isinstance(like, tuple)
                      else _array(obj[name], np.asarray(like), where))
    return type(template)(*values)


def _array(value: Any, like: np.ndarray, path: str) -> np.ndarray:
    """The array of the map ``value``, of ``like``'s dtype and shape (:func:`record_from_maps`)."""
    if not isinstance(value, dict) or set(value) != {"dtype", "shape", "data"}:
        raise SnapshotError(path, "expected an array map {dtype, shape, data}")
    dtype = STATE_DTYPES.get(value["dtype"]) if isinstance(value["dtype"], str) else None
    if dtype is None or dtype.kind != like.dtype.kind:
        raise SnapshotError(f"{path}.dtype", f"expected {like.dtype.name}, got {str(value['dtype'])[:40]!r}")
    if value["shape"] != list(like.shape):
        raise SnapshotError(f"{path}.shape", f"expected {list(like.shape)}, got {str(value['shape'])[:40]}")
    data = value["data"]
    if not isinstance(data, bytes) or len(data) != like.size * dtype.itemsize:
        raise SnapshotError(f"{path}.data", f"expected {like.size * dtype.itemsize} bytes for shape {list(like.shape)}")
    raw = np.frombuffer(data, dtype=np.uint8 if dtype.kind == "b" else dtype)
    if dtype.kind == "f" and not np.isfinite(raw).all():
        raise SnapshotError(path, "contains NaN or infinity")
    if dtype.kind == "b" and raw.size and raw.max() > 1:
        raise SnapshotError(path, "a boolean other than 0 or 1")
    return raw.astype(like.dtype).reshape(like.shape)
