"""A router outage takes every liveliness token with each client's link: the multi-target centre's
trackers whose tokens it took have not departed, and a tracker's wait for the centre's resets stands still.

The federated multi-target pipeline of ``test_hostile_messages`` (three trackers, the centre and the
recorder, in process through :class:`test_hostile_messages.Bus`) is cut mid-run as a router restart
cuts it (:class:`fedtrack.zsession.Peers`, :class:`fedtrack.zsession.Link`); about 1 s each."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
import zenoh
from test_hostile_messages import KEYS, MTT_SENSORS, Bus, mtt_lines, mtt_services, pictures

from fedtrack.wire import TrackReport, encode
from fedtrack.zsession import LINK_GRACE_S

OUTAGE_T = 6.0  # the router dies then (the scenario is 12 s)


def token(callback: Any, key: str, alive: bool) -> None:
    callback(SimpleNamespace(key_expr=key, kind=zenoh.SampleKind.PUT if alive else zenoh.SampleKind.DELETE))


def router(services: list[Any], alive: bool) -> None:
    for svc in services:
        token(svc._on_router, KEYS.alive("router", "router"), alive)


def trackers(centre: Any, sensors: tuple[str, ...], alive: bool) -> None:
    """The centre sees the tokens of ``sensors``' trackers come or go."""
    for s in sensors:
        token(centre._on_alive, KEYS.alive("mtt-local", s), alive)


def run(tmp_path: Path, outage: Any = None) -> tuple[list[tuple[Any, ...]], Any]:
    """The scenario through the federated pipeline; ``outage(centre)`` at ``OUTAGE_T``."""
    services = mtt_services(tmp_path, "mtt-federated")
    centre = services["centre"]
    bus = Bus(list(services.values()))
    router([centre], True)
    cut = False
    for msg in mtt_lines(tmp_path):
        if msg.t >= OUTAGE_T and not cut and outage is not None:
            cut = True
            outage(centre)
        bus.put(KEYS.sensor_meas(msg.sensor), encode(msg))
    centre.on_tick()
    centre.on_stop()
    bus.drain()
    return pictures(bus), centre


@pytest.mark.parametrize("returns", ["in time", "too late"])
def test_a_router_outage_departs_no_tracker_whose_token_comes_back(tmp_path: Path, returns: str) -> None:
    """The centre's link goes and with it every tracker's token; the link comes back and the trackers'
    tokens one by one. Before, the centre took each lost token for a departure at its next tick: all three
    trackers left (``sensors_left`` 3, their local tracks unmapped from the central tracks, which their next
    reports built afresh). Now none has left and the pictures are those of a run without the outage. A
    tracker whose token is not back ``LINK_GRACE_S`` after the link died meanwhile: it leaves (once, though
    its reports come on)."""
    plain, _ = run(tmp_path / "plain")
    late = "s3" if returns == "too late" else None

    def outage(centre: Any) -> None:
        trackers(centre, MTT_SENSORS, True)
        trackers(centre, MTT_SENSORS, False)  # the link closes: its tokens go just before the router's
        router([centre], False)
        centre.on_tick()
        router([centre], True)
        trackers(centre, ("s2",), True)
        centre.on_tick()  # within LINK_GRACE_S of the link's return
        assert "sensors_left" not in centre.counters
        trackers(centre, tuple(s for s in ("s1", "s3") if s != late), True)
        centre._router_back_at -= LINK_GRACE_S  # then the grace is over
        centre.on_tick()
        centre.on_tick()

    live, centre = run(tmp_path / "outage", outage)
    if late is None:
        assert "sensors_left" not in centre.counters and live == plain
        assert not centre.peers.lost and centre.peers.present == set(MTT_SENSORS)
    else:
        assert centre.counters["sensors_left"] == 1 and set(centre.silence.last) == set(MTT_SENSORS)
        assert live != plain  # s3's local tracks left their central tracks
    assert "rejected_handler_error" not in centre.counters


def test_a_trackers_reset_wait_stands_still_while_the_router_is_down(tmp_path: Path) -> None:
    """s1's tracker awaits the resets of its first report when its link goes, for longer than its
    ``--reset-timeout`` (5 s here). Before, it went on without them at its next tick (``reset_timeouts``);
    now its wait runs neither while the link is cut nor ``LINK_GRACE_S`` after its return."""
    services = mtt_services(tmp_path, "mtt-federated")
    local = services["s1"]
    bus = Bus([local])  # no centre: the resets never come
    router([local], True)
    first = next(m for m in mtt_lines(tmp_path) if m.sensor == "s1")
    bus.put(KEYS.sensor_meas("s1"), encode(first))
    assert local.awaiting == first.seq and len(bus.of(TrackReport)) == 1
    router([local], False)
    local.awaiting_since -= 10.0  # an outage of 10 s
    local.on_tick()
    router([local], True)
    local._router_back_at -= 1.0  # 1 s after the link's return: within LINK_GRACE_S
    local.on_tick()
    assert local.awaiting == first.seq and "reset_timeouts" not in local.counters
    local._router_back_at -= LINK_GRACE_S + local.reset_timeout_s  # its timeout run out after the grace
    local.on_tick()
    assert local.awaiting is None and local.counters["reset_timeouts"] == 1
