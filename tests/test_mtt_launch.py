"""``fedtrack launch`` of a live multi-target deployment (separate processes over a loopback
router, multicast scouting off): 2-D and radar sensors with their own periods, one local tracker
each, the centre and the recorder; its pictures equal the replay of its recording."""

from __future__ import annotations

import datetime
import json
import os
import sqlite3
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from support import assert_same_pictures, cli_in_process, free_port

from fedtrack.fusion_center.mtt.replay import replay_mtt

CONFIG = """
[deployment]
name = "mttlaunch{port}"
seed = 3
speed = 4.0
router_listen = "tcp/127.0.0.1:{port}"
ready_timeout_s = 60.0

[multitarget]
algorithm = "{algorithm}"
targets = 5
sensors = "pos:1.0,radar:1.3,pos:0.7"
duration = 16.0
clutter = 3.0

[mtt]
clutter_density = 1.2e-7
sensors = ["s1", "r2", "s3"]
maneuver = "vdie"

[mtt.sensor.r2]
clutter_density = 1e-8
"""


def launch(tmp_path: Path, algorithm: str) -> tuple[subprocess.CompletedProcess[str], Path, Path]:
    config = tmp_path / "mtt.toml"
    config.write_text(CONFIG.format(port=free_port(), algorithm=algorithm))
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "fedtrack.cli", "launch", str(config), "--out", str(out)],
                          capture_output=True, text=True, timeout=180)
    return proc, config, out


def test_live_multitarget_deployment_equals_its_replay(tmp_path: Path) -> None:
    proc, config, out = launch(tmp_path, "mtt-federated")
    assert proc.returncode == 0, proc.stderr[-3000:]
    for name in ("measurements.jsonl", "tracks.jsonl", "truth.jsonl", "summary.json", "tracks.png"):
        assert (out / name).is_file(), name
    summary = json.loads((out / "summary.json").read_text())
    assert summary["pictures"] >= 14 and summary["rejected"] == 0 and np.isfinite(summary["mean"]["gospa"])
    assert set(summary["exit_codes"].values()) == {0} and len(summary["exit_codes"]) == 9
    live = [json.loads(x) for x in (out / "tracks.jsonl").read_text().splitlines()]
    assert live and len(live[-1]["tracks"][0]["x"]) == 6  # a radar makes the central state 3-D
    # the sensors kept the one start the launcher gave once all were ready: scan at t sent at start + t / speed
    start = float((out / "logs" / "start-at").read_text())
    db = sqlite3.connect(out / "recording.db")
    lag = np.array(db.execute("SELECT stamp_ns / 1e9 - ? - t / 4.0 FROM measurements", (start,)).fetchall())
    db.close()
    # a sensor keeps the start on its monotonic clock, converted once from the wall clock (hosts share no
    # other); the two clocks may differ by a step of the wall clock (NTP) mid-run: 1 ms allowed for that
    assert lag.size >= 40 and -1e-3 <= lag.min() and lag.max() < 1.0, (lag.min(), lag.max())
    replayed = tmp_path / "replay.jsonl"
    replay_mtt("mtt-federated", out / "measurements.jsonl", config, replayed)  # `fedtrack replay`'s call
    assert_same_pictures(live, [json.loads(x) for x in replayed.read_text().splitlines()])


def test_a_multitarget_launch_needs_realtime_pacing(tmp_path: Path) -> None:
    """Paced in real time without ``pacing`` in the file (CONFIG has none: the launches above); an
    explicit other pacing is refused."""
    config = tmp_path / "mtt.toml"
    lockstep = CONFIG.format(port=free_port(), algorithm="mtt-federated").replace("seed = 3\n",
                                                                                   'seed = 3\npacing = "lockstep"\n')
    config.write_text(lockstep)
    proc = subprocess.run([sys.executable, "-m", "fedtrack.cli", "launch", str(config), "--out", str(tmp_path / "o")],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "deployment.pacing" in proc.stderr and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_a_sensor_joins_and_another_is_killed_during_a_launch(tmp_path: Path) -> None:
    """``join_at`` / ``kill_at``: s3 (which the config does not name) joins at 10 s of 26, s1's
    tracker and sensor are SIGKILLed at 20 s; nothing restarts, the centre drops s1
    within 1 s, s3's tracks associate within 3 of its scans, no central track that another sensor
    supported is lost, and the recording still replays to the live pictures. s3's tracker is made 2 s
    slower to start (a sitecustomize on PYTHONPATH; at load 14 it was ready 7.8 s after the start):
    started mid-run, 2 s before its join, its first scan reached no tracker (at load 14 none did:
    ``KeyError: 's3'``); now every scan of s3 from its join on is processed."""
    slow = tmp_path / "slow"
    slow.mkdir()
    (slow / "sitecustomize.py").write_text('import sys, time\nif sys.argv[1:5] == ["serve", "mtt-local", "--id", "s3"]:'
                                           '\n    time.sleep(2.0)\n')
    config = tmp_path / "mtt.toml"
    text = CONFIG.format(port=free_port(), algorithm="mtt-federated")
    text = text.replace('sensors = "pos:1.0,radar:1.3,pos:0.7"', 'sensors = "pos:1.0,pos:0.7,pos:1.3"')
    text = text.replace("duration = 16.0", "duration = 26.0\njoin_at = { s3 = 10.0 }\nkill_at = { s1 = 20.0 }")
    text = text.replace('sensors = ["s1", "r2", "s3"]', 'sensors = "any"').replace("[mtt.sensor.r2]\n", "")
    text = text.replace("clutter_density = 1e-8\n", "")
    config.write_text(text)
    out = tmp_path / "out"
    path = os.pathsep.join([str(slow), *filter(None, [os.environ.get("PYTHONPATH")])])
    proc = subprocess.run([sys.executable, "-m", "fedtrack.cli", "launch", str(config), "--out", str(out)],
                          capture_output=True, text=True, timeout=180, env={**os.environ, "PYTHONPATH": path})
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["restarts"] == {} and summary["rejected"] == 0 and "scans_not_recorded" not in summary
    def s3_times(path: Path) -> list[float]:
        return [obj["t"] for obj in map(json.loads, path.read_text().splitlines())
                if obj.get("sensor") == "s3" and not obj.get("left")]  # a departure line is no scan

    assert s3_times(out / "measurements.jsonl") == [t for t in s3_times(out / "scenario" / "measurements.jsonl")
                                                    if t >= 10.0], (out / "logs" / "mtt-local-s3.log").read_text()
    codes = summary["exit_codes"]
    assert codes.pop("mtt-local/s1") == -9 and codes.pop("sensor/s1") == -9 and set(codes.values()) == {0}
    joined, left = summary["membership"]["joined"]["s3"], summary["membership"]["left"]["s1"]
    assert joined["first_t"] >= 10.0 and joined["tracks_associated"] >= 3
    assert joined["scans_to_associate"]["max"] <= 3
    assert 0 <= left["dropped_after_s"] < 1.0 and left["supported_by_others"] >= 3 and left["lost"] == []
    assert "s3 joined at" in proc.stderr and "s1 killed: dropped" in proc.stderr
    live = [json.loads(x) for x in (out / "tracks.jsonl").read_text().splitlines()]
    assert any("s3" in tr["sensors"] for tr in live[-1]["tracks"])
    assert not any("s1" in tr["sensors"] for tr in live[-1]["tracks"])
    replayed = tmp_path / "replay.jsonl"
    replay_mtt("mtt-federated", out / "measurements.jsonl", config, replayed)  # `fedtrack replay`'s call
    assert_same_pictures(live, [json.loads(x) for x in replayed.read_text().splitlines()])


@pytest.mark.parametrize("extra, field", [
    ("join_at = { s3 = 40.0 }", "multitarget.join_at.s3"),
    ("kill_at = { s1 = 5.0 }\njoin_at = { s1 = 8.0 }", "multitarget.kill_at.s1"),
    ("join_at = { s9 = 5.0 }", "multitarget.join_at.s9"),
    ("join_at = { s1 = 5.0, r2 = 5.0, s3 = 5.0 }", "multitarget.join_at"),
    ("half_width = 0.0", "multitarget.half_width"),
    ("pd = 1.5", "multitarget.pd: must be in (0, 1], got 1.5"),
    ("pd = nan", "multitarget.pd: must be in (0, 1], got nan"),
])
def test_a_wrong_join_or_kill_schedule_fails_at_start(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                     monkeypatch: pytest.MonkeyPatch, extra: str, field: str) -> None:
    """In this process (starting a process fails the test); the exit code as a shell sees it: the
    test above, also a launch refused at start."""
    config = tmp_path / "mtt.toml"
    config.write_text(CONFIG.format(port=free_port(), algorithm="mtt-federated").replace(
        "duration = 16.0", f"duration = 16.0\n{extra}"))
    proc = cli_in_process(["launch", str(config), "--out", str(tmp_path / "o")], capsys, monkeypatch)
    assert proc.returncode == 2 and field in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("edit, field", [
    (lambda c: c.replace("ready_timeout_s = 60.0", 'ready_timeout_s = 60.0\nlocal_sensors = ["s2"]'),
     "deployment.local_sensors: 's2' is not a sensor of the scenario (s1, r2, s3)"),
    (lambda c: c.replace('sensors = ["s1", "r2", "s3"]', 'sensors = "any"') + "\n[mtt.sensor.r3]\npd = 0.8\n",
     "mtt.sensor.r3: 'r3' is not a sensor of the scenario (s1, r2, s3)"),
    (lambda c: c + "noise_floor = [10.0, 10.0]\n",
     "mtt.sensor.r2.noise_floor: 2 values for a radar sensor, which measures 3 coordinates"),
    (lambda c: c + "\n[mtt.sensor.s1]\nnoise_floor = [10.0, 0.002, 0.002]\n",
     "mtt.sensor.s1.noise_floor: 3 values for a pos sensor, which measures 2 coordinates"),
])
def test_a_scenario_sensor_table_that_fits_no_sensor_fails_at_start(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch,
        edit: Callable[[str], str], field: str) -> None:
    """``local_sensors`` and ``[mtt.sensor.<id>]`` name the scenario's sensors, a ``noise_floor`` one value per
    coordinate its sensor measures (validate58): launched before, a host started no sensor of its own, a table
    went unused, or the centre refused every report of the sensor (``centre_floor_mismatch``)."""
    config = tmp_path / "mtt.toml"
    config.write_text(edit(CONFIG.format(port=free_port(), algorithm="mtt-federated")))
    proc = cli_in_process(["launch", str(config), "--out", str(tmp_path / "o")], capsys, monkeypatch)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    (line,) = proc.stderr.strip().splitlines()
    assert line.startswith(f"fedtrack: error: {config}: {field}"), line


def test_a_sensor_killed_in_a_region_launch_is_summarised_without_a_replay(tmp_path: Path) -> None:
    """``kill_at`` with ``[regions]``: the summary's membership replayed the recording with the one
    centre, which does not take a region run's lines (each scan once per region, tagged ``region``):
    the launch ended in a traceback after its run (``unknown field 'region'``), without summary.json.
    Now a region run's membership says when the centre dropped the killed sensor, and nothing it
    would need that replay for. In-process, on a recording of one line."""
    from fedtrack.deploy.multitarget import membership_summary
    from fedtrack.deploy.report import LaunchReport
    from fedtrack.deploy.settings import load_settings

    config = tmp_path / "config.toml"
    config.write_text(CONFIG.format(port=free_port(), algorithm="mtt-federated").replace(
        'clutter = 3.0\n', 'clutter = 3.0\nkill_at = { s1 = 8.0 }\n') + "[regions]\nmargin = 500.0\n"
        "grid = {origin = [-5000.0, -5000.0], cell = [5000.0, 10000.0], nx = 2, ny = 1}\n")
    (tmp_path / "measurements.jsonl").write_text(json.dumps(
        {"t": 0.25, "sensor": "s3", "R": [[100.0, 0.0], [0.0, 100.0]], "detections": [{"z": [1.0, 2.0]}], "seq": 0,
         "region": "x0y0"}) + "\n")
    (tmp_path / "logs").mkdir()
    (tmp_path / "logs" / "mtt-centre-x0y0.log").write_text(
        "2026-11-27 10:00:02,500 fedtrack.mtt-centre.x0y0 INFO: sensor s1 left: dropped from fusion\n")
    killed = datetime.datetime(2026, 11, 27, 10, 0, 2, 400000).timestamp()
    report = LaunchReport(events=[("killed", "mtt-local/s1", killed), ("killed", "sensor/s1", killed)])
    summary = membership_summary(tmp_path, report, load_settings(config))
    assert summary["joined"] == {} and summary["left"]["s1"]["dropped_after_s"] == pytest.approx(0.1, abs=1e-3)
