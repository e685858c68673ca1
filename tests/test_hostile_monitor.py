"""Hostile messages at the launcher's monitor (``fedtrack launch`` / ``demo``'s own session), at the
state queryable and at every service's watch of the router's liveliness token, driven in-process.

The monitor subscribes to every service's Health and every sensor's measurements and builds the
run's summary from them (``summary.json``: each service's final counters, the rejected total, the
measurements per sensor). Under mutual TLS and access control an identity may publish only on its
own keys, but the monitor read the service a Health belongs to, and the sensor a measurement belongs
to, from the payload, never from the key: sensor 1's certificate could overwrite the fusion centre's
counters in the summary (hiding its rejections) or count measurements for sensor 2.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any, Self

import numpy as np
import pytest
import zenoh

from fedtrack.deploy.launcher import Launcher
from fedtrack.deploy.settings import load_settings
from fedtrack.wire import Health, Measurement, encode


def sample(key: str, payload: bytes) -> Any:
    """What a Zenoh subscriber callback gets (the fields the monitor reads)."""
    return SimpleNamespace(key_expr=key, kind=zenoh.SampleKind.PUT,
                           payload=SimpleNamespace(to_bytes=lambda: payload))


@pytest.fixture
def launcher(tmp_path: Path) -> Launcher:
    cfg = tmp_path / "c.toml"
    cfg.write_text('[deployment]\nname = "mon"\n')
    return Launcher(load_settings(cfg), [], quiet=True)


def health(role: str, sid: str, rejected: int) -> Health:
    return Health(role=role, id=sid, seq=7, status="ok",
                  counters={"received": 100, "rejected": rejected, "published": 100, "dropped": 0})


def test_a_health_on_another_services_key_is_rejected_not_summarized(launcher: Launcher) -> None:
    """sensor-1 (its own key, which the access control admits) published the fusion centre's Health
    with 0 rejected after the genuine one with 5: the summary said 0 rejected (now 5, and the
    forgery counted); one naming another role of id 1 added a service that does not exist."""
    keys = launcher.keys
    launcher._on_health(sample(keys.health("fusion-center", "fusion"), encode(health("fusion-center", "fusion", 5))))
    launcher._on_health(sample(keys.health("sensor", "1"), encode(health("fusion-center", "fusion", 0))))
    launcher._on_health(sample(keys.health("sensor", "1"), encode(health("recorder", "1", 0))))
    launcher._on_health(sample(keys.health("sensor", "1"), encode(health("sensor", "1", 0))))  # its own: taken
    assert sorted(launcher.report.health) == ["fusion-center/fusion", "sensor/1"]
    assert launcher.report.health["fusion-center/fusion"]["rejected"] == 5
    assert launcher.report.monitor_rejected == 2 and launcher.report.rejected() == 5 + 2


def test_a_measurement_on_another_sensors_key_is_not_counted_for_it(launcher: Launcher) -> None:
    """A measurement of sensor 2 published on sensor 1's key was counted as sensor 2's (the summary's
    measurements per sensor, the progress line's rates); the services reject it (``sender``)."""
    keys = launcher.keys
    for sid in ("1", "2"):
        m = Measurement(sensor=sid, seq=0, t=0.0, kind="position", z=np.zeros(2), R=np.eye(2))
        launcher._on_meas(sample(keys.sensor_meas("1"), encode(m)))
    launcher._on_meas(sample(keys.sensor_meas("1"), b"\x81\xa6schema\x02"))  # malformed: counted too
    assert launcher.report.measurements == {"1": 1} and set(launcher._arrivals) == {"1"}
    assert list(launcher.report.publish_stamps_ns[0]) == ["1"]
    assert launcher.report.monitor_rejected == 2


def test_a_sensor_numbering_scans_afresh_grows_the_monitor_by_a_bounded_amount(launcher: Launcher) -> None:
    """The monitor kept every measurement's publish stamp by scan number (the latency figures), for
    good: sensor 1 numbering its scans afresh on its own key grew it by 212 B a number (21 MB per
    100,000), and repeating one number by 8 B a copy. It now keeps one stamp per sensor and number, up
    to ``max_seq_jump`` (1000) beyond the newest fused track's number (the services reject one further
    ahead); an honest run's stamps, a number at a time with its track, are all kept."""
    from fedtrack.wire import FusedTrack

    keys = launcher.keys

    def measurement(sensor: str, seq: int) -> Any:
        m = Measurement(sensor=sensor, seq=seq, t=float(seq), kind="position", z=np.zeros(2), R=np.eye(2),
                        stamp_ns=seq + 1)
        return sample(keys.sensor_meas(sensor), encode(m))

    def track(seq: int) -> Any:
        t = FusedTrack(seq=seq, t=float(seq), model="cv", x=np.zeros(4), P=np.eye(4), maneuver=False, degraded=False,
                       sensors=("1", "2"), stamp_ns=1, extra={})
        return sample(keys.fusion_track(), encode(t))

    for seq in range(300):  # honest: both sensors' scan, then its track
        launcher._on_meas(measurement("1", seq))
        launcher._on_meas(measurement("2", seq))
        launcher._on_track(track(seq))
    stamps = launcher.report.publish_stamps_ns
    assert all(stamps[seq] == {"1": seq + 1, "2": seq + 1} for seq in range(300))
    for seq in range(2500):  # the flood: 2,500 numbers, then one number 1,000 times
        launcher._on_meas(measurement("1", seq))
    for _ in range(1000):
        launcher._on_meas(measurement("1", 7))
    assert len(stamps) == 299 + 1 + launcher.settings.deployment.max_seq_jump
    assert all(stamps[seq] == {"1": seq + 1, "2": seq + 1} for seq in range(300))  # the first stamp stays
    assert all(len(stamps[seq]) == 1 for seq in range(300, 1300))


def test_a_multi_target_sensors_flood_keeps_one_scan_stamp_a_picture_period(tmp_path: Path) -> None:
    """The picture latency needs, per picture at T, the first scan later than T + ``picture_delay``. The
    monitor kept every multi-target scan's (t, publish stamp) for it, so sensor s1 flooding its own key
    grew the launcher by a stamp a scan, for good; it now keeps the first scan of each picture period
    of the scenario (60 s here), and the latencies equal those of every scan kept, the old rule."""
    import bisect

    cfg = tmp_path / "c.toml"
    cfg.write_text('[deployment]\nname = "mon"\n[multitarget]\nduration = 60.0\n[mtt]\nperiod = 1.0\n'
                   "picture_delay = 0.3\n")
    launcher = Launcher(load_settings(cfg), [], quiet=True)
    keys, rng = launcher.keys, np.random.default_rng(5)

    def scan(sensor: str, seq: int, t: float, stamp: int) -> Any:
        m = Measurement(sensor=sensor, seq=seq, t=t, kind="scan", z=np.zeros(0), R=np.eye(2), stamp_ns=stamp)
        return sample(keys.sensor_meas(sensor), encode(m))

    every: list[tuple[float, int]] = []
    for seq, t in enumerate(np.sort(rng.uniform(0.0, 60.0, 200))):  # an honest sensor, stamps in ms
        stamp = int(t * 1e9) + int(rng.integers(0, 10**7))
        every.append((float(t), stamp))
        launcher._on_meas(scan("s2", seq, float(t), stamp))
    arrivals = [(float(T), int((T + 0.3) * 1e9) + 5 * 10**7) for T in range(1, 60)]
    launcher.report.picture_arrivals = arrivals

    def old() -> list[float]:  # every scan kept: the first later than T + delay
        scans, times = sorted(every), [t for t, _ in sorted(every)]
        return [(a - scans[k][1]) / 1e6 for T, a in arrivals if (k := bisect.bisect_right(times, T + 0.3)) < len(scans)]
    assert launcher.report.picture_latencies_ms(1.0, 0.3) == old() and len(old()) == 59
    for seq in range(2_000):  # the flood: times all over, stamped late
        t = float(rng.uniform(-1e6, 1e6))
        every.append((t, 2 * 10**18))
        launcher._on_meas(scan("s1", seq, t, 2 * 10**18))
    assert len(launcher.report.scan_slots) <= 63 and launcher.report.picture_latencies_ms(1.0, 0.3) == old()


# ---------------------------------------------------------------- the state queryable (fusion/state)

class FakeQuery:
    """What a queryable's callback gets (the fields the service reads), recording its replies."""

    def __init__(self, key: str, payload: bytes | None = None, parameters: str = "") -> None:
        self.key_expr, self.parameters, self.attachment = key, parameters, None
        self.payload = None if payload is None else zenoh.ZBytes(payload)
        self.replies: list[tuple[str, bytes]] = []
        self.dropped = False

    def reply(self, key: str, payload: bytes, **_: Any) -> None:
        self.replies.append((str(key), payload))

    def drop(self) -> None:
        self.dropped = True

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *_: object) -> None:
        self.drop()


@pytest.fixture
def centre() -> Any:
    from fedtrack.fusion_center.centre import FederatedCentre
    from fedtrack.fusion_center.service import FusionCenterService
    from fedtrack.local_filters.vdie.config import FusionConfig
    from fedtrack.wire import FusedTrack
    from fedtrack.zsession import SessionOptions

    svc = FusionCenterService(["1", "2"], FederatedCentre(["1", "2"], FusionConfig()), 0.5, service_id="fusion",
                              options=SessionOptions(connect=("tcp/127.0.0.1:1",)), deployment="mon")
    svc._queryables = svc.queryables()
    svc.last_track = FusedTrack(seq=3, t=3.0, model="cv", x=np.zeros(4), P=np.eye(4), maneuver=False,
                                degraded=False, sensors=("1", "2"), stamp_ns=1, extra={})
    return svc


def ask(svc: Any, query: FakeQuery) -> None:
    """The query as the Zenoh callback hands it over, then handled by the worker."""
    svc._on_query(0, query)
    while svc._queue.qsize():
        svc._dispatch(svc._queue.get_nowait())


def test_a_wildcard_query_is_answered_on_the_state_key(centre: Any) -> None:
    """``get fedtrack/<dep>/**`` was answered on ``fedtrack/<dep>/**`` itself: a reply on a wildcard,
    which the access control refuses (the ``fusion`` identity replies on ``fusion/**`` only)."""
    query = FakeQuery("fedtrack/mon/**")
    ask(centre, query)
    assert [k for k, _ in query.replies] == ["fedtrack/mon/fusion/state"]
    assert centre.counters["rejected"] == 0


def test_a_query_with_a_payload_or_parameters_is_refused_where_it_arrives(centre: Any) -> None:
    """The queryable takes no payload: one was answered as if absent, and held in the inbox until then
    uncounted by its byte bound (10,000 queries of any size). Now the query is dropped (unanswered) in
    the Zenoh callback, and the worker counts it ``rejected_query``."""
    held = FakeQuery("fedtrack/mon/fusion/state", payload=b"x" * 1_000_000)
    centre._on_query(0, held)
    assert held.dropped and all(item[3] is not held for stream in centre._queue._streams.values() for item in stream)
    ask(centre, FakeQuery("fedtrack/mon/fusion/state", parameters="_time=[..]"))
    assert not held.replies and centre.counters.get("rejected_query") == 2 and centre.counters["rejected"] == 2


def test_queries_on_many_selectors_take_one_turn_of_the_inbox(centre: Any) -> None:
    """The inbox serves each stream in turn; a query's stream was its selector, so a querier spreading
    a flood over 100 selectors of ``fusion/state`` won 100 turns for each of an estimate's."""
    queries = [FakeQuery(f"fedtrack/mon/fusion/{'s' * k}$*") for k in range(1, 101)]
    for query in queries:
        centre._on_query(0, query)
    assert len(centre._queue._streams) == 1
    while centre._queue.qsize():
        centre._dispatch(centre._queue.get_nowait())
    assert all(len(q.replies) == 1 for q in queries)


# ---------------------------------------------------------------- the router's liveliness token

def test_a_router_token_declared_and_withdrawn_by_another_is_no_outage(centre: Any) -> None:
    """Every client counts ``router_outages`` and logs 'router ... is gone' when a router token goes.
    A token under ``alive/router/`` that any session (unauthenticated) declared and withdrew was an
    outage at every service, though its router never went (the live hostile test sends such tokens).
    Now only the last router token going is: the link to its own router closed, which takes every
    token with it."""
    def token(name: str, kind: zenoh.SampleKind) -> None:
        centre._on_router(SimpleNamespace(key_expr=centre.keys.alive("router", name), kind=kind))

    token("router", zenoh.SampleKind.PUT)
    token("forged", zenoh.SampleKind.PUT)
    token("forged", zenoh.SampleKind.DELETE)
    assert centre._router_outages == 0 and centre._router_lost_at is None
    token("router", zenoh.SampleKind.DELETE)  # its own router's link closed
    assert centre._router_outages == 1 and centre._router_lost_at is not None
    token("router", zenoh.SampleKind.PUT)
    assert centre._router_lost_at is None

