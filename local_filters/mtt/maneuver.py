"""Per-track maneuver handling of the multi-target trackers: VDIE (paper 004 section III) on every
track of a 2-D position tracker, batched over the track axis (``[mtt] maneuver = "vdie"``).

Each track carries, beside the CV view ``x, P`` that association, reports and pictures use, its
:class:`~fedtrack.local_filters.vdie.estimation.VdieState`: the state in the CA order ``[x, vx,
ax, y, vy, ay]``, its model (CV or CA), the candidate banks of the input estimator and the
acceleration-significance statistics. One scan is :func:`vdie_step` with the tracker's own
filter as its step function: predict in the track's model, update with the detection the
association gave it (a missed track is predicted only, which adds nothing to its input
estimates). In CV a track whose windowed least-squares input estimate is significant switches to
CA, compensated for the maneuver since its onset (eqs. (69)-(71)); in CA one whose acceleration
is no longer significant over ``p`` scans returns to CV (eq. (81)). The CV view of a CA track is
its marginal (the accelerations dropped).

Models over an interval ``dt`` (scans come at any times, so they are built per interval):

* CV: the tracker's own (:func:`fedtrack.local_filters.mtt.models.motion`), so a track that
  never maneuvers is exactly the CV tracker's track; its input gain is ``B = [dt^2/2, dt]'``
  per axis (a constant acceleration over the interval);
* CA: per axis ``F = [[1, dt, dt^2/2], [0, 1, dt], [0, 0, 1]]``; ``noise_model =
  "continuous"``: a white jerk of intensity ``q`` (``Q = q [[dt^5/20, dt^4/8, dt^3/6],
  [dt^4/8, dt^3/3, dt^2/2], [dt^3/6, dt^2/2, dt]]``, consistent over irregular intervals);
  ``"discrete"``: paper 004's ``q G G'``, ``G = [dt^2/2, dt, 1]'``.

Radar tracks (3-D state) keep the CV model: paper 004's estimator is 2-D.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any, NamedTuple

import numpy as np

from fedtrack.local_filters.linear.kalman import GaussianState, predict, update_residual
from fedtrack.local_filters.linear.models import CA, CV, LinearModel
from fedtrack.local_filters.linear.tracking import rounded_interval
from fedtrack.local_filters.mtt.models import motion, position_matrix
from fedtrack.local_filters.vdie.estimation import (
    EVENT_NONE,
    VdieParams,
    VdieState,
    cv_part,
    embed_cv,
    vdie_init,
    vdie_step,
)


def _axes(a: np.ndarray) -> np.ndarray:
    return np.kron(np.eye(2), a)


@lru_cache(maxsize=256)
def maneuver_models(dt: float, q: float, noise_model: str) -> tuple[LinearModel, LinearModel]:
    """The CV and CA models of one interval (see the module docstring)."""
    cv = motion(4, dt, q, noise_model)
    step = _axes(np.array([[dt * dt / 2.0], [dt]]))
    cv_model = LinearModel(CV, dt, q, cv.F, cv.Q, position_matrix(4), step, step, (0, 2), (1, 3), None)
    f = np.array([[1.0, dt, dt * dt / 2.0], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    if noise_model == "continuous":
        qa = q * np.array([[dt**5 / 20.0, dt**4 / 8.0, dt**3 / 6.0], [dt**4 / 8.0, dt**3 / 3.0, dt**2 / 2.0],
                           [dt**3 / 6.0, dt**2 / 2.0, dt]])
    else:
        g = np.array([dt * dt / 2.0, dt, 1.0])
        qa = q * np.outer(g, g)
    H = np.zeros((2, 6))
    H[0, 0] = H[1, 3] = 1.0
    G = _axes(np.array([[dt * dt / 2.0], [dt], [1.0]]))
    pulse = _axes(np.array([[0.0], [0.0], [1.0]]))
    ca_model = LinearModel(CA, dt, q, _axes(f), _axes(qa), H, G, pulse, (0, 3), (1, 4), (2, 5))
    return cv_model, ca_model


def take(state: VdieState, idx: np.ndarray) -> VdieState:
    """The tracks ``idx`` of a batched VDIE state (every field's leading axis is the track)."""
    return _map(lambda a: a[idx], state)


def concat(a: VdieState, b: VdieState) -> VdieState:
    return _map(lambda u, v: np.concatenate([u, v]), a, b)


def _map(fn: Any, *states: Any) -> Any:
    first = states[0]
    if isinstance(first, tuple):
        return type(first)(*(_map(fn, *parts) for parts in zip(*states)))
    return fn(*states)


def start(x: np.ndarray, P: np.ndarray, t: float, params: VdieParams) -> VdieState:
    """New tracks (CV view ``x`` (N, 4), ``P``) in CV with empty candidate banks."""
    x6, P6 = embed_cv(x, P)
    return vdie_init(x6, P6, np.zeros(x.shape[0], bool), params, t)


def predicted_view(state: VdieState, dt: float, q: float, noise_model: str, q_scale: float | np.ndarray = 1.0
                   ) -> GaussianState:
    """Every track predicted ``dt`` ahead in its own model, as its CV view."""
    cv, ca = maneuver_models(rounded_interval(dt), q, noise_model)
    scale = np.asarray(q_scale)[..., None, None]
    as_cv = predict(cv_part(state.x, state.P), cv.F, scale * cv.Q)
    as_ca = cv_part(*predict(GaussianState(state.x, state.P), ca.F, scale * ca.Q))
    ca_rows = state.is_ca
    return GaussianState(np.where(ca_rows[:, None], as_ca.x, as_cv.x),
                         np.where(ca_rows[:, None, None], as_ca.P, as_cv.P))


class ManeuverStep(NamedTuple):
    state: VdieState
    view: GaussianState  # the CV view after the scan
    events: np.ndarray  # (N,) EVENT_* code per track


def maneuver_step(state: VdieState, t: float, dt: float, q: float, noise_model: str, params: VdieParams,
                  rows: np.ndarray, z: np.ndarray, R: np.ndarray, q_scale: float | np.ndarray = 1.0
                  ) -> ManeuverStep:
    """One scan of every track: the tracks ``rows`` are updated with their detections ``z``
    (position sensors), the rest predicted."""
    cv, ca = maneuver_models(rounded_interval(dt), q, noise_model)
    scale = np.asarray(q_scale)[..., None, None]

    def step_fn(post: GaussianState, model: LinearModel) -> tuple[GaussianState, GaussianState]:
        prior = predict(post, model.F, scale * model.Q)
        if not rows.size:
            return prior, prior
        H = np.broadcast_to(model.H, (rows.size,) + model.H.shape)
        x0 = prior.x[rows]
        upd = update_residual(GaussianState(x0, prior.P[rows]), z - x0[:, list(model.pos)], H, R).state
        x, P = prior.x.copy(), prior.P.copy()
        x[rows], P[rows] = upd.x, upd.P
        return prior, GaussianState(x, P)

    new, events, _ = vdie_step(state, t, cv, ca, params, step_fn)
    return ManeuverStep(new, cv_part(new.x, new.P), events.kind)


def maneuvering(events: np.ndarray) -> int:
    """Model switches and compensations among ``events``."""
    return int(np.count_nonzero(events != EVENT_NONE))
