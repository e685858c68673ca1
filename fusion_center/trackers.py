"""Scan-by-scan multi-sensor trackers: kf, federated-kf, decentralized-kf, fvdie, dvdie.

The maths lives in pure round functions (:func:`federated_round`,
:func:`decentralized_round`, ...) that the networked services call too; the classes
here only hold the current state records between scans. Every tracker batches over
leading axes of ``zs`` (Monte Carlo runs): ``zs`` is ``(..., N, 2)``.

Initialization (shared by all algorithms so they are comparable to round-off):
each sensor's first measurement gives a one-point local estimate, position ``z_i``
with covariance ``R_i`` and zero velocity with variance ``N * initial_velocity_std^2``; the
first fused estimate is their information sum (which is the centralized one-point
initialization with velocity variance ``initial_velocity_std^2``). With ``x0``/``P0`` in the
config, every filter instead starts from that prior at the first scan's time and
updates with the first scan.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from fedtrack.fusion_center.fusion import (
    centralized_update,
    decentralized_fuse,
    federated_fuse,
    federated_local_step,
    federated_reset,
)
from fedtrack.local_filters.linear.kalman import (
    GaussianState,
    from_information,
    information,
    predict,
)
from fedtrack.local_filters.linear.models import CA, CV, CV_IN_CA, LinearModel
from fedtrack.local_filters.linear.tracking import (
    local_kf_step,
    models_for,
    one_point_init,
    rounded_interval,
)
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.local_filters.vdie.estimation import (
    EVENT_END,
    EVENT_NAMES,
    EVENT_NEW_CA,
    EVENT_NONE,
    EVENT_ONSET,
    CentreState,
    LocalReports,
    dvdie_centre_step,
    embed_cv,
    local_reports,
    vdie_init,
    vdie_step,
)

ALGORITHMS = ("kf", "federated-kf", "decentralized-kf", "fvdie", "dvdie")


class ScanEstimate(NamedTuple):
    """One scan's fused estimate (CA layout; CV runs carry placeholder accelerations)."""

    x: np.ndarray
    P: np.ndarray
    is_ca: np.ndarray
    event: np.ndarray  # vdie EVENT_* code (always EVENT_NONE for the plain KFs)


class ModelEstimate(NamedTuple):
    """One scan's estimate in the state order of the filter's current model."""

    model: str  # "cv" or "ca"
    x: np.ndarray  # (4,) CV [x, vx, y, vy] or (6,) CA [x, vx, ax, y, vy, ay]
    P: np.ndarray
    event: str | None  # "onset" / "new-ca" / "end" / None


def model_estimate(est: ScanEstimate) -> ModelEstimate:
    """The unbatched :class:`ScanEstimate` ``est`` in its model's own state order."""
    is_ca = bool(est.is_ca)
    idx = np.arange(6) if is_ca else CV_IN_CA
    return ModelEstimate(CA if is_ca else CV, est.x[idx], est.P[np.ix_(idx, idx)], EVENT_NAMES.get(int(est.event)))


def fuse_independent(local: GaussianState, present: np.ndarray | None) -> GaussianState:
    """Information sum over the sensor axis of the present local estimates."""
    Y, y = information(local)
    w = np.ones(local.x.shape[:-1]) if present is None else np.asarray(present, dtype=float)
    return from_information(np.einsum("...i,...ijk->...jk", w, Y), np.einsum("...i,...ij->...j", w, y))


class FederatedRound(NamedTuple):
    master_prior: GaussianState
    fused: GaussianState
    local_prior: GaussianState
    local_post: GaussianState


def federated_round(fused_prev: GaussianState, model: LinearModel, zs: np.ndarray, Rs: np.ndarray,
                    betas: np.ndarray, present: np.ndarray | None) -> FederatedRound:
    """Reset (20)-(22), local filters (9)-(12), master fusion (15)-(16)."""
    local = federated_reset(fused_prev, betas)
    local_prior, local_post = federated_local_step(local, zs, model.F, model.Q, model.H, Rs, betas, present)
    master_prior = predict(fused_prev, model.F, model.Q)
    partial = present is not None and not np.all(present)
    fused = federated_fuse(local_post, betas, present if partial else None, master_prior if partial else None)
    return FederatedRound(master_prior, fused, local_prior, local_post)


class Tracker:
    """Base class: keeps the scan clock and the common initialization."""

    name = ""

    def __init__(self, n_sensors: int, config: FusionConfig | None = None) -> None:
        self.config = config or FusionConfig()
        self.n_sensors = n_sensors
        self.betas = self.config.betas(n_sensors)
        self.t: float | None = None

    def step(self, t: float, zs: np.ndarray, Rs: np.ndarray,
             present: np.ndarray | None = None) -> ModelEstimate:
        """Process one scan at time ``t`` (``zs`` is ``(N, 2)``, ``Rs`` ``(N, 2, 2)``).

        ``present`` (N,) marks the sensors that reported. Returns the estimate in the state
        order of the model the filter is in: CV ``[x, vx, y, vy]`` or CA ``[x, vx, ax, y, vy, ay]``.
        """
        if np.ndim(zs) != 2:
            raise ValueError(f"step takes one scan (N, 2); use step_batch for batches, got {np.shape(zs)}")
        return model_estimate(self.step_batch(t, zs, Rs, present))

    def step_batch(self, t: float, zs: np.ndarray, Rs: np.ndarray,
                   present: np.ndarray | None = None) -> ScanEstimate:
        """Process one scan of a batch (``zs`` is ``(..., N, 2)``: Monte Carlo runs).

        Runs may be in different models, so the estimate is in the CA layout with the CV runs'
        accelerations as placeholders (:class:`ScanEstimate`).
        """
        if present is not None:
            present = np.asarray(present, dtype=bool)
            if not present.any():
                raise ValueError("a scan needs at least one measurement")
            zs = np.where(present[:, None], zs, 0.0)
            if np.all(present):
                present = None
        if self.t is None:
            self.t = t
            if self.config.x0 is None:
                speed_var = self.n_sensors * self.config.initial_velocity_std ** 2
                return self._start(one_point_init(zs, Rs, speed_var), present, t)
            x0 = np.broadcast_to(np.asarray(self.config.x0), zs.shape[:-2] + (4,))
            P0 = np.broadcast_to(np.asarray(self.config.P0), zs.shape[:-2] + (4, 4))
            self._start_prior(GaussianState(x0.copy(), P0.copy()), t)
        dt = t - self.t
        if dt < 0:
            raise ValueError(f"scan time {t} is before the previous scan {self.t}")
        self.t = t
        cv, ca = models_for(rounded_interval(dt), self.config.q)
        return self._update(cv, ca, zs, Rs, present, t)

    def _start(self, local: GaussianState, present: np.ndarray | None, t: float) -> ScanEstimate:
        raise NotImplementedError

    def _start_prior(self, prior: GaussianState, t: float) -> None:
        raise NotImplementedError

    def _update(self, cv: LinearModel, ca: LinearModel, zs: np.ndarray, Rs: np.ndarray,
                present: np.ndarray | None, t: float) -> ScanEstimate:
        raise NotImplementedError


def _cv_estimate(state: GaussianState) -> ScanEstimate:
    x, P = embed_cv(state.x, state.P)
    batch = state.x.shape[:-1]
    return ScanEstimate(x, P, np.zeros(batch, dtype=bool), np.full(batch, EVENT_NONE))


class CentralizedKF(Tracker):
    """The reference: one CV Kalman filter updating with every sensor's measurement (5)-(8)."""

    name = "kf"

    def _start(self, local: GaussianState, present: np.ndarray | None, t: float) -> ScanEstimate:
        self.state = fuse_independent(local, present)
        return _cv_estimate(self.state)

    def _start_prior(self, prior: GaussianState, t: float) -> None:
        self.state = prior

    def _update(self, cv, ca, zs, Rs, present, t):
        prior = predict(self.state, cv.F, cv.Q)
        if present is None:
            self.state = centralized_update(prior, zs, cv.H, Rs)
        else:
            idx = np.flatnonzero(present)
            self.state = centralized_update(prior, zs[..., idx, :], cv.H, Rs[..., idx, :, :])
        return _cv_estimate(self.state)


class FederatedKF(CentralizedKF):
    """Federated CV filter with reset at every scan (equal to :class:`CentralizedKF`)."""

    name = "federated-kf"

    def _update(self, cv, ca, zs, Rs, present, t):
        self.state = federated_round(self.state, cv, zs, Rs, self.betas, present).fused
        return _cv_estimate(self.state)


class DecentralizedKF(Tracker):
    """Stand-alone local CV filters fused by the Hashemipour form (no feedback)."""

    name = "decentralized-kf"

    def _start(self, local: GaussianState, present: np.ndarray | None, t: float) -> ScanEstimate:
        self.local = local
        self.centre = fuse_independent(local, present)
        return _cv_estimate(self.centre)

    def _start_prior(self, prior: GaussianState, t: float) -> None:
        self.centre = prior
        self.local = GaussianState(np.repeat(prior.x[..., None, :], self.n_sensors, axis=-2),
                                   np.repeat(prior.P[..., None, :, :], self.n_sensors, axis=-3))

    def _update(self, cv, ca, zs, Rs, present, t):
        local_prior, self.local = local_kf_step(self.local, cv, zs, Rs, present)
        self.centre = decentralized_fuse(predict(self.centre, cv.F, cv.Q), local_prior, self.local)
        return _cv_estimate(self.centre)


class VdieStart:
    """Mixin: after the base tracker's start, set up the variable-dimension state (``_init_vdie``)."""

    def _start(self, local, present, t):
        est = super()._start(local, present, t)  # type: ignore[misc]
        self._init_vdie(t)
        return est

    def _start_prior(self, prior, t):
        super()._start_prior(prior, t)  # type: ignore[misc]
        self._init_vdie(t)

    def _init_vdie(self, t: float) -> None:
        raise NotImplementedError


class FVDIE(VdieStart, CentralizedKF):
    """Federated variable-dimension filter with input estimation at the master."""

    name = "fvdie"

    def _init_vdie(self, t: float) -> None:
        x, P = embed_cv(self.state.x, self.state.P)
        self.vdie = vdie_init(x, P, np.zeros(x.shape[:-1], dtype=bool), self.config.vdie, t)

    def _update(self, cv, ca, zs, Rs, present, t):
        def step_fn(post_prev: GaussianState, model: LinearModel) -> tuple[GaussianState, GaussianState]:
            rnd = federated_round(post_prev, model, zs, Rs, self.betas, present)
            return rnd.master_prior, rnd.fused

        self.vdie, events, _ = vdie_step(self.vdie, t, cv, ca, self.config.vdie, step_fn)
        return ScanEstimate(self.vdie.x, self.vdie.P, self.vdie.is_ca, events.kind)


def scan_event(local_kinds: np.ndarray) -> np.ndarray:
    """One event per scan from the locals' events: a detection (onset, new-ca) wins over an end."""
    detection = (local_kinds == EVENT_ONSET) | (local_kinds == EVENT_NEW_CA)
    det = np.where(detection, local_kinds, EVENT_NONE).max(axis=-1)
    ended = (local_kinds == EVENT_END).any(axis=-1)
    return np.where(det != EVENT_NONE, det, np.where(ended, EVENT_END, EVENT_NONE))


def _take_sensors(idx: np.ndarray, a: Any, n_batch: int) -> Any:
    """The sensors ``idx`` of ``a`` (an array or a tuple of them, the sensor axis after ``n_batch``)."""
    if isinstance(a, tuple):
        return type(a)(*(_take_sensors(idx, u, n_batch) for u in a))
    return np.take(a, idx, axis=n_batch)


def _put_sensors(idx: np.ndarray, part: Any, whole: Any, n_batch: int) -> Any:
    """``whole`` with its sensors ``idx`` replaced by ``part`` (same nesting as :func:`_take_sensors`)."""
    if isinstance(whole, tuple):
        return type(whole)(*(_put_sensors(idx, p, w, n_batch) for p, w in zip(part, whole, strict=True)))
    out = whole.copy()
    out[(slice(None),) * n_batch + (idx,)] = part
    return out


def _concat_sensors(parts: list[Any], n_batch: int) -> Any:
    """Tuples of arrays (or arrays) joined along the sensor axis."""
    if isinstance(parts[0], tuple):
        return type(parts[0])(*(_concat_sensors(list(fields), n_batch) for fields in zip(*parts, strict=True)))
    return np.concatenate(parts, axis=n_batch)


class DVDIE(VdieStart, DecentralizedKF):
    """Single-sensor VDIE in every local filter; the centre fuses without feedback.

    As live (:class:`~fedtrack.fusion_center.centre.DecentralizedCentre` fed by
    :class:`~fedtrack.local_filters.vdie.local.VdieLocalFilter`): a local filter starts at its own
    sensor's first measurement and steps at its sensor's measurements only, over the interval since
    its last one, and the centre takes the reports of the scan's sensors. Before the single56
    session the replay fused a silent local's prediction as an independent estimate at every
    re-initialization, stepped a silent local's detector through the scans it missed, and started
    a local absent from the first scan at ``z = 0``.
    """

    name = "dvdie"

    def _start(self, local: GaussianState, present: np.ndarray | None, t: float) -> ScanEstimate:
        est = super()._start(local, present, t)
        self.started = np.ones(self.n_sensors, dtype=bool) if present is None else present.copy()
        self.last_t = np.full(self.n_sensors, t)
        return est

    def _start_prior(self, prior: GaussianState, t: float) -> None:
        super()._start_prior(prior, t)
        self.started = np.ones(self.n_sensors, dtype=bool)
        self.last_t = np.full(self.n_sensors, t)

    def _init_vdie(self, t: float) -> None:
        x, P = embed_cv(self.local.x, self.local.P)
        self.vdie = vdie_init(x, P, np.zeros(x.shape[:-1], dtype=bool), self.config.vdie, t)
        cx, cP = embed_cv(self.centre.x, self.centre.P)
        self.centre_state = CentreState(cx, cP, np.zeros(cx.shape[:-1], dtype=bool))

    def _update(self, cv, ca, zs, Rs, present, t):
        n_batch = zs.ndim - 2
        got = np.ones(self.n_sensors, dtype=bool) if present is None else present
        new = got & ~self.started  # a local filter's first measurement: it starts there (live: init)
        stepped = np.flatnonzero(got & self.started)
        if stepped.size == self.n_sensors and np.all(self.last_t == self.last_t[0]):
            groups = [(stepped, cv, ca)]  # every local over the scan interval: one batched step
        else:
            groups = [(stepped[j:j + 1], *models_for(rounded_interval(t - self.last_t[i]), self.config.q))
                      for j, i in enumerate(stepped)]
        reports = {}
        for idx, cv_i, ca_i in groups:
            def step_fn(post_prev: GaussianState, model: LinearModel, idx=idx) -> tuple[GaussianState, GaussianState]:
                return local_kf_step(post_prev, model, zs[..., idx, :], Rs[..., idx, :, :], None)

            before = self.vdie if idx.size == self.n_sensors else _take_sensors(idx, self.vdie, n_batch)
            after, events, trace = vdie_step(before, t, cv_i, ca_i, self.config.vdie, step_fn)
            self.vdie = after if idx.size == self.n_sensors else _put_sensors(idx, after, self.vdie, n_batch)
            rep = local_reports(before, after, events, trace)
            reports.update({i: _take_sensors(np.array([j]), rep, n_batch) for j, i in enumerate(idx)})
        if new.any():
            x, P = embed_cv(*one_point_init(zs, Rs, self.n_sensors * self.config.initial_velocity_std ** 2))
            no = np.zeros(x.shape[:-1], dtype=bool)
            fresh = vdie_init(x, P, no, self.config.vdie, t)
            self.vdie = _put_sensors(np.flatnonzero(new), _take_sensors(np.flatnonzero(new), fresh, n_batch),
                                     self.vdie, n_batch)
            start = LocalReports(no, x, P, no, np.full(no.shape, EVENT_NONE), GaussianState(x, P), GaussianState(x, P))
            reports.update({i: _take_sensors(np.array([i]), start, n_batch) for i in np.flatnonzero(new)})
        self.started = self.started | new
        self.last_t = np.where(got, t, self.last_t)
        joined = _concat_sensors([reports[i] for i in np.flatnonzero(got)], n_batch)
        self.centre_state = dvdie_centre_step(self.centre_state, cv, ca, joined, restart=bool(new.any()))
        return ScanEstimate(self.centre_state.x, self.centre_state.P, self.centre_state.is_ca,
                            scan_event(joined.kind))


TRACKERS: dict[str, type[Tracker]] = {
    cls.name: cls for cls in (CentralizedKF, FederatedKF, DecentralizedKF, FVDIE, DVDIE)
}


def make_tracker(algorithm: str, n_sensors: int, config: FusionConfig | None = None) -> Tracker:
    """A fresh tracker by algorithm name (one of :data:`ALGORITHMS`)."""
    try:
        cls = TRACKERS[algorithm]
    except KeyError as exc:
        raise ValueError(f"unknown fusion algorithm {algorithm!r}; choose from {', '.join(ALGORITHMS)}") from exc
    return cls(n_sensors, config)

