"""Where a local tracker's report goes when the centre is sharded by region (docs/multitarget.md#regions).

Every report goes to every region's centre as one sub-report: the report's retired ids always, and
the rows (local tracks) that concern the region: those within ``margin`` of it (its owner by
position included: :func:`near_regions`) and those whose local track the tracker believes that
region's centre holds. Each row carries ``elsewhere``: the tracker believes another region's centre
holds it. Every centre answers every sub-report (:class:`RegionAnswer`: the federated resets of
the rows it fused, the rows it holds after it, and the local tracks it handed over since its last
answer to this sensor with their new regions), and the tracker learns from the answers which
region holds which of its local tracks (:meth:`RegionRouter.learn`). The same code routes in the
replay and in ``serve mtt-local``, so both send the same rows to the same centres.

A local track handed over (an answer's ``moved``) awaits its new owner: until that region's answer holds it,
its rows are flagged ``elsewhere`` in every sub-report, so that no centre takes them as a free row and starts
a track of its own before the hand-over itself has arrived there (the two travel on different keys, and under
load the hand-over came several reports late: docs/multitarget.md, "The race"). The wait is bounded by
``wait_s`` of data time, ``[mtt]``'s ``unsupported_s``: the longest the new owner keeps the handed-over
central track unfed, past which its record would be deleted there anyway; then the belief is forgotten
(counted ``expired``) and the rows are free again.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from fedtrack import wire
from fedtrack.local_filters.mtt.local import LocalReport, Resets, resets_from_wire, resets_to_wire
from fedtrack.local_filters.regions import Regions, near_regions


def sub_report(report: LocalReport, rows: np.ndarray) -> LocalReport:
    """The rows ``rows`` (bool over the report's tracks) of a report; its retired ids all kept."""
    det = rows[report.detected]
    return report._replace(ids=report.ids[rows], x=report.x[rows], P=report.P[rows],
                           confirmed=report.confirmed[rows], detected=report.detected[rows],
                           obs_H=report.obs_H[det], obs_R=report.obs_R[det], obs_z=report.obs_z[det],
                           started=report.started[det],
                           existence=None if report.existence is None else report.existence[rows])


class RegionAnswer(NamedTuple):
    """A region centre's answer to one sub-report: its resets (none when decentralized), the
    process-noise factor (its live sensors), the sub-report's local tracks it holds after it, and
    the local tracks of this sensor it handed over since its last answer (``moved``) with the
    index of the region each went to (``moved_to``)."""

    resets: Resets
    q_scale: float
    held: np.ndarray
    moved: np.ndarray
    moved_to: np.ndarray


@dataclass
class RegionRouter:
    """One tracker's belief of which region's centre holds each of its local tracks."""

    regions: Regions
    wait_s: float  # [s] of data time: the longest a handed-over local track awaits its new owner
    holder: dict[int, int] = field(default_factory=dict)  # local track id -> region index
    awaiting: dict[int, float] = field(default_factory=dict)  # handed over, not yet held by its new owner -> since
    latest: float = -math.inf  # the newest report time split
    expired: int = 0  # local tracks whose new owner did not hold them within wait_s (then forgotten)

    def split(self, report: LocalReport) -> list[tuple[LocalReport, np.ndarray]]:
        """Per region (in order) its sub-report and the rows' ``elsewhere`` flags (a local track awaiting its
        new owner: flagged in every one); forgets the retired tracks."""
        self.latest = max(self.latest, report.t)
        n, R = report.ids.size, len(self.regions.ids)
        believed = np.fromiter(map(self.holder.get, report.ids.tolist(), [-1] * n), dtype=np.int64, count=n)
        rows = near_regions(self.regions, report.x[:, [0, 2]]) if n else np.zeros((0, R), dtype=bool)
        held = np.flatnonzero(believed >= 0)
        rows[held, believed[held]] = True
        waits = np.fromiter(map(self.awaiting.__contains__, report.ids.tolist()), dtype=bool, count=n)
        for lid in report.retired.tolist():
            self.holder.pop(lid, None)
            self.awaiting.pop(lid, None)
        out = []
        for r in range(R):
            mine = rows[:, r]
            out.append((report if mine.all() else sub_report(report, mine),
                        (believed[mine] >= 0) & ((believed[mine] != r) | waits[mine])))
        return out

    def learn(self, sent: list[LocalReport], answers: list[RegionAnswer], answering: list[int] | None = None) -> None:
        """The answers of the regions ``answering`` (default: every region, in order) to the
        sub-reports ``sent`` to them: a local track a region held before and no longer holds is
        forgotten (but one awaiting that region as its new owner), then the hand-overs (``moved``: awaited from
        the newest report time) and the holdings (``held``: no longer awaited) are noted, in region order; a local
        track still awaited after a report made more than ``wait_s`` after its move is forgotten (``expired``)."""
        regions = list(range(len(answers))) if answering is None else answering
        before = dict(self.holder)
        for r, sub, answer in zip(regions, sent, answers):
            for lid in np.setdiff1d(sub.ids, answer.held).tolist():
                if before.get(lid) == r and self.holder.get(lid) == r and lid not in self.awaiting:
                    del self.holder[lid]
        live = set(np.concatenate([sub.ids for sub in sent]).tolist()) if sent else set()
        for answer in answers:
            for lid, to in zip(answer.moved.tolist(), answer.moved_to.tolist()):
                if lid in live:  # not retired since
                    self.holder[lid] = to
                    self.awaiting[lid] = self.latest
        for r, answer in zip(regions, answers):
            for lid in answer.held.tolist():
                self.holder[lid] = r
                self.awaiting.pop(lid, None)
        for lid in [lid for lid, since in self.awaiting.items() if self.latest - since > self.wait_s]:
            del self.awaiting[lid]  # a report made wait_s after the move, and still no answer holds it
            self.holder.pop(lid, None)
            self.expired += 1


def answers_only(sub: LocalReport, answer: RegionAnswer) -> bool:
    """Whether ``answer`` holds and resets only local tracks of the sub-report ``sub`` it answers (as a
    centre's answer does: :meth:`RegionRouter.learn` notes every local track an answer holds)."""
    return bool(np.isin(answer.held, sub.ids).all() and np.isin(answer.resets.ids, sub.ids).all())


def join_answers(answers: list[RegionAnswer]) -> tuple[Resets, float]:
    """The resets of every region's centre for one report, as one (each local track is fused by
    one centre at most), and the largest process-noise factor among them."""
    parts = [a.resets for a in answers]
    first = parts[0]
    resets = first._replace(ids=np.concatenate([p.ids for p in parts]), x=np.concatenate([p.x for p in parts]),
                            P=np.concatenate([p.P for p in parts]))
    return resets, max(a.q_scale for a in answers)


def answer_to_wire(seq: int, answer: RegionAnswer, regions: Regions, region: int) -> wire.TrackResets:
    """Region ``region``'s answer to report ``seq`` as ``TrackResets`` with its region fields."""
    msg = resets_to_wire(seq, answer.resets, answer.q_scale)
    return wire.TrackResets.unchecked(**{**{f.name: getattr(msg, f.name) for f in dataclasses.fields(msg)},
                                         "region": regions.ids[region], "held": tuple(answer.held.tolist()),
                                         "moved": tuple(answer.moved.tolist()),
                                         "moved_to": tuple(regions.ids[r] for r in answer.moved_to.tolist())})


def answer_from_wire(msg: wire.TrackResets, regions: Regions) -> tuple[int, RegionAnswer]:
    """The answering region's index and its answer; ValueError naming the field for a region or a
    hand-over destination that is not one of ``regions``."""
    index = {rid: r for r, rid in enumerate(regions.ids)}
    if msg.region not in index or any(r not in index for r in msg.moved_to):
        raise ValueError(f"region: {msg.region!r} or a moved_to region is not one of {', '.join(regions.ids)}")
    return index[msg.region], RegionAnswer(resets_from_wire(msg), msg.q_scale, np.array(msg.held, dtype=np.int64),
                                           np.array(msg.moved, dtype=np.int64),
                                           np.array([index[r] for r in msg.moved_to], dtype=np.int64))
