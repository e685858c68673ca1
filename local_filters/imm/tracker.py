"""A single-track IMM tracker fed one measurement at a time (used by the replay and the service).

The prior is taken to hold at the first measurement's time, so the first measurement
is an update only (``dt = 0``: ``F = I``, no process noise, no acceleration input, no
mode switch); so is any later measurement with a repeated timestamp. Otherwise the
motion model uses the actual ``dt`` and the mode transitions use ``Pi^(dt / T)`` with
``T = transition_interval`` (the paper's 1 s): unchanged at the nominal interval, ``Pi^2``
over a missed measurement, a fractional power for irregular sampling.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from fedtrack.local_filters.imm.config import IMMConfig
from fedtrack.local_filters.imm.filter import (
    ALGORITHMS,
    StepOutput,
    VSState,
    group_label,
    initial_state,
    step,
    transition_over,
)
from fedtrack.local_filters.linear.models import cv_model


class TrackPoint(NamedTuple):
    """One estimate: time, ``x = [x, vx, y, vy]``, ``P``, acceleration ``sum mu_i a_i``,
    mode probabilities by model name (0 for models not running) and the active group label."""

    t: float
    x: np.ndarray
    P: np.ndarray
    acceleration: np.ndarray
    mode_probabilities: dict[str, float]
    active_group: str

    def as_dict(self) -> dict[str, Any]:
        return {"t": self.t, "x": self.x.tolist(), "P": self.P.tolist(),
                "acceleration": self.acceleration.tolist(),
                "mode_probabilities": self.mode_probabilities, "active_group": self.active_group}


def prior(cfg: IMMConfig, z0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``x0``, ``P0`` from the config; without ``x0`` centred on the first measurement at rest."""
    sp, sv = cfg.initial_position_std, cfg.initial_velocity_std
    P0 = np.array(cfg.P0) if cfg.P0 is not None else np.diag([sp * sp, sv * sv, sp * sp, sv * sv])
    x0 = np.array(cfg.x0) if cfg.x0 is not None else np.array([z0[0], 0.0, z0[1], 0.0])
    return x0, P0


class IMMTracker:
    """Holds one track's :class:`VSState` between measurements (thin stateful wrapper)."""

    def __init__(self, cfg: IMMConfig, algorithm: str) -> None:
        if algorithm not in ALGORITHMS:
            raise ValueError(f"unknown IMM algorithm {algorithm!r} (expected one of {', '.join(ALGORITHMS)})")
        self.cfg = cfg
        self.algorithm = algorithm
        self.bank = cfg.bank()
        self.thresholds = cfg.thresholds()
        self.state: VSState | None = None
        self.t: float | None = None

    def update(self, t: float, z: np.ndarray, R: np.ndarray) -> TrackPoint:
        """Process a position measurement ``z (2,)`` with covariance ``R (2, 2)`` taken at ``t``."""
        if self.t is not None and t < self.t:
            raise ValueError(f"measurement time {t} is earlier than the previous one ({self.t})")
        if self.state is None:
            x0, P0 = prior(self.cfg, z)
            self.state = initial_state(self.bank, self.algorithm, self.cfg.initial_group_index(), x0[None], P0[None])
            self.t = t
        dt = t - self.t  # type: ignore[operator]
        Pi = transition_over(self.bank.Pi, round(dt / self.cfg.transition_interval, 9))
        self.state, out = step(self.bank, self.algorithm, self.state, cv_model(dt, self.cfg.q), z[None], R,
                               self.thresholds, Pi)
        self.t = t
        return self._point(t, out)

    def _point(self, t: float, out: StepOutput) -> TrackPoint:
        return TrackPoint(t, out.est.x[0], out.est.P[0], out.acc[0],
                          dict(zip(self.bank.names, out.mu[0].tolist())),
                          group_label(self.bank, int(out.old[0]), int(out.new[0])))
