"""fedtrack launch CONFIG.toml: start every service of a deployment as separate processes.

Order: router -> local filters, fusion center, recorder -> (all announced by liveliness)
-> sensors -> (all announced) -> with realtime pacing, their common start time, given
``START_MARGIN_S`` ahead (:func:`release_sensors`). While it runs it shows scans fused, per-sensor scan rates and the latency
from a sensor's publish to the fused track's arrival. It ends when the sensors have
published their last scan (then stops the rest), or on Ctrl-C / SIGTERM (stops
everything, no orphans: every child also gets SIGTERM if the launcher dies). Exit code
0 when every service ended cleanly, 1 naming the service that failed. Once everything has
stopped, it writes ``measurements.jsonl`` and ``tracks.jsonl`` from this host's recording
(:meth:`Launcher._export_recording`).

Supervision: a service that exits with a non-zero code (or a signal) after start-up is
restarted after a backoff (``RESTART_BACKOFF_S``, doubling up to ``RESTART_BACKOFF_MAX_S``),
the reason logged, at most ``MAX_RESTARTS`` times per service. Beyond that, an essential
service (router, fusion center, recorder) stops the deployment cleanly (exit 1); a
sensor or local filter is left out and the rest goes on degraded (exit 1 at the end).

Failover (``[multitarget] standby = true``): every multi-target centre gets a hot standby
(``<id>-standby``, ``serve mtt-centre --standby``), started once the primaries are ready. When a
primary dies its standby takes over (:mod:`fedtrack.fusion_center.mtt.standby`) and the launcher
restarts the dead process as the new standby; the report lists each failover (the centre's
scope, when its primary token went, how long until the standby held it and until the scope's
next picture arrived, in seconds and in scans of the slowest sensor).
"""

from __future__ import annotations

import argparse
import collections
import ctypes
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from fedtrack.config import ConfigError, in_file
from fedtrack.deploy.failovers import FailoverWatch
from fedtrack.deploy.multitarget import (
    SCENARIO_DIR,
    check_multitarget,
    finish_multitarget,
    prepare,
    sensor_ids,
    sensor_specs,
    service_args,
)
from fedtrack.deploy.procstat import process_usage
from fedtrack.deploy.report import LaunchReport, finish
from fedtrack.deploy.security import (
    LAUNCHER,
    check_router_names,
    host_endpoints,
    identity,
    router_limits,
    write_configs,
)
from fedtrack.deploy.settings import Settings, check_launchable, load_settings
from fedtrack.deployment import ROLES, listen_address, port_in_use
from fedtrack.jsonl import InputError, output_folder
from fedtrack.keys import Keys
from fedtrack.local_filters.mtt.service import RESET_TIMEOUT_S
from fedtrack.local_filters.regions import load_regions
from fedtrack.recording import Recording
from fedtrack.services.rejections import clip
from fedtrack.wire import FusedTrack, Health, M, Measurement, TrackPicture, WireError, decode
from fedtrack.zsession import SessionError, SessionOptions, close_session, open_session, wait_alive

STOP_GRACE_S = 5.0
RECORDER_GRACE_S = 20.0  # the recorder commits what it still holds (a row an fsync) before it stops
PR_SET_PDEATHSIG = 1
ESSENTIAL_ROLES = ("router", "fusion-center", "recorder")
MAX_RESTARTS = 3
SNAPSHOT = "fusion-center.snapshot"  # the fusion center's state, for its restarts within this run
PICTURE_SNAPSHOT = "picture.snapshot"  # serve picture's last merged time, for its restarts within this run
RESTART_BACKOFF_S = 0.5
RESTART_BACKOFF_MAX_S = 4.0
START_FILE = "start-at"  # beside the sensors' logs: their common start time (realtime), written once all are ready
START_MARGIN_S = 0.25  # the start is this long after the last sensor was ready: 25 of the sensors' 10 ms polls of START_FILE
JOIN_LEAD_S = 2.0  # a joining sensor's processes start this long before its join time
ROUTER_DRAIN_S = 0.5  # a router joined to other hosts' routers is stopped this long after the rest (in-flight data)


def describe_exit(code: int) -> str:
    """``exit code 3`` or ``signal SIGKILL``."""
    if code < 0:
        try:
            return f"signal {signal.Signals(-code).name}"
        except ValueError:
            return f"signal {-code}"
    return f"exit code {code}"


RATE_WINDOW_S = 5.0  # the progress line's per-sensor rates: scans a second over the last 5 s (over the whole
# run before 2026-11-27, so a sensor killed at 60 s still showed 1/s at 90 s and one joining at 30 s 0/s)
USAGE_SAMPLE_S = 0.5  # how often the launcher samples its services' peak RSS and CPU time
STOP_STAGE = {"fusion-center": 1, "mtt-centre": 1, "picture": 2, "recorder": 3, "router": 4}  # others 0


class LaunchError(RuntimeError):
    """A service failed to start or an essential service died."""


@dataclass
class ServiceProcess:
    role: str
    id: str
    argv: list[str]
    log_path: Path
    proc: subprocess.Popen[bytes] | None = None
    join_at_s: float | None = None  # scenario seconds: started then (``[multitarget] join_at``)
    kill_at_s: float | None = None  # scenario seconds: SIGKILLed then, never restarted (``kill_at``)
    killed: bool = False

    @property
    def name(self) -> str:
        return f"{self.role}/{self.id}"

    @property
    def region(self) -> str | None:
        """The region of a region centre (``--region RID``), else None."""
        return self.argv[self.argv.index("--region") + 1] if "--region" in self.argv else None

    @property
    def standby(self) -> bool:
        return "--standby" in self.argv

    def log_tail(self, lines: int = 15) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return "(no log)"


class Stopped(KeyboardInterrupt):
    """Ctrl-C or SIGTERM stopped the deployment; every service was shut down. ``report`` holds
    what was seen up to then (a host without sensors normally ends this way)."""

    def __init__(self, report: LaunchReport) -> None:
        super().__init__()
        self.report = report


class ServiceFailed(LaunchError):
    """The deployment ran to its end, but some service failed; ``report`` holds what was seen."""

    def __init__(self, report: LaunchReport, message: str) -> None:
        super().__init__(message)
        self.report = report


def _die_with_parent() -> None:
    """Child side: receive SIGTERM if the launcher dies (Linux prctl), then start a new group."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        pass


def service_plan(settings: Settings, config_path: Path, out_dir: Path, log_dir: Path,
                 recorder_exports: bool = True) -> list[ServiceProcess]:
    """The processes this host starts, in start order (sensors last). The recorder writes
    ``out_dir``'s JSON Lines files itself when it stops (``--out``) unless ``recorder_exports``
    is false: ``fedtrack launch`` writes them once everything has stopped."""
    dep = settings.deployment
    connect = [a for ep in dep.connect_endpoints for a in ("--connect", ep)]
    common = ["--deployment", dep.name, *connect]
    base = [sys.executable, "-m", "fedtrack.cli", "serve"]
    sensors = [s.id for s in settings.sensor]
    here = [s for s in sensors if dep.local_sensors is None or s in dep.local_sensors]
    plan: list[ServiceProcess] = []
    exports = ["--out", str(out_dir)] if recorder_exports else []

    def add(role: str, sid: str, args: list[str]) -> None:
        plan.append(ServiceProcess(role, sid, base + [role, "--id", sid] + args,
                                   log_dir / f"{role}-{sid}.log"))

    if "router" in dep.services and dep.router_listen:
        peers = [a for ep in dep.router_connect for a in ("--connect", ep)]
        add("router", "router", ["--deployment", dep.name, "--listen", dep.router_listen, *peers])
    cfg = ["--config", str(config_path)]
    if settings.multitarget is not None:
        if "recorder" in dep.services:
            add("recorder", "recorder", ["--db", str(out_dir / "recording.db"), *exports, *common])
        mt = settings.multitarget
        for role, sid, args in service_args(settings, out_dir / SCENARIO_DIR / "measurements.jsonl",
                                            load_regions(config_path)):
            if runs_here(settings, role, sid, args):
                snapshot = ["--snapshot", str(out_dir / PICTURE_SNAPSHOT)] if role == "picture" else []
                add(role, sid, [*args, *cfg, *common, *snapshot])
                if role in ("sensor", "mtt-local"):
                    plan[-1].join_at_s, plan[-1].kill_at_s = mt.join_at.get(sid), mt.kill_at.get(sid)
                if role == "mtt-centre" and mt.standby:
                    add(role, f"{sid}-standby", [*args, *cfg, *common, "--standby"])
        return plan
    if "local-filter" in dep.services:
        for s in here:
            add("local-filter", s, ["--sensor", s, *cfg, *common])
    if "fusion-center" in dep.services:
        add("fusion-center", "fusion", [*cfg, *common, "--snapshot", str(out_dir / SNAPSHOT)])
    if "recorder" in dep.services:
        add("recorder", "recorder", ["--db", str(out_dir / "recording.db"), *exports, *common])
    if "sensor" in dep.services:
        for s in here:
            add("sensor", s, [*cfg, *common])
    return plan


def set_aside_recording(db: Path) -> Path | None:
    """Move an earlier run's recording database ``db`` (with SQLite's ``-wal`` and ``-shm``
    files) to ``db.previous``, replacing the one kept there; returns where, or None without one.
    The recorder appends to its database (across its restarts within a run), so a run into an
    output folder that held another run's recording exported both runs' data as one."""
    if not db.exists():
        return None
    kept = db.with_name(db.name + ".previous")
    for suffix in ("", "-wal", "-shm"):
        Path(str(kept) + suffix).unlink(missing_ok=True)
        if Path(str(db) + suffix).exists():
            Path(str(db) + suffix).rename(str(kept) + suffix)
    return kept


def runs_here(settings: Settings, role: str, sid: str, args: list[str]) -> bool:
    """Whether this host runs a multi-target service: its role is in ``deployment.services``, a
    sensor's services only for ``local_sensors``, a region's centre only for ``local_regions``."""
    dep = settings.deployment
    if role in ("sensor", "mtt-local") and sid not in here_mtt(settings):
        return False
    if "--region" in args and dep.local_regions is not None and args[args.index("--region") + 1] not in dep.local_regions:
        return False
    return role in dep.services or role not in ROLES


def here_mtt(settings: Settings) -> list[str]:
    """The multi-target scenario's sensors this host runs (``deployment.local_sensors``, default all)."""
    assert settings.multitarget is not None
    ids = sensor_ids(settings.multitarget)
    local = settings.deployment.local_sensors
    return [s for s in ids if local is None or s in local]


def apply_zenoh_settings(settings: Settings, config_path: Path, out_dir: Path,
                         plan: list[ServiceProcess]) -> str | None:
    """Hand every service of ``plan`` its Zenoh configuration (``[zenoh]`` table, see
    :mod:`fedtrack.deploy.security`) with ``--zenoh-config``; returns the launcher monitor's file."""
    dep = settings.deployment

    def ident(sp: ServiceProcess) -> str:
        return identity(sp.role, sp.id, sp.region)

    if settings.zenoh.insecure:  # the file's explicit opt-out, which every ``serve`` then needs off loopback
        for sp in plan:
            sp.argv = [*sp.argv, "--insecure"]
    here = sorted({ident(sp) for sp in plan})  # the certificates this host needs (other hosts hold theirs)
    sensors = sensor_ids(settings.multitarget) if settings.multitarget is not None else [s.id for s in settings.sensor]
    regions = load_regions(config_path) if settings.multitarget is not None else None
    centres = [identity("mtt-centre", rid, rid) for rid in (regions.ids if regions is not None else ())]
    everyone = sorted({*here, *(identity("sensor", sid) for sid in sensors), *centres, "router", "fusion", "recorder"})
    with in_file(config_path):
        paths = write_configs(settings.zenoh, config_path.parent, Keys(dep.name), here, out_dir, everyone,
                              router_limits(dep.deadline_s, RESET_TIMEOUT_S))
        if settings.zenoh.tls_dir is not None:
            check_router_names((config_path.parent / settings.zenoh.tls_dir).resolve(), host_endpoints(dep))
    if not paths:
        return None
    for sp in plan:
        sp.argv = [*sp.argv, "--zenoh-config", str(paths[ident(sp)])]
    return str(paths[LAUNCHER])


def await_start(sensors: list[ServiceProcess]) -> Path | None:
    """Have the realtime ``sensors`` wait, once ready, for their common start time in one file
    (``START_FILE`` beside their logs, an earlier run's removed): ``--start-file``; returns the file."""
    if not sensors:
        return None
    path = sensors[0].log_path.parent / START_FILE
    path.unlink(missing_ok=True)
    for sp in sensors:
        sp.argv = [*sp.argv, "--start-file", str(path)]
    return path


def release_sensors(sensors: list[ServiceProcess], path: Path | None, start_at: float) -> float:
    """Give the ``sensors`` one wall-clock start time (realtime pacing schedules scan k at
    start + k T / speed, so they stay in step and do not drift): written to ``path`` for those
    waiting on it, and ``--start-at`` instead of ``--start-file`` for their later starts (restarts,
    sensors that join); returns it."""
    if path is not None:
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(f"{start_at:.6f}\n")
        tmp.replace(path)
    for sp in sensors:
        if "--start-file" in sp.argv:
            i = sp.argv.index("--start-file")
            sp.argv = [*sp.argv[:i], *sp.argv[i + 2:]]
        sp.argv = [*sp.argv, "--start-at", f"{start_at:.6f}"]
    return start_at


class Launcher:
    """Runs a plan of service processes and watches the deployment over Zenoh."""

    def __init__(self, settings: Settings, plan: list[ServiceProcess], quiet: bool = False,
                 max_scans: int | None = None, zenoh_config: str | None = None, title: str = "fedtrack launch",
                 scopes: frozenset[str] = frozenset()) -> None:
        self.settings = settings
        self.title = title  # the command the launcher's own lines name (``fedtrack demo`` runs one too)
        self.zenoh_config = zenoh_config
        self.plan = plan
        self.quiet = quiet
        self.max_scans = max_scans
        self._enough = threading.Event()
        self.keys = Keys(settings.deployment.name)
        self.report = LaunchReport()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._session: zenoh.Session | None = None
        self._subs: list[Any] = []
        self._restart_at: dict[str, float] = {}  # service -> monotonic time of its pending restart
        self.watch = FailoverWatch(scopes)  # failovers and router outages, from the tokens and pictures
        self._wall0_ns, self._mono0_ns = time.time_ns(), time.monotonic_ns()  # the watch's clock (_watch_ns)
        self._epoch: float | None = None  # wall-clock time of the sensors' scenario time 0
        self._arrivals: dict[str, collections.deque[float]] = {}  # sensor -> its scans of the last RATE_WINDOW_S
        # the newest fused track's scan number: a measurement's publish stamp is kept only up to max_seq_jump beyond
        # it (the services reject one further ahead), one per sensor and scan: a sensor numbering its scans
        # afresh on its own key grew the launcher by 212 B each (21 MB per 100,000), for good
        self._newest_track = -1

    # ------------------------------------------------------------ processes
    def _start(self, sp: ServiceProcess) -> None:
        sp.log_path.parent.mkdir(parents=True, exist_ok=True)
        log = sp.log_path.open("ab" if sp.proc is not None else "wb")  # a restart appends to the log
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        sp.proc = subprocess.Popen(sp.argv, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                   preexec_fn=_die_with_parent, env=env)
        log.close()

    def _check_alive(self, group: list[ServiceProcess], starting: bool = False) -> None:
        """Any service failing while starting ends the deployment; later, a failed service is
        restarted after a backoff, up to MAX_RESTARTS times (see the module docstring)."""
        now = time.monotonic()
        for sp in group:
            if (sp.proc is None or sp.proc.poll() is None or sp.proc.returncode == 0 or sp.name in self.report.failed
                    or sp.killed):
                continue
            reason = describe_exit(sp.proc.returncode)
            if starting:
                raise LaunchError(f"{sp.name} exited with {reason}:\n{sp.log_tail()}")
            due = self._restart_at.get(sp.name)
            if due is not None:
                if now >= due:
                    del self._restart_at[sp.name]
                    self._as_standby(sp)
                    self._start(sp)
                continue
            done = self.report.restarts.get(sp.name, 0)
            if done >= MAX_RESTARTS:
                if sp.role in ESSENTIAL_ROLES:
                    raise LaunchError(f"{sp.name} exited with {reason} after {done} restarts (limit "
                                      f"{MAX_RESTARTS}); stopping the deployment:\n{sp.log_tail()}")
                self.report.failed.append(sp.name)
                self._say(f"{sp.name} exited with {reason} after {done} restarts (limit {MAX_RESTARTS}); "
                          "continuing without it")
                continue
            delay = min(RESTART_BACKOFF_S * 2 ** done, RESTART_BACKOFF_MAX_S)
            self.report.restarts[sp.name] = done + 1
            self._restart_at[sp.name] = now + delay
            self._say(f"{sp.name} exited with {reason}; restart {done + 1} of {MAX_RESTARTS} in {delay:g} s")

    def _as_standby(self, sp: ServiceProcess) -> None:
        """A centre with standbys restarts as a standby: its twin took over (or will) when it died."""
        mt = self.settings.multitarget
        if sp.role == "mtt-centre" and mt is not None and mt.standby and not sp.standby:
            sp.argv = [*sp.argv, "--standby"]
            self._say(f"{sp.name} restarts as a standby")

    def _sample_usage(self) -> None:
        """Record every running service's peak RSS and CPU time so far (the last sample before it exits)."""
        for sp in self.plan:
            if sp.proc is not None and sp.proc.poll() is None:
                usage = process_usage(sp.proc.pid)
                if usage is not None:
                    self.report.processes[sp.name] = {"max_rss_mb": usage.peak_rss_mb, "cpu_s": usage.cpu_s}

    def _finished(self, sp: ServiceProcess) -> bool:
        """Ended for good: exited 0, killed by the schedule, or given up after MAX_RESTARTS."""
        return sp.proc is not None and sp.proc.poll() is not None and (sp.proc.returncode == 0 or sp.killed
                                                                       or sp.name in self.report.failed)

    def _follow_schedule(self) -> None:
        """``[multitarget] join_at`` / ``kill_at``: start a joining sensor's processes
        ``JOIN_LEAD_S`` before its join time (its sensor publishes only the scans from then on);
        SIGKILL a leaving sensor's processes at their time (a crash: nothing is said to the
        centre, and the launcher does not restart them)."""
        if self._epoch is None:
            return
        speed = self.settings.deployment.speed
        now = time.time()
        for sp in self.plan:
            if sp.join_at_s is not None and sp.proc is None and now >= self._epoch + sp.join_at_s / speed - JOIN_LEAD_S:
                self._start(sp)
                self.report.events.append(("started", sp.name, now))
                if not self.quiet:
                    self._say(f"{sp.name} started (joins at t = {sp.join_at_s:g} s)")
            if (sp.kill_at_s is not None and not sp.killed and sp.proc is not None
                    and now >= self._epoch + sp.kill_at_s / speed):
                sp.proc.kill()
                sp.killed = True
                self.report.events.append(("killed", sp.name, now))
                if not self.quiet:
                    self._say(f"{sp.name} killed (SIGKILL at t = {sp.kill_at_s:g} s)")

    def _say(self, text: str) -> None:
        sys.stderr.write(f"\n{self.title}: {text}\n")
        sys.stderr.flush()

    def stop_all(self) -> None:
        """SIGTERM every child still running, stage by stage, SIGKILL after a grace period.

        Stages: sensors and local filters, then the fusion centres (whose last output, such as
        a multi-target centre's final pictures, still reaches the recorder), then the picture
        merger of region centres, then the recorder, then the routers: their final Health (counters after the last line was
        written) still reaches the monitor, so the report's counters are final. A router joined to
        other hosts' routers (``router_connect``) goes ``ROUTER_DRAIN_S`` after the rest: measured in
        deploy/netns-regions.sh, a region centre's final pictures were lost when its host's router
        stopped at once.
        """
        self._sample_usage()
        with self._lock:
            self.watch.stopping = True
        running = [sp for sp in reversed(self.plan) if sp.proc is not None and sp.proc.poll() is None]
        starting = self._starting(running)
        stages = [[sp for sp in running if STOP_STAGE.get(sp.role, 0) == k] for k in range(max(STOP_STAGE.values()) + 1)]
        for group in stages:
            if self.settings.deployment.router_connect and any(sp.role == "router" for sp in group):
                time.sleep(ROUTER_DRAIN_S)  # what the services sent last is still on its way to the other routers
            for sp in group:
                sp.proc.send_signal(signal.SIGTERM)
            deadline = time.monotonic() + (RECORDER_GRACE_S if any(sp.role == "recorder" for sp in group)
                                           else STOP_GRACE_S)
            for sp in group:
                try:
                    sp.proc.wait(timeout=max(deadline - time.monotonic(), 0.05))
                except subprocess.TimeoutExpired:
                    sp.proc.kill()
                    sp.proc.wait(timeout=5)
        for sp in self.plan:
            if sp.proc is not None:
                self.report.exit_codes[sp.name] = sp.proc.returncode
                if sp.name in starting and sp.proc.returncode == -signal.SIGTERM:
                    self.report.events.append(("stopped starting", sp.name, time.time()))

    def _starting(self, running: list[ServiceProcess]) -> set[str]:
        """The restarted services of ``running`` not up yet (no liveliness token): the SIGTERM of the stop
        may come before such a one handles it, and its exit by the signal is no failure. A local filter
        SIGKILLed at scan 35 of a lockstep ``deploy/local.toml`` run was restarted 0.5 s later and still
        importing when the last scan went out: the launch ended in exit 1, 'local-filter/2 failed'."""
        restarted = [sp for sp in running if sp.name in self.report.restarts]
        if not restarted or self._session is None:
            return set()
        missing = wait_alive(self._session, [self.keys.alive(sp.role, sp.id) for sp in restarted], timeout_s=0.2)
        return {sp.name for sp in restarted if self.keys.alive(sp.role, sp.id) in missing}

    # ------------------------------------------------------------ zenoh monitoring
    def _open_monitor(self) -> None:
        opts = SessionOptions(mode="client", connect=self.settings.deployment.connect_endpoints,
                              connect_timeout_s=self.settings.deployment.ready_timeout_s,
                              config_file=self.zenoh_config)
        try:
            self._session = open_session(opts)
        except SessionError as exc:  # a host without a router, whose router is not up (was a traceback)
            raise LaunchError(f"no router reached within ready_timeout_s = {opts.connect_timeout_s:g} s: "
                              f"{exc}") from None
        self._subs = [
            self._session.declare_subscriber(self.keys.fusion_track(), self._on_track),
            self._session.declare_subscriber(self.keys.sensor_meas(), self._on_meas),
            self._session.declare_subscriber(self.keys.health(), self._on_health),
            self._session.declare_subscriber(self.keys.mtt_picture(), self._on_picture),
            self._session.liveliness().declare_subscriber(self.keys.primary(), self._on_primary_token),
            self._session.liveliness().declare_subscriber(self.keys.alive("router"), self._on_router_token,
                                                          history=True),
            self._session.declare_subscriber(self.keys.region_picture(), self._on_region_picture),
        ]

    def _monitored(self, sample: zenoh.Sample, msg_type: type[M], key_of: Callable[[M], str] | None = None) -> M | None:
        """The message of ``sample`` decoded as ``msg_type`` or None when it is rejected: malformed, or
        (``key_of``) published on another key than the one its payload names as its sender's (a Health's
        role and id, a measurement's sensor). The access control admits an identity on its own keys
        only, not its payloads: before 2026-11-27 sensor 1's identity could publish the fusion centre's
        Health, with its counters, on ``health/sensor/1``, and the summary showed them. Counted in
        ``LaunchReport.monitor_rejected`` (in the summary's rejected total), the first one logged."""
        key = str(sample.key_expr)
        try:
            msg = decode(sample.payload.to_bytes(), msg_type)
        except WireError as exc:
            return self._monitor_rejects(key, str(exc))
        if key_of is not None and key_of(msg) != key:
            return self._monitor_rejects(key, f"sender: its payload is of {key_of(msg)}")
        return msg

    def _monitor_rejects(self, key: str, reason: str) -> None:
        with self._lock:
            self.report.monitor_rejected += 1
            first = self.report.monitor_rejected == 1
        if first:
            self._say(f"rejected a message on {clip(key)}: {clip(reason)} (every one is counted in summary.json's "
                      "monitor_rejected)")

    def _on_track(self, sample: zenoh.Sample) -> None:
        now = time.time_ns()
        track = self._monitored(sample, FusedTrack)
        if track is None:
            return
        with self._lock:
            self.report.scans_fused += 1
            self.report.latencies_ms.append((now - track.stamp_ns) / 1e6)
            self.report.track_arrivals_ns[track.seq] = now
            self._newest_track = max(self._newest_track, track.seq)
            if self.max_scans is not None and self.report.scans_fused >= self.max_scans:
                self._enough.set()

    def _on_picture(self, sample: zenoh.Sample) -> None:
        now = time.time_ns()
        pic = self._monitored(sample, TrackPicture)
        if pic is None:
            return
        if pic.closing or pic.part != pic.parts - 1:  # a picture in parts arrived with its last (docs/wire.md)
            return
        with self._lock:
            self.report.pictures += 1
            self.report.picture_arrivals.append((pic.t, now))
            self.watch.covered("all", self._watch_ns())

    def _watch_ns(self) -> int:
        """The failover watch's clock: the wall clock as it read at the launcher's start, advanced by the
        monotonic clock, so that a step of the host's clock moves no failover or outage figure (stepped
        back 30 s before a frozen primary's take-over, its region's pictures seemed silent for -25 s and
        the take-over was no failover, before 2026-11-27)."""
        return self._wall0_ns + time.monotonic_ns() - self._mono0_ns

    def _on_region_picture(self, sample: zenoh.Sample) -> None:
        """A region centre's picture (``region/<rid>/picture``): covers its region after a failover."""
        with self._lock:
            self.watch.covered(str(sample.key_expr).split("/")[-2], self._watch_ns())

    def _on_primary_token(self, sample: zenoh.Sample) -> None:
        """A centre's primary token went or was claimed (:meth:`FailoverWatch.primary_token`)."""
        now, (scope, instance) = self._watch_ns(), str(sample.key_expr).rsplit("/", 2)[-2:]
        with self._lock:
            line = self.watch.primary_token(scope, instance, sample.kind == zenoh.SampleKind.DELETE, now)
        if line:
            self._say(line)

    def _on_router_token(self, sample: zenoh.Sample) -> None:
        """A router token went or came (:meth:`FailoverWatch.router_token`)."""
        now, name = self._watch_ns(), str(sample.key_expr).rsplit("/", 1)[-1]
        with self._lock:
            line = self.watch.router_token(name, sample.kind == zenoh.SampleKind.DELETE, now)
        if line:
            self._say(line)

    def _on_meas(self, sample: zenoh.Sample) -> None:
        m = self._monitored(sample, Measurement, lambda m: self.keys.sensor_meas(m.sensor))
        if m is None:
            return
        if m.part != m.parts - 1:  # a scan in parts counts once, with its last part
            return
        with self._lock:
            self.report.measurements[m.sensor] = self.report.measurements.get(m.sensor, 0) + 1
            arrivals, now = self._arrivals.setdefault(m.sensor, collections.deque()), time.monotonic()
            arrivals.append(now)
            while arrivals[0] < now - RATE_WINDOW_S:  # held for the rates only (quiet: never shown)
                arrivals.popleft()
            if m.kind == "scan":
                mt = self.settings.multitarget
                self.report.note_scan(m.t, m.stamp_ns, self.settings.mtt.period, self.settings.mtt.picture_delay,
                                      mt.duration if mt is not None else 0.0)
            elif m.seq <= self._newest_track + self.settings.deployment.max_seq_jump:
                self.report.publish_stamps_ns.setdefault(m.seq, {}).setdefault(m.sensor, m.stamp_ns)

    def _on_health(self, sample: zenoh.Sample) -> None:
        h = self._monitored(sample, Health, lambda h: self.keys.health(h.role, h.id))
        if h is None:
            return
        with self._lock:
            self.report.health[f"{h.role}/{h.id}"] = dict(h.counters)

    def _status_line(self, start: float) -> str:
        with self._lock:
            now = time.monotonic()
            window = min(max(now - start, 1e-9), RATE_WINDOW_S)
            for times in self._arrivals.values():
                while times and times[0] < now - window:
                    times.popleft()
            rates = " ".join(f"{s}:{len(self._arrivals[s]) / window:.1f}/s" for s in sorted(self._arrivals))
            lat = self.report.latencies_ms[-50:]
            last = f"{np.median(lat):.1f} ms" if lat else "-"
            if self.settings.multitarget is not None:
                return f"pictures {self.report.pictures}  sensors {rates or '-'}"
            return f"scans fused {self.report.scans_fused}  sensors {rates or '-'}  latency(p50 last 50) {last}"

    # ------------------------------------------------------------ run
    def request_stop(self) -> None:
        self._stop.set()

    def run(self) -> LaunchReport:
        """Start, wait for the sensors to finish (or a stop request), stop everything."""
        start = time.monotonic()
        dep = self.settings.deployment
        sensors = [sp for sp in self.plan if sp.role == "sensor"]
        others = [sp for sp in self.plan if sp.role not in ("sensor", "router") and sp.join_at_s is None
                  and not sp.standby]
        standbys = [sp for sp in self.plan if sp.standby]  # once their primaries hold the tokens
        routers = [sp for sp in self.plan if sp.role == "router"]
        stopped = False
        for sp in self.plan:  # a snapshot left by an earlier run must not be resumed from
            if "--snapshot" in sp.argv:
                Path(sp.argv[sp.argv.index("--snapshot") + 1]).unlink(missing_ok=True)
            if "--db" in sp.argv:  # nor an earlier run's recording appended to
                kept = set_aside_recording(Path(sp.argv[sp.argv.index("--db") + 1]))
                if kept is not None and not self.quiet:
                    print(f"{self.title}: an earlier run's recording moved to {kept}", file=sys.stderr)
        try:
            for sp in routers:
                self._start(sp)
            self._wait_listening(routers, dep.ready_timeout_s)
            self._open_monitor()
            for sp in others:
                self._start(sp)
            self._wait_ready(routers + others, dep.ready_timeout_s)
            for sp in standbys:
                self._start(sp)
            self._wait_ready(standbys, dep.ready_timeout_s)
            first = [sp for sp in sensors if sp.join_at_s is None]
            start_file = await_start(first) if dep.pacing == "realtime" else None
            for sp in first:
                self._start(sp)
            if dep.pacing == "realtime":
                self._wait_ready(first, dep.ready_timeout_s)
                self._epoch = release_sensors(sensors, start_file, time.time() + START_MARGIN_S)
            self._watch(sensors, start)
        except KeyboardInterrupt:
            stopped = True
        finally:
            self.stop_all()
            self._export_recording()
            for sub in self._subs:
                sub.undeclare()
            if self._session is not None:
                close_session(self._session)
            self.report.wall_s = time.monotonic() - start
            self.report.failovers = [f.summary(self._epoch, dep.speed, self._scan_s()) for f in self.watch.failovers]
            self.report.router_outages = [o.summary(self._epoch, dep.speed) for o in self.watch.outages]
        if stopped:
            raise Stopped(self.report)
        failed = {n: c for n, c in self.report.exit_codes.items() if c not in (0, None) and n not in self.report.killed}
        if failed and not self._stop.is_set():
            name = next(iter(failed))
            sp = next(p for p in self.plan if p.name == name)
            raise ServiceFailed(self.report, f"{', '.join(failed)} failed; {name} exited with code "
                                f"{failed[name]}:\n{sp.log_tail()}")
        return self.report

    def _export_recording(self) -> None:
        """Write ``measurements.jsonl`` and ``tracks.jsonl`` beside the recording of this host's
        recorder, once every service has stopped (``fedtrack export``'s files), unless the recorder
        was planned to write them itself (``--out``): the export takes as long as the data needs
        (3 s for 2 minutes of 1,000 targets and 4 sensors), with no stop grace to outlast, and is
        written even when the recorder was killed (every row it stored is committed)."""
        for sp in self.plan:
            if sp.role != "recorder" or "--out" in sp.argv:
                continue
            db = Path(sp.argv[sp.argv.index("--db") + 1])
            if not db.is_file():  # removed while the run went on (it was set aside before the start)
                self._say(f"no recording to export: {db} is gone")
                continue
            started = time.monotonic()
            try:
                recording = Recording(db, readonly=True)
                try:
                    n_meas, n_tracks = recording.export(db.parent / "measurements.jsonl", db.parent / "tracks.jsonl")
                finally:
                    recording.close()
            except InputError as exc:
                self._say(f"could not export the recording: {exc}")
                continue
            if not self.quiet:
                self._say(f"exported {n_meas} measurement lines and {n_tracks} track lines from {db} "
                          f"in {time.monotonic() - started:.1f} s")

    def _scan_s(self) -> float:
        """The slowest sensor's period (scenario seconds): a failover's unit of time."""
        mt = self.settings.multitarget
        return 1.0 if mt is None else max(s.period for s in sensor_specs(mt))

    def _wait_listening(self, routers: list[ServiceProcess], timeout_s: float) -> None:
        """Until the router listens on its port; a router that exits first fails the launch at once."""
        endpoint = self.settings.deployment.router_listen
        if not routers or not endpoint.startswith(("tcp/", "tls/")):
            return
        deadline = time.monotonic() + timeout_s
        while not port_in_use(endpoint):
            for sp in routers:
                if sp.proc is not None and sp.proc.poll() is not None:
                    last = sp.log_tail(1).strip()
                    raise LaunchError(f"router exited with code {sp.proc.returncode} before listening on "
                                      f"{endpoint}: {last}")
            if time.monotonic() > deadline:
                raise LaunchError(f"router not listening on {endpoint} after {timeout_s:g} s")
            time.sleep(0.05)

    def _wait_ready(self, group: list[ServiceProcess], timeout_s: float) -> None:
        assert self._session is not None
        want = [self.keys.alive(sp.role, sp.id) for sp in group]
        deadline = time.monotonic() + timeout_s
        while True:
            self._check_alive(group, starting=True)
            if self._stop.is_set():
                raise KeyboardInterrupt
            missing = sorted(wait_alive(self._session, want, timeout_s=0.2))
            if not missing:
                return
            if time.monotonic() > deadline:
                raise LaunchError(f"not ready after {timeout_s:g} s: {', '.join(missing)}")

    def _watch(self, sensors: list[ServiceProcess], start: float) -> None:
        tty = sys.stderr.isatty()
        last_print = last_sample = 0.0
        while not self._stop.is_set():
            self._follow_schedule()
            self._check_alive(self.plan)
            if time.monotonic() - last_sample >= USAGE_SAMPLE_S:
                self._sample_usage()
                last_sample = time.monotonic()
            if sensors and all(self._finished(sp) for sp in sensors) or self._enough.is_set():
                break
            if not sensors and all(self._finished(sp) for sp in self.plan):
                break
            now = time.monotonic()
            if not self.quiet and now - last_print >= (0.2 if tty else 2.0):
                sys.stderr.write(("\r" if tty else "") + self._status_line(start) + ("" if tty else "\n"))
                sys.stderr.flush()
                last_print = now
            time.sleep(0.05)
        if not self.quiet:
            sys.stderr.write(("\r" if tty else "") + self._status_line(start) + "\n")
        if self._stop.is_set():
            raise KeyboardInterrupt


def install_stop_handlers(launcher: Launcher) -> None:
    """Ctrl-C and SIGTERM ask the launcher to stop everything cleanly."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: launcher.request_stop())


def run_deployment(settings: Settings, config_path: Path, out_dir: Path, quiet: bool = False,
                   title: str = "fedtrack launch") -> LaunchReport:
    """Launch the services of ``settings`` on this host and wait for the scenario to end."""
    launcher = prepare_launcher(settings, config_path, out_dir, quiet, title)
    install_stop_handlers(launcher)
    return launcher.run()


def prepare_launcher(settings: Settings, config_path: Path, out_dir: Path, quiet: bool = False,
                     title: str = "fedtrack launch") -> Launcher:
    """What :func:`run_deployment` does before it runs: the checks (port, multi-target scenario), the
    plan and the Zenoh configurations; the launcher is ready to ``run()`` (from any thread)."""
    dep = settings.deployment
    if "router" in dep.services and dep.router_listen and port_in_use(dep.router_listen):
        raise ConfigError(f"{config_path}: deployment.router_listen: port {listen_address(dep.router_listen, '')[1]} "
                          f"for the router is already in use ({dep.router_listen})")
    if settings.multitarget is not None:
        settings = check_multitarget(settings, config_path)
        prepare(settings, out_dir)
        if config_path.resolve() != (out_dir / "config.toml").resolve():  # ``demo`` writes it there itself
            shutil.copyfile(config_path, out_dir / "config.toml")  # what ``replay --config OUT/config.toml`` reads
    plan = service_plan(settings, config_path, out_dir, out_dir / "logs", recorder_exports=False)
    monitor_config = apply_zenoh_settings(settings, config_path, out_dir, plan)
    return Launcher(settings, plan, quiet=quiet, zenoh_config=monitor_config, title=title,
                    scopes=failover_scopes(settings, config_path))


def failover_scopes(settings: Settings, config_path: Path) -> frozenset[str]:
    """The scopes of a deployment's multi-target centres (their primary tokens' second-last chunk):
    each region of ``[regions]``, or ``all`` for the one centre; none without ``[multitarget]``, and none
    without its ``standby = true``: a centre's token going is then its end, no failover (host A of
    deploy/multihost-regions/, run in its documented order, reported host C's centre stopping as
    'failover of x1y0 ... took over after - s')."""
    if settings.multitarget is None or not settings.multitarget.standby:
        return frozenset()
    regions = load_regions(config_path)
    return frozenset(regions.ids) if regions is not None else frozenset({"all"})


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="fedtrack launch", description=__doc__.splitlines()[0])
    parser.add_argument("config", type=Path, help="deployment TOML (see deploy/)")
    parser.add_argument("--out", type=Path, help="recorder output and logs (default: deployment.out)")
    args = parser.parse_args(argv)
    settings = load_settings(args.config)
    check_launchable(settings, args.config)
    # --out follows every command's output rule; [deployment] out (fedtrack-out/<name>) is made as it is
    made = not (args.out or Path(settings.deployment.out)).exists()  # by this run, if refused below
    out = output_folder(args.out) if args.out else Path(settings.deployment.out)
    try:
        launcher = prepare_launcher(settings, args.config.resolve(), out)
    except ConfigError:  # refused before any service started: nothing of this run is left behind
        if made:
            shutil.rmtree(out, ignore_errors=True)
        raise
    install_stop_handlers(launcher)
    code = None
    try:
        report = launcher.run()
    except Stopped as exc:
        report, code = exc.report, 130
        print("fedtrack launch: stopped; every service was shut down", file=sys.stderr)
    except ServiceFailed as exc:
        report = exc.report
        print(f"fedtrack launch: {exc}", file=sys.stderr)
    except LaunchError as exc:
        print(f"fedtrack launch: {exc}", file=sys.stderr)
        return 1
    try:
        if settings.multitarget is not None:
            finish_multitarget(out, report, "fedtrack launch", settings)
        else:
            finish(out, settings, report, args.config.resolve(), "fedtrack launch")
    except InputError as exc:  # the disk full at the end: before 2026-11-27 exit 2 naming the copy's source
        print(f"fedtrack launch: the run's summary not written: {exc}", file=sys.stderr)
        return 1
    if code is not None:
        return code
    return 1 if report.failed or any(c not in (0, None) and n not in report.killed for n, c in report.exit_codes.items()) else 0
