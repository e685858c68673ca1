"""The truth of ``fedtrack simulate traffic``: a recording's window (``--start``, ``--duration``) inside
the box (``--box``), each airborne aircraft's samples in the common ENU frame about ``--origin``
(:mod:`fedtrack.geodetic`), split where a gap exceeds ``--max-gap`` (:func:`segments`), positions
reconciled with the recorded velocities (:func:`reconcile`; a velocity the positions rule out left
out, :func:`velocity_at_odds`) and interpolated on the ``DT`` grid by cubic Hermite pieces
(:func:`build_truth`); a window too large for the machine's memory is refused before it is made.
"""

from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import numpy as np
from scipy.interpolate import CubicHermiteSpline
from scipy.linalg import solveh_banded

from fedtrack.geodetic import (
    Frame,
    common_from_local_vectors,
    enu_from_geodetic,
    geodetic_from_enu,
    local_from_common_vectors,
    surface_enu,
    surface_xy,
)
from fedtrack.jsonl import InputError
from fedtrack.sensors.multitarget import DT, TRUTH_CELL_BYTES, memory_room
from fedtrack.sensors.state_vectors import Recording

#: the reconciliation of recorded positions with recorded velocities (docs/geodetic.md)
SIGMA_POSITION = 50.0  # m: a state vector's position is up to a second older or newer than its time
SIGMA_VELOCITY = 0.5  # m/s: ground speed is reported to the knot, vertical rate to 64 ft/min
#: the trackers' two motion modes (``[mtt] process_noise = "imm"``) from civil air-traffic kinematics, not
#: from a recording (docs/geodetic.md, "The motion model"): turns at 25 deg of bank or 3 deg/s, whichever
#: is less (ICAO PANS-OPS), so a horizontal acceleration of at most g tan 25 deg = 4.57 m/s^2
MANEUVER_ACCELERATION = 9.80665 * math.tan(math.radians(25.0))
MANEUVER_S = 90.0 / 3.0  # s: a 90 deg heading change at the standard rate of 3 deg/s
STRAIGHT_S = 120.0  # s: terminal-area legs between heading changes (holding legs 1-1.5 min, approach segments 1-3 min)
CHI2_2_999 = math.sqrt(-2.0 * math.log(0.001))  # its 99.9 % radius: 3.717
MAX_GAP_S = 30.0  # s: --max-gap at least (three of OpenSky's 10 s historical state vectors)
GLITCH_STEPS = 5  # steps either side of a sample whose median speed bounds its step (glitches)
#: an altitude glitch's bounds (:func:`altitude_glitches`): the largest vertical acceleration flown, 1 g (a parabolic
#: flight's, the traffic package's ``featured/zero_gravity``), and Mode C's altitude resolution, 100 ft (the coarsest
#: a transponder reports: Gillham code; Mode S's Q-bit reports 25 ft)
VERTICAL_ACCELERATION = 9.80665
ALTITUDE_RESOLUTION = 30.48
#: the highest runway an aircraft reported on the ground can stand on: Daocheng Yading airport's, 4,411 m, the highest
#: airport with scheduled flights (:func:`above_the_runways`)
HIGHEST_RUNWAY = 4411.0


class Truth(NamedTuple):
    """States ``x`` (steps, N, 6) ``[x, vx, y, vy, z, vz]`` on the ``DT`` grid from ``t0`` [s since
    1970], ``alive`` (steps, N), each target's ``icao24`` (N,); ``dropped``: the recording's samples
    and aircraft left out, by reason (:func:`build_truth`). ``surface``: the world is the ellipsoid's
    surface (2-D sensors only): ``x``, ``y`` are the common frame's east, north of the point of the ellipsoid
    below the aircraft, ``z`` its height above the ellipsoid (:func:`on_surface`). ``highest``: the highest
    recorded altitude [m] of the samples its tracks kept (the altitude glitches left out; -inf: none)."""

    t0: float
    x: np.ndarray
    alive: np.ndarray
    icao24: list[str]
    dropped: dict[str, int]
    surface: bool = False
    highest: float = -math.inf


class Segments(NamedTuple):
    """Row indices of each track (:func:`segments`), and the rows left out: how many ``repeated`` (a time or
    position repeated), which ``single`` (row indices: tracks of one sample)."""

    pieces: list[np.ndarray]
    repeated: int
    single: np.ndarray


def segments(rec: Recording, max_gap: float) -> Segments:
    """Row indices of each track: one aircraft's samples, a repeated (stale) position or time dropped,
    split where the gap between samples exceeds ``max_gap`` [s]; tracks of one sample dropped."""
    out = []
    single: list[np.ndarray] = []
    repeated = 0
    bounds = np.flatnonzero(np.r_[True, rec.icao24[1:] != rec.icao24[:-1], True])
    for a, b in zip(bounds[:-1], bounds[1:]):
        rows = np.arange(a, b)
        same = np.r_[False, (np.diff(rec.t[rows]) <= 0)
                     | np.all(np.diff(rec.lla[rows, :2], axis=0) == 0, axis=1)]
        repeated += int(same.sum())
        rows = rows[~same]
        for piece in np.split(rows, np.flatnonzero(np.diff(rec.t[rows]) > max_gap) + 1):
            (out if len(piece) >= 2 else single).append(piece)
    return Segments(out, repeated, np.concatenate(single) if single else np.zeros(0, int))


def default_max_gap(rec: Recording) -> float:
    """``--max-gap``'s default [s]: three sampling intervals, the recording's median time between an aircraft's
    consecutive samples, at least ``MAX_GAP_S`` (three of OpenSky's 10 s historical state vectors): a survey
    recorded every 29-31 s (the traffic package's ``surveys/texas``, ``indiana``) was cut at 30 s into tracks of one
    sample, left out, and the truth lost its aircraft between them."""
    steps = np.diff(rec.t)[rec.icao24[1:] == rec.icao24[:-1]]
    steps = steps[steps > 0]
    return max(MAX_GAP_S, 3.0 * float(np.median(steps))) if steps.size else MAX_GAP_S


def reconcile(t: np.ndarray, pos: np.ndarray, vel: np.ndarray, sigma_p: float = SIGMA_POSITION,
              sigma_v: float = SIGMA_VELOCITY) -> np.ndarray:
    """Positions (n, 3) consistent with the recorded velocities: the least-squares ``s`` of
    ``sum |s_k - p_k|^2 / sigma_p^2 + sum |s_k+1 - s_k - (v_k + v_k+1) dt_k / 2|^2 / (sigma_v dt_k)^2``,
    a tridiagonal system (one solve for the three axes)."""
    dt = np.diff(t)
    w = 1.0 / (sigma_v * dt) ** 2
    step = 0.5 * (vel[1:] + vel[:-1]) * dt[:, None]
    diag = np.full(len(t), 1.0 / sigma_p**2)
    diag[:-1] += w
    diag[1:] += w
    rhs = pos / sigma_p**2
    rhs[:-1] -= w[:, None] * step
    rhs[1:] += w[:, None] * step
    return solveh_banded(np.vstack([np.r_[0.0, -w], diag]), rhs)


def common_velocity(frame: Frame, t: np.ndarray, lla: np.ndarray, local: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """A track's recorded velocities ``local`` (n, 3) [m/s, the axes at each sample ``lla``] in the common
    axes, a component not recorded (NaN: a vertical rate, a cell) the derivative's of the common-frame
    positions ``pos`` (n, 3) at times ``t``, filled in the local axes (the turn mixes the three)."""
    slope = local_from_common_vectors(frame, lla[:, 0], lla[:, 1], np.gradient(pos, t, axis=0))
    return common_from_local_vectors(frame, lla[:, 0], lla[:, 1], np.where(np.isfinite(local), local, slope))


def on_surface(frame: Frame, pos: np.ndarray, vel: np.ndarray, dt: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities (n, 3) of common-frame ``pos``, ``vel`` (n, 3) in a 2-D world on the Earth: east,
    north of the point of the ellipsoid below each position (its latitude and longitude at h = 0: what a 2-D
    position sensor measures, :func:`fedtrack.geodetic.surface_xy`) and its height above the ellipsoid; the
    velocities by central differences along ``vel`` over +-``dt`` s (within 1e-6 m/s of a step of 0.01 s, aircraft up
    to 400 km from the origin)."""
    points = np.concatenate([pos, pos - vel * dt, pos + vel * dt])
    out = np.column_stack([surface_xy(frame, points), geodetic_from_enu(frame, points)[:, 2]])
    here, before, after = np.split(out, 3)
    return here, (after - before) / (2.0 * dt)


def truth_geodetic(frame: Frame, truth: Truth, states: np.ndarray) -> np.ndarray:
    """``[lat, lon, h]`` (n, 3) of the truth's states (n, 6): a 3-D world's positions, a 2-D world's points of the
    ellipsoid with the height kept beside them."""
    if not truth.surface:
        return geodetic_from_enu(frame, states[:, [0, 2, 4]]).reshape(-1, 3)
    lla = geodetic_from_enu(frame, surface_enu(frame, states[:, [0, 2]])).reshape(-1, 3)
    lla[:, 2] = states[:, 4]
    return lla


def velocity_at_odds(frame: Frame, t: np.ndarray, lla: np.ndarray, local: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """Which samples' recorded horizontal velocities ``local`` (n, 3) [m/s, the axes at each sample ``lla``] point
    where the recorded positions ``pos`` (n, 3, common frame) at times ``t`` rule out (n,): the recorded ground
    track is off the direction of the chord between the sample's neighbours (at a track's ends, the sample and its
    one neighbour), ``span`` s apart, by more than the heading change of a turn at ``MANEUVER_ACCELERATION`` over
    half the span plus the chord's own direction noise at its 99.9 % radius, ``asin(CHI2_2_999 sqrt(2)
    SIGMA_POSITION / span / |chord|)`` (a chord shorter than that radius points nowhere). Only the direction: a
    stale position (OpenSky's) makes a chord's speed wrong. E.g. a track stored as an 8-bit integer (the traffic
    package's calibration samples: -128 to 127, 104 deg off for a true track of 128 deg or more)."""
    k = np.arange(len(t))
    lo, hi = np.maximum(k - 1, 0), np.minimum(k + 1, len(t) - 1)
    span = t[hi] - t[lo]
    chord = local_from_common_vectors(frame, lla[:, 0], lla[:, 1], (pos[hi] - pos[lo]) / span[:, None])[:, :2]
    v = local[:, :2]
    speed, moved = np.linalg.norm(v, axis=1), np.linalg.norm(chord, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = CHI2_2_999 * math.sqrt(2.0) * SIGMA_POSITION / span / moved
        noise = np.where(ratio < 1.0, np.arcsin(np.minimum(ratio, 1.0)), np.pi)
        angle = np.arccos(np.clip(np.sum(v * chord, axis=1) / (speed * moved), -1.0, 1.0))
        return angle > MANEUVER_ACCELERATION / speed * span / 2.0 + noise  # NaN (not recorded): False


def glitches(t: np.ndarray, pos: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """Which of a track's samples (n,) hold a position no aircraft could have reached (a position decoded wrong:
    ``featured/airbus_tree`` jumps 2.7 km west in 1 s, then 2.9 km south, while it reads 215 m/s): in time order,
    a sample farther horizontally from the last sample kept than ``(2 v + MANEUVER_ACCELERATION dt / 2) dt`` plus
    the two positions' noise at its 99.9 % radius, ``CHI2_2_999 sqrt(2) SIGMA_POSITION``, with ``dt`` the time
    between them and ``v`` the largest of their recorded ground speeds ``speed`` (n,) [m/s] (NaN: not recorded) and
    the median speed between consecutive positions over the ``GLITCH_STEPS`` steps either side of the sample (a
    recorded speed can be stale too: ``tv_relay/tour_de_france`` reads 11 m/s for a minute while its positions fly
    122 m/s; a glitch is one step or two among them and moves no median). The factor 2: a stale position (OpenSky
    holds a position up to a sampling interval) makes a step up to twice as long as flown
    (``calibration/montreal``'s longest, 1,140 m in 5 s at 106 m/s, is inside the bound with its noise term, 1,383
    m). A track's first sample is taken as right: were it a glitch, the samples after it are dropped until the
    bound, growing with ``dt``, reaches them (the glitch's distance over the speed, 13 s for 2.7 km at 215 m/s)."""
    step = np.linalg.norm(np.diff(pos[:, :2], axis=0), axis=1) / np.diff(t)
    out = np.zeros(len(t), bool)
    last = 0
    reach = CHI2_2_999 * math.sqrt(2.0) * SIGMA_POSITION
    for k in range(1, len(t)):
        dt = t[k] - t[last]
        v = np.nanmax([speed[k], speed[last], float(np.median(step[max(k - GLITCH_STEPS, 0):k + GLITCH_STEPS]))])
        if np.linalg.norm(pos[k, :2] - pos[last, :2]) > (2.0 * v + MANEUVER_ACCELERATION * dt / 2.0) * dt + reach:
            out[k] = True
        else:
            last = k
    return out


def altitude_glitches(t: np.ndarray, alt: np.ndarray, rate: np.ndarray) -> np.ndarray:
    """Which of a track's samples (n,) hold an altitude decoded wrong (a Mode S altitude error: the Paris extract's
    ``4d21ec`` reads 1,410 m, 9,754 m, 1,410 m a second apart, three times): above both or below both the median
    altitude of the ``GLITCH_STEPS`` samples before it and of those after it, each by more than the aircraft could
    climb or descend in the time ``s`` to the farthest of them, ``v s + VERTICAL_ACCELERATION s^2 / 2`` plus
    ``ALTITUDE_RESOLUTION``, with ``v`` the larger of its recorded vertical rate ``rate`` (n,) [m/s] (NaN: not
    recorded) and the median vertical speed between consecutive samples over the ``GLITCH_STEPS`` steps either side
    (a glitch is one step or two among them and moves no median). Both sides: an altitude held and then caught up
    (``featured/dreamliner_airfrance`` 7,925 -> 8,222 m in a second), a step, agrees with one side and is kept, so
    is a track's first or last sample. The positions' bound (:func:`glitches`) is horizontal: before 2026-11-28 such a
    sample went into the truth, an 8 km jump for a second where no vertical rate is recorded."""
    n, w = len(t), GLITCH_STEPS
    pad = np.full(w, np.nan)
    t_win = np.lib.stride_tricks.sliding_window_view(np.r_[pad, t, pad], 2 * w + 1)
    h_win = np.lib.stride_tricks.sliding_window_view(np.r_[pad, alt, pad], 2 * w + 1)
    climb = np.abs(np.diff(alt)) / np.diff(t)
    steps = np.lib.stride_tricks.sliding_window_view(np.r_[pad, climb, pad], 2 * w)[:n]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a track's ends: one side empty (all NaN), never a glitch
        v = np.fmax(np.abs(rate), np.nanmedian(steps, axis=1))
        offs, reach = [], []
        for side in (slice(0, w), slice(w + 1, 2 * w + 1)):
            s = np.nanmax(np.abs(t_win[:, side] - t[:, None]), axis=1)
            offs.append(alt - np.nanmedian(h_win[:, side], axis=1))
            reach.append(v * s + VERTICAL_ACCELERATION * s * s / 2.0 + ALTITUDE_RESOLUTION)
    return (offs[0] * offs[1] > 0) & (np.abs(offs[0]) > reach[0]) & (np.abs(offs[1]) > reach[1])


def above_the_runways(t: np.ndarray, alt: np.ndarray, rate: np.ndarray, ground: np.ndarray) -> np.ndarray:
    """Which of a track's samples (n,) at times ``t`` hold an altitude ``alt`` that an aircraft reported on the ground
    before it and after it (times ``ground``, sorted; those rows dropped on reading) could not reach and leave:
    higher than ``HIGHEST_RUNWAY`` by more than ``v s + VERTICAL_ACCELERATION s^2 / 2 + ALTITUDE_RESOLUTION``, ``s``
    the time to the farther of the two reports and ``v`` its recorded vertical rate ``rate`` (NaN: not recorded, 0).
    Both sides: a flag on the ground can be wrong too (``collections/savan`` cruises at 6.7 km and 142 m/s with one
    report on the ground 14-21 s away). ``noisy/noisy_takeoff`` taxis at 22 m/s while its rows flagged airborne,
    between rows flagged on the ground every few seconds, read 10,965 m: a track of its own, since a 107 s gap
    follows, that agrees with itself (no glitch to :func:`altitude_glitches`)."""
    if not ground.size:
        return np.zeros(len(t), bool)
    at = np.searchsorted(ground, t)
    inside = (at > 0) & (at < ground.size)  # a report on the ground before it and one after it
    s = np.maximum(t - ground[np.maximum(at - 1, 0)], ground[np.minimum(at, ground.size - 1)] - t)
    v = np.nan_to_num(np.abs(rate))
    return inside & (alt > HIGHEST_RUNWAY + v * s + VERTICAL_ACCELERATION * s * s / 2.0 + ALTITUDE_RESOLUTION)


def _steps_before(t: float, steps: int, after: bool = False) -> int:
    """How many of the grid's times ``k DT`` (``k < steps``) are before ``t`` (``after``: at or before it)."""
    k = min(max(math.floor(t / DT) - 1, 0), steps)  # then exact: k DT as the grid computes it
    while k < steps and (k * DT <= t if after else k * DT < t):
        k += 1
    return k


def build_truth(rec: Recording, frame: Frame, start: float, duration: float | None, box: float,
                max_gap: float, scan_bytes: float = 0.0, surface: bool = False) -> Truth:
    """Truth on the ``DT`` grid from the first sample + ``start`` for ``duration`` s (None: to the last
    sample); a target is alive between its track's first and last samples while inside the square of
    side ``box`` [m] about the origin. A window whose grid, with ``scan_bytes`` a second of it for the
    sensors' scans, would take more than :func:`memory_room` is refused before it is made. ``surface``: a 2-D
    world, each track's samples :func:`on_surface` before the Hermite pieces."""
    t0 = float(rec.t.min()) + start
    end = float(rec.t.max()) if duration is None else t0 + duration
    if not end > t0:
        span = float(rec.t.max() - rec.t.min())
        raise InputError(f"--start {start:g}: no data after it (the recording spans {span:g} s from its first "
                         f"sample; --start must be less)")
    steps = int(round((end - t0) / DT)) + 1
    # times from t0: at 1.7e9 s a float's step is 2.4e-7 s, 5e-5 m at 200 m/s, and t0 + k DT would be
    # rounded to it; the recorded times less t0 are exact (Sterbenz) and the grid k DT is the same for
    # any shift of the whole recording
    rel = rec.t - t0
    found = segments(rec, max_gap)
    kept: list[tuple[slice, np.ndarray, np.ndarray, str]] = []  # each track inside the box: its steps, states, inside
    at_odds = glitched = high = runway = lone = 0
    ground = rec.ground or {}
    highest = -math.inf
    for rows in (p for p in found.pieces if rel[p[-1]] >= 0 and rec.t[p[0]] <= end):
        pos = enu_from_geodetic(frame, *rec.lla[rows].T)
        wrong = glitches(rel[rows], pos, np.linalg.norm(rec.velocity[rows, :2], axis=1))
        aloft = altitude_glitches(rel[rows], rec.lla[rows, 2], rec.velocity[rows, 2]) & ~wrong
        landed = above_the_runways(rec.t[rows], rec.lla[rows, 2], rec.velocity[rows, 2],
                                   ground.get(str(rec.icao24[rows[0]]), np.zeros(0))) & ~wrong & ~aloft
        wrong |= aloft | landed
        if (~wrong).sum() < 2:  # nothing left to fly: a track of its own at an altitude no runway has
            runway += int(landed.sum())
            lone += int((~wrong).sum())
            continue
        rows, pos = rows[~wrong], pos[~wrong]
        live = slice(_steps_before(rel[rows[0]], steps), _steps_before(rel[rows[-1]], steps, after=True))
        grid = np.arange(live.start, live.stop) * DT  # the window's grid k DT, each track's steps only
        recorded = rec.velocity[rows].copy()
        odd = velocity_at_odds(frame, rel[rows], rec.lla[rows], recorded, pos)
        recorded[odd, :2] = np.nan  # the positions' derivative instead
        if np.isfinite(recorded).any():
            pos = reconcile(rel[rows], pos, common_velocity(frame, rel[rows], rec.lla[rows], recorded, pos))
        vel = common_velocity(frame, rel[rows], rec.lla[rows], recorded, pos)
        if surface:
            pos, vel = on_surface(frame, pos, vel)
        spline = CubicHermiteSpline(rel[rows], pos, vel)
        p, v = spline(grid), spline(grid, 1)
        inside = np.all(np.abs(p[:, :2]) <= box / 2, axis=1)
        if inside.any():  # a track never inside the box takes no room in the grid
            at_odds += int(odd.sum())
            glitched += int((wrong & ~aloft & ~landed).sum())
            high += int(aloft.sum())
            runway += int(landed.sum())
            highest = max(highest, float(rec.lla[rows, 2].max()))
            kept.append((live, np.stack([p[:, 0], v[:, 0], p[:, 1], v[:, 1], p[:, 2], v[:, 2]], axis=-1), inside,
                         str(rec.icao24[rows[0]])))
    need, room = steps * len(kept) * TRUTH_CELL_BYTES + (steps - 1) * DT * scan_bytes, memory_room()
    if need > room:
        raise InputError(f"the window is too long: {(steps - 1) * DT:g} s of {len(kept)} aircraft tracks inside the "
                         f"box and the sensors' scans need {need / 2**30:.3g} GiB of memory, more than a quarter of "
                         f"this machine's ({room / 2**30:.3g} GiB); the recording's airborne samples span "
                         f"{float(rec.t.max() - rec.t.min()):g} s: give a shorter --duration (and --start) or a "
                         "smaller --box")
    x = np.zeros((steps, len(kept), 6))
    alive = np.zeros((steps, len(kept)), bool)
    for j, (live, state, inside, _) in enumerate(kept):
        x[live, j] = state
        alive[live, j] = inside
    icao24 = [icao for *_, icao in kept]
    dropped = {**rec.dropped, "repeating a time or position": found.repeated,
               "in a track of one sample": len(found.single) + lone,
               "horizontal velocities at odds with the positions (their derivative taken)": at_odds,
               "positions farther from the previous one than the aircraft could fly (glitches)": glitched,
               "altitudes off those either side by more than the aircraft could climb or descend (altitude glitches)":
                   high,
               "altitudes above every runway between reports on the ground": runway,
               "aircraft with no track inside the box and window": len(set(rec.icao24.tolist())) - len(set(icao24))}
    return Truth(t0, x, alive, icao24, dropped, surface, highest)
