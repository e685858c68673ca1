"""A router outage takes every liveliness token with each client's link: the peers it took are not dead.

The federated pipeline of ``test_fuzz_handlers`` (two local filters and the centre, in process, through
their own dispatch) is cut mid-run as a router restart cuts it, and the services come back one by one
with the backlog recovered from the publishers' caches (:class:`fedtrack.zsession.Peers`)."""

from __future__ import annotations

import logging
from dataclasses import replace
from types import SimpleNamespace
from typing import Any

import pytest
import zenoh
from test_fuzz_handlers import KEYS, MEASUREMENTS, SCANS, SENSORS, Pipeline, run

from fedtrack.services.dispatch import REJECT_LOG_INTERVAL_S
from fedtrack.wire import LocalEstimate, Reset, encode
from fedtrack.zsession import LINK_GRACE_S, LOST_KEPT, Link, Peers

OUTAGE_AT = 20  # the first scan after the outage (the backlog: it and the next)


def token(callback: Any, key: str, alive: bool) -> None:
    callback(SimpleNamespace(key_expr=key, kind=zenoh.SampleKind.PUT if alive else zenoh.SampleKind.DELETE))


def peer_tokens(pipe: Pipeline, sensors: tuple[str, ...], alive: bool) -> None:
    """The centre sees the tokens of ``sensors``' sensors and local filters come or go."""
    for s in sensors:
        for role in ("sensor", "local-filter"):
            token(lambda x, role=role: pipe.centre._on_liveliness(role, x), KEYS.alive(role, s), alive)


def centre_token(pipe: Pipeline, sensors: tuple[str, ...], alive: bool) -> None:
    """The local filters of ``sensors`` see the centre's token come or go."""
    for s in sensors:
        token(pipe.locals[s]._on_centre_liveliness, KEYS.alive("fusion-center", "fusion"), alive)


def router_token(services: list[Any], alive: bool) -> None:
    for svc in services:
        token(svc._on_router, KEYS.alive("router", "router"), alive)


def scan(pipe: Pipeline, k: int, sensors: tuple[str, ...] = SENSORS) -> None:
    """Scan ``k`` of ``sensors``: each one's measurement, then its estimate (if made) at the centre."""
    for s in sensors:
        pipe.measurement(s, s, encode(MEASUREMENTS[s][k]))
        estimate(pipe, k, s)


def estimate(pipe: Pipeline, k: int, sensor: str) -> None:
    """The estimate of scan ``k`` that ``sensor``'s filter made, if any, at the centre."""
    mine = [m for _, m in pipe.published if isinstance(m, LocalEstimate) and m.sensor == sensor and m.seq == k]
    if mine:
        pipe.estimate(sensor, encode(mine[-1]))


def resets(pipe: Pipeline, k: int) -> None:
    for r in [m for _, m in pipe.published if isinstance(m, Reset) and m.seq == k]:
        pipe.reset(r.sensor, encode(r))


def finish_as_without_outage(pipe: Pipeline, plain: list[Any]) -> None:
    """The scans after the backlog in lockstep; the tracks equal those of the run without the outage, and
    nothing was fused without a reset, degraded, late or rejected."""
    for k in range(OUTAGE_AT + 2, SCANS):
        scan(pipe, k)
        resets(pipe, k)
    assert [encode(t) for t in pipe.tracks()] == [encode(t) for t in plain]
    counters = [svc.counters for svc in (*pipe.locals.values(), pipe.centre)]
    assert not any(c.get(name) for c in counters for name in ("no_reset", "degraded_scans", "late", "rejected"))


def test_peers_lost_with_the_link_get_its_grace() -> None:
    """A token that went while the link held is gone at once; one that went with the link is not while
    the link is cut, nor for ``LINK_GRACE_S`` after it is back; a flood of tokens is bounded."""
    peers = Peers()
    for key in ("a", "b", "c"):
        peers.token(key, True, 0.0)
    peers.token("a", False, 1.0)
    assert peers.gone(Link(), 1.0) == {"a"} and peers.present == {"b", "c"}
    peers.token("b", False, 2.0)  # the link closes: its tokens go just before the router's
    peers.token("c", False, 2.0)
    assert peers.gone(Link(cut=True), 2.5) == set()
    back = Link(back_at=3.0)
    peers.token("c", True, 3.1)
    assert peers.gone(back, 3.1) == set() and peers.gone(back, 3.0 + LINK_GRACE_S) == {"a", "b"}
    peers.token("c", False, 3.2)  # died after the link was back: at once
    assert peers.gone(back, 3.2) == {"c"}
    for i in range(10 * LOST_KEPT):
        peers.token(f"forged{i}", True, 4.0)
        peers.token(f"forged{i}", False, 4.0)
    assert len(peers.lost) == LOST_KEPT


@pytest.mark.parametrize("returns", ["in time", "too late"])
def test_a_router_outage_costs_nothing_when_the_peers_come_back(returns: str) -> None:
    """After the outage filter 2 and its sensor are back first, with the backlog of scans 20-21; filter 1
    a little later. Before, the centre took filter 1's missing tokens for its death and fused scan 20
    with filter 2's estimate alone (filter 1's came late), and filter 2, the centre's token not back
    yet, went on alone with scan 21 (flagged ``no-reset``): live, after a 2.5 s router restart, two of
    three filters went on alone for 33 scans. Now they are waited for, and the run's tracks are those of
    a run without the outage. A peer whose token is not back ``LINK_GRACE_S`` after the link died
    meanwhile: then it is not waited for, as before."""
    plain = run().tracks()
    pipe = Pipeline()
    first, later = SENSORS[1], SENSORS[0]
    services = [*pipe.locals.values(), pipe.centre]
    router_token(services, True)
    peer_tokens(pipe, SENSORS, True)
    centre_token(pipe, SENSORS, True)
    for k in range(OUTAGE_AT):
        scan(pipe, k)
        resets(pipe, k)
    # the router dies: at every service every token goes with the link, the router's last
    peer_tokens(pipe, SENSORS, False)
    centre_token(pipe, SENSORS, False)
    router_token(services, False)
    late = LINK_GRACE_S if returns == "too late" else 0.0  # how long ago each link came back
    router_token([pipe.locals[first]], True)  # filter 2's link is back first, with the sensor's backlog
    pipe.locals[first]._router_back_at -= late
    for k in (OUTAGE_AT, OUTAGE_AT + 1):
        pipe.measurement(first, first, encode(MEASUREMENTS[first][k]))
    estimates = [m for _, m in pipe.published if isinstance(m, LocalEstimate) and m.sensor == first]
    if late:  # the centre not back LINK_GRACE_S after the filter's link: it died meanwhile, not waited for
        assert estimates[-1].seq == OUTAGE_AT + 1 and estimates[-1].degraded == ("no-reset",)
    else:
        assert estimates[-1].seq == OUTAGE_AT  # scan 21 waits for the reset of scan 20
    router_token([pipe.centre], True)  # then the centre's link, which sees filter 2 back
    pipe.centre._router_back_at -= late
    peer_tokens(pipe, (first,), True)
    centre_token(pipe, (first,), True)
    estimate(pipe, OUTAGE_AT, first)
    tracks = pipe.tracks()
    if late:  # filter 1 not back LINK_GRACE_S after the centre's link: it died meanwhile, not waited for
        assert tracks[-1].seq == OUTAGE_AT and tracks[-1].sensors == (first,) and tracks[-1].degraded
        return
    assert tracks[-1].seq == OUTAGE_AT - 1
    router_token([pipe.locals[later]], True)  # filter 1's link last
    peer_tokens(pipe, (later,), True)
    centre_token(pipe, (later,), True)
    for k in (OUTAGE_AT, OUTAGE_AT + 1):
        scan(pipe, k, (later,))
    resets(pipe, OUTAGE_AT)
    for s in SENSORS:  # each filter's estimate of scan 21, made once its reset of scan 20 applied
        estimate(pipe, OUTAGE_AT + 1, s)
    resets(pipe, OUTAGE_AT + 1)
    finish_as_without_outage(pipe, plain)


def test_a_wait_does_not_run_while_the_link_is_cut() -> None:
    """A wait for other sessions' messages counts only while the link holds, from its return after a cut."""
    assert Link().waited(1.0, 3.0) == 2.0
    assert Link(cut=True).waited(1.0, 30.0) == 0.0
    back = Link(back_at=2.5)  # the peers may still be coming back for LINK_GRACE_S
    assert back.waited(1.0, 3.0) < 0 and back.waited(1.0, 3.0 + LINK_GRACE_S) == 0.5
    assert back.waited(2.5 + LINK_GRACE_S + 1.0, 2.5 + LINK_GRACE_S + 3.0) == 2.0


def test_the_deadlines_stand_still_while_the_router_is_down() -> None:
    """The router dies while filter 1's estimate of scan 20 is on its way and filter 2's is in; filter 1
    already holds scan 21, waiting for the reset of scan 20. The outage lasts longer than the deadline
    (0.5 s, the same for the reset). Before, the centre fused scan 20 without filter 1 and filter 1 went
    on alone with scan 21, each for want of what the outage held up; live (a 3.6 s router restart under
    load) filter 3 then ran through its backlog alone, ahead of the others by more than the deadline, and
    the centre fused scans 45-80 from its estimates alone. Nor does either decide until the peers had
    ``LINK_GRACE_S`` to be back: what they sent before their subscribers were known again arrives with
    the recovery their publishers' next heartbeat sets off (live, 0.34 s after the centre's link was back,
    while the filters' 0.5 s wait for their resets ran; once every filter gave up and went on alone
    through its backlog). What the outage held up, delivered after that, is fused as without the outage."""
    plain = run().tracks()
    pipe = Pipeline()
    services = [*pipe.locals.values(), pipe.centre]
    router_token(services, True)
    for k in range(OUTAGE_AT):
        scan(pipe, k)
        resets(pipe, k)
    held, on_time = SENSORS
    for k in (OUTAGE_AT, OUTAGE_AT + 1):
        pipe.measurement(held, held, encode(MEASUREMENTS[held][k]))
    pipe.measurement(on_time, on_time, encode(MEASUREMENTS[on_time][OUTAGE_AT]))
    estimate(pipe, OUTAGE_AT, on_time)
    router_token(services, False)
    pipe.centre.scans[OUTAGE_AT].first_arrival -= 10.0  # an outage of 10 s
    pipe.locals[held].waiting_since -= 10.0
    for svc in services:
        svc.on_tick()
    assert pipe.tracks()[-1].seq == OUTAGE_AT - 1 and not pipe.locals[held].alone
    router_token(services, True)
    for svc in services:  # 1 s after the link's return: past the deadline, within LINK_GRACE_S
        svc._router_back_at -= 1.0
        svc.on_tick()
    assert pipe.tracks()[-1].seq == OUTAGE_AT - 1 and not pipe.locals[held].alone
    estimate(pipe, OUTAGE_AT, held)
    resets(pipe, OUTAGE_AT)
    pipe.measurement(on_time, on_time, encode(MEASUREMENTS[on_time][OUTAGE_AT + 1]))
    for s in SENSORS:
        estimate(pipe, OUTAGE_AT + 1, s)
    resets(pipe, OUTAGE_AT + 1)
    finish_as_without_outage(pipe, plain)


def test_a_filter_waits_for_the_reset_the_centre_makes_at_its_deadline() -> None:
    """Filter 2's estimate of scan 20 reaches the centre first and filter 2 holds scan 21; filter 1's
    estimate is held up (a process descheduled) until the centre's deadline, 0.5 s after the first
    estimate, has passed. The centre then fuses without it and sends its resets. Filter 2 waited for its
    reset one deadline, from about the same moment, so it gave up just before the reset came and went on
    alone (live at load 21: alone for scans 25-42, every later reset coming after its next scan). Now it
    waits two (``RESET_WAIT_DEADLINES``) and takes the reset."""
    pipe = Pipeline()
    for k in range(OUTAGE_AT):
        scan(pipe, k)
        resets(pipe, k)
    first = SENSORS[1]  # filter 1 (SENSORS[0]) is the slow one
    for k in (OUTAGE_AT, OUTAGE_AT + 1):
        pipe.measurement(first, first, encode(MEASUREMENTS[first][k]))
    estimate(pipe, OUTAGE_AT, first)
    elapsed = pipe.centre.deadline_s + 0.05  # since filter 2 published and began to wait
    pipe.locals[first].waiting_since -= elapsed
    pipe.centre.scans[OUTAGE_AT].first_arrival -= elapsed
    pipe.locals[first].on_tick()  # the filter's clock runs out first (it began to wait first) ...
    pipe.centre.on_tick()  # ... then the centre's: scan 20 fused without filter 1, the resets sent
    assert pipe.tracks()[-1].seq == OUTAGE_AT and pipe.tracks()[-1].sensors == (first,)
    resets(pipe, OUTAGE_AT)
    estimates = [m for _, m in pipe.published if isinstance(m, LocalEstimate) and m.sensor == first]
    assert estimates[-1].seq == OUTAGE_AT + 1 and estimates[-1].degraded == ()  # made after the reset
    assert not pipe.locals[first].alone and not pipe.locals[first].counters.get("no_reset")


def test_a_token_declared_and_withdrawn_in_a_loop_is_logged_a_bounded_number_of_times(caplog: Any) -> None:
    """A sensor's process declaring and withdrawing its own token in a loop (its key: the access control
    admits it; 2,000 a second measured through a router, each a PUT and a DELETE at every subscriber) had
    the centre log a line a change: 4,000 lines for 2,000 toggles. It now logs a token's going and return
    at most ``TOKEN_LINES`` times every ``REJECT_LOG_INTERVAL_S``, the next line counting the changes not
    logged; a sensor that dies and restarts is still logged both ways, and the centre still sees the token
    as it stands."""
    pipe = Pipeline()
    sensor = SENSORS[0]
    with caplog.at_level(logging.WARNING, logger=pipe.centre.log.name):
        peer_tokens(pipe, (sensor,), True)
        peer_tokens(pipe, (sensor,), False)  # a death and a restart: both logged
        peer_tokens(pipe, (sensor,), True)
        assert [r.getMessage() for r in caplog.records] == [f"{role} {sensor} {what}" for what in (
            "is gone (liveliness): fusing without it", "is back") for role in ("sensor", "local-filter")]
        for k in range(2000):
            token(lambda x: pipe.centre._on_liveliness("sensor", x), KEYS.alive("sensor", sensor), k % 2 == 1)
        assert len(caplog.records) == 4
        pipe.centre._token_said = {key: (since - REJECT_LOG_INTERVAL_S, lines, unsaid)  # the interval is over
                                   for key, (since, lines, unsaid) in pipe.centre._token_said.items()}
        token(lambda x: pipe.centre._on_liveliness("sensor", x), KEYS.alive("sensor", sensor), False)
    assert caplog.records[-1].getMessage() == (f"sensor {sensor} is gone (liveliness): fusing without it "
                                               "(2000 more changes of its token not logged)")
    assert pipe.centre.gone(1e9) == {sensor}


@pytest.mark.parametrize(("seq", "t"), [(10**9, 1e4), (4, 0.05)])
def test_one_sensors_estimate_before_the_first_scan_cannot_start_the_centre(seq: int, t: float) -> None:
    """Nothing fused yet (a start, or a restart without a snapshot), the centre takes the first scan that
    comes as where the scans start. Sensor 1 (its own key) sent one estimate numbered 10^9 before the
    sensors started: the centre fused it alone and every genuine estimate after it was late, 1 scan of 34
    fused. Now two sensors' estimates of one scan passed over start the scans again from it: after the
    forged track, the tracks are those of the run without it."""
    plain = run().tracks()
    first = Pipeline()
    first.measurement(SENSORS[0], SENSORS[0], encode(MEASUREMENTS[SENSORS[0]][0]))
    forged = replace(first.estimates_of_last_scan()[-1], seq=seq, t=t)
    pipe = Pipeline()
    peer_tokens(pipe, SENSORS, True)
    pipe.estimate(SENSORS[0], encode(forged))
    for buf in pipe.centre.scans.values():  # its deadline passed before the sensors' first scan
        buf.first_arrival -= 10 * pipe.centre.deadline_s
    pipe.centre.on_tick()
    assert [t.seq for t in pipe.tracks()] == [seq]
    for k in range(SCANS):
        scan(pipe, k)
        resets(pipe, k)
    assert [encode(t) for t in pipe.tracks()[1:]] == [encode(t) for t in plain] and len(plain) == SCANS
    assert pipe.centre.counters["restarted"] == 1


def test_a_silent_filter_does_not_stop_the_scans_of_the_other() -> None:
    """Both local filters live, sensor 2 silent: sensor 1's scans are fused alone at their deadlines
    (degraded), as before; its late estimates alone start nothing again."""
    pipe = Pipeline()
    peer_tokens(pipe, SENSORS, True)
    for k in range(SCANS):
        scan(pipe, k, sensors=(SENSORS[0],))
        for buf in pipe.centre.scans.values():
            buf.first_arrival -= 10 * pipe.centre.deadline_s
        pipe.centre.on_tick()
        resets(pipe, k)
    assert [t.seq for t in pipe.tracks()] == list(range(SCANS))
    assert not pipe.centre.counters.get("restarted")
