"""Hostile messages through a live router (issue 24, item 3; marker ``fuzz``).

A real deployment runs (the paper 004 pipeline, lockstep, and the multi-target one, realtime;
each stopped one second after the attack) through :func:`fedtrack.deploy.launcher.prepare_launcher`, the machinery of
``fedtrack demo`` and ``fedtrack launch``. An attacker joins the bus as a client, learns the keys
from the traffic (a subscriber on ``fedtrack/<deployment>/**`` and on the liveliness tokens
``alive/**``) and, once the pipeline runs, publishes hostile variants of what it saw on every key
it learned (measurements, estimates, resets, fused tracks, events, multi-target reports, resets
and pictures, every service's health), declares and withdraws liveliness tokens under every role
it saw, and queries ``fusion/state`` with hostile payloads. Classes (:func:`variants`):

* ``structure``: random bytes, a non-map, a missing / unknown field, another message's ``type``,
  another schema;
* ``depth``: a map nested 1,000 deep (top level and inside a field), a list nested 100,000 deep;
* ``size``: a 1 MB string, container headers claiming 4 G items, a payload over 2 MiB;
* ``numeric``: every integer field at -1 / 2**63 / 2**64 - 1, every float at NaN / inf / 1e308 /
  5e-324, arrays of NaN, of 1e300, with a lying shape or dtype;
* ``types``: every field as a string, a list, a map, a boolean, nil or bytes;
* ``time``: ``t`` 1e6 s ahead and behind, ``seq`` 1e6 ahead;
* ``replay``: the latest genuine message again (a duplicate) and as scan 0, and an older genuine
  message re-stamped with the latest and the next ``seq`` and ``t`` (plausible forgeries);
* ``liveliness``: tokens of forged ids under every role seen, declared, then withdrawn;
* ``query``: ``get`` on ``fusion/state`` with hostile payloads.

Asserted in every run: no process dies or restarts (the launcher's exit codes and restart
counts), and every hostile message that can be decoded by nobody (the malformed classes) is
counted in the ``rejected`` counter of every service that subscribes to its key.

* **Authenticated** (mutual TLS and access control, the default of ``fedtrack demo`` and
  ``deploy/multitarget.toml``): the attacker holds a valid certificate, sensor 1's. The router
  admits its messages only on sensor 1's own keys (its measurements, its local filter's or
  tracker's output, their health and liveliness); forgeries on every other key never arrive (the
  test's own observer, on the recorder's certificate, sees none; the attacker learns the keys on it too,
  as sensor 1's may read only what its roles read). On its own keys it sends every
  class but the plausible forgeries (``replay``): a compromised sensor can always lie about its
  own data, which no authentication prevents. Asserted: the fused output (every fused track, or
  every picture) equals the clean run's (the offline replay of the genuine measurements) to 1e-9.
* **Unauthenticated** (``--insecure``): every message arrives; a plausible forgery can arrive
  before the genuine message. Asserted: the first fused track that differs from the clean run's
  (every later one depends on it) is accounted for: flagged ``contested`` itself, or named by a
  later fused track's ``extra["contested_scans"]`` (its measurement, or the reset of the scan
  before it, reached a local filter from the forger first; the conflict became known only when
  the genuine message came, after the scan's track was out: docs/wire.md, "Contested scans").

The classes, messages per class and the counts are printed (``pytest -s``). Each run takes 12-25 s
here (start-up, the attack, the stop; 45-61 s for the file); loopback only, free ports, multicast
scouting off, bounded waits, and only the processes the launcher started are stopped.
"""

from __future__ import annotations

import json
import math
import signal
import threading
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
import zenoh
from support import assert_same_pictures

from fedtrack.deploy.access_control import identity, own_keys
from fedtrack.deploy.demo import demo_settings, free_port, multitarget_settings, write_config
from fedtrack.deploy.launcher import Stopped, prepare_launcher
from fedtrack.deploy.report import LaunchReport
from fedtrack.deploy.settings import Settings
from fedtrack.fusion_center.mtt.replay import replay_mtt
from fedtrack.fusion_center.replay import replay_fusion
from fedtrack.jsonl import write_jsonl
from fedtrack.keys import Keys
from fedtrack.sensors.service import SensorSettings, position_scans
from fedtrack.wire import (
    FusedTrack,
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
    measurement_to_replay,
    picture_to_replay,
)
from fedtrack.zsession import SessionOptions, close_session, open_session

pytestmark = pytest.mark.fuzz

PAPER_DURATION_S = 3000.0  # paper 004 scenario 1 run on, lockstep as in `fedtrack demo`; stopped after the attack
# (forged fused tracks drive lockstep sensors ahead: the unauthenticated run went through 300 scans in 3 s)
MTT_DURATION_S, MTT_SPEED = 60.0, 5.0  # the multi-target default's length; stopped after the attack
SETTLE_S = 1.0  # after the attack, before the stop
MIN_OUTPUTS = 8  # fused tracks or pictures the run must have produced
DEADLINE_S = 10.0  # no scan is fused degraded because the loaded machine delayed an estimate
ROUNDS = 3  # attack rounds, ROUND_GAP_S apart, once the pipeline runs
ROUND_GAP_S = 0.2
DEEP = 1000
PER_SENSOR = ("local-filter", "mtt-local")  # subscribe to their own sensor's keys only
FAMILIES: dict[str, tuple[type, tuple[str, ...]]] = {  # key family -> (message, services subscribed)
    "meas": (Measurement, ("local-filter", "mtt-local", "recorder")),
    "estimate": (LocalEstimate, ("fusion-center", "recorder")),
    "reset": (Reset, ("local-filter",)),
    "track": (FusedTrack, ("recorder", "sensor")),
    "event": (ManeuverEvent, ("recorder",)),
    "report": (TrackReport, ("mtt-centre",)),
    "mtt-resets": (TrackResets, ("mtt-local",)),
    "picture": (TrackPicture, ("recorder",)),
    "health": (Health, ()),
}


def family(keys: Keys, key: str) -> tuple[str, str | None] | None:
    """``(family, sensor or None)`` of a concrete key of the deployment, None for others (``@adv``)."""
    parts = key.split("/")[2:]
    if len(parts) < 2 or any(p.startswith("@") for p in parts):
        return None
    match parts:
        case ["sensor", sid, "meas"]:
            return "meas", sid
        case ["local", sid, "estimate"]:
            return "estimate", sid
        case ["local", sid, "tracks"]:
            return "report", sid
        case ["fusion", "reset", sid]:
            return "reset", sid
        case ["fusion", "mtt-resets", sid]:
            return "mtt-resets", sid
        case ["fusion", "track"] | ["fusion", "event"] | ["fusion", "picture"]:
            return parts[1], None
        case ["health", _, _]:
            return "health", None
    return None


# ---------------------------------------------------------------- hostile variants
def deep_map(depth: int) -> bytes:
    return b"\x81\xa1k" * depth + b"\xc0"  # {"k": {"k": ... nil}}


def with_raw(obj: dict[str, Any], field: str, raw: bytes) -> bytes:
    """``obj`` packed with ``field``'s value replaced by the raw msgpack bytes ``raw``."""
    marker = "\x00raw\x00"
    return msgpack.packb({**obj, field: marker}).replace(msgpack.packb(marker), raw, 1)


def is_array(value: Any) -> bool:
    return isinstance(value, dict) and set(value) == {"dtype", "shape", "data"}


def numeric_variants(obj: dict[str, Any]) -> list[bytes]:
    out = []
    for f, v in obj.items():
        if f in ("schema", "type") or isinstance(v, bool):
            continue
        if isinstance(v, int):
            out += [msgpack.packb({**obj, f: x}) for x in (-1, 2**63, 2**64 - 1)]
        elif isinstance(v, float):
            out += [msgpack.packb({**obj, f: x}) for x in (math.nan, math.inf, 1e308, 5e-324)]
        elif is_array(v):
            n = len(v["data"]) // 8
            for fill in (math.nan, 1e300, -1e300):
                out.append(msgpack.packb({**obj, f: {**v, "data": np.full(n, fill).tobytes()}}))
            out.append(msgpack.packb({**obj, f: {**v, "shape": [10**9]}}))
            out.append(msgpack.packb({**obj, f: {**v, "dtype": "float16"}}))
            out.append(msgpack.packb({**obj, f: {**v, "data": v["data"][:-3]}}))
    return out


def variants(genuine: bytes, older: bytes | None, rng: np.random.Generator, plausible: bool,
             oversize: bool) -> list[tuple[str, bytes]]:
    """``(class, payload)`` hostile variants of one genuine message (see the module docstring);
    ``plausible``: include the re-stamped replays; ``oversize``: include a payload over 2 MiB."""
    obj = msgpack.unpackb(genuine, raw=False)
    fields = [f for f in obj if f not in ("schema", "type")]
    some = [fields[int(i)] for i in rng.choice(len(fields), size=min(2, len(fields)), replace=False)]
    out = [("structure", rng.bytes(int(n))) for n in (1, 17, 300)]
    out += [("structure", msgpack.packb(v)) for v in ([obj], 7, "x", None, {})]
    out += [("structure", msgpack.packb({k: v for k, v in obj.items() if k != f})) for f in some]
    out += [("structure", msgpack.packb({**obj, "bogus": 1})),
            ("structure", msgpack.packb({**obj, "type": "Reset" if obj.get("type") != "Reset" else "Health"})),
            ("structure", msgpack.packb({**obj, "schema": 99}))]
    out += [("depth", deep_map(DEEP)), ("depth", b"\x91" * 100_000 + b"\xc0")]
    out += [("depth", with_raw(obj, f, deep_map(DEEP))) for f in some]
    out += [("size", msgpack.packb({**obj, some[0]: "x" * 1_000_000})), ("size", b"\xdd\xff\xff\xff\xff\x01"),
            ("size", b"\xdf\xff\xff\xff\xff\xa1k")]
    if oversize:
        out.append(("size", genuine + rng.bytes(2 * 1024 * 1024)))
    out += [("numeric", p) for p in numeric_variants(obj)]
    for f in some:
        for wrong in ("x", [1, 2], {"a": 1}, True, None, b"\x00"):
            if type(wrong) is not type(obj[f]) and not (wrong is None and obj[f] is None):
                out.append(("types", msgpack.packb({**obj, f: wrong})))
    if isinstance(obj.get("t"), float):
        out += [("time", msgpack.packb({**obj, "t": obj["t"] + dt})) for dt in (1e6, -1e6)]
    if isinstance(obj.get("seq"), int):
        out.append(("time", msgpack.packb({**obj, "seq": obj["seq"] + 10**6})))
    if plausible:
        out.append(("replay", genuine))
        if isinstance(obj.get("seq"), int):  # the latest again as scan 0 (multi-target services take any order)
            out.append(("replay", msgpack.packb({**obj, "seq": 0})))
        if older is not None and "seq" in obj:
            old = msgpack.unpackb(older, raw=False)
            for step in (0, 1):
                stamped = {**old, "seq": obj["seq"] + step}
                if isinstance(obj.get("t"), float) and isinstance(old.get("t"), float):
                    stamped["t"] = obj["t"] + step * (obj["t"] - old["t"]) / max(obj["seq"] - old["seq"], 1)
                out.append(("replay", msgpack.packb(stamped)))
    return out


# ---------------------------------------------------------------- the attacker
class Attacker:
    """A client that learns the deployment's keys and publishes hostile variants on them."""

    def __init__(self, endpoint: str, keys: Keys, zenoh_config: str | None, own: set[str] | None,
                 ready: set[str], learn_config: str | None) -> None:
        self.keys = keys
        self.ready = ready  # key families to have seen twice before the attack starts
        self.own = own  # keys the router admits from this identity (None: every key)
        self.session = open_session(SessionOptions(connect=(endpoint,), connect_timeout_s=20.0,
                                                   config_file=zenoh_config))
        # sensor 1's identity reads only what its roles read: the keys are learnt as a reader of every key
        self.learner = open_session(SessionOptions(connect=(endpoint,), connect_timeout_s=20.0,
                                                   config_file=learn_config))
        self.lock = threading.Lock()
        self.seen: dict[str, list[bytes]] = {}
        self.alive: set[str] = set()
        self.families: Counter[str] = Counter()
        self.sent: list[tuple[str, str, str, bytes]] = []  # (class, family, key, payload)
        self.forged: set[bytes] = set()  # payloads sent that no genuine service had published
        self.absurd: set[bytes] = set()  # those of them no genuine service will ever publish (not ``replay``)
        self.genuine: set[bytes] = set()
        root = f"fedtrack/{keys.deployment}"
        self.subs = [self.learner.declare_subscriber(f"{root}/**", self._on_sample),
                     self.learner.liveliness().declare_subscriber(f"{root}/alive/**", self._on_alive, history=True)]
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._attack, daemon=True)
        self.span = (math.nan, math.nan)  # wall-clock start and end of the attack

    def _on_sample(self, sample: Any) -> None:
        payload = sample.payload.to_bytes()
        key = str(sample.key_expr)
        with self.lock:
            if payload in self.forged or family(self.keys, key) is None:
                return
            self.genuine.add(payload)
            self.seen.setdefault(key, []).append(payload)
            del self.seen[key][:-20]
            self.families[family(self.keys, key)[0]] += 1  # type: ignore[index]

    def _on_alive(self, sample: Any) -> None:
        with self.lock:
            self.alive.add(str(sample.key_expr))

    def plausible_on(self, key: str) -> bool:
        return self.own is None or key not in self.own

    def _put(self, cls: str, fam: str, key: str, payload: bytes) -> None:
        with self.lock:
            self.sent.append((cls, fam, key, payload))
            if payload not in self.genuine:
                self.forged.add(payload)
                if cls != "replay":
                    self.absurd.add(payload)
        self.session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)

    def _attack(self) -> None:
        rng = np.random.default_rng(24)
        deadline = time.monotonic() + 60.0
        while not self.stop.is_set() and min(self.families[f] for f in self.ready) < 2 and time.monotonic() < deadline:
            time.sleep(0.02)
        tokens: list[Any] = []
        start = time.time()
        for rnd in range(ROUNDS):
            if self.stop.is_set():
                break
            with self.lock:
                learned = {k: list(v) for k, v in self.seen.items()}
                alive = sorted(self.alive)
            for key, payloads in sorted(learned.items()):
                fam, _ = family(self.keys, key)  # type: ignore[misc]
                older = payloads[-3] if len(payloads) >= 3 else None
                for cls, payload in variants(payloads[-1], older, rng, self.plausible_on(key), rnd == 0):
                    self._put(cls, fam, key, payload)
            for token in tokens:
                token.undeclare()
            tokens = []
            for role in sorted({k.split("/")[3] for k in alive}):
                for forged in (f"forged{rnd}", "x" * 64):
                    key = self.keys.alive(role, forged)
                    tokens.append(self.session.liveliness().declare_token(key))
                    with self.lock:
                        self.sent.append(("liveliness", "alive", key, b""))
            for cls, payload in variants(learned.get(self.keys.fusion_track(), [msgpack.packb({"t": 0.0})])[-1],
                                         None, rng, False, False)[:8]:
                replies = self.session.get(self.keys.fusion_state(), payload=payload, timeout=0.5)
                for _ in replies:
                    pass
                with self.lock:
                    self.sent.append(("query", "state", self.keys.fusion_state(), payload))
            self.stop.wait(ROUND_GAP_S)
        for token in tokens:
            token.undeclare()
        self.span = (start, time.time())

    def close(self) -> None:
        self.stop.set()
        self.thread.join(30)
        for sub in self.subs:
            sub.undeclare()
        close_session(self.session)
        close_session(self.learner)


def observe_outputs(endpoint: str, keys: Keys, zenoh_config: str | None, sink: list[tuple[str, bytes]]) -> Any:
    """A session (the recorder's identity, which reads every key) collecting every sample under the
    deployment: what arrived."""
    session = open_session(SessionOptions(connect=(endpoint,), connect_timeout_s=20.0, config_file=zenoh_config))
    sub = session.declare_subscriber(f"fedtrack/{keys.deployment}/**",
                                     lambda s: sink.append((str(s.key_expr), s.payload.to_bytes())))
    return session, sub


# ---------------------------------------------------------------- runs
def paper_settings(tmp_path: Path, secure: bool) -> Settings:
    base = demo_settings(2, 1, "federated", 1, free_port(), tmp_path, tls_dir=Path("certs") if secure else None)
    return replace(base, deployment=replace(base.deployment, name=f"hostile{time.monotonic_ns() % 10**6}",
                                            duration_s=PAPER_DURATION_S, deadline_s=DEADLINE_S))


def mtt_settings(tmp_path: Path, secure: bool) -> Settings:
    base = multitarget_settings("federated", 1, free_port(), tmp_path, tls_dir=Path("certs") if secure else None)
    assert base.multitarget is not None
    return replace(base, deployment=replace(base.deployment, name=f"hostile{time.monotonic_ns() % 10**6}",
                                            speed=MTT_SPEED),
                   multitarget=replace(base.multitarget, duration=MTT_DURATION_S, targets=6))


def attack(tmp_path: Path, settings: Settings, secure: bool) -> tuple[LaunchReport, Attacker, list[tuple[str, bytes]]]:
    """Run the deployment under attack; returns the launcher's report, the attacker, what the observer saw."""
    config = tmp_path / "config.toml"
    write_config(settings, config)
    launcher = prepare_launcher(settings, config, tmp_path, quiet=True)
    endpoint = settings.deployment.router_listen
    zdir = tmp_path / "zenoh"
    keys = Keys(settings.deployment.name)
    attacker_sensor = min(sp.id for sp in launcher.plan if sp.role == "sensor")
    own = None
    if secure:
        own = set(own_keys(keys, identity("sensor", attacker_sensor)))
    result: dict[str, Any] = {}

    def run() -> None:
        try:
            result["ended"] = launcher.run()  # the scenario ended first: the attack had no time
        except Stopped as exc:
            result["stopped"] = exc.report

    runner = threading.Thread(target=run, daemon=True)
    runner.start()
    deadline = time.monotonic() + 60
    while launcher._session is None and runner.is_alive() and time.monotonic() < deadline:
        time.sleep(0.02)  # the router listens and the monitor is connected
    seen: list[tuple[str, bytes]] = []
    reader = str(zdir / "recorder.json5") if secure else None
    observer, spy = observe_outputs(endpoint, keys, reader, seen)
    ready = {"meas", "report"} if settings.multitarget is not None else {"meas", "estimate", "reset", "track"}
    attacker = Attacker(endpoint, keys, str(zdir / f"sensor-{attacker_sensor}.json5") if secure else None, own, ready,
                        reader)
    attacker.thread.start()
    try:
        attacker.thread.join(60)
        time.sleep(SETTLE_S)  # every hostile message delivered and handled
        launcher.request_stop()
        runner.join(60)
        assert not runner.is_alive(), "the deployment did not stop within 60 s"
    finally:
        attacker.close()
        spy.undeclare()
        close_session(observer)
    assert "stopped" in result, "the scenario ended before the attack was over"
    return result["stopped"], attacker, seen


def final_health(keys: Keys, attacker: Attacker, seen: list[tuple[str, bytes]]) -> dict[str, Health]:
    """Per service, the genuine Health with the highest ``seq`` the observer saw (the final one,
    status ``stopped``, when the service stopped cleanly)."""
    out: dict[str, Health] = {}
    for key, payload in seen:
        if family(keys, key) == ("health", None) and payload not in attacker.forged:
            h = decode(payload, Health)
            name = f"{h.role}/{h.id}"
            if name not in out or h.seq > out[name].seq:
                out[name] = h
    return out


def counted(health: dict[str, Health], attacker: Attacker, keys: Keys) -> dict[str, tuple[int, int]]:
    """Per service: (hostile messages no decoder accepts that reached it, its final ``rejected`` counter)."""
    malformed: Counter[str] = Counter()
    for _, fam, key, payload in attacker.sent:
        if fam not in FAMILIES or attacker.own is not None and key not in attacker.own:
            continue  # not a message, or denied at the router
        msg_type, roles = FAMILIES[fam]
        try:
            decode(payload, msg_type)
            continue
        except WireError:
            pass
        _, sid = family(keys, key)  # type: ignore[misc]
        for name in health:
            role, service_id = name.split("/", 1)
            if role in roles and (role not in PER_SENSOR or service_id == sid):
                malformed[name] += 1
    return {name: (malformed[name], h.counters.get("rejected", 0)) for name, h in health.items()}


def print_attack(title: str, attacker: Attacker, counts: dict[str, tuple[int, int]], report: LaunchReport,
                 health: dict[str, Health]) -> None:
    per_class = Counter(cls for cls, *_ in attacker.sent)
    per_family = Counter(fam for _, fam, *_ in attacker.sent)
    print(f"\n{title}: {len(attacker.sent)} hostile messages; per class {dict(sorted(per_class.items()))}; "
          f"per key family {dict(sorted(per_family.items()))}")
    first, last = input_span(report)
    print(f"{title}: attack {attacker.span[0] - first:.2f} s to {attacker.span[1] - first:.2f} s after the sensors' "
          f"first scan (stopped {SETTLE_S:g} s later), their last scan at {last - first:.2f} s; restarts {report.restarts or 0}; exit codes "
          f"{set(report.exit_codes.values())}")
    for name, (bad, rejected) in sorted(counts.items()):
        extra = {k: v for k, v in health[name].counters.items() if k.startswith(("rejected_", "contested", "duplicate",
                                                                                 "conflict"))}
        print(f"{title}:   {name:<22} malformed received {bad:>5}  rejected {rejected:>5}  {extra}")


def input_span(report: LaunchReport) -> tuple[float, float]:
    """Wall-clock time of the sensors' first and last publish (as the launcher's monitor saw them)."""
    stamps = [ns / 1e9 for seq in report.publish_stamps_ns.values() for ns in seq.values()] + \
        [ns / 1e9 for ns in report.scan_span_ns or ()]
    return min(stamps), max(stamps)


def assert_survived(report: LaunchReport, counts: dict[str, tuple[int, int]], health: dict[str, Health]) -> None:
    assert set(health) == {sp for sp in report.exit_codes}, (set(health), report.exit_codes)
    # final counters: the observer's, or, where a flood kept the observer's copy behind the router's stop, the
    # launcher monitor's (a sensor's final stopped, exit 0, missed by the observer at a load of 5)
    said = {name: report.statuses.get(name, h.status) if h.status != "stopped" else h.status
            for name, h in health.items()}
    assert {name: status for name, status in said.items() if status != "stopped"} == {}, said
    assert report.restarts == {} and report.failed == [], report.restarts
    # every service stopped cleanly (its final Health says so); one that the launcher's SIGTERM met
    # while its interpreter was exiting, or whose exit outlived the grace period (STOP_GRACE_S) on
    # this loaded machine and was SIGKILLed, is named
    late = {name: code for name, code in report.exit_codes.items() if code != 0}
    if late:
        print(f"signalled on exit after a clean stop: {late}")
    assert report.exit_codes and set(late.values()) <= {-signal.SIGKILL, -signal.SIGTERM}, report.exit_codes
    for name, (bad, rejected) in counts.items():
        assert rejected >= bad, f"{name}: {bad} malformed messages reached it, {rejected} counted: {health[name]}"
    assert sum(bad for bad, _ in counts.values()) > 0


def published(keys: Keys, attacker: Attacker, seen: list[tuple[str, bytes]]) -> set[tuple[str, float]]:
    """``(sensor, t)`` of every genuine measurement the sensors published (a realtime sensor that
    starts late skips the scans already due)."""
    return {(m.sensor, m.t) for m in (decode(p, Measurement) for k, p in seen
                                      if family(keys, k) == ("meas", k.split("/")[3]) and p not in attacker.forged)}


def centre_order(keys: Keys, attacker: Attacker, seen: list[tuple[str, bytes]],
                 pictures: list[TrackPicture]) -> list[dict[str, Any]]:
    """The genuine scans the sensors published, in the multi-target centre's processing order (the
    pictures' ``fused_sensors`` / ``fused_seqs``, departures at ``left``), as replay lines: the clean
    run of what the live centre fused (``fedtrack export`` orders a recording the same way)."""
    genuine: dict[tuple[str, int], Measurement] = {}
    for key, payload in seen:
        if family(keys, key) == ("meas", key.split("/")[3]) and payload not in attacker.forged:
            m = decode(payload, Measurement)
            genuine.setdefault((m.sensor, m.seq), m)
    lines: list[dict[str, Any]] = []
    for pic in pictures:
        for i, scan in enumerate(zip(pic.fused_sensors, pic.fused_seqs)):
            if i in pic.left:
                lines.append({"t": pic.t, "sensor": scan[0], "left": True})
            else:
                assert scan in genuine, f"the centre fused scan {scan}, which no sensor published"
                lines.append(measurement_to_replay(genuine[scan]))
    return lines


def clean_tracks(tmp_path: Path, settings: Settings, sent: set[tuple[str, float]]) -> dict[float, dict[str, Any]]:
    """The clean run's fused tracks by time: the replay of the genuine measurements the sensors published."""
    sensors = SensorSettings(deployment=settings.deployment, sensor=settings.sensor)
    per_sensor = [list(position_scans(sensors, s.id)) for s in settings.sensor]
    lines = [line for scan in zip(*per_sensor) for line in scan if (line["sensor"], line["t"]) in sent]
    write_jsonl(tmp_path / "clean-m.jsonl", lines)
    replay_fusion("fvdie", tmp_path / "clean-m.jsonl", tmp_path / "config.toml", tmp_path / "clean.jsonl")
    return {row["t"]: row for row in map(json.loads, (tmp_path / "clean.jsonl").read_text().splitlines())}


def same_track(track: FusedTrack, clean: dict[str, Any]) -> bool:
    return (track.t == clean["t"] and track.model == clean["model"]
            and np.allclose(track.x, clean["x"], rtol=1e-9, atol=1e-9)
            and np.allclose(track.P, clean["P"], rtol=1e-9, atol=1e-9))


@pytest.mark.parametrize("secure", [True, False], ids=["authenticated", "unauthenticated"])
def test_paper_pipeline_under_attack(tmp_path: Path, secure: bool) -> None:
    settings = paper_settings(tmp_path, secure)
    report, attacker, seen = attack(tmp_path, settings, secure)
    keys = Keys(settings.deployment.name)
    health = final_health(keys, attacker, seen)
    counts = counted(health, attacker, keys)
    title = f"paper pipeline, {'authenticated' if secure else 'unauthenticated'}"
    print_attack(title, attacker, counts, report, health)
    assert_survived(report, counts, health)
    clean = clean_tracks(tmp_path, settings, published(keys, attacker, seen))
    if secure:
        assert not [k for k, p in seen if p in attacker.absurd and k not in attacker.own], \
            "a forgery on a key sensor 1 does not own arrived"
    genuine = [decode(p, FusedTrack) for k, p in seen if k == keys.fusion_track() and p not in attacker.forged]
    by_seq = {track.seq: track for track in genuine}  # the last one of a scan, should the centre correct it
    while by_seq and by_seq[max(by_seq)].degraded:  # the stop: sensors and local filters leave first, the centre
        del by_seq[max(by_seq)]          # fused what it had (the last scan or two; no other is degraded)
    assert len(by_seq) >= MIN_OUTPUTS and {track.t for track in by_seq.values()} <= set(clean), sorted(by_seq)
    changed = [seq for seq, track in by_seq.items() if not same_track(track, clean[track.t])]
    print(f"{title}: {len(changed)} of {len(by_seq)} fused tracks differ from the clean run's "
          f"(flagged contested: {sum(bool(by_seq[s].contested) for s in changed)})")
    if secure:
        assert changed == [], [(s, by_seq[s].degraded, by_seq[s].sensors, by_seq[s].contested) for s in changed[:3]]
        return
    # A fused track depends on every earlier scan: once a forgery is used the run leaves the clean one
    # for good, so the scan where it first differs is the one that must be accounted for: flagged
    # contested itself, or named by a later track (``extra["contested_scans"]``) as the scan whose
    # measurement (that scan) or reset (the scan before) a local filter took from the forger first.
    named = {seq for track in genuine if track.contested
             for seq in (track.seq, *(int(s) for s in track.extra.get("contested_scans", [])))}
    first = min(changed, default=None)
    print(f"{title}: first differing scan {first}; contested scans named by the fused tracks: {sorted(named)}")
    assert first is None or {first - 1, first} & named, \
        f"scan {first} differs from the clean run's and is not flagged contested (named: {sorted(named)})"
    # every changed scan is at or after a contested one (the effect carries on until re-convergence)
    assert all(any(c <= seq for c in named) for seq in changed)


def test_multitarget_under_attack_authenticated(tmp_path: Path) -> None:
    settings = mtt_settings(tmp_path, True)
    report, attacker, seen = attack(tmp_path, settings, True)
    keys = Keys(settings.deployment.name)
    health = final_health(keys, attacker, seen)
    counts = counted(health, attacker, keys)
    print_attack("multi-target, authenticated", attacker, counts, report, health)
    assert_survived(report, counts, health)
    assert attacker.own is not None
    assert not [k for k, p in seen if p in attacker.absurd and k not in attacker.own]
    pictures = {pic.seq: pic for pic in (decode(p, TrackPicture) for k, p in seen
                                          if k == keys.mtt_picture() and p not in attacker.forged)}
    live = [picture_to_replay(pictures[seq]) for seq in sorted(pictures) if not pictures[seq].closing]
    write_jsonl(tmp_path / "clean-m.jsonl", centre_order(keys, attacker, seen, [pictures[q] for q in sorted(pictures)]))
    replay_mtt("mtt-federated", tmp_path / "clean-m.jsonl", tmp_path / "config.toml", tmp_path / "clean.jsonl")
    clean = [json.loads(line) for line in (tmp_path / "clean.jsonl").read_text().splitlines()]
    print(f"multi-target, authenticated: {len(live)} pictures, equal to the clean run's: ", end="")
    assert len(live) >= MIN_OUTPUTS
    assert_same_pictures(live, clean)
    print("yes")
