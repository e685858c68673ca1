"""One central track with an out-of-sequence buffer: exact fusion of observations in time order.

A central track keeps the observations it fused during the last ``max_lag`` seconds, each
with the posterior after it. An observation older than the newest one is inserted in time
order and the observations after it are fused again from the posterior before it (buffer
and reprocess): the result equals fusing the time-sorted observations, to round-off. An
observation older than ``max_lag`` (or than the oldest kept posterior) is late and not fused.
Why this and not a retrodiction method: see docs/multitarget.md.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fedtrack.local_filters.mtt.models import motion, predict_tracks

Observation1 = tuple[np.ndarray, np.ndarray, np.ndarray]  # H (m, D), R (m, m), z (m,)


class Fused(NamedTuple):
    """An observation at ``t`` and the posterior ``(x, P)`` after fusing it."""

    t: float
    obs: Observation1 | None  # None: the track's starting state
    x: np.ndarray
    P: np.ndarray


class CentralTrack(NamedTuple):
    id: int
    history: tuple[Fused, ...]  # time order; history[0] is the checkpoint (older ones folded)
    confirmed: bool
    hits: int  # detections fused, the start included

    @property
    def t(self) -> float:
        return self.history[-1].t

    @property
    def x(self) -> np.ndarray:
        return self.history[-1].x

    @property
    def P(self) -> np.ndarray:
        return self.history[-1].P


def predict_to(x: np.ndarray, P: np.ndarray, dt: float, q: float, noise_model: str
               ) -> tuple[np.ndarray, np.ndarray]:
    if dt == 0.0:
        return x, P
    xp, Pp = predict_tracks(x[None], P[None], motion(x.shape[0], round(dt, 12), q, noise_model))
    return xp[0], Pp[0]


def update(x: np.ndarray, P: np.ndarray, obs: Observation1) -> tuple[np.ndarray, np.ndarray]:
    """Kalman update with a linearized observation (Joseph form, gain by a solve)."""
    H, R, z = obs
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    x = x + K @ (z - H @ x)
    A = np.eye(x.shape[0]) - K @ H
    P = A @ P @ A.T + K @ R @ K.T
    return x, 0.5 * (P + P.T)


def start(track_id: int, t: float, x: np.ndarray, P: np.ndarray, confirmed: bool) -> CentralTrack:
    return CentralTrack(track_id, (Fused(t, None, x, P),), confirmed, 1)


def state_at(track: CentralTrack, t: float, q: float, noise_model: str) -> tuple[np.ndarray, np.ndarray]:
    """The track's estimate at ``t`` from the observations up to ``t`` (``t`` >= its checkpoint)."""
    k = len(track.history) - 1
    while k > 0 and track.history[k].t > t:
        k -= 1
    h = track.history[k]
    return predict_to(h.x, h.P, max(t - h.t, 0.0), q, noise_model)


def fuse(track: CentralTrack, t: float, obs: Observation1, q: float, noise_model: str, max_lag: float
         ) -> tuple[CentralTrack, np.ndarray, np.ndarray] | None:
    """Fuse ``obs`` taken at ``t``; returns the new track and its posterior at ``t``, or None if late."""
    hist = track.history
    if t < hist[0].t or t < hist[-1].t - max_lag:
        return None
    k = len(hist)
    while k > 1 and hist[k - 1].t > t:
        k -= 1
    redo = [Fused(t, obs, hist[0].x, hist[0].P)] + list(hist[k:])
    out = list(hist[:k])
    at_t: tuple[np.ndarray, np.ndarray] | None = None
    for item in redo:
        prev = out[-1]
        x, P = predict_to(prev.x, prev.P, item.t - prev.t, q, noise_model)
        assert item.obs is not None
        x, P = update(x, P, item.obs)
        out.append(Fused(item.t, item.obs, x, P))
        if at_t is None:
            at_t = (x, P)
    horizon = out[-1].t - max_lag
    first = 0
    while first + 1 < len(out) and out[first + 1].t < horizon:
        first += 1
    new = CentralTrack(track.id, tuple(out[first:]), track.confirmed, track.hits + 1)
    assert at_t is not None
    return new, at_t[0], at_t[1]


def append(track: CentralTrack, t: float, obs: Observation1, x: np.ndarray, P: np.ndarray, max_lag: float
           ) -> CentralTrack:
    """The track after an in-order observation at ``t`` (``t`` >= its newest) whose posterior is ``(x, P)``."""
    out = track.history + (Fused(t, obs, x, P),)
    horizon = t - max_lag
    first = 0
    while first + 1 < len(out) and out[first + 1].t < horizon:
        first += 1
    return CentralTrack(track.id, out[first:], track.confirmed, track.hits + 1)
