"""Messages valid on the wire but semantically hostile, against the services in-process (marker
``security``): what an attacker holding a valid identity on the bus, or a broken sensor, can send.

Each test first shows the harm the message did (a buffer that grew with every message, a track
the message wrecked) and then that the service now bounds or refuses it, counted. The services are
driven through their own dispatch (decode, sender check, guarded handler), the path a Zenoh sample
takes (:class:`test_hostile_messages.Bus`).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_hostile_messages import KEYS, OPTIONS, Bus, mtt_lines

from fedtrack.local_filters.mtt import history as history_module
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.history import MAX_ENTRIES
from fedtrack.local_filters.mtt import service as service_module
from fedtrack.local_filters.mtt.service import MttLocalService
from fedtrack.wire import Measurement, encode

pytestmark = pytest.mark.security


def scan(sensor: str, seq: int, t: float, z: np.ndarray, R: np.ndarray | None = None) -> Measurement:
    """A multi-target scan of ``sensor`` with detections ``z`` (k, 2)."""
    return Measurement(sensor=sensor, seq=seq, t=t, kind="scan", z=np.zeros(0),
                       R=np.eye(2) * 100.0 if R is None else R, detections=[(row, 0.0) for row in z], stamp_ns=1)


def mtt_local(federated: bool, **kwargs: Any) -> tuple[Bus, MttLocalService]:
    svc = MttLocalService("s1", federated, MttConfig(sensors=("s1",), max_lag=3.0, clutter_density=1e-7), 2.0,
                          service_id="s1", options=OPTIONS, deployment=KEYS.deployment, **kwargs)
    return Bus([svc]), svc


# ---------------------------------------------------------------- scans microseconds apart

def test_scans_microseconds_apart_keep_a_bounded_history(monkeypatch: Any) -> None:
    """A sensor sending scans 0.1 ms apart (all within ``max_lag``) made its tracker keep every one,
    with the state after it: memory grew with every scan and one late scan re-ran them all (2,000
    scans: 58 MB, 3.5 s). The history keeps at most MAX_ENTRIES (256; 16 here, for speed), the
    older folded into the checkpoint; a scan before the checkpoint is late."""
    assert MAX_ENTRIES == 256
    monkeypatch.setattr(history_module, "MAX_ENTRIES", 16)
    bus, svc = mtt_local(federated=False)
    rng = np.random.default_rng(3)
    n = 16 + 24
    for k in range(n):
        bus.put(KEYS.sensor_meas("s1"), encode(scan("s1", k, 1e-4 * k, rng.uniform(-5e3, 5e3, (3, 2)))))
    history = svc.tracker.history  # type: ignore[union-attr]
    assert svc.counters["reports"] == n
    assert len(history.times) == 16 and history.base_t == pytest.approx(1e-4 * (n - 16 - 1))
    bus.put(KEYS.sensor_meas("s1"), encode(scan("s1", n, 1e-4 * 10.5, rng.uniform(-5e3, 5e3, (3, 2)))))
    assert svc.counters["late"] == 1 and len(history.times) == 16


def test_scans_waiting_for_resets_are_bounded(monkeypatch: Any) -> None:
    """A federated tracker holds the scans that arrive while it waits for the centre's resets: with
    the centre slow or gone (one scan a ``--reset-timeout``) or a sensor flooding scans, that queue
    grew with every scan. It holds at most MAX_ENTRIES (16 here); beyond, the oldest waiting scan
    is dropped and counted ``queue_dropped``, and the tracker goes on with the newest."""
    monkeypatch.setattr(service_module, "MAX_ENTRIES", 16)
    bus, svc = mtt_local(federated=True)
    rng = np.random.default_rng(4)
    n = 40
    for k in range(n):
        bus.put(KEYS.sensor_meas("s1"), encode(scan("s1", k, float(k), rng.uniform(-5e3, 5e3, (3, 2)))))
    assert svc.awaiting == 0 and len(svc.queue) == 16 and svc.counters["queue_dropped"] == n - 1 - 16
    assert [seq for seq, _, _ in svc.queue] == list(range(n - 16, n))
    svc.awaiting_since -= 10.0  # the reset timeout passed: the tracker goes on with the oldest kept
    svc.on_tick()
    assert svc.counters["reports"] == 2 and svc.awaiting == n - 16 and len(svc.queue) == 15
