"""When a live centre counts a sensor as gone for want of its messages (docs/multitarget.md, "Joining
and leaving").

A sensor's tracker reports every scan, empty ones too, over a reliable link, so a live sensor is
never silent for long; but how long is long is the sensor's own business: a position sensor at 1
Hz, a surveillance radar turning in 12 s, any of them slowed down by a launch's ``speed``. A
fixed bound drops a slow sensor between every two of its scans (it rejoins at the next: each time
its local tracks leave their central tracks and the others' sharing factors change). So the bound
follows the sensor: its silence must exceed both ``[mtt] leave_after_s`` and ``LEAVE_INTERVALS``
times its usual interval between arrivals (:func:`usual_interval` of its last ``INTERVALS_KEPT``;
a late scan arrives up to two of its periods after its time, so two arrivals of a live sensor are
at most three intervals apart: three periods of silence can be a late scan, four cannot). A sensor with
no interval yet (one message so far) may be silent for ``LEAVE_INTERVALS`` times the longer of
``leave_after_s`` and the others' longest usual interval (which carries a slowed deployment's
pace): a sensor whose period is up to four times that is not dropped before its second message.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field

LEAVE_INTERVALS = 4
# the median of 8 intervals holds while at most 3 are off: a late scan puts one long and one short
# interval among them, so up to one late scan in 8 (the simulator's --late is 0.2: 1.6 in 8)
INTERVALS_KEPT = 8


@dataclass
class Silence:
    """The sensors heard from (wall-clock, monotonic seconds) and their intervals between arrivals."""

    floor_s: float  # ``[mtt] leave_after_s``
    last: dict[str, float] = field(default_factory=dict)  # live sensor -> time of its last message
    previous: dict[str, float] = field(default_factory=dict)  # sensor -> its last message, kept after it left
    gaps: dict[str, deque[float]] = field(default_factory=dict)  # sensor -> its last intervals between messages

    def heard(self, sensor: str, now: float) -> None:
        """A message of ``sensor`` arrived at ``now``."""
        if sensor in self.previous:
            self.gaps.setdefault(sensor, deque(maxlen=INTERVALS_KEPT)).append(now - self.previous[sensor])
        self.previous[sensor] = self.last[sensor] = now

    def bound_s(self, sensor: str) -> float:
        """How long ``sensor`` may be silent and still count as live (module docstring)."""
        return self._bound(sensor, self._usual())

    def silent(self, now: float) -> list[str]:
        """The live sensors silent beyond their bound at ``now`` (every tick: the usual intervals
        are taken once)."""
        usual = self._usual()
        return [s for s, heard in self.last.items() if now - heard > self._bound(s, usual)]

    def _usual(self) -> dict[str, float]:
        """Each sensor's usual interval between messages (:func:`usual_interval` of its last ones)."""
        return usual_intervals(self.gaps)

    def _bound(self, sensor: str, usual: dict[str, float]) -> float:
        return silence_bound(sensor, usual, self.floor_s)

    def left(self, sensor: str) -> None:
        """``sensor`` is no longer live (silent, or its liveliness token went); its intervals stay."""
        del self.last[sensor]


def usual_interval(gaps: Iterable[float]) -> float:
    """A sensor's usual interval between messages: the one in which the middle of the time its
    intervals ``gaps`` span falls (a time-weighted median), the longest left out (one outage or late
    scan does not move it). Steady messages: their period, as the plain median. Bursts (up to 4
    messages close together, then a pause, within the ``INTERVALS_KEPT`` kept): the pause, which holds
    most of the time; the plain median was the interval within a burst, so a sensor pausing longer
    than ``leave_after_s`` between its bursts was dropped at every pause (before untuned5)."""
    kept = sorted(gaps)
    kept = kept[:-1] or kept
    half, spanned = sum(kept) / 2.0, 0.0
    for gap in kept:
        spanned += gap
        if spanned >= half:
            return gap
    return kept[-1]


def usual_intervals(gaps: dict[str, deque[float]]) -> dict[str, float]:
    """:func:`usual_interval` of every sensor with an interval."""
    return {s: usual_interval(g) for s, g in gaps.items() if g}


def silence_bound(sensor: str, usual: dict[str, float], floor_s: float) -> float:
    """How long ``sensor`` may be silent and still count as live, ``usual`` every sensor's usual
    interval and ``floor_s`` the least bound (module docstring)."""
    if sensor in usual:
        return max(floor_s, LEAVE_INTERVALS * usual[sensor])
    return LEAVE_INTERVALS * max([floor_s, *usual.values()])
