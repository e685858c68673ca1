"""When a live multi-target centre counts a silent sensor as gone (fusion_center/mtt/silence.py):
after ``leave_after_s`` and four of the sensor's own usual intervals between messages."""

from __future__ import annotations

import pytest

from fedtrack.fusion_center.mtt.silence import LEAVE_INTERVALS, Silence


def heard_every(silence: Silence, sensor: str, period: float, times: int, start: float = 0.0) -> float:
    t = start
    for _ in range(times):
        silence.heard(sensor, t)
        t += period
    return t - period


def test_a_slow_sensor_is_not_dropped_between_its_scans_and_is_once_silent_for_four_intervals() -> None:
    silence = Silence(floor_s=5.0)
    last = heard_every(silence, "radar", 12.0, 5)  # a surveillance radar's 12 s turn
    assert silence.bound_s("radar") == LEAVE_INTERVALS * 12.0
    assert silence.silent(last + 12.0 * 3.9) == []  # a scan up to two periods late keeps it live
    assert silence.silent(last + 12.0 * 4.1) == ["radar"]


def test_a_fast_sensor_keeps_the_floor_and_a_late_scan_does_not_move_its_interval() -> None:
    silence = Silence(floor_s=5.0)
    last = heard_every(silence, "s1", 1.0, 6)
    silence.heard("s1", last + 2.9)  # a late scan: 2.9 s of silence, then two arrivals close together
    silence.heard("s1", last + 3.0)
    assert silence.bound_s("s1") == 5.0  # median interval 1 s: the floor
    assert silence.silent(last + 3.0 + 4.9) == [] and silence.silent(last + 3.0 + 5.1) == ["s1"]


def test_a_sensor_heard_once_takes_the_others_pace_and_rejoins_with_its_intervals() -> None:
    silence = Silence(floor_s=5.0)
    silence.heard("radar", 0.0)
    assert silence.bound_s("radar") == 20.0  # nothing known: four floors, so a 12 s radar's second scan comes in time
    assert silence.silent(12.0) == [] and silence.silent(20.5) == ["radar"]
    heard_every(silence, "s1", 10.0, 4)  # a launch at 0.1x: 10 s of wall clock between scans
    silence.heard("s2", 30.0)
    assert silence.bound_s("s2") == 40.0 and silence.silent(60.0) == ["radar"]
    silence.left("s1")
    assert "s1" not in silence.last and silence.bound_s("s1") == 40.0  # a rejoiner keeps its pace
    silence.heard("s1", 200.0)
    assert silence.silent(230.0) == ["radar", "s2"]  # s1 (median interval still 10 s) is live; the others went quiet


def test_a_bursty_sensor_is_not_dropped_between_its_bursts() -> None:
    """Bursts of 4 messages 0.05 s apart every 8 s: the usual interval is the 7.85 s pause (the time
    between messages is mostly spent there), so the sensor stays live through its pauses and is
    dropped once silent for four of them; a sensor whose one long interval was an outage keeps its
    1 s. Before untuned5 the usual interval was the median, 0.05 s, and the bound the 5 s floor:
    the bursty sensor was dropped at every pause."""
    silence = Silence(floor_s=5.0)
    for k in range(4):
        for j in range(4):
            silence.heard("burst", 8.0 * k + 0.05 * j)
    last = 8.0 * 3 + 0.15
    assert silence.bound_s("burst") == pytest.approx(LEAVE_INTERVALS * 7.85)
    assert silence.silent(last + 7.9) == [] and silence.silent(last + 4 * 7.85 + 0.1) == ["burst"]
    t = heard_every(silence, "s1", 1.0, 5)
    t = heard_every(silence, "s1", 1.0, 4, start=t + 60.0)  # back after 60 s
    assert silence.bound_s("s1") == 5.0 and silence.silent(t + 5.1) == ["burst", "s1"]
