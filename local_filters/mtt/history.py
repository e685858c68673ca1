"""A tracker's last ``max_lag`` seconds of scans: out-of-sequence scans fused exactly.

:class:`ScanHistory` keeps a tracker's scans in time order with its state after each, and the
state before the oldest (the checkpoint). A scan at or after the newest is one step. An older
one, no more than ``max_lag`` before the newest and not before the checkpoint, is inserted in
time order and the scans after it are run again from the state before it (buffer and
reprocess, association included): the states equal those of the same tracker run on the
time-sorted scans. An older scan is late. The states before the newest ``max_lag`` seconds are
folded into the checkpoint.

It is the out-of-sequence rule of every tracker of scans: ``mtt-centralized``'s tracker of every
sensor's scans, ``mtt-local``'s, and the local trackers of ``mtt-federated`` /
``mtt-decentralized`` (:class:`fedtrack.local_filters.mtt.local.SensorTracker`), in the replay
and in the live services. (The track-to-track centre fuses its local observations out of
sequence the same way, per central track: :mod:`fedtrack.fusion_center.mtt.central_track`.)
"""

from __future__ import annotations

import bisect
from collections.abc import Callable
from typing import Generic, TypeVar

# At most this many kept entries (scans of a tracker, observations of a central track): far more than
# max_lag seconds of any real sensor set hold (8 sensors at 10 Hz over 3 s: 240), so that a sensor
# repeating one time stamp, or sending scans microseconds apart, cannot grow a buffer (and the scans one
# late scan re-runs) without bound; beyond it the oldest is folded into the checkpoint (an older one is
# then late).
MAX_ENTRIES = 256

S = TypeVar("S")  # the state after a scan
E = TypeVar("E")  # what the history keeps of a scan (the scan, and what else a step needs)


class ScanHistory(Generic[S, E]):
    """Entries (``E``, at times ``times``) of the last ``max_lag`` seconds in time order, with
    the state (``S``) after each and the checkpoint ``base`` before the oldest."""

    def __init__(self, base: S, max_lag: float) -> None:
        self.base, self.base_t, self.max_lag = base, None, max_lag
        self.times: list[float] = []
        self.entries: list[E] = []
        self.after: list[S] = []

    def is_late(self, t: float) -> bool:
        """Whether an entry at ``t`` is too old to fuse exactly: more than ``max_lag`` before the
        newest, or before the checkpoint."""
        return bool(self.times) and t < self.times[-1] - self.max_lag or (self.base_t is not None and t < self.base_t)

    @property
    def newest(self) -> S:
        return self.after[-1] if self.after else self.base

    def state_at(self, T: float) -> S:
        """The state after the last entry up to ``T`` (the checkpoint if none)."""
        k = bisect.bisect_right(self.times, T)
        return self.after[k - 1] if k else self.base

    def state_after(self, T: float, n: int) -> tuple[S, int]:
        """The state ``n`` entries after the last entry up to ``T`` (the checkpoint counts as the
        state before the oldest), or after the newest if fewer came after it; and how many
        entries after that one it is (0: :meth:`state_at`)."""
        k = bisect.bisect_right(self.times, T)
        back = max(min(n, len(self.times) - k), 0)
        return (self.after[k - 1 + back] if k + back else self.base), back

    def insert(self, t: float, entry: E, step: Callable[[S, E], S]) -> int:
        """Add ``entry`` (not late) at ``t`` after the entries up to ``t`` and run it and the later
        ones with ``step`` from the state before it; returns its position, from which the states
        were computed (before the oldest entries are folded into the checkpoint)."""
        k = bisect.bisect_right(self.times, t)
        self.times.insert(k, t)
        self.entries.insert(k, entry)
        self.rerun(k, step)
        return k

    def rerun(self, k: int, step: Callable[[S, E], S]) -> None:
        """Run the entries from position ``k`` on again (one of them changed)."""
        state = self.after[k - 1] if k else self.base
        del self.after[k:]
        for entry in self.entries[k:]:
            state = step(state, entry)
            self.after.append(state)

    def fold(self) -> None:
        """Fold the entries before the newest ``max_lag`` seconds, and those beyond the newest
        :data:`MAX_ENTRIES`, into the checkpoint."""
        drop = bisect.bisect_left(self.times, self.times[-1] - self.max_lag) if self.times else 0
        drop = max(drop, len(self.times) - MAX_ENTRIES)
        if drop:
            self.base, self.base_t = self.after[drop - 1], self.times[drop - 1]
            del self.times[:drop], self.entries[:drop], self.after[:drop]
