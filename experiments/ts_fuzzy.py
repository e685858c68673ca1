"""Paper 003: fedtrack train ts-fuzzy and fedtrack reproduce ts-fuzzy.

Training: simulate radar runs, build TS training data, identify by GA + RLS.
Training data (paper 003 section 2.2, with run-time inputs per the errata): the plain CV EKF
(``q`` = 1 (m/s^2)^2, as in ``fedtrack replay --algorithm ekf``) tracks paper 002's radar
scenario; each step after the first second gives one sample, input = the smoothed Cartesian
innovation (3), output = the EKF's position and velocity error ``truth - x(k|k)`` (6).
Training noise comes from ``numpy.random.default_rng([TRAIN_TAG, seed])``; evaluation uses
``EVAL_TAG``, so training and evaluation streams never coincide for any pair of seeds.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from fedtrack.config import ConfigError, seed_number
from fedtrack.experiments.input_estimation import (
    EVAL_TAG,
    STATE_LABELS,
    TRAIN_TAG,
    metrics,
    plot_x_error,
    print_summary,
    run_filters,
    scenario_json,
    scenario_rng,
    write,
)
from fedtrack.experiments.tables import announce
from fedtrack.jsonl import check_output
from fedtrack.local_filters.radar.ekf import CV3, motion_model_3d
from fedtrack.local_filters.radar.filters import (
    MODEL_ENV,
    EkfConfig,
    EkfTsFuzzyConfig,
    filter_kind,
    load_compatible_model,
)
from fedtrack.local_filters.radar.ts_fuzzy import GAParams, TSModel, identify, load_model, save_model
from fedtrack.local_filters.radar.ts_fuzzy_ekf import TAU_S, error_components, ts_init, ts_step
from fedtrack.progress import progress_bar
from fedtrack.sensors.radar import RadarConfig, simulate

TS_TRAIN_RUNS = 20
SKIP_STEPS = 50  # the first second (two-point initialization transient) is left out


def training_data(runs: int, seed: int, q: float = EkfConfig.q,
                  radar: RadarConfig = RadarConfig()) -> tuple[np.ndarray, np.ndarray]:
    """Inputs (m, 3) and EKF errors (m, 6) from ``runs`` simulated runs (training stream)."""
    traj, zs = simulate(radar, runs, scenario_rng(TRAIN_TAG, seed))
    model = motion_model_3d(CV3, radar.T, q)
    truth = traj.state(CV3)[:, error_components(model)]
    sensor = np.asarray(radar.sensor_position, float)
    state = ts_init(zs[:, 0], zs[:, 1], radar.R, model, sensor)
    X, Y = [], []
    K = zs.shape[1]
    with progress_bar(K - 2, "simulate training runs") as bar:
        for k in range(2, K):
            state = ts_step(state, zs[:, k], radar.R, model, sensor)
            if k >= SKIP_STEPS:
                X.append(state.ema)
                Y.append(truth[k] - state.filt.x[:, error_components(model)])
            bar.update()
    return np.concatenate(X), np.concatenate(Y)


def train(runs: int, seed: int, ga: GAParams, q: float = EkfConfig.q) -> tuple[TSModel, dict[str, float]]:
    """Simulate, then identify (GA with progress, then RLS). Summary includes wall and CPU time."""
    wall0, cpu0 = time.perf_counter(), time.process_time()
    X, Y = training_data(runs, seed, q)
    with progress_bar(ga.generations + 1, "GA + RLS") as bar:
        model, summary = identify(X, Y, ga, np.random.default_rng([TRAIN_TAG, seed, 1]), bar.update)
    summary.update(samples=int(X.shape[0]), train_wall_s=time.perf_counter() - wall0,
                   train_cpu_s=time.process_time() - cpu0)
    return model, summary


def _model_meta(runs: int, seed: int, q: float, summary: dict[str, float]) -> dict[str, float | int]:
    return {"train_tag": TRAIN_TAG, "train_seed": seed, "train_runs": runs, "q": q, "tau_s": TAU_S,
            **summary}


def main(argv: list[str]) -> int:
    """``fedtrack train ts-fuzzy --runs N --seed S --out MODEL.npz [GA options]``."""
    ap = argparse.ArgumentParser(prog="fedtrack train ts-fuzzy", description="train the TS-fuzzy error model of paper 003: simulate radar runs, identify by GA + RLS")
    ap.add_argument("--runs", type=int, default=20, help="simulated training runs (default 20)")
    ap.add_argument("--seed", type=seed_number, default=1, help="seed of the training runs and the GA (default: %(default)s)")
    ap.add_argument("--out", required=True, help="output model file (.npz)")
    ap.add_argument("--population", type=int, default=GAParams.population,
                    help="GA population size (default: %(default)s)")
    ap.add_argument("--generations", type=int, default=GAParams.generations,
                    help="GA generations (default: %(default)s)")
    ap.add_argument("--max-rules", type=int, default=GAParams.max_rules,
                    help="largest number of fuzzy rules the GA may choose (default: %(default)s)")
    args = ap.parse_args(argv)
    if args.runs < 1:
        ap.error("--runs must be >= 1")
    out = check_output(args.out)
    ga = GAParams(population=args.population, generations=args.generations, max_rules=args.max_rules)
    try:
        ga.validate()
    except ConfigError as exc:  # named as the option (was "population: must be >= 1", a key of no file; tour61)
        ap.error(f"--{str(exc).replace('_', '-')}")
    model, summary = train(args.runs, args.seed, ga)
    save_model(out, model, **_model_meta(args.runs, args.seed, EkfConfig.q, summary))
    print(f"wrote {out}: {summary['rules']} rules, fitness {summary['fitness']:.4f}, "
          f"validation MSE (standardized) GA {summary['ga_val_mse']:.4f} -> RLS {summary['rls_val_mse']:.4f}, "
          f"{summary['samples']} samples, wall {summary['train_wall_s']:.1f} s, CPU {summary['train_cpu_s']:.1f} s")
    return 0


def _plot_state_sq(t: np.ndarray, sq: dict[str, np.ndarray], path: Path, runs: int) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 2, figsize=(10, 8), sharex=True)
    for c, label in enumerate(STATE_LABELS):
        ax = axes[c // 2, c % 2]
        for name, s in sq.items():
            ax.semilogy(t[1:], s[1:, c], label=name, lw=0.8)
        ax.set_ylabel(f"mean sq. error {label}" + (" (m/s)^2" if label.startswith("v") else " (m^2)"))
        ax.grid(True, which="both", alpha=0.3)
    axes[0, 0].legend()
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    fig.suptitle(f"Paper 003 Fig. 3: squared error per state, mean over {runs} held-out runs")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def reproduce_ts_fuzzy(runs: int, seed: int, json_path: Path, plots_dir: Path | None,
                       model: Path | None = None) -> dict:
    """Paper 003: plain CV EKF vs TS-fuzzy compensated EKF on held-out runs.

    The model is loaded from ``model`` (``--model``), else from ``$FEDTRACK_TS_FUZZY_MODEL`` if
    set; otherwise it is trained here (``TS_TRAIN_RUNS`` runs, paper GA settings) on the training
    stream of ``seed``, which takes minutes. Evaluation runs use the evaluation stream, disjoint
    from every training stream.
    """
    wall0 = time.perf_counter()
    radar, cfg = RadarConfig(), EkfTsFuzzyConfig()
    named = "--model" if model is not None else f"${MODEL_ENV}"  # where the model file was given
    model = model or (Path(os.environ[MODEL_ENV]) if os.environ.get(MODEL_ENV) else None)
    what = f"CV EKF vs TS-fuzzy compensated EKF on the 3-D radar turn scenario, {runs} runs, seed {seed}"
    if model is not None:
        if not model.is_file():
            raise ConfigError(f"{named}: {model} does not exist")
        announce(f"reproduce ts-fuzzy: paper 003, {what}; model {model}")
        ts = load_compatible_model(model, named)
        training = {"source": str(model), **{k: v.item() for k, v in load_model(model)[1].items()}}
    else:
        ga = GAParams()
        announce(f"reproduce ts-fuzzy: paper 003, {what}.\n"
                 f"No model given (--model PATH or ${MODEL_ENV}): training a model: {ga.generations} generations "
                 f"of {ga.population} (GA, then RLS) on {TS_TRAIN_RUNS} simulated runs; this takes minutes. "
                 "'fedtrack train ts-fuzzy --out MODEL.npz' saves a model for --model.")
        ts, summary = train(TS_TRAIN_RUNS, seed, ga, cfg.q)
        announce(f"trained: {summary['rules']} rules in {summary['train_wall_s']:.0f} s; evaluating")
        training = {"source": "trained by this command", "train_tag": TRAIN_TAG, "train_seed": seed,
                    "train_runs": TS_TRAIN_RUNS, **summary}
    traj, zs = simulate(radar, runs, scenario_rng(EVAL_TAG, seed))
    kinds = {"ekf": filter_kind("ekf", cfg), "ekf_tsfuzzy": filter_kind("ekf-tsfuzzy", cfg, ts)}
    res = run_filters(kinds, zs, radar, cfg.q)
    rng = np.random.default_rng([seed, 98])
    truth = traj.state(CV3)
    filters = {k: metrics(r.x[..., [0, 2, 4]] - traj.pos, r.maneuver, traj.turn_start, rng)
               for k, r in res.items()}
    sq = {k: np.mean((r.x - truth) ** 2, axis=0) for k, r in res.items()}
    for k in kinds:
        filters[k]["mse_state"] = dict(zip(STATE_LABELS, np.nanmean(sq[k], axis=0).tolist()))
    better = [a < b for a, b in zip(filters["ekf_tsfuzzy"]["mse_pos_axis"], filters["ekf"]["mse_pos_axis"])]
    result = {
        "paper": "003", "runs": runs, "seed": seed, "scenario": scenario_json(radar, traj),
        "training": training,
        "evaluation_seeds": {"stream": f"numpy default_rng([{EVAL_TAG}, {seed}])", "runs": runs,
                             "disjoint_from_training": True,
                             "note": f"training uses default_rng([{TRAIN_TAG}, seed]); the tags differ"},
        "t": traj.t.tolist(), "filters": filters,
        "acceptance": {"tsfuzzy_lower_mse_each_axis": all(better), "per_axis": better},
    }
    if plots_dir is not None:
        plots_dir.mkdir(parents=True, exist_ok=True)
        _plot_state_sq(traj.t, sq, plots_dir / "fig3_squared_errors.png", runs)
        plot_x_error(traj.t, filters, traj.t[traj.turn_start], plots_dir / "ts_fuzzy_x_error.png",
                      f"EKF vs TS-fuzzy compensated EKF: x-axis RMS error ({runs} runs)")
    result["wall_time_s"] = time.perf_counter() - wall0
    write(result, json_path)
    print_summary(result)
    print(f"  model: {training['source']}; TS-fuzzy MSE below the EKF's on every axis: "
          f"{result['acceptance']['tsfuzzy_lower_mse_each_axis']}")
    return result
