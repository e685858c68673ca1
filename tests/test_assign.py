"""Global nearest neighbour by connected components equals one assignment over the whole matrix."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from fedtrack.local_filters.mtt.associators import gnn
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


def test_a_crowd_linking_a_whole_scan_is_matched_without_its_dense_matrix() -> None:
    """A grid of 3,600 tracks on its 3,600 detections, each track gating its own detection and its 8
    neighbours: one component of 3,600 x 3,600, whose dense matrices (a cost and a pair index an
    entry) took 207 MB (a scan of the wire's 131,072 detections: 275 GB; a grid of 6,000 in replay
    670 MB, and 16,000 two-point starts 4.5 GB and 22 s). Beyond ``DENSE_ENTRIES`` it is matched
    greedily on its pairs: here each track its own detection, the cheapest pair, in a few MB."""
    g = np.stack(np.meshgrid(np.arange(60.0), np.arange(60.0)), -1).reshape(-1, 2)
    near = cKDTree(g).query_ball_point(g, 1.5)
    rows = np.repeat(np.arange(g.shape[0]), [len(a) for a in near])
    cols = np.concatenate([np.asarray(a, np.int64) for a in near])
    cost = np.linalg.norm(g[rows] - g[cols], axis=1) - 2.0
    assert g.shape[0] ** 2 > gnn.DENSE_ENTRIES
    tracemalloc.start()
    try:
        picked = assign(g.shape[0], g.shape[0], rows, cols, cost)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert np.array_equal(np.sort(rows[picked]), np.arange(g.shape[0])) and np.array_equal(rows[picked], cols[picked])
    assert peak < 20e6, peak


@settings(max_examples=100, deadline=None)
@given(st.integers(1, 30), st.integers(1, 30), st.floats(0.05, 0.6), st.integers(0, 2**32 - 1))
def test_a_crowd_beyond_the_dense_bound_gets_a_greedy_matching(n_tracks: int, n_dets: int, density: float,
                                                               seed: int) -> None:
    """With ``DENSE_ENTRIES`` (and ``SMALL_COMPONENT``) lowered to 0 every component is matched
    greedily: a matching of usable pairs, taken cheapest first while both ends are free."""
    rng = np.random.default_rng(seed)
    rows, cols = np.nonzero(rng.random((n_tracks, n_dets)) < density)
    cost = rng.normal(-1.0, 1.0, size=rows.size)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(gnn, "DENSE_ENTRIES", 0)
        mp.setattr(gnn, "SMALL_COMPONENT", 0)  # no component enumerated either (a star's cheapest pair is greedy's)
        picked = assign(n_tracks, n_dets, rows, cols, cost)
    assert np.all(cost[picked] < 0.0)
    assert np.unique(rows[picked]).size == picked.size and np.unique(cols[picked]).size == picked.size
    free_r, free_c, expected = set(range(n_tracks)), set(range(n_dets)), []
    for k in np.argsort(cost, kind="stable").tolist():
        if cost[k] < 0.0 and rows[k] in free_r and cols[k] in free_c:
            free_r.discard(rows[k])
            free_c.discard(cols[k])
            expected.append(k)
    assert sorted(picked.tolist()) == sorted(expected)
