"""Zenoh plumbing: sessions, the Service base class, and router + recorder as real processes.

Loopback only, multicast scouting off, every process and session is stopped in a
``finally`` with bounded timeouts.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh
from support import WAIT_S, feed, free_port, wait_until

from fedtrack.fusion_center.mtt.pictures import picture_window
from fedtrack.fusion_center.mtt.service import MttCentreService
from fedtrack.keys import Keys
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.service import MttLocalService
from fedtrack.local_filters.regions import load_regions
from fedtrack.services import publishing
from fedtrack.services.base import QueryHandler, Service, Subscription
from fedtrack.wire import (
    MAX_TRACKS,
    Detection,
    FusedTrack,
    Health,
    ManeuverEvent,
    Measurement,
    TrackPicture,
    decode,
    encode,
    measurement_to_replay,
)
from fedtrack.zsession import (
    SessionError,
    SessionOptions,
    alive_keys,
    close_session,
    make_config,
    open_session,
    wait_alive,
)

ROOT = Path(__file__).resolve().parents[1]




def spawn(args: list[str], log: Path) -> subprocess.Popen[bytes]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    with log.open("wb") as fh:
        return subprocess.Popen([sys.executable, "-m", "fedtrack.cli", "serve", *args], cwd=ROOT, env=env,
                                stdout=fh, stderr=subprocess.STDOUT)


def terminate(proc: subprocess.Popen[bytes], timeout: float = 5.0) -> int:
    """SIGTERM, then SIGKILL after ``timeout``; returns the exit code."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout)
    return int(proc.returncode)


def client(port: int, connect_timeout_s: float = 5.0) -> zenoh.Session:
    """A client session of the router on ``port``, waiting up to ``connect_timeout_s`` for it to listen."""
    return open_session(SessionOptions(connect=(f"tcp/127.0.0.1:{port}",), connect_timeout_s=connect_timeout_s))


def collect(session: zenoh.Session, key: str, msg_type: type) -> tuple[list[Any], Any]:
    """Subscribe to ``key``; returns the list the decoded messages are appended to, and the subscriber."""
    received: list[Any] = []
    sub = session.declare_subscriber(key, lambda s: received.append(decode(s.payload.to_bytes(), msg_type)))
    return received, sub


def measurement(sensor: str, seq: int, **kw: Any) -> Measurement:
    return Measurement(sensor=sensor, seq=seq, t=0.1 * seq, kind="position", z=np.array([seq, -1.0]),
                       R=np.eye(2), **kw)


def test_config_always_disables_scouting_and_shared_memory() -> None:
    cfg = make_config(SessionOptions(mode="router", connect=(), listen=("tcp/127.0.0.1:0",), lease_ms=1000))
    assert json.loads(cfg.get_json("scouting/multicast/enabled")) is False
    assert json.loads(cfg.get_json("transport/shared_memory/enabled")) is False
    assert json.loads(cfg.get_json("listen/endpoints")) == ["tcp/127.0.0.1:0"]
    assert json.loads(cfg.get_json("transport/link/tx/lease")) == 1000
    with pytest.raises(ValueError, match="invalid endpoint"):
        SessionOptions(connect=("127.0.0.1:7447",))
    with pytest.raises(ValueError, match="client needs"):
        SessionOptions(connect=())


def test_client_without_router_fails_after_its_timeout() -> None:
    start = time.monotonic()
    with pytest.raises(SessionError, match="cannot open a zenoh client session"):
        open_session(SessionOptions(connect=(f"tcp/127.0.0.1:{free_port()}",), connect_timeout_s=0.3))
    assert time.monotonic() - start < 5.0


def test_a_service_connecting_for_ever_stops_when_asked() -> None:
    """``serve ROLE --connect-timeout -1`` (wait for ever) with no router there: ``zenoh.open`` waited in native
    code, where the service's SIGTERM and Ctrl-C handlers never ran, and only SIGKILL ended it (tour61). Now the
    session opens in a thread of its own and a stop asked meanwhile (what the handlers do) ends ``run`` with 0."""
    from fedtrack.sensors.service import SensorService

    sensor = SensorService([{"t": 0.0}], 1.0, "lockstep", 1.0, 5.0, service_id="s1",
                           options=SessionOptions(connect=(f"tcp/127.0.0.1:{free_port()}",), connect_timeout_s=-1.0))
    codes: list[int] = []
    runner = threading.Thread(target=lambda: codes.append(sensor.run()), daemon=True)
    runner.start()
    sensor.stop()
    runner.join(WAIT_S)
    assert not runner.is_alive() and codes == [0] and sensor.session is None


def test_router_and_recorder_processes(tmp_path: Path) -> None:
    """A client publishes good and malformed payloads; the recorder writes the good ones in seq
    order and counts the bad one in its Health; both services exit 0 on SIGTERM."""
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    keys = Keys("t1")
    out = tmp_path / "rec"
    router = spawn(["router", "--listen", endpoint, "--deployment", "t1"], tmp_path / "router.log")
    recorder: subprocess.Popen[bytes] | None = None
    session: zenoh.Session | None = None
    try:
        recorder = spawn(["recorder", "--connect", endpoint, "--deployment", "t1", "--id", "rec",
                          "--health-period", "0.2", "--out", str(out)], tmp_path / "recorder.log")
        session = client(port, 20.0)  # the router's process still starting: 5 s ran out at a load of 30
        health, _health_sub = collect(session, keys.health("recorder", "rec"), Health)
        assert wait_alive(session, [keys.alive("recorder", "rec"), keys.alive("router", "router")], WAIT_S) == set()
        assert alive_keys(session, keys.alive()) == {keys.alive("recorder", "rec"), keys.alive("router", "router")}

        sonar = Measurement(sensor="b", seq=0, t=0.0, kind="sonar", z=np.zeros(0), R=np.eye(2),
                            detections=tuple(Detection(np.array([i, 2.0 * i]), 1.0 + i) for i in range(200)))
        assert len(encode(sonar)) > 3072  # large enough for zenoh's shared-memory path (disabled)
        track = FusedTrack(seq=0, t=0.0, model="cv", x=np.ones(4), P=np.eye(4), maneuver=False, degraded=True,
                           sensors=("a",), stamp_ns=5, extra={"existence": 0.5})
        feed(session, keys.sensor_meas("a"), encode(measurement("a", 1)))  # seq 1 before seq 0: reordered
        feed(session, keys.sensor_meas("a"), b"\x93not a message")
        feed(session, keys.sensor_meas("b"), encode(sonar))
        feed(session, keys.fusion_track(), encode(track))
        assert wait_until(lambda: bool(health) and health[-1].counters["received"] == 3
                          and health[-1].counters["rejected"] == 1), f"health: {health[-1:]}"

        assert terminate(recorder) == 0
        assert health[-1].status == "stopped"  # the final Health before exiting
        lines = [json.loads(x) for x in (out / "measurements.jsonl").read_text().splitlines()]
        assert [line["sensor"] for line in lines] == ["b", "a"]
        assert lines[0] == json.loads(json.dumps(measurement_to_replay(sonar)))
        assert lines[1] == {"t": 0.1, "sensor": "a", "z": [1.0, -1.0], "R": [[1.0, 0.0], [0.0, 1.0]]}
        tracks = [json.loads(x) for x in (out / "tracks.jsonl").read_text().splitlines()]
        assert tracks == [{"t": 0.0, "x": [1.0] * 4, "P": np.eye(4).tolist(), "model": "cv", "maneuver": False,
                           "degraded": True, "seq": 0, "sensors": ["a"], "existence": 0.5,
                           "event": None}]
        log = (tmp_path / "recorder.log").read_text()
        assert "rejected a message on fedtrack/t1/sensor/a/meas (14 bytes): payload: not valid msgpack" in log
        assert "Traceback" not in log
        assert wait_until(lambda: not alive_keys(session, keys.alive("recorder")), 3.0)
    finally:
        if session is not None:
            close_session(session)
        if recorder is not None:
            terminate(recorder)
        router_code = terminate(router)
    assert router_code == 0, (tmp_path / "router.log").read_text()


def test_cli_user_errors_are_clean(tmp_path: Path) -> None:
    bad = subprocess.run([sys.executable, "-m", "fedtrack.cli", "serve", "recorder", "--connect", "localhost:1",
                          "--out", str(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=30)
    assert bad.returncode == 2 and "--connect: invalid endpoint 'localhost:1'" in bad.stderr
    nobody = subprocess.run([sys.executable, "-m", "fedtrack.cli", "serve", "recorder", "--connect",
                             f"tcp/127.0.0.1:{free_port()}", "--connect-timeout", "0.3", "--out", str(tmp_path)],
                            cwd=ROOT, capture_output=True, text=True, timeout=30)
    assert nobody.returncode == 1 and "cannot open a zenoh client session" in nobody.stderr
    assert "Traceback" not in nobody.stderr


class Echo(Service):
    """Test service: answers fusion/state, turns measurements into events, fails on seq 99 (after
    changing ``last``, which the failure undoes)."""

    role = "echo"
    tick_period_s = 0.05
    state_attrs = ("last",)

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.ticks = 0
        self.stopped = False
        self.last: Measurement | None = None

    def subscriptions(self) -> list[Subscription]:
        return [Subscription(self.keys.sensor_meas(), Measurement, self.on_measurement)]

    def queryables(self) -> list[QueryHandler]:
        return [QueryHandler(self.keys.fusion_state(), self.state)]

    def on_measurement(self, msg: Measurement) -> None:
        self.last = msg
        if msg.seq == 99:
            raise ZeroDivisionError("boom")
        self.publish(self.keys.fusion_event(), ManeuverEvent(seq=msg.seq, t=msg.t, kind="onset", onset=msg.t,
                                                             u=msg.z, statistic=1.0))

    def state(self) -> FusedTrack | None:
        if self.last is None:
            return None
        return FusedTrack(seq=self.last.seq, t=self.last.t, model="cv", x=np.zeros(4), P=np.eye(4),
                          maneuver=False, degraded=False, sensors=(self.last.sensor,), stamp_ns=self.last.stamp_ns)

    def on_tick(self) -> None:
        self.ticks += 1

    def on_stop(self) -> None:
        self.stopped = True


def run_in_thread(service: Service) -> tuple[threading.Thread, list[int]]:
    code: list[int] = []
    thread = threading.Thread(target=lambda: code.append(service.run()), daemon=True)
    thread.start()
    return thread, code


def query_state(session: zenoh.Session, keys: Keys) -> list[FusedTrack]:
    return [decode(r.ok.payload.to_bytes(), FusedTrack) for r in session.get(keys.fusion_state(), timeout=2.0)
            if r.ok is not None]


def test_service_handlers_queryable_ticks_and_a_failing_handler() -> None:
    port = free_port()
    keys = Keys("t2")
    router = open_session(SessionOptions(mode="router", connect=(), listen=(f"tcp/127.0.0.1:{port}",)))
    session: zenoh.Session | None = None
    service = Echo(service_id="e1", options=SessionOptions(connect=(f"tcp/127.0.0.1:{port}",)),
                   deployment="t2", health_period_s=0.1)
    thread, code = run_in_thread(service)
    try:
        session = client(port)
        events, _sub = collect(session, keys.fusion_event(), ManeuverEvent)
        assert wait_alive(session, [keys.alive("echo", "e1")], WAIT_S) == set()
        assert query_state(session, keys) == []  # handler returned None: no reply
        feed(session, keys.sensor_meas("s1"), encode(measurement("s1", 3, stamp_ns=42)))
        assert wait_until(lambda: len(events) == 1)
        assert events[0].seq == 3 and events[0].u.tolist() == [3.0, -1.0]
        state = query_state(session, keys)
        assert len(state) == 1 and state[0].seq == 3 and state[0].stamp_ns == 42
        assert service.counters["published"] == 1 and service.counters["received"] == 1
        assert wait_until(lambda: service.ticks > 0)

        feed(session, keys.sensor_meas("s1"), encode(measurement("s1", 99)))
        # a handler error rejects the message (counted, logged), undoes its changes, and the service goes on
        assert wait_until(lambda: service.counters.get("rejected_handler_error") == 1)
        assert service.last is not None and service.last.seq == 3 and service.counters["rejected"] == 1
        feed(session, keys.sensor_meas("s1"), encode(measurement("s1", 4)))
        assert wait_until(lambda: len(events) == 2) and events[1].seq == 4
        assert alive_keys(session, keys.alive("echo", "e1")) and not code
    finally:
        service.stop()
        thread.join(WAIT_S)
        if session is not None:
            close_session(session)
        close_session(router)


class PlainEcho(Echo):
    """Echo that also publishes a FusedTrack per measurement, its events on a plain publisher."""

    role = "plainecho"

    def plain_outputs(self) -> tuple[str, ...]:
        return (self.keys.fusion_event(),)

    def on_measurement(self, msg: Measurement) -> None:
        super().on_measurement(msg)
        track = self.state()
        assert track is not None
        self.publish(self.keys.fusion_track(), track)


@contextmanager
def served(make: Callable[[SessionOptions], Service]) -> Iterator[tuple[zenoh.Session, Service]]:
    """A router on a free port, a client session, and the service ``make(options)`` running in a
    thread and announced; all stopped and closed afterwards."""
    port = free_port()
    router = open_session(SessionOptions(mode="router", connect=(), listen=(f"tcp/127.0.0.1:{port}",)))
    session = client(port)
    service = make(SessionOptions(connect=(f"tcp/127.0.0.1:{port}",)))
    thread, _code = run_in_thread(service)
    try:
        assert wait_alive(session, [service.keys.alive(service.role, service.id)], WAIT_S) == set()
        yield session, service
    finally:
        service.stop()
        thread.join(WAIT_S)
        close_session(session)
        close_session(router)


def late_history(session: zenoh.Session, key: str, convert: Callable[[zenoh.Sample], Any],
                 expected: Callable[[list[Any]], bool]) -> list[Any]:
    """What a subscriber declared now with history gets of ``key``: the publishers' caches, once ``expected``
    holds of what came, and what more comes in 0.5 s after that. Before, what was not in 0.5 s after the first
    reply was taken as not coming: at a load of 30, 5 of a region's 13 cached pictures of two parts had come."""
    late: list[Any] = []
    hist = zenoh.ext.declare_advanced_subscriber(session, key, lambda s: late.append(convert(s)),
                                                 history=zenoh.ext.HistoryConfig(detect_late_publishers=True))
    try:
        assert wait_until(lambda: expected(list(late)), timeout=30.0), late
        time.sleep(0.5)  # nothing more comes
        return list(late)
    finally:
        hist.undeclare()


def test_plain_outputs_are_published_without_a_cache() -> None:
    """A key in ``plain_outputs`` reaches a live subscriber but is not kept for a late one with
    history; the service's other keys are (the advanced publisher's cache)."""
    keys = Keys("t5")
    with served(lambda options: PlainEcho(service_id="p1", options=options, deployment="t5")) as (session, service):
        live, _sub = collect(session, keys.fusion_event(), ManeuverEvent)
        for seq in (1, 2):
            feed(session, keys.sensor_meas("s1"), encode(measurement("s1", seq)))
        assert wait_until(lambda: len(live) == 2 and service.counters["published"] == 4)
        late = late_history(session, keys.fusion_track().rsplit("/", 1)[0] + "/*", lambda s: str(s.key_expr),
                            lambda got: got.count(keys.fusion_track()) >= 2)
        assert late.count(keys.fusion_track()) == 2 and keys.fusion_event() not in late


class Grower(Echo):
    """Echo that also publishes, per measurement ``seq`` of s1, a scan of ``100 seq`` detections."""

    role = "grower"

    def subscriptions(self) -> list[Subscription]:
        return [Subscription(self.keys.sensor_meas("s1"), Measurement, self.on_measurement)]

    def on_measurement(self, msg: Measurement) -> None:
        self.publish(self.keys.sensor_meas("g"), Measurement(
            sensor="g", seq=msg.seq, t=msg.t, kind="scan", z=np.zeros(0), R=np.eye(2),
            detections=tuple((np.full(2, float(i)), 0.0) for i in range(100 * msg.seq)), stamp_ns=1))
        self.last = msg  # once published: a test waiting for it finds the scan in the cache


def test_a_cache_outgrown_by_its_messages_keeps_about_cache_bytes_of_the_latest(monkeypatch: pytest.MonkeyPatch) -> None:
    """An advanced publisher keeps ``cache_depth`` messages: once they grow (a picture from a few
    tracks to thousands) it is declared again with a smaller cache, and a late subscriber with
    history gets the latest messages, as many as fit in about CACHE_BYTES."""
    monkeypatch.setattr(publishing, "CACHE_BYTES", 40_000)
    monkeypatch.setattr(publishing, "MIN_CACHE_SAMPLES", 3)
    keys = Keys("t6")
    with served(lambda options: Grower(service_id="g1", options=options, deployment="t6")) as (session, service):
        feed(session, keys.sensor_meas("s1"), encode(measurement("s1", 0)))  # an empty scan: a deep cache
        assert wait_until(lambda: keys.sensor_meas("g") in service._publishers)
        small = service._publishers[keys.sensor_meas("g")][1]
        for seq in range(5, 11):  # 500-1,000 detections: about 20-40 kB each
            feed(session, keys.sensor_meas("s1"), encode(measurement("s1", seq)))
        assert wait_until(lambda: service.last is not None and service.last.seq == 10)  # type: ignore[attr-defined]
        depth = service._publishers[keys.sensor_meas("g")][1]
        assert small > 2 * depth and depth == 3  # 40 kB of 20-40 kB scans: the floor
        late = late_history(session, keys.sensor_meas("g"), lambda s: decode(s.payload.to_bytes(), Measurement).seq,
                            lambda got: len(got) >= depth)
        assert late == list(range(11 - depth, 11))


class RegionPictures(Echo):
    """Echo that publishes, per measurement ``seq`` of s1, region x0y0's picture at ``t = seq`` of
    ``seq`` tracks, on a region centre's windowed publisher (``[mtt] period`` 1 s, real time)."""

    role = "regionpictures"
    cfg, speed = MttConfig(), 1.0  # what MttCentreService.windowed_outputs reads
    windowed_outputs = MttCentreService.windowed_outputs

    def on_measurement(self, msg: Measurement) -> None:
        n = msg.seq
        self.publish(self.keys.region_picture("x0y0"), TrackPicture(
            seq=msg.seq, t=float(msg.seq), ids=tuple(range(n)), x=np.ones((n, 4)), P=np.tile(np.eye(4), (n, 1)),
            confirmed=(True,) * n, sensors=(("s1", "s2"),) * n, fused_sensors=(), fused_seqs=(), stamp_ns=1))
        self.last = msg


def test_a_region_centre_keeps_its_last_picture_window_of_pictures() -> None:
    """A region picture's advanced publisher keeps the last ``picture_window`` pictures (13 at 1 s, real
    time), in their parts: a late subscriber with history (a restarted ``serve picture``) gets exactly
    those, once they grow to 2 parts too, so that the cache holds at most 13 pictures' bytes (not
    CACHE_BYTES: 64 MiB)."""
    keys = Keys("t7")
    window = picture_window(1.0, 1.0)
    with served(lambda options: RegionPictures(service_id="r1", options=options, deployment="t7")) as (session, svc):
        service: RegionPictures = svc  # type: ignore[assignment]
        def upto(seqs: range, parts: int) -> list[tuple[int, int]]:
            for seq in seqs:
                feed(session, keys.sensor_meas("s1"), encode(measurement("s1", seq)))
            assert wait_until(lambda: service.last is not None and service.last.seq == seqs[-1])
            return late_history(session, keys.region_picture("x0y0"),
                                lambda s: (decode(s.payload.to_bytes(), TrackPicture), len(s.payload.to_bytes())),
                                lambda got: len(got) >= parts * window)
        late = upto(range(1, 21), 1)
        assert [m.seq for m, _ in late] == list(range(21 - window, 21)) and window == 13
        big = MAX_TRACKS + 1  # two parts a picture from here on: the cache is declared again, 26 parts deep
        late = upto(range(big, big + 20), 2)
        assert service._publishers[keys.region_picture("x0y0")][1] == 2 * window
        assert sorted({m.seq for m, _ in late}) == list(range(big + 20 - window, big + 20)) and len(late) == 2 * window
        largest = sum(size for m, size in late if m.seq == big + 19)
        assert sum(size for _, size in late) <= window * largest


def test_no_plain_output_is_read_from_a_cache() -> None:
    """The outputs the multi-target centre and trackers publish without a cache are none of the
    keys that services read with history or recovery (the recorder's, the single-target filters'
    and fusion center's), and they cover the centre's answers and hand-overs; the region pictures,
    which ``serve picture`` reads with history, keep a window of them."""
    from types import SimpleNamespace

    from fedtrack.fusion_center.service import FusionCenterService
    from fedtrack.local_filters.mtt.service import MttLocalService
    from fedtrack.local_filters.service import LocalFilterService
    from fedtrack.services.recorder import Recorder

    keys = Keys("d")
    me = SimpleNamespace(keys=keys, sensor="s1", mode="federated", on_message=print, on_estimate=None,
                         on_measurement=None, on_reset=None)  # the services' attributes their methods read
    plain = [zenoh.KeyExpr(k) for k in MttCentreService.plain_outputs(me) + MttLocalService.plain_outputs(me)]
    read = [sub.key for subs in (Recorder.subscriptions(me), FusionCenterService.subscriptions(me),
                                 LocalFilterService.subscriptions(me)) for sub in subs if sub.history or sub.recover]
    assert keys.mtt_picture() in read and keys.sensor_meas("s1") in read
    assert not [(str(p), k) for p in plain for k in read if p.intersects(zenoh.KeyExpr(k))]
    for output in (keys.mtt_resets("s1"), keys.region_resets("x0y0", "s1"), keys.region_handover("x1y0", "x0y0"),
                   keys.mtt_report("s1"), keys.region_report("x0y0", "s1")):
        assert any(p.includes(zenoh.KeyExpr(output)) for p in plain), output
    assert not any(p.intersects(zenoh.KeyExpr(keys.region_picture("x0y0"))) for p in plain)


def test_a_multi_target_tracker_recovers_its_sensors_scans_from_the_sensors_cache() -> None:
    """The multi-target tracker reads its sensor's scans with recovery, as the single-target local filter
    does: scans published while the router's link was down come from the sensor's cache when it is back
    (before 2026-11-27 two router outages of 1.5 s lost 20 of 128 scans at the trackers, live)."""
    from types import SimpleNamespace

    from fedtrack.local_filters.mtt.service import MttLocalService

    keys = Keys("d")
    for regions, federated in ((None, True), (None, False), (object(), True)):
        me = SimpleNamespace(keys=keys, sensor="s1", regions=regions, federated=federated, on_scan=None,
                             on_answer=None, on_resets=None)
        assert [sub.key for sub in MttLocalService.subscriptions(me) if sub.recover] == [keys.sensor_meas("s1")]


def test_service_stop_is_clean_and_publishes_final_health() -> None:
    port = free_port()
    keys = Keys("t3")
    router = open_session(SessionOptions(mode="router", connect=(), listen=(f"tcp/127.0.0.1:{port}",)))
    session = client(port)
    service = Echo(service_id="e2", options=SessionOptions(connect=(f"tcp/127.0.0.1:{port}",)), deployment="t3")
    health, _sub = collect(session, keys.health("echo", "e2"), Health)
    thread, code = run_in_thread(service)
    try:
        assert wait_alive(session, [keys.alive("echo", "e2")], WAIT_S) == set()
        feed(session, keys.sensor_meas("s1"), encode(measurement("s1", 1))[:-3])  # truncated payload
        assert wait_until(lambda: service.counters["rejected"] == 1)
        service.stop()
        thread.join(WAIT_S)
        assert code == [0] and service.stopped
        assert wait_until(lambda: bool(health) and health[-1].status == "stopped")
        assert health[-1].counters["rejected"] == 1 and health[-1].counters["received"] == 0
    finally:
        service.stop()
        thread.join(WAIT_S)
        close_session(session)
        close_session(router)


def test_recorder_with_unusable_output_exits_2(tmp_path: Path) -> None:
    from fedtrack.services.recorder import Recorder

    port = free_port()
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("")
    router = open_session(SessionOptions(mode="router", connect=(), listen=(f"tcp/127.0.0.1:{port}",)))
    try:
        recorder = Recorder(db=blocker / "r.db", out=blocker, service_id="r", options=SessionOptions(connect=(f"tcp/127.0.0.1:{port}",)))
        assert recorder.run() == 2 and recorder.status == "failed"
    finally:
        close_session(router)


def test_a_tracker_knows_which_regions_its_sub_reports_reach(tmp_path: Path) -> None:
    """A region deployment's ``mtt-local`` declares its sub-reports' publishers at its start, so that
    Zenoh's matching status says by its first report whether anything (a region's centre or standby)
    takes a region's sub-reports: a region none reaches is not waited for (``unreached``)."""
    config = tmp_path / "regions.toml"
    config.write_text("[regions]\nmargin = 500.0\n"
                      "grid = {origin = [-5000.0, -5000.0], cell = [5000.0, 10000.0], nx = 2, ny = 1}\n")
    regions = load_regions(config)
    keys = Keys("t8")
    with served(lambda options: MttLocalService("s1", True, MttConfig(), regions=regions, service_id="s1",
                                                options=options, deployment="t8")) as (session, svc):
        tracker: MttLocalService = svc  # type: ignore[assignment]
        x0, x1 = keys.region_report("x0y0", "s1"), keys.region_report("x1y0", "s1")
        assert not tracker.reaches(x0) and not tracker.reaches(x1)
        centre = session.declare_subscriber(keys.region_report("x0y0"), lambda sample: None)
        assert wait_until(lambda: tracker.reaches(x0), 2.0) and not tracker.reaches(x1)
        centre.undeclare()
        assert wait_until(lambda: not tracker.reaches(x0), 2.0)
