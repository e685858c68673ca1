"""Set distances between truth and tracks (GOSPA with its parts, OSPA) and the id changes of a
truth's assigned tracks (the metrics of :mod:`.scoring`)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.optimize import linear_sum_assignment

#: --c, --p: c^p below 10^300 keeps the p-th power parts, sums of up to c^p per target and track, finite in
#: float64 (max 1.8e308) for up to 1e8 of them
MAX_POWER_EXPONENT = 300


class SetDistance(NamedTuple):
    gospa: float
    localisation: float
    missed: float
    false: float
    ospa: float
    pairs: list[tuple[int, int]]  # (truth index, track index) with d < c


def set_distance(truth: np.ndarray, tracks: np.ndarray, c: float, p: float, flat: np.ndarray | None = None
                 ) -> SetDistance:
    """GOSPA (alpha = 2) and OSPA between position sets ``truth`` (n, k) and ``tracks`` (m, k); ``flat`` (m,):
    the tracks whose distances are taken on x, y only (an altitude not measured)."""
    n, m = len(truth), len(tracks)
    half = c**p / 2.0
    if n == 0 or m == 0:
        gospa_p = half * (n + m)
        return SetDistance(gospa_p ** (1 / p), 0.0, half * n, half * m, 0.0 if n == m else c, [])
    diff = truth[:, None, :] - tracks[None, :, :]
    if flat is not None and flat.any():
        diff[:, flat, 2:] = 0.0
    d = np.linalg.norm(diff, axis=-1)
    cost = np.minimum(d, c) ** p
    ri, ci = linear_sum_assignment(cost)
    close = d[ri, ci] < c
    loc = float(np.sum(d[ri, ci][close] ** p))
    k = int(np.sum(close))
    missed, false = half * (n - k), half * (m - k)
    ospa = (float(np.sum(cost[ri, ci])) + c**p * abs(m - n)) / max(n, m)
    pairs = [(int(r), int(q)) for r, q, ok in zip(ri, ci, close) if ok]
    return SetDistance((loc + missed + false) ** (1 / p), loc, missed, false, ospa ** (1 / p), pairs)


def id_changes(sequence: list[int | None]) -> tuple[int, int]:
    """``(switches, fragmentations)`` of one truth's assigned-track sequence (None: unassigned)."""
    switches = fragments = 0
    last: int | None = None
    gap = False
    for tid in sequence:
        if tid is None:
            gap = last is not None
            continue
        if last is not None and tid != last:
            switches += 1
        if gap:
            fragments += 1
            gap = False
        last = tid
    return switches, fragments
