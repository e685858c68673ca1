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

from fedtrack.local_filters.mtt.models import predict_batch
from fedtrack.local_filters.linear.kalman import GaussianState, update

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


def start(track_id: int, t: float, x: np.ndarray, P: np.ndarray, confirmed: bool) -> CentralTrack:
    return CentralTrack(track_id, (Fused(t, None, x, P),), confirmed, 1)


def states_at(tracks: list[CentralTrack], t: float, q: float, noise_model: str) -> tuple[np.ndarray, np.ndarray]:
    """The estimates (N, D), (N, D, D) of non-empty ``tracks`` at ``t`` from their observations up
    to ``t`` (``t`` >= each checkpoint), in one batched prediction."""
    base = []
    for track in tracks:
        hist = track.history
        k = len(hist) - 1
        while k > 0 and hist[k].t > t:
            k -= 1
        base.append(hist[k])
    dt = np.round(np.maximum(t - np.array([h.t for h in base]), 0.0), 12)
    return predict_batch(np.array([h.x for h in base]), np.array([h.P for h in base]), dt, q, noise_model)


def _step(prev: list[Fused], t: np.ndarray, obs: list[Observation1], q: float, noise_model: str
          ) -> tuple[np.ndarray, np.ndarray]:
    """Posteriors after predicting each ``prev[i]`` to ``t[i]`` and fusing ``obs[i]`` (one measurement
    size), batched."""
    dt = np.round(t - np.array([p.t for p in prev]), 12)
    x, P = predict_batch(np.array([p.x for p in prev]), np.array([p.P for p in prev]), dt, q, noise_model)
    H, R, z = (np.array(a) for a in zip(*obs))
    return update(GaussianState(x, P), z, H, R)[0]


def _trimmed(track: CentralTrack, fused: tuple[Fused, ...], max_lag: float) -> CentralTrack:
    """``track`` with history ``fused`` (time order), entries older than ``max_lag`` before the
    newest folded into the checkpoint (the last one before that horizon)."""
    horizon = fused[-1].t - max_lag
    first = 0
    while first + 1 < len(fused) and fused[first + 1].t < horizon:
        first += 1
    return CentralTrack(track.id, fused[first:] if first else fused, track.confirmed, track.hits + 1)


def fuse_many(tracks: list[CentralTrack], t: float, obs: list[Observation1], q: float, noise_model: str,
              max_lag: float) -> list[tuple[CentralTrack, np.ndarray, np.ndarray] | None]:
    """Fuse observation ``obs[i]``, taken at ``t``, into ``tracks[i]`` (distinct tracks); per track the
    new track and its posterior at ``t``, or None if the observation is late.

    An observation at or after a track's newest is one batched step for all such tracks. For the
    others, each track's observations from ``t`` on are fused again in time order from the
    posterior before ``t``; the re-processing goes step by step over all those tracks at once, one
    batched prediction and Joseph-form update per step and measurement size.
    """
    done: list[tuple[CentralTrack, np.ndarray, np.ndarray] | None] = [None] * len(tracks)
    out: dict[int, list[Fused]] = {}  # per track: the kept history, then what is fused
    redo: dict[int, list[tuple[float, Observation1]]] = {}  # per track: what to fuse, from ``t`` on
    in_order: dict[int, list[int]] = {}  # by measurement size: tracks with nothing after ``t``
    for i, (track, o) in enumerate(zip(tracks, obs)):
        hist = track.history
        if t < hist[0].t or t < hist[-1].t - max_lag:
            continue  # late
        if t >= hist[-1].t:
            in_order.setdefault(o[0].shape[0], []).append(i)
            continue
        k = len(hist)
        while k > 1 and hist[k - 1].t > t:
            k -= 1
        out[i] = list(hist[:k])
        redo[i] = [(t, o)] + [(h.t, h.obs) for h in hist[k:]]  # type: ignore[misc]
    for group in in_order.values():
        x, P = _step([tracks[i].history[-1] for i in group], np.full(len(group), t), [obs[i] for i in group],
                     q, noise_model)
        for i, xj, Pj in zip(group, x, P):
            done[i] = (_trimmed(tracks[i], tracks[i].history + (Fused(t, obs[i], xj, Pj),), max_lag), xj, Pj)
    pending = list(redo)
    step = 0
    while pending:
        by_size: dict[int, list[int]] = {}
        for i in pending:
            by_size.setdefault(redo[i][step][1][0].shape[0], []).append(i)
        for group in by_size.values():
            items = [redo[i][step] for i in group]
            x, P = _step([out[i][-1] for i in group], np.array([ti for ti, _ in items]), [o for _, o in items],
                         q, noise_model)
            for i, (ti, o), xj, Pj in zip(group, items, x, P):
                out[i].append(Fused(ti, o, xj, Pj))
        step += 1
        pending = [i for i in pending if len(redo[i]) > step]
    for i, fused in out.items():
        at_t = fused[len(fused) - len(redo[i])]
        done[i] = (_trimmed(tracks[i], tuple(fused), max_lag), at_t.x, at_t.P)
    return done
