"""The live region centres' algorithm as engines, their pictures merged, and the replay of a live
run's recording, each region centre in its own recorded order (docs/multitarget.md#regions).

A live region centre (``serve mtt-centre --region RID``) runs a :class:`RegionEngine`: the
:class:`RegionCentre` of its region, fed the sub-reports and the hand-overs in its arrival order,
with its own :class:`PictureClock`. ``serve picture`` merges the regions' pictures of each time
(:func:`merge_pictures`) and lists in the merged picture every region's processed entries, tagged
with the region (``TrackPicture.regions``). :func:`recorded_pictures` replays such a recording:
every region centre takes its entries in its recorded order, the local trackers track their
scans in order and go on once every region that fused their report answered (as the live trackers
do: a region whose centre was gone never answered), a hand-over is
taken over where its region took it, and the pictures are made and merged as the live services
made them; so the replay of a recording equals its live pictures.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from fedtrack.deployment import MAX_TIME_JUMP_S
from fedtrack.fusion_center.mtt.centre import HandOver, TrackToTrackCentre
from fedtrack.fusion_center.mtt.engines import (
    Engine,
    PictureClock,
    PictureTracks,
    centre_picture,
    no_tracks,
    union_picture,
)
from fedtrack.fusion_center.mtt.failover.standby import NUMBER_ROOM
from fedtrack.fusion_center.mtt.shards import RegionCentre
from fedtrack.geodetic import Frame, RadarSite
from fedtrack.jsonl import InputError, read_jsonl
from fedtrack.local_filters.linear.gating import track_difference_d2
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.local import LocalReport, SensorTracker
from fedtrack.local_filters.mtt.routing import RegionAnswer, RegionRouter, join_answers
from fedtrack.local_filters.mtt.scan import SensorLeft, SensorScan, TrackerRestarted, parse_line
from fedtrack.local_filters.regions import Regions


class RegionPicture(NamedTuple):
    """A region centre's picture: the tracks it holds, and copies of the ones it handed over within
    ``[mtt] unsupported_s`` of data time before (``flying``, each with the latest data time the
    centre had seen at its hand-over: reports from several sensors come out of time order), shown
    in the merged picture while no region shows the track as its own."""

    held: PictureTracks
    flying: PictureTracks | None = None
    flying_t: tuple[float, ...] = ()


# A handed-over track's copy is shown by its old owner for pictures up to ``[mtt] unsupported_s`` of data time
# after the hand-over: a picture made by the old owner after it and by the new owner before the track arrived (each
# makes a picture when the first data after its time arrives) still shows it. The record and the reports travel on
# different keys, so under load it may arrive several reports late (flake60: after 2.6 s, when the copy was kept two
# periods, and one merged picture lacked the track); the trackers await the new owner for ``unsupported_s``
# (``RegionRouter.wait_s``), the new owner would delete the track as unsupported by then anyway, so the copy is kept
# as long. The merger shows a copy only while no region shows the track as its own.


@dataclass
class RegionEngine(Engine):
    """One region's centre (:class:`RegionCentre`) as the live service and the replay run it, with
    the copies of the tracks it handed over lately (:class:`RegionPicture`)."""

    feedback: bool = True
    regions: Regions | None = None
    index: int = 0
    region: RegionCentre = field(init=False)
    shadow: TrackToTrackCentre = field(init=False)  # the tracks handed over lately, as they left
    handed_t: dict[int, float] = field(default_factory=dict)  # their ids -> the latest data time at the hand-over
    high: float = -np.inf  # the latest data time of the sub-reports so far
    sites: dict[str, RadarSite] = field(default_factory=dict)  # [frame.sites]: the radars' sites (life rules)
    frame: Frame | None = None  # [frame]: a 2-D report's track starts at the origin's height there (level_z)

    def __post_init__(self) -> None:
        assert self.regions is not None
        self.region = RegionCentre(self.cfg, self.dim, self.feedback, self.regions, self.index, sites=self.sites,
                                   frame=self.frame)
        self.shadow = TrackToTrackCentre(self.cfg, self.dim, self.feedback, sites=self.sites, frame=self.frame)

    def issue_past(self, shown: int) -> None:
        """:meth:`Engine.issue_past` in the region's sequence of ids (those of region ``index`` of R: ``index``
        modulo R)."""
        c = self.region.centre
        c.next_id = max(c.next_id, shown + 1 + (c.next_id - shown - 1) % c.id_step)

    def answer(self, report: LocalReport, elsewhere: np.ndarray
               ) -> tuple[RegionAnswer, list[tuple[int, int, HandOver]]]:
        self.scans += 1
        self.high = max(self.high, report.t)
        answer, moving = self.region.answer(report, elsewhere)
        for _, _, record in moving:
            self.remember(record)
        return answer, moving

    def remember(self, record: HandOver) -> None:
        """Keep a copy of a track handed over (shown by :meth:`region_picture` for a while)."""
        if record.id in self.handed_t:
            self.shadow.hand_over(record.id)
        for key in record.members:  # a local track is a member of its latest copy only
            self.shadow._unmap(key)
        self.shadow.take_over(record)
        self.handed_t[record.id] = self.high

    def take_over(self, record: HandOver) -> None:
        self.region.take_over(record)

    def leave(self, sensor: str, at_once: bool = False) -> None:
        self.region.drop_sensor(sensor)

    def restart(self, sensor: str) -> None:
        """The sensor's tracker restarted: the local tracks of its former process go (as at a departure)."""
        self.region.drop_sensor(sensor, departed=False)

    def picture(self, T: float) -> PictureTracks:
        return centre_picture(self.region.centre, T) or no_tracks(self.dim)

    def region_picture(self, T: float) -> RegionPicture:
        """The held tracks and the copies still shown (those handed over within
        ``unsupported_s`` before ``T``, not held here again) predicted to ``T``."""
        for cid, t in list(self.handed_t.items()):
            if T >= t + self.cfg.unsupported_s:
                self.shadow.hand_over(cid)
                del self.handed_t[cid]
        held = self.picture(T)
        flying = centre_picture(self.shadow, T)
        if flying is None:
            return RegionPicture(held)
        keep = ~np.isin(flying.ids, held.ids)
        flying = flying if keep.all() else rows_of(flying, keep)
        return RegionPicture(held, flying, tuple(self.handed_t[i] for i in flying.ids))

    def counters(self) -> dict[str, int]:
        r = self.region
        return {**super().counters(), **{f"centre_{k}": v for k, v in vars(r.centre.counters).items()},
                "handed_over": r.handed_over, "taken_over": r.taken_over, "in_flight": r.in_flight}


def rows_of(p: PictureTracks, keep: np.ndarray) -> PictureTracks:
    """The tracks ``keep`` (bool) of a picture."""
    pick = np.flatnonzero(keep).tolist()
    return PictureTracks([p.ids[i] for i in pick], p.x[keep], p.P[keep], [p.confirmed[i] for i in pick],
                         [p.sensors[i] for i in pick], [p.models[i] for i in pick],
                         None if p.maneuver is None else p.maneuver[keep],
                         None if p.existence is None else [p.existence[i] for i in pick])


def alias(i: int, r: int, regions: int) -> int:
    """The id under which the merged picture shows region ``r``'s track ``i`` (of ``regions``) when another
    region's track holds ``i`` (:func:`merge_pictures`): past every id a region issues (``NUMBER_ROOM``)."""
    return NUMBER_ROOM + (i * regions + r) % NUMBER_ROOM


def one_target(a: PictureTracks, i: int, b: PictureTracks, j: int, gate: float) -> bool:
    """Whether track ``i`` of picture ``a`` and track ``j`` of picture ``b`` (of one time) are estimates of
    one target: their difference within ``gate`` (chi-square), as the duplicate merge tests two tracks."""
    d2, _ = track_difference_d2((a.x[i] - b.x[j])[None], (a.P[i] + b.P[j])[None])
    return bool(d2[0] <= gate)


def same_target(parts: list[RegionPicture | None], keeper: tuple[int, int], copies: list[tuple[int, int]],
                gate: float) -> dict[tuple[int, int], bool]:
    """Each copy (region, row) of ``copies`` but ``keeper``: whether it is an estimate of ``keeper``'s target
    (:func:`one_target` on the regions' held tracks)."""
    kept = parts[keeper[0]].held  # type: ignore[union-attr]
    return {(k, row): one_target(kept, keeper[1], parts[k].held, row, gate)  # type: ignore[union-attr]
            for k, row in copies if (k, row) != keeper}


def merge_pictures(parts: list[RegionPicture | None], dim: int, gate: float, before: dict[int, int] | None = None
                   ) -> tuple[PictureTracks, list[int], list[int], dict[int, int]]:
    """The regions' pictures of one time (in region order; None: the region has none) as one, in
    increasing id: every held track, an id held in two regions' pictures (a hand-over between their
    pictures: two copies of one track, within ``gate`` of each other) from the first region; then the
    handed-over copies of ids no region holds, the latest hand-over's. Two tracks under one id (beyond
    ``gate``: a region handed a track under an id another issued, docs/multitarget.md) are both shown:
    the one of the region that showed the id in the previous merged picture (``before``: id -> region), so
    that no shown track changes its id, else the id's issuing region's (region ``r`` of ``R`` issues ``r,
    r + R, ...``), else the first region's, under it, the other under its :func:`alias`. Returns it, the
    ids held twice, the ids aliased and the region showing each held id under it (the next ``before``)."""
    before = before or {}
    R = len(parts)
    where: dict[int, list[tuple[int, int]]] = {}  # id -> (region, row) of each held copy, in region order
    for k, p in enumerate(parts):
        if p is not None:
            for row, i in enumerate(p.held.ids):
                where.setdefault(i, []).append((k, row))
    keep = [np.ones(0 if p is None else len(p.held.ids), dtype=bool) for p in parts]
    renamed: list[dict[int, int]] = [{} for _ in parts]  # per region: row -> its alias
    twice: list[int] = []
    aliased: list[int] = []
    for i, copies in where.items():
        if len(copies) == 1:
            continue
        verdicts = same_target(parts, copies[0], copies, gate)
        if not all(verdicts.values()):
            keeper = next((c for c in copies if c[0] == before.get(i, i % R)),
                          next((c for c in copies if c[0] == i % R), copies[0]))
            verdicts = verdicts if keeper == copies[0] else same_target(parts, keeper, copies, gate)
        for (k, row), same in verdicts.items():
            if same:
                keep[k][row] = False
                twice.append(i)
            else:
                renamed[k][row] = alias(i, k, R)
                aliased.append(i)
    shown = {i: k for i, copies in where.items() for k, row in copies if keep[k][row] and row not in renamed[k]}
    kept: list[PictureTracks | None] = []
    for k, p in enumerate(parts):
        if p is None:
            continue
        held = p.held if keep[k].all() else rows_of(p.held, keep[k])
        if renamed[k]:
            held = held._replace(ids=[renamed[k].get(row, i) for row, i in enumerate(p.held.ids) if keep[k][row]])
        kept.append(held)
    seen = set(where)
    latest: dict[int, tuple[float, int]] = {}  # id -> (hand-over time, region position in parts)
    for k, p in enumerate(parts):
        if p is not None and p.flying is not None:
            for i, t in zip(p.flying.ids, p.flying_t):
                if i not in seen and t > latest.get(i, (-np.inf, 0))[0]:
                    latest[i] = (t, k)
    for k, p in enumerate(parts):
        if p is not None and p.flying is not None:
            keep = np.array([latest.get(i, (0.0, -1))[1] == k for i in p.flying.ids], dtype=bool)
            if keep.any():
                kept.append(rows_of(p.flying, keep))
    return union_picture(kept, dim), twice, aliased, shown


# ---------------------------------------------------------------- the replay of a recording

class Handed(NamedTuple):
    """A recorded hand-over entry: region ``source``'s hand-over number ``serial``."""

    source: str
    serial: int


class Began(NamedTuple):
    """A recorded start of a region centre process with no tracks, numbering its tracks from ``next_id``
    and its hand-overs from ``serial`` (a centre started again after its former one stopped or died)."""

    next_id: int
    serial: int


# (scan, its number), a departure, a tracker's restart (with its next scan's number), a hand-over, a centre's start
Entry = tuple[SensorScan, int] | SensorLeft | TrackerRestarted | Handed | Began


def read_region_entries(path: Path, regions: Regions) -> list[tuple[int, Entry]]:
    """The entries of a live region run's recording (``measurements.jsonl``, every line tagged with
    the ``region`` that processed it), as (region index, entry), in the recorded order."""
    out: list[tuple[int, Entry]] = []
    index = {rid: r for r, rid in enumerate(regions.ids)}
    for lineno, obj in read_jsonl(path):
        where = f"{path}:{lineno}"
        rid = obj.pop("region", None) if isinstance(obj, dict) else None
        if rid not in index:
            raise InputError(f"{where}: region: expected one of the config's regions ({', '.join(regions.ids)}), "
                             f"got {rid!r}")
        if "handover" in obj:
            if set(obj) != {"t", "handover", "from"} or obj["from"] not in index or not isinstance(obj["handover"], int):
                raise InputError(f"{where}: a hand-over line is {{\"t\", \"region\", \"handover\": N, \"from\": region}}")
            out.append((index[rid], Handed(obj["from"], obj["handover"])))
            continue
        if "began" in obj:
            numbers = [obj.get(k) for k in ("next_id", "serial")]
            if (set(obj) != {"t", "began", "next_id", "serial"} or obj["began"] is not True
                    or not all(type(n) is int and 0 <= n < NUMBER_ROOM for n in numbers)
                    or numbers[0] % len(regions.ids) != index[rid]):
                raise InputError(f"{where}: a centre's start is {{\"t\", \"region\", \"began\": true, \"next_id\": N, "
                                 "\"serial\": S}} (integers in [0, 2^62), N in the region's sequence of ids)")
            out.append((index[rid], Began(numbers[0], numbers[1])))
            continue
        seq = obj.pop("seq", None)
        entry = parse_line(obj, where)
        if isinstance(entry, (SensorScan, TrackerRestarted)):
            if not isinstance(seq, int) or isinstance(seq, bool) or seq < 0:
                raise InputError(f"{where}: seq: a region run's scan or restart line needs its scan number")
            out.append((index[rid], (entry, seq) if isinstance(entry, SensorScan) else entry._replace(seq=seq)))
        else:
            out.append((index[rid], entry))
    return out


def is_region_recording(path: Path) -> bool:
    """Whether the first line of ``path`` is tagged with a region (a live region run's recording)."""
    for _, obj in read_jsonl(path):
        return isinstance(obj, dict) and "region" in obj
    return False


@dataclass
class _Tracker:
    """A local tracker of the replay: its scans in order, its router, the report awaiting answers."""

    scans: list[tuple[SensorScan, int]]
    router: RegionRouter
    tracker: SensorTracker | None = None
    next: int = 0  # its next scan
    seq: int | None = None  # the report awaiting answers
    scan: SensorScan | None = None
    parts: list[tuple[LocalReport, np.ndarray]] = field(default_factory=list)
    answers: dict[int, RegionAnswer] = field(default_factory=dict)
    expired: int = 0  # the hand-overs its former processes' routers let expire (``RegionRouter.expired``)


def recorded_pictures(cfg: MttConfig, dim: int, feedback: bool, regions: Regions, entries: list[tuple[int, Entry]],
                      counts: dict[str, int], max_gap: float = MAX_TIME_JUMP_S,
                      sites: dict[str, RadarSite] | None = None, frame: Frame | None = None
                      ) -> Iterator[tuple[float, PictureTracks]]:
    """The merged pictures of a live region run from its recorded entries (module docstring);
    ``counts`` gets the trackers' scans and the centres' counters added up (the replay's report);
    ``max_gap``: the centres' ``[deployment] max_time_jump_s`` (:class:`PictureClock`); ``sites``: ``[frame.sites]``;
    ``frame``: ``[frame]``."""
    R = len(regions.ids)
    engines = [RegionEngine(cfg, dim, feedback=feedback, regions=regions, index=r, sites=sites or {},
                            frame=frame) for r in range(R)]
    clocks = [PictureClock(cfg.period, cfg.picture_delay, max_gap=max_gap) for _ in range(R)]
    queues: list[deque[Entry]] = [deque() for _ in range(R)]
    trackers: dict[str, _Tracker] = {}
    firsts: set[tuple[str, int]] = set()
    # (sensor, scan number): its tracker restarted with that scan (each region lists the restart)
    restarts = {(e.sensor, e.seq) for _, e in entries if isinstance(e, TrackerRestarted)}
    # (sensor, report number) -> the regions that fused it: the tracker waits for their answers only (a
    # region that never fused a report, its centre gone, never answered it: the live tracker went on without)
    fused_by: dict[tuple[str, int], set[int]] = {}
    for r, entry in entries:
        queues[r].append(entry)
        if isinstance(entry, tuple) and not isinstance(entry, (SensorLeft, TrackerRestarted, Handed, Began)):
            scan, seq = entry
            fused_by.setdefault((scan.sensor, seq), set()).add(r)
            if (scan.sensor, seq) not in firsts:
                firsts.add((scan.sensor, seq))
                tracker = trackers.setdefault(scan.sensor, _Tracker([], RegionRouter(regions, cfg.unsupported_s)))
                tracker.scans.append(entry)
    outbox: dict[tuple[int, int], HandOver] = {}
    retired: list[RegionEngine] = []  # the engines of region centre processes that a later one replaced
    shown: list[dict[float, RegionPicture]] = [{} for _ in range(R)]
    index = {rid: r for r, rid in enumerate(regions.ids)}

    def report_of(sensor: str, seq: int) -> _Tracker | None:
        """The sensor's tracker with report ``seq`` made (tracking its next scan if it may), else None."""
        tr = trackers[sensor]
        if tr.seq is None and tr.next < len(tr.scans) and tr.scans[tr.next][1] == seq:
            scan = tr.scans[tr.next][0]
            tr.next += 1
            if (sensor, seq) in restarts:  # a new tracker process: tracks, ids and what it learnt afresh
                tr.expired += tr.router.expired
                tr.tracker, tr.router = None, RegionRouter(regions, cfg.unsupported_s)
            if tr.tracker is None:
                tr.tracker = SensorTracker(scan, cfg, feedback)
            if tr.tracker.is_late(scan):  # the live tracker took no late scan: not the order it took them in
                raise InputError(f"the recorded region entries list scan {seq} of {sensor} (t = {scan.t:g}) after "
                                 f"its tracker's scan of t = {tr.tracker.history.times[-1]:g}, more than max_lag "
                                 "later: not an order its tracker took them in")
            report, _ = tr.tracker.track(scan)
            tr.seq, tr.scan, tr.parts, tr.answers = seq, scan, tr.router.split(report), {}
        return tr if tr.seq == seq else None

    def step(r: int, entry: Entry) -> bool:
        """Region ``r`` takes ``entry`` if it can now (False: it waits for another region or tracker)."""
        if isinstance(entry, Began):  # a new process of the region's centre: empty, its numbers, its own clock
            for T in clocks[r].final():  # the pictures its former process made as it stopped
                shown[r][T] = engines[r].region_picture(T)
            retired.append(engines[r])  # its counters still count
            engines[r] = RegionEngine(cfg, dim, feedback=feedback, regions=regions, index=r, sites=sites or {},
                                      frame=frame)
            engines[r].region.centre.next_id, engines[r].region.serial = entry
            clocks[r] = PictureClock(cfg.period, cfg.picture_delay, max_gap=max_gap)
        elif isinstance(entry, Handed):
            record = outbox.pop((index[entry.source], entry.serial), None)
            if record is None:
                return False
            engines[r].take_over(record)
        elif isinstance(entry, SensorLeft):
            engines[r].leave(entry.sensor)
            clocks[r].left()
        elif isinstance(entry, TrackerRestarted):
            pass  # taken with the scan it names, after the pictures due (as the live centre takes it)
        else:
            scan, seq = entry
            tr = report_of(scan.sensor, seq)
            if tr is None:
                return False
            for T in clocks[r].due(scan.t):
                shown[r][T] = engines[r].region_picture(T)
            if (scan.sensor, seq) in restarts:
                engines[r].restart(scan.sensor)
            answer, moving = engines[r].answer(*tr.parts[r])
            outbox.update(((r, serial), record) for _, serial, record in moving)
            tr.answers[r] = answer
            if len(tr.answers) == len(fused_by[scan.sensor, seq]):
                got = sorted(tr.answers)
                answers = [tr.answers[k] for k in got]
                tr.router.learn([tr.parts[k][0] for k in got], answers, got)
                if feedback:
                    assert tr.tracker is not None and tr.scan is not None
                    tr.tracker.adopt(tr.scan, *join_answers(answers))
                tr.seq = tr.scan = None
        return True

    while any(queues):
        progress = False
        for r in range(R):
            while queues[r] and step(r, queues[r][0]):
                queues[r].popleft()
                progress = True
        if not progress:
            stuck = [f"{regions.ids[r]}: {q[0]!r:.80}" for r, q in enumerate(queues) if q]
            raise InputError("the recorded region entries cannot be replayed in their order (a tracker's report "
                             f"or a hand-over that no region made first): {'; '.join(stuck)}")
    for r in range(R):
        for T in clocks[r].final():
            shown[r][T] = engines[r].region_picture(T)
    counts.update({"scans": len(firsts), "late": 0, "duplicates": 0, "conflicts": 0, "rerun": 0, "lead": 0})
    for e in engines + retired:
        for k, v in e.counters().items():
            if k.startswith("centre_") or k in ("handed_over", "in_flight"):
                counts["centre_" + k.removeprefix("centre_")] = counts.get("centre_" + k.removeprefix("centre_"), 0) + v
    counts["centre_handover_expired"] = sum(tr.expired + tr.router.expired for tr in trackers.values())
    before: dict[int, int] = {}
    for T in sorted(set().union(*shown)):
        merged, _, _, before = merge_pictures([s.get(T) for s in shown], dim, cfg.thresholds.association[dim], before)
        yield T, merged
