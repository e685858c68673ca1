"""The sensors of ``fedtrack simulate traffic`` on the Earth: their spec (``--sensors``: position
sensors, radars at WGS-84 sites, ADS-B receivers; :func:`parse_sensors`), each one's noise, an
ADS-B receiver's view of the aircraft (each reporting at its own rate, :func:`adsb_view`), and their
scans of the truth (:func:`sensor_scans`, through :func:`fedtrack.sensors.multitarget.sensor_lines`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from fedtrack.geodetic import (
    WGS84_A,
    WGS84_E2,
    Frame,
    RadarSite,
    geodetic_error,
    geodetic_from_enu,
    ground_angle,
    radio_reach,
    site_from_geodetic,
)
from fedtrack.jsonl import InputError
from fedtrack.sensors.multitarget import DT, Scenario, SensorSpec, parse_noise, parse_spec, sensor_lines
from fedtrack.sensors.traffic_truth import Truth

#: NACp -> EPU [m], the 95 % bound of the horizontal position error (DO-260B); sigma per axis = EPU / 2.448
NACP_EPU = {7: 185.2, 8: 92.6, 9: 30.0, 10: 10.0, 11: 3.0}
SQUITTER_S = (0.4, 0.6)  # s: airborne position squitters at random intervals of 0.4-0.6 s (DO-260B)
CHI2_2_95 = math.sqrt(-2.0 * math.log(0.05))  # the 95 % radius of a 2-D standard normal: 2.448


def parse_kinds(spec: str) -> list[SensorSpec]:
    """The sensors of ``KIND:PERIOD[/SIGMA...][@LAT/LON/H],...`` (``pos``, ``radar``, ``adsb``), noises
    and sites left out."""
    return parse_spec(",".join(item.strip().partition("@")[0].partition("/")[0] for item in spec.split(",")),
                      ("pos", "radar", "adsb"))


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


def sensor_scans(truth: Truth, sensors: list[tuple[SensorSpec, RadarSite | None, np.ndarray | None]], sc: Scenario,
                 nacp: int, rng: np.random.Generator) -> list[tuple[float, dict[str, Any]]]:
    """``(arrival time, line)`` of every scan of ``sensors`` (:func:`parse_sensors`) on ``truth``, in arrival
    order (:func:`~fedtrack.sensors.multitarget.sensor_lines`); an ADS-B receiver's of what it holds
    (:func:`adsb_view`, each aircraft at its own rate), as 2-D position plots without clutter, with the
    accuracy of NACp ``nacp``."""
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
    return lines
