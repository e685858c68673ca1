"""``fedtrack bench kernels``: single steps and batches of the estimation core, side by side.

Stone Soup runs its own ``ConstantVelocity`` (continuous white-noise) transition model, whose
cost per step is that of any linear-Gaussian model.

* CV Kalman step (predict + update, one target, 2-D position measurement): fedtrack's
  ``predict``/``update``, FilterPy's ``KalmanFilter``, Stone Soup's ``KalmanPredictor`` /
  ``KalmanUpdater``, and a minimal plain-numpy floor written here.
* Radar EKF step (3-D CV, range/azimuth/elevation): fedtrack's ``ekf_step``, FilterPy's
  ``ExtendedKalmanFilter``, Stone Soup's ``ExtendedKalmanUpdater`` with
  ``CartesianToElevationBearingRange``.
* Batched CV Kalman steps at 1, 100 and 10,000 targets: target-steps per second.
* PDA scan of one CV track with 1, 5 and 20 detections in its gate: fedtrack's PDA-AI
  functions without amplitudes (plain PDA) against Stone Soup's ``PDAHypothesiser`` and
  ``PDAUpdater`` (``pda_vs_stonesoup`` is the 20-detection ratio).

Every library runs the same model and data; each timing is the median of interleaved rounds,
and ratios are fedtrack's time over the other's, measured in the same run. FilterPy and Stone
Soup come from the ``bench`` extra; when missing, their entries say so.
"""

from __future__ import annotations

import importlib.util
import time
from datetime import datetime, timedelta
from typing import Any, Callable

import numpy as np

from fedtrack.local_filters.linear.kalman import GaussianState, predict, update
from fedtrack.local_filters.linear.models import cv_model
from fedtrack.local_filters.radar.ekf import CV3, ekf_step, motion_model_3d, radar_h, radar_jacobian

Q_CV, R_POS = 0.25, np.array([[100.0, 5.0], [5.0, 100.0]])
R_RADAR = np.diag([10.0**2, 0.002**2, 0.002**2])
SENSOR = np.array([0.0, 0.0, 0.0])


def available(module: str) -> bool:
    return importlib.util.find_spec(module) is not None


def per_step(run: Callable[[int], Any], steps: int, rounds: int) -> float:
    """Median over ``rounds`` of the seconds per step of ``run(steps)``."""
    return side_by_side({"run": run}, steps, rounds)["run"]


def side_by_side(runners: dict[str, Callable[[int], Any]], steps: int, rounds: int) -> dict[str, float]:
    """Per runner, the median over ``rounds`` of the seconds per step of ``run(steps)``, the
    runners taking turns round by round so that the shared machine's load drifts over all alike."""
    times: dict[str, list[float]] = {name: [] for name in runners}
    for _ in range(rounds):
        for name, run in runners.items():
            t0 = time.perf_counter()
            run(steps)
            times[name].append((time.perf_counter() - t0) / steps)
    return {name: float(np.median(values)) for name, values in times.items()}


def cv_data(steps: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(steps, dtype=float)
    return np.column_stack([100 + 10 * t, -50 + 5 * t]) + rng.multivariate_normal([0, 0], R_POS, steps)


def cv_runners(steps: int) -> dict[str, Callable[[int], Any]]:
    model = cv_model(1.0, Q_CV)
    zs = cv_data(steps)
    x0, P0 = np.array([100.0, 0.0, -50.0, 0.0]), np.diag([100.0, 1e4, 100.0, 1e4])

    def fedtrack_run(n: int) -> None:
        s = GaussianState(x0, P0)
        for k in range(n):
            s, _ = update(predict(s, model.F, model.Q), zs[k], model.H, R_POS)

    F, Q, H = model.F, model.Q, model.H
    eye = np.eye(4)

    def floor_run(n: int) -> None:
        x, P = x0, P0
        for k in range(n):
            x = F @ x
            P = F @ P @ F.T + Q
            S = H @ P @ H.T + R_POS
            K = np.linalg.solve(S, H @ P).T
            x = x + K @ (zs[k] - H @ x)
            A = eye - K @ H
            P = A @ P @ A.T + K @ R_POS @ K.T

    runners: dict[str, Callable[[int], Any]] = {"fedtrack": fedtrack_run, "numpy_floor": floor_run}
    if available("filterpy"):
        from filterpy.kalman import KalmanFilter

        def filterpy_run(n: int) -> None:
            kf = KalmanFilter(dim_x=4, dim_z=2)
            kf.F, kf.Q, kf.H, kf.R, kf.x, kf.P = F, Q, H, R_POS, x0.copy(), P0.copy()
            for k in range(n):
                kf.predict()
                kf.update(zs[k])
        runners["filterpy"] = filterpy_run
    if available("stonesoup"):
        runners["stonesoup"] = stonesoup_cv(zs, x0, P0)
    return runners


def stonesoup_cv(zs: np.ndarray, x0: np.ndarray, P0: np.ndarray) -> Callable[[int], Any]:
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.transition.linear import CombinedLinearGaussianTransitionModel, ConstantVelocity
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.types.detection import Detection
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.state import GaussianState as SSState
    from stonesoup.updater.kalman import KalmanUpdater

    transition = CombinedLinearGaussianTransitionModel([ConstantVelocity(Q_CV), ConstantVelocity(Q_CV)])
    measurement = LinearGaussian(ndim_state=4, mapping=(0, 2), noise_covar=R_POS)
    predictor, updater = KalmanPredictor(transition), KalmanUpdater(measurement)
    t0 = datetime(2026, 1, 1)

    def run(n: int) -> None:
        state = SSState(x0.reshape(-1, 1), P0, timestamp=t0)
        for k in range(n):
            ts = t0 + timedelta(seconds=k + 1)
            pred = predictor.predict(state, timestamp=ts)
            det = Detection(zs[k].reshape(-1, 1), timestamp=ts, measurement_model=measurement)
            state = updater.update(SingleHypothesis(pred, det))
    return run


def radar_data(steps: int, seed: int = 2) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(steps, dtype=float) * 0.5
    pos = np.column_stack([3000 + 100 * t, 2000 - 50 * t, np.full(steps, 800.0)])
    from fedtrack.local_filters.radar.measurement import polar_from_cartesian
    return polar_from_cartesian(pos - SENSOR) + rng.multivariate_normal(np.zeros(3), R_RADAR, steps)


def ekf_runners(steps: int) -> dict[str, Callable[[int], Any]]:
    model = motion_model_3d(CV3, 0.5, 1.0)
    zs = radar_data(steps)
    x0 = np.array([3000.0, 100.0, 2000.0, -50.0, 800.0, 0.0])
    P0 = np.diag([100.0, 400.0, 100.0, 400.0, 100.0, 400.0])

    def fedtrack_run(n: int) -> None:
        s = GaussianState(x0, P0)
        for k in range(n):
            s = ekf_step(s, zs[k], R_RADAR, model, SENSOR).state

    runners: dict[str, Callable[[int], Any]] = {"fedtrack": fedtrack_run}
    if available("filterpy"):
        from filterpy.kalman import ExtendedKalmanFilter

        def hx(x: np.ndarray) -> np.ndarray:
            return radar_h(x, model, SENSOR)

        def jac(x: np.ndarray) -> np.ndarray:
            return radar_jacobian(x, model, SENSOR)

        def filterpy_run(n: int) -> None:
            ekf = ExtendedKalmanFilter(dim_x=6, dim_z=3)
            ekf.F, ekf.Q, ekf.R, ekf.x, ekf.P = model.F, model.Q, R_RADAR, x0.copy(), P0.copy()
            for k in range(n):
                ekf.predict()
                ekf.update(zs[k], jac, hx)
        runners["filterpy"] = filterpy_run
    if available("stonesoup"):
        runners["stonesoup"] = stonesoup_ekf(zs, x0, P0, model)
    return runners


def stonesoup_ekf(zs: np.ndarray, x0: np.ndarray, P0: np.ndarray, model: Any) -> Callable[[int], Any]:
    from stonesoup.models.measurement.nonlinear import CartesianToElevationBearingRange
    from stonesoup.models.transition.linear import CombinedLinearGaussianTransitionModel, ConstantVelocity
    from stonesoup.predictor.kalman import ExtendedKalmanPredictor
    from stonesoup.types.detection import Detection
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.state import GaussianState as SSState
    from stonesoup.updater.kalman import ExtendedKalmanUpdater

    transition = CombinedLinearGaussianTransitionModel([ConstantVelocity(1.0)] * 3)
    # Stone Soup orders the measurement elevation, bearing, range
    measurement = CartesianToElevationBearingRange(ndim_state=6, mapping=(0, 2, 4),
                                                   noise_covar=np.diag(np.diag(R_RADAR)[::-1]))
    predictor, updater = ExtendedKalmanPredictor(transition), ExtendedKalmanUpdater(measurement)
    zss = zs[:, ::-1].copy()
    t0 = datetime(2026, 1, 1)

    def run(n: int) -> None:
        state = SSState(x0.reshape(-1, 1), P0, timestamp=t0)
        for k in range(n):
            ts = t0 + timedelta(seconds=0.5 * (k + 1))
            pred = predictor.predict(state, timestamp=ts)
            det = Detection(zss[k].reshape(-1, 1), timestamp=ts, measurement_model=measurement)
            state = updater.update(SingleHypothesis(pred, det))
    return run


def batched_rate(targets: int, steps: int, rounds: int) -> float:
    """fedtrack target-steps per second: ``steps`` predict+update steps of ``targets`` tracks at once."""
    model = cv_model(1.0, Q_CV)
    rng = np.random.default_rng(3)
    zs = rng.normal(size=(steps, targets, 2)) * 10
    x0 = np.zeros((targets, 4))
    P0 = np.broadcast_to(np.diag([100.0, 1e4, 100.0, 1e4]), (targets, 4, 4)).copy()

    def run(n: int) -> None:
        s = GaussianState(x0, P0)
        for k in range(n):
            s, _ = update(predict(s, model.F, model.Q), zs[k], model.H, R_POS)
    return targets / per_step(run, steps, rounds)


def imm_runners(steps: int) -> dict[str, Callable[[int], Any]]:
    """13-model FSIMM step (paper 000's mode set, one target): fedtrack's ``step`` against
    FilterPy's ``IMMEstimator`` over 13 Kalman filters whose control input is each mode's
    acceleration (``B = G a_m``, ``u = 1``), with the same transition matrix and measurements."""
    from fedtrack.local_filters.imm.config import IMMConfig
    from fedtrack.local_filters.imm.filter import FSIMM, initial_state, mode_inputs, step

    cfg = IMMConfig()
    bank, th = cfg.bank(), cfg.thresholds()
    model = cv_model(1.0, cfg.q)
    inputs = mode_inputs(model, bank.acc)
    zs = cv_data(steps, seed=4)
    x0, P0 = np.array([100.0, 0.0, -50.0, 0.0]), np.diag([100.0, 1e4, 100.0, 1e4])

    def fedtrack_run(n: int) -> None:
        s = initial_state(bank, FSIMM, 0, x0[None], P0[None])
        for k in range(n):
            s, _ = step(bank, FSIMM, s, model, zs[k][None], R_POS, th, bank.Pi)

    runners: dict[str, Callable[[int], Any]] = {"fedtrack": fedtrack_run}
    if available("filterpy"):
        from filterpy.kalman import IMMEstimator, KalmanFilter

        def filterpy_run(n: int) -> None:
            filters = []
            for m in range(bank.size):
                kf = KalmanFilter(dim_x=4, dim_z=2, dim_u=1)
                kf.F, kf.Q, kf.H, kf.R = model.F, model.Q, model.H, R_POS
                kf.B, kf.x, kf.P = inputs[m][:, None], x0.copy(), P0.copy()
                filters.append(kf)
            imm = IMMEstimator(filters, np.full(bank.size, 1.0 / bank.size), bank.Pi)
            u = np.ones(1)
            for k in range(n):
                imm.predict(u)
                imm.update(zs[k])
        runners["filterpy"] = filterpy_run
    return runners


PDA_CLUTTER, PDA_PD = 1e-4, 0.9


def pda_runners(steps: int, detections: int) -> dict[str, Callable[[int], Any]]:
    """One PDA scan of one CV track (predict, gate, association probabilities, update) with
    ``detections`` detections in its gate: fedtrack's PDA-AI functions with no amplitude (plain
    PDA, eqs (4)-(5)) against Stone Soup's ``PDAHypothesiser`` + ``PDAUpdater`` on the same data."""
    from fedtrack.local_filters.pda.association import constants, gate, pda_ai_hypothesise, pda_update
    from fedtrack.local_filters.pda.config import PDAParams

    model = cv_model(1.0, Q_CV)
    c = constants(PDAParams(pd=PDA_PD, clutter_density=PDA_CLUTTER))
    rng = np.random.default_rng(5)
    truth = cv_data(steps, seed=6)
    scans = truth[:, None, :] + 4.0 * rng.standard_normal((steps, detections, 2))  # all inside the gate
    x0, P0 = np.array([100.0, 10.0, -50.0, 5.0]), np.diag([100.0, 4.0, 100.0, 4.0])
    no_amplitude = np.zeros((1, detections))
    valid = np.ones((1, detections), dtype=bool)

    def fedtrack_run(n: int) -> None:
        s = GaussianState(x0[None], P0[None])
        for k in range(n):
            pred = predict(s, model.F, model.Q)
            g = gate(pred, scans[k][None], valid, model.H, R_POS, c)
            s = pda_update(pred, g, pda_ai_hypothesise(g, no_amplitude, c), c)

    runners: dict[str, Callable[[int], Any]] = {"fedtrack": fedtrack_run}
    if available("stonesoup"):
        runners["stonesoup"] = stonesoup_pda(scans, x0, P0, c.pg)
    return runners


def stonesoup_pda(scans: np.ndarray, x0: np.ndarray, P0: np.ndarray, pg: float) -> Callable[[int], Any]:
    from stonesoup.hypothesiser.probability import PDAHypothesiser
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.transition.linear import CombinedLinearGaussianTransitionModel, ConstantVelocity
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.types.detection import Detection
    from stonesoup.types.state import GaussianState as SSState
    from stonesoup.types.track import Track
    from stonesoup.updater.kalman import KalmanUpdater
    from stonesoup.updater.probability import PDAUpdater

    transition = CombinedLinearGaussianTransitionModel([ConstantVelocity(Q_CV), ConstantVelocity(Q_CV)])
    measurement = LinearGaussian(ndim_state=4, mapping=(0, 2), noise_covar=R_POS)
    predictor = KalmanPredictor(transition)
    hypothesiser = PDAHypothesiser(predictor, KalmanUpdater(measurement), clutter_spatial_density=PDA_CLUTTER,
                                   prob_detect=PDA_PD, prob_gate=pg)
    updater = PDAUpdater(measurement)
    t0 = datetime(2026, 1, 1)

    def run(n: int) -> None:
        track = Track([SSState(x0.reshape(-1, 1), P0, timestamp=t0)])
        for k in range(n):
            ts = t0 + timedelta(seconds=k + 1)
            dets = {Detection(z.reshape(-1, 1), timestamp=ts, measurement_model=measurement) for z in scans[k]}
            track.append(updater.update(hypothesiser.hypothesise(track, dets, ts)))
    return run


def bench_kernels(quick: bool = False) -> dict[str, Any]:
    steps, rounds = (200, 3) if quick else (2000, 7)
    out: dict[str, Any] = {"seconds_per_step": {}, "ratios": {}, "missing": []}
    pda = [(f"pda{m}", pda_runners(steps // 10, m), steps // 10) for m in (1, 5, 20)]
    for name, runners, n_steps in (("kf", cv_runners(steps), steps), ("ekf", ekf_runners(steps), steps),
                                   ("imm13", imm_runners(steps // 10), steps // 10), *pda):
        times = side_by_side(runners, n_steps, rounds)
        out["seconds_per_step"][name] = times
        for other in ("filterpy", "stonesoup", "numpy_floor"):
            if other in times:
                out["ratios"][f"{name}_vs_{other}"] = times["fedtrack"] / times[other]
    if "pda20_vs_stonesoup" in out["ratios"]:
        out["ratios"]["pda_vs_stonesoup"] = out["ratios"]["pda20_vs_stonesoup"]  # the key: 20 detections
    out["missing"] = [m for m in ("filterpy", "stonesoup") if not available(m)]
    out["batched_target_steps_per_s"] = {str(n): batched_rate(n, max(steps // (1 + n // 100), 5), rounds)
                                         for n in (1, 100, 10_000)}
    return out
