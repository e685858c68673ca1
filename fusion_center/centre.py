"""The fusion centre of the distributed pipeline, working from received local estimates.

:class:`FederatedCentre` (FVDIE) fuses the local posteriors (15)-(16), runs the input
estimator on the fused quantities and returns the resets (20)-(22);
:class:`DecentralizedCentre` (DVDIE) fuses single-sensor VDIE locals without feedback.
Both call the same functions as ``fedtrack.fusion_center.trackers`` (used by ``fedtrack
replay``), so a healthy deployment reproduces ``replay`` to round-off. A scan whose
local estimates did not all arrive is fused from those that did (sharing factors
renormalized, see :func:`fedtrack.fusion_center.fusion.federated_fuse`) and marked degraded.
So is a federated scan in which some local filters went on alone (flagged ``init``: they missed
the last reset, so (15)-(16) do not hold for their estimates) while others did not: the alone
estimates are left out of that scan, and the reset sent to every local brings them back.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fedtrack.fusion_center.fusion import federated_fuse, federated_reset
from fedtrack.fusion_center.trackers import ScanEstimate, fuse_independent, scan_event
from fedtrack.local_filters.linear.kalman import GaussianState, predict
from fedtrack.local_filters.linear.models import CA, LinearModel
from fedtrack.local_filters.linear.tracking import models_for, rounded_interval
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.local_filters.vdie.estimation import (
    EVENT_NAMES,
    EVENT_NONE,
    CentreState,
    LocalReports,
    VdieEvents,
    cv_part,
    dvdie_centre_step,
    embed_cv,
    vdie_init,
    vdie_step,
)
from fedtrack.local_filters.vdie.local import LocalOutput

EVENT_CODES = {name: code for code, name in EVENT_NAMES.items()}


class ResetCommand(NamedTuple):
    """What local filter ``i`` adopts after a scan: ``x``, ``P = beta_i P_fused`` in ``model``."""

    model: str
    x: np.ndarray
    P: np.ndarray
    share: float  # 1 / beta_i


class CentreResult(NamedTuple):
    estimate: ScanEstimate  # CA layout
    events: VdieEvents | None  # the master's own decision (federated)
    resets: dict[str, ResetCommand]
    fused: tuple[str, ...]  # the sensors whose estimates this scan fused


def _own_order(x: np.ndarray, P: np.ndarray, is_ca: bool) -> GaussianState:
    return GaussianState(x, P) if is_ca else cv_part(x, P)


class FederatedCentre:
    """FVDIE master: fusion (15)-(16), input estimation on fused quantities, reset (20)-(22)."""

    def __init__(self, sensors: list[str], config: FusionConfig) -> None:
        self.sensors = list(sensors)
        self.config = config
        self.betas = config.betas(len(sensors))
        self.vdie = None
        self.t: float | None = None

    @property
    def model(self) -> str:
        return CA if self.vdie is not None and bool(self.vdie.is_ca) else "cv"

    def fuse(self, t: float, outputs: dict[str, LocalOutput]) -> CentreResult:
        present = np.array([s in outputs for s in self.sensors])
        if self.vdie is None and self.config.x0 is not None:
            self._start(embed_cv(np.asarray(self.config.x0, float), np.asarray(self.config.P0, float)), t)
        elif self.vdie is None or all(o.init for o in outputs.values()):
            # start, or every local went on alone (no reset: (15)-(16) do not apply): fuse them as
            # independent estimates; a restarted centre may meet locals in CA: their CV part
            locals_ = self._stack(outputs, lambda o: cv_part(o.x, o.P) if o.x.shape[0] == 6
                                  else GaussianState(o.x, o.P), present, None)
            fused = fuse_independent(locals_, present)
            self._start(embed_cv(fused.x, fused.P), t)
            return self._result(None, tuple(outputs))
        cv, ca = models_for(rounded_interval(t - self.t), self.config.q)
        self.t = t
        current = self.model
        # left out of this scan: a local that went on alone (it missed the last reset: its estimate is
        # not its share of the master's prior plus its measurements, which (15)-(16) presume; fused
        # as if it were, a restart that left some locals alone cost 25 m RMS against 6 m for the 20
        # scans after), and a local still in the other model (e.g. back after a gap)
        dim = 6 if current == CA else 4
        usable = {s: o for s, o in outputs.items() if not o.init and o.x.shape[0] == dim}
        mask = np.array([s in usable for s in self.sensors])

        def step_fn(post_prev: GaussianState, model: LinearModel) -> tuple[GaussianState, GaussianState]:
            master_prior = predict(post_prev, model.F, model.Q)
            if model.name != current:  # the branch no run is in: never selected
                return master_prior, master_prior
            posts = self._stack(usable, lambda o: GaussianState(o.x, o.P), mask, master_prior)
            partial = not mask.all()
            fused = federated_fuse(posts, self.betas, mask if partial else None,
                                   master_prior if partial else None)
            return master_prior, fused

        self.vdie, events, _ = vdie_step(self.vdie, t, cv, ca, self.config.vdie, step_fn)
        return self._result(events, tuple(usable))

    def _start(self, xp: tuple[np.ndarray, np.ndarray], t: float) -> None:
        self.vdie = vdie_init(xp[0], xp[1], np.zeros((), dtype=bool), self.config.vdie, t)
        self.t = t

    def _stack(self, outputs: dict[str, LocalOutput], pick, present: np.ndarray,
               fill: GaussianState | None) -> GaussianState:
        states = [pick(outputs[s]) if s in outputs else fill for s in self.sensors]
        if fill is None:  # first scan: absent sensors get a harmless placeholder, masked out
            ref = next(st for st in states if st is not None)
            states = [st if st is not None else GaussianState(ref.x, ref.P) for st in states]
        return GaussianState(np.stack([s.x for s in states]), np.stack([s.P for s in states]))

    def _result(self, events: VdieEvents | None, fused: tuple[str, ...]) -> CentreResult:
        is_ca = bool(self.vdie.is_ca)
        kind = int(events.kind) if events is not None else EVENT_NONE
        est = ScanEstimate(self.vdie.x, self.vdie.P, np.asarray(is_ca), np.asarray(kind))
        own = _own_order(self.vdie.x, self.vdie.P, is_ca)
        local = federated_reset(own, self.betas)
        resets = {s: ResetCommand(CA if is_ca else "cv", local.x[i], local.P[i], float(1.0 / self.betas[i]))
                  for i, s in enumerate(self.sensors)}
        return CentreResult(est, events, resets, tuple(s for s in self.sensors if s in fused))


class DecentralizedCentre:
    """DVDIE centre: Hashemipour fusion of single-sensor VDIE locals, without feedback."""

    def __init__(self, sensors: list[str], config: FusionConfig) -> None:
        self.sensors = list(sensors)
        self.config = config
        self.state: CentreState | None = None
        self.t: float | None = None

    def fuse(self, t: float, outputs: dict[str, LocalOutput]) -> CentreResult:
        got = [s for s in self.sensors if s in outputs]
        if self.state is None and self.config.x0 is None:
            posts = GaussianState(np.stack([outputs[s].x for s in got]), np.stack([outputs[s].P for s in got]))
            fused = fuse_independent(posts, None)
            self.state = CentreState(*embed_cv(fused.x, fused.P), np.zeros((), dtype=bool))
            self.t = t
            return self._result(EVENT_NONE, tuple(got))
        if self.state is None:
            x0, P0 = embed_cv(np.asarray(self.config.x0, float), np.asarray(self.config.P0, float))
            self.state = CentreState(x0, P0, np.zeros((), dtype=bool))
            self.t = t
        cv, ca = models_for(rounded_interval(t - self.t), self.config.q)
        self.t = t
        received = [outputs[s] for s in got]
        reports = stack_reports(received)
        restart = any(o.init for o in received)
        self.state = dvdie_centre_step(self.state, cv, ca, reports, restart)
        return self._result(int(scan_event(reports.kind)), tuple(got))

    def _result(self, kind: int, fused: tuple[str, ...]) -> CentreResult:
        est = ScanEstimate(self.state.x, self.state.P, np.asarray(self.state.is_ca), np.asarray(kind))
        return CentreResult(est, None, {}, fused)


def _layout(x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """A CV (4) or CA (6) estimate in the CA layout, and whether it is CA."""
    if x.shape[0] == 6:
        return x, P, True
    return (*embed_cv(x, P), False)


def stack_reports(outputs: list[LocalOutput]) -> LocalReports:
    """Received local outputs as the DVDIE centre's :class:`LocalReports` (sensor axis first)."""
    xs, Ps, now_ca, was_ca, kinds, pxs, pPs = [], [], [], [], [], [], []
    for o in outputs:
        x, P, is_ca = _layout(o.x, o.P)
        xs.append(x)
        Ps.append(P)
        now_ca.append(is_ca)
        px, pP, p_ca = _layout(o.x_prior, o.P_prior)
        pxs.append(px)
        pPs.append(pP)
        was_ca.append(p_ca)
        kinds.append(EVENT_CODES.get(o.event, EVENT_NONE) if o.event else EVENT_NONE)
    x, P = np.stack(xs), np.stack(Ps)
    return LocalReports(np.array(was_ca), x, P, np.array(now_ca), np.array(kinds),
                        GaussianState(np.stack(pxs), np.stack(pPs)), GaussianState(x, P))
