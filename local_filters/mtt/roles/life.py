"""Role 6 of a scan, confirmation and deletion: M-of-N (:func:`m_of_n`), or by existence for
``jipda`` (:func:`existence_manage`); the misses in a row that delete a track on a fast sensor
(:func:`deletion_at`); the count raised on a cluttered sensor's scans (:func:`count_at`); and, in a
tracker of several sensors' scans, which scans count for a track
(:func:`scan_sees`, :func:`scan_counts`)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from fedtrack.geodetic import Frame, own_axes
from fedtrack.local_filters.mtt.associators import jipda
from fedtrack.local_filters.mtt.config import LOST, clutter_hit, log_miss_of, miss_count, raised_count, scan_lost
from fedtrack.local_filters.mtt.roles.gating import Gating
from fedtrack.local_filters.mtt.roles.tracks import TrackParams, TrackSet
from fedtrack.local_filters.mtt.scan import SensorScan
from fedtrack.local_filters.radar.measurement import cartesian_from_polar

# Wald's thresholds on a tentative track's evidence since its start (:func:`m_of_n` where the count rules a tracker
# of several sensors' scans; the track-to-track centre's CentreLife._evidence), as jipda's and mht's tests:
# ln((1 - beta) / alpha) = 4.6 with jipda's alpha FALSE_CONFIRM and beta LOST_TRUE, and ln(beta / (1 - alpha))
CONFIRM_EVIDENCE = math.log((1.0 - jipda.LOST_TRUE) / jipda.FALSE_CONFIRM)
DROP_EVIDENCE = math.log(jipda.LOST_TRUE / (1.0 - jipda.FALSE_CONFIRM))
# the volume of the unit ball in m dimensions (a gate's volume: UNIT_BALL[m] g^(m/2) sqrt(det S))
UNIT_BALL = {2: math.pi, 3: 4.0 * math.pi / 3.0}


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
    log_hit: np.ndarray | None = None  # (N,) a detection's evidence for the track (keeps_evidence), else None

    def take(self, idx: np.ndarray) -> Sight:
        return Sight(self.place[idx], self.view[idx], None if self.log_hit is None else self.log_hit[idx])

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
    """In a tracker of several sensors' scans (``params.sensor_bit``), per track (its
    predicted state in ``x``) what the scan shows of its place (:class:`Sight`): a detection of the
    scan in the track's gate, or the track's position strictly inside the x-y extent of the scan's
    detections (targets' and clutter: a sensor's detections lie in what it sees; a sensor that
    covers the area puts its clutter all round a track) and, for a radar, inside its view
    (:func:`radar_view`: a far radar's clutter surrounds a low aircraft in x-y, above its horizon).
    A scan without a detection whose sensor had detected ``held_tracks`` confirmed tracks (:func:`held`),
    too many for it to miss them all at once (:func:`empty_shows_blind`: a sensor blinded, jammed or
    cut off that still sends its scans), shows no view: it counts only for the tracks no other
    sensor detected (:meth:`Sight.counts`), as a sensor's silence counts for none. One sensor's tracker sees every
    track's place, and its Sight carries only the hits' evidence where it keeps it (:func:`keeps_evidence`; else
    None)."""
    n = x.shape[0]
    log_hit = None
    if keeps_evidence(params):  # no gating: no detection, no hit to weigh
        log_hit = np.zeros(n) if gating is None else hit_evidence(gating.logdet, scan.dim, params)
    if not params.sensor_bit:
        return None if log_hit is None else Sight(np.ones(n, dtype=bool), np.ones(n, dtype=bool), log_hit)
    sees = np.zeros(n, dtype=bool) if gating is None else np.bincount(gating.pairs.rows, minlength=n) > 0
    view = np.ones(n, dtype=bool)
    if not scan.z.shape[0] and empty_shows_blind(params.pd, held_tracks):
        return Sight(sees, ~view, log_hit)
    if n and scan.z.shape[0] > 1:
        pos = scan.z if scan.sensor_position is None else scan.sensor_position + cartesian_from_polar(scan.z)
        xy = pos[:, :2]
        lo, hi, at = xy.min(axis=0), xy.max(axis=0), x[:, [0, 2]]
        if scan.sensor_position is not None:
            view = radar_view(x, scan, params.frame)
        sees |= ((at > lo) & (at < hi)).all(axis=1) & view
    return Sight(sees, view, log_hit)


def keeps_evidence(params: TrackParams) -> bool:
    """Whether a tracker keeps each tentative track's evidence, for Wald's test (:func:`count_life`): a tracker
    whose count rules its tracks (``gnn``, mht's ``"counts"``; not jipda's existence, nor mht's score), one
    sensor's or several sensors' (before the clutter61 session several sensors' alone)."""
    return params.initial_existence is None and (params.mht is None or params.mht.management == "counts")


def hit_evidence(logdet: np.ndarray, m: int, params: TrackParams) -> np.ndarray:
    """Per track, the log-likelihood ratio of a detection in its gate (``ln det S`` per track, ``m``
    measured dimensions) for a target against the scan's clutter: ``ln((P_D (1 - p) + p) / p)``, ``p = 1 -
    exp(-lambda V)`` the chance that clutter (density ``lambda`` per unit of the measurement space) falls into
    the gate of volume ``V = UNIT_BALL[m] g^(m/2) sqrt(det S)``, a target's detection (``P_D``) or clutter
    putting one there. Without clutter: a hit is certain (``inf``). A miss weighs ``ln(1 - P_D)``
    whatever ``p`` (no detection: neither the target's nor clutter's, against clutter's alone)."""
    lam = params.clutter_density
    if lam <= 0.0:
        return np.full(logdet.shape, np.inf)
    volume = UNIT_BALL[m] * params.gate[m] ** (m / 2.0) * np.exp(0.5 * logdet)
    p = -np.expm1(-lam * volume)
    pd = min(params.pd, 1.0 - 1e-12)
    with np.errstate(divide="ignore"):
        return np.log(pd * (1.0 - p) + p) - np.log(p)


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


def tally(tracks: TrackSet, detected: np.ndarray, params: TrackParams, sees: Sight | None = None
          ) -> tuple[TrackSet, np.ndarray | bool, np.ndarray | int]:
    """The track counts after the scan: hits, scans counted (:func:`scan_counts`, ``sees``: :func:`scan_sees`)
    and misses in a row, and where the tracker keeps it (:func:`keeps_evidence`, ``sees`` carrying each track's
    :func:`hit_evidence`) each tentative track's evidence (``evidence[:, 0]``), Wald's log-likelihood ratio
    since its start: a hit adds its :func:`hit_evidence`, a counted miss ``ln(1 - P_D)``. With the scans
    counted and the misses in a row that delete each track (:func:`scan_counts`)."""
    tracks, counted, need = scan_counts(tracks, detected, params, sees)
    evidence = tracks.evidence
    if evidence is not None and sees is not None and sees.log_hit is not None:
        step = np.where(detected, sees.log_hit, np.where(counted, math.log1p(-min(params.pd, 1.0 - 1e-12)), 0.0))
        evidence = evidence.copy()
        evidence[:, 0] = np.where(tracks.confirmed, 0.0, evidence[:, 0] + step)
    return tracks._replace(hits=tracks.hits + detected, age=tracks.age + counted,
                           misses=np.where(detected, 0, tracks.misses + counted), evidence=evidence), counted, need


def passes_wald(evidence: np.ndarray | None) -> np.ndarray | bool:
    """Per track, whether its evidence since its start (``evidence[:, 0]``, :func:`tally`) reaches Wald's
    ``CONFIRM_EVIDENCE`` plus its births share (``evidence[:, 1]``); True where the tracker keeps none."""
    return True if evidence is None else evidence[:, 0] >= CONFIRM_EVIDENCE + evidence[:, 1]


def count_life(tracks: TrackSet, params: TrackParams, need: np.ndarray | int) -> tuple[np.ndarray, np.ndarray]:
    """The count's rule, gnn's (:func:`m_of_n`) and mht's ``"counts"`` (:func:`..tracker.mht_step`), on the
    counts :func:`tally` left: which tracks are confirmed and which stay. M-of-N: confirmed with
    ``confirm_hits`` hits within the first ``confirm_window`` counted scans, and, where the tracker keeps the
    evidence (:func:`keeps_evidence`) and the track's start's scan started more than one track, Wald's test passed
    as below (the count bounds a start's false confirmation, and so a scan's only where it starts one; a hit in a
    gate that the scan's clutter fills often is weak evidence: a coarse sensor's clutter confirmed as tracks by the
    count alone, clutter61), a
    tentative track that can no longer reach the count deleted, a confirmed one after ``need`` misses in a row.
    Where the tracker weighs each
    scan's evidence (``params.weighed``: some present sensor's clutter would raise the count), the configured
    count with Wald's test instead of the window: confirmed once the track has ``confirm_hits`` hits and its
    evidence reaches ``CONFIRM_EVIDENCE`` plus the log of the tracks its start's scan started (``evidence[:,
    1]``: the scan's births share the test's false confirmations, as jipda's births share its prior odds, so
    that a scan confirms clutter with at most ``FALSE_CONFIRM``), a tentative track deleted once its evidence
    falls to ``DROP_EVIDENCE`` (a true target lost with ``LOST_TRUE``): each scan weighed by its own sensor's
    clutter in the track's gate, so that a coarse sensor's clutter does not raise the count for the tracks a
    fine sensor confirms (docs/multitarget.md, mixnoise60)."""
    hits, evidence = tracks.hits, tracks.evidence
    if params.weighed and evidence is not None:
        confirmed = tracks.confirmed | ((hits >= params.confirm_hits) & passes_wald(evidence))
        tentative_live = evidence[:, 0] > DROP_EVIDENCE
    else:  # a lone birth: the count's own bound (raised_count's, a start's) is its scan's
        lone = True if evidence is None else evidence[:, 1] <= 0.0
        confirmed = tracks.confirmed | ((hits >= params.confirm_hits) & (lone | passes_wald(evidence)))
        tentative_live = params.confirm_window - tracks.age >= params.confirm_hits - hits
    return confirmed, np.where(confirmed, tracks.misses < need, tentative_live)


def m_of_n(tracks: TrackSet, detected: np.ndarray, params: TrackParams, sees: Sight | None = None
           ) -> tuple[TrackSet, np.ndarray]:
    """Role 6: the track counts after the scan (:func:`tally`), and which tracks stay (:func:`count_life`)."""
    tracks, _, need = tally(tracks, detected, params, sees)
    confirmed, live = count_life(tracks, params, need)
    return tracks._replace(confirmed=confirmed), live


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
    chance of 1/2 of confirming within the window. A radar's scan (its density per m rad^2), a
    sensor without clutter and a tracker that weighs each scan's evidence instead (``params.weighed``) keep the
    configured count."""
    if (scan.dim != 2 or params.clutter_density <= 0 or params.initial_existence is not None
            or params.mht is not None and params.mht.management != "counts" or params.weighed):
        return params
    hit = clutter_hit(params.clutter_density, scan.R, dt, params.init_velocity_std, params.gate[2])
    hits, window = raised_count(hit, params.pd, params.confirm_hits, params.confirm_window)
    if (hits, window) == (params.confirm_hits, params.confirm_window):
        return params
    return params._replace(confirm_hits=hits, confirm_window=window)
