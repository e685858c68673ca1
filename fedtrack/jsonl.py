"""JSON Lines I/O with strict validation: every error names the file and line."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import orjson


class InputError(ValueError):
    """Invalid input data; the message names the file and line."""


def check_readable(p: Path) -> None:
    """An InputError naming ``p`` unless it is an existing regular file."""
    if not p.exists():
        raise InputError(f"{p}: file does not exist")
    if p.is_dir():
        raise InputError(f"{p}: is a directory, not a file")


def read_jsonl(path: str | Path) -> Iterator[tuple[int, dict[str, Any]]]:
    """Yield ``(line_number, object)`` for each non-blank line; anything that is not UTF-8 JSON
    objects, one per line (binary, UTF-16, nesting too deep, unreadable), raises InputError
    naming the file and line."""
    p = Path(path)
    check_readable(p)
    try:
        with p.open("rb") as fh:
            for lineno, raw in enumerate(fh, start=1):
                if raw.strip():
                    yield lineno, _parse_line(p, lineno, raw)
    except OSError as exc:
        raise InputError(f"{p}: cannot read: {exc.strerror or exc}") from exc


def _parse_line(p: Path, lineno: int, raw: bytes) -> dict[str, Any]:
    where = f"{p}:{lineno}"
    try:  # strict RFC 8259 JSON, 3x faster; anything else takes json's path and its messages
        obj = orjson.loads(raw)
    except orjson.JSONDecodeError:
        obj = None
    if isinstance(obj, dict):
        return obj
    try:
        line = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        hint = " (UTF-16?)" if raw[:2] in (b"\xff\xfe", b"\xfe\xff") else ""
        raise InputError(f"{where}: not UTF-8 text{hint}: byte {exc.start}") from exc
    try:
        obj = json.loads(line)
    except json.JSONDecodeError as exc:
        raise InputError(f"{where}: invalid JSON: {exc.msg}") from exc
    except RecursionError as exc:
        raise InputError(f"{where}: invalid JSON: nested too deeply") from exc
    if not isinstance(obj, dict):
        raise InputError(f"{where}: expected a JSON object")
    return obj


def write_jsonl(path: str | Path, rows: list[dict[str, Any]]) -> None:
    """Write one JSON object per line (numpy arrays become lists)."""
    with Path(path).open("w") as fh:
        for row in rows:
            fh.write(json.dumps(row, default=_to_builtin) + "\n")


def _to_builtin(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"not JSON serializable: {type(obj).__name__}")


#: Fields every measurement line may carry besides its format's own: ``kind``, ``seq`` and
#: ``stamp_ns`` (as the recorder and ``fedtrack.wire.measurement_to_replay`` write them) and
#: ``truth`` (written by the simulators, ignored by the estimators).
COMMON_FIELDS = frozenset({"t", "sensor", "R", "kind", "seq", "stamp_ns", "truth"})
POSITION_FIELDS = COMMON_FIELDS | {"z"}
SONAR_FIELDS = COMMON_FIELDS | {"z", "detections"}
RADAR_FIELDS = COMMON_FIELDS | {"z", "sensor_position"}


def check_fields(obj: dict[str, Any], allowed: frozenset[str], kind: str, where: str) -> None:
    """The one rule for input lines: a field outside ``allowed``, or a ``kind`` other than
    ``kind``, is an :class:`InputError` naming ``file:line`` and the field."""
    unknown = sorted(set(obj) - allowed)
    if unknown:
        raise InputError(f"{where}: unknown field {unknown[0]!r} (allowed: {', '.join(sorted(allowed))})")
    if obj.get("kind", kind) != kind:
        raise InputError(f"{where}: kind must be {kind!r} here, got {obj['kind']!r}")


def require(obj: dict[str, Any], key: str, where: str) -> Any:
    if key not in obj:
        raise InputError(f"{where}: missing field {key!r}")
    return obj[key]


def as_float(value: Any, name: str, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(f"{where}: {name} must be a finite number, got {value!r}")
    return float(value)


def as_vector(value: Any, name: str, where: str, size: int | None = None) -> np.ndarray:
    """A finite 1-D float vector (of length ``size`` if given)."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}: {name} must be a list of numbers") from exc
    if arr.ndim != 1 or (size is not None and arr.shape[0] != size):
        want = f"length {size}" if size is not None else "a flat list"
        raise InputError(f"{where}: {name} must be {want}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{where}: {name} contains NaN or infinity")
    return arr


def as_covariance(value: Any, name: str, where: str, size: int | None = None,
                  rtol: float = 1e-9) -> np.ndarray:
    """A finite, symmetric, positive-definite square matrix."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}: {name} must be a square matrix of numbers") from exc
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1] or (size is not None and arr.shape[0] != size):
        want = f"{size}x{size}" if size is not None else "square"
        raise InputError(f"{where}: {name} must be {want}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{where}: {name} contains NaN or infinity")
    scale = max(float(np.max(np.abs(arr))), 1e-300)
    if np.max(np.abs(arr - arr.T)) > rtol * scale:
        raise InputError(f"{where}: {name} is not symmetric")
    try:
        np.linalg.cholesky(arr)
    except np.linalg.LinAlgError as exc:
        raise InputError(f"{where}: {name} is not positive definite") from exc
    return arr


def position_line(obj: dict[str, Any], where: str) -> tuple[float, str, np.ndarray, np.ndarray]:
    """``(t, sensor, z, R)`` of a 2-D position measurement line ``{"t", "sensor", "z", "R"}``."""
    check_fields(obj, POSITION_FIELDS, "position", where)
    t = as_float(require(obj, "t", where), "t", where)
    sensor = require(obj, "sensor", where)
    if not isinstance(sensor, str) or not sensor:
        raise InputError(f"{where}: sensor must be a non-empty string, got {sensor!r}")
    z = as_vector(require(obj, "z", where), "z", where, size=2)
    R = as_covariance(require(obj, "R", where), "R", where, size=2)
    return t, sensor, z, R
