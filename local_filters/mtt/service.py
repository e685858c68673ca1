"""``fedtrack serve mtt-local --sensor ID [--mode federated|decentralized] [--config TOML]``: one
sensor's local multi-target tracker.

Consumes the sensor's scans (``Measurement`` of kind ``scan`` on ``sensor/<ID>/meas``), runs
:func:`fedtrack.local_filters.mtt.local.local_step` on each in order and publishes a
``TrackReport`` on ``local/<ID>/tracks``. Federated: after each report it holds the next scans
until the centre's ``TrackResets`` for that report (``fusion/mtt-resets/<ID>``) has been
adopted, so that its tracker sees exactly what the replay's does; after ``--reset-timeout``
seconds without them (not counting a router outage and ``LINK_GRACE_S`` after it) it goes on
(counted in ``reset_timeouts``; from then on the live tracks may differ from the replay). A scan
older than the tracker's newest (the sensor's link reordered it) is fused in time order, the later
scans run again (counted ``rerun``;
:class:`fedtrack.local_filters.mtt.local.SensorTracker`), and reported; one more than ``max_lag``
older is dropped and counted ``late``, and one equal to a scan tracked before (another number), or its
sensor's detections again off its schedule (:func:`~fedtrack.local_filters.mtt.local.resends_own`),
``duplicate``, as in the replay. The report of the process's first scan is marked ``first``: a
restarted tracker starts afresh, and the centre lists the restart for the replay. At most
``MAX_ENTRIES`` scans wait (for resets, or behind a slow tracker): beyond, the oldest waiting one
is dropped and counted ``queue_dropped``. Stopped while scans wait for the centre's answers, it tracks them
first (:meth:`MttLocalService.held`; at most ``drain_deadline_s``, the rest counted ``dropped``).

Rejected (docs/wire.md#rejections): a measurement of another kind or shape (``wrong_model``),
a sensor the config does not allow (``unknown_sensor``), a scan number more than
``[deployment] max_seq_jump`` ahead (``seq_jump``) or a time more than ``max_time_jump_s``
ahead (``time_jump``), a second different scan with a number already taken or second,
different resets for the report whose resets it adopted (``conflict``; an identical one is a
``duplicate``), resets for a report not awaiting them (``unexpected``; those of one of the last ``TIMED_OUT_KEPT``
reports whose wait timed out are late, counted ``late_resets`` and dropped) or of another state size
(``wrong_model``). A conflict is also counted ``contested`` and named in the next report's
``contested`` (the first message may have been the forgery: docs/wire.md, "Contested scans").

With ``[regions]`` in the config (docs/multitarget.md#regions) it publishes each report as one
sub-report per region (:class:`fedtrack.local_filters.mtt.routing.RegionRouter`) on
``region/<rid>/local/<ID>/tracks`` and, federated or decentralized, waits for every region
centre's answer (``region/<rid>/mtt-resets/<ID>``) before its next scan: it learns from them
which region holds which of its local tracks, and (federated) adopts their resets together. A
region whose sub-report no subscriber took (its centre and standby both gone: Zenoh's matching
status, trusted while the link to the router is settled, and for a region one of its sub-reports
reached before) is not waited for (counted ``unreached``): that centre never fuses the report, and
the replay, which waits for the regions whose recorded entries list it, goes on without it too;
before, every tracker waited ``--reset-timeout`` for it on every report, and every region's
picture was late. A region never reached is waited for: a new session learns the centres'
subscribers some time after it opens, and a tracker under load that took them for gone went on
without the answers of centres that fused its first reports (live and replay differed).
"""

from __future__ import annotations

import time
from collections import deque
from pathlib import Path

from fedtrack.config import finite_number, load_tables
from fedtrack.deployment import MODES
from fedtrack.geodetic import FrameConfig
from fedtrack.keys import check_id
from fedtrack.local_filters.linear.gating import CrowdedScan
from fedtrack.local_filters.mtt.config import MttConfig, MttServiceSettings
from fedtrack.local_filters.mtt.history import MAX_ENTRIES
from fedtrack.local_filters.mtt.local import LocalReport, SensorTracker, report_to_wire, resets_from_wire
from fedtrack.local_filters.mtt.routing import (
    RegionAnswer,
    RegionRouter,
    answer_from_wire,
    answers_only,
    join_answers,
)
from fedtrack.local_filters.mtt.scan import SensorScan, misplaced, scan_from_measurement
from fedtrack.local_filters.regions import Regions, load_regions
from fedtrack.services.admission import ReceivedScans, digest
from fedtrack.services.base import Service, Subscription, service_kwargs, service_parser
from fedtrack.services.clock import check_time_jump, time_jump
from fedtrack.services.lead import LeadGuard, LoneStart
from fedtrack.services.rejections import Conflict, Rejected, require_covariances, require_finite
from fedtrack.wire import Measurement, TrackResets
from fedtrack.zsession import id_arg

TIMED_OUT_KEPT = 16  # reports whose late resets are told apart from unexpected ones
RESET_TIMEOUT_S = 2.0  # federated: go on without the centre's answers after this long (``--reset-timeout``)


class MttLocalService(Service):
    """The local multi-target tracker of one sensor."""

    role = "mtt-local"
    tick_period_s = 0.05
    # the tracker (a SensorTracker: its scans of the last max_lag seconds) changes in place and is
    # put back by the transaction if a scan fails; ``received`` is only changed once a scan was
    # handled (compute, then commit)
    state_attrs = ("tracker", "queue", "awaiting", "awaiting_since", "awaiting_scan", "adopted",
                   "contested_scans", "router", "sent", "answers", "unreached", "reached", "lead", "timed_out")

    def __init__(self, sensor: str, federated: bool, cfg: MttConfig, reset_timeout_s: float = RESET_TIMEOUT_S,
                 max_seq_jump: int = 1000, max_time_jump_s: float = 3600.0, regions: Regions | None = None,
                 sites: FrameConfig | None = None, **kwargs: object) -> None:
        super().__init__(**kwargs)  # type: ignore[arg-type]
        self.sites = sites  # [frame] with its sites: a radar scan's sensor_position checked (scan.misplaced)
        self.regions = regions
        self.router = None if regions is None else RegionRouter(regions, cfg.unsupported_s)
        self.sent: list[LocalReport] = []  # the sub-reports of the report awaiting answers (regions)
        self.answers: dict[int, tuple[RegionAnswer, bytes]] = {}  # region -> its answer and digest
        self.unreached: set[int] = set()  # the regions whose sub-report no subscriber took: not awaited
        # the regions a sub-report of this process reached once: only their subscribers' absence is known (a
        # new session learns the others' subscribers some time after it opens; until then it matches none)
        self.reached: set[int] = set()
        self.sensor = check_id(sensor, "--sensor")
        self.federated = federated
        self.cfg = cfg
        self.reset_timeout_s = reset_timeout_s
        self.max_time_jump_s = max_time_jump_s
        self.tracker: SensorTracker | None = None
        self.queue: deque[tuple[int, SensorScan, int]] = deque()  # (seq, scan, stamp) waiting
        # a scan stamped far ahead waits for the sensor's next one (lead.py)
        self.lead: LeadGuard[tuple[int, SensorScan, int]] = self._guard()
        self.received = ReceivedScans(max_seq_jump)
        self.awaiting: int | None = None  # report whose resets are due (federated)
        self.awaiting_scan: SensorScan | None = None  # the scan of that report
        self.awaiting_since = 0.0
        self.adopted: tuple[int, bytes] | None = None  # the report number and digest of the resets adopted last
        # the latest reports whose resets or answers timed out: one that comes after all is late, not unexpected
        self.timed_out: deque[int] = deque(maxlen=TIMED_OUT_KEPT)
        self.noted = False  # whether the count's note (MttConfig.count_note) was judged
        self.first_t: float | None = None  # the first scan's time: the note is judged over the next interval

    def subscriptions(self) -> list[Subscription]:
        # recovered from the sensor's cache (which the recorder reads with history) when the router's link
        # went: before 2026-11-27 the scans of two router outages of 1.5 s were lost (20 of 128)
        subs = [Subscription(self.keys.sensor_meas(self.sensor), Measurement, self.on_scan, recover=True)]
        if self.regions is not None:
            subs.append(Subscription(self.keys.region_resets(None, self.sensor), TrackResets, self.on_answer))
        elif self.federated:
            subs.append(Subscription(self.keys.mtt_resets(self.sensor), TrackResets, self.on_resets))
        return subs

    def plain_outputs(self) -> tuple[str, ...]:
        """The reports and sub-reports: the centres (and standbys) take them as plain subscribers."""
        return self.keys.mtt_report(), self.keys.region_report()

    def on_start(self) -> None:
        """Declare the sub-reports' publishers now: whether a region's has a subscriber is known by the
        first report (:meth:`Publishing.reaches`)."""
        for rid in self.regions.ids if self.regions is not None else ():
            self.declare_plain(self.keys.region_report(rid, self.sensor))

    def on_scan(self, msg: Measurement) -> None:
        try:
            scan = scan_from_measurement(msg)
        except ValueError as exc:
            raise Rejected("wrong_model", str(exc)) from None
        if not self.cfg.allows(msg.sensor):
            raise Rejected("unknown_sensor", f"sensor {msg.sensor!r} is not in mtt.sensors")
        problem = misplaced(scan, self.sites)
        if problem:
            raise Rejected("wrong_site", f"scan {msg.seq} of {msg.sensor}: {problem}")
        lone = self.lead.lone
        assert lone is not None
        again = lone.contradicted(msg.t, msg)
        if self.abandons(again, msg):
            self._forget()
            for scan in again:
                self.on_scan(scan)
            return
        if lone.contradicts(msg.t):  # refused without raising: the guard keeps it as a contradiction
            if lone.start is not None and msg.t > lone.start:
                self.note_rejected(self.keys.sensor_meas(self.sensor), time_jump(lone.start, msg.t, lone.gap))
            else:
                self.count("late")
            return
        check_time_jump(self.lead.newest, msg.t, self.max_time_jump_s)
        if not self.admitted(self.received, msg):
            return
        times = self.lead.times()
        released = self.in_time(self.lead, self.keys.sensor_meas(self.sensor), msg,
                                item=(msg.seq, scan, msg.stamp_ns))
        for _, taken, _ in released:  # in the queue, so taken: the next scan's lead is from them
            self.lead.took(taken.sensor, taken.t)
        self.queue.extend(released)
        if len(self.queue) > MAX_ENTRIES:  # as many as a history keeps: the oldest waiting scans go
            self.count("queue_dropped", len(self.queue) - MAX_ENTRIES)
            while len(self.queue) > MAX_ENTRIES:
                self.queue.popleft()
        if msg.seq in self._advance():  # dropped: as if it never came
            self.lead.restore(times)
            return
        self.received.take(msg)
        if self.first_t is None:
            self.first_t = scan.t
        elif not self.noted and scan.t > self.first_t:  # the count's chance on this sensor's clutter over its
            self.noted = True  # interval, once (a position sensor's is per m^2)
            note = self.cfg.count_note({self.sensor: scan.R} if scan.dim == 2 else {},
                                       {self.sensor: scan.t - self.first_t})
            if note:
                self.log.warning("%s", note)

    def on_resets(self, msg: TrackResets) -> None:
        if self.adopted is not None and msg.seq == self.adopted[0]:
            if digest(msg) == self.adopted[1]:
                self.count("duplicate")
                return
            self.contest(self.keys.mtt_resets(self.sensor), Conflict(
                msg.seq, f"second, different resets for report {msg.seq} (the first were adopted)"))
            return
        if self.awaiting is None or msg.seq != self.awaiting:
            if msg.seq in self.timed_out:
                self.count("late_resets")
                return
            raise Rejected("unexpected", f"resets for report {msg.seq}, awaiting {self.awaiting}")
        assert self.tracker is not None and self.awaiting_scan is not None
        d = self.tracker.tracker.state.tracks.x.shape[1]
        if msg.ids and msg.x.shape[1] != d:
            raise Rejected("wrong_model", f"resets of size {msg.x.shape[1]} for a {d}-D tracker")
        self.tracker.adopt(self.awaiting_scan, resets_from_wire(msg), msg.q_scale)
        self.adopted = (msg.seq, digest(msg))
        self.awaiting = self.awaiting_scan = None
        self._advance()

    def on_answer(self, msg: TrackResets) -> None:
        """A region centre's answer to a sub-report (``[regions]``)."""
        assert self.regions is not None and self.router is not None
        try:
            region, answer = answer_from_wire(msg, self.regions)
        except ValueError as exc:
            raise Rejected("unknown_region", str(exc)) from None
        if msg.seq != self.awaiting or region in self.answers:
            if region in self.answers and msg.seq == self.awaiting and digest(msg) == self.answers[region][1]:
                self.count("duplicate")
                return
            if msg.seq != self.awaiting and msg.seq in self.timed_out:
                self.count("late_resets")
                return
            raise Rejected("unexpected", f"answer of {msg.region} for report {msg.seq}, awaiting {self.awaiting}")
        assert self.tracker is not None and self.awaiting_scan is not None
        d = self.tracker.tracker.state.tracks.x.shape[1]
        if msg.ids and msg.x.shape[1] != d:
            raise Rejected("wrong_model", f"resets of size {msg.x.shape[1]} for a {d}-D tracker")
        if not answers_only(self.sent[region], answer):  # the tracker would keep every id it holds
            raise Rejected("unexpected", f"answer of {msg.region} for report {msg.seq}: it holds or resets local "
                           "tracks its sub-report did not carry")
        self.answers[region] = (answer, digest(msg))
        if self._answered():
            self._learn()

    def _guard(self) -> LeadGuard[tuple[int, SensorScan, int]]:
        """The guard against scans stamped far ahead, with the start's recovery rule on times (lead.LoneStart)."""
        return LeadGuard(self.cfg.max_lag, lone=LoneStart(self.max_time_jump_s, ahead=True))

    def _forget(self) -> None:
        """The tracker's only scan was abandoned (:meth:`abandons`): it starts again as this process did (its next
        report flagged first), the scans and answers it waited for and the numbers it took forgotten."""
        self.tracker, self.lead, self.received = None, self._guard(), ReceivedScans(self.received.max_seq_jump)
        self.queue.clear()
        self.awaiting = self.awaiting_scan = None
        self.sent, self.answers, self.unreached = [], {}, set()
        self.first_t, self.noted = None, False

    def _answered(self) -> bool:
        """Every region answered the sub-report awaited, but those it did not reach (``unreached``)."""
        assert self.regions is not None
        return len(self.answers.keys() | self.unreached) == len(self.regions.ids)

    def _learn(self, advance: bool = True) -> None:
        """Every region answered (or the wait timed out): learn where the local tracks are held and,
        federated, adopt the resets together; then go on (``advance``: track the waiting scans)."""
        assert self.router is not None and self.tracker is not None and self.awaiting_scan is not None
        got = sorted(self.answers)
        answers = [self.answers[r][0] for r in got]
        if answers:
            expired = self.router.expired
            self.router.learn([self.sent[r] for r in got], answers, got)
            if self.router.expired > expired:  # hand-overs whose new owner did not hold them in time
                self.count("handover_expired", self.router.expired - expired)
            if self.federated:
                self.tracker.adopt(self.awaiting_scan, *join_answers(answers))
        if self.unreached and self.awaiting not in self.timed_out:  # an answer of a region not awaited that
            self.timed_out.append(self.awaiting)  # comes after all is late, not unexpected
        self.awaiting = self.awaiting_scan = None
        self.sent, self.answers, self.unreached = [], {}, set()
        if advance:
            self._advance()

    def on_tick(self) -> None:
        """Go on without the answers awaited ``--reset-timeout`` seconds, not counting a router outage and
        ``LINK_GRACE_S`` after it (:meth:`fedtrack.zsession.Link.waited`: nothing can come meanwhile)."""
        if self.awaiting is not None and self.link().waited(self.awaiting_since,
                                                             time.monotonic()) > self.reset_timeout_s:
            self.count("reset_timeouts")
            self.timed_out.append(self.awaiting)
            self.log.warning("no resets for report %d after %.1f s: going on without them",
                             self.awaiting, self.reset_timeout_s)
            if self.regions is not None:
                self._learn()  # what the regions that answered said
                return
            self.awaiting = self.awaiting_scan = None
            self._advance()

    def held(self) -> bool:
        """Scans wait for the answers to a report: at a clean stop the tracker goes on until it has tracked them
        (the centre, stopped after the trackers, still answers), for at most ``drain_deadline_s``."""
        return self.awaiting is not None and bool(self.queue)

    def on_stop(self) -> None:
        """A scan still held for a witness (stamped far ahead, lead.py) is counted ``rejected_time_lead``; one still
        waiting for the answers to a report, ``dropped``."""
        self.note_leads(self.keys.sensor_meas(self.sensor), self.lead.end())
        if self.queue:
            self.count("dropped", len(self.queue))
            self.log.warning("stopped with %d scan(s) waiting for the centre's answers, not tracked", len(self.queue))

    def _advance(self) -> list[int]:
        """Track the waiting scans, in arrival order, while no resets are due; returns the scan
        numbers the tracker failed on (each dropped, a rejection, the state as before it)."""
        failed = []
        while self.queue and self.awaiting is None:
            seq, scan, stamp = self.queue.popleft()
            with self.guarded(f"scan {seq}", key=self.keys.sensor_meas(self.sensor)) as attempt:
                first = self.tracker is None  # this process's first report: the centre records a restart
                if first:
                    self.tracker = SensorTracker(scan, self.cfg, self.federated)
                if self.tracker.is_late(scan):
                    self.count("late")
                    continue
                if self.tracker.is_duplicate(scan):
                    self.count("duplicate")
                    continue
                if scan.repeated:
                    self.count("repeated", scan.repeated)
                try:
                    report, rerun = self.tracker.track(scan)
                except CrowdedScan as exc:  # the transaction puts the tracker back
                    raise Rejected("crowded", f"scan {seq} of {self.sensor}: {exc}") from None
                require_finite(f"scan {seq}: the local tracks", report.x, report.P)
                require_covariances(f"scan {seq}: the local tracks", report.P)
                contested = self.take_contested()
                if self.router is not None and self.regions is not None:
                    parts = self.router.split(report)
                    settled = self.link().settled(time.monotonic())
                    self.unreached = set()
                    for r, (rid, (sub, elsewhere)) in enumerate(zip(self.regions.ids, parts)):
                        key = self.keys.region_report(rid, self.sensor)
                        self.publish(key, report_to_wire(sub, seq, stamp, contested, tuple(elsewhere.tolist()), first))
                        if self.reaches(key):
                            self.reached.add(r)
                        elif settled and r in self.reached:
                            self.unreached.add(r)
                    self.sent, self.answers = [sub for sub, _ in parts], {}
                    if self.unreached:
                        self.count("unreached", len(self.unreached))
                else:
                    self.publish(self.keys.mtt_report(self.sensor),
                                 report_to_wire(report, seq, stamp, contested, first=first))
                self.count("reports")
                if rerun:
                    self.count("rerun", rerun)
                if self.federated or self.regions is not None:
                    self.awaiting, self.awaiting_since, self.awaiting_scan = seq, time.monotonic(), scan
                    if self.regions is not None and self._answered():  # no region reached: none to wait for
                        self._learn(advance=False)
            if attempt.failed:
                failed.append(seq)
        return failed


def main(argv: list[str]) -> int:
    parser = service_parser("mtt-local", "one sensor's local multi-target tracker", per_sensor=True)
    parser.add_argument("--sensor", required=True, type=id_arg("--sensor"), help="sensor id whose scans to track")
    parser.add_argument("--mode", choices=MODES, default="federated",
                        help="federated: take the centre's resets; decentralized: none (default: %(default)s)")
    parser.add_argument("--config", help="configuration file; reads [mtt], [deployment] and [frame] (a radar "
                        "scan's sensor_position against its site; docs/multitarget.md; default: none, every key at "
                        "its default)")
    parser.add_argument("--reset-timeout", type=finite_number, default=RESET_TIMEOUT_S, metavar="SECONDS",
                        help="federated: go on without the centre's resets after this long (default: %(default)s)")
    args = parser.parse_args(argv)
    if args.reset_timeout <= 0:
        parser.error("--reset-timeout must be > 0")
    kwargs = service_kwargs(parser, args)
    path = Path(args.config) if args.config else None
    settings = load_tables(path, MttServiceSettings)  # a ConfigError is the CLI's one-line error
    dep = settings.deployment
    return MttLocalService(args.sensor, args.mode == "federated", settings.mtt, args.reset_timeout,
                           dep.max_seq_jump, dep.max_time_jump_s, load_regions(path), sites=settings.frame,
                           **kwargs).run()
