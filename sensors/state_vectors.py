"""Recorded air traffic read for ``fedtrack simulate traffic``: state vectors (OpenSky's, or the
``traffic`` library's export), one row per aircraft and time; CSV, JSON (pandas' ``to_json``), JSON
Lines (each optionally gzipped) or Parquet (needs pyarrow: the ``real`` extra); columns matched by
their accepted names (:data:`COLUMNS`), units by ``--units`` (:data:`UNITS`); the airborne samples
with a position, sorted by aircraft then time (:func:`read_recording`).
"""

from __future__ import annotations

import csv
import gzip
import io
import json
import math
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from fedtrack.jsonl import InputError, check_readable, read_jsonl

#: column -> accepted names (the first is ours; OpenSky's and the traffic library's follow)
COLUMNS: dict[str, tuple[str, ...]] = {
    "time": ("time", "timestamp", "ts"),
    "icao24": ("icao24", "icao", "hex"),
    "latitude": ("latitude", "lat"),
    "longitude": ("longitude", "lon", "lng"),
    "altitude": ("altitude", "baroaltitude", "baro_altitude", "alt"),
    "groundspeed": ("groundspeed", "velocity", "ground_speed", "gs"),
    "track": ("track", "heading", "true_track"),
    "vertical_rate": ("vertical_rate", "vertrate", "vertical_speed"),
    "onground": ("onground", "on_ground"),
}
REQUIRED = ("time", "icao24", "latitude", "longitude", "altitude")
VELOCITY = ("groundspeed", "track", "vertical_rate")
#: --units -> factors to m, m/s, m/s of altitude, ground speed, vertical rate
UNITS = {"si": (1.0, 1.0, 1.0), "aviation": (0.3048, 1852.0 / 3600.0, 0.3048 / 60.0)}
#: a time this large is milliseconds since 1970 (pandas' JSON, the traffic library's): as seconds it would
#: be after the year 5000
MILLISECONDS_FROM = 1e11


class Recording(NamedTuple):
    """Airborne samples, sorted by aircraft then time: ``t`` [s since 1970], ``icao24``, ``lla`` (N, 3)
    [deg, deg, m], ``velocity`` (N, 3) east, north, up [m/s] in the local axes (NaN: not recorded);
    ``dropped``: the rows read but left out, by reason; ``ground``: each aircraft's times of its rows on the ground
    (sorted; a report on the ground bounds its altitude seconds away: :func:`~.traffic_truth.above_the_runways`)."""

    t: np.ndarray
    icao24: np.ndarray
    lla: np.ndarray
    velocity: np.ndarray
    dropped: dict[str, int]
    ground: dict[str, np.ndarray] | None = None


def _rows(path: Path) -> tuple[list[str], list[tuple[int, list[Any]]]]:
    """``(column names, [(line or row number, values)])`` of a CSV, JSON Lines or Parquet file."""
    name = path.name.lower()
    opener = gzip.open if name.endswith(".gz") else open
    base = name.removesuffix(".gz")
    try:
        if base.endswith(".parquet"):
            try:
                import pyarrow.parquet as pq
            except ImportError as exc:
                raise InputError(f"{path}: reading Parquet needs pyarrow (pip install 'fedtrack[real]')") from exc
            table = pq.read_table(path).to_pydict()
            cols = list(table)
            return cols, [(i + 1, list(row)) for i, row in enumerate(zip(*table.values()))]
        if base.endswith(".csv"):
            with opener(path, "rt", newline="", encoding="utf-8-sig") as fh:  # a spreadsheet's byte-order mark
                reader = csv.reader(fh)
                cols = next(reader, [])
                return cols, [(i, row) for i, row in enumerate(reader, start=2) if row]
        if base.endswith(".json"):
            with opener(path, "rb") as fh:
                return _json_table(json.load(fh), path)
        if base.endswith((".jsonl", ".ndjson")):
            if name.endswith(".gz"):
                with gzip.open(path, "rb") as fh:
                    text = fh.read()
                tmp = [(i, json.loads(line)) for i, line in enumerate(io.BytesIO(text), start=1) if line.strip()]
            else:
                tmp = list(read_jsonl(path))
            cols = sorted({k for _, obj in tmp for k in obj})
            return cols, [(i, [obj.get(c) for c in cols]) for i, obj in tmp]
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, csv.Error, RecursionError) as exc:
        raise InputError(f"{path}: cannot read: {exc}") from exc
    raise InputError(f"{path}: unknown format (expected .csv, .json, .jsonl or .parquet; .csv, .json and .jsonl "
                     "may be gzipped)")


def _json_table(obj: Any, path: Path) -> tuple[list[str], list[tuple[int, list[Any]]]]:
    """``(column names, [(row number from 1, values)])`` of a JSON table as pandas' ``to_json`` writes one
    (the ``traffic`` package's samples): an array of row objects (``orient="records"``) or an object of
    columns, each an object from row label to a value that is no object or array (``orient="columns"``, pandas'
    default)."""
    if isinstance(obj, list) and all(isinstance(row, dict) for row in obj):
        cols = sorted({k for row in obj for k in row})
        return cols, [(i, [row.get(c) for c in cols]) for i, row in enumerate(obj, start=1)]
    if isinstance(obj, dict) and obj and all(isinstance(col, dict) and not any(isinstance(v, (dict, list))
                                                                               for v in col.values())
                                             for col in obj.values()):
        cols = list(obj)
        labels = list(dict.fromkeys(label for col in obj.values() for label in col))
        return cols, [(i, [obj[c].get(label) for c in cols]) for i, label in enumerate(labels, start=1)]
    raise InputError(f"{path}: not a table of state vectors: a .json file must hold an array of row objects "
                     "or an object of columns (pandas' to_json, orient records or columns)")


def _seconds(value: Any, where: str) -> float:
    if isinstance(value, datetime):
        stamp = value
    else:
        try:
            seconds = None if isinstance(value, bool) else float(str(value).strip())
        except ValueError:
            seconds = None
        if seconds is not None:
            if not math.isfinite(seconds):
                raise InputError(f"{where}: time: {value!r} is not a finite number of seconds")
            return seconds / 1000.0 if abs(seconds) >= MILLISECONDS_FROM else seconds
        try:
            stamp = datetime.fromisoformat(str(value).strip().replace("Z", "+00:00"))
        except ValueError as exc:
            raise InputError(f"{where}: time: {value!r} is neither seconds nor an ISO-8601 date") from exc
    if stamp.tzinfo is None:
        stamp = stamp.replace(tzinfo=timezone.utc)
    return stamp.timestamp()


def _address(value: Any, where: str) -> str:
    """An aircraft's icao24, trimmed and lower-cased; an empty one is an error (its rows would be one
    aircraft's track, whatever aircraft they are)."""
    text = "" if value is None else str(value).strip().lower()
    if text in ("", "nan", "none", "null"):
        raise InputError(f"{where}: icao24: {value!r} is empty (each row needs the aircraft's address)")
    return text


def _number(value: Any, where: str, field: str) -> float:
    if value is None or value == "":
        return math.nan
    try:
        return float(value)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}: {field}: {value!r} is not a number") from exc


def _flag(value: Any) -> bool:
    return value is True or str(value).strip().lower() in ("true", "1", "t", "yes")


def read_recording(path: Path, units: str = "si") -> Recording:
    """The airborne samples of a recording (rows on the ground or without a position dropped)."""
    check_readable(path)
    names, rows = _rows(path)
    lower = {n.lower(): i for i, n in enumerate(names)}
    index: dict[str, int] = {}
    for col, aliases in COLUMNS.items():
        found = [lower[a] for a in aliases if a in lower]
        if found:
            index[col] = found[0]
        elif col in REQUIRED:
            raise InputError(f"{path}: no {col} column (accepted names: {', '.join(aliases)})")
    k_alt, k_gs, k_vr = UNITS[units]
    t, ids, lla, vel = [], [], [], []
    ground = missing = 0
    grounded: dict[str, list[float]] = {}
    for lineno, row in rows:
        where = f"{path}:{lineno}"
        if len(row) < len(names):
            raise InputError(f"{where}: {len(row)} fields, the header has {len(names)}")
        if "onground" in index and _flag(row[index["onground"]]):
            ground += 1
            try:  # its time only bounds the airborne samples' altitudes: a row it cannot read bounds nothing
                icao, when = _address(row[index["icao24"]], where), _seconds(row[index["time"]], where)
            except InputError:
                continue
            grounded.setdefault(icao, []).append(when)
            continue
        point = [_number(row[index[c]], where, c) for c in ("latitude", "longitude", "altitude")]
        if not all(map(math.isfinite, point)):
            missing += 1
            continue
        if not (-90 <= point[0] <= 90 and -180 <= point[1] <= 360):
            raise InputError(f"{where}: latitude, longitude: {point[0]}, {point[1]} is not on the Earth")
        t.append(_seconds(row[index["time"]], where))
        ids.append(_address(row[index["icao24"]], where))
        lla.append([point[0], point[1], point[2] * k_alt])
        gs, trk, vr = (_number(row[index[c]], where, c) if c in index else math.nan for c in VELOCITY)
        a = math.radians(trk)
        vel.append([gs * k_gs * math.sin(a), gs * k_gs * math.cos(a), vr * k_vr])  # NaN: not recorded
    if not t:
        raise InputError(f"{path}: no airborne sample with a position")
    order = np.lexsort((np.array(t), np.array(ids)))
    return Recording(np.array(t)[order], np.array(ids)[order], np.array(lla, float)[order],
                     np.array(vel, float)[order], {"on the ground": ground, "without a position or altitude": missing},
                     {icao: np.sort(np.array(times)) for icao, times in grounded.items()})
