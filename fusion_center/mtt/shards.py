"""The track-to-track centre sharded by region: one :class:`TrackToTrackCentre` per region.

Each region's centre owns the central tracks whose latest estimate lies in its region
(:func:`region_of`: the first region containing the position, else the nearest). A local
track's row of a report goes to the centre owning the central track it is mapped to; an
unmapped row to the centre owning the row's position. Every centre gets every report (its
rows, possibly none), so that each counts every sensor's scans (the misses of its tracks, the
live sensors behind the federated shares). After each report, a central track whose latest
estimate left its owner's region is handed over (:class:`HandOver`: id, states, the
out-of-sequence buffer, the maneuver detector, the life counts and the local-track mapping)
to the new owner, where it continues unbroken.

Ids are unique without an allocator: region ``r`` of ``R`` numbers its tracks ``r, r + R,
r + 2R, ...`` (with one region, the unsharded centre's ``0, 1, 2, ...``). The picture is the
union of the centres' tracks in increasing id; a track is in exactly one centre at any time.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from fedtrack.fusion_center.mtt.centre import Counters, TrackToTrackCentre
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.local import LocalReport, Resets
from fedtrack.local_filters.regions import Regions, region_of


def sub_report(report: LocalReport, rows: np.ndarray) -> LocalReport:
    """The rows ``rows`` (bool over the report's tracks) of a report; its retired ids all kept."""
    det = rows[report.detected]
    return report._replace(ids=report.ids[rows], x=report.x[rows], P=report.P[rows],
                           confirmed=report.confirmed[rows], detected=report.detected[rows],
                           obs_H=report.obs_H[det], obs_R=report.obs_R[det], obs_z=report.obs_z[det],
                           started=report.started[det],
                           existence=None if report.existence is None else report.existence[rows])


def join_resets(parts: list[Resets]) -> Resets:
    """The resets of every region's centre for one report, as one."""
    first = parts[0]
    return first._replace(ids=np.concatenate([p.ids for p in parts]), x=np.concatenate([p.x for p in parts]),
                          P=np.concatenate([p.P for p in parts]))


@dataclass
class ShardedCentre:
    """One :class:`TrackToTrackCentre` per region of ``regions``, run in turn."""

    cfg: MttConfig
    dim: int
    feedback: bool
    regions: Regions
    handed_over: int = 0
    centres: list[TrackToTrackCentre] = field(default_factory=list)
    # CPU seconds (process time) spent in each region's centre (its reports, its hand-overs out
    # and in) and in routing rows to regions (the local trackers' part in a live deployment)
    cpu_s: list[float] = field(default_factory=list)
    routing_s: float = 0.0

    def __post_init__(self) -> None:
        n = len(self.regions.ids)
        self.centres = [TrackToTrackCentre(self.cfg, self.dim, self.feedback, next_id=r, id_step=n) for r in range(n)]
        self.cpu_s = [0.0] * n

    def route(self, report: LocalReport) -> np.ndarray:
        """The region (index) each of the report's rows goes to."""
        out = region_of(self.regions, report.x[:, [0, 2]]) if report.ids.size else np.zeros(0, dtype=np.int64)
        for r, c in enumerate(self.centres):
            mine = np.fromiter(((report.sensor, i) in c.mapping for i in report.ids.tolist()), dtype=bool,
                               count=report.ids.size)
            out[mine] = r
        return out

    def answer(self, report: LocalReport) -> tuple[Resets, float]:
        """:meth:`TrackToTrackCentre.answer` of every region's centre on its rows, then the hand-overs."""
        start = time.process_time()
        route = self.route(report)
        self.routing_s += time.process_time() - start
        parts, touched, q_scale = [], [], 1.0
        for r, c in enumerate(self.centres):
            start = time.process_time()
            rows = route == r
            sub = report if rows.all() else sub_report(report, rows)
            resets, q_scale = c.answer(sub)  # the same q_scale in each
            touched.append(c.moved[np.isin(c.moved, c.tracks.ids)])  # not merged away or pruned
            self.cpu_s[r] += time.process_time() - start
            parts.append(resets)
        self.hand_over(touched)
        return join_resets(parts), q_scale

    def hand_over(self, touched: list[np.ndarray]) -> None:
        """Move each central track whose latest estimate left its owner's region to the new owner;
        only the tracks of ``touched`` (per region, the ids this report's rows were fused into or
        started, in increasing order) can have moved; with one region none can."""
        if len(self.centres) == 1:
            return
        moving = []
        for r, (c, cids) in enumerate(zip(self.centres, touched)):
            start = time.process_time()
            if cids.size:
                owner = region_of(self.regions, c.tracks.latest(c.tracks.slots_of(cids))[1][:, [0, 2]])
                moving += [(int(o), c.hand_over(cid)) for cid, o in zip(cids.tolist(), owner.tolist()) if o != r]
            self.cpu_s[r] += time.process_time() - start
        for owner, record in moving:
            start = time.process_time()
            self.centres[owner].take_over(record)
            self.cpu_s[owner] += time.process_time() - start
        self.handed_over += len(moving)

    def drop_sensor(self, sensor: str) -> None:
        for c in self.centres:
            c.drop_sensor(sensor)

    def counters(self) -> dict[str, int]:
        """The centres' counters added up (a departure once), and the hand-overs."""
        total = {k: sum(getattr(c.counters, k) for c in self.centres) for k in vars(Counters())}
        total["left"] = self.centres[0].counters.left
        return {**total, "handed_over": self.handed_over}
