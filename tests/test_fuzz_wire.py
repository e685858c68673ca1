"""Fuzzing every decoder: any payload is a valid message or a WireError, nothing else (hypothesis).

At least 10,000 generated payloads per message type: valid messages with one field replaced
by an arbitrary value (overflow-scale numbers, 2^63, huge or nested containers, malformed
arrays of any shape and dtype, msgpack extension types and timestamps), plus arbitrary msgpack
structures and raw bytes for every type.
"""

from __future__ import annotations

import math
from typing import Any

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_wire import (
    event,
    fused,
    health,
    local_estimate,
    position,
    reset,
    track_picture,
    track_report,
    track_resets,
)

from fedtrack.wire import MESSAGE_TYPES, HandOver, WireError, decode, encode

pytestmark = pytest.mark.fuzz

HAND_OVER = HandOver(source="x1y0", serial=0, id=1, confirmed=True, ring=np.zeros((1, 5)), neg_inf=(0,),
                     sensors=("s1",), support=(1,), streak=(0,), window=(True, False), last_support=0.0,
                     member_sensors=("s1",), member_ids=(3,), strikes=(0,))
SAMPLES = {type(m): m for m in (position(), local_estimate(), reset(), fused(), event(), health(), track_report(),
                                track_resets(), track_picture(), HAND_OVER)}
PAYLOADS = 10_000  # per message type

numbers = st.one_of(st.integers(min_value=-(2**63), max_value=2**64 - 1),
                    st.floats(allow_nan=True, allow_infinity=True),
                    st.sampled_from([9e307, -9e307, 1e308, 2.0**63, 2**62, 2**63, -1, 0, 1e-320]))
extensions = st.one_of(st.builds(msgpack.ExtType, st.integers(0, 127), st.binary(max_size=16)),
                       st.builds(msgpack.Timestamp, st.integers(0, 2**34 - 1), st.integers(0, 999_999_999)))
scalars = st.one_of(st.none(), st.booleans(), numbers, st.text(max_size=12), st.binary(max_size=40), extensions)


def arrays() -> st.SearchStrategy[dict[str, Any]]:
    """Array maps, well formed or not: any shape, dtype and data."""
    def build(shape: list[int], fill: float, dtype: str, cut: int) -> dict[str, Any]:
        n = math.prod(shape) if all(0 <= d <= 64 for d in shape) else 1
        data = np.full(n, fill, dtype="<f8").tobytes()
        return {"dtype": dtype, "shape": shape, "data": data[: max(len(data) - cut, 0)]}
    return st.builds(build, st.lists(st.integers(-2, 70), max_size=3), numbers.filter(lambda v: isinstance(v, float)),
                     st.sampled_from(["float64", "int64", "float32", "x"]), st.sampled_from([0, 0, 0, 1, 8]))


values = st.recursive(st.one_of(scalars, arrays()),
                      lambda inner: st.one_of(st.lists(inner, max_size=4),
                                              st.dictionaries(st.text(max_size=8), inner, max_size=4)),
                      max_leaves=12)


def check(payload: bytes, msg_type: type) -> bool:
    """True if ``payload`` is rejected (a WireError); else it must be a valid ``msg_type``."""
    try:
        msg = decode(payload, msg_type)
    except WireError:
        return True
    assert isinstance(msg, msg_type)
    decode(encode(msg), msg_type)  # what was accepted is a valid message
    return False


@pytest.mark.parametrize("msg_type", sorted(SAMPLES, key=lambda t: t.__name__), ids=lambda t: t.__name__)
def test_mutated_messages_are_valid_or_rejected(msg_type: type) -> None:
    """Each generated value goes into every field in turn (and as an extra field); every message type
    (``HandOver`` since the redteam59 session)."""
    assert set(SAMPLES) == set(MESSAGE_TYPES)
    base = msgpack.unpackb(encode(SAMPLES[msg_type]), raw=False)
    keys = sorted(base) + ["extra"]
    sent = 0

    @settings(max_examples=PAYLOADS // len(keys) + 1, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(value=values, nest=st.integers(0, 2))
    def run(value: Any, nest: int) -> None:
        nonlocal sent
        for _ in range(nest):
            value = {"v": value}
        for key in keys:
            check(msgpack.packb({**base, key: value}, use_bin_type=True), msg_type)
            sent += 1

    run()
    assert sent >= PAYLOADS


def test_arbitrary_payloads_are_rejected() -> None:
    @settings(max_examples=2_000, deadline=None, database=None, suppress_health_check=list(HealthCheck))
    @given(payload=st.one_of(st.binary(max_size=300), values.map(lambda v: msgpack.packb(v, use_bin_type=True))),
           msg_type=st.sampled_from(sorted(MESSAGE_TYPES, key=lambda t: t.__name__)))
    def run(payload: bytes, msg_type: type) -> None:
        tried.add(msg_type)
        rejected.append(check(payload, msg_type))

    tried: set[type] = set()
    rejected: list[bool] = []
    run()
    # no envelope ({"schema": 1, "type": ...} with every field) comes out of random bytes or structures
    assert len(rejected) >= 1_000 and all(rejected) and tried == set(MESSAGE_TYPES)


def test_deeply_nested_payload_is_rejected() -> None:
    deep: Any = []
    for _ in range(1000):
        deep = {"v": deep}
    for msg_type in MESSAGE_TYPES:
        with pytest.raises(WireError):
            decode(msgpack.packb(deep, use_bin_type=True), msg_type)


def test_overflow_scale_covariance_is_a_wire_error() -> None:
    obj = msgpack.unpackb(encode(position()), raw=False)
    obj["R"] = {"dtype": "float64", "shape": [2, 2], "data": np.full(4, 9e307).astype("<f8").tobytes()}
    with pytest.raises(WireError, match="overflow-scale"):
        decode(msgpack.packb(obj, use_bin_type=True), type(position()))
