"""``fedtrack serve fusion-center --sensors ID,ID,... --mode federated|decentralized``.

Collects ``local/<id>/estimate`` per scan (``seq``) and fuses scan k when every expected
local filter has reported, except those whose liveliness token ``alive/local-filter/<id>``
or ``alive/sensor/<id>`` went away (the process died; logged; not a token that went with the
centre's own link to its router, until it has had ``LINK_GRACE_S`` to come back:
:class:`fedtrack.zsession.Peers`), or when ``deadline_s``
has passed since the first estimate arrived (not counting a router outage and ``LINK_GRACE_S``
after it: :meth:`fedtrack.zsession.Link.waited`). A scan fused without
every configured sensor uses those it has (sharing factors renormalized) and is marked
degraded; a dead local filter (its token gone within milliseconds of the process dying)
costs no waiting, a frozen one costs the deadline. Scans are fused in order. Publishes, per scan: the resets
``fusion/reset/<id>`` (federated), the track ``fusion/track``, and on a maneuver decision
``fusion/event``. ``fusion/state`` answers with the latest track (restarted sensors and
local filters resume from it). With ``--snapshot PATH`` (``launch`` gives
``OUT/fusion-center.snapshot`` and removes it when a run starts) the centre writes its
state after every scan (atomically, as data only: ``fedtrack.fusion_center.snapshot``) and a
restarted centre resumes from it (counter ``restored``) if it missed at most
``SNAPSHOT_MAX_GAP`` scans; otherwise (the local filters went on alone meanwhile), without a
snapshot, and with one it refuses (counter ``snapshot_refused``: another deployment, version
or configuration, cut, corrupted or tampered with), it rebuilds its state from the first scan
of local estimates it receives, as at start-up (counter ``rebuilt``).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from fedtrack.config import ConfigError, finite_number, in_file, load_tables
from fedtrack.deployment import MODES, DeploymentConfig
from fedtrack.fusion_center.centre import (
    CentreResult,
    DecentralizedCentre,
    FederatedCentre,
)
from fedtrack.fusion_center.snapshot import SNAPSHOT_MAGIC, restored, snapshot_data
from fedtrack.local_filters.linear.models import CA_ACC, CV_IN_CA
from fedtrack.local_filters.vdie.config import PipelineSettings
from fedtrack.local_filters.vdie.estimation import EVENT_NAMES, EVENT_NONE
from fedtrack.local_filters.vdie.local import LocalOutput
from fedtrack.services.admission import MAX_CONTESTED, contested_extra, digest
from fedtrack.services.base import QueryHandler, Service, Subscription, service_kwargs, service_parser
from fedtrack.services.clock import ClockJump
from fedtrack.services.dispatch import REJECT_LOG_INTERVAL_S
from fedtrack.services.lead import LEAD_INTERVALS, NumberedLeadGuard
from fedtrack.services.rejections import Conflict, Numerical, Rejected
from fedtrack.services.snapshot import read_sealed, write_sealed
from fedtrack.wire import FusedTrack, LocalEstimate, ManeuverEvent, Reset, acceptable_covariances
from fedtrack.zsession import Peers

FUSED_KEPT = 64  # fused scans whose estimate digests are kept to tell a late conflict from a re-delivery
SNAPSHOT_MAX_GAP = 3  # scans missed beyond which a restored snapshot is dropped for a rebuild
SNAPSHOT_FAILURES_LOGGED = 100  # a snapshot that cannot be written: the first failure logged, then every 100th
# scans passed over whose late estimates are kept while one sensor's start stands alone (_passed_over): a
# bound on memory, not a tuning. The scans start again from one at least LEAD_INTERVALS before the next, and
# the sensors' estimates of one scan arrive within LEAD_INTERVALS scans of each other (the lead rule's bound on
# how late a scan may be); twice that keeps such a scan until its second sensor's estimate comes.
BEHIND_KEPT = 2 * LEAD_INTERVALS
TOKEN_LINES = 2  # lines a peer's token may have logged every REJECT_LOG_INTERVAL_S: its going and its return


class ScanBuffer:
    """Local estimates of one scan, as they arrive."""

    def __init__(self, t: float, now: float) -> None:
        self.t = t
        self.first_arrival = now
        self.outputs: dict[str, LocalOutput] = {}
        self.stamps: list[int] = []
        self.digests: dict[str, bytes] = {}  # per sensor, the digest of the estimate taken
        self.contested = False  # a second, different estimate of one of its sensors arrived (docs/wire.md)
        self.named: set[int] = set()  # contested scans its estimates name (their local filters')


class FusionCenterService(Service):
    role = "fusion-center"
    tick_period_s = 0.01
    # the centre's records are rebound, never changed in place: a pickle of these (dispatch's checkpoint,
    # in memory) is the whole state
    state_attrs = ("centre", "scans", "next_seq", "last_track", "restored", "fused", "left_out", "contested_scans",
                   "lead", "seconded", "behind")
    tick_state_attrs = ()  # on_tick checkpoints only when a scan is waiting (100 ticks a second)

    def __init__(self, sensors: list[str], centre: FederatedCentre | DecentralizedCentre,
                 deadline_s: float, snapshot: Path | None = None, max_seq_jump: int = 1000,
                 max_time_jump_s: float = 3600.0, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.max_seq_jump = max_seq_jump
        self.jump = ClockJump(max_time_jump_s)
        self.snapshot = snapshot
        self.restored = False  # resumed from the snapshot, no scan fused since
        self.sensors = sensors
        self.centre = centre
        self.deadline_s = deadline_s
        self.scans: dict[int, ScanBuffer] = {}
        # an estimate stamped far ahead of the data waits for another sensor's (fedtrack/services/lead.py)
        self.lead: NumberedLeadGuard[LocalEstimate] = NumberedLeadGuard()
        self.next_seq: int | None = None
        self.last_track: FusedTrack | None = None
        self.fused: dict[int, dict[str, bytes]] = {}  # the last FUSED_KEPT scans' estimate digests per sensor
        self.left_out: tuple[str, ...] = ()  # sensors whose estimates the last scan received but did not fuse
        # whether the scans' start stands: a scan with two sensors' estimates fused (or the state restored);
        # until then, the late estimates of scans passed over (:meth:`_passed_over`)
        self.seconded = len(sensors) < 2
        self.behind: dict[int, dict[str, LocalEstimate]] = {}
        # the sensors' and local filters' liveliness tokens (keys ROLE/ID), filled by Zenoh threads
        self.peers = Peers()
        # token -> (start of its logging window, lines in it, changes not logged since the last line)
        self._token_said: dict[str, tuple[float, int, int]] = {}
        self._liveliness: list[Any] = []

    def on_start(self) -> None:
        self._restore()
        self._liveliness = [self.session.liveliness().declare_subscriber(
            self.keys.alive(role), lambda s, role=role: self._on_liveliness(role, s), history=True)
            for role in ("sensor", "local-filter")]

    def _restore(self) -> None:
        """Resume from ``--snapshot`` if it holds this deployment's centre (a restart mid-run). A file
        it refuses (read as data only, every field checked: fedtrack.fusion_center.snapshot) is
        logged in one line naming the field and counted ``snapshot_refused``; the centre then starts
        fresh, as without one."""
        if self.snapshot is None or not self.snapshot.is_file():
            return
        try:
            centre, track = restored(read_sealed(self.snapshot, SNAPSHOT_MAGIC), self.keys.deployment, self.centre)
        except (OSError, ValueError) as exc:  # every refusal of the reader is a ValueError naming the field
            self.count("snapshot_refused")
            self.log.warning("snapshot %s refused (%s: %s): starting fresh", self.snapshot, type(exc).__name__, exc)
            return
        self.centre, self.last_track, self.next_seq = centre, track, track.seq + 1
        self.restored = self.seconded = True
        self.count("restored")
        self.log.warning("restored the state of scan %d (t=%g) from %s", track.seq, track.t, self.snapshot)

    def _save(self, track: FusedTrack) -> None:
        """Write the state after ``track`` to ``--snapshot`` (atomically: a kill leaves the previous one).
        A write that fails (the disk full, the file size limit, no file descriptor left) is counted
        ``snapshot_failed`` and the scan stands: the snapshot only serves a restart, which then finds an
        older one (``SNAPSHOT_MAX_GAP``). Before 2026-11-27 the failure undid the scan after its track and
        resets were out: under a 1,000-byte file size limit from scan 43, 58 of 101 scans were rejected
        as ``handler_error``, the state stayed at scan 43 and the replay no longer equalled the tracks."""
        if self.snapshot is None:
            return
        data = snapshot_data(self.keys.deployment, self.centre, track)
        try:
            write_sealed(self.snapshot, SNAPSHOT_MAGIC, data)
        except OSError as exc:
            self.count("snapshot_failed")
            if self.counters["snapshot_failed"] % SNAPSHOT_FAILURES_LOGGED == 1:
                self.log.warning("%s: cannot write the snapshot of scan %d: %s (%d failed so far; the scans go on, "
                                 "a restart finds an older snapshot)", self.snapshot, track.seq,
                                 exc.strerror or exc, self.counters["snapshot_failed"])

    def on_stop(self) -> None:
        for sub in self._liveliness:
            sub.undeclare()

    def _on_liveliness(self, role: str, sample: Any) -> None:
        """Zenoh thread: track the tokens of sensors and local filters (:class:`Peers`); a token of a
        sensor not configured changes nothing. Its going and its return are logged, at most
        ``TOKEN_LINES`` lines a token every ``REJECT_LOG_INTERVAL_S`` (a death and a restart: the next line
        counts the changes not logged): a sensor's process declaring and withdrawing its token in a loop
        (its own key, which the access control admits) had the centre write a line a change, 4,000 a second."""
        sensor = str(sample.key_expr).rsplit("/", 1)[-1]
        if sensor not in self.sensors:
            return
        key, alive, now = f"{role}/{sensor}", sample.kind == zenoh.SampleKind.PUT, time.monotonic()
        back = alive and key in self.peers.lost
        self.peers.token(key, alive, now)
        if not back and alive:
            return
        since, lines, unsaid = self._token_said.get(key, (-float("inf"), 0, 0))
        if now - since >= REJECT_LOG_INTERVAL_S:
            since, lines = now, 0
        if lines >= TOKEN_LINES:
            self._token_said[key] = (since, lines, unsaid + 1)
            return
        self._token_said[key] = (since, lines + 1, 0)
        more = f" ({unsaid} more changes of its token not logged)" if unsaid else ""
        if back:
            self.log.warning("%s %s is back%s", role, sensor, more)
        else:
            self.log.warning("%s %s is gone (liveliness): fusing without it%s", role, sensor, more)

    def gone(self, now: float) -> set[str]:
        """The sensors whose sensor or local filter died (:meth:`Peers.gone`: not those whose tokens went
        with this centre's link to its router and may still come back): not waited for."""
        return {key.rsplit("/", 1)[-1] for key in self.peers.gone(self.link(), now)}

    def subscriptions(self) -> list[Subscription]:
        return [Subscription(self.keys.local_estimate(), LocalEstimate, self.on_estimate, recover=True)]

    def queryables(self) -> list[QueryHandler]:
        return [QueryHandler(self.keys.fusion_state(), lambda: self.last_track)]

    def on_estimate(self, msg: LocalEstimate) -> None:
        if msg.sensor not in self.sensors:
            raise Rejected("unknown_sensor", f"{msg.sensor!r} is not one of {', '.join(self.sensors)}")
        if msg.model not in ("cv", "ca") or msg.x.shape[0] != (6 if msg.model == "ca" else 4):
            # e.g. a 3-D radar filter's estimate: not a 2-D CV/CA state
            raise Rejected("wrong_model", f"a {msg.x.shape[0]}-D {msg.model!r} state: this centre fuses 4-D cv "
                           "and 6-D ca states")
        if self.next_seq is not None and msg.seq < self.next_seq:
            first = self.fused.get(msg.seq, {}).get(msg.sensor)
            if first is None and not self.seconded:
                self._passed_over(msg)
                return
            if first is None or first == digest(msg):
                self.count("late")
                return
            # the scan's track is out: the next one says that it (and so what follows) may be forged
            self.contest(self.keys.local_estimate(msg.sensor), Conflict(
                msg.seq, f"scan {msg.seq}: a second, different estimate of {msg.sensor} after the scan was fused"))
            return
        if self.next_seq is not None and msg.seq - self.next_seq > self.max_seq_jump:
            raise Rejected("seq_jump", f"scan {msg.seq} is more than {self.max_seq_jump} ahead of {self.next_seq}")
        last_t = self.last_track.t if self.last_track is not None else None
        if last_t is not None and msg.t <= last_t:
            raise Rejected("time_jump", f"scan {msg.seq} at t={msg.t}, not after the last fused scan (t={last_t})")
        gone = self.gone(time.monotonic())
        others = [s for s in self.sensors if s != msg.sensor and s not in gone]
        if self.jump.restart(last_t, msg.sensor, msg.seq, msg.t, witnesses=others):
            self.start_again(msg)
        for sensor in gone:  # a dead sensor keeps no other's lone estimates from witnessing themselves
            self.lead.leave(sensor)
        for estimate in self.in_time(self.lead, self.keys.local_estimate(msg.sensor), msg):
            self._collect(estimate)
        self.fuse_ready()

    def _passed_over(self, msg: LocalEstimate) -> None:
        """A late estimate (``msg.seq`` before the next scan) while no scan with two sensors' estimates
        has been fused: counted ``late`` and kept (the last ``BEHIND_KEPT`` scans). Once two sensors'
        estimates of one scan at least ``LEAD_INTERVALS`` before the next have come so, the scans
        start again from it (counted ``restarted``): the start was one sensor's alone, far ahead of
        the others. One estimate of sensor 1 numbered 10^9, sent before the first scan (at a start,
        or a restart without a snapshot), started the scans there and made every genuine estimate
        late: 1 scan of 34 fused. Waiting for two sensors instead would fuse nothing while a local
        filter is up and its sensor silent."""
        self.count("late")
        assert self.next_seq is not None
        kept = {**self.behind.get(msg.seq, {})}
        kept.setdefault(msg.sensor, msg)
        self.behind = dict(sorted({**self.behind, msg.seq: kept}.items())[-BEHIND_KEPT:])
        if len(kept) < 2 or self.next_seq - msg.seq < LEAD_INTERVALS:
            return
        behind = [m for seq, by in sorted(self.behind.items()) if seq >= msg.seq for m in by.values()]
        self.start_again(min(behind, key=lambda m: m.seq), "before the scans one sensor started far ahead")
        self.behind = {}
        for estimate in behind:
            self._collect(estimate)
        self.fuse_ready()

    def start_again(self, msg: LocalEstimate, why: str = "after a pause beyond max_time_jump_s") -> None:
        """Estimate ``msg`` follows one rejected beyond ``max_time_jump_s`` (:class:`ClockJump`), or
        two sensors' estimates of its scan came after one sensor's scans far ahead were fused
        (:meth:`_passed_over`): the centre starts again from its scan (in the first case the local
        filters did: their estimates are flagged ``init``), dropping the scans still waiting."""
        self.restarted(msg, why)
        self.count("dropped_scans", len(self.scans))
        self.centre = type(self.centre)(self.sensors, self.centre.config)
        self.scans, self.lead, self.last_track, self.next_seq = {}, NumberedLeadGuard(), None, msg.seq

    def _collect(self, msg: LocalEstimate) -> None:
        """Add ``msg`` (checked) to its scan's buffer, unless that scan's other estimates are at
        another time or it repeats one (both contest the scan; an identical one is a duplicate)."""
        buf = self.scans.get(msg.seq)
        if buf is not None and msg.t != buf.t:
            self.contest_scan(buf, msg, Rejected("time_jump", f"scan {msg.seq} at t={msg.t}, its other estimates at t={buf.t}"))
            return
        if buf is not None and msg.sensor in buf.outputs:
            first = buf.outputs[msg.sensor]
            same = (first.model == msg.model and np.array_equal(first.x, msg.x) and np.array_equal(first.P, msg.P))
            if same:
                self.count("duplicate")
                return
            self.contest_scan(buf, msg, Rejected("conflict", f"scan {msg.seq}: a second, different estimate of "
                                                        f"{msg.sensor} (the first stays)"))
            return
        buf = self.scans.setdefault(msg.seq, ScanBuffer(msg.t, time.monotonic()))
        buf.outputs[msg.sensor] = LocalOutput(
            msg.model, np.asarray(msg.x), np.asarray(msg.P), np.asarray(msg.x_prior), np.asarray(msg.P_prior),
            init="init" in msg.degraded or "no-reset" in msg.degraded,  # not conditioned on the last reset
            event=msg.maneuver.event if msg.maneuver is not None else None)
        buf.stamps.append(msg.stamp_ns)
        buf.digests[msg.sensor] = digest(msg)
        buf.named.update(msg.contested)
        self.lead.took(msg.sensor, msg.t, msg.seq)

    def contest_scan(self, buf: ScanBuffer, msg: LocalEstimate, exc: Rejected) -> None:
        """A second, different estimate for a scan still being collected: rejected (the first
        stays), and the scan's fused track is marked ``contested`` (either may be a forgery)."""
        if not buf.contested:
            self.count("contested")
        buf.contested = True
        self.note_rejected(self.keys.local_estimate(msg.sensor), exc)

    def on_tick(self) -> None:
        if self.scans:
            with self.guarded("on_tick"):
                self.fuse_ready()

    def fuse_ready(self) -> None:
        """Fuse complete scans in order; a scan whose deadline passed is fused as it is."""
        now, link = time.monotonic(), self.link()
        gone = self.gone(now)
        while self.scans:
            if self.next_seq is None or self.next_seq not in self.scans:
                oldest = min(self.scans)
                # nothing at all arrived for next_seq: skip it once a later scan is overdue
                if self.next_seq is not None and link.waited(self.scans[oldest].first_arrival, now) < self.deadline_s:
                    return
                if self.next_seq is not None:
                    self.count("skipped_scans", oldest - self.next_seq)
                    self.log.warning("scans %d..%d: no estimate arrived (skipped)", self.next_seq, oldest - 1)
                    if self.restored and oldest - self.next_seq > SNAPSHOT_MAX_GAP:
                        # the local filters went on alone meanwhile: their estimates describe the target
                        # better than the snapshot predicted over the gap
                        self.centre = type(self.centre)(self.sensors, self.centre.config)
                        self.last_track = None
                        self.log.warning("snapshot %d scans old: rebuilding from the local estimates instead",
                                         oldest - self.next_seq)
                self.restored = False
                self.next_seq = oldest
            buf = self.scans[self.next_seq]
            complete = len(buf.outputs) == len(self.sensors)
            waiting_for = [s for s in self.sensors if s not in buf.outputs and s not in gone]
            if waiting_for and link.waited(buf.first_arrival, now) < self.deadline_s:
                return
            del self.scans[self.next_seq]
            seq, self.next_seq = self.next_seq, self.next_seq + 1
            with self.guarded(f"fusing scan {seq}"):  # a scan that fails is dropped, its state undone
                self.fuse_scan(seq, buf, degraded=not complete)
                self.drop_earlier()

    def drop_earlier(self) -> None:
        """Reject (``time_jump``) the estimates of later scans that are not after the track just
        fused, as they would be had they come now, so that the scan's genuine estimates, at its own
        time, are taken: one estimate of scan k + 1 stamped before scan k, arriving first, had the
        others refused and was fused alone, its track going back in time. A scan already contested
        is named by the next track."""
        assert self.last_track is not None
        last = self.last_track
        for seq in [q for q, buf in self.scans.items() if buf.t <= last.t]:
            buf = self.scans.pop(seq)
            for sensor in buf.outputs:
                self.note_rejected(self.keys.local_estimate(sensor), Rejected(
                    "time_jump", f"scan {seq} at t={buf.t}, not after scan {last.seq} (t={last.t})"))
            if buf.contested or buf.named:
                self.contested_scans = sorted(set(self.contested_scans) | buf.named | {seq})[:MAX_CONTESTED]

    def fuse_scan(self, seq: int, buf: ScanBuffer, degraded: bool) -> None:
        if seq > 0 and (self.last_track is None or all(o.init for o in buf.outputs.values())):
            degraded = True  # not the federated filter's estimate: the local filters' fused as independent
            self.count("rebuilt")
            why = "started mid-run (a restart)" if self.last_track is None else "every local filter went on alone"
            self.log.warning("%s: state rebuilt from the local estimates of scan %d", why, seq)
        result = self.centre.fuse(buf.t, buf.outputs)
        if not usable(result):
            # a local's prior that is not its share of the centre's (e.g. rejoined from an older
            # centre state after its sensor's gap) can make the federated sum indefinite: rather
            # than publish it (or fail), start again from the local estimates, as after a restart
            self.count("rebuilt_not_positive_definite")
            self.log.warning("scan %d: fused covariance not positive definite: state rebuilt from the local "
                             "estimates", seq)
            self.centre = type(self.centre)(self.sensors, self.centre.config)
            result = self.centre.fuse(buf.t, buf.outputs)
            if not usable(result):
                raise Numerical(f"scan {seq}: fused covariance not positive definite, even rebuilt")
        left_out = tuple(s for s in self.sensors if s in buf.outputs and s not in result.fused)
        if left_out:  # went on alone, or in the other model: not fused this scan (the reset brings them back)
            self.count("estimates_left_out", len(left_out))
            degraded = True
            if left_out != self.left_out:
                self.log.warning("scan %d: estimates of %s left out (made alone, without the last reset, or in "
                                 "the other model)", seq, ", ".join(left_out))
        self.left_out = left_out
        if degraded:
            self.count("degraded_scans")
        named = tuple(sorted(buf.named | set(self.take_contested()) | ({seq} if buf.contested else set())))[:MAX_CONTESTED]
        if named:
            self.log.warning("scan %d: fused track contested (scans %s)", seq, list(named))
        track = make_track(seq, buf, result, degraded, list(result.fused), named)
        self.publish(self.keys.fusion_track(), track)  # the output first; the resets are for the next scan
        for sensor, cmd in result.resets.items():
            self.publish(self.keys.fusion_reset(sensor), Reset.unchecked(
                sensor=sensor, seq=seq, t=buf.t, model=cmd.model, x=cmd.x, P=cmd.P, beta=cmd.share))
        self.last_track = track
        if len(buf.outputs) >= 2:  # the scans' start stands
            self.seconded, self.behind = True, {}
        self.fused = {q: d for q, d in self.fused.items() if q > seq - FUSED_KEPT} | {seq: buf.digests}
        self._save(track)
        self.count("scans_fused")
        kind = int(result.estimate.event)
        if kind != EVENT_NONE:
            self.count(f"events_{EVENT_NAMES[kind].replace('-', '_')}")
            ev = result.events
            self.publish(self.keys.fusion_event(), ManeuverEvent(
                seq=seq, t=buf.t, kind=EVENT_NAMES[kind],
                onset=float(ev.onset) if ev is not None else buf.t,
                u=np.asarray(ev.u) if ev is not None else np.asarray(result.estimate.x[CA_ACC]),
                statistic=float(ev.statistic) if ev is not None else 0.0))


def usable(result: CentreResult) -> bool:
    """A finite fused state whose covariance and resets are positive definite as the wire requires."""
    return bool(np.all(np.isfinite(result.estimate.x))) and all(
        acceptable_covariances(P) for P in [result.estimate.P, *(c.P for c in result.resets.values())])


def make_track(seq: int, buf: ScanBuffer, result: CentreResult, degraded: bool, sensors: list[str],
               contested: tuple[int, ...] = ()) -> FusedTrack:
    """The fused track of scan ``seq``, ``contested`` (naming the scans in ``extra``) when it may be
    built on a forged message (docs/wire.md, "Contested scans")."""
    est = result.estimate
    is_ca = bool(est.is_ca)
    idx = np.arange(6) if is_ca else CV_IN_CA
    kind = int(est.event)
    extra = ({"event": EVENT_NAMES[kind]} if kind != EVENT_NONE else {}) | contested_extra(contested)
    return FusedTrack.unchecked(seq=seq, t=buf.t, model="ca" if is_ca else "cv", x=est.x[idx], P=est.P[np.ix_(idx, idx)],
                      maneuver=is_ca, degraded=degraded, sensors=tuple(sensors), stamp_ns=min(buf.stamps),
                      extra=extra, contested=bool(contested))


def main(argv: list[str]) -> int:
    parser = service_parser("fusion-center", "fuse the local estimates of a deployment")
    defaults = DeploymentConfig()  # a [deployment] table's, which --mode and --deadline override
    parser.add_argument("--sensors", help="comma-separated sensor ids (default: fusion.sensors of the config)")
    parser.add_argument("--mode", choices=MODES, help="federated or decentralized (default: deployment.mode of "
                                                        f"--config, else {defaults.mode})")
    parser.add_argument("--config", type=Path, help="deployment TOML ([deployment], [fusion], [[sensor]]; "
                                                    "default: none, every key at its default)")
    parser.add_argument("--deadline", type=finite_number,
                        help="seconds to wait for a scan's estimates (default: deployment.deadline_s of --config, "
                             f"else {defaults.deadline_s:g})")
    parser.add_argument("--snapshot", type=Path, help="write the state here after every scan; resume from it at start "
                        "(a restart mid-run; default: none, no snapshot)")
    args = parser.parse_args(argv)
    settings = load_tables(args.config, PipelineSettings)
    sensors = (args.sensors.split(",") if args.sensors else
               list(settings.fusion.sensors or [s.id for s in settings.sensor]))
    with in_file(args.config):
        if not sensors or len(set(sensors)) != len(sensors) or not all(sensors):
            raise ConfigError("fusion.sensors: need one or more distinct sensor ids (or --sensors a,b,c)")
        if settings.fusion.sensors is not None and list(settings.fusion.sensors) != sensors:
            raise ConfigError("fusion.sensors: --sensors disagrees with the config's sensor list")
    deadline = args.deadline if args.deadline is not None else settings.deployment.deadline_s
    if deadline <= 0:
        parser.error("--deadline must be > 0")
    mode = args.mode or settings.deployment.mode
    centre_cls = FederatedCentre if mode == "federated" else DecentralizedCentre
    centre = centre_cls(sensors, settings.fusion)
    return FusionCenterService(sensors, centre, deadline, snapshot=args.snapshot,
                               max_seq_jump=settings.deployment.max_seq_jump,
                               max_time_jump_s=settings.deployment.max_time_jump_s,
                               **service_kwargs(parser, args)).run()
