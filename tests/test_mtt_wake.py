"""A sensor frozen (SIGSTOP, a stalled host) and woken: its missed scans come in a burst, their
reports far older than ``max_lag`` before the centre's newest data.

The centre compares a report's unmapped local tracks with the central tracks at the report's time;
a central track whose checkpoint is newer than that time gives its checkpoint, so a report 20 s old
matched nothing and started a central track per local track (the sensor had left by the silence
rule: all of them unmapped). Live (100 targets, 2 x 2 regions, a sensor frozen 12 s at speed 2)
the burst left 96 false confirmed tracks in the last picture. Such a report is now late
(``late_reports``): neither fused nor mapped, answered with no resets.
"""

from __future__ import annotations

import numpy as np
import pytest

from fedtrack.fusion_center.mtt.centre import TrackToTrackCentre
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.local import LocalReport

H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
TARGETS = 3  # 500 m apart in y, each at 20 m/s in x


def report(sensor: str, t: float, started: bool = False) -> LocalReport:
    """A position sensor's report of its confirmed local tracks 1..TARGETS, each detected on its target."""
    x = np.array([[20.0 * t, 20.0, 500.0 * k, 0.0] for k in range(TARGETS)])
    return LocalReport(sensor, t, np.arange(1, TARGETS + 1), x,
                       np.broadcast_to(np.diag([100.0, 25.0, 100.0, 25.0]), (TARGETS, 4, 4)).copy(),
                       np.ones(TARGETS, bool), np.ones(TARGETS, bool), np.broadcast_to(H, (TARGETS, 2, 4)).copy(),
                       np.broadcast_to(100.0 * np.eye(2), (TARGETS, 2, 2)).copy(), x[:, [0, 2]].copy(),
                       np.full(TARGETS, started), np.zeros(0, np.int64))


@pytest.mark.parametrize("feedback", [True, False])
def test_a_burst_of_reports_far_behind_the_data_starts_no_central_track(feedback: bool) -> None:
    """s1 and s2 track 3 targets; s2 stops after 10 s and is dropped (silence), s1 goes on to 30 s;
    then s2's reports of 10.5-30.5 s come at once. Before: its first late report started 3 central
    tracks beside the 3 (6 live); now 3 live throughout, the 20 reports more than max_lag (3 s) old
    counted late, unanswered by resets, and s2 joins the central tracks again when its reports are
    within max_lag."""
    centre = TrackToTrackCentre(MttConfig(), 4, feedback)
    for k in range(31):
        centre.answer(report("s1", float(k), started=k == 0))
        if k <= 10:
            centre.answer(report("s2", k + 0.5, started=k == 0))
    centre.drop_sensor("s2")
    live = []
    for k in range(10, 31):
        resets, _ = centre.answer(report("s2", k + 0.5))
        live.append(centre.tracks.live().size)
        if k + 0.5 < 30 - 3.0:
            assert resets.ids.size == 0
    assert live == [TARGETS] * len(live)
    assert centre.counters.late_reports == sum(1 for k in range(10, 31) if k + 0.5 < 30 - 3.0) == 17
    assert {key[0] for key in centre.mapping} == {"s1", "s2"} and len(centre.mapping) == 2 * TARGETS
