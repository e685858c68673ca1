"""``fedtrack serve local-filter --sensor ID --mode federated|decentralized``.

Subscribes to ``sensor/<ID>/meas`` and publishes ``local/<ID>/estimate``.

* federated: the FVDIE local filter. Scan k+1 is processed only after the centre's
  reset of scan k has been applied (``fusion/reset/<ID>``); if that reset has not come
  within two of the deployment's ``deadline_s`` (``RESET_WAIT_DEADLINES``; not counting a router
  outage and ``LINK_GRACE_S`` after it: :meth:`fedtrack.zsession.Link.waited`), or at once when the
  centre's liveliness token is gone (not with the filter's own link to its router:
  :class:`fedtrack.zsession.Peers`), the
  filter goes on alone from its own estimate (logged once) and flags the estimate ``no-reset``
  (counted in ``no_reset``) until resets come again. On start, and after a gap in its
  measurements, it adopts the centre's latest track (``fusion/state``) and rejoins from the scan
  after it (counted in ``rejoined``; gaps in ``gaps``).
* decentralized: the DVDIE local filter, a stand-alone single-sensor VDIE.
* ``--filter ekf|ekf-ie|ekf-tsfuzzy``: a 3-D radar filter (papers 002/003) on a radar
  sensor's measurements (see :class:`RadarLocalFilterService`).

After a pause beyond ``max_time_jump_s`` the filter starts again (``restarted``:
:class:`fedtrack.services.clock.ClockJump`). Measurements are processed in ``seq`` order; one
whose time is not after the filter's is rejected (``time_jump``) and dropped when its turn
comes (no gap is counted for its number: it came); one that arrives again for a scan already processed or waiting is
counted in ``late`` and dropped (never silently) if it is the same message; a second,
*different* measurement for such a scan, or a second, different reset of the scan whose reset
was applied, is rejected (``conflict``), counted ``contested`` and named
in the ``contested`` list of the next estimate published (the first message stays and may be
the forgery: docs/wire.md, "Contested scans").
"""

from __future__ import annotations

import pickle
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from fedtrack.config import ConfigError, in_file, load_tables
from fedtrack.deployment import MODES, DeploymentConfig
from fedtrack.jsonl import InputError
from fedtrack.local_filters.radar.filters import RadarFilter, make_radar_filter, parse_measurement, take_checked
from fedtrack.local_filters.vdie.config import PipelineSettings
from fedtrack.local_filters.vdie.local import (
    FederatedLocalFilter,
    LocalOutput,
    VdieLocalFilter,
)
from fedtrack.services.admission import digest
from fedtrack.services.base import Service, Subscription, service_kwargs, service_parser
from fedtrack.services.clock import ClockJump
from fedtrack.services.lead import NumberedLeadGuard
from fedtrack.services.rejections import (
    Conflict,
    Numerical,
    Rejected,
    require_covariances,
    require_finite,
)
from fedtrack.wire import (
    FusedTrack,
    LocalEstimate,
    ManeuverInfo,
    Measurement,
    Reset,
    measurement_to_replay,
)
from fedtrack.zsession import Peers, id_arg

FILTERS = ("vdie", "ekf", "ekf-ie", "ekf-tsfuzzy")
TAKEN_KEPT = 64  # processed scans whose measurement digest is kept to tell a conflict from a re-delivery
# Deadlines (deployment.deadline_s) a federated filter waits for its reset before it goes on alone: the
# centre fuses the scan at the latest one deadline after the scan's first estimate arrived, and the reset
# must then still be made and delivered, which the second deadline bounds. With one, whenever the centre
# waited out its deadline (another filter slow) the first filter gave up just before the reset came and went
# on alone; on a loaded machine its later resets all came after its next scan, so it stayed alone (before
# 2026-11-27: tests/test_faults.py::test_kill_local_filter_mid_maneuver at load 21, filter 2 alone for
# scans 25-42 and the degraded scans not those of the kill).
RESET_WAIT_DEADLINES = 2


class LocalFilterService(Service):
    """One sensor's local filter."""

    role = "local-filter"
    tick_period_s = 0.02
    # the filter rebinds its records (never changes them in place): a pickle of these is the whole state
    state_attrs = ("filter", "pending", "processed_up_to", "refused_up_to", "processed_t", "applied", "reset_up_to",
                   "waiting_since", "alone", "taken", "contested_scans", "lead")
    tick_state_attrs = ()  # on_tick checkpoints only when a scan is waiting (50 ticks a second)

    def __init__(self, sensor: str, mode: str, filt: FederatedLocalFilter | VdieLocalFilter,
                 deadline_s: float, max_seq_jump: int = 1000, max_time_jump_s: float = 3600.0,
                 **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.sensor = sensor
        self.max_seq_jump = max_seq_jump
        self.jump = ClockJump(max_time_jump_s)
        self.processed_t: float | None = None  # time of the scan processed last
        self.applied: Reset | None = None  # the reset applied last
        self.mode = mode
        self.filter = filt
        self.fresh = pickle.dumps(filt)  # the filter as it starts (again, after a pause: start_again)
        self.reset_timeout_s = RESET_WAIT_DEADLINES * deadline_s
        self.pending: dict[int, Measurement] = {}
        self.lead: NumberedLeadGuard[Measurement] = NumberedLeadGuard.one_sensor()  # far ahead: waits for the next
        self.taken: dict[int, bytes] = {}  # digests of the last TAKEN_KEPT scans processed, by seq
        self.processed_up_to = -1
        self.refused_up_to = -1  # the last scan refused when its turn came (time_jump, numerical): no gap
        self.reset_up_to = -1
        self.waiting_since: float | None = None
        self.alone = False  # carrying on without resets (the fusion centre is silent or gone)
        self.centres = Peers()  # the fusion centre's liveliness tokens (filled by a Zenoh thread)
        self._liveliness: Any = None

    def subscriptions(self) -> list[Subscription]:
        subs = [Subscription(self.keys.sensor_meas(self.sensor), Measurement, self.on_measurement, recover=True)]
        if self.mode == "federated":
            subs.append(Subscription(self.keys.fusion_reset(self.sensor), Reset, self.on_reset, recover=True))
        return subs

    def on_start(self) -> None:
        if self.mode == "federated":
            self._liveliness = self.session.liveliness().declare_subscriber(
                self.keys.alive("fusion-center"), self._on_centre_liveliness, history=True)
        self.rejoin("started")

    def on_stop(self) -> None:
        if self._liveliness is not None:
            self._liveliness.undeclare()

    def _on_centre_liveliness(self, sample: Any) -> None:
        """Zenoh thread: a fusion centre token appeared or went (:meth:`centre_gone`)."""
        self.centres.token(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT, time.monotonic())

    def centre_gone(self, now: float) -> bool:
        """A dead fusion centre is not waited for (its resets cannot come). It is gone when no token under
        ``alive/fusion-center/`` is left and every one that went counts as a death (:meth:`Peers.gone`: not
        one that went with this filter's own link to its router, until it had its time to come back): a
        token of another id declared and withdrawn (a forgery, without authentication) does not end the
        wait for the real centre's resets."""
        lost = self.centres.lost
        return not self.centres.present and bool(lost) and self.centres.gone(self.link(), now) >= lost.keys()

    def rejoin(self, why: str) -> None:
        """Federated: adopt the fusion centre's latest track (``fusion/state``), if there is one, as a
        reset (``P`` scaled by this filter's sharing factor) and go on from the scan after it."""
        if self.mode != "federated":
            return
        assert isinstance(self.filter, FederatedLocalFilter)
        for track in self.query(self.keys.fusion_state(), FusedTrack)[:1]:
            if track.seq <= self.processed_up_to:
                return
            if {"cv": 4, "ca": 6}.get(track.model) != track.x.shape[0]:
                self.note_rejected(self.keys.fusion_state(), Rejected(
                    "wrong_model", f"fusion centre state of a {track.x.shape[0]}-D {track.model!r} state"))
                return
            self.filter.apply_reset(track.t, np.asarray(track.x), self.filter.beta * np.asarray(track.P))
            self.processed_up_to = self.reset_up_to = track.seq
            self.count("rejoined")
            self.log.warning("%s: rejoined from the fusion centre's state of scan %d (t=%g, %s)", why, track.seq,
                             track.t, track.model)

    def on_measurement(self, msg: Measurement) -> None:
        if msg.kind != "position" or msg.z.shape != (2,):
            self.count("wrong_kind")
            self.log.warning("ignored a %s measurement of dimension %d: this filter takes 2-D positions",
                             msg.kind, msg.z.shape[0])
            return
        if msg.seq <= self.processed_up_to or msg.seq in self.pending:
            first = digest(self.pending[msg.seq]) if msg.seq in self.pending else self.taken.get(msg.seq)
            if first is None or first == digest(msg):
                again = self.lead.contradicted(msg)
                if self.abandons(again, msg):
                    self.start_again(msg, forget=True)
                    for scan in again:
                        self.on_measurement(scan)
                    return
                self.count("late")
                return
            self.contest(self.keys.sensor_meas(self.sensor), Conflict(
                msg.seq, f"a second, different measurement for scan {msg.seq} (the first stays)"))
            return
        expected = max([self.processed_up_to, self.refused_up_to, *self.pending]) + 1
        if self.processed_up_to >= 0 and msg.seq - expected > self.max_seq_jump:
            raise Rejected("seq_jump", f"scan {msg.seq} is more than {self.max_seq_jump} ahead of {expected}")
        if self.jump.restart(self.processed_t, msg.sensor, msg.seq, msg.t):
            self.start_again(msg)
        times = self.lead.times()
        queued = [scan.seq for scan in self.in_time(self.lead, self.keys.sensor_meas(self.sensor), msg)
                  if (scan is msg or not (scan.seq <= self.processed_up_to or scan.seq in self.pending))
                  and self._take(scan)]  # (a held scan repeated meanwhile is taken once)
        self.process_ready()
        if msg.seq in queued and msg.seq not in self.pending and self.taken.get(msg.seq) is None:
            self.lead.restore(times)  # the filter failed on it: as if it never came

    def start_again(self, msg: Measurement, forget: bool = False) -> None:
        """Scan ``msg`` follows one rejected beyond ``max_time_jump_s`` (:class:`ClockJump`): the
        filter starts again from it, dropping the scans still waiting, and waits for no reset of the
        scans before it (its estimate is flagged ``init``: the centre starts again too). ``forget``: the
        filter's only scan was abandoned (:meth:`abandons`, counted there), the numbers taken forgotten too."""
        if forget:
            self.processed_up_to = self.refused_up_to = -1
            self.taken = {}
        else:
            self.restarted(msg)
        self.count("dropped_scans", len(self.pending))
        self.filter, self.pending, self.lead = pickle.loads(self.fresh), {}, NumberedLeadGuard.one_sensor()
        self.processed_t, self.reset_up_to, self.waiting_since = None, self.processed_up_to, None

    def _take(self, msg: Measurement) -> bool:
        """Queue scan ``msg`` (checked) for the filter, after the rejoin a gap before it calls for;
        False when that rejoin made it late. A scan refused when its turn came is no gap."""
        expected = max([self.processed_up_to, self.refused_up_to, *self.pending]) + 1
        if self.processed_up_to >= 0 and msg.seq > expected:
            self.count("gaps", msg.seq - expected)
            self.log.warning("measurements %d..%d of sensor %s never arrived", expected, msg.seq - 1, self.sensor)
            if not self.pending:
                self.rejoin(f"after the gap {expected}..{msg.seq - 1}")
                if msg.seq <= self.processed_up_to:
                    self.count("late")
                    return False
        self.lead.took(msg.sensor, msg.t, msg.seq)
        self.pending[msg.seq] = msg
        return True

    def on_reset(self, msg: Reset) -> None:
        if self.applied is not None and msg.seq == self.applied.seq:
            same = (msg.t == self.applied.t and msg.model == self.applied.model
                    and np.array_equal(msg.x, self.applied.x) and np.array_equal(msg.P, self.applied.P))
            if same:
                self.count("duplicate")
                return
            self.contest(self.keys.fusion_reset(self.sensor), Conflict(
                msg.seq, f"a second, different reset of scan {msg.seq} (the first stays)"))
            return
        if msg.seq != self.processed_up_to or msg.seq <= self.reset_up_to:
            self.count("stale_reset")  # only the reset of the scan just processed applies
            return
        if msg.t != self.processed_t:
            raise Rejected("time_jump", f"reset of scan {msg.seq} at t={msg.t}, the scan was at t={self.processed_t}")
        if {"cv": 4, "ca": 6}.get(msg.model) != msg.x.shape[0]:
            raise Rejected("wrong_model", f"reset of a {msg.x.shape[0]}-D {msg.model!r} state: this filter takes "
                           "a 4-D cv or 6-D ca state")
        assert isinstance(self.filter, FederatedLocalFilter)
        self.filter.apply_reset(msg.t, msg.x, msg.P)
        self.reset_up_to = msg.seq
        self.applied = msg
        if self.alone:
            self.alone = False
            self.log.warning("resets from the fusion centre resumed at scan %d", msg.seq)
        self.process_ready()

    def on_tick(self) -> None:
        if self.pending:
            with self.guarded("on_tick"):
                self.process_ready()

    def process_ready(self) -> None:
        """Process pending scans in order while their precondition (reset) holds."""
        while self.pending:
            seq = min(self.pending)
            if self.mode == "federated" and self.processed_up_to >= 0 and self.reset_up_to < self.processed_up_to:
                now = time.monotonic()
                if self.waiting_since is None:
                    self.waiting_since = now
                centre_gone = self.centre_gone(now)
                waited = self.link().waited(self.waiting_since, now)  # not during a router outage
                if not (self.alone or centre_gone) and waited < self.reset_timeout_s:
                    return
                self.count("no_reset")
                if not self.alone:
                    self.alone = True
                    why = ("the fusion centre is gone (liveliness)" if centre_gone else
                           f"no reset for scan {self.processed_up_to} within {self.reset_timeout_s:g} s")
                    self.log.warning("%s: carrying on alone (estimates flagged no-reset)", why)
                self.reset_up_to = self.processed_up_to  # go on from the local estimate
                self._process(self.pending.pop(seq), ("no-reset",))
            else:
                self._process(self.pending.pop(seq), ())
            self.waiting_since = None

    def _process(self, msg: Measurement, flags: tuple[str, ...]) -> None:
        """Filter scan ``msg`` (taken off ``pending``) and publish the estimate; a scan the filter
        fails on is dropped, with the filter as it was before it (a rejection)."""
        with self.guarded(f"scan {msg.seq}", key=self.keys.sensor_meas(self.sensor)) as attempt:
            if self.filter.t is not None and msg.t <= self.filter.t:  # a broken clock: the filter would predict back
                raise Rejected("time_jump", f"scan {msg.seq} at t={msg.t}, not after the filter's time {self.filter.t}")
            out = self.filter.process(msg.t, np.asarray(msg.z), np.asarray(msg.R))
            require_finite(f"scan {msg.seq}: the local estimate", out.x, out.P, out.x_prior, out.P_prior)
            require_covariances(f"scan {msg.seq}: the local estimate", out.P, out.P_prior)
            self.processed_up_to = msg.seq
            self.processed_t = msg.t
            self.taken = {seq: d for seq, d in self.taken.items() if seq > msg.seq - TAKEN_KEPT} | {msg.seq: digest(msg)}
            self.publish(self.keys.local_estimate(self.sensor),
                         to_message(self.sensor, msg, out, flags, self.take_contested()))
        if attempt.failed:
            self.refused_up_to = max(self.refused_up_to, msg.seq)


class RadarLocalFilterService(Service):
    """A 3-D radar local filter (``--filter ekf|ekf-ie|ekf-tsfuzzy``) publishing its estimates.

    The state is 3-D (``[x, vx, y, vy, z, vz]``, model ``cv3``/``ca3`` as the filter labels
    it); the 2-D federated fusion center does not fuse such estimates (it counts them as
    ``wrong_model``). The filter keeps no prior for the wire, so ``x_prior``/``P_prior``
    repeat the posterior and the estimate is flagged ``no-prior``. A scan not after the filter's
    time is rejected (``time_jump``, as at the 2-D local filters). It starts again (``restarted``)
    after a pause beyond ``max_time_jump_s`` (:class:`ClockJump`) and on the second scan in a row
    it cannot process (``numerical``: :func:`take_checked`, which ``replay`` follows too).
    """

    role = "local-filter"
    state_attrs = ("filter", "processed_up_to", "lead")

    def __init__(self, sensor: str, filt: RadarFilter, max_time_jump_s: float = 3600.0, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.sensor = sensor
        self.filter = filt
        self.fresh = pickle.dumps(filt)  # the filter as it starts (again: start_again)
        self.jump = ClockJump(max_time_jump_s)
        self.failed = False  # the last scan failed (numerical); not checkpointed: its rejection must remember it
        self.processed_up_to = -1
        self.lead: NumberedLeadGuard[Measurement] = NumberedLeadGuard.one_sensor()  # far ahead: waits for the next

    def subscriptions(self) -> list[Subscription]:
        return [Subscription(self.keys.sensor_meas(self.sensor), Measurement, self.on_measurement)]

    def _fresh(self) -> None:
        """The filter starts afresh (its only scan abandoned: :meth:`contradicting`), the numbers taken forgotten."""
        self.filter, self.lead, self.processed_up_to = pickle.loads(self.fresh), NumberedLeadGuard.one_sensor(), -1

    def on_measurement(self, msg: Measurement) -> None:
        if msg.kind != "radar":
            self.count("wrong_kind")
            return
        if self.contradicting(self.lead, msg, self._fresh, self.on_measurement):
            return
        if msg.seq <= self.processed_up_to:
            self.count("late")
            return
        if self.jump.restart(self.filter.last_t, msg.sensor, msg.seq, msg.t):
            self.start_again(msg)
        for scan in self.in_time(self.lead, self.keys.sensor_meas(self.sensor), msg):
            if scan.seq > self.processed_up_to:
                with self.guarded(f"scan {scan.seq}", key=self.keys.sensor_meas(self.sensor)):  # each on its own
                    self._step(scan)

    def start_again(self, msg: Measurement, why: str = "after a pause beyond max_time_jump_s") -> None:
        """The filter starts again from scan ``msg`` (two-point initialization)."""
        self.restarted(msg, why)
        self.filter, self.lead = pickle.loads(self.fresh), NumberedLeadGuard.one_sensor()

    def _step(self, msg: Measurement) -> None:
        """Filter radar scan ``msg`` and publish the estimate (:func:`take_checked`: on the second scan
        in a row that fails, ``numerical``, start again from it)."""
        last_t = self.filter.last_t
        if last_t is not None and not msg.t > last_t:  # as the 2-D local filters: a broken or forged clock
            raise Rejected("time_jump", f"scan {msg.seq} at t={msg.t}, not after the filter's time {last_t}")
        self.lead.took(msg.sensor, msg.t, msg.seq)
        where = f"scan {msg.seq}"
        try:
            filt, est = take_checked(self.filter, parse_measurement(measurement_to_replay(msg), where), self.failed,
                                     where)
        except Numerical:
            self.failed = True
            raise
        except InputError as exc:  # a rejection like any other: rejected and rejected_input, nothing kept
            raise Rejected("input", str(exc)) from None
        if filt is not self.filter:
            self.start_again(msg, "on the second scan in a row it cannot process")
            self.lead.took(msg.sensor, msg.t, msg.seq)
        self.filter, self.failed, self.processed_up_to = filt, False, msg.seq
        if est is None:  # the first measurement only starts the two-point initialization
            return
        x, P = np.asarray(est["x"]), np.asarray(est["P"])
        self.publish(self.keys.local_estimate(self.sensor), LocalEstimate.unchecked(
            sensor=self.sensor, seq=msg.seq, t=msg.t, model=est["model"], x=x, P=P, x_prior=x, P_prior=P,
            stamp_ns=msg.stamp_ns, degraded=("no-prior",)))


def to_message(sensor: str, meas: Measurement, out: LocalOutput, flags: tuple[str, ...],
               contested: tuple[int, ...] = ()) -> LocalEstimate:
    """The estimate of scan ``meas``; ``contested``: the scans it names contested (docs/wire.md)."""
    maneuver = None
    if out.event is not None:
        maneuver = ManeuverInfo(event=out.event, detected=out.event in ("onset", "new-ca"), onset=out.onset,
                                u=out.u, gamma=out.gamma)
    return LocalEstimate.unchecked(sensor=sensor, seq=meas.seq, t=meas.t, model=out.model, x=out.x, P=out.P,
                         x_prior=out.x_prior, P_prior=out.P_prior, stamp_ns=meas.stamp_ns, maneuver=maneuver,
                         degraded=(("init",) if out.init else ()) + flags, contested=contested)


def main(argv: list[str]) -> int:
    parser = service_parser("local-filter", "run one sensor's local filter", per_sensor=True)
    parser.add_argument("--sensor", required=True, type=id_arg("--sensor"), help="the sensor id this filter serves")
    parser.add_argument("--mode", choices=MODES, help="federated or decentralized (default: deployment.mode of "
                                                        f"--config, else {DeploymentConfig().mode})")
    parser.add_argument("--config", type=Path, help="deployment TOML ([deployment], [fusion], [[sensor]]; default: "
                        "none, every key at its default, but --filter vdie needs the deployment's sensors from it: "
                        "[fusion] sensors or the [[sensor]] ids)")
    parser.add_argument("--filter", choices=FILTERS, default="vdie",
                        help="vdie: the 2-D federated/DVDIE local filter (default); ekf, ekf-ie, ekf-tsfuzzy: "
                             "3-D radar filters configured by [radar_filter]")
    args = parser.parse_args(argv)
    settings = load_tables(args.config, PipelineSettings)
    if args.filter != "vdie":
        with in_file(args.config):
            folder = None if args.config is None else args.config.parent
            radar = make_radar_filter(args.filter, settings.radar_filter, folder)
        return RadarLocalFilterService(args.sensor, radar, settings.deployment.max_time_jump_s,
                                       **service_kwargs(parser, args)).run()
    mode = args.mode or settings.deployment.mode
    sensors = settings.fusion.sensors or tuple(s.id for s in settings.sensor)
    with in_file(args.config):
        if not sensors:  # the filter's share of the information, 1/beta_i, needs every sensor of the deployment
            raise ConfigError(f"fusion.sensors: none given: the filter of sensor {args.sensor!r} needs every sensor "
                              "of the deployment; give --config FILE with [fusion] sensors or [[sensor]] ids")
        if args.sensor not in sensors:
            raise ConfigError(f"fusion.sensors: sensor {args.sensor!r} is not listed ({', '.join(sensors)})")
        n = len(sensors)
        betas = settings.fusion.betas(n)
    if mode == "federated":
        beta = float(betas[sensors.index(args.sensor)])
        filt: FederatedLocalFilter | VdieLocalFilter = FederatedLocalFilter(beta, n, settings.fusion)
    else:
        filt = VdieLocalFilter(n, settings.fusion)
    return LocalFilterService(args.sensor, mode, filt, settings.deployment.deadline_s,
                              settings.deployment.max_seq_jump, settings.deployment.max_time_jump_s,
                              **service_kwargs(parser, args)).run()
