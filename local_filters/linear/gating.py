"""Candidate (track, detection) pairs for a chi-square gate, found with a k-d tree.

``nu' S^-1 nu <= gate`` implies ``|nu|^2 <= gate lambda_max(S) <= gate trace(S)``: the ball of
radius ``sqrt(gate trace S_i)`` around track i's predicted measurement holds its gate ellipse.
The pairs inside the balls are a superset of the gated pairs, so gating them alone gives the
result of the full N x M test at O(N K) cost. A measurement space with angles (a radar's range,
azimuth, elevation) is searched in each component's units over its median spread, the angles on a
circle of 2 pi (:func:`gate_ball_pairs`' ``angular``).
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.spatial import cKDTree

# A scan whose detections fall in more than this many tracks' balls is refused (CrowdedScan), counted
# by the tree before any pair is made: about 200 B a pair in a tracker's scan (measured: 2,048
# detections equal up to round-off, one message, on the 2,048 tracks of the scan before: 4.2 x 10^6
# pairs, 1.5-2 s and 840 MB a scan; 4,096 in two parts 27 s and 4.7 GB for three scans; the 131,072
# of a scan in parts would need 3.5 TB). An honest scan's pairs are a few per detection: 10^5 targets
# with as many false detections stay near 10^5-10^6 only if packed within one another's gates.
# The multi-target centre's MAX_CANDIDATE_PAIRS, for the same reason.
MAX_GATED_PAIRS = 1 << 20


class CrowdedScan(ValueError):
    """A scan whose detections would make more than ``MAX_GATED_PAIRS`` candidate pairs."""


def ball_query(tree: cKDTree, centres: np.ndarray, radius: np.ndarray | float, what: str,
               bounded: bool = True) -> np.ndarray:
    """``tree.query_ball_point(centres, radius)`` (an index list per centre); with ``bounded``,
    :class:`CrowdedScan` (naming the pairs as ``what``) where the lists would hold more than
    ``MAX_GATED_PAIRS`` indices, counted first, only where the centres times the tree's points exceed
    the bound. Both the trackers' gates and the two-point starts' pairs (:mod:`...mtt.initiation`)
    read the bound here."""
    if bounded and centres.shape[0] * tree.n > MAX_GATED_PAIRS:
        total = int(np.sum(tree.query_ball_point(centres, radius, return_length=True)))
        if total > MAX_GATED_PAIRS:
            raise CrowdedScan(f"{total} pairs of {what}, at most {MAX_GATED_PAIRS}")
    return tree.query_ball_point(centres, radius)


def gate_ball_pairs(z: np.ndarray, centres: np.ndarray, S: np.ndarray, gate: float, bounded: bool = False,
                    angular: tuple[int, ...] = ()) -> tuple[np.ndarray, np.ndarray]:
    """``(rows, cols)``: track ``rows[k]`` and detection ``cols[k]`` of ``z`` (M, m) lie within
    ``sqrt(gate trace S_i)`` of track i's predicted measurement ``centres`` (N, m); rows ascending,
    each row's columns ascending. ``bounded``: :class:`CrowdedScan` for more than ``MAX_GATED_PAIRS``
    pairs (counted first, only where N M exceeds the bound).

    ``angular``: the components that are angles [rad], whose residuals wrap (a radar's azimuth).
    Then each component ``c`` is divided by ``s_c``, the median over the tracks of ``sqrt(S_i,cc)``
    (a ball in metres and radians together would be as wide in radians as the range's spread in
    metres), and the angles searched on a circle of ``2 pi / s_c`` (the k-d tree's periodic box):
    the ball ``sqrt(gate trace(D^-1 S_i D^-1))``, ``D = diag(s)``, still holds the gate ellipse of
    the wrapped residual, since ``nu' S^-1 nu`` is unchanged by the scaling."""
    n = centres.shape[0]
    if n == 0 or z.shape[0] == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    box = None
    if angular:
        spread = np.sqrt(np.median(np.diagonal(S, axis1=-2, axis2=-1), axis=0))
        z, centres, S = z / spread, centres / spread, S / np.outer(spread, spread)
        box = np.zeros(z.shape[1])
        box[list(angular)] = 2.0 * np.pi / spread[list(angular)]
        for k in angular:  # into [0, box) as the tree requires (np.mod can round up to box itself)
            z[:, k] = np.mod(z[:, k], box[k])
            z[z[:, k] >= box[k], k] = 0.0
    radius = np.sqrt(gate * np.trace(S, axis1=-2, axis2=-1))
    near = ball_query(cKDTree(z, boxsize=box), centres, radius,
                      "tracks and detections within one another's gates", bounded)
    counts = np.fromiter(map(len, near), dtype=np.int64, count=n)
    cols = np.fromiter(itertools.chain.from_iterable(near), dtype=np.int64, count=int(counts.sum()))
    return np.repeat(np.arange(n), counts), cols


def track_difference_d2(diff: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The track-to-track chi-square statistic ``d' S^-1 d`` of differences ``diff`` (N, n) of two
    estimates with ``S = P_a + P_b`` (N, n, n), and ``ln det S`` (N,), by a Cholesky factor."""
    L = np.linalg.cholesky(S)
    w = np.linalg.solve(L, diff[..., None])[..., 0]
    return np.sum(w * w, axis=-1), 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1)
