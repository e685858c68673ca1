"""``[mtt] associator = "gnn"``: global nearest neighbour (the tracker's :class:`Associator`).

Cost of a gated pair: ``-2 ln N(nu_ij; 0, S_i) + 2 ln(lambda (1 - P_D) / P_D)`` =
``d2_ij + ln det(2 pi S_i) + 2 ln(lambda (1 - P_D) / P_D)``, minus twice the log-likelihood ratio
of "track i made detection j" against "detection j is clutter and track i was missed"; a pair
whose cost is not negative is not assigned. Confirmed tracks take their detections first
(:func:`assign_by_precedence`); the assignment is solved per connected component of the gating
graph (:func:`assign`), so a scan of many well separated targets costs many tiny assignments.
Hard: each track gets at most one detection (weight 1); a detection it takes starts no track.
"""

from __future__ import annotations

import heapq
import itertools
import math
from functools import cache

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from fedtrack.local_filters.mtt.association import Association, AssociationInput, Associator


def assign(n_tracks: int, n_detections: int, rows: np.ndarray, cols: np.ndarray, cost: np.ndarray) -> np.ndarray:
    """Global nearest neighbour over candidate pairs (``rows``, ``cols``) with negative ``cost``:
    the indices of the chosen pairs. Solved per connected component of the pair graph: a
    component of one pair takes it, one of a single track or a single detection its cheapest
    pair, one of at most ``SMALL_COMPONENT`` on either side its best enumerated matching, the
    others ``linear_sum_assignment``. When no track and no detection is in two pairs (the
    fusion centre's few new local tracks of a scan, mostly), every pair is taken at once."""
    usable = (cost < 0.0).nonzero()[0]
    if usable.size == 0:
        return usable
    r, c = rows[usable], cols[usable]
    if np.bincount(r).max() == 1 and np.bincount(c).max() == 1:
        return usable
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
    full = (~star).nonzero()[0]  # full components are contiguous runs of pairs
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
            if n_r[k] * n_c[k] > DENSE_ENTRIES:
                chosen.append(usable[s:e][_assign_greedy(local_r[s:e], local_c[s:e], cost[usable[s:e]])])
                continue
            sub = np.zeros((n_r[k], n_c[k]))
            pair = np.full((n_r[k], n_c[k]), -1)
            sub[local_r[s:e], local_c[s:e]] = cost[usable[s:e]]
            pair[local_r[s:e], local_c[s:e]] = usable[s:e]
            ri, ci = linear_sum_assignment(sub)
            picked = pair[ri, ci]
            chosen.append(picked[picked >= 0])
    return np.concatenate(chosen)


# A component of more than this many (track, detection) entries is matched greedily on its pairs
# (:func:`_assign_greedy`), not optimally on a dense matrix: a crowd of detections each within the
# gate of a few others' tracks (or, for two-point starts, within max_speed of a few starts) links a
# whole scan into one component, whose dense matrices (a float and an index an entry) took 670 MB
# for a grid of 6,000 detections, 4.5 GB and 22 s for the pairs of 16,000 two-point starts, and
# would take 275 GB for a scan of the wire's 131,072 detections (an exact sparse solver,
# LAPJVsp, took 63 s on those 16,000 starts). 2^22 entries (64 MB) is a component of 2,048 x
# 2,048, far beyond any honest cluster (tens of tracks): every smaller one is solved as before.
DENSE_ENTRIES = 1 << 22


def _assign_greedy(r: np.ndarray, c: np.ndarray, cost: np.ndarray) -> np.ndarray:
    """The indices of the pairs (``r``, ``c``) chosen cheapest first (the first of equal ones), each
    while its track and its detection are both free: a maximal matching in time O(P log P) and
    memory linear in the pairs ``P``, not the least-cost one."""
    track_free, det_free = [True] * (int(r.max()) + 1), [True] * (int(c.max()) + 1)
    rows, cols, out = r.tolist(), c.tolist(), []
    for k in np.argsort(cost, kind="stable").tolist():
        i, j = rows[k], cols[k]
        if track_free[i] and det_free[j]:
            track_free[i] = det_free[j] = False
            out.append(k)
    return np.array(sorted(out), dtype=np.int64)


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
        sel = (shape == code).nonzero()[0]
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


def assign_by_precedence(n_detections: int, rows: np.ndarray, cols: np.ndarray, cost: np.ndarray,
                         confirmed: np.ndarray) -> np.ndarray:
    """Confirmed tracks take their detections first, tentative tracks share what is left (so a
    tentative track started on clutter never takes a confirmed track's detection). Returns the
    indices of the chosen pairs (``rows``, ``cols``)."""
    n = confirmed.size
    first = confirmed[rows].nonzero()[0]
    picked = first[assign(n, n_detections, rows[first], cols[first], cost[first])]
    free = np.ones(n_detections, bool)
    free[cols[picked]] = False
    second = (~confirmed[rows] & free[cols]).nonzero()[0]
    return np.concatenate([picked, second[assign(n, n_detections, rows[second], cols[second], cost[second])]])


def associate(inp: AssociationInput) -> Association:
    """The global-nearest-neighbour assignment of one scan."""
    if inp.pd >= 1.0:
        bias = -1e6  # no missed detections: any gated pair beats a miss
    else:
        bias = 2.0 * math.log(max(inp.clutter_density, 1e-300) * (1.0 - inp.pd) / inp.pd)
    cost = -2.0 * inp.log_likelihood + bias
    chosen = assign_by_precedence(inp.n_detections, inp.rows, inp.cols, cost, inp.confirmed)
    chosen = chosen[np.argsort(inp.rows[chosen])]
    claimed = np.zeros(inp.n_detections, bool)
    claimed[inp.cols[chosen]] = True
    return Association(chosen, np.ones(chosen.size), claimed)


# ---------------------------------------------------------------- k best assignments
#
# Murty (1968), "An algorithm for ranking all the assignments in order of increasing cost": the
# best assignment of a problem is found by ``scipy.optimize.linear_sum_assignment``; after a
# solution ``(r_1, c_1) .. (r_n, c_n)`` is taken, its problem is split into ``n`` sub-problems,
# the i-th forcing ``(r_1, c_1) .. (r_{i-1}, c_{i-1})`` and forbidding ``(r_i, c_i)``: they
# partition the remaining assignments, so the next best is the best of the sub-problems' optima
# (a priority queue). Forbidden entries are ``+inf``; a sub-problem without a finite assignment
# is dropped. A queued sub-problem is kept as its forbidden entries and its count of forced rows
# (rows ``0..i-1`` keep the columns of the solution it came from), not as a copy of its matrix:
# the queue holds O(n) numbers per sub-problem instead of O(n m) (a cluster of 300 tracks in heavy
# clutter queued gigabytes of matrices). A sub-problem is solved without its forced rows and their
# columns (Miller, Stone and Cox 1997's reduction): ``n - i`` rows instead of ``n``.


def k_best_assignments(cost: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` (or fewer, if fewer exist) least-cost assignments of every row of ``cost``
    (n, m), n <= m, to distinct columns (``+inf``: forbidden), cheapest first: their costs
    (k',) and each row's column (k', n)."""
    n, m = cost.shape
    if n > m:
        raise ValueError(f"k_best_assignments: {n} rows and {m} columns (rows must not exceed columns)")
    if n == 0:
        return np.zeros(1), np.zeros((1, 0), np.intp)
    costs: list[float] = []
    sols: list[np.ndarray] = []
    first = _solve(cost)
    if first is None:
        return np.zeros(0), np.zeros((0, n), np.intp)
    # (cost, tie-break, columns, the sub-problem's forbidden entries, rows forced)
    heap: list[tuple[float, int, np.ndarray, tuple[tuple[int, int], ...], int]] = [(first[0], 0, first[1], (), 0)]
    serial = 1
    rows = np.arange(n)
    while heap and len(costs) < k:
        total, _, cols, forbidden, fixed = heapq.heappop(heap)
        costs.append(total)
        sols.append(cols)
        if len(costs) == k:
            break  # its sub-problems could only rank assignments beyond the k-th
        work = cost.copy()
        for r, c in forbidden:
            work[r, c] = np.inf
        free = np.ones(m, dtype=bool)
        free[cols[:fixed]] = False
        for i in range(fixed, n):  # sub-problem i: rows 0..i-1 keep cols, (i, cols[i]) forbidden
            c = int(cols[i])
            kept = work[i, c]
            work[i, c] = np.inf
            found = _solve_rest(work, i, free, cols, rows)
            work[i, c] = kept
            if found is not None:
                heapq.heappush(heap, (found[0], serial, found[1], forbidden + ((i, c),), i))
                serial += 1
            free[c] = False
    return np.array(costs), np.array(sols, dtype=np.intp).reshape(len(sols), n)


def _solve_rest(work: np.ndarray, i: int, free: np.ndarray, cols: np.ndarray, rows: np.ndarray
                ) -> tuple[float, np.ndarray] | None:
    """The optimal assignment with rows ``0..i-1`` kept at ``cols``: rows ``i..`` over the ``free``
    columns; its total over every row (None if none is finite: the kept rows' entries are)."""
    columns = np.flatnonzero(free)
    rest = _solve(work[i:][:, columns])
    if rest is None:
        return None
    full = cols.copy()
    full[i:] = columns[rest[1]]
    return float(work[rows, full].sum()), full  # summed over every row, as the whole problem's would be


def _solve(cost: np.ndarray) -> tuple[float, np.ndarray] | None:
    """The optimal assignment (total cost, each row's column), None if none is finite."""
    try:
        rows, cols = linear_sum_assignment(cost)
    except ValueError:  # scipy: "cost matrix is infeasible"
        return None
    total = float(cost[rows, cols].sum())
    return (total, cols) if np.isfinite(total) else None


GNN = Associator("gnn", associate)
