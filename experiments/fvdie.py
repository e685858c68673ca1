"""``fedtrack reproduce fvdie``: seeded Monte Carlo reproduction of paper 004.

FVDIE, DVDIE and the centralized CV Kalman filter (``kf``, no maneuver handling) run on
the same truth and measurements (common random numbers) for scenarios 1 and 2 with two
sensors, all runs batched.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from scipy.stats import chi2
from tqdm import tqdm

from fedtrack.experiments.tables import announce
from fedtrack.fusion_center.trackers import make_tracker
from fedtrack.local_filters.linear.kalman import nees
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.local_filters.vdie.estimation import EVENT_NEW_CA, EVENT_ONSET
from fedtrack.progress import progress_bar
from fedtrack.sensors.scenarios import DEFAULT_R, Scenario, paper004_scenario, simulate_positions, simulate_truth

FILTERS = ("fvdie", "dvdie", "kf")
TABLE1_TIMES = (30, 31, 32, 33, 34, 70, 71, 72, 73, 74)
PAPER_TABLE1 = {
    "fvdie": [3.96, 3.89, 12.9, 14.1, 7.15, 4.18, 4.17, 10.3, 16.0, 7.33],
    "dvdie": [4.02, 4.09, 16.8, 53.5, 35.9, 4.35, 4.76, 12.1, 39.6, 34.1],
}
PAPER_FALSE_DETECTIONS = {"1": {"fvdie": 3.38, "dvdie": 5.74}, "2": {"fvdie": 3.20, "dvdie": 5.92}}
CV_NEES_WINDOW = (5.0, 29.0)  # non-maneuvering segment used for the NEES check (after start-up)
CV_SEGMENT = (20.0, 30.0)  # the CV segment before the first maneuver, where false onsets cost accuracy


class MonteCarloRun(NamedTuple):
    """Per-run, per-scan estimates of one tracker."""

    x: np.ndarray  # (runs, K, 6) CA layout
    P: np.ndarray  # (runs, K, 6, 6)
    is_ca: np.ndarray  # (runs, K)
    event: np.ndarray  # (runs, K)
    cpu_s: float


def run_tracker(algorithm: str, times: np.ndarray, zs: np.ndarray, Rs: np.ndarray,
                config: FusionConfig, progress: tqdm | None = None) -> MonteCarloRun:
    """Run one tracker over all runs at once (``zs``: runs x K x N x 2)."""
    tracker = make_tracker(algorithm, zs.shape[2], config)
    xs, Ps, modes, events = [], [], [], []
    start = time.process_time()
    for k, t in enumerate(times):
        est = tracker.step_batch(float(t), zs[:, k], Rs)
        xs.append(est.x)
        Ps.append(est.P)
        modes.append(est.is_ca)
        events.append(est.event)
        if progress is not None:
            progress.update()
    cpu = time.process_time() - start
    return MonteCarloRun(np.stack(xs, 1), np.stack(Ps, 1), np.stack(modes, 1), np.stack(events, 1), cpu)


def false_detection_rule(scenario: Scenario, settle_s: float) -> str:
    segs = ", ".join(f"({s.t_start:g}, {s.t_end + settle_s:g}]" for s in scenario.segments)
    return (f"A detection is a maneuver onset (CV->CA) or new-acceleration (CA->CA) decision; for DVDIE, "
            f"a scan in which any local filter decided one. It is true if its scan time t lies in "
            f"(t_start, t_end + {settle_s:g} s] of a maneuver segment (the settling interval is the "
            f"detection window, {settle_s:g} s), here {segs}; every other detection is false.")


def true_detection_mask(scenario: Scenario, times: np.ndarray, settle_s: float) -> np.ndarray:
    ok = np.zeros(times.shape, dtype=bool)
    for seg in scenario.segments:
        ok |= (times > seg.t_start) & (times <= seg.t_end + settle_s)
    return ok


def rms_with_stderr(err: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """RMS over runs (axis 0) and its delta-method standard error."""
    sq = err ** 2
    ms = sq.mean(axis=0)
    rms = np.sqrt(ms)
    se = sq.std(axis=0, ddof=1) / np.sqrt(err.shape[0]) / np.maximum(2.0 * rms, 1e-300)
    return rms, se


def segment_rms(err: np.ndarray) -> tuple[float, float]:
    """RMS over runs and scans (``err``: runs x scans) and its standard error over runs."""
    per_run = (err ** 2).mean(axis=1)
    rms = float(np.sqrt(per_run.mean()))
    return rms, float(per_run.std(ddof=1) / np.sqrt(len(per_run)) / max(2.0 * rms, 1e-300))


def segment_ratio(err_a: np.ndarray, err_b: np.ndarray) -> tuple[float, float]:
    """RMS ratio a / b over runs and scans (runs x scans, the same runs) and its paired
    delta-method standard error over runs."""
    ma, mb = (err_a ** 2).mean(axis=1), (err_b ** 2).mean(axis=1)
    ratio = float(np.sqrt(ma.mean() / mb.mean()))
    influence = 0.5 * ratio * (ma / ma.mean() - mb / mb.mean())
    return ratio, float(influence.std(ddof=1) / np.sqrt(len(ma)))


def summarize(run: MonteCarloRun, truth: np.ndarray, times: np.ndarray, scenario: Scenario,
              settle_s: float) -> dict[str, Any]:
    err = run.x - truth
    rms = {name: rms_with_stderr(err[..., i]) for name, i in
           (("pos_x", 0), ("vel_x", 1), ("pos_y", 3), ("vel_y", 4))}
    detection = (run.event == EVENT_ONSET) | (run.event == EVENT_NEW_CA)
    false = detection & ~true_detection_mask(scenario, times, settle_s)
    false_per_run = false.sum(axis=1)
    idx = [int(np.flatnonzero(times == t)[0]) for t in TABLE1_TIMES]
    out: dict[str, Any] = {"t": times.tolist()}
    for name, (r, _) in rms.items():
        out[f"rms_{name}"] = r.tolist()
    out["table1"] = {str(t): float(rms["pos_x"][0][i]) for t, i in zip(TABLE1_TIMES, idx)}
    out["table1_stderr"] = {str(t): float(rms["pos_x"][1][i]) for t, i in zip(TABLE1_TIMES, idx)}
    seg = (times >= CV_SEGMENT[0]) & (times <= CV_SEGMENT[1])
    seg_rms, seg_se = segment_rms(err[:, seg, 0])
    out["cv_segment"] = {"t": list(CV_SEGMENT), "rms_pos_x": seg_rms, "stderr": seg_se}
    out["false_detections_per_run"] = float(false_per_run.mean())
    out["false_detections_stderr"] = float(false_per_run.std(ddof=1) / np.sqrt(len(false_per_run)))
    out["detections_per_run"] = float(detection.sum(axis=1).mean())
    out["detection_times"] = [times[row].tolist() for row in detection]
    out["cpu_s"] = run.cpu_s
    return out


def cv_segment_nees(run: MonteCarloRun, truth: np.ndarray, times: np.ndarray) -> dict[str, Any]:
    """Average NEES of the fused CV estimate (4 dof) over runs, per scan of the CV segment."""
    cv = [0, 1, 3, 4]
    sel = (times >= CV_NEES_WINDOW[0]) & (times <= CV_NEES_WINDOW[1])
    e = (run.x - truth)[:, sel][..., cv]
    P = run.P[:, sel][..., cv, :][..., :, cv]
    per_scan = nees(e, P).mean(axis=0)
    runs = truth.shape[0]
    lo, hi = chi2.ppf([0.025, 0.975], 4 * runs) / runs
    return {"t": times[sel].tolist(), "mean_nees": per_scan.tolist(), "band_95": [float(lo), float(hi)],
            "fraction_in_band": float(np.mean((per_scan >= lo) & (per_scan <= hi))),
            "time_average": float(per_scan.mean())}


def reproduce_fvdie(runs: int, seed: int, json_path: Path, plots_dir: Path | None) -> dict[str, Any]:
    """Monte Carlo of FVDIE, DVDIE and kf on paper 004 scenarios 1 and 2 with two sensors."""
    if runs < 2:
        raise ValueError("--runs must be at least 2 (standard errors need two runs)")
    announce(f"reproduce fvdie: paper 004, FVDIE, DVDIE and the centralized KF with two sensors on "
             f"scenarios 1 and 2, {runs} Monte Carlo runs each, seed {seed}")
    wall = time.perf_counter()
    config = FusionConfig()
    settle_s = config.vdie.window * 1.0
    Rs = np.array([DEFAULT_R, DEFAULT_R])
    scen_seeds = np.random.SeedSequence(seed).spawn(2)
    scenarios = [paper004_scenario(1), paper004_scenario(2)]
    result: dict[str, Any] = {
        "runs": runs, "seed": seed, "sensors": 2, "R": DEFAULT_R.tolist(), "q": config.q,
        "vdie": {"window": config.vdie.window, "p": config.vdie.p, "h_detect": config.vdie.h_detect,
                 "h_cv": config.vdie.h_cv, "detect_sigma": config.vdie.detect_sigma,
                 "cv_sigma": config.vdie.cv_sigma, "min_samples": config.vdie.min_samples,
                 "detect_correction": config.vdie.detect_correction},
        "paper": {"table1": PAPER_TABLE1, "false_detections_per_run": PAPER_FALSE_DETECTIONS},
        "scenarios": {},
    }
    total = sum(len(s.times) for s in scenarios) * len(FILTERS)
    with progress_bar(total, f"reproduce fvdie ({runs} runs)") as progress:
        for scenario, ss in zip(scenarios, scen_seeds):
            rng = np.random.default_rng(ss)
            truth = simulate_truth(scenario, runs, rng)
            zs = simulate_positions(truth, Rs, rng)
            times = scenario.times
            filters = {}
            nees_report = None
            seg = (times >= CV_SEGMENT[0]) & (times <= CV_SEGMENT[1])
            seg_err = {}
            for name in FILTERS:
                run = run_tracker(name, times, zs, Rs, config, progress)
                filters[name] = summarize(run, truth, times, scenario, settle_s)
                seg_err[name] = (run.x - truth)[:, seg, 0]
                if name == "kf":
                    nees_report = cv_segment_nees(run, truth, times)
            result["scenarios"][scenario.name] = {
                "false_detection_rule": false_detection_rule(scenario, settle_s),
                "maneuvers": [[seg.t_start, seg.t_end] for seg in scenario.segments],
                "filters": filters,
                "kf_cv_segment_nees": nees_report,
                "cv_segment_fvdie_over_dvdie": dict(zip(("ratio", "stderr"),
                                                        segment_ratio(seg_err["fvdie"], seg_err["dvdie"]))),
            }
    result["wall_time_s"] = time.perf_counter() - wall
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(result))
    if plots_dir is not None:
        plot_rms(result, plots_dir)
    print_summary(result)
    return result


def print_summary(result: dict[str, Any]) -> None:
    """Table 1 and false detections next to the paper's values."""
    for sname, scen in result["scenarios"].items():
        print(f"\nscenario {sname}: x position RMS error [m] (+- standard error), {result['runs']} runs")
        lo, hi = CV_SEGMENT
        print("  t    " + f"{f'CV {lo:g}-{hi:g}':>14}" + "".join(f"{t:>14}" for t in TABLE1_TIMES))
        for name in FILTERS:
            f = scen["filters"][name]
            seg = f"{f['cv_segment']['rms_pos_x']:8.2f}+-{f['cv_segment']['stderr']:<4.2f}"
            cells = "".join(f"{f['table1'][str(t)]:8.2f}+-{f['table1_stderr'][str(t)]:<4.2f}" for t in TABLE1_TIMES)
            print(f"  {name:5}{seg}{cells}")
            if sname == "1" and name in PAPER_TABLE1:
                print("  paper" + " " * 14 + "".join(f"{v:14.2f}" for v in PAPER_TABLE1[name]))
        for name in ("fvdie", "dvdie"):
            f = scen["filters"][name]
            print(f"  false detections/run {name}: {f['false_detections_per_run']:.2f} "
                  f"+- {f['false_detections_stderr']:.2f} (paper {PAPER_FALSE_DETECTIONS[sname][name]})")
        r = scen["cv_segment_fvdie_over_dvdie"]
        print(f"  CV segment {lo:g}-{hi:g} s, fvdie / dvdie RMS in the same runs: {r['ratio']:.3f} "
              f"+- {r['stderr']:.3f}")
        n = scen["kf_cv_segment_nees"]
        print(f"  kf NEES on the CV segment: time average {n['time_average']:.2f} (4 dof), "
              f"{100 * n['fraction_in_band']:.0f}% of scans in the 95% band")
    print(f"\nwall time {result['wall_time_s']:.1f} s")


def plot_rms(result: dict[str, Any], plots_dir: Path) -> list[Path]:
    """Figures 5-8 of the paper: RMS position and velocity error vs time, all filters, the
    maneuvers shaded and the paper's Table 1 values (scenario 1, x) as markers."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plots_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    figure_no = {("1", "x"): 5, ("1", "y"): 6, ("2", "x"): 7, ("2", "y"): 8}
    styles = {"fvdie": ("-", "C0"), "dvdie": ("--", "C1"), "kf": (":", "C2")}
    for (sname, axis), fig_no in figure_no.items():
        scen = result["scenarios"][sname]
        fig, axes = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
        for ax, quantity, unit in ((axes[0], "pos", "m"), (axes[1], "vel", "m/s")):
            for i, (t0, t1) in enumerate(scen.get("maneuvers", [])):
                ax.axvspan(t0, t1, color="0.85", zorder=0, label="maneuver" if i == 0 else None)
            for name in FILTERS:
                f = scen["filters"][name]
                line, color = styles[name]
                ax.plot(f["t"], f[f"rms_{quantity}_{axis}"], line, color=color, label=name.upper())
                if (sname, axis, quantity) == ("1", "x", "pos") and name in PAPER_TABLE1:
                    ax.plot(TABLE1_TIMES, PAPER_TABLE1[name], "o" if name == "fvdie" else "s",
                            color=color, mfc="none", label=f"paper {name.upper()} (Table 1)")
            ax.set_yscale("log")
            ax.set_ylabel(f"RMS {quantity} error {axis} [{unit}]")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend()
        axes[1].set_xlabel("time [s]")
        fig.suptitle(f"Fig. {fig_no}: scenario {sname}, {axis} axis, {result['runs']} runs")
        fig.tight_layout()
        path = plots_dir / f"fig{fig_no}_scenario{sname}_{axis}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths
