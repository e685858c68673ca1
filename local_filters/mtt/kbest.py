"""The k best assignments of a rectangular cost matrix (Murty's algorithm) and the k best sums
of independent sorted lists: the global-hypothesis search of the MHT tracker (:mod:`.mht`).

Murty (1968), "An algorithm for ranking all the assignments in order of increasing cost": the
best assignment of a problem is found by ``scipy.optimize.linear_sum_assignment``; after a
solution ``(r_1, c_1) .. (r_n, c_n)`` is taken, its problem is split into ``n`` sub-problems,
the i-th forcing ``(r_1, c_1) .. (r_{i-1}, c_{i-1})`` and forbidding ``(r_i, c_i)``: they
partition the remaining assignments, so the next best is the best of the sub-problems' optima
(a priority queue). Forbidden entries are ``+inf``; a sub-problem without a finite assignment
is dropped.
"""

from __future__ import annotations

import heapq

import numpy as np
from scipy.optimize import linear_sum_assignment


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
    heap = [(first[0], 0, first[1], cost, 0)]  # (cost, tie-break, columns, sub-problem, rows forced)
    serial = 1
    while heap and len(costs) < k:
        total, _, cols, sub, fixed = heapq.heappop(heap)
        costs.append(total)
        sols.append(cols)
        # rows are forced in the order 0..n-1: those < fixed are forced in sub already
        work = sub.copy()
        for i in range(fixed, n):
            child = work.copy()
            child[i, cols[i]] = np.inf  # forbid (i, cols[i])
            found = _solve(child)
            if found is not None:
                heapq.heappush(heap, (found[0], serial, found[1], child, i))
                serial += 1
            _force(work, i, cols[i])  # the next sub-problems keep (i, cols[i])
    return np.array(costs), np.array(sols, dtype=np.intp).reshape(len(sols), n)


def _force(cost: np.ndarray, row: int, col: int) -> None:
    """Force ``(row, col)`` in place: every other entry of the row and of the column forbidden."""
    keep = cost[row, col]
    cost[row, :] = np.inf
    cost[:, col] = np.inf
    cost[row, col] = keep


def _solve(cost: np.ndarray) -> tuple[float, np.ndarray] | None:
    """The optimal assignment (total cost, each row's column), None if none is finite."""
    try:
        rows, cols = linear_sum_assignment(cost)
    except ValueError:  # scipy: "cost matrix is infeasible"
        return None
    total = float(cost[rows, cols].sum())
    return (total, cols) if np.isfinite(total) else None


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
