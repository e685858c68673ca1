"""Candidate (track, detection) pairs for a chi-square gate, found with a k-d tree.

``nu' S^-1 nu <= gate`` implies ``|nu|^2 <= gate lambda_max(S) <= gate trace(S)``: the ball of
radius ``sqrt(gate trace S_i)`` around track i's predicted measurement holds its gate ellipse.
The pairs inside the balls are a superset of the gated pairs, so gating them alone gives the
result of the full N x M test at O(N K) cost. (Measurement spaces that wrap, such as a radar's
azimuth, need every pair.)
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.spatial import cKDTree


def gate_ball_pairs(z: np.ndarray, centres: np.ndarray, S: np.ndarray, gate: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """``(rows, cols)``: track ``rows[k]`` and detection ``cols[k]`` of ``z`` (M, m) lie within
    ``sqrt(gate trace S_i)`` of track i's predicted measurement ``centres`` (N, m); rows ascending."""
    n = centres.shape[0]
    if n == 0 or z.shape[0] == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    radius = np.sqrt(gate * np.trace(S, axis1=-2, axis2=-1))
    near = cKDTree(z).query_ball_point(centres, radius)
    counts = np.fromiter(map(len, near), dtype=np.int64, count=n)
    cols = np.fromiter(itertools.chain.from_iterable(near), dtype=np.int64, count=int(counts.sum()))
    return np.repeat(np.arange(n), counts), cols


def track_difference_d2(diff: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The track-to-track chi-square statistic ``d' S^-1 d`` of differences ``diff`` (N, n) of two
    estimates with ``S = P_a + P_b`` (N, n, n), and ``ln det S`` (N,), by a Cholesky factor."""
    L = np.linalg.cholesky(S)
    w = np.linalg.solve(L, diff[..., None])[..., 0]
    return np.sum(w * w, axis=-1), 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)
