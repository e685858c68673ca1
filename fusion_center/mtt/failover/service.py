"""A multi-target centre's failover, its service side (:class:`CentreFailover`, mixed into
:class:`fedtrack.fusion_center.mtt.service.MttCentreService`): the primary token it claims or
watches, what a standby watches of its primary's outputs and withholds of its own, a warm region
standby's inputs taken in its primary's order (:mod:`.ordered`), its take-over and a primary's
step-down, over Zenoh; the decisions are :mod:`.standby`'s."""

from __future__ import annotations

import time

import zenoh

from fedtrack.config import ConfigError
from fedtrack.fusion_center.mtt.failover.ordered import Item
from fedtrack.fusion_center.mtt.failover.standby import (
    NUMBER_ROOM,
    PRIMARY_CHANGES_KEPT,
    SILENT_S,
    claim_instance,
    next_after,
    numbers_of,
)
from fedtrack.fusion_center.mtt.regional import RegionEngine
from fedtrack.services.base import Subscription
from fedtrack.services.rejections import Rejected
from fedtrack.wire import HandOver, Message, TrackPicture, TrackReport, TrackResets
from fedtrack.zsession import LOST_KEPT


class CentreFailover:
    """The failover hooks of :class:`fedtrack.fusion_center.mtt.service.MttCentreService`. It relies
    on that service's ``standby``, ``primary_token``, ``primary_seen``, ``tokens_dropped``, ``started_standby``,
    ``peers``, ``silence``, ``engine``, ``region``, ``clock`` and ``follow`` (its methods ``_take``,
    ``_process``, ``_leave``, ``take_handover``), and on :class:`fedtrack.services.base.Service`'s ``session``,
    ``keys``, ``counters``, ``count``, ``log``, ``_inputs`` and ``_router_lost_at``."""

    def _scope(self) -> str:
        """What this centre covers, the chunk of its primary token: its region, or ``all``."""
        return self.region or "all"

    def _start_failover(self) -> None:
        """Watch the primary tokens; a primary claims one (refusing to start if another holds one;
        two started together both claim, and the earlier claim steps down: :meth:`_failover_tick`). A
        region's centre, primary or standby, also holds the region's centre token while it runs."""
        assert self.session is not None
        key = self.keys.primary(self._scope())
        present = any(reply.ok is not None for reply in self.session.liveliness().get(key, timeout=1.0))
        if self.standby.primary:
            if present:
                raise ConfigError(f"{key}: this centre already has a primary; start another with --standby")
            self._claim()
        elif not present:
            self.standby.found_none(time.monotonic())
        self._inputs.append(self.session.liveliness().declare_subscriber(key, self._on_primary, history=True))
        # every centre of a scope, primary or standby: serve picture waits for a region's pictures, and a
        # primary stopped mid-run leaves its scope to another centre of it (_steps_aside)
        self._inputs.append(self.session.liveliness().declare_token(
            self.keys.region_centre(self._scope(), str(self.session.zid()))))

    def _claim(self) -> None:
        """Declare this centre's primary token, under a new instance (:func:`.standby.claim_instance`)."""
        assert self.session is not None
        self.standby.instance = claim_instance(str(self.session.zid()), time.time_ns(), self.standby.latest)
        self.primary_token = self.session.liveliness().declare_token(self.keys.primary(self._scope(),
                                                                                       self.standby.instance))

    def _on_primary(self, sample: zenoh.Sample) -> None:
        """Zenoh thread: a primary token appeared or went; the worker acts on it (on_tick). At most
        ``PRIMARY_CHANGES_KEPT`` wait at once, the rest dropped and counted (``tokens_dropped``): before, a flood
        of forged tokens between two ticks queued every change (tests/test_hostile_regions.py)."""
        if len(self.primary_seen) >= PRIMARY_CHANGES_KEPT:
            self.tokens_dropped += 1
            return
        self.primary_seen.append((sample.kind == zenoh.SampleKind.PUT, time.monotonic(),
                                  str(sample.key_expr).rsplit("/", 1)[-1]))

    def _primary_outputs(self) -> list[Subscription]:
        """A standby watches what its primary publishes (:meth:`Standby.sent`): the pictures, the
        answers and (a region's) the hand-overs it sends to the other regions; a primary declares
        them too, for it may step down (:meth:`_failover_tick`), but takes no sample while it is the
        primary (``wanted``): decoding its own pictures and answers cost a 1,000-track centre about a
        fifth of its CPU."""
        def watching() -> bool:
            return not self.standby.primary or bool(self.standby.silent)

        keys = ([self.keys.mtt_picture(), self.keys.mtt_resets()] if self.region is None else
                [self.keys.region_picture(self.region), self.keys.region_resets(self.region),
                 self.keys.region_handover(None, self.region)])
        return [Subscription(key, kind, self._primary_sent, wanted=watching, remote=True)
                for key, kind in zip(keys, (TrackPicture, TrackResets, HandOver))]

    def _primary_sent(self, msg: TrackPicture | TrackResets | HandOver) -> None:
        if self.standby.primary:  # another session publishes this region's outputs: a silent token's holder?
            self.standby.heard_remote(time.monotonic())
            return
        beyond = [n for n in numbers_of(msg) if n >= NUMBER_ROOM]
        if beyond:  # no primary issues one; numbering after it would leave the wire's integers
            raise Rejected("seq_jump", f"an output of the primary with id or number {beyond[0]}: at most "
                           f"{NUMBER_ROOM - 1} (NUMBER_ROOM) leaves room to number after it")
        self.standby.sent(msg, time.monotonic())
        if isinstance(msg, TrackPicture) and not msg.closing and self.in_order():
            self.follow.listed(msg, time.monotonic())
            self._follow()
        if self.standby.cold and not self.in_order():  # a standby in order numbers as its primary does
            self._catch_up(msg)

    def in_order(self) -> bool:
        """Whether this centre takes its inputs in its primary's order (:mod:`.ordered`): a region's
        standby started as one, never a primary, warm (undecided until the first picture of its
        primary: its inputs are held meanwhile)."""
        return (self.region is not None and self.started_standby and not self.standby.primary
                and not self.standby.instance and self.follow.warm is not False)

    def hold_input(self, msg: TrackReport | HandOver) -> None:
        """An admitted sub-report or hand-over of a standby in order: held until its primary lists it."""
        self._take_held(self.follow.arrived(msg, time.monotonic()))
        self._follow()

    def _follow(self) -> None:
        """Take the inputs the primary's pictures listed, in their order, as far as they are here."""
        skipped = self.follow.skipped
        listed, stale = self.follow.due(time.monotonic())
        self._take_held(listed, listed=True)
        self._take_held(stale)
        if self.follow.skipped > skipped:
            self.count("order_skipped", self.follow.skipped - skipped)
        if self.follow.warm is False and self.follow.held:  # started after its primary had fused: its state
            listed, rest = self.follow.release()  # is its own, its inputs taken in arrival order from now on
            self._take_held(listed + rest)

    def _take_held(self, items: list[Item], listed: bool = False) -> None:
        """Take held inputs, each as its own transaction: listed ones (``listed``; a departure the entry
        ``("left", sensor)``) as the primary processed them; the others as they arrived (a sub-report
        through the lead guard)."""
        for entry, msg in items:
            with self.guarded(f"{entry} in its primary's order"):
                if msg is None:
                    if entry[0] == "left" and entry[1] in self.silence.last:
                        self._leave(entry[1])
                    elif entry[0] == "began":
                        self._began_again(entry[2], entry[3])
                elif isinstance(msg, HandOver):
                    self.take_handover(msg)
                elif listed:
                    self._process(msg)
                else:
                    self._take(msg)

    def _catch_up(self, msg: TrackPicture | TrackResets | HandOver) -> None:
        """A cold standby keeps its track ids and hand-over numbers ahead of its primary's
        (:func:`.standby.next_after`), and numbers its pictures as its primary does
        (:meth:`PictureClock.numbered`)."""
        if isinstance(msg, TrackPicture) and not msg.closing:
            self.clock.numbered(msg.seq, msg.t)
        engine = self.engine
        region = engine.region if isinstance(engine, RegionEngine) else None
        centre = region.centre if region is not None else getattr(engine, "centre", None)
        if isinstance(msg, HandOver) and region is not None:
            region.serial = max(region.serial, msg.serial + 1)
        if centre is not None and isinstance(msg, (TrackPicture, HandOver)):
            ids = msg.ids if isinstance(msg, TrackPicture) else (msg.id,)
            centre.next_id = next_after(centre.next_id, centre.id_step, ids)

    def publish(self, key: str, msg: Message) -> None:
        """Publish, or, as a standby that has not taken over, withhold (:meth:`Standby.hold`)."""
        if self.standby.primary:
            super().publish(key, msg)
            return
        self.standby.hold(key, msg, time.monotonic())
        self.count("withheld")

    def _failover_tick(self) -> None:
        """A standby takes over once no primary token exists, or only tokens that serve nobody
        (:meth:`Standby.due`): it claims the token and publishes what the dead primary never sent. A
        primary that sees another primary's token of a later claim, one not known to serve nobody,
        steps down (:meth:`Standby.yields`): it withdraws its token."""
        standby = self.standby
        while self.primary_seen:
            alive, now, instance = self.primary_seen.popleft()
            standby.token(alive, now, instance)
        if standby.ignored:
            self.counters["tokens_ignored"] = standby.ignored
        if self.tokens_dropped:
            self.counters["tokens_dropped"] = self.tokens_dropped
        if standby.cut != (self._router_lost_at is not None):  # its own link to the router went or came back
            standby.link(self._router_lost_at is None, time.monotonic())
        if standby.yields():
            standby.step_down(time.monotonic())
            if self.primary_token is not None:
                self.primary_token.undeclare()
                self.primary_token = None
            self.count("stepped_down")
            self.log.warning("stepped down as the primary of %s: another primary (instance %s) holds it; this one "
                             "(%s) is its hot standby", self._scope(), max(standby.holders - standby.silent),
                             standby.instance)
            return
        if not standby.due(time.monotonic()):
            return
        listed, rest = self.follow.release()  # taken as a standby: its outputs withheld, or settled
        self._take_held(listed, listed=True)
        self._take_held(rest)
        self._claim()
        standing = sorted(standby.holders - standby.silent)
        flushed = standby.take_over()
        if standing:
            self.count("silent_tokens", len(standing))
            self.log.warning("the primary token(s) of %s (instance %s) stood, but nothing of the region was published "
                             "for %g s while reports came: taking over beside them", self._scope(),
                             ", ".join(standing), SILENT_S)
        for key, msg in flushed:
            self.publish(key, msg)
        self.counters["took_over"] = 1
        self.log.warning("took over as the primary of %s: published %d withheld output(s) the primary never sent; "
                         "as a standby %d picture(s) equal to the primary's, %d differed (largest state difference "
                         "%.3g)", self._scope(), len(flushed), standby.same, standby.differ, standby.max_difference)

    def on_stopping(self) -> None:
        """At a clean stop, while its watches are up: whether to step aside (:meth:`_steps_aside`)."""
        self.aside = self._steps_aside()

    def _steps_aside(self) -> bool:
        """At a clean stop: whether this primary (a region's or the unsharded centre) leaves its scope to
        its standby as a killed one does, publishing nothing more (no pictures of the end of the data, no
        closing record): the deployment runs on (a tracker it heard from still holds its token: ``peers``)
        and another centre of the scope (its standby) holds the scope's centre token. Before, such a primary
        (SIGTERM mid-run) published the pictures due at the end of the data, made early, and a closing
        record: the merger took a region's early picture and refused the standby's of that time
        (``rejected_conflict``), and the replay of the recording parted from the live pictures (the
        unsharded centre's too). A liveliness query of the trackers' tokens, which this centre also
        watches, found none in 10 of 28 live stops of the unsharded centre (it then published the end as
        before); and ``mtt-centralized``'s are the sensors'. At the end of a run the trackers stop first
        (the launcher's ``STOP_STAGE``): their tokens are gone."""
        if not self.standby.primary or self.session is None:
            return False
        lost = self.peers.lost  # more gone than Peers keeps (LOST_KEPT): it cannot tell, and publishes the end
        if len(lost) >= LOST_KEPT or all(sensor in lost for sensor in self.silence.previous):
            return False
        others = {str(reply.ok.key_expr).rsplit("/", 1)[-1] for reply in
                  self.session.liveliness().get(self.keys.region_centre(self._scope()), timeout=1.0)
                  if reply.ok is not None} - {str(self.session.zid())}
        if not others:
            return False
        self.count("stepped_aside")
        self.log.warning("stopping while the trackers run on: left %s to its other centre(s) (%s) as a "
                         "killed primary, with no pictures of the end of the data and no closing record",
                         "region " + self.region if self.region is not None else "the unsharded centre's scope",
                         ", ".join(sorted(others)))
        return True

    def _failover_counters(self) -> None:
        if self.started_standby:
            self.counters["standby_same"], self.counters["standby_differ"] = self.standby.same, self.standby.differ
