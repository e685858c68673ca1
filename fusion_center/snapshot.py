"""The fusion centre's snapshot (``serve fusion-center --snapshot``): its state after a scan as data
only, read back field by field against what this build and configuration make (docs/deploy.md,
"Snapshot format").

The file is :func:`fedtrack.services.snapshot.write_sealed`'s: ``SNAPSHOT_MAGIC`` (the format's name
and version), a BLAKE2b digest, then one msgpack map ``{deployment, mode, sensors, state, track}``:
the deployment's name, ``"federated"`` or ``"decentralized"``, the centre's sensor ids in order, its
filter state (:func:`~fedtrack.services.snapshot.record_maps` of the FVDIE master's ``VdieState`` or
the DVDIE centre's ``CentreState``) and the last fused track's wire bytes (its time is the centre's).
Before 2026-11-27 the map was a pickle of the centre object (version 1), which ran any code a file
put in the output folder held when the centre restarted."""

from __future__ import annotations

from typing import NamedTuple, TypeVar

import msgpack
import numpy as np

from fedtrack.fusion_center.centre import DecentralizedCentre, FederatedCentre
from fedtrack.local_filters.vdie.estimation import CentreState, VdieState, vdie_init
from fedtrack.services.snapshot import SnapshotError, record_from_maps, record_maps
from fedtrack.wire import MAX_MAGNITUDE, FusedTrack, WireError, acceptable_covariances, decode, encode, unpack

SNAPSHOT_MAGIC = b"fedtrack-centre-2\n"  # then a 32-byte BLAKE2b digest of the map, then the map
FIELDS = ("deployment", "mode", "sensors", "state", "track")
Centre = FederatedCentre | DecentralizedCentre
S = TypeVar("S", VdieState, CentreState)


class Restored(NamedTuple):
    """A snapshot read back: the centre, as it was after its last scan, and that scan's track."""

    centre: Centre
    track: FusedTrack


def _mode(centre: Centre) -> str:
    return "federated" if isinstance(centre, FederatedCentre) else "decentralized"


def _state(centre: Centre) -> VdieState | CentreState | None:
    """The centre's filter state (None before its first scan)."""
    return centre.vdie if isinstance(centre, FederatedCentre) else centre.state


def _template(centre: Centre) -> VdieState | CentreState:
    """A filter state of ``centre``'s configuration: the fields, dtypes and shapes a snapshot's must have."""
    x, P, is_ca = np.zeros(6), np.eye(6), np.zeros((), dtype=bool)
    if isinstance(centre, FederatedCentre):
        return vdie_init(x, P, is_ca, centre.config.vdie, 0.0)
    return CentreState(x, P, is_ca)


def snapshot_data(deployment: str, centre: Centre, track: FusedTrack) -> bytes:
    """The snapshot map's bytes of ``centre`` after the scan of ``track``."""
    state = _state(centre)
    return msgpack.packb({"deployment": deployment, "mode": _mode(centre), "sensors": list(centre.sensors),
                          "state": None if state is None else record_maps(state), "track": encode(track)},
                         use_bin_type=True)


def restored(data: bytes, deployment: str, blank: Centre) -> Restored:
    """The centre of the snapshot map ``data``, built on ``blank`` (this process's new centre: its
    configuration, sensors and mode are what the map must match), and its last track. SnapshotError
    (a ValueError naming the field) for anything else: not msgpack within the wire's limits, another
    deployment, mode or sensor list, a field missing, unknown or of the wrong type, an array of
    another dtype or shape (another ``[fusion.vdie]`` window or ``p``), a value not finite, a state
    covariance that is not one, a track the wire refuses."""
    try:
        obj = unpack(data)  # bounded msgpack, no extension types
    except WireError as exc:
        raise SnapshotError("snapshot", exc.reason) from None
    if not isinstance(obj, dict) or set(obj) != set(FIELDS):
        keys = sorted(map(str, obj))[:10] if isinstance(obj, dict) else type(obj).__name__
        raise SnapshotError("snapshot", f"expected the fields {list(FIELDS)}, got {keys}")
    for name, want in (("deployment", deployment), ("mode", _mode(blank)), ("sensors", list(blank.sensors))):
        if obj[name] != want:
            raise SnapshotError(name, f"the snapshot's is {str(obj[name])[:80]!r}, this centre's {want!r}")
    if not isinstance(obj["track"], bytes):
        raise SnapshotError("track", f"expected the wire bytes of a FusedTrack, got {type(obj['track']).__name__}")
    try:
        track = decode(obj["track"], FusedTrack)
    except WireError as exc:
        raise SnapshotError(f"track.{exc.field}", exc.reason) from None
    state = None if obj["state"] is None else _checked(record_from_maps(obj["state"], _template(blank), "state"))
    centre = type(blank)(blank.sensors, blank.config)
    centre.t = track.t  # a centre's time is that of its last fused scan
    if isinstance(centre, FederatedCentre):
        centre.vdie = state
    else:
        centre.state = state  # type: ignore[assignment]
    return Restored(centre, track)


def _checked(state: S) -> S:
    """``state`` if its estimate is one the centre could have kept (what the service's ``usable``
    checks of each fused scan: ``x`` within the wire's bound, ``P`` a covariance the wire accepts)
    and its counters are counts (a candidate slot's samples at least -1, empty; steps in CA at least 0)."""
    if not np.abs(state.x).max() <= MAX_MAGNITUDE:
        raise SnapshotError("state.x", f"values beyond +-{MAX_MAGNITUDE:g}")
    if not acceptable_covariances(state.P):
        raise SnapshotError("state.P", "not a symmetric positive-definite covariance")
    if isinstance(state, VdieState):
        for name, bank in (("bank_cv", state.bank_cv), ("bank_ca", state.bank_ca)):
            if np.any(bank.count < -1):
                raise SnapshotError(f"state.{name}.count", "a count below -1")
        if np.any(state.ca_steps < 0):
            raise SnapshotError("state.ca_steps", "a negative count")
    return state
