"""``fedtrack serve sensor``: a simulated sensor publishing its scans over Zenoh.

Pacing:

* ``lockstep``: scan 0 at the common start, scan k+1 once the fused track of scan k is out (or
  after ``--lockstep-timeout`` seconds without it, counted in ``lockstep_timeouts``), so a
  whole scenario runs as fast as the pipeline allows;
* ``realtime``: scan k at wall-clock time ``start + k T / speed``.

The common start is ``--start-at``, or ``--start-file``: the launcher starts a host's sensors, waits
until all of them are ready and then writes their common start into that file, so they stay in step
(without either, when the sensor is ready). A lockstep sensor that went first on its own, as before
2026-11-27, had its scan 0 fused without the sensors still starting once the centre's ``deadline_s``
had passed, and a late one, finding a fused track, skipped its scan 0 as if restarted
(docs/deploy.md, Launching).

After its last scan a paper-pipeline sensor waits for that scan's fused track (at most
``--lockstep-timeout``) and exits 0. A multi-target sensor (kind ``scan``) exits at once: no
service answers its scans (no fused track ever comes), and the launcher's staged stop lets its
tracker and the centres handle what it sent before they stop.

Kinds: ``position`` (paper 004 scenario with the ``[[sensor]]`` R, the default),
``sonar`` (cluttered scans with amplitudes, paper 001, table ``[sonar]``) and ``radar``
(range/azimuth/elevation, paper 002, table ``[radar]``); all seeded by ``deployment.seed``.
``scan``: a multi-target sensor publishing its own lines of a multi-target measurements file
(``--measurements``, as ``fedtrack simulate multitarget`` writes it), in time order, scan
``k`` at wall-clock time ``start + t_k / speed`` (realtime pacing only: each sensor keeps its
own period and phase; ``--join-at T``: only its scans from ``T`` on, for a sensor that joins a
running deployment).
"""

from __future__ import annotations

import argparse
import bisect
import math
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from fedtrack.config import ConfigError, finite_number, load_tables, read_small_file, seed_number
from fedtrack.deployment import PACINGS, DeploymentConfig, SensorConfig
from fedtrack.jsonl import InputError, read_jsonl
from fedtrack.local_filters.mtt.scan import SensorScan, parse_scan, scan_to_measurement
from fedtrack.sensors.radar import RadarConfig, radar_scans
from fedtrack.sensors.scenarios import (
    deployment_scenario,
    deployment_truth,
    sensor_measurements,
)
from fedtrack.sensors.sonar import SonarConfig, sonar_scans
from fedtrack.services.base import Service, Subscription, service_kwargs, service_parser
from fedtrack.wire import FusedTrack, Measurement, measurement_from_replay

KINDS = ("position", "sonar", "radar", "scan")
START_FILE_BYTES = 64  # the start file holds one time in Unix seconds (the launcher writes its repr)



@dataclass(frozen=True)
class SensorSettings:
    """The tables a simulated sensor reads: ``[deployment]``, ``[[sensor]]``, ``[sonar]``, ``[radar]``."""

    deployment: DeploymentConfig = field(default_factory=DeploymentConfig)
    sensor: tuple[SensorConfig, ...] = ()
    sonar: SonarConfig = field(default_factory=SonarConfig)
    radar: RadarConfig = field(default_factory=RadarConfig)


def position_scans(settings: SensorSettings, sensor_id: str) -> Iterator[dict[str, Any]]:
    """Replay-format lines of one position sensor in the deployment's paper 004 scenario."""
    dep = settings.deployment
    scenario = deployment_scenario(dep.scenario, dep.duration_s)
    R = next((np.array(s.R) for s in settings.sensor if s.id == sensor_id), None)
    if R is None:
        R = np.array([[100.0, 5.0], [5.0, 100.0]])
    truth = deployment_truth(scenario, dep.seed)
    zs = sensor_measurements(truth, R, dep.seed, sensor_id)
    for t, z in zip(scenario.times, zs):
        yield {"t": float(t), "sensor": sensor_id, "z": z.tolist(), "R": R.tolist()}


def scan_source(kind: str, settings: SensorSettings, sensor_id: str) -> tuple[list[dict[str, Any]], float]:
    """All scans of the sensor as replay lines (without the simulator's truth), and the scan period."""
    seed = settings.deployment.seed
    if kind == "position":
        lines = list(position_scans(settings, sensor_id))
    elif kind == "sonar":
        lines = list(sonar_scans(replace(settings.sonar, sensor=sensor_id), seed))
    else:
        lines = list(radar_scans(replace(settings.radar, sensor=sensor_id), seed))
    lines = [{k: v for k, v in line.items() if k != "truth"} for line in lines]
    period = lines[1]["t"] - lines[0]["t"] if len(lines) > 1 else 1.0
    return lines, period


class SensorService(Service):
    """Publishes ``sensor/<id>/meas`` scan by scan."""

    role = "sensor"
    tick_period_s = 0.01

    def __init__(self, lines: list[dict[str, Any]], period_s: float, pacing: str, speed: float,
                 lockstep_timeout_s: float, start_at: float | None = None, scans: list[SensorScan] | None = None,
                 start_file: Path | None = None, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.lines = lines
        self.scans = scans  # multi-target scans (kind scan), published at their own times
        self.pacing = pacing
        self.interval_s = period_s / speed
        # seconds after the start at which each scan is due (realtime)
        self.due_s = ([scan.t / speed for scan in scans] if scans is not None
                      else [k * self.interval_s for k in range(len(lines))])
        self.total = len(self.due_s)
        self.lockstep_timeout_s = lockstep_timeout_s
        self.start_at = start_at  # wall-clock time of scan 0 (realtime); None: from start_file, else when ready
        self.start_mono: float | None = None  # start_at on the monotonic clock, taken once start_at is known
        self.start_file = start_file
        self.next_seq = 0
        self.last_publish = -float("inf")
        self.fused_up_to = -1

    def start_problem(self, now: float) -> str | None:
        """Why ``--start-at`` is refused at ``now`` (Unix s), None when it is taken: a time before 1970 (``-1`` was
        taken before the tour61 session, the sensor publishing nothing). A start in the past is a restarted sensor's,
        which resumes at the scan then due (:meth:`nothing_left`); a lockstep sensor sends scan 0 at once."""
        if self.start_at is not None and self.start_at < 0:
            return f"--start-at: must be a Unix time >= 0 (seconds since 1970), got {self.start_at:g}"
        return None

    def nothing_left(self, now: float) -> str | None:
        """What to say when a realtime ``--start-at`` had every scan of this sensor due by ``now``, None otherwise: the
        sensor then ends at once, exit 0, having published nothing. A launcher restarting a sensor that failed after
        its last scan was due must see it finished (the tour61 session's exit 2 here made the launcher retry it,
        give it up and end in exit 1); a mistyped start is said in one line, not taken silently as before."""
        if (self.start_at is None or self.pacing != "realtime" or not self.due_s
                or self.start_at + self.due_s[-1] >= now):
            return None
        return (f"--start-at {self.start_at:.3f}: every scan of this sensor was due by "
                f"{self.start_at + self.due_s[-1]:.3f}, {now - self.start_at - self.due_s[-1]:.0f} s ago: nothing left "
                "to publish (give a start ahead of now, or the first start's time to resume a sensor mid-run)")

    def subscriptions(self) -> list[Subscription]:
        """Lockstep pacing follows the fused track and any single-sensor tracker of this sensor."""
        return [Subscription(self.keys.fusion_track(), FusedTrack, self.on_track),
                Subscription(self.keys.tracker_track(None, self.id), FusedTrack, self.on_track)]

    def on_start(self) -> None:
        """A restarted sensor resumes at the current scan: the one due now (realtime) or the one
        after the fusion centre's latest track (lockstep); its missed scans are not sent."""
        if self.pacing == "realtime" and self.start_at is not None and time.time() > self.start_at:
            self.next_seq = bisect.bisect_left(self.due_s, time.time() - self.start_at)
        elif self.pacing == "lockstep":
            latest = self.query(self.keys.fusion_state(), FusedTrack)
            if latest:
                self.fused_up_to = latest[0].seq
                self.next_seq = min(latest[0].seq + 1, self.total)
        if self.next_seq:
            self.log.warning("resuming at scan %d (a restart: scans before it are not sent)", self.next_seq)
            self.count("resumed_at", self.next_seq)

    def on_track(self, msg: FusedTrack) -> None:
        self.fused_up_to = max(self.fused_up_to, msg.seq)

    def on_tick(self) -> None:
        now = time.monotonic()
        if self.start_at is None:
            self.start_at = read_start(self.start_file) if self.start_file is not None else time.time()
            if self.start_at is None:
                return  # the launcher has not given the start yet
            if self.start_file is None and self.pacing == "realtime":  # started by hand: how to resume is said
                self.log.info("scan 0 at %.3f (Unix s): restarted with --start-at %.3f, this sensor resumes at the "
                              "scan then due (without it, it numbers its scans from 0 again)",
                              self.start_at, self.start_at)
        if self.start_mono is None:
            # the common start is a wall-clock time (hosts share no other clock), the scans' times after it
            # monotonic: the wall clock stepped back 30 s mid-run stopped every sensor for 30 s before
            # 2026-11-27, and one stepped forward sent the scans of the skipped seconds at once
            # both clocks read together: `now` was read before the start file, and the time that took
            # would put scan 0 that much before the common start
            self.start_mono = time.monotonic() + (self.start_at - time.time())
        if now < self.start_mono:
            return  # scan 0 (either pacing) goes out at the common start
        if self.next_seq >= self.total:
            waited = now - self.last_publish
            if self.scans is not None or self.fused_up_to >= self.total - 1 or waited >= self.lockstep_timeout_s:
                self.stop()
            return
        if self.pacing == "lockstep":
            due = self.next_seq == 0 or self.fused_up_to >= self.next_seq - 1
            if not due and now - self.last_publish >= self.lockstep_timeout_s:
                self.count("lockstep_timeouts")
                due = True
        else:
            due = now >= self.start_mono + self.due_s[self.next_seq]
        if due:
            self.publish_scan(now)

    def publish_scan(self, now: float) -> None:
        seq = self.next_seq
        if self.scans is not None:
            self.publish(self.keys.sensor_meas(self.id), scan_to_measurement(self.scans[seq], seq, time.time_ns()))
            self.count("scans")
            self.next_seq += 1
            self.last_publish = now
            return
        line = self.lines[seq]
        msg = measurement_from_replay(line, f"scan {seq}", seq=seq)
        self.publish(self.keys.sensor_meas(self.id), Measurement(
            sensor=msg.sensor, seq=seq, t=msg.t, kind=msg.kind, z=msg.z, R=msg.R, detections=msg.detections,
            sensor_position=msg.sensor_position, stamp_ns=time.time_ns()))
        self.count("scans")
        self.next_seq += 1
        self.last_publish = now


def add_sensor_args(parser: argparse.ArgumentParser) -> None:
    dep = DeploymentConfig()  # the defaults of a [deployment] table, which these options override
    parser.add_argument("--config", type=Path, help="deployment TOML ([deployment], [[sensor]]; default: none, every "
                                                    "key at its default)")
    parser.add_argument("--kind", choices=KINDS, default="position",
                        help="what the sensor simulates or replays (default: %(default)s)")
    parser.add_argument("--measurements", type=Path,
                        help="kind scan (required there): the multi-target measurements file whose lines of this "
                             "sensor to publish (default: none)")
    parser.add_argument("--scenario", type=int, choices=(1, 2),
                        help=f"paper 004 scenario (default: deployment.scenario of --config, else {dep.scenario})")
    parser.add_argument("--seed", type=seed_number,
                        help=f"deployment seed (default: deployment.seed of --config, else {dep.seed})")
    parser.add_argument("--pacing", choices=PACINGS,
                        help=f"lockstep or realtime (default: deployment.pacing of --config, else {dep.pacing})")
    parser.add_argument("--speed", type=finite_number, help="realtime pacing: speed-up factor over real time (default: "
                                                    f"deployment.speed of --config, else {dep.speed:g})")
    parser.add_argument("--lockstep-timeout", type=finite_number, default=5.0, metavar="SECONDS",
                        help="publish the next scan anyway after this long without a fused track "
                             "(default: %(default)s)")
    parser.add_argument("--start-at", type=finite_number, metavar="EPOCH_S",
                        help="wall-clock time (Unix seconds, >= 0) of scan 0, shared by the sensors of a deployment; "
                             "in the past: a restart, resuming at the scan then due (realtime: refused when every "
                             "scan was due; default: when this sensor is ready)")
    parser.add_argument("--start-file", type=Path, metavar="PATH",
                        help="without --start-at: wait until PATH holds the start time (Unix seconds; fedtrack "
                             "launch writes it once every sensor of its host is ready; default: none)")
    parser.add_argument("--join-at", type=finite_number, metavar="SECONDS",
                        help="kind scan: publish only the scans at t >= SECONDS (a sensor that joins a running "
                             "deployment; scan times count from --start-at; default: every scan)")


def main(argv: list[str]) -> int:
    parser = service_parser("sensor", "publish a simulated sensor's scans")
    add_sensor_args(parser)
    args = parser.parse_args(argv)
    settings = load_tables(args.config, SensorSettings)
    dep = settings.deployment
    overrides = {k: v for k, v in (("scenario", args.scenario), ("seed", args.seed), ("pacing", args.pacing),
                                   ("speed", args.speed)) if v is not None}
    if overrides:
        settings = replace(settings, deployment=replace(dep, **overrides))
        try:
            settings.deployment.validate()
        except ConfigError as exc:  # an option's value (the file's were checked as it was read): named as the option
            parser.error(f"--{exc}")
    if args.lockstep_timeout <= 0:
        parser.error("--lockstep-timeout must be > 0")
    if args.kind != "scan" and (args.measurements is not None or args.join_at is not None):
        parser.error(f"--measurements and --join-at apply to --kind scan only (a {args.kind} sensor simulates its "
                     "scans)")
    if args.kind == "scan":
        if args.measurements is None:
            parser.error("--kind scan needs --measurements FILE (the scans to publish)")
        if settings.deployment.pacing != "realtime":  # named alone: a given --measurements was said missing too
            source = "--pacing" if args.pacing else "deployment.pacing or its default"
            parser.error(f"--kind scan paces its scans in real time: give --pacing realtime (the pacing is "
                         f"{settings.deployment.pacing}, {source})")
        scans = own_scans(args.measurements, args.id)
        if args.join_at is not None:
            scans = [s for s in scans if s.t >= args.join_at]
        return run_checked(parser, SensorService([], 1.0, "realtime", settings.deployment.speed,
                                                 args.lockstep_timeout, args.start_at, scans=scans,
                                                 start_file=args.start_file, **service_kwargs(parser, args)))
    known = [sensor.id for sensor in settings.sensor]
    if args.kind == "position" and known and args.id not in known:  # was published with the default R, unheard
        parser.error(f"--id {args.id}: not a [[sensor]] id of {args.config} ({', '.join(known)})")
    lines, period = scan_source(args.kind, settings, args.id)
    return run_checked(parser, SensorService(lines, period, settings.deployment.pacing, settings.deployment.speed,
                                             args.lockstep_timeout, args.start_at, start_file=args.start_file,
                                             **service_kwargs(parser, args)))


def run_checked(parser: argparse.ArgumentParser, service: SensorService) -> int:
    """Run ``service``; exit 2 naming ``--start-at`` when :meth:`SensorService.start_problem` refuses it; 0, having
    said why, when it has nothing left to publish (:meth:`SensorService.nothing_left`)."""
    problem = service.start_problem(time.time())
    if problem:
        parser.error(problem)
    over = service.nothing_left(time.time())
    if over:
        print(f"{parser.prog}: {over}", file=sys.stderr)
        return 0
    return service.run()


def read_start(path: Path) -> float | None:
    """The start time (Unix seconds) in ``path``, or None while the file does not exist (the
    launcher writes it whole: a temporary file renamed)."""
    raw = read_small_file(path, START_FILE_BYTES, "start file")  # a FIFO, /dev/zero: refused unread
    if raw is None:
        return None
    text = raw.decode(errors="replace")
    try:
        start = float(text)
    except ValueError:
        start = math.nan
    if not math.isfinite(start):
        raise ValueError(f"{path}: not a start time in Unix seconds: {text[:40]!r}")
    return start


def own_scans(path: Path, sensor: str) -> list[SensorScan]:
    """The scans of ``sensor`` in a multi-target measurements file, in time order (InputError if none)."""
    scans = [parse_scan(obj, f"{path}:{lineno}") for lineno, obj in read_jsonl(path)]
    own = sorted((s for s in scans if s.sensor == sensor), key=lambda s: s.t)
    if not own:
        raise InputError(f"{path}: no scan of sensor {sensor!r} (its sensors: "
                         f"{', '.join(sorted({s.sensor for s in scans})) or 'none'})")
    return own
