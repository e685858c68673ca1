"""The track-to-track centre's life rules (its mixin :class:`CentreLife`): M-of-N confirmation over
every sensor's scans, deletion by the tracking sensors' misses, by lost support and by timeout.
The rules are in :mod:`.track_to_track`'s docstring."""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np

from fedtrack.fusion_center.mtt.centre.candidates import candidate_pairs
from fedtrack.fusion_center.mtt.silence import LEAVE_INTERVALS
from fedtrack.geodetic import RadarSite, above_radio_horizon
from fedtrack.local_filters.mtt.associators.jipda import FALSE_CONFIRM
from fedtrack.local_filters.mtt.config import MttConfig, miss_count, scan_lost
from fedtrack.local_filters.mtt.local import LocalReport
from fedtrack.local_filters.mtt.roles.life import CONFIRM_EVIDENCE, DROP_EVIDENCE

# A confirmed track that several sensors see is deleted once each of them missed it on its
# last CENTRAL_MISSES scans ((1 - P_D)^4 = 1e-4 or less for a live target with P_D = 0.9): the
# track-to-track centre's rule per tracking sensor, and mtt-centralized's as misses in a row
# over every sensor's scans (CENTRAL_MISSES per sensor: engines.central_params).
CENTRAL_MISSES = 2
# At the sensors' detection probabilities the counts may need to be longer: config.miss_count.
# A tentative central track's vetting (bits; CentreLife._corroborated): a sensor that supports none of it
# reported since its start (VETTED), and its confirmation was held back for a sensor's denial (HELD: counted
# uncorroborated once)
VETTED, HELD = 1, 4
# Per tentative slot and sensor (CentreLife._corroborated): the sensor's latest scan that saw the track's
# place missed it while one other sensor alone supported it (PENDING), and so did its scan before (DENIED:
# CENTRAL_MISSES misses in a row, which would delete the track if it were confirmed)
PENDING, DENIED = 1, 2
# Live sensors needed for a denial to hold a track back (CentreLife._corroborated): with two, a denial is one
# sensor's word against the other's, and the centre cannot tell which of them is wrong. One lying sensor of
# two (its scans emptied) held every target of the other tentative: simulate multitarget --seed 1 with s1 and
# s2 only, mean GOSPA 86.77 -> 521.65 m (attack53); with three a denial costs the liar's targets little.
# Nor does a track wait to be vetted with fewer: without a denial the wait only delays the count, by up to the
# other sensor's period (a 0.2 s sensor beside a 5 s one: fusion worse than the fast sensor alone; fastslow56).
DENIAL_LIVE = 3
# A central track's height raised by this many standard deviations before it is judged below a radar's
# horizon (2.33: above it with a chance of at most FALSE_CONFIRM, :meth:`CentreLife._below_horizon`).
Z_FALSE_CONFIRM = NormalDist().inv_cdf(1.0 - FALSE_CONFIRM)
# Wald's thresholds on a tentative track's evidence since its start (CentreLife._evidence): roles.life's
# CONFIRM_EVIDENCE, and DROP_EVIDENCE, above which a tentative central track's evidence is kept (the test
# started again there, as a new track's would be), so that a track that clutter made look false can still be
# confirmed by its target's later detections


def log_ratios(pd: float, clutter: float, gate: float, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`CentreLife._evidence` of a position sensor of detection probability ``pd`` and clutter density
    ``clutter`` on tracks whose gates (at ``gate``, the 2-D chi-square quantile) have the covariances ``S``
    (n, 2, 2): per track, the log-likelihood ratios of a detection and of a miss."""
    area = math.pi * gate * np.sqrt(np.maximum(np.linalg.det(S), 0.0))
    pd = min(pd, 1.0 - 1e-12)
    p = np.minimum(-np.expm1(-clutter * area), pd)
    with np.errstate(divide="ignore"):
        return np.log(pd) - np.log(p), math.log1p(-pd) - np.log1p(-p)


def surely_above(site: RadarSite | None, X: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Per central state of ``X`` (covariances ``P``), whether a radar at ``site`` surely sees its place: the
    place lowered by ``Z_FALSE_CONFIRM`` standard deviations of its height is above the radar's radio horizon
    (:func:`above_radio_horizon`; below it with a chance of at most ``FALSE_CONFIRM``, the mirror of
    :meth:`CentreLife._below_horizon`). A sensor without a site (``None``) and a 2-D state: always. A track of
    unknown height (a position sensor's alone, ``init_z_std``) is lowered below any horizon."""
    if site is None or X.shape[1] != 6:
        return np.ones(X.shape[0], dtype=bool)
    return above_radio_horizon(site, X[:, 0::2] - np.outer(Z_FALSE_CONFIRM * np.sqrt(P[:, 4, 4]), [0.0, 0.0, 1.0]))


def needs_local_confirmation(cfg: MttConfig, sensor: str, R: np.ndarray, interval: float = 1.0) -> bool:
    """Whether a central track also needs a local track confirmed by its tracker, judged on position
    sensor ``sensor`` of noise covariance ``R`` and period ``interval``: where the local trackers' own
    rule is safer there than the centre's count, whose chance to confirm a track started on that
    sensor's clutter (:meth:`MttConfig.counts_false_confirm` of :meth:`MttConfig.clutter_gate_hit`)
    exceeds the local trackers' bound: a test's (:attr:`MttConfig.confirm_bound`), or, where they
    count (``gnn``, mht's ``"counts"``), their count raised on that clutter
    (:meth:`MttConfig.raised_count_of`, the same rule with jipda's bound)."""
    bound = cfg.confirm_bound
    if bound is None:
        return cfg.raised_count_of(sensor, R, interval)[0] > cfg.confirm_hits
    return cfg.counts_false_confirm(cfg.clutter_gate_hit(sensor, R, interval)) > bound


class CentreLife:
    """Confirmation and deletion of :class:`~.track_to_track.TrackToTrackCentre`'s central tracks (mixed
    into it). It relies on the centre's ``cfg``, ``counters``, ``tracks``, ``departed``, ``absorbed``,
    ``mapping``, ``members``, ``local_confirmation``, ``own_confirmed``, ``n_live``, ``feedback``, ``excluded``,
    ``sensor_names``, ``usual``, the per-slot arrays ``support``, ``streak``, ``window``, ``vetting``, ``denied`` and
    ``last_support``, the per-column ``column_interval`` and ``column_log_miss``, the report's ``report_states``, and on
    its methods ``_unmap``, ``sensor_lists`` and ``_states_now``."""

    def _states_at(self, slots: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """What :meth:`CentralTracks.states_at` ``t`` gives for ``slots``: while a report's life rules run
        (``report_states``), from its prediction (:meth:`_states_now`: the tracks the rules look at are those it
        did not fuse into, whose estimates at its time it predicted already, row by row as a prediction of them
        alone would), not predicted again (three to four predictions of a few tracks a report: perf60)."""
        known = self.report_states
        if known is None or known[0] != t:
            return self.tracks.states_at(slots, t)
        return self._states_now(slots, t, *known[1:])

    def _vouched(self, slots: np.ndarray, sensor: str) -> np.ndarray:
        """Per slot of ``slots``, whether a local track of ``sensor`` that its tracker confirmed (at its latest
        report, :attr:`own_confirmed`: of the rows taken, which hold every local track mapped here) maps to it;
        looked up from the few slots' local tracks, not from every confirmed track of the report."""
        confirmed, members = self.own_confirmed.get(sensor, frozenset()), self.members
        return np.array([any(s == sensor and lid in confirmed for s, lid in members.get(cid, ()))
                         for cid in self.tracks.ids[slots].tolist()], dtype=bool)

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
        seen = old & hit
        if seen.any():  # the misses since: a late detection's sensors' scans after it
            self.streak[seen] = np.minimum(self.streak[seen], self._scans_after(report.t))
            self.gave_up[seen] &= self.streak[seen] > 0
            seen = seen.nonzero()[0]
            self.evidence[seen] = np.minimum(self.evidence[seen] + self._evidence(seen, hit[seen], col, report), 0.0)
        missed = (old > hit) & (report.t > self.last_support)  # confirmed, not detected, after its last detection
        missed = missed.nonzero()[0]
        dead = missed[:0]
        if missed.size:
            streak = self.streak[missed]
            streak[:, col] += 1
            self.streak[missed] = streak
            tracking = self._tracking(missed)
            n_tracking = np.count_nonzero(tracking, axis=1)
            need = self._misses_needed(tracking, n_tracking, scan_lost(float(self.column_interval[col])))[:, None]
            counts = tracking[:, col].copy()  # the misses of a sensor not tracking it where it sees it too
            others = (~counts).nonzero()[0] if self.sensor_names[col] not in self.excluded else counts[:0]
            if others.size:
                counts[others] = self._in_view(missed[others], report)
            absent = missed[counts]
            self.evidence[absent] += self._evidence(absent, hit[absent], col, report)
            bound = need[:, 0] * np.where(tracking, self.column_log_miss, 0.0).sum(axis=1)
            enough = self._misses_enough(streak, tracking, need) | (self.evidence[missed] <= bound)
            dead = missed[(n_tracking > 0) & enough]
        tentative = (live ^ old).nonzero()[0]  # live and tentative
        counts = hit[tentative] | ~self._blind_to(tentative, col, report)  # the scan counts for them
        young = tentative[counts]
        window = np.concatenate([self.window[young, 1:], hit[young, None]], axis=1)
        self.window[young] = window
        evidence = self.evidence[young] + self._evidence(young, hit[young], col, report)
        self.evidence[young] = np.maximum(evidence, DROP_EVIDENCE)
        counted = ((np.count_nonzero(window, axis=1) >= cfg.confirm_hits)
                   & (self.evidence[young] >= CONFIRM_EVIDENCE + self.share[young]))  # the births share the bound
        now = self._corroborated(tentative, counts, counted, hit, col, report)  # count, Wald, others
        if cfg.confirm_bound is not None and self.n_live == 1:
            now = young[self._vouched(young, report.sensor)]  # one sensor: its tracker's own test
        elif self.local_confirmation and now.size:
            now = now[self._vouched(now, report.sensor)]
        if now.size:
            tracks.confirmed[now], tracks.confirmed_t[now] = True, report.t
            self.evidence[now] = 0.0
        for cid in tracks.ids[dead].tolist():
            self._delete(cid)
        old &= tracks.ids >= 0  # the tracks confirmed before this scan and not deleted by it
        self._denied_confirmed(old.nonzero()[0], hit, col, report)

    def _denied_confirmed(self, confirmed: np.ndarray, hit: np.ndarray, col: int, report: LocalReport) -> None:
        """Make tentative again (counted ``demoted``) those of the confirmed slots ``confirmed`` that the scan
        (``report``, sensor column ``col``) and the other sensors' latest scans deny. A sensor's misses in a row
        of a confirmed track that one other sensor alone supports (``denied``, per slot and column: its supporter's
        detections do not reset them, as they reset the tracking sensors' count) are those of its scans that
        surely see the place: inside the x-y extent of its local tracks and above a sited radar's horizon with
        the track lowered by ``Z_FALSE_CONFIRM`` standard deviations of its height (:meth:`_view`,
        :func:`surely_above`), and holding no local track that may be its own of the target
        (:meth:`_duplicate_beside`); any other scan of it resets its count. Once those misses are as unlikely for
        a live target as the misses that delete a confirmed track its sensors track (:meth:`_misses_needed`,
        :meth:`_misses_enough`: ``CENTRAL_MISSES`` each when two or more deny, ``delete_misses`` for one, more
        at a low P_D), the track is tentative again, denied (``DENIED``): the hold of :meth:`_corroborated`
        keeps it there until local tracks that two sensors' trackers confirmed map to it. With fewer than
        ``DENIAL_LIVE`` live sensors a denial is one sensor's word against the other's: none. A lying sensor's
        ghost that the others see and never detect, confirmed on its own scans, stayed in the picture for good
        (its detections reset the count that deletes a confirmed track)."""
        denied, misses = self.denied, np.zeros(confirmed.size, dtype=np.int8)
        if self.n_live >= DENIAL_LIVE and self.sensor_names[col] not in self.excluded and confirmed.size:
            support = self._fused_support(confirmed)
            alone = ((np.count_nonzero(support, axis=1) == 1) & ~support[:, col] & ~hit[confirmed]).nonzero()[0]
            if alone.size:  # (most reports of an honest scene have none: no predictions made)
                X, P = self._states_at(confirmed[alone], report.t)
                sees = self._view(X, P, report)[0] & surely_above(self.sites.get(report.sensor), X, P)
                sees[sees] = ~self._duplicate_beside(confirmed[alone[sees]], support[alone[sees]], report)
                seen = alone[sees]
                misses[seen] = np.minimum(denied[confirmed[seen], col], np.iinfo(np.int8).max - 1) + 1
        denied[confirmed, col] = misses
        asked = confirmed[misses > 0]
        if not asked.size:
            return
        deniers = self._counted(denied[asked] > 0)
        lost = scan_lost(float(self.column_interval[col]))
        need = self._misses_needed(deniers, np.count_nonzero(deniers, axis=1), lost)[:, None]
        out = asked[self._misses_enough(denied[asked].astype(np.int64), deniers, need)]
        if out.size:
            self.tracks.confirmed[out] = False
            self.window[out], self.evidence[out] = False, 0.0
            denied[out] = np.minimum(denied[out], DENIED)
            self.counters.demoted += out.size

    def _corroborated(self, tentative: np.ndarray, counts: np.ndarray, holds: np.ndarray, hit: np.ndarray,
                      col: int, report: LocalReport) -> np.ndarray:
        """Of the tentative slots whose count holds (``holds``, per slot of ``tentative[counts]``), those that
        are not one sensor's alone unheard or denied by the others. A scan (``report``) of sensor column ``col``
        vets each tentative slot (of ``tentative``) it
        supports none of: blind to it or not, the sensor has had its say. It questions one that exactly one
        other sensor supports when the scan counts for it (``counts``: it sees its place, :meth:`_blind_to`),
        it surely sees that place (:meth:`_surely_seen`: a radar's miss of a track of unknown height may be its
        horizon's; before 2026-11-28 such misses denied an aircraft below every radar's horizon for good),
        did not detect it and holds no track of its own there mapped to a duplicate (:meth:`_duplicate_beside`:
        fast beside two slow sensors, seed 1, each of the 7 slow sensors' questions that held a target's track came
        from its detected local track 14-150 m from it, mapped to a central track of its own; fastslow57)
        (``PENDING``), and denies it when its previous scan did so too (``DENIED``: the
        ``CENTRAL_MISSES`` misses that would delete it if it were confirmed; a live target at P_D 0.9 once in a
        hundred); its next detection takes a question back, not a denial (a local track of clutter mapped for
        a scan would), its local track that its tracker confirmed mapped to the slot (:meth:`_vouched`, of this
        report) takes either back (the sensor now says the target is there: kept, a denial by each of two honest
        sensors while their tracks of a target swapped held it tentative for good, both sensors seeing and
        vouching for it; seed 1 without s2, one target for 250 s), and its next scan blind to the slot takes
        either back (blindness is judged on what the
        centre knows then: a track that its tracker has not confirmed yet gets no skip). With ``DENIAL_LIVE`` live
        sensors or more, a slot that one sensor alone supports is confirmed only once vetted, not by the report
        that questions it, not while another sensor that surely sees
        its place questions it (until that sensor's next say: its supporter's scans in between are one sensor's
        word, however many; :meth:`_surely_seen`) and, while a sensor denies it, only once local tracks that two
        sensors' trackers confirmed map to it (held back, it is counted ``uncorroborated`` once). A compromised
        sensor's consistent ghosts (its own tracker confirms them) filled the count's window with its own scans and
        were confirmed for good, before or despite the others' scans: seed 1, 20 ghosts from t = 100 s, mean GOSPA
        74 -> 223 m; from a sensor scanning every 0.25 s (or sending its scans in bursts) they were confirmed
        between another sensor's question and its denial (attack54: 54 -> 225 m)."""
        sensor, t = report.sensor, report.t
        support = self._fused_support(tentative)  # looked up once: nothing here changes it
        self.vetting[tentative[~support[:, col]]] |= VETTED
        denied = self.denied
        denied[tentative[~counts], col] = 0  # blind to it now
        counted, support = tentative[counts], support[counts]
        detected = counted[hit[counted]]
        denied[detected[denied[detected, col] == PENDING], col] = 0
        asked = tentative[denied[tentative, col] > 0]
        denied[asked[self._vouched(asked, sensor)], col] = 0  # the sensor vouches for it now
        n_support = np.count_nonzero(support, axis=1)
        missed = counted[(n_support == 1) & ~hit[counted] & ~support[:, col]]
        if missed.size:  # a sensor questions only a place it surely sees: a radar's miss may be its horizon's
            alone_col = np.zeros((missed.size, len(self.sensor_names)), dtype=bool)
            alone_col[:, col] = True
            missed = missed[self._surely_seen(missed, alone_col, t)]
        if missed.size:  # nor where its own track of the target may be mapped to a duplicate
            missed = missed[~self._duplicate_beside(missed, support[np.searchsorted(counted, missed)], report)]
        denied[missed, col] = np.where(denied[missed, col] > 0, DENIED, PENDING)
        now = counted[holds]
        if self.n_live < DENIAL_LIVE:  # no third sensor to settle a question: the count alone (fastslow56)
            return now
        state, alone = self.vetting[now], n_support[holds] == 1
        held = alone & ((state & VETTED) == 0)
        held |= denied[now, col] > 0  # the report that questions it does not confirm it
        asking = alone & ~held & self._counted(denied[now] == PENDING).any(axis=1)
        if asking.any():  # nor its supporter's before the answer of a sensor that surely sees it
            held[asking] = self._surely_seen(now[asking], denied[now[asking]] == PENDING, t)
        doubt = self._counted(denied[now] == DENIED).any(axis=1).nonzero()[0]
        if doubt.size:
            held[doubt] |= self._vouching(now[doubt]) < 2
        if not held.any():
            return now
        first = now[held & ((state & HELD) == 0)]
        first = first[self._counted(denied[first] == DENIED).any(axis=1)]  # not those waiting to be vetted
        self.counters.uncorroborated += first.size
        self.vetting[first] |= HELD
        return now[~held]

    def _duplicate_beside(self, slots: np.ndarray, support: np.ndarray, report: LocalReport) -> np.ndarray:
        """Per tentative slot of ``slots`` that one sensor alone supports (``support``: slots x sensor columns),
        whether the report's sensor holds a local track there that may be its own track of the same target: a track
        of two detections or more (its tracker confirmed it, or this scan updated it, not started it), within the
        association test's reach of the slot in x-y (:meth:`_reach_pairs`), mapped to another central track that no
        local track of the slot's supporter maps to (the two sensors' tracks of one target, kept apart by the
        association test on the whole state: a slow sensor's velocity). Its miss of the slot is then no evidence
        against it: the detection is there, under the duplicate. A ghost beside a target that the supporter tracks
        too (the sensor's track mapped to the target's track, which the supporter supports) is still questioned,
        and so is one beside the sensor's newly started tracks (its clutter, one detection)."""
        beside = np.zeros(slots.size, dtype=bool)
        m, n = self._reach_pairs(*self._states_at(slots, report.t), report)
        updated = report.detected.copy()  # detected by this scan and not started by it: two detections or more
        updated[report.detected.nonzero()[0][report.started]] = False
        keep = report.confirmed[n] | updated[n]
        m, n = m[keep], n[keep]
        if not m.size:
            return beside
        slot_of, mapping, sensor = self.tracks.slot, self.mapping, report.sensor
        other = np.array([slot_of.get(mapping.get((sensor, int(lid))), -1) for lid in report.ids[n].tolist()])
        mapped = other >= 0
        m, other = m[mapped], other[mapped]
        supporter = support[m].argmax(axis=1)
        beside[m[~self._fused_support(other)[np.arange(m.size), supporter]]] = True
        return beside

    def _vouching(self, slots: np.ndarray) -> np.ndarray:
        """Per slot of ``slots``, how many sensors have a local track that their tracker confirmed (at their
        latest report) mapped to it, an excluded sensor's not counted."""
        confirmed, members = self.own_confirmed, self.members
        return np.array([len({s for s, lid in members.get(cid, ()) if lid in confirmed.get(s, ())} - self.excluded)
                         for cid in self.tracks.ids[slots].tolist()], dtype=np.int64)

    def _scans_after(self, t: float) -> np.ndarray:
        """Per sensor column, its scans later than ``t`` (of those within ``max_lag`` of its newest): at most
        the misses a track detected at ``t`` has since. A detection that came late (out of sequence) left
        the misses of the scans after it counted; before the linger session it cleared them, and a dead
        target's track stayed until the sensors missed it again (mtt-federated jipda on 200 births and deaths
        over 600 s: 66 of 188 deaths)."""
        return np.array([sum(1 for u in self.scan_times.get(name, ()) if u > t) for name in self.sensor_names],
                        dtype=np.int64)

    def _fused_support(self, slots: np.ndarray) -> np.ndarray:
        """Per slot and sensor column, whether a local track of that sensor maps there, an excluded
        sensor's not counted (its misses and its tracks count for nothing while it is left out)."""
        return self._counted(self.support[slots] > 0)

    def _tracking(self, slots: np.ndarray) -> np.ndarray:
        """Per slot and sensor column, whether that sensor's misses count toward deleting the slot's
        confirmed track: a local track of the sensor maps there, or its tracker retired its last one
        there since the track's last detection (``gave_up``: the tracker's own miss evidence, which
        the sensor's scans since keep adding to; before the linger session its column left the count,
        and the other sensors' misses had to make up for it); an excluded sensor's not counted."""
        return self._counted((self.support[slots] > 0) | self.gave_up[slots])

    def _counted(self, columns: np.ndarray) -> np.ndarray:
        """``columns`` (slots x sensor columns, a fresh array) with the columns of the sensors left out
        (:attr:`excluded`) cleared; as it is when none is (every report: no array made)."""
        if self.excluded:
            columns &= np.array([name not in self.excluded for name in self.sensor_names])
        return columns

    def _blind_to(self, slots: np.ndarray, col: int, report: LocalReport) -> np.ndarray:
        """Per tentative track of ``slots``, whether the report of sensor column ``col`` is no evidence
        against it: none of this sensor's local tracks maps to it, and at the report's time it lies outside
        the x-y extent of the report's local tracks (a sensor's tracks, its clutter's too, lie in what it
        sees) and beyond the association test's reach of each of them (in x-y: a sensor without clutter,
        whose extent is its targets', sees the target beside which another sensor's track is a duplicate),
        where this sensor may be blind; and it is no one sensor's ghost: two other sensors' local tracks map
        to it, or one sensor's local track that its tracker confirmed does and this sensor's clutter shows
        it is blind there (:meth:`_clutter_would_show`; a sensor whose reports show one target and no
        clutter shows nothing of where it is blind, and a ghost of another sensor stays tentative beside it),
        or this sensor is a radar with a site that cannot see it: below its radio horizon
        (:meth:`_below_horizon`), where the extent does not count (a far radar's clutter surrounds a low aircraft in
        x-y, high above it); or, whatever else holds, a sited radar that may not see it (:meth:`_maybe_hidden`:
        not surely above its horizon, one sensor's track or not). Counted as misses, a faster sensor's
        scans of another part of the area filled the window and kept the tracks of slower sensors tentative for good."""
        support = self._fused_support(slots)
        n_support = np.count_nonzero(support, axis=1)
        maybe = (n_support >= 1) & ~support[:, col]
        hidden = self._maybe_hidden(slots, maybe, report)
        maybe &= ~hidden
        one = maybe & (n_support == 1)
        if one.any():
            maybe[one] = self._own_confirmed(slots[one])
        if not maybe.any():
            return hidden
        X, P = self._states_at(slots[maybe], report.t)
        inside, below = self._view(X, P, report)
        out = ~inside
        out[out] = ~self._reach(X[out], P[out], report)
        shows = self._clutter_would_show(X[:, [0, 2]], report)
        maybe[maybe] = out & ((n_support[maybe] >= 2) | below | shows)
        return maybe | hidden

    def _maybe_hidden(self, slots: np.ndarray, others: np.ndarray, report: LocalReport) -> np.ndarray:
        """Per slot of ``slots``, whether it is one of ``others`` (other sensors' tracks) and the report's radar,
        with a site, may not see its place: not :func:`surely_above` its horizon (the place lowered by
        ``Z_FALSE_CONFIRM`` standard deviations of its height; a track of unknown height, a position sensor's
        alone, is lowered below any horizon). Its miss there may be its horizon's, no evidence against the track,
        as it is none against a confirmed track (:meth:`_in_view`) nor a question (:meth:`_surely_seen`). Before
        confirm62 such misses counted for a tentative track (the place raised, :meth:`_below_horizon`) and an
        aircraft below both radars' horizon that the position sensor s3 alone saw waited for the count 12
        pictures, where s3's own tracker took 4 (traffic sample ``featured/kiwi``)."""
        hidden = np.zeros(slots.size, dtype=bool)
        site = self.sites.get(report.sensor)
        if site is None or report.obs_R.shape[1:] == (2, 2) or not others.any():
            return hidden
        X, P = self._states_at(slots[others], report.t)
        hidden[others] = ~surely_above(site, X, P)
        return hidden

    def _view(self, X: np.ndarray, P: np.ndarray, report: LocalReport) -> tuple[np.ndarray, np.ndarray]:
        """Per central state of ``X`` (covariances ``P``) at the report's time: whether it lies inside the x-y
        extent of the report's local tracks (two or more) and above a sited radar's horizon; whether it is
        below that horizon."""
        below = self._below_horizon(X, P, report)
        if report.x.shape[0] < 2:
            return np.zeros(X.shape[0], dtype=bool), below
        at, local = X[:, [0, 2]], report.x[:, [0, 2]]
        return ((at > local.min(axis=0)) & (at < local.max(axis=0))).all(axis=1) & ~below, below

    def _reach(self, X: np.ndarray, P: np.ndarray, report: LocalReport) -> np.ndarray:
        """Per central state of ``X`` (covariances ``P``), whether it is within the association test's reach
        (in x-y) of one of the report's local tracks (:meth:`_reach_pairs`)."""
        reach = np.zeros(X.shape[0], dtype=bool)
        reach[self._reach_pairs(X, P, report)[0]] = True
        return reach

    def _reach_pairs(self, X: np.ndarray, P: np.ndarray, report: LocalReport) -> tuple[np.ndarray, np.ndarray]:
        """The pairs ``(i, j)`` of a central state ``X[i]`` (covariance ``P[i]``) and a report's local track ``j``
        within the association test's reach of each other in x-y: the test made on the pairs close enough that it
        can pass (:func:`~.candidates.candidate_pairs`: a direct distance bound, a k-d tree beyond), not on every
        state and local track."""
        xy = [0, 2]
        if not report.x.shape[0] or not X.shape[0]:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        gate, local = self.cfg.thresholds.association[2], report.x[:, xy]
        m, n = candidate_pairs(X[:, xy], np.sqrt(P[:, 0, 0] + P[:, 2, 2]), local,
                               np.sqrt(report.P[:, 0, 0] + report.P[:, 2, 2]), gate)
        d = X[m][:, xy] - local[n]
        S = P[m][:, xy][:, :, xy] + report.P[n][:, xy][:, :, xy]
        ok = np.einsum("ki,ki->k", d, np.linalg.solve(S, d[..., None])[..., 0]) <= gate
        return m[ok], n[ok]

    def _in_view(self, slots: np.ndarray, report: LocalReport) -> np.ndarray:
        """Per confirmed track of ``slots`` that the report's sensor does not track, whether the report shows
        that the sensor sees where it is (:meth:`_view`): inside the extent of its local tracks, surely above a sited
        radar's horizon (:func:`surely_above`: a miss there may be the horizon's; before 2026-11-28, kiruna57, the
        track raised above it as for a tentative one, and a far radar's misses deleted a position sensor's track of
        unknown height again and again: ``calibration/kiruna``, 23 id switches in 30 min), and beyond the reach of
        each of them that may hold its detections: a local track mapped to another central track that shares a
        sensor with it does not (:meth:`_apart`)."""
        X, P = self._states_at(slots, report.t)
        inside, _ = self._view(X, P, report)
        inside &= surely_above(self.sites.get(report.sensor), X, P)
        rows = inside.nonzero()[0]
        m, n = self._reach_pairs(X[rows], P[rows], report)
        m = m[~self._apart(slots[rows[m]], report.ids[n], report.sensor)]
        inside[rows[m]] = False
        return inside

    def _apart(self, slots: np.ndarray, lids: np.ndarray, sensor: str) -> np.ndarray:
        """Per pair of a central track's slot of ``slots`` and a local track of ``sensor`` (its id in ``lids``), whether
        the local track is mapped to another central track that shares a sensor with the slot's: that sensor's two
        local tracks, one on each, are two targets (a tracker keeps one track of a target), so the local track holds
        the other target's detections, not the slot's. A sensor that sees the slot's place and holds no other local
        track within reach of it missed its target: three coarse sensors' second tracks of a target, mapped
        together, kept a duplicate of the target's track for 40 s that the nine finer sensors never detected, their
        misses not counted beside their local tracks of the target (``mtt-decentralized`` jipda, untuned53's twelve
        sensors, seed 2: ``tests/test_mtt_centre_life.py``)."""
        slot_of, mapping = self.tracks.slot, self.mapping
        other = np.array([slot_of.get(mapping.get((sensor, lid)), -1) for lid in lids.tolist()], dtype=np.int64)
        apart = (other >= 0) & (other != slots)
        if apart.any():
            apart[apart] = (self._fused_support(slots[apart]) & self._fused_support(other[apart])).any(axis=1)
        return apart

    def _evidence(self, slots: np.ndarray, hit: np.ndarray, col: int, report: LocalReport) -> np.ndarray:
        """Per slot of ``slots``, the scan (``report``, sensor column ``col``) as evidence on its central track, the
        log-likelihood ratio of a track on a target against one on clutter: ``ln(P_D / p)`` where it detects the
        track (``hit``) and ``ln((1 - P_D) / (1 - p))`` where not, ``p = 1 - exp(-lambda pi g sqrt(det S))`` the
        chance that the sensor's clutter falls into the track's gate (``g`` at ``gate_probability``), ``S = R + H P
        H'`` its noise and the track's position covariance before the scan (:meth:`_priors`), as ``mtt-centralized``'s
        hit evidence takes its gate's ``S`` (``roles.life.hit_evidence``); a sensor whose clutter is in the gate as
        often as a target (``p >= P_D``) says nothing either way (0, 0); a sensor without clutter, or a radar (no
        such formula for its density per m rad^2): a hit is decisive (``inf``), a miss ``ln(1 - P_D)``. Before
        central61 ``S`` was ``R``, a track known far better than the noise: a 1 m sensor's clutter track that
        joined a track of a 300 m sensor alone weighed +12.2 (a chance of 4e-6) and confirmed it at once beside
        the target's own track; its clutter falls into that gate with 0.39, +0.85 now
        (``tests/test_mtt_centre_life.py``)."""
        R = self._gate_noise(col)
        if R is None or not slots.size:
            return np.where(hit, np.inf, self.column_log_miss[col])
        return np.where(hit, *self._gate_ratios(col, R + self._priors(slots, hit, report)))

    def _start_hit(self, col: int) -> float:
        """The evidence of a scan (sensor column ``col``) on a central track it starts: :meth:`_evidence`'s hit on a
        gate of ``S = R`` (the detection is its own gate's centre, :meth:`_priors`); ``inf`` without clutter or
        ``R`` (a radar)."""
        R = self._gate_noise(col)
        return math.inf if R is None else float(self._gate_ratios(col, R[None])[0][0])

    def _gate_noise(self, col: int) -> np.ndarray | None:
        """Sensor column ``col``'s noise ``R`` where its clutter weighs a scan as evidence in a gate (a position
        sensor with clutter); None otherwise (no clutter, or a radar: no ``R`` kept)."""
        R = self.column_R[col]
        return None if self.cfg.clutter_of(self.sensor_names[col]) <= 0.0 or np.isnan(R).any() else R

    def _gate_ratios(self, col: int, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:func:`log_ratios` of sensor column ``col``'s scans on gates of covariances ``S``."""
        sensor = self.sensor_names[col]
        return log_ratios(self.cfg.pd_of(sensor), self.cfg.clutter_of(sensor), self.cfg.thresholds.gate[2], S)

    def _priors(self, slots: np.ndarray, hit: np.ndarray, report: LocalReport) -> np.ndarray:
        """Per slot of ``slots``, its central track's x-y covariance before the report's observations were fused:
        where the report detects it (``hit``), the report's own prediction to its time (``report_states``), zero
        for a track the report started (its detection is its own gate's centre); where not, the track's newest
        estimate's (the life rules predict nothing of their own, perf60, and a report without detections, which
        makes no prediction, leaves what the full path leaves)."""
        xy = [0, 2]
        out = self.tracks.latest(slots)[2][:, xy][:, :, xy]
        known = self.report_states
        if known is not None and known[0] == report.t and hit.any():
            (_, P0, at), touched = known[1], known[2]
            row = np.where(hit, at[slots], -1)
            ahead = row >= 0
            out[ahead] = P0[row[ahead]][:, xy][:, :, xy]
            out[hit & ~ahead & np.isin(slots, touched)] = 0.0
        return out

    def _below_horizon(self, X: np.ndarray, P: np.ndarray, report: LocalReport) -> np.ndarray:
        """Per central state of ``X`` (covariances ``P``, 3-D), whether the report's radar cannot see it: the
        radar has a site (``sites``, ``[frame.sites]``) and the state's place raised by ``Z_FALSE_CONFIRM``
        standard deviations of its height is below the radar's radio horizon (:func:`above_radio_horizon`: the
        4/3 Earth, the simulators' own rule of sight). No radar detects below its horizon, so its report is no
        evidence there; the chance that a target of that estimate stands above it after all (its height
        Gaussian) is at most ``FALSE_CONFIRM``, jipda's bound on confirming clutter. A track of unknown height
        (a position sensor's, ``init_z_std``) is raised above any horizon; the horizontal error is left out
        (at 200 km the horizon's height changes by 2.5 cm a metre)."""
        site = self.sites.get(report.sensor)
        if site is None or X.shape[1] != 6 or report.obs_R.shape[1:] == (2, 2):
            return np.zeros(X.shape[0], dtype=bool)
        up = X[:, 0::2] + np.outer(Z_FALSE_CONFIRM * np.sqrt(P[:, 4, 4]), [0.0, 0.0, 1.0])
        return ~above_radio_horizon(site, up)

    def _surely_seen(self, slots: np.ndarray, asking: np.ndarray, t: float) -> np.ndarray:
        """Per slot of ``slots`` at ``t``, whether one of the sensors asking about it (``asking``: slots x sensor
        columns, a fresh array) surely sees its place: a sensor without a site in ``sites`` does (as far as the
        centre knows), a radar with one where the place lowered by ``Z_FALSE_CONFIRM`` standard deviations of its
        height is above the radar's radio horizon (the mirror of :meth:`_below_horizon`: below it with a chance
        of at most ``FALSE_CONFIRM``). A track of unknown height (a position sensor's alone, ``init_z_std``) is
        lowered below any horizon: a radar's miss there may be its horizon's (aircraft on the ground at Orly and
        Le Bourget, which the recorded Paris traffic's s3 alone sees)."""
        asking = self._counted(asking)
        sited = [(c, self.sites[name]) for c, name in enumerate(self.sensor_names) if name in self.sites]
        if sited:
            X, P = self._states_at(slots, t)
            for c, site in sited:
                asking[:, c] &= surely_above(site, X, P)
        return asking.any(axis=1)

    def _own_confirmed(self, slots: np.ndarray) -> np.ndarray:
        """Per slot of ``slots``, whether a local track that its tracker confirmed (at its latest report) maps
        to it (looked up from the slot's local tracks: each sensor's confirmed ones are a set)."""
        confirmed = self.own_confirmed
        return np.array([any(lid in confirmed.get(s, ()) for s, lid in self.members.get(cid, ()))
                         for cid in self.tracks.ids[slots].tolist()], dtype=bool)

    def _clutter_would_show(self, at: np.ndarray, report: LocalReport) -> np.ndarray:
        """Per x-y place of ``at``, whether the report's sensor, had it seen there, would have put a clutter
        detection, which starts a local track, nearer to it than the nearest of the report's local tracks
        but for a chance of ``FALSE_CONFIRM`` (jipda's bound on confirming clutter, which the count's note
        also holds the count to): ``exp(-lambda pi d^2) <= FALSE_CONFIRM``, ``lambda`` the sensor's clutter
        density per m^2 (one scan's clutter), ``d`` that distance. False where that shows nothing: a sensor
        without clutter, a report without local tracks, a radar's (its density is per m rad^2; the same
        count in its own space shows nothing below its horizon, which bounds its clutter: docs/multitarget.md,
        "A radar blind below its horizon")."""
        lam, local = self.cfg.clutter_of(report.sensor), report.x[:, [0, 2]]
        if lam <= 0.0 or not local.shape[0] or report.obs_R.shape[1:] != (2, 2):
            return np.zeros(at.shape[0], dtype=bool)
        d2 = ((at[:, None, :] - local[None, :, :]) ** 2).sum(axis=2).min(axis=1)
        return -lam * math.pi * d2 <= math.log(FALSE_CONFIRM)

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

    def prune(self, now: float) -> None:
        """Delete central tracks no local track maps to, or unsupported for longer than :meth:`_support_bound`."""
        self._delete_where(now - self.last_support > self._support_bound())
        self.departed.expire(now)

    def _support_bound(self) -> np.ndarray | float:
        """Per slot, how long its central track may go without a fused observation: ``central_timeout``, or,
        where longer, the silence bound of its fastest tracking sensor (``LEAVE_INTERVALS`` of the sensor's
        usual interval, :mod:`~fedtrack.fusion_center.mtt.silence`) up to ``max_lag``
        (:meth:`~fedtrack.local_filters.mtt.config.MttConfig.unsupported_s`): while a sensor tracking it may
        still be live, its scans and misses judge the track (the misses rule, its tracker's own deletion), not
        the clock. The fixed 5 s deleted a track of a sensor scanning every 8 s at the sensor's first miss,
        where its tracker keeps it, so that one sensor's centre was not its tracker (untuned58 session).
        Federated with more than one live sensor the clock stays: a held central track resets its sensors'
        local tracks to its prediction with ``beta`` = the live sensors' count inflating their covariance and
        process noise, so that a slow sensor's track held unsupported gates far clutter and runs away (tour48's
        federated gate; three sensors at 7-13 s: mean GOSPA +4 to +19 %)."""
        if (self.feedback and self.n_live > 1) or self.cfg.unsupported_s <= self.cfg.central_timeout:
            return self.cfg.central_timeout  # (the defaults: max_lag within central_timeout)
        usual = self.usual
        reach = LEAVE_INTERVALS * np.array([usual.get(s, 0.0) for s in self.sensor_names])
        fastest = np.where(self.support > 0, reach, np.inf).min(axis=1, initial=np.inf)
        return np.clip(np.where(np.isfinite(fastest), fastest, 0.0), self.cfg.central_timeout,
                       self.cfg.unsupported_s)

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
