"""Hypothesis-driven fuzz of the multi-target services' and the radar local filter's handlers with messages that
must be refused (redteam63): a compromised but authenticated peer sends, among a genuine stream, payloads with a
NaN or an infinity (a time or an array value), a field of the wrong type, an array of negative or huge claimed shape,
a list of 2,049 items, nesting 1,000 deep, a msgpack extension type, bytes that are no message, a genuine message on
another sensor's (or region's) key or on a key of another message type. Each must be counted (``rejected``, or a
``duplicate`` of the genuine one), raise nothing out of the dispatch, fail no handler (``rejected_handler_error``),
leave every picture (estimate) the clean run's and every service's state no larger than the clean run's (nothing of
a refused message kept). ``test_fuzz_services.py`` mutates at random and checks escapes only; this checks that no
such message steers a picture or grows a service. Deployments on the in-process bus of ``test_hostile_messages``:
the multi-target one (``mtt-centralized``, ``-federated``, ``-decentralized``), two region centres with
``serve picture``, the radar local filter."""

from __future__ import annotations

import math
import pickle
import random
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_fuzz_services import region_bus
from test_hostile_messages import KEYS, OPTIONS, Bus, _matches, mtt_lines, mtt_services
from test_mtt_regions_live import scenario as region_scenario

from fedtrack.local_filters.radar.filters import make_radar_filter
from fedtrack.local_filters.service import RadarLocalFilterService
from fedtrack.sensors.radar import RadarConfig, radar_scans
from fedtrack.services.base import Service
from fedtrack.wire import LocalEstimate, Measurement, TrackPicture, encode

pytestmark = pytest.mark.fuzz

KINDS = ("nan", "inf", "wrong_type", "negative_shape", "huge_shape", "long_list", "deep", "ext", "garbage",
         "other_sensor_key", "other_type_key")
HOSTILE = 12  # per example
EXAMPLES = 12


def arrays(obj: dict[str, Any]) -> list[dict[str, Any]]:
    """The array maps of a decoded payload (top level and one list down: a scan's detections)."""
    found = [v for v in obj.values() if isinstance(v, dict) and set(v) == {"dtype", "shape", "data"}]
    for v in obj.values():
        if isinstance(v, list):
            found += [a for d in v if isinstance(d, dict) for a in arrays(d)]
    return found


def deep() -> dict[str, Any]:
    value: dict[str, Any] = {}
    for _ in range(1000):
        value = {"v": value}
    return value


def hostile(key: str, payload: bytes, kind: str, rng: random.Random, keys: list[str]) -> tuple[str, bytes] | None:
    """A message of ``kind`` made from the genuine ``payload`` on ``key`` (None: ``kind`` does not apply to it);
    ``keys``: every key a genuine message came on."""
    if kind == "garbage":
        return key, bytes(rng.randrange(256) for _ in range(rng.randint(1, 200)))
    if kind in ("other_sensor_key", "other_type_key"):
        # another sensor's (region's) key of the same kind: the keys differ in one chunk
        one_off = {k for k in keys if len(k.split("/")) == len(key.split("/"))
                   and sum(a != b for a, b in zip(k.split("/"), key.split("/"))) == 1}
        other = sorted(one_off) if kind == "other_sensor_key" else [k for k in keys if k != key and k not in one_off]
        return (rng.choice(other), payload) if other else None
    obj = msgpack.unpackb(payload, raw=False)
    fields = [f for f in obj if f not in ("schema", "type")]
    filled = [a for a in arrays(obj) if a["data"]]
    if kind in ("nan", "inf"):
        bad = math.nan if kind == "nan" else rng.choice([math.inf, -math.inf])
        if "t" in obj and (not filled or rng.random() < 0.5):
            obj["t"] = bad
        elif filled:
            a = rng.choice(filled)
            values = np.frombuffer(a["data"], "<f8").copy()
            values[rng.randrange(values.size)] = bad
            a["data"] = values.tobytes()
        else:
            return None
    elif kind == "wrong_type":
        field = rng.choice(fields)
        obj[field] = [1] if isinstance(obj[field], str) else "x"
    elif kind in ("negative_shape", "huge_shape"):
        if not filled:
            return None
        a = rng.choice(filled)
        a["shape"] = [-rng.randint(1, 5), *a["shape"][1:]] if kind == "negative_shape" else [2**40, *a["shape"][1:]]
    elif kind == "long_list":
        lists = [f for f in fields if isinstance(obj[f], list)]
        if not lists:
            return None
        field = rng.choice(lists)
        obj[field] = [obj[field][0] if obj[field] else 0] * 2049
    else:  # deep, ext
        obj[rng.choice(fields)] = deep() if kind == "deep" else msgpack.ExtType(1, b"x")
    try:
        return key, msgpack.packb(obj, use_bin_type=True)
    except ValueError:  # deeper than msgpack's packer goes: the nesting alone
        return key, msgpack.packb(deep(), use_bin_type=True)


def state_size(services: list[Service]) -> list[int]:
    """Each service's checkpointed state, pickled: its size."""
    return [len(pickle.dumps(tuple(getattr(s, a) for a in s.state_attrs))) for s in services]


class Deployment:
    """A deployment's genuine inputs, how to build its services and what of its output must not move."""

    def __init__(self, make: Callable[[], Bus], inputs: list[tuple[str, bytes]],
                 outputs: Callable[[Bus], list[Any]], stop: Callable[[Bus], None] = lambda bus: None) -> None:
        self.make, self.inputs, self.outputs, self.stop = make, inputs, outputs, stop
        self.keys: list[str] = []
        bus = self.run([])
        self.clean, self.clean_sizes = outputs(bus), state_size(bus.services)
        # the keys of the genuine stream some service takes
        taken = {sub.key for svc in bus.services for sub in svc._subscriptions}
        self.keys = sorted({k for k, _ in [*inputs, *bus.published] if any(_matches(t, k) for t in taken)})

    def run(self, attacks: list[tuple[int, str, int]]) -> Bus:
        """The genuine inputs, each followed by the hostile messages made from the ``stream`` message at the
        positions ``attacks`` names (position, kind, seed) after it came; every refused one counted."""
        bus = self.make()
        due: dict[int, list[tuple[str, int]]] = {}
        for at, kind, seed in attacks:
            due.setdefault(at % len(self.inputs), []).append((kind, seed))
        for i, (key, payload) in enumerate(self.inputs):
            bus.put(key, payload)
            for kind, seed in due.get(i, []):
                rng = random.Random(seed)
                sources = [(k, p) for k, p in self.inputs[:i + 1] + [(k, encode(m)) for k, m in bus.published]
                           if k in self.keys]  # what a service takes
                made = hostile(*rng.choice(sources), kind, rng, self.keys)
                if made is None:
                    continue
                before = counted(bus.services)
                bus.put(*made)  # an exception here is an escape
                assert counted(bus.services) > before, f"a {kind} message on {made[0]} was not counted"
        self.stop(bus)
        assert sum(s.counters.get("rejected_handler_error", 0) for s in bus.services) == 0
        return bus


def counted(services: list[Service]) -> int:
    return sum(s.counters["rejected"] + s.counters.get("duplicate", 0) for s in services)


def pictures_of(bus: Bus, *keys: str) -> list[Any]:
    return [(k, p.seq, p.t, p.ids, p.x.tobytes(), p.P.tobytes(), p.contested) for k, p in bus.published
            if isinstance(p, TrackPicture) and (not keys or k in keys)]


def mtt(tmp: Path, algorithm: str) -> Deployment:
    lines = mtt_lines(tmp)
    runs = iter(range(10**6))

    def make() -> Bus:
        return Bus(list(mtt_services(tmp / f"{algorithm}-{next(runs)}", algorithm).values()))
    return Deployment(make, [(KEYS.sensor_meas(m.sensor), encode(m)) for m in lines], pictures_of,
                      lambda bus: bus.services[0].on_stop())


def regions(tmp: Path) -> Deployment:
    scans = region_scenario(tmp / "scenario")[0]
    runs = iter(range(10**6))

    def make() -> Bus:
        folder = tmp / f"regions-{next(runs)}"
        folder.mkdir()
        return region_bus(folder)
    return Deployment(make, [(KEYS.sensor_meas(m.sensor), encode(m)) for m in scans], pictures_of)


def radar() -> Deployment:
    lines = list(radar_scans(RadarConfig(), seed=3))[:40]
    scans = [Measurement(sensor="r1", seq=k, t=x["t"], kind="radar", z=np.array(x["z"]), R=np.array(x["R"]),
                         sensor_position=np.array(x["sensor_position"]), stamp_ns=1) for k, x in enumerate(lines)]

    def make() -> Bus:
        return Bus([RadarLocalFilterService("r1", make_radar_filter("ekf"), service_id="r1", options=OPTIONS,
                                            deployment=KEYS.deployment)])

    def estimates(bus: Bus) -> list[Any]:
        return [(e.seq, e.t, e.x.tobytes(), e.P.tobytes()) for e in bus.of(LocalEstimate)]
    return Deployment(make, [(KEYS.sensor_meas("r1"), encode(m)) for m in scans], estimates)


@pytest.fixture(scope="module")
def deployments(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Deployment]:
    tmp = tmp_path_factory.mktemp("refused")
    return {**{a: mtt(tmp, a) for a in ("mtt-centralized", "mtt-federated", "mtt-decentralized")},
            "regions": regions(tmp), "radar": radar()}


attack = st.tuples(st.integers(0, 10**6), st.sampled_from(KINDS), st.integers(0, 2**32 - 1))


@pytest.mark.parametrize("name", ["mtt-centralized", "mtt-federated", "mtt-decentralized", "regions", "radar"])
def test_refused_messages_steer_nothing_and_keep_nothing(deployments: dict[str, Deployment], name: str) -> None:
    deployment = deployments[name]
    assert len(deployment.clean) > 5

    @settings(max_examples=EXAMPLES, deadline=None, derandomize=True,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
    @given(st.lists(attack, min_size=HOSTILE, max_size=HOSTILE))
    def check(attacks: list[tuple[int, str, int]]) -> None:
        bus = deployment.run(attacks)
        assert deployment.outputs(bus) == deployment.clean
        assert all(a <= b for a, b in zip(state_size(bus.services), deployment.clean_sizes))

    check()
