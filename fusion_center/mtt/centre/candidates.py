"""Candidate pairs for a chi-square test of track differences: the pairs of a query's positions and
a centre's tracks close enough in x-y that the test can pass (the track-to-track centre's
association, its hand-over check and its duplicate merge; :mod:`.track_to_track`)."""

from __future__ import annotations

import itertools
import math

import numpy as np
from scipy.spatial import cKDTree

XY = slice(0, 3, 2)  # the x and y positions of a state [x, vx, y, vy(, z, vz)], as a view

# At most this many (query, position) pairs are tested directly rather than through a k-d tree:
# building and querying a tree costs about 60 us at any size, the direct test about 1 us per
# 1,000 pairs (measured: equal near 30,000 pairs); a centre's few unmapped local tracks or
# merge candidates against its tracks are a few thousand pairs.
DIRECT_PAIRS = 1 << 15
# At most this many candidate pairs of one query (a report's unmapped local tracks, or the merge
# test's tracks) and the centre's tracks: each pair's difference, covariance sum and Cholesky
# factor take about 0.5 kB (4-D states; 0.7 kB 6-D), so a report costs at most about 0.5-0.7 GB
# there. Honest reports stay far below: a local track reaches the few central tracks of its
# target's neighbours (10,000 rows with 10 each are 10^5 pairs; a crowd of 1,000 tracks 20 m
# apart within one another's reach, about 140 each at 10 m noise, 1.4 x 10^5), while a report of
# 2,048 fresh local tracks within a metre of 2,048 central ones made 4.2 x 10^6 (14 s, 2.3 GB;
# 4,096: 45 s, 9 GB): refused as CrowdedReport instead (the service counts it rejected_crowded).
MAX_CANDIDATE_PAIRS = 1 << 20


class CrowdedReport(ValueError):
    """A report whose tracks would make more than ``MAX_CANDIDATE_PAIRS`` candidate pairs."""


def candidate_pairs(pos_q: np.ndarray, spread_q: np.ndarray, pos: np.ndarray, spread: np.ndarray, gate: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The pairs ``(i, j)`` of a query ``pos_q[i]`` and a position ``pos[j]`` that can pass the
    chi-square test ``d' (P_i + P_j)^-1 d <= gate``, as two arrays (``i`` ascending, then ``j``):
    its x-y marginal alone needs ``|dxy|^2 <= gate tr(P_xy,i + P_xy,j) <= gate (spread_i +
    spread_j)^2`` (``spread``: root of the x-y position variances), so a pair farther apart fails.

    Up to ``DIRECT_PAIRS`` pairs that bound is tested on every pair. Beyond, one k-d tree query
    per query position with the reach of the largest spread among the ordinary positions (about
    the 90th percentile of the spreads, one partition instead of a quantile's sort and
    interpolation), plus a direct check against the few with a larger spread (tentative tracks
    with a large velocity uncertainty), so that one of them does not make every query cover the
    region; that gives some farther pairs too (the reach only splits the work: the test decides).
    More than ``MAX_CANDIDATE_PAIRS`` pairs from the tree: :class:`CrowdedReport` (counted before
    any is made).
    """
    factor = math.sqrt(gate)
    if pos_q.shape[0] * pos.shape[0] <= DIRECT_PAIRS:
        dx, dy = pos_q[:, 0, None] - pos[:, 0], pos_q[:, 1, None] - pos[:, 1]
        reach = factor * (spread_q[:, None] + spread)
        return np.nonzero(dx * dx + dy * dy <= reach * reach)
    kth = int(0.9 * (spread.size - 1))
    big_spread = float(np.partition(spread, kth)[kth])
    big = (spread > big_spread).nonzero()[0]
    tree, radius = cKDTree(pos), factor * (spread_q + big_spread)
    if pos_q.shape[0] * pos.shape[0] > MAX_CANDIDATE_PAIRS:
        n = int(np.sum(tree.query_ball_point(pos_q, radius, return_length=True)))
        if n > MAX_CANDIDATE_PAIRS:
            raise CrowdedReport(f"{n} pairs of tracks within the association test's reach, at most "
                                f"{MAX_CANDIDATE_PAIRS}")
    near = tree.query_ball_point(pos_q, radius)
    if big.size:
        reach = factor * (spread_q[:, None] + spread[big][None, :])
        close = np.linalg.norm(pos_q[:, None, :] - pos[big][None, :, :], axis=-1) <= reach
        near = [sorted(set(js) | set(big[close[i]].tolist())) for i, js in enumerate(near)]
    counts = np.fromiter(map(len, near), dtype=np.int64, count=len(near))
    j = np.fromiter(itertools.chain.from_iterable(near), dtype=np.int64, count=int(counts.sum()))
    return np.repeat(np.arange(len(near)), counts), j
