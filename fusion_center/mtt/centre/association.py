"""The track-to-track centre's association of local tracks with central tracks (its mixin
:class:`CentreAssociation`): the hysteresis check of mapped local tracks, the association of the
unmapped and lonely ones (and the movers and swaps in formations), and the merge of
duplicate central tracks. The rules are in :mod:`.track_to_track`'s docstring."""

from __future__ import annotations

import math

import numpy as np

from fedtrack.fusion_center.mtt.centre.candidates import XY, candidate_pairs
from fedtrack.local_filters.linear.gating import track_difference_d2
from fedtrack.local_filters.mtt.associators.gnn import assign
from fedtrack.local_filters.mtt.local import LocalReport

LocalKey = tuple[str, int]  # (sensor, local track id)

ASSOCIATION_SHIFT = 1e6  # larger than any gated pair's d2 + ln det


class CentreAssociation:
    """Association and duplicate merge of :class:`~.track_to_track.TrackToTrackCentre` (mixed into it). It
    relies on the centre's ``cfg``, ``dim``, ``counters``, ``tracks`` (central tracks), ``mapping``
    and ``members`` (local tracks to slots and back), ``strikes``, ``support`` and ``last_support``
    (per-slot arrays), and on its methods ``_map``, ``_unmap`` and ``_start``."""

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
        """The rows of the mapped confirmed local tracks that share their central
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

    def _associate(self, report: LocalReport, det_rows: np.ndarray, unmapped: list[int], alone: list[int],
                   cands: np.ndarray, tested: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
                   stay: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None, start: bool = True
                   ) -> set[LocalKey]:
        """Map the scan's unmapped local tracks (those not associated start central tracks) and
        move its confirmed local tracks that are alone on their central tracks to central tracks of
        other sensors that pass the test (their own central tracks, left without a local track,
        go at the next :meth:`prune`); returns the local tracks that started central tracks.
        ``cands``, ``tested``: :meth:`_pairs`' candidates and pairs ``(ri, ci)`` with their test
        (``d2``, ``ln det``); ``stay``: the movers' own central tracks (slots, one a mover, the last
        rows) and their pairs with them (mover, own central track of mover, cost): staying, or a swap.
        ``start`` False (an excluded sensor, :mod:`.consistency`): those not associated stay unmapped."""
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
        # Wald's threshold of the central tracks it starts (CentreLife._count_scan): raised by their births share
        # and by the start's own detection, which the report counts as a hit and which is no evidence yet
        births = sum(u not in assigned for u in range(len(unmapped))) if start else 0
        log_hit = self._start_hit(self._col(s))
        share = math.log(max(births, 1)) + (log_hit if math.isfinite(log_hit) else 0.0)
        for u in range(len(unmapped) + len(alone)):
            row = int(rows[u])
            key = (s, int(report.ids[row]))
            if u in assigned:
                if self.mapping.get(key) != assigned[u]:  # a mover may stay
                    self._map(key, assigned[u])
            elif u < len(unmapped) and start:
                self._map(key, self._start(t, report.x[row], report.P[row], share))
                fresh.add(key)
        return fresh

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
