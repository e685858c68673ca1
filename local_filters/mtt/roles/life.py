"""Role 6 of a scan, confirmation and deletion: M-of-N (:func:`m_of_n`), or by existence for
``jipda`` (:func:`existence_manage`); the misses in a row that delete a track on a fast sensor
(:func:`deletion_at`); the count raised on a cluttered sensor's scans (:func:`count_at`); and, in a
tracker of several sensors' scans, which scans count for a track
(:func:`scan_sees`, :func:`scan_counts`)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fedtrack.geodetic import Frame, own_axes
from fedtrack.local_filters.mtt.associators import jipda
from fedtrack.local_filters.mtt.config import LOST, clutter_hit, log_miss_of, miss_count, raised_count, scan_lost
from fedtrack.local_filters.mtt.roles.gating import Gating
from fedtrack.local_filters.mtt.roles.tracks import TrackParams, TrackSet
from fedtrack.local_filters.mtt.scan import SensorScan
from fedtrack.local_filters.radar.measurement import cartesian_from_polar


def popcount(bits: np.ndarray) -> np.ndarray:
    """The set bits of each int64 of ``bits`` (N,)."""
    return np.unpackbits(np.ascontiguousarray(bits, dtype=np.int64).view(np.uint8).reshape(-1, 8), axis=1).sum(axis=1)


class Sight(NamedTuple):
    """What one scan of a tracker of several sensors' scans shows of each track's place
    (:func:`scan_sees`): ``place``, that its sensor sees it (a detection in the track's gate, or the
    track inside the extent of the scan's detections); ``view``, that the track is inside the
    radar's view the detections show (True for a position scan: its extent is ``place``'s)."""

    place: np.ndarray  # (N,) bool
    view: np.ndarray  # (N,) bool

    def take(self, idx: np.ndarray) -> Sight:
        return Sight(self.place[idx], self.view[idx])

    def counts(self, detected_by: np.ndarray, sensor_bit: int) -> np.ndarray:
        """The tracks the scan counts for: its sensor sees the place, or detected the track before
        and the track is still inside its view (or no other sensor detected it: the sensor that
        holds a track alone always counts, so that it can be deleted)."""
        others = (detected_by & ~sensor_bit) != 0
        return (((detected_by & sensor_bit) != 0) & (self.view | ~others)) | self.place


def radar_view(x: np.ndarray, scan: SensorScan, frame: Frame | None = None) -> np.ndarray:
    """Per track (its predicted state in ``x``, 3-D), whether it is inside a radar scan's view as
    its detections (targets' and clutter) show it, seen from ``sensor_position``: at an elevation
    above the lowest detection's (below it: the radar's horizon or lowest beam), at a range below
    the farthest detection's (its reach), and in the arc of azimuth the detections span (its sector:
    outside the largest gap between neighbouring detections' azimuths). A track on an edge is outside.
    With a ``frame`` (the common frame on the Earth) the elevations and azimuths are the radar's own,
    about its site's east-north-up axes (:func:`fedtrack.geodetic.own_axes`): its horizontal leans from
    the common frame's by the angle between their normals, 1.75 deg at 195 km, and in the common axes
    the lowest detection away from the origin is that much lower than the radar's horizon towards it."""
    rel = x[:, [0, 2, 4]] - scan.sensor_position
    a, e = scan.z[:, 1], scan.z[:, 2]
    if frame is not None:
        axes = own_axes(frame, tuple(scan.sensor_position.tolist()))
        rel, own = rel @ axes.T, cartesian_from_polar(scan.z) @ axes.T
        a, e = np.arctan2(own[:, 1], own[:, 0]), np.arctan2(own[:, 2], np.hypot(own[:, 0], own[:, 1]))
    rng = np.linalg.norm(rel, axis=1)
    el = np.arctan2(rel[:, 2], np.hypot(rel[:, 0], rel[:, 1]))
    az = np.arctan2(rel[:, 1], rel[:, 0])
    r, a = scan.z[:, 0], np.sort(np.mod(a, 2 * np.pi))
    gaps = np.diff(np.concatenate([a, a[:1] + 2 * np.pi]))
    k = int(np.argmax(gaps))  # the largest gap: from a[k] on, counter-clockwise, for gaps[k]
    return (el > e.min()) & (rng < r.max()) & (np.mod(az - a[k], 2 * np.pi) > gaps[k])


def held(tracks: TrackSet, bit: int) -> int:
    """The confirmed tracks (distinct ids: mht's branches share their track's) that the sensor of
    ``bit`` has detected, in a tracker of several sensors' scans."""
    if not bit or tracks.detected_by is None:
        return 0
    return int(np.unique(tracks.ids[tracks.confirmed & ((tracks.detected_by & bit) != 0)]).size)


def empty_shows_blind(pd: float, held_tracks: int) -> bool:
    """Whether a scan without a detection shows its sensor blind rather than missing every one of the
    ``held_tracks`` confirmed tracks it detected before: a sensor that sees them all misses them all
    with a chance of ``(1 - pd)^held_tracks`` (its clutter's absence left aside), at most ``LOST``
    (the deletion rule's chance of losing a live target) from :func:`miss_count` tracks on (3 at
    P_D 0.9)."""
    return held_tracks > 0 and held_tracks >= int(miss_count(log_miss_of(pd)))


def scan_sees(x: np.ndarray, gating: Gating | None, scan: SensorScan, params: TrackParams, held_tracks: int = 0
              ) -> Sight | None:
    """In a tracker of several sensors' scans (``params.sensor_bit``; else None), per track (its
    predicted state in ``x``) what the scan shows of its place (:class:`Sight`): a detection of the
    scan in the track's gate, or the track's position strictly inside the x-y extent of the scan's
    detections (targets' and clutter: a sensor's detections lie in what it sees; a sensor that
    covers the area puts its clutter all round a track) and, for a radar, inside its view
    (:func:`radar_view`: a far radar's clutter surrounds a low aircraft in x-y, above its horizon).
    A scan without a detection whose sensor had detected ``held_tracks`` confirmed tracks (:func:`held`),
    too many for it to miss them all at once (:func:`empty_shows_blind`: a sensor blinded, jammed or
    cut off that still sends its scans), shows no view: it counts only for the tracks no other
    sensor detected (:meth:`Sight.counts`), as a sensor's silence counts for none."""
    if not params.sensor_bit:
        return None
    n = x.shape[0]
    sees = np.zeros(n, dtype=bool) if gating is None else np.bincount(gating.pairs.rows, minlength=n) > 0
    view = np.ones(n, dtype=bool)
    if not scan.z.shape[0] and empty_shows_blind(params.pd, held_tracks):
        return Sight(sees, ~view)
    if n and scan.z.shape[0] > 1:
        pos = scan.z if scan.sensor_position is None else scan.sensor_position + cartesian_from_polar(scan.z)
        xy = pos[:, :2]
        lo, hi, at = xy.min(axis=0), xy.max(axis=0), x[:, [0, 2]]
        if scan.sensor_position is not None:
            view = radar_view(x, scan, params.frame)
        sees |= ((at > lo) & (at < hi)).all(axis=1) & view
    return Sight(sees, view)


def scan_counts(tracks: TrackSet, detected: np.ndarray, params: TrackParams, sight: Sight | None = None
                ) -> tuple[TrackSet, np.ndarray | bool, np.ndarray | int]:
    """Which tracks the scan counts for in the life rules, and the misses in a row that delete each.

    One sensor's tracker: every track, ``delete_misses``. A tracker of several sensors' scans
    (``params.sensor_bit``): a sensor's scan counts for a track where the scan shows that the
    sensor sees the track's place (``sight``, :func:`scan_sees`: a detection in its gate, as beside
    a target's own track for its twin, or the track inside the extent of the scan's detections), or
    once that sensor has detected the track (now or before: ``detected_by``) while the track is
    inside the radar's view the scan shows (a track that descended below a radar's horizon is no
    longer counted by it, unless no other sensor detected it); a sensor that has none of these may not see the target at
    all (out of its range or field of view, behind the horizon), and its misses are then no
    evidence against it (docs/multitarget.md#sensors-that-cannot-see-a-target). A confirmed track
    is deleted after ``sensor_misses`` misses in a row per sensor that detected it, at least
    ``lone_misses``, at most ``delete_misses``."""
    if not params.sensor_bit or tracks.detected_by is None:
        return tracks, True, params.delete_misses
    by = tracks.detected_by | np.where(detected, params.sensor_bit, 0)
    counted = (by & params.sensor_bit) != 0 if sight is None else sight.counts(by, params.sensor_bit) | detected
    need = np.clip(params.sensor_misses * popcount(by), params.lone_misses, params.delete_misses)
    return tracks._replace(detected_by=by), counted, need


def m_of_n(tracks: TrackSet, detected: np.ndarray, params: TrackParams, sees: Sight | None = None
           ) -> tuple[TrackSet, np.ndarray]:
    """Role 6: the track counts after the scan, and which tracks stay (M-of-N confirmation,
    deletion after ``delete_misses`` consecutive misses; the scans counted: :func:`scan_counts`,
    ``sees``: :func:`scan_sees`)."""
    tracks, counted, need = scan_counts(tracks, detected, params, sees)
    hits = tracks.hits + detected
    age = tracks.age + counted
    misses = np.where(detected, 0, tracks.misses + counted)
    confirmed = tracks.confirmed | (hits >= params.confirm_hits)
    live = np.where(confirmed, misses < need, params.confirm_window - age >= params.confirm_hits - hits)
    return tracks._replace(hits=hits, age=age, misses=misses, confirmed=confirmed), live


def existence_manage(tracks: TrackSet, detected: np.ndarray, params: TrackParams, sees: Sight | None = None
                     ) -> tuple[TrackSet, np.ndarray]:
    """Role 6 for ``jipda``: confirmation and deletion by existence (:func:`jipda.derived_rules`);
    the counts kept as :func:`m_of_n` keeps them."""
    counted, _ = m_of_n(tracks, detected, params, sees)
    if tracks.existence is None:  # no tracks yet
        return counted, np.zeros(tracks.size, bool)
    pg = jipda.scan_constants(params.pd, params.clutter_density, params.gate[2], 2).pg
    confirmed, live = jipda.manage(tracks.existence, tracks.confirmed, jipda.derived_rules(params.pd, pg))
    return counted._replace(confirmed=confirmed), live


def deletion_at(params: TrackParams, dt: float) -> TrackParams:
    """``params`` for a scan ``dt`` [s] after the tracker's last: ``delete_misses`` at least the
    misses in a row whose chance for a live target at ``pd`` is at most
    :func:`~..config.scan_lost` (``LOST`` a second as well as a scan: at P_D 0.9, 4 from 0.1 s to
    1 s apart, 5 at 20 Hz). In a tracker of several sensors' scans (``sensor_bit``) that is the
    cap of :func:`scan_counts`; a track one sensor detected takes that sensor's own interval
    (``lone_misses``, set in ``mtt-centralized``'s parameters)."""
    lost = scan_lost(dt)
    if lost == LOST:
        return params
    m = int(miss_count(log_miss_of(params.pd), lost))
    return params._replace(delete_misses=m) if m > params.delete_misses else params


def count_at(params: TrackParams, scan: SensorScan, dt: float) -> TrackParams:
    """``params`` for a position scan ``dt`` [s] after the tracker's last, where the M-of-N count
    rules the tracks (``gnn``, mht's ``"counts"``): ``confirm_hits`` and ``confirm_window`` raised
    (:func:`~..config.raised_count`: the smallest window, then hits, never fewer of either or of the
    misses allowed than configured) until the chance of confirming a track started on the scan's
    clutter is at most jipda's bound, 0.01, each later scan hitting it with the chance
    :func:`~..config.clutter_hit` gives at the scan's ``R`` and clutter density over ``dt`` (at least
    1 s: as the deletion counts, judged a second on a faster sensor), while a real target keeps a
    chance of 1/2 of confirming within the window. A radar's scan (its density per m rad^2) and a
    sensor without clutter keep the configured count."""
    if (scan.dim != 2 or params.clutter_density <= 0 or params.initial_existence is not None
            or params.mht is not None and params.mht.management != "counts"):
        return params
    hit = clutter_hit(params.clutter_density, scan.R, dt, params.init_velocity_std, params.gate[2])
    hits, window = raised_count(hit, params.pd, params.confirm_hits, params.confirm_window)
    if (hits, window) == (params.confirm_hits, params.confirm_window):
        return params
    return params._replace(confirm_hits=hits, confirm_window=window)
