"""Local multi-target tracker: one scan as a chain of roles over the batched track set.

The records the roles pass are :mod:`.roles.tracks`'s; this module holds the tracker's state, the
associators ``[mtt] associator`` names (:data:`ASSOCIATORS`) and the chain. :func:`tracker_step` runs,
each role a small pure function:

1. **predict** (:func:`~.roles.filtering.predict`) every track to the scan time (CV, :mod:`.models`; or
   each track in its own model with ``[mtt] maneuver = "vdie"``, :mod:`.maneuver`).
2. **gate** (:func:`~.roles.gating.gate_scan`): ``d2_ij = nu_ij' S_i^-1 nu_ij`` with
   ``S_i = H_i P_i H_i' + R`` against the chi-square quantile of ``gate_probability`` (m = 2 or 3
   degrees of freedom), and each gated pair's log-likelihood
   ``ln N(nu_ij; 0, S_i) = -(d2_ij + ln det(2 pi S_i)) / 2``; a radar linearized at the predictions,
   or, for a track whose altitude is unobserved, about a plot's altitude
   (:func:`~.roles.gating.relinearize_altitude`).
3. **associate** (:func:`associate`): the :class:`~.association.Associator` that ``[mtt] associator``
   names (:data:`ASSOCIATORS`; ``gnn``: :mod:`.associators.gnn`). The interface, and how a soft
   associator (``jipda``) or one with memory (``mht``) plugs in: :mod:`.association`.
4. **update** (:func:`~.roles.filtering.hard_update`, or the associator's): a track with one detection
   by the EKF (Joseph form; exact Kalman for position sensors).
5. **initiate** (:func:`~.initiation.initiate`): every detection the associator did not claim starts a
   tentative track: position from the detection and its covariance, zero velocity with
   ``init_velocity_std`` per axis (and, for a 2-D detection in a 3-D state, altitude 0 with
   ``init_z_std``); or, where it pairs with an earlier one-point start that it lies beyond but
   within ``max_speed`` of, the two-point start of :mod:`.initiation` (a fast target's). Ids are
   integers in order of creation, never reused.
6. **confirm / delete** (:func:`~.roles.life.m_of_n`, or the associator's): a track is confirmed once
   it has ``confirm_hits`` detections within its first ``confirm_window`` scans (both raised on a
   cluttered position sensor's scans, :func:`~.roles.life.count_at`; in ``mtt-centralized`` kept where a
   present sensor's clutter would raise it, each scan's evidence weighed instead: :func:`~.roles.life.count_life`,
   mht's ``"counts"`` too); a tentative track
   that can no longer reach that is deleted; a confirmed track is deleted after ``delete_misses``
   consecutive misses, or more on a fast sensor (:func:`~.roles.life.deletion_at`).

With ``associator = "mht"`` the roles run on the branches of its memory instead (:func:`mht_step`).

Each updated or started track carries its detection as a linearized observation
``(H, R, z - h(x0) + H x0)`` at the linearization point ``x0`` (the track's prediction;
for a start, the detection's Cartesian position with its covariance): what a fusion centre
needs to fuse the local tracks exactly (docs/multitarget.md).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.special import expit, logit

from fedtrack.local_filters.linear.kalman import GaussianState
from fedtrack.local_filters.mtt import initiation
from fedtrack.local_filters.mtt.association import Association, AssociationInput, Associator
from fedtrack.local_filters.mtt.associators import jipda, mht
from fedtrack.local_filters.mtt.associators.gnn import GNN
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.initiation import initiate, paired_evidence, paired_log_odds
from fedtrack.local_filters.mtt.roles.filtering import (
    detection_update,
    hard_update,
    jipda_update,
    modes_at_scan,
    predict_tracks,
)
from fedtrack.local_filters.mtt.roles.gating import Gating, gate_scan
from fedtrack.local_filters.mtt.roles.life import (
    Sight,
    count_at,
    count_life,
    deletion_at,
    existence_manage,
    held,
    m_of_n,
    scan_sees,
    tally,
)
from fedtrack.local_filters.mtt.roles.tracks import Observation, TrackParams, TrackSet, concat, empty_tracks
from fedtrack.local_filters.mtt.scan import SensorScan

# the associators ``[mtt] associator`` selects (config.ASSOCIATORS lists the names, with those
# still to come)
ASSOCIATORS: dict[str, Associator] = {GNN.name: GNN}
JIPDA = Associator("jipda", jipda.associate_scan, jipda_update, existence_manage)
ASSOCIATORS[JIPDA.name] = JIPDA


def track_params(cfg: MttConfig, sensor: str | None, dim: int, feedback: bool = False,
                 events: bool = False) -> TrackParams:
    """Parameters of the tracker of ``sensor`` (None: a tracker of every sensor's detections) for
    one scan of ``sensor``; ``events``: its tracks are the output (``mtt-local``,
    ``mtt-centralized``), not reports to a centre. ``[mtt] maneuver = "vdie"`` applies VDIE to
    2-D trackers without federated feedback (the centre's resets own a federated tracker's
    state, and its central tracks are CV), and the maneuver detector (:mod:`.detector`, with
    VDIE's parameters and window) to the tracks of a 3-D tracker whose tracks are the output (a
    track-to-track centre runs its own on the central tracks). A tracker of every sensor's scans
    (``mtt-centralized``) takes the fusion centre's policy on top
    (:func:`fedtrack.fusion_center.mtt.engines.central_params`). Two motion modes where ``[mtt]
    process_noise`` resolves to ``"imm"``, except on a sensor too coarse to see a maneuver
    (:meth:`MttConfig.modes_of`)."""
    vdie = detect = None
    if cfg.maneuver == "vdie":  # both over the window of the tracker's own scans
        vdie = cfg.vdie if dim == 4 and not feedback else None
        detect = cfg.vdie if dim == 6 and events else None
    return TrackParams(dim, cfg.q, cfg.noise_model, cfg.init_velocity_std, cfg.init_z_std,
                       cfg.pd if sensor is None else cfg.pd_of(sensor),
                       cfg.clutter_density if sensor is None else cfg.clutter_of(sensor),
                       cfg.thresholds.gate, cfg.confirm_hits, cfg.confirm_window, cfg.misses_to_delete(sensor), vdie, detect,
                       ASSOCIATORS[cfg.associator], jipda.BIRTH_EXISTENCE if cfg.associator == "jipda" else None,
                       mht=cfg.mht_settings if cfg.associator == "mht" else None,
                       modes=cfg.modes_of(sensor, dim) if vdie is None and not feedback else None,
                       max_speed=cfg.max_speed)


class TrackerState(NamedTuple):
    tracks: TrackSet
    t: float | None
    next_id: int
    memory: object = None  # the associator's memory (Association.memory)
    starts: initiation.Starts = initiation.NO_STARTS  # one-point starts waiting for a second detection


class ScanResult(NamedTuple):
    state: TrackerState
    detected: np.ndarray  # (N,) bool over state.tracks: updated or started by this scan
    observations: Observation  # for the detected tracks, in order
    retired: np.ndarray  # ids deleted by this scan


def initial_state(dim: int, next_id: int = 0) -> TrackerState:
    return TrackerState(empty_tracks(dim), None, next_id)


def associate(state: TrackerState, gating: Gating | None, scan: SensorScan, params: TrackParams,
              dt: float = 0.0, sees: Sight | None = None) -> Association:
    """Role 3: the associator's answer (nothing to associate without gated pairs, unless the
    associator keeps the existence of tracks, which a scan without pairs still lowers); ``sees``:
    :func:`scan_sees`."""
    n, n_det = state.tracks.size, scan.z.shape[0]
    if gating is None and (params.initial_existence is None or n == 0):
        return Association(np.zeros(0, np.int64), np.zeros(0), np.zeros(n_det, bool), state.tracks.existence,
                           state.memory)
    none = np.zeros(0, np.int64)
    rows, cols, log_l = (none, none, np.zeros(0)) if gating is None else (*gating.pairs[:2], gating.log_likelihood)
    by = state.tracks.detected_by
    return params.associator.associate(AssociationInput(
        n, n_det, rows, cols, log_l, scan.dim, state.tracks.confirmed, state.tracks.existence,
        params.pd, params.clutter_density, scan.amplitude, state.memory, params.gate[scan.dim], dt,
        None if by is None or sees is None else ~sees.counts(by, params.sensor_bit)))


def tracker_step(state: TrackerState, scan: SensorScan, params: TrackParams,
                 q_scale: float | np.ndarray = 1.0) -> ScanResult:
    """Process one scan (times must not decrease); ``q_scale`` scales ``Q`` (federated ``beta_i``)."""
    tracks = state.tracks
    if state.t is not None and scan.t < state.t:
        raise ValueError(f"scan at t = {scan.t} is before the tracker's time {state.t}")
    dt = 0.0 if state.t is None else scan.t - state.t
    params = count_at(deletion_at(params, dt), scan, dt)
    if params.associator.step is not None:
        return params.associator.step(state, scan, params, q_scale)
    if params.initial_existence is not None and tracks.existence is None:  # an empty set keeping existence
        tracks = tracks._replace(existence=np.zeros(tracks.size))
        state = state._replace(tracks=tracks)
    at_scan, pred = predict_tracks(tracks, dt, params, q_scale)
    gating = gate_scan(pred, scan, params, modes_at_scan(at_scan, params))
    sees = scan_sees(pred.x, gating, scan, params, held(tracks, params.sensor_bit))
    assoc = associate(state, gating, scan, params, dt, sees)
    role = params.associator
    if role.update is None:
        upd = hard_update(at_scan, pred, gating, assoc, scan, dt, params, q_scale)
    else:
        upd = role.update(at_scan, pred, gating, assoc, scan, dt, params, q_scale)
    updated, live = (m_of_n if role.manage is None else role.manage)(upd.tracks, upd.detected, params, sees)
    det = np.flatnonzero(~assoc.claimed)
    init = initiate(state.starts, updated, live, scan, det, params, state.next_id)
    new, obs_new = paired_evidence(init.tracks, init, tracks.evidence), init.observations
    if assoc.birth is not None or new.existence is not None:
        born = assoc.birth[det] if assoc.birth is not None else new.existence[:det.size]
        if init.pairs.det.size:  # a pair's track: its start's existence before the scan, predicted to it
            born = expit(paired_log_odds(logit(born), init, logit(jipda.predicted_existence(tracks.existence, dt))))
        new = new._replace(existence=born)
    detected = np.concatenate([upd.detected[live], np.ones(new.size, bool)])
    keep_info = live[upd.detected]
    return ScanResult(TrackerState(concat(updated.take(live), new), scan.t, state.next_id + new.size, assoc.memory,
                                   init.starts),
                      detected, Observation(*(np.concatenate([u[keep_info], v]) for u, v in zip(upd.observations,
                                                                                                 obs_new))),
                      tracks.ids[~live])


def mht_step(state: TrackerState, scan: SensorScan, params: TrackParams, q_scale: float | np.ndarray = 1.0
             ) -> ScanResult:
    """The scan with ``associator = "mht"`` (:mod:`.associators.mht`): the roles run on the branches its memory
    holds (every track's leaves) instead of the tracks, with two modes per leaf as
    :func:`hard_update` on a track (``process_noise = "imm"``); the tracks are the best global
    hypothesis's, by id. The given tracks' ``x``, ``P`` replace those of the best hypothesis's
    leaves first (a federated tracker's resets; otherwise they are those leaves')."""
    settings, d, m = params.mht, params.dim, scan.dim
    mem = state.memory if state.memory is not None else mht.initial_state(empty_tracks(d), settings.window)
    mp = mht.mht_params(settings, params.pd, params.clutter_density, params.gate[m], m, params.delete_misses)
    leaves, n_det = mem.leaves, scan.z.shape[0]
    best = np.flatnonzero(mem.hyps[0])
    best = best[np.argsort(leaves.ids[best], kind="stable")]
    if np.array_equal(leaves.ids[best], state.tracks.ids):  # the tracks as given (federated resets)
        x, P = leaves.x.copy(), leaves.P.copy()
        x[best], P[best] = state.tracks.x, state.tracks.P
        leaves = leaves._replace(x=x, P=P)
    dt = 0.0 if state.t is None else scan.t - state.t
    at_scan, (x, P) = predict_tracks(leaves, dt, params, q_scale)
    modes = modes_at_scan(at_scan, params)  # each leaf's modes (process_noise = "imm")
    gating = gate_scan(GaussianState(x, P), scan, params, modes)
    g_rows = g_cols = np.zeros(0, np.int64)
    nu, inc, miss = np.zeros((0, m)), np.zeros(0), mht.miss_increment(mp)
    if gating is not None:
        g_rows, g_cols, nu, _ = gating.pairs
        inc, miss = mht.score_increments(gating.log_likelihood, mp,
                                         None if scan.amplitude is None else scan.amplitude[g_cols])
    br = mht.extend_clusters(mem._replace(leaves=leaves), n_det, g_rows, g_cols, inc, miss, mp)
    hit = br.pair >= 0
    pidx = br.pair[hit]
    cx, cP = x[br.parent], P[br.parent]
    cmodes = None if modes is None else modes.take(br.parent)  # a miss keeps its parent's prediction
    obs = Observation(np.zeros((0, m, d)), np.zeros((0, m, m)), np.zeros((0, m)))
    if pidx.size:
        H, x0 = gating.lin.H[g_rows[pidx]], cx[hit]
        cx[hit], cP[hit] = detection_update(x0, cP[hit], cmodes, np.flatnonzero(hit), nu[pidx], H, scan.R)
        obs = Observation(H, np.broadcast_to(scan.R, (pidx.size, m, m)).copy(), nu[pidx] + np.einsum("nij,nj->ni", H, x0))
    sees = scan_sees(x, gating, scan, params, held(leaves, params.sensor_bit))
    old, counted, need = tally(leaves.take(br.parent), hit, params, None if sees is None else sees.take(br.parent))
    step = np.where(hit, 0.0, miss * counted)  # each branch's score increment (a miss the scan counts)
    step[hit] = inc[pidx]
    score = mem.score[br.parent] + step
    peak = np.maximum(mem.peak[br.parent], score)
    if mp.management == "counts":  # gnn's rule (roles.life.count_life): window 1, k 1 is gnn
        confirmed, live = count_life(old, params, need)
    else:
        confirmed, live = mht.manage(mp._replace(delete_misses=need), old.confirmed, score, peak, old.misses)
    children = TrackSet(old.ids, cx, cP, old.hits, old.age, old.misses, confirmed, modes=cmodes,
                        detected_by=old.detected_by, evidence=old.evidence)
    fresh = br.births  # a detection that a kept hypothesis of its cluster leaves unused starts a track there
    init = initiate(state.starts, children, live, scan, fresh, params, state.next_id)
    partner = None if leaves.evidence is None else leaves.evidence[br.parent]  # before the scan's tally
    new, obs_new = paired_evidence(init.tracks, init, partner), init.observations
    new_score = mht.birth_scores(mp, None if scan.amplitude is None else scan.amplitude[fresh], fresh.size)
    if init.pairs.det.size:  # a pair's track: its start's leaf's score before the scan and the pair's ratio
        new_score = paired_log_odds(new_score, init, mem.score[br.parent])
    if mp.management == "score":
        new = new._replace(confirmed=new_score >= mp.confirm_score)
    n_child = br.parent.size
    serial = mem.next_branch + np.arange(n_child + new.size)
    lineage = np.concatenate([mem.lineage[br.parent, 1:], serial[:n_child, None]], axis=1)
    grown = mht.MhtState(concat(children, new), np.concatenate([score, new_score]),
                         np.concatenate([peak, new_score]),
                         np.concatenate([lineage, np.repeat(serial[n_child:, None], settings.window, axis=1)]),
                         np.concatenate([br.holds, br.birth_holds[:, init.source]], axis=1), br.value,
                         int(mem.next_branch + serial.size),
                         np.concatenate([mht.leaf_existence(mem.existence[br.parent], step, dt),
                                         mht.birth_existence(new_score)]),
                         np.concatenate([br.cluster, br.birth_cluster[init.source]]))
    branch_det = np.full(n_child, -1)  # each branch's detection (-1: a miss), then the new tracks'
    branch_det[hit] = g_cols[pidx]
    branch_det = np.concatenate([branch_det, fresh[init.source]])  # a pair's track: its detection's too
    branch_obs = np.full(branch_det.size, -1)  # each branch's row of the observations
    branch_obs[branch_det >= 0] = np.arange(pidx.size + new.size)
    mem, kept = mht.prune(grown, np.concatenate([live, np.ones(new.size, bool)]), mp)
    best = np.flatnonzero(mem.hyps[0])
    best = best[np.argsort(mem.leaves.ids[best], kind="stable")]
    rows = branch_obs[kept[best]]
    all_obs = [np.concatenate([u, v]) for u, v in zip(obs, obs_new)]
    tracks = mem.leaves.take(best)
    tracks = tracks._replace(confirmed=mht.shown(mp.management, tracks.confirmed, mem.existence[best]))
    return ScanResult(TrackerState(tracks, scan.t, state.next_id + new.size, mem, init.starts), rows >= 0,
                      Observation(*(a[rows[rows >= 0]] for a in all_obs)),
                      np.setdiff1d(leaves.ids, mem.leaves.ids))


def mht_decided(then: TrackerState, later: TrackerState, back: int, management: str) -> TrackerState:
    """The MHT's deferred decision (docs/mht.md#the-picture-the-n-scan-back-decision): ``then``, the
    state after a scan, with its tracks replaced by those of the best hypothesis of ``later``, the
    state ``back`` scans on (``1 <= back < window``), each as its ancestor at ``then``'s scan was
    (the filtered ``x``, ``P`` and modes along the branch that hypothesis kept: the leaf of
    ``then`` whose serial is ``lineage[:, -1 - back]``), sorted by id. A track born after
    ``then``'s scan has no such ancestor and is left out. Status as decided: shown
    (:func:`mht.shown`) when ``later``'s leaf is confirmed and the ancestor's existence was at
    least 1/2 (confirmation is a decision the window defers too; the existence is the branch's
    at ``then``'s scan)."""
    past, now = then.memory, later.memory
    if past is None or now is None or not past.leaves.size:
        return then
    best = np.flatnonzero(now.hyps[0])
    ancestor = now.lineage[best, -1 - back]
    own = past.lineage[:, -1]
    order = np.argsort(own, kind="stable")
    at = order[np.minimum(np.searchsorted(own, ancestor, sorter=order), own.size - 1)]
    found = own[at] == ancestor
    rows, leaves = at[found], best[found]
    by_id = np.argsort(past.leaves.ids[rows], kind="stable")
    rows, leaves = rows[by_id], leaves[by_id]
    tracks = past.leaves.take(rows)
    confirmed = mht.shown(management, now.leaves.confirmed[leaves], past.existence[rows])
    return then._replace(tracks=tracks._replace(confirmed=confirmed))


def _whole_scan(*_: object) -> None:
    raise TypeError("mht takes the whole scan (Associator.step), not the tracker's chain")


MHT = Associator("mht", _whole_scan, step=mht_step)
ASSOCIATORS[MHT.name] = MHT
