"""Typed wire messages of the distributed pipeline, encoded with msgpack.

Usage::

    payload = encode(Measurement(sensor="s1", seq=3, t=0.3, kind="position",
                                 z=[1.0, 2.0], R=np.eye(2)))
    msg = decode(payload, Measurement)      # raises WireError naming the field

Every message is a frozen dataclass that validates itself on construction, so an
object of these types is always valid: decoding and building one in Python run
the same checks. Arrays are stored as read-only float64 numpy arrays and
covariances are exactly symmetric (symmetrized after the tolerance check).

On the wire a message is a msgpack map ``{"schema": SCHEMA_VERSION, "type":
<class name>, <field>: <value>, ...}``. Every field is present (optional ones
may be nil); unknown fields are rejected. A numpy array is a map ``{"dtype":
"float64" | "int64", "shape": [d0, ...], "data": <little-endian bytes>}``.
A message whose batch (detections, tracks) exceeds a bound of one message is sent as
:func:`parts` (at most MAX_PARTS messages, each within every bound; :func:`payloads` encodes
them) and rebuilt by the receiver with :func:`join`. The full contract is in ``docs/wire.md``.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, NamedTuple, Sequence, TypeVar

import msgpack
import numpy as np
import orjson

from fedtrack.jsonl import InputError
from fedtrack.keys import InvalidName, check_id

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


# ---------------------------------------------------------------- field validators
# Each takes (value, path) and returns the normalized value or raises WireError(path, ...).

def _identifier(value: Any, path: str) -> str:
    try:
        return check_id(value, "value")
    except InvalidName as exc:
        raise WireError(path, str(exc).removeprefix("value ")) from None


def _text(value: Any, path: str) -> str:
    if not isinstance(value, str):
        raise WireError(path, f"expected a string, got {type(value).__name__}")
    if len(value) > MAX_STRING_LENGTH:
        raise WireError(path, f"string longer than {MAX_STRING_LENGTH} characters")
    return value


def _choice(*options: str) -> Callable[[Any, str], str]:
    def check(value: Any, path: str) -> str:
        if not isinstance(value, str) or value not in options:
            raise WireError(path, f"expected one of {', '.join(options)}; got {brief(value)}")
        return value
    return check


def _count(value: Any, path: str) -> int:
    """A non-negative 64-bit integer."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise WireError(path, f"expected an integer, got {type(value).__name__}")
    if not 0 <= int(value) <= _INT64_MAX:
        raise WireError(path, f"must be in [0, 2**63), got {value}")
    return int(value)


def _real(value: Any, path: str) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise WireError(path, f"expected a number, got {type(value).__name__}")
    if not math.isfinite(value):
        raise WireError(path, f"must be finite, got {value}")
    return float(value)


def _scans(value: Any, path: str) -> tuple[int, ...]:
    """Scan numbers (at most MAX_LIST_ITEMS): the contested scans an output names."""
    return tuple(_count(v, f"{path}[{i}]") for i, v in enumerate(_sequence(value, path, MAX_LIST_ITEMS)))


def _flag(value: Any, path: str) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise WireError(path, f"expected true or false, got {type(value).__name__}")
    return bool(value)


def _array(value: Any, path: str, ndim: int, limit: int = MAX_ARRAY_ELEMENTS) -> np.ndarray:
    """A finite read-only float64 array of ``ndim`` dimensions within the size bound ``limit``."""
    try:
        arr = np.asarray(value)
        if arr.dtype.kind not in "fiu":
            raise TypeError(f"dtype {arr.dtype}")
        arr = arr.astype(np.float64, copy=arr.flags.writeable)
    except (TypeError, ValueError) as exc:
        raise WireError(path, f"expected an array of real numbers ({exc})") from None
    if arr.ndim != ndim:
        raise WireError(path, f"expected {ndim} dimension(s), got shape {arr.shape}")
    if arr.size > limit:
        raise WireError(path, f"{arr.size} elements exceed the limit of {limit}")
    # one reduction for both checks: NaN fails every comparison, infinity exceeds the bound
    if arr.size and not np.abs(arr).max() <= MAX_MAGNITUDE:
        if not np.isfinite(arr).all():
            raise WireError(path, "contains NaN or infinity")
        raise WireError(path, f"values beyond +-{MAX_MAGNITUDE:g} (overflow-scale)")
    arr.setflags(write=False)
    return arr


def _vector(value: Any, path: str) -> np.ndarray:
    return _array(value, path, 1)


def _covariance(value: Any, path: str) -> np.ndarray:
    """Square, symmetric within SYMMETRY_RTOL, positive definite (eigenvalue ratio > PD_RTOL)."""
    arr = _array(value, path, 2)
    if arr.shape[0] != arr.shape[1]:
        raise WireError(path, f"expected a square matrix, got shape {arr.shape}")
    if arr.size == 0:
        return arr
    scale = float(np.abs(arr).max())
    if np.abs(arr - arr.T).max() > SYMMETRY_RTOL * scale:
        raise WireError(path, "not symmetric")
    sym = 0.5 * (arr + arr.T)
    try:
        eig = np.linalg.eigvalsh(sym)
    except np.linalg.LinAlgError:
        raise WireError(path, "eigenvalues could not be computed") from None
    if not eig[0] > PD_RTOL * eig[-1] or eig[-1] <= 0.0:
        raise WireError(path, f"not positive definite (eigenvalues {eig[0]:.3g} .. {eig[-1]:.3g})")
    sym.setflags(write=False)
    return sym


def predictable(values: np.ndarray, P: np.ndarray, horizon: float) -> bool:
    """Whether states ``values`` and covariances ``P`` (any shapes) stay within the receivers'
    +-MAX_MAGNITUDE once a tracker predicts them over ``horizon`` seconds (docs/wire.md, "Values a
    centre predicts"). One step of a constant-acceleration block ``[p, v, a]`` multiplies a value
    by at most its transition's row sum ``g = 1 + h + h^2 / 2`` (constant velocity: ``1 + h``) and a
    covariance by ``g^2``; half of the bound is kept for the process noise and for fusion's
    rounding. So ``max |x| <= MAX_MAGNITUDE / (2 g)`` and ``max |P| <= MAX_MAGNITUDE / (2 g^2)``."""
    g = 1.0 + horizon + 0.5 * horizon * horizon
    x, C = np.asarray(values, dtype=np.float64), np.asarray(P, dtype=np.float64)
    return bool((x.size == 0 or np.max(np.abs(x)) * g <= 0.5 * MAX_MAGNITUDE)
                and (C.size == 0 or np.max(np.abs(C)) * g * g <= 0.5 * MAX_MAGNITUDE))


def acceptable_covariances(P: np.ndarray) -> bool:
    """Whether every covariance in ``P`` (one (d, d), a stack (n, d, d) or n stacked (n d, d)) is one
    a receiver accepts (:func:`_covariance`): within +-MAX_MAGNITUDE, symmetric within SYMMETRY_RTOL,
    positive definite with an eigenvalue ratio above PD_RTOL. A service checks what it is about to
    keep and publish with it: an estimate every receiver would refuse fails where it arises."""
    P = np.asarray(P, dtype=np.float64)
    if P.size == 0:
        return True
    stack = P.reshape(-1, P.shape[-1], P.shape[-1])
    scale = np.max(np.abs(stack), axis=(1, 2))
    if not np.all(scale <= MAX_MAGNITUDE):  # NaN too
        return False
    T = np.swapaxes(stack, 1, 2)
    if np.any(np.max(np.abs(stack - T), axis=(1, 2)) > SYMMETRY_RTOL * scale):
        return False
    eig = np.linalg.eigvalsh(0.5 * (stack + T))
    return bool(np.all((eig[:, -1] > 0.0) & (eig[:, 0] > PD_RTOL * eig[:, -1])))


def _whole(limit: int) -> int:
    """The bound of a batch in a whole message (built in Python, sent in parts): MAX_PARTS times
    ``limit``, the bound in one message on the wire (:func:`encode` and :func:`decode` check that)."""
    return MAX_PARTS * limit


def _optional(check: Callable[[Any, str], Any]) -> Callable[[Any, str], Any]:
    def optional(value: Any, path: str) -> Any:
        return None if value is None else check(value, path)
    return optional


def _sequence(value: Any, path: str, limit: int) -> list[Any]:
    if not isinstance(value, (list, tuple)):
        raise WireError(path, f"expected a list, got {type(value).__name__}")
    if len(value) > limit:
        raise WireError(path, f"{len(value)} items exceed the limit of {limit}")
    return list(value)


def _mapping(value: Any, path: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise WireError(path, f"expected a map, got {type(value).__name__}")
    if len(value) > MAX_MAP_ITEMS:
        raise WireError(path, f"{len(value)} entries exceed the limit of {MAX_MAP_ITEMS}")
    for key in value:
        _identifier(key, f"{path} key {brief(key)}")
    return value


def _identifiers(value: Any, path: str) -> tuple[str, ...]:
    return tuple(_identifier(v, f"{path}[{i}]") for i, v in enumerate(_sequence(value, path, MAX_LIST_ITEMS)))


def _counters(value: Any, path: str) -> dict[str, int]:
    return {k: _count(v, f"{path}.{k}") for k, v in _mapping(value, path).items()}


def _extra_value(value: Any, path: str) -> float | str | tuple[float, ...] | dict[str, float]:
    if isinstance(value, str):
        return _text(value, path)
    if isinstance(value, (list, tuple)):
        return tuple(_real(v, f"{path}[{i}]") for i, v in enumerate(_sequence(value, path, MAX_LIST_ITEMS)))
    if isinstance(value, dict):
        return {k: _real(v, f"{path}.{k}") for k, v in _mapping(value, path).items()}
    return _real(value, path)


def _extra(value: Any, path: str) -> dict[str, Any]:
    extra = {k: _extra_value(v, f"{path}.{k}") for k, v in _mapping(value, path).items()}
    reserved = sorted(set(extra) & {f.name for f in _record_fields(FusedTrack)})
    if reserved:
        raise WireError(f"{path}.{reserved[0]}", "key is reserved for a FusedTrack field")
    return extra


def _check_part(part: int, parts: int) -> None:
    """A part's index and count: 0 <= part < parts <= MAX_PARTS."""
    if not 1 <= parts <= MAX_PARTS:
        raise WireError("parts", f"must be in [1, {MAX_PARTS}], got {parts}")
    if part >= parts:
        raise WireError("part", f"must be below parts ({parts}), got {part}")


def _check_square(P: np.ndarray, n: int, path: str, against: str) -> None:
    if P.shape != (n, n):
        raise WireError(path, f"expected shape ({n}, {n}) to match {against}, got {P.shape}")


# ---------------------------------------------------------------- records

R = TypeVar("R", bound="_Record")


class _Items(NamedTuple):
    """Per-item fields of a message type, split together by :func:`parts` (docs/wire.md, "Messages
    in parts"). The first field, a tuple, counts the items; an array holds the same number of rows
    for each item (a stacked covariance (n d, d): d); a tuple left empty while there are items
    (``elsewhere``, ``ca``, ``regions``) stays empty in every part; None stays None. ``limit`` names
    the wire bound on their number in one message. ``cut``: None, the items in even runs; "of":
    the items of the first batch's items flagged by its field ``ref``, in order (a report's
    observations, one per detected track); "at": the first field lists positions among the items
    of the batch whose first field is ``ref`` (ascending), each entry going with its position."""

    fields: tuple[str, ...]
    limit: str
    cut: str | None = None
    ref: str | None = None


@functools.cache
def _record_fields(cls: type[_Record]) -> tuple[dataclasses.Field[Any], ...]:
    """The dataclass fields of a record class, looked up once (a scan has a record per detection)."""
    return dataclasses.fields(cls)  # type: ignore[arg-type]


class _Record:
    """Base of every record: validates and normalizes fields in ``__post_init__``.

    ``_fields`` maps field name -> validator; ``_arrays`` names the fields carried as
    wire arrays; ``_records`` maps a field to the nested record class of its item(s).
    Top-level messages prefix errors with their class name.
    """

    _fields: ClassVar[dict[str, Callable[[Any, str], Any]]] = {}
    _arrays: ClassVar[tuple[str, ...]] = ()
    _records: ClassVar[dict[str, type[_Record]]] = {}
    _top_level: ClassVar[bool] = True
    # fields added for the region centres (issue 27): left out of the encoding while they hold their
    # default and taken as the default when absent, so that a deployment without regions sends the
    # same bytes as before they existed
    _omitted: ClassVar[tuple[str, ...]] = ()
    # a batched message's per-item fields (:class:`_Items`): it has the fields ``part`` and ``parts``
    _items: ClassVar[tuple[_Items, ...]] = ()

    def __post_init__(self) -> None:
        try:
            for name, check in self._fields.items():
                object.__setattr__(self, name, check(getattr(self, name), name))
            if self._items:
                _check_part(self.part, self.parts)  # type: ignore[attr-defined]
            self._check()
        except WireError as exc:
            if not self._top_level:
                raise
            raise WireError(f"{type(self).__name__}.{exc.field}", exc.reason) from None

    def _check(self) -> None:
        """Cross-field checks (shapes); fields are already normalized."""

    @classmethod
    def unchecked(cls: type[R], **values: Any) -> R:
        """A record of this process's own computed values, built without the field checks.

        Decoding is the trust boundary: it checks every field of every message received. A
        service's own outgoing messages (estimates, resets, tracks, reports, pictures) skip a
        second check at build time; their covariances are validated once, by the receiver (a
        ``LocalEstimate``'s two eigen-decompositions were half of its build). Array fields are
        taken as float64 arrays in their wire layout (stacked covariances already stacked);
        defaults apply as in the constructor.
        """
        rec = object.__new__(cls)
        for f in _record_fields(cls):
            if f.name in values:
                value = values.pop(f.name)
            elif f.default is not dataclasses.MISSING:
                value = f.default
            elif f.default_factory is not dataclasses.MISSING:
                value = f.default_factory()
            else:
                raise TypeError(f"{cls.__name__}.unchecked: missing field {f.name!r}")
            if f.name in cls._arrays and value is not None:
                value = np.asarray(value, dtype=np.float64)
            object.__setattr__(rec, f.name, value)
        if values:
            raise TypeError(f"{cls.__name__}.unchecked: unknown field(s) {', '.join(sorted(values))}")
        return rec


@dataclass(frozen=True, eq=False)
class Detection(_Record):
    """One sonar detection: position measurement ``z`` (d,) and signal ``amplitude``."""

    z: np.ndarray
    amplitude: float

    _fields = {"z": _vector, "amplitude": _real}
    _arrays = ("z",)
    _top_level = False


def _detections(value: Any, path: str) -> tuple[Detection, ...]:
    items = _sequence(value, path, _whole(MAX_DETECTIONS))
    out = []
    for i, item in enumerate(items):
        if isinstance(item, Detection):
            out.append(item)
            continue
        if not isinstance(item, (tuple, list)) or len(item) != 2:
            raise WireError(f"{path}[{i}]", "expected a Detection or a (z, amplitude) pair")
        try:
            out.append(Detection(*item))
        except WireError as exc:
            raise WireError(f"{path}[{i}].{exc.field}", exc.reason) from None
    return tuple(out)


@dataclass(frozen=True, eq=False)
class ManeuverInfo(_Record):
    """A local filter's maneuver decision at this scan: ``event`` (onset / new-ca / end),
    whether it is a detection (onset, new-ca), the estimated onset time and input ``u`` (k,)
    with covariance ``gamma`` (k, k)."""

    event: str
    detected: bool
    onset: float
    u: np.ndarray
    gamma: np.ndarray

    _fields = {"event": _choice(*EVENT_KINDS), "detected": _flag, "onset": _real, "u": _vector,
               "gamma": _covariance}
    _arrays = ("u", "gamma")
    _top_level = False

    def _check(self) -> None:
        _check_square(self.gamma, self.u.shape[0], "gamma", "u")


def _maneuver_info(value: Any, path: str) -> ManeuverInfo | None:
    if value is None or isinstance(value, ManeuverInfo):
        return value
    if not isinstance(value, dict):
        raise WireError(path, f"expected a maneuver record, got {type(value).__name__}")
    try:
        return ManeuverInfo(**value)
    except TypeError as exc:
        raise WireError(path, str(exc)) from None
    except WireError as exc:
        raise WireError(f"{path}.{exc.field}", exc.reason) from None


def _check_resolvable(z: np.ndarray, R: np.ndarray) -> None:
    """The noise of ``z`` is at least the spacing of float64 numbers at ``z``'s magnitude: its
    smallest standard deviation sqrt(min eig R) >= FLOAT_EPS max|z|. A smaller one cannot be
    represented in ``z`` itself (a position of 1e100 m carries no digit below about 1e84 m, a
    variance of 1e-300 none at 1 m), and no filter can weigh such a measurement: it would be taken
    as exact where its own rounding is larger than its claimed noise."""
    floor = (FLOAT_EPS * float(np.abs(z).max())) ** 2
    if floor <= PD_RTOL * float(np.abs(R).max()):  # then below min eig R (> PD_RTOL max eig R): no eigenvalues needed
        return
    smallest = float(np.linalg.eigvalsh(R)[0])
    if not smallest >= floor:
        raise WireError("R", f"noise std {math.sqrt(max(smallest, 0.0)):.3g} below the float64 resolution "
                        f"{math.sqrt(floor):.3g} of z (|z| up to {float(np.abs(z).max()):.3g})")


@dataclass(frozen=True, eq=False)
class Measurement(_Record):
    """One scan of one sensor.

    ``position``/``radar``: ``z`` (m,) with noise covariance ``R`` (m, m), no detections;
    radar also carries ``sensor_position`` (2 or 3,). ``sonar``: ``z`` empty, each
    detection's ``z`` is (d,) with covariance ``R`` (d, d). ``scan``: a multi-target sensor's
    scan (docs/multitarget-formats.md): ``z`` empty, detections as for sonar (amplitude 0 on
    every detection when the sensor gives none), ``sensor_position`` (3,) for a radar (then
    each ``z`` is range, azimuth, elevation). ``stamp_ns`` is the wall-clock publish time
    (``time.time_ns()``), for end-to-end latency.
    """

    sensor: str
    seq: int
    t: float
    kind: str
    z: np.ndarray
    R: np.ndarray
    detections: tuple[Detection, ...] = ()
    sensor_position: np.ndarray | None = None
    stamp_ns: int = field(default_factory=time.time_ns)
    part: int = 0  # this part's index, parts: how many (docs/wire.md, "Messages in parts"); on the wire only when > 1
    parts: int = 1

    _fields = {"sensor": _identifier, "seq": _count, "t": _real, "kind": _choice(*MEASUREMENT_KINDS),
               "z": _vector, "R": _covariance, "detections": _detections,
               "sensor_position": _optional(_vector), "stamp_ns": _count, "part": _count,
               "parts": _count}
    _arrays = ("z", "R", "sensor_position")
    _records = {"detections": Detection}
    _omitted = ("part", "parts")
    _items = (_Items(("detections",), "MAX_DETECTIONS"),)

    def _check(self) -> None:
        if self.kind in ("sonar", "scan"):
            if self.z.size:
                raise WireError("z", f"must be empty for {self.kind} (detections carry the positions)")
            for i, det in enumerate(self.detections):
                if det.z.shape[0] != self.R.shape[0]:
                    raise WireError(f"detections[{i}].z", f"length {det.z.shape[0]} does not match R "
                                    f"{self.R.shape}")
        else:
            if self.z.size == 0:
                raise WireError("z", f"must not be empty for kind {self.kind}")
            if self.detections:
                raise WireError("detections", "only sonar and scan measurements carry detections")
            _check_square(self.R, self.z.shape[0], "R", "z")
            _check_resolvable(self.z, self.R)
        if self.R.size == 0:
            raise WireError("R", "must not be empty")
        if self.kind == "radar" and self.sensor_position is None:
            raise WireError("sensor_position", "required for radar")
        if self.sensor_position is not None and self.sensor_position.shape[0] not in (2, 3):
            raise WireError("sensor_position", f"expected 2 or 3 coordinates, got {self.sensor_position.shape[0]}")


@dataclass(frozen=True, eq=False)
class LocalEstimate(_Record):
    """A local filter's posterior ``(x, P)`` and prior ``(x_prior, P_prior)`` for scan ``seq``.

    ``model`` names the posterior's model; the prior is in the model the filter updated
    with, which differs from ``model`` (and so may differ in dimension) in a scan where
    a variable-dimension filter switched. ``stamp_ns`` is the stamp of the measurement it
    processed; ``degraded`` lists flags such as ``"init"`` (no prior: a first estimate);
    ``contested``: the scans (of this sensor) for which the local filter received a second,
    different Measurement or Reset since its previous estimate (empty when none; docs/wire.md,
    "Contested scans").
    """

    sensor: str
    seq: int
    t: float
    model: str
    x: np.ndarray
    P: np.ndarray
    x_prior: np.ndarray
    P_prior: np.ndarray
    stamp_ns: int
    maneuver: ManeuverInfo | None = None
    degraded: tuple[str, ...] = ()
    contested: tuple[int, ...] = ()

    _fields = {"sensor": _identifier, "seq": _count, "t": _real, "model": _identifier, "x": _vector,
               "P": _covariance, "x_prior": _vector, "P_prior": _covariance, "stamp_ns": _count,
               "maneuver": _maneuver_info, "degraded": _identifiers, "contested": _scans}
    _arrays = ("x", "P", "x_prior", "P_prior")
    _records = {"maneuver": ManeuverInfo}

    def _check(self) -> None:
        n = self.x.shape[0]
        if n == 0:
            raise WireError("x", "must not be empty")
        _check_square(self.P, n, "P", "x")
        if self.x_prior.shape[0] == 0:
            raise WireError("x_prior", "must not be empty")
        _check_square(self.P_prior, self.x_prior.shape[0], "P_prior", "x_prior")


@dataclass(frozen=True, eq=False)
class Reset(_Record):
    """The fusion center's reset of local filter ``sensor`` for scan ``seq``.

    ``P`` is already scaled by the sensor's sharing factor (paper 004's ``beta_i >= 1``:
    ``P_i = beta_i P``, eq. (20)), so the local filter adopts ``(x, P)`` as is and uses
    ``Q_i = beta_i Q`` (eq. (22)). The ``beta`` field carries the information share
    ``1 / beta_i`` in (0, 1] (Carlson's convention).
    """

    sensor: str
    seq: int
    t: float
    model: str
    x: np.ndarray
    P: np.ndarray
    beta: float

    _fields = {"sensor": _identifier, "seq": _count, "t": _real, "model": _identifier, "x": _vector,
               "P": _covariance, "beta": _real}
    _arrays = ("x", "P")

    def _check(self) -> None:
        if self.x.shape[0] == 0:
            raise WireError("x", "must not be empty")
        _check_square(self.P, self.x.shape[0], "P", "x")
        if not 0.0 < self.beta <= 1.0:
            raise WireError("beta", f"must be in (0, 1], got {self.beta}")


@dataclass(frozen=True, eq=False)
class FusedTrack(_Record):
    """The fused track of scan ``seq``.

    ``sensors``: the sensors fused in this scan; ``stamp_ns``: earliest measurement
    stamp of the scan; ``extra``: small map of str -> float | str | list of floats |
    map of floats (IMM mode probabilities, existence, status, active group, ...);
    ``contested``: this track may be built on a forged message: a second, different message
    arrived for a (sensor, scan) it depends on (the first was used; either may be the forgery);
    ``extra["contested_scans"]`` then names those scans (docs/wire.md, "Contested scans").
    """

    seq: int
    t: float
    model: str
    x: np.ndarray
    P: np.ndarray
    maneuver: bool
    degraded: bool
    sensors: tuple[str, ...]
    stamp_ns: int
    extra: dict[str, Any] = field(default_factory=dict)
    contested: bool = False

    _fields = {"seq": _count, "t": _real, "model": _identifier, "x": _vector, "P": _covariance,
               "maneuver": _flag, "degraded": _flag, "sensors": _identifiers, "stamp_ns": _count,
               "extra": _extra, "contested": _flag}
    _arrays = ("x", "P")

    def _check(self) -> None:
        if self.x.shape[0] == 0:
            raise WireError("x", "must not be empty")
        _check_square(self.P, self.x.shape[0], "P", "x")


@dataclass(frozen=True, eq=False)
class ManeuverEvent(_Record):
    """Maneuver ``onset`` detected / ``new-ca`` model started / maneuver ``end``."""

    seq: int
    t: float
    kind: str
    onset: float
    u: np.ndarray
    statistic: float

    _fields = {"seq": _count, "t": _real, "kind": _choice(*EVENT_KINDS), "onset": _real, "u": _vector,
               "statistic": _real}
    _arrays = ("u",)


def _counts(value: Any, path: str) -> tuple[int, ...]:
    """Per-track integers (ids, positions): a list of plain ints in range at once (a 10,000-track
    report holds some 50,000), anything else item by item, which names the first bad one."""
    if (type(value) in (list, tuple) and len(value) <= _whole(MAX_TRACKS) and all(type(v) is int for v in value)
            and (not value or 0 <= min(value) and max(value) <= _INT64_MAX)):
        return tuple(value)
    return _counts_each(value, path)


def _flags(value: Any, path: str) -> tuple[bool, ...]:
    """Per-track flags: a list of plain booleans at once, anything else item by item (see _counts)."""
    if type(value) in (list, tuple) and len(value) <= _whole(MAX_TRACKS) and all(type(v) is bool for v in value):
        return tuple(value)
    return _flags_each(value, path)




def _check_probabilities(p: np.ndarray | None, n: int, path: str = "existence") -> None:
    """None, or one probability in [0, 1] for each of the ``n`` tracks."""
    if p is not None and (p.shape != (n,) or not ((p >= 0.0) & (p <= 1.0)).all()):
        raise WireError(path, f"expected one probability in [0, 1] for each of the {n} tracks")


def _batch(value: Any, path: str) -> np.ndarray:
    """A 2-D array of a batch of tracks (up to MAX_BATCH_ELEMENTS elements a message)."""
    return _array(value, path, 2, _whole(MAX_BATCH_ELEMENTS))


def _batch_vector(value: Any, path: str) -> np.ndarray:
    """A 1-D array of one value per track of a batch (existence)."""
    return _array(value, path, 1, _whole(MAX_BATCH_ELEMENTS))


def _tracks_list(check: Callable[[Any, str], Any]) -> Callable[[Any, str], tuple[Any, ...]]:
    """A list of up to MAX_TRACKS values a message, each checked by ``check``."""
    def values(value: Any, path: str) -> tuple[Any, ...]:
        return tuple(check(v, f"{path}[{i}]") for i, v in enumerate(_sequence(value, path, _whole(MAX_TRACKS))))
    return values


_optional_batch = _optional(_batch)
_optional_batch_vector = _optional(_batch_vector)
_BATCH_CHECKS = (_batch, _optional_batch, _optional_batch_vector)  # decoded within MAX_BATCH_ELEMENTS
_identifier_list = _tracks_list(_identifier)
_reals = _tracks_list(_real)
_counts_each = _tracks_list(_count)  # the item-by-item paths of _counts and _flags
_flags_each = _tracks_list(_flag)


def _covariance_stack(P: np.ndarray, n: int, d: int, path: str) -> np.ndarray:
    """``P`` (n d, d): ``n`` covariances stacked, each symmetric within SYMMETRY_RTOL and positive
    definite (eigenvalue ratio > PD_RTOL), checked in one batched call; returned symmetrized."""
    if P.shape != (n * d, d):
        raise WireError(path, f"expected shape ({n * d}, {d}) for {n} stacked {d}x{d} covariances, got {P.shape}")
    if n == 0 or d == 0:
        return P
    stack = P.reshape(n, d, d)
    scale = np.max(np.abs(stack), axis=(1, 2))
    bad = np.max(np.abs(stack - np.swapaxes(stack, 1, 2)), axis=(1, 2)) > SYMMETRY_RTOL * scale
    if np.any(bad):
        raise WireError(f"{path}[{int(np.argmax(bad))}]", "not symmetric")
    sym = 0.5 * (stack + np.swapaxes(stack, 1, 2))
    try:
        eig = np.linalg.eigvalsh(sym)
    except np.linalg.LinAlgError:
        raise WireError(path, "eigenvalues could not be computed") from None
    bad = ~(eig[:, 0] > PD_RTOL * eig[:, -1]) | (eig[:, -1] <= 0.0)
    if np.any(bad):
        k = int(np.argmax(bad))
        raise WireError(f"{path}[{k}]", f"not positive definite (eigenvalues {eig[k, 0]:.3g} .. {eig[k, -1]:.3g})")
    out = sym.reshape(n * d, d)
    out.setflags(write=False)
    return out


def _track_batch(ids: tuple[int, ...], x: np.ndarray, P: np.ndarray) -> tuple[int, np.ndarray]:
    """Checks ``n`` tracks: unique ids, ``x`` (n, d), ``P`` (n d, d) covariances; returns d and ``P``."""
    n = len(ids)
    if x.shape[0] != n:
        raise WireError("x", f"expected one row per id ({n}), got shape {x.shape}")
    if len(set(ids)) != n:
        raise WireError("ids", "track ids are not unique")
    d = x.shape[1]
    if n and d == 0:
        raise WireError("x", "must not be empty")
    return d, _covariance_stack(P, n, d, "P")


@dataclass(frozen=True, eq=False)
class TrackReport(_Record):
    """A local multi-target tracker's output for scan ``seq`` of ``sensor``: its ``n`` live tracks
    batched (``ids``; ``x`` (n, d); ``P`` (n d, d), the covariances stacked; ``confirmed``;
    ``detected``: updated or started by this scan), the (linearized) observation each of the
    ``k`` detected tracks used, in track order (``obs_H`` (k m, d), ``obs_R`` (k m, m) stacked,
    ``obs_z`` (k, m): ``z ~ N(H x, R)``; ``started``: the track started from it), and the ids
    this scan deleted (``retired``); ``contested``: the scans (of this sensor) for which the
    tracker received a second, different Measurement or TrackResets since its previous report
    (docs/wire.md, "Contested scans")."""

    sensor: str
    seq: int
    t: float
    ids: tuple[int, ...]
    x: np.ndarray
    P: np.ndarray
    confirmed: tuple[bool, ...]
    detected: tuple[bool, ...]
    obs_H: np.ndarray
    obs_R: np.ndarray
    obs_z: np.ndarray
    started: tuple[bool, ...]
    retired: tuple[int, ...]
    stamp_ns: int
    contested: tuple[int, ...] = ()
    existence: np.ndarray | None = None  # (n,) each track's existence probability (jipda), else None
    # a region's sub-report (docs/multitarget.md#regions): per track, whether its tracker believes
    # another region's centre holds it (empty: none does; omitted then)
    elsewhere: tuple[bool, ...] = ()
    part: int = 0  # this part's index, parts: how many (docs/wire.md, "Messages in parts"); on the wire only when > 1
    parts: int = 1

    _fields = {"sensor": _identifier, "seq": _count, "t": _real, "ids": _counts, "x": _batch, "P": _batch,
               "confirmed": _flags, "detected": _flags, "obs_H": _batch, "obs_R": _batch, "obs_z": _batch,
               "started": _flags, "retired": _counts, "stamp_ns": _count, "contested": _scans,
               "existence": _optional_batch_vector, "elsewhere": _flags, "part": _count, "parts": _count}
    _arrays = ("x", "P", "obs_H", "obs_R", "obs_z", "existence")
    _omitted = ("elsewhere", "part", "parts")
    _items = (_Items(("ids", "x", "P", "confirmed", "detected", "existence", "elsewhere"), "MAX_TRACKS"),
              _Items(("started", "obs_H", "obs_R", "obs_z"), "MAX_TRACKS", "of", "detected"),
              _Items(("retired",), "MAX_TRACKS"))

    def _check(self) -> None:
        n = len(self.ids)
        d, P = _track_batch(self.ids, self.x, self.P)
        object.__setattr__(self, "P", P)
        if len(self.confirmed) != n or len(self.detected) != n:
            raise WireError("detected", f"expected confirmed and detected for each of the {n} tracks")
        if len(self.elsewhere) not in (0, n):
            raise WireError("elsewhere", f"expected none or one for each of the {n} tracks")
        k = sum(self.detected)
        m = self.obs_z.shape[1]
        if self.obs_z.shape[0] != k or len(self.started) != k:
            raise WireError("obs_z", f"expected one observation per detected track ({k})")
        if k and m == 0:
            raise WireError("obs_z", "must not be empty")
        if self.obs_H.shape != (k * m, d):
            raise WireError("obs_H", f"expected shape ({k * m}, {d}), got {self.obs_H.shape}")
        object.__setattr__(self, "obs_R", _covariance_stack(self.obs_R, k, m, "obs_R"))
        _check_probabilities(self.existence, n)


@dataclass(frozen=True, eq=False)
class TrackResets(_Record):
    """The multi-target centre's answer to ``sensor``'s report ``seq`` (federated mode): the
    resets of local tracks ``ids`` (``x`` (n, d), ``P`` (n d, d) stacked, already scaled) and
    ``q_scale``, the process-noise factor (number of live sensors) for its next scan.

    A region centre's answer (docs/multitarget.md#regions; decentralized too, with no resets) also
    names its ``region``, the local tracks of the sub-report it ``held`` after it, and the ones
    it handed over since its last answer to this sensor (``moved``) with their new regions
    (``moved_to``); without regions these fields are absent."""

    sensor: str
    seq: int
    t: float
    q_scale: float
    ids: tuple[int, ...]
    x: np.ndarray
    P: np.ndarray
    region: str | None = None
    held: tuple[int, ...] = ()
    moved: tuple[int, ...] = ()
    moved_to: tuple[str, ...] = ()
    part: int = 0  # this part's index, parts: how many (docs/wire.md, "Messages in parts"); on the wire only when > 1
    parts: int = 1

    _fields = {"sensor": _identifier, "seq": _count, "t": _real, "q_scale": _real, "ids": _counts,
               "x": _batch, "P": _batch, "region": _optional(_identifier), "held": _counts, "moved": _counts,
               "moved_to": _identifier_list, "part": _count, "parts": _count}
    _arrays = ("x", "P")
    _omitted = ("region", "held", "moved", "moved_to", "part", "parts")
    _items = (_Items(("ids", "x", "P"), "MAX_TRACKS"), _Items(("held",), "MAX_TRACKS"),
              _Items(("moved", "moved_to"), "MAX_TRACKS"))

    def _check(self) -> None:
        if not 1.0 <= self.q_scale <= MAX_TRACKS:
            raise WireError("q_scale", f"must be in [1, {MAX_TRACKS}], got {self.q_scale}")
        object.__setattr__(self, "P", _track_batch(self.ids, self.x, self.P)[1])
        if len(self.moved) != len(self.moved_to):
            raise WireError("moved_to", "expected one region per moved track")
        if self.region is None and (self.held or self.moved):
            raise WireError("region", "held and moved come with the answering region")


def _id_lists(value: Any, path: str) -> tuple[tuple[str, ...], ...]:
    """A list of id lists (a picture's per-track sensors), each distinct id checked once: the lists
    repeat a few sensor ids (1,000 tracks: 4,000 checks of 4 ids). Same results and errors as
    ``_identifiers`` on each list."""
    valid: set[str] = set()

    def ids(items: list[Any], where: str) -> tuple[str, ...]:
        for j, x in enumerate(items):
            if not (type(x) is str and x in valid):
                valid.add(_identifier(x, f"{where}[{j}]"))
        return tuple(items)

    return tuple(ids(_sequence(v, f"{path}[{i}]", MAX_LIST_ITEMS), f"{path}[{i}]")
                 for i, v in enumerate(_sequence(value, path, _whole(MAX_TRACKS))))


@dataclass(frozen=True, eq=False)
class TrackPicture(_Record):
    """The multi-target centre's picture number ``seq`` at ``t`` (every ``period`` seconds): its
    tracks predicted to ``t`` (``ids``, ``x`` (n, d), ``P`` (n d, d) stacked, ``confirmed``,
    ``sensors`` per track), and the scans it processed since the previous picture, in its
    processing order (``fused_sensors[i]``, ``fused_seqs[i]``): the order a replay of the
    recorded scans must follow. The entries at the positions ``left`` are no scans but
    departures: the centre dropped that sensor there (its ``fused_seqs`` entry is 0). A
    ``closing`` record (the last one, on a clean stop) is no picture: it has no tracks and only
    lists what the centre processed after the last picture. ``contested``: since the previous
    picture a second, different message arrived for a (sensor, scan) the centre had already
    taken, or a report fused since then names contested scans of its local tracker (the first
    message was used; either may be a forgery: docs/wire.md, "Contested scans")."""

    seq: int
    t: float
    ids: tuple[int, ...]
    x: np.ndarray
    P: np.ndarray
    confirmed: tuple[bool, ...]
    sensors: tuple[tuple[str, ...], ...]
    fused_sensors: tuple[str, ...]
    fused_seqs: tuple[int, ...]
    stamp_ns: int
    closing: bool = False
    left: tuple[int, ...] = ()
    ca: tuple[bool, ...] = ()  # per track: in the CA model (``[mtt] maneuver``); empty: every track CV
    # central tracks' maneuver detector (``[mtt] maneuver = "vdie"``; None: none runs): the positions
    # of the tracks whose maneuver is detected and one row [onset, ax, ay, statistic] for each
    maneuvering: tuple[int, ...] = ()
    maneuver: np.ndarray | None = None
    contested: bool = False
    existence: np.ndarray | None = None  # (n,) each track's existence probability, None: not kept
    lla: np.ndarray | None = None  # (n, 3) [lat deg, lon deg, h m] of each track ([frame] set), else None
    # region centres (docs/multitarget.md#regions; absent without regions): ``handovers``, the
    # positions in the fused lists that are hand-overs taken over there (``fused_sensors``: the
    # sending region, ``fused_seqs``: its hand-over number); in the merged picture, ``regions``
    # names the region that processed each entry of the fused lists (each region's in its order)
    handovers: tuple[int, ...] = ()
    regions: tuple[str, ...] = ()
    # a region centre's picture: the positions of the tracks it handed over shortly before (shown
    # until their new owner shows them) and the data time of each hand-over
    in_flight: tuple[int, ...] = ()
    in_flight_t: tuple[float, ...] = ()
    part: int = 0  # this part's index, parts: how many (docs/wire.md, "Messages in parts"); on the wire only when > 1
    parts: int = 1

    _fields = {"seq": _count, "t": _real, "ids": _counts, "x": _batch, "P": _batch, "confirmed": _flags,
               "sensors": _id_lists, "ca": _flags, "maneuvering": _counts, "maneuver": _optional_batch,
               "fused_sensors": _identifier_list,
               "fused_seqs": _counts, "stamp_ns": _count, "closing": _flag, "left": _counts, "contested": _flag,
               "existence": _optional_batch_vector, "lla": _optional_batch,
               "handovers": _counts, "regions": _identifier_list,
               "in_flight": _counts, "in_flight_t": _reals, "part": _count, "parts": _count}
    _arrays = ("x", "P", "maneuver", "existence", "lla")
    _omitted = ("handovers", "regions", "in_flight", "in_flight_t", "part", "parts")
    _items = (_Items(("ids", "x", "P", "confirmed", "sensors", "ca", "existence", "lla"), "MAX_TRACKS"),
              _Items(("fused_seqs", "fused_sensors", "regions"), "MAX_TRACKS"),
              _Items(("maneuvering", "maneuver"), "MAX_TRACKS", "at", "ids"),
              _Items(("in_flight", "in_flight_t"), "MAX_TRACKS", "at", "ids"),
              _Items(("left",), "MAX_TRACKS", "at", "fused_seqs"),
              _Items(("handovers",), "MAX_TRACKS", "at", "fused_seqs"))

    def _check(self) -> None:
        n = len(self.ids)
        object.__setattr__(self, "P", _track_batch(self.ids, self.x, self.P)[1])
        k = len(self.maneuvering)
        if self.maneuver is None and k or self.maneuver is not None and self.maneuver.shape != (k, 4):
            raise WireError("maneuver", f"expected one row [onset, ax, ay, statistic] for each of the {k} "
                                        "maneuvering tracks")
        if len(set(self.maneuvering)) != k or any(i >= n for i in self.maneuvering):
            raise WireError("maneuvering", f"expected distinct positions among the {n} tracks")
        if len(self.confirmed) != n or len(self.sensors) != n:
            raise WireError("sensors", f"expected confirmed and sensors for each of the {n} tracks")
        if len(self.fused_sensors) != len(self.fused_seqs):
            raise WireError("fused_seqs", "expected one per fused_sensors entry")
        if len(self.ca) not in (0, n):
            raise WireError("ca", f"expected none or one for each of the {n} tracks")
        if len(set(self.left)) != len(self.left) or any(i >= len(self.fused_seqs) for i in self.left):
            raise WireError("left", "expected distinct positions in the fused lists")
        if (len(set(self.handovers)) != len(self.handovers) or set(self.handovers) & set(self.left)
                or any(i >= len(self.fused_seqs) for i in self.handovers)):
            raise WireError("handovers", "expected distinct positions in the fused lists, none a departure")
        if len(self.regions) not in (0, len(self.fused_seqs)):
            raise WireError("regions", "expected none or one for each entry of the fused lists")
        if (len(set(self.in_flight)) != len(self.in_flight) or any(i >= n for i in self.in_flight)
                or len(self.in_flight_t) != len(self.in_flight)):
            raise WireError("in_flight", f"expected distinct positions among the {n} tracks, each with its time")
        if self.closing and n:
            raise WireError("ids", "a closing record has no tracks")
        _check_probabilities(self.existence, n)
        if self.lla is not None and (self.lla.shape != (n, 3) or not (np.abs(self.lla[:, 0]) <= 90.0).all()
                                     or not (np.abs(self.lla[:, 1]) <= 180.0).all()):
            raise WireError("lla", f"expected one row [lat, lon, h] (|lat| <= 90, |lon| <= 180) for each of the {n} tracks")


@dataclass(frozen=True, eq=False)
class HandOver(_Record):
    """A region centre's central track ``id`` handed to the region its latest estimate entered
    (docs/multitarget.md#regions), sent by region ``source`` as its hand-over number ``serial``:
    ``confirmed``; ``ring`` (n, w), its ``n`` out-of-sequence buffer entries (the checkpoint
    first), each the centre's ring fields flattened in their order (time, state, covariance, the
    observation's size, H, R, z, and the maneuver detector's bank and detection when it runs;
    ``-inf`` values, a detector's "no estimate yet", are 0 there and listed by their flat
    positions in ``neg_inf``); per sensor of ``sensors`` its local tracks mapped to the track
    (``support``) and misses in a row (``streak``); the M-of-N ``window``; ``last_support``, the
    time of its last fused observation; its local tracks (``member_sensors[i]``,
    ``member_ids[i]``) and their association ``strikes``."""

    source: str
    serial: int
    id: int
    confirmed: bool
    ring: np.ndarray
    neg_inf: tuple[int, ...]
    sensors: tuple[str, ...]
    support: tuple[int, ...]
    streak: tuple[int, ...]
    window: tuple[bool, ...]
    last_support: float
    member_sensors: tuple[str, ...]
    member_ids: tuple[int, ...]
    strikes: tuple[int, ...]

    _fields = {"source": _identifier, "serial": _count, "id": _count, "confirmed": _flag, "ring": _batch,
               "neg_inf": _counts, "sensors": _identifier_list, "support": _counts,
               "streak": _counts,
               "window": _flags, "last_support": _real,
               "member_sensors": _identifier_list, "member_ids": _counts,
               "strikes": _counts}
    _arrays = ("ring",)

    def _check(self) -> None:
        if self.ring.shape[0] == 0 or self.ring.shape[1] == 0:
            raise WireError("ring", "expected at least one entry")
        if len(set(self.neg_inf)) != len(self.neg_inf) or any(i >= self.ring.size for i in self.neg_inf):
            raise WireError("neg_inf", f"expected distinct positions among the {self.ring.size} ring values")
        s = len(self.sensors)
        if len(set(self.sensors)) != s or len(self.support) != s or len(self.streak) != s:
            raise WireError("sensors", "expected distinct sensors, each with its support and streak")
        n = len(self.member_ids)
        if len(self.member_sensors) != n or len(self.strikes) != n:
            raise WireError("member_ids", "expected a sensor and strikes for each member")
        if len(set(zip(self.member_sensors, self.member_ids))) != n or not set(self.member_sensors) <= set(self.sensors):
            raise WireError("member_sensors", "expected distinct members of the listed sensors")


@dataclass(frozen=True, eq=False)
class Health(_Record):
    """Periodic status of service ``role``/``id``: counters such as received, rejected, published."""

    role: str
    id: str
    seq: int
    counters: dict[str, int]
    status: str

    _fields = {"role": _identifier, "id": _identifier, "seq": _count, "counters": _counters, "status": _text}


M = TypeVar("M", bound=_Record)
Message = (Measurement | LocalEstimate | Reset | FusedTrack | ManeuverEvent | Health | TrackReport | TrackResets
           | TrackPicture | HandOver)
MESSAGE_TYPES: tuple[type[_Record], ...] = (Measurement, LocalEstimate, Reset, FusedTrack, ManeuverEvent, Health,
                                            TrackReport, TrackResets, TrackPicture, HandOver)


# ---------------------------------------------------------------- encoding

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
    _check_counts(msg, " (send it in parts: fedtrack.wire.parts)")
    payload = _pack(msg)
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise WireError(name, f"encoded size {len(payload)} bytes exceeds the limit of {MAX_PAYLOAD_BYTES}")
    return payload


# ---------------------------------------------------------------- decoding

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
    shape, and its data of the right length; every amplitude a finite real. The ``z`` data are
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
    if not all(map(math.isfinite, amplitudes)):
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
            value = _decode_array(value, where, MAX_BATCH_ELEMENTS if cls._fields[name] in _BATCH_CHECKS else MAX_ARRAY_ELEMENTS)
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


# ---------------------------------------------------------------- messages in parts

def _count_over(msg: _Record) -> tuple[str, int, int] | None:
    """The first batch of ``msg`` beyond its bound in one message: (field, items, bound); else None."""
    for items in msg._items:
        n, limit = len(getattr(msg, items.fields[0])), globals()[items.limit]
        if n > limit:
            return items.fields[0], n, limit
    return None


def _check_counts(msg: _Record, hint: str = "") -> None:
    """WireError naming the field when a batch of ``msg`` exceeds its bound in one message."""
    over = _count_over(msg)
    if over is not None:
        name, n, limit = over
        raise WireError(f"{type(msg).__name__}.{name}", f"{n} items exceed the limit of {limit} per message{hint}")


def _rows(value: Any, a: int, b: int, n: int) -> Any:
    """Items [a, b) of a per-item field of ``n`` items (see :class:`_Items`)."""
    if value is None:
        return None
    if isinstance(value, np.ndarray):
        r = value.shape[0] // n if n else 0
        return value[a * r:b * r]
    return value[a:b] if len(value) else value


def _cut(msg: M, k: int) -> list[M]:
    """``msg`` cut into ``k`` parts: each batch's items in ``k`` runs (:class:`_Items`), the other
    fields copied; built unchecked (the receiver decodes each part)."""
    cls, name = type(msg), type(msg).__name__
    batched = {f for items in cls._items for f in items.fields}
    head = {f.name: getattr(msg, f.name) for f in _record_fields(cls) if f.name not in batched}
    values: list[dict[str, Any]] = [{**head, "part": j, "parts": k} for j in range(k)]
    bounds: dict[str, list[int]] = {}  # a batch's first field -> its k + 1 run boundaries
    for items in cls._items:
        first = items.fields[0]
        n = len(getattr(msg, first))
        offsets = [0] * k
        if items.cut is None:
            cuts = [j * n // k for j in range(k + 1)]
        elif items.cut == "of":
            flagged = np.concatenate([[0], np.cumsum(np.asarray(getattr(msg, items.ref), dtype=np.int64))])
            cuts = [int(flagged[b]) for b in bounds[cls._items[0].fields[0]]]
        else:
            outer = bounds[items.ref]  # type: ignore[index]
            owner = np.searchsorted(outer, np.asarray(getattr(msg, first), dtype=np.int64), side="right") - 1
            if np.any(np.diff(owner) < 0):
                raise WireError(f"{name}.{first}", "positions must ascend for the message to be sent in parts")
            cuts = np.searchsorted(owner, np.arange(k + 1)).tolist()
            offsets = outer[:k]
        bounds[first] = cuts
        for j in range(k):
            for f in items.fields:
                values[j][f] = _rows(getattr(msg, f), cuts[j], cuts[j + 1], n)
            if offsets[j]:
                values[j][first] = tuple(p - offsets[j] for p in values[j][first])
    return [cls.unchecked(**v) for v in values]


def _split(msg: M) -> list[tuple[M, bytes]]:
    """The parts of ``msg`` with their payloads (see :func:`parts`)."""
    if not isinstance(msg, MESSAGE_TYPES):
        raise WireError("message", f"not a wire message type: {type(msg).__name__}")
    name = type(msg).__name__
    if _count_over(msg) is None:
        payload = _pack(msg)
        if len(payload) <= MAX_PAYLOAD_BYTES:
            return [(msg, payload)]
        if not msg._items:
            raise WireError(name, f"encoded size {len(payload)} bytes exceeds the limit of {MAX_PAYLOAD_BYTES}")
        k = 2
    else:  # the fewest parts that bring every batch within its bound
        k = max(-(-len(getattr(msg, items.fields[0])) // globals()[items.limit]) for items in msg._items)
    while k <= MAX_PARTS:
        cut = _cut(msg, k)
        packed = [_pack(p) for p in cut]
        largest = max(map(len, packed))
        if largest <= MAX_PAYLOAD_BYTES:
            return list(zip(cut, packed))
        k = max(k + 1, -(-k * largest // MAX_PAYLOAD_BYTES))
    raise WireError(name, f"does not fit in MAX_PARTS = {MAX_PARTS} messages of at most {MAX_PAYLOAD_BYTES} bytes")


def parts(msg: M) -> tuple[M, ...]:
    """``msg`` as messages within every bound of one message (docs/wire.md, "Messages in parts"):
    ``(msg,)`` itself when it is within them (encoded as ever: ``part`` and ``parts`` are left out);
    else the fewest parts, at most MAX_PARTS, in which each batch's count is within its bound and
    each payload within MAX_PAYLOAD_BYTES. Each part holds a run of every batch's items (the
    per-item fields of :class:`_Items`) and a copy of every other field, ``part`` its index (from
    0), ``parts`` their number; :func:`join` is the inverse. WireError if no MAX_PARTS parts fit
    (or ``msg`` is of a type that is not batched and too large)."""
    return tuple(p for p, _ in _split(msg))


def payloads(msg: Message) -> tuple[bytes, ...]:
    """The encoded :func:`parts` of ``msg``, one payload (one put) each."""
    return tuple(payload for _, payload in _split(msg))


def _same(a: Any, b: Any) -> bool:
    """Whether two values of a field are the same (arrays: shape and every value)."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.shape == b.shape and np.array_equal(a, b)
    return type(a) is type(b) and a == b


def join(received: Sequence[M]) -> M:
    """The message whose :func:`parts` are ``received`` (in any order; each a checked message:
    decoded, or built), checked as a whole (its cross-field checks; each field's values were
    checked in their part: a 10,000-track report joins in 14 ms instead of 25).

    WireError naming the field when the parts are not one message's: of different types, a
    ``parts`` that differs (or exceeds MAX_PARTS), an index repeated or missing, any other field
    than the per-item ones differing between parts, per-item fields that do not fit together (a
    None beside an array, rows of different widths), or a whole that is not a valid message (e.g.
    a track id in two parts)."""
    if not received:
        raise WireError("parts", "no parts to join")
    cls = type(received[0])
    name = cls.__name__
    if not cls._items:
        raise WireError(name, "is not a batched message type")
    for p in received:
        if type(p) is not cls:
            raise WireError(f"{name}.type", f"a part of type {type(p).__name__} among {name} parts")
    k = received[0].parts  # type: ignore[attr-defined]
    for p in received:
        if p.parts != k:  # type: ignore[attr-defined]
            raise WireError(f"{name}.parts", f"parts differ: {k} and {p.parts}")  # type: ignore[attr-defined]
    if k > MAX_PARTS:
        raise WireError(f"{name}.parts", f"must be at most {MAX_PARTS}, got {k}")
    ordered = sorted(received, key=lambda p: p.part)  # type: ignore[attr-defined]
    for j, p in enumerate(ordered):
        if p.part != j:  # type: ignore[attr-defined]
            repeated = j > 0 and ordered[j - 1].part == p.part  # type: ignore[attr-defined]
            raise WireError(f"{name}.part", f"part {p.part if repeated else j} of {k} "  # type: ignore[attr-defined]
                                            f"{'repeated' if repeated else 'missing'}")
    if len(ordered) != k:
        raise WireError(f"{name}.part", f"part {len(ordered)} of {k} missing")
    batched = {f for items in cls._items for f in items.fields}
    kwargs: dict[str, Any] = {}
    for f in _record_fields(cls):
        if f.name in batched or f.name in ("part", "parts"):
            continue
        value = getattr(ordered[0], f.name)
        for j, p in enumerate(ordered[1:], 1):
            if not _same(getattr(p, f.name), value):
                raise WireError(f"{name}.{f.name}", f"differs between parts 0 and {j}")
        kwargs[f.name] = value
    counts: dict[str, list[int]] = {}  # a batch's first field -> its items in each part
    for items in cls._items:
        first = items.fields[0]
        counts[first] = [len(getattr(p, first)) for p in ordered]
        for f in items.fields:
            vals = [getattr(p, f) for p in ordered]
            if f == first and items.cut == "at":  # positions in the part's run of the outer batch
                starts = np.cumsum([0, *counts[items.ref][:-1]]).tolist()  # type: ignore[index]
                vals = [tuple(x + s for x in v) for v, s in zip(vals, starts)]
            if all(v is None for v in vals):
                kwargs[f] = None
            elif any(v is None for v in vals):
                raise WireError(f"{name}.{f}", "absent in some parts, present in others")
            elif isinstance(vals[0], np.ndarray):
                try:
                    kwargs[f] = np.concatenate(vals)
                except ValueError:
                    raise WireError(f"{name}.{f}", "rows of different shapes in different parts") from None
            else:
                kwargs[f] = tuple(x for v in vals for x in v)
    # every field's values were checked in their part (decoded, or built): the whole needs only the
    # checks across fields and items (shapes, lengths, unique ids), not the field checks again
    whole = cls.unchecked(**kwargs)
    for f in cls._arrays:
        if getattr(whole, f) is not None:
            getattr(whole, f).setflags(write=False)
    try:
        whole._check()
    except WireError as exc:
        raise WireError(f"{name}.{exc.field}", exc.reason) from None
    return whole


# ---------------------------------------------------------------- replay JSON lines

_REPLAY_MEASUREMENT_KEYS = frozenset({"t", "sensor", "z", "R", "sensor_position", "detections", "seq", "kind",
                                      "stamp_ns"})


def measurement_to_replay(m: Measurement) -> dict[str, Any]:
    """The replay-input line ``{"t", "sensor", "z", "R"}`` (+ ``sensor_position``, ``detections``);
    a multi-target ``scan`` gives the multi-target line (docs/multitarget-formats.md)."""
    if m.kind == "scan":
        with_amplitude = any(d.amplitude != 0 for d in m.detections)
        line: dict[str, Any] = {"t": m.t, "sensor": m.sensor, "R": m.R.tolist(),
                                "detections": [{"z": d.z.tolist(), "amplitude": d.amplitude} if with_amplitude
                                               else {"z": d.z.tolist()} for d in m.detections]}
        if m.sensor_position is not None:
            line["sensor_position"] = m.sensor_position.tolist()
        return line
    row: dict[str, Any] = {"t": m.t, "sensor": m.sensor, "z": m.z.tolist(), "R": m.R.tolist()}
    if m.sensor_position is not None:
        row["sensor_position"] = m.sensor_position.tolist()
    if m.kind == "sonar":
        row["detections"] = [{"z": d.z.tolist(), "amplitude": d.amplitude} for d in m.detections]
    return row


def picture_rows(ids: list[int], X: np.ndarray, P: np.ndarray, confirmed: list[bool], sensors: list[list[str]],
                 models: list[str] | None = None, maneuver: np.ndarray | None = None,
                 existence: list[float] | None = None, lla: np.ndarray | None = None) -> list[dict[str, Any]]:
    """The tracks of a multi-target picture line (docs/multitarget-formats.md), from batched
    states ``X`` (n, d), ``P`` (n, d, d): ``x`` is the CV state (a CA track's marginal), ``models``
    each track's motion model (all ``"cv"`` when None), ``maneuver`` (n, 4) each central track's
    detected maneuver ``[onset, ax, ay, statistic]`` (a row of NaN: none; None: no detector),
    ``existence`` each track's existence probability (``[mtt] associator = "jipda"``; None: not kept),
    ``lla`` (n, 3) each track's WGS-84 position (:func:`with_geodetic`; None: no ``[frame]``)."""
    k = X.shape[1] // 2
    xs, Ps = X.tolist(), P.tolist()
    models = models or ["cv"] * len(ids)
    rows = [{"id": int(tid), "pos": x[0::2][:k], "vel": x[1::2][:k], "x": x, "P": cov, "model": model,
             "status": "confirmed" if conf else "tentative", "sensors": list(sens)}
            for tid, x, cov, conf, sens, model in zip(ids, xs, Ps, confirmed, sensors, models)]
    if maneuver is not None:
        for i in np.flatnonzero(~np.isnan(maneuver[:, 0])).tolist():
            onset, ax, ay, statistic = maneuver[i].tolist()
            rows[i]["maneuver"] = {"onset": onset, "accel": [ax, ay], "statistic": statistic}
    if existence is not None:
        for row, e in zip(rows, existence):
            row["existence"] = e
    return rows if lla is None else with_geodetic(rows, lla)


def with_geodetic(rows: list[dict[str, Any]], lla: np.ndarray) -> list[dict[str, Any]]:
    """Picture or truth rows with ``lat``, ``lon`` [deg] (9 decimals) and, for a 3-D state (``x`` of
    6), ``alt`` [m above the ellipsoid] (4 decimals) from ``lla`` (n, 3), placed beside ``x``; a
    longitude in [-180, 180) stays there once rounded (179.9999999997 is -180.0, not 180.0)."""
    out = []
    for row, (lat, lon, h) in zip(rows, lla.tolist()):
        lon = round(lon, 9)
        extra = {"lat": round(lat, 9), "lon": lon - 360.0 if lon >= 180.0 else lon}
        if len(row["x"]) >= 6:
            extra["alt"] = round(h, 4)
        out.append({**row, **extra})
    return out


def picture_line(t: float, ids: list[int], X: np.ndarray, P: np.ndarray, confirmed: list[bool],
                 sensors: list[list[str]], models: list[str] | None = None, maneuver: np.ndarray | None = None,
                 existence: list[float] | None = None, head: dict[str, Any] | None = None) -> str:
    """The line ``{"t": t, **head, "tracks": picture_rows(...)}`` of a tracks file (``head``: the
    replay's ``algorithm`` and ``detector``), by orjson (a picture of 1,000 tracks: 4 ms against
    json's 28; the same values, each float in its shortest exact form). A picture with a
    non-finite number goes through ``json`` (which spells it ``NaN`` or ``Infinity``; orjson
    would write ``null``)."""
    line = {"t": t, **(head or {}), "tracks": picture_rows(ids, X, P, confirmed, sensors, models, maneuver, existence)}
    if not (np.isfinite(X).all() and np.isfinite(P).all()):
        return json.dumps(line)
    return orjson.dumps(line).decode()


def picture_to_replay(pic: TrackPicture) -> dict[str, Any]:
    """The picture line ``{"t", "tracks": [...]}`` that ``replay --algorithm mtt-*`` writes
    (plus ``"contested": true`` for a contested picture, which no replay writes)."""
    d = pic.x.shape[1]
    models = ["ca" if ca else "cv" for ca in pic.ca] if pic.ca else None
    maneuver = None
    if pic.maneuver is not None:
        maneuver = np.full((len(pic.ids), 4), np.nan)
        maneuver[list(pic.maneuvering)] = pic.maneuver
    existence = None if pic.existence is None else pic.existence.tolist()
    line = {"t": pic.t, "tracks": picture_rows(list(pic.ids), pic.x, pic.P.reshape(-1, d, d), list(pic.confirmed),
                                               [list(s) for s in pic.sensors], models, maneuver, existence, pic.lla)}
    if pic.contested:
        line["contested"] = True
    return line


def _json_field(obj: dict[str, Any], key: str, where: str) -> Any:
    if key not in obj:
        raise InputError(f"{where}: missing field {key!r}")
    return obj[key]


def _json_array(value: Any, key: str, where: str) -> np.ndarray:
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{where}: {key} must be a (nested) list of numbers") from None


def measurement_from_replay(obj: dict[str, Any], where: str, seq: int = 0) -> Measurement:
    """Inverse of :func:`measurement_to_replay`; ``kind`` is inferred when absent
    (detections -> sonar, sensor_position -> radar, else position). ``seq`` is used
    unless the line has one. Raises InputError naming ``where`` and the field.
    """
    unknown = sorted(set(obj) - _REPLAY_MEASUREMENT_KEYS)
    if unknown:
        raise InputError(f"{where}: unknown field {unknown[0]!r}")
    kind = obj.get("kind", "sonar" if "detections" in obj else "radar" if "sensor_position" in obj else "position")
    detections = obj.get("detections", [])
    if not isinstance(detections, list) or not all(isinstance(d, dict) for d in detections):
        raise InputError(f"{where}: detections must be a list of {{\"z\", \"amplitude\"}} objects")
    try:
        return Measurement(
            sensor=_json_field(obj, "sensor", where), seq=obj.get("seq", seq), t=_json_field(obj, "t", where),
            kind=kind, z=_json_array(_json_field(obj, "z", where), "z", where),
            R=_json_array(_json_field(obj, "R", where), "R", where),
            detections=tuple((_json_array(_json_field(d, "z", f"{where}: detections[{i}]"), "z", where),
                              _json_field(d, "amplitude", f"{where}: detections[{i}]"))
                             for i, d in enumerate(detections)),
            sensor_position=(None if obj.get("sensor_position") is None
                             else _json_array(obj["sensor_position"], "sensor_position", where)),
            stamp_ns=obj.get("stamp_ns", 0))
    except WireError as exc:
        raise InputError(f"{where}: {exc}") from None


_TRACK_DEFAULT_KEYS = ("t", "x", "P", "model", "maneuver", "degraded", "seq", "sensors")


def track_to_replay(track: FusedTrack) -> dict[str, Any]:
    """The replay-output line ``{"t", "x", "P", "model", "maneuver", "degraded", "seq", "sensors"}``
    plus the ``extra`` entries as top-level fields, and ``"contested": true`` for a contested
    track (which no replay writes)."""
    row: dict[str, Any] = {"t": track.t, "x": track.x.tolist(), "P": track.P.tolist(), "model": track.model,
                           "maneuver": track.maneuver, "degraded": track.degraded, "seq": track.seq,
                           "sensors": list(track.sensors)}
    row.update({k: list(v) if isinstance(v, tuple) else v for k, v in track.extra.items()})
    if track.contested:
        row["contested"] = True
    return row


def track_from_replay(obj: dict[str, Any], where: str, seq: int = 0) -> FusedTrack:
    """Inverse of :func:`track_to_replay`. ``degraded`` (false), ``seq`` (the argument),
    ``sensors`` ([]), ``stamp_ns`` (0) and ``contested`` (false) may be absent; other keys become ``extra``,
    except null-valued ones (e.g. ``"event": null`` of the fusion replay), which count as absent."""
    extra = {k: v for k, v in obj.items() if k not in (*_TRACK_DEFAULT_KEYS, "stamp_ns", "contested") and v is not None}
    try:
        return FusedTrack(
            seq=obj.get("seq", seq), t=_json_field(obj, "t", where), model=_json_field(obj, "model", where),
            x=_json_array(_json_field(obj, "x", where), "x", where),
            P=_json_array(_json_field(obj, "P", where), "P", where),
            maneuver=_json_field(obj, "maneuver", where), degraded=obj.get("degraded", False),
            sensors=obj.get("sensors", ()), stamp_ns=obj.get("stamp_ns", 0), extra=extra,
            contested=obj.get("contested", False))
    except WireError as exc:
        raise InputError(f"{where}: {exc}") from None
