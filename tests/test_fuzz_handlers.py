"""Fuzzing the handlers: hostile messages interleaved with a real scan stream never change what a
service publishes; each is a counted rejection (or a counted late/duplicate), never an exception.

Two federated local filters and the fusion center run in-process on the paper-004 scenario,
resets included; their handlers are driven through the service's own dispatch (decode, sender
check, handler), so the path is the one a Zenoh sample takes. Hypothesis inserts, per example,
300 hostile messages built from the genuine ones (measurements, estimates and resets): a
sender that is not the key's, an unknown sensor, a wrong model or state size, a sequence
number far ahead, a time that is not the scan's, a second different message for a sensor and
scan, overflow-scale values, garbage. 100 examples: 30,000 hostile messages, about 10,000
through each of the three handlers (measurement, estimate, reset).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fedtrack.fusion_center.centre import FederatedCentre
from fedtrack.fusion_center.service import FusionCenterService
from fedtrack.keys import Keys
from fedtrack.local_filters.service import LocalFilterService
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.local_filters.vdie.local import FederatedLocalFilter
from fedtrack.sensors.scenarios import DEFAULT_R, paper004_scenario, simulate_positions, simulate_truth
from fedtrack.wire import FusedTrack, LocalEstimate, Measurement, Reset, encode
from fedtrack.zsession import SessionOptions

pytestmark = pytest.mark.fuzz

SENSORS = ("1", "2")
SCANS = 34  # the first maneuver starts at t = 30
HOSTILE = 300  # per example, over the three handlers (about 100 each)
EXAMPLES = 100
KEYS = Keys("fuzz")
OPTIONS = SessionOptions(connect=("tcp/127.0.0.1:1",))
KINDS = ("sender", "unknown_sensor", "wrong_model", "seq_jump", "time_jump", "conflict", "overflow", "garbage")


def measurements() -> dict[str, list[Measurement]]:
    scenario = paper004_scenario(1)
    rng = np.random.default_rng(9)
    Rs = np.array([DEFAULT_R, DEFAULT_R])
    zs = simulate_positions(simulate_truth(scenario, 1, rng), Rs, rng)[0]
    return {s: [Measurement(sensor=s, seq=k, t=float(scenario.times[k]), kind="position", z=zs[k, i],
                            R=Rs[i], stamp_ns=k + 1) for k in range(SCANS)] for i, s in enumerate(SENSORS)}


MEASUREMENTS = measurements()


class Pipeline:
    """The services, their dispatch, and what they published."""

    def __init__(self, snapshot: Path | None = None) -> None:
        config = FusionConfig()
        self.published: list[tuple[str, Any]] = []
        n = len(SENSORS)
        self.locals = {s: LocalFilterService(s, "federated", FederatedLocalFilter(float(n), n, config), 0.5,
                                             service_id=s, options=OPTIONS, deployment=KEYS.deployment)
                       for s in SENSORS}
        self.centre = FusionCenterService(list(SENSORS), FederatedCentre(list(SENSORS), config), 0.5,
                                          service_id="fusion", options=OPTIONS, deployment=KEYS.deployment,
                                          snapshot=snapshot)
        for svc in (*self.locals.values(), self.centre):
            svc._subscriptions = svc.subscriptions()
            svc.publish = lambda key, msg: self.published.append((key, msg))  # type: ignore[method-assign]

    @staticmethod
    def send(svc: Any, key: str, payload: bytes, subscription: int = 0) -> None:
        svc._dispatch(("sample", subscription, key, payload))

    def reset(self, key_sensor: str, payload: bytes) -> None:
        self.send(self.locals.get(key_sensor, self.locals[SENSORS[0]]), KEYS.fusion_reset(key_sensor), payload, 1)

    def measurement(self, sensor: str, key_sensor: str, payload: bytes) -> None:
        target = self.locals.get(key_sensor, self.locals[sensor])
        self.send(target, KEYS.sensor_meas(key_sensor), payload)

    def estimate(self, key_sensor: str, payload: bytes) -> None:
        self.send(self.centre, KEYS.local_estimate(key_sensor), payload)

    def estimates_of_last_scan(self) -> list[LocalEstimate]:
        return [m for _, m in self.published if isinstance(m, LocalEstimate)]

    def tracks(self) -> list[FusedTrack]:
        return [m for _, m in self.published if isinstance(m, FusedTrack)]

    def rejected(self) -> int:
        counted = ("rejected", "late", "duplicate", "stale_reset")
        return sum(svc.counters.get(c, 0) for svc in (*self.locals.values(), self.centre) for c in counted)


def run(attacks: dict[int, list[tuple[str, str, float]]] | None = None, snapshot: Path | None = None) -> Pipeline:
    """The stream scan by scan: sensor 1's measurement and estimate, the hostile messages of the
    scan, sensor 2's (which completes the scan); returns the pipeline (its centre's ``--snapshot``)."""
    pipe = Pipeline(snapshot)
    for k in range(SCANS):
        scan_attacks = (attacks or {}).get(k, [])
        for s in SENSORS:
            meas = MEASUREMENTS[s][k]
            pipe.measurement(s, s, encode(meas))
            est = pipe.estimates_of_last_scan()[-1]
            pipe.estimate(s, encode(est))
            if s == SENSORS[0]:
                for kind, target, value in scan_attacks:
                    if target != "reset":
                        hostile(pipe, kind, target, value, meas, est)
        # the scan is fused: hostile resets arrive before the centre's own (which then apply),
        # a conflicting one after it
        resets = [m for _, m in pipe.published if isinstance(m, Reset) and m.seq == k]
        assert len(resets) == len(SENSORS) or k == 0
        hostile_resets = [(kind, value) for kind, target, value in scan_attacks if target == "reset" and resets]
        for kind, value in hostile_resets:
            if kind != "conflict":
                hostile_reset(pipe, kind, value, resets[0])
        for r in resets:
            pipe.reset(r.sensor, encode(r))
        for kind, value in hostile_resets:
            if kind == "conflict":
                pipe.reset(resets[0].sensor, encode(replace(resets[0], x=resets[0].x + 1.0 + abs(value))))
    return pipe


def hostile_reset(pipe: Pipeline, kind: str, value: float, reset: Reset) -> None:
    """A hostile reset for the scan just fused, sent before the centre's own reset (a conflicting
    one, sent after it, is built in :func:`run`)."""
    other = next(s for s in SENSORS if s != reset.sensor)
    if kind in ("sender", "unknown_sensor"):
        pipe.reset(other, encode(reset))
    elif kind == "wrong_model":  # a 3-D radar state: no 2-D filter can take it
        pipe.reset(reset.sensor, encode(replace(reset, model="cv3", x=np.zeros(6), P=np.eye(6))))
    elif kind == "seq_jump":
        pipe.reset(reset.sensor, encode(replace(reset, seq=reset.seq + 2**40)))
    elif kind == "time_jump":
        pipe.reset(reset.sensor, encode(replace(reset, t=reset.t + 1.0 + abs(value), x=reset.x + value)))

    elif kind == "overflow":
        pipe.reset(reset.sensor, encode(reset).replace(b"\x00" * 4, b"\x7f\xef\xff\xff", 1))
    else:
        pipe.reset(reset.sensor, bytes(int(abs(value) * 11 + i) % 256 for i in range(50)))


def hostile(pipe: Pipeline, kind: str, target: str, value: float, meas: Measurement, est: LocalEstimate) -> None:
    """One hostile measurement (``target`` "meas") or estimate ("est") derived from the genuine ones."""
    other = SENSORS[1]
    if target == "meas":
        if kind == "sender":
            pipe.measurement(meas.sensor, other, encode(meas))
        elif kind in ("seq_jump", "conflict"):
            jump = 10_000 if kind == "seq_jump" else 0
            pipe.measurement(meas.sensor, meas.sensor, encode(replace(meas, seq=meas.seq + jump, z=meas.z + value)))
        elif kind == "time_jump":
            pipe.measurement(meas.sensor, meas.sensor, encode(replace(meas, seq=meas.seq - 1, t=meas.t + value)))
        elif kind == "overflow":
            pipe.measurement(meas.sensor, meas.sensor, encode(meas).replace(b"\x00" * 4, b"\x7f\xef\xff\xff", 1))
        else:
            pipe.measurement(meas.sensor, meas.sensor, bytes(int(abs(value) * 7 + i) % 256 for i in range(40)))
        return
    if kind == "sender":
        pipe.estimate(other, encode(est))
    elif kind == "unknown_sensor":
        pipe.estimate("rogue", encode(replace(est, sensor="rogue")))
    elif kind == "wrong_model":
        pipe.estimate(est.sensor, encode(replace(est, model="cv3", x=np.zeros(6), P=np.eye(6),
                                                 x_prior=np.zeros(6), P_prior=np.eye(6))))
    elif kind == "seq_jump":
        pipe.estimate(est.sensor, encode(replace(est, seq=est.seq + 2**62)))
    elif kind == "time_jump":
        pipe.estimate(other, encode(replace(est, sensor=other, t=est.t + 1e6 + abs(value))))
    elif kind == "conflict":
        pipe.estimate(est.sensor, encode(replace(est, x=est.x + 100.0 + value)))
    elif kind == "overflow":
        pipe.estimate(est.sensor, encode(est).replace(b"\x00" * 4, b"\x7f\xef\xff\xff", 1))
    else:
        pipe.estimate(est.sensor, bytes(int(abs(value) * 13 + i) % 256 for i in range(60)))


CLEAN = run()


def test_the_clean_stream_is_tracked() -> None:
    tracks = CLEAN.tracks()
    assert [t.seq for t in tracks] == list(range(SCANS)) and CLEAN.rejected() == 0
    assert any(t.maneuver for t in tracks[31:])


attack = st.tuples(st.integers(1, SCANS - 1), st.sampled_from(KINDS), st.sampled_from(("meas", "est", "reset")),
                   st.floats(-1e3, 1e3, allow_nan=False))


@settings(max_examples=EXAMPLES, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.large_base_example])
@given(st.lists(attack, min_size=HOSTILE, max_size=HOSTILE))
def test_hostile_messages_are_counted_and_change_nothing(attacks: list[tuple[int, str, str, float]]) -> None:
    by_scan: dict[int, list[tuple[str, str, float]]] = {}
    for k, kind, target, value in attacks:
        by_scan.setdefault(k, []).append((kind, target, value))
    pipe = run(by_scan)
    clean, got = CLEAN.tracks(), pipe.tracks()
    assert [t.seq for t in got] == [t.seq for t in clean]
    for a, b in zip(got, clean):
        np.testing.assert_array_equal(a.x, b.x)
        np.testing.assert_array_equal(a.P, b.P)
    assert pipe.rejected() == HOSTILE


def test_an_indefinite_fusion_is_rebuilt_from_the_local_estimates(monkeypatch: Any) -> None:
    """If the federated sum comes out indefinite (a local's prior that is not its share of the
    centre's), the centre starts again from the local estimates instead of failing on the reset."""
    pipe = Pipeline()
    centre = pipe.centre.centre
    real_fuse = type(centre).fuse
    calls = {"n": 0}

    def fuse_once_indefinite(self: Any, t: float, outputs: Any) -> Any:
        result = real_fuse(self, t, outputs)
        calls["n"] += 1
        if calls["n"] == 10:  # scan 9: spoil the estimate and every reset
            bad = np.diag([-1.0] + [1.0] * (result.estimate.P.shape[0] - 1))
            return result._replace(estimate=result.estimate._replace(P=bad),
                                   resets={s: c._replace(P=bad[: c.P.shape[0], : c.P.shape[0]])
                                           for s, c in result.resets.items()})
        return result

    monkeypatch.setattr(type(centre), "fuse", fuse_once_indefinite)
    for k in range(12):
        for s in SENSORS:
            pipe.measurement(s, s, encode(MEASUREMENTS[s][k]))
            pipe.estimate(s, encode(pipe.estimates_of_last_scan()[-1]))
        for r in [m for _, m in pipe.published if isinstance(m, Reset) and m.seq == k]:
            pipe.reset(r.sensor, encode(r))
    assert [t.seq for t in pipe.tracks()] == list(range(12))
    assert pipe.centre.counters.get("rebuilt_not_positive_definite") == 1
