"""A sensor's feed copied under a second sensor id, found at the track-to-track centre from the reports.

The centre never sees the scans, but a report carries the data behind it: each detected track's
observation ``(H, R, z)``. For a position sensor ``z`` is the detection itself (a start's, exactly; an
update's ``nu + H x0``, the detection up to round-off), and so is jipda's equivalent observation of a
track with one detection in its gate (its ``R`` is not the scan's); a radar's update is linearized
about the track's prediction ``x0``, and only its starts are the detection. A copied feed's tracker
gets the same scans at the same times, so these observations equal the original's to round-off,
federated too, where the centre's resets move the copy's tracks (and a radar's ``x0``, its updates'
``z`` by about a tenth of their noise) away from the original's. The tracks, covariances and ``R``
are no test (equal ``R`` and periods are what honest sensors of one make share); two independent
sensors' noisy detections differ by their noise.

A report of ``s`` at ``t`` is compared with every report another sensor ``o`` made at the very same
``t`` (held for ``max_lag``), of the same observation size: it agrees when at least one, and at least
half, of its first ``SAMPLE`` observations that are detections (:func:`sample`) each equal one of
``o``'s within ``TOLERANCE`` of their own standard deviation in every coordinate (:func:`equal_rows`;
the half keeps apart honest sensors whose detections are quantized, which may share a value now and
then; the sample bounds the cost, a sort of 64 rows and a look-up of ``o``'s, made only when two
sensors report at the same time). ``REPEAT``
agreeing comparisons of the pair in a row make the two one feed: the sensor heard from later (its first
report arrived later: an honest sensor is normally there before a copier joins) is the copy, and from
then on none of its reports is fused (:class:`~.track_to_track.TrackToTrackCentre` counts them
``copies``; its local tracks leave their central tracks and it is not live). ``REPEAT`` comparisons in a
row that do not agree release it (the feed was fixed, or the id reused by a real sensor), and so do
``REPEAT`` of its reports in a row after one the original did not match (nothing of the original at or
after the copy's previous report: the kept sensor went silent, and the copy's reports are the only
data; the pair is then found again at its next agreeing comparison), and either sensor's departure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

# Two honest sensors' detections of one target differ by noise of sqrt(2) sigma per coordinate: they fall
# within TOLERANCE sigma of each other with probability 2e-3 / (sqrt(2 pi) sqrt(2)) = 5.6e-4 per coordinate,
# 3.2e-7 for a 2-D detection, so half of a report's detections agreeing by chance is out of reach; a copy's
# differ by round-off (7e-15 m), a federated radar copy's linearized ones by about 0.1 sigma (only starts
# compared). REPEAT is not needed against chance but against quantized detections (a shared grid value now
# and then) and one report's coincidence; 3 in a row lets a copy's first 2 reports through.
TOLERANCE = 1e-3  # of an observation's standard deviation per coordinate
SAMPLE = 64  # a report's observations compared (its first): a copy's agree all but a few, honest ones none
REPEAT = 3  # agreeing comparisons of a pair in a row that make them one feed; disagreeing ones that release it


class Found(NamedTuple):
    """At data time ``t`` sensor ``copy`` was found to copy ``original``'s feed (``found``), or released."""

    t: float
    copy: str
    original: str
    found: bool


def equal_rows(z: np.ndarray, tol: np.ndarray, other: np.ndarray) -> int:
    """How many rows of ``z`` (K, m) equal some row of ``other`` (L, m) within ``tol`` (K, m), coordinate by
    coordinate. ``z`` is sorted by its first coordinate and each row of ``other`` looked up there (``z``
    the smaller: a report's sample), first by the first coordinate within the largest of its tolerances."""
    if not len(z) or not len(other):
        return 0
    order = np.argsort(z[:, 0], kind="stable")
    first, reach = z[order, 0], float(tol[:, 0].max())
    rows = np.arange(len(other))
    at = np.searchsorted(first, other[:, 0] - reach)  # each row's first candidate in z
    hit = np.zeros(len(z), dtype=bool)
    while rows.size:  # the candidates in turn while a row has one within reach (none or one, as a rule)
        near = at < first.size
        near[near] = first[at[near]] <= other[rows[near], 0] + reach
        rows, at = rows[near], at[near]
        same = (np.abs(z[order[at]] - other[rows]) <= tol[order[at]]).all(axis=1)
        hit[order[at[same]]] = True
        rows, at = rows[~same], at[~same] + 1
    return int(np.count_nonzero(hit))


def pair(a: str, b: str) -> tuple[str, str]:
    """Two sensors' key in :attr:`FeedCopies.streak` (sorted)."""
    return (a, b) if a < b else (b, a)


class Observations(NamedTuple):
    """A report's observations: ``z`` (K, m), ``R`` (K, m, m), ``H`` (K, m, d) and ``started`` (K,) bool."""

    z: np.ndarray
    R: np.ndarray
    H: np.ndarray
    started: np.ndarray


def sample(obs: Observations) -> tuple[np.ndarray, np.ndarray]:
    """The first ``SAMPLE`` observations that are the detection itself (a start, or an update whose ``H``
    selects coordinates: a radar's update is linearized about its track's prediction, which the
    centre's resets move in a federated copy's tracker) and their tolerances (``TOLERANCE`` of each
    coordinate's standard deviation)."""
    raw = obs.started | ((obs.H == 0.0) | (obs.H == 1.0)).all(axis=(1, 2))
    rows = np.flatnonzero(raw)[:SAMPLE]
    return obs.z[rows], TOLERANCE * np.sqrt(np.diagonal(obs.R[rows], axis1=1, axis2=2))


def agrees(z: np.ndarray, tol: np.ndarray, other: np.ndarray) -> bool:
    """Whether a report's sample ``z`` (tolerances ``tol``: :func:`sample`) is another sensor's observations
    ``other``: at least one, and at least half, of its rows equal one of ``other``'s (:func:`equal_rows`)."""
    n = equal_rows(z, tol, other)
    return n >= 1 and 2 * n >= len(z)


@dataclass
class FeedCopies:
    """The reports' observations of the last ``max_lag`` seconds by time and sensor, the pairs' runs of
    agreeing comparisons, and the sensors found to copy another's feed."""

    max_lag: float
    held: dict[float, dict[str, np.ndarray]] = field(default_factory=dict)  # t -> sensor -> its observations
    streak: dict[tuple[str, str], int] = field(default_factory=dict)  # sorted pair -> agreeing in a row
    copy_of: dict[str, str] = field(default_factory=dict)  # copy -> original
    apart: dict[str, int] = field(default_factory=dict)  # copy -> its reports in a row its original did not match
    heard: dict[str, int] = field(default_factory=dict)  # sensor -> its first report's place in arrival order
    last: dict[str, float] = field(default_factory=dict)  # sensor -> its latest report's time (with observations)
    arrivals: int = 0
    newest: float = -math.inf
    found: list[Found] = field(default_factory=list)  # not yet logged (drained)

    def is_copy(self, sensor: str, t: float, obs: Observations, rows: np.ndarray | None = None) -> bool:
        """Compare ``sensor``'s report at ``t`` (its observations ``obs``, of them the rows ``rows``, None: all)
        with the other sensors' at ``t``; returns whether ``sensor`` copies another's feed (its report not to be
        fused). Only ``z`` of the rows is gathered unless another sensor reported at ``t`` (a region's sub-report
        gathered all four arrays at every report before, for a comparison most reports never make: perf60)."""
        z = obs.z if rows is None else obs.z[rows]
        if t < self.newest - self.max_lag:  # too old (and late)
            return sensor in self.copy_of
        if sensor not in self.heard:
            self.heard[sensor], self.arrivals = self.arrivals, self.arrivals + 1
        if t > self.newest:  # any report's, as the centre's rule for a late one (none heard here is late there)
            self.newest = t
            for old in [k for k in self.held if k < t - self.max_lag]:
                del self.held[old]
        if not len(z):  # no observation tells nothing
            return sensor in self.copy_of
        self._original_silent(sensor, t)
        same_t = self.held.setdefault(t, {})
        mine = None
        for other, zo in same_t.items():
            if other != sensor and zo.shape[1] == z.shape[1]:  # a radar's beside a position sensor's: no copy
                mine = sample(obs if rows is None else Observations(*(a[rows] for a in obs))) if mine is None else mine
                if len(mine[0]):  # updates of a radar alone tell nothing
                    self._compare(sensor, other, agrees(*mine, zo), t)
        same_t[sensor] = z
        self.last[sensor] = max(t, self.last.get(sensor, t))
        return sensor in self.copy_of

    def _original_silent(self, sensor: str, t: float) -> None:
        """A copy's report at ``t``: its previous one, if the original made none at or after it, counts as
        a comparison that did not agree (the kept sensor silent: the copy's reports are the only data)."""
        original = self.copy_of.get(sensor)
        if original is None:
            return
        before = self.last.get(sensor, t)
        silent = before < t and self.last.get(original, -math.inf) < before
        if silent and self._apart(sensor, False, t):  # released: found again at the pair's next agreeing comparison
            self.streak[pair(sensor, original)] = REPEAT - 1

    def _compare(self, sensor: str, other: str, agree: bool, t: float) -> None:
        copy = sensor if self.copy_of.get(sensor) == other else other if self.copy_of.get(other) == sensor else None
        if copy is not None:  # a known pair: does it still hold?
            self._apart(copy, agree, t)
            return
        both = pair(sensor, other)
        self.streak[both] = self.streak.get(both, 0) + 1 if agree else 0
        copy, original = (sensor, other) if self.heard[sensor] > self.heard[other] else (other, sensor)
        if self.streak[both] >= REPEAT and copy not in self.copy_of:
            del self.streak[both]
            self.copy_of[copy] = original
            self.found.append(Found(t, copy, original, True))

    def _apart(self, copy: str, agree: bool, t: float) -> bool:
        """The copy's run of reports its original did not match, ended by one that did; released at ``REPEAT``
        (returns whether it was)."""
        self.apart[copy] = 0 if agree else self.apart.get(copy, 0) + 1
        if self.apart[copy] < REPEAT:
            return False
        self.found.append(Found(t, copy, self.copy_of[copy], False))
        self._release(copy)
        return True

    def _release(self, copy: str) -> None:
        del self.copy_of[copy]
        self.apart.pop(copy, None)

    def drop(self, sensor: str) -> None:
        """``sensor`` left: its observations, runs and pairs go (a copy of it is fused again; released
        this way, no :class:`Found` is logged)."""
        for kept in self.held.values():
            kept.pop(sensor, None)
        self.heard.pop(sensor, None)
        self.last.pop(sensor, None)
        self.streak = {p: n for p, n in self.streak.items() if sensor not in p}
        for copy in [c for c, o in self.copy_of.items() if sensor in (c, o)]:
            self._release(copy)

    def drain(self) -> list[Found]:
        """The pairs found or released since the last call."""
        out, self.found = self.found, []
        return out
