"""A rogue client floods the keys of a running deployment: the tracks are those of the same
measurements without it (replay), nothing dies, and the floods are counted as rejections."""

from __future__ import annotations

import json
import subprocess
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from test_pipeline_e2e import SENSORS, deployment, launch_cmd, rows

from fedtrack.cli import main as cli_main
from fedtrack.deploy.settings import load_settings
from fedtrack.keys import Keys
from fedtrack.wire import LocalEstimate, Measurement, Reset, encode
from fedtrack.zsession import SessionOptions, close_session, open_session

pytestmark = pytest.mark.security

RATE = 1000.0  # messages per second, over all the flooded keys


def hostile_payloads(sensors: list[str]) -> list[tuple[str, bytes]]:
    """(sensor whose keys get it, payload) for every kind: garbage, overflow, wrong sender,
    sequence jumps, wrong models, times that are not the scan's."""
    rng = np.random.default_rng(1)
    x4, P4 = np.zeros(4), np.eye(4)
    out: list[tuple[str, bytes]] = []
    for s in sensors:
        other = next(o for o in sensors if o != s)
        meas = Measurement(sensor=s, seq=2**40, t=1e9, kind="position", z=np.zeros(2), R=np.eye(2), stamp_ns=1)
        est = LocalEstimate(sensor=s, seq=2**40, t=1e9, model="cv", x=x4, P=P4, x_prior=x4, P_prior=P4,
                            stamp_ns=1, maneuver=None, degraded=())
        out += [(s, rng.bytes(int(n))) for n in rng.integers(1, 300, 4)]
        out += [(s, encode(meas)), (s, encode(replace(meas, sensor=other, seq=3))),
                (s, encode(meas).replace(b"\x00" * 8, b"\x7f\xef\xff\xff\xff\xff\xff\xff", 1)),
                (s, encode(est)), (s, encode(replace(est, sensor=other, seq=3))),
                (s, encode(replace(est, model="cv3", x=np.zeros(6), P=np.eye(6), x_prior=np.zeros(6),
                                   P_prior=np.eye(6), seq=5))),
                (s, encode(Reset(sensor=s, seq=2**40, t=1e9, model="cv", x=x4, P=P4, beta=0.5))),
                (s, encode(Reset(sensor=other, seq=3, t=3.0, model="cv", x=x4 + 500.0, P=P4, beta=0.5)))]
    return out


def flood(endpoint: str, keys: Keys, payloads: list[tuple[str, bytes]], stop: threading.Event,
          sent: list[int]) -> None:
    session = open_session(SessionOptions(connect=(endpoint,), connect_timeout_s=20.0))
    try:
        # start once the pipeline runs: the first fused track is out
        started = threading.Event()
        sub = session.declare_subscriber(keys.fusion_track(), lambda _s: started.set())
        started.wait(60)
        sub.undeclare()
        targets = [keys.sensor_meas, keys.local_estimate, keys.fusion_reset]
        t0, n = time.monotonic(), 0
        while not stop.is_set():
            sensor, payload = payloads[n % len(payloads)]
            session.put(targets[n % 3](sensor), payload)
            n += 1
            ahead = n / RATE - (time.monotonic() - t0)
            if ahead > 0:
                time.sleep(ahead)
        sent.append(n)
    finally:
        close_session(session)


def test_rogue_flood_changes_nothing_and_kills_nothing(tmp_path: Path) -> None:
    cfg, name = deployment(tmp_path, "federated")
    settings = load_settings(cfg)
    stop, sent = threading.Event(), []
    rogue = threading.Thread(target=flood, args=(settings.deployment.router_listen, Keys(name),
                                                 hostile_payloads([s for s, _ in SENSORS]), stop, sent))
    rogue.start()
    try:
        proc = subprocess.run(launch_cmd(cfg, tmp_path), capture_output=True, text=True, timeout=240)
    finally:
        stop.set()
        rogue.join(30)
    assert proc.returncode == 0, proc.stderr[-3000:]  # every service ran to the end, none restarted
    tracks = rows(tmp_path / "tracks.jsonl")
    assert len(tracks) == 101 and not any(t["degraded"] for t in tracks)
    out = tmp_path / "replay.jsonl"
    assert cli_main(["replay", "--algorithm", "fvdie", "--config", str(cfg),
                     "--measurements", str(tmp_path / "measurements.jsonl"), "--out", str(out)]) == 0
    for net, rep in zip(tracks, rows(out), strict=True):
        assert net["t"] == rep["t"] and net["model"] == rep["model"]
        np.testing.assert_allclose(net["x"], rep["x"], rtol=1e-9, atol=1e-9)
    health = json.loads((tmp_path / "summary.json").read_text())["health"]
    rejected = sum(h.get("rejected", 0) for h in health.values())
    assert sent and sent[0] > 1000 and rejected > 0.5 * sent[0], (sent, rejected)
    assert all(h.get("rejected_sender", 0) > 0 for k, h in health.items() if k.startswith("local-filter"))
    assert health["fusion-center/fusion"].get("rejected_seq_jump", 0) > 0
