"""Maneuvering-target scenarios S1 and S2 of paper 000 (eq. (12)), batched over Monte Carlo runs.

Truth model (paper 000 eq. (7)): ``x_k = F x_{k-1} + G w_k`` with ``w_k ~ N(a_k, q I)``,
i.e. the process noise has the mode ``a_k`` of eq. (12) as its mean and variance
``Q = 10^2 I``; ``z_k = H x_k + v_k``, ``v_k ~ N(0, 20^2 I)``, ``T = 1 s``. The mode
``a_k`` acts over ``(k-1, k]``, so the IMM's mode probability at ``k`` estimates it.
The initial state is 20 km and 340 m/s *per axis* (the paper: "X축, Y축 각각", each
axis): ``x_0 = [20000, 340, 20000, 340]``. Beyond step 200 a profile repeats.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fedtrack.local_filters.linear.kalman import mat_vec
from fedtrack.local_filters.linear.models import cv_model

# (first k, last k, [ax, ay]) in m/s^2, paper 000 eq. (12)
PROFILES: dict[str, tuple[tuple[int, int, tuple[float, float]], ...]] = {
    "S1": ((1, 30, (0, 0)), (31, 45, (18, 3)), (46, 55, (38, -2)), (56, 80, (0, 0)),
           (81, 98, (1, 22)), (99, 119, (3, -1)), (120, 139, (-35, 1)), (140, 150, (-20, 0)),
           (151, 200, (3, 2))),
    "S2": ((1, 30, (0, 0)), (31, 45, (35, -3)), (46, 55, (-2, 15)), (56, 80, (0, 31)),
           (81, 98, (3, -11)), (99, 119, (0, 0)), (120, 139, (-35, 4)), (140, 150, (2, 0)),
           (151, 200, (2, -18))),
}
PERIOD = 200
X0 = np.array([20000.0, 340.0, 20000.0, 340.0])
T_SAMPLE = 1.0
Q_ACC = 100.0  # variance of w_k per axis
R_MEAS = 400.0 * np.eye(2)


class Truth(NamedTuple):
    """``x (R, K+1, 4)`` states at k = 0..K, ``z (R, K, 2)`` measurements at k = 1..K,
    ``acc (K, 2)`` the scenario mode a_k for k = 1..K."""

    x: np.ndarray
    z: np.ndarray
    acc: np.ndarray


def acceleration_profile(name: str, steps: int = PERIOD) -> np.ndarray:
    """``(steps, 2)`` mode accelerations a_k for k = 1..steps (repeating every 200 steps)."""
    if name not in PROFILES:
        raise ValueError(f"unknown scenario {name!r} (expected one of {sorted(PROFILES)})")
    base = np.zeros((PERIOD, 2))
    for first, last, a in PROFILES[name]:
        base[first - 1:last] = a
    return base[np.arange(steps) % PERIOD]


def simulate(name: str, runs: int, rng: np.random.Generator, steps: int = PERIOD,
             q: float = Q_ACC, R: np.ndarray = R_MEAS, x0: np.ndarray = X0,
             T: float = T_SAMPLE) -> Truth:
    """Seeded truth and measurements for ``runs`` independent runs of scenario ``name``."""
    model = cv_model(T, q)
    acc = acceleration_profile(name, steps)
    w = acc[None] + np.sqrt(q) * rng.standard_normal((runs, steps, 2))
    v = rng.standard_normal((runs, steps, 2)) @ np.linalg.cholesky(R).T
    x = np.empty((runs, steps + 1, 4))
    x[:, 0] = x0
    for k in range(steps):
        x[:, k + 1] = mat_vec(model.F, x[:, k]) + w[:, k] @ model.G.T
    z = x[:, 1:][..., [0, 2]] + v
    return Truth(x, z, acc)
