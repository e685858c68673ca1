"""Global nearest neighbour by connected components equals one assignment over the whole matrix."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linear_sum_assignment

from fedtrack.local_filters.mtt.associators.gnn import assign


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 12), st.integers(1, 12), st.floats(0.05, 0.6), st.integers(0, 2**32 - 1))
def test_assign_by_components_is_an_optimal_matching(n_tracks: int, n_dets: int, density: float, seed: int) -> None:
    """Sparse candidate pairs with random costs (some not negative, so unusable): the chosen pairs
    form a matching of usable pairs whose total cost is that of the optimal assignment of the dense
    matrix (0 where there is no usable pair: leaving a track unassigned)."""
    rng = np.random.default_rng(seed)
    mask = rng.random((n_tracks, n_dets)) < density
    rows, cols = np.nonzero(mask)
    cost = rng.normal(-1.0, 1.0, size=rows.size)
    picked = assign(n_tracks, n_dets, rows, cols, cost)
    assert np.all(cost[picked] < 0.0)
    assert np.unique(rows[picked]).size == picked.size and np.unique(cols[picked]).size == picked.size
    dense = np.zeros((n_tracks, n_dets))
    usable = cost < 0.0
    dense[rows[usable], cols[usable]] = cost[usable]
    ri, ci = linear_sum_assignment(dense)
    assert abs(cost[picked].sum() - dense[ri, ci].sum()) <= 1e-9
