"""Typed wire messages of the distributed pipeline, encoded with msgpack.

Usage::

    payload = encode(Measurement(sensor="s1", seq=3, t=0.3, kind="position",
                                 z=[1.0, 2.0], R=np.eye(2)))
    msg = decode(payload, Measurement)      # raises WireError naming the field

Every message is a frozen dataclass that validates itself on construction, so an
object of these types is always valid: decoding and building one in Python run
the same checks. Arrays are stored as read-only float64 numpy arrays and
covariances are exactly symmetric (symmetrized after the tolerance check).

On the wire a message is a msgpack map ``{"schema": SCHEMA_VERSION, "type":
<class name>, <field>: <value>, ...}``. Every field is present (optional ones
may be nil); unknown fields are rejected. A numpy array is a map ``{"dtype":
"float64" | "int64", "shape": [d0, ...], "data": <little-endian bytes>}``.
A message whose batch (detections, tracks) exceeds a bound of one message is sent as
:func:`parts` (at most MAX_PARTS messages, each within every bound; :func:`payloads` encodes
them) and rebuilt by the receiver with :func:`join`. The full contract is in ``docs/wire.md``.

The package's modules, each one job: :mod:`~fedtrack.wire.limits` (bounds, WireError),
:mod:`~fedtrack.wire.fields` (field validators), :mod:`~fedtrack.wire.records` (the record base and the
single-target messages), :mod:`~fedtrack.wire.batches` (the multi-target messages),
:mod:`~fedtrack.wire.codec` (encode, decode), :mod:`~fedtrack.wire.multipart` (messages in parts) and
:mod:`~fedtrack.wire.replay_json` (the replay files' objects); this module re-exports their public names.
"""

from fedtrack.wire.batches import HandOver, TrackPicture, TrackReport, TrackResets
from fedtrack.wire.codec import MESSAGE_TYPES, M, Message, decode, encode, unpack
from fedtrack.wire.fields import acceptable_covariances, predictable
from fedtrack.wire.limits import (
    BRIEF_CHARS,
    EVENT_KINDS,
    FLOAT_EPS,
    MAX_ARRAY_ELEMENTS,
    MAX_BATCH_ELEMENTS,
    MAX_CONTAINER_ITEMS,
    MAX_DEPTH,
    MAX_DETECTIONS,
    MAX_ITEMS,
    MAX_LIST_ITEMS,
    MAX_MAGNITUDE,
    MAX_MAP_ITEMS,
    MAX_PARTS,
    MAX_PAYLOAD_BYTES,
    MAX_STRING_LENGTH,
    MAX_TRACKS,
    MEASUREMENT_KINDS,
    PD_RTOL,
    SCHEMA_VERSION,
    SYMMETRY_RTOL,
    WIRE_DTYPES,
    WireError,
    brief,
)
from fedtrack.wire.multipart import join, parts, payloads
from fedtrack.wire.records import (
    Detection,
    FusedTrack,
    Health,
    LocalEstimate,
    ManeuverEvent,
    ManeuverInfo,
    Measurement,
    Reset,
)
from fedtrack.wire.replay_json import (
    measurement_from_replay,
    measurement_to_replay,
    picture_line,
    picture_rows,
    picture_to_replay,
    track_from_replay,
    track_to_replay,
    with_geodetic,
)

__all__ = [
    "BRIEF_CHARS", "Detection", "EVENT_KINDS", "FLOAT_EPS", "FusedTrack", "HandOver", "Health",
    "LocalEstimate", "M", "MAX_ARRAY_ELEMENTS", "MAX_BATCH_ELEMENTS", "MAX_CONTAINER_ITEMS", "MAX_DEPTH",
    "MAX_DETECTIONS", "MAX_ITEMS", "MAX_LIST_ITEMS", "MAX_MAGNITUDE", "MAX_MAP_ITEMS", "MAX_PARTS",
    "MAX_PAYLOAD_BYTES", "MAX_STRING_LENGTH", "MAX_TRACKS", "MEASUREMENT_KINDS", "MESSAGE_TYPES",
    "ManeuverEvent", "ManeuverInfo", "Measurement", "Message", "PD_RTOL", "Reset", "SCHEMA_VERSION",
    "SYMMETRY_RTOL", "TrackPicture", "TrackReport", "TrackResets", "WIRE_DTYPES", "WireError",
    "acceptable_covariances", "brief", "decode", "encode", "join", "measurement_from_replay",
    "measurement_to_replay", "parts", "payloads", "picture_line", "picture_rows",
    "picture_to_replay", "predictable", "track_from_replay", "track_to_replay", "unpack",
    "with_geodetic",
]
