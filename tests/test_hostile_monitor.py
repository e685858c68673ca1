"""Hostile messages at the launcher's monitor (``fedtrack launch`` / ``demo``'s own session) and at
the state queryable, driven in-process.

The monitor subscribes to every service's Health and every sensor's measurements and builds the
run's summary from them (``summary.json``: each service's final counters, the rejected total, the
measurements per sensor). Under mutual TLS and access control an identity may publish only on its
own keys, but the monitor read the service a Health belongs to, and the sensor a measurement belongs
to, from the payload, never from the key: sensor 1's certificate could overwrite the fusion centre's
counters in the summary (hiding its rejections) or count measurements for sensor 2.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import zenoh

from fedtrack.deploy.launcher import Launcher
from fedtrack.deploy.settings import load_settings
from fedtrack.wire import Health, Measurement, encode


def sample(key: str, payload: bytes) -> Any:
    """What a Zenoh subscriber callback gets (the fields the monitor reads)."""
    return SimpleNamespace(key_expr=key, kind=zenoh.SampleKind.PUT,
                           payload=SimpleNamespace(to_bytes=lambda: payload))


@pytest.fixture
def launcher(tmp_path: Path) -> Launcher:
    cfg = tmp_path / "c.toml"
    cfg.write_text('[deployment]\nname = "mon"\n')
    return Launcher(load_settings(cfg), [], quiet=True)


def health(role: str, sid: str, rejected: int) -> Health:
    return Health(role=role, id=sid, seq=7, status="ok",
                  counters={"received": 100, "rejected": rejected, "published": 100, "dropped": 0})


def test_a_health_on_another_services_key_is_rejected_not_summarized(launcher: Launcher) -> None:
    """sensor-1 (its own key, which the access control admits) published the fusion centre's Health
    with 0 rejected after the genuine one with 5: the summary said 0 rejected (now 5, and the
    forgery counted); one naming another role of id 1 added a service that does not exist."""
    keys = launcher.keys
    launcher._on_health(sample(keys.health("fusion-center", "fusion"), encode(health("fusion-center", "fusion", 5))))
    launcher._on_health(sample(keys.health("sensor", "1"), encode(health("fusion-center", "fusion", 0))))
    launcher._on_health(sample(keys.health("sensor", "1"), encode(health("recorder", "1", 0))))
    launcher._on_health(sample(keys.health("sensor", "1"), encode(health("sensor", "1", 0))))  # its own: taken
    assert sorted(launcher.report.health) == ["fusion-center/fusion", "sensor/1"]
    assert launcher.report.health["fusion-center/fusion"]["rejected"] == 5
    assert launcher.report.monitor_rejected == 2 and launcher.report.rejected() == 5 + 2


def test_a_measurement_on_another_sensors_key_is_not_counted_for_it(launcher: Launcher) -> None:
    """A measurement of sensor 2 published on sensor 1's key was counted as sensor 2's (the summary's
    measurements per sensor, the progress line's rates); the services reject it (``sender``)."""
    keys = launcher.keys
    for sid in ("1", "2"):
        m = Measurement(sensor=sid, seq=0, t=0.0, kind="position", z=np.zeros(2), R=np.eye(2))
        launcher._on_meas(sample(keys.sensor_meas("1"), encode(m)))
    launcher._on_meas(sample(keys.sensor_meas("1"), b"\x81\xa6schema\x02"))  # malformed: counted too
    assert launcher.report.measurements == {"1": 1} and set(launcher._arrivals) == {"1"}
    assert launcher.report.publish_stamps_ns[0] == [launcher.report.publish_stamps_ns[0][0]]
    assert launcher.report.monitor_rejected == 2
