"""The three hostile messages of issue 24, and handlers that fail half-way, against every service
in-process (each driven through its own dispatch: bounded decode, sender check, guarded handler).

A :class:`Bus` delivers what the services publish to the services subscribed to its key, one
message at a time in publication order (as Zenoh does, without the network), so a whole
deployment runs in one thread: the paper pipeline (two federated local filters, the fusion
centre, an IMM tracker, a sonar HPDA tracker, the recorder) and the multi-target one (three
federated local trackers, the centre, the recorder).
"""

from __future__ import annotations

import json
import logging
import pickle
from collections import deque
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
from support import assert_same_pictures, numbered_measurements
from test_fuzz_handlers import MEASUREMENTS, SCANS, SENSORS
from test_fuzz_trackers import sonar_stream

from fedtrack.fusion_center.centre import FederatedCentre
from fedtrack.fusion_center.mtt.engines import TrackToTrackEngine
from fedtrack.fusion_center.mtt.replay import replay_mtt
from fedtrack.fusion_center.mtt.service import MttCentreService
from fedtrack.fusion_center.service import FusionCenterService
from fedtrack.keys import Keys
from fedtrack.local_filters.imm.config import load_imm_config
from fedtrack.local_filters.imm.service import IMMService
from fedtrack.local_filters.imm.tracker import IMMTracker
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.service import MttLocalService
from fedtrack.local_filters.pda.config import load_config
from fedtrack.local_filters.pda.service import PDAService
from fedtrack.local_filters.service import LocalFilterService
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.local_filters.vdie.local import FederatedLocalFilter
from fedtrack.recording import Recording
from fedtrack.sensors.multitarget import Scenario, parse_spec, simulate
from fedtrack.sensors.sonar import SonarConfig, sonar_scans
from fedtrack.services.base import Service
from fedtrack.services.recorder import Recorder
from fedtrack.wire import (
    FusedTrack,
    Health,
    LocalEstimate,
    Measurement,
    Reset,
    TrackPicture,
    WireError,
    decode,
    encode,
    measurement_from_replay,
)
from fedtrack.zsession import SessionOptions

KEYS = Keys("hostile")
OPTIONS = SessionOptions(connect=("tcp/127.0.0.1:1",))  # never opened: the bus stands in for Zenoh
MTT_SENSORS = ("s1", "s2", "s3")
# what the base class keeps for itself (I/O, logging): the rest of a service's attributes is its state
INFRASTRUCTURE = {"options", "keys", "log", "session", "_queue", "_publishers", "_inputs", "_subscriptions",
                  "_queryables", "_miss_lock", "_last_log", "_suppressed", "publish", "counters", "recording",
                  "_liveliness", "_dispatch"}


def _matches(pattern: str, key: str) -> bool:
    """Zenoh's ``*`` (one chunk) wildcard, the only one the services subscribe with."""
    p, k = pattern.split("/"), key.split("/")
    return len(p) == len(k) and all(a in ("*", b) for a, b in zip(p, k))


class Replies:
    """Stands in for a service's Zenoh session in :meth:`Service.query`: the replies are ``payloads``."""

    class _Reply:
        def __init__(self, payload: bytes) -> None:
            self.ok = self
            self.payload = self
            self._bytes = payload

        def to_bytes(self) -> bytes:
            return self._bytes

    def __init__(self) -> None:
        self.payloads: list[bytes] = []

    def get(self, key: str, timeout: float) -> list[Any]:
        return [self._Reply(p) for p in self.payloads]

    def liveliness(self) -> Any:
        """No liveliness token is found (a centre stopped on the bus publishes its end as alone)."""
        return NoTokens()


class NoTokens:
    """A liveliness query's answer on the bus: no token."""

    def get(self, key: str, timeout: float) -> list[Any]:
        return []


class Bus:
    """In-process delivery of what the services publish, in publication order (queries get the
    replies a :class:`Replies` holds: none unless a test puts some there)."""

    def __init__(self, services: list[Service]) -> None:
        self.services = services
        self.published: list[tuple[str, Any]] = []
        self.pending: list[tuple[str, bytes]] = []
        self._routes: dict[str, list[tuple[Service, int]]] = {}  # key -> its subscribers
        for svc in services:
            svc._subscriptions = svc.subscriptions()
            svc.session = Replies()  # type: ignore[assignment]
            svc.publish = (lambda key, msg: (self.published.append((key, msg)),  # type: ignore[method-assign]
                                             self.pending.append((key, encode(msg)))))

    def put(self, key: str, payload: bytes) -> None:
        """Deliver ``payload`` on ``key`` (to every subscriber), then everything it caused."""
        self.pending.append((key, payload))
        self.drain()

    def drain(self) -> None:
        while self.pending:
            key, data = self.pending.pop(0)
            if key not in self._routes:
                self._routes[key] = [(svc, index) for svc in self.services
                                     for index, sub in enumerate(svc._subscriptions) if _matches(sub.key, key)]
            for svc, index in self._routes[key]:
                svc._dispatch(("sample", index, key, data))

    def of(self, msg_type: type) -> list[Any]:
        return [m for _, m in self.published if isinstance(m, msg_type)]


def canonical(value: Any) -> Any:
    """``value`` as nested tuples that compare equal exactly when the values are equal (arrays by
    dtype, shape and bytes; floats by their bits, so NaN equals NaN; sets sorted; objects by their
    attributes). For the tests' own state only: it recurses."""
    if isinstance(value, np.ndarray):
        return ("array", value.dtype.str, value.shape, value.tobytes())
    if isinstance(value, (float, np.floating)):
        return ("float", float(value).hex())
    if isinstance(value, dict):
        return ("dict", tuple((canonical(k), canonical(v)) for k, v in value.items()))
    if isinstance(value, (set, frozenset)):
        return ("set", tuple(sorted((canonical(v) for v in value), key=repr)))
    if isinstance(value, (list, tuple, deque)):
        return (type(value).__name__, tuple(canonical(v) for v in value))
    if hasattr(value, "__dict__") and not callable(value):
        return (type(value).__name__, canonical(vars(value)))
    return value


def fingerprint(svc: Service) -> dict[str, Any]:
    """Every attribute of ``svc`` but the base class's I/O ones, :func:`canonical` (equal: equal state)."""
    return {k: canonical(v) for k, v in vars(svc).items() if k not in INFRASTRUCTURE}


# ---------------------------------------------------------------- the paper pipeline

def paper_services(tmp_path: Path) -> dict[str, Service]:
    config = FusionConfig()
    n = len(SENSORS)
    common: dict[str, Any] = {"options": OPTIONS, "deployment": KEYS.deployment}
    services: dict[str, Service] = {
        f"local-{s}": LocalFilterService(s, "federated", FederatedLocalFilter(float(n), n, config), 0.5,
                                         service_id=s, **common) for s in SENSORS}
    services["centre"] = FusionCenterService(list(SENSORS), FederatedCentre(list(SENSORS), config), 0.5,
                                             service_id="fusion", **common)
    services["imm"] = IMMService(SENSORS[0], "ao-vsimm", load_imm_config(None), service_id="imm", **common)
    services["hpda"] = PDAService("sonar1", "hpda", load_config(None), service_id="hpda", **common)
    recorder = Recorder(tmp_path / "paper.db", service_id="rec", **common)
    recorder.on_start()
    recorder.recording.db.execute("PRAGMA synchronous = OFF")  # type: ignore[union-attr]  # test speed only
    services["recorder"] = recorder
    return services


SONAR = sonar_stream()


def paper_scan(bus: Bus, k: int) -> None:
    """Scan ``k``: each sensor's measurement (the estimates, fusion and resets follow on the bus)."""
    for s in SENSORS:
        bus.put(KEYS.sensor_meas(s), encode(MEASUREMENTS[s][k]))
    if k < len(SONAR):
        bus.put(KEYS.sensor_meas("sonar1"), encode(SONAR[k]))


def paper_run(tmp_path: Path, before: Callable[[Bus, int], None] | None = None) -> tuple[Bus, dict[str, Service]]:
    services = paper_services(tmp_path)
    bus = Bus(list(services.values()))
    for k in range(SCANS):
        if before is not None:
            before(bus, k)
        paper_scan(bus, k)
    return bus, services


class CleanRuns:
    """The clean runs, each made once per module on first use (the tests compare their attacked or
    failing runs with them and change nothing in them): the paper pipeline's, the multi-target one's."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self._paper: tuple[Bus, dict[str, Service]] | None = None
        self._mtt: tuple[Bus, dict[str, Service]] | None = None

    def paper(self) -> tuple[Bus, dict[str, Service]]:
        if self._paper is None:
            self._paper = paper_run(self.folder / "paper")
        return self._paper

    def mtt(self) -> tuple[Bus, dict[str, Service]]:
        if self._mtt is None:
            services = mtt_services(self.folder / "mtt")
            bus = Bus(list(services.values()))
            for m in mtt_lines(self.folder):
                bus.put(KEYS.sensor_meas(m.sensor), encode(m))
            self._mtt = bus, services
        return self._mtt


@pytest.fixture(scope="module")
def clean_runs(tmp_path_factory: pytest.TempPathFactory) -> CleanRuns:
    return CleanRuns(tmp_path_factory.mktemp("clean"))


def same_tracks(a: list[FusedTrack], b: list[FusedTrack]) -> None:
    assert [(t.seq, t.model, t.contested) for t in a] == [(t.seq, t.model, t.contested) for t in b]
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.x, y.x)
        np.testing.assert_array_equal(x.P, y.P)


def fused(bus: Bus) -> list[FusedTrack]:
    return [m for key, m in bus.published if key == KEYS.fusion_track()]


def assert_one_time_jump_changes_nothing(svc: Any, attacked: Bus, clean: Bus) -> None:
    """``svc`` rejected one message, as ``time_jump``, and contested no scan; every fused track of the
    ``attacked`` run is the ``clean`` run's, one a scan."""
    assert svc.counters.get("rejected_time_jump") == 1 and svc.counters["rejected"] == 1
    assert svc.counters.get("contested", 0) == 0
    same_tracks(fused(attacked), fused(clean))
    assert len(fused(attacked)) == SCANS


# ---------------------------------------------------------------- the multi-target deployment

def mtt_lines(tmp_path: Path) -> list[Measurement]:
    out = tmp_path / "mtt-scenario"
    simulate(Scenario(targets=4, duration=12.0, clutter=2.0, late=0.0), parse_spec("pos:1.0,pos:0.7,pos:1.3"), 3, out)
    return numbered_measurements(out / "measurements.jsonl")


def mtt_services(tmp_path: Path, algorithm: str = "mtt-federated") -> dict[str, Service]:
    cfg = MttConfig(sensors=MTT_SENSORS, max_lag=3.0, clutter_density=2.0 / 5000.0**2)
    common: dict[str, Any] = {"options": OPTIONS, "deployment": KEYS.deployment}
    services: dict[str, Service] = {"centre": MttCentreService(algorithm, cfg, 4, service_id="centre", **common)}
    if algorithm != "mtt-centralized":
        services.update({s: MttLocalService(s, algorithm == "mtt-federated", cfg, 5.0, service_id=s, **common)
                         for s in MTT_SENSORS})
    recorder = Recorder(tmp_path / f"{algorithm}.db", service_id="rec", **common)
    recorder.on_start()
    recorder.recording.db.execute("PRAGMA synchronous = OFF")  # type: ignore[union-attr]
    services["recorder"] = recorder
    return services


def assert_recording_replays(services: dict[str, Service], bus: Bus, tmp_path: Path) -> None:
    """The centre of :func:`mtt_services` (``mtt-federated``, sensors s1-s3) stopped, its recording exported and
    replayed with a config of those sensors: the replay's pictures are the live ones."""
    services["centre"].on_stop()
    bus.drain()
    measurements, live = tmp_path / "m.jsonl", tmp_path / "live.jsonl"
    services["recorder"].recording.export(measurements, live)  # type: ignore[attr-defined]
    config = tmp_path / "c.toml"
    config.write_text('[mtt]\nsensors = ["s1", "s2", "s3"]\nmax_lag = 3.0\nclutter_density = 8e-8\n')
    again = tmp_path / "again.jsonl"
    replay_mtt("mtt-federated", measurements, config, again)
    assert_same_pictures(*([json.loads(x) for x in f.read_text().splitlines()] for f in (live, again)))


def pictures(bus: Bus) -> list[tuple[Any, ...]]:
    return [(p.seq, p.t, p.ids, p.x.tobytes(), p.P.tobytes(), p.fused_sensors, p.fused_seqs, p.contested)
            for p in bus.of(TrackPicture)]


# ---------------------------------------------------------------- issue 24, message 1

def deep_map(depth: int = 1000) -> bytes:
    deep: Any = {}
    for _ in range(depth):
        deep = {"v": deep}
    return msgpack.packb({"schema": 1, "type": deep, "role": deep}, use_bin_type=True)


def test_a_1000_deep_map_on_any_key_is_one_counted_rejection(tmp_path: Path, caplog: Any) -> None:
    """Issue 24: a map nested 1,000 deep killed every service with RecursionError while it
    formatted the rejection. Sent on every key every service subscribes to (and decoded as the
    Health that the launcher's monitor and the benchmarks read): one bounded rejection each."""
    payload = deep_map()
    with pytest.raises(WireError, match="nested more than"):
        decode(payload, Health)
    services = [*paper_services(tmp_path).values(), *mtt_services(tmp_path).values(),
                mtt_services(tmp_path / "c", "mtt-centralized")["centre"]]
    bus = Bus(services)
    caplog.set_level(logging.WARNING)
    for svc in services:
        for index, sub in enumerate(svc._subscriptions):
            key = sub.key.replace("*", "1")
            before = fingerprint(svc)
            svc._dispatch(("sample", index, key, payload))
            assert fingerprint(svc) == before
        assert svc.counters["rejected"] == len(svc._subscriptions) and svc.counters["received"] == 0
    lines = [r.getMessage() for r in caplog.records if "rejected a message" in r.getMessage()]
    assert len(lines) == len(services) and all(len(line) < 400 for line in lines), lines
    assert all("containers nested more than 8 deep" in line for line in lines)
    assert bus.published == []


# ---------------------------------------------------------------- issue 24, message 2

def test_an_estimate_far_ahead_of_its_scan_is_rejected_and_changes_nothing(tmp_path: Path, clean_runs: CleanRuns) -> None:
    """Issue 24: a LocalEstimate time-stamped far ahead of its scan, arriving before the scan's
    genuine estimates, crashed the centre (LinAlgError) and changed the fused track. It is now
    rejected (``time_jump``: more than ``max_time_jump_s`` after the last fused scan) and the
    fused tracks equal the clean run's."""
    clean, _ = clean_runs.paper()
    forged_at = 12

    def forge(bus: Bus, k: int) -> None:
        if k == forged_at:
            genuine = next(e for e in clean.of(LocalEstimate) if e.seq == k and e.sensor == SENSORS[0])
            bus.put(KEYS.local_estimate(SENSORS[0]), encode(replace(genuine, t=genuine.t + 1e6)))

    attacked, services = paper_run(tmp_path / "attacked", forge)
    assert services["centre"].counters.get("rejected_numerical", 0) == 0  # it crashed the centre (LinAlgError)
    assert_one_time_jump_changes_nothing(services["centre"], attacked, clean)


# ---------------------------------------------------------------- issue 24, message 3

def test_a_replayed_estimate_arriving_first_marks_its_scan_contested(tmp_path: Path, clean_runs: CleanRuns) -> None:
    """Issue 24: an older genuine estimate re-published with the current scan's ``seq`` and ``t``
    arrives before the genuine one and is fused (without authentication nothing tells them apart).
    When the genuine one arrives, the scan's fused track is marked ``contested`` (Health counter
    ``contested``); the other scans are the clean run's."""
    clean, _ = clean_runs.paper()
    forged_at = 20

    def replay_old(bus: Bus, k: int) -> None:
        if k == forged_at:
            old = next(e for e in clean.of(LocalEstimate) if e.seq == k - 5 and e.sensor == SENSORS[0])
            bus.put(KEYS.local_estimate(SENSORS[0]), encode(replace(old, seq=k, t=MEASUREMENTS[SENSORS[0]][k].t)))

    attacked, services = paper_run(tmp_path / "attacked", replay_old)
    centre = services["centre"]
    assert centre.counters.get("contested") == 1 and centre.counters.get("rejected_conflict") == 1
    tracks = fused(attacked)
    assert [t.seq for t in tracks if t.contested] == [forged_at]
    same_tracks(tracks[:forged_at], fused(clean)[:forged_at])
    rows = list(Recording(tmp_path / "attacked" / "paper.db").messages(FusedTrack, "seq"))
    assert [t.seq for t in rows if t.contested] == [forged_at]  # recorded as published


def test_a_conflicting_report_marks_the_next_picture_contested(tmp_path: Path) -> None:
    """The multi-target centre: a second, different report for a (sensor, scan) it already fused
    is rejected and marks the next picture ``contested``; the pictures before it are unchanged."""
    scans = mtt_lines(tmp_path)
    runs = []
    for name, forge in (("clean", False), ("forged", True)):
        services = mtt_services(tmp_path / name)
        bus = Bus(list(services.values()))
        for i, m in enumerate(scans):
            bus.put(KEYS.sensor_meas(m.sensor), encode(m))
            if forge and i == len(scans) // 2:
                report = [r for key, r in bus.published if key == KEYS.mtt_report(m.sensor)][-1]
                bus.put(KEYS.mtt_report(m.sensor), encode(replace(report, t=report.t, x=report.x + 1.0)))
        runs.append((bus, services))
    (clean, _), (forged, services) = runs
    assert services["centre"].counters.get("contested") == 1
    assert services["centre"].counters.get("rejected_conflict") == 1
    flagged = [i for i, p in enumerate(forged.of(TrackPicture)) if p.contested]  # positions (a number is t / period)
    assert len(flagged) == 1
    assert pictures(forged)[:flagged[0]] == pictures(clean)[:flagged[0]]



def test_a_messages_digest_ignores_its_stamp_only(tmp_path: Path) -> None:
    """``digest`` (a re-delivery or a conflict) of a decoded report: that of the message re-checked
    with its stamp cleared; another stamp gives the same, another estimate another."""
    from hashlib import blake2b

    from fedtrack.services.admission import digest
    from fedtrack.wire import TrackReport, decode

    scans = mtt_lines(tmp_path)
    services = mtt_services(tmp_path / "run")
    bus = Bus(list(services.values()))
    for m in scans[:12]:
        bus.put(KEYS.sensor_meas(m.sensor), encode(m))
    reports = [decode(encode(r), TrackReport) for key, r in bus.published if isinstance(r, TrackReport)]
    assert len(reports) >= 6 and any(r.ids for r in reports)
    for r in reports:
        assert digest(r) == blake2b(encode(replace(r, stamp_ns=0)), digest_size=16).digest()
        assert digest(replace(r, stamp_ns=r.stamp_ns + 1)) == digest(r)
        assert digest(replace(r, t=r.t + 1e-9)) != digest(r)


# ---------------------------------------------------------------- handlers that fail half-way

def fail_once(real: Callable[..., Any], at: int, exc: Exception, after: bool = True) -> Callable[..., Any]:
    """``real``, except that its ``at``-th call raises ``exc``: after running (so after changing
    what it changes) or, with ``after`` false, before."""
    calls = [0]

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        calls[0] += 1
        if calls[0] == at and not after:
            raise exc
        out = real(*args, **kwargs)
        if calls[0] == at:
            raise exc
        return out
    wrapper.calls = calls  # type: ignore[attr-defined]
    return wrapper


def resend_after_a_failure(svc: Service, restored: list[bool]) -> None:
    """Make ``svc`` check, after each message it rejected, that its state is what it was before
    the message, and then take the same message again (a retransmission)."""
    dispatch = svc._dispatch

    def checked(item: tuple[Any, ...]) -> None:
        before, rejected = fingerprint(svc), svc.counters["rejected"]
        dispatch(item)
        if svc.counters["rejected"] > rejected:
            after = fingerprint(svc)
            # a local filter notes the number of a scan it refused when its turn came (no gap counted after
            # it, as the refusal's counter is kept): the one trace a refusal leaves, besides the counters
            noted = [after.pop(k) != before.pop(k) for k in ("refused_up_to",) if k in before]
            restored.append(after == before and all(noted))
            dispatch(item)
    svc._dispatch = checked  # type: ignore[method-assign]


def outputs(bus: Bus) -> dict[str, list[bytes]]:
    """Everything published, per key, wall-clock stamps cleared."""
    out: dict[str, list[bytes]] = {}
    for key, msg in bus.published:
        out.setdefault(key, []).append(encode(replace(msg, stamp_ns=0) if hasattr(msg, "stamp_ns") else msg))
    return out


def state_counters(svc: Service) -> dict[str, int]:
    return {k: v for k, v in svc.counters.items() if not k.startswith("rejected") and k != "received"}


PDA_SERVICE = __import__("fedtrack.local_filters.pda.service", fromlist=["manager_step"])
MTT_LOCAL = __import__("fedtrack.local_filters.mtt.local", fromlist=["local_step"])  # SensorTracker calls it
FUSION_SERVICE = __import__("fedtrack.fusion_center.service", fromlist=["LocalOutput"])
# family -> (service, patched owner, attribute, call that fails, exception, raised after the call, reason)
FAILURES: dict[str, tuple[str, Any, str, int, Exception, bool, str]] = {
    "local-filter": ("local-1", FederatedLocalFilter, "process", 21, np.linalg.LinAlgError("Singular matrix"),
                     True, "numerical"),
    "centre": ("centre", FUSION_SERVICE, "LocalOutput", 31, RuntimeError("a bug"), True, "handler_error"),
    "imm": ("imm", IMMTracker, "update", 12, FloatingPointError("overflow"), True, "numerical"),
    "hpda": ("hpda", PDA_SERVICE, "manager_step", 5, KeyError("a bug"), True, "handler_error"),
    "recorder": ("recorder", Recording, "add", 40, OSError("disk full"), False, "handler_error"),
    "mtt-local": ("s2", MTT_LOCAL, "local_step", 7, FloatingPointError("overflow"), True, "numerical"),
    "mtt-centre": ("centre", TrackToTrackEngine, "fuse", 15, np.linalg.LinAlgError("Singular matrix"), True,
                   "numerical"),
}


@pytest.mark.parametrize("family", sorted(FAILURES))
def test_a_handler_failing_half_way_leaves_no_trace(tmp_path: Path, family: str, monkeypatch: Any,
                                                    clean_runs: CleanRuns) -> None:
    """A handler that raises after changing its state (a numerical failure, or a bug) rejects the
    message, counted by reason; the service's state is exactly as before the message, and the
    same message sent again then gives exactly the clean run's outputs and counters."""
    name, owner, attr, at, exc, after, reason = FAILURES[family]
    multitarget = family.startswith("mtt")
    scans = mtt_lines(tmp_path) if multitarget else []

    def failing_run(path: Path) -> tuple[Bus, Service, list[bool]]:
        services = mtt_services(path) if multitarget else paper_services(path)
        bus = Bus(list(services.values()))
        restored: list[bool] = []
        resend_after_a_failure(services[name], restored)
        monkeypatch.setattr(owner, attr, fail_once(getattr(owner, attr), at, exc, after))
        if multitarget:
            for m in scans:
                bus.put(KEYS.sensor_meas(m.sensor), encode(m))
        else:
            for k in range(SCANS):
                paper_scan(bus, k)
        return bus, services[name], restored

    clean, clean_services = clean_runs.mtt() if multitarget else clean_runs.paper()  # before the patch
    clean_svc = clean_services[name]
    bus, svc, restored = failing_run(tmp_path / "failing")
    assert getattr(owner, attr).calls[0] > at  # the failure happened mid-run
    assert restored == [True]
    assert svc.counters.get(f"rejected_{reason}") == 1 and svc.counters["rejected"] == 1
    assert state_counters(svc) == state_counters(clean_svc)
    assert outputs(bus) == outputs(clean)
    assert clean_svc.counters["rejected"] == 0


def test_a_scan_the_centre_cannot_fuse_is_dropped_and_its_state_kept(tmp_path: Path, monkeypatch: Any) -> None:
    """A fusion that fails numerically (a singular matrix inside the centre's step, after it
    changed its state) drops that scan (``rejected_numerical``: no track, no resets), leaves the
    centre's filter as it was before the scan, and the next scans are fused."""
    k = 10
    monkeypatch.setattr(FederatedCentre, "fuse", fail_once(FederatedCentre.fuse, k + 1,
                                                           np.linalg.LinAlgError("Singular matrix")))
    services = paper_services(tmp_path)
    bus = Bus(list(services.values()))
    centre: FusionCenterService = services["centre"]  # type: ignore[assignment]
    states = []
    for scan in range(SCANS):
        paper_scan(bus, scan)
        states.append(pickle.dumps(centre.centre))
        for s in SENSORS:  # no reset for scan k: the local filters go on alone after their deadline
            local: LocalFilterService = services[f"local-{s}"]  # type: ignore[assignment]
            if local.pending:
                local.waiting_since = -1e9
                local.on_tick()
        bus.drain()
    assert centre.counters.get("rejected_numerical") == 1
    assert [t.seq for t in fused(bus)] == [s for s in range(SCANS) if s != k]
    assert states[k] == states[k - 1]
    assert k not in {r.seq for r in bus.of(Reset)} and k - 1 in {r.seq for r in bus.of(Reset)}


# ---------------------------------------------------------------- issue 24 item 5: forgeries that arrive first

def forged_measurement(sensor_msgs: list[Measurement], k: int, back: int = 5) -> Measurement:
    """An older genuine measurement re-stamped with scan ``k``'s ``seq`` and ``t`` (plausible)."""
    return replace(sensor_msgs[k - back], seq=k, t=sensor_msgs[k].t)


def named(track: FusedTrack) -> list[int]:
    return [int(s) for s in track.extra.get("contested_scans", [])]


def test_a_forged_measurement_first_at_a_local_filter_and_the_imm_is_named_by_the_next_outputs(
        tmp_path: Path, clean_runs: CleanRuns) -> None:
    """A forged measurement of sensor 1, scan k, arrives before the genuine one: the local filter
    and the IMM tracker take it (their outputs of scan k are built on it, unflagged: nothing told
    them apart yet). The genuine one is then a second, different message for that scan: rejected
    (``conflict``), counted ``contested``, and named by the next outputs: the local estimate of
    scan k + 1 (``contested = (k,)``), the fused track of scan k + 1 and the IMM's track of scan
    k + 1 (``contested``, ``extra["contested_scans"] = [k]``). Before scan k all equals the clean run."""
    clean, _ = clean_runs.paper()
    k = 20

    def forge(bus: Bus, scan: int) -> None:
        if scan == k:
            bus.put(KEYS.sensor_meas(SENSORS[0]), encode(forged_measurement(MEASUREMENTS[SENSORS[0]], k)))

    attacked, services = paper_run(tmp_path / "attacked", forge)
    for name in (f"local-{SENSORS[0]}", "imm"):
        assert services[name].counters.get("contested") == 1, name
        assert services[name].counters.get("rejected_conflict") == 1, name
    assert services[f"local-{SENSORS[1]}"].counters.get("contested", 0) == 0
    estimates = [e for e in attacked.of(LocalEstimate) if e.sensor == SENSORS[0]]
    assert [(e.seq, e.contested) for e in estimates if e.contested] == [(k + 1, (k,))]
    tracks = fused(attacked)
    same_tracks(tracks[:k], fused(clean)[:k])
    assert not np.array_equal(tracks[k].x, fused(clean)[k].x)  # the forgery was fused
    assert [(t.seq, named(t)) for t in tracks if t.contested] == [(k + 1, [k])]
    imm = [m for key, m in attacked.published if key == KEYS.tracker_track("imm", SENSORS[0])]
    imm_clean = [m for key, m in clean.published if key == KEYS.tracker_track("imm", SENSORS[0])]
    same_tracks(imm[:k], imm_clean[:k])
    assert [(t.seq, named(t)) for t in imm if t.contested] == [(k + 1, [k])]
    rows = list(Recording(tmp_path / "attacked" / "paper.db").messages(FusedTrack, "seq"))
    assert [t.seq for t in rows if t.contested] == [k + 1]  # recorded as published


def test_a_forged_reset_first_at_a_local_filter_flags_the_tracks_built_on_it(tmp_path: Path, clean_runs: CleanRuns) -> None:
    """A forged reset of scan k (the genuine reset's state moved by 50 m) reaches sensor 1's local
    filter before the centre's: the filter adopts it, and when the genuine reset comes (a second,
    different reset of scan k: ``conflict``) the next estimate names scan k, so that the first
    fused track built on the forgery (scan k + 1) is ``contested`` and names it."""
    clean, _ = clean_runs.paper()
    k = 20
    genuine = next(r for r in clean.of(Reset) if r.seq == k and r.sensor == SENSORS[0])
    forged = replace(genuine, x=genuine.x + np.r_[50.0, 0.0, 50.0, 0.0, np.zeros(genuine.x.shape[0] - 4)])
    services = paper_services(tmp_path / "attacked")
    bus = Bus(list(services.values()))
    for scan in range(SCANS):
        if scan != k:
            paper_scan(bus, scan)
            continue
        bus.put(KEYS.sensor_meas(SENSORS[0]), encode(MEASUREMENTS[SENSORS[0]][k]))
        bus.put(KEYS.fusion_reset(SENSORS[0]), encode(forged))  # before the scan is fused
        bus.put(KEYS.sensor_meas(SENSORS[1]), encode(MEASUREMENTS[SENSORS[1]][k]))
    local = services[f"local-{SENSORS[0]}"]
    assert local.counters.get("contested") == 1 and local.counters.get("rejected_conflict") == 1
    tracks = fused(bus)
    same_tracks(tracks[:k + 1], fused(clean)[:k + 1])  # the forged reset acts from scan k + 1
    assert not np.array_equal(tracks[k + 1].x, fused(clean)[k + 1].x)
    assert [(t.seq, named(t)) for t in tracks if t.contested] == [(k + 1, [k])]


def test_a_forged_sonar_scan_first_at_the_hpda_tracker_is_named_by_its_next_tracks() -> None:
    """HPDA: a forged sonar scan k (an older one re-stamped) arrives first and is tracked; the
    genuine scan k is a ``conflict``, and the confirmed tracks of scan k + 1 are ``contested``,
    naming scan k; before scan k the tracks equal the clean run's."""
    stream = [measurement_from_replay({key: v for key, v in line.items() if key != "truth"}, "sonar", seq=i)
              for i, line in enumerate(list(sonar_scans(SonarConfig(sensor="sonar1"), 3))[:14])]
    k = 10
    runs = []
    for forge in (False, True):
        svc = PDAService("sonar1", "hpda", load_config(None), service_id="hpda", options=OPTIONS,
                         deployment=KEYS.deployment)
        bus = Bus([svc])
        for i, m in enumerate(stream):
            if forge and i == k:
                bus.put(KEYS.sensor_meas("sonar1"), encode(forged_measurement(stream, k, 3)))
            bus.put(KEYS.sensor_meas("sonar1"), encode(m))
        runs.append((bus.of(FusedTrack), svc))
    (clean, _), (attacked, svc) = runs
    assert svc.counters.get("contested") == 1 and svc.counters.get("rejected_conflict") == 1
    same_tracks([t for t in attacked if t.seq < k], [t for t in clean if t.seq < k])
    assert {t.seq for t in attacked if t.seq == k + 1} and all(t.contested for t in attacked if t.seq == k + 1)
    assert {(t.seq, tuple(named(t))) for t in attacked if t.contested} == {(k + 1, (k,))}


def test_a_forged_scan_first_at_a_multitarget_local_tracker_flags_the_next_report_and_picture(
        tmp_path: Path) -> None:
    """mtt-local: a forged scan of s1 (an older scan re-stamped with the next scan's ``seq`` and
    ``t``) arrives before the genuine one and is tracked; the genuine one is a ``conflict``, the
    local tracker's next report names that scan (``contested``), and the centre's picture that
    fuses that report is ``contested``. Until the forged scan the pictures equal the clean run's."""
    scans = mtt_lines(tmp_path)
    at = [i for i, m in enumerate(scans) if m.sensor == "s1"][6]
    older = [m for m in scans[:at] if m.sensor == "s1"][-3]
    runs = []
    for name, forge in (("clean", False), ("forged", True)):
        services = mtt_services(tmp_path / name)
        bus = Bus(list(services.values()))
        for i, m in enumerate(scans):
            if forge and i == at:
                bus.put(KEYS.sensor_meas("s1"), encode(replace(older, seq=m.seq, t=m.t)))
            bus.put(KEYS.sensor_meas(m.sensor), encode(m))
        runs.append((bus, services))
    (clean, _), (forged, services) = runs
    assert services["s1"].counters.get("contested") == 1 and services["s1"].counters.get("rejected_conflict") == 1
    reports = [r for key, r in forged.published if key == KEYS.mtt_report("s1")]
    assert [(r.seq, r.contested) for r in reports if r.contested] == [(scans[at].seq + 1, (scans[at].seq,))]
    pics = forged.of(TrackPicture)
    flagged = [i for i, p in enumerate(pics) if p.contested]
    assert len(flagged) == 1
    assert any(("s1", scans[at].seq + 1) == scan for scan in zip(pics[flagged[0]].fused_sensors,
                                                                  pics[flagged[0]].fused_seqs))
    first_changed = next(i for i, (a, b) in enumerate(zip(pictures(forged), pictures(clean))) if a != b)
    assert pictures(forged)[:first_changed] == pictures(clean)[:first_changed] and first_changed <= flagged[0]
