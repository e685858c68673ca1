"""Track-to-track fusion centre: association of local tracks, exact fusion, feedback, track life.

Input: for each sensor scan, the local tracker's :class:`LocalReport` (its tracks after the
scan, the linearized observation of every track the scan detected, the tracks it retired).

* **Association.** A local track keeps the central track it was mapped to (so ids do not
  swap at crossings). An unmapped local track is associated by a chi-square test on the
  difference of the two estimates, ``d' (P_l + P_c)^-1 d`` against the quantile of
  ``association_gate_probability`` (dof = local state size), and an assignment
  (``linear_sum_assignment``) over the scan's unmapped tracks and the central tracks that
  have no track of this sensor yet; the rest start central tracks. A mapped pair that fails
  the test ``unmap_after`` times in a row is unmapped (hysteresis) and associated afresh. A
  confirmed local track alone on its central track (it started it and no other sensor's track
  joined) takes part in every association of its sensor's scans, so that a track that narrowly
  failed the test at its start (one detection, no velocity) joins the others' central track once
  it passes; its own central track, left without a local track, is deleted. Decentralized (no
  resets), a confirmed local track that shares its central track with others also takes part
  when it passes the test with a confirmed central track lacking its sensor, its own central track
  one more candidate at its own cost: in a formation, where the test passes the neighbours too, a
  track kept on a neighbour's central track moves to the one it fits better. Two such tracks of one
  sensor that each pass the test with the other's confirmed central track (mapped to each other's
  targets at their start) may also trade places, when one fits the other's better than its own.
* **Fusion.** The centre fuses each local observation (``H, R, z``) into its central track at
  the observation's time, predicting the central track there; out-of-sequence observations up
  to ``max_lag`` old are fused exactly (:mod:`.central_track`; each observation fused again is
  counted ``reprocessed``), older ones are counted as late, and those older than their central
  track's start (another sensor's scan of the target, delivered after the track was started) as
  ``before_start``; neither is fused. Because it fuses what each detection added and never a
  local estimate, there is no double counting: the result equals a centralized filter of the
  same detections.
* **Federated** (``feedback``): after fusing, the centre resets the local track to the
  central estimate with ``P_i = beta_i P`` (``beta_i`` = the number of live sensors, so the
  shares sum to one and renormalize when sensors join or leave); the local tracker then
  predicts with ``Q_i = beta_i Q`` (paper 004 eqs. (17)-(22)). **Decentralized**: no feedback.
* **Life.** A central track is confirmed by the centralized tracker's M-of-N rule applied to
  the scans of every sensor: ``confirm_hits`` detections among the last ``confirm_window``
  sensor scans the centre received since the track started (the starting scan included). A
  false local track of one sensor gets no detections from the others' scans and stays
  tentative; with one live sensor the rule is that sensor's tracker's own (the count for gnn,
  a local track confirmed by its tracker for jipda and mht's score). Where the local trackers confirm
  by a test with a false-confirmation bound (jipda's existence, mht's score) and the count's
  chance to confirm a track started on clutter exceeds that bound at some position sensor's
  clutter density and noise (:func:`needs_local_confirmation`), a track also needs a local track that its
  tracker confirmed: in heavy clutter the count alone confirmed tracks on several sensors'
  clutter tracks. A confirmed track is deleted once every sensor that tracks it (a local track
  maps to it) missed it on its last ``CENTRAL_MISSES`` (2) scans since its last detection
  (``delete_misses`` when one sensor tracks it; more at a lower P_D: :func:`~fedtrack.local_filters.mtt.config.miss_count`): a target that died goes within two scans of the
  slowest sensor instead of lingering until every local tracker deleted its track. It is also deleted when no local
  track maps to it any more or none supported it for ``central_timeout`` seconds.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from fedtrack.fusion_center.mtt.central_track import CentralTracks, DepartedTracks, padded
from fedtrack.fusion_center.mtt.silence import INTERVALS_KEPT, silence_bound, usual_intervals
from fedtrack.local_filters.linear.gating import track_difference_d2
from fedtrack.local_filters.mtt.associators.gnn import assign
from fedtrack.local_filters.mtt.config import MttConfig, miss_count, scan_lost
from fedtrack.local_filters.mtt.local import LocalReport, Resets, no_resets

LocalKey = tuple[str, int]  # (sensor, local track id)

# A confirmed track that several sensors see is deleted once each of them missed it on its
# last CENTRAL_MISSES scans ((1 - P_D)^4 = 1e-4 or less for a live target with P_D = 0.9): the
# track-to-track centre's rule per tracking sensor, and mtt-centralized's as misses in a row
# over every sensor's scans (CENTRAL_MISSES per sensor: engines.central_params).
CENTRAL_MISSES = 2
# At the sensors' detection probabilities the counts may need to be longer: config.miss_count.


ASSOCIATION_SHIFT = 1e6  # larger than any gated pair's d2 + ln det
XY = slice(0, 3, 2)  # the x and y positions of a state [x, vx, y, vy(, z, vz)], as a view


def needs_local_confirmation(cfg: MttConfig, sensor: str, R: np.ndarray) -> bool:
    """Whether a central track also needs a local track confirmed by its tracker, judged on position
    sensor ``sensor`` of noise covariance ``R``: where the local trackers confirm by a test with a
    false-confirmation bound (:attr:`MttConfig.confirm_bound`) and the count's chance to confirm a
    track started on that sensor's clutter exceeds that bound (:meth:`MttConfig.counts_false_confirm`
    of :meth:`MttConfig.clutter_gate_hit`)."""
    bound = cfg.confirm_bound
    return bound is not None and cfg.counts_false_confirm(cfg.clutter_gate_hit(sensor, R)) > bound


@dataclass
class Counters:
    fused: int = 0  # local observations fused
    late: int = 0  # local observations older than max_lag before their central track's newest: not fused
    before_start: int = 0  # local observations older than their central track's start: not fused
    reprocessed: int = 0  # observations fused again after an older one was inserted before them
    started: int = 0
    deleted: int = 0
    unmapped: int = 0
    merged: int = 0
    left: int = 0
    late_reports: int = 0  # reports older than max_lag before the newest report: neither fused nor mapped


# At most this many (query, position) pairs are tested directly rather than through a k-d tree:
# building and querying a tree costs about 60 us at any size, the direct test about 1 us per
# 1,000 pairs (measured: equal near 30,000 pairs); a centre's few unmapped local tracks or
# merge candidates against its tracks are a few thousand pairs.
DIRECT_PAIRS = 1 << 15
# At most this many candidate pairs of one query (a report's unmapped local tracks, or the merge
# test's tracks) and the centre's tracks: each pair's difference, covariance sum and Cholesky
# factor take about 0.5 kB (4-D states; 0.7 kB 6-D), so a report costs at most about 0.5-0.7 GB
# there. Honest reports stay far below: a local track reaches the few central tracks of its
# target's neighbours (10,000 rows with 10 each are 10^5 pairs; a crowd of 1,000 tracks 20 m
# apart within one another's reach, about 140 each at 10 m noise, 1.4 x 10^5), while a report of
# 2,048 fresh local tracks within a metre of 2,048 central ones made 4.2 x 10^6 (14 s, 2.3 GB;
# 4,096: 45 s, 9 GB): refused as CrowdedReport instead (the service counts it rejected_crowded).
MAX_CANDIDATE_PAIRS = 1 << 20


class CrowdedReport(ValueError):
    """A report whose tracks would make more than ``MAX_CANDIDATE_PAIRS`` candidate pairs."""


def candidate_pairs(pos_q: np.ndarray, spread_q: np.ndarray, pos: np.ndarray, spread: np.ndarray, gate: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The pairs ``(i, j)`` of a query ``pos_q[i]`` and a position ``pos[j]`` that can pass the
    chi-square test ``d' (P_i + P_j)^-1 d <= gate``, as two arrays (``i`` ascending, then ``j``):
    its x-y marginal alone needs ``|dxy|^2 <= gate tr(P_xy,i + P_xy,j) <= gate (spread_i +
    spread_j)^2`` (``spread``: root of the x-y position variances), so a pair farther apart fails.

    Up to ``DIRECT_PAIRS`` pairs that bound is tested on every pair. Beyond, one k-d tree query
    per query position with the reach of the largest spread among the ordinary positions (about
    the 90th percentile of the spreads, one partition instead of a quantile's sort and
    interpolation), plus a direct check against the few with a larger spread (tentative tracks
    with a large velocity uncertainty), so that one of them does not make every query cover the
    region; that gives some farther pairs too (the reach only splits the work: the test decides).
    More than ``MAX_CANDIDATE_PAIRS`` pairs from the tree: :class:`CrowdedReport` (counted before
    any is made).
    """
    factor = math.sqrt(gate)
    if pos_q.shape[0] * pos.shape[0] <= DIRECT_PAIRS:
        dx, dy = pos_q[:, 0, None] - pos[:, 0], pos_q[:, 1, None] - pos[:, 1]
        reach = factor * (spread_q[:, None] + spread)
        return np.nonzero(dx * dx + dy * dy <= reach * reach)
    kth = int(0.9 * (spread.size - 1))
    big_spread = float(np.partition(spread, kth)[kth])
    big = (spread > big_spread).nonzero()[0]
    tree, radius = cKDTree(pos), factor * (spread_q + big_spread)
    if pos_q.shape[0] * pos.shape[0] > MAX_CANDIDATE_PAIRS:
        n = int(np.sum(tree.query_ball_point(pos_q, radius, return_length=True)))
        if n > MAX_CANDIDATE_PAIRS:
            raise CrowdedReport(f"{n} pairs of tracks within the association test's reach, at most "
                                f"{MAX_CANDIDATE_PAIRS}")
    near = tree.query_ball_point(pos_q, radius)
    if big.size:
        reach = factor * (spread_q[:, None] + spread[big][None, :])
        close = np.linalg.norm(pos_q[:, None, :] - pos[big][None, :, :], axis=-1) <= reach
        near = [sorted(set(js) | set(big[close[i]].tolist())) for i, js in enumerate(near)]
    counts = np.fromiter(map(len, near), dtype=np.int64, count=len(near))
    j = np.fromiter(itertools.chain.from_iterable(near), dtype=np.int64, count=int(counts.sum()))
    return np.repeat(np.arange(len(near)), counts), j


class HandOver(NamedTuple):
    """Everything a central track's new owner needs (a region centre's track crossing a border,
    :mod:`.shards`): its id, confirmation, ring entries (:meth:`CentralTracks.entries`: the states,
    the observations within ``max_lag`` and the maneuver detector's banks), per sensor its local
    tracks mapped there and its misses in a row, the M-of-N window, the time of its last fused
    observation, and its local tracks with their association strikes."""

    id: int
    confirmed: bool
    entries: tuple[np.ndarray, ...]
    sensors: tuple[str, ...]
    support: np.ndarray  # (S,) local tracks of each of ``sensors`` mapped to it
    streak: np.ndarray  # (S,) misses in a row per sensor
    window: np.ndarray  # (confirm_window,) its last scans' hits (tentative)
    last_support: float
    members: tuple[LocalKey, ...]
    strikes: tuple[int, ...]  # per member


@dataclass
class TrackToTrackCentre:
    """Central tracks of dimension ``dim`` (4 or 6) fused from local trackers' reports.

    The central tracks' states live in :class:`CentralTracks`; the life rules' counts in arrays
    by the same slots, one column per sensor seen (``sensor_names``)."""

    cfg: MttConfig
    dim: int
    feedback: bool
    mapping: dict[LocalKey, int] = field(default_factory=dict)
    members: dict[int, set[LocalKey]] = field(default_factory=dict)  # the mapping reversed
    strikes: dict[LocalKey, int] = field(default_factory=dict)
    sensor_seen: dict[str, float] = field(default_factory=dict)
    sensor_names: list[str] = field(default_factory=list)  # column order of the per-sensor arrays
    # sensor -> its last intervals between scans on the data's time (a late scan adds none)
    scan_gaps: dict[str, deque[float]] = field(default_factory=dict)
    next_id: int = 0
    id_step: int = 1  # ids next_id, next_id + id_step, ...: region r of R starts at r, steps by R (shards)
    counters: Counters = field(default_factory=Counters)

    def __post_init__(self) -> None:
        cfg = self.cfg
        self.tracks = CentralTracks(self.dim, cfg.q, cfg.noise_model, cfg.max_lag,
                                    detector=cfg.central_detector, modes=cfg.mode_rates)
        self._column: dict[str, int] = {}
        self.column_log_miss = np.zeros(0)  # per sensor column, ln(1 - P_D) of its sensor (MttConfig.log_miss)
        self.column_interval = np.zeros(0)  # per sensor column, its latest scan's time since its previous one
        self.n_live = 0  # live sensors at the latest report's time (live_sensors), counted once a report
        self.support = np.zeros((0, 0), dtype=np.int64)  # local tracks of each sensor mapped to a slot
        self.streak = np.zeros((0, 0), dtype=np.int64)  # a confirmed slot's misses in a row per sensor
        self.window = np.zeros((0, cfg.confirm_window), dtype=bool)  # a tentative slot's last scans
        # whether the count alone is unsafe on some position sensor's clutter (judged once per sensor)
        self.local_confirmation = False
        self.count_judged: set[str] = set()
        self.last_support = np.zeros(0)  # when a local observation was last fused into a slot
        # the ids and slots of the central tracks the last report's observations were fused into (or
        # started), one per fused row (an id may repeat; a track deleted since no longer has its id in
        # its slot): the only ones whose latest estimate moved (a region centre checks whether they left it)
        self.moved = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
        self.departed = DepartedTracks(self.tracks)  # confirmed tracks deleted, for later pictures
        self.absorbed: set[int] = set()  # tracks whose local tracks moved to another (not departed)
        self._fit()

    def _fit(self) -> None:
        """Size the per-slot arrays to the track table's capacity and the sensors seen."""
        rows, cols = self.tracks.capacity, len(self.sensor_names)
        self.support = padded(self.support, (rows, cols))
        self.streak = padded(self.streak, (rows, cols))
        self.window = padded(self.window, (rows, self.cfg.confirm_window))
        self.last_support = padded(self.last_support, (rows,))

    def _col(self, sensor: str) -> int:
        col = self._column.get(sensor)
        if col is None:
            col = self._column[sensor] = len(self.sensor_names)
            self.sensor_names.append(sensor)
            self.column_log_miss = np.append(self.column_log_miss, self.cfg.log_miss(sensor))
            self.column_interval = np.append(self.column_interval, 0.0)
            self._fit()
        return col

    def _central_ids(self, keys: list[LocalKey]) -> tuple[np.ndarray, np.ndarray]:
        """The central track each local track maps to (-1: none) and its slot (-1: none), as arrays."""
        cids = list(map(self.mapping.get, keys, itertools.repeat(-1)))
        slots = map(self.tracks.slot.get, cids, itertools.repeat(-1))
        return np.array(cids, dtype=np.int64), np.fromiter(slots, dtype=np.int64, count=len(cids))

    def _map(self, key: LocalKey, cid: int) -> None:
        old = self.mapping.get(key)
        if old is not None and old != cid:
            self.absorbed.add(old)
        self._unmap(key)
        self.mapping[key] = cid
        self.members.setdefault(cid, set()).add(key)
        self.support[self.tracks.slot[cid], self._col(key[0])] += 1

    def _unmap(self, key: LocalKey) -> bool:
        cid = self.mapping.pop(key, None)
        if cid is None:
            return False
        keys = self.members.get(cid)
        if keys is not None:
            keys.discard(key)
            if not keys:
                del self.members[cid]
        slot = self.tracks.slot.get(cid)
        if slot is not None:
            self.support[slot, self._column[key[0]]] -= 1
        return True

    def drop_sensor(self, sensor: str) -> None:
        """A sensor left (its tracker's liveliness was lost, or it fell silent): it no longer
        counts as live (the other trackers' sharing factors are renormalized from their next
        answer on) nor in the deletion rule, and its local tracks leave their central tracks
        (a central track left without any is deleted by the next :meth:`prune`)."""
        self.sensor_seen.pop(sensor, None)
        self.scan_gaps.pop(sensor, None)
        for key in [k for k in self.mapping if k[0] == sensor]:
            self._unmap(key)
            self.strikes.pop(key, None)
        self._drop_column(sensor)
        self.counters.left += 1

    def _drop_column(self, sensor: str) -> None:
        """Free a departed sensor's column of the per-sensor arrays (a column a slot and a
        sensor each: kept, they grew with every sensor ever seen, and a picture's sensor lists
        came out empty beyond 64 of them); it gets a new one if it comes back."""
        col = self._column.pop(sensor, None)
        if col is None:
            return
        del self.sensor_names[col]
        self.support = np.delete(self.support, col, axis=1)
        self.streak = np.delete(self.streak, col, axis=1)
        self.column_log_miss = np.delete(self.column_log_miss, col)
        self.column_interval = np.delete(self.column_interval, col)
        self._column = {name: k for k, name in enumerate(self.sensor_names)}
        self.count_judged.discard(sensor)

    def live_sensors(self, now: float) -> list[str]:
        """The sensors whose latest scan is within their silence bound of ``now`` (the live centre's
        rule on the data's time, :func:`~.silence.silence_bound` with ``central_timeout`` as its floor:
        a sensor scanning every 8 s, or in bursts 8 s apart, stays live between its scans)."""
        usual = self._usual_intervals()
        return sorted(s for s, t in self.sensor_seen.items()
                      if now - t <= silence_bound(s, usual, self.cfg.central_timeout))

    def _usual_intervals(self) -> dict[str, float]:
        """Each sensor's usual interval between scans on the data's time (:func:`~.silence.usual_interval`)."""
        return usual_intervals(self.scan_gaps)

    def _embed(self, H: np.ndarray) -> np.ndarray:
        """A local observation matrix in the central state (2-D states are the prefix of 3-D)."""
        if H.shape[-1] == self.dim:
            return H
        out = np.zeros(H.shape[:-1] + (self.dim,))
        out[..., : H.shape[-1]] = H
        return out

    def _central_start(self, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = x.shape[0]
        if d == self.dim:
            return x.copy(), P.copy()
        xc, Pc = np.zeros(self.dim), np.zeros((self.dim, self.dim))
        xc[:d], Pc[:d, :d] = x, P
        Pc[4, 4], Pc[5, 5] = self.cfg.init_z_std**2, self.cfg.init_velocity_std**2
        return xc, Pc

    def _start(self, t: float, x: np.ndarray, P: np.ndarray) -> int:
        """A new tentative central track at ``t``; returns its id."""
        cid = self.next_id
        self.next_id += self.id_step
        slot = self.tracks.start(cid, t, *self._central_start(x, P))
        self._fit()
        self.support[slot], self.streak[slot], self.window[slot] = 0, 0, False
        self.last_support[slot] = t
        self.counters.started += 1
        return cid

    def ingest(self, report: LocalReport, rows: np.ndarray | None = None) -> Resets:
        """Fuse one local tracker's scan; returns the federated resets (empty when decentralized).
        ``rows`` (bool per row; None: all): the rows taken, the others left as if the report did not
        hold them (a region's, :meth:`RegionCentre.taken`: none of them is mapped here), without
        building the sub-report (:func:`fedtrack.local_filters.mtt.routing.sub_report`).

        A scan that detected none of the report's tracks (a region's sub-report without rows of
        its region: every region centre gets every scan) only counts in the life rules: what
        :meth:`_fuse_rows` leaves after such a scan, without its predictions of the tracks.

        A report older than ``max_lag`` before the newest one (a sensor's missed scans sent in a burst
        when it wakes) is late: neither fused nor associated, counted ``late_reports``. Its local
        tracks, compared with the central tracks at its time, far behind theirs, had started a
        central track each, kept beside the others' (a 12 s freeze: 96 false tracks in a picture)."""
        if report.t < max(self.sensor_seen.values(), default=report.t) - self.cfg.max_lag:
            self.counters.late_reports += 1
            self.moved = np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
            return no_resets(report.sensor, report.t, report.x.shape[1])
        col = self._note_scan(report)
        det_rows = (report.detected if rows is None else report.detected & rows).nonzero()[0]
        if det_rows.size:
            obs = None if rows is None else rows[report.detected].nonzero()[0]
            resets = self._fuse_rows(report, det_rows, col, obs)
            self._unmap_retired(report)  # a late scan's own tracks that later scans deleted: fused, now unmapped
            return resets
        self.moved = det_rows, det_rows.copy()  # nothing fused into: no track moved
        self._count_scan(col, det_rows, report)
        return no_resets(report.sensor, report.t, report.x.shape[1])

    def _note_scan(self, report: LocalReport) -> int:
        """The sensor's latest scan time and its retired local tracks unmapped (and, at its first
        report with an observation, whether its clutter and noise make the count unsafe: a position
        sensor's observations are 2-D); returns its column."""
        t, s = report.t, report.sensor
        if s not in self.count_judged and len(report.obs_R):
            self.count_judged.add(s)
            if report.obs_R.shape[1] == 2 and needs_local_confirmation(self.cfg, s, report.obs_R[0]):
                self.local_confirmation = True
        previous = self.sensor_seen.get(s, t)
        self.sensor_seen[s] = max(previous, t)
        if t > previous:
            self.scan_gaps.setdefault(s, deque(maxlen=INTERVALS_KEPT)).append(t - previous)
        self.n_live = len(self.live_sensors(t))
        col = self._col(s)
        self.column_interval[col] = t - previous
        self._unmap_retired(report)
        return col

    def _unmap_retired(self, report: LocalReport) -> None:
        """Unmap the report's retired local tracks that are mapped."""
        if report.retired.size:
            s, retired = report.sensor, report.retired.tolist()
            for key in self.mapping.keys() & {(s, lid) for lid in retired}:  # retired and mapped
                self._unmap(key)
                self.counters.unmapped += 1
            for lid in retired if self.strikes else ():
                self.strikes.pop((s, lid), None)

    def _fuse_rows(self, report: LocalReport, det_rows: np.ndarray, col: int, obs: np.ndarray | None = None
                   ) -> Resets:
        """The detected rows ``det_rows`` of a report of sensor column ``col``: the hysteresis check,
        association, fusion, resets, the life rules' count of the scan and the duplicate merge.
        ``obs``: their observations' rows (None: every observation's)."""
        t, s = report.t, report.sensor
        d = report.x.shape[1]
        started, H, R, z = ((report.started, report.obs_H, report.obs_R, report.obs_z) if obs is None else
                            (report.started[obs], report.obs_H[obs], report.obs_R[obs], report.obs_z[obs]))
        keys = [(s, i) for i in report.ids[det_rows].tolist()]
        cid, slots = self._central_ids(keys)  # a mapped local track's central track is live; -1: unmapped
        # the estimates at t of the central tracks of the rows to check, of those without a track of
        # this sensor and of those without a track of some other sensor, in one prediction shared by
        # the check, the association, the fusion and the merge test (``at``: each slot's row, -1: none).
        # The association's candidates are among them (a track loses this sensor's last local track
        # before it only by the check below), and so are the merge test's tracks (_merge_duplicates)
        check = ((cid >= 0) > started).nonzero()[0]  # mapped and not started by the local tracker now
        tracks = self.tracks
        has = self.support > 0
        others = ~has[:, col] | (has != has.any(axis=0)).any(axis=1)
        need = np.concatenate([slots[check], (others & (tracks.ids >= 0)).nonzero()[0]])
        X, P = tracks.states_at(need, t)
        at = np.full(tracks.capacity, -1, dtype=np.int64)
        at[need] = np.arange(need.size)
        # the hysteresis check's pairs and the association's in one test; the association's again
        # only if the check unmapped a local track (its rows and candidates then change)
        unmapped_rows, alone = self._unassociated(report, det_rows, cid, slots)
        cands, pairs = self._pairs(report, det_rows[unmapped_rows + alone], col, (X, P, at))
        rows = det_rows[check]
        d2, logdet = track_difference_d2(np.concatenate([report.x[rows] - X[:check.size, :d], pairs[2]]),
                                         np.concatenate([report.P[rows] + P[:check.size, :d, :d], pairs[3]]))
        tested = pairs[0], pairs[1], d2[check.size:], logdet[check.size:]
        if check.size and self._hysteresis(report, keys, check, d2[:check.size], cid, slots):
            unmapped_rows, alone = self._unassociated(report, det_rows, cid, slots)
            cands, (ri, ci, diff, S) = self._pairs(report, det_rows[unmapped_rows + alone], col, (X, P, at))
            tested = (ri, ci, *track_difference_d2(diff, S))
        stay = None
        staying = d2[:check.size] + logdet[:check.size]  # each checked row's cost on its own central track
        movers, swaps = ([], None) if self.feedback else self._movers(report, det_rows, cid, slots, (check, staying),
                                                                       alone, col, (X, P, at))
        if movers:  # decentralized: a mapped confirmed track moves where it fits better than on its own
            own = np.searchsorted(check, movers)
            m = np.arange(len(movers))
            stay = (slots[movers], np.concatenate([m, swaps[0]]), np.concatenate([m, swaps[1]]),
                    np.concatenate([staying[own], swaps[2]]))
            alone = alone + movers
            cands, (ri, ci, diff, S) = self._pairs(report, det_rows[unmapped_rows + alone], col, (X, P, at))
            tested = (ri, ci, *track_difference_d2(diff, S))
        fresh = self._associate(report, det_rows, unmapped_rows, alone, cands, tested, stay)
        for k in unmapped_rows + alone:
            cid[k] = self.mapping[keys[k]]
            slots[k] = tracks.slot[cid[k]]
        is_fresh = np.zeros(len(keys), dtype=bool)
        is_fresh[[k for k in unmapped_rows if keys[k] in fresh]] = True
        if at.size < tracks.capacity:  # a track started since has none
            at = np.concatenate([at, np.full(tracks.capacity - at.size, -1, dtype=np.int64)])
        fused, x_post, P_post = self._fuse_scan((H, R, z), slots, is_fresh, t, (X, P, at))
        rows = slice(None) if fused.all() else fused.nonzero()[0]  # each row's observation fused (the usual)
        supported = slots[rows]
        self.moved = cid[rows], supported
        self.last_support[supported] = np.maximum(self.last_support[supported], t)
        if self.feedback and supported.size:
            beta = float(max(self.n_live, 1))
            resets = Resets(s, t, report.ids[det_rows[rows]], x_post[rows, :d], beta * P_post[rows, :d, :d])
        else:
            resets = no_resets(s, t, d)
        self._count_scan(col, supported, report)
        still_live = tracks.ids[slots] == cid
        self._merge_duplicates(slots[still_live], t, (X, P, at), supported)
        return resets

    def _states_now(self, slots: np.ndarray, t: float, states: tuple[np.ndarray, np.ndarray, np.ndarray],
                    touched: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """What :meth:`CentralTracks.states_at` ``t`` gives for ``slots``, from what the report has
        (``touched``: the slots it fused into or started): an untouched track's estimate in ``states``
        (X, P, at: the report's prediction); a touched one's entry at ``t`` (a prediction over 0 s
        leaves it as it is; with motion modes it combines the modes again, so it is predicted); the
        rest (none in :meth:`_fuse_rows`) predicted."""
        tracks = self.tracks
        X0, P0, at = states
        new = np.zeros(tracks.capacity, dtype=bool)
        new[touched] = True
        new = new[slots]
        row = np.where(new, -1, at[slots])
        X, P = np.empty((slots.size,) + X0.shape[1:]), np.empty((slots.size,) + P0.shape[1:])
        kept = row >= 0
        X[kept], P[kept] = X0[row[kept]], P0[row[kept]]
        if tracks.modes is None and new.any():
            s = slots[new]
            p = tracks._entry_at(s, t)[0]
            X[new], P[new] = tracks.x[s, p], tracks.P[s, p]
            kept |= new
        if not kept.all():
            rest = ~kept
            X[rest], P[rest] = tracks.states_at(slots[rest], t)
        return X, P

    def _hysteresis(self, report: LocalReport, keys: list[LocalKey], check: np.ndarray, d2: np.ndarray,
                    cid: np.ndarray, slots: np.ndarray) -> bool:
        """The check of the mapped rows ``check`` (``d2``: each one's test against its central track): a
        local track inconsistent with its central track ``unmap_after`` times in a row is unmapped
        (its ``cid`` and ``slots`` set to -1), a consistent one's strikes forgiven; returns whether
        one was unmapped."""
        cfg, s = self.cfg, report.sensor
        bad = d2 > cfg.thresholds.association[report.x.shape[1]]
        struck = [key for key in self.strikes if key[0] == s]
        if struck:  # a consistent local track's strikes are forgiven
            good = {keys[k][1] for k in check[~bad].tolist()}
            for key in struck:
                if key[1] in good:
                    del self.strikes[key]
        unmapped = False
        for k in check[bad].tolist():
            key = keys[k]
            self.strikes[key] = self.strikes.get(key, 0) + 1
            if self.strikes[key] >= cfg.unmap_after:
                self._unmap(key)
                self.strikes.pop(key)
                self.counters.unmapped += 1
                cid[k] = slots[k] = -1
                unmapped = True
        return unmapped

    def _unassociated(self, report: LocalReport, det_rows: np.ndarray, cid: np.ndarray, slots: np.ndarray
                      ) -> tuple[list[int], list[int]]:
        """The rows the association takes: the unmapped ones, and the confirmed local tracks alone on
        their central tracks (no other local track maps there)."""
        mapped = (cid >= 0).nonzero()[0]
        lonely = report.confirmed[det_rows[mapped]] & (self.support[slots[mapped]].sum(axis=1) == 1)
        return (cid < 0).nonzero()[0].tolist(), mapped[lonely].tolist()

    def _movers(self, report: LocalReport, det_rows: np.ndarray, cid: np.ndarray, slots: np.ndarray,
                checked: tuple[np.ndarray, np.ndarray], alone: list[int], col: int,
                states: tuple[np.ndarray, np.ndarray, np.ndarray]
                ) -> tuple[list[int], tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Decentralized: the rows of the mapped confirmed local tracks that share their central
        track with other local tracks (the ``alone`` ones aside) and pass the test with a confirmed
        central track of other sensors that has none of sensor column ``col``, or with another such
        row's confirmed central track (the two may swap): each takes part in the association, the
        movers' own central tracks more candidates and only confirmed ones besides
        (:meth:`_associate`). Returns the rows and the swap pairs ``(i, j, d2 + ln det)``: mover ``i``
        passes the test with mover ``j``'s own central track, and ``j`` with ``i``'s, and one of them
        fits the other's better than its own (else the swap costs more). Only the rows the
        hysteresis check tested (``checked``: the rows and each one's ``d2 + ln det`` against its
        own central track, the cost of staying) can move. ``states``: as :meth:`_pairs`'."""
        check, staying = checked
        none = np.zeros(0, dtype=np.int64)
        sharing = np.zeros(cid.size, dtype=bool)
        sharing[check] = True
        sharing &= (cid >= 0) & report.confirmed[det_rows]
        sharing[sharing] = self.support[slots[sharing]].sum(axis=1) > 1
        sharing[alone] = False
        rows = sharing.nonzero()[0]
        if not rows.size:
            return [], (none, none, np.zeros(0))
        gate = self.cfg.thresholds.association[report.x.shape[1]]
        ri, _, diff, S = self._pairs(report, det_rows[rows], col, states, movers=True)[1]
        moving = set(rows[ri[track_difference_d2(diff, S)[0] <= gate]].tolist()) if ri.size else set()
        si, sj, cost = self._swap_pairs(report, det_rows[rows], slots[rows], states)
        if si.size:  # both ways pass, and one of the two fits the other's better than its own
            own = staying[np.searchsorted(check, rows)]
            better = cost < own[si]
            pair = si * rows.size + sj
            back = np.isin(pair, sj * rows.size + si)
            either = np.isin(pair, (sj * rows.size + si)[better]) | better
            si, sj, cost = si[back & either], sj[back & either], cost[back & either]
        moving.update(rows[si].tolist(), rows[sj].tolist())
        movers = sorted(moving)
        index = np.searchsorted(movers, rows)
        return movers, (index[si], index[sj], cost)

    def _swap_pairs(self, report: LocalReport, rows: np.ndarray, own: np.ndarray,
                    states: tuple[np.ndarray, np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The pairs ``(i, j)`` of the local tracks ``rows`` (one sensor's, each on its own central
        track, slots ``own``) where track ``i`` passes the test with track ``j``'s central track, a
        confirmed one, with their ``d2 + ln det``: two tracks of a sensor mapped to each other's
        targets (a swap in a formation, made at their start) can only trade places."""
        X, P, at = states
        d = report.x.shape[1]
        none = np.zeros(0, dtype=np.int64)
        conf = self.tracks.confirmed[own].nonzero()[0]
        if not conf.size:
            return none, none, np.zeros(0)
        xc, Pc = X[at[own[conf]], :d], P[at[own[conf]], :d, :d]  # the confirmed ones: a tight spread
        U, PU = report.x[rows], report.P[rows]
        gate = self.cfg.thresholds.association[d]
        i, k = candidate_pairs(U[:, XY], np.sqrt(PU[:, 0, 0] + PU[:, 2, 2]), xc[:, XY],
                               np.sqrt(Pc[:, 0, 0] + Pc[:, 2, 2]), gate)
        j = conf[k]
        keep = i != j
        i, j, k = i[keep], j[keep], k[keep]
        d2, logdet = track_difference_d2(U[i] - xc[k], PU[i] + Pc[k])
        passes = d2 <= gate
        return i[passes], j[passes], (d2 + logdet)[passes]

    def _pairs(self, report: LocalReport, rows: np.ndarray, col: int, states: tuple[np.ndarray, np.ndarray, np.ndarray],
               movers: bool = False) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        """The association's candidates (the central tracks without a track of sensor column ``col``,
        in increasing id) and its candidate pairs ``(ri, ci)`` of the local tracks ``rows`` and those
        within the chi-square test's reach, with their differences and covariance sums to test.
        ``states``: the central tracks' estimates at the report's time and each slot's row there.
        ``movers``: :meth:`_movers`' candidates and pairs: only the confirmed candidates that local
        tracks map to, the pairs looked up from their side (they are far fewer than ``rows``)."""
        ids, d = self.tracks.ids, report.x.shape[1]
        cands = ((self.support[:, col] == 0) & (ids >= 0)).nonzero()[0]
        if movers:
            cands = cands[self.tracks.confirmed[cands] & self.support[cands].any(axis=1)]
        cands = cands[ids[cands].argsort()]
        if not (rows.size and cands.size):
            none = np.zeros(0, dtype=np.int64)
            return cands, (none, none, np.zeros((0, d)), np.zeros((0, d, d)))
        X, P, at = states
        xc, Pc = X[at[cands], :d], P[at[cands], :d, :d]
        U = report.x[rows]  # their covariances gathered for the pairs only
        local = U[:, XY], np.sqrt(report.P[rows, 0, 0] + report.P[rows, 2, 2])
        central = xc[:, XY], np.sqrt(Pc[:, 0, 0] + Pc[:, 2, 2])
        gate = self.cfg.thresholds.association[d]
        if movers:
            ci, ri = candidate_pairs(*central, *local, gate)
        else:
            ri, ci = candidate_pairs(*local, *central, gate)
        return cands, (ri, ci, U[ri] - xc[ci], report.P[rows[ri]] + Pc[ci])

    def _vouched(self, report: LocalReport) -> np.ndarray:
        """Slots of the central tracks that a track confirmed by the report's tracker maps to."""
        s, mapping = report.sensor, self.mapping
        cids = [mapping[key] for key in ((s, lid) for lid in report.ids[report.confirmed].tolist()) if key in mapping]
        return self.tracks.slots_of(cids)

    def _count_scan(self, col: int, detected: np.ndarray, report: LocalReport) -> None:
        """One scan (``report``) of sensor column ``col`` in the life rules: M-of-N confirmation of
        tentative tracks (the centralized rule over every sensor's scans; where the local trackers'
        own test is safer than the count in some position sensor's clutter,
        :func:`needs_local_confirmation`, a track is confirmed when the rule holds and a local track
        that its tracker confirmed maps to it); a confirmed track that this sensor tracks (a local
        track maps to it) and did not detect misses, and is deleted after ``delete_misses``
        consecutive misses (when several track it, misses as unlikely as ``CENTRAL_MISSES`` of each
        tracking sensor, in any mix: :meth:`_misses_enough`); a
        track confirmed now is confirmed from the scan's time on (:meth:`CentralTracks.as_of`)."""
        cfg, tracks = self.cfg, self.tracks
        hit = np.zeros(tracks.capacity, dtype=bool)
        hit[detected] = True
        live = tracks.ids >= 0
        old = live & tracks.confirmed
        self.streak[old & hit] = 0
        missed = (old > hit).nonzero()[0]  # confirmed and not detected
        dead = missed[:0]
        if missed.size:
            streak = self.streak[missed]
            streak[:, col] += 1
            self.streak[missed] = streak
            tracking = self.support[missed] > 0
            n_tracking = np.count_nonzero(tracking, axis=1)
            need = self._misses_needed(tracking, n_tracking, scan_lost(float(self.column_interval[col])))[:, None]
            dead = missed[(n_tracking > 0) & self._misses_enough(streak, tracking, need)]
        young = (live ^ old).nonzero()[0]  # live and tentative
        window = np.concatenate([self.window[young, 1:], hit[young, None]], axis=1)
        self.window[young] = window
        now = young[np.count_nonzero(window, axis=1) >= cfg.confirm_hits]
        if cfg.confirm_bound is not None and self.n_live == 1:
            now = np.intersect1d(young, self._vouched(report))  # one sensor: its tracker's own test
        elif self.local_confirmation and now.size:
            now = np.intersect1d(now, self._vouched(report))
        if now.size:
            tracks.confirmed[now], tracks.confirmed_t[now] = True, report.t
        for cid in tracks.ids[dead].tolist():
            self._delete(cid)

    def _misses_enough(self, streak: np.ndarray, tracking: np.ndarray, need: np.ndarray) -> np.ndarray:
        """Per row, whether the tracking sensors' misses since the track's last detection (``streak``,
        rows x sensor columns) are as unlikely for a live target as ``need`` misses of each of them
        (``need``, rows x 1): the sum of their log miss probabilities is at most theirs, in any mix of
        sensors, as ``mtt-centralized`` counts misses in a row over every sensor's scans. Each of them
        missing ``need`` times waited for the slowest: a dead target's track stayed in about 2 pictures
        against 0.8 for ``mtt-centralized`` (jipda, sensors at 1.0 / 0.7 / 1.3 s; before fedids)."""
        log_miss = np.where(tracking, self.column_log_miss, 0.0)
        return (streak * log_miss).sum(axis=1) <= need[:, 0] * log_miss.sum(axis=1)

    def _misses_needed(self, tracking: np.ndarray, n_tracking: np.ndarray, lost: float) -> np.ndarray:
        """Misses in a row per tracking sensor before a confirmed track is deleted, per row of
        ``tracking`` (tracks x sensor columns; ``n_tracking`` its row sums): ``CENTRAL_MISSES`` with
        several tracking sensors, ``delete_misses`` with one, or more where a miss by each of them
        is likely enough that the chance of as many for a live target exceeds ``lost``
        (:func:`miss_count`; ``LOST``, or ``LOST`` a second at a scan less than a second after its
        sensor's previous one: :func:`~fedtrack.local_filters.mtt.config.scan_lost`)."""
        floor = np.where(n_tracking > 1, CENTRAL_MISSES, self.cfg.delete_misses)
        total = tracking @ self.column_log_miss  # 0: none tracks the row
        return np.maximum(miss_count(np.where(total < 0.0, total, -np.inf), lost), floor).astype(np.int64)

    def _delete(self, cid: int) -> None:
        """Delete ``cid`` by the life rules; a confirmed one stays in later pictures up to its last
        supported time (:class:`DepartedTracks`) unless its local tracks moved to another track."""
        slot = self.tracks.slot[cid]
        if self.tracks.confirmed[slot] and cid not in self.absorbed:
            self.departed.keep(cid, self.tracks, float(self.last_support[slot]),
                               self.sensor_lists(np.array([slot]))[0])
        for key in list(self.members.get(cid, ())):
            self._unmap(key)
        self.tracks.delete(cid)
        self.counters.deleted += 1

    def _fuse_scan(self, observations: tuple[np.ndarray, np.ndarray, np.ndarray], slots: np.ndarray,
                   fresh: np.ndarray, t: float, states: tuple[np.ndarray, np.ndarray, np.ndarray]
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Fuse the scan's ``observations`` (H, R, z) into their central tracks' ``slots``; returns per detected
        row whether it was fused (or started its track: ``fresh``) and the posterior at ``t``.

        The observations of distinct central tracks are fused together (:meth:`CentralTracks.fuse`:
        in order, or out of sequence with the later ones fused again); a second observation of one
        central track in the next round. The first round starts from the report's prediction
        ``states`` (X, P, at) when it has every track's (without motion modes).
        """
        n = slots.size
        ok, X, P = fresh.copy(), np.zeros((n, self.dim)), np.zeros((n, self.dim, self.dim))
        started = fresh.nonzero()[0]
        if started.size:
            X[started], P[started] = self.tracks.latest(slots[started])[1:]  # started from this local estimate
        H_obs, R_obs, z_obs = observations
        H_all = self._embed(H_obs)
        pending = (~fresh).nonzero()[0]
        reprocessed = self.tracks.reprocessed
        X0, P0, at = states
        first = self.tracks.modes is None
        while pending.size:
            distinct = np.bincount(slots[pending]).max() == 1  # one observation per central track: all at once
            now = pending if distinct else pending[np.sort(np.unique(slots[pending], return_index=True)[1])]
            row = at[slots[now]]
            prior = (X0[row], P0[row]) if first and (row >= 0).all() else None
            first = False  # a later round's tracks were fused into in this one
            done, x_now, P_now = self.tracks.fuse(slots[now], t, H_all[now], R_obs[now], z_obs[now], prior)
            ok[now], X[now], P[now] = done, x_now, P_now
            fused = int(np.count_nonzero(done))
            self.counters.fused += fused
            if fused < done.size:  # a track not fused into is as it was: its newest entry before the fusion
                late = int(np.count_nonzero(t < self.tracks.newest_t(slots[now[~done]]) - self.cfg.max_lag))
                self.counters.late += late
                self.counters.before_start += done.size - fused - late
            pending = pending[~np.isin(pending, now, assume_unique=True)] if now.size < pending.size else now[:0]
        self.counters.reprocessed += self.tracks.reprocessed - reprocessed
        return ok, X, P

    def _merge_duplicates(self, updated: np.ndarray, t: float, states: tuple[np.ndarray, np.ndarray, np.ndarray],
                          touched: np.ndarray) -> None:
        """Merge a central track into an older one that passes the track-to-track test and shares
        no sensor with it (two sensors' tracks of one target that missed each other at the start).

        Both tracks of such a pair lack some sensor that has local tracks (a track supported by
        every such sensor shares one with any other), so only those tracks are looked at; their
        estimates at ``t`` from the report's (:meth:`_states_now`: ``states``, the slots ``touched``)."""
        tracks = self.tracks
        if len(tracks) < 2 or not updated.size:
            return
        has = self.support > 0  # a free slot has none
        partial = ((has != has.any(axis=0)).any(axis=1) & (tracks.ids >= 0)).nonzero()[0]
        if partial.size < 2:
            return
        mark = np.zeros(tracks.capacity, dtype=bool)
        mark[updated] = True  # ``updated``: the slots of this scan's tracks
        partial = partial[tracks.ids[partial].argsort()]  # in increasing id
        mine = mark[partial].nonzero()[0]
        if not mine.size:
            return
        X, P = self._states_now(partial, t, states, touched)
        gate = self.cfg.thresholds.association[self.dim]
        pos, spread = X[:, XY], np.sqrt(P[:, 0, 0] + P[:, 2, 2])
        # a track with a sensor every track of this scan has (the reporting one) merges with none of
        # them: left out before the pairs are made (one report of 8,192 local tracks within a few
        # metres made all 67 million pairs, 14 s and 3.7 GB for a test that refused each of them)
        common = has[partial[mine]].all(axis=0)
        others = (~has[partial][:, common].any(axis=1)).nonzero()[0]
        K, J = candidate_pairs(pos[mine], spread[mine], pos[others], spread[others], gate)
        K, J = mine[K], others[J]
        # a track never merges with itself, nor with one that shares a sensor with it (a track keeps
        # its sensors, and a kept track gains the merged one's): only the other pairs are tested
        tested = (K != J) & ~(has[partial[K]] & has[partial[J]]).any(axis=1)
        K, J = K[tested], J[tested]
        if not K.size:
            return
        diff = X[J] - X[K]  # the chi-square test of every candidate pair at once
        passes = track_difference_d2(diff, P[J] + P[K])[0] <= gate
        close: dict[int, list[int]] = {}
        for k, j in zip(K[passes].tolist(), J[passes].tolist()):
            close.setdefault(k, []).append(j)
        ids = tracks.ids[partial].tolist()
        for k in mine.tolist():
            if ids[k] not in tracks:
                continue
            for j in sorted(close.get(k, ())):
                cid, other = ids[k], ids[j]
                if other not in tracks:
                    continue
                mask, other_mask = self.support[partial[k]] > 0, self.support[partial[j]] > 0
                if not other_mask.any() or (mask & other_mask).any():
                    continue  # shares a sensor, or no local track maps to it any more (pruned next)
                keep, drop = min(cid, other), max(cid, other)
                for key in list(self.members.get(drop, ())):
                    self._map(key, keep)
                ks, ds = tracks.slot[keep], tracks.slot[drop]
                tracks.merge_life(ks, ds)
                self.last_support[ks] = max(self.last_support[ks], self.last_support[ds])
                tracks.delete(drop)
                self.counters.merged += 1
                break

    def _associate(self, report: LocalReport, det_rows: np.ndarray, unmapped: list[int], alone: list[int],
                   cands: np.ndarray, tested: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
                   stay: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None) -> set[LocalKey]:
        """Map the scan's unmapped local tracks (those not associated start central tracks) and
        move its confirmed local tracks that are alone on their central tracks to central tracks of
        other sensors that pass the test (their own central tracks, left without a local track,
        go at the next :meth:`prune`); returns the local tracks that started central tracks.
        ``cands``, ``tested``: :meth:`_pairs`' candidates and pairs ``(ri, ci)`` with their test
        (``d2``, ``ln det``); ``stay``: the movers' own central tracks (slots, one a mover, the last
        rows) and their pairs with them (mover, own central track of mover, cost): staying, or a swap."""
        fresh: set[LocalKey] = set()
        if not unmapped and not alone:
            return fresh
        cfg, t, s = self.cfg, report.t, report.sensor
        rows = det_rows[unmapped + alone]
        d = report.x.shape[1]
        assigned: dict[int, int] = {}
        if cands.size or stay is not None:
            ri, ci, d2, logdet = tested
            gate = cfg.thresholds.association[d]
            # a confirmed track moves only to another sensor's central track: one that no local
            # track maps to any more (its track retired or unmapped in this report) is pruned next
            inside = (d2 <= gate) & ((ri < len(unmapped)) | self.support[cands[ci]].any(axis=1))
            ri, ci, cost = ri[inside], ci[inside], d2[inside] + logdet[inside]
            if stay is not None:  # the last rows (movers) may stay on their own central tracks, or swap them
                own, mover, to, own_cost = stay
                keep = (ri < len(rows) - own.size) | self.tracks.confirmed[cands[ci]]  # movers: to confirmed ones
                ri = np.concatenate([ri[keep], len(rows) - own.size + mover])
                ci = np.concatenate([ci[keep], cands.size + to])
                cost = np.concatenate([cost[keep], own_cost])
                cands = np.concatenate([cands, own])
            # most gated pairs first, then the least cost: a shift makes every gated pair's cost negative
            picked = assign(len(rows), cands.size, ri, ci, cost - ASSOCIATION_SHIFT)
            cand_ids = self.tracks.ids[cands]
            assigned = {int(ri[k]): int(cand_ids[ci[k]]) for k in picked}
        for u in range(len(unmapped) + len(alone)):
            row = int(rows[u])
            key = (s, int(report.ids[row]))
            if u in assigned:
                if self.mapping.get(key) != assigned[u]:  # a mover may stay
                    self._map(key, assigned[u])
            elif u < len(unmapped):
                self._map(key, self._start(t, report.x[row], report.P[row]))
                fresh.add(key)
        return fresh

    def answer(self, report: LocalReport, rows: np.ndarray | None = None) -> tuple[Resets, float]:
        """Everything the centre does with one report (its ``rows``: :meth:`ingest`): fuse it, then
        delete unsupported central tracks; returns the resets for its sensor and the process-noise
        factor (the number of live sensors, 1 when decentralized) for that sensor's next scan."""
        resets = self.ingest(report, rows)
        q_scale = float(max(self.n_live, 1)) if self.feedback else 1.0
        self.prune(report.t)
        return resets, q_scale

    def prune(self, now: float) -> None:
        """Delete central tracks no local track maps to, or unsupported for ``central_timeout``."""
        self._delete_where(now - self.last_support > self.cfg.central_timeout)
        self.departed.expire(now)

    def drop_unsupported(self) -> None:
        """Delete the central tracks no local track maps to (after :meth:`drop_sensor`), as the
        next :meth:`prune` would: a picture before the next report does not show them."""
        self._delete_where(np.zeros(self.tracks.ids.shape, bool))

    def _delete_where(self, stale: np.ndarray) -> None:
        ids = self.tracks.ids  # over every slot at once; only live ones are deleted
        gone = ~self.support.any(axis=1) | stale
        for cid in ids[gone & (ids >= 0)].tolist():
            self._delete(cid)
        self.absorbed.clear()

    def hand_over(self, cid: int) -> HandOver:
        """Remove central track ``cid`` (to a neighbour region's centre) and return its record."""
        slot = self.tracks.slot[cid]
        members = tuple(sorted(self.members.pop(cid, ())))
        record = HandOver(cid, bool(self.tracks.confirmed[slot]), self.tracks.entries(cid), tuple(self.sensor_names),
                          self.support[slot].copy(), self.streak[slot].copy(), self.window[slot].copy(),
                          float(self.last_support[slot]), members, tuple(self.strikes.pop(k, 0) for k in members))
        for key in members:
            del self.mapping[key]
        self.support[slot] = 0
        self.tracks.delete(cid)
        return record

    def take_over(self, record: HandOver) -> None:
        """Continue a neighbour region's central track from its :meth:`hand_over` record."""
        slot = self.tracks.place(record.id, record.confirmed, record.entries)
        self._fit()
        cols = [self._col(s) for s in record.sensors]
        self.support[slot], self.streak[slot] = 0, 0
        self.support[slot, cols], self.streak[slot, cols] = record.support, record.streak
        self.window[slot], self.last_support[slot] = record.window, record.last_support
        for key, strikes in zip(record.members, record.strikes):
            self.mapping[key] = record.id
            self.members.setdefault(record.id, set()).add(key)
            if strikes:
                self.strikes[key] = strikes

    def sensors_of(self, cid: int) -> list[str]:
        """The sensors whose local tracks map to central track ``cid``."""
        return self.sensor_lists(np.array([self.tracks.slot[cid]]))[0]

    def sensor_lists(self, slots: np.ndarray) -> list[list[str]]:
        """The sensors whose local tracks map to each central track slot."""
        names = self.sensor_names
        unique, inverse = np.unique(self.support[slots] > 0, axis=0, return_inverse=True)  # each sensor set once
        sets = [sorted(names[c] for c in np.flatnonzero(row).tolist()) for row in unique]
        return [list(sets[k]) for k in inverse.ravel().tolist()]
