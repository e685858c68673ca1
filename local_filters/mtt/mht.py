"""Track-oriented multiple-hypothesis tracking (MHT) as pure functions over batched branches.

Every target track is a tree of **branches** (its alternative detection histories); its live
ones (leaves) are stored together, batched, as a :class:`TrackSet` whose ``ids`` name each
leaf's track (its tree). A **global hypothesis** picks at most one leaf per track with no
detection used twice; the ``k`` best are kept, as a boolean (hypotheses, leaves) matrix.

Per scan (:func:`mht_step`):

1. Predict every leaf; gate every leaf against the detections (:func:`.tracker.gate`).
2. Score each gated pair with the track-score increments (log-likelihood ratios of "target"
   against "clutter", Blackman & Popoli 6.2; :func:`score_increments`): a detection
   ``ln(P_D N(nu; 0, S) / lambda)`` plus paper 001's amplitude log-ratio ``ln f1r(a)/f0r(a)``
   (eqs (1), (2), (6), (7): :func:`~fedtrack.local_filters.pda.association.log_amplitude_ratio`)
   when the detections carry amplitudes; a miss ``ln(1 - P_D P_G)``.
3. Extend each kept global hypothesis by its ``k`` best assignments of the current scan
   (:func:`best_extensions`): each of its leaves takes one gated detection or misses, each
   detection at most once; the gain of a pair is its increment over the miss. The problem
   is split into the connected components (clusters) of the leaves' gating graph; each
   cluster's k best by Murty's algorithm over ``linear_sum_assignment``
   (:func:`.kbest.k_best_assignments`), the hypothesis's k best as the k best sums over the
   clusters (:func:`.kbest.k_best_sums`). Of all the extensions of all the hypotheses, the ``k``
   best (hypothesis value plus gain) are kept. A detection that a kept hypothesis leaves
   unused starts a new track (one tree per detection, the same in every hypothesis that
   leaves it unused).
4. The branches the kept hypotheses use are the new leaves: a miss branch keeps the
   prediction, a detection branch is the (E)KF update (Joseph form) of its parent.
5. Track management per branch: ``"score"`` (the SPRT, :func:`sprt_thresholds`) or
   ``"counts"`` (gnn's M-of-N rules and its track precedence, for the equivalence with gnn).
   A deleted branch leaves its track out of the hypotheses that used it.
6. N-scan pruning: of every track of the best hypothesis, only the leaves that share its
   branch ``window - 1`` scans back stay (``window = 1``: its leaf alone); at most
   ``max_branches`` leaves per track (those of the best hypotheses first). A hypothesis that
   used a removed leaf is dropped, a leaf that no hypothesis uses is removed.

The picture is the best hypothesis's leaves (:func:`best_tracks`).

With ``window = 1`` and ``k = 1`` and ``"counts"`` management this is gnn: the one
hypothesis is gnn's optimal assignment and N-scan pruning keeps exactly its branches
(tests/test_mht.py, to 1e-9). The global hypotheses are extended scan by scan (Cox &
Hingorani 1996: Murty's k best per hypothesis), so an assignment that leaves the k best at
one scan cannot return at a later one: that is what ``k`` bounds. Defaults and their
derivation: docs/multitarget.md#mht.
"""

from __future__ import annotations

import math
from functools import lru_cache, partial
from typing import NamedTuple

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from fedtrack.local_filters.linear.kalman import GaussianState, update_residual
from fedtrack.local_filters.mtt.association import Associator
from fedtrack.local_filters.mtt.config import MhtConfig
from fedtrack.local_filters.mtt.kbest import k_best_assignments, k_best_sums
from fedtrack.local_filters.mtt.scan import SensorScan
from fedtrack.local_filters.mtt.tracker import (
    Observation,
    ScanResult,
    TrackerState,
    TrackParams,
    TrackSet,
    _concat,
    empty_tracks,
    gate_scan,
    predict,
    start_tracks,
)
from fedtrack.local_filters.pda.association import Constants, constants, log_amplitude_ratio
from fedtrack.local_filters.pda.config import PDAParams

MANAGEMENTS = ("score", "counts")


class MhtParams(NamedTuple):
    """What the MHT needs per scan beside the tracker's :class:`TrackParams` (no maneuver handling)."""

    track: TrackParams
    window: int  # N: scans back to the branch that N-scan pruning keeps (1: the best leaf only)
    k: int  # global hypotheses kept
    max_branches: int  # leaves kept per track
    management: str  # "score" (SPRT) or "counts" (gnn's M-of-N and precedence)
    pg: float  # gate probability P_G
    confirm_score: float  # SPRT upper threshold ln((1 - beta) / alpha)
    delete_score: float  # SPRT lower threshold ln(beta / (1 - alpha))
    birth_score: float = 0.0  # a new track's score before its detection's amplitude: ln(beta_NT / lambda)
    amplitude: Constants | None = None  # amplitude model (threshold tau, SNR); None: amplitudes ignored


def sprt_thresholds(false_track: float, miss: float) -> tuple[float, float]:
    """Wald's SPRT thresholds on a track score (a log-likelihood ratio of target against false
    track): confirm at ``ln((1 - beta) / alpha)``, delete at ``ln(beta / (1 - alpha))``, where
    ``alpha = false_track`` is the probability of confirming a track started on clutter and
    ``beta = miss`` that of deleting a track on a real target (Wald 1947; Blackman & Popoli
    6.2.4)."""
    if not (0.0 < false_track < 1.0 and 0.0 < miss < 1.0 and false_track + miss < 1.0):
        raise ValueError("sprt_thresholds: false_track and miss must be in (0, 1) with a sum below 1")
    return math.log((1.0 - miss) / false_track), math.log(miss / (1.0 - false_track))


class MhtState(NamedTuple):
    """Every track's leaves, batched (``leaves.ids``: the track of each), their scores and
    lineage, and the kept global hypotheses (best first)."""

    leaves: TrackSet
    score: np.ndarray  # (L,) track score: the log-likelihood ratio of the leaf's history
    peak: np.ndarray  # (L,) the highest score along the leaf's history
    lineage: np.ndarray  # (L, window) branch serials of its ancestors, oldest first, its own last
    hyps: np.ndarray  # (K, L) bool: the leaves each global hypothesis holds
    t: float | None
    next_id: int
    next_branch: int


def initial_mht_state(dim: int, window: int) -> MhtState:
    return MhtState(empty_tracks(dim), np.zeros(0), np.zeros(0), np.zeros((0, window), np.int64),
                    np.ones((1, 0), bool), None, 0, 0)


class MhtResult(NamedTuple):
    state: MhtState
    tracks: TrackSet  # the best hypothesis's tracks, by id
    detected: np.ndarray  # (N,) bool over tracks: updated or started by this scan
    observations: Observation  # for the detected tracks, in order
    assigned: np.ndarray  # (A, 2) the best hypothesis's (track id, detection) of this scan, started tracks not included
    retired: np.ndarray  # ids of the tracks that lost their last leaf at this scan


def score_increments(log_n: np.ndarray, params: MhtParams, amplitude: np.ndarray | None) -> tuple[np.ndarray, float]:
    """Track-score increments: per gated pair ``ln(P_D N(nu; 0, S) / lambda)`` from its
    ``log_n = ln N(nu; 0, S)`` (+ the amplitude log-ratio of its detection ``amplitude``), and a
    miss's ``ln(1 - P_D P_G)``."""
    tp = params.track
    inc = math.log(tp.pd) + log_n - math.log(max(tp.clutter_density, 1e-300))
    if amplitude is not None and params.amplitude is not None:
        inc = inc + log_amplitude_ratio(amplitude, params.amplitude)
    return inc, math.log1p(-tp.pd * params.pg)


def best_extensions(n_det: int, r: np.ndarray, c: np.ndarray, gain: np.ndarray, k: int,
                    names: np.ndarray | None = None, cache: dict | None = None
                    ) -> tuple[np.ndarray, list[np.ndarray]]:
    """The ``k`` best ways for rows to take one detection each of their candidate pairs
    (``r``, ``c``, ``gain`` over a miss) or miss (gain 0), each
    detection at most once: the total gains, best first, and per way the indices of the pairs
    it takes. Per connected component of the pairs: a component of one row ranks its pairs and
    its miss, a larger one takes Murty's k best; combined by the k best sums. ``cache`` holds
    the components solved already, by the ``names`` of their pairs (ascending): the global
    hypotheses of a scan share most of them."""
    if r.size == 0:
        return np.zeros(1), [np.zeros(0, np.intp)]
    rows, r_local = np.unique(r, return_inverse=True)
    n = rows.size + n_det
    graph = coo_matrix((np.ones(r.size), (r_local, rows.size + c)), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    comp = label[r_local]
    order = np.argsort(comp, kind="stable")
    bounds = np.flatnonzero(np.r_[True, comp[order][1:] != comp[order][:-1], True])
    lists, ways = [], []
    for s, e in zip(bounds[:-1].tolist(), bounds[1:].tolist()):
        sel = order[s:e]
        key = names[sel].tobytes() if cache is not None else None
        if key is not None and key in cache:
            costs, picked = cache[key]
        else:
            costs, picked = _component_best(r_local[sel], c[sel], gain[sel], k)
            if key is not None:
                cache[key] = costs, picked
        lists.append(costs)
        ways.append([sel[p[p >= 0]] for p in picked])
    sums, picks = k_best_sums(lists, k)
    return -sums, [np.concatenate([ways[j][i] for j, i in enumerate(row)]) for row in picks.tolist()]


def _component_best(r: np.ndarray, c: np.ndarray, gain: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The k best assignments of one connected component of pairs: costs (minus the gains)
    ascending and, per assignment and row, the index of its pair (-1: a miss)."""
    rr, r_of = np.unique(r, return_inverse=True)
    if rr.size == 1:  # one row: its miss and each of its pairs
        options = np.r_[0.0, -gain]
        best = np.argsort(options, kind="stable")[:k]
        return options[best], (best - 1)[:, None]
    cc, c_of = np.unique(c, return_inverse=True)
    nr, nc = rr.size, cc.size
    cost = np.full((nr, nc + nr), np.inf)
    cost[r_of, c_of] = -gain
    cost[np.arange(nr), nc + np.arange(nr)] = 0.0  # each row's own miss
    pair = np.full((nr, nc + nr), -1)
    pair[r_of, c_of] = np.arange(r.size)
    costs, cols = k_best_assignments(cost, k)
    return costs, pair[np.arange(nr), cols]


def _extend(hyp_rows: np.ndarray, n_det: int, g_rows: np.ndarray, g_cols: np.ndarray, gain: np.ndarray,
            confirmed: np.ndarray, params: MhtParams, cache: dict) -> tuple[np.ndarray, list[np.ndarray]]:
    """The k best extensions of one hypothesis (its leaves ``hyp_rows``) over the gated pairs:
    their gains and chosen pair indices. ``"counts"``: confirmed leaves choose first, tentative
    ones among the detections left (gnn's precedence), each stage by its k best."""
    mine = np.zeros(confirmed.size, bool)
    mine[hyp_rows] = True
    pairs = np.flatnonzero(mine[g_rows])
    if params.management != "counts":
        gains, ways = best_extensions(n_det, g_rows[pairs], g_cols[pairs], gain[pairs], params.k, pairs, cache)
        return gains, [pairs[w] for w in ways]
    first = pairs[confirmed[g_rows[pairs]]]
    second = pairs[~confirmed[g_rows[pairs]]]
    out_gain, out_ways = [], []
    for g1, w1 in zip(*best_extensions(n_det, g_rows[first], g_cols[first], gain[first], params.k, first, cache)):
        taken = first[w1]
        free = np.ones(n_det, bool)
        free[g_cols[taken]] = False
        rest = second[free[g_cols[second]]]
        for g2, w2 in zip(*best_extensions(n_det, g_rows[rest], g_cols[rest], gain[rest], params.k, rest, cache)):
            out_gain.append(g1 + g2)
            out_ways.append(np.concatenate([taken, rest[w2]]))
    order = np.argsort(-np.array(out_gain), kind="stable")[:params.k]
    return np.array(out_gain)[order], [out_ways[i] for i in order.tolist()]


def hypothesis_values(state: MhtState, birth_score: float) -> np.ndarray:
    """Each global hypothesis's value: the sum over its leaves of their score gained since birth
    (the log-likelihood ratio of its assignments against "every detection clutter or a new
    track"; a new track counts 0, so a detection is given to a track exactly when that beats
    a miss, gnn's rule)."""
    return state.hyps.astype(float) @ (state.score - birth_score) if state.score.size else np.zeros(len(state.hyps))


def mht_step(state: MhtState, scan: SensorScan, params: MhtParams, q_scale: float | np.ndarray = 1.0) -> MhtResult:
    """Process one scan (times must not decrease); ``q_scale`` scales ``Q``."""
    tp = params.track
    leaves, d = state.leaves, tp.dim
    if state.t is not None and scan.t < state.t:
        raise ValueError(f"scan at t = {scan.t} is before the tracker's time {state.t}")
    x, P = predict(leaves, 0.0 if state.t is None else scan.t - state.t, tp, q_scale)
    m, n_det = scan.dim, scan.z.shape[0]
    g_rows = g_cols = np.zeros(0, np.int64)
    nu, inc = np.zeros((0, m)), np.zeros(0)
    miss = math.log1p(-tp.pd * params.pg)
    gating = gate_scan(GaussianState(x, P), scan, tp)
    if gating is not None:
        g_rows, g_cols, nu, _ = gating.pairs
        amp = None if scan.amplitude is None else scan.amplitude[g_cols]
        inc, miss = score_increments(gating.log_likelihood, params, amp)
    # 3. the k best extensions of every kept hypothesis
    values = hypothesis_values(state, params.birth_score)
    cand_value, cand_parent, cand_pairs = [], [], []
    cache: dict = {}
    for h, row in enumerate(state.hyps):
        gains, ways = _extend(np.flatnonzero(row), n_det, g_rows, g_cols, inc - miss, leaves.confirmed, params, cache)
        cand_value.extend((values[h] + gains).tolist())
        cand_parent.extend([h] * len(ways))
        cand_pairs.extend(ways)
    keep = np.argsort(-np.array(cand_value), kind="stable")[:params.k]
    parents = np.array(cand_parent, np.intp)[keep]
    chosen = [cand_pairs[i] for i in keep.tolist()]
    # 4. the branches the kept hypotheses use: key leaf * (n_det + 1) + detection + 1 (0: a miss)
    keys_per_hyp = []
    for parent, pairs in zip(parents.tolist(), chosen):
        det_of = np.full(leaves.size, -1)
        det_of[g_rows[pairs]] = g_cols[pairs]
        held = np.flatnonzero(state.hyps[parent])
        keys_per_hyp.append(held * (n_det + 1) + det_of[held] + 1)
    keys, key_index = np.unique(np.concatenate(keys_per_hyp + [np.zeros(0, np.int64)]), return_inverse=True)
    parent_leaf, det = np.divmod(keys, n_det + 1)
    det = det - 1
    hit = det >= 0
    pair_of = np.full((leaves.size, n_det), -1)
    pair_of[g_rows, g_cols] = np.arange(g_rows.size)
    pidx = pair_of[parent_leaf[hit], det[hit]]
    cx, cP = x[parent_leaf], P[parent_leaf]
    obs = Observation(np.zeros((0, m, d)), np.zeros((0, m, m)), np.zeros((0, m)))
    if pidx.size:
        lin_h = gating.lin.H[parent_leaf[hit]]
        x0 = cx[hit]
        cx[hit], cP[hit] = update_residual(GaussianState(x0, cP[hit]), nu[pidx], lin_h, scan.R).state
        obs = Observation(lin_h, np.broadcast_to(scan.R, (pidx.size, m, m)).copy(),
                          nu[pidx] + np.einsum("nij,nj->ni", lin_h, x0))
    old = leaves.take(parent_leaf)
    score = state.score[parent_leaf] + np.where(hit, 0.0, miss)
    score[hit] += inc[pidx]
    peak = np.maximum(state.peak[parent_leaf], score)
    hits = old.hits + hit
    misses = np.where(hit, 0, old.misses + 1)
    # 5. track management per branch
    age = old.age + 1
    if params.management == "counts":
        confirmed = old.confirmed | (hits >= tp.confirm_hits)
        live = np.where(confirmed, misses < tp.delete_misses, tp.confirm_window - age >= tp.confirm_hits - hits)
    else:
        confirmed = old.confirmed | (score >= params.confirm_score)
        live = np.where(confirmed, score - peak > params.delete_score, score > params.delete_score)
    children = TrackSet(old.ids, cx, cP, hits, age, misses, confirmed)
    serial = state.next_branch + np.arange(keys.size)
    lineage = np.concatenate([state.lineage[parent_leaf, 1:], serial[:, None]], axis=1)
    n_child = keys.size
    hyps = np.zeros((len(chosen), n_child), bool)
    offsets = np.cumsum([0] + [kk.size for kk in keys_per_hyp])
    for h in range(len(chosen)):
        hyps[h, key_index[offsets[h]:offsets[h + 1]]] = True
    # new tracks: a detection some kept hypothesis leaves unused
    used = np.zeros((len(chosen), n_det), bool)
    for h, pairs in enumerate(chosen):
        used[h, g_cols[pairs]] = True
    fresh = np.flatnonzero(~used.all(axis=0)) if len(chosen) else np.arange(n_det)
    new, obs_new = start_tracks(scan, fresh, tp, state.next_id)
    new_score = np.full(fresh.size, params.birth_score)
    if scan.amplitude is not None and params.amplitude is not None:
        new_score = new_score + log_amplitude_ratio(scan.amplitude[fresh], params.amplitude)
    if params.management == "score":
        new = new._replace(confirmed=new_score >= params.confirm_score)
    new_serial = state.next_branch + n_child + np.arange(fresh.size)
    starts = np.zeros((len(chosen), fresh.size), bool)
    starts[:, :] = ~used[:, fresh]
    tracks = _concat(children, new)
    state2 = MhtState(tracks, np.concatenate([score, new_score]), np.concatenate([peak, new_score]),
                      np.concatenate([lineage, np.repeat(new_serial[:, None], params.window, axis=1)]),
                      np.concatenate([hyps & live, starts], axis=1), scan.t, state.next_id + fresh.size,
                      state.next_branch + n_child + fresh.size)
    branch_obs = Observation(*(np.concatenate([u, v]) for u, v in zip(obs, obs_new)))
    branch_det = np.concatenate([det, fresh])  # each new leaf's detection (-1: a miss)
    alive = np.concatenate([live, np.ones(fresh.size, bool)])
    state2, kept = _prune(state2, alive, params)
    best = np.flatnonzero(state2.hyps[0]) if len(state2.hyps) else np.zeros(0, np.intp)
    best = best[np.argsort(state2.leaves.ids[best], kind="stable")]
    det_best = branch_det[kept][best]
    had_det = np.flatnonzero(branch_det >= 0)  # rows of branch_obs, in branch order
    obs_row = np.full(branch_det.size, -1)
    obs_row[had_det] = np.arange(had_det.size)
    rows_best = obs_row[kept][best][det_best >= 0]
    result_tracks = state2.leaves.take(best)
    took = (det_best >= 0) & (kept[best] < n_child)  # an existing track's detection
    retired = np.setdiff1d(leaves.ids, state2.leaves.ids)
    return MhtResult(state2, result_tracks, det_best >= 0, Observation(*(a[rows_best] for a in branch_obs)),
                     np.stack([result_tracks.ids[took], det_best[took]], axis=1), retired)


def _prune(state: MhtState, alive: np.ndarray, params: MhtParams) -> tuple[MhtState, np.ndarray]:
    """N-scan pruning and the cap on leaves per track (module docstring, step 6), then the
    leaves no hypothesis holds and duplicate hypotheses removed; hypotheses best first.
    Returns the state and the indices of the leaves kept."""
    hyps = state.hyps & alive
    ids = state.leaves.ids
    if hyps.shape[1] == 0:
        hyps = hyps[:1]
    elif hyps.shape[0]:
        values = hyps.astype(float) @ (state.score - params.birth_score)
        hyps = hyps[np.argsort(-values, kind="stable")]
        _, first = np.unique(np.packbits(hyps, axis=1), axis=0, return_index=True)
        hyps = hyps[np.sort(first)]
    keep = alive.copy()
    if hyps.shape[0]:
        best = np.flatnonzero(hyps[0])  # N-scan pruning around the best hypothesis's branches
        root = np.full(int(ids.max()) + 1 if ids.size else 0, -1)
        root[ids[best]] = state.lineage[best, 0]
        pruned = (root[ids] >= 0) & (state.lineage[:, 0] != root[ids])
        keep &= ~pruned
        # the cap: per track, the leaves of the best hypotheses first
        rank = np.where(hyps.any(axis=0), np.argmax(hyps, axis=0), hyps.shape[0])
        order = np.lexsort((rank, ids))
        first_of = np.r_[True, ids[order][1:] != ids[order][:-1]]
        start = np.maximum.accumulate(np.where(first_of, np.arange(order.size), 0))
        within = np.empty(order.size, np.int64)
        within[order] = np.arange(order.size) - start
        keep &= within < params.max_branches
        hyps = hyps[~(hyps & ~keep).any(axis=1)]
        keep &= hyps.any(axis=0)
    idx = np.flatnonzero(keep)
    out = MhtState(state.leaves.take(idx), state.score[idx], state.peak[idx], state.lineage[idx],
                   hyps[:, idx], state.t, state.next_id, state.next_branch)
    return out, idx


def best_tracks(state: MhtState) -> TrackSet:
    """The best global hypothesis's tracks, by id (the picture)."""
    best = np.flatnonzero(state.hyps[0]) if len(state.hyps) else np.zeros(0, np.intp)
    return state.leaves.take(best[np.argsort(state.leaves.ids[best], kind="stable")])


# paper 001's mean target SNR for scans whose detections carry amplitudes (jipda's too)
SNR = PDAParams().snr


@lru_cache(maxsize=64)
def scan_constants(pd: float, clutter_density: float, gate_d2: float, m: int) -> Constants:
    """Paper 001's constants for an ``m``-dimensional scan gated at ``gate_d2``: ``P_G`` and the
    amplitude threshold ``tau`` (the terms JIPDA scores its pairs with)."""
    return constants(PDAParams(pd=pd, clutter_density=clutter_density, snr=SNR, gate=gate_d2), n=m)


def mht_params(settings: MhtConfig, tp: TrackParams, m: int) -> MhtParams:
    """The MHT's parameters for a scan of measurement size ``m``. ``"counts"`` management is
    gnn's model too: its M-of-N rules and track precedence, and a gate that holds every target
    detection (``P_G = 1`` in the miss term, gnn's cost), so that window 1 and k 1 are gnn."""
    c = scan_constants(tp.pd, tp.clutter_density, tp.gate[m], m)
    confirm, delete = sprt_thresholds(settings.false_track, settings.miss)
    return MhtParams(tp, settings.window, settings.k, settings.max_branches, settings.management,
                     1.0 if settings.management == "counts" else c.pg, confirm, delete, 0.0, c)


def tracker_step(state: TrackerState, scan: SensorScan, params: TrackParams, q_scale: float | np.ndarray,
                 settings: MhtConfig) -> ScanResult:
    """The tracker's scan with ``associator = "mht"``: :func:`mht_step` on the branches its
    memory holds; the tracks are the best hypothesis's."""
    memory = state.memory if state.memory is not None else initial_mht_state(params.dim, settings.window)
    res = mht_step(memory, scan, mht_params(settings, params, scan.dim), q_scale)
    return ScanResult(TrackerState(res.tracks, scan.t, res.state.next_id, res.state), res.detected,
                      res.observations, res.retired)


def associator(settings: MhtConfig) -> Associator:
    """``[mtt] associator = "mht"`` with its ``[mtt.mht]`` settings (the whole scan: ``step``)."""
    return Associator("mht", _no_chain, step=partial(tracker_step, settings=settings))


def _no_chain(*_: object) -> None:
    raise TypeError("mht takes the whole scan (Associator.step), not the tracker's chain")
