"""``fedtrack serve picture --config TOML [--wait SECONDS]``: the region centres' pictures merged.

Subscribes to every region's picture (``region/<rid>/picture`` for each region of the config's
``[regions]``) and publishes one ``TrackPicture`` per picture time on ``fusion/picture`` (the
recorder records it as the unsharded centre's): the union of the regions' tracks by id, each id
once (an id in two regions' pictures, a hand-over between their pictures, is taken from the first
region and counted ``seen_twice``; two tracks of different targets under one id both, the second under an
alias, counted ``id_collision``: :func:`fedtrack.fusion_center.mtt.regional.merge_pictures`),
and the fused lists of every region in region order, each entry tagged with its region
(``regions``; ``left`` and ``handovers`` shifted to their positions), so that ``replay --regions
config`` of the recording takes each region's entries in its order.

A picture time is merged once every region has published its picture of that time, a later one
(it has none of that time: it started later, or, when it had published a picture before that time,
lost it: counted ``missing_region`` and the picture ``contested``) or its closing record, or has no
live centre (none of its centres, primary or standby, holds its token ``alive/mtt-region/<rid>/*``:
counted ``missing_region`` and ``no_centre``, not waited for; a region that publishes while none of its
tokens shows is waited for until one does; the first pictures wait until two regions with a live centre
have sent one, and go through the lead guard in time order: :meth:`PictureMergeService._admit`; a start of one
region's pictures is abandoned when two regions' pictures agree against it, more than ``max_time_jump_s`` away:
:meth:`PictureMergeService._against`, ``start_abandoned``); after
``--wait`` seconds (from the first region's picture of that time) without one, it is merged without
that region: counted ``missing_region``, logged, and the picture marked ``contested`` when the region had
published before. The merged picture names the regions it lacks (``missing``). A region centre's first
picture lists its start (``began``: its first track id and hand-over number, the recorder's centre start
line), and a region that sends a picture after its closing record (a centre started again after a clean
stop) has that record's entries merged before the new process's, so that the replay starts the region's
centre afresh after them; a start other than the picture's first entry, its region's, is refused
(``wrong_region``). (A region's picture that
comes after its time was merged is counted
``late_picture``; its fused lists go into the next merged picture, its tracks nowhere: live and
replay then differ at that picture; when they do not fit beside the regions' own entries in one
merged picture, they are dropped, counted ``late_dropped``). A region picture holding more tracks
or entries than its share of one merged picture (``PICTURE_ITEMS`` / regions) is rejected
(``too_large``), and one (not a closing record) whose time is not a multiple of ``[mtt] period``, where
every region centre's clock makes them, is rejected (``time_jump``): a region's pictures between the
others' made merged pictures of that region alone. A region picture not after the latest taken from its
region is a ``duplicate`` when equal to the one taken for its time, else refused (``conflict``) and
the next merged picture marked ``contested``. With ``[frame]`` in the config each merged track carries its WGS-84
position (``lla``, as a centre's picture does: the recorder's ``tracks.jsonl`` then has the ``lat``,
``lon``, ``alt`` that ``replay --regions config`` writes). On a clean stop it merges what it holds and
publishes a closing record with the regions' closing lists.

It subscribes with history: a region centre keeps its last ``picture_window`` pictures
(:meth:`MttCentreService.windowed_outputs`), so a merger started again after it died merges the
pictures of its outage, in order, numbered as they would have been. For ``HISTORY_SETTLE_S`` after its
start it merges nothing (the caches' replies, and the base service's second query of them, come in;
they are held, each once, and go through the lead guard in time order: interleaved with the regions'
live pictures, a live picture came far ahead of the replies taken so far, was held as leading and
dropped by the next reply, 15 in a live run), then starts at the first time every region's cache
holds (``cache_partial``: a region whose cache was one picture shorter would otherwise be missing from
the oldest). A region's picture of a time not yet merged that
comes after a later one (its cache's reply overtaken by a live picture) is queued in time order; the
digests of each region's last ``window`` pictures taken tell a re-delivery (a ``duplicate``: the
second query, a standby's cache) from a second, different picture (``conflict``). With ``--snapshot
PATH`` (``launch`` gives ``OUT/picture.snapshot`` and removes it when a run starts) it writes the time
of each picture it publishes there, and the region that showed each id (only those another region than
the id's issuer showed), behind a digest (a file cut or corrupted on disk is refused, and
every time the caches hold is merged); started again, it merges only the times after it (the region
pictures of earlier times counted ``merged_before``): the last one's pictures sent again would carry
new stamps, each a ``conflict`` at the recorder and a repeat to a display; and an id two regions' tracks
hold stays with the track shown under it (since the redteam63 session).
"""

from __future__ import annotations

import pickle
import time
from collections import deque
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from fedtrack.config import ConfigError, finite_number, load_tables, read_small_file
from fedtrack.deployment import MAX_TIME_JUMP_S
from fedtrack.fusion_center.mtt.engines import PictureClock
from fedtrack.fusion_center.mtt.failover.standby import CENTRE_TOKENS_KEPT, NUMBER_ROOM
from fedtrack.fusion_center.mtt.pictures import (
    MERGE_WAIT_S,
    PICTURE_ITEMS,
    picture_message,
    picture_tracks,
    picture_window,
)
from fedtrack.fusion_center.mtt.regional import RegionPicture, merge_pictures, rows_of
from fedtrack.geodetic import Frame, load_frame, picture_geodetic
from fedtrack.local_filters.mtt.config import MttConfig, MttServiceSettings
from fedtrack.local_filters.regions import Regions, load_regions
from fedtrack.services.admission import digest
from fedtrack.services.base import (
    HISTORY_RECHECK_S,
    Service,
    Subscription,
    TokenWatch,
    service_kwargs,
    service_parser,
)
from fedtrack.services.dispatch import held_bytes
from fedtrack.services.lead import LeadGuard, SoleStart
from fedtrack.services.rejections import Conflict, Rejected
from fedtrack.services.snapshot import MAX_SNAPSHOT_BYTES, unsealed, write_sealed
from fedtrack.wire import TrackPicture
from fedtrack.zsession import Peers

# a merger's first HISTORY_SETTLE_S: the caches' replies and the base service's second query of them (at
# HISTORY_RECHECK_S) are in (loopback: milliseconds after it)
HISTORY_SETTLE_S = HISTORY_RECHECK_S + 0.5
# --snapshot: then the digest, the last merged time (its repr), a newline and the ids the last merged picture showed
# from another region than their issuer's (merge_pictures' ``before`` beyond its default, id % regions), each an
# int64 id and a uint32 region: at most PICTURE_ITEMS of 12 bytes, 1.5 MiB, within MAX_SNAPSHOT_BYTES
SNAPSHOT_MAGIC = b"fedtrack-picture-2\n"
SHOWN_DTYPE = np.dtype([("id", "<i8"), ("region", "<u4")])
# A merged picture carries at most PICTURE_ITEMS tracks and fused entries, as any picture. Each of R
# regions' pictures may hold 1/R of it (rejected ``too_large`` beyond: 65,536 for 2 regions, 1,310 for
# 100, above a region's period of scans, 64 live sensors at 10 Hz, and issue 27's 10^5 tracks over the
# regions); the entries of late pictures go into the next merged picture, or are dropped when they do
# not fit beside its regions' own (``late_dropped``), so that every merged picture can be sent
# (sensor or sending region, seq, kind: scan / left / handover / restarted / began, region, a began's first
# hand-over number)
Entries = list[tuple[str, int, str, str, int]]


def entries_of(msg: TrackPicture, region: str) -> Entries:
    """A region picture's fused lists as tagged entries."""
    kinds = {**{i: "left" for i in msg.left}, **{i: "handover" for i in msg.handovers},
             **{i: "restarted" for i in msg.restarted}, **{i: "began" for i in msg.began}}
    serials = dict(zip(msg.began, msg.began_serials))
    return [(s, q, kinds.get(i, "scan"), region, serials.get(i, 0))
            for i, (s, q) in enumerate(zip(msg.fused_sensors, msg.fused_seqs))]


def region_picture_of(msg: TrackPicture) -> RegionPicture:
    """A region centre's picture: its held tracks and its copies of tracks in flight."""
    tracks = picture_tracks(msg)
    if not msg.in_flight:
        return RegionPicture(tracks)
    flying = np.zeros(len(msg.ids), dtype=bool)
    flying[list(msg.in_flight)] = True
    order = np.argsort(msg.in_flight)
    return RegionPicture(rows_of(tracks, ~flying), rows_of(tracks, flying),
                         tuple(msg.in_flight_t[k] for k in order.tolist()))


def snapshot_data(T: float, shown: dict[int, int], regions: int) -> bytes:
    """What the snapshot keeps after the merged picture of time ``T`` (``SNAPSHOT_MAGIC``): ``T`` and the ids that
    picture showed from another region (of ``regions``) than their issuer's (``shown``: id -> region)."""
    moved = [(i, k) for i, k in shown.items() if k != i % regions]
    return repr(T).encode() + b"\n" + np.array(moved, dtype=SHOWN_DTYPE).tobytes()


def resumed(raw: bytes, regions: int) -> tuple[float, dict[int, int]]:
    """The last merged time and the region showing each id under it (:func:`snapshot_data`; an id not listed: its
    issuer, id % ``regions``) in a snapshot file's bytes ``raw``; ValueError for a file that is not one, or cut or
    corrupted (checked by its digest: before 2026-11-27 the file held the time alone, and a digit changed on disk,
    12.0 to 92.0, made a restart skip every picture up to t = 92 unmerged), or naming a region not of ``regions``.
    Before the redteam63 session the file held the time alone: a merger started again forgot which region showed
    an id, so an id held by two regions' tracks of different targets went to its issuer's, renaming the track
    shown under it."""
    head, newline, rest = unsealed(raw, SNAPSHOT_MAGIC).partition(b"\n")
    T = float(head.decode())
    if not np.isfinite(T):
        raise ValueError(f"a time of {T}")
    if not newline or len(rest) % SHOWN_DTYPE.itemsize:
        raise ValueError(f"a list of the ids shown of {len(rest)} bytes, not a multiple of {SHOWN_DTYPE.itemsize}")
    shown = np.frombuffer(rest, SHOWN_DTYPE)
    if (shown["id"] < 0).any() or (shown["region"] >= regions).any():
        raise ValueError(f"an id shown below 0 or by a region beyond the {regions} of the config")
    return T, dict(zip(shown["id"].tolist(), shown["region"].tolist()))


class PictureMergeService(Service):
    """Merges the region centres' pictures into the deployment's picture."""

    role = "picture"
    tick_period_s = 0.05
    state_attrs = ("pending", "started", "closing", "late", "merged_t", "shown", "seq", "clock", "lead", "latest",
                   "contested", "seen", "settle_until", "settling", "first", "first_at", "earliest", "uncovered",
                   "closed", "tokenless", "sole")
    # what a merger abandoning a start of one region's pictures puts back as before its first picture (SoleStart):
    # what taking a picture changes, but the pictures published (``seq``) and the regions heard from (``started``)
    start_attrs = ("pending", "late", "merged_t", "shown", "clock", "lead", "latest", "seen", "earliest", "first_seen",
                   "sole")

    def __init__(self, regions: Regions, dim: int, wait_s: float, period: float, frame: Frame | None = None,
                 window: int | None = None, snapshot: Path | None = None, gate: float | None = None,
                 init_z_std: float | None = None, start_gap: float = MAX_TIME_JUMP_S, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.regions, self.dim, self.wait_s, self.period = regions, dim, wait_s, period
        # two regions' tracks under one id are one track's copies within it ([mtt] association_gate_probability)
        self.gate = MttConfig().thresholds.association[dim] if gate is None else gate
        # the region pictures a region centre keeps (picture_window; default: at real time)
        self.window = picture_window(period, 1.0) if window is None else window
        self.seen: list[dict[float, bytes]] = [{} for _ in regions.ids]  # its last ``window`` times taken: digest
        self.settle_until: float | None = None  # merge nothing before (on_start: the caches' replies come in)
        self.settling: list[tuple[int, TrackPicture]] = []  # pictures that came before it, in arrival order
        self.first: list[tuple[int, TrackPicture]] = []  # the pictures before the lead guard took one (_admit)
        self.first_at: float | None = None  # when the first of them came
        self.snapshot = snapshot  # where the time of the last picture published is kept (--snapshot)
        self.resumed_t: float | None = None  # the last time merged before this start (read from the snapshot)
        self.frame = frame  # [frame]: each merged track's WGS-84 position too
        self.init_z_std = init_z_std  # [mtt]'s: an altitude not measured is placed at the origin's height (geodetic)
        R = len(regions.ids)
        self.pending: list[deque[TrackPicture]] = [deque() for _ in range(R)]
        self.started = [False] * R  # the region published a picture
        self.closing: list[TrackPicture | None] = [None] * R
        self.closed: list[bytes | None] = [None] * R  # the digest of each region's last closing record taken
        self.late: list[Entries] = [[] for _ in range(R)]  # entries of pictures that came after their time
        self.first_seen: dict[float, float] = {}  # picture time -> monotonic time of its first region picture
        self.merged_t: float | None = None
        self.shown: dict[int, int] = {}  # the region showing each id under it in the last merged picture
        self.seq = 0  # pictures published
        self.clock = PictureClock(period, 0.0)  # their numbers: the regions' (PictureClock.number)
        self.latest: list[TrackPicture | None] = [None] * R  # each region's latest picture taken (queued or merged)
        self.earliest: list[float] = [np.inf] * R  # each region's earliest picture time taken
        self.contested = False  # a region sent a second, different picture of a time it had sent: the next merge says so
        # a region picture stamped far ahead of the others waits for a witness (fedtrack/services/lead.py)
        # ... each region's usual interval its period from the start (a region makes a picture every period)
        # ... and the first pictures until two agree within start_gap ([deployment] max_time_jump_s)
        self.lead: LeadGuard[TrackPicture] = LeadGuard(max_lag=0.0, usual=dict.fromkeys(regions.ids, period),
                                                       start_gap=start_gap)
        # ... and a start of one region's pictures, abandoned when two regions' pictures agree against it (one region:
        # none can; lead.SoleStart, as at serve mtt-centre)
        self.sole: SoleStart[tuple[int, TrackPicture]] = SoleStart(start_gap, ended=len(regions.ids) < 2)
        self.fresh: bytes | None = None  # the start_attrs before the first picture went through the lead guard
        # each region's centres' tokens (region_centre), once watched (token_watches; a Zenoh thread's)
        self.centres: dict[str, Peers] | None = None
        self.uncovered: frozenset[int] = frozenset()  # the regions last found without a live centre (logged)
        self.tokenless: frozenset[int] = frozenset()  # regions publishing while none of their tokens shows: waited for

    def token_watches(self) -> list[TokenWatch]:
        """Every region centre's token: a region none holds is not waited for (:meth:`_uncovered`)."""
        self.centres = {rid: Peers(CENTRE_TOKENS_KEPT) for rid in self.regions.ids}
        return [TokenWatch(self.keys.region_centre(), self._on_centre)]

    def _on_centre(self, key: str, alive: bool) -> None:
        """Zenoh thread: a region centre's token came or went (one naming no region of the config changes
        nothing; nor one beyond ``CENTRE_TOKENS_KEPT`` of its region's)."""
        peers = None if self.centres is None else self.centres.get(key.rsplit("/", 2)[-2])
        if peers is not None:
            peers.token(key, alive, time.monotonic())

    def _uncovered(self, now: float) -> frozenset[int]:
        """The regions without a live centre at ``now``: none holds its token while this merger's link has
        held long enough for every live one's to be here (:meth:`fedtrack.zsession.Link.settled`: the
        tokens that went with a router outage are back within ``LINK_GRACE_S``). None before the tokens
        are watched; nor a region that published a picture while none of its tokens showed (``tokenless``:
        an access control written before the token, which drops it, would otherwise have every region
        merged without), until one shows."""
        if self.centres is None or not self.link().settled(now):
            return frozenset()
        held = {rid for rid, peers in self.centres.items() if peers.present}
        self.tokenless = frozenset(r for r in self.tokenless if self.regions.ids[r] not in held)
        return frozenset(r for r, rid in enumerate(self.regions.ids) if rid not in held) - self.tokenless

    def subscriptions(self) -> list[Subscription]:
        return [Subscription(self.keys.region_picture(rid), TrackPicture, partial(self.on_picture, r), history=True)
                for r, rid in enumerate(self.regions.ids)]

    def on_start(self) -> None:
        """Settle the region caches' replies from now on; resume after the snapshot's time, if any."""
        self.settle_until = time.monotonic() + HISTORY_SETTLE_S
        if self.snapshot is not None and self.snapshot.exists():
            try:  # a FIFO or a link to /dev/zero is refused unread (it blocked the start; a MemoryError)
                raw = read_small_file(self.snapshot, MAX_SNAPSHOT_BYTES, "snapshot") or b""
                self.resumed_t, self.shown = resumed(raw, len(self.regions.ids))
                self.log.info("pictures up to t=%g were merged before this start (%s)", self.resumed_t, self.snapshot)
            except (OSError, ValueError) as exc:
                self.log.warning("%s: not a snapshot (%s): every time the region caches hold is merged", self.snapshot,
                                 exc)

    def on_picture(self, r: int, msg: TrackPicture) -> None:
        if msg.ids and msg.x.shape[1] != self.dim:  # its merge with the others' would fail
            raise Rejected("wrong_model", f"region {self.regions.ids[r]}'s picture at t={msg.t} has {msg.x.shape[1]}-D "
                           f"tracks; this merger's are {self.dim}-D (--dim)")
        if not msg.closing and round(msg.t / self.period) * self.period != msg.t:  # PictureClock's k period
            raise Rejected("time_jump", f"region {self.regions.ids[r]}'s picture at t={msg.t!r} is not at a multiple "
                           f"of the picture period {self.period:g} s ([mtt] period), where every region's are")
        if not msg.closing and not (msg.seq < NUMBER_ROOM and abs(msg.t) / self.period < NUMBER_ROOM / 2):
            # the merged pictures are numbered on from the first region picture taken (PictureClock.numbered): within
            # these, every merged picture's number stays below 2**63; a first picture numbered 2**63 - 1 at t = 0 made
            # every merged picture's number leave the wire's integers, each refused by every receiver
            raise Rejected("seq_jump", f"region {self.regions.ids[r]}'s picture {msg.seq} at t={msg.t:g}: a number of "
                           f"{NUMBER_ROOM:.3g} or more, or a time of {NUMBER_ROOM / 2:.3g} periods or more from t = 0: "
                           "the merged pictures numbered on from it could leave the wire's integers")
        rid, R = self.regions.ids[r], len(self.regions.ids)
        if msg.began and (msg.began != (0,) or msg.fused_sensors[0] != rid or msg.fused_seqs[0] % R != r):
            # a centre lists its own start, first, once, with a track id of its region's sequence (the replay's check)
            raise Rejected("wrong_region", f"region {rid}'s picture at t={msg.t}: a centre's start at positions "
                           f"{list(msg.began)[:4]}, not its own first entry naming {rid} and an id of its sequence")
        share = PICTURE_ITEMS // R
        if max(len(msg.ids), len(msg.fused_sensors)) > share:
            raise Rejected("too_large", f"region {self.regions.ids[r]}'s picture at t={msg.t}: {len(msg.ids)} tracks, "
                           f"{len(msg.fused_sensors)} entries; its share of a merged picture is {share}")
        self.started[r] = True
        if self.settle_until is not None:  # the caches' replies, interleaved with live pictures: sorted first
            if any(q == r and p.t == msg.t and digest(p) == digest(msg) for q, p in self.settling):
                self.count("duplicate")
            else:
                self.settling.append((r, msg))
        elif msg.closing:
            self._close(r, msg)
        else:
            self._admit(r, msg)
        self._merge()

    def _close(self, r: int, msg: TrackPicture) -> None:
        """Keep region ``r``'s closing record: a picture of the region taken after it is a new process's."""
        if digest(msg) == self.closed[r]:  # a re-delivery (a cache's) of the one taken
            self.count("duplicate")
            return
        self.closed[r] = digest(msg)
        self.closing[r] = msg

    def held(self) -> bool:
        """At a clean stop: a region that sent pictures has not sent its closing record (what its centre
        processed after its last picture, published as it stops). The merger goes on until every such region's
        has come, for at most ``drain_deadline_s`` (a centre that died sends none), so that the merged closing
        record holds every region's last entries: stopped after its centres (the launcher's order) with one
        still on its way, it left them out, and the recording did not replay to the live pictures."""
        coming = {r for r, msg in self.settling if msg.closing}
        return any(s and c is None and r not in coming for r, (s, c) in enumerate(zip(self.started, self.closing)))

    def _admit(self, r: int, msg: TrackPicture) -> None:
        """Take region ``r``'s picture, and those it witnesses, through the lead guard. Before the guard has
        taken any (it takes the first as it comes: nothing to lead yet), the pictures wait until two regions
        with a live centre have sent one, or ``--wait``, and go through it in time order (:meth:`_release`): a
        region's identity sending first a picture stamped 10^9 s ahead made it a region that started later,
        and every genuine picture of it was refused (before the redteam59 session)."""
        if self.lead.newest is None:
            if self.fresh is None:  # after on_start (the snapshot's ids shown), before the first picture
                self.fresh = pickle.dumps(tuple(getattr(self, a) for a in self.start_attrs))
            self.first.append((r, msg))
            self.first_at = time.monotonic() if self.first_at is None else self.first_at
            covered = len(self.regions.ids) - len(self._uncovered(time.monotonic()))
            if len({q for q, _ in self.first}) >= min(2, covered):
                self._release()
            return
        self._guarded(r, msg)

    def _release(self) -> None:
        """The first pictures held by :meth:`_admit`, through the lead guard in time order."""
        first, self.first, self.first_at = sorted(self.first, key=lambda item: item[1].t), [], None
        if len({r for r, _ in first}) < 2:  # one region's: nothing to agree with, its first picture starts
            self.lead.start_gap = None
        for r, msg in first:
            self._guarded(r, msg)

    def _guarded(self, r: int, msg: TrackPicture) -> None:
        """Region ``r``'s picture, and those it witnesses, through the lead guard (:meth:`_take`); one that
        contradicts a start of one region's pictures is held instead (:meth:`_against`). The first pictures the
        start passed over (more than ``start_gap`` from it: counted by the lead guard) contradict it too: held."""
        rid = self.regions.ids[r]
        if self.sole.contradicts(msg.t):
            self._against(r, msg)
            return
        first = self.lead.first
        released = self.in_time(self.lead, self.keys.region_picture(rid), msg, rid, (r, msg))
        for region, picture in released:
            self._take(region, picture)
        if released and first and not self.lead.first:  # the start: the first pictures not taken were dropped
            for _, _, (q, picture), _ in first:
                if not any(picture is p for _, p in released) and self.sole.contradicts(picture.t):
                    self._against(q, picture, counted=True)

    def _against(self, r: int, msg: TrackPicture, counted: bool = False) -> None:
        """Region ``r``'s picture contradicts a start of one region's pictures (:class:`SoleStart`): held, counted
        ``rejected_time_behind`` or ``rejected_time_lead`` (unless ``counted``); or, when a held one of another
        region agrees with it, the start abandoned (``start_abandoned``): the merger's state as before its first
        picture, then the held pictures near it and it taken again (the start rule: they agree)."""
        rid = self.regions.ids[r]
        again = self.sole.contradicted(rid, msg.t, (r, msg), held_bytes(msg))
        if not again:
            if not counted:
                assert self.sole.span is not None
                self.note_rejected(self.keys.region_picture(rid), Rejected(
                    "time_behind" if msg.t < self.sole.span[0] else "time_lead",
                    f"region {rid}'s picture at t={msg.t:g}, more than max_time_jump_s from the start, every picture "
                    f"taken region {self.sole.sensor}'s (held: lead.SoleStart)"))
            return
        self.count("start_abandoned")
        self.log.warning("region %s's picture at t=%g and another region's agree against the start, every picture "
                         "taken region %s's: started again from them (lead.SoleStart)", rid, msg.t, self.sole.sensor)
        assert self.fresh is not None  # a start was taken
        for name, value in zip(self.start_attrs, pickle.loads(self.fresh)):
            setattr(self, name, value)
        for q, picture in again:
            self._guarded(q, picture)

    def _take(self, r: int, msg: TrackPicture) -> None:
        """Queue region ``r``'s picture for its time, or count it late when that time was merged. A
        picture of a time taken from the region before (a re-delivery from a cache, or two primaries'
        during a split brain, before or after the merge of its time) is a ``duplicate`` when equal to
        the one taken, else rejected (``conflict``; the first stays) and the next merged picture
        ``contested``; so is one before the latest taken whose time was merged. One before the latest
        whose time was not merged (a cache's reply overtaken by a live picture) is queued in order."""
        latest, seen, mark = self.latest[r], self.seen[r], digest(msg)
        merged = self.merged_t is not None and msg.t <= self.merged_t
        if msg.t in seen or (latest is not None and msg.t <= latest.t and merged):
            if seen.get(msg.t) == mark:
                self.count("duplicate")
                return
            if not self.contested:
                self.count("contested")
            self.contested = True
            self.note_rejected(self.keys.region_picture(self.regions.ids[r]), Conflict(msg.seq, (
                f"region {self.regions.ids[r]}'s picture at t={msg.t}: it has sent one at "
                f"t={msg.t if latest is None else latest.t}")))
            return
        closed = self.closing[r]
        if closed is not None:  # a centre of the region started again after its former one's clean stop
            self.late[r] += entries_of(closed, self.regions.ids[r])  # what that one processed last goes first
            self.closing[r] = None
        seen[msg.t] = mark
        while len(seen) > self.window:
            del seen[min(seen)]
        if latest is None or msg.t > latest.t:
            self.latest[r] = msg
        self.earliest[r] = min(self.earliest[r], msg.t)
        self.lead.took(self.regions.ids[r], msg.t)
        self.sole.took(self.regions.ids[r], msg.t)
        if self.clock.first is None:  # a merger started again numbers on from the last one's numbers
            self.clock.numbered(msg.seq, msg.t)
        if self.resumed_t is not None and msg.t <= self.resumed_t:  # the last merger published that time
            self.count("merged_before")
            return
        if self.merged_t is not None and msg.t <= self.merged_t:
            self.count("late_picture")
            self.log.warning("region %s's picture at t=%g came after that time was merged", self.regions.ids[r], msg.t)
            self.late[r] += entries_of(msg, self.regions.ids[r])
        else:
            queue = self.pending[r]
            queue.insert(sum(p.t < msg.t for p in queue), msg)
            self.first_seen.setdefault(msg.t, time.monotonic())
        if r in self._uncovered(time.monotonic()):
            self.tokenless |= {r}
            self.log.warning("region %s publishes pictures, but none of its centres' tokens (%s) shows (an access "
                             "control without it?): its pictures are waited for until one does", self.regions.ids[r],
                             self.keys.region_centre(self.regions.ids[r]))

    def on_tick(self) -> None:
        ignored = sum(peers.ignored for peers in (self.centres or {}).values())
        if ignored:
            self.counters["tokens_ignored"] = ignored
        self._merge()

    def _merge(self, force: bool = False) -> None:
        """Publish every picture time that is complete (or whose wait is over, or all when ``force``)."""
        if self.settle_until is not None:
            if not force and time.monotonic() < self.settle_until:
                return
            self.settle_until = None
            # a closing record (at its centre's latest data time) in time order too, after the pictures of its time;
            # before 2026-11-28 it was kept at once, so that a run ended within the settling took the region's
            # pictures for a new process's and put its last entries first
            for r, msg in sorted(self.settling, key=lambda item: (item[1].t, item[1].closing)):
                if msg.closing:
                    self._close(r, msg)
                else:
                    self._admit(r, msg)
            self.settling = []
            self._from_caches()
        now = time.monotonic()
        if self.first and (force or now - self.first_at >= self.wait_s):  # type: ignore[operator]
            self._release()
        uncovered = self._uncovered(now)
        self._say_uncovered(uncovered)
        while True:
            heads = [q[0].t for q in self.pending if q]
            if not heads:
                return
            T = min(heads)
            absent = [r for r, q in enumerate(self.pending) if not q and self.closing[r] is None]
            awaited = [r for r in absent if r not in uncovered]  # a region without a live centre sends nothing
            if awaited and not force and now - self.first_seen[T] < self.wait_s:
                return
            # a region that had sent a picture before T and whose next is after it lost T's (or skipped it)
            passed = [r for r, q in enumerate(self.pending) if q and q[0].t > T and self.earliest[r] < T]
            for r in absent + passed:
                self.count("missing_region")
                if r in uncovered:
                    self.count("no_centre")
                else:
                    self.log.warning("picture at t=%g merged without region %s", T, self.regions.ids[r])
            parts = [q.popleft() if q and q[0].t == T else None for q in self.pending]
            self._publish(T, parts, contested=bool(passed) or any(self.started[r] for r in absent),
                          missing=tuple(self.regions.ids[r] for r in sorted(absent + passed)))
            self.first_seen.pop(T, None)
            self.merged_t = T

    def _say_uncovered(self, uncovered: frozenset[int]) -> None:
        """Log each region found without a live centre, and each whose centre is back, once."""
        for r in sorted(uncovered - self.uncovered):
            self.log.warning("region %s has no live centre (its token %s went, or none was declared): merging "
                             "without it at once", self.regions.ids[r], self.keys.region_centre(self.regions.ids[r]))
        for r in sorted(self.uncovered - uncovered):
            self.log.warning("region %s has a live centre again: waiting for its pictures", self.regions.ids[r])
        self.uncovered = uncovered

    def _from_caches(self) -> None:
        """At the end of the start's settling: when every region has pictures queued (its cache's), drop
        the times before the first all of them hold, which would be merged without a region."""
        if not all(self.pending):
            return
        first = max(q[0].t for q in self.pending)
        for queue in self.pending:
            while queue[0].t < first:
                self.first_seen.pop(queue.popleft().t, None)
                self.count("cache_partial")

    def _publish(self, T: float, parts: list[TrackPicture | None], contested: bool = False,
                 closing: bool = False, missing: tuple[str, ...] = ()) -> None:
        tracks, twice, aliased, self.shown = merge_pictures(
            [None if p is None else region_picture_of(p) for p in parts], self.dim, self.gate, self.shown)
        if twice:
            self.count("seen_twice", len(twice))
            self.log.warning("picture at t=%g: ids %s in two regions' pictures (the first region's taken)", T, twice)
        if aliased:  # two tracks under one id: one was handed over under an id its region did not issue
            self.count("id_collision", len(aliased))
            self.log.warning("picture at t=%g: ids %s held by two regions' tracks of different targets (the one "
                             "shown under the id before keeps it, else the issuing region's; the other under an "
                             "alias)", T, aliased)
            contested = True
        current = [[] if p is None else entries_of(p, self.regions.ids[r]) for r, p in enumerate(parts)]
        held = sum(map(len, self.late))
        if held + sum(map(len, current)) > PICTURE_ITEMS:  # the late ones do not fit beside them: dropped
            self.count("late_dropped", held)
            self.log.warning("picture at t=%g: %d entries of late region pictures dropped (no room)", T, held)
            self.late = [[] for _ in self.late]
        entries: Entries = []
        for r, now in enumerate(current):
            entries += self.late[r] + now
            self.late[r] = []
        order = [(s, q) for s, q, _, _, _ in entries]
        left = [i for i, e in enumerate(entries) if e[2] == "left"]
        handovers = [i for i, e in enumerate(entries) if e[2] == "handover"]
        restarted = [i for i, e in enumerate(entries) if e[2] == "restarted"]
        began = tuple((i, e[4]) for i, e in enumerate(entries) if e[2] == "began")
        contested = contested or self.contested or any(p is not None and p.contested for p in parts)
        self.contested = False
        # a closing record is numbered after the last picture
        number = self.clock.number(T) if not closing else 0 if self.merged_t is None else self.clock.number(
            self.merged_t) + 1
        self.publish(self.keys.mtt_picture(), picture_message(
            number, T, tracks, order, left, contested, closing, handovers, tuple(e[3] for e in entries),
            earth=picture_geodetic(self.frame, tracks.x, tracks.P, self.init_z_std),
            restarted=restarted,
            missing=missing, began=began))
        self.seq += 1
        self.counters["pictures"] = self.seq
        if self.snapshot is not None and not closing:
            self._keep(T)

    def _keep(self, T: float) -> None:
        """Write ``T`` and the ids shown (:func:`snapshot_data`) to the snapshot (a whole file, renamed into place)."""
        assert self.snapshot is not None
        try:
            write_sealed(self.snapshot, SNAPSHOT_MAGIC, snapshot_data(T, self.shown, len(self.regions.ids)))
        except OSError as exc:
            self.log.warning("%s: %s (a restart merges again what the region caches hold)", self.snapshot, exc)

    def on_stop(self) -> None:
        """The pictures still held, then one closing record of the regions' closing lists (a picture
        still held for a witness, stamped far ahead, is counted ``rejected_time_lead``)."""
        if self.first:
            self._release()
        self.note_leads(self.keys.region_picture(), self.lead.end())
        self._merge(force=True)
        ended = [c for c in self.closing if c is not None and c.fused_sensors]  # a closing record lists entries
        if ended or any(self.late):
            self._publish(max((c.t for c in ended), default=self.merged_t or 0.0), self.closing, closing=True)


def service_from_args(argv: list[str]) -> PictureMergeService:
    """The merger that ``serve picture ARGV`` runs (a ConfigError is the CLI's one-line error)."""
    parser = service_parser("picture", "merge the region centres' pictures into one")
    parser.add_argument("--config", required=True, help="configuration file; reads [regions], [mtt] (its period), "
                        "[deployment] and [frame] (the merged tracks' lat, lon, alt)")
    parser.add_argument("--dim", type=int, choices=(4, 6), default=4,
                        help="central state size: 6 when any sensor is a radar (default: %(default)s)")
    parser.add_argument("--snapshot", type=Path, metavar="PATH",
                        help="keep the time of the last picture published here; started again, merge only later "
                        "times (launch: OUT/picture.snapshot; default: none, a restart merges again every time the "
                        "region centres' caches hold)")
    parser.add_argument("--wait", type=finite_number, default=MERGE_WAIT_S, metavar="SECONDS",
                        help="merge a picture time without a region after this long (default: %(default)s)")
    args = parser.parse_args(argv)
    if not args.wait > 0:
        parser.error("--wait must be > 0")
    kwargs = service_kwargs(parser, args)
    regions = load_regions(Path(args.config))
    if regions is None:
        raise ConfigError(f"{args.config}: serve picture needs a [regions] table")
    settings = load_tables(Path(args.config), MttServiceSettings)
    period = settings.mtt.period  # the region centres' picture period
    frame = load_frame(Path(args.config))
    return PictureMergeService(regions, args.dim, args.wait, period, None if frame is None else frame.frame,
                               picture_window(period, settings.deployment.speed), args.snapshot,
                               settings.mtt.thresholds.association[args.dim], settings.mtt.init_z_std,
                               settings.deployment.max_time_jump_s, **kwargs)


def main(argv: list[str]) -> int:
    return service_from_args(argv).run()
