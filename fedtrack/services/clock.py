"""A tracker's clock against scans far after its last one (``[deployment] max_time_jump_s``).

Predicting over such a gap would leave a covariance meaningless, so the scan is rejected
(``time_jump``); :class:`ClockJump` lets the data resume after a real pause (or a clock set forward)
by starting the tracker again, as ``replay`` does (docs/wire.md, "Rejections").
"""

from __future__ import annotations

from typing import Iterable

from fedtrack.services.rejections import Rejected


def check_time_jump(last: float | None, t: float, bound: float) -> None:
    """Rejected("time_jump") when ``t`` is more than ``bound`` seconds after ``last``: predicting
    over such a gap would leave a tracker's covariance meaningless (a forged or broken clock)."""
    if last is not None and t - last > bound:
        raise time_jump(last, t, bound)


def time_jump(last: float, t: float, bound: float) -> Rejected:
    """The rejection of a scan at ``t``, more than ``bound`` s after the last one (``last``)."""
    return Rejected("time_jump", f"t = {t} is {t - last:.6g} s after the last scan (max_time_jump_s = {bound:g})")


class ClockJump:
    """:func:`check_time_jump` that lets the data resume after a pause: a scan (or estimate) more
    than ``bound`` s after the tracker's time is rejected (``time_jump``), unless the one of its
    sensor rejected so just before it, and one of every other sensor ``witnesses`` names (the
    fusion centre's live sensors: one sensor alone cannot move the centre's clock), have lower
    numbers and earlier times within ``bound`` of it (the data goes on there: sensors that paused,
    or whose clocks were set forward); then the tracker starts again from it, as ``replay`` does.
    Before, every scan after such a pause was rejected, for good. Not part of a service's
    checkpointed state: a rejection must remember it."""

    def __init__(self, bound: float) -> None:
        self.bound = bound
        self.first: dict[str, tuple[int, float]] = {}  # per sensor, (seq, t) of its scan rejected last so

    def restart(self, last: float | None, sensor: str, seq: int, t: float, witnesses: Iterable[str] = ()) -> bool:
        """True when the tracker (at ``last``) is to start again at ``sensor``'s scan ``seq`` at ``t``;
        False when ``t`` is within the bound; Rejected("time_jump") otherwise."""
        if last is None or t - last <= self.bound:
            self.first.pop(sensor, None)
            return False
        before = {s: self.first.get(s) for s in {sensor, *witnesses}}
        self.first[sensor] = (seq, t)
        if all(f is not None and f[0] < seq and f[1] < t <= f[1] + self.bound for f in before.values()):
            self.first = {}
            return True
        raise time_jump(last, t, self.bound)
