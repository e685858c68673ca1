"""Per-sensor consistency monitoring at the track-to-track centre: a flagged sensor is left out of the fusion.

Every local observation ``(H, R, z)`` fused into a central track that another sensor also supports
has a normalized innovation ``nu' S^-1 nu`` against the central prediction at its time (``nu = z - H
x``, ``S = H P H' + R``; the prediction carries the other sensors' detections). The central track is a
centralized filter of every sensor's detections, so under the model its innovations are independent
and each is chi-square with ``m`` (the observation's size) degrees of freedom.

The test is relative: over the last ``window`` seconds of the data's time, a sensor's sum ``A`` of
``a`` degrees of freedom against the other sensors' sum ``B`` of ``b``. Under the model ``(A / a) /
(B / b)`` is F(a, b) distributed whatever the window holds, and a factor common to every sensor (a
maneuver, a process noise too small, both raising every innovation of the track) cancels. The sensor
is flagged when its upper tail ``log P(F >= f)`` is below ``log(FALSE_ALARM)`` (1e-6 per test, in log
space: ``scipy.special.fdtrc``, what ``scipy.stats.f.sf`` computes, without importing
``scipy.stats``: 20 MB of every centre process and 0.06 ms a call), and stays flagged until a
window's tail probability is back above ``CLEAR_P`` (1e-2). One-sided: a sensor whose innovations
are smaller than the others' (an ``R`` claimed too large) only loses weight in the fusion and is not
flagged.

A single innovation enters the sums at most at its cap, the chi-square quantile of ``m`` dof at the
local trackers' ``gate_probability`` (``[mtt]``, 0.999 by default: ``cap_tail`` = 1e-3): the edge of
what a tracker takes as its track's detection, so a detection misassociated by a local tracker (clutter
in a formation) adds one bounded term rather than one that outweighs a window of honest ones, while
an honest innovation passes the cap as often as it passes the tracker's gate. Under the model the cap lowers
the expected sum by ``E[(X - c)+] / m`` of itself: 1.0e-3 for ``m = 2``, 7.0e-4 for ``m = 3``, both
sides alike (the test then rejects slightly less often than its level). A looser cap (1 - 1e-4) let the
dense scenario (``--scenario dense``, formations in heavy clutter) flag an honest sensor once in
120 s, at tail probabilities of 10^-6.1.

With two sensors on the tracks the test cannot tell which of them is wrong (each one's innovations
carry the other's error); with three or more, a faulty sensor's error is shared out among the others
and stands out in its own. The central tracks a faulty sensor pulls raise the honest sensors'
innovations too (most those of the sensors
with the smallest noise): a sensor is flagged only when its test is also the worst of every sensor's
at that time (isolation by the largest residual); tested against the others pooled alone, a 50 m bias
on the fastest of three sensors also flagged an honest one 3 times in 200 s (cap at 1 - 1e-4). Nor is it
flagged when another sensor's window lies further below the rest than its own lies above the pool
(:meth:`SensorConsistency._pulled`): a sensor claiming a small ``R`` whose reports sit at (or a step off)
the central predictions pulls the tracks with its own innovations small, and every honest sensor's
excess is its pull; the pooled test flagged the honest sensors in turn and never the puller (which this
rule does not flag either: see docs/multitarget.md, "A sensor pulling the tracks").

While a sensor is flagged and the isolation holds (three or more live sensors, two or more of them not
flagged: :func:`~.track_to_track.excluded_sensors`), the centre fuses none of its observations; they
still enter its window here, tested against the central predictions of the others' detections alone,
so that the flag clears when its data agrees with theirs again, and it is fused again from its next
report on.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy import special

from fedtrack.local_filters.linear.kalman import symmetrize
from fedtrack.local_filters.mtt.config import MttConfig

FALSE_ALARM = 1e-6  # per test of one sensor's window, under the model
CLEAR_P = 1e-2  # a flagged sensor is cleared when its window's tail probability is above this
WINDOW_SCANS = 5  # the window holds this many scans of the slowest sensor (seconds: its usual interval x 5)
DEFAULT_WINDOW_S = 5.0  # before any sensor's usual interval is known
MIN_OBSERVATIONS = 10  # a test needs this many innovations on each side


class ScanInnovations(NamedTuple):
    """One sensor scan's contribution: its time, the capped sum of its innovations, their dof and
    their number."""

    t: float
    nis: float
    dof: int
    count: int


class Transition(NamedTuple):
    """A sensor flagged (``flagged``) or cleared at data time ``t``, with its window's ratio to the
    others' and its log tail probability."""

    t: float
    sensor: str
    flagged: bool
    log_p: float
    ratio: float


def innovations(H: np.ndarray, R: np.ndarray, z: np.ndarray, x: np.ndarray, P: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Per row the innovation ``nu = z - H x`` and its covariance ``S = H P H' + R`` (symmetrized); each row's
    are those of that row alone (the registration takes a subset of the monitor's rows)."""
    return z - np.einsum("kmd,kd->km", H, x), symmetrize(H @ P @ np.swapaxes(H, -1, -2) + R)


def normalized_innovations(nu: np.ndarray, S: np.ndarray) -> np.ndarray:
    """``nu' S^-1 nu`` per row (a solve) of :func:`innovations`."""
    return np.einsum("km,km->k", nu, np.linalg.solve(S, nu[..., None])[..., 0])


def window_sums(kept: deque[ScanInnovations]) -> tuple[float, int, int]:
    """A sensor's window sums: its scans' capped innovations, their dof and their number."""
    return sum(e.nis for e in kept), sum(e.dof for e in kept), sum(e.count for e in kept)


def cap(m: int, tail: float) -> float:
    """The largest value one innovation of ``m`` dof adds to a window's sum: its chi-square quantile at
    ``1 - tail``."""
    return float(special.chdtri(m, tail))  # scipy.stats.chi2.isf's own function, without scipy.stats


def relative_tail(a_sum: float, a_dof: int, b_sum: float, b_dof: int) -> tuple[float, float]:
    """The ratio ``(A / a) / (B / b)`` and ``log P(F(a, b) >= ratio)``: the sensor's innovations against
    the others' (both sums of chi-square terms under the model)."""
    ratio = (a_sum / a_dof) / max(b_sum / b_dof, 1e-300)
    tail = float(special.fdtrc(a_dof, b_dof, ratio)) if ratio < math.inf else 0.0
    return ratio, math.log(tail) if tail > 0.0 else -math.inf  # a tail below the doubles' range (B = 0): -inf


def lower_tail(a_sum: float, a_dof: int, b_sum: float, b_dof: int) -> float:
    """``log P(F(a, b) <= ratio)`` of :func:`relative_tail`'s ratio: a sensor's innovations too small
    against the others'."""
    ratio = (a_sum / a_dof) / max(b_sum / b_dof, 1e-300)
    tail = float(special.fdtr(a_dof, b_dof, ratio)) if ratio < math.inf else 1.0
    return math.log(tail) if tail > 0.0 else -math.inf


@dataclass
class SensorConsistency:
    """Each sensor's innovations over the window and the sensors flagged now; ``cap_tail``: ``1 -
    gate_probability`` of the local trackers (each innovation's cap)."""

    cap_tail: float = 1.0 - MttConfig.gate_probability
    scans: dict[str, deque[ScanInnovations]] = field(default_factory=dict)
    flagged: dict[str, float] = field(default_factory=dict)  # sensor -> data time it was flagged
    onsets: int = 0
    transitions: list[Transition] = field(default_factory=list)  # not yet logged (the service drains them)
    newest: float = -math.inf
    _caps: dict[int, float] = field(default_factory=dict)
    # each sensor's window sums (innovations, dof, count) while its window is unchanged (a report changes its
    # own and those whose oldest scans it ends: the others' sums are not made again at every report)
    _summed: dict[str, tuple[float, int, int]] = field(default_factory=dict)

    def add(self, sensor: str, t: float, nis: np.ndarray, m: int, window: float) -> None:
        """One scan's innovations ``nis`` of ``sensor`` at ``t``, each of ``m`` dof (a scan's observations
        are all of one size); then its test over ``window`` seconds. A scan without any changes nothing
        (as a report without detected rows, which never gets here)."""
        if not nis.size:
            return
        self.newest = max(self.newest, t)
        for s, kept in self.scans.items():
            while kept and kept[0].t < self.newest - window:
                kept.popleft()
                self._summed.pop(s, None)
        self._summed.pop(sensor, None)
        capped = np.fmin(nis, self._cap(m))  # a NaN too enters at the cap
        self.scans.setdefault(sensor, deque()).append(ScanInnovations(t, float(capped.sum()), m * nis.size, nis.size))
        self._judge(sensor, t)

    def _cap(self, m: int) -> float:
        if m not in self._caps:
            self._caps[m] = cap(m, self.cap_tail)
        return self._caps[m]

    def tests(self) -> dict[str, tuple[float, float]]:
        """Each sensor's ratio and log tail probability over the window (those with enough innovations
        on both sides)."""
        sums, total = self._sums()
        return {s: test for s in sums if (test := self._test(sums[s], total)) is not None}

    def _sums(self) -> tuple[dict[str, tuple[float, int, int]], list[float]]:
        """Each sensor's window sums (innovations, dof, count) and their totals over the sensors."""
        for s, kept in self.scans.items():
            if s not in self._summed:
                self._summed[s] = window_sums(kept)
        sums = {s: self._summed[s] for s in self.scans}
        return sums, [sum(v[k] for v in sums.values()) for k in range(3)]

    @staticmethod
    def _test(own: tuple[float, int, int], total: list[float]) -> tuple[float, float] | None:
        """One sensor's :func:`relative_tail` against the others (``total`` less its ``own`` sums), or
        None without enough innovations on both sides."""
        a, a_dof, a_n = own
        b, b_dof, b_n = total[0] - a, total[1] - a_dof, total[2] - a_n
        return relative_tail(a, a_dof, b, b_dof) if min(a_n, b_n) >= MIN_OBSERVATIONS else None

    def _judge(self, sensor: str, t: float) -> None:
        """The reporting sensor's test; the others' only when it would be flagged (it must be the worst)."""
        sums, total = self._sums()
        test = self._test(sums[sensor], total)
        if test is None:
            return
        ratio, log_p = test
        if sensor not in self.flagged:
            if log_p < math.log(FALSE_ALARM) and log_p <= min(lp for _, lp in self.tests().values()) \
                    and not self._pulled(sensor, sums, log_p):
                self.flagged[sensor] = t
                self.onsets += 1
                self.transitions.append(Transition(t, sensor, True, log_p, ratio))
        elif log_p > math.log(CLEAR_P):
            del self.flagged[sensor]
            self.transitions.append(Transition(t, sensor, False, log_p, ratio))

    def _pulled(self, sensor: str, sums: dict[str, tuple[float, int, int]], log_p: float) -> bool:
        """Whether another sensor's window lies below (:func:`lower_tail` under ``FALSE_ALARM``) those of the
        sensors other than it and ``sensor``: a sensor whose small ``R`` claims pull the central tracks keeps
        its own innovations small and raises every other's, so that each honest sensor failed the pooled
        test in turn and was flagged, and two of three flagged switched the exclusion off. ``sensor`` is then
        not flagged: its excess is the pull's (a sensor's own fault raises the others' innovations, never
        lowers one's below the rest)."""
        others = {s: v for s, v in sums.items() if s != sensor}
        rest = [sum(v[k] for v in others.values()) for k in range(3)]
        for b, b_dof, b_n in others.values():
            c, c_dof, c_n = rest[0] - b, rest[1] - b_dof, rest[2] - b_n
            if min(b_n, c_n) >= MIN_OBSERVATIONS \
                    and lower_tail(b, b_dof, c, c_dof) < log_p:
                return True
        return False

    def drop(self, sensor: str) -> None:
        """A sensor left: its window and flag go (a flag ends with no transition logged)."""
        self.scans.pop(sensor, None)
        self._summed.pop(sensor, None)
        self.flagged.pop(sensor, None)

    def drain(self) -> list[Transition]:
        """The transitions since the last call."""
        out, self.transitions = self.transitions, []
        return out


def window_seconds(usual: dict[str, float]) -> float:
    """The window: ``WINDOW_SCANS`` scans of the slowest sensor (``DEFAULT_WINDOW_S`` before any is known)."""
    return WINDOW_SCANS * max(usual.values()) if usual else DEFAULT_WINDOW_S
