"""Role 5 of a local tracker's scan, track starts (:func:`initiate`): every detection that no track
took starts a tentative track at its position with zero velocity (a one-point start,
:func:`start_tracks`), and where it pairs with an earlier one-point start, a two-point start too.

Two-point track initiation: a fast target's second detection, which falls outside the gate of
the zero-velocity track its first detection started, starts a track with the velocity of the
difference (two-point differencing: Bar-Shalom, Li & Kirubarajan 2001, 'Estimation with
Applications to Tracking and Navigation', sec. 5.5.3;
docs/multitarget.md#fast-targets-two-point-starts-fastinit-session).

A tracker keeps its one-point starts that still wait for a second detection (:class:`Starts`: each
one's track id, time and Cartesian position with its covariance). At a scan, a detection that no
track took (the tracker's own roles ran first, so a slow target's second detection went to its
one-point track as before) pairs (:func:`pair_starts`) with a waiting start of an earlier scan when

* the start's track is alive and its velocity still unmeasured (:func:`unmeasured`): its one
  detection, or more that told too little of the velocity, as a fast target's next detection does
  when it falls inside the zero-velocity start's gate (a radar's plot 100 m across at 100 km, half
  a second later) and the track takes it with the prior's velocity,
* the difference ``d`` of the two positions is outside the gate of the start's zero-velocity
  prediction (``init_velocity_std``): beyond what the one-point start covers, and
* ``d`` is within the gate of the ball ``|v| dt <= max_speed dt`` (the speed bound, ``[mtt]
  max_speed``): its excess over ``max_speed dt`` along ``d`` passes the chi-square gate under
  both detections' covariances and the process noise, and
* the pair measures the velocity within the bound: the variance of ``d`` (summed over the axes)
  is at most ``(max_speed dt)^2`` (scans microseconds apart pair no detections: their velocity
  would be the noise over ``dt``);

each detection and each start pairs at most once (an assignment preferring the lowest implied
speed), and only where the pair's likelihood ratio against clutter passes the associator's own
rule (:func:`least_log_lr`). The pair's track (:func:`two_point_state`) is the posterior of the
state at the second detection given both detections with a flat prior on the velocity (for
position sensors the velocity ``(z_2 - z_1) / dt`` with the covariance that follows from both
``R`` and ``Q``); the tracker starts it beside the one-point track of its second detection
(:func:`initiate`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from fedtrack.geodetic import Frame, level_z
from fedtrack.local_filters.linear.gating import ball_query
from fedtrack.local_filters.linear.kalman import solve_spd, symmetrize
from fedtrack.local_filters.mtt import detector, maneuver
from fedtrack.local_filters.mtt.associators.gnn import assign
from fedtrack.local_filters.mtt.models import motion, position_from_detection, position_matrix, start_modes
from fedtrack.local_filters.mtt.roles.life import keeps_evidence
from fedtrack.local_filters.mtt.roles.tracks import Observation, TrackParams, TrackSet, concat
from fedtrack.local_filters.mtt.scan import SensorScan


class Starts(NamedTuple):
    """One-point starts waiting for a second detection: each one's track id, its scan's time, its
    detection's Cartesian position (n, 3; ``z`` 0 where ``k`` is 2) with its covariance (n, 3, 3)
    and the position's size ``k`` (2: a 2-D position sensor's, 3: a radar's)."""

    ids: np.ndarray
    t: np.ndarray
    pos: np.ndarray
    cov: np.ndarray
    k: np.ndarray

    def take(self, idx: np.ndarray) -> Starts:
        """The starts at ``idx`` (indices or a bool mask)."""
        return Starts(*(a[idx] for a in self))


NO_STARTS = Starts(np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros(0, np.int64))


def padded(pos: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions (n, k) and covariances (n, k, k) as (n, 3) and (n, 3, 3) (zeros beyond ``k``)."""
    n, k = pos.shape
    p, c = np.zeros((n, 3)), np.zeros((n, 3, 3))
    p[:, :k], c[:, :k, :k] = pos, cov
    return p, c


def recorded(starts: Starts, waiting: np.ndarray, ids: np.ndarray, t: float, pos: np.ndarray, cov: np.ndarray
             ) -> Starts:
    """``starts`` where ``waiting`` (bool over them) with the new one-point starts ``ids`` at ``t``
    (positions ``pos`` (n, k), covariances ``cov``) added."""
    p, c = padded(pos, cov)
    new = Starts(ids.astype(np.int64), np.full(ids.size, t), p, c, np.full(ids.size, pos.shape[1], np.int64))
    kept = starts.take(np.flatnonzero(waiting))
    return Starts(*(np.concatenate([a, b]) for a, b in zip(kept, new)))


class PairParams(NamedTuple):
    """What the pairing needs of the tracker's parameters."""

    dim: int  # the state size D (4 or 6)
    q: float
    noise_model: str
    max_speed: float  # [m/s] the speed bound; 0: no two-point starts
    init_velocity_std: float  # the one-point start's velocity prior (what it already covers)
    init_z_std: float
    gate: dict[int, float]  # chi-square gate by measurement size
    pd: float
    clutter_density: float  # of the scan's sensor, per unit of its measurement space
    min_log_lr: float = 0.0  # a pair's log-likelihood ratio must exceed this (:func:`least_log_lr`)
    frame: Frame | None = None  # [frame]: an altitude unobserved is centred on the Earth (:func:`level_z`)


def least_log_lr(pd: float, by_existence: bool) -> float:
    """The least log-likelihood ratio ``ln(1 - P_D + P_D / (lambda V))`` of a pair that starts a track,
    each associator's own rule for a detection: where the tracks keep an existence (jipda) or a
    score (mht's ``"score"``), 0: the pair raises its start's odds (so its track never starts below
    its start's); where they count (gnn, mht's ``"counts"``), gnn's assignment rule, ``P_D p / (lambda
    (1 - P_D)) > 1`` with the pair's density ``p = 1 / V``: ``ln(2 (1 - P_D))``."""
    return 0.0 if by_existence or pd >= 1.0 else math.log(2.0 * (1.0 - pd))


class Pairing(NamedTuple):
    """The pairs of one scan: the detection (index into the given positions) and the start (index
    into :class:`Starts`) of each, the two-point state at the scan, and the pair's log-likelihood
    ratio ``ln(1 - P_D + P_D / (lambda V))`` against clutter (``V`` the volume that the speed bound
    allows the second detection; ``lambda`` the clutter density there)."""

    det: np.ndarray
    start: np.ndarray
    x: np.ndarray
    P: np.ndarray
    log_lr: np.ndarray


def no_pairing(dim: int) -> Pairing:
    """A scan's pairs when there are none (states of size ``dim``)."""
    none = np.zeros(0, np.int64)
    return Pairing(none, none, np.zeros((0, dim)), np.zeros((0, dim, dim)), np.zeros(0))


def cv_back(dim: int, dt: np.ndarray, q: float, noise_model: str) -> tuple[np.ndarray, np.ndarray]:
    """``F(dt)^-1 = F(-dt)`` and ``Q(dt)`` (n, D, D) of the CV model (:func:`~.models.motion`) for
    each ``dt`` (n,) (a scan's few intervals: cached)."""
    back = [motion(dim, -step, q, noise_model).F for step in dt.tolist()]
    Q = [motion(dim, step, q, noise_model).Q for step in dt.tolist()]
    return np.array(back).reshape(-1, dim, dim), np.array(Q).reshape(-1, dim, dim)


def two_point_state(first: Starts, pos: np.ndarray, cov: np.ndarray, k: int, dt: np.ndarray, p: PairParams
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The state at the second detections (``pos`` (n, 3), ``cov`` (n, 3, 3), position size ``k``)
    given the first (``first``, each ``dt`` (n,) earlier), with a flat prior on the position and the
    velocity they observe: in information form, the second detection as ``H x`` and the first as
    ``H F^-1 x`` with covariance ``R_1 + H F^-1 Q F^-T H'`` (the first's position given the state at
    the second under the CV model: exact). A 3-D state's altitude observed by neither detection keeps
    the one-point start's prior (``z`` the origin's height at the second detection, :func:`level_z`, with
    ``init_z_std``), and its vertical velocity observed by fewer than two the one-point start's
    ``init_velocity_std``. Returns ``x`` (n, D) and ``P``."""
    n, d = dt.size, p.dim
    back, Q = cv_back(d, dt, p.q, p.noise_model)
    Y, y = np.zeros((n, d, d)), np.zeros((n, d))
    for size, rows, R0, z in ((k, np.arange(n), cov, pos), *((int(j), np.flatnonzero(first.k == j), first.cov,
                                                              first.pos) for j in np.unique(first.k))):
        H = np.broadcast_to(position_matrix(d, size), (rows.size, size, d))
        R = R0[rows, :size, :size]
        if z is first.pos:  # the first detection, seen from the second's time
            H = H @ back[rows]
            R = symmetrize(R + H @ Q[rows] @ np.swapaxes(H, -1, -2))
        Ht = np.swapaxes(H, -1, -2)
        Y[rows] += Ht @ solve_spd(R, H)
        y[rows] += (Ht @ solve_spd(R, z[rows, :size, None]))[..., 0]
    if d == 6:
        seen = (first.k == 3).astype(int) + (k == 3)
        Y[seen == 0, 4, 4] += 1.0 / p.init_z_std**2
        y[seen == 0, 4] += level_z(p.frame, pos[seen == 0, :2]) / p.init_z_std**2
        Y[seen < 2, 5, 5] += 1.0 / p.init_velocity_std**2
    P = symmetrize(np.linalg.solve(Y, np.broadcast_to(np.eye(d), Y.shape)))
    return (P @ y[..., None])[..., 0], P


def unmeasured(tracks: TrackSet, init_velocity_std: float) -> np.ndarray:
    """The tracks whose horizontal velocity is still more the one-point start's prior than measured:
    a variance of either axis above half the prior's ``init_velocity_std^2`` (their detections gave
    less information on it than the prior had; a one-point start's track with its one detection has
    the prior's)."""
    return np.maximum(tracks.P[:, 1, 1], tracks.P[:, 3, 3]) > 0.5 * init_velocity_std**2


def _ball(k: int, r: np.ndarray) -> np.ndarray:
    """The volume of a ``k``-ball (2: a disc) of radii ``r``."""
    return math.pi * r**2 if k == 2 else 4.0 / 3.0 * math.pi * r**3


def pair_starts(starts: Starts, waiting: np.ndarray, t: float, pos: np.ndarray, cov: np.ndarray,
                density_scale: np.ndarray, p: PairParams) -> Pairing:
    """The two-point pairs of a scan at ``t`` (module docstring): the detections no track took, at
    Cartesian positions ``pos`` (M, k) with covariances ``cov``, against the ``waiting`` starts (bool
    over ``starts``). ``density_scale`` (M,): each detection's clutter density per m^k over the
    sensor's per unit of its measurement space (1 for a position sensor; a radar's ``1 / |det J|``)."""
    cand = np.flatnonzero(waiting & (starts.t < t))
    m, k = pos.shape
    if p.max_speed <= 0.0 or not cand.size or not m:
        return no_pairing(p.dim)
    posp, covp = padded(pos, cov)
    dt = t - starts.t[cand]
    three = np.minimum(starts.k[cand], k) == 3  # both observe the altitude
    gate = np.where(three, p.gate[3], p.gate[2])
    q_pos = cv_back(2, dt, p.q, p.noise_model)[1][:, 0, 0]  # the process noise of a position coordinate
    spread = np.trace(starts.cov[cand], axis1=-2, axis2=-1) + np.trace(cov, axis1=-2, axis2=-1).max() + 3 * q_pos
    reach = p.max_speed * dt
    # a crowd of starts and detections is refused before its pairs are made (CrowdedScan)
    near = ball_query(cKDTree(pos[:, :2]), starts.pos[cand, :2], reach + np.sqrt(gate * spread),
                      "two-point starts and detections within max_speed")
    counts = np.fromiter(map(len, near), dtype=np.int64, count=cand.size)
    if not counts.sum():
        return no_pairing(p.dim)
    ri = np.repeat(np.arange(cand.size), counts)
    cj = np.concatenate([np.asarray(a, np.int64) for a in near])
    flat = ~three[ri]  # 2-D pairs: the altitude left out (its row and column the identity's)
    diff = posp[cj] - starts.pos[cand[ri]]
    diff[flat, 2] = 0.0
    S = covp[cj] + starts.cov[cand[ri]] + q_pos[ri, None, None] * np.eye(3)
    S[flat, 2, :] = S[flat, :, 2] = 0.0
    S[flat, 2, 2] = 1.0
    dist = np.linalg.norm(diff, axis=1)
    excess = diff * np.maximum(0.0, 1.0 - reach[ri] / np.maximum(dist, 1e-300))[:, None]
    d2_fast = np.einsum("ni,ni->n", excess, solve_spd(S, excess[..., None])[..., 0])
    widen = (p.init_velocity_std * dt[ri]) ** 2
    slow = S + widen[:, None, None] * np.eye(3)
    slow[flat, 2, 2] = 1.0
    d2_slow = np.einsum("ni,ni->n", diff, solve_spd(slow, diff[..., None])[..., 0])
    r = reach[ri]
    if k == 2:
        volume = _ball(2, r)
    else:  # a radar's plot: the ball, or beside a 2-D start the disc times the altitude's spread
        z_spread = np.sqrt(2 * math.pi * (p.init_z_std**2 + covp[cj, 2, 2]))
        volume = np.where(three[ri], _ball(3, r), _ball(2, r) * z_spread)
    log_lr = np.log(1.0 - p.pd + p.pd / (max(p.clutter_density, 1e-300) * density_scale[cj] * volume))
    # the pair must measure the velocity to within the bound: the noise of the difference (its
    # variance summed over the axes) at most (max_speed dt)^2, else the pair's state is the noise
    # over dt (scans 1 ps apart: velocity variances of 1e26 and covariances not positive definite)
    measured = np.trace(S, axis1=-2, axis2=-1) - flat <= r**2
    ok = (d2_fast <= gate[ri]) & (d2_slow > gate[ri]) & (log_lr > p.min_log_lr) & measured
    ri, cj, dist, log_lr = ri[ok], cj[ok], dist[ok], log_lr[ok]
    if not ri.size:
        return no_pairing(p.dim)
    speed = dist / dt[ri]
    # each start and each detection at most once, the lowest implied speed first (every cost negative)
    picked = assign(cand.size, m, ri, cj, speed / max(float(speed.max()), 1.0) - 2.0)
    ri, cj = ri[picked], cj[picked]
    x, P = two_point_state(starts.take(cand[ri]), posp[cj], covp[cj], k, dt[ri], p)
    return Pairing(cj, cand[ri], x, P, log_lr[picked])


def start_tracks(scan: SensorScan, det: np.ndarray, params: TrackParams, first_id: int,
                 two: tuple[Pairing, TrackSet] | None = None) -> tuple[TrackSet, Observation]:
    """Tentative tracks from the detections ``det`` of ``scan`` (one-point initialization); with
    ``two`` (pairs of these detections, :func:`pair_starts`, with their starts' tracks),
    the pairs' two-point states and, in a tracker of several sensors' scans, their starts' sensors
    too."""
    d = params.dim
    pos, Ppos = position_from_detection(scan.z[det], scan.R, scan.sensor_position)
    k = pos.shape[1]
    n = pos.shape[0]
    pidx = [0, 2, 4][:k]
    x = np.zeros((n, d))
    x[:, pidx] = pos
    P = np.zeros((n, d, d))
    P[np.ix_(np.arange(n), pidx, pidx)] = Ppos
    for v in (1, 3, 5)[: d // 2]:
        P[:, v, v] = params.init_velocity_std**2
    if d == 6 and k == 2:  # the altitude unknown: the origin's height there, +-init_z_std (docs/geodetic.md)
        x[:, 4] = level_z(params.frame, pos)
        P[:, 4, 4] = params.init_z_std**2
    obs = Observation(np.broadcast_to(position_matrix(d, k), (n, k, d)).copy(), Ppos, pos)
    one = np.ones(n, np.int64)
    by = np.full(n, params.sensor_bit, np.int64) if params.sensor_bit else None
    if two is not None:
        x, P = two[0].x.copy(), two[0].P.copy()
        if by is not None and two[1].detected_by is not None:
            by |= two[1].detected_by
    ids = first_id + np.arange(n, dtype=np.int64)
    man = None if params.maneuver is None else maneuver.start(x, P, scan.t, params.maneuver)
    inputs = None if params.detector is None else detector.start(n, d, scan.t, params.detector)
    existence = None if params.initial_existence is None else np.full(n, params.initial_existence)
    modes = None if params.modes is None else start_modes(x, P, params.modes)
    # confirmed at birth by the count (1 of 1) only where the count confirms: jipda's existence does
    born = (one >= params.confirm_hits) & (existence is None)
    evidence = np.zeros((n, 2)) if keeps_evidence(params) else None  # Wald's test starts (:func:`births_share`)
    return TrackSet(ids, x, P, one, one.copy(), np.zeros(n, np.int64), born, man, inputs, existence, modes, by,
                    evidence), obs


def births_share(new: TrackSet) -> TrackSet:
    """The scan's new tracks, where the tracker keeps their evidence (``roles.life.keeps_evidence``), with Wald's
    test started: no evidence yet, and the log of their number (``evidence[:, 1]``), by which the test's
    threshold rises for each (``roles.life.count_life``): the births share the scan's false confirmations."""
    if new.evidence is None or not new.size:
        return new
    return new._replace(evidence=np.column_stack([np.zeros(new.size), np.full(new.size, math.log(new.size))]))


class Initiated(NamedTuple):
    """Role 5's result: the new tracks (one per detection given, then one per pair) with their
    observations and each one's detection (index into the detections given), the one-point starts
    waiting after the scan, and the scan's pairs (:func:`pair_starts`) with their starts'
    rows in the tracks given to :func:`initiate` and whether each start's track still had only its
    start's detection (``alone``)."""

    tracks: TrackSet
    observations: Observation
    source: np.ndarray
    starts: Starts
    pairs: Pairing
    partners: np.ndarray
    alone: np.ndarray


def initiate(starts: Starts, tracks: TrackSet, live: np.ndarray, scan: SensorScan, det: np.ndarray,
             params: TrackParams, first_id: int) -> Initiated:
    """Role 5: tracks from the detections ``det`` no track took: a one-point start from each (as
    before two-point starts: a slow target's first detection starts its track whatever it pairs
    with) and a two-point start from each pair (:mod:`.initiation`; at most one per detection). A
    pair's track counts afresh, one hit at one scan old (its second detection says only that it
    lies within the speed bound's reach, as a clutter detection there does with probability
    ``lambda V``; counted as a second hit it let clutter pairs confirm on one more clutter hit: the
    false tracks of gnn's ``mtt-local`` on the default scenario doubled). ``tracks``, ``live``: the
    tracker's tracks (or mht's leaves) after the scan's update and life rules; a start waits while
    its track is live with its velocity unmeasured (:func:`unmeasured`), each at most until it pairs."""
    one, obs = start_tracks(scan, det, params, first_id)
    if params.max_speed <= 0.0:  # no two-point starts: nothing waits
        return Initiated(births_share(one), obs, np.arange(det.size), starts, no_pairing(params.dim),
                         np.zeros(0, np.int64), np.zeros(0, bool))
    lone = np.flatnonzero(live & unmeasured(tracks, params.init_velocity_std))
    order = np.argsort(tracks.ids[lone], kind="stable")
    at = np.minimum(np.searchsorted(tracks.ids[lone], starts.ids, sorter=order), max(lone.size - 1, 0))
    rows = lone[order[at]] if lone.size else np.zeros(starts.ids.size, np.int64)
    waiting = (tracks.ids[rows] == starts.ids) if lone.size else np.zeros(starts.ids.size, bool)
    pos, cov = position_from_detection(scan.z[det], scan.R, scan.sensor_position)
    scale = np.ones(det.size)
    if scan.sensor_position is not None:  # a radar's clutter per m^3: its density over |det J| = r^2 cos(el)
        scale = 1.0 / (scan.z[det, 0] ** 2 * np.abs(np.cos(scan.z[det, 2])))
    by_existence = params.initial_existence is not None or (params.mht is not None
                                                            and params.mht.management == "score")
    pairs = pair_starts(starts, waiting, scan.t, pos, cov, scale, PairParams(
        params.dim, params.q, params.noise_model, params.max_speed, params.init_velocity_std, params.init_z_std,
        params.gate, params.pd, params.clutter_density, least_log_lr(params.pd, by_existence), params.frame))
    partners = rows[pairs.start]
    alone = tracks.hits[partners] == 1
    waiting[pairs.start] = False
    kept = recorded(starts, waiting, one.ids, scan.t, pos, cov)
    if not pairs.det.size:
        return Initiated(births_share(one), obs, np.arange(det.size), kept, pairs, partners, alone)
    two, obs_two = start_tracks(scan, det[pairs.det], params, first_id + det.size, (pairs, tracks.take(partners)))
    return Initiated(births_share(concat(one, two)), Observation(*(np.concatenate(u) for u in zip(obs, obs_two))),
                     np.concatenate([np.arange(det.size), pairs.det]), kept, pairs, partners, alone)


def paired_evidence(new: TrackSet, init: Initiated, partner: np.ndarray | None) -> TrackSet:
    """New tracks (:func:`initiate`'s) with each pair's track's Wald evidence (``roles.life.tally``) as
    :func:`paired_log_odds` gives its odds: where its start's track still had only its start's detection
    (``alone``), the start's before the scan (``partner``, over the tracks given to :func:`initiate`: its births
    share too) plus the pair's log-likelihood ratio, the start's track updated by the second detection; else
    the scan's births share alone (:func:`births_share`). No evidence kept, no pair: as given."""
    if new.evidence is None or partner is None or not init.pairs.det.size:
        return new
    evidence = new.evidence.copy()
    rows = new.size - init.pairs.det.size + np.flatnonzero(init.alone)
    evidence[rows] = partner[init.partners[init.alone]]
    evidence[rows, 0] += init.pairs.log_lr[init.alone]
    return new._replace(evidence=evidence)


def paired_log_odds(log_odds: np.ndarray, init: Initiated, partner_log_odds: np.ndarray) -> np.ndarray:
    """New tracks' existence log odds (jipda's existence, mht's score): ``log_odds`` (the one-point
    starts'), then for each pair's track its start's before the scan (``partner_log_odds``, over the
    tracks given to :func:`initiate`) plus the pair's log-likelihood ratio
    ``ln(1 - P_D + P_D / (lambda V))``: the start's track updated, as jipda's and mht's own
    update of a track with one detection in its gate, by the second detection under the speed
    bound (its density ``1 / V``) instead of the zero-velocity start's gate. A start whose track
    took more detections since (its velocity still unmeasured: :func:`unmeasured`) gives instead
    the odds of a one-point start, the paired detection's own: its track's odds rose on detections
    the pair does not take (a slow target's, where a clutter detection pairs with its start)."""
    start = np.where(init.alone, partner_log_odds[init.partners], log_odds[init.pairs.det])
    return np.concatenate([log_odds, start + init.pairs.log_lr])
