"""Local multi-target tracker: chi-square gating, global nearest neighbour, M-of-N track logic.

One scan (:func:`tracker_step`), all maths batched over the track axis:

1. Predict every track to the scan time (CV, :mod:`fedtrack.local_filters.mtt.models`).
2. Gate: ``d2_ij = nu_ij' S_i^-1 nu_ij`` with ``S_i = H_i P_i H_i' + R`` against the
   chi-square quantile of ``gate_probability`` (m = 2 or 3 degrees of freedom).
3. Assign (global nearest neighbour): ``scipy.optimize.linear_sum_assignment`` on the
   gated pairs with cost ``d2_ij + ln det(2 pi S_i) + 2 ln(lambda (1 - P_D) / P_D)``
   (minus twice the log-likelihood ratio of "track i made detection j" against "detection
   j is clutter and track i was missed"); a pair whose cost is not negative is not assigned.
   The problem is split into the connected components of the gating graph first, so a
   scan with many well separated targets costs many tiny assignments.
4. Update assigned tracks (EKF for radars, Joseph form); unassigned detections start
   tentative tracks: position from the detection and its covariance, zero velocity with
   ``init_velocity_std`` per axis (and, for a 2-D detection in a 3-D state, altitude 0
   with ``init_z_std``).
5. Track logic: a track is confirmed once it has ``confirm_hits`` detections within its
   first ``confirm_window`` scans; a tentative track that can no longer reach that is
   deleted; a confirmed track is deleted after ``delete_misses`` consecutive misses.
   Ids are integers in order of creation, never reused.

Each updated or started track carries its detection as a linearized observation
``(H, R, z - h(x0) + H x0)`` at the linearization point ``x0`` (the track's prediction;
for a start, the detection's Cartesian position with its covariance): what a fusion centre
needs to fuse the local tracks exactly (docs/multitarget.md).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from functools import cache, lru_cache
from typing import NamedTuple

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from fedtrack.local_filters.linear.gating import gate_ball_pairs
from fedtrack.local_filters.linear.kalman import GaussianState, mat_vec, spd_inverse_logdet, update_residual
from fedtrack.local_filters.mtt import detector, maneuver
from fedtrack.local_filters.mtt.config import CENTRAL_MISSES, MttConfig
from fedtrack.local_filters.mtt.models import (
    Linearized,
    linearize,
    motion,
    position_from_detection,
    position_matrix,
    predict_tracks,
)
from fedtrack.local_filters.mtt.scan import SensorScan
from fedtrack.local_filters.radar.measurement import wrap_angle
from fedtrack.local_filters.vdie.estimation import VdieParams, VdieState

LOG_2PI = math.log(2.0 * math.pi)


class TrackParams(NamedTuple):
    """What one tracker needs per scan (built from ``[mtt]`` by :func:`track_params`)."""

    dim: int
    q: float
    noise_model: str
    init_velocity_std: float
    init_z_std: float
    pd: float
    clutter_density: float
    gate: dict[int, float]
    confirm_hits: int
    confirm_window: int
    delete_misses: int
    maneuver: VdieParams | None = None  # per-track VDIE (2-D position trackers), None: CV only
    detector: VdieParams | None = None  # per-track maneuver events (3-D trackers), None: none


def track_params(cfg: MttConfig, sensor: str | None, dim: int, feedback: bool = False,
                 every_sensor: bool = False, events: bool = False) -> TrackParams:
    """Parameters of the tracker of ``sensor`` (None: a tracker of every sensor's detections) for
    one scan of ``sensor``; ``every_sensor``: the tracker takes every sensor's scans; ``events``:
    its tracks are the output (``mtt-local``, ``mtt-centralized``), not reports to a centre.
    ``[mtt] maneuver = "vdie"`` applies VDIE to 2-D trackers without federated feedback (the
    centre's resets own a federated tracker's state, and its central tracks are CV), and the
    maneuver detector (:mod:`.detector`, with VDIE's parameters and window) to the tracks of a
    3-D tracker whose tracks are the output (a track-to-track centre runs its own on the
    central tracks)."""
    vdie = detect = None
    if cfg.maneuver == "vdie":  # both over the window of the tracker's own scans
        params = _every_sensor_window(cfg.vdie, cfg.listed_sensors) if every_sensor else cfg.vdie
        vdie = params if dim == 4 and not feedback else None
        detect = params if dim == 6 and events else None
    # a tracker of every sensor's scans counts misses over all of them: CENTRAL_MISSES per listed
    # sensor in a row, as the track-to-track centre's rule (3 in a row dropped a live target of
    # three sensors at P_D = 0.9 about once a minute among 60)
    delete = max(cfg.delete_misses, CENTRAL_MISSES * cfg.listed_sensors) if every_sensor else cfg.delete_misses
    return TrackParams(dim, cfg.q, cfg.noise_model, cfg.init_velocity_std, cfg.init_z_std,
                       cfg.pd if sensor is None else cfg.pd_of(sensor),
                       cfg.clutter_density if sensor is None else cfg.clutter_of(sensor),
                       cfg.thresholds.gate, cfg.confirm_hits, cfg.confirm_window, delete, vdie, detect)


@lru_cache(maxsize=16)
def _every_sensor_window(vdie: VdieParams, sensors: int) -> VdieParams:
    """A tracker of every sensor's scans (``mtt-centralized``) keeps ``window`` candidate onsets
    per sensor the config lists, so that its window spans about the same time as a sensor's own."""
    return dataclasses.replace(vdie, window=vdie.window * sensors)


class TrackSet(NamedTuple):
    """Live tracks, batched: ``x`` (N, D), ``P`` (N, D, D) (with maneuver handling, the CV view
    of ``man``, every track's VDIE state: :mod:`fedtrack.local_filters.mtt.maneuver`; or, on a
    3-D tracker, ``inputs``, every track's maneuver detector: :mod:`.detector`)."""

    ids: np.ndarray
    x: np.ndarray
    P: np.ndarray
    hits: np.ndarray
    age: np.ndarray  # scans since the start, the starting one included
    misses: np.ndarray  # consecutive misses
    confirmed: np.ndarray
    man: VdieState | None = None
    inputs: detector.TrackInputs | None = None

    def take(self, idx: np.ndarray) -> "TrackSet":
        return TrackSet(*(a[idx] for a in self[:-2]), None if self.man is None else maneuver.take(self.man, idx),
                        None if self.inputs is None else detector.take(self.inputs, idx))

    @property
    def models(self) -> list[str]:
        """Each track's motion model, ``"cv"`` or ``"ca"``."""
        if self.man is None:
            return ["cv"] * self.size
        return ["ca" if ca else "cv" for ca in self.man.is_ca.tolist()]

    @property
    def size(self) -> int:
        return int(self.ids.shape[0])


class TrackerState(NamedTuple):
    tracks: TrackSet
    t: float | None
    next_id: int


class Observation(NamedTuple):
    """What one detection says about its track, linearized: ``z ~ N(H x, R)`` (batched, K tracks).

    ``z = z_det - h(x0) + H x0`` at the linearization point ``x0``; exact for position sensors.
    """

    H: np.ndarray  # (K, m, D)
    R: np.ndarray  # (K, m, m)
    z: np.ndarray  # (K, m)


class ScanResult(NamedTuple):
    state: TrackerState
    detected: np.ndarray  # (N,) bool over state.tracks: updated or started by this scan
    observations: Observation  # for the detected tracks, in order
    retired: np.ndarray  # ids deleted by this scan


def empty_tracks(dim: int) -> TrackSet:
    return TrackSet(np.zeros(0, np.int64), np.zeros((0, dim)), np.zeros((0, dim, dim)), np.zeros(0, np.int64),
                    np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, bool))


def initial_state(dim: int) -> TrackerState:
    return TrackerState(empty_tracks(dim), None, 0)


def _concat(a: TrackSet, b: TrackSet) -> TrackSet:
    extras = []  # the per-track states beside x, P (None on an empty side: its tracker had no tracks)
    for u, v, join in ((a.man, b.man, maneuver.concat), (a.inputs, b.inputs, detector.concat)):
        if u is None or v is None:
            extras.append(v if a.size == 0 else u if b.size == 0 else None)
        else:
            extras.append(join(u, v))
    return TrackSet(*(np.concatenate([u, v]) for u, v in zip(a[:-2], b[:-2])), *extras)


def innovation_covariance(P: np.ndarray, lin: Linearized, R: np.ndarray) -> np.ndarray:
    S = lin.H @ P @ np.swapaxes(lin.H, -1, -2) + R
    return 0.5 * (S + np.swapaxes(S, -1, -2))


class Gated(NamedTuple):
    """The (track, detection) pairs inside the chi-square gate, with their innovations."""

    rows: np.ndarray  # (K,) track index
    cols: np.ndarray  # (K,) detection index
    nu: np.ndarray  # (K, m) innovation z_j - zhat_i, angles wrapped
    d2: np.ndarray  # (K,) squared Mahalanobis distance


def gate(z: np.ndarray, lin: Linearized, S: np.ndarray, gate_d2: float) -> tuple[Gated, np.ndarray]:
    """The gated pairs and ``ln det S`` (N,) per track (``d2 = nu' S^-1 nu``).

    Only a position sensor's pairs within the balls of :func:`gate_ball_pairs` are computed; a
    radar's azimuth residual wraps, so it keeps every pair."""
    if lin.angular:
        n, m = S.shape[0], z.shape[0]
        rows, cols = np.repeat(np.arange(n), m), np.tile(np.arange(m), n)
    else:
        rows, cols = gate_ball_pairs(z, lin.zhat, S, gate_d2)
    S_inv, logdet = spd_inverse_logdet(S)
    nu = z[cols] - lin.zhat[rows]
    for k in lin.angular:
        nu[:, k] = wrap_angle(nu[:, k])
    d2 = np.sum(nu * mat_vec(S_inv[rows], nu), axis=-1)
    inside = d2 <= gate_d2
    return Gated(rows[inside], cols[inside], nu[inside], d2[inside]), logdet


def assign(n_tracks: int, n_detections: int, rows: np.ndarray, cols: np.ndarray, cost: np.ndarray) -> np.ndarray:
    """Global nearest neighbour over candidate pairs (``rows``, ``cols``) with negative ``cost``:
    the indices of the chosen pairs. Solved per connected component of the pair graph: a
    component of one pair takes it, one of a single track or a single detection its cheapest
    pair, one of at most ``SMALL_COMPONENT`` on either side its best enumerated matching, the
    others ``linear_sum_assignment``."""
    usable = np.flatnonzero(cost < 0.0)
    if usable.size == 0:
        return usable
    r, c = rows[usable], cols[usable]
    n = n_tracks + n_detections
    _, label = connected_components(_pair_graph(n_tracks, n, r, c), directed=False)
    comp = label[r]
    order = np.argsort(comp, kind="stable")
    usable, r, c, comp = usable[order], r[order], c[order], comp[order]
    local_r, n_r = _rank_in_component(r, comp, n)
    local_c, n_c = _rank_in_component(c, comp, n)
    star = (n_r[comp] == 1) | (n_c[comp] == 1)  # one track or one detection (or both: one pair)
    # per star component, its cheapest pair (the first of equal ones)
    by_cost = np.lexsort((np.arange(usable.size), cost[usable], comp))
    by_cost = by_cost[star[by_cost]]
    first = np.ones(by_cost.size, dtype=bool)
    first[1:] = comp[by_cost[1:]] != comp[by_cost[:-1]]
    chosen = [usable[by_cost[first]]]
    full = np.flatnonzero(~star)  # full components are contiguous runs of pairs
    is_small = np.maximum(n_r, n_c)[comp[full]] <= SMALL_COMPONENT
    small, full = full[is_small], full[~is_small]
    if small.size:
        chosen.append(_assign_small(usable[small], comp[small], local_r[small], local_c[small], cost[usable[small]],
                                    n_r, n_c))
    if full.size:
        change = comp[full[1:]] != comp[full[:-1]]
        starts, ends = full[np.r_[True, change]], full[np.r_[change, True]] + 1
        for s, e in zip(starts.tolist(), ends.tolist()):
            k = comp[s]
            sub = np.zeros((n_r[k], n_c[k]))
            pair = np.full((n_r[k], n_c[k]), -1)
            sub[local_r[s:e], local_c[s:e]] = cost[usable[s:e]]
            pair[local_r[s:e], local_c[s:e]] = usable[s:e]
            ri, ci = linear_sum_assignment(sub)
            picked = pair[ri, ci]
            chosen.append(picked[picked >= 0])
    return np.concatenate(chosen)


# Components of at most this many tracks and detections are solved by enumerating their
# matchings, all components of one shape at once (a 3 x 3 has 6): 93 % of a 1,000-target
# scene's components, each of which cost a linear_sum_assignment call of about 10 us.
SMALL_COMPONENT = 3


@cache
def _injections(a: int, b: int) -> np.ndarray:
    """Every injective map of ``a`` rows into ``b >= a`` columns, (count, a)."""
    return np.array(list(itertools.permutations(range(b), a)), dtype=np.intp).reshape(-1, a)


def _assign_small(pairs: np.ndarray, comp: np.ndarray, r: np.ndarray, c: np.ndarray, cost: np.ndarray,
                  n_r: np.ndarray, n_c: np.ndarray) -> np.ndarray:
    """The optimal matching of each small component (``pairs`` with component ``comp``, rank
    ``r``, ``c`` in it, ``cost`` < 0; its sizes ``n_r``, ``n_c``): the matching of the smaller
    side into the larger with the least total cost, a missing pair costing 0 and not kept (what
    ``linear_sum_assignment`` gives on the component's dense matrix)."""
    out = []
    shape = n_r[comp] * (SMALL_COMPONENT + 1) + n_c[comp]
    for code in np.unique(shape).tolist():
        a, b = divmod(code, SMALL_COMPONENT + 1)
        sel = np.flatnonzero(shape == code)
        comps, row = np.unique(comp[sel], return_inverse=True)
        rr, cc = (r[sel], c[sel]) if a <= b else (c[sel], r[sel])  # rows: the smaller side
        a, b = min(a, b), max(a, b)
        sub = np.zeros((comps.size, a, b))
        pair = np.full((comps.size, a, b), -1)
        sub[row, rr, cc], pair[row, rr, cc] = cost[sel], pairs[sel]
        maps = _injections(a, b)
        best = maps[np.argmin(sub[:, np.arange(a), maps].sum(axis=-1), axis=1)]  # (components, a)
        picked = pair[np.arange(comps.size)[:, None], np.arange(a), best].ravel()
        out.append(picked[picked >= 0])
    return np.concatenate(out) if out else np.zeros(0, np.int64)


def _pair_graph(n_tracks: int, n: int, r: np.ndarray, c: np.ndarray) -> csr_matrix:
    """The bipartite graph of pairs (track ``r``, detection ``c``) on ``n`` nodes (tracks, then
    detections), built straight as CSR (a COO build and conversion cost 2.5x)."""
    if np.any(r[1:] < r[:-1]):  # CSR lists each track's detections together
        c = c[np.argsort(r, kind="stable")]
    indptr = np.zeros(n + 1, dtype=np.int32)
    indptr[1:n_tracks + 1] = np.cumsum(np.bincount(r, minlength=n_tracks))
    indptr[n_tracks + 1:] = indptr[n_tracks]
    return csr_matrix((np.ones(r.size), (n_tracks + c).astype(np.int32), indptr), shape=(n, n))


def _rank_in_component(v: np.ndarray, comp: np.ndarray, n_comp: int) -> tuple[np.ndarray, np.ndarray]:
    """Per pair, the rank of its value ``v`` (>= 0) among the distinct values of its component
    ``comp`` (< ``n_comp``), and the number of distinct values per component (what ``np.unique``
    per component gives, at once)."""
    span = int(v.max()) + 1
    distinct, inverse = np.unique(comp.astype(np.int64) * span + v, return_inverse=True)
    owner = distinct // span
    first = np.r_[True, owner[1:] != owner[:-1]]
    start = np.maximum.accumulate(np.where(first, np.arange(distinct.size), 0))
    return (np.arange(distinct.size) - start)[inverse.ravel()], np.bincount(owner, minlength=n_comp)


def assign_by_precedence(n_detections: int, g: Gated, cost: np.ndarray, confirmed: np.ndarray) -> np.ndarray:
    """Confirmed tracks take their detections first, tentative tracks share what is left (so a
    tentative track started on clutter never takes a confirmed track's detection). Returns the
    indices of the chosen pairs."""
    n = confirmed.size
    first = np.flatnonzero(confirmed[g.rows])
    picked = first[assign(n, n_detections, g.rows[first], g.cols[first], cost[first])]
    free = np.ones(n_detections, bool)
    free[g.cols[picked]] = False
    second = np.flatnonzero(~confirmed[g.rows] & free[g.cols])
    return np.concatenate([picked, second[assign(n, n_detections, g.rows[second], g.cols[second], cost[second])]])


def start_tracks(scan: SensorScan, det: np.ndarray, params: TrackParams, first_id: int
                 ) -> tuple[TrackSet, Observation]:
    """Tentative tracks from the detections ``det`` of ``scan`` (one-point initialization)."""
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
    if d == 6 and k == 2:
        P[:, 4, 4] = params.init_z_std**2
    obs = Observation(np.broadcast_to(position_matrix(d, k), (n, k, d)).copy(), Ppos, pos)
    one = np.ones(n, np.int64)
    ids = first_id + np.arange(n, dtype=np.int64)
    man = None if params.maneuver is None else maneuver.start(x, P, scan.t, params.maneuver)
    inputs = None if params.detector is None else detector.start(n, d, scan.t, params.detector)
    return TrackSet(ids, x, P, one, one.copy(), np.zeros(n, np.int64), one >= params.confirm_hits, man,
                    inputs), obs


def tracker_step(state: TrackerState, scan: SensorScan, params: TrackParams,
                 q_scale: float | np.ndarray = 1.0) -> ScanResult:
    """Process one scan (times must not decrease); ``q_scale`` scales ``Q`` (federated ``beta_i``)."""
    tracks = state.tracks
    d = params.dim
    if state.t is not None and scan.t < state.t:
        raise ValueError(f"scan at t = {scan.t} is before the tracker's time {state.t}")
    dt = 0.0 if state.t is None else scan.t - state.t
    man = tracks.man if params.maneuver is not None else None
    inputs = tracks.inputs if params.detector is not None else None
    if man is not None and tracks.size:
        x, P = maneuver.predicted_view(man, dt, params.q, params.noise_model, q_scale)
    elif tracks.size and dt > 0:
        x, P = predict_tracks(tracks.x, tracks.P, motion(d, round(dt, 12), params.q, params.noise_model), q_scale)
    else:
        x, P = tracks.x.copy(), tracks.P.copy()
    m = scan.dim
    n_det = scan.z.shape[0]
    assigned = np.zeros(tracks.size, bool)
    obs_upd = Observation(np.zeros((0, m, d)), np.zeros((0, m, m)), np.zeros((0, m)))
    used = np.zeros(n_det, bool)
    ti = dj = np.zeros(0, np.int64)
    if tracks.size and n_det:
        lin = linearize(x, scan.sensor_position)
        S = innovation_covariance(P, lin, scan.R)
        g, logdet = gate(scan.z, lin, S, params.gate[m])
        pd = params.pd
        if pd >= 1.0:
            bias = -1e6  # no missed detections: any gated pair beats a miss
        else:
            bias = 2.0 * math.log(max(params.clutter_density, 1e-300) * (1.0 - pd) / pd)
        cost = g.d2 + logdet[g.rows] + m * LOG_2PI + bias
        chosen = assign_by_precedence(n_det, g, cost, tracks.confirmed)
        chosen = chosen[np.argsort(g.rows[chosen])]
        ti, dj = g.rows[chosen], g.cols[chosen]
        if ti.size:
            H, R = lin.H[ti], scan.R
            nu_a, x0 = g.nu[chosen], x[ti]
            P0 = P[ti]
            if man is None:
                x[ti], P[ti] = update_residual(GaussianState(x0, P0), nu_a, H, R).state  # Joseph form
            obs_upd = Observation(H, np.broadcast_to(R, (ti.size, m, m)).copy(),
                                  nu_a + np.einsum("nij,nj->ni", H, x0))
            if inputs is not None:
                inputs = detector.observe(inputs, ti, scan.t, x0, P0, *obs_upd)
            assigned[ti] = True
            used[dj] = True
    if man is not None and tracks.size:
        step = maneuver.maneuver_step(man, scan.t, dt, params.q, params.noise_model, params.maneuver,
                                      ti, scan.z[dj], scan.R, q_scale)
        (x, P), man = step.view, step.state
    hits = tracks.hits + assigned
    age = tracks.age + 1
    misses = np.where(assigned, 0, tracks.misses + 1)
    confirmed = tracks.confirmed | (hits >= params.confirm_hits)
    live = np.where(confirmed, misses < params.delete_misses,
                    params.confirm_window - age >= params.confirm_hits - hits)
    updated = TrackSet(tracks.ids, x, P, hits, age, misses, confirmed, man, inputs)
    kept = updated.take(live)
    new, obs_new = start_tracks(scan, np.flatnonzero(~used), params, state.next_id)
    detected = np.concatenate([assigned[live], np.ones(new.size, bool)])
    keep_info = live[assigned]
    return ScanResult(TrackerState(_concat(kept, new), scan.t, state.next_id + new.size), detected,
                      Observation(*(np.concatenate([u[keep_info], v]) for u, v in zip(obs_upd, obs_new))),
                      tracks.ids[~live])

