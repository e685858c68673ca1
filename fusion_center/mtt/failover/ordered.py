"""A warm standby's inputs taken in its primary's order (:class:`PrimaryOrder`).

Two centres subscribed to the same keys get each sender's messages in order, but the sub-reports of
several trackers and the hand-overs of several regions interleave as the router delivers them to
each, so a standby that takes them in its own arrival order fuses them in another order than its
primary under load, and its state differs (``standby_differ``: 12 of 24 pictures of an untouched
region in ``tests/test_region_failover.py``'s run, 43 of 44 of one region of a loaded 4 x 4 grid).
After a take-over the live pictures then continued from that state while the replay of the recording
(the primary's order, then the standby's) continued from the primary's. So a warm standby (started
with its primary: the first picture of it that it sees is its first) holds its inputs until a picture
of its primary lists them, and takes them in the order listed (its fused lists: sub-reports,
hand-overs taken, departures); at its take-over it takes what its primary listed and it holds, then
the rest in arrival order, which its own pictures list for the replay. Its state at the take-over is
then the primary's at its last picture, and the replay of the recording equals the live pictures.
"""

from __future__ import annotations

from collections import Counter, OrderedDict, deque
from collections.abc import Hashable
from dataclasses import dataclass, field

from fedtrack.local_filters.mtt.service import RESET_TIMEOUT_S
from fedtrack.wire import HandOver, TrackPicture, TrackReport

# A listed input that has not come after this long is passed over (counted ``order_skipped``): the
# primary's picture comes after the inputs it lists, on the same router; one that far behind is lost
# to this standby. The trackers' reset timeout: they go on without a region's answer after it anyway.
ORDER_WAIT_S = RESET_TIMEOUT_S


NO_INPUT = ("left", "began")  # entries that name no input: a departure, the primary's start afresh


def entries_listed(msg: TrackPicture) -> list[Hashable]:
    """The inputs a picture's fused lists name, in its centre's order: ``("report", sensor, seq)``,
    ``("handover", source, serial)``, ``("left", sensor)``, and the primary's start afresh, ``("began", region,
    first id, first hand-over number)`` (a restart is its report's, not listed)."""
    left, handovers, restarted = set(msg.left), set(msg.handovers), set(msg.restarted)
    began = dict(zip(msg.began, msg.began_serials))
    out: list[Hashable] = []
    for i, (name, seq) in enumerate(zip(msg.fused_sensors, msg.fused_seqs)):
        if i in restarted:
            continue
        out.append(("began", name, seq, began[i]) if i in began else ("left", name) if i in left
                   else ("handover", name, seq) if i in handovers else ("report", name, seq))
    return out


def entry_of(msg: TrackReport | HandOver) -> Hashable:
    """The entry a picture names an input by (:func:`entries_listed`)."""
    if isinstance(msg, HandOver):
        return ("handover", msg.source, msg.serial)
    return ("report", msg.sensor, msg.seq)


Item = tuple[Hashable, TrackReport | HandOver | None]


@dataclass
class PrimaryOrder:
    """The inputs a warm standby holds, and its primary's order of them still to take; times are
    monotonic seconds given by the caller."""

    limit: int  # inputs held at most (the inbox's bound): beyond, the oldest is taken in arrival order
    # entry -> (input, when it came), in arrival order
    held: OrderedDict[Hashable, tuple[TrackReport | HandOver, float]] = field(default_factory=OrderedDict)
    script: deque[tuple[Hashable, float]] = field(default_factory=deque)  # listed (and when), not taken yet
    waiting: Counter[Hashable] = field(default_factory=Counter)  # the entries of ``script``, counted
    skipped: int = 0
    # warm: it gets every input its primary's first picture lists (within ORDER_WAIT_S of it), so it has
    # seen all its primary fused; cold (False): it started later; None: no picture of the primary yet, or
    # the first one's inputs not all here yet (``missing``)
    warm: bool | None = None
    missing: set[Hashable] = field(default_factory=set)

    def arrived(self, msg: TrackReport | HandOver, now: float) -> list[Item]:
        """Hold ``msg`` (a second copy of one held is dropped: the admission told it apart); returns
        the oldest inputs beyond ``limit``, to be taken now in arrival order."""
        entry = entry_of(msg)
        self.held.setdefault(entry, (msg, now))
        self.missing.discard(entry)
        if self.warm is None and self.script and not self.missing:
            self.warm = True
        over: list[Item] = []
        while len(self.held) > self.limit:
            gone, (old, _) = self.held.popitem(last=False)
            over.append((gone, old))
        return over

    def listed(self, msg: TrackPicture, now: float) -> None:
        """A picture of the primary: its inputs are taken in its order. The first decides whether this
        standby is warm: it holds (or gets within ``ORDER_WAIT_S``) every input the picture lists; one
        that lists none is its primary's first if numbered 0 (else this standby started later)."""
        entries = entries_listed(msg)
        if self.warm is None and not self.script:
            inputs = [e for e in entries if e[0] not in NO_INPUT]
            self.missing = {e for e in inputs if e not in self.held}
            self.warm = (msg.seq == 0) if not inputs else True if not self.missing else None
        if self.warm is not False:
            self.script.extend((e, now) for e in entries)
            self.waiting.update(entries)

    def due(self, now: float) -> tuple[list[Item], list[Item]]:
        """The listed entries to take now, in order, each with its input (None for a departure or a start); one
        whose input has not come ``ORDER_WAIT_S`` after it was listed is passed over (``skipped``); of
        the first picture, that makes this standby cold (``warm`` False). And the inputs held that long
        that no picture listed (its primary refused them, or published no picture meanwhile: a stuck
        or silent one), to be taken in arrival order."""
        listed: list[Item] = []
        if self.warm is None and self.script and now - self.script[0][1] >= ORDER_WAIT_S:
            self.warm = False
        while self.warm and self.script:
            head, since = self.script[0]
            if head[0] not in NO_INPUT and head not in self.held:
                if now - since < ORDER_WAIT_S:
                    break
                self.skipped += 1
                self._pop()
                continue
            self._pop()
            listed.append((head, self.held.pop(head)[0] if head in self.held else None))
        stale = []
        for e, (_, came) in self.held.items():  # in arrival order: the old ones first
            if now - came < ORDER_WAIT_S:
                break
            if not self.waiting[e]:
                stale.append(e)
        return listed, [(e, self.held.pop(e)[0]) for e in stale]

    def _pop(self) -> None:
        """The script's head taken or passed over. The entries still listed are counted as they come and go
        (``waiting``): building their set on each call made an input's cost grow with the script, and a
        primary's 600 pictures listing 2,000 inputs that never came, 500 a second, took 20.7 s of CPU (1.7 s now)."""
        head, _ = self.script.popleft()
        self.waiting[head] -= 1
        if not self.waiting[head]:
            del self.waiting[head]

    def release(self) -> tuple[list[Item], list[Item]]:
        """At a take-over (or once cold): the listed entries whose inputs are held, in order, and every
        other input held, in arrival order; nothing is held afterwards."""
        listed = [(e, self.held.pop(e)[0] if e in self.held else None) for e, _ in self.script
                  if e[0] in NO_INPUT or e in self.held]
        rest: list[Item] = [(e, msg) for e, (msg, _) in self.held.items()]
        self.held.clear()
        self.script.clear()
        self.waiting.clear()
        self.missing.clear()
        return listed, rest
