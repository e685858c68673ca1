"""Local filters of the distributed pipeline (one per sensor process).

* :class:`FederatedLocalFilter`: paper 004 eqs. (9)-(12) with ``Q_i = beta_i Q``, adopting
  the centre's reset ``(x, beta_i P, model)`` before each scan.
* :class:`VdieLocalFilter`: a stand-alone single-sensor VDIE (DVDIE's local filter).

Both use exactly the functions the in-process trackers of ``fedtrack.fusion_center.trackers``
use, so the network pipeline reproduces ``fedtrack replay`` to round-off.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fedtrack.local_filters.linear.kalman import GaussianState, predict, update
from fedtrack.local_filters.linear.models import CA, CV
from fedtrack.local_filters.linear.tracking import local_kf_step, models_for, one_point_init, rounded_interval
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.local_filters.vdie.estimation import (
    EVENT_NAMES,
    EVENT_NONE,
    VdieEvents,
    cv_part,
    embed_cv,
    vdie_init,
    vdie_step,
)


class LocalOutput(NamedTuple):
    """A local filter's result for one scan, in its models' own state orders."""

    model: str
    x: np.ndarray
    P: np.ndarray
    x_prior: np.ndarray
    P_prior: np.ndarray
    init: bool
    event: str | None = None  # onset / new-ca / end
    onset: float = 0.0
    u: np.ndarray | None = None
    gamma: np.ndarray | None = None


def model_name(dim: int) -> str:
    return CA if dim == 6 else CV


def _initial(config: FusionConfig, n_sensors: int, z: np.ndarray, R: np.ndarray,
             scale: float) -> tuple[GaussianState, bool]:
    """One-point estimate (velocity variance ``N v^2``) or the configured prior ``(x0, scale P0)``."""
    if config.x0 is None:
        local = one_point_init(z[None, :], R[None], n_sensors * config.initial_velocity_std ** 2)
        return GaussianState(local.x[0], local.P[0]), True
    return GaussianState(np.asarray(config.x0, dtype=float), scale * np.asarray(config.P0, dtype=float)), False


class FederatedLocalFilter:
    """Local filter ``i`` of the federated filter."""

    def __init__(self, beta: float, n_sensors: int, config: FusionConfig) -> None:
        self.beta = beta
        self.n_sensors = n_sensors
        self.config = config
        self.state: GaussianState | None = None
        self.t: float | None = None

    def apply_reset(self, t: float, x: np.ndarray, P: np.ndarray) -> None:
        """Eqs. (20)-(21): adopt the fused estimate of scan time ``t`` (``P`` already ``beta_i P``)."""
        self.state = GaussianState(np.array(x, dtype=float), np.array(P, dtype=float))
        self.t = t

    def process(self, t: float, z: np.ndarray, R: np.ndarray) -> LocalOutput:
        if self.state is None:
            start, is_estimate = _initial(self.config, self.n_sensors, z, R, self.beta)
            self.t = t
            if is_estimate:
                self.state = start
                return LocalOutput(CV, start.x, start.P, start.x, start.P, init=True)
            self.state = start
        model = models_for(rounded_interval(t - self.t), self.config.q)[0 if self.state.x.shape[0] == 4 else 1]
        prior = predict(self.state, model.F, self.beta * model.Q)  # (11) with Q_i = beta_i Q (22)
        post, _ = update(prior, z, model.H, R)  # (10), (12)
        self.state, self.t = post, t
        return LocalOutput(model.name, post.x, post.P, prior.x, prior.P, init=False)


class VdieLocalFilter:
    """A single-sensor variable-dimension filter with input estimation (DVDIE local)."""

    def __init__(self, n_sensors: int, config: FusionConfig) -> None:
        self.n_sensors = n_sensors
        self.config = config
        self.vdie = None
        self.t: float | None = None

    def process(self, t: float, z: np.ndarray, R: np.ndarray) -> LocalOutput:
        if self.vdie is None:
            start, is_estimate = _initial(self.config, self.n_sensors, z, R, 1.0)
            x, P = embed_cv(start.x, start.P)
            self.vdie = vdie_init(x, P, np.zeros((), dtype=bool), self.config.vdie, t)
            self.t = t
            if is_estimate:
                return LocalOutput(CV, start.x, start.P, start.x, start.P, init=True)
        cv, ca = models_for(rounded_interval(t - self.t), self.config.q)
        self.t = t

        def step_fn(post_prev: GaussianState, model):
            return local_kf_step(post_prev, model, z, R, None)

        before = self.vdie
        self.vdie, events, trace = vdie_step(before, t, cv, ca, self.config.vdie, step_fn)
        return vdie_output(bool(before.is_ca), self.vdie.x, self.vdie.P, bool(self.vdie.is_ca), trace.prior, events)


def vdie_output(was_ca: bool, x: np.ndarray, P: np.ndarray, is_ca: bool, prior: GaussianState,
                events: VdieEvents) -> LocalOutput:
    """Cut CA-layout arrays down to each model's own state order."""
    now = GaussianState(x, P) if is_ca else cv_part(x, P)
    pre = prior if was_ca else cv_part(prior.x, prior.P)
    kind = int(events.kind)
    if kind == EVENT_NONE:
        return LocalOutput(model_name(now.x.shape[0]), now.x, now.P, pre.x, pre.P, init=False)
    return LocalOutput(model_name(now.x.shape[0]), now.x, now.P, pre.x, pre.P, init=False,
                       event=EVENT_NAMES[kind], onset=float(events.onset), u=np.asarray(events.u),
                       gamma=np.asarray(events.gamma))
