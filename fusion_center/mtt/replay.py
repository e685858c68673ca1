"""``fedtrack replay --algorithm mtt-local | mtt-centralized | mtt-federated | mtt-decentralized``.

Reads one sensor scan per line in arrival order (:mod:`fedtrack.local_filters.mtt.scan`) and
writes the track picture every ``period`` seconds: ``{"t", "algorithm", "detector", "tracks":
[...]}`` with every track predicted to ``t``. The picture at ``T`` is written once a scan later
than ``T + picture_delay`` arrives: with ``picture_delay = 0`` it holds the data that had arrived
by then; with ``picture_delay = max_lag`` it holds every scan up to ``T`` that is not late. At
the end of the input the pictures still due are written, up to the first whole period at or
after the latest scan (the last picture holds every scan).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import sys
import time
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from fedtrack.config import ConfigError, did_you_mean, load_tables
from fedtrack.deployment import MAX_TIME_JUMP_S, max_time_jump
from fedtrack.fusion_center.mtt.centre.candidates import CrowdedReport
from fedtrack.fusion_center.mtt.centre.consistency import FALSE_ALARM, Transition
from fedtrack.fusion_center.mtt.centre.copies import Found
from fedtrack.fusion_center.mtt.centre.registration import FALSE_ALARM as REGISTRATION_FALSE_ALARM
from fedtrack.fusion_center.mtt.centre.registration import correction_lines
from fedtrack.fusion_center.mtt.engines import ALGORITHMS, Engine, PictureClock, PictureTracks, make_engine
from fedtrack.fusion_center.mtt.regional import is_region_recording, read_region_entries, recorded_pictures
from fedtrack.fusion_center.mtt.silence import silence_bound, usual_intervals
from fedtrack.geodetic import FrameConfig, geodetic_line, load_frame
from fedtrack.jsonl import InputError, check_output, output_file, read_jsonl
from fedtrack.local_filters.linear.gating import CrowdedScan
from fedtrack.local_filters.mtt.config import MttConfig, MttSettings
from fedtrack.local_filters.mtt.models import position_from_detection
from fedtrack.local_filters.mtt.scan import SensorLeft, SensorScan, TrackerRestarted, misplaced, parse_line
from fedtrack.local_filters.regions import Regions, grid_over, load_regions, parse_grid_spec
from fedtrack.progress import progress_bar
from fedtrack.services.lead import LeadGuard

Line = SensorScan | SensorLeft | TrackerRestarted  # a line of the multi-target input


def read_scans(path: Path, cfg: MttConfig, frame: FrameConfig | None = None) -> list[Line]:
    """Every line of ``path`` (scans, departures and restarts), validated; a sensor the config does not
    allow is an error, and so is, with a ``[frame]``, a radar scan's ``sensor_position`` that cannot be its
    sensor's (:func:`~fedtrack.local_filters.mtt.scan.misplaced`)."""
    scans: list[Line] = []
    kind: dict[str, tuple[bool, int]] = {}  # sensor -> (radar, line of its first scan)
    for lineno, obj in read_jsonl(path):
        where = f"{path}:{lineno}"
        scan = parse_line(obj, where)
        if not cfg.allows(scan.sensor):
            raise InputError(f"{where}: sensor {scan.sensor!r} is not in mtt.sensors"
                             + did_you_mean(scan.sensor, cfg.sensors if isinstance(cfg.sensors, tuple) else ()))
        if isinstance(scan, SensorScan):
            radar, first = kind.setdefault(scan.sensor, (scan.sensor_position is not None, lineno))
            if radar != (scan.sensor_position is not None):
                raise InputError(f"{where}: sensor {scan.sensor!r} sent {_KIND[radar]} scans (line {first}) and "
                                 f"now a {_KIND[not radar]} scan; a sensor's scans are all of one kind (give the "
                                 "other kind's scans their own sensor id)")
            problem = misplaced(scan, frame)
            if problem:
                raise InputError(f"{where}: {problem}")
        scans.append(scan)
    return scans


_KIND = {True: "radar (sensor_position)", False: "2-D position"}


def state_dim(scans: list[Line], sensor: str | None = None) -> int:
    """The state size of a tracker of ``scans`` (of ``sensor``'s only, if given): 6 when any is a
    radar's, else 4."""
    return 6 if any(isinstance(s, SensorScan) and s.sensor_position is not None
                    and (sensor is None or s.sensor == sensor) for s in scans) else 4


def pictures(engine: Engine, scans: list[Line], period: float, delay: float,
             max_gap: float = MAX_TIME_JUMP_S) -> Iterator[tuple[float, PictureTracks]]:
    """Feed ``scans`` in arrival order and yield each picture once the data has passed its time (none more
    than ``max_gap``, ``[deployment] max_time_jump_s``, before the data: :class:`PictureClock`); a
    scan stamped far ahead of the data waits for a witness (:class:`LeadGuard`, ``engine.lead``)."""
    clock = PictureClock(period, delay, max_gap=max_gap)
    engine.lead = guard = engine.lead or LeadGuard(engine.cfg.max_lag, corroborate=True)
    recorded = any(isinstance(item, (SensorLeft, TrackerRestarted)) for item in scans)  # a live centre's recording
    heard: dict[str, float] = {}  # sensor -> the data's time (the newest scan taken) at its last scan
    restarts: set[str] = set()  # sensors whose tracker restarts with their next scan, after the pictures due
    for item in scans:
        if isinstance(item, SensorLeft):
            guard.leave(item.sensor)
            engine.leave(item.sensor)
            clock.left()
            continue
        if isinstance(item, TrackerRestarted):  # the live centre took it with the report, after the pictures due
            restarts.add(item.sensor)
            continue
        for scan in guard.admit(item.sensor, item.t, item):
            for T in clock.due(engine.data_time(scan.sensor, scan.t)):
                for sensor in [] if recorded else silent(guard, heard, T, engine.cfg.central_timeout):
                    guard.leave(sensor)
                    engine.leave(sensor, at_once=True)
                yield _picture(engine, T)
            if scan.sensor in restarts:
                restarts.discard(scan.sensor)
                engine.restart(scan.sensor)
            engine.repeated += scan.repeated
            try:
                engine.ingest(scan)
            except (CrowdedReport, CrowdedScan) as exc:
                raise CrowdedReport(f"the scan of {scan.sensor} at t = {scan.t:g}: {exc}") from None
            guard.took(scan.sensor, scan.t)
            heard[scan.sensor] = guard.newest
    guard.end()
    for T in clock.final():
        yield _picture(engine, T)


@contextmanager
def crowded_as_input(measurements: Path) -> Iterator[None]:
    """A :class:`CrowdedReport` of the centre as the input error it is (docs/wire.md, ``crowded``)."""
    try:
        yield
    except CrowdedReport as exc:
        raise InputError(f"{measurements}: {exc}: more tracks within one another's reach than a centre "
                         "takes (docs/wire.md#rejections, crowded)") from None


def silent(guard: LeadGuard, heard: dict[str, float], T: float, floor_s: float) -> list[str]:
    """The live sensors (``guard.live``) silent at ``T`` beyond their bound (the live centre's
    rule, :func:`~fedtrack.fusion_center.mtt.silence.silence_bound`, with ``central_timeout`` for
    ``leave_after_s``): whose last scan came when the data's time (the newest scan taken) was
    ``heard[s]``, more than the bound before ``T``; the data's time stands for the wall clock, so a
    sensor whose scans come steadily but stamped behind the others' (a slow link) is not silent.
    The replay of data without departure lines drops them as the live centre would have
    (docs/multitarget.md, "Silence in a replay")."""
    usual = usual_intervals(guard.gaps)  # the silence rule's usual interval, not the guard's median
    return sorted(s for s in guard.live if T - heard[s] > silence_bound(s, usual, floor_s))


def _picture(engine: Engine, T: float) -> tuple[float, PictureTracks]:
    start = time.perf_counter()
    picture = engine.picture(T)
    engine.took("pictures", start)
    return T, picture


def periods(scans: list[Line]) -> dict[str, float]:
    """Each sensor's usual interval between its scans (:func:`~.silence.usual_intervals` of their times in
    order), for sensors with two scans or more."""
    times: dict[str, list[float]] = {}
    for scan in scans:
        if isinstance(scan, SensorScan):
            times.setdefault(scan.sensor, []).append(scan.t)
    gaps = {s: deque(b - a for a, b in itertools.pairwise(sorted(ts)) if b > a) for s, ts in times.items()}
    return usual_intervals(gaps)


def counter_lines(counts: dict[str, int]) -> list[str]:
    """What the engine's counters count, one line each (the centre's only for a centre)."""
    lines: list[str] = [f"{counts['scans']} scans fused",
             f"{counts['late']} scans late (older than max_lag before their tracker's newest), not fused",
             f"{counts['duplicates']} duplicate scans (equal to one fused before), not fused",
             (f"{counts.get('conflicts', 0)} scans at a time their sensor has another scan of, not fused "
              "(live: rejected_conflict)"),
             f"{counts['rerun']} scans run again after an out-of-sequence scan before them",
             f"{counts.get('repeated', 0)} detections equal to an earlier one of their scan, dropped",
             (f"{counts.get('lead', 0)} scans stamped too far ahead of the data and never witnessed, not fused "
              "(docs/multitarget.md#scans-stamped-far-ahead)")]
    if "copies" in counts:
        lines.append(f"{counts['copies']} scans equal to another sensor's (a duplicated feed), not fused")
    if "centre_fused" in counts:
        lines += [f"{counts['centre_fused']} centre observations fused",
                  f"{counts['centre_reprocessed']} centre observations re-processed (fused again after an older one)",
                  f"{counts['centre_late']} centre observations late (older than max_lag), not fused",
                  (f"{counts.get('centre_late_reports', 0)} reports late (older than max_lag before the centre's "
                   "newest), neither fused nor associated"),
                  (f"{counts['centre_before_start']} centre observations older than their central track's "
                   "start, not fused"),
                  (f"{counts.get('centre_uncorroborated', 0)} tentative central tracks of one sensor alone held back "
                   "(another sensor sees their place and missed them)"),
                  (f"{counts.get('centre_demoted', 0)} confirmed central tracks of one sensor alone made tentative "
                   "again (the others see their place and deny them)")]
    if "centre_copies" in counts:
        lines.append(f"{counts['centre_copies']} reports of a sensor copying another's feed (the same observations at "
                     "the same times), not fused")
    if "noise_raised" in counts or "centre_noise_raised" in counts:
        pre, what = ("", "detections") if "noise_raised" in counts else ("centre_", "centre observations")
        lines.append(f"{counts[pre + 'noise_raised']} {what} whose R claimed less than their sensor's noise_floor, "
                     f"raised to it; {counts[pre + 'floor_mismatch']} {'scans' if not pre else 'reports'} of "
                     "another size than their sensor's noise_floor, not fused")
    if "centre_inconsistency_onsets" in counts:
        lines.append(f"{counts['centre_inconsistency_onsets']} sensors flagged inconsistent (innovations against the "
                     f"others' beyond the {FALSE_ALARM:g} test), {counts['centre_inconsistent_sensors']} still "
                     f"flagged at the end, {counts.get('centre_excluded_observations', 0)} of their observations "
                     "left out of the fusion")
    if "centre_registration_corrections" in counts:
        lines.append(f"{counts['centre_registration_corrections']} registration corrections (a sensor's offsets or "
                     f"clock off the consensus beyond the {REGISTRATION_FALSE_ALARM:g} test), "
                     f"{counts['centre_registered_sensors']} sensors corrected at the end")
    if "centre_handed_over" in counts:
        lines.append(f"{counts['centre_handed_over']} central tracks handed over between regions, "
                     f"{counts.get('centre_handover_expired', 0)} local tracks whose new owner did not hold them "
                     "within unsupported_s, forgotten (live: the trackers' handover_expired)")
    return lines


def consistency_lines(transitions: list[Transition], shown: int = 10) -> list[str]:
    """The sensors the centre flagged inconsistent, with the times they were flagged (the first ``shown``)."""
    onsets = [tr for tr in transitions if tr.flagged]
    if not onsets:
        return []
    listed = ", ".join(f"{tr.sensor} at t={tr.t:.2f} (x{tr.ratio:.2f})" for tr in onsets[:shown])
    more = f" and {len(onsets) - shown} more" if len(onsets) > shown else ""
    return [f"sensors flagged inconsistent: {listed}{more}"]


def copy_lines(found: list[Found], shown: int = 10) -> list[str]:
    """The sensors the centre found to copy another's feed, and those released, with the times (the first
    ``shown`` of each)."""
    lines = []
    for is_found, what in ((True, "sensors found copying another's feed (their reports not fused)"),
                           (False, "copying sensors released (fused again)")):
        some = [f for f in found if f.found is is_found]
        if some:
            listed = ", ".join(f"{f.copy} of {f.original} at t={f.t:.2f}" for f in some[:shown])
            more = f" and {len(some) - shown} more" if len(some) > shown else ""
            lines.append(f"{what}: {listed}{more}")
    return lines


def data_regions(spec: str, scans: list[Line], config: Path | None) -> Regions:
    """``--regions SPEC``: ``config`` (the config file's ``[regions]``) or ``NXxNY``, a grid over the
    extent of the detections' positions (margin: the config's, else 0). A note on stderr when no
    detection is within the config's regions' extent (every track then goes to the nearest region)."""
    configured = load_regions(config)
    positions = (position_from_detection(s.z, s.R, s.sensor_position)[0][:, :2] for s in scans
                 if isinstance(s, SensorScan) and s.z.size)  # x, y per scan, made as they are read
    if spec == "config":
        if configured is None:
            raise ConfigError(f"--regions config: {config or 'no config file'} has no [regions] table")
        lo, hi = configured.vertices.min(axis=(0, 1)), configured.vertices.max(axis=(0, 1))
        inside = any(((p >= lo) & (p <= hi)).all(axis=1).any() for p in positions)  # stops at the first
        if not inside and any(isinstance(s, SensorScan) and s.z.size for s in scans):
            print(f"--regions config: note: none of the measurements' detections is within the extent of {config}'s "
                  "regions (each track goes to the nearest region; lat_lon given as lon, lat?)", file=sys.stderr)
        return configured
    nx, ny = parse_grid_spec(spec)
    positions = list(positions)
    if not positions:
        raise ConfigError("--regions: the measurements hold no detection to span a grid over")
    return grid_over(np.concatenate(positions), nx, ny, 0.0 if configured is None else configured.margin)


def replay_mtt(algorithm: str, measurements: Path, config: Path | None, out: Path,
               period: float | None = None, sensor: str | None = None, regions: str | None = None) -> int:
    """Entry point of ``fedtrack replay --algorithm mtt-*``; returns the number of pictures written."""
    if algorithm not in ALGORITHMS:
        raise ConfigError(f"algorithm: unknown multi-target algorithm {algorithm!r}")
    cfg = load_tables(config, MttSettings).mtt
    if period is not None:
        try:
            cfg = dataclasses.replace(cfg, period=period)
            cfg.validate()
        except ConfigError as err:
            raise ConfigError(f"--{err}") from None
    if (algorithm == "mtt-local") != (sensor is not None):
        raise ConfigError("--sensor ID is required by mtt-local and only by it")
    check_output(out)
    start = time.perf_counter()
    recording = is_region_recording(measurements)
    if recording and (regions is None or algorithm == "mtt-local"):
        raise ConfigError(f"{measurements}: a live region run's recording (its lines name their region): replay it "
                          "with --algorithm mtt-federated or mtt-decentralized --regions config")
    frame = load_frame(config)  # [frame]: the tracks on the Earth too (lat, lon, alt), each radar's own axes
    sites = {} if frame is None else frame.radar_sites()  # [frame.sites]: a track-to-track centre's radars
    if recording:
        # a live region run's recording: each region centre in its recorded order (regional.py)
        if regions != "config":
            raise ConfigError("--regions: a region run's recording replays with --regions config (its regions)")
        shards = data_regions(regions, [], config)
        entries = read_region_entries(measurements, shards)
        scans = [e[0] for _, e in entries if isinstance(e, tuple) and isinstance(e[0], SensorScan)]
        dim = state_dim(scans)
        engine = make_engine(algorithm, cfg, dim)
        recorded: dict[str, int] = {}
        source = recorded_pictures(cfg, dim, algorithm == "mtt-federated", shards, entries, recorded,
                                   max_time_jump(config), sites, None if frame is None else frame.frame)
    else:
        scans = read_scans(measurements, cfg, frame)
        if not any(isinstance(s, SensorScan) for s in scans):  # as the single-target replay refuses an empty file
            raise InputError(f"{measurements}: no scans")
        if sensor is not None and not any(s.sensor == sensor for s in scans):
            raise InputError(f"{measurements}: no scan of sensor {sensor!r} (its sensors: "
                             f"{', '.join(sorted({s.sensor for s in scans})) or 'none'})")
        dim = state_dim(scans, sensor)
        shards = None if regions is None else data_regions(regions, scans, config)
        engine = make_engine(algorithm, cfg, dim, sensor, shards, None if frame is None else frame.frame, sites)
        source = pictures(engine, scans, cfg.period, cfg.picture_delay, max_time_jump(config))
        recorded = {}
    note = cfg.count_note({s.sensor: s.R for s in reversed(scans) if isinstance(s, SensorScan) and s.dim == 2
                           and (sensor is None or s.sensor == sensor)},  # each sensor's first R
                          periods(scans))
    if note:
        print(f"{algorithm}: note: {note}", file=sys.stderr)
    heard = {s.sensor for s in scans if isinstance(s, SensorScan)}
    stray = sorted(set(cfg.sensor) - heard)
    if stray:  # a mistyped id (S1 for s1): its noise_floor, pd, clutter_density unused, silently before tour61
        print(f"{algorithm}: note: {', '.join(f'[mtt.sensor.{sid}]' for sid in stray)} of {config} names no sensor "
              f"of {measurements} (its sensors: {', '.join(sorted(heard))}): its keys are not used", file=sys.stderr)
    read_s = time.perf_counter() - start
    n = onsets = 0
    detector = False  # whether the pictures carry maneuver events (a detector runs)
    maneuvering: set[int] = set()
    head = {"algorithm": algorithm, "detector": cfg.maneuver}
    times = [s.t for s in scans if isinstance(s, SensorScan)]
    expected = math.ceil(max(times) / cfg.period) - math.ceil(min(times) / cfg.period) + 1 if times else 0
    with output_file(out) as fh, progress_bar(expected, f"{algorithm} pictures") as bar, crowded_as_input(measurements):
        for T, tracks in source:
            bar.update()
            start = time.perf_counter()
            line = tracks.on_the_earth(None if frame is None else frame.frame, cfg.init_z_std).line(T, head)
            fh.write((line if frame is None else geodetic_line(line, frame.frame, cfg.init_z_std)) + "\n")
            engine.took("writing", start)
            n += 1
            detector = detector or tracks.maneuver is not None
            now = tracks.maneuvering()
            onsets, maneuvering = onsets + len(now - maneuvering), now
    counts = recorded or engine.counters()
    for line in counter_lines(counts):
        print(f"{algorithm}: {line}", file=sys.stderr)
    for line in consistency_lines(engine.consistency_transitions() if hasattr(engine, "consistency_transitions")
                                  else []):
        print(f"{algorithm}: {line}", file=sys.stderr)
    for line in copy_lines(engine.feed_copies() if hasattr(engine, "feed_copies") else []):
        print(f"{algorithm}: {line}", file=sys.stderr)
    for reg in engine.registrations() if hasattr(engine, "registrations") else []:
        for line in correction_lines(reg):
            print(f"{algorithm}: {line}", file=sys.stderr)
    if detector:
        print(f"{algorithm}: {onsets} maneuver onsets detected (pictures with a track's maneuver that the "
              "previous picture did not show)", file=sys.stderr)
    stages = {"reading": read_s, **engine.stage_s}
    print(f"{algorithm}: seconds per input scan by stage: "
          + ", ".join(f"{name} {sec / max(len(scans), 1):.4f}" for name, sec in stages.items())
          + f" ({len(scans)} scans)", file=sys.stderr)
    return n
