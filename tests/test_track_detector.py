"""Maneuver events on the tracks of 3-D trackers (radar ``mtt-local``, 3-D ``mtt-centralized``)."""

from __future__ import annotations

import itertools
import json
import re
from pathlib import Path

import numpy as np
import pytest

from fedtrack.fusion_center.mtt.evaluation import evaluate
from fedtrack.fusion_center.mtt.replay import replay_mtt
from fedtrack.local_filters.mtt.models import RADAR_LAYOUT
from fedtrack.local_filters.radar.ekf import radar_h
from fedtrack.sensors.multitarget import Scenario, parse_spec, simulate

BASE = "[mtt]\nq = 1.0\npd = 1.0\nclutter_density = 0.0\ninit_velocity_std = 30.0\n"


def pictures(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def replay_both(algorithm: str, measurements: Path, config: str, tmp_path: Path, sensor: str | None
                ) -> tuple[list[dict], list[dict]]:
    """The pictures without and with ``maneuver = "vdie"``."""
    out = []
    for name, text in (("cv", config), ("man", config.replace("[mtt]\n", '[mtt]\nmaneuver = "vdie"\n', 1))):
        (tmp_path / f"{name}.toml").write_text(text)
        replay_mtt(algorithm, measurements, tmp_path / f"{name}.toml", tmp_path / f"{name}.jsonl", sensor=sensor)
        out.append(pictures(tmp_path / f"{name}.jsonl"))
    return out[0], out[1]


def accelerating(t: np.ndarray, t_on: float, a: np.ndarray) -> np.ndarray:
    """Truth ``[x, vx, y, vy, z, vz]`` at times ``t``: CV, then a constant horizontal ``a`` from ``t_on``."""
    x0 = np.array([3000.0, -15.0, 1000.0, 10.0, 500.0, 0.0])
    s = np.maximum(t - t_on, 0.0)[:, None]
    x = x0 + t[:, None] * np.array([x0[1], 0, x0[3], 0, x0[5], 0])
    x[:, [0, 2]] += 0.5 * a * s * s
    x[:, [1, 3]] += a * s
    return x


@pytest.mark.parametrize("algorithm", ["mtt-local", "mtt-centralized"])
def test_a_radar_track_reports_its_maneuver_without_changing_its_estimate(tmp_path: Path, algorithm: str) -> None:
    """A target accelerating by 2 m/s^2 from 30 s, seen by noise-free radars (one at 1 Hz;
    centralized: a second at 0.7 s): with the detector the estimates equal those without it, no
    maneuver is reported before the onset, and one is from within 10 s of it on, with an onset and
    an acceleration near the truth's."""
    t_on, a = 30.0, np.array([1.2, -1.6])
    rows = []
    sensors = (("r1", 1.0, 0.0, [0.0, 0.0, 0.0]), ("r2", 0.7, 0.3, [500.0, -800.0, 0.0]))
    for sensor, period, phase, position in sensors[: 1 if algorithm == "mtt-local" else 2]:
        times = np.arange(phase, 60.0, period).round(6)
        z = radar_h(accelerating(times, t_on, a), RADAR_LAYOUT, np.array(position))
        rows += [{"t": t, "sensor": sensor, "sensor_position": position,
                  "R": np.diag([10.0**2, 0.002**2, 0.002**2]).tolist(), "detections": [{"z": zk}]}
                 for t, zk in zip(times.tolist(), z.tolist())]
    rows.sort(key=lambda r: r["t"])
    measurements = tmp_path / "m.jsonl"
    measurements.write_text("".join(json.dumps(r) + "\n" for r in rows))
    listed = '["r1"]' if algorithm == "mtt-local" else '["r1", "r2"]'  # the window: 15 scans of each
    cv, man = replay_both(algorithm, measurements, BASE + f"sensors = {listed}\n", tmp_path,
                          "r1" if algorithm == "mtt-local" else None)
    flags = []
    for plain, pic in zip(cv, man, strict=True):
        assert [t["id"] for t in plain["tracks"]] == [t["id"] for t in pic["tracks"]] and len(pic["tracks"]) == 1
        p, q = plain["tracks"][0], pic["tracks"][0]
        assert p["x"] == q["x"] and p["P"] == q["P"] and "maneuver" not in p
        if "maneuver" in q:
            flags.append((pic["t"], q["maneuver"]))
        elif pic["t"] >= t_on + 10.0:
            raise AssertionError(f"no maneuver reported at {pic['t']}")
    assert flags and flags[0][0] > t_on
    first = flags[0][1]
    assert abs(first["onset"] - t_on) <= 2.0 and np.hypot(*(np.array(first["accel"]) - a)) < 0.5


def test_radar_maneuver_flags_follow_the_truth(tmp_path: Path) -> None:
    """On the simulator's cluttered radar scenario, a radar's own tracker flags maneuvers while
    targets accelerate and seldom on straight legs (here 1.4 % of the pairs, one track's few
    seconds; over five 40-target scenarios of 120 s, 0.1-0.2 %); the 3-D tracks' estimates and
    ids are those without the detector. With ``q = 1``, the value these rates were measured at: the
    simulator's own ``q`` (2.47 here) is derived for a CV filter without a detector and takes
    more of the turns into the process noise (7.6 % flagged while accelerating)."""
    simulate(Scenario(targets=12, duration=90.0, clutter=2.0), parse_spec("radar:1.0,radar:0.8"), 3, tmp_path)
    config = re.sub(r"(?m)^q = .*$", "q = 1.0", (tmp_path / "config.toml").read_text())
    cv, man = replay_both("mtt-local", tmp_path / "measurements.jsonl", config, tmp_path, "r1")
    for plain, pic in zip(cv, man, strict=True):
        assert [t["id"] for t in plain["tracks"]] == [t["id"] for t in pic["tracks"]]
        assert [t["x"] for t in plain["tracks"]] == [t["x"] for t in pic["tracks"]]
    result = evaluate(tmp_path / "man.jsonl", tmp_path / "truth.jsonl")["maneuvers"]
    assert result["onsets"] >= 3
    maneuvering, straight = result["flagged_while_maneuvering"], result["flagged_while_straight"]
    assert maneuvering > 0.1 and straight < 0.03 and maneuvering > 5.0 * straight


def test_out_of_sequence_scans_give_the_time_sorted_maneuvers(tmp_path: Path) -> None:
    """3-D ``mtt-centralized`` rolls back for a late scan, its detectors with it: on arrival-order
    data (20 % of scans late) with ``picture_delay = max_lag``, the pictures, maneuvers included,
    equal those of the time-sorted data to 1e-9."""
    simulate(Scenario(targets=8, duration=80.0, clutter=2.0, late=0.2), parse_spec("radar:1.0,pos:0.7,pos:1.3"), 4,
             tmp_path)
    rows = [json.loads(line) for line in (tmp_path / "measurements.jsonl").read_text().splitlines()]
    assert any(a["t"] > b["t"] for a, b in itertools.pairwise(rows)), "the scenario has out-of-sequence lines"
    (tmp_path / "sorted.jsonl").write_text("".join(json.dumps(r) + "\n" for r in sorted(rows, key=lambda r: r["t"])))
    config = (tmp_path / "config.toml").read_text()
    assert "max_lag = 3.0" in config
    (tmp_path / "c.toml").write_text(config.replace("[mtt]\n", '[mtt]\nmaneuver = "vdie"\npicture_delay = 3.0\n', 1))
    for name in ("measurements", "sorted"):
        replay_mtt("mtt-centralized", tmp_path / f"{name}.jsonl", tmp_path / "c.toml", tmp_path / f"{name}-out.jsonl")
    arrival, ordered = pictures(tmp_path / "measurements-out.jsonl"), pictures(tmp_path / "sorted-out.jsonl")
    flagged = 0
    for a, b in zip(arrival, ordered, strict=True):
        assert [t["id"] for t in a["tracks"]] == [t["id"] for t in b["tracks"]]
        for ta, tb in zip(a["tracks"], b["tracks"]):
            np.testing.assert_allclose(ta["x"], tb["x"], rtol=1e-9, atol=1e-9)
            assert ("maneuver" in ta) == ("maneuver" in tb)
            if "maneuver" in ta:
                flagged += 1
                ma, mb = ta["maneuver"], tb["maneuver"]
                np.testing.assert_allclose([ma["onset"], *ma["accel"], ma["statistic"]],
                                           [mb["onset"], *mb["accel"], mb["statistic"]], rtol=1e-9, atol=1e-9)
    assert flagged > 0
