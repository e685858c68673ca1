"""The IMM tracker service over Zenoh: measurements in, FusedTrack with mode probabilities out."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from support import WAIT_S, feed, free_port, wait_until

from fedtrack.keys import Keys
from fedtrack.local_filters.imm.config import IMMConfig
from fedtrack.local_filters.imm.service import IMMService
from fedtrack.local_filters.imm.tracker import IMMTracker
from fedtrack.sensors.imm_scenarios import simulate
from fedtrack.wire import FusedTrack, Measurement, decode, encode
from fedtrack.zsession import SessionOptions, close_session, open_session, wait_alive

ROOT = Path(__file__).resolve().parents[1]




def test_service_tracks_like_the_replay_tracker():
    port = free_port()
    keys = Keys("imm-t1")
    router = open_session(SessionOptions(mode="router", connect=(), listen=(f"tcp/127.0.0.1:{port}",)))
    session = open_session(SessionOptions(connect=(f"tcp/127.0.0.1:{port}",), connect_timeout_s=5.0))
    service = IMMService("radar-1", "ao-vsimm", IMMConfig(), service_id="imm-1",
                         options=SessionOptions(connect=(f"tcp/127.0.0.1:{port}",)), deployment="imm-t1")
    code: list[int] = []
    thread = threading.Thread(target=lambda: code.append(service.run()), daemon=True)
    tracks: list[FusedTrack] = []
    sub = session.declare_subscriber(keys.tracker_track("imm"), lambda s: tracks.append(decode(s.payload.to_bytes(), FusedTrack)))
    thread.start()
    try:
        assert wait_alive(session, [keys.alive("imm", "imm-1")], WAIT_S) == set()
        truth = simulate("S1", 1, np.random.default_rng(5), steps=40)
        R = 400.0 * np.eye(2)
        ref = IMMTracker(IMMConfig(), "ao-vsimm")
        expected = []
        for k in range(40):
            feed(session, keys.sensor_meas("radar-1"), encode(Measurement(
                sensor="radar-1", seq=k, t=float(k + 1), kind="position", z=truth.z[0, k], R=R)))
            expected.append(ref.update(float(k + 1), truth.z[0, k], R))
        # skipped: another dimension, an older time
        feed(session, keys.sensor_meas("radar-1"), encode(Measurement(
            sensor="radar-1", seq=98, t=50.0, kind="position", z=np.zeros(3), R=np.eye(3))))
        feed(session, keys.sensor_meas("radar-1"), encode(Measurement(
            sensor="radar-1", seq=99, t=2.0, kind="position", z=np.zeros(2), R=R)))
        assert wait_until(lambda: service.counters.get("out_of_order", 0) == 1)
        assert wait_until(lambda: len(tracks) >= 40)  # tracks arrive here asynchronously
        assert len(tracks) == 40 and service.counters["unsupported"] == 1
        for got, want in zip(tracks, expected):
            np.testing.assert_allclose(got.x, want.x, rtol=1e-12)
            assert got.extra["active_group"] == want.active_group
            assert got.extra["mode_probabilities"] == pytest.approx(want.mode_probabilities, abs=1e-15)
            assert got.sensors == ("radar-1",) and got.model == "ao-vsimm"
        assert not tracks[20].maneuver and tracks[-1].maneuver  # S1 maneuvers from k = 31
        service.stop()
        thread.join(WAIT_S)
        assert code == [0]
    finally:
        service.stop()
        thread.join(WAIT_S)
        sub.undeclare()
        close_session(session)
        close_session(router)


def test_cli_rejects_a_bad_config_cleanly(tmp_path: Path):
    cfg = tmp_path / "c.toml"
    cfg.write_text("[imm]\ntransition_matrix = 1\n")
    run = subprocess.run([sys.executable, "-m", "fedtrack.cli", "serve", "imm", "--sensor", "s1", "--config", str(cfg),
                          "--connect", f"tcp/127.0.0.1:{free_port()}", "--connect-timeout", "0.3"],
                         cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and f"{cfg}: unknown config key imm.transition_matrix" in run.stderr
    assert "Traceback" not in run.stderr
    bad_id = subprocess.run([sys.executable, "-m", "fedtrack.cli", "serve", "imm", "--sensor", "a/b"],
                            cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert bad_id.returncode == 2 and "--sensor" in bad_id.stderr and "Traceback" not in bad_id.stderr


def test_the_recorder_stores_the_trackers_tracks_and_export_writes_them(tmp_path: Path,
                                                                         capsys: pytest.CaptureFixture[str]) -> None:
    """A user running ``serve imm`` (or ``serve hpda``) beside the recorder finds its tracks in the recording
    (table ``tracker_tracks``, counter ``tracker_tracks_recorded``) and ``fedtrack export --tracker-tracks`` writes
    them as seen live; before (tour58) the recorder did not subscribe to ``tracker/*/*/track`` and stored none.
    Two hpda tracks of one scan are two rows (their track ids); a copy of a row is a duplicate."""
    from fedtrack.cli import main
    from fedtrack.services.recorder import Recorder
    from fedtrack.wire import track_to_replay

    port = free_port()
    keys = Keys("imm-rec")
    options = SessionOptions(connect=(f"tcp/127.0.0.1:{port}",))
    router = open_session(SessionOptions(mode="router", connect=(), listen=(f"tcp/127.0.0.1:{port}",)))
    session = open_session(SessionOptions(connect=(f"tcp/127.0.0.1:{port}",), connect_timeout_s=5.0))
    service = IMMService("radar-1", "ao-vsimm", IMMConfig(), service_id="imm-1", options=options, deployment="imm-rec")
    recorder = Recorder(db=tmp_path / "r.db", service_id="rec", options=options, deployment="imm-rec")
    threads = [threading.Thread(target=svc.run, daemon=True) for svc in (service, recorder)]
    tracks: list[FusedTrack] = []
    sub = session.declare_subscriber(keys.tracker_track("imm"),
                                     lambda s: tracks.append(decode(s.payload.to_bytes(), FusedTrack)))
    for thread in threads:
        thread.start()
    try:
        assert wait_alive(session, [keys.alive("imm", "imm-1"), keys.alive("recorder", "rec")], WAIT_S) == set()
        truth = simulate("S1", 1, np.random.default_rng(5), steps=10)
        for k in range(10):
            feed(session, keys.sensor_meas("radar-1"), encode(Measurement(
                sensor="radar-1", seq=k, t=float(k + 1), kind="position", z=truth.z[0, k], R=400.0 * np.eye(2))))
        assert wait_until(lambda: len(tracks) == 10 and recorder.counters.get("tracker_tracks_recorded") == 10)
    finally:
        for svc, thread in zip((service, recorder), threads):
            svc.stop()
            thread.join(WAIT_S)
        sub.undeclare()
        close_session(session)
        close_session(router)
    assert main(["export", "--db", str(tmp_path / "r.db"), "--out", str(tmp_path / "m.jsonl"),
                 "--tracker-tracks", str(tmp_path / "imm.jsonl")]) == 0
    assert ", 10 single-sensor tracker tracks to " in capsys.readouterr().out
    lines = [json.loads(line) for line in (tmp_path / "imm.jsonl").read_text().splitlines()]
    assert lines == [json.loads(json.dumps(track_to_replay(t))) for t in tracks]
    from fedtrack.recording import DUPLICATE, RECORDED, TRACKER_TRACKS, Recording

    recording = Recording(tmp_path / "r.db")
    two = [FusedTrack(seq=3, t=3.0, model="hpda", x=np.ones(4), P=np.eye(4), maneuver=False, degraded=False,
                      sensors=("sonar1",), stamp_ns=1, extra={"track": float(i)}) for i in (1, 2)]
    assert [recording.add(t, encode(t), TRACKER_TRACKS) for t in (*two, two[0])] == [RECORDED, RECORDED, DUPLICATE]
    assert recording.count(TRACKER_TRACKS) == 12
    recording.close()
