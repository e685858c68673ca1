"""JSON Lines I/O with strict validation: every error names the file and line; and the one way
every command writes an output file (:func:`output_file`: checked up front, written whole or not
at all)."""

from __future__ import annotations

import contextlib
import errno
import json
import math
import sys
from pathlib import Path
from typing import IO, Any, Iterator

import numpy as np
import orjson

from fedtrack.atomic import atomic_file
from fedtrack.config import did_you_mean

STORAGE_FULL = frozenset({errno.ENOSPC, errno.EFBIG, errno.EDQUOT})  # a write the disk or a limit refused


class InputError(ValueError):
    """Invalid input data; the message names the file and line."""


def check_readable(p: Path) -> None:
    """An InputError naming ``p`` unless it is an existing regular file."""
    if not p.exists():
        raise InputError(f"{p}: file does not exist")
    if p.is_dir():
        raise InputError(f"{p}: is a directory, not a file")


def check_output(path: str | Path) -> Path:
    """``path`` as an output file, or an InputError naming it: its folder must exist (fedtrack never
    creates missing folders) and it must not be a folder itself. Every command checks its outputs
    with this before it starts work, and :func:`output_file` checks again when it writes."""
    p = Path(path)
    if p.is_dir():
        raise InputError(f"{p}: is a folder; name a file to write")
    folder = p.parent
    if not folder.is_dir():
        raise InputError(f"{p}: the folder {folder} does not exist (fedtrack does not create folders; "
                         "create it first)")
    return p


def _file_key(path: Path) -> tuple[Any, ...]:
    """What makes two paths one file: an existing file's device and inode (a link, ``./x`` or another spelling of
    it), a missing one's resolved path."""
    try:
        st = path.stat()
    except OSError:
        return ("path", str(path.resolve()))
    return ("inode", st.st_dev, st.st_ino)


def check_outputs(outputs: dict[str, str | Path | None], inputs: dict[str, str | Path | None] | None = None) -> None:
    """:func:`check_output` of each of a command's ``outputs`` (option -> path; None: not given), and an InputError
    naming both options when an output is one of its ``inputs`` or another output, by any path: written whole at the
    end, it would replace what the command read or wrote first (before the tour60 session ``replay --out M
    --measurements M`` left the estimates where the measurements had been, and ``export --tracks R --db R`` wrote
    the tracks over the recording database)."""
    seen = {_file_key(Path(p)): option for option, p in (inputs or {}).items() if p is not None}
    for option, p in outputs.items():
        if p is None:
            continue
        key = _file_key(check_output(p))
        if key in seen:
            raise InputError(f"{p}: {option} is also {seen[key]} (an output is written whole at the end and would "
                             "replace it; give another path)")
        seen[key] = option


def check_output_folder(path: str | Path) -> Path:
    """``path`` as a folder a command will write several files into, or an InputError naming it:
    a folder, or missing in a folder that exists (the rule of :func:`check_output`). A command
    checks it before it starts work and creates it (:func:`output_folder`) when it writes."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InputError(f"{p}: exists and is not a folder")
    if not p.is_dir():
        check_output(p)
    return p


def output_folder(path: str | Path) -> Path:
    """``path`` as a folder a command writes several files into (``simulate --out DIR``): created
    if missing, but its own folder must exist (the rule of :func:`check_output`: fedtrack creates
    what it is told to write, never the folders above it); an InputError naming it otherwise."""
    p = check_output_folder(path)
    if not p.is_dir():
        try:
            p.mkdir()
        except OSError as exc:
            raise InputError(f"{p}: cannot create: {exc.strerror or exc}") from None
    return p


@contextlib.contextmanager
def output_file(path: str | Path, mode: str = "w") -> Iterator[IO[Any]]:
    """Write ``path`` whole or not at all (:func:`fedtrack.atomic.atomic_file`: a temporary file in the
    same folder, fsync'ed and renamed onto ``path`` when the block ends without an exception, removed
    when it raises), so an error half-way (a bad input line, Ctrl-C) leaves no half-written output
    and an existing file untouched. ``mode`` is ``"w"`` (text) or ``"wb"``. The disk full or the file size limit
    reached while it is written is an InputError naming ``path`` (a write's OSError names no file:
    before 2026-11-27 the launcher said 'could not export the recording: None: cannot write')."""
    p = check_output(path)
    entered = False
    try:
        with atomic_file(p, mode) as fh:
            entered = True
            yield fh
    except OSError as exc:  # the temporary file is gone (fedtrack.atomic); the output named
        if not entered or (exc.filename is None and exc.errno in STORAGE_FULL):
            raise InputError(f"{p}: cannot write: {exc.strerror or exc}") from None
        raise


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
        word = line[exc.pos:exc.pos + 9].lower()
        hint = (" (nan and infinity are not JSON numbers: a finite number is expected)"
                if word.startswith(("nan", "inf", "-inf", "-nan")) else "")
        raise InputError(f"{where}: invalid JSON at column {exc.colno}: {exc.msg}{hint}") from exc
    except RecursionError as exc:
        raise InputError(f"{where}: invalid JSON: nested too deeply") from exc
    except ValueError as exc:  # an integer of more digits than Python converts
        raise InputError(f"{where}: invalid JSON: a number of more than {sys.get_int_max_str_digits()} digits") from exc
    if not isinstance(obj, dict):
        raise InputError(f"{where}: expected a JSON object")
    return obj


def write_jsonl(path: str | Path, rows: list[dict[str, Any]]) -> None:
    """Write one JSON object per line (numpy arrays become lists), whole or not at all."""
    with output_file(path) as fh:
        for row in rows:
            fh.write(json.dumps(row, default=_to_builtin) + "\n")


def _to_builtin(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"not JSON serializable: {type(obj).__name__}")


#: Unknown fields that mean the file is of another format than the algorithm reads: the hint
#: ``(the reader's kind, the field) -> what to do``.
FORMAT_HINTS = {
    ("position", "detections"): "this is a scan of detections: replay it with --algorithm mtt-local, "
                                "mtt-centralized, mtt-federated or mtt-decentralized (pda-ai or hpda for sonar "
                                "scans with amplitudes)",
    ("position", "sensor_position"): "this is a radar line: replay it with --algorithm ekf, ekf-ie or ekf-tsfuzzy",
    ("radar", "detections"): "this is a scan of detections: replay it with --algorithm mtt-*",
    ("sonar", "sensor_position"): "this is a radar scan: replay it with --algorithm mtt-*",
    ("mtt", "z"): "this is a single measurement, not a scan: replay it with --algorithm kf (or another "
                  "single-target algorithm), or write a scan's detections as \"detections\": [{\"z\": [...]}]",
}

#: Fields every measurement line may carry besides its format's own: ``kind``, ``seq`` and
#: ``stamp_ns`` (as the recorder and ``fedtrack.wire.measurement_to_replay`` write them) and
#: ``truth`` (written by the simulators, ignored by the estimators).
COMMON_FIELDS = frozenset({"t", "sensor", "R", "kind", "seq", "stamp_ns", "truth"})
POSITION_FIELDS = COMMON_FIELDS | {"z"}
SONAR_FIELDS = COMMON_FIELDS | {"z", "detections"}
RADAR_FIELDS = COMMON_FIELDS | {"z", "sensor_position"}


#: a picture line's rows: a tracks file's "tracks", a truth file's "targets" (one given for the other is named)
PICTURE_ROWS = {"tracks": ("targets", "--truth"), "targets": ("tracks", "--tracks")}


def picture_rows(obj: dict[str, Any], key: str, where: str) -> list[Any]:
    """The ``key`` rows (``tracks`` or ``targets``) of a line ``{"t": number, key: [...]}``; an InputError naming
    ``where`` otherwise, and saying which option a truth file given as tracks (or the reverse) belongs to."""
    other, option = PICTURE_ROWS[key]
    if key not in obj and other in obj:
        raise InputError(f"{where}: has \"{other}\" where \"{key}\" is expected: give the "
                         f"{option.lstrip('-')} file to {option}")
    rows = obj.get(key)
    if not is_number(obj.get("t")) or not isinstance(rows, list):
        raise InputError(f"{where}: expected {{\"t\": number, \"{key}\": [...]}}")
    return rows


def check_fields(obj: dict[str, Any], allowed: frozenset[str], kind: str, where: str) -> None:
    """The one rule for input lines: a field outside ``allowed``, or a ``kind`` other than
    ``kind``, is an :class:`InputError` naming ``file:line`` and the field."""
    unknown = sorted(set(obj) - allowed)
    if unknown:
        field = str(unknown[0])
        hint = FORMAT_HINTS.get((kind, field))
        raise InputError(f"{where}: unknown field {field!r}" + (f": {hint}" if hint else did_you_mean(field, allowed)
                         or f" (allowed: {', '.join(sorted(allowed))})"))
    if obj.get("kind", kind) != kind:
        raise InputError(f"{where}: kind must be {kind!r} here, got {obj['kind']!r}")


def require(obj: dict[str, Any], key: str, where: str) -> Any:
    if key not in obj:
        raise InputError(f"{where}: missing field {key!r}")
    return obj[key]


def _json_text(value: Any) -> str:
    """``value`` as it reads in the input: ``null``, ``"NaN" (a string)``, ``true``, ``NaN``."""
    if isinstance(value, str):
        return f"{json.dumps(value)} (a string)"
    if isinstance(value, float) and not math.isfinite(value):
        return "NaN" if math.isnan(value) else ("Infinity" if value > 0 else "-Infinity")
    return json.dumps(value) if isinstance(value, (bool, type(None), int, float)) else type(value).__name__


def is_number(value: Any) -> bool:
    """A finite JSON number (not a boolean, not a string)."""
    return not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)


def as_float(value: Any, name: str, where: str) -> float:
    if not is_number(value):
        raise InputError(f"{where}: {name} must be a finite number, got {_json_text(value)}")
    return float(value)


def _not_numbers(value: Any, name: str, where: str, want: str) -> InputError:
    """The error naming the first entry of nested lists ``value`` that is not a finite number
    (``z[0] must be a finite number, got null``), or saying what shape was expected."""
    def first_bad(v: Any, path: str) -> tuple[str, Any] | None:
        if isinstance(v, (list, tuple)):
            for i, item in enumerate(v):
                found = first_bad(item, f"{path}[{i}]")
                if found:
                    return found
            return None
        return None if is_number(v) else (path, v)
    found = first_bad(value, name) if isinstance(value, (list, tuple)) else (name, value)
    if found is None:
        return InputError(f"{where}: {name} must be {want}")
    at, bad = found
    if at == name:
        return InputError(f"{where}: {name} must be {want}, got {_json_text(bad)}")
    return InputError(f"{where}: {at} must be a finite number, got {_json_text(bad)}")


def as_vector(value: Any, name: str, where: str, size: int | None = None) -> np.ndarray:
    """A finite 1-D float vector (of length ``size`` if given)."""
    want = f"a list of {size} numbers" if size is not None else "a list of numbers"
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise _not_numbers(value, name, where, want) from None
    if not isinstance(value, (list, tuple)):
        raise InputError(f"{where}: {name} must be {want}, got {_json_text(value)}")
    if arr.ndim != 1 or (size is not None and arr.shape[0] != size):
        got = str(len(value)) if arr.ndim == 1 else f"shape {arr.shape}"
        raise InputError(f"{where}: {name} must be {want}, got {got}")
    if not all(is_number(v) for v in value):
        raise _not_numbers(value, name, where, want)
    return arr


def as_covariance(value: Any, name: str, where: str, size: int | None = None,
                  rtol: float = 1e-9) -> np.ndarray:
    """A finite, symmetric, positive-definite square matrix."""
    want = f"a {size}x{size} matrix (a list of {size} rows of {size} numbers)" if size is not None \
        else "a square matrix of numbers"
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise _not_numbers(value, name, where, want) from None
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1] or (size is not None and arr.shape[0] != size):
        raise InputError(f"{where}: {name} must be {want}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)) or not all(is_number(v) for row in value for v in row):
        raise _not_numbers(value, name, where, want)
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


class NumericalRefusals:
    """A single-target replay's count of lines whose estimate came out non-finite or not positive
    definite: left out with the tracker kept as it was, as the live tracker rejects them
    (``rejected_numerical``: its state restored), so that a replay equals the live run."""

    def __init__(self) -> None:
        self.left_out = 0

    def line(self, algorithm: str, unit: str) -> str:
        """The counter line a replay prints when it left out any ``unit``."""
        return (f"{algorithm}: {self.left_out} {unit} whose estimate came out non-finite or not positive "
                "definite, left out (live: rejected_numerical)")


class RepeatedTimes:
    """A single-target replay's rule for a line of a sensor at the time of that sensor's last line
    taken (as a measurement sent again under a new number is): left out and counted, as the live
    trackers refuse it (``serve imm``, ``serve hpda``:
    :meth:`~fedtrack.services.dispatch.Dispatch.after_last`; the 2-D and radar local filters,
    ``time_jump``), so that a replay equals the live run."""

    def __init__(self) -> None:
        self.left_out = 0
        self._last: dict[str, float] = {}  # each sensor's time of its last line taken

    def taken(self, sensor: str, t: float) -> bool:
        """Whether ``sensor``'s line at ``t`` is taken; False (counted) at the time of its last one taken."""
        if self._last.get(sensor) == t:
            self.left_out += 1
            return False
        self._last[sensor] = t
        return True

    def refused(self, sensor: str, last: float | None) -> None:
        """The line just taken was refused after all (its estimate failed): ``last`` is again the
        time of ``sensor``'s last line taken (None: none)."""
        if last is None:
            self._last.pop(sensor, None)
        else:
            self._last[sensor] = last

    def line(self, algorithm: str, unit: str, live: str) -> str:
        """The counter line a replay prints: ``unit`` what a line is, ``live`` the live rejection."""
        return (f"{algorithm}: {self.left_out} {unit} at the time of their sensor's last one taken, left out "
                f"(live: rejected_{live})")
