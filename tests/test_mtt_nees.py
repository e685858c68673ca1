"""Covariance consistency (NEES) of the multi-target trackers on the simulator's default scenario,
and the simulator's process noise derived from its truth (docs/multitarget.md#covariance-consistency-nees)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from support import in_parallel, replay_evaluated

from fedtrack.config import load_tables
from fedtrack.experiments.nees_straight import QS, straight_nees
from fedtrack.local_filters.mtt.config import MttSettings
from fedtrack.sensors.multitarget import (
    DT,
    MAX_ACCELERATION,
    Scenario,
    parse_spec,
    process_noise,
    simulate,
    simulate_truth,
)


def test_process_noise_from_the_truths_maximum_acceleration_and_the_longest_period() -> None:
    """``q = (a_M / 2)^2 T``: a_M = 6 deg/s at 30 m/s = pi m/s^2, bounding every simulated truth's
    acceleration (finite differences of the 0.05 s grid), T the longest sensor period."""
    assert MAX_ACCELERATION == pytest.approx(math.pi, abs=1e-12)
    x, _ = simulate_truth(Scenario(targets=60, duration=300.0), False, np.random.default_rng(1))
    accel = np.hypot(*(np.diff(x[:, :, [1, 3]], axis=0) / DT).transpose(2, 0, 1))
    assert 0.9 * MAX_ACCELERATION < accel.max() <= MAX_ACCELERATION + 1e-9
    assert process_noise(parse_spec("pos:1.0,pos:0.7,pos:1.3")) == pytest.approx(math.pi**2 / 4 * 1.3, abs=1e-6)
    assert process_noise(parse_spec("pos:0.5,radar:2.0")) == pytest.approx(math.pi**2 / 4 * 2.0, abs=1e-6)


def test_a_cv_filter_alone_puts_86_percent_of_straight_legs_in_the_band_whatever_q() -> None:
    """Why the state's 90% is not reached (docs/multitarget.md, "Straight legs at 86 % whatever q"):
    a CV Kalman filter alone, no association, on straight legs seen by the default sensors
    (experiments/nees_straight.py, 50 runs of 200 s): with the derived q and with q / 100 the same
    84-89% of the 4-dof NEES inside the band, the rest below, the velocity error a quarter of its
    variance (the steady state is scale-free; measured 86.2 / 86.8 %, 0.244 / 0.248); only at q =
    3e-6, whose steady state does not come within 200 s, more than 90% (93.2 %, 0.99)."""
    for q in (QS[0], QS[0] / 100):
        result = straight_nees(q, runs=50)
        assert 0.84 <= result.inside <= 0.89 and result.below >= 0.1, result
        assert 0.2 <= result.velocity_ratio <= 0.3, result
    tiny = straight_nees(3e-6, runs=50)
    assert tiny.inside > 0.9 and tiny.velocity_ratio > 0.8, tiny


@pytest.fixture(scope="module")
def scenario(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The default scenario (seed 1: three sensors at 1.0 / 0.7 / 1.3 s, P_D 0.9, 10 false
    detections a scan, 300 s) with 20 of its 60 targets, and the ``config.toml`` it writes."""
    out = tmp_path_factory.mktemp("nees")
    simulate(Scenario(targets=20), parse_spec("pos:1.0,pos:0.7,pos:1.3"), 1, out)
    return out


IMM = 'process_noise = "imm"\n'
ALGORITHMS = (("mtt-centralized", None), ("mtt-federated", None), ("mtt-local", "s1"))


@pytest.fixture(scope="module")
def replayed(scenario: Path) -> dict[tuple[str, str], dict]:
    """``evaluate`` of each algorithm replayed with the scenario's config, and of mtt-centralized and
    mtt-local with ``IMM`` added to its ``[mtt]``, by (algorithm, the keys added); the five
    replays at once, over two processes."""
    runs = [(algorithm, sensor, extra) for extra in ("", IMM) for algorithm, sensor in ALGORITHMS
            if not extra or algorithm != "mtt-federated"]
    calls = []
    for algorithm, sensor, extra in runs:
        config = scenario / f"config{len(extra)}.toml"
        config.write_text((scenario / "config.toml").read_text().replace("[mtt]\n", "[mtt]\n" + extra, 1))
        calls.append((replay_evaluated, (algorithm, scenario / "measurements.jsonl", config,
                                         scenario / f"{algorithm}{len(extra)}.jsonl", scenario / "truth.jsonl", sensor)))
    return {(algorithm, extra): result for (algorithm, _, extra), result in zip(runs, in_parallel(calls))}


def test_nees_inside_the_95_percent_band_on_the_default_scenario(scenario: Path,
                                                                 replayed: dict[tuple[str, str], dict]) -> None:
    """Replayed with the ``config.toml`` the simulator writes, for mtt-centralized, mtt-federated
    and mtt-local: at least 95% of the assigned pairs' position NEES (2 dof) inside the two-sided
    95% chi-square band, at least 85% of the state's (4 dof) while the truth accelerates, and at
    least 86% of the state's overall. Issue 28 asks 90% of the state's: not met (a CV filter with
    q > 0 is conservative in velocity on straight legs; an adaptive level and an IMM were measured
    and are below this: docs/multitarget.md#covariance-consistency-nees). Measured: position
    0.961 / 0.960 / 0.959, accelerating 0.963 / 0.968 / 0.884, state 0.875 / 0.874 / 0.866; with
    the earlier q = 1: 0.940 / 0.940 / 0.936, 0.447 / 0.447 / 0.398, 0.855 / 0.856 / 0.842."""
    assert load_tables(scenario / "config.toml", MttSettings).mtt.q == pytest.approx(math.pi**2 / 4 * 1.3, abs=1e-6)
    inside = {}
    for algorithm, sensor in ALGORITHMS:
        parts = {row["part"]: row for row in replayed[algorithm, ""]["nees"]}
        assert (parts["state"]["dof"], parts["position"]["dof"]) == (4, 2)
        assert parts["state"]["pairs"] > 4000
        inside[algorithm] = (parts["position"]["inside_95"], parts["state"]["maneuvering"]["inside_95"],
                             parts["state"]["inside_95"])
    for position, accelerating, state in inside.values():
        assert position >= 0.95 and accelerating >= 0.85 and state >= 0.86, inside


def test_imm_lowers_gospa_on_the_default_scenario(replayed: dict[tuple[str, str], dict]) -> None:
    """``process_noise = "imm"`` on the same data (mtt-centralized, mtt-local): mean GOSPA at least
    10% below the fixed q's (measured 32.3 against 42.0, 66.0 against 78.8), the position NEES
    still at least 93% inside (0.953 / 0.942), the state's below the fixed q's (0.824 / 0.812
    against 0.875 / 0.866: the combined covariance hedges for a maneuver on the straight legs)."""
    for algorithm, _ in ALGORITHMS[::2]:
        fixed, imm = replayed[algorithm, ""], replayed[algorithm, IMM]
        assert imm["mean"]["gospa"] <= 0.9 * fixed["mean"]["gospa"], (algorithm, imm["mean"], fixed["mean"])
        parts = {row["part"]: row for row in imm["nees"]}
        assert parts["position"]["inside_95"] >= 0.93, (algorithm, parts)
        assert parts["state"]["inside_95"] < {row["part"]: row for row in fixed["nees"]}["state"]["inside_95"]
