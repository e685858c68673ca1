"""Per-track maneuver handling of the multi-target trackers (``[mtt] maneuver = "vdie"``)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from support import in_parallel

from fedtrack.config import ConfigError, load_tables
from fedtrack.fusion_center.mtt.engines import central_params
from fedtrack.fusion_center.mtt.replay import replay_mtt
from fedtrack.local_filters.mtt.config import MttConfig, MttSettings
from fedtrack.local_filters.mtt.scan import SensorScan
from fedtrack.local_filters.mtt.tracker import initial_state, track_params, tracker_step
from fedtrack.local_filters.vdie.estimation import VdieParams
from fedtrack.sensors.multitarget import Scenario, parse_spec, simulate


def pictures(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.mark.parametrize("algorithm", ["mtt-local", "mtt-centralized", "mtt-decentralized"])
def test_vdie_that_never_detects_a_maneuver_is_the_cv_tracker(tmp_path: Path, algorithm: str) -> None:
    """With a detector that never fires, every track stays in CV: the tracks, their ids and the
    pictures equal those of ``maneuver = "none"`` to 1e-9 (the VDIE filter step and prediction
    are the CV tracker's own), on maneuvering, cluttered, asynchronous data."""
    simulate(Scenario(targets=8, duration=40.0, clutter=3.0), parse_spec("pos:1.0,pos:0.7,pos:1.3"), 2, tmp_path)
    base = (tmp_path / "config.toml").read_text()
    (tmp_path / "vdie.toml").write_text(base.replace("[mtt]\n", '[mtt]\nmaneuver = "vdie"\n', 1)
                                        + "\n[mtt.vdie]\ndetect_sigma = 40.0\n")
    sensor = "s2" if algorithm == "mtt-local" else None
    for name in ("config", "vdie"):
        replay_mtt(algorithm, tmp_path / "measurements.jsonl", tmp_path / f"{name}.toml", tmp_path / f"{name}.jsonl",
                   sensor=sensor)
    cv, vdie = pictures(tmp_path / "config.jsonl"), pictures(tmp_path / "vdie.jsonl")
    assert len(cv) == len(vdie) >= 35 and sum(len(p["tracks"]) for p in cv) > 200
    for a, b in zip(cv, vdie):
        assert [t["id"] for t in a["tracks"]] == [t["id"] for t in b["tracks"]]
        assert all(t["model"] == "cv" for t in b["tracks"])
        for ta, tb in zip(a["tracks"], b["tracks"]):
            np.testing.assert_allclose(tb["x"], ta["x"], rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(tb["P"], ta["P"], rtol=1e-9, atol=1e-9)


def turning_target(rng: np.random.Generator, n: int, accel: float) -> tuple[np.ndarray, np.ndarray]:
    """Truth ``(n, 4)`` at 1 s: straight for 20 s, then a coordinated turn of ``accel`` m/s^2 at
    20 m/s until the end; position detections with 10 m noise."""
    speed, omega = 20.0, accel / 20.0
    x = np.zeros((n, 4))
    x[0] = [0.0, speed, 0.0, 0.0]
    for k in range(1, n):
        w = omega if k > 20 else 0.0
        vx, vy = x[k - 1, 1], x[k - 1, 3]
        if w:
            s, c = np.sin(w), np.cos(w)
            x[k] = [x[k - 1, 0] + (vx * s - vy * (1 - c)) / w, vx * c - vy * s,
                    x[k - 1, 2] + (vx * (1 - c) + vy * s) / w, vx * s + vy * c]
        else:
            x[k] = [x[k - 1, 0] + vx, vx, x[k - 1, 2] + vy, vy]
    return x, x[:, [0, 2]] + 10.0 * rng.standard_normal((n, 2))


def track_errors(z: np.ndarray, truth: np.ndarray, cfg: MttConfig) -> np.ndarray | None:
    """Position error of the first track after each scan (pd = 1, no clutter); None if it was lost
    (deleted after its detections left its gate ``delete_misses`` scans in a row)."""
    state = initial_state(4)
    R = np.eye(2) * 100.0
    errors = []
    for k, zk in enumerate(z):
        state = tracker_step(state, SensorScan(float(k), "s1", R, zk[None, :], None, None),
                             track_params(cfg, "s1", 4)).state
        first = np.flatnonzero(state.tracks.ids == 0)
        if not first.size:
            return None
        errors.append(np.linalg.norm(state.tracks.x[first[0], [0, 2]] - truth[k, [0, 2]]))
    return np.array(errors)


BASE = MttConfig(pd=1.0, clutter_density=0.0, q=1.0, init_velocity_std=30.0)
VDIE = dataclasses.replace(BASE, maneuver="vdie")
SEEDS = 40


def turn_errors(seed: int, accel: float) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``track_errors`` of the CV and of the VDIE tracker on seed ``seed``'s turn of ``accel`` m/s^2."""
    truth, z = turning_target(np.random.default_rng(seed), 50, accel)
    return track_errors(z, truth, BASE), track_errors(z, truth, VDIE)


@pytest.fixture(scope="module")
def turns() -> dict[float, list[tuple[np.ndarray | None, np.ndarray | None]]]:
    """``turn_errors`` of seeds 0 to 39 for the 2 and the 3 m/s^2 turns, by turn: 160 independent
    tracker runs, over two processes."""
    accels = (2.0, 3.0)
    runs = in_parallel([(turn_errors, (seed, accel)) for accel in accels for seed in range(SEEDS)])
    return {accel: runs[i * SEEDS:(i + 1) * SEEDS] for i, accel in enumerate(accels)}


def test_vdie_follows_a_turn_better_than_cv(turns: dict[float, list[tuple[np.ndarray | None, np.ndarray | None]]]) -> None:
    """A 2 m/s^2 turn after 20 s of straight flight, 40 seeded runs, those where both keep the
    target: VDIE's position RMS over the turn is below the CV tracker's by more than 3 standard
    errors of the paired difference, and on the straight leg not worse by more than 3 of them."""
    turn, straight = [], []
    for e_cv, e_vd in turns[2.0]:
        if e_cv is None or e_vd is None:
            continue
        turn.append(np.sqrt(np.mean(e_cv[25:] ** 2)) - np.sqrt(np.mean(e_vd[25:] ** 2)))
        straight.append(np.sqrt(np.mean(e_cv[5:20] ** 2)) - np.sqrt(np.mean(e_vd[5:20] ** 2)))
    gain, se = np.mean(turn), np.std(turn, ddof=1) / np.sqrt(len(turn))
    loss, se_s = -np.mean(straight), np.std(straight, ddof=1) / np.sqrt(len(straight))
    print(f"turn: CV - VDIE RMS {gain:.2f} +- {se:.2f} m; straight: VDIE - CV {loss:.2f} +- {se_s:.2f} m "
          f"({len(turn)} runs of 40 kept by both)")
    assert len(turn) >= 20
    assert gain > 3 * se and gain > 1.0
    assert loss < 3 * se_s + 0.5


def test_vdie_keeps_a_hard_turn_that_cv_loses(turns: dict[float, list[tuple[np.ndarray | None, np.ndarray | None]]]) -> None:
    """A 3 m/s^2 turn, 40 seeded runs: the CV tracker's track is lost (its detections leave the
    gate) in nearly every run, VDIE's in few."""
    lost_cv = sum(e_cv is None for e_cv, _ in turns[3.0])
    lost_vdie = sum(e_vd is None for _, e_vd in turns[3.0])
    print(f"3 m/s^2 turn, 40 runs: track lost by CV in {lost_cv}, by VDIE in {lost_vdie}")
    assert lost_cv >= 34 and lost_vdie <= 14


def test_maneuver_settings_are_checked(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text('[mtt]\nmaneuver = "imm"\n')
    with pytest.raises(ConfigError, match="maneuver: must be one of none, vdie"):
        load_tables(path, MttSettings)
    path.write_text('[mtt]\nmaneuver = "vdie"\n[mtt.vdie]\nwindow = 0\n')
    with pytest.raises(ConfigError, match="mtt.vdie.window"):
        load_tables(path, MttSettings)
    cfg = load_tables(None, MttSettings).mtt
    assert cfg.maneuver == "none" and cfg.vdie == VdieParams(window=15)
    listed = dataclasses.replace(cfg, maneuver="vdie", sensors=("a", "b", "c"))
    assert central_params(listed, "a", 4).maneuver.window == 45
    assert track_params(listed, "a", 4).maneuver.window == 15
    assert track_params(listed, "a", 4, feedback=True).maneuver is None  # federated: the centre owns the state
    assert track_params(listed, "a", 6).maneuver is None  # a radar tracker stays CV
