"""The multi-target algorithms as engines fed one sensor scan at a time, in arrival order.

* ``mtt-local``: one sensor's :func:`tracker_step` alone.
* ``mtt-centralized``: one tracker of every sensor's detections (measurement-level fusion,
  the optimum the others are measured against), with the fusion centre's policy
  (:func:`central_params`).
* ``mtt-federated`` / ``mtt-decentralized``: one local tracker per sensor
  (:class:`SensorTracker`) and the :class:`TrackToTrackCentre` (with or without reset feedback).

Every tracker of scans fuses out-of-sequence scans up to ``max_lag`` old exactly by rolling back
to its state before the scan and re-running the later scans in time order (association
included; :class:`ScanHistory`); older ones are late, repeated ones duplicates.
``picture(T)`` is every track predicted to ``T`` from the data up to ``T`` (``associator = "mht"``
in a tracker of scans: as the window decided them with the scans after ``T`` that are in,
:meth:`ScanTrackerEngine.mht_state_at`)."""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, NamedTuple

import numpy as np

from fedtrack.deployment import MAX_TIME_JUMP_S
from fedtrack.fusion_center.mtt.centre import TrackToTrackCentre
from fedtrack.fusion_center.mtt.centre.consistency import Transition
from fedtrack.fusion_center.mtt.centre.copies import Found
from fedtrack.fusion_center.mtt.centre.registration import SensorRegistration
from fedtrack.fusion_center.mtt.centre.track_life import CENTRAL_MISSES
from fedtrack.fusion_center.mtt.shards import ShardedCentre
from fedtrack.geodetic import Frame, RadarSite, above_the_surface
from fedtrack.local_filters.linear.noise_floor import raise_to_floor
from fedtrack.local_filters.mtt.associators import jipda
from fedtrack.local_filters.mtt.config import LOST, MttConfig, miss_count, scan_lost
from fedtrack.local_filters.mtt.history import ScanHistory
from fedtrack.local_filters.mtt.local import (
    LocalReport,
    Resets,
    SensorTracker,
    copies_another,
    is_conflict,
    is_duplicate,
)
from fedtrack.local_filters.mtt.maneuver import predicted_view
from fedtrack.local_filters.mtt.models import modes_predict, predict_batch
from fedtrack.local_filters.mtt.roles.life import keeps_evidence
from fedtrack.local_filters.mtt.roles.tracks import TrackParams
from fedtrack.local_filters.mtt.scan import SensorScan
from fedtrack.local_filters.mtt.tracker import TrackerState, initial_state, mht_decided, track_params, tracker_step
from fedtrack.local_filters.pda.association import existence_predict
from fedtrack.local_filters.regions import Regions
from fedtrack.local_filters.vdie.estimation import VdieParams
from fedtrack.services.lead import LeadGuard
from fedtrack.wire import picture_line

ALGORITHMS = ("mtt-local", "mtt-centralized", "mtt-federated", "mtt-decentralized")


class PictureTracks(NamedTuple):
    """The tracks of one picture, batched, every track predicted to the picture's time: what the
    replay writes as a line (:meth:`line`) and the live centre sends as a ``TrackPicture``."""

    ids: list[int]
    x: np.ndarray  # (n, d) CV states (a CA track's marginal)
    P: np.ndarray  # (n, d, d)
    confirmed: list[bool]
    sensors: list[list[str]]
    models: list[str]  # "cv" or "ca" per track
    # (n, 4) detected maneuvers [onset, ax, ay, statistic] (central tracks, or a 3-D tracker's
    # tracks), NaN rows where none; None where no maneuver detector runs
    maneuver: np.ndarray | None = None
    existence: list[float] | None = None  # per track (associators that keep it), None: not kept

    def maneuver_rows(self) -> list[int]:
        """The positions of the central tracks whose maneuver is detected."""
        return [] if self.maneuver is None else np.flatnonzero(~np.isnan(self.maneuver[:, 0])).tolist()

    def maneuvering(self) -> set[int]:
        """The ids of the central tracks whose maneuver is detected."""
        return {self.ids[i] for i in self.maneuver_rows()}

    def line(self, t: float, head: dict[str, Any] | None = None) -> str:
        """The picture's line in a tracks file (``{"t": t, **head, "tracks": rows}`` as JSON)."""
        return picture_line(t, self.ids, self.x, self.P, self.confirmed, self.sensors, self.models, self.maneuver,
                            self.existence, head)

    def on_the_earth(self, frame: Frame | None, init_z_std: float) -> PictureTracks:
        """The tracks with a measured altitude held above the Earth's lowest surface
        (:func:`fedtrack.geodetic.above_the_surface`), as ``replay`` and the live centres show them; without a
        ``[frame]`` (a flat world) as they are."""
        if frame is None:
            return self
        x, P = above_the_surface(frame, self.x, self.P, init_z_std)
        return self._replace(x=x, P=P)


@dataclass
class PictureClock:
    """When pictures are due: the picture at ``T = k period`` once a scan later than
    ``T + delay`` arrives (``high`` is the latest scan time seen), the rest at the end; none more
    than ``max_gap`` (``[deployment] max_time_jump_s``) before the data (those are ``skipped``): a
    gap in the data, or a first scan far before the rest, made a picture for every period of it, one
    scan of a sensor's stamped 20,000 s before the others' 20,000 pictures (27 s of a centre's time;
    10^9 s: for good)."""

    period: float
    delay: float
    k: int | None = None
    high: float = -math.inf
    departed: bool = False  # a sensor left after the latest scan
    first: int | None = None  # the ``k`` of picture number 0: 0, or the first picture's when before t = 0
    max_gap: float = MAX_TIME_JUMP_S
    skipped: int = 0  # picture times not made: more than ``max_gap`` before the data
    fixed: bool = False  # ``first`` is final: a picture was made, or :meth:`numbered` gave it

    def left(self) -> None:
        """A sensor left (a departure line, or a live centre dropping it)."""
        self.departed = True

    def due(self, t: float) -> list[float]:
        """Picture times due before a scan at ``t`` is ingested."""
        if self.k is None:
            self.k = math.ceil(t / self.period - 1e-9)
        self.high = max(self.high, t)
        self.departed = False
        oldest = math.ceil((self.high - self.delay - self.max_gap) / self.period - 1e-9)
        if oldest > self.k:
            self.skipped += oldest - self.k
            self.k = oldest
        if not self.fixed:  # t = 0 is picture 0 (times before it: the first picture made is)
            self.first = min(self.k, 0)
        out = []
        while self.k * self.period + self.delay < self.high:
            out.append(self.k * self.period)
            self.k += 1
        self.fixed = self.fixed or bool(out)
        return out

    def number(self, T: float) -> int:
        """The number of the picture at ``T`` (a closing record: the next picture's): its place on the
        period grid counted from t = 0 (from the first picture when that is earlier), so that a centre
        started again, or a standby taking over, numbers a picture time as the first run did, without
        having seen any of its pictures (a live deployment's times count from the sensors' start); with
        times before 0, once it knows that run's ``first`` (:meth:`numbered`); never below 0. (A count
        of each process's own pictures from 0 gave a cold standby's and a restarted ``serve picture``'s
        pictures the numbers of earlier ones, and the recorder, which keys pictures by number, refused
        them as ``conflict``s.)"""
        return max(round(T / self.period) - (self.first or 0), 0)

    def numbered(self, seq: int, T: float) -> None:
        """Picture ``seq`` of the run is at ``T``: number as it does (a cold standby, from its primary's)."""
        self.first = round(T / self.period) - seq
        self.fixed = True

    def final(self) -> list[float]:
        """Picture times still due at the end of the data: up to the first whole period at or after
        the latest scan, so that the last picture holds every scan; but only up to the latest scan
        when sensors left after it (the trackers of a live run that stopped before its centre:
        a picture past the data would be made without them)."""
        out = []
        while self.k is not None and ((self.k - 1) * self.period < self.high - 1e-9 if not self.departed
                                      else self.k * self.period <= self.high + 1e-9):
            out.append(self.k * self.period)
            self.k += 1
        return out


def central_params(cfg: MttConfig, sensor: str | None, dim: int, present: tuple[str, ...] = (), bit: int = 0,
                   interval: float = 0.0) -> TrackParams:
    """The parameters of ``mtt-centralized``'s tracker for a scan of ``sensor``: the fusion
    centre's policy on a sensor's own tracker's. It counts misses over every sensor's scans, so a
    confirmed track goes after ``CENTRAL_MISSES`` per sensor in a row (the track-to-track
    centre's rule; 3 in a row dropped a live target of three sensors at P_D = 0.9 about once a
    minute among 60; below P_D 0.9 more, :func:`~fedtrack.local_filters.mtt.config.miss_count` of the sensors' mean
    log miss), and its maneuver handling keeps ``window`` candidate onsets per sensor, so that
    the window spans about the time a sensor's own does. The sensors are those ``[mtt] sensors``
    lists, or with ``"any"`` the sensors ``present`` (:meth:`CentralizedEngine.present`: those
    that scanned within ``central_timeout`` of the newest scan; with ``"any"`` the count was 1
    and the miss ``[mtt] pd``'s, so a P_D 0.3 sensor beside a 0.9 one deleted a live track every
    few seconds: 10 id switches among 6 targets in 100 s). ``bit``: the sensor's bit in the tracks'
    ``detected_by`` (:meth:`CentralizedEngine.bit`): a sensor's scans count for a track once it has
    detected it, and a confirmed track goes after ``CENTRAL_MISSES`` misses in a row per sensor that
    detected it (:func:`~fedtrack.local_filters.mtt.roles.life.scan_counts`), so that a target only
    some sensors can see is tracked as well as by those sensors' own trackers. ``interval``: the
    sensor's latest time between its scans (``CentralizedEngine.intervals``); below 1 s a track
    it alone detected goes after at least the misses its own tracker takes there
    (:func:`~fedtrack.local_filters.mtt.config.scan_lost`: ``LOST`` a second as well as a scan). Its
    motion modes are those of a tracker of every sensor (``MttConfig.modes_of(None, ...)``), whatever
    sensor's scan: a coarse sensor's own tracker's CV would switch the tracks' model scan by scan."""
    p = track_params(cfg, sensor, dim, events=True)
    sensors = list(present) if isinstance(cfg.sensors, str) else cfg.sensors
    n = max(len(sensors), 1)
    log_miss = float(np.mean([cfg.log_miss(s) for s in sensors] or [cfg.log_miss()]))  # a scan's miss, on average
    lone = max(cfg.delete_misses, int(miss_count(log_miss)))
    if sensor is not None and scan_lost(interval) < LOST:
        lone = max(lone, cfg.misses_to_delete(sensor, interval))
    return p._replace(delete_misses=max(lone, CENTRAL_MISSES * n), sensor_bit=bit, sensor_misses=CENTRAL_MISSES,
                      lone_misses=lone, maneuver=_every_sensor_window(p.maneuver, n),
                      detector=_every_sensor_window(p.detector, n),
                      modes=cfg.modes_of(None, dim) if p.maneuver is None else None)


@lru_cache(maxsize=16)
def _every_sensor_window(vdie: VdieParams | None, sensors: int) -> VdieParams | None:
    return None if vdie is None else dataclasses.replace(vdie, window=vdie.window * sensors)


def no_tracks(dim: int) -> PictureTracks:
    return PictureTracks([], np.zeros((0, dim)), np.zeros((0, dim, dim)), [], [], [])


def tracker_picture(state: TrackerState, T: float, cfg: MttConfig, sensors: list[str],
                    detector: VdieParams | None = None) -> PictureTracks:
    """The tracker's tracks predicted to ``T``; ``detector``: the parameters its tracks' maneuver
    detectors run with (3-D trackers), which decide what counts as detected."""
    tr = state.tracks
    if not tr.size:
        return no_tracks(tr.x.shape[1])
    x, P = tr.x, tr.P
    if state.t is not None and T > state.t:
        if tr.man is not None:  # each track in its own model (maneuver handling)
            x, P = predicted_view(tr.man, T - state.t, cfg.q, cfg.noise_model)
        elif tr.modes is not None:  # two modes per track: their combination
            x, P = modes_predict(tr.modes, T - state.t, cfg.q, cfg.noise_model, cfg.mode_rates)[1]
        else:
            x, P = predict_batch(x, P, T - state.t, cfg.q, cfg.noise_model)
    maneuver = None if tr.inputs is None or detector is None else tr.inputs.detection.picture_rows(detector)
    existence = None
    if tr.existence is not None:  # predicted to T as the tracks are (jipda.survival)
        existence = existence_predict(tr.existence, jipda.survival(max(T - (state.t or T), 0.0), 1.0,
                                                                   jipda.SURVIVAL_PER_SECOND), 0.0).tolist()
    return PictureTracks(tr.ids.tolist(), x, P, tr.confirmed.tolist(), [sensors] * tr.size, tr.models, maneuver,
                         existence)


@dataclass
class Engine:
    cfg: MttConfig
    dim: int
    late: int = 0  # scans older than max_lag (or than the tracker's checkpoint): not fused
    scans: int = 0  # scans fused
    duplicates: int = 0  # a scan equal to one fused before: not fused again
    conflicts: int = 0  # a second, different scan of a sensor at a time it has one of: not fused (live refuses it)
    rerun: int = 0  # scans run again after an out-of-sequence scan before them
    repeated: int = 0  # detections equal to an earlier one of their scan, dropped (scan.distinct)
    stage_s: dict[str, float] = field(default_factory=dict)  # wall seconds per stage (replay's report)
    lead: LeadGuard | None = None  # the replay's guard against scans stamped far ahead (its `dropped`)
    first_id: int = 0  # the first track id it issues (a live centre that abandoned a start: past those it showed)

    def ingest(self, scan: SensorScan) -> None:
        raise NotImplementedError

    def issue_past(self, shown: int) -> None:
        """Issue no track id up to ``shown`` (the largest id a published picture showed): a fresh engine of a live
        centre that abandoned a start (docs/multitarget.md, "What an abandoned start published")."""
        self.first_id = max(self.first_id, shown + 1)

    def took(self, stage: str, since: float) -> float:
        """Add the time since ``since`` (``time.perf_counter``) to ``stage``; returns now."""
        now = time.perf_counter()
        self.stage_s[stage] = self.stage_s.get(stage, 0.0) + now - since
        return now

    def picture(self, T: float) -> PictureTracks:
        """Every track predicted to ``T`` from the data up to ``T``."""
        raise NotImplementedError

    def data_time(self, sensor: str, t: float) -> float:
        """The time of ``sensor``'s scan stamped ``t`` on the picture clock: ``t`` itself, less a track-to-track
        centre's correction of the sensor's clock (:mod:`~.centre.registration`)."""
        return t

    def leave(self, sensor: str, at_once: bool = False) -> None:
        """A departure (:class:`SensorLeft`), or a sensor silent in a replay (``at_once``)."""

    def restart(self, sensor: str) -> None:
        """``sensor``'s local tracker started afresh (:class:`TrackerRestarted`: a restarted process);
        a tracker of scans (``mtt-centralized``) has no local tracker to restart."""

    def counters(self) -> dict[str, int]:
        return {"scans": self.scans, "late": self.late, "duplicates": self.duplicates, "conflicts": self.conflicts,
                "rerun": self.rerun, "repeated": self.repeated,
                "lead": self.lead.dropped if self.lead is not None else 0}


@dataclass
class ScanTrackerEngine(Engine):
    """A tracker of scans with its :class:`ScanHistory`: out-of-sequence scans up to ``max_lag``
    old fused exactly (the later ones run again from the state before them), older ones late.
    It keeps the states of the last ``max_lag`` (>= ``picture_delay``) seconds, so a picture at
    ``T`` comes from the state after the last scan up to ``T`` (mht's: with the tracks a few scans
    later decided, :meth:`mht_state_at`)."""

    history: ScanHistory[TrackerState, SensorScan] | None = None

    def params(self, sensor: str | None) -> TrackParams:
        raise NotImplementedError

    def takes(self, scan: SensorScan) -> bool:
        return True

    def _step(self, state: TrackerState, scan: SensorScan) -> TrackerState:
        return tracker_step(state, scan, self.params(scan.sensor)).state

    def ingest(self, scan: SensorScan) -> None:
        if not self.takes(scan):
            return
        if self.history is None:
            self.history = ScanHistory(initial_state(self.dim, self.first_id), self.cfg.max_lag)
        if self.history.is_late(scan.t):
            self.late += 1
            return
        if is_duplicate(self.history, scan, lambda s: s):
            self.duplicates += 1
            return
        if is_conflict(self.history, scan, lambda s: s):
            self.conflicts += 1
            return
        self.scans += 1
        start = time.perf_counter()
        k = self.history.insert(scan.t, scan, self._step)
        self.rerun += len(self.history.times) - 1 - k
        self.took("tracker", start)
        self.history.fold()

    def senders(self) -> list[str]:
        raise NotImplementedError

    def picture(self, T: float) -> PictureTracks:
        if self.history is None:
            return no_tracks(self.dim)
        params = self.params(None)
        state = self.history.state_at(T) if params.mht is None else self.mht_state_at(T, params)
        return tracker_picture(state, T, self.cfg, self.senders(), params.detector)

    def mht_state_at(self, T: float, params: TrackParams) -> TrackerState:
        """``associator = "mht"``: the state after the last scan up to ``T`` with the tracks that
        the best hypothesis ``window - 1`` scans later decided (:func:`mht_decided`: its N-scan
        pruning made their assignments up to ``T`` final), or that of the newest scan if fewer
        have arrived; with none after ``T`` (``picture_delay = 0``), the state itself. At most
        ``delete_misses - 1`` scans later: a confirmed track that this hypothesis deleted had then
        missed every scan since before ``T`` (deletion takes ``delete_misses`` misses in a row), so
        its leaving the picture at ``T`` is the decision that it was gone by ``T``."""
        assert self.history is not None and params.mht is not None
        then = self.history.state_at(T)
        later, back = self.history.state_after(T, min(params.mht.window, params.delete_misses) - 1)
        return mht_decided(then, later, back, params.mht.management) if back else then


@dataclass
class LocalEngine(ScanTrackerEngine):
    """``mtt-local``: the tracker of ``sensor``; other sensors' scans are ignored."""

    sensor: str = ""

    away: bool = False  # the sensor fell silent (replay.pictures) and has not scanned since

    def takes(self, scan: SensorScan) -> bool:
        return scan.sensor == self.sensor

    def ingest(self, scan: SensorScan) -> None:
        self.away = self.away and not self.takes(scan)
        super().ingest(scan)

    def leave(self, sensor: str, at_once: bool = False) -> None:
        self.away = self.away or (at_once and sensor == self.sensor)

    def restart(self, sensor: str) -> None:
        if sensor == self.sensor:
            self.history = None

    def picture(self, T: float) -> PictureTracks:
        """The tracks at ``T``; none while the sensor is silent (as the centre drops a silent
        sensor's tracks: its tracker keeps them, and they come back with its next scan)."""
        return no_tracks(self.dim) if self.away else super().picture(T)

    def params(self, sensor: str | None) -> TrackParams:
        return track_params(self.cfg, self.sensor, self.dim, events=True)

    def senders(self) -> list[str]:
        return [self.sensor]


@dataclass
class CentralizedEngine(ScanTrackerEngine):
    """``mtt-centralized``: one tracker of every sensor's scans, with the centre's policy
    (:func:`central_params`)."""

    seen: dict[str, float] = field(default_factory=dict)  # sensor -> the time of its newest scan
    quiet: bool = False  # every sensor fell silent (replay.pictures) and none has scanned since
    bits: dict[str, int] = field(default_factory=dict)  # sensor -> its bit in the tracks' detected_by
    intervals: dict[str, float] = field(default_factory=dict)  # sensor -> its latest time between scans
    copies: int = 0  # scans equal to another sensor's (a duplicated feed): not fused, the sensor not seen
    noise_raised: int = 0  # detections whose scan's R claimed less than its sensor's noise_floor: raised to it
    floor_mismatch: int = 0  # scans whose size is not their sensor's noise_floor's: not fused
    frame: Frame | None = None  # [frame]: each radar's view in its own axes (roles.life.radar_view)
    noise: dict[str, np.ndarray] = field(default_factory=dict)  # position sensor -> its latest scan's R

    def bit(self, sensor: str) -> int:
        """The sensor's bit in the tracks' ``detected_by``, in order of first scan (beyond 63
        sensors two share a bit: a track detected by one counts the other's scans as well)."""
        return 1 << self.bits.setdefault(sensor, len(self.bits) % 63)

    def ingest(self, scan: SensorScan) -> None:
        floor = self.cfg.noise_floor_of(scan.sensor)
        if floor is not None:  # the centre's noise floor (local_filters/linear/noise_floor.py), as track-to-track
            if floor.size != scan.dim:
                self.floor_mismatch += 1
                return
            R, raised = raise_to_floor(scan.R[None], floor)
            if raised[0]:
                scan = scan._replace(R=R[0])
                self.noise_raised += scan.z.shape[0]
        if self.history is not None and copies_another(self.history, scan, lambda s: s):
            self.copies += 1
            return
        newest = self.seen.get(scan.sensor, scan.t)
        if scan.t > newest:
            self.intervals[scan.sensor] = scan.t - newest
        if scan.dim == 2:
            self.noise[scan.sensor] = scan.R
        self.seen[scan.sensor] = max(scan.t, newest)
        self.quiet = False
        super().ingest(scan)

    def counters(self) -> dict[str, int]:
        return {**super().counters(), "copies": self.copies, "noise_raised": self.noise_raised,
                "floor_mismatch": self.floor_mismatch}

    def leave(self, sensor: str, at_once: bool = False) -> None:
        self.seen.pop(sensor, None)
        self.intervals.pop(sensor, None)
        self.quiet = self.quiet or (at_once and not self.seen)

    def picture(self, T: float) -> PictureTracks:
        """The tracks at ``T``; none while every sensor is silent (replay.pictures)."""
        return no_tracks(self.dim) if self.quiet else super().picture(T)

    def present(self) -> tuple[str, ...]:
        """The sensors that scanned within ``central_timeout`` of the newest scan (a sensor silent
        that long is not live: the track-to-track centre's rule)."""
        newest = max(self.seen.values(), default=0.0)
        return tuple(sorted(s for s, t in self.seen.items() if newest - t <= self.cfg.central_timeout))

    def params(self, sensor: str | None) -> TrackParams:
        """:func:`central_params` of a scan of ``sensor``. Any sensor's scans may hit a track started on any one's
        clutter: where the count rules the tracks (``gnn``, mht's ``"counts"``) and the most cluttered present
        position sensor's tracker would raise its own count (:meth:`MttConfig.raised_count_of` at its latest
        ``R`` and interval), the tracker keeps the configured count and weighs each scan's evidence
        (``weighed``, ``roles.life.count_life``; raising the count to the worst sensor's, 12 of 13 beside a
        300 m sensor, held back the tracks a 1 m sensor confirms in three scans: docs/multitarget.md,
        mixnoise60). A tracker that keeps no evidence takes the raised count."""
        present = self.present()
        if sensor is None:
            return central_params(self.cfg, sensor, self.dim, present)
        p = central_params(self.cfg, sensor, self.dim, present, self.bit(sensor),
                           self.intervals.get(sensor, 0.0))._replace(frame=self.frame)
        if self.cfg.confirm_bound is not None:
            return p
        hits, window = max([(p.confirm_hits, p.confirm_window)] + [
            self.cfg.raised_count_of(s, self.noise[s], self.intervals.get(s, 1.0)) for s in present if s in self.noise])
        if keeps_evidence(p) and (hits, window) != (p.confirm_hits, p.confirm_window):
            return p._replace(weighed=True)
        return p._replace(confirm_hits=hits, confirm_window=window)

    def senders(self) -> list[str]:
        return sorted({s.sensor for s in self.history.entries}) if self.history is not None else []


@dataclass
class TrackToTrackEngine(Engine):
    """``mtt-federated`` (``feedback``) or ``mtt-decentralized``: local trackers plus the centre.

    A scan goes through its sensor's tracker (:class:`SensorTracker`: out-of-sequence scans of the
    sensor within ``max_lag`` fused exactly), the report through the centre, and the centre's
    resets and next process-noise factor (the number of live sensors) back to the tracker:
    what the live services do message by message."""

    feedback: bool = True
    local: dict[str, SensorTracker] = field(default_factory=dict)
    centre: TrackToTrackCentre | ShardedCentre | None = None
    regions: Regions | None = None  # a centre per region (:class:`ShardedCentre`), else one centre
    existence: CentralExistence | None = None  # the local trackers keep existence (jipda)
    sites: dict[str, RadarSite] = field(default_factory=dict)  # [frame.sites]: the centre's radars' sites
    frame: Frame | None = None  # [frame]: a 2-D report's track starts at the origin's height there (level_z)

    def ingest(self, scan: SensorScan) -> None:
        tracker = self.local.get(scan.sensor)
        if tracker is None:
            tracker = self.local[scan.sensor] = SensorTracker(scan, self.cfg, self.feedback)
        if tracker.is_late(scan):
            self.late += 1
            return
        if tracker.is_duplicate(scan):
            self.duplicates += 1
            return
        if tracker.is_conflict(scan):
            self.conflicts += 1
            return
        start = time.perf_counter()
        report, rerun = tracker.track(scan)
        self.rerun += rerun
        start = self.took("local trackers", start)
        resets, q_scale = self.fuse(report)
        start = self.took("centre", start)
        tracker.adopt(scan, resets, q_scale)
        self.took("local trackers", start)

    def leave(self, sensor: str, at_once: bool = False) -> None:
        """``sensor`` left: its local tracks leave their central tracks (``at_once``: and the central
        tracks it alone supported go now, not at the next report, as ``replay`` does for a silent
        sensor, whose pictures until then would show them; a live departure keeps the rule by which
        its recording replays to its pictures)."""
        if self.centre is not None:
            self.centre.drop_sensor(sensor)
        centres = [] if self.centre is None or not at_once else (
            [c.centre for c in self.centre.centres] if isinstance(self.centre, ShardedCentre) else [self.centre])
        for c in centres:
            c.drop_unsupported()
        if self.existence is not None:
            self.existence.leave(sensor)

    def restart(self, sensor: str) -> None:
        """The sensor's tracker starts afresh with its next scan, and the centre drops the local
        tracks of its former process (their ids will be issued again), as at a departure."""
        self.local.pop(sensor, None)
        if self.centre is not None:
            self.centre.drop_sensor(sensor, departed=False)
        if self.existence is not None:
            self.existence.leave(sensor)

    def fuse(self, report: LocalReport) -> tuple[Resets, float]:
        """The centre's part of a scan, as the live centre does it per report."""
        if self.centre is None:
            self.centre = (TrackToTrackCentre(self.cfg, self.dim, self.feedback, sites=self.sites, frame=self.frame,
                                              next_id=self.first_id)
                           if self.regions is None
                           else ShardedCentre(self.cfg, self.dim, self.feedback, self.regions, sites=self.sites,
                                            frame=self.frame))
        self.scans += 1
        if report.existence is not None:
            self.existence = self.existence or CentralExistence()
            self.existence.report(report)
        return self.centre.answer(report)

    def picture(self, T: float) -> PictureTracks:
        if self.centre is None:
            return no_tracks(self.dim)
        if isinstance(self.centre, ShardedCentre):
            picture = union_picture([centre_picture(c.centre, T, self.existence) for c in self.centre.centres],
                                    self.dim)
        else:
            picture = centre_picture(self.centre, T, self.existence) or no_tracks(self.dim)
        if self.existence is not None:
            self.existence.retain(picture.ids)
        return picture

    def data_time(self, sensor: str, t: float) -> float:
        """``t`` less the centre's clock correction of ``sensor`` (a centre of regions: each corrects its own
        reports; the picture clock keeps the stamps)."""
        return t - self.centre.registration.clock(sensor) if isinstance(self.centre, TrackToTrackCentre) else t

    def registrations(self) -> list[SensorRegistration]:
        """The centre's registration estimators (each region's)."""
        if isinstance(self.centre, ShardedCentre):
            return [c.centre.registration for c in self.centre.centres]
        return [] if self.centre is None else [self.centre.registration]

    def consistency_transitions(self) -> list[Transition]:
        """The sensors flagged or cleared by the centre's consistency test (each region's) since the last call."""
        if isinstance(self.centre, ShardedCentre):
            return sorted(tr for c in self.centre.centres for tr in c.centre.consistency.drain())
        return [] if self.centre is None else self.centre.consistency.drain()

    def feed_copies(self) -> list[Found]:
        """The sensors found to copy another's feed, or released, by the centre (each region's) since the last call."""
        if isinstance(self.centre, ShardedCentre):
            return sorted({f for c in self.centre.centres for f in c.centre.copies.drain()})  # each region finds it
        return [] if self.centre is None else self.centre.copies.drain()

    def inconsistent_sensors(self) -> list[str]:
        """The sensors the centre (some region's) flags inconsistent now."""
        if isinstance(self.centre, ShardedCentre):
            return sorted({s for c in self.centre.centres for s in c.centre.consistency.flagged})
        return [] if self.centre is None else sorted(self.centre.consistency.flagged)

    def counters(self) -> dict[str, int]:
        out = super().counters()
        if isinstance(self.centre, ShardedCentre):
            out.update({f"centre_{k}": v for k, v in self.centre.counters().items()})
        elif self.centre is not None:
            out.update({f"centre_{k}": v for k, v in vars(self.centre.counters).items()})
        return out


@dataclass
class CentralExistence:
    """The existence of the track-to-track centre's tracks when the local trackers keep one (jipda:
    ``TrackReport.existence``). The centre runs no existence recursion of its own: a central
    track's existence is the largest among the local tracks mapped to it, each as its latest
    report gave it (a target is there if any sensor's tracker is sure of it); a central track that
    no local track holds any more keeps the value it had."""

    local: dict[tuple[str, int], float] = field(default_factory=dict)  # (sensor, local id) -> latest
    central: dict[int, float] = field(default_factory=dict)  # central id -> value of the last picture

    def report(self, report: LocalReport) -> None:
        assert report.existence is not None
        for lid in report.retired.tolist():
            self.local.pop((report.sensor, lid), None)
        self.local.update(zip(((report.sensor, lid) for lid in report.ids.tolist()), report.existence.tolist()))

    def leave(self, sensor: str) -> None:
        for key in [k for k in self.local if k[0] == sensor]:
            del self.local[key]

    def of(self, c: TrackToTrackCentre, ids: list[int]) -> list[float]:
        """The existence of central tracks ``ids`` of centre ``c`` (0.0 for one never reported)."""
        best: dict[int, float] = {}
        for key, cid in c.mapping.items():
            e = self.local.get(key)
            if e is not None and e > best.get(cid, -1.0):
                best[cid] = e
        self.central.update(best)
        return [self.central.get(cid, 0.0) for cid in ids]

    def retain(self, ids: list[int]) -> None:
        """Forget the last values of central tracks no longer in the picture (deleted or merged)."""
        self.central = {cid: self.central[cid] for cid in ids if cid in self.central}


def centre_picture(c: TrackToTrackCentre, T: float, existence: CentralExistence | None = None) -> PictureTracks | None:
    """A centre's central tracks predicted to ``T`` (None without tracks), with the confirmed ones
    deleted since that were last supported at or after ``T`` (:class:`DepartedTracks`)."""
    slots = c.tracks.live()
    began, confirmed = c.tracks.as_of(slots, T)
    slots, confirmed = slots[began], confirmed[began]
    gone = c.departed.shown_at(T)
    if not slots.size and not gone.size:
        return None
    parts = [(c.tracks, slots), (c.departed.tracks, gone)]
    states = [table.states_at(s, T) for table, s in parts]
    X, P = np.concatenate([x for x, _ in states]), np.concatenate([p for _, p in states])
    maneuver = None
    if c.tracks.detector is not None:
        maneuver = np.concatenate([table.maneuvers_at(s, T).picture_rows(table.detector) for table, s in parts])
    ids = c.tracks.ids[slots].tolist() + c.departed.tracks.ids[gone].tolist()
    sensors = c.sensor_lists(slots) + [c.departed.sensors[cid] for cid in ids[slots.size:]]
    flags = confirmed.tolist() + [True] * gone.size
    order = np.argsort(ids, kind="stable")
    pick = order.tolist()
    return PictureTracks([ids[k] for k in pick], X[order], P[order], [flags[k] for k in pick],
                         [sensors[k] for k in pick], ["cv"] * len(ids), None if maneuver is None else maneuver[order],
                         None if existence is None else existence.of(c, [ids[k] for k in pick]))


def union_picture(parts: list[PictureTracks | None], dim: int) -> PictureTracks:
    """The regions' pictures as one, in increasing id (a track is in one region only). A part
    without a detector's rows or existence beside one with them (a region centre that has had no
    report with existence yet) gives its tracks no detected maneuver and an existence of 1, as a
    tracker keeping none treats its tracks."""
    parts = [p for p in parts if p is not None]
    if not parts:
        return no_tracks(dim)
    ids = [i for p in parts for i in p.ids]
    pick = np.argsort(ids, kind="stable").tolist()

    def joined(name: str) -> list:
        rows = [row for p in parts for row in getattr(p, name)]
        return [rows[k] for k in pick]

    maneuver = existence = None
    if any(p.maneuver is not None for p in parts):
        maneuver = np.concatenate([np.full((len(p.ids), 4), np.nan) if p.maneuver is None else p.maneuver
                                   for p in parts])[pick]
    if any(p.existence is not None for p in parts):
        rows = [e for p in parts for e in ([1.0] * len(p.ids) if p.existence is None else p.existence)]
        existence = [rows[k] for k in pick]
    return PictureTracks(joined("ids"), np.concatenate([p.x for p in parts])[pick],
                         np.concatenate([p.P for p in parts])[pick], joined("confirmed"), joined("sensors"),
                         joined("models"), maneuver, existence)


def make_engine(algorithm: str, cfg: MttConfig, dim: int, sensor: str | None = None,
                regions: Regions | None = None, frame: Frame | None = None,
                sites: dict[str, RadarSite] | None = None) -> Engine:
    if algorithm == "mtt-local":
        if not sensor:
            raise ValueError("mtt-local needs --sensor ID")
        return LocalEngine(cfg, dim, sensor=sensor)
    if algorithm == "mtt-centralized":
        return CentralizedEngine(cfg, dim, frame=frame)
    if algorithm in ("mtt-federated", "mtt-decentralized"):
        return TrackToTrackEngine(cfg, dim, feedback=algorithm == "mtt-federated", regions=regions, sites=sites or {},
                                  frame=frame)
    raise ValueError(f"unknown multi-target algorithm {algorithm!r}")
