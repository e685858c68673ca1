"""Tour49's pole case rebuilt (docs/multitarget.md, "A radar blind below its horizon"): two radars 131 km
apart across the North Pole and three aircraft flying straight for 10 min, aircraft 2 (300-470 m up, 245 km
from ``r1`` beyond ``r2``) below ``r1``'s radio horizon and seen by ``r2`` alone. Each radar's plots and
clutter (N a scan, uniform in its own range 20-300 km, azimuth and elevation 0-0.3 rad) are drawn in its own
frame and converted to the scan format by the recipe of docs/multitarget-formats.md; the config is
``simulate traffic``'s derivation with both sites in ``[frame.sites]``.

Per algorithm and associator: the pictures in which each aircraft has a confirmed track within 2 km
(horizontally), and mean GOSPA on x, y at c = 2 km and c = 100 m with its parts. Usage:
``python -m fedtrack.experiments.pole_radars [--clutter 3] [--duration 600] [--seed 1] [--out DIR]``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import tempfile
from pathlib import Path
from typing import NamedTuple

import numpy as np

from fedtrack.config import to_toml
from fedtrack.fusion_center.mtt.evaluation import evaluate
from fedtrack.fusion_center.mtt.replay import replay_mtt
from fedtrack.geodetic import (
    Frame,
    RadarSite,
    above_radio_horizon,
    aer_from_enu,
    enu_from_aer,
    enu_from_geodetic,
    geodetic_from_enu,
    site_from_geodetic,
    surface_enu,
)
from fedtrack.local_filters.radar.measurement import polar_from_cartesian
from fedtrack.sensors.traffic_truth import MANEUVER_ACCELERATION, MANEUVER_S, STRAIGHT_S

ORIGIN = (89.3, 0.0, 0.0)
REACH = (20e3, 300e3)  # [m] the radars' clutter ranges (and reach)
ELEVATION = 0.3  # [rad] their clutter's elevation span
PD = 0.9
HELD_M = 2000.0  # a confirmed track this near an aircraft (horizontally) holds it


class Radar(NamedTuple):
    id: str
    lat_lon_h: tuple[float, float, float]
    period: float  # [s]
    phase: float  # [s] its first scan
    sd: tuple[float, float, float]  # range [m], azimuth, elevation [deg]
    late: float  # share of its scans delivered up to 1.5 periods late


RADARS = (Radar("r1", (89.0, 10.0, 60.0), 5.0, 0.7, (25.0, 0.1, 0.1), 0.0),
          Radar("r2", (89.83, -170.0, 900.0), 12.0, 3.1, (40.0, 0.12, 0.15), 0.2))


def aircraft(site: dict[str, RadarSite]) -> list[tuple[np.ndarray, np.ndarray, float, float]]:
    """Each aircraft's start (x, y) and velocity in the common frame and its heights at start and end [m]."""
    p1, p2 = site["r1"].position[:2], site["r2"].position[:2]
    u = (p2 - p1) / np.linalg.norm(p2 - p1)
    n, mid = np.array([-u[1], u[0]]), (p1 + p2) / 2
    return [(mid - 60e3 * n - 20e3 * u, 220.0 * n, 9000.0, 9000.0),
            (p1 + 245e3 * u - 60e3 * n, 200.0 * n, 300.0, 470.0),
            (mid + 50e3 * n + 40e3 * u, -180.0 * u - 80.0 * n, 6000.0, 5000.0)]


def positions(frame: Frame, plan: tuple[np.ndarray, np.ndarray, float, float], t: np.ndarray,
              duration: float) -> np.ndarray:
    """Common-frame positions (N, 3) at times ``t``: over the ellipsoid point below (x, y), at the height."""
    start, velocity, h0, h1 = plan
    lat, lon, _ = geodetic_from_enu(frame, surface_enu(frame, start + np.outer(t, velocity))).T
    return enu_from_geodetic(frame, lat, lon, h0 + (h1 - h0) * t / duration)


def write_scenario(out: Path, clutter: float, duration: float, seed: int) -> None:
    """``measurements.jsonl`` (arrival order), ``truth.jsonl`` (1 s) and ``config.toml`` into ``out``."""
    rng = np.random.default_rng(seed)
    frame = Frame(*ORIGIN)
    site = {r.id: site_from_geodetic(frame, *r.lat_lon_h) for r in RADARS}
    plans = aircraft(site)
    lines = []
    for radar in RADARS:
        R = np.diag([radar.sd[0] ** 2, math.radians(radar.sd[1]) ** 2, math.radians(radar.sd[2]) ** 2])
        L, own_site = np.sqrt(R), site[radar.id]
        for k, t in enumerate(np.arange(radar.phase, duration, radar.period)):
            plots = []
            for plan in plans:
                at = positions(frame, plan, np.array([t]), duration)
                seen = above_radio_horizon(own_site, at)[0] and np.linalg.norm(at - own_site.position) < REACH[1]
                if seen and rng.uniform() < PD:
                    aer = aer_from_enu(own_site, at)[0]
                    plots.append(np.array([aer[2], aer[0], aer[1]]) + L @ rng.standard_normal(3))
            m = rng.poisson(clutter)
            false = np.column_stack([rng.uniform(*REACH, m), rng.uniform(-np.pi, np.pi, m),
                                     rng.uniform(0, ELEVATION, m)])
            own = np.vstack([*plots, false])
            own = own[rng.permutation(len(own))]
            z = polar_from_cartesian(enu_from_aer(own_site, own[:, [1, 2, 0]]) - own_site.position)
            delay = 0.2 + (rng.uniform(0, 1.5 * radar.period) if k and rng.uniform() < radar.late else 0.0)
            lines.append((t + delay, {"t": round(float(t), 3), "sensor": radar.id, "R": R.tolist(),
                                      "sensor_position": own_site.position.tolist(),
                                      "detections": [{"z": d.tolist()} for d in z]}))
    lines.sort(key=lambda item: item[0])
    out.mkdir(parents=True, exist_ok=True)
    (out / "measurements.jsonl").write_text("".join(json.dumps(line) + "\n" for _, line in lines))
    seconds = np.arange(int(duration) + 1.0)
    tracks = [(positions(frame, plan, seconds, duration),
               positions(frame, plan, seconds + 0.5, duration) - positions(frame, plan, seconds - 0.5, duration))
              for plan in plans]
    (out / "truth.jsonl").write_text("".join(
        json.dumps({"t": float(s), "targets": [{"id": i + 1, "x": np.column_stack([p[k], v[k]]).ravel().tolist()}
                                               for i, (p, v) in enumerate(tracks)]}) + "\n"
        for k, s in enumerate(seconds)))
    longest = max(r.period for r in RADARS)
    density = clutter / ((REACH[1] - REACH[0]) * 2 * math.pi * ELEVATION)
    mtt = {"sensors": [r.id for r in RADARS], "pd": PD, "process_noise": "imm",
           "q": round(MANEUVER_ACCELERATION**2 * longest, 3), "maneuver_s": MANEUVER_S, "straight_s": STRAIGHT_S,
           "init_velocity_std": 110.0, "init_z_std": 4500.0, "max_lag": 2 * longest + 1.0,
           "central_timeout": 2 * longest + 1.0, "period": 1.0, "clutter_density": 1e-12,
           "sensor": {r.id: {"clutter_density": density} for r in RADARS}}
    frame_table = {"origin": list(ORIGIN), "sites": {r.id: list(r.lat_lon_h) for r in RADARS}}
    (out / "config.toml").write_text(to_toml({"mtt": mtt, "frame": frame_table}))


def held(tracks: Path, truth: Path) -> dict[int, int]:
    """Per aircraft, the pictures with a confirmed track within ``HELD_M`` of it (x, y)."""
    truths = {round(o["t"], 6): o["targets"] for o in map(json.loads, truth.read_text().splitlines())}
    count: dict[int, int] = {}
    for picture in map(json.loads, tracks.read_text().splitlines()):
        shown = np.array([[tr["x"][0], tr["x"][2]] for tr in picture["tracks"] if tr["status"] == "confirmed"])
        for g in truths.get(round(picture["t"], 6), []):
            near = len(shown) and bool((np.hypot(*(shown - [g["x"][0], g["x"][2]]).T) < HELD_M).any())
            count[g["id"]] = count.get(g["id"], 0) + near
    return count


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clutter", type=float, default=3.0, help="clutter plots a scan per radar (default: 3)")
    parser.add_argument("--duration", type=float, default=600.0, help="[s] (default: 600)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", help="folder for the scenario and pictures (default: a temporary one)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out or tmp)
        write_scenario(out, args.clutter, args.duration, args.seed)
        base = (out / "config.toml").read_text()
        for algorithm in ("mtt-federated", "mtt-decentralized", "mtt-centralized"):
            for associator in ("gnn", "jipda", "mht"):
                config, pictures = out / f"{associator}.toml", out / f"{algorithm}-{associator}.jsonl"
                config.write_text(base.replace("[mtt]\n", f'[mtt]\nassociator = "{associator}"\n', 1))
                with contextlib.redirect_stderr(io.StringIO()):  # replay's counters
                    replay_mtt(algorithm, out / "measurements.jsonl", config, pictures)
                gospa = [evaluate(pictures, out / "truth.jsonl", c=c, horizontal=True)["mean"] for c in (2000.0, 100.0)]
                parts = " / ".join(f"{gospa[0][k]:,.0f}" for k in ("localisation", "missed", "false"))
                print(f"{algorithm} {associator}: held {held(pictures, out / 'truth.jsonl')}; mean GOSPA c = 2 km "
                      f"{gospa[0]['gospa']:.2f} ({parts}), c = 100 m {gospa[1]['gospa']:.2f}", flush=True)


if __name__ == "__main__":
    main()
