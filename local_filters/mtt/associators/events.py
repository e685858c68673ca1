"""Joint association events of one cluster of tracks and detections, for :mod:`.jipda`: exact
enumeration of every event (:func:`enumerate_clusters`, batched over clusters of one shape) and
the ``k`` most likely events (:func:`k_best_clusters`: a bounded breadth-first search,
:func:`top_events`, or Murty's partitioning, :func:`~.gnn.k_best_assignments`); docs/jipda.md.

A cluster is ``log_pair`` (a, b) (the log pair factors, ``-inf`` where not gated) and ``log_miss``
(a,) (each track's "missed" log factor); an event gives each track at most one detection and each
detection at most one track, and its log weight is the sum of its tracks' factors."""

from __future__ import annotations

import math
from functools import cache
from typing import NamedTuple

import numpy as np
from scipy.sparse import csc_matrix, csr_matrix

from fedtrack.local_filters.mtt.associators.gnn import k_best_assignments


@cache
def event_count(a: int, b: int) -> int:
    """Joint events of ``a`` tracks and ``b`` detections: partial matchings, ``sum_k C(a,k) b!/(b-k)!``."""
    return sum(math.comb(a, k) * math.perm(b, k) for k in range(min(a, b) + 1))


@cache
def joint_events(a: int, b: int) -> np.ndarray:
    """Every joint event of ``a`` tracks and ``b`` detections, (E, a): track ``i`` takes detection
    ``T[e, i]`` (``b``: none); no detection twice."""
    table = np.zeros((1, 0), dtype=np.intp)
    for _ in range(a):
        ext = np.repeat(table, b + 1, axis=0)
        col = np.tile(np.arange(b + 1), table.shape[0])
        ok = (col == b) | ~np.any(ext == col[:, None], axis=1)
        table = np.concatenate([ext, col[:, None]], axis=1)[ok]
    table.setflags(write=False)
    return table


@cache
def _event_slots(a: int, b: int) -> np.ndarray:
    """(E, a): where each event's outcome of track ``i`` sits in a cluster's flattened ``(a, b + 1)``
    log weights, ``i (b + 1) + T[e, i]`` (:func:`joint_events`)."""
    slots = np.arange(a) * (b + 1) + joint_events(a, b)
    slots.setflags(write=False)
    return slots


@cache
def _marginal_map(a: int, b: int) -> csc_matrix:
    """(a (b + 1), E) indicator of "event e gives track i the outcome o" (o = b: none), held
    transposed (the product of :func:`enumerate_clusters` is over its columns)."""
    slots = _event_slots(a, b)
    e = slots.shape[0]
    return csr_matrix((np.ones(e * a), (np.repeat(np.arange(e), a), slots.ravel())), shape=(e, a * (b + 1))).T


def enumerate_clusters(log_pair: np.ndarray, log_miss: np.ndarray) -> np.ndarray:
    """Exact marginals of clusters of one shape: ``log_pair`` (C, a, b) (``-inf`` where not gated),
    ``log_miss`` (C, a); returns ``W`` (C, a, b + 1), column ``b`` the "missed" marginal ``W_i0``."""
    c, a, b = log_pair.shape
    L = np.concatenate([log_pair, log_miss[..., None]], axis=-1).reshape(c, a * (b + 1))
    lw = L[:, _event_slots(a, b)].sum(axis=-1)  # (C, E) log P(e) unnormalized
    w = np.exp(lw - lw.max(axis=1, keepdims=True))  # "all missed" is always finite
    w /= w.sum(axis=1, keepdims=True)
    return np.asarray((_marginal_map(a, b) @ w.T).T).reshape(c, a, b + 1)


def k_best_clusters(log_pair: np.ndarray, log_miss: np.ndarray, k: int) -> np.ndarray:
    """Marginals ``W`` (C, a, b + 1) of clusters padded to one shape (``log_pair`` (C, a, b),
    ``log_miss`` (C, a); a padding track has no gated pair and ``log_miss`` 0, a padding detection
    no gated pair: neither changes a cluster's events or their weights), each from its ``k`` most
    likely joint events, normalized over them: the event sum truncated to its largest terms.
    The events come from :func:`top_events` (bounded search, the clusters as one batch); for a
    cluster whose frontier would exceed :data:`FRONTIER_MAX`, from Murty's partitioning
    (:func:`~.gnn.k_best_assignments`, a private "missed" column per track) over its tracks and
    detections that have a gated pair. Both give the same ``k`` events (ties aside) in the same
    order."""
    c, _, b = log_pair.shape
    found = top_events(log_pair, log_miss, k)
    W = _event_marginals(found.cluster, found.score, found.event, c, b)
    for i in np.flatnonzero(found.overflow):
        gated = np.isfinite(log_pair[i])
        tr, det = np.flatnonzero(gated.any(axis=1)), np.flatnonzero(gated.any(axis=0))
        lp = log_pair[i][np.ix_(tr, det)]
        cost = np.full((tr.size, det.size + tr.size), np.inf)
        cost[:, :det.size] = np.where(np.isfinite(lp), -lp, np.inf)  # an ungated pair: forbidden
        cost[np.arange(tr.size), det.size + np.arange(tr.size)] = -log_miss[i, tr]
        totals, events = k_best_assignments(cost, k)
        one = _event_marginals(np.zeros(totals.size, np.intp), -totals, np.minimum(events, det.size), 1, det.size)[0]
        W[i] = 0.0
        W[i, :, b] = 1.0  # a track without a gated pair is missed in every event
        W[i, tr[:, None], det] = one[:, :-1]
        W[i, tr, b] = one[:, -1]
    return W


def _event_marginals(cluster: np.ndarray, score: np.ndarray, event: np.ndarray, c: int, b: int) -> np.ndarray:
    """``W`` (c, a, b + 1) from each cluster's events (``cluster`` ascending, the most likely of a
    cluster first; ``event`` (R, a), ``b`` missed): their weights ``exp(score)`` normalized per
    cluster, summed per track and outcome in event order."""
    a = event.shape[1]
    start = np.searchsorted(cluster, np.arange(c + 1))
    top = np.full(c, -np.inf)
    np.maximum.at(top, cluster, score)
    weights = np.exp(score - top[cluster])
    for i in range(c):  # each cluster's sum over its own slice, as one cluster alone sums it
        weights[start[i]:start[i + 1]] /= weights[start[i]:start[i + 1]].sum()
    slot = (cluster[:, None] * a + np.arange(a)) * (b + 1) + event
    W = np.bincount(slot.ravel(), np.repeat(weights, a), minlength=c * a * (b + 1))
    return np.asarray(W, dtype=float).reshape(c, a, b + 1)  # bincount of nothing is integer


# Largest frontier of :func:`top_events` (a track's extensions of the partial events kept so far)
# before it hands the cluster to Murty: 20,000 partial events of up to 12 tracks, about 2 MB.
FRONTIER_MAX = 20_000


class TopEvents(NamedTuple):
    """The most likely joint events of a batch of clusters, by cluster, the most likely first."""

    cluster: np.ndarray  # (R,) each event's cluster, ascending
    score: np.ndarray  # (R,) its log weight
    event: np.ndarray  # (R, a) each track's outcome (``b``: missed)
    overflow: np.ndarray  # (C,) the cluster's frontier outgrew FRONTIER_MAX: no events found


def top_events(log_pair: np.ndarray, log_miss: np.ndarray, k: int) -> TopEvents:
    """The ``k`` most likely joint events of each of ``C`` clusters of one shape (``log_pair``
    (C, a, b), ``log_miss`` (C, a); fewer if fewer exist), most likely first, ties in event order;
    none for a cluster whose frontier outgrows :data:`FRONTIER_MAX`. Breadth-first over each
    cluster's tracks with exact pruning: a partial event over tracks ``0..i`` is dropped when its
    bound ``score + sum_{t > i} max_o L[t, o]`` (no track beyond ``i`` can do better than its best
    outcome) is below the ``k``-th largest among its cluster's partial events' greedy completions
    (:func:`_greedy_completion`), each of which is a distinct full event (so ``k`` full events beat
    every completion of the dropped one). The clusters' partial events are one batch, each
    cluster's kept together in event order; a cluster leaves the search after its last track that
    is not padding (no gated pair, ``log_miss`` 0: missed at log weight 0 in every event)."""
    c, a, b = log_pair.shape
    L = np.concatenate([log_pair, log_miss[..., None]], axis=2)  # (C, a, b + 1), ``b`` missed (finite)
    # widest gap between a track's best outcome and its miss first: the bound tightens fastest
    perm = np.argsort(log_miss - L.max(axis=2), axis=1, kind="stable")
    L = np.take_along_axis(L, perm[..., None], axis=1)
    gated = np.isfinite(L)
    # the clusters deepest first (depth: tracks up to the last one that is not padding), so that
    # those still searched at track ``i``, the first ``live[i]``, hold a prefix of the partial events
    padding = ~np.any(gated[:, :, :b], axis=2) & (L[:, :, b] == 0.0)
    depth = a - np.cumprod(padding[:, ::-1], axis=1).sum(axis=1)
    rank = np.argsort(-depth, kind="stable")
    L, gated = L[rank], gated[rank]
    live = np.searchsorted(-depth[rank], -np.arange(a + 1))  # clusters deeper than i
    best_tail = np.zeros((c, a + 1))  # sum_{t >= i} max_o L[t, o]
    best_tail[:, :a] = np.cumsum(L.max(axis=2)[:, ::-1], axis=1)[:, ::-1]
    bit = _outcome_bits(b)
    # each track's outcomes, most likely first (ties: lower index), up to its miss (always free):
    # their bits (C, n_t) and log weights (C n_t,), for the greedy completions
    pref = np.argsort(-L, axis=2, kind="stable")
    reach = np.argmax(pref == b, axis=2).max(axis=0) + 1  # (a,) the longest list up to the miss
    prefs = [(bit[pref[:, t, :n]], np.take_along_axis(L[:, t], pref[:, t, :n], axis=1).ravel())
             for t, n in enumerate(reach.tolist())]
    cl = np.arange(c)  # each partial event's cluster (in depth order)
    parents, outcomes = [], []  # per track, each partial event's parent (the previous track's) and outcome
    score = np.zeros(c)
    used = np.zeros(c, dtype=bit.dtype)  # the detections a partial event gave its tracks, as bits
    overflow = np.zeros(c, dtype=bool)
    done = [(cl[:0], score[:0], np.zeros((0, a), dtype=np.intp))]  # the clusters that left the search:
    # their partial events' clusters, scores and outcomes
    for i in range(a + 1):
        cut = int(np.searchsorted(cl, live[i]))
        if cut < cl.size or i == a:
            done.append((cl[cut:], score[cut:], _trace(parents, outcomes, np.arange(cut, cl.size), a, b)))
            cl, score, used = cl[:cut], score[:cut], used[:cut]
        if not cl.size:
            break
        p, o = np.nonzero(gated[cl, i] & ((used[:, None] & bit) == 0))  # "missed" (bit 0) is never used
        score = score[p] + L[cl[p], i, o]
        cl, used = cl[p], used[p] | bit[o]
        count = np.bincount(cl, minlength=c)
        wide = count > k
        if np.any(count > FRONTIER_MAX):
            overflow |= count > FRONTIER_MAX
            wide &= ~overflow
            keep = ~overflow[cl]
        elif not np.any(wide):
            parents.append(p)
            outcomes.append(o)
            continue
        else:
            keep = np.ones(cl.size, dtype=bool)
        sub = np.flatnonzero(wide[cl])
        if sub.size:  # each wide cluster's floor: the k-th largest of its partial events' completions
            csub = cl[sub]
            total = _greedy_completion(prefs[i + 1:], live[i + 1:a], csub, used[sub], score[sub])
            floor = np.zeros(c)
            start = np.searchsorted(csub, np.arange(c))
            for j in np.flatnonzero(wide).tolist():
                own = total[start[j]:start[j] + count[j]]
                floor[j] = np.partition(own, count[j] - k)[count[j] - k]
            keep[sub] = score[sub] + best_tail[csub, i + 1] >= floor[csub]
        parents.append(p[keep])
        outcomes.append(o[keep])
        score, cl, used = score[keep], cl[keep], used[keep]
    cl, score, table = (np.concatenate(u) for u in zip(*done))
    cl = rank[cl]
    order = np.lexsort((-score, cl))
    first = np.searchsorted(cl[order], np.arange(c))
    order = order[np.arange(order.size) - first[cl[order]] < k]
    event = np.take_along_axis(table[order], np.argsort(perm, axis=1)[cl[order]], axis=1)
    overflowed = np.zeros(c, dtype=bool)
    overflowed[rank] = overflow
    return TopEvents(cl[order], score[order], event, overflowed)


def _trace(parents: list[np.ndarray], outcomes: list[np.ndarray], at: np.ndarray, a: int, b: int) -> np.ndarray:
    """The outcomes (len(at), a) of the partial events ``at`` over the first ``len(parents)``
    tracks, back along their parents; the tracks after them missed (``b``)."""
    table = np.full((at.size, a), b, dtype=np.intp)
    for i in range(len(parents) - 1, -1, -1):
        table[:, i] = outcomes[i][at]
        at = parents[i][at]
    return table


def _outcome_bits(b: int) -> np.ndarray:
    """Each outcome's bit in a set of used detections (b + 1,): ``1 << j`` for detection ``j``, 0
    for "missed"; ``uint64`` up to 64 detections, Python integers beyond."""
    if b <= 64:
        return np.append(np.left_shift(np.uint64(1), np.arange(b, dtype=np.uint64)), np.uint64(0))
    return np.array([1 << j for j in range(b)] + [0], dtype=object)


def _greedy_completion(prefs: list[tuple[np.ndarray, np.ndarray]], live: np.ndarray, cl: np.ndarray,
                       used: np.ndarray, score: np.ndarray) -> np.ndarray:
    """Log weight of each partial event (its cluster ``cl``, ascending; its ``used`` detections as
    bits; its ``score``) completed greedily: each later track takes its most likely outcome that no
    earlier track took, the first free one of its outcomes ``prefs[t]`` (their bits (C, n), most
    likely first, ties by index, up to the miss; their log weights (C n,)); only clusters
    ``< live[t]`` have a track ``t`` that is not padding (the others' is missed at log weight 0).
    Distinct partial events give distinct full events."""
    total = score.copy()
    for (bits, value), n in zip(prefs, live.tolist()):
        m = int(np.searchsorted(cl, n))
        if not m:
            break
        at = cl[:m] * bits.shape[1] + np.argmax((used[:m, None] & bits[cl[:m]]) == 0, axis=1)
        total[:m] += value[at]
        used[:m] |= bits.ravel()[at]
    return total
