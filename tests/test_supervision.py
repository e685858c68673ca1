"""The launcher's supervision of its children: restart with backoff, the reason, the limit, the stop."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import pytest
from support import wait_until

from fedtrack.deploy import launcher as launcher_mod
from fedtrack.deploy.launcher import Launcher, LaunchError, describe_exit
from fedtrack.deploy.plan import ServiceProcess
from fedtrack.deploy.settings import MultitargetSettings, Settings


def crashing(role: str, tmp_path: Path) -> ServiceProcess:
    return ServiceProcess(role, "x", [sys.executable, "-c", "import sys; print('up'); sys.exit(3)"],
                          tmp_path / f"{role}.log")


def supervise(launcher: Launcher, sp: ServiceProcess, rounds: int) -> None:
    """Let ``sp`` crash and be restarted ``rounds`` times (backoff patched to 10 ms)."""
    for _ in range(rounds):
        assert wait_until(lambda: sp.proc.poll() is not None, 10.0)
        old = sp.proc
        launcher._check_alive([sp])  # schedules the restart ...
        assert wait_until(lambda: launcher._check_alive([sp]) or sp.proc is not old, 5.0)  # ... and starts it


@pytest.mark.parametrize("role", ["recorder", "sensor"])
def test_restart_with_backoff_then_the_limit(tmp_path: Path, role: str, monkeypatch: pytest.MonkeyPatch,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(launcher_mod, "RESTART_BACKOFF_S", 0.01)
    sp = crashing(role, tmp_path)
    launcher = Launcher(Settings(), [sp], quiet=True)
    launcher._start(sp)
    supervise(launcher, sp, launcher_mod.MAX_RESTARTS)
    assert launcher.report.restarts == {sp.name: 3}
    assert wait_until(lambda: sp.proc.poll() is not None, 10.0)
    assert sp.log_path.read_text().count("up") == 4  # every restart appends to the log
    if role == "recorder":  # essential: the deployment stops, naming it and the limit
        with pytest.raises(LaunchError, match=r"recorder/x exited with exit code 3 after 3 restarts \(limit 3\)"):
            launcher._check_alive([sp])
    else:  # a sensor is left out; the rest goes on
        launcher._check_alive([sp])
        assert launcher.report.failed == [sp.name] and launcher._finished(sp)
    err = capsys.readouterr().err
    assert f"{sp.name} exited with exit code 3; restart 1 of 3 in 0.01 s" in err
    assert describe_exit(-9) == "signal SIGKILL"


@pytest.mark.parametrize("standby", [True, False])
def test_a_centre_of_a_standby_pair_stopped_mid_run_is_restarted_as_the_standby(
        tmp_path: Path, standby: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """A centre exits 0 only when stopped, and the launcher stops it only at the end: one of a standby pair
    that exits 0 mid-run was stopped by an operator (its twin took over) and is restarted as the standby, as a
    killed one is. Without standbys, and on the launcher's own stop, a clean exit stays one. Before, a centre
    of a pair that exited 0 was left stopped and its scope ran on without a standby."""
    monkeypatch.setattr(launcher_mod, "RESTART_BACKOFF_S", 0.01)
    clean = [sys.executable, "-c", "print('up')"]
    centre, sensor = (ServiceProcess(role, "c", clean, tmp_path / f"{role}.log") for role in ("mtt-centre", "sensor"))
    launcher = Launcher(Settings(multitarget=MultitargetSettings(standby=standby)), [centre, sensor], quiet=True)
    for sp in (centre, sensor):
        launcher._start(sp)
    assert wait_until(lambda: centre.proc.poll() == 0 and sensor.proc.poll() == 0, 10.0)
    first = centre.proc
    launcher._check_alive([centre, sensor])  # schedules the centre's restart (a pair) ...
    if standby:
        assert wait_until(lambda: launcher._check_alive([centre, sensor]) or centre.proc is not first, 5.0)
        assert centre.argv == [*clean, "--standby"]  # ... as the standby
    else:
        assert centre.proc is first and centre.argv == clean
    assert launcher.report.restarts == ({centre.name: 1} if standby else {})
    assert wait_until(lambda: centre.proc.poll() == 0, 10.0)
    launcher._stop.set()  # the launcher's own stop (Ctrl-C reaches the children too): no restart
    launcher._check_alive([centre, sensor])
    assert launcher.report.restarts == ({centre.name: 1} if standby else {}) and not launcher._restart_at


def test_a_new_run_sets_an_earlier_runs_recording_aside(tmp_path: Path) -> None:
    """The recorder appends to its database (across its restarts within a run): a run into a folder
    that holds another run's recording starts a fresh one, the earlier one kept as
    ``recording.db.previous`` (one generation), so the exports hold this run's data alone (a
    ``fedtrack demo`` after ``fedtrack demo --scenario multitarget`` in the same folder exported the
    earlier run's pictures and ended in a KeyError)."""
    import numpy as np

    from fedtrack.deploy.launcher import set_aside_recording
    from fedtrack.recording import Recording
    from fedtrack.wire import Measurement, encode

    db = tmp_path / "recording.db"
    assert set_aside_recording(db) is None
    for run in range(2):
        rec = Recording(db)
        msg = Measurement(sensor="p1", seq=run, t=float(run), kind="position", z=np.array([float(run), 0.0]),
                          R=np.eye(2), stamp_ns=1)
        rec.add(msg, encode(msg))
        rec.close()
        kept = set_aside_recording(db)
        assert kept == tmp_path / "recording.db.previous" and not db.exists()
        again = Recording(kept)
        assert [m.t for m in again.messages(Measurement, "t")] == [float(run)]  # that run's alone
        again.close()


def test_realtime_sensors_wait_for_the_start_the_launcher_gives_once_they_are_ready(tmp_path: Path) -> None:
    """``await_start`` points every sensor at one start file (an earlier run's removed); a sensor
    told it publishes nothing until the file holds the start, then scan k at start + k T / speed;
    ``release_sensors`` writes the file whole and gives later starts (restarts, joins) ``--start-at``."""
    from fedtrack.deploy.plan import await_start, release_sensors
    from fedtrack.sensors.service import SensorService
    from fedtrack.zsession import SessionOptions

    logs = tmp_path / "logs"
    logs.mkdir()
    plan = [ServiceProcess("sensor", s, ["serve", "sensor", "--id", s], logs / f"sensor-{s}.log") for s in ("1", "2")]
    (logs / "start-at").write_text("1.0\n")  # an earlier run's start
    path = await_start(plan)
    assert path == logs / "start-at" and not path.exists()
    assert all(sp.argv[-2:] == ["--start-file", str(path)] for sp in plan)
    period, speed = 1.0, 20.0
    sensor = SensorService([{}] * 3, period, "realtime", speed, 5.0, start_file=path, service_id="1",
                           options=SessionOptions())
    sent: list[float] = []

    def publish_scan(now: float) -> None:
        sent.append(time.time())
        sensor.next_seq += 1

    sensor.publish_scan = publish_scan  # type: ignore[method-assign]
    for _ in range(3):
        sensor.on_tick()
    assert sent == [] and sensor.start_at is None
    start = time.time() + 0.05
    assert release_sensors(plan, path, start) == start
    assert float(path.read_text()) == pytest.approx(start, abs=1e-6)
    assert all("--start-file" not in sp.argv and sp.argv[-2:] == ["--start-at", f"{start:.6f}"] for sp in plan)
    assert wait_until(lambda: sensor.on_tick() or len(sent) == 3, 5.0)
    assert sensor.start_at == pytest.approx(start, abs=1e-6)
    assert all(sent[k] >= start + k * period / speed for k in range(3)), [s - start for s in sent]
    path.write_text("soon\n")
    late = SensorService([{}], period, "realtime", speed, 5.0, start_file=path, service_id="2", options=SessionOptions())
    with pytest.raises(ValueError, match="start-at: not a start time in Unix seconds: 'soon"):
        late.on_tick()


def test_a_start_file_that_is_no_short_regular_file_is_refused_unread(tmp_path: Path) -> None:
    """A FIFO or a link to /dev/zero where the launcher's start file goes: a sensor's tick blocked on the
    FIFO for good, or read /dev/zero until a MemoryError; now each is a ValueError (the tick rejected, the
    sensor waiting on), as is a file longer than one time, and non-UTF-8 bytes are no time either."""
    from fedtrack.sensors.service import read_start

    path = tmp_path / "start-at"
    path.symlink_to("/dev/zero")
    with pytest.raises(ValueError, match="start-at: not a regular file, not a start file"):
        read_start(path)
    path.unlink()
    os.mkfifo(path)
    with pytest.raises(ValueError, match="start-at: not a regular file, not a start file"):
        read_start(path)
    path.unlink()
    path.write_bytes(b"\xff1.0")
    with pytest.raises(ValueError, match="not a start time in Unix seconds"):
        read_start(path)
    path.write_text(" " * 100 + "1.0")
    with pytest.raises(ValueError, match="larger than 64 bytes"):
        read_start(path)


def test_a_lockstep_sensor_waits_for_the_start_then_for_each_track(tmp_path: Path) -> None:
    """Lockstep pacing: a sensor told ``--start-file`` sends nothing until the file holds the start
    (the launcher writes it once every sensor is up), then scan 0, then scan k + 1 once the fused
    track of scan k is out. Before 2026-11-27 it sent scan 0 as soon as it was up, ahead of sensors
    still starting (``tests/test_launch_start.py``)."""
    from types import SimpleNamespace

    from fedtrack.sensors.service import SensorService
    from fedtrack.zsession import SessionOptions

    path = tmp_path / "start-at"
    sensor = SensorService([{}] * 3, 1.0, "lockstep", 1.0, 5.0, start_file=path, service_id="1",
                           options=SessionOptions())
    sent: list[int] = []

    def publish_scan(now: float) -> None:
        sent.append(sensor.next_seq)
        sensor.next_seq += 1
        sensor.last_publish = now

    sensor.publish_scan = publish_scan  # type: ignore[method-assign]
    for _ in range(3):
        sensor.on_tick()
    assert sent == []
    path.write_text(f"{time.time():.6f}\n")
    sensor.on_tick()
    sensor.on_tick()
    assert sent == [0]  # scan 1 waits for scan 0's track
    sensor.on_track(SimpleNamespace(seq=0))  # type: ignore[arg-type]
    sensor.on_tick()
    assert sent == [0, 1] and sensor.counters.get("lockstep_timeouts", 0) == 0


def test_a_realtime_sensor_keeps_its_pace_when_the_wall_clock_steps(monkeypatch: pytest.MonkeyPatch) -> None:
    """The common start is a wall-clock time; the scans after it are paced on the monotonic clock. The
    wall clock stepped back by 30 s after scan 2 and then forward by 60 s: scans 3 and 4 go out 1 s
    apart as before (before 2026-11-27 the sensor sent nothing for the 30 s, then at once every scan
    the forward step skipped)."""
    from types import SimpleNamespace

    import fedtrack.sensors.service as module
    from fedtrack.zsession import SessionOptions

    clock = {"wall": 1000.0, "mono": 50.0}
    monkeypatch.setattr(module, "time", SimpleNamespace(time=lambda: clock["wall"], monotonic=lambda: clock["mono"]))
    sensor = module.SensorService([{}] * 40, 1.0, "realtime", 1.0, 5.0, start_at=1000.0, service_id="1",
                                  options=SessionOptions())
    sent: list[float] = []  # the monotonic times of the scans

    def publish_scan(now: float) -> None:
        sent.append(now)
        sensor.next_seq += 1

    sensor.publish_scan = publish_scan  # type: ignore[method-assign]

    def run(seconds: float) -> None:  # the base service's ticks, every 10 ms
        for _ in range(round(seconds / 0.01)):
            sensor.on_tick()
            clock["wall"] += 0.01
            clock["mono"] += 0.01
    run(2.5)
    clock["wall"] -= 30.0
    run(1.0)
    clock["wall"] += 60.0
    run(1.0)
    assert sent == pytest.approx([50.0, 51.0, 52.0, 53.0, 54.0], abs=0.011)


def test_a_sensor_started_by_hand_says_the_start_a_restart_resumes_from(monkeypatch: pytest.MonkeyPatch,
                                                                        caplog: pytest.LogCaptureFixture) -> None:
    """A realtime sensor started by hand (no --start-at, no start file) says its scan 0's time and that a
    restart given it resumes there: restarted without it, it numbered its scans from 0 again, each a scan
    recorded before (tour59: the recorder kept the first and counted the rest, nothing said). Given it, the
    restart 10 s later resumes at scan 10."""
    import logging
    from types import SimpleNamespace

    import fedtrack.sensors.service as module
    from fedtrack.zsession import SessionOptions

    clock = {"wall": 1000.0, "mono": 50.0}
    monkeypatch.setattr(module, "time", SimpleNamespace(time=lambda: clock["wall"], monotonic=lambda: clock["mono"]))
    sensor = module.SensorService([{}] * 40, 1.0, "realtime", 1.0, 5.0, service_id="s1", options=SessionOptions())
    sensor.publish_scan = lambda now: None  # type: ignore[method-assign]
    with caplog.at_level(logging.INFO):
        sensor.on_tick()
        sensor.on_tick()
    said = [r.getMessage() for r in caplog.records if "scan 0 at" in r.getMessage()]
    assert said == ["scan 0 at 1000.000 (Unix s): restarted with --start-at 1000.000, this sensor resumes at the scan "
                    "then due (without it, it numbers its scans from 0 again)"]
    clock["wall"] += 10.0
    again = module.SensorService([{}] * 40, 1.0, "realtime", 1.0, 5.0, start_at=1000.0, service_id="s1",
                                 options=SessionOptions())
    again.count = lambda *args: None  # type: ignore[method-assign]
    again.on_start()
    assert again.next_seq == 10


def test_a_restart_still_starting_when_the_run_ends_is_no_failure(tmp_path: Path) -> None:
    """The stop's SIGTERM meets a restarted service before it is up (it has not declared its liveliness
    token, nor its SIGTERM handler): its exit by the signal is no failure. A local filter SIGKILLed at
    scan 35 of a lockstep ``deploy/local.toml`` run was still starting when the last scan went out, and
    the launch ended in exit 1 ('local-filter/2 failed; ... exited with code -15'). A restarted service
    that is up, and one never restarted, keep the rule: a signal is a failure."""
    from support import free_port

    from fedtrack.zsession import SessionOptions, close_session, open_session

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_session(SessionOptions(mode="router", connect=(), listen=(endpoint,)))
    monitor = open_session(SessionOptions(connect=(endpoint,), connect_timeout_s=5.0))
    sleeper = [sys.executable, "-c", "import time; print('starting', flush=True); time.sleep(60)"]
    starting, never = (ServiceProcess("local-filter", sid, sleeper, tmp_path / f"{sid}.log") for sid in ("2", "3"))
    launcher = Launcher(Settings(), [starting, never], quiet=True)
    launcher._session = monitor
    try:
        for sp in (starting, never):
            launcher._start(sp)
        launcher.report.restarts = {starting.name: 1}
        assert wait_until(lambda: all("starting" in sp.log_path.read_text() for sp in (starting, never)), 10.0)
        launcher.stop_all()
    finally:
        close_session(monitor)
        close_session(router)
    assert launcher.report.exit_codes == {starting.name: -15, never.name: -15}
    assert launcher.report.killed == {starting.name}


# A service of a few lines: a client session, its liveliness token and Health. ``clean`` says ``stopped`` on
# SIGTERM and then hangs in its interpreter's exit (an atexit handler); ``hung`` ignores SIGTERM, never says it.
FAKE_SERVICE = """
import atexit, signal, sys, time
from fedtrack.keys import Keys
from fedtrack.wire import Health, encode
from fedtrack.zsession import SessionOptions, close_session, open_session

sid, deployment, endpoint = sys.argv[1:4]
keys, stop = Keys(deployment), []
session = open_session(SessionOptions(connect=(endpoint,), connect_timeout_s=20.0))
token = session.liveliness().declare_token(keys.alive("local-filter", sid))
signal.signal(signal.SIGTERM, signal.SIG_IGN if sid == "hung" else lambda *_: stop.append(1))

def health(seq, status):
    session.put(keys.health("local-filter", sid), encode(Health("local-filter", sid, seq, {}, status)))

health(1, "ok")
deadline = time.monotonic() + 60
while not stop and time.monotonic() < deadline:
    time.sleep(0.01)
health(2, "stopped")
token.undeclare()
close_session(session)
atexit.register(time.sleep, 60)
"""


def test_a_process_killed_in_its_exit_after_its_final_health_said_stopped_is_no_failure(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The stop's grace SIGKILLs both: ``clean`` after its final Health said ``stopped`` (its interpreter's
    exit outlived the grace, as services' did at load 16-20) is listed as killed after a clean stop and
    is no failure; ``hung``, which never said it, stays one. Before 2026-11-27 both were failures (launch exit 1)."""
    from support import free_port

    from fedtrack.deploy.report import summarize
    from fedtrack.deployment import DeploymentConfig
    from fedtrack.zsession import SessionOptions, close_session, open_session

    monkeypatch.setattr(launcher_mod, "STOP_GRACE_S", 1.0)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    name = f"grace{time.monotonic_ns() % 10**9}"
    router = open_session(SessionOptions(mode="router", connect=(), listen=(endpoint,)))
    settings = Settings(deployment=DeploymentConfig(name=name, router_listen=endpoint, ready_timeout_s=10.0))
    clean, hung = (ServiceProcess("local-filter", sid, [sys.executable, "-c", FAKE_SERVICE, sid, name, endpoint],
                                  tmp_path / f"{sid}.log") for sid in ("clean", "hung"))
    launcher = Launcher(settings, [clean, hung], quiet=True)
    try:
        launcher._open_monitor()
        for sp in (clean, hung):
            launcher._start(sp)
        assert wait_until(lambda: set(launcher.report.health) == {clean.name, hung.name}, 30.0), \
            (clean.log_tail(), hung.log_tail())  # their first Health arrived
        launcher.stop_all()
    finally:
        for sub in launcher._subs:
            sub.undeclare()
        if launcher._session is not None:
            close_session(launcher._session)
        close_session(router)
    report = launcher.report
    assert report.exit_codes == {clean.name: -9, hung.name: -9}, (clean.log_tail(), hung.log_tail())
    assert report.killed == {clean.name}  # before: set(), both failed
    assert report.statuses == {clean.name: "stopped", hung.name: "ok"}
    assert report.killed_after_clean_stop == [clean.name]
    assert report.failed_exits() == {hung.name: -9}  # launch exits 1 for hung, would exit 0 without it
    summary = summarize(tmp_path, settings, report, tmp_path / "config.toml")
    assert summary["killed_after_clean_stop"] == [clean.name] and summary["exit_codes"] == report.exit_codes


def test_a_serve_process_ends_without_the_interpreters_teardown(tmp_path: Path) -> None:
    """``python -m fedtrack.cli serve router`` (the launcher's command line), SIGTERMed once ready, with a
    ``sitecustomize`` on PYTHONPATH whose teardown takes 60 s and whose non-daemon thread ends 0.5 s after
    the ``stopped`` line: the process waits for the thread, runs the exit handlers, skips the teardown and
    exits 0 at once (:func:`fedtrack.cli.run`). Before 2026-11-27 the teardown ran: numpy's, scipy's and
    the rest's took 1-3 s at load average 10-14 after a service logged ``stopped``, beyond the launcher's
    5 s grace under heavier load."""
    import os
    import signal
    import subprocess

    from support import free_port

    (tmp_path / "sitecustomize.py").write_text(
        "import atexit, logging, threading, time\n"
        "stopped = threading.Event()\n"
        "class Watch(logging.Handler):\n"
        "    def emit(self, record):\n"
        "        if record.getMessage().startswith('stopped (exit code'):\n"
        "            stopped.set()\n"
        "logging.getLogger('fedtrack').addHandler(Watch())\n"
        "def late():\n"
        "    stopped.wait(60)\n"
        "    time.sleep(0.5)\n"
        "    print('thread done', flush=True)\n"
        "threading.Thread(target=late).start()\n"
        "atexit.register(print, 'exit handlers ran', flush=True)\n"
        "import slow_teardown\n")
    (tmp_path / "slow_teardown.py").write_text(  # freed in the teardown (sleep bound: the module's globals may be gone)
        "import time\n"
        "class SlowTeardown:\n"
        "    def __del__(self, sleep=time.sleep):\n"
        "        sleep(60)\n"
        "held = SlowTeardown()\n")
    env = dict(os.environ, PYTHONPATH=str(tmp_path))
    log = tmp_path / "router.log"
    with log.open("wb") as out:
        proc = subprocess.Popen([sys.executable, "-m", "fedtrack.cli", "serve", "router", "--listen",
                                 f"tcp/127.0.0.1:{free_port()}", "--deployment", f"t{os.getpid()}"],
                                stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env)
    try:
        assert wait_until(lambda: " ready " in log.read_text() or proc.poll() is not None, 30.0), log.read_text()
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=10.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
    text = log.read_text()
    assert proc.returncode == 0, text
    assert "stopped (exit code 0)" in text and text.rstrip().endswith("thread done\nexit handlers ran"), text
