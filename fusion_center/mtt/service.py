"""``fedtrack serve mtt-centre --algorithm mtt-federated|mtt-decentralized|mtt-centralized
[--dim 4|6] [--config TOML]``: the multi-target fusion centre.

Track-to-track (``mtt-federated``, ``mtt-decentralized``): consumes the local trackers'
``TrackReport`` s (``local/*/tracks``) and runs :meth:`TrackToTrackCentre.answer` on each, in
arrival order; federated, it answers each report with the sensor's ``TrackResets``
(``fusion/mtt-resets/<id>``). Measurement level (``mtt-centralized``): consumes the sensors'
scans (``sensor/*/meas``) and runs the centralized tracker (roll-back for out-of-sequence
scans). Every ``period`` seconds of data it publishes a ``TrackPicture`` (``fusion/picture``)
by the replay's rule (:class:`fedtrack.fusion_center.mtt.engines.PictureClock`), carrying the
scans it processed since the previous picture in its processing order; on a clean stop it
publishes the pictures still due. ``fedtrack replay`` of the recorded scans in that order
gives the same pictures.

Sensors join by publishing (any sensor ``[mtt] sensors`` allows, at any time). A sensor
leaves when its tracker's liveliness token (``alive/mtt-local/<id>``; for ``mtt-centralized``
the sensor's own, ``alive/sensor/<id>``) disappears (one that went with the centre's own link to
its router only if it is not back ``LINK_GRACE_S`` after the link is: :class:`fedtrack.zsession.Peers`),
or when nothing of it arrived for
``[mtt] leave_after_s`` seconds of wall-clock time and four of its usual intervals between
messages (:mod:`fedtrack.fusion_center.mtt.silence`): within one tick (50 ms) the centre drops it
(:meth:`TrackToTrackCentre.drop_sensor`: no longer live, so the others' sharing factors are
renormalized; its local tracks leave their central tracks) and lists the departure in the next
picture, so that the replay drops it at the same point.

``--region RID`` (track-to-track only; the config's ``[regions]``, docs/multitarget.md#regions):
the centre of one region. It takes the sub-reports ``region/RID/local/*/tracks`` and the
hand-overs ``region/RID/handover/*`` in arrival order (:class:`fedtrack.fusion_center.mtt.regional.RegionEngine`),
answers every sub-report on ``region/RID/mtt-resets/<id>`` (decentralized too: the answer says
which local tracks it holds), sends the central tracks that left its region as ``HandOver``
to ``region/<new>/handover/RID`` and publishes its region's picture on ``region/RID/picture``, its
fused lists naming the hand-overs it took over (``handovers``); ``serve picture`` merges them. With
``--numbers PATH`` it reserves its track ids and hand-over numbers there before issuing them, and a
process started again numbers after its former one (:mod:`fedtrack.fusion_center.mtt.numbers`).

``--dim``: the central state size, 6 when any sensor is a radar (the replay's rule on the
recorded scans). Rejected (docs/wire.md#rejections): a sensor the config does not allow
(``unknown_sensor``), a report of another state size or a scan of another kind
(``wrong_model``), a second, different message for a (sensor, scan) already taken
(``conflict``; an identical one is a ``duplicate``) and a scan number more than
``[deployment] max_seq_jump`` ahead of the sensor's last (``seq_jump``), and a sensor that would
be live beside ``MAX_LIST_ITEMS`` (64) others (``too_many_sensors``: a picture's track lists at
most that many sensors, and each live sensor raises every tracker's sharing factor).

Its failover (a primary's token, ``--standby``) is :mod:`fedtrack.fusion_center.mtt.failover`'s, its
pictures as messages :mod:`fedtrack.fusion_center.mtt.pictures`'.
"""

from __future__ import annotations

import math
import pickle
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from fedtrack.config import ConfigError, load_tables
from fedtrack.deployment import MAX_TIME_JUMP_S
from fedtrack.fusion_center.mtt.centre.candidates import CrowdedReport
from fedtrack.fusion_center.mtt.centre.registration import describe
from fedtrack.fusion_center.mtt.engines import (
    CentralizedEngine,
    PictureClock,
    TrackToTrackEngine,
    no_tracks,
    union_picture,
)
from fedtrack.fusion_center.mtt.failover.ordered import PrimaryOrder
from fedtrack.fusion_center.mtt.failover.service import CentreFailover
from fedtrack.fusion_center.mtt.failover.standby import NUMBER_ROOM, SETTLED_MAX, Standby, next_after
from fedtrack.fusion_center.mtt.numbers import Numbers, read_numbers, reservation, write_numbers
from fedtrack.fusion_center.mtt.pictures import PICTURE_ITEMS, picture_message, picture_window
from fedtrack.fusion_center.mtt.regional import RegionEngine
from fedtrack.fusion_center.mtt.shards import confirmed_holder, disputed, handover_from_wire, handover_to_wire
from fedtrack.fusion_center.mtt.silence import Silence
from fedtrack.geodetic import Frame, FrameConfig, picture_geodetic
from fedtrack.local_filters.linear.gating import CrowdedScan
from fedtrack.local_filters.mtt.config import MttConfig, MttServiceSettings
from fedtrack.local_filters.mtt.local import could_be_first, report_from_wire, resets_to_wire
from fedtrack.local_filters.mtt.routing import answer_to_wire
from fedtrack.local_filters.mtt.scan import misplaced, scan_from_measurement
from fedtrack.local_filters.mtt.service import RESET_TIMEOUT_S
from fedtrack.local_filters.regions import Regions, load_regions
from fedtrack.services.admission import ReceivedScans, digest
from fedtrack.services.base import Service, Subscription, service_kwargs, service_parser
from fedtrack.services.dispatch import held_bytes
from fedtrack.services.lead import LeadGuard, SoleStart
from fedtrack.services.rejections import Conflict, Rejected, require_covariances, require_finite
from fedtrack.wire import (
    MAX_LIST_ITEMS,
    MAX_MAGNITUDE,
    MAX_STRING_LENGTH,
    HandOver,
    Measurement,
    TrackPicture,
    TrackReport,
    predictable,
)
from fedtrack.zsession import Peers

ALGORITHMS = ("mtt-federated", "mtt-decentralized", "mtt-centralized")
# hand-overs per sending region whose digests are kept to tell a re-delivery (a duplicate) or a second,
# different one (a conflict) from a new one, as the fusion centre's FUSED_KEPT scans: a sender numbers its
# hand-overs in order and a re-sent one (after a failover) is among its latest; an older one is late. Kept
# all, they grew with every hand-over and were pickled with every message (100,000: 56 ms a message)
HANDOVERS_KEPT = 64


class MttCentreService(CentreFailover, Service):
    """The multi-target fusion centre."""

    role = "mtt-centre"
    tick_period_s = 0.05
    # restored after a failed handler (the engine changes in place: pickled before each message;
    # ``received`` is only changed once a message was handled); on_tick guards its departures itself
    state_attrs = ("engine", "clock", "order", "left_at", "restarted_at", "pictures", "silence", "contested",
                   "handovers_at", "taken", "lead", "began", "start_held_at", "sole")
    # what a centre abandoning a start of one sensor puts back as it was before its first message (SoleStart)
    start_attrs = tuple(a for a in state_attrs if a != "pictures")
    tick_state_attrs = ()

    def __init__(self, algorithm: str, cfg: MttConfig, dim: int = 4, max_seq_jump: int = 1000,
                 frame: Frame | None = None, region: str | None = None, regions: Regions | None = None,
                 standby: bool = False, speed: float = 1.0, numbers: Path | None = None,
                 sites: FrameConfig | None = None, max_time_jump_s: float = MAX_TIME_JUMP_S,
                 **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.speed = speed  # [deployment] speed: its pictures' pace, for picture_window
        self.frame = frame  # [frame]: each picture track's WGS-84 position too
        self.sites = sites  # [frame] with its sites: a radar scan's sensor_position checked (scan.misplaced)
        if algorithm not in ALGORITHMS:
            raise ConfigError(f"algorithm: expected one of {', '.join(ALGORITHMS)}, got {algorithm!r}")
        self.algorithm = algorithm
        self.cfg = cfg
        self.dim = dim
        self.received = ReceivedScans(max_seq_jump)
        self.region, self.regions = region, regions
        self.engine: CentralizedEngine | TrackToTrackEngine | RegionEngine
        feedback = algorithm == "mtt-federated"
        radar_sites = {} if sites is None else sites.radar_sites()  # the life rules' radars (track_life)
        if region is not None:
            if algorithm == "mtt-centralized" or regions is None or region not in regions.ids:
                raise ConfigError(f"--region {region}: needs a track-to-track algorithm and a config whose [regions] "
                                  f"has it ({', '.join(regions.ids) if regions else 'no [regions]'})")
            self.engine = RegionEngine(cfg, dim, feedback=feedback, regions=regions, index=regions.ids.index(region),
                                       sites=radar_sites, frame=frame)
        else:
            if numbers is not None:
                raise ConfigError("--numbers: a region centre's (--region) only")
            self.engine = (CentralizedEngine(cfg, dim, frame=frame) if algorithm == "mtt-centralized"
                           else TrackToTrackEngine(cfg, dim, feedback=feedback, sites=radar_sites,
                                                  frame=frame))
        self.picture_key = self.keys.mtt_picture() if region is None else self.keys.region_picture(region)
        # --numbers: the ids and hand-over numbers reserved there (:mod:`.numbers`); a former process's go on
        self.numbers = numbers
        self.reserved: Numbers | None = None
        if numbers is not None and isinstance(self.engine, RegionEngine):
            r = self.engine.region
            self.reserved = read_numbers(numbers, r.name, r.index, r.centre.id_step)
            if self.reserved is not None:
                r.centre.next_id, r.serial = self.reserved
        # a region centre's first picture says it began with no tracks, and its numbers then (a replay of the
        # recording starts the region's centre afresh there: docs/multitarget.md#regions)
        self.began = (Numbers(self.engine.region.centre.next_id, self.engine.region.serial)
                      if isinstance(self.engine, RegionEngine) else None)
        self.handovers_at: list[int] = []  # positions in ``order`` that are hand-overs taken over
        self.taken: dict[str, dict[int, bytes]] = {}  # sending region -> its last HANDOVERS_KEPT numbers taken: digest
        self.clock = PictureClock(cfg.period, cfg.picture_delay, max_gap=max_time_jump_s)
        # a scan or report stamped far ahead of the data waits for a witness (fedtrack/services/lead.py)
        # ... and, beside two or more other live sensors, for another sensor's data near its time
        # ... and, where a witness can come (two or more sensors allowed), the first messages until two agree within
        # max_time_jump_s, for at most start_wait_s of wall-clock time (fedtrack/services/lead.py, "The start")
        witnessed = cfg.sensors == "any" or len(cfg.sensors) >= 2
        self.lead: LeadGuard[Measurement | TrackReport] = LeadGuard(
            cfg.max_lag, corroborate=True, start_gap=max_time_jump_s if witnessed else None)
        self.start_wait_s = min(cfg.leave_after_s, RESET_TIMEOUT_S / 2)
        # ... and a start of one sensor's messages, abandoned when two others agree against it (lead.SoleStart)
        self.sole: SoleStart[Measurement | TrackReport] = SoleStart(max_time_jump_s, ended=not witnessed)
        self.sole_shown = -1  # the largest track id a picture published under such a start showed (_keep_published)
        self.start_held_at: float | None = None  # when the first message held for the start came (time.monotonic)
        self.order: list[tuple[str, int]] = []  # scans processed since the last picture
        self.left_at: list[int] = []  # positions in ``order`` that are departures
        self.restarted_at: list[int] = []  # positions in ``order`` where a sensor's tracker restarted
        self.pictures = 0
        self.silence = Silence(cfg.leave_after_s)  # the sensors heard from, and when one counts as gone
        self.peers = Peers()  # the tokens of the sensors heard from, by sensor (a Zenoh thread's)
        self.departed: dict[str, float] = {}  # sensor -> when its token went, for the losses acted on
        self.contested = False  # a conflicting message since the last picture (docs/wire.md)
        # failover (:mod:`.failover.standby`): a primary's (``primary``), or a hot standby's withheld outputs
        self.started_standby = standby
        self.standby = Standby(self._scope(), time.monotonic(), primary=not standby)
        self.primary_token: Any = None  # the liveliness token ``alive/mtt-primary/<scope>/<instance>``, while primary
        self.primary_seen: deque[tuple[bool, float, str]] = deque()  # primary tokens' changes (a Zenoh thread)
        self.tokens_dropped = 0  # of them, not queued: PRIMARY_CHANGES_KEPT were waiting (a Zenoh thread's)
        self.follow = PrimaryOrder(SETTLED_MAX)  # a warm region standby's inputs, held for its primary's order
        self.aside = False  # stepped aside at its clean stop (on_stopping)
        self.fresh = pickle.dumps(tuple(getattr(self, a) for a in self.start_attrs))  # before the first message

    def on_start(self) -> None:
        assert self.session is not None
        role = "sensor" if self.algorithm == "mtt-centralized" else "mtt-local"
        # with history: the tokens already at the router when this centre's link comes back (the trackers that
        # reconnected first) come as PUTs too, as the fusion centre's do (else they would count as deaths)
        self._inputs.append(self.session.liveliness().declare_subscriber(self.keys.alive(role), self._on_alive,
                                                                         history=True))
        self._start_failover()

    def _on_alive(self, sample: zenoh.Sample) -> None:
        """Zenoh thread: a tracker's (or sensor's) token came or went (:class:`Peers`); the worker drops
        the sensor of one gone (on_tick). Only the sensors heard from are followed: another's token
        changes nothing (a flood of forged tokens holds no memory)."""
        sensor = str(sample.key_expr).rsplit("/", 1)[-1]
        if sensor in self.silence.previous:
            self.peers.token(sensor, sample.kind == zenoh.SampleKind.PUT, time.monotonic())

    def _token_departures(self, now: float) -> list[str]:
        """The sensors whose tokens went and count as their trackers' deaths at ``now`` (:meth:`Peers.went`:
        not one that went with this centre's link to its router and may still come back), each loss once
        (a sensor heard again without its token back, a report in flight from a dead tracker, leaves no
        second time for it)."""
        went, lost = self.peers.went(self.link(), now), self.peers.lost
        new = [sensor for sensor, when in went.items() if self.departed.get(sensor) != when]
        self.departed = {s: when for s, when in {**self.departed, **went}.items() if lost.get(s) == when}
        return new

    def on_tick(self) -> None:
        self._failover_tick()
        if self.in_order():  # its departures are its primary's, listed in its pictures
            self._follow()
            return
        now = time.monotonic()
        if self.lead.first and self.start_held_at is not None and now - self.start_held_at >= self.start_wait_s:
            self._open_start()
        silent = self.silence.silent(now) + self._token_departures(now)
        for sensor in dict.fromkeys(silent):
            if sensor not in self.silence.last:
                continue
            with self.guarded(f"the departure of {sensor}"):
                self._leave(sensor)

    def _open_start(self) -> None:
        """No witness of the first messages held within ``start_wait_s``: take them as they came (counted
        ``start_unwitnessed``; fedtrack/services/lead.py, "The start")."""
        held = self.lead.open_start()
        self.start_held_at = None
        self.count("start_unwitnessed", len(held))
        self.log.warning("%d first message(s) not witnessed within %g s: taken as they came", len(held),
                         self.start_wait_s)
        for msg in held:
            with self.guarded(f"first message {msg.seq} of {msg.sensor}"):
                self._process(msg)

    def _leave(self, sensor: str) -> None:
        """Drop ``sensor`` from fusion (its tracker gone or silent); the next picture lists it."""
        self.silence.left(sensor)
        self.engine.leave(sensor)
        self.lead.leave(sensor)
        self.clock.left()
        self.left_at.append(len(self.order))
        self.order.append((sensor, 0))
        self.count("sensors_left")
        self.log.info("sensor %s left: dropped from fusion", sensor)

    def subscriptions(self) -> list[Subscription]:
        return self._inputs_of_centre() + self._primary_outputs()

    def plain_outputs(self) -> tuple[str, ...]:
        """The answers and hand-overs: their readers (the trackers, the region centres and standbys,
        the launcher) are plain subscribers. The one centre's ``fusion/picture`` keeps its cache: the
        recorder reads it with history."""
        k = self.keys
        return k.mtt_resets(), k.region_resets(), k.region_handover()

    def windowed_outputs(self) -> dict[str, int]:
        """The region pictures: the last :func:`picture_window` of them, which a restarted ``serve
        picture`` (a subscriber with history) merges."""
        return {self.keys.region_picture(): picture_window(self.cfg.period, self.speed)}

    def _inputs_of_centre(self) -> list[Subscription]:
        if self.algorithm == "mtt-centralized":
            return [Subscription(self.keys.sensor_meas(), Measurement, self.on_scan)]
        if self.region is not None:
            return [Subscription(self.keys.region_report(self.region), TrackReport, self.on_report),
                    Subscription(self.keys.region_handover(self.region), HandOver, self.on_handover)]
        return [Subscription(self.keys.mtt_report(), TrackReport, self.on_report)]

    def _admit(self, msg: Measurement | TrackReport) -> bool:
        """True for a new (sensor, scan). False for an identical repeat (counted ``duplicate``) and
        for a second, different one: rejected, and the next picture is marked ``contested`` (the
        first was fused)."""
        if not self.cfg.allows(msg.sensor):
            raise Rejected("unknown_sensor", f"sensor {msg.sensor!r} is not in mtt.sensors")
        if msg.sensor not in self.silence.last and len(self.silence.last) >= MAX_LIST_ITEMS:
            raise Rejected("too_many_sensors", f"sensor {msg.sensor!r} would be live beside {MAX_LIST_ITEMS} others: "
                           f"a picture's track lists at most {MAX_LIST_ITEMS} sensors")
        try:
            if self.received.check(msg):
                return True
            self.count("duplicate")
            return False
        except Conflict as exc:
            conflict = exc
        if not self.contested:
            self.count("contested")
        self.contested = True
        self.note_rejected(self.keys.mtt_report(msg.sensor) if isinstance(msg, TrackReport)
                           else self.keys.sensor_meas(msg.sensor), conflict)
        return False

    def _take(self, msg: Measurement | TrackReport) -> None:
        """Process ``msg`` (checked; :meth:`_process`) unless it is stamped far ahead of the data, or
        ahead of every other sensor's: then it waits for a witness or another sensor's data
        (:class:`LeadGuard`; taken as received meanwhile), and the messages released with it are
        processed in time order."""
        key = self.keys.mtt_report(msg.sensor) if isinstance(msg, TrackReport) else self.keys.sensor_meas(msg.sensor)
        if self.sole.contradicts(msg.t):
            self._contradicting(key, msg)
            return
        released = self.in_time(self.lead, key, msg)
        self.start_held_at = (self.start_held_at or time.monotonic()) if self.lead.first else None
        if not any(item is msg for item in released):
            self.received.take(msg)
        for held in released:
            self._process(held)

    def _process(self, msg: Measurement | TrackReport) -> None:
        """Make the pictures due before data at ``msg.t``, process ``msg``, then publish them (compute,
        then commit: a failure undoes both) and note the scan."""
        skipped = self.clock.skipped
        pictures = [self._picture(T) for T in self.clock.due(self.engine.data_time(msg.sensor, msg.t))]
        if self.clock.skipped > skipped:
            self.count("skipped_pictures", self.clock.skipped - skipped)
            self.log.warning("scan %d of %s at t=%g: %d picture times more than max_time_jump_s = %g s before it "
                             "not made", msg.seq, msg.sensor, msg.t, self.clock.skipped - skipped, self.clock.max_gap)
        self._room(f"scan {msg.seq} of {msg.sensor}")
        if isinstance(msg, Measurement):
            scan = scan_from_measurement(msg)
            try:
                self.engine.ingest(scan)
            except CrowdedScan as exc:  # the transaction puts the centre back
                raise Rejected("crowded", f"scan {msg.seq} of {msg.sensor}: {exc}") from None
            self.engine.repeated += scan.repeated
        else:
            self._restart(msg)
            self._fuse(msg)
        for picture in pictures:
            self.publish(self.picture_key, picture)
            if not self.sole.ended:  # a start it may abandon: what it showed stays issued (_keep_published)
                self.sole_shown = max([self.sole_shown, *picture.ids])
        self.order.append((msg.sensor, msg.seq))
        self.silence.heard(msg.sensor, time.monotonic())
        self.lead.took(msg.sensor, msg.t)
        self.sole.took(msg.sensor, msg.t)
        self.received.take(msg)

    def _contradicting(self, key: str, msg: Measurement | TrackReport) -> None:
        """``msg`` contradicts a start of one sensor's messages (:class:`SoleStart`): held, counted
        ``rejected_time_behind`` or ``rejected_time_lead``; or, with a held one of another sensor that agrees with
        it, the start abandoned (``start_abandoned``): the centre's state as before its first message, then the held
        messages near it and it taken again."""
        self.received.take(msg)
        again = self.sole.contradicted(msg.sensor, msg.t, msg, held_bytes(msg))
        if not again:
            assert self.sole.span is not None
            early = msg.t < self.sole.span[0]
            self.note_rejected(key, Rejected("time_behind" if early else "time_lead", (
                f"{msg.sensor}'s message {msg.seq} at t={msg.t:g}, more than max_time_jump_s from the start, "
                f"every message taken {self.sole.sensor}'s (held: lead.SoleStart)")))
            return
        self.count("start_abandoned")
        self.log.warning("%s's message %d at t=%g and another sensor's agree against the start, every message "
                         "taken %s's: started again from them (lead.SoleStart)", msg.sensor, msg.seq, msg.t,
                         self.sole.sensor)
        serial = self.engine.region.serial if isinstance(self.engine, RegionEngine) else 0
        self._afresh()
        self._keep_published(serial)
        for held in again:
            self._take(held)

    def _afresh(self) -> None:
        """The state a start changes put back as before the first message (``start_attrs``), the clock's grid
        kept once a picture fixed it: its pictures' numbers keep naming their times (:meth:`_keep_published`)."""
        clock = self.clock
        for name, value in zip(self.start_attrs, pickle.loads(self.fresh)):
            setattr(self, name, value)
        if clock.fixed:
            self.clock.first, self.clock.fixed = clock.first, True

    def _began_again(self, next_id: int, serial: int) -> None:
        """A warm region standby in its primary's order: a picture of the primary says it began afresh (its
        ``began`` entry: it abandoned a start, :meth:`_contradicting`) after this standby took inputs. It starts
        afresh too, numbering as its primary then does, and takes the entries listed after (before, it fused them
        on its former state: at 10^9 s 125 sub-reports late, and after a take-over 4 of 30 merged pictures the
        clean run's). Its primary's first picture's entry finds it fresh: nothing to do."""
        if self.lead.newest is None or not isinstance(self.engine, RegionEngine):
            return
        self._afresh()
        region = self.engine.region
        region.centre.next_id, region.serial = next_id, serial
        self.began = Numbers(next_id, serial)
        self.count("start_abandoned")
        self.log.warning("its primary began afresh (numbers %d, %d): so does this standby", next_id, serial)

    def _keep_published(self, serial: int) -> None:
        """After an abandoned start (its state put back as before the first message): what it published stays
        published, so no number it gave is given again. Its pictures' numbers keep naming their times (the clock's
        grid, kept by :meth:`_afresh`: the recorder keys pictures by number, and the start's at -10^12 s took the
        numbers 0, 1, ... that the honest pictures then took again, refused ``conflict``), the ids its pictures
        showed are not issued again (``sole_shown``), nor its hand-overs' numbers (below ``serial``: each was
        published as it was issued); a region centre's next picture says it began with those numbers
        (docs/multitarget.md, "What an abandoned start published")."""
        self.engine.issue_past(self.sole_shown)
        if isinstance(self.engine, RegionEngine):
            region = self.engine.region
            region.serial = max(region.serial, serial)
            if self.began is not None:
                self.began = Numbers(region.centre.next_id, region.serial)

    def _restart(self, msg: TrackReport) -> None:
        """The first report of a tracker process from a sensor heard before: its tracker restarted
        (its tracks and ids afresh). The local tracks of its former process leave their central
        tracks, and the next picture lists the restart before the report, so that a replay of the
        recording starts that sensor's tracker afresh there too (docs/multitarget-formats.md, restart line).
        A report marked ``first`` that keeps tracks of earlier scans is no restart (``restarts_ignored``)."""
        if not msg.first or msg.sensor not in self.silence.previous:
            return
        if not could_be_first(msg):  # its tracker ran on: a replay, restarting it there, would part from live
            self.count("restarts_ignored")
            return
        self.engine.restart(msg.sensor)
        self.restarted_at.append(len(self.order))
        self.order.append((msg.sensor, msg.seq))
        self.count("trackers_restarted")
        self.log.info("sensor %s's tracker restarted: its former tracks dropped from fusion", msg.sensor)

    def _room(self, what: str) -> None:
        """Rejected("too_large") when the next picture already lists as many entries as it may."""
        if len(self.order) >= PICTURE_ITEMS - MAX_LIST_ITEMS:
            raise Rejected("too_large", f"{what}: the next picture already lists {len(self.order)} scans and "
                           f"hand-overs, at most {PICTURE_ITEMS - MAX_LIST_ITEMS} (PICTURE_ITEMS)")

    def on_scan(self, msg: Measurement) -> None:
        try:
            scan = scan_from_measurement(msg)
        except ValueError as exc:
            raise Rejected("wrong_model", str(exc)) from None
        problem = misplaced(scan, self.sites)
        if problem:
            raise Rejected("wrong_site", f"scan {msg.seq} of {msg.sensor}: {problem}")
        if scan.sensor_position is not None and self.dim != 6:
            raise Rejected("wrong_model", "a radar scan at a 2-D centre (--dim 4)")
        where = scan.z if scan.sensor_position is None else np.concatenate([scan.z.ravel(), scan.sensor_position])
        self._in_scale(f"scan {msg.seq} of {msg.sensor}", where, scan.R)
        self._numbered(f"scan {msg.seq} of {msg.sensor}", msg.t)
        if self._admit(msg):
            self._take(msg)

    def on_report(self, msg: TrackReport) -> None:
        d = msg.x.shape[1] if msg.ids else None
        if d is not None and (d not in (4, 6) or d > self.dim):
            raise Rejected("wrong_model", f"local state of size {d} at a centre of size {self.dim}")
        m = msg.obs_z.shape[1]
        if msg.obs_z.shape[0] and not (m in (2, 3) and m <= d // 2):  # a position, or a radar's 3
            raise Rejected("wrong_model", f"observations of size {m} from a local state of size {d}")
        self._in_scale(f"report {msg.seq} of {msg.sensor}", np.concatenate([msg.x.ravel(), msg.obs_z.ravel()]),
                       np.concatenate([msg.P.ravel(), msg.obs_R.ravel()]))  # the observations are fused too
        self._numbered(f"report {msg.seq} of {msg.sensor}", msg.t)
        if not self._admit(msg):
            return
        if msg.contested:  # its local tracker took a conflicting scan or resets (docs/wire.md)
            self.log.warning("report %d of %s names contested scans %s", msg.seq, msg.sensor, list(msg.contested))
        if self.in_order():
            self.hold_input(msg)
            return
        self._take(msg)

    def _in_scale(self, what: str, values: np.ndarray, P: np.ndarray) -> None:
        """Refuse (``scale``) states or covariances that a picture predicted from them could carry
        beyond the wire's bound, which every receiver would refuse: the horizon is the longest a
        picture predicts a track from the data that made it, ``unsupported_s`` (unsupported tracks are
        deleted: ``central_timeout``, or ``max_lag`` where longer) + ``max_lag`` (the data's own lag) +
        ``period`` (:func:`fedtrack.wire.predictable`)."""
        horizon = self.cfg.unsupported_s + self.cfg.max_lag + self.cfg.period
        if not predictable(values, P, horizon):
            raise Rejected("scale", f"{what}: values up to {np.max(np.abs(values), initial=0.0):.3g}, covariances up "
                           f"to {np.max(np.abs(P), initial=0.0):.3g}: predicted over {horizon:g} s they could leave "
                           f"the wire's +-{MAX_MAGNITUDE:g}")

    def _numbered(self, what: str, t: float) -> None:
        """Refuse (``time_jump``) a time whose picture's number would leave the wire's integers
        (``NUMBER_ROOM`` periods from t = 0): a first scan at t = 1e19 s made the closing record
        unpublishable and the centre's stop fail (``OverflowError``)."""
        if not abs(t) / self.cfg.period < NUMBER_ROOM:
            raise Rejected("time_jump", f"{what} at t={t:g}: its picture would be number "
                           f"{abs(t) / self.cfg.period:.3g}, beyond {NUMBER_ROOM:.3g} ({self.cfg.period:g} s "
                           "pictures from t = 0)")

    def _fuse(self, msg: TrackReport) -> None:
        """The centre's part of a report (its region's part at a region centre); the next picture is
        contested if the report names contested scans. A report whose tracks would make more
        candidate pairs than the centre takes (:class:`CrowdedReport`) is rejected ``crowded``."""
        report, engine = report_from_wire(msg), self.engine
        try:
            if isinstance(engine, RegionEngine):
                self._answer(engine, msg, report)
            else:
                assert isinstance(engine, TrackToTrackEngine)
                resets, q_scale = engine.fuse(report)
                if engine.feedback:
                    require_covariances(f"the resets of report {msg.seq} of {msg.sensor}", resets.P)
                    self.publish(self.keys.mtt_resets(msg.sensor), resets_to_wire(msg.seq, resets, q_scale))
        except CrowdedReport as exc:  # the transaction puts the centre back (fedtrack.services.base)
            raise Rejected("crowded", f"report {msg.seq} of {msg.sensor}: {exc}") from None
        for tr in (engine.region.centre.consistency.drain() if isinstance(engine, RegionEngine)
                   else engine.consistency_transitions()):
            self.log.warning("sensor %s %s at t=%.2f: its innovations %.2f times the others', tail probability "
                             "%.2g; %s", tr.sensor, "inconsistent" if tr.flagged else "consistent again", tr.t,
                             tr.ratio, math.exp(tr.log_p), "its observations are left out of the fusion while it is "
                             "flagged and three or more sensors are live" if tr.flagged else "fused again")
        for f in (engine.region.centre.copies.drain() if isinstance(engine, RegionEngine) else engine.feed_copies()):
            self.log.warning("sensor %s %s %s's feed at t=%.2f (the same observations at the same times): its reports "
                             "are %s", f.copy, "copies" if f.found else "no longer copies", f.original, f.t,
                             "not fused" if f.found else "fused again")
        registrations = ([engine.region.centre.registration] if isinstance(engine, RegionEngine)
                         else engine.registrations())
        for c in (c for reg in registrations for c in reg.drain()):
            self.log.warning("sensor %s off the consensus at t=%.2f by %s (chi-square %.1f): its reports are "
                             "corrected by %s from its next one", c.sensor, c.t, describe(c.step), c.chi2,
                             describe(c.total))
        flagged = (sorted(engine.region.centre.consistency.flagged) if isinstance(engine, RegionEngine)
                   else engine.inconsistent_sensors())
        corrected = sorted({s for reg in registrations for s in reg.applied})
        parts = ([f"inconsistent sensors: {','.join(flagged)}"] if flagged else []) \
            + ([f"registration corrected: {','.join(corrected)}"] if corrected else [])
        self.status = "; ".join(parts)[:MAX_STRING_LENGTH] or "ok"
        self.contested = self.contested or bool(msg.contested)

    def _answer(self, engine: RegionEngine, msg: TrackReport, report: Any) -> None:
        """A region centre's part of a sub-report: fuse, hand over, answer (sends last)."""
        assert self.regions is not None
        elsewhere = np.array(msg.elsewhere, dtype=bool) if msg.elsewhere else np.zeros(len(msg.ids), dtype=bool)
        self._reserve(engine, len(msg.ids))
        answer, moving = engine.answer(report, elsewhere)
        here = self.regions.ids[engine.index]
        for owner, serial, record in moving:
            self.publish(self.keys.region_handover(self.regions.ids[owner], here),
                         handover_to_wire(record, here, serial))
        self.count("handed_over", len(moving))
        self.publish(self.keys.region_resets(self.region, msg.sensor),
                     answer_to_wire(msg.seq, answer, self.regions, engine.index))

    def _reserve(self, engine: RegionEngine, rows: int) -> None:
        """Before a sub-report of ``rows`` rows is fused: reserve in the numbers file the ids and hand-over
        numbers it may issue (:func:`.numbers.reservation`). A file that cannot be written is counted
        ``numbers_unsaved`` and the centre fuses on (a restart would number from the last reservation)."""
        if self.numbers is None:
            return
        region = engine.region
        due = reservation(Numbers(region.centre.next_id, region.serial), self.reserved, region.centre.id_step, rows)
        if due is None:
            return
        try:
            write_numbers(self.numbers, region.name, due)
        except OSError as exc:
            self.count("numbers_unsaved")
            self.log.warning("numbers file %s not written (%s): a restart would number from its last reservation",
                             self.numbers, exc.strerror)
            return
        self.reserved = due

    def on_handover(self, msg: HandOver) -> None:
        """A neighbour's central track taken over (listed in the next picture's fused lists); a standby in
        its primary's order holds it until then (:meth:`hold_input`)."""
        assert self.regions is not None
        if msg.source not in self.regions.ids or msg.source == self.region:
            raise Rejected("unknown_region", f"a hand-over from {msg.source!r}: not another region of [regions]")
        if self.in_order():
            self.hold_input(msg)
            return
        self.take_handover(msg)

    def take_handover(self, msg: HandOver) -> None:
        """Take a neighbour's central track over (checked: :meth:`on_handover`)."""
        engine = self.engine
        assert isinstance(engine, RegionEngine)
        assert self.regions is not None
        seen = self.taken.get(msg.source, {})
        first = seen.get(msg.serial)
        if first is not None:
            if first == digest(msg):
                self.count("duplicate")
                return
            self._contest(msg, f"a second, different hand-over {msg.serial} of {msg.source} (the first was taken)")
            return
        if len(seen) >= HANDOVERS_KEPT and msg.serial < min(seen):  # older than every one kept: a re-delivery
            self.count("late")
            return
        try:
            record = handover_from_wire(msg, engine.region.centre)
        except ValueError as exc:
            raise Rejected("wrong_model", str(exc)) from None
        ring = engine.region.centre.tracks.ring_of(record.entries)
        if ring["t"][-1] > self.lead.horizon():  # the sender fused it from a report this centre gets too
            raise Rejected("time_lead", f"hand-over {msg.serial} of {msg.source}: its newest entry at "
                           f"t={ring['t'][-1]:g} is beyond t={self.lead.horizon():g}, the latest a report "
                           "would be taken here at once")
        newest = ring["x"][-1]
        owner = int(engine.region.owners(newest[[0]], newest[[2]])[0])
        if owner != engine.index:  # its sender hands a track to the owner of its newest estimate's position
            raise Rejected("wrong_region", f"hand-over {msg.serial} of {msg.source}: its newest estimate, at "
                           f"({newest[0]:.6g}, {newest[2]:.6g}), is in region {self.regions.ids[owner]!r}")
        self._in_scale(f"hand-over {msg.serial} of {msg.source}", np.concatenate([ring["x"].ravel(), ring["z"].ravel()]),
                       np.concatenate([ring["P"].ravel(), ring["R"].ravel()]))  # its observations are fused again
        held = confirmed_holder(engine.region.centre, record)
        if held is not None:  # a confirmed track here fuses the local tracks the record would take to a new id
            self._contest(msg, f"hand-over {msg.serial} of {msg.source}: names local tracks of confirmed central "
                               f"track {held[0]} here (newest state t={held[1]:g}; the record's newest entry "
                               f"t={ring['t'][-1]:g})")
            return
        holder = disputed(engine.region.centre, record)
        if holder is not None:  # two claims on one local track, as far apart as two targets' tracks
            self._contest(msg, f"hand-over {msg.serial} of {msg.source}: names local tracks of central track "
                               f"{holder[0]} here, which it is not an estimate of (chi-square {holder[1]:.4g}, beyond "
                               f"the association gate {self.cfg.thresholds.association[self.dim]:.4g})")
            return
        centre, R, here = engine.region.centre, len(engine.regions.ids), engine.index
        unissued = msg.id % R == here and msg.id >= centre.next_id
        late = self.standby.cold and not self.standby.primary  # its primary issued ids before it started
        if msg.id in centre.tracks or (unissued and not late):
            raise Rejected("conflict", f"central track {msg.id} is already here, or is an id this region has "
                                       "not issued")
        if unissued:  # a track of this region that left before the cold standby started and comes back
            if msg.id >= NUMBER_ROOM:
                raise Rejected("seq_jump", f"hand-over {msg.serial} of {msg.source}: id {msg.id}, at most "
                               f"{NUMBER_ROOM - 1} (NUMBER_ROOM) leaves room to number after it")
            centre.next_id = next_after(centre.next_id, centre.id_step, [msg.id])
        self._room(f"hand-over {msg.serial} of {msg.source}")
        engine.take_over(record)
        seen = {**seen, msg.serial: digest(msg)}
        self.taken[msg.source] = dict(sorted(seen.items())[-HANDOVERS_KEPT:])
        self.handovers_at.append(len(self.order))
        self.order.append((msg.source, msg.serial))
        self.count("taken_over")

    def _contest(self, msg: HandOver, detail: str) -> None:
        """Refuse a hand-over that contradicts what was taken (``conflict``, the state kept) and mark the next
        picture contested: either may be the forgery."""
        if not self.contested:
            self.count("contested")
        self.contested = True
        self.note_rejected(self.keys.region_handover(self.region, msg.source),
                           Conflict(msg.serial, detail))

    def _picture(self, T: float, closing: bool = False) -> TrackPicture:
        """The next picture, at ``T`` (it lists the scans since the previous one)."""
        flying: dict[int, float] = {}
        if closing:
            tracks = no_tracks(self.dim)
        elif isinstance(self.engine, RegionEngine):  # its tracks and the copies of those it handed over lately
            shown = self.engine.region_picture(T)
            tracks = union_picture([shown.held, shown.flying], self.dim)
            flying = dict(zip(shown.flying.ids, shown.flying_t)) if shown.flying is not None else {}
        else:
            tracks = self.engine.picture(T)
        tracks = tracks.on_the_earth(self.frame, self.cfg.init_z_std)
        require_finite(f"the picture at t={T}", tracks.x, tracks.P)
        seq = self.clock.number((self.clock.k or 0) * self.clock.period if closing else T)
        order, left, handovers, restarted, began = self.order, self.left_at, self.handovers_at, self.restarted_at, ()
        if self.began is not None:  # this process's first picture: its start is its first entry
            assert self.region is not None
            order = [(self.region, self.began.next_id), *order]
            left, handovers, restarted = ([i + 1 for i in at] for at in (left, handovers, restarted))
            began = ((0, self.began.serial),)
            self.began = None
        picture = picture_message(seq, T, tracks, order, left, self.contested, closing, handovers, flying=flying,
                                  restarted=restarted, began=began,
                                  earth=picture_geodetic(self.frame, tracks.x, tracks.P, self.cfg.init_z_std))
        self.pictures += 1
        self.order, self.left_at, self.contested, self.handovers_at = [], [], False, []
        self.restarted_at = []
        self.counters["pictures"] = self.pictures
        for name, value in self.engine.counters().items():
            self.counters[name] = value
        self._failover_counters()
        return picture

    def _publish_picture(self, T: float, closing: bool = False) -> None:
        self.publish(self.picture_key, self._picture(T, closing))

    def on_stop(self) -> None:
        """The pictures still due at the end of the data (as the replay writes them), then the
        closing record of the scans processed after the last picture (a region centre's even when none: the
        merger awaits it at its own stop, :meth:`PictureMergeService.held`), unless this primary stepped
        aside for its standby (:meth:`_steps_aside`); messages still held for a witness (stamped far
        ahead) are counted ``rejected_time_lead``."""
        self.note_leads(self.keys.mtt_report(), self.lead.end())
        if self.aside:
            return
        for T in self.clock.final():
            self._publish_picture(T)
        if self.order or (self.region is not None and self.pictures):  # a region's always: the merger awaits it
            self._publish_picture(self.clock.high, closing=True)



def service_from_args(argv: list[str]) -> MttCentreService:
    """The centre that ``serve mtt-centre ARGV`` runs (a ConfigError is the CLI's one-line error)."""
    parser = service_parser("mtt-centre", "the multi-target fusion centre")
    parser.add_argument("--algorithm", choices=ALGORITHMS, default="mtt-federated", help="the fusion of the local trackers' tracks (default: %(default)s)")
    parser.add_argument("--dim", type=int, choices=(4, 6), default=4,
                        help="central state size: 6 when any sensor is a radar (default: %(default)s)")
    parser.add_argument("--config", help="configuration file; reads [mtt], [deployment], [frame] and, with "
                        "--region, [regions] (docs/multitarget.md; default: none, every key at its default)")
    parser.add_argument("--region", metavar="RID", help="the centre of this region of the config's [regions] only "
                        "(docs/multitarget.md#regions; default: none, the one centre of the whole area)")
    parser.add_argument("--standby", action="store_true",
                        help="hot standby: run the centre, publish nothing until the primary is gone (docs/deploy.md)")
    parser.add_argument("--numbers", metavar="PATH",
                        help="with --region: the file where the centre reserves its track ids and hand-over numbers "
                        "before issuing them; started again with it, it numbers after its former process "
                        "(docs/deploy.md; default: none, numbering from the start)")
    args = parser.parse_args(argv)
    kwargs = service_kwargs(parser, args)
    path = Path(args.config) if args.config else None
    settings = load_tables(path, MttServiceSettings)
    frame = None if settings.frame is None else settings.frame.frame
    regions = load_regions(path) if args.region else None
    return MttCentreService(args.algorithm, settings.mtt, args.dim, settings.deployment.max_seq_jump, frame,
                            args.region, regions, standby=args.standby, speed=settings.deployment.speed,
                            numbers=Path(args.numbers) if args.numbers else None, sites=settings.frame,
                            max_time_jump_s=settings.deployment.max_time_jump_s, **kwargs)


def main(argv: list[str]) -> int:
    return service_from_args(argv).run()
