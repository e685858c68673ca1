"""The record base (validated on construction, built unchecked by a service for its own values) and the
single-target messages: Measurement, LocalEstimate, Reset, FusedTrack, ManeuverEvent, Health."""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, NamedTuple, TypeVar

import numpy as np

from fedtrack.wire.fields import (
    _check_part,
    _check_square,
    _check_state,
    _choice,
    _count,
    _counters,
    _covariance,
    _flag,
    _identifier,
    _identifiers,
    _mapping,
    _optional,
    _real,
    _scans,
    _sequence,
    _text,
    _vector,
    _whole,
)
from fedtrack.wire.limits import (
    EVENT_KINDS,
    FLOAT_EPS,
    MAX_DETECTIONS,
    MAX_LIST_ITEMS,
    MEASUREMENT_KINDS,
    PD_RTOL,
    WireError,
)

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
        _check_state(self.x, self.P)
        _check_state(self.x_prior, self.P_prior, "x_prior", "P_prior")


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
        _check_state(self.x, self.P)
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
        _check_state(self.x, self.P)


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




@dataclass(frozen=True, eq=False)
class Health(_Record):
    """Periodic status of service ``role``/``id``: counters such as received, rejected, published."""

    role: str
    id: str
    seq: int
    counters: dict[str, int]
    status: str

    _fields = {"role": _identifier, "id": _identifier, "seq": _count, "counters": _counters, "status": _text}
