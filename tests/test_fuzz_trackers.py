"""Fuzzing the single-sensor trackers' handlers (``serve imm``, ``serve hpda``): hostile
measurements interleaved with a real scan stream change nothing they publish and are counted.

Each service runs in-process and is driven through its own dispatch (decode, sender check,
handler). Hypothesis inserts 400 hostile measurements per example, 25 examples (10,000 per
service): another sensor's id, the wrong kind or dimension, a time far ahead (a forged or broken
clock: ``[deployment] max_time_jump_s``), a time in the past, the scan's bytes altered (an
overflow-scale value, or a valid but different second message for the scan: a conflict), garbage.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Callable

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fedtrack.keys import Keys
from fedtrack.local_filters.imm.config import load_imm_config
from fedtrack.local_filters.imm.service import IMMService
from fedtrack.local_filters.pda.config import load_config
from fedtrack.local_filters.pda.service import PDAService
from fedtrack.sensors.sonar import SonarConfig, sonar_scans
from fedtrack.wire import FusedTrack, Measurement, encode, measurement_from_replay
from fedtrack.zsession import SessionOptions

pytestmark = pytest.mark.fuzz

KEYS = Keys("fuzztrk")
OPTIONS = SessionOptions(connect=("tcp/127.0.0.1:1",))
HOSTILE = 400  # per example; 25 examples: 10,000 per service
EXAMPLES = 25
KINDS = ("sender", "kind", "dimension", "time_jump", "past", "overflow", "garbage")


def position_stream() -> list[Measurement]:
    rng = np.random.default_rng(4)
    R = np.array([[100.0, 5.0], [5.0, 100.0]])
    return [Measurement(sensor="p1", seq=k, t=float(k), kind="position",
                        z=np.array([1000.0 + 20.0 * k, -500.0 + 5.0 * k]) + rng.multivariate_normal([0, 0], R),
                        R=R, stamp_ns=k + 1) for k in range(25)]


def sonar_stream() -> list[Measurement]:
    lines = list(sonar_scans(SonarConfig(sensor="sonar1"), 3))[:8]
    return [measurement_from_replay({k: v for k, v in line.items() if k != "truth"}, "sonar", seq=k)
            for k, line in enumerate(lines)]


SERVICES: dict[str, tuple[Callable[[], Any], list[Measurement]]] = {
    "imm": (lambda: IMMService("p1", "ao-vsimm", load_imm_config(None), service_id="p1", options=OPTIONS,
                               deployment=KEYS.deployment), position_stream()),
    "hpda": (lambda: PDAService("sonar1", "hpda", load_config(None), service_id="sonar1", options=OPTIONS,
                                deployment=KEYS.deployment), sonar_stream()),
}


def run(name: str, attacks: dict[int, list[tuple[str, float]]]) -> tuple[list[FusedTrack], int]:
    make, stream = SERVICES[name]
    svc = make()
    svc._subscriptions = svc.subscriptions()
    out: list[FusedTrack] = []
    svc.publish = lambda key, msg: out.append(msg)  # type: ignore[method-assign]

    def send(key_sensor: str, payload: bytes) -> None:
        svc._dispatch(("sample", 0, KEYS.sensor_meas(key_sensor), payload))

    for k, meas in enumerate(stream):
        send(meas.sensor, encode(meas))
        for kind, value in attacks.get(k, []):
            if kind == "sender":
                send("other", encode(meas))
            elif kind == "kind":
                send(meas.sensor, encode(replace(meas, kind="radar", z=np.ones(3), R=np.eye(3), detections=(),
                                                 sensor_position=np.zeros(3))))
            elif kind == "dimension":
                send(meas.sensor, encode(replace(meas, z=np.ones(3), R=np.eye(3)) if meas.kind == "position"
                                         else replace(meas, R=np.eye(3), detections=())))
            elif kind == "time_jump":
                send(meas.sensor, encode(replace(meas, t=meas.t + 1e7 + abs(value))))
            elif kind == "past":
                send(meas.sensor, encode(replace(meas, t=meas.t - 1.0 - abs(value))))
            elif kind == "overflow":
                send(meas.sensor, encode(meas).replace(b"\x00" * 4, b"\x7f\xef\xff\xff", 1))
            else:
                send(meas.sensor, bytes(int(abs(value) * 7 + i) % 256 for i in range(45)))
    counted = sum(svc.counters.get(c, 0) for c in ("rejected", "unsupported", "out_of_order", "duplicate"))
    return out, counted


CLEAN = {name: run(name, {}) for name in SERVICES}


@pytest.mark.parametrize("name", sorted(SERVICES))
def test_clean_streams_are_tracked(name: str) -> None:
    tracks, counted = CLEAN[name]
    assert tracks and counted == 0


attack = st.tuples(st.integers(0, 7), st.sampled_from(KINDS), st.floats(-1e3, 1e3, allow_nan=False))


@pytest.mark.parametrize("name", sorted(SERVICES))
@settings(max_examples=EXAMPLES, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.large_base_example])
@given(attacks=st.lists(attack, min_size=HOSTILE, max_size=HOSTILE))
def test_hostile_measurements_are_counted_and_change_nothing(name: str, attacks: list[tuple[int, str, float]]) -> None:
    by_scan: dict[int, list[tuple[str, float]]] = {}
    for k, kind, value in attacks:
        by_scan.setdefault(k, []).append((kind, value))
    tracks, counted = run(name, by_scan)
    clean, _ = CLEAN[name]
    assert len(tracks) == len(clean)
    for a, b in zip(tracks, clean):
        assert a.seq == b.seq
        np.testing.assert_array_equal(a.x, b.x)
        np.testing.assert_array_equal(a.P, b.P)
    assert counted == HOSTILE
