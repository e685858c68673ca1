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
  it passes; its own central track, left without a local track, is deleted.
* **Fusion.** The centre fuses each local observation (``H, R, z``) into its central track at
  the observation's time, predicting the central track there; out-of-sequence observations
  up to ``max_lag`` old are fused exactly (:mod:`.central_track`), older ones are counted as
  late. Because it fuses what each detection added and never a local estimate, there is no
  double counting: the result equals a centralized filter of the same detections.
* **Federated** (``feedback``): after fusing, the centre resets the local track to the
  central estimate with ``P_i = beta_i P`` (``beta_i`` = the number of live sensors, so the
  shares sum to one and renormalize when sensors join or leave); the local tracker then
  predicts with ``Q_i = beta_i Q`` (paper 004 eqs. (17)-(22)). **Decentralized**: no feedback.
* **Life.** A central track is confirmed by the centralized tracker's M-of-N rule applied to
  the scans of every sensor: ``confirm_hits`` detections among the last ``confirm_window``
  sensor scans the centre received since the track started (the starting scan included). A
  false local track of one sensor gets no detections from the others' scans and stays
  tentative; with one live sensor the rule is that sensor's own. A confirmed track is deleted
  once every sensor that tracks it (a local track maps to it) missed it on its last
  ``CENTRAL_MISSES`` (2) scans since its last detection (``delete_misses`` when one sensor
  tracks it): a target that died goes within two scans of the slowest sensor instead of
  lingering until every local tracker deleted its track. It is also deleted when no local
  track maps to it any more or none supported it for ``central_timeout`` seconds.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from fedtrack.fusion_center.mtt.central_track import CentralTrack, fuse_many, start, states_at
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.local import LocalReport, Reset
from fedtrack.local_filters.mtt.tracker import assign

LocalKey = tuple[str, int]  # (sensor, local track id)
# A confirmed track that two or more sensors track is deleted once each of them missed it on
# its last CENTRAL_MISSES scans since its last detection: (1 - P_D)^4 = 1e-4 or less for a live
# target with P_D = 0.9, where the centralized rule's 3 misses in a row (1e-3) drop a live
# target about once a minute among 60 targets seen by 3 sensors.
CENTRAL_MISSES = 2
ASSOCIATION_SHIFT = 1e6  # larger than any gated pair's d2 + ln det


@dataclass
class Counters:
    fused: int = 0
    late: int = 0
    started: int = 0
    deleted: int = 0
    unmapped: int = 0
    merged: int = 0
    left: int = 0


def candidate_pairs(pos: np.ndarray, spread: np.ndarray, rows: list[int], gate: float) -> list[list[int]]:
    """For each of ``rows``, every track ``j`` within ``sqrt(gate) (spread_k + spread_j)`` of it
    (``spread``: root of the x-y position variances): a pair farther apart fails the chi-square
    test ``d' (P_j + P_k)^-1 d <= gate``, whose x-y marginal alone needs
    ``|dxy|^2 <= gate tr(P_xy,j + P_xy,k) <= gate (spread_j + spread_k)^2``.

    One k-d tree query per row with the reach of the largest spread among the ordinary tracks,
    plus a direct check against the few tracks with a larger spread (tentative tracks with a
    large velocity uncertainty), so that one of them does not make every query cover the region.
    """
    factor = float(np.sqrt(gate))
    big_spread = float(np.quantile(spread, 0.9))
    big = np.flatnonzero(spread > big_spread)
    tree = cKDTree(pos)
    out = tree.query_ball_point(pos[rows], factor * (spread[rows] + big_spread))
    if big.size:
        reach = factor * (spread[rows][:, None] + spread[big][None, :])
        close = np.linalg.norm(pos[rows][:, None, :] - pos[big][None, :, :], axis=-1) <= reach
        out = [sorted(set(near) | set(big[close[i]].tolist())) for i, near in enumerate(out)]
    return out


@dataclass
class TrackToTrackCentre:
    """Central tracks of dimension ``dim`` (4 or 6) fused from local trackers' reports."""

    cfg: MttConfig
    dim: int
    feedback: bool
    tracks: dict[int, CentralTrack] = field(default_factory=dict)
    mapping: dict[LocalKey, int] = field(default_factory=dict)
    members: dict[int, set[LocalKey]] = field(default_factory=dict)  # the mapping reversed
    strikes: dict[LocalKey, int] = field(default_factory=dict)
    last_support: dict[int, float] = field(default_factory=dict)
    sensor_seen: dict[str, float] = field(default_factory=dict)
    recent_hits: dict[int, deque[bool]] = field(default_factory=dict)  # tentative tracks' last scans
    misses: dict[int, dict[str, int]] = field(default_factory=dict)  # per tracking sensor, scans missed in a row
    next_id: int = 0
    counters: Counters = field(default_factory=Counters)

    def _map(self, key: LocalKey, cid: int) -> None:
        self._unmap(key)
        self.mapping[key] = cid
        self.members.setdefault(cid, set()).add(key)

    def _unmap(self, key: LocalKey) -> bool:
        cid = self.mapping.pop(key, None)
        if cid is None:
            return False
        keys = self.members.get(cid)
        if keys is not None:
            keys.discard(key)
            if not keys:
                del self.members[cid]
        return True

    def drop_sensor(self, sensor: str) -> None:
        """A sensor left (its tracker's liveliness was lost, or it fell silent): it no longer
        counts as live (the other trackers' sharing factors are renormalized from their next
        answer on) nor in the deletion rule, and its local tracks leave their central tracks
        (a central track left without any is deleted by the next :meth:`prune`)."""
        self.sensor_seen.pop(sensor, None)
        for key in [k for k in self.mapping if k[0] == sensor]:
            self._unmap(key)
            self.strikes.pop(key, None)
        for per_sensor in self.misses.values():
            per_sensor.pop(sensor, None)
        self.counters.left += 1

    def live_sensors(self, now: float) -> list[str]:
        return sorted(s for s, t in self.sensor_seen.items() if now - t <= self.cfg.central_timeout)

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

    def ingest(self, report: LocalReport) -> list[Reset]:
        """Fuse one local tracker's scan; returns the federated resets (empty when decentralized)."""
        cfg, t, s = self.cfg, report.t, report.sensor
        self.sensor_seen[s] = max(self.sensor_seen.get(s, t), t)
        for lid in report.retired.tolist():
            if self._unmap((s, lid)):
                self.counters.unmapped += 1
            self.strikes.pop((s, lid), None)
        d = report.x.shape[1]
        det_rows = np.flatnonzero(report.detected)
        keys = [(s, i) for i in report.ids[det_rows].tolist()]
        started = report.started.tolist()
        # hysteresis: a mapped local track inconsistent with its central track unmap_after times in a row
        check = [k for k, key in enumerate(keys) if not started[k] and self.mapping.get(key) in self.tracks]
        if check:
            xc, Pc = self._priors([self.mapping[keys[k]] for k in check], t)
            rows = det_rows[check]
            diff = report.x[rows] - xc[:, :d]
            d2 = np.einsum("ni,ni->n", diff, np.linalg.solve(report.P[rows] + Pc[:, :d, :d], diff[..., None])[..., 0])
            for k, bad in zip(check, (d2 > cfg.thresholds.association[d]).tolist()):
                key = keys[k]
                if not bad:
                    self.strikes.pop(key, None)
                    continue
                self.strikes[key] = self.strikes.get(key, 0) + 1
                if self.strikes[key] >= cfg.unmap_after:
                    self._unmap(key)
                    self.strikes.pop(key)
                    self.counters.unmapped += 1
        unmapped_rows = [k for k, key in enumerate(keys) if self.mapping.get(key) not in self.tracks]
        for k in unmapped_rows:
            self._unmap(keys[k])
        confirmed = report.confirmed[det_rows].tolist()
        alone = [k for k, key in enumerate(keys) if confirmed[k] and key in self.mapping
                 and len(self.members.get(self.mapping[key], ())) == 1]
        fresh = self._associate(report, det_rows, unmapped_rows, alone)
        posterior = self._fuse_scan(report, keys, fresh, t)
        beta = float(max(len(self.live_sensors(t)), 1))
        fused = [k for k in range(len(keys)) if k in posterior]
        for k in fused:
            cid = self.mapping[keys[k]]
            self.last_support[cid] = max(self.last_support.get(cid, t), t)
        resets = []
        if self.feedback and fused:
            X = np.array([posterior[k][0][:d] for k in fused])
            P = beta * np.array([posterior[k][1][:d, :d] for k in fused])
            resets = [Reset(s, keys[k][1], t, x, Pk) for k, x, Pk in zip(fused, X, P)]
        self._count_scan(s, {self.mapping[keys[k]] for k in posterior})
        self._merge_duplicates({self.mapping[key] for key in keys if key in self.mapping}, t)
        return resets

    def _count_scan(self, sensor: str, detected: set[int]) -> None:
        """One sensor scan of the centralized life rules: M-of-N confirmation of tentative
        tracks; a confirmed track that this sensor tracks (a local track maps to it) and did not
        detect misses, and is deleted after ``delete_misses`` consecutive misses."""
        cfg = self.cfg
        for table in (self.recent_hits, self.misses):
            for cid in [c for c in table if c not in self.tracks]:
                del table[cid]
        dead = []
        for cid, track in self.tracks.items():
            hit = cid in detected
            if track.confirmed:
                streak = self.misses.setdefault(cid, {})
                if hit:
                    streak.clear()
                    continue
                streak[sensor] = streak.get(sensor, 0) + 1
                tracking = self._sensor_set(cid)
                need = CENTRAL_MISSES if len(tracking) > 1 else cfg.delete_misses
                if tracking and all(streak.get(s, 0) >= need for s in tracking):
                    dead.append(cid)
                continue
            window = self.recent_hits.setdefault(cid, deque(maxlen=cfg.confirm_window))
            window.append(hit)
            if sum(window) >= cfg.confirm_hits:
                self.tracks[cid] = track._replace(confirmed=True)
                del self.recent_hits[cid]
        for cid in dead:
            self._delete(cid)

    def _delete(self, cid: int) -> None:
        del self.tracks[cid]
        self.last_support.pop(cid, None)
        self.misses.pop(cid, None)
        for key in list(self.members.get(cid, ())):
            self._unmap(key)
        self.counters.deleted += 1

    def _priors(self, cids: list[int], t: float) -> tuple[np.ndarray, np.ndarray]:
        """Central estimates at ``t`` (batched); a track newer than ``t`` gives its estimate at ``t``."""
        return states_at([self.tracks[c] for c in cids], t, self.cfg.q, self.cfg.noise_model)

    def _fuse_scan(self, report: LocalReport, keys: list[LocalKey], fresh: set[LocalKey], t: float
                   ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """Fuse the scan's observations; returns the posterior at ``t`` per detected row that was fused.

        The observations of distinct central tracks are fused together (:func:`fuse_many`: in
        order, or out of sequence with the later ones fused again); a second observation of one
        central track in the next round.
        """
        cfg = self.cfg
        out: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        pending = []
        for k, key in enumerate(keys):
            if key in fresh:
                cid = self.mapping[key]
                out[k] = (self.tracks[cid].x, self.tracks[cid].P)  # started from this local estimate
            else:
                pending.append(k)
        H_all = self._embed(report.obs_H)
        while pending:
            now, later, taken = [], [], set()
            for k in pending:
                cid = self.mapping[keys[k]]
                (later if cid in taken else now).append(k)
                taken.add(cid)
            cids = [self.mapping[keys[k]] for k in now]
            obs = [(H_all[k], report.obs_R[k], report.obs_z[k]) for k in now]
            for k, cid, done in zip(now, cids, fuse_many([self.tracks[c] for c in cids], t, obs, cfg.q,
                                                          cfg.noise_model, cfg.max_lag)):
                if done is None:
                    self.counters.late += 1
                    continue
                self.tracks[cid], xc, Pc = done
                out[k] = (xc, Pc)
                self.counters.fused += 1
            pending = later
        return out

    def _merge_duplicates(self, updated: set[int], t: float) -> None:
        """Merge a central track into an older one that passes the track-to-track test and shares
        no sensor with it (two sensors' tracks of one target that missed each other at the start)."""
        if len(self.tracks) < 2:
            return
        sensors = {c: self._sensor_set(c) for c in updated if c in self.tracks}
        # a track that every sensor with a local track supports shares a sensor with any other
        everyone = {s for s, _ in self.mapping}
        updated = {c for c, seen in sensors.items() if seen != everyone}
        if not updated:
            return
        cfg = self.cfg
        ids = sorted(self.tracks)
        row = {c: k for k, c in enumerate(ids)}
        X, P = self._priors(ids, t)
        gate = cfg.thresholds.association[self.dim]
        mine = [row[c] for c in sorted(updated)]
        near = candidate_pairs(X[:, [0, 2]], np.sqrt(P[:, 0, 0] + P[:, 2, 2]), mine, gate)
        K = np.fromiter((k for k, js in zip(mine, near) for _ in js), dtype=np.int64)
        J = np.fromiter((j for js in near for j in js), dtype=np.int64, count=K.size)
        diff = X[J] - X[K]  # the chi-square test of every candidate pair at once
        passes = np.einsum("ni,ni->n", diff, np.linalg.solve(P[J] + P[K], diff[..., None])[..., 0]) <= gate
        close: dict[int, list[int]] = {}
        for k, j in zip(K[passes].tolist(), J[passes].tolist()):
            if j != k:
                close.setdefault(k, []).append(j)
        for k, js in zip(mine, near):
            cid = ids[k]
            if cid not in self.tracks or len(js) < 2:
                continue
            for j in sorted(close.get(k, ())):
                other = ids[j]
                if other not in self.tracks:
                    continue
                for c in (cid, other):
                    if c not in sensors:
                        sensors[c] = self._sensor_set(c)
                if not sensors[other] or sensors[cid] & sensors[other]:
                    continue  # shares a sensor, or no local track maps to it any more (pruned next)
                keep, drop = min(cid, other), max(cid, other)
                for key in list(self.members.get(drop, ())):
                    self._map(key, keep)
                sensors[keep] = sensors.get(keep, set()) | sensors.pop(drop, set())
                kept = self.tracks[keep]
                self.tracks[keep] = kept._replace(confirmed=kept.confirmed or self.tracks[drop].confirmed)
                del self.tracks[drop]
                self.last_support[keep] = max(self.last_support.get(keep, t), self.last_support.pop(drop, t))
                self.counters.merged += 1
                break

    def _associate(self, report: LocalReport, det_rows: np.ndarray, unmapped: list[int], alone: list[int]
                   ) -> set[LocalKey]:
        """Map the scan's unmapped local tracks (those not associated start central tracks) and
        move its confirmed local tracks that are alone on their central tracks to central tracks of
        other sensors that pass the test (their own central tracks, left without a local track,
        go at the next :meth:`prune`); returns the local tracks that started central tracks."""
        fresh: set[LocalKey] = set()
        if not unmapped and not alone:
            return fresh
        cfg, t, s = self.cfg, report.t, report.sensor
        taken = {cid for cid, keys in self.members.items() if any(sensor == s for sensor, _ in keys)}
        cands = [cid for cid in self.tracks if cid not in taken]
        rows = det_rows[unmapped + alone]
        d = report.x.shape[1]
        assigned: dict[int, int] = {}
        if cands:
            xc, Pc = self._priors(cands, t)
            xc, Pc = xc[:, :d], Pc[:, :d, :d]
            U, C = report.x[rows], report.P[rows]
            # candidate pairs within the chi-square test's reach (k-d tree), then the test on them
            pos = np.concatenate([U[:, [0, 2]], xc[:, [0, 2]]])
            spread = np.sqrt(np.concatenate([C[:, 0, 0] + C[:, 2, 2], Pc[:, 0, 0] + Pc[:, 2, 2]]))
            gate = cfg.thresholds.association[d]
            near = candidate_pairs(pos, spread, list(range(len(rows))), gate)
            ri = np.fromiter((u for u, js in enumerate(near) for j in js if j >= len(rows)), dtype=np.int64)
            ci = np.fromiter((j - len(rows) for js in near for j in js if j >= len(rows)), dtype=np.int64,
                             count=ri.size)
            L = np.linalg.cholesky(C[ri] + Pc[ci])
            w = np.linalg.solve(L, (U[ri] - xc[ci])[..., None])[..., 0]
            d2 = np.sum(w * w, axis=-1)
            logdet = 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)
            inside = d2 <= gate
            ri, ci, cost = ri[inside], ci[inside], d2[inside] + logdet[inside]
            # most gated pairs first, then the least cost: a shift makes every gated pair's cost negative
            picked = assign(len(rows), len(cands), ri, ci, cost - ASSOCIATION_SHIFT)
            assigned = {int(ri[k]): cands[int(ci[k])] for k in picked}
        for u in range(len(unmapped) + len(alone)):
            row = int(rows[u])
            key = (s, int(report.ids[row]))
            if u in assigned:
                self._map(key, assigned[u])
                continue
            if u >= len(unmapped):
                continue
            x, P = self._central_start(report.x[row], report.P[row])
            cid = self.next_id
            self.next_id += 1
            self.tracks[cid] = start(cid, t, x, P, False)
            self._map(key, cid)
            fresh.add(key)
            self.counters.started += 1
        return fresh

    def answer(self, report: LocalReport) -> tuple[list[Reset], float]:
        """Everything the centre does with one report: fuse it, then delete unsupported central
        tracks; returns the resets for its sensor and the process-noise factor (the number of
        live sensors, 1 when decentralized) for that sensor's next scan."""
        resets = self.ingest(report)
        q_scale = float(max(len(self.live_sensors(report.t)), 1)) if self.feedback else 1.0
        self.prune(report.t)
        return resets, q_scale

    def prune(self, now: float) -> None:
        """Delete central tracks no local track maps to, or unsupported for ``central_timeout``."""
        for cid in list(self.tracks):
            if cid not in self.members or now - self.last_support.get(cid, now) > self.cfg.central_timeout:
                self._delete(cid)

    def sensors_of(self, cid: int) -> list[str]:
        return sorted(self._sensor_set(cid))

    def _sensor_set(self, cid: int) -> set[str]:
        """The sensors whose local tracks map to central track ``cid``."""
        return {s for s, _ in self.members.get(cid, ())}
