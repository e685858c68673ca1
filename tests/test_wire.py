"""Wire protocol: round trips, every validation failure, replay conversions, key expressions."""

from __future__ import annotations

import dataclasses
from typing import Any

import msgpack
import numpy as np
import pytest

from fedtrack import wire
from fedtrack.jsonl import InputError
from fedtrack.keys import InvalidName, Keys
from fedtrack.wire import (
    SCHEMA_VERSION,
    Detection,
    FusedTrack,
    Health,
    LocalEstimate,
    ManeuverEvent,
    ManeuverInfo,
    Measurement,
    Reset,
    TrackPicture,
    TrackReport,
    TrackResets,
    WireError,
    decode,
    encode,
)
from tests.support import patch_wire

RNG = np.random.default_rng(7)


def spd(n: int) -> np.ndarray:
    A = RNG.normal(size=(n, n))
    P = A @ A.T + n * np.eye(n)
    return 0.5 * (P + P.T)


def position() -> Measurement:
    return Measurement(sensor="s1", seq=4, t=0.4, kind="position", z=RNG.normal(size=2), R=spd(2), stamp_ns=17)


def radar() -> Measurement:
    return Measurement(sensor="radar-1", seq=5, t=0.5, kind="radar", z=RNG.normal(size=3), R=spd(3),
                       sensor_position=np.array([1.0, -2.0, 0.5]), stamp_ns=18)


def sonar(n_det: int = 3) -> Measurement:
    return Measurement(sensor="sonar_2", seq=6, t=0.6, kind="sonar", z=np.zeros(0), R=spd(2),
                       detections=tuple(Detection(RNG.normal(size=2), float(a)) for a in RNG.uniform(1, 5, n_det)),
                       stamp_ns=19)


def local_estimate(maneuver: bool = True) -> LocalEstimate:
    info = ManeuverInfo(event="onset", detected=True, onset=0.3, u=RNG.normal(size=2), gamma=spd(2)) if maneuver else None
    return LocalEstimate(sensor="s1", seq=7, t=0.7, model="ca", x=RNG.normal(size=6), P=spd(6),
                         x_prior=RNG.normal(size=6), P_prior=spd(6), stamp_ns=20, maneuver=info,
                         degraded=("late",))


def reset() -> Reset:
    return Reset(sensor="s2", seq=8, t=0.8, model="cv", x=RNG.normal(size=4), P=spd(4), beta=0.25)


def fused() -> FusedTrack:
    return FusedTrack(seq=9, t=0.9, model="imm", x=RNG.normal(size=4), P=spd(4), maneuver=True, degraded=False,
                      sensors=("s1", "s2"), stamp_ns=21,
                      extra={"mode_probabilities": (0.25, 0.75), "status": "confirmed", "existence": 0.99,
                             "by_model": {"cv": 0.25, "ca": 0.75}})


def event() -> ManeuverEvent:
    return ManeuverEvent(seq=10, t=1.0, kind="new-ca", onset=0.7, u=RNG.normal(size=2), statistic=12.5)


def health() -> Health:
    return Health(role="recorder", id="rec-1", seq=11, counters={"received": 5, "rejected": 1}, status="ok")


ALL = [position, radar, sonar, local_estimate, lambda: local_estimate(False), reset, fused, event, health]


def assert_same(a: Any, b: Any, path: str = "msg") -> None:
    """Field-by-field exact equality (arrays bit-exact), recursing into records."""
    if dataclasses.is_dataclass(a):
        assert type(a) is type(b), path
        for f in dataclasses.fields(a):
            assert_same(getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and b.dtype == np.float64, path
        assert a.shape == b.shape and np.array_equal(a, b), path
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{path}[{i}]")
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for k in a:
            assert_same(a[k], b[k], f"{path}.{k}")
    else:
        assert type(a) is type(b) and a == b, path


@pytest.mark.parametrize("make", ALL)
def test_round_trip_every_message(make: Any) -> None:
    msg = make()
    back = decode(encode(msg), type(msg))
    assert_same(msg, back)
    assert encode(back) == encode(msg)


def test_decoded_arrays_are_read_only_and_covariances_exactly_symmetric() -> None:
    msg = decode(encode(local_estimate()), LocalEstimate)
    assert not msg.x.flags.writeable and not msg.P.flags.writeable
    assert np.array_equal(msg.P, msg.P.T)
    with pytest.raises(dataclasses.FrozenInstanceError):
        msg.seq = 3  # type: ignore[misc]


def test_construction_copies_and_converts_inputs() -> None:
    z = np.array([1.0, 2.0])
    m = Measurement(sensor="s", seq=np.int64(1), t=1, kind="position", z=z, R=[[1, 0], [0, 1]], stamp_ns=0)
    z[0] = 99.0
    assert m.z[0] == 1.0 and m.R.dtype == np.float64 and type(m.seq) is int and type(m.t) is float


def test_nearly_symmetric_covariance_is_accepted_and_symmetrized() -> None:
    R = spd(2)
    R[0, 1] += 1e-13 * np.abs(R).max()
    m = Measurement(sensor="s", seq=0, t=0.0, kind="position", z=[0.0, 0.0], R=R)
    assert np.array_equal(m.R, m.R.T)
    assert abs(m.R[0, 1] - 0.5 * (R[0, 1] + R[1, 0])) == 0.0


def test_int64_arrays_are_accepted_and_converted() -> None:
    obj = raw(position())
    obj["z"] = {"dtype": "int64", "shape": [2], "data": np.array([3, -4], dtype="<i8").tobytes()}
    m = decode(msgpack.packb(obj, use_bin_type=True), Measurement)
    assert m.z.dtype == np.float64 and m.z.tolist() == [3.0, -4.0]


# ------------------------------------------------------------------ validation failures

def raw(msg: Any) -> dict[str, Any]:
    return msgpack.unpackb(encode(msg), raw=False)


def tampered(msg: Any, **changes: Any) -> bytes:
    obj = raw(msg)
    for key, value in changes.items():
        if value is DELETE:
            del obj[key]
        else:
            obj[key] = value
    return msgpack.packb(obj, use_bin_type=True)


DELETE = object()


def arr(values: Any, dtype: str = "float64") -> dict[str, Any]:
    a = np.asarray(values, dtype={"float64": "<f8", "int64": "<i8", "float32": "<f4"}[dtype])
    return {"dtype": dtype, "shape": list(a.shape), "data": a.tobytes()}


def expect(payload: bytes, msg_type: type, field: str, reason: str) -> None:
    with pytest.raises(WireError) as info:
        decode(payload, msg_type)
    assert info.value.field == field, str(info.value)
    assert reason in info.value.reason, str(info.value)
    assert str(info.value).startswith(field)


@pytest.mark.parametrize("make, changes, field, reason", [
    (position, {"z": arr([np.nan, 1.0])}, "Measurement.z", "NaN"),
    (position, {"t": float("inf")}, "Measurement.t", "finite"),
    (local_estimate, {"P": arr(np.diag([1, 1, 1, 1, 1, np.inf]))}, "LocalEstimate.P", "NaN"),
    (position, {"z": arr([1.0, 2.0], "float32")}, "Measurement.z.dtype", "float64"),
    (position, {"z": {"dtype": "bool", "shape": [2], "data": b"\x01\x00"}}, "Measurement.z.dtype", "float64"),
    (position, {"z": [1.0, 2.0]}, "Measurement.z", "array map"),
    (position, {"R": arr([[1.0, 0.5], [0.0, 1.0]])}, "Measurement.R", "not symmetric"),
    (position, {"R": arr([[1.0, 2.0], [2.0, 1.0]])}, "Measurement.R", "not positive definite"),
    (position, {"R": arr([[1.0, 0.0], [0.0, 0.0]])}, "Measurement.R", "not positive definite"),
    (reset, {"P": arr(-np.eye(4))}, "Reset.P", "not positive definite"),
    (position, {"R": arr(np.eye(3))}, "Measurement.R", "match z"),
    (position, {"R": arr(np.ones((2, 3)))}, "Measurement.R", "square"),
    (position, {"z": arr(np.ones((2, 1)))}, "Measurement.z", "dimension"),
    (position, {"z": {"dtype": "float64", "shape": [2], "data": b"\x00" * 8}}, "Measurement.z.data", "16 bytes"),
    (position, {"z": {"dtype": "float64", "shape": [1, 1, 2], "data": b"\x00" * 16}}, "Measurement.z.shape", ""),
    (position, {"z": {"dtype": "float64", "shape": [-2], "data": b""}}, "Measurement.z.shape", ""),
    (local_estimate, {"x_prior": arr(np.zeros(4))}, "LocalEstimate.P_prior", "match x_prior"),
    (local_estimate, {"P_prior": arr(np.eye(4))}, "LocalEstimate.P_prior", "match x"),
    (fused, {"P": arr(np.eye(6))}, "FusedTrack.P", "match x"),
    (local_estimate, {"maneuver": {"event": "onset", "detected": True, "onset": 0.1, "u": arr([1.0, 2.0]), "gamma": arr(np.eye(3))}},
     "LocalEstimate.maneuver.gamma", "match u"),
    (local_estimate, {"maneuver": {"event": "onset", "detected": 1, "onset": 0.1, "u": arr([1.0]), "gamma": arr(np.eye(1))}},
     "LocalEstimate.maneuver.detected", "true or false"),
    (position, {"sensor": None}, "Measurement.sensor", "string"),
    (position, {"sensor": "a/b"}, "Measurement.sensor", "forbidden"),
    (position, {"sensor": ""}, "Measurement.sensor", "empty"),
    (position, {"seq": "4"}, "Measurement.seq", "integer"),
    (position, {"seq": True}, "Measurement.seq", "integer"),
    (position, {"seq": -1}, "Measurement.seq", "[0, 2**63)"),
    (position, {"t": "now"}, "Measurement.t", "number"),
    (position, {"t": 1e300}, "Measurement.t", "beyond +-1e+100"),  # taken before 2026-11-27, as any finite real
    (sonar, {"detections": [{"z": arr([1.0, 2.0]), "amplitude": -1e101}]},
     "Measurement.detections[0].amplitude", "beyond +-1e+100"),
    (position, {"kind": "lidar"}, "Measurement.kind", "one of"),
    (position, {"detections": [{"z": arr([1.0, 2.0]), "amplitude": 1.0}]}, "Measurement.detections", "only sonar"),
    (radar, {"sensor_position": None}, "Measurement.sensor_position", "required for radar"),
    (radar, {"sensor_position": arr([1.0])}, "Measurement.sensor_position", "2 or 3"),
    (sonar, {"z": arr([1.0, 2.0])}, "Measurement.z", "empty for sonar"),
    (sonar, {"detections": [{"z": arr([1.0, 2.0, 3.0]), "amplitude": 1.0}]}, "Measurement.detections[0].z",
     "does not match R"),
    (sonar, {"detections": [{"z": arr([1.0, 2.0]), "amplitude": float("nan")}]},
     "Measurement.detections[0].amplitude", "finite"),
    (sonar, {"detections": [{"z": arr([1.0, 2.0])}]}, "Measurement.detections[0].amplitude", "missing"),
    (reset, {"beta": 0.0}, "Reset.beta", "(0, 1]"),
    (reset, {"beta": 1.5}, "Reset.beta", "(0, 1]"),
    (fused, {"maneuver": "yes"}, "FusedTrack.maneuver", "true or false"),
    (fused, {"sensors": ["s1", "s*"]}, "FusedTrack.sensors[1]", "forbidden"),
    (fused, {"extra": {"x": 1.0}}, "FusedTrack.extra.x", "reserved"),
    (fused, {"extra": {"p": [0.5, float("nan")]}}, "FusedTrack.extra.p[1]", "finite"),
    (fused, {"extra": {"p": {"cv": "high"}}}, "FusedTrack.extra.p.cv", "number"),
    (fused, {"extra": {"p": None}}, "FusedTrack.extra.p", "number"),
    (event, {"kind": "start"}, "ManeuverEvent.kind", "one of"),
    (health, {"counters": {"received": -3}}, "Health.counters.received", "[0, 2**63)"),
    (health, {"counters": {"received": 1.5}}, "Health.counters.received", "integer"),
    (health, {"status": 3}, "Health.status", "string"),
])
def test_invalid_field_raises_wire_error_naming_it(make: Any, changes: dict[str, Any], field: str,
                                                   reason: str) -> None:
    msg = make()
    expect(tampered(msg, **changes), type(msg), field, reason)


def test_missing_unknown_and_envelope_fields() -> None:
    m = position()
    expect(tampered(m, R=DELETE), Measurement, "Measurement.R", "missing field")
    expect(tampered(m, sensor_position=DELETE), Measurement, "Measurement.sensor_position", "missing field")
    expect(tampered(m, colour="red"), Measurement, "Measurement.colour", "unknown field")
    expect(tampered(m, schema=SCHEMA_VERSION + 1), Measurement, "Measurement.schema",
           f"unsupported schema version {SCHEMA_VERSION + 1}")
    expect(tampered(m, schema=DELETE), Measurement, "Measurement.schema", "missing")
    expect(tampered(m, type="Reset"), Measurement, "Measurement.type", "expected 'Measurement'")
    expect(encode(m), Health, "Health.type", "got 'Measurement'")


@pytest.mark.parametrize("payload, reason", [
    (b"\xc1garbage", "not valid msgpack"),
    (b"", "not valid msgpack"),
    (b"\x91" * 5000, "not valid msgpack"),
    (msgpack.packb([1, 2, 3]), "expected a msgpack map"),
    (b"\x00" * (wire.MAX_PAYLOAD_BYTES + 1), "exceed the limit"),
])
def test_garbage_and_oversize_payloads(payload: bytes, reason: str) -> None:
    expect(payload, Measurement, "payload", reason)


def test_size_bounds() -> None:
    n = wire.MAX_ARRAY_ELEMENTS + 1
    expect(tampered(position(), z=arr(np.zeros(n))), Measurement, "Measurement.z.shape", "at most 2 sizes")
    expect(tampered(local_estimate(), P=arr(np.eye(65))), LocalEstimate, "LocalEstimate.P", "exceed the limit")
    too_many = [{"z": arr([1.0, 2.0]), "amplitude": 1.0}] * (wire.MAX_DETECTIONS + 1)
    expect(tampered(sonar(), detections=too_many), Measurement, "payload", "max_array_len")  # msgpack's own limit
    expect(tampered(fused(), extra={f"k{i}": 1.0 for i in range(wire.MAX_MAP_ITEMS + 1)}), FusedTrack,
           "FusedTrack.extra", "exceed the limit")
    expect(tampered(health(), status="x" * (wire.MAX_STRING_LENGTH + 1)), Health, "Health.status", "longer")
    # a FusedTrack at every bound (64-state, 32 extra lists of 64 floats) still fits in one payload
    big = FusedTrack(seq=0, t=0.0, model="cv", x=np.zeros(64), P=np.eye(64), maneuver=False, degraded=False,
                     sensors=(), stamp_ns=0, extra={f"k{i}": tuple(range(64)) for i in range(32)})
    assert_same(big, decode(encode(big), FusedTrack))
    d = 64  # a sonar scan at every bound: MAX_DETECTIONS detections of the largest z whose R fits the element bound
    widest = Measurement(sensor="s", seq=0, t=0.0, kind="sonar", z=[], R=np.eye(d),
                         detections=[(np.ones(d), 1.0)] * wire.MAX_DETECTIONS)
    assert len(encode(widest)) < wire.MAX_PAYLOAD_BYTES
    assert_same(widest, decode(encode(widest), Measurement))


def test_construction_validates_like_decoding() -> None:
    with pytest.raises(WireError, match=r"^Measurement\.R: not positive definite"):
        Measurement(sensor="s", seq=0, t=0.0, kind="position", z=[0.0, 0.0], R=[[1.0, 2.0], [2.0, 1.0]])
    with pytest.raises(WireError, match=r"^Measurement\.detections\[1\]\.z: contains NaN"):
        Measurement(sensor="s", seq=0, t=0.0, kind="sonar", z=[], R=np.eye(2),
                    detections=[([0.0, 0.0], 1.0), ([np.nan, 0.0], 1.0)])
    with pytest.raises(WireError, match=r"^Measurement\.detections\[0\]: expected a Detection or a \(z, amplitude\)"):
        Measurement(sensor="s", seq=0, t=0.0, kind="sonar", z=[], R=np.eye(2), detections=[[0.0, 0.0, 1.0]])
    with pytest.raises(WireError, match=r"^LocalEstimate\.maneuver\.u: expected an array"):
        dataclasses.replace(local_estimate(), maneuver={"event": "onset", "detected": True, "onset": 0.0, "u": ["a"], "gamma": [[1]]})
    with pytest.raises(WireError, match=r"^message: not a wire message type"):
        encode({"schema": 1})  # type: ignore[arg-type]


# ------------------------------------------------------------------ replay JSON lines

@pytest.mark.parametrize("make", [position, radar, sonar])
def test_measurement_replay_round_trip(make: Any) -> None:
    m = make()
    row = wire.measurement_to_replay(m)
    expected_keys = {"t", "sensor", "z", "R"} | ({"sensor_position"} if m.kind == "radar" else set()) \
        | ({"detections"} if m.kind == "sonar" else set())
    assert set(row) == expected_keys
    back = wire.measurement_from_replay(row, "m.jsonl:1", seq=m.seq)
    assert_same(dataclasses.replace(m, stamp_ns=0), back)


def test_track_replay_round_trip_puts_extra_at_top_level() -> None:
    tr = fused()
    row = wire.track_to_replay(tr)
    assert row["mode_probabilities"] == [0.25, 0.75] and row["seq"] == 9 and row["degraded"] is False
    assert_same(dataclasses.replace(tr, stamp_ns=0), wire.track_from_replay(row, "t.jsonl:1"))
    minimal = wire.track_from_replay({"t": 1.0, "x": [0, 0], "P": [[1, 0], [0, 1]], "model": "cv",
                                      "maneuver": False, "event": None}, "t.jsonl:2", seq=5)
    assert minimal.seq == 5 and minimal.sensors == () and minimal.extra == {} and minimal.degraded is False


@pytest.mark.parametrize("row, message", [
    ({"t": 0.0, "z": [1.0], "R": [[1.0]]}, "m.jsonl:3: missing field 'sensor'"),
    ({"t": 0.0, "sensor": "s", "z": [1.0], "R": np.eye(2).tolist()}, "m.jsonl:3: Measurement.R: expected shape (1, 1)"),
    ({"t": 0.0, "sensor": "s", "z": [1.0, [2]], "R": [[1.0]]}, "m.jsonl:3: z must be a (nested) list"),
    ({"t": 0.0, "sensor": "s", "z": [1.0], "R": [[1.0]], "truth": 1}, "m.jsonl:3: unknown field 'truth'"),
    ({"t": 0.0, "sensor": "s", "z": [], "R": [[1.0]], "detections": [{"z": [1.0]}]},
     "m.jsonl:3: detections[0]: missing field 'amplitude'"),
])
def test_measurement_from_replay_errors_name_line_and_field(row: dict[str, Any], message: str) -> None:
    with pytest.raises(InputError) as info:
        wire.measurement_from_replay(row, "m.jsonl:3")
    assert str(info.value).startswith(message), str(info.value)


def test_track_from_replay_errors_name_line_and_field() -> None:
    with pytest.raises(InputError, match=r"^t.jsonl:4: FusedTrack.P: not symmetric"):
        wire.track_from_replay({"t": 0.0, "x": [0, 0], "P": [[1, 0.5], [0, 1]], "model": "cv", "maneuver": False},
                               "t.jsonl:4")


# ------------------------------------------------------------------ key expressions

def test_keys() -> None:
    k = Keys("lab")
    assert k.sensor_meas("s1") == "fedtrack/lab/sensor/s1/meas"
    assert k.sensor_meas() == "fedtrack/lab/sensor/*/meas"
    assert k.local_estimate("s1") == "fedtrack/lab/local/s1/estimate"
    assert k.fusion_reset("s1") == "fedtrack/lab/fusion/reset/s1"
    assert k.fusion_track() == "fedtrack/lab/fusion/track"
    assert k.fusion_event() == "fedtrack/lab/fusion/event"
    assert k.fusion_state() == "fedtrack/lab/fusion/state"
    assert k.health("recorder", "r1") == "fedtrack/lab/health/recorder/r1"
    assert k.health() == "fedtrack/lab/health/*/*"
    assert k.alive("router", "main") == "fedtrack/lab/alive/router/main"
    assert Keys().fusion_track() == "fedtrack/demo/fusion/track"


@pytest.mark.parametrize("bad", ["", "a/b", "a*", "$x", "q?", "#1", "has space", "x" * 65])
def test_keys_reject_bad_ids(bad: str) -> None:
    with pytest.raises(InvalidName, match="sensor id"):
        Keys("lab").sensor_meas(bad)
    with pytest.raises(InvalidName, match="deployment"):
        Keys(bad)


def test_encoder_refuses_payloads_over_the_limit(monkeypatch: pytest.MonkeyPatch) -> None:
    msg = sonar(n_det=50)
    patch_wire(monkeypatch, "MAX_PAYLOAD_BYTES", len(encode(msg)) - 1)
    with pytest.raises(WireError, match=r"^Measurement: encoded size \d+ bytes exceeds the limit"):
        encode(msg)


def track_report() -> TrackReport:
    return TrackReport(sensor="s2", seq=11, t=1.1, ids=(4, 7), x=RNG.normal(size=(2, 4)),
                       P=np.concatenate([spd(4), spd(4)]), confirmed=(True, False), detected=(True, False),
                       obs_H=RNG.normal(size=(2, 4)), obs_R=spd(2), obs_z=RNG.normal(size=(1, 2)), started=(False,),
                       retired=(1, 3), stamp_ns=23)


def existence_report() -> TrackReport:
    """A report of jipda's local tracker: each track's existence beside its state."""
    return TrackReport(**{**vars(track_report()), "existence": np.array([0.97, 0.4])})


def earth_picture() -> TrackPicture:
    """A picture with existence and each track's WGS-84 position (``[frame]`` set)."""
    return TrackPicture(**{**vars(maneuver_picture()), "existence": np.array([0.99, 0.5]),
                           "lla": np.array([[48.85, 2.35, 120.0], [-33.9, 151.2, 15.0]])})


def track_resets() -> TrackResets:
    return TrackResets(sensor="s2", seq=11, t=1.1, q_scale=3.0, ids=(4,), x=RNG.normal(size=(1, 4)), P=spd(4))


def track_picture() -> TrackPicture:
    return TrackPicture(seq=2, t=2.0, ids=(9,), x=RNG.normal(size=(1, 6)), P=spd(6), confirmed=(True,),
                        sensors=(("s1", "s2"),), fused_sensors=("s1", "s2"), fused_seqs=(5, 7), stamp_ns=24)


def scan() -> Measurement:
    return Measurement(sensor="s3", seq=2, t=0.2, kind="scan", z=np.zeros(0), R=spd(3),
                       detections=((np.array([900.0, 0.1, 0.02]), 0.0),), sensor_position=np.zeros(3), stamp_ns=5)


def maneuver_picture() -> TrackPicture:
    """A picture of two central tracks, the second's maneuver detected."""
    return TrackPicture(seq=3, t=3.0, ids=(9, 12), x=RNG.normal(size=(2, 4)), P=np.concatenate([spd(4), spd(4)]),
                        confirmed=(True, False), sensors=(("s1",), ("s2",)), fused_sensors=(), fused_seqs=(),
                        stamp_ns=25, maneuvering=(1,), maneuver=np.array([[2.1, 1.5, -0.5, 31.0]]))


def test_a_picture_carries_central_maneuvers_to_its_replay_line() -> None:
    from fedtrack.wire import picture_to_replay

    rows = picture_to_replay(decode(encode(maneuver_picture()), TrackPicture))["tracks"]
    assert "maneuver" not in rows[0]
    assert rows[1]["maneuver"] == {"onset": 2.1, "accel": [1.5, -0.5], "statistic": 31.0}


def test_a_picture_carries_existence_and_the_earth_to_its_replay_line() -> None:
    from fedtrack.wire import picture_to_replay

    rows = picture_to_replay(decode(encode(earth_picture()), TrackPicture))["tracks"]
    assert [(r["existence"], r["lat"], r["lon"], "alt" in r) for r in rows] == \
        [(0.99, 48.85, 2.35, False), (0.5, -33.9, 151.2, False)]  # 2-D states: no altitude


@pytest.mark.parametrize("make", [track_report, track_resets, track_picture, scan, maneuver_picture,
                                  existence_report, earth_picture])
def test_multitarget_messages_round_trip(make) -> None:
    msg = make()
    back = decode(encode(msg), type(msg))
    assert encode(back) == encode(msg)


@pytest.mark.parametrize("change, field", [
    (lambda m: TrackReport(**{**vars(m), "ids": (4, 4)}), "ids"),  # repeated id
    (lambda m: TrackReport(**{**vars(m), "obs_z": np.zeros((0, 2)), "started": ()}), "obs_z"),  # one per detected
    (lambda m: TrackReport(**{**vars(m), "P": np.concatenate([spd(4), -spd(4)])}), "P"),  # not PD
    (lambda m: TrackResets(**{**vars(track_resets()), "q_scale": 0.5}), "q_scale"),
    (lambda m: TrackPicture(**{**vars(track_picture()), "fused_seqs": (5,)}), "fused_seqs"),
    (lambda m: TrackPicture(**{**vars(track_picture()), "closing": True}), "ids"),  # a closing record has none
    (lambda m: TrackPicture(**{**vars(maneuver_picture()), "maneuvering": (2,)}), "maneuvering"),  # no such track
    (lambda m: TrackPicture(**{**vars(maneuver_picture()), "maneuvering": (0, 1)}), "maneuver"),  # one row short
    (lambda m: TrackPicture(**{**vars(maneuver_picture()), "maneuver": None}), "maneuver"),
    (lambda m: TrackPicture(**{**vars(maneuver_picture()), "maneuver": np.array([[np.nan, 0, 0, 1.0]])}), "maneuver"),
    (lambda m: TrackReport(**{**vars(existence_report()), "existence": np.array([0.5, 1.5])}), "existence"),
    (lambda m: TrackReport(**{**vars(existence_report()), "existence": np.array([0.5])}), "existence"),
    (lambda m: TrackPicture(**{**vars(earth_picture()), "existence": np.array([-0.1, 0.5])}), "existence"),
    (lambda m: TrackPicture(**{**vars(earth_picture()), "lla": np.array([[95.0, 2.0, 0.0], [0.0, 0.0, 0.0]])}), "lla"),
    (lambda m: TrackPicture(**{**vars(earth_picture()), "lla": np.zeros((1, 3))}), "lla"),
])
def test_multitarget_messages_are_checked(change, field: str) -> None:
    with pytest.raises(WireError, match=field):
        change(track_report())


@pytest.mark.parametrize("d", [4, 6])
def test_picture_line_holds_the_rows_exactly(d: int) -> None:
    """The picture writer (orjson) gives the rows' values exactly (every float round-trips):
    symmetric and non-symmetric covariances, mixed statuses, sensors and models; a non-finite
    number in json's spelling."""
    import json

    from fedtrack.wire import picture_line, picture_rows

    n = 7
    X = RNG.normal(size=(n, d)) * 1e3
    A = RNG.normal(size=(n, d, d))
    P = A @ np.swapaxes(A, -1, -2)
    P = 0.5 * (P + np.swapaxes(P, -1, -2))
    ids, confirmed = list(range(3, 3 + n)), [k % 2 == 0 for k in range(n)]
    sensors = [["s1", "s2"] if k % 3 else ['s"3'] for k in range(n)]
    models = ["ca" if k == 2 else "cv" for k in range(n)]
    skewed = P.copy()
    skewed[:, 0, 1] += 1e-6
    broken = X.copy()
    broken[1, 0] = np.nan
    for cov in (P, skewed, P * 1e-30, P * 1e30):
        for m in (models, None):
            expected = {"t": 12.5, "tracks": picture_rows(ids, X, cov, confirmed, sensors, m)}
            assert json.loads(picture_line(12.5, ids, X, cov, confirmed, sensors, m)) == expected
    nan_line = json.dumps({"t": 12.5, "tracks": picture_rows(ids, broken, P, confirmed, sensors, models)})
    assert picture_line(12.5, ids, broken, P, confirmed, sensors, models) == nan_line
    assert json.loads(picture_line(0.0, [], np.zeros((0, d)), np.zeros((0, d, d)), [], [])) == {"t": 0.0, "tracks": []}


def test_a_pictures_centre_starts_and_missing_regions_are_checked() -> None:
    """``began`` names distinct positions of the fused lists, none a departure, each with its hand-over
    number; ``missing`` distinct region ids; both round-trip and are left off the wire when empty."""
    base = dict(seq=1, t=1.0, ids=(), x=np.zeros((0, 4)), P=np.zeros((0, 4)), confirmed=(), sensors=(),
                fused_sensors=("x0y0", "s1"), fused_seqs=(4, 2), stamp_ns=1)
    ok = TrackPicture(**base, began=(0,), began_serials=(3,), missing=("x1y0",))
    again = decode(encode(ok), TrackPicture)
    assert (again.began, again.began_serials, again.missing) == ((0,), (3,), ("x1y0",))
    assert b"began" not in encode(TrackPicture(**base)) and b"missing" not in encode(TrackPicture(**base))
    for bad in (dict(began=(0,)), dict(began=(2,), began_serials=(3,)), dict(began=(1,), began_serials=(3,), left=(1,)),
                dict(missing=("x1y0", "x1y0"))):
        with pytest.raises(WireError):
            TrackPicture(**base, **bad)
