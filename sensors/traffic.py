"""``fedtrack simulate traffic``: recorded air traffic as truth, sensors on the Earth simulated on it.

Input (:mod:`fedtrack.sensors.state_vectors`): recorded state vectors (OpenSky's, or the ``traffic``
library's export), one row per aircraft and time; CSV, JSON Lines (either optionally gzipped) or
Parquet (needs pyarrow: the ``real`` extra). Truth (:mod:`fedtrack.sensors.traffic_truth`): each
airborne aircraft's samples in the common ENU frame about ``--origin`` (:mod:`fedtrack.geodetic`),
interpolated between samples by cubic Hermite pieces through the recorded positions and velocities;
a gap longer than ``--max-gap`` ends a track and the next sample starts a new one (a new truth id).
Sensors (:mod:`fedtrack.sensors.traffic_sensors`, through :mod:`fedtrack.sensors.multitarget`'s
``sensor_lines``): 2-D position plots, radars in their own frames at sites on the Earth, and ADS-B
receivers; each with its period, phase, P_D, clutter and delays. This module is the command: it puts
them together and writes the files (:func:`simulate`), the tracker keys derived for them in
``config.toml`` (:func:`derived_tracker`).
"""

from __future__ import annotations

import argparse
import math
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from fedtrack.config import seed_number
from fedtrack.geodetic import (
    Frame,
    enu_from_geodetic,
    gaussian_radius,
    geodetic_error,
    ground_angle,
    median_lon,
    wrap_lon,
)
from fedtrack.jsonl import InputError, check_output_folder
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.sensors.multitarget import (
    DETECTION_BYTES,
    DT,
    MAX_CLUTTER,
    SCAN_BYTES,
    Scenario,
    SensorSpec,
    check_options,
    clutter_density,
    longest_revisit,
    noise_floors,
    position_clutter_density,
    write_scenario,
)
from fedtrack.sensors.state_vectors import UNITS, Recording, read_recording
from fedtrack.sensors.traffic_sensors import NACP_EPU, parse_kinds, parse_sensors, sensor_scans
from fedtrack.sensors.traffic_truth import (
    MANEUVER_ACCELERATION,
    MANEUVER_S,
    STRAIGHT_S,
    Truth,
    build_truth,
    default_max_gap,
    segments,
    truth_geodetic,
)

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


def derived_tracker(truth: Truth, specs: list[SensorSpec], frame: Frame) -> dict[str, float | str]:
    """The tracker keys derived from the recording, the sensors and civil air-traffic kinematics
    (docs/geodetic.md): two motion modes, straight and maneuvering, the maneuvering one's ``q`` letting
    the velocity change by ``MANEUVER_ACCELERATION`` times the longest sensor period over that period
    (of the sensors that scan again within the window: a slower one scans once, never late;
    :func:`~fedtrack.sensors.multitarget.longest_revisit`); ``init_z_std`` half the largest height of an
    aircraft above or below the origin's, where a 2-D start is centred (:func:`~fedtrack.geodetic.level_z`)."""
    v = truth.x[..., [1, 3]]
    # at least one step of the grid: a window of one row (a --duration below DT, or a --start within DT of
    # the recording's end) gave q 0, which replay refuses in the config it wrote
    duration = max(truth.alive.shape[0] - 1, 1) * DT
    longest = longest_revisit(specs, duration)
    speed = np.linalg.norm(v, axis=-1)[truth.alive]
    # heights above the ellipsoid, not the common frame's z: that holds the Earth's curvature too (d^2 / 2R, 14.2 km
    # for the Paris extract about an origin 555 km south against 4.2 km about it; docs/geodetic.md)
    alt = truth_geodetic(frame, truth, truth.x[truth.alive])[:, 2] - frame.h
    return {"process_noise": "imm", "q": round(MANEUVER_ACCELERATION**2 * longest, 3), "maneuver_s": MANEUVER_S,
            "straight_s": STRAIGHT_S,
            # at least the tracker's own default, as init_z_std: a window of aircraft standing still (a parked one not
            # flagged on the ground) wrote 0.0, which replay refused in the config this wrote
            "init_velocity_std": round(max(float(speed.max()) / 2 if speed.size else 0.0, MttConfig.init_velocity_std),
                                       1),
            "init_z_std": round(max(float(np.abs(alt).max()) / 2 if alt.size else 0.0, MttConfig.init_z_std), 1),
            "max_lag": round(2 * longest + 1.0, 3),
            "central_timeout": round(max(5.0, 2 * longest + 1.0), 3)}


class Knobs(NamedTuple):
    """What the error for a window without truth tells to change: ``simulate traffic``'s options (:data:`OPTIONS`)
    or a launch's ``[multitarget]`` keys (before the tour62 session a launch was told the options)."""

    origin: str
    box: str
    window: str
    max_gap: str | None  # None: none to set (a launch takes the recording's default_max_gap)


OPTIONS = Knobs("--origin", "--box", "--start / --duration", "--max-gap")


def simulate(rec: Recording, frame: Frame, spec: str, seed: int, out: Path, start: float = 0.0,
             duration: float | None = None, box: float = 100e3, max_gap: float | None = None, pd: float = 0.9,
             clutter: float = 10.0, late: float = 0.2, nacp: int = 9, knobs: Knobs = OPTIONS) -> dict[str, Any]:
    """Write ``measurements.jsonl``, ``truth.jsonl`` and ``config.toml`` to ``out``, each whole or not
    at all (a library caller's folder is created; the command checks it first: :func:`main`). ``max_gap`` None:
    :func:`default_max_gap` of the recording; ``knobs``: what an error for a window without aircraft advises."""
    rng = np.random.default_rng(seed)
    max_gap = default_max_gap(rec) if max_gap is None else max_gap
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
                         f"{rec.lla[:, 0].max():g}, longitudes {rec.lla[:, 1].min():g} to {rec.lla[:, 1].max():g}"
                         f"{_centre(rec, frame, start, duration)}"
                         f"{_cause(rec, frame, start, duration, box, max_gap, knobs)}")
    # the site check's aircraft: the truth's highest (before 2026-11-28 the recording's, glitches included: an
    # altitude decoded 20 km high widened every radar's reach by 400 km; docs/geodetic.md)
    sensors = parse_sensors(spec, frame, box, rng, truth.highest)
    specs = [s for s, _, _ in sensors]
    steps = truth.alive.shape[0]
    sc = Scenario(targets=len(truth.icao24), duration=(steps - 1) * DT, region=box / 2, pd=pd, clutter=clutter,
                  late=late)
    lines = sensor_scans(truth, sensors, sc, nacp, rng)
    dims = [0, 1, 2, 3, 4, 5] if three_d else [0, 1, 2, 3]
    derived = derived_tracker(truth, specs, frame)
    mtt: dict[str, Any] = {**derived, "pd": pd, "clutter_density": position_clutter_density(sc), "period": 1.0,
                           "sensors": [s.id for s in specs]}
    # every sensor its own density: a radar's per m rad^2, a position sensor's per m^2; an ADS-B receiver's
    # false reports are none, written as one per (1000 km)^2 (the tracker's log takes no zero)
    floors = noise_floors(lines)  # the noise each sensor declares: no report claims less (noise_floor.py)
    mtt["sensor"] = {s.id: {"clutter_density": 1e-12 if s.kind == "adsb" else clutter_density(s, sc),
                            **({"noise_floor": floors[s.id]} if s.id in floors else {})} for s in specs}
    frame_table = {"origin": list(frame), "sites": {s.id: site.geodetic.tolist() for s, site, _ in sensors if site}}
    write_scenario(out, lines, (truth_row(frame, truth, second, dims) for second in range(int(sc.duration) + 1)),
                   {"frame": frame_table, "mtt": mtt})  # [mtt] last: keys appended land in it
    return {"scans": len(lines), "targets": len(truth.icao24), "aircraft": len(set(truth.icao24)),
            "rows": len(rec.t) + sum(rec.dropped.values()), "dropped": truth.dropped,
            "start": truth.t0, "duration": sc.duration,
            "most_alive": int(truth.alive.sum(axis=1).max()), "derived": derived,
            "sensors": [f"{s.id} ({s.kind}, {s.period:g} s)" for s in specs]}


def truth_row(frame: Frame, truth: Truth, second: int, dims: list[int]) -> dict[str, Any]:
    """``truth.jsonl``'s line of ``second``: every live aircraft's state, ``icao24`` and place on the Earth."""
    step = int(round(second / DT))
    live = np.flatnonzero(truth.alive[step])
    lla = truth_geodetic(frame, truth, truth.x[step][live])
    targets = [{"id": int(i), "x": truth.x[step, i, dims].tolist(), "icao24": truth.icao24[i],
                "lat": round(float(g[0]), 8), "lon": float(wrap_lon(round(float(g[1]), 8))),  # 180 -> -180
                "alt": round(float(g[2]), 3)}
               for i, g in zip(live, lla)]
    return {"t": float(second), "targets": targets}


def _centre(rec: Recording, frame: Frame, start: float, duration: float | None) -> str:
    """Where the error for a window without truth says the window's aircraft are: the origin ``--origin`` defaults
    to (:func:`window_origin`) and its distance from the one given."""
    centre = window_origin(rec, start, duration)
    far = ground_angle(frame.lat, frame.lon, centre.lat, centre.lon) * gaussian_radius(frame.lat) / 1e3
    return f"; the window's median position is {centre.lat:.4f}, {centre.lon:.4f}, {far:.0f} km from the origin"


def _cause(rec: Recording, frame: Frame, start: float, duration: float | None, box: float, max_gap: float,
           knobs: Knobs) -> str:
    """How the error for a window without truth ends: what it says of the recording's samples inside the box during
    the window, that each repeats its aircraft's previous position (a frozen position, as the traffic package's
    ``noisy/noisy_spoofing`` holds for hours: the box and window were right, and ``--max-gap`` would not help), or
    that ``--max-gap`` cut them into tracks of one sample (a gap shorter than the recording's sampling interval);
    nothing when there are none (the origin, box or window is the cause: ``--max-gap`` was advised there too before
    the tour61 session, when any sample of the recording was a track of one sample); then what to change, named as
    ``knobs``."""
    since = rec.t - rec.t.min()
    pos = enu_from_geodetic(frame, *rec.lla.T)
    here = ((since >= start) & (since <= start + (math.inf if duration is None else duration))
            & np.all(np.abs(pos[:, :2]) <= box / 2, axis=1))
    aircraft = rec.icao24[here].tolist()
    places = len(set(zip(aircraft, *rec.lla[here, :2].T.tolist())))
    if len(aircraft) > places == len(set(aircraft)):  # every aircraft inside holds one position, sample after sample
        return (f"; its {len(aircraft)} samples inside the box are {places} frozen position{'s' * (places != 1)}, "
                "each aircraft's samples repeating one (a spoofed or stuck report; a repeated position is left out "
                f"as stale): change {knobs.window} to a window where the aircraft move")
    lone = int(here[segments(rec, max_gap).single].sum())
    advice = f"move {knobs.origin}, widen {knobs.box} or change {knobs.window}"
    if not lone:
        return f": {advice}"
    gap = f"{knobs.max_gap} {max_gap:g} s" if knobs.max_gap else f"{max_gap:g} s"
    raise_gap = f"raise {knobs.max_gap} above the recording's sampling interval, " if knobs.max_gap else ""
    return (f"; {lone} samples inside the box left out as tracks of one sample (a gap of more than {gap} before and "
            f"after each): {raise_gap}{advice}")


def read_line(source: Path, info: dict[str, Any]) -> str:
    """What :func:`simulate` read of ``source`` and left out, by reason (nothing is left out silently)."""
    left_out = ", ".join(f"{n} {why}" for why, n in info["dropped"].items() if n) or "none"
    return f"read {source}: {info['rows']} rows; left out: {left_out}"


def window_origin(rec: Recording, start: float = 0.0, duration: float | None = None) -> Frame:
    """The median position of the recording's airborne samples within the window (``start`` to ``start + duration``
    s after its first sample; the whole recording when the window holds none), at h = 0: the origin where the
    window's aircraft are. The longitudes' median is about their circular mean (:func:`~fedtrack.geodetic.median_lon`:
    a scene across the antimeridian is centred on it). The whole recording's median can be far from them: the
    traffic package's multi-day and long-haul samples put it 85-1,900 km from the aircraft of the demo's window
    (``featured/elal747`` 1,730 km), and ``demo --scenario traffic --source`` was refused on 20 of them
    (docs/geodetic.md)."""
    since = rec.t - rec.t.min()
    inside = (since >= start) & (since <= start + (math.inf if duration is None else duration))
    lla = rec.lla[inside] if inside.any() else rec.lla
    return Frame(float(np.median(lla[:, 0])), median_lon(lla[:, 1]), 0.0)


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
    parser.add_argument("--origin", help="LAT,LON[,H]: the common frame's origin (deg, deg, m; south and west "
                        "negative, e.g. -33.9,151.2; default: the median position of the window's airborne samples, "
                        "h 0)")
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
    parser.add_argument("--max-gap", type=float,
                        help="seconds: a longer gap between an aircraft's samples ends its track (default: three "
                             "times the recording's median sampling interval, at least 30)")
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
    check_options(args, (("box", 0 < args.box < math.inf, "finite and > 0"),
                         ("max-gap", args.max_gap is None or args.max_gap > 0, "> 0"),
                         ("start", 0 <= args.start < math.inf, "finite and >= 0")))
    check_output_folder(args.out)  # created once the data is read and the sensors parsed
    frame = None if args.origin is None else _origin(args.origin)
    rec = read_recording(args.source, args.units)
    if frame is None:
        frame = window_origin(rec, args.start, args.duration)
        print(f"origin {frame.lat:.6f},{frame.lon:.6f}: the median position of the window's airborne samples")
    info = simulate(rec, frame, args.sensors, args.seed, args.out, args.start, args.duration, args.box * 1e3,
                    args.max_gap, args.pd, args.clutter, args.late, args.nacp)
    print(read_line(args.source, info))
    print(f"wrote {args.out}/measurements.jsonl ({info['scans']} scans), truth.jsonl ({info['targets']} tracks of "
          f"{info['aircraft']} aircraft, at most {info['most_alive']} at once, {info['duration']:g} s from "
          f"{datetime.fromtimestamp(info['start'], timezone.utc):%Y-%m-%d %H:%M:%S} UTC), config.toml; "
          f"sensors: {', '.join(info['sensors'])}")
    return 0
