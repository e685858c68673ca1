"""``fedtrack simulate traffic``: recorded air traffic as truth, sensors on the Earth simulated on it.

Input: recorded state vectors (OpenSky's, or the ``traffic`` library's export), one row per
aircraft and time; CSV, JSON Lines (either optionally gzipped) or Parquet (needs pyarrow: the
``real`` extra). Truth: each airborne aircraft's samples in the common ENU frame about
``--origin`` (:mod:`fedtrack.geodetic`), interpolated between samples by cubic Hermite pieces
through the recorded positions and velocities; a gap longer than ``--max-gap`` ends a track and
the next sample starts a new one (a new truth id). Sensors (:mod:`fedtrack.sensors.multitarget`'s
``sensor_lines``): 2-D position plots, radars in their own frames at sites on the Earth, and
ADS-B receivers; each with its period, phase, P_D, clutter and delays.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import gzip
import io
import json
import math
import os
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from scipy.interpolate import CubicHermiteSpline
from scipy.linalg import solveh_banded

from fedtrack.config import seed_number, to_toml
from fedtrack.geodetic import (
    WGS84_A,
    WGS84_E2,
    Frame,
    RadarSite,
    common_from_local_vectors,
    enu_from_geodetic,
    geodetic_error,
    geodetic_from_enu,
    ground_angle,
    local_from_common_vectors,
    radio_reach,
    site_from_geodetic,
    surface_enu,
    surface_xy,
    wrap_lon,
)
from fedtrack.jsonl import InputError, check_output_folder, check_readable, output_file, read_jsonl
from fedtrack.sensors.multitarget import (
    DT,
    MAX_CLUTTER,
    RADAR_SD,
    Scenario,
    SensorSpec,
    check_options,
    clutter_density,
    parse_spec,
    position_clutter_density,
    sensor_lines,
)

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
#: NACp -> EPU [m], the 95 % bound of the horizontal position error (DO-260B); sigma per axis = EPU / 2.448
NACP_EPU = {7: 185.2, 8: 92.6, 9: 30.0, 10: 10.0, 11: 3.0}
#: the reconciliation of recorded positions with recorded velocities (docs/geodetic.md)
SIGMA_POSITION = 50.0  # m: a state vector's position is up to a second older or newer than its time
SIGMA_VELOCITY = 0.5  # m/s: ground speed is reported to the knot, vertical rate to 64 ft/min
#: a time this large is milliseconds since 1970 (pandas' JSON, the traffic library's): as seconds it would
#: be after the year 5000
MILLISECONDS_FROM = 1e11
#: memory a window takes: per state of the truth grid (a step of ``DT`` of one aircraft track inside the box) 100
#: bytes at the peak (six float64 and a flag held, plus each track's states before the grid and the derived keys'
#: temporaries: measured, 5.44 GB of peak resident memory for the whole of the traffic package's
#: ``collections/quickstart``, 10,798 s of 244 tracks, 52.7 million states); per scan and detection until they
#: are written (Python's dicts and lists, measured with tracemalloc: 1,000 + 430 a detection)
TRUTH_CELL_BYTES = 100
SCAN_BYTES = 1000
DETECTION_BYTES = 430
SQUITTER_S = (0.4, 0.6)  # s: airborne position squitters at random intervals of 0.4-0.6 s (DO-260B)
#: the trackers' two motion modes (``[mtt] process_noise = "imm"``) from civil air-traffic kinematics, not
#: from a recording (docs/geodetic.md, "The motion model"): turns at 25 deg of bank or 3 deg/s, whichever
#: is less (ICAO PANS-OPS), so a horizontal acceleration of at most g tan 25 deg = 4.57 m/s^2
MANEUVER_ACCELERATION = 9.80665 * math.tan(math.radians(25.0))
MANEUVER_S = 90.0 / 3.0  # s: a 90 deg heading change at the standard rate of 3 deg/s
STRAIGHT_S = 120.0  # s: terminal-area legs between heading changes (holding legs 1-1.5 min, approach segments 1-3 min)
CHI2_2_95 = math.sqrt(-2.0 * math.log(0.05))  # the 95 % radius of a 2-D standard normal: 2.448
CHI2_2_999 = math.sqrt(-2.0 * math.log(0.001))  # its 99.9 % radius: 3.717

HELP_COLUMNS = """input columns (names are matched case-insensitively; the first name is ours, the others
OpenSky's and the traffic library's):
  time           seconds since 1970 (UTC; a number over 1e11 is taken as milliseconds, as
                 pandas writes JSON), or an ISO-8601 date and time (UTC when no zone):
                 time, timestamp, ts
  icao24         the aircraft's address: icao24, icao, hex
  latitude       degrees (WGS-84): latitude, lat
  longitude      degrees (WGS-84): longitude, lon, lng
  altitude       barometric altitude, taken as height above the WGS-84 ellipsoid: altitude,
                 baroaltitude, baro_altitude, alt
  groundspeed    optional: groundspeed, velocity, ground_speed, gs
  track          optional, degrees from true north: track, heading, true_track
  vertical_rate  optional: vertical_rate, vertrate, vertical_speed
  onground       optional, true/false: onground, on_ground (rows on the ground are dropped)
units (--units): si (default, OpenSky's state vectors): altitude m, speeds m/s; aviation (the
traffic library's export): altitude ft, ground speed kt, vertical rate ft/min.
A velocity not recorded (no ground speed and track, or no vertical rate: columns or cells) is the
derivative of the positions (numpy's gradient).

sensors (--sensors, comma-separated KIND:PERIOD[/SIGMA...][@LAT/LON/H]):
  pos:P[/S]      2-D position plots every P s; noise S m per axis (default: drawn in 10-20 m
                 per axis, correlation 0.3)
  radar:P[/SR/SA[/SE]][@SITE]
                 a radar scanning every P s at the WGS-84 site LAT/LON/H (deg, deg, m); without a
                 site it stands on the box's edge at the origin's height; noise in its own
                 frame: range SR m, azimuth SA and elevation SE degrees (default 10 m, 2 mrad =
                 0.1146 deg, 2 mrad); it detects only above its radio horizon (4/3 Earth)
  e.g. the set of published requirements in docs/geodetic.md:
                 radar:4/70/0.08@49.2/2.0/100,radar:5/70/0.08@48.6/2.9/100,pos:2/106
  adsb:P         an ADS-B receiver publishing every P s the reports received since its last scan;
                 each aircraft reports at its own rate (a period drawn in 0.4-0.6 s, DO-260B's
                 squitter interval), its position moved to the scan time with its velocity;
                 accuracy from --nacp; no clutter"""


class Recording(NamedTuple):
    """Airborne samples, sorted by aircraft then time: ``t`` [s since 1970], ``icao24``, ``lla`` (N, 3)
    [deg, deg, m], ``velocity`` (N, 3) east, north, up [m/s] in the local axes (NaN: not recorded);
    ``dropped``: the rows read but left out, by reason."""

    t: np.ndarray
    icao24: np.ndarray
    lla: np.ndarray
    velocity: np.ndarray
    dropped: dict[str, int]


class Truth(NamedTuple):
    """States ``x`` (steps, N, 6) ``[x, vx, y, vy, z, vz]`` on the ``DT`` grid from ``t0`` [s since
    1970], ``alive`` (steps, N), each target's ``icao24`` (N,); ``dropped``: the recording's samples
    and aircraft left out, by reason (:func:`build_truth`). ``surface``: the world is the ellipsoid's
    surface (2-D sensors only): ``x``, ``y`` are the common frame's east, north of the point of the ellipsoid
    below the aircraft, ``z`` its height above the ellipsoid (:func:`on_surface`)."""

    t0: float
    x: np.ndarray
    alive: np.ndarray
    icao24: list[str]
    dropped: dict[str, int]
    surface: bool = False


class Segments(NamedTuple):
    """Row indices of each track (:func:`segments`), and how many rows were left out: ``repeated``
    (a time or position repeated), ``single`` (a track of one sample)."""

    pieces: list[np.ndarray]
    repeated: int
    single: int


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
    for lineno, row in rows:
        where = f"{path}:{lineno}"
        if len(row) < len(names):
            raise InputError(f"{where}: {len(row)} fields, the header has {len(names)}")
        if "onground" in index and _flag(row[index["onground"]]):
            ground += 1
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
                     np.array(vel, float)[order], {"on the ground": ground, "without a position or altitude": missing})


def segments(rec: Recording, max_gap: float) -> Segments:
    """Row indices of each track: one aircraft's samples, a repeated (stale) position or time dropped,
    split where the gap between samples exceeds ``max_gap`` [s]; tracks of one sample dropped."""
    out = []
    repeated = single = 0
    bounds = np.flatnonzero(np.r_[True, rec.icao24[1:] != rec.icao24[:-1], True])
    for a, b in zip(bounds[:-1], bounds[1:]):
        rows = np.arange(a, b)
        same = np.r_[False, (np.diff(rec.t[rows]) <= 0)
                     | np.all(np.diff(rec.lla[rows, :2], axis=0) == 0, axis=1)]
        repeated += int(same.sum())
        rows = rows[~same]
        for piece in np.split(rows, np.flatnonzero(np.diff(rec.t[rows]) > max_gap) + 1):
            if len(piece) >= 2:
                out.append(piece)
            else:
                single += len(piece)
    return Segments(out, repeated, single)


def reconcile(t: np.ndarray, pos: np.ndarray, vel: np.ndarray, sigma_p: float = SIGMA_POSITION,
              sigma_v: float = SIGMA_VELOCITY) -> np.ndarray:
    """Positions (n, 3) consistent with the recorded velocities: the least-squares ``s`` of
    ``sum |s_k - p_k|^2 / sigma_p^2 + sum |s_k+1 - s_k - (v_k + v_k+1) dt_k / 2|^2 / (sigma_v dt_k)^2``,
    a tridiagonal system (one solve for the three axes)."""
    dt = np.diff(t)
    w = 1.0 / (sigma_v * dt) ** 2
    step = 0.5 * (vel[1:] + vel[:-1]) * dt[:, None]
    diag = np.full(len(t), 1.0 / sigma_p**2)
    diag[:-1] += w
    diag[1:] += w
    rhs = pos / sigma_p**2
    rhs[:-1] -= w[:, None] * step
    rhs[1:] += w[:, None] * step
    return solveh_banded(np.vstack([np.r_[0.0, -w], diag]), rhs)


def common_velocity(frame: Frame, t: np.ndarray, lla: np.ndarray, local: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """A track's recorded velocities ``local`` (n, 3) [m/s, the axes at each sample ``lla``] in the common
    axes, a component not recorded (NaN: a vertical rate, a cell) the derivative's of the common-frame
    positions ``pos`` (n, 3) at times ``t``, filled in the local axes (the turn mixes the three)."""
    slope = local_from_common_vectors(frame, lla[:, 0], lla[:, 1], np.gradient(pos, t, axis=0))
    return common_from_local_vectors(frame, lla[:, 0], lla[:, 1], np.where(np.isfinite(local), local, slope))


def on_surface(frame: Frame, pos: np.ndarray, vel: np.ndarray, dt: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities (n, 3) of common-frame ``pos``, ``vel`` (n, 3) in a 2-D world on the Earth: east,
    north of the point of the ellipsoid below each position (its latitude and longitude at h = 0: what a 2-D
    position sensor measures, :func:`fedtrack.geodetic.surface_xy`) and its height above the ellipsoid; the
    velocities by central differences along ``vel`` over +-``dt`` s (within 1e-6 m/s of a step of 0.01 s, aircraft up
    to 400 km from the origin)."""
    points = np.concatenate([pos, pos - vel * dt, pos + vel * dt])
    out = np.column_stack([surface_xy(frame, points), geodetic_from_enu(frame, points)[:, 2]])
    here, before, after = np.split(out, 3)
    return here, (after - before) / (2.0 * dt)


def truth_geodetic(frame: Frame, truth: Truth, states: np.ndarray) -> np.ndarray:
    """``[lat, lon, h]`` (n, 3) of the truth's states (n, 6): a 3-D world's positions, a 2-D world's points of the
    ellipsoid with the height kept beside them."""
    if not truth.surface:
        return geodetic_from_enu(frame, states[:, [0, 2, 4]]).reshape(-1, 3)
    lla = geodetic_from_enu(frame, surface_enu(frame, states[:, [0, 2]])).reshape(-1, 3)
    lla[:, 2] = states[:, 4]
    return lla


def velocity_at_odds(frame: Frame, t: np.ndarray, lla: np.ndarray, local: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """Which samples' recorded horizontal velocities ``local`` (n, 3) [m/s, the axes at each sample ``lla``] point
    where the recorded positions ``pos`` (n, 3, common frame) at times ``t`` rule out (n,): the recorded ground
    track is off the direction of the chord between the sample's neighbours (at a track's ends, the sample and its
    one neighbour), ``span`` s apart, by more than the heading change of a turn at ``MANEUVER_ACCELERATION`` over
    half the span plus the chord's own direction noise at its 99.9 % radius, ``asin(CHI2_2_999 sqrt(2)
    SIGMA_POSITION / span / |chord|)`` (a chord shorter than that radius points nowhere). Only the direction: a
    stale position (OpenSky's) makes a chord's speed wrong. E.g. a track stored as an 8-bit integer (the traffic
    package's calibration samples: -128 to 127, 104 deg off for a true track of 128 deg or more)."""
    k = np.arange(len(t))
    lo, hi = np.maximum(k - 1, 0), np.minimum(k + 1, len(t) - 1)
    span = t[hi] - t[lo]
    chord = local_from_common_vectors(frame, lla[:, 0], lla[:, 1], (pos[hi] - pos[lo]) / span[:, None])[:, :2]
    v = local[:, :2]
    speed, moved = np.linalg.norm(v, axis=1), np.linalg.norm(chord, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = CHI2_2_999 * math.sqrt(2.0) * SIGMA_POSITION / span / moved
        noise = np.where(ratio < 1.0, np.arcsin(np.minimum(ratio, 1.0)), np.pi)
        angle = np.arccos(np.clip(np.sum(v * chord, axis=1) / (speed * moved), -1.0, 1.0))
        return angle > MANEUVER_ACCELERATION / speed * span / 2.0 + noise  # NaN (not recorded): False


def memory_room() -> float:
    """Bytes a window's truth and scans may take: a quarter of the machine's physical memory (1 GiB where it is not
    known)."""
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") / 4
    except (AttributeError, ValueError, OSError):
        return 2.0**30


def _steps_before(t: float, steps: int, after: bool = False) -> int:
    """How many of the grid's times ``k DT`` (``k < steps``) are before ``t`` (``after``: at or before it)."""
    k = min(max(math.floor(t / DT) - 1, 0), steps)  # then exact: k DT as the grid computes it
    while k < steps and (k * DT <= t if after else k * DT < t):
        k += 1
    return k


def build_truth(rec: Recording, frame: Frame, start: float, duration: float | None, box: float,
                max_gap: float, scan_bytes: float = 0.0, surface: bool = False) -> Truth:
    """Truth on the ``DT`` grid from the first sample + ``start`` for ``duration`` s (None: to the last
    sample); a target is alive between its track's first and last samples while inside the square of
    side ``box`` [m] about the origin. A window whose grid, with ``scan_bytes`` a second of it for the
    sensors' scans, would take more than :func:`memory_room` is refused before it is made. ``surface``: a 2-D
    world, each track's samples :func:`on_surface` before the Hermite pieces."""
    t0 = float(rec.t.min()) + start
    end = float(rec.t.max()) if duration is None else t0 + duration
    if not end > t0:
        span = float(rec.t.max() - rec.t.min())
        raise InputError(f"--start {start:g}: no data after it (the recording spans {span:g} s from its first "
                         f"sample; --start must be less)")
    steps = int(round((end - t0) / DT)) + 1
    # times from t0: at 1.7e9 s a float's step is 2.4e-7 s, 5e-5 m at 200 m/s, and t0 + k DT would be
    # rounded to it; the recorded times less t0 are exact (Sterbenz) and the grid k DT is the same for
    # any shift of the whole recording
    rel = rec.t - t0
    found = segments(rec, max_gap)
    kept: list[tuple[slice, np.ndarray, np.ndarray, str]] = []  # each track inside the box: its steps, states, inside
    at_odds = 0
    for rows in (p for p in found.pieces if rel[p[-1]] >= 0 and rec.t[p[0]] <= end):
        live = slice(_steps_before(rel[rows[0]], steps), _steps_before(rel[rows[-1]], steps, after=True))
        grid = np.arange(live.start, live.stop) * DT  # the window's grid k DT, each track's steps only
        pos = enu_from_geodetic(frame, *rec.lla[rows].T)
        recorded = rec.velocity[rows].copy()
        odd = velocity_at_odds(frame, rel[rows], rec.lla[rows], recorded, pos)
        recorded[odd, :2] = np.nan  # the positions' derivative instead
        if np.isfinite(recorded).any():
            pos = reconcile(rel[rows], pos, common_velocity(frame, rel[rows], rec.lla[rows], recorded, pos))
        vel = common_velocity(frame, rel[rows], rec.lla[rows], recorded, pos)
        if surface:
            pos, vel = on_surface(frame, pos, vel)
        spline = CubicHermiteSpline(rel[rows], pos, vel)
        p, v = spline(grid), spline(grid, 1)
        inside = np.all(np.abs(p[:, :2]) <= box / 2, axis=1)
        if inside.any():  # a track never inside the box takes no room in the grid
            at_odds += int(odd.sum())
            kept.append((live, np.stack([p[:, 0], v[:, 0], p[:, 1], v[:, 1], p[:, 2], v[:, 2]], axis=-1), inside,
                         str(rec.icao24[rows[0]])))
    need, room = steps * len(kept) * TRUTH_CELL_BYTES + (steps - 1) * DT * scan_bytes, memory_room()
    if need > room:
        raise InputError(f"the window is too long: {(steps - 1) * DT:g} s of {len(kept)} aircraft tracks inside the "
                         f"box and the sensors' scans need {need / 2**30:.3g} GiB of memory, more than a quarter of "
                         f"this machine's ({room / 2**30:.3g} GiB); the recording's airborne samples span "
                         f"{float(rec.t.max() - rec.t.min()):g} s: give a shorter --duration (and --start) or a "
                         "smaller --box")
    x = np.zeros((steps, len(kept), 6))
    alive = np.zeros((steps, len(kept)), bool)
    for j, (live, state, inside, _) in enumerate(kept):
        x[live, j] = state
        alive[live, j] = inside
    icao24 = [icao for *_, icao in kept]
    dropped = {**rec.dropped, "repeating a time or position": found.repeated, "in a track of one sample": found.single,
               "horizontal velocities at odds with the positions (their derivative taken)": at_odds,
               "aircraft with no track inside the box and window": len(set(rec.icao24.tolist())) - len(set(icao24))}
    return Truth(t0, x, alive, icao24, dropped, surface)


def parse_kinds(spec: str) -> list[SensorSpec]:
    """The sensors of ``KIND:PERIOD[/SIGMA...][@LAT/LON/H],...`` (``pos``, ``radar``, ``adsb``), noises
    and sites left out."""
    return parse_spec(",".join(item.strip().partition("@")[0].partition("/")[0] for item in spec.split(",")),
                      ("pos", "radar", "adsb"))


def parse_noise(kind: str, sigmas: str, item: str) -> np.ndarray | None:
    """``R`` of a sensor's ``/SIGMA...`` (None when not given): ``pos`` ``/SIGMA`` m per axis; ``radar``
    ``/SIGMA_R/SIGMA_AZ[/SIGMA_EL]`` in m, degrees, degrees (the elevation's default ``RADAR_SD``)."""
    if not sigmas:
        return None
    sizes = {"pos": (1,), "radar": (2, 3)}.get(kind, ())
    try:
        values = [float(v) for v in sigmas.split("/")]
    except ValueError:
        values = []
    if not sizes:
        raise InputError(f"--sensors: {item!r}: an ADS-B receiver takes no noise (its accuracy is --nacp's)")
    if len(values) not in sizes or not all(math.isfinite(v) and v > 0 for v in values):
        form = "pos:P/SIGMA (m)" if kind == "pos" else "radar:P/SIGMA_R/SIGMA_AZ[/SIGMA_EL] (m, deg, deg)"
        raise InputError(f"--sensors: {item!r}: the noise is {form}, each > 0")
    if kind == "pos":
        return np.eye(2) * values[0] ** 2
    sd = [values[0], *np.radians(values[1:])] + list(RADAR_SD[len(values):])
    return np.diag(np.square(sd))


def parse_sensors(spec: str, frame: Frame, box: float, rng: np.random.Generator,
                  highest: float = math.inf) -> list[tuple[SensorSpec, RadarSite | None, np.ndarray | None]]:
    """``radar:4/70/0.08@49.1/2.1/90,pos:1/100,adsb:1`` -> sensors ``r1``, ``s2``, ``a3`` with their
    sites (a radar without one stands on the box's edge) and noises (:func:`parse_noise`). A site from
    which no aircraft up to ``highest`` [m] inside the box is above the radio horizon is refused: a site
    in radians, or with its latitude and longitude swapped, stands thousands of km away and its radar
    would give clutter only."""
    items = [item.strip().partition("@") for item in spec.split(",")]
    out: list[tuple[SensorSpec, RadarSite | None, np.ndarray | None]] = []
    for s, (base, at, where) in zip(parse_kinds(spec), items):
        noise = parse_noise(s.kind, base.partition("/")[2], base)
        if s.kind != "radar":
            if at:
                raise InputError(f"--sensors: {base}@{where}: only a radar takes a site")
            out.append((s, None, noise))
            continue
        if not at:  # on the box's edge, at the origin's height (the common frame's plane rises d^2 / 2R above the
            # ground: 34 km at 660 km, the edge of a 1,200 km box)
            angle = rng.uniform(-np.pi, np.pi)
            lat, lon, _ = geodetic_from_enu(frame, 0.55 * box * np.array([np.cos(angle), np.sin(angle), 0.0])).tolist()
            out.append((s, site_from_geodetic(frame, lat, lon, frame.h), noise))
            continue
        try:
            lat, lon, h = (float(v) for v in where.split("/"))
        except ValueError:
            lat = lon = h = math.nan
        problem = geodetic_error(lat, lon, h)
        if problem:
            raise InputError(f"--sensors: {base}@{where}: the site is not LAT/LON/H ({problem})")
        site = site_from_geodetic(frame, lat, lon, h)
        # the box's farthest point is box / sqrt(2) from the origin; the ground distance is taken on the sphere
        # of the smallest radius of curvature, which makes it short by up to 1 % and the refusal a sure one
        distance = WGS84_A * (1.0 - WGS84_E2) * ground_angle(lat, lon, frame.lat, frame.lon) - box / math.sqrt(2.0)
        if distance > radio_reach(site, highest):
            raise InputError(f"--sensors: {base}@{where}: the site is {distance / 1e3:.0f} km from the box, beyond "
                             f"the radio horizon ({radio_reach(site, highest) / 1e3:.0f} km) of every aircraft in it "
                             f"(up to {highest:.0f} m): is it LAT/LON/H in degrees, degrees, metres?")
        out.append((s, site, noise))
    return out


def adsb_view(truth: Truth, period: float, report_period: np.ndarray,
              rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """What an ADS-B receiver publishing every ``period`` s holds of each target on the ``DT`` grid:
    the target's last report (one every ``report_period`` s, its own rate, at a random phase) moved to
    that time with the report's velocity, and whether a report arrived within the last ``period``."""
    steps, n = truth.alive.shape
    k = np.arange(steps)[:, None]
    every = np.maximum(np.round(report_period / DT).astype(int), 1)[None, :]
    phase = (rng.uniform(0, 1, n) * every[0]).astype(int)[None, :]
    last = k - (k - phase) % every  # the step of each target's last report
    fresh = (last >= 0) & (k - last < max(1, int(round(period / DT))))
    src = np.clip(last, 0, steps - 1)
    cols = np.arange(n)[None, :]
    rep = truth.x[src, cols]
    lag = (k - src) * DT
    moved = rep.copy()
    moved[..., [0, 2, 4]] += rep[..., [1, 3, 5]] * lag[..., None]
    return moved, fresh & truth.alive[src, cols] & truth.alive


def derived_tracker(truth: Truth, specs: list[SensorSpec]) -> dict[str, float | str]:
    """The tracker keys derived from the recording, the sensors and civil air-traffic kinematics
    (docs/geodetic.md): two motion modes, straight and maneuvering, the maneuvering one's ``q`` letting
    the velocity change by ``MANEUVER_ACCELERATION`` times the longest sensor period over that period."""
    v = truth.x[..., [1, 3]]
    longest = max(s.period for s in specs)
    speed = np.linalg.norm(v, axis=-1)[truth.alive]
    alt = truth.x[..., 4][truth.alive]
    return {"process_noise": "imm", "q": round(MANEUVER_ACCELERATION**2 * longest, 3), "maneuver_s": MANEUVER_S,
            "straight_s": STRAIGHT_S,
            "init_velocity_std": round(float(speed.max()) / 2 if speed.size else 30.0, 1),
            "init_z_std": round(max(float(np.abs(alt).max()) / 2 if alt.size else 1000.0, 1000.0), 1),
            "max_lag": round(2 * longest + 1.0, 3),
            "central_timeout": round(max(5.0, 2 * longest + 1.0), 3)}


def simulate(rec: Recording, frame: Frame, spec: str, seed: int, out: Path, start: float = 0.0,
             duration: float | None = None, box: float = 100e3, max_gap: float = 30.0, pd: float = 0.9,
             clutter: float = 10.0, late: float = 0.2, nacp: int = 9) -> dict[str, Any]:
    """Write ``measurements.jsonl``, ``truth.jsonl`` and ``config.toml`` to ``out``, each whole or not
    at all (a library caller's folder is created; the command checks it first: :func:`main`)."""
    rng = np.random.default_rng(seed)
    scan_bytes = sum((SCAN_BYTES + DETECTION_BYTES * (clutter if s.kind != "adsb" else 0.0)) / s.period
                     for s in parse_kinds(spec))  # a second's scans, the aircraft's detections left out
    three_d = any(s.kind == "radar" for s in parse_kinds(spec))
    truth = build_truth(rec, frame, start, duration, box, max_gap, scan_bytes, surface=not three_d)
    if not truth.icao24:
        t0 = float(rec.t.min())
        window = f"{start:g} s to {'the end' if duration is None else f'{start + duration:g} s'} after the first sample"
        raise InputError(f"no airborne aircraft inside the box during the window (box {box / 1e3:g} km about "
                         f"{frame.lat:g}, {frame.lon:g}; window {window}); the recording's airborne samples span "
                         f"{float(rec.t.max()) - t0:g} s, latitudes {rec.lla[:, 0].min():g} to "
                         f"{rec.lla[:, 0].max():g}, longitudes {rec.lla[:, 1].min():g} to {rec.lla[:, 1].max():g}: "
                         "move --origin, widen --box or change --start / --duration")
    sensors = parse_sensors(spec, frame, box, rng, float(rec.lla[:, 2].max()))
    specs = [s for s, _, _ in sensors]
    steps = truth.alive.shape[0]
    sc = Scenario(targets=len(truth.icao24), duration=(steps - 1) * DT, region=box / 2, pd=pd, clutter=clutter,
                  late=late)
    report_period = rng.uniform(*SQUITTER_S, len(truth.icao24))  # each aircraft's own rate
    sd = NACP_EPU[nacp] / CHI2_2_95
    lines = []
    for s, site, noise in sensors:
        if s.kind == "adsb":
            moved, fresh = adsb_view(truth, s.period, report_period, rng)
            lines += sensor_lines(dataclasses.replace(s, kind="pos"), dataclasses.replace(sc, clutter=0.0), moved,
                                  fresh, True, rng, noise=np.diag([sd**2, sd**2]))
        else:
            lines += sensor_lines(s, sc, truth.x, truth.alive, True, rng, site=site, noise=noise)
    lines.sort(key=lambda item: item[0])
    out.mkdir(parents=True, exist_ok=True)
    with output_file(out / "measurements.jsonl") as fh:
        for _, line in lines:
            fh.write(json.dumps(line) + "\n")
    dims = [0, 1, 2, 3, 4, 5] if three_d else [0, 1, 2, 3]
    with output_file(out / "truth.jsonl") as fh:
        for second in range(int(sc.duration) + 1):
            step = int(round(second / DT))
            live = np.flatnonzero(truth.alive[step])
            lla = truth_geodetic(frame, truth, truth.x[step][live])
            targets = [{"id": int(i), "x": truth.x[step, i, dims].tolist(), "icao24": truth.icao24[i],
                        "lat": round(float(g[0]), 8), "lon": float(wrap_lon(round(float(g[1]), 8))),  # 180 -> -180
                        "alt": round(float(g[2]), 3)}
                       for i, g in zip(live, lla)]
            fh.write(json.dumps({"t": float(second), "targets": targets}) + "\n")
    derived = derived_tracker(truth, specs)
    mtt: dict[str, Any] = {**derived, "pd": pd, "clutter_density": position_clutter_density(sc), "period": 1.0,
                           "sensors": [s.id for s in specs]}
    # every sensor its own density: a radar's per m rad^2, a position sensor's per m^2; an ADS-B receiver's
    # false reports are none, written as one per (1000 km)^2 (the tracker's log takes no zero)
    mtt["sensor"] = {s.id: {"clutter_density": 1e-12 if s.kind == "adsb" else clutter_density(s, sc)} for s in specs}
    frame_table = {"origin": list(frame), "sites": {s.id: site.geodetic.tolist() for s, site, _ in sensors if site}}
    with output_file(out / "config.toml") as fh:
        fh.write(to_toml({"mtt": mtt, "frame": frame_table}))
    return {"scans": len(lines), "targets": len(truth.icao24), "aircraft": len(set(truth.icao24)),
            "rows": len(rec.t) + sum(rec.dropped.values()), "dropped": truth.dropped,
            "start": truth.t0, "duration": sc.duration,
            "most_alive": int(truth.alive.sum(axis=1).max()), "derived": derived,
            "sensors": [f"{s.id} ({s.kind}, {s.period:g} s)" for s in specs]}


def read_line(source: Path, info: dict[str, Any]) -> str:
    """What :func:`simulate` read of ``source`` and left out, by reason (nothing is left out silently)."""
    left_out = ", ".join(f"{n} {why}" for why, n in info["dropped"].items() if n) or "none"
    return f"read {source}: {info['rows']} rows; left out: {left_out}"


def _origin(text: str) -> Frame:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    problem = geodetic_error(*values, *[0.0] * (3 - len(values))) if len(values) in (2, 3) else "two or three numbers"
    if problem:
        raise InputError(f"--origin: {text!r} is not LAT,LON[,H] (degrees, degrees, metres; {problem})")
    return Frame(*values)


def _negative_values_joined(argv: list[str]) -> list[str]:
    """``--origin -33.9,151.2`` as ``--origin=-33.9,151.2``: argparse reads a value that starts with ``-`` and is
    not a plain number as the next option ("expected one argument"), so a southern or western origin needed the
    ``=`` form."""
    out: list[str] = []
    for arg in argv:
        if out and out[-1] == "--origin" and arg[:1] == "-" and (arg[1:2].isdigit() or arg[1:2] == "."):
            out[-1] = f"--origin={arg}"
        else:
            out.append(arg)
    return out


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="fedtrack simulate traffic", epilog=HELP_COLUMNS,
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     description="recorded air traffic as truth; position sensors, radars and "
                                                 "ADS-B on the Earth simulated on it, for replay and evaluate")
    parser.add_argument("--source", required=True, type=Path, help="recorded state vectors (.csv, .json, .jsonl, "
                        ".parquet; .csv, .json and .jsonl may be gzipped; .json: pandas' to_json, as the traffic "
                        "package's samples)")
    parser.add_argument("--origin", required=True, help="LAT,LON[,H]: the common frame's origin (deg, deg, m; "
                        "south and west negative, e.g. -33.9,151.2)")
    parser.add_argument("--sensors", default="radar:4,radar:5,pos:2",
                        help="comma-separated KIND:PERIOD[@LAT/LON/H] (below; default radar:4,radar:5,pos:2)")
    parser.add_argument("--seed", type=seed_number, default=1, help="seed of the sensors' noise, detections, clutter, "
                        "delays and ADS-B report times (default: %(default)s)")
    parser.add_argument("--out", required=True, type=Path, metavar="DIR",
                        help="folder to write into (created if missing; its own folder must exist)")
    parser.add_argument("--start", type=float, default=0.0, help="seconds after the first sample (default 0)")
    parser.add_argument("--duration", type=float, help="seconds (default: to the last sample)")
    parser.add_argument("--box", type=float, default=100.0,
                        help="km: the side of the square about the origin whose aircraft are truth (default 100)")
    parser.add_argument("--max-gap", type=float, default=30.0,
                        help="seconds: a longer gap between an aircraft's samples ends its track (default 30)")
    parser.add_argument("--units", choices=sorted(UNITS), default="si", help="input units (below; default si)")
    parser.add_argument("--pd", type=float, default=0.9,
                        help="probability that a sensor detects an aircraft in a scan (default: %(default)s)")
    parser.add_argument("--clutter", type=float, default=10.0,
                        help=f"mean number of false detections per scan, not ADS-B (Poisson; at most "
                             f"{MAX_CLUTTER:.0f}; default: %(default)s)")
    parser.add_argument("--late", type=float, default=0.2,
                        help="fraction of scans delivered late, up to two of their sensor's periods "
                             "(default: %(default)s)")
    parser.add_argument("--nacp", type=int, choices=sorted(NACP_EPU), default=9,
                        help="ADS-B navigation accuracy category: sigma per axis = EPU / 2.448 (9: 30 m EPU, "
                             "12.3 m; default 9)")
    args = parser.parse_args(_negative_values_joined(argv))
    check_options(args, (("box", 0 < args.box < math.inf, "finite and > 0"), ("max-gap", args.max_gap > 0, "> 0"),
                         ("start", 0 <= args.start < math.inf, "finite and >= 0")))
    check_output_folder(args.out)  # created once the data is read and the sensors parsed
    frame = _origin(args.origin)
    rec = read_recording(args.source, args.units)
    info = simulate(rec, frame, args.sensors, args.seed, args.out, args.start, args.duration, args.box * 1e3,
                    args.max_gap, args.pd, args.clutter, args.late, args.nacp)
    print(read_line(args.source, info))
    print(f"wrote {args.out}/measurements.jsonl ({info['scans']} scans), truth.jsonl ({info['targets']} tracks of "
          f"{info['aircraft']} aircraft, at most {info['most_alive']} at once, {info['duration']:g} s from "
          f"{datetime.fromtimestamp(info['start'], timezone.utc):%Y-%m-%d %H:%M:%S} UTC), config.toml; "
          f"sensors: {', '.join(info['sensors'])}")
    return 0
