"""One sensor scan of detections: the multi-target input line and its validation.

Line format (JSON Lines, one line per sensor scan, in arrival order)::

    {"t": s, "sensor": id, "R": [[..]], "detections": [{"z": [..], "amplitude": a?}, ...],
     "sensor_position": [x, y, z]?}

A line with ``sensor_position`` is a radar scan (``z`` = range [m], azimuth, elevation
[rad] of the target less ``sensor_position`` in the common frame's axes: azimuth ``atan2(d_y, d_x)``,
elevation above the x-y plane; :func:`check_plots`); without it, a 2-D position scan (``z`` = [x, y] [m]).
A line ``{"t", "sensor", "left": true}`` records that a live centre dropped the sensor there (:class:`SensorLeft`); one
``{"t", "sensor", "restarted": true}`` that the sensor's local tracker started afresh there, a
restarted process (:class:`TrackerRestarted`).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from fedtrack.geodetic import FrameConfig, sensor_position_error
from fedtrack.jsonl import COMMON_FIELDS, InputError, as_covariance, as_float, as_vector, check_fields, require
from fedtrack.keys import InvalidName, check_id
from fedtrack.local_filters.radar.measurement import polar_error
from fedtrack.wire import Measurement

SCAN_FIELDS = COMMON_FIELDS | {"detections", "sensor_position"}
DETECTION_FIELDS = frozenset({"z", "amplitude"})
MAX_DETECTIONS = 100_000


class SensorScan(NamedTuple):
    t: float
    sensor: str
    R: np.ndarray  # (m, m)
    z: np.ndarray  # (M, m)
    amplitude: np.ndarray | None  # (M,) when every detection carries one
    sensor_position: np.ndarray | None  # (3,) for a radar
    repeated: int = 0  # detections dropped as equal to an earlier one of the scan (:func:`distinct`)

    @property
    def dim(self) -> int:
        return self.R.shape[0]


class SensorLeft(NamedTuple):
    """A departure line ``{"t": s, "sensor": id, "left": true}``: from here on the centre no
    longer counts ``sensor`` (a live centre writes one where it dropped a sensor; ``t`` is the
    data time of the picture that recorded it, for information)."""

    t: float
    sensor: str


class TrackerRestarted(NamedTuple):
    """A restart line ``{"t": s, "sensor": id, "restarted": true}``: the sensor's local tracker
    started afresh with its next scan (its process restarted: tracks and ids new), and the centre
    dropped the local tracks of the former one (a live centre writes one where it took the first
    report of a tracker process from a sensor it had heard before; ``t`` as a departure's;
    ``seq``: in a region run's recording, the number of that next scan)."""

    t: float
    sensor: str
    seq: int | None = None


MARKS = {"left": ("departure", SensorLeft), "restarted": ("restart", TrackerRestarted)}


def parse_line(obj: dict[str, Any], where: str) -> SensorScan | SensorLeft | TrackerRestarted:
    """A scan line, a departure line (one with ``"left": true``) or a restart line (``"restarted": true``)."""
    mark = next((name for name in MARKS if name in obj), None)
    if mark is None:
        return parse_scan(obj, where)
    what, kind = MARKS[mark]
    check_fields(obj, frozenset({"t", "sensor", mark}), what, where)
    if obj[mark] is not True:
        raise InputError(f"{where}: {mark} must be true")
    sensor = require(obj, "sensor", where)
    try:
        check_id(sensor)
    except (InvalidName, TypeError) as exc:
        raise InputError(f"{where}: sensor: {exc}") from exc
    return kind(as_float(require(obj, "t", where), "t", where), sensor)


def parse_scan(obj: dict[str, Any], where: str) -> SensorScan:
    """Validate one multi-target input line (errors name ``where`` = ``file:line`` and the field)."""
    check_fields(obj, SCAN_FIELDS, obj.get("kind", "mtt"), where)
    t = as_float(require(obj, "t", where), "t", where)
    sensor = require(obj, "sensor", where)
    if not isinstance(sensor, str):
        raise InputError(f"{where}: sensor must be a string id, got {sensor!r}")
    try:
        check_id(sensor)
    except InvalidName as exc:
        raise InputError(f"{where}: sensor: {exc}") from exc
    sp = obj.get("sensor_position")
    sensor_position = None if sp is None else as_vector(sp, "sensor_position", where, 3)
    m = 2 if sensor_position is None else 3
    R = require(obj, "R", where)
    if isinstance(R, list) and len(R) == 5 - m:  # the other kind's R: say what makes a scan a radar's
        raise InputError(f"{where}: R is {5 - m}x{5 - m} but " + (
            "the line has no sensor_position: a radar scan needs sensor_position [x, y, z] (and z = "
            "[range, azimuth, elevation]); a 2-D position scan has a 2x2 R" if m == 2 else
            "the line has sensor_position: a radar scan has a 3x3 R (range, azimuth, elevation); "
            "a 2-D position scan has no sensor_position"))
    R = as_covariance(R, "R", where, m)
    dets = require(obj, "detections", where)
    if not isinstance(dets, list) or len(dets) > MAX_DETECTIONS:
        raise InputError(f"{where}: detections must be a list of at most {MAX_DETECTIONS} objects")
    if all(type(det) is dict and det.keys() == {"z"} for det in dets):  # the common case, batched
        try:
            z = np.asarray([det["z"] for det in dets], dtype=float)
        except (TypeError, ValueError):
            z = None  # a malformed one: the loop below names it
        if z is not None and z.shape == (len(dets), m) and np.all(np.isfinite(z)):
            if sensor_position is not None:
                check_plots(z, where)
            return distinct(SensorScan(t, sensor, R, z, None, sensor_position))
    z = np.empty((len(dets), m))
    amp = np.empty(len(dets))
    has_amp = 0
    for j, det in enumerate(dets):
        if not isinstance(det, dict):
            raise InputError(f"{where}: detections[{j}] must be an object")
        check_fields(det, DETECTION_FIELDS, "detection", f"{where}: detections[{j}]")
        z[j] = as_vector(require(det, "z", where), f"detections[{j}].z", where, m)
        if "amplitude" in det:
            amp[j] = as_float(det["amplitude"], f"detections[{j}].amplitude", where)
            has_amp += 1
    if 0 < has_amp < len(dets):
        raise InputError(f"{where}: amplitude must be given for every detection of a scan or for none")
    if sensor_position is not None:
        check_plots(z, where)
    return distinct(SensorScan(t, sensor, R, z, amp if has_amp else None, sensor_position))


def check_plots(z: np.ndarray, where: str) -> None:
    """A radar scan's detections ``z`` (M, 3) are plots (:func:`polar_error`), else an error naming ``where``, the
    detection and its component."""
    problem = polar_error(z)
    if problem:
        raise InputError(f"{where}: detections[{problem[0]}].{problem[1]}")


def misplaced(scan: SensorScan, frame: FrameConfig | None) -> str | None:
    """Why a radar scan's ``sensor_position`` cannot be its radar's on the Earth of ``frame`` (``[frame]``: its
    heights, its ``[frame.sites]``; :func:`~fedtrack.geodetic.sensor_position_error`); None when it can, or for a
    position scan or without a frame. ``replay`` refuses such a file, the live trackers such a scan."""
    if frame is None or scan.sensor_position is None:
        return None
    return sensor_position_error(frame, scan.sensor, scan.sensor_position)


def distinct(scan: SensorScan) -> SensorScan:
    """``scan`` without the detections whose ``z`` equals an earlier one's of the same scan (a sensor
    or link that reports a detection twice), their number in ``repeated``. A repeat carries no new
    information, and a tracker that took it as a second detection started a second track on every
    target (docs/multitarget-formats.md, "Repeated detections")."""
    if scan.z.shape[0] < 2:
        return scan
    _, first = np.unique(scan.z, axis=0, return_index=True)
    if first.size == scan.z.shape[0]:
        return scan
    keep = np.sort(first)
    amp = None if scan.amplitude is None else scan.amplitude[keep]
    return scan._replace(z=scan.z[keep], amplitude=amp, repeated=scan.repeated + scan.z.shape[0] - keep.size)


def scan_to_measurement(scan: SensorScan, seq: int, stamp_ns: int) -> Measurement:
    """The wire form (``kind = "scan"``; amplitude 0 on every detection when the scan has none)."""
    amp = scan.amplitude if scan.amplitude is not None else np.zeros(scan.z.shape[0])
    return Measurement(sensor=scan.sensor, seq=seq, t=scan.t, kind="scan", z=np.zeros(0), R=scan.R,
                       detections=tuple(zip(scan.z, amp.tolist())), sensor_position=scan.sensor_position,
                       stamp_ns=stamp_ns)


def scan_from_measurement(msg: Measurement) -> SensorScan:
    """Inverse of :func:`scan_to_measurement` (repeated detections dropped: :func:`distinct`); ValueError
    naming the field for a measurement that is not a valid multi-target scan (another kind, wrong
    sizes, a radar plot that :func:`polar_error` refuses)."""
    if msg.kind != "scan":
        raise ValueError(f"kind: expected 'scan', got {msg.kind!r}")
    m = 2 if msg.sensor_position is None else 3
    if msg.R.shape != (m, m) or (msg.sensor_position is not None and msg.sensor_position.shape != (3,)):
        raise ValueError(f"R: expected ({m}, {m}) for a {'radar' if m == 3 else 'position'} scan, got {msg.R.shape}")
    z = np.array([d.z for d in msg.detections]).reshape(-1, m)
    amp = np.array([d.amplitude for d in msg.detections])
    problem = None if msg.sensor_position is None else polar_error(z)
    if problem:
        raise ValueError(f"detections[{problem[0]}].{problem[1]}")
    return distinct(SensorScan(msg.t, msg.sensor, np.array(msg.R), z, amp if np.any(amp != 0) else None,
                               None if msg.sensor_position is None else np.array(msg.sensor_position)))
