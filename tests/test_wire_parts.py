"""Messages beyond the per-message bounds go in parts and come back whole: ``wire.parts`` / ``wire.join``
(docs/wire.md, "Messages in parts"), with the bounds made small (MAX_TRACKS = 4, MAX_DETECTIONS = 3)."""

from __future__ import annotations

import json
import sqlite3
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pytest
import zenoh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support import WAIT_S, feed, free_port, wait_until

from fedtrack import wire
from fedtrack.jsonl import InputError
from fedtrack.keys import Keys
from fedtrack.recording import Recording
from fedtrack.services.base import Service, Subscription
from fedtrack.services.reassembly import Reassembly
from fedtrack.services.recorder import Recorder
from fedtrack.wire import (
    FusedTrack,
    Measurement,
    TrackPicture,
    TrackReport,
    TrackResets,
    WireError,
    decode,
    encode,
    join,
    parts,
    payloads,
)
from fedtrack.zsession import SessionOptions, close_session, open_session, wait_alive
from tests.support import patch_wire
from tests.test_wire import assert_same

SMALL_TRACKS, SMALL_DETECTIONS = 4, 3
SIZES = st.sampled_from([0, 1, 3, 4, 5, 8, 9, 13])  # 0, 1, the limits, limit + 1, several parts


@pytest.fixture(autouse=True)
def small_limits(monkeypatch: pytest.MonkeyPatch) -> None:
    patch_wire(monkeypatch, "MAX_TRACKS", SMALL_TRACKS)
    patch_wire(monkeypatch, "MAX_DETECTIONS", SMALL_DETECTIONS)


def spd_stack(rng: np.random.Generator, n: int, d: int) -> np.ndarray:
    a = rng.normal(size=(n, d, d))
    return (a @ np.swapaxes(a, 1, 2) + d * np.eye(d)).reshape(n * d, d)


def subset(rng: np.random.Generator, n: int) -> tuple[int, ...]:
    return tuple(np.flatnonzero(rng.random(n) < 0.4).tolist())


def make_scan(n: int, seed: int) -> Measurement:
    rng = np.random.default_rng(seed)
    return Measurement(sensor="s3", seq=7, t=0.5, kind="scan", z=np.zeros(0), R=spd_stack(rng, 1, 2),
                       detections=tuple((rng.normal(size=2), float(rng.random())) for _ in range(n)), stamp_ns=11)


def make_report(n: int, seed: int) -> TrackReport:
    rng = np.random.default_rng(seed)
    detected = tuple(bool(b) for b in rng.random(n) < 0.6)
    k, m, d = sum(detected), 2, 4
    return TrackReport(sensor="s2", seq=11, t=1.1, ids=tuple(range(100, 100 + n)), x=rng.normal(size=(n, d)),
                       P=spd_stack(rng, n, d), confirmed=tuple(bool(b) for b in rng.random(n) < 0.5),
                       detected=detected, obs_H=rng.normal(size=(k * m, d)), obs_R=spd_stack(rng, k, m),
                       obs_z=rng.normal(size=(k, m)), started=tuple(bool(b) for b in rng.random(k) < 0.3),
                       retired=tuple(range(1, 1 + int(rng.integers(0, 9)))), stamp_ns=23, contested=(3,),
                       existence=rng.random(n) if seed % 2 else None,
                       elsewhere=tuple(bool(b) for b in rng.random(n) < 0.5) if seed % 3 == 0 else ())


def make_resets(n: int, seed: int) -> TrackResets:
    rng = np.random.default_rng(seed)
    moved = tuple(range(50, 50 + int(rng.integers(0, 7))))
    return TrackResets(sensor="s2", seq=11, t=1.1, q_scale=3.0, ids=tuple(range(n)), x=rng.normal(size=(n, 4)),
                       P=spd_stack(rng, n, 4), region="r1", held=tuple(range(200, 200 + int(rng.integers(0, 9)))),
                       moved=moved, moved_to=tuple(f"r{i % 3}" for i in range(len(moved))))


def make_picture(n: int, seed: int) -> TrackPicture:
    rng = np.random.default_rng(seed)
    f = int(rng.integers(0, 10))
    maneuvering = subset(rng, n) if seed % 3 else ()
    in_flight = subset(rng, n)
    left = subset(rng, f)
    handovers = tuple(i for i in subset(rng, f) if i not in left)
    return TrackPicture(seq=3, t=3.0, ids=tuple(range(5, 5 + n)), x=rng.normal(size=(n, 4)), P=spd_stack(rng, n, 4),
                        confirmed=tuple(bool(b) for b in rng.random(n) < 0.5),
                        sensors=tuple(tuple(f"s{j}" for j in range(i % 3)) for i in range(n)),
                        fused_sensors=tuple(f"s{i % 2}" for i in range(f)), fused_seqs=tuple(range(f)), stamp_ns=25,
                        ca=tuple(bool(b) for b in rng.random(n) < 0.5) if seed % 2 else (),
                        maneuvering=maneuvering,
                        maneuver=rng.normal(size=(len(maneuvering), 4)) if seed % 3 else None,
                        existence=rng.random(n) if seed % 2 else None,
                        lla=np.column_stack([rng.uniform(-90, 90, n), rng.uniform(-180, 180, n), rng.normal(size=n)])
                        if seed % 5 == 0 else None,
                        contested=bool(seed % 2), left=left, handovers=handovers,
                        regions=tuple(f"r{i % 2}" for i in range(f)) if seed % 3 == 0 else (),
                        in_flight=in_flight, in_flight_t=tuple(float(i) for i in range(len(in_flight))))


MAKERS = {"scan": (make_scan, SMALL_DETECTIONS), "report": (make_report, SMALL_TRACKS),
          "resets": (make_resets, SMALL_TRACKS), "picture": (make_picture, SMALL_TRACKS)}


@pytest.mark.fuzz
@pytest.mark.parametrize("kind", MAKERS)
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(n=SIZES, seed=st.integers(0, 2**16))
def test_join_of_parts_is_the_message_and_every_part_is_a_valid_message(kind: str, n: int, seed: int) -> None:
    make, limit = MAKERS[kind]
    msg = make(n, seed)
    split = parts(msg)
    biggest = max(n, *(len(getattr(msg, items.fields[0])) for items in type(msg)._items))
    assert len(split) == max(1, -(-biggest // limit))
    if len(split) == 1:
        assert split[0] is msg and b"parts" not in encode(msg)  # today's message, today's bytes
    for j, part in enumerate(split):
        back = decode(encode(part), type(msg))  # within every per-message bound
        assert_same(back, part)
        assert (back.part, back.parts) == ((j, len(split)) if len(split) > 1 else (0, 1))
    whole = join([decode(encode(p), type(msg)) for p in reversed(split)])
    assert_same(whole, msg)


def test_a_message_beyond_a_bound_is_refused_whole_and_sent_in_parts() -> None:
    msg = make_picture(9, 1)
    with pytest.raises(WireError, match=r"^TrackPicture.ids: 9 items exceed the limit of 4 per message"):
        encode(msg)
    assert [p.parts for p in parts(msg)] == [3, 3, 3]
    assert [len(p.ids) for p in parts(msg)] == [3, 3, 3]


def test_a_message_over_the_payload_bytes_is_split_by_size(monkeypatch: pytest.MonkeyPatch) -> None:
    msg = next(m for m in (make_picture(4, s) for s in range(2, 99)) if len(m.fused_seqs) <= 4)  # within the counts
    patch_wire(monkeypatch, "MAX_PAYLOAD_BYTES", len(encode(msg)) * 2 // 3)
    split = parts(msg)
    assert len(split) >= 2 and all(len(encode(p)) <= wire.MAX_PAYLOAD_BYTES for p in split)
    assert_same(join(list(split)), msg)


def test_a_message_needing_more_than_max_parts_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    msg = make_report(9, 1)
    patch_wire(monkeypatch, "MAX_PARTS", 2)
    with pytest.raises(WireError, match=r"^TrackReport: does not fit in MAX_PARTS = 2 messages"):
        parts(msg)


def replaced(msg: Any, **changes: Any) -> Any:
    return type(msg).unchecked(**{**vars(msg), **changes})


@pytest.mark.security
def test_join_rejects_parts_that_are_not_one_message() -> None:
    split = list(parts(make_report(9, 3)))  # 3 parts
    cases = [
        ([split[0], split[2]], "TrackReport.part", "part 1 of 3 missing"),
        ([split[0], split[1], split[1], split[2]], "TrackReport.part", "part 1 of 3 repeated"),
        ([split[0], split[1]], "TrackReport.part", "part 2 of 3 missing"),
        ([split[0], replaced(split[1], t=9.9), split[2]], "TrackReport.t", "differs between parts 0 and 1"),
        ([split[0], replaced(split[1], sensor="s9"), split[2]], "TrackReport.sensor", "differs"),
        ([split[0], replaced(split[1], parts=4), split[2]], "TrackReport.parts", "parts differ: 3 and 4"),
        ([replaced(p, parts=65) for p in split], "TrackReport.parts", "must be at most 64"),
        ([split[0], replaced(split[1], existence=None), split[2]], "TrackReport.existence",
         "absent in some parts"),
        ([split[0], replaced(split[1], ids=split[0].ids), split[2]], "TrackReport.ids", "not unique"),
        ([split[0], make_picture(1, 1), split[2]], "TrackReport.type", "a part of type TrackPicture"),
    ]
    for given_parts, field, reason in cases:
        with pytest.raises(WireError, match=reason) as err:
            join(given_parts)
        assert err.value.field == field
    with pytest.raises(WireError, match=r"parts: must be in \[1, 64\], got 65"):
        decode(encode(replaced(split[0], parts=65)), TrackReport)
    with pytest.raises(WireError, match=r"part: must be below parts \(3\), got 3"):
        decode(encode(replaced(split[0], part=3)), TrackReport)


@pytest.mark.security
def test_decode_holds_a_payload_to_the_per_message_bounds(monkeypatch: pytest.MonkeyPatch) -> None:
    whole_scan, whole_report = make_scan(5, 1), make_report(7, 1)
    scan = encode(Measurement.unchecked(**{**vars(whole_scan), "detections": whole_scan.detections[:3]}))
    report = encode(parts(whole_report)[1])  # 4 tracks (3 in the first part)
    assert len(decode(scan, Measurement).detections) == 3 and len(decode(report, TrackReport).ids) == 4
    patch_wire(monkeypatch, "MAX_DETECTIONS", 2)
    patch_wire(monkeypatch, "MAX_TRACKS", 3)
    with pytest.raises(WireError, match=r"^Measurement.detections: 3 items exceed the limit of 2$"):
        decode(scan, Measurement)
    with pytest.raises(WireError, match=r"^TrackReport.ids: 4 items exceed the limit of 3 per message$"):
        decode(report, TrackReport)


# ---------------------------------------------------------------- over Zenoh: Service publishes parts, receives whole

class Collector(Service):
    """Keeps every picture and scan its handlers get."""

    role = "collector"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.pictures: list[TrackPicture] = []
        self.scans: list[Measurement] = []

    def subscriptions(self) -> list[Subscription]:
        return [Subscription(self.keys.mtt_picture(), TrackPicture, self.pictures.append),
                Subscription(self.keys.sensor_meas(), Measurement, self.scans.append)]


class Splitter(Service):
    """Publishes ``picture`` whenever a FusedTrack comes."""

    role = "splitter"

    def __init__(self, picture: TrackPicture, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.picture = picture

    def subscriptions(self) -> list[Subscription]:
        return [Subscription(self.keys.fusion_track(), FusedTrack, lambda _: self.publish(self.keys.mtt_picture(),
                                                                                         self.picture))]


@contextmanager
def deployment(*services: Service) -> Iterator[zenoh.Session]:
    """A router on a free loopback port, ``services`` (made for it by name) running in threads, and a client session."""
    port = free_port()
    router = open_session(SessionOptions(mode="router", connect=(), listen=(f"tcp/127.0.0.1:{port}",)))
    options = SessionOptions(connect=(f"tcp/127.0.0.1:{port}",))
    threads = []
    session = None
    try:
        for service in services:
            service.options = options
            threads.append(threading.Thread(target=service.run, daemon=True))
            threads[-1].start()
        session = open_session(options)
        keys = Keys("parts")
        assert wait_alive(session, [keys.alive(s.role, s.id) for s in services], WAIT_S) == set()
        yield session
    finally:
        for service in services:
            service.stop()
        for thread in threads:
            thread.join(WAIT_S)
        if session is not None:
            close_session(session)
        close_session(router)


def service(cls: type[Service], **kwargs: Any) -> Any:
    return cls(service_id="one", options=SessionOptions(connect=("tcp/127.0.0.1:1",)), deployment="parts",
               health_period_s=0.1, **kwargs)


def test_a_service_publishes_parts_and_a_subscriber_gets_the_message_once_whole() -> None:
    picture = make_picture(13, 5)  # 4 parts
    collector, splitter = service(Collector), service(Splitter, picture=picture)
    scan = make_scan(7, 2)
    with deployment(collector, splitter) as session:
        keys = Keys("parts")
        feed(session, keys.fusion_track(), encode(FusedTrack(seq=1, t=1.0, model="cv", x=np.zeros(4), P=np.eye(4),
                                                           maneuver=False, degraded=False, sensors=(), stamp_ns=1)))
        for payload in reversed(payloads(scan)):  # any order
            feed(session, keys.sensor_meas("s3"), payload)
        assert wait_until(lambda: len(collector.pictures) == 1 and len(collector.scans) == 1)
        time.sleep(0.3)  # nothing more comes
        assert len(collector.pictures) == 1 and len(collector.scans) == 1
        assert_same(collector.pictures[0], picture)
        assert_same(collector.scans[0], scan)
        assert splitter.counters["published"] == 1 and collector.counters["received"] == 2
        assert collector.counters["rejected"] == 0 and not collector._reassembly.pending


@pytest.mark.security
def test_hostile_parts_are_dropped_and_counted_within_the_bounds() -> None:
    collector = service(Collector)
    with deployment(collector) as session:
        keys, put = Keys("parts"), session.put
        reassembly = collector._reassembly
        counters = collector.counters
        # a flood of first parts, each of another message: at most MAX_PENDING_PER_STREAM held a stream
        first = [payloads(replaced(make_picture(9, 1), seq=seq))[0] for seq in range(40)]
        reassembly.max_bytes = 5 * len(first[0])
        for payload in first:
            put(keys.mtt_picture(), payload)
        assert wait_until(lambda: counters.get("parts_incomplete", 0) == 38)
        assert len(reassembly.pending) == 2 and reassembly.held_bytes == 2 * len(first[0])
        # ... of many senders: each held or evicted, within the held bytes
        for i in range(30):
            put(keys.sensor_meas(f"x{i}"), payloads(replaced(make_scan(7, i), sensor=f"x{i}"))[0])
        assert wait_until(lambda: counters.get("parts_incomplete", 0) + len(reassembly.pending) == 70)
        assert reassembly.held_bytes <= reassembly.max_bytes and counters["parts_incomplete"] > 38
        # a message that never completes goes after the timeout
        reassembly.timeout_s = 0.3
        assert wait_until(lambda: not reassembly.pending and reassembly.held_bytes == 0)
        assert counters["parts_incomplete"] == 70 and collector.pictures == collector.scans == []
        reassembly.timeout_s, reassembly.max_bytes = 60.0, 10**9
        # a repeated part is a duplicate; a different one with its index, or parts that do not join, rejected
        good = payloads(make_scan(7, 3))
        bad = payloads(replaced(make_scan(7, 3), t=9.0))
        for payload in (good[0], good[0], bad[0], bad[1]):
            put(keys.sensor_meas("s3"), payload)
        assert wait_until(lambda: counters.get("duplicate") == 1 and counters.get("rejected_parts") == 1)
        put(keys.sensor_meas("s3"), bad[2])  # parts 0 (good), 1, 2 (bad): Measurement.t differs
        assert wait_until(lambda: counters.get("rejected_parts") == 2 and not reassembly.pending)
        assert collector.scans == [] and counters["rejected"] == 2
        # an older message still incomplete when a newer one of its stream completes is dropped
        older = payloads(replaced(make_scan(7, 1), seq=5))
        put(keys.sensor_meas("s3"), older[0])
        for payload in payloads(replaced(make_scan(7, 1), seq=6)):
            put(keys.sensor_meas("s3"), payload)
        assert wait_until(lambda: len(collector.scans) == 1 and counters["parts_incomplete"] == 71)
        assert collector.scans[0].seq == 6 and not reassembly.pending


@pytest.mark.security
def test_a_sender_flooding_parts_evicts_its_own_messages_not_another_streams() -> None:
    """Beyond the bytes held, the stream holding the most loses its oldest message: a genuine
    picture in assembly survives a flood of another sender's parts and completes."""
    counts: dict[str, int] = {}
    reassembly = Reassembly(lambda name: counts.__setitem__(name, counts.get(name, 0) + 1))
    genuine = payloads(make_picture(9, 1))  # 3 parts
    flood = [payloads(replaced(make_scan(13, 2), seq=seq)) for seq in range(10)]  # 5 parts each
    reassembly.max_bytes = len(genuine[0]) + 4 * len(flood[0][0])
    reassembly.add("picture", decode(genuine[0], TrackPicture), genuine[0], 0.0)
    for parts_of in flood:
        for payload in parts_of[:4]:  # never the last part
            assert reassembly.add("s3", decode(payload, Measurement), payload, 0.0) is None
    assert reassembly.held_bytes <= reassembly.max_bytes and counts["parts_incomplete"] >= 9
    assert all(k[0] == "s3" for k in list(reassembly.pending)[1:])
    for payload in genuine[1:]:
        whole = reassembly.add("picture", decode(payload, TrackPicture), payload, 0.0)
    assert whole is not None
    assert_same(whole[0], make_picture(9, 1))


def test_the_recorder_stores_each_part_and_gives_the_picture_whole(tmp_path: Path) -> None:
    """Over Zenoh: a split picture and scan reach the recorder as parts, a row each; ``messages``
    and ``export`` give them joined; a message missing a part is left out and counted."""
    picture = make_picture(13, 5)
    db = tmp_path / "rec.db"
    recorder = service(Recorder, db=db)
    splitter = service(Splitter, picture=picture)
    scan = make_scan(7, 2)
    with deployment(recorder, splitter) as session:
        keys = Keys("parts")
        feed(session, keys.fusion_track(), encode(FusedTrack(seq=1, t=1.0, model="cv", x=np.zeros(4), P=np.eye(4),
                                                           maneuver=False, degraded=False, sensors=(), stamp_ns=1)))
        for payload in payloads(scan):
            feed(session, keys.sensor_meas("s3"), payload)
        lone = payloads(replaced(make_scan(7, 3), seq=8))[0]  # a scan whose other parts never come
        feed(session, keys.sensor_meas("s3"), lone)
        feed(session, keys.sensor_meas("s3"), lone)
        assert wait_until(lambda: recorder.counters.get("pictures_recorded") == 4
                          and recorder.counters.get("measurements_recorded") == 4)
        assert wait_until(lambda: recorder.counters.get("duplicate") == 1)
    rec = Recording(db, readonly=True)
    try:
        assert rec.db.execute("SELECT part, parts FROM pictures ORDER BY part").fetchall() == [(j, 4) for j in range(4)]
        [whole] = rec.messages(TrackPicture, "seq")
        assert_same(whole, picture)
        [joined] = rec.messages(Measurement, "t, id")
        assert_same(joined, scan)
        assert rec.incomplete == 1  # the lone part
        out, tracks = tmp_path / "m.jsonl", tmp_path / "t.jsonl"
        assert rec.export(out, tracks)[1] == 1
        assert len(json.loads(tracks.read_text())["tracks"]) == 13
        [unlisted] = (tmp_path / "unprocessed.jsonl").read_text().splitlines()  # the picture lists no scan of s3
        assert len(json.loads(unlisted)["detections"]) == 7
    finally:
        rec.close()
    con = sqlite3.connect(db)
    con.execute("UPDATE meta SET value = '1' WHERE key = 'schema_version'")
    con.commit()
    con.close()
    with pytest.raises(InputError, match=r"rec.db: recording schema version 1, expected 2 \(written before messages "
                                         r"in parts"):
        Recording(db)  # read, but never written (tests/test_recorder.py)
