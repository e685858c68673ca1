"""Fuzzing every decoder and handler of every service with a fast seeded mutation generator over
valid encodings: at least 10,000 payloads per message type, 0 escapes.

The paper pipeline, the multi-target deployment and its region centres (their ``HandOver`` s) run
in-process on the bus of
``test_hostile_messages`` (each service through its own dispatch: bounded decode, sender check,
guarded handler). After each genuine message, mutations of it (10,000 per type in all) are published on
its key, so they reach every service subscribed to it (a measurement: the local filter, the IMM
tracker and the recorder) in a state where the genuine one was plausible (the multi-target scans:
2,000 more measurements). A mutation is one of:
a field (at any depth) replaced by a hostile value (nesting 9 to 1,000 deep, 2,049-item lists,
5,000-character strings, NaN, infinity, 1e308, 2^64 - 1, wrong types, malformed array maps,
extension types); an array's values scaled by up to 1e+-300 or one value made extreme; ``seq`` or
``t`` moved (by up to 1e12); or the bytes flipped, cut or extended. Health (which no service
subscribes to; the launcher's monitor decodes it), the fusion centre's snapshot file and the
liveliness callbacks are fuzzed on their own. The paper pipeline's part and the multi-target part
(its scans, reports, resets, pictures, the hand-overs and Health) share no service: they run at
once in two processes (seeded ``SEED`` and ``SEED + 1``), their tallies added.

An escape is an exception out of a dispatch or a callback, or a handler failing on a message its
decoder accepted (``rejected_handler_error``: a bug). Per type, the test prints the payloads
sent, how many the decoder rejected, and the rejections the services counted (each subscriber
counts a payload its decoder rejected; the handlers count theirs by reason).
"""

from __future__ import annotations

import logging
import math
import random
import time
from collections.abc import Callable
from hashlib import blake2b
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
import zenoh
from support import in_parallel
from test_fuzz_handlers import MEASUREMENTS, SCANS, SENSORS
from test_hostile_messages import (
    KEYS,
    MTT_SENSORS,
    OPTIONS,
    SONAR,
    Bus,
    mtt_lines,
    mtt_services,
    paper_scan,
    paper_services,
)
from test_mtt_regions_live import scenario as region_scenario
from test_mtt_regions_live import services as region_services
from test_wire import health

from fedtrack.fusion_center.centre import FederatedCentre
from fedtrack.fusion_center.service import FusionCenterService
from fedtrack.fusion_center.snapshot import SNAPSHOT_MAGIC
from fedtrack.local_filters.service import LocalFilterService
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.services import dispatch as service_dispatch
from fedtrack.services.snapshot import DIGEST_BYTES
from fedtrack.wire import (
    FusedTrack,
    HandOver,
    Health,
    LocalEstimate,
    ManeuverEvent,
    Measurement,
    Reset,
    TrackPicture,
    TrackReport,
    TrackResets,
    WireError,
    decode,
    encode,
)
from fedtrack.zsession import LOST_KEPT, SessionOptions

pytestmark = pytest.mark.fuzz

PAYLOADS = 10_000  # at least, per message type
SEED = 24


class Mutator:
    """Seeded mutations of valid msgpack payloads (see the module docstring)."""

    def __init__(self, seed: int) -> None:
        self.rng = random.Random(seed)

    def deep(self) -> Any:
        value: Any = {}
        for _ in range(self.rng.randint(9, 1000)):
            value = {"v": value}
        return value

    def hostile(self) -> Any:
        r = self.rng
        return r.choice([
            self.deep, lambda: [0] * 2049, lambda: "x" * r.randint(257, 5000), lambda: bytes(r.randint(0, 64)),
            lambda: math.nan, lambda: math.inf, lambda: -math.inf, lambda: 1e308, lambda: -1e308, lambda: 5e-324,
            lambda: 2**64 - 1, lambda: 2**63, lambda: -(2**63), lambda: -1, lambda: 0, lambda: None, lambda: True,
            lambda: "", list, dict, lambda: msgpack.ExtType(1, b"x"),
            lambda: {f"k{i}": i for i in range(r.choice([33, 40, 70]))},
            lambda: {"dtype": r.choice(["float64", "int64", "float32"]),
                     "shape": [r.randint(-1, 5000) for _ in range(r.randint(0, 3))], "data": bytes(r.randint(0, 80))},
        ])()

    def slots(self, obj: Any) -> list[tuple[Any, Any]]:
        """Every (container, key) of ``obj`` (an explicit stack: valid payloads are shallow)."""
        out, stack = [], [obj]
        while stack:
            node = stack.pop()
            keys = list(node) if isinstance(node, dict) else range(len(node))
            for key in keys:
                out.append((node, key))
                if isinstance(node[key], (dict, list)):
                    stack.append(node[key])
        return out

    def arrays(self, obj: Any) -> list[dict[str, Any]]:
        return [c[k] for c, k in self.slots(obj) if isinstance(c[k], dict) and set(c[k]) == {"dtype", "shape", "data"}
                and c[k]["dtype"] == "float64" and len(c[k]["data"])]

    def mutate(self, payload: bytes) -> bytes:
        r = self.rng
        kind = r.random()
        if kind < 0.25:  # bytes
            data = bytearray(payload)
            how = r.randrange(3)
            if how == 0:
                for _ in range(r.randint(1, 4)):
                    data[r.randrange(len(data))] = r.randrange(256)
            elif how == 1:
                del data[r.randrange(len(data)):]
            else:
                data += bytes(r.randrange(256) for _ in range(r.randint(1, 16)))
            return bytes(data)
        obj = msgpack.unpackb(payload, raw=False)
        if kind < 0.6:  # a field at any depth made hostile (or removed, or one added)
            container, key = r.choice(self.slots(obj))
            if r.random() < 0.1 and isinstance(container, dict):
                del container[key]
            elif r.random() < 0.05:
                obj["unexpected"] = self.hostile()
            else:
                container[key] = self.hostile()
        elif kind < 0.85 and (arrays := self.arrays(obj)):  # an array's values: scaled, one made extreme, noise
            arr = r.choice(arrays)
            values = np.frombuffer(arr["data"], "<f8").copy()
            how = r.randrange(3)
            if how == 0:
                values *= 10.0 ** r.uniform(-300, 300)
            elif how == 1:
                values[r.randrange(values.size)] = r.choice([math.nan, math.inf, 1e300, -1e300, 0.0, 1e-300, -1.0])
            else:
                values += np.random.default_rng(r.randrange(2**32)).normal(0, 10.0 ** r.uniform(-12, 6), values.size)
            arr["data"] = values.astype("<f8").tobytes()
        else:  # the scan's number or time moved
            if "t" in obj and r.random() < 0.6:
                obj["t"] = obj["t"] + r.choice([-1, 1]) * 10.0 ** r.uniform(-9, 12)
            elif "seq" in obj:
                obj["seq"] = r.choice([obj["seq"] + r.randint(-3, 3), r.randrange(2**63), 0])
        try:
            return msgpack.packb(obj, use_bin_type=True)
        except ValueError:  # deeper than msgpack's packer goes: the nesting alone, as a payload
            return msgpack.packb(self.deep(), use_bin_type=True)


class Tally:
    """Per message type: payloads sent, rejected by the decoder, rejections the services counted."""

    def __init__(self) -> None:
        self.rows: dict[str, list[int]] = {}

    def add(self, name: str, decoder_rejected: bool, counted: int = 0) -> None:
        row = self.rows.setdefault(name, [0, 0, 0])
        row[0] += 1
        row[1] += decoder_rejected
        row[2] += counted

    def merge(self, rows: dict[str, list[int]]) -> None:
        """Add another tally's rows."""
        for name, counts in rows.items():
            self.rows[name] = [a + b for a, b in zip(self.rows.get(name, [0, 0, 0]), counts)]

    def report(self) -> str:
        return "\n".join(f"{name:16s} payloads {n:6d}  decoder rejected {d:6d}  rejections counted {h:6d}"
                         for name, (n, d, h) in sorted(self.rows.items()))


def handler_counts(services: list[Any]) -> tuple[int, int]:
    """(rejections counted, by the decoders of every subscriber and by the handlers; handler
    errors) over ``services``."""
    return (sum(svc.counters["rejected"] for svc in services),
            sum(svc.counters.get("rejected_handler_error", 0) for svc in services))


def rejected_by_decoder(payload: bytes, msg_type: type) -> bool:
    try:
        decode(payload, msg_type)
        return False
    except WireError:
        return True


class Decoded:
    """What the services' own decoder (:func:`fedtrack.services.dispatch.decode`, wrapped while the
    test runs) said of each payload since the last :meth:`outcome`: a payload a subscriber
    decoded need not be decoded again for the tally (the test's time was a quarter in that)."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.seen: dict[tuple[bytes, type], bool] = {}
        real = service_dispatch.decode

        def logged(payload: bytes, msg_type: type) -> Any:
            try:
                msg = real(payload, msg_type)
            except WireError:
                self.seen[payload, msg_type] = True
                raise
            self.seen[payload, msg_type] = False
            return msg
        monkeypatch.setattr(service_dispatch, "decode", logged)

    def forget(self) -> None:
        self.seen.clear()

    def outcome(self, payload: bytes, msg_type: type) -> bool:
        """Whether the decoder rejects ``payload`` as ``msg_type`` (decoded here if no service did)."""
        rejected = self.seen.get((payload, msg_type))
        self.forget()
        return rejected_by_decoder(payload, msg_type) if rejected is None else rejected


def fuzz_stream(bus: Bus, genuine: list[tuple[str, bytes, type]], mutator: Mutator, tally: Tally, per: int,
                types: set[type], decoded: Decoded) -> None:
    """Deliver each genuine message, then ``per`` mutations of it if its type is in ``types``."""
    for key, payload, msg_type in genuine:
        bus.put(key, payload)
        if msg_type not in types:
            continue
        for _ in range(per):
            bad = mutator.mutate(payload)
            decoded.forget()  # what the genuine stream decoded
            before, errors = handler_counts(bus.services)
            bus.put(key, bad)  # an exception here fails the test: an escape
            after, errors_after = handler_counts(bus.services)
            assert errors_after == errors, f"a handler failed on a {msg_type.__name__} the decoder accepted"
            tally.add(msg_type.__name__, decoded.outcome(bad, msg_type), after - before)


def published_stream(bus: Bus, run: Callable[[Bus], None]) -> list[tuple[str, bytes, type]]:
    """Run a clean deployment; every message it published, in order (the inputs to mutate)."""
    run(bus)
    return [(key, encode(msg), type(msg)) for key, msg in bus.published]


def fuzz_part(fuzz: Callable[[Path, Mutator, Tally, Decoded], None], seed: int, tmp_path: Path
              ) -> dict[str, list[int]]:
    """One part of the test (:func:`fuzz_paper_services`, seeded ``SEED``; :func:`fuzz_multitarget_services`,
    ``SEED + 1``), run in a process of its own: the tally's rows."""
    mutator, tally = Mutator(seed), Tally()
    tmp_path.mkdir()
    with pytest.MonkeyPatch.context() as monkeypatch:
        decoded = Decoded(monkeypatch)
        fuzz(tmp_path, mutator, tally, decoded)
    return tally.rows


def fuzz_paper_services(tmp_path: Path, mutator: Mutator, tally: Tally, decoded: Decoded) -> None:
    # the paper pipeline: measurements (position, sonar), estimates, resets, tracks, events
    clean = Bus(list(paper_services(tmp_path / "clean").values()))

    def paper(bus: Bus) -> None:
        for k in range(SCANS):
            paper_scan(bus, k)
    published = published_stream(clean, paper)
    sensors_in = []
    for k in range(SCANS):  # the inputs of each scan, as paper_scan sends them
        sensors_in += [(KEYS.sensor_meas(s), encode(MEASUREMENTS[s][k]), Measurement) for s in SENSORS]
        if k < len(SONAR):
            sensors_in.append((KEYS.sensor_meas("sonar1"), encode(SONAR[k]), Measurement))
    by_type: dict[type, int] = {}
    for _, _, t in published + sensors_in:
        by_type[t] = by_type.get(t, 0) + 1
    services = list(paper_services(tmp_path / "fuzzed").values())
    bus = Bus(services)
    # genuine inputs from the sensors, each followed by what it caused (delivered by the bus)
    per_type = {t: -(-PAYLOADS // n) for t, n in by_type.items()}
    for key, payload, msg_type in sensors_in:
        fuzz_stream(bus, [(key, payload, msg_type)], mutator, tally, per_type[Measurement], {Measurement}, decoded)
    # the services' own outputs, mutated, on their keys (the clean run's, in order)
    for msg_type in (LocalEstimate, Reset, FusedTrack, ManeuverEvent):
        fuzz_stream(bus, [p for p in published if p[2] is msg_type], mutator, tally, per_type[msg_type], {msg_type},
                    decoded)
    # fusion/state replies (a FusedTrack): what a local filter adopts when it rejoins
    local = next(svc for svc in services if isinstance(svc, LocalFilterService))
    good = encode(bus.of(FusedTrack)[-1])
    for _ in range(PAYLOADS):
        bad = mutator.mutate(good)
        local.session.payloads = [bad]  # type: ignore[union-attr]
        decoded.forget()
        before, errors = handler_counts([local])
        with local.guarded("rejoin"):  # as on_measurement calls it
            local.rejoin("fuzz")
        after, errors_after = handler_counts([local])
        assert errors_after == errors, "rejoin failed on a reply the decoder accepted"
        tally.add("FusedTrack reply", decoded.outcome(bad, FusedTrack), after - before)


def fuzz_multitarget_services(tmp_path: Path, mutator: Mutator, tally: Tally, decoded: Decoded) -> None:
    # the multi-target deployment (federated: reports and resets; pictures to the recorder)
    scans = mtt_lines(tmp_path)
    mclean = Bus(list(mtt_services(tmp_path / "mclean").values()))

    def mtt(bus: Bus) -> None:
        for m in scans:
            bus.put(KEYS.sensor_meas(m.sensor), encode(m))
    mpublished = published_stream(mclean, mtt)
    mbus = Bus(list(mtt_services(tmp_path / "mfuzzed").values()))
    counts = {t: sum(1 for p in mpublished if p[2] is t) for t in (TrackReport, TrackResets, TrackPicture)}
    scan_inputs = [(KEYS.sensor_meas(m.sensor), encode(m), Measurement) for m in scans]
    # multi-target scans: 2,000 more Measurements (the paper stream above has 10,000)
    fuzz_stream(mbus, scan_inputs, mutator, tally, -(-2_000 // len(scans)), {Measurement}, decoded)
    for msg_type, n in counts.items():
        fuzz_stream(mbus, [p for p in mpublished if p[2] is msg_type], mutator, tally, -(-PAYLOADS // n), {msg_type}, decoded)

    # region centres (issue 27): the hand-overs between the two regions' centres
    rclean = region_bus(tmp_path / "rclean")

    def regions(bus: Bus) -> None:
        for m in rscans:
            bus.put(KEYS.sensor_meas(m.sensor), encode(m))
    rscans = region_scenario(tmp_path / "rscenario")[0]
    handovers = [p for p in published_stream(rclean, regions) if p[2] is HandOver]
    assert handovers
    rbus = region_bus(tmp_path / "rfuzzed")
    for m in rscans:  # the genuine stream first: each hand-over then meets the state it was made in
        rbus.put(KEYS.sensor_meas(m.sensor), encode(m))
    fuzz_stream(rbus, handovers, mutator, tally, -(-PAYLOADS // len(handovers)), {HandOver}, decoded)

    # Health: no service subscribes to it; the launcher's monitor and the benchmarks decode it
    good = encode(health())
    for _ in range(PAYLOADS):
        tally.add("Health", rejected_by_decoder(mutator.mutate(good), Health))


def test_every_handler_takes_10000_mutations_per_type_without_an_escape(tmp_path: Path) -> None:
    """The paper pipeline's part and the multi-target part (independent services, buses and seeded
    generators) at once, over two processes: an escape fails its part, and the test."""
    tally = Tally()
    for rows in in_parallel([(fuzz_part, (fuzz_multitarget_services, SEED + 1, tmp_path / "multitarget")),
                             (fuzz_part, (fuzz_paper_services, SEED, tmp_path / "paper"))]):
        tally.merge(rows)
    print("\n" + tally.report())
    names = {"Measurement", "LocalEstimate", "Reset", "FusedTrack", "FusedTrack reply", "ManeuverEvent",
             "TrackReport", "TrackResets", "TrackPicture", "Health", "HandOver"}
    assert set(tally.rows) == names
    assert all(n >= PAYLOADS for n, _, _ in tally.rows.values()), tally.report()
    # every kind of outcome happened: not everything died in the decoder
    assert all(0 < d < n for n, d, _ in tally.rows.values()), tally.report()


def region_bus(tmp_path: Path) -> Bus:
    """The region deployment of ``test_mtt_regions_live`` (two region centres, three trackers, the
    merger, the recorder) on a bus."""
    _, cfg, config = region_scenario(tmp_path)
    centres, local, merger, recorder = region_services(tmp_path, "mtt-federated", config, cfg,
                                                       {"options": OPTIONS, "deployment": KEYS.deployment})
    recorder.on_start()
    return Bus([*centres, *local, merger, recorder])


class Sample:
    """A liveliness sample as the callbacks see it."""

    def __init__(self, key: str, put: bool) -> None:
        self.key_expr = key
        self.kind = zenoh.SampleKind.PUT if put else zenoh.SampleKind.DELETE


def test_liveliness_callbacks_take_any_token(tmp_path: Path) -> None:
    """10,000 liveliness samples of any key (configured ids, unknown ids, 10,000-character or
    slash-ridden keys) per callback: no exception, and the centres' departure lists stay bounded."""
    r = random.Random(SEED)
    paper = paper_services(tmp_path / "p")
    mtt = mtt_services(tmp_path / "m")
    centre, mcentre, local = paper["centre"], mtt["centre"], paper["local-1"]
    callbacks: list[Callable[[Sample], None]] = [
        lambda s: centre._on_liveliness(r.choice(["sensor", "local-filter"]), s), mcentre._on_alive,
        local._on_centre_liveliness, centre._on_router]
    ids = ["1", "2", "s1", "s2", "rogue", "x" * 10_000, "a/b/c", "\u00e9\u00e8", ""]
    n = 0
    for callback in callbacks:
        for _ in range(PAYLOADS):
            key = f"fedtrack/{KEYS.deployment}/alive/{r.choice(['sensor', 'local-filter', 'mtt-local'])}/{r.choice(ids)}"
            callback(Sample(key, r.random() < 0.5))
            n += 1
        mcentre.on_tick()
    assert n == 4 * PAYLOADS
    assert centre.gone(time.monotonic()) <= set(centre.sensors) and not (mcentre.peers.lost or mcentre.peers.present)
    assert len(local.centres.lost) <= LOST_KEPT
    assert set(mcentre.silence.last) <= set(MTT_SENSORS)
    print(f"\nliveliness: {n} samples over {len(callbacks)} callbacks")


def test_a_corrupted_snapshot_never_stops_the_centre(tmp_path: Path) -> None:
    """10,000 mutations of a real centre snapshot (bytes flipped, cut, extended), half of them of its
    map behind a digest made again (as a writer of the output folder could): the centre starts fresh
    or resumes, never raises, and fuses the next scan (or rejects it, counted)."""
    services = paper_services(tmp_path / "run")
    snapshot = tmp_path / "centre.snapshot"
    centre: FusionCenterService = services["centre"]  # type: ignore[assignment]
    centre.snapshot = snapshot
    bus = Bus(list(services.values()))
    for k in range(6):
        paper_scan(bus, k)
    good = snapshot.read_bytes()
    paper_scan(bus, 6)  # the estimates of scan 6, for the centres restored below
    estimate = next(e for e in bus.of(LocalEstimate) if e.seq == 6)
    outcomes = {"restored": 0, "fresh": 0}
    quiet = logging.getLogger(centre.log.name)  # 10,000 "unusable snapshot" warnings would be the test's time
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    try:
        restore_corrupted(good, estimate, outcomes, tmp_path / "mutated.snapshot")
    finally:
        quiet.setLevel(level)
    print(f"\nsnapshots: {PAYLOADS} corrupted, {outcomes['restored']} restored, {outcomes['fresh']} started fresh")
    assert sum(outcomes.values()) == PAYLOADS and outcomes["fresh"] > 0


def restore_corrupted(good: bytes, estimate: LocalEstimate, outcomes: dict[str, int], mutated: Path) -> None:
    """PAYLOADS centres restored from corruptions of the snapshot ``good`` (every other one of its map,
    sealed again), each written to the file ``mutated`` first; every 500th then takes ``estimate``."""
    mutator = Mutator(SEED)
    opts = SessionOptions(connect=("tcp/127.0.0.1:1",))
    head = len(SNAPSHOT_MAGIC) + DIGEST_BYTES
    for i in range(PAYLOADS):
        resealed = i % 2 == 1
        data = bytearray(good[head:] if resealed else good)
        how = mutator.rng.randrange(3)
        if how == 0:
            for _ in range(mutator.rng.randint(1, 4)):
                data[mutator.rng.randrange(len(data))] = mutator.rng.randrange(256)
        elif how == 1:
            del data[mutator.rng.randrange(len(data)):]
        else:
            data[mutator.rng.randrange(len(data)):mutator.rng.randrange(len(data))] = bytes(8)
        if resealed:
            data[:0] = SNAPSHOT_MAGIC + blake2b(bytes(data), digest_size=DIGEST_BYTES).digest()
        mutated.write_bytes(data)
        fresh = FusionCenterService(list(SENSORS), FederatedCentre(list(SENSORS), FusionConfig()), 0.5,
                                    snapshot=mutated, service_id="fusion",
                                    options=opts, deployment=KEYS.deployment)
        fresh._restore()
        outcomes["restored" if fresh.restored else "fresh"] += 1
        if i % 500 == 0:  # a restored centre still takes (or rejects) a scan
            fresh._subscriptions = fresh.subscriptions()
            fresh.publish = lambda key, msg: None  # type: ignore[method-assign]
            fresh._dispatch(("sample", 0, KEYS.local_estimate(estimate.sensor), encode(estimate)))
            assert fresh.counters.get("rejected_handler_error", 0) == 0
