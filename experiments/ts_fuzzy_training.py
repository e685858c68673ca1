"""``fedtrack train ts-fuzzy``: simulate radar runs, build TS training data, identify by GA + RLS.

Training data (paper 003 section 2.2, with run-time inputs per the errata): the plain CV EKF
(``q`` = 1 (m/s^2)^2, as in ``fedtrack replay --algorithm ekf``) tracks paper 002's radar
scenario; each step after the first second gives one sample, input = the smoothed Cartesian
innovation (3), output = the EKF's position and velocity error ``truth - x(k|k)`` (6).
Training noise comes from ``numpy.random.default_rng([TRAIN_TAG, seed])``; evaluation uses
``EVAL_TAG``, so training and evaluation streams never coincide for any pair of seeds.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from fedtrack.config import ConfigError
from fedtrack.local_filters.radar.ekf import CV3, motion_model_3d
from fedtrack.local_filters.radar.filters import EkfConfig
from fedtrack.local_filters.radar.ts_fuzzy import GAParams, TSModel, identify, save_model
from fedtrack.local_filters.radar.ts_fuzzy_ekf import TAU_S, error_components, ts_init, ts_step
from fedtrack.progress import progress_bar
from fedtrack.sensors.radar import RadarConfig, simulate

TRAIN_TAG = 0
EVAL_TAG = 1
SKIP_STEPS = 50  # the first second (two-point initialization transient) is left out


def scenario_rng(tag: int, seed: int) -> np.random.Generator:
    """The noise stream of a (training or evaluation) set of runs."""
    return np.random.default_rng([tag, seed])


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
    ap = argparse.ArgumentParser(prog="fedtrack train ts-fuzzy", description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20, help="simulated training runs (default 20)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", required=True, help="output model file (.npz)")
    ap.add_argument("--population", type=int, default=GAParams.population)
    ap.add_argument("--generations", type=int, default=GAParams.generations)
    ap.add_argument("--max-rules", type=int, default=GAParams.max_rules)
    args = ap.parse_args(argv)
    if args.runs < 1:
        ap.error("--runs must be >= 1")
    out = Path(args.out)
    if not out.parent.is_dir():
        raise ConfigError(f"--out: directory {out.parent} does not exist")
    ga = GAParams(population=args.population, generations=args.generations, max_rules=args.max_rules)
    ga.validate()
    model, summary = train(args.runs, args.seed, ga)
    save_model(out, model, **_model_meta(args.runs, args.seed, EkfConfig.q, summary))
    print(f"wrote {out}: {summary['rules']} rules, fitness {summary['fitness']:.4f}, "
          f"validation MSE (standardized) GA {summary['ga_val_mse']:.4f} -> RLS {summary['rls_val_mse']:.4f}, "
          f"{summary['samples']} samples, wall {summary['train_wall_s']:.1f} s, CPU {summary['train_cpu_s']:.1f} s")
    return 0
