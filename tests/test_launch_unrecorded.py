"""A paper deployment's recorder stores every fused track the launcher saw live before the stop, or the
launch says which it lacks and ends with exit 1 (in process: no service is started)."""

from __future__ import annotations

import json
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from fedtrack.deploy import launcher
from fedtrack.deploy.demo import free_port, write_config
from fedtrack.deploy.report import LaunchReport
from fedtrack.deploy.settings import Settings, load_settings
from fedtrack.deployment import DeploymentConfig, SensorConfig
from fedtrack.local_filters.vdie.config import FusionConfig
from fedtrack.recording import Recording
from fedtrack.wire import FusedTrack, Measurement, TrackPicture, encode


def paper_config(tmp_path: Path) -> Path:
    """A one-sensor paper deployment's config in ``tmp_path`` (a free router port)."""
    cfg = tmp_path / "config.toml"
    write_config(Settings(fusion=FusionConfig(sensors=("a",)), sensor=(SensorConfig(id="a"),),
                          deployment=DeploymentConfig(name="unrec", router_listen=f"tcp/127.0.0.1:{free_port()}",
                                                      out=str(tmp_path))), cfg)
    return cfg


def test_fused_tracks_missing_from_the_recording_end_the_launch_with_exit_1(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """At CI load 11 a lockstep run's recorder, stopped with a backlog, left 32 of the 101 fused tracks the
    launcher had seen out of tracks.jsonl and the launch exited 0, its summary saying '69 of 101'."""
    cfg = paper_config(tmp_path)

    def run(self: launcher.Launcher) -> LaunchReport:  # the live run: 5 tracks seen, 3 of them recorded
        lines = [{"t": float(k), "x": [0.0, 0.0, 0.0, 0.0], "P": np.eye(4).tolist(), "model": "cv", "maneuver": False,
                  "degraded": False, "seq": k, "sensors": ["a"], "event": None} for k in (0, 1, 3)]
        (tmp_path / "tracks.jsonl").write_text("".join(json.dumps(line) + "\n" for line in lines))
        return LaunchReport(scans_fused=5, track_arrivals_ns=dict.fromkeys(range(5), 1))

    monkeypatch.setattr(launcher.Launcher, "run", run)
    assert launcher.main([str(cfg), "--out", str(tmp_path)]) == 1  # before: 0
    out, err = capsys.readouterr()
    assert "3 of 101 (0 degraded, 2 seen live but not recorded)" in out
    assert "fedtrack launch: 2 fused tracks seen live are not in the recording (scans 2, 4;" in err
    assert json.loads((tmp_path / "summary.json").read_text())["tracks_not_recorded"] == [2, 4]


def paper_launcher(tmp_path: Path) -> launcher.Launcher:
    cfg = paper_config(tmp_path)
    return launcher.prepare_launcher(load_settings(cfg), cfg, tmp_path, quiet=True)


def test_the_launcher_waits_for_a_slow_recorder_to_store_the_tracks_seen_before_it_stops(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The sensors done, the launcher stops nothing while the recording still grows towards the fused
    tracks seen live: with every fsync slowed to 60 ms a lockstep run's recorder had stored 2 of 101 when
    the sensors ended, and the stop left 9 in tracks.jsonl (exit 0). Here a track is committed every
    0.1 s; a recording that stops growing is given up after RECORDER_STALL_S."""
    monkeypatch.setattr(launcher, "RECORDER_STALL_S", 0.5)  # the waits' bounds below (4 s) stay under the default 5 s
    run = paper_launcher(tmp_path)
    run.report.track_arrivals_ns = dict.fromkeys(range(10), 1)
    db = tmp_path / "recording.db"  # the recorder's (--db of the plan)

    def store(seqs: range, pause_s: float) -> None:  # the recorder: its own connection, a commit a row
        recording = Recording(db)
        for seq in seqs:
            time.sleep(pause_s)
            track = FusedTrack(seq=seq, t=float(seq), model="cv", x=np.ones(4), P=np.eye(4), maneuver=False,
                               degraded=False, sensors=("a",), stamp_ns=1)
            recording.add(track, encode(track))
        recording.close()

    def stored() -> int:
        recording = Recording(db, readonly=True)
        try:
            return recording.count(FusedTrack)
        finally:
            recording.close()

    store(range(4), 0.0)
    writer = threading.Thread(target=store, args=(range(4, 10), 0.1))
    started = time.monotonic()
    writer.start()
    run._await_recording()
    waited, held = time.monotonic() - started, stored()
    writer.join()
    assert held == 10 and 0.5 <= waited < 4.0  # returned once all 10 were stored (before: at once, with 4)
    run.report.track_arrivals_ns = dict.fromkeys(range(12), 1)  # 2 never stored
    started = time.monotonic()
    run._await_recording()
    assert 0.5 <= time.monotonic() - started < 4.0


MTT_CONFIG = """
[deployment]
name = "unrecmtt"
router_listen = "tcp/127.0.0.1:{port}"

[multitarget]
targets = 2
sensors = "pos:1.0"
duration = 4.0
"""


def mtt_launcher(tmp_path: Path) -> launcher.Launcher:
    """A one-sensor multi-target deployment's launcher (its scenario simulated into ``tmp_path``)."""
    cfg = tmp_path / "mtt.toml"
    cfg.write_text(MTT_CONFIG.format(port=free_port()))
    return launcher.prepare_launcher(load_settings(cfg), cfg, tmp_path, quiet=True)


def store_mtt(db: Path, pictures: list[int], scans: list[int], pause_s: float = 0.0) -> None:
    """The recorder: its own connection, a commit a row (a picture, then a scan of s1, in turn)."""
    recording = Recording(db)
    rows: list[TrackPicture | Measurement] = [
        TrackPicture(seq=k, t=float(k), ids=(), x=np.zeros((0, 4)), P=np.zeros((0, 4)), confirmed=(), sensors=(),
                     fused_sensors=(), fused_seqs=(), stamp_ns=1) for k in pictures]
    rows += [Measurement(sensor="s1", seq=k, t=float(k), kind="position", z=np.zeros(2), R=np.eye(2), stamp_ns=1)
             for k in scans]
    for row in rows:
        time.sleep(pause_s)
        recording.add(row, encode(row))
    recording.close()


def test_the_launcher_waits_for_a_slow_recorder_to_store_the_pictures_and_scans_seen(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A multi-target deployment's recorder is waited for as a paper deployment's: with every fsync slowed to
    400 ms it held 9 of the 66 pictures and scans seen when the sensors ended, kept 11 of 15 pictures and 37
    of 51 scans after its 15 s drain, and the launch exited 0 (before: no wait). Here a row is committed every
    0.1 s; a recording that stops growing is given up after RECORDER_STALL_S."""
    monkeypatch.setattr(launcher, "RECORDER_STALL_S", 0.5)
    run = mtt_launcher(tmp_path)
    run.report.picture_seqs, run.report.measurements = set(range(4)), {"s1": 4}
    db = tmp_path / "recording.db"
    store_mtt(db, [0, 1], [0])
    writer = threading.Thread(target=store_mtt, args=(db, [2, 3], [1, 2, 3], 0.1))
    started = time.monotonic()
    writer.start()
    run._await_recording()
    waited = time.monotonic() - started
    writer.join()
    recording = Recording(db, readonly=True)
    assert recording.pictures() == {0, 1, 2, 3} and recording.scans() == {"s1": 4}
    recording.close()
    assert 0.4 <= waited < 4.0  # returned once all were stored (before: at once)
    run.report.picture_seqs.add(4)  # never stored
    started = time.monotonic()
    run._await_recording()
    assert 0.5 <= time.monotonic() - started < 4.0


def test_a_sender_publishing_during_the_wait_does_not_hold_the_launch(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """What was seen is taken when the wait starts: a compromised sensor publishing on after the stop, a new
    scan (recorded) and a repeat of an old number (counted, not a new row) every 0.05 s, kept the count seen
    ahead of the growing recording and held the launch for as long as it went on (here 4 s, the bound of this
    test; before: 4 s); now the wait ends once the recording holds as much as was seen at its start."""
    monkeypatch.setattr(launcher, "RECORDER_STALL_S", 0.5)
    run = mtt_launcher(tmp_path)
    db = tmp_path / "recording.db"
    store_mtt(db, [0], [0, 1])
    run.report.picture_seqs, run.report.measurements = {0}, {"s1": 4}
    done = threading.Event()

    def hostile() -> None:
        seq, end = 100, time.monotonic() + 4.0
        while not done.is_set() and time.monotonic() < end:
            store_mtt(db, [], [seq])
            with run._lock:
                run.report.measurements["s1"] += 2
            seq += 1
            time.sleep(0.05)

    sender = threading.Thread(target=hostile)
    sender.start()
    started = time.monotonic()
    run._await_recording()
    waited = time.monotonic() - started
    done.set()
    sender.join()
    assert waited < 4.0


@pytest.mark.parametrize("lacks", ["pictures", "scans"])
def test_pictures_or_scans_missing_from_a_multitarget_recording_end_the_launch_with_exit_1(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], lacks: str) -> None:
    """The pictures the launcher saw that the recording lacks are listed (``pictures_not_recorded``) and
    said; they, or scans the sensors were to publish that it lacks (``scans_not_recorded``), end the launch
    with exit 1: both ended it with exit 0, the pictures not even counted."""
    cfg = tmp_path / "mtt.toml"
    cfg.write_text(MTT_CONFIG.format(port=free_port()))

    def run(self: launcher.Launcher) -> LaunchReport:  # the live run: pictures 0-4 seen
        n = sum(1 for _ in (tmp_path / "scenario" / "measurements.jsonl").open())  # s1's scans
        store_mtt(tmp_path / "recording.db", [0, 1, 3] if lacks == "pictures" else list(range(5)),
                  list(range(n - 2 if lacks == "scans" else n)))
        return LaunchReport(pictures=5, picture_seqs=set(range(5)))

    monkeypatch.setattr(launcher.Launcher, "run", run)
    assert launcher.main([str(cfg), "--out", str(tmp_path)]) == 1  # before: 0
    err = capsys.readouterr().err
    summary = json.loads((tmp_path / "summary.json").read_text())
    if lacks == "pictures":
        assert "fedtrack launch: 2 pictures seen live are not in the recording (pictures 2, 4; see " in err
        assert summary["pictures_not_recorded"] == [2, 4] and "scans_not_recorded" not in summary
    else:
        assert "fedtrack launch: 2 scans the sensors were to publish are not in the recording (s1: 2)" in err
        assert summary["scans_not_recorded"] == {"s1": 2} and "pictures_not_recorded" not in summary


def test_the_recorder_is_waited_for_after_the_services_before_it_stopped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                                                         ) -> None:
    """The wait comes in the stop, after the centres stopped (a multi-target centre publishes its final
    pictures and closing record as it stops) and before the recorder's SIGTERM; a run stopped before its end
    (Ctrl-C, a failure) does not wait."""
    run = mtt_launcher(tmp_path)
    centre, recorder = (next(sp for sp in run.plan if sp.role == role) for role in ("mtt-centre", "recorder"))
    seen: list[tuple[bool, bool]] = []

    def wait() -> None:  # whether the centre had ended and the recorder was still running
        assert centre.proc is not None and recorder.proc is not None
        seen.append((centre.proc.poll() is not None, recorder.proc.poll() is None))

    monkeypatch.setattr(run, "_await_recording", wait)
    for settle in (True, False):
        run.plan = [centre, recorder]
        for sp in run.plan:
            sp.proc = subprocess.Popen(["sleep", "30"])
        run.stop_all(settle)
        assert all(sp.proc is not None and sp.proc.returncode is not None for sp in run.plan)
    assert seen == [(True, True)]  # once (settle), the centre ended, the recorder still running


def test_a_closed_pipe_at_the_end_still_closes_the_launchers_session(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """``fedtrack demo --scenario multitarget 2>&1 | head -2``: the export's line to the closed pipe raised, the
    launcher's subscribers were never undeclared nor its session closed, and their callback threads (not daemons)
    held the process at its exit for good, after exit code 141 was decided (before tour57). Now they are closed
    whatever the end raises. Here every step runs in process, none starts a service; the export raises."""
    fleet = paper_launcher(tmp_path)
    undeclared: list[int] = []
    closed: list[object] = []

    class Sub:
        def __init__(self, k: int) -> None:
            self.k = k

        def undeclare(self) -> None:
            undeclared.append(self.k)

    def open_monitor(self: launcher.Launcher) -> None:
        self._session, self._subs = "session", [Sub(k) for k in range(3)]  # type: ignore[assignment]

    def broken_pipe(self: launcher.Launcher) -> None:
        raise BrokenPipeError(32, "Broken pipe")

    for name in ("_start", "_wait_listening", "_wait_ready", "_watch", "stop_all"):
        monkeypatch.setattr(launcher.Launcher, name, lambda self, *a, **k: None)
    monkeypatch.setattr(launcher.Launcher, "_open_monitor", open_monitor)
    monkeypatch.setattr(launcher.Launcher, "_export_recording", broken_pipe)
    monkeypatch.setattr(launcher, "await_start", lambda sensors: tmp_path / "start-at")
    monkeypatch.setattr(launcher, "release_sensors", lambda *a: 0.0)
    monkeypatch.setattr(launcher, "close_session", closed.append)
    with pytest.raises(BrokenPipeError):
        fleet.run()
    assert undeclared == [0, 1, 2] and closed == ["session"]


def test_recorded_scans_no_picture_lists_are_said_and_counted(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    """The recorded scans no picture lists (a tracker stopped with them still queued beyond its 2 s drain counts
    them ``dropped``) went only to ``unprocessed.jsonl``, the launch saying nothing (tour58): now they are counted
    per sensor in ``summary.json``'s ``scans_not_tracked`` and said in a line. The exit stays 0: the recording
    holds them and its replay gives the live pictures."""
    cfg = tmp_path / "mtt.toml"
    cfg.write_text(MTT_CONFIG.format(port=free_port()))

    def run(self: launcher.Launcher) -> LaunchReport:  # the live run: one picture, of every scan but the last 2
        n = sum(1 for _ in (tmp_path / "scenario" / "measurements.jsonl").open())  # s1's scans
        recording = Recording(tmp_path / "recording.db")
        rows: list[TrackPicture | Measurement] = [
            Measurement(sensor="s1", seq=k, t=float(k), kind="position", z=np.zeros(2), R=np.eye(2), stamp_ns=1)
            for k in range(n)]
        rows.insert(n - 2, TrackPicture(seq=0, t=float(n - 3), ids=(), x=np.zeros((0, 4)), P=np.zeros((0, 4)),
                                        confirmed=(), sensors=(), fused_sensors=("s1",) * (n - 2),
                                        fused_seqs=tuple(range(n - 2)), stamp_ns=1))
        for row in rows:
            recording.add(row, encode(row))
        recording.close()
        self._export_recording()  # as the run does once every service has stopped
        return LaunchReport(pictures=1, picture_seqs={0}, measurements={"s1": n})

    monkeypatch.setattr(launcher.Launcher, "run", run)
    assert launcher.main([str(cfg), "--out", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    assert (f"fedtrack launch: 2 recorded scans are in no picture (s1: 2; {tmp_path / 'unprocessed.jsonl'}): no "
            "tracker took them (see each mtt-local's counters dropped, late and queue_dropped in summary.json)") in err
    assert json.loads((tmp_path / "summary.json").read_text())["scans_not_tracked"] == {"s1": 2}


def test_a_run_stopped_before_anything_was_recorded_names_only_the_files_written(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """Ctrl-C during a multi-target launch's start (the recorder not yet storing) ends with the files there named:
    before (tour58) it said ``wrote OUT/: measurements.jsonl tracks.jsonl truth.jsonl summary.json tracks.png
    config.toml`` of a folder without the first two and the plot, and ``no recording to export: OUT/recording.db
    is gone`` of a file never made."""
    cfg = tmp_path / "mtt.toml"
    cfg.write_text(MTT_CONFIG.format(port=free_port()))

    def run(self: launcher.Launcher) -> LaunchReport:  # stopped before the recorder made its database
        self._export_recording()
        return LaunchReport()

    monkeypatch.setattr(launcher.Launcher, "run", run)
    launcher.main([str(cfg), "--out", str(tmp_path)])
    out, err = capsys.readouterr()
    assert f"wrote {tmp_path}/: truth.jsonl summary.json config.toml\n" in out
    assert (f"no recording to export: {tmp_path / 'recording.db'} does not exist (the recorder stored nothing, or the "
            "file was removed during the run)") in err


def test_a_run_stopped_at_the_start_does_not_call_the_unpublished_scenario_lost(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """Ctrl-C while the services start: exit 130 and no scan said lost (tour58: '191 scans the sensors were to
    publish are not in the recording', of scans never published). A run stopped later is held to the scans the
    launcher saw live: 3 seen, 2 recorded, 1 said."""
    cfg = tmp_path / "mtt.toml"
    cfg.write_text(MTT_CONFIG.format(port=free_port()))

    def ctrl_c(self: launcher.Launcher, sp: object) -> None:  # the first service's start interrupted
        raise KeyboardInterrupt

    monkeypatch.setattr(launcher.Launcher, "_start", ctrl_c)
    assert launcher.main([str(cfg), "--out", str(tmp_path)]) == 130
    err = capsys.readouterr().err
    assert "not in the recording" not in err and "scans_not_recorded" not in json.loads(
        (tmp_path / "summary.json").read_text())

    def seen_three(self: launcher.Launcher, sp: object) -> None:  # three scans of s1 live, two recorded
        self.report.measurements = {"s1": 3}
        store_mtt(tmp_path / "recording.db", [], [0, 1])
        raise KeyboardInterrupt

    monkeypatch.setattr(launcher.Launcher, "_start", seen_three)
    assert launcher.main([str(cfg), "--out", str(tmp_path)]) == 130
    err = capsys.readouterr().err
    assert "fedtrack launch: 1 scans seen live are not in the recording (s1: 1)" in err
    assert json.loads((tmp_path / "summary.json").read_text())["scans_not_recorded"] == {"s1": 1}


def test_a_demo_stopped_by_ctrl_c_writes_its_summary_as_launch_does(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """``fedtrack demo`` stopped by Ctrl-C once the services start: exit 130 with the summary of what ran
    (``summary.json``, ``truth.jsonl``), as ``launch``; before the tour60 session it returned 130 with neither
    (docs/deploy.md: "At the end (also after Ctrl-C / SIGTERM ...)")."""
    from fedtrack.deploy import demo

    def ctrl_c(self: launcher.Launcher, sp: object) -> None:  # the first service's start interrupted
        raise KeyboardInterrupt

    monkeypatch.setattr(launcher.Launcher, "_start", ctrl_c)
    out = tmp_path / "out"
    assert demo.main(["--scenario", "multitarget", "--insecure", "--out", str(out)]) == 130
    err = capsys.readouterr().err
    assert "fedtrack demo: stopped; every service was shut down" in err
    assert json.loads((out / "summary.json").read_text())["pictures"] == 0
    assert (out / "truth.jsonl").is_file()


def test_the_routers_wait_for_the_final_health_of_the_services_stopped_before_them(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A service that exited 0 said its final Health before its session closed; behind a flood it may still be in a
    router's queue, and the routers, stopped at once after it, lost it (a hostile run's sensor, whose final
    ``stopped`` the readers never saw). The router stage now waits until the monitor has it, at most
    FINAL_HEALTH_WAIT_S: here it arrives 0.3 s late; one that never comes is waited for no longer than the bound."""
    monkeypatch.setattr(launcher, "FINAL_HEALTH_WAIT_S", 3.0)
    run = paper_launcher(tmp_path)
    sensors = [sp for sp in run.plan if sp.role == "sensor"]
    for sp in sensors:
        sp.proc = subprocess.Popen(["true"])
        sp.proc.wait()

    def say_stopped() -> None:
        time.sleep(0.3)
        with run._lock:
            run.report.statuses.update({sp.name: "stopped" for sp in sensors})

    late = threading.Thread(target=say_stopped)
    started = time.monotonic()
    late.start()
    run._await_final_health(sensors)
    waited = time.monotonic() - started
    late.join()
    assert 0.3 <= waited < 2.5, waited  # returned once every final Health came (before: not waited for at all)
    run.report.statuses.clear()
    started = time.monotonic()
    run._await_final_health(sensors)
    assert 3.0 <= time.monotonic() - started < 6.0  # never said: given up after the bound
