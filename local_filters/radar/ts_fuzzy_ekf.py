"""EKF with Takagi-Sugeno fuzzy error compensation (paper 003, section 2.2).

Paper 003 trains on "noise-free minus noisy measurement", which needs ground truth at run time
(errata). The model inputs here are run-time quantities only: the Cartesian innovation
``c_k = sensor + cartesian(z_k) - position(x(k|k-1))`` (converted measurement minus predicted
position), smoothed by an exponential moving average with time constant ``TAU_S`` = 0.3 s
(``e <- e + a (c - e)``, ``a = 1 - exp(-T/tau)``), 3 inputs as in the paper's Figure 2. A CV
EKF lagging a maneuver shows a persistent mean innovation, so the smoothed innovation predicts
the EKF's error. The model outputs the EKF's error ``truth - x(k|k)`` in position and velocity
(6 outputs, one TS consequent per output on a shared premise). The correction is applied to the
reported estimate only (``x_comp = x(k|k) + f(e_k)``); the EKF itself runs unchanged, so the
inputs at run time are distributed as in training. The reported covariance is the EKF's.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from fedtrack.local_filters.linear.kalman import GaussianState
from fedtrack.local_filters.radar.ekf import (
    MotionModel3D,
    ekf_step,
    position,
    two_point_init,
)
from fedtrack.local_filters.radar.measurement import cartesian_from_polar
from fedtrack.local_filters.radar.ts_fuzzy import TSModel, predict

# Smoothing time constant of the innovation feature, s: chosen among 0.1, 0.2, 0.3, 0.5, 1 s by an
# affine fit on 5 training-stream runs (seed 1) scored on 5 other training-stream runs (seed 2).
TAU_S = 0.3


class TSState(NamedTuple):
    """EKF state and the smoothed Cartesian innovation ``ema`` (..., 3)."""

    filt: GaussianState
    ema: np.ndarray


def ts_init(z0: np.ndarray, z1: np.ndarray, R: np.ndarray, model: MotionModel3D,
            sensor_position: np.ndarray) -> TSState:
    """Two-point EKF initialization with a zero feature."""
    s = two_point_init(z0, z1, R, model, sensor_position)
    return TSState(s, np.zeros(s.x.shape[:-1] + (3,)))


def ts_step(state: TSState, z: np.ndarray, R: np.ndarray, model: MotionModel3D,
            sensor_position: np.ndarray) -> TSState:
    """One EKF cycle and the feature update (the feature uses the predicted position)."""
    res = ekf_step(state.filt, z, R, model, sensor_position)
    x_pred = state.filt.x @ model.F.T
    c = sensor_position + cartesian_from_polar(z) - position(x_pred, model)
    a = 1.0 - math.exp(-model.T / TAU_S)
    return TSState(res.state, state.ema + a * (c - state.ema))


def error_components(model: MotionModel3D) -> np.ndarray:
    """State indices the TS model compensates: positions then velocities."""
    return np.concatenate([model.pos, model.vel])


def compensated(state: TSState, ts: TSModel, model: MotionModel3D) -> np.ndarray:
    """``x(k|k) + f(e_k)``: the EKF estimate plus the TS model's predicted error."""
    x = state.filt.x.copy()
    x[..., error_components(model)] += predict(ts, state.ema)
    return x
