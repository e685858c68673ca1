"""``fedtrack simulate multitarget``: many targets, asynchronous 2-D and radar sensors, clutter, delays.

Truth: targets move at constant speed (8-30 m/s) with coordinated turns (a few per target,
2-6 deg/s for 8-25 s: at most ``MAX_ACCELERATION`` = pi m/s^2) in a square of half-width
``region`` metres; pairs of targets are aimed to pass the same point at the same time
(crossings); some targets are born late or die early.
Radar scenarios give every target a constant altitude. Truth is integrated on a 0.05 s grid
(exact per step for a constant turn rate).

Formations (``--formation G``): targets fly in groups of ``G``, each group one of the above
trajectories (its crossings, turns, birth and death) with its members side by side across the
track, neighbours between one and two noise sigmas of the coarsest possible position sensor
apart (``POS_SD_MAX`` to ``2 POS_SD_MAX``: 20-40 m). ``--scenario dense`` is issue 25's dense
scenario: groups of three crossing other groups, P_D 0.8, 50 false detections per scan, 120 s.

Sensors (``SPEC`` = comma-separated ``kind:period[/sigma...]``, kind ``pos`` or ``radar``): each has its
own period and a random phase (its first scan within the period, or within the scenario when the
period is longer: every sensor scans at least once); every target is detected with ``pd``; ``clutter`` false
detections per scan on average (Poisson), uniform over the region (radar: over its range,
azimuth and elevation cover). Position sensors have noise std 10-20 m per axis; radars
10 m in range and 2 mrad in angle, standing at the region's edge; ``/sigma`` sets a position sensor's
(m per axis, uncorrelated) or a radar's (``/sigma_r/sigma_az[/sigma_el]``, m and degrees) instead.

Delays: every scan reaches the tracker ``base_delay`` + an exponential jitter after its time,
and a fraction ``late`` of the scans (never the first) up to two periods later; a sensor's link
is FIFO (a Zenoh publisher's samples arrive in order), so out-of-sequence lines come from the
interleaving of sensors, unless ``fifo`` is False (``--non-fifo``: UDP, several paths, a
store-and-forward relay), when a late scan arrives after its sensor's later scans and the
trackers' own out-of-sequence handling is exercised. ``measurements.jsonl`` is written in
arrival order.

``config.toml`` sets ``[mtt] q`` from the truth's maximum acceleration and the sensors' periods
(:func:`process_noise`, docs/multitarget.md#covariance-consistency-nees) and ``max_lag`` from the
delays (:func:`max_lag`: every late scan is fused).
"""

from __future__ import annotations

import argparse
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from fedtrack.config import seed_number, to_toml
from fedtrack.geodetic import RadarSite, above_radio_horizon, aer_from_enu, enu_from_aer
from fedtrack.jsonl import InputError, check_output_folder, output_file
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.scan import MAX_DETECTIONS
from fedtrack.local_filters.radar.measurement import polar_from_cartesian, wrap_angle

DT = 0.05
#: the largest mean clutter count per scan: its Poisson count stays 10 standard deviations below half the
#: detections a replay reads in one scan (``MAX_DETECTIONS``; the other half left for targets),
#: lambda + 10 sqrt(lambda) = MAX_DETECTIONS / 2: 47,813
MAX_CLUTTER = ((math.sqrt(100.0 + 2.0 * MAX_DETECTIONS) - 10.0) / 2.0) ** 2
SPEED = (8.0, 30.0)  # m/s, uniform
TURN_RATE = (2.0, 6.0)  # deg/s, uniform, either sign
# m/s^2: the fastest turn of the fastest target (a crossing only slows a target down: its
# meeting point, when clipped to the region, comes nearer)
MAX_ACCELERATION = float(np.deg2rad(TURN_RATE[1]) * SPEED[1])
JITTER_S = 0.02  # s: the mean of a scan's exponential delay jitter
LATE_TAIL = 1e-6  # the chance per scan that its jitter exceeds the bound max_lag allows for
POS_SD_MIN, POS_SD_MAX = 10.0, 20.0  # a position sensor's noise std per axis (m)
RADAR_SD = (10.0, 0.002, 0.002)  # a radar's noise std: range (m), azimuth, elevation (rad)
#: memory a simulation takes (``simulate traffic``'s window, ``simulate multitarget``'s scenario: :func:`memory_need`):
#: per state of the truth grid (a step of ``DT`` of one target) 100 bytes at the peak (six float64 and a flag held,
#: plus, for traffic, each track's states before the grid and the derived keys' temporaries: measured, 5.44 GB of
#: peak resident memory for the whole of the traffic package's ``collections/quickstart``, 10,798 s of 244 tracks,
#: 52.7 million states; ``simulate multitarget``'s default scenario 101 bytes with tracemalloc, the turn rates and
#: alive masks beside the states); per scan and detection until they are written (Python's dicts and lists,
#: measured with tracemalloc: 1,000 + 430 a detection)
TRUTH_CELL_BYTES = 100
SCAN_BYTES = 1000
DETECTION_BYTES = 430


@dataclass(frozen=True)
class SensorSpec:
    id: str
    kind: str  # "pos" or "radar"
    period: float
    noise: tuple[float, ...] = ()  # ``/SIGMA...`` of the spec (:func:`noise_matrix`); () the simulator's own


@dataclass(frozen=True)
class Scenario:
    targets: int = 60
    duration: float = 300.0
    region: float = 5000.0
    pd: float = 0.9
    clutter: float = 10.0
    late: float = 0.2
    base_delay: float = 0.05
    formation: int = 1  # targets per group
    fifo: bool = True  # a sensor's scans arrive in their own order (False: a late scan may come after later ones)


# ``--scenario`` presets: options the command line did not set
PRESETS: dict[str, dict[str, float]] = {
    "default": {},
    "dense": {"pd": 0.8, "clutter": 50.0, "duration": 120.0, "formation": 3},
}


ID_PREFIX = {"pos": "s", "radar": "r", "adsb": "a"}


def noise_matrix(kind: str, sigmas: tuple[float, ...]) -> np.ndarray:
    """``R`` of a ``pos`` sensor's ``(SIGMA,)`` [m a axis] or a radar's ``(SIGMA_R, SIGMA_AZ[, SIGMA_EL])``
    [m, deg, deg] (the elevation's default ``RADAR_SD``)."""
    if kind == "pos":
        return np.eye(2) * sigmas[0] ** 2
    sd = [sigmas[0], *np.radians(sigmas[1:])] + list(RADAR_SD[len(sigmas):])
    return np.diag(np.square(sd))


def parse_sigmas(kind: str, sigmas: str, item: str) -> tuple[float, ...]:
    """The numbers of a sensor's ``/SIGMA...`` (``()`` when not given; :func:`noise_matrix`)."""
    if not sigmas:
        return ()
    sizes = {"pos": (1,), "radar": (2, 3)}.get(kind, ())
    try:
        values = tuple(float(v) for v in sigmas.split("/"))
    except ValueError:
        values = ()
    if not sizes:
        raise InputError(f"--sensors: {item!r}: an ADS-B receiver takes no noise (its accuracy is --nacp's)")
    if len(values) not in sizes or not all(math.isfinite(v) and v > 0 for v in values):
        form = "pos:P/SIGMA (m)" if kind == "pos" else "radar:P/SIGMA_R/SIGMA_AZ[/SIGMA_EL] (m, deg, deg)"
        raise InputError(f"--sensors: {item!r}: the noise is {form}, each > 0")
    return values


def parse_noise(kind: str, sigmas: str, item: str) -> np.ndarray | None:
    """``R`` of a sensor's ``/SIGMA...`` (None when not given; :func:`parse_sigmas`, :func:`noise_matrix`)."""
    values = parse_sigmas(kind, sigmas, item)
    return noise_matrix(kind, values) if values else None


def parse_spec(spec: str, kinds: tuple[str, ...] = ("pos", "radar")) -> list[SensorSpec]:
    """``pos:1.0,pos:0.7/5,radar:1.3`` -> sensors ``s1``, ``s2`` (5 m a axis, :func:`parse_noise`), ``r3``
    (``adsb``: ``a``, where ``kinds`` has it)."""
    out = []
    for k, item in enumerate(spec.split(","), start=1):
        kind, _, rest = item.strip().partition(":")
        period, _, sigmas = rest.partition("/")
        try:
            value = float(period)
        except ValueError:
            value = float("nan")
        if kind not in kinds or not DT <= value < math.inf:
            raise InputError(f"--sensors: {item!r} is not KIND:PERIOD[/SIGMA...] with KIND {' or '.join(kinds)} "
                             f"and PERIOD a finite number of seconds >= {DT:g} (the truth's time step)")
        out.append(SensorSpec(f"{ID_PREFIX[kind]}{k}", kind, value, parse_sigmas(kind, sigmas, item.strip())))
    return out


def simulate_truth(sc: Scenario, three_d: bool, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """States ``(steps, N, 6)`` ``[x, vx, y, vy, z, vz]`` on the ``DT`` grid and an alive mask ``(steps, N)``."""
    steps = int(round(sc.duration / DT)) + 1
    n = -(-sc.targets // sc.formation)  # one trajectory per group
    speed = rng.uniform(*SPEED, n)
    heading = rng.uniform(-np.pi, np.pi, n)
    pos = rng.uniform(-0.7 * sc.region, 0.7 * sc.region, (n, 2))
    # crossings: the second of each pair is aimed at the first one's position at a common time
    for a in range(0, n - 1, 4):
        b = a + 1
        tc = rng.uniform(0.2, 0.8) * sc.duration
        meet = pos[a] + tc * speed[a] * np.array([np.cos(heading[a]), np.sin(heading[a])])
        meet = np.clip(meet, -0.8 * sc.region, 0.8 * sc.region)
        heading[a] = math.atan2(*(meet - pos[a])[::-1])
        speed[a] = float(np.linalg.norm(meet - pos[a]) / tc)
        heading[b] = heading[a] + rng.choice([-1, 1]) * rng.uniform(0.5, 2.0)
        speed[b] = rng.uniform(*SPEED)
        pos[b] = meet - tc * speed[b] * np.array([np.cos(heading[b]), np.sin(heading[b])])
    omega = np.zeros((steps, n))
    for i in range(n):
        for _ in range(rng.integers(1, 4)):
            start = int(rng.uniform(0, sc.duration) / DT)
            omega[start:start + int(rng.uniform(8, 25) / DT), i] = np.deg2rad(rng.uniform(*TURN_RATE)) * rng.choice([-1, 1])
    alt = rng.uniform(300.0, 3000.0, n) if three_d else np.zeros(n)
    x = np.zeros((steps, n, 6))
    x[0, :, 0], x[0, :, 2], x[0, :, 4] = pos[:, 0], pos[:, 1], alt
    x[0, :, 1], x[0, :, 3] = speed * np.cos(heading), speed * np.sin(heading)
    for k in range(1, steps):
        w = omega[k - 1]
        vx, vy = x[k - 1, :, 1], x[k - 1, :, 3]
        small = np.abs(w) < 1e-9
        ws = np.where(small, 1.0, w)
        s, c = np.sin(w * DT), np.cos(w * DT)
        dx = np.where(small, vx * DT, (vx * s - vy * (1 - c)) / ws)
        dy = np.where(small, vy * DT, (vx * (1 - c) + vy * s) / ws)
        x[k, :, 0], x[k, :, 2], x[k, :, 4] = x[k - 1, :, 0] + dx, x[k - 1, :, 2] + dy, alt
        x[k, :, 1], x[k, :, 3] = vx * c - vy * s, vx * s + vy * c
    born = np.where(rng.uniform(size=n) < 0.2, rng.uniform(0, 0.5 * sc.duration, n), 0.0)
    dies = np.where(rng.uniform(size=n) < 0.2, rng.uniform(0.5 * sc.duration, sc.duration, n), np.inf)
    t = np.arange(steps) * DT
    alive = (t[:, None] >= born[None]) & (t[:, None] <= dies[None])
    if sc.formation == 1:
        return x, alive
    return formation(x, alive, sc.targets, sc.formation, rng)


def formation(x: np.ndarray, alive: np.ndarray, targets: int, size: int, rng: np.random.Generator
              ) -> tuple[np.ndarray, np.ndarray]:
    """Groups of ``size`` from one trajectory each: member ``r`` of a group is its trajectory moved
    ``r s`` across the initial heading (``s`` uniform in ``[POS_SD_MAX, 2 POS_SD_MAX]`` per group);
    the same velocities and turns, so the formation holds."""
    member = np.arange(targets)
    group, rank = member // size, member % size
    heading = np.arctan2(x[0, :, 3], x[0, :, 1])
    spacing = rng.uniform(POS_SD_MAX, 2 * POS_SD_MAX, x.shape[1])
    offset = np.zeros((targets, 6))
    offset[:, 0] = -np.sin(heading[group]) * spacing[group] * rank
    offset[:, 2] = np.cos(heading[group]) * spacing[group] * rank
    return x[:, group] + offset, alive[:, group]


def sensor_lines(spec: SensorSpec, sc: Scenario, x: np.ndarray, alive: np.ndarray, three_d: bool,
                 rng: np.random.Generator, site: RadarSite | None = None,
                 noise: np.ndarray | None = None) -> list[tuple[float, dict[str, Any]]]:
    """``(arrival time, line)`` of every scan of one sensor.

    A radar with a ``site`` on the Earth (:mod:`fedtrack.geodetic`) measures and errs in its own
    frame (range, azimuth from north, elevation about its site's ENU axes); its detections are then
    given, exactly, as range, azimuth and elevation about ``sensor_position`` in the common frame's
    axes, the trackers' measurement model; it detects only the targets above its radio horizon
    (:func:`fedtrack.geodetic.above_radio_horizon`). Without a site it stands at a random point of the
    region's edge and measures in the common frame's axes. ``noise``: the sensor's ``R`` (default: the
    spec's ``/SIGMA...``, else a position sensor's 10-20 m per axis, drawn (drawn either way, so that a
    given noise leaves the other draws as they were), a radar's ``RADAR_SD``)."""
    # the first scan at a random phase within the period, or within the scenario when the period is
    # longer (else such a sensor had no scan at all with chance 1 - duration / period: its launch failed)
    phase = round(rng.uniform(0, min(spec.period, sc.duration)) / DT) * DT
    times = np.arange(phase, sc.duration + 1e-9, spec.period)
    out: list[tuple[float, dict[str, Any]]] = []
    last_arrival = -np.inf
    if noise is None and spec.noise:
        noise = noise_matrix(spec.kind, spec.noise)
    if spec.kind == "pos":
        sd = rng.uniform(POS_SD_MIN, POS_SD_MAX)
        R = np.array([[sd**2, 0.3 * sd**2], [0.3 * sd**2, sd**2]]) if noise is None else noise
        where = None
    else:
        R = np.diag(np.square(RADAR_SD)) if noise is None else noise
        if site is None:
            angle = rng.uniform(-np.pi, np.pi)
            where = np.array([1.1 * sc.region * np.cos(angle), 1.1 * sc.region * np.sin(angle), 0.0])
        else:
            where = site.position
    L = np.linalg.cholesky(R)
    for k, t in enumerate(times):
        step = int(round(t / DT))
        live = np.flatnonzero(alive[step] & (rng.uniform(size=alive.shape[1]) < sc.pd))
        truth = x[step, live]
        if where is None:
            z = truth[:, [0, 2]]
        elif site is None:
            z = polar_from_cartesian(truth[:, [0, 2, 4]] - where)
        else:
            z = aer_from_enu(site, truth[:, [0, 2, 4]])[:, [2, 0, 1]]  # [range, az from north, el], own frame
        z = z + rng.standard_normal(z.shape) @ L.T
        n_false = rng.poisson(sc.clutter)
        if where is None:
            clutter = rng.uniform(-sc.region, sc.region, (n_false, 2))
        else:
            clutter = np.column_stack([rng.uniform(*radar_range(sc), n_false), rng.uniform(-np.pi, np.pi, n_false),
                                       rng.uniform(0.0, radar_elevation(sc), n_false)])
        order = rng.permutation(len(z) + n_false)
        seen = np.ones(len(z), bool) if site is None else above_radio_horizon(site, truth[:, [0, 2, 4]])
        dets = np.concatenate([z, clutter])[order][np.r_[seen, np.ones(n_false, bool)][order]]  # the same draws
        if site is not None:
            dets = polar_from_cartesian(enu_from_aer(site, dets[:, [1, 2, 0]]) - where)
        if where is not None:
            dets[:, 1] = wrap_angle(dets[:, 1])
        line: dict[str, Any] = {"t": round(float(t), 6), "sensor": spec.id, "R": R.tolist(),
                                "detections": [{"z": d.tolist()} for d in dets]}
        if where is not None:
            line["sensor_position"] = where.tolist()
        delay = sc.base_delay + rng.exponential(JITTER_S)
        if k and rng.uniform() < sc.late:
            delay += rng.uniform(0, 2 * spec.period)
        last_arrival = max(last_arrival, t + delay) if sc.fifo else t + delay
        out.append((last_arrival, line))
    return out


def revisits(specs: list[SensorSpec], duration: float) -> list[float]:
    """The periods of the sensors that may scan more than once in ``duration`` seconds: a slower one
    scans once (:func:`sensor_lines`), so no tracker predicts across its period and its one scan,
    the first, is never late."""
    return [s.period for s in specs if s.period <= duration]


def longest_revisit(specs: list[SensorSpec], duration: float) -> float:
    """The longest interval a tracker predicts across in ``duration`` seconds: the period of the slowest
    sensor that scans again (:func:`revisits`), or the duration when none does."""
    return max(revisits(specs, duration), default=duration)


def process_noise(specs: list[SensorSpec], duration: float = math.inf) -> float:
    """``[mtt] q`` [m^2/s^3] for this simulator: ``(a_M / 2)^2 T`` with ``a_M`` = ``MAX_ACCELERATION``
    and ``T`` the longest period of a sensor that scans again within ``duration`` (:func:`longest_revisit`;
    none: the duration). Bar-Shalom, Li, Kirubarajan (2001), sections 6.2.2 and
    6.3.2: the velocity change over a scan interval, ``sqrt(q T)`` for a continuous white-noise
    acceleration, should be ``0.5 a_M`` to ``a_M`` times ``T``; the lower end, since the targets
    turn a fraction of the time and mostly below ``a_M``. (Before 2026-11-27 ``T`` was the longest
    period of all: a sensor of period 1e9 s in a 120 s scenario, which scans once, made q 2.5e9 and
    the mean GOSPA of the two others' tracks 414 m instead of 32.)"""
    T = longest_revisit(specs, duration)
    return round((MAX_ACCELERATION / 2.0) ** 2 * T, 6)


def max_lag(sc: Scenario, specs: list[SensorSpec]) -> float:
    """``[mtt] max_lag`` [s] that keeps every scan this simulator delivers late: a scan arrives at most
    ``base_delay`` + its jitter + two of its sensor's periods after its time (:func:`sensor_lines`;
    a sensor that scans once is never late, :func:`revisits`), and so comes at most that far behind
    the newest scan any tracker has (one sensor's or all of them); the jitter's bound
    ``JITTER_S ln(1 / LATE_TAIL)`` (0.28 s) is exceeded once in 10^6 scans. Never below ``[mtt]``'s
    default 3 s (the default sensors need 2.93 s)."""
    bound = 2 * max(revisits(specs, sc.duration), default=0.0) + sc.base_delay + JITTER_S * math.log(1 / LATE_TAIL)
    return max(MttConfig().max_lag, math.ceil(bound * 100) / 100)


def radar_range(sc: Scenario) -> tuple[float, float]:
    return 0.2 * sc.region, 2.6 * sc.region


def radar_elevation(sc: Scenario) -> float:
    return 0.3


def position_clutter_density(sc: Scenario) -> float:
    """A position sensor's false detections per m^2 (``[mtt] clutter_density``)."""
    return sc.clutter / (2 * sc.region) ** 2


def clutter_density(spec: SensorSpec, sc: Scenario) -> float:
    """False detections per unit of the sensor's measurement space (m^2, or m rad^2 for a radar)."""
    if spec.kind == "pos":
        return position_clutter_density(sc)
    lo, hi = radar_range(sc)
    return sc.clutter / ((hi - lo) * 2 * np.pi * radar_elevation(sc))


def noise_floors(lines: list[tuple[float, dict[str, Any]]]) -> dict[str, list[float]]:
    """Each sensor's ``[mtt.sensor.<id>] noise_floor``: per coordinate the least over its scans of
    ``sqrt(R_ii lambda_min(C))``, ``C`` the correlation matrix of the scan's ``R``, so that ``diag(floor²)``
    lies below every ``R`` it declared (a radar's diagonal ``R``: its standard deviations; a position
    sensor's ``sd² [[1, 0.3], [0.3, 1]]``: ``sqrt(0.7) sd`` on both axes)."""
    floors: dict[str, np.ndarray] = {}
    for _, line in lines:
        R = np.array(line["R"])
        sd = np.sqrt(np.diag(R))
        floor = sd * math.sqrt(np.linalg.eigvalsh(R / np.outer(sd, sd))[0])
        sid = line["sensor"]
        floors[sid] = np.minimum(floors[sid], floor) if sid in floors else floor
    return {sid: [float(v) for v in f] for sid, f in floors.items()}


def memory_room() -> float:
    """Bytes a window's truth and scans may take: a quarter of the machine's physical memory (1 GiB where it is not
    known)."""
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") / 4
    except (AttributeError, ValueError, OSError):
        return 2.0**30


def memory_need(sc: Scenario, specs: list[SensorSpec]) -> float:
    """Bytes :func:`simulate` takes at most for ``sc``'s random truth and its scans: ``TRUTH_CELL_BYTES`` per step
    of ``DT`` of each trajectory and, in formations, of each target (the groups' copy of their trajectories), and
    every scan with a detection of each target and its mean clutter count held until they are written."""
    steps = round(sc.duration / DT) + 1
    cells = steps * (-(-sc.targets // sc.formation) + (sc.targets if sc.formation > 1 else 0))
    scans = sum(math.floor(sc.duration / s.period) + 1 for s in specs)
    return cells * TRUTH_CELL_BYTES + scans * (SCAN_BYTES + DETECTION_BYTES * (sc.targets * sc.pd + sc.clutter))


def check_room(sc: Scenario, specs: list[SensorSpec],
               hint: str = "give a shorter --duration, fewer --targets, less --clutter or slower --sensors") -> None:
    """An InputError, before anything is made, when :func:`memory_need` exceeds :func:`memory_room`, ending
    with ``hint`` (before 2026-11-28 ``--duration 1e9`` ended in numpy's MemoryError and a traceback)."""
    need, room = memory_need(sc, specs), memory_room()
    if need > room:
        raise InputError(f"the scenario is too large: {sc.duration:g} s of {sc.targets} targets and the sensors' "
                         f"scans need {need / 2**30:.3g} GiB of memory, more than a quarter of this machine's "
                         f"({room / 2**30:.3g} GiB): {hint}")


def write_scenario(out: Path, lines: list[tuple[float, dict[str, Any]]], truth_rows: Iterable[dict[str, Any]],
                   config: dict[str, Any]) -> None:
    """``measurements.jsonl`` (``lines`` in order), ``truth.jsonl`` and ``config.toml`` into ``out`` (created) as one:
    each to its temporary file, all renamed at the end, so that an error or Ctrl-C half-way leaves the folder's
    files, an earlier run's scenario, as they were (before the tour60 session each file was renamed when written: a
    Ctrl-C after the first left this run's measurements beside the earlier run's truth and config)."""
    out.mkdir(parents=True, exist_ok=True)
    with (output_file(out / "measurements.jsonl") as meas, output_file(out / "truth.jsonl") as truth,
          output_file(out / "config.toml") as cfg):
        for _, line in lines:
            meas.write(json.dumps(line) + "\n")
        for row in truth_rows:
            truth.write(json.dumps(row) + "\n")
        cfg.write(to_toml(config))


def simulate(sc: Scenario, specs: list[SensorSpec], seed: int, out: Path,
             truth: tuple[np.ndarray, np.ndarray] | None = None) -> dict[str, Any]:
    """Write ``measurements.jsonl``, ``truth.jsonl`` and ``config.toml`` to ``out`` (a library
    caller's folder is created; the command checks it first: :func:`main`); ``truth``: given states
    and alive mask (as :func:`simulate_truth` returns) instead of the scenario's random ones."""
    if truth is None:
        check_room(sc, specs)
    rng = np.random.default_rng(seed)
    three_d = any(s.kind == "radar" for s in specs)
    x, alive = simulate_truth(sc, three_d, rng) if truth is None else truth
    lines = [item for spec in specs for item in sensor_lines(spec, sc, x, alive, three_d, rng)]
    lines.sort(key=lambda item: item[0])
    dims = [0, 1, 2, 3, 4, 5] if three_d else [0, 1, 2, 3]
    truth_rows = ({"t": float(sec), "targets": [{"id": int(i), "x": x[round(sec / DT), i, dims].tolist()}
                                                for i in np.flatnonzero(alive[round(sec / DT)])]}
                  for sec in range(int(sc.duration) + 1))
    mtt: dict[str, Any] = {"q": process_noise(specs, sc.duration), "pd": sc.pd,
                           "clutter_density": position_clutter_density(sc),
                           "max_lag": max_lag(sc, specs), "period": 1.0, "init_velocity_std": 30.0,
                           "sensors": [s.id for s in specs]}
    floors = noise_floors(lines)  # the noise each sensor declares: no report claims less (noise_floor.py)
    mtt["sensor"] = {s.id: {**({"clutter_density": clutter_density(s, sc)} if s.kind == "radar" else {}),
                            **({"noise_floor": floors[s.id]} if s.id in floors else {})} for s in specs}
    mtt["sensor"] = {sid: table for sid, table in mtt["sensor"].items() if table}
    if not mtt["sensor"]:
        del mtt["sensor"]
    write_scenario(out, lines, truth_rows, {"mtt": mtt})
    out_of_order = sum(1 for a, b in zip(lines, lines[1:]) if b[1]["t"] < a[1]["t"])
    return {"scans": len(lines), "out_of_sequence": out_of_order, "targets": sc.targets,
            "sensors": [f"{s.id} ({s.kind}, {s.period:g} s)" for s in specs]}


def check_options(args: argparse.Namespace, extra: tuple[tuple[str, bool, str], ...] = ()) -> None:
    """An InputError naming the first of the simulators' common options (``--duration``, ``--pd``, ``--clutter``,
    ``--late``) or of ``extra`` (``(option, valid, rule)``) that is out of its range."""
    common = (("duration", args.duration is None or 0 < args.duration < math.inf, "finite and > 0"),
              ("pd", 0 < args.pd <= 1, "in (0, 1]"),
              ("clutter", 0 <= args.clutter <= MAX_CLUTTER, f"in [0, {MAX_CLUTTER:.0f}]"),
              ("late", 0 <= args.late < 1, "in [0, 1)"))
    for name, ok, rule in (*common, *extra):
        if not ok:
            raise InputError(f"--{name}: must be {rule}, got {getattr(args, name.replace('-', '_')):g}")


SENSOR_IDS = ("Sensor ids: the k-th sensor of --sensors (counted from 1) is s<k> for a position sensor and "
              "r<k> for a radar: pos:1.0,radar:0.7 gives s1 and r2, the ids [mtt] sensors, [mtt.sensor.<id>] and "
              "replay --sensor take.")


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="fedtrack simulate multitarget",
                                     description="simulate a multi-target scenario for replay and evaluate: writes "
                                     "measurements.jsonl (arrival order), truth.jsonl and config.toml into --out",
                                     epilog=SENSOR_IDS)
    parser.add_argument("--scenario", choices=sorted(PRESETS), default="default",
                        help="default: the options' defaults; dense: issue 25's dense scenario, groups of three "
                             "targets 20-40 m apart (within 2 sigma of the coarsest position sensor) crossing other "
                             "groups, --pd 0.8 --clutter 50 --duration 120 --formation 3 (options given override)")
    parser.add_argument("--targets", type=int, default=Scenario.targets,
                        help="number of targets (crossing pairs, turns, some born late or dying early; "
                             "default: %(default)s)")
    parser.add_argument("--sensors", default="pos:1.0,pos:0.7,pos:1.3", metavar="SPEC",
                        help=f"comma-separated KIND:PERIOD[/SIGMA...], KIND pos (2-D position) or radar, PERIOD in "
                             f"seconds, at least {DT:g} (the truth's time step); /SIGMA: a position sensor's noise "
                             f"std per axis [m] (default: drawn in {POS_SD_MIN:g}-{POS_SD_MAX:g}), a radar's "
                             f"/SIGMA_R/SIGMA_AZ[/SIGMA_EL] [m, deg, deg] (default: {RADAR_SD[0]:g} m, "
                             f"{math.degrees(RADAR_SD[1]):.3g} deg); default: %(default)s")
    parser.add_argument("--seed", type=seed_number, default=1, help="seed of truth, noise, clutter and delays "
                        "(default: %(default)s)")
    parser.add_argument("--duration", type=float,
                        help=f"seconds of scenario (default: {Scenario.duration:g}; dense: 120)")
    parser.add_argument("--pd", type=float,
                        help=f"probability that a sensor detects a target in a scan (default: {Scenario.pd:g}; "
                             "dense: 0.8)")
    parser.add_argument("--clutter", type=float,
                        help=f"mean number of false detections per scan (Poisson; at most {MAX_CLUTTER:.0f}, "
                             f"a scan replay can read; default: {Scenario.clutter:g}; dense: 50)")
    parser.add_argument("--half-width", type=float, default=Scenario.region, metavar="M",
                        help="half the side of the square area [m]: targets start within 0.7 of it, position "
                             "sensors' clutter is uniform over all of it, radars stand 1.1 of it from the centre "
                             "(default: %(default)g, a 10 km square; --clutter stays a count per scan, so its "
                             "density falls as the area grows)")
    parser.add_argument("--formation", type=int,
                        help="targets per group flying side by side, 20-40 m apart (default: 1; dense: 3)")
    parser.add_argument("--late", type=float, default=Scenario.late,
                        help="fraction of scans delivered late, up to two of their sensor's periods "
                             "(default: %(default)s)")
    parser.add_argument("--non-fifo", action="store_true",
                        help="a sensor's link is not first-in-first-out: a late scan arrives after the same "
                             "sensor's later scans, as over UDP or several paths (default: each sensor's scans "
                             "arrive in their own order; lines of different sensors interleave either way)")
    parser.add_argument("--out", required=True, type=Path, metavar="DIR",
                        help="folder to write into (created if missing; its own folder must exist)")
    args = parser.parse_args(argv)
    for key in ("duration", "pd", "clutter", "formation"):
        if getattr(args, key) is None:
            setattr(args, key, PRESETS[args.scenario].get(key, getattr(Scenario, key)))
    check_options(args, (("targets", args.targets >= 1, ">= 1"), ("formation", args.formation >= 1, ">= 1"),
                         ("half-width", 0 < args.half_width < math.inf, "finite and > 0")))
    specs = parse_spec(args.sensors)
    sc = Scenario(targets=args.targets, duration=args.duration, region=args.half_width, pd=args.pd,
                  clutter=args.clutter, late=args.late, formation=int(args.formation), fifo=not args.non_fifo)
    check_room(sc, specs)
    check_output_folder(args.out)  # created as the files are written: a Ctrl-C before left it empty (tour61)
    info = simulate(sc, specs, args.seed, args.out)
    print(f"wrote {args.out}/measurements.jsonl ({info['scans']} scans, {info['out_of_sequence']} out of "
          f"sequence), truth.jsonl ({args.targets} targets), config.toml; sensors: {', '.join(info['sensors'])}")
    return 0
