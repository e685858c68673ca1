"""Track-oriented multiple-hypothesis tracking (MHT): the hypothesis maths, as pure functions
over batched branches (``[mtt] associator = "mht"``; the tracker runs them in
:func:`fedtrack.local_filters.mtt.tracker.mht_step`).

Every target track is a tree of **branches** (its alternative detection histories); its live
ones (leaves) are stored together, batched, as the tracker's ``TrackSet`` whose ``ids`` name each
leaf's track. The tracks are split into **clusters** of interacting tracks (tracks whose
leaves shared a gated detection, and have not been decided since); a **hypothesis** of a
cluster picks at most one leaf per track of it with no detection used twice; each cluster keeps
its ``k`` best, as a boolean (rank, leaves) matrix whose row r holds every cluster's r-th best
(row 0, the union of the clusters' best, is the best global hypothesis: the clusters are
independent), with a (rank, cluster) matrix of values.

Per scan:

1. The tracker predicts every leaf and gates it against the detections (its ``predict`` and
   ``gate_scan`` roles).
2. Each gated pair is scored with the track-score increments (log-likelihood ratios of
   "target" against "clutter", Blackman & Popoli 1999, 6.2; :func:`score_increments`): a
   detection ``ln(P_D N(nu; 0, S) / lambda)`` plus paper 001's amplitude log-ratio
   ``ln f1r(a) / f0r(a)`` (eqs (1), (2), (6), (7):
   :func:`~fedtrack.local_filters.pda.association.log_amplitude_ratio`) when the detections carry
   amplitudes; a miss ``ln(1 - P_D P_G)``. These are JIPDA's pair and miss factors
   (``local_filters/mtt/associators/jipda.py``) at existence 1, from the same constants (paper 001's
   ``constants``: ``P_G``, the amplitude threshold ``tau``, the SNR: :func:`~.jipda.scan_constants`).
3. Per cluster (:func:`extend_clusters`): the old clusters joined by the detections their
   leaves gate are the scan's clusters; each one's parents are the k best combinations of its old
   clusters' hypotheses (:func:`k_best_sums`), each parent extended by its ``k`` best assignments
   of the cluster's gated pairs: each of its leaves takes one gated detection or misses, each
   detection at most once; a pair's gain is what it adds to the hypothesis value over the miss,
   each track's existence kept open (:func:`value_increments`). The parent's pairs are split
   into their connected components; each component's k best by Murty's algorithm over
   ``linear_sum_assignment`` (:func:`~.gnn.k_best_assignments`), the parent's k best as the k best
   sums over its components. Of all the extensions of all the parents the cluster keeps its
   ``k`` best, less those less probable than ``eps`` = ``MHT_WINDOW_MISS`` times its best (the
   window's own ``eps``). A cluster of one track is ranked with every other such at once
   (:func:`_simple_clusters`). A detection that a kept hypothesis of its cluster leaves unused
   starts a new track there (one per detection), in that cluster.
4. The branches the kept hypotheses use are the new leaves: a miss keeps the
   prediction, a detection is the (E)KF update (Joseph form) of its parent; with ``process_noise =
   "imm"`` every leaf carries its two motion modes, as a gnn track does (docs/mht.md).
5. Track management per branch: ``"score"``, Wald's SPRT on the track score (:func:`manage`,
   :func:`sprt_thresholds`), or ``"counts"``, gnn's rules, the same function
   (:func:`~fedtrack.local_filters.mtt.roles.life.count_life`: M-of-N, or where a tracker of several
   sensors' scans weighs each scan's evidence, Wald's test on it; with gnn's precedence of the
   confirmed tracks in step 3 and P_G = 1, gnn's cost: :func:`mht_params`). A deleted branch
   leaves its track out of the hypotheses that held it. ``"score"`` also keeps each branch's
   existence probability with jipda's survival (:func:`leaf_existence`): a confirmed track is in
   the picture while it is at least 1/2 (:func:`shown`, jipda's rule).
6. :func:`prune`: N-scan pruning (of every track of the best hypothesis only the leaves that
   share its branch ``window - 1`` scans back stay; ``window = 1``: its leaf alone), at most
   ``max_branches`` leaves per track (those of the best hypotheses first); a hypothesis that
   held a removed leaf is dropped, a leaf that no hypothesis holds is removed; a track decided
   in its cluster (one leaf, held by all its hypotheses) leaves it as a cluster of its own.

The picture is the best hypothesis's tracks; with ``picture_delay``, the best hypothesis's a few
scans later, each track as its ancestor at the picture's time was (the N-scan-back decision:
:func:`~fedtrack.local_filters.mtt.tracker.mht_decided`). With ``window = 1``, ``k = 1`` and
``"counts"`` this is gnn (tests/test_mht.py, to 1e-9). The hypotheses are extended scan by scan
(Cox & Hingorani 1996: Murty's k best per hypothesis), so an assignment that leaves its cluster's
k best at one scan cannot come back later: that is what ``k`` bounds; k per cluster (the
track-oriented MHT's structure) keeps the cost linear in the clusters. Defaults and their derivation:
docs/mht.md.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.special import expit

from fedtrack.local_filters.mtt.associators.gnn import k_best_assignments
from fedtrack.local_filters.mtt.associators.jipda import (
    BIRTH_EXISTENCE,
    SHOW,
    SURVIVAL_PER_SECOND,
    scan_constants,
    survival,
)
from fedtrack.local_filters.mtt.config import MHT_WINDOW_MISS, MhtConfig, log_miss_of
from fedtrack.local_filters.pda.association import Constants, existence_update, log_amplitude_ratio


class MhtParams(NamedTuple):
    """What the MHT needs for one scan (built by :func:`mht_params`)."""

    pd: float
    clutter_density: float
    delete_misses: int  # "score": a confirmed branch deleted after this many misses in a row (and its fall)
    window: int  # N: scans back to the branch that N-scan pruning keeps (1: the best leaf only)
    k: int  # global hypotheses kept
    max_branches: int  # leaves kept per track
    management: str  # "score" (SPRT) or "counts" (gnn's M-of-N and precedence)
    pg: float  # gate probability P_G in the miss term
    confirm_score: float  # confirmed at score ln odds(B) + ln((1 - beta) / alpha) (:func:`mht_params`)
    delete_score: float  # a tentative track deleted at score ln odds(B) + ln(beta / (1 - alpha))
    drop_score: float  # SPRT lower threshold ln(beta / (1 - alpha)): a confirmed track's fall from its peak
    amplitude: Constants | None = None  # amplitude model (threshold tau, SNR); None: amplitudes ignored


# a hypothesis less probable than eps = MHT_WINDOW_MISS times its cluster's best is dropped
LOG_UNLIKELY = math.log(MHT_WINDOW_MISS)


def sprt_thresholds(false_track: float, miss: float) -> tuple[float, float]:
    """Wald's SPRT thresholds on a track score (a log-likelihood ratio of target against false
    track): confirm at ``ln((1 - beta) / alpha)``, delete at ``ln(beta / (1 - alpha))``, where
    ``alpha = false_track`` is the probability of confirming a track started on clutter and
    ``beta = miss`` that of deleting a track on a real target (Wald 1947; Blackman & Popoli
    6.2.4)."""
    if not (0.0 < false_track < 1.0 and 0.0 < miss < 1.0 and false_track + miss < 1.0):
        raise ValueError("sprt_thresholds: false_track and miss must be in (0, 1) with a sum below 1")
    return math.log((1.0 - miss) / false_track), math.log(miss / (1.0 - false_track))


# ln of jipda's prior odds that a scan's unused detections hold a new target (BIRTH_EXISTENCE)
LOG_BIRTH_ODDS = math.log(BIRTH_EXISTENCE / (1.0 - BIRTH_EXISTENCE))


def mht_params(settings: MhtConfig, pd: float, clutter_density: float, gate_d2: float, m: int,
               delete_misses: int) -> MhtParams:
    """The MHT's parameters for a scan of measurement size ``m`` gated at ``gate_d2``; ``delete_misses``
    is gnn's. ``"counts"`` management is gnn's model too: its M-of-N rules (the tracker's
    :func:`~fedtrack.local_filters.mtt.roles.life.count_life`) and track precedence, and a gate that holds
    every target detection (``P_G = 1`` in the miss term: gnn's cost), so that window 1 and k 1 are gnn.
    ``"score"``: a track's score is its log posterior odds (:func:`birth_scores`), so Wald's
    thresholds are moved by the prior log odds ``ln odds(B)``: the SPRT on the track's likelihood
    ratio since its birth."""
    c = scan_constants(pd, clutter_density, gate_d2, m)
    confirm, delete = sprt_thresholds(settings.false_track, settings.miss)
    prior = LOG_BIRTH_ODDS if settings.management == "score" else 0.0
    return MhtParams(pd, clutter_density, delete_misses, settings.window, settings.k, settings.max_branches,
                     settings.management, 1.0 if settings.management == "counts" else c.pg, confirm + prior,
                     delete + prior, delete, c)


class MhtState(NamedTuple):
    """The tracker's memory with ``associator = "mht"``: every track's leaves, batched (the
    tracker's ``TrackSet``; ``leaves.ids``: the track of each), their scores and lineage, and the
    kept global hypotheses (best first)."""

    leaves: Any  # TrackSet of every leaf
    score: np.ndarray  # (L,) track score: the log-likelihood ratio of the leaf's history
    peak: np.ndarray  # (L,) the highest score along the leaf's history
    lineage: np.ndarray  # (L, window) branch serials of its ancestors, oldest first, its own last
    hyps: np.ndarray  # (K, L) bool: row r holds the leaves of every cluster's r-th best hypothesis
    value: np.ndarray  # (K, C) each cluster's hypotheses' log-likelihood ratios, best first (-inf: fewer)
    next_branch: int  # the next branch serial
    existence: np.ndarray  # (L,) the leaf's existence probability (:func:`leaf_existence`)
    cluster: np.ndarray  # (L,) the cluster of the leaf's track (:func:`extend_clusters`)


def initial_state(leaves: Any, window: int) -> MhtState:
    """No leaves (``leaves``: an empty ``TrackSet``) and one empty hypothesis."""
    return MhtState(leaves, np.zeros(0), np.zeros(0), np.zeros((0, window), np.int64), np.ones((1, 0), bool),
                    np.zeros((1, 0)), 0, np.zeros(0), np.zeros(0, np.intp))


def score_increments(log_n: np.ndarray, params: MhtParams, amplitude: np.ndarray | None) -> tuple[np.ndarray, float]:
    """Track-score increments: per gated pair ``ln(P_D N(nu; 0, S) / lambda)`` from its
    ``log_n = ln N(nu; 0, S)`` (+ the amplitude log-ratio of its detection ``amplitude``), and a
    miss's ``ln(1 - P_D P_G)``."""
    inc = math.log(params.pd) + log_n - math.log(max(params.clutter_density, 1e-300))
    if amplitude is not None and params.amplitude is not None:
        inc = inc + log_amplitude_ratio(amplitude, params.amplitude)
    return inc, miss_increment(params)


def miss_increment(params: MhtParams) -> float:
    """``ln(1 - P_D P_G)``: the track produced no detection in its gate; finite where ``P_D P_G`` is 1
    (:func:`~..config.log_miss_of`: P_D 1 with ``"counts"``' ``P_G = 1`` made it ``ln 0``, a traceback)."""
    return log_miss_of(params.pd * params.pg)


def birth_scores(params: MhtParams, amplitude: np.ndarray | None, n: int) -> np.ndarray:
    """The scores of ``n`` new tracks, plus their detections' amplitude log-ratios. ``"score"``:
    the prior log odds ``ln odds(B)`` that a detection no track takes is a new target (jipda's
    prior ``B`` of a lone birth, :data:`~.jipda.BIRTH_EXISTENCE`; Blackman & Popoli 6.2's initial
    score ``ln(beta_NT / beta_FA)``); ``"counts"``: 0."""
    score = np.full(n, LOG_BIRTH_ODDS if params.management == "score" else 0.0)
    if amplitude is not None and params.amplitude is not None:
        score = score + log_amplitude_ratio(amplitude, params.amplitude)
    return score


def best_extensions(r: np.ndarray, c: np.ndarray, gain: np.ndarray, k: int,
                    names: np.ndarray | None = None, cache: dict | None = None
                    ) -> tuple[np.ndarray, list[np.ndarray]]:
    """The ``k`` best ways for rows to take one detection each of their candidate pairs
    (``r``, ``c``, ``gain`` over a miss) or miss (gain 0), each
    detection at most once: the total gains, best first, and per way the indices of the pairs
    it takes. Per connected component of the pairs: a component of one row ranks its pairs and
    its miss, a larger one takes Murty's k best; combined by the k best sums. ``cache`` holds
    the components solved already, by the ``names`` of their pairs (ascending): the parents of
    a cluster share most of them."""
    if r.size == 0:
        return np.zeros(1), [np.zeros(0, np.intp)]
    if (r == r[0]).all():  # one row: its miss and each of its pairs, as a component of one row below
        costs, picked = _component_best(r, c, gain, k)
        return -costs, [p[p >= 0] for p in picked]
    _, r_local = np.unique(r, return_inverse=True)
    comp = _pair_components(r_local, np.unique(c, return_inverse=True)[1])
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


def _pair_components(r: np.ndarray, c: np.ndarray) -> np.ndarray:
    """The connected components of pairs (rows ``r``, columns ``c``, both from 0) that share a row
    or a column: per pair the least index of its component (the least label spread a hop a round).
    Not scipy's ``connected_components`` over ``gnn._pair_graph`` (as gnn and jipda use once a
    scan): this runs per cluster and hypothesis on a few pairs, where building the sparse graph
    made mht 20 % slower at 1,000 targets (23.3-24.3 against 19.1-19.4 s CPU)."""
    label = np.arange(r.size)
    while True:
        by_r, by_c = np.full(r.max() + 1, r.size), np.full(c.max() + 1, r.size)
        np.minimum.at(by_r, r, label)
        np.minimum.at(by_c, c, label)
        new = np.minimum(by_r[r], by_c[c])
        if np.array_equal(new, label):
            return label
        label = new


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


def _extend(held: np.ndarray, cand: np.ndarray, n_det: int, g_rows: np.ndarray, g_cols: np.ndarray,
            gain: np.ndarray, confirmed: np.ndarray, params: MhtParams, cache: dict
            ) -> tuple[np.ndarray, list[np.ndarray]]:
    """The k best extensions of one hypothesis (``held``: a mask of its leaves) over the gated
    pairs ``cand`` of its cluster: their gains and chosen pair indices. ``"counts"``: confirmed
    leaves choose first, tentative ones among the detections left (gnn's precedence), each stage
    by its k best."""
    pairs = cand[held[g_rows[cand]]]
    if pairs.size == 0:
        return np.zeros(1), [pairs]
    if params.management != "counts":
        gains, ways = best_extensions(g_rows[pairs], g_cols[pairs], gain[pairs], params.k, pairs, cache)
        return gains, [pairs[w] for w in ways]
    first = pairs[confirmed[g_rows[pairs]]]
    second = pairs[~confirmed[g_rows[pairs]]]
    out_gain, out_ways = [], []
    for g1, w1 in zip(*best_extensions(g_rows[first], g_cols[first], gain[first], params.k, first, cache)):
        taken = first[w1]
        free = np.ones(n_det, bool)
        free[g_cols[taken]] = False
        rest = second[free[g_cols[second]]]
        for g2, w2 in zip(*best_extensions(g_rows[rest], g_cols[rest], gain[rest], params.k, rest, cache)):
            out_gain.append(g1 + g2)
            out_ways.append(np.concatenate([taken, rest[w2]]))
    order = np.argsort(-np.array(out_gain), kind="stable")[:params.k]
    return np.array(out_gain)[order], [out_ways[i] for i in order.tolist()]


class Branches(NamedTuple):
    """Steps 3 and 4: the scan's clusters' kept hypotheses and the branches they use."""

    parent: np.ndarray  # (C,) parent leaf of each child branch
    pair: np.ndarray  # (C,) its gated pair (-1: a miss)
    holds: np.ndarray  # (K, C) bool: the children each rank's hypothesis (of their cluster) holds
    cluster: np.ndarray  # (C,) each child's cluster
    value: np.ndarray  # (K, G) each cluster's hypotheses' values, best first (-inf: fewer than K)
    births: np.ndarray  # (F,) the detections that start a track
    birth_holds: np.ndarray  # (K, F) bool: the hypotheses (ranks of its cluster) that hold each new track
    birth_cluster: np.ndarray  # (F,) each new track's cluster


def extend_clusters(state: MhtState, n_det: int, g_rows: np.ndarray, g_cols: np.ndarray, inc: np.ndarray,
                    miss: float, params: MhtParams) -> Branches:
    """Steps 3 and 4 per cluster: the old clusters joined by the detections their leaves gate
    (a detection gated by none alone) are the scan's clusters; each one's parents are the k best
    combinations of its old clusters' hypotheses (:func:`k_best_sums`, values added: the old
    clusters are independent), each parent extended by its k best assignments of the cluster's
    gated pairs (``g_rows`` leaf, ``g_cols`` detection, score increment ``inc``; ``miss`` a
    miss's), of which the cluster keeps its k best. A hypothesis's value is the log-likelihood
    ratio of its cluster's assignments so far against "every detection clutter": its parents'
    plus this scan's increment of every track it holds (a miss or its detection;
    :func:`value_increments`); only values of one cluster are compared, so each cluster's may
    be offset by a constant. A detection of the cluster that one of its kept hypotheses leaves
    unused starts a track, held by those hypotheses (gnn's one-point start); a new track adds
    nothing, and a track deleted later keeps what it added: two tracks sharing one target's
    detections pay a miss at every scan and lose to one track that takes them all."""
    leaf_miss, gain = value_increments(state.score, g_rows, inc, miss, params)
    n_old, k = state.value.shape[1], params.k
    n = n_old + n_det
    graph = coo_matrix((np.ones(g_rows.size), (state.cluster[g_rows], n_old + g_cols)), shape=(n, n))
    n_groups, label = connected_components(graph, directed=False)
    n_pairs, n_leaves = g_rows.size, state.score.size
    n_valid = np.isfinite(state.value).sum(axis=0)
    group_of = label[state.cluster]
    # simple clusters (at most one old cluster, of one track): ranked at once
    first_leaf = np.unique(state.cluster.astype(np.int64) * (int(state.leaves.ids.max(initial=0)) + 1)
                           + state.leaves.ids) // (int(state.leaves.ids.max(initial=0)) + 1)
    single = np.bincount(first_leaf, minlength=n_old) == 1
    n_members = np.bincount(label[:n_old], minlength=n_groups)
    simple = n_members <= 1
    simple[label[:n_old][~single]] = False
    lone = np.flatnonzero(simple[group_of])
    lone_pairs = np.flatnonzero(simple[group_of[g_rows]])
    values = np.full((k, n_groups), -np.inf)
    keys, key_rank, births, birth_rank = _simple_clusters(state, lone, lone_pairs, label[:n_old], g_rows, g_cols, gain,
                                                          leaf_miss, values)
    alone = np.flatnonzero(n_members[label[n_old:]] == 0)  # a detection that no track gates
    values[0, label[n_old + alone]] = 0.0
    births.append(alone)
    birth_rank.append(np.zeros(alone.size, np.intp))
    # the others: the k best parents, each extended by its k best, the k best kept
    n_complex = int((~simple).sum())
    complex_ = np.full(n_groups, -1)
    complex_[~simple] = np.arange(n_complex)
    members = _members(complex_[label[:n_old]], n_complex)
    dets = _members(complex_[label[n_old:]], n_complex)
    pairs_of = _members(complex_[group_of[g_rows]], n_complex)
    leaves_of = _members(state.cluster, n_old)
    cache: dict = {}
    mask, taken, pair_of = np.zeros(n_leaves, bool), np.zeros(n_det, bool), np.full(n_leaves, -1)
    for g, own, cand, mine in zip(np.flatnonzero(~simple).tolist(), members, pairs_of, dets):
        cand_value, cand_held, cand_pairs = [], [], []
        sums, picks = k_best_sums([-state.value[:n_valid[c], c] for c in own], k)
        for total, ranks in zip(sums.tolist(), picks):
            held = np.concatenate([np.zeros(0, np.intp)] + [
                leaves_of[c][state.hyps[r, leaves_of[c]]] for c, r in zip(own, ranks.tolist())])
            mask[held] = True
            gains, ways = _extend(mask, cand, n_det, g_rows, g_cols, gain, state.leaves.confirmed, params, cache)
            mask[held] = False
            cand_value.extend((leaf_miss[held].sum() - total + gains).tolist())
            cand_held.extend([held] * len(ways))
            cand_pairs.extend(ways)
        cand_value = np.array(cand_value)
        best = np.argsort(-cand_value, kind="stable")[:k]
        best = best[cand_value[best] >= cand_value[best[0]] + LOG_UNLIKELY]
        values[:best.size, g] = cand_value[best]
        for rank, i in enumerate(best.tolist()):
            held, pairs = cand_held[i], cand_pairs[i]
            pair_of[g_rows[pairs]] = pairs
            keys.append(held * (n_pairs + 1) + pair_of[held] + 1)  # leaf * (n_pairs + 1) + pair + 1 (0: a miss)
            pair_of[g_rows[pairs]] = -1
            key_rank.append(np.full(held.size, rank))
            taken[g_cols[pairs]] = True
            births.append(mine[~taken[mine]])
            taken[g_cols[pairs]] = False
            birth_rank.append(np.full(births[-1].size, rank))
    uniq, key_index = np.unique(np.concatenate(keys), return_inverse=True)
    holds = np.zeros((k, uniq.size), bool)
    holds[np.concatenate(key_rank), key_index] = True
    parent_leaf, pair = np.divmod(uniq, n_pairs + 1)
    born, born_index = np.unique(np.concatenate(births), return_inverse=True)
    birth_holds = np.zeros((k, born.size), bool)
    birth_holds[np.concatenate(birth_rank), born_index] = True
    return Branches(parent_leaf, pair - 1, holds, group_of[parent_leaf], values, born, birth_holds, label[n_old + born])


def _simple_clusters(state: MhtState, lone: np.ndarray, lone_pairs: np.ndarray, cluster_group: np.ndarray,
                     g_rows: np.ndarray, g_cols: np.ndarray, gain: np.ndarray, leaf_miss: np.ndarray,
                     values: np.ndarray) -> tuple[list, list, list, list]:
    """The scan's clusters of one track (its leaves ``lone``, their gated pairs ``lone_pairs``),
    all at once: each of its old cluster's hypotheses (that track's leaf, or none) extended by
    the leaf's miss and each of its pairs, the cluster's k best kept (ties as the loop of
    :func:`extend_clusters` breaks them: the better parent, then the miss, then the pairs in
    order), their values written into ``values`` (rank, cluster); the children's keys and ranks,
    and the detections each leaves to new tracks with the ranks that hold them."""
    k, n_pairs = values.shape[0], g_rows.size
    held_by = np.argmax(state.hyps[:, lone], axis=0)  # a track's leaf is held by one hypothesis of its cluster
    clusters = np.unique(state.cluster[lone])
    with_leaf = np.zeros((state.value.shape[0], clusters.size), bool)
    with_leaf[held_by, np.searchsorted(clusters, state.cluster[lone])] = True
    empty_rank, empty_of = np.nonzero(np.isfinite(state.value[:, clusters]) & ~with_leaf)  # the track absent
    leaf = np.concatenate([np.full(empty_rank.size, -1), lone, g_rows[lone_pairs]])
    parent = np.concatenate([empty_rank, held_by, held_by[np.searchsorted(lone, g_rows[lone_pairs])]])
    pair = np.concatenate([np.full(empty_rank.size + lone.size, -1), lone_pairs])
    cluster = np.concatenate([clusters[empty_of], state.cluster[leaf[empty_rank.size:]]])
    value = (np.concatenate([np.zeros(empty_rank.size), leaf_miss[lone], leaf_miss[g_rows[lone_pairs]]])
             + state.value[parent, cluster]) + np.concatenate([np.zeros(empty_rank.size + lone.size), gain[lone_pairs]])
    group = cluster_group[cluster]
    order = np.lexsort((pair, parent, -value, group))
    first = np.r_[True, group[order][1:] != group[order][:-1]]
    rank = np.arange(order.size) - np.maximum.accumulate(np.where(first, np.arange(order.size), 0))
    top = value[order][np.maximum.accumulate(np.where(first, np.arange(order.size), 0))]
    kept = (rank < k) & (value[order] >= top + LOG_UNLIKELY)
    order, rank = order[kept], rank[kept]
    leaf, pair, group = leaf[order], pair[order], group[order]
    values[rank, group] = value[order]
    # each kept option leaves its cluster's other detections to new tracks
    span = int(g_cols.max(initial=0)) + 1
    det_group, det = np.divmod(np.unique(cluster_group[state.cluster[g_rows[lone_pairs]]].astype(np.int64) * span
                                         + g_cols[lone_pairs]), span)
    start = np.searchsorted(det_group, group)
    count = np.searchsorted(det_group, group, side="right") - start
    option = np.repeat(np.arange(group.size), count)
    d = det[np.repeat(start, count) + np.arange(option.size) - np.repeat(np.cumsum(count) - count, count)]
    taken = np.full(pair.size, -1)
    taken[pair >= 0] = g_cols[pair[pair >= 0]]
    left = d != taken[option]
    kept = leaf >= 0
    return ([leaf[kept] * (n_pairs + 1) + pair[kept] + 1], [rank[kept]], [d[left]], [rank[option[left]]])


def _members(label: np.ndarray, n: int) -> list[np.ndarray]:
    """The indices of each of ``n`` labels (ascending within a label; a label -1 is left out)."""
    order = np.argsort(label, kind="stable")
    order = order[label[order] >= 0]
    return np.split(order, np.searchsorted(label[order], np.arange(1, n)))


def value_increments(score: np.ndarray, g_rows: np.ndarray, inc: np.ndarray, miss: float, params: MhtParams
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Each leaf's value increment if it misses (L,), and each gated pair's gain over that miss
    (K,). ``"counts"``: the score increments (``miss``; ``inc - miss``). ``"score"``: a track's
    score is the log odds that it is a target rather than clutter, so the hypothesis keeps both
    (the track, or its detections clutter): its log-likelihood ratio is
    ``softplus(score) = ln(1 + e^score)``, and a scan adds ``softplus(score + increment) -
    softplus(score)``. An established track (score >> 0) gains its increment over its miss; a
    track born last scan (score ``ln odds(B)`` = -2.2) about its increment plus that prior, so
    a target's detection goes to the track that holds it unless it fits a track born beside it
    better by some 4 nats (Blackman & Popoli 6.2: a global hypothesis's score is the sum of its
    tracks' scores, a track below 0 left out as false)."""
    if params.management == "counts":
        return np.full(score.size, miss), inc - miss
    base = np.logaddexp(0.0, score)
    leaf_miss = np.logaddexp(0.0, score + miss) - base
    return leaf_miss, np.logaddexp(0.0, score[g_rows] + inc) - base[g_rows] - leaf_miss[g_rows]


def manage(params: MhtParams, confirmed: np.ndarray, score: np.ndarray, peak: np.ndarray, misses: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """Step 5 with ``"score"``: each branch's confirmation and whether it stays. Confirmed once its
    score reaches the SPRT's upper threshold (moved by the birth prior, :func:`mht_params`); a
    tentative branch deleted at the lower one, a
    confirmed one when its score has fallen that far below its peak (the test restarted at the
    peak: "a false track since then") and it has missed ``delete_misses`` scans in a row (the
    tracker's rule, which for a tracker of every sensor's scans is the fusion centre's: misses
    over the merged stream). ``"counts"`` is gnn's rule itself
    (:func:`fedtrack.local_filters.mtt.roles.life.count_life`, in the tracker)."""
    confirmed = confirmed | (score >= params.confirm_score)
    kept = (score - peak > params.drop_score) | (misses < params.delete_misses)
    return confirmed, np.where(confirmed, kept, score > params.delete_score)


def leaf_existence(parent: np.ndarray, log_lr: np.ndarray, dt: float) -> np.ndarray:
    """Each branch's existence probability: its parent's ``parent`` predicted over ``dt`` with
    jipda's survival ``p11 = exp(-dt / MEAN_LIFETIME)`` (:func:`~.jipda.survival`; targets die) and
    updated with the branch's score increment ``log_lr`` (its detection's likelihood ratio or the
    miss's ``ln(1 - P_D P_G)``): paper 001's IPDA existence, eqs (8) and (15), along the branch's
    one detection history (JIPDA's at one hypothesis); a new track's: :func:`birth_existence`. Unlike
    the score, which sums the likelihood ratios since birth, it falls after a target's death as
    fast as the misses say (its odds before a scan are at most ``p11 / (1 - p11)``)."""
    return existence_update(parent, log_lr, survival(dt, 1.0, SURVIVAL_PER_SECOND), 0.0)


def birth_existence(score: np.ndarray) -> np.ndarray:
    """New tracks' existence from their birth scores (:func:`birth_scores`, log odds): jipda's
    ``BIRTH_EXISTENCE`` = 0.1, moved by the detection's amplitude ratio."""
    return expit(score)


def shown(management: str, confirmed: np.ndarray, existence: np.ndarray) -> np.ndarray:
    """The confirmed tracks the picture shows: ``"score"``, while their existence is at least
    ``SHOW`` = 1/2 (jipda's rule: GOSPA with alpha = 2 charges a false and a missed target alike,
    so a track is worth showing while it more likely than not exists); below, the track stays
    confirmed and kept, out of the picture, until a detection brings it back. ``"counts"``: every
    confirmed track (gnn's pictures)."""
    return confirmed & (existence >= SHOW) if management == "score" else confirmed


def prune(state: MhtState, alive: np.ndarray, params: MhtParams) -> tuple[MhtState, np.ndarray]:
    """Step 6, per cluster: the branches not ``alive`` leave their hypotheses, a hypothesis equal
    to a better one of its cluster is dropped; N-scan pruning around the best hypotheses (row 0)
    and the cap on leaves per track; a hypothesis that held a removed leaf is dropped, a leaf
    that no hypothesis holds is removed; then a track decided in its cluster (one leaf, held by
    every hypothesis of it) leaves it as a cluster of its own (the rest's values change by a
    constant). Returns the state and the indices of the leaves kept."""
    ids, cl = state.leaves.ids, state.cluster
    valid = np.isfinite(state.value)
    hyps = state.hyps & alive & valid[:, cl]
    for c in np.flatnonzero(valid.sum(axis=0) > 1).tolist():  # a hypothesis equal to a better one
        mine = np.flatnonzero(cl == c)
        ranks = np.flatnonzero(valid[:, c])
        _, first = np.unique(np.packbits(hyps[np.ix_(ranks, mine)], axis=1), axis=0, return_index=True)
        valid[ranks, c] = np.isin(np.arange(ranks.size), first)
    hyps &= valid[:, cl]
    keep = alive.copy()
    if ids.size:
        best = np.flatnonzero(hyps[0])  # N-scan pruning around the best hypotheses' branches
        root = np.full(int(ids.max()) + 1, -1)
        root[ids[best]] = state.lineage[best, 0]
        keep &= (root[ids] < 0) | (state.lineage[:, 0] == root[ids])
        # the cap: per track, the leaves of the best hypotheses first
        rank = np.where(hyps.any(axis=0), np.argmax(hyps, axis=0), hyps.shape[0])
        order = np.lexsort((rank, ids))
        first_of = np.r_[True, ids[order][1:] != ids[order][:-1]]
        start = np.maximum.accumulate(np.where(first_of, np.arange(order.size), 0))
        within = np.empty(order.size, np.int64)
        within[order] = np.arange(order.size) - start
        keep &= within < params.max_branches
        r, leaf = np.nonzero(hyps & ~keep)
        valid[r, cl[leaf]] = False
        hyps &= valid[:, cl]
        keep &= hyps.any(axis=0)
    new_rank = np.cumsum(valid, axis=0) - 1  # each cluster's kept hypotheses, best first
    packed, value = np.zeros_like(hyps), np.full(state.value.shape, -np.inf)
    r, leaf = np.nonzero(hyps)
    packed[new_rank[r, cl[leaf]], leaf] = True
    r, c = np.nonzero(valid)
    value[new_rank[r, c], c] = state.value[r, c]
    idx = np.flatnonzero(keep)
    packed, cl = packed[:, idx], cl[idx]
    # a track decided in its cluster leaves it
    per_track = np.bincount(ids[idx], minlength=int(ids.max(initial=-1)) + 1)[ids[idx]]
    decided = (per_track == 1) & (packed.sum(axis=0) == valid.sum(axis=0)[cl])
    cl = np.where(decided, value.shape[1] + np.arange(idx.size), cl)
    value = np.concatenate([value, np.full((value.shape[0], idx.size), -np.inf)], axis=1)
    value[0, value.shape[1] - idx.size + np.arange(idx.size)] = 0.0
    packed[1:, decided] = False
    used, cl = np.unique(cl, return_inverse=True)
    value = value[:, used]
    rows = max(1, int(np.isfinite(value).sum(axis=0).max(initial=1)))
    return MhtState(state.leaves.take(idx), state.score[idx], state.peak[idx], state.lineage[idx], packed[:rows],
                    value[:rows], state.next_branch, state.existence[idx], cl), idx


def k_best_sums(lists: list[np.ndarray], k: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` least sums taking one entry of each ascending list: the sums (k',) ascending
    and the chosen index per list (k', len(lists)). The k best of ``A + B`` lie among the first
    k of each, so lists are combined pairwise on their k x k outer sums."""
    total = np.zeros(1)
    picks = np.zeros((1, 0), np.intp)
    for values in lists:
        v = values[:k]
        outer = (total[:, None] + v[None, :]).ravel()
        order = np.argsort(outer, kind="stable")[:k]
        parent, choice = np.divmod(order, v.size)
        total = outer[order]
        picks = np.concatenate([picks[parent], choice[:, None]], axis=1)
    return total, picks
