"""The multi-target messages, a batch of tracks each (TrackReport, TrackResets, TrackPicture,
HandOver), and their batched field checks."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from fedtrack.wire.fields import _array, _count, _flag, _identifier, _optional, _real, _scans, _sequence, _whole
from fedtrack.wire.limits import (
    _INT64_MAX,
    MAX_BATCH_ELEMENTS,
    MAX_LIST_ITEMS,
    MAX_TRACKS,
    PD_RTOL,
    SYMMETRY_RTOL,
    WireError,
)
from fedtrack.wire.records import _Items, _Record


def _counts(value: Any, path: str) -> tuple[int, ...]:
    """Per-track integers (ids, positions): a list of plain ints in range at once (a 10,000-track
    report holds some 50,000), anything else item by item, which names the first bad one."""
    if (type(value) in (list, tuple) and len(value) <= _whole(MAX_TRACKS) and all(type(v) is int for v in value)
            and (not value or 0 <= min(value) and max(value) <= _INT64_MAX)):
        return tuple(value)
    return _counts_each(value, path)


def _flags(value: Any, path: str) -> tuple[bool, ...]:
    """Per-track flags: a list of plain booleans at once, anything else item by item (see _counts)."""
    if type(value) in (list, tuple) and len(value) <= _whole(MAX_TRACKS) and all(type(v) is bool for v in value):
        return tuple(value)
    return _flags_each(value, path)




def _check_probabilities(p: np.ndarray | None, n: int, path: str = "existence") -> None:
    """None, or one probability in [0, 1] for each of the ``n`` tracks."""
    if p is not None and (p.shape != (n,) or not ((p >= 0.0) & (p <= 1.0)).all()):
        raise WireError(path, f"expected one probability in [0, 1] for each of the {n} tracks")


def _batch(value: Any, path: str) -> np.ndarray:
    """A 2-D array of a batch of tracks (up to MAX_BATCH_ELEMENTS elements a message)."""
    return _array(value, path, 2, _whole(MAX_BATCH_ELEMENTS))


def _batch_vector(value: Any, path: str) -> np.ndarray:
    """A 1-D array of one value per track of a batch (existence)."""
    return _array(value, path, 1, _whole(MAX_BATCH_ELEMENTS))


def _tracks_list(check: Callable[[Any, str], Any]) -> Callable[[Any, str], tuple[Any, ...]]:
    """A list of up to MAX_TRACKS values a message, each checked by ``check``."""
    def values(value: Any, path: str) -> tuple[Any, ...]:
        return tuple(check(v, f"{path}[{i}]") for i, v in enumerate(_sequence(value, path, _whole(MAX_TRACKS))))
    return values


_optional_batch = _optional(_batch)
_optional_batch_vector = _optional(_batch_vector)
_BATCH_CHECKS = (_batch, _optional_batch, _optional_batch_vector)  # decoded within MAX_BATCH_ELEMENTS
_identifier_list = _tracks_list(_identifier)
_reals = _tracks_list(_real)
_counts_each = _tracks_list(_count)  # the item-by-item paths of _counts and _flags
_flags_each = _tracks_list(_flag)


def _covariance_stack(P: np.ndarray, n: int, d: int, path: str) -> np.ndarray:
    """``P`` (n d, d): ``n`` covariances stacked, each symmetric within SYMMETRY_RTOL and positive
    definite (eigenvalue ratio > PD_RTOL), checked in one batched call; returned symmetrized."""
    if P.shape != (n * d, d):
        raise WireError(path, f"expected shape ({n * d}, {d}) for {n} stacked {d}x{d} covariances, got {P.shape}")
    if n == 0 or d == 0:
        return P
    stack = P.reshape(n, d, d)
    scale = np.max(np.abs(stack), axis=(1, 2))
    bad = np.max(np.abs(stack - np.swapaxes(stack, 1, 2)), axis=(1, 2)) > SYMMETRY_RTOL * scale
    if np.any(bad):
        raise WireError(f"{path}[{int(np.argmax(bad))}]", "not symmetric")
    sym = 0.5 * (stack + np.swapaxes(stack, 1, 2))
    try:
        eig = np.linalg.eigvalsh(sym)
    except np.linalg.LinAlgError:
        raise WireError(path, "eigenvalues could not be computed") from None
    bad = ~(eig[:, 0] > PD_RTOL * eig[:, -1]) | (eig[:, -1] <= 0.0)
    if np.any(bad):
        k = int(np.argmax(bad))
        raise WireError(f"{path}[{k}]", f"not positive definite (eigenvalues {eig[k, 0]:.3g} .. {eig[k, -1]:.3g})")
    out = sym.reshape(n * d, d)
    out.setflags(write=False)
    return out


def _track_batch(ids: tuple[int, ...], x: np.ndarray, P: np.ndarray) -> tuple[int, np.ndarray]:
    """Checks ``n`` tracks: unique ids, ``x`` (n, d), ``P`` (n d, d) covariances; returns d and ``P``."""
    n = len(ids)
    if x.shape[0] != n:
        raise WireError("x", f"expected one row per id ({n}), got shape {x.shape}")
    if len(set(ids)) != n:
        raise WireError("ids", "track ids are not unique")
    d = x.shape[1]
    if n and d == 0:
        raise WireError("x", "must not be empty")
    return d, _covariance_stack(P, n, d, "P")


@dataclass(frozen=True, eq=False)
class TrackReport(_Record):
    """A local multi-target tracker's output for scan ``seq`` of ``sensor``: its ``n`` live tracks
    batched (``ids``; ``x`` (n, d); ``P`` (n d, d), the covariances stacked; ``confirmed``;
    ``detected``: updated or started by this scan), the (linearized) observation each of the
    ``k`` detected tracks used, in track order (``obs_H`` (k m, d), ``obs_R`` (k m, m) stacked,
    ``obs_z`` (k, m): ``z ~ N(H x, R)``; ``started``: the track started from it), and the ids
    this scan deleted (``retired``); ``contested``: the scans (of this sensor) for which the
    tracker received a second, different Measurement or TrackResets since its previous report
    (docs/wire.md, "Contested scans")."""

    sensor: str
    seq: int
    t: float
    ids: tuple[int, ...]
    x: np.ndarray
    P: np.ndarray
    confirmed: tuple[bool, ...]
    detected: tuple[bool, ...]
    obs_H: np.ndarray
    obs_R: np.ndarray
    obs_z: np.ndarray
    started: tuple[bool, ...]
    retired: tuple[int, ...]
    stamp_ns: int
    contested: tuple[int, ...] = ()
    existence: np.ndarray | None = None  # (n,) each track's existence probability (jipda), else None
    # a region's sub-report (docs/multitarget.md#regions): per track, whether its tracker believes
    # another region's centre holds it (empty: none does; omitted then)
    elsewhere: tuple[bool, ...] = ()
    first: bool = False  # the first report of this tracker process; on the wire only when true
    part: int = 0  # this part's index, parts: how many (docs/wire.md, "Messages in parts"); on the wire only when > 1
    parts: int = 1

    _fields = {"sensor": _identifier, "seq": _count, "t": _real, "ids": _counts, "x": _batch, "P": _batch,
               "confirmed": _flags, "detected": _flags, "obs_H": _batch, "obs_R": _batch, "obs_z": _batch,
               "started": _flags, "retired": _counts, "stamp_ns": _count, "contested": _scans,
               "existence": _optional_batch_vector, "elsewhere": _flags, "first": _flag, "part": _count,
               "parts": _count}
    _arrays = ("x", "P", "obs_H", "obs_R", "obs_z", "existence")
    _omitted = ("elsewhere", "first", "part", "parts")
    _items = (_Items(("ids", "x", "P", "confirmed", "detected", "existence", "elsewhere"), "MAX_TRACKS"),
              _Items(("started", "obs_H", "obs_R", "obs_z"), "MAX_TRACKS", "of", "detected"),
              _Items(("retired",), "MAX_TRACKS"))

    def _check(self) -> None:
        n = len(self.ids)
        d, P = _track_batch(self.ids, self.x, self.P)
        object.__setattr__(self, "P", P)
        if len(self.confirmed) != n or len(self.detected) != n:
            raise WireError("detected", f"expected confirmed and detected for each of the {n} tracks")
        if len(self.elsewhere) not in (0, n):
            raise WireError("elsewhere", f"expected none or one for each of the {n} tracks")
        k = sum(self.detected)
        m = self.obs_z.shape[1]
        if self.obs_z.shape[0] != k or len(self.started) != k:
            raise WireError("obs_z", f"expected one observation per detected track ({k})")
        if k and m == 0:
            raise WireError("obs_z", "must not be empty")
        if self.obs_H.shape != (k * m, d):
            raise WireError("obs_H", f"expected shape ({k * m}, {d}), got {self.obs_H.shape}")
        object.__setattr__(self, "obs_R", _covariance_stack(self.obs_R, k, m, "obs_R"))
        _check_probabilities(self.existence, n)


@dataclass(frozen=True, eq=False)
class TrackResets(_Record):
    """The multi-target centre's answer to ``sensor``'s report ``seq`` (federated mode): the
    resets of local tracks ``ids`` (``x`` (n, d), ``P`` (n d, d) stacked, already scaled) and
    ``q_scale``, the process-noise factor (number of live sensors) for its next scan.

    A region centre's answer (docs/multitarget.md#regions; decentralized too, with no resets) also
    names its ``region``, the local tracks of the sub-report it ``held`` after it, and the ones
    it handed over since its last answer to this sensor (``moved``) with their new regions
    (``moved_to``); without regions these fields are absent."""

    sensor: str
    seq: int
    t: float
    q_scale: float
    ids: tuple[int, ...]
    x: np.ndarray
    P: np.ndarray
    region: str | None = None
    held: tuple[int, ...] = ()
    moved: tuple[int, ...] = ()
    moved_to: tuple[str, ...] = ()
    part: int = 0  # this part's index, parts: how many (docs/wire.md, "Messages in parts"); on the wire only when > 1
    parts: int = 1

    _fields = {"sensor": _identifier, "seq": _count, "t": _real, "q_scale": _real, "ids": _counts,
               "x": _batch, "P": _batch, "region": _optional(_identifier), "held": _counts, "moved": _counts,
               "moved_to": _identifier_list, "part": _count, "parts": _count}
    _arrays = ("x", "P")
    _omitted = ("region", "held", "moved", "moved_to", "part", "parts")
    _items = (_Items(("ids", "x", "P"), "MAX_TRACKS"), _Items(("held",), "MAX_TRACKS"),
              _Items(("moved", "moved_to"), "MAX_TRACKS"))

    def _check(self) -> None:
        if not 1.0 <= self.q_scale <= MAX_TRACKS:
            raise WireError("q_scale", f"must be in [1, {MAX_TRACKS}], got {self.q_scale}")
        object.__setattr__(self, "P", _track_batch(self.ids, self.x, self.P)[1])
        if len(self.moved) != len(self.moved_to):
            raise WireError("moved_to", "expected one region per moved track")
        if self.region is None and (self.held or self.moved):
            raise WireError("region", "held and moved come with the answering region")


def _id_lists(value: Any, path: str) -> tuple[tuple[str, ...], ...]:
    """A list of id lists (a picture's per-track sensors), each distinct id checked once: the lists
    repeat a few sensor ids (1,000 tracks: 4,000 checks of 4 ids). Same results and errors as
    ``_identifiers`` on each list."""
    valid: set[str] = set()

    def ids(items: list[Any], where: str) -> tuple[str, ...]:
        for j, x in enumerate(items):
            if not (type(x) is str and x in valid):
                valid.add(_identifier(x, f"{where}[{j}]"))
        return tuple(items)

    return tuple(ids(_sequence(v, f"{path}[{i}]", MAX_LIST_ITEMS), f"{path}[{i}]")
                 for i, v in enumerate(_sequence(value, path, _whole(MAX_TRACKS))))


@dataclass(frozen=True, eq=False)
class TrackPicture(_Record):
    """The multi-target centre's picture number ``seq`` at ``t`` (every ``period`` seconds): its
    tracks predicted to ``t`` (``ids``, ``x`` (n, d), ``P`` (n d, d) stacked, ``confirmed``,
    ``sensors`` per track), and the scans it processed since the previous picture, in its
    processing order (``fused_sensors[i]``, ``fused_seqs[i]``): the order a replay of the
    recorded scans must follow. The entries at the positions ``left`` are no scans but
    departures: the centre dropped that sensor there (its ``fused_seqs`` entry is 0); those at
    ``restarted``, the sensor's tracker started afresh there (a restarted process), with the
    report of scan ``fused_seqs`` (the next entry of that sensor). A
    ``closing`` record (the last one, on a clean stop) is no picture: it has no tracks and only
    lists what the centre processed after the last picture. ``contested``: since the previous
    picture a second, different message arrived for a (sensor, scan) the centre had already
    taken, or a report fused since then names contested scans of its local tracker (the first
    message was used; either may be a forgery: docs/wire.md, "Contested scans")."""

    seq: int
    t: float
    ids: tuple[int, ...]
    x: np.ndarray
    P: np.ndarray
    confirmed: tuple[bool, ...]
    sensors: tuple[tuple[str, ...], ...]
    fused_sensors: tuple[str, ...]
    fused_seqs: tuple[int, ...]
    stamp_ns: int
    closing: bool = False
    left: tuple[int, ...] = ()
    ca: tuple[bool, ...] = ()  # per track: in the CA model (``[mtt] maneuver``); empty: every track CV
    # central tracks' maneuver detector (``[mtt] maneuver = "vdie"``; None: none runs): the positions
    # of the tracks whose maneuver is detected and one row [onset, ax, ay, statistic] for each
    maneuvering: tuple[int, ...] = ()
    maneuver: np.ndarray | None = None
    contested: bool = False
    existence: np.ndarray | None = None  # (n,) each track's existence probability, None: not kept
    lla: np.ndarray | None = None  # (n, 3) [lat deg, lon deg, h m] of each track ([frame] set), else None
    # per track: false when its altitude nobody measured (its ``lla`` at the origin's height,
    # fedtrack.geodetic.altitude_unmeasured); empty when every track's was (or no [frame])
    alt_measured: tuple[bool, ...] = ()
    # region centres (docs/multitarget.md#regions; absent without regions): ``handovers``, the
    # positions in the fused lists that are hand-overs taken over there (``fused_sensors``: the
    # sending region, ``fused_seqs``: its hand-over number); in the merged picture, ``regions``
    # names the region that processed each entry of the fused lists (each region's in its order)
    handovers: tuple[int, ...] = ()
    regions: tuple[str, ...] = ()
    # a region centre's picture: the positions of the tracks it handed over shortly before (shown
    # until their new owner shows them) and the data time of each hand-over
    in_flight: tuple[int, ...] = ()
    in_flight_t: tuple[float, ...] = ()
    restarted: tuple[int, ...] = ()
    # a region centre process's first picture (and the merge): the positions in the fused lists where a centre of
    # the region (``fused_sensors``) began with no tracks, numbering its tracks from ``fused_seqs`` and its
    # hand-overs from ``began_serials`` (one each)
    began: tuple[int, ...] = ()
    began_serials: tuple[int, ...] = ()
    # a merged picture: the regions whose picture of its time it lacks (no live centre, or gone past --wait)
    missing: tuple[str, ...] = ()
    part: int = 0  # this part's index, parts: how many (docs/wire.md, "Messages in parts"); on the wire only when > 1
    parts: int = 1

    _fields = {"seq": _count, "t": _real, "ids": _counts, "x": _batch, "P": _batch, "confirmed": _flags,
               "sensors": _id_lists, "ca": _flags, "maneuvering": _counts, "maneuver": _optional_batch,
               "fused_sensors": _identifier_list,
               "fused_seqs": _counts, "stamp_ns": _count, "closing": _flag, "left": _counts, "contested": _flag,
               "existence": _optional_batch_vector, "lla": _optional_batch,
               "alt_measured": _flags, "handovers": _counts, "regions": _identifier_list,
               "in_flight": _counts, "in_flight_t": _reals, "restarted": _counts, "began": _counts,
               "began_serials": _counts, "missing": _identifier_list,
               "part": _count, "parts": _count}
    _arrays = ("x", "P", "maneuver", "existence", "lla")
    _omitted = ("handovers", "regions", "in_flight", "in_flight_t", "restarted", "began", "began_serials", "missing",
                "alt_measured", "part", "parts")
    _items = (_Items(("ids", "x", "P", "confirmed", "sensors", "ca", "existence", "lla", "alt_measured"), "MAX_TRACKS"),
              _Items(("fused_seqs", "fused_sensors", "regions"), "MAX_TRACKS"),
              _Items(("maneuvering", "maneuver"), "MAX_TRACKS", "at", "ids"),
              _Items(("in_flight", "in_flight_t"), "MAX_TRACKS", "at", "ids"),
              _Items(("left",), "MAX_TRACKS", "at", "fused_seqs"),
              _Items(("handovers",), "MAX_TRACKS", "at", "fused_seqs"),
              _Items(("restarted",), "MAX_TRACKS", "at", "fused_seqs"),
              _Items(("began", "began_serials"), "MAX_TRACKS", "at", "fused_seqs"))

    def _check(self) -> None:
        n = len(self.ids)
        object.__setattr__(self, "P", _track_batch(self.ids, self.x, self.P)[1])
        k = len(self.maneuvering)
        if self.maneuver is None and k or self.maneuver is not None and self.maneuver.shape != (k, 4):
            raise WireError("maneuver", f"expected one row [onset, ax, ay, statistic] for each of the {k} "
                                        "maneuvering tracks")
        if len(set(self.maneuvering)) != k or any(i >= n for i in self.maneuvering):
            raise WireError("maneuvering", f"expected distinct positions among the {n} tracks")
        if len(self.confirmed) != n or len(self.sensors) != n:
            raise WireError("sensors", f"expected confirmed and sensors for each of the {n} tracks")
        if len(self.fused_sensors) != len(self.fused_seqs):
            raise WireError("fused_seqs", "expected one per fused_sensors entry")
        if len(self.ca) not in (0, n):
            raise WireError("ca", f"expected none or one for each of the {n} tracks")
        if len(set(self.left)) != len(self.left) or any(i >= len(self.fused_seqs) for i in self.left):
            raise WireError("left", "expected distinct positions in the fused lists")
        if (len(set(self.handovers)) != len(self.handovers) or set(self.handovers) & set(self.left)
                or any(i >= len(self.fused_seqs) for i in self.handovers)):
            raise WireError("handovers", "expected distinct positions in the fused lists, none a departure")
        if (len(set(self.restarted)) != len(self.restarted) or set(self.restarted) & {*self.left, *self.handovers}
                or any(i >= len(self.fused_seqs) for i in self.restarted)):
            raise WireError("restarted", "expected distinct positions in the fused lists, none a departure or a "
                                         "hand-over")
        if (len(set(self.began)) != len(self.began) or set(self.began) & {*self.left, *self.handovers, *self.restarted}
                or any(i >= len(self.fused_seqs) for i in self.began) or len(self.began_serials) != len(self.began)):
            raise WireError("began", "expected distinct positions in the fused lists, none a departure, hand-over or "
                                     "restart, each with its hand-over number (began_serials)")
        if len(self.regions) not in (0, len(self.fused_seqs)):
            raise WireError("regions", "expected none or one for each entry of the fused lists")
        if (len(set(self.in_flight)) != len(self.in_flight) or any(i >= n for i in self.in_flight)
                or len(self.in_flight_t) != len(self.in_flight)):
            raise WireError("in_flight", f"expected distinct positions among the {n} tracks, each with its time")
        if self.closing and n:
            raise WireError("ids", "a closing record has no tracks")
        if len(set(self.missing)) != len(self.missing):
            raise WireError("missing", "expected distinct region ids")
        _check_probabilities(self.existence, n)
        if self.lla is not None and (self.lla.shape != (n, 3) or not (np.abs(self.lla[:, 0]) <= 90.0).all()
                                     or not (np.abs(self.lla[:, 1]) <= 180.0).all()):
            raise WireError("lla", "expected one row [lat, lon, h] (|lat| <= 90, |lon| <= 180) for each of the "
                                   f"{n} tracks")
        if self.alt_measured and (len(self.alt_measured) != n or self.lla is None or self.x.shape[1] != 6):
            raise WireError("alt_measured", f"expected none or one for each of the {n} tracks, with lla and 3-D "
                                            "states")


@dataclass(frozen=True, eq=False)
class HandOver(_Record):
    """A region centre's central track ``id`` handed to the region its latest estimate entered
    (docs/multitarget.md#regions), sent by region ``source`` as its hand-over number ``serial``:
    ``confirmed``; ``ring`` (n, w), its ``n`` out-of-sequence buffer entries (the checkpoint
    first), each the centre's ring fields flattened in their order (time, state, covariance, the
    observation's size, H, R, z, and the maneuver detector's bank and detection when it runs;
    ``-inf`` values, a detector's "no estimate yet", are 0 there and listed by their flat
    positions in ``neg_inf``); per sensor of ``sensors`` its local tracks mapped to the track
    (``support``) and misses in a row (``streak``); the M-of-N ``window``; ``last_support``, the
    time of its last fused observation; its local tracks (``member_sensors[i]``,
    ``member_ids[i]``) and their association ``strikes``."""

    source: str
    serial: int
    id: int
    confirmed: bool
    ring: np.ndarray
    neg_inf: tuple[int, ...]
    sensors: tuple[str, ...]
    support: tuple[int, ...]
    streak: tuple[int, ...]
    window: tuple[bool, ...]
    last_support: float
    member_sensors: tuple[str, ...]
    member_ids: tuple[int, ...]
    strikes: tuple[int, ...]

    _fields = {"source": _identifier, "serial": _count, "id": _count, "confirmed": _flag, "ring": _batch,
               "neg_inf": _counts, "sensors": _identifier_list, "support": _counts,
               "streak": _counts,
               "window": _flags, "last_support": _real,
               "member_sensors": _identifier_list, "member_ids": _counts,
               "strikes": _counts}
    _arrays = ("ring",)

    def _check(self) -> None:
        if self.ring.shape[0] == 0 or self.ring.shape[1] == 0:
            raise WireError("ring", "expected at least one entry")
        if len(set(self.neg_inf)) != len(self.neg_inf) or any(i >= self.ring.size for i in self.neg_inf):
            raise WireError("neg_inf", f"expected distinct positions among the {self.ring.size} ring values")
        s = len(self.sensors)
        if len(set(self.sensors)) != s or len(self.support) != s or len(self.streak) != s:
            raise WireError("sensors", "expected distinct sensors, each with its support and streak")
        n = len(self.member_ids)
        if len(self.member_sensors) != n or len(self.strikes) != n:
            raise WireError("member_ids", "expected a sensor and strikes for each member")
        if (len(set(zip(self.member_sensors, self.member_ids))) != n
                or not set(self.member_sensors) <= set(self.sensors)):
            raise WireError("member_sensors", "expected distinct members of the listed sensors")
