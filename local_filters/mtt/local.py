"""A sensor's local multi-target tracker as the fusion centre sees it: the report of each scan,
the federated resets it adopts, and both as wire messages.

The replay engine (:mod:`fedtrack.fusion_center.mtt.engines`) and the live service
(:mod:`fedtrack.local_filters.mtt.service`) run the same :func:`local_step` and
:func:`adopt`, so a deployment and the replay of its recorded scans agree exactly.

Federated timing: the process-noise factor ``q_scale`` (``beta_i``, the number of live
sensors) a tracker uses for a scan is the one the centre returned with the resets of the
tracker's previous report (1 before the first answer), so a live tracker never needs to
know what the centre knows at the moment its next scan arrives.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fedtrack import wire
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.scan import SensorScan
from fedtrack.local_filters.mtt.tracker import TrackerState, initial_state, track_params, tracker_step


class LocalReport(NamedTuple):
    """One local tracker's output for one scan, local tracks in the local state size ``d``."""

    sensor: str
    t: float
    ids: np.ndarray  # (N,) every live local track
    x: np.ndarray  # (N, d)
    P: np.ndarray  # (N, d, d)
    confirmed: np.ndarray  # (N,)
    detected: np.ndarray  # (N,) bool: tracks this scan updated or started
    obs_H: np.ndarray  # (K, m, d) for the detected tracks in order
    obs_R: np.ndarray  # (K, m, m)
    obs_z: np.ndarray  # (K, m)
    started: np.ndarray  # (K,) bool: the detected track started at this scan
    retired: np.ndarray  # ids deleted by this scan


class Resets(NamedTuple):
    """Federated feedback for local tracks ``ids`` of one sensor: ``x`` (n, d) and ``beta_i P``
    (n, d, d) at ``t`` (local state size)."""

    sensor: str
    t: float
    ids: np.ndarray  # (n,) local track ids
    x: np.ndarray
    P: np.ndarray


def no_resets(sensor: str, t: float, d: int) -> Resets:
    return Resets(sensor, t, np.zeros(0, dtype=np.int64), np.zeros((0, d)), np.zeros((0, d, d)))


class LocalTracker(NamedTuple):
    """A local tracker's state and the process-noise factor for its next scan."""

    state: TrackerState
    q_scale: float = 1.0
    feedback: bool = False  # federated: the centre's resets own its state (no maneuver handling)


def new_local_tracker(scan: SensorScan, feedback: bool = False) -> LocalTracker:
    """An empty tracker for the sensor of ``scan`` (a 3-D state for a radar)."""
    return LocalTracker(initial_state(6 if scan.sensor_position is not None else 4), feedback=feedback)


def is_late(tracker: LocalTracker, scan: SensorScan) -> bool:
    """A sensor's own scan older than its tracker (its link is not FIFO): dropped and counted."""
    return tracker.state.t is not None and scan.t < tracker.state.t


def local_step(tracker: LocalTracker, scan: SensorScan, cfg: MttConfig) -> tuple[LocalTracker, LocalReport]:
    """Track one scan (not late) and report it."""
    d = tracker.state.tracks.x.shape[1]
    res = tracker_step(tracker.state, scan, track_params(cfg, scan.sensor, d, tracker.feedback),
                       q_scale=tracker.q_scale)
    tr = res.state.tracks
    started = tr.age[res.detected] == 1
    report = LocalReport(scan.sensor, scan.t, tr.ids, tr.x, tr.P, tr.confirmed, res.detected,
                         *res.observations, started, res.retired)
    return tracker._replace(state=res.state), report


def adopt(tracker: LocalTracker, resets: Resets, q_scale: float) -> LocalTracker:
    """Take the centre's resets (by local track id; ids no longer live are ignored; for an id
    given twice, the last) and the process-noise factor for the next scan."""
    tr = tracker.state.tracks
    if resets.ids.size and tr.ids.size:
        order = np.argsort(tr.ids, kind="stable")
        at = np.minimum(np.searchsorted(tr.ids, resets.ids, sorter=order), tr.ids.size - 1)
        rows = order[at]
        live = tr.ids[rows] == resets.ids
        x, P = tr.x.copy(), tr.P.copy()
        x[rows[live]], P[rows[live]] = resets.x[live], resets.P[live]
        tr = tr._replace(x=x, P=P)
    return tracker._replace(state=tracker.state._replace(tracks=tr), q_scale=q_scale)


# ---------------------------------------------------------------- wire

def report_to_wire(report: LocalReport, seq: int, stamp_ns: int) -> wire.TrackReport:
    d = report.x.shape[1]
    k, m = report.obs_z.shape
    return wire.TrackReport.unchecked(
        sensor=report.sensor, seq=seq, t=report.t, ids=tuple(report.ids.tolist()), x=report.x,
        P=report.P.reshape(-1, d), confirmed=tuple(report.confirmed.tolist()),
        detected=tuple(report.detected.tolist()), obs_H=report.obs_H.reshape(k * m, d),
        obs_R=report.obs_R.reshape(k * m, m), obs_z=report.obs_z, started=tuple(report.started.tolist()),
        retired=tuple(report.retired.tolist()), stamp_ns=stamp_ns)


def report_from_wire(msg: wire.TrackReport) -> LocalReport:
    d = msg.x.shape[1]
    k, m = msg.obs_z.shape
    return LocalReport(msg.sensor, msg.t, np.array(msg.ids, dtype=np.int64), np.array(msg.x),
                       np.array(msg.P).reshape(-1, d, d), np.array(msg.confirmed, dtype=bool),
                       np.array(msg.detected, dtype=bool), np.array(msg.obs_H).reshape(k, m, d),
                       np.array(msg.obs_R).reshape(k, m, m), np.array(msg.obs_z), np.array(msg.started, dtype=bool),
                       np.array(msg.retired, dtype=np.int64))


def resets_to_wire(seq: int, resets: Resets, q_scale: float) -> wire.TrackResets:
    """The resets (possibly none) answering report ``seq``."""
    d = resets.x.shape[1]
    return wire.TrackResets.unchecked(sensor=resets.sensor, seq=seq, t=resets.t, q_scale=q_scale,
                                      ids=tuple(resets.ids.tolist()), x=resets.x, P=resets.P.reshape(-1, d))


def resets_from_wire(msg: wire.TrackResets) -> Resets:
    d = msg.x.shape[1]
    return Resets(msg.sensor, msg.t, np.array(msg.ids, dtype=np.int64), np.array(msg.x),
                  np.array(msg.P).reshape(-1, d, d))
