"""Seeded Monte Carlo checks of paper 004's numbers (200 runs, all batched: a few seconds)."""

import numpy as np
import pytest
from scipy.stats import chi2

from fedtrack.experiments.fvdie import (
    CV_SEGMENT,
    PAPER_FALSE_DETECTIONS,
    PAPER_TABLE1,
    TABLE1_TIMES,
    cv_segment_nees,
    run_tracker,
    segment_ratio,
    summarize,
)
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.local_filters.vdie.estimation import VdieParams
from fedtrack.sensors.scenarios import DEFAULT_R, paper004_scenario, simulate_positions, simulate_truth

RUNS = 200


@pytest.fixture(scope="module")
def results():
    config = FusionConfig()
    out = {}
    for number in (1, 2):
        scenario = paper004_scenario(number)
        rng = np.random.default_rng(100 + number)
        truth = simulate_truth(scenario, RUNS, rng)
        Rs = np.array([DEFAULT_R, DEFAULT_R])
        zs = simulate_positions(truth, Rs, rng)
        runs = {name: run_tracker(name, scenario.times, zs, Rs, config) for name in ("fvdie", "dvdie", "kf")}
        out[number] = {
            "summary": {n: summarize(r, truth, scenario.times, scenario, 6.0) for n, r in runs.items()},
            "nees": cv_segment_nees(runs["kf"], truth, scenario.times),
            "truth": truth, "zs": zs, "runs": runs,
        }
    return out


def test_steady_state_fused_rms_matches_table1(results):
    # CV segment t = 20..29 pooled: 2 sensors 3.96 m +- 0.3 (paper Table 1 at t = 30)
    r = results[1]
    err = r["runs"]["kf"].x[:, 20:30, 0] - r["truth"][:, 20:30, 0]
    assert np.sqrt(np.mean(err ** 2)) == pytest.approx(3.96, abs=0.3)


def test_single_sensor_steady_state_rms():
    scenario = paper004_scenario(1)
    rng = np.random.default_rng(7)
    truth = simulate_truth(scenario, RUNS, rng)
    Rs = np.array([DEFAULT_R])
    zs = simulate_positions(truth, Rs, rng)
    run = run_tracker("kf", scenario.times[:30], zs[:, :30], Rs, FusionConfig())
    err = run.x[:, 20:30, 0] - truth[:, 20:30, 0]
    assert np.sqrt(np.mean(err ** 2)) == pytest.approx(5.20, abs=0.35)


@pytest.mark.parametrize("number", [1, 2])
def test_nees_of_fused_cv_estimate_in_95_band(results, number):
    nees = results[number]["nees"]
    lo, hi = chi2.ppf([0.025, 0.975], 4 * RUNS) / RUNS
    # the time average over the CV segment lies in the per-scan 95% band of a 4-dof NEES
    assert lo <= nees["time_average"] <= hi
    assert nees["fraction_in_band"] >= 0.75


def test_fvdie_meets_table1(results):
    s = results[1]["summary"]
    for t in (33, 34, 73, 74):
        paper = PAPER_TABLE1["fvdie"][TABLE1_TIMES.index(t)]
        assert s["fvdie"]["table1"][str(t)] <= 1.1 * paper, t
        assert s["fvdie"]["table1"][str(t)] <= s["dvdie"]["table1"][str(t)], t


@pytest.mark.parametrize("number", [1, 2])
def test_fvdie_false_detections_at_most_the_papers(results, number):
    s = results[number]["summary"]
    assert s["fvdie"]["false_detections_per_run"] <= PAPER_FALSE_DETECTIONS[str(number)]["fvdie"]
    # never more than DVDIE's beyond the Monte Carlo noise (2 standard errors of the difference)
    diff = s["fvdie"]["false_detections_per_run"] - s["dvdie"]["false_detections_per_run"]
    se = np.hypot(s["dvdie"]["false_detections_stderr"], s["fvdie"]["false_detections_stderr"])
    assert diff < 2 * se


def test_kf_never_detects_and_maneuvers_are_detected(results):
    s = results[1]["summary"]
    assert s["kf"]["detections_per_run"] == 0
    # every FVDIE run detects both maneuver onsets within 3 s
    times = [np.array(d) for d in s["fvdie"]["detection_times"]]
    assert all(np.any((d > 30) & (d <= 33)) and np.any((d > 70) & (d <= 73)) for d in times)


def test_false_onsets_cost_fvdie_at_most_3_percent_on_the_cv_segment():
    """Issue 15: with the window-corrected threshold, FVDIE's CV-segment RMS is within 3% of
    DVDIE's in the same runs, and clearly below FVDIE's with every candidate onset tested at
    3 sigma (1,000 runs of the scans up to t = 30, before any maneuver)."""
    scenario = paper004_scenario(1)
    keep = scenario.times <= CV_SEGMENT[1]
    times = scenario.times[keep]
    rng = np.random.default_rng(2024)
    truth = simulate_truth(scenario, 1000, rng)[:, keep]
    Rs = np.array([DEFAULT_R, DEFAULT_R])
    zs = simulate_positions(truth, Rs, rng)
    seg = times >= CV_SEGMENT[0]

    def seg_err(name: str, config: FusionConfig) -> np.ndarray:
        return (run_tracker(name, times, zs, Rs, config).x - truth)[:, seg, 0]

    fvdie = seg_err("fvdie", FusionConfig())
    ratio, se = segment_ratio(fvdie, seg_err("dvdie", FusionConfig()))
    assert ratio < 1.03, (ratio, se)
    uncorrected = seg_err("fvdie", FusionConfig(vdie=VdieParams(detect_correction="none")))
    gain, se_gain = segment_ratio(fvdie, uncorrected)
    assert gain < 1 - 2 * se_gain, (gain, se_gain)
