"""The fast-target table of docs/multitarget.md ("Fast targets: two-point starts"): each row's
scenario written and replayed by ``gnn``, ``jipda`` and ``mht`` with ``mtt-centralized``,
``mtt-federated`` and ``mtt-decentralized``, with the configuration a user must write (the sensors'
clutter densities, nothing about the targets' speeds). Rows:

* ``pos``: 8 straight targets at 300-700 m/s, two 50 m position sensors at 1 Hz (the second half a
  period after the first), P_D 0.9, 10 false detections a scan over a 120 km square, late scans as
  ``simulate multitarget``'s (a fifth, by up to two periods), 120 s; ``pos-slow``: the same at 0.2 Hz;
* ``radar``: the same targets at 3-9 km altitude seen by two radars (50 m, 1 mrad) 100 km south and
  west of the centre (60-180 km away), at 1 Hz half a second apart, their clutter over 20-220 km,
  every azimuth and 0-0.3 rad;
* ``mixed``: ``simulate multitarget``'s trajectories for 10 targets (5-30 m/s) and one at 200 m/s,
  its three position sensors (1.0 / 0.7 / 1.3 s) at 10 m, ``clutter_density`` 1e-7, 120 s; also the
  fast one's share of the pictures with a confirmed track within 100 m.

Prints mean GOSPA (c = 100, p = 2) and the missed and false targets a picture. Usage:
``python -m fedtrack.experiments.fast_targets --row radar [--seed 1] [--out DIR]``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from fedtrack.config import to_toml
from fedtrack.experiments.tables import print_table
from fedtrack.fusion_center.mtt.evaluation.scoring import evaluate
from fedtrack.fusion_center.mtt.replay import replay_mtt
from fedtrack.local_filters.radar.measurement import polar_from_cartesian, wrap_angle
from fedtrack.sensors import multitarget as mt

ROWS = ("pos", "pos-slow", "radar", "mixed")
DURATION = 120.0
HALF_WIDTH = 60000.0  # m: the 2-D rows' clutter square
SITES = (np.array([-100000.0, 0.0, 0.0]), np.array([0.0, -100000.0, 0.0]))
RADAR_R = np.diag([2500.0, 1e-6, 1e-6])
RADAR_COVER = (20000.0, 220000.0, 0.3)  # m, m, rad: the radars' clutter in range and elevation
FAST_ID = 10  # the mixed row's fast target


def fast_truth(rng: np.random.Generator, targets: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Start positions (n, 3; altitude 3-9 km) and velocities (300-700 m/s, any heading, level)."""
    speed, head = rng.uniform(300, 700, targets), rng.uniform(-np.pi, np.pi, targets)
    v = np.c_[speed * np.cos(head), speed * np.sin(head), np.zeros(targets)]
    return np.c_[rng.uniform(-20000, 20000, (targets, 2)), rng.uniform(3000, 9000, targets)], v


def fast_scans(p0: np.ndarray, v: np.ndarray, radar: bool, period: float, rng: np.random.Generator
               ) -> list[tuple[float, dict[str, Any]]]:
    """(arrival, line) of both sensors' scans (the second half a period after the first)."""
    sc = mt.Scenario()
    lines = []
    for s in range(2):
        last = -np.inf
        for k, t in enumerate(np.arange(s * period / 2, DURATION + 1e-9, period)):
            p = p0 + v * t
            seen = rng.uniform(size=len(p)) < sc.pd
            n = rng.poisson(sc.clutter)
            if radar:
                z = polar_from_cartesian(p[seen] - SITES[s]) + rng.standard_normal((seen.sum(), 3)) * np.sqrt(
                    np.diag(RADAR_R))
                lo, hi, el = RADAR_COVER
                false = np.c_[rng.uniform(lo, hi, n), rng.uniform(-np.pi, np.pi, n), rng.uniform(0, el, n)]
            else:
                z = p[seen, :2] + 50.0 * rng.standard_normal((seen.sum(), 2))
                false = rng.uniform(-HALF_WIDTH, HALF_WIDTH, (n, 2))
            dets = np.concatenate([z, false])[rng.permutation(len(z) + n)]
            line: dict[str, Any] = {"t": round(float(t), 6), "sensor": f"{'r' if radar else 's'}{s + 1}"}
            if radar:
                dets[:, 1] = wrap_angle(dets[:, 1])
                line.update(R=RADAR_R.tolist(), sensor_position=SITES[s].tolist())
            else:
                line.update(R=(2500.0 * np.eye(2)).tolist())
            line["detections"] = [{"z": d.tolist()} for d in dets]
            delay = sc.base_delay + rng.exponential(mt.JITTER_S)
            if k and rng.uniform() < sc.late:
                delay += rng.uniform(0, 2 * period)
            last = max(last, t + delay)  # each sensor's link first-in-first-out
            lines.append((last, line))
    return lines


def write_row(row: str, seed: int, out: Path) -> None:
    """``measurements.jsonl``, ``truth.jsonl`` and ``config.toml`` of ``row`` into ``out``."""
    rng = np.random.default_rng(seed)
    mtt: dict[str, Any]
    if row == "mixed":
        sc = mt.Scenario(targets=10, duration=DURATION, clutter=10.0)
        x, alive = mt.simulate_truth(sc, False, rng)
        t = np.arange(x.shape[0]) * mt.DT
        fast = np.zeros((x.shape[0], 1, 6))
        fast[:, 0, 0], fast[:, 0, 1], fast[:, 0, 2] = -12000.0 + 200.0 * t, 200.0, rng.uniform(-3000, 3000)
        x, alive = np.concatenate([x, fast], axis=1), np.concatenate([alive, np.ones((len(t), 1), bool)], axis=1)
        specs = mt.parse_spec("pos:1.0,pos:0.7,pos:1.3")
        lines = [item for s in specs for item in mt.sensor_lines(s, sc, x, alive, False, rng, noise=100.0 * np.eye(2))]
        steps = [round(sec / mt.DT) for sec in range(int(DURATION) + 1)]
        truth = [[(int(i), x[k, i, :4]) for i in np.flatnonzero(alive[k])] for k in steps]
        mtt = {"q": mt.process_noise(specs), "clutter_density": 1e-7, "max_lag": mt.max_lag(sc, specs),
               "sensors": [s.id for s in specs]}
    else:
        radar, period = row == "radar", 5.0 if row == "pos-slow" else 1.0
        p0, v = fast_truth(rng)
        lines = fast_scans(p0, v, radar, period, rng)
        dims = slice(0, 6) if radar else slice(0, 4)
        truth = [[(i, np.c_[p0[i] + v[i] * sec, v[i]].ravel()[dims]) for i in range(len(p0))]
                 for sec in range(int(DURATION) + 1)]
        mtt = {"max_lag": max(3.0, 2 * period + 0.4), "sensors": ["r1", "r2"] if radar else ["s1", "s2"]}
        if radar:
            lo, hi, el = RADAR_COVER
            mtt["sensor"] = {s: {"clutter_density": mt.Scenario().clutter / ((hi - lo) * 2 * np.pi * el)}
                             for s in ("r1", "r2")}
        else:
            mtt["clutter_density"] = mt.Scenario().clutter / (2 * HALF_WIDTH) ** 2
    lines.sort(key=lambda item: item[0])
    (out / "measurements.jsonl").write_text("".join(json.dumps(line) + "\n" for _, line in lines))
    (out / "truth.jsonl").write_text("".join(
        json.dumps({"t": float(sec), "targets": [{"id": i, "x": s.tolist()} for i, s in targets]}) + "\n"
        for sec, targets in enumerate(truth)))
    (out / "config.toml").write_text(to_toml({"mtt": mtt}))


def fast_share(tracks: Path, truth: Path) -> float:
    """The share of the pictures at a truth time with a confirmed track within 100 m of ``FAST_ID``."""
    at = {round(line["t"], 6): line for line in map(json.loads, truth.read_text().splitlines())}
    hits = []
    for picture in map(json.loads, tracks.read_text().splitlines()):
        line = at.get(round(picture["t"], 6))
        if line is None:
            continue
        g = next(np.array(tg["x"])[[0, 2]] for tg in line["targets"] if tg["id"] == FAST_ID)
        hits.append(any(tr["status"] == "confirmed" and np.hypot(*(np.array(tr["pos"][:2]) - g)) < 100.0
                        for tr in picture["tracks"]))
    return float(np.mean(hits))


def main(argv: list[str] | None = None) -> int:
    """Write ``--row``'s scenario, replay it with each associator and centre, print the table."""
    parser = argparse.ArgumentParser(prog="python -m fedtrack.experiments.fast_targets", description=__doc__)
    parser.add_argument("--row", choices=ROWS, required=True)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path,
                        help="keep the scenario and the pictures here (default: a temporary folder)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        out.mkdir(exist_ok=True)
        write_row(args.row, args.seed, out)
        rows = []
        for assoc in ("gnn", "jipda", "mht"):
            config = out / f"config-{assoc}.toml"
            config.write_text((out / "config.toml").read_text().replace("[mtt]\n", f'[mtt]\nassociator = "{assoc}"\n',
                                                                        1))
            for algorithm in ("mtt-centralized", "mtt-federated", "mtt-decentralized"):
                tracks = out / f"tracks-{assoc}-{algorithm}.jsonl"
                replay_mtt(algorithm, out / "measurements.jsonl", config, tracks)
                mean = evaluate(tracks, out / "truth.jsonl")["mean"]
                half = 100.0**2 / 2  # a missed or false target's share of GOSPA^2 at c = 100, p = 2
                share = f"{100 * fast_share(tracks, out / 'truth.jsonl'):.0f} %" if args.row == "mixed" else "-"
                rows.append([assoc, algorithm, f"{mean['gospa']:.1f}", f"{mean['missed'] / half:.2f}",
                             f"{mean['false'] / half:.2f}", share])
        print_table(f"{args.row}, seed {args.seed}",
                    ["associator", "algorithm", "GOSPA", "missed", "false", "fast share"], rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
