"""End-to-end: separate processes over Zenoh on loopback reproduce `fedtrack replay`.

Router, 3 sensors, 3 local filters, the fusion center and the recorder are started by
`fedtrack launch` as separate processes (explicit free loopback port, multicast scouting
off in every session, bounded timeouts; only processes this test started are killed).
"""

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from support import wait_until

from fedtrack.cli import main as cli_main
from fedtrack.deploy.demo import free_port, write_config
from fedtrack.deploy.settings import Settings
from fedtrack.deployment import DeploymentConfig, SensorConfig
from fedtrack.local_filters.vdie.config import FusionConfig

SENSORS = (("a", ((100.0, 5.0), (5.0, 100.0))), ("b", ((60.0, -10.0), (-10.0, 150.0))),
           ("c", ((220.0, 30.0), (30.0, 90.0))))


def deployment(tmp_path: Path, mode: str, pacing: str = "lockstep", speed: float = 1.0) -> tuple[Path, str]:
    name = f"e2e-{mode[:3]}-{os.getpid()}-{time.monotonic_ns() % 100000}"
    settings = Settings(
        fusion=FusionConfig(sensors=tuple(s for s, _ in SENSORS), sharing=(2.0, 4.0, 4.0)),
        deployment=DeploymentConfig(name=name, mode=mode, scenario=1, seed=7, pacing=pacing, speed=speed,
                                    router_listen=f"tcp/127.0.0.1:{free_port()}", out=str(tmp_path),
                                    ready_timeout_s=60.0),
        sensor=tuple(SensorConfig(id=s, R=r) for s, r in SENSORS),
    )
    cfg = tmp_path / "config.toml"
    write_config(settings, cfg)
    return cfg, name


def launch_cmd(cfg: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "fedtrack.cli", "launch", str(cfg), "--out", str(out)]


def rows(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def recorded_tracks(out: Path) -> int:
    """Fused tracks the recorder has committed so far (its database, read while it writes)."""
    db = out / "recording.db"
    if not db.exists():
        return 0
    con = sqlite3.connect(db, timeout=5)
    try:
        return int(con.execute("SELECT COUNT(*) FROM tracks").fetchone()[0])
    except sqlite3.OperationalError:  # the schema is not created yet
        return 0
    finally:
        con.close()


@pytest.mark.parametrize("mode,algorithm", [("federated", "fvdie"), ("decentralized", "dvdie")])
def test_network_tracks_equal_replay(tmp_path, mode, algorithm):
    cfg, _ = deployment(tmp_path, mode)
    proc = subprocess.run(launch_cmd(cfg, tmp_path), capture_output=True, text=True, timeout=150)
    assert proc.returncode == 0, proc.stderr[-3000:]
    tracks = rows(tmp_path / "tracks.jsonl")
    meas = rows(tmp_path / "measurements.jsonl")
    assert len(tracks) == 101 and len(meas) == 303
    assert not any(t["degraded"] for t in tracks)
    assert all("event" in t for t in tracks)  # the replay's field, null when no decision
    # launch writes truth, summary and plot like the demo; the recorder's counters are final
    assert len(rows(tmp_path / "truth.jsonl")) == 101 and (tmp_path / "tracks.png").stat().st_size > 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["scans"] == 101 and summary["rms_position_error_m"] < 20.0
    recorder = summary["health"]["recorder/recorder"]
    assert recorder["measurements_recorded"] == 303 and recorder["tracks_recorded"] == 101
    assert "fedtrack launch summary" in proc.stdout
    out = tmp_path / "replay.jsonl"
    assert cli_main(["replay", "--algorithm", algorithm, "--config", str(cfg),
                     "--measurements", str(tmp_path / "measurements.jsonl"), "--out", str(out)]) == 0
    replay = rows(out)
    assert len(replay) == len(tracks)
    switches = 0
    for net, rep in zip(tracks, replay):
        assert net["t"] == rep["t"] and net["model"] == rep["model"]
        assert net.get("event") == rep["event"]
        np.testing.assert_allclose(net["x"], rep["x"], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(net["P"], rep["P"], rtol=1e-9, atol=1e-12)
        switches += rep["event"] is not None
    assert switches >= 2  # the maneuvers switched the model and are in the comparison


def deployment_pids(name: str) -> list[int]:
    """PIDs of live processes whose command line names this deployment (ours only)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            state = (entry / "stat").read_text().split()[2]
        except OSError:
            continue
        if name in cmd and state != "Z":
            pids.append(int(entry.name))
    return pids


def test_sigterm_stops_every_process(tmp_path):
    cfg, name = deployment(tmp_path, "federated", pacing="realtime", speed=4.0)
    shm_before = set(Path("/dev/shm").glob("*zenoh*"))
    proc = subprocess.Popen(launch_cmd(cfg, tmp_path), stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 60
        tracks = tmp_path / "tracks.jsonl"
        while time.monotonic() < deadline:
            if recorded_tracks(tmp_path) >= 5:
                break
            assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
            time.sleep(0.1)
        else:
            pytest.fail("the deployment fused no scans within 60 s")
        assert len(deployment_pids(name)) >= 9  # router, 3 sensors, 3 filters, centre, recorder
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=30)
        assert wait_until(lambda: deployment_pids(name) == [], 0.5), deployment_pids(name)  # was a fixed 0.5 s
        assert set(Path("/dev/shm").glob("*zenoh*")) <= shm_before
        assert len(rows(tracks)) < 101  # stopped mid-run
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        for pid in deployment_pids(name):
            os.kill(pid, signal.SIGKILL)
