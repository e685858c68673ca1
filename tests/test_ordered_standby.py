"""A warm region standby's inputs in its primary's order (:class:`~fedtrack.fusion_center.mtt.failover.ordered.
PrimaryOrder`), in process: what odd pictures of its primary cost it."""

from __future__ import annotations

import time

import numpy as np

from fedtrack.fusion_center.mtt.failover.ordered import ORDER_WAIT_S, PrimaryOrder
from fedtrack.wire import TrackPicture, TrackReport


def picture(seq: int, entries: list[tuple[str, int]]) -> TrackPicture:
    """A primary's picture without tracks whose fused lists name the sub-reports ``entries`` (sensor, scan)."""
    return TrackPicture(seq=seq, t=float(seq), ids=(), x=np.zeros((0, 4)), P=np.zeros((0, 4)), confirmed=(),
                        sensors=(), fused_sensors=tuple(s for s, _ in entries), fused_seqs=tuple(n for _, n in entries),
                        stamp_ns=1)


def report(sensor: str, seq: int) -> TrackReport:
    """An empty sub-report of ``sensor``'s scan ``seq``."""
    return TrackReport(sensor=sensor, seq=seq, t=float(seq), ids=(), x=np.zeros((0, 4)), P=np.zeros((0, 4)),
                       confirmed=(), detected=(), obs_H=np.zeros((0, 4)), obs_R=np.zeros((0, 2)),
                       obs_z=np.zeros((0, 2)), started=(), retired=(), stamp_ns=1)


def test_an_input_costs_the_same_whatever_the_primary_listed() -> None:
    """Pictures listing 200,000 inputs that never come: each input's turn built the set of every entry still
    listed, 500 inputs took 8.6 s of CPU (600 pictures of 2,000 such entries, 500 a second: 20.7 s, now 1.7 s);
    now the entries are counted as they come and go. The order is kept: a listed input waits for its turn, an
    unlisted one is taken in arrival order once ``ORDER_WAIT_S`` old, the never-coming entries passed over."""
    order = PrimaryOrder(10_000)
    order.arrived(report("s1", 0), 0.0)
    order.listed(picture(0, [("s1", 0)]), 0.0)
    assert order.due(0.0)[0][0][0] == ("report", "s1", 0) and order.warm
    for k in range(1, 101):
        order.listed(picture(k, [("sx", 10**6 * k + i) for i in range(2000)] + [("s1", k)]), 0.1)
    started = time.process_time()
    for k in range(1, 501):
        order.arrived(report("s2", k), 0.2)
        assert order.due(0.2) == ([], [])
    assert time.process_time() - started < 1.0
    order.arrived(report("s1", 1), 0.3)
    listed, stale = order.due(ORDER_WAIT_S + 0.2)
    assert [e for e, _ in listed] == [("report", "s1", 1)] and order.skipped == 100 * 2000 + 99
    assert [e for e, _ in stale] == [("report", "s2", k) for k in range(1, 501)]
    assert not order.script and not order.waiting and not order.held
