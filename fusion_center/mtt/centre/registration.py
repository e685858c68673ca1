"""Online sensor registration at the track-to-track centre: each sensor's position offset and clock offset.

A sensor whose positions carry a fixed offset ``b`` (2-D, or 3-D with a 3-D state), or whose clock runs
``c`` seconds ahead of the others' (its detection stamped ``t`` is of the target at ``t - c``: it sits
``-c v`` along the velocity), puts each detection ``H (x + D(x) theta)`` for the target's state ``x``,
with ``theta = (b, c)`` and ``D(x)`` adding ``b - c v`` to the state's positions. Against a central
track's prediction ``(X, P)`` at its time the observation's innovation is, to first order,

    nu = z - H X = A theta + e,   A = H D(X),   e ~ N(0, S),   S = H P H' + R,

the model of the consistency monitor's innovations (:mod:`.consistency`), with the same rows (a central
track that another sensor also supports, one observation of it in the scan) of the confirmed central tracks
(a tentative track's velocity is not yet known: on ``bench scale``'s honest 1,000 targets and four sensors
their first seconds had s3 corrected at t = 1.55 and 2.18 s, chi-square 40 and 55). Each scan adds its
information ``A' S^-1 A`` and ``A' S^-1 nu`` (solves); the sum over a window gives the weighted least
squares estimate of ``theta`` and its covariance, the inverse of the information (a recursive least
squares estimate restarted at each correction), over every associated track of the scan at once.

**Position sensors only.** A radar's error is a bias of range, azimuth and elevation, not a Cartesian
offset, and its updates are linearized about each track's prediction: a sensor any of whose tested
observations has an ``H`` that does not select coordinates is left out (neither estimated nor corrected,
nor in the consensus). On the recorded Switzerland traffic (two radars, one position sensor), with the
radars estimated, radar r2 was "corrected" by (-164, +364, +745) m at t = 172 s (chi-square 2674), taken
back 14 s later, and ``mtt-federated``'s mean GOSPA went from 86.7 to 125.5 m.

**The consensus.** The central tracks fuse every sensor's detections, this one's too, so a faulty
sensor's estimate is its offset less its pull on the tracks, and every other sensor's estimate is minus
that pull. Each sensor is therefore compared with the **medoid** of the sensors' estimates over the
window (the sensor whose estimate lies nearest every other's, in the sum of their Mahalanobis distances):
the pull, common to every sensor's estimate, cancels in the difference ``d = theta_s - theta_r``, of
covariance ``C_s + C_r``. With one faulty sensor of three or more the medoid is an honest one. With fewer
than ``MIN_SENSORS`` (3) sensors estimated and live, which of two differing sensors is wrong cannot be
told: the estimates are reported, nothing is corrected.

**The rule.** ``d' (C_s + C_r)^-1 d`` is chi-square with ``k = dim(theta)`` degrees of freedom when the
sensor agrees with the consensus; ``d`` is significant when it exceeds the chi-square quantile at ``1 -
FALSE_ALARM`` (1e-6 per test, the monitor's level: a test at every scan of every sensor, about 1,000 in a
default 300 s run, under the model one false correction in a thousand such runs). The sensor's
correction then grows by ``d``, every window restarts (the tracks' pull changes with the correction), and
its reports are corrected before association from its next one on: the offsets taken off the positions
of each local estimate (``x - E b``) and each observation (``z - H E b``, ``E`` putting ``b`` on the
state's positions), the clock offset off the report's time (``t - c``: its detections and estimates are of
the targets at ``t - c``, exactly, where ``-c v`` is the first order of it). Federated, the resets go back
in the sensor's own frame (``x_c + E b`` at ``t + c``): its tracker keeps tracking its raw detections on
its own clock. A correction that would put the clock correction beyond ``max_lag`` is not made (reported
only): the sensor's reports would all be older than ``max_lag`` before the others', late, and the estimate
that far off is no clock's (a 200 m bias, whose local tracks mostly fail the association test, was
"corrected" by +5.5 s with offsets of (+32, +61) m, from the few misassociated pairs). The picture clock
runs on the corrected times (``Engine.data_time``): a sensor whose clock runs ahead otherwise has the
pictures made before the others' data of their time came.

**The gate.** An innovation beyond the local trackers' gate (the chi-square quantile at their
``gate_probability``) is left out, and a sensor is estimated only while at least ``MIN_OBSERVATIONS`` of
its window's innovations, and at least half of its scans' observations, are within it: a sensor far off (a
200 m bias) has its local tracks unmapped, and the few pairs left within the gate are misassociations, no
sample of its offset (they corrected s2 by (-46, -7) m and +2.6 s, ``mtt-decentralized`` of seed 1 88.78 ->
91.52 m). Within the gate, a truncated sample shrinks the estimate towards zero: the next corrections
make up the rest.
"""
from __future__ import annotations

import functools
import itertools
import math
from collections import deque
from dataclasses import dataclass, field
from functools import cached_property
from typing import NamedTuple

import numpy as np
from scipy import special

from fedtrack.fusion_center.mtt.centre.consistency import cap
from fedtrack.local_filters.linear.kalman import symmetrize
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.local import LocalReport, Resets

FALSE_ALARM = 1e-6  # per test of one sensor's estimate against the consensus, under the model
MIN_SENSORS = 3  # sensors estimated (and live) before the consensus is taken and a sensor corrected
MIN_OBSERVATIONS = 10  # innovations a sensor's window needs for an estimate (the monitor's)
# the estimate's prior (zero, these standard deviations), only to keep the solve defined where the window
# leaves a parameter unobserved (targets all moving one way, a 2-D sensor's height offset): far weaker
# than one observation of the noise of any sensor
PRIOR_OFFSET_M = 1e4
PRIOR_CLOCK_S = 1e2
WINDOW_ROOM = 16  # rows of a sensor's window array at first (doubled when full: a window of 5 s holds 5 scans at 1 Hz)


class InformationWindow:
    """A sensor's scans' information on ``theta`` (of size ``k``) over the window, oldest first: per scan its time
    and a row holding ``A' S^-1 A`` (flattened), ``A' S^-1 nu``, the number of innovations within the gate (those
    summed) and of the scan's observations, the rows in order in one array, so that the window's sums are one
    reduction (over the first axis: row after row, the sums of adding the scans one by one, as Python's ``sum``
    of the scans' arrays made them at every report)."""

    def __init__(self, k: int) -> None:
        self.k = k
        self.t: deque[float] = deque()
        self.rows = np.zeros((WINDOW_ROOM, k * k + k + 2))
        self.start = 0  # the window's rows: rows[start:start + len(t)]

    def __len__(self) -> int:
        return len(self.t)

    def append(self, t: float, Y: np.ndarray, y: np.ndarray, count: int, observed: int) -> None:
        """One scan's information at ``t`` after the others (the rows moved to the front, or into an array
        twice the size, when there is no room after them)."""
        n, end = len(self.t), self.start + len(self.t)
        if end == self.rows.shape[0]:
            rows = self.rows if 2 * n < self.rows.shape[0] else np.zeros((2 * self.rows.shape[0], self.rows.shape[1]))
            rows[:n] = self.rows[self.start:end]
            self.rows, self.start, end = rows, 0, n
        self.rows[end] = np.concatenate([Y.ravel(), y, (count, observed)])
        self.t.append(t)

    def drop_before(self, t: float) -> bool:
        """Leave out the scans before ``t``; whether there were any."""
        kept, n = self.t, len(self.t)
        while kept and kept[0] < t:
            kept.popleft()
        self.start += n - len(kept)
        return len(kept) < n

    def sums(self) -> tuple[np.ndarray, np.ndarray, int, int]:
        """The window's ``A' S^-1 A``, ``A' S^-1 nu`` and innovations within the gate and observations, summed
        (``+ 0.0``: a sum of -0.0 only is 0.0, as Python's ``sum`` from its start 0 gives it)."""
        k = self.k
        total = np.add.reduce(self.rows[self.start:self.start + len(self.t)], axis=0) + 0.0
        return total[:k * k].reshape(k, k), total[k * k:k * k + k], int(total[-2]), int(total[-1])


class Estimate(NamedTuple):
    """A sensor's registration against the consensus: ``theta`` (offsets in m, then the clock offset in s),
    its covariance and ``d' C^-1 d``; ``reference`` the sensor it was compared with (None: fewer than
    ``MIN_SENSORS``, ``theta`` then against the central tracks)."""

    theta: np.ndarray
    cov: np.ndarray
    chi2: float
    reference: str | None


class Correction(NamedTuple):
    """A correction at data time ``t``: its ``step`` with its covariance and the sensor's whole correction since
    (``total``)."""

    t: float
    sensor: str
    step: np.ndarray
    cov: np.ndarray
    total: np.ndarray
    chi2: float


def layout(dim: int) -> tuple[np.ndarray, np.ndarray]:
    """The position and velocity indices of a state of size ``dim`` (``[x, vx, y, vy(, z, vz)]``)."""
    return np.arange(0, dim, 2), np.arange(1, dim, 2)


def offset(d: int, theta: np.ndarray) -> np.ndarray:
    """``E b``: ``theta``'s offsets on the positions of a state of size ``d`` (those beyond them left out)."""
    pos = layout(d)[0]
    out = np.zeros(d)
    out[pos] = theta[: pos.size]
    return out


def design(H: np.ndarray, X: np.ndarray, k: int) -> np.ndarray:
    """``A = H D(X)`` (n, m, k) for observations ``H`` (n, m, d) of states ``X`` (n, d): the columns of the
    positions' offsets, then the clock's."""
    pos, vel = layout(X.shape[-1])
    A = np.zeros(H.shape[:-1] + (k,))
    A[..., : pos.size] = H[..., pos]
    A[..., -1] = -np.einsum("nmp,np->nm", H[..., pos], X[:, vel])
    return A


def scan_information(H: np.ndarray, nu: np.ndarray, S: np.ndarray, X: np.ndarray, k: int,
                     gate: float = math.inf) -> tuple[np.ndarray, np.ndarray, int]:
    """``sum A' S^-1 A`` and ``sum A' S^-1 nu`` over the observations ``H`` of the central predictions ``X``, with
    innovations ``nu`` and their covariances ``S`` (:func:`~.consistency.innovations`), whose ``nu' S^-1 nu`` is
    within ``gate`` (one solve for both), and their number."""
    A = design(H, X, k)
    W = np.linalg.solve(S, np.concatenate([A, nu[..., None]], axis=-1))  # S^-1 [A nu]
    inside = np.einsum("nm,nm->n", nu, W[..., k]) <= gate  # a NaN's row is left out too
    M = np.einsum("nmk,nml->kl", A[inside], W[inside])
    return symmetrize(M[:, :k]), M[:, k], int(np.count_nonzero(inside))


@functools.cache
def prior_information(k: int) -> np.ndarray:
    """The weak prior's information on ``theta`` of size ``k`` (made once per size: read at every report)."""
    out = np.diag(np.r_[np.full(k - 1, PRIOR_OFFSET_M ** -2), PRIOR_CLOCK_S ** -2])
    out.flags.writeable = False
    return out


def solve_estimate(Y: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The estimate and covariance of information ``Y`` and ``y`` with the weak prior added."""
    cov = symmetrize(np.linalg.inv(Y + prior_information(y.size)))
    return cov @ y, cov


def sensor_frame(resets: Resets, theta: np.ndarray | None) -> Resets:
    """Federated resets of a report corrected by ``theta`` (None: none) back in their sensor's frame and
    clock."""
    if theta is None:
        return resets
    return resets._replace(t=resets.t + float(theta[-1]), x=resets.x + offset(resets.x.shape[1], theta))


def chi2_of(d: np.ndarray, C: np.ndarray) -> float:
    """``d' C^-1 d`` (a solve)."""
    return float(d @ np.linalg.solve(C, d))


@dataclass
class SensorRegistration:
    """Each sensor's registration information over the window, its correction and the corrections made;
    ``k``: the size of ``theta`` (the state's positions, then the clock); ``max_lag``: the centre's (the
    largest clock correction made); ``gate_tail``: ``1 - gate_probability`` of the local trackers (an
    innovation beyond their gate is left out)."""

    k: int
    max_lag: float
    gate_tail: float = 1.0 - MttConfig.gate_probability
    scans: dict[str, InformationWindow] = field(default_factory=dict)
    applied: dict[str, np.ndarray] = field(default_factory=dict)  # sensor -> its correction theta
    estimates: dict[str, Estimate] = field(default_factory=dict)  # at each sensor's latest test
    linearized: set[str] = field(default_factory=set)  # sensors with observations linearized (radars): left out
    corrections: int = 0
    made: list[Correction] = field(default_factory=list)  # not yet logged (the service drains them)
    newest: float = -math.inf
    # each sensor's window estimate (None: too few observations) while its window is unchanged
    _solved: dict[str, tuple[np.ndarray, np.ndarray] | None] = field(default_factory=dict)

    @cached_property
    def threshold(self) -> float:
        """The chi-square quantile of ``k`` dof at ``1 - FALSE_ALARM`` (computed once: read at every report)."""
        return float(special.chdtri(self.k, FALSE_ALARM))

    def correct(self, report: LocalReport) -> LocalReport:
        """The report with its sensor's correction applied (as it is without one)."""
        theta = self.applied.get(report.sensor)
        if theta is None:
            return report
        shift = offset(report.x.shape[1], theta)
        return report._replace(t=report.t - float(theta[-1]), x=report.x - shift,
                               obs_z=report.obs_z - report.obs_H @ shift)

    def clock(self, sensor: str) -> float:
        """The sensor's clock correction (0 without one)."""
        theta = self.applied.get(sensor)
        return 0.0 if theta is None else float(theta[-1])

    def add(self, sensor: str, t: float, observations: tuple[np.ndarray, np.ndarray, np.ndarray], X: np.ndarray,
            window: float, live: list[str], observed: int) -> None:
        """One scan's (already corrected) observations ``H`` (central size) of the central predictions ``X``, with
        their innovations and covariances ``(H, nu, S)`` (:func:`~.consistency.innovations`), of the ``observed``
        observations of the scan; then the sensor's test against the consensus of the ``live`` sensors' windows of
        ``window`` seconds."""
        H, nu, S = observations
        if not observed or sensor in self.linearized:
            return
        if nu.shape[0] and not ((H == 0.0) | (H == 1.0)).all():  # a radar's update: linearized about a prediction
            self.linearized.add(sensor)
            self.scans.pop(sensor, None)
            self._solved.pop(sensor, None)
            return
        self.newest = max(self.newest, t)
        for s, kept in self.scans.items():
            if kept.drop_before(self.newest - window):
                self._solved.pop(s, None)
        self._solved.pop(sensor, None)
        Y, y, n = (scan_information(H, nu, S, X, self.k, cap(nu.shape[-1], self.gate_tail)) if nu.shape[0]
                   else (np.zeros((self.k, self.k)), np.zeros(self.k), 0))
        kept = self.scans.get(sensor)
        if kept is None:
            kept = self.scans[sensor] = InformationWindow(self.k)
        kept.append(t, Y, y, n, observed)
        self._judge(sensor, t, live)

    def _window_estimates(self, live: list[str]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Each live sensor's estimate and covariance over its window (those with ``MIN_OBSERVATIONS`` within the
        gate, and at least half of their scans' observations)."""
        for s in live:
            if s not in self._solved:
                kept = self.scans.get(s)
                Y, y, n, observed = kept.sums() if kept else (None, None, 0, 0)
                self._solved[s] = (solve_estimate(Y, y) if n >= MIN_OBSERVATIONS and 2 * n >= observed else None)
        return {s: e for s in live if (e := self._solved[s]) is not None}

    def _judge(self, sensor: str, t: float, live: list[str]) -> None:
        """The reporting sensor's estimate against the consensus (its correction grown by a significant one)."""
        est = self._window_estimates(live)
        if sensor not in est:
            return
        if len(est) < MIN_SENSORS or len(live) < MIN_SENSORS:  # no consensus: reported only
            theta, cov = est[sensor]
            self.estimates[sensor] = Estimate(theta, cov, chi2_of(theta, cov), None)
            return
        ref, pair_chi2 = medoid(est)
        theta, cov = est[sensor]
        d, C = theta - est[ref][0], cov + est[ref][1]
        chi2 = pair_chi2[min(sensor, ref), max(sensor, ref)] if ref != sensor else 0.0  # chi2_of(d, C): -d's is d's
        self.estimates[sensor] = Estimate(d, C, chi2, ref)
        total = self.applied.get(sensor, np.zeros(self.k)) + d
        if chi2 > self.threshold and abs(total[-1]) <= self.max_lag:
            self.applied[sensor] = total
            self.corrections += 1
            self.made.append(Correction(t, sensor, d, C, total.copy(), chi2))
            self.scans.clear()  # every sensor's innovations had the tracks' pull of the old correction
            self._solved.clear()

    def drop(self, sensor: str) -> None:
        """A sensor left: its window, estimate and correction go (a returning sensor is estimated afresh)."""
        self.scans.pop(sensor, None)
        self._solved.pop(sensor, None)
        self.estimates.pop(sensor, None)
        self.applied.pop(sensor, None)

    def drain(self) -> list[Correction]:
        """The corrections since the last call."""
        out, self.made = self.made, []
        return out


def describe(theta: np.ndarray) -> str:
    """``theta`` as text: ``offset (+1.2, -0.4) m, clock +2.00 s``."""
    return f"offset ({', '.join(f'{v:+.1f}' for v in theta[:-1])}) m, clock {theta[-1]:+.2f} s"


def correction_lines(reg: SensorRegistration, shown: int = 10) -> list[str]:
    """The corrections made since the last drain (the first ``shown``), each sensor's correction at the end, and
    its latest estimates when they exceed the test (corrected or not: with fewer than ``MIN_SENSORS``,
    reported only)."""
    made, lines = reg.drain(), []
    if made:
        listed = ", ".join(f"{c.sensor} at t={c.t:.2f} by {describe(c.step)} (chi-square {c.chi2:.1f})"
                           for c in made[:shown])
        more = f" and {len(made) - shown} more" if len(made) > shown else ""
        ends = "; ".join(f"{s} {describe(theta)}" for s, theta in sorted(reg.applied.items()))
        lines += [f"sensors' registration corrected: {listed}{more}",
                  f"registration corrections at the end: {ends or 'none'}"]
    off = sorted((s, e) for s, e in reg.estimates.items() if e.chi2 > reg.threshold)
    if off:
        lines.append("registration estimates beyond the test at the end: " + "; ".join(
            f"{s} {describe(e.theta)} (chi-square {e.chi2:.1f}, against "
            f"{e.reference or 'the central tracks: fewer than 3 sensors, not corrected'})" for s, e in off))
    return lines


def medoid(estimates: dict[str, tuple[np.ndarray, np.ndarray]]) -> tuple[str, dict[tuple[str, str], float]]:
    """The sensor whose estimate has the least sum of Mahalanobis distances to the others' (each pair's
    difference against the sum of their covariances); ties go to the first name in order. Also each pair's
    ``d' C^-1 d`` (:func:`chi2_of`, by the names in order): the pairs' systems solved in one call (each as
    :func:`chi2_of` solves it alone)."""
    names = sorted(estimates)
    cost = dict.fromkeys(names, 0.0)
    pairs = list(itertools.combinations(names, 2))
    if not pairs:
        return names[0], {}
    d = np.array([estimates[a][0] - estimates[b][0] for a, b in pairs])  # (np.stack: the same, at twice the cost)
    w = np.linalg.solve(np.array([estimates[a][1] + estimates[b][1] for a, b in pairs]), d[..., None])[..., 0]
    chi2 = dict(zip(pairs, map(float, map(np.dot, d, w))))
    for (a, b), c in chi2.items():
        dist = math.sqrt(c)
        cost[a] += dist
        cost[b] += dist
    return min(names, key=cost.__getitem__), chi2
