"""Micro-benchmark of the estimation core: one CV Kalman scan-update over Monte Carlo runs.

Three implementations of the same maths (``fedtrack.local_filters.linear.kalman``: predict, then the
Joseph-form update) on the same seeded data, paper 004 scenario 1 measured by one
position sensor:

* ``batched``: ``predict``/``update`` once per scan on arrays ``(runs, 4)``;
* ``loop``: a plain Python loop over runs calling the same functions on ``(4,)`` arrays;
* ``filterpy``: ``filterpy.kalman.KalmanFilter`` per run (only if it is importable; it
  forms ``S^-1`` explicitly, so it agrees to round-off, not bit for bit).

The methods are timed in alternating rounds (the machine is shared) and reported per
scan-update (one run, one scan), with the per-round ratio to ``batched``.
"""

from __future__ import annotations

import importlib.util
import time
from typing import Any, Callable, NamedTuple

import numpy as np

from fedtrack.local_filters.linear.kalman import GaussianState, predict, update
from fedtrack.local_filters.linear.models import LinearModel, cv_model
from fedtrack.sensors.scenarios import DEFAULT_R, paper004_scenario, simulate_positions, simulate_truth

INIT_VEL_VAR = 500.0 ** 2  # m^2/s^2, as the fusion trackers' initial_velocity_std default


class KfData(NamedTuple):
    """Measurements ``z (runs, K, 2)`` and the first-scan state ``x0 (runs, 4)``, ``P0 (4, 4)``."""

    z: np.ndarray
    x0: np.ndarray
    P0: np.ndarray


def make_data(runs: int, seed: int) -> tuple[LinearModel, np.ndarray, KfData]:
    """Seeded scenario-1 measurements of ``runs`` Monte Carlo runs, one sensor with the default R."""
    scenario = paper004_scenario(1)
    rng = np.random.default_rng(seed)
    truth = simulate_truth(scenario, runs, rng)
    z = simulate_positions(truth, DEFAULT_R[None], rng)[:, :, 0]
    x0 = np.zeros((runs, 4))
    x0[:, [0, 2]] = z[:, 0]
    P0 = np.diag([DEFAULT_R[0, 0], INIT_VEL_VAR, DEFAULT_R[1, 1], INIT_VEL_VAR])
    P0[0, 2] = P0[2, 0] = DEFAULT_R[0, 1]
    return cv_model(scenario.T, scenario.q), DEFAULT_R, KfData(z, x0, P0)


def run_batched(model: LinearModel, R: np.ndarray, data: KfData) -> GaussianState:
    """All runs at once; returns the final posteriors ``(runs, 4)``, ``(runs, 4, 4)``."""
    state = GaussianState(data.x0, np.broadcast_to(data.P0, data.x0.shape + (4,)).copy())
    for k in range(1, data.z.shape[1]):
        state = predict(state, model.F, model.Q)  # paper 004 eqs. (5), (7)
        state, _ = update(state, data.z[:, k], model.H, R)  # eqs. (6), (8) with N = 1, Joseph form
    return state


def run_loop(model: LinearModel, R: np.ndarray, data: KfData) -> GaussianState:
    """The same maths, one run at a time in a Python loop."""
    xs, Ps = [], []
    for m in range(data.z.shape[0]):
        state = GaussianState(data.x0[m], data.P0.copy())
        for k in range(1, data.z.shape[1]):
            state = predict(state, model.F, model.Q)
            state, _ = update(state, data.z[m, k], model.H, R)
        xs.append(state.x)
        Ps.append(state.P)
    return GaussianState(np.stack(xs), np.stack(Ps))


def filterpy_available() -> bool:
    return importlib.util.find_spec("filterpy") is not None


def run_filterpy(model: LinearModel, R: np.ndarray, data: KfData) -> GaussianState:
    """``filterpy.kalman.KalmanFilter`` per run (its update is the Joseph form too)."""
    from filterpy.kalman import KalmanFilter

    xs, Ps = [], []
    for m in range(data.z.shape[0]):
        kf = KalmanFilter(dim_x=4, dim_z=2)
        kf.F, kf.Q, kf.H, kf.R = model.F, model.Q, model.H, R
        kf.x, kf.P = data.x0[m].copy(), data.P0.copy()
        for k in range(1, data.z.shape[1]):
            kf.predict()
            kf.update(data.z[m, k])
        xs.append(np.asarray(kf.x).reshape(4))
        Ps.append(np.asarray(kf.P))
    return GaussianState(np.stack(xs), np.stack(Ps))


def max_relative_diff(a: GaussianState, b: GaussianState) -> float:
    """Largest ``|a - b| / max(1, |b|)`` over means and covariances."""
    return float(max(np.max(np.abs(a.x - b.x) / np.maximum(1.0, np.abs(b.x))),
                     np.max(np.abs(a.P - b.P) / np.maximum(1.0, np.abs(b.P)))))


def bench_kf(runs: int, loop_runs: int, rounds: int, seed: int,
             tick: Callable[[], None] = lambda: None) -> dict[str, Any]:
    """Time the implementations in ``rounds`` alternating rounds; per-update times and ratios.

    ``batched`` uses ``runs`` runs, the per-run loops the first ``loop_runs`` of them.
    """
    model, R, data = make_data(runs, seed)
    small = KfData(data.z[:loop_runs], data.x0[:loop_runs], data.P0)
    scans = data.z.shape[1] - 1
    methods: dict[str, tuple[Callable[..., GaussianState], KfData]] = {
        "batched": (run_batched, data), "loop": (run_loop, small)}
    if filterpy_available():
        methods["filterpy"] = (run_filterpy, small)
    per_update: dict[str, list[float]] = {name: [] for name in methods}
    results: dict[str, GaussianState] = {}
    for _ in range(rounds):
        for name, (fn, d) in methods.items():
            t0 = time.perf_counter()
            results[name] = fn(model, R, d)
            per_update[name].append((time.perf_counter() - t0) / (d.z.shape[0] * scans))
        tick()
    base = np.asarray(per_update["batched"])
    out: dict[str, Any] = {"runs_batched": runs, "runs_loop": loop_runs, "scans": scans, "rounds": rounds,
                           "seed": seed, "methods": {}}
    reference = GaussianState(results["batched"].x[:loop_runs], results["batched"].P[:loop_runs])
    for name, times in per_update.items():
        t = np.asarray(times)
        ratio = t / base
        out["methods"][name] = {
            "us_per_update_median": float(np.median(t) * 1e6),
            "ratio_to_batched_median": float(np.median(ratio)),
            "ratio_to_batched_min": float(ratio.min()),
            "ratio_to_batched_max": float(ratio.max()),
            "max_rel_diff_to_batched": 0.0 if name == "batched" else max_relative_diff(results[name], reference),
        }
    if "filterpy" not in methods:
        out["methods"]["filterpy"] = "not installed"
    return out
