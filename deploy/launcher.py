"""fedtrack launch CONFIG.toml: start every service of a deployment as separate processes.

Order: router -> local filters, fusion center, recorder -> (all announced by liveliness)
-> sensors -> (all announced) -> their common start time (:func:`release_sensors`), with realtime
pacing given ``START_MARGIN_S`` ahead, with lockstep pacing now (scan 0 then, the next scans as the
fused tracks come). While it runs it shows scans fused, per-sensor scan rates and the latency
from a sensor's publish to the fused track's arrival. It ends when the sensors have
published their last scan (then it stops the services, and before this host's recorder waits for the
recording to hold what was seen live: :meth:`Launcher._await_recording`), or on Ctrl-C / SIGTERM (stops
everything, no orphans: every child also gets SIGTERM if the launcher dies). Exit code
0 when every service ended cleanly, 1 naming the service that failed. A service that the stop's
grace SIGKILLs after its final Health said ``stopped`` (its interpreter's exit outlived the grace)
ended cleanly: it is listed as killed after a clean stop (:meth:`Launcher._note_exit`). Once
everything has stopped, it writes ``measurements.jsonl`` and ``tracks.jsonl`` from this host's recording
(:meth:`Launcher._export_recording`).

Supervision: a service that exits with a non-zero code (or a signal) after start-up, or a
centre of a standby pair that exits 0 mid-run (:meth:`Launcher._paired`), is restarted after a
backoff (``RESTART_BACKOFF_S``, doubling up to ``RESTART_BACKOFF_MAX_S``),
the reason logged, at most ``MAX_RESTARTS`` times per service. Beyond that, an essential
service (router, fusion center, recorder) stops the deployment cleanly (exit 1); a
sensor or local filter is left out and the rest goes on degraded (exit 1 at the end).

Failover (``[multitarget] standby = true``): every multi-target centre gets a hot standby
(``<id>-standby``, ``serve mtt-centre --standby``), started once the primaries are ready. When a
primary dies its standby takes over (:mod:`fedtrack.fusion_center.mtt.failover.standby`) and the launcher
restarts the dead process as the new standby; the report lists each failover (the centre's
scope, when its primary token went, how long until the standby held it and until the scope's
next picture arrived, in seconds and in scans of the slowest sensor).

The plan of processes and their arguments is :mod:`fedtrack.deploy.plan`'s, the Zenoh session that
watches the deployment :mod:`fedtrack.deploy.monitor`'s; this module starts, supervises and stops.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from fedtrack.config import ConfigError
from fedtrack.deploy.monitor import FINAL_STATUSES, LaunchError, Monitor
from fedtrack.deploy.multitarget import (
    check_multitarget,
    derived_config,
    finish_multitarget,
    prepare,
    sensor_specs,
)
from fedtrack.deploy.plan import (
    ServiceProcess,
    apply_zenoh_settings,
    await_start,
    failover_scopes,
    release_sensors,
    service_plan,
)
from fedtrack.deploy.procstat import process_usage
from fedtrack.deploy.report import CLEAN_STOP_KILLED, LaunchReport, finish, unrecorded
from fedtrack.deploy.settings import Settings, check_launchable, load_settings
from fedtrack.deployment import listen_problem, port_in_use
from fedtrack.jsonl import InputError, output_folder
from fedtrack.recording import Recording
from fedtrack.services.base import CLOSE_DEADLINE_S
from fedtrack.services.recorder import Recorder
from fedtrack.wire import FusedTrack
from fedtrack.zsession import close_session, wait_alive

STOP_GRACE_S = 5.0
# the recorder commits what it still holds (a row an fsync, for at most its drain deadline), then says its
# final Health and closes its session: its stage's grace outlasts both
RECORDER_GRACE_S = Recorder.drain_deadline_s + CLOSE_DEADLINE_S + 3.0
PR_SET_PDEATHSIG = 1
ESSENTIAL_ROLES = ("router", "fusion-center", "recorder")
MAX_RESTARTS = 3
RESTART_BACKOFF_S = 0.5
RESTART_BACKOFF_MAX_S = 4.0
# realtime: the start is this long after the last sensor was ready: 25 of the sensors' 10 ms polls of START_FILE
START_MARGIN_S = 0.25
# before it stops its recorder, the launcher waits for this host's recording to hold what it saw live (fused
# tracks; pictures and scans) while that grows; it gives up after this long without one more: far beyond a
# row's commit (an fsync: 3 ms here, 60 ms slowed on purpose), so only a recorder that stopped storing is given up on
RECORDER_STALL_S = 5.0
ROUTER_DRAIN_S = 0.5  # a router joined to other hosts' routers is stopped this long after the rest (in-flight data)
# the routers wait at most this long for the final Health of the services stopped before them (stop_all); a
# client's TCP queue to a reader drains in milliseconds, and a flood keeps it behind for about a second
FINAL_HEALTH_WAIT_S = 2.0


def describe_exit(code: int) -> str:
    """``exit code 3`` or ``signal SIGKILL``."""
    if code < 0:
        try:
            return f"signal {signal.Signals(-code).name}"
        except ValueError:
            return f"signal {-code}"
    return f"exit code {code}"

USAGE_SAMPLE_S = 0.5  # how often the launcher samples its services' peak RSS and CPU time
STOP_STAGE = {"fusion-center": 1, "mtt-centre": 1, "picture": 2, "recorder": 3, "router": 4}  # others 0


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



class Launcher(Monitor):
    """Runs a plan of service processes and watches the deployment over Zenoh (:class:`Monitor`)."""

    def __init__(self, settings: Settings, plan: list[ServiceProcess], quiet: bool = False,
                 max_scans: int | None = None, zenoh_config: str | None = None, title: str = "fedtrack launch",
                 scopes: frozenset[str] = frozenset()) -> None:
        super().__init__(settings, max_scans, zenoh_config, title, scopes)
        self.plan = plan
        self.quiet = quiet
        self._stop = threading.Event()
        self._restart_at: dict[str, float] = {}  # service -> monotonic time of its pending restart
        self._epoch: float | None = None  # wall-clock time of the sensors' scenario time 0

    # ------------------------------------------------------------ processes
    def _start(self, sp: ServiceProcess) -> None:
        with self._lock:  # a status said by the process before this one (a restart) says nothing of this one
            self.report.statuses.pop(sp.name, None)
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
            if (sp.proc is None or sp.proc.poll() is None or sp.name in self.report.failed or sp.killed
                    or sp.proc.returncode == 0 and (starting or self._stop.is_set() or not self._paired(sp))):
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

    def _paired(self, sp: ServiceProcess) -> bool:
        """Whether ``sp`` is a multi-target centre with a twin (``[multitarget] standby``). Such a centre
        that exits 0 mid-run is restarted too: a centre exits 0 only when stopped (SIGTERM, SIGINT), and the
        launcher stops it only after the sensors' end or on its own stop (not restarted then), so an operator
        stopped it, and its twin took over; restarted as the standby, the pair is whole again (a rolling
        restart). Before, it stayed stopped and its scope ran on without a standby."""
        mt = self.settings.multitarget
        return sp.role == "mtt-centre" and mt is not None and mt.standby

    def _as_standby(self, sp: ServiceProcess) -> None:
        """A centre with standbys restarts as a standby: its twin took over (or will) when it died."""
        if self._paired(sp) and not sp.standby:
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
        """``[multitarget] kill_at``: SIGKILL a leaving sensor's processes at their time (a crash:
        nothing is said to the centre, and the launcher does not restart them). A joining sensor's
        processes start with the others (ready before the common start); its sensor publishes only
        its scans from ``join_at`` on."""
        if self._epoch is None:
            return
        speed = self.settings.deployment.speed
        now = time.time()
        for sp in self.plan:
            if (sp.kill_at_s is not None and not sp.killed and sp.proc is not None
                    and now >= self._epoch + sp.kill_at_s / speed):
                sp.proc.kill()
                sp.killed = True
                self.report.events.append(("killed", sp.name, now))
                if not self.quiet:
                    self._say(f"{sp.name} killed (SIGKILL at t = {sp.kill_at_s:g} s)")

    def stop_all(self, settle: bool = False) -> None:
        """SIGTERM every child still running, stage by stage, SIGKILL after a grace period; ``settle`` (the
        run came to its end): before the recorder's stage, wait for its recording (:meth:`_await_recording`).

        Stages: sensors and local filters, then the fusion centres (whose last output, such as
        a multi-target centre's final pictures, still reaches the recorder), then the picture
        merger of region centres, then the recorder, then the routers (once the monitor has the final Health of each
        service stopped before them, at most FINAL_HEALTH_WAIT_S: :meth:`_await_final_health`): their final Health
        (counters after the last line was
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
            if settle and any(sp.role == "recorder" for sp in group):
                self._await_recording()  # what the services stopped before published last included
            if any(sp.role == "router" for sp in group):
                self._await_final_health([sp for sp in running if sp.role != "router"])
                if self.settings.deployment.router_connect:
                    time.sleep(ROUTER_DRAIN_S)  # what the services sent last is on its way to the other routers
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
                self._note_exit(sp, starting)

    def _await_final_health(self, stopped: list[ServiceProcess]) -> None:
        """Before the routers stop: wait, at most FINAL_HEALTH_WAIT_S, until the monitor has the final Health of each
        of ``stopped`` that exited 0 (said before its session closed, still in a router's queue behind a flood: a
        hostile run's sensor said ``stopped`` and exited 0, and the router stopped before its final Health reached
        the readers, ``tests/test_live_hostile.py`` at a load of 5)."""
        deadline = time.monotonic() + FINAL_HEALTH_WAIT_S
        names = {sp.name for sp in stopped if sp.proc is not None and sp.proc.returncode == 0}
        while time.monotonic() < deadline:
            with self._lock:
                if all(self.report.statuses.get(name) in FINAL_STATUSES for name in names):
                    return
            time.sleep(0.02)

    def _note_exit(self, sp: ServiceProcess, starting: set[str]) -> None:
        """Record ``sp``'s exit code once the stop is over, and whether its signal is no failure: a restart
        still starting met by the SIGTERM, or an exit ended by a signal (the grace's SIGKILL) after the
        process's final Health said ``stopped``. By then its work was done (``on_stop``, the final
        counters, the session closed); the signal cut short only the interpreter's exit. A process killed
        that never said so stays a failure."""
        assert sp.proc is not None
        code = sp.proc.returncode
        self.report.exit_codes[sp.name] = code
        if code is None or code >= 0:
            return
        if sp.name in starting and code == -signal.SIGTERM:
            self.report.events.append(("stopped starting", sp.name, time.time()))
            return
        with self._lock:
            said = self.report.statuses.get(sp.name)
        if said == "stopped":
            self.report.events.append((CLEAN_STOP_KILLED, sp.name, time.time()))
            if not self.quiet:
                self._say(f"{sp.name} ended by {describe_exit(code)} in its exit, after its final Health said "
                          "stopped: not a failure")

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
    # ------------------------------------------------------------ run
    def request_stop(self) -> None:
        self._stop.set()

    def run(self) -> LaunchReport:
        """Start, wait for the sensors to finish (or a stop request), stop everything."""
        start = time.monotonic()
        dep = self.settings.deployment
        sensors = [sp for sp in self.plan if sp.role == "sensor"]
        others = [sp for sp in self.plan if sp.role not in ("sensor", "router") and not sp.standby]
        standbys = [sp for sp in self.plan if sp.standby]  # once their primaries hold the tokens
        routers = [sp for sp in self.plan if sp.role == "router"]
        stopped = settle = False
        for sp in self.plan:  # a snapshot or numbers file left by an earlier run must not be resumed from
            for flag in ("--snapshot", "--numbers"):
                if flag in sp.argv:
                    Path(sp.argv[sp.argv.index(flag) + 1]).unlink(missing_ok=True)
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
            # a joining sensor's too: started mid-run, 2 s before its join time, it and its tracker were
            # ready 5.4 / 7.8 s after the start at load 14 (join at 2.5 s) and none of its scans reached its tracker
            start_file = await_start(sensors)
            for sp in sensors:
                self._start(sp)
            self._wait_ready(sensors, dep.ready_timeout_s)
            if dep.pacing == "realtime":
                self._epoch = release_sensors(sensors, start_file, time.time() + START_MARGIN_S)
            else:  # lockstep follows the fused tracks, not the clock: scan 0 once every sensor has read the start
                release_sensors(sensors, start_file, time.time())
            self._watch(sensors, start)
            settle = True
        except KeyboardInterrupt:
            stopped = True
        finally:
            try:
                self.stop_all(settle)
                stopped = stopped or self._stop.is_set()  # Ctrl-C while the recorder was waited for
                self._export_recording()
            finally:  # also when saying so fails (a closed pipe): each subscriber's callback thread outlives it
                for sub in self._subs:  # and held the process at its exit, for good (tour57)
                    sub.undeclare()
                if self._session is not None:
                    close_session(self._session)
            self.report.wall_s = time.monotonic() - start
            self.report.failovers = [f.summary(self._epoch, dep.speed, self._scan_s()) for f in self.watch.failovers]
            self.report.router_outages = [o.summary(self._epoch, dep.speed) for o in self.watch.outages]
            self.report.primary_tokens_ignored = self.watch.tokens_ignored
        if stopped:
            self.report.stopped = True
            raise Stopped(self.report)
        failed = self.report.failed_exits()
        if failed and not self._stop.is_set():
            name = next(iter(failed))
            sp = next(p for p in self.plan if p.name == name)
            raise ServiceFailed(self.report, f"{', '.join(failed)} failed; {name} exited with code "
                                f"{failed[name]}:\n{sp.log_tail()}")
        return self.report

    def _await_recording(self) -> None:
        """Before this host's recorder is stopped: while its recording holds less of what the launcher saw
        live (:meth:`_recording_holds`) and that still grows, wait; given up after ``RECORDER_STALL_S``
        without growth, or on Ctrl-C. What was seen is taken once, when the wait starts (the services before
        the recorder stopped): a sender still publishing (a compromised sensor's new scan and a repeat of
        an old number every 0.1 s, each counted seen, one recorded) kept the count seen ahead of a growing
        recording and held the launch for as long as it went on (2026-11-28). The recorder commits a row an
        fsync: with every fsync slowed to 60 ms it had stored 2 of a lockstep run's 101 fused tracks when the
        sensors ended, and its 2 s drain left 9 in tracks.jsonl, exit 0 (2026-11-27; now 101 after 40 s more); a
        multi-target run's, every fsync slowed to 400 ms, kept 11 of the 15 pictures and 37 of the 51 scans seen
        after its 15 s drain, exit 0 (2026-11-28)."""
        recorder = next((sp for sp in self.plan if sp.role == "recorder"), None)
        if recorder is None:
            return
        db = Path(recorder.argv[recorder.argv.index("--db") + 1])
        try:
            recording = Recording(db, readonly=True)
        except InputError:  # not there (the recorder never started) or damaged: the export says so
            return
        what = "fused tracks" if self.settings.multitarget is None else "pictures and scans"
        held, since, said = -1, time.monotonic(), False
        with self._lock:
            live = (len(self.report.track_arrivals_ns), set(self.report.picture_seqs), dict(self.report.measurements))
        try:
            while not self._stop.is_set():
                now_held, seen = self._recording_holds(recording, *live)
                if now_held >= seen:
                    return
                if now_held != held:
                    held, since = now_held, time.monotonic()
                elif time.monotonic() - since > RECORDER_STALL_S:
                    self._say(f"{recorder.name} stored {held} of the {seen} {what} seen, none more in "
                              f"{RECORDER_STALL_S:g} s: stopping it")
                    return
                if not said and not self.quiet:
                    self._say(f"waiting for {recorder.name} to store the {what} seen ({held} of {seen})")
                    said = True
                time.sleep(0.05)
        except InputError as exc:  # a read fault of the recording
            self._say(f"could not read the recording: {exc}")
        finally:
            recording.close()

    def _recording_holds(self, recording: Recording, tracks: int, pictures: set[int],
                         scans: dict[str, int]) -> tuple[int, int]:
        """How much of what the launcher saw live ``recording`` holds, and how much it saw: a paper
        deployment's fused ``tracks``; a multi-target one's ``pictures`` (by number) and each sensor's ``scans``."""
        if self.settings.multitarget is None:
            return min(recording.count(FusedTrack), tracks), tracks
        recorded = recording.scans()
        held = len(pictures & recording.pictures()) + sum(min(n, recorded.get(s, 0)) for s, n in scans.items())
        return held, len(pictures) + sum(scans.values())

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
            if not db.is_file():  # never made (a stop before the recorder stored a row), or removed during the run
                self._say(f"no recording to export: {db} does not exist (the recorder stored nothing, or the file "
                          "was removed during the run)")
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
    services_config = config_path
    problem = listen_problem(dep.router_listen) if "router" in dep.services and dep.router_listen else None
    if problem:
        raise ConfigError(f"{config_path}: deployment.router_listen: {problem}, where the router would listen")
    if settings.multitarget is not None:
        settings = check_multitarget(settings, config_path)
        try:
            prepare(settings, out_dir)
        except InputError as exc:  # a recording missing, unreadable or without aircraft in the window: named as the
            # key it came from, and the output folder this run made removed (before the tour61 session neither)
            key = "multitarget.source" if settings.multitarget and settings.multitarget.source else "multitarget"
            raise ConfigError(f"{config_path}: {key}: {exc}") from None
        if settings.multitarget is not None and settings.multitarget.source:
            settings, services_config, derived = derived_config(settings, config_path, out_dir)
            if derived:  # none for ``demo``'s config, which holds them all
                print(f"scenario: tracker keys derived as simulate traffic derives them (not in {config_path.name}): "
                      f"{', '.join(derived)}", file=sys.stderr)
        elif config_path.resolve() != (out_dir / "config.toml").resolve():  # ``demo`` writes it there itself
            shutil.copyfile(config_path, out_dir / "config.toml")  # what ``replay --config OUT/config.toml`` reads
    # the services read the recorded-traffic launch's derived [mtt] (every other path is the file's own: a tls_dir
    # relative to it)
    plan = service_plan(settings, services_config, out_dir, out_dir / "logs", recorder_exports=False)
    monitor_config = apply_zenoh_settings(settings, config_path, out_dir, plan)
    return Launcher(settings, plan, quiet=quiet, zenoh_config=monitor_config, title=title,
                    scopes=failover_scopes(settings, config_path))


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
            summary = finish_multitarget(out, report, "fedtrack launch", settings)
        else:
            summary = finish(out, settings, report, args.config.resolve(), "fedtrack launch")
    except InputError as exc:  # the disk full at the end: before 2026-11-27 exit 2 naming the copy's source
        print(f"fedtrack launch: the run's summary not written: {exc}", file=sys.stderr)
        return 1
    if code is not None:
        return code
    return 1 if report.failed or report.failed_exits() or unrecorded(summary) else 0
