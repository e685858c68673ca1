"""``fedtrack reproduce input-estimation`` (paper 002); its radar Monte Carlo metrics serve paper 003 too.

It runs seeded Monte Carlo over paper 002's radar scenario (see :mod:`fedtrack.sensors.radar`) and
report, per filter under ``"filters"``: the per-time-step RMS position error per axis
(``rms_pos_x``/``_y``/``_z``, over runs, aligned with the top-level ``t``; index 0 is before
initialization and is null), ``mean_rms_pos_straight`` / ``mean_rms_pos_turn`` (time average of
the per-step RMS 3-D position error over each segment; the straight segment starts at the first
estimate, so it includes the initialization transient), per-axis mean squared position error,
with bootstrap (over runs) standard errors (``*_se``).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from fedtrack.experiments.tables import announce, pm, print_table
from fedtrack.local_filters.radar.ekf import CV3, motion_model_3d
from fedtrack.local_filters.radar.filters import (
    EkfIEConfig,
    FilterKind,
    filter_kind,
    run_batch,
)
from fedtrack.sensors.radar import G0, RadarConfig, Trajectory, simulate

TRAIN_TAG = 0
EVAL_TAG = 1


def scenario_rng(tag: int, seed: int) -> np.random.Generator:
    """The noise stream of a (training or evaluation) set of runs."""
    return np.random.default_rng([tag, seed])


BOOTSTRAP = 200
STATE_LABELS = ("x", "vx", "y", "vy", "z", "vz")


def scenario_json(radar: RadarConfig, traj: Trajectory) -> dict[str, Any]:
    return {"rate_hz": radar.rate_hz, "sigma_range_m": radar.sigma_range,
            "sigma_azimuth_rad": radar.sigma_azimuth, "sigma_elevation_rad": radar.sigma_elevation,
            "speed_m_s": radar.speed, "turn_radius_m": radar.turn_radius,
            "turn_bank_deg": math.degrees(math.asin((radar.apex_z - radar.start[2]) / radar.turn_radius)),
            "turn_acceleration_m_s2": radar.turn_acceleration,
            "turn_acceleration_g": radar.turn_acceleration / G0,
            "straight_s": radar.straight_s, "turn_start_index": traj.turn_start, "steps": int(traj.t.shape[0])}


def _bootstrap_se(stat: Any, n: int, rng: np.random.Generator) -> float:
    """Standard error of ``stat(run_indices)`` by resampling runs."""
    vals = [stat(rng.integers(0, n, size=n)) for _ in range(BOOTSTRAP)]
    return float(np.std(vals, ddof=1))


def _squared_pos_error(err: np.ndarray) -> np.ndarray:
    """Squared 3-D position error (runs, K-1) from the first estimate on."""
    return np.sum(err ** 2, axis=-1)[:, 1:]


def _segment_mean_rms(sq: np.ndarray, idx: np.ndarray, sl: slice) -> float:
    """Time average over ``sl`` of the RMS (over runs ``idx``) position error."""
    return float(np.mean(np.sqrt(np.mean(sq[idx][:, sl], axis=0))))


def metrics(err: np.ndarray, man: np.ndarray, turn: int, rng: np.random.Generator) -> dict[str, Any]:
    """Metrics of position errors ``err`` (runs, K, 3) (NaN at index 0)."""
    sq = _squared_pos_error(err)
    t0 = turn - 1  # index of the turn start in sq

    def seg(idx: np.ndarray, sl: slice) -> float:
        return _segment_mean_rms(sq, idx, sl)

    allr = np.arange(err.shape[0])
    rms_axis = np.sqrt(np.mean(err ** 2, axis=0))
    mse_axis = np.mean(err[:, 1:] ** 2, axis=1)  # per run, per axis
    out: dict[str, Any] = {f"rms_pos_{a}": [None] + rms_axis[1:, i].tolist() for i, a in enumerate("xyz")}
    for name, sl in (("straight", slice(0, t0)), ("turn", slice(t0, None))):
        out[f"mean_rms_pos_{name}"] = seg(allr, sl)
        out[f"mean_rms_pos_{name}_se"] = _bootstrap_se(lambda i: seg(i, sl), err.shape[0], rng)
        out[f"maneuver_fraction_{name}"] = float(np.mean(man[:, 1:][:, sl]))
    out["mse_pos_axis"] = mse_axis.mean(axis=0).tolist()
    out["mse_pos_axis_se"] = (mse_axis.std(axis=0, ddof=1) / math.sqrt(err.shape[0])).tolist()
    return out


def run_filters(kinds: dict[str, FilterKind], zs: np.ndarray, radar: RadarConfig, q: float
                 ) -> dict[str, Any]:
    model = motion_model_3d(CV3, radar.T, q)
    sensor = np.asarray(radar.sensor_position, float)
    return {name: run_batch(kind, zs, radar.R, sensor, model, label=name) for name, kind in kinds.items()}


def _paired_ratio(errs: dict[str, np.ndarray], num: str, den: str, sl: slice,
                  rng: np.random.Generator) -> tuple[float, float]:
    """Ratio of segment mean-RMS errors of two filters on the same runs, with bootstrap SE."""
    sq = {k: _squared_pos_error(v) for k, v in errs.items()}

    def ratio(idx: np.ndarray) -> float:
        return _segment_mean_rms(sq[num], idx, sl) / _segment_mean_rms(sq[den], idx, sl)

    n = next(iter(sq.values())).shape[0]
    return ratio(np.arange(n)), _bootstrap_se(ratio, n, rng)


def write(result: dict[str, Any], json_path: Path) -> None:
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(result, indent=1))


def plot_x_error(t: np.ndarray, filters: dict[str, Any], turn_t: float, path: Path, title: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for name, m in filters.items():
        ax.semilogy(t[1:], m["rms_pos_x"][1:], label=name)
    ax.axvline(turn_t, color="k", ls=":", label="turn starts")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("RMS x error (m)")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def reproduce_input_estimation(runs: int, seed: int, json_path: Path, plots_dir: Path | None) -> dict:
    """Paper 002: plain CV EKF vs EKF with direct input estimation over ``runs`` runs."""
    announce(f"reproduce input-estimation: paper 002, CV EKF vs EKF with direct input estimation on the "
             f"3-D radar turn scenario, {runs} Monte Carlo runs, seed {seed}")
    wall0 = time.perf_counter()
    radar, cfg = RadarConfig(), EkfIEConfig()
    window = cfg.params.scans(radar.T)
    traj, zs = simulate(radar, runs, np.random.default_rng(seed))
    kinds = {"ekf": filter_kind("ekf", cfg), "ekf_ie": filter_kind("ekf-ie", cfg)}
    res = run_filters(kinds, zs, radar, cfg.q)
    rng = np.random.default_rng([seed, 99])
    errs = {k: r.x[..., [0, 2, 4]] - traj.pos for k, r in res.items()}
    filters = {k: metrics(errs[k], res[k].maneuver, traj.turn_start, rng) for k in kinds}
    t0 = traj.turn_start - 1
    turn_ratio = _paired_ratio(errs, "ekf_ie", "ekf", slice(t0, None), rng)
    straight_ratio = _paired_ratio(errs, "ekf_ie", "ekf", slice(0, t0), rng)
    result = {
        "paper": "002", "runs": runs, "seed": seed, "scenario": scenario_json(radar, traj),
        "config": {"q": cfg.q, "window": window, "window_s": cfg.params.window_s, "p_false_alarm": cfg.p_false_alarm,
                   "p_input": cfg.p_input, "eta_window": cfg.params.eta_window(window),
                   "eta_input": cfg.params.eta_input},
        "t": traj.t.tolist(), "filters": filters,
        "acceptance": {
            "turn_ratio_ie_over_ekf": turn_ratio[0], "turn_ratio_se": turn_ratio[1],
            "turn_ratio_at_most_one_third": turn_ratio[0] <= 1.0 / 3.0,
            "straight_ratio_ie_over_ekf": straight_ratio[0], "straight_ratio_se": straight_ratio[1],
            "straight_within_10_percent": straight_ratio[0] <= 1.1},
    }
    if plots_dir is not None:
        plots_dir.mkdir(parents=True, exist_ok=True)
        plot_x_error(traj.t, filters, traj.t[traj.turn_start], plots_dir / "fig4_x_error.png",
                      f"Paper 002 Fig. 4: x-axis RMS error ({runs} runs)")
    result["wall_time_s"] = time.perf_counter() - wall0
    write(result, json_path)
    print_summary(result)
    acc = result["acceptance"]
    print(f"  turn RMS ratio EKF-IE / EKF {pm(acc['turn_ratio_ie_over_ekf'], acc['turn_ratio_se'], 3)} "
          f"(at most 1/3: {acc['turn_ratio_at_most_one_third']}), straight ratio "
          f"{pm(acc['straight_ratio_ie_over_ekf'], acc['straight_ratio_se'], 3)}")
    return result


def print_summary(result: dict[str, Any]) -> None:
    """Position RMS on the straight and the turn segments, maneuver flags, per-axis MSE (papers 002, 003)."""
    rows = [[name, pm(f["mean_rms_pos_straight"], f["mean_rms_pos_straight_se"]),
             pm(f["mean_rms_pos_turn"], f["mean_rms_pos_turn_se"]), f"{f['maneuver_fraction_turn']:.2f}",
             " / ".join(f"{v:.1f}" for v in f["mse_pos_axis"])]
            for name, f in result["filters"].items()]
    print_table(f"paper {result['paper']}: position error, {result['runs']} runs (seed {result['seed']})",
                ["filter", "RMS straight [m]", "RMS turn [m]", "maneuver flag (turn)", "MSE x / y / z [m^2]"], rows)
