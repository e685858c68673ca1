"""The track-to-track centre sharded by region: one :class:`RegionCentre` per region.

Each region's centre owns the central tracks whose latest estimate lies in its region
(:func:`region_of`: the first region containing the position, else the nearest). It gets every
report of every local tracker as a sub-report (:mod:`fedtrack.local_filters.mtt.routing`: the
rows near the region or believed held by it, each flagged ``elsewhere`` when the tracker believes
another region holds it) and takes a row (:meth:`RegionCentre.taken`) when it holds the row's
local track, or when the track is held by no region (not ``elsewhere``), was not handed over from
here since the tracker last heard from this centre, and its position is in the region. It counts
every sensor's scans (the misses of its tracks, the live sensors behind the federated shares) and
answers every sub-report. After each sub-report, a central track whose latest estimate left the
region is handed over (:class:`HandOver`: id, states, the out-of-sequence buffer, the maneuver
detector, the life counts and the local-track mapping) to the new owner, where it continues
unbroken; until the tracker has heard of it (the old owner's next answer) the old owner ignores
that track's rows (counted ``in_flight``).

Ids are unique without an allocator: region ``r`` of ``R`` numbers its tracks ``r, r + R,
r + 2R, ...`` (with one region, the unsharded centre's ``0, 1, 2, ...``). The picture is the
union of the centres' tracks in increasing id.

:class:`ShardedCentre` runs the region centres in turn on each report and hands tracks over at once
(the replay of a scans file); :mod:`.picture_merge` replays a live run's recording, each centre in
its own recorded order.
"""

from __future__ import annotations

import itertools
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.special import ndtri

from fedtrack import wire
from fedtrack.fusion_center.mtt.central_track import MAX_ENTRIES
from fedtrack.fusion_center.mtt.centre import Counters, HandOver, TrackToTrackCentre
from fedtrack.fusion_center.mtt.centre.association import LocalKey
from fedtrack.geodetic import Frame, RadarSite
from fedtrack.local_filters.linear.gating import track_difference_d2
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.local import LocalReport, Resets
from fedtrack.local_filters.mtt.models import predict_batch
from fedtrack.local_filters.mtt.routing import RegionAnswer, RegionRouter, join_answers
from fedtrack.local_filters.regions import Regions, distances, region_of

# The hand-over hysteresis (docs/multitarget.md#hand-over-hysteresis): a central track is handed
# over only when its estimate lies more than HAND_OVER_SIGMAS position sigmas outside its region
# (the largest sigma of its position covariance: not less than the one along the border's normal),
# at most ``margin``. A target on the border, its estimate's error along the normal N(0, sigma^2),
# is handed over falsely with probability at most FALSE_HAND_OVER per answer.
FALSE_HAND_OVER = 1e-3
HAND_OVER_SIGMAS = float(ndtri(1.0 - FALSE_HAND_OVER))  # 3.09


def rectangle(regions: Regions, r: int) -> tuple[float, float, float, float] | None:
    """Region ``r``'s bounds ``(x0, x1, y0, y1)`` when it is an axis-parallel rectangle (a grid cell),
    else None."""
    corners = regions.vertices[r]
    ring = corners[np.any(corners != np.roll(corners, 1, axis=0), axis=1)]  # repeats dropped
    step = ring != np.roll(ring, -1, axis=0)  # per edge: x changes, y changes
    if ring.shape[0] != 4 or not (np.array_equal(step[:, 0], ~step[:, 1]) and step[0, 0] != step[1, 0]):
        return None
    (x0, y0), (x1, y1) = ring.min(axis=0).tolist(), ring.max(axis=0).tolist()
    return x0, x1, y0, y1


def interior(regions: Regions, r: int) -> np.ndarray:
    """An open box ``(x0, x1, y0, y1)`` whose every point :func:`region_of` gives to region ``r``,
    or NaNs (none known): a region that is an axis-parallel rectangle (a grid cell), shrunk by
    ``1e-9`` of the largest coordinate (a point that far inside is inside by the even-odd rule, as
    exactly computed), kept only if no earlier region's bounding box, grown as much, meets it
    (such a point is at a distance > 0 from every earlier region, rounding included: region ``r``
    is the first containing it)."""
    v = regions.vertices
    lo, hi = v.min(axis=1), v.max(axis=1)  # (R, 2) bounding boxes
    eps = 1e-9 * max(float(np.abs(v).max()), 1.0)
    a, b = lo[r] + eps, hi[r] - eps
    if (rectangle(regions, r) is None or np.any(a >= b)
            or np.any(np.all((lo[:r] - eps < b) & (hi[:r] + eps > a), axis=1))):
        return np.full(4, np.nan)  # not a rectangle with axis-parallel edges, or an earlier region near
    return np.array([a[0], b[0], a[1], b[1]])


def keyed(table: dict[LocalKey, Any], sensor: str, ids: list[int]) -> np.ndarray:
    """Per local track ``ids`` of ``sensor``, whether ``table`` has it (bool array; the look-ups in C)."""
    return np.fromiter(map(table.__contains__, zip(itertools.repeat(sensor), ids)), dtype=bool, count=len(ids))


@dataclass
class RegionCentre:
    """The centre of region ``index`` of ``regions``: a :class:`TrackToTrackCentre` numbering its
    tracks ``index, index + R, ...``, and the local tracks it handed over that their trackers have
    not heard of yet."""

    cfg: MttConfig
    dim: int
    feedback: bool
    regions: Regions
    index: int
    forwarded: dict[LocalKey, int] = field(default_factory=dict)  # handed over -> the new region
    serial: int = 0  # hand-overs sent
    handed_over: int = 0
    taken_over: int = 0
    in_flight: int = 0  # rows not fused: their central track was handed over, the tracker not yet told
    rows: int = 0  # rows of the sub-reports received
    rows_taken: int = 0  # of them, those fused here (:meth:`taken`); the rest: the margin's, and in flight
    sites: dict[str, RadarSite] = field(default_factory=dict)  # [frame.sites]: the radars' sites (life rules)
    frame: Frame | None = None  # [frame]: a 2-D report's track starts at the origin's height there (level_z)

    def __post_init__(self) -> None:
        self.centre = TrackToTrackCentre(self.cfg, self.dim, self.feedback, next_id=self.index,
                                         id_step=len(self.regions.ids), sites=self.sites,
                                         frame=self.frame)
        self.boxes = np.stack([interior(self.regions, r) for r in range(len(self.regions.ids))])  # (R, 4)
        self.box = tuple(self.boxes[self.index].tolist())  # its own, as floats (owners)
        self.own = self.regions._replace(ids=(self.name,), vertices=self.regions.vertices[self.index:self.index + 1])
        self.rect = rectangle(self.regions, self.index)  # its bounds if a rectangle (beyond_band)
        self.scale = float(np.abs(self.own.vertices).max())

    @property
    def name(self) -> str:
        return self.regions.ids[self.index]

    def taken(self, report: LocalReport, elsewhere: np.ndarray) -> np.ndarray:
        """The rows of a sub-report this centre fuses (bool per row)."""
        s, ids = report.sensor, report.ids.tolist()
        mine = keyed(self.centre.mapping, s, ids)
        free = ~(mine | elsewhere)
        away = {lid for sensor, lid in self.forwarded if sensor == s}  # a few in flight: ids, not (sensor, id) keys
        if away:
            gone = np.fromiter(map(away.__contains__, ids), dtype=bool, count=len(ids)) & ~mine
            self.in_flight += int(gone.sum())
            free &= ~gone
        rows = free.nonzero()[0] if self.boxes.shape[0] > 1 else free[:0]  # one region owns every position
        if rows.size:
            x = report.x[rows]  # one gather, its columns viewed
            free[rows] = self.owners(x[:, 0], x[:, 2]) == self.index
        return mine | free

    def owners(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The region of each position (:func:`region_of`): this region's inside its interior box,
        else that of the other interior box containing it (:func:`interior`: the boxes are disjoint,
        and every point of region ``r``'s is ``r``'s), else :func:`region_of`'s look at the regions."""
        x0, x1, y0, y1 = self.box
        owner = np.full(x.size, self.index)
        out = (~((x > x0) & (x < x1) & (y > y0) & (y < y1))).nonzero()[0]  # most positions are inside
        if out.size:
            x0, x1, y0, y1 = self.boxes.T  # (R,) each; a NaN box contains nothing
            xc, yc = x[out, None], y[out, None]
            boxed = (xc > x0) & (xc < x1) & (yc > y0) & (yc < y1)  # (N, R)
            box = boxed.argmax(axis=1)
            owner[out] = box
            look = out[~boxed[np.arange(out.size), box]]  # in no box
            if look.size:
                owner[look] = region_of(self.regions, np.stack([x[look], y[look]], axis=1))
        return owner

    def beyond_band(self, x: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Per estimate (states ``x``, covariances ``P``) outside the region: whether it lies farther
        outside than ``HAND_OVER_SIGMAS`` times its largest position sigma, capped at ``margin``
        (the hysteresis of the module constants; the tracker sends the rows to the holder anyway).

        The distance outside a rectangle (a grid cell) from its sides, not :func:`distances`' test
        of every edge (a third of its time on a few estimates); where the two could round to different
        sides of the band (within ``1e-9`` of the coordinates), :func:`distances` decides."""
        a, b, d = P[:, 0, 0], P[:, 0, 2], P[:, 2, 2]
        sigma = np.sqrt(0.5 * (a + d) + np.hypot(0.5 * (a - d), b))  # the 2 x 2 block's largest eigenvalue
        band = np.minimum(HAND_OVER_SIGMAS * sigma, self.regions.margin)
        if self.rect is None:
            return distances(self.own, x[:, [0, 2]])[:, 0] > band
        x0, x1, y0, y1 = self.rect
        px, py = x[:, 0], x[:, 2]
        dx, dy = np.maximum(np.maximum(x0 - px, px - x1), 0.0), np.maximum(np.maximum(y0 - py, py - y1), 0.0)
        outside = np.sqrt(dx * dx + dy * dy)
        beyond = outside > band
        near = (np.abs(outside - band) <= 1e-9 * (np.abs(px) + np.abs(py) + self.scale)).nonzero()[0]
        if near.size:
            beyond[near] = distances(self.own, x[near][:, [0, 2]])[:, 0] > band[near]
        return beyond

    def answer(self, report: LocalReport, elsewhere: np.ndarray
               ) -> tuple[RegionAnswer, list[tuple[int, int, HandOver]]]:
        """Fuse the rows it takes of a sub-report, hand over the central tracks that left the region;
        returns the answer and the hand-overs ``(new owner, this centre's hand-over number, record)``."""
        take = self.taken(report, elsewhere)
        self.rows += take.size
        self.rows_taken += int(take.sum())
        resets, q_scale = self.centre.answer(report, None if take.all() else take)
        c = self.centre
        moving: list[tuple[int, int, HandOver]] = []
        ids, slots = c.moved  # only the tracks this report fused into (or started) can have left
        if ids.size and len(self.regions.ids) > 1:
            live = c.tracks.ids[slots] == ids  # not merged away, deleted or pruned since
            sl = slots[live]
            p = c.tracks.newest(sl)
            x = c.tracks.x[sl, p]  # the latest estimates (one gather; their positions' columns viewed)
            owner = self.owners(x[:, 0], x[:, 2])
            out = owner != self.index
            if out.any():  # a track short of a live sensor's local track goes at once (its twin may be next door)
                whole = np.fromiter((c.fused_members(cid) >= c.n_live for cid in ids[live][out].tolist()),
                                    dtype=bool, count=int(out.sum()))
                out[out] = ~whole | self.beyond_band(x[out], c.tracks.P[sl[out], p[out]])
            if out.any():
                first: dict[int, int] = {}  # each track leaving, to its owner at its first row
                for cid, o in zip(ids[live][out].tolist(), owner[out].tolist()):
                    first.setdefault(cid, o)
                for cid, o in sorted(first.items()):  # in increasing id
                    record = c.hand_over(cid)
                    self.forwarded.update((key, o) for key in record.members)
                    moving.append((o, self.serial, record))
                    self.serial += 1
        self.handed_over += len(moving)
        s = report.sensor
        kept = report.ids[take]  # a row not taken was not mapped here, nor is it now
        held = kept[keyed(c.mapping, s, kept.tolist())]
        told = [(key[1], r) for key, r in self.forwarded.items() if key[0] == s]
        for lid, _ in told:
            del self.forwarded[(s, lid)]
        moved = np.array([lid for lid, _ in told], dtype=np.int64)
        return RegionAnswer(resets, q_scale, held, moved, np.array([r for _, r in told], dtype=np.int64)), moving

    def take_over(self, record: HandOver) -> None:
        """Continue a neighbour's central track (a local track of it this centre mapped meanwhile
        is moved to it)."""
        for key in record.members:
            self.centre._unmap(key)
            self.forwarded.pop(key, None)
        self.centre.take_over(record)
        self.taken_over += 1

    def drop_sensor(self, sensor: str, departed: bool = True) -> None:
        self.centre.drop_sensor(sensor, departed)
        for key in [k for k in self.forwarded if k[0] == sensor]:
            del self.forwarded[key]


# ---------------------------------------------------------------- the hand-over on the wire

def handover_to_wire(record: HandOver, source: str, serial: int) -> wire.HandOver:
    """The wire form of a hand-over record (its ring entries flattened per entry)."""
    n = record.entries[0].shape[0]
    ring = np.concatenate([np.asarray(a, dtype=np.float64).reshape(n, -1) for a in record.entries], axis=1)
    neg = np.flatnonzero(np.isneginf(ring))
    ring = np.where(np.isneginf(ring), 0.0, ring)
    used = np.flatnonzero((record.support != 0) | (record.streak != 0))  # the sensors of the track (0 elsewhere)
    return wire.HandOver.unchecked(
        source=source, serial=serial, id=record.id, confirmed=record.confirmed, ring=ring,
        neg_inf=tuple(neg.tolist()), sensors=tuple(record.sensors[k] for k in used.tolist()),
        support=tuple(record.support[used].tolist()), streak=tuple(record.streak[used].tolist()),
        window=tuple(record.window.tolist()), last_support=record.last_support,
        member_sensors=tuple(s for s, _ in record.members), member_ids=tuple(i for _, i in record.members),
        strikes=record.strikes)


def handover_from_wire(msg: wire.HandOver, centre: TrackToTrackCentre) -> HandOver:
    """The record of a wire hand-over for ``centre`` (its ring fields' shapes); ValueError when the
    message does not fit them (another state size, detector or M-of-N window), names more sensors
    than a picture's track may list or sensors ``[mtt] sensors`` does not allow, holds a
    covariance that is not positive definite, or is not a track's record as :meth:`hand_over` makes
    one: a ``support`` other than its local tracks' count per sensor (the centre keeps the two
    equal; a track with support and no local track is never deleted as unsupported), or a
    ``last_support`` after its newest ring entry (the time of an observation fused into it; one
    later would keep the track from ever being deleted as stale)."""
    tracks = centre.tracks
    shapes = [getattr(tracks, name).shape[2:] for name in tracks._ring]
    widths = [int(np.prod(s, dtype=np.int64)) for s in shapes]
    if msg.ring.shape[1] != sum(widths) or len(msg.window) != centre.cfg.confirm_window:
        raise ValueError(f"ring: {msg.ring.shape[1]} values per entry and a window of {len(msg.window)} do not fit "
                         f"this centre's {sum(widths)} and {centre.cfg.confirm_window}")
    if {s: n for s, n in zip(msg.sensors, msg.support) if n} != Counter(msg.member_sensors):
        raise ValueError("support: not the number of its local tracks (member_sensors) of each sensor")
    if not msg.last_support <= msg.ring[-1, 0]:
        raise ValueError(f"last_support: {msg.last_support:g} is after its newest ring entry's time "
                         f"{msg.ring[-1, 0]:g}")
    named = set(msg.sensors) | set(msg.member_sensors)
    if len(named) > wire.MAX_LIST_ITEMS or not all(map(centre.cfg.allows, named)):
        raise ValueError(f"sensors: {len(named)} sensors, at most {wire.MAX_LIST_ITEMS} of those [mtt] sensors "
                         "allows (a picture's track lists them)")
    n = msg.ring.shape[0]
    if n > MAX_ENTRIES:
        raise ValueError(f"ring: {n} entries, at most {MAX_ENTRIES}")
    ring = np.array(msg.ring)
    ring.flat[list(msg.neg_inf)] = -np.inf
    entries, at = [], 0
    for name, shape, width in zip(tracks._ring, shapes, widths):
        dtype = getattr(tracks, name).dtype
        part = ring[:, at:at + width].reshape((n,) + shape)
        if dtype != np.float64:  # counts (an observation's size, the detector's samples): small integers
            if not np.all((part == np.round(part)) & (np.abs(part) <= MAX_ENTRIES)):
                raise ValueError(f"ring: {name} must hold small integers")
            part = part.astype(dtype)
        entries.append(part)
        at += width
    if not (np.all(entries[3] >= 0) and np.all(entries[3] <= tracks.H.shape[2]) and np.all(np.diff(entries[0]) >= 0)):
        raise ValueError("ring: observation sizes out of range or entries out of time order")
    for name, part in zip(tracks._ring, entries):  # the posteriors (and each motion mode's), as the wire checks any
        if name in ("P", "mode_P") and not wire.acceptable_covariances(part):
            raise ValueError(f"ring: a covariance {name} is not positive definite within the wire's bounds")
    return HandOver(msg.id, msg.confirmed, tuple(entries), msg.sensors, np.array(msg.support, dtype=np.int64),
                    np.array(msg.streak, dtype=np.int64), np.array(msg.window, dtype=bool), msg.last_support,
                    tuple(zip(msg.member_sensors, msg.member_ids)), msg.strikes)


def holders_of(centre: TrackToTrackCentre, record: HandOver) -> list[int]:
    """The central tracks of ``centre`` holding a local track that ``record`` names (its members), in increasing id."""
    return sorted({centre.mapping[key] for key in record.members if key in centre.mapping})


def confirmed_holder(centre: TrackToTrackCentre, record: HandOver) -> tuple[int, float] | None:
    """A confirmed central track of ``centre`` holding a local track that ``record`` names, and its newest
    state's time; None when there is none.

    An honest record's member mapped here too was taken from a row that arrived before the record, mostly by a
    track started here (tentative: the record comes within one report; docs/multitarget.md counts the honest
    hand-overs that found a confirmed one). A record naming the local tracks of a confirmed track here takes them
    to a new id: stamped in the past it passes :func:`disputed` (its covariance predicted over the gap), and a
    copy of the track's own state passes it at any time, so either renamed the target's track
    (docs/wire.md, ``conflict`` of ``mtt-centre --region``)."""
    holders = holders_of(centre, record)
    if not holders:
        return None
    tracks = centre.tracks
    slots = tracks.slots_of(holders)
    confirmed = tracks.confirmed[slots]
    if not confirmed.any():
        return None
    k = int(np.flatnonzero(confirmed)[0])
    return holders[k], float(tracks.newest_t(slots[k:k + 1])[0])


def disputed(centre: TrackToTrackCentre, record: HandOver) -> tuple[int, float] | None:
    """A central track of ``centre`` holding a local track that ``record`` names (its members) of which the
    record's newest estimate is not an estimate, and the chi-square between the two; None when there is none.

    Both are predicted to the later of their newest times and tested as the duplicate merge tests two
    central tracks (the association gate, ``[mtt] association_gate_probability``, on the whole state): an
    honest record's member mapped here too (its row taken here as the hand-over crossed the tracker's next
    report) maps a track of the same target, whose errors the shared local track correlates with the record's,
    so it passes at least at the gate's probability. A record that fails it would take that track's local
    tracks to a state elsewhere (docs/wire.md, ``conflict`` of ``mtt-centre --region``)."""
    tracks = centre.tracks
    holders = holders_of(centre, record)
    if not holders:
        return None
    ring = tracks.ring_of(record.entries)
    t_r = float(ring["t"][-1])
    slots = tracks.slots_of(holders)
    T = max(t_r, float(tracks.newest_t(slots).max()))
    X, P = tracks.states_at(slots, T)
    x_r, P_r = predict_batch(ring["x"][-1:], ring["P"][-1:], T - t_r, tracks.q, tracks.noise_model)
    d2 = track_difference_d2(X - x_r, P + P_r)[0]
    worst = int(d2.argmax())
    if d2[worst] <= centre.cfg.thresholds.association[tracks.dim]:
        return None
    return holders[worst], float(d2[worst])


# ---------------------------------------------------------------- the replay of a scans file

@dataclass
class ShardedCentre:
    """One :class:`RegionCentre` per region of ``regions``, run in turn on each report; the
    trackers' routing (:class:`RegionRouter`) is kept here for them; hand-overs are taken over at
    once (the order a live run gives when nothing overtakes)."""

    cfg: MttConfig
    dim: int
    feedback: bool
    regions: Regions
    centres: list[RegionCentre] = field(default_factory=list)
    routers: dict[str, RegionRouter] = field(default_factory=dict)
    # CPU seconds (process time) spent in each region's centre (its reports, its hand-overs out
    # and in) and in routing rows to regions (the local trackers' part in a live deployment)
    cpu_s: list[float] = field(default_factory=list)
    routing_s: float = 0.0
    sites: dict[str, RadarSite] = field(default_factory=dict)  # [frame.sites]: the radars' sites (life rules)
    frame: Frame | None = None  # [frame]: a 2-D report's track starts at the origin's height there (level_z)
    # when a list (one per region, ``record()``): each region centre's calls as made, in order, for a replay of
    # that centre alone (``fedtrack bench scale``'s own-process measurement); None: nothing kept
    calls: list[list[tuple[Any, ...]]] | None = None

    def __post_init__(self) -> None:
        n = len(self.regions.ids)
        self.centres = [RegionCentre(self.cfg, self.dim, self.feedback, self.regions, r, sites=self.sites,
                                     frame=self.frame)
                        for r in range(n)]
        self.cpu_s = [0.0] * n

    def record(self) -> list[list[tuple[Any, ...]]]:
        """Keep each region centre's calls from now on, to be drained by the caller: ``("answer", sub-report,
        elsewhere, [(new owner, hand-over number, track id) of each hand-over out])``, ``("take_over",
        record)``, ``("drop", sensor, departed)``; the objects themselves (not copies), after each call."""
        self.calls = [[] for _ in self.centres]
        return self.calls

    def answer(self, report: LocalReport) -> tuple[Resets, float]:
        """Every region centre's answer to its sub-report, the hand-overs taken over, the answers
        learnt by the report's router; returns the joined resets and the process-noise factor."""
        start = time.process_time()
        router = self.routers.setdefault(report.sensor, RegionRouter(self.regions, self.cfg.unsupported_s))
        parts = router.split(report)
        self.routing_s += time.process_time() - start
        answers, moving = [], []
        for r, (c, (sub, elsewhere)) in enumerate(zip(self.centres, parts)):
            start = time.process_time()
            answer, out = c.answer(sub, elsewhere)
            self.cpu_s[r] += time.process_time() - start
            if self.calls is not None:
                self.calls[r].append(("answer", sub, elsewhere, [(o, k, h.id) for o, k, h in out]))
            answers.append(answer)
            moving += out
        for owner, _, record in moving:
            start = time.process_time()
            self.centres[owner].take_over(record)
            self.cpu_s[owner] += time.process_time() - start
            if self.calls is not None:
                self.calls[owner].append(("take_over", record))
        router.learn([sub for sub, _ in parts], answers)
        return join_answers(answers)

    @property
    def handed_over(self) -> int:
        return sum(c.handed_over for c in self.centres)

    def drop_sensor(self, sensor: str, departed: bool = True) -> None:
        for r, c in enumerate(self.centres):
            c.drop_sensor(sensor, departed)
            if self.calls is not None:
                self.calls[r].append(("drop", sensor, departed))

    def counters(self) -> dict[str, int]:
        """The centres' counters added up (a departure once), the hand-overs, the rows in flight and the trackers'
        hand-overs whose new owner did not hold them in time (``handover_expired``, :class:`RegionRouter`)."""
        total = {k: sum(getattr(c.centre.counters, k) for c in self.centres) for k in vars(Counters())}
        total["left"] = self.centres[0].centre.counters.left
        return {**total, "handed_over": self.handed_over, "in_flight": sum(c.in_flight for c in self.centres),
                "handover_expired": sum(router.expired for router in self.routers.values())}
