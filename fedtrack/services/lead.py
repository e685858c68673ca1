"""Scans stamped far ahead of the data wait for a witness before they move a tracker's clock.

A tracker's clock is its newest scan time: a scan up to ``max_lag`` before it is fused out of
sequence, an older one is late. So a single scan stamped far ahead (a forged message, a sensor
whose clock jumped) would make every other sensor's scans late until the data caught up with it,
and the picture clock would make a picture for every period in between: one message would stop
the tracking for as long as its lead.

**The rule** (:class:`LeadGuard`, in front of every tracker of scans and every track-to-track
centre, in the replay and the live services alike). A scan of sensor ``s`` *leads* when its time
is more than ``bound(s) = max(max_lag, LEAD_INTERVALS x usual(s))`` after the newest time taken,
``usual(s)`` being the median of ``s``'s last ``INTERVALS_KEPT`` intervals between the times of
its scans taken (a sensor without one yet: the longest of the others'; no sensor with one: no
bound, so the data's first interval is taken as it comes). A scan that does not lead is taken at
once (the guard is transparent to data without leads). A leading scan is held until

* a *witness* arrives: a scan that leads too, within ``bound`` of it, from another sensor, or a
  later one from the same sensor when it is the only live sensor the guard knows (a one-sensor
  tracker, or the others left), however far after it: a lone sensor whose usual interval was
  made tiny (a burst of scans milliseconds apart) had each later scan, one real interval after the
  last, held and never witnessed, for good (before 2026-11-27; ``tests/test_hostile_trackers.py``).
  The held scans near the witness, or before it, are then taken in their arrival order, and the
  witness after them: the data resumed after a gap (every sensor's clock moved on together), and a
  held scan before the witness is behind the resumed data, not ahead of it (a sensor sending bursts
  of scans a few milliseconds apart, then nothing for longer than ``max_lag``, while the others
  were silent: its burst was dropped as not near the witness before untuned5);
* or a scan that does not lead arrives (the rest of the data is still at the old time): the held
  scans after it are dropped, each counted in ``dropped`` (a forged or broken time); those before
  it are taken before it (behind the data: a bursty sensor's burst, led by its tiny usual interval,
  and passed by a slow sensor's scan within that sensor's wider bound; dropped before untuned5).

``LEAD_INTERVALS = 4``: a sensor's scan arrives up to two of its periods late (the simulator's
``--late``, docs/multitarget-formats.md), so its newest scan taken is at most three intervals
after its previous one, however its scans overtake each other; four cannot be lateness. At most
``HELD_MAX`` scans and ``HELD_BYTES`` are held (the oldest beyond them dropped, counted): a
deployment's sensors resume within a few scans of each other, and a flood of leading scans must
not grow a tracker.

**Corroboration** (``corroborate``: the multi-target centres, live and in the replay). The rule
above bounds one scan's lead over the newest time, not how fast one sensor moves that time on:
a sensor sending its scans one usual interval apart but faster than the data comes (a compromised
tracker counting ahead) made the centre's clock run away, every other sensor's scans late and
the pictures empty. So when at least ``CORROBORATORS`` other sensors are live, a scan that the
rule above gives is taken only if another sensor ``o`` has reached near its time: a scan of
``o`` taken, given or waiting at most ``reach(o) = max_lag + usual(o)`` before it (no sensor with an
interval yet: ``max_lag``; it was infinite, and a sensor's second scan 10^9 s ahead, once three
sensors had sent one each, moved the clock there). Else it
waits (bounded as the held scans, the oldest dropped, counted), and is taken, in time order with
what comes, once another sensor's data gets there or fewer other sensors are live. ``reach``:
``max_lag`` bounds how far a scan arrives behind the newest one (docs/multitarget.md, "Simulated
delays and max_lag"), so when a scan at ``t`` arrives every other sensor has one taken at least
``t - max_lag - usual(o)`` (its scans one interval apart, each within ``max_lag``): honest data
never waits. One liar among three or more sensors is outvoted; of two, nothing tells the racing
clock from the lagging one, and the rule is off.

**The start** (``start_gap``: ``serve picture``, ``[deployment] max_time_jump_s``). The rules above lead from
the newest time taken, so the first message of all is taken as it comes: a region's first picture stamped t =
-10^12 s, sent before any other, was merged alone as a picture of that time (before the redteam60 session).
With ``start_gap``, the first messages are held until one arrives within ``start_gap`` of a held one (another
sensor's, or another time of its own sensor: a repeat is no witness): the data's start is where two agree.
Those within ``start_gap`` of it are taken, in arrival order (as they came without the rule), and it after
them; those more than ``start_gap`` before it are dropped, counted in ``behind``; those after it in
``dropped``. ``start_gap`` is the deployment's bound on a plausible gap between two scans
(``max_time_jump_s``, 3,600 s: a tracker predicts over no longer), so honest data agrees at its second
message. One message cannot set the start; two of one identity that agree with each other, sent before any
honest one, still can (and a lone region's, at ``serve picture``); at ``serve mtt-centre`` and ``serve picture``
such a start is abandoned when two other sensors (regions) agree against it (:class:`SoleStart`, below).

**The start at a one-sensor tracker** (:class:`LoneStart`: ``serve local-filter`` (the radar one too, since the
redteam63 session: its first scan numbered 50 ahead left 0 of 39 estimates), ``imm``, ``hpda`` on scan numbers,
``mtt-local`` on times). A tracker of one sensor has no other sensor to witness its first scan, and holding
the first scan for the sensor's next one changes when a tracker answers (a report per scan at once). So the first
scan is taken as it comes, and abandoned when the data contradicts it: while it is the only scan taken, two later
scans each more than ``gap`` behind it (or, on times, after it), the second after the first within ``gap`` of it
(the sensor's data goes on there), make the tracker start again from them (``start_abandoned``): a scan numbered 50
ahead (or stamped 10^9 s ahead), sent first, made every honest scan after it ``late`` (one 10^12 s before,
``time_jump``), for good. ``gap``: for scan numbers ``LEAD_INTERVALS`` (a scan arrives at most two periods late, so
an honest one is never more than three numbers behind the newest: the rule above); for times ``[deployment]
max_time_jump_s`` (``start_gap``'s bound on a plausible gap). A scan taken after the first that does not contradict
it ends the rule: honest data never abandons its start (its second scan agrees). Two forged scans of the sensor that
agree with each other, sent right after its first honest one, still restart the tracker from them (as two set the
start above).

**The start of one sensor at a centre** (:class:`SoleStart`: ``serve mtt-centre`` where the start rule is on).
Two messages of one sensor that agree with each other (its own later message witnesses its first) set the start, and
so does one taken unwitnessed when ``start_wait_s`` ran out (below): a compromised peer sending first two messages
stamped 10^9 s ahead, or one more than ``start_wait_s`` before any honest message, made every honest message late
(before the redteam63 session). So while every message the centre took is of one sensor, a message more than
``gap`` (``max_time_jump_s``, ``start_gap``'s) before or after that sensor's times contradicts the start: it is held,
not processed (counted ``rejected_time_behind`` or ``rejected_time_lead``), and when a held one of another sensor
agrees with it within ``gap`` the centre abandons its start (its state as before its first message;
``start_abandoned``) and starts again from the held ones within ``gap`` of it, in arrival order, through the start
rule (they agree). Two sensors against one: one identity cannot abandon another's start, and an honest start is
abandoned only when two other sensors agree on a time more than ``max_time_jump_s`` from it, a gap no service
predicts over. A message of another sensor taken ends the rule, so honest data never meets it. At most HELD_MAX
messages and HELD_BYTES are held (the oldest dropped, counted as above). With two sensors, one of them the liar,
nothing tells the two apart and the first start stands.

``serve picture`` (since the redteam64 session) keeps one with regions for sensors, on two or more regions: a region's
identity sending first two pictures that agree, or one released alone after ``--wait``, at 10^9 s (or -10^12 s) left
0 of 12 merged pictures the clean run's; its state (what taking a picture changes) is put back as before its first
picture (docs/multitarget.md, "The start of one region at the merger").

``serve mtt-centre`` (each region centre too) uses it live where a witness can come: ``[mtt] sensors`` lists two
or more sensors or is ``"any"`` (one listed: the first message is taken as it comes). A sensor configured but not
running never witnesses, and a federated tracker waits for its first answer before it reports again, so the wait is
bounded in wall-clock time by ``start_wait_s = min([mtt] leave_after_s, RESET_TIMEOUT_S / 2)``: no longer than
the centre's own bound on a live sensor's silence (its silence rule; 5 s), and the answer to a held first report
reaches its tracker within the trackers' default ``--reset-timeout`` (2 s; the other half for the report's fusion
and the answer's way), so a tracker running alone goes on as the replay does. Then the held first messages are
taken as they came (:meth:`LeadGuard.open_start`, counted ``start_unwitnessed``): a forged first message sent
more than ``start_wait_s`` before any honest one still sets the start, as one of a lone sensor must (abandoned
when two other sensors agree against it: :class:`SoleStart`). Not used by
the scan trackers nor the replay, which takes the recorded order (docs/multitarget.md, "Scans stamped far
ahead": measured and left).
"""

from __future__ import annotations

import statistics
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Any, Generic, NamedTuple, Protocol, TypeVar

from fedtrack import wire

LEAD_INTERVALS = 4
# the median of 8 intervals holds while at most 3 are off (one late scan puts a long and a short one
# among them): the silence rule's choice (fedtrack.fusion_center.mtt.silence)
INTERVALS_KEPT = 8
# When the data resumes after a gap, every live sensor's first scan witnesses the others', so at most
# one scan per live sensor waits (a centre takes at most MAX_LIST_ITEMS live sensors; a lone sensor's
# waits for its next): more held scans are a flood. A held scan of 2,048 detections is 32 kB.
HELD_MAX = wire.MAX_LIST_ITEMS
# and at most one largest message's worth of bytes (a report joined from MAX_PARTS parts: the
# reassembly's own bound, services/reassembly.py): a flood of large leading reports cannot grow a service
HELD_BYTES = wire.MAX_PARTS * wire.MAX_PAYLOAD_BYTES
# other live sensors needed before a scan must be corroborated: with one other, a racing clock and a
# lagging one cannot be told apart
CORROBORATORS = 2

class Times(NamedTuple):
    """What :meth:`LeadGuard.took` changes (:meth:`LeadGuard.times`, :meth:`LeadGuard.restore`)."""

    newest: float | None
    last: dict[str, float]
    gaps: dict[str, deque[float]]
    usual: dict[str, float]
    live: set[str]
    lone: LoneStart[Any] | None


T = TypeVar("T")  # what is held: a scan or a message (or what a service keeps of it)


@dataclass
class LeadGuard(Generic[T]):
    """The newest time taken, each sensor's usual interval between its scans' times, and the
    leading scans held (module docstring)."""

    max_lag: float
    newest: float | None = None
    last: dict[str, float] = field(default_factory=dict)  # sensor -> time of its newest scan taken
    gaps: dict[str, deque[float]] = field(default_factory=dict)  # sensor -> its last intervals
    usual: dict[str, float] = field(default_factory=dict)  # sensor -> the median of its gaps
    live: set[str] = field(default_factory=set)  # sensors taken and not left
    held: list[tuple[str, float, T, int]] = field(default_factory=list)  # (sensor, t, item, bytes), arrival order
    dropped: int = 0  # held scans never witnessed (or beyond HELD_MAX): not taken
    corroborate: bool = False  # scans wait for another sensor's data near their time (module docstring)
    waiting: list[tuple[str, float, T, int]] = field(default_factory=list)  # not corroborated yet, arrival order
    start_gap: float | None = None  # the first scans wait until two agree within it (module docstring); None: not
    first: tuple[tuple[str, float, T, int], ...] = ()  # the scans held before the start, arrival order
    behind: int = 0  # first scans dropped as more than start_gap before the start
    unwitnessed: int = 0  # first scans taken unwitnessed when the start's wait ran out (open_start)
    lone: LoneStart[T] | None = None  # a one-sensor tracker's first scan, abandoned if contradicted (module docstring)

    def bound(self, sensor: str) -> float:
        """How far after the newest time a scan of ``sensor`` may be and still be taken at once."""
        if sensor in self.usual:
            return max(self.max_lag, LEAD_INTERVALS * self.usual[sensor])
        return max(self.max_lag, LEAD_INTERVALS * max(self.usual.values())) if self.usual else float("inf")

    def horizon(self) -> float:
        """The latest time any sensor's scan would be taken at once: the newest time taken plus the
        widest ``bound`` (a sensor without an interval of its own gets the longest; infinite before
        the first scan or interval)."""
        return float("inf") if self.newest is None else self.newest + self.bound("")

    def admit(self, sensor: str, t: float, item: T, size: int = 0) -> list[T]:
        """The items to take now, in order, on the arrival of ``item`` (``sensor``'s, at ``t``, of
        about ``size`` bytes): ``[item]`` when it does not lead; ``[]`` while it is held; the
        witnessed held items and ``item`` when it is a witness; with ``corroborate``, of those and
        the waiting ones, the corroborated, in time order. The caller reports each item it took
        with :meth:`took`."""
        started = self.start_gap is None or self.newest is not None
        given = self._witnessed(sensor, t, item, size) if started else self._start(sensor, t, item, size)
        if not self.corroborate or not started:  # the start's scans in arrival order, as they came before it
            return [g[2] for g in given]
        pool = self.waiting + given
        reached = {o: self.last[o] for o in self.live}
        for s, at, _, _ in pool:
            reached[s] = max(at, reached.get(s, at))
        taken = [p for p in pool if self._corroborated(p[0], p[1], reached)]
        self.waiting = [p for p in pool if not any(p is q for q in taken)]
        self.dropped += _bounded(self.waiting)
        return [p[2] for p in sorted(taken, key=lambda p: p[1])]

    def _witnessed(self, sensor: str, t: float, item: T, size: int) -> list[tuple[str, float, T, int]]:
        """The lead rule (module docstring): what to take now, as (sensor, t, item, bytes)."""
        arrived = (sensor, t, item, size)
        if self.newest is None or t - self.newest <= self.bound(sensor):
            # the data is still near the old time: the held scans after ``t`` led it and are dropped; those
            # before ``t`` (within this sensor's wider bound) are behind the data, not ahead of it
            behind = [h for h in self.held if h[1] < t]
            self.dropped += len(self.held) - len(behind)
            self.held.clear()
            return [*behind, arrived]
        lone = not (self.live - {sensor})

        def near(h: tuple[str, float, T, int]) -> bool:  # a lone sensor's later scan, however far: it moved on
            return abs(t - h[1]) <= self.bound(h[0]) or (lone and h[0] == sensor and t > h[1])

        if not any(near(h) and self._witnesses(sensor, t, h) for h in self.held):
            self.held.append(arrived)
            self.dropped += _bounded(self.held)
            return []
        # near the witness, or before it: the resumed data has passed a held scan's time (a sensor's scans
        # a gap of more than the bound apart, as a burst's after a long pause, led and are not ahead of it)
        taken = [h for h in self.held if near(h) or h[1] < t]
        self.dropped += len(self.held) - len(taken)
        self.held.clear()
        return [*taken, arrived]

    def _start(self, sensor: str, t: float, item: T, size: int) -> list[tuple[str, float, T, int]]:
        """The start rule (module docstring): ``[]`` until ``item`` agrees with a held first scan, then the held
        scans within ``start_gap`` of it, in arrival order, and it."""
        arrived, gap = (sensor, t, item, size), self.start_gap or 0.0
        if not any(abs(t - h[1]) <= gap and (h[0], h[1]) != (sensor, t) for h in self.first):
            held = [*self.first, arrived]
            self.dropped += _bounded(held)
            self.first = tuple(held)
            return []
        taken = [h for h in self.first if abs(t - h[1]) <= gap]
        self.behind += sum(h[1] < t - gap for h in self.first)
        self.dropped += sum(h[1] > t + gap for h in self.first)
        self.first = ()
        return [*taken, arrived]

    def open_start(self) -> list[T]:
        """The start's wait ran out (the service's bound, module docstring): the held first scans, taken as they
        came (arrival order, as without the rule), each counted in ``unwitnessed``; the start rule is off."""
        items = [h[2] for h in self.first]
        self.unwitnessed += len(items)
        self.first, self.start_gap = (), None
        return items

    def _corroborated(self, sensor: str, t: float, reached: dict[str, float]) -> bool:
        """Whether a scan of ``sensor`` at ``t`` may be taken: fewer than CORROBORATORS other
        sensors are live, or another sensor's data (``reached``: each sensor's newest time taken,
        given or waiting) is within its reach of ``t``."""
        if len(self.live - {sensor}) < CORROBORATORS:
            return True
        return any(at >= t - self.max_lag - self._usual(o) for o, at in reached.items() if o != sensor)

    def _usual(self, sensor: str) -> float:
        """``sensor``'s usual interval; without one, the longest of the others'; none known yet (the data's
        first interval): 0, so that a scan is corroborated by another sensor's within ``max_lag`` of it."""
        if sensor in self.usual:
            return self.usual[sensor]
        return max(self.usual.values()) if self.usual else 0.0

    def _witnesses(self, sensor: str, t: float, held: tuple[str, float, T, int]) -> bool:
        """Whether a leading scan of ``sensor`` at ``t`` witnesses ``held``: another sensor's, or
        a later scan of the same sensor when no other sensor is live (a repeat is no witness)."""
        return sensor != held[0] or (t > held[1] and not (self.live - {sensor}))

    def took(self, sensor: str, t: float) -> None:
        """A scan of ``sensor`` at ``t`` that :meth:`admit` gave was taken (its tracker handled it)."""
        if sensor in self.last and t > self.last[sensor]:
            gaps = self.gaps.setdefault(sensor, deque(maxlen=INTERVALS_KEPT))
            gaps.append(t - self.last[sensor])
            self.usual[sensor] = statistics.median(gaps)
        self.last[sensor] = max(t, self.last.get(sensor, t))
        self.newest = t if self.newest is None else max(self.newest, t)
        self.live.add(sensor)
        if self.lone is not None:
            self.lone.took(t)

    def end(self) -> int:
        """The data ended (a replay's input, a service stopping): the scans still held or waiting are
        dropped; returns how many."""
        n = len(self.held) + len(self.waiting) + len(self.first)
        self.dropped += n
        self.held.clear()
        self.waiting.clear()
        self.first = ()
        return n

    def times(self) -> Times:
        """A copy of what :meth:`took` changes, for :meth:`restore`."""
        return Times(self.newest, dict(self.last), {s: deque(g, maxlen=INTERVALS_KEPT) for s, g in self.gaps.items()},
                     dict(self.usual), set(self.live), None if self.lone is None else replace(self.lone))

    def restore(self, times: Times) -> None:
        """Forget the scans taken since :meth:`times` gave ``times`` (their handling failed)."""
        self.newest, self.last, self.gaps, self.usual, self.live, self.lone = times

    def leave(self, sensor: str) -> None:
        """``sensor`` left: it no longer keeps another sensor's lone scans from witnessing themselves."""
        self.live.discard(sensor)


def _bounded(items: list[tuple[str, float, T, int]]) -> int:
    """Drop the oldest of ``items`` beyond HELD_MAX items or HELD_BYTES; returns how many."""
    n = 0
    while len(items) > HELD_MAX or sum(i[3] for i in items) > HELD_BYTES:
        items.pop(0)
        n += 1
    return n


@dataclass
class LoneStart(Generic[T]):
    """The first scan a one-sensor tracker took, abandoned when two later scans contradict it (module docstring,
    "The start at a one-sensor tracker")."""

    gap: float  # a scan more than this behind the first contradicts it (a number, or a time)
    ahead: bool = False  # one more than gap ahead of it too (times: a tracker refuses it, time_jump)
    start: float | None = None  # the first scan's number (or time) while it is the only one taken
    taken: int = 0  # scans taken (the rule is on while one is)
    against: tuple[float, T] | None = None  # the last scan that contradicted it: its number (or time), itself

    def took(self, at: float) -> None:
        """A scan at ``at`` (number or time) was taken."""
        self.taken += 1
        self.start = at if self.taken == 1 else None
        self.against = None

    def contradicts(self, at: float) -> bool:
        """Whether a scan at ``at`` is more than ``gap`` behind (or, ``ahead``, after) the first while it is the only
        one taken. The tracker refuses it without raising (a raising handler would put the guard back)."""
        return self.start is not None and (at < self.start - self.gap or (self.ahead and at > self.start + self.gap))

    def contradicted(self, at: float, item: T) -> list[T]:
        """``item`` (at ``at``) arrived: ``[]``, or, when it contradicts the first and agrees with the scan that
        contradicted it before (the second later, within ``gap``), both, in order: the tracker
        abandons its first scan and starts again from them."""
        if not self.contradicts(at):
            return []
        prior, self.against = self.against, (at, item)
        return [prior[1], item] if prior is not None and prior[0] < at <= prior[0] + self.gap else []


@dataclass
class SoleStart(Generic[T]):
    """A centre's start while every message it took is of one sensor, abandoned when two other sensors' messages
    agree against it (module docstring, "The start of one sensor at a centre")."""

    gap: float  # a message more than this before or after the start's times contradicts it
    sensor: str | None = None  # the one sensor whose messages were taken; None: none yet
    span: tuple[float, float] | None = None  # the earliest and the latest time taken of it
    ended: bool = False  # a message of another sensor was taken: the start is witnessed
    against: list[tuple[str, float, T, int]] = field(default_factory=list)  # (sensor, t, item, bytes), arrival order

    def took(self, sensor: str, t: float) -> None:
        """A message of ``sensor`` at ``t`` was taken."""
        if self.ended:
            return
        if self.sensor is not None and sensor != self.sensor:
            self.ended, self.against = True, []
            return
        self.sensor, self.span = sensor, (t, t) if self.span is None else (min(self.span[0], t), max(self.span[1], t))

    def contradicts(self, t: float) -> bool:
        """Whether a message at ``t`` is more than ``gap`` before or after the times of the start's sensor, every
        message taken being of it."""
        return not self.ended and self.span is not None and not self.span[0] - self.gap <= t <= self.span[1] + self.gap

    def contradicted(self, sensor: str, t: float, item: T, size: int = 0) -> list[T]:
        """A message that contradicts the start arrived: ``[]`` while held (the oldest dropped beyond HELD_MAX or
        HELD_BYTES), or, when one held of another sensor agrees with it within ``gap``, the held ones within
        ``gap`` of it, in arrival order, and it: the centre abandons its start and starts again from them."""
        if any(h[0] != sensor and abs(h[1] - t) <= self.gap for h in self.against):
            return [h[2] for h in self.against if abs(h[1] - t) <= self.gap] + [item]
        self.against.append((sensor, t, item, size))
        _bounded(self.against)  # (each counted as it came)
        return []


class Numbered(Protocol):
    """A message of a numbered stream (its scan number ``seq``)."""

    seq: int


N = TypeVar("N", bound=Numbered)


@dataclass
class NumberedLeadGuard(Generic[N]):
    """A :class:`LeadGuard` on the times of a numbered stream (a single-target service's scans, the
    fusion centre's estimates: scan numbers in step with time) and one on its scan numbers, each
    number taken as a time: a scan numbered more than LEAD_INTERVALS of its usual steps (one) past
    the newest taken waits for a witness too, so that one message numbered far ahead (with a
    plausible time) cannot make every later scan late in a service that takes scans in number
    order. A scan passes the time guard, then the number guard."""

    time: LeadGuard[N] = field(default_factory=lambda: LeadGuard(max_lag=0.0))
    number: LeadGuard[N] = field(default_factory=lambda: LeadGuard(max_lag=0.0))

    @classmethod
    def one_sensor(cls) -> NumberedLeadGuard[N]:
        """The guard of a one-sensor tracker (``local-filter``, 2-D and radar, ``imm``, ``hpda``): its number guard
        keeps a :class:`LoneStart` on the scan numbers (module docstring); the fusion centre's, of several sensors,
        none."""
        return cls(number=LeadGuard(max_lag=0.0, lone=LoneStart(LEAD_INTERVALS)))

    @property
    def dropped(self) -> int:
        return self.time.dropped + self.number.dropped

    @property
    def behind(self) -> int:
        return self.time.behind + self.number.behind

    @property
    def newest(self) -> float | None:
        return self.time.newest

    def admit(self, sensor: str, t: float, item: N, size: int = 0) -> list[N]:
        """As :meth:`LeadGuard.admit`; what the time guard gives goes through the number guard."""
        return [out for released in self.time.admit(sensor, t, item, size)
                for out in self.number.admit(sensor, float(released.seq), released, size)]

    def took(self, sensor: str, t: float, seq: int) -> None:
        self.time.took(sensor, t)
        self.number.took(sensor, float(seq))

    def contradicts(self, msg: N) -> bool:
        """:meth:`LoneStart.contradicts` on the scan numbers."""
        return self.number.lone is not None and self.number.lone.contradicts(float(msg.seq))

    def contradicted(self, msg: N) -> list[N]:
        """:meth:`LoneStart.contradicted` on the scan numbers: the scans to start again from, or ``[]``."""
        return self.number.lone.contradicted(float(msg.seq), msg) if self.number.lone is not None else []

    def end(self) -> int:
        return self.time.end() + self.number.end()

    def times(self) -> tuple[Times, Times]:
        return self.time.times(), self.number.times()

    def restore(self, times: tuple[Times, Times]) -> None:
        self.time.restore(times[0])
        self.number.restore(times[1])

    def leave(self, sensor: str) -> None:
        self.time.leave(sensor)
        self.number.leave(sensor)
