"""The replay files' JSON objects of measurements, tracks and pictures (docs/multitarget-formats.md)."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import orjson

from fedtrack.jsonl import InputError
from fedtrack.wire.batches import TrackPicture
from fedtrack.wire.limits import WireError
from fedtrack.wire.records import FusedTrack, Measurement

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
                 existence: list[float] | None = None, lla: np.ndarray | None = None,
                 alt_measured: tuple[bool, ...] = ()) -> list[dict[str, Any]]:
    """The tracks of a multi-target picture line (docs/multitarget-formats.md), from batched
    states ``X`` (n, d), ``P`` (n, d, d): ``x`` is the CV state (a CA track's marginal), ``models``
    each track's motion model (all ``"cv"`` when None), ``maneuver`` (n, 4) each central track's
    detected maneuver ``[onset, ax, ay, statistic]`` (a row of NaN: none; None: no detector),
    ``existence`` each track's existence probability (``[mtt] associator = "jipda"``; None: not kept),
    ``lla`` (n, 3) each track's WGS-84 position and ``alt_measured`` whether its altitude was measured
    (:func:`with_geodetic`; None: no ``[frame]``)."""
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
    return rows if lla is None else with_geodetic(rows, lla, alt_measured)


def with_geodetic(rows: list[dict[str, Any]], lla: np.ndarray,
                  alt_measured: tuple[bool, ...] = ()) -> list[dict[str, Any]]:
    """Picture or truth rows with ``lat``, ``lon`` [deg] (9 decimals) and, for a 3-D state (``x`` of
    6), ``alt`` [m above the ellipsoid] (4 decimals) from ``lla`` (n, 3), placed beside ``x``; a
    longitude in [-180, 180) stays there once rounded (179.9999999997 is -180.0, not 180.0). A row whose
    ``alt_measured`` (none or one per row) is false gets ``"alt_measured": false`` last (docs/geodetic.md,
    "Altitudes nobody measured")."""
    out = []
    for i, (row, (lat, lon, h)) in enumerate(zip(rows, lla.tolist())):
        lon = round(lon, 9)
        extra = {"lat": round(lat, 9), "lon": lon - 360.0 if lon >= 180.0 else lon}
        if len(row["x"]) >= 6:
            extra["alt"] = round(h, 4)
        if alt_measured and not alt_measured[i]:
            extra["alt_measured"] = False
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
                                               [list(s) for s in pic.sensors], models, maneuver, existence, pic.lla,
                                               pic.alt_measured)}
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
