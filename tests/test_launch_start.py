"""The launcher holds a lockstep deployment's sensors until every one is up: scan 0 waits for them all.

One live launch on loopback (explicit free port, multicast scouting off, bounded timeouts; the
launcher stops only the processes it started).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from fedtrack.deploy.demo import free_port, write_config
from fedtrack.deploy.launcher import prepare_launcher
from fedtrack.deploy.settings import Settings
from fedtrack.deployment import DeploymentConfig, SensorConfig
from fedtrack.local_filters.vdie.config import FusionConfig

DEADLINE_S = 1.0  # the centre's wait for a scan's estimates; the late sensor comes up twice that after the other
LATE_S = 2 * DEADLINE_S
SCANS = 5


def test_a_lockstep_sensor_slow_to_start_misses_no_scan(tmp_path: Path) -> None:
    """Sensor ``b``'s process sleeps ``LATE_S`` before it starts (a loaded machine's import): every
    scan is still fused from both sensors. Before 2026-11-27 sensor ``a`` sent scan 0 as soon as it
    was up, the centre fused it without ``b`` once ``deadline_s`` had passed (degraded), and ``b``,
    finding a fused track, skipped its scan 0 as a restarted sensor does (``resumed_at``):
    ``tests/test_pipeline_e2e.py`` failed so once in 49 runs at load average 8-20."""
    name = f"late-{os.getpid()}-{time.monotonic_ns() % 100000}"
    settings = Settings(
        fusion=FusionConfig(sensors=("a", "b"), sharing=(2.0, 2.0)),
        deployment=DeploymentConfig(name=name, mode="decentralized", seed=7, deadline_s=DEADLINE_S,
                                    duration_s=float(SCANS - 1), router_listen=f"tcp/127.0.0.1:{free_port()}",
                                    services=("router", "sensor", "local-filter", "fusion-center"),
                                    out=str(tmp_path), ready_timeout_s=60.0),
        sensor=(SensorConfig(id="a", R=((100.0, 5.0), (5.0, 100.0))),
                SensorConfig(id="b", R=((60.0, -10.0), (-10.0, 150.0)))),
    )
    cfg = tmp_path / "config.toml"
    write_config(settings, cfg)
    launcher = prepare_launcher(settings, cfg, tmp_path, quiet=True)
    late = next(sp for sp in launcher.plan if sp.name == "sensor/b")
    late.argv = ["sh", "-c", f'sleep {LATE_S:g} && exec "$@"', "late-sensor", *late.argv]
    report = launcher.run()
    assert report.exit_codes == {sp.name: 0 for sp in launcher.plan}
    assert report.measurements == {"a": SCANS, "b": SCANS}
    assert set(report.publish_stamps_ns[0]) == {"a", "b"}  # b's scan 0 went out
    centre = report.health["fusion-center/fusion"]
    assert centre["scans_fused"] == SCANS and centre.get("degraded_scans", 0) == 0, centre
    assert "resumed_at" not in report.health["sensor/b"]
