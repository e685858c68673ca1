"""The wire's fast paths give exactly the per-item paths' outcomes (hypothesis, about 3 s).

A scan's detections decoded at once (``codec._regular_detections``) against the per-item decode
(the fast path switched off): equal records or the same WireError (field, reason), and the same
bytes when encoded again. The structure limits walked level by level against the depth-first walk
that names the error. An array encoded without a conversion when it needs none: the same bytes.
"""

from __future__ import annotations

import copy
from typing import Any

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_wire import assert_same

from fedtrack.wire import Detection, Measurement, WireError, batches, codec, decode, encode
from tests.support import patch_wire

pytestmark = pytest.mark.fuzz

SETTINGS = settings(max_examples=300, deadline=None, database=None, suppress_health_check=list(HealthCheck))

# mutations of one detection: (what, value); values that the per-item path rejects, or accepts differently
ODD_VALUES = [None, True, 1.5, "x", b"\x00" * 8, [], {}, float("nan"), float("inf"), 2**64 - 1, -(2**63), 1e308]
Z_FILL = [float("nan"), float("inf"), -float("inf"), 1.1e100, -1e101, 1e100, 0.0, -0.0]


def outcome(payload: bytes) -> Measurement | WireError:
    try:
        return decode(payload, Measurement)
    except WireError as exc:
        return exc


def per_item(payload: bytes) -> Measurement | WireError:
    """The decode with the fast path switched off: every detection through ``_decode_record``."""
    with pytest.MonkeyPatch.context() as mp:
        patch_wire(mp, "_regular_detections", lambda items: None)
        return outcome(payload)


@st.composite
def scans(draw: st.DrawFn) -> tuple[dict[str, Any], bool]:
    """A scan's msgpack map with a generated detection list, and whether any detection was mutated."""
    d = draw(st.integers(0, 4))
    n = draw(st.integers(1, 30))
    dtype = draw(st.sampled_from(["float64", "float64", "int64"]))
    if dtype == "float64":
        values = draw(st.lists(st.floats(-1e6, 1e6), min_size=n * d, max_size=n * d))
    else:
        values = draw(st.lists(st.integers(-(2**63), 2**63 - 1), min_size=n * d, max_size=n * d))
    data = np.asarray(values, dtype="<f8" if dtype == "float64" else "<i8").reshape(n, d)
    amplitude = st.one_of(st.floats(-1e3, 1e3), st.integers(-(2**63), 2**64 - 1))
    dets = [{"z": {"dtype": dtype, "shape": [d], "data": row.tobytes()}, "amplitude": draw(amplitude)}
            for row in data]
    mutated = False
    for _ in range(draw(st.sampled_from([0, 0, 1, 1, 2]))):
        mutated = True
        j = draw(st.integers(0, n - 1))
        det = dets[j]
        what = draw(st.sampled_from(["item", "drop", "add", "z", "z-drop", "z-add", "dtype", "shape", "data",
                                     "fill", "amplitude"]))
        odd = copy.deepcopy(draw(st.sampled_from(ODD_VALUES)))  # a fresh {} or [] each time
        if what == "item" or not isinstance(det, dict):
            dets[j] = odd
        elif what == "drop":
            det.pop(draw(st.sampled_from(["z", "amplitude"])), None)  # a second mutation may drop what one dropped
        elif what == "add":
            det["extra"] = 1.0
        elif what == "amplitude":
            det["amplitude"] = draw(st.sampled_from([float("nan"), float("inf"), -float("inf"), odd]))
        elif what == "z" or not isinstance(det.get("z"), dict):
            det["z"] = odd
        elif what in ("z-drop", "z-add"):
            gone = draw(st.sampled_from(["dtype", "shape", "data"]))
            det["z"] = {k: v for k, v in det["z"].items() if k != gone}
            if what == "z-add":
                det["z"]["extra"] = 1
        elif what == "dtype":
            det["z"] = {**det["z"], "dtype": draw(st.sampled_from(["float32", "int64", "float64", 8, None]))}
        elif what == "shape":
            det["z"] = {**det["z"], "shape": draw(st.sampled_from(
                [[True], [False], [float(d)], [d, 1], [1, d], [d + 1], [], [-1], [4097], "x", [None], None]))}
        elif what == "data":
            cut = draw(st.sampled_from([-8, -1, 1, 8]))
            raw = det["z"].get("data", b"")
            det["z"] = {**det["z"], "data": raw[:cut] if cut < 0 else raw + b"\x00" * cut}
        elif d:  # fill: one value of z out of bounds or at them
            row = np.ones(d)
            row[draw(st.integers(0, d - 1))] = draw(st.sampled_from(Z_FILL))
            det["z"] = {"dtype": "float64", "shape": [d], "data": row.tobytes()}
    r = draw(st.sampled_from([d, d, max(d, 1), 2]))  # R of the detections' size mostly; else a mismatch
    base = msgpack.unpackb(encode(Measurement(sensor="s", seq=1, t=0.5, kind=draw(st.sampled_from(["scan", "sonar"])),
                                              z=[], R=np.eye(max(r, 1)), stamp_ns=7)), raw=False)
    return {**base, "detections": dets}, mutated


def test_decoding_detections_at_once_equals_the_per_item_decode() -> None:
    seen = {"fast": 0, "valid": 0, "rejected": 0}

    @SETTINGS
    @given(scan=scans())
    def run(scan: tuple[dict[str, Any], bool]) -> None:
        obj, mutated = scan
        payload = msgpack.packb(obj, use_bin_type=True)
        fast, slow = outcome(payload), per_item(payload)
        if not mutated:  # a regular list: the fast path takes it whatever the scan's other checks say
            assert codec._regular_detections(obj["detections"]) is not None
        seen["fast"] += codec._regular_detections(obj["detections"]) is not None
        if isinstance(slow, WireError):
            seen["rejected"] += 1
            assert isinstance(fast, WireError), (slow, fast)
            assert (fast.field, fast.reason) == (slow.field, slow.reason)
            return
        seen["valid"] += 1
        assert isinstance(fast, Measurement), fast
        assert_same(fast, slow)
        assert isinstance(fast.detections, tuple)
        for a, b in zip(fast.detections, slow.detections):
            assert type(a) is Detection and type(a.amplitude) is float
            assert a.z.flags.writeable is b.z.flags.writeable is False
            assert a.z.dtype == b.z.dtype == np.float64
        assert encode(fast) == encode(slow)

    run()
    # both outcomes and both paths were exercised, not just one (each typically 80-190 of the 300; a
    # CI run once drew only 38 valid scans, so the floor is 20, not 50)
    assert min(seen.values()) >= 20, seen


def test_level_walk_of_the_structure_limits_equals_the_depth_first_walk(monkeypatch: pytest.MonkeyPatch) -> None:
    patch_wire(monkeypatch, "MAX_DEPTH", 3)  # small limits, so that generated structures meet either or both
    patch_wire(monkeypatch, "MAX_ITEMS", 10)
    leaves = st.one_of(st.none(), st.integers())
    structures = st.recursive(leaves, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                              st.dictionaries(st.text(max_size=2), inner, max_size=3)),
                              max_leaves=30)
    seen = {"passed": 0, "deep": 0, "many": 0}

    @settings(SETTINGS, derandomize=True)  # the same 300 examples every run: each kind of outcome 10 times or more
    @given(obj=structures, wrap=st.integers(0, 2))
    def run(obj: Any, wrap: int) -> None:
        for _ in range(wrap):  # deeper
            obj = [obj, 0]
        def check(walk: Any) -> str:
            try:
                walk(obj)
            except WireError as exc:
                assert exc.field == "payload"
                return exc.reason
            return "passed"

        level = check(codec._check_structure)
        assert level == check(codec._structure_error)
        seen["deep" if "deep" in level else "many" if "items" in level else "passed"] += 1

    run()
    assert min(seen.values()) >= 10, seen


@settings(SETTINGS, max_examples=100)
@given(shape=st.lists(st.integers(0, 5), min_size=1, max_size=2), layout=st.sampled_from(["<f8", ">f8", "<f4", "<i8",
                                                                                          "fortran", "strided"]),
       seed=st.integers(0, 2**32 - 1))
def test_an_array_encodes_to_its_values_as_little_endian_float64(shape: list[int], layout: str, seed: int) -> None:
    """``_encode_array`` converts only what is not little-endian float64 already: the bytes are
    ``astype("<f8").tobytes()``'s (the conversion it always made before) for any dtype and layout."""
    values = np.random.default_rng(seed).normal(scale=1e3, size=shape)
    if layout == "fortran":
        arr = np.asfortranarray(values)
    elif layout == "strided":
        arr = np.repeat(values, 2, axis=-1)[..., ::2]
    else:
        arr = values.astype(layout)
    assert codec._encode_array(arr) == {"dtype": "float64", "shape": list(arr.shape),
                                       "data": arr.astype("<f8").tobytes()}


def _outcome(check: Any, value: Any) -> Any:
    try:
        out = check(value, "f")
    except WireError as exc:
        return ("error", exc.field, exc.reason)
    assert type(out) is tuple
    return ("value", tuple((type(v), v) for v in out))


ODD_ITEMS = st.sampled_from([True, False, 0, 1, 7, -1, 2**63 - 1, 2**63, 1.0, None, "1", np.bool_(True),
                             np.int64(3)])


@settings(SETTINGS, max_examples=300)
@given(items=st.lists(ODD_ITEMS, max_size=12), as_tuple=st.booleans())
def test_per_track_flags_and_counts_at_once_equal_the_per_item_check(items: list[Any], as_tuple: bool) -> None:
    """``_flags`` and ``_counts`` take a list of plain booleans or in-range ints at once: the same
    tuple (types included) as the per-item check, or, for anything else, the same error."""
    value = tuple(items) if as_tuple else items
    assert _outcome(batches._flags, value) == _outcome(batches._flags_each, value)
    assert _outcome(batches._counts, value) == _outcome(batches._counts_each, value)
    regular = [bool(i % 2) for i in range(len(items))]
    assert _outcome(batches._flags, regular) == _outcome(batches._flags_each, regular)
