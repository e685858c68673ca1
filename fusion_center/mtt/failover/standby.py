"""A region centre's hot standby (issue 27, failover): what it withholds and when it takes over.

A standby (``serve mtt-centre --region RID --standby``) subscribes the region's inputs as its
primary does and runs the same centre on them, but publishes nothing: every output it would
publish (resets, hand-overs, pictures) is *withheld* here, under its identity (:func:`output_of`:
a picture's time, the answered report's sensor and ``seq``, a hand-over's source region and
number). It also watches the
primary's outputs on the same keys: an output the primary sent is *settled* (dropped from the
withheld ones, or, if the standby has not computed it yet, remembered so that it is dropped when
it is), and a picture of the same time is compared with the standby's own (``same`` /
``differ``, the largest state difference): what the standby would have said differently.

The primary holds the liveliness token ``alive/mtt-primary/<RID>/<instance>`` (``<instance>``:
when it claimed the token, then its Zenoh session id: :func:`claim_instance`). When it disappears (the
primary's process or host died: about 3 ms for a killed process, the lease for a frozen one),
the standby waits ``SETTLE_S`` (outputs the primary sent before dying, in flight on the same
links, arrive first), declares the token itself and publishes what it withheld and the primary
never sent (the answers, hand-overs and pictures that died with it, in the order it made them),
then every output from its next message on: its tracks and their ids continue. It never
publishes while a primary token exists; a standby that sees no primary token for
``START_GRACE_S`` after it started takes over too, and one whose query at the start finds none
after ``SETTLE_S`` (the primary died before it came up: :meth:`Standby.found_none`).

Two primaries at once (split brain: two standbys taking over at the same instant, or two
primaries started together, each before it saw the other's token, or a primary frozen past its
lease that wakes after its standby took over): each sees the other's token, and the one whose
claim is not the latest among the region's tokens steps down
(:meth:`Standby.yields`, :meth:`Standby.step_down`): it withdraws its token and becomes a hot
standby again, so exactly one keeps the region, the same one whichever saw the other first. Two
standbys ran the same centre on the same inputs, so what both published in between is the same
outputs twice (within a token's propagation, milliseconds on one network); a woken primary missed
the reports of its freeze, and the later claim keeps the region.

An output of a kind of which the primary sent a later one (:func:`place_of`) is not withheld: the
primary went past it. Withheld outputs older than ``WITHHELD_S`` are forgotten (the primary was alive long after
them, so it sent them, or they were lost between it and the standby).

A standby started after its primary had published (the launcher's restart of a dead centre) is
*cold*: the first picture of the primary it sees is not the first (``seq > 0``). It rebuilds its
central tracks from the reports it gets, under ids of its own, so it keeps its numbering ahead of
the primary's (:func:`next_after`: its next track id above every id of its scope the primary
showed or handed over, its next hand-over number above the primary's), and after a take-over no
id and no hand-over number is issued twice. An id or number from ``NUMBER_ROOM`` (2^62) on is refused
(the service's ``rejected_seq_jump``): no region issues one, and numbering after it would leave the
wire's integers.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Hashable, Iterable
from dataclasses import dataclass, field

import numpy as np

from fedtrack.services.base import QUEUE_SIZE
from fedtrack.wire import HandOver, Message, TrackPicture, TrackResets
from fedtrack.zsession import LOST_KEPT

SETTLE_S = 0.2  # after the primary's token went, before the standby takes over
START_GRACE_S = 2.0  # a standby that saw no primary for this long after it started takes over
WITHHELD_S = 10.0  # a withheld output (or a settled one not yet made) is forgotten after this long
# A cold standby numbers its tracks and hand-overs after those its primary's outputs show (next_after);
# an id or number from this on is refused: past it, the next one could leave the wire's integers (2^63),
# and a region issuing one id per track (of R regions) or one number per hand-over never gets there
NUMBER_ROOM = 2**62
# The primary's outputs the standby has not made yet (settled) are its lag behind the primary: at most one
# output per message its inbox holds (QUEUE_SIZE); more are a flood on the primary's keys, the oldest
# forgotten. Only a picture is kept whole, for the comparison, and only the latest PICTURES_SETTLED (a
# standby catching up is a picture or two behind): every output was kept whole for WITHHELD_S, and 200
# forged answers of 2,048 tracks on its primary's keys were 81 MB held
SETTLED_MAX = QUEUE_SIZE
PICTURES_SETTLED = 4
# A token whose holder published nothing of the region for this long, while the standby made an answer or a
# picture this long ago (data was coming), serves nobody: a forged token (any ``fusion`` identity may
# declare one), or a primary whose worker is stuck while its session lives. More than twice the trackers'
# reset timeout (2 s: they go on without the region after it), and under WITHHELD_S (the answer still held)
SILENT_S = 5.0
# A region's centre tokens followed (``alive/mtt-region/<rid>/*`` by ``serve picture``; its primary tokens
# ``alive/mtt-primary/<rid>/*`` by its standby and the launcher): its primary and its standby, each restarted at
# most MAX_RESTARTS (3) times by the launcher, a killed one's token standing until its lease ends, hold at most
# 2 x (1 + 3) = 8 at once; LOST_KEPT (64) leaves room for standbys an operator adds. More come from a flood (any
# ``fusion`` identity may declare them): not followed, counted ``tokens_ignored``
CENTRE_TOKENS_KEPT = LOST_KEPT
# The primary tokens' changes a centre queues between two of its ticks (its Zenoh thread's, read by its worker):
# each token it may follow appearing and going within one tick, 2 x CENTRE_TOKENS_KEPT (a centre claims a new
# instance each time, so a genuine token appears and goes once). More are a flood between two ticks: the newest
# dropped, counted ``tokens_dropped`` (a genuine primary's going lost among them is still found by SILENT_S)
PRIMARY_CHANGES_KEPT = 2 * CENTRE_TOKENS_KEPT


def claim_instance(session: str, now_ns: int, after: str = "") -> str:
    """The last chunk of a primary token claimed at ``now_ns`` (wall clock) by Zenoh session ``session``:
    the claim's time first (20 digits), so that of two primaries the later claim sorts last and keeps
    the scope (:meth:`Standby.yields`). The earlier one may be a primary frozen past its lease (its
    session, woken, declares its token again) that missed every report since: with the session ids'
    order alone it kept the region as often as not, its tracks as they were before the freeze (7 of a
    region's confirmed tracks gone from the pictures after a 12 s SIGSTOP). The claim's time is at
    least 1 ns after that of ``after``, the latest claim this centre has seen (:attr:`Standby.latest`): a
    take-over is later than the primary it replaces whatever the wall clock did (stepped back 30 s
    before a 12 s freeze of the primary, the standby's claim sorted first, and it stepped down when the
    stale primary woke: 24 messages rejected); a claim of 20 nines (which only a forger makes) is not
    followed past the 20 digits."""
    before = claimed_ns(after)
    ns = now_ns if before is None else max(now_ns, before + 1)
    return f"{ns if ns < 10**20 else now_ns:020d}.{session}"


def claimed_ns(instance: str) -> int | None:
    """The claim time of a primary token's ``instance`` (:func:`claim_instance`), None for a chunk of
    another form (a token anyone else declared)."""
    head = instance[:20]
    if len(head) == 20 and head.isascii() and head.isdigit() and instance[20:21] in ("", "."):
        return int(head)
    return None


def output_of(msg: Message) -> Hashable:
    """An output's identity, the same for the primary's and the standby's copy of it."""
    if isinstance(msg, TrackResets):
        return ("resets", msg.sensor, msg.seq)
    if isinstance(msg, HandOver):
        return ("handover", msg.source, msg.serial)
    if isinstance(msg, TrackPicture):  # by time: the clocks' grid is k period, also for a standby started late
        return ("picture", msg.t, msg.closing)
    raise TypeError(f"a centre does not publish {type(msg).__name__}")


def place_of(msg: Message) -> tuple[Hashable, float] | None:
    """An output's kind and its place in the kind's order, in which the primary sends them: a picture's
    time, an answer's report number (per sensor), a hand-over's number (per sending region); None for a
    closing record. A standby that made an output its primary has gone past (:meth:`Standby.hold`) is
    behind: a primary woken from a freeze, stepped down, runs through the reports queued before it; it
    kept every such output (the primary's own had been forgotten after ``WITHHELD_S``) and published them
    at its take-over: 24 pictures of times merged long before and 15 answers to reports the trackers had
    left, all refused (live, 2 x 2 regions: x0y0's primary frozen 12 s, then its standby killed)."""
    if isinstance(msg, TrackResets):
        return ("resets", msg.sensor), msg.seq
    if isinstance(msg, HandOver):
        return ("handover", msg.source), msg.serial
    if isinstance(msg, TrackPicture) and not msg.closing:
        return ("picture",), msg.t
    return None


def behind(msg: Message, place: tuple[Hashable, float]) -> bool:
    """Whether ``msg`` is of ``place``'s kind and not after it (:func:`place_of`)."""
    mine = place_of(msg)
    return mine is not None and mine[0] == place[0] and mine[1] <= place[1]


def numbers_of(msg: Message) -> list[int]:
    """The track ids and hand-over numbers an output shows (what a cold standby numbers after)."""
    if isinstance(msg, TrackPicture):
        return list(msg.ids)
    if isinstance(msg, HandOver):
        return [msg.id, msg.serial]
    return []


def next_after(current: int, step: int, seen: Iterable[int]) -> int:
    """``current``, or, if an id of ``seen`` in its sequence (``current`` modulo ``step``) is not below
    it, the next value of that sequence after the largest such id."""
    mine = [i for i in seen if i % step == current % step and i >= current]
    return max(mine) + step if mine else current


def picture_difference(mine: TrackPicture, theirs: TrackPicture) -> float | None:
    """The largest state difference between two pictures of the same tracks (None: other ids)."""
    if mine.ids != theirs.ids:
        return None
    return float(np.max(np.abs(mine.x - theirs.x))) if mine.ids else 0.0


@dataclass
class Standby:
    """The standby's side of one region's failover (see the module docstring); times are
    monotonic seconds, given by the caller."""

    region: str
    started: float
    instance: str = ""  # the last chunk of this centre's token while it claims one (claim_instance)
    latest: str = ""  # the latest instance whose token this centre saw (claim_instance's ``after``)
    primary: bool = False
    holders: set[str] = field(default_factory=set)  # the instances whose primary token exists, this one's aside
    since: dict[str, float] = field(default_factory=dict)  # when each holder's token appeared
    silent: set[str] = field(default_factory=set)  # of them, those that stood while nothing was published (SILENT_S)
    absent_since: float | None = None  # when the token was last seen going (or the start)
    fresh: float = 0.0  # the start, or when this centre's link to its router came back: START_GRACE_S from then
    cut: bool = False  # this centre's link to its router is gone (every token went with it): no take-over
    heard: float = 0.0  # when an output of the primary last arrived (or the start, or this one stepped down)
    held: OrderedDict[Hashable, tuple[float, str, Message]] = field(default_factory=OrderedDict)  # (made, key, msg)
    # (seen, "", a picture or None): the primary's outputs not made here yet (SETTLED_MAX, PICTURES_SETTLED)
    settled: OrderedDict[Hashable, tuple[float, str, Message | None]] = field(default_factory=OrderedDict)
    past: dict[Hashable, float] = field(default_factory=dict)  # per kind, the latest place the primary sent (place_of)
    cold: bool | None = None  # started after the primary had published (None: no picture of it seen yet)
    same: int = 0  # pictures equal to the primary's (ids and states)
    differ: int = 0  # pictures with other ids or states
    max_difference: float = 0.0  # largest state difference among the pictures with the same ids
    ignored: int = 0  # primary tokens not followed: beyond CENTRE_TOKENS_KEPT holders

    def __post_init__(self) -> None:
        self.absent_since = self.heard = self.fresh = self.started

    @property
    def present(self) -> bool:
        """Another instance's primary token exists (liveliness), not one known to serve nobody (``silent``)."""
        return bool(self.holders - self.silent)

    def token(self, alive: bool, now: float, instance: str = "") -> None:
        """Instance ``instance``'s primary token appeared (``alive``) or went (this one's own is ignored;
        unnamed: another's). A token that would be one more than ``CENTRE_TOKENS_KEPT`` holders is not followed
        (counted ``ignored``), nor is its going: :attr:`present` copies the holders at each token, and 20,000
        forged tokens cost 2.6 s of CPU (``tests/test_hostile_regions.py``)."""
        if instance and instance == self.instance:
            return
        if instance not in self.holders and len(self.holders) >= CENTRE_TOKENS_KEPT:
            self.ignored += int(alive)
            return
        if alive:
            self.holders.add(instance)
            self.since.setdefault(instance, now)
            if claimed_ns(instance) is not None:
                self.latest = max(self.latest, instance)
        else:
            self.holders.discard(instance)
            self.since.pop(instance, None)
            self.silent.discard(instance)  # a token declared again is judged afresh
        self.absent_since = None if self.present else now

    def found_none(self, now: float) -> None:
        """A query at the start found no primary token (the primary died before this standby came up,
        as when the launcher restarts a killed centre as a standby while its twin dies too): take over
        after ``SETTLE_S``, not ``START_GRACE_S``, unless a token appears meanwhile. The grace waited
        for tokens that the query has already answered for: it left a region whose primary and standby
        were both killed uncovered 2 s longer (4.1 scans of 1.3 s at 2x, instead of 1.1)."""
        if not self.holders and self.absent_since == self.fresh:
            self.absent_since = max(now, self.fresh + 1e-9)  # not the start's any more: SETTLE_S from now

    def due(self, now: float) -> bool:
        """Whether to take over now: no primary token for ``SETTLE_S`` (``START_GRACE_S`` when
        none was ever seen since the start); or tokens stand, each for ``SILENT_S`` at least, but
        nothing of the primary arrived for as long while this standby made an answer or a picture that
        long ago (not a hand-over: a cold standby numbers its own) (:meth:`take_over` then marks their
        holders ``silent``)."""
        if self.primary or self.cut:
            return False
        if self.present:
            ago = now - SILENT_S
            return (self.heard <= ago and all(self.since[i] <= ago for i in self.holders - self.silent)
                    and any(made <= ago and output[0] != "handover" for output, (made, _, _) in self.held.items()))
        if self.absent_since is None:
            return False
        wait = START_GRACE_S if self.absent_since == self.fresh else SETTLE_S
        return now - self.absent_since >= wait

    def link(self, up: bool, now: float) -> None:
        """This centre's link to its router went (the last router token gone: every other token went with
        it, which says nothing of the primary) or came back. Cut, it never takes over: before, a killed
        router made every standby take over and every primary step down when it was back (4 failovers
        of a 2 x 2 run, each region's tracks moved to a standby's). Back, the primary's token comes
        again within milliseconds; one that has not after ``START_GRACE_S`` died meanwhile."""
        self.cut = not up
        if up and not self.present:
            self.absent_since = self.fresh = now

    def yields(self) -> bool:
        """Whether this primary must step down: another primary's claim is later (split brain; instances
        sort by their claim, :func:`claim_instance`), one not known to serve nobody (``silent``)."""
        return self.primary and any(other > self.instance for other in self.holders - self.silent)

    def step_down(self, now: float) -> None:
        """Become a hot standby again (after :meth:`yields`): withhold from now on."""
        self.primary = False
        self.heard = now

    def heard_remote(self, now: float) -> None:
        """As the primary: an output of another session arrived on this region's keys. While every
        other token is ``silent`` it is theirs: they serve after all (a primary frozen past
        ``SILENT_S`` and woken), and the claims' order decides again (:meth:`yields`)."""
        if self.holders and self.holders <= self.silent:
            self.silent.clear()

    def hold(self, key: str, msg: Message, now: float) -> None:
        """An output the standby made for ``key``: withheld, unless the primary sent it already."""
        self._forget(now)
        output = output_of(msg)
        sent = self.settled.pop(output, None)
        if sent is not None:
            if sent[2] is not None:
                self._compare(msg, sent[2])
            return
        place = place_of(msg)
        if place is not None and behind(msg, (place[0], self.past.get(place[0], -math.inf))):
            return  # the primary has sent a later one of its kind: this one it sent (or lost) long ago
        self.held[output] = (now, key, msg)

    def sent(self, msg: Message, now: float) -> None:
        """An output the primary sent: settled."""
        self.heard = now
        if self.cold is None and isinstance(msg, TrackPicture):
            self.cold = msg.seq > 0
        self._forget(now)
        output = output_of(msg)
        place = place_of(msg)
        if place is not None:
            self.past[place[0]] = max(self.past.pop(place[0], -math.inf), place[1])  # the latest kind last
            while len(self.past) > SETTLED_MAX:  # one per sensor and region: more are a flood, the oldest forgotten
                del self.past[next(iter(self.past))]
            for gone in [k for k, (_, _, m) in self.held.items() if k != output and behind(m, place)]:
                del self.held[gone]  # made before this arrived, of a place the primary has gone past
        mine = self.held.pop(output, None)
        if mine is not None:
            self._compare(mine[2], msg)
            return
        self.settled[output] = (now, "", msg if isinstance(msg, TrackPicture) else None)
        while len(self.settled) > SETTLED_MAX:
            self.settled.popitem(last=False)
        if isinstance(msg, TrackPicture):  # the older pictures beyond the latest PICTURES_SETTLED: not compared
            kept = [k for k, (_, _, m) in self.settled.items() if m is not None]
            for k in kept[:-PICTURES_SETTLED]:
                self.settled[k] = (*self.settled[k][:2], None)

    def take_over(self) -> list[tuple[str, Message]]:
        """Become the primary; returns the withheld outputs the primary never sent (key, message), in order.
        The tokens still standing (:meth:`due`'s second case) serve nobody: ``silent`` from now on."""
        self.primary = True
        self.silent |= self.holders
        out = [(key, msg) for _, key, msg in self.held.values()]
        self.held.clear()
        self.settled.clear()
        return out

    def _compare(self, mine: Message, theirs: Message) -> None:
        if not isinstance(mine, TrackPicture) or not isinstance(theirs, TrackPicture):
            return
        diff = picture_difference(mine, theirs)
        if diff == 0.0:
            self.same += 1
        else:
            self.differ += 1
        if diff is not None:
            self.max_difference = max(self.max_difference, diff)

    def _forget(self, now: float) -> None:
        for table in (self.held, self.settled):
            while table and now - next(iter(table.values()))[0] > WITHHELD_S:
                table.popitem(last=False)
